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
//! `unsafe` here is the AVX2 and AVX-512 intrinsics, behind the [`Avx2`]
//! and [`Avx512`] proofs as in [`super::simd`].

use std::marker::PhantomData;

use arrayvec::ArrayVec;

use super::leaf::{BlockTest, Ray4, Tri4, EMPTY_ID};
use super::params::SLAB_SLACK;
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

/// What a node test reports for a packet: per child lane, the rays whose
/// box test hit it and their least entry distance; and the hit lanes.
pub struct NodeHits {
    pub rays: [u32; 8],
    pub near: [f32; 8],
    pub lanes: u32,
}

/// Tests of a packet of up to `R` rays against nodes and leaf blocks.
pub trait PacketKernel<const R: usize>: Copy {
    /// The packet prepared for the tests.
    type Rays;
    fn prepare(self, rays: &[Ray]) -> Self::Rays;
    /// The box test of every ray of `active` against every child of `node`,
    /// ray `r` within `(its tmin, tmax[r])`; the least entry distances only
    /// when `NEAR` (the any-hit traversal neither sorts nor culls by them).
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        rays: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
    ) -> NodeHits;
    /// Closest-hit test of the rays of `active` against the lanes `in_leaf` of
    /// `block`: a ray whose hit beats `hits[r]` (by [`Hit::is_closer_than`],
    /// hits with `t` below `tmax[r]` only) gets it. Returns the rays whose
    /// hit changed.
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        rays: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
        hits: &mut [Option<Hit>],
    ) -> u32;
    /// The rays of `active` that hit a lane `in_leaf` of `block` within their
    /// segment.
    fn leaf_any(self, block: &Tri4, in_leaf: u32, rays: &Self::Rays, active: u32) -> u32;
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
    fn prepare(self, rays: &[Ray]) -> Self::Rays {
        rays.iter()
            .map(|ray| Lane {
                ray: *ray,
                prepared: T::prepare(ray),
                ray4: Ray4::new(ray),
                wray: WideRay::new(ray, safe_reciprocal(ray.dir)),
                tmin: ray.tmin * (1.0 - SLAB_SLACK),
            })
            .collect()
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
        hits: &mut [Option<Hit>],
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
                if hits[r].is_none_or(|b| hit.is_closer_than(&b)) {
                    hits[r] = Some(hit);
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
    hits: &mut [Option<Hit>],
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
            if hits[r].is_none_or(|b| hit.is_closer_than(&b)) {
                hits[r] = Some(hit);
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
}

#[cfg(target_arch = "x86_64")]
impl PacketKernel<PACKET> for Avx2Packet {
    type Rays = RaysSoa;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> RaysSoa {
        use std::arch::x86_64::*;
        let mut p = RaysSoa::default();
        for (r, ray) in rays.iter().enumerate() {
            for a in 0..3 {
                p.origin[a][r] = ray.origin[a];
                p.dir[a][r] = ray.dir[a];
            }
            p.tmin[r] = ray.tmin;
            p.tmax[r] = ray.tmax;
        }
        // SAFETY: `self.0` proves AVX2; loads and stores are of 32-byte
        // aligned rows of `p` (RaysSoa is aligned to 32).
        unsafe {
            let big = _mm256_set1_ps(RECIPROCAL_MAX);
            for a in 0..3 {
                // safe_reciprocal: (1 / d) clamped (see RECIPROCAL_MAX).
                let inv = _mm256_div_ps(_mm256_set1_ps(1.0), _mm256_load_ps(p.dir[a].as_ptr()));
                let inv = _mm256_min_ps(
                    _mm256_max_ps(inv, _mm256_sub_ps(_mm256_setzero_ps(), big)),
                    big,
                );
                _mm256_store_ps(p.inv_dir[a].as_mut_ptr(), inv);
                let positive = _mm256_cmp_ps::<_CMP_GE_OQ>(inv, _mm256_setzero_ps());
                _mm256_store_ps(p.positive[a].as_mut_ptr() as *mut f32, positive);
            }
            let tmin = _mm256_load_ps(p.tmin.as_ptr());
            _mm256_store_ps(
                p.node_tmin.as_mut_ptr(),
                _mm256_mul_ps(tmin, _mm256_set1_ps(1.0 - SLAB_SLACK)),
            );
        }
        // Sign bits per ray: bit a set when axis a is negative.
        let mut signs = [0u32; PACKET];
        for (r, sign) in signs.iter_mut().enumerate().take(rays.len()) {
            *sign = (p.positive[0][r] == 0) as u32
                | ((p.positive[1][r] == 0) as u32) << 1
                | ((p.positive[2][r] == 0) as u32) << 2;
        }
        let first = signs[0] as usize;
        p.rows = signs[..rays.len()]
            .iter()
            .all(|&s| s == signs[0])
            .then_some([first & 1, 2 + (first >> 1 & 1), 4 + (first >> 2 & 1)]);
        p
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
        // (RaysSoa is aligned to 32) or from `tmax` (an unaligned load).
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
            let lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let live = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                _mm256_and_si256(_mm256_set1_epi32(active as i32), lane_bits),
                _mm256_setzero_si256(),
            ));
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
                        let m = _mm256_blendv_ps(inf, near, hit);
                        let m =
                            _mm_min_ps(_mm256_castps256_ps128(m), _mm256_extractf128_ps::<1>(m));
                        let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
                        let m = _mm_min_ss(m, _mm_shuffle_ps::<0b01>(m, m));
                        out.near[c] = _mm_cvtss_f32(m);
                    }
                }};
            }
            // The used lanes (unused ones hold EMPTY).
            let used = !(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
                _mm256_load_si256(node.child.as_ptr() as *const __m256i),
                _mm256_set1_epi32(EMPTY as i32),
            ))) as u32)
                & 0xFF;
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
        hits: &mut [Option<Hit>],
    ) -> u32 {
        leaf_closest_by_lanes(self, block, in_leaf, p, active, tmax, hits)
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &RaysSoa, active: u32) -> u32 {
        leaf_any_by_lanes(self, block, in_leaf, p, &p.tmax, active)
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
}

#[cfg(target_arch = "x86_64")]
impl PacketKernel<PACKET16> for Avx512Packet {
    type Rays = RaysSoa16;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> RaysSoa16 {
        use std::arch::x86_64::*;
        let mut p = RaysSoa16::default();
        for (r, ray) in rays.iter().enumerate() {
            for a in 0..3 {
                p.origin[a][r] = ray.origin[a];
                p.dir[a][r] = ray.dir[a];
            }
            p.tmin[r] = ray.tmin;
            p.tmax[r] = ray.tmax;
        }
        // SAFETY: `self.0` proves AVX-512F (see `Avx512::detect`); loads and
        // stores are of 64-byte aligned rows of `p` (RaysSoa16 is aligned to
        // 64 and every row is 64 bytes from its start).
        unsafe {
            let big = _mm512_set1_ps(RECIPROCAL_MAX);
            for a in 0..3 {
                // safe_reciprocal: (1 / d) clamped, as the AVX2 kernel.
                let inv = _mm512_div_ps(_mm512_set1_ps(1.0), _mm512_load_ps(p.dir[a].as_ptr()));
                let inv = _mm512_min_ps(
                    _mm512_max_ps(inv, _mm512_sub_ps(_mm512_setzero_ps(), big)),
                    big,
                );
                _mm512_store_ps(p.inv_dir[a].as_mut_ptr(), inv);
                p.positive[a] = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(inv, _mm512_setzero_ps());
            }
            let tmin = _mm512_load_ps(p.tmin.as_ptr());
            _mm512_store_ps(
                p.node_tmin.as_mut_ptr(),
                _mm512_mul_ps(tmin, _mm512_set1_ps(1.0 - SLAB_SLACK)),
            );
        }
        // Sign bits per ray: bit a set when axis a is negative.
        let sign = |r: usize| {
            (0..3).fold(0usize, |s, a| {
                s | (((p.positive[a] >> r) & 1 == 0) as usize) << a
            })
        };
        let first = sign(0);
        p.rows = (0..rays.len()).all(|r| sign(r) == first).then_some([
            first & 1,
            2 + (first >> 1 & 1),
            4 + (first >> 2 & 1),
        ]);
        p
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
        let mut used = 0u32;
        for (c, &child) in node.child.iter().enumerate() {
            used |= ((child != EMPTY) as u32) << c;
        }
        // SAFETY: `self.0` proves the CPU has AVX-512F; every load reads
        // sixteen f32 from a 64-byte aligned row of `p` (RaysSoa16 is aligned
        // to 64) or from `tmax` (an unaligned load). No closures (see the
        // AVX2 kernel).
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
                            out.near[c] = _mm512_mask_reduce_min_ps(hit, near);
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
        hits: &mut [Option<Hit>],
    ) -> u32 {
        leaf_closest_by_lanes(self, block, in_leaf, p, active, tmax, hits)
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &RaysSoa16, active: u32) -> u32 {
        leaf_any_by_lanes(self, block, in_leaf, p, &p.tmax, active)
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
        // of `p` (RaysSoa16 is aligned to 64) or sixteen f32 of `tmax`
        // (unaligned load); stores write sixteen f32 to local arrays.
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
                return (0, [0f32; 16], [0f32; 16], [0f32; 16]);
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
                & cmp!(_CMP_LT_OQ, t, _mm512_loadu_ps(tmax.as_ptr()));
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
