//! Binned surface-area-heuristic builder (Wald 2007): per node, centroids are
//! binned on all three axes, every bin boundary is costed with
//! `C_TRAVERSAL + (A_left N_left + A_right N_right) / A_node * C_INTERSECT`, and the
//! node becomes a leaf when that is not cheaper than `N * C_INTERSECT` and
//! `N <= max_leaf`. Nodes whose centroids all coincide fall back to an
//! object-median split, so degenerate input (identical or coplanar triangles)
//! always terminates.

use super::{median_partition, PrimRef, Splitter, MAX_SPLIT_DEPTH};
use crate::geometry::Aabb;

/// Bins per axis.
pub const BINS: usize = 16;
/// Cost of visiting a node, relative to one ray/triangle test.
pub const C_TRAVERSAL: f32 = 1.0;
/// Cost of one ray/triangle test.
pub const C_INTERSECT: f32 = 1.0;
/// Default most triangles per leaf (see the README for the measurement).
pub const DEFAULT_MAX_LEAF_SIZE: usize = 4;

pub struct BinnedSah {
    max_leaf: usize,
}

impl BinnedSah {
    pub fn new(max_leaf: usize) -> Self {
        BinnedSah {
            max_leaf: max_leaf.max(1),
        }
    }
}

#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

/// The bin of centroid coordinate `c` for a centroid range starting at `lo` with
/// `scale = BINS / extent`; used both for binning and for the partition.
#[inline]
fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
    (((c - lo) * scale) as usize).min(BINS - 1)
}

impl Splitter for BinnedSah {
    fn split(&self, prims: &mut [PrimRef], bounds: &Aabb, depth: u32) -> Option<usize> {
        let n = prims.len();
        if n <= 1 {
            return None;
        }
        let centroids = prims.iter().fold(Aabb::EMPTY, |b, p| b.grown(p.centroid));
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

        let parent_area = bounds.surface_area();
        let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, first bin of the right side)
        for axis in 0..3 {
            if extent[axis] <= 0.0 {
                continue;
            }
            let lo = centroids.min[axis];
            let scale = BINS as f32 / extent[axis];
            let mut bins = [Bin {
                bounds: Aabb::EMPTY,
                count: 0,
            }; BINS];
            for p in prims.iter() {
                let b = &mut bins[bin_of(p.centroid[axis], lo, scale)];
                b.bounds = b.bounds.union(p.bounds);
                b.count += 1;
            }
            // Right-to-left sweep: area * count of everything right of each plane.
            let mut right_cost = [0f32; BINS];
            let mut acc = Aabb::EMPTY;
            let mut count = 0u32;
            for i in (1..BINS).rev() {
                acc = acc.union(bins[i].bounds);
                count += bins[i].count;
                right_cost[i] = acc.surface_area() * count as f32;
            }
            let mut acc = Aabb::EMPTY;
            let mut left_count = 0u32;
            for plane in 1..BINS {
                acc = acc.union(bins[plane - 1].bounds);
                left_count += bins[plane - 1].count;
                if left_count == 0 || left_count as usize == n {
                    continue;
                }
                let cost = C_TRAVERSAL
                    + C_INTERSECT * (acc.surface_area() * left_count as f32 + right_cost[plane])
                        / parent_area.max(f32::MIN_POSITIVE);
                // Strictly lower wins: ties keep the lowest axis and plane.
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, plane));
                }
            }
        }
        let (cost, axis, plane) = best?;
        if n <= self.max_leaf && cost >= n as f32 * C_INTERSECT {
            return None;
        }
        let lo = centroids.min[axis];
        let scale = BINS as f32 / extent[axis];
        Some(partition(prims, |p| {
            bin_of(p.centroid[axis], lo, scale) < plane
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
