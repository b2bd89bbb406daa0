//! The `raylab` binary as a user runs it: results on stdout, one-line errors on
//! stderr, non-zero exit status on bad input, never a panic.

mod common;

use common::{
    assert_one_line_error, assert_one_line_error_naming, assert_success, embree_packets,
    own_packets, raylab, temp_dir,
};

#[test]
fn bad_flags_fail_with_one_line_naming_the_flag() {
    let d = temp_dir("flags");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    assert_one_line_error(&["render", "--size", "0x10", "-o", o], "--size");
    assert_one_line_error(&["render", "--size", "big", "-o", o], "--size");
    assert_one_line_error(&["render", "--fov", "0", "-o", o], "--fov");
    assert_one_line_error(&["render", "--fov", "180", "-o", o], "--fov");
    assert_one_line_error(&["render", "--fov", "-10", "-o", o], "--fov");
    assert_one_line_error(&["bench", "--fov", "-10", "--out", o], "--fov");
    assert_one_line_error(&["render", "--eye", "1,2", "-o", o], "--eye");
    assert_one_line_error(&["render", "--eye", "0,1,nan", "-o", o], "--eye");
    assert_one_line_error(&["render", "--eye", "-1,2", "-o", o], "--eye");
    assert_one_line_error(&["render", "--threads", "0", "-o", o], "--threads");
    assert_one_line_error(&["render", "--ao", "sometimes", "-o", o], "--ao");
    assert_one_line_error(&["render", "--ao-dist", "-1", "-o", o], "--ao-dist");
    assert_one_line_error(
        &["render", "--eye", "0,1,3", "--look", "0,1,3", "-o", o],
        "--look",
    );
    assert_one_line_error(&["render", "--backend", "magic", "-o", o], "--backend");
    assert_one_line_error(&["render", "--schedule", "chaos", "-o", o], "--schedule");
    // Backends by name: a bad one is named with the names there are.
    let names = "naive[-watertight], bvh|bvh4|bvh8-BUILDER";
    for (args, flag) in [
        (&["validate", "--against", "bvh-sahh"][..], "--against"),
        (
            &["validate", "--against", "bvh-sah-packet8"][..],
            "--against",
        ),
        (
            &["stress", "--backends", "bvh8-sah,magic"][..],
            "--backends",
        ),
        (
            &[
                "bench",
                "--variants",
                "naive-serial,magic-serial",
                "--quick",
            ][..],
            "--variants",
        ),
    ] {
        let bad = args[2].rsplit(',').next().unwrap();
        let needle = if bad.contains("packet8") {
            "no packet8 path"
        } else {
            names
        };
        assert_one_line_error_naming(args, &[flag, bad, needle]);
    }
    assert_one_line_error_naming(
        &["stats", "--builder", "sahh"],
        &["--builder", "sahh", "median, lbvh, sah, sbvh, embree-low"],
    );
    assert!(!std::path::Path::new(o).exists());
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn bad_scenes_fail_with_one_line_naming_the_file() {
    let d = temp_dir("scenes");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    assert_one_line_error(
        &["render", "/no/such/scene.obj", "-o", o],
        "/no/such/scene.obj",
    );
    assert_one_line_error(&["render", "cornell-nope", "-o", o], "cornell-nope");
    // The error lists every kind of scene the command takes.
    assert_one_line_error_naming(
        &["render", "nope", "-o", o],
        &[
            ".ply",
            ".glb",
            "cornell-water",
            "mesh:N",
            "grass:N",
            "city45:N",
        ],
    );
    let bad = d.join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n").unwrap();
    assert_one_line_error(&["render", bad.to_str().unwrap(), "-o", o], "bad.obj:3:");
    let empty = d.join("empty.obj");
    std::fs::write(&empty, "# nothing\n").unwrap();
    assert_one_line_error(&["render", empty.to_str().unwrap(), "-o", o], "no faces");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn unwritable_output_fails_before_rendering() {
    assert_one_line_error(
        &["render", "-o", "/no/such/dir/out.png"],
        "/no/such/dir/out.png",
    );
    assert_one_line_error(&["render", "-o", "out.jpg"], "PNG");
}

#[test]
fn json_report_has_the_stable_keys_and_matches_the_png() {
    let d = temp_dir("json");
    let o = d.join("cornell.png");
    let out = raylab(&[
        "render",
        "cornell-original",
        "--size",
        "40x30",
        "--schedule",
        "rayon",
        "--threads",
        "2",
        "--json",
        "-o",
        o.to_str().unwrap(),
    ]);
    assert_success(&out);
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("one JSON object on stdout");
    for key in [
        "scene",
        "triangles",
        "backend",
        "schedule",
        "threads",
        "width",
        "height",
        "load_ms",
        "build_ms",
        "render_ms",
        "rays",
        "output",
        "image_hash",
    ] {
        assert!(v.get(key).is_some(), "missing key {key} in {v}");
    }
    assert_eq!(v["triangles"], 36);
    // The default backend is raylab's fastest own one, not the naive scan,
    // on its fastest query path (16-ray packets with AVX-512, else 8).
    assert_eq!(v["backend"], format!("bvh8-sah-{}", own_packets()));
    assert_eq!(v["schedule"], "rayon");
    assert_eq!(v["width"], 40);
    assert_eq!(v["rays"]["primary"], 1200);
    assert!(v["rays"]["shadow"].as_u64().unwrap() > 0);
    assert!(v["rays"]["ao"].as_u64().unwrap() > 0);
    let png = image::open(&o).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (40, 30));
    assert_eq!(
        v["image_hash"],
        raylab::render::srgb::image_hash(png.as_raw())
    );

    // Negative coordinates are values, not flags.
    let out3 = raylab(&[
        "render",
        "cornell-empty",
        "--size",
        "8x6",
        "--eye",
        "-0.5,1,3",
        "-q",
        "-o",
        o.to_str().unwrap(),
    ]);
    assert_success(&out3);

    // The same image from another schedule: same hash.
    let out2 = raylab(&[
        "render",
        "cornell-original",
        "--size",
        "40x30",
        "--schedule",
        "rows",
        "--json",
        "-q",
        "-o",
        o.to_str().unwrap(),
    ]);
    let v2: serde_json::Value = serde_json::from_slice(&out2.stdout).unwrap();
    assert_eq!(v["image_hash"], v2["image_hash"]);
    assert!(
        out2.stderr.is_empty(),
        "--quiet printed: {}",
        String::from_utf8_lossy(&out2.stderr)
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn stress_quick_writes_its_report() {
    let d = temp_dir("stress");
    let out = raylab(&[
        "stress",
        "--quick",
        "--suite",
        "leaks",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_success(&out);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("| icosphere-320 |") && table.contains("naive-watertight"),
        "{table}"
    );
    for f in ["stress.md", "stress.json", "leaks.csv"] {
        assert!(d.join(f).is_file(), "{f} missing");
    }
    let csv = std::fs::read_to_string(d.join("leaks.csv")).unwrap();
    assert!(csv.lines().count() > 6 && csv.starts_with("mesh,triangles,backend"));
    assert_one_line_error(&["stress", "--suite", "everything"], "--suite");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn intersector_flag_selects_the_watertight_test() {
    let d = temp_dir("wt");
    let o = d.join("wt.png");
    let out = raylab(&[
        "render",
        "cornell-sphere",
        "--backend",
        "bvh",
        "--intersector",
        "watertight",
        "--size",
        "32x24",
        "--json",
        "-q",
        "-o",
        o.to_str().unwrap(),
    ]);
    assert_success(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // The default tree is the 8-wide one, the fastest, in packets.
    assert_eq!(
        v["backend"],
        format!("bvh8-sah-watertight-{}", own_packets())
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn scenes_lists_the_builtins() {
    let out = raylab(&["scenes"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for name in [
        "cornell-empty",
        "cornell-original",
        "cornell-sphere",
        "cornell-water",
    ] {
        assert!(text.contains(name));
    }
}

#[test]
fn validate_and_stats_say_what_they_do_on_stderr_unless_quiet() {
    for cmd in [
        &["validate", "cornell-empty", "--size", "16x12"][..],
        &["stats", "cornell-empty", "--builder", "sah", "--reps", "1"][..],
    ] {
        let loud = raylab(cmd);
        assert!(loud.status.success(), "{cmd:?}");
        let said = String::from_utf8_lossy(&loud.stderr);
        assert!(said.contains("cornell-empty"), "{cmd:?}: {said}");
        let quiet = raylab(&[cmd, &["-q"]].concat());
        assert!(quiet.status.success(), "{cmd:?} -q");
        assert!(quiet.stderr.is_empty(), "{cmd:?} -q: {quiet:?}");
        assert!(!quiet.stdout.is_empty(), "{cmd:?} -q still reports");
    }
}

#[test]
fn stats_report_the_wide_trees_beside_the_binary_one() {
    let out = raylab(&[
        "stats",
        "cornell-water",
        "--builder",
        "sah",
        "--size",
        "64x48",
        "--reps",
        "1",
        "--json",
    ]);
    assert_success(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let r = &v[0];
    let nodes = r["nodes"].as_u64().unwrap();
    for (key, width) in [("wide4", 4), ("wide8", 8)] {
        let w = &r[key];
        assert_eq!(w["width"], width);
        let wide_nodes = w["nodes"].as_u64().unwrap();
        // Collapsing N ways leaves at most about 1/(N-1) of the binary nodes.
        assert!(
            wide_nodes > 0 && wide_nodes * (width - 1) < nodes,
            "{key}: {wide_nodes} of {nodes}"
        );
        assert!(w["bytes_per_triangle"].as_f64().unwrap() > 0.0);
        // Blocks of four are mostly full: the SAH counts leaf tests by block.
        let fill = w["block_fill"].as_f64().unwrap();
        assert!(fill > 0.7 && fill <= 1.0, "{key}: fill {fill}");
        assert!(w["mean_leaf_size"].as_f64().unwrap() > r["mean_leaf_size"].as_f64().unwrap());
        for kind in ["primary", "shadow", "ao"] {
            let binary = r[kind]["nodes_per_ray"].as_f64().unwrap();
            let wide = w[kind]["nodes_per_ray"].as_f64().unwrap();
            assert!(
                wide > 0.0 && wide < binary,
                "{key} {kind}: {wide} vs {binary}"
            );
            assert_eq!(w[kind]["rays"], r[kind]["rays"]);
        }
    }
}

/// A unit cube, 8 vertices and 6 quads, wound outward, in ASCII PLY.
const CUBE_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n\
element face 6\nproperty list uchar int vertex_indices\nend_header\n\
0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n\
4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 1 2 6 5\n4 0 4 7 3\n";

/// Renders `scene` at 64x48 with --json; the parsed report.
fn render_json(
    scene: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> serde_json::Value {
    let mut args = vec![
        "render",
        scene.to_str().unwrap(),
        "--size",
        "64x48",
        "--json",
        "-q",
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    let o = raylab(&args);
    assert_success(&o);
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn files_that_are_not_boxes_are_framed_lit_and_shadowed() {
    let d = temp_dir("formats");
    // The cube far from the origin and small: the study's view would miss it.
    let far: String = CUBE_PLY
        .lines()
        .map(|l| {
            let w: Vec<f32> = l.split(' ').filter_map(|x| x.parse().ok()).collect();
            if w.len() == 3 && !l.starts_with('4') {
                format!(
                    "{} {} {}\n",
                    40.0 + w[0] * 0.01,
                    -7.0 + w[1] * 0.01,
                    12.0 + w[2] * 0.01
                )
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let ply = d.join("cube.ply");
    std::fs::write(&ply, far).unwrap();
    let v = render_json(&ply, &d.join("cube.png"), &[]);
    assert_eq!(v["triangles"], 12);
    let hits = v["rays"]["primary_hits"].as_u64().unwrap() as f64;
    assert!(
        hits / 3072.0 > 0.05,
        "the framed view sees the cube: {hits} of 3072"
    );
    // The default light casts shadow rays, and says so.
    assert!(v["rays"]["shadow"].as_u64().unwrap() > 0);
    let w = v["warnings"].to_string();
    assert!(w.contains("default area light"), "{w}");
    // The study's view, given explicitly, misses it, with a warning.
    let v = render_json(
        &ply,
        &d.join("miss.png"),
        &["--eye", "0,1,3", "--look", "0,1,0"],
    );
    assert_eq!(v["rays"]["primary_hits"], 0);
    assert!(
        v["warnings"].to_string().contains("under 1%"),
        "{}",
        v["warnings"]
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn gltf_with_an_embedded_buffer_renders_through_the_cli() {
    let d = temp_dir("gltf");
    // One triangle, its 3 positions in a base64 data URI.
    let mut bin = Vec::new();
    for x in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(x.to_le_bytes());
    }
    let b64 = common::base64_encode(&bin);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"scale":[2,2,2]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "buffers":[{{"uri":"data:application/octet-stream;base64,{b64}","byteLength":36}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}]}}"#
    );
    let path = d.join("tri.gltf");
    std::fs::write(&path, json).unwrap();
    let v = render_json(&path, &d.join("tri.png"), &[]);
    assert_eq!(v["triangles"], 1);
    assert!(v["rays"]["primary_hits"].as_u64().unwrap() > 100);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn files_raylab_does_not_read_get_one_line_naming_the_format() {
    let d = temp_dir("unread");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    let cases: [(&str, &[u8], &str); 6] = [
        ("part.stl", b"solid part\nfacet normal 0 0 1\n", "STL files are not read"),
        ("rig.fbx", b"Kaydara FBX Binary  \0\x1a\0", "FBX files are not read"),
        ("tool", b"\x7fELF\x02\x01\x01\0\0\0", "a binary file"),
        ("wide.obj", b"\xff\xfev\0 \x001\0", "UTF-16"),
        ("cloud.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n", "point cloud"),
        ("mesh.off", b"OFF\n3 1 0\n", "OFF files are not read"),
    ];
    for (name, bytes, needle) in cases {
        let path = d.join(name);
        std::fs::write(&path, bytes).unwrap();
        assert_one_line_error(&["render", path.to_str().unwrap(), "-o", o], needle);
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn flags_the_chosen_backend_would_ignore_are_refused() {
    let d = temp_dir("ignored");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    for (args, needle) in [
        (
            &["--backend", "embree", "--intersector", "watertight"][..],
            "--intersector",
        ),
        (
            &["--backend", "bvh", "--embree-robust"][..],
            "--embree-robust",
        ),
        (
            &["--backend", "bvh", "--embree-quality", "high"][..],
            "--embree-quality",
        ),
        (
            &["--backend", "naive", "--builder", "median"][..],
            "--builder",
        ),
        (
            &["--backend", "naive", "--bvh-width", "4"][..],
            "--bvh-width",
        ),
        (
            &["--backend", "embree", "--leaf-size", "2"][..],
            "--leaf-size",
        ),
        // Query paths a backend does not have.
        (&["--backend", "naive", "--query", "packet8"][..], "--query"),
        (&["--bvh-width", "4", "--query", "packet8"][..], "--query"),
        (&["--bvh-width", "2", "--query", "packet16"][..], "--query"),
        (&["--query", "stream"][..], "--query"),
        (&["--query", "sideways"][..], "--query"),
        // The quality ladder: for the BVH and Embree, instead of the flags
        // that name a builder or Embree's quality.
        (
            &["--backend", "naive", "--quality", "high"][..],
            "--quality",
        ),
        (&["--quality", "high", "--builder", "sah"][..], "--quality"),
        (
            &[
                "--backend",
                "embree",
                "--quality",
                "low",
                "--embree-quality",
                "high",
            ][..],
            "--quality",
        ),
        (&["--quality", "best"][..], "--quality"),
        (&["--backend", "embree", "--optimize"][..], "--optimize"),
    ] {
        let mut a = vec!["render", "cornell-empty", "--size", "8x6", "-o", o];
        a.extend(args);
        assert_one_line_error(&a, needle);
        a[0] = "validate";
        a.retain(|x| *x != "-o" && *x != o);
        assert_one_line_error(&a, needle);
    }
    // Flags that do apply are taken.
    let ok = raylab(&[
        "render",
        "cornell-empty",
        "--size",
        "8x6",
        "--backend",
        "naive",
        "--intersector",
        "watertight",
        "-q",
        "-o",
        o,
    ]);
    assert_success(&ok);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn an_output_path_that_is_a_directory_is_refused_before_any_work() {
    let d = temp_dir("outdir");
    let dir = d.join("render.png");
    std::fs::create_dir_all(&dir).unwrap();
    // The naive scan of a million triangles would take minutes: the refusal
    // must come first.
    let start = std::time::Instant::now();
    assert_one_line_error(
        &[
            "render",
            "mesh:1000000",
            "--backend",
            "naive",
            "-o",
            dir.to_str().unwrap(),
        ],
        "is a directory",
    );
    assert!(start.elapsed().as_secs() < 60);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn clap_errors_keep_their_suggestion_and_possible_values_on_one_line() {
    assert_one_line_error(&["rendr"], "similar subcommand exists: 'render'");
    assert_one_line_error(
        &["render", "--backend", "magic"],
        "possible values: naive, bvh, embree",
    );
    assert_one_line_error(&["bench", "--ao", "cosine:0", "--quick"], "--ao");
}

#[test]
fn a_closed_stdout_ends_the_process_quietly() {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args([
            "validate",
            "cornell-empty",
            "--count",
            "200",
            "--size",
            "16x12",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Close the reading end before raylab writes its table.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("internal error")
            && !err.contains("panicked")
            && !err.contains("Broken pipe"),
        "{err}"
    );
    use std::os::unix::process::ExitStatusExt;
    // Ended by SIGPIPE (as git and C tools are), or a clean exit.
    assert!(
        out.status.signal() == Some(13) || out.status.success(),
        "{:?}: {err}",
        out.status
    );
}

#[test]
fn blender_style_ka_zero_keeps_ambient_occlusion_visible() {
    // Blender's MTL writes Ka 0 0 0; the ambient term used to vanish with it, so
    // AO changed nothing in the image (the same hash at 5x the time).
    let d = temp_dir("blender-ka");
    std::fs::write(
        d.join("m.mtl"),
        "newmtl Material\nNs 225\nKa 0.000000 0.000000 0.000000\nKd 0.8 0.8 0.8\nKs 0.5 0.5 0.5\nKe 0 0 0\nillum 2\n",
    )
    .unwrap();
    let obj = d.join("cube.obj");
    std::fs::write(
        &obj,
        "mtllib m.mtl\no Cube\nv 1 1 -1\nv 1 -1 -1\nv 1 1 1\nv 1 -1 1\nv -1 1 -1\nv -1 -1 -1\nv -1 1 1\nv -1 -1 1\n\
         v -3 -1 -3\nv 3 -1 -3\nv 3 -1 3\nv -3 -1 3\nusemtl Material\ns off\n\
         f 1 5 7 3\nf 4 3 7 8\nf 8 7 5 6\nf 6 2 4 8\nf 2 1 3 4\nf 6 5 1 2\nf 9 12 11 10\n",
    )
    .unwrap();
    let hash = |ao: &str| {
        render_json(&obj, &d.join(format!("{ao}.png")), &["--ao", ao])["image_hash"].clone()
    };
    assert_ne!(hash("off"), hash("paper"), "AO must change the image");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn huge_and_far_triangles_render_lit_not_black() {
    // A model of size 1e10: its f32 normals overflowed to zero and it rendered
    // black; its default light's area overflowed too.
    let d = temp_dir("huge");
    let obj = d.join("big.obj");
    let s = 1e10f32;
    std::fs::write(
        &obj,
        format!("v 0 0 0\nv {s} 0 0\nv 0 {s} 0\nv 0 0 {s}\nf 1 2 3\nf 1 3 4\nf 1 4 2\n"),
    )
    .unwrap();
    let png = d.join("big.png");
    let v = render_json(&obj, &png, &["--ao", "off"]);
    assert_eq!(v["triangles"], 3, "{v}");
    assert!(v["rays"]["shadow"].as_u64().unwrap() > 0, "{v}");
    let img = image::open(&png).unwrap().to_rgb8();
    let lit = img
        .pixels()
        .filter(|p| p.0.iter().any(|&c| c > 120))
        .count();
    assert!(lit > 100, "only {lit} lit pixels");
    // Coordinates near 3e38 are no longer called degenerate; such a scene is
    // beyond what f32 rays can frame, and says so in one line.
    let vast = d.join("vast.obj");
    std::fs::write(
        &vast,
        "v -3e38 -3e38 0\nv 3e38 -3e38 0\nv -3e38 3e38 0\nf 1 2 3\n",
    )
    .unwrap();
    let scene = raylab::scene::load::load_file(&vast).unwrap();
    assert_eq!((scene.triangle_count(), scene.dropped_degenerate), (1, 0));
    let o = d.join("vast.png");
    assert_one_line_error(
        &["render", vast.to_str().unwrap(), "-o", o.to_str().unwrap()],
        "too large to frame",
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_light_from_the_command_line_replaces_the_default_one() {
    let d = temp_dir("light-flag");
    let obj = d.join("floor.obj");
    std::fs::write(
        &obj,
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 3 2\nf 1 4 3\n",
    )
    .unwrap();
    for light in ["point:0,2,0", "quad:0,2,0:0.5", "quad:0,2,0:0.5:40"] {
        let v = render_json(&obj, &d.join("l.png"), &["--light", light, "--ao", "off"]);
        assert!(v["rays"]["shadow"].as_u64().unwrap() > 0, "{light}: {v}");
        assert!(
            !v["warnings"].to_string().contains("default area light"),
            "{light}"
        );
    }
    // A light under the floor: the side the camera sees faces away from it, so
    // no shadow ray is cast.
    let v = render_json(&obj, &d.join("under.png"), &["--light", "quad:0,-1,0:0.5"]);
    assert_eq!(v["rays"]["shadow"], 0, "{v}");
    assert_one_line_error(
        &["render", obj.to_str().unwrap(), "--light", "spot:0,1,0"],
        "--light",
    );
    // A quad faces down --up: over a Z-up floor it lights every point the
    // camera sees (one shadow ray each), as over the Y-up one.
    let zup = d.join("floor-z.obj");
    std::fs::write(
        &zup,
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n",
    )
    .unwrap();
    for (file, up, light) in [
        (&obj, "0,1,0", "quad:0,2,0:0.5"),
        (&zup, "0,0,1", "quad:0,0,2:0.5"),
    ] {
        let v = render_json(
            file,
            &d.join("up.png"),
            &["--up", up, "--light", light, "--ao", "off"],
        );
        assert_eq!(v["rays"]["shadow"], v["rays"]["primary_hits"], "{up}: {v}");
        assert!(v["rays"]["primary_hits"].as_u64().unwrap() > 0);
    }
    std::fs::remove_dir_all(&d).ok();
}

/// raylab's query paths render the image its single-ray path renders, and
/// the report names the path.
#[test]
fn query_paths_render_the_same_image_and_are_named() {
    let d = temp_dir("query");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    let render = |args: &[&str]| {
        let mut a = vec![
            "render",
            "cornell-sphere",
            "--size",
            "48x36",
            "--ao",
            "cosine:3",
            "--json",
            "-q",
            "-o",
            o,
        ];
        a.extend(args);
        let out = raylab(&a);
        assert_success(&out);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        (
            v["backend"].as_str().unwrap().to_string(),
            v["image_hash"].clone(),
        )
    };
    let (name, single) = render(&["--query", "single"]);
    assert_eq!(name, "bvh8-sah");
    let (name, packet) = render(&["--query", "packet8"]);
    assert_eq!(name, "bvh8-sah-packet8");
    assert_eq!(packet, single);
    let (name, packet16) = render(&["--query", "packet16"]);
    assert_eq!(name, "bvh8-sah-packet16");
    assert_eq!(packet16, single);
    let (name, binary) = render(&["--bvh-width", "2"]);
    assert_eq!(
        name, "bvh-sah",
        "the binary tree's default path is single rays"
    );
    assert_eq!(binary, single);
    // Embree's packet kernels break shared-edge ties differently from its
    // single-ray kernel, so only the names are checked for Embree.
    if raylab::accel::embree::AVAILABLE {
        for q in ["packet4", "packet8", "packet16"] {
            let (name, _) = render(&["--backend", "embree", "--query", q]);
            assert_eq!(name, format!("embree-medium-{q}"));
        }
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn quality_rungs_name_their_builders_and_render_the_same_image() {
    let d = temp_dir("quality");
    let o = d.join("x.png");
    let render = |scene: &str, args: &[&str]| {
        let v = render_json(std::path::Path::new(scene), &o, args);
        (
            v["backend"].as_str().unwrap().to_string(),
            v["image_hash"].clone(),
        )
    };
    // Long thin blades: the SBVH splits them, and must find the same hits.
    for scene in ["cornell-water", "grass:3000"] {
        let (name, medium) = render(scene, &[]);
        let own = own_packets();
        assert_eq!(name, format!("bvh8-sah-{own}"));
        for (rung, builder) in [("low", "lbvh"), ("medium", "sah"), ("high", "sbvh")] {
            let (name, image) = render(scene, &["--quality", rung]);
            let opt = if rung == "high" { "-opt" } else { "" };
            assert_eq!(name, format!("bvh8-{builder}{opt}-{own}"), "{scene}");
            assert_eq!(image, medium, "{scene}: --quality {rung}");
            let (name, image) = render(scene, &["--builder", builder, "--bvh-width", "2"]);
            assert_eq!(name, format!("bvh-{builder}"), "{scene}");
            assert_eq!(image, medium, "{scene}: binary {builder}");
            let (name, image) = render(scene, &["--builder", builder, "--optimize"]);
            assert_eq!(name, format!("bvh8-{builder}-opt-{own}"), "{scene}");
            assert_eq!(image, medium, "{scene}: optimised {builder}");
        }
    }
    if raylab::accel::embree::AVAILABLE {
        let (name, _) = render(
            "cornell-empty",
            &["--backend", "embree", "--quality", "high"],
        );
        assert_eq!(name, format!("embree-high-{}", embree_packets()));
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn validate_judges_the_secondary_ray_origins_of_a_flat_field() {
    for against in ["naive", "exact"] {
        let out = raylab(&[
            "validate",
            "plane:2000",
            "--against",
            against,
            "--size",
            "48x36",
            "--count",
            "300",
            "--json",
        ]);
        assert_success(&out);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let spawns = &v[0]["spawns"];
        assert!(spawns["surfaces"].as_u64().unwrap() > 300, "{spawns}");
        assert_eq!(spawns["behind"].as_u64(), Some(0), "{spawns}");
    }
}

/// Node boxes far from the origin are not swollen by a margin proportional to
/// the coordinates: `far:2000` is `mesh:2000` moved to about 1e5, and its
/// binary tree's shadow rays test 1.05x the triangles of the mesh at the
/// origin (2026-12-05). With a margin of one ulp of the coordinates they
/// tested 2.3x, with two ulps 3.4x, and the traversal took 1.4-1.6x and
/// 1.9-2.3x Embree's time per ray kind on far:20000.
#[test]
fn boxes_far_from_the_origin_stay_tight() {
    // Triangles tested per shadow ray: the binary tree's, and the 8-wide
    // tree's through the single-ray walk a render takes (whose fused node
    // test, taken 1e5 from the origin, grew far:2000's boxes by 12 ulps of
    // their coordinates: 3.7x mesh:2000's triangles, 1.7x without it).
    let shadow_triangles = |scene: &str| {
        let out = raylab(&[
            "stats",
            scene,
            "--builder",
            "sah",
            "--size",
            "128x96",
            "--reps",
            "1",
            "--json",
            "-q",
        ]);
        assert_success(&out);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let per_ray = |v: &serde_json::Value| v["shadow"]["triangles_per_ray"].as_f64().unwrap();
        (per_ray(&v[0]), per_ray(&v[0]["wide8"]))
    };
    let (far, near) = (shadow_triangles("far:2000"), shadow_triangles("mesh:2000"));
    assert!(
        far.0 < 1.5 * near.0,
        "binary tree: far {} vs near {} triangles per shadow ray",
        far.0,
        near.0
    );
    assert!(
        far.1 < 2.5 * near.1,
        "8-wide tree: far {} vs near {} triangles per shadow ray",
        far.1,
        near.1
    );
}

#[test]
fn the_cliff_finder_runs_the_libraries_part_only() {
    assert_one_line_error(
        &["bench", "--cliffs", "--parts", "trace"],
        "--cliffs: the cliff finder runs the libraries part only",
    );
    assert_one_line_error(&["bench", "--cliffs", "--rays", "x.rays"], "--cliffs");
}
