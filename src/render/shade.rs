//! The shading kernel: renders one rectangle of the image in three passes
//! (primary rays, shadow rays, AO rays), each timed, so the render summary can
//! report work by ray kind without a clock read per ray.
//!
//! Radiance model (direct light only, as in the study): emission `Ke`, plus an
//! ambient term `AMBIENT * Ka * visibility` (visibility is the AO fraction, 1 with
//! AO off), plus Lambert (`Kd / pi`) and normalised Blinn-Phong
//! (`Ks (Ns + 2) / 2pi cos^Ns`) reflection of light sampled by area on the emissive
//! triangles (and the scene's extra light, see [`crate::scene::light`]), one
//! shadow ray per sample. Emitters are one-sided: they emit on the side their
//! winding's normal points to (pbrt-v4's and Mitsuba's area lights are too), and
//! from both sides with `two_sided_lights`.
//!
//! Self-intersection: secondary rays start at the hit point interpolated from
//! the triangle's vertices, moved along the geometric normal (on the side they
//! leave from) by a bound on that point's error ([`spawn_origin`], pbrt-v4's
//! and Wachter and Binder's way), so they start strictly on the right side of
//! the surface at any distance from the camera and the origin; shadow rays
//! stop short of the light by a relative `SHADOW_END` so the emitter itself
//! never occludes.
//!
//! Why this offset (measured against the others by `raylab stress --suite
//! offset`): `docs/design.md`, "Self-intersection offset".

use std::f32::consts::PI;
use std::time::Instant;

use glam::Vec3;

use super::{AoMode, Rect, RenderSettings, RenderStats, Tracer};
use crate::geometry::{triangle_unit_normal, Hit, Ray};
use crate::rng::{Rng, STREAM_AO, STREAM_LIGHT};
use crate::scene::light::Emitter;
use crate::scene::Scene;

/// Radiance of the uniform ambient light that `Ka` reflects.
pub const AMBIENT: f32 = 0.15;
/// Shadow rays end at `(1 - SHADOW_END)` of the distance to the light sample.
const SHADOW_END: f32 = 1e-3;

/// Where the secondary rays of `hit` start, leaving its triangle on the side
/// of unit normal `n` (the geometric normal on the viewer's side): see
/// [`spawn_origin`]. Every secondary ray of the renderer, and `validate`'s
/// diffuse bounces, start here.
#[inline]
pub fn secondary_origin(scene: &Scene, hit: &Hit, n: Vec3) -> Vec3 {
    scene.spawn_point(hit, n)
}

/// Where the secondary rays of one primary hit start, as [`Tracer::spawned`]
/// is told: the triangle left (and its instance), its geometric normal on
/// the side left (unit), and the origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spawn {
    pub tri: u32,
    /// The instance that placed `tri` (0 in a flat scene).
    pub inst: u32,
    pub normal: Vec3,
    pub origin: Vec3,
}

/// The study's 14 AO directions: 6 axes and 8 normalised diagonals.
pub fn paper_ao_directions() -> [Vec3; 14] {
    let d = 1.0 / 3f32.sqrt();
    let mut dirs = [Vec3::ZERO; 14];
    let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    dirs[..6].copy_from_slice(&axes);
    let mut i = 6;
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for sz in [-1.0, 1.0] {
                dirs[i] = Vec3::new(sx, sy, sz) * d;
                i += 1;
            }
        }
    }
    dirs
}

/// A cosine-weighted direction about unit `n` from two uniform numbers in
/// [0, 1) (Malley's method: a uniform point on the disc, lifted).
pub fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let (t, b) = basis(n);
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()
}

/// An orthonormal basis around unit `n` (Duff et al. 2017, branchless).
#[inline]
fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// What pass 1 leaves for the later passes at a pixel whose primary ray hit.
#[derive(Clone, Copy)]
struct Surface {
    /// Index into the rectangle's pixels.
    slot: usize,
    /// Global pixel index (seeds the random streams).
    pixel: u64,
    /// Where its secondary rays start ([`secondary_origin`]).
    origin: Vec3,
    /// Geometric normal, unit, on the viewer's side.
    ng: Vec3,
    /// Shading normal, unit, on the viewer's side.
    ns: Vec3,
    /// Unit direction towards the viewer.
    wo: Vec3,
    tri: u32,
    /// The instance that placed `tri` (0 in a flat scene).
    inst: u32,
}

/// Pixels per side of the blocks primary rays are issued in: a packet of 8
/// consecutive rays covers 4 x 2 pixels, one of 16 the whole block.
const BLOCK: u32 = 4;
/// Most rays in one stream of secondary rays: a pass takes the surfaces in
/// groups whose rays fit (a whole 64 x 48 tile at one ray per pixel), so a
/// pass with thousands of samples per pixel does not hold them all at once.
const STREAM_RAYS: usize = 4096;

/// The pixels of `rect` in 4 x 4 blocks (row by row inside a block, blocks
/// row by row), so that neighbouring rays of a stream are neighbouring pixels.
fn block_order(rect: Rect) -> Vec<(u32, u32)> {
    let mut pixels = Vec::with_capacity(rect.pixel_count());
    for by in (rect.y0..rect.y1).step_by(BLOCK as usize) {
        for bx in (rect.x0..rect.x1).step_by(BLOCK as usize) {
            for y in by..(by + BLOCK).min(rect.y1) {
                for x in bx..(bx + BLOCK).min(rect.x1) {
                    pixels.push((x, y));
                }
            }
        }
    }
    pixels
}

/// The surfaces of a pass in groups of at most [`STREAM_RAYS`] rays when each
/// casts up to `per_surface` (at least one surface a group).
fn groups(surfaces: &[Surface], per_surface: usize) -> std::slice::Chunks<'_, Surface> {
    surfaces.chunks((STREAM_RAYS / per_surface.max(1)).max(1))
}

/// Renders `rect` into `out` (row-major, `rect.pixel_count()` long, linear radiance).
///
/// Each pass asks the tracer in streams with coherent rays adjacent: primary
/// rays by 4 x 4 pixel blocks; shadow rays by surface, in that order; the
/// study's AO direction by direction over the surfaces, cosine AO sample
/// index by sample index. Every pixel's random numbers are drawn in the same
/// order as one pixel at a time would, and every sum is added in the same
/// order, so the image is the same bit for bit whatever the stream order.
pub fn render_rect<T: Tracer + ?Sized>(
    scene: &Scene,
    tracer: &T,
    settings: &RenderSettings,
    rect: Rect,
    out: &mut [Vec3],
) -> RenderStats {
    debug_assert_eq!(out.len(), rect.pixel_count());
    let mut stats = RenderStats::default();
    let width = rect.x1 - rect.x0;
    out.fill(Vec3::ZERO);

    // Pass 1: primary rays; emission and the hit surfaces.
    let start = Instant::now();
    let pixels = block_order(rect);
    let rays: Vec<Ray> = pixels
        .iter()
        .map(|&(x, y)| settings.camera.ray(x, y))
        .collect();
    let mut hits = vec![None; rays.len()];
    tracer.primary_stream(&rays, &mut hits);
    let mut surfaces = Vec::with_capacity(out.len());
    for ((&(x, y), ray), hit) in pixels.iter().zip(&rays).zip(hits) {
        let Some(hit) = hit else {
            continue;
        };
        let slot = ((y - rect.y0) * width + (x - rect.x0)) as usize;
        let tri = scene.hit_triangle(&hit);
        let wo = -ray.dir;
        let mut ng = triangle_unit_normal(&tri);
        let front = ng.dot(wo) >= 0.0;
        if !front {
            ng = -ng;
        }
        let mut ns = scene.hit_shading_normal(&hit).unwrap_or(ng);
        if ns.dot(wo) < 0.0 {
            ns = -ns;
        }
        // An emitter is seen glowing from its emitting side only.
        if front || settings.two_sided_lights {
            out[slot] = scene.material_of(hit.tri).ke;
        }
        surfaces.push(Surface {
            slot,
            pixel: y as u64 * settings.width as u64 + x as u64,
            origin: secondary_origin(scene, &hit, ng),
            ng,
            ns,
            wo,
            tri: hit.tri,
            inst: hit.inst,
        });
    }
    tracer.spawned(&mut surfaces.iter().map(|s| Spawn {
        tri: s.tri,
        inst: s.inst,
        normal: s.ng,
        origin: s.origin,
    }));
    stats.primary_rays = out.len() as u64;
    stats.primary_hits = surfaces.len() as u64;
    stats.primary_time = start.elapsed();

    // Pass 2: direct light.
    let start = Instant::now();
    stats.shadow_rays = direct_light(scene, tracer, settings, &surfaces, out);
    stats.shadow_time = start.elapsed();

    // Pass 3: ambient term, darkened by AO.
    let start = Instant::now();
    stats.ao_rays = ambient(scene, tracer, settings, &surfaces, out);
    stats.ao_time = start.elapsed();
    stats
}

/// A shadow ray's sample: what it adds to its surface's sum when unoccluded.
#[derive(Clone, Copy)]
struct LightSample {
    contribution: Vec3,
    /// Sampled on the extra light (else on the emissive triangles).
    extra: bool,
}

/// Adds the reflected direct light of every surface to `out` and returns the
/// number of shadow rays cast.
fn direct_light<T: Tracer + ?Sized>(
    scene: &Scene,
    tracer: &T,
    settings: &RenderSettings,
    surfaces: &[Surface],
    out: &mut [Vec3],
) -> u64 {
    let lights = &scene.lights;
    if lights.is_empty() || settings.light_samples == 0 {
        return 0;
    }
    // Monte Carlo estimate: the triangles' pdf is 1 / total light area; the extra
    // quad's 1 / its area, a point light's a delta. With both emissive triangles
    // and an extra light, each sample picks one of the two with probability 1/2,
    // so the estimate divides by that probability.
    // (Clamped: a quad of area beyond f32 would make 0 * inf = NaN.)
    let sources = (!lights.triangles.is_empty()) as u32 + lights.extra.is_some() as u32;
    let extra_area = match lights.extra {
        Some(e) => e.area().unwrap_or(1.0).min(f32::MAX),
        None => 1.0,
    };
    // (area * sources) / samples, in that order: with one source this is the
    // same float as before extra lights existed, so old images stay bit-identical.
    let n = settings.light_samples as f32;
    let sources = sources as f32;
    let (tris_scale, extra_scale) = (lights.total_area * sources / n, extra_area * sources / n);
    let mut cast = 0;
    let (mut rays, mut samples, mut counts) = (Vec::new(), Vec::new(), Vec::new());
    let mut occluded = Vec::new();
    for group in groups(surfaces, settings.light_samples as usize) {
        rays.clear();
        samples.clear();
        counts.clear();
        for s in group {
            counts.push(light_samples(scene, settings, s, &mut rays, &mut samples));
        }
        occluded.clear();
        occluded.resize(rays.len(), false);
        tracer.shadow_stream(&rays, &mut occluded);
        let mut next = 0;
        for (s, &count) in group.iter().zip(&counts) {
            let mut sum_tris = Vec3::ZERO;
            let mut sum_extra = Vec3::ZERO;
            for (sample, &blocked) in samples[next..next + count]
                .iter()
                .zip(&occluded[next..next + count])
            {
                if blocked {
                    continue;
                }
                if sample.extra {
                    sum_extra += sample.contribution;
                } else {
                    sum_tris += sample.contribution;
                }
            }
            next += count;
            out[s.slot] += sum_tris * tris_scale + sum_extra * extra_scale;
        }
        cast += rays.len() as u64;
    }
    cast
}

/// The light samples at `s`: pushes a shadow ray to `rays` and what it adds
/// when unoccluded to `samples` for each sample that needs one (a light below
/// the surface needs none), and returns how many it pushed.
fn light_samples(
    scene: &Scene,
    settings: &RenderSettings,
    s: &Surface,
    rays: &mut Vec<Ray>,
    samples: &mut Vec<LightSample>,
) -> usize {
    let mat = scene.material_of(s.tri);
    let lights = &scene.lights;
    let has_tris = !lights.triangles.is_empty();
    // The extra quad's normal, once per pixel rather than per sample.
    let extra_normal = lights.extra.and_then(|e| e.normal());
    let mut rng = Rng::for_pixel(s.pixel, settings.seed, STREAM_LIGHT);
    let origin = s.origin;
    let before = rays.len();
    for _ in 0..settings.light_samples {
        let mut u = rng.next_f32();
        let (r1, r2) = (rng.next_f32(), rng.next_f32());
        // With both sources, the first random number decides and, rescaled,
        // picks the triangle.
        let use_extra = match (has_tris, lights.extra.is_some()) {
            (true, true) => {
                let extra = u >= 0.5;
                u = (u * 2.0).fract();
                extra
            }
            (false, _) => true,
            (true, false) => false,
        };
        // The sampled point, its radiance (a point light's intensity) and the
        // light's unit normal there (None for a point light, which has no area).
        let (q, le, light_normal) = if use_extra {
            match lights.extra.expect("an extra light") {
                Emitter::Point {
                    position,
                    intensity,
                } => (position, intensity, None),
                Emitter::Quad {
                    corner,
                    edge_u,
                    edge_v,
                    radiance,
                } => (corner + edge_u * r1 + edge_v * r2, radiance, extra_normal),
            }
        } else {
            let k = lights.pick(u);
            let (light, tri) = (lights.triangles[k], scene.light_triangle(k));
            // Uniform point on the triangle (square-root warp).
            let su = r1.sqrt();
            let q = tri[0] * (1.0 - su) + tri[1] * (su * (1.0 - r2)) + tri[2] * (su * r2);
            (
                q,
                scene.material_of(light).ke,
                Some(triangle_unit_normal(&tri)),
            )
        };
        let to_light = q - origin;
        let dist2 = to_light.length_squared();
        if !(dist2 > 0.0) {
            continue;
        }
        let dist = dist2.sqrt();
        let wi = to_light / dist;
        let cos_s = s.ns.dot(wi);
        if s.ng.dot(wi) <= 0.0 || cos_s <= 0.0 {
            continue; // light below the surface: no ray needed
        }
        // Area emitters shine on the side their normal points to (towards the
        // surface: against wi), unless two-sided.
        let cos_l = match light_normal {
            None => 1.0,
            Some(n) if settings.two_sided_lights => n.dot(wi).abs(),
            Some(n) => -n.dot(wi),
        };
        if cos_l <= 0.0 {
            continue;
        }
        rays.push(Ray::segment(origin, wi, 0.0, dist * (1.0 - SHADOW_END)));
        let h = (wi + s.wo).normalize_or_zero();
        let spec = mat.ks * ((mat.ns + 2.0) / (2.0 * PI)) * s.ns.dot(h).max(0.0).powf(mat.ns);
        let brdf = mat.kd / PI + spec;
        samples.push(LightSample {
            contribution: le * brdf * (cos_s * cos_l / dist2),
            extra: use_extra,
        });
    }
    rays.len() - before
}

/// Adds the ambient term of every surface, darkened by its unoccluded fraction
/// of AO directions, to `out`, and returns the number of AO rays cast.
fn ambient<T: Tracer + ?Sized>(
    scene: &Scene,
    tracer: &T,
    settings: &RenderSettings,
    surfaces: &[Surface],
    out: &mut [Vec3],
) -> u64 {
    let mut add = |s: &Surface, visibility: f32| {
        out[s.slot] += AMBIENT * scene.material_of(s.tri).ka * visibility;
    };
    let dist = settings.ao_dist;
    let (mut rays, mut owners, mut occluded) = (Vec::new(), Vec::new(), Vec::new());
    let mut cast = 0;
    match settings.ao {
        AoMode::Off => surfaces.iter().for_each(|s| add(s, 1.0)),
        AoMode::Paper => {
            let dirs = paper_ao_directions();
            for group in groups(surfaces, dirs.len()) {
                let origins: Vec<Vec3> = group.iter().map(|s| s.origin).collect();
                // Direction by direction: a packet holds one direction from
                // neighbouring pixels.
                rays.clear();
                owners.clear();
                for d in dirs {
                    for (i, s) in group.iter().enumerate() {
                        if d.dot(s.ng) > 0.0 {
                            rays.push(Ray::segment(origins[i], d, 0.0, dist));
                            owners.push(i);
                        }
                    }
                }
                occluded.clear();
                occluded.resize(rays.len(), false);
                tracer.ao_stream(&rays, &mut occluded);
                let mut open = vec![0u32; group.len()];
                let mut count = vec![0u32; group.len()];
                for (&i, &blocked) in owners.iter().zip(&occluded) {
                    count[i] += 1;
                    open[i] += !blocked as u32;
                }
                // At least one of the 14 directions lies in any open hemisphere.
                for (i, s) in group.iter().enumerate() {
                    add(s, open[i] as f32 / count[i] as f32);
                }
                cast += rays.len() as u64;
            }
        }
        AoMode::Cosine(n) => {
            for group in groups(surfaces, n as usize) {
                // Each surface's random stream, frame and rotation, drawn in the
                // order one surface at a time would draw them.
                let mut frames: Vec<(Rng, Vec3, Vec3, f32, Vec3)> = group
                    .iter()
                    .map(|s| {
                        let mut rng = Rng::for_pixel(s.pixel, settings.seed, STREAM_AO);
                        let (t, b) = basis(s.ng);
                        // Stratified: the radial coordinate in n jittered strata, the
                        // angle on a randomly rotated golden-ratio sequence.
                        let rotation = rng.next_f32();
                        (rng, t, b, rotation, s.origin)
                    })
                    .collect();
                // Sample index by sample index over the surfaces.
                rays.clear();
                owners.clear();
                for i in 0..n {
                    for (k, (s, (rng, t, b, rotation, origin))) in
                        group.iter().zip(&mut frames).enumerate()
                    {
                        let u1 = (i as f32 + rng.next_f32()) / n as f32;
                        let u2 = (*rotation + i as f32 * 0.618_034).fract();
                        let r = u1.sqrt();
                        let phi = 2.0 * PI * u2;
                        let local =
                            Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
                        let d = *t * local.x + *b * local.y + s.ng * local.z;
                        rays.push(Ray::segment(*origin, d, 0.0, dist));
                        owners.push(k);
                    }
                }
                occluded.clear();
                occluded.resize(rays.len(), false);
                tracer.ao_stream(&rays, &mut occluded);
                let mut open = vec![0u32; group.len()];
                for (&k, &blocked) in owners.iter().zip(&occluded) {
                    open[k] += !blocked as u32;
                }
                for (k, s) in group.iter().enumerate() {
                    add(s, open[k] as f32 / n as f32);
                }
                cast += rays.len() as u64;
            }
        }
    }
    cast
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_directions_are_fourteen_unit_vectors() {
        let dirs = paper_ao_directions();
        for d in dirs {
            assert!((d.length() - 1.0).abs() < 1e-6);
        }
        // Symmetric set: for an axis normal, 5 directions lie strictly above.
        assert_eq!(dirs.iter().filter(|d| d.dot(Vec3::Y) > 0.0).count(), 5);
    }

    #[test]
    fn basis_is_orthonormal() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.4, 0.5).normalize(),
        ] {
            let (t, b) = basis(n);
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5);
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn secondary_origins_leave_the_surface_at_any_magnitude() {
        // A floor triangle at y = c, seen from above and from below.
        for m in [0.0f32, 0.01, 1.0, 3.7, 1e3, 1e6, -1e6] {
            let c = Vec3::splat(m);
            let tri = [
                c + Vec3::new(-1.0, 0.0, -1.0),
                c + Vec3::new(1.0, 0.0, -1.0),
                c + Vec3::new(0.0, 0.0, 1.0),
            ];
            for n in [Vec3::Y, -Vec3::Y] {
                let q = crate::geometry::spawn_origin(&tri, 0.3, 0.3, n);
                assert!((q.y - m) * n.y > 0.0, "{m}: {} leaves {n}", q.y);
                // Small: well under a thousandth of the magnitude (or 1e-4 near 0).
                assert!((q.y - m).abs() <= 1e-4 * m.abs().max(1.0), "{m}: {}", q.y);
            }
        }
    }
}
