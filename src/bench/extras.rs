//! The bench's experiments beyond the study's tables, each feeding one chart:
//! thread scaling, cost growth with triangle count, AO error against time,
//! builder quality against time, leak rate against speed, and the validation
//! summary of the report.

use std::time::Instant;

use serde::Serialize;

use super::measure::{Stat, View};
use super::metrics::{psnr, rmse};
use super::variants::Variant;
use crate::accel::bvh::{BuildParams, BuilderKind, BvhBackend};
use crate::accel::{build_backend, Backend, BackendKind, BackendSpec};
use crate::error::Result;
use crate::progress::{Progress, StepBar};
use crate::render::{render, AoMode, Frame, RenderSettings, Schedule};
use crate::scene::Scene;
use crate::table::ms;

/// Renders `reps` times and returns the render times and the last frame.
fn timed_renders(
    scene: &Scene,
    backend: &dyn Backend,
    settings: &RenderSettings,
    schedule: Schedule,
    threads: usize,
    reps: usize,
) -> Result<(Stat, Frame)> {
    let mut times = Vec::with_capacity(reps);
    let mut frame = None;
    for _ in 0..reps.max(1) {
        let start = Instant::now();
        let (f, _) = render(
            scene,
            backend,
            settings,
            schedule,
            threads,
            &Progress::new(),
        )?;
        times.push(ms(start.elapsed()));
        frame = Some(f);
    }
    Ok((Stat::of(&times), frame.expect("at least one render")))
}

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
pub fn scaling_variants() -> Vec<Variant> {
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

/// Render time of each variant on each of `thread_counts`, repetitions
/// interleaved across thread counts. The backend is built once per variant.
pub fn thread_scaling(
    scene: &Scene,
    settings: &RenderSettings,
    thread_counts: &[usize],
    reps: usize,
    bar: &StepBar,
) -> Result<Vec<ScalingPoint>> {
    let mut out = Vec::new();
    let max_threads = thread_counts.iter().copied().max().unwrap_or(1);
    for variant in scaling_variants() {
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
pub fn growth_variants() -> Vec<Variant> {
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

/// Build and render cost of each backend on `mesh:N` scenes; naive only up to
/// `naive_max` triangles (its cost is O(N) per ray).
pub fn cost_growth(
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
        for variant in growth_variants() {
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
                    super::measure::run_once(&scene, &variant, settings, threads)?;
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

/// One point of the AO error chart.
#[derive(Clone, Debug, Serialize)]
pub struct AoErrorPoint {
    pub scene: String,
    /// `paper` or `cosine:N`.
    pub ao: String,
    /// AO rays per shaded pixel: 14 candidate directions for `paper` (those in
    /// the hemisphere are cast), N for `cosine:N`.
    pub samples: u32,
    pub render_ms: Stat,
    /// Against the `cosine` reference, on display values in [0, 1].
    pub rmse: f64,
    pub psnr_db: f64,
}

/// The variant the AO error experiment renders with: Embree when built in.
pub fn fastest_variant() -> Variant {
    let name = if crate::accel::embree::AVAILABLE {
        "embree-tiles"
    } else {
        "bvh-sah-tiles"
    };
    Variant::named(name).expect("a known variant")
}

/// What the AO error experiment renders.
#[derive(Clone, Debug)]
pub struct AoErrorSetup {
    pub view: View,
    pub size: (u32, u32),
    /// The N of each `cosine:N` measured.
    pub samples: Vec<u32>,
    /// The N of the `cosine:N` reference.
    pub reference: u32,
}

/// Error of `paper` and `cosine:N` for each N against a `cosine:reference`
/// render of the same view, seed and light samples (so direct light is the
/// same in every image and only AO differs), with the render time of each.
pub fn ao_error(
    scene: &Scene,
    setup: &AoErrorSetup,
    threads: usize,
    reps: usize,
    bar: &StepBar,
) -> Result<Vec<AoErrorPoint>> {
    let AoErrorSetup {
        view,
        size,
        samples,
        reference,
    } = setup;
    let (size, reference) = (*size, *reference);
    let variant = fastest_variant();
    let backend = build_backend(&variant.spec(threads), scene)?;
    bar.set_message(format!(
        "AO error: cosine:{reference} reference of {}",
        scene.name
    ));
    let settings = |ao| view.settings(size, ao, 1);
    let (_, truth) = timed_renders(
        scene,
        backend.as_ref(),
        &settings(AoMode::Cosine(reference))?,
        variant.schedule,
        threads,
        1,
    )?;
    bar.step();
    let mut modes = vec![AoMode::Paper];
    modes.extend(samples.iter().map(|&n| AoMode::Cosine(n)));
    let mut out = Vec::new();
    for ao in modes {
        bar.set_message(format!("AO error: {ao} on {}", scene.name));
        let (t, frame) = timed_renders(
            scene,
            backend.as_ref(),
            &settings(ao)?,
            variant.schedule,
            threads,
            reps,
        )?;
        bar.step();
        let e = rmse(&frame, &truth)?;
        out.push(AoErrorPoint {
            scene: scene.name.clone(),
            ao: ao.to_string(),
            samples: match ao {
                AoMode::Cosine(n) => n,
                _ => 14,
            },
            render_ms: t,
            rmse: e,
            psnr_db: psnr(e),
        });
    }
    Ok(out)
}

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
    /// The same builder's 8-wide tree (what `--backend bvh` traverses; leaf
    /// tests in pairs): build time as the renderer builds it, SAH cost under
    /// that block model, and memory.
    pub wide8_build_ms: f64,
    pub wide8_sah_cost: f64,
    pub wide8_bytes_per_triangle: f64,
}

/// The builders compared (Embree's only when built in).
pub fn quality_builders() -> Vec<BuilderKind> {
    BuilderKind::ALL
        .into_iter()
        .filter(|b| b.embree_quality().is_none() || crate::accel::embree::AVAILABLE)
        .collect()
}

/// Each builder on `scene`: build time, SAH cost and traversal work per ray (from
/// `raylab stats`), and the render time of its tree.
pub fn builder_quality(
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
        let report = crate::stats::builder_report(scene, &params, settings, threads, reps)?;
        let backend = BvhBackend::new(scene, &params)?;
        let (render_ms, _) =
            timed_renders(scene, &backend, settings, Schedule::Tiles, threads, reps)?;
        bar.step();
        let work = [report.primary, report.shadow, report.ao];
        let rays: u64 = work.iter().map(|w| w.rays).sum();
        let per_ray = |f: fn(&crate::stats::KindWork) -> f64| {
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
            wide8_sah_cost: report.wide8.sah_cost,
            wide8_bytes_per_triangle: report.wide8.bytes_per_triangle,
        });
    }
    Ok(out)
}

/// One scene's validation against the reference backend.
#[derive(Clone, Debug, Serialize)]
pub struct ValidationRow {
    pub scene: String,
    pub tested: String,
    pub reference: String,
    pub rays: usize,
    pub ties: usize,
    pub genuine: usize,
}

/// Every hit of the median and SAH BVHs against Embree (naive without Embree)
/// on the primary, shadow, AO and random ray sets of `settings`, `count` rays each.
pub fn validation(
    scene: &Scene,
    settings: &RenderSettings,
    count: usize,
    threads: usize,
    bar: &StepBar,
) -> Result<Vec<ValidationRow>> {
    use crate::validate::{compare, ray_sets, RaySet};
    let against = if crate::accel::embree::AVAILABLE {
        BackendKind::Embree
    } else {
        BackendKind::Naive
    };
    let reference = build_backend(&BackendSpec::default_for(against, threads), scene)?;
    let triangles = scene.triangle_vertices();
    let sets = ray_sets(
        scene,
        reference.as_ref(),
        settings,
        &RaySet::ALL,
        count,
        false,
    )?;
    let mut out = Vec::new();
    for builder in [BuilderKind::Median, BuilderKind::Sah] {
        bar.set_message(format!(
            "validate: bvh-{} on {}",
            builder.name(),
            scene.name
        ));
        let tested = build_backend(
            &BackendSpec::bvh(BuildParams::for_builder(builder).with_threads(threads)),
            scene,
        )?;
        let mut row = ValidationRow {
            scene: scene.name.clone(),
            tested: tested.name(),
            reference: reference.name(),
            rays: 0,
            ties: 0,
            genuine: 0,
        };
        for (set, rays) in &sets {
            let (r, _) = compare(
                set.name(),
                rays,
                tested.as_ref(),
                reference.as_ref(),
                &triangles,
            );
            row.rays += r.rays;
            row.ties += r.ties;
            row.genuine += r.genuine;
        }
        bar.step();
        out.push(row);
    }
    Ok(out)
}
