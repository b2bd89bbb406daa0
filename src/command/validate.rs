//! `raylab validate`: its flags, the comparison per scene, its table and verdict.

use std::path::{Path, PathBuf};

use clap::Args;
use serde::Serialize;

use super::args::{parse_threads, BackendArgs, SceneFileArgs, ViewArgs};
use crate::accel::{build_backend, BackendKind, BackendSpec};
use crate::error::{Error, Result};
use crate::measure::rayfile::RaySets;
use crate::measure::validate::{ray_sets, RaySet, SpawnReport};
use crate::output;
use crate::render::schedule::default_threads;
use crate::scene::builtin::BUILTIN_SCENES;
use crate::table::{
    Align::{Left, Right},
    Table,
};

#[derive(Args, Debug)]
pub struct ValidateArgs {
    /// Scene files (.obj, .ply, .gltf, .glb) or built-in names [default: the
    /// four built-in Cornell boxes].
    scenes: Vec<String>,
    #[command(flatten)]
    pub accel: BackendArgs,
    /// The reference: `exact` (every ray decided in exact arithmetic where
    /// double precision allows: each answer right, wrong or undecidable), a
    /// backend by the name reports give it (bvh8-sah-watertight,
    /// embree-high-robust, tinybvh-bvh, ...), or a --backend name for
    /// that backend's default (bvh: bvh8-sah, the tree a render builds;
    /// embree: embree-medium). Without Embree built in, the default is naive.
    #[arg(long, value_name = "BACKEND", default_value = Reference::default_name(), value_parser = parse_against)]
    against: Reference,
    /// Ray sets to compare: primary, shadow, ao, diffuse, random, all (those
    /// five) or edges (aimed at vertices and edges: best judged with
    /// `--against exact`, since two f32 tests disagree there by design); or
    /// a ray file (`raylab rays`, format in docs/reference.md) whose rays are
    /// traced instead of a render's (one scene).
    #[arg(long, value_name = "SET|FILE", default_value = "all")]
    rays: String,
    /// At most this many rays per set (evenly subsampled).
    #[arg(long, value_name = "N", default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    count: u64,
    /// Write a picture of primary-ray agreement (red: genuine, yellow: tie);
    /// with several scenes the scene name is added to the file name.
    #[arg(long, value_name = "PNG")]
    diff_image: Option<PathBuf>,
    /// Exit with status 1 when a scene has more genuine disagreements than this.
    #[arg(long, value_name = "N", default_value_t = 0)]
    max_genuine: usize,
    /// Worker threads [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    #[command(flatten)]
    view: ViewArgs,
    #[command(flatten)]
    files: SceneFileArgs,
    /// For instanced scenes (forest:N, a glTF file placing a mesh more than
    /// once): test the backend's two-level structure (raylab's two-level
    /// tree for bvh, Embree's instances for embree), its hits numbered as
    /// the flattened list numbers them, against the reference over the
    /// flattened list. Without it both trace the flattened list.
    #[arg(long)]
    instances: bool,
    /// Print one JSON array with a report per scene on stdout.
    #[arg(long)]
    json: bool,
    /// No progress lines on stderr (one per scene as its validation starts).
    #[arg(long, short = 'q')]
    quiet: bool,
}

/// `--against`: the exact reference, or a backend.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reference {
    /// The exact reference (`src/measure/exact.rs`).
    Exact,
    /// A backend (its build threads set when it is built).
    Backend(BackendSpec),
}

impl Reference {
    /// The default: Embree where it is built in, else the naive scan.
    fn default_name() -> &'static str {
        if crate::accel::embree::AVAILABLE {
            BackendKind::Embree.name()
        } else {
            BackendKind::Naive.name()
        }
    }
}

/// Parses `--against`: `exact`, or a backend ([`crate::accel::parse_backend`]:
/// its name as reports print it, or a `--backend` name for its default).
pub fn parse_against(s: &str) -> std::result::Result<Reference, String> {
    if s.trim() == "exact" {
        return Ok(Reference::Exact);
    }
    crate::accel::parse_backend(s)
        .map(Reference::Backend)
        .map_err(|e| format!("{e}, or exact"))
}

/// One scene judged against the exact reference.
#[derive(Serialize)]
struct ExactValidateReport {
    scene: String,
    backend: String,
    against: &'static str,
    wrong: usize,
    undecidable: usize,
    wrong_per_million: f64,
    max_genuine: usize,
    pass: bool,
    sets: Vec<crate::measure::exact::ExactReport>,
    /// The recorded render's secondary-ray origins, judged against their own
    /// surfaces (None for a ray file, or sets recorded without a render).
    spawns: Option<SpawnReport>,
}

#[derive(Serialize)]
struct ValidateReport {
    scene: String,
    backend: String,
    against: String,
    genuine: usize,
    ties: usize,
    max_genuine: usize,
    pass: bool,
    sets: Vec<crate::measure::validate::SetReport>,
    /// See [`ExactValidateReport::spawns`].
    spawns: Option<SpawnReport>,
    diff_image: Option<String>,
}

/// Says on stderr which scene is being validated, unless `--quiet`: a large
/// scene's build and recording render take a while.
fn announce(args: &ValidateArgs, scene: &crate::scene::Scene, spec: &BackendSpec, against: &str) {
    if !args.quiet {
        crate::console::say(&format!(
            "validate: {} ({} triangles), {} against {against} ...",
            scene.name,
            scene.triangles.len(),
            spec.name()
        ));
    }
}

/// The backend tested on `name` (loaded as `flat`): built over the
/// flattened list, or with `--instances` the two-level structure over the
/// instanced scene, answering in the flattened list's numbers.
fn tested_backend(
    args: &ValidateArgs,
    name: &str,
    spec: &BackendSpec,
    flat: &crate::scene::Scene,
) -> Result<crate::accel::Built> {
    if !args.instances {
        return build_backend(spec, flat);
    }
    let instanced = args.files.load_instanced(name)?;
    if !instanced.is_instanced() {
        return Err(Error::usage(
            "--instances",
            format!(
                "{} has no instances (each mesh is placed once)",
                instanced.name
            ),
        ));
    }
    crate::accel::flat_numbered::numbered_as_flattened(
        crate::accel::build_scene_backend(spec, &instanced)?,
        &instanced,
    )
}

/// The names `--rays` takes for sets of a render's rays (else it is a file).
const SETS: [&str; 7] = [
    "primary", "shadow", "ao", "diffuse", "random", "edges", "all",
];

/// Refuses the view, size and AO flags with a ray file: its rays are traced
/// as they are, so those flags would be ignored.
pub fn check_ray_file_flags(m: &clap::ArgMatches, args: &ValidateArgs) -> Result<()> {
    if SETS.contains(&args.rays.as_str()) {
        return Ok(());
    }
    match super::args::first_given(m, super::args::VIEW_FLAGS) {
        Some(flag) => Err(Error::usage(
            flag,
            "does not apply to --rays FILE: a ray file's rays are traced as they are (view, size, AO and light flags make the rays of a render)",
        )),
        None => Ok(()),
    }
}

/// The rays of `--rays FILE`, or `None` when `--rays` names a set. A file
/// applies to one scene, and has no raster for `--diff-image`.
fn file_rays(args: &ValidateArgs, names: &[String]) -> Result<Option<RaySets>> {
    if SETS.contains(&args.rays.as_str()) {
        return Ok(None);
    }
    let path = Path::new(&args.rays);
    if !path.is_file() {
        return Err(Error::usage(
            "--rays",
            format!(
                "'{}' is neither a ray set ({}) nor a ray file",
                args.rays,
                SETS.join(", ")
            ),
        ));
    }
    if names.len() != 1 {
        return Err(Error::usage(
            "--rays",
            "a ray file is traced in one scene: give exactly one",
        ));
    }
    if args.diff_image.is_some() {
        return Err(Error::usage(
            "--diff-image",
            "draws a render's primary rays, not a ray file's",
        ));
    }
    crate::measure::rayfile::read(path).map(Some)
}

/// Each set of `rays` evenly subsampled to at most `count`.
fn subsampled(rays: &RaySets, count: usize) -> RaySets {
    rays.iter()
        .map(|(set, r)| (*set, crate::measure::validate::subsample(r.clone(), count)))
        .collect()
}

fn diff_image_path(base: &Path, scene: &str, several: bool) -> PathBuf {
    if !several {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let tag: String = Path::new(scene)
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    base.with_file_name(format!("{stem}-{tag}.png"))
}

pub fn run(args: &ValidateArgs) -> Result<()> {
    use crate::measure::validate::{compare, mismatch_image};
    let threads = args.threads.unwrap_or_else(default_threads);
    let names: Vec<String> = if args.scenes.is_empty() {
        BUILTIN_SCENES.iter().map(|(n, _)| n.to_string()).collect()
    } else {
        args.scenes.clone()
    };
    args.files.check(&names)?;
    if let Some(path) = &args.diff_image {
        output::check_writable(&diff_image_path(path, &names[0], names.len() > 1))?;
    }
    let sets: Vec<RaySet> = match args.rays.as_str() {
        "primary" => vec![RaySet::Primary],
        "shadow" => vec![RaySet::Shadow],
        "ao" => vec![RaySet::Ao],
        "diffuse" => vec![RaySet::Diffuse],
        "random" => vec![RaySet::Random],
        "edges" => vec![RaySet::Edges],
        _ => RaySet::ALL.to_vec(),
    };
    let file_rays = file_rays(args, &names)?;
    let count = args.count as usize;
    let spec = args.accel.spec(threads)?;
    let reference_spec = match args.against {
        Reference::Exact => return run_exact(args, &names, &sets, file_rays, spec, threads),
        // The reference on `threads`.
        Reference::Backend(reference) => reference.with_build_threads(threads),
    };
    let against = reference_spec.kind();
    let mut reports = Vec::new();
    for name in &names {
        let mut scene = args.files.load(name)?;
        let settings = args.view.prepare(&mut scene)?;
        announce(args, &scene, &spec, &reference_spec.name());
        let tested = tested_backend(args, name, &spec, &scene)?;
        let reference = build_backend(&reference_spec, &scene)?;
        let triangles = scene.triangle_vertices();
        // Record the render's rays with the faster of the two (naive is slow);
        // rays of another library's image would carry its wrong answers, so
        // against the naive scan those are recorded with raylab's tree, built
        // only when a render is recorded (not for a ray file, primary,
        // random or edge rays).
        let records = file_rays.is_none() && sets.iter().any(|s| s.is_recorded());
        let raylab_tree;
        let recorder: &dyn crate::accel::Backend = match against {
            BackendKind::Naive if spec.kind().is_library() && records => {
                raylab_tree =
                    build_backend(&BackendSpec::DEFAULT.with_build_threads(threads), &scene)?;
                raylab_tree.as_ref()
            }
            BackendKind::Naive => tested.as_ref(),
            _ => reference.as_ref(),
        };
        let (set_rays, spawns) = match &file_rays {
            Some(rays) => (subsampled(rays, count), None),
            None => ray_sets(
                &scene,
                recorder,
                &settings,
                &sets,
                count,
                args.diff_image.is_some(),
            )?,
        };
        let mut set_reports = Vec::new();
        let mut diff_written = None;
        for (set, rays) in &set_rays {
            let (label, rays) = (set.name(), rays);
            let is_primary = *set == RaySet::Primary;
            let (report, agreements) =
                compare(label, rays, tested.as_ref(), reference.as_ref(), &triangles);
            if is_primary {
                if let Some(base) = &args.diff_image {
                    let path = diff_image_path(base, name, names.len() > 1);
                    let hits: Vec<bool> = rays
                        .iter()
                        .map(|r| reference.intersect(r).is_some())
                        .collect();
                    output::write_png(
                        &path,
                        settings.width,
                        settings.height,
                        &mismatch_image(&agreements, &hits),
                    )?;
                    diff_written = Some(path.display().to_string());
                }
            }
            set_reports.push(report);
        }
        let genuine: usize = set_reports.iter().map(|r| r.genuine).sum();
        let ties: usize = set_reports.iter().map(|r| r.ties).sum();
        let behind = spawns.as_ref().map_or(0, |s| s.behind);
        let pass = genuine <= args.max_genuine && behind == 0;
        if !args.json {
            crate::console::outln(&format!(
                "{} ({} triangles): {} against {}",
                scene.name,
                scene.triangle_count(),
                tested.name(),
                reference.name()
            ))?;
            crate::console::out(&set_table(&set_reports).markdown())?;
            print_spawns(spawns.as_ref())?;
            crate::console::outln(&format!(
                "{}: {genuine} genuine disagreements (max {}), {ties} ties\n",
                if pass { "ok" } else { "FAIL" },
                args.max_genuine
            ))?;
        }
        reports.push(ValidateReport {
            scene: scene.name.clone(),
            backend: tested.name(),
            against: reference.name(),
            genuine,
            ties,
            max_genuine: args.max_genuine,
            pass,
            sets: set_reports,
            spawns,
            diff_image: diff_written,
        });
    }
    let failed = reports.iter().filter(|r| !r.pass).map(|r| r.scene.as_str());
    finish(args, &reports, failed, "genuine disagreements")
}

/// Prints, under a set table, how many of the render's secondary rays start
/// behind their own surface (the examples when any do).
fn print_spawns(spawns: Option<&SpawnReport>) -> Result<()> {
    let Some(s) = spawns else { return Ok(()) };
    crate::console::outln(&format!(
        "secondary-ray origins: {} of {} behind or on their own surface",
        s.behind, s.surfaces
    ))?;
    for (tri, origin) in &s.examples {
        crate::console::outln(&format!("  triangle {tri}: origin {origin:?}"))?;
    }
    Ok(())
}

/// Prints the JSON reports when asked, and fails naming the scenes with
/// more `what` than `--max-genuine` (or any secondary-ray origin behind its
/// surface).
fn finish<'a>(
    args: &ValidateArgs,
    reports: &impl Serialize,
    failed: impl Iterator<Item = &'a str>,
    what: &str,
) -> Result<()> {
    if args.json {
        crate::console::outln(&serde_json::to_string_pretty(reports)?)?;
    }
    let failed: Vec<&str> = failed.collect();
    if failed.is_empty() {
        Ok(())
    } else {
        Err(Error::Other(format!(
            "validate: {what} above --max-genuine {} (or secondary rays starting behind their surface) in {}",
            args.max_genuine,
            failed.join(", ")
        )))
    }
}

/// `validate --against exact`: every answer of the backend under test judged
/// against the exact reference, on rays recorded with raylab's tree.
fn run_exact(
    args: &ValidateArgs,
    names: &[String],
    sets: &[crate::measure::validate::RaySet],
    file_rays: Option<RaySets>,
    spec: BackendSpec,
    threads: usize,
) -> Result<()> {
    use crate::measure::exact::{judge, ExactReference};
    if args.diff_image.is_some() {
        return Err(Error::usage(
            "--diff-image",
            "draws agreement with a backend, not with --against exact",
        ));
    }
    let count = args.count as usize;
    let mut reports = Vec::new();
    for name in names {
        let mut scene = args.files.load(name)?;
        let settings = args.view.prepare(&mut scene)?;
        announce(args, &scene, &spec, "the exact reference");
        let tested = tested_backend(args, name, &spec, &scene)?;
        let reference = ExactReference::new(scene.triangle_vertices());
        let (set_rays, spawns) = match &file_rays {
            Some(rays) => (subsampled(rays, count), None),
            None => {
                // The rays of raylab's render (its tree is the naive scan's
                // hits bit for bit), so every backend is judged on the same rays.
                let recorder =
                    build_backend(&BackendSpec::DEFAULT.with_build_threads(threads), &scene)?;
                ray_sets(&scene, recorder.as_ref(), &settings, sets, count, false)?
            }
        };
        let set_reports: Vec<crate::measure::exact::ExactReport> = set_rays
            .iter()
            .map(|(set, rays)| judge(set.name(), rays, tested.as_ref(), &reference))
            .collect();
        let wrong: usize = set_reports.iter().map(|r| r.wrong()).sum();
        let undecidable: usize = set_reports.iter().map(|r| r.undecidable_answers()).sum();
        let queries: usize = set_reports.iter().map(|r| 2 * r.rays).sum();
        let behind = spawns.as_ref().map_or(0, |s| s.behind);
        let report = ExactValidateReport {
            scene: scene.name.clone(),
            backend: tested.name(),
            against: "exact",
            wrong,
            undecidable,
            wrong_per_million: wrong as f64 * 1e6 / queries.max(1) as f64,
            max_genuine: args.max_genuine,
            pass: wrong <= args.max_genuine && behind == 0,
            sets: set_reports,
            spawns,
        };
        if !args.json {
            crate::console::outln(&format!(
                "{} ({} triangles): {} against the exact reference",
                scene.name,
                scene.triangle_count(),
                report.backend
            ))?;
            crate::console::out(&exact_table(&report.sets).markdown())?;
            print_spawns(report.spawns.as_ref())?;
            crate::console::outln(&format!(
                "{}: {wrong} wrong answers ({:.1} per million queries, max {}), {undecidable} undecidable in double precision\n",
                if report.pass { "ok" } else { "FAIL" },
                report.wrong_per_million,
                args.max_genuine
            ))?;
        }
        reports.push(report);
    }
    let failed = reports.iter().filter(|r| !r.pass).map(|r| r.scene.as_str());
    finish(args, &reports, failed, "wrong answers")
}

/// One row per ray set: the backend's closest-hit and any-hit answers as the
/// exact reference judges them.
fn exact_table(sets: &[crate::measure::exact::ExactReport]) -> Table {
    let mut t = Table::new([
        ("set", Left),
        ("rays", Right),
        ("right", Right),
        ("false miss", Right),
        ("false hit", Right),
        ("wrong triangle", Right),
        ("t error", Right),
        ("undecidable", Right),
        ("edge ties", Right),
        ("occlusion right", Right),
        ("occl. false miss", Right),
        ("occl. false hit", Right),
        ("occl. undecidable", Right),
        ("occl. edge ties", Right),
    ]);
    for r in sets {
        t.row([
            r.set.clone(),
            r.rays.to_string(),
            r.right.to_string(),
            r.false_miss.to_string(),
            r.false_hit.to_string(),
            r.wrong_triangle.to_string(),
            r.t_error.to_string(),
            r.undecidable.to_string(),
            r.edge_tie.to_string(),
            r.occlusion_right.to_string(),
            r.occlusion_false_miss.to_string(),
            r.occlusion_false_hit.to_string(),
            r.occlusion_undecidable.to_string(),
            r.occlusion_edge_tie.to_string(),
        ]);
    }
    t
}

/// One row per ray set: how the backend under test agreed with the reference.
fn set_table(sets: &[crate::measure::validate::SetReport]) -> Table {
    let mut t = Table::new([
        ("set", Left),
        ("rays", Right),
        ("hit/miss agree", Right),
        ("same triangle", Right),
        ("ties", Right),
        ("genuine", Right),
        ("occlusion mismatches", Right),
        ("max rel dt", Right),
        ("mean rel dt", Right),
    ]);
    for r in sets {
        t.row([
            r.set.to_string(),
            r.rays.to_string(),
            r.hit_miss_agree.to_string(),
            r.same_triangle.to_string(),
            r.ties.to_string(),
            r.genuine.to_string(),
            r.occlusion_mismatches.to_string(),
            format!("{:.2e}", r.max_rel_dt),
            format!("{:.2e}", r.mean_rel_dt),
        ]);
    }
    t
}
