//! Fixtures shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

use glam::Vec3;
use raylab::camera::Camera;
use raylab::render::{AoMode, RenderSettings};

/// The study's default view at a small size.
pub fn settings(width: u32, height: u32, ao: AoMode) -> RenderSettings {
    RenderSettings {
        width,
        height,
        camera: Camera::new(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            60.0,
            width,
            height,
        )
        .unwrap(),
        ao,
        ao_dist: 0.2,
        light_samples: 1,
        seed: 1,
        two_sided_lights: false,
    }
}

/// The pixel a point projects to from the study's default view (eye (0,1,3),
/// looking down -z, vertical FOV 60).
pub fn project(p: Vec3, width: u32, height: u32) -> (u32, u32) {
    let depth = 3.0 - p.z;
    let scale = height as f32 * 0.5 / (30f32.to_radians().tan() * depth);
    let x = width as f32 * 0.5 + p.x * scale;
    let y = height as f32 * 0.5 - (p.y - 1.0) * scale;
    (x as u32, y as u32)
}

/// A small deterministic generator for test data (SplitMix64).
pub struct TestRng(pub u64);

impl TestRng {
    pub fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }

    pub fn vec_in(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        Vec3::new(
            self.range(lo.x, hi.x),
            self.range(lo.y, hi.y),
            self.range(lo.z, hi.z),
        )
    }

    /// A uniformly distributed unit vector.
    pub fn unit(&mut self) -> Vec3 {
        loop {
            let v = self.vec_in(Vec3::splat(-1.0), Vec3::splat(1.0));
            let l = v.length();
            if l > 1e-3 && l <= 1.0 {
                return v / l;
            }
        }
    }
}

/// Runs the `raylab` binary with `args`.
pub fn raylab(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args(args)
        .output()
        .expect("run raylab")
}

/// A fresh folder for one test (process id in the name).
pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("raylab-test-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Asserts a failed run with exactly one line on stderr containing `needle`.
pub fn assert_one_line_error(args: &[&str], needle: &str) {
    assert_one_line_error_naming(args, &[needle]);
}

/// As [`assert_one_line_error`], the one line holding every one of `needles`
/// (one run of the command).
pub fn assert_one_line_error_naming(args: &[&str], needles: &[&str]) {
    let out = raylab(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "{args:?}: stderr was:\n{err}"
    );
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    for needle in needles {
        assert!(
            err.contains(needle),
            "{args:?}: expected '{needle}' in: {err}"
        );
    }
}

/// The binary tree of `params`' splits, built through the one entry point.
pub fn binary(
    tris: &[[Vec3; 3]],
    params: &raylab::accel::bvh::BuildParams,
) -> raylab::accel::bvh::Bvh {
    let tree = raylab::accel::bvh::build(tris, &params.binary()).unwrap();
    tree.into_binary().expect("width 2 builds a binary tree")
}

/// Asserts that a raylab run succeeded, showing its stderr when it did not.
pub fn assert_success(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The name of raylab's fastest packet path on this CPU (`packet16` with
/// AVX-512F, else `packet8`), which renders use by default.
pub fn own_packets() -> &'static str {
    if raylab::accel::bvh::simd::Avx512::detect().is_some() {
        "packet16"
    } else {
        "packet8"
    }
}

/// The name of Embree's default packet path here (`packet16` where it
/// traces 16 rays natively, else `packet8`).
pub fn embree_packets() -> &'static str {
    if raylab::accel::embree::native_packets_or_none().contains(&16) {
        "packet16"
    } else {
        "packet8"
    }
}

/// Standard base64 with padding (the test's own, to need no crate).
pub fn base64_encode(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}
