//! Criterion benches of the hot kernels on fixed ray sets, so regressions show in
//! `cargo bench`: the ray/box and ray/triangle tests, closest-hit and any-hit
//! queries per backend on the study's scenes (coherent camera rays and the
//! incoherent AO rays a render casts), the same queries as streams on every
//! query path (single rays, packets, Embree's stream API), raylab's
//! two-level tree against Embree's instances on an instanced forest, and
//! builds per builder against size.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;
use raylab::accel::bvh::BuildParams;

use raylab::accel::{build_backend, build_scene_backend, Backend, BackendSpec, Query};
use raylab::camera::Camera;
use raylab::geometry::{intersect_triangle, Aabb, Ray, SlabRay, TriangleTest, Watertight};
use raylab::scene::builtin::builtin;

/// The AO rays of a 48x36 render of `scene` (paper AO): an incoherent fixed set.
fn ao_rays(scene: &raylab::scene::Scene) -> Vec<Ray> {
    recorded(scene).ao
}

/// The rays a 48x36 render of `scene` casts (paper AO), in its stream order.
fn recorded(scene: &raylab::scene::Scene) -> raylab::measure::validate::Recorded {
    let settings = raylab::render::RenderSettings {
        width: 48,
        height: 36,
        camera: Camera::new(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            60.0,
            48,
            36,
        )
        .unwrap(),
        ao: raylab::render::AoMode::Paper,
        ao_dist: 0.2,
        light_samples: 1,
        seed: 1,
        two_sided_lights: false,
    };
    let bvh = raylab::accel::bvh::BvhBackend::new(&scene.mesh(), &BuildParams::sah()).unwrap();
    raylab::measure::validate::recorded_rays(scene, &bvh, &settings).unwrap()
}

fn ray_box(c: &mut Criterion) {
    let rays = camera_rays();
    let prepared: Vec<SlabRay> = rays.iter().map(SlabRay::new).collect();
    let boxes = [
        (
            "hit",
            Aabb {
                min: Vec3::new(-0.5, 0.5, -0.5),
                max: Vec3::new(0.5, 1.5, 0.5),
            },
        ),
        (
            "thin",
            Aabb {
                min: Vec3::new(-1.0, 0.0, -1.0),
                max: Vec3::new(1.0, 0.0, 1.0),
            },
        ),
    ];
    let mut g = c.benchmark_group("ray_box");
    g.throughput(Throughput::Elements(rays.len() as u64));
    for (name, aabb) in boxes {
        g.bench_function(name, |b| {
            b.iter(|| {
                prepared
                    .iter()
                    .filter(|slab| {
                        std::hint::black_box(&aabb)
                            .intersect(slab, 0.0, f32::INFINITY)
                            .is_some()
                    })
                    .count()
            })
        });
    }
    g.finish();
}

/// Primary rays of a 32x24 image from the study's default view: a fixed set.
fn camera_rays() -> Vec<Ray> {
    let cam = Camera::new(
        Vec3::new(0.0, 1.0, 3.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::Y,
        60.0,
        32,
        24,
    )
    .unwrap();
    (0..24)
        .flat_map(|y| (0..32).map(move |x| cam.ray(x, y)))
        .collect()
}

fn ray_triangle(c: &mut Criterion) {
    let tri = [
        Vec3::new(-1.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 2.0, 0.0),
    ];
    let rays = camera_rays();
    let mut g = c.benchmark_group("ray_triangle");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.bench_function("moller_trumbore", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|r| intersect_triangle(std::hint::black_box(r), &tri).is_some())
                .count()
        })
    });
    // The same test on a block of four triangles at once (the wide trees' leaf
    // test); throughput counts rays, so divide by four for per-triangle cost.
    let block = raylab::accel::bvh::leaf::Tri4::new(&[tri; 4], &[0, 1, 2, 3]);
    g.bench_function("moller_trumbore_simd_block_of_4", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|r| {
                    let r = std::hint::black_box(*r);
                    let r4 = raylab::accel::bvh::leaf::Ray4::new(r);
                    raylab::accel::bvh::leaf::intersect4(&r4, r.tmin, r.tmax, &block).mask != 0
                })
                .count()
        })
    });
    g.bench_function("watertight", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|r| {
                    let r = std::hint::black_box(*r);
                    Watertight::test(&Watertight::prepare(r), r, &tri).is_some()
                })
                .count()
        })
    });
    g.finish();
}

/// The backends compared on one scene: naive (only where it finishes in
/// reasonable time), both BVH builders, the SAH tree 4- and 8-wide, and Embree.
fn backends(scene: &raylab::scene::Scene, with_naive: bool) -> Vec<(String, Box<dyn Backend>)> {
    let mut specs = Vec::new();
    if with_naive {
        specs.push(BackendSpec::naive());
    }
    for params in [
        BuildParams::median(),
        BuildParams::sah(),
        BuildParams::sah().with_width(4),
        BuildParams::sah().with_width(8),
    ] {
        specs.push(BackendSpec::bvh(params));
    }
    if raylab::accel::embree::AVAILABLE {
        specs.push(BackendSpec::embree(1));
    }
    specs
        .iter()
        .map(|spec| {
            let built = build_backend(spec, scene).unwrap();
            (built.name(), built.backend)
        })
        .collect()
}

/// Closest hit and any hit per backend on the same coherent camera rays.
fn camera_queries(c: &mut Criterion) {
    let rays = camera_rays();
    let mut g = c.benchmark_group("camera_rays");
    g.throughput(Throughput::Elements(rays.len() as u64));
    for name in ["cornell-original", "cornell-sphere", "cornell-water"] {
        let scene = builtin(name).unwrap();
        for (backend_name, backend) in backends(&scene, name != "cornell-water") {
            let id = format!("{backend_name}/{name}");
            g.bench_with_input(BenchmarkId::new("intersect", &id), &rays, |b, rays| {
                b.iter(|| rays.iter().filter_map(|r| backend.intersect(r)).count())
            });
            g.bench_with_input(BenchmarkId::new("occluded", &id), &rays, |b, rays| {
                b.iter(|| rays.iter().filter(|r| backend.occluded(r)).count())
            });
        }
    }
    g.finish();
}

/// Every backend on the same incoherent AO rays of cornell-water.
fn ao_queries(c: &mut Criterion) {
    let scene = builtin("cornell-water").unwrap();
    let rays = ao_rays(&scene);
    let mut g = c.benchmark_group("ao_rays");
    g.throughput(Throughput::Elements(rays.len() as u64));
    for (name, backend) in &backends(&scene, false) {
        g.bench_with_input(BenchmarkId::new("occluded", name), &rays, |b, rays| {
            b.iter(|| rays.iter().filter(|r| backend.occluded(r)).count())
        });
        g.bench_with_input(BenchmarkId::new("intersect", name), &rays, |b, rays| {
            b.iter(|| rays.iter().filter_map(|r| backend.intersect(r)).count())
        });
    }
    g.finish();
}

/// The 8-wide tree and Embree on every query path they have, asked in
/// streams of 512 rays as the renderer and the trace part ask: the primary
/// and AO rays of a cornell-water render in its stream order.
fn stream_queries(c: &mut Criterion) {
    let scene = builtin("cornell-water").unwrap();
    let rays = recorded(&scene);
    let mut specs = vec![BackendSpec::bvh(BuildParams::sah().with_width(8))];
    if raylab::accel::embree::AVAILABLE {
        specs.push(BackendSpec::embree(1));
    }
    let mut g = c.benchmark_group("streams");
    for structure in specs {
        for query in structure.queries() {
            let built = build_backend(&structure.with_query(query).unwrap(), &scene).unwrap();
            let name = built.name();
            g.throughput(Throughput::Elements(rays.primary.len() as u64));
            g.bench_function(BenchmarkId::new("intersect_primary", &name), |b| {
                let mut hits = vec![None; 512];
                b.iter(|| {
                    let mut n = 0;
                    for chunk in rays.primary.chunks(512) {
                        built.intersect_stream(chunk, &mut hits[..chunk.len()]);
                        n += hits[..chunk.len()].iter().flatten().count();
                    }
                    n
                })
            });
            g.throughput(Throughput::Elements(rays.ao.len() as u64));
            g.bench_function(BenchmarkId::new("occluded_ao", &name), |b| {
                let mut occluded = vec![false; 512];
                b.iter(|| {
                    let mut n = 0;
                    for chunk in rays.ao.chunks(512) {
                        built.occluded_stream(chunk, &mut occluded[..chunk.len()]);
                        n += occluded[..chunk.len()].iter().filter(|&&o| o).count();
                    }
                    n
                })
            });
        }
    }
    g.finish();
}

/// Instanced scenes: raylab's two-level tree and Embree's instances, single
/// rays, on the primary, shadow and AO rays of a 128x96 render of
/// `forest:1000` (1001 instances of 4 meshes, 10^7 placed triangles) from its
/// default view. Finer than the bench's `instances` part for a change to
/// the instance walk: the same rays, per kind, with criterion's statistics.
fn instanced_queries(c: &mut Criterion) {
    let mut scene = builtin("forest:1000").unwrap();
    scene.set_extra_light(None, Vec3::Y);
    let (w, h) = (128, 96);
    let (eye, look) = raylab::camera::default_view(&scene, None, None, Vec3::Y, 60.0, (w, h));
    let settings = raylab::render::RenderSettings {
        width: w,
        height: h,
        camera: Camera::new(eye, look, Vec3::Y, 60.0, w, h).unwrap(),
        ao: raylab::render::AoMode::Paper,
        ao_dist: raylab::render::default_ao_dist(&scene),
        light_samples: 1,
        seed: 1,
        two_sided_lights: false,
    };
    let mut specs = vec![BackendSpec::DEFAULT];
    if raylab::accel::embree::AVAILABLE {
        specs.push(BackendSpec::embree(1).with_query(Query::Single).unwrap());
    }
    let built: Vec<_> = specs
        .iter()
        .map(|spec| build_scene_backend(spec, &scene).unwrap())
        .collect();
    let rays =
        raylab::measure::validate::recorded_rays(&scene, built[0].as_ref(), &settings).unwrap();
    let mut g = c.benchmark_group("instances");
    for b in &built {
        let name = b.name();
        for (kind, rays, closest) in [
            ("primary", &rays.primary, true),
            ("shadow", &rays.shadow, false),
            ("ao", &rays.ao, false),
        ] {
            g.throughput(Throughput::Elements(rays.len() as u64));
            g.bench_function(BenchmarkId::new(kind, &name), |bench| {
                bench.iter(|| {
                    if closest {
                        rays.iter().filter_map(|r| b.intersect(r)).count()
                    } else {
                        rays.iter().filter(|r| b.occluded(r)).count()
                    }
                })
            });
        }
    }
    g.finish();
}

/// Build time against triangle count on the procedural meshes, serial and on 2 threads.
fn bvh_builds(c: &mut Criterion) {
    // As the binary does: repeated builds reuse freed memory on every thread
    // count (two-thread builds otherwise fault all their memory in afresh).
    raylab::os::keep_freed_memory();
    let mut g = c.benchmark_group("bvh_build");
    g.sample_size(10);
    for n in [1_000u64, 10_000, 100_000] {
        let tris = builtin(&format!("mesh:{n}")).unwrap().triangle_vertices();
        g.throughput(Throughput::Elements(tris.len() as u64));
        use raylab::accel::bvh::params::Quality;
        let mut builders = vec![
            BuildParams::median(),
            BuildParams::sah(),
            BuildParams::sah().with_width(8),
            // The quality ladder's other rungs, as the renderer builds them.
            BuildParams::for_quality(Quality::Low).with_width(8),
            BuildParams::for_quality(Quality::High).with_width(8),
        ];
        if raylab::accel::embree::AVAILABLE {
            // Embree's builder (rtcBuildBVH) into our layout, and Embree's own scene build.
            builders.push(BuildParams::for_builder(
                raylab::accel::bvh::BuilderKind::EmbreeMedium,
            ));
        }
        for params in builders {
            for threads in [1, 2] {
                let p = params.with_threads(threads);
                let wide = if p.width > 2 {
                    format!("-{}wide", p.width)
                } else {
                    String::new()
                };
                let opt = if p.optimize { "-opt" } else { "" };
                let id = format!("{}{opt}{wide}-{threads}t", params.builder.name());
                g.bench_with_input(BenchmarkId::new(id, n), &tris, |b, tris| {
                    // The tree the renderer traverses (wide trees built directly).
                    b.iter(|| raylab::accel::bvh::build(tris, &p).unwrap())
                });
            }
        }
    }
    g.finish();
}

/// One frame's update per strategy on the animated built-ins: raylab's refit
/// against Embree's, on 1 and 2 threads (the `animation` bench part times
/// them per frame inside a whole animation; this is the kernel alone).
fn refits(c: &mut Criterion) {
    use raylab::accel::bvh::params::Quality;
    use raylab::accel::update::{Follower, Strategy};
    use raylab::scene::motion::Animation;
    raylab::os::keep_freed_memory();
    let mut g = c.benchmark_group("refit");
    g.sample_size(20);
    for name in ["cloth:20000", "explode:20000"] {
        let animation = Animation::parse(name).unwrap().unwrap();
        let frame = animation.frame(animation.duration / 2.0).unwrap();
        g.throughput(Throughput::Elements(frame.triangle_count() as u64));
        let mut strategies = vec![Strategy::Refit(Quality::Medium)];
        if raylab::accel::embree::AVAILABLE {
            strategies.push(Strategy::EmbreeRefit);
        }
        for strategy in strategies {
            for threads in [1, 2] {
                let mut f = Follower::new(strategy, animation.rest(), threads).unwrap();
                let id = format!("{}-{threads}t", strategy.name());
                g.bench_function(BenchmarkId::new(id, name), |b| {
                    b.iter(|| f.update(&frame).unwrap())
                });
            }
        }
    }
    g.finish();
}

criterion_group!(
    benches,
    refits,
    ray_box,
    ray_triangle,
    camera_queries,
    ao_queries,
    stream_queries,
    instanced_queries,
    bvh_builds
);
criterion_main!(benches);
