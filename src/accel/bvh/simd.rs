//! The node kernels of the wide trees: the slab test of all `N` child boxes
//! of a node at once, in a portable form (glam's `Vec4`: SSE2 on x86-64, NEON
//! on aarch64, scalar elsewhere) and with AVX2 for 8-wide nodes, chosen at run
//! time. [`slab_test_scalar`] is the reference both are tested against, lane
//! by lane and bit for bit.
//!
//! `unsafe` outside the Embree module lives here (and in the other SIMD
//! modules, `simd_lanes` and `simd_stack`, and the AVX2 entry points of the
//! wide traversal, `wide::traverse`): the AVX2 intrinsics
//! load through pointers, and AVX2 code may only run on a CPU that has it. An
//! [`Avx2`] value can only be made by [`Avx2::detect`], which checks the CPU,
//! so holding one is the proof every `unsafe` block below relies on.

use glam::{Vec3, Vec4};

use super::wide::WideNode;
use crate::geometry::{SlabRay, TriangleTest, BOX_GROWTH};

/// A ray prepared for the node kernels: per axis the origin the near plane's
/// distance is measured from and the far plane's (both the ray's origin
/// unless the ray lies in a plane of that axis, see [`SlabRay`]), the
/// reciprocal direction, and which bound row of a node is the near plane and
/// which the far.
#[derive(Clone, Copy, Debug)]
pub struct WideRay {
    pub near_origin: [f32; 3],
    pub far_origin: [f32; 3],
    pub inv_dir: [f32; 3],
    /// The reciprocal the far planes' distances are multiplied by,
    /// [`SlabRay::inv_far`] (the conservative enlargement folded in).
    pub inv_far: [f32; 3],
    /// `near[a]` is the row of `WideNode::bounds` holding the near plane on axis
    /// `a` (the minimum for a positive direction, the maximum for a negative one).
    pub near: [usize; 3],
    pub far: [usize; 3],
    /// [`BOX_GROWTH`] with the sign of the direction on each axis: what
    /// [`NodeKernel::intersect_grown`] moves a near plane's distance down
    /// by (a far plane's up), per unit of its box's farthest distance.
    pub grow: [f32; 3],
    /// The fused kernel's planes ([`fused_slab_test_scalar`]), meaningful
    /// when [`Self::fused`].
    pub planes: FusedPlanes,
    /// Whether this is a ray for the fused kernel ([`WideRay::fused`]),
    /// whose unfused fields are not set, or for the unfused ones
    /// ([`WideRay::new`]), whose planes are not.
    pub fused: bool,
}

/// A ray's planes for the fused kernel, per axis: each distance is
/// `bound * inv + shift` in one fused multiply-add.
#[derive(Clone, Copy, Debug)]
pub struct FusedPlanes {
    /// `inv_dir` times [`FUSED_NEAR_SCALE`].
    pub inv_near: [f32; 3],
    /// `-(near_origin * inv_near)` rounded, then moved down past its
    /// rounding ([`FusedPlanes::new`]): at most the exact value.
    pub near_shift: [f32; 3],
    /// `inv_far` times [`FUSED_FAR_SCALE`].
    pub inv_far: [f32; 3],
    /// `-(far_origin * inv_far)` rounded, moved up past its rounding: at
    /// least the exact value.
    pub far_shift: [f32; 3],
}

impl FusedPlanes {
    /// The planes of a ray from `origin` with reciprocals `inv` and
    /// `inv_far` ([`WideRay`]'s; a ray in no axis plane measures both its
    /// near and far planes from its origin), and whether the fused kernel
    /// may use them (finite shifts, reciprocals well above the subnormals,
    /// so that their scaling holds).
    ///
    /// Each shift is `-origin * inv` from the reciprocal scaled both ways
    /// past the roundings of the scaled reciprocal and of the product
    /// ([`SHIFT_NEAR_UP`] and the others): the lower of the two products is
    /// below the exact value whichever sign it has, the higher above it.
    /// Two products and a min from the reciprocal, a short chain before the
    /// first node's FMA. An origin coordinate of zero gives a zero shift,
    /// not a subnormal one (a subnormal operand costs an FMA a microcode
    /// assist on Intel: with `next_down` of zero, primary rays took
    /// 3.4-4.5x their time on grass:3000 and mesh:20000).
    #[inline(always)]
    fn new(origin: Vec3, inv: Vec3, inv_far: Vec3) -> (FusedPlanes, bool) {
        // Four lanes, the fourth 1.0: as `Vec3` the compiler filled a
        // fourth lane with whatever the register held, and a subnormal there
        // cost every ray a microcode assist.
        let origin = origin.extend(1.0);
        let (inv, inv_far) = (inv.extend(1.0), inv_far.extend(1.0));
        let inv_near = inv * FUSED_NEAR_SCALE;
        let fused_far = inv_far * FUSED_FAR_SCALE;
        let near_shift = (origin * (inv * -SHIFT_NEAR_UP)).min(origin * (inv * -SHIFT_NEAR_DOWN));
        let far_shift =
            (origin * (inv_far * -SHIFT_FAR_UP)).max(origin * (inv_far * -SHIFT_FAR_DOWN));
        let fused = near_shift.is_finite()
            && far_shift.is_finite()
            && inv.abs().cmpge(Vec4::splat(1e-30)).all();
        let planes = FusedPlanes {
            inv_near: inv_near.truncate().to_array(),
            near_shift: near_shift.truncate().to_array(),
            inv_far: fused_far.truncate().to_array(),
            far_shift: far_shift.truncate().to_array(),
        };
        (planes, fused)
    }
}

/// The near shift's reciprocal scales: the near planes' scale times `1 +-
/// 8u` (`4 * EPSILON`), past the two roundings of the scaled reciprocal and
/// the product.
const SHIFT_NEAR_UP: f32 = FUSED_NEAR_SCALE * (1.0 + 4.0 * f32::EPSILON);
const SHIFT_NEAR_DOWN: f32 = FUSED_NEAR_SCALE * (1.0 - 4.0 * f32::EPSILON);
/// The far shift's, as the near's.
const SHIFT_FAR_UP: f32 = FUSED_FAR_SCALE * (1.0 + 4.0 * f32::EPSILON);
const SHIFT_FAR_DOWN: f32 = FUSED_FAR_SCALE * (1.0 - 4.0 * f32::EPSILON);

/// How much the fused kernel shrinks the near planes' reciprocal, `1 - 8u`
/// (`u = 2^-24`): with it a near distance is at most the unfused test's
/// (see [`fused_slab_test_scalar`]).
pub const FUSED_NEAR_SCALE: f32 = 1.0 - 4.0 * f32::EPSILON;
/// How much the fused kernel grows the far planes' reciprocal, `1 + 8u`.
pub const FUSED_FAR_SCALE: f32 = 1.0 + 4.0 * f32::EPSILON;

impl WideRay {
    /// Always inlined: into the AVX2 entry points, where it is compiled
    /// with their features; called out of line it was 19% of the time of
    /// plane:20000's shadow rays (one node visit each).
    #[inline(always)]
    pub fn new(slab: &SlabRay) -> WideRay {
        // The sign of the reciprocal decides: safe_reciprocal keeps the sign of
        // a zero component, so -0.0 counts as negative, as the slab test needs.
        let inv_dir = slab.inv_dir;
        let positive = |a: usize| inv_dir[a] >= 0.0;
        let (near, far) = Self::rows(inv_dir);
        let (near_origin, far_origin) = (
            |a: usize| {
                if positive(a) {
                    slab.from_min[a]
                } else {
                    slab.from_max[a]
                }
            },
            |a: usize| {
                if positive(a) {
                    slab.from_max[a]
                } else {
                    slab.from_min[a]
                }
            },
        );
        WideRay {
            near_origin: [near_origin(0), near_origin(1), near_origin(2)],
            far_origin: [far_origin(0), far_origin(1), far_origin(2)],
            inv_dir: inv_dir.to_array(),
            inv_far: slab.inv_far.to_array(),
            near,
            far,
            grow: [0, 1, 2].map(|a| BOX_GROWTH.copysign(inv_dir[a])),
            planes: FusedPlanes {
                inv_near: [0.0; 3],
                near_shift: [0.0; 3],
                inv_far: [0.0; 3],
                far_shift: [0.0; 3],
            },
            fused: false,
        }
    }

    /// The ray for the fused kernel alone (its rows and planes; the unfused
    /// test's fields left zero, so that none of their work is done), or
    /// `None` where the fused kernel may not take it (an axis the ray lies
    /// in, an origin coordinate beyond `origin_limit`, the tree's
    /// [`WideBvh::fused_origin_limit`](super::wide::WideBvh), shifts that
    /// overflow, a subnormal reciprocal).
    #[inline(always)]
    pub fn fused(slab: &SlabRay, origin_limit: f32) -> Option<WideRay> {
        let inv_dir = slab.inv_dir;
        // Outside any axis plane the planes are measured from the origin.
        if slab.from_min != slab.from_max || slab.from_min.abs().max_element() > origin_limit {
            return None;
        }
        let (planes, fused) = FusedPlanes::new(slab.from_min, inv_dir, slab.inv_far);
        if !fused {
            return None;
        }
        let (near, far) = Self::rows(inv_dir);
        Some(WideRay {
            near_origin: [0.0; 3],
            far_origin: [0.0; 3],
            inv_dir: [0.0; 3],
            inv_far: [0.0; 3],
            near,
            far,
            grow: [0.0; 3],
            planes,
            fused: true,
        })
    }

    /// The rows of `WideNode::bounds` holding each axis's near plane and far
    /// plane for a ray with reciprocal direction `inv_dir`: the minimum is
    /// near where the reciprocal is `>= 0` (`safe_reciprocal` keeps a
    /// zero's sign, so `-0.0` counts as negative, as the slab test needs).
    #[inline(always)]
    fn rows(inv_dir: Vec3) -> ([usize; 3], [usize; 3]) {
        let row = |a: usize| if inv_dir[a] >= 0.0 { 2 * a } else { 2 * a + 1 };
        (
            [row(0), row(1), row(2)],
            [row(0) ^ 1, row(1) ^ 1, row(2) ^ 1],
        )
    }
}

/// The slab test of every lane of an `N`-wide node.
///
/// Returns the mask of lanes whose box overlaps `(tmin, tmax)` and each lane's
/// entry distance (meaningful for set lanes only). For a valid box this equals
/// [`crate::geometry::Aabb::intersect`] bit for bit (choosing the near plane by
/// the direction's sign is the same as the min/max of the two planes); unused
/// lanes hold an inverted box, which the sign choice always rejects.
pub trait NodeKernel<const N: usize>: Copy {
    fn intersect(self, node: &WideNode<N>, ray: &WideRay, tmin: f32, tmax: f32) -> (u32, [f32; N]);

    /// [`Self::intersect`] with each lane's box grown by [`BOX_GROWTH`]
    /// times its own farthest distance from the ray's origin: the test for
    /// triangle tests with [`TriangleTest::GROWS_BOXES`]. Bit for bit
    /// [`grown_slab_test_scalar`], which is the default.
    #[inline(always)]
    fn intersect_grown(
        self,
        node: &WideNode<N>,
        ray: &WideRay,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; N]) {
        grown_slab_test_scalar(node, ray, tmin, tmax)
    }

    /// The node test triangle test `T` needs: grown boxes or exact ones
    /// (decided at compile time).
    #[inline(always)]
    fn intersect_for<T: TriangleTest>(
        self,
        node: &WideNode<N>,
        ray: &WideRay,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; N]) {
        if T::GROWS_BOXES {
            self.intersect_grown(node, ray, tmin, tmax)
        } else {
            self.intersect(node, ray, tmin, tmax)
        }
    }

    /// The AVX2 proof when this kernel is the AVX2 one (the closest-hit
    /// walk then orders a node's hit children with its sorting network,
    /// `simd_stack`).
    #[inline(always)]
    fn avx2(self) -> Option<Avx2> {
        None
    }
}

/// The portable kernel: `N / 4` glam `Vec4` operations per step.
#[derive(Clone, Copy, Debug, Default)]
pub struct Portable;

impl<const N: usize> NodeKernel<N> for Portable {
    #[inline(always)]
    fn intersect(self, node: &WideNode<N>, ray: &WideRay, tmin: f32, tmax: f32) -> (u32, [f32; N]) {
        let mut mask = 0;
        let mut near = [0f32; N];
        for h in 0..N / 4 {
            let row = |r: usize| Vec4::from_slice(&node.bounds[r][4 * h..]);
            let slab =
                |r: usize, origin: f32, inv: f32| (row(r) - Vec4::splat(origin)) * Vec4::splat(inv);
            let entry = |a: usize| slab(ray.near[a], ray.near_origin[a], ray.inv_dir[a]);
            let exit = |a: usize| slab(ray.far[a], ray.far_origin[a], ray.inv_far[a]);
            let n = entry(0).max(entry(1)).max(entry(2).max(Vec4::splat(tmin)));
            let f = exit(0).min(exit(1)).min(exit(2).min(Vec4::splat(tmax)));
            mask |= n.cmple(f).bitmask() << (4 * h);
            n.write_to_slice(&mut near[4 * h..]);
        }
        (mask, near)
    }
}

/// The reference for the kernels: [`crate::geometry::Aabb::intersect`]'s
/// operations one lane at a time, with the near plane chosen by sign.
pub fn slab_test_scalar<const N: usize>(
    node: &WideNode<N>,
    ray: &WideRay,
    tmin: f32,
    tmax: f32,
) -> (u32, [f32; N]) {
    let mut mask = 0;
    let mut near = [0f32; N];
    for (lane, slot) in near.iter_mut().enumerate() {
        let entry =
            |a: usize| (node.bounds[ray.near[a]][lane] - ray.near_origin[a]) * ray.inv_dir[a];
        let exit = |a: usize| (node.bounds[ray.far[a]][lane] - ray.far_origin[a]) * ray.inv_far[a];
        let (hit, n) = overlap(
            [entry(0), entry(1), entry(2)],
            [exit(0), exit(1), exit(2)],
            tmin,
            tmax,
        );
        mask |= (hit as u32) << lane;
        *slot = n;
    }
    (mask, near)
}

/// Whether a lane's box overlaps `(tmin, tmax)`, from its three entry and
/// exit distances, and its entry distance: the reduction of the scalar
/// references, in the kernels' order.
#[inline(always)]
fn overlap(entry: [f32; 3], exit: [f32; 3], tmin: f32, tmax: f32) -> (bool, f32) {
    let n = entry[0].max(entry[1]).max(entry[2].max(tmin));
    let f = exit[0].min(exit[1]).min(exit[2].min(tmax));
    (n <= f, n)
}

/// The bits of [`f32::MAX`], the cap on a lane's farthest distance in the
/// grown test.
const FARTHEST_CAP: u32 = 0x7f7f_ffff;

/// [`slab_test_scalar`] with every lane's box grown for the watertight
/// test ([`BOX_GROWTH`]): the reference [`NodeKernel::intersect_grown`] is
/// tested against bit for bit. The planes' distances from the origin are
/// computed first, as in the unfused test; the largest of a lane's six,
/// by magnitude, is its box's farthest distance from the origin on an axis
/// (the near and far rows are the minimum and maximum planes), and moves
/// each near distance down and each far one up by [`BOX_GROWTH`] of it in
/// one fused multiply-add (its rounding a 32nd of the growth) before the
/// multiply by the reciprocal.
///
/// The maxima are of the magnitudes' bits (integers, one cycle each on
/// AVX2, against four for float maxima; the same order for non-negative
/// floats), capped at [`f32::MAX`]: an unused lane's inverted box is
/// infinite, and an infinite growth would make its distances NaN, which
/// the reductions could pass over (`inf - inf`); capped, they stay
/// infinite and reject the lane.
pub fn grown_slab_test_scalar<const N: usize>(
    node: &WideNode<N>,
    ray: &WideRay,
    tmin: f32,
    tmax: f32,
) -> (u32, [f32; N]) {
    let mut mask = 0;
    let mut near = [0f32; N];
    for (lane, slot) in near.iter_mut().enumerate() {
        let dn = [0, 1, 2].map(|a| node.bounds[ray.near[a]][lane] - ray.near_origin[a]);
        let df = [0, 1, 2].map(|a| node.bounds[ray.far[a]][lane] - ray.far_origin[a]);
        let m = (0..3).fold(0u32, |m, a| {
            m.max(dn[a].abs().to_bits()).max(df[a].abs().to_bits())
        });
        let m = f32::from_bits(m.min(FARTHEST_CAP));
        let entry = |a: usize| (-m).mul_add(ray.grow[a], dn[a]) * ray.inv_dir[a];
        let exit = |a: usize| m.mul_add(ray.grow[a], df[a]) * ray.inv_far[a];
        let (hit, n) = overlap(
            [entry(0), entry(1), entry(2)],
            [exit(0), exit(1), exit(2)],
            tmin,
            tmax,
        );
        mask |= (hit as u32) << lane;
        *slot = n;
    }
    (mask, near)
}

/// The slab test of the AVX2 kernel for rays with [`WideRay::fused`], one
/// lane at a time: the reference that kernel is tested against bit for bit.
///
/// Each plane's distance is one fused multiply-add, `bound * inv + shift`:
/// one rounding, not the subtract's and the multiply's, and one step less
/// between a node's load and its mask. Embree computes it so, with `shift`
/// the rounded `-origin * inv`, whose error is relative to itself, not to
/// the distance, which is why that form misses boxes far from the origin.
/// Here the shift is moved past its rounding ([`FusedPlanes`]), so the sum
/// before rounding is at most the exact near distance (with the near
/// reciprocal) and at least the exact far one; rounding is monotone, so
/// each distance is within one rounding of exact. The reciprocals are
/// scaled by `1 -+ 8u` ([`FUSED_NEAR_SCALE`], [`FUSED_FAR_SCALE`]), more
/// than the unfused test's two roundings and one less, so every near
/// distance is at most [`slab_test_scalar`]'s and every far one at least
/// its: **every box the unfused test keeps, this one keeps**, with an entry
/// no farther (a few ulps looser at most). The traversals' answers are the
/// same bits (the triangles decide the hits; the test
/// `fused_kernel_keeps_what_the_unfused_keeps` checks the claim, and
/// `..._every_box_the_ray_reaches` against f64).
///
/// The reductions and the compare are on the floats' bits as signed
/// integers (one cycle each on AVX2, against four for float min and max):
/// the floats' order for the values that decide. `tmin` is taken as `+0.0`
/// or above, so the entry is never below it and never negative; a far
/// distance below zero rejects the box whichever negative one the minimum
/// picks, as the floats do, except `-0.0`, which the floats would keep
/// against an entry of zero: the shifts make a fused far distance
/// positive wherever the unfused one is a zero.
pub fn fused_slab_test_scalar<const N: usize>(
    node: &WideNode<N>,
    ray: &WideRay,
    tmin: f32,
    tmax: f32,
) -> (u32, [f32; N]) {
    let bits = |x: f32| x.to_bits() as i32;
    let p = &ray.planes;
    let tmin = if tmin > 0.0 { tmin } else { 0.0 };
    let mut mask = 0;
    let mut near = [0f32; N];
    for (lane, slot) in near.iter_mut().enumerate() {
        let entry =
            |a: usize| bits(node.bounds[ray.near[a]][lane].mul_add(p.inv_near[a], p.near_shift[a]));
        let exit =
            |a: usize| bits(node.bounds[ray.far[a]][lane].mul_add(p.inv_far[a], p.far_shift[a]));
        let n = entry(0).max(entry(1)).max(entry(2).max(bits(tmin)));
        let f = exit(0).min(exit(1)).min(exit(2).min(bits(tmax)));
        if n <= f {
            mask |= 1 << lane;
        }
        *slot = f32::from_bits(n as u32);
    }
    (mask, near)
}

/// Asks the CPU to bring the cache lines of `*value` (up to four) into L1, so
/// that a child selected by a node test is on its way while the traversal does
/// other work (as Embree does for every hit child). A hint: no effect on
/// results, nothing on targets without a prefetch instruction.
#[inline(always)]
pub fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = value as *const T as *const i8;
        let (first, lines) = cache_lines(p as usize, std::mem::size_of::<T>());
        let first = p.wrapping_sub(p as usize - first);
        for line in 0..lines {
            // SAFETY: a prefetch never faults or changes memory, whatever the
            // address (these are the lines `*value` overlaps); SSE, which
            // has PREFETCHT0, is part of x86-64.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(first.wrapping_add(64 * line)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}

/// The first 64-byte cache line that `size` bytes at `addr` overlap, and
/// how many they overlap (at most four). Counted from the line the value
/// starts in, not from its first byte: a 160-byte leaf block, 16-byte
/// aligned, may start 48 bytes into a line (every other block does in an
/// array that starts 16 bytes into one, as glibc's large allocations do)
/// and then overlaps four lines, the last (its triangle ids) left out when
/// three lines were counted from its first byte.
#[inline(always)]
pub fn cache_lines(addr: usize, size: usize) -> (usize, usize) {
    let first = addr & !63;
    (first, (addr - first + size).div_ceil(64).min(4))
}

/// The bins of the lanes of `f` (each at least 0): each lane truncated to
/// an integer and capped at `last`, as `(lane as u32).min(last)` computes it,
/// in one SSE2 conversion on x86-64 (the builder's binning loop). The binner
/// reads the xyz lanes.
#[inline(always)]
pub fn bin_indices(f: Vec4, last: usize) -> [u32; 4] {
    // Capping before truncating gives the same integer for lanes >= 0 and
    // keeps every lane within i32.
    let f = f.min(Vec4::splat(last as f32));
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of every x86-64 CPU; the transmute is of one
        // 16-byte integer vector into four u32 lanes, in lane order.
        unsafe { std::mem::transmute::<__m128i, [u32; 4]>(_mm_cvttps_epi32(f.into())) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    [f.x as u32, f.y as u32, f.z as u32, f.w as u32]
}

/// Proof that this CPU runs AVX2 (and FMA, which the node kernel uses, and
/// BMI1 and POPCNT, which the traversal's bit scans use): only
/// [`Avx2::detect`] makes one. Every CPU with AVX2 has FMA3.
#[derive(Clone, Copy, Debug)]
pub struct Avx2 {
    _checked: (),
}

impl Avx2 {
    /// `Some` when the CPU has AVX2, FMA, BMI1 and POPCNT (checked once by the
    /// standard library, cached), unless `RAYLAB_SIMD=portable` asks for the
    /// portable kernels.
    pub fn detect() -> Option<Avx2> {
        if std::env::var("RAYLAB_SIMD").is_ok_and(|v| v == "portable") {
            return None;
        }
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2")
            && is_x86_feature_detected!("fma")
            && is_x86_feature_detected!("bmi1")
            && is_x86_feature_detected!("popcnt")
        {
            return Some(Avx2 { _checked: () });
        }
        None
    }
}

/// Proof that this CPU runs AVX-512F besides AVX2 (and BMI1, POPCNT): only
/// [`Avx512::detect`] makes one. The 16-ray packet kernel
/// (`simd_packet::SimdPacket<Avx512>`, its lanes in `simd_lanes`) relies on
/// it.
#[derive(Clone, Copy, Debug)]
pub struct Avx512 {
    pub avx2: Avx2,
}

impl Avx512 {
    /// `Some` when the CPU has AVX-512F and [`Avx2::detect`] succeeds, unless
    /// `RAYLAB_SIMD=avx2` (or `portable`) asks for narrower kernels. Checked
    /// once per process: the packet dispatch asks for every packet.
    pub fn detect() -> Option<Avx512> {
        static DETECTED: std::sync::OnceLock<Option<Avx512>> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| {
            let avx2 = Avx2::detect()?;
            if std::env::var("RAYLAB_SIMD").is_ok_and(|v| v == "avx2") {
                return None;
            }
            #[cfg(target_arch = "x86_64")]
            if is_x86_feature_detected!("avx512f") {
                return Some(Avx512 { avx2 });
            }
            let _ = avx2;
            None
        })
    }
}

/// Which kernel a tree's queries use, chosen when it is built.
#[derive(Clone, Copy, Debug)]
pub enum Kernel {
    Portable,
    Avx2(Avx2),
}

impl Kernel {
    /// AVX2 where the CPU has it, else portable.
    pub fn detect() -> Kernel {
        Avx2::detect().map_or(Kernel::Portable, Kernel::Avx2)
    }

    pub fn name(self) -> &'static str {
        match self {
            Kernel::Portable => "portable",
            Kernel::Avx2(_) => "avx2",
        }
    }

    /// The kernels raylab's wide trees run on this CPU, by query path: the
    /// node kernel ([`Kernel::detect`]) for single rays and packets of 8,
    /// AVX-512 for packets of 16 where the CPU has it ([`Avx512::detect`];
    /// without it those rays take the portable kernels one by one). The
    /// bench's header said `avx2` on an AVX-512 machine.
    pub fn in_use() -> String {
        match (Kernel::detect(), Avx512::detect()) {
            (Kernel::Avx2(_), Some(_)) => {
                "avx2 (single rays, packets of 8), avx-512 (packets of 16)".to_string()
            }
            (Kernel::Avx2(_), None) => {
                "avx2 (single rays, packets of 8), portable (packets of 16, per ray)".to_string()
            }
            (Kernel::Portable, _) => "portable".to_string(),
        }
    }
}

/// [`Portable`]'s operations on eight lanes in one AVX register each. Always
/// inlined into the AVX2 traversal functions below, which is where its
/// intrinsics are compiled (they need the caller to have AVX enabled).
#[cfg(target_arch = "x86_64")]
impl NodeKernel<8> for Avx2 {
    #[inline(always)]
    fn intersect(self, node: &WideNode<8>, ray: &WideRay, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        use std::arch::x86_64::*;
        // SAFETY: `self` proves the CPU has AVX2 (see `Avx2::detect`). Each row
        // of `node.bounds` is eight f32 behind a live reference, 32-byte aligned
        // (the node is 64-byte aligned and rows are 32 bytes); `out` is eight
        // writable f32.
        unsafe {
            let b = &node.bounds;
            // Near planes measured from `near_origin`, far ones from
            // `far_origin`. Branching to measure both from the origin when
            // the ray lies in no axis plane (three registers, not six) cost
            // single rays and the hybrid packets' single-ray finish 10-15% of
            // their time (measured): the extra registers cost none seen.
            let at = |row: usize, o: f32, inv: f32| {
                _mm256_mul_ps(
                    _mm256_sub_ps(_mm256_load_ps(b[row].as_ptr()), _mm256_set1_ps(o)),
                    _mm256_set1_ps(inv),
                )
            };
            let (on, of) = (ray.near_origin, ray.far_origin);
            let (inv, inv_far) = (ray.inv_dir, ray.inv_far);
            let (nx, ny, nz) = (
                at(ray.near[0], on[0], inv[0]),
                at(ray.near[1], on[1], inv[1]),
                at(ray.near[2], on[2], inv[2]),
            );
            let (fx, fy, fz) = (
                at(ray.far[0], of[0], inv_far[0]),
                at(ray.far[1], of[1], inv_far[1]),
                at(ray.far[2], of[2], inv_far[2]),
            );
            // Reduced as trees (two steps deep, not three; the far side
            // also lost its multiply by the enlargement, now in `inv_far`):
            // a visit is a chain of dependent loads and tests, so its
            // latency is the single ray's time per node.
            let near = _mm256_max_ps(
                _mm256_max_ps(nx, ny),
                _mm256_max_ps(nz, _mm256_set1_ps(tmin)),
            );
            let far = _mm256_min_ps(
                _mm256_min_ps(fx, fy),
                _mm256_min_ps(fz, _mm256_set1_ps(tmax)),
            );
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32;
            let mut out = [0f32; 8];
            _mm256_storeu_ps(out.as_mut_ptr(), near);
            (mask, out)
        }
    }

    /// [`grown_slab_test_scalar`]'s operations, eight lanes at once. The
    /// farthest distance is a tree of integer maxima three deep beside the
    /// unfused test's subtract and multiply: a visit's chain grows by an
    /// `and`, four one-cycle integer steps and an FMA.
    #[inline(always)]
    fn intersect_grown(
        self,
        node: &WideNode<8>,
        ray: &WideRay,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        use std::arch::x86_64::*;
        // SAFETY: as in `intersect`: `self` proves AVX2 and FMA; each row
        // of `node.bounds` is eight aligned f32 behind a live reference;
        // `out` is eight writable f32.
        unsafe {
            let b = &node.bounds;
            let d = |row: usize, o: f32| {
                _mm256_sub_ps(_mm256_load_ps(b[row].as_ptr()), _mm256_set1_ps(o))
            };
            let (on, of) = (ray.near_origin, ray.far_origin);
            let dn = [0, 1, 2].map(|a| d(ray.near[a], on[a]));
            let df = [0, 1, 2].map(|a| d(ray.far[a], of[a]));
            let magnitude = _mm256_set1_epi32(0x7fff_ffff);
            let abs = |v: __m256| _mm256_and_si256(_mm256_castps_si256(v), magnitude);
            let m = _mm256_max_epi32(
                _mm256_max_epi32(
                    _mm256_max_epi32(abs(dn[0]), abs(df[0])),
                    _mm256_max_epi32(abs(dn[1]), abs(df[1])),
                ),
                _mm256_max_epi32(abs(dn[2]), abs(df[2])),
            );
            let m =
                _mm256_castsi256_ps(_mm256_min_epi32(m, _mm256_set1_epi32(FARTHEST_CAP as i32)));
            let entry = |a: usize| {
                _mm256_mul_ps(
                    _mm256_fnmadd_ps(m, _mm256_set1_ps(ray.grow[a]), dn[a]),
                    _mm256_set1_ps(ray.inv_dir[a]),
                )
            };
            let exit = |a: usize| {
                _mm256_mul_ps(
                    _mm256_fmadd_ps(m, _mm256_set1_ps(ray.grow[a]), df[a]),
                    _mm256_set1_ps(ray.inv_far[a]),
                )
            };
            let near = _mm256_max_ps(
                _mm256_max_ps(entry(0), entry(1)),
                _mm256_max_ps(entry(2), _mm256_set1_ps(tmin)),
            );
            let far = _mm256_min_ps(
                _mm256_min_ps(exit(0), exit(1)),
                _mm256_min_ps(exit(2), _mm256_set1_ps(tmax)),
            );
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32;
            let mut out = [0f32; 8];
            _mm256_storeu_ps(out.as_mut_ptr(), near);
            (mask, out)
        }
    }

    #[inline(always)]
    fn avx2(self) -> Option<Avx2> {
        Some(self)
    }
}

/// The AVX2 kernel for rays with [`WideRay::fused`]:
/// [`fused_slab_test_scalar`]'s operations, eight lanes at once. A kernel
/// of its own, not a branch in [`Avx2`]'s: with both forms in one loop the
/// traversal kept both rays' constants live and spilled them (394
/// instructions moving YMM registers to and from the stack in the
/// closest-hit walks, against 108).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx2Fused(pub Avx2);

#[cfg(target_arch = "x86_64")]
impl NodeKernel<8> for Avx2Fused {
    #[inline(always)]
    fn intersect(self, node: &WideNode<8>, ray: &WideRay, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        use std::arch::x86_64::*;
        debug_assert!(ray.fused);
        // SAFETY: `self.0` proves the CPU has AVX2 and FMA (see
        // `Avx2::detect`). Each row of `node.bounds` is eight f32 behind a
        // live reference, 32-byte aligned (the node is 64-byte aligned and
        // rows are 32 bytes); `out` is eight writable f32.
        unsafe {
            let b = &node.bounds;
            // `fused_slab_test_scalar`'s operations, eight lanes at once.
            let fused = |row: usize, inv: f32, shift: f32| {
                _mm256_castps_si256(_mm256_fmadd_ps(
                    _mm256_load_ps(b[row].as_ptr()),
                    _mm256_set1_ps(inv),
                    _mm256_set1_ps(shift),
                ))
            };
            let p = &ray.planes;
            let (inv, inv_far) = (p.inv_near, p.inv_far);
            let (sn, sf) = (p.near_shift, p.far_shift);
            let (nx, ny, nz) = (
                fused(ray.near[0], inv[0], sn[0]),
                fused(ray.near[1], inv[1], sn[1]),
                fused(ray.near[2], inv[2], sn[2]),
            );
            let (fx, fy, fz) = (
                fused(ray.far[0], inv_far[0], sf[0]),
                fused(ray.far[1], inv_far[1], sf[1]),
                fused(ray.far[2], inv_far[2], sf[2]),
            );
            let tmin = if tmin > 0.0 { tmin } else { 0.0 };
            let near = _mm256_max_epi32(
                _mm256_max_epi32(nx, ny),
                _mm256_max_epi32(nz, _mm256_set1_epi32(tmin.to_bits() as i32)),
            );
            let far = _mm256_min_epi32(
                _mm256_min_epi32(fx, fy),
                _mm256_min_epi32(fz, _mm256_set1_epi32(tmax.to_bits() as i32)),
            );
            let beyond = _mm256_cmpgt_epi32(near, far);
            let mask = !(_mm256_movemask_ps(_mm256_castsi256_ps(beyond)) as u32) & 0xFF;
            let mut out = [0f32; 8];
            _mm256_storeu_ps(out.as_mut_ptr(), _mm256_castsi256_ps(near));
            (mask, out)
        }
    }

    #[inline(always)]
    fn avx2(self) -> Option<Avx2> {
        Some(self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::wide::WideNode;
    use crate::geometry::{Aabb, Ray, SlabRay};
    use crate::rng::Rng;
    use glam::Vec3;

    /// The prefetch covers every line a leaf block or a node overlaps,
    /// wherever its alignment lets it start.
    #[test]
    fn prefetch_lines_cover_the_whole_value() {
        use crate::accel::bvh::leaf::Tri4;
        assert_eq!(cache_lines(0, 224), (0, 4));
        assert_eq!(cache_lines(32, 224), (0, 4));
        assert_eq!(cache_lines(16, 160), (0, 3));
        assert_eq!(cache_lines(48, 160), (0, 4));
        assert_eq!(cache_lines(64 + 48, 160), (64, 4));
        assert_eq!(cache_lines(130, 4), (128, 1));
        for (size, align) in [
            (std::mem::size_of::<Tri4>(), std::mem::align_of::<Tri4>()),
            (
                std::mem::size_of::<WideNode<8>>(),
                std::mem::align_of::<WideNode<8>>(),
            ),
        ] {
            for start in (4096..4096 + 128).step_by(align) {
                let (first, lines) = cache_lines(start, size);
                assert!(
                    first <= start && first + 64 * lines >= start + size,
                    "{size} at {start}"
                );
            }
        }
    }

    fn random_node<const N: usize>(rng: &mut Rng) -> WideNode<N> {
        let mut node = WideNode::<N>::empty();
        for lane in 0..N {
            if rng.next_f32() < 0.2 {
                continue; // an unused lane keeps its inverted box
            }
            let mut p = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0 - 2.0;
            let (a, mut b) = (p(), p());
            if lane % 3 == 0 {
                b.y = a.y; // flat boxes must be hit too
            }
            node.set_lane(lane, &crate::geometry::Aabb::from_points(&[a, b]), 0);
        }
        node
    }

    /// `kernel` against its scalar reference on random nodes and rays:
    /// [`fused_slab_test_scalar`] when `fused` (the rays it takes), else
    /// [`slab_test_scalar`] and [`Aabb::intersect`].
    fn check<const N: usize, K: NodeKernel<N>>(kernel: K, fused: bool) {
        let mut rng = Rng::for_pixel(4, 2, 8);
        let mut hits = 0;
        for k in 0..20_000 {
            let node = random_node::<N>(&mut rng);
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 6.0 - 3.0;
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            if k % 5 == 0 {
                d.x = 0.0; // huge reciprocals
            }
            if k % 10 == 0 {
                d.z = -0.0;
            }
            // Origins in the plane of a child's face on the zero axes: the
            // case `SlabRay` measures from either side of the plane.
            let mut o = o;
            if k % 4 == 0 {
                let lane = k / 4 % N;
                if node.child[lane] != super::super::wide::EMPTY {
                    let face = node.lane_bounds(lane);
                    let pick = |lo: f32, hi: f32| if k % 8 == 0 { lo } else { hi };
                    if d.x == 0.0 {
                        o.x = pick(face.min.x, face.max.x);
                    }
                    if d.z == 0.0 {
                        o.z = pick(face.min.z, face.max.z);
                    }
                }
            }
            let ray = Ray::new(o, d);
            let slab = SlabRay::new(&ray);
            let wray = if fused {
                match WideRay::fused(&slab, f32::INFINITY) {
                    Some(w) => w,
                    None => continue, // the fused kernel is not handed such rays
                }
            } else {
                WideRay::new(&slab)
            };
            let tmax = if k % 3 == 0 {
                f32::INFINITY
            } else {
                rng.next_f32() * 5.0
            };
            let (mask, near) = kernel.intersect(&node, &wray, 0.0, tmax);
            let (want_mask, want_near) = if fused {
                fused_slab_test_scalar(&node, &wray, 0.0, tmax)
            } else {
                slab_test_scalar(&node, &wray, 0.0, tmax)
            };
            assert_eq!(mask, want_mask, "ray {k}");
            for lane in 0..N {
                if fused {
                    // The fused test is its own reference's (above); how it
                    // stands to the unfused one, `fused_kernel_keeps_...`.
                    if mask >> lane & 1 == 1 {
                        assert_eq!(near[lane].to_bits(), want_near[lane].to_bits(), "ray {k}");
                        hits += 1;
                    }
                    continue;
                }
                if mask >> lane & 1 == 1 {
                    assert_eq!(near[lane].to_bits(), want_near[lane].to_bits(), "ray {k}");
                    // And the box test every other backend uses agrees.
                    let b = node.lane_bounds(lane);
                    assert_eq!(
                        b.intersect(&slab, 0.0, tmax).map(f32::to_bits),
                        Some(near[lane].to_bits()),
                        "ray {k} lane {lane}"
                    );
                    hits += 1;
                } else if node.child[lane] != super::super::wide::EMPTY {
                    let b = node.lane_bounds(lane);
                    assert!(b.intersect(&slab, 0.0, tmax).is_none());
                }
            }
        }
        assert!(hits > 1_000, "too few hits to mean anything: {hits}");
    }

    #[test]
    fn bin_indices_truncate_and_cap_as_the_scalar_cast() {
        let mut rng = Rng::for_pixel(9, 9, 9);
        for k in 0..100_000 {
            let v = |rng: &mut Rng| match k % 4 {
                0 => rng.next_f32() * 16.0,
                1 => (rng.next_f32() * 16.0).floor(),
                2 => 15.0 + rng.next_f32(),
                _ => rng.next_f32() * 1e12,
            };
            let f = Vec4::new(v(&mut rng), v(&mut rng), v(&mut rng), 0.0);
            let want = [0, 1, 2].map(|a| (f[a] as u32).min(15));
            assert_eq!(bin_indices(f, 15)[..3], want, "{f}");
        }
    }

    /// The grown test ([`NodeKernel::intersect_grown`]): AVX2 equals its
    /// scalar reference bit for bit; it keeps every box the exact test
    /// keeps and no unused lane, near the origin and 1e5 from it (where an
    /// ulp of the coordinates is 4,000 times the growth of a box a unit
    /// away, which growing the coordinates would lose); and it keeps a box
    /// the ray passes beside, parallel to its face, at half the growth, a
    /// gap the exact test sees.
    #[test]
    fn grown_kernels_equal_their_reference_and_keep_what_the_exact_test_keeps() {
        let avx2 = Avx2::detect();
        let mut rng = Rng::for_pixel(5, 3, 1);
        let (mut kept, mut beside) = (0, 0);
        for k in 0..20_000 {
            let shift = if k % 2 == 0 {
                Vec3::ZERO
            } else {
                Vec3::new(1e5, -3e4, 7e4)
            };
            let mut node = random_node::<8>(&mut rng);
            for lane in 0..8 {
                if node.child[lane] != super::super::wide::EMPTY {
                    let b = node.lane_bounds(lane);
                    let b = Aabb {
                        min: b.min + shift,
                        max: b.max + shift,
                    };
                    node.set_lane(lane, &b, 0);
                }
            }
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 6.0 - 3.0;
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            if k % 5 == 0 {
                d.z = -0.0;
            }
            let mut o = o + shift;
            // Every fourth ray passes beside a lane's box, parallel to its
            // face x = max.x, at half its growth.
            let lane = k / 4 % 8;
            let aside = k % 4 == 0 && node.child[lane] != super::super::wide::EMPTY;
            debug_assert!(!aside || shift == Vec3::ZERO);
            if aside {
                let b = node.lane_bounds(lane);
                d.x = 0.0;
                let c = b.center();
                o.y = c.y - d.y * 8.0;
                o.z = c.z - d.z * 8.0;
                let slab = SlabRay::new(&Ray::new(Vec3::new(b.max.x, o.y, o.z), d));
                let farthest = (b.min - slab.from_min)
                    .abs()
                    .max((b.max - slab.from_max).abs())
                    .max_element();
                o.x = b.max.x + farthest * BOX_GROWTH * 0.5;
                if o.x == b.max.x {
                    continue;
                }
            }
            let ray = Ray::new(o, d);
            let wray = WideRay::new(&SlabRay::new(&ray));
            let tmax = if k % 3 == 0 {
                f32::INFINITY
            } else {
                rng.next_f32() * 50.0
            };
            let (mask, near) = grown_slab_test_scalar(&node, &wray, 0.0, tmax);
            let (exact, _) = slab_test_scalar(&node, &wray, 0.0, tmax);
            let used = (0..8).filter(|&l| node.child[l] != super::super::wide::EMPTY);
            let used = used.fold(0, |m, l| m | 1 << l);
            assert_eq!(mask & exact, exact, "ray {k}: a box the exact test keeps");
            assert_eq!(mask & !used, 0, "ray {k}: an unused lane");
            kept += (mask & !exact).count_ones();
            // (Where the gap is under the exact test's reach beside a
            // plane the ray lies in, `SlabRay`, that test keeps it too.)
            if aside && tmax == f32::INFINITY && exact >> lane & 1 == 0 {
                assert_eq!(mask >> lane & 1, 1, "ray {k}: the grown test keeps it");
                beside += 1;
            }
            if let Some(avx2) = avx2 {
                let (got, got_near) = avx2.intersect_grown(&node, &wray, 0.0, tmax);
                assert_eq!(got, mask, "ray {k}");
                for l in (0..8).filter(|l| mask >> l & 1 == 1) {
                    assert_eq!(got_near[l].to_bits(), near[l].to_bits(), "ray {k} lane {l}");
                }
            }
        }
        assert!(kept > 0 && beside > 500, "{kept} kept, {beside} beside");
    }

    #[test]
    fn portable_kernels_equal_the_scalar_slab_test() {
        check::<4, _>(Portable, false);
        check::<8, _>(Portable, false);
    }

    #[test]
    fn avx2_kernel_equals_the_scalar_slab_test() {
        match Avx2::detect() {
            Some(k) => {
                check::<8, _>(k, false);
                check::<8, _>(Avx2Fused(k), true);
            }
            None => eprintln!("no AVX2 on this CPU: the AVX2 kernel is not tested"),
        }
    }

    /// Random and adversarial cases, as `check` makes them, and more: origins
    /// far from the boxes' scale, origins on faces, `tmin` above zero.
    /// Every lane the unfused test keeps, the fused one keeps, with an entry
    /// no farther; and it keeps few more. (Its margin is an ulp of
    /// `origin * inv`, so at 10^6 from the origin it keeps boxes within
    /// about 0.1 of the origin that a `tmin` of 0.5 excludes: those are
    /// not counted.)
    #[test]
    fn fused_kernel_keeps_what_the_unfused_keeps() {
        let mut rng = Rng::for_pixel(5, 1, 3);
        let (mut kept, mut extra, mut fused_rays) = (0usize, 0usize, 0usize);
        for k in 0..60_000 {
            let scale = [1.0f32, 1.0, 1e4, 1e6][k % 4];
            let node = random_node::<8>(&mut rng);
            let mut node = node;
            for row in node.bounds.iter_mut() {
                for b in row.iter_mut().filter(|b| b.is_finite()) {
                    *b = *b * scale + scale;
                }
            }
            let mut o = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 6.0 - 3.0)
                * scale
                + Vec3::splat(scale);
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            if k % 5 == 0 {
                d.x = 0.0;
            }
            if k % 11 == 0 {
                d.z = -0.0;
            }
            let lane = k / 3 % 8;
            if k % 3 == 0 && node.child[lane] != super::super::wide::EMPTY {
                // On a face or a corner of a child.
                let b = node.lane_bounds(lane);
                o.x = if k % 2 == 0 { b.min.x } else { b.max.x };
                if k % 9 == 0 {
                    o.y = b.max.y;
                    o.z = b.min.z;
                }
            }
            let mut ray = Ray::new(o, d);
            ray.tmin = [0.0, 0.0, 1e-4 * scale, 0.5][k / 4 % 4];
            let slab = SlabRay::new(&ray);
            let Some(wray) = WideRay::fused(&slab, f32::INFINITY) else {
                continue;
            };
            let unfused = WideRay::new(&slab);
            fused_rays += 1;
            let tmin = ray.tmin * (1.0 - crate::accel::bvh::params::SLAB_SLACK);
            let tmax = if k % 3 == 1 {
                f32::INFINITY
            } else {
                rng.next_f32() * 5.0 * scale
            };
            let (mask, near) = fused_slab_test_scalar(&node, &wray, tmin, tmax);
            let (old_mask, old_near) = slab_test_scalar(&node, &unfused, tmin, tmax);
            for lane in 0..8 {
                if old_mask >> lane & 1 == 1 {
                    kept += 1;
                    assert!(mask >> lane & 1 == 1, "ray {k} lane {lane}: {ray:?}");
                    assert!(near[lane] <= old_near[lane], "ray {k} lane {lane}: {ray:?}");
                } else if mask >> lane & 1 == 1 && scale < 1e6 {
                    extra += 1;
                }
            }
        }
        assert!(
            fused_rays > 40_000 && kept > 9_000,
            "{fused_rays} rays, {kept} kept"
        );
        assert!(
            extra * 500 < kept,
            "the fused test kept {extra} more than {kept}"
        );
    }

    /// The exact slab test in f64 (every f32 is exact in f64, and the
    /// distances' rounding is far below the margins that matter here):
    /// whether the box meets the ray's segment `[tmin, tmax]`.
    fn reaches_exactly(b: &Aabb, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        let (mut near, mut far) = (tmin as f64, tmax as f64);
        for a in 0..3 {
            let (o, d) = (ray.origin[a] as f64, ray.dir[a] as f64);
            let (lo, hi) = (b.min[a] as f64, b.max[a] as f64);
            if d == 0.0 {
                if o < lo || o > hi {
                    return false;
                }
                continue;
            }
            let (t0, t1) = ((lo - o) / d, (hi - o) / d);
            near = near.max(t0.min(t1));
            far = far.min(t0.max(t1));
        }
        near <= far
    }

    /// The fused test keeps every box the ray reaches in exact arithmetic,
    /// on the cases that break an unguarded one: origins far from the
    /// boxes' scale (where `origin * inv` rounds by more than a box is
    /// wide), flat boxes a ray grazes, boxes met at one point, and rays
    /// lying in a box's face. The other side of the trade (it is not much
    /// looser) is what the traversal's node counts show.
    #[test]
    fn fused_kernel_keeps_every_box_the_ray_reaches() {
        let mut rng = Rng::for_pixel(7, 3, 1);
        let mut reached = 0;
        let mut fused_rays = 0;
        for k in 0..40_000 {
            let scale = [1.0f32, 1e3, 1e5, 3e6][k % 4];
            let center = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * scale;
            let size = [1e-3f32, 1.0, 1e-5][k / 4 % 3] * scale.sqrt();
            let mut p =
                || center + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * size;
            let mut node = WideNode::<8>::empty();
            let mut boxes = Vec::new();
            for lane in 0..8 {
                let (a, mut b) = (p(), p());
                if lane % 3 == 0 {
                    b.z = a.z; // flat
                }
                let bx = Aabb::from_points(&[a, b]);
                node.set_lane(lane, &bx, 0);
                boxes.push(bx);
            }
            // A ray from far off aimed at a corner, a face's point or a
            // random point of one box.
            let target_box = boxes[k % 8];
            let target = match k % 3 {
                0 => target_box.min,
                1 => Vec3::new(target_box.min.x, target_box.center().y, target_box.max.z),
                _ => p(),
            };
            let away = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            let mut origin = target + away * scale * 0.5;
            let mut dir = target - origin;
            if k % 7 == 0 {
                dir.y = 0.0; // in a plane of y
                origin.y = target_box.max.y;
            }
            if dir == Vec3::ZERO {
                continue;
            }
            let ray = Ray::new(origin, dir);
            let Some(wray) = WideRay::fused(&SlabRay::new(&ray), f32::INFINITY) else {
                continue; // in an axis plane: the unfused kernel's
            };
            fused_rays += 1;
            let tmax = if k % 2 == 0 {
                f32::INFINITY
            } else {
                1.0 + rng.next_f32()
            };
            let tmin = ray.tmin * (1.0 - crate::accel::bvh::params::SLAB_SLACK);
            let (mask, near) = fused_slab_test_scalar(&node, &wray, tmin, tmax);
            if let Some(avx2) = Avx2::detect() {
                let (avx_mask, avx_near) = Avx2Fused(avx2).intersect(&node, &wray, tmin, tmax);
                assert_eq!(avx_mask, mask, "ray {k}");
                assert_eq!(
                    avx_near.map(f32::to_bits),
                    near.map(f32::to_bits),
                    "ray {k}"
                );
            }
            for (lane, bx) in boxes.iter().enumerate() {
                if reaches_exactly(bx, &ray, ray.tmin, tmax) {
                    reached += 1;
                    assert!(
                        mask >> lane & 1 == 1,
                        "ray {k}: {ray:?} reaches {bx:?} but the fused test drops it"
                    );
                }
            }
        }
        assert!(
            reached > 10_000,
            "too few boxes reached to mean anything: {reached}"
        );
        assert!(
            fused_rays > 30_000,
            "too few rays took the fused test: {fused_rays}"
        );
    }

    /// Rays whose shifts overflow (an origin far out on an axis the ray
    /// lies in) are marked to take the unfused test.
    #[test]
    fn rays_whose_shifts_overflow_are_not_fused() {
        // 1e9 times a reciprocal clamped to 1e30 overflows.
        let far_out = Ray::new(Vec3::new(1e9, 0.0, 0.0), Vec3::new(1e-32, 1.0, 0.0));
        assert!(WideRay::fused(&SlabRay::new(&far_out), f32::INFINITY).is_none());
        let in_plane = Ray::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0));
        assert!(WideRay::fused(&SlabRay::new(&in_plane), f32::INFINITY).is_none());
        let near = Ray::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.5, 1.0, 0.25));
        assert!(WideRay::fused(&SlabRay::new(&near), f32::INFINITY).is_some());
    }
}
