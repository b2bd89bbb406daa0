//! What every top-down builder shares: primitive references, the recursion (with
//! `rayon::join` above a size cut-off) writing nodes straight into the flat
//! [`Bvh`] layout, and the gather of leaf triangles. A builder only decides, per
//! node, whether to make a leaf and how to partition ([`Splitter`]); each lives
//! in its own file.
//!
//! Speed (the build is part of every measured render): primitives are 32-byte
//! SIMD boxes; a splitter returns its children's bounds and centroid bounds
//! (the SAH builder gets them from its bins and its partition), so a node
//! costs two passes over its primitives, not four; and nodes are written in
//! place: a subtree of `k` primitives owns `2k - 1` node slots of one array,
//! handed to the two halves of a `rayon::join` with `split_at_mut`, and the
//! slots a subtree leaves unused are squeezed out once at the end.
//!
//! Determinism: a node's partition depends only on its primitives (bins are
//! exact unions and counts, however the reduction is chunked), and the layout
//! depends only on the tree, so the tree is the same for every thread count.
//!
//! How the SAH build is made fast, step by step with what each gave:
//! `docs/design.md`, "Builders, layouts and traversal".

pub mod median;
pub mod nary;
pub mod sah;

use glam::{Vec3, Vec4};
use rayon::prelude::*;

use super::{Bvh, Node};
use crate::geometry::Aabb;

/// The builders a user can choose with `--builder`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BuilderKind {
    /// The study's: median split on centroids along an axis cycling x, y, z.
    Median,
    /// Binned surface-area heuristic over all three axes.
    Sah,
    /// Embree's builder (rtcBuildBVH) at low quality, in raylab's layout.
    EmbreeLow,
    /// Embree's builder at medium quality.
    EmbreeMedium,
    /// Embree's builder at high quality (spatial splits).
    EmbreeHigh,
}

impl BuilderKind {
    pub const ALL: [BuilderKind; 5] = [
        BuilderKind::Median,
        BuilderKind::Sah,
        BuilderKind::EmbreeLow,
        BuilderKind::EmbreeMedium,
        BuilderKind::EmbreeHigh,
    ];

    pub fn name(self) -> &'static str {
        match self {
            BuilderKind::Median => "median",
            BuilderKind::Sah => "sah",
            BuilderKind::EmbreeLow => "embree-low",
            BuilderKind::EmbreeMedium => "embree-medium",
            BuilderKind::EmbreeHigh => "embree-high",
        }
    }

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
    /// (the built tree collapsed into wide SIMD nodes, [`super::wide`]).
    pub width: usize,
    /// The SAH counts a leaf's triangle tests in blocks of this many: 1 for the
    /// binary tree (one test per triangle), 4 for the wide trees, whose leaves
    /// are tested four triangles at once ([`super::leaf`]), as Embree's
    /// `sahBlockSize`. Set by [`BuildParams::with_width`].
    pub sah_block: usize,
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
        }
    }

    /// Binned SAH with the default leaf limit, built serially.
    pub const fn sah() -> Self {
        BuildParams {
            builder: BuilderKind::Sah,
            max_leaf_size: sah::DEFAULT_MAX_LEAF_SIZE,
            threads: 1,
            width: 2,
            sah_block: 1,
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

    /// Counts leaf tests in blocks of `block` triangles in the SAH.
    pub const fn with_sah_block(mut self, block: usize) -> Self {
        self.sah_block = block;
        self
    }

    pub const fn with_max_leaf_size(mut self, n: usize) -> Self {
        self.max_leaf_size = n;
        self
    }
}

/// The SAH's leaf-test block for wide trees, chosen by measurement (README):
/// counting tests in blocks of four, as the SIMD leaf test does them, makes
/// every node of up to four triangles a leaf however spread out, and rays
/// that start on surfaces (shadow, AO) then test more triangles (AO on
/// mesh:1e5 fell from 18.9 to 11.9 Mrays/s); counting one test per triangle
/// leaves blocks half empty; pairs give the fastest trees, and small leaves
/// share blocks ([`super::wide`]), which keeps their memory near the
/// four-block tree's.
pub const WIDE_SAH_BLOCK: usize = 2;

/// The triangles a BVH is built over: vertex triples in a slice, or a scene's
/// (read through its index list, so the build makes no copy of them).
pub trait Triangles: Sync {
    fn count(&self) -> usize;
    /// The vertices of triangle `i`.
    fn get(&self, i: usize) -> [Vec3; 3];
    /// A hint that triangle `i` will be read soon, for reads in an order
    /// the hardware cannot guess (the leaf fill): `stage` 0 asks for what
    /// locates its vertices (a scene's index triple), 1 for the vertices
    /// themselves (reading the triple, which stage 0 should have brought).
    #[inline]
    fn prefetch(&self, _i: usize, _stage: u8) {}
}

/// Slices and vectors of vertex triples.
impl<L: AsRef<[[Vec3; 3]]> + Sync + ?Sized> Triangles for L {
    #[inline]
    fn count(&self) -> usize {
        self.as_ref().len()
    }
    #[inline]
    fn get(&self, i: usize) -> [Vec3; 3] {
        self.as_ref()[i]
    }
}

impl Triangles for crate::scene::Scene {
    #[inline]
    fn count(&self) -> usize {
        self.triangle_count()
    }
    #[inline]
    fn get(&self, i: usize) -> [Vec3; 3] {
        self.triangle(i)
    }
    #[inline]
    fn prefetch(&self, i: usize, stage: u8) {
        use crate::accel::bvh::simd::prefetch;
        let Some(triple) = self.triangles.get(i) else {
            return;
        };
        if stage == 0 {
            prefetch(triple);
        } else {
            for &v in triple {
                if let Some(p) = self.positions.get(v as usize) {
                    prefetch(p);
                }
            }
        }
    }
}

/// Twice the bias that puts a scene index's bits in the normal float range.
const INDEX_BIAS: u32 = 0x0080_0000;

/// Most triangles a build takes: indices stay below this after the bias.
pub const MAX_TRIANGLES: usize = (0x7F00_0000 - 1) as usize;

/// A triangle as the builders see it: its box as two SIMD vectors (32 bytes,
/// as Embree's `PrimRef`). The minimum's w lane carries the scene index's bits,
/// shifted up by one exponent step so that they always form a normal float:
/// arithmetic on whole vectors never meets a denormal (slow on many CPUs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub struct PrimRef {
    pub lo: Vec4,
    pub hi: Vec4,
}

impl PrimRef {
    /// The reference to triangle `index` (at most [`MAX_TRIANGLES`]) with box `b`.
    #[inline]
    pub fn new(b: &Aabb, index: u32) -> PrimRef {
        debug_assert!((index as usize) < MAX_TRIANGLES);
        PrimRef {
            lo: b.min.extend(f32::from_bits(index + INDEX_BIAS)),
            hi: b.max.extend(0.0),
        }
    }

    /// Scene triangle index; also the final tie-break in every sort, so
    /// partitions never depend on the order primitives arrive in.
    #[inline]
    pub fn index(&self) -> u32 {
        self.lo.w.to_bits() - INDEX_BIAS
    }

    #[inline]
    pub fn bounds(&self) -> Aabb {
        Aabb {
            min: self.lo.truncate(),
            max: self.hi.truncate(),
        }
    }

    /// Twice the box centre in xyz (`lo + hi`): what the builders bin and sort
    /// by, in the same order as the centre, without a multiplication.
    #[inline]
    pub fn centroid2(&self) -> Vec4 {
        self.lo + self.hi
    }
}

/// An axis-aligned box as two SIMD vectors (w lanes unused).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Box4 {
    pub lo: Vec4,
    pub hi: Vec4,
}

impl Box4 {
    pub const EMPTY: Box4 = Box4 {
        lo: Vec4::INFINITY,
        hi: Vec4::NEG_INFINITY,
    };

    #[inline]
    pub fn union(self, o: Box4) -> Box4 {
        Box4 {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    #[inline]
    pub fn grow(&mut self, p: Vec4) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }

    /// Surface area, 0 for the empty box; the same arithmetic as
    /// [`Aabb::surface_area`], so both give the same bits.
    #[inline]
    pub fn area(self) -> f32 {
        let e = (self.hi - self.lo).max(Vec4::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    #[inline]
    pub fn to_aabb(self) -> Aabb {
        Aabb {
            min: self.lo.truncate(),
            max: self.hi.truncate(),
        }
    }
}

/// What a node's split needs to know of its primitives, and what a split
/// returns for each child: the union of their boxes and the bounds of their
/// doubled centroids ([`PrimRef::centroid2`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeInfo {
    pub bounds: Box4,
    pub centroids: Box4,
}

impl NodeInfo {
    /// Of `prims`, in parallel chunks for large inputs when `parallel`.
    pub fn of(prims: &[PrimRef], parallel: bool) -> NodeInfo {
        let empty = NodeInfo {
            bounds: Box4::EMPTY,
            centroids: Box4::EMPTY,
        };
        reduce_prims(
            prims,
            parallel,
            empty,
            |i, p| {
                i.bounds = i.bounds.union(Box4 { lo: p.lo, hi: p.hi });
                i.centroids.grow(p.centroid2());
            },
            |a, b| {
                a.bounds = a.bounds.union(b.bounds);
                a.centroids = a.centroids.union(b.centroids);
            },
        )
    }
}

/// Below this many primitives a subtree is built on the current thread.
pub const PARALLEL_CUTOFF: usize = 4096;

/// Beyond this depth every builder falls back to an object-median split, which
/// bounds the depth by `MAX_SPLIT_DEPTH + log2(n)`, within the traversal stack.
pub const MAX_SPLIT_DEPTH: u32 = 32;

/// Per-node decision of a top-down builder.
pub trait Splitter: Sync {
    /// Either `None` (make a leaf of all `prims`) or `Some((mid, left, right))`
    /// with `0 < mid < prims.len()` after reordering `prims` so that `..mid`
    /// goes left, and each side's [`NodeInfo`]. `info` is `prims`' own.
    /// `parallel` allows the splitter to use rayon for large nodes.
    fn split(
        &self,
        prims: &mut [PrimRef],
        info: &NodeInfo,
        depth: u32,
        parallel: bool,
    ) -> Option<(usize, NodeInfo, NodeInfo)>;
}

/// `splitter`'s split of `prims`, with the rule every builder keeps: a split
/// that puts everything on one side is a leaf. The binary and the wide
/// builders both split through here, so their trees stay the same.
pub(crate) fn try_split<S: Splitter>(
    splitter: &S,
    prims: &mut [PrimRef],
    info: &NodeInfo,
    depth: u32,
    parallel: bool,
) -> Option<(usize, NodeInfo, NodeInfo)> {
    let n = prims.len();
    splitter
        .split(prims, info, depth, parallel)
        .filter(|&(mid, ..)| mid > 0 && mid < n)
}

/// raylab's own splitters, chosen by [`BuilderKind`].
enum OwnSplitter {
    Median(median::Median),
    Sah(sah::BinnedSah),
}

impl OwnSplitter {
    /// The splitter of `params`' builder; `None` for Embree's builders.
    fn of(params: &BuildParams) -> Option<OwnSplitter> {
        let max_leaf = params.max_leaf_size.max(1);
        match params.builder {
            BuilderKind::Median => Some(OwnSplitter::Median(median::Median { max_leaf })),
            BuilderKind::Sah => Some(OwnSplitter::Sah(sah::BinnedSah::new(
                max_leaf,
                params.sah_block,
            ))),
            _ => None,
        }
    }
}

impl Splitter for OwnSplitter {
    fn split(
        &self,
        prims: &mut [PrimRef],
        info: &NodeInfo,
        depth: u32,
        parallel: bool,
    ) -> Option<(usize, NodeInfo, NodeInfo)> {
        match self {
            OwnSplitter::Median(s) => s.split(prims, info, depth, parallel),
            OwnSplitter::Sah(s) => s.split(prims, info, depth, parallel),
        }
    }
}

/// The triangle count, or the error for more than a build takes.
fn checked_count<T: Triangles + ?Sized>(triangles: &T) -> crate::Result<usize> {
    let count = triangles.count();
    if count > MAX_TRIANGLES {
        return Err(crate::Error::Other(format!(
            "BVH build: {count} triangles, at most {MAX_TRIANGLES}"
        )));
    }
    Ok(count)
}

/// Below this many primitives a per-node reduction (bounds, bins) runs serially.
pub const PARALLEL_REDUCE_CUTOFF: usize = 1 << 16;

/// Folds `prims` into one value; in parallel chunks for large inputs when
/// `parallel`. Every use is exact (box unions, integer counts), so the result does
/// not depend on the chunking and the tree stays deterministic.
pub fn reduce_prims<T: Send + Sync + Clone>(
    prims: &[PrimRef],
    parallel: bool,
    identity: T,
    fold: impl Fn(&mut T, &PrimRef) + Sync,
    combine: impl Fn(&mut T, T) + Sync + Send,
) -> T {
    // Accumulators are updated in place: a large one (SAH bins) must not be
    // moved or copied per primitive, nor cloned for a serial fold.
    let fold_into = |mut acc: T, chunk: &[PrimRef]| {
        for p in chunk {
            fold(&mut acc, p);
        }
        acc
    };
    if parallel && prims.len() >= PARALLEL_REDUCE_CUTOFF {
        prims
            .par_chunks(PARALLEL_REDUCE_CUTOFF / 4)
            .map(|chunk| fold_into(identity.clone(), chunk))
            .reduce(
                || identity.clone(),
                |mut a, b| {
                    combine(&mut a, b);
                    a
                },
            )
    } else {
        fold_into(identity, prims)
    }
}

/// The infos of `prims[..mid]` and `prims[mid..]`, for splits that do not get
/// them on the way (median splits).
pub fn side_infos(prims: &[PrimRef], mid: usize, parallel: bool) -> (NodeInfo, NodeInfo) {
    (
        NodeInfo::of(&prims[..mid], parallel),
        NodeInfo::of(&prims[mid..], parallel),
    )
}

/// A built binary tree before its triangles are gathered: nodes in the
/// [`Bvh`] layout, except that slots no subtree used may lie between them
/// (nothing points there; [`Skeleton::compact`] squeezes them out), and the
/// scene index of each leaf slot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Skeleton {
    pub nodes: Vec<Node>,
    pub tri_ids: Vec<u32>,
}

impl Skeleton {
    /// The same tree with its nodes renumbered depth-first without gaps.
    pub fn compact(self) -> Skeleton {
        if self.nodes.is_empty() {
            return self;
        }
        Skeleton {
            nodes: compact(&self.nodes),
            tri_ids: self.tri_ids,
        }
    }

    /// The [`Bvh`]: the skeleton, compacted, with each leaf slot's vertices
    /// gathered.
    pub fn gather<T: Triangles + ?Sized>(self, triangles: &T, parallel: bool) -> Bvh {
        let s = self.compact();
        let tris = if parallel {
            s.tri_ids
                .par_iter()
                .map(|&i| triangles.get(i as usize))
                .collect()
        } else {
            s.tri_ids
                .iter()
                .map(|&i| triangles.get(i as usize))
                .collect()
        };
        Bvh {
            nodes: s.nodes,
            tri_ids: s.tri_ids,
            tris,
        }
    }
}

/// Temporary tree, flattened once into the compact layout (the Embree
/// builder's callbacks make one). Leaves refer to a range of `tri_ids`.
pub(crate) enum BuildNode {
    Leaf {
        bounds: Aabb,
        start: u32,
        count: u32,
    },
    Interior {
        bounds: Aabb,
        children: Box<[BuildNode; 2]>,
    },
}

/// Builds the hierarchy (the entry point behind [`Bvh::build`]) on a pool of
/// `params.threads` threads. Only the Embree builders can fail (no Embree in
/// this build, or an Embree error).
pub fn build<T: Triangles + ?Sized>(triangles: &T, params: &BuildParams) -> crate::Result<Bvh> {
    in_pool(params.threads, || {
        Ok(skeleton_here(triangles, params)?.gather(triangles, params.threads > 1))
    })
}

/// Runs `f` on a pool of `threads` threads (on the calling thread for one).
/// Code inside passes `parallel = threads > 1` down and runs serially when
/// it is false, so one thread means no other thread at all.
///
/// Pools are made once per thread count and kept, as the Embree builder's
/// devices are: starting threads is not part of a build, and a pool made
/// per build also gave each build fresh per-thread heaps whose pages all
/// faulted again (mesh:1e5 on 2 threads: 1770 page faults a build).
pub fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    if threads <= 1 {
        return f();
    }
    static POOLS: KeptPerThreads<rayon::ThreadPool> = KeptPerThreads::new();
    let pool = POOLS
        .get(threads, || {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map(std::sync::Arc::new)
        })
        .ok();
    match pool {
        Some(pool) => pool.install(f),
        // No threads to be had: the same result, computed serially.
        None => f(),
    }
}

/// Values made once per thread count and kept for the process: the build
/// thread pools and the Embree builder's devices (starting threads is not
/// part of a build).
struct KeptPerThreads<T>(
    std::sync::OnceLock<std::sync::Mutex<std::collections::HashMap<usize, std::sync::Arc<T>>>>,
);

impl<T> KeptPerThreads<T> {
    const fn new() -> Self {
        KeptPerThreads(std::sync::OnceLock::new())
    }

    /// The value for `threads`, made by `make` the first time it is asked
    /// for (a failed `make` is not kept, so a later call tries again).
    fn get<E>(
        &self,
        threads: usize,
        make: impl FnOnce() -> Result<std::sync::Arc<T>, E>,
    ) -> Result<std::sync::Arc<T>, E> {
        // Entries are only ever added, so a map poisoned by a panic in
        // another caller is still whole.
        let mut kept = self
            .0
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(value) = kept.get(&threads) {
            return Ok(value.clone());
        }
        let value = make()?;
        kept.insert(threads, value.clone());
        Ok(value)
    }
}

/// Builds the tree without gathering its triangles (what the wide trees are
/// collapsed from), on a pool of `params.threads` threads.
pub fn build_skeleton<T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<Skeleton> {
    in_pool(params.threads, || skeleton_here(triangles, params))
}

/// [`build_skeleton`] on the current thread pool.
pub fn skeleton_here<T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<Skeleton> {
    let count = checked_count(triangles)?;
    let Some(splitter) = OwnSplitter::of(params) else {
        // Embree's builder splits triangles spatially: it takes a slice.
        let all: Vec<[Vec3; 3]> = (0..count).map(|i| triangles.get(i)).collect();
        let quality = params.builder.embree_quality().expect("an Embree builder");
        return build_with_embree(&all, params, quality);
    };
    if count == 0 {
        return Ok(Skeleton::default());
    }
    Ok(top_down(triangles, &splitter, params.threads > 1))
}

/// The references of `triangles`, made in parallel when `parallel`.
pub(crate) fn prim_refs<T: Triangles + ?Sized>(triangles: &T, parallel: bool) -> Vec<PrimRef> {
    let make = |i: usize| PrimRef::new(&Aabb::from_points(&triangles.get(i)), i as u32);
    let mut prims = crate::os::huge_vec(triangles.count());
    if parallel {
        (0..triangles.count())
            .into_par_iter()
            .map(make)
            .collect_into_vec(&mut prims);
    } else {
        prims.extend((0..triangles.count()).map(make));
    }
    prims
}

/// Builds the `N`-wide tree with the builder of `params` on the current
/// thread pool: directly top-down ([`nary`]) for raylab's builders, by
/// collapsing the binary tree for Embree's.
pub fn wide_here<const N: usize, T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<super::wide::WideBvh<N>> {
    let parallel = params.threads > 1;
    match OwnSplitter::of(params) {
        Some(splitter) => {
            checked_count(triangles)?;
            nary::build(
                triangles,
                &splitter,
                parallel,
                super::simd::Kernel::detect(),
            )
        }
        None => super::wide::WideBvh::from_skeleton(
            &skeleton_here(triangles, params)?,
            triangles,
            parallel,
        ),
    }
}

/// Builds top-down with `splitter` into node slots in place (unused slots
/// stay in; [`Skeleton::compact`] removes them where a gapless array is
/// wanted).
fn top_down<T: Triangles + ?Sized, S: Splitter>(
    triangles: &T,
    splitter: &S,
    parallel: bool,
) -> Skeleton {
    let mut prims = prim_refs(triangles, parallel);
    let info = NodeInfo::of(&prims, parallel);
    let count = 2 * prims.len() - 1;
    let mut slots = crate::os::huge_vec(count);
    if parallel {
        // Filling 32 bytes per slot (and faulting the pages in) is worth two threads.
        slots.par_extend(rayon::iter::repeat_n(UNUSED, count));
    } else {
        slots.resize(count, UNUSED);
    }
    recurse(&mut prims, 0, info, 0, splitter, parallel, 0, &mut slots);
    let tri_ids = if parallel {
        prims.par_iter().map(PrimRef::index).collect()
    } else {
        prims.iter().map(PrimRef::index).collect()
    };
    Skeleton {
        nodes: slots,
        tri_ids,
    }
}

/// A node slot no subtree wrote.
const UNUSED: Node = Node {
    min: Vec3::ZERO,
    offset: u32::MAX,
    max: Vec3::ZERO,
    count: 0,
};

/// Builds the subtree of `prims` (the leaf slots from `start` on) into
/// `nodes`, which holds its `2 * prims.len() - 1` slots, the first of them
/// at index `base` of the whole array.
#[allow(clippy::too_many_arguments)]
fn recurse<S: Splitter>(
    prims: &mut [PrimRef],
    start: usize,
    info: NodeInfo,
    depth: u32,
    splitter: &S,
    parallel: bool,
    base: usize,
    nodes: &mut [Node],
) {
    let n = prims.len();
    debug_assert!(nodes.len() >= 2 * n - 1);
    let b = padded(info.bounds.to_aabb());
    let split = try_split(splitter, prims, &info, depth, parallel);
    let Some((mid, left, right)) = split else {
        nodes[0] = Node {
            min: b.min,
            offset: start as u32,
            max: b.max,
            count: n as u32,
        };
        return;
    };
    // Left subtree in the slots right after this node, right subtree after
    // all of the left's.
    let right_base = base + 2 * mid;
    nodes[0] = Node {
        min: b.min,
        offset: right_base as u32,
        max: b.max,
        count: 0,
    };
    let (lp, rp) = prims.split_at_mut(mid);
    let (ln, rn) = nodes[1..].split_at_mut(2 * mid - 1);
    let mut left_job =
        move || recurse(lp, start, left, depth + 1, splitter, parallel, base + 1, ln);
    let mut right_job = move || {
        recurse(
            rp,
            start + mid,
            right,
            depth + 1,
            splitter,
            parallel,
            right_base,
            rn,
        )
    };
    if parallel && n >= PARALLEL_CUTOFF {
        rayon::join(left_job, right_job);
    } else {
        left_job();
        right_job();
    }
}

/// The nodes reachable from slot 0, renumbered depth-first without gaps.
fn compact(slots: &[Node]) -> Vec<Node> {
    let mut out: Vec<Node> = Vec::with_capacity(slots.len());
    // (slot, the output node whose right-child offset points here)
    let mut stack: Vec<(usize, Option<usize>)> = vec![(0, None)];
    while let Some((slot, parent)) = stack.pop() {
        let index = out.len();
        if let Some(p) = parent {
            out[p].offset = index as u32;
        }
        let node = slots[slot];
        debug_assert!(node != UNUSED);
        out.push(node);
        if !node.is_leaf() {
            stack.push((node.offset as usize, Some(index)));
            stack.push((slot + 1, None));
        }
    }
    out
}

#[cfg(feature = "embree")]
fn build_with_embree(
    triangles: &[[Vec3; 3]],
    params: &BuildParams,
    quality: crate::accel::embree::Quality,
) -> crate::Result<Skeleton> {
    use crate::accel::embree::Device;
    // One device per thread count, made once: device start-up (thread pool) is
    // not part of a build.
    static DEVICES: KeptPerThreads<Device> = KeptPerThreads::new();
    let device = DEVICES.get(params.threads, || {
        Device::new(&format!("threads={}", params.threads.max(1)))
    })?;
    crate::accel::embree::builder::build(
        &device,
        triangles,
        quality,
        params.max_leaf_size,
        params.sah_block,
    )
}

#[cfg(not(feature = "embree"))]
fn build_with_embree(
    _triangles: &[[Vec3; 3]],
    _params: &BuildParams,
    _quality: crate::accel::embree::Quality,
) -> crate::Result<Skeleton> {
    Err(crate::accel::embree::unavailable())
}

/// Flattens a temporary tree whose leaves index `tri_ids` into the compact
/// layout.
pub(crate) fn skeleton_of(root: BuildNode, tri_ids: Vec<u32>) -> Skeleton {
    let mut nodes = Vec::with_capacity(2 * tri_ids.len());
    flatten(root, &mut nodes);
    Skeleton { nodes, tri_ids }
}

/// Node boxes are stored grown by this fraction of their largest coordinate
/// magnitude (and of their extent). The ray/triangle test accepts hits that lie
/// outside a triangle by rounding error (a ray aimed at a shared vertex), and
/// the box must still admit those rays or the BVH would miss hits the naive scan
/// finds. A parent's margin is never smaller than its children's, so children
/// stay inside their parents.
pub const BOX_MARGIN: f32 = 1.0 / (1 << 20) as f32;

pub(crate) fn padded(b: Aabb) -> Aabb {
    let magnitude = b
        .min
        .abs()
        .max(b.max.abs())
        .max_element()
        .max(b.extent().max_element());
    let pad = glam::Vec3::splat(magnitude * BOX_MARGIN);
    Aabb {
        min: b.min - pad,
        max: b.max + pad,
    }
}

fn flatten(node: BuildNode, nodes: &mut Vec<Node>) -> u32 {
    let index = nodes.len();
    nodes.push(UNUSED);
    nodes[index] = match node {
        BuildNode::Leaf {
            bounds,
            start,
            count,
        } => {
            let b = padded(bounds);
            Node {
                min: b.min,
                offset: start,
                max: b.max,
                count,
            }
        }
        BuildNode::Interior { bounds, children } => {
            let [left, right] = *children;
            flatten(left, nodes);
            let right_index = flatten(right, nodes);
            let b = padded(bounds);
            Node {
                min: b.min,
                offset: right_index,
                max: b.max,
                count: 0,
            }
        }
    };
    index as u32
}

/// Reorders `prims` so that the `mid` smallest by (centroid on `axis`, index) come
/// first: the object-median partition, in O(n), identical to a full sort's.
pub fn median_partition(prims: &mut [PrimRef], axis: usize, mid: usize) {
    if mid == 0 || mid >= prims.len() {
        return;
    }
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid2()[axis]
            .total_cmp(&b.centroid2()[axis])
            .then(a.index().cmp(&b.index()))
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point_prim(c: Vec3, index: u32) -> PrimRef {
        PrimRef::new(&Aabb::from_points(&[c]), index)
    }

    #[test]
    fn prim_refs_keep_index_and_box_and_never_hold_denormals() {
        let b = Aabb::from_points(&[Vec3::new(-1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.5)]);
        for index in [0, 1, 12345, (MAX_TRIANGLES - 1) as u32] {
            let p = PrimRef::new(&b, index);
            assert_eq!(p.index(), index);
            assert_eq!(p.bounds(), b);
            assert!(p.lo.w.is_normal() && p.centroid2().w.is_normal(), "{index}");
            assert_eq!(p.centroid2().truncate(), b.min + b.max);
        }
    }

    #[test]
    fn wide_build_over_a_scene_equals_the_build_over_its_vertices() {
        // A scene is read through its index list (and prefetched through it
        // in the leaf fill); the tree must not notice.
        let scene = crate::scene::builtin::builtin("cornell-water").unwrap();
        let vertices = scene.triangle_vertices();
        for threads in [1, 2] {
            let params = BuildParams::sah().with_width(8).with_threads(threads);
            let from_scene = in_pool(threads, || wide_here::<8, _>(&scene, &params)).unwrap();
            let from_vertices = in_pool(threads, || wide_here::<8, _>(&vertices, &params)).unwrap();
            assert!(from_scene.nodes == from_vertices.nodes, "{threads} threads");
            assert!(
                from_scene.blocks == from_vertices.blocks,
                "{threads} threads"
            );
        }
        // Hints past the end are ignored.
        for stage in [0, 1] {
            scene.prefetch(scene.triangle_count(), stage);
            scene.prefetch(usize::MAX, stage);
        }
    }

    #[test]
    fn median_partition_matches_a_sort() {
        let prims: Vec<PrimRef> = (0..101u32)
            .map(|i| {
                // Many equal keys, so the index tie-break matters.
                point_prim(Vec3::splat((i * 37 % 11) as f32), i)
            })
            .collect();
        let mut sorted = prims.clone();
        sorted.sort_by(|a, b| a.lo.x.total_cmp(&b.lo.x).then(a.index().cmp(&b.index())));
        let mut part = prims.clone();
        median_partition(&mut part, 0, 51);
        let mut left: Vec<u32> = part[..51].iter().map(PrimRef::index).collect();
        let mut want: Vec<u32> = sorted[..51].iter().map(PrimRef::index).collect();
        left.sort();
        want.sort();
        assert_eq!(left, want);
    }

    #[test]
    fn compaction_renumbers_depth_first_without_gaps() {
        let tris: Vec<[Vec3; 3]> = (0..300)
            .map(|i| {
                let c = Vec3::new((i % 17) as f32, (i % 5) as f32, (i / 17) as f32);
                [c, c + Vec3::X * 0.5, c + Vec3::Y * 0.5]
            })
            .collect();
        for params in [
            BuildParams::sah(),
            BuildParams::sah().with_width(8),
            BuildParams::median(),
        ] {
            let s = build_skeleton(&tris, &params).unwrap().compact();
            assert!(s.nodes.iter().all(|n| *n != UNUSED));
            let leaves = s.nodes.iter().filter(|n| n.is_leaf()).count();
            assert_eq!(s.nodes.len(), 2 * leaves - 1);
            for (i, n) in s.nodes.iter().enumerate() {
                if !n.is_leaf() {
                    assert!(n.offset as usize > i + 1 && (n.offset as usize) < s.nodes.len());
                }
            }
            let mut ids = s.tri_ids.clone();
            ids.sort();
            assert_eq!(ids, (0..300).collect::<Vec<u32>>());
        }
    }
}
