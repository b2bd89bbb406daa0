//! The `libraries` part: every CPU BVH side by side, raylab's, Embree and the
//! other libraries (tinybvh, obvhs, the bvh crate), each on its fastest query
//! path, on the same recorded rays in one process: build time on one thread,
//! throughput per ray kind on one thread, and how many of its answers are
//! wrong against the exact reference (`src/measure/exact.rs`). Its chart is the
//! design card's "chart one against the other": time per ray against wrong
//! answers per million, one point per backend and intersector.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::ChartSection;
use crate::accel::bvh::BuildParams;
use crate::accel::library::Library;
use crate::accel::{build_backend, BackendSpec, Built, Query};
use crate::bench::charts::{
    distinct, family_shade, log_axis, log_label, log_range, save_chart, side_legend, DrawResult,
    Swatch, FONT, SIDE_LEGEND,
};
use crate::bench::config::BenchConfig;
use crate::bench::family::Family;
use crate::bench::measure::Stat;
use crate::bench::timing::{min_run_s, passes_for, trace};
use crate::error::Result;
use crate::geometry::{Intersector, Ray};
use crate::measure::exact::{judge_answers, ExactAnswer, ExactReference, ExactReport};
use crate::measure::validate::{edge_rays, recorded_rays, RaySet};
use crate::progress::StepBar;
use crate::render::AoMode;
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Every CPU BVH: speed against accuracy",
    stem: "libraries",
    caption: "Time per ray (one thread, mean over the render's ray kinds) against wrong answers per million against the exact reference, per scene: top row on the render's rays, bottom row on rays aimed at the scene's vertices and edges. A backend with none sits on the bottom line (dot: raylab, triangle: Embree, cross: another library; colour: the family, a shade per backend). Lower left is better.",
};

/// The ray kinds: a render's, its diffuse bounces, random rays (only from a
/// ray file, `bench --rays`), and rays aimed at the scene's vertices and
/// edges (the leak suite's, judged apart: they are adversarial, not work a
/// renderer does, so they stay out of the mean time per ray).
pub const KINDS: [RaySet; 6] = [
    RaySet::Primary,
    RaySet::Shadow,
    RaySet::Ao,
    RaySet::Diffuse,
    RaySet::Random,
    RaySet::Edges,
];

/// One backend on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct LibraryPoint {
    pub scene: String,
    pub triangles: usize,
    pub backend: String,
    /// Whose it is (`raylab`, `embree`, or the library's name).
    pub family: Family,
    /// Whether its triangle test is watertight ([`BackendSpec::is_robust`]).
    pub robust: bool,
    /// Median build ms on one thread (after an untimed build).
    pub build_ms: Stat,
    /// Mrays/s on one thread per kind, in [`KINDS`] order, on the query
    /// path that was fastest for that kind.
    pub mrays: Vec<f64>,
    /// That path per kind (`single`, `packet8`, `packet16`; empty where not
    /// measured).
    pub paths: Vec<String>,
    /// Mean ns per ray over the kinds but edges (each kind weighted alike).
    pub ns_per_ray: f64,
    pub rays: usize,
    /// Wrong answers (the query each kind asks) against the exact reference,
    /// on every kind but edges.
    pub wrong: usize,
    pub undecidable: usize,
    pub wrong_per_million: f64,
    /// The same on the edge and vertex rays, closest hit and any hit both
    /// asked (per million answers).
    pub edge_rays: usize,
    pub edge_wrong: usize,
    pub edge_undecidable: usize,
    pub edge_wrong_per_million: f64,
    /// What the library lacks and raylab filled in (empty for raylab's own).
    pub limits: Vec<String>,
    /// Why it could not be built on this scene (then nothing was measured).
    pub failed: Option<String>,
}

/// The backends compared, each on its fastest query path, built on one
/// thread: raylab's 8-wide tree with both triangle tests and at its high
/// rung, Embree plain and robust and at its high quality (spatial splits,
/// as raylab's high rung), and every layout of the other libraries built in.
fn specs() -> Vec<BackendSpec> {
    let bvh8 = BackendSpec::bvh(BuildParams::sah().with_width(8));
    // raylab's high rung too (SBVH with reinsertion), beside tinybvh's BuildHQ.
    let high = BackendSpec::bvh(
        BuildParams::for_quality(crate::accel::bvh::params::Quality::High).with_width(8),
    );
    let mut out = vec![bvh8, bvh8.with_intersector(Intersector::Watertight), high];
    if crate::accel::embree::AVAILABLE {
        use crate::accel::embree::Quality::{High, Medium};
        // Embree's high quality beside raylab's high rung: without it the
        // part set raylab's spatial splits against Embree's plain SAH.
        for (quality, robust) in [(Medium, false), (Medium, true), (High, false)] {
            out.push(BackendSpec::Embree {
                quality,
                robust,
                threads: 1,
                query: crate::accel::Query::Single,
            });
        }
    }
    out.extend(
        Library::ALL
            .into_iter()
            .filter(Library::available)
            .map(|l| BackendSpec::library(l, 1)),
    );
    out.into_iter()
        .map(BackendSpec::with_fastest_query)
        .collect()
}

/// The query paths each backend is timed on, where it has them (Embree's
/// packets both coherent and incoherent: either can be its fastest).
const PATHS: [Query; 5] = [
    Query::Single,
    Query::Packet(8),
    Query::Packet(16),
    Query::IncoherentPacket(8),
    Query::IncoherentPacket(16),
];

/// Progress steps: one per scene and backend.
pub fn steps(_cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    (scenes.len() * specs().len()) as u64
}

/// Every backend on every scene, on the rays of its first view at half size.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<LibraryPoint>> {
    let size = cfg.smaller(2);
    let reps = cfg.extra_reps();
    let per_kind = if cfg.quick { 2_000 } else { 50_000 };
    let mut out = Vec::new();
    for scene in scenes {
        let settings = cfg
            .first_view(scene, size)
            .settings(size, AoMode::Paper, 1)?;
        let mut rays: Vec<Vec<Ray>> = match &cfg.rays {
            // A ray file (`--rays`): its rays, whole.
            Some(file) => KINDS
                .iter()
                .map(|k| {
                    file.iter()
                        .filter(|(set, _)| set == k)
                        .flat_map(|(_, r)| r.iter().copied())
                        .collect()
                })
                .collect(),
            None => {
                bar.set_message(format!("libraries: recording the rays of {}", scene.name));
                let recorder = build_backend(
                    &BackendSpec::bvh(BuildParams::sah().with_width(8)).with_fastest_query(),
                    scene,
                )?;
                let recorded = recorded_rays(scene, recorder.as_ref(), &settings)?;
                let diffuse = recorded.diffuse(scene, settings.seed);
                [
                    &recorded.primary,
                    &recorded.shadow,
                    &recorded.ao,
                    &diffuse,
                    &Vec::new(),
                    &Vec::new(),
                ]
                .into_iter()
                .map(|r| window(r, per_kind))
                .collect()
            }
        };
        // The scene's own edge and vertex rays, with a ray file too.
        let triangles = scene.triangle_vertices();
        rays[KINDS.len() - 1] = edge_rays(&triangles, per_kind, settings.seed);
        bar.set_message(format!("libraries: exact answers on {}", scene.name));
        let reference = ExactReference::new(triangles);
        // Worked out once, for every backend.
        let answers: Vec<Vec<ExactAnswer>> = rays.iter().map(|r| reference.answers(r)).collect();
        // Every backend built first (an untimed build, then the timed ones),
        // with its other query paths: packets win on coherent rays and may
        // lose on incoherent ones, so each kind is timed on every path and
        // the fastest counts (Embree's too).
        let mut backends: Vec<(Built, Vec<Built>, Stat)> = Vec::new();
        // Rows in `specs` order: the one saying why a backend was not built,
        // or None for a built one (filled in once traced).
        let mut rows: Vec<Option<LibraryPoint>> = Vec::new();
        for spec in specs() {
            bar.set_message(format!(
                "libraries: building {} on {}",
                spec.name(),
                scene.name
            ));
            let built = match build_backend(&spec, scene) {
                Ok(b) => b,
                // A library that cannot build this scene is reported, not fatal.
                Err(e) => {
                    rows.push(Some(not_built(scene, &spec, e.to_string())));
                    bar.step();
                    continue;
                }
            };
            let mut times = Vec::new();
            for _ in 0..reps.max(1) {
                let built = build_backend(&spec, scene)?;
                built.check_build_threads()?;
                times.push(built.build_time.as_secs_f64() * 1e3);
            }
            let others = PATHS
                .iter()
                .filter(|&&q| q != spec.query() && spec.queries().contains(&q))
                .map(|&q| build_backend(&spec.with_query(q)?, scene))
                .collect::<Result<Vec<Built>>>()?;
            backends.push((built, others, Stat::of(&times)));
            rows.push(None);
        }
        bar.set_message(format!("libraries: tracing on {}", scene.name));
        let timed = time_interleaved(&backends, &rays, reps, min_run_s(cfg));
        let mut measured = backends.iter().zip(timed);
        for row in rows {
            match row {
                Some(failed) => out.push(failed),
                None => {
                    if let Some(((built, _, build_ms), (mrays, paths))) = measured.next() {
                        out.push(judged(
                            scene, built, *build_ms, mrays, paths, &rays, &answers,
                        ));
                        bar.step();
                    }
                }
            }
        }
    }
    Ok(out)
}

/// The row of a backend that could not be built on `scene`.
fn not_built(scene: &Scene, spec: &BackendSpec, why: String) -> LibraryPoint {
    LibraryPoint {
        scene: scene.name.clone(),
        triangles: scene.triangle_count(),
        backend: spec.structure_name(),
        family: Family::of(spec),
        robust: spec.is_robust(),
        build_ms: Stat::of(&[]),
        mrays: vec![f64::NAN; KINDS.len()],
        paths: vec![String::new(); KINDS.len()],
        ns_per_ray: f64::NAN,
        rays: 0,
        wrong: 0,
        undecidable: 0,
        wrong_per_million: f64::NAN,
        edge_rays: 0,
        edge_wrong: 0,
        edge_undecidable: 0,
        edge_wrong_per_million: f64::NAN,
        limits: Vec::new(),
        failed: Some(why),
    }
}

/// Mrays/s on one thread per backend and kind, on the backend's fastest
/// path for that kind, and that path's name. Per kind every backend and
/// path is traced once untimed, then `reps` rounds each tracing all of
/// them in turn (so drift on a shared machine hits all alike), each run at
/// least `min_run` seconds long; the median of each counts.
fn time_interleaved(
    backends: &[(Built, Vec<Built>, Stat)],
    rays: &[Vec<Ray>],
    reps: usize,
    min_run: f64,
) -> Vec<(Vec<f64>, Vec<String>)> {
    let mut out = vec![(Vec::new(), Vec::new()); backends.len()];
    // Per backend: its own path first, then its others.
    let candidates: Vec<Vec<&Built>> = backends
        .iter()
        .map(|(b, others, _)| std::iter::once(b).chain(others).collect())
        .collect();
    for (kind, rays) in KINDS.iter().zip(rays) {
        let closest = kind.closest();
        if rays.is_empty() {
            for o in &mut out {
                o.0.push(f64::NAN);
                o.1.push(String::new());
            }
            continue;
        }
        // The warm-up also sets each path's passes per timed run.
        let passes: Vec<Vec<usize>> = candidates
            .iter()
            .map(|c| {
                c.iter()
                    .map(|path| passes_for(trace(path.as_ref(), closest, rays, 1, 1).0, min_run))
                    .collect()
            })
            .collect();
        let mut rates: Vec<Vec<Vec<f64>>> = candidates
            .iter()
            .map(|c| vec![Vec::new(); c.len()])
            .collect();
        for _ in 0..reps.max(1) {
            for ((c, r), p) in candidates.iter().zip(&mut rates).zip(&passes) {
                for ((path, r), &n) in c.iter().zip(r).zip(p) {
                    let secs = trace(path.as_ref(), closest, rays, 1, n).0.max(1e-12);
                    r.push((rays.len() * n) as f64 / secs / 1e6);
                }
            }
        }
        for ((c, r), o) in candidates.iter().zip(&rates).zip(&mut out) {
            let (best, rate) = r.iter().map(|r| Stat::of(r).median).enumerate().fold(
                (0, f64::NEG_INFINITY),
                |a, (i, m)| if m > a.1 { (i, m) } else { a },
            );
            o.0.push(rate);
            o.1.push(c[best].spec.query().name());
        }
    }
    out
}

/// At most `n` consecutive rays from the middle of `rays`, in the order the
/// render cast them. Not an even subsample: neighbouring rays are what
/// packets trace together, and every 40th ray of a frame made raylab's and
/// Embree's packet paths look 2.6x slower than they are (engine primary
/// rays: 7.8 Mrays/s against 14.5 on the whole frame).
pub(crate) fn window(rays: &[Ray], n: usize) -> Vec<Ray> {
    let start = rays.len().saturating_sub(n) / 2;
    rays[start..(start + n).min(rays.len())].to_vec()
}

/// The rays of one frame of `scene`, recorded through `recorder` at half
/// the bench's size with the paper's AO: per kind (primary, shadow, AO) a
/// [`window`] of `per_kind`, and how many rays a whole frame at the bench's
/// size casts (the recorded count scaled by the pixels).
pub(crate) fn recorded_windows(
    scene: &Scene,
    recorder: &dyn crate::accel::Backend,
    cfg: &BenchConfig,
    per_kind: usize,
) -> Result<(Vec<Vec<Ray>>, f64)> {
    let size = cfg.smaller(2);
    let settings = cfg
        .first_view(scene, size)
        .settings(size, crate::render::AoMode::Paper, 1)?;
    let recorded = crate::measure::validate::recorded_rays(scene, recorder, &settings)?;
    let scale = (cfg.size.0 as f64 * cfg.size.1 as f64) / (size.0 as f64 * size.1 as f64);
    let whole = (recorded.primary.len() + recorded.shadow.len() + recorded.ao.len()) as f64;
    let rays = [&recorded.primary, &recorded.shadow, &recorded.ao]
        .into_iter()
        .map(|r| window(r, per_kind))
        .collect();
    Ok((rays, whole * scale))
}

/// The ms a frame of `frame_rays` rays takes at `mrays` (Mrays/s per kind),
/// the kinds in the proportions of `rays` (a kind with none counts nothing).
pub(crate) fn frame_ms(rays: &[Vec<Ray>], mrays: &[f64], frame_rays: f64) -> f64 {
    let shares: Vec<f64> = rays.iter().map(|r| r.len() as f64).collect();
    let total: f64 = shares.iter().sum::<f64>().max(1.0);
    shares
        .iter()
        .zip(mrays)
        .filter(|(s, _)| **s > 0.0)
        .map(|(s, m)| frame_rays * s / total / (m * 1e3))
        .sum()
}

/// `built`'s point: its timings, and the exact reference's verdicts on its
/// answers (the query each kind asks; both queries on the edge rays).
fn judged(
    scene: &Scene,
    built: &Built,
    build_ms: Stat,
    mrays: Vec<f64>,
    paths: Vec<String>,
    rays: &[Vec<Ray>],
    answers: &[Vec<ExactAnswer>],
) -> LibraryPoint {
    let (mut wrong, mut undecidable, mut total) = (0, 0, 0);
    let mut edges = ExactReport::default();
    for ((kind, rays), answers) in KINDS.iter().zip(rays).zip(answers) {
        if rays.is_empty() {
            continue;
        }
        let r = judge_answers(kind.name(), rays, answers, built.as_ref());
        if *kind == RaySet::Edges {
            edges = r;
            continue;
        }
        if kind.closest() {
            wrong += r.closest_wrong();
            undecidable += r.undecidable;
        } else {
            wrong += r.occlusion_wrong();
            undecidable += r.occlusion_undecidable;
        }
        total += rays.len();
    }
    let measured: Vec<f64> = KINDS
        .iter()
        .zip(&mrays)
        .filter(|(k, m)| **k != RaySet::Edges && m.is_finite())
        .map(|(_, m)| *m)
        .collect();
    let ns_per_ray = measured.iter().map(|m| 1e3 / m).sum::<f64>() / measured.len().max(1) as f64;
    let limits = match built.spec {
        BackendSpec::Library { library, .. } => {
            library.limits().iter().map(|s| s.to_string()).collect()
        }
        _ => Vec::new(),
    };
    LibraryPoint {
        scene: scene.name.clone(),
        triangles: scene.triangle_count(),
        backend: built.spec.structure_name(),
        family: Family::of(&built.spec),
        robust: built.spec.is_robust(),
        build_ms,
        mrays,
        paths,
        ns_per_ray,
        rays: total,
        wrong,
        undecidable,
        wrong_per_million: wrong as f64 * 1e6 / total.max(1) as f64,
        edge_rays: edges.rays,
        edge_wrong: edges.wrong(),
        edge_undecidable: edges.undecidable_answers(),
        edge_wrong_per_million: if edges.rays > 0 {
            edges.wrong_per_million()
        } else {
            f64::NAN
        },
        limits,
        failed: None,
    }
}

/// The part's table: per scene and backend, build ms, Mrays/s per kind, and
/// wrong answers per million; then what each library lacks.
pub fn markdown(points: &[LibraryPoint]) -> String {
    // The kinds measured anywhere (random rays come only from ray files).
    let kinds: Vec<usize> = (0..KINDS.len())
        .filter(|&k| {
            points
                .iter()
                .any(|p| p.mrays.get(k).is_some_and(|m| m.is_finite()))
        })
        .collect();
    let mut t = Table::new([("scene", Left), ("backend", Left), ("build ms", Right)]);
    for &k in &kinds {
        t.column(format!("Mrays/s {}", KINDS[k].name()), Right);
    }
    t.column("fastest path per kind", Left);
    t.column("wrong per million", Right);
    t.column("undecidable", Right);
    t.column("edge rays: wrong per million", Right);
    t.column("undecidable", Right);
    for p in points {
        if let Some(why) = &p.failed {
            let mut row = vec![p.scene.clone(), p.backend.clone()];
            row.extend((0..kinds.len() + 5).map(|_| "-".to_string()));
            row.push(format!("not built: {why}"));
            t.row(row);
            continue;
        }
        let mut row = vec![
            p.scene.clone(),
            p.backend.clone(),
            format!("{:.2}", p.build_ms.median),
        ];
        row.extend(kinds.iter().map(|&k| match p.mrays.get(k) {
            Some(m) if m.is_finite() => format!("{m:.2}"),
            _ => "-".to_string(),
        }));
        let paths: Vec<&str> = kinds
            .iter()
            .map(|&k| p.paths.get(k).map_or("-", |s| s.as_str()))
            .collect();
        row.push(paths.join("/"));
        row.push(format!("{:.0} ({})", p.wrong_per_million, p.wrong));
        row.push(p.undecidable.to_string());
        if p.edge_rays > 0 {
            row.push(format!(
                "{:.0} ({})",
                p.edge_wrong_per_million, p.edge_wrong
            ));
            row.push(p.edge_undecidable.to_string());
        } else {
            row.extend(["-".to_string(), "-".to_string()]);
        }
        t.row(row);
    }
    let mut limits: Vec<(String, Vec<String>)> = Vec::new();
    for p in points.iter().filter(|p| !p.limits.is_empty()) {
        if !limits.iter().any(|(b, _)| *b == p.backend) {
            limits.push((p.backend.clone(), p.limits.clone()));
        }
    }
    let limits: String = limits
        .iter()
        .map(|(b, l)| format!("- `{b}`: {}\n", l.join("; ")))
        .collect();
    format!(
        "### Every CPU BVH side by side\n\nOne thread, each backend on its fastest query path per ray kind (raylab's 8-wide trees and Embree are timed on single rays and on packets of 8 and 16, interleaved, and the fastest counts; the path is listed), the same recorded rays (one render's primary, shadow and AO rays and a diffuse bounce per primary hit: at most 50000 consecutive rays of each from the middle of the render's stream, so that packets hold neighbouring rays). Wrong: answers (closest hit for primary and diffuse, any hit for shadow and AO) that the exact reference says are false misses, false hits, the wrong triangle or a t beyond its bound; undecidable: double precision could not say. Edge rays: as many rays aimed exactly at the scene's vertices and at points on its edges, from 1e-4 to 0.5 of the scene's size away (`validate --rays edges`), each asked for its closest hit and for any hit; they are timed but kept out of the time per ray in the chart.\n\n{}\nWhat the other libraries lack, and what raylab does instead:\n\n{limits}",
        t.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[LibraryPoint]) -> Result<Vec<String>> {
    let scenes = distinct(points.iter().map(|p| p.scene.as_str()))
        .len()
        .clamp(1, MAX_SCENES) as u32;
    let width = 420 * scenes + SIDE_LEGEND + 60;
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (width, 900),
        draw_libraries,
        points
    )?])
}

/// Scenes drawn side by side (the table has them all).
const MAX_SCENES: usize = 6;

/// Where a count of zero wrong answers is drawn on the log axis.
const ZERO_LINE: f64 = 0.1;

fn draw_libraries<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[LibraryPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let (panels, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND + 60));
    let scenes: Vec<&str> = distinct(pts.iter().map(|p| p.scene.as_str()))
        .into_iter()
        .take(MAX_SCENES)
        .collect();
    let backends = distinct(pts.iter().map(|p| p.backend.as_str()));
    // Each backend in a shade of its family's colour.
    let family_of = |b: &str| {
        pts.iter()
            .find(|p| p.backend == b)
            .map_or(Family::Raylab, |p| p.family)
    };
    let colors: Vec<RGBAColor> = backends
        .iter()
        .map(|b| {
            let f = family_of(b);
            let kin: Vec<&&str> = backends.iter().filter(|o| family_of(o) == f).collect();
            let i = kin.iter().position(|o| **o == *b).unwrap_or(0);
            family_shade(f, i, kin.len())
        })
        .collect();
    let areas = panels.split_evenly((2, scenes.len().max(1)));
    // Top row: the render's rays; bottom row: the edge and vertex rays.
    type WrongOf = fn(&LibraryPoint) -> f64;
    let rows: [(&str, WrongOf); 2] = [
        ("render rays", |p| p.wrong_per_million),
        ("edge rays", |p| p.edge_wrong_per_million),
    ];
    for (row, (label, wrong)) in rows.iter().enumerate() {
        for (col, scene) in scenes.iter().enumerate() {
            let area = &areas[row * scenes.len() + col];
            let here: Vec<&LibraryPoint> = pts
                .iter()
                .filter(|p| p.scene == *scene && p.failed.is_none() && wrong(p).is_finite())
                .collect();
            let y = |p: &LibraryPoint| wrong(p).max(ZERO_LINE);
            let name = std::path::Path::new(scene)
                .file_stem()
                .map_or(scene.to_string(), |s| s.to_string_lossy().into_owned());
            let y_range = log_range(here.iter().map(|p| y(p)).chain([ZERO_LINE, 1e3]));
            let mut chart = ChartBuilder::on(area)
                .caption(format!("{name}: {label}"), (FONT, 17))
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(60)
                .build_cartesian_2d(
                    log_axis(log_range(here.iter().map(|p| p.ns_per_ray.max(1e-3)))),
                    log_axis(y_range),
                )?;
            chart
                .configure_mesh()
                .x_desc("ns per render ray, 1 thread (log)")
                .y_desc(format!("wrong per million, {label} (log; 0 at bottom)"))
                .x_label_formatter(&log_label)
                .y_label_formatter(&|v| {
                    if *v <= ZERO_LINE * 1.01 {
                        "0".to_string()
                    } else {
                        log_label(v)
                    }
                })
                .draw()?;
            for p in &here {
                let ci = backends.iter().position(|b| *b == p.backend).unwrap_or(0);
                let c = colors[ci];
                let at = (p.ns_per_ray.max(1e-3), y(p));
                match p.family {
                    Family::Raylab => {
                        chart.draw_series(std::iter::once(Circle::new(at, 6, c.filled())))?;
                    }
                    Family::Embree => {
                        chart.draw_series(std::iter::once(TriangleMarker::new(
                            at,
                            7,
                            c.filled(),
                        )))?;
                    }
                    _ => {
                        chart.draw_series(std::iter::once(Cross::new(at, 6, c.stroke_width(2))))?;
                    }
                }
            }
        }
    }
    let entries: Vec<(String, RGBAColor)> = backends
        .iter()
        .enumerate()
        .map(|(i, b)| (b.to_string(), colors[i]))
        .collect();
    side_legend(&side, &entries, Swatch::Dot)?;
    root.present()?;
    Ok(())
}
