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

use glam::Vec4;

use super::wide::WideNode;
use crate::geometry::SlabRay;

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
}

impl WideRay {
    #[inline]
    pub fn new(slab: &SlabRay) -> WideRay {
        // The sign of the reciprocal decides: safe_reciprocal keeps the sign of
        // a zero component, so -0.0 counts as negative, as the slab test needs.
        let inv_dir = slab.inv_dir;
        let positive = |a: usize| inv_dir[a] >= 0.0;
        let row = |a: usize| if positive(a) { 2 * a } else { 2 * a + 1 };
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
            near: [row(0), row(1), row(2)],
            far: [row(0) ^ 1, row(1) ^ 1, row(2) ^ 1],
        }
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
        let n = entry(0).max(entry(1)).max(entry(2).max(tmin));
        let f = exit(0).min(exit(1)).min(exit(2).min(tmax));
        if n <= f {
            mask |= 1 << lane;
        }
        *slot = n;
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
        let lines = std::mem::size_of::<T>().div_ceil(64).min(4);
        for line in 0..lines {
            // SAFETY: a prefetch never faults or changes memory; the addresses lie
            // inside `*value` (the last line may start past its end only when T
            // is not a multiple of 64 bytes, and prefetching any address is
            // allowed). SSE, which has PREFETCHT0, is part of x86-64.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * line)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
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

/// Proof that this CPU runs AVX2 (and BMI1 and POPCNT, which the traversal's
/// bit scans use): only [`Avx2::detect`] makes one.
#[derive(Clone, Copy, Debug)]
pub struct Avx2 {
    _checked: (),
}

impl Avx2 {
    /// `Some` when the CPU has AVX2, BMI1 and POPCNT (checked once by the
    /// standard library, cached), unless `RAYLAB_SIMD=portable` asks for the
    /// portable kernels.
    pub fn detect() -> Option<Avx2> {
        if std::env::var("RAYLAB_SIMD").is_ok_and(|v| v == "portable") {
            return None;
        }
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2")
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

    #[inline(always)]
    fn avx2(self) -> Option<Avx2> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::wide::WideNode;
    use crate::geometry::{Ray, SlabRay};
    use crate::rng::Rng;
    use glam::Vec3;

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

    fn check<const N: usize, K: NodeKernel<N>>(kernel: K) {
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
            let wray = WideRay::new(&slab);
            let tmax = if k % 3 == 0 {
                f32::INFINITY
            } else {
                rng.next_f32() * 5.0
            };
            let (mask, near) = kernel.intersect(&node, &wray, 0.0, tmax);
            let (want_mask, want_near) = slab_test_scalar(&node, &wray, 0.0, tmax);
            assert_eq!(mask, want_mask, "ray {k}");
            for lane in 0..N {
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

    #[test]
    fn portable_kernels_equal_the_scalar_slab_test() {
        check::<4, _>(Portable);
        check::<8, _>(Portable);
    }

    #[test]
    fn avx2_kernel_equals_the_scalar_slab_test() {
        match Avx2::detect() {
            Some(k) => check::<8, _>(k),
            None => eprintln!("no AVX2 on this CPU: the AVX2 kernel is not tested"),
        }
    }
}
