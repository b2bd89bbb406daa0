//! `raylab bench`: the study's tables for any scenes in one command, and the
//! experiments and charts that explain them, written as Markdown, CSV, JSON,
//! PNG/SVG charts and one HTML page.
//!
//! The parts (`--parts`) live in [`parts`], one file each: `tables` (the
//! variant matrix, measured by [`measure`]), `trace` (query throughput without
//! shading), `scaling`, `growth`, `ao-error`, `builders`, `ladder`,
//! `libraries`, `leaks` and `validate`. This file runs the matrix, then the
//! others in a loop over [`parts::PartReport`]'s list, and writes the report,
//! led by its [`summary`]; images for it come from the matrix's own renders.
//!
//! How the matrix measures and what each part does: `docs/design.md`, "The
//! bench"; results of full runs: `docs/results.md`.

pub(crate) mod charts;
pub(crate) mod config;
pub(crate) mod family;
pub mod html;
pub(crate) mod measure;
pub(crate) mod metrics;
pub(crate) mod parts;
pub(crate) mod summary;
pub(crate) mod timing;
pub mod variants;

use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::output;
use crate::progress::StepBar;
use crate::render::{srgb, AoMode};
use crate::scene::Scene;
pub use config::{BenchConfig, Part};
use measure::{Matrix, Measurement, View};
use parts::{tables, Reports};
use summary::Summary;

/// The machine a bench ran on.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    pub cpu: String,
    pub physical_cores: Option<usize>,
    pub hardware_threads: usize,
    pub bench_threads: usize,
    pub os: String,
    pub embree_version: String,
    /// Packet widths Embree traces natively here (its other widths it emulates).
    pub embree_native_packets: Vec<usize>,
    /// raylab's SIMD kernels on this CPU, by query path
    /// ([`crate::accel::bvh::simd::Kernel::in_use`]).
    pub simd: String,
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
            embree_native_packets: crate::accel::embree::native_packets_or_none(),
            simd: crate::accel::bvh::simd::Kernel::in_use(),
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

/// bench.json's format. 2 (2026-12-05): `format`, `command`, `date` and
/// `summary` added; trace points name their `family` ("raylab", "embree",
/// "tinybvh", "obvhs", "bvh-crate") where format 1 had the `embree` and
/// `library` booleans, and library points say their library where they said
/// "library". Format 1 had no `format` field.
pub const FORMAT: u32 = 2;

/// Everything a bench run measured; `bench.json` is this.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    /// bench.json's format: [`FORMAT`] (a reader can tell the layouts apart).
    pub format: u32,
    /// The command line that asked for the run.
    pub command: String,
    /// The day it ran (UTC, `YYYY-MM-DD`).
    pub date: String,
    pub machine: Machine,
    /// The answer the report leads with (see [`summary`]).
    pub summary: Summary,
    pub size: (u32, u32),
    pub reps: usize,
    pub quick: bool,
    pub max_variant_s: f64,
    pub views: Vec<String>,
    pub ao_modes: Vec<String>,
    pub variants: Vec<(String, String)>,
    pub baseline: String,
    pub measurements: Vec<Measurement>,
    /// The other parts' points, each under its key (`trace`, `scaling`,
    /// ..., `validation`).
    #[serde(flatten)]
    pub parts: Reports,
    pub images: Vec<SceneImages>,
    /// PNG charts written (relative to the report folder).
    pub charts: Vec<String>,
    pub elapsed_s: f64,
}

/// The file bench writes first into its report folder. A folder that holds
/// other files but not this one was not made by bench: its files could be
/// the user's own `index.html` or `images/`, which bench would overwrite.
pub const MARKER: &str = ".raylab-bench";

/// Refuses `dir` as a report folder when it holds files bench did not write
/// (it has no [`MARKER`]), unless `force`. A folder that does not exist yet,
/// an empty one, or an earlier report's is taken.
pub fn check_out_dir(dir: &Path, force: bool) -> Result<()> {
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut other = None;
    for entry in entries {
        let name = entry.map_err(|e| Error::io(dir, e))?.file_name();
        if name == MARKER {
            return Ok(());
        }
        other.get_or_insert(name);
    }
    match other {
        Some(name) if !force => Err(Error::usage(
            "--out",
            format!(
                "{} holds files raylab bench did not write (such as {name:?}), which it could overwrite: give a new or empty folder, or --force",
                dir.display()
            ),
        )),
        _ => Ok(()),
    }
}

/// Runs the bench and writes the report folder; returns the report.
pub fn run(cfg: &BenchConfig, scenes: &[Scene]) -> Result<BenchReport> {
    let started = std::time::Instant::now();
    check_out_dir(&cfg.out, cfg.force)?;
    for sub in ["", "charts", "images"] {
        let dir = cfg.out.join(sub);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    }
    output::write_text(
        &cfg.out.join(MARKER),
        "This folder holds a report of raylab bench, which writes into it again\nwithout --force.\n",
    )?;
    output::check_writable(&cfg.out.join("images").join("probe.png"))?;
    if cfg.parts.iter().any(|p| parts::draws(*p)) {
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
    // Progress units are expected milliseconds; each step of the other parts
    // counts as `step` of them.
    let step: u64 = if cfg.quick { 100 } else { 3000 };
    let steps: u64 = Part::ALL
        .into_iter()
        .filter(|p| cfg.wants(*p))
        .map(|p| parts::steps(p, cfg, scenes))
        .sum();
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
    // The other parts, in order.
    let mut reports = Vec::new();
    for part in Part::ALL.into_iter().filter(|p| cfg.wants(*p)) {
        reports.extend(parts::run(part, cfg, scenes, &bar)?);
    }
    let reports = Reports(reports);
    bar.finish();

    let images = write_images(&cfg.out, scenes, &kept)?;
    let summary = Summary::of(
        reports.libraries(),
        reports.trace(),
        reports.validation(),
        &measurements,
        reports.animation(),
        reports.instances(),
    );
    let mut report = BenchReport {
        format: FORMAT,
        command: cfg.command.clone(),
        date: summary::today(),
        machine: Machine::detect(cfg.threads),
        summary,
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
        parts: reports,
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
            output::write_png(&dir.join(&rel), f.width, f.height, &srgb::to_srgb8(f))?;
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
    if !r.measurements.is_empty() {
        files.extend(tables::charts(dir, &r.measurements, &r.ao_modes)?);
    }
    for report in r.parts.0.iter().filter(|p| !p.is_empty()) {
        files.extend(report.charts(dir)?);
    }
    // A chart drawn twice over is a part's bug (the trace part once drew
    // each of its two charts 528 times): refused, not written into the page.
    if let Some(twice) = html::first_duplicate(files.iter().map(String::as_str)) {
        return Err(Error::Other(format!(
            "bench: chart {twice} was drawn more than once"
        )));
    }
    Ok(files.into_iter().map(|f| format!("charts/{f}")).collect())
}

/// The Markdown of the whole report: a header naming the machine, the
/// summary (the answer), then the parts' tables ([`parts_markdown`]).
pub fn markdown(r: &BenchReport) -> String {
    format!(
        "{}{}{}",
        header_markdown(r),
        r.summary.markdown(),
        parts_markdown(r)
    )
}

/// The report's heading and the machine, settings, date and command.
fn header_markdown(r: &BenchReport) -> String {
    let m = &r.machine;
    format!(
        "## raylab bench\n\n{}: `{}`\n\nMachine: {} ({} hardware threads{}), {} bench threads; {}; raylab's kernels {}; Embree {}{}. Image {}x{}, {} rep(s) {} (slow variants capped at {} s per cell), views {}.\n\n",
        r.date,
        r.command,
        m.cpu,
        m.hardware_threads,
        m.physical_cores.map_or(String::new(), |c| format!(", {c} cores")),
        m.bench_threads,
        m.os,
        m.simd,
        m.embree_version,
        match m.embree_native_packets.as_slice() {
            [] => String::new(),
            widths => format!(
                " (native packets of {} rays)",
                widths.iter().map(|w| w.to_string()).collect::<Vec<_>>().join(", ")
            ),
        },
        r.size.0,
        r.size.1,
        r.reps,
        if r.quick { "without warm-up (--quick)" } else { "after a warm-up" },
        r.max_variant_s,
        r.views.join(" ")
    )
}

/// The study's tables, then one table per extra experiment.
fn parts_markdown(r: &BenchReport) -> String {
    let mut out = String::new();
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
    for report in r.parts.0.iter().filter(|p| !p.is_empty()) {
        out.push_str(&report.markdown());
    }
    out
}

fn write_files(dir: &Path, r: &BenchReport) -> Result<()> {
    let write = |name: &str, text: &str| output::write_text(&dir.join(name), text);
    let md = markdown(r);
    write("bench.md", &md)?;
    write(
        "summary.md",
        &r.summary.page(&r.date, &r.machine, &r.command, r.quick),
    )?;
    write("bench.csv", &tables::csv(&r.measurements))?;
    let json = serde_json::to_string_pretty(r)?;
    write("bench.json", &json)?;
    let page = report_html(r);
    // Each image once: the page's own check fails on duplicates too.
    if let Some(twice) = html::first_duplicate(html::image_sources(&page)) {
        return Err(Error::Other(format!(
            "bench: index.html would show {twice} more than once"
        )));
    }
    write("index.html", &page)?;
    Ok(())
}

fn report_html(r: &BenchReport) -> String {
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
        ("kernels".to_string(), m.simd.clone()),
        ("date".to_string(), r.date.clone()),
        ("command".to_string(), r.command.clone()),
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
    // The answer first.
    let mut sections = vec![Section {
        id: "summary".into(),
        title: "Summary".into(),
        // (The section's own title stands for the Markdown's.)
        body: markdown_to_html(r.summary.markdown().trim_start_matches("### Summary\n\n")),
    }];
    if !r.measurements.is_empty() {
        let variants: String = r
            .variants
            .iter()
            .map(|(n, d)| format!("<tr><td>{}</td><td>{}</td></tr>", escape(n), escape(d)))
            .collect();
        let section = &tables::SECTION;
        sections.push(Section {
            id: "speedups".into(),
            title: section.title.into(),
            body: format!(
                "{}<table>{variants}</table>",
                chart(section.stem, section.caption)
            ),
        });
    }
    // The tables part has its section above (with the variants); the others
    // show their charts.
    for part in Part::ALL.into_iter().filter(|p| *p != Part::Tables) {
        let section = parts::section(part);
        if section.stem.is_empty() {
            continue;
        }
        let body = chart(section.stem, section.caption);
        if !body.is_empty() {
            sections.push(Section {
                id: part.name().into(),
                title: section.title.into(),
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
        body: markdown_to_html(&parts_markdown(r)),
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
