//! The packet kernels of the 8-wide tree's packet traversal
//! (`wide::packet`): how up to [`PACKET`] or [`PACKET16`] rays are tested
//! against a node's eight child boxes and against a leaf block's triangles.
//!
//! - [`PerRay`]: each ray with the single-ray kernels (any node kernel, any
//!   triangle test), lane by lane; the portable path.
//! - [`SimdPacket`]: the rays in the lanes of SIMD registers, one child box
//!   or one triangle at a time (Moller-Trumbore), written once over
//!   [`Lanes`](super::simd_lanes::Lanes): eight rays in AVX2 registers (`SimdPacket<Avx2>`, `--query
//!   packet8`) or sixteen in AVX-512 registers (`SimdPacket<Avx512>`,
//!   `--query packet16`, where the CPU has AVX-512F). Every lane runs the
//!   single-ray kernels' operations in the same order (the slab test of
//!   [`super::simd`] with the near plane chosen by the ray's sign, the
//!   Moller-Trumbore of [`super::leaf::intersect4`]), no fused multiply-add,
//!   so each ray gets the single-ray results bit for bit at either width
//!   (tested, and the two widths against each other).
//! - [`GrownPacket`]: the watertight test's packets, the same node test with
//!   every box grown as the single-ray grown test grows it, and at the
//!   leaves the watertight test on the lanes
//!   ([`super::simd_watertight`]), each lane bit for bit the scalar test.
//!
//! The SIMD kernel lays a packet out by lanes with in-register transposes
//! (the rays are `repr(C)`), finds its valid rays with a few vector
//! compares, and, when the rays agree in sign, bounds them by a [`Frustum`]
//! that skips with one 8-lane test per node the children no ray can enter
//! (Embree's coherent-packet idea, made exact here: tested to keep every
//! child a ray's own test enters). On the coherent rays of a render most
//! children are skipped (84% on cornell-water's primary rays).
//!
//! No `unsafe` here: the intrinsics are [`super::simd_lanes`]'s, behind the
//! [`Avx2`](super::simd::Avx2) and [`Avx512`](super::simd::Avx512) proofs.

use std::marker::PhantomData;

use arrayvec::ArrayVec;

use super::leaf::{bits, BlockTest, Ray4, Tri4, EMPTY_ID};
use super::params::{CULL_SLACK, SLAB_SLACK};
#[cfg(target_arch = "x86_64")]
use super::simd::Avx2;
use super::simd::{NodeKernel, WideRay};
#[cfg(target_arch = "x86_64")]
use super::simd_lanes::{LaneTriangles, Lanes};
#[cfg(target_arch = "x86_64")]
use super::simd_watertight::WatertightLanes;
use super::wide::WideNode;
#[cfg(target_arch = "x86_64")]
use super::wide::EMPTY;
use crate::geometry::{above_plane, below_plane, Hit, Ray, SlabRay, IN_PLANE_REACH};
#[cfg(target_arch = "x86_64")]
use crate::geometry::{BOX_GROWTH, RECIPROCAL_MAX, SLAB_GROW};

/// Rays per packet of the AVX2 kernel (`--query packet8`).
pub const PACKET: usize = 8;

/// Rays per packet of the AVX-512 kernel (`--query packet16`).
pub const PACKET16: usize = 16;

/// The margin (relative to the determinant) by which every lane's `u` must
/// lie outside [0, 1] for [`SimdPacket`]'s triangle test to stop before its
/// division: far above the division's rounding (2^-23), so a lane it stops
/// is one the full test rejects.
const U_MARGIN: f32 = 1.0 / (1 << 20) as f32;

/// Bounds on a packet's rays that let one 8-lane test per node skip the
/// children no ray of the packet can enter (the frustum test of Embree's
/// coherent packet traversal, here made exact for raylab's slab test).
///
/// Each ray's slab distance on an axis is `round(round(plane - o) * inv)`.
/// Rounding is monotone, so with `o` in `[o_lo, o_hi]` and `inv` in
/// `[inv_lo, inv_hi]` (one sign for all rays) the near plane's distance is at
/// least `min(d * inv_lo, d * inv_hi)` with `d = plane - o_hi` (`o_lo` when
/// the axis runs negative), both products rounded, and the far plane's at
/// most the `max` of the products with the other origin bound (the far
/// planes' reciprocals grown by [`SLAB_GROW`](crate::geometry::SLAB_GROW), as
/// each ray's own are: `SlabRay::inv_far`). A child whose least possible
/// entry exceeds its greatest possible exit (and the rays' `tmax`, as each
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
    /// Per axis, the least and greatest reciprocal direction, and the
    /// least and greatest exit planes' reciprocal (`SlabRay::inv_far`:
    /// rounding is monotone, so these are the products of the first two).
    inv_lo: [f32; 3],
    inv_hi: [f32; 3],
    inv_far_lo: [f32; 3],
    inv_far_hi: [f32; 3],
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
            (f.inv_far_lo[a], f.inv_far_hi[a]) = (f.inv_lo[a] * SLAB_GROW, f.inv_hi[a] * SLAB_GROW);
        }
        f
    }

    /// The children of `node` that some ray of the packet may enter, a bit
    /// per lane, and per lane the least entry distance any ray of the
    /// packet can have (at least the rays' least `tmin`): eight lanes, one
    /// per child, whatever the packet's width. With `GROWN`, the boxes
    /// grown as the watertight packets' node test grows them
    /// ([`GrownPacket`]): each plane moved out by [`Self::growth_bound`],
    /// at least any ray's own growth, before its distance is bounded (the
    /// rounded `(plane - o) -+ g` is monotone in `o` and `g`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn children<const GROWN: bool>(&self, l: Avx2, node: &WideNode<8>) -> (u32, [f32; 8]) {
        let b = &node.bounds;
        let g = if GROWN {
            self.growth_bound(l, node)
        } else {
            l.splat(0.0)
        };
        // Macros, not closures: a closure is compiled without the entry
        // point's target features, and the intrinsics would not inline.
        macro_rules! distance {
            ($row:expr, $o:expr, $pick:ident, $lo:expr, $hi:expr) => {{
                let row = $row;
                let mut d = l.sub(l.load(&b[row]), l.splat($o));
                if GROWN {
                    // A minimum plane moves down, a maximum one up.
                    d = if row & 1 == 0 {
                        l.sub(d, g)
                    } else {
                        l.add(d, g)
                    };
                }
                l.$pick(l.mul(d, l.splat($lo)), l.mul(d, l.splat($hi)))
            }};
        }
        macro_rules! near {
            ($a:expr) => {
                distance!(
                    self.near_row[$a],
                    self.o_near[$a],
                    min,
                    self.inv_lo[$a],
                    self.inv_hi[$a]
                )
            };
        }
        macro_rules! far {
            ($a:expr) => {
                distance!(
                    self.near_row[$a] ^ 1,
                    self.o_far[$a],
                    max,
                    self.inv_far_lo[$a],
                    self.inv_far_hi[$a]
                )
            };
        }
        let entry = l.max(
            l.max(near!(0), near!(1)),
            l.max(near!(2), l.splat(self.tmin)),
        );
        let exit = l.min(l.min(far!(0), far!(1)), l.min(far!(2), l.splat(self.tmax)));
        // Skipped only where entry > exit for sure (a NaN keeps the child).
        (!l.bits(l.gt(entry, exit)) & 0xFF, l.store(entry))
    }

    /// Per child of `node`, a bound on the growth of its box for every ray
    /// of the packet in the watertight packets' node test: [`BOX_GROWTH`]
    /// of the farthest a plane of the box lies from a corner of the
    /// origins' bounds. Each ray's growth is that of the farthest of its
    /// own distances `plane - o` (from the moved origins of a ray in a
    /// plane of an axis, which the bounds hold too), whose rounding is
    /// monotone in `o`: its magnitude is greatest at a bound.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn growth_bound(&self, l: Avx2, node: &WideNode<8>) -> <Avx2 as Lanes<8>>::F {
        let b = &node.bounds;
        let mut farthest = l.splat(0.0);
        for a in 0..3 {
            let (o_a, o_b) = (l.splat(self.o_near[a]), l.splat(self.o_far[a]));
            for row in [2 * a, 2 * a + 1] {
                let plane = l.load(&b[row]);
                farthest = l.max(
                    farthest,
                    l.max(l.abs(l.sub(plane, o_a)), l.abs(l.sub(plane, o_b))),
                );
            }
        }
        l.mul(l.min(farthest, l.splat(f32::MAX)), l.splat(BOX_GROWTH))
    }
}

/// The lanes of `node` that hold a child (unused ones hold [`EMPTY`]), a
/// bit per lane, in one compare.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn used_lanes(l: Avx2, node: &WideNode<8>) -> u32 {
    !l.bits(l.eq_u32(l.load_u32(&node.child), l.splat_u32(EMPTY))) & 0xFF
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

/// What a packet's node test shares across a node's children: the rays
/// tested, their `tmin` and `tmax` lanes, and, for a packet with a
/// frustum, its entry bound per child (the children are then ordered, and
/// culled when popped, by it: one vector for all children instead of a
/// reduction per child).
#[cfg(target_arch = "x86_64")]
struct ChildTest<L: Lanes<R>, const R: usize> {
    live: L::M,
    tmin: L::F,
    tmax: L::F,
    frustum_entry: Option<[f32; 8]>,
}

#[cfg(target_arch = "x86_64")]
impl<L: Lanes<R>, const R: usize> ChildTest<L, R> {
    /// The test of `node`'s children for the rays of `active` of packet
    /// `p` (within their `tmin` and `tmax`), and the children to test: the
    /// used lanes its frustum, if any, leaves (boxes grown when `GROWN`).
    #[inline(always)]
    fn of<const GROWN: bool>(
        l: L,
        p: &SoaRays<L, R>,
        node: &WideNode<8>,
        active: u32,
        tmax: &[f32; R],
    ) -> (Self, u32) {
        // `Frustum::children`, its boxes grown when `GROWN`; all eight
        // children and no bound without a frustum.
        let (frustum_used, frustum_entry) = match &p.frustum {
            Some(f) => {
                let (m, entry) = f.children::<GROWN>(l.avx2(), node);
                (m, Some(entry))
            }
            None => (0xFF, None),
        };
        let test = ChildTest {
            live: l.mask(active),
            tmin: p.node_tmin,
            tmax: l.load(tmax),
            frustum_entry,
        };
        (test, used_lanes(l.avx2(), node) & frustum_used)
    }

    /// Child `c` into `out` from its rays' entry and exit distances per
    /// axis: the rays whose entry is not past their exit, and (with
    /// `NEAR`) a lower bound on their entries.
    #[inline(always)]
    fn record<const NEAR: bool>(
        &self,
        l: L,
        out: &mut NodeHits,
        c: usize,
        entry: [L::F; 3],
        exit: [L::F; 3],
    ) {
        let near = l.max(l.max(entry[0], entry[1]), l.max(entry[2], self.tmin));
        let far = l.min(l.min(exit[0], exit[1]), l.min(exit[2], self.tmax));
        let hit = l.and(l.le(near, far), self.live);
        let rays = l.bits(hit);
        if rays != 0 {
            out.lanes |= 1 << c;
            out.rays[c] = rays;
            if NEAR {
                out.near[c] = match &self.frustum_entry {
                    Some(entry) => entry[c],
                    None => l.min_where(hit, near),
                };
            }
        }
    }
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
        inst: 0,
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
            inst: 0,
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

/// Each ray with the single-ray node kernel `K` (its test for `T`,
/// [`NodeKernel::intersect_for`]) and block test `T`.
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
                wray: WideRay::new(&SlabRay::new(ray)),
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
            let (hit, entry) = self
                .kernel
                .intersect_for::<T>(node, &lane.wray, lane.tmin, tmax[r]);
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

/// The rays of a packet in the lanes of SIMD registers ([`Lanes`](super::simd_lanes::Lanes): eight in
/// AVX2, sixteen in AVX-512), Moller-Trumbore at the leaves.
#[derive(Clone, Copy, Debug)]
pub struct SimdPacket<L>(pub L);

/// A packet by lanes, for [`SimdPacket`]; lanes past the packet hold zeros
/// (never read: every result is masked by the active rays).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct SoaRays<L: Lanes<R>, const R: usize> {
    origin: [L::F; 3],
    /// Whether a valid ray lies in a plane of some axis (a zero direction
    /// component): its node tests measure each plane from its own origin
    /// ([`SlabRay`]), computed per node test (fields for them cost the
    /// common packets 10% of their time: measured).
    in_plane: bool,
    dir: [L::F; 3],
    inv_dir: [L::F; 3],
    /// `inv_dir * SLAB_GROW`, for the far planes (`SlabRay::inv_far`).
    inv_far: [L::F; 3],
    /// Per axis, the lanes whose reciprocal direction is >= 0 (the near
    /// plane is the box's minimum, as [`WideRay`] chooses it).
    positive: [L::M; 3],
    /// The near plane's row per axis ([`WideRay::near`]) when every ray of
    /// the packet has the same signs (the usual case for neighbouring rays).
    rows: Option<[usize; 3]>,
    /// The node kernel's `tmin` (widened by [`SLAB_SLACK`]) and the
    /// triangle test's.
    node_tmin: L::F,
    tmin: L::F,
    tmax: L::F,
    /// Bounds on the rays when they agree in sign, to skip the children no
    /// ray can enter.
    frustum: Option<Frustum>,
}

#[cfg(target_arch = "x86_64")]
impl<L: Lanes<R>, const R: usize> SoaRays<L, R> {
    /// SlabRay's origins per axis, the minimum planes' and the maximum
    /// planes': the rays' own, moved by above_plane's and below_plane's
    /// operations in the lanes of rays lying in a plane of the axis.
    #[inline(always)]
    fn slab_origins(&self, l: L) -> ([L::F; 3], [L::F; 3]) {
        let (mut from_min, mut from_max) = (self.origin, self.origin);
        if self.in_plane {
            let (eps, reach) = (l.splat(f32::EPSILON), l.splat(IN_PLANE_REACH));
            let zero = l.splat(0.0);
            for a in 0..3 {
                let o = self.origin[a];
                let step = l.max(l.mul(l.abs(o), eps), reach);
                let flat = l.eq(self.dir[a], zero);
                from_min[a] = l.blend(flat, o, l.add(o, step));
                from_max[a] = l.blend(flat, o, l.sub(o, step));
            }
        }
        (from_min, from_max)
    }
}

#[cfg(target_arch = "x86_64")]
impl<L: Lanes<R>, const R: usize> PacketKernel<R> for SimdPacket<L> {
    type Rays = SoaRays<L, R>;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> (Self::Rays, u32) {
        let l = self.0;
        debug_assert!(rays.len() <= R);
        let (components, loaded) = l.load_rays(rays);
        let valid = l.bits(l.valid_rays(&components));
        let [ox, oy, oz, dx, dy, dz, tmin, tmax] = components;
        let zero = l.splat(0.0);
        // Macros, not closures (see `Frustum::children`).
        macro_rules! nonzero {
            ($v:expr) => {
                l.ne($v, zero)
            };
        }
        // safe_reciprocal: (1 / d) clamped (see RECIPROCAL_MAX).
        let big = l.splat(RECIPROCAL_MAX);
        macro_rules! inv {
            ($d:expr) => {
                l.min(l.max(l.div(l.splat(1.0), $d), l.sub(zero, big)), big)
            };
        }
        let inv_dir = [inv!(dx), inv!(dy), inv!(dz)];
        let grow = l.splat(SLAB_GROW);
        // Not `map`: a closure is compiled without the entry point's target
        // features (see `Frustum::children`).
        let inv_far = [
            l.mul(inv_dir[0], grow),
            l.mul(inv_dir[1], grow),
            l.mul(inv_dir[2], grow),
        ];
        let positive = [
            l.ge(inv_dir[0], zero),
            l.ge(inv_dir[1], zero),
            l.ge(inv_dir[2], zero),
        ];
        let rows = shared_near_rows(positive.map(|m| l.bits(m)), rays.len());
        // Whether rays lie in a plane of an axis (rare: axis-aligned
        // directions), for the node tests and the frustum.
        let in_plane = [
            l.bits(l.andnot(nonzero!(dx), l.mask(valid))) != 0,
            l.bits(l.andnot(nonzero!(dy), l.mask(valid))) != 0,
            l.bits(l.andnot(nonzero!(dz), l.mask(valid))) != 0,
        ];
        // The valid rays' bounds, component by component (lanes 0-7); lanes
        // 3-5 of `inv_of_*`: the reciprocals of the directions' bounds.
        let (lo, hi) = l.ray_bounds(&loaded, valid);
        let (inv_of_lo, inv_of_hi) = (l.store(inv!(lo)), l.store(inv!(hi)));
        let (mut lo, mut hi) = (l.store(lo), l.store(hi));
        // The frustum's origin bounds, widened as SlabRay widens the origins
        // of in-plane rays (above_plane and below_plane are monotone, so the
        // bounds' images bound every ray's).
        for a in (0..3).filter(|&a| in_plane[a]) {
            (lo[a], hi[a]) = (below_plane(lo[a]), above_plane(hi[a]));
        }
        let frustum = rows
            .filter(|_| valid != 0)
            .map(|rows| Frustum::of_lanes(rows, &lo, &hi, &inv_of_lo, &inv_of_hi));
        (
            SoaRays {
                origin: [ox, oy, oz],
                in_plane: in_plane.contains(&true),
                dir: [dx, dy, dz],
                inv_dir,
                inv_far,
                positive,
                rows,
                node_tmin: l.mul(tmin, l.splat(1.0 - SLAB_SLACK)),
                tmin,
                tmax,
                frustum,
            },
            valid,
        )
    }

    #[inline(always)]
    fn coherent(p: &Self::Rays) -> bool {
        p.frustum.is_some()
    }

    #[inline(always)]
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        p: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
    ) -> NodeHits {
        let l = self.0;
        let mut out = NodeHits {
            rays: [0; 8],
            near: [f32::INFINITY; 8],
            lanes: 0,
        };
        let (inv, inv_far) = (p.inv_dir, p.inv_far);
        // A coherent packet's children are ordered (and culled when popped)
        // by the frustum's least possible entry (as Embree's coherent
        // packets are): a bound on the rays' own entries.
        let (test, used) = ChildTest::of::<false>(l, p, node, active, tmax);
        let b = &node.bounds;
        // Per axis the single-ray kernel's (plane - origin) * inv with the
        // plane the ray's sign makes near, and the far one: the same row for
        // all rays when they agree in sign (`p.rows`), else both planes
        // computed and each ray's chosen by a blend. Macros, not closures
        // (see `Frustum::children`).
        macro_rules! plane {
            ($row:expr, $inv:expr, $c:expr, $origin:expr) => {
                l.mul(l.sub(l.splat(b[$row][$c]), $origin), $inv)
            };
        }
        // One child: its rays' box test from the slab distances per axis.
        macro_rules! child {
            ($c:expr, ($nx:expr, $fx:expr), ($ny:expr, $fy:expr), ($nz:expr, $fz:expr)) => {
                test.record::<NEAR>(l, &mut out, $c, [$nx, $ny, $nz], [$fx, $fy, $fz])
            };
        }
        match p.rows {
            Some([rx, ry, rz]) if !p.in_plane => {
                // The common case, every plane measured from the origin
                // (three registers, not six).
                let o = p.origin;
                for c in bits(used) {
                    child!(
                        c,
                        (
                            plane!(rx, inv[0], c, o[0]),
                            plane!(rx ^ 1, inv_far[0], c, o[0])
                        ),
                        (
                            plane!(ry, inv[1], c, o[1]),
                            plane!(ry ^ 1, inv_far[1], c, o[1])
                        ),
                        (
                            plane!(rz, inv[2], c, o[2]),
                            plane!(rz ^ 1, inv_far[2], c, o[2])
                        )
                    );
                }
            }
            // Mixed signs, or a ray lying in a plane of some axis: both
            // planes per axis, each measured from its own origin
            // (`SlabRay`), each ray's chosen by a blend.
            _ => {
                let (from_min, from_max) = p.slab_origins(l);
                macro_rules! blended {
                    ($a:expr, $c:expr) => {{
                        // Each plane's offset once, times the near and the
                        // far reciprocal.
                        let to_min = l.sub(l.splat(b[2 * $a][$c]), from_min[$a]);
                        let to_max = l.sub(l.splat(b[2 * $a + 1][$c]), from_max[$a]);
                        let (near_inv, far_inv) = (inv[$a], inv_far[$a]);
                        (
                            l.blend(
                                p.positive[$a],
                                l.mul(to_max, near_inv),
                                l.mul(to_min, near_inv),
                            ),
                            l.blend(
                                p.positive[$a],
                                l.mul(to_min, far_inv),
                                l.mul(to_max, far_inv),
                            ),
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
        out
    }

    #[inline(always)]
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        p: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
        hits: &mut PacketHits<R>,
    ) -> u32 {
        closest_in_block(self.0, p, block, in_leaf, active, tmax, hits)
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &Self::Rays, active: u32) -> u32 {
        any_in_block(self.0, p, block, in_leaf, active)
    }

    #[inline(always)]
    fn tighten(self, hits: &PacketHits<R>, changed: u32, tmax: &mut [f32; R], cut: &mut [f32; R]) {
        let l = self.0;
        // The rays with a hit (`tri` is not EMPTY_ID), as the default method.
        let no_hit = l.eq_u32(l.load_u32(&hits.tri), l.splat_u32(EMPTY_ID));
        let with_hit = l.andnot(no_hit, l.mask(changed));
        let t = l.load(&hits.t);
        // A hit's t is above tmin >= 0 (finite, positive): the next float
        // up is its bits plus one, as `leaf_closest` has it.
        l.store_where(tmax, with_hit, l.bits_plus_one(t));
        l.store_where(cut, with_hit, l.mul(t, l.splat(1.0 + CULL_SLACK)));
    }

    #[inline(always)]
    fn reach(self, near: f32, cut: &[f32; R]) -> u32 {
        let l = self.0;
        l.bits(l.le(l.splat(near), l.load(cut)))
    }
}

#[cfg(target_arch = "x86_64")]
impl<L: Lanes<R>, const R: usize> LaneTriangles<L, R> for SoaRays<L, R> {
    #[inline(always)]
    fn triangle(
        &self,
        l: L,
        block: &Tri4,
        i: usize,
        _: L::M,
        tmax: L::F,
    ) -> (L::M, L::F, L::F, L::F) {
        SimdPacket(l).triangle(block, i, self, tmax)
    }

    #[inline(always)]
    fn tmax(&self) -> L::F {
        self.tmax
    }
}

/// [`PacketKernel::leaf_closest`] with the lane test of `p`, one triangle
/// at a time for every ray.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn closest_in_block<L: Lanes<R>, P: LaneTriangles<L, R>, const R: usize>(
    l: L,
    p: &P,
    block: &Tri4,
    in_leaf: u32,
    active: u32,
    tmax: &[f32; R],
    hits: &mut PacketHits<R>,
) -> u32 {
    // The hits and the rays' `tmax` stay in registers through the
    // block: a lane takes a triangle's hit where it is closer by
    // `Hit::is_closer_than` (t below, or equal with a lower index; the
    // index compare unsigned, as `u32`'s), and its `tmax` becomes the
    // hit's `t.next_up()`: for the positive `t` a hit has (above
    // `tmin >= 0`), the next float up is the bits plus one.
    let mut limit = l.load(tmax);
    let mut best_t = l.load(&hits.t);
    let mut best_u = l.load(&hits.u);
    let mut best_v = l.load(&hits.v);
    let mut best_tri = l.load_u32(&hits.tri);
    let live = l.mask(active);
    let mut changed = l.mask(0);
    for i in bits(in_leaf) {
        let id = block.ids[i];
        if id == EMPTY_ID {
            continue;
        }
        let (ok, t, u, v) = p.triangle(l, block, i, live, limit);
        let found = l.and(ok, live);
        if l.bits(found) == 0 {
            continue;
        }
        let idv = l.splat_u32(id);
        let closer = l.or(
            l.and(found, l.lt(t, best_t)),
            l.and(l.and(found, l.eq(t, best_t)), l.lt_u32(idv, best_tri)),
        );
        best_t = l.blend(closer, best_t, t);
        best_u = l.blend(closer, best_u, u);
        best_v = l.blend(closer, best_v, v);
        best_tri = l.blend_u32(closer, best_tri, idv);
        limit = l.blend(closer, limit, l.bits_plus_one(t));
        changed = l.or(changed, closer);
    }
    let changed = l.bits(changed);
    if changed != 0 {
        hits.t = l.store(best_t);
        hits.u = l.store(best_u);
        hits.v = l.store(best_v);
        l.store_u32(&mut hits.tri, best_tri);
    }
    changed
}

/// [`PacketKernel::leaf_any`] with the lane test of `p`: the rays of
/// `active` that hit a lane `in_leaf` of `block` within their segment, one
/// triangle at a time.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn any_in_block<L: Lanes<R>, P: LaneTriangles<L, R>, const R: usize>(
    l: L,
    p: &P,
    block: &Tri4,
    in_leaf: u32,
    active: u32,
) -> u32 {
    let mut hit = 0;
    for i in bits(in_leaf) {
        if block.ids[i] == EMPTY_ID {
            continue;
        }
        let live = l.mask(active & !hit);
        hit |= l.bits(p.triangle(l, block, i, live, p.tmax()).0) & active & !hit;
        if hit == active {
            break;
        }
    }
    hit
}

#[cfg(target_arch = "x86_64")]
impl<L> SimdPacket<L> {
    /// Moller-Trumbore of the rays against lane `i` of `block`, the
    /// operations of [`super::leaf::intersect4`] in the same order: the
    /// lanes that hit within `(tmin, tmax)`, and each lane's t, u and v
    /// (meaningful where they hit).
    #[inline(always)]
    fn triangle<const R: usize>(
        self,
        block: &Tri4,
        i: usize,
        p: &SoaRays<L, R>,
        tmax: L::F,
    ) -> (L::M, L::F, L::F, L::F)
    where
        L: Lanes<R>,
    {
        let l = self.0;
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
        // Macros, not closures (see `Frustum::children`).
        macro_rules! s {
            ($x:expr) => {
                l.splat($x)
            };
        }
        macro_rules! add {
            ($a:expr, $b:expr) => {
                l.add($a, $b)
            };
        }
        macro_rules! sub {
            ($a:expr, $b:expr) => {
                l.sub($a, $b)
            };
        }
        macro_rules! mul {
            ($a:expr, $b:expr) => {
                l.mul($a, $b)
            };
        }
        let [ox, oy, oz] = p.origin;
        let [dx, dy, dz] = p.dir;
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
        // Before dividing: when every lane's u = u_num / det lies outside
        // [0, 1] by more than U_MARGIN (u_num * sign(det) against |det|,
        // exact but for the margin), no rounding of the division below can
        // bring it back, and no lane hits. NaN lanes compare false and go on
        // to the full test, which rejects them.
        let abs_det = l.abs(det);
        let signed = l.flip_sign(u_num, det);
        let margin = mul!(abs_det, s!(U_MARGIN));
        let outside = l.or(
            l.lt(signed, sub!(s!(0.0), margin)),
            l.gt(signed, add!(abs_det, margin)),
        );
        if l.bits(outside) == ((1u64 << R) - 1) as u32 {
            let zero = s!(0.0);
            return (l.mask(0), zero, zero, zero);
        }
        let inv_det = l.div(s!(1.0), det);
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
        let ok = l.and(
            l.and(
                l.and(l.ge(abs_det, s!(f32::MIN_POSITIVE)), l.ge(u, s!(0.0))),
                l.and(l.le(u, s!(1.0)), l.ge(v, s!(0.0))),
            ),
            l.and(
                l.and(l.le(add!(u, v), s!(1.0)), l.gt(t, p.tmin)),
                l.lt(t, tmax),
            ),
        );
        (ok, t, u, v)
    }
}

/// The watertight test's packets: [`SimdPacket`]'s node test across the
/// rays' lanes with every box grown as
/// [`NodeKernel::intersect_grown`] grows it (by [`BOX_GROWTH`] of its
/// farthest distance from each ray's origin), and the watertight test
/// across the lanes at the leaves ([`WatertightLanes`]). Rays that agree
/// in sign keep their [`Frustum`], its boxes grown by a bound on every
/// ray's growth (`Frustum::children::<true>`). Before it each ray of a watertight
/// packet walked the tree with the single-ray kernels, and the packets were
/// slower than single rays; then each ray tested the leaves on its own,
/// four triangles at a time, and the packets spent 4-5x Moller-Trumbore
/// packets' time on coherent rays. Only for [`Watertight`](crate::geometry::Watertight)
/// (its leaves are that test, whatever block test the traversal's
/// single-ray finish uses).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct GrownPacket<L>(pub L);

/// A packet for [`GrownPacket`]: by lanes for the node tests, and for the
/// watertight test.
#[cfg(target_arch = "x86_64")]
pub struct GrownRays<L: Lanes<R>, const R: usize> {
    soa: SoaRays<L, R>,
    watertight: WatertightLanes<L, R>,
}

#[cfg(target_arch = "x86_64")]
impl<L: Lanes<R>, const R: usize> PacketKernel<R> for GrownPacket<L> {
    type Rays = GrownRays<L, R>;

    #[inline(always)]
    fn prepare(self, rays: &[Ray]) -> (Self::Rays, u32) {
        let (soa, valid) = SimdPacket(self.0).prepare(rays);
        let watertight = WatertightLanes::new(self.0, rays);
        (GrownRays { soa, watertight }, valid)
    }

    /// Whether the rays agree in sign on every axis.
    #[inline(always)]
    fn coherent(p: &Self::Rays) -> bool {
        p.soa.rows.is_some()
    }

    #[inline(always)]
    fn node<const NEAR: bool>(
        self,
        node: &WideNode<8>,
        p: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
    ) -> NodeHits {
        let (l, s) = (self.0, &p.soa);
        let mut out = NodeHits {
            rays: [0; 8],
            near: [f32::INFINITY; 8],
            lanes: 0,
        };
        let (inv, inv_far) = (s.inv_dir, s.inv_far);
        // A packet with one sign per axis skips the children its frustum's
        // grown boxes rule out, and orders them by the frustum's entry
        // bound, as SimdPacket.
        let (test, used) = ChildTest::of::<true>(l, s, node, active, tmax);
        let b = &node.bounds;
        let (from_min, from_max) = s.slab_origins(l);
        let (growth, cap) = (l.splat(BOX_GROWTH), l.splat(f32::MAX));
        // Macros, not closures (see `Frustum::children`).
        macro_rules! planes {
            ($a:expr, $c:expr) => {
                (
                    l.sub(l.splat(b[2 * $a][$c]), from_min[$a]),
                    l.sub(l.splat(b[2 * $a + 1][$c]), from_max[$a]),
                )
            };
        }
        // Each ray's entry and exit on axis `a` of its box grown by `g`.
        macro_rules! slab {
            ($to_min:expr, $to_max:expr, $g:expr, $a:expr) => {{
                let (lo, hi) = (l.sub($to_min, $g), l.add($to_max, $g));
                (
                    l.blend(s.positive[$a], l.mul(hi, inv[$a]), l.mul(lo, inv[$a])),
                    l.blend(
                        s.positive[$a],
                        l.mul(lo, inv_far[$a]),
                        l.mul(hi, inv_far[$a]),
                    ),
                )
            }};
        }
        // Each ray's growth of child `c`'s box: BOX_GROWTH of the farthest
        // of its planes, from the planes' distances.
        macro_rules! growth_of {
            ($x0:expr, $x1:expr, $y0:expr, $y1:expr, $z0:expr, $z1:expr) => {{
                let farthest = l.max(
                    l.max(l.max(l.abs($x0), l.abs($x1)), l.max(l.abs($y0), l.abs($y1))),
                    l.max(l.abs($z0), l.abs($z1)),
                );
                l.mul(l.min(farthest, cap), growth)
            }};
        }
        // With one sign per axis for every ray and no ray in a plane (the
        // usual packet): each axis's near and far planes known once for the
        // packet, two products per axis instead of four and a blend; the
        // same values (the near plane moved out by `g` is `to_min - g` or
        // `to_max + g`, and `x + (-g)` is `x - g` exactly, zeros included).
        let shared_rows = s.rows.filter(|_| !s.in_plane);
        for c in bits(used) {
            let ((x0, x1), (y0, y1), (z0, z1)) = (planes!(0, c), planes!(1, c), planes!(2, c));
            let g = growth_of!(x0, x1, y0, y1, z0, z1);
            let ((nx, fx), (ny, fy), (nz, fz)) = match shared_rows {
                Some(rows) => {
                    let minus_g = l.flip_sign(g, l.splat(-1.0));
                    macro_rules! known {
                        ($to_min:expr, $to_max:expr, $a:expr) => {{
                            if rows[$a] & 1 == 0 {
                                (
                                    l.mul(l.add($to_min, minus_g), inv[$a]),
                                    l.mul(l.add($to_max, g), inv_far[$a]),
                                )
                            } else {
                                (
                                    l.mul(l.add($to_max, g), inv[$a]),
                                    l.mul(l.add($to_min, minus_g), inv_far[$a]),
                                )
                            }
                        }};
                    }
                    (known!(x0, x1, 0), known!(y0, y1, 1), known!(z0, z1, 2))
                }
                None => (
                    slab!(x0, x1, g, 0),
                    slab!(y0, y1, g, 1),
                    slab!(z0, z1, g, 2),
                ),
            };
            test.record::<NEAR>(l, &mut out, c, [nx, ny, nz], [fx, fy, fz]);
        }
        out
    }

    #[inline(always)]
    fn leaf_closest(
        self,
        block: &Tri4,
        in_leaf: u32,
        p: &Self::Rays,
        active: u32,
        tmax: &[f32; R],
        hits: &mut PacketHits<R>,
    ) -> u32 {
        closest_in_block(self.0, &p.watertight, block, in_leaf, active, tmax, hits)
    }

    #[inline(always)]
    fn leaf_any(self, block: &Tri4, in_leaf: u32, p: &Self::Rays, active: u32) -> u32 {
        any_in_block(self.0, &p.watertight, block, in_leaf, active)
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::bvh::simd::{Avx512, Portable};
    use crate::accel::bvh::simd_lanes::Lanes;
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
            let (got_p, got_active) = SimdPacket(avx2).prepare(short);
            assert_eq!(got_active, active, "valid rays, packet {k}");
            let tmax: [f32; PACKET] = std::array::from_fn(|r| short.get(r).map_or(0.0, |r| r.tmax));
            for near in [false, true] {
                let (want, got) = if near {
                    (
                        reference.node::<true>(&node, &want_p, active, &tmax),
                        SimdPacket(avx2).node::<true>(&node, &got_p, active, &tmax),
                    )
                } else {
                    (
                        reference.node::<false>(&node, &want_p, active, &tmax),
                        SimdPacket(avx2).node::<false>(&node, &got_p, active, &tmax),
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
                let kept = f.children::<false>(avx2, &node).0 & used;
                tested += used.count_ones();
                skipped += (used & !kept).count_ones();
            }
            let Some(avx512) = avx512 else { continue };
            let (want_p, active) = PacketKernel::<PACKET16>::prepare(reference, &rays);
            let (got_p, got_active) = SimdPacket(avx512).prepare(&rays);
            assert_eq!(got_active, active, "valid rays, packet {k}");
            let tmax: [f32; PACKET16] =
                std::array::from_fn(|r| rays.get(r).map_or(0.0, |r| r.tmax));
            let want = reference.node::<true>(&node, &want_p, active, &tmax);
            let got = SimdPacket(avx512).node::<true>(&node, &got_p, active, &tmax);
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

    /// The watertight packets' node test ([`GrownPacket`]) keeps, per ray
    /// and child, every box the single-ray grown test keeps
    /// ([`NodeKernel::intersect_grown`], ray by ray), on coherent packets,
    /// packets whose rays differ in sign, and rays lying in a plane of an
    /// axis; with an entry bound no later than the exact boxes' entry.
    #[test]
    fn grown_packets_keep_every_box_the_single_ray_grown_test_keeps() {
        use crate::geometry::Watertight;
        let Some(avx2) = Avx2::detect() else {
            eprintln!("no AVX2 on this CPU: the grown packet node test is not tested");
            return;
        };
        let avx512 = Avx512::detect();
        let mut rng = Rng::for_pixel(2, 9, 5);
        let (mut kept, mut grown_only) = (0u32, 0u32);
        for k in 0..20_000 {
            let spread_o = [0.0, 1e-3, 0.3][k % 3];
            let spread_d = [0.0, 1e-3, 0.05][k / 3 % 3];
            let mut rays = coherent(&mut rng, 1 + k % PACKET16, spread_o, spread_d);
            if k % 4 == 1 {
                // Mixed signs: every other ray turned around.
                for r in rays.iter_mut().step_by(2) {
                    r.dir = -r.dir;
                }
            }
            if k % 4 == 2 {
                for r in rays.iter_mut().step_by(3) {
                    r.dir.x = 0.0;
                }
            }
            let node = node_around(&mut rng, &rays);
            let grown = PerRay::<Portable, Watertight>::new(Portable);
            let exact = PerRay::<Portable, MollerTrumbore>::new(Portable);
            macro_rules! check {
                ($lanes:expr, $width:expr, $rays:expr) => {{
                    let rays: &[Ray] = $rays;
                    let packet = GrownPacket($lanes);
                    let (want_p, active) = PacketKernel::<$width>::prepare(grown, rays);
                    let (exact_p, _) = PacketKernel::<$width>::prepare(exact, rays);
                    let (got_p, got_active) = PacketKernel::<$width>::prepare(packet, rays);
                    assert_eq!(got_active, active, "valid rays, packet {k}");
                    let tmax: [f32; $width] =
                        std::array::from_fn(|r| rays.get(r).map_or(0.0, |r| r.tmax));
                    let want = grown.node::<true>(&node, &want_p, active, &tmax);
                    let plain = exact.node::<true>(&node, &exact_p, active, &tmax);
                    let got = packet.node::<true>(&node, &got_p, active, &tmax);
                    for c in 0..8 {
                        assert_eq!(
                            got.rays[c] & want.rays[c],
                            want.rays[c],
                            "packet {k} child {c}: {rays:?} {node:?}"
                        );
                        if plain.rays[c] != 0 {
                            assert!(got.near[c] <= plain.near[c], "packet {k} child {c}");
                        }
                        // The entry the traversal orders and culls by is a
                        // lower bound on each kept ray's own grown entry.
                        if want.rays[c] != 0 {
                            assert!(
                                got.near[c] <= want.near[c],
                                "packet {k} child {c}: {} > {}",
                                got.near[c],
                                want.near[c]
                            );
                        }
                        kept += want.rays[c].count_ones();
                        grown_only += (got.rays[c] & !plain.rays[c]).count_ones();
                    }
                }};
            }
            check!(avx2, PACKET, &rays[..rays.len().min(PACKET)]);
            if let Some(avx512) = avx512 {
                check!(avx512, PACKET16, &rays);
            }
        }
        assert!(
            kept > 10_000 && grown_only > 0,
            "{kept} kept, {grown_only} by the growth alone"
        );
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
                    inst: 0,
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
            SimdPacket(avx2).tighten(&hits, changed, &mut got_tmax, &mut got_cut);
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
            SimdPacket(avx512).tighten(&hits, changed, &mut got_tmax, &mut got_cut);
            assert_eq!(bits_of(&got_tmax), bits_of(&want_tmax), "AVX-512 case {k}");
            assert_eq!(bits_of(&got_cut), bits_of(&want_cut), "AVX-512 case {k}");
        }
    }

    /// Triangles for the kernels to disagree on if they could: small random
    /// ones, a degenerate one (collinear), a sliver, a large one, and
    /// copies of one another (ties at the same t, told apart by index).
    fn adversarial_tris(rng: &mut Rng) -> Vec<[Vec3; 3]> {
        let mut v = |s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        let c = v(4.0) - Vec3::splat(2.0);
        let small = [c + v(1.0), c + v(1.0), c + v(1.0)];
        let (a, b) = (v(4.0) - Vec3::splat(2.0), v(4.0) - Vec3::splat(2.0));
        let collinear = [a, b, a + (b - a) * 0.25];
        let sliver = [a, b, (a + b) * 0.5 + Vec3::splat(1e-6)];
        let large = [
            Vec3::new(-1e4, -1e4, c.z),
            Vec3::new(1e4, -1e4, c.z + 1.0),
            Vec3::new(0.0, 1e4, c.z),
        ];
        vec![
            small,
            collinear,
            sliver,
            large,
            small,
            [c + v(1.0), c, c + v(1.0)],
        ]
    }

    /// Sixteen rays against `tris`: aimed at a vertex, an edge's midpoint or
    /// the centre (the aim at t = 1, and some segments ending exactly
    /// there), along an edge's line (in the triangle's plane),
    /// axis-parallel with zero and negative-zero components, huge and tiny
    /// coordinates, random, and invalid ones.
    fn adversarial_rays(rng: &mut Rng, tris: &[[Vec3; 3]]) -> Vec<Ray> {
        (0..PACKET16)
            .map(|r| {
                let mut f = || rng.next_f32();
                let tri = tris[(f() * tris.len() as f32) as usize % tris.len()];
                let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
                let o = Vec3::new(f(), f(), f()) * 8.0 - Vec3::splat(4.0);
                let toward = |aim: Vec3| Ray::new(o, aim - o);
                let mut ray = match (f() * 10.0) as usize {
                    0 => toward(tri[r % 3]),
                    1 => toward((tri[r % 3] + tri[(r + 1) % 3]) * 0.5),
                    2 => toward(centre),
                    3 => Ray::new(tri[0] * 2.0 - tri[1], tri[1] - tri[0]),
                    4 => {
                        let axes = [
                            Vec3::X,
                            -Vec3::Y,
                            Vec3::new(0.0, -0.0, 1.0),
                            Vec3::new(-0.0, 0.0, -1.0),
                        ];
                        let d = axes[r % 4];
                        Ray::new(centre - d * 3.0, d)
                    }
                    5 => Ray::new(o * 1e18, centre - o * 1e18),
                    6 => Ray::new(o, (centre - o) * 1e-30),
                    7 => [
                        Ray::new(o, Vec3::ZERO),
                        Ray::new(Vec3::splat(f32::NAN), Vec3::X),
                        Ray::new(o, Vec3::new(f32::INFINITY, 0.0, 1.0)),
                        Ray::segment(o, Vec3::X, 2.0, 1.0),
                    ][r % 4],
                    _ => Ray::new(o, Vec3::new(f(), f(), f()) * 2.0 - Vec3::ONE),
                };
                match (f() * 4.0) as usize {
                    0 => ray.tmax = 1.0,
                    1 => ray.tmax = f() * 3.0,
                    2 => ray.tmin = f() * 0.5,
                    _ => {}
                }
                ray
            })
            .collect()
    }

    /// Everything the SIMD kernel `k` answers about each ray of `rays`, as
    /// bits, a record per ray: its validity; per block and triangle lane
    /// the triangle test (hit, t, u, v); the closest-hit merge of the
    /// blocks in turn (rays changed, hits, tightened limits); the any-hit
    /// test; the node test (per child, with and without entry bounds).
    fn records<L: Lanes<R>, const R: usize>(
        k: SimdPacket<L>,
        rays: &[Ray],
        blocks: &[Tri4],
        node: &WideNode<8>,
    ) -> Vec<Vec<u32>> {
        let l = k.0;
        let (p, valid) = k.prepare(rays);
        let mut rec: Vec<Vec<u32>> = (0..rays.len()).map(|r| vec![valid >> r & 1]).collect();
        let mut tmax: [f32; R] = std::array::from_fn(|r| rays.get(r).map_or(0.0, |r| r.tmax));
        let mut cut: [f32; R] = tmax.map(|t| t * (1.0 + CULL_SLACK));
        let mut hits = PacketHits::<R>::none();
        let all = (1u32 << rays.len()) - 1;
        for block in blocks {
            for i in 0..4 {
                let (ok, t, u, v) = k.triangle(block, i, &p, l.load(&tmax));
                let (ok, t, u, v) = (l.bits(ok), l.store(t), l.store(u), l.store(v));
                for (r, rec) in rec.iter_mut().enumerate() {
                    let hit = ok >> r & 1;
                    rec.push(hit);
                    if hit == 1 {
                        rec.extend([t[r].to_bits(), u[r].to_bits(), v[r].to_bits()]);
                    }
                }
            }
            let changed = k.leaf_closest(block, 0xF, &p, valid, &tmax, &mut hits);
            k.tighten(&hits, changed, &mut tmax, &mut cut);
            let any = k.leaf_any(block, 0xF, &p, valid);
            let reach = k.reach(1.0, &cut);
            for (r, rec) in rec.iter_mut().enumerate() {
                let h = hits.lanes(r);
                rec.extend([changed >> r & 1, any >> r & 1, reach >> r & 1]);
                rec.extend([h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.tri]);
                rec.extend([tmax[r].to_bits(), cut[r].to_bits()]);
            }
        }
        let near = k.node::<true>(node, &p, valid & all, &cut);
        let far = k.node::<false>(node, &p, valid & all, &cut);
        for (r, rec) in rec.iter_mut().enumerate() {
            rec.extend((0..8).map(|c| (near.rays[c] >> r & 1) | (far.rays[c] >> r & 1) << 1));
        }
        rec
    }

    /// The AVX2 kernel (rays 0-7 and 8-15 as two packets) and the AVX-512
    /// kernel (all sixteen in one) answer every ray the same bit for bit:
    /// triangle tests, closest-hit merges with ties between copies of a
    /// triangle (indices on both sides of 2^31: the unsigned compare),
    /// tightened limits, any-hit tests and node tests, on random and
    /// adversarial rays, triangles and boxes.
    #[test]
    fn avx2_and_avx512_kernels_agree_bit_for_bit() {
        let (Some(avx2), Some(avx512)) = (Avx2::detect(), Avx512::detect()) else {
            eprintln!("no AVX-512 on this CPU: the AVX2 and AVX-512 kernels are not compared");
            return;
        };
        let mut rng = Rng::for_pixel(13, 8, 21);
        let mut hits = 0;
        for k in 0..3_000 {
            let tris = adversarial_tris(&mut rng);
            let rays = if k % 4 == 3 {
                coherent(&mut rng, PACKET16, 1e-3, 0.05)
            } else {
                adversarial_rays(&mut rng, &tris)
            };
            // The same triangles in a second block with other indices (the
            // copies tie), some of them above 2^31.
            let ids = [5, 9, 0x8000_0003, 1];
            let ids2 = [0x8000_0001, 3, 7, 0xFFFF_FFF0];
            let blocks = [
                Tri4::new(&tris[..4], &ids),
                Tri4::new(&[tris[4], tris[0], tris[5], tris[3]], &ids2),
                Tri4::new(&tris[1..3], &ids[..2]),
            ];
            let node = node_around(&mut rng, &rays);
            let mut two = records(SimdPacket(avx2), &rays[..PACKET], &blocks, &node);
            two.extend(records(SimdPacket(avx2), &rays[PACKET..], &blocks, &node));
            let one = records(SimdPacket(avx512), &rays, &blocks, &node);
            for r in 0..PACKET16 {
                assert_eq!(two[r], one[r], "packet {k}, ray {r}: {:?}", rays[r]);
            }
            // Validity, per block 4 lanes and 9 merged values, 8 children:
            // the rest is t, u, v of triangle hits.
            let base = 1 + blocks.len() * (4 + 9) + 8;
            hits += one.iter().map(|rec| (rec.len() - base) / 3).sum::<usize>();
        }
        assert!(hits > 5_000, "only {hits} triangle hits");
    }
}
