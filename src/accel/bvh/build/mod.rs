//! What every top-down builder shares: primitive references, the recursion (with
//! `rayon::join` above a size cut-off), and flattening into the [`Bvh`] layout.
//! A builder only decides, per node, whether to make a leaf and how to partition
//! ([`Splitter`]); each lives in its own file.
//!
//! Determinism: a node's partition depends only on its primitives, and subtrees
//! are flattened in a fixed order after the parallel part, so the tree is the same
//! for every thread count.

pub mod median;
pub mod sah;

use glam::Vec3;

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

/// A triangle as the builders see it.
#[derive(Clone, Copy, Debug)]
pub struct PrimRef {
    pub bounds: Aabb,
    pub centroid: Vec3,
    /// Scene triangle index; also the final tie-break in every sort, so partitions
    /// never depend on the order primitives arrive in.
    pub index: u32,
}

/// Below this many primitives a subtree is built on the current thread.
pub const PARALLEL_CUTOFF: usize = 4096;

/// Beyond this depth every builder falls back to an object-median split, which
/// bounds the depth by `MAX_SPLIT_DEPTH + log2(n)`, within the traversal stack.
pub const MAX_SPLIT_DEPTH: u32 = 32;

/// Per-node decision of a top-down builder.
pub trait Splitter: Sync {
    /// Either `None` (make a leaf of all `prims`) or `Some(mid)` with
    /// `0 < mid < prims.len()` after reordering `prims` so that `..mid` goes left.
    /// `parallel` allows the splitter to use rayon for large nodes.
    fn split(
        &self,
        prims: &mut [PrimRef],
        bounds: &Aabb,
        depth: u32,
        parallel: bool,
    ) -> Option<usize>;
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
    use rayon::prelude::*;
    // Accumulators are updated in place: a large one (SAH bins) must not be
    // moved per primitive.
    let serial = |chunk: &[PrimRef]| {
        let mut acc = identity.clone();
        for p in chunk {
            fold(&mut acc, p);
        }
        acc
    };
    if parallel && prims.len() >= PARALLEL_REDUCE_CUTOFF {
        prims
            .par_chunks(PARALLEL_REDUCE_CUTOFF / 4)
            .map(serial)
            .reduce(
                || identity.clone(),
                |mut a, b| {
                    combine(&mut a, b);
                    a
                },
            )
    } else {
        serial(prims)
    }
}

/// Temporary tree, flattened once into the compact layout. Leaves refer to a
/// range of the leaf-ordered triangle list.
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

/// Builds the hierarchy (the entry point behind [`Bvh::build`]). Only the
/// Embree builders can fail (no Embree in this build, or an Embree error).
pub fn build(triangles: &[[Vec3; 3]], params: &BuildParams) -> crate::Result<Bvh> {
    if let Some(quality) = params.builder.embree_quality() {
        return build_with_embree(triangles, params, quality);
    }
    if triangles.is_empty() {
        return Ok(Bvh::default());
    }
    let max_leaf = params.max_leaf_size.max(1);
    let run = |prims: &mut [PrimRef]| {
        let parallel = params.threads > 1;
        match params.builder {
            BuilderKind::Median => recurse(prims, 0, 0, &median::Median { max_leaf }, parallel),
            _ => recurse(
                prims,
                0,
                0,
                &sah::BinnedSah::new(max_leaf, params.sah_block),
                parallel,
            ),
        }
    };
    let mut prims: Vec<PrimRef> = triangles
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let bounds = Aabb::from_points(t);
            PrimRef {
                bounds,
                centroid: bounds.center(),
                index: i as u32,
            }
        })
        .collect();
    let root = if params.threads > 1 {
        match rayon::ThreadPoolBuilder::new()
            .num_threads(params.threads)
            .build()
        {
            Ok(pool) => pool.install(|| run(&mut prims)),
            // No threads to be had: the same tree, built serially.
            Err(_) => run(&mut prims),
        }
    } else {
        run(&mut prims)
    };
    Ok(assemble(
        root,
        prims.iter().map(|p| p.index).collect(),
        triangles,
    ))
}

#[cfg(feature = "embree")]
fn build_with_embree(
    triangles: &[[Vec3; 3]],
    params: &BuildParams,
    quality: crate::accel::embree::Quality,
) -> crate::Result<Bvh> {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};

    use crate::accel::embree::Device;
    // One device per thread count, made once: device start-up (thread pool) is
    // not part of a build.
    static DEVICES: OnceLock<Mutex<HashMap<usize, Arc<Device>>>> = OnceLock::new();
    let device = {
        let mut devices = DEVICES
            .get_or_init(Default::default)
            .lock()
            .map_err(|_| crate::Error::Other("embree device cache poisoned".into()))?;
        match devices.get(&params.threads) {
            Some(d) => d.clone(),
            None => {
                let d = Device::new(&format!("threads={}", params.threads.max(1)))?;
                devices.insert(params.threads, d.clone());
                d
            }
        }
    };
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
) -> crate::Result<Bvh> {
    Err(crate::accel::embree::unavailable())
}

/// Flattens a temporary tree whose leaves index `tri_ids` into the compact
/// layout, gathering the triangles' vertices in leaf order.
pub(crate) fn assemble(root: BuildNode, tri_ids: Vec<u32>, triangles: &[[Vec3; 3]]) -> Bvh {
    let mut nodes = Vec::with_capacity(2 * tri_ids.len());
    flatten(root, &mut nodes);
    let tris = tri_ids.iter().map(|&i| triangles[i as usize]).collect();
    Bvh {
        nodes,
        tri_ids,
        tris,
    }
}

fn recurse<S: Splitter>(
    prims: &mut [PrimRef],
    start: usize,
    depth: u32,
    splitter: &S,
    parallel: bool,
) -> BuildNode {
    let bounds = reduce_prims(
        prims,
        parallel,
        Aabb::EMPTY,
        |b, p| *b = b.union(p.bounds),
        |a, b| *a = a.union(b),
    );
    let mid = splitter.split(prims, &bounds, depth, parallel);
    let Some(mid) = mid.filter(|&m| m > 0 && m < prims.len()) else {
        return BuildNode::Leaf {
            bounds,
            start: start as u32,
            count: prims.len() as u32,
        };
    };
    let n = prims.len();
    let (left, right) = prims.split_at_mut(mid);
    let (l, r) = if parallel && n >= PARALLEL_CUTOFF {
        rayon::join(
            || recurse(left, start, depth + 1, splitter, true),
            || recurse(right, start + mid, depth + 1, splitter, true),
        )
    } else {
        (
            recurse(left, start, depth + 1, splitter, parallel),
            recurse(right, start + mid, depth + 1, splitter, parallel),
        )
    };
    BuildNode::Interior {
        bounds,
        children: Box::new([l, r]),
    }
}

/// Node boxes are stored grown by this fraction of their largest coordinate
/// magnitude (and of their extent). The ray/triangle test accepts hits that lie
/// outside a triangle by rounding error (a ray aimed at a shared vertex), and
/// the box must still admit those rays or the BVH would miss hits the naive scan
/// finds. A parent's margin is never smaller than its children's, so children
/// stay inside their parents.
pub const BOX_MARGIN: f32 = 1.0 / (1 << 20) as f32;

fn padded(b: Aabb) -> Aabb {
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
    let blank = Node {
        min: Vec3::ZERO,
        offset: 0,
        max: Vec3::ZERO,
        count: 0,
    };
    nodes.push(blank);
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
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.index.cmp(&b.index))
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_partition_matches_a_sort() {
        let prims: Vec<PrimRef> = (0..101u32)
            .map(|i| {
                // Many equal keys, so the index tie-break matters.
                let c = Vec3::splat((i * 37 % 11) as f32);
                PrimRef {
                    bounds: Aabb::from_points(&[c]),
                    centroid: c,
                    index: i,
                }
            })
            .collect();
        let mut sorted = prims.clone();
        sorted.sort_by(|a, b| {
            a.centroid
                .x
                .total_cmp(&b.centroid.x)
                .then(a.index.cmp(&b.index))
        });
        let mut part = prims.clone();
        median_partition(&mut part, 0, 51);
        let mut left: Vec<u32> = part[..51].iter().map(|p| p.index).collect();
        let mut want: Vec<u32> = sorted[..51].iter().map(|p| p.index).collect();
        left.sort();
        want.sort();
        assert_eq!(left, want);
    }
}
