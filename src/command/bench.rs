//! `raylab bench`: its flags, and the run that loads the scenes, runs the parts
//! and writes the report.

use std::path::PathBuf;

use clap::Args;
use glam::Vec3;

use super::args::{parse_fov, parse_size, parse_threads, parse_vec3, SceneFileArgs};
use crate::bench::Part;
use crate::error::{Error, Result};
use crate::render::schedule::default_threads;
use crate::render::AoMode;
use crate::scene::builtin::BUILTIN_SCENES;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Scene files (.obj, .ply, .gltf, .glb) or built-in names [default: the
    /// four built-in Cornell boxes].
    scenes: Vec<String>,
    /// Views: `default` (the study's (0,1,3) and (2,1,3) for the built-in boxes,
    /// the framing rule for other scenes), `paper` (the study's two for every
    /// scene), or eye positions separated by spaces or semicolons ("0,1,3;2,1,3"),
    /// each looking at --look or the scene's default look-at point.
    #[arg(
        long,
        value_name = "default|paper|X,Y,Z...",
        default_value = "default",
        allow_hyphen_values = true
    )]
    views: String,
    /// One eye position for every scene (instead of --views).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    eye: Option<Vec3>,
    /// Point looked at [default: (0,1,0) in the built-in boxes, the bounding box's
    /// centre in other scenes].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    look: Option<Vec3>,
    /// Up vector.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, default_value = "0,1,0", value_parser = parse_vec3)]
    up: Vec3,
    /// Vertical field of view in degrees, in (0, 180), and no narrower than f32 rays resolve at the image's height (0.042 at 768 pixels).
    #[arg(long, value_name = "DEG", default_value_t = 60.0, allow_negative_numbers = true, value_parser = parse_fov)]
    fov: f32,
    /// Variants: all, paper (the study's combinations), or names separated by commas.
    #[arg(long, value_name = "LIST", default_value = "all")]
    variants: String,
    /// AO modes of the tables, separated by commas: off, paper, cosine:N, or
    /// both (off and paper).
    #[arg(long, value_name = "LIST", default_value = "both")]
    ao: String,
    /// Measured runs per variant and cell, after one warm-up [default: 10; 1 and
    /// no warm-up with --quick].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1000))]
    reps: Option<u32>,
    /// Image size [default: 1024x768; 96x72 with --quick].
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Worker threads of the parallel variants [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    /// Small images, one rep and small experiments: under a minute (what CI runs).
    #[arg(long)]
    quick: bool,
    /// Stop repeating a variant in a cell once its runs would pass this many
    /// seconds (it keeps at least one run): caps the naive loop on big scenes.
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    max_variant_s: f64,
    /// Parts to run, separated by commas: all, or tables, trace, scaling,
    /// growth, ao-error, builders, ladder, libraries, leaks, validate,
    /// animation.
    #[arg(long, value_name = "LIST", default_value = "all")]
    parts: String,
    /// A ray file (`raylab rays`) for the `libraries` part to trace instead
    /// of a render's rays: every backend side by side on these rays (one
    /// scene; runs the `libraries` part only).
    /// (Not with --variants: the libraries part traces every backend.)
    #[arg(long, value_name = "FILE", conflicts_with = "variants")]
    rays: Option<PathBuf>,
    /// The cliff finder: run the `libraries` part over generated scenes of
    /// every class a user might bring (planar, architecture interior,
    /// closed scan, CAD slivers, foliage, huge and tiny, far from the
    /// origin, heavy overlap, the study's box; smaller with --quick) and
    /// the SCENEs given, and lead with where raylab's best path is behind
    /// the best peer. (Not with --rays: each class traces its own rays.)
    #[arg(long, conflicts_with = "rays")]
    cliffs: bool,
    /// The refit policy's factors in the `animation` part, separated by
    /// commas (a policy each): rebuild when the refitted tree's SAH cost
    /// exceeds F times its cost when last built (numbers above 1)
    /// [default: 1.5].
    #[arg(long, value_name = "F,...", value_parser = crate::accel::update::parse_factors)]
    rebuild_factor: Option<crate::accel::update::Factors>,
    /// Folder for bench.md, bench.csv, bench.json, charts/, images/ and
    /// index.html. A folder holding files bench did not write is refused
    /// (they could be overwritten) unless --force is given.
    #[arg(long, value_name = "DIR", default_value = "bench-report")]
    out: PathBuf,
    /// Write into --out even when it holds files bench did not write.
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    files: SceneFileArgs,
    /// Print the report as one JSON object on stdout instead of the tables.
    #[arg(long)]
    json: bool,
    /// No progress on stderr.
    #[arg(long, short = 'q')]
    quiet: bool,
}

/// Parses `--views` with `--eye`, `--look`, `--up` and `--fov`.
fn parse_views(args: &BenchArgs) -> Result<crate::bench::measure::ViewPlan> {
    use crate::bench::measure::ViewPlan;
    let s = args.views.trim();
    let explicit = s != "default";
    if explicit && args.eye.is_some() {
        return Err(Error::usage(
            "--eye",
            "give either --eye or --views, not both",
        ));
    }
    let mut plan = match s {
        "default" => ViewPlan::default(),
        "paper" => ViewPlan::paper(),
        _ => {
            let eyes = s
                .split([';', ' '])
                .map(str::trim)
                .filter(|p| !p.is_empty())
                .map(|p| parse_vec3(p).map_err(|e| Error::usage("--views", format!("'{p}': {e}"))))
                .collect::<Result<Vec<_>>>()?;
            if eyes.is_empty() {
                return Err(Error::usage("--views", "no view given"));
            }
            ViewPlan {
                eyes: Some(eyes),
                ..ViewPlan::default()
            }
        }
    };
    plan.eye = args.eye;
    if args.look.is_some() {
        plan.look = args.look;
    }
    plan.up = args.up;
    plan.fov = args.fov;
    if let (Some(eyes), Some(look)) = (&plan.eyes, plan.look) {
        if let Some(e) = eyes.iter().find(|&&e| e == look) {
            return Err(Error::usage(
                "--views",
                format!("{},{},{} is the point looked at", e.x, e.y, e.z),
            ));
        }
    }
    Ok(plan)
}

/// Parses bench's `--ao`: modes separated by commas, `both` for off and paper;
/// each mode once, in the order given.
fn parse_ao_list(s: &str) -> Result<Vec<AoMode>> {
    let mut out = Vec::new();
    for p in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let modes = if p == "both" {
            vec![AoMode::Off, AoMode::Paper]
        } else {
            vec![p
                .parse::<AoMode>()
                .map_err(|e| Error::usage("--ao", format!("{e} (or both)")))?]
        };
        for m in modes {
            if !out.contains(&m) {
                out.push(m);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--ao", "no AO mode given"));
    }
    Ok(out)
}

fn parse_parts(s: &str) -> Result<Vec<Part>> {
    let mut out = Vec::new();
    for p in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        if p == "all" {
            out.extend(Part::ALL);
        } else {
            out.push(p.parse().map_err(|e: String| Error::usage("--parts", e))?);
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--parts", "no part given"));
    }
    Ok(out)
}

pub fn run(args: &BenchArgs) -> Result<()> {
    use crate::bench::{self, BenchConfig};
    if !(args.max_variant_s.is_finite() && args.max_variant_s > 0.0) {
        return Err(Error::usage(
            "--max-variant-s",
            "must be a positive number of seconds",
        ));
    }
    let views = parse_views(args)?;
    let variants = bench::variants::parse_variants(&args.variants)?;
    let ao_modes = parse_ao_list(&args.ao)?;
    let cfg = BenchConfig {
        scenes: args.scenes.clone(),
        views,
        variants,
        ao_modes,
        reps: args.reps.unwrap_or(if args.quick { 1 } else { 10 }) as usize,
        size: args
            .size
            .unwrap_or(if args.quick { (96, 72) } else { (1024, 768) }),
        threads: args.threads.unwrap_or_else(default_threads),
        quick: args.quick,
        max_variant_s: args.max_variant_s,
        parts: parse_parts(&args.parts)?,
        out: args.out.clone(),
        force: args.force,
        quiet: args.quiet,
        rays: None,
        command: crate::bench::summary::command_line(std::env::args()),
        rebuild_factors: args.rebuild_factor.clone().map_or(Vec::new(), |f| f.0),
        ref_policy: args.files.policy(),
    };
    if args.rebuild_factor.is_some() && !cfg.wants(crate::bench::config::Part::Animation) {
        return Err(Error::usage(
            "--rebuild-factor",
            "applies to the animation part (--parts animation)",
        ));
    }
    let mut cfg = cfg;
    // Before the scenes load and the measuring starts.
    crate::bench::check_out_dir(&cfg.out, cfg.force)?;
    if let Some(path) = &args.rays {
        if args.scenes.len() != 1 {
            return Err(Error::usage(
                "--rays",
                "a ray file is traced in one scene: give exactly one",
            ));
        }
        if args.parts != "all" && cfg.parts != [crate::bench::config::Part::Libraries] {
            return Err(Error::usage(
                "--rays",
                "a ray file is traced by the libraries part only (--parts libraries)",
            ));
        }
        cfg.parts = vec![crate::bench::config::Part::Libraries];
        cfg.rays = Some(crate::measure::rayfile::read(path)?);
    }
    if args.cliffs {
        if args.parts != "all" && cfg.parts != [crate::bench::config::Part::Libraries] {
            return Err(Error::usage(
                "--cliffs",
                "the cliff finder runs the libraries part only (--parts libraries)",
            ));
        }
        cfg.parts = vec![crate::bench::config::Part::Libraries];
        let classes = crate::bench::parts::cliffs::CLASSES
            .iter()
            .map(|(_, full, quick)| if args.quick { *quick } else { *full }.to_string());
        cfg.scenes = classes.chain(args.scenes.iter().cloned()).collect();
    }
    let names: Vec<String> = if cfg.scenes.is_empty() {
        BUILTIN_SCENES.iter().map(|(n, _)| n.to_string()).collect()
    } else {
        cfg.scenes.clone()
    };
    args.files.check(&names)?;
    // The instances part loads its scenes itself, instances kept: a run of
    // it alone flattens nothing (forest:100000 does not fit flattened).
    let only_instances = cfg.parts == [crate::bench::config::Part::Instances];
    let mut scenes = names
        .iter()
        .filter(|_| !only_instances)
        .map(|n| args.files.load(n))
        .collect::<Result<Vec<_>>>()?;
    for scene in &mut scenes {
        // A view whose eye is the point it looks at: refused before any work.
        for view in cfg.views.views_for(scene, cfg.size) {
            if view.eye == view.look {
                let flag = if args.eye.is_some() {
                    "--eye"
                } else {
                    "--views"
                };
                return Err(Error::usage(
                    flag,
                    format!("{} is the point looked at in {}", view.label(), scene.name),
                ));
            }
        }
        scene.set_extra_light(None, args.up);
        if !args.quiet {
            for w in &scene.warnings {
                crate::console::say(&format!("warning: {}: {w}", scene.name));
            }
        }
    }
    let report = bench::run(&cfg, &scenes)?;
    if args.json {
        crate::console::outln(&serde_json::to_string_pretty(&report)?)?;
    } else {
        crate::console::out(&bench::markdown(&report))?;
        crate::console::outln(&format!(
            "Report: {} (also bench.md, summary.md, bench.csv, bench.json, charts/); {:.0} s.",
            cfg.out.join("index.html").display(),
            report.elapsed_s
        ))?;
    }
    if let Some(m) = report.measurements.iter().find(|m| !m.deterministic) {
        return Err(Error::Other(format!(
            "bench: {} gave different images in repeated runs on {} {}",
            m.variant, m.scene, m.view
        )));
    }
    if let Some(v) = report.parts.validation().iter().find(|v| v.genuine > 0) {
        return Err(Error::Other(format!(
            "bench: {} disagrees with {} on {} rays of {}",
            v.tested, v.reference, v.genuine, v.scene
        )));
    }
    // Embree's wrong answers are its own rounding, reported in the table
    // (as the libraries part reports them); raylab's trees must answer as
    // a fresh build does, bit for bit.
    if let Some(p) = report
        .parts
        .animation()
        .iter()
        .find(|p| p.wrong > 0 && !p.embree)
    {
        return Err(Error::Other(format!(
            "bench: {} answers {} of {} rays unlike a fresh build on frame {} of {}",
            p.strategy, p.wrong, p.checked, p.frame, p.scene
        )));
    }
    Ok(())
}
