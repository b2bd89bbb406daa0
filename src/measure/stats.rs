//! `raylab stats`: per scene and builder, build times (serial and parallel), the
//! tree's shape and SAH cost, and the traversal work measured over an actual
//! render through the shared shading loop.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::accel::bvh::quality::TreeStats;
use crate::accel::bvh::traverse::{Counts, Traversal};
use crate::accel::bvh::wide::{TraversalCosts, WideBvh};
use crate::accel::bvh::{build, params, BuildParams, Bvh, Tree};
use crate::error::Result;
use crate::geometry::{Hit, Ray};
use crate::progress::Progress;
use crate::render::{render, RenderSettings, Schedule, Tracer};
use crate::scene::Scene;
use crate::table::ms;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// One builder on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct BuilderReport {
    pub scene: String,
    pub triangles: usize,
    pub builder: String,
    pub max_leaf_size_param: usize,
    /// Median of the timed builds on one thread.
    pub build_ms_serial: f64,
    /// Median of the timed builds on `build_threads` threads.
    pub build_ms_parallel: f64,
    pub build_threads: usize,
    /// Whether the serial and parallel builds produced the same tree.
    pub deterministic: bool,
    #[serde(flatten)]
    pub tree: TreeStats,
    pub sah_constants: SahConstants,
    /// The measured unit costs of the wide trees' SAH cost.
    pub traversal_costs: TraversalCosts,
    /// Traversal work per ray kind over the render described by `settings`.
    pub primary: KindWork,
    pub shadow: KindWork,
    pub ao: KindWork,
    /// The trees `--bvh-width 4` and `--bvh-width 8` traverse: the same
    /// builder with leaf tests counted in pairs, built directly wide (Embree's
    /// builders: collapsed from their binary tree).
    pub wide4: WideReport,
    pub wide8: WideReport,
}

/// A wide tree: size, its SAH cost as traversed, and traversal work over the
/// same render.
#[derive(Clone, Debug, Serialize)]
pub struct WideReport {
    pub width: usize,
    /// Median build time on `build_threads` threads, as the renderer builds it.
    pub build_ms: f64,
    /// The SAH cost of the wide tree as its traversal walks it: expected
    /// nanoseconds per ray in node visits and leaf block tests, at the
    /// report's measured [`TraversalCosts`] (`WideBvh::sah_cost`).
    pub sah_ns_per_ray: f64,
    /// Triangle references per leaf lane.
    pub mean_leaf_size: f64,
    pub nodes: usize,
    /// Blocks of four leaf triangles, and the share of their lanes in use.
    pub blocks: usize,
    pub block_fill: f64,
    pub memory_bytes: usize,
    pub bytes_per_triangle: f64,
    pub primary: KindWork,
    pub shadow: KindWork,
    pub ao: KindWork,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct SahConstants {
    pub traversal: f32,
    pub intersect: f32,
    pub normalised_by: &'static str,
}

const SAH_CONSTANTS: SahConstants = SahConstants {
    traversal: params::C_TRAVERSAL,
    intersect: params::C_INTERSECT,
    normalised_by: "root surface area",
};

/// Builds `reps` times as the renderer builds ([`build`] over the scene) and
/// returns the median time and the last tree.
fn timed_build(scene: &Scene, params: &BuildParams, reps: usize) -> Result<(Duration, Tree)> {
    let mut times = Vec::with_capacity(reps);
    let mut tree = None;
    for _ in 0..reps.max(1) {
        let start = Instant::now();
        tree = Some(build(&scene.mesh(), params)?);
        times.push(start.elapsed());
    }
    times.sort();
    Ok((times[times.len() / 2], tree.expect("at least one build")))
}

/// The binary tree of a [`timed_build`] of width 2.
fn binary(tree: Tree) -> Bvh {
    tree.into_binary().expect("a build of width 2 is binary")
}

/// Measures one builder on `scene`: `reps` timed builds serially and on
/// `threads` threads, then a counting render with `settings` on `threads` threads.
pub fn builder_report(
    scene: &Scene,
    params: &BuildParams,
    settings: &RenderSettings,
    threads: usize,
    reps: usize,
) -> Result<BuilderReport> {
    let params = params.with_width(2);
    let (serial_time, serial) = timed_build(scene, &params.with_threads(1), reps)?;
    let (parallel_time, parallel) = timed_build(scene, &params.with_threads(threads), reps)?;
    let (serial, parallel) = (binary(serial), binary(parallel));
    let deterministic = serial.nodes == parallel.nodes && serial.tri_ids == parallel.tri_ids;
    let (primary, shadow, ao) = counted_work(scene, &parallel, settings, threads)?;
    let costs = TraversalCosts::of_default_path();
    let wide4 = wide_report(scene, &params, 4, &costs, settings, threads, reps)?;
    let wide8 = wide_report(scene, &params, 8, &costs, settings, threads, reps)?;
    Ok(BuilderReport {
        scene: scene.name.clone(),
        triangles: scene.triangle_count(),
        builder: format!(
            "{}{}",
            params.builder.name(),
            if params.optimize { "-opt" } else { "" }
        ),
        max_leaf_size_param: params.max_leaf_size,
        build_ms_serial: ms(serial_time),
        build_ms_parallel: ms(parallel_time),
        build_threads: threads,
        deterministic,
        tree: TreeStats::with_block(&parallel, scene.triangle_count(), params.sah_block),
        sah_constants: SAH_CONSTANTS,
        traversal_costs: costs,
        primary,
        shadow,
        ao,
        wide4,
        wide8,
    })
}

/// Traversal work of `tree` per ray kind (primary, shadow, AO) over a render
/// of `scene` with `settings` through the shared shading loop.
fn counted_work<B: Traversal + Sync>(
    scene: &Scene,
    tree: &B,
    settings: &RenderSettings,
    threads: usize,
) -> Result<(KindWork, KindWork, KindWork)> {
    let tracer = CountingTracer::new(tree);
    render(
        scene,
        &tracer,
        settings,
        Schedule::Rayon,
        threads,
        &Progress::new(),
    )?;
    Ok(tracer.work())
}

/// Builds the tree `--bvh-width width` traverses, timed as the renderer
/// builds it, costs it as traversed at `costs`, and counts its traversal work
/// over a render.
#[allow(clippy::too_many_arguments)]
fn wide_report(
    scene: &Scene,
    params: &BuildParams,
    width: usize,
    costs: &TraversalCosts,
    settings: &RenderSettings,
    threads: usize,
    reps: usize,
) -> Result<WideReport> {
    let params = params.with_width(width).with_threads(threads);
    let (time, wide) = timed_build(scene, &params, reps)?;
    let (nodes, blocks, triangles, leaves, sah_ns_per_ray) = match &wide {
        Tree::Wide4(t) => wide_shape(t, costs),
        Tree::Wide8(t) => wide_shape(t, costs),
        Tree::Binary(_) => unreachable!("a build of width 4 or 8 is wide"),
    };
    let (primary, shadow, ao) = counted_work(scene, &wide, settings, threads)?;
    let lanes = blocks * crate::accel::bvh::leaf::LANES;
    let memory = wide.memory_bytes();
    Ok(WideReport {
        width,
        build_ms: ms(time),
        sah_ns_per_ray,
        mean_leaf_size: triangles as f64 / leaves.max(1) as f64,
        nodes,
        blocks,
        block_fill: triangles as f64 / lanes.max(1) as f64,
        memory_bytes: memory,
        bytes_per_triangle: memory as f64 / scene.triangle_count().max(1) as f64,
        primary,
        shadow,
        ao,
    })
}

/// Nodes, blocks, leaf references, leaf lanes and the SAH cost at `costs`.
fn wide_shape<const N: usize>(
    t: &WideBvh<N>,
    costs: &TraversalCosts,
) -> (usize, usize, usize, usize, f64) {
    let leaves = t
        .nodes
        .iter()
        .map(|n| (0..N).filter(|&lane| n.is_leaf(lane)).count())
        .sum();
    (
        t.nodes.len(),
        t.blocks.len(),
        t.triangle_count(),
        leaves,
        t.sah_cost(costs),
    )
}

/// The reports as a Markdown table, one row per (scene, builder).
pub fn markdown_table(reports: &[BuilderReport]) -> String {
    let columns = [
        ("scene", Left),
        ("tris", Right),
        ("builder", Left),
        ("build ms 1 thr", Right),
        ("build ms N thr", Right),
        ("nodes", Right),
        ("leaves", Right),
        ("depth max/mean", Left),
        ("leaf mean/max", Left),
        ("bytes/tri", Right),
        ("SAH cost", Right),
        ("nodes/ray P/S/AO", Left),
        ("tris/ray P/S/AO", Left),
        ("4-wide nodes", Right),
        ("4-wide bytes/tri", Right),
        ("4-wide nodes/ray P/S/AO", Left),
        ("8-wide nodes", Right),
        ("8-wide bytes/tri", Right),
        ("8-wide nodes/ray P/S/AO", Left),
        ("block fill", Right),
        ("8-wide SAH ns/ray", Right),
    ];
    let mut table = Table::new(columns);
    // One figure per ray kind, "primary/shadow/AO".
    let per_kind = |kinds: [&KindWork; 3], figure: fn(&KindWork) -> f64| {
        let [p, s, a] = kinds.map(figure);
        format!("{p:.1}/{s:.1}/{a:.1}")
    };
    let nodes = |w: &KindWork| w.nodes_per_ray;
    for r in reports {
        let t = &r.tree;
        table.row([
            r.scene.clone(),
            r.triangles.to_string(),
            r.builder.clone(),
            format!("{:.2}", r.build_ms_serial),
            format!("{:.2} ({})", r.build_ms_parallel, r.build_threads),
            t.nodes.to_string(),
            t.leaves.to_string(),
            format!("{}/{:.1}", t.max_depth, t.mean_leaf_depth),
            format!("{:.2}/{}", t.mean_leaf_size, t.max_leaf_size),
            format!("{:.1}", t.bytes_per_triangle),
            format!("{:.2}", t.sah_cost),
            per_kind([&r.primary, &r.shadow, &r.ao], nodes),
            per_kind([&r.primary, &r.shadow, &r.ao], |w| w.triangles_per_ray),
            r.wide4.nodes.to_string(),
            format!("{:.1}", r.wide4.bytes_per_triangle),
            per_kind([&r.wide4.primary, &r.wide4.shadow, &r.wide4.ao], nodes),
            r.wide8.nodes.to_string(),
            format!("{:.1}", r.wide8.bytes_per_triangle),
            per_kind([&r.wide8.primary, &r.wide8.shadow, &r.wide8.ao], nodes),
            format!("{:.0}%", r.wide8.block_fill * 100.0),
            format!("{:.1}", r.wide8.sah_ns_per_ray),
        ]);
    }
    let mut out = table.markdown();
    out.push_str(&format!(
        "\nSAH cost: C_traversal = {}, C_intersect = {}, normalised by the {}. Work per ray measured over the render's primary (P), shadow (S) and AO rays.\n",
        SAH_CONSTANTS.traversal, SAH_CONSTANTS.intersect, SAH_CONSTANTS.normalised_by
    ));
    if let Some(r) = reports.first() {
        out.push_str(&format!(
            "8-wide SAH ns/ray: the SAH cost of the 8-wide tree as traversed, expected ns per ray in node visits and block tests at the measured {} (docs/design.md, \"The SAH cost of a wide tree\").\n",
            r.traversal_costs.describe()
        ));
    }
    out
}

/// Traversal work by ray kind, summed over a render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct KindWork {
    pub rays: u64,
    pub nodes_per_ray: f64,
    pub triangles_per_ray: f64,
}

#[derive(Default)]
struct AtomicWork {
    rays: AtomicU64,
    nodes: AtomicU64,
    triangles: AtomicU64,
}

impl AtomicWork {
    fn add(&self, c: Counts) {
        self.rays.fetch_add(1, Ordering::Relaxed);
        self.nodes.fetch_add(c.nodes, Ordering::Relaxed);
        self.triangles.fetch_add(c.triangles, Ordering::Relaxed);
    }

    fn get(&self) -> KindWork {
        let rays = self.rays.load(Ordering::Relaxed);
        let per = |x: &AtomicU64| x.load(Ordering::Relaxed) as f64 / rays.max(1) as f64;
        KindWork {
            rays,
            nodes_per_ray: per(&self.nodes),
            triangles_per_ray: per(&self.triangles),
        }
    }
}

/// A tracer that counts nodes visited and triangles tested per ray kind while
/// rendering through the same shading loop, over a binary or a 4-wide tree.
pub struct CountingTracer<'a, B: Traversal = Bvh> {
    bvh: &'a B,
    primary: AtomicWork,
    shadow: AtomicWork,
    ao: AtomicWork,
}

impl<'a, B: Traversal> CountingTracer<'a, B> {
    pub fn new(bvh: &'a B) -> Self {
        CountingTracer {
            bvh,
            primary: AtomicWork::default(),
            shadow: AtomicWork::default(),
            ao: AtomicWork::default(),
        }
    }

    /// (primary, shadow, ao) work so far.
    pub fn work(&self) -> (KindWork, KindWork, KindWork) {
        (self.primary.get(), self.shadow.get(), self.ao.get())
    }
}

impl<B: Traversal + Sync> Tracer for CountingTracer<'_, B> {
    fn primary(&self, ray: &Ray) -> Option<Hit> {
        let mut c = Counts::default();
        let hit = self.bvh.intersect_counted(ray, &mut c);
        self.primary.add(c);
        hit
    }

    fn shadow(&self, ray: &Ray) -> bool {
        let mut c = Counts::default();
        let hit = self.bvh.occluded_counted(ray, &mut c);
        self.shadow.add(c);
        hit
    }

    fn ao(&self, ray: &Ray) -> bool {
        let mut c = Counts::default();
        let hit = self.bvh.occluded_counted(ray, &mut c);
        self.ao.add(c);
        hit
    }
}
