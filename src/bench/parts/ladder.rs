//! The `ladder` part: each rung of the build-quality ladder (`--quality low,
//! medium, high`) for raylab's 8-wide tree and for Embree's own scene, on
//! every bench scene: build time on one thread and on the bench's threads
//! (raylab's and Embree's builds of a rung paired, [`paired_builds`]),
//! SAH cost (raylab's), the render time, and the trace throughput per ray
//! kind of one render's recorded rays on each structure's fastest query path
//! (raylab's trees traced by raylab, Embree's by Embree; the trace part's
//! measurement, rungs interleaved run by run). A render of the half-size
//! image lasts about 50 ms here, and its per-kind times moved by 10-15%
//! between runs, more than the rungs differ; the recorded rays are traced
//! in runs of at least [`MIN_RUN_S`](crate::bench::timing::MIN_RUN_S), every rung in
//! turn. Its chart is the Pareto front per scene: build time against the
//! time to trace one render's rays.

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
    color, distinct, log_axis, log_label, log_range, save_chart, side_legend, DrawResult, Swatch,
    FONT, SIDE_LEGEND,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::Stat;
use crate::error::Result;
use crate::measure::validate::RaySet;
use crate::progress::{Progress, StepBar};
use crate::render::{render, AoMode, Schedule};

use super::trace::{self, TracePoint, KINDS};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Build-quality ladder",
    stem: "ladder",
    caption: "Build time against the time to trace one render's primary, shadow and AO rays (no shading), per scene, each rung of raylab's and Embree's ladders on the bench's threads: the lower left is better, a rung pays where it moves down more than right.",
};

const RUNGS: [Quality; 3] = [Quality::Low, Quality::Medium, Quality::High];

/// The least time the timed pairs of a rung's builds take on one thread
/// count (see [`paired_builds`]): the builds of a rung last 0.1-300 ms, and
/// a median of three pairs moved by 10-20% between runs on two threads.
const BUILD_PAIRS_S: f64 = 0.4;

/// The most pairs of builds of a rung on one thread count.
const MAX_BUILD_PAIRS: usize = 41;

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
    /// Build times on one thread and on the bench's threads, of
    /// `build_pairs` builds at least (see [`paired_builds`]).
    pub build_ms_1t: Stat,
    pub build_ms_nt: Stat,
    pub build_threads: usize,
    pub build_pairs: usize,
    /// raylab's rungs: the median over the pairs of builds of raylab's time
    /// over Embree's same rung's, on one thread and on the bench's threads
    /// (NaN for Embree, or without it).
    pub build_over_embree_1t: f64,
    pub build_over_embree_nt: f64,
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
    /// Trace throughput of one render's recorded rays per kind, in
    /// [`KINDS`] order (primary, shadow, AO, diffuse): the median Mrays/s on
    /// one thread and on the bench's threads (NaN where a kind had no rays).
    pub trace_mrays_1t: [f64; 4],
    pub trace_mrays_nt: [f64; 4],
    /// The time (ms) to trace one render's primary, shadow and AO rays at
    /// those rates, on one thread and on the bench's threads: the render's
    /// ray work without its shading.
    pub trace_ms_1t: f64,
    pub trace_ms_nt: f64,
    /// Answers that differ from raylab's low rung on the recorded rays, all
    /// kinds: 0 for raylab's rungs (or the bench fails); Embree's ties on
    /// shared edges and own misses.
    pub differing: usize,
}

/// Progress steps: one per scene, rung and structure, and one per scene and
/// traced ray kind.
pub fn steps(_cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    (scenes.len() * (RUNGS.len() * structures().len() + KINDS.len())) as u64
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

/// The rung's builds on one thread count: each structure's build times,
/// and raylab's over Embree's pair by pair.
struct PairedBuilds {
    /// Per structure, in [`structures`] order.
    ms: Vec<Stat>,
    pairs: usize,
    over_embree: Option<Stat>,
}

/// Times `rung`'s builds of every structure on `threads`: after an untimed
/// build of each (the first Embree build on a thread count makes its
/// device), pairs of builds, one of each structure, the order swapped every
/// pair, so that raylab's and Embree's builds share the machine's noisy
/// spells and each pair's ratio is a fair one. At least
/// `cfg.extra_reps()` pairs, then more until the pairs have taken
/// [`BUILD_PAIRS_S`], at most [`MAX_BUILD_PAIRS`] (one for `--quick`).
fn paired_builds(
    cfg: &BenchConfig,
    scene: &Scene,
    rung: Quality,
    threads: usize,
) -> Result<PairedBuilds> {
    let specs: Vec<BackendSpec> = structures()
        .into_iter()
        .map(|s| spec(s, rung, threads))
        .collect();
    let time = |spec: &BackendSpec| -> Result<f64> {
        let built = build_backend(spec, scene)?;
        built.check_build_threads()?;
        Ok(built.build_time.as_secs_f64() * 1e3)
    };
    for spec in &specs {
        time(spec)?;
    }
    let (least, most, budget) = if cfg.quick {
        (1, 1, 0.0)
    } else {
        (cfg.extra_reps(), MAX_BUILD_PAIRS, BUILD_PAIRS_S)
    };
    let mut times = vec![Vec::new(); specs.len()];
    let mut ratios = Vec::new();
    let start = std::time::Instant::now();
    let mut pairs = 0;
    while pairs < least || (pairs < most && start.elapsed().as_secs_f64() < budget) {
        let mut order: Vec<usize> = (0..specs.len()).collect();
        if pairs % 2 == 1 {
            order.reverse();
        }
        for i in order {
            times[i].push(time(&specs[i])?);
        }
        if let [own, embree] = &times[..] {
            ratios.push(own[pairs] / embree[pairs]);
        }
        pairs += 1;
    }
    Ok(PairedBuilds {
        ms: times.iter().map(|t| Stat::of(t)).collect(),
        pairs,
        over_embree: (!ratios.is_empty()).then(|| Stat::of(&ratios)),
    })
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
        // Builds first, with no structure of this scene held: Embree builds
        // on the most threads any live Embree device asked for, so a kept
        // two-thread scene would make its one-thread builds two-thread ones
        // (`Built::check_build_threads`).
        let mut points = Vec::new();
        // Each point's rung and structure, in the order of the points.
        let mut series = Vec::new();
        for &rung in &RUNGS {
            bar.set_message(format!(
                "ladder: builds of {} on {}",
                rung.name(),
                scene.name
            ));
            let one = paired_builds(cfg, scene, rung, 1)?;
            let many = paired_builds(cfg, scene, rung, cfg.threads)?;
            for (i, structure) in structures().into_iter().enumerate() {
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
                let over_embree = |b: &PairedBuilds| match (structure, &b.over_embree) {
                    ("raylab", Some(r)) => r.median,
                    _ => f64::NAN,
                };
                series.push((rung, structure));
                points.push(LadderPoint {
                    scene: scene.name.clone(),
                    triangles: scene.triangle_count(),
                    rung: rung.name().to_string(),
                    structure: structure.to_string(),
                    backend: spec(structure, rung, cfg.threads).name(),
                    build_ms_1t: one.ms[i],
                    build_ms_nt: many.ms[i],
                    build_threads: cfg.threads,
                    build_pairs: one.pairs.min(many.pairs),
                    build_over_embree_1t: over_embree(&one),
                    build_over_embree_nt: over_embree(&many),
                    sah_ns_per_ray,
                    references_per_triangle,
                    render_ms: Stat::default(),
                    trace_mrays_1t: [f64::NAN; 4],
                    trace_mrays_nt: [f64::NAN; 4],
                    trace_ms_1t: f64::NAN,
                    trace_ms_nt: f64::NAN,
                    differing: 0,
                });
            }
        }
        // Then each structure on the bench's threads, kept for the traces.
        let mut backends = Vec::new();
        for (p, &(rung, structure)) in points.iter_mut().zip(&series) {
            bar.set_message(format!(
                "ladder: renders of {structure} {} on {}",
                rung.name(),
                scene.name
            ));
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
            // The first render wakes the pool and faults the pages in.
            let mut times = Vec::new();
            render_once()?;
            for _ in 0..reps.max(1) {
                let start = std::time::Instant::now();
                render_once()?;
                times.push(start.elapsed().as_secs_f64() * 1e3);
            }
            bar.step();
            p.render_ms = Stat::of(&times);
            backends.push((built, Vec::new()));
        }
        // Every rung's structure traces the same recorded rays, the rungs in
        // turn within each run; raylab's rungs must answer as its low rung
        // does, bit for bit.
        let traced = trace::trace_backends(
            scene,
            &settings,
            &backends,
            &trace::thread_counts(cfg),
            trace::trace_reps(cfg),
            crate::bench::timing::min_run_s(cfg),
            bar,
        )?;
        for p in &mut points {
            add_trace(p, &traced, cfg.threads);
        }
        out.extend(points);
    }
    Ok(out)
}

/// Fills `p`'s trace figures from the trace points of its backend.
fn add_trace(p: &mut LadderPoint, traced: &[TracePoint], threads: usize) {
    let mut rays = [0usize; 4];
    for t in traced.iter().filter(|t| t.backend == p.backend) {
        let Some(k) = KINDS.iter().position(|k| *k == t.kind) else {
            continue;
        };
        rays[k] = t.rays;
        if t.threads == 1 {
            p.trace_mrays_1t[k] = t.mrays.median;
            p.differing += t.differing;
        }
        if t.threads == threads {
            p.trace_mrays_nt[k] = t.mrays.median;
        }
    }
    // One render's rays: the kinds a render casts (no diffuse bounces).
    let render_kinds = [RaySet::Primary, RaySet::Shadow, RaySet::Ao];
    let ms = |mrays: &[f64; 4]| {
        KINDS
            .iter()
            .zip(mrays.iter().zip(rays))
            .filter(|(k, _)| render_kinds.contains(k))
            .map(|(_, (&rate, n))| if n == 0 { 0.0 } else { n as f64 / rate / 1e3 })
            .sum::<f64>()
    };
    p.trace_ms_1t = ms(&p.trace_mrays_1t);
    p.trace_ms_nt = ms(&p.trace_mrays_nt);
}

/// `v` with `digits` decimals, `-` where not measured (NaN).
fn fixed(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "-".to_string()
    }
}

/// Four rates (or ratios) as `a/b/c/d`, `-` where not measured.
fn by_kind(values: [f64; 4]) -> String {
    values.map(|v| fixed(v, 2)).join("/")
}

/// The part's tables: one row per scene, rung and structure, with each
/// raylab rung's build and trace time against Embree's same rung; then each
/// structure's low and high rung against its medium rung, per ray kind.
pub fn markdown(points: &[LadderPoint]) -> String {
    let threads = points.first().map_or(1, |p| p.build_threads);
    let fewest = points.iter().map(|p| p.build_pairs).min().unwrap_or(0);
    let most = points.iter().map(|p| p.build_pairs).max().unwrap_or(0);
    let pairs = if fewest == most {
        fewest.to_string()
    } else {
        format!("{fewest} to {most}")
    };
    let nt = |what: &str| format!("{what} {threads}T");
    let (build_nt, trace_nt, over_nt) = (
        nt("build ms"),
        nt("trace Mrays/s P/S/AO/D"),
        nt("over medium P/S/AO/D"),
    );
    let mut t = Table::new([
        ("scene", Left),
        ("rung", Left),
        ("backend", Left),
        ("build ms 1T", Right),
        (build_nt.as_str(), Right),
        ("SAH ns/ray", Right),
        ("refs/tri", Right),
        ("render ms", Right),
        ("trace Mrays/s P/S/AO/D 1T", Right),
        (trace_nt.as_str(), Right),
        ("build / Embree's 1T, NT", Right),
        ("trace time / Embree's 1T, NT", Right),
    ]);
    for p in points {
        let embree = points
            .iter()
            .find(|e| e.structure == "embree" && e.scene == p.scene && e.rung == p.rung);
        let (build_ratio, trace_ratio) = match embree {
            Some(e) if p.structure == "raylab" => (
                format!(
                    "{}, {}",
                    fixed(p.build_over_embree_1t, 2),
                    fixed(p.build_over_embree_nt, 2)
                ),
                format!(
                    "{}, {}",
                    fixed(p.trace_ms_1t / e.trace_ms_1t, 2),
                    fixed(p.trace_ms_nt / e.trace_ms_nt, 2)
                ),
            ),
            _ => ("-".to_string(), "-".to_string()),
        };
        t.row([
            p.scene.clone(),
            p.rung.clone(),
            p.backend.clone(),
            format!("{:.2}", p.build_ms_1t.median),
            format!("{:.2}", p.build_ms_nt.median),
            fixed(p.sah_ns_per_ray, 1),
            fixed(p.references_per_triangle, 2),
            format!("{:.1}", p.render_ms.median),
            by_kind(p.trace_mrays_1t),
            by_kind(p.trace_mrays_nt),
            build_ratio,
            trace_ratio,
        ]);
    }
    let mut gain = Table::new([
        ("scene", Left),
        ("structure", Left),
        ("rung", Left),
        ("over medium P/S/AO/D 1T", Right),
        (over_nt.as_str(), Right),
    ]);
    for p in points.iter().filter(|p| p.rung != Quality::Medium.name()) {
        let Some(medium) = points.iter().find(|m| {
            m.scene == p.scene && m.structure == p.structure && m.rung == Quality::Medium.name()
        }) else {
            continue;
        };
        let over = |a: [f64; 4], b: [f64; 4]| by_kind(std::array::from_fn(|k| a[k] / b[k]));
        gain.row([
            p.scene.clone(),
            p.structure.clone(),
            p.rung.clone(),
            over(p.trace_mrays_1t, medium.trace_mrays_1t),
            over(p.trace_mrays_nt, medium.trace_mrays_nt),
        ]);
    }
    format!(
        "### Build-quality ladder\n\nEach rung (`--quality`) of raylab's 8-wide tree (low: LBVH, medium: binned SAH, high: SBVH with reinsertion) and of Embree's scene (its build quality of the same name), each on its fastest query path. Build: raylab's and Embree's builds of a rung alternate on each thread count, the order swapped every pair, {pairs} pairs per rung and thread count (as many as fit in {BUILD_PAIRS_S} s, at most {MAX_BUILD_PAIRS}; per row in bench.json); the median ms of each, and build / Embree's: the median of the pairs' ratios. SAH ns/ray: raylab's 8-wide tree as traversed, expected ns per ray in node visits and block tests at the measured {} (docs/design.md, \"The SAH cost of a wide tree\"). Trace: one render's recorded rays per kind (primary, shadow, AO, and one diffuse bounce per primary hit), median Mrays/s of wall time, every rung in turn in each run; trace time: the time of the render's primary, shadow and AO rays at those rates.\n\n{}\n\nTrace speed of each rung over its structure's medium rung, per ray kind (above 1: faster):\n\n{}\n",
        TraversalCosts::of_default_path().describe(),
        t.markdown(),
        gain.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[LadderPoint]) -> Result<Vec<String>> {
    let (rows, cols) = panel_grid(distinct(points.iter().map(|p| p.scene.as_str())).len());
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (460 * cols as u32 + SIDE_LEGEND, 520 * rows as u32),
        draw_ladder,
        points
    )?])
}

/// Panels in a row of the chart, at most: a sixth scene starts a new row.
const PANELS_PER_ROW: usize = 3;

/// Rows and columns of panels for `scenes` scenes: every scene gets one.
fn panel_grid(scenes: usize) -> (usize, usize) {
    let scenes = scenes.max(1);
    let cols = scenes.min(PANELS_PER_ROW);
    (scenes.div_ceil(cols), cols)
}

fn draw_ladder<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, pts: &[LadderPoint]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let (panels, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND));
    let scenes = distinct(pts.iter().map(|p| p.scene.as_str()));
    let areas = panels.split_evenly(panel_grid(scenes.len()));
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
                log_axis(log_range(
                    here.iter().map(|p| p.build_ms_nt.median.max(1e-3)),
                )),
                log_axis(log_range(here.iter().map(|p| p.trace_ms_nt.max(1e-3)))),
            )?;
        chart
            .configure_mesh()
            .x_desc("build ms (log)")
            .y_desc("trace ms of one render's rays (log)")
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
                        .map(|p| (p.build_ms_nt.median.max(1e-3), p.trace_ms_nt.max(1e-3)))
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

#[cfg(test)]
mod tests {
    use super::*;

    fn traced(backend: &str, kind: RaySet, threads: usize, rays: usize, mrays: f64) -> TracePoint {
        TracePoint {
            scene: "s".into(),
            triangles: 1,
            backend: backend.into(),
            structure: backend.into(),
            query: "packet16".into(),
            family: crate::bench::family::Family::Raylab,
            kind,
            threads,
            rays,
            mrays: Stat::of(&[mrays]),
            differing: usize::from(threads == 1),
            build_ms: f64::NAN,
            memory_bytes: None,
        }
    }

    fn point(rung: Quality, backend: &str) -> LadderPoint {
        LadderPoint {
            scene: "s".into(),
            triangles: 1,
            rung: rung.name().into(),
            structure: "raylab".into(),
            backend: backend.into(),
            build_ms_1t: Stat::of(&[1.0]),
            build_ms_nt: Stat::of(&[1.0]),
            build_threads: 2,
            build_pairs: 1,
            build_over_embree_1t: f64::NAN,
            build_over_embree_nt: f64::NAN,
            sah_ns_per_ray: 1.0,
            references_per_triangle: 1.0,
            render_ms: Stat::of(&[1.0]),
            trace_mrays_1t: [f64::NAN; 4],
            trace_mrays_nt: [f64::NAN; 4],
            trace_ms_1t: f64::NAN,
            trace_ms_nt: f64::NAN,
            differing: 0,
        }
    }

    #[test]
    fn trace_figures_come_from_the_backends_own_points() {
        // 2000 primary rays at 1 Mrays/s (2 ms), 1000 shadow at 2 (0.5 ms),
        // 4000 AO at 4 (1 ms) on one thread, twice those rates on two; the
        // diffuse rays are not part of a render's trace time. Another
        // backend's points must not leak in.
        let mut pts = Vec::new();
        for (threads, x) in [(1, 1.0), (2, 2.0)] {
            pts.push(traced("b", RaySet::Primary, threads, 2000, x));
            pts.push(traced("b", RaySet::Shadow, threads, 1000, 2.0 * x));
            pts.push(traced("b", RaySet::Ao, threads, 4000, 4.0 * x));
            pts.push(traced("b", RaySet::Diffuse, threads, 2000, 0.1 * x));
            pts.push(traced("other", RaySet::Primary, threads, 2000, 100.0));
        }
        let mut p = point(Quality::Medium, "b");
        add_trace(&mut p, &pts, 2);
        assert_eq!(p.trace_mrays_1t, [1.0, 2.0, 4.0, 0.1]);
        assert_eq!(p.trace_mrays_nt, [2.0, 4.0, 8.0, 0.2]);
        assert!((p.trace_ms_1t - 3.5).abs() < 1e-9, "{}", p.trace_ms_1t);
        assert!((p.trace_ms_nt - 1.75).abs() < 1e-9, "{}", p.trace_ms_nt);
        // Differing answers are summed over the kinds once (one thread).
        assert_eq!(p.differing, 4);
    }

    #[test]
    fn every_scene_gets_a_panel() {
        for scenes in 0..=10 {
            let (rows, cols) = panel_grid(scenes);
            assert!(rows * cols >= scenes && cols <= PANELS_PER_ROW, "{scenes}");
            // No empty row.
            assert!((rows - 1) * cols < scenes.max(1), "{scenes}");
        }
        assert_eq!(panel_grid(5), (2, 3));
        assert_eq!(panel_grid(2), (1, 2));
    }

    #[test]
    fn the_build_ratio_is_the_pairs_not_the_medians() {
        // Medians of 1 ms each, but raylab's builds were 0.8 and 0.9 of
        // Embree's pair by pair: the table quotes the pairs.
        let mut own = point(Quality::Low, "bvh8-lbvh-packet16");
        own.build_over_embree_1t = 0.8;
        own.build_over_embree_nt = 0.9;
        let mut embree = point(Quality::Low, "embree-low-packet16");
        embree.structure = "embree".into();
        let md = markdown(&[own, embree]);
        let row = md
            .lines()
            .find(|l| l.contains("bvh8-lbvh-packet16"))
            .expect("raylab's row");
        assert!(row.contains("| 0.80, 0.90 |"), "{row}");
        let row = md
            .lines()
            .find(|l| l.contains("embree-low-packet16"))
            .expect("Embree's row");
        assert!(!row.contains("0.80"), "{row}");
    }

    #[test]
    fn the_gain_table_divides_each_rung_by_its_medium_rung() {
        let mut medium = point(Quality::Medium, "m");
        medium.trace_mrays_1t = [10.0, 10.0, 10.0, 10.0];
        medium.trace_mrays_nt = [20.0, 20.0, 20.0, 20.0];
        let mut high = point(Quality::High, "h");
        high.trace_mrays_1t = [12.0, 11.0, 9.0, f64::NAN];
        high.trace_mrays_nt = [30.0, 20.0, 10.0, 40.0];
        let md = markdown(&[medium, high]);
        assert!(
            md.contains("| s | raylab | high | 1.20/1.10/0.90/- | 1.50/1.00/0.50/2.00 |"),
            "{md}"
        );
    }
}
