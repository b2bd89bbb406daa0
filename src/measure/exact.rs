//! The exact reference (`validate --against exact`): for each ray, what an
//! infinitely precise ray/triangle test says, so that every backend (raylab's,
//! Embree, the other libraries) is judged right or wrong instead of only
//! compared with another backend that rounds too.
//!
//! Per triangle, the decisions are signs of determinants of the input
//! coordinates, taken exactly with Shewchuk's adaptive `orient3d` (the
//! `robust` crate):
//! - the line meets the triangle iff the three edge functions
//!   `e_i = det[v_i - o, v_i+1 - o, d]` are all >= 0 or all <= 0, not all 0
//!   (an exact 0 is a ray through an edge or vertex: both triangles of a
//!   shared edge are hit, so either may be the closest);
//! - the hit lies ahead iff `det[v0 - o, v1 - o, v2 - o]` (the origin's side of
//!   the plane, exact from the f32 inputs) has the edge functions' sign.
//!
//! `v - o` of two f32 values is exact in f64 unless their exponents are more
//! than 29 apart; that is checked (Two-Sum), and such a triangle is decided in
//! plain f64 with an error bound, or left undecided. `t` itself is a quotient
//! of determinants, computed in f64 with a forward error bound (Shewchuk's
//! `o3derrboundA` with room to spare): an interval. Whether `t` lies inside
//! `(tmin, tmax)` is therefore decided when the interval is clear of both
//! ends, and is otherwise "undecidable in double precision".
//!
//! Candidate triangles come from a binary BVH in f64 whose boxes are padded,
//! so culling never drops a triangle the exact test would hit.
//!
//! **Edge ties.** A ray through (or within rounding of) a triangle's edge is
//! decided exactly here, but no f32 test can be right about it every time:
//! moving the inputs by a few f32 ulps flips the answer. So the reference
//! also notes, per ray, which hits lie within [`EDGE_ULPS`] ulps of the
//! inputs' magnitude of their triangle's boundary, and which triangles it
//! misses by no more than that (grazes), measured across the ray. An answer
//! that differs from the exact one only there is an **edge tie**, not
//! wrong: the neighbour across a shared edge at the same t, or a hit on or a
//! miss of an edge no other triangle shares. A miss where the ray passes
//! through an edge two triangles share stays a false miss: that is a leak,
//! which a watertight test never makes.

use glam::{DVec3, Vec3};
use robust::{orient3d, Coord3D};
use serde::Serialize;

use crate::geometry::{Hit, Ray};

/// How far a backend's `t` may be from the exact interval, relative to the
/// query's scale: the largest input coordinate (origin or vertex; f32 tests
/// translate the triangle to the origin first) or the hit's distance, in
/// units of the direction, and divided by the cosine of the ray's angle to
/// the triangle's normal (a rounding error across the plane moves t by
/// 1 / cos along a slanting ray). f32 arithmetic on a few operations is
/// within 1e-6 of it; 1e-5 leaves room for the libraries' fast reciprocals.
pub const T_TOLERANCE: f64 = 1e-5;

/// How near (across the ray, in f32 ulps of the largest input coordinate) a
/// triangle's boundary must pass for an answer there to be an edge tie.
/// Measured: raylab's watertight test needs 4 on rays aimed at edges.
pub const EDGE_ULPS: f64 = 4.0;

/// Bound on the error of a 3x3 determinant evaluated in f64, relative to its
/// permanent (Shewchuk's `o3derrboundA` is (7 + 56 eps) eps; inexact inputs
/// `v - o` add 3 eps).
const DET_ERROR: f64 = 16.0 * f64::EPSILON;

/// One triangle the ray (possibly) hits within its range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExactHit {
    pub tri: u32,
    /// The exact t lies in `[t_lo, t_hi]`.
    pub t_lo: f64,
    pub t_hi: f64,
    /// The hit, and its lying within `(tmin, tmax)`, are certain (else only
    /// possible: double precision could not decide).
    pub sure: bool,
    /// The ray passes within [`EDGE_ULPS`] of the triangle's boundary.
    pub near_edge: bool,
    /// How far an f32 test's t may be from the interval (see [`T_TOLERANCE`]).
    pub t_slack: f64,
    /// Missing it is an edge tie, not a leak: the ray passes within
    /// rounding of one of its edges (not exactly through it: inclusive
    /// tests hit that) that no triangle it misses continues across (an
    /// open edge), or at a fold: another such hit at the same t, such as a
    /// box's edge or a mesh's silhouette the ray clips (in and out at once:
    /// rounding may drop both). A ray crossing the surface at an
    /// edge shared with a grazed neighbour must hit one of the two: a miss
    /// there is a leak, which a watertight test never makes.
    pub tie_if_missed: bool,
}

/// A triangle the ray misses, but within [`EDGE_ULPS`] of its boundary,
/// at about `t` (within the range).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Graze {
    pub tri: u32,
    pub t: f64,
    pub t_slack: f64,
}

/// What the exact test says of one triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Contact {
    /// Hit within the range: t in `[t_lo, t_hi]`, surely or possibly.
    Hit {
        t_lo: f64,
        t_hi: f64,
        sure: bool,
        t_slack: f64,
        /// The ray passes exactly through an edge or vertex.
        on_edge: bool,
        /// Bit i: edge i (`v_i` to `v_i+1`) passes within rounding (any
        /// bit set: the ray passes near the triangle's boundary).
        near_edges: u8,
    },
    /// Missed by no more than rounding, at about `t`.
    Graze { t: f64, t_slack: f64 },
}

/// What the exact test says of one ray: every triangle it surely or possibly
/// hits within its range.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExactAnswer {
    pub hits: Vec<ExactHit>,
    /// Triangles missed within rounding of their boundary (edge ties).
    pub grazes: Vec<Graze>,
}

/// Whether something lies within a ray's range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Occluder {
    Surely,
    SurelyNot,
    Possibly,
}

/// A backend's answer judged against the exact one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Right,
    /// No hit where one surely lies within the range.
    FalseMiss,
    /// A hit where nothing lies within the range, or on a triangle the ray
    /// surely misses.
    FalseHit,
    /// A triangle the ray hits, but another is surely nearer.
    WrongTriangle,
    /// The right triangle at a t outside the exact interval (by more than
    /// [`T_TOLERANCE`]).
    TError,
    /// Double precision could not decide.
    Undecidable,
    /// Differs from the exact answer only at a triangle's edge, within
    /// rounding of the inputs (not a leak: see the module's notes).
    EdgeTie,
}

impl Verdict {
    pub fn is_wrong(self) -> bool {
        !matches!(
            self,
            Verdict::Right | Verdict::Undecidable | Verdict::EdgeTie
        )
    }
}

impl ExactAnswer {
    /// Whether an occluder lies within the range.
    pub fn occluder(&self) -> Occluder {
        if self.hits.iter().any(|h| h.sure) {
            Occluder::Surely
        } else if self.hits.is_empty() {
            Occluder::SurelyNot
        } else {
            Occluder::Possibly
        }
    }

    /// A miss of every sure hit is an edge tie when each is (see
    /// [`ExactHit::tie_if_missed`]).
    fn miss_is_edge_tie(&self) -> bool {
        self.hits.iter().filter(|h| h.sure).all(|h| h.tie_if_missed)
    }

    /// Judges a closest-hit answer to `ray`.
    pub fn judge_closest(&self, got: Option<Hit>) -> Verdict {
        let Some(got) = got else {
            return match self.occluder() {
                Occluder::Surely if self.miss_is_edge_tie() => Verdict::EdgeTie,
                Occluder::Surely => Verdict::FalseMiss,
                Occluder::Possibly => Verdict::Undecidable,
                Occluder::SurelyNot => Verdict::Right,
            };
        };
        let t = got.t as f64;
        // A sure hit nearer than `t_lo` by more than rounding, and one a
        // miss of which is not an edge tie.
        let clearly_nearer = |t_lo: f64| {
            self.hits
                .iter()
                .any(|h| h.sure && h.t_hi + h.t_slack < t_lo && !h.tie_if_missed)
        };
        let Some(mine) = self.hits.iter().find(|h| h.tri == got.tri) else {
            if let Some(g) = self.grazes.iter().find(|g| g.tri == got.tri) {
                // A triangle missed by rounding: defensible unless something
                // is clearly nearer.
                return if clearly_nearer(g.t - g.t_slack) {
                    Verdict::WrongTriangle
                } else if (t - g.t).abs() > g.t_slack {
                    Verdict::TError
                } else {
                    Verdict::EdgeTie
                };
            }
            return if self.hits.iter().any(|h| h.sure) {
                Verdict::WrongTriangle
            } else if self.hits.is_empty() {
                Verdict::FalseHit
            } else {
                // Its own hit was ruled out but another might exist: still
                // the wrong triangle if that one is real, a false hit if not.
                Verdict::Undecidable
            };
        };
        if t < mine.t_lo - mine.t_slack || t > mine.t_hi + mine.t_slack {
            return Verdict::TError;
        }
        // Another hit surely nearer?
        if self.hits.iter().any(|h| h.sure && h.t_hi < mine.t_lo) {
            return if clearly_nearer(mine.t_lo - mine.t_slack) {
                Verdict::WrongTriangle
            } else {
                // Only hits at the same t, or at an edge, are nearer.
                Verdict::EdgeTie
            };
        }
        let nearer_possible = self
            .hits
            .iter()
            .any(|h| !h.sure && h.tri != mine.tri && h.t_hi < mine.t_lo);
        if mine.sure && !nearer_possible {
            Verdict::Right
        } else {
            Verdict::Undecidable
        }
    }

    /// Judges an any-hit answer.
    pub fn judge_occluded(&self, got: bool) -> Verdict {
        match (self.occluder(), got) {
            (Occluder::Surely, true) | (Occluder::SurelyNot, false) => Verdict::Right,
            (Occluder::Surely, false) if self.miss_is_edge_tie() => Verdict::EdgeTie,
            (Occluder::Surely, false) => Verdict::FalseMiss,
            (Occluder::SurelyNot, true) if !self.grazes.is_empty() => Verdict::EdgeTie,
            (Occluder::SurelyNot, true) => Verdict::FalseHit,
            (Occluder::Possibly, _) => Verdict::Undecidable,
        }
    }
}

fn coord(v: DVec3) -> Coord3D<f64> {
    Coord3D {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// `a - b` in f64 and whether it is exact (Knuth's Two-Sum error is 0).
fn exact_diff(a: f64, b: f64) -> (f64, bool) {
    let s = a - b;
    let bv = s - a;
    let av = s - bv;
    let err = (a - av) + (-b - bv);
    (s, err == 0.0)
}

/// det[a, b, c] (rows) in f64 and its permanent (the sum of its terms'
/// magnitudes, which bounds its rounding).
fn det3(a: DVec3, b: DVec3, c: DVec3) -> (f64, f64) {
    let det = a.dot(b.cross(c));
    let (a, b, c) = (a.abs(), b.abs(), c.abs());
    let perm = a.x * (b.y * c.z + b.z * c.y)
        + a.y * (b.x * c.z + b.z * c.x)
        + a.z * (b.x * c.y + b.y * c.x);
    (det, perm)
}

/// A sign known for certain, or not.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Sign {
    Neg,
    Zero,
    Pos,
    Unknown,
}

fn sign_of(x: f64) -> Sign {
    if x > 0.0 {
        Sign::Pos
    } else if x < 0.0 {
        Sign::Neg
    } else {
        Sign::Zero
    }
}

/// The sign of an f64 value with error at most `bound` (never Zero: an
/// approximate zero is Unknown).
fn sign_within(x: f64, bound: f64) -> Sign {
    if x > bound {
        Sign::Pos
    } else if x < -bound {
        Sign::Neg
    } else {
        Sign::Unknown
    }
}

/// The exact test of one triangle against one ray: a hit within the range
/// (sure or possible), a graze (missed within rounding of its boundary), or
/// `None` (surely missed, by more than rounding).
pub fn exact_test(tri: &[Vec3; 3], ray: &Ray) -> Option<Contact> {
    let o = ray.origin.as_dvec3();
    let d = ray.dir.as_dvec3();
    let v = tri.map(|p| p.as_dvec3());
    let mut exact = true;
    let u = v.map(|p| {
        let (x, ex) = exact_diff(p.x, o.x);
        let (y, ey) = exact_diff(p.y, o.y);
        let (z, ez) = exact_diff(p.z, o.z);
        exact &= ex && ey && ez;
        DVec3::new(x, y, z)
    });
    // Edge functions: their signs, and their f64 values for t.
    let mut signs = [Sign::Unknown; 3];
    let mut values = [0.0; 3];
    let mut edge_sum = 0.0;
    let mut edge_error = 0.0;
    for i in 0..3 {
        let (a, b) = (u[i], u[(i + 1) % 3]);
        let (e, perm) = det3(a, b, d);
        values[i] = e;
        edge_sum += e;
        edge_error += DET_ERROR * perm;
        signs[i] = if exact {
            // orient3d(a, b, c, p) is det[a - p; b - p; c - p], exactly.
            sign_of(orient3d(coord(a), coord(b), coord(d), coord(DVec3::ZERO)))
        } else {
            sign_within(e, DET_ERROR * perm)
        };
    }
    edge_error += 3.0 * f64::EPSILON * edge_sum.abs();
    // Distances across the ray from the line to each edge (signed like the
    // edge function): e_i / |(v_i+1 - v_i) x d|.
    let across = |i: usize| {
        let len = (u[(i + 1) % 3] - u[i]).cross(d).length();
        if len > 0.0 {
            values[i] / len
        } else {
            0.0
        }
    };
    let scale = v
        .iter()
        .fold(o.abs().max_element(), |m, p| m.max(p.abs().max_element()));
    let near = EDGE_ULPS * f32::EPSILON as f64 * scale;
    // An f32 test's t is good to a few ulps of the inputs' magnitude across
    // the plane, which along a ray at an angle to it is 1 / cos longer; and
    // a sliver's plane turns under rounding of its vertices by its aspect
    // ratio (longest edge over height): about 1 for a well-shaped one.
    // Worked out only for a hit or a graze, never for a plain miss.
    let t_slack = |t: f64| {
        let normal = (u[1] - u[0]).cross(u[2] - u[0]);
        let cos = normal.dot(d).abs() / (normal.length() * d.length());
        let longest = (0..3)
            .map(|i| (u[(i + 1) % 3] - u[i]).length_squared())
            .fold(0.0, f64::max);
        let aspect = (longest / normal.length()).max(1.0);
        T_TOLERANCE * aspect * scale.max(t.abs() * d.length()) / (d.length() * cos.max(1e-9))
    };
    let side = edge_sum.signum();
    let has = |s: Sign| signs.contains(&s);
    if has(Sign::Pos) && has(Sign::Neg) {
        // Surely outside an edge: a graze when no edge is further than `near`
        // on the wrong side (the side of the edge functions' sum).
        if edge_sum == 0.0 || !(0..3).all(|i| side * across(i) >= -near) {
            return None;
        }
        let t = det3(u[0], u[1], u[2]).0 / edge_sum;
        return (t > ray.tmin as f64 && t < ray.tmax as f64).then_some(Contact::Graze {
            t,
            t_slack: t_slack(t),
        });
    }
    if signs.iter().all(|&s| s == Sign::Zero) {
        return None; // the ray lies in the triangle's plane (or it has no area)
    }
    let line_sure = !has(Sign::Unknown);
    // The side of the plane the origin is on: exact from the f32 inputs.
    // det[v0 - o; v1 - o; v2 - o] = det[u0; u1; u2], t's numerator.
    let plane = sign_of(orient3d(coord(v[0]), coord(v[1]), coord(v[2]), coord(o)));
    // t = det[u0, u1, u2] / sum(e_i): an interval.
    let (num, num_perm) = det3(u[0], u[1], u[2]);
    let num_error = DET_ERROR * num_perm;
    let direction = if has(Sign::Pos) {
        Sign::Pos
    } else if has(Sign::Neg) {
        Sign::Neg
    } else {
        sign_within(edge_sum, edge_error)
    };
    // Ahead of the origin: the plane side agrees with the direction.
    let ahead = match (plane, direction) {
        (Sign::Zero, _) => return None, // t = 0: never in (tmin, tmax)
        (_, Sign::Unknown) => Sign::Unknown,
        (p, dir) if p == dir => Sign::Pos,
        _ => return None, // behind the origin
    };
    let (t_lo, t_hi) = if edge_sum.abs() > edge_error {
        let (n, e) = (num.abs(), edge_sum.abs());
        let lo = ((n - num_error).max(0.0) / (e + edge_error)) * (1.0 - 2.0 * f64::EPSILON);
        let hi = ((n + num_error) / (e - edge_error)) * (1.0 + 2.0 * f64::EPSILON);
        (lo, hi)
    } else {
        (0.0, f64::INFINITY)
    };
    let (tmin, tmax) = (ray.tmin as f64, ray.tmax as f64);
    if t_hi <= tmin || t_lo >= tmax {
        return None;
    }
    let in_range = (t_lo > tmin || (tmin == 0.0 && ahead == Sign::Pos)) && t_hi < tmax;
    Some(Contact::Hit {
        t_lo,
        t_hi,
        sure: line_sure && ahead == Sign::Pos && in_range,
        t_slack: t_slack(if t_hi.is_finite() { t_hi } else { t_lo }),
        on_edge: has(Sign::Zero),
        near_edges: (0..3).fold(0, |m, i| m | (((side * across(i) <= near) as u8) << i)),
    })
}

/// The exact reference over a scene's triangles.
pub struct ExactReference {
    triangles: Vec<[Vec3; 3]>,
    nodes: Vec<Node>,
    order: Vec<u32>,
    pad: f64,
}

struct Node {
    lo: DVec3,
    hi: DVec3,
    /// Leaf: `count > 0`, triangles `order[first..first + count]`;
    /// interior: children `first` and `first + 1`.
    first: u32,
    count: u32,
}

const LEAF_SIZE: usize = 4;

impl ExactReference {
    pub fn new(triangles: Vec<[Vec3; 3]>) -> Self {
        let boxes: Vec<(DVec3, DVec3)> = triangles
            .iter()
            .map(|t| {
                let v = t.map(|p| p.as_dvec3());
                (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
            })
            .collect();
        let (lo, hi) = boxes.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), b| (lo.min(b.0), hi.max(b.1)),
        );
        let extent = if boxes.is_empty() {
            0.0
        } else {
            (hi - lo).length().max(lo.abs().max(hi.abs()).max_element())
        };
        let mut order: Vec<u32> = (0..triangles.len() as u32).collect();
        let mut nodes = Vec::new();
        if !triangles.is_empty() {
            nodes.push(Node {
                lo: DVec3::ZERO,
                hi: DVec3::ZERO,
                first: 0,
                count: 0,
            });
            build(&boxes, &mut order, 0, 0, &mut nodes);
        }
        ExactReference {
            triangles,
            nodes,
            order,
            // Above f64 rounding of the slab test and above the reach of
            // a graze (EDGE_ULPS f32 ulps of the largest coordinate).
            pad: extent * (4.0 * EDGE_ULPS * f32::EPSILON as f64) + 1e-30,
        }
    }

    /// The exact answer to each of `rays`, in parallel.
    pub fn answers(&self, rays: &[Ray]) -> Vec<ExactAnswer> {
        use rayon::prelude::*;
        rays.par_iter().map(|r| self.answer(r)).collect()
    }

    /// Every triangle `ray` surely or possibly hits within its range.
    pub fn answer(&self, ray: &Ray) -> ExactAnswer {
        let mut out = ExactAnswer::default();
        if !ray.is_valid() || self.nodes.is_empty() {
            return out;
        }
        let o = ray.origin.as_dvec3();
        let inv = DVec3::ONE / ray.dir.as_dvec3();
        let (tmin, tmax) = (ray.tmin as f64, ray.tmax as f64);
        let mut edges_near = Vec::new();
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            let (lo, hi) = (node.lo - self.pad, node.hi + self.pad);
            let a = (lo - o) * inv;
            let b = (hi - o) * inv;
            let near = a.min(b).max_element().max(tmin * (1.0 - 1e-9) - self.pad);
            let far = a.max(b).min_element().min(tmax * (1.0 + 1e-9) + self.pad);
            // NaN (a zero direction component on the slab's plane) keeps
            // the node: only a clear miss culls.
            if near > far {
                continue;
            }
            if node.count > 0 {
                let range = node.first as usize..(node.first + node.count) as usize;
                for &tri in &self.order[range] {
                    match exact_test(&self.triangles[tri as usize], ray) {
                        Some(Contact::Hit {
                            t_lo,
                            t_hi,
                            sure,
                            t_slack,
                            on_edge,
                            near_edges,
                        }) => {
                            let near_edge = near_edges != 0;
                            out.hits.push(ExactHit {
                                tri,
                                t_lo,
                                t_hi,
                                sure,
                                near_edge,
                                t_slack,
                                // Settled below, once the grazes are known.
                                tie_if_missed: near_edge && !on_edge,
                            });
                            edges_near.push(near_edges);
                        }
                        Some(Contact::Graze { t, t_slack }) => {
                            out.grazes.push(Graze { tri, t, t_slack })
                        }
                        None => {}
                    }
                }
            } else {
                stack.push(node.first);
                stack.push(node.first + 1);
            }
        }
        // A fold: two hits near an edge, not exactly on it, at one t (the
        // ray clips the surface's silhouette, in and out at once).
        let folds: Vec<bool> = out
            .hits
            .iter()
            .map(|h| {
                h.sure
                    && h.tie_if_missed
                    && out.hits.iter().any(|o| {
                        o.tri != h.tri
                            && o.sure
                            && o.tie_if_missed
                            && o.t_lo <= h.t_hi + h.t_slack
                            && o.t_hi >= h.t_lo - h.t_slack
                    })
            })
            .collect();
        // Elsewhere a near edge is covered when a grazed triangle shares it
        // (both vertices bit-identical): the surface continues across it.
        // Near a vertex (two near edges meet there) the surface must also
        // close around it: every edge at the vertex, among the triangles
        // the ray hits or grazes (all that hold the vertex), used twice.
        // A vertex on a boundary, or at a crack between parts that do not
        // share it, leaves the ray room to pass: a tie.
        let near_tris: Vec<u32> = out
            .hits
            .iter()
            .map(|h| h.tri)
            .chain(out.grazes.iter().map(|g| g.tri))
            .collect();
        let fan_closed = |v: Vec3| {
            let key = |p: Vec3| p.to_array().map(|x| (x + 0.0).to_bits());
            let mut uses: Vec<([u32; 3], u32)> = Vec::new();
            for &t in &near_tris {
                let tri = &self.triangles[t as usize];
                if !tri.contains(&v) {
                    continue;
                }
                for w in tri.iter().filter(|&&w| w != v) {
                    match uses.iter_mut().find(|(k, _)| *k == key(*w)) {
                        Some((_, n)) => *n += 1,
                        None => uses.push((key(*w), 1)),
                    }
                }
            }
            uses.iter().all(|&(_, n)| n == 2)
        };
        for ((h, near), fold) in out.hits.iter_mut().zip(edges_near).zip(folds) {
            if !h.tie_if_missed || fold {
                continue;
            }
            let tri = &self.triangles[h.tri as usize];
            let covered = |i: usize| {
                let (a, b) = (tri[i], tri[(i + 1) % 3]);
                out.grazes.iter().any(|g| {
                    let other = &self.triangles[g.tri as usize];
                    other.contains(&a) && other.contains(&b)
                })
            };
            let is_near = |i: usize| near & (1 << i) != 0;
            // Vertex k is where edges k - 1 and k meet.
            let open_vertex =
                (0..3).any(|k| is_near((k + 2) % 3) && is_near(k) && !fan_closed(tri[k]));
            h.tie_if_missed = open_vertex || (0..3).any(|i| is_near(i) && !covered(i));
        }
        out
    }
}

/// Median split on the longest axis of the centroids' bounds; fills node
/// `at` with `order[start..]`'s triangles.
fn build(
    boxes: &[(DVec3, DVec3)],
    order: &mut [u32],
    start: u32,
    at: usize,
    nodes: &mut Vec<Node>,
) {
    let (lo, hi) = order.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &t| (lo.min(boxes[t as usize].0), hi.max(boxes[t as usize].1)),
    );
    nodes[at].lo = lo;
    nodes[at].hi = hi;
    if order.len() <= LEAF_SIZE {
        nodes[at].first = start;
        nodes[at].count = order.len() as u32;
        return;
    }
    let centre = |t: u32| boxes[t as usize].0 + boxes[t as usize].1;
    let (clo, chi) = order.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &t| (lo.min(centre(t)), hi.max(centre(t))),
    );
    let axis = (chi - clo).max_position();
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]));
    let left = nodes.len();
    nodes[at].first = left as u32;
    nodes[at].count = 0;
    for _ in 0..2 {
        nodes.push(Node {
            lo: DVec3::ZERO,
            hi: DVec3::ZERO,
            first: 0,
            count: 0,
        });
    }
    let (l, r) = order.split_at_mut(mid);
    build(boxes, l, start, left, nodes);
    build(boxes, r, start + mid as u32, left + 1, nodes);
}

/// How a backend's answers on one ray set fared against the exact reference.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ExactReport {
    pub set: String,
    pub rays: usize,
    /// Closest-hit answers.
    pub right: usize,
    pub false_miss: usize,
    pub false_hit: usize,
    pub wrong_triangle: usize,
    pub t_error: usize,
    pub undecidable: usize,
    /// Answers that differ from the exact one only within rounding of an
    /// edge (not wrong).
    pub edge_tie: usize,
    /// Any-hit answers.
    pub occlusion_right: usize,
    pub occlusion_false_miss: usize,
    pub occlusion_false_hit: usize,
    pub occlusion_undecidable: usize,
    pub occlusion_edge_tie: usize,
    /// The first few wrong answers, to reproduce them.
    pub examples: Vec<WrongAnswer>,
}

impl ExactReport {
    /// Wrong closest-hit and any-hit answers together.
    pub fn wrong(&self) -> usize {
        self.closest_wrong() + self.occlusion_wrong()
    }

    /// Wrong closest-hit answers.
    pub fn closest_wrong(&self) -> usize {
        self.false_miss + self.false_hit + self.wrong_triangle + self.t_error
    }

    /// Wrong any-hit answers.
    pub fn occlusion_wrong(&self) -> usize {
        self.occlusion_false_miss + self.occlusion_false_hit
    }

    /// Undecidable closest-hit and any-hit answers together.
    pub fn undecidable_answers(&self) -> usize {
        self.undecidable + self.occlusion_undecidable
    }

    /// Edge ties among closest-hit and any-hit answers together.
    pub fn edge_tie_answers(&self) -> usize {
        self.edge_tie + self.occlusion_edge_tie
    }

    /// Wrong answers per million queries (two per ray: closest and any hit).
    pub fn wrong_per_million(&self) -> f64 {
        self.wrong() as f64 * 1e6 / (2 * self.rays).max(1) as f64
    }
}

/// One wrong answer: the ray, what the backend said and the exact hits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WrongAnswer {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub tmin: f32,
    pub tmax: f32,
    pub query: &'static str,
    pub verdict: String,
    /// (t, triangle) the backend returned (closest hit), or its occlusion.
    pub got: Option<(f32, u32)>,
    pub got_occluded: bool,
    /// (triangle, t_lo, t_hi, sure) of the exact hits, nearest first (at most 4).
    pub exact: Vec<(u32, f64, f64, bool)>,
    /// (triangle, t) of the triangles missed within rounding of an edge,
    /// nearest first (at most 4).
    pub grazes: Vec<(u32, f64)>,
}

/// Judges `backend`'s closest and any-hit answers on `rays` (asked in
/// streams, so its `--query` path is what is judged).
pub fn judge(
    name: &str,
    rays: &[Ray],
    backend: &dyn crate::accel::Backend,
    reference: &ExactReference,
) -> ExactReport {
    judge_answers(name, rays, &reference.answers(rays), backend)
}

/// [`judge`] with the exact answers worked out already (`answers[i]` is
/// `rays[i]`'s), for judging several backends on the same rays.
pub fn judge_answers(
    name: &str,
    rays: &[Ray],
    answers: &[ExactAnswer],
    backend: &dyn crate::accel::Backend,
) -> ExactReport {
    use rayon::prelude::*;
    assert_eq!(rays.len(), answers.len(), "one exact answer per ray");
    let per_ray: Vec<(Verdict, Verdict, Option<Hit>, bool)> = rays
        .par_chunks(256)
        .zip(answers.par_chunks(256))
        .flat_map_iter(|(chunk, exact)| {
            let mut hits = vec![None; chunk.len()];
            let mut occluded = vec![false; chunk.len()];
            backend.intersect_stream(chunk, &mut hits);
            backend.occluded_stream(chunk, &mut occluded);
            exact
                .iter()
                .zip(hits.into_iter().zip(occluded))
                .map(|(exact, (hit, occ))| {
                    (
                        exact.judge_closest(hit),
                        exact.judge_occluded(occ),
                        hit,
                        occ,
                    )
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let mut r = ExactReport {
        set: name.to_string(),
        rays: rays.len(),
        ..ExactReport::default()
    };
    for ((ray, answer), &(closest, any, hit, occ)) in rays.iter().zip(answers).zip(&per_ray) {
        match closest {
            Verdict::Right => r.right += 1,
            Verdict::FalseMiss => r.false_miss += 1,
            Verdict::FalseHit => r.false_hit += 1,
            Verdict::WrongTriangle => r.wrong_triangle += 1,
            Verdict::TError => r.t_error += 1,
            Verdict::Undecidable => r.undecidable += 1,
            Verdict::EdgeTie => r.edge_tie += 1,
        }
        match any {
            Verdict::Right => r.occlusion_right += 1,
            Verdict::FalseMiss => r.occlusion_false_miss += 1,
            Verdict::FalseHit => r.occlusion_false_hit += 1,
            Verdict::EdgeTie => r.occlusion_edge_tie += 1,
            _ => r.occlusion_undecidable += 1,
        }
        let wrong = [("closest", closest), ("any", any)]
            .into_iter()
            .find(|(_, v)| v.is_wrong());
        if let (Some((query, verdict)), true) =
            (wrong, r.examples.len() < crate::measure::validate::EXAMPLES)
        {
            let mut exact = answer.hits.clone();
            exact.sort_by(|a, b| a.t_lo.total_cmp(&b.t_lo));
            r.examples.push(WrongAnswer {
                origin: ray.origin.to_array(),
                dir: ray.dir.to_array(),
                tmin: ray.tmin,
                tmax: ray.tmax,
                query,
                verdict: format!("{verdict:?}"),
                got: hit.map(|h| (h.t, h.tri)),
                got_occluded: occ,
                exact: exact
                    .iter()
                    .take(4)
                    .map(|h| (h.tri, h.t_lo, h.t_hi, h.sure))
                    .collect(),
                grazes: {
                    let mut g: Vec<(u32, f64)> =
                        answer.grazes.iter().map(|g| (g.tri, g.t)).collect();
                    g.sort_by(|a, b| a.1.total_cmp(&b.1));
                    g.truncate(4);
                    g
                },
            });
        }
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(o: [f32; 3], d: [f32; 3]) -> Ray {
        Ray::new(Vec3::from_array(o), Vec3::from_array(d))
    }

    const TRI: [Vec3; 3] = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];

    /// The hit's (t_lo, t_hi, sure), or None for a miss or a graze.
    fn hit_of(tri: &[Vec3; 3], r: &Ray) -> Option<(f64, f64, bool)> {
        match exact_test(tri, r)? {
            Contact::Hit {
                t_lo, t_hi, sure, ..
            } => Some((t_lo, t_hi, sure)),
            Contact::Graze { .. } => None,
        }
    }

    #[test]
    fn inside_hits_surely_at_the_right_t_from_either_side() {
        for (o, d) in [
            ([0.25, 0.25, 2.0], [0.0, 0.0, -1.0]),
            ([0.25, 0.25, -2.0], [0.0, 0.0, 0.5]),
        ] {
            let (lo, hi, sure) = hit_of(&TRI, &ray(o, d)).unwrap();
            let want = if d[2] < 0.0 { 2.0 } else { 4.0 };
            assert!(
                sure && lo <= want && want <= hi && hi - lo < 1e-12,
                "{lo} {hi}"
            );
        }
    }

    #[test]
    fn outside_behind_and_beyond_tmax_miss_surely() {
        assert!(exact_test(&TRI, &ray([0.75, 0.75, 2.0], [0.0, 0.0, -1.0])).is_none());
        assert!(exact_test(&TRI, &ray([0.25, 0.25, 2.0], [0.0, 0.0, 1.0])).is_none());
        let short = Ray::segment(Vec3::new(0.25, 0.25, 2.0), Vec3::NEG_Z, 0.0, 1.5);
        assert!(exact_test(&TRI, &short).is_none());
        // In the plane: no hit.
        assert!(exact_test(&TRI, &ray([-1.0, 0.25, 0.0], [1.0, 0.0, 0.0])).is_none());
    }

    #[test]
    fn a_ray_through_a_shared_edge_hits_both_triangles_surely() {
        // Two triangles sharing the diagonal x + y = 1; the ray passes
        // exactly through it.
        let other = [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let r = ray([0.5, 0.5, 3.0], [0.0, 0.0, -1.0]);
        assert!(hit_of(&TRI, &r).unwrap().2);
        assert!(hit_of(&other, &r).unwrap().2);
        let reference = ExactReference::new(vec![TRI, other]);
        let answer = reference.answer(&r);
        assert_eq!(answer.hits.iter().filter(|h| h.sure).count(), 2);
        for tri in [0, 1] {
            let hit = Hit {
                t: 3.0,
                u: 0.5,
                v: 0.5,
                tri,
                inst: 0,
            };
            assert_eq!(answer.judge_closest(Some(hit)), Verdict::Right);
        }
        assert_eq!(answer.judge_closest(None), Verdict::FalseMiss);
        assert_eq!(answer.judge_occluded(false), Verdict::FalseMiss);
        assert_eq!(answer.judge_occluded(true), Verdict::Right);
    }

    /// The square of TRI and its neighbour across the diagonal x + y = 1.
    const OTHER: [Vec3; 3] = [
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];

    fn at(tri: u32, t: f32) -> Option<Hit> {
        Some(Hit {
            t,
            u: 0.0,
            v: 0.0,
            tri,
            inst: 0,
        })
    }

    #[test]
    fn the_neighbour_within_rounding_of_a_shared_edge_is_a_tie_and_a_miss_a_leak() {
        // One ulp inside TRI, just off the shared diagonal.
        let x = 0.5f32;
        let y = f32::from_bits(0.5f32.to_bits() - 1);
        let r = ray([x, y, 3.0], [0.0, 0.0, -1.0]);
        let reference = ExactReference::new(vec![TRI, OTHER]);
        let a = reference.answer(&r);
        assert_eq!(a.hits.len(), 1);
        assert!(a.hits[0].near_edge && a.hits[0].tri == 0);
        assert_eq!(a.grazes.len(), 1);
        assert_eq!(a.judge_closest(at(0, 3.0)), Verdict::Right);
        assert_eq!(a.judge_closest(at(1, 3.0)), Verdict::EdgeTie);
        assert_eq!(a.judge_closest(at(1, 3.5)), Verdict::TError);
        // The edge is shared: missing both triangles is a leak.
        assert_eq!(a.judge_closest(None), Verdict::FalseMiss);
        assert_eq!(a.judge_occluded(false), Verdict::FalseMiss);
    }

    #[test]
    fn an_open_edge_within_rounding_is_a_tie_either_way_and_far_from_it_is_not() {
        let reference = ExactReference::new(vec![TRI]);
        let just_in = f32::from_bits(0.5f32.to_bits() - 1);
        let just_out = f32::from_bits(0.5f32.to_bits() + 1);
        // Inside by an ulp: a miss is a tie (no neighbour shares the edge).
        let r = ray([0.5, just_in, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert_eq!(a.judge_closest(None), Verdict::EdgeTie);
        assert_eq!(a.judge_occluded(false), Verdict::EdgeTie);
        // Outside by an ulp: a hit is a tie.
        let r = ray([0.5, just_out, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert!(a.hits.is_empty() && a.grazes.len() == 1);
        assert_eq!(a.judge_closest(at(0, 3.0)), Verdict::EdgeTie);
        assert_eq!(a.judge_occluded(true), Verdict::EdgeTie);
        // Outside by 1e-3: a hit is false; deep inside a miss is false.
        let r = ray([0.5, 0.501, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert!(a.grazes.is_empty());
        assert_eq!(a.judge_closest(at(0, 3.0)), Verdict::FalseHit);
        assert_eq!(a.judge_occluded(true), Verdict::FalseHit);
        let r = ray([0.25, 0.25, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert_eq!(a.judge_closest(None), Verdict::FalseMiss);
    }

    #[test]
    fn near_a_vertex_a_miss_leaks_inside_a_closed_fan_and_ties_on_an_open_one() {
        let v = Vec3::ZERO;
        let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        let (a, b, c, d) = (p(1.0, 0.0), p(0.0, 1.0), p(-1.0, 0.0), p(0.0, -1.0));
        // Within rounding of the vertex, inside the second quadrant's
        // triangle, whose two edges there are both shared.
        let r = ray([-2e-8, 5e-8, 3.0], [0.0, 0.0, -1.0]);
        let closed = ExactReference::new(vec![[v, a, b], [v, b, c], [v, c, d], [v, d, a]]);
        let answer = closed.answer(&r);
        assert_eq!(answer.hits.len(), 1);
        assert_eq!(answer.hits[0].tri, 1);
        assert_eq!(answer.judge_closest(None), Verdict::FalseMiss);
        // Three quarters of the fan: the vertex is on the surface's boundary.
        let open = ExactReference::new(vec![[v, a, b], [v, b, c], [v, c, d]]);
        let answer = open.answer(&r);
        assert_eq!(answer.hits[0].tri, 1);
        assert_eq!(answer.judge_closest(None), Verdict::EdgeTie);
    }

    #[test]
    fn a_hit_behind_one_at_an_edge_is_a_tie_and_behind_a_clear_one_is_wrong() {
        // TRI at z = 0, and a big triangle behind it at z = -1.
        let far = [
            Vec3::new(-5.0, -5.0, -1.0),
            Vec3::new(5.0, -5.0, -1.0),
            Vec3::new(0.0, 5.0, -1.0),
        ];
        let reference = ExactReference::new(vec![TRI, far]);
        let just_in = f32::from_bits(0.5f32.to_bits() - 1);
        let r = ray([0.5, just_in, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert_eq!(a.judge_closest(at(1, 4.0)), Verdict::EdgeTie);
        let r = ray([0.25, 0.25, 3.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        assert_eq!(a.judge_closest(at(1, 4.0)), Verdict::WrongTriangle);
    }

    #[test]
    fn wrong_answers_are_named() {
        let far = [
            Vec3::new(-5.0, -5.0, -1.0),
            Vec3::new(5.0, -5.0, -1.0),
            Vec3::new(0.0, 5.0, -1.0),
        ];
        let reference = ExactReference::new(vec![TRI, far]);
        let r = ray([0.25, 0.25, 2.0], [0.0, 0.0, -1.0]);
        let a = reference.answer(&r);
        let hit = |tri, t| {
            Some(Hit {
                t,
                u: 0.0,
                v: 0.0,
                tri,
                inst: 0,
            })
        };
        assert_eq!(a.judge_closest(hit(0, 2.0)), Verdict::Right);
        assert_eq!(a.judge_closest(hit(1, 3.0)), Verdict::WrongTriangle);
        assert_eq!(a.judge_closest(hit(0, 2.1)), Verdict::TError);
        let miss = reference.answer(&ray([9.0, 9.0, 2.0], [0.0, 0.0, -1.0]));
        assert_eq!(miss.judge_closest(hit(0, 2.0)), Verdict::FalseHit);
        assert_eq!(miss.judge_occluded(true), Verdict::FalseHit);
        assert_eq!(miss.judge_closest(None), Verdict::Right);
    }

    #[test]
    fn the_tree_finds_what_the_brute_force_finds() {
        let mut rng = crate::rng::Rng::for_pixel(1, 2, 3);
        let mut r = || rng.next_f32() * 2.0 - 1.0;
        let tris: Vec<[Vec3; 3]> = (0..500)
            .map(|_| {
                let c = Vec3::new(r(), r(), r()) * 4.0;
                [
                    c,
                    c + Vec3::new(r(), r(), r()) * 0.3,
                    c + Vec3::new(r(), r(), r()) * 0.3,
                ]
            })
            .collect();
        let reference = ExactReference::new(tris.clone());
        for _ in 0..500 {
            let ray = Ray::new(Vec3::new(r(), r(), r()) * 5.0, Vec3::new(r(), r(), r()));
            let answer = reference.answer(&ray);
            let mut got: Vec<u32> = answer
                .hits
                .iter()
                .map(|h| h.tri)
                .chain(answer.grazes.iter().map(|g| g.tri))
                .collect();
            got.sort_unstable();
            let want: Vec<u32> = (0..tris.len() as u32)
                .filter(|&i| exact_test(&tris[i as usize], &ray).is_some())
                .collect();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn the_sign_conventions_agree_with_plain_arithmetic() {
        // On a generic configuration f64 is far from any zero: the exact
        // path must say what plain arithmetic says.
        let tri = [
            Vec3::new(0.3, -0.2, 1.1),
            Vec3::new(1.7, 0.4, 0.9),
            Vec3::new(0.1, 1.3, 1.4),
        ];
        let r = ray([0.5, 0.4, -2.0], [0.05, 0.02, 1.0]);
        let (lo, hi, sure) = hit_of(&tri, &r).unwrap();
        let naive = raylab_mt(&tri, &r).unwrap() as f64;
        assert!(sure && (lo - naive).abs() < 1e-5 && (hi - naive).abs() < 1e-5);
    }

    fn raylab_mt(tri: &[Vec3; 3], ray: &Ray) -> Option<f32> {
        let n = crate::accel::naive::Naive::from_triangles(vec![*tri]);
        use crate::accel::Backend;
        n.intersect(ray).map(|h| h.t)
    }
}
