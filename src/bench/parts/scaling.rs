//! The `scaling` part: render time of the parallel variants on 1 to N
//! threads (and twice N), the last scene, half the bench's image size.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::accel::{build_backend, BackendKind};
use crate::bench::charts::{color, legend, line_with_points, save_chart, DrawResult, FONT};
use crate::bench::config::BenchConfig;
use crate::bench::measure::Stat;
use crate::bench::variants::Variant;
use crate::error::Result;
use crate::progress::{Progress, StepBar};
use crate::render::{render, AoMode, RenderSettings};
use crate::scene::Scene;
use crate::table::{
    ms,
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Thread scaling",
    stem: "thread-scaling",
    caption: "Render speedup over one thread per schedule; the grey line is ideal scaling.",
};

/// One point of the thread-scaling chart.
#[derive(Clone, Debug, Serialize)]
pub struct ScalingPoint {
    pub scene: String,
    pub variant: String,
    pub threads: usize,
    pub render_ms: Stat,
    /// Over the same variant on one thread.
    pub speedup: f64,
}

/// The variants whose render time is measured on 1..N threads: the binary,
/// 4-wide and 8-wide SAH BVHs and Embree, over the locked tile queue (and
/// Embree's also over rayon).
pub fn variants() -> Vec<Variant> {
    [
        "bvh-sah-tiles",
        "bvh4-sah-tiles",
        "bvh8-sah-tiles",
        "embree-tiles",
        "embree-rayon",
    ]
    .iter()
    .filter_map(|n| Variant::named(n))
    .filter(|v| v.kind != BackendKind::Embree || crate::accel::embree::AVAILABLE)
    .collect()
}

/// The thread counts measured: 1..=threads, then twice that.
fn thread_counts(cfg: &BenchConfig) -> Vec<usize> {
    let mut t: Vec<usize> = (1..=cfg.threads).collect();
    t.push(cfg.threads * 2);
    t
}

/// Progress steps: one per variant.
pub fn steps(_cfg: &BenchConfig, _scenes: &[Scene]) -> u64 {
    variants().len() as u64
}

/// Thread scaling on the last of `scenes`, from its first view.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<ScalingPoint>> {
    let Some(last) = scenes.last() else {
        return Ok(Vec::new());
    };
    let size = cfg.smaller(2);
    let settings = cfg
        .first_view(last, size)
        .settings(size, AoMode::Paper, 1)?;
    thread_scaling(last, &settings, &thread_counts(cfg), cfg.extra_reps(), bar)
}

/// Render time of each variant on each of `thread_counts`, repetitions
/// interleaved across thread counts. The backend is built once per variant.
fn thread_scaling(
    scene: &Scene,
    settings: &RenderSettings,
    thread_counts: &[usize],
    reps: usize,
    bar: &StepBar,
) -> Result<Vec<ScalingPoint>> {
    let mut out = Vec::new();
    let max_threads = thread_counts.iter().copied().max().unwrap_or(1);
    for variant in variants() {
        bar.set_message(format!(
            "thread scaling: {} on {}",
            variant.name, scene.name
        ));
        let backend = build_backend(&variant.spec(max_threads), scene)?;
        let mut times: Vec<Vec<f64>> = vec![Vec::new(); thread_counts.len()];
        for _ in 0..reps.max(1) {
            for (slot, &t) in times.iter_mut().zip(thread_counts) {
                let start = Instant::now();
                render(
                    scene,
                    backend.as_ref(),
                    settings,
                    variant.schedule,
                    t,
                    &Progress::new(),
                )?;
                slot.push(ms(start.elapsed()));
            }
        }
        bar.step();
        let one = Stat::of(&times[0]).median;
        for (t, ts) in thread_counts.iter().zip(&times) {
            let s = Stat::of(ts);
            out.push(ScalingPoint {
                scene: scene.name.clone(),
                variant: variant.name.to_string(),
                threads: *t,
                render_ms: s,
                speedup: one / s.median.max(1e-9),
            });
        }
    }
    Ok(out)
}

/// The part's table.
pub fn markdown(points: &[ScalingPoint]) -> String {
    let mut t = Table::new([
        ("variant", Left),
        ("threads", Right),
        ("render ms", Right),
        ("speedup", Right),
    ]);
    for p in points {
        t.row([
            p.variant.clone(),
            p.threads.to_string(),
            format!("{:.1}", p.render_ms.median),
            format!("{:.2}x", p.speedup),
        ]);
    }
    format!(
        "### Thread scaling (render only, median ms and speedup over 1 thread)\n\n{}\n",
        t.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[ScalingPoint]) -> Result<Vec<String>> {
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (800, 520),
        draw_scaling,
        points
    )?])
}

fn draw_scaling<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[ScalingPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let max_t = pts.iter().map(|p| p.threads).max().unwrap_or(1) as f64;
    let max_s = pts.iter().map(|p| p.speedup).fold(max_t, f64::max);
    let scene = pts.first().map_or("", |p| p.scene.as_str());
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("Thread scaling of the render, {scene}"), (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d(0.5f64..max_t + 0.5, 0f64..max_s * 1.1)?;
    chart
        .configure_mesh()
        .x_desc("render threads")
        .y_desc("speedup over 1 thread")
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            [(1.0, 1.0), (max_t, max_t)],
            BLACK.mix(0.4).stroke_width(1),
        ))?
        .label("ideal")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.4)));
    let mut variants: Vec<&str> = Vec::new();
    for p in pts {
        if !variants.contains(&p.variant.as_str()) {
            variants.push(&p.variant);
        }
    }
    for (i, v) in variants.iter().enumerate() {
        let c = color(i);
        let line: Vec<(f64, f64)> = pts
            .iter()
            .filter(|p| p.variant == *v)
            .map(|p| (p.threads as f64, p.speedup))
            .collect();
        line_with_points(&mut chart, &line, c, v)?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    root.present()?;
    Ok(())
}
