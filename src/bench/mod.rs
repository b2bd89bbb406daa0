//! `raylab bench`: the study's tables for any scenes in one command, and the
//! experiments and charts that explain them, written as Markdown, CSV, JSON,
//! PNG/SVG charts and one HTML page.
//!
//! Parts: `tables` (the variant matrix, [`measure`]), `scaling`, `growth`,
//! `ao-error`, `builders`, `leaks` and `validate` ([`extras`]), and `trace`
//! (query throughput without shading, [`trace`]). Images for the
//! report come from the matrix's own renders.
//!
//! How the matrix measures and what each part does: `docs/design.md`, "The
//! bench"; results of full runs: `docs/results.md`.

pub mod charts;
pub mod extras;
pub mod html;
pub mod measure;
pub mod metrics;
pub mod tables;
pub mod trace;
pub mod variants;

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::{Error, Result};
use crate::progress::StepBar;
use crate::render::{output, AoMode};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};
use extras::{AoErrorPoint, BuilderPoint, GrowthPoint, ScalingPoint, ValidationRow};
use measure::{Matrix, Measurement, View, ViewPlan};
use variants::Variant;

/// The parts of a bench run (`--parts`), in the order they run. Each part's
/// name, report title, chart and caption are here, in one place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// The study's matrix: every variant on every scene, view and AO mode.
    Tables,
    /// Query throughput per backend and ray kind on recorded rays, and builds.
    Trace,
    /// Render speedup over one thread, per schedule.
    Scaling,
    /// Build time and time per ray against triangle count.
    Growth,
    /// AO error against render time.
    AoError,
    /// Tree quality against build and render time, per builder.
    Builders,
    /// Rays that leak through closed meshes, per intersection method.
    Leaks,
    /// Every BVH's hits against Embree's (or naive's).
    Validate,
}

impl Part {
    pub const ALL: [Part; 8] = [
        Part::Tables,
        Part::Trace,
        Part::Scaling,
        Part::Growth,
        Part::AoError,
        Part::Builders,
        Part::Leaks,
        Part::Validate,
    ];

    /// The name `--parts` takes.
    pub fn name(self) -> &'static str {
        match self {
            Part::Tables => "tables",
            Part::Trace => "trace",
            Part::Scaling => "scaling",
            Part::Growth => "growth",
            Part::AoError => "ao-error",
            Part::Builders => "builders",
            Part::Leaks => "leaks",
            Part::Validate => "validate",
        }
    }

    /// The HTML report's section title, the stem of the part's chart files and
    /// the chart's caption, for the parts with a section of their own (the
    /// tables part has the speedup section, validate has no chart).
    fn section(self) -> Option<(&'static str, &'static str, &'static str)> {
        Some(match self {
            Part::Trace => ("Query throughput", "trace-", "Rays traced per second per backend, scene and ray kind, on one thread count per chart (log scale; the same recorded rays for every backend, no shading)."),
            Part::Scaling => ("Thread scaling", "thread-scaling", "Render speedup over one thread per schedule; the grey line is ideal scaling."),
            Part::Growth => ("Cost growth", "cost-growth", "Build time and time per ray against triangle count (log-log): naive grows as O(N) per ray, the hierarchies as O(log N)."),
            Part::AoError => ("AO error against time", "ao-error", "Error of the study's 14 fixed AO directions and of N random cosine samples against a cosine reference, against render time."),
            Part::Builders => ("Builder quality", "builders", "Tree quality (SAH cost, nodes visited per ray) against build and render time."),
            Part::Leaks => ("Leaks against speed", "leaks", "Rays that pass through closed meshes at vertices and edges, against query time, per intersection method."),
            Part::Tables | Part::Validate => return None,
        })
    }

    /// Whether the part draws a chart (and so needs the chart font).
    fn draws(self) -> bool {
        self != Part::Validate
    }
}

impl std::str::FromStr for Part {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Part, String> {
        Part::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Part::ALL.iter().map(|p| p.name()).collect();
                format!("unknown part '{s}' (known: all, {})", names.join(", "))
            })
    }
}

/// Everything a bench run needs; built by the CLI from its flags.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub scenes: Vec<String>,
    pub views: ViewPlan,
    pub variants: Vec<Variant>,
    pub ao_modes: Vec<AoMode>,
    pub reps: usize,
    pub size: (u32, u32),
    pub threads: usize,
    pub quick: bool,
    pub max_variant_s: f64,
    pub parts: Vec<Part>,
    pub out: PathBuf,
    pub quiet: bool,
}

impl BenchConfig {
    fn wants(&self, part: Part) -> bool {
        self.parts.contains(&part)
    }

    /// Sizes of the procedural meshes of the cost-growth part.
    fn growth_sizes(&self) -> Vec<u64> {
        if self.quick {
            vec![1_000, 10_000]
        } else {
            vec![1_000, 10_000, 100_000, 1_000_000, 10_000_000]
        }
    }

    /// Sample counts N of `cosine:N` and the reference's N.
    fn ao_samples(&self) -> (Vec<u32>, u32) {
        if self.quick {
            (vec![1, 4, 16], 256)
        } else {
            ((0..=8).map(|k| 1 << k).collect(), 1024)
        }
    }

    /// Repetitions of the extra experiments (medians of these).
    fn extra_reps(&self) -> usize {
        if self.quick {
            1
        } else {
            self.reps.clamp(1, 3)
        }
    }

    /// An image size `divisor` times smaller than the bench's (at least 16 x 12).
    fn smaller(&self, divisor: u32) -> (u32, u32) {
        (
            (self.size.0 / divisor).max(16),
            (self.size.1 / divisor).max(12),
        )
    }

    /// The thread counts of the trace part: one, and all bench threads.
    fn trace_threads(&self) -> Vec<usize> {
        if self.threads > 1 {
            vec![1, self.threads]
        } else {
            vec![1]
        }
    }

    /// The thread counts of the scaling part: 1..=threads, then twice that.
    fn thread_counts(&self) -> Vec<usize> {
        let mut t: Vec<usize> = (1..=self.threads).collect();
        t.push(self.threads * 2);
        t
    }
}

/// The machine a bench ran on.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    pub cpu: String,
    pub physical_cores: Option<usize>,
    pub hardware_threads: usize,
    pub bench_threads: usize,
    pub os: String,
    pub embree_version: String,
    pub raylab_version: String,
}

impl Machine {
    pub fn detect(bench_threads: usize) -> Machine {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let field = |name: &str| {
            cpuinfo
                .lines()
                .find(|l| l.starts_with(name))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        };
        let os = std::fs::read_to_string("/etc/os-release")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("PRETTY_NAME="))
                    .map(|v| v.trim_matches('"').to_string())
            })
            .unwrap_or_else(|| std::env::consts::OS.to_string());
        Machine {
            cpu: field("model name").unwrap_or_else(|| std::env::consts::ARCH.to_string()),
            physical_cores: field("cpu cores").and_then(|v| v.parse().ok()),
            hardware_threads: crate::render::schedule::default_threads(),
            bench_threads,
            os,
            embree_version: crate::accel::embree::version_or_none(),
            raylab_version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }
}

/// One scene's pictures in the report.
#[derive(Clone, Debug, Serialize)]
pub struct SceneImages {
    pub scene: String,
    /// (variant, PNG path relative to the report folder).
    pub renders: Vec<(String, String)>,
    /// Amplified difference of each render against the first (naive when run).
    pub difference: Option<String>,
    /// Pixels whose 8-bit value differs from the first render, per other render.
    pub differing_pixels: Vec<(String, usize)>,
}

/// Everything a bench run measured; `bench.json` is this.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub machine: Machine,
    pub size: (u32, u32),
    pub reps: usize,
    pub quick: bool,
    pub max_variant_s: f64,
    pub views: Vec<String>,
    pub ao_modes: Vec<String>,
    pub variants: Vec<(String, String)>,
    pub baseline: String,
    pub measurements: Vec<Measurement>,
    pub trace: Vec<trace::TracePoint>,
    pub scaling: Vec<ScalingPoint>,
    pub growth: Vec<GrowthPoint>,
    pub ao_error: Vec<AoErrorPoint>,
    pub builders: Vec<BuilderPoint>,
    pub leaks: Vec<crate::stress::LeakRow>,
    pub validation: Vec<ValidationRow>,
    pub images: Vec<SceneImages>,
    /// PNG charts written (relative to the report folder).
    pub charts: Vec<String>,
    pub elapsed_s: f64,
}

/// Runs the bench and writes the report folder; returns the report.
pub fn run(cfg: &BenchConfig, scenes: &[Scene]) -> Result<BenchReport> {
    let started = std::time::Instant::now();
    for sub in ["", "charts", "images"] {
        let dir = cfg.out.join(sub);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    }
    output::check_writable(&cfg.out.join("images").join("probe.png"))?;
    if cfg.parts.iter().any(|p| p.draws()) {
        // Every part but validate draws a chart: fail before measuring for an
        // hour, not after.
        charts::init_font()?;
    }
    let images_ao = cfg
        .ao_modes
        .iter()
        .copied()
        .find(|a| *a == AoMode::Paper)
        .or(cfg.ao_modes.first().copied());
    let matrix = Matrix {
        scenes,
        views: &cfg.views,
        ao_modes: &cfg.ao_modes,
        variants: &cfg.variants,
        size: cfg.size,
        threads: cfg.threads,
        reps: cfg.reps,
        // --quick trades the warm-up for time: its numbers are a smoke test.
        warmup: !cfg.quick,
        max_variant_s: cfg.max_variant_s,
        seed: 1,
        images_ao,
    };
    let last_two: Vec<&Scene> = scenes.iter().rev().take(2).rev().collect();
    let (ao_n, _) = cfg.ao_samples();
    // Progress units are expected milliseconds; each step of the other parts
    // counts as `step` of them.
    let step: u64 = if cfg.quick { 100 } else { 3000 };
    let mut steps = 0;
    let trace_specs = trace::trace_specs(&cfg.variants, cfg.threads);
    if cfg.wants(Part::Trace) {
        steps += 3 * scenes.len() as u64;
    }
    if cfg.wants(Part::Scaling) {
        steps += extras::scaling_variants().len() as u64;
    }
    if cfg.wants(Part::Growth) {
        steps += (cfg.growth_sizes().len() * extras::growth_variants().len()) as u64;
    }
    if cfg.wants(Part::AoError) {
        steps += (last_two.len() * (ao_n.len() + 2)) as u64;
    }
    if cfg.wants(Part::Builders) {
        steps += (last_two.len() * extras::quality_builders().len()) as u64;
    }
    if cfg.wants(Part::Leaks) {
        steps += 1;
    }
    if cfg.wants(Part::Validate) {
        steps += 2 * scenes.len() as u64;
    }
    let mut units = steps * step;
    if cfg.wants(Part::Tables) {
        units += matrix.planned_units();
    }
    let bar = StepBar::new(units, cfg.quiet).with_step(step);

    let (measurements, kept) = if cfg.wants(Part::Tables) {
        matrix.run(&bar)?
    } else {
        (Vec::new(), Vec::new())
    };
    let reps = cfg.extra_reps();
    let last = scenes.last().expect("at least one scene");
    // The parts that render one view use each scene's first view.
    let first_view = |scene: &Scene, size| cfg.views.first_for(scene, size);
    let mut trace_points = Vec::new();
    if cfg.wants(Part::Trace) && !trace_specs.is_empty() {
        let trace_reps = if cfg.quick { 1 } else { cfg.reps.clamp(1, 5) };
        for scene in scenes {
            let settings = first_view(scene, cfg.size).settings(cfg.size, AoMode::Paper, 1)?;
            trace_points.extend(trace::trace_throughput(
                scene,
                &settings,
                &trace_specs,
                &cfg.trace_threads(),
                trace_reps,
                &bar,
            )?);
        }
    }
    let scaling = if cfg.wants(Part::Scaling) {
        let size = cfg.smaller(2);
        let settings = first_view(last, size).settings(size, AoMode::Paper, 1)?;
        extras::thread_scaling(last, &settings, &cfg.thread_counts(), reps, &bar)?
    } else {
        Vec::new()
    };
    let growth = if cfg.wants(Part::Growth) {
        let settings = View::PAPER[0].settings(
            if cfg.quick { (32, 24) } else { (96, 72) },
            AoMode::Paper,
            1,
        )?;
        let naive_max = if cfg.quick { 10_000 } else { 100_000 };
        extras::cost_growth(
            &cfg.growth_sizes(),
            &settings,
            cfg.threads,
            reps,
            naive_max,
            &bar,
        )?
    } else {
        Vec::new()
    };
    let mut ao_error = Vec::new();
    if cfg.wants(Part::AoError) {
        let (samples, reference) = cfg.ao_samples();
        let size = if cfg.quick { (48, 36) } else { (256, 192) };
        for scene in &last_two {
            let setup = extras::AoErrorSetup {
                view: first_view(scene, size),
                size,
                samples: samples.clone(),
                reference,
            };
            ao_error.extend(extras::ao_error(scene, &setup, cfg.threads, reps, &bar)?);
        }
    }
    let mut builders = Vec::new();
    if cfg.wants(Part::Builders) {
        let size = cfg.smaller(2);
        for scene in &last_two {
            let settings = first_view(scene, size).settings(size, AoMode::Paper, 1)?;
            builders.extend(extras::builder_quality(
                scene,
                &settings,
                cfg.threads,
                reps,
                &bar,
            )?);
        }
    }
    let leaks = if cfg.wants(Part::Leaks) {
        bar.set_message("leaks: rays at vertices and edges of closed meshes".into());
        let rows = crate::stress::leak_suite(
            &crate::stress::leak_meshes(cfg.quick),
            if cfg.quick { 2 } else { 4 },
        )?;
        bar.step();
        rows
    } else {
        Vec::new()
    };
    let mut validation = Vec::new();
    if cfg.wants(Part::Validate) {
        let count = if cfg.quick { 2_000 } else { 20_000 };
        for scene in scenes {
            let size = cfg.smaller(4);
            let settings = first_view(scene, size).settings(size, AoMode::Paper, 1)?;
            validation.extend(extras::validation(
                scene,
                &settings,
                count,
                cfg.threads,
                &bar,
            )?);
        }
    }
    bar.finish();

    let images = write_images(&cfg.out, scenes, &kept)?;
    let mut report = BenchReport {
        machine: Machine::detect(cfg.threads),
        size: cfg.size,
        reps: cfg.reps,
        quick: cfg.quick,
        max_variant_s: cfg.max_variant_s,
        views: distinct_labels(scenes.iter().flat_map(|s| cfg.views.views_for(s, cfg.size))),
        ao_modes: cfg.ao_modes.iter().map(|a| a.to_string()).collect(),
        variants: cfg
            .variants
            .iter()
            .map(|v| (v.name.to_string(), v.describe()))
            .collect(),
        baseline: tables::baseline_name(&measurements).to_string(),
        measurements,
        trace: trace_points,
        scaling,
        growth,
        ao_error,
        builders,
        leaks,
        validation,
        images,
        charts: Vec::new(),
        elapsed_s: 0.0,
    };
    report.charts = write_charts(&cfg.out.join("charts"), &report)?;
    report.elapsed_s = started.elapsed().as_secs_f64();
    write_files(&cfg.out, &report)?;
    Ok(report)
}

/// File-name form of a scene name (`mesh:1e5` and paths become safe names).
fn file_tag(name: &str) -> String {
    let stem = Path::new(name)
        .file_stem()
        .map_or(name.to_string(), |s| s.to_string_lossy().to_string());
    stem.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn write_images(
    dir: &Path,
    scenes: &[Scene],
    kept: &[measure::KeptFrame],
) -> Result<Vec<SceneImages>> {
    let mut out = Vec::new();
    for (si, scene) in scenes.iter().enumerate() {
        let frames: Vec<&measure::KeptFrame> = kept.iter().filter(|k| k.scene == si).collect();
        if frames.is_empty() {
            continue;
        }
        let tag = file_tag(&scene.name);
        let mut img = SceneImages {
            scene: scene.name.clone(),
            renders: Vec::new(),
            difference: None,
            differing_pixels: Vec::new(),
        };
        for k in &frames {
            let rel = format!("images/{tag}-{}.png", k.variant.name);
            let f = &k.frame;
            output::write_png(&dir.join(&rel), f.width, f.height, &output::to_srgb8(f))?;
            img.renders.push((k.variant.name.to_string(), rel));
        }
        if frames.len() > 1 {
            // Largest difference of any render from the first, amplified 8x.
            let first = &frames[0].frame;
            let mut combined = vec![0u8; first.pixels.len() * 3];
            for k in &frames[1..] {
                let (diff, n) = metrics::difference_image(first, &k.frame, 8.0)?;
                for (c, d) in combined.iter_mut().zip(diff) {
                    *c = (*c).max(d);
                }
                img.differing_pixels.push((k.variant.name.to_string(), n));
            }
            let rel = format!("images/{tag}-difference.png");
            output::write_png(&dir.join(&rel), first.width, first.height, &combined)?;
            img.difference = Some(rel);
        }
        out.push(img);
    }
    Ok(out)
}

fn write_charts(dir: &Path, r: &BenchReport) -> Result<Vec<String>> {
    let mut files = Vec::new();
    let mut push = |f: String| files.push(format!("charts/{f}"));
    if !r.measurements.is_empty() {
        for ao in &r.ao_modes {
            push(charts::speedup_chart(
                dir,
                &charts::SpeedupData {
                    ms: &r.measurements,
                    ao: ao.clone(),
                },
            )?);
        }
    }
    let mut trace_threads: Vec<usize> = r.trace.iter().map(|p| p.threads).collect();
    trace_threads.dedup();
    for threads in trace_threads {
        push(charts::trace_chart(
            dir,
            &charts::TraceData {
                points: &r.trace,
                threads,
            },
        )?);
    }
    if !r.scaling.is_empty() {
        push(charts::scaling_chart(dir, &r.scaling)?);
    }
    if !r.growth.is_empty() {
        push(charts::growth_chart(dir, &r.growth)?);
    }
    if !r.ao_error.is_empty() {
        push(charts::ao_error_chart(dir, &r.ao_error)?);
    }
    if !r.builders.is_empty() {
        push(charts::builders_chart(dir, &r.builders)?);
    }
    if !r.leaks.is_empty() {
        push(charts::leaks_chart(dir, &r.leaks)?);
    }
    Ok(files)
}

/// The Markdown of the whole report: the study's tables, then one table per
/// extra experiment.
pub fn markdown(r: &BenchReport) -> String {
    let m = &r.machine;
    let mut out = format!(
        "## raylab bench\n\nMachine: {} ({} hardware threads{}), {} bench threads; {}; Embree {}. Image {}x{}, {} rep(s) {} (slow variants capped at {} s per cell), views {}.\n\n",
        m.cpu,
        m.hardware_threads,
        m.physical_cores.map_or(String::new(), |c| format!(", {c} cores")),
        m.bench_threads,
        m.os,
        m.embree_version,
        r.size.0,
        r.size.1,
        r.reps,
        if r.quick { "without warm-up (--quick)" } else { "after a warm-up" },
        r.max_variant_s,
        r.views.join(" ")
    );
    if !r.measurements.is_empty() {
        out.push_str(&tables::markdown(&r.measurements));
        let ao = r
            .ao_modes
            .iter()
            .find(|a| *a == "paper")
            .or(r.ao_modes.first());
        if let (Some(ao), Some(view)) = (ao, r.views.first()) {
            out.push_str(&tables::kind_rates_markdown(&r.measurements, ao, view));
        }
        let bad: Vec<String> = r
            .measurements
            .iter()
            .filter(|m| !m.deterministic)
            .map(|m| format!("{} on {} {} ao {}", m.variant, m.scene, m.view, m.ao))
            .collect();
        if !bad.is_empty() {
            out.push_str(&format!(
                "\nWARNING: runs gave different images: {}\n\n",
                bad.join("; ")
            ));
        }
    }
    if !r.trace.is_empty() {
        out.push_str(&trace::markdown(&r.trace));
    }
    if !r.scaling.is_empty() {
        out.push_str("### Thread scaling (render only, median ms and speedup over 1 thread)\n\n");
        let mut t = Table::new([
            ("variant", Left),
            ("threads", Right),
            ("render ms", Right),
            ("speedup", Right),
        ]);
        for p in &r.scaling {
            t.row([
                p.variant.clone(),
                p.threads.to_string(),
                format!("{:.1}", p.render_ms.median),
                format!("{:.2}x", p.speedup),
            ]);
        }
        out.push_str(&t.markdown());
        out.push('\n');
    }
    if !r.growth.is_empty() {
        out.push_str("### Cost growth on mesh:N (build ms, ns per ray on one thread)\n\n");
        let mut t = Table::new([
            ("backend", Left),
            ("triangles", Right),
            ("build ms", Right),
            ("render ms", Right),
            ("ns/ray", Right),
        ]);
        for p in &r.growth {
            t.row([
                p.backend.clone(),
                p.triangles.to_string(),
                format!("{:.2}", p.build_ms),
                format!("{:.1}", p.render_ms),
                format!("{:.1}", p.ns_per_ray),
            ]);
        }
        out.push_str(&t.markdown());
        out.push('\n');
    }
    if !r.ao_error.is_empty() {
        out.push_str("### AO error against a cosine reference (display values)\n\n");
        let mut t = Table::new([
            ("scene", Left),
            ("ao", Left),
            ("AO rays/pixel", Right),
            ("render ms", Right),
            ("RMSE", Right),
            ("PSNR dB", Right),
        ]);
        for p in &r.ao_error {
            t.row([
                p.scene.clone(),
                p.ao.to_string(),
                p.samples.to_string(),
                format!("{:.1}", p.render_ms.median),
                format!("{:.5}", p.rmse),
                format!("{:.2}", p.psnr_db),
            ]);
        }
        out.push_str(&t.markdown());
        out.push('\n');
    }
    if !r.builders.is_empty() {
        out.push_str("### Builder quality\n\nBinary trees, and each builder's 8-wide tree (leaf tests counted in pairs).\n\n");
        let mut t = Table::new([
            ("scene", Left),
            ("builder", Left),
            ("build ms", Right),
            ("SAH cost", Right),
            ("nodes/ray", Right),
            ("tris/ray", Right),
            ("bytes/tri", Right),
            ("render ms", Right),
            ("8-wide build ms", Right),
            ("8-wide SAH cost", Right),
            ("8-wide bytes/tri", Right),
        ]);
        for p in &r.builders {
            t.row([
                p.scene.clone(),
                p.builder.clone(),
                format!("{:.2}", p.build_ms),
                format!("{:.2}", p.sah_cost),
                format!("{:.1}", p.nodes_per_ray),
                format!("{:.1}", p.triangles_per_ray),
                format!("{:.1}", p.bytes_per_triangle),
                format!("{:.1}", p.render_ms.median),
                format!("{:.2}", p.wide8_build_ms),
                format!("{:.2}", p.wide8_sah_cost),
                format!("{:.1}", p.wide8_bytes_per_triangle),
            ]);
        }
        out.push_str(&t.markdown());
        out.push('\n');
    }
    if !r.leaks.is_empty() {
        out.push_str("### Leaks against speed (rays through closed meshes)\n\n");
        out.push_str(&crate::stress::leak_table(&r.leaks).markdown());
        out.push('\n');
    }
    if !r.validation.is_empty() {
        out.push_str("### Validation (primary, shadow, AO and random rays)\n\n");
        let mut t = Table::new([
            ("scene", Left),
            ("tested", Left),
            ("reference", Left),
            ("rays", Right),
            ("ties", Right),
            ("genuine", Right),
        ]);
        for v in &r.validation {
            t.row([
                v.scene.clone(),
                v.tested.clone(),
                v.reference.clone(),
                v.rays.to_string(),
                v.ties.to_string(),
                v.genuine.to_string(),
            ]);
        }
        out.push_str(&t.markdown());
        out.push('\n');
    }
    out
}

fn write_files(dir: &Path, r: &BenchReport) -> Result<()> {
    let write = |name: &str, text: &str| output::write_text(&dir.join(name), text);
    let md = markdown(r);
    write("bench.md", &md)?;
    write("bench.csv", &tables::csv(&r.measurements))?;
    let json = serde_json::to_string_pretty(r)?;
    write("bench.json", &json)?;
    write("index.html", &report_html(r, &md))?;
    Ok(())
}

fn report_html(r: &BenchReport, md: &str) -> String {
    use html::{escape, figure, markdown_to_html, Section};
    let m = &r.machine;
    let meta = vec![
        ("CPU".to_string(), m.cpu.clone()),
        (
            "threads".to_string(),
            format!(
                "{} hardware{}, {} used by the bench",
                m.hardware_threads,
                m.physical_cores.map_or(String::new(), |c| format!(" ({c} cores)")),
                m.bench_threads
            ),
        ),
        ("system".to_string(), m.os.clone()),
        ("Embree".to_string(), m.embree_version.clone()),
        ("raylab".to_string(), m.raylab_version.clone()),
        (
            "settings".to_string(),
            format!(
                "{}x{}, views {}, AO {}, {} rep(s){}, slow variants capped at {} s per cell; ran {:.0} s",
                r.size.0,
                r.size.1,
                r.views.join(" "),
                r.ao_modes.join(", "),
                r.reps,
                if r.quick { " without warm-up (--quick)" } else { " after a warm-up" },
                r.max_variant_s,
                r.elapsed_s
            ),
        ),
    ];
    let chart = |stem: &str, caption: &str| -> String {
        r.charts
            .iter()
            .filter(|c| c.starts_with(&format!("charts/{stem}")) && c.ends_with(".png"))
            .map(|c| figure(c, Some(&c.replace(".png", ".svg")), caption))
            .collect()
    };
    let mut sections = Vec::new();
    if !r.measurements.is_empty() {
        let variants: String = r
            .variants
            .iter()
            .map(|(n, d)| format!("<tr><td>{}</td><td>{}</td></tr>", escape(n), escape(d)))
            .collect();
        sections.push(Section {
            id: "speedups".into(),
            title: "Speedups".into(),
            body: format!(
                "{}<table>{variants}</table>",
                chart(
                    "speedup",
                    "Speedup of each variant over the baseline, per scene and view (log scale)."
                )
            ),
        });
    }
    for part in Part::ALL {
        let Some((title, stem, caption)) = part.section() else {
            continue;
        };
        let body = chart(stem, caption);
        if !body.is_empty() {
            sections.push(Section {
                id: part.name().into(),
                title: title.into(),
                body,
            });
        }
    }
    if !r.images.is_empty() {
        let mut body = String::from("<p>First view, one render per backend kind; the difference image is the largest difference of any render from the first, amplified 8 times (black: identical).</p>\n");
        for img in &r.images {
            body.push_str(&format!(
                "<h3>{}</h3><div class=\"row\">",
                escape(&img.scene)
            ));
            for (variant, path) in &img.renders {
                body.push_str(&figure(path, None, variant));
            }
            if let Some(d) = &img.difference {
                let counts: Vec<String> = img
                    .differing_pixels
                    .iter()
                    .map(|(v, n)| format!("{v}: {n} pixels differ"))
                    .collect();
                body.push_str(&figure(
                    d,
                    None,
                    &format!("difference ({})", counts.join(", ")),
                ));
            }
            body.push_str("</div>\n");
        }
        sections.push(Section {
            id: "images".into(),
            title: "Renders".into(),
            body,
        });
    }
    sections.push(Section {
        id: "tables".into(),
        title: "Tables".into(),
        body: markdown_to_html(md),
    });
    html::page("raylab bench", &meta, &sections)
}

/// The labels of `views` in first-seen order, each once.
fn distinct_labels(views: impl Iterator<Item = View>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for v in views {
        let label = v.label();
        if !out.contains(&label) {
            out.push(label);
        }
    }
    out
}
