//! The one shading and ambient-occlusion loop every backend renders through, the
//! schedules that divide the image between threads, and image output.
//!
//! Data flows one way: a [`Scene`](crate::scene::Scene) and a
//! [`Backend`] go in, a linear-radiance [`Frame`] and
//! [`RenderStats`] come out, and [`output`] turns the frame into 8-bit sRGB.

pub(crate) mod schedule;
pub(crate) mod shade;
pub mod srgb;

use std::ops::AddAssign;
use std::str::FromStr;
use std::time::Duration;

use glam::Vec3;

use crate::accel::Backend;
use crate::camera::Camera;
use crate::error::Error;
use crate::geometry::{Hit, Ray};

pub use schedule::{render, Schedule};

/// The shading loop's three queries, by ray kind. Every [`Backend`] is a tracer
/// (primary rays use `intersect`, shadow and AO rays `occluded`); instrumented
/// tracers (counting traversal work, recording rays) implement it directly, so the
/// loop that measures is the loop that renders.
///
/// The loop asks in streams (a tile's pass at a time, neighbouring rays
/// adjacent: [`shade`]); a tracer that only answers single rays gets the
/// default streams, which ask one ray at a time in stream order.
pub trait Tracer: Sync {
    fn primary(&self, ray: &Ray) -> Option<Hit>;
    fn shadow(&self, ray: &Ray) -> bool;
    fn ao(&self, ray: &Ray) -> bool;

    fn primary_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        for (ray, hit) in rays.iter().zip(hits) {
            *hit = self.primary(ray);
        }
    }
    fn shadow_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        for (ray, o) in rays.iter().zip(occluded) {
            *o = self.shadow(ray);
        }
    }
    fn ao_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        for (ray, o) in rays.iter().zip(occluded) {
            *o = self.ao(ray);
        }
    }
    /// See [`Backend::flushes_denormals`].
    fn flushes_denormals(&self) -> bool {
        false
    }
    /// Told, once per rectangle, where the secondary rays of each primary
    /// hit start: `validate` records them to judge, exactly, that none starts
    /// behind its own surface. A tracer that does not listen leaves the
    /// iterator untouched (nothing is computed).
    fn spawned(&self, _spawns: &mut dyn Iterator<Item = shade::Spawn>) {}
}

impl<B: Backend + ?Sized> Tracer for B {
    #[inline]
    fn primary(&self, ray: &Ray) -> Option<Hit> {
        self.intersect(ray)
    }
    #[inline]
    fn shadow(&self, ray: &Ray) -> bool {
        self.occluded(ray)
    }
    #[inline]
    fn ao(&self, ray: &Ray) -> bool {
        self.occluded(ray)
    }
    fn primary_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        self.intersect_stream(rays, hits)
    }
    fn shadow_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        self.occluded_stream(rays, occluded)
    }
    fn ao_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        self.occluded_stream(rays, occluded)
    }
    fn flushes_denormals(&self) -> bool {
        Backend::flushes_denormals(self)
    }
}

/// Ambient occlusion: off, the study's 14 fixed directions, or N cosine samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AoMode {
    Off,
    /// The study's set: 6 axis directions and 8 normalised diagonals, of which those
    /// in the surface's hemisphere are cast.
    Paper,
    /// N stratified cosine-weighted hemisphere directions per pixel.
    Cosine(u32),
}

impl FromStr for AoMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(AoMode::Off),
            "paper" => Ok(AoMode::Paper),
            _ => {
                let n = s
                    .strip_prefix("cosine:")
                    .ok_or_else(|| format!("'{s}': expected off, paper or cosine:N"))?;
                match n.parse::<u32>() {
                    Ok(n) if (1..=4096).contains(&n) => Ok(AoMode::Cosine(n)),
                    _ => Err(format!(
                        "'{s}': N in cosine:N must be an integer in 1..=4096"
                    )),
                }
            }
        }
    }
}

impl std::fmt::Display for AoMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AoMode::Off => write!(f, "off"),
            AoMode::Paper => write!(f, "paper"),
            AoMode::Cosine(n) => write!(f, "cosine:{n}"),
        }
    }
}

/// Everything that decides the image, apart from the scene and the backend.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub ao: AoMode,
    /// Length of AO rays in scene units (the study used 0.2 in its 2-unit box).
    pub ao_dist: f32,
    /// Shadow rays per pixel towards points sampled by area on emissive triangles.
    pub light_samples: u32,
    /// Seeds every pixel's random stream together with the pixel index.
    pub seed: u64,
    /// Emitters shine from both faces (the old behaviour) instead of only the
    /// side their winding's normal points to.
    pub two_sided_lights: bool,
}

impl RenderSettings {
    /// Checks the values that are not the camera's: AO distance and light samples.
    pub fn validate(&self) -> Result<(), Error> {
        if !(self.ao_dist.is_finite() && self.ao_dist > 0.0) {
            return Err(Error::usage(
                "--ao-dist",
                format!("{} must be a positive number", self.ao_dist),
            ));
        }
        if self.light_samples > 4096 {
            return Err(Error::usage("--light-samples", "at most 4096"));
        }
        Ok(())
    }
}

/// Linear radiance per pixel, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Vec3>,
}

/// A rectangle of pixels `[x0, x1) x [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Rect {
    pub fn pixel_count(&self) -> usize {
        ((self.x1 - self.x0) * (self.y1 - self.y0)) as usize
    }
}

/// Ray counts by kind and the time spent in each pass, summed over threads.
///
/// A pass's time includes its shading work (sampling, BRDF), not only tracing; it
/// is thread time, so for parallel schedules it exceeds wall time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderStats {
    pub primary_rays: u64,
    /// Primary rays that hit a triangle.
    pub primary_hits: u64,
    pub shadow_rays: u64,
    pub ao_rays: u64,
    pub primary_time: Duration,
    pub shadow_time: Duration,
    pub ao_time: Duration,
}

impl RenderStats {
    pub fn total_rays(&self) -> u64 {
        self.primary_rays + self.shadow_rays + self.ao_rays
    }
}

impl AddAssign for RenderStats {
    fn add_assign(&mut self, o: Self) {
        self.primary_rays += o.primary_rays;
        self.primary_hits += o.primary_hits;
        self.shadow_rays += o.shadow_rays;
        self.ao_rays += o.ao_rays;
        self.primary_time += o.primary_time;
        self.shadow_time += o.shadow_time;
        self.ao_time += o.ao_time;
    }
}

/// 0.2 (the study's) in the built-in boxes, else 1/16 of the bounding box's
/// diagonal (0.22 for the box, so files of any scale get the same look).
pub fn default_ao_dist(scene: &crate::scene::Scene) -> f32 {
    if scene.study_frame {
        0.2
    } else {
        let b = scene.bounds();
        ((b.max - b.min).as_dvec3().length() / 16.0).max(f32::MIN_POSITIVE as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ao_modes_parse_and_print() {
        for s in ["off", "paper", "cosine:1", "cosine:64"] {
            assert_eq!(s.parse::<AoMode>().unwrap().to_string(), s);
        }
        for bad in ["", "on", "cosine:", "cosine:0", "cosine:x", "cosine:99999"] {
            assert!(bad.parse::<AoMode>().is_err(), "{bad}");
        }
    }
}
