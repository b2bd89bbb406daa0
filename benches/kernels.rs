//! Criterion benches of the hot kernels on fixed ray sets, so regressions show in
//! `cargo bench`: the ray/triangle test, and closest-hit and any-hit queries per
//! backend on the study's scenes.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;
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

criterion_group!(benches, ray_triangle, naive_queries);
criterion_main!(benches);
