//! The command line: parses flags with clap, runs the library, prints a readable
//! summary on stderr and (with `--json`) one JSON object on stdout. Every error is
//! one line on stderr and a non-zero exit status.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};
use glam::Vec3;
use serde::Serialize;

use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::accel::embree::Quality;
use crate::accel::{build_backend, BackendKind, BackendSpec};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::Intersector;
use crate::progress::Progress;
use crate::render::{self, output, AoMode, RenderSettings, Schedule};
use crate::scene::builtin::{builtin, BUILTIN_SCENES, PROCEDURAL_SCENES};
use crate::scene::light::LightArg;
use crate::scene::load::load_file;
use crate::scene::Scene;

#[derive(Parser, Debug)]
#[command(
    name = "raylab",
    version,
    about = "Compare ray-tracing acceleration structures on the CPU"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene with one backend and schedule, write a PNG and print timings.
    Render(RenderArgs),
    /// Check one backend's hits against another's on the same ray sets.
    Validate(ValidateArgs),
    /// Find where intersection methods fail: leaks, self-intersection offsets,
    /// degenerate and hostile input.
    Stress(StressArgs),
    /// BVH quality per scene and builder: build times, shape, SAH cost, and
    /// traversal work per ray measured over a render.
    Stats(StatsArgs),
    /// The study's tables (times and speedups of every variant over scenes,
    /// views and AO modes), scaling and accuracy charts, and an HTML report.
    Bench(BenchArgs),
    /// List the built-in scenes.
    Scenes,
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// .obj files or built-in names [default: the four built-in Cornell boxes].
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
    /// Vertical field of view in degrees, in (0, 180).
    #[arg(long, value_name = "DEG", default_value_t = 60.0, value_parser = parse_fov)]
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
    /// growth, ao-error, builders, leaks, validate.
    #[arg(long, value_name = "LIST", default_value = "all")]
    parts: String,
    /// Folder for bench.md, bench.csv, bench.json, charts/, images/ and index.html.
    #[arg(long, value_name = "DIR", default_value = "bench-report")]
    out: PathBuf,
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

fn parse_parts(s: &str) -> Result<Vec<&'static str>> {
    use crate::bench::PARTS;
    let mut out = Vec::new();
    for p in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        if p == "all" {
            out.extend(PARTS);
            continue;
        }
        let known = PARTS.iter().find(|k| **k == p).ok_or_else(|| {
            Error::usage(
                "--parts",
                format!("unknown part '{p}' (known: all, {})", PARTS.join(", ")),
            )
        })?;
        out.push(*known);
    }
    if out.is_empty() {
        return Err(Error::usage("--parts", "no part given"));
    }
    Ok(out)
}

fn run_bench(args: &BenchArgs) -> Result<()> {
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
        quiet: args.quiet,
    };
    let names: Vec<String> = if cfg.scenes.is_empty() {
        BUILTIN_SCENES.iter().map(|(n, _)| n.to_string()).collect()
    } else {
        cfg.scenes.clone()
    };
    let mut scenes = names
        .iter()
        .map(|n| load_scene(n))
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
                eprintln!("warning: {}: {w}", scene.name);
            }
        }
    }
    let report = bench::run(&cfg, &scenes)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", bench::markdown(&report));
        println!(
            "Report: {} (also bench.md, bench.csv, bench.json, charts/); {:.0} s.",
            cfg.out.join("index.html").display(),
            report.elapsed_s
        );
    }
    if let Some(m) = report.measurements.iter().find(|m| !m.deterministic) {
        return Err(Error::Other(format!(
            "bench: {} gave different images in repeated runs on {} {}",
            m.variant, m.scene, m.view
        )));
    }
    if let Some(v) = report.validation.iter().find(|v| v.genuine > 0) {
        return Err(Error::Other(format!(
            "bench: {} disagrees with {} on {} rays of {}",
            v.tested, v.reference, v.genuine, v.scene
        )));
    }
    Ok(())
}

/// Camera, lighting and shading flags shared by commands that render.
#[derive(Args, Debug, Clone)]
pub struct ViewArgs {
    /// Eye position [default: (0,1,3) for the built-in boxes; for other scenes
    /// the framing rule (see the README)].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    pub eye: Option<Vec3>,
    /// Point looked at [default: (0,1,0) for the built-in boxes; the centre of
    /// the scene's bounding box for other scenes].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    pub look: Option<Vec3>,
    /// Up vector (also the axis the default light and view are placed along).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, default_value = "0,1,0", value_parser = parse_vec3)]
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180).
    #[arg(long, value_name = "DEG", default_value_t = 60.0, value_parser = parse_fov)]
    pub fov: f32,
    /// Image size.
    #[arg(long, value_name = "WxH", default_value = "1024x768", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Ambient occlusion: off, paper (the study's 14 fixed directions) or cosine:N.
    #[arg(long, value_name = "MODE", default_value = "paper")]
    pub ao: AoMode,
    /// Length of AO rays in scene units [default: 0.2 for the built-in boxes,
    /// 1/16 of the bounding box's diagonal for other scenes].
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    pub ao_dist: Option<f32>,
    /// Shadow rays per pixel towards the lights.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub light_samples: u32,
    /// A light that is not geometry: point:X,Y,Z[:INTENSITY] or
    /// quad:X,Y,Z:SIZE[:RADIANCE] (a square facing down -Y); without a power it
    /// gives the default light's irradiance at the scene's centre. It is added to
    /// the scene's emitters, and replaces the default light of a scene without.
    #[arg(long, value_name = "SPEC", allow_hyphen_values = true)]
    pub light: Option<LightArg>,
    /// Emitters shine from both faces, not only from the side their winding's
    /// normal points to.
    #[arg(long)]
    pub two_sided_lights: bool,
    /// Seed of the per-pixel random streams.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
}

impl ViewArgs {
    /// Lights `scene` as the flags say (a `--light`, or the default light of a
    /// scene without emissive triangles, with a warning) and makes the render
    /// settings: the camera from the flags or, where they are not given, the
    /// scene's default view.
    pub fn prepare(&self, scene: &mut Scene) -> Result<RenderSettings> {
        let light = self.light.map(|l| l.emitter(&scene.bounds()));
        scene.set_extra_light(light, self.up);
        let (width, height) = self.size;
        let (eye, look) = default_view(scene, self.eye, self.look, self.up, self.fov, self.size);
        if !(eye.is_finite() && look.is_finite()) {
            return Err(Error::Scene {
                name: scene.name.clone(),
                msg: "too large to frame with f32 rays (the default view's eye is beyond f32): give --eye and --look".into(),
            });
        }
        let camera = Camera::new(eye, look, self.up, self.fov, width, height)?;
        let settings = RenderSettings {
            width,
            height,
            camera,
            ao: self.ao,
            ao_dist: self.ao_dist.unwrap_or_else(|| default_ao_dist(scene)),
            light_samples: self.light_samples,
            seed: self.seed,
            two_sided_lights: self.two_sided_lights,
        };
        settings.validate()?;
        Ok(settings)
    }
}

/// The eye and look-at point: the given ones, else the study's view for a
/// built-in box, else the framing of the scene's bounds (a given `look` moves
/// the framed eye with it).
pub fn default_view(
    scene: &Scene,
    eye: Option<Vec3>,
    look: Option<Vec3>,
    up: Vec3,
    fov: f32,
    (width, height): (u32, u32),
) -> (Vec3, Vec3) {
    let (framed_eye, framed_look) = if scene.study_frame {
        (Vec3::new(0.0, 1.0, 3.0), Vec3::new(0.0, 1.0, 0.0))
    } else {
        let points = scene
            .triangles
            .iter()
            .flatten()
            .map(|&i| scene.positions[i as usize]);
        crate::camera::framing(points, up, fov, width, height)
    };
    match (eye, look) {
        (Some(e), Some(l)) => (e, l),
        (Some(e), None) => (e, framed_look),
        (None, Some(l)) => (l + (framed_eye - framed_look), l),
        (None, None) => (framed_eye, framed_look),
    }
}

/// 0.2 (the study's) in the built-in boxes, else 1/16 of the bounding box's
/// diagonal (0.22 for the box, so files of any scale get the same look).
pub fn default_ao_dist(scene: &Scene) -> f32 {
    if scene.study_frame {
        0.2
    } else {
        let b = scene.bounds();
        ((b.max - b.min).length() / 16.0).max(f32::MIN_POSITIVE)
    }
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// An .obj file or a built-in scene name (see `raylab scenes`).
    #[arg(default_value = "cornell-original")]
    scene: String,
    /// Acceleration structure [default: bvh, raylab's fastest; naive is the
    /// study's O(N) baseline, hours on a large model].
    #[arg(long, value_enum, default_value_t = BackendKind::Bvh)]
    backend: BackendKind,
    #[command(flatten)]
    bvh: BvhArgs,
    #[command(flatten)]
    embree: EmbreeArgs,
    /// How the image is divided between threads.
    #[arg(long, value_enum, default_value_t = Schedule::Tiles)]
    schedule: Schedule,
    /// Worker threads for the tiles and rayon schedules [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    #[command(flatten)]
    view: ViewArgs,
    /// Output PNG.
    #[arg(
        short = 'o',
        long = "output",
        value_name = "PNG",
        default_value = "out.png"
    )]
    output: PathBuf,
    /// Print one JSON object with the results on stdout.
    #[arg(long)]
    json: bool,
    /// No progress bar and no summary on stderr.
    #[arg(long, short = 'q')]
    quiet: bool,
}

/// How a BVH is built (used with `--backend bvh`).
#[derive(Args, Debug, Clone)]
pub struct BvhArgs {
    /// BVH builder: median (the study's) or sah (binned SAH).
    #[arg(long, value_enum, default_value_t = BuilderKind::Sah)]
    pub builder: BuilderKind,
    /// Most triangles per BVH leaf [default: 1 for median, 4 for sah].
    #[arg(long, value_name = "N", value_parser = parse_leaf_size)]
    pub leaf_size: Option<usize>,
    /// Threads for the BVH build [default: --threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub build_threads: Option<usize>,
    /// Ray/triangle test of the naive and bvh backends.
    #[arg(long, value_enum, default_value_t = Intersector::Mt)]
    pub intersector: Intersector,
    /// Children per BVH node traversed: 8 (8-wide nodes built directly and tested
    /// with AVX2 where the CPU has it; the fastest), 4 (the built tree collapsed
    /// into 4-wide nodes tested with SSE), or 2 (the binary tree as built).
    #[arg(long, value_name = "N", default_value_t = 8, value_parser = parse_bvh_width)]
    pub bvh_width: usize,
}

fn parse_bvh_width(s: &str) -> std::result::Result<usize, String> {
    match s {
        "2" => Ok(2),
        "4" => Ok(4),
        "8" => Ok(8),
        _ => Err(format!("'{s}' must be 2, 4 or 8")),
    }
}

impl BvhArgs {
    pub fn params(&self, builder: BuilderKind, threads: usize) -> BuildParams {
        let p = BuildParams::for_builder(builder)
            .with_threads(self.build_threads.unwrap_or(threads))
            .with_width(self.bvh_width);
        match self.leaf_size {
            Some(n) => p.with_max_leaf_size(n),
            None => p,
        }
    }
}

/// How the Embree backend builds its scene (used with `--backend embree`).
#[derive(Args, Debug, Clone)]
pub struct EmbreeArgs {
    /// Embree's scene build quality.
    #[arg(long, value_enum, default_value_t = Quality::Medium)]
    pub embree_quality: Quality,
    /// Set RTC_SCENE_FLAG_ROBUST (watertight-leaning traversal, slower).
    #[arg(long)]
    pub embree_robust: bool,
}

/// The backend a command's flags describe.
fn backend_spec(
    kind: BackendKind,
    bvh: &BvhArgs,
    embree: &EmbreeArgs,
    threads: usize,
) -> BackendSpec {
    BackendSpec {
        kind,
        bvh: bvh.params(bvh.builder, threads),
        intersector: bvh.intersector,
        embree_quality: embree.embree_quality,
        embree_robust: embree.embree_robust,
    }
}

fn parse_leaf_size(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=255).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' must be a whole number in 1..=255")),
    }
}

#[derive(Args, Debug)]
struct StatsArgs {
    /// .obj files or built-in names [default: the four built-in Cornell boxes].
    scenes: Vec<String>,
    /// Which builders to measure: median, sah, embree-low, embree-medium,
    /// embree-high, or all (the Embree ones only when Embree is built in).
    #[arg(long, value_name = "NAME", default_value = "all", value_parser = ["median", "sah", "embree-low", "embree-medium", "embree-high", "all"])]
    builder: String,
    /// Most triangles per leaf for every builder [default: each builder's own].
    #[arg(long, value_name = "N", value_parser = parse_leaf_size)]
    leaf_size: Option<usize>,
    /// Threads for the parallel build and the counting render [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    /// Timed builds per measurement (the median is reported).
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    reps: u32,
    #[command(flatten)]
    view: ViewArgs,
    /// Print the reports as one JSON array on stdout instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
struct ValidateArgs {
    /// .obj files or built-in names [default: the four built-in Cornell boxes].
    scenes: Vec<String>,
    /// The backend under test.
    #[arg(long, value_enum, default_value_t = BackendKind::Bvh)]
    backend: BackendKind,
    #[command(flatten)]
    bvh: BvhArgs,
    #[command(flatten)]
    embree: EmbreeArgs,
    /// The reference backend (built with its defaults).
    #[arg(long, value_enum, default_value_t = if crate::accel::embree::AVAILABLE { BackendKind::Embree } else { BackendKind::Naive })]
    against: BackendKind,
    /// Ray sets to compare.
    #[arg(long, value_name = "SET", default_value = "all", value_parser = ["primary", "shadow", "ao", "random", "all"])]
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
    /// Print one JSON array with a report per scene on stdout.
    #[arg(long)]
    json: bool,
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
    sets: Vec<crate::validate::SetReport>,
    diff_image: Option<String>,
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

fn run_validate(args: &ValidateArgs) -> Result<()> {
    use crate::validate::{compare, mismatch_image, ray_sets, RaySet};
    let threads = args.threads.unwrap_or_else(default_threads);
    let names: Vec<String> = if args.scenes.is_empty() {
        BUILTIN_SCENES.iter().map(|(n, _)| n.to_string()).collect()
    } else {
        args.scenes.clone()
    };
    if let Some(path) = &args.diff_image {
        output::check_writable(&diff_image_path(path, &names[0], names.len() > 1))?;
    }
    let sets: Vec<RaySet> = match args.rays.as_str() {
        "primary" => vec![RaySet::Primary],
        "shadow" => vec![RaySet::Shadow],
        "ao" => vec![RaySet::Ao],
        "random" => vec![RaySet::Random],
        _ => RaySet::ALL.to_vec(),
    };
    let count = args.count as usize;
    let spec = backend_spec(args.backend, &args.bvh, &args.embree, threads);
    // The reference with its defaults (Embree MEDIUM, SAH BVH, MT) on `threads`.
    let reference_spec =
        BackendSpec::bvh(BuildParams::sah().with_threads(threads)).with_kind(args.against);
    let mut reports = Vec::new();
    for name in &names {
        let mut scene = load_scene(name)?;
        let settings = args.view.prepare(&mut scene)?;
        let tested = build_backend(&spec, &scene)?;
        let reference = build_backend(&reference_spec, &scene)?;
        let triangles = scene.triangle_vertices();
        // Record the render's rays with the faster of the two (naive is slow).
        let recorder: &dyn crate::accel::Backend = if args.against == BackendKind::Naive {
            tested.as_ref()
        } else {
            reference.as_ref()
        };
        let set_rays = ray_sets(
            &scene,
            recorder,
            &settings,
            &sets,
            count,
            args.diff_image.is_some(),
        )?;
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
        if !args.json {
            println!(
                "{} ({} triangles): {} against {}",
                scene.name,
                scene.triangle_count(),
                tested.name(),
                reference.name()
            );
            println!("| set | rays | hit/miss agree | same triangle | ties | genuine | occlusion mismatches | max rel dt | mean rel dt |");
            println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
            for r in &set_reports {
                println!(
                    "| {} | {} | {} | {} | {} | {} | {} | {:.2e} | {:.2e} |",
                    r.set,
                    r.rays,
                    r.hit_miss_agree,
                    r.same_triangle,
                    r.ties,
                    r.genuine,
                    r.occlusion_mismatches,
                    r.max_rel_dt,
                    r.mean_rel_dt
                );
            }
            let verdict = if genuine <= args.max_genuine {
                "ok"
            } else {
                "FAIL"
            };
            println!(
                "{verdict}: {genuine} genuine disagreements (max {}), {ties} ties\n",
                args.max_genuine
            );
        }
        reports.push(ValidateReport {
            scene: scene.name.clone(),
            backend: tested.name(),
            against: reference.name(),
            genuine,
            ties,
            max_genuine: args.max_genuine,
            pass: genuine <= args.max_genuine,
            sets: set_reports,
            diff_image: diff_written,
        });
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    }
    let failed: Vec<&str> = reports
        .iter()
        .filter(|r| !r.pass)
        .map(|r| r.scene.as_str())
        .collect();
    if failed.is_empty() {
        Ok(())
    } else {
        Err(Error::Other(format!(
            "validate: genuine disagreements above --max-genuine {} in {}",
            args.max_genuine,
            failed.join(", ")
        )))
    }
}

#[derive(Args, Debug)]
struct StressArgs {
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
    /// Backends of the leak suite, separated by commas: all, naive, bvh-median,
    /// bvh-sah, embree (each with both intersectors or both Embree modes). The
    /// naive scan tests every triangle per ray: minutes on a mesh of 10^4.
    #[arg(long, value_name = "LIST", default_value = "all")]
    backends: String,
    /// Write stress.md, stress.json and leaks.csv into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print the report as one JSON object on stdout instead of tables.
    #[arg(long)]
    json: bool,
}

fn run_stress(args: &StressArgs) -> Result<()> {
    use crate::stress::*;
    let want = |name: &str| args.suite == "all" || args.suite == name;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        output::check_writable(&dir.join("probe.png"))?;
    }
    let kinds = parse_stress_backends(&args.backends)?;
    // The user's meshes are read (and refused when open) before any suite runs.
    let user_meshes = args
        .mesh
        .iter()
        .map(|p| file_mesh(p))
        .collect::<Result<Vec<_>>>()?;
    let mut report = StressReport::default();
    let q = args.quick;
    if want("leaks") {
        eprintln!("stress: leaks ...");
        let mut meshes = leak_meshes(q);
        meshes.extend(user_meshes);
        report.leaks = leak_suite_with(&meshes, if q { 2 } else { 4 }, &kinds)?;
    }
    if want("offset") {
        eprintln!("stress: offset ...");
        let shifts: &[f32] = if q {
            &[0.0, 1e2, 1e4, 1e6]
        } else {
            &[0.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6]
        };
        report.offset = offset_suite(shifts, if q { 2000 } else { 20_000 })?;
    }
    if want("degenerate") {
        eprintln!("stress: degenerate ...");
        report.degenerate = degenerate_suite(if q { 2000 } else { 20_000 })?;
    }
    if want("hostile") {
        eprintln!("stress: hostile ...");
        report.hostile = Some(hostile_suite(if q { 500 } else { 5000 }, 1)?);
    }
    let json = serde_json::to_string_pretty(&report)?;
    if let Some(dir) = &args.out {
        let write = |name: &str, text: &str| output::write_text(&dir.join(name), text);
        write("stress.md", &report.markdown())?;
        write("stress.json", &json)?;
        let mut csv =
            String::from("mesh,triangles,backend,intersector,rays,leaks,leak_rate,ns_per_ray\n");
        for r in &report.leaks {
            csv.push_str(&format!(
                "{},{},{},{},{},{},{},{}\n",
                r.mesh,
                r.triangles,
                r.backend,
                r.intersector,
                r.rays,
                r.leaks,
                r.leak_rate,
                r.ns_per_ray
            ));
        }
        write("leaks.csv", &csv)?;
    }
    if args.json {
        println!("{json}");
    } else {
        print!("{}", report.markdown());
    }
    let hostile_failed = report
        .hostile
        .as_ref()
        .is_some_and(|h| h.panics > 0 || h.invalid_scenes > 0 || h.multi_line_errors > 0);
    let nan = report.degenerate.iter().any(|r| r.nan_results > 0);
    if hostile_failed || nan {
        return Err(Error::Other(
            "stress: raylab itself failed (panic, NaN or invalid scene): see the report".into(),
        ));
    }
    Ok(())
}

fn run_stats(args: &StatsArgs) -> Result<()> {
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
    let mut reports = Vec::new();
    for name in &names {
        let mut scene = load_scene(name)?;
        let settings = args.view.prepare(&mut scene)?;
        for &builder in &builders {
            let mut params = BuildParams::for_builder(builder);
            if let Some(n) = args.leaf_size {
                params = params.with_max_leaf_size(n);
            }
            eprintln!("stats: {} with {} ...", scene.name, builder.name());
            reports.push(crate::stats::builder_report(
                &scene,
                &params,
                &settings,
                threads,
                args.reps as usize,
            )?);
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        print!("{}", crate::stats::markdown_table(&reports));
        println!(
            "Render for work per ray: {}x{}, ao {}, {} light sample(s); builds on 1 and {} threads, median of {}.",
            args.view.size.0, args.view.size.1, args.view.ao, args.view.light_samples, threads, args.reps
        );
    }
    Ok(())
}

fn parse_vec3(s: &str) -> std::result::Result<Vec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers X,Y,Z, got {}",
            parts.len()
        ));
    }
    let mut v = [0.0f32; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p.parse().map_err(|_| format!("'{p}' is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("'{p}' is not finite"));
        }
    }
    Ok(Vec3::from_array(v))
}

fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| "expected WIDTHxHEIGHT, e.g. 1024x768".to_string())?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("width '{w}' is not a whole number"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("height '{h}' is not a whole number"))?;
    if w == 0 || h == 0 {
        return Err("width and height must be at least 1".into());
    }
    if w > 16384 || h > 16384 {
        return Err("width and height must be at most 16384".into());
    }
    Ok((w, h))
}

fn parse_fov(s: &str) -> std::result::Result<f32, String> {
    let f: f32 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(f > 0.0 && f < 180.0) {
        return Err(format!("{f} is outside (0, 180) degrees"));
    }
    Ok(f)
}

fn parse_threads(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=1024).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' must be a whole number in 1..=1024")),
    }
}

/// The linked Embree's version ("none" in a build without Embree).
pub fn embree_version() -> String {
    #[cfg(feature = "embree")]
    return crate::accel::embree::version();
    #[cfg(not(feature = "embree"))]
    "none".to_string()
}

/// All hardware threads, the default for `--threads`.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Loads `spec`: a scene file (an existing file, a path, or a name with a scene
/// extension), or else a built-in scene name.
pub fn load_scene(spec: &str) -> Result<Scene> {
    let path = Path::new(spec);
    let has_scene_extension = path.extension().is_some_and(|e| {
        let e = e.to_string_lossy().to_ascii_lowercase();
        crate::scene::load::EXTENSIONS.contains(&e.as_str())
    });
    let looks_like_file = has_scene_extension || spec.contains(std::path::MAIN_SEPARATOR);
    if looks_like_file || path.is_file() {
        load_file(path)
    } else {
        builtin(spec)
    }
}

/// A rate with three significant digits (the naive scan's 0.0041 Mrays/s read
/// "0.00" with two decimals).
fn significant(x: f64) -> String {
    if !(x.is_finite() && x > 0.0) {
        return format!("{x}");
    }
    let decimals = (2 - x.log10().floor() as i32).clamp(0, 9) as usize;
    format!("{x:.decimals$}")
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

#[derive(Serialize)]
struct RayCounts {
    primary: u64,
    /// Primary rays that hit the scene.
    primary_hits: u64,
    shadow: u64,
    ao: u64,
}

#[derive(Serialize)]
struct KindTimes {
    primary: f64,
    shadow: f64,
    ao: f64,
}

#[derive(Serialize)]
struct RenderReport {
    scene: String,
    triangles: usize,
    emissive_triangles: usize,
    dropped_degenerate: usize,
    backend: String,
    schedule: Schedule,
    threads: usize,
    width: u32,
    height: u32,
    ao: String,
    light_samples: u32,
    seed: u64,
    load_ms: f64,
    build_ms: f64,
    /// Bytes of the acceleration structure (BVH nodes and leaf triangles;
    /// for Embree, what its memory monitor reports the build left allocated).
    #[serde(skip_serializing_if = "Option::is_none")]
    memory_bytes: Option<usize>,
    render_ms: f64,
    rays: RayCounts,
    /// Time spent in each pass, summed over threads (includes that pass's shading).
    thread_ms: KindTimes,
    /// All rays over render wall time.
    mrays_per_s: f64,
    output: String,
    image_hash: String,
    warnings: Vec<String>,
    /// The linked Embree's version, for the embree backend.
    #[serde(skip_serializing_if = "Option::is_none")]
    embree_version: Option<String>,
}

fn run_render(args: &RenderArgs) -> Result<()> {
    output::check_writable(&args.output)?;
    let threads = args.threads.unwrap_or_else(default_threads);
    let say = |line: String| {
        if !args.quiet {
            eprintln!("{line}");
        }
    };

    let start = Instant::now();
    let mut scene = load_scene(&args.scene)?;
    let load_time = start.elapsed();
    let settings = args.view.prepare(&mut scene)?;
    for w in &scene.warnings {
        say(format!("warning: {w}"));
    }
    say(format!(
        "scene {}: {} triangles ({} emissive), loaded in {:.1} ms",
        scene.name,
        scene.triangle_count(),
        scene.lights.triangles.len(),
        ms(load_time)
    ));

    let backend = build_backend(
        &backend_spec(args.backend, &args.bvh, &args.embree, threads),
        &scene,
    )?;
    say(format!(
        "backend {}: built in {:.1} ms",
        backend.name(),
        ms(backend.build_time())
    ));

    let progress = Progress::new();
    let total_pixels = settings.width as u64 * settings.height as u64;
    // The clock stops inside the watched work, so the progress monitor's
    // shutdown is never part of the render time.
    let (rendered, render_time) = progress.watch(
        "render",
        total_pixels,
        args.quiet,
        Duration::from_secs(1),
        || {
            let start = Instant::now();
            let rendered = render::render(
                &scene,
                backend.as_ref(),
                &settings,
                args.schedule,
                threads,
                &progress,
            );
            (rendered, start.elapsed())
        },
    );
    let (frame, stats) = rendered?;

    let mut warnings = scene.warnings.clone();
    if stats.primary_hits * 100 < stats.primary_rays {
        let w = format!(
            "only {} of {} primary rays hit the scene (under 1%): check --eye, --look and --up",
            stats.primary_hits, stats.primary_rays
        );
        say(format!("warning: {w}"));
        warnings.push(w);
    }
    let rgb8 = output::to_srgb8(&frame);
    let hash = output::image_hash(&rgb8);
    output::write_png(&args.output, frame.width, frame.height, &rgb8)?;

    let threads_used = args.schedule.threads_used(threads, settings.height);
    let mrays = stats.total_rays() as f64 / render_time.as_secs_f64().max(1e-9) / 1e6;
    let per_thread = |rays: u64, t: Duration| rays as f64 / t.as_secs_f64().max(1e-9) / 1e6;
    say(format!(
        "render {}x{} {} ({} thread{}), ao {}: {:.1} ms, {:.2} M rays, {} Mrays/s",
        settings.width,
        settings.height,
        args.schedule.name(),
        threads_used,
        if threads_used == 1 { "" } else { "s" },
        settings.ao,
        ms(render_time),
        stats.total_rays() as f64 / 1e6,
        significant(mrays)
    ));
    say(format!(
        "  per thread: primary {} rays {} Mrays/s | shadow {} rays {} Mrays/s | ao {} rays {} Mrays/s",
        stats.primary_rays,
        significant(per_thread(stats.primary_rays, stats.primary_time)),
        stats.shadow_rays,
        significant(per_thread(stats.shadow_rays, stats.shadow_time)),
        stats.ao_rays,
        significant(per_thread(stats.ao_rays, stats.ao_time)),
    ));
    say(format!(
        "wrote {} (image hash {hash})",
        args.output.display()
    ));

    if args.json {
        let report = RenderReport {
            scene: scene.name.clone(),
            triangles: scene.triangle_count(),
            emissive_triangles: scene.lights.triangles.len(),
            dropped_degenerate: scene.dropped_degenerate,
            backend: backend.name(),
            schedule: args.schedule,
            threads: threads_used,
            width: settings.width,
            height: settings.height,
            ao: settings.ao.to_string(),
            light_samples: settings.light_samples,
            seed: settings.seed,
            load_ms: ms(load_time),
            build_ms: ms(backend.build_time()),
            memory_bytes: backend.memory_bytes(),
            render_ms: ms(render_time),
            rays: RayCounts {
                primary: stats.primary_rays,
                primary_hits: stats.primary_hits,
                shadow: stats.shadow_rays,
                ao: stats.ao_rays,
            },
            thread_ms: KindTimes {
                primary: ms(stats.primary_time),
                shadow: ms(stats.shadow_time),
                ao: ms(stats.ao_time),
            },
            mrays_per_s: mrays,
            output: args.output.display().to_string(),
            image_hash: hash,
            warnings,
            embree_version: (args.backend == BackendKind::Embree).then(embree_version),
        };
        let text = serde_json::to_string(&report)?;
        println!("{text}");
    }
    Ok(())
}

/// Runs the command line and returns the process exit status.
pub fn main() -> i32 {
    // A bug must still end in one line, not a backtrace over the user's terminal.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!("raylab: internal error{place}: {msg} (please report this)");
    }));
    crate::os::quiet_on_closed_pipe();
    use clap::{CommandFactory, FromArgMatches};
    let parsed = Cli::command()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m).map(|cli| (cli, m)));
    let (cli, matches) = match parsed {
        Ok(parsed) => parsed,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion)
                || e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            {
                let _ = e.print();
                return if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                    2
                } else {
                    0
                };
            }
            eprintln!("raylab: {}", one_line_clap_error(&e.render().to_string()));
            return 2;
        }
    };
    let sub = matches.subcommand().map(|(_, m)| m);
    let result = match &cli.command {
        Command::Render(args) => sub
            .map_or(Ok(()), |m| check_backend_flags(m, args.backend))
            .and_then(|()| run_render(args)),
        Command::Stats(args) => run_stats(args),
        Command::Validate(args) => sub
            .map_or(Ok(()), |m| check_backend_flags(m, args.backend))
            .and_then(|()| run_validate(args)),
        Command::Stress(args) => run_stress(args),
        Command::Bench(args) => run_bench(args),
        Command::Scenes => {
            for (name, about) in BUILTIN_SCENES.iter().chain(PROCEDURAL_SCENES) {
                println!("{name:18} {about}");
            }
            Ok(())
        }
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("raylab: {e}");
            1
        }
    }
}

/// clap's message in one line: its first line, then its tips and possible
/// values in brackets ("did you mean ..."), without the usage block.
fn one_line_clap_error(text: &str) -> String {
    let mut lines = text
        .lines()
        .take_while(|l| !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .map(str::trim)
        .filter(|l| !l.is_empty());
    let first = lines
        .next()
        .unwrap_or("invalid arguments")
        .trim_start_matches("error: ")
        .to_string();
    let rest: Vec<&str> = lines.collect();
    if rest.is_empty() {
        first
    } else {
        format!("{first} ({})", rest.join("; "))
    }
}

/// Refuses backend flags given on the command line that the chosen backend
/// would ignore (they used to be ignored silently).
fn check_backend_flags(m: &clap::ArgMatches, backend: BackendKind) -> Result<()> {
    use clap::parser::ValueSource;
    // (argument id, flag, the backends it applies to)
    const FLAGS: &[(&str, &str, &[BackendKind])] = &[
        ("builder", "--builder", &[BackendKind::Bvh]),
        ("leaf_size", "--leaf-size", &[BackendKind::Bvh]),
        ("bvh_width", "--bvh-width", &[BackendKind::Bvh]),
        (
            "build_threads",
            "--build-threads",
            &[BackendKind::Bvh, BackendKind::Embree],
        ),
        (
            "intersector",
            "--intersector",
            &[BackendKind::Naive, BackendKind::Bvh],
        ),
        ("embree_quality", "--embree-quality", &[BackendKind::Embree]),
        ("embree_robust", "--embree-robust", &[BackendKind::Embree]),
    ];
    let name = |k: &BackendKind| format!("{k:?}").to_lowercase();
    for (id, flag, applies) in FLAGS {
        let given = m.value_source(id) == Some(ValueSource::CommandLine);
        if given && !applies.contains(&backend) {
            let to: Vec<String> = applies
                .iter()
                .map(|k| format!("--backend {}", name(k)))
                .collect();
            return Err(Error::usage(
                flag,
                format!(
                    "applies only to {}, not to --backend {}",
                    to.join(" or "),
                    name(&backend)
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_keep_three_significant_digits() {
        assert_eq!(significant(44.4612), "44.5");
        assert_eq!(significant(0.004123), "0.00412");
        assert_eq!(significant(1234.5), "1234");
        assert_eq!(significant(0.0), "0");
    }

    #[test]
    fn clap_messages_become_one_line_with_their_tips() {
        let text = "error: unrecognized subcommand 'rendr'\n\n  tip: a similar subcommand exists: 'render'\n\nUsage: raylab <COMMAND>\n\nFor more information, try '--help'.\n";
        assert_eq!(
            one_line_clap_error(text),
            "unrecognized subcommand 'rendr' (tip: a similar subcommand exists: 'render')"
        );
    }
}
