//! Issue 41 as a user and an attacker meet it: a scene's references stay in
//! its folder, output writes fail in one line and never follow a planted
//! link, a closed stderr does not stop a render, and flags that another flag
//! makes meaningless are refused (exit 2).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use common::{assert_success, raylab, temp_dir};

/// Asserts a run that fails with exit status `code` and one line on stderr
/// holding every one of `needles`; returns that line.
fn assert_fails(args: &[&str], code: i32, needles: &[&str]) -> String {
    let out = raylab(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(
        !err.contains("panicked") && !err.contains("internal error"),
        "{err}"
    );
    for needle in needles {
        assert!(
            err.contains(needle),
            "{args:?}: expected '{needle}' in: {err}"
        );
    }
    err
}

/// One triangle's three positions (36 bytes), then 3 u16 indices of which the
/// last is 0x4142 (out of range), and 2 bytes of padding.
fn triangle_bin() -> Vec<u8> {
    let mut bin = Vec::new();
    for x in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(x.to_le_bytes());
    }
    for i in [0u16, 1, 0x4142, 0] {
        bin.extend(i.to_le_bytes());
    }
    bin
}

/// A glTF of one triangle whose buffer is `uri` (`"byteLength"` 44); with
/// `indexed`, the primitive reads the out-of-range index buffer.
fn gltf_json(uri: &str, indexed: bool) -> String {
    let indices = if indexed { r#","indices":1"# } else { "" };
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}{indices}}}]}}],
        "buffers":[{{"uri":"{uri}","byteLength":44}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}]}}"#
    )
}

/// `root/scene/` (where scenes are written) beside `root/private/secret.bin`
/// (a valid buffer, so that only the folder rule can refuse it).
fn folders(tag: &str) -> (PathBuf, PathBuf) {
    let root = temp_dir(tag);
    std::fs::create_dir_all(root.join("scene/sub")).unwrap();
    std::fs::create_dir_all(root.join("private")).unwrap();
    std::fs::write(root.join("private/secret.bin"), triangle_bin()).unwrap();
    (root.join("scene"), root)
}

fn write_gltf(dir: &Path, name: &str, uri: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, gltf_json(uri, false)).unwrap();
    path.to_str().unwrap().to_string()
}

#[test]
fn gltf_buffers_outside_the_scene_folder_are_refused() {
    let (scene, root) = folders("refs-gltf");
    let o = root.join("x.png");
    let o = o.to_str().unwrap();
    let secret = root.join("private/secret.bin");
    std::os::unix::fs::symlink(&secret, scene.join("link.bin")).unwrap();
    std::os::unix::fs::symlink(root.join("private"), scene.join("sub/up")).unwrap();
    let absolute = secret.to_str().unwrap().to_string();
    for (uri, why) in [
        ("../private/secret.bin", "climbs out of the scene's folder"),
        (
            "sub/../../private/secret.bin",
            "climbs out of the scene's folder",
        ),
        (
            "%2e%2e%2fprivate%2fsecret.bin",
            "climbs out of the scene's folder",
        ),
        (
            "..%2F..%2F..%2F..%2F..%2Fetc%2Fpasswd",
            "climbs out of the scene's folder",
        ),
        (&absolute, "an absolute path"),
        ("/dev/zero", "an absolute path"),
        ("link.bin", "a symbolic link out of the scene's folder"),
        (
            "sub/up/secret.bin",
            "a symbolic link out of the scene's folder",
        ),
        (
            "sub/up/not-there.bin",
            "a symbolic link out of the scene's folder",
        ),
    ] {
        let path = write_gltf(&scene, "hostile.gltf", uri);
        let err = assert_fails(
            &["render", &path, "-o", o],
            1,
            &["hostile.gltf", "buffer 0", uri, why, "--allow-outside-refs"],
        );
        assert!(!err.contains("index 16706"), "{err}");
    }
    // Asked for, the same references are read.
    for uri in ["../private/secret.bin", &absolute, "link.bin"] {
        let path = write_gltf(&scene, "allowed.gltf", uri);
        let out = raylab(&[
            "render",
            &path,
            "--allow-outside-refs",
            "--size",
            "16x12",
            "-q",
            "-o",
            o,
        ]);
        assert_success(&out);
    }
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn only_regular_files_are_read_as_buffers_even_when_allowed() {
    let (scene, root) = folders("refs-special");
    let o = root.join("x.png");
    let o = o.to_str().unwrap();
    let fifo = scene.join("pipe.bin");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    for (uri, allow, kind) in [
        ("pipe.bin", false, "a FIFO, not a regular file"),
        ("sub", false, "a folder, not a regular file"),
        ("/dev/zero", true, "a device, not a regular file"),
        ("/dev/null", true, "a device, not a regular file"),
    ] {
        let path = write_gltf(&scene, "special.gltf", uri);
        let mut args = vec!["render", &path, "-o", o];
        if allow {
            args.push("--allow-outside-refs");
        }
        // A FIFO opened for reading would hang here: the run must end.
        assert_fails(&args, 1, &["special.gltf", "buffer 0", kind]);
    }
    // A file shorter than its byteLength: said without the file's own length.
    std::fs::write(scene.join("short.bin"), [0u8; 10]).unwrap();
    let path = write_gltf(&scene, "short.gltf", "short.bin");
    let err = assert_fails(
        &["render", &path, "-o", o],
        1,
        &["shorter than the 44 bytes"],
    );
    assert!(!err.contains(" 10 ") && !err.contains("has 10"), "{err}");
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn index_values_from_an_outside_buffer_are_not_shown() {
    let (scene, root) = folders("refs-index");
    let o = root.join("x.png");
    let o = o.to_str().unwrap();
    let path = scene.join("index.gltf");
    std::fs::write(&path, gltf_json("../private/secret.bin", true)).unwrap();
    let path = path.to_str().unwrap();
    let err = assert_fails(
        &["render", path, "--allow-outside-refs", "-o", o],
        1,
        &["accessor 1: mesh primitive index out of range (3 vertices)"],
    );
    assert!(
        !err.contains("index 16706"),
        "the index value leaked: {err}"
    );
    // The scene's own buffer (a data URI): its value helps and is shown.
    let b64 = common::base64_encode(&triangle_bin());
    let own = gltf_json(&format!("data:application/octet-stream;base64,{b64}"), true);
    std::fs::write(scene.join("own.gltf"), own).unwrap();
    let own = scene.join("own.gltf");
    assert_fails(
        &["render", own.to_str().unwrap(), "-o", o],
        1,
        &["accessor 1: mesh primitive index 16706 out of range"],
    );
    std::fs::remove_dir_all(&root).ok();
}

const BOX_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf 1 2 3 4\n";
const RED_MTL: &str = "newmtl red\nKd 0.8 0.1 0.1\n";

#[test]
fn mtllib_stays_in_the_scene_folder() {
    let (scene, root) = folders("refs-obj");
    let o = root.join("x.png");
    let o = o.to_str().unwrap();
    std::fs::write(root.join("private/red.mtl"), RED_MTL).unwrap();
    std::fs::write(scene.join("sub/red.mtl"), RED_MTL).unwrap();
    std::fs::write(scene.join("red.mtl"), RED_MTL).unwrap();
    std::os::unix::fs::symlink(root.join("private/red.mtl"), scene.join("link.mtl")).unwrap();
    let obj = |name: &str, lib: &str| {
        let path = scene.join(name);
        std::fs::write(&path, format!("mtllib {lib}\n{BOX_OBJ}")).unwrap();
        path.to_str().unwrap().to_string()
    };
    for (lib, why) in [
        ("../private/red.mtl", "climbs out"),
        ("/etc/passwd", "an absolute path"),
        ("link.mtl", "a symbolic link out"),
        ("sub", "a folder, not a regular file"),
    ] {
        let path = obj("hostile.obj", lib);
        assert_fails(
            &["render", &path, "-o", o],
            1,
            &["hostile.obj:1:", "material library", lib, why],
        );
    }
    // The same folder, a subfolder, and outside when asked: the material is read.
    for (lib, extra) in [
        ("red.mtl", None),
        ("sub/red.mtl", None),
        ("../private/red.mtl", Some("--allow-outside-refs")),
    ] {
        let path = obj("fine.obj", lib);
        let mut args = vec!["render", &path, "--size", "8x6", "-q", "-o", o];
        args.extend(extra);
        let out = raylab(&args);
        assert_success(&out);
        assert!(
            out.stderr.is_empty(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // A missing library stays a warning (the faces are grey).
    let path = obj("missing.obj", "gone.mtl");
    let out = raylab(&["render", &path, "--size", "8x6", "-o", o]);
    assert_success(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains("material library \"gone.mtl\""));
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn allow_outside_refs_needs_a_scene_file() {
    let d = temp_dir("refs-builtin");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    assert_fails(
        &["render", "cornell-empty", "--allow-outside-refs", "-o", o],
        2,
        &["--allow-outside-refs", "built-in"],
    );
    assert_fails(
        &[
            "stress",
            "--quick",
            "--suite",
            "offset",
            "--allow-outside-refs",
        ],
        2,
        &["--allow-outside-refs", "--mesh"],
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_full_stdout_is_one_line_and_a_full_stderr_changes_nothing() {
    let d = temp_dir("full");
    let o = d.join("x.png");
    let full = || {
        std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
    };
    let out = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args([
            "render",
            "--size",
            "16x12",
            "--json",
            "-o",
            o.to_str().unwrap(),
        ])
        .stdout(full())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let last = err.trim_end().lines().last().unwrap_or("");
    assert!(
        last.contains("stdout") && last.contains("No space"),
        "{err}"
    );
    assert!(
        !err.contains("panicked") && !err.contains("internal error"),
        "{err}"
    );
    // The image was written before the report.
    assert!(o.exists());
    std::fs::remove_file(&o).unwrap();

    let status = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args(["render", "--size", "16x12", "-o", o.to_str().unwrap()])
        .stderr(full())
        .status()
        .unwrap();
    assert!(status.success(), "{status:?}");
    assert!(o.exists());
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_closed_stderr_does_not_stop_the_render() {
    // As `raylab render 2>&1 | head -1`: the reader is gone before raylab
    // writes its summary, and the image must still be written.
    let d = temp_dir("epipe");
    let o = d.join("x.png");
    let mut child = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args(["render", "--size", "32x24", "-o", o.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    assert!(image::open(&o).is_ok());
    // A closed stdout still ends raylab quietly, as `| head` expects.
    let mut child = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args(["scenes"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn reports_and_ray_files_are_written_whole_and_never_through_a_planted_link() {
    let d = temp_dir("atomic");
    let victim = d.join("victim.txt");
    std::fs::write(&victim, "keep").unwrap();
    let rays = d.join("r.rays");
    // The names the old writer would have used next.
    for pid in 0..4 {
        let link = d.join(format!("r.rays.tmp-{}", std::process::id() + pid));
        std::os::unix::fs::symlink(&victim, link).unwrap();
    }
    let out = raylab(&[
        "rays",
        "cornell-empty",
        "--size",
        "8x6",
        "--count",
        "50",
        "--out",
        rays.to_str().unwrap(),
    ]);
    assert_success(&out);
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
    assert!(std::fs::metadata(&rays).unwrap().len() > 0);
    // No temporary file left: only the links planted before.
    let left: Vec<PathBuf> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains(".tmp-") && !p.is_symlink())
        .collect();
    assert!(left.is_empty(), "{left:?}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_terminated_write_leaves_no_temporary_file() {
    // A noisy image (one cosine AO ray), so that its PNG takes a while to
    // encode: the test ends raylab while the temporary file grows.
    let d = temp_dir("signal");
    let o = d.join("big.png");
    let mut child = Command::new(env!("CARGO_BIN_EXE_raylab"))
        .args([
            "render",
            "--size",
            "2048x2048",
            "--ao",
            "cosine:1",
            "-q",
            "-o",
        ])
        .arg(&o)
        .spawn()
        .unwrap();
    let growing = || {
        std::fs::read_dir(&d).unwrap().any(|e| {
            let e = e.unwrap();
            e.file_name().to_string_lossy().contains(".tmp-")
                && e.metadata().is_ok_and(|m| m.len() > 0)
        })
    };
    let mut killed = false;
    while child.try_wait().unwrap().is_none() {
        if growing() {
            let pid = child.id().to_string();
            killed = Command::new("kill")
                .args(["-TERM", &pid])
                .status()
                .unwrap()
                .success();
            break;
        }
    }
    let status = child.wait().unwrap();
    if killed && !status.success() {
        // The signal may also have come just after the rename: the image
        // is then whole, and only a temporary file would be wrong.
        let left: Vec<_> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.to_string_lossy().contains(".tmp-"))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    } else {
        // The write ended before the signal came: nothing to judge here.
        eprintln!("the PNG was written before the signal; status {status:?}");
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn bench_refuses_a_folder_it_did_not_write_unless_forced() {
    let d = temp_dir("bench-out");
    let out = d.join("mine");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("index.html"), "my own page").unwrap();
    let o = out.to_str().unwrap();
    let cheap = [
        "bench",
        "cornell-empty",
        "--quick",
        "-q",
        "--parts",
        "tables",
        "--variants",
        "bvh-sah-serial",
        "--ao",
        "off",
        "--size",
        "16x12",
        "--out",
        o,
    ];
    assert_fails(&cheap, 2, &["--out", "index.html", "--force"]);
    assert_eq!(
        std::fs::read_to_string(out.join("index.html")).unwrap(),
        "my own page"
    );
    let mut forced = cheap.to_vec();
    forced.push("--force");
    assert_success(&raylab(&forced));
    // Its own folder now: a second run needs no --force.
    assert_success(&raylab(&cheap));
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn flags_that_another_flag_makes_meaningless_are_refused() {
    let d = temp_dir("meaningless");
    let o = d.join("x.png");
    let o = o.to_str().unwrap();
    let dark = d.join("dark.obj");
    std::fs::write(&dark, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let dark = dark.to_str().unwrap();
    let rays = d.join("r.rays");
    assert_success(&raylab(&[
        "rays",
        "cornell-empty",
        "--size",
        "8x6",
        "--count",
        "20",
        "--out",
        rays.to_str().unwrap(),
    ]));
    let rays = rays.to_str().unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (
            &["render", "--schedule", "serial", "--threads", "2", "-o", o],
            &["--threads", "serial"],
        ),
        (
            &["render", "--schedule", "rows", "--threads", "1", "-o", o],
            &["--threads", "rows"],
        ),
        (
            &["render", "--ao", "off", "--ao-dist", "0.5", "-o", o],
            &["--ao-dist", "--ao off"],
        ),
        (
            &["rays", "--ao", "off", "--ao-dist", "0.5", "--out", rays],
            &["--ao-dist"],
        ),
        (
            &["validate", "cornell-empty", "--rays", rays, "--size", "8x6"],
            &["--size", "--rays FILE"],
        ),
        (
            &[
                "validate",
                "cornell-empty",
                "--rays",
                rays,
                "--eye",
                "0,1,2",
            ],
            &["--eye", "--rays FILE"],
        ),
        (
            &["validate", "cornell-empty", "--rays", rays, "--ao", "off"],
            &["--ao", "--rays FILE"],
        ),
        (
            &[
                "bench",
                "cornell-empty",
                "--rays",
                rays,
                "--variants",
                "paper",
                "--out",
                o,
            ],
            &["--rays", "--variants"],
        ),
        (
            &[
                "render",
                dark,
                "--light",
                "point:0,1,1",
                "--light-samples",
                "4",
                "-o",
                o,
            ],
            &["--light-samples", "point light", "--light-samples 1"],
        ),
        (
            &["render", dark, "--two-sided-lights", "-o", o],
            &["--two-sided-lights", "no emissive"],
        ),
        (
            &[
                "render",
                dark,
                "--light",
                "point:0,1,1",
                "--two-sided-lights",
                "-o",
                o,
            ],
            &["--two-sided-lights"],
        ),
    ];
    for (args, needles) in cases {
        assert_fails(args, 2, needles);
    }
    // What stays meaningful: threads with the parallel schedules, several
    // samples of a point light beside emissive triangles, two-sided
    // emitters in a scene that has them or with a --light quad.
    for args in [
        &["render", "--schedule", "tiles", "--threads", "2"][..],
        &["render", "--light", "point:0,1,1", "--light-samples", "4"],
        &["render", "--two-sided-lights"],
        &[
            "render",
            dark,
            "--light",
            "quad:0,2,0:1",
            "--two-sided-lights",
        ],
        &["render", "--ao", "off"],
        &["validate", "cornell-empty", "--rays", rays, "--count", "10"],
    ] {
        let mut args = args.to_vec();
        if args[0] == "render" {
            args.extend(["--size", "8x6", "-q", "-o", o]);
        }
        assert_success(&raylab(&args));
    }
    std::fs::remove_dir_all(&d).ok();
}
