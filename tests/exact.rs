//! `validate --against exact`: raylab's watertight path is never wrong, on
//! every built-in scene and ray set; and the command's own errors.

mod common;

use common::{assert_one_line_error, assert_success, raylab, temp_dir};

#[test]
fn the_watertight_path_is_never_wrong_against_the_exact_reference() {
    for (backend, rays) in [
        (&["--backend", "bvh"][..], "all"),
        (&["--backend", "naive"][..], "all"),
        (&["--backend", "bvh"][..], "edges"),
    ] {
        let mut args = vec![
            "validate",
            "cornell-original",
            "cornell-sphere",
            "cornell-water",
            "mesh:2000",
            "--against",
            "exact",
            "--intersector",
            "watertight",
            "--size",
            "64x48",
            "--count",
            "3000",
            "--rays",
            rays,
            "--json",
        ];
        args.extend(backend);
        let out = raylab(&args);
        let reports: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        for r in reports.as_array().unwrap() {
            assert_eq!(r["wrong"], 0, "{r}");
            assert_eq!(r["against"], "exact");
            let sets = r["sets"].as_array().unwrap();
            assert_eq!(sets.len(), if rays == "all" { 5 } else { 1 }, "{r}");
            let judged: u64 = sets
                .iter()
                .map(|s| {
                    ["right", "undecidable", "edge_tie"]
                        .iter()
                        .map(|k| s[k].as_u64().unwrap())
                        .sum::<u64>()
                })
                .sum();
            let rays: u64 = sets.iter().map(|s| s["rays"].as_u64().unwrap()).sum();
            assert_eq!(judged, rays, "{r}");
        }
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn the_exact_reference_finds_the_moller_trumbore_leaks_on_edge_rays() {
    // Rays aimed at shared edges: MT's f32 tests disagree across an edge
    // and some rays pass between two triangles (judged wrong, not ties);
    // the watertight test on the same rays is right (test above).
    let out = raylab(&[
        "validate",
        "mesh:2000",
        "--against",
        "exact",
        "--rays",
        "edges",
        "--count",
        "20000",
        "--intersector",
        "mt",
        "--json",
    ]);
    let reports: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let set = &reports[0]["sets"][0];
    assert_eq!(set["set"], "edges");
    assert!(set["wrong_triangle"].as_u64().unwrap() > 0, "{set}");
    assert!(set["edge_tie"].as_u64().unwrap() > 0, "{set}");
    assert!(!out.status.success(), "wrong answers fail validate");
}

#[test]
fn exact_validation_refuses_a_diff_image() {
    let d = temp_dir("exact-diff");
    let png = d.join("d.png");
    assert_one_line_error(
        &[
            "validate",
            "cornell-empty",
            "--against",
            "exact",
            "--diff-image",
            png.to_str().unwrap(),
        ],
        "--diff-image",
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn ray_files_round_trip_through_validate_and_bench() {
    let d = temp_dir("rayfile");
    let file = d.join("box.rays");
    let f = file.to_str().unwrap();
    let out = raylab(&[
        "rays",
        "cornell-sphere",
        "--out",
        f,
        "--count",
        "500",
        "--size",
        "32x24",
    ]);
    assert_success(&out);
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(&bytes[..8], b"RAYLABRY");
    let n = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    assert!(n > 500, "primary, shadow, ao and diffuse rays: {n}");
    assert_eq!(bytes.len(), 64 + 36 * n);
    // Traced and judged as a user would.
    let out = raylab(&[
        "validate",
        "cornell-sphere",
        "--rays",
        f,
        "--against",
        "exact",
        "--intersector",
        "watertight",
        "--json",
    ]);
    assert_success(&out);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let traced: u64 = report[0]["sets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["rays"].as_u64().unwrap())
        .sum();
    assert_eq!(traced as usize, n, "every ray of the file, none recorded");
    let bench_out = d.join("bench");
    let out = raylab(&[
        "bench",
        "cornell-sphere",
        "--rays",
        f,
        "--quick",
        "-q",
        "--json",
        "--out",
        bench_out.to_str().unwrap(),
    ]);
    assert_success(&out);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let points = report["libraries"].as_array().unwrap();
    assert!(!points.is_empty());
    for p in points {
        assert_eq!(p["rays"].as_u64().unwrap() as usize, n, "{p}");
    }
    // Bad uses and bad files: one line each.
    assert_one_line_error(
        &["validate", "cornell-sphere", "cornell-empty", "--rays", f],
        "--rays",
    );
    assert_one_line_error(
        &["validate", "cornell-sphere", "--rays", "nope.rays"],
        "--rays",
    );
    assert_one_line_error(
        &["bench", "cornell-sphere", "--rays", f, "--parts", "trace"],
        "--rays",
    );
    let short = d.join("short.rays");
    std::fs::write(&short, &bytes[..bytes.len() - 7]).unwrap();
    assert_one_line_error(
        &[
            "validate",
            "cornell-sphere",
            "--rays",
            short.to_str().unwrap(),
        ],
        "offset",
    );
    assert_one_line_error(
        &["rays", "cornell-sphere", "--out", d.to_str().unwrap()],
        "--out",
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn ray_files_of_an_instanced_scene_are_recorded_without_flattening_it() {
    // forest:10 places 105,428 triangles from 31,322 unique ones: over a
    // budget of 100,000 flattened, within it as meshes and instances (as
    // `render` takes it). `rays` flattened it before, and refused.
    let d = temp_dir("rayfile-instanced");
    let file = d.join("forest.rays");
    let out = raylab(&[
        "rays",
        "forest:10",
        "--max-triangles",
        "100000",
        "--out",
        file.to_str().unwrap(),
        "--count",
        "300",
        "--size",
        "32x24",
    ]);
    assert_success(&out);
    // Read back as `validate --rays` and `bench --rays` read it.
    let sets = raylab::measure::rayfile::read(&file).unwrap();
    let n: usize = sets.iter().map(|(_, rays)| rays.len()).sum();
    assert!(n > 300, "primary, shadow, ao and diffuse rays: {n}");
    std::fs::remove_dir_all(&d).ok();
}
