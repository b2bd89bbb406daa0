//! The packet kernels of the 8-wide tree's packet traversal
//! (`wide::packet`): how up to [`PACKET`] rays are tested against a node's
//! eight child boxes and against a leaf block's triangles.
//!
//! - [`PerRay`]: each ray with the single-ray kernels (any node kernel, any
//!   triangle test), lane by lane; the portable path.
//! - [`Avx2Packet`]: the eight rays in the eight lanes of AVX registers, one
//!   child box or one triangle at a time (Moller-Trumbore). Every lane runs
//!   the single-ray kernels' operations in the same order (the slab test of
//!   [`super::simd`] with the near plane chosen by the ray's sign, the
//!   Moller-Trumbore of [`super::leaf::intersect4`]), no fused multiply-add,
//!   so each ray gets the single-ray results bit for bit (tested).
//!
//! - [`Avx512Packet`]: sixteen rays in the lanes of AVX-512 registers, the
//!   same operations in the same order, compares into mask registers
//!   (`--query packet16`, where the CPU has AVX-512F).
//!
//! Both SIMD kernels lay a packet out by lanes with in-register transposes
//! (the rays are `repr(C)`), find its valid rays with a few vector compares,
//! and, when the rays agree in sign, bound them by a [`Frustum`] that skips
//! with one 8-lane test per node the children no ray can enter (Embree's
//! coherent-packet idea, made exact here: tested to keep every child a ray's
//! own test enters). On the coherent rays of a render most children are
//! skipped (84% on cornell-water's primary rays).
//!
//! `unsafe` here is the AVX2 and AVX-512 intrinsics, behind the [`Avx2`]
//! and [`Avx512`] proofs as in [`super::simd`].

use std::marker::PhantomData;

use arrayvec::ArrayVec;

use super::leaf::{BlockTest, Ray4, Tri4, EMPTY_ID};
use super::params::{CULL_SLACK, SLAB_SLACK};
use super::simd::{Avx2, Avx512, NodeKernel, WideRay};
use super::wide::{WideNode, EMPTY};
use crate::geometry::{safe_reciprocal, Hit, Ray, RECIPROCAL_MAX};

/// Rays per packet of the AVX2 kernel (`--query packet8`).
pub const PACKET: usize = 8;

/// Rays per packet of the AVX-512 kernel (`--query packet16`).
pub const PACKET16: usize = 16;

/// The margin (relative to the determinant) by which every lane's `u` must
/// lie outside [0, 1] for [`Avx2Packet`]'s triangle test to stop before its
/// division: far above the division's rounding (2^-23), so a lane it stops
/// is one the full test rejects.
const U_MARGIN: f32 = 1.0 / (1 << 20) as f32;

/// The bits of `mask`, lowest first.
#[inline(always)]
pub fn bits(mut mask: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let bit = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            bit
        })
    })
}

/// Bounds on a packet's rays that let one 8-lane test per node skip the
/// children no ray of the packet can enter (the frustum test of Embree's
/// coherent packet traversal, here made exact for raylab's slab test).
///
/// Each ray's slab distance on an axis is `round(round(plane - o) * inv)`.
/// Rounding is monotone, so with `o` in `[o_lo, o_hi]` and `inv` in
/// `[inv_lo, inv_hi]` (one sign for all rays) the near plane's distance is at
/// least `min(d * inv_lo, d * inv_hi)` with `d = plane - o_hi` (`o_lo` when
/// the axis runs negative), both products rounded, and the far plane's at
/// most the `max` of the products with the other origin bound. A child whose
/// least possible entry exceeds its greatest possible exit (after
/// [`SLAB_GROW`](crate::geometry::SLAB_GROW) and the rays' `tmax`, as each
/// ray's own test) is missed by every ray's own test, so skipping it changes
/// no answer; every other child still gets the per-ray test.
#[derive(Clone, Copy, Debug, Default)]
pub struct Frustum {
    /// Per axis, the row of the near plane ([`WideRay::near`]'s choice).
    near_row: [usize; 3],
    /// Per axis, the origin bound the near and the far plane's distances
    /// are taken from.
    o_near: [f32; 3],
    o_far: [f32; 3],
    /// Per axis, the least and greatest reciprocal direction.
    inv_lo: [f32; 3],
    inv_hi: [f32; 3],
    /// The least node-test `tmin` of the rays, and a bound on every `tmax`
    /// a node test may be given for them (see [`Frustum::of_lanes`]).
    tmin: f32,
    tmax: f32,
}

impl Frustum {
    /// The frustum of rays whose near planes are the rows `rows` (they agree
    /// in sign on every axis), from their least (`lo`) and greatest (`hi`)
    /// values per component in a ray's memory order (origin in lanes 0-2,
    /// direction 3-5, `tmin` 6, `tmax` 7) and the reciprocals of those two
    /// vectors, as a kernel gathers them while it lays the packet out.
    ///
    /// The reciprocal directions' bounds are the reciprocals of the
    /// directions' bounds, swapped: `1 / d` and its clamp fall as `d` rises
    /// within one sign, and so does their rounding. The traversals give node
    /// tests a ray's `tmax` widened by [`SLAB_SLACK`] (any hit) or a cut at
    /// most its `tmax` widened by [`CULL_SLACK`] (closest hit, the cut only
    /// shrinking as hits are found): the greater of the two widenings of the
    /// greatest `tmax` bounds both, rounding being monotone.
    #[inline(always)]
    fn of_lanes(
        rows: [usize; 3],
        lo: &[f32],
        hi: &[f32],
        inv_of_lo: &[f32],
        inv_of_hi: &[f32],
    ) -> Frustum {
        let tmax = hi[7];
        let mut f = Frustum {
            near_row: rows,
            tmin: lo[6] * (1.0 - SLAB_SLACK),
            tmax: (tmax * (1.0 + CULL_SLACK)).max(tmax * (1.0 + SLAB_SLACK)),
            ..Frustum::default()
        };
        for (a, row) in rows.iter().enumerate() {
            // The near plane is the minimum (an even row) when the axis runs
            // positive; its distance is least from the greatest origin.
            (f.o_near[a], f.o_far[a]) = if row.is_multiple_of(2) {
                (hi[a], lo[a])
            } else {
                (lo[a], hi[a])
            };
            (f.inv_lo[a], f.inv_hi[a]) = (inv_of_hi[3 + a], inv_of_lo[3 + a]);
        }
        f
    }

    /// The children of `node` that some ray of the packet may enter, a bit
    /// per lane, and per lane the least entry distance any ray of the
    /// packet can have (at least the rays' least `tmin`).
    ///
    /// # Safety
    /// The CPU must run AVX (inlined into the AVX2 and AVX-512 kernels).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn children(&self, node: &WideNode<8>) -> (u32, [f32; 8]) {
        use crate::geometry::SLAB_GROW;
        use std::arch::x86_64::*;
        // SAFETY: the caller runs AVX; every load reads a row of eight f32
        // of `node` (unaligned load).
        unsafe {
            let b = &node.bounds;
            // Macros, not closures: a closure is compiled without AVX.
            macro_rules! distance {
                ($row:expr, $a:expr, $o:expr, $pick:ident) => {{
                    let d = _mm256_sub_ps(_mm256_loadu_ps(b[$row].as_ptr()), _mm256_set1_ps($o));
                    $pick(
                        _mm256_mul_ps(d, _mm256_set1_ps(self.inv_lo[$a])),
                        _mm256_mul_ps(d, _mm256_set1_ps(self.inv_hi[$a])),
                    )
                }};
            }
            macro_rules! near {
                ($a:expr) => {
                    distance!(self.near_row[$a], $a, self.o_near[$a], _mm256_min_ps)
                };
            }
            macro_rules! far {
                ($a:expr) => {
                    distance!(self.near_row[$a] ^ 1, $a, self.o_far[$a], _mm256_max_ps)
                };
            }
            let entry = _mm256_max_ps(
                _mm256_max_ps(_mm256_max_ps(near!(0), near!(1)), near!(2)),
                _mm256_set1_ps(self.tmin),
            );
            let exit = _mm256_min_ps(
                _mm256_mul_ps(
                    _mm256_min_ps(_mm256_min_ps(far!(0), far!(1)), far!(2)),
                    _mm256_set1_ps(SLAB_GROW),
                ),
                _mm256_set1_ps(self.tmax),
            );
            // Skipped only where entry > exit for sure (a NaN keeps the child).
            let mut out = [0f32; 8];
            _mm256_storeu_ps(out.as_mut_ptr(), entry);
            (
                !(_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(entry, exit)) as u32) & 0xFF,
                out,
            )
        }
    }
}

/// The lanes of `node` that hold a child (unused ones hold [`EMPTY`]), a
/// bit per lane, in one compare.
///
/// # Safety
/// The CPU must run AVX2 (inlined into the AVX2 and AVX-512 kernels).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn used_lanes(node: &WideNode<8>) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: the caller runs AVX2; the load reads the node's eight child
    // indices, 32-byte aligned (`WideNode` is aligned to 32 and `child`
    // follows six 32-byte rows).
    unsafe {
        let empty = _mm256_cmpeq_epi32(
            _mm256_load_si256(node.child.as_ptr() as *const __m256i),
            _mm256_set1_epi32(EMPTY as i32),
        );
        !(_mm256_movemask_ps(_mm256_castsi256_ps(empty)) as u32) & 0xFF
    }
}

/// The lanes of bits `mask` (bit `r` for lane `r`) as an AVX2 lane mask:
/// all ones where the bit is set.
///
/// # Safety
/// The CPU must run AVX2 (inlined into the AVX2 kernel).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn lanes_of(mask: u32) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    // SAFETY: the caller runs AVX2; register operations only.
    unsafe {
        let lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        _mm256_cmpgt_epi32(
            _mm256_and_si256(_mm256_set1_epi32(mask as i32), lane_bits),
            _mm256_setzero_si256(),
        )
    }
}

/// What a node test reports for a packet: per child lane, the rays whose
/// box test hit it and a lower bound on their entry distances (their least
/// entry distance, or a coherent packet's frustum bound); and the hit lanes.
/// The traversal orders children and culls popped ones by `near`: a lower
/// bound keeps every culling decision safe.
pub struct NodeHits {
    pub rays: [u32; 8],
    pub near: [f32; 8],
    pub lanes: u32,
}

/// A packet's closest hits so far, by lanes (so that the AVX-512 kernel
/// keeps them in registers through a leaf): ray `r` has no hit while
/// `tri[r]` is [`EMPTY_ID`] (no scene triangle has that index), and then
/// `t[r]` is infinite, so any hit is closer.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub struct PacketHits<const R: usize> {
    pub t: [f32; R],
    pub u: [f32; R],
    pub v: [f32; R],
    pub tri: [u32; R],
}

impl<const R: usize> PacketHits<R> {
    /// What a ray without a hit holds.
    const NONE: Hit = Hit {
        t: f32::INFINITY,
        u: 0.0,
        v: 0.0,
        tri: EMPTY_ID,
    };

    /// No ray has a hit.
    pub fn none() -> Self {
        let n = Self::NONE;
        PacketHits {
            t: [n.t; R],
            u: [n.u; R],
            v: [n.v; R],
            tri: [n.tri; R],
        }
    }

    /// Ray `r`'s lanes as a hit ([`Self::NONE`] when it has none).
    #[inline(always)]
    fn lanes(&self, r: usize) -> Hit {
        Hit {
            t: self.t[r],
            u: self.u[r],
            v: self.v[r],
            tri: self.tri[r],
        }
    }

    /// Ray `r`'s hit.
    #[inline(always)]
    pub fn get(&self, r: usize) -> Option<Hit> {
        (self.tri[r] != EMPTY_ID).then(|| self.lanes(r))
    }

    /// Sets ray `r`'s hit.
    #[inline(always)]
    pub fn set(&mut self, r: usize, hit: Option<Hit>) {
        let hit = hit.unwrap_or(Self::NONE);
        (self.t[r], self.u[r], self.v[r], self.tri[r]) = (hit.t, hit.u, hit.v, hit.tri);
    }

    /// Keeps `hit` for ray `r` if it beats the ray's hit by
    /// [`Hit::is_closer_than`] (any hit beats [`Self::NONE`]: its `t` is
    /// infinite); returns whether it did.
    #[inline(always)]
    pub fn offer(&mut self, r: usize, hit: Hit) -> bool {
        let closer = hit.is_closer_than(&self.lanes(r));
        if closer {
            self.set(r, Some(hit));
        }
        closer
    }
}

/// Tests of a packet of up to `R` rays against nodes and leaf blocks.
pub trait PacketKernel<const R: usize>: Copy {
    /// The packet prepared for the tests.
    type Rays;
    /// The packet prepared, and its valid rays ([`Ray::is_valid`]) as a bit
    /// per ray.
    fn prepare(self, rays: &[Ray]) -> (Self::Rays, u32);
    /// Whether the packet's rays agree in sign on every axis (the SIMD
    /// kernels then bound them by a [`Frustum`]); the portable kernel says
    /// yes, so its packets keep the one switch threshold.
    fn coherent(rays: &Self::Rays) -> bool;
    /// The box test of every ray of `active` against every child of `node`,
    /// ray `r` within `(its tmin, tmax[r])`; the entry distance bounds only
    /// when `NEAR` (the any-hit traversal neither sorts nor culls by them).
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        rays: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
    ) -> NodeHits;
    /// Closest-hit test of the rays of `active` against the lanes `in_leaf` of
    /// `block`: a ray whose hit beats its hit in `hits` (by
    /// [`Hit::is_closer_than`], hits with `t` below `tmax[r]` only) gets it.
    /// Returns the rays whose hit changed.
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        rays: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
        hits: &mut PacketHits<R>,
    ) -> u32;
    /// The rays of `active` that hit a lane `in_leaf` of `block` within their
    /// segment.
    fn leaf_any(self, block: &Tri4, in_leaf: u32, rays: &Self::Rays, active: u32) -> u32;
    /// For each ray of `changed` that has a hit in `hits`: `tmax[r]` becomes
    /// the float after its `t` (triangles are then tested below it: a hit at
    /// the same `t` with a lower index still wins) and `cut[r]` its `t`
    /// widened by [`CULL_SLACK`] (boxes entered beyond it are culled).
    #[inline(always)]
    fn tighten(self, hits: &PacketHits<R>, changed: u32, tmax: &mut [f32; R], cut: &mut [f32; R]) {
        for r in bits(changed) {
            if let Some(hit) = hits.get(r) {
                tmax[r] = hit.t.next_up();
                cut[r] = hit.t * (1.0 + CULL_SLACK);
            }
        }
    }
    /// The rays whose `cut` is at least `near`, a bit per ray: which rays of
    /// a popped stack entry may still find a closer hit in it.
    #[inline(always)]
    fn reach(self, near: f32, cut: &[f32; R]) -> u32 {
        let mut mask = 0;
        for (r, &c) in cut.iter().enumerate() {
            mask |= ((near <= c) as u32) << r;
        }
        mask
    }
}

/// Floats per [`Ray`] (`repr(C)`: origin, direction, tmin, tmax).
const RAY_FLOATS: usize = 8;
const _: () = assert!(std::mem::size_of::<Ray>() == RAY_FLOATS * 4);

/// The near plane's row per axis ([`WideRay::near`]'s choice) shared by the
/// `n` rays of a packet, from `positive[a]` (bit `r` set when ray `r`'s
/// reciprocal direction on axis `a` is >= 0); `None` when the rays differ in
/// sign on some axis, or there are none.
#[inline(always)]
fn shared_near_rows(positive: [u32; 3], n: usize) -> Option<[usize; 3]> {
    let lanes = (1u32 << n) - 1;
    let agree = positive
        .iter()
        .all(|&m| m & lanes == 0 || m & lanes == lanes);
    // Bit a set when axis a runs negative.
    let negative = (0..3).fold(0, |s, a| s | ((positive[a] & 1 == 0) as usize) << a);
    (agree && n > 0).then_some([
        negative & 1,
        2 + (negative >> 1 & 1),
        4 + (negative >> 2 & 1),
    ])
}

/// Lane indices for `_mm512_permutex2var_ps` (0-15 from the first source,
/// 16-31 from the second) of each round of [`transpose_16x8`]: lane `j` of
/// the result takes the lane the expression gives for `j` (a constant).
macro_rules! permutation {
    (|$j:ident| $pick:expr) => {{
        let mut idx = [0i32; 16];
        let mut $j = 0;
        while $j < 16 {
            idx[$j] = ($pick) as i32;
            $j += 1;
        }
        idx
    }};
}

/// Sixteen rays by components: from `pairs[k]`, rays `2k` and `2k + 1` as
/// laid out in memory (component `c` of ray `2k + j` in lane `8j + c`), to
/// one register per component `c` with ray `r` in lane `r`. Three rounds of
/// two-source permutes, each halving the components and doubling the rays a
/// register holds.
///
/// # Safety
/// The CPU must run AVX-512F.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn transpose_16x8(pairs: &[std::arch::x86_64::__m512; 8]) -> [std::arch::x86_64::__m512; 8] {
    use std::arch::x86_64::*;
    // Round 1, rays 4g..4g + 4, half h of the components: lane 4c + r holds
    // component 4h + c of ray 4g + r.
    const A: [[i32; 16]; 2] = [
        permutation!(|j| (j % 4 / 2) * 16 + (j % 2) * 8 + j / 4),
        permutation!(|j| (j % 4 / 2) * 16 + (j % 2) * 8 + 4 + j / 4),
    ];
    // Round 2, rays 8s..8s + 8, components 4h + 2q, 4h + 2q + 1: lane 8i + r
    // holds component 4h + 2q + i of ray 8s + r.
    const B: [[i32; 16]; 2] = [
        permutation!(|j| (j % 8 / 4) * 16 + 4 * (j / 8) + j % 4),
        permutation!(|j| (j % 8 / 4) * 16 + 4 * (2 + j / 8) + j % 4),
    ];
    // Round 3, all sixteen rays of one component: lane r.
    const C: [[i32; 16]; 2] = [
        permutation!(|j| (j / 8) * 16 + j % 8),
        permutation!(|j| (j / 8) * 16 + 8 + j % 8),
    ];
    // SAFETY: the caller runs AVX-512F; the index tables are read whole.
    unsafe {
        macro_rules! permute {
            ($a:expr, $idx:expr, $b:expr) => {
                _mm512_permutex2var_ps($a, _mm512_loadu_si512($idx.as_ptr() as *const _), $b)
            };
        }
        // a[g][h]
        let mut a = [[_mm512_setzero_ps(); 2]; 4];
        for g in 0..4 {
            for h in 0..2 {
                a[g][h] = permute!(pairs[2 * g], A[h], pairs[2 * g + 1]);
            }
        }
        // b[s][h][q]
        let mut b = [[[_mm512_setzero_ps(); 2]; 2]; 2];
        for s in 0..2 {
            for h in 0..2 {
                for q in 0..2 {
                    b[s][h][q] = permute!(a[2 * s][h], B[q], a[2 * s + 1][h]);
                }
            }
        }
        let mut rows = [_mm512_setzero_ps(); 8];
        for h in 0..2 {
            for q in 0..2 {
                for i in 0..2 {
                    rows[4 * h + 2 * q + i] = permute!(b[0][h][q], C[i], b[1][h][q]);
                }
            }
        }
        rows
    }
}

/// Eight rays by components: from `by_ray[r]`, ray `r` as laid out in
/// memory (eight f32), to one register per component with ray `r` in lane
/// `r` (the usual unpack, shuffle and lane-swap rounds).
///
/// # Safety
/// The CPU must run AVX.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn transpose_8x8(by_ray: &[std::arch::x86_64::__m256; 8]) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    // SAFETY: the caller runs AVX; register operations only.
    unsafe {
        let r = by_ray;
        // Rays 2i, 2i + 1 interleaved: components 0, 1, 4, 5 and 2, 3, 6, 7.
        let mut t = [_mm256_setzero_ps(); 8];
        for i in 0..4 {
            t[2 * i] = _mm256_unpacklo_ps(r[2 * i], r[2 * i + 1]);
            t[2 * i + 1] = _mm256_unpackhi_ps(r[2 * i], r[2 * i + 1]);
        }
        // Rays 4g..4g + 4 of components c and c + 4 in each 128-bit half.
        let mut u = [_mm256_setzero_ps(); 8];
        for g in 0..2 {
            let (lo, hi) = (4 * g, 4 * g + 2);
            u[4 * g] = _mm256_shuffle_ps::<0x44>(t[lo], t[hi]);
            u[4 * g + 1] = _mm256_shuffle_ps::<0xEE>(t[lo], t[hi]);
            u[4 * g + 2] = _mm256_shuffle_ps::<0x44>(t[lo + 1], t[hi + 1]);
            u[4 * g + 3] = _mm256_shuffle_ps::<0xEE>(t[lo + 1], t[hi + 1]);
        }
        // Halves joined: component c from the low halves, c + 4 from the high.
        let mut rows = [_mm256_setzero_ps(); 8];
        for c in 0..4 {
            rows[c] = _mm256_permute2f128_ps::<0x20>(u[c], u[4 + c]);
            rows[c + 4] = _mm256_permute2f128_ps::<0x31>(u[c], u[4 + c]);
        }
        rows
    }
}

/// Each ray with the single-ray node kernel `K` and block test `T`.
pub struct PerRay<K, T> {
    kernel: K,
    _test: PhantomData<T>,
}

impl<K: Copy, T> Clone for PerRay<K, T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<K: Copy, T> Copy for PerRay<K, T> {}

impl<K, T> PerRay<K, T> {
    pub fn new(kernel: K) -> Self {
        PerRay {
            kernel,
            _test: PhantomData,
        }
    }
}

/// One ray of a [`PerRay`] packet, prepared for the single-ray tests.
pub struct Lane<P> {
    ray: Ray,
    prepared: P,
    ray4: Ray4,
    wray: WideRay,
    /// The node kernel's `tmin` (the ray's, widened by [`SLAB_SLACK`]).
    tmin: f32,
}

impl<K: NodeKernel<8>, T: BlockTest, const R: usize> PacketKernel<R> for PerRay<K, T> {
    type Rays = ArrayVec<Lane<T::Prepared>, R>;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> (Self::Rays, u32) {
        let valid = rays
            .iter()
            .enumerate()
            .fold(0, |v, (r, ray)| v | (ray.is_valid() as u32) << r);
        let lanes = rays
            .iter()
            .map(|ray| Lane {
                ray: *ray,
                prepared: T::prepare(ray),
                ray4: Ray4::new(ray),
                wray: WideRay::new(ray, safe_reciprocal(ray.dir)),
                tmin: ray.tmin * (1.0 - SLAB_SLACK),
            })
            .collect();
        (lanes, valid)
    }

    #[inline(always)]
    fn coherent(_: &Self::Rays) -> bool {
        true
    }

    #[inline(always)]
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        lanes: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
    ) -> NodeHits {
        let mut out = NodeHits {
            rays: [0; 8],
            near: [f32::INFINITY; 8],
            lanes: 0,
        };
        for r in bits(active) {
            let lane = &lanes[r];
            let (hit, entry) = self.kernel.intersect(node, &lane.wray, lane.tmin, tmax[r]);
            out.lanes |= hit;
            for c in bits(hit) {
                out.rays[c] |= 1 << r;
                if NEAR {
                    out.near[c] = out.near[c].min(entry[c]);
                }
            }
        }
        out
    }

    #[inline(always)]
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        lanes: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
        hits: &mut PacketHits<R>,
    ) -> u32 {
        let mut changed = 0;
        for r in bits(active) {
            let lane = &lanes[r];
            let test_ray = Ray {
                tmax: tmax[r],
                ..lane.ray
            };
            let mut found = T::test4(&lane.prepared, &lane.ray4, &test_ray, block);
            found.mask &= in_leaf;
            if let Some(hit) = found.closest(&block.ids) {
                if hits.offer(r, hit) {
                    changed |= 1 << r;
                }
            }
        }
        changed
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, lanes: &Self::Rays, active: u32) -> u32 {
        bits(active)
            .filter(|&r| {
                let lane = &lanes[r];
                T::test4(&lane.prepared, &lane.ray4, &lane.ray, block).mask & in_leaf != 0
            })
            .fold(0, |m, r| m | 1 << r)
    }
}

/// A packet kernel that tests its `R` rays against one triangle of a block
/// at a time, all rays in SIMD lanes ([`Avx2Packet`], [`Avx512Packet`]); its
/// leaf tests are [`leaf_closest_by_lanes`] and [`leaf_any_by_lanes`].
#[cfg(target_arch = "x86_64")]
trait TriangleLanes<const R: usize>: Copy {
    type Rays;
    /// Moller-Trumbore of the rays against lane `i` of `block`: the rays hit
    /// within `(tmin, tmax[r])`, and each ray's t, u and v.
    #[allow(clippy::type_complexity)]
    fn triangle(
        self,
        block: &Tri4,
        i: usize,
        p: &Self::Rays,
        tmax: &[f32; R],
    ) -> (u32, [f32; R], [f32; R], [f32; R]);
}

/// [`PacketKernel::leaf_closest`] one triangle at a time.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn leaf_closest_by_lanes<L: TriangleLanes<R>, const R: usize>(
    lanes: L,
    block: &Tri4,
    in_leaf: u32,
    p: &L::Rays,
    active: u32,
    tmax: &[f32; R],
    hits: &mut PacketHits<R>,
) -> u32 {
    let mut changed = 0;
    let mut tmax = *tmax;
    for i in bits(in_leaf) {
        if block.ids[i] == EMPTY_ID {
            continue;
        }
        let (mut found, t, u, v) = lanes.triangle(block, i, p, &tmax);
        found &= active;
        for r in bits(found) {
            let hit = Hit {
                t: t[r],
                u: u[r],
                v: v[r],
                tri: block.ids[i],
            };
            if hits.offer(r, hit) {
                tmax[r] = hit.t.next_up();
                changed |= 1 << r;
            }
        }
    }
    changed
}

/// [`PacketKernel::leaf_any`] one triangle at a time, each ray within
/// `(tmin, tmax[r])`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn leaf_any_by_lanes<L: TriangleLanes<R>, const R: usize>(
    lanes: L,
    block: &Tri4,
    in_leaf: u32,
    p: &L::Rays,
    tmax: &[f32; R],
    active: u32,
) -> u32 {
    let mut hit = 0;
    for i in bits(in_leaf) {
        if block.ids[i] == EMPTY_ID {
            continue;
        }
        hit |= lanes.triangle(block, i, p, tmax).0 & active & !hit;
        if hit == active {
            break;
        }
    }
    hit
}

/// Eight rays in the lanes of AVX registers, Moller-Trumbore at the leaves.
#[derive(Clone, Copy, Debug)]
pub struct Avx2Packet(pub Avx2);

/// A packet by lanes, for [`Avx2Packet`]; unused lanes hold zeros (never
/// read: every result is masked by the active rays).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
pub struct RaysSoa {
    origin: [[f32; 8]; 3],
    dir: [[f32; 8]; 3],
    inv_dir: [[f32; 8]; 3],
    /// Per axis: all bits set in lanes whose reciprocal direction is >= 0
    /// (the near plane is the box's minimum, as [`WideRay`] chooses it).
    positive: [[u32; 8]; 3],
    /// The near plane's row per axis ([`WideRay::near`]) when every ray of
    /// the packet has the same signs (the usual case for neighbouring rays).
    rows: Option<[usize; 3]>,
    /// The node kernel's `tmin` (widened by [`SLAB_SLACK`]) and the
    /// triangle test's.
    node_tmin: [f32; 8],
    tmin: [f32; 8],
    tmax: [f32; 8],
    /// Bounds on the rays when they agree in sign, to skip the children no
    /// ray can enter.
    frustum: Option<Frustum>,
}

#[cfg(target_arch = "x86_64")]
impl PacketKernel<PACKET> for Avx2Packet {
    type Rays = RaysSoa;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> (RaysSoa, u32) {
        use std::arch::x86_64::*;
        debug_assert!(rays.len() <= PACKET);
        // SAFETY: `self.0` proves AVX2 (see `Avx2::detect`). Each load reads
        // one ray of `rays` whole (`Ray` is `repr(C)`, eight f32); stores
        // write eight f32 or u32 into local arrays. Macros, not closures (see
        // `node`).
        unsafe {
            // Ray r in register r, zero past the packet.
            let mut by_ray = [_mm256_setzero_ps(); PACKET];
            for (reg, ray) in by_ray.iter_mut().zip(rays) {
                *reg = _mm256_loadu_ps(ray as *const Ray as *const f32);
            }
            let [ox, oy, oz, dx, dy, dz, tmin, tmax] = transpose_8x8(&by_ray);
            // Ray::is_valid for the eight lanes (zero lanes are invalid:
            // their direction is zero). Ordered compares fail on NaN.
            let inf = _mm256_set1_ps(f32::INFINITY);
            let zero = _mm256_setzero_ps();
            let sign_bit = _mm256_set1_ps(-0.0);
            // Each compare as a bit per ray, as the AVX-512 kernel's masks.
            macro_rules! bits_of {
                ($cmp:expr) => {
                    _mm256_movemask_ps($cmp) as u32
                };
            }
            macro_rules! finite {
                ($v:expr) => {
                    bits_of!(_mm256_cmp_ps::<_CMP_LT_OQ>(
                        _mm256_andnot_ps(sign_bit, $v),
                        inf
                    ))
                };
            }
            macro_rules! nonzero {
                ($v:expr) => {
                    bits_of!(_mm256_cmp_ps::<_CMP_NEQ_OQ>($v, zero))
                };
            }
            let valid = finite!(ox)
                & finite!(oy)
                & finite!(oz)
                & finite!(dx)
                & finite!(dy)
                & finite!(dz)
                & (nonzero!(dx) | nonzero!(dy) | nonzero!(dz))
                & finite!(tmin)
                & bits_of!(_mm256_cmp_ps::<_CMP_GE_OQ>(tmin, zero))
                & bits_of!(_mm256_cmp_ps::<_CMP_GE_OQ>(tmax, tmin));
            // safe_reciprocal: (1 / d) clamped (see RECIPROCAL_MAX).
            let big = _mm256_set1_ps(RECIPROCAL_MAX);
            macro_rules! inv {
                ($d:expr) => {
                    _mm256_min_ps(
                        _mm256_max_ps(
                            _mm256_div_ps(_mm256_set1_ps(1.0), $d),
                            _mm256_sub_ps(zero, big),
                        ),
                        big,
                    )
                };
            }
            let inv_dir = [inv!(dx), inv!(dy), inv!(dz)];
            let mut positive = [_mm256_setzero_ps(); 3];
            let mut pos_bits = [0u32; 3];
            for a in 0..3 {
                positive[a] = _mm256_cmp_ps::<_CMP_GE_OQ>(inv_dir[a], zero);
                pos_bits[a] = bits_of!(positive[a]);
            }
            let rows = shared_near_rows(pos_bits, rays.len());
            // The valid rays' bounds, component by component.
            let (mut lo, mut hi) = (inf, _mm256_set1_ps(f32::NEG_INFINITY));
            for (r, ray) in by_ray.iter().enumerate() {
                if valid >> r & 1 == 1 {
                    lo = _mm256_min_ps(lo, *ray);
                    hi = _mm256_max_ps(hi, *ray);
                }
            }
            macro_rules! store {
                ($v:expr) => {{
                    let mut out = [0f32; 8];
                    _mm256_storeu_ps(out.as_mut_ptr(), $v);
                    out
                }};
            }
            macro_rules! store_bits {
                ($v:expr) => {{
                    let mut out = [0u32; 8];
                    _mm256_storeu_ps(out.as_mut_ptr() as *mut f32, $v);
                    out
                }};
            }
            // Lanes 3-5: the reciprocals of the directions' bounds.
            let (inv_of_lo, inv_of_hi) = (store!(inv!(lo)), store!(inv!(hi)));
            let (lo, hi) = (store!(lo), store!(hi));
            let frustum = rows
                .filter(|_| valid != 0)
                .map(|rows| Frustum::of_lanes(rows, &lo, &hi, &inv_of_lo, &inv_of_hi));
            (
                RaysSoa {
                    origin: [store!(ox), store!(oy), store!(oz)],
                    dir: [store!(dx), store!(dy), store!(dz)],
                    inv_dir: [store!(inv_dir[0]), store!(inv_dir[1]), store!(inv_dir[2])],
                    positive: [
                        store_bits!(positive[0]),
                        store_bits!(positive[1]),
                        store_bits!(positive[2]),
                    ],
                    rows,
                    node_tmin: store!(_mm256_mul_ps(tmin, _mm256_set1_ps(1.0 - SLAB_SLACK))),
                    tmin: store!(tmin),
                    tmax: store!(tmax),
                    frustum,
                },
                valid,
            )
        }
    }

    #[inline(always)]
    fn coherent(p: &Self::Rays) -> bool {
        p.frustum.is_some()
    }

    #[inline(always)]
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        p: &RaysSoa,
        active: u32,
        tmax: &[f32; 8],
    ) -> NodeHits {
        use crate::geometry::SLAB_GROW;
        use std::arch::x86_64::*;
        let mut out = NodeHits {
            rays: [0; 8],
            near: [f32::INFINITY; 8],
            lanes: 0,
        };
        // SAFETY: `self.0` proves the CPU has AVX2 (see `Avx2::detect`); every
        // load reads eight f32 or u32 from a 32-byte aligned row of `p`
        // (RaysSoa is aligned to 32) or from `tmax` (an unaligned load);
        // `Frustum::children` needs AVX, which AVX2 includes.
        // No closures: a closure is a function of its own, compiled without
        // AVX, into which the intrinsics would not be inlined.
        unsafe {
            macro_rules! row {
                ($row:expr) => {
                    _mm256_load_ps($row.as_ptr() as *const f32)
                };
            }
            let o = [row!(p.origin[0]), row!(p.origin[1]), row!(p.origin[2])];
            let inv = [row!(p.inv_dir[0]), row!(p.inv_dir[1]), row!(p.inv_dir[2])];
            let pos = [
                row!(p.positive[0]),
                row!(p.positive[1]),
                row!(p.positive[2]),
            ];
            let tmin = row!(p.node_tmin);
            let tmax = _mm256_loadu_ps(tmax.as_ptr());
            let grow = _mm256_set1_ps(SLAB_GROW);
            let inf = _mm256_set1_ps(f32::INFINITY);
            let live = _mm256_castsi256_ps(lanes_of(active));
            // As the AVX-512 kernel: a coherent packet's children are
            // ordered by the frustum's least possible entry.
            let (frustum_used, frustum_entry) = match &p.frustum {
                Some(f) => {
                    let (m, entry) = f.children(node);
                    (m, Some(entry))
                }
                None => (0xFF, None),
            };
            let b = &node.bounds;
            // Per axis the single-ray kernel's (plane - origin) * inv with the
            // plane the ray's sign makes near, and the far one: the same row
            // for all rays when they agree in sign (`p.rows`), else both
            // planes computed and each ray's chosen by a blend.
            macro_rules! plane {
                ($row:expr, $a:expr, $c:expr) => {
                    _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(b[$row][$c]), o[$a]), inv[$a])
                };
            }
            // One child: its rays' entry and exit distances from the slab
            // distances of each axis, the box test, the least entry distance.
            macro_rules! child {
                ($c:expr, ($nx:expr, $fx:expr), ($ny:expr, $fy:expr), ($nz:expr, $fz:expr)) => {{
                    let c = $c;
                    let near = _mm256_max_ps(_mm256_max_ps(_mm256_max_ps($nx, $ny), $nz), tmin);
                    let far = _mm256_min_ps(
                        _mm256_mul_ps(_mm256_min_ps(_mm256_min_ps($fx, $fy), $fz), grow),
                        tmax,
                    );
                    let hit = _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far), live);
                    let rays = _mm256_movemask_ps(hit) as u32;
                    if rays != 0 {
                        out.lanes |= 1 << c;
                        out.rays[c] = rays;
                    }
                    if NEAR && rays != 0 {
                        out.near[c] = match &frustum_entry {
                            Some(entry) => entry[c],
                            None => {
                                let m = _mm256_blendv_ps(inf, near, hit);
                                let m = _mm_min_ps(
                                    _mm256_castps256_ps128(m),
                                    _mm256_extractf128_ps::<1>(m),
                                );
                                let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
                                let m = _mm_min_ss(m, _mm_shuffle_ps::<0b01>(m, m));
                                _mm_cvtss_f32(m)
                            }
                        };
                    }
                }};
            }
            let used = used_lanes(node) & frustum_used;
            match p.rows {
                Some([rx, ry, rz]) => {
                    for c in bits(used) {
                        child!(
                            c,
                            (plane!(rx, 0, c), plane!(rx ^ 1, 0, c)),
                            (plane!(ry, 1, c), plane!(ry ^ 1, 1, c)),
                            (plane!(rz, 2, c), plane!(rz ^ 1, 2, c))
                        );
                    }
                }
                None => {
                    macro_rules! blended {
                        ($a:expr, $c:expr) => {{
                            let lo = plane!(2 * $a, $a, $c);
                            let hi = plane!(2 * $a + 1, $a, $c);
                            (
                                _mm256_blendv_ps(hi, lo, pos[$a]),
                                _mm256_blendv_ps(lo, hi, pos[$a]),
                            )
                        }};
                    }
                    for c in bits(used) {
                        let ((nx, fx), (ny, fy), (nz, fz)) =
                            (blended!(0, c), blended!(1, c), blended!(2, c));
                        child!(c, (nx, fx), (ny, fy), (nz, fz));
                    }
                }
            }
        }
        out
    }

    #[inline(always)]
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        p: &RaysSoa,
        active: u32,
        tmax: &[f32; 8],
        hits: &mut PacketHits<8>,
    ) -> u32 {
        leaf_closest_by_lanes(self, block, in_leaf, p, active, tmax, hits)
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &RaysSoa, active: u32) -> u32 {
        leaf_any_by_lanes(self, block, in_leaf, p, &p.tmax, active)
    }

    #[inline(always)]
    fn tighten(
        self,
        hits: &PacketHits<PACKET>,
        changed: u32,
        tmax: &mut [f32; PACKET],
        cut: &mut [f32; PACKET],
    ) {
        use std::arch::x86_64::*;
        // SAFETY: `self.0` proves AVX2; loads and stores read and write the
        // eight lanes of `hits` (aligned), `tmax` and `cut` (unaligned).
        unsafe {
            let in_changed = lanes_of(changed);
            let tri = _mm256_load_si256(hits.tri.as_ptr() as *const __m256i);
            let no_hit = _mm256_cmpeq_epi32(tri, _mm256_set1_epi32(EMPTY_ID as i32));
            let with_hit = _mm256_andnot_si256(no_hit, in_changed);
            let t = _mm256_load_ps(hits.t.as_ptr());
            // As the AVX-512 kernel: a hit's next float up is its bits + 1.
            let next_up = _mm256_castsi256_ps(_mm256_add_epi32(
                _mm256_castps_si256(t),
                _mm256_set1_epi32(1),
            ));
            let widened = _mm256_mul_ps(t, _mm256_set1_ps(1.0 + CULL_SLACK));
            _mm256_maskstore_ps(tmax.as_mut_ptr(), with_hit, next_up);
            _mm256_maskstore_ps(cut.as_mut_ptr(), with_hit, widened);
        }
    }

    #[inline(always)]
    fn reach(self, near: f32, cut: &[f32; PACKET]) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY: `self.0` proves AVX2; the load reads the eight f32 of `cut`.
        unsafe {
            let c = _mm256_loadu_ps(cut.as_ptr());
            _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_set1_ps(near), c)) as u32
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl TriangleLanes<PACKET> for Avx2Packet {
    type Rays = RaysSoa;

    /// Moller-Trumbore of the eight rays against lane `i` of `block`, the
    /// operations of [`super::leaf::intersect4`] in the same order: the rays
    /// hit within `(tmin, tmax[r])`, and each lane's t, u and v.
    #[inline(always)]
    fn triangle(
        self,
        block: &Tri4,
        i: usize,
        p: &RaysSoa,
        tmax: &[f32; 8],
    ) -> (u32, [f32; 8], [f32; 8], [f32; 8]) {
        use std::arch::x86_64::*;
        let [v0, v1, v2] = &block.v;
        // The edges as the SIMD lanes of `intersect4` compute them.
        let e1 = [
            v1[0][i] - v0[0][i],
            v1[1][i] - v0[1][i],
            v1[2][i] - v0[2][i],
        ];
        let e2 = [
            v2[0][i] - v0[0][i],
            v2[1][i] - v0[1][i],
            v2[2][i] - v0[2][i],
        ];
        // SAFETY: `self.0` proves AVX2; loads read 32-byte aligned rows of `p`
        // (RaysSoa is aligned to 32) or eight f32 of `tmax` (unaligned load);
        // stores write eight f32 to local arrays. No closures (see `node`).
        unsafe {
            macro_rules! s {
                ($x:expr) => {
                    _mm256_set1_ps($x)
                };
            }
            macro_rules! add {
                ($a:expr, $b:expr) => {
                    _mm256_add_ps($a, $b)
                };
            }
            macro_rules! sub {
                ($a:expr, $b:expr) => {
                    _mm256_sub_ps($a, $b)
                };
            }
            macro_rules! mul {
                ($a:expr, $b:expr) => {
                    _mm256_mul_ps($a, $b)
                };
            }
            macro_rules! row {
                ($row:expr) => {
                    _mm256_load_ps($row.as_ptr())
                };
            }
            let (ox, oy, oz) = (row!(p.origin[0]), row!(p.origin[1]), row!(p.origin[2]));
            let (dx, dy, dz) = (row!(p.dir[0]), row!(p.dir[1]), row!(p.dir[2]));
            let (e1x, e1y, e1z) = (s!(e1[0]), s!(e1[1]), s!(e1[2]));
            let (e2x, e2y, e2z) = (s!(e2[0]), s!(e2[1]), s!(e2[2]));
            let px = sub!(mul!(dy, e2z), mul!(e2y, dz));
            let py = sub!(mul!(dz, e2x), mul!(e2z, dx));
            let pz = sub!(mul!(dx, e2y), mul!(e2x, dy));
            let det = add!(add!(mul!(e1x, px), mul!(e1y, py)), mul!(e1z, pz));
            let (sx, sy, sz) = (
                sub!(ox, s!(v0[0][i])),
                sub!(oy, s!(v0[1][i])),
                sub!(oz, s!(v0[2][i])),
            );
            let u_num = add!(add!(mul!(sx, px), mul!(sy, py)), mul!(sz, pz));
            // Before dividing: when every lane's u = u_num / det lies
            // outside [0, 1] by more than U_MARGIN (u_num * sign(det) against
            // |det|, exact but for the margin), no rounding of the division
            // below can bring it back, and no lane hits. NaN lanes compare
            // false and go on to the full test, which rejects them.
            let abs_det = _mm256_andnot_ps(s!(-0.0), det);
            let signed = _mm256_xor_ps(u_num, _mm256_and_ps(det, s!(-0.0)));
            let margin = mul!(abs_det, s!(U_MARGIN));
            let outside = _mm256_or_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(signed, sub!(s!(0.0), margin)),
                _mm256_cmp_ps::<_CMP_GT_OQ>(signed, add!(abs_det, margin)),
            );
            if _mm256_movemask_ps(outside) == 0xFF {
                return (0, [0f32; 8], [0f32; 8], [0f32; 8]);
            }
            let inv_det = _mm256_div_ps(s!(1.0), det);
            let u = mul!(u_num, inv_det);
            let qx = sub!(mul!(sy, e1z), mul!(e1y, sz));
            let qy = sub!(mul!(sz, e1x), mul!(e1z, sx));
            let qz = sub!(mul!(sx, e1y), mul!(e1x, sy));
            let v = mul!(
                add!(add!(mul!(dx, qx), mul!(dy, qy)), mul!(dz, qz)),
                inv_det
            );
            let t = mul!(
                add!(add!(mul!(e2x, qx), mul!(e2y, qy)), mul!(e2z, qz)),
                inv_det
            );
            let ok = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GE_OQ>(abs_det, s!(f32::MIN_POSITIVE)),
                        _mm256_cmp_ps::<_CMP_GE_OQ>(u, s!(0.0)),
                    ),
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_LE_OQ>(u, s!(1.0)),
                        _mm256_cmp_ps::<_CMP_GE_OQ>(v, s!(0.0)),
                    ),
                ),
                _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_LE_OQ>(add!(u, v), s!(1.0)),
                        _mm256_cmp_ps::<_CMP_GT_OQ>(t, row!(p.tmin)),
                    ),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_loadu_ps(tmax.as_ptr())),
                ),
            );
            let mask = _mm256_movemask_ps(ok) as u32;
            let (mut ts, mut us, mut vs) = ([0f32; 8], [0f32; 8], [0f32; 8]);
            if mask != 0 {
                _mm256_storeu_ps(ts.as_mut_ptr(), t);
                _mm256_storeu_ps(us.as_mut_ptr(), u);
                _mm256_storeu_ps(vs.as_mut_ptr(), v);
            }
            (mask, ts, us, vs)
        }
    }
}

/// Sixteen rays in the lanes of AVX-512 registers, Moller-Trumbore at the
/// leaves: [`Avx2Packet`]'s operations lane for lane, in the same order,
/// with compares into mask registers, so each ray again gets the single-ray
/// results bit for bit (tested).
#[derive(Clone, Copy, Debug)]
pub struct Avx512Packet(pub Avx512);

/// A packet of 16 by lanes, for [`Avx512Packet`]; unused lanes hold zeros
/// (never read: every result is masked by the active rays).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
pub struct RaysSoa16 {
    origin: [[f32; 16]; 3],
    dir: [[f32; 16]; 3],
    inv_dir: [[f32; 16]; 3],
    node_tmin: [f32; 16],
    tmin: [f32; 16],
    tmax: [f32; 16],
    /// Per axis: bit `r` set when ray `r`'s reciprocal direction is >= 0.
    positive: [u16; 3],
    /// As [`RaysSoa::rows`].
    rows: Option<[usize; 3]>,
    /// As [`RaysSoa::frustum`].
    frustum: Option<Frustum>,
}

#[cfg(target_arch = "x86_64")]
impl PacketKernel<PACKET16> for Avx512Packet {
    type Rays = RaysSoa16;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> (RaysSoa16, u32) {
        use std::arch::x86_64::*;
        debug_assert!(rays.len() <= PACKET16);
        let floats = rays.len() * RAY_FLOATS;
        let base = rays.as_ptr() as *const f32;
        // SAFETY: `self.0` proves AVX-512F (see `Avx512::detect`). Each
        // masked load reads only the floats of `rays` (`Ray` is `repr(C)`,
        // eight f32: RAY_FLOATS) below `floats`; masked-off lanes are neither
        // read nor faulted on, and the pointer is formed with `wrapping_add`.
        // Stores write sixteen f32 into local arrays.
        unsafe {
            // pairs[k]: rays 2k and 2k + 1, component c of ray 2k + j in lane
            // 8j + c; lanes past the packet are zero.
            // (Macros, not closures: a closure is compiled without AVX-512.)
            let mut pairs = [_mm512_setzero_ps(); 8];
            for (k, pair) in pairs.iter_mut().enumerate() {
                let first = 16 * k;
                let avail = floats.saturating_sub(first).min(16) as u32;
                let mask = ((1u64 << avail) - 1) as __mmask16;
                *pair = _mm512_maskz_loadu_ps(mask, base.wrapping_add(first));
            }
            let rows = transpose_16x8(&pairs);
            // Ray::is_valid for the sixteen lanes (zero lanes are invalid:
            // their direction is zero). Ordered compares fail on NaN.
            let inf = _mm512_set1_ps(f32::INFINITY);
            let zero = _mm512_setzero_ps();
            macro_rules! finite {
                ($v:expr) => {
                    _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_abs_ps($v), inf)
                };
            }
            macro_rules! nonzero {
                ($v:expr) => {
                    _mm512_cmp_ps_mask::<_CMP_NEQ_OQ>($v, zero)
                };
            }
            let [ox, oy, oz, dx, dy, dz, tmin, tmax] = rows;
            let valid = finite!(ox)
                & finite!(oy)
                & finite!(oz)
                & finite!(dx)
                & finite!(dy)
                & finite!(dz)
                & (nonzero!(dx) | nonzero!(dy) | nonzero!(dz))
                & finite!(tmin)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(tmin, zero)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(tmax, tmin);
            // safe_reciprocal: (1 / d) clamped, as the AVX2 kernel.
            let big = _mm512_set1_ps(RECIPROCAL_MAX);
            macro_rules! inv {
                ($d:expr) => {
                    _mm512_min_ps(
                        _mm512_max_ps(
                            _mm512_div_ps(_mm512_set1_ps(1.0), $d),
                            _mm512_sub_ps(zero, big),
                        ),
                        big,
                    )
                };
            }
            let (ix, iy, iz) = (inv!(dx), inv!(dy), inv!(dz));
            let positive = [
                _mm512_cmp_ps_mask::<_CMP_GE_OQ>(ix, zero),
                _mm512_cmp_ps_mask::<_CMP_GE_OQ>(iy, zero),
                _mm512_cmp_ps_mask::<_CMP_GE_OQ>(iz, zero),
            ];
            let near_rows = shared_near_rows(positive.map(u32::from), rays.len());
            // The valid rays' bounds, from the pairs: a lane of ray 2k + j
            // joins when that ray is valid.
            let mut lo = inf;
            let mut hi = _mm512_set1_ps(f32::NEG_INFINITY);
            for (k, pair) in pairs.iter().enumerate() {
                let m = (valid >> (2 * k)) & 3;
                let m = (((m & 1) * 0x00FF) | ((m >> 1) * 0xFF00)) as __mmask16;
                lo = _mm512_mask_min_ps(lo, m, lo, *pair);
                hi = _mm512_mask_max_ps(hi, m, hi, *pair);
            }
            // Even and odd rays' halves combined.
            let lo = _mm512_min_ps(lo, _mm512_shuffle_f32x4::<0b0100_1110>(lo, lo));
            let hi = _mm512_max_ps(hi, _mm512_shuffle_f32x4::<0b0100_1110>(hi, hi));
            macro_rules! store {
                ($v:expr) => {{
                    let mut out = [0f32; 16];
                    _mm512_storeu_ps(out.as_mut_ptr(), $v);
                    out
                }};
            }
            // Lanes 3-5: the reciprocals of the directions' bounds.
            let (inv_of_lo, inv_of_hi) = (store!(inv!(lo)), store!(inv!(hi)));
            let (lo, hi) = (store!(lo), store!(hi));
            let frustum = near_rows
                .filter(|_| valid != 0)
                .map(|rows| Frustum::of_lanes(rows, &lo, &hi, &inv_of_lo, &inv_of_hi));
            (
                RaysSoa16 {
                    origin: [store!(ox), store!(oy), store!(oz)],
                    dir: [store!(dx), store!(dy), store!(dz)],
                    inv_dir: [store!(ix), store!(iy), store!(iz)],
                    node_tmin: store!(_mm512_mul_ps(tmin, _mm512_set1_ps(1.0 - SLAB_SLACK))),
                    tmin: store!(tmin),
                    tmax: store!(tmax),
                    positive,
                    rows: near_rows,
                    frustum,
                },
                valid as u32,
            )
        }
    }

    #[inline(always)]
    fn coherent(p: &Self::Rays) -> bool {
        p.frustum.is_some()
    }

    #[inline(always)]
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        p: &RaysSoa16,
        active: u32,
        tmax: &[f32; PACKET16],
    ) -> NodeHits {
        use crate::geometry::SLAB_GROW;
        use std::arch::x86_64::*;
        let mut out = NodeHits {
            rays: [0; 8],
            near: [f32::INFINITY; 8],
            lanes: 0,
        };
        // SAFETY: `self.0` proves the CPU has AVX-512F; every load reads
        // sixteen f32 from a 64-byte aligned row of `p` (RaysSoa16 is aligned
        // to 64) or from `tmax` (an unaligned load); `Frustum::children`
        // and `used_lanes` need AVX and AVX2, which `self.0.avx2` proves. No
        // closures (see the AVX2 kernel).
        unsafe {
            macro_rules! row {
                ($row:expr) => {
                    _mm512_load_ps($row.as_ptr())
                };
            }
            let o = [row!(p.origin[0]), row!(p.origin[1]), row!(p.origin[2])];
            let inv = [row!(p.inv_dir[0]), row!(p.inv_dir[1]), row!(p.inv_dir[2])];
            let tmin = row!(p.node_tmin);
            let tmax = _mm512_loadu_ps(tmax.as_ptr());
            let grow = _mm512_set1_ps(SLAB_GROW);
            let live = active as __mmask16;
            let mut used = used_lanes(node);
            // A coherent packet's children are ordered (and culled when
            // popped) by the frustum's least possible entry (as Embree's
            // coherent packets are): a bound on the rays' own entries, one
            // vector for all children instead of a reduction per child.
            let mut frustum_entry = None;
            if let Some(f) = &p.frustum {
                let (m, entry) = f.children(node);
                used &= m;
                frustum_entry = Some(entry);
            }
            let b = &node.bounds;
            macro_rules! plane {
                ($row:expr, $a:expr, $c:expr) => {
                    _mm512_mul_ps(_mm512_sub_ps(_mm512_set1_ps(b[$row][$c]), o[$a]), inv[$a])
                };
            }
            macro_rules! child {
                ($c:expr, ($nx:expr, $fx:expr), ($ny:expr, $fy:expr), ($nz:expr, $fz:expr)) => {{
                    let c = $c;
                    let near = _mm512_max_ps(_mm512_max_ps(_mm512_max_ps($nx, $ny), $nz), tmin);
                    let far = _mm512_min_ps(
                        _mm512_mul_ps(_mm512_min_ps(_mm512_min_ps($fx, $fy), $fz), grow),
                        tmax,
                    );
                    let hit = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(live, near, far);
                    if hit != 0 {
                        out.lanes |= 1 << c;
                        out.rays[c] = hit as u32;
                        if NEAR {
                            out.near[c] = match &frustum_entry {
                                Some(entry) => entry[c],
                                None => _mm512_mask_reduce_min_ps(hit, near),
                            };
                        }
                    }
                }};
            }
            match p.rows {
                Some([rx, ry, rz]) => {
                    for c in bits(used) {
                        child!(
                            c,
                            (plane!(rx, 0, c), plane!(rx ^ 1, 0, c)),
                            (plane!(ry, 1, c), plane!(ry ^ 1, 1, c)),
                            (plane!(rz, 2, c), plane!(rz ^ 1, 2, c))
                        );
                    }
                }
                None => {
                    macro_rules! blended {
                        ($a:expr, $c:expr) => {{
                            let lo = plane!(2 * $a, $a, $c);
                            let hi = plane!(2 * $a + 1, $a, $c);
                            (
                                _mm512_mask_blend_ps(p.positive[$a], hi, lo),
                                _mm512_mask_blend_ps(p.positive[$a], lo, hi),
                            )
                        }};
                    }
                    for c in bits(used) {
                        let ((nx, fx), (ny, fy), (nz, fz)) =
                            (blended!(0, c), blended!(1, c), blended!(2, c));
                        child!(c, (nx, fx), (ny, fy), (nz, fz));
                    }
                }
            }
        }
        out
    }

    #[inline(always)]
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        p: &RaysSoa16,
        active: u32,
        tmax: &[f32; PACKET16],
        hits: &mut PacketHits<PACKET16>,
    ) -> u32 {
        use std::arch::x86_64::*;
        // As `leaf_closest_by_lanes`, with the hits and the rays' `tmax` in
        // registers through the block: a lane takes a triangle's hit where
        // it is closer by `Hit::is_closer_than` (t below, or equal with a
        // lower index; the index compare unsigned, as `u32`'s), and its
        // `tmax` becomes the hit's `t.next_up()`: for the positive `t` a hit
        // has (above `tmin >= 0`), the next float up is the bits plus one.
        // SAFETY: `self.0` proves AVX-512F; loads and stores read and write
        // sixteen lanes of `hits` (64-byte aligned) or `tmax` (unaligned).
        unsafe {
            let mut limit = _mm512_loadu_ps(tmax.as_ptr());
            let mut best_t = _mm512_load_ps(hits.t.as_ptr());
            let mut best_u = _mm512_load_ps(hits.u.as_ptr());
            let mut best_v = _mm512_load_ps(hits.v.as_ptr());
            let mut best_tri = _mm512_load_si512(hits.tri.as_ptr() as *const _);
            let one = _mm512_set1_epi32(1);
            let mut changed: __mmask16 = 0;
            for i in bits(in_leaf) {
                let id = block.ids[i];
                if id == EMPTY_ID {
                    continue;
                }
                let (ok, t, u, v) = self.triangle16(block, i, p, limit);
                let found = ok & active as __mmask16;
                if found == 0 {
                    continue;
                }
                let idv = _mm512_set1_epi32(id as i32);
                let closer = _mm512_mask_cmp_ps_mask::<_CMP_LT_OQ>(found, t, best_t)
                    | (_mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(found, t, best_t)
                        & _mm512_cmplt_epu32_mask(idv, best_tri));
                best_t = _mm512_mask_mov_ps(best_t, closer, t);
                best_u = _mm512_mask_mov_ps(best_u, closer, u);
                best_v = _mm512_mask_mov_ps(best_v, closer, v);
                best_tri = _mm512_mask_mov_epi32(best_tri, closer, idv);
                let next_up = _mm512_castsi512_ps(_mm512_add_epi32(_mm512_castps_si512(t), one));
                limit = _mm512_mask_mov_ps(limit, closer, next_up);
                changed |= closer;
            }
            if changed != 0 {
                _mm512_store_ps(hits.t.as_mut_ptr(), best_t);
                _mm512_store_ps(hits.u.as_mut_ptr(), best_u);
                _mm512_store_ps(hits.v.as_mut_ptr(), best_v);
                _mm512_store_si512(hits.tri.as_mut_ptr() as *mut _, best_tri);
            }
            changed as u32
        }
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &RaysSoa16, active: u32) -> u32 {
        leaf_any_by_lanes(self, block, in_leaf, p, &p.tmax, active)
    }

    #[inline(always)]
    fn tighten(
        self,
        hits: &PacketHits<PACKET16>,
        changed: u32,
        tmax: &mut [f32; PACKET16],
        cut: &mut [f32; PACKET16],
    ) {
        use std::arch::x86_64::*;
        // SAFETY: `self.0` proves AVX-512F; loads and stores read and write
        // the sixteen lanes of `hits` (64-byte aligned), `tmax` and `cut`
        // (unaligned).
        unsafe {
            // The rays with a hit (`tri` is not EMPTY_ID), as the default.
            let with_hit = _mm512_mask_cmpneq_epi32_mask(
                changed as __mmask16,
                _mm512_load_si512(hits.tri.as_ptr() as *const _),
                _mm512_set1_epi32(EMPTY_ID as i32),
            );
            let t = _mm512_load_ps(hits.t.as_ptr());
            // A hit's t is above tmin >= 0 (finite, positive): the next
            // float up is its bits plus one, as `leaf_closest` has it.
            let next_up = _mm512_castsi512_ps(_mm512_add_epi32(
                _mm512_castps_si512(t),
                _mm512_set1_epi32(1),
            ));
            let widened = _mm512_mul_ps(t, _mm512_set1_ps(1.0 + CULL_SLACK));
            _mm512_mask_storeu_ps(tmax.as_mut_ptr(), with_hit, next_up);
            _mm512_mask_storeu_ps(cut.as_mut_ptr(), with_hit, widened);
        }
    }

    #[inline(always)]
    fn reach(self, near: f32, cut: &[f32; PACKET16]) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY: `self.0` proves AVX-512F; the load reads the sixteen f32
        // of `cut`.
        unsafe {
            let c = _mm512_loadu_ps(cut.as_ptr());
            _mm512_cmp_ps_mask::<_CMP_LE_OQ>(_mm512_set1_ps(near), c) as u32
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl TriangleLanes<PACKET16> for Avx512Packet {
    type Rays = RaysSoa16;

    /// [`Avx2Packet`]'s triangle test for sixteen rays: the rays hit within
    /// `(tmin, tmax[r])`, and each lane's t, u and v.
    #[inline(always)]
    fn triangle(
        self,
        block: &Tri4,
        i: usize,
        p: &RaysSoa16,
        tmax: &[f32; PACKET16],
    ) -> (u32, [f32; 16], [f32; 16], [f32; 16]) {
        use std::arch::x86_64::*;
        // SAFETY: `self.0` proves AVX-512F; the load reads sixteen f32 of
        // `tmax` (unaligned), the stores write sixteen f32 to local arrays.
        unsafe {
            let (ok, t, u, v) = self.triangle16(block, i, p, _mm512_loadu_ps(tmax.as_ptr()));
            let (mut ts, mut us, mut vs) = ([0f32; 16], [0f32; 16], [0f32; 16]);
            if ok != 0 {
                _mm512_storeu_ps(ts.as_mut_ptr(), t);
                _mm512_storeu_ps(us.as_mut_ptr(), u);
                _mm512_storeu_ps(vs.as_mut_ptr(), v);
            }
            (ok as u32, ts, us, vs)
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl Avx512Packet {
    /// The triangle test of [`TriangleLanes::triangle`] with `tmax` and the
    /// results in registers: the rays that hit within `(tmin, tmax)`, and
    /// each lane's t, u and v (meaningful where they hit).
    ///
    /// # Safety
    /// The CPU must run AVX-512F (`self.0` proves it; `unsafe` only because
    /// the registers are its types).
    #[inline(always)]
    unsafe fn triangle16(
        self,
        block: &Tri4,
        i: usize,
        p: &RaysSoa16,
        tmax: std::arch::x86_64::__m512,
    ) -> (
        std::arch::x86_64::__mmask16,
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
    ) {
        use std::arch::x86_64::*;
        let [v0, v1, v2] = &block.v;
        let e1 = [
            v1[0][i] - v0[0][i],
            v1[1][i] - v0[1][i],
            v1[2][i] - v0[2][i],
        ];
        let e2 = [
            v2[0][i] - v0[0][i],
            v2[1][i] - v0[1][i],
            v2[2][i] - v0[2][i],
        ];
        // SAFETY: `self.0` proves AVX-512F; loads read 64-byte aligned rows
        // of `p` (RaysSoa16 is aligned to 64).
        unsafe {
            macro_rules! s {
                ($x:expr) => {
                    _mm512_set1_ps($x)
                };
            }
            macro_rules! add {
                ($a:expr, $b:expr) => {
                    _mm512_add_ps($a, $b)
                };
            }
            macro_rules! sub {
                ($a:expr, $b:expr) => {
                    _mm512_sub_ps($a, $b)
                };
            }
            macro_rules! mul {
                ($a:expr, $b:expr) => {
                    _mm512_mul_ps($a, $b)
                };
            }
            macro_rules! row {
                ($row:expr) => {
                    _mm512_load_ps($row.as_ptr())
                };
            }
            macro_rules! cmp {
                ($op:ident, $a:expr, $b:expr) => {
                    _mm512_cmp_ps_mask::<$op>($a, $b)
                };
            }
            let (ox, oy, oz) = (row!(p.origin[0]), row!(p.origin[1]), row!(p.origin[2]));
            let (dx, dy, dz) = (row!(p.dir[0]), row!(p.dir[1]), row!(p.dir[2]));
            let (e1x, e1y, e1z) = (s!(e1[0]), s!(e1[1]), s!(e1[2]));
            let (e2x, e2y, e2z) = (s!(e2[0]), s!(e2[1]), s!(e2[2]));
            let px = sub!(mul!(dy, e2z), mul!(e2y, dz));
            let py = sub!(mul!(dz, e2x), mul!(e2z, dx));
            let pz = sub!(mul!(dx, e2y), mul!(e2x, dy));
            let det = add!(add!(mul!(e1x, px), mul!(e1y, py)), mul!(e1z, pz));
            let (sx, sy, sz) = (
                sub!(ox, s!(v0[0][i])),
                sub!(oy, s!(v0[1][i])),
                sub!(oz, s!(v0[2][i])),
            );
            let u_num = add!(add!(mul!(sx, px), mul!(sy, py)), mul!(sz, pz));
            // The early exit of the AVX2 kernel (see there), by bits.
            let sign_bit = _mm512_set1_epi32(i32::MIN);
            let abs_det =
                _mm512_castsi512_ps(_mm512_andnot_si512(sign_bit, _mm512_castps_si512(det)));
            let signed = _mm512_castsi512_ps(_mm512_xor_si512(
                _mm512_castps_si512(u_num),
                _mm512_and_si512(_mm512_castps_si512(det), sign_bit),
            ));
            let margin = mul!(abs_det, s!(U_MARGIN));
            let outside = cmp!(_CMP_LT_OQ, signed, sub!(s!(0.0), margin))
                | cmp!(_CMP_GT_OQ, signed, add!(abs_det, margin));
            if outside == 0xFFFF {
                let zero = _mm512_setzero_ps();
                return (0, zero, zero, zero);
            }
            let inv_det = _mm512_div_ps(s!(1.0), det);
            let u = mul!(u_num, inv_det);
            let qx = sub!(mul!(sy, e1z), mul!(e1y, sz));
            let qy = sub!(mul!(sz, e1x), mul!(e1z, sx));
            let qz = sub!(mul!(sx, e1y), mul!(e1x, sy));
            let v = mul!(
                add!(add!(mul!(dx, qx), mul!(dy, qy)), mul!(dz, qz)),
                inv_det
            );
            let t = mul!(
                add!(add!(mul!(e2x, qx), mul!(e2y, qy)), mul!(e2z, qz)),
                inv_det
            );
            let ok = cmp!(_CMP_GE_OQ, abs_det, s!(f32::MIN_POSITIVE))
                & cmp!(_CMP_GE_OQ, u, s!(0.0))
                & cmp!(_CMP_LE_OQ, u, s!(1.0))
                & cmp!(_CMP_GE_OQ, v, s!(0.0))
                & cmp!(_CMP_LE_OQ, add!(u, v), s!(1.0))
                & cmp!(_CMP_GT_OQ, t, row!(p.tmin))
                & cmp!(_CMP_LT_OQ, t, tmax);
            (ok, t, u, v)
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::bvh::simd::Portable;
    use crate::geometry::{Aabb, MollerTrumbore};
    use crate::rng::Rng;

    /// A packet of `n` rays with one sign per axis (the frustum's case):
    /// origins and directions spread by the given amounts around a base ray,
    /// some with a finite `tmax`, some with a `tmin`.
    fn coherent(rng: &mut Rng, n: usize, spread_o: f32, spread_d: f32) -> Vec<Ray> {
        let mut v = |s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        let base_o = v(4.0) - Vec3::splat(2.0);
        let signs = v(2.0).map(|c| if c < 1.0 { -1.0 } else { 1.0 });
        let base_d = (v(0.8) + Vec3::splat(0.2)) * signs;
        let bounded = v(1.0).x < 0.5;
        (0..n)
            .map(|_| {
                let jitter = v(1.0) - Vec3::splat(0.5);
                let mut ray = Ray::new(
                    base_o + jitter * spread_o,
                    base_d + (v(1.0) - Vec3::splat(0.5)) * spread_d,
                );
                if bounded {
                    ray.tmax = 0.5 + v(3.5).x;
                }
                if v(1.0).y < 0.2 {
                    ray.tmin = v(0.5).z;
                }
                ray
            })
            .collect()
    }

    /// Eight children around points on the packet's rays: boxes with a face
    /// or a corner exactly on a ray's point, thin and flat boxes, boxes away
    /// from every ray, and unused lanes.
    fn node_around(rng: &mut Rng, rays: &[Ray]) -> WideNode<8> {
        let mut node = WideNode::<8>::empty();
        for lane in 0..8 {
            let pick = |x: f32, n: usize| ((x * n as f32) as usize).min(n - 1);
            let kind = pick(rng.next_f32(), 6);
            if kind == 5 {
                continue;
            }
            let ray = rays[pick(rng.next_f32(), rays.len())];
            let point = ray.origin + ray.dir * (rng.next_f32() * 5.0);
            let mut ext = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.3;
            let (lo, hi) = match kind {
                // A corner on the ray's point, the box away from it.
                0 => (point, point + ext()),
                1 => (point - ext(), point),
                // Flat on one axis through the point.
                2 => {
                    let (mut lo, mut hi) = (point - ext(), point + ext());
                    lo.y = point.y;
                    hi.y = point.y;
                    (lo, hi)
                }
                // Around the point.
                3 => (point - ext(), point + ext()),
                // Somewhere else.
                _ => {
                    let far = point + Vec3::splat(3.0) + ext() * 10.0;
                    (far, far + ext())
                }
            };
            node.set_lane(lane, &Aabb { min: lo, max: hi }, lane as u32);
        }
        node
    }

    /// Whether `got` reports `want`'s hits, and for each hit child an entry
    /// bound: `want`'s (the rays' least entry) bit for bit, or with a
    /// frustum (`bounded`) at most that and not NaN.
    fn same(want: &NodeHits, got: &NodeHits, near: bool, bounded: bool) -> bool {
        let entries_agree = bits(want.lanes).all(|c| {
            let (w, g) = (want.near[c], got.near[c]);
            if bounded {
                g <= w
            } else {
                g.to_bits() == w.to_bits()
            }
        });
        want.lanes == got.lanes && want.rays == got.rays && (!near || entries_agree)
    }

    /// The AVX2 and AVX-512 node tests, frustum and all, report exactly the
    /// single-ray kernel's hits per ray and child on coherent packets aimed
    /// at box faces and corners, with entry bounds at most the rays' least
    /// entry (equal to it for equal rays); and the frustum does skip
    /// children.
    #[test]
    fn the_frustum_keeps_every_child_a_ray_enters() {
        let Some(avx2) = Avx2::detect() else {
            eprintln!("no AVX2 on this CPU: the packet node kernels are not tested");
            return;
        };
        let avx512 = Avx512::detect();
        let mut rng = Rng::for_pixel(7, 3, 11);
        let (mut tested, mut skipped, mut exact_bounds) = (0, 0, 0);
        for k in 0..20_000 {
            let spread_o = [0.0, 1e-3, 0.3][k % 3];
            let spread_d = [0.0, 1e-3, 0.05][k / 3 % 3];
            let rays = coherent(&mut rng, 1 + k % PACKET16, spread_o, spread_d);
            let node = node_around(&mut rng, &rays);
            let used = (0..8)
                .filter(|&c| node.child[c] != EMPTY)
                .fold(0, |m, c| m | 1 << c);
            let short = &rays[..rays.len().min(PACKET)];
            let reference = PerRay::<Portable, MollerTrumbore>::new(Portable);
            let (want_p, active) = PacketKernel::<PACKET>::prepare(reference, short);
            let (got_p, got_active) = avx2_packet(avx2).prepare(short);
            assert_eq!(got_active, active, "valid rays, packet {k}");
            let tmax: [f32; PACKET] = std::array::from_fn(|r| short.get(r).map_or(0.0, |r| r.tmax));
            for near in [false, true] {
                let (want, got) = if near {
                    (
                        reference.node::<true>(&node, &want_p, active, &tmax),
                        avx2_packet(avx2).node::<true>(&node, &got_p, active, &tmax),
                    )
                } else {
                    (
                        reference.node::<false>(&node, &want_p, active, &tmax),
                        avx2_packet(avx2).node::<false>(&node, &got_p, active, &tmax),
                    )
                };
                let bounded = got_p.frustum.is_some();
                assert!(
                    same(&want, &got, near, bounded),
                    "AVX2 packet {k}: {rays:?} {node:?}"
                );
                if near && bounded && spread_o == 0.0 && spread_d == 0.0 {
                    // Equal rays: the frustum's bound is their entry.
                    assert!(same(&want, &got, near, false), "AVX2 packet {k}");
                    exact_bounds += 1;
                }
            }
            if let Some(f) = got_p.frustum {
                // SAFETY: AVX2 (hence AVX) was detected above.
                let kept = unsafe { f.children(&node) }.0 & used;
                tested += used.count_ones();
                skipped += (used & !kept).count_ones();
            }
            let Some(avx512) = avx512 else { continue };
            let (want_p, active) = PacketKernel::<PACKET16>::prepare(reference, &rays);
            let (got_p, got_active) = Avx512Packet(avx512).prepare(&rays);
            assert_eq!(got_active, active, "valid rays, packet {k}");
            let tmax: [f32; PACKET16] =
                std::array::from_fn(|r| rays.get(r).map_or(0.0, |r| r.tmax));
            let want = reference.node::<true>(&node, &want_p, active, &tmax);
            let got = Avx512Packet(avx512).node::<true>(&node, &got_p, active, &tmax);
            let bounded = got_p.frustum.is_some();
            assert!(
                same(&want, &got, true, bounded),
                "AVX-512 packet {k}: {rays:?} {node:?}"
            );
            if bounded && spread_o == 0.0 && spread_d == 0.0 {
                assert!(same(&want, &got, true, false), "AVX-512 packet {k}");
            }
        }
        if avx512.is_none() {
            eprintln!("no AVX-512 on this CPU: the AVX-512 node kernel is not tested");
        }
        assert!(
            skipped > tested / 10 && skipped < tested,
            "the frustum skipped {skipped} of {tested} children"
        );
        assert!(exact_bounds > 100, "{exact_bounds} packets of equal rays");
    }

    fn avx2_packet(avx2: Avx2) -> Avx2Packet {
        Avx2Packet(avx2)
    }

    /// Random hits (about one ray in four without one), changed masks and
    /// limits, as `tighten` meets them.
    fn random_tighten_case<const R: usize>(
        rng: &mut Rng,
    ) -> (PacketHits<R>, u32, [f32; R], [f32; R]) {
        let mut hits = PacketHits::<R>::none();
        for r in 0..R {
            if rng.next_f32() < 0.75 {
                let t = [rng.next_f32() * 10.0, 1e-30, f32::MAX][r % 3];
                let hit = Hit {
                    t,
                    u: 0.1,
                    v: 0.2,
                    tri: r as u32 * 7,
                };
                hits.set(r, Some(hit));
            }
        }
        let changed = (rng.next_f32() * (1u64 << R) as f32) as u32 & ((1u64 << R) - 1) as u32;
        let tmax = std::array::from_fn(|_| rng.next_f32() * 20.0);
        let cut = std::array::from_fn(|_| rng.next_f32() * 20.0);
        (hits, changed, tmax, cut)
    }

    /// The SIMD kernels tighten each changed ray's limits as the default
    /// (scalar) method does, bit for bit, and leave the others alone.
    #[test]
    fn simd_tightening_equals_the_scalar_one() {
        let Some(avx2) = Avx2::detect() else {
            eprintln!("no AVX2 on this CPU: the packet kernels' tightening is not tested");
            return;
        };
        let reference = PerRay::<Portable, MollerTrumbore>::new(Portable);
        let bits_of = |a: &[f32]| a.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut rng = Rng::for_pixel(5, 1, 9);
        for k in 0..2_000 {
            let (hits, changed, tmax, cut) = random_tighten_case::<PACKET>(&mut rng);
            let (mut want_tmax, mut want_cut) = (tmax, cut);
            PacketKernel::<PACKET>::tighten(
                reference,
                &hits,
                changed,
                &mut want_tmax,
                &mut want_cut,
            );
            let (mut got_tmax, mut got_cut) = (tmax, cut);
            avx2_packet(avx2).tighten(&hits, changed, &mut got_tmax, &mut got_cut);
            assert_eq!(bits_of(&got_tmax), bits_of(&want_tmax), "AVX2 case {k}");
            assert_eq!(bits_of(&got_cut), bits_of(&want_cut), "AVX2 case {k}");
            let Some(avx512) = Avx512::detect() else {
                continue;
            };
            let (hits, changed, tmax, cut) = random_tighten_case::<PACKET16>(&mut rng);
            let (mut want_tmax, mut want_cut) = (tmax, cut);
            PacketKernel::<PACKET16>::tighten(
                reference,
                &hits,
                changed,
                &mut want_tmax,
                &mut want_cut,
            );
            let (mut got_tmax, mut got_cut) = (tmax, cut);
            Avx512Packet(avx512).tighten(&hits, changed, &mut got_tmax, &mut got_cut);
            assert_eq!(bits_of(&got_tmax), bits_of(&want_tmax), "AVX-512 case {k}");
            assert_eq!(bits_of(&got_cut), bits_of(&want_cut), "AVX-512 case {k}");
        }
    }
}
