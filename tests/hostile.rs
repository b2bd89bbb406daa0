//! Hostile files, flags and rays through the `raylab` binary (issue 41): each
//! case is its minimal file, and each must end in one line on stderr and exit
//! 1 (2 for flags), never a panic (101) or an abort (a signal).

mod common;

use std::path::{Path, PathBuf};

use base64::Engine;
use common::{raylab, temp_dir};

/// Runs `raylab render FILE --size 16x12` and asserts a one-line error with
/// exit 1 holding every one of `needles`.
fn assert_refused(file: &Path, needles: &[&str]) {
    let (out, err) = render_16x12(file, &[]);
    assert_eq!(out.status.code(), Some(1), "{}: {err}", file.display());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    for n in needles {
        assert!(err.contains(n), "expected '{n}' in: {err}");
    }
    assert!(!file.with_extension("png").exists());
}

/// Renders `file` at 16x12 into `file` with the extension `png`, with the
/// `extra` flags: the run and its stderr.
fn render_16x12(file: &Path, extra: &[&str]) -> (std::process::Output, String) {
    let png = file.with_extension("png");
    let mut args = vec![
        "render",
        file.to_str().unwrap(),
        "--size",
        "16x12",
        "-o",
        png.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = raylab(&args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, err)
}

/// Writes `text` to `name` in `dir`.
fn write(dir: &Path, name: &str, text: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// A one-triangle glTF (three f32 positions, three u16 indices, embedded as
/// base64) with `edit` applied to its JSON.
fn triangle_gltf(edit: impl Fn(String) -> String) -> String {
    let mut bin = Vec::new();
    for x in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(x.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        bin.extend(i.to_le_bytes());
    }
    let data = base64::engine::general_purpose::STANDARD.encode(&bin);
    edit(format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"uri":"data:application/octet-stream;base64,{data}","byteLength":44}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":8}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}]}}"#
    ))
}

#[test]
fn the_most_negative_obj_index_is_refused() {
    let d = temp_dir("hostile-obj-index");
    let f = write(
        &d,
        "min.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n",
    );
    assert_refused(&f, &["min.obj:4:", "before the first vertex"]);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn gltf_that_the_gltf_crate_would_panic_on_is_refused() {
    let d = temp_dir("hostile-gltf");
    // A UTF-8 byte order mark before the JSON is read past.
    for (name, text) in [
        ("ok.gltf", triangle_gltf(|j| j)),
        ("bom.gltf", format!("\u{feff}{}", triangle_gltf(|j| j))),
    ] {
        let (out, err) = render_16x12(&write(&d, name, text), &[]);
        assert!(out.status.success(), "{name}: {err}");
    }
    for (name, from, to, needle) in [
        (
            "float-index.gltf",
            r#""componentType":5123,"count":3"#,
            r#""componentType":5126,"count":2"#,
            "index accessor 1 is F32",
        ),
        (
            "signed-index.gltf",
            r#""componentType":5123"#,
            r#""componentType":5122"#,
            "index accessor 1 is I16",
        ),
        (
            "stride.gltf",
            r#""byteLength":36}"#,
            r#""byteLength":36,"byteStride":4}"#,
            "byteStride 4, smaller than its 12-byte elements",
        ),
        (
            "position-past.gltf",
            r#""POSITION":0"#,
            r#""POSITION":7"#,
            "names accessor 7, the file has 2",
        ),
        (
            "shared-child.gltf",
            r#""nodes":[{"mesh":0}]"#,
            r#""nodes":[{"mesh":0},{"children":[0]},{"children":[0]}]"#,
            "glTF node graphs must be trees",
        ),
        (
            "animated-node-past.gltf",
            r#""scenes""#,
            r#""animations":[{"samplers":[{"input":1,"output":0}],"channels":[{"sampler":0,"target":{"node":50,"path":"translation"}}]}],"scenes""#,
            "animation 0 channel 0 targets node 50, the file has 1",
        ),
        (
            "negative-colour.gltf",
            r#""indices":1}]}],"#,
            r#""indices":1,"material":0}]}],"materials":[{"pbrMetallicRoughness":{"baseColorFactor":[1,-1,1,1]}}],"#,
            "must be finite and non-negative",
        ),
        (
            "meshopt.gltf",
            r#""scenes""#,
            r#""extensionsRequired":["EXT_meshopt_compression","KHR_mesh_quantization"],"scenes""#,
            "does not read: EXT_meshopt_compression (Draco- or meshopt-compressed",
        ),
    ] {
        let f = write(
            &d,
            name,
            triangle_gltf(|j| {
                assert!(j.contains(from), "{from}");
                j.replacen(from, to, 1)
            }),
        );
        assert_refused(&f, &[name, needle]);
    }
    std::fs::remove_dir_all(&d).ok();
}

/// A glTF file with animations raylab cannot follow is refused by the
/// `animation` bench part, which once took it for a scene that does not move
/// and timed the built-in animations in its place (exit 0).
#[test]
fn bench_refuses_an_animated_file_it_cannot_follow() {
    let d = temp_dir("hostile-bench-animation");
    // Keyframe times 0, 0 (the first two position floats): not increasing.
    let f = write(
        &d,
        "still.gltf",
        triangle_gltf(|j| {
            let j = j.replacen(
                r#"{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}]"#,
                r#"{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"},
                   {"bufferView":0,"componentType":5126,"count":2,"type":"SCALAR"},
                   {"bufferView":0,"componentType":5126,"count":2,"type":"VEC3"}]"#,
                1,
            );
            j.replacen(
                r#""scenes""#,
                r#""animations":[{"samplers":[{"input":2,"output":3}],"channels":[{"sampler":0,"target":{"node":0,"path":"translation"}}]}],"scenes""#,
                1,
            )
        }),
    );
    let out = d.join("report");
    common::assert_one_line_error_naming(
        &[
            "bench",
            f.to_str().unwrap(),
            "--quick",
            "--parts",
            "animation",
            "--threads",
            "1",
            "--out",
            out.to_str().unwrap(),
            "-q",
        ],
        &["still.gltf", "strictly increasing"],
    );
    std::fs::remove_dir_all(&d).ok();
}

/// Memory that runs out (here under `ulimit -v`; on a machine, a scene or
/// image within the budgets but past its memory) ends raylab with one line
/// and exit status 1, not Rust's abort (SIGABRT and a backtrace), and
/// writes no image.
#[cfg(target_os = "linux")]
#[test]
fn running_out_of_memory_is_one_line_not_an_abort() {
    let d = temp_dir("hostile-oom");
    let png = d.join("big.png");
    // 8000x6000 pixels need about 1.2 GB of image buffers, past 400 MB.
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg(r#"ulimit -v 400000 && exec "$0" render cornell-empty --size 8000x6000 -q -o "$1""#)
        .arg(env!("CARGO_BIN_EXE_raylab"))
        .arg(&png)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("raylab: out of memory:") && err.contains("--max-pixels"),
        "{err}"
    );
    assert!(!png.exists());
    std::fs::remove_dir_all(&d).ok();
}

/// A plain chain of nodes is a legal tree however deep: 300 levels load
/// (256 were once refused as "a cycle?"), and past raylab's limit the
/// refusal says it is a limit.
#[test]
fn deep_node_chains_load_up_to_a_stated_limit() {
    let d = temp_dir("hostile-deep");
    let chain = |n: usize| {
        let mut nodes: Vec<String> = (1..n).map(|c| format!(r#"{{"children":[{c}]}}"#)).collect();
        nodes.push(r#"{"mesh":0}"#.into());
        format!(r#""nodes":[{}]"#, nodes.join(","))
    };
    let deep = |n: usize| triangle_gltf(|j| j.replacen(r#""nodes":[{"mesh":0}]"#, &chain(n), 1));
    let (out, err) = render_16x12(&write(&d, "chain300.gltf", deep(300)), &[]);
    assert!(out.status.success(), "{err}");
    let refused = write(&d, "chain5000.gltf", deep(5000));
    assert_refused(
        &refused,
        &["chain5000.gltf", "levels deep, past raylab's limit"],
    );
    std::fs::remove_dir_all(&d).ok();
}

/// A `TRIANGLES` primitive whose index count is not a multiple of 3 (the
/// format forbids it) renders its whole triangles, with a warning that the
/// rest was dropped.
#[test]
fn a_partial_triangle_is_dropped_with_a_warning() {
    let d = temp_dir("hostile-partial");
    let f = write(
        &d,
        "four.gltf",
        triangle_gltf(|j| {
            j.replacen(
                r#""componentType":5123,"count":3"#,
                r#""componentType":5123,"count":4"#,
                1,
            )
        }),
    );
    let (out, err) = render_16x12(&f, &[]);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains(
            "four.gltf: 1 triangle primitives have an index count that is not a multiple of 3"
        ),
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// Rays no backend may crash on: non-finite, zero directions, tmin past
/// tmax, denormals, and finite coordinates past Embree's limit or whose move
/// to tmin overflows f32 (for the libraries without tmin). Each with whether
/// it must be a miss everywhere (it is not a valid ray).
fn hostile_rays() -> Vec<(raylab::geometry::Ray, bool)> {
    use glam::Vec3;
    use raylab::geometry::Ray;
    let ray = |o: Vec3, d: Vec3, tmin: f32, tmax: f32| Ray {
        origin: o,
        dir: d,
        tmin,
        tmax,
    };
    let (eye, down) = (Vec3::new(0.0, 1.0, 3.0), Vec3::new(0.0, 0.0, -1.0));
    let inf = f32::INFINITY;
    let big = 3e38f32;
    vec![
        (ray(Vec3::new(f32::NAN, 1.0, 3.0), down, 0.0, inf), true),
        (ray(eye, Vec3::new(0.0, f32::NAN, -1.0), 0.0, inf), true),
        (ray(Vec3::new(inf, 1.0, 3.0), down, 0.0, inf), true),
        (ray(eye, Vec3::new(-inf, 0.0, -1.0), 0.0, inf), true),
        (ray(eye, Vec3::ZERO, 0.0, inf), true),
        (ray(eye, down, 2.0, 1.0), true),
        (ray(eye, down, f32::NAN, inf), true),
        (ray(eye, down, 0.0, f32::NAN), true),
        (ray(eye, down, -1.0, inf), true),
        // Valid rays the libraries must survive, hit or miss.
        (
            ray(
                Vec3::new(2e18, 1.0, 3.0),
                Vec3::new(-1.0, 0.0, -1e-18),
                0.0,
                inf,
            ),
            false,
        ),
        (
            ray(
                Vec3::new(-big, big, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                0.0,
                inf,
            ),
            false,
        ),
        (ray(eye, Vec3::new(big, -big, -big), 0.0, inf), false),
        (ray(eye, Vec3::new(big, big, -big), 10.0, inf), false),
        (ray(eye, Vec3::new(1e-40, 1e-40, -1e-40), 0.0, inf), false),
        (ray(eye, down, 1e-45, 1e-44), false),
        (ray(eye, down, 0.0, f32::MAX), false),
        (
            ray(Vec3::splat(1e-42), Vec3::new(1e-42, 1.0, -1e-42), 0.0, inf),
            false,
        ),
    ]
}

#[test]
fn hostile_rays_through_every_backend_are_answered() {
    use raylab::accel::library::{Library, ObvhsLayout};
    use raylab::accel::{build_backend, BackendSpec, Query};
    let scene = raylab::scene::builtin::builtin("cornell-original").unwrap();
    let mut specs = vec![
        BackendSpec::naive(),
        BackendSpec::bvh(raylab::accel::bvh::BuildParams::sah().with_width(8)),
        BackendSpec::bvh(raylab::accel::bvh::BuildParams::sah())
            .with_intersector(raylab::geometry::Intersector::Watertight),
    ];
    for library in Library::ALL.into_iter().filter(Library::available) {
        specs.push(BackendSpec::library(library, 2));
    }
    specs.push(BackendSpec::library(
        Library::Obvhs {
            layout: ObvhsLayout::Bvh2,
            quality: raylab::accel::embree::Quality::High,
        },
        2,
    ));
    if cfg!(feature = "embree") {
        for q in Query::ALL {
            if let Ok(s) = BackendSpec::embree(2).with_query(q) {
                specs.push(s);
            }
        }
    }
    let rays = hostile_rays();
    let all: Vec<_> = rays.iter().map(|(r, _)| *r).collect();
    for spec in specs {
        let name = spec.name();
        let built = build_backend(&spec, &scene).unwrap();
        let b = &built.backend;
        let mut hits = vec![None; all.len()];
        let mut occluded = vec![false; all.len()];
        b.intersect_stream(&all, &mut hits);
        b.occluded_stream(&all, &mut occluded);
        for (i, (ray, must_miss)) in rays.iter().enumerate() {
            let (hit, occ) = (b.intersect(ray), b.occluded(ray));
            if *must_miss {
                assert!(hit.is_none() && !occ, "{name}: ray {i} {ray:?}");
                assert!(hits[i].is_none() && !occluded[i], "{name} stream: ray {i}");
            }
            if let Some(h) = hit {
                assert!(h.t.is_finite() && h.t >= ray.tmin, "{name}: ray {i}: {h:?}");
            }
            let past_limit =
                ray.origin.abs().max_element() > 1.844e18 || ray.dir.abs().max_element() > 1.844e18;
            if (spec.is_embree() || name.starts_with("tinybvh")) && past_limit {
                assert!(
                    hit.is_none() && !occ,
                    "{name}: ray {i} past the library's limit"
                );
            }
        }
    }
}

#[test]
fn an_eye_past_embrees_limit_renders_without_aborting() {
    let d = temp_dir("hostile-eye");
    let png = d.join("far.png");
    for backend in ["embree", "tinybvh", "obvhs", "bvh-crate", "bvh"] {
        let out = raylab(&[
            "render",
            "--backend",
            backend,
            "--eye",
            "2e18,1,3",
            "--size",
            "16x12",
            "-o",
            png.to_str().unwrap(),
        ]);
        let code = out.status.code();
        let err = String::from_utf8_lossy(&out.stderr);
        // 0, or 1 where this raylab lacks the backend's feature.
        assert!(
            code == Some(0) || code == Some(1),
            "{backend}: {code:?} {err}"
        );
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn budgets_are_checked_before_allocating_and_name_their_flag() {
    let d = temp_dir("hostile-budgets");
    let png = d.join("x.png");
    let png = png.to_str().unwrap();
    // 6.4 GB of image buffers.
    common::assert_one_line_error_naming(
        &["render", "--size", "16384x16384", "-o", png],
        &["--size", "268435456 pixels", "--max-pixels"],
    );
    let out = raylab(&[
        "render",
        "--size",
        "16x12",
        "--max-pixels",
        "100",
        "-o",
        png,
    ]);
    // A flag's value over its budget is a usage error: exit 2, as every
    // refused flag.
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("over the budget of 100"));
    let bad = raylab(&["render", "--max-pixels", "0", "-o", png]);
    assert_eq!(bad.status.code(), Some(2));
    // Triangles: OBJ faces as they are read, glTF instances before reading.
    let obj = write(
        &d,
        "quads.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf 1 2 3 4\n",
    );
    let out = raylab(&[
        "render",
        obj.to_str().unwrap(),
        "--max-triangles",
        "3",
        "-o",
        png,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("quads.obj:6: expands to 4 triangles, over the budget of 3 (raise it with --max-triangles)"), "{err}");
    let gltf = write(
        &d,
        "inst.gltf",
        triangle_gltf(|j| {
            j.replace(
                r#""nodes":[{"mesh":0}]"#,
                r#""nodes":[{"mesh":0},{"mesh":0}]"#,
            )
            .replace(r#""nodes":[0]"#, r#""nodes":[0,1]"#)
        }),
    );
    // Placed twice, the mesh is stored once (an instanced scene): within
    // a budget of 1; flattened, it expands to 2.
    let out = raylab(&[
        "render",
        gltf.to_str().unwrap(),
        "--max-triangles",
        "1",
        "--flatten",
        "-o",
        png,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("expands to 2 triangles") && err.contains("--max-triangles"),
        "{err}"
    );
    let out = raylab(&[
        "render",
        gltf.to_str().unwrap(),
        "--max-triangles",
        "1",
        "--size",
        "16x12",
        "-o",
        png,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = raylab(&[
        "render",
        gltf.to_str().unwrap(),
        "--max-triangles",
        "2",
        "--size",
        "16x12",
        "-o",
        png,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Instances are budgeted too: 1001 placements of the triangle, past
    // the least any budget allows (1000), are refused before any is made.
    let nodes = vec![r#"{"mesh":0}"#; 1001].join(",");
    let roots = (0..1001)
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(",");
    let many = write(
        &d,
        "many.gltf",
        triangle_gltf(|j| {
            j.replace(r#""nodes":[{"mesh":0}]"#, &format!(r#""nodes":[{nodes}]"#))
                .replace(r#""nodes":[0]"#, &format!(r#""nodes":[{roots}]"#))
        }),
    );
    let out = raylab(&[
        "render",
        many.to_str().unwrap(),
        "--max-triangles",
        "100",
        "-o",
        png,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("places 1001 instances, over the budget of 1000")
            && err.contains("--max-triangles"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn blender_279_mtl_loads_with_one_warning() {
    let d = temp_dir("hostile-ns");
    write(&d, "b.mtl", "newmtl skin\nNs -1.960784\nKd 0.8 0.6 0.5\n");
    let obj = write(
        &d,
        "b.obj",
        "mtllib b.mtl\nusemtl skin\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let (out, err) = render_16x12(&obj, &[]);
    assert!(out.status.success(), "{err}");
    assert_eq!(
        err.lines()
            .filter(|l| l.contains("'Ns' -1.960784 is negative; read as 0"))
            .count(),
        1,
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn obvhs_refuses_a_chain_of_identical_triangles_in_one_line() {
    let d = temp_dir("hostile-obvhs");
    let obj = write(
        &d,
        "same.obj",
        // 5,000 make a chain as deep as 25,000 did (which overflowed the
        // stack) past the limit, in a fifth of the build time.
        "v 0 0 0\nv 1 0 0\nv 0 1 0\n".to_string() + &"f 1 2 3\n".repeat(5_000),
    );
    let (out, err) = render_16x12(&obj, &["--backend", "obvhs"]);
    if err.contains("built without") {
        return;
    }
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.trim_end()
            .lines()
            .last()
            .unwrap()
            .contains("obvhs: its binary tree is")
            && err.contains("--layout bvh2"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// The Cornell-like box of `tests/cli.rs`'s scenes scaled by `s`.
fn scaled_box(s: f32) -> String {
    let mut text = String::new();
    for v in [
        [-1.0f32, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 2.0, -1.0],
        [-1.0, 2.0, -1.0],
        [-1.0, 0.0, 1.0],
        [1.0, 0.0, 1.0],
    ] {
        text += &format!("v {} {} {}\n", v[0] * s, v[1] * s, v[2] * s);
    }
    text + "f 1 2 3 4\nf 1 5 6 2\n"
}

#[test]
fn scenes_too_large_or_too_small_for_f32_rays_are_refused_not_black() {
    let d = temp_dir("hostile-scale");
    for (s, needle) in [
        (1e13f32, "too large to frame and trace with f32 rays"),
        (1e-20, "too small to frame and trace with f32 rays"),
        // Was "--look: look-at point equals the eye", with no --look given.
        (1e-30, "too small to frame and trace with f32 rays"),
    ] {
        let f = write(&d, &format!("box{s:e}.obj"), scaled_box(s));
        assert_refused(&f, &[needle, "scale the scene"]);
        let out = raylab(&["validate", f.to_str().unwrap(), "--size", "16x12"]);
        assert_eq!(out.status.code(), Some(1));
        assert!(String::from_utf8_lossy(&out.stderr).contains(needle));
    }
    // Within the range, both ends render lit.
    for s in [1e12f32, 1e-9] {
        let f = write(&d, &format!("ok{s:e}.obj"), scaled_box(s));
        let png = d.join(format!("ok{s:e}.png"));
        let out = raylab(&[
            "render",
            f.to_str().unwrap(),
            "--size",
            "32x24",
            "-o",
            png.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{s}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = image::open(&png).unwrap().to_rgb8();
        let lit = img.pixels().filter(|p| p.0.iter().any(|&c| c > 20)).count();
        assert!(lit > 50, "{s}: only {lit} lit pixels");
    }
    std::fs::remove_dir_all(&d).ok();
}
