//! The stack of the wide trees' single-ray closest-hit walk
//! (`wide::traverse`, also the packets' last rays), and how a node's hit
//! children go onto it: all but the nearest, ordered so that the nearest of
//! them is popped first.
//!
//! Two ways to order them, with the same effect on what is visited:
//! - [`ChildStack::push_by_distance`]: find the nearest lane, then insert
//!   each other child into its place (the scalar way, any width). Its
//!   branches follow the distances, which incoherent rays make random.
//! - [`network_push`], a sorting network under the AVX2 kernel (for three
//!   hit children or more, where the stack has room for eight): each lane's
//!   key is its entry distance's bits with the lane in the lowest three
//!   (entry distances are never negative, so their bits sort as the floats
//!   do), sorted in six compare-exchange steps, and stored as a whole at the
//!   top of the stack: no branch on the distances. Measured on recorded rays
//!   (one thread, Intel Xeon with AVX-512, fastest of 16 passes alternating
//!   which goes first), over the scalar way's time: grass:2000's diffuse
//!   single rays 0.85-0.88 and its primary ones 0.90, its diffuse packets of
//!   16 0.92; forest:10's diffuse rays 0.97, cornell-water's 0.99; Sponza's
//!   primary single rays, two node visits a ray, 1.00-1.04 (their best path
//!   is packets: 1.00). docs/results.md, "A node's hit children sorted
//!   without branches".
//!
//! The order decides how soon a ray finds its hit, never which hit it
//! returns: the closest is chosen by `Hit::is_closer_than` whichever order
//! the leaves come in, and an entry is skipped only when it starts beyond
//! the cut (`CULL_SLACK` above the best hit). The network's keys drop the
//! lowest three bits of the distance, which only rounds a pending entry's
//! distance down (an entry kept that the exact distance might skip), and
//! breaks ties within eight ulps by lane as the scalar way breaks exact ones
//! (the highest lane first).
//!
//! `unsafe` here: the stack's entries are `MaybeUninit` (clearing a stack of
//! 64 entries per ray cost 8% of the time, measured), read only below its
//! length; and the AVX2 intrinsics, behind the [`Avx2`] proof.

use std::mem::MaybeUninit;

use super::leaf::bits;
#[cfg(target_arch = "x86_64")]
use super::simd::Avx2;
use super::simd::NodeKernel;
use super::wide::WideNode;

/// Pending children and their entry distances, at most `S`.
pub struct ChildStack<const S: usize> {
    child: [MaybeUninit<u32>; S],
    near: [MaybeUninit<f32>; S],
    /// Entries `..len` are initialised (every write below stores an entry
    /// before `len` passes it).
    len: usize,
}

impl<const S: usize> ChildStack<S> {
    #[inline(always)]
    pub fn new() -> Self {
        ChildStack {
            child: [const { MaybeUninit::uninit() }; S],
            near: [const { MaybeUninit::uninit() }; S],
            len: 0,
        }
    }

    #[inline(always)]
    pub fn len(&self) -> usize {
        self.len
    }

    /// The top entry, removed.
    #[inline(always)]
    pub fn pop(&mut self) -> Option<(u32, f32)> {
        let top = self.len.checked_sub(1)?;
        self.len = top;
        // SAFETY: entries below the old length are initialised (the field's
        // invariant), and `top` is below it.
        Some(unsafe { (self.child[top].assume_init(), self.near[top].assume_init()) })
    }

    /// The entry at `i`, which must be below the length.
    #[inline(always)]
    fn entry(&self, i: usize) -> (u32, f32) {
        assert!(i < self.len);
        // SAFETY: `i` is below the length (asserted), so initialised.
        unsafe { (self.child[i].assume_init(), self.near[i].assume_init()) }
    }

    /// Writes entry `i` (at most the length: it must stay contiguous).
    #[inline(always)]
    fn set(&mut self, i: usize, (child, near): (u32, f32)) {
        self.child[i] = MaybeUninit::new(child);
        self.near[i] = MaybeUninit::new(near);
    }

    /// The children of the entries from `from` up (for prefetching them).
    #[inline(always)]
    pub fn children_from(&self, from: usize) -> impl Iterator<Item = u32> + '_ {
        (from..self.len).map(|i| self.entry(i).0)
    }

    /// [`Self::push_by_distance`] for exactly two lanes in `mask`: the nearer
    /// (the higher lane of equals, as [`nearest_lane`]) chosen by a select,
    /// not a branch on the distances, which incoherent rays make random.
    /// Single rays with it, over the scalar way's time (recorded rays, one
    /// thread, Intel Xeon): cornell-water, grass:3000, mesh:20000 and
    /// Sponza's view, primary and diffuse, 0.975-1.00.
    #[inline(always)]
    pub fn push_two<const N: usize>(
        &mut self,
        child: &[u32; N],
        mask: u32,
        near: &[f32; N],
    ) -> usize {
        let a = mask.trailing_zeros() as usize;
        let b = (mask & (mask - 1)).trailing_zeros() as usize;
        let take_b = usize::from(near[b] <= near[a]).wrapping_neg();
        let next = a ^ ((a ^ b) & take_b);
        let other = a ^ b ^ next;
        assert!(self.len < S, "traversal stack overflow");
        self.set(self.len, (child[other], near[other]));
        self.len += 1;
        next
    }

    /// Pushes the children of the lanes of `mask` (two or more) but the
    /// nearest, farthest first, so that the nearest of them is on top;
    /// returns the nearest lane ([`nearest_lane`]). The scalar way.
    #[inline(always)]
    pub fn push_by_distance<const N: usize>(
        &mut self,
        child: &[u32; N],
        mask: u32,
        near: &[f32; N],
    ) -> usize {
        let next = nearest_lane(mask, near);
        let base = self.len;
        for lane in bits(mask & !(1 << next)) {
            assert!(self.len < S, "traversal stack overflow");
            let key = near[lane];
            let mut j = self.len;
            while j > base && self.entry(j - 1).1 < key {
                self.set(j, self.entry(j - 1));
                j -= 1;
            }
            self.set(j, (child[lane], key));
            self.len += 1;
        }
        next
    }
}

/// The lane of `mask` (not empty) with the least `near`, the last of
/// equals: the closest-hit traversals, single-ray and packet, visit it next
/// and push the other hit lanes (the sorted push pops the last of equals
/// first; on the engine's primary packets taking the first was 2% slower).
#[inline(always)]
pub(crate) fn nearest_lane(mask: u32, near: &[f32]) -> usize {
    let mut next = mask.trailing_zeros() as usize;
    for lane in bits(mask & (mask - 1)) {
        if near[lane] <= near[next] {
            next = lane;
        }
    }
    next
}

/// Pushes the children of `node`'s lanes in `mask` (two or more, with entry
/// distances `near`) but the nearest onto `stack`, the nearest of them on
/// top, and returns the nearest lane: by [`network_push`] for an 8-wide node
/// under the AVX2 kernel, else the scalar way.
#[inline(always)]
pub fn push_by_distance<K: NodeKernel<N>, const N: usize, const S: usize>(
    kernel: K,
    stack: &mut ChildStack<S>,
    node: &WideNode<N>,
    mask: u32,
    near: &[f32; N],
) -> usize {
    #[cfg(target_arch = "x86_64")]
    if let (Some(avx2), Ok(child), Ok(near)) = (
        kernel.avx2(),
        <&[u32; 8]>::try_from(&node.child[..]),
        <&[f32; 8]>::try_from(&near[..]),
    ) {
        return network_push(avx2, stack, child, mask, near);
    }
    let _ = kernel;
    stack.push_by_distance(&node.child, mask, near)
}

/// [`ChildStack::push_by_distance`] for an 8-wide node, by the sorting
/// network of the module notes for three hit lanes or more (where the stack
/// has room for eight entries; else the scalar way), by
/// [`ChildStack::push_two`] for two.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub fn network_push<const S: usize>(
    avx2: Avx2,
    stack: &mut ChildStack<S>,
    child: &[u32; 8],
    mask: u32,
    near: &[f32; 8],
) -> usize {
    use std::arch::x86_64::*;
    let _ = avx2;
    let hits = mask.count_ones() as usize;
    let at = stack.len;
    if hits == 2 {
        return stack.push_two(child, mask, near);
    }
    if hits < 3 || at + 8 > S {
        return stack.push_by_distance(child, mask, near);
    }
    // SAFETY: `avx2` proves the CPU has AVX2 (see `Avx2::detect`).
    // `near` and `child` are eight 4-byte values behind live references
    // (unaligned loads). The two stores write eight entries from `at`,
    // and `at + 8 <= S` (checked above), so they stay inside the arrays;
    // `MaybeUninit<T>` has `T`'s layout.
    unsafe {
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let hit = _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(mask as i32), bit), bit);
        // Key: the distance's bits (>= +0.0: the kernel's `max` with a
        // tmin >= 0 returns that +0.0 for a -0.0 or NaN entry), 7 - lane
        // in the low three bits (the highest lane first among equals);
        // lanes not hit sort last.
        let seven = _mm256_set1_epi32(7);
        let dist = _mm256_loadu_si256(near.as_ptr().cast());
        let keys = _mm256_or_si256(
            _mm256_and_si256(dist, _mm256_set1_epi32(!7)),
            _mm256_sub_epi32(seven, lane),
        );
        let mut d = _mm256_blendv_epi8(_mm256_set1_epi32(i32::MAX), keys, hit);
        // The nearest lane from a horizontal minimum, ready before the
        // sort: the next node's load waits for it, not for the stack.
        let m = _mm256_min_epi32(d, _mm256_shuffle_epi32::<0xB1>(d));
        let m = _mm256_min_epi32(m, _mm256_shuffle_epi32::<0x4E>(m));
        let m = _mm256_min_epi32(m, _mm256_permute2x128_si256::<1>(m, m));
        let next = 7 - (_mm256_cvtsi256_si32(m) & 7) as usize;
        // Bitonic sort, ascending: each step pairs lane i with i ^ j
        // (j = 1, 2, 1, 4, 2, 1) and the blend's set bits take the pair's
        // maximum.
        macro_rules! step {
            ($partner:expr, $max_lanes:literal) => {{
                let other = $partner;
                d = _mm256_blend_epi32::<$max_lanes>(
                    _mm256_min_epi32(d, other),
                    _mm256_max_epi32(d, other),
                );
            }};
        }
        step!(_mm256_shuffle_epi32::<0xB1>(d), 0x66);
        step!(_mm256_shuffle_epi32::<0x4E>(d), 0x3C);
        step!(_mm256_shuffle_epi32::<0xB1>(d), 0x5A);
        step!(_mm256_permute2x128_si256::<1>(d, d), 0xF0);
        step!(_mm256_shuffle_epi32::<0x4E>(d), 0xCC);
        step!(_mm256_shuffle_epi32::<0xB1>(d), 0xAA);
        // Farthest first: position i takes sorted key hits - 1 - i, so
        // the pushed `hits - 1` entries are the sorted ones but the
        // nearest, which lands above them and is not kept.
        let order = _mm256_and_si256(
            _mm256_sub_epi32(_mm256_set1_epi32(hits as i32 - 1), lane),
            seven,
        );
        let sorted = _mm256_permutevar8x32_epi32(d, order);
        let lanes = _mm256_sub_epi32(seven, _mm256_and_si256(sorted, seven));
        let children =
            _mm256_permutevar8x32_epi32(_mm256_loadu_si256(child.as_ptr().cast()), lanes);
        let dists = _mm256_and_si256(sorted, _mm256_set1_epi32(!7));
        _mm256_storeu_si256(stack.child.as_mut_ptr().add(at).cast(), children);
        _mm256_storeu_si256(stack.near.as_mut_ptr().add(at).cast(), dists);
        // The top entry once more by a scalar store: the next pop (often
        // soon, on short rays) loads it forwarded from this store rather
        // than from part of the vector one (1.07 -> 1.04 of the scalar
        // way's time on Sponza's primary rays, measured).
        let top = _mm256_set1_epi32(hits as i32 - 2);
        let top_child = _mm256_cvtsi256_si32(_mm256_permutevar8x32_epi32(children, top));
        let top_near = _mm256_cvtsi256_si32(_mm256_permutevar8x32_epi32(dists, top));
        stack.child[at + hits - 2] = MaybeUninit::new(top_child as u32);
        stack.near[at + hits - 2] = MaybeUninit::new(f32::from_bits(top_near as u32));
        stack.len = at + hits - 1;
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// What a stack holds, top first.
    fn drain<const S: usize>(stack: &mut ChildStack<S>) -> Vec<(u32, f32)> {
        std::iter::from_fn(|| stack.pop()).collect()
    }

    /// The network pushes what the scalar way pushes, in the same order up
    /// to distances within eight ulps (rounded down to a multiple of eight
    /// ulps), and returns the same nearest lane, for every mask of three
    /// hits or more, with distinct, equal, zero and near-equal distances,
    /// over entries already on the stack; with two hits (`push_two`'s
    /// select), or no room for eight, exactly the scalar way's.
    #[test]
    fn the_network_orders_as_the_scalar_way() {
        let Some(avx2) = Avx2::detect() else {
            eprintln!("no AVX2 on this CPU: the sorting network is not tested");
            return;
        };
        let mut rng = Rng::for_pixel(7, 3, 1);
        let child: [u32; 8] = std::array::from_fn(|i| 100 + i as u32);
        for case in 0..20_000 {
            let mask = (rng.next_f32() * 256.0) as u32 & 0xFF;
            if mask.count_ones() < 2 {
                continue;
            }
            let near: [f32; 8] = std::array::from_fn(|_| match case % 4 {
                0 => rng.next_f32() * 10.0,
                1 => (rng.next_f32() * 3.0).floor(),
                2 => 1.0 + (rng.next_f32() * 4.0).floor() * f32::EPSILON,
                _ => [0.0, 2.5, 1e30][(rng.next_f32() * 3.0) as usize % 3],
            });
            let below = (case % 5) as u32;
            let mut scalar = ChildStack::<16>::new();
            let mut simd = ChildStack::<16>::new();
            for s in [&mut scalar, &mut simd] {
                for i in 0..below {
                    s.set(i as usize, (i, 50.0));
                    s.len += 1;
                }
            }
            let want = scalar.push_by_distance(&child, mask, &near);
            let got = network_push(avx2, &mut simd, &child, mask, &near);
            let label = format!("mask {mask:08b} near {near:?}");
            let bucket = |lane: usize| near[lane].to_bits() >> 3;
            assert!(
                got == want || bucket(got) == bucket(want),
                "nearest lane {got}, not {want}: {label}"
            );
            let (want, got) = (drain(&mut scalar), drain(&mut simd));
            assert_eq!(want.len(), got.len(), "{label}");
            for ((wc, wn), (gc, gn)) in want.iter().zip(&got) {
                if *wc >= 100 {
                    // A pushed child: its distance rounded down to 8 ulps
                    // by the network (three hits or more), else exact.
                    let rounded = if mask.count_ones() >= 3 { !7 } else { !0 };
                    assert_eq!(gn.to_bits(), wn.to_bits() & rounded, "{label}");
                    let (wl, gl) = ((wc - 100) as usize, (gc - 100) as usize);
                    let close = bucket(wl) == bucket(gl);
                    assert!(wc == gc || close, "{label}: {want:?} against {got:?}");
                } else {
                    assert_eq!((wc, wn.to_bits()), (gc, gn.to_bits()), "{label}");
                }
            }
        }
        // No room for eight more: the scalar way, exactly.
        let mut full = ChildStack::<10>::new();
        for i in 0..5 {
            full.set(i, (i as u32, 9.0));
            full.len += 1;
        }
        let near = [3.0, 1.0, 2.0, 0.5, 4.0, 8.0, 6.0, 7.0];
        assert_eq!(network_push(avx2, &mut full, &child, 0b1111, &near), 3);
        assert_eq!(
            drain(&mut full)[..3],
            [(101, 1.0), (102, 2.0), (100, 3.0)],
            "the scalar way's order"
        );
    }
}
