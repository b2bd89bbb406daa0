//! The offset suite: rays leaving a floor translated far from the origin by
//! each self-intersection strategy, counting false self-hits and missed
//! occluders.

use glam::Vec3;
use serde::Serialize;

use crate::accel::bvh::{BuildParams, BvhBackend};
use crate::accel::Backend;
use crate::error::Result;
use crate::geometry::{Hit, Intersector, OffsetStrategy, Ray};
use crate::rng::Rng;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// One strategy at one translation.
#[derive(Clone, Debug, Serialize)]
pub struct OffsetRow {
    pub translation: f32,
    /// The floor and where the primary rays that found its points came
    /// from: "near" (the floor at (T, T, T), the rays from about one scale
    /// unit above, steep) or "field" (the floor in the plane y = 0 at
    /// (T, 0, T), the rays from 200 scale units away at a grazing 3 degrees,
    /// as a camera sees a field's far side).
    pub view: &'static str,
    pub strategy: OffsetStrategy,
    pub intersector: Intersector,
    pub rays: usize,
    /// Rays leaving the floor that hit it again.
    pub self_hit_rate: f64,
    /// Upward rays that miss an occluder 1e-3 (5e-5, 1e-5) of the scale above.
    pub missed_at_1e3: f64,
    pub missed_at_5e5: f64,
    pub missed_at_1e5: f64,
}

/// A square of half-size `half` at height `y`, centred at `c` (two triangles).
fn square(c: Vec3, y: f32, half: f32) -> [[Vec3; 3]; 2] {
    let p = |x: f32, z: f32| Vec3::new(c.x + x, y, c.z + z);
    [
        [p(-half, -half), p(half, -half), p(half, half)],
        [p(-half, -half), p(half, half), p(-half, half)],
    ]
}

/// The offset suite: for each translation, points on a floor found by primary
/// rays (with their rounding), then rays leaving it by each strategy.
pub fn offset_suite(translations: &[f32], points: usize) -> Result<Vec<OffsetRow>> {
    let mut rows = Vec::new();
    for &shift in translations {
        for view in ["near", "field"] {
            // "field": the floor stays in the plane y = 0 (a ground's height is
            // 0 in most exports however far out it lies).
            let c = match view {
                "near" => Vec3::splat(shift),
                _ => Vec3::new(shift, 0.0, shift),
            };
            let scale = shift.abs().max(1.0);
            let floor = square(c, c.y, 1.0);
            // Wide enough that no upward ray (cosine >= 0.2, so at most 5 units
            // sideways per unit up) can pass beside it.
            let with_occluder = |h: f32| {
                let mut t = floor.to_vec();
                t.extend(square(c, c.y + h * scale, 2.0 + 6.0 * h * scale));
                t
            };
            let (near, closer, nearest) = (
                with_occluder(1e-3),
                with_occluder(5e-5),
                with_occluder(1e-5),
            );
            for intersector in [Intersector::Mt, Intersector::Watertight] {
                let make = |t: &[[Vec3; 3]]| {
                    BvhBackend::new(t, &BuildParams::sah()).map(|b| b.with_intersector(intersector))
                };
                let (floor_only, near_b) = (make(&floor)?, make(&near)?);
                let (closer_b, nearest_b) = (make(&closer)?, make(&nearest)?);
                let mut rng = Rng::for_pixel(shift.to_bits() as u64, 5, 0x0FF5);
                // Surface points as a renderer finds them: the hits of primary rays
                // (each strategy starts from o + t d or from the hit's barycentrics).
                let hits: Vec<(Ray, Hit)> = (0..points)
                    .filter_map(|_| {
                        let target = c + Vec3::new(
                            rng.next_f32() * 1.8 - 0.9,
                            0.0,
                            rng.next_f32() * 1.8 - 0.9,
                        );
                        let o = if view == "near" {
                            target
                                + Vec3::new(rng.next_f32() - 0.5, 1.0, rng.next_f32() - 0.5) * scale
                        } else {
                            // Far and grazing, as a camera sees a field's far side.
                            let phi = std::f32::consts::TAU * rng.next_f32();
                            let grazing = 3f32.to_radians();
                            let back = Vec3::new(
                                phi.cos() * grazing.cos(),
                                grazing.sin(),
                                phi.sin() * grazing.cos(),
                            );
                            target + back * (200.0 * scale)
                        };
                        let ray = Ray::new(o, (target - o).normalize());
                        floor_only.intersect(&ray).map(|h| (ray, h))
                    })
                    .collect();
                for strategy in OffsetStrategy::ALL {
                    let (mut self_hits, mut missed3, mut missed45, mut missed5, mut n) =
                        (0, 0, 0, 0, 0);
                    for (primary, hit) in &hits {
                        // Cosine-ish upward directions, not grazing (cos >= 0.2), so a
                        // finite occluder above covers every one.
                        let (u, v) = (rng.next_f32(), rng.next_f32());
                        let cos = 0.2 + 0.8 * u;
                        let sin = (1.0 - cos * cos).sqrt();
                        let phi = std::f32::consts::TAU * v;
                        let d = Vec3::new(sin * phi.cos(), cos, sin * phi.sin());
                        let tri = &floor[hit.tri as usize];
                        let (origin, tmin) =
                            strategy.apply(primary, (hit.t, hit.u, hit.v), tri, Vec3::Y);
                        let ray = Ray::segment(origin, d, tmin, f32::INFINITY);
                        n += 1;
                        self_hits += floor_only.occluded(&ray) as usize;
                        // The occluder is triangles 2 and 3; a floor hit or a miss both fail.
                        let hits_occluder =
                            |b: &BvhBackend| b.intersect(&ray).is_some_and(|h| h.tri >= 2);
                        missed3 += !hits_occluder(&near_b) as usize;
                        missed45 += !hits_occluder(&closer_b) as usize;
                        missed5 += !hits_occluder(&nearest_b) as usize;
                    }
                    let rate = |x: usize| x as f64 / n.max(1) as f64;
                    rows.push(OffsetRow {
                        translation: shift,
                        view,
                        strategy,
                        intersector,
                        rays: n,
                        self_hit_rate: rate(self_hits),
                        missed_at_1e3: rate(missed3),
                        missed_at_5e5: rate(missed45),
                        missed_at_1e5: rate(missed5),
                    });
                }
            }
        }
    }
    Ok(rows)
}

/// The offset rows as a table.
pub fn offset_table(rows: &[OffsetRow]) -> Table {
    let mut t = Table::new([
        ("T", Right),
        ("view", Left),
        ("strategy", Left),
        ("test", Left),
        ("rays", Right),
        ("false self-hits", Right),
        ("missed occluder at 1e-3", Right),
        ("at 5e-5", Right),
        ("at 1e-5", Right),
    ]);
    for r in rows {
        t.row([
            format!("{:.0e}", r.translation),
            r.view.to_string(),
            r.strategy.name().to_string(),
            r.intersector.name().to_string(),
            r.rays.to_string(),
            format!("{:.4}", r.self_hit_rate),
            format!("{:.4}", r.missed_at_1e3),
            format!("{:.4}", r.missed_at_5e5),
            format!("{:.4}", r.missed_at_1e5),
        ]);
    }
    t
}
