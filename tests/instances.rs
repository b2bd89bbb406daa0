//! Instanced scenes: raylab's two-level tree and Embree's instances answer
//! as the naive scan over the flattened list does (the same triangle as
//! placed, up to the transform's rounding, on random rays and rays aimed at
//! the instances' vertices), a render and its `--flatten` copy frame the
//! same view, `forest:N` past what flattening holds renders, and the flags
//! of instanced scenes fail in one line.

mod common;

use common::{assert_one_line_error, assert_success, raylab, temp_dir, TestRng};
use glam::{Affine3A, Quat, Vec3};
use raylab::accel::naive::Naive;
use raylab::accel::{build_scene_backend, Backend, BackendSpec, Query};
use raylab::geometry::Ray;
use raylab::measure::validate::{classify, Agreement};
use raylab::scene::builtin::builtin;
use raylab::scene::Scene;

/// Four meshes placed 40 times, turned, scaled (one mirrored) and overlapping.
fn scene() -> Scene {
    let meshes = [
        "mesh:500",
        "cornell-sphere",
        "cornell-original",
        "grass:200",
    ]
    .map(|n| builtin(n).unwrap())
    .to_vec();
    let mut rng = TestRng(11);
    let placements = (0..40)
        .map(|i| {
            let scale =
                Vec3::new(1.0, if i == 7 { -1.0 } else { 1.0 }, 1.0) * (0.4 + rng.next_f32());
            let m = Affine3A::from_scale_rotation_translation(
                scale,
                Quat::from_rotation_y(6.0 * rng.next_f32())
                    * Quat::from_rotation_z(0.5 * rng.next_f32()),
                rng.vec_in(Vec3::new(-4.0, 0.0, -4.0), Vec3::new(4.0, 2.0, 4.0)),
            );
            (i % 4, m)
        })
        .collect();
    Scene::instanced("test", meshes, placements).unwrap()
}

/// Random rays through the scene's box, and rays aimed at placed vertices.
fn rays(scene: &Scene, flat: &Scene, n: usize) -> Vec<Ray> {
    let b = scene.bounds();
    let mut rng = TestRng(5);
    let mut out = Vec::new();
    for i in 0..n {
        let o = rng.vec_in(b.min - 2.0, b.max + 2.0);
        let to = if i % 2 == 0 {
            rng.vec_in(b.min, b.max)
        } else {
            let t =
                (rng.next_f32() * flat.triangle_count() as f32) as usize % flat.triangle_count();
            flat.triangle(t)[i % 3]
        };
        out.push(Ray::new(o, to - o));
    }
    out
}

/// The instanced fixture, its flattened triangles, the naive scan over them
/// and 6000 rays (aimed at vertices, edges and at random).
fn fixture() -> (Scene, Vec<[Vec3; 3]>, Naive, Vec<Ray>) {
    let s = scene();
    let flat = s.flattened().unwrap();
    let triangles = flat.triangle_vertices();
    let naive = Naive::from_triangles(triangles.clone());
    let rays = rays(&s, &flat, 6000);
    (s, triangles, naive, rays)
}

/// Whether an instanced structure's `got` (in instance numbering)
/// genuinely disagrees with the naive scan's `want` on the flattened list:
/// the same triangle at a `t` off by rounding is no disagreement.
fn genuine(
    s: &Scene,
    triangles: &[[Vec3; 3]],
    ray: &Ray,
    want: Option<raylab::geometry::Hit>,
    got: Option<raylab::geometry::Hit>,
) -> bool {
    let got = got.map(|h| raylab::geometry::Hit {
        tri: s.flat_index(&h) as u32,
        inst: 0,
        ..h
    });
    let same = matches!((want, got), (Some(w), Some(g)) if w.tri == g.tri && (w.t - g.t).abs() <= 1e-4 * w.t);
    classify(ray, want, got, triangles) == Agreement::Genuine && !same
}

#[test]
fn two_level_structures_answer_as_the_flattened_naive_scan() {
    let (s, triangles, naive, rays) = fixture();
    let mut specs = vec![
        BackendSpec::DEFAULT,
        BackendSpec::bvh(raylab::accel::bvh::BuildParams::sah()),
    ];
    if raylab::accel::embree::AVAILABLE {
        specs.push(BackendSpec::embree(1));
    }
    for spec in specs {
        let built = build_scene_backend(&spec.with_query(Query::Single).unwrap(), &s).unwrap();
        let (mut genuine, mut any_hit) = (0, 0);
        for ray in &rays {
            let want = naive.intersect(ray);
            genuine += self::genuine(&s, &triangles, ray, want, built.intersect(ray)) as usize;
            any_hit += (built.occluded(ray) != want.is_some()) as usize;
        }
        // Rays aimed at vertices touch edges; the transform's rounding moves
        // them by an ulp, so a handful may go either way.
        assert!(
            genuine <= 6,
            "{}: {genuine} genuine of {}",
            built.name(),
            rays.len()
        );
        assert!(
            any_hit <= 6,
            "{}: {any_hit} any-hit answers differ",
            built.name()
        );
    }
}

#[test]
fn render_traces_instances_and_their_flattened_copy_alike() {
    let dir = temp_dir("instances-render");
    let a = dir.join("a.png");
    let b = dir.join("b.png");
    let run = |extra: &[&str], out: &std::path::Path| {
        let mut args = vec![
            "render",
            "forest:30",
            "--size",
            "96x72",
            "-q",
            "--json",
            "-o",
        ];
        args.push(out.to_str().unwrap());
        args.extend_from_slice(extra);
        let r = raylab(&args);
        assert_success(&r);
        String::from_utf8_lossy(&r.stdout).to_string()
    };
    let two = run(&[], &a);
    let flat = run(&["--flatten"], &b);
    assert!(two.contains("\"instances\":31"), "{two}");
    assert!(flat.contains("\"instances\":1"), "{flat}");
    let field = |j: &str, k: &str| {
        j.split(&format!("\"{k}\":"))
            .nth(1)
            .unwrap()
            .split([',', '}'])
            .next()
            .unwrap()
            .to_string()
    };
    // The same placed triangles, and the same view: the images differ at
    // a few pixels at most (the transform's rounding).
    assert_eq!(field(&two, "triangles"), field(&flat, "triangles"));
    assert_eq!(field(&two, "primary_hits"), field(&flat, "primary_hits"));
    let (ia, ib) = (
        image::open(&a).unwrap().to_rgb8(),
        image::open(&b).unwrap().to_rgb8(),
    );
    let differ = ia.pixels().zip(ib.pixels()).filter(|(p, q)| p != q).count();
    assert!(differ * 100 < ia.pixels().count(), "{differ} pixels differ");
}

#[test]
fn forests_past_what_flattening_holds_render_and_say_their_memory() {
    let dir = temp_dir("instances-forest");
    let out = dir.join("f.png");
    let r = raylab(&[
        "render",
        "forest:200000",
        "--size",
        "64x48",
        "-q",
        "--json",
        "-o",
        out.to_str().unwrap(),
        "--max-triangles",
        "100000000",
    ]);
    assert_success(&r);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(text.contains("\"instances\":200001"), "{text}");
    assert!(text.contains("\"peak_memory_bytes\":"), "{text}");
    // 2 x 10^9 placed triangles: flattening them is refused in one line.
    assert_one_line_error(
        &["render", "forest:200000", "--flatten", "--size", "64x48"],
        "--max-triangles",
    );
}

#[test]
fn instanced_flags_get_one_line_errors() {
    assert_one_line_error(&["render", "cornell-original", "--flatten"], "--flatten");
    // -q: the scene's summary and warnings come before the backend's error.
    assert_one_line_error(
        &["render", "forest:10", "-q", "--backend", "naive"],
        "--backend",
    );
    assert_one_line_error(
        &["render", "forest:10", "-q", "--query", "stream"],
        "--query",
    );
    assert_one_line_error(
        &[
            "render",
            "forest:10",
            "-q",
            "--backend",
            "embree",
            "--query",
            "stream",
        ],
        "--query",
    );
    assert_one_line_error(
        &["render", "explode:2000", "--time", "1", "--flatten"],
        "--flatten",
    );
    assert_one_line_error(
        &["validate", "cornell-original", "--instances", "-q"],
        "--instances",
    );
}

#[test]
fn validate_judges_the_two_level_tree_on_its_flattened_numbers() {
    let r = raylab(&[
        "validate",
        "forest:20",
        "--instances",
        "--against",
        "exact",
        "--count",
        "3000",
        "--size",
        "64x48",
        "-q",
        "--json",
    ]);
    assert_success(&r);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(text.contains("\"wrong\": 0,"), "{text}");
    assert!(text.contains("\"pass\": true"), "{text}");
}

#[test]
fn packets_through_instances_answer_as_single_rays() {
    let (s, triangles, naive, rays) = fixture();
    let mut specs = vec![BackendSpec::DEFAULT];
    if raylab::accel::embree::AVAILABLE {
        specs.push(BackendSpec::embree(1));
    }
    for spec in specs {
        let single = build_scene_backend(&spec.with_query(Query::Single).unwrap(), &s).unwrap();
        let paths = [4, 8, 16]
            .into_iter()
            .flat_map(|n| [Query::Packet(n), Query::IncoherentPacket(n)]);
        for q in paths {
            let Ok(packets) = spec.with_query(q) else {
                continue;
            };
            let Ok(packets) = build_scene_backend(&packets, &s) else {
                continue;
            };
            let mut hits = vec![None; rays.len()];
            let mut occluded = vec![false; rays.len()];
            packets.intersect_stream(&rays, &mut hits);
            packets.occluded_stream(&rays, &mut occluded);
            let is_raylab = spec.kind() != raylab::accel::BackendKind::Embree;
            let mut genuine = 0;
            for (k, ray) in rays.iter().enumerate() {
                if is_raylab {
                    // raylab's packets are its single rays, bit for bit.
                    assert_eq!(hits[k], single.intersect(ray), "{} ray {k}", packets.name());
                    assert_eq!(
                        occluded[k],
                        single.occluded(ray),
                        "{} ray {k}",
                        packets.name()
                    );
                    continue;
                }
                // Embree's packets round as they do: judged as its single rays are.
                let want = naive.intersect(ray);
                genuine += self::genuine(&s, &triangles, ray, want, hits[k]) as usize;
                genuine += (occluded[k] != want.is_some()) as usize;
            }
            assert!(genuine <= 12, "{}: {genuine} genuine", packets.name());
        }
    }
}
