//! The BVH backends against the naive reference: the same hits bit for bit (same
//! triangle, same t, ties broken alike) on random, axis-aligned and adversarial
//! rays; tree invariants; degenerate input; determinism across thread counts; and
//! bit-identical renders.

mod common;

use common::{binary, settings, TestRng};
use glam::Vec3;
use raylab::accel::bvh::simd::Kernel;
use raylab::accel::bvh::{build, BuildParams, BuilderKind, Bvh, BvhBackend, Traversal, Tree};
use raylab::accel::naive::Naive;
use raylab::accel::Backend;
use raylab::geometry::{Aabb, Intersector, Ray};
use raylab::measure::validate::{classify, Agreement};
use raylab::progress::Progress;
use raylab::render::{render, AoMode, Schedule};
use raylab::scene::builtin::{builtin, BUILTIN_SCENES};

const BUILDERS: [BuildParams; 6] = [
    BuildParams::median(),
    BuildParams::sah(),
    BuildParams::for_builder(BuilderKind::Lbvh),
    // Spatial splits: triangles in several leaves, each with a clipped box.
    BuildParams::for_builder(BuilderKind::Sbvh),
    // Reinsertion moves subtrees: the high rung.
    BuildParams::for_quality(raylab::accel::bvh::params::Quality::High),
    // A multi-triangle-leaf median tree exercises leaf loops with ties inside a leaf.
    BuildParams::median().with_max_leaf_size(3),
];

/// The wide trees checked beside the binary one: the same splits 4 and 8
/// wide (each node kernel), and the tree built for 8-wide traversal (leaf
/// costs in blocks of two).
fn wide_trees(tris: &[[Vec3; 3]], params: &BuildParams) -> Vec<(String, Tree)> {
    let same_splits = |width| {
        let p = params.with_width(width).with_sah_block(params.sah_block);
        build(tris, &p).unwrap()
    };
    let mut out = vec![
        ("4-wide".to_string(), same_splits(4)),
        (
            "8-wide portable".to_string(),
            same_splits(8).with_kernel(Kernel::Portable),
        ),
    ];
    if let Kernel::Avx2(_) = Kernel::detect() {
        out.push((
            "8-wide avx2".to_string(),
            same_splits(8).with_kernel(Kernel::detect()),
        ));
    }
    if params.builder != BuilderKind::Median {
        out.push((
            "8-wide built for blocks".to_string(),
            build(tris, &params.with_width(8)).unwrap(),
        ));
    }
    out
}

/// Random rays: origins in and around `bounds` (50% margin), uniform directions,
/// with some axis-aligned directions (zero components) mixed in.
fn random_rays(bounds: Aabb, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = TestRng(seed);
    let margin = bounds.extent() * 0.5 + Vec3::splat(1e-3);
    let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    (0..n)
        .map(|i| {
            let o = rng.vec_in(bounds.min - margin, bounds.max + margin);
            let d = if i % 10 == 0 {
                axes[i / 10 % 6]
            } else {
                rng.unit()
            };
            Ray::new(o, d)
        })
        .collect()
}

/// Rays aimed exactly at vertices and edge midpoints: the shared-edge ties.
fn adversarial_rays(tris: &[[Vec3; 3]], bounds: Aabb, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = TestRng(seed);
    let margin = bounds.extent() * 0.5 + Vec3::splat(1e-3);
    (0..n)
        .map(|i| {
            let t = &tris[(rng.next_f32() * tris.len() as f32) as usize % tris.len()];
            let target = match i % 3 {
                0 => t[i % 3],
                1 => (t[0] + t[1]) * 0.5,
                _ => (t[1] + t[2]) * 0.5,
            };
            let o = rng.vec_in(bounds.min - margin, bounds.max + margin);
            Ray::new(o, (target - o).normalize_or(Vec3::X))
        })
        .collect()
}

/// Closest hits of every builder's binary and 4-wide trees must agree with naive
/// exactly, except that `allow_ties` accepts a different
/// triangle sharing a vertex at the same t (within 1e-5 relative): for rays aimed
/// exactly at shared vertices, MT's rounding, not geometry, picks the winner.
/// Returns the number of ties seen.
fn assert_same_hits(
    name: &str,
    tris: &[[Vec3; 3]],
    rays: &[Ray],
    seed: u64,
    allow_ties: bool,
) -> usize {
    let mut ties = 0;
    let naive = Naive::from_triangles(tris.to_vec());
    let mut rng = TestRng(seed);
    let diag = Aabb::from_points(&tris.iter().flatten().copied().collect::<Vec<_>>())
        .extent()
        .length();
    for params in BUILDERS {
        let bvh = binary(tris, &params);
        let wide = wide_trees(tris, &params);
        for (i, ray) in rays.iter().enumerate() {
            let want = naive.intersect(ray);
            let got = bvh.intersect(ray);
            if got != want {
                let agreement = classify(ray, got, want, tris);
                assert!(
                    allow_ties && agreement == Agreement::Tie,
                    "{name} {params:?}: ray {i} {ray:?}: bvh {got:?} naive {want:?} ({agreement:?})"
                );
                ties += 1;
            }
            // The wide trees under the same rule. They may break a vertex tie
            // differently from the binary tree: they visit boxes in another order,
            // and MT's t at a vertex can lie beyond the slab test's slack, so which
            // of two triangles meeting there is found first decides.
            for (label, tree) in &wide {
                let got_wide = tree.intersect_using(ray, Intersector::Mt);
                if got_wide != want {
                    let agreement = classify(ray, got_wide, want, tris);
                    assert!(
                        allow_ties && agreement == Agreement::Tie,
                        "{name} {params:?}: {label} ray {i} {ray:?}: {got_wide:?} naive {want:?} ({agreement:?})"
                    );
                    ties += 1;
                }
            }
            let segment = Ray::segment(ray.origin, ray.dir, 0.0, rng.range(0.0, 2.0 * diag));
            let occluded = naive.occluded(&segment);
            assert_eq!(
                bvh.occluded(&segment),
                occluded,
                "{name} {params:?}: occlusion ray {i} {segment:?}"
            );
            for (label, tree) in &wide {
                assert_eq!(
                    tree.occluded_using(&segment, Intersector::Mt),
                    occluded,
                    "{name} {params:?}: {label} occlusion ray {i} {segment:?}"
                );
            }
        }
    }
    ties
}

#[test]
fn bvh_hits_match_naive_on_random_rays_in_builtin_scenes() {
    for (k, (name, _)) in BUILTIN_SCENES.iter().enumerate() {
        let scene = builtin(name).unwrap();
        let tris = scene.triangle_vertices();
        let rays = random_rays(scene.bounds(), 100_000, 17 + k as u64);
        assert_same_hits(name, &tris, &rays, 99, false);
    }
}

#[test]
fn bvh_hits_match_naive_on_rays_aimed_at_vertices_and_edges() {
    for (k, (name, _)) in BUILTIN_SCENES.iter().enumerate() {
        let scene = builtin(name).unwrap();
        let tris = scene.triangle_vertices();
        let rays = adversarial_rays(&tris, scene.bounds(), 20_000, 5 + k as u64);
        let ties = assert_same_hits(name, &tris, &rays, 3, true);
        // Ties are rare events at exact vertices, not a licence for sloppiness.
        assert!(
            ties * 1000 < rays.len() * BUILDERS.len() * 2,
            "{name}: {ties} ties"
        );
    }
}

fn soup(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = TestRng(seed);
    (0..n)
        .map(|_| {
            let c = rng.vec_in(Vec3::splat(-1.0), Vec3::splat(1.0));
            let size = 0.3 * rng.next_f32().powi(2) + 1e-3;
            [
                c + rng.unit() * size,
                c + rng.unit() * size,
                c + rng.unit() * size,
            ]
        })
        .collect()
}

#[test]
fn bvh_hits_match_naive_on_random_triangle_soups() {
    for (n, rays) in [
        (1, 2000),
        (2, 2000),
        (3, 2000),
        (10, 5000),
        (100, 20_000),
        (1000, 20_000),
        (10_000, 5000),
    ] {
        let tris = soup(n, n as u64);
        let bounds = Aabb::from_points(&tris.iter().flatten().copied().collect::<Vec<_>>());
        let mut all = random_rays(bounds, rays, 7 * n as u64);
        all.extend(adversarial_rays(&tris, bounds, rays / 4, n as u64));
        // Soup triangles share no vertices, so there is no tie to excuse.
        assert_same_hits(&format!("soup of {n}"), &tris, &all, 11, false);
    }
}

/// Triangles 0.03-0.1 across scattered over a 4-unit cube about `centre`,
/// each with an edge in a plane z = const (its first two vertices share their
/// z), the third vertex above or below: a leaf box's top or bottom face lies
/// in that plane, as on meshes far from the origin, where coordinates are
/// coarse and vertices share them.
fn edge_in_plane_triangles(n: usize, centre: Vec3, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = TestRng(seed);
    (0..n)
        .map(|_| {
            let c = centre + rng.vec_in(Vec3::splat(-2.0), Vec3::splat(2.0));
            let size = rng.range(0.03, 0.1);
            let up = if rng.next_f32() < 0.5 { size } else { -size };
            let mut v = |dz: f32| c + Vec3::new(rng.range(-size, size), rng.range(-size, size), dz);
            let (a, b, apex) = (v(0.0), v(0.0), v(up));
            [a, Vec3::new(b.x, b.y, a.z), apex]
        })
        .collect()
}

/// Rays along +-x and +-y (either sign of zero in the other components)
/// lying in the plane of a triangle's in-plane edge and crossing it: their
/// origin lies exactly in a leaf box's face plane. Measured from the origin,
/// that face's slab distance is `0 * RECIPROCAL_MAX = 0`, and the box was
/// culled when it was the exit (17 false misses on far:20000's AO rays).
fn rays_in_edge_planes(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = TestRng(seed);
    let bounds = Aabb::from_points(&tris.iter().flatten().copied().collect::<Vec<_>>());
    (0..n)
        .map(|i| {
            let t = &tris[i % tris.len()];
            let p = t[0] + (t[1] - t[0]) * rng.next_f32();
            // The first half in runs of 16 alike (packets whose rays agree
            // in sign), the second mixed ray by ray.
            let j = if i < n / 2 { i / 16 } else { i };
            let zero = if j / 4 % 2 == 0 { 0.0 } else { -0.0 };
            let (o, d) = match j % 4 {
                0 => (
                    Vec3::new(bounds.min.x - 1.0, p.y, t[0].z),
                    Vec3::new(1.0, zero, zero),
                ),
                1 => (
                    Vec3::new(bounds.max.x + 1.0, p.y, t[0].z),
                    Vec3::new(-1.0, zero, zero),
                ),
                2 => (
                    Vec3::new(p.x, bounds.min.y - 1.0, t[0].z),
                    Vec3::new(zero, 1.0, zero),
                ),
                _ => (
                    Vec3::new(p.x, bounds.max.y + 1.0, t[0].z),
                    Vec3::new(zero, -1.0, zero),
                ),
            };
            Ray::new(o, d)
        })
        .collect()
}

/// Rays lying in a leaf box's face plane get naive's answers from every
/// tree and path: binary, 4- and 8-wide single rays (each node kernel), and
/// 8- and 16-ray packets; near the origin and 1e5 from it.
#[test]
fn rays_in_a_box_face_plane_hit_as_naive_does() {
    use raylab::accel::bvh::BvhBackend;
    use raylab::accel::Query;
    for (k, centre) in [Vec3::ZERO, Vec3::new(1e5, 0.0, 1e5)]
        .into_iter()
        .enumerate()
    {
        let tris = edge_in_plane_triangles(2000, centre, 31 + k as u64);
        let rays = rays_in_edge_planes(&tris, 8000, 41 + k as u64);
        let naive = Naive::from_triangles(tris.clone());
        let hits = rays.iter().filter(|r| naive.intersect(r).is_some()).count();
        // Most cross their edge where Moller-Trumbore's rounding says inside.
        assert!(hits > rays.len() / 4, "{centre}: only {hits} hits");
        assert_same_hits(&format!("edge planes at {centre}"), &tris, &rays, 13, false);
        for width in [8, 16] {
            let packets = BvhBackend::new(&tris, &BuildParams::sah().with_width(8))
                .unwrap()
                .with_query(Query::Packet(width))
                .unwrap();
            let mut got = vec![None; rays.len()];
            packets.intersect_stream(&rays, &mut got);
            let mut occluded = vec![false; rays.len()];
            packets.occluded_stream(&rays, &mut occluded);
            for (i, ray) in rays.iter().enumerate() {
                let want = naive.intersect(ray);
                assert_eq!(got[i], want, "{centre} packet{width} ray {i} {ray:?}");
                assert_eq!(
                    occluded[i],
                    want.is_some(),
                    "{centre} packet{width} ray {i}"
                );
            }
        }
    }
}

/// Checks the layout's invariants. A builder that splits triangles
/// (`splits`) may put one in several leaves, each holding only its part.
fn check_invariants(bvh: &Bvh, tris: &[[Vec3; 3]], max_leaf: usize, splits: bool) {
    let mut seen = vec![0u32; tris.len()];
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let n = &bvh.nodes[i];
        if n.is_leaf() {
            assert!(
                n.count as usize <= max_leaf,
                "leaf of {} > {max_leaf}",
                n.count
            );
            for slot in n.offset as usize..(n.offset + n.count) as usize {
                let id = bvh.tri_ids[slot] as usize;
                seen[id] += 1;
                assert_eq!(bvh.tris[slot], tris[id], "gathered vertices out of order");
                assert!(
                    splits || n.bounds().contains(&Aabb::from_points(&tris[id])),
                    "triangle outside its leaf"
                );
            }
        } else {
            for child in [i + 1, n.offset as usize] {
                assert!(child > i && child < bvh.nodes.len());
                assert!(
                    n.bounds().contains(&bvh.nodes[child].bounds()),
                    "child {child} outside parent {i}"
                );
                stack.push(child);
            }
        }
    }
    assert!(
        seen.iter().all(|&c| c == 1 || (splits && c > 1)),
        "every triangle must be in exactly one leaf (with spatial splits: at least one)"
    );
}

#[test]
fn trees_keep_their_invariants() {
    for tris in [
        soup(1, 1),
        soup(7, 2),
        soup(1000, 3),
        builtin("cornell-water").unwrap().triangle_vertices(),
    ] {
        for params in BUILDERS {
            let splits = params.builder == BuilderKind::Sbvh;
            check_invariants(&binary(&tris, &params), &tris, params.max_leaf_size, splits);
        }
        for leaf in [1, 2, 8] {
            let params = BuildParams::sah().with_max_leaf_size(leaf);
            check_invariants(&binary(&tris, &params), &tris, leaf, false);
        }
    }
}

#[test]
fn median_tree_is_the_studys_shape() {
    let tris = soup(1000, 4);
    let bvh = binary(&tris, &BuildParams::median());
    let s = raylab::accel::bvh::quality::TreeStats::of(&bvh, tris.len());
    // One triangle per leaf, balanced: 2n - 1 nodes, depth ceil(log2 n).
    assert_eq!(s.leaves, 1000);
    assert_eq!(s.nodes, 1999);
    assert_eq!(s.max_leaf_size, 1);
    assert_eq!(s.max_depth, 10);
}

#[test]
fn degenerate_inputs_build_and_trace() {
    let t = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let cases: Vec<(&str, Vec<[Vec3; 3]>)> = vec![
        ("one triangle", vec![t]),
        ("all identical", vec![t; 5000]),
        (
            "all in one plane",
            soup(3000, 9)
                .into_iter()
                .map(|tri| tri.map(|v| Vec3::new(v.x, v.y, 0.5)))
                .collect(),
        ),
        ("zero-area", vec![[Vec3::ZERO, Vec3::X, Vec3::X * 2.0]; 100]),
        ("points", vec![[Vec3::ONE; 3]; 50]),
        (
            "huge and tiny",
            vec![
                [
                    Vec3::splat(-1e6),
                    Vec3::new(1e6, -1e6, 0.0),
                    Vec3::new(0.0, 1e6, 0.0),
                ],
                [Vec3::ZERO, Vec3::X * 1e-6, Vec3::Y * 1e-6],
                t,
            ],
        ),
        ("empty", vec![]),
    ];
    for (name, tris) in cases {
        let bounds = if tris.is_empty() {
            Aabb::from_points(&[Vec3::ZERO, Vec3::ONE])
        } else {
            Aabb::from_points(&tris.iter().flatten().copied().collect::<Vec<_>>())
        };
        let rays = random_rays(bounds, 2000, 1);
        let naive = Naive::from_triangles(tris.clone());
        for params in BUILDERS {
            let bvh = binary(&tris, &params);
            for r in &rays {
                assert_eq!(bvh.intersect(r), naive.intersect(r), "{name} {params:?}");
            }
            let nan = Ray::new(Vec3::NAN, Vec3::X);
            assert!(bvh.intersect(&nan).is_none() && !bvh.occluded(&nan));
        }
    }
}

#[test]
fn tree_is_identical_for_any_thread_count() {
    // 2,500 triangles: built on two threads by the top-down builders (from
    // 1,024), on one by the LBVH (below 4,096).
    for tris in [soup(30_000, 12), soup(2_500, 13)] {
        identical_for_any_thread_count(&tris);
    }
}

fn identical_for_any_thread_count(tris: &[[Vec3; 3]]) {
    for params in [
        BuildParams::median(),
        BuildParams::for_builder(BuilderKind::Lbvh),
        BuildParams::sah(),
        BuildParams::for_builder(BuilderKind::Sbvh),
        BuildParams::sah().with_optimize(true),
    ] {
        let one = binary(tris, &params);
        for threads in [2, 4] {
            let many = binary(tris, &params.with_threads(threads));
            assert!(
                one.nodes == many.nodes && one.tri_ids == many.tri_ids,
                "{params:?} on {threads} threads"
            );
        }
    }
    // The 8-wide trees made other than by the binary builders' splits: the
    // LBVH's (its own wide builder) and those whose lanes are ordered for the
    // any-hit walk.
    for params in [
        BuildParams::for_builder(BuilderKind::Lbvh),
        BuildParams::for_builder(BuilderKind::Sbvh),
        BuildParams::for_quality(raylab::accel::bvh::params::Quality::High),
    ] {
        let params = params.with_width(8);
        let wide = |threads| match build(tris, &params.with_threads(threads)).unwrap() {
            Tree::Wide8(t) => t,
            _ => unreachable!("an 8-wide tree"),
        };
        let one = wide(1);
        for threads in [2, 4] {
            let many = wide(threads);
            assert!(
                one.nodes == many.nodes && one.blocks == many.blocks,
                "{params:?} 8-wide on {threads} threads"
            );
        }
    }
}

#[test]
fn bvh_renders_are_bit_identical_to_naive() {
    for (name, _) in BUILTIN_SCENES {
        let scene = builtin(name).unwrap();
        let s = settings(128, 96, AoMode::Paper);
        let naive = Naive::new(&scene);
        let (reference, _) =
            render(&scene, &naive, &s, Schedule::Rayon, 2, &Progress::new()).unwrap();
        for params in [
            BuildParams::median(),
            BuildParams::sah(),
            BuildParams::median().with_width(4),
            BuildParams::sah().with_width(4),
            BuildParams::for_builder(BuilderKind::Lbvh).with_width(8),
            BuildParams::for_builder(BuilderKind::Sbvh).with_width(8),
        ] {
            let bvh = BvhBackend::new(&scene.mesh(), &params).unwrap();
            let (frame, _) =
                render(&scene, &bvh, &s, Schedule::Tiles, 2, &Progress::new()).unwrap();
            assert!(
                frame == reference,
                "{name}: {params:?} image differs from naive"
            );
        }
    }
}

/// With the watertight test too, naive's, the binary tree's and the 8-wide
/// tree's images are the same (cosine AO and several light samples: many
/// rays from surfaces, through edges).
#[test]
fn watertight_renders_are_bit_identical_to_naive() {
    let scene = builtin("cornell-sphere").unwrap();
    let mut s = settings(256, 192, AoMode::Cosine(8));
    s.light_samples = 4;
    let naive = Naive::new(&scene).with_intersector(Intersector::Watertight);
    let (reference, _) = render(&scene, &naive, &s, Schedule::Rayon, 2, &Progress::new()).unwrap();
    for params in [BuildParams::sah(), BuildParams::sah().with_width(8)] {
        let bvh = BvhBackend::new(&scene.mesh(), &params)
            .unwrap()
            .with_intersector(Intersector::Watertight);
        let (frame, _) = render(&scene, &bvh, &s, Schedule::Tiles, 2, &Progress::new()).unwrap();
        assert!(
            frame == reference,
            "{params:?}: watertight image differs from naive's"
        );
    }
}

#[test]
fn sah_tree_is_cheaper_than_median_on_the_big_scenes() {
    use raylab::accel::bvh::quality::TreeStats;
    for name in ["cornell-sphere", "cornell-water"] {
        let tris = builtin(name).unwrap().triangle_vertices();
        let median = TreeStats::of(&binary(&tris, &BuildParams::median()), tris.len());
        let sah = TreeStats::of(&binary(&tris, &BuildParams::sah()), tris.len());
        assert!(
            sah.sah_cost < median.sah_cost,
            "{name}: sah {} vs median {}",
            sah.sah_cost,
            median.sah_cost
        );
    }
}

/// The 8-wide tree's packet paths (8 and 16 rays) answer the rays a render
/// casts (recorded in the order its streams ask them, and the diffuse
/// bounces) exactly as its single-ray path does, with either triangle test;
/// and images rendered through them are the single-ray images bit for bit.
#[test]
fn packet_path_answers_recorded_rays_as_single_rays_do() {
    use raylab::accel::{build_backend, BackendSpec, Query};
    use raylab::measure::validate::recorded_rays;
    for (name, _) in BUILTIN_SCENES {
        let scene = builtin(name).unwrap();
        let mut s = settings(128, 96, AoMode::Cosine(4));
        s.light_samples = 2;
        let paths = [Intersector::Mt, Intersector::Watertight]
            .into_iter()
            .flat_map(|i| [(i, 8), (i, 16)]);
        for (intersector, width) in paths {
            let single =
                BackendSpec::bvh(BuildParams::sah().with_width(8)).with_intersector(intersector);
            let packet = single.with_query(Query::Packet(width)).unwrap();
            let (single, packet) = (
                build_backend(&single, &scene).unwrap(),
                build_backend(&packet, &scene).unwrap(),
            );
            let rec = recorded_rays(&scene, single.as_ref(), &s).unwrap();
            let diffuse = rec.diffuse(&scene, 7);
            for (kind, rays) in [("primary", &rec.primary), ("diffuse", &diffuse)] {
                let mut hits = vec![None; rays.len()];
                packet.intersect_stream(rays, &mut hits);
                for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
                    let want = single.intersect(ray);
                    assert!(
                        hit.map(|h| (h.t.to_bits(), h.tri)) == want.map(|h| (h.t.to_bits(), h.tri)),
                        "{name} {intersector:?} packet{width} {kind} ray {i}: packet {hit:?}, single {want:?}"
                    );
                }
            }
            for (kind, rays) in [("shadow", &rec.shadow), ("ao", &rec.ao)] {
                let mut occluded = vec![false; rays.len()];
                packet.occluded_stream(rays, &mut occluded);
                for (i, (ray, o)) in rays.iter().zip(&occluded).enumerate() {
                    assert_eq!(
                        *o,
                        single.occluded(ray),
                        "{name} {intersector:?} packet{width} {kind} ray {i}"
                    );
                }
            }
            let image = |b: &dyn Backend| {
                render(&scene, b, &s, Schedule::Tiles, 2, &Progress::new())
                    .unwrap()
                    .0
            };
            assert!(
                image(single.as_ref()) == image(packet.as_ref()),
                "{name} {intersector:?}: packet{width} image differs"
            );
        }
    }
}

/// Walls meeting at a corner (the planes x = c.x and z = c.z, 3 high, one of
/// them a thin wall's 0.1 end face, whose box margin is under an ulp of its
/// coordinates), at coordinates up to 40 from the origin and a hundred more
/// 3e4 from it, and rays aimed at points of the shared edge: the watertight
/// test gives each ray to one wall or the other by its rounding, and every
/// tree and path must find what the naive scan finds. Without the boxes'
/// growth (`Aabb::intersect_grown`, `NodeKernel::intersect_grown`) the
/// trees culled the box of the wall a ray went to when the exact ray passes
/// just outside it (rooms:20000: 2 edge rays in 50,000 went on to the next
/// room).
#[test]
fn watertight_trees_leave_no_hole_where_two_walls_meet() {
    use raylab::accel::Query;
    let mut rng = TestRng(77);
    let mut tris = Vec::new();
    let (mut inside, mut rays) = (Vec::new(), Vec::new());
    for corner in 0..400 {
        let snap = |v: f32| (v * 10.0).round() / 10.0;
        let far = if corner < 300 {
            Vec3::ZERO
        } else {
            Vec3::new(3e4, 0.0, -2e4)
        };
        let c = far
            + Vec3::new(
                snap(rng.range(-40.0, 40.0)),
                0.0,
                snap(rng.range(-40.0, 40.0)),
            );
        let long = rng.range(0.5, 4.0);
        let quad = |p: Vec3, u: Vec3, v: Vec3| [[p, p + u, p + u + v], [p, p + u + v, p + v]];
        let up = Vec3::new(0.0, 3.0, 0.0);
        tris.extend(quad(c, Vec3::new(0.0, 0.0, 0.1), up)); // the end face, x = c.x
        tris.extend(quad(c, Vec3::new(-long, 0.0, 0.0), up)); // the wall z = c.z
                                                              // Far away, aimed at least 0.05 inside the walls' ends and from at
                                                              // least 0.05 in front of them: an origin is rounded to the
                                                              // coordinates' ulps, 0.002 there, which moves where the ray goes.
        let least = if far == Vec3::ZERO { 0.0 } else { 0.05 };
        for _ in 0..80 {
            let target = c + Vec3::new(0.0, rng.range(least, 3.0 - least), 0.0);
            // From the corner's open side, at up to 2 units.
            let open = Vec3::new(
                -rng.range(least, 2.0),
                rng.range(-1.0, 1.0),
                rng.range(least, 2.0),
            );
            inside.push(Ray::new(target + open, -open));
            // From anywhere near, the thin wall's body included.
            let near = rng.vec_in(Vec3::splat(-0.3), Vec3::splat(0.3));
            rays.push(Ray::new(target + near, -near));
        }
    }
    let naive = Naive::from_triangles(tris.clone()).with_intersector(Intersector::Watertight);
    // Watertight: every ray from inside the corner hits one of the walls.
    let inside_hits = inside
        .iter()
        .filter(|r| naive.intersect(r).is_some())
        .count();
    assert_eq!(inside_hits, inside.len());
    rays.extend(inside);
    let want: Vec<_> = rays.iter().map(|r| naive.intersect(r)).collect();
    for params in [BuildParams::median(), BuildParams::sah()] {
        let bvh = binary(&tris, &params);
        for (i, ray) in rays.iter().enumerate() {
            let got = bvh.intersect_using(ray, Intersector::Watertight);
            assert_eq!(got, want[i], "{params:?} binary ray {i} {ray:?}");
        }
        for (label, tree) in wide_trees(&tris, &params) {
            for (i, ray) in rays.iter().enumerate() {
                let got = tree.intersect_using(ray, Intersector::Watertight);
                assert_eq!(got, want[i], "{params:?} {label} ray {i} {ray:?}");
                let occluded = tree.occluded_using(ray, Intersector::Watertight);
                assert_eq!(occluded, want[i].is_some(), "{params:?} {label} ray {i}");
            }
        }
        for query in [Query::Packet(8), Query::Packet(16)] {
            let packets = BvhBackend::new(&tris, &params.with_width(8))
                .unwrap()
                .with_intersector(Intersector::Watertight)
                .with_query(query)
                .unwrap();
            let mut got = vec![None; rays.len()];
            packets.intersect_stream(&rays, &mut got);
            assert_eq!(got, want, "{params:?} {query:?}");
        }
    }
}
