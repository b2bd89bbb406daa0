//! `validate --against exact`: raylab's watertight path is never wrong, on
//! every built-in scene and ray set; and the command's own errors.

mod common;

use common::{assert_one_line_error, raylab, temp_dir};

#[test]
fn the_watertight_path_is_never_wrong_against_the_exact_reference() {
    for backend in [&["--backend", "bvh"][..], &["--backend", "naive"][..]] {
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
            "--json",
        ];
        args.extend(backend);
        let out = raylab(&args);
        let reports: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        for r in reports.as_array().unwrap() {
            assert_eq!(r["wrong"], 0, "{r}");
            assert_eq!(r["against"], "exact");
            let sets = r["sets"].as_array().unwrap();
            assert_eq!(sets.len(), 5, "every ray set");
            let judged: u64 = sets
                .iter()
                .map(|s| s["right"].as_u64().unwrap() + s["undecidable"].as_u64().unwrap())
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
