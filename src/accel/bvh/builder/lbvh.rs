//! The linear BVH (Lauterbach et al. 2009; the split rule of Karras 2012):
//! the low rung of the quality ladder, built for speed, not for the SAH.
//!
//! Each triangle's box centre is quantised to a 1024^3 grid over the scene's
//! centres and interleaved into a 30-bit Morton code; the triangles are
//! sorted by (code, scene index) with a stable radix sort (on two or more
//! threads, a run per thread, the runs then merged). A node's range of
//! sorted triangles then splits where the highest bit in which its first
//! and last codes differ changes (a binary search), so every split is a
//! plane of the grid, found without looking at boxes; equal codes split at
//! the middle. This file makes the codes, the sort and the binary tree
//! ([`build`]: boxes are unions of the children's, made on the way back up),
//! which serves the binary and optimised trees; the wide trees the renderer
//! traverses are made with the same splits by [`super::lbvh_wide`].
//!
//! Determinism: the sort is by code then index, and the splits depend only
//! on the sorted codes, so the tree is the same for any thread count.

use glam::{UVec4, Vec4};

use super::topdown::prim_refs;
use crate::accel::bvh::node::{padded, Skeleton, UNUSED};
use crate::accel::bvh::params::LBVH_PARALLEL_CUTOFF;
use crate::accel::bvh::prim::{Box4, PrimRef, Triangles};
use crate::accel::bvh::simd::bin_indices;
use crate::accel::bvh::Node;
use crate::geometry::Aabb;

/// Bits of the Morton code per axis (30 in all: the depth of the code's
/// splits stays below `MAX_SPLIT_DEPTH`, so the tree fits the traversal
/// stack like every builder's).
const BITS: u32 = 10;

/// Bits sorted per radix pass: 3 passes over the 30 bits.
const RADIX_BITS: u32 = 10;

/// The LBVH of `triangles` with leaves of at most `max_leaf`, its
/// independent halves built in parallel when `parallel`.
pub(crate) fn build<T: Triangles + ?Sized>(
    triangles: &T,
    max_leaf: usize,
    parallel: bool,
) -> Skeleton {
    let prims = sorted_refs(triangles, parallel);
    if prims.is_empty() {
        return Skeleton::default();
    }
    let count = 2 * prims.len() - 1;
    let mut nodes = crate::os::huge_vec(count);
    nodes.resize(count, UNUSED);
    let ctx = Ctx {
        max_leaf: max_leaf.max(1),
        parallel,
    };
    ctx.recurse(&prims, 0, 0, &mut nodes);
    Skeleton {
        nodes,
        tri_ids: prims.iter().map(PrimRef::index).collect(),
    }
}

/// The references of `triangles` sorted by (Morton code, index), each
/// carrying its code ([`PrimRef::key`]): what [`build`] splits.
fn sorted_refs<T: Triangles + ?Sized>(triangles: &T, parallel: bool) -> Vec<PrimRef> {
    sorted_by_code(prim_refs(triangles, parallel), parallel)
}

/// Every triangle of `triangles` as `code << 32 | index`, sorted: the same
/// codes and order as [`build`]'s references, made from the triangles
/// without references (what the wide build, [`super::lbvh_wide`], reads).
/// Each triangle is read once, for its box's centre, in parallel when
/// `parallel`.
pub(super) fn sorted_keys<T: Triangles + ?Sized>(triangles: &T, parallel: bool) -> Vec<u64> {
    let centres = collect(triangles.count(), parallel, |i| {
        let b = Aabb::from_points(&triangles.get(i));
        b.min.extend(0.0) + b.max.extend(0.0)
    });
    keys(centres.len(), |i| centres[i], parallel)
}

/// `f` of `0..n`, in parallel when `parallel`.
fn collect<V: Send>(n: usize, parallel: bool, f: impl Fn(usize) -> V + Sync + Send) -> Vec<V> {
    use rayon::prelude::*;
    if parallel {
        (0..n).into_par_iter().map(f).collect()
    } else {
        (0..n).map(f).collect()
    }
}

/// The sorted `code << 32 | index` of `n` doubled centres (`centre(i)`, w
/// lane 0), on the grid over their bounds.
fn keys(n: usize, centre: impl Fn(usize) -> Vec4 + Sync + Send, parallel: bool) -> Vec<u64> {
    let mut bounds = Box4::EMPTY;
    for i in 0..n {
        bounds.grow(centre(i));
    }
    let (lo, scale) = grid(&bounds);
    let keys = collect(n, parallel, |i| {
        (morton(centre(i), lo, scale) as u64) << 32 | i as u64
    });
    sort_keys(keys, parallel)
}

/// The 30-bit Morton code of a doubled centre `c2` on the grid of
/// `lo`-based cells `scale` (cells per unit, per axis). The three cells are
/// made and spread on all lanes at once, with no branch: with a scalar
/// float-to-integer cast per axis (each a saturating conversion, branching
/// on its range) the codes took 0.47 ms of a one-thread engine build (110k
/// triangles), 0.35 ms this way.
#[inline]
fn morton(c2: Vec4, lo: Vec4, scale: Vec4) -> u32 {
    // Below the grid (never, but for rounding) is cell 0, beyond it the
    // last cell.
    let q = ((c2 - lo) * scale).max(Vec4::ZERO);
    let v = spread(UVec4::from(bin_indices(q, (1 << BITS) - 1)));
    v.x << 2 | v.y << 1 | v.z
}

/// The low 10 bits of each lane of `v` moved to every third bit.
#[inline]
fn spread(v: UVec4) -> UVec4 {
    let mut x = v & UVec4::splat(0x3ff);
    x = (x | x << 16) & UVec4::splat(0x0300_00ff);
    x = (x | x << 8) & UVec4::splat(0x0300_f00f);
    x = (x | x << 4) & UVec4::splat(0x030c_30c3);
    (x | x << 2) & UVec4::splat(0x0924_9249)
}

/// The Morton grid over the doubled centres in `centres`: its corner, and
/// cells per unit along each axis (none along an axis where all centres
/// coincide).
fn grid(centres: &Box4) -> (Vec4, Vec4) {
    let lo = centres.lo;
    let extent = centres.hi - lo;
    let cells = (1u32 << BITS) as f32;
    let scale = Vec4::select(
        extent.cmpgt(Vec4::ZERO),
        Vec4::splat(cells) / extent,
        Vec4::ZERO,
    );
    (lo, scale)
}

/// `prims` sorted by (Morton code, index), each carrying its code
/// ([`PrimRef::key`]: what the splits read).
fn sorted_by_code(prims: Vec<PrimRef>, parallel: bool) -> Vec<PrimRef> {
    use rayon::prelude::*;
    let keys = keys(prims.len(), |i| prims[i].centroid2(), parallel);
    let gather = |&k: &u64| prims[k as u32 as usize].with_key((k >> 32) as u32);
    if parallel {
        keys.par_iter().map(gather).collect()
    } else {
        keys.iter().map(gather).collect()
    }
}

/// `keys` (`code << 32 | position`, every key distinct) sorted: by code,
/// equal codes in position order. In parallel when `parallel`, the keys are
/// cut into one run per thread (rounded up to a power of two, runs of at
/// least [`SORT_RUN_MIN`] keys), each run is radix-sorted on its own thread
/// and sorted runs are merged pairwise, each merge itself split in two. The
/// keys are distinct, so every cut gives the serial sort's order.
fn sort_keys(mut keys: Vec<u64>, parallel: bool) -> Vec<u64> {
    let mut spare = vec![0u64; keys.len()];
    let mut depth = 0;
    if parallel {
        while 1 << depth < rayon::current_num_threads() && keys.len() >> (depth + 1) >= SORT_RUN_MIN
        {
            depth += 1;
        }
    }
    if sort_between(&mut keys, &mut spare, depth) {
        spare
    } else {
        keys
    }
}

/// Shortest run of keys sorted on a thread of its own by [`sort_keys`].
const SORT_RUN_MIN: usize = 16 * 1024;

/// Sorts the keys in `a`, with `b` (as long) for scratch, as `2^depth`
/// runs merged pairwise; returns whether the sorted keys ended in `b`.
fn sort_between(a: &mut [u64], b: &mut [u64], depth: u32) -> bool {
    if depth == 0 {
        return radix_sort(a, b);
    }
    let mid = a.len() / 2;
    let (a_lo, a_hi) = a.split_at_mut(mid);
    let (b_lo, b_hi) = b.split_at_mut(mid);
    let (in_b, _) = rayon::join(
        || sort_between(a_lo, b_lo, depth - 1),
        || sort_between(a_hi, b_hi, depth - 1),
    );
    // Both halves took the same number of passes, so they ended in the
    // same buffer; merge them into the other.
    if in_b {
        let (lo, hi) = b.split_at(mid);
        merge(lo, hi, a);
        false
    } else {
        let (lo, hi) = a.split_at(mid);
        merge(lo, hi, b);
        true
    }
}

/// Shortest merge split between two threads.
const MERGE_SPLIT_MIN: usize = 8 * 1024;

/// `lo` and `hi` (each sorted, no key in both) merged into `out`, in two
/// halves on two threads down to [`MERGE_SPLIT_MIN`] keys.
fn merge(lo: &[u64], hi: &[u64], out: &mut [u64]) {
    if out.len() < MERGE_SPLIT_MIN {
        let (mut i, mut j) = (0, 0);
        for o in out {
            // Take from `lo` while `hi` is spent or `lo`'s key is smaller.
            if j == hi.len() || (i < lo.len() && lo[i] < hi[j]) {
                *o = lo[i];
                i += 1;
            } else {
                *o = hi[j];
                j += 1;
            }
        }
        return;
    }
    // The first `half` keys of the merge: the `i` smallest of `lo` and the
    // `half - i` smallest of `hi`, `i` found by bisection.
    let half = out.len() / 2;
    let (mut first, mut last) = (half.saturating_sub(hi.len()), half.min(lo.len()));
    while first < last {
        let i = (first + last) / 2;
        if lo[i] < hi[half - i - 1] {
            first = i + 1;
        } else {
            last = i;
        }
    }
    let (out_lo, out_hi) = out.split_at_mut(half);
    rayon::join(
        || merge(&lo[..first], &hi[..half - first], out_lo),
        || merge(&lo[first..], &hi[half - first..], out_hi),
    );
}

/// `keys` sorted by code, equal codes in their order in `keys`: a stable
/// least-significant-digit radix sort of the code's bits, passing the keys
/// back and forth between `keys` and `spare` (as long). Returns whether the
/// sorted keys ended in `spare`.
fn radix_sort(keys: &mut [u64], spare: &mut [u64]) -> bool {
    let buckets = 1usize << RADIX_BITS;
    let passes = (3 * BITS).div_ceil(RADIX_BITS);
    let (mut from, mut to) = (keys, spare);
    for pass in 0..passes {
        let shift = 32 + pass * RADIX_BITS;
        let digit = |k: u64| (k >> shift) as usize & (buckets - 1);
        let mut starts = vec![0usize; buckets];
        for &k in from.iter() {
            starts[digit(k)] += 1;
        }
        let mut sum = 0;
        for s in &mut starts {
            let c = *s;
            *s = sum;
            sum += c;
        }
        for &k in from.iter() {
            let d = digit(k);
            to[starts[d]] = k;
            starts[d] += 1;
        }
        std::mem::swap(&mut from, &mut to);
    }
    passes % 2 == 1
}

/// Where a range of references sorted by code ([`PrimRef::key`]) splits:
/// at the first code with the highest differing bit of the first and last
/// set, or in the middle when all are equal. Always in `1..prims.len()` for
/// two or more references.
fn split_point(prims: &[PrimRef]) -> usize {
    split_by_code(prims, PrimRef::key)
}

/// Where a range of `items` sorted by `code` splits ([`split_point`]).
#[inline]
pub(super) fn split_by_code<K>(items: &[K], code: impl Fn(&K) -> u32) -> usize {
    let (first, last) = (code(&items[0]), code(&items[items.len() - 1]));
    if first == last {
        return items.len() / 2;
    }
    let bit = 31 - (first ^ last).leading_zeros();
    // Every code in the range shares the bits above `bit`, so those with
    // it set form the tail.
    items.partition_point(|k| code(k) & (1 << bit) == 0)
}

struct Ctx {
    max_leaf: usize,
    parallel: bool,
}

impl Ctx {
    /// Builds the subtree of `prims` (leaf slots from `start` on) into
    /// `nodes`, its `2 * prims.len() - 1` slots, the first at index `base`
    /// of the whole array; returns the subtree's (unpadded) box.
    fn recurse(&self, prims: &[PrimRef], start: usize, base: usize, nodes: &mut [Node]) -> Box4 {
        let n = prims.len();
        if n <= self.max_leaf {
            let b = prims
                .iter()
                .fold(Box4::EMPTY, |b, p| b.union(Box4 { lo: p.lo, hi: p.hi }));
            let p = padded(b.to_aabb());
            nodes[0] = Node {
                min: p.min,
                offset: start as u32,
                max: p.max,
                count: n as u32,
            };
            return b;
        }
        let mid = split_point(prims);
        let right_base = base + 2 * mid;
        let (lp, rp) = prims.split_at(mid);
        let (first, rest) = nodes.split_at_mut(1);
        let (ln, rn) = rest.split_at_mut(2 * mid - 1);
        let mut left = move || self.recurse(lp, start, base + 1, ln);
        let mut right = move || self.recurse(rp, start + mid, right_base, rn);
        let (lb, rb) = if self.parallel && n >= LBVH_PARALLEL_CUTOFF {
            rayon::join(left, right)
        } else {
            (left(), right())
        };
        let b = lb.union(rb);
        let p = padded(b.to_aabb());
        first[0] = Node {
            min: p.min,
            offset: right_base as u32,
            max: p.max,
            count: 0,
        };
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::test_fixtures::random_tris;

    #[test]
    fn morton_codes_interleave_x_y_z_from_the_top() {
        assert_eq!(
            spread(UVec4::new(0b11, 0x3ff, 0, 1)),
            UVec4::new(0b1001, 0x0924_9249, 0, 1)
        );
        let lo = Vec4::ZERO;
        let scale = Vec4::splat(1.0);
        // x's top cell bit is the code's top bit.
        assert_eq!(morton(Vec4::new(512.0, 0.0, 0.0, 0.0), lo, scale), 1 << 29);
        assert_eq!(morton(Vec4::new(0.0, 512.0, 0.0, 0.0), lo, scale), 1 << 28);
        assert_eq!(morton(Vec4::new(0.0, 0.0, 1.0, 0.0), lo, scale), 1);
        // Outside the grid clamps to its last cell.
        assert_eq!(
            morton(Vec4::splat(5000.0), lo, scale),
            (1 << 30) - 1,
            "clamped"
        );
    }

    /// The code as a scalar cast per axis and a bit loop would make it.
    fn morton_by_bits(c2: Vec4, lo: Vec4, scale: Vec4) -> u32 {
        let q = ((c2 - lo) * scale).max(Vec4::ZERO);
        let cells = [q.x, q.y, q.z].map(|v| (v as u32).min((1 << BITS) - 1));
        let mut code = 0;
        for bit in (0..BITS).rev() {
            for cell in cells {
                code = code << 1 | (cell >> bit & 1);
            }
        }
        code
    }

    #[test]
    fn morton_codes_match_a_bit_by_bit_interleave() {
        let mut rng = crate::rng::Rng::for_pixel(3, 1, 4);
        let lo = Vec4::new(-1.5, 2.0, -1e3, 0.0);
        let scale = Vec4::new(300.0, 1.0, 0.25, 0.0);
        for k in 0..200_000 {
            // Inside the grid, on cell boundaries, and beyond both ends.
            let v = |rng: &mut crate::rng::Rng| match k % 4 {
                0 => rng.next_f32() * 4000.0 - 1000.0,
                1 => (rng.next_f32() * 1100.0).floor(),
                2 => -rng.next_f32() * 1e9,
                _ => rng.next_f32() * 1e12,
            };
            let cells = Vec4::new(v(&mut rng), v(&mut rng), v(&mut rng), 0.0);
            // The centre whose cells those are, near enough: both codes
            // are taken from it.
            let c2 = cells / scale.max(Vec4::splat(1e-30)) + lo;
            let c2 = c2 * Vec4::new(1.0, 1.0, 1.0, 0.0);
            assert_eq!(morton(c2, lo, scale), morton_by_bits(c2, lo, scale), "{c2}");
        }
        // An axis of no extent (scale 0) is cell 0.
        let flat = Vec4::new(1.0, 0.0, 1.0, 0.0);
        assert_eq!(
            morton(Vec4::splat(7.0), Vec4::ZERO, flat),
            morton_by_bits(Vec4::splat(7.0), Vec4::ZERO, flat)
        );
    }

    #[test]
    fn splits_fall_where_the_highest_differing_bit_changes() {
        let at = |codes: &[u32]| {
            let point = crate::geometry::Aabb::from_points(&[glam::Vec3::ZERO; 3]);
            let prims: Vec<PrimRef> = (0..codes.len() as u32)
                .map(|i| PrimRef::new(&point, i).with_key(codes[i as usize]))
                .collect();
            split_point(&prims)
        };
        assert_eq!(at(&[0b000, 0b001, 0b100, 0b101]), 2);
        assert_eq!(at(&[0b000, 0b010, 0b011, 0b011, 0b100]), 4);
        assert_eq!(at(&[7, 7, 7]), 1);
        assert_eq!(at(&[0, 1]), 1);
    }

    #[test]
    fn sort_orders_by_code_then_index_and_keeps_every_triangle() {
        let tris = random_tris(5000, 3);
        for parallel in [false, true] {
            let prims = prim_refs(&tris, parallel);
            let info = crate::accel::bvh::prim::NodeInfo::of(&prims, parallel);
            let sorted = sorted_by_code(prims.clone(), parallel);
            assert_eq!(sorted.len(), prims.len());
            for w in sorted.windows(2) {
                let (a, b) = (w[0], w[1]);
                assert!(a.key() < b.key() || (a.key() == b.key() && a.index() < b.index()));
            }
            // Each carries its own Morton code.
            let (lo, scale) = grid(&info.centroids);
            for p in &sorted {
                assert_eq!(p.key(), morton(p.centroid2(), lo, scale));
            }
            let mut ids: Vec<u32> = sorted.iter().map(PrimRef::index).collect();
            ids.sort();
            assert_eq!(ids, (0..5000).collect::<Vec<u32>>());
        }
    }

    #[test]
    fn the_parallel_sort_gives_the_serial_order() {
        // Codes from a few hundred values, so that many keys share a code
        // and the order within a code (the index) is tested too; lengths
        // around the run and merge cut-offs, odd ones included.
        for n in [1, 2, 3, SORT_RUN_MIN * 2 - 1, SORT_RUN_MIN * 2 + 1, 100_003] {
            let mut x = n as u64 + 1;
            let keys: Vec<u64> = (0..n as u64)
                .map(|i| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    (x % 300) << 32 | i
                })
                .collect();
            let mut expected = keys.clone();
            expected.sort_unstable();
            assert_eq!(sort_keys(keys.clone(), false), expected, "serial, n = {n}");
            for threads in [2, 3, 4] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let sorted = pool.install(|| sort_keys(keys.clone(), true));
                assert_eq!(sorted, expected, "{threads} threads, n = {n}");
            }
        }
    }

    #[test]
    fn merges_split_where_the_first_half_of_the_output_ends() {
        // Interleaved, one run after the other, and runs of unequal length.
        let evens: Vec<u64> = (0..20_000).map(|i| 2 * i).collect();
        let odds: Vec<u64> = (0..20_000).map(|i| 2 * i + 1).collect();
        let low: Vec<u64> = (0..5_000).collect();
        let high: Vec<u64> = (5_000..40_000).collect();
        for (a, b) in [(&evens, &odds), (&low, &high), (&high, &low), (&odds, &low)] {
            let mut out = vec![0; a.len() + b.len()];
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            pool.install(|| merge(a, b, &mut out));
            let mut expected: Vec<u64> = a.iter().chain(b).copied().collect();
            expected.sort_unstable();
            assert_eq!(out, expected);
        }
    }

    #[test]
    fn every_node_box_holds_its_triangles_and_leaves_respect_the_limit() {
        let tris = random_tris(3000, 8);
        let s = build(&tris, 4, false).compact();
        assert_eq!(s, build(&tris, 4, true).compact(), "parallel build differs");
        let mut stack = vec![(0usize, None::<crate::geometry::Aabb>)];
        let mut seen = 0;
        while let Some((i, parent)) = stack.pop() {
            let n = s.nodes[i];
            if let Some(p) = parent {
                assert!(p.contains(&n.bounds()), "child outside its parent");
            }
            if n.is_leaf() {
                assert!(n.count <= 4);
                for slot in n.offset..n.offset + n.count {
                    let t = tris[s.tri_ids[slot as usize] as usize];
                    assert!(n.bounds().contains(&crate::geometry::Aabb::from_points(&t)));
                    seen += 1;
                }
            } else {
                stack.push((i + 1, Some(n.bounds())));
                stack.push((n.offset as usize, Some(n.bounds())));
            }
        }
        assert_eq!(seen, tris.len());
    }
}
