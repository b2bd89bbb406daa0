//! The `leaks` part: the stress leak suite (rays aimed at the vertices and
//! edges of closed meshes) per intersection method, against query time.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::bench::charts::{
    color, legend, lin_range, log_axis, log_label, log_range, save_chart, DrawResult, FONT,
};
use crate::bench::config::BenchConfig;
use crate::error::Result;
use crate::measure::stress::LeakRow;
use crate::progress::StepBar;
use crate::scene::Scene;

pub const SECTION: ChartSection = ChartSection {
    title: "Leaks against speed",
    stem: "leaks",
    caption: "Rays that pass through closed meshes at vertices and edges, against query time, per intersection method.",
};

/// Progress steps: one, the whole suite.
pub fn steps(_cfg: &BenchConfig, _scenes: &[Scene]) -> u64 {
    1
}

/// The leak suite on its own meshes (the bench's scenes are not used).
pub fn run(cfg: &BenchConfig, _scenes: &[Scene], bar: &StepBar) -> Result<Vec<LeakRow>> {
    bar.set_message("leaks: rays at vertices and edges of closed meshes".into());
    let rows = crate::measure::stress::leak_suite(
        &crate::measure::stress::leak_meshes(cfg.quick),
        if cfg.quick { 2 } else { 4 },
    )?;
    bar.step();
    Ok(rows)
}

/// The part's table.
pub fn markdown(points: &[LeakRow]) -> String {
    format!(
        "### Leaks against speed (rays through closed meshes)\n\n{}\n",
        crate::measure::stress::leak_table(points).markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[LeakRow]) -> Result<Vec<String>> {
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (900, 520),
        draw_leaks,
        points
    )?])
}

fn draw_leaks<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, rows: &[LeakRow]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let method = |r: &LeakRow| {
        if r.embree {
            r.backend.clone()
        } else {
            format!(
                "{} ({})",
                r.backend.split("-watertight").next().unwrap_or(""),
                r.intersector
            )
        }
    };
    let mut methods: Vec<String> = Vec::new();
    for r in rows {
        let m = method(r);
        if !methods.contains(&m) {
            methods.push(m);
        }
    }
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Leak rate against speed, per intersection method",
            (FONT, 20),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(
            log_axis(log_range(rows.iter().map(|r| r.ns_per_ray))),
            lin_range(rows.iter().map(|r| r.leak_rate * 100.0), true),
        )?;
    chart
        .configure_mesh()
        .x_desc("ns per closest-hit query (log)")
        .x_label_formatter(&log_label)
        .y_desc("rays through the mesh (%)")
        .draw()?;
    for (i, m) in methods.iter().enumerate() {
        let c = color(i);
        chart
            .draw_series(
                rows.iter()
                    .filter(|r| method(r) == *m)
                    .map(|r| Circle::new((r.ns_per_ray, r.leak_rate * 100.0), 5, c.filled())),
            )?
            .label(m.as_str())
            .legend(move |(x, y)| Circle::new((x + 6, y), 5, c.filled()));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    root.present()?;
    Ok(())
}
