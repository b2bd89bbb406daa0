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
//! Self-intersection: secondary rays start at the hit point moved along the
//! geometric normal (on the side they leave from) by [`ray_offset`], an
//! integer-ULP offset; shadow rays stop short of the light by a relative
//! `SHADOW_END` so the emitter itself never occludes.
//!
//! Why this offset (measured against the others by `raylab stress --suite
//! offset`): `docs/design.md`, "Self-intersection offset".

use std::f32::consts::PI;
use std::time::Instant;

use glam::Vec3;

use super::rng::{Rng, STREAM_AO, STREAM_LIGHT};
use super::{AoMode, Rect, RenderSettings, RenderStats, Tracer};
use crate::geometry::{triangle_unit_normal, OffsetStrategy, Ray};
use crate::scene::light::Emitter;
use crate::scene::Scene;

/// Radiance of the uniform ambient light that `Ka` reflects.
pub const AMBIENT: f32 = 0.15;
/// Shadow rays end at `(1 - SHADOW_END)` of the distance to the light sample.
const SHADOW_END: f32 = 1e-3;

/// Where secondary rays start: the hit point moved along the geometric normal
/// by Wachter and Binder's integer-ULP offset ([`OffsetStrategy::Ulp`]). Chosen
/// by `raylab stress --suite offset`: no false self-hits at any translation from
/// 0 to 1e6, and occluders as close as 5e-5 of the coordinates' magnitude are
/// still found (a scaled 1e-4 epsilon misses them all).
#[inline]
pub fn ray_offset(p: Vec3, n: Vec3) -> Vec3 {
    OffsetStrategy::Ulp.apply(p, n).0
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
    p: Vec3,
    /// Geometric normal, unit, on the viewer's side.
    ng: Vec3,
    /// Shading normal, unit, on the viewer's side.
    ns: Vec3,
    /// Unit direction towards the viewer.
    wo: Vec3,
    tri: u32,
}

/// Renders `rect` into `out` (row-major, `rect.pixel_count()` long, linear radiance).
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

    // Pass 1: primary rays; emission and the hit surfaces.
    let start = Instant::now();
    let mut surfaces = Vec::with_capacity(out.len());
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            let slot = ((y - rect.y0) * width + (x - rect.x0)) as usize;
            let ray = settings.camera.ray(x, y);
            out[slot] = Vec3::ZERO;
            let Some(hit) = tracer.primary(&ray) else {
                continue;
            };
            let tri = scene.triangle(hit.tri as usize);
            let wo = -ray.dir;
            let mut ng = triangle_unit_normal(&tri);
            let front = ng.dot(wo) >= 0.0;
            if !front {
                ng = -ng;
            }
            let mut ns = scene.shading_normal(hit.tri, hit.u, hit.v).unwrap_or(ng);
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
                p: ray.at(hit.t),
                ng,
                ns,
                wo,
                tri: hit.tri,
            });
        }
    }
    stats.primary_rays = out.len() as u64;
    stats.primary_hits = surfaces.len() as u64;
    stats.primary_time = start.elapsed();

    // Pass 2: direct light.
    let start = Instant::now();
    for s in &surfaces {
        let (radiance, rays) = direct_light(scene, tracer, settings, s);
        out[s.slot] += radiance;
        stats.shadow_rays += rays;
    }
    stats.shadow_time = start.elapsed();

    // Pass 3: ambient term, darkened by AO.
    let start = Instant::now();
    for s in &surfaces {
        let (visibility, rays) = ambient_visibility(tracer, settings, s);
        out[s.slot] += AMBIENT * scene.material_of(s.tri).ka * visibility;
        stats.ao_rays += rays;
    }
    stats.ao_time = start.elapsed();
    stats
}

/// Reflected direct light at `s` and the number of shadow rays cast.
fn direct_light<T: Tracer + ?Sized>(
    scene: &Scene,
    tracer: &T,
    settings: &RenderSettings,
    s: &Surface,
) -> (Vec3, u64) {
    let mat = scene.material_of(s.tri);
    let lights = &scene.lights;
    if lights.is_empty() || settings.light_samples == 0 {
        return (Vec3::ZERO, 0);
    }
    let has_tris = !lights.triangles.is_empty();
    // With both emissive triangles and an extra light, each sample picks one of
    // the two with probability 1/2 (the first random number decides and, rescaled,
    // picks the triangle), so the estimate divides by that probability.
    let sources = has_tris as u32 + lights.extra.is_some() as u32;
    // The extra quad's normal, once per pixel rather than per sample.
    let extra_normal = lights.extra.and_then(|e| e.normal());
    let mut rng = Rng::for_pixel(s.pixel, settings.seed, STREAM_LIGHT);
    let origin = ray_offset(s.p, s.ng);
    let mut sum_tris = Vec3::ZERO;
    let mut sum_extra = Vec3::ZERO;
    let mut rays = 0;
    for _ in 0..settings.light_samples {
        let mut u = rng.next_f32();
        let (r1, r2) = (rng.next_f32(), rng.next_f32());
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
            let light = lights.triangles[lights.pick(u)];
            let tri = scene.triangle(light as usize);
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
        rays += 1;
        let shadow = Ray::segment(origin, wi, 0.0, dist * (1.0 - SHADOW_END));
        if tracer.shadow(&shadow) {
            continue;
        }
        let h = (wi + s.wo).normalize_or_zero();
        let spec = mat.ks * ((mat.ns + 2.0) / (2.0 * PI)) * s.ns.dot(h).max(0.0).powf(mat.ns);
        let brdf = mat.kd / PI + spec;
        let contribution = le * brdf * (cos_s * cos_l / dist2);
        if use_extra {
            sum_extra += contribution;
        } else {
            sum_tris += contribution;
        }
    }
    // Monte Carlo estimate: the triangles' pdf is 1 / total light area; the extra
    // quad's 1 / its area, a point light's a delta.
    // (Clamped: a quad of area beyond f32 would make 0 * inf = NaN.)
    let extra_area = match lights.extra {
        Some(e) => e.area().unwrap_or(1.0).min(f32::MAX),
        None => 1.0,
    };
    // (area * sources) / samples, in that order: with one source this is the
    // same float as before extra lights existed, so old images stay bit-identical.
    let n = settings.light_samples as f32;
    let sources = sources as f32;
    (
        sum_tris * (lights.total_area * sources / n) + sum_extra * (extra_area * sources / n),
        rays,
    )
}

/// The unoccluded fraction of AO directions at `s` and the number of AO rays cast.
fn ambient_visibility<T: Tracer + ?Sized>(
    tracer: &T,
    settings: &RenderSettings,
    s: &Surface,
) -> (f32, u64) {
    let origin = ray_offset(s.p, s.ng);
    let dist = settings.ao_dist;
    match settings.ao {
        AoMode::Off => (1.0, 0),
        AoMode::Paper => {
            let mut cast = 0u32;
            let mut open = 0u32;
            for d in paper_ao_directions() {
                if d.dot(s.ng) > 0.0 {
                    cast += 1;
                    open += !tracer.ao(&Ray::segment(origin, d, 0.0, dist)) as u32;
                }
            }
            // At least one of the 14 directions lies in any open hemisphere.
            (open as f32 / cast as f32, cast as u64)
        }
        AoMode::Cosine(n) => {
            let mut rng = Rng::for_pixel(s.pixel, settings.seed, STREAM_AO);
            let (t, b) = basis(s.ng);
            // Stratified: the radial coordinate in n jittered strata, the angle on a
            // randomly rotated golden-ratio sequence.
            let rotation = rng.next_f32();
            let mut open = 0u32;
            for i in 0..n {
                let u1 = (i as f32 + rng.next_f32()) / n as f32;
                let u2 = (rotation + i as f32 * 0.618_034).fract();
                let r = u1.sqrt();
                let phi = 2.0 * PI * u2;
                let local = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
                let d = t * local.x + b * local.y + s.ng * local.z;
                open += !tracer.ao(&Ray::segment(origin, d, 0.0, dist)) as u32;
            }
            (open as f32 / n as f32, n as u64)
        }
    }
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
    fn offset_moves_off_the_surface_at_any_magnitude() {
        for m in [0.0f32, 0.01, 1.0, 3.7, 1e3, 1e6, -1e6] {
            let p = Vec3::splat(m);
            let q = ray_offset(p, Vec3::Y);
            assert!(q.y > p.y, "{m}: {} -> {}", p.y, q.y);
            assert_eq!((q.x, q.z), (p.x, p.z));
            // Small: well under a thousandth of the magnitude (or 1e-4 near 0).
            assert!(
                q.y - p.y <= 1e-4 * m.abs().max(1.0),
                "{m}: moved {}",
                q.y - p.y
            );
        }
        let down = ray_offset(Vec3::new(0.0, 5.0, 0.0), -Vec3::Y);
        assert!(down.y < 5.0);
    }
}
