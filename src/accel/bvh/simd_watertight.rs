//! The watertight ray/triangle test ([`Watertight::test`]) across a
//! packet's rays: one triangle against every ray of a packet at once, each
//! ray in a SIMD lane with its own axis permutation and shear, the scalar
//! test's operations in the same order (no fused multiply-adds), so that
//! each lane's answer is the scalar test's bit for bit. As in
//! [`watertight4`](super::leaf::watertight4), the lanes the scalar test
//! decides apart go to it: an edge function exactly zero (redone in double
//! precision there) and a hit within [`NEAR_ORIGIN`] of the origin (its side
//! of the origin decided exactly).
//!
//! Why: the watertight packets ([`GrownPacket`](super::simd_packet::GrownPacket))
//! tested their leaves ray by ray, four triangles at a time, and spent 4-5x
//! Moller-Trumbore packets' time on coherent rays, where the Moller-Trumbore
//! packets test a triangle against all their rays in one pass.

use arrayvec::ArrayVec;

use super::leaf::Tri4;
use super::simd_lanes::{LaneTriangles, Lanes};
use crate::geometry::{ahead_of_origin, Ray, TriangleTest, Watertight, NEAR_ORIGIN};

/// Each ray's watertight set-up ([`Watertight::prepare`]) in the lanes of
/// a packet, with the rays themselves for the lanes the scalar test decides.
pub struct WatertightLanes<L: Lanes<R>, const R: usize> {
    /// The lanes whose dominant direction axis (`kz`) is x, and y (else z).
    kz_x: L::M,
    kz_y: L::M,
    /// `kz` when every ray of the packet has the same one (the usual case
    /// for neighbouring rays): each vertex coordinate is then one splat
    /// instead of a blend of three.
    shared_kz: Option<usize>,
    /// The origin's coordinates permuted as each ray's test permutes them
    /// (`kx`, `ky`, `kz`).
    origin: [L::F; 3],
    /// `sx`, `sy`, `sz`.
    shear: [L::F; 3],
    /// Per ray, the scalar test's near-origin rule: a hit at `t` is decided
    /// exactly where `t * dir_max <= reach`.
    dir_max: L::F,
    reach: L::F,
    tmin: L::F,
    tmax: L::F,
    /// The packet's rays (lanes past them unused).
    rays: ArrayVec<Ray, R>,
}

impl<L: Lanes<R>, const R: usize> WatertightLanes<L, R> {
    /// The set-up of `rays` (at most `R`), each ray's computed by
    /// [`Watertight::prepare`] itself.
    #[inline(always)]
    pub fn new(l: L, rays: &[Ray]) -> Self {
        let (mut kz_x, mut kz_y) = (0u32, 0u32);
        let mut kz_seen = [false; 3];
        let mut origin = [[0f32; R]; 3];
        let mut shear = [[0f32; R]; 3];
        let (mut dir_max, mut reach) = ([0f32; R], [0f32; R]);
        let (mut tmin, mut tmax) = ([0f32; R], [0f32; R]);
        for (r, ray) in rays.iter().enumerate() {
            let w = Watertight::prepare(ray);
            kz_x |= ((w.kz == 0) as u32) << r;
            kz_y |= ((w.kz == 1) as u32) << r;
            kz_seen[w.kz] = true;
            let o = ray.origin;
            (origin[0][r], origin[1][r], origin[2][r]) = (o[w.kx], o[w.ky], o[w.kz]);
            (shear[0][r], shear[1][r], shear[2][r]) = (w.sx, w.sy, w.sz);
            dir_max[r] = ray.dir.abs().max_element();
            reach[r] = NEAR_ORIGIN * ray.origin.abs().max_element().max(1.0);
            (tmin[r], tmax[r]) = (ray.tmin, ray.tmax);
        }
        let shared_kz = match kz_seen {
            [true, false, false] => Some(0),
            [false, true, false] => Some(1),
            [false, false, true] => Some(2),
            _ => None,
        };
        WatertightLanes {
            kz_x: l.mask(kz_x),
            kz_y: l.mask(kz_y),
            shared_kz,
            origin: [l.load(&origin[0]), l.load(&origin[1]), l.load(&origin[2])],
            shear: [l.load(&shear[0]), l.load(&shear[1]), l.load(&shear[2])],
            dir_max: l.load(&dir_max),
            reach: l.load(&reach),
            tmin: l.load(&tmin),
            tmax: l.load(&tmax),
            rays: rays.iter().copied().collect(),
        }
    }
}

impl<L: Lanes<R>, const R: usize> LaneTriangles<L, R> for WatertightLanes<L, R> {
    /// [`Watertight::test`] of the rays of `live` (each within its `tmin`
    /// and its lane of `tmax`) against lane `i` of `block`: the lanes that
    /// hit, and each lane's t, u and v (meaningful where they hit).
    #[inline(always)]
    fn triangle(
        &self,
        l: L,
        block: &Tri4,
        i: usize,
        live: L::M,
        tmax: L::F,
    ) -> (L::M, L::F, L::F, L::F) {
        let zero = l.splat(0.0);
        let nothing = (l.mask(0), zero, zero, zero);
        // Each vertex translated to the origin, permuted, sheared in x and
        // y (the scalar test's `v - origin`, then its permutation: the same
        // subtraction per coordinate). Macros, not closures (a closure is
        // compiled without the entry point's target features).
        macro_rules! vertex {
            ($k:expr) => {{
                let v = &block.v[$k];
                let c = [v[0][i], v[1][i], v[2][i]];
                let [x, y, z] = match self.shared_kz {
                    Some(kz) => {
                        let (kx, ky) = ((kz + 1) % 3, (kz + 2) % 3);
                        [l.splat(c[kx]), l.splat(c[ky]), l.splat(c[kz])]
                    }
                    None => {
                        let (cx, cy, cz) = (l.splat(c[0]), l.splat(c[1]), l.splat(c[2]));
                        // kz = 0: (y, z, x); kz = 1: (z, x, y); kz = 2: (x, y, z).
                        [
                            l.blend(self.kz_x, l.blend(self.kz_y, cx, cz), cy),
                            l.blend(self.kz_x, l.blend(self.kz_y, cy, cx), cz),
                            l.blend(self.kz_x, l.blend(self.kz_y, cz, cy), cx),
                        ]
                    }
                };
                let (x, y, z) = (
                    l.sub(x, self.origin[0]),
                    l.sub(y, self.origin[1]),
                    l.sub(z, self.origin[2]),
                );
                [
                    l.add(x, l.mul(self.shear[0], z)),
                    l.add(y, l.mul(self.shear[1], z)),
                    z,
                ]
            }};
        }
        let p = [vertex!(0), vertex!(1), vertex!(2)];
        let e0 = l.sub(l.mul(p[1][0], p[2][1]), l.mul(p[1][1], p[2][0]));
        let e1 = l.sub(l.mul(p[2][0], p[0][1]), l.mul(p[2][1], p[0][0]));
        let e2 = l.sub(l.mul(p[0][0], p[1][1]), l.mul(p[0][1], p[1][0]));
        let exact_zero = l.bits(l.and(
            l.or(l.or(l.eq(e0, zero), l.eq(e1, zero)), l.eq(e2, zero)),
            live,
        ));
        let negative = l.or(l.or(l.lt(e0, zero), l.lt(e1, zero)), l.lt(e2, zero));
        let positive = l.or(l.or(l.gt(e0, zero), l.gt(e1, zero)), l.gt(e2, zero));
        // The rays that pass the edge tests: usually few of a packet; none
        // is the common answer for a triangle of a leaf.
        let inside_edges = l.andnot(l.and(negative, positive), live);
        if l.bits(inside_edges) | exact_zero == 0 {
            return nothing;
        }
        let det = l.add(l.add(e0, e1), e2);
        let sz = self.shear[2];
        let z = [l.mul(p[0][2], sz), l.mul(p[1][2], sz), l.mul(p[2][2], sz)];
        let t_scaled = l.add(l.add(l.mul(e0, z[0]), l.mul(e1, z[1])), l.mul(e2, z[2]));
        let (lo, hi) = (l.mul(self.tmin, det), l.mul(tmax, det));
        let pad = l.splat(4.0 * f32::EPSILON);
        let (lo_pad, hi_pad) = (l.mul(l.abs(lo), pad), l.mul(l.abs(hi), pad));
        let inside_negative = l.and(
            l.lt(t_scaled, l.add(lo, lo_pad)),
            l.gt(t_scaled, l.sub(hi, hi_pad)),
        );
        let inside_positive = l.and(
            l.gt(t_scaled, l.sub(lo, lo_pad)),
            l.lt(t_scaled, l.add(hi, hi_pad)),
        );
        let det_negative = l.lt(det, zero);
        let inside = l.or(
            l.and(det_negative, inside_negative),
            l.andnot(det_negative, inside_positive),
        );
        let inv = l.div(l.splat(1.0), det);
        let t = l.mul(t_scaled, inv);
        let ok = l.and(
            l.and(l.and(inside_edges, l.ne(det, zero)), inside),
            l.and(l.gt(t, self.tmin), l.lt(t, tmax)),
        );
        let mut mask = l.bits(ok) & !exact_zero;
        let (mut t, mut u, mut v) = (t, l.mul(e1, inv), l.mul(e2, inv));
        let near = l.bits(l.le(l.mul(t, self.dir_max), self.reach)) & mask;
        if near | exact_zero != 0 {
            let tri = block.triangle(i);
            for r in super::leaf::bits(near) {
                if !ahead_of_origin(&self.rays[r], &tri) {
                    mask &= !(1 << r);
                }
            }
            if exact_zero != 0 {
                let limit = l.store(tmax);
                let (mut ts, mut us, mut vs) = (l.store(t), l.store(u), l.store(v));
                for r in super::leaf::bits(exact_zero) {
                    let ray = Ray {
                        tmax: limit[r],
                        ..self.rays[r]
                    };
                    if let Some((th, uh, vh)) =
                        Watertight::test(&Watertight::prepare(&ray), &ray, &tri)
                    {
                        mask |= 1 << r;
                        (ts[r], us[r], vs[r]) = (th, uh, vh);
                    }
                }
                (t, u, v) = (l.load(&ts), l.load(&us), l.load(&vs));
            }
        }
        (l.mask(mask), t, u, v)
    }

    #[inline(always)]
    fn tmax(&self) -> L::F {
        self.tmax
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::bvh::leaf::EMPTY_ID;
    use crate::accel::bvh::simd::{Avx2, Avx512};
    use crate::rng::Rng;

    /// Packets of `R` rays against random blocks, each lane against
    /// [`Watertight::test`] bit for bit: rays aimed exactly at vertices
    /// and at edges' midpoints (edge functions exactly zero: the scalar
    /// lanes), rays starting on a triangle's plane (the near-origin
    /// lanes), packets whose rays share their dominant axis and packets
    /// whose rays do not, lowered limits, lanes left out of `live`, and
    /// degenerate triangles.
    fn lanes_equal_the_scalar_test<L: Lanes<R>, const R: usize>(l: L, seed: u64) {
        let mut rng = Rng::for_pixel(seed, 5, 9);
        let (mut hits, mut zero_hits, mut near_hits, mut shared) = (0, 0, 0, 0);
        for k in 0..6_000 {
            let mut p = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let n = 1 + k % 4;
            let mut tris: Vec<[Vec3; 3]> = (0..n)
                .map(|_| {
                    [
                        p() * 2.0 - Vec3::ONE,
                        p() * 2.0 - Vec3::ONE,
                        p() * 2.0 - Vec3::ONE,
                    ]
                })
                .collect();
            if k % 13 == 0 {
                tris[0][1] = tris[0][2];
            }
            let ids: Vec<u32> = (0..n as u32).map(|i| 10 + i).collect();
            let block = Tri4::new(&tris, &ids);
            // A coherent packet (one base direction, jittered) or a
            // scattered one.
            let coherent = k % 2 == 0;
            let base_o = p() * 4.0 - Vec3::splat(2.0);
            let base_d = p() - Vec3::splat(0.5);
            let rays: Vec<Ray> = (0..R)
                .map(|r| {
                    let tri = tris[(k + r) % n];
                    let o = if coherent {
                        base_o + (p() - Vec3::splat(0.5)) * 0.1
                    } else {
                        p() * 4.0 - Vec3::splat(2.0)
                    };
                    let target = if coherent {
                        o + base_d + (p() - Vec3::splat(0.5)) * 0.05
                    } else {
                        p() - Vec3::splat(0.5)
                    };
                    let mut ray = Ray::new(o, target - o);
                    match (k + 3 * r) % 7 {
                        0 => ray.dir = tri[r % 3] - o,
                        1 => ray.dir = (tri[r % 3] + tri[(r + 1) % 3]) * 0.5 - o,
                        2 => {
                            ray.origin = (tri[0] + tri[1] + tri[2]) / 3.0;
                            ray.dir = target - ray.origin;
                        }
                        _ => {}
                    }
                    if (k + r) % 5 == 0 {
                        ray.tmax = p().x * 1.5;
                    }
                    if (k + r) % 9 == 0 {
                        ray.tmin = p().y * 0.2;
                    }
                    ray
                })
                .collect();
            let setup = WatertightLanes::new(l, &rays);
            shared += setup.shared_kz.is_some() as usize;
            let limit: [f32; R] = std::array::from_fn(|r| {
                if (k + r) % 3 == 0 {
                    rays[r].tmax * p().z
                } else {
                    rays[r].tmax
                }
            });
            let live_bits = if k % 4 == 0 {
                (rng.next_f32() * ((1u64 << R) - 1) as f32) as u32
            } else {
                ((1u64 << R) - 1) as u32
            };
            for i in 0..4 {
                let (mask, t, u, v) =
                    setup.triangle(l, &block, i, l.mask(live_bits), l.load(&limit));
                let (mask, t, u, v) = (l.bits(mask), l.store(t), l.store(u), l.store(v));
                for r in super::super::leaf::bits(live_bits) {
                    let ray = Ray {
                        tmax: limit[r],
                        ..rays[r]
                    };
                    let w = Watertight::prepare(&ray);
                    let want = (block.ids[i] != EMPTY_ID)
                        .then(|| Watertight::test(&w, &ray, &block.triangle(i)))
                        .flatten();
                    let got = (mask >> r & 1 == 1).then(|| (t[r], u[r], v[r]));
                    let bits = |h: Option<(f32, f32, f32)>| {
                        h.map(|(t, u, v)| (t.to_bits(), u.to_bits(), v.to_bits()))
                    };
                    assert_eq!(
                        bits(got),
                        bits(want),
                        "packet {k} triangle {i} ray {r}: {ray:?}"
                    );
                    hits += want.is_some() as usize;
                    if block.ids[i] != EMPTY_ID {
                        let q = block.triangle(i).map(|v| v - ray.origin).map(|v| {
                            let (x, y, z) = (v[w.kx], v[w.ky], v[w.kz]);
                            (x + w.sx * z, y + w.sy * z)
                        });
                        let e = |a: (f32, f32), b: (f32, f32)| a.0 * b.1 - a.1 * b.0;
                        // Hits the scalar test decides apart: an edge
                        // function exactly zero on a triangle with area (a
                        // ray through a vertex or an edge: the double-
                        // precision lanes), and a hit within the near-origin
                        // reach (decided by `ahead_of_origin`).
                        let zero = [e(q[1], q[2]), e(q[2], q[0]), e(q[0], q[1])].contains(&0.0);
                        let degenerate = k % 13 == 0 && i == 0;
                        zero_hits += (zero && !degenerate && want.is_some()) as usize;
                        let reach = NEAR_ORIGIN * ray.origin.abs().max_element().max(1.0);
                        near_hits += want
                            .is_some_and(|h| h.0 * ray.dir.abs().max_element() <= reach)
                            as usize;
                    }
                }
            }
        }
        assert!(
            hits > 10_000 && zero_hits > 1_000 && near_hits > 500 && shared > 200,
            "{hits} hits, {zero_hits} with a zero edge function, {near_hits} near the origin, \
             {shared} packets with one dominant axis"
        );
    }

    #[test]
    fn the_lane_test_equals_the_scalar_one_ray_by_ray() {
        if let Some(avx2) = Avx2::detect() {
            lanes_equal_the_scalar_test::<_, 8>(avx2, 1);
        } else {
            eprintln!("no AVX2 on this CPU: the lane test is not tested");
        }
        if let Some(avx512) = Avx512::detect() {
            lanes_equal_the_scalar_test::<_, 16>(avx512, 2);
        } else {
            eprintln!("no AVX-512 on this CPU: its lane test is not tested");
        }
    }
}
