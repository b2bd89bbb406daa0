//! The SIMD lanes the packet kernel ([`super::simd_packet::SimdPacket`]) is
//! written over: [`Lanes`], implemented by the [`Avx2`] proof for eight rays
//! in `__m256` registers and by the [`Avx512`] proof for sixteen in
//! `__m512` registers (compares into `__mmask16`).
//!
//! Every operation is one lane-wise IEEE operation (or a compare, a blend, a
//! bit move) with no fused multiply-add, so the kernel's one body gives each
//! lane the same result whichever width runs it. What differs by width is
//! here only: how a packet is loaded and transposed, the valid rays' bounds,
//! and the least lane under a mask.
//!
//! This file holds all of the packet kernel's `unsafe`: the intrinsics. Each
//! method takes the proof (`self`, made only by [`Avx2::detect`] or
//! [`Avx512::detect`], which check the CPU), so the methods are safe to call;
//! all are `#[inline(always)]`, so they are compiled inside the traversal's
//! `#[target_feature]` entry points (`wide::traverse`), where the intrinsics
//! are inlined.

use std::arch::x86_64::*;

use super::leaf::Tri4;
use super::simd::{Avx2, Avx512};
use crate::geometry::Ray;

/// A triangle test across a packet's ray lanes, for the packets' leaf
/// loops (`simd_packet`'s `closest_in_block` and `any_in_block`):
/// Moller-Trumbore on `SoaRays`, or the watertight test
/// (`simd_watertight::WatertightLanes`).
pub(crate) trait LaneTriangles<L: Lanes<R>, const R: usize> {
    /// The rays of `live` (at least; other lanes may be set too) that hit
    /// lane `i` of `block` within their `tmin` and their lane of `tmax`,
    /// and each lane's t, u and v (meaningful where they hit).
    fn triangle(
        &self,
        l: L,
        block: &Tri4,
        i: usize,
        live: L::M,
        tmax: L::F,
    ) -> (L::M, L::F, L::F, L::F);
    /// The rays' own `tmax`.
    fn tmax(&self) -> L::F;
}

/// `R` f32 lanes and the operations the packet kernel runs on them.
pub trait Lanes<const R: usize>: Copy {
    /// `R` f32 lanes.
    type F: Copy + std::fmt::Debug;
    /// `R` u32 lanes.
    type U: Copy;
    /// A lane mask: what a compare returns.
    type M: Copy + std::fmt::Debug;
    /// A packet's rays as loaded, before transposing (see
    /// [`Lanes::ray_bounds`]).
    type Loaded: Copy;

    /// The AVX2 proof this one includes (the node-level tests of an 8-wide
    /// node run on eight lanes whatever the packet's width).
    fn avx2(self) -> Avx2;

    fn splat(self, x: f32) -> Self::F;
    /// Loads `R` f32 (unaligned).
    fn load(self, a: &[f32; R]) -> Self::F;
    fn store(self, v: Self::F) -> [f32; R];
    /// Stores the lanes of `v` where `m` is set into `dst`, leaving the others.
    fn store_where(self, dst: &mut [f32; R], m: Self::M, v: Self::F);
    fn add(self, a: Self::F, b: Self::F) -> Self::F;
    fn sub(self, a: Self::F, b: Self::F) -> Self::F;
    fn mul(self, a: Self::F, b: Self::F) -> Self::F;
    fn div(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a < b ? a : b` per lane (the `minps` rule: `b` when either is NaN).
    fn min(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a > b ? a : b` per lane (`b` when either is NaN).
    fn max(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a` with its sign bit cleared.
    fn abs(self, a: Self::F) -> Self::F;
    /// `a` with its sign flipped where `b`'s sign bit is set.
    fn flip_sign(self, a: Self::F, b: Self::F) -> Self::F;
    /// The float after each lane's: its bits plus one (the next float up
    /// for positive finite lanes).
    fn bits_plus_one(self, a: Self::F) -> Self::F;
    /// `m ? b : a` per lane.
    fn blend(self, m: Self::M, a: Self::F, b: Self::F) -> Self::F;

    // Ordered, quiet compares: false where a lane is NaN (but `ne`: also
    // false there, `_CMP_NEQ_OQ`).
    fn lt(self, a: Self::F, b: Self::F) -> Self::M;
    fn le(self, a: Self::F, b: Self::F) -> Self::M;
    fn gt(self, a: Self::F, b: Self::F) -> Self::M;
    fn ge(self, a: Self::F, b: Self::F) -> Self::M;
    fn eq(self, a: Self::F, b: Self::F) -> Self::M;
    fn ne(self, a: Self::F, b: Self::F) -> Self::M;

    fn and(self, a: Self::M, b: Self::M) -> Self::M;
    fn or(self, a: Self::M, b: Self::M) -> Self::M;
    /// `!a & b`.
    fn andnot(self, a: Self::M, b: Self::M) -> Self::M;
    /// The mask as a bit per lane.
    fn bits(self, m: Self::M) -> u32;
    /// The lanes of the bits of `bits` (lane `r` set for bit `r`).
    fn mask(self, bits: u32) -> Self::M;

    /// Loads `R` u32 (unaligned).
    fn load_u32(self, a: &[u32; R]) -> Self::U;
    fn store_u32(self, dst: &mut [u32; R], v: Self::U);
    fn splat_u32(self, x: u32) -> Self::U;
    fn eq_u32(self, a: Self::U, b: Self::U) -> Self::M;
    /// `a < b` per lane, unsigned (as `u32`'s `<`).
    fn lt_u32(self, a: Self::U, b: Self::U) -> Self::M;
    /// `m ? b : a` per lane.
    fn blend_u32(self, m: Self::M, a: Self::U, b: Self::U) -> Self::U;

    /// The least lane of `v` where `m` is set (`m` not empty).
    fn min_where(self, m: Self::M, v: Self::F) -> f32;

    /// Up to `R` rays by components: per component of a ray in memory order
    /// (origin, direction, `tmin`, `tmax`), a register with ray `r` in lane
    /// `r`, zero past the packet; and the rays as loaded.
    fn load_rays(self, rays: &[Ray]) -> ([Self::F; 8], Self::Loaded);
    /// [`Ray::is_valid`] lane by lane, on the components [`Self::load_rays`]
    /// gives: origin and direction finite, the direction not zero, `tmin`
    /// finite and not negative, `tmax` not below it. Ordered compares fail
    /// on NaN, and lanes past the packet (zero direction) are invalid.
    #[inline(always)]
    fn valid_rays(self, c: &[Self::F; 8]) -> Self::M {
        let (inf, zero) = (self.splat(f32::INFINITY), self.splat(0.0));
        let mut valid = self.lt(self.abs(c[0]), inf);
        for &v in &c[1..7] {
            valid = self.and(valid, self.lt(self.abs(v), inf));
        }
        let moving = self.or(
            self.or(self.ne(c[3], zero), self.ne(c[4], zero)),
            self.ne(c[5], zero),
        );
        let segment = self.and(self.ge(c[6], zero), self.ge(c[7], c[6]));
        self.and(valid, self.and(moving, segment))
    }
    /// The least and greatest value of each component (lanes 0-7, in a
    /// ray's memory order) over the rays whose bit is set in `valid`.
    fn ray_bounds(self, loaded: &Self::Loaded, valid: u32) -> (Self::F, Self::F);
}

/// Floats per [`Ray`] (`repr(C)`: origin, direction, tmin, tmax).
const RAY_FLOATS: usize = 8;
const _: () = assert!(std::mem::size_of::<Ray>() == RAY_FLOATS * 4);

/// Defines the register-only methods of [`Lanes`] for one instruction set:
/// each is the one intrinsic named.
macro_rules! binary_ops {
    ($f:ty, $($name:ident => $op:expr),* $(,)?) => {
        $(
            #[inline(always)]
            fn $name(self, a: $f, b: $f) -> $f {
                // SAFETY: `self` proves the CPU has the instruction set
                // (see the impl); register operations only.
                unsafe { ($op)(a, b) }
            }
        )*
    };
}

impl Lanes<8> for Avx2 {
    type F = __m256;
    type U = __m256i;
    /// All ones in the set lanes, as AVX compares return.
    type M = __m256;
    /// Ray `r` in register `r`.
    type Loaded = [__m256; 8];

    #[inline(always)]
    fn avx2(self) -> Avx2 {
        self
    }

    #[inline(always)]
    fn splat(self, x: f32) -> __m256 {
        // SAFETY: `self` proves AVX2 (which includes AVX); register only.
        unsafe { _mm256_set1_ps(x) }
    }

    #[inline(always)]
    fn load(self, a: &[f32; 8]) -> __m256 {
        // SAFETY: `self` proves AVX; the unaligned load reads the eight
        // f32 of `a`.
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    }

    #[inline(always)]
    fn store(self, v: __m256) -> [f32; 8] {
        let mut out = [0f32; 8];
        // SAFETY: `self` proves AVX; the unaligned store writes the eight
        // f32 of `out`.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    }

    #[inline(always)]
    fn store_where(self, dst: &mut [f32; 8], m: __m256, v: __m256) {
        // SAFETY: `self` proves AVX; the masked store writes only lanes of
        // the eight f32 of `dst`.
        unsafe { _mm256_maskstore_ps(dst.as_mut_ptr(), _mm256_castps_si256(m), v) }
    }

    binary_ops!(
        __m256,
        add => _mm256_add_ps,
        sub => _mm256_sub_ps,
        mul => _mm256_mul_ps,
        div => _mm256_div_ps,
        min => _mm256_min_ps,
        max => _mm256_max_ps,
        and => _mm256_and_ps,
        or => _mm256_or_ps,
        andnot => _mm256_andnot_ps,
        lt => _mm256_cmp_ps::<_CMP_LT_OQ>,
        le => _mm256_cmp_ps::<_CMP_LE_OQ>,
        gt => _mm256_cmp_ps::<_CMP_GT_OQ>,
        ge => _mm256_cmp_ps::<_CMP_GE_OQ>,
        eq => _mm256_cmp_ps::<_CMP_EQ_OQ>,
        ne => _mm256_cmp_ps::<_CMP_NEQ_OQ>,
    );

    #[inline(always)]
    fn abs(self, a: __m256) -> __m256 {
        // SAFETY: `self` proves AVX; register operations only.
        unsafe { _mm256_andnot_ps(_mm256_set1_ps(-0.0), a) }
    }

    #[inline(always)]
    fn flip_sign(self, a: __m256, b: __m256) -> __m256 {
        // SAFETY: `self` proves AVX; register operations only.
        unsafe { _mm256_xor_ps(a, _mm256_and_ps(b, _mm256_set1_ps(-0.0))) }
    }

    #[inline(always)]
    fn bits_plus_one(self, a: __m256) -> __m256 {
        // SAFETY: `self` proves AVX2 (the integer add); register only.
        unsafe {
            _mm256_castsi256_ps(_mm256_add_epi32(
                _mm256_castps_si256(a),
                _mm256_set1_epi32(1),
            ))
        }
    }

    #[inline(always)]
    fn blend(self, m: __m256, a: __m256, b: __m256) -> __m256 {
        // SAFETY: `self` proves AVX; register only (`blendv` takes each
        // lane's top bit, all ones or zeros in a compare's mask).
        unsafe { _mm256_blendv_ps(a, b, m) }
    }

    #[inline(always)]
    fn bits(self, m: __m256) -> u32 {
        // SAFETY: `self` proves AVX; register only.
        unsafe { _mm256_movemask_ps(m) as u32 }
    }

    #[inline(always)]
    fn mask(self, bits: u32) -> __m256 {
        // SAFETY: `self` proves AVX2; register operations only.
        unsafe {
            let lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                _mm256_and_si256(_mm256_set1_epi32(bits as i32), lane_bits),
                _mm256_setzero_si256(),
            ))
        }
    }

    #[inline(always)]
    fn load_u32(self, a: &[u32; 8]) -> __m256i {
        // SAFETY: `self` proves AVX; the unaligned load reads the eight u32
        // of `a`.
        unsafe { _mm256_loadu_si256(a.as_ptr() as *const __m256i) }
    }

    #[inline(always)]
    fn store_u32(self, dst: &mut [u32; 8], v: __m256i) {
        // SAFETY: `self` proves AVX; the unaligned store writes the eight
        // u32 of `dst`.
        unsafe { _mm256_storeu_si256(dst.as_mut_ptr() as *mut __m256i, v) }
    }

    #[inline(always)]
    fn splat_u32(self, x: u32) -> __m256i {
        // SAFETY: `self` proves AVX; register only.
        unsafe { _mm256_set1_epi32(x as i32) }
    }

    #[inline(always)]
    fn eq_u32(self, a: __m256i, b: __m256i) -> __m256 {
        // SAFETY: `self` proves AVX2; register only.
        unsafe { _mm256_castsi256_ps(_mm256_cmpeq_epi32(a, b)) }
    }

    #[inline(always)]
    fn lt_u32(self, a: __m256i, b: __m256i) -> __m256 {
        // SAFETY: `self` proves AVX2; register only. Flipping the top bit
        // maps u32's order onto i32's.
        unsafe {
            let top = _mm256_set1_epi32(i32::MIN);
            _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                _mm256_xor_si256(b, top),
                _mm256_xor_si256(a, top),
            ))
        }
    }

    #[inline(always)]
    fn blend_u32(self, m: __m256, a: __m256i, b: __m256i) -> __m256i {
        // SAFETY: `self` proves AVX; register only.
        unsafe {
            _mm256_castps_si256(_mm256_blendv_ps(
                _mm256_castsi256_ps(a),
                _mm256_castsi256_ps(b),
                m,
            ))
        }
    }

    #[inline(always)]
    fn min_where(self, m: __m256, v: __m256) -> f32 {
        // SAFETY: `self` proves AVX; register operations only.
        unsafe {
            let m = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), v, m);
            let m = _mm_min_ps(_mm256_castps256_ps128(m), _mm256_extractf128_ps::<1>(m));
            let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
            let m = _mm_min_ss(m, _mm_shuffle_ps::<0b01>(m, m));
            _mm_cvtss_f32(m)
        }
    }

    #[inline(always)]
    fn load_rays(self, rays: &[Ray]) -> ([__m256; 8], [__m256; 8]) {
        debug_assert!(rays.len() <= 8);
        // SAFETY: `self` proves AVX. Each load reads one ray of `rays` whole
        // (`Ray` is `repr(C)`, eight f32: RAY_FLOATS).
        unsafe {
            let mut by_ray = [_mm256_setzero_ps(); 8];
            for (reg, ray) in by_ray.iter_mut().zip(rays) {
                *reg = _mm256_loadu_ps(ray as *const Ray as *const f32);
            }
            (transpose_8x8(&by_ray), by_ray)
        }
    }

    #[inline(always)]
    fn ray_bounds(self, by_ray: &[__m256; 8], valid: u32) -> (__m256, __m256) {
        // SAFETY: `self` proves AVX; register operations only.
        unsafe {
            let mut lo = _mm256_set1_ps(f32::INFINITY);
            let mut hi = _mm256_set1_ps(f32::NEG_INFINITY);
            for (r, ray) in by_ray.iter().enumerate() {
                if valid >> r & 1 == 1 {
                    lo = _mm256_min_ps(lo, *ray);
                    hi = _mm256_max_ps(hi, *ray);
                }
            }
            (lo, hi)
        }
    }
}

/// Eight rays by components: from `by_ray[r]`, ray `r` as laid out in
/// memory (eight f32), to one register per component with ray `r` in lane
/// `r` (the usual unpack, shuffle and lane-swap rounds).
///
/// # Safety
/// The CPU must run AVX.
#[inline(always)]
unsafe fn transpose_8x8(by_ray: &[__m256; 8]) -> [__m256; 8] {
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

impl Lanes<16> for Avx512 {
    type F = __m512;
    type U = __m512i;
    /// A bit per lane, as AVX-512 compares return.
    type M = __mmask16;
    /// `pairs[k]`: rays `2k` and `2k + 1`, component `c` of ray `2k + j` in
    /// lane `8j + c`.
    type Loaded = [__m512; 8];

    #[inline(always)]
    fn avx2(self) -> Avx2 {
        self.avx2
    }

    #[inline(always)]
    fn splat(self, x: f32) -> __m512 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_set1_ps(x) }
    }

    #[inline(always)]
    fn load(self, a: &[f32; 16]) -> __m512 {
        // SAFETY: `self` proves AVX-512F; the unaligned load reads the
        // sixteen f32 of `a`.
        unsafe { _mm512_loadu_ps(a.as_ptr()) }
    }

    #[inline(always)]
    fn store(self, v: __m512) -> [f32; 16] {
        let mut out = [0f32; 16];
        // SAFETY: `self` proves AVX-512F; the unaligned store writes the
        // sixteen f32 of `out`.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr(), v) };
        out
    }

    #[inline(always)]
    fn store_where(self, dst: &mut [f32; 16], m: __mmask16, v: __m512) {
        // SAFETY: `self` proves AVX-512F; the masked store writes only
        // lanes of the sixteen f32 of `dst`.
        unsafe { _mm512_mask_storeu_ps(dst.as_mut_ptr(), m, v) }
    }

    binary_ops!(
        __m512,
        add => _mm512_add_ps,
        sub => _mm512_sub_ps,
        mul => _mm512_mul_ps,
        div => _mm512_div_ps,
        min => _mm512_min_ps,
        max => _mm512_max_ps,
    );

    #[inline(always)]
    fn abs(self, a: __m512) -> __m512 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_abs_ps(a) }
    }

    #[inline(always)]
    fn flip_sign(self, a: __m512, b: __m512) -> __m512 {
        // SAFETY: `self` proves AVX-512F; register operations only.
        unsafe {
            let sign_bit = _mm512_set1_epi32(i32::MIN);
            _mm512_castsi512_ps(_mm512_xor_si512(
                _mm512_castps_si512(a),
                _mm512_and_si512(_mm512_castps_si512(b), sign_bit),
            ))
        }
    }

    #[inline(always)]
    fn bits_plus_one(self, a: __m512) -> __m512 {
        // SAFETY: `self` proves AVX-512F; register operations only.
        unsafe {
            _mm512_castsi512_ps(_mm512_add_epi32(
                _mm512_castps_si512(a),
                _mm512_set1_epi32(1),
            ))
        }
    }

    #[inline(always)]
    fn blend(self, m: __mmask16, a: __m512, b: __m512) -> __m512 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_mask_blend_ps(m, a, b) }
    }

    #[inline(always)]
    fn lt(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_cmp_ps_mask::<_CMP_LT_OQ>(a, b) }
    }

    #[inline(always)]
    fn le(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: as `lt`.
        unsafe { _mm512_cmp_ps_mask::<_CMP_LE_OQ>(a, b) }
    }

    #[inline(always)]
    fn gt(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: as `lt`.
        unsafe { _mm512_cmp_ps_mask::<_CMP_GT_OQ>(a, b) }
    }

    #[inline(always)]
    fn ge(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: as `lt`.
        unsafe { _mm512_cmp_ps_mask::<_CMP_GE_OQ>(a, b) }
    }

    #[inline(always)]
    fn eq(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: as `lt`.
        unsafe { _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(a, b) }
    }

    #[inline(always)]
    fn ne(self, a: __m512, b: __m512) -> __mmask16 {
        // SAFETY: as `lt`.
        unsafe { _mm512_cmp_ps_mask::<_CMP_NEQ_OQ>(a, b) }
    }

    #[inline(always)]
    fn and(self, a: __mmask16, b: __mmask16) -> __mmask16 {
        a & b
    }

    #[inline(always)]
    fn or(self, a: __mmask16, b: __mmask16) -> __mmask16 {
        a | b
    }

    #[inline(always)]
    fn andnot(self, a: __mmask16, b: __mmask16) -> __mmask16 {
        !a & b
    }

    #[inline(always)]
    fn bits(self, m: __mmask16) -> u32 {
        m as u32
    }

    #[inline(always)]
    fn mask(self, bits: u32) -> __mmask16 {
        bits as __mmask16
    }

    #[inline(always)]
    fn load_u32(self, a: &[u32; 16]) -> __m512i {
        // SAFETY: `self` proves AVX-512F; the unaligned load reads the
        // sixteen u32 of `a`.
        unsafe { _mm512_loadu_si512(a.as_ptr() as *const _) }
    }

    #[inline(always)]
    fn store_u32(self, dst: &mut [u32; 16], v: __m512i) {
        // SAFETY: `self` proves AVX-512F; the unaligned store writes the
        // sixteen u32 of `dst`.
        unsafe { _mm512_storeu_si512(dst.as_mut_ptr() as *mut _, v) }
    }

    #[inline(always)]
    fn splat_u32(self, x: u32) -> __m512i {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_set1_epi32(x as i32) }
    }

    #[inline(always)]
    fn eq_u32(self, a: __m512i, b: __m512i) -> __mmask16 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_cmpeq_epi32_mask(a, b) }
    }

    #[inline(always)]
    fn lt_u32(self, a: __m512i, b: __m512i) -> __mmask16 {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_cmplt_epu32_mask(a, b) }
    }

    #[inline(always)]
    fn blend_u32(self, m: __mmask16, a: __m512i, b: __m512i) -> __m512i {
        // SAFETY: `self` proves AVX-512F; register only.
        unsafe { _mm512_mask_blend_epi32(m, a, b) }
    }

    #[inline(always)]
    fn min_where(self, m: __mmask16, v: __m512) -> f32 {
        // SAFETY: `self` proves AVX-512F; register operations only.
        unsafe { _mm512_mask_reduce_min_ps(m, v) }
    }

    #[inline(always)]
    fn load_rays(self, rays: &[Ray]) -> ([__m512; 8], [__m512; 8]) {
        debug_assert!(rays.len() <= 16);
        let floats = rays.len() * RAY_FLOATS;
        let base = rays.as_ptr() as *const f32;
        // SAFETY: `self` proves AVX-512F. Each masked load reads only the
        // floats of `rays` (`Ray` is `repr(C)`, eight f32: RAY_FLOATS) below
        // `floats`; masked-off lanes are neither read nor faulted on, and
        // the pointer is formed with `wrapping_add`.
        unsafe {
            // Lanes past the packet are zero.
            let mut pairs = [_mm512_setzero_ps(); 8];
            for (k, pair) in pairs.iter_mut().enumerate() {
                let first = 16 * k;
                let avail = floats.saturating_sub(first).min(16) as u32;
                let mask = ((1u64 << avail) - 1) as __mmask16;
                *pair = _mm512_maskz_loadu_ps(mask, base.wrapping_add(first));
            }
            (transpose_16x8(&pairs), pairs)
        }
    }

    #[inline(always)]
    fn ray_bounds(self, pairs: &[__m512; 8], valid: u32) -> (__m512, __m512) {
        // SAFETY: `self` proves AVX-512F; register operations only.
        unsafe {
            // A lane of ray 2k + j joins when that ray is valid.
            let mut lo = _mm512_set1_ps(f32::INFINITY);
            let mut hi = _mm512_set1_ps(f32::NEG_INFINITY);
            for (k, pair) in pairs.iter().enumerate() {
                let m = (valid >> (2 * k)) & 3;
                let m = (((m & 1) * 0x00FF) | ((m >> 1) * 0xFF00)) as __mmask16;
                lo = _mm512_mask_min_ps(lo, m, lo, *pair);
                hi = _mm512_mask_max_ps(hi, m, hi, *pair);
            }
            // Even and odd rays' halves combined.
            (
                _mm512_min_ps(lo, _mm512_shuffle_f32x4::<0b0100_1110>(lo, lo)),
                _mm512_max_ps(hi, _mm512_shuffle_f32x4::<0b0100_1110>(hi, hi)),
            )
        }
    }
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
#[inline(always)]
unsafe fn transpose_16x8(pairs: &[__m512; 8]) -> [__m512; 8] {
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
