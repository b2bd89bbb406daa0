//! The degenerate suite: zero-area, sliver, huge-and-tiny, coplanar and
//! identical triangles, and random, parallel, axis-aligned and NaN rays,
//! through every backend, judged against naive and the exact reference.

use glam::Vec3;
use serde::Serialize;

use super::backends::built_or_not;
use crate::accel::naive::Naive;
use crate::accel::{Backend, BackendSpec};
use crate::error::Result;
use crate::geometry::{Aabb, Intersector, Ray};
use crate::measure::exact::{judge_answers, ExactReference};
use crate::measure::validate::{classify, Agreement};
use crate::rng::Rng;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// One degenerate case against one backend.
#[derive(Clone, Debug, Serialize)]
pub struct DegenerateRow {
    pub case: String,
    pub triangles: usize,
    pub backend: String,
    pub rays: usize,
    /// Hits with a non-finite t, u or v.
    pub nan_results: usize,
    /// Genuine disagreements with naive (same triangle test; Embree and
    /// the other libraries against MT).
    pub genuine_vs_naive: usize,
    /// Closest-hit and any-hit answers the exact reference judges wrong,
    /// and those it cannot decide in double precision.
    pub exact_wrong: usize,
    pub undecidable: usize,
    /// Another library's (tinybvh, obvhs, the bvh crate), not raylab's or
    /// Embree's: its NaN results do not fail `stress`.
    pub library: bool,
    /// Why the backend could not be built on this case (nothing measured).
    pub not_built: Option<String>,
}

/// One degenerate input: a name, vertex positions and index triples.
pub struct DegenerateCase {
    pub name: &'static str,
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// The degenerate inputs.
pub fn degenerate_cases() -> Vec<DegenerateCase> {
    let mut rng = Rng::for_pixel(0, 9, 0xDE6);
    let mut r = || rng.next_f32() * 2.0 - 1.0;
    let mut cases = Vec::new();
    let one = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
    cases.push((
        "zero-area",
        vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        vec![[0, 1, 2]; 50],
    ));
    cases.push((
        "collinear",
        (0..30)
            .map(|i| Vec3::new(i as f32 * 0.1, i as f32 * 0.05, 0.0))
            .collect(),
        (0..28).map(|i| [i, i + 1, i + 2]).collect(),
    ));
    cases.push((
        "repeated vertices",
        one.clone(),
        vec![[0, 0, 1], [1, 1, 1], [0, 1, 2], [2, 2, 0]],
    ));
    let slivers: Vec<Vec3> = (0..200)
        .flat_map(|i| {
            let x = i as f32 * 0.01;
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 5.0, 1e-6, 0.0),
                Vec3::new(x + 10.0, 0.0, 1e-7),
            ]
        })
        .collect();
    cases.push((
        "slivers",
        slivers,
        (0..200).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    ));
    cases.push((
        "huge and tiny",
        vec![
            Vec3::splat(-1e6),
            Vec3::new(1e6, -1e6, 0.0),
            Vec3::new(0.0, 1e6, 0.0),
            Vec3::ZERO,
            Vec3::X * 1e-6,
            Vec3::Y * 1e-6,
            Vec3::Z,
            Vec3::X,
            Vec3::Y,
        ],
        vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]],
    ));
    let plane: Vec<Vec3> = (0..900).map(|_| Vec3::new(r(), r(), 0.25)).collect();
    cases.push((
        "one plane",
        plane,
        (0..300).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    ));
    cases.push(("identical", one, vec![[0, 1, 2]; 2000]));
    cases
        .into_iter()
        .map(|(name, positions, triangles)| DegenerateCase {
            name,
            positions,
            triangles,
        })
        .collect()
}

/// The degenerate suite: every backend on every case with random rays,
/// rays parallel to the triangles' plane, axis-aligned rays and NaN/inf
/// rays, judged against naive and against the exact reference. A library
/// that refuses a case (tinybvh's BVH8_CPU conversion on `identical`, which
/// once crashed the process) gets a "not built" row.
pub fn degenerate_suite(rays_per_case: usize, specs: &[BackendSpec]) -> Result<Vec<DegenerateRow>> {
    let mut rows = Vec::new();
    for DegenerateCase {
        name,
        positions,
        triangles,
    } in degenerate_cases()
    {
        let tris: Vec<[Vec3; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| positions[i as usize]))
            .collect();
        let bounds = Aabb::from_points(&positions);
        let mut rays = crate::measure::validate::random_rays(bounds, rays_per_case, 3);
        let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
        let mut rng = Rng::for_pixel(1, 2, 3);
        for i in 0..rays_per_case / 2 {
            let o = bounds.min
                + bounds.extent() * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let d = if i % 2 == 0 {
                axes[i / 2 % 6]
            } else {
                // In the plane of a triangle: parallel to it.
                let t = &tris[i % tris.len()];
                (t[1] - t[0]).normalize_or(Vec3::X)
            };
            rays.push(Ray::new(o, d));
        }
        rays.extend([
            Ray::new(Vec3::NAN, Vec3::X),
            Ray::new(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 0.0)),
            Ray::new(Vec3::splat(f32::INFINITY), Vec3::X),
            Ray::new(Vec3::ZERO, Vec3::ZERO),
            Ray::segment(Vec3::ZERO, Vec3::X, 0.0, f32::NAN),
            Ray::segment(Vec3::ZERO, Vec3::X, f32::INFINITY, f32::INFINITY),
        ]);
        let naive_mt = Naive::from_triangles(tris.clone());
        let naive_wt =
            Naive::from_triangles(tris.clone()).with_intersector(Intersector::Watertight);
        let reference = ExactReference::new(tris.clone());
        let answers = reference.answers(&rays);
        for (spec, built, intersector) in built_or_not(&positions, &triangles, specs) {
            let backend = match built {
                Ok(b) => b,
                Err(e) => {
                    rows.push(DegenerateRow {
                        case: name.to_string(),
                        triangles: tris.len(),
                        backend: spec.name(),
                        rays: 0,
                        nan_results: 0,
                        genuine_vs_naive: 0,
                        exact_wrong: 0,
                        undecidable: 0,
                        library: spec.is_library(),
                        not_built: Some(e.to_string()),
                    });
                    continue;
                }
            };
            let reference: &dyn Backend = if intersector == "watertight" {
                &naive_wt
            } else {
                &naive_mt
            };
            let mut nan = 0;
            let mut genuine = 0;
            for ray in &rays {
                let h = backend.intersect(ray);
                if h.is_some_and(|h| !(h.t.is_finite() && h.u.is_finite() && h.v.is_finite())) {
                    nan += 1;
                }
                let agreement = classify(ray, h, reference.intersect(ray), &tris);
                genuine += (agreement == Agreement::Genuine) as usize;
            }
            let judged = judge_answers(name, &rays, &answers, backend.as_ref());
            rows.push(DegenerateRow {
                case: name.to_string(),
                triangles: tris.len(),
                backend: backend.name(),
                rays: rays.len(),
                nan_results: nan,
                genuine_vs_naive: genuine,
                exact_wrong: judged.wrong(),
                undecidable: judged.undecidable_answers(),
                library: spec.is_library(),
                not_built: None,
            });
        }
    }
    Ok(rows)
}

/// The degenerate rows as a table.
pub fn degenerate_table(rows: &[DegenerateRow]) -> Table {
    let mut t = Table::new([
        ("case", Left),
        ("triangles", Right),
        ("backend", Left),
        ("rays", Right),
        ("NaN results", Right),
        ("genuine vs naive", Right),
        ("wrong vs exact", Right),
        ("undecidable", Right),
    ]);
    for r in rows {
        if let Some(why) = &r.not_built {
            t.row([
                r.case.to_string(),
                r.triangles.to_string(),
                r.backend.clone(),
                "-".into(),
                "-".into(),
                "-".into(),
                "-".into(),
                format!("not built: {why}"),
            ]);
            continue;
        }
        t.row([
            r.case.to_string(),
            r.triangles.to_string(),
            r.backend.clone(),
            r.rays.to_string(),
            r.nan_results.to_string(),
            r.genuine_vs_naive.to_string(),
            r.exact_wrong.to_string(),
            r.undecidable.to_string(),
        ]);
    }
    t
}
