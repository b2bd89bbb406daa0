//! The `builders` part: each builder's tree quality (SAH cost, nodes and
//! triangles visited per ray, memory) against its build and render time, on
//! the last two scenes; the binary trees and each builder's 8-wide tree.

use std::path::Path;

use serde::Serialize;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::accel::bvh::wide::TraversalCosts;
use crate::accel::bvh::{BuildParams, BuilderKind, BvhBackend};
use crate::bench::charts::{
    color, lin_range, log_axis, log_label, log_range, palette_entries, save_chart, side_legend,
    DrawResult, Swatch, FONT, SIDE_LEGEND,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::{timed_renders, Stat};
use crate::error::Result;
use crate::progress::StepBar;
use crate::render::{AoMode, RenderSettings, Schedule};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Builder quality",
    stem: "builders",
    caption: "Tree quality (SAH cost, nodes visited per ray) against build and render time.",
};

/// One point of the builder-quality chart.
#[derive(Clone, Debug, Serialize)]
pub struct BuilderPoint {
    pub scene: String,
    pub triangles: usize,
    pub builder: String,
    pub build_ms: f64,
    pub build_threads: usize,
    pub sah_cost: f64,
    /// Node visits per ray over all rays of the render.
    pub nodes_per_ray: f64,
    pub triangles_per_ray: f64,
    pub bytes_per_triangle: f64,
    /// Render time with the tiles schedule (median).
    pub render_ms: Stat,
    /// The same builder's 8-wide tree (what `--backend bvh` traverses):
    /// build time as the renderer builds it, SAH cost as traversed (expected
    /// ns per ray in node visits and block tests at the measured costs of
    /// `traversal_costs`), and memory.
    pub wide8_build_ms: f64,
    pub wide8_sah_ns_per_ray: f64,
    pub traversal_costs: TraversalCosts,
    pub wide8_bytes_per_triangle: f64,
}

/// The builders compared (Embree's only when built in).
pub fn quality_builders() -> Vec<BuilderKind> {
    BuilderKind::ALL
        .into_iter()
        .filter(|b| b.embree_quality().is_none() || crate::accel::embree::AVAILABLE)
        .collect()
}

/// Progress steps: one per scene and builder.
pub fn steps(_cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    (BenchConfig::last_two(scenes).len() * quality_builders().len()) as u64
}

/// Every builder on the last two of `scenes`, each from its first view at half size.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<BuilderPoint>> {
    let size = cfg.smaller(2);
    let mut out = Vec::new();
    for scene in BenchConfig::last_two(scenes) {
        let settings = cfg
            .first_view(scene, size)
            .settings(size, AoMode::Paper, 1)?;
        out.extend(builder_quality(
            scene,
            &settings,
            cfg.threads,
            cfg.extra_reps(),
            bar,
        )?);
    }
    Ok(out)
}

/// Each builder on `scene`: build time, SAH cost and traversal work per ray (from
/// `raylab stats`), and the render time of its tree.
fn builder_quality(
    scene: &Scene,
    settings: &RenderSettings,
    threads: usize,
    reps: usize,
    bar: &StepBar,
) -> Result<Vec<BuilderPoint>> {
    let mut out = Vec::new();
    for builder in quality_builders() {
        bar.set_message(format!("builders: {} on {}", builder.name(), scene.name));
        let params = BuildParams::for_builder(builder).with_threads(threads);
        let report =
            crate::measure::stats::builder_report(scene, &params, settings, threads, reps)?;
        let backend = BvhBackend::new(&scene.mesh(), &params)?;
        let (render_ms, _) =
            timed_renders(scene, &backend, settings, Schedule::Tiles, threads, reps)?;
        bar.step();
        let work = [report.primary, report.shadow, report.ao];
        let rays: u64 = work.iter().map(|w| w.rays).sum();
        let per_ray = |f: fn(&crate::measure::stats::KindWork) -> f64| {
            work.iter().map(|w| f(w) * w.rays as f64).sum::<f64>() / rays.max(1) as f64
        };
        out.push(BuilderPoint {
            scene: scene.name.clone(),
            triangles: scene.triangle_count(),
            builder: builder.name().to_string(),
            build_ms: report.build_ms_parallel,
            build_threads: threads,
            sah_cost: report.tree.sah_cost,
            nodes_per_ray: per_ray(|w| w.nodes_per_ray),
            triangles_per_ray: per_ray(|w| w.triangles_per_ray),
            bytes_per_triangle: report.tree.bytes_per_triangle,
            render_ms,
            wide8_build_ms: report.wide8.build_ms,
            wide8_sah_ns_per_ray: report.wide8.sah_ns_per_ray,
            traversal_costs: report.traversal_costs,
            wide8_bytes_per_triangle: report.wide8.bytes_per_triangle,
        });
    }
    Ok(out)
}

/// The part's table.
pub fn markdown(points: &[BuilderPoint]) -> String {
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
        ("8-wide SAH ns/ray", Right),
        ("8-wide bytes/tri", Right),
    ]);
    for p in points {
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
            format!("{:.1}", p.wide8_sah_ns_per_ray),
            format!("{:.1}", p.wide8_bytes_per_triangle),
        ]);
    }
    let costs = points
        .first()
        .map_or(String::new(), |p| p.traversal_costs.describe());
    format!("### Builder quality\n\nBinary trees (SAH cost: one unit per node and per pair of triangles), and each builder's 8-wide tree (SAH cost as traversed: expected ns per ray in node visits and block tests at the measured {costs}).\n\n{}\n", t.markdown())
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[BuilderPoint]) -> Result<Vec<String>> {
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (1390, 520),
        draw_builders,
        points
    )?])
}

fn draw_builders<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[BuilderPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let (panels, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND));
    let (left, right) = panels.split_horizontally((width.saturating_sub(SIDE_LEGEND)) / 2);
    let mut builders: Vec<&str> = Vec::new();
    let mut scenes: Vec<&str> = Vec::new();
    for p in pts {
        if !builders.contains(&p.builder.as_str()) {
            builders.push(&p.builder);
        }
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    type Axis = fn(&BuilderPoint) -> f64;
    for (area, title, xdesc, ydesc, fx, fy) in [
        (
            &left,
            "SAH cost against build time",
            "build ms (log)",
            "SAH cost",
            (|p: &BuilderPoint| p.build_ms.max(1e-3)) as Axis,
            (|p: &BuilderPoint| p.sah_cost) as Axis,
        ),
        (
            &right,
            "Nodes per ray against render time",
            "render ms (log)",
            "nodes visited per ray",
            (|p: &BuilderPoint| p.render_ms.median) as Axis,
            (|p: &BuilderPoint| p.nodes_per_ray) as Axis,
        ),
    ] {
        let mut chart = ChartBuilder::on(area)
            .caption(title, (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(
                log_axis(log_range(pts.iter().map(fx))),
                lin_range(pts.iter().map(fy), true),
            )?;
        chart
            .configure_mesh()
            .x_desc(xdesc)
            .y_desc(ydesc)
            .x_label_formatter(&log_label)
            .draw()?;
        for (i, b) in builders.iter().enumerate() {
            let c = color(i);
            chart.draw_series(pts.iter().filter(|p| p.builder == *b).map(|p| {
                let si = scenes.iter().position(|s| *s == p.scene).unwrap_or(0);
                let marker: DynElement<DB, (f64, f64)> = if si % 2 == 0 {
                    Circle::new((fx(p), fy(p)), 5, c.filled()).into_dyn()
                } else {
                    TriangleMarker::new((fx(p), fy(p)), 6, c.filled()).into_dyn()
                };
                marker
            }))?;
        }
    }
    side_legend(&side, &palette_entries(&builders), Swatch::Dot)?;
    let note = format!(
        "circles: {}   triangles: {}",
        scenes.first().copied().unwrap_or(""),
        scenes.get(1).copied().unwrap_or("-")
    );
    root.draw(&Text::new(note, (20, 500), (FONT, 13).into_font()))?;
    root.present()?;
    Ok(())
}
