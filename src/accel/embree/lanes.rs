//! Rays as Embree takes them: which rays it may be given ([`embree_takes`]),
//! and its ray packets laid out from raylab's rays (each component's lanes:
//! origin, direction, `tnear`, `tfar`).
//!
//! raylab's own packet kernels load a packet with in-register transposes
//! ([`Lanes::load_rays`]); Embree's packets were filled lane by lane, with
//! the validity test as a chain of scalar branches. That wrapper alone took
//! 8.0 ns per ray of 16-ray closest-hit packets and 6.7 of occlusion ones
//! (forest:10's recorded rays, Intel Xeon, Embree's call skipped), a
//! quarter of Embree's packet time there, inside every Embree packet figure
//! raylab published. With the same transposes as raylab's packets (AVX2
//! for 8 lanes, AVX-512 for 16) Embree's packets are given the same start.

#[cfg(target_arch = "x86_64")]
use crate::accel::bvh::simd::{Avx2, Avx512};
#[cfg(target_arch = "x86_64")]
use crate::accel::bvh::simd_lanes::Lanes;
use crate::geometry::Ray;

/// Embree's `FLT_LARGE` (common/math/constants.h): the largest origin or
/// direction component its ray validation (`RayK::valid`) accepts. Builds
/// with assertions on (Debian's) abort the process on a ray past it.
pub const EMBREE_MAX_COORDINATE: f32 = 1.844e18;

/// Whether Embree can take `ray`: a valid ray ([`Ray::is_valid`]) whose
/// origin and direction components are within [`EMBREE_MAX_COORDINATE`].
/// Any other ray is answered as a miss without calling Embree.
#[inline]
pub fn embree_takes(ray: &Ray) -> bool {
    ray.is_valid()
        && ray.origin.abs().max_element() <= EMBREE_MAX_COORDINATE
        && ray.dir.abs().max_element() <= EMBREE_MAX_COORDINATE
}

/// A packet's ray components in a ray's memory order (origin x, y, z,
/// direction x, y, z, `tnear`, `tfar`), each `N` lanes of Embree's packet.
pub(super) type Components<'a, const N: usize> = [&'a mut [f32; N]; 8];

/// Writes `rays` (at most `N`) into lanes 0.. of `out` and returns the
/// lanes Embree takes as bits (lanes past `rays` neither written nor set).
/// Lanes it does not take hold the rays as given; Embree reads no lane
/// outside its valid mask.
#[inline]
pub(super) fn lay_out<const N: usize>(rays: &[Ray], out: Components<'_, N>) -> u32 {
    debug_assert!(rays.len() <= N);
    #[cfg(target_arch = "x86_64")]
    {
        if N == 16 && rays.len() == 16 {
            if let Some(avx512) = Avx512::detect() {
                let out = out.map(|c| <&mut [f32; 16]>::try_from(&mut c[..]).expect("16 lanes"));
                // SAFETY: an `Avx512` is made only by `Avx512::detect`, which
                // checked AVX-512F besides AVX2, BMI1 and POPCNT.
                return unsafe { lay_out_avx512(avx512, rays, out) };
            }
        }
        if N == 8 && rays.len() == 8 {
            if let Some(avx2) = Avx2::detect() {
                let out = out.map(|c| <&mut [f32; 8]>::try_from(&mut c[..]).expect("8 lanes"));
                // SAFETY: an `Avx2` is made only by `Avx2::detect`, which
                // checked AVX2, BMI1 and POPCNT.
                return unsafe { lay_out_avx2(avx2, rays, out) };
            }
        }
    }
    lay_out_by_lane(rays, out)
}

/// [`lay_out`] one lane at a time (a packet's last rays, 4-lane packets,
/// CPUs without the SIMD kernels).
fn lay_out_by_lane<const N: usize>(rays: &[Ray], out: Components<'_, N>) -> u32 {
    let [ox, oy, oz, dx, dy, dz, tnear, tfar] = out;
    let mut valid = 0;
    for (lane, ray) in rays.iter().enumerate() {
        valid |= u32::from(embree_takes(ray)) << lane;
        ox[lane] = ray.origin.x;
        oy[lane] = ray.origin.y;
        oz[lane] = ray.origin.z;
        dx[lane] = ray.dir.x;
        dy[lane] = ray.dir.y;
        dz[lane] = ray.dir.z;
        tnear[lane] = ray.tmin;
        tfar[lane] = ray.tmax;
    }
    valid
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,popcnt")]
fn lay_out_avx2(avx2: Avx2, rays: &[Ray], out: Components<'_, 8>) -> u32 {
    lay_out_with(avx2, rays, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,bmi1,popcnt")]
fn lay_out_avx512(avx512: Avx512, rays: &[Ray], out: Components<'_, 16>) -> u32 {
    lay_out_with(avx512, rays, out)
}

/// [`lay_out`] of a full packet with `R`-lane registers: the rays loaded
/// and transposed as raylab's packets load theirs, each component stored
/// whole, and [`embree_takes`] evaluated on all lanes at once.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn lay_out_with<L: Lanes<R>, const R: usize>(l: L, rays: &[Ray], out: Components<'_, R>) -> u32 {
    let (c, _) = l.load_rays(rays);
    for (dst, v) in out.into_iter().zip(c) {
        *dst = l.store(v);
    }
    // embree_takes, lane-wise: a valid ray with every origin and direction
    // component within Embree's bound.
    let bound = l.splat(EMBREE_MAX_COORDINATE);
    let mut takes = l.valid_rays(&c);
    for v in &c[..6] {
        takes = l.and(takes, l.le(l.abs(*v), bound));
    }
    l.bits(takes)
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::rng::Rng;

    /// Rays Embree must refuse or take at every edge of [`embree_takes`].
    fn edge_rays() -> Vec<Ray> {
        let big = EMBREE_MAX_COORDINATE;
        let odd = [
            0.0,
            -0.0,
            1.0,
            -3.5,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            big,
            -big,
            big.next_up(),
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-45,
        ];
        let mut rng = Rng::for_pixel(3, 7, 0);
        let mut rays = Vec::new();
        for k in 0..4000 {
            let mut ray = Ray::segment(
                Vec3::new(0.5, -1.0, 2.0),
                Vec3::new(0.3, 0.2, -1.0),
                0.0,
                f32::INFINITY,
            );
            // One to three odd components per ray, the rest ordinary.
            for _ in 0..1 + k % 3 {
                let v = odd[(rng.next_u64() % odd.len() as u64) as usize];
                match rng.next_u64() % 8 {
                    0 => ray.origin.x = v,
                    1 => ray.origin.y = v,
                    2 => ray.origin.z = v,
                    3 => ray.dir.x = v,
                    4 => ray.dir.y = v,
                    5 => ray.dir = Vec3::splat(v),
                    6 => ray.tmin = v,
                    _ => ray.tmax = v,
                }
            }
            rays.push(ray);
        }
        rays
    }

    /// Lays `packet` out in packets of `N` lanes and checks every lane
    /// against the ray and [`embree_takes`]; returns how many it takes.
    fn check<const N: usize>(packet: &[Ray]) -> usize {
        let mut c = [[f32::NAN; N]; 8];
        let [a, b, cc, d, e, f, g, h] = &mut c;
        let valid = lay_out::<N>(packet, [a, b, cc, d, e, f, g, h]);
        for (lane, ray) in packet.iter().enumerate() {
            assert_eq!(valid >> lane & 1 == 1, embree_takes(ray), "{ray:?}");
            let want = [
                ray.origin.x,
                ray.origin.y,
                ray.origin.z,
                ray.dir.x,
                ray.dir.y,
                ray.dir.z,
                ray.tmin,
                ray.tmax,
            ];
            for (k, w) in want.iter().enumerate() {
                assert_eq!(c[k][lane].to_bits(), w.to_bits(), "component {k}");
            }
        }
        assert_eq!(valid >> packet.len(), 0, "no lane past the rays");
        valid.count_ones() as usize
    }

    #[test]
    fn packets_are_laid_out_as_lane_by_lane_and_take_the_rays_embree_takes() {
        let rays = edge_rays();
        let mut taken = 0;
        for packet in rays.chunks(16) {
            taken += check::<16>(packet);
        }
        for packet in rays.chunks(8) {
            taken += check::<8>(packet);
        }
        // Lane by lane: 4-ray packets, and partial ones.
        for packet in rays.chunks(4).chain(rays.chunks(3)) {
            taken += check::<4>(packet);
        }
        // Both answers are common among these rays.
        assert!(taken > rays.len() && taken < 3 * rays.len(), "{taken}");
    }
}
