//! Every `raylab stress` suite in quick mode, with the properties the project
//! promises asserted: no leaks for watertight tests and robust Embree, the
//! default offset free of self-hits, degenerate input harmless, hostile files
//! rejected cleanly. Moller-Trumbore's and plain Embree's leaks are counted by
//! the suite, not asserted.

use raylab::geometry::{Intersector, OffsetStrategy};
use raylab::measure::stress::*;

#[test]
fn watertight_and_robust_embree_never_leak_on_closed_meshes() {
    let rows = leak_suite(&leak_meshes(true), 2).unwrap();
    assert!(rows.len() >= 4 * 6, "{} rows", rows.len());
    for r in &rows {
        assert!(r.rays > 100, "{}: only {} rays", r.mesh, r.rays);
        if r.intersector == "watertight" || r.backend.ends_with("-robust") {
            assert_eq!(
                r.leaks, 0,
                "{} leaks {} of {} rays on {}",
                r.backend, r.leaks, r.rays, r.mesh
            );
        }
    }
    // The suite must be able to see leaks at all: MT leaks somewhere.
    assert!(rows.iter().any(|r| r.backend == "naive" && r.leaks > 0));
}

#[test]
fn leak_rays_hit_when_aimed_from_inside() {
    // Every ray from the centre of a sphere must hit it; naive MT may leak only a few.
    let mesh = icosphere(1);
    let rays = leak_rays(&mesh, 0, 1);
    assert_eq!(
        rays.len(),
        42 + 2 * 120,
        "one inside ray per vertex and two per edge"
    );
}

#[test]
fn default_offset_has_no_self_hits_and_finds_near_occluders() {
    let rows = offset_suite(&[0.0, 1e3, 1e4, 1e6], 1000).unwrap();
    // The renderer's: from the hit's barycentrics, by a bound on its error,
    // on a floor near the camera and on a field seen far and grazing.
    for r in rows
        .iter()
        .filter(|r| r.strategy == OffsetStrategy::Bounded)
    {
        assert_eq!(r.self_hit_rate, 0.0, "{r:?}");
        assert_eq!(r.missed_at_1e3, 0.0, "{r:?}");
        assert_eq!(r.missed_at_5e5, 0.0, "{r:?}");
    }
    // The previous default, from o + t d: clean near the camera, but a
    // field in y = 0 seen from far self-hits (the speckled flat exports).
    let ulp = |view: &str| {
        rows.iter()
            .filter(|r| r.strategy == OffsetStrategy::Ulp && r.view == view)
            .map(|r| r.self_hit_rate)
            .fold(0.0, f64::max)
    };
    assert_eq!(ulp("near"), 0.0);
    assert!(ulp("field") > 0.1, "{}", ulp("field"));
    // The suite must be able to see self-hits: no offset at all self-hits far out.
    assert!(rows.iter().any(|r| r.strategy == OffsetStrategy::None
        && r.intersector == Intersector::Mt
        && r.self_hit_rate > 0.05));
}

#[test]
fn degenerate_input_gives_no_nan_and_agrees_with_naive() {
    let rows = degenerate_suite(1000, &default_stress_specs()).unwrap();
    let cases = degenerate_cases().len();
    assert_eq!(rows.len() % cases, 0);
    assert!(rows.len() / cases >= 6, "every backend on every case");
    for r in rows.iter().filter(|r| !r.library) {
        assert!(r.not_built.is_none(), "{r:?}");
        assert_eq!(r.nan_results, 0, "{r:?}");
        assert_eq!(r.genuine_vs_naive, 0, "{r:?}");
        if r.backend.contains("watertight") {
            assert_eq!(r.exact_wrong, 0, "{r:?}");
        }
    }
}

#[test]
fn hostile_files_never_panic_and_never_load_invalid_scenes() {
    let r = hostile_suite(3000, 2024).unwrap();
    assert_eq!(r.panics, 0, "{r:?}");
    assert_eq!(r.invalid_scenes, 0, "{r:?}");
    assert_eq!(r.multi_line_errors, 0, "{r:?}");
    // Both outcomes must occur, or the mutations test nothing.
    assert!(r.loaded > 100 && r.rejected > 100, "{r:?}");
}

#[test]
fn report_has_every_table() {
    let report = StressReport {
        leaks: leak_suite(&[cube(1)], 1).unwrap(),
        offset: offset_suite(&[0.0], 50).unwrap(),
        degenerate: degenerate_suite(50, &parse_stress_backends("bvh8-sah").unwrap()).unwrap(),
        hostile: Some(hostile_suite(20, 1).unwrap()),
    };
    let md = report.markdown();
    for heading in ["## Leaks", "## Offset", "## Degenerate", "## Hostile"] {
        assert!(md.contains(heading), "{heading} missing");
    }
    let json: serde_json::Value = serde_json::to_value(&report).unwrap();
    assert!(json["leaks"].as_array().unwrap().len() >= 6);
}

#[test]
fn user_meshes_must_be_closed_and_backends_can_be_chosen() {
    let dir = std::env::temp_dir().join(format!("raylab-stress-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A tetrahedron with one face missing, and the whole one; the closed one
    // with split vertices (one normal per face), which welding must join.
    let open = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\n";
    let closed = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 -1\nvn 0 -1 0\nvn -1 0 0\nvn 1 1 1\n\
                  f 1//1 3//1 2//1\nf 1//2 2//2 4//2\nf 1//3 4//3 3//3\nf 2//4 3//4 4//4\n";
    std::fs::write(dir.join("open.obj"), open).unwrap();
    std::fs::write(dir.join("closed.obj"), closed).unwrap();
    let Err(e) = file_mesh(&dir.join("open.obj"), Default::default()) else {
        panic!("an open mesh was taken")
    };
    let e = e.to_string();
    assert!(e.contains("not a closed mesh (3 edges"), "{e}");
    let mesh = file_mesh(&dir.join("closed.obj"), Default::default()).unwrap();
    assert_eq!(mesh.positions.len(), 4, "split vertices are welded");
    // Backends by the names reports give them, each exactly that backend;
    // a --backend name is its default (bvh: the tree a render builds).
    let specs = parse_stress_backends("bvh-sah, bvh8-sah-watertight,bvh-sah").unwrap();
    let rows = leak_suite_with(&[mesh], 2, &specs).unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r.backend.as_str()).collect();
    assert_eq!(names, ["bvh-sah", "bvh8-sah-watertight"]);
    let names = |list: &str| -> Vec<String> {
        let specs = parse_stress_backends(list).unwrap();
        specs.iter().map(|s| s.name()).collect()
    };
    assert_eq!(names("bvh,naive"), ["bvh8-sah", "naive"]);
    let all = names("all");
    for name in [
        "naive-watertight",
        "bvh-median",
        "bvh8-sah",
        "bvh8-sah-watertight",
    ] {
        assert!(all.iter().any(|n| n == name), "{name} not in {all:?}");
    }
    assert!(
        !all.iter().any(|n| n == "bvh-sah"),
        "the binary tree is not the default"
    );
    for bad in ["warp", "bvh-sah-packet8", "", " , "] {
        let e = parse_stress_backends(bad).unwrap_err().to_string();
        assert!(e.contains("--backends") && !e.contains('\n'), "{e}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
