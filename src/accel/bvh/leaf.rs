//! Leaf triangles of the wide trees in blocks of four, structure of arrays,
//! so that one SIMD Moller-Trumbore, or one SIMD watertight test, tests four
//! triangles at once.
//!
//! A block holds the three vertices lane by lane and the scene index of each
//! triangle, so a leaf is one contiguous read (160 bytes) with nothing to look
//! up elsewhere. Edges are not stored: `v1 - v0` in a SIMD lane is the same
//! subtraction as in the scalar test, so the lane results are bit-identical to
//! [`intersect_triangle`]'s, and the watertight test still gets the exact
//! vertices. Unused lanes hold a point triangle at the origin (its determinant
//! is zero, so it never hits) and the id [`EMPTY_ID`].

use glam::{Vec3, Vec4};

use super::prim::Triangles;
use crate::geometry::{
    ahead_of_origin, intersect_triangle, Hit, MollerTrumbore, Ray, TriangleTest, Watertight,
    WatertightRay, NEAR_ORIGIN,
};

/// Triangles per block.
pub const LANES: usize = 4;

/// The id of an unused lane.
pub const EMPTY_ID: u32 = u32::MAX;

/// Four triangles, lane `i` of every array belonging to triangle `i`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub struct Tri4 {
    /// `v[k][axis]`: vertex `k`'s coordinate on `axis` for the four lanes.
    pub v: [[Vec4; 3]; 3],
    /// Scene index of each lane's triangle, [`EMPTY_ID`] for unused lanes.
    pub ids: [u32; LANES],
}

impl Tri4 {
    /// A block of up to four triangles (`tris` and `ids` of equal length, at
    /// most [`LANES`]).
    pub fn new(tris: &[[Vec3; 3]], ids: &[u32]) -> Tri4 {
        debug_assert!(tris.len() <= LANES && tris.len() == ids.len());
        let mut block = Tri4::empty();
        for (lane, (tri, &id)) in tris.iter().zip(ids).enumerate() {
            block.set_lane(lane, tri, id);
        }
        block
    }

    /// A block with every lane unused.
    pub fn empty() -> Tri4 {
        Tri4 {
            v: [[Vec4::ZERO; 3]; 3],
            ids: [EMPTY_ID; LANES],
        }
    }

    /// Puts triangle `tri` (scene index `id`) in lane `lane`. Inlined: called
    /// from another codegen unit, the triangle went through the stack and was
    /// read back wider than it was written, which stalled every leaf fill.
    #[inline]
    pub fn set_lane(&mut self, lane: usize, tri: &[Vec3; 3], id: u32) {
        for (k, vertex) in tri.iter().enumerate() {
            for axis in 0..3 {
                self.v[k][axis][lane] = vertex[axis];
            }
        }
        self.ids[lane] = id;
    }

    /// Sets the lanes named in `ids` (at most [`LANES`]) to those triangles
    /// of `triangles`; lanes whose id is [`EMPTY_ID`] are left as they are.
    /// Always inlined, as [`Tri4::set_lane`] is, into the leaf fill and the
    /// refit.
    #[inline(always)]
    pub(crate) fn fill<T: Triangles + ?Sized>(&mut self, ids: &[u32], triangles: &T) {
        for (lane, &id) in ids.iter().enumerate() {
            if id != EMPTY_ID {
                self.set_lane(lane, &triangles.get(id as usize), id);
            }
        }
    }

    /// The triangle of `lane`.
    #[inline]
    pub fn triangle(&self, lane: usize) -> [Vec3; 3] {
        let v = |k: usize| Vec3::new(self.v[k][0][lane], self.v[k][1][lane], self.v[k][2][lane]);
        [v(0), v(1), v(2)]
    }

    /// Number of used lanes.
    #[inline]
    pub fn len(&self) -> usize {
        self.ids.iter().filter(|&&id| id != EMPTY_ID).count()
    }

    /// Whether no lane is used (never true of a block in a tree).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Asks for the triangles `ids` of one block ([`EMPTY_ID`] where unused) to
/// be read ahead: `stage` 0 their index triples, 1 their vertices. Leaf
/// order jumps about a scene's triangle order, so whatever fills blocks
/// (the wide build's leaf fill, the refit) asks a few blocks early.
#[inline]
pub(crate) fn prefetch_triangles<T: Triangles + ?Sized>(triangles: &T, ids: &[u32], stage: u8) {
    for &id in ids.iter().filter(|&&id| id != EMPTY_ID) {
        triangles.prefetch(id as usize, stage);
    }
}

/// The hits of a ray on the four lanes of a block.
#[derive(Clone, Copy, Debug)]
pub struct Hits4 {
    /// Bit `i` set when lane `i` is hit within `(tmin, tmax)`.
    pub mask: u32,
    pub t: Vec4,
    pub u: Vec4,
    pub v: Vec4,
}

impl Hits4 {
    /// The closest of the hit lanes by [`Hit::is_closer_than`] (lowest id on
    /// equal `t`), if any.
    #[inline]
    pub fn closest(&self, ids: &[u32; LANES]) -> Option<Hit> {
        let mut mask = self.mask;
        let mut best: Option<Hit> = None;
        while mask != 0 {
            let lane = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let hit = Hit {
                t: self.t[lane],
                u: self.u[lane],
                v: self.v[lane],
                tri: ids[lane],
                inst: 0,
            };
            if best.is_none_or(|b| hit.is_closer_than(&b)) {
                best = Some(hit);
            }
        }
        best
    }
}

/// A ray broadcast to four lanes for [`intersect4`].
#[derive(Clone, Copy, Debug)]
pub struct Ray4 {
    pub origin: [Vec4; 3],
    pub dir: [Vec4; 3],
}

impl Ray4 {
    #[inline]
    pub fn new(ray: &Ray) -> Ray4 {
        let s = |v: Vec3| [Vec4::splat(v.x), Vec4::splat(v.y), Vec4::splat(v.z)];
        Ray4 {
            origin: s(ray.origin),
            dir: s(ray.dir),
        }
    }
}

/// Moller-Trumbore on four triangles at once: lane for lane the operations of
/// [`intersect_triangle`] in the same order (no fused multiply-adds), so a hit
/// lane's `(t, u, v)` is bit-identical to the scalar test's and a lane hits
/// exactly when the scalar test reports a hit.
#[inline(always)]
pub fn intersect4(ray4: &Ray4, tmin: f32, tmax: f32, block: &Tri4) -> Hits4 {
    let [ox, oy, oz] = ray4.origin;
    let [dx, dy, dz] = ray4.dir;
    let [v0, v1, v2] = &block.v;
    let (e1x, e1y, e1z) = (v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]);
    let (e2x, e2y, e2z) = (v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]);
    // p = dir x e2
    let px = dy * e2z - e2y * dz;
    let py = dz * e2x - e2z * dx;
    let pz = dx * e2y - e2x * dy;
    let det = e1x * px + e1y * py + e1z * pz;
    let inv_det = Vec4::ONE / det;
    let (sx, sy, sz) = (ox - v0[0], oy - v0[1], oz - v0[2]);
    let u = (sx * px + sy * py + sz * pz) * inv_det;
    // q = s x e1
    let qx = sy * e1z - e1y * sz;
    let qy = sz * e1x - e1z * sx;
    let qz = sx * e1y - e1x * sy;
    let v = (dx * qx + dy * qy + dz * qz) * inv_det;
    let t = (e2x * qx + e2y * qy + e2z * qz) * inv_det;
    // Every test is written so that NaN fails it, as in the scalar test.
    let ok = det.abs().cmpge(Vec4::splat(f32::MIN_POSITIVE))
        & u.cmpge(Vec4::ZERO)
        & u.cmple(Vec4::ONE)
        & v.cmpge(Vec4::ZERO)
        & (u + v).cmple(Vec4::ONE)
        & t.cmpgt(Vec4::splat(tmin))
        & t.cmplt(Vec4::splat(tmax));
    Hits4 {
        mask: ok.bitmask(),
        t,
        u,
        v,
    }
}

/// A ray/triangle test applied to a whole block, four lanes at once.
pub trait BlockTest: TriangleTest {
    /// Whether this is Moller-Trumbore, which the SIMD packet kernel
    /// computes for 8 or 16 rays at once (`simd_packet::SimdPacket`).
    const IS_MOLLER_TRUMBORE: bool = false;

    /// The hits of `ray` (broadcast as `ray4`) on the lanes of `block` within
    /// `(ray.tmin, ray.tmax)`, each as [`TriangleTest::test`] reports it.
    fn test4(prepared: &Self::Prepared, ray4: &Ray4, ray: &Ray, block: &Tri4) -> Hits4;
}

impl BlockTest for MollerTrumbore {
    const IS_MOLLER_TRUMBORE: bool = true;

    #[inline(always)]
    fn test4(_: &(), ray4: &Ray4, ray: &Ray, block: &Tri4) -> Hits4 {
        intersect4(ray4, ray.tmin, ray.tmax, block)
    }
}

impl BlockTest for Watertight {
    #[inline(always)]
    fn test4(prepared: &Self::Prepared, _: &Ray4, ray: &Ray, block: &Tri4) -> Hits4 {
        watertight4(prepared, ray, block)
    }
}

/// The watertight test on four triangles at once: lane for lane the
/// operations of [`Watertight::test`] in the same order (no fused
/// multiply-adds), so each lane's answer is the scalar test's, bit for bit.
/// The lanes the scalar test decides apart are handed to it: an edge
/// function exactly zero (redone in double precision there) and a hit
/// within [`NEAR_ORIGIN`] of the origin (its side of the origin decided
/// exactly); both are rare on render rays. The scalar test lane by lane
/// made watertight rays spend 3-4x Moller-Trumbore's time on leaf-bound
/// scenes (pipes:20000).
#[inline(always)]
pub fn watertight4(w: &WatertightRay, ray: &Ray, block: &Tri4) -> Hits4 {
    let used = block
        .ids
        .iter()
        .enumerate()
        .fold(0, |m, (lane, &id)| m | ((id != EMPTY_ID) as u32) << lane);
    let (o, [kx, ky, kz]) = (ray.origin, [w.kx, w.ky, w.kz]);
    let (sx, sy, sz) = (Vec4::splat(w.sx), Vec4::splat(w.sy), Vec4::splat(w.sz));
    // Each vertex translated to the origin, permuted, sheared in x and y.
    let p = block.v.map(|v| {
        let (x, y, z) = (
            v[kx] - Vec4::splat(o[kx]),
            v[ky] - Vec4::splat(o[ky]),
            v[kz] - Vec4::splat(o[kz]),
        );
        [x + sx * z, y + sy * z, z]
    });
    let e0 = p[1][0] * p[2][1] - p[1][1] * p[2][0];
    let e1 = p[2][0] * p[0][1] - p[2][1] * p[0][0];
    let e2 = p[0][0] * p[1][1] - p[0][1] * p[1][0];
    let zero = Vec4::ZERO;
    let exact_zero = (e0.cmpeq(zero) | e1.cmpeq(zero) | e2.cmpeq(zero)).bitmask() & used;
    let negative = e0.cmplt(zero) | e1.cmplt(zero) | e2.cmplt(zero);
    let positive = e0.cmpgt(zero) | e1.cmpgt(zero) | e2.cmpgt(zero);
    let det = e0 + e1 + e2;
    let z = [p[0][2] * sz, p[1][2] * sz, p[2][2] * sz];
    let t_scaled = e0 * z[0] + e1 * z[1] + e2 * z[2];
    let (lo, hi) = (Vec4::splat(ray.tmin) * det, Vec4::splat(ray.tmax) * det);
    let pad = Vec4::splat(4.0 * f32::EPSILON);
    let inside_negative = t_scaled.cmplt(lo + lo.abs() * pad) & t_scaled.cmpgt(hi - hi.abs() * pad);
    let inside_positive = t_scaled.cmpgt(lo - lo.abs() * pad) & t_scaled.cmplt(hi + hi.abs() * pad);
    let det_negative = det.cmplt(zero);
    let inside = (det_negative & inside_negative) | (!det_negative & inside_positive);
    let inv = Vec4::ONE / det;
    let t = t_scaled * inv;
    let ok = !(negative & positive)
        & det.cmpne(zero)
        & inside
        & t.cmpgt(Vec4::splat(ray.tmin))
        & t.cmplt(Vec4::splat(ray.tmax));
    let mut mask = ok.bitmask() & used & !exact_zero;
    let reach = NEAR_ORIGIN * ray.origin.abs().max_element().max(1.0);
    let near = (t * Vec4::splat(ray.dir.abs().max_element())).cmple(Vec4::splat(reach));
    let mut hits = Hits4 {
        mask: 0,
        t,
        u: e1 * inv,
        v: e2 * inv,
    };
    for lane in bits(near.bitmask() & mask) {
        if !ahead_of_origin(ray, &block.triangle(lane)) {
            mask &= !(1 << lane);
        }
    }
    hits.mask = mask;
    for lane in bits(exact_zero) {
        if let Some((t, u, v)) = Watertight::test(w, ray, &block.triangle(lane)) {
            hits.mask |= 1 << lane;
            hits.t[lane] = t;
            hits.u[lane] = u;
            hits.v[lane] = v;
        }
    }
    hits
}

/// The set bits of a mask, lowest first: the lanes, rays or children it
/// selects.
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

/// The reference for [`intersect4`]: the scalar test lane by lane.
pub fn intersect4_scalar(ray: &Ray, block: &Tri4) -> [Option<(f32, f32, f32)>; LANES] {
    std::array::from_fn(|lane| intersect_triangle(ray, &block.triangle(lane)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_block(rng: &mut Rng, lanes: usize) -> Tri4 {
        let mut p = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        let tris: Vec<[Vec3; 3]> = (0..lanes).map(|_| [p(), p(), p()]).collect();
        let ids: Vec<u32> = (0..lanes as u32).map(|i| 10 + i).collect();
        Tri4::new(&tris, &ids)
    }

    #[test]
    fn simd_triangle_test_equals_the_scalar_one_lane_by_lane() {
        let mut rng = Rng::for_pixel(3, 1, 4);
        let mut hits = 0;
        for k in 0..50_000 {
            let block = random_block(&mut rng, 1 + k % 4);
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0 - 2.0;
            let target = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            let mut ray = Ray::new(o, target - o);
            if k % 5 == 0 {
                ray.tmax = rng.next_f32() * 1.5;
            }
            if k % 7 == 0 {
                // Aimed exactly at a vertex: the rounding-sensitive case.
                let lane = k % block.len();
                ray.dir = block.triangle(lane)[k % 3] - o;
            }
            let simd = intersect4(&Ray4::new(&ray), ray.tmin, ray.tmax, &block);
            for (lane, want) in intersect4_scalar(&ray, &block).iter().enumerate() {
                let got = (simd.mask >> lane & 1 == 1)
                    .then(|| (simd.t[lane], simd.u[lane], simd.v[lane]));
                let bits = |h: Option<(f32, f32, f32)>| {
                    h.map(|(t, u, v)| (t.to_bits(), u.to_bits(), v.to_bits()))
                };
                assert_eq!(bits(got), bits(*want), "ray {k} lane {lane}");
                hits += want.is_some() as usize;
            }
        }
        assert!(hits > 5_000, "too few hits to mean anything: {hits}");
    }

    /// [`watertight4`] against [`Watertight::test`] lane by lane, bit for
    /// bit: random blocks and rays, rays aimed exactly at vertices and at
    /// edges' midpoints (edge functions exactly zero: the double-precision
    /// lanes), rays starting on a triangle's plane (the near-origin lanes),
    /// degenerate triangles, finite and infinite `tmax`, unused lanes.
    #[test]
    fn simd_watertight_test_equals_the_scalar_one_lane_by_lane() {
        let mut rng = Rng::for_pixel(8, 2, 6);
        let (mut hits, mut zero_lanes, mut near_lanes) = (0, 0, 0);
        for k in 0..100_000 {
            let mut block = random_block(&mut rng, 1 + k % 4);
            if k % 11 == 0 {
                // A degenerate lane: two vertices equal.
                let mut tri = block.triangle(0);
                tri[1] = tri[2];
                block.set_lane(0, &tri, 10);
            }
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0 - 2.0;
            let target = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            let mut ray = Ray::new(o, target - o);
            if k % 5 == 0 {
                ray.tmax = rng.next_f32() * 1.5;
            }
            let chosen = k % block.len();
            let tri = block.triangle(chosen);
            match k % 7 {
                0 => ray.dir = tri[k % 3] - o,
                1 => ray.dir = (tri[k % 3] + tri[(k + 1) % 3]) * 0.5 - o,
                2 => {
                    // From a point of the triangle's plane (its centroid),
                    // leaving it at a slant.
                    ray.origin = (tri[0] + tri[1] + tri[2]) / 3.0;
                    ray.dir = target - ray.origin;
                }
                _ => {}
            }
            let prepared = Watertight::prepare(&ray);
            let simd = watertight4(&prepared, &ray, &block);
            let w = &prepared;
            for lane in 0..LANES {
                let want = (block.ids[lane] != EMPTY_ID)
                    .then(|| Watertight::test(w, &ray, &block.triangle(lane)))
                    .flatten();
                let got = (simd.mask >> lane & 1 == 1)
                    .then(|| (simd.t[lane], simd.u[lane], simd.v[lane]));
                let bits = |h: Option<(f32, f32, f32)>| {
                    h.map(|(t, u, v)| (t.to_bits(), u.to_bits(), v.to_bits()))
                };
                assert_eq!(bits(got), bits(want), "ray {k} lane {lane} {ray:?}");
                hits += want.is_some() as usize;
                if block.ids[lane] != EMPTY_ID {
                    let t = block.triangle(lane).map(|v| v - ray.origin);
                    let p = t.map(|v| {
                        let (x, y, z) = (v[w.kx], v[w.ky], v[w.kz]);
                        (x + w.sx * z, y + w.sy * z)
                    });
                    let e = |a: (f32, f32), b: (f32, f32)| a.0 * b.1 - a.1 * b.0;
                    zero_lanes +=
                        [e(p[1], p[2]), e(p[2], p[0]), e(p[0], p[1])].contains(&0.0) as usize;
                    // The ray's own triangle, at t about 0: unless its edge
                    // functions are zero, decided by the near-origin check.
                    near_lanes += (k % 7 == 2 && lane == chosen) as usize;
                }
            }
        }
        assert!(
            hits > 10_000 && zero_lanes > 1_000 && near_lanes > 1_000,
            "{hits} hits, {zero_lanes} lanes with a zero edge function, {near_lanes} near"
        );
    }

    #[test]
    fn empty_lanes_never_hit_and_nan_rays_miss() {
        let tri = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::Y,
        ];
        let block = Tri4::new(&[tri], &[7]);
        assert_eq!(block.len(), 1);
        // Through the origin, where the empty lanes' point triangles sit.
        let ray = Ray::new(Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let hits = intersect4(&Ray4::new(&ray), 0.0, f32::INFINITY, &block);
        assert_eq!(hits.mask, 1);
        assert_eq!(hits.closest(&block.ids).unwrap().tri, 7);
        let nan = Ray::new(Vec3::new(f32::NAN, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(
            intersect4(&Ray4::new(&nan), 0.0, f32::INFINITY, &block).mask,
            0
        );
    }

    #[test]
    fn closest_lane_breaks_ties_by_lowest_id() {
        let tri = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::Y,
        ];
        let far = tri.map(|v| v - Vec3::Z);
        let block = Tri4::new(&[far, tri, tri], &[1, 9, 4]);
        let ray = Ray::new(Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let hits = intersect4(&Ray4::new(&ray), 0.0, f32::INFINITY, &block);
        assert_eq!(hits.mask, 0b111);
        let best = hits.closest(&block.ids).unwrap();
        assert_eq!((best.tri, best.t), (4, 1.0));
    }
}
