//! Scenes that move: every update strategy (raylab's refit, rebuilds and
//! policy; Embree's refit and rebuilds) followed through an animation's
//! frames answers as the naive scan over that frame does: raylab's trees bit
//! for bit, on every query path, Embree's with no genuine disagreement. The
//! explosion carries triangles far outside the rest pose's bounds, so a stale
//! box would lose hits. Also: a refit never rebuilds, the policy rebuilds
//! when and only when its cost grew past the factor, and the render and bench
//! flags of animations.

mod common;

use common::{assert_one_line_error, assert_success, raylab, temp_dir, TestRng};
use glam::Vec3;
use raylab::accel::bvh::params::Quality;
use raylab::accel::naive::Naive;
use raylab::accel::update::{Follower, Strategy};
use raylab::accel::{Backend, Query};
use raylab::geometry::{Hit, Ray};
use raylab::measure::validate::{classify, Agreement};
use raylab::scene::motion::Animation;

/// Rays from inside and around the box, in every direction, in runs of
/// neighbours (so that packets see coherent and incoherent groups).
fn rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = TestRng(seed);
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let o = rng.vec_in(Vec3::new(-1.5, -0.5, -1.5), Vec3::new(1.5, 2.5, 3.0));
        let d = rng.unit();
        for k in 0..8 {
            let jitter = Vec3::new(k as f32 * 1e-3, 0.0, -(k as f32) * 1e-3);
            out.push(Ray::new(o, (d + jitter).normalize()));
        }
    }
    out.truncate(n);
    out
}

fn closest(backend: &dyn Backend, rays: &[Ray]) -> Vec<Option<Hit>> {
    let mut hits = vec![None; rays.len()];
    backend.intersect_stream(rays, &mut hits);
    hits
}

fn occluded(backend: &dyn Backend, rays: &[Ray]) -> Vec<bool> {
    let mut out = vec![false; rays.len()];
    backend.occluded_stream(rays, &mut out);
    out
}

#[test]
fn every_strategy_answers_as_the_naive_scan_on_every_frame() {
    let rays = rays(4000, 17);
    for name in ["explode:3000", "cloth:3000"] {
        let animation = Animation::parse(name).unwrap().unwrap();
        let times = [0.0, 0.4, 1.0, 1.6, 2.0];
        let mut followers: Vec<Follower> = Strategy::compared(&[1.3, 2.0])
            .into_iter()
            .map(|s| Follower::new(s, animation.rest(), 2).unwrap())
            .collect();
        for &t in &times {
            let frame = animation.frame(t).unwrap();
            let naive = Naive::new(&frame);
            let want = closest(&naive, &rays);
            let want_any = occluded(&naive, &rays);
            let triangles = frame.triangle_vertices();
            for f in &mut followers {
                f.update(&frame).unwrap();
                let who = format!("{name} at {t} s, {}", f.strategy.name());
                for q in f.queries() {
                    f.set_query(q).unwrap();
                    let got = closest(f.backend(), &rays);
                    let got_any = occluded(f.backend(), &rays);
                    if f.strategy.is_embree() {
                        let genuine = rays
                            .iter()
                            .zip(got.iter().zip(&want))
                            .filter(|(r, (g, w))| {
                                classify(r, **g, **w, &triangles) == Agreement::Genuine
                            })
                            .count();
                        assert_eq!(genuine, 0, "{who} {q}");
                    } else {
                        assert_eq!(got, want, "{who} {q}");
                        assert_eq!(got_any, want_any, "{who} {q}");
                    }
                }
            }
        }
    }
}

#[test]
fn refits_never_rebuild_and_the_policy_rebuilds_past_its_factor() {
    let animation = Animation::parse("explode:3000").unwrap().unwrap();
    let mut refit = Follower::new(Strategy::Refit(Quality::Medium), animation.rest(), 1).unwrap();
    let factor = 1.2;
    let mut policy = Follower::new(
        Strategy::Policy {
            rung: Quality::Medium,
            factor,
        },
        animation.rest(),
        1,
    )
    .unwrap();
    let built = policy.policy_cost().unwrap();
    let mut reference = built;
    let mut rebuilds = 0;
    for step in 1..=10 {
        let frame = animation.frame(0.2 * step as f32).unwrap();
        assert!(!refit.update(&frame).unwrap().rebuilt);
        // What the refitted tree would cost: the refit-only follower's,
        // while the policy has not rebuilt yet.
        let refitted = refit.policy_cost().unwrap();
        let updated = policy.update(&frame).unwrap();
        if rebuilds == 0 {
            assert_eq!(
                updated.rebuilt,
                refitted > factor as f64 * reference,
                "step {step}: refitted {refitted}, built {reference}"
            );
        }
        if updated.rebuilt {
            rebuilds += 1;
            reference = policy.policy_cost().unwrap();
        }
    }
    // The explosion swells a refitted tree far past 1.2x.
    assert!((1..10).contains(&rebuilds), "{rebuilds} rebuilds");
    assert!(refit.policy_cost().unwrap() > 1.5 * built);
}

#[test]
fn render_takes_a_time_and_frames_of_an_animation() {
    let dir = temp_dir("animation-render");
    let out = dir.join("e.png");
    let o = out.to_str().unwrap();
    let r = raylab(&[
        "render",
        "explode:2000",
        "--time",
        "1",
        "--size",
        "64x48",
        "-q",
        "-o",
        o,
    ]);
    assert_success(&r);
    assert!(out.exists());
    let r = raylab(&[
        "render",
        "cloth:2000",
        "--frames",
        "3..4",
        "--fps",
        "10",
        "--size",
        "64x48",
        "-q",
        "-o",
        o,
        "--json",
    ]);
    assert_success(&r);
    let text = String::from_utf8_lossy(&r.stdout);
    assert_eq!(text.lines().count(), 2, "{text}");
    assert!(dir.join("e_0003.png").exists() && dir.join("e_0004.png").exists());
    // The frames differ: the cloth moves.
    let hashes: Vec<&str> = text
        .lines()
        .map(|l| {
            l.split("\"image_hash\":\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap()
        })
        .collect();
    assert_ne!(hashes[0], hashes[1]);
}

#[test]
fn bad_animation_flags_get_one_line_errors() {
    assert_one_line_error(&["render", "cornell-original", "--time", "1"], "--time");
    assert_one_line_error(&["render", "mesh:1000", "--frames", "0..3"], "--frames");
    assert_one_line_error(&["render", "explode:2000", "--time", "9"], "--time");
    assert_one_line_error(&["render", "explode:2000", "--time", "-1"], "--time");
    assert_one_line_error(&["render", "cloth:2000", "--frames", "4..2"], "--frames");
    assert_one_line_error(&["render", "cloth:2000", "--frames", "0..100"], "--frames");
    assert_one_line_error(
        &["render", "cloth:2000", "--fps", "0", "--frames", "0..1"],
        "--fps",
    );
    assert_one_line_error(&["render", "cloth:2000", "--fps", "10"], "--frames");
    assert_one_line_error(&["render", "cloth:20", "--time", "1"], "cloth:N");
    assert_one_line_error(
        &[
            "bench",
            "--quick",
            "--parts",
            "libraries",
            "--rebuild-factor",
            "2",
        ],
        "--rebuild-factor",
    );
    assert_one_line_error(
        &[
            "bench",
            "--quick",
            "--parts",
            "animation",
            "--rebuild-factor",
            "0.5",
        ],
        "--rebuild-factor",
    );
}

/// A frame that cannot be rendered (here a triangle scaled to nothing at
/// 1 s) fails `--frames` with one line naming the frame, its time and the
/// frames already written.
#[test]
fn a_failing_frame_is_named_with_the_frames_written_before_it() {
    use base64::Engine;
    let floats: [f32; 17] = [
        0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, // the triangle
        0.0, 1.0, // keyframe times
        1.0, 1.0, 1.0, 0.0, 0.0, 0.0, // scales: 1, then 0
    ];
    let bin: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
    let data = base64::engine::general_purpose::STANDARD.encode(&bin);
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "buffers":[{{"uri":"data:application/octet-stream;base64,{data}","byteLength":68}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":8}},
                       {{"buffer":0,"byteOffset":44,"byteLength":24}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5126,"count":2,"type":"SCALAR","min":[0],"max":[1]}},
                     {{"bufferView":2,"componentType":5126,"count":2,"type":"VEC3"}}],
        "animations":[{{"samplers":[{{"input":1,"output":2}}],
                        "channels":[{{"sampler":0,"target":{{"node":0,"path":"scale"}}}}]}}]}}"#
    );
    let d = temp_dir("animation-failing-frame");
    let file = d.join("shrink.gltf");
    std::fs::write(&file, gltf).unwrap();
    let out = d.join("f.png");
    common::assert_one_line_error_naming(
        &[
            "render",
            file.to_str().unwrap(),
            "--frames",
            "0..2",
            "--fps",
            "2",
            "--size",
            "16x12",
            "-q",
            "-o",
            out.to_str().unwrap(),
        ],
        &[
            "--frames: frame 2 (at 1 s)",
            "too small",
            "(frames 0..1 written)",
        ],
    );
    assert!(d.join("f_0001.png").exists() && !d.join("f_0002.png").exists());
    std::fs::remove_dir_all(&d).ok();
}

/// Rays from above and beside the belt of rocks towards points in it, in
/// runs of neighbours, over a scene's `bounds`.
fn belt_rays(n: usize, seed: u64, min: Vec3, max: Vec3) -> Vec<Ray> {
    let mut rng = TestRng(seed);
    let mut out = Vec::with_capacity(n);
    let size = max - min;
    while out.len() < n {
        let o = rng.vec_in(min - size * 0.1, max + Vec3::new(0.0, 6.0, 0.0));
        let target = rng.vec_in(min, max);
        for k in 0..8 {
            let jitter = Vec3::new(k as f32 * 0.02, 0.0, -(k as f32) * 0.02);
            out.push(Ray::new(o, (target + jitter - o).normalize()));
        }
    }
    out.truncate(n);
    out
}

#[test]
fn moving_instances_every_strategy_answers_as_a_fresh_two_level_tree() {
    use raylab::accel::bvh::BuildParams;
    use raylab::accel::{build_scene_backend, BackendSpec};
    let animation = Animation::parse("asteroids:80").unwrap().unwrap();
    assert!(animation.moves_instances());
    let rest = animation.rest();
    let b = rest.bounds();
    let rays = belt_rays(3000, 29, b.min, b.max);
    let mut followers: Vec<Follower> = Strategy::compared(&[1.1, 1.5])
        .into_iter()
        .map(|s| Follower::new(s, rest, 2).unwrap())
        .collect();
    let mut hits = 0;
    for t in [0.0, 0.5, 1.0, 1.5, 2.0] {
        let frame = animation.frame(t).unwrap();
        // The meshes stay; every rock but the ground leaves the box it had
        // at rest by the end (a stale TLAS box would lose its hits).
        assert_eq!(frame.positions, rest.positions);
        if t == 2.0 {
            let (a, z) = (
                rest.instancing.as_ref().unwrap(),
                frame.instancing.as_ref().unwrap(),
            );
            let left = (1..a.instances.len())
                .filter(|&i| {
                    let (p, q) = (a.world_box(i), z.world_box(i));
                    p.union(q).extent().length() > p.extent().length() + q.extent().length()
                })
                .count();
            assert!(left * 10 > a.instances.len() * 9, "{left} rocks left");
        }
        let fresh =
            build_scene_backend(&BackendSpec::bvh(BuildParams::sah().with_width(8)), &frame)
                .unwrap();
        let want = closest(fresh.backend.as_ref(), &rays);
        let want_any = occluded(fresh.backend.as_ref(), &rays);
        hits += want.iter().flatten().count();
        let flat = frame.flattened().unwrap();
        let triangles = flat.triangle_vertices();
        let numbered = |h: Option<Hit>| {
            h.map(|h| Hit {
                tri: frame.flat_index(&h) as u32,
                inst: 0,
                ..h
            })
        };
        for f in &mut followers {
            f.update(&frame).unwrap();
            let who = format!("asteroids:80 at {t} s, {}", f.strategy.name());
            for q in f.queries() {
                if f.set_query(q).is_err() {
                    // packet16 needs AVX-512.
                    assert_eq!(q, Query::Packet(16), "{who}");
                    continue;
                }
                let got = closest(f.backend(), &rays);
                let got_any = occluded(f.backend(), &rays);
                if f.strategy.is_embree() {
                    let genuine = rays
                        .iter()
                        .zip(got.iter().zip(&want))
                        .filter(|(r, (g, w))| {
                            classify(r, numbered(**g), numbered(**w), &triangles)
                                == Agreement::Genuine
                        })
                        .count();
                    assert_eq!(genuine, 0, "{who} {q}");
                } else {
                    assert_eq!(got, want, "{who} {q}");
                    assert_eq!(got_any, want_any, "{who} {q}");
                }
            }
        }
    }
    assert!(hits > 3000, "{hits} hits over five frames");
}

#[test]
fn a_refitted_tlas_swells_as_the_belt_shears_and_the_policy_rebuilds_it() {
    let animation = Animation::parse("asteroids:400").unwrap().unwrap();
    let rest = animation.rest();
    let mut refit = Follower::new(Strategy::Refit(Quality::Medium), rest, 1).unwrap();
    let built = refit.policy_cost().unwrap();
    let mut policy = Follower::new(
        Strategy::Policy {
            rung: Quality::Medium,
            factor: 1.1,
        },
        rest,
        1,
    )
    .unwrap();
    let mut rebuilds = 0;
    for step in 1..=8 {
        let frame = animation.frame(0.25 * step as f32).unwrap();
        assert!(!refit.update(&frame).unwrap().rebuilt);
        rebuilds += policy.update(&frame).unwrap().rebuilt as usize;
    }
    let swollen = refit.policy_cost().unwrap();
    assert!(
        swollen > 1.2 * built,
        "{swollen} against {built} when built"
    );
    assert!(rebuilds >= 1, "the policy never rebuilt");
    assert!(policy.policy_cost().unwrap() < swollen);
}

#[test]
fn render_moves_the_instances_and_flatten_traces_them_as_one_list() {
    let dir = temp_dir("animation-instances");
    let hash = |args: &[&str]| {
        let r = raylab(args);
        assert_success(&r);
        let text = String::from_utf8_lossy(&r.stdout).into_owned();
        text.split("\"image_hash\":\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .to_string()
    };
    let out = dir.join("a.png");
    let o = out.to_str().unwrap();
    let at = |t: &str, extra: &[&str]| {
        let mut args = vec![
            "render",
            "asteroids:40",
            "--time",
            t,
            "--size",
            "96x64",
            "-q",
            "-o",
            o,
            "--json",
        ];
        args.extend_from_slice(extra);
        hash(&args)
    };
    let (start, later) = (at("0", &[]), at("1.5", &[]));
    assert_ne!(start, later, "the rocks move");
    assert!(out.exists());
    // Flattened, the frame is the same picture up to the transforms'
    // rounding: it renders (the hashes may differ by rounding).
    at("1.5", &["--flatten"]);
}
