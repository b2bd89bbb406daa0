//! Binned surface-area-heuristic builder (Wald 2007): per node, centroids are
//! binned on all three axes, every bin boundary is costed with
//! `C_TRAVERSAL + (A_left B(N_left) + A_right B(N_right)) / A_node * C_INTERSECT`,
//! and the node becomes a leaf when that is not cheaper than `B(N) * C_INTERSECT`
//! and `N <= max_leaf`. `B(n)` counts triangle tests: `n` for one triangle at a
//! time, `ceil(n / block)` for leaves tested in blocks (the wide trees).
//!
//! Nodes of at most [`SWEEP_MAX`] triangles (most nodes of a tree) are split by
//! an exact sweep instead: centroids sorted on each axis, every split position
//! costed. That is the SAH's best split, never worse than the binned one, and
//! cheaper there than filling and sweeping bins. Nodes whose centroids all coincide fall back to an
//! object-median split, so degenerate input (identical or coplanar triangles)
//! always terminates.

use glam::{Vec3, Vec4};

use super::partition::{partition, Plane};
use super::topdown::{median_partition, side_infos, Split, Splitter};
use crate::accel::bvh::params::{
    BIN_ROUND, C_INTERSECT, C_TRAVERSAL, MAX_SPLIT_DEPTH, PARALLEL_REDUCE_CUTOFF, SWEEP_MAX,
};
use crate::accel::bvh::prim::{Box4, NodeInfo, PrimRef};
use crate::accel::bvh::simd::bin_indices;

pub struct BinnedSah {
    max_leaf: usize,
    block: u32,
    /// `log2(block)` when `block` is a power of two (always, but for a
    /// user's odd choice): the tests are then a shift, not a division.
    block_shift: Option<u32>,
    /// `tests(k)` for the sweep's child sizes `k <= SWEEP_MAX`, looked up.
    sweep_tests: [f32; SWEEP_MAX + 1],
}

impl BinnedSah {
    /// Leaves of at most `max_leaf` triangles, tested `block` at a time.
    pub fn new(max_leaf: usize, block: usize) -> Self {
        let mut sah = BinnedSah {
            max_leaf: max_leaf.max(1),
            block: block.max(1) as u32,
            block_shift: block
                .max(1)
                .is_power_of_two()
                .then(|| block.max(1).trailing_zeros()),
            sweep_tests: [0.0; SWEEP_MAX + 1],
        };
        for k in 0..=SWEEP_MAX {
            sah.sweep_tests[k] = sah.tests(k as u32);
        }
        sah
    }

    /// The triangle tests of a leaf of `n` triangles.
    #[inline]
    fn tests(&self, n: u32) -> f32 {
        match self.block_shift {
            // No overflow: `n` is at most `MAX_TRIANGLES` (below 2^31).
            Some(shift) => ((n + self.block - 1) >> shift) as f32,
            None => n.div_ceil(self.block) as f32,
        }
    }
}

/// The `B` bins of all three axes: `boxes[bin][axis]` is the union of the
/// boxes whose centroid falls in `bin` on `axis`, `counts[bin][axis]` their
/// number. Sized by the node's bin count ([`bins_for`]), so that a small node
/// clears and merges only the bins it uses.
#[derive(Clone)]
pub(super) struct Bins<const B: usize> {
    pub(super) boxes: [[Box4; 3]; B],
    pub(super) counts: [[u32; 3]; B],
}

impl<const B: usize> Bins<B> {
    fn empty() -> Self {
        Bins {
            boxes: [[Box4::EMPTY; 3]; B],
            counts: [[0; 3]; B],
        }
    }

    fn add(&mut self, other: &Self) {
        for (a, b) in self.boxes.iter_mut().zip(&other.boxes) {
            for (x, y) in a.iter_mut().zip(b) {
                *x = x.union(*y);
            }
        }
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }
}

/// Bins per axis for a node of `n` triangles. Measured on mesh:1e5/1e6 and
/// cornell-water: 32 bins at the top make the trees' SAH cost 3-8% lower than
/// 16 (and lower than Embree MEDIUM's, which bins 4 + n/20); below, setting up
/// and sweeping the bins, not binning the triangles, is the cost, and fewer
/// bins lose little there.
pub fn bins_for(n: usize) -> usize {
    if n >= 512 {
        32
    } else if n >= 64 {
        16
    } else {
        8
    }
}

/// Bins `prims` into `B` bins. Two things keep the updates (a load, min or
/// max and store of each axis's bin) from waiting on one another, which
/// halved the time per primitive (measured on mesh:1e6 nodes of 512 to 4096
/// triangles, coherent and shuffled): the bin indices of a round of
/// [`BIN_ROUND`] primitives are computed before any bin is updated, so every
/// update's address is known when it issues and the CPU need not guess
/// whether it reads a bin that an earlier update is still writing; and even
/// and odd primitives go to separate bin sets merged at the end, since
/// neighbours often fall in the same bins.
pub(super) fn bin_pairs<const B: usize>(prims: &[PrimRef], lo: Vec4, scale: Vec4) -> Bins<B> {
    debug_assert!(B.is_power_of_two());
    let mut even = Bins::<B>::empty();
    let mut odd = Bins::<B>::empty();
    let add = |bins: &mut Bins<B>, p: &PrimRef, bin: &[u32; 4]| {
        for (axis, &b) in bin[..3].iter().enumerate() {
            // `b < B` already; the mask lets the compiler drop the bounds check.
            let b = b as usize & (B - 1);
            let slot = &mut bins.boxes[b][axis];
            slot.lo = slot.lo.min(p.lo);
            slot.hi = slot.hi.max(p.hi);
            bins.counts[b][axis] += 1;
        }
    };
    let mut bins = [[0u32; 4]; BIN_ROUND];
    for round in prims.chunks(BIN_ROUND) {
        for (bin, p) in bins.iter_mut().zip(round) {
            *bin = bin_indices((p.centroid2() - lo) * scale, B - 1);
        }
        let mut pairs = round.chunks_exact(2).zip(bins.chunks_exact(2));
        for (pair, bin) in &mut pairs {
            add(&mut even, &pair[0], &bin[0]);
            add(&mut odd, &pair[1], &bin[1]);
        }
        if round.len() % 2 == 1 {
            add(&mut even, &round[round.len() - 1], &bins[round.len() - 1]);
        }
    }
    even.add(&odd);
    even
}

impl Splitter for BinnedSah {
    fn split(&self, prims: &mut [PrimRef], info: &NodeInfo, depth: u32, parallel: bool) -> Split {
        let n = prims.len();
        // A leaf of at most one block costs one test; any split costs more.
        if n <= 1 || (n <= self.block as usize && n <= self.max_leaf) {
            return None;
        }
        let extent = (info.centroids.hi - info.centroids.lo).truncate();
        let widest = extent.max_position();
        if depth >= MAX_SPLIT_DEPTH || extent[widest] <= 0.0 {
            // Too deep, or all centroids coincide: an object-median split keeps
            // the depth logarithmic from here on.
            if n <= self.max_leaf {
                return None;
            }
            median_partition(prims, widest, n / 2);
            let (left, right) = side_infos(prims, n / 2, parallel);
            return Some((n / 2, left, right));
        }

        if n <= SWEEP_MAX {
            return self.sweep(prims, info);
        }

        match bins_for(n) {
            32 => self.binned::<32>(prims, info, extent, parallel),
            16 => self.binned::<16>(prims, info, extent, parallel),
            _ => self.binned::<8>(prims, info, extent, parallel),
        }
    }
}

impl BinnedSah {
    /// The best of the `B - 1` bin boundaries on each axis (`extent`: of the
    /// doubled centroids), applied; `None` when a leaf is cheaper.
    fn binned<const B: usize>(
        &self,
        prims: &mut [PrimRef],
        info: &NodeInfo,
        extent: Vec3,
        parallel: bool,
    ) -> Split {
        let n = prims.len();
        // Bin all three axes in one pass; an axis of zero extent gets scale 0 and
        // puts everything in bin 0, where no plane can separate it.
        let lo = info.centroids.lo;
        let scale =
            Vec3::select(extent.cmpgt(Vec3::ZERO), B as f32 / extent, Vec3::ZERO).extend(0.0);
        let bin_chunk = |chunk: &[PrimRef]| bin_pairs::<B>(chunk, lo, scale);
        let bins = if parallel && n >= PARALLEL_REDUCE_CUTOFF {
            use rayon::prelude::*;
            prims
                .par_chunks(PARALLEL_REDUCE_CUTOFF / 4)
                .map(bin_chunk)
                .reduce(Bins::empty, |mut a, b| {
                    a.add(&b);
                    a
                })
        } else {
            bin_chunk(prims)
        };

        // Candidates are compared by A_left B(N_left) + A_right B(N_right); the
        // cost formula is applied to the winner only.
        struct Best {
            weighted: f32,
            axis: usize,
            plane: usize,
            left: Box4,
            right: Box4,
        }
        let mut best: Option<Best> = None;
        for axis in 0..3 {
            // Right-to-left sweep: box and area-weighted tests of everything
            // right of each plane.
            let mut right_cost = [0f32; B];
            let mut right_box = [Box4::EMPTY; B];
            let mut acc = Box4::EMPTY;
            let mut count = 0u32;
            for i in (1..B).rev() {
                acc = acc.union(bins.boxes[i][axis]);
                count += bins.counts[i][axis];
                right_cost[i] = acc.area() * self.tests(count);
                right_box[i] = acc;
            }
            let mut acc = Box4::EMPTY;
            let mut left_count = 0u32;
            for plane in 1..B {
                acc = acc.union(bins.boxes[plane - 1][axis]);
                left_count += bins.counts[plane - 1][axis];
                if left_count == 0 || left_count as usize == n {
                    continue;
                }
                let weighted = acc.area() * self.tests(left_count) + right_cost[plane];
                // Strictly lower wins: ties keep the lowest axis and plane.
                if best.as_ref().is_none_or(|b| weighted < b.weighted) {
                    best = Some(Best {
                        weighted,
                        axis,
                        plane,
                        left: acc,
                        right: right_box[plane],
                    });
                }
            }
        }
        let best = best?;
        if self.leaf_is_cheaper(n, best.weighted, info) {
            return None;
        }
        let (axis, plane) = (best.axis, best.plane);
        // A primitive goes left when its bin, `min(trunc((c - lo) * scale),
        // B - 1)` as binning computed it, is below `plane`: for the
        // non-negative `(c - lo) * scale` and an integer plane of at most
        // `B - 1`, exactly when `(c - lo) * scale < plane`, a compare of
        // floats without the conversion.
        let plane = Plane {
            axis,
            lo,
            scale,
            plane: plane as f32,
        };
        let (mid, left_centroids, right_centroids) = partition(prims, &plane, parallel);
        Some((
            mid,
            NodeInfo {
                bounds: best.left,
                centroids: left_centroids,
            },
            NodeInfo {
                bounds: best.right,
                centroids: right_centroids,
            },
        ))
    }

    /// Whether a leaf of the node's `n` triangles costs no more than its best
    /// split (area-weighted child tests `weighted`), and is allowed.
    fn leaf_is_cheaper(&self, n: usize, weighted: f32, info: &NodeInfo) -> bool {
        let area = info.bounds.area().max(f32::MIN_POSITIVE);
        let cost = C_TRAVERSAL + C_INTERSECT * weighted / area;
        n <= self.max_leaf && cost >= self.tests(n as u32) * C_INTERSECT
    }

    /// The exact SAH split of a small node (at most [`SWEEP_MAX`] triangles):
    /// on each axis the triangles sorted by centroid (then index), every split
    /// position costed with prefix and suffix boxes; ties keep the lowest axis
    /// and position.
    fn sweep(&self, prims: &mut [PrimRef], info: &NodeInfo) -> Split {
        let n = prims.len();
        debug_assert!((2..=SWEEP_MAX).contains(&n));
        // Sort keys: each centroid's bits mapped to an order-preserving
        // integer (the order of `f32::total_cmp`), then the index; all
        // distinct, so each key's rank (how many keys are smaller) is its
        // place in the sorted order. Counting ranks has no data-dependent
        // branch, where a sort of so few keys mispredicts on every other
        // comparison. Keys of all three axes are made in one pass.
        let mut keys = [[0u64; SWEEP_MAX]; 3];
        for (i, p) in prims.iter().enumerate() {
            let c = p.centroid2();
            let index = p.index() as u64;
            for (axis, axis_keys) in keys.iter_mut().enumerate() {
                let bits = c[axis].to_bits();
                let ordered = if bits >> 31 == 1 {
                    !bits
                } else {
                    bits | 1 << 31
                };
                axis_keys[i] = (ordered as u64) << 32 | index;
            }
        }
        let mut orders = [[0u8; SWEEP_MAX]; 3];
        // (area-weighted child tests, axis, split position)
        let mut best: Option<(f32, usize, usize)> = None;
        for axis in 0..3 {
            let (keys, order) = (&keys[axis][..n], &mut orders[axis]);
            for (i, &key) in keys.iter().enumerate() {
                let rank: usize = keys.iter().map(|&k| (k < key) as usize).sum();
                order[rank] = i as u8;
            }
            let boxed = |i: u8| Box4 {
                lo: prims[i as usize].lo,
                hi: prims[i as usize].hi,
            };
            let mut right_cost = [0f32; SWEEP_MAX];
            let mut acc = Box4::EMPTY;
            for k in (1..n).rev() {
                acc = acc.union(boxed(order[k]));
                right_cost[k] = acc.area() * self.sweep_tests[n - k];
            }
            let mut acc = Box4::EMPTY;
            for k in 1..n {
                acc = acc.union(boxed(order[k - 1]));
                let weighted = acc.area() * self.sweep_tests[k] + right_cost[k];
                if best.is_none_or(|b| weighted < b.0) {
                    best = Some((weighted, axis, k));
                }
            }
        }
        let (weighted, axis, k) = best?;
        if self.leaf_is_cheaper(n, weighted, info) {
            return None;
        }
        let mut sorted = [prims[0]; SWEEP_MAX];
        for (slot, &i) in sorted.iter_mut().zip(&orders[axis][..n]) {
            *slot = prims[i as usize];
        }
        for (p, s) in prims.iter_mut().zip(&sorted) {
            *p = *s;
        }
        let (left, right) = side_infos(prims, k, false);
        Some((k, left, right))
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::geometry::Aabb;

    fn prims_of(tris: &[[Vec3; 3]]) -> Vec<PrimRef> {
        tris.iter()
            .enumerate()
            .map(|(i, t)| PrimRef::new(&Aabb::from_points(t), i as u32))
            .collect()
    }

    /// Triangles on a coarse grid, so that many centroids coincide on some
    /// axis and the index tie-break decides the order.
    fn gridded(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        random_tris(n, seed)
            .into_iter()
            .map(|t| {
                let snap = (t[0] * 0.5).round();
                [snap, snap + Vec3::X * 0.25, snap + Vec3::Y * 0.25]
            })
            .collect()
    }

    fn union(prims: &[PrimRef]) -> Box4 {
        prims
            .iter()
            .fold(Box4::EMPTY, |b, p| b.union(Box4 { lo: p.lo, hi: p.hi }))
    }

    /// The split the exact sweep must find: every axis sorted by (centroid,
    /// index), every position costed, strictly lower wins.
    fn brute_force(sah: &BinnedSah, prims: &[PrimRef]) -> Option<(usize, Vec<u32>)> {
        let n = prims.len();
        let mut best: Option<(f32, Vec<PrimRef>, usize)> = None;
        for axis in 0..3 {
            let mut sorted = prims.to_vec();
            sorted.sort_by(|a, b| {
                a.centroid2()[axis]
                    .total_cmp(&b.centroid2()[axis])
                    .then(a.index().cmp(&b.index()))
            });
            for k in 1..n {
                let weighted = union(&sorted[..k]).area() * sah.tests(k as u32)
                    + union(&sorted[k..]).area() * sah.tests((n - k) as u32);
                if best.as_ref().is_none_or(|b| weighted < b.0) {
                    best = Some((weighted, sorted.clone(), k));
                }
            }
        }
        let (weighted, sorted, k) = best?;
        let info = NodeInfo::of(prims, false);
        if sah.leaf_is_cheaper(n, weighted, &info) {
            return None;
        }
        let mut left: Vec<u32> = sorted[..k].iter().map(PrimRef::index).collect();
        left.sort_unstable();
        Some((k, left))
    }

    #[test]
    fn exact_sweep_finds_the_brute_force_best_split() {
        let mut splits = 0;
        for (seed, n) in (0..400u64).map(|s| (s, 2 + (s as usize % (SWEEP_MAX - 1)))) {
            let tris = if seed % 2 == 0 {
                random_tris(n, seed)
            } else {
                gridded(n, seed)
            };
            for block in [1, 2, 4] {
                let sah = BinnedSah::new(4, block);
                let mut prims = prims_of(&tris);
                let info = NodeInfo::of(&prims, false);
                let got = sah.split(&mut prims, &info, 0, false);
                let want = brute_force(&sah, &prims_of(&tris));
                let what = format!("seed {seed}, n {n}, block {block}");
                match (got, want) {
                    (None, None) => {}
                    (Some((mid, left, right)), Some((k, want_left))) => {
                        splits += 1;
                        assert_eq!(mid, k, "{what}");
                        let mut got_left: Vec<u32> =
                            prims[..mid].iter().map(PrimRef::index).collect();
                        got_left.sort_unstable();
                        assert_eq!(got_left, want_left, "{what}");
                        assert_eq!(left, NodeInfo::of(&prims[..mid], false), "{what}");
                        assert_eq!(right, NodeInfo::of(&prims[mid..], false), "{what}");
                    }
                    (got, want) => panic!("{what}: split {got:?}, brute force {want:?}"),
                }
            }
        }
        assert!(splits > 500, "too few splits to mean anything: {splits}");
    }

    #[test]
    fn binned_splits_return_their_sides_own_bounds_serial_or_parallel() {
        // The side bounds come from the bins and the centroid bounds from
        // the partition: they equal the sides' own only if the partition
        // sent each primitive to the side its bin is on. 70,000 triangles
        // take the parallel binning.
        for (n, seed) in [
            (17, 1),
            (63, 2),
            (64, 3),
            (511, 4),
            (512, 5),
            (5000, 6),
            (70_000, 7),
        ] {
            // Centres on whole numbers 0..=8 along x: with 8 bins over that
            // extent, every centroid lies exactly on a bin boundary, where a
            // partition that rounds differently from the binning shows.
            let on_boundaries: Vec<[Vec3; 3]> = (0..n)
                .map(|i| {
                    let c = Vec3::new((i % 9) as f32, (i % 7) as f32 * 0.01, 0.0);
                    [c - Vec3::Y * 0.1, c + Vec3::Y * 0.1, c + Vec3::Z * 0.1]
                })
                .collect();
            for tris in [random_tris(n, seed), gridded(n, seed), on_boundaries] {
                let sah = BinnedSah::new(4, 2);
                let mut results = Vec::new();
                for parallel in [false, true] {
                    let mut prims = prims_of(&tris);
                    let info = NodeInfo::of(&prims, parallel);
                    let (mid, left, right) = sah
                        .split(&mut prims, &info, 0, parallel)
                        .unwrap_or_else(|| panic!("n {n}: a split"));
                    assert!(mid > 0 && mid < n, "n {n}");
                    assert_eq!(left, NodeInfo::of(&prims[..mid], false), "n {n}");
                    assert_eq!(right, NodeInfo::of(&prims[mid..], false), "n {n}");
                    results.push(prims.iter().map(PrimRef::index).collect::<Vec<_>>());
                }
                assert_eq!(
                    results[0], results[1],
                    "n {n}: parallel binning changed the split"
                );
            }
        }
    }

    #[test]
    fn leaf_tests_count_blocks() {
        for block in [1usize, 2, 3, 4, 8] {
            let sah = BinnedSah::new(4, block);
            for n in 0..100u32 {
                assert_eq!(sah.tests(n), n.div_ceil(block as u32) as f32, "{block} {n}");
            }
            for k in 0..=SWEEP_MAX {
                assert_eq!(sah.sweep_tests[k], sah.tests(k as u32));
            }
        }
    }
}
