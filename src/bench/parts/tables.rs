//! The study's tables from the bench's measurements: times in ms per scene
//! (columns, by triangle count) and view (rows), one table per variant and AO
//! mode, and speedups over the baseline (`naive-serial`); as Markdown and CSV,
//! and the speedup charts. The matrix itself is measured by
//! [`crate::bench::measure`].

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::bench::charts::{
    best_per_family, draw_bars, log_label, log_range, save_chart, short, Bars, DrawResult,
};
use crate::bench::measure::Measurement;
use crate::bench::variants::BASELINE;
use crate::error::Result;
use crate::table::{
    fmt_ms,
    Align::{Left, Right},
    Table,
};

/// Distinct values of `key` in first-seen order.
fn distinct<'a>(ms: &'a [Measurement], key: impl Fn(&'a Measurement) -> &'a str) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for m in ms {
        let k = key(m);
        if !out.contains(&k) {
            out.push(k);
        }
    }
    out
}

/// The variant speedups are relative to: `naive-serial` when it was measured,
/// else the first variant.
pub fn baseline_name(ms: &[Measurement]) -> &str {
    if ms.iter().any(|m| m.variant == BASELINE) {
        BASELINE
    } else {
        ms.first().map_or(BASELINE, |m| m.variant.as_str())
    }
}

/// The measurement of `variant` on the cell of `m`.
pub fn find<'a>(ms: &'a [Measurement], m: &Measurement, variant: &str) -> Option<&'a Measurement> {
    ms.iter()
        .find(|o| o.variant == variant && o.scene == m.scene && o.view == m.view && o.ao == m.ao)
}

/// Median total time of the baseline over `m`'s, on `m`'s cell.
pub fn speedup(ms: &[Measurement], m: &Measurement) -> Option<f64> {
    let base = find(ms, m, baseline_name(ms))?;
    (m.total_ms.median > 0.0 && base.total_ms.n > 0)
        .then(|| base.total_ms.median / m.total_ms.median)
}

/// Column headers: scene names with their triangle counts.
fn scene_headers(ms: &[Measurement]) -> Vec<(String, String)> {
    distinct(ms, |m| &m.scene)
        .into_iter()
        .map(|s| {
            let tris = ms.iter().find(|m| m.scene == s).map_or(0, |m| m.triangles);
            (s.to_string(), format!("{s} ({tris})"))
        })
        .collect()
}

/// Per AO mode: a summary of all variants' speedups, then one table per variant
/// with the median total ms (min..max, runs) and the speedup per view and scene.
pub fn markdown(ms: &[Measurement]) -> String {
    let mut out = String::new();
    let base = baseline_name(ms);
    let scenes = scene_headers(ms);
    let views = distinct(ms, |m| &m.view);
    for ao in distinct(ms, |m| &m.ao) {
        let here: Vec<&Measurement> = ms.iter().filter(|m| m.ao == ao).collect();
        out.push_str(&format!(
            "### AO {ao}: speedup over {base} (median total time, build included)\n\n"
        ));
        let mut table = Table::new([("variant", Left), ("view", Left)]);
        for (_, h) in &scenes {
            table.column(h.clone(), Right);
        }
        for variant in distinct(ms, |m| &m.variant) {
            for view in &views {
                let mut row = vec![variant.to_string(), view.to_string()];
                for (scene, _) in &scenes {
                    let cell = here
                        .iter()
                        .find(|m| m.variant == variant && m.view == *view && m.scene == *scene);
                    row.push(
                        cell.and_then(|m| speedup(ms, m))
                            .map_or("-".to_string(), |s| format!("{s:.2}x")),
                    );
                }
                table.row(row);
            }
        }
        out.push_str(&table.markdown());
        out.push('\n');
        for variant in distinct(ms, |m| &m.variant) {
            let first = here.iter().find(|m| m.variant == variant);
            let Some(first) = first else { continue };
            out.push_str(&format!(
                "#### {variant}, AO {ao} ({} build thread(s), {} render thread(s))\n\n",
                first.build_threads, first.render_threads
            ));
            let mut table = Table::new([("view", Left), ("", Left)]);
            for (_, h) in &scenes {
                table.column(h.clone(), Right);
            }
            for view in &views {
                let cells: Vec<Option<&&Measurement>> = scenes
                    .iter()
                    .map(|(scene, _)| {
                        here.iter()
                            .find(|m| m.variant == variant && m.view == *view && m.scene == *scene)
                    })
                    .collect();
                let mut row = |label: &str, f: &dyn Fn(&Measurement) -> String| {
                    let mut line = vec![view.to_string(), label.to_string()];
                    line.extend(cells.iter().map(|c| c.map_or("-".to_string(), |m| f(m))));
                    table.row(line);
                };
                row("total ms", &|m| {
                    format!(
                        "{} ({}..{}, n={})",
                        fmt_ms(m.total_ms.median),
                        fmt_ms(m.total_ms.min),
                        fmt_ms(m.total_ms.max),
                        m.total_ms.n
                    )
                });
                row("build ms", &|m| fmt_ms(m.build_ms.median));
                row("speedup", &|m| {
                    speedup(ms, m).map_or("-".to_string(), |s| format!("{s:.2}x"))
                });
            }
            out.push_str(&table.markdown());
            out.push('\n');
        }
    }
    out
}

/// Per variant and scene on one AO mode and view: Mrays/s per thread by ray kind
/// (primary/shadow/AO, shading included), the figure the single-ray comparison
/// with Embree is about.
pub fn kind_rates_markdown(ms: &[Measurement], ao: &str, view: &str) -> String {
    let scenes = scene_headers(ms);
    let mut table = Table::new([("variant", Left)]);
    for (_, h) in &scenes {
        table.column(h.clone(), Right);
    }
    for variant in distinct(ms, |m| &m.variant) {
        let mut row = vec![variant.to_string()];
        for (scene, _) in &scenes {
            row.push(
                ms.iter()
                    .find(|m| {
                        m.variant == variant && m.scene == *scene && m.ao == ao && m.view == view
                    })
                    .map_or("-".to_string(), |m| {
                        let r = &m.thread_mrays_per_s;
                        format!("{:.2}/{:.2}/{:.2}", r.primary, r.shadow, r.ao)
                    }),
            );
        }
        table.row(row);
    }
    format!(
        "### Mrays/s per thread by ray kind (primary/shadow/AO, shading included), AO {ao}, view {view}\n\n{}\n",
        table.markdown()
    )
}

/// One row per measurement, with its speedup; the header names every column.
pub const CSV_HEADER: &str = "ao,variant,backend,schedule,scene,triangles,view,runs,build_threads,render_threads,build_ms_median,render_ms_median,total_ms_median,total_ms_min,total_ms_max,spread,speedup,mrays_per_s,primary_mrays_per_thread_s,shadow_mrays_per_thread_s,ao_mrays_per_thread_s,image_hash,deterministic";

pub fn csv(ms: &[Measurement]) -> String {
    let mut table = Table::new(CSV_HEADER.split(',').map(|c| (c, Left)));
    for m in ms {
        let f4 = |x: f64| format!("{x:.4}");
        table.row([
            m.ao.clone(),
            m.variant.clone(),
            m.backend.clone(),
            m.schedule.clone(),
            m.scene.clone(),
            m.triangles.to_string(),
            m.view.clone(),
            m.total_ms.n.to_string(),
            m.build_threads.to_string(),
            m.render_threads.to_string(),
            f4(m.build_ms.median),
            f4(m.render_ms.median),
            f4(m.total_ms.median),
            f4(m.total_ms.min),
            f4(m.total_ms.max),
            f4(m.total_ms.spread()),
            speedup(ms, m).map_or(String::new(), f4),
            f4(m.mrays_per_s),
            f4(m.thread_mrays_per_s.primary),
            f4(m.thread_mrays_per_s.shadow),
            f4(m.thread_mrays_per_s.ao),
            m.image_hash.clone(),
            m.deterministic.to_string(),
        ]);
    }
    table.csv()
}

pub const SECTION: ChartSection = ChartSection {
    title: "Speedups",
    stem: "speedup",
    caption: "Speedup over the baseline per scene and view (log scale): the best variant of each family (raylab, Embree, each library); the tables below have every variant.",
};

/// The part's charts: one per AO mode.
pub fn charts(dir: &Path, ms: &[Measurement], ao_modes: &[String]) -> Result<Vec<String>> {
    ao_modes
        .iter()
        .map(|ao| {
            let data = SpeedupData { ms, ao: ao.clone() };
            let name = format!("{}-ao-{}", SECTION.stem, ao.replace(':', "-"));
            save_chart!(dir, &name, (1390, 560), draw_speedup, &data)
        })
        .collect()
}

/// Speedup over the baseline per scene and view, one bar per variant (log scale).
struct SpeedupData<'a> {
    ms: &'a [Measurement],
    ao: String,
}

fn draw_speedup<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, d: &SpeedupData) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let here: Vec<&Measurement> = d.ms.iter().filter(|m| m.ao == d.ao).collect();
    let mut groups: Vec<(String, String, usize)> = Vec::new();
    for m in &here {
        if !groups.iter().any(|(s, v, _)| *s == m.scene && *v == m.view) {
            groups.push((m.scene.clone(), m.view.clone(), m.triangles));
        }
    }
    // The best variant of each family per cell (the tables have each).
    let series = best_per_family(
        &here,
        groups.len(),
        |m| m.family,
        |m| m.variant.as_str(),
        |m, g| {
            let (scene, view, _) = &groups[g];
            (m.scene == *scene && m.view == *view)
                .then(|| speedup(d.ms, m))
                .flatten()
        },
        "variants",
    );
    let values: Vec<f64> = here.iter().filter_map(|m| speedup(d.ms, m)).collect();
    let y = log_range(values.iter().copied().chain([1.0]));
    let speedup_label = |v: &f64| {
        let l = log_label(v);
        if l.is_empty() {
            l
        } else {
            format!("{l}x")
        }
    };
    draw_bars(
        root,
        &Bars {
            caption: format!(
                "Speedup over {} (total time, median), AO {}",
                super::tables::baseline_name(d.ms),
                d.ao
            ),
            y_desc: "speedup (log)",
            groups: groups
                .iter()
                .map(|(scene, view, tris)| (short(scene), format!("{tris} tris {view}")))
                .collect(),
            series,
            y: (y.start.min(0.5))..y.end,
            y_label: &speedup_label,
        },
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bench::measure::Stat;

    /// A measurement with a fixed total time, for table tests.
    pub fn fake(scene: &str, view: &str, ao: &str, variant: &str, total: f64) -> Measurement {
        let t = Stat {
            n: 3,
            median: total,
            min: total * 0.9,
            max: total * 1.2,
        };
        Measurement {
            scene: scene.into(),
            triangles: scene.len(),
            view: view.into(),
            ao: ao.into(),
            variant: variant.into(),
            backend: "x".into(),
            family: crate::bench::family::Family::Raylab,
            schedule: "serial".into(),
            build_threads: 1,
            render_threads: 1,
            build_ms: Stat { median: 1.0, ..t },
            render_ms: t,
            total_ms: t,
            warmup_counted: false,
            rays: 10,
            mrays_per_s: 1.0,
            thread_mrays_per_s: Default::default(),
            image_hash: "0".into(),
            deterministic: true,
        }
    }

    #[test]
    fn speedups_divide_the_baseline_of_the_same_cell() {
        let ms = vec![
            fake("a", "(0,1,3)", "paper", "naive-serial", 1000.0),
            fake("a", "(2,1,3)", "paper", "naive-serial", 500.0),
            fake("a", "(0,1,3)", "off", "naive-serial", 100.0),
            fake("a", "(0,1,3)", "paper", "bvh-sah-tiles", 10.0),
            fake("a", "(2,1,3)", "paper", "bvh-sah-tiles", 10.0),
            fake("a", "(0,1,3)", "off", "bvh-sah-tiles", 20.0),
            fake("b", "(0,1,3)", "paper", "bvh-sah-tiles", 20.0),
        ];
        assert_eq!(baseline_name(&ms), "naive-serial");
        let s: Vec<Option<f64>> = ms.iter().map(|m| speedup(&ms, m)).collect();
        assert_eq!(
            s,
            [
                Some(1.0),
                Some(1.0),
                Some(1.0),
                Some(100.0),
                Some(50.0),
                Some(5.0),
                None
            ]
        );
        let md = markdown(&ms);
        assert!(
            md.contains("| bvh-sah-tiles | (0,1,3) | 100.00x | - |"),
            "{md}"
        );
        assert!(md.contains("### AO off"));
        assert!(md.contains("#### bvh-sah-tiles, AO paper"));
        let csv = csv(&ms);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), ms.len() + 1);
        let cols = CSV_HEADER.split(',').count();
        for line in &lines {
            // The view is quoted because it holds commas.
            let unquoted = line.replace("\"(0,1,3)\"", "v").replace("\"(2,1,3)\"", "v");
            assert_eq!(unquoted.split(',').count(), cols, "{line}");
        }
        assert!(lines[4].contains(",100.0000,"), "{}", lines[4]);
    }

    #[test]
    fn without_naive_serial_the_first_variant_is_the_baseline() {
        let ms = vec![
            fake("a", "v", "off", "bvh-median-serial", 40.0),
            fake("a", "v", "off", "bvh-sah-tiles", 10.0),
        ];
        assert_eq!(baseline_name(&ms), "bvh-median-serial");
        assert_eq!(speedup(&ms, &ms[1]), Some(4.0));
    }
}
