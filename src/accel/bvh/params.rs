//! Every tunable of raylab's BVHs in one place: the builders a user can pick
//! and their parameters ([`BuildParams`], with `const fn` presets), and the
//! constants the builders, the wide layout and the traversals share. Each
//! value was chosen by measurement; the measurements are in the doc comments
//! and in `docs/design.md`. Constants that define a layout's encoding (bit
//! fields, lane counts) stay beside the layout.

pub use crate::accel::embree::Quality;

/// The builders a user can choose with `--builder`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BuilderKind {
    /// The study's: median split on centroids along an axis cycling x, y, z.
    Median,
    /// Linear BVH (Karras 2012): triangles sorted by the Morton code of
    /// their centre, split where the highest differing bit of the codes
    /// changes; the fast builder of the low rung.
    Lbvh,
    /// Binned surface-area heuristic over all three axes.
    Sah,
    /// Spatial-split BVH (Stich et al. 2009): binned SAH object splits and,
    /// where children would overlap, splits of triangles at a plane;
    /// leaves may share a triangle. The high rung.
    Sbvh,
    /// Embree's builder (rtcBuildBVH) at low quality, in raylab's layout.
    EmbreeLow,
    /// Embree's builder at medium quality.
    EmbreeMedium,
    /// Embree's builder at high quality (spatial splits).
    EmbreeHigh,
}

impl BuilderKind {
    pub const ALL: [BuilderKind; 7] = [
        BuilderKind::Median,
        BuilderKind::Lbvh,
        BuilderKind::Sah,
        BuilderKind::Sbvh,
        BuilderKind::EmbreeLow,
        BuilderKind::EmbreeMedium,
        BuilderKind::EmbreeHigh,
    ];

    /// Embree's build quality for the `embree-*` builders.
    pub fn embree_quality(self) -> Option<crate::accel::embree::Quality> {
        use crate::accel::embree::Quality;
        match self {
            BuilderKind::EmbreeLow => Some(Quality::Low),
            BuilderKind::EmbreeMedium => Some(Quality::Medium),
            BuilderKind::EmbreeHigh => Some(Quality::High),
            _ => None,
        }
    }
}

/// Build parameters; the presets are the defaults chosen by measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildParams {
    pub builder: BuilderKind,
    /// Most triangles in one leaf. The median builder splits down to this (the
    /// study used 1); the SAH builder may stop earlier when a split does not pay.
    pub max_leaf_size: usize,
    /// Threads for the build: 1 builds serially on the calling thread.
    pub threads: usize,
    /// Children per node of the tree traversed: 2 (the built tree), 4 or 8
    /// (wide SIMD nodes, [`super::wide`]).
    pub width: usize,
    /// The SAH counts a leaf's triangle tests in blocks of this many: 1 for the
    /// binary tree (one test per triangle), 4 for the wide trees, whose leaves
    /// are tested four triangles at once ([`super::leaf`]), as Embree's
    /// `sahBlockSize`. Set by [`BuildParams::with_width`].
    pub sah_block: usize,
    /// Reinsertion optimisation of the binary tree after the build
    /// (`--optimize`; [`OPTIMIZE_BATCH`], [`OPTIMIZE_ROUNDS`]).
    pub optimize: bool,
}

impl BuildParams {
    /// The study's tree: one triangle per leaf, built serially.
    pub const fn median() -> Self {
        BuildParams {
            builder: BuilderKind::Median,
            max_leaf_size: 1,
            threads: 1,
            width: 2,
            sah_block: 1,
            optimize: false,
        }
    }

    /// Binned SAH with the default leaf limit, built serially.
    pub const fn sah() -> Self {
        BuildParams {
            builder: BuilderKind::Sah,
            max_leaf_size: DEFAULT_MAX_LEAF_SIZE,
            threads: 1,
            width: 2,
            sah_block: 1,
            optimize: false,
        }
    }

    /// Each builder's defaults; Embree's builder gets the SAH builder's leaf limit
    /// so that the two are compared like for like.
    pub const fn for_builder(builder: BuilderKind) -> Self {
        match builder {
            BuilderKind::Median => Self::median(),
            _ => BuildParams {
                builder,
                ..Self::sah()
            },
        }
    }

    /// The pipeline of each rung of the quality ladder (`--quality`), in this
    /// one place: low is the LBVH (the fastest build), medium the binned SAH
    /// (the default, and what the figures before the ladder used), high the
    /// spatial-split SBVH, reinsertion-optimised. Embree's rung of the same name is its build
    /// quality of that name (Morton, binned SAH, spatial splits).
    ///
    /// The high rung adds reinsertion (`--optimize`): measured with
    /// `raylab stats`, it took the SBVH's 8-wide nodes per AO ray from 4.6
    /// to 3.4 on `city45:3000`, 7.7 to 7.1 on `grass:20000` and 5.4 to 5.3
    /// on 2CylinderEngine, for 10-20% more build time. The low rung stays
    /// without it (it doubles the LBVH's build time).
    pub const fn for_quality(quality: Quality) -> Self {
        match quality {
            Quality::Low => Self::for_builder(BuilderKind::Lbvh),
            Quality::Medium => Self::for_builder(BuilderKind::Sah),
            Quality::High => Self::for_builder(BuilderKind::Sbvh).with_optimize(true),
        }
    }

    pub const fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads;
        self
    }

    /// Traverse a `width`-wide tree (2, 4 or 8); wide trees are built with
    /// the SAH counting leaf tests in pairs ([`WIDE_SAH_BLOCK`]).
    pub const fn with_width(mut self, width: usize) -> Self {
        self.width = width;
        self.sah_block = if width > 2 { WIDE_SAH_BLOCK } else { 1 };
        self
    }

    /// The binary tree of the same splits: width 2, the SAH block kept (what
    /// a wide tree's SAH cost is measured on, and what a collapse starts from).
    pub const fn binary(self) -> Self {
        let block = self.sah_block;
        self.with_width(2).with_sah_block(block)
    }

    /// Counts leaf tests in blocks of `block` triangles in the SAH.
    pub const fn with_sah_block(mut self, block: usize) -> Self {
        self.sah_block = block;
        self
    }

    /// Whether the wide tree's lanes are reordered for the any-hit
    /// traversals (`wide::order`): for the spatial-split builder only
    /// ([`ORDER_BLOCK_COST`]'s notes). Trees made directly wide by the
    /// top-down builders keep their order.
    pub const fn orders_lanes(&self) -> bool {
        matches!(self.builder, BuilderKind::Sbvh)
    }

    /// Reinsertion optimisation after the build, or not.
    pub const fn with_optimize(mut self, optimize: bool) -> Self {
        self.optimize = optimize;
        self
    }

    pub const fn with_max_leaf_size(mut self, n: usize) -> Self {
        self.max_leaf_size = n;
        self
    }
}

/// The SAH's leaf-test block for wide trees, chosen by measurement (docs/design.md):
/// counting tests in blocks of four, as the SIMD leaf test does them, makes
/// every node of up to four triangles a leaf however spread out, and rays
/// that start on surfaces (shadow, AO) then test more triangles (AO on
/// mesh:1e5 fell from 18.9 to 11.9 Mrays/s); counting one test per triangle
/// leaves blocks half empty; pairs give the fastest trees, and small leaves
/// share blocks ([`super::wide`]), which keeps their memory near the
/// four-block tree's.
pub const WIDE_SAH_BLOCK: usize = 2;

// ---- The SAH ----

/// Cost of visiting a node, relative to one ray/triangle test.
pub const C_TRAVERSAL: f32 = 1.0;
/// Cost of one ray/triangle test.
pub const C_INTERSECT: f32 = 1.0;
/// Default most triangles per leaf (see `docs/design.md` for the measurement).
pub const DEFAULT_MAX_LEAF_SIZE: usize = 4;
/// Nodes of at most this many triangles are split by the exact sweep.
pub const SWEEP_MAX: usize = 16;
/// Primitives binned per round: their bin indices are computed first, then
/// the bins updated.
pub const BIN_ROUND: usize = 32;

// ---- Spatial splits (the SBVH builder) ----

/// The SBVH may add at most this fraction of the triangle count as extra
/// leaf references (triangles split into several leaves). A node passes what
/// its split left of its allowance to its children in proportion to their
/// sizes, so the tree does not depend on the order nodes are built in.
/// Measured (binary SAH cost, pairs): 0.3, 0.5 and 1.0 gave 374, 353 and 310
/// on `grass:20000` and 83.4, 81.4 and 79.5 on 2CylinderEngine, for builds
/// about 35% longer at 1.0 than at 0.3; Embree's HIGH builder, given room for
/// one split per triangle (`embree::builder`), reaches 317 and 79.6. 1.0 gives
/// both the same room.
///
/// Embree's HIGH builds get the same budget ([`embree_split_replications`]).
/// Its scene build defaults to 1.2 references per triangle (its device's
/// `max_spatial_split_replications`), a fifth of this budget, and builds a
/// different tree: the ladder compared builds at unequal budgets. Measured
/// on a Zen 4 (`raylab bench --parts ladder grass:20000 city45:3000
/// .../2CylinderEngine.glb --reps 3`, the binaries before and after taking
/// turns, three runs each; medians): Embree HIGH's one-thread build went
/// from 93 to 133 ms (grass), 81 to 109 (city45) and 238 to 368 (the
/// engine), and its trees rendered faster (205 to 167 ms, 40 to 38, 29 to
/// 23). raylab's high rung over Embree HIGH's build time, 1 / 2 threads:
/// 0.96-1.24 / 1.33-1.79 (grass), 1.26-1.32 / 1.45-1.60 (city45),
/// 1.52-1.64 / 1.47-1.94 (the engine) before; 0.82-0.88 / 0.88-1.27,
/// 0.84-0.87 / 1.06-1.57, 0.93-0.98 / 1.02-1.11 at equal budgets.
/// At 0.2 (Embree's default) raylab's high rung built 2.0-2.3x faster but
/// traced `grass:20000` only 1.04-1.08x faster than the medium rung,
/// against 1.19-1.31x at 1.0 (`raylab render --quality high --query
/// packet16`, one thread, budgets alternated five times).
pub const SBVH_GROWTH: f32 = 1.0;

/// References per triangle Embree's HIGH builders may make: its device's
/// `max_spatial_split_replications` for scene builds, the room in the
/// primitive array for `rtcBuildBVH`; [`SBVH_GROWTH`]'s budget.
pub const fn embree_split_replications() -> f32 {
    1.0 + SBVH_GROWTH
}

/// A spatial split is tried only where the best object split's children
/// overlap by more than this fraction of the root's surface area (Stich et
/// al.'s alpha). Measured: on 2CylinderEngine (110k triangles, one thread)
/// 1e-5, 1e-4 and 1e-3 give SAH costs of 83.44, 83.44 and 83.51 for builds
/// of 877, 732 and 554 ms; but where a huge box holds small detail
/// (`city45:3000`, under a 40 x 40 ground plane) every overlap is tiny
/// against the root, and 1e-3 made no spatial split at all (SAH cost 9.23,
/// the SAH builder's) where 1e-5 gives 9.16 and 7% fewer nodes per ray.
pub const SBVH_ALPHA: f32 = 1e-5;

/// ... and by at least this fraction of the node's own area (as Embree's
/// spatial-split heuristic asks, with 0.1).
pub const SBVH_NODE_OVERLAP: f32 = 0.1;

/// A subtree stops searching for spatial splits once a search in it found
/// no plane cheaper than this much more than its object split (here 10%):
/// where spatial splits lose clearly, they rarely win further down, and the
/// searches were most of the SBVH's build time. Counted on one build each
/// (bin parts computed, binary SAH cost, 8-wide nodes per P/S/AO ray), with
/// 0.1 against searching everywhere: 2CylinderEngine 9.7M against 12.4M
/// parts, SAH 79.9 against 79.5, nodes 2.35/5.21/5.40 against
/// 2.34/5.20/5.39; grass:20000 3.6M against 5.5M, 311.3 against 310.2,
/// nodes within 0.01; city45:3000 2.7M against 3.8M, 9.09 against 9.08,
/// 4.61/5.29/4.61 against 4.58/5.12/4.56; mesh:50000 (where spatial splits
/// barely pay) 0.1M against 3.4M, 29.00 against 29.02. 0.05 saved more
/// (the engine 7.5M) for 1-2% more nodes per ray; a subtree that gave up
/// after two searches lost by any margin, 6.7M for 1-3% more triangle
/// tests per ray.
pub const SBVH_GIVE_UP: f32 = 0.1;

/// Bins per axis of the spatial-split search (Embree's spatial binning uses
/// 16 too). On 2CylinderEngine 32 bins gave no lower SAH cost (83.45 against
/// 83.44) for 1.3x the build time, 8 bins a 1% higher cost.
pub const SBVH_BINS: usize = 16;

/// Nodes of at most this many references get object splits only (the SAH
/// builder's): spatial splits pay at the top of a tree, where big boxes
/// overlap.
pub const SBVH_MIN_SPATIAL: usize = 16;

/// Nodes of at least this many references bin (and cost their object
/// split) in parallel chunks of half as many; the bins are exact unions and
/// counts, so the tree does not change.
pub const SBVH_PARALLEL_BINNING: usize = 8192;

// ---- The wide tree's lane order (`wide::order`) ----

/// A leaf block's test over a node visit in the lane-order cost. The
/// in-cache probes of `raylab stats` put it between 0.7 and 1.2 on Zen 4
/// (7.9 / 11.5 ns and 18.4 / 15.1 ns in two runs); the counts below are
/// with 1.2.
///
/// Which trees get the order ([`BuildParams::orders_lanes`]): the
/// spatial-split builder's (the high rung's). Counted over 400k recorded
/// rays of one render per scene (cornell-original, cornell-water,
/// 2CylinderEngine, Wuson, mesh:1e6, Sponza; node visits / triangle tests
/// per ray, the builder's order against this one): on the high rung's trees
/// Sponza's shadow rays 7.02 / 5.94 against 4.04 / 4.38 and its AO rays
/// 7.36 / 5.64 against 7.12 / 5.27; elsewhere within 3% except
/// cornell-water's shadow rays (2.35 / 1.96 against 2.41 / 2.06) and
/// mesh:1e6's (4.94 / 2.74 against 5.03 / 3.06). Timed in one process
/// beside Embree, one thread, Sponza's shadow rays went from 7.2 to 11.0
/// Mrays/s as single rays and 10.7 to 16.2 in packets of 16, its AO
/// packets from 36.5 to 39.6. On the SAH builder's trees the same order
/// cost Sponza's AO rays 5% more node visits and 13% more triangle tests
/// (shadow rays 5% fewer visits), so the medium rung keeps the builder's.
pub const ORDER_BLOCK_COST: f32 = 1.2;

// ---- Reinsertion optimisation (`--optimize`) ----

/// Share of the tree's nodes a reinsertion round tries to move: those with
/// the largest boxes (madmann91/bvh v2 uses 5% too).
pub const OPTIMIZE_BATCH: f32 = 0.05;

/// Most reinsertion rounds; fewer when a round moves nothing.
pub const OPTIMIZE_ROUNDS: usize = 3;

// ---- Parallelism and depth of the top-down builds ----

/// Below this many primitives a subtree of a top-down build (SAH, SBVH,
/// median split) is built on the current thread, and so is a whole scene
/// (`build`). 1024, where it was 4096: a scene of 1k-4k triangles built on
/// one thread left the second idle while Embree used both (Wuson, 3.7k
/// triangles, two threads, paired with Embree's same rung: medium 1.22 ->
/// 0.84, high 0.84 -> 0.62); on larger scenes the two were level.
pub const PARALLEL_CUTOFF: usize = 1024;

/// The LBVH's own [`PARALLEL_CUTOFF`]: its builds are so fast (0.08 ms for
/// cornell-sphere's 2,188 triangles, 0.2 ms for Wuson's 3,732) that waking
/// the second thread costs more than it gives below 4096 (two threads,
/// paired with Embree LOW: cornell-sphere 0.39 on one thread against 0.67
/// split at 1024, Wuson 0.53 against 0.65).
pub const LBVH_PARALLEL_CUTOFF: usize = 4096;

/// Beyond this depth every builder falls back to an object-median split, which
/// bounds the depth by `MAX_SPLIT_DEPTH + log2(n)`, within the traversal stack.
pub const MAX_SPLIT_DEPTH: u32 = 32;

/// Below this many primitives a per-node reduction (bounds, bins) runs
/// serially. 8192 (chunks of 2048) rather than 65536: the top nodes of
/// meshes of 10k-65k triangles then bin on both threads. Sapphire Rapids,
/// ladder part, two alternations: mesh:50000's two-thread SAH build went
/// from 1.06-1.07x Embree MEDIUM's time to 1.01-1.03x, the other scenes
/// within noise. The bins are exact unions and counts however they are
/// chunked, so the tree does not change.
pub const PARALLEL_REDUCE_CUTOFF: usize = 1 << 13;

// ---- Layouts ----

/// Node boxes are stored grown by this fraction of their extent
/// (`node::padded`, which says why not more, and why nothing in proportion to
/// the coordinates). The ray/triangle test accepts hits that lie
/// outside a triangle by rounding error (a ray aimed at a shared vertex), and
/// the box must still admit those rays or the BVH would miss hits the naive scan
/// finds. A parent's margin is never smaller than its children's, so children
/// stay inside their parents.
pub const BOX_MARGIN: f32 = 1.0 / (1 << 22) as f32;

/// A wide node's interior child of at most this many triangles whose two
/// halves are both leaves is made one leaf of all of them (two blocks at
/// most), not a node of two leaf lanes. Such nodes were 37% of mesh:1e6's
/// 8-wide nodes, for a box test that saves at most one block test; as
/// leaves, the tree took 59.3 bytes per triangle instead of 68.6, and its
/// rays ran at the same speed or faster on one thread (cornell-sphere,
/// cornell-water, mesh:1e5, mesh:1e6, two trace runs each). The SAH with
/// pair-costed leaves would merge few of them: it prices the node's test at
/// one triangle pair, below what it costs.
pub const MERGE_MAX: usize = 8;

/// Blocks ahead of the one being filled whose triangles' vertices are
/// prefetched by the wide build's leaf fill (and twice as far, their index
/// triples).
pub const FILL_AHEAD: usize = 8;

// ---- Traversal ----

/// Stack entries of the traversals of ordinary trees: every builder bounds
/// the binary depth by [`MAX_SPLIT_DEPTH`]` + log2(n)`, within 64. A wide
/// tree whose deepest path could need more (see `WideBvh::stack_need`) is
/// traversed with [`DEEP_STACK`] entries.
pub const STACK: usize = 64;
/// Enough for any wide tree of binary depth 64.
pub const DEEP_STACK: usize = 64 * 7 + 1;

/// Slab intervals are widened by this relative amount so that f32 rounding in the
/// slab test never culls a box that holds a hit the triangle test would report
/// (the conservative slab test of Ize 2013 uses 1 + 2 gamma(3), about 7.2e-7).
pub const SLAB_SLACK: f32 = 1e-6;

/// Closest-hit traversal skips a box only when it starts beyond the best hit by
/// this relative amount: Moller-Trumbore's t for rays grazing a vertex can be off
/// by more than 1e-5 relative (measured on the adversarial rays of the tests),
/// and a tighter cut makes the answer depend on the order boxes are visited in.
pub const CULL_SLACK: f32 = 1e-4;

/// How far from the origin, in multiples of a tree's largest extent, its
/// boxes and a ray's origin may lie for the single-ray walk to take the
/// fused node test (`simd::Avx2Fused`). Its distances err by about
/// `12 * EPSILON` of the larger of the box's and the origin's coordinates
/// (it keeps every box the unfused test keeps by growing them that much),
/// where the unfused test errs by about `EPSILON` of the distance along the
/// ray. At 16 extents that is at most 2.3e-5 of the scene's size. far:20000
/// (mesh:20000 1e5 from the origin, 7e4 extents) fused was 1.5-2.4x slower
/// in single rays than unfused: its boxes grown by 0.2 units where its
/// triangles are 0.03 across (docs/results.md).
pub const FUSED_ORIGIN_REACH: f32 = 16.0;

/// A packet entry with fewer active rays than this finishes its subtree ray
/// by ray with the single-ray traversal (`wide::packet`): a lone ray pays the
/// whole packet's node tests for nothing. 3 and 4 made no consistent
/// difference (A/B with `raylab bench --parts trace`: docs/design.md,
/// "Streams and packets").
pub const PACKET_MIN_RAYS: u32 = 2;

/// [`PACKET_MIN_RAYS`] for packets whose rays differ in sign on some axis
/// (diffuse bounces, cosine AO), which get no frustum: their entries split
/// fast, and a few rays finish sooner one by one. Measured on a Zen 4 (trace
/// part, 1 thread, three alternations of the binaries) on the diffuse rays
/// of cornell-water, cornell-sphere, the engine and Wuson: 16-ray packets
/// 11-14% faster (3-12% as a ratio over the same run's single rays). 4 for
/// every packet made coherent primary rays 12-20% slower on the boxes, so
/// coherent packets keep 2.
pub const PACKET_MIN_RAYS_INCOHERENT: u32 = 4;

/// The refit policy's default factor (`bench --rebuild-factor`): rebuild
/// when the refitted tree's SAH cost exceeds this many times its cost when
/// last built. Measured by the `animation` bench part, which runs the policy
/// at this factor beside refit-only and rebuild-every-frame (docs/results.md,
/// "Scenes that move").
pub const REBUILD_FACTOR: f32 = 1.5;

/// The unit costs the refit policy's SAH cost weighs node visits and leaf
/// block tests with: fixed, so that which frames rebuild never depends on a
/// timing (their ratio is about what `TraversalCosts::measure` finds here:
/// a block test 1.5-2 node visits).
pub const REFIT_POLICY_COSTS: super::wide::TraversalCosts = super::wide::TraversalCosts {
    node_ns: 1.0,
    block_ns: 1.75,
    kernel: "policy units",
};

/// Blocks per task of a parallel refit's vertex pass.
pub const REFIT_CHUNK: usize = 256;

/// How long a shared job's caller spins waiting for its helpers to finish
/// (`pool::share`; an item's length) before it sleeps in the scope's wait.
pub const SHARE_SPIN: std::time::Duration = std::time::Duration::from_micros(200);

/// Levels of a wide tree whose subtrees a parallel refit fits in parallel
/// (8-wide: up to 64 tasks under the root, enough for 2-16 threads).
pub const REFIT_PARALLEL_DEPTH: u32 = 2;
