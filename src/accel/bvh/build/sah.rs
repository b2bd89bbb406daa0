//! Binned surface-area-heuristic builder (Wald 2007): per node, centroids are
//! binned on all three axes, every bin boundary is costed with
//! `C_TRAVERSAL + (A_left B(N_left) + A_right B(N_right)) / A_node * C_INTERSECT`,
//! and the node becomes a leaf when that is not cheaper than `B(N) * C_INTERSECT`
//! and `N <= max_leaf`. `B(n)` counts triangle tests: `n` for one triangle at a
//! time, `ceil(n / 4)` for leaves tested in blocks of four (the wide trees). Nodes whose centroids all coincide fall back to an
//! object-median split, so degenerate input (identical or coplanar triangles)
//! always terminates.

use glam::Vec3;

use super::{median_partition, reduce_prims, PrimRef, Splitter, MAX_SPLIT_DEPTH};
use crate::geometry::Aabb;

/// Bins per axis (nodes of fewer triangles use one bin per triangle: the per-node
/// sweep, not the binning, dominates build time at the bottom of the tree).
pub const BINS: usize = 16;
/// Cost of visiting a node, relative to one ray/triangle test.
pub const C_TRAVERSAL: f32 = 1.0;
/// Cost of one ray/triangle test.
pub const C_INTERSECT: f32 = 1.0;
/// Default most triangles per leaf (see the README for the measurement).
pub const DEFAULT_MAX_LEAF_SIZE: usize = 4;

pub struct BinnedSah {
    max_leaf: usize,
    block: u32,
}

impl BinnedSah {
    /// Leaves of at most `max_leaf` triangles, tested `block` at a time.
    pub fn new(max_leaf: usize, block: usize) -> Self {
        BinnedSah {
            max_leaf: max_leaf.max(1),
            block: block.max(1) as u32,
        }
    }

    /// The triangle tests of a leaf of `n` triangles.
    #[inline]
    fn tests(&self, n: u32) -> f32 {
        n.div_ceil(self.block) as f32
    }
}

#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

/// The bin of centroid coordinate `c` for a centroid range starting at `lo` with
/// `scale = bins / extent`; used both for binning and for the partition.
#[inline]
fn bin_of(c: f32, lo: f32, scale: f32, bins: usize) -> usize {
    (((c - lo) * scale) as usize).min(bins - 1)
}

impl Splitter for BinnedSah {
    fn split(
        &self,
        prims: &mut [PrimRef],
        bounds: &Aabb,
        depth: u32,
        parallel: bool,
    ) -> Option<usize> {
        let n = prims.len();
        if n <= 1 {
            return None;
        }
        let centroids = reduce_prims(
            prims,
            parallel,
            Aabb::EMPTY,
            |b, p| *b = b.grown(p.centroid),
            |a, b| *a = a.union(b),
        );
        let extent = centroids.extent();
        let widest = extent.max_position();
        if depth >= MAX_SPLIT_DEPTH || extent[widest] <= 0.0 {
            // Too deep, or all centroids coincide: an object-median split keeps
            // the depth logarithmic from here on.
            if n <= self.max_leaf {
                return None;
            }
            median_partition(prims, widest, n / 2);
            return Some(n / 2);
        }

        // Bin all three axes in one pass; an axis of zero extent gets scale 0 and
        // puts everything in bin 0, where no plane can separate it.
        let nbins = BINS.min(n);
        let lo = centroids.min;
        let scale = Vec3::select(extent.cmpgt(Vec3::ZERO), nbins as f32 / extent, Vec3::ZERO);
        let empty = [[Bin {
            bounds: Aabb::EMPTY,
            count: 0,
        }; BINS]; 3];
        let bins = reduce_prims(
            prims,
            parallel,
            empty,
            |bins, p| {
                for (axis, axis_bins) in bins.iter_mut().enumerate() {
                    let b = &mut axis_bins[bin_of(p.centroid[axis], lo[axis], scale[axis], nbins)];
                    b.bounds = b.bounds.union(p.bounds);
                    b.count += 1;
                }
            },
            |a, b| {
                for (axis_a, axis_b) in a.iter_mut().zip(&b) {
                    for (x, y) in axis_a.iter_mut().zip(axis_b) {
                        x.bounds = x.bounds.union(y.bounds);
                        x.count += y.count;
                    }
                }
            },
        );

        // Candidates are compared by A_left N_left + A_right N_right; the cost
        // formula is applied to the winner only.
        let mut best: Option<(f32, usize, usize)> = None; // (area-weighted count, axis, first bin of the right side)
        for (axis, bins) in bins.iter().enumerate() {
            let bins = &bins[..nbins];
            // Right-to-left sweep: area * count of everything right of each plane.
            let mut right_cost = [0f32; BINS];
            let mut acc = Aabb::EMPTY;
            let mut count = 0u32;
            for i in (1..nbins).rev() {
                acc = acc.union(bins[i].bounds);
                count += bins[i].count;
                right_cost[i] = acc.surface_area() * self.tests(count);
            }
            let mut acc = Aabb::EMPTY;
            let mut left_count = 0u32;
            for plane in 1..nbins {
                acc = acc.union(bins[plane - 1].bounds);
                left_count += bins[plane - 1].count;
                if left_count == 0 || left_count as usize == n {
                    continue;
                }
                let weighted = acc.surface_area() * self.tests(left_count) + right_cost[plane];
                // Strictly lower wins: ties keep the lowest axis and plane.
                if best.is_none_or(|(c, _, _)| weighted < c) {
                    best = Some((weighted, axis, plane));
                }
            }
        }
        let (weighted, axis, plane) = best?;
        let cost =
            C_TRAVERSAL + C_INTERSECT * weighted / bounds.surface_area().max(f32::MIN_POSITIVE);
        if n <= self.max_leaf && cost >= self.tests(n as u32) * C_INTERSECT {
            return None;
        }
        let (lo, scale) = (lo[axis], scale[axis]);
        Some(partition(prims, |p| {
            bin_of(p.centroid[axis], lo, scale, nbins) < plane
        }))
    }
}

/// In-place two-pointer partition; returns the number of elements satisfying
/// `left`. Deterministic for a given input order.
fn partition(prims: &mut [PrimRef], left: impl Fn(&PrimRef) -> bool) -> usize {
    let mut i = 0;
    let mut j = prims.len();
    while i < j {
        if left(&prims[i]) {
            i += 1;
        } else {
            j -= 1;
            prims.swap(i, j);
        }
    }
    i
}
