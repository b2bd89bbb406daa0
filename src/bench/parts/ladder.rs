//! The `ladder` part: each rung of the build-quality ladder (`--quality low,
//! medium, high`) for raylab's 8-wide tree and for Embree's own scene, on
//! every bench scene: build time on one thread and on the bench's threads,
//! SAH cost (raylab's), and the render's throughput per ray kind on each
//! structure's fastest query path (raylab's trees traced by raylab, Embree's
//! by Embree). Its chart is the Pareto front per scene: build time against
//! render time.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::ChartSection;
use crate::accel::bvh::params::Quality;
use crate::accel::bvh::wide::TraversalCosts;
use crate::accel::bvh::{build, BuildParams, Tree};
use crate::accel::{build_backend, BackendSpec};
use crate::bench::charts::{
    color, distinct, log_label, log_range, save_chart, side_legend, DrawResult, Swatch, FONT,
    SIDE_LEGEND,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::Stat;
use crate::error::Result;
use crate::progress::{Progress, StepBar};
use crate::render::{render, AoMode, RenderStats, Schedule};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Build-quality ladder",
    stem: "ladder",
    caption: "Build time against render time per scene, each rung of raylab's and Embree's ladders: the lower left is better, a rung pays where it moves down more than right.",
};

const RUNGS: [Quality; 3] = [Quality::Low, Quality::Medium, Quality::High];

/// One rung of one structure on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct LadderPoint {
    pub scene: String,
    pub triangles: usize,
    /// `low`, `medium` or `high`.
    pub rung: String,
    /// `raylab` or `embree`.
    pub structure: String,
    /// The backend's name (builder and query path).
    pub backend: String,
    pub build_ms_1t: Stat,
    pub build_ms_nt: Stat,
    pub build_threads: usize,
    /// raylab's trees: the SAH cost of the 8-wide tree as traversed
    /// (`WideBvh::sah_cost`: expected ns per ray in node visits and block
    /// tests at [`TraversalCosts::of_default_path`]); Embree's: not
    /// available (NaN).
    pub sah_ns_per_ray: f64,
    /// References in leaves per triangle (above 1 where triangles were
    /// split; NaN for Embree).
    pub references_per_triangle: f64,
    /// Render time (tiles schedule, the bench's threads), median.
    pub render_ms: Stat,
    /// Throughput per thread per ray kind over the median render.
    pub primary_mrays: f64,
    pub shadow_mrays: f64,
    pub ao_mrays: f64,
}

/// Progress steps: one per scene, rung and structure.
pub fn steps(_cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    (scenes.len() * RUNGS.len() * structures().len()) as u64
}

/// The structures on the ladder: raylab's, and Embree's when built in.
fn structures() -> Vec<&'static str> {
    if crate::accel::embree::AVAILABLE {
        vec!["raylab", "embree"]
    } else {
        vec!["raylab"]
    }
}

/// The spec of `structure` at `rung`, built on `threads`, on its fastest
/// query path.
fn spec(structure: &str, rung: Quality, threads: usize) -> BackendSpec {
    let spec = match structure {
        "raylab" => BackendSpec::bvh(
            BuildParams::for_quality(rung)
                .with_width(8)
                .with_threads(threads),
        ),
        _ => BackendSpec::embree_at(rung, threads),
    };
    spec.with_fastest_query()
}

/// Every rung of every structure on every scene, from its first view at
/// half size.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<LadderPoint>> {
    let size = cfg.smaller(2);
    let reps = cfg.extra_reps();
    let mut out = Vec::new();
    for scene in scenes {
        let settings = cfg
            .first_view(scene, size)
            .settings(size, AoMode::Paper, 1)?;
        for rung in RUNGS {
            for structure in structures() {
                bar.set_message(format!(
                    "ladder: {structure} {} on {}",
                    rung.name(),
                    scene.name
                ));
                // Each series starts with an untimed build and render: the
                // first Embree build on a thread count makes its device (14 ms
                // against 0.2 for cornell-empty), the first render wakes the
                // pool and faults the pages in.
                let builds = |threads: usize| -> Result<Stat> {
                    build_backend(&spec(structure, rung, threads), scene)?;
                    let mut times = Vec::new();
                    for _ in 0..reps.max(1) {
                        let built = build_backend(&spec(structure, rung, threads), scene)?;
                        times.push(built.build_time.as_secs_f64() * 1e3);
                    }
                    Ok(Stat::of(&times))
                };
                let build_ms_1t = builds(1)?;
                let build_ms_nt = builds(cfg.threads)?;
                let (sah_ns_per_ray, references_per_triangle) = if structure == "raylab" {
                    let params = BuildParams::for_quality(rung).with_width(8);
                    let Tree::Wide8(tree) = build(&scene.mesh(), &params)? else {
                        unreachable!("width 8 builds an 8-wide tree")
                    };
                    (
                        tree.sah_cost(&TraversalCosts::of_default_path()),
                        tree.triangle_count() as f64 / scene.triangle_count().max(1) as f64,
                    )
                } else {
                    (f64::NAN, f64::NAN)
                };
                let built = build_backend(&spec(structure, rung, cfg.threads), scene)?;
                let render_once = || {
                    render(
                        scene,
                        built.backend.as_ref(),
                        &settings,
                        Schedule::Tiles,
                        cfg.threads,
                        &Progress::new(),
                    )
                };
                let mut times = Vec::new();
                let mut kinds: Vec<RenderStats> = Vec::new();
                render_once()?;
                for _ in 0..reps.max(1) {
                    let start = std::time::Instant::now();
                    let (_, stats) = render_once()?;
                    times.push(start.elapsed().as_secs_f64() * 1e3);
                    kinds.push(stats);
                }
                let render_ms = Stat::of(&times);
                // The kind throughputs of the median render.
                let mut order: Vec<usize> = (0..times.len()).collect();
                order.sort_by(|&a, &b| times[a].total_cmp(&times[b]));
                let median = &kinds[order[order.len() / 2]];
                let mrays = |rays: u64, t: std::time::Duration| {
                    rays as f64 / t.as_secs_f64().max(1e-12) / 1e6
                };
                bar.step();
                out.push(LadderPoint {
                    scene: scene.name.clone(),
                    triangles: scene.triangle_count(),
                    rung: rung.name().to_string(),
                    structure: structure.to_string(),
                    backend: built.name(),
                    build_ms_1t,
                    build_ms_nt,
                    build_threads: cfg.threads,
                    sah_ns_per_ray,
                    references_per_triangle,
                    render_ms,
                    primary_mrays: mrays(median.primary_rays, median.primary_time),
                    shadow_mrays: mrays(median.shadow_rays, median.shadow_time),
                    ao_mrays: mrays(median.ao_rays, median.ao_time),
                });
            }
        }
    }
    Ok(out)
}

/// The part's table: one row per scene, rung and structure, and each
/// raylab rung's build and render time against Embree's same rung.
pub fn markdown(points: &[LadderPoint]) -> String {
    let threads = points.first().map_or(1, |p| p.build_threads);
    let mut t = Table::new([
        ("scene", Left),
        ("rung", Left),
        ("backend", Left),
        ("build ms 1T", Right),
        (
            Box::leak(format!("build ms {threads}T").into_boxed_str()),
            Right,
        ),
        ("SAH ns/ray", Right),
        ("refs/tri", Right),
        ("render ms", Right),
        ("Mrays/s P/S/AO", Right),
        ("build / Embree's 1T, NT", Right),
        ("render / Embree's", Right),
    ]);
    let num = |v: f64, digits: usize| {
        if v.is_finite() {
            format!("{v:.digits$}")
        } else {
            "-".to_string()
        }
    };
    for p in points {
        let embree = points
            .iter()
            .find(|e| e.structure == "embree" && e.scene == p.scene && e.rung == p.rung);
        let (build_ratio, render_ratio) = match embree {
            Some(e) if p.structure == "raylab" => (
                format!(
                    "{:.2}, {:.2}",
                    p.build_ms_1t.median / e.build_ms_1t.median,
                    p.build_ms_nt.median / e.build_ms_nt.median
                ),
                format!("{:.2}", p.render_ms.median / e.render_ms.median),
            ),
            _ => ("-".to_string(), "-".to_string()),
        };
        t.row([
            p.scene.clone(),
            p.rung.clone(),
            p.backend.clone(),
            format!("{:.2}", p.build_ms_1t.median),
            format!("{:.2}", p.build_ms_nt.median),
            num(p.sah_ns_per_ray, 1),
            num(p.references_per_triangle, 2),
            format!("{:.1}", p.render_ms.median),
            format!(
                "{:.2}/{:.2}/{:.2}",
                p.primary_mrays, p.shadow_mrays, p.ao_mrays
            ),
            build_ratio,
            render_ratio,
        ]);
    }
    format!(
        "### Build-quality ladder\n\nEach rung (`--quality`) of raylab's 8-wide tree (low: LBVH, medium: binned SAH, high: SBVH with reinsertion) and of Embree's scene (its build quality of the same name), each on its fastest query path. SAH ns/ray: raylab's 8-wide tree as traversed, expected ns per ray in node visits and block tests at the measured {} (docs/design.md, \"The SAH cost of a wide tree\"). Mrays/s per thread over the median render.\n\n{}\n",
        TraversalCosts::of_default_path().describe(),
        t.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[LadderPoint]) -> Result<Vec<String>> {
    let scenes = distinct(points.iter().map(|p| p.scene.as_str()))
        .len()
        .max(1) as u32;
    let width = 460 * scenes.min(4) + SIDE_LEGEND;
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (width, 520),
        draw_ladder,
        points
    )?])
}

fn draw_ladder<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, pts: &[LadderPoint]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let (panels, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND));
    // The first four scenes (the chart stays readable).
    let scenes: Vec<&str> = distinct(pts.iter().map(|p| p.scene.as_str()))
        .into_iter()
        .take(4)
        .collect();
    let areas = panels.split_evenly((1, scenes.len().max(1)));
    let series: Vec<(String, usize)> = ["raylab", "embree"]
        .iter()
        .enumerate()
        .map(|(i, s)| (s.to_string(), i))
        .collect();
    for (area, scene) in areas.iter().zip(&scenes) {
        let here: Vec<&LadderPoint> = pts.iter().filter(|p| p.scene == *scene).collect();
        let title = std::path::Path::new(scene)
            .file_stem()
            .map_or(scene.to_string(), |s| s.to_string_lossy().into_owned());
        let mut chart = ChartBuilder::on(area)
            .caption(title, (FONT, 18))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(
                log_range(here.iter().map(|p| p.build_ms_nt.median.max(1e-3))).log_scale(),
                log_range(here.iter().map(|p| p.render_ms.median.max(1e-3))).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc("build ms (log)")
            .y_desc("render ms (log)")
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        for (name, ci) in &series {
            let c = color(*ci);
            let line: Vec<(f64, f64)> = RUNGS
                .iter()
                .filter_map(|r| {
                    here.iter()
                        .find(|p| p.structure == *name && p.rung == r.name())
                        .map(|p| (p.build_ms_nt.median.max(1e-3), p.render_ms.median.max(1e-3)))
                })
                .collect();
            chart.draw_series(LineSeries::new(line.clone(), c.stroke_width(2)))?;
            for (point, rung) in line.iter().zip(RUNGS) {
                chart.draw_series(std::iter::once(Circle::new(*point, 5, c.filled())))?;
                chart.draw_series(std::iter::once(Text::new(
                    rung.name().to_string(),
                    (point.0, point.1),
                    (FONT, 13).into_font(),
                )))?;
            }
        }
    }
    let entries: Vec<(String, RGBAColor)> = series
        .iter()
        .map(|(name, ci)| (name.clone(), color(*ci)))
        .collect();
    side_legend(&side, &entries, Swatch::Dot)?;
    root.present()?;
    Ok(())
}
