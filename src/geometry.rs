//! Rays, hits, bounding boxes and the ray/triangle test every backend shares.
//!
//! All backends call [`intersect_triangle`] on the same gathered vertex data, so a
//! hit found by two backends has a bit-identical `t`; ties between triangles at the
//! same `t` are broken by the lowest triangle index ([`Hit::is_closer_than`]).

use glam::Vec3;

/// A ray segment `origin + t * dir` for `t` in the open interval `(tmin, tmax)`.
///
/// `dir` need not be normalised; `t` is measured in units of `dir`.
/// `repr(C)`: the SIMD packet kernels load rays as eight f32 each.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub tmin: f32,
    pub tmax: f32,
}

impl Ray {
    /// A ray from `origin` along `dir` with `tmin = 0` and `tmax = +inf`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray {
            origin,
            dir,
            tmin: 0.0,
            tmax: f32::INFINITY,
        }
    }

    /// A ray restricted to `(tmin, tmax)`.
    pub fn segment(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Self {
        Ray {
            origin,
            dir,
            tmin,
            tmax,
        }
    }

    /// Whether the ray can hit anything: finite origin, finite non-zero direction,
    /// `tmin` finite and not above `tmax` (which may be `+inf`). Backends return
    /// "no hit" for rays that fail this, so NaN input never produces a hit or a panic.
    #[inline]
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && self.dir.is_finite()
            && self.dir != Vec3::ZERO
            && self.tmin.is_finite()
            && self.tmin >= 0.0
            && self.tmax >= self.tmin // false for NaN
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// The closest (or any) intersection of a ray with a triangle.
///
/// `u` and `v` are the barycentric weights of vertices 1 and 2 (vertex 0 has
/// `1 - u - v`); `tri` is the triangle's index in the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
    pub tri: u32,
    /// The instance the triangle was hit through (0 in a scene without
    /// instances): `tri` is an index into the scene's unique triangles, placed
    /// by `scene.instancing`'s instance `inst`.
    pub inst: u32,
}

impl Hit {
    /// The ordering every backend uses for closest hits: smaller `t` wins, and at
    /// equal `t` the lower instance, then the lower triangle index wins (the
    /// order a flattened copy of the scene numbers its triangles in), so
    /// results never depend on the order in which a backend happens to visit
    /// triangles.
    #[inline]
    pub fn is_closer_than(&self, other: &Hit) -> bool {
        self.t < other.t || (self.t == other.t && (self.inst, self.tri) < (other.inst, other.tri))
    }
}

/// An axis-aligned bounding box. The empty box has `min = +inf`, `max = -inf`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::INFINITY,
        max: Vec3::NEG_INFINITY,
    };

    /// Inlined: every builder calls it per triangle, and as a call (it was
    /// not inlined across codegen units) a pass over the engine's 110k
    /// triangles took 2.6 ms instead of 0.28.
    #[inline]
    pub fn from_points(points: &[Vec3]) -> Self {
        points.iter().fold(Self::EMPTY, |b, &p| b.grown(p))
    }

    #[inline]
    pub fn grown(self, p: Vec3) -> Self {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    #[inline]
    pub fn union(self, other: Aabb) -> Self {
        Aabb {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    #[inline]
    pub fn is_empty(&self) -> bool {
        !(self.min.cmple(self.max).all())
    }

    #[inline]
    pub fn extent(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    #[inline]
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area; 0 for the empty box.
    #[inline]
    pub fn surface_area(&self) -> f32 {
        let e = self.extent();
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Whether `other` lies inside this box (boundaries included).
    pub fn contains(&self, other: &Aabb) -> bool {
        other.is_empty() || (self.min.cmple(other.min).all() && other.max.cmple(self.max).all())
    }

    /// Slab test against a ray prepared as [`SlabRay`]. Returns the entry
    /// distance if the box overlaps `(tmin, tmax)`, with `tmax` the caller's
    /// current closest hit.
    ///
    /// Conservative: the exit distance is enlarged by `1 + 2 gamma(3)` (pbrt-v4,
    /// after Ize 2013), which bounds the rounding of the three operations per slab,
    /// so a box that a ray touches in one point (a vertex, a flat box's face) is
    /// never culled by rounding; and a ray lying in a face's plane keeps the box
    /// (see [`SlabRay`]). The enlargement is in the reciprocal the exit
    /// planes are multiplied by ([`SlabRay::inv_far`]), not a multiply of the
    /// exit distance: the same number of rounded operations, so the same
    /// bound, and one step less between a node's load and its hit mask.
    #[inline]
    pub fn intersect(&self, ray: &SlabRay, tmin: f32, tmax: f32) -> Option<f32> {
        let (d0, d1) = (self.min - ray.from_min, self.max - ray.from_max);
        Self::slab_entry(d0, d1, ray, tmin, tmax)
    }

    /// The entry distance from the minimum and maximum planes' distances
    /// from the ray's origins (`d0`, `d1`), if it is not past the exit.
    #[inline(always)]
    fn slab_entry(d0: Vec3, d1: Vec3, ray: &SlabRay, tmin: f32, tmax: f32) -> Option<f32> {
        let (t0, t1) = (d0 * ray.inv_dir, d1 * ray.inv_dir);
        let (f0, f1) = (d0 * ray.inv_far, d1 * ray.inv_far);
        let near = t0.min(t1).max_element().max(tmin);
        let far = f0.max(f1).min_element().min(tmax);
        if near <= far {
            Some(near)
        } else {
            None
        }
    }

    /// [`Self::intersect`] of this box grown on every side by [`BOX_GROWTH`]
    /// times the farthest it lies from the ray's origin on an axis, for
    /// [`TriangleTest::GROWS_BOXES`]. The growth is added to the planes'
    /// distances from the origin (each rounded relative to itself, so the
    /// growth, 32 of its half-ulps, survives), not to their coordinates.
    #[inline]
    pub fn intersect_grown(&self, ray: &SlabRay, tmin: f32, tmax: f32) -> Option<f32> {
        let (d0, d1) = (self.min - ray.from_min, self.max - ray.from_max);
        let grow = Vec3::splat(d0.abs().max(d1.abs()).max_element() * BOX_GROWTH);
        Self::slab_entry(d0 - grow, d1 + grow, ray, tmin, tmax)
    }
}

/// `gamma(3) = 3u / (1 - 3u)` with `u = 2^-24`: the relative error bound of three
/// rounded f32 operations (pbrt's error analysis).
pub const GAMMA3: f32 = 3.0 * (f32::EPSILON * 0.5) / (1.0 - 3.0 * (f32::EPSILON * 0.5));

/// The conservative slab test's growth of exit distances, 1 + 2 gamma(3) (Ize
/// 2013): [`Aabb::intersect`] and the wide trees' node kernels use it.
pub const SLAB_GROW: f32 = 1.0 + 2.0 * GAMMA3;

/// The magnitude [`safe_reciprocal`] clamps to. For every non-NaN `c` its
/// result equals `(1 / c).clamp(-RECIPROCAL_MAX, RECIPROCAL_MAX)` (a zero's
/// infinite reciprocal clamps to the same signed value), which is how the
/// packet kernels compute it eight rays at a time.
pub const RECIPROCAL_MAX: f32 = 1e30;

/// `1 / d` per component, with zero components mapped to a huge finite value of the
/// same sign instead of infinity, so the slab test never computes `0 * inf = NaN`
/// for rays that lie in a slab's boundary plane.
#[inline]
pub fn safe_reciprocal(d: Vec3) -> Vec3 {
    const BIG: f32 = RECIPROCAL_MAX;
    let r = |c: f32| {
        if c == 0.0 {
            if c.is_sign_negative() {
                -BIG
            } else {
                BIG
            }
        } else {
            (1.0 / c).clamp(-BIG, BIG)
        }
    };
    Vec3::new(r(d.x), r(d.y), r(d.z))
}

/// How far a ray with a zero direction component reaches to either side of
/// its plane in the slab tests, at least (see [`SlabRay`]): `1e-10 *
/// RECIPROCAL_MAX = 1e20`, a slab distance beyond any ray's `tmax`.
pub const IN_PLANE_REACH: f32 = 1e-10;

/// A ray as every slab test of raylab's trees sees it: the reciprocal
/// direction ([`safe_reciprocal`]), and the origin the boxes' minimum planes
/// (`from_min`) and maximum planes (`from_max`) are measured from.
///
/// On an axis where the direction is not zero both are the origin, and the
/// test is the textbook one. Where it is zero the ray lies in a plane of that
/// axis and meets a box only if the plane lies within the box's slab, the
/// faces included; but `(face - origin) * RECIPROCAL_MAX` is `0 * BIG = 0`
/// when the origin lies exactly in a face (origins land on vertex
/// coordinates often far from the origin, where floats are coarse), and a
/// zero exit distance culls the box as soon as another axis's entry is
/// positive: a ray along +x in the plane of a leaf box's top face missed the
/// triangle whose edge lies in it (`far:20000`'s AO rays, 17 false misses).
/// So on such an axis the minimum planes are measured from just above the
/// origin and the maximum planes from just below it (by an ulp, and at least
/// [`IN_PLANE_REACH`]): a face the ray lies in is a huge distance behind the
/// entry and ahead of the exit, the slab test keeps the box, and a box whose
/// face is that close to the plane on its far side is kept too (only ever
/// one more box visited, never a hit lost).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlabRay {
    pub from_min: Vec3,
    pub from_max: Vec3,
    pub inv_dir: Vec3,
    /// `inv_dir * SLAB_GROW`, what exit planes' distances are multiplied by
    /// (see [`Aabb::intersect`]). Rounding is monotone, so the packet
    /// frustum's bounds on it are the products of its bounds on `inv_dir`.
    pub inv_far: Vec3,
}

impl SlabRay {
    #[inline(always)]
    pub fn new(ray: &Ray) -> SlabRay {
        let in_plane = ray.dir.cmpeq(Vec3::ZERO);
        if !in_plane.any() {
            let inv_dir = safe_reciprocal(ray.dir);
            return SlabRay {
                from_min: ray.origin,
                from_max: ray.origin,
                inv_dir,
                inv_far: inv_dir * SLAB_GROW,
            };
        }
        let o = ray.origin;
        let inv_dir = safe_reciprocal(ray.dir);
        SlabRay {
            from_min: Vec3::select(in_plane, o.map(above_plane), o),
            from_max: Vec3::select(in_plane, o.map(below_plane), o),
            inv_dir,
            inv_far: inv_dir * SLAB_GROW,
        }
    }
}

/// How much the slab tests grow a box for a triangle test with
/// [`TriangleTest::GROWS_BOXES`], per unit of the farthest the box lies from
/// the ray's origin on an axis: 16 ulps (at 1), against the watertight
/// test's roundings of a vertex's translation to the origin and its shear,
/// a few ulps of that distance each. A ray through a shared edge can go to
/// a triangle it misses in exact arithmetic by those roundings; an exact
/// slab test then culls that triangle's box while the other triangle
/// rejects the ray: a hole (rooms:20000's edge rays, 2 in 50,000, through
/// the corner edge of two walls). Each box is grown from its own farthest
/// corner, in the distances from the origin (a coordinate 1e5 from the
/// origin has ulps of 0.008, which would swallow the growth of a box a
/// unit away): growing every box by the root's farthest corner instead
/// made short rays leaving a wall enter every neighbour's box (AO rays
/// 5.9x slower on rooms:20000). Not a bound for edges far shorter than
/// their distance from the ray's origin, whose edge functions cancel.
pub const BOX_GROWTH: f32 = 16.0 * f32::EPSILON;

/// The coordinate [`SlabRay`] measures minimum planes from when the ray
/// lies in the plane at `c`: `c + max(|c| * 2^-23, IN_PLANE_REACH)`, at least
/// an ulp above `c` (`|c| * 2^-23` is exact and never under an ulp of `c`)
/// and at most two. Monotone in `c` (the maximum of two rising functions),
/// which the packet frustum relies on: the greatest origin's value bounds
/// every ray's. The packet kernels compute the same operations lane by lane.
#[inline]
pub fn above_plane(c: f32) -> f32 {
    c + (c.abs() * f32::EPSILON).max(IN_PLANE_REACH)
}

/// [`above_plane`]'s mirror, for maximum planes.
#[inline]
pub fn below_plane(c: f32) -> f32 {
    c - (c.abs() * f32::EPSILON).max(IN_PLANE_REACH)
}

/// Moller-Trumbore ray/triangle test. Returns `(t, u, v)` for a hit with `t` in
/// `(ray.tmin, ray.tmax)`, both sides of the triangle counting; edges and vertices
/// are inclusive, so a ray through a shared edge hits both triangles (a tie).
///
/// Degenerate triangles and rays parallel to the plane (|det| below the smallest
/// normal float) never hit; NaN anywhere yields `None` because every accept test
/// is written so that NaN compares false.
#[inline]
pub fn intersect_triangle(ray: &Ray, tri: &[Vec3; 3]) -> Option<(f32, f32, f32)> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = ray.dir.cross(e2);
    let det = e1.dot(p);
    if !(det.abs() >= f32::MIN_POSITIVE) {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = ray.origin - tri[0];
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.dir.dot(q) * inv_det;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = e2.dot(q) * inv_det;
    if t > ray.tmin && t < ray.tmax {
        Some((t, u, v))
    } else {
        None
    }
}

/// How rays are tested against triangles (`--intersector`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Intersector {
    /// Moller-Trumbore (1997): fast, but rays through shared edges and vertices
    /// can pass between triangles (leak) through rounding.
    #[default]
    Mt,
    /// Woop, Benthin and Wald (2013): watertight; shared edges are never missed.
    Watertight,
}

/// A ray/triangle test with per-ray set-up, so traversal code is generic over
/// the method and pays for the set-up once per ray.
pub trait TriangleTest {
    /// Whether the trees' slab tests grow every box for this test, by
    /// [`BOX_GROWTH`] of its farthest distance from the ray's origin
    /// ([`Aabb::intersect_grown`]). Not for Moller-Trumbore, which promises
    /// nothing at edges (a ray through a shared edge may miss both
    /// triangles whatever the boxes do).
    const GROWS_BOXES: bool = false;
    /// Per-ray data.
    type Prepared;
    fn prepare(ray: &Ray) -> Self::Prepared;
    /// `(t, u, v)` as [`intersect_triangle`] returns it.
    fn test(prepared: &Self::Prepared, ray: &Ray, tri: &[Vec3; 3]) -> Option<(f32, f32, f32)>;
}

/// Moller-Trumbore as a [`TriangleTest`].
pub struct MollerTrumbore;

impl TriangleTest for MollerTrumbore {
    type Prepared = ();
    #[inline(always)]
    fn prepare(_ray: &Ray) {}
    #[inline(always)]
    fn test(_: &(), ray: &Ray, tri: &[Vec3; 3]) -> Option<(f32, f32, f32)> {
        intersect_triangle(ray, tri)
    }
}

/// The watertight test's per-ray set-up: the axis permutation that makes z the
/// dominant direction axis, and the shear that maps the ray onto +z.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    pub(crate) kx: usize,
    pub(crate) ky: usize,
    pub(crate) kz: usize,
    pub(crate) sx: f32,
    pub(crate) sy: f32,
    pub(crate) sz: f32,
}

/// Woop, Benthin and Wald (2013), "Watertight Ray/Triangle Intersection", JCGT
/// 2(1), as in pbrt-v4: vertices are translated to the ray origin, permuted and
/// sheared so the ray is the +z axis, and the 2D edge functions are evaluated,
/// in double precision when one is exactly zero. A point on a shared edge gives
/// the same edge value for both triangles, so no ray passes between them.
pub struct Watertight;

impl TriangleTest for Watertight {
    const GROWS_BOXES: bool = true;
    type Prepared = WatertightRay;

    #[inline]
    fn prepare(ray: &Ray) -> WatertightRay {
        let kz = ray.dir.abs().max_position();
        let kx = (kz + 1) % 3;
        let ky = (kx + 1) % 3;
        let d = ray.dir;
        WatertightRay {
            kx,
            ky,
            kz,
            sx: -d[kx] / d[kz],
            sy: -d[ky] / d[kz],
            sz: 1.0 / d[kz],
        }
    }

    #[inline]
    fn test(w: &WatertightRay, ray: &Ray, tri: &[Vec3; 3]) -> Option<(f32, f32, f32)> {
        let p = tri.map(|v| {
            let t = v - ray.origin;
            Vec3::new(t[w.kx], t[w.ky], t[w.kz])
        });
        // Shear x and y; z is scaled below, only when needed.
        let p = p.map(|v| Vec3::new(v.x + w.sx * v.z, v.y + w.sy * v.z, v.z));
        let mut e0 = p[1].x * p[2].y - p[1].y * p[2].x;
        let mut e1 = p[2].x * p[0].y - p[2].y * p[0].x;
        let mut e2 = p[0].x * p[1].y - p[0].y * p[1].x;
        if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
            let dp = |a: Vec3, b: Vec3| (a.x as f64 * b.y as f64 - a.y as f64 * b.x as f64) as f32;
            e0 = dp(p[1], p[2]);
            e1 = dp(p[2], p[0]);
            e2 = dp(p[0], p[1]);
        }
        if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
            return None;
        }
        let det = e0 + e1 + e2;
        if !(det != 0.0) {
            return None;
        }
        let z = [p[0].z * w.sz, p[1].z * w.sz, p[2].z * w.sz];
        let t_scaled = e0 * z[0] + e1 * z[1] + e2 * z[2];
        // Range pre-test without dividing: t in (tmin, tmax) with det's sign,
        // widened by a few ulps so that it never rejects a t that the exact
        // test below accepts (tmax * det and t_scaled / det each round). A
        // traversal tests with tmax just above its best t to find a tie at
        // the same t with a lower index; unwidened, rounding here rejected
        // some of those, and which of two triangles meeting on an edge won
        // depended on the order they were visited in.
        let (lo, hi) = (ray.tmin * det, ray.tmax * det);
        let pad = 4.0 * f32::EPSILON;
        let inside = if det < 0.0 {
            t_scaled < lo + lo.abs() * pad && t_scaled > hi - hi.abs() * pad
        } else {
            t_scaled > lo - lo.abs() * pad && t_scaled < hi + hi.abs() * pad
        };
        if !inside {
            return None;
        }
        let inv = 1.0 / det;
        let t = t_scaled * inv;
        if !(t > ray.tmin && t < ray.tmax) {
            return None;
        }
        if t * ray.dir.abs().max_element() <= NEAR_ORIGIN * ray.origin.abs().max_element().max(1.0)
            && !ahead_of_origin(ray, tri)
        {
            return None;
        }
        Some((t, e1 * inv, e2 * inv))
    }
}

/// Hits nearer the origin than this (relative to the origin's magnitude) have
/// their side of the origin decided exactly by [`ahead_of_origin`]: a ray
/// that starts on a triangle's plane (a shadow ray leaving a wall at the
/// corner with another) has t = 0 there, which f32 computes as about 1e-12
/// and would count as a hit. Far above that rounding; far below where the
/// renderer's offset rays meet real occluders often.
pub(crate) const NEAR_ORIGIN: f32 = 1e-4;

/// Whether the hit of `ray`'s line with the plane of `tri` (which it crosses)
/// lies strictly ahead of the origin: the origin's side of the plane, exactly
/// (Shewchuk's orient3d on the f32 inputs), against the direction's side
/// (f64; a direction that grazes the plane within its rounding keeps the hit).
pub(crate) fn ahead_of_origin(ray: &Ray, tri: &[Vec3; 3]) -> bool {
    let c = |v: Vec3| robust::Coord3D {
        x: v.x as f64,
        y: v.y as f64,
        z: v.z as f64,
    };
    // det[v0 - o; v1 - o; v2 - o] = n . (v0 - o), exactly: t * (n . d).
    let side = robust::orient3d(c(tri[0]), c(tri[1]), c(tri[2]), c(ray.origin));
    if side == 0.0 {
        return false; // the origin lies on the plane: t = 0
    }
    let v = tri.map(|p| p.as_dvec3());
    let n = (v[1] - v[0]).cross(v[2] - v[0]);
    let n_dot_d = n.dot(ray.dir.as_dvec3());
    let bound = 1e-12 * n.length() * ray.dir.as_dvec3().length();
    n_dot_d.abs() <= bound || (side > 0.0) == (n_dot_d > 0.0)
}

/// Where secondary rays start, to avoid hitting the surface they leave
/// (self-intersection). `raylab stress --suite offset` measures each.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OffsetStrategy {
    /// The hit point itself, `tmin = 0`.
    None,
    /// Moved 1e-4 scene units along the normal.
    Fixed,
    /// Moved `1e-4 * max(1, |p|_max)` along the normal.
    Scaled,
    /// The hit point, with `tmin = 1e-4 * max(1, |p|_max)` instead of a moved origin.
    Tmin,
    /// Wachter and Binder (Ray Tracing Gems, ch. 6): each coordinate moved by
    /// 256 * n units in the last place (a fixed 1/65536 * n near the origin).
    Ulp,
    /// The point interpolated from the triangle's vertices and moved by a
    /// bound on its error ([`spawn_origin`], pbrt-v4's way): the renderer's.
    Bounded,
}

impl OffsetStrategy {
    pub const ALL: [OffsetStrategy; 6] = [
        OffsetStrategy::None,
        OffsetStrategy::Fixed,
        OffsetStrategy::Scaled,
        OffsetStrategy::Tmin,
        OffsetStrategy::Ulp,
        OffsetStrategy::Bounded,
    ];

    /// The origin and `tmin` of a ray leaving the hit `(t, u, v)` of `ray` on
    /// `tri`, on the side of unit normal `n`. Every strategy but
    /// [`OffsetStrategy::Bounded`] starts from the point `ray.at(t)`.
    #[inline]
    pub fn apply(self, ray: &Ray, hit: (f32, f32, f32), tri: &[Vec3; 3], n: Vec3) -> (Vec3, f32) {
        let (t, u, v) = hit;
        let p = ray.at(t);
        let scale = || 1e-4 * p.abs().max_element().max(1.0);
        match self {
            OffsetStrategy::None => (p, 0.0),
            OffsetStrategy::Fixed => (p + n * 1e-4, 0.0),
            OffsetStrategy::Scaled => (p + n * scale(), 0.0),
            OffsetStrategy::Tmin => (p, scale()),
            OffsetStrategy::Ulp => (offset_ulp(p, n), 0.0),
            OffsetStrategy::Bounded => (spawn_origin(tri, u, v, n), 0.0),
        }
    }
}

/// pbrt's `gamma(n)`: a bound on the relative error that `n` successive f32
/// operations (each rounding by at most half an ulp) can accumulate.
#[inline]
pub const fn gamma(n: u32) -> f32 {
    let e = n as f32 * (f32::EPSILON * 0.5);
    e / (1.0 - e)
}

/// The point at barycentrics `(u, v)` (the weights of vertices 1 and 2) on
/// `tri`, interpolated from the vertices rather than rebuilt from a ray, and a
/// per-axis bound on its distance from the exact point of the triangle's plane.
///
/// `o + t * d` carries the error of `t`, which grows with the distance the ray
/// travelled; the interpolated point's error follows only the vertices'
/// magnitudes (pbrt-v4, `Triangle::InteractionFromIntersection`). Barycentrics
/// outside the triangle (a backend's rounding at an edge) are clamped into it,
/// so the point is always on the triangle. The bound, `gamma(7)` times the
/// largest vertex magnitude per axis, also covers weights that sum to 1 only
/// up to rounding.
#[inline]
pub fn surface_point(tri: &[Vec3; 3], u: f32, v: f32) -> (Vec3, Vec3) {
    let u = u.clamp(0.0, 1.0);
    let v = v.clamp(0.0, 1.0 - u);
    let w = (1.0 - u - v).max(0.0);
    let p = tri[0] * w + tri[1] * u + tri[2] * v;
    let magnitude = tri[0].abs().max(tri[1].abs()).max(tri[2].abs());
    (p, magnitude * gamma(7))
}

/// How far past the bound on the point's error [`spawn_origin`] moves, for
/// Moller-Trumbore: its `t` for the triangle a ray leaves is the triple
/// product `s . (e1 x e2)` over `|e1 x e2|`, whose rounding grows with the
/// magnitude `M` of the coordinates and the longest edge `L`, and is
/// amplified by the triangle's thinness `L^2 / |e1 x e2|`. The step is
/// `SPAWN_MT_ULPS * eps * (M + L) * L^2 / |e1 x e2|`, at most
/// [`SPAWN_MAX_STEP`] of the edge. The watertight test needs none (it
/// decides a hit next to its origin exactly). Measured by the
/// `spawned_rays_never_hit_the_triangle_they_leave` test (200,000 rays off
/// tilted triangles and slivers, 1e-2 to 1e5 from the origin, cosines down
/// to 0.01): none hits its own triangle from a quarter of an ulp up, 1,343
/// do without the step; 4 leaves a margin of 16.
pub const SPAWN_MT_ULPS: f32 = 4.0;
/// The most [`SPAWN_MT_ULPS`]'s step may take, as a fraction of the longest
/// edge: past it a sliver is too thin for any offset that does not lose
/// contact with its neighbours (2^-8 of its length).
pub const SPAWN_MAX_STEP: f32 = 1.0 / 256.0;

/// Where a secondary ray leaving `tri` at barycentrics `(u, v)` starts: the
/// interpolated point ([`surface_point`]) moved along the unit normal `n`
/// (pointing to the side the ray leaves from) by the bound on its error
/// projected on `n`, plus the step that covers Moller-Trumbore's rounding
/// ([`SPAWN_MT_ULPS`]), each coordinate then rounded one more ulp away from
/// the surface (pbrt-v4's `OffsetRayOrigin`, Wachter and Binder's argument).
/// The result lies strictly on `n`'s side of the triangle's exact plane at
/// any distance from the origin and the camera; `raylab validate` checks it
/// exactly.
#[inline]
pub fn spawn_origin(tri: &[Vec3; 3], u: f32, v: f32, n: Vec3) -> Vec3 {
    spawn_origin_stepped(tri, u, v, n, SPAWN_MT_ULPS, Vec3::ZERO)
}

/// [`spawn_origin`], moved further by the per-component error bound `pad`
/// (an instance's transform round trip: the instanced scene's shader spawns
/// in mesh space, and the instance's tree sees the origin moved to world
/// space and back).
#[inline]
pub fn spawn_origin_padded(tri: &[Vec3; 3], u: f32, v: f32, n: Vec3, pad: Vec3) -> Vec3 {
    spawn_origin_stepped(tri, u, v, n, SPAWN_MT_ULPS, pad)
}

/// [`spawn_origin`] with the Moller-Trumbore step in `mt_ulps` (the tests
/// measure it).
#[inline]
fn spawn_origin_stepped(tri: &[Vec3; 3], u: f32, v: f32, n: Vec3, mt_ulps: f32, pad: Vec3) -> Vec3 {
    let (p, err) = surface_point(tri, u, v);
    let (e1, e2, e3) = (tri[1] - tri[0], tri[2] - tri[0], tri[2] - tri[1]);
    let edge2 = e1
        .length_squared()
        .max(e2.length_squared())
        .max(e3.length_squared());
    let edge = edge2.sqrt();
    let magnitude = tri[0]
        .abs()
        .max(tri[1].abs())
        .max(tri[2].abs())
        .max_element();
    let cross = e1.cross(e2).length();
    let mt = mt_ulps * f32::EPSILON * (magnitude + edge) * (edge2 / cross);
    // NaN (a degenerate cross product) falls to the cap.
    let step = if mt <= edge * SPAWN_MAX_STEP {
        mt
    } else {
        edge * SPAWN_MAX_STEP
    };
    let d = n.abs().dot(err + pad) + step;
    let moved = p + n * d;
    let away = |q: f32, nc: f32| {
        if nc > 0.0 {
            q.next_up()
        } else if nc < 0.0 {
            q.next_down()
        } else {
            q
        }
    };
    Vec3::new(away(moved.x, n.x), away(moved.y, n.y), away(moved.z, n.z))
}

/// Whether `p` lies strictly on the side of `tri`'s plane that `n` points
/// to, decided exactly (Shewchuk's orient3d on the f32 inputs; `n` only
/// picks the side, by its sign against the winding normal in f64). False on
/// the plane, and for a degenerate triangle.
pub fn strictly_in_front(tri: &[Vec3; 3], p: Vec3, n: Vec3) -> bool {
    let c = |v: Vec3| robust::Coord3D {
        x: v.x as f64,
        y: v.y as f64,
        z: v.z as f64,
    };
    // orient3d = N . (v0 - p) for the winding normal N.
    let side = -robust::orient3d(c(tri[0]), c(tri[1]), c(tri[2]), c(p));
    let v = tri.map(|q| q.as_dvec3());
    let facing = (v[1] - v[0]).cross(v[2] - v[0]).dot(n.as_dvec3());
    side != 0.0 && facing != 0.0 && (side > 0.0) == (facing > 0.0)
}

/// Wachter and Binder's offset: per coordinate, `256 * n` units in the last
/// place away from the surface, which is a relative step whatever the magnitude;
/// near zero, where ULPs are tiny, a fixed `n / 65536` instead.
#[inline]
pub fn offset_ulp(p: Vec3, n: Vec3) -> Vec3 {
    const NEAR_ORIGIN: f32 = 1.0 / 32.0;
    let step = |pc: f32, nc: f32| {
        if pc.abs() < NEAR_ORIGIN {
            return pc + nc / 65536.0;
        }
        let ulps = (256.0 * nc) as i32;
        let ulps = if pc < 0.0 { -ulps } else { ulps };
        f32::from_bits((pc.to_bits() as i32).wrapping_add(ulps) as u32)
    };
    Vec3::new(step(p.x, n.x), step(p.y, n.y), step(p.z, n.z))
}

/// The unnormalised geometric normal `(v1 - v0) x (v2 - v0)` (length = 2 * area).
#[inline]
pub fn triangle_normal(tri: &[Vec3; 3]) -> Vec3 {
    (tri[1] - tri[0]).cross(tri[2] - tri[0])
}

/// The unit geometric normal, by winding (the direction of
/// `(v1 - v0) x (v2 - v0)`); zero for a triangle of zero area or with a
/// non-finite vertex. Exact to f32 rounding at any scale: where the f32 cross
/// product would overflow (edges above about 1e19) or underflow (below about
/// 1e-19), it is taken in f64 instead, so a triangle of size 1e10 or with
/// coordinates near 3e38 still has a normal.
#[inline]
pub fn triangle_unit_normal(tri: &[Vec3; 3]) -> Vec3 {
    let n = triangle_normal(tri);
    let len2 = n.length_squared();
    if len2.is_finite() && len2 >= f32::MIN_POSITIVE {
        return n.normalize();
    }
    let n = (tri[1].as_dvec3() - tri[0].as_dvec3()).cross(tri[2].as_dvec3() - tri[0].as_dvec3());
    if !n.is_finite() {
        return Vec3::ZERO;
    }
    n.normalize_or_zero().as_vec3()
}

/// Triangle area, taken in f64 (0 for degenerate triangles, NaN for non-finite
/// vertices; +inf only where the area itself exceeds f32).
#[inline]
pub fn triangle_area(tri: &[Vec3; 3]) -> f32 {
    let n = (tri[1].as_dvec3() - tri[0].as_dvec3()).cross(tri[2].as_dvec3() - tri[0].as_dvec3());
    (0.5 * n.length()) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_normals_survive_huge_and_tiny_triangles() {
        for scale in [1e-30f32, 1e-20, 1.0, 1e10, 1e20, 1e36] {
            let tri = [Vec3::ZERO, Vec3::X * scale, Vec3::Y * scale];
            assert_eq!(triangle_unit_normal(&tri), Vec3::Z, "scale {scale}");
            // The area itself fits an f32 from about 1e-19 up.
            if scale >= 1e-19 {
                assert!(triangle_area(&tri) > 0.0, "scale {scale}");
            }
        }
        // Coordinates near f32::MAX: the f32 edges overflow, the f64 ones do not.
        let m = 3e38f32;
        let tri = [
            Vec3::new(-m, -m, 0.0),
            Vec3::new(m, -m, 0.0),
            Vec3::new(-m, m, 0.0),
        ];
        assert_eq!(triangle_unit_normal(&tri), Vec3::Z);
        let flat = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        assert_eq!(triangle_unit_normal(&flat), Vec3::ZERO);
        assert_eq!(triangle_area(&flat), 0.0);
        let bad = [Vec3::NAN, Vec3::X, Vec3::Y];
        assert_eq!(triangle_unit_normal(&bad), Vec3::ZERO);
    }

    fn unit_tri() -> [Vec3; 3] {
        [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ]
    }

    #[test]
    fn front_hit_reports_t_and_barycentrics() {
        let r = Ray::new(Vec3::new(0.25, 0.5, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let (t, u, v) = intersect_triangle(&r, &unit_tri()).unwrap();
        assert!((t - 1.0).abs() < 1e-6);
        assert!((u - 0.25).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
    }

    #[test]
    fn back_side_hits_too() {
        let r = Ray::new(Vec3::new(0.25, 0.25, -2.0), Vec3::new(0.0, 0.0, 1.0));
        let (t, _, _) = intersect_triangle(&r, &unit_tri()).unwrap();
        assert!((t - 2.0).abs() < 1e-6);
    }

    #[test]
    fn edge_and_vertex_are_inclusive() {
        let tri = unit_tri();
        for p in [
            Vec3::new(0.5, 0.0, 1.0),
            Vec3::new(0.0, 0.5, 1.0),
            Vec3::new(0.5, 0.5, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
        ] {
            let r = Ray::new(p, Vec3::new(0.0, 0.0, -1.0));
            assert!(intersect_triangle(&r, &tri).is_some(), "{p}");
        }
    }

    #[test]
    fn outside_misses() {
        let r = Ray::new(Vec3::new(0.6, 0.6, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(intersect_triangle(&r, &unit_tri()).is_none());
        let r = Ray::new(Vec3::new(-0.01, 0.5, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(intersect_triangle(&r, &unit_tri()).is_none());
    }

    #[test]
    fn parallel_ray_misses() {
        let r = Ray::new(Vec3::new(-1.0, 0.25, 0.0), Vec3::new(1.0, 0.0, 0.0));
        assert!(intersect_triangle(&r, &unit_tri()).is_none());
        let r = Ray::new(Vec3::new(-1.0, 0.25, 0.5), Vec3::new(1.0, 0.0, 0.0));
        assert!(intersect_triangle(&r, &unit_tri()).is_none());
    }

    #[test]
    fn triangle_behind_origin_misses() {
        let r = Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::new(0.0, 0.0, 1.0));
        assert!(intersect_triangle(&r, &unit_tri()).is_none());
    }

    #[test]
    fn tmax_and_tmin_cut_off() {
        let d = Vec3::new(0.0, 0.0, -1.0);
        let o = Vec3::new(0.25, 0.25, 1.0);
        assert!(intersect_triangle(&Ray::segment(o, d, 0.0, 0.999), &unit_tri()).is_none());
        assert!(intersect_triangle(&Ray::segment(o, d, 0.0, 1.001), &unit_tri()).is_some());
        assert!(intersect_triangle(&Ray::segment(o, d, 1.001, 5.0), &unit_tri()).is_none());
    }

    #[test]
    fn nan_inputs_never_hit() {
        let tri = unit_tri();
        let nan = Vec3::new(f32::NAN, 0.0, 0.0);
        let d = Vec3::new(0.0, 0.0, -1.0);
        let o = Vec3::new(0.25, 0.25, 1.0);
        assert!(intersect_triangle(&Ray::new(nan, d), &tri).is_none());
        assert!(intersect_triangle(&Ray::new(o, nan), &tri).is_none());
        assert!(intersect_triangle(&Ray::segment(o, d, 0.0, f32::NAN), &tri).is_none());
        let bad = [nan, tri[1], tri[2]];
        assert!(intersect_triangle(&Ray::new(o, d), &bad).is_none());
        assert!(!Ray::new(o, Vec3::ZERO).is_valid());
        assert!(!Ray::new(nan, d).is_valid());
        assert!(!Ray::segment(o, d, 0.0, f32::NAN).is_valid());
        assert!(Ray::new(o, d).is_valid());
    }

    #[test]
    fn degenerate_triangle_never_hits() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        let r = Ray::new(Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(intersect_triangle(&r, &tri).is_none());
    }

    fn watertight(ray: &Ray, tri: &[Vec3; 3]) -> Option<(f32, f32, f32)> {
        Watertight::test(&Watertight::prepare(ray), ray, tri)
    }

    #[test]
    fn watertight_agrees_with_mt_on_hand_made_cases() {
        let tri = unit_tri();
        let down = Vec3::new(0.0, 0.0, -1.0);
        let (t, u, v) = watertight(&Ray::new(Vec3::new(0.25, 0.5, 1.0), down), &tri).unwrap();
        assert!((t - 1.0).abs() < 1e-6 && (u - 0.25).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
        assert!(
            watertight(&Ray::new(Vec3::new(0.25, 0.25, -2.0), -down), &tri).is_some(),
            "back side"
        );
        assert!(
            watertight(&Ray::new(Vec3::new(0.6, 0.6, 1.0), down), &tri).is_none(),
            "outside"
        );
        assert!(
            watertight(&Ray::new(Vec3::new(-1.0, 0.25, 0.0), Vec3::X), &tri).is_none(),
            "parallel"
        );
        assert!(
            watertight(&Ray::new(Vec3::new(0.25, 0.25, 1.0), -down), &tri).is_none(),
            "behind"
        );
        let o = Vec3::new(0.25, 0.25, 1.0);
        assert!(
            watertight(&Ray::segment(o, down, 0.0, 0.999), &tri).is_none(),
            "tmax"
        );
        assert!(
            watertight(&Ray::segment(o, down, 1.001, 5.0), &tri).is_none(),
            "tmin"
        );
        assert!(
            watertight(&Ray::new(Vec3::new(0.5, 0.0, 1.0), down), &tri).is_some(),
            "edge"
        );
        assert!(watertight(
            &Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::new(f32::NAN, 0.0, -1.0)),
            &tri
        )
        .is_none());
    }

    #[test]
    fn watertight_never_misses_both_triangles_of_a_shared_edge() {
        // A quad split along its diagonal; rays through points on the diagonal,
        // from many directions, must hit at least one of the two triangles.
        let a = Vec3::new(-1.3, 0.1, 0.7);
        let b = Vec3::new(0.9, 0.2, -0.4);
        let c = Vec3::new(1.1, 0.05, 0.9);
        let d = Vec3::new(-0.8, 0.15, -1.2);
        let (t1, t2) = ([a, b, c], [a, d, b]);
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / (1u64 << 24) as f32
        };
        for _ in 0..20_000 {
            let s = next();
            let target = a + (b - a) * s;
            let o = Vec3::new(next() * 4.0 - 2.0, 1.0 + next() * 3.0, next() * 4.0 - 2.0);
            let r = Ray::new(o, target - o);
            let p = Watertight::prepare(&r);
            assert!(
                Watertight::test(&p, &r, &t1).is_some() || Watertight::test(&p, &r, &t2).is_some(),
                "watertight leak at {target}"
            );
        }
    }

    #[test]
    fn ties_break_to_lowest_index() {
        let a = Hit {
            t: 1.0,
            u: 0.0,
            v: 0.0,
            tri: 3,
            inst: 0,
        };
        let b = Hit { tri: 7, ..a };
        assert!(a.is_closer_than(&b));
        assert!(!b.is_closer_than(&a));
        let c = Hit { t: 0.5, ..b };
        assert!(c.is_closer_than(&a));
    }

    /// Self-hits of rays spawned by [`spawn_origin_stepped`] with `step`
    /// off tilted triangles (slivers among them) anywhere from 1e-2 to 1e5
    /// from the origin, in directions down to a cosine of 0.01, against
    /// their own triangle with Moller-Trumbore and the watertight test.
    fn spawned_self_hits(step: f32) -> (usize, usize, usize) {
        let mut rng = crate::rng::Rng::for_pixel(1, 2, 3);
        let mut r = || rng.next_f32();
        let (mut mt, mut wt, mut behind) = (0, 0, 0);
        for i in 0..200_000 {
            let at = Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5) * 10f32.powf(r() * 7.0 - 2.0);
            let size = at.abs().max_element().max(1.0) * 10f32.powf(-r() * 3.0);
            let thin = if i % 2 == 0 {
                10f32.powf(-r() * 3.0)
            } else {
                1.0
            };
            let a = Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize_or_zero();
            let b = a
                .cross(Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5))
                .normalize_or_zero();
            let tri = [at, at + a * size, at + (a * 0.5 + b * thin) * size];
            let n = triangle_unit_normal(&tri);
            if n == Vec3::ZERO {
                continue;
            }
            let n = if r() < 0.5 { n } else { -n };
            let (u, v) = (r(), r());
            let (u, v) = if u + v > 1.0 {
                (1.0 - u, 1.0 - v)
            } else {
                (u, v)
            };
            let o = spawn_origin_stepped(&tri, u, v, n, step, Vec3::ZERO);
            behind += !strictly_in_front(&tri, o, n) as usize;
            let cos = 0.01 + 0.99 * r();
            let t = n.any_orthonormal_vector();
            let d = n * cos + t * (1.0 - cos * cos).sqrt();
            let ray = Ray::new(o, d);
            mt += intersect_triangle(&ray, &tri).is_some() as usize;
            wt += Watertight::test(&Watertight::prepare(&ray), &ray, &tri).is_some() as usize;
        }
        (mt, wt, behind)
    }

    #[test]
    fn spawned_rays_never_hit_the_triangle_they_leave() {
        assert_eq!(spawned_self_hits(SPAWN_MT_ULPS), (0, 0, 0));
        // The bound on the point alone is not enough for Moller-Trumbore
        // (1,343 of 200,000 found their own triangle; a quarter ulp of step
        // already none): the test can see what the step is for.
        let (mt, watertight, behind) = spawned_self_hits(0.0);
        assert!(mt > 100, "{mt}");
        assert_eq!((watertight, behind), (0, 0));
    }

    #[test]
    fn slab_test_handles_zero_direction_components() {
        let b = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let test =
            |o: Vec3, d: Vec3, tmax: f32| b.intersect(&SlabRay::new(&Ray::new(o, d)), 0.0, tmax);
        // Ray inside the slab x in [0,1] travelling along +z with dx = dy = 0.
        let d = Vec3::new(0.0, 0.0, 1.0);
        let t = test(Vec3::new(0.5, 0.5, -1.0), d, f32::INFINITY);
        assert!((t.unwrap() - 1.0).abs() < 1e-6);
        // Ray in the boundary plane x = 0 still counts (flat boxes must be hit).
        assert!(test(Vec3::new(0.0, 0.5, -1.0), d, f32::INFINITY).is_some());
        // Outside the slab: miss.
        assert!(test(Vec3::new(1.5, 0.5, -1.0), d, f32::INFINITY).is_none());
        // Beyond tmax: miss.
        assert!(test(Vec3::new(0.5, 0.5, -1.0), d, 0.5).is_none());
    }

    /// A ray lying in a face's plane, entering the box through another axis
    /// (a positive entry), keeps the box on every face and either sign of
    /// zero, near the origin and far from it. Measured from the origin
    /// itself, the maximum faces (the minimum ones for -0.0) gave the slab an
    /// exit of `0 * RECIPROCAL_MAX = 0` and culled the box.
    #[test]
    fn rays_in_a_face_plane_keep_the_box() {
        for centre in [Vec3::ZERO, Vec3::splat(1e5), Vec3::new(-3e4, 7.0, 1e6)] {
            let b = Aabb {
                min: centre,
                max: centre + Vec3::new(0.25, 0.5, 1.0),
            };
            for axis in [1, 2] {
                for face in [b.min[axis], b.max[axis]] {
                    for zero in [0.0f32, -0.0] {
                        let mut o = b.min - Vec3::X;
                        o[axis] = face;
                        let mut d = Vec3::new(1.0, 0.0, 0.0);
                        d[axis] = zero;
                        d[3 - axis] = 0.0;
                        o[3 - axis] = b.min[3 - axis];
                        let slab = SlabRay::new(&Ray::new(o, d));
                        let entry = b.intersect(&slab, 0.0, f32::INFINITY);
                        assert!(
                            entry.is_some_and(|t| (0.5..2.0).contains(&t)),
                            "centre {centre} axis {axis} face {face} zero {zero}: {entry:?}"
                        );
                        // The textbook test (the origin for both faces) culls
                        // the box on one face of the two.
                        let plain = SlabRay {
                            from_min: o,
                            from_max: o,
                            inv_dir: slab.inv_dir,
                            inv_far: slab.inv_far,
                        };
                        let culled = b.intersect(&plain, 0.0, f32::INFINITY).is_none();
                        let exit_face = if zero.is_sign_negative() {
                            b.min
                        } else {
                            b.max
                        };
                        assert_eq!(culled, face == exit_face[axis]);
                        // A plane beside the box still misses it.
                        let mut beside = o;
                        beside[axis] = b.max[axis] + 1e-3 * b.max[axis].abs().max(1.0);
                        assert!(b
                            .intersect(&SlabRay::new(&Ray::new(beside, d)), 0.0, f32::INFINITY)
                            .is_none());
                    }
                }
            }
        }
        // The reach is an ulp or two far from the origin and IN_PLANE_REACH
        // near it.
        for c in [1e5f32, -1e5, 3.0, -0.75, 1e-20] {
            let (up, down) = (above_plane(c), below_plane(c));
            assert!(
                up > c && up <= c.next_up().next_up().max(c + IN_PLANE_REACH),
                "{c}"
            );
            assert!(
                down < c && down >= c.next_down().next_down().min(c - IN_PLANE_REACH),
                "{c}"
            );
        }
        assert_eq!(below_plane(0.0), -IN_PLANE_REACH);
        assert!(above_plane(-0.0) > 0.0);
    }

    #[test]
    fn aabb_union_contains_and_area() {
        let a = Aabb::from_points(&[Vec3::ZERO, Vec3::ONE]);
        assert_eq!(a.surface_area(), 6.0);
        assert_eq!(Aabb::EMPTY.surface_area(), 0.0);
        assert!(Aabb::EMPTY.is_empty());
        let b = a.union(Aabb::from_points(&[Vec3::splat(2.0)]));
        assert!(b.contains(&a));
        assert!(!a.contains(&b));
    }
}
