//! `raylab stats`: its flags and the builder reports per scene.

use clap::Args;

use super::args::{parse_leaf_size, parse_threads, SceneFileArgs, ViewArgs};
use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::error::Result;
use crate::render::schedule::default_threads;
use crate::scene::builtin::BUILTIN_SCENES;

/// What `--builder` takes: every builder's name, and `all`.
fn builder_names() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(
        BuilderKind::ALL
            .map(BuilderKind::name)
            .into_iter()
            .chain(["all"]),
    )
}

#[derive(Args, Debug)]
pub struct StatsArgs {
    /// Scene files (.obj, .ply, .gltf, .glb) or built-in names [default: the
    /// four built-in Cornell boxes].
    scenes: Vec<String>,
    /// Which builders to measure: one builder, or all (the
    /// Embree ones only when Embree is built in).
    #[arg(long, value_name = "NAME", default_value = "all", value_parser = builder_names())]
    builder: String,
    /// Most triangles per leaf for every builder [default: each builder's own].
    #[arg(long, value_name = "N", value_parser = parse_leaf_size)]
    leaf_size: Option<usize>,
    /// Reinsertion-optimise every builder's tree (as `render --optimize`).
    #[arg(long)]
    optimize: bool,
    /// Threads for the parallel build and the counting render [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    /// Timed builds per measurement (the median is reported).
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    reps: u32,
    #[command(flatten)]
    view: ViewArgs,
    #[command(flatten)]
    files: SceneFileArgs,
    /// Print the reports as one JSON array on stdout instead of a table.
    #[arg(long)]
    json: bool,
    /// No progress lines on stderr (one per scene and builder).
    #[arg(long, short = 'q')]
    quiet: bool,
}

pub fn run(args: &StatsArgs) -> Result<()> {
    let threads = args.threads.unwrap_or_else(default_threads);
    let builders: Vec<BuilderKind> = if args.builder == "all" {
        BuilderKind::ALL
            .into_iter()
            .filter(|b| b.embree_quality().is_none() || crate::accel::embree::AVAILABLE)
            .collect()
    } else {
        BuilderKind::ALL
            .into_iter()
            .filter(|b| b.name() == args.builder)
            .collect()
    };
    let names: Vec<String> = if args.scenes.is_empty() {
        BUILTIN_SCENES.iter().map(|(n, _)| n.to_string()).collect()
    } else {
        args.scenes.clone()
    };
    args.files.check(&names)?;
    let mut reports = Vec::new();
    for name in &names {
        let mut scene = args.files.load(name)?;
        let settings = args.view.prepare(&mut scene)?;
        for &builder in &builders {
            let mut params = BuildParams::for_builder(builder).with_optimize(args.optimize);
            if let Some(n) = args.leaf_size {
                params = params.with_max_leaf_size(n);
            }
            if !args.quiet {
                crate::console::say(&format!(
                    "stats: {} with {} ...",
                    scene.name,
                    builder.name()
                ));
            }
            reports.push(crate::measure::stats::builder_report(
                &scene,
                &params,
                &settings,
                threads,
                args.reps as usize,
            )?);
        }
    }
    if args.json {
        crate::console::outln(&serde_json::to_string_pretty(&reports)?)?;
    } else {
        crate::console::out(&crate::measure::stats::markdown_table(&reports))?;
        crate::console::outln(&format!(
            "Render for work per ray: {}x{}, ao {}, {} light sample(s); builds on 1 and {} threads, median of {}.",
            args.view.size.0, args.view.size.1, args.view.ao, args.view.light_samples, threads, args.reps
        ))?;
    }
    Ok(())
}
