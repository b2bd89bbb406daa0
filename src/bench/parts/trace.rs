//! Query throughput without shading: the rays one render casts (primary,
//! shadow and AO, in the order its streams ask them) and one diffuse bounce
//! per primary hit (incoherent), recorded once per scene, traced by every
//! backend on every query path it has (single rays, packets, streams) on each
//! thread count, repetitions interleaved across backends so that a noisy
//! machine slows them alike. Every path is asked in streams of [`CHUNK`](crate::bench::timing::CHUNK) rays.
//!
//! A speed figure is only quoted for right answers (tinybvh's habit): before
//! timing, every backend answers every ray once; raylab's own backends must
//! give the reference's answers bit for bit (the bench fails otherwise), and
//! Embree's and the other libraries' differing answers (another triangle, or
//! a hit against a miss) are counted and reported: ties on shared edges, and
//! the libraries' own misses, which `raylab validate` classifies.

use std::path::Path;

use serde::Serialize;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::bench::charts::{
    best_per_family, draw_bars, log_label, log_range, save_chart, short, Bars, DrawResult,
};

use super::ChartSection;
use crate::accel::{build_backend, BackendKind, BackendSpec, Built};
use crate::bench::config::BenchConfig;
use crate::bench::family::Family;
use crate::bench::measure::Stat;
use crate::bench::timing::{answers, digest, min_run_s, passes_for, trace, Answer};
use crate::error::{Error, Result};
use crate::measure::validate::{recorded_rays, RaySet};
use crate::progress::StepBar;
use crate::render::AoMode;
use crate::render::RenderSettings;
use crate::scene::Scene;
use crate::table::ms;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Query throughput",
    stem: "trace-",
    caption: "Rays traced per second per scene and ray kind, on one thread count per chart (log scale; the same recorded rays for every backend, no shading): the fastest backend and query path of each family (raylab, Embree, each library); the table below has every one.",
};

/// The thread counts measured: one, and all bench threads.
pub(crate) fn thread_counts(cfg: &BenchConfig) -> Vec<usize> {
    if cfg.threads > 1 {
        vec![1, cfg.threads]
    } else {
        vec![1]
    }
}

/// Progress steps: one per scene and ray kind (none without a backend to trace).
pub fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    if trace_specs(&cfg.variants, cfg.threads).is_empty() {
        0
    } else {
        KINDS.len() as u64 * scenes.len() as u64
    }
}

/// Timed runs per backend, ray kind and thread count.
pub(crate) fn trace_reps(cfg: &BenchConfig) -> usize {
    if cfg.quick {
        1
    } else {
        cfg.reps.clamp(1, 5)
    }
}

/// The ray kinds measured.
pub(crate) const KINDS: [RaySet; 4] =
    [RaySet::Primary, RaySet::Shadow, RaySet::Ao, RaySet::Diffuse];

/// Throughput of every backend of the bench's variants on each of `scenes`
/// (the rays of one render from its first view, paper AO).
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<TracePoint>> {
    let specs = trace_specs(&cfg.variants, cfg.threads);
    let reps = trace_reps(cfg);
    let mut out = Vec::new();
    if specs.is_empty() {
        return Ok(out);
    }
    for scene in scenes {
        let settings = cfg
            .first_view(scene, cfg.size)
            .settings(cfg.size, AoMode::Paper, 1)?;
        out.extend(trace_throughput(
            scene,
            &settings,
            &specs,
            &thread_counts(cfg),
            reps,
            min_run_s(cfg),
            bar,
        )?);
    }
    Ok(out)
}

/// One backend's throughput on one ray kind and thread count.
#[derive(Clone, Debug, Serialize)]
pub struct TracePoint {
    pub scene: String,
    pub triangles: usize,
    /// The backend with its query path ([`BackendSpec::name`]).
    pub backend: String,
    /// What was built ([`BackendSpec::structure_name`]): the query paths of
    /// one structure share its build.
    pub structure: String,
    /// The query path: `single`, `packet8`, `stream`.
    pub query: String,
    /// Whose it is: raylab's own, Embree (the reference the own backends'
    /// times are divided by), or another library.
    pub family: Family,
    /// `primary` or `diffuse` (closest hit), `shadow` or `ao` (any hit).
    pub kind: RaySet,
    pub threads: usize,
    pub rays: usize,
    /// Millions of rays per second of wall time, over the measured runs.
    pub mrays: Stat,
    /// Answers that differ from the reference backend's (0 for raylab's own
    /// backends, or the bench fails).
    pub differing: usize,
    /// Build time of the backend on `threads` threads: the median (ms) of
    /// `reps` builds after a warm-up, interleaved with the other backends'
    /// (NaN when not measured).
    pub build_ms: f64,
    /// Bytes of its acceleration structure ([`Backend::memory_bytes`]).
    pub memory_bytes: Option<usize>,
}

/// The backends of the trace part for the bench's variants: each distinct
/// structure once (schedules and query paths do not matter here), the naive
/// scan left out.
pub fn trace_specs(
    variants: &[crate::bench::variants::Variant],
    threads: usize,
) -> Vec<BackendSpec> {
    let mut specs: Vec<BackendSpec> = Vec::new();
    for v in variants.iter().filter(|v| v.kind != BackendKind::Naive) {
        // One per structure: the trace traces each on all its query paths.
        let spec = v.spec(threads).with_build_threads(threads);
        let spec = spec.with_query(crate::accel::Query::Single).unwrap_or(spec);
        if !specs.contains(&spec) {
            specs.push(spec);
        }
    }
    specs
}

/// Measures every backend of `specs` on the rays of one render of `scene`
/// with `settings`, on each of `thread_counts`, `reps` times, each timed
/// run at least `min_run` seconds long (see [`MIN_RUN_S`](crate::bench::timing::MIN_RUN_S)). The first own
/// (non-Embree) backend is the reference every other is checked against.
///
/// Builds are measured too: on each thread count, a warm-up build and `reps`
/// timed ones per backend, backends interleaved build by build (so a noisy
/// spell of the machine falls on all of them), each build as the backend
/// is timed by [`build_backend`]. The rays are traced by the last
/// build on the largest thread count.
pub fn trace_throughput(
    scene: &Scene,
    settings: &RenderSettings,
    specs: &[BackendSpec],
    thread_counts: &[usize],
    reps: usize,
    min_run: f64,
    bar: &StepBar,
) -> Result<Vec<TracePoint>> {
    let mut kept: Vec<Option<Built>> = specs.iter().map(|_| None).collect();
    let mut builds = vec![vec![Vec::new(); thread_counts.len()]; specs.len()];
    let largest = (0..thread_counts.len()).max_by_key(|&i| thread_counts[i]);
    for (ti, &threads) in thread_counts.iter().enumerate() {
        for run in 0..=reps.max(1) {
            bar.set_message(format!(
                "trace: builds of {} on {threads} thread(s), run {run}/{}",
                scene.name,
                reps.max(1)
            ));
            for (si, spec) in specs.iter().enumerate() {
                let b = build_backend(&spec.with_build_threads(threads), scene)?;
                b.check_build_threads()?;
                if run > 0 {
                    builds[si][ti].push(ms(b.build_time));
                }
                if Some(ti) == largest {
                    kept[si] = Some(b);
                }
            }
        }
    }
    let mut backends: Vec<(Built, Vec<f64>)> = Vec::new();
    for (built, runs) in kept.into_iter().zip(builds) {
        let Some(built) = built else { continue };
        let build_ms: Vec<f64> = runs.iter().map(|r| Stat::of(r).median).collect();
        // Every other query path of the same structure, built once more
        // (untimed: the same build) to be traced beside it.
        let spec = built.spec;
        backends.push((built, build_ms.clone()));
        for query in spec.queries() {
            if query != spec.query() {
                bar.set_message(format!(
                    "trace: {} on {}",
                    spec.with_query(query)?.name(),
                    scene.name
                ));
                backends.push((
                    build_backend(&spec.with_query(query)?, scene)?,
                    build_ms.clone(),
                ));
            }
        }
    }
    trace_backends(
        scene,
        settings,
        &backends,
        thread_counts,
        reps,
        min_run,
        bar,
    )
}

/// [`trace_throughput`] over backends already built, each with its median
/// build time in ms on each of `thread_counts` (empty: not measured).
pub fn trace_backends(
    scene: &Scene,
    settings: &RenderSettings,
    backends: &[(Built, Vec<f64>)],
    thread_counts: &[usize],
    reps: usize,
    min_run: f64,
    bar: &StepBar,
) -> Result<Vec<TracePoint>> {
    if backends.is_empty() {
        return Ok(Vec::new());
    }
    let reference = backends
        .iter()
        .position(|(b, _)| b.spec.is_own())
        .unwrap_or(0);
    bar.set_message(format!("trace: recording the rays of {}", scene.name));
    let recorded = recorded_rays(scene, backends[reference].0.as_ref(), settings)?;
    let diffuse = recorded.diffuse(scene, settings.seed);
    let sets = KINDS.map(|kind| {
        let rays = match kind {
            RaySet::Primary => &recorded.primary,
            RaySet::Shadow => &recorded.shadow,
            RaySet::Ao => &recorded.ao,
            _ => &diffuse,
        };
        (kind, rays)
    });
    let mut out = Vec::new();
    let mut got = Vec::new();
    for (kind, rays) in sets {
        if rays.is_empty() {
            continue;
        }
        let closest = kind.closest();
        // Answers first: a speed is only reported for right answers.
        let mut want = Vec::new();
        answers(backends[reference].0.as_ref(), closest, rays, &mut want);
        let mut differing = Vec::with_capacity(backends.len());
        for (b, _) in backends {
            // Embree and the other libraries compute t with their own
            // arithmetic: only the triangle hit is comparable.
            let exact = b.spec.is_own();
            let same = |a: Answer, w: Answer| match (a, w) {
                (Answer::Closest(a), Answer::Closest(w)) if !exact => {
                    a.map(|h| h.0) == w.map(|h| h.0)
                }
                _ => a == w,
            };
            answers(b.as_ref(), closest, rays, &mut got);
            let n = got
                .iter()
                .zip(&want)
                .filter(|(a, w)| !same(**a, **w))
                .count();
            if n > 0 && exact {
                return Err(Error::Other(format!(
                    "trace: {} differs from {} on {n} of {} {} rays of {}",
                    b.name(),
                    backends[reference].0.name(),
                    rays.len(),
                    kind.name(),
                    scene.name
                )));
            }
            differing.push(n);
        }
        let expected: u64 = want.iter().map(|&a| digest(a)).fold(0, u64::wrapping_add);
        let mut rates = vec![vec![Vec::new(); thread_counts.len()]; backends.len()];
        // Passes per run of each backend and thread count, set by the warm-up.
        let mut passes = vec![vec![1usize; thread_counts.len()]; backends.len()];
        for rep in 0..reps.max(1) + 1 {
            bar.set_message(format!(
                "trace: {} rays of {}, run {}/{}",
                kind.name(),
                scene.name,
                rep,
                reps.max(1)
            ));
            for (ti, &threads) in thread_counts.iter().enumerate() {
                for (bi, (b, _)) in backends.iter().enumerate() {
                    let n = passes[bi][ti];
                    let (seconds, sum) = trace(b.as_ref(), closest, rays, threads, n);
                    if differing[bi] == 0 && sum != expected {
                        return Err(Error::Other(format!(
                            "trace: {} answered differently on {threads} threads",
                            b.name()
                        )));
                    }
                    // Run 0 warms caches and the branch predictors, and
                    // sets how many passes the timed runs make.
                    if rep > 0 {
                        rates[bi][ti].push((rays.len() * n) as f64 / seconds.max(1e-12) / 1e6);
                    } else {
                        passes[bi][ti] = passes_for(seconds, min_run);
                    }
                }
            }
        }
        bar.step();
        for (bi, (b, build_ms)) in backends.iter().enumerate() {
            for (ti, &threads) in thread_counts.iter().enumerate() {
                let build_ms = build_ms.get(ti).copied().unwrap_or(f64::NAN);
                out.push(TracePoint {
                    scene: scene.name.clone(),
                    triangles: scene.triangle_count(),
                    backend: b.name(),
                    structure: b.spec.structure_name(),
                    query: b.spec.query().name(),
                    family: Family::of(&b.spec),
                    kind,
                    threads,
                    rays: rays.len(),
                    mrays: Stat::of(&rates[bi][ti]),
                    differing: differing[bi],
                    build_ms,
                    memory_bytes: b.memory_bytes(),
                });
            }
        }
    }
    Ok(out)
}

/// The build table: per scene and backend, the median build time on each
/// thread count, the own backends' time over Embree's on the same count (at
/// most 1: as fast as Embree or faster), and bytes per triangle.
fn build_markdown(points: &[TracePoint]) -> String {
    let mut counts: Vec<usize> = points.iter().map(|p| p.threads).collect();
    counts.sort_unstable();
    counts.dedup();
    let has_embree = points.iter().any(|p| p.family == Family::Embree);
    let mut table = Table::new([("scene", Left), ("backend", Left)]);
    for t in &counts {
        table.column(format!("build ms, {t} thr"), Right);
        if has_embree {
            table.column(format!("/Embree, {t} thr"), Right);
        }
    }
    table.column("bytes/triangle", Right);
    // One row per structure: its query paths share the build.
    let mut seen: Vec<(&str, &str)> = Vec::new();
    for p in points {
        if seen.contains(&(p.scene.as_str(), p.structure.as_str())) {
            continue;
        }
        seen.push((&p.scene, &p.structure));
        let mut row = vec![p.scene.clone(), p.structure.clone()];
        for &t in &counts {
            let build = |which: &dyn Fn(&TracePoint) -> bool| {
                points
                    .iter()
                    .find(|q| q.scene == p.scene && q.threads == t && which(q))
                    .map(|q| q.build_ms)
            };
            let own = build(&|q| q.structure == p.structure);
            row.push(match own {
                Some(ms) if ms.is_finite() => crate::table::fmt_ms(ms),
                _ => "-".to_string(),
            });
            if has_embree {
                let embree = build(&|q| q.family == Family::Embree);
                row.push(match (own, embree) {
                    (Some(o), Some(e))
                        if p.family != Family::Embree && o.is_finite() && e > 0.0 =>
                    {
                        format!("{:.2}", o / e)
                    }
                    _ => String::new(),
                });
            }
        }
        row.push(p.memory_bytes.map_or("-".to_string(), |b| {
            format!("{:.1}", b as f64 / p.triangles.max(1) as f64)
        }));
        table.row(row);
    }
    format!(
        "\nBuild time (median ms of the timed builds, backends interleaved) and memory of each backend:\n\n{}",
        table.markdown()
    )
}

/// The trace table: one row per scene, ray kind and thread count, Mrays/s per
/// backend and query path, and the best own path's time over the best Embree
/// path's and over the best other library's (at most 1 means as fast as that
/// reference at its best, or faster).
pub fn markdown(points: &[TracePoint]) -> String {
    let mut backends: Vec<&str> = Vec::new();
    for p in points {
        if !backends.contains(&p.backend.as_str()) {
            backends.push(&p.backend);
        }
    }
    let has_embree = points.iter().any(|p| p.family == Family::Embree);
    let mut table = Table::new([
        ("scene", Left),
        ("triangles", Right),
        ("rays", Left),
        ("threads", Right),
    ]);
    for b in &backends {
        table.column(*b, Right);
    }
    let has_library = points.iter().any(|p| p.family.is_library());
    if has_embree || has_library {
        table.column("best own", Right);
    }
    if has_embree {
        table.column("best Embree", Right);
        table.column("own/Embree time", Right);
    }
    if has_library {
        table.column("best library", Right);
        table.column("own/library time", Right);
    }
    let mut rows: Vec<(&str, RaySet, usize)> = Vec::new();
    for p in points {
        let key = (p.scene.as_str(), p.kind, p.threads);
        if !rows.contains(&key) {
            rows.push(key);
        }
    }
    for (scene, kind, threads) in rows {
        let cell: Vec<&TracePoint> = points
            .iter()
            .filter(|p| p.scene == scene && p.kind == kind && p.threads == threads)
            .collect();
        let first = cell[0];
        let mut row = vec![
            scene.to_string(),
            first.triangles.to_string(),
            format!("{} ({})", kind.name(), first.rays),
            threads.to_string(),
        ];
        for b in &backends {
            row.push(match cell.iter().find(|p| p.backend == *b) {
                Some(p) if p.differing > 0 => {
                    format!("{:.2} ({} differ)", p.mrays.median, p.differing)
                }
                Some(p) => format!("{:.2}", p.mrays.median),
                None => String::new(),
            });
        }
        let fastest = |which: &dyn Fn(&TracePoint) -> bool| {
            cell.iter()
                .copied()
                .filter(|p| which(p))
                .max_by(|a, b| a.mrays.median.total_cmp(&b.mrays.median))
        };
        let own = fastest(&|p| p.family == Family::Raylab);
        if has_embree || has_library {
            row.push(own.map_or(String::new(), |o| o.backend.clone()));
        }
        // The best of each reference and the best own path's time over its.
        for (has, which) in [
            (
                has_embree,
                &(|p: &TracePoint| p.family == Family::Embree) as &dyn Fn(&TracePoint) -> bool,
            ),
            (has_library, &|p: &TracePoint| p.family.is_library()),
        ] {
            if !has {
                continue;
            }
            match (own, fastest(which)) {
                (Some(o), Some(r)) => {
                    row.push(r.backend.clone());
                    row.push(format!("{:.2}", r.mrays.median / o.mrays.median.max(1e-12)));
                }
                _ => row.extend([String::new(), String::new()]),
            }
        }
        table.row(row);
    }
    format!(
        "### Trace throughput (no shading; the same recorded rays for every backend; median Mrays/s of wall time)\n\n{}{}\n",
        table.markdown(),
        build_markdown(points)
    )
}

/// The part's charts: one per thread count.
pub fn charts(dir: &Path, points: &[TracePoint]) -> Result<Vec<String>> {
    // Each thread count once: the points alternate between them (per
    // backend), and `dedup` alone drew each chart 528 times over.
    let mut counts: Vec<usize> = points.iter().map(|p| p.threads).collect();
    counts.sort_unstable();
    counts.dedup();
    counts
        .into_iter()
        .map(|threads| {
            let data = TraceData { points, threads };
            let name = format!("{}{threads}t", SECTION.stem);
            save_chart!(dir, &name, (1390, 560), draw_trace, &data)
        })
        .collect()
}

/// Query throughput per scene and ray kind on one thread count, one bar per
/// backend (log scale), so each of raylab's trees stands beside Embree.
struct TraceData<'a> {
    points: &'a [TracePoint],
    threads: usize,
}

fn draw_trace<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, d: &TraceData) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let here: Vec<&TracePoint> = d.points.iter().filter(|p| p.threads == d.threads).collect();
    let mut groups: Vec<(String, RaySet)> = Vec::new();
    for p in &here {
        if !groups.iter().any(|(s, k)| *s == p.scene && *k == p.kind) {
            groups.push((p.scene.clone(), p.kind));
        }
    }
    // The fastest backend and path of each family per cell (the table has each).
    let series = best_per_family(
        &here,
        groups.len(),
        |p| p.family,
        |p| p.backend.as_str(),
        |p, g| {
            let (scene, kind) = &groups[g];
            (p.scene == *scene && p.kind == *kind).then_some(p.mrays.median)
        },
        "paths",
    );
    draw_bars(
        root,
        &Bars {
            caption: format!(
                "Query throughput without shading, {} thread{} (median Mrays/s)",
                d.threads,
                if d.threads == 1 { "" } else { "s" }
            ),
            y_desc: "Mrays/s (log)",
            groups: groups
                .iter()
                .map(|(scene, kind)| (short(scene), kind.name().to_string()))
                .collect(),
            series,
            y: log_range(here.iter().map(|p| p.mrays.median)),
            y_label: &log_label,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::{BuildParams, BvhBackend};
    use crate::accel::Backend;
    use crate::bench::measure::View;
    use crate::geometry::Hit;
    use crate::geometry::Ray;
    use crate::render::AoMode;

    /// The SAH tree, but every 50th closest hit reports another triangle.
    struct Planted(BvhBackend);

    impl Backend for Planted {
        fn intersect(&self, ray: &Ray) -> Option<Hit> {
            let hit = self.0.intersect(ray)?;
            let wrong = ray
                .dir
                .x
                .to_bits()
                .is_multiple_of(50)
                .then_some(hit.tri + 1);
            Some(Hit {
                tri: wrong.unwrap_or(hit.tri),
                inst: 0,
                ..hit
            })
        }
        fn occluded(&self, ray: &Ray) -> bool {
            self.0.occluded(ray)
        }
    }

    fn setup() -> (Scene, RenderSettings) {
        let scene = crate::scene::builtin::builtin("cornell-sphere").unwrap();
        let settings = View::PAPER[0].settings((48, 36), AoMode::Paper, 1).unwrap();
        (scene, settings)
    }

    #[test]
    fn own_backends_agree_and_every_kind_and_thread_count_is_measured() {
        let (scene, settings) = setup();
        let specs: Vec<BackendSpec> = [2, 4, 8]
            .map(|w| BackendSpec::bvh(BuildParams::sah().with_width(w)))
            .to_vec();
        let bar = StepBar::new(0, true);
        let points = trace_throughput(&scene, &settings, &specs, &[1, 2], 1, 0.0, &bar).unwrap();
        // The binary and 4-wide trees on single rays, the 8-wide tree on its
        // three query paths, every ray kind, two thread counts.
        assert_eq!(points.len(), 5 * KINDS.len() * 2);
        for q in ["packet8", "packet16"] {
            assert!(points.iter().any(|p| p.backend == format!("bvh8-sah-{q}")
                && p.structure == "bvh8-sah"
                && p.query == q));
        }
        for p in &points {
            assert_eq!(p.differing, 0, "{p:?}");
            assert!(p.mrays.median > 0.0 && p.rays > 0, "{p:?}");
        }
        let md = markdown(&points);
        assert!(md.contains("| cornell-sphere | 2188 | ao ("), "{md}");
        assert!(md.contains("| cornell-sphere | 2188 | diffuse ("), "{md}");
        assert!(md.contains("| cornell-sphere | bvh8-sah |"), "{md}");
        assert!(points.iter().all(|p| p.memory_bytes.is_some_and(|b| b > 0)));
        // Every backend's builds were timed on each thread count.
        assert!(
            points
                .iter()
                .all(|p| p.build_ms.is_finite() && p.build_ms > 0.0),
            "{points:?}"
        );
        assert!(
            md.contains("| build ms, 1 thr | build ms, 2 thr | bytes/triangle |"),
            "{md}"
        );
        assert!(
            !md.contains("own/Embree"),
            "no Embree column without Embree: {md}"
        );
    }

    #[test]
    fn a_wrong_own_backend_fails_the_trace() {
        let (scene, settings) = setup();
        let right = build_backend(&BackendSpec::bvh(BuildParams::sah()), &scene).unwrap();
        // The planted fault in the 4-wide tree, named as such.
        let wide = BuildParams::sah().with_width(4);
        let planted = Built {
            spec: BackendSpec::bvh(wide),
            backend: Box::new(Planted(BvhBackend::new(&scene.mesh(), &wide).unwrap())),
            build_time: std::time::Duration::ZERO,
            build_threads: 1,
        };
        let backends = vec![(right, Vec::new()), (planted, Vec::new())];
        let bar = StepBar::new(0, true);
        let err = trace_backends(&scene, &settings, &backends, &[1], 1, 0.0, &bar)
            .unwrap_err()
            .to_string();
        assert!(err.contains("bvh4-sah differs from bvh-sah"), "{err}");
    }
}
