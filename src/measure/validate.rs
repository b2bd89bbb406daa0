//! Comparing the hits of two backends (`raylab validate`): the same ray sets go
//! through both, and every answer is classified as the same hit, a tie (both hit
//! adjacent triangles at the same distance, as on a shared edge or vertex), or a
//! genuine disagreement (one misses, or one reports a farther hit, or their
//! occlusion answers differ).
//!
//! Ray sets: the primary rays of a render (raster order), its shadow rays and
//! its AO rays (recorded through the shared shading loop), diffuse bounce rays
//! (one cosine-weighted ray per primary hit, unbounded: incoherent work), and
//! random rays in and around the scene.

use std::sync::Mutex;

use glam::Vec3;
use serde::Serialize;

use crate::accel::Backend;
use crate::geometry::{strictly_in_front, Aabb, Hit, Ray};
use crate::progress::Progress;
use crate::render::shade::Spawn;
use crate::render::{render, RenderSettings, Schedule, Tracer};
use crate::scene::Scene;

/// Relative tolerance on `t` for two hits to count as the same distance,
/// relative to the distance scale of the query (see [`t_scale`]).
pub const T_TOLERANCE: f32 = 1e-5;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Agreement {
    /// Both miss, or both hit the same triangle at the same `t` (within tolerance).
    Same,
    /// Decided by rounding, not geometry: both hit different triangles at the
    /// same `t` (within tolerance) on a shared vertex or edge or where they
    /// overlap in one plane; or only one hits, or hits nearer, exactly on its
    /// triangle's edge (the other passed through the edge); or one reports a
    /// hit at the ray's very start (a self-intersection).
    Tie,
    /// One misses, or the hits are at different distances or on unrelated triangles.
    Genuine,
}

/// The magnitude against which a difference in `t` is judged: the larger of the
/// two distances and the ray origin's largest coordinate (in units of the
/// direction's length). A ray that starts on a surface has a tiny `t`, but its
/// rounding error follows the coordinates, not `t`.
pub fn t_scale(ray: &Ray, a: f32, b: f32) -> f32 {
    let origin = ray.origin.abs().max_element() / ray.dir.length().max(f32::MIN_POSITIVE);
    a.abs().max(b.abs()).max(origin).max(f32::MIN_POSITIVE)
}

/// Cosines below this count as this (a ray within the plane has no t error
/// bound at all; a floor keeps the bound finite).
const MIN_GRAZING_COS: f32 = 1e-4;

/// The most a triangle's shape multiplies the `t` error by ([`same_t_on`]).
const MAX_SLIVER_FACTOR: f32 = 1e3;

/// Whether `a` and `b` are the same distance up to rounding, for hits on the
/// plane of `tri` (and of `other`, a second triangle hit at the other `t`,
/// if any): [`T_TOLERANCE`] of [`t_scale`] divided by the
/// cosine between the ray and the plane's normal (both tests' rounding moves
/// the plane by a few ulps, which moves the hit along a ray at angle theta
/// by that over cos(theta)), and multiplied by how badly the triangle's
/// shape conditions its plane, the longest edge squared over twice its area
/// (1/sin of its sharpest angle, up to [`MAX_SLIVER_FACTOR`]): Moller-Trumbore
/// and Embree take the plane from two edges, and a sliver's edges nearly
/// cancel. A convex 400-gon fanned from one vertex (triangles of 0.45
/// degrees there) gave its primary rays t 2e-5 apart from raylab and Embree
/// on neighbouring coplanar triangles: 328 "genuine" disagreements where
/// the exact reference found both right.
fn same_t_on(ray: &Ray, a: f32, b: f32, tri: &[Vec3; 3], other: Option<&[Vec3; 3]>) -> bool {
    let factor = |t: &[Vec3; 3]| {
        let n = crate::geometry::triangle_unit_normal(t);
        let cos = n
            .dot(ray.dir.normalize_or_zero())
            .abs()
            .max(MIN_GRAZING_COS);
        let longest = [t[1] - t[0], t[2] - t[1], t[0] - t[2]]
            .map(|e| e.length())
            .into_iter()
            .fold(0.0f32, f32::max);
        let area2 = crate::geometry::triangle_normal(t).length();
        let sliver = (longest * longest / area2).clamp(1.0, MAX_SLIVER_FACTOR);
        sliver / cos
    };
    let own = factor(tri);
    let f = other.map_or(own, |o| own.max(factor(o)));
    (a - b).abs() <= T_TOLERANCE * t_scale(ray, a, b) * f
}

/// Whether triangles `a` and `b` share at least one vertex position.
pub fn adjacent(a: &[Vec3; 3], b: &[Vec3; 3]) -> bool {
    a.iter().any(|p| b.contains(p))
}

/// Whether `p` lies on triangle `tri` up to a small tolerance (relative to the
/// triangle's size and the coordinates' magnitude): within the plane, and with
/// barycentric coordinates no more negative than the tolerance.
pub fn on_triangle(p: Vec3, tri: &[Vec3; 3]) -> bool {
    let (e1, e2) = (tri[1] - tri[0], tri[2] - tri[0]);
    let n = e1.cross(e2);
    let area2 = n.length();
    if !(area2 > 0.0) {
        return false;
    }
    let scale = e1.length().max(e2.length()).max(p.abs().max_element());
    let w = p - tri[0];
    if (n.dot(w) / area2).abs() > 1e-5 * scale {
        return false;
    }
    // Barycentrics from sub-triangle areas, signed along n.
    let b1 = w.cross(e2).dot(n) / (area2 * area2);
    let b2 = e1.cross(w).dot(n) / (area2 * area2);
    let slack = 1e-4;
    b1 >= -slack && b2 >= -slack && b1 + b2 <= 1.0 + slack
}

/// Classifies two answers to the same closest-hit query along `ray`;
/// `triangles` are the scene's triangles by index. Different triangles at the
/// same distance are a tie when they share a vertex, or when each hit point also
/// lies on the other triangle (shared edges, coplanar overlaps).
pub fn classify(ray: &Ray, a: Option<Hit>, b: Option<Hit>, triangles: &[[Vec3; 3]]) -> Agreement {
    // A hit at the ray's very start (t within tolerance of tmin) is a
    // self-intersection that rounding may or may not report: whatever the other
    // backend says, the two agree up to rounding.
    let at_start = |h: &Option<Hit>| {
        h.is_some_and(|h| (h.t - ray.tmin).abs() <= T_TOLERANCE * t_scale(ray, h.t, ray.tmin))
    };
    if (at_start(&a) || at_start(&b)) && a.map(|h| h.tri) != b.map(|h| h.tri) {
        return Agreement::Tie;
    }
    match (a, b) {
        (None, None) => Agreement::Same,
        // The same triangle at a t that differs by no more than rounding of its
        // plane, amplified by how nearly the ray runs along it (a shadow ray
        // grazing a wall at cos 0.003 gets t 3.5e-5 apart from MT and Embree).
        (Some(x), Some(y))
            if x.tri == y.tri && same_t_on(ray, x.t, y.t, &triangles[x.tri as usize], None) =>
        {
            Agreement::Same
        }
        (Some(x), Some(y))
            if same_t_on(
                ray,
                x.t,
                y.t,
                &triangles[x.tri as usize],
                Some(&triangles[y.tri as usize]),
            ) =>
        {
            let (ta, tb) = (&triangles[x.tri as usize], &triangles[y.tri as usize]);
            if x.tri == y.tri {
                Agreement::Same
            } else if adjacent(ta, tb)
                || (on_triangle(ray.at(x.t), tb) && on_triangle(ray.at(y.t), ta))
            {
                Agreement::Tie
            } else {
                Agreement::Genuine
            }
        }
        (Some(h), None) | (None, Some(h)) if on_edge(ray, &h, triangles) => Agreement::Tie,
        // A hit at the segment's end that the other test put just beyond it:
        // along a ray grazing the triangle's plane, the plane's few ulps of
        // rounding move the hit by that over the cosine (a shadow ray running
        // along a ceiling to its light: cosine 6e-5, Embree's t past tmax,
        // raylab's 2e-4 inside, and the exact reference with raylab).
        (Some(h), None) | (None, Some(h))
            if ray.tmax.is_finite()
                && same_t_on(ray, h.t, ray.tmax, &triangles[h.tri as usize], None) =>
        {
            Agreement::Tie
        }
        // One backend hits a triangle on its edge, the other passed through that
        // edge and hit something farther: the same edge rounding as a hit
        // against a miss (Moller-Trumbore leaks through shared edges; seen on a
        // primary ray through the sphere of CornellBox-Water).
        (Some(x), Some(y)) if on_edge(ray, if x.t <= y.t { &x } else { &y }, triangles) => {
            Agreement::Tie
        }
        _ => Agreement::Genuine,
    }
}

/// Whether a hit lies on its triangle's boundary (a barycentric coordinate
/// within 1e-5 of 0), where inclusive and exclusive edge rules disagree: by
/// the backend's barycentrics, unless the hit point itself (computed in f64
/// from the ray and the triangle) lies clearly inside, 1% of the way in from
/// every edge. Barycentrics that overflowed (Embree's on a scene 1e13
/// across come back 0) made every hit an "edge", so a backend missing
/// interior hits passed as ties; no rounding of a hit's `t` moves it 1% of
/// its triangle.
fn on_edge(ray: &Ray, h: &Hit, triangles: &[[Vec3; 3]]) -> bool {
    let by_backend = h.u.min(h.v).min(1.0 - h.u - h.v) <= 1e-5;
    by_backend
        && triangles
            .get(h.tri as usize)
            .is_none_or(|tri| !clearly_inside(ray, h.t, tri))
}

/// Whether the point at `t` along `ray` projects into `tri` at least 1% of
/// the way in from every edge, in f64 (false when that cannot be computed).
fn clearly_inside(ray: &Ray, t: f32, tri: &[Vec3; 3]) -> bool {
    let p = ray.origin.as_dvec3() + ray.dir.as_dvec3() * f64::from(t);
    let [a, b, c] = tri.map(|v| v.as_dvec3());
    let (e1, e2, w) = (b - a, c - a, p - a);
    let n = e1.cross(e2);
    let n2 = n.length_squared();
    if !(n2 > 0.0 && n2.is_finite() && p.is_finite()) {
        return false;
    }
    let b1 = w.cross(e2).dot(n) / n2;
    let b2 = e1.cross(w).dot(n) / n2;
    b1.min(b2).min(1.0 - b1 - b2) > 0.01
}

/// The kinds of ray set `validate` compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RaySet {
    Primary,
    Shadow,
    Ao,
    /// One cosine-weighted bounce ray per primary hit, unbounded (closest hit).
    Diffuse,
    Random,
    /// Rays aimed exactly at the scene's vertices and at points on its edges
    /// (the leak suite's rays, on any scene), closest hit.
    Edges,
}

impl RaySet {
    /// What `--rays all` means: a render's rays and random rays. Not the
    /// edge rays, which are asked for by name: there two different f32
    /// tests disagree by design (each leaks its own way), which only the
    /// exact reference can judge.
    pub const ALL: [RaySet; 5] = [
        RaySet::Primary,
        RaySet::Shadow,
        RaySet::Ao,
        RaySet::Diffuse,
        RaySet::Random,
    ];

    /// Whether the set's rays are recorded from a render (shadow and AO
    /// rays, and the diffuse bounces from its primary hits); the others are
    /// made without one.
    pub fn is_recorded(self) -> bool {
        matches!(self, RaySet::Shadow | RaySet::Ao | RaySet::Diffuse)
    }

    /// Whether the set asks for closest hits (else any hit).
    pub fn closest(self) -> bool {
        matches!(
            self,
            RaySet::Primary | RaySet::Diffuse | RaySet::Random | RaySet::Edges
        )
    }
}

/// Records the rays of a render, in the order the shading loop asks for
/// them (its streams: neighbouring rays adjacent), while tracing with `backend`.
struct Recorder<'a> {
    backend: &'a dyn Backend,
    primary: Mutex<(Vec<Ray>, Vec<Option<Hit>>)>,
    shadow: Mutex<Vec<Ray>>,
    ao: Mutex<Vec<Ray>>,
    spawns: Mutex<Vec<Spawn>>,
}

fn record(into: &Mutex<Vec<Ray>>, rays: &[Ray]) {
    if let Ok(mut v) = into.lock() {
        v.extend_from_slice(rays);
    }
}

impl Tracer for Recorder<'_> {
    fn primary(&self, ray: &Ray) -> Option<Hit> {
        let mut hit = [None];
        self.primary_stream(std::slice::from_ref(ray), &mut hit);
        hit[0]
    }
    fn shadow(&self, ray: &Ray) -> bool {
        record(&self.shadow, std::slice::from_ref(ray));
        self.backend.occluded(ray)
    }
    fn ao(&self, ray: &Ray) -> bool {
        record(&self.ao, std::slice::from_ref(ray));
        self.backend.occluded(ray)
    }
    fn primary_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        self.backend.intersect_stream(rays, hits);
        if let Ok(mut v) = self.primary.lock() {
            v.0.extend_from_slice(rays);
            v.1.extend_from_slice(hits);
        }
    }
    fn shadow_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        record(&self.shadow, rays);
        self.backend.occluded_stream(rays, occluded)
    }
    fn ao_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        record(&self.ao, rays);
        self.backend.occluded_stream(rays, occluded)
    }
    fn spawned(&self, spawns: &mut dyn Iterator<Item = Spawn>) {
        if let Ok(mut v) = self.spawns.lock() {
            v.extend(spawns);
        }
    }
}

/// The rays a serial render casts, in the order its streams ask them.
pub struct Recorded {
    pub primary: Vec<Ray>,
    /// The recording backend's answer to each primary ray.
    pub primary_hits: Vec<Option<Hit>>,
    pub shadow: Vec<Ray>,
    pub ao: Vec<Ray>,
    /// Where the render's secondary rays started, one per primary hit.
    pub spawns: Vec<Spawn>,
}

impl Recorded {
    /// One diffuse bounce per primary hit, in primary order: from the hit
    /// point (moved off the surface as the renderer moves secondary rays) in
    /// a cosine-weighted direction about the normal on the viewer's side,
    /// with unbounded `tmax`; deterministic for a `seed`.
    pub fn diffuse(&self, scene: &Scene, seed: u64) -> Vec<Ray> {
        self.primary
            .iter()
            .zip(&self.primary_hits)
            .enumerate()
            .filter_map(|(i, (ray, hit))| {
                let hit = (*hit)?;
                // The world triangle: an instanced scene's hit names its
                // mesh's triangle, which the instance moves.
                let mut n = crate::geometry::triangle_unit_normal(&scene.hit_triangle(&hit));
                if n.dot(ray.dir) > 0.0 {
                    n = -n;
                }
                let mut rng = crate::rng::Rng::for_pixel(i as u64, seed, STREAM_DIFFUSE);
                let (u1, u2) = (rng.next_f32(), rng.next_f32());
                let origin = crate::render::shade::secondary_origin(scene, &hit, n);
                Some(Ray::new(
                    origin,
                    crate::render::shade::cosine_direction(n, u1, u2),
                ))
            })
            .collect()
    }
}

/// The random stream of the diffuse bounce directions.
const STREAM_DIFFUSE: u64 = 0xD1FF;

/// The primary rays of `settings` in raster order.
pub fn primary_rays(settings: &RenderSettings) -> Vec<Ray> {
    (0..settings.height)
        .flat_map(|y| (0..settings.width).map(move |x| settings.camera.ray(x, y)))
        .collect()
}

/// The rays a serial render of `scene` with `backend` casts, in the order
/// they are cast.
pub fn recorded_rays(
    scene: &Scene,
    backend: &dyn Backend,
    settings: &RenderSettings,
) -> crate::Result<Recorded> {
    let recorder = Recorder {
        backend,
        primary: Mutex::new((Vec::new(), Vec::new())),
        shadow: Mutex::new(Vec::new()),
        ao: Mutex::new(Vec::new()),
        spawns: Mutex::new(Vec::new()),
    };
    render(
        scene,
        &recorder,
        settings,
        Schedule::Serial,
        1,
        &Progress::new(),
    )?;
    let take = |m: Mutex<Vec<Ray>>| m.into_inner().unwrap_or_default();
    let (primary, primary_hits) = recorder.primary.into_inner().unwrap_or_default();
    Ok(Recorded {
        primary,
        primary_hits,
        shadow: take(recorder.shadow),
        ao: take(recorder.ao),
        spawns: recorder.spawns.into_inner().unwrap_or_default(),
    })
}

/// How many of a render's secondary-ray origins lie behind (or on) the
/// surface they leave, judged exactly ([`strictly_in_front`]): each one
/// would start its shadow and AO rays inside the surface, a self-hit that no
/// check of the rays' answers can see (the exact reference judges a ray as
/// given).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SpawnReport {
    /// Primary hits whose secondary-ray origin was judged.
    pub surfaces: usize,
    /// Origins behind or on their own surface's plane.
    pub behind: usize,
    /// The first few, to reproduce them: (triangle, origin).
    pub examples: Vec<(u32, [f32; 3])>,
}

/// Judges every recorded secondary-ray origin against its own triangle.
pub fn judge_spawns(scene: &Scene, spawns: &[Spawn]) -> SpawnReport {
    use rayon::prelude::*;
    let bad: Vec<&Spawn> = spawns
        .par_iter()
        .filter(|s| !strictly_in_front(&scene.placed_triangle(s.tri, s.inst), s.origin, s.normal))
        .collect();
    SpawnReport {
        surfaces: spawns.len(),
        behind: bad.len(),
        examples: bad
            .iter()
            .take(EXAMPLES)
            .map(|s| (s.tri, s.origin.to_array()))
            .collect(),
    }
}

/// Ray sets, each with its rays.
pub type SetRays = Vec<(RaySet, Vec<Ray>)>;

/// The rays of each of `sets`, at most `count` per set (evenly subsampled), except
/// that primary rays are kept whole (one per pixel, in raster order) when
/// `whole_primary`. Shadow and AO rays are those a serial render with `recorder`
/// casts. With them, when a render was recorded for them, its secondary-ray
/// origins judged ([`judge_spawns`]).
pub fn ray_sets(
    scene: &Scene,
    recorder: &dyn Backend,
    settings: &RenderSettings,
    sets: &[RaySet],
    count: usize,
    whole_primary: bool,
) -> crate::Result<(SetRays, Option<SpawnReport>)> {
    let needs_recording = sets.iter().any(|s| s.is_recorded());
    let recorded = if needs_recording {
        Some(recorded_rays(scene, recorder, settings)?)
    } else {
        None
    };
    let (shadow, ao, diffuse) = match &recorded {
        Some(r) => (
            r.shadow.clone(),
            r.ao.clone(),
            r.diffuse(scene, settings.seed),
        ),
        None => (Vec::new(), Vec::new(), Vec::new()),
    };
    let spawns = recorded.as_ref().map(|r| judge_spawns(scene, &r.spawns));
    let sets = sets
        .iter()
        .map(|&set| {
            let rays = match set {
                RaySet::Primary if whole_primary => primary_rays(settings),
                RaySet::Primary => subsample(primary_rays(settings), count),
                RaySet::Shadow => subsample(shadow.clone(), count),
                RaySet::Ao => subsample(ao.clone(), count),
                RaySet::Diffuse => subsample(diffuse.clone(), count),
                RaySet::Random => random_rays(scene.bounds(), count, settings.seed),
                RaySet::Edges => edge_rays(&scene.triangle_vertices(), count, settings.seed),
            };
            (set, rays)
        })
        .collect();
    Ok((sets, spawns))
}

/// `n` rays with origins uniform in `bounds` grown by half its size on every
/// side and uniformly distributed directions; deterministic for a `seed`.
pub fn random_rays(bounds: Aabb, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = crate::rng::Rng::for_pixel(0, seed, 0xA11D);
    let margin = bounds.extent() * 0.5 + Vec3::splat(1e-3);
    let (lo, size) = (bounds.min - margin, bounds.extent() + 2.0 * margin);
    let mut rays = Vec::with_capacity(n);
    while rays.len() < n {
        let o = lo + size * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        if let Some(d) = ball_direction(&mut rng) {
            rays.push(Ray::new(o, d));
        }
    }
    rays
}

/// One draw of a uniformly distributed unit direction: a point in the cube
/// [-1, 1]^3, kept (normalised) when it lies in the unit ball and not at
/// its centre, else None (the caller draws again).
fn ball_direction(rng: &mut crate::rng::Rng) -> Option<Vec3> {
    let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - Vec3::ONE;
    let len = d.length();
    (len > 1e-3 && len <= 1.0).then(|| d / len)
}

/// `n` rays each aimed exactly at a vertex of a random triangle or at a
/// point on one of its edges (its midpoint or a random point), where
/// neighbouring triangles meet and a triangle test can leak: uniformly
/// distributed directions, origins at log-uniform distances from 1e-4 to 0.5
/// of the scene's size behind the target (so some start almost on the
/// surface). Deterministic for a `seed`; empty for a scene with no triangles.
pub fn edge_rays(triangles: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = crate::rng::Rng::for_pixel(0, seed, 0xED6E);
    if triangles.is_empty() {
        return Vec::new();
    }
    let points: Vec<Vec3> = triangles.iter().flatten().copied().collect();
    let size = Aabb::from_points(&points).extent().length().max(1e-6);
    let mut rays = Vec::with_capacity(n);
    while rays.len() < n {
        let pick = (rng.next_f32() * triangles.len() as f32) as usize;
        let tri = &triangles[pick.min(triangles.len() - 1)];
        let k = ((rng.next_f32() * 9.0) as usize).min(8);
        let target = match k {
            0..=2 => tri[k],
            3..=5 => (tri[k - 3] + tri[(k - 2) % 3]) * 0.5,
            _ => {
                let (a, b) = (tri[k - 6], tri[(k - 5) % 3]);
                a + (b - a) * rng.next_f32()
            }
        };
        let d = ball_direction(&mut rng);
        let distance = size * 10f32.powf(-4.0 + 3.7 * rng.next_f32());
        if let (Some(d), true) = (d, target.is_finite()) {
            rays.push(Ray::new(target - d * distance, d));
        }
    }
    rays
}

/// At most `n` rays of `rays`, evenly strided (all of them if there are fewer).
pub fn subsample(rays: Vec<Ray>, n: usize) -> Vec<Ray> {
    if rays.len() <= n || n == 0 {
        return rays;
    }
    let step = rays.len() as f64 / n as f64;
    (0..n).map(|i| rays[(i as f64 * step) as usize]).collect()
}

/// Agreement of two backends on one ray set.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SetReport {
    pub set: String,
    pub rays: usize,
    /// Both hit or both missed.
    pub hit_miss_agree: usize,
    /// Both hit the same triangle (t within tolerance).
    pub same_triangle: usize,
    pub both_hit: usize,
    pub ties: usize,
    pub genuine: usize,
    /// Rays whose occlusion answers differ (counted in `genuine` too).
    pub occlusion_mismatches: usize,
    /// Over rays where both hit: |t_a - t_b| relative to the query's distance
    /// scale (the larger t, or the origin's magnitude when larger).
    pub max_rel_dt: f64,
    pub mean_rel_dt: f64,
    /// The first few genuine disagreements, to reproduce them.
    pub examples: Vec<Disagreement>,
}

/// One genuine disagreement: the ray and both backends' answers.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Disagreement {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub tmin: f32,
    pub tmax: f32,
    /// (t, triangle) of the backend under test, and of the reference.
    pub tested: Option<(f32, u32)>,
    pub reference: Option<(f32, u32)>,
    pub tested_occluded: bool,
    pub reference_occluded: bool,
}

/// How many genuine disagreements a [`SetReport`] keeps as examples.
pub const EXAMPLES: usize = 5;

/// Sends every ray through both backends (closest hit and occlusion) and
/// classifies the answers; returns the report and the per-ray classification.
pub fn compare(
    name: &str,
    rays: &[Ray],
    a: &dyn Backend,
    b: &dyn Backend,
    triangles: &[[Vec3; 3]],
) -> (SetReport, Vec<Agreement>) {
    use rayon::prelude::*;
    // Asked as streams, so that a backend's packet or stream path is what is
    // validated (chunks of neighbouring rays, as the renderer asks).
    let answers = |backend: &dyn Backend| -> Vec<(Option<Hit>, bool)> {
        rays.par_chunks(256)
            .flat_map_iter(|chunk| {
                let mut hits = vec![None; chunk.len()];
                let mut occluded = vec![false; chunk.len()];
                backend.intersect_stream(chunk, &mut hits);
                backend.occluded_stream(chunk, &mut occluded);
                hits.into_iter().zip(occluded)
            })
            .collect()
    };
    let (answers_a, answers_b) = (answers(a), answers(b));
    let per_ray: Vec<(Agreement, Option<f64>, bool, bool)> = rays
        .par_iter()
        .zip(answers_a.par_iter().zip(&answers_b))
        .map(|(ray, (&(ha, oa), &(hb, ob)))| {
            let mut agreement = classify(ray, ha, hb, triangles);
            let occlusion_differs = oa != ob;
            // An occlusion answer that contradicts agreeing closest hits is genuine;
            // one that follows an edge tie is the same tie.
            if occlusion_differs && agreement == Agreement::Same {
                agreement = Agreement::Genuine;
            }
            let dt = match (ha, hb) {
                (Some(x), Some(y)) => Some(((x.t - y.t).abs() / t_scale(ray, x.t, y.t)) as f64),
                _ => None,
            };
            let same_tri = matches!((ha, hb), (Some(x), Some(y)) if x.tri == y.tri);
            (agreement, dt, occlusion_differs, same_tri)
        })
        .collect();
    let mut r = SetReport {
        set: name.to_string(),
        rays: rays.len(),
        ..SetReport::default()
    };
    let mut dt_sum = 0.0;
    let mut both_miss = 0;
    for (agreement, dt, occlusion_differs, same_tri) in &per_ray {
        match agreement {
            Agreement::Tie => r.ties += 1,
            Agreement::Genuine => r.genuine += 1,
            Agreement::Same => {}
        }
        r.occlusion_mismatches += *occlusion_differs as usize;
        r.same_triangle += *same_tri as usize;
        match dt {
            Some(dt) => {
                r.both_hit += 1;
                dt_sum += dt;
                r.max_rel_dt = r.max_rel_dt.max(*dt);
            }
            None => both_miss += (*agreement == Agreement::Same) as usize,
        }
    }
    r.examples = rays
        .iter()
        .zip(&per_ray)
        .filter(|(_, p)| p.0 == Agreement::Genuine)
        .take(EXAMPLES)
        .map(|(ray, _)| Disagreement {
            origin: ray.origin.to_array(),
            dir: ray.dir.to_array(),
            tmin: ray.tmin,
            tmax: ray.tmax,
            tested: a.intersect(ray).map(|h| (h.t, h.tri)),
            reference: b.intersect(ray).map(|h| (h.t, h.tri)),
            tested_occluded: a.occluded(ray),
            reference_occluded: b.occluded(ray),
        })
        .collect();
    r.hit_miss_agree = r.both_hit + both_miss;
    r.mean_rel_dt = if r.both_hit > 0 {
        dt_sum / r.both_hit as f64
    } else {
        0.0
    };
    (r, per_ray.into_iter().map(|p| p.0).collect())
}

/// An RGB8 picture of per-pixel agreement for primary rays in raster order:
/// black where both agree on a miss, grey where they agree on a hit, yellow for
/// ties, red for genuine disagreements.
pub fn mismatch_image(agreements: &[Agreement], hits: &[bool]) -> Vec<u8> {
    agreements
        .iter()
        .zip(hits)
        .flat_map(|(a, &hit)| match a {
            Agreement::Same if hit => [60, 60, 60],
            Agreement::Same => [0, 0, 0],
            Agreement::Tie => [255, 220, 0],
            Agreement::Genuine => [255, 0, 0],
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_instanced_scenes_bounces_and_origins_leave_the_world_triangle_on_the_viewers_side() {
        // One box placed turned a quarter about x and moved: its mesh-space
        // normals point elsewhere than its world ones.
        use glam::{Affine3A, Quat};
        let mesh = crate::scene::builtin::builtin("cornell-empty").unwrap();
        let turned = Affine3A::from_rotation_translation(
            Quat::from_rotation_x(std::f32::consts::FRAC_PI_2),
            Vec3::new(0.0, 1.0, -1.0),
        );
        let scene = Scene::instanced("turned", vec![mesh], vec![(0, turned)]).unwrap();
        let params = crate::accel::bvh::BuildParams::sah().with_width(8);
        let tree =
            crate::accel::build_scene_backend(&crate::accel::BackendSpec::bvh(params), &scene)
                .unwrap();
        let eye = Vec3::new(0.2, 1.3, 1.5);
        let settings = RenderSettings {
            width: 24,
            height: 18,
            camera: crate::camera::Camera::new(
                eye,
                Vec3::new(0.0, 1.0, -1.0),
                Vec3::Y,
                70.0,
                24,
                18,
            )
            .unwrap(),
            ao: crate::render::AoMode::Off,
            ao_dist: 0.2,
            light_samples: 1,
            seed: 1,
            two_sided_lights: false,
        };
        let recorded = recorded_rays(&scene, tree.as_ref(), &settings).unwrap();
        let bounces = recorded.diffuse(&scene, 1);
        let hits: Vec<(&Ray, Hit)> = recorded
            .primary
            .iter()
            .zip(&recorded.primary_hits)
            .filter_map(|(r, h)| Some((r, (*h)?)))
            .collect();
        assert_eq!(bounces.len(), hits.len());
        assert!(hits.len() > 200, "{} primary hits", hits.len());
        // Their origins, judged against the placed (world) triangles.
        let judged = judge_spawns(&scene, &recorded.spawns);
        assert_eq!(judged.surfaces, hits.len());
        assert_eq!(judged.behind, 0, "{:?}", judged.examples);
        for ((ray, hit), bounce) in hits.iter().zip(&bounces) {
            let n = crate::geometry::triangle_unit_normal(&scene.hit_triangle(hit));
            let facing = if n.dot(ray.dir) > 0.0 { -n } else { n };
            assert!(
                bounce.dir.dot(facing) > 0.0,
                "a bounce off triangle {} leaves into it: {bounce:?}",
                hit.tri
            );
        }
    }

    /// A hit in the middle of its triangle.
    fn hit(t: f32, tri: u32) -> Option<Hit> {
        Some(Hit {
            t,
            u: 0.3,
            v: 0.3,
            tri,
            inst: 0,
        })
    }

    #[test]
    fn same_triangle_t_tolerance_grows_as_the_ray_grazes_it() {
        // Triangle 0 lies in z = 0. Relative dt of 3.5e-5, as MT and Embree gave
        // for a shadow ray along a wall of CornellBox-Glossy at cos 0.0027.
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::X, Vec3::Y, Vec3::ONE],
        ];
        let (t, dt) = (0.5, 0.5 * 3.5e-5);
        let grazing = Ray::new(
            Vec3::new(-0.1, 0.2, -0.0014),
            Vec3::new(1.0, 0.0, 0.0027).normalize(),
        );
        assert_eq!(
            classify(&grazing, hit(t, 0), hit(t + dt, 0), &tris),
            Agreement::Same
        );
        // Head on, the same dt is beyond rounding.
        let head_on = Ray::new(Vec3::new(0.2, 0.2, -0.5), Vec3::Z);
        assert_eq!(
            classify(&head_on, hit(t, 0), hit(t + dt, 0), &tris),
            Agreement::Genuine
        );
        // Other triangles get no such slack.
        assert_eq!(
            classify(&grazing, hit(t, 0), hit(t + 0.1, 1), &tris),
            Agreement::Genuine
        );
    }

    #[test]
    fn t_tolerance_grows_on_slivers_and_on_both_triangles_of_a_tie() {
        // A sliver of a fan (its sharpest angle 0.45 degrees, 1/sin about
        // 127) and its neighbour, in z = 0, hit head on; dt 4e-5 of the
        // ray's scale (its origin's 1.0), twice what raylab and Embree gave
        // on a fanned 400-gon, and twice a right triangle's tolerance.
        let a = (0.45f32).to_radians();
        let rim = |k: f32| Vec3::new(2.0 * (k * a).cos(), 2.0 * (k * a).sin(), 0.0);
        let tris = [
            [Vec3::ZERO, rim(0.0), rim(1.0)],
            [Vec3::ZERO, rim(1.0), rim(2.0)],
            [Vec3::ZERO, Vec3::X, Vec3::Y],
        ];
        let (t, dt) = (0.5, 4e-5);
        let head_on = Ray::new(Vec3::new(1.0, 0.0078, -0.5), Vec3::Z);
        assert_eq!(
            classify(&head_on, hit(t, 0), hit(t + dt, 0), &tris),
            Agreement::Same
        );
        assert_eq!(
            classify(&head_on, hit(t, 0), hit(t + dt, 1), &tris),
            Agreement::Tie
        );
        // A well-shaped triangle gets no such slack, and neither does a
        // difference past it on the sliver.
        assert_eq!(
            classify(&head_on, hit(t, 2), hit(t + dt, 2), &tris),
            Agreement::Genuine
        );
        assert_eq!(
            classify(&head_on, hit(t, 0), hit(t + 0.01, 0), &tris),
            Agreement::Genuine
        );
    }

    #[test]
    fn a_grazing_hit_at_the_segment_end_against_a_miss_is_a_tie() {
        let tris = [[Vec3::ZERO, Vec3::X, Vec3::Y]];
        // Along z = 0 at cosine 6e-5, ending 2e-4 (relative) past the hit.
        let grazing = Ray::segment(
            Vec3::new(-0.1, 0.2, -3e-5),
            Vec3::new(1.0, 0.0, 6e-5).normalize(),
            0.0,
            0.5 * (1.0 + 2e-4),
        );
        assert_eq!(classify(&grazing, hit(0.5, 0), None, &tris), Agreement::Tie);
        // Head on, or far inside the segment, a miss is genuine; and an
        // unbounded ray has no end to be near.
        let head_on = Ray::segment(Vec3::new(0.2, 0.2, -0.5), Vec3::Z, 0.0, 0.5 * (1.0 + 2e-4));
        assert_eq!(
            classify(&head_on, None, hit(0.5, 0), &tris),
            Agreement::Genuine
        );
        let long = Ray {
            tmax: 2.0,
            ..grazing
        };
        assert_eq!(
            classify(&long, hit(0.5, 0), None, &tris),
            Agreement::Genuine
        );
        let unbounded = Ray {
            tmax: f32::INFINITY,
            ..grazing
        };
        assert_eq!(
            classify(&unbounded, hit(0.5, 0), None, &tris),
            Agreement::Genuine
        );
    }

    #[test]
    fn classification() {
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::X, Vec3::Y, Vec3::ONE],
            [Vec3::splat(5.0), Vec3::splat(6.0), Vec3::new(5.0, 6.0, 7.0)],
        ];
        let r = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z);
        assert_eq!(classify(&r, None, None, &tris), Agreement::Same);
        assert_eq!(
            classify(&r, hit(1.0, 0), hit(1.0 + 1e-6, 0), &tris),
            Agreement::Same
        );
        assert_eq!(
            classify(&r, hit(1.0, 0), hit(1.0, 1), &tris),
            Agreement::Tie
        );
        assert_eq!(
            classify(&r, hit(1.0, 0), hit(1.0, 2), &tris),
            Agreement::Genuine
        );
        assert_eq!(
            classify(&r, hit(1.0, 0), hit(1.1, 1), &tris),
            Agreement::Genuine
        );
        assert_eq!(classify(&r, hit(1.0, 0), None, &tris), Agreement::Genuine);
        assert_eq!(classify(&r, None, hit(1.0, 0), &tris), Agreement::Genuine);
        // A hit on the edge v = 0 of triangle 0, by its barycentrics and by
        // its point: a tie against a miss.
        let r = Ray::new(Vec3::new(0.5, 0.0, -1.0), Vec3::Z);
        let edge = Some(Hit {
            t: 1.0,
            u: 0.5,
            v: 0.0,
            tri: 0,
            inst: 0,
        });
        assert_eq!(classify(&r, edge, None, &tris), Agreement::Tie);
        // Barycentrics saying "edge" for a point well inside (overflowed,
        // as Embree's on a scene 1e13 across): a genuine disagreement.
        let inside = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z);
        assert_eq!(classify(&inside, edge, None, &tris), Agreement::Genuine);
        // Through the edge to something farther: a tie; nearer off the edge and
        // the edge hit farther: genuine.
        assert_eq!(classify(&r, edge, hit(1.5, 2), &tris), Agreement::Tie);
        assert_eq!(classify(&r, hit(1.5, 2), edge, &tris), Agreement::Tie);
        let far_edge = edge.map(|h| Hit { t: 2.0, ..h });
        assert_eq!(
            classify(&r, hit(1.5, 2), far_edge, &tris),
            Agreement::Genuine
        );
        // A ray starting on a surface: tiny t, judged against the origin's scale.
        let on_surface = Ray::new(Vec3::new(0.2, 0.2, 1.0), Vec3::Z);
        assert_eq!(
            classify(&on_surface, hit(4.5e-4, 0), hit(4.5001e-4, 0), &tris),
            Agreement::Same
        );
    }

    #[test]
    fn coplanar_overlap_is_a_tie() {
        // Two overlapping triangles in the plane z = 0 that share no vertex.
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [
                Vec3::new(0.1, 0.1, 0.0),
                Vec3::new(2.0, 0.1, 0.0),
                Vec3::new(0.1, 2.0, 0.0),
            ],
            [
                Vec3::new(0.1, 0.1, 0.5),
                Vec3::new(2.0, 0.1, 0.5),
                Vec3::new(0.1, 2.0, 0.5),
            ],
        ];
        let r = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z);
        assert_eq!(
            classify(&r, hit(1.0, 0), hit(1.0, 1), &tris),
            Agreement::Tie
        );
        assert!(on_triangle(Vec3::new(0.2, 0.2, 0.0), &tris[1]));
        assert!(!on_triangle(Vec3::new(0.2, 0.2, 0.0), &tris[2]));
        assert!(!on_triangle(Vec3::new(3.0, 3.0, 0.0), &tris[1]));
    }

    #[test]
    fn subsample_strides_evenly() {
        let rays: Vec<Ray> = (0..10)
            .map(|i| Ray::new(Vec3::splat(i as f32), Vec3::X))
            .collect();
        let s = subsample(rays.clone(), 5);
        assert_eq!(s.len(), 5);
        assert_eq!(s[1].origin.x, 2.0);
        assert_eq!(subsample(rays, 50).len(), 10);
    }
}
