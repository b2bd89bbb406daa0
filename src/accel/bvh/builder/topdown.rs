//! What every top-down builder shares: the per-node split protocol
//! ([`Splitter`]), and the binary recursion (with `rayon::join` above a size
//! cut-off) writing nodes straight into the flat [`Bvh`] layout. A builder only
//! decides, per node, whether to make a leaf and how to partition; each lives
//! in its own file ([`super::median`], [`super::sah`]); [`super::nary`] runs
//! the same splits into wide nodes.
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

use rayon::prelude::*;

use crate::accel::bvh::node::{padded, Skeleton, UNUSED};
use crate::accel::bvh::params::PARALLEL_CUTOFF;
use crate::accel::bvh::prim::{NodeInfo, PrimRef, Triangles};
use crate::accel::bvh::Node;
use crate::geometry::Aabb;

/// A split as [`Splitter::split`] returns it: `None` for a leaf, or the
/// number of primitives going left and each side's [`NodeInfo`].
pub(crate) type Split = Option<(usize, NodeInfo, NodeInfo)>;

/// Per-node decision of a top-down builder.
pub trait Splitter: Sync {
    /// Either `None` (make a leaf of all `prims`) or `Some((mid, left, right))`
    /// with `0 < mid < prims.len()` after reordering `prims` so that `..mid`
    /// goes left, and each side's [`NodeInfo`]. `info` is `prims`' own.
    /// `parallel` allows the splitter to use rayon for large nodes.
    fn split(&self, prims: &mut [PrimRef], info: &NodeInfo, depth: u32, parallel: bool) -> Split;
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
) -> Split {
    let n = prims.len();
    splitter
        .split(prims, info, depth, parallel)
        .filter(|&(mid, ..)| mid > 0 && mid < n)
}

/// The infos of `prims[..mid]` and `prims[mid..]`, for splits that do not get
/// them on the way (median splits).
pub fn side_infos(prims: &[PrimRef], mid: usize, parallel: bool) -> (NodeInfo, NodeInfo) {
    (
        NodeInfo::of(&prims[..mid], parallel),
        NodeInfo::of(&prims[mid..], parallel),
    )
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

/// Builds top-down with `splitter` into node slots in place (unused slots
/// stay in; [`Skeleton::compact`] removes them where a gapless array is
/// wanted).
pub(super) fn top_down<T: Triangles + ?Sized, S: Splitter>(
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
    use glam::Vec3;

    use super::*;

    fn point_prim(c: Vec3, index: u32) -> PrimRef {
        PrimRef::new(&Aabb::from_points(&[c]), index)
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
}
