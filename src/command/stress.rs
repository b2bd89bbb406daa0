//! `raylab stress`: its flags, the suites it runs and the report files.

use std::path::PathBuf;

use clap::Args;

use crate::error::{Error, Result};
use crate::output;
use crate::table::{Align, Table};

#[derive(Args, Debug)]
pub struct StressArgs {
    /// Which suite to run.
    #[arg(long, value_name = "SUITE", default_value = "all", value_parser = ["leaks", "offset", "degenerate", "hostile", "all"])]
    suite: String,
    /// Small meshes and few rays (what the tests run): seconds instead of minutes.
    #[arg(long)]
    quick: bool,
    /// Extra closed meshes for the leak suite (outside rays only): scene files
    /// in any format raylab reads; an open mesh is refused.
    #[arg(long, value_name = "FILE")]
    mesh: Vec<PathBuf>,
    /// Backends of the leak and degenerate suites, separated by commas: their
    /// names as reports print them (naive-watertight, bvh-median, bvh8-sah,
    /// embree-medium-robust, tinybvh-bvh, ...; see docs/reference.md), a
    /// --backend name for its default (bvh: bvh8-sah), libraries (every
    /// layout of tinybvh, obvhs and the bvh crate), or all: naive,
    /// bvh-median and bvh8-sah each with mt and watertight, Embree plain
    /// and robust, and the libraries. The naive scan tests every triangle
    /// per ray: minutes on a mesh of 10^4.
    #[arg(long, value_name = "LIST", default_value = "all")]
    backends: String,
    #[command(flatten)]
    files: super::args::SceneFileArgs,
    /// Write stress.md, stress.json and leaks.csv into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print the report as one JSON object on stdout instead of tables.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &StressArgs) -> Result<()> {
    use crate::measure::stress::*;
    let want = |name: &str| args.suite == "all" || args.suite == name;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        output::check_writable(&dir.join("probe.png"))?;
    }
    let specs = parse_stress_backends(&args.backends)?;
    if args.files.allow_outside_refs && args.mesh.is_empty() {
        return Err(Error::usage(
            "--allow-outside-refs",
            "applies to the scene files of --mesh; none is given",
        ));
    }
    // The user's meshes are read (and refused when open) before any suite runs.
    let user_meshes = args
        .mesh
        .iter()
        .map(|p| file_mesh(p, args.files.policy()))
        .collect::<Result<Vec<_>>>()?;
    let mut report = StressReport::default();
    let q = args.quick;
    if want("leaks") {
        crate::console::say("stress: leaks ...");
        let mut meshes = leak_meshes(q);
        meshes.extend(user_meshes);
        report.leaks = leak_suite_with(&meshes, if q { 2 } else { 4 }, &specs)?;
    }
    if want("offset") {
        crate::console::say("stress: offset ...");
        let shifts: &[f32] = if q {
            &[0.0, 1e2, 1e4, 1e6]
        } else {
            &[0.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6]
        };
        report.offset = offset_suite(shifts, if q { 2000 } else { 20_000 })?;
    }
    if want("degenerate") {
        crate::console::say("stress: degenerate ...");
        report.degenerate = degenerate_suite(if q { 2000 } else { 20_000 }, &specs)?;
    }
    if want("hostile") {
        crate::console::say("stress: hostile ...");
        report.hostile = Some(hostile_suite(if q { 500 } else { 5000 }, 1)?);
    }
    let json = serde_json::to_string_pretty(&report)?;
    if let Some(dir) = &args.out {
        let write = |name: &str, text: &str| output::write_text(&dir.join(name), text);
        write("stress.md", &report.markdown())?;
        write("stress.json", &json)?;
        // The leak table's columns, with the numbers unrounded.
        let mut csv = Table::new(
            [
                "mesh",
                "triangles",
                "backend",
                "intersector",
                "rays",
                "leaks",
                "leak_rate",
                "exact_wrong",
                "edge_ties",
                "ns_per_ray",
            ]
            .map(|c| (c, Align::Left)),
        );
        for r in &report.leaks {
            csv.row([
                r.mesh.clone(),
                r.triangles.to_string(),
                r.backend.clone(),
                r.intersector.clone(),
                r.rays.to_string(),
                r.leaks.to_string(),
                r.leak_rate.to_string(),
                r.exact_wrong.to_string(),
                r.edge_ties.to_string(),
                r.ns_per_ray.to_string(),
            ]);
        }
        write("leaks.csv", &csv.csv())?;
    }
    if args.json {
        crate::console::outln(&json)?;
    } else {
        crate::console::out(&report.markdown())?;
    }
    let hostile_failed = report
        .hostile
        .as_ref()
        .is_some_and(|h| h.panics > 0 || h.invalid_scenes > 0 || h.multi_line_errors > 0);
    // Another library's NaN is a finding about it, not a failure of raylab.
    let nan = report
        .degenerate
        .iter()
        .any(|r| r.nan_results > 0 && !r.library);
    if hostile_failed || nan {
        return Err(Error::Other(
            "stress: raylab itself failed (panic, NaN or invalid scene): see the report".into(),
        ));
    }
    Ok(())
}
