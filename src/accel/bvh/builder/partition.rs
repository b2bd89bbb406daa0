//! The SAH builder's partition of a node's references at its chosen plane,
//! with the same result, element for element, as a Hoare partition (both
//! ends scan, misplaced pairs swap), so trees, leaf orders and images are
//! those the Hoare partition made.
//!
//! Why not Hoare itself: its two scans branch on every reference, and the
//! branch turns wherever a run of references on one side ends, which in a
//! node's mixed order is every few references (mispredicted each time). Here
//! a first pass writes each reference's side as a bit (no branch on the
//! side) and takes each side's centroid bounds; a second visits only the
//! misplaced references, by bit scans over those words, and swaps them in
//! Hoare's pairs: the k-th reference of the right side found among the first
//! `mid` places (counting up) with the k-th of the left side found among the
//! others (counting down), `mid` being the left side's size.
//!
//! Both passes split into independent pieces (the words of fixed chunks;
//! ranges of the pairs), which [`partition`] runs in parallel for large
//! nodes: the result is the same for any thread count.

use arrayvec::ArrayVec;
use glam::{BVec4A, Vec4};
use rayon::prelude::*;

use crate::accel::bvh::params::PARALLEL_REDUCE_CUTOFF;
use crate::accel::bvh::prim::{Box4, PrimRef};

/// References per mask word.
const WORD: usize = 64;

/// Words per chunk of the parallel first pass.
const CHUNK_WORDS: usize = PARALLEL_REDUCE_CUTOFF / 4 / WORD;

/// Words kept on the stack: every node below the parallel cut-off.
const STACK_WORDS: usize = PARALLEL_REDUCE_CUTOFF / WORD;

/// Which side of the plane a reference goes to: left when its doubled
/// centroid `c` has `(c - lo) * scale < plane` on `axis`, the binning's own
/// arithmetic (so the bins' side boxes are the sides' boxes).
#[derive(Clone, Copy)]
pub(super) struct Plane {
    pub axis: usize,
    pub lo: Vec4,
    pub scale: Vec4,
    pub plane: f32,
}

/// The first pass's result over some references besides their side bits
/// (bit `k` of word `w`: reference `64 w + k`, set when left): how many go
/// left, and each side's centroid bounds.
struct Sides {
    left: usize,
    left_centroids: Box4,
    right_centroids: Box4,
}

impl Sides {
    const EMPTY: Sides = Sides {
        left: 0,
        left_centroids: Box4::EMPTY,
        right_centroids: Box4::EMPTY,
    };

    /// What [`partition`] returns.
    fn result(&self) -> (usize, Box4, Box4) {
        (self.left, self.left_centroids, self.right_centroids)
    }

    fn add(mut self, other: Sides) -> Sides {
        self.left += other.left;
        self.left_centroids = self.left_centroids.union(other.left_centroids);
        self.right_centroids = self.right_centroids.union(other.right_centroids);
        self
    }
}

/// Appends the side bits of `prims` to `words`, a word per 64 references;
/// returns the count and bounds.
fn mark(prims: &[PrimRef], plane: &Plane, words: &mut impl Extend<u64>) -> Sides {
    let planes = Vec4::splat(plane.plane);
    let none = Vec4::INFINITY;
    let (mut ll, mut lh) = (Vec4::INFINITY, Vec4::NEG_INFINITY);
    let (mut rl, mut rh) = (Vec4::INFINITY, Vec4::NEG_INFINITY);
    let mut left = 0;
    for refs in prims.chunks(WORD) {
        let mut bits = 0u64;
        for (k, p) in refs.iter().enumerate() {
            let c = p.centroid2();
            let below = ((c - plane.lo) * plane.scale).cmplt(planes).bitmask();
            let is_left = (below >> plane.axis) & 1 == 1;
            bits |= (is_left as u64) << k;
            // Each side's bounds take the centroid, the other's +-infinity:
            // selects, not a branch.
            let side = BVec4A::splat(is_left);
            ll = ll.min(Vec4::select(side, c, none));
            lh = lh.max(Vec4::select(side, c, -none));
            rl = rl.min(Vec4::select(side, none, c));
            rh = rh.max(Vec4::select(side, -none, c));
        }
        left += bits.count_ones() as usize;
        words.extend(std::iter::once(bits));
    }
    Sides {
        left,
        left_centroids: Box4 { lo: ll, hi: lh },
        right_centroids: Box4 { lo: rl, hi: rh },
    }
}

/// Bits `0..k` of a word (`k` clamped to `0..=64`).
fn below(k: isize) -> u64 {
    match k {
        ..=0 => 0,
        64.. => !0,
        _ => (1u64 << k) - 1,
    }
}

/// The misplaced references among the first `mid` (right-side bits clear)
/// in word `w`.
fn low_misplaced(words: &[u64], w: usize, mid: usize) -> u64 {
    !words[w] & below(mid as isize - (w * WORD) as isize)
}

/// The misplaced references from `mid` on (left-side bits set) in word `w`.
fn high_misplaced(words: &[u64], w: usize, mid: usize) -> u64 {
    words[w] & !below(mid as isize - (w * WORD) as isize)
}

/// Swaps the pairs from rank `first` on, `count` of them: `low` holds the
/// references from index `low_base` of the node, `high` those from
/// `high_base`, and every pair of these ranks lies in them.
fn swap_pairs(
    low: &mut [PrimRef],
    low_base: usize,
    high: &mut [PrimRef],
    high_base: usize,
    words: &[u64],
    mid: usize,
    (first, count): (usize, usize),
) {
    if count == 0 {
        return;
    }
    let (mut lw, mut lbits) = nth_low(words, mid, first);
    let (mut hw, mut hbits) = nth_high(words, mid, first);
    for _ in 0..count {
        while lbits == 0 {
            lw += 1;
            lbits = low_misplaced(words, lw, mid);
        }
        while hbits == 0 {
            hw -= 1;
            hbits = high_misplaced(words, hw, mid);
        }
        let a = lw * WORD + lbits.trailing_zeros() as usize;
        lbits &= lbits - 1;
        let top = WORD - 1 - hbits.leading_zeros() as usize;
        hbits &= !(1 << top);
        let b = hw * WORD + top;
        std::mem::swap(&mut low[a - low_base], &mut high[b - high_base]);
    }
}

/// The word holding the `rank`-th misplaced reference below `mid` (from 0,
/// counting up), and that word's misplaced bits from it on.
fn nth_low(words: &[u64], mid: usize, rank: usize) -> (usize, u64) {
    let mut left = rank;
    let mut w = 0;
    loop {
        let bits = low_misplaced(words, w, mid);
        let n = bits.count_ones() as usize;
        if left < n {
            return (w, drop_lowest(bits, left));
        }
        left -= n;
        w += 1;
    }
}

/// The word holding the `rank`-th misplaced reference from `mid` on (from 0,
/// counting down from the end), and that word's misplaced bits from it down.
fn nth_high(words: &[u64], mid: usize, rank: usize) -> (usize, u64) {
    let mut left = rank;
    let mut w = words.len() - 1;
    loop {
        let bits = high_misplaced(words, w, mid);
        let n = bits.count_ones() as usize;
        if left < n {
            let mut bits = bits;
            for _ in 0..left {
                bits &= !(1 << (WORD - 1 - bits.leading_zeros() as usize));
            }
            return (w, bits);
        }
        left -= n;
        w -= 1;
    }
}

/// `bits` without its `k` lowest set bits.
fn drop_lowest(mut bits: u64, k: usize) -> u64 {
    for _ in 0..k {
        bits &= bits - 1;
    }
    bits
}

/// Reorders `prims` so that those left of `plane` come first, exactly as a
/// Hoare partition would; returns how many go left and each side's centroid
/// bounds. In parallel for large nodes when `parallel`; the same result
/// either way.
pub(super) fn partition(
    prims: &mut [PrimRef],
    plane: &Plane,
    parallel: bool,
) -> (usize, Box4, Box4) {
    let n = prims.len();
    if parallel && n >= PARALLEL_REDUCE_CUTOFF {
        let marked: Vec<(ArrayVec<u64, CHUNK_WORDS>, Sides)> = prims
            .par_chunks(CHUNK_WORDS * WORD)
            .map(|refs| {
                let mut words = ArrayVec::new();
                let sides = mark(refs, plane, &mut words);
                (words, sides)
            })
            .collect();
        let mut words = Vec::with_capacity(n.div_ceil(WORD));
        let mut sides = Sides::EMPTY;
        for (w, s) in marked {
            words.extend(w);
            sides = sides.add(s);
        }
        swap_all(prims, &words, sides.left, true);
        sides.result()
    } else if n <= STACK_WORDS * WORD {
        serial(prims, plane, ArrayVec::<u64, STACK_WORDS>::new())
    } else {
        serial(prims, plane, Vec::with_capacity(n.div_ceil(WORD)))
    }
}

/// [`partition`] on the calling thread, the side bits kept in `words`.
fn serial(
    prims: &mut [PrimRef],
    plane: &Plane,
    mut words: impl Extend<u64> + AsRef<[u64]>,
) -> (usize, Box4, Box4) {
    let sides = mark(prims, plane, &mut words);
    swap_all(prims, words.as_ref(), sides.left, false);
    sides.result()
}

/// Swaps every misplaced pair of `prims` as marked in `words` (`mid` going
/// left); in two halves on two threads when `parallel` and there are many.
fn swap_all(prims: &mut [PrimRef], words: &[u64], mid: usize, parallel: bool) {
    let pairs: usize = (0..mid.div_ceil(WORD))
        .map(|w| low_misplaced(words, w, mid).count_ones() as usize)
        .sum();
    let (low, high) = prims.split_at_mut(mid);
    if parallel && pairs >= CHUNK_WORDS * WORD {
        // The first half of the pairs lies below the second half on the low
        // side and above it on the high side: split both there.
        let half = pairs / 2;
        let (lw, lbits) = nth_low(words, mid, half);
        let low_split = lw * WORD + lbits.trailing_zeros() as usize;
        let (hw, hbits) = nth_high(words, mid, half);
        let high_split = hw * WORD + WORD - hbits.leading_zeros() as usize;
        let (low_a, low_b) = low.split_at_mut(low_split);
        let (high_b, high_a) = high.split_at_mut(high_split - mid);
        rayon::join(
            || swap_pairs(low_a, 0, high_a, high_split, words, mid, (0, half)),
            || {
                swap_pairs(
                    low_b,
                    low_split,
                    high_b,
                    mid,
                    words,
                    mid,
                    (half, pairs - half),
                )
            },
        );
    } else {
        swap_pairs(low, 0, high, mid, words, mid, (0, pairs));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::geometry::Aabb;

    /// The Hoare partition this module must match, as the SAH builder had it.
    fn hoare(prims: &mut [PrimRef], plane: &Plane) -> (usize, Box4, Box4) {
        let left = |c: Vec4| {
            (c[plane.axis] - plane.lo[plane.axis]) * plane.scale[plane.axis] < plane.plane
        };
        let (mut lc, mut rc) = (Box4::EMPTY, Box4::EMPTY);
        let (mut i, mut j) = (0, prims.len());
        loop {
            while i < j && left(prims[i].centroid2()) {
                lc.grow(prims[i].centroid2());
                i += 1;
            }
            while i < j && !left(prims[j - 1].centroid2()) {
                rc.grow(prims[j - 1].centroid2());
                j -= 1;
            }
            if i >= j {
                break;
            }
            prims.swap(i, j - 1);
            lc.grow(prims[i].centroid2());
            rc.grow(prims[j - 1].centroid2());
            i += 1;
            j -= 1;
        }
        (i, lc, rc)
    }

    #[test]
    fn partitions_as_hoare_does_serial_or_parallel() {
        let mut cases = 0;
        for (n, seed) in [
            (0, 1),
            (1, 2),
            (2, 3),
            (17, 4),
            (63, 5),
            (64, 6),
            (65, 7),
            (1000, 8),
            (8191, 9),
            (8192, 10),
            (20_000, 11),
            (70_001, 12),
        ] {
            let tris = random_tris(n, seed);
            let prims: Vec<PrimRef> = tris
                .iter()
                .enumerate()
                .map(|(i, t)| PrimRef::new(&Aabb::from_points(t), i as u32))
                .collect();
            // Planes across the range, all going one way or the other at
            // the ends; the scale of 0 on one axis puts everything in bin 0.
            let info = crate::accel::bvh::prim::NodeInfo::of(&prims, false);
            let extent = info.centroids.hi - info.centroids.lo;
            for axis in 0..3 {
                for plane in [0.0, 1.0, 3.0, 7.5, 16.0, 31.0, 32.0] {
                    let mut scale = Vec4::ZERO;
                    if axis != 2 || plane != 7.5 {
                        scale[axis] = 32.0 / extent[axis].max(1e-30);
                    }
                    let plane = Plane {
                        axis,
                        lo: info.centroids.lo,
                        scale,
                        plane,
                    };
                    let mut want = prims.clone();
                    let want_result = hoare(&mut want, &plane);
                    for parallel in [false, true] {
                        let mut got = prims.clone();
                        let got_result = partition(&mut got, &plane, parallel);
                        let what = format!(
                            "n {n} axis {axis} plane {} parallel {parallel}",
                            plane.plane
                        );
                        assert_eq!(got_result.0, want_result.0, "{what}");
                        assert_eq!(got, want, "{what}");
                        assert_eq!(got_result.1, want_result.1, "{what}");
                        assert_eq!(got_result.2, want_result.2, "{what}");
                        cases += 1;
                    }
                }
            }
        }
        assert!(cases > 400);
    }
}
