//! The other libraries' backends (tinybvh, obvhs, the bvh crate) as raylab
//! wraps them: on rays where none of their documented gaps applies (a front
//! face hit well inside a triangle, far from the origin, tmin 0 or a tmin
//! well before the hit), each must return the naive scan's triangle, t and
//! barycentrics, and the same occlusion. This checks the wrapping (index
//! maps, units of t, barycentric conventions, tmin and tmax), not the
//! libraries: their defects are what `validate` and `stress` report.

#![cfg(all(feature = "tinybvh", feature = "obvhs", feature = "bvh-crate"))]

mod common;

use common::{assert_one_line_error, assert_success, raylab, temp_dir, TestRng};
use glam::Vec3;
use raylab::accel::embree::Quality;
use raylab::accel::library::{Library, ObvhsLayout};
use raylab::accel::{build_backend, Backend, BackendSpec};
use raylab::geometry::{Hit, Ray};
use raylab::scene::builtin::builtin;

/// Every layout raylab wraps, and obvhs's other presets.
fn libraries() -> Vec<Library> {
    let mut all = Library::ALL.to_vec();
    all.extend([
        Library::Obvhs {
            layout: ObvhsLayout::Bvh2,
            quality: Quality::High,
        },
        Library::Obvhs {
            layout: ObvhsLayout::CwBvh,
            quality: Quality::Low,
        },
    ]);
    all
}

/// Rays from random points at random triangles' interior points (barycentrics
/// at least 0.1 from every edge), kept where the naive scan's closest hit is
/// a front face, well inside its triangle and at least 1e-3 of the scene away.
fn clear_rays(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<(Ray, Hit)> {
    let naive = raylab::accel::naive::Naive::from_triangles(tris.to_vec());
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for t in tris {
        for v in t {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
    }
    let size = (hi - lo).length();
    let mut rng = TestRng(seed);
    let mut out = Vec::new();
    while out.len() < n {
        let tri = &tris[(rng.next_f32() * tris.len() as f32) as usize % tris.len()];
        let (a, b) = (rng.range(0.1, 0.8), rng.range(0.1, 0.8));
        let (a, b) = if a + b > 0.9 {
            (0.9 - b, 0.9 - a)
        } else {
            (a, b)
        };
        let target = tri[0] + (tri[1] - tri[0]) * a + (tri[2] - tri[0]) * b;
        let origin = rng.vec_in(lo - (hi - lo) * 0.5, hi + (hi - lo) * 0.5);
        let ray = Ray::new(origin, target - origin);
        let Some(hit) = naive.intersect(&ray) else {
            continue;
        };
        let [v0, v1, v2] = tris[hit.tri as usize];
        let front = (v1 - v0).cross(v2 - v0).dot(ray.dir) < 0.0;
        let inside = hit.u > 0.05 && hit.v > 0.05 && hit.u + hit.v < 0.95;
        if front && inside && hit.t * ray.dir.length() > 1e-3 * size {
            out.push((ray, hit));
        }
    }
    out
}

fn check(scene: &str, seed: u64) {
    let scene = builtin(scene).unwrap();
    let tris = scene.triangle_vertices();
    let rays = clear_rays(&tris, 3000, seed);
    for library in libraries() {
        let built = build_backend(&BackendSpec::library(library, 2), &scene).unwrap();
        let name = built.name();
        let mut wrong = Vec::new();
        for (ray, want) in &rays {
            let got = built.intersect(ray);
            let close = |a: f32, b: f32, tol: f32| (a - b).abs() <= tol * b.abs().max(1.0);
            let same = got.is_some_and(|g| {
                g.tri == want.tri
                    && close(g.t, want.t, 1e-4)
                    && close(g.u, want.u, 1e-3)
                    && close(g.v, want.v, 1e-3)
            });
            // Occlusion: the segment stopping halfway is clear only where
            // nothing else lies in front (the naive scan says); one past the
            // hit is blocked; tmin past the first hit finds what lies behind.
            let half = Ray::segment(ray.origin, ray.dir, 0.0, want.t * 0.5);
            let past = Ray::segment(ray.origin, ray.dir, 0.0, want.t * 1.5);
            let behind = Ray::segment(ray.origin, ray.dir, want.t * 1.01, f32::INFINITY);
            let naive_behind = raylab::accel::naive::Naive::from_triangles(tris.clone())
                .intersect(&behind)
                .map(|h| h.tri);
            let behind_ok = match naive_behind {
                // Only judged where what lies behind is itself a clear hit.
                Some(tri) => {
                    let [v0, v1, v2] = tris[tri as usize];
                    let front = (v1 - v0).cross(v2 - v0).dot(ray.dir) < 0.0;
                    !front || built.intersect(&behind).map(|h| h.tri) == Some(tri)
                }
                None => built.intersect(&behind).is_none(),
            };
            if !same || built.occluded(&half) || !built.occluded(&past) || !behind_ok {
                wrong.push((ray, want, got));
            }
        }
        // A handful of rays may graze another triangle's edge in front of
        // the target or behind it; a wrapping error shows on most rays.
        assert!(
            wrong.len() * 200 <= rays.len(),
            "{name}: {} of {} clear rays answered differently, e.g. {:?}",
            wrong.len(),
            rays.len(),
            &wrong[..wrong.len().min(3)]
        );
    }
}

#[test]
fn libraries_answer_clear_rays_as_the_naive_scan_does_in_a_box() {
    check("cornell-sphere", 11);
}

#[test]
fn libraries_answer_clear_rays_as_the_naive_scan_does_in_a_mesh() {
    check("mesh:3000", 12);
}

#[test]
fn libraries_return_nothing_for_invalid_rays_and_empty_scenes() {
    let scene = builtin("cornell-empty").unwrap();
    let bad = [
        Ray::new(Vec3::new(0.0, 1.0, 3.0), Vec3::ZERO),
        Ray::new(Vec3::new(f32::NAN, 1.0, 3.0), Vec3::new(0.0, 0.0, -1.0)),
        Ray::segment(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 0.0, -1.0),
            2.0,
            1.0,
        ),
    ];
    let empty = raylab::scene::MeshRef {
        positions: &[],
        triangles: &[],
    };
    for library in libraries() {
        let built = build_backend(&BackendSpec::library(library, 1), &scene).unwrap();
        for ray in &bad {
            assert!(built.intersect(ray).is_none(), "{}: {ray:?}", built.name());
            assert!(!built.occluded(ray), "{}: {ray:?}", built.name());
        }
        let none = build_backend(&BackendSpec::library(library, 1), empty).unwrap();
        let ray = Ray::new(Vec3::ZERO, Vec3::X);
        assert!(none.intersect(&ray).is_none() && !none.occluded(&ray));
    }
}

#[test]
fn library_flags_a_library_has_no_use_for_are_refused() {
    let d = temp_dir("library-flags");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    let r = |extra: &[&str], needle: &str| {
        let mut args = vec!["render", "cornell-empty", "--size", "8x6", "-o", o];
        args.extend(extra);
        assert_one_line_error(&args, needle);
    };
    r(&["--backend", "tinybvh", "--layout", "cwbvh"], "--layout");
    r(&["--backend", "obvhs", "--layout", "bvh8"], "--layout");
    r(&["--backend", "bvh-crate", "--layout", "bvh2"], "--layout");
    r(&["--backend", "bvh", "--layout", "bvh8"], "--layout");
    r(&["--backend", "tinybvh", "--quality", "low"], "--quality");
    r(
        &["--backend", "bvh-crate", "--quality", "high"],
        "--quality",
    );
    r(
        &["--backend", "tinybvh", "--build-threads", "2"],
        "--build-threads",
    );
    r(
        &["--backend", "obvhs", "--intersector", "watertight"],
        "--intersector",
    );
    r(&["--backend", "obvhs", "--builder", "sah"], "--builder");
    r(&["--backend", "tinybvh", "--query", "packet8"], "--query");
    assert!(!std::path::Path::new(o).exists());
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn library_renders_are_the_same_on_any_thread_count_and_name_the_layout() {
    let d = temp_dir("library-render");
    for (extra, name) in [
        (
            &["--backend", "tinybvh", "--quality", "high"][..],
            "tinybvh-bvh8-hq",
        ),
        (
            &["--backend", "obvhs", "--layout", "bvh2"][..],
            "obvhs-bvh2-medium",
        ),
        (&["--backend", "bvh-crate"][..], "bvh-crate"),
    ] {
        let mut images = Vec::new();
        for threads in ["1", "2"] {
            let png = d.join(format!("{name}-{threads}.png"));
            let mut args = vec![
                "render",
                "cornell-sphere",
                "--size",
                "48x36",
                "--threads",
                threads,
                "--json",
                "-q",
                "-o",
                png.to_str().unwrap(),
            ];
            args.extend(extra);
            let out = raylab(&args);
            assert_success(&out);
            let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            assert_eq!(report["backend"], name);
            images.push(std::fs::read(&png).unwrap());
        }
        assert!(
            images[0] == images[1],
            "{name}: images differ by thread count"
        );
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_tree_tinybvh_cannot_convert_is_refused_not_a_crash() {
    // 2000 copies of one triangle: tinybvh splits the leaf into a 500-deep
    // chain, and its BVH8_CPU conversion used to crash the process on it.
    let d = temp_dir("library-identical");
    let obj = d.join("identical.obj");
    let mut text = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    text.push_str(&"f 1 2 3\n".repeat(2000));
    std::fs::write(&obj, text).unwrap();
    let png = d.join("x.png");
    let (obj, png) = (obj.to_str().unwrap(), png.to_str().unwrap());
    let args = ["render", obj, "--size", "16x12", "-q", "-o", png];
    assert_one_line_error(
        &[&args[..], &["--backend", "tinybvh"]].concat(),
        "--layout bvh",
    );
    assert_success(&raylab(
        &[&args[..], &["--backend", "tinybvh", "--layout", "bvh"]].concat(),
    ));
    std::fs::remove_dir_all(&d).ok();
}
