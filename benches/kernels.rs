//! Criterion benches of the hot kernels on fixed ray sets, so regressions show in
//! `cargo bench`: the ray/triangle test, and closest-hit and any-hit queries per
//! backend on the study's scenes.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;
use raylab::accel::bvh::{BuildParams, Bvh};
use raylab::accel::naive::Naive;
use raylab::accel::Backend;
use raylab::camera::Camera;
use raylab::geometry::{intersect_triangle, Ray};
use raylab::scene::builtin::builtin;

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
    g.finish();
}

fn naive_queries(c: &mut Criterion) {
    let rays = camera_rays();
    let mut g = c.benchmark_group("naive");
    g.throughput(Throughput::Elements(rays.len() as u64));
    for name in ["cornell-original", "cornell-sphere"] {
        let scene = builtin(name).unwrap();
        let naive = Naive::new(&scene);
        g.bench_with_input(BenchmarkId::new("intersect", name), &rays, |b, rays| {
            b.iter(|| rays.iter().filter_map(|r| naive.intersect(r)).count())
        });
        g.bench_with_input(BenchmarkId::new("occluded", name), &rays, |b, rays| {
            b.iter(|| rays.iter().filter(|r| naive.occluded(r)).count())
        });
    }
    g.finish();
}

/// Closest-hit and any-hit per BVH builder on the study's scenes, same ray set.
fn bvh_queries(c: &mut Criterion) {
    let rays = camera_rays();
    let mut g = c.benchmark_group("bvh");
    g.throughput(Throughput::Elements(rays.len() as u64));
    for name in ["cornell-sphere", "cornell-water"] {
        let tris = builtin(name).unwrap().triangle_vertices();
        for params in [BuildParams::median(), BuildParams::sah()] {
            let bvh = Bvh::build(&tris, &params).unwrap();
            let id = format!("{}/{name}", params.builder.name());
            g.bench_with_input(BenchmarkId::new("intersect", &id), &rays, |b, rays| {
                b.iter(|| rays.iter().filter_map(|r| bvh.intersect(r)).count())
            });
            g.bench_with_input(BenchmarkId::new("occluded", &id), &rays, |b, rays| {
                b.iter(|| rays.iter().filter(|r| bvh.occluded(r)).count())
            });
        }
    }
    g.finish();
}

/// Build time against triangle count on the procedural meshes, serial and on 2 threads.
fn bvh_builds(c: &mut Criterion) {
    let mut g = c.benchmark_group("bvh_build");
    g.sample_size(10);
    for n in [1_000u64, 10_000, 100_000] {
        let tris = builtin(&format!("mesh:{n}")).unwrap().triangle_vertices();
        g.throughput(Throughput::Elements(tris.len() as u64));
        for params in [BuildParams::median(), BuildParams::sah()] {
            for threads in [1, 2] {
                let p = params.with_threads(threads);
                let id = format!("{}-{threads}t", params.builder.name());
                g.bench_with_input(BenchmarkId::new(id, n), &tris, |b, tris| {
                    b.iter(|| Bvh::build(tris, &p).unwrap())
                });
            }
        }
    }
    g.finish();
}

criterion_group!(
    benches,
    ray_triangle,
    naive_queries,
    bvh_queries,
    bvh_builds
);
criterion_main!(benches);
