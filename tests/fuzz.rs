//! A mutation fuzzer over every input raylab reads (OBJ/MTL, PLY, glTF/GLB,
//! ray files) and hostile rays through every backend, run as the `raylab`
//! binary a user runs: each mutant is `raylab render FILE --size 16x12` (or
//! `raylab validate --rays FILE` for ray files) in a child process under a
//! time limit and an address-space limit, and its end is classified:
//!
//! - exit 0, 1 or 2 with a `raylab:` (or clap's `error:`) line: fine;
//! - exit 101: a panic; killed by a signal: an abort (SIGABRT, SIGSEGV, a
//!   stack overflow), or a blowup when the allocator said it ran out;
//!   killed by the time limit: a hang; any other exit (tinybvh's `exit(1)`
//!   without raylab's line counts here too): a bad exit.
//!
//! Seeds are the fixtures written below (one or more per format, with what
//! each reader is known to take: materials, normals, negative indices,
//! concave faces, instancing, strips, sparse accessors, quantization) and,
//! where the machine has them, assimp's sample models
//! (/usr/share/assimp/models: real exporters' OBJ, PLY and glTF files).
//!
//! Mutations are chosen by a fixed-seed generator, so a run is repeatable:
//! bit flips, interesting bytes and 32-bit words, deleted, duplicated and
//! spliced ranges, numbers in text replaced by edge values, and lines
//! repeated up to thousands of times.
//!
//! CI runs the default: `cargo test --release --test fuzz` (300 mutants and
//! the hostile ray files). On demand, more: `RAYLAB_FUZZ_CASES=5000
//! RAYLAB_FUZZ_SEED=7 cargo test --release --test fuzz -- --nocapture`.
//! Findings are kept, one file each, under the folder the summary names;
//! every one that was fixed became a test in tests/hostile.rs with its
//! minimal file. (A mutation run through the binary, rather than cargo-fuzz
//! with `arbitrary`: it needs no nightly compiler or sanitizer build, runs in
//! the ordinary test suite, and sees aborts and stack overflows in C++
//! libraries as a user would, which an in-process harness cannot survive.)

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use glam::Vec3;
use raylab::geometry::Ray;
use raylab::measure::validate::RaySet;

/// Mutants in a default run (the CI run): `RAYLAB_FUZZ_CASES` overrides.
const DEFAULT_CASES: usize = 300;
/// Wall-clock limit of one case: a 16x12 render of a file under a few
/// megabytes takes well under a second, even with two other builds running.
const CASE_SECONDS: u64 = 20;
/// Address-space limit of one case (`ulimit -v`, KiB): every backend renders
/// the fixtures within 1.5 GB, so an input that asks for more is refused
/// early or shows up as a blowup.
const CASE_KIB: u64 = 2_000_000;

/// A small deterministic generator (SplitMix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }

    fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

/// A seed file: its name (the extension picks the reader), its bytes, and
/// the files it names (MTL, glTF buffers), copied beside every mutant.
#[derive(Clone)]
struct Seed {
    name: String,
    bytes: Vec<u8>,
    companions: Vec<(String, Vec<u8>)>,
}

fn seed(name: &str, bytes: impl Into<Vec<u8>>) -> Seed {
    Seed {
        name: name.into(),
        bytes: bytes.into(),
        companions: Vec::new(),
    }
}

const OBJ: &str = "# a box with a lamp, normals, negative indices and a concave face
mtllib box.mtl
o box
v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv -1 2 -1\nv 1 2 -1\nv 1 2 1\nv -1 2 1
vn 0 1 0\nvn 0 -1 0\nvt 0 0\nvt 1 0\nvt 1 1
usemtl white
f 1//1 2//1 3//1 4//1
f 5/1/2 8/2/2 7/3/2 6/1/2
usemtl red
f 1 5 6 2
f -8 -4 -1 -5
g lamp
usemtl light
v -0.3 1.99 -0.3\nv 0.3 1.99 -0.3\nv 0.3 1.99 0.3\nv 0 1.99 0\nv -0.3 1.99 0.3
f 9 10 11 12 13
l 1 2
p 3
";

const MTL: &str = "newmtl white\nKa 0 0 0\nKd 0.8 0.8 0.8\nKs 0.1 0.1 0.1\nNs 10\n\
newmtl red\nKd 0.8 0.1 0.1\nNs -1.960784\n\
newmtl light\nKd 0.5\nKe 10 10 8\n";

const PLY_ASCII: &str = "ply
format ascii 1.0
comment a quad and a triangle
element vertex 5
property float x
property float y
property float z
element face 2
property list uchar int vertex_indices
end_header
-1 0 -1
1 0 -1
1 2 -1
-1 2 -1
0 1 -2
4 0 1 2 3
3 0 1 4
";

/// A binary little-endian PLY of the same mesh.
fn ply_binary() -> Vec<u8> {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    for v in [
        [-1f32, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 2.0, -1.0],
        [-1.0, 2.0, -1.0],
        [0.0, 1.0, -2.0],
    ] {
        for x in v {
            b.extend(x.to_le_bytes());
        }
    }
    b.push(4);
    for i in [0i32, 1, 2, 3] {
        b.extend(i.to_le_bytes());
    }
    b.push(3);
    for i in [0i32, 1, 4] {
        b.extend(i.to_le_bytes());
    }
    b
}

/// The glTF fixture's buffer: 4 f32 positions, 4 i8 normalized normals
/// (quantized), 6 u16 triangle indices, 4 u16 strip indices.
fn gltf_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for p in [
        [0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ] {
        for x in p {
            b.extend(x.to_le_bytes());
        }
    }
    for _ in 0..4 {
        b.extend([0u8, 0, 127, 0]);
    }
    for i in [0u16, 1, 2, 0, 2, 3, 0, 1, 3, 2] {
        b.extend(i.to_le_bytes());
    }
    b
}

/// A glTF document over [`gltf_buffer`]: instancing, a mirrored child, a
/// strip, a sparse accessor, quantized normals and an emissive material.
fn gltf_json(uri: Option<&str>) -> String {
    let uri = uri.map_or(String::new(), |u| format!(r#""uri":"{u}","#));
    format!(
        r#"{{"asset":{{"version":"2.0"}},
"extensionsUsed":["KHR_materials_emissive_strength","KHR_mesh_quantization"],
"extensionsRequired":["KHR_mesh_quantization"],
"scene":0,"scenes":[{{"nodes":[0,1,3]}}],
"nodes":[{{"mesh":0,"translation":[0.5,0,0]}},{{"scale":[-1,1,1],"children":[2]}},
  {{"mesh":0,"translation":[1,0,0],"rotation":[0,0.7071068,0,0.7071068]}},{{"mesh":1,"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,-1,1]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},"indices":2,"material":0}},
  {{"attributes":{{"POSITION":0}},"mode":1}}]}},
  {{"primitives":[{{"attributes":{{"POSITION":4}},"indices":3,"mode":5}}]}}],
"materials":[{{"name":"lamp","pbrMetallicRoughness":{{"baseColorFactor":[0.2,0.4,0.6,1]}},
  "emissiveFactor":[1,0.5,0.25],"extensions":{{"KHR_materials_emissive_strength":{{"emissiveStrength":4}}}}}}],
"buffers":[{{{uri}"byteLength":84}}],
"bufferViews":[{{"buffer":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":16,"byteStride":4}},
  {{"buffer":0,"byteOffset":64,"byteLength":12}},{{"buffer":0,"byteOffset":76,"byteLength":8}}],
"accessors":[
  {{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
  {{"bufferView":1,"componentType":5120,"normalized":true,"count":4,"type":"VEC3"}},
  {{"bufferView":2,"componentType":5123,"count":6,"type":"SCALAR"}},
  {{"bufferView":3,"componentType":5123,"count":4,"type":"SCALAR"}},
  {{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0],
    "sparse":{{"count":2,"indices":{{"bufferView":3,"componentType":5123}},"values":{{"bufferView":0,"byteOffset":12}}}}}}
]}}"#
    )
}

/// A GLB container of `json` and `bin`.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + j.len() + 8 + b.len()) as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(b);
    out
}

/// Rays of every kind at the built-in Cornell box (the ray-file seed).
fn ray_file_seed() -> Vec<u8> {
    let eye = Vec3::new(0.0, 1.0, 3.0);
    let rays: Vec<Ray> = (0..16)
        .map(|i| Ray {
            origin: eye,
            dir: Vec3::new(i as f32 / 8.0 - 1.0, 0.1, -1.0),
            tmin: 0.0,
            tmax: f32::INFINITY,
        })
        .collect();
    raylab::measure::rayfile::encode(&[
        (RaySet::Primary, rays.clone()),
        (RaySet::Shadow, rays[..4].to_vec()),
        (RaySet::Ao, rays[4..8].to_vec()),
    ])
}

/// How many of [`seeds`] are the fixtures (the rest are assimp's).
const FIXTURES: usize = 8;

/// Every seed: the fixtures, then assimp's models where installed.
fn seeds() -> Vec<Seed> {
    let mut obj = seed("box.obj", OBJ);
    obj.companions.push(("box.mtl".into(), MTL.into()));
    // The MTL mutated, the OBJ kept: mutants of this seed are written as
    // its companion "mtl.mtl" (see `run_file_case`).
    let mut mtl = seed("mtl.obj", OBJ.replace("box.mtl", "mtl.mtl"));
    mtl.companions.push(("mtl.mtl".into(), MTL.into()));
    let data = base64::engine::general_purpose::STANDARD.encode(gltf_buffer());
    let mut external = seed("ext.gltf", gltf_json(Some("ext.bin")));
    external.companions.push(("ext.bin".into(), gltf_buffer()));
    let mut out = vec![
        obj,
        mtl,
        seed("quad.ply", PLY_ASCII),
        seed("bin.ply", ply_binary()),
        seed(
            "embedded.gltf",
            gltf_json(Some(&format!(
                "data:application/octet-stream;base64,{data}"
            ))),
        ),
        external,
        seed("scene.glb", glb(&gltf_json(None), &gltf_buffer())),
        seed("cornell.rays", ray_file_seed()),
    ];
    out.extend(assimp_seeds(Path::new("/usr/share/assimp/models")));
    out
}

/// assimp's OBJ, PLY, glTF and GLB samples under 256 KB, each with the
/// files beside it that it may name (.mtl, .bin), under 1 MB together.
fn assimp_seeds(root: &Path) -> Vec<Seed> {
    let mut files = Vec::new();
    let mut dirs = vec![root.to_path_buf()];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else {
                files.push(p);
            }
        }
    }
    files.sort();
    let ext = |p: &Path| {
        p.extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default()
    };
    let mut out = Vec::new();
    for p in &files {
        let e = ext(p);
        if !["obj", "ply", "gltf", "glb"].contains(&e.as_str()) {
            continue;
        }
        let Ok(bytes) = std::fs::read(p) else {
            continue;
        };
        if bytes.len() > 256 << 10 {
            continue;
        }
        let mut companions = Vec::new();
        let mut total = 0;
        if let Some(dir) = p.parent() {
            for c in files.iter().filter(|c| c.parent() == Some(dir)) {
                if matches!(ext(c).as_str(), "mtl" | "bin") {
                    if let Ok(b) = std::fs::read(c) {
                        total += b.len();
                        if total > 1 << 20 {
                            break;
                        }
                        let name = c.file_name().unwrap().to_string_lossy().into_owned();
                        companions.push((name, b));
                    }
                }
            }
        }
        out.push(Seed {
            name: format!("assimp-{}", p.file_name().unwrap().to_string_lossy()),
            bytes,
            companions,
        });
    }
    out
}

/// Numbers at the edges of what the readers take.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "1",
    "-1",
    "2",
    "3",
    "-3",
    "255",
    "256",
    "65535",
    "65536",
    "2147483647",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "18446744073709551616",
    "1e38",
    "3.5e38",
    "1e39",
    "-1e39",
    "nan",
    "inf",
    "-inf",
    "1e-45",
    "2e18",
    "1e13",
    "1e-13",
    "5120",
    "5121",
    "5122",
    "5123",
    "5125",
    "5126",
    "0.5",
    "-1.960784",
    "100000000",
    "",
];

/// 32-bit words at the edges of binary fields (counts, lengths, floats).
const WORDS: &[u32] = &[
    0,
    1,
    2,
    3,
    4,
    0x7f,
    0x80,
    0xff,
    0x100,
    0xffff,
    0x1_0000,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x7fc0_0000,
    0x7f80_0000,
    0xff80_0000,
    0x7f7f_ffff,
    0x5dcc_b9a2,
    0x0000_0001,
    0x8000_0001,
    0x3f80_0000,
];

/// One mutation of `b`, using `others` (seeds' bytes) for splices.
fn mutate(b: &mut Vec<u8>, rng: &mut Rng, others: &[Seed]) {
    let len = b.len();
    // Text keeps its syntax more often through number and line mutations,
    // and reaches the readers' checks behind the parser's; half of a text
    // file's mutations are those.
    let text = !b[..len.min(512)].contains(&0) && !b.starts_with(b"glTF");
    let kind = if text && rng.below(2) == 0 {
        *rng.pick(&[6, 7, 8])
    } else {
        rng.below(10)
    };
    match kind {
        0 if len > 0 => {
            let i = rng.below(len);
            b[i] ^= 1 << rng.below(8);
        }
        1 if len > 0 => {
            let i = rng.below(len);
            b[i] = *rng.pick(&[
                0u8, 0xff, 0x7f, 0x80, b'-', b'9', b'.', b'e', b'\n', b' ', b'/',
            ]);
        }
        2 if len >= 4 => {
            let i = rng.below(len - 3);
            b[i..i + 4].copy_from_slice(&rng.pick(WORDS).to_le_bytes());
        }
        3 if len > 0 => {
            let i = rng.below(len);
            let n = 1 + rng.below(64.min(len - i));
            b.drain(i..i + n);
        }
        4 if len > 0 => {
            let i = rng.below(len);
            let n = 1 + rng.below(256.min(len - i));
            let chunk = b[i..i + n].to_vec();
            let at = rng.below(len + 1);
            b.splice(at..at, chunk);
        }
        5 => {
            let other = &rng.pick(others).bytes;
            if !other.is_empty() && len > 0 {
                let i = rng.below(other.len());
                let n = 1 + rng.below(128.min(other.len() - i));
                let at = rng.below(len + 1);
                b.splice(at..at, other[i..i + n].iter().copied());
            }
        }
        6 | 7 => {
            // A number in text replaced by an edge value.
            let starts: Vec<usize> = (0..len)
                .filter(|&i| {
                    (b[i].is_ascii_digit() || b[i] == b'-')
                        && (i == 0 || !b[i - 1].is_ascii_alphanumeric() && b[i - 1] != b'.')
                })
                .collect();
            if !starts.is_empty() {
                let s = *rng.pick(&starts);
                let mut e = s + 1;
                while e < len && (b[e].is_ascii_digit() || b".eE-+".contains(&b[e])) {
                    e += 1;
                }
                b.splice(s..e, rng.pick(NUMBERS).bytes());
            }
        }
        8 => {
            // A line repeated: many faces, many `mtllib`s, many records.
            let lines: Vec<usize> = std::iter::once(0)
                .chain((0..len).filter(|&i| b[i] == b'\n').map(|i| i + 1))
                .filter(|&i| i < len)
                .collect();
            if !lines.is_empty() {
                let s = *rng.pick(&lines);
                let e = b[s..]
                    .iter()
                    .position(|&c| c == b'\n')
                    .map_or(len, |p| s + p + 1);
                let line = b[s..e].to_vec();
                let times = *rng.pick(&[2usize, 10, 100, 1000, 5000]);
                let mut rep = Vec::with_capacity(line.len() * times + 1);
                for _ in 0..times {
                    rep.extend(&line);
                    if !line.ends_with(b"\n") {
                        rep.push(b'\n');
                    }
                }
                b.splice(s..e, rep);
            }
        }
        _ if len > 0 => {
            // Truncated.
            b.truncate(rng.below(len));
        }
        _ => b.extend(rng.pick(NUMBERS).bytes()),
    }
}

/// How a case ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Outcome {
    /// Exit 0: rendered (or validated).
    Ok,
    /// Exit 1 or 2 with raylab's one line: refused, as it should be.
    Refused,
    Panic,
    Abort,
    Hang,
    Blowup,
    BadExit,
}

/// Runs `args` of the raylab binary in `dir` under the limits, and says how
/// it ended, with its stderr.
fn run_case(dir: &Path, args: &[&str]) -> (Outcome, String) {
    // RAYLAB_FUZZ_BIN: another build (e.g. an older one, for before/after).
    let bin = std::env::var("RAYLAB_FUZZ_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_raylab").to_string());
    // `ulimit -v` in a shell that then becomes raylab: the address-space
    // limit without a crate or unsafe code.
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {CASE_KIB} && exec \"$0\" \"$@\""))
        .arg(&bin)
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run raylab");
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = Vec::new();
        std::io::Read::read_to_end(&mut stderr, &mut s).ok();
        s
    });
    let deadline = Instant::now() + Duration::from_secs(CASE_SECONDS);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if Instant::now() > deadline {
            child.kill().ok();
            child.wait().ok();
            break None;
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    let err = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    let Some(status) = status else {
        return (Outcome::Hang, err);
    };
    use std::os::unix::process::ExitStatusExt;
    let outcome = match (status.code(), status.signal()) {
        (Some(0), _) => Outcome::Ok,
        (Some(1 | 2), _)
            if err
                .lines()
                .any(|l| l.starts_with("raylab: ") || l.starts_with("error: "))
                && !err.contains("Fatal error") =>
        {
            Outcome::Refused
        }
        (Some(101), _) => Outcome::Panic,
        (_, Some(_)) if err.contains("memory allocation of") => Outcome::Blowup,
        (_, Some(_)) => Outcome::Abort,
        _ => Outcome::BadExit,
    };
    (outcome, err)
}

/// The backends a case is rendered with, in turn: each sees mutants.
const BACKENDS: &[&str] = &["bvh", "embree", "tinybvh", "obvhs", "bvh-crate", "naive"];

/// Writes `bytes` as the mutant of `s` (or of its first companion, for the
/// MTL seed) in a fresh `dir`, with the other files beside it, and runs it.
fn run_file_case(dir: &Path, s: &Seed, bytes: &[u8], backend: &str) -> (Outcome, String) {
    std::fs::remove_dir_all(dir).ok();
    std::fs::create_dir_all(dir).unwrap();
    let mtl_mutant = s.name == "mtl.obj";
    std::fs::write(
        dir.join(&s.name),
        if mtl_mutant { &s.bytes[..] } else { bytes },
    )
    .unwrap();
    for (i, (name, b)) in s.companions.iter().enumerate() {
        let b = if mtl_mutant && i == 0 { bytes } else { b };
        std::fs::write(dir.join(name), b).unwrap();
    }
    if s.name.ends_with(".rays") {
        return run_case(
            dir,
            &[
                "validate",
                "cornell-original",
                "--rays",
                &s.name,
                "--backend",
                backend,
            ],
        );
    }
    run_case(
        dir,
        &[
            "render",
            &s.name,
            "--size",
            "16x12",
            "--backend",
            backend,
            "-o",
            "out.png",
        ],
    )
}

/// Hostile rays from the edges of f32 (NaN, infinities, the largest finite
/// values, Embree's limit, denormals, zeros), mixed at random, with tmin past
/// tmax and zero directions among them.
fn hostile_rays(rng: &mut Rng, n: usize) -> Vec<Ray> {
    const VALUES: &[f32] = &[
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.5,
        3.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN,
        3e38,
        1.8e18,
        1.9e18,
        -2e18,
        1e30,
        1e13,
        1e-13,
        1e-40,
        -1e-45,
        f32::EPSILON,
    ];
    let eye = Vec3::new(0.0, 1.0, 3.0);
    (0..n)
        .map(|_| {
            let mut v = || *rng.pick(VALUES);
            let (origin, dir) = (Vec3::new(v(), v(), v()), Vec3::new(v(), v(), v()));
            let (tmin, tmax) = (v().abs(), v());
            match rng.below(4) {
                // From the eye, direction hostile.
                0 => Ray {
                    origin: eye,
                    dir,
                    tmin: 0.0,
                    tmax: f32::INFINITY,
                },
                // Towards the box, origin hostile.
                1 => Ray {
                    origin,
                    dir: eye - origin,
                    tmin: 0.0,
                    tmax: f32::INFINITY,
                },
                2 => Ray {
                    origin: eye,
                    dir: Vec3::new(0.1, 0.0, -1.0),
                    tmin,
                    tmax,
                },
                _ => Ray {
                    origin,
                    dir,
                    tmin,
                    tmax,
                },
            }
        })
        .collect()
}

/// Where findings are kept: `RAYLAB_FUZZ_OUT`, else the test target's tmp.
fn findings_dir() -> PathBuf {
    std::env::var_os("RAYLAB_FUZZ_OUT")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-findings"))
}

fn env_number(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[test]
fn mutated_files_and_hostile_rays_end_in_one_line_or_success() {
    let cases = env_number("RAYLAB_FUZZ_CASES", DEFAULT_CASES as u64) as usize;
    let mut rng = Rng(env_number("RAYLAB_FUZZ_SEED", 1));
    let seeds = seeds();
    let fixtures = FIXTURES.min(seeds.len());
    let work = common::temp_dir("fuzz");
    let findings = findings_dir();
    let mut counts = std::collections::BTreeMap::new();
    let mut found = Vec::new();
    // RAYLAB_FUZZ_VERBOSE=1: each case's outcome and last stderr line.
    let verbose = std::env::var_os("RAYLAB_FUZZ_VERBOSE").is_some();
    let mut record = |outcome: Outcome, what: String, bytes: &[u8], err: &str| {
        *counts.entry(outcome).or_insert(0usize) += 1;
        if verbose {
            let last = err.trim_end().lines().last().unwrap_or("");
            println!("{outcome:?} {what}: {last}");
        }
        if !matches!(outcome, Outcome::Ok | Outcome::Refused) {
            std::fs::create_dir_all(&findings).unwrap();
            let keep = findings.join(format!("{}-{what}", found.len()));
            std::fs::write(&keep, bytes).unwrap();
            let last = err.trim_end().lines().last().unwrap_or("").to_string();
            found.push(format!("{outcome:?}: {} ({last})", keep.display()));
        }
    };
    let start = Instant::now();
    for case in 0..cases {
        // Half the cases from the fixtures (every reader's features), half
        // from the real files (usually many more of them).
        let s = if rng.below(2) == 0 || seeds.len() == fixtures {
            &seeds[rng.below(fixtures)]
        } else {
            &seeds[fixtures + rng.below(seeds.len() - fixtures)]
        };
        let mut bytes = match s.name.as_str() {
            "mtl.obj" => s.companions[0].1.clone(),
            _ => s.bytes.clone(),
        };
        for _ in 0..1 + rng.below(3) {
            mutate(&mut bytes, &mut rng, &seeds);
        }
        let backend = BACKENDS[case % BACKENDS.len()];
        let dir = work.join("case");
        let (outcome, err) = run_file_case(&dir, s, &bytes, backend);
        record(outcome, format!("{backend}-{}", s.name), &bytes, &err);
    }
    // Hostile rays: 3,000 a run at the default, through every backend.
    let ray_files = (cases / 100).max(3);
    let mut rays_run = 0;
    for f in 0..ray_files {
        let rays = hostile_rays(&mut rng, 1000);
        rays_run += rays.len();
        let bytes = raylab::measure::rayfile::encode(&[(RaySet::Random, rays)]);
        let backend = BACKENDS[f % BACKENDS.len()];
        let s = seed("hostile.rays", bytes.clone());
        let (outcome, err) = run_file_case(&work.join("rays"), &s, &bytes, backend);
        record(outcome, format!("{backend}-hostile.rays"), &bytes, &err);
    }
    std::fs::remove_dir_all(&work).ok();
    let n = |o| counts.get(&o).copied().unwrap_or(0);
    println!(
        "fuzz: {cases} mutants of {} seeds and {ray_files} files of {rays_run} hostile rays in {:.0} s: rendered {}, refused {}, panics {}, aborts {}, hangs {}, blowups {}, bad exits {}",
        seeds.len(),
        start.elapsed().as_secs_f64(),
        n(Outcome::Ok),
        n(Outcome::Refused),
        n(Outcome::Panic),
        n(Outcome::Abort),
        n(Outcome::Hang),
        n(Outcome::Blowup),
        n(Outcome::BadExit),
    );
    assert!(
        found.is_empty(),
        "{} findings:\n{}",
        found.len(),
        found.join("\n")
    );
}
