//! The `growth` part: build time and time per ray of each backend on
//! `mesh:N` (10^3 to 10^7 triangles; naive only while it finishes), a small
//! render with paper AO right after each build.

use std::path::Path;

use serde::Serialize;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::accel::BackendKind;
use crate::bench::charts::{
    color, legend, line_with_points, log_axis, log_label, log_range, save_chart, DrawResult, FONT,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::{Stat, View};
use crate::bench::variants::Variant;
use crate::error::Result;
use crate::progress::StepBar;
use crate::render::{AoMode, RenderSettings};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Cost growth",
    stem: "cost-growth",
    caption: "Build time and time per ray against triangle count (log-log): naive grows as O(N) per ray, the hierarchies as O(log N).",
};

/// One point of the cost-growth chart.
#[derive(Clone, Debug, Serialize)]
pub struct GrowthPoint {
    pub backend: String,
    pub triangles: usize,
    /// Median build time (from the scene to a ready structure).
    pub build_ms: f64,
    pub render_ms: f64,
    pub rays: u64,
    /// Render wall time per ray times the render threads: time per ray on one thread.
    pub ns_per_ray: f64,
}

/// The backends of the cost-growth chart.
pub fn variants() -> Vec<Variant> {
    [
        "naive-tiles",
        "bvh-median-pbuild-tiles",
        "bvh-sah-tiles",
        "bvh4-sah-tiles",
        "bvh8-sah-tiles",
        "embree-tiles",
    ]
    .iter()
    .filter_map(|n| Variant::named(n))
    .filter(|v| v.kind != BackendKind::Embree || crate::accel::embree::AVAILABLE)
    .collect()
}

/// Sizes of the procedural meshes.
fn sizes(cfg: &BenchConfig) -> Vec<u64> {
    if cfg.quick {
        vec![1_000, 10_000]
    } else {
        vec![1_000, 10_000, 100_000, 1_000_000, 10_000_000]
    }
}

/// Progress steps: one per mesh and variant.
pub fn steps(cfg: &BenchConfig, _scenes: &[Scene]) -> u64 {
    (sizes(cfg).len() * variants().len()) as u64
}

/// Cost growth on `mesh:N` (the bench's scenes are not used), from the study's first view.
pub fn run(cfg: &BenchConfig, _scenes: &[Scene], bar: &StepBar) -> Result<Vec<GrowthPoint>> {
    let settings = View::PAPER[0].settings(
        if cfg.quick { (32, 24) } else { (96, 72) },
        AoMode::Paper,
        1,
    )?;
    let naive_max = if cfg.quick { 10_000 } else { 100_000 };
    cost_growth(
        &sizes(cfg),
        &settings,
        cfg.threads,
        cfg.extra_reps(),
        naive_max,
        bar,
    )
}

/// Build and render cost of each backend on `mesh:N` scenes; naive only up to
/// `naive_max` triangles (its cost is O(N) per ray).
fn cost_growth(
    sizes: &[u64],
    settings: &RenderSettings,
    threads: usize,
    reps: usize,
    naive_max: u64,
    bar: &StepBar,
) -> Result<Vec<GrowthPoint>> {
    let mut out = Vec::new();
    for &n in sizes {
        let scene = crate::scene::builtin::builtin(&format!("mesh:{n}"))?;
        for variant in variants() {
            bar.set_message(format!("cost growth: {} on mesh:{n}", variant.name));
            if variant.kind == BackendKind::Naive && n > naive_max {
                bar.step();
                continue;
            }
            let mut builds = Vec::new();
            let mut renders = Vec::new();
            let mut rays = 0;
            for _ in 0..reps.max(1) {
                let (build_ms, render_ms, _, stats) =
                    crate::bench::measure::run_once(&scene, &variant, settings, threads)?;
                builds.push(build_ms);
                renders.push(render_ms);
                rays = stats.total_rays();
            }
            bar.step();
            let render_ms = Stat::of(&renders).median;
            out.push(GrowthPoint {
                backend: variant.name.trim_end_matches("-tiles").to_string(),
                triangles: scene.triangle_count(),
                build_ms: Stat::of(&builds).median,
                render_ms,
                rays,
                ns_per_ray: render_ms * 1e6 * threads as f64 / rays.max(1) as f64,
            });
        }
    }
    Ok(out)
}

/// The part's table.
pub fn markdown(points: &[GrowthPoint]) -> String {
    let mut t = Table::new([
        ("backend", Left),
        ("triangles", Right),
        ("build ms", Right),
        ("render ms", Right),
        ("ns/ray", Right),
    ]);
    for p in points {
        t.row([
            p.backend.clone(),
            p.triangles.to_string(),
            format!("{:.2}", p.build_ms),
            format!("{:.1}", p.render_ms),
            format!("{:.1}", p.ns_per_ray),
        ]);
    }
    format!(
        "### Cost growth on mesh:N (build ms, ns per ray on one thread)\n\n{}\n",
        t.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[GrowthPoint]) -> Result<Vec<String>> {
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (1200, 520),
        draw_growth,
        points
    )?])
}

fn draw_growth<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, pts: &[GrowthPoint]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(600);
    let mut backends: Vec<&str> = Vec::new();
    for p in pts {
        if !backends.contains(&p.backend.as_str()) {
            backends.push(&p.backend);
        }
    }
    let x = log_range(pts.iter().map(|p| p.triangles as f64));
    for (area, title, ydesc, get) in [
        (
            &left,
            "Build time against triangles",
            "build ms (log)",
            (|p: &GrowthPoint| p.build_ms.max(1e-3)) as fn(&GrowthPoint) -> f64,
        ),
        (
            &right,
            "Render time per ray against triangles",
            "ns per ray on one thread (log)",
            |p: &GrowthPoint| p.ns_per_ray,
        ),
    ] {
        let y = log_range(pts.iter().map(get));
        let mut chart = ChartBuilder::on(area)
            .caption(title, (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(log_axis(x.clone()), log_axis(y))?;
        chart
            .configure_mesh()
            .x_desc("triangles (log)")
            .y_desc(ydesc)
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        for (i, b) in backends.iter().enumerate() {
            let c = color(i);
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.backend == *b)
                .map(|p| (p.triangles as f64, get(p)))
                .collect();
            line_with_points(&mut chart, &line, c, b)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    }
    root.present()?;
    Ok(())
}
