//! `raylab stress`: where intersection methods fail, measured, and proof that
//! raylab itself does not fail on hostile input.
//!
//! - **leaks**: closed meshes (icosphere, cube, torus, a high-valence double
//!   fan, and any OBJ given) and rays aimed exactly at their vertices and at
//!   points on their edges, from inside and from outside; a ray that misses a
//!   mesh it must hit is a leak. Counted per backend and triangle test.
//! - **offset**: a floor translated by 0 .. 1e6 units; rays leaving it by each
//!   [`OffsetStrategy`]: the rate of false self-hits, and of missed occluders
//!   at 1e-3, 5e-5 and 1e-5 of the scene's scale above the floor.
//! - **degenerate**: zero-area, collinear, repeated-vertex, sliver, huge and
//!   tiny, coplanar and identical triangles; random, parallel, axis-aligned and
//!   NaN rays: no panic, no NaN, and the same answers as naive.
//! - **hostile**: randomly mutated OBJ/MTL text: the loader returns a valid
//!   scene or a one-line error, never panics.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use crate::accel::bvh::{BuildParams, BvhBackend};
use crate::accel::embree::Quality;
use crate::accel::library::Library;
use crate::accel::naive::Naive;
use crate::accel::{build_backend, Backend, BackendSpec, Built};
use crate::error::{Error, Result};
use crate::geometry::{Aabb, Hit, Intersector, OffsetStrategy, Ray};
use crate::measure::exact::{judge_answers, ExactReference};
use crate::measure::validate::{classify, Agreement};
use crate::rng::Rng;
use crate::scene::MeshRef;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// A triangle mesh as index triples over shared vertices, with a point inside
/// for every target (None for meshes whose inside is unknown).
pub struct TestMesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    inside: fn(Vec3) -> Option<Vec3>,
}

fn at_origin(_: Vec3) -> Option<Vec3> {
    Some(Vec3::ZERO)
}

/// Subdivided icosahedron on the unit sphere: 20 * 4^levels triangles.
pub fn icosphere(levels: u32) -> TestMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut positions: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::from_array(*p).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut mid = |a: u32, b: u32, positions: &mut Vec<Vec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push(((positions[a as usize] + positions[b as usize]) * 0.5).normalize());
                positions.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(triangles.len() * 4);
        for [a, b, c] in triangles {
            let (ab, bc, ca) = (
                mid(a, b, &mut positions),
                mid(b, c, &mut positions),
                mid(c, a, &mut positions),
            );
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    TestMesh {
        name: format!("icosphere-{}", triangles.len()),
        positions,
        triangles,
        inside: at_origin,
    }
}

/// The cube [-1, 1]^3, each face an n x n grid of quads, wound outwards.
pub fn cube(n: u32) -> TestMesh {
    let mut positions = Vec::new();
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut triangles = Vec::new();
    // Vertices on a shared integer lattice, so faces meeting at an edge share them.
    let mut vertex = |g: [i64; 3], positions: &mut Vec<Vec3>| {
        *index.entry(g).or_insert_with(|| {
            positions.push(
                Vec3::new(g[0] as f32, g[1] as f32, g[2] as f32) * (2.0 / n as f32) - Vec3::ONE,
            );
            positions.len() as u32 - 1
        })
    };
    let n = n as i64;
    for axis in 0..3 {
        for side in [0, n] {
            for i in 0..n {
                for j in 0..n {
                    let g = |a: i64, b: i64| {
                        let mut v = [0i64; 3];
                        v[axis] = side;
                        v[(axis + 1) % 3] = a;
                        v[(axis + 2) % 3] = b;
                        v
                    };
                    let q = [g(i, j), g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)]
                        .map(|v| vertex(v, &mut positions));
                    // Counter-clockwise seen from outside: the (u, v) order faces +axis,
                    // so the side-0 faces are reversed.
                    if side == n {
                        triangles.push([q[0], q[1], q[2]]);
                        triangles.push([q[0], q[2], q[3]]);
                    } else {
                        triangles.push([q[0], q[2], q[1]]);
                        triangles.push([q[0], q[3], q[2]]);
                    }
                }
            }
        }
    }
    TestMesh {
        name: format!("cube-{}", triangles.len()),
        positions,
        triangles,
        inside: at_origin,
    }
}

/// A torus of radii 1 and 0.35 around the y axis, `nu x nv` quads.
pub fn torus(nu: u32, nv: u32) -> TestMesh {
    let (big, small) = (1.0f32, 0.35f32);
    let mut positions = Vec::new();
    for i in 0..nu {
        let u = i as f32 / nu as f32 * std::f32::consts::TAU;
        for j in 0..nv {
            let v = j as f32 / nv as f32 * std::f32::consts::TAU;
            let r = big + small * v.cos();
            positions.push(Vec3::new(r * u.cos(), small * v.sin(), r * u.sin()));
        }
    }
    let at = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    let mut triangles = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    // Inside the tube: its centre circle at the target's azimuth.
    fn tube_centre(target: Vec3) -> Option<Vec3> {
        let d = Vec3::new(target.x, 0.0, target.z).normalize_or_zero();
        (d != Vec3::ZERO).then_some(d)
    }
    TestMesh {
        name: format!("torus-{}", triangles.len()),
        positions,
        triangles,
        inside: tube_centre,
    }
}

/// A closed double fan: a ring of `n` vertices and two apexes of valence `n`.
pub fn double_fan(n: u32) -> TestMesh {
    let mut positions = vec![Vec3::Y, -Vec3::Y];
    for i in 0..n {
        let a = i as f32 / n as f32 * std::f32::consts::TAU;
        positions.push(Vec3::new(a.cos(), 0.0, a.sin()));
    }
    let ring = |i: u32| 2 + i % n;
    let mut triangles = Vec::new();
    for i in 0..n {
        triangles.push([0, ring(i + 1), ring(i)]);
        triangles.push([1, ring(i), ring(i + 1)]);
    }
    TestMesh {
        name: format!("fan-{}", triangles.len()),
        positions,
        triangles,
        inside: at_origin,
    }
}

/// A closed mesh from a scene file (its inside unknown: outside rays only).
/// Vertices at the same position are welded first (loaders split them where
/// normals differ); then every edge must belong to exactly two triangles, since
/// a ray through a hole is no leak and the suite's count would be meaningless.
pub fn file_mesh(path: &Path, policy: crate::scene::refs::RefPolicy) -> Result<TestMesh> {
    fn unknown(_: Vec3) -> Option<Vec3> {
        None
    }
    let scene = crate::scene::load::load_file_with(path, policy)?;
    let (positions, triangles) = weld(&scene.positions, &scene.triangles);
    if let Some((edges, at)) = open_edges(&positions, &triangles) {
        return Err(Error::usage(
            "--mesh",
            format!(
                "{}: not a closed mesh ({edges} edges do not belong to exactly two triangles, one at ({}, {}, {})): the leak suite needs a closed surface",
                path.display(),
                at.x,
                at.y,
                at.z
            ),
        ));
    }
    Ok(TestMesh {
        name: path.display().to_string(),
        positions,
        triangles,
        inside: unknown,
    })
}

/// Merges vertices with bit-identical positions.
fn weld(positions: &[Vec3], triangles: &[[u32; 3]]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut index_of: std::collections::HashMap<[u32; 3], u32> = std::collections::HashMap::new();
    let mut welded = Vec::new();
    let remap: Vec<u32> = positions
        .iter()
        .map(|p| {
            let key = p.to_array().map(|x| (x + 0.0).to_bits());
            *index_of.entry(key).or_insert_with(|| {
                welded.push(*p);
                (welded.len() - 1) as u32
            })
        })
        .collect();
    let tris = triangles
        .iter()
        .map(|t| t.map(|i| remap[i as usize]))
        .collect();
    (welded, tris)
}

/// The number of edges not shared by exactly two triangles, and a point on one
/// of them; None for a closed mesh.
fn open_edges(positions: &[Vec3], triangles: &[[u32; 3]]) -> Option<(usize, Vec3)> {
    let mut uses: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut bad = uses.iter().filter(|(_, &n)| n != 2);
    let &(a, _) = bad.next()?.0;
    Some((1 + bad.count(), positions[a as usize]))
}

/// A point on the unit sphere from two uniforms.
fn sphere_point(u: f32, v: f32) -> Vec3 {
    let z = 2.0 * u - 1.0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * v;
    Vec3::new(r * phi.cos(), z, r * phi.sin())
}

/// The leak rays of a mesh: for every vertex, every edge midpoint and a random
/// point on every edge, one ray from inside (when the inside is known) and
/// `outside` rays from a sphere around the mesh, kept only when they enter
/// every face that touches the target (cosine below -0.1): a ray that only
/// grazes the target (a silhouette) may legitimately miss.
pub fn leak_rays(mesh: &TestMesh, outside: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::for_pixel(0, seed, 0x1EA4);
    let bounds = Aabb::from_points(&mesh.positions);
    let (centre, radius) = (bounds.center(), bounds.extent().length().max(1e-3) * 1.5);
    // Unit normals of the faces touching each vertex and each edge.
    let mut vertex_faces: Vec<Vec<Vec3>> = vec![Vec::new(); mesh.positions.len()];
    let mut edges: HashMap<(u32, u32), Vec<Vec3>> = HashMap::new();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero();
        for i in 0..3 {
            vertex_faces[t[i] as usize].push(n);
            let (x, y) = (t[i], t[(i + 1) % 3]);
            edges.entry((x.min(y), x.max(y))).or_default().push(n);
        }
    }
    let mut targets: Vec<(Vec3, Vec<Vec3>)> = mesh
        .triangles
        .iter()
        .flatten()
        .map(|&i| i as usize)
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .map(|i| (mesh.positions[i], vertex_faces[i].clone()))
        .collect();
    let mut edge_list: Vec<_> = edges.into_iter().collect();
    edge_list.sort_by_key(|(k, _)| *k);
    for ((a, b), normals) in edge_list {
        let (pa, pb) = (mesh.positions[a as usize], mesh.positions[b as usize]);
        targets.push(((pa + pb) * 0.5, normals.clone()));
        let s = rng.next_f32();
        targets.push((pa + (pb - pa) * s, normals));
    }
    let mut rays = Vec::new();
    for (target, normals) in targets {
        if let Some(inside) = (mesh.inside)(target) {
            if inside != target {
                rays.push(Ray::new(inside, (target - inside).normalize()));
            }
        }
        for _ in 0..outside {
            let o = centre + sphere_point(rng.next_f32(), rng.next_f32()) * radius;
            let d = (target - o).normalize_or_zero();
            // Faces may be wound either way: entering means the same side for all.
            let enters = |sign: f32| normals.iter().all(|n| sign * d.dot(*n) < -0.1);
            if d != Vec3::ZERO && (enters(1.0) || enters(-1.0)) {
                rays.push(Ray::new(o, d));
            }
        }
    }
    rays
}

/// One backend's result on one mesh.
#[derive(Clone, Debug, Serialize)]
pub struct LeakRow {
    pub mesh: String,
    pub triangles: usize,
    pub backend: String,
    /// Embree, which has its own ray/triangle test (`intersector` reads `embree`).
    pub embree: bool,
    pub intersector: String,
    pub rays: usize,
    pub leaks: usize,
    pub leak_rate: f64,
    /// Tracing time per ray (closest hit), for the leak-against-speed chart.
    pub ns_per_ray: f64,
    /// Closest-hit and any-hit answers the exact reference judges wrong
    /// (leaks, false hits, wrong triangles, t errors), and edge ties.
    pub exact_wrong: usize,
    pub edge_ties: usize,
}

/// The backends the leak and degenerate suites compare when `--backends`
/// names none (`all`): the naive scan, the study's median tree and the tree
/// a render builds ([`BackendSpec::DEFAULT`]), each with Moller-Trumbore and
/// the watertight test; Embree plain and robust; each other library's
/// layouts ([`Library::ALL`]); those this raylab was built with, all built
/// on one thread.
pub fn default_stress_specs() -> Vec<BackendSpec> {
    let mut out = Vec::new();
    for intersector in [Intersector::Mt, Intersector::Watertight] {
        for spec in [
            BackendSpec::naive(),
            BackendSpec::bvh(BuildParams::median()),
            BackendSpec::DEFAULT,
        ] {
            out.push(spec.with_intersector(intersector));
        }
    }
    if crate::accel::embree::AVAILABLE {
        for robust in [false, true] {
            out.push(BackendSpec::Embree {
                quality: Quality::Medium,
                robust,
                threads: 1,
                query: crate::accel::Query::Single,
            });
        }
    }
    out.extend(library_specs());
    out
}

/// Each other library's layouts this raylab was built with, on one thread.
fn library_specs() -> impl Iterator<Item = BackendSpec> {
    Library::ALL
        .into_iter()
        .filter(Library::available)
        .map(|library| BackendSpec::library(library, 1))
}

/// Parses `--backends`: backend names as reports print them
/// ([`crate::accel::parse_backend`]: `bvh8-sah-watertight`,
/// `embree-medium-robust`, `tinybvh-bvh`, or a `--backend` name for its
/// default) separated by commas, `libraries` (each other library's layouts)
/// or `all` ([`default_stress_specs`]). A backend this raylab was built
/// without is an error when named.
pub fn parse_stress_backends(s: &str) -> Result<Vec<BackendSpec>> {
    let mut out: Vec<BackendSpec> = Vec::new();
    let mut push = |spec: BackendSpec| {
        if !out.contains(&spec) {
            out.push(spec);
        }
    };
    for p in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        match p {
            "all" => default_stress_specs().into_iter().for_each(&mut push),
            "libraries" => library_specs().for_each(&mut push),
            name => {
                let spec = crate::accel::parse_backend(name)
                    .map_err(|e| Error::usage("--backends", format!("{e}; or all, libraries")))?;
                match spec {
                    BackendSpec::Embree { .. } if !crate::accel::embree::AVAILABLE => {
                        return Err(crate::accel::embree::unavailable())
                    }
                    BackendSpec::Library { library, .. } if !library.available() => {
                        return Err(crate::accel::library::unavailable(&library))
                    }
                    _ => push(spec),
                }
            }
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--backends", "no backend given"));
    }
    Ok(out)
}

/// `specs` built over raw arrays (degenerate triangles kept), with each
/// one's ray/triangle test as reports name it (`mt`, `watertight`, or
/// `embree` for Embree's own).
fn stress_backends(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    specs: &[BackendSpec],
) -> Result<Vec<(Built, String)>> {
    built_or_not(positions, triangles, specs)
        .into_iter()
        .map(|(_, built, test)| Ok((built?, test)))
        .collect()
}

/// Each of `specs`, built, or why it could not be: a library refusing an
/// input is a finding, not the end of the suite.
fn built_or_not(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    specs: &[BackendSpec],
) -> Vec<(BackendSpec, Result<Built>, String)> {
    let mesh = MeshRef {
        positions,
        triangles,
    };
    specs
        .iter()
        .map(|&spec| {
            let test = match spec {
                BackendSpec::Naive { intersector } | BackendSpec::Bvh { intersector, .. } => {
                    intersector.name()
                }
                BackendSpec::Embree { .. } => "embree",
                BackendSpec::Library { .. } => "its own",
            };
            let built = build_backend(&spec, mesh);
            (spec, built, test.to_string())
        })
        .collect()
}

/// The leak suite over `meshes` with every backend ([`default_stress_specs`]).
pub fn leak_suite(meshes: &[TestMesh], outside: usize) -> Result<Vec<LeakRow>> {
    leak_suite_with(meshes, outside, &default_stress_specs())
}

/// The leak suite over `meshes` with the backends `specs`.
pub fn leak_suite_with(
    meshes: &[TestMesh],
    outside: usize,
    specs: &[BackendSpec],
) -> Result<Vec<LeakRow>> {
    let mut rows = Vec::new();
    for (k, mesh) in meshes.iter().enumerate() {
        let rays = leak_rays(mesh, outside, 17 + k as u64);
        let reference = ExactReference::new(
            MeshRef {
                positions: &mesh.positions,
                triangles: &mesh.triangles,
            }
            .triangle_vertices(),
        );
        let answers = reference.answers(&rays);
        for (backend, intersector) in stress_backends(&mesh.positions, &mesh.triangles, specs)? {
            let start = Instant::now();
            let leaks = rays
                .iter()
                .filter(|r| backend.intersect(r).is_none())
                .count();
            let elapsed = start.elapsed();
            let judged = judge_answers("leaks", &rays, &answers, backend.as_ref());
            rows.push(LeakRow {
                mesh: mesh.name.clone(),
                triangles: mesh.triangles.len(),
                backend: backend.name(),
                embree: backend.spec.is_embree(),
                intersector,
                rays: rays.len(),
                leaks,
                leak_rate: leaks as f64 / rays.len().max(1) as f64,
                ns_per_ray: elapsed.as_secs_f64() * 1e9 / rays.len().max(1) as f64,
                exact_wrong: judged.wrong(),
                edge_ties: judged.edge_tie_answers(),
            });
        }
    }
    Ok(rows)
}

/// The default meshes of the leak suite.
pub fn leak_meshes(quick: bool) -> Vec<TestMesh> {
    if quick {
        vec![icosphere(2), cube(2), torus(24, 12), double_fan(64)]
    } else {
        vec![icosphere(4), cube(8), torus(96, 48), double_fan(2048)]
    }
}

/// One strategy at one translation.
#[derive(Clone, Debug, Serialize)]
pub struct OffsetRow {
    pub translation: f32,
    /// The floor and where the primary rays that found its points came
    /// from: "near" (the floor at (T, T, T), the rays from about one scale
    /// unit above, steep) or "field" (the floor in the plane y = 0 at
    /// (T, 0, T), the rays from 200 scale units away at a grazing 3 degrees,
    /// as a camera sees a field's far side).
    pub view: &'static str,
    pub strategy: OffsetStrategy,
    pub intersector: Intersector,
    pub rays: usize,
    /// Rays leaving the floor that hit it again.
    pub self_hit_rate: f64,
    /// Upward rays that miss an occluder 1e-3 (5e-5, 1e-5) of the scale above.
    pub missed_at_1e3: f64,
    pub missed_at_5e5: f64,
    pub missed_at_1e5: f64,
}

/// A square of half-size `half` at height `y`, centred at `c` (two triangles).
fn square(c: Vec3, y: f32, half: f32) -> [[Vec3; 3]; 2] {
    let p = |x: f32, z: f32| Vec3::new(c.x + x, y, c.z + z);
    [
        [p(-half, -half), p(half, -half), p(half, half)],
        [p(-half, -half), p(half, half), p(-half, half)],
    ]
}

/// The offset suite: for each translation, points on a floor found by primary
/// rays (with their rounding), then rays leaving it by each strategy.
pub fn offset_suite(translations: &[f32], points: usize) -> Result<Vec<OffsetRow>> {
    let mut rows = Vec::new();
    for &shift in translations {
        for view in ["near", "field"] {
            // "field": the floor stays in the plane y = 0 (a ground's height is
            // 0 in most exports however far out it lies).
            let c = match view {
                "near" => Vec3::splat(shift),
                _ => Vec3::new(shift, 0.0, shift),
            };
            let scale = shift.abs().max(1.0);
            let floor = square(c, c.y, 1.0);
            // Wide enough that no upward ray (cosine >= 0.2, so at most 5 units
            // sideways per unit up) can pass beside it.
            let with_occluder = |h: f32| {
                let mut t = floor.to_vec();
                t.extend(square(c, c.y + h * scale, 2.0 + 6.0 * h * scale));
                t
            };
            let (near, closer, nearest) = (
                with_occluder(1e-3),
                with_occluder(5e-5),
                with_occluder(1e-5),
            );
            for intersector in [Intersector::Mt, Intersector::Watertight] {
                let make = |t: &[[Vec3; 3]]| {
                    BvhBackend::new(t, &BuildParams::sah()).map(|b| b.with_intersector(intersector))
                };
                let (floor_only, near_b) = (make(&floor)?, make(&near)?);
                let (closer_b, nearest_b) = (make(&closer)?, make(&nearest)?);
                let mut rng = Rng::for_pixel(shift.to_bits() as u64, 5, 0x0FF5);
                // Surface points as a renderer finds them: the hits of primary rays
                // (each strategy starts from o + t d or from the hit's barycentrics).
                let hits: Vec<(Ray, Hit)> = (0..points)
                    .filter_map(|_| {
                        let target = c + Vec3::new(
                            rng.next_f32() * 1.8 - 0.9,
                            0.0,
                            rng.next_f32() * 1.8 - 0.9,
                        );
                        let o = if view == "near" {
                            target
                                + Vec3::new(rng.next_f32() - 0.5, 1.0, rng.next_f32() - 0.5) * scale
                        } else {
                            // Far and grazing, as a camera sees a field's far side.
                            let phi = std::f32::consts::TAU * rng.next_f32();
                            let grazing = 3f32.to_radians();
                            let back = Vec3::new(
                                phi.cos() * grazing.cos(),
                                grazing.sin(),
                                phi.sin() * grazing.cos(),
                            );
                            target + back * (200.0 * scale)
                        };
                        let ray = Ray::new(o, (target - o).normalize());
                        floor_only.intersect(&ray).map(|h| (ray, h))
                    })
                    .collect();
                for strategy in OffsetStrategy::ALL {
                    let (mut self_hits, mut missed3, mut missed45, mut missed5, mut n) =
                        (0, 0, 0, 0, 0);
                    for (primary, hit) in &hits {
                        // Cosine-ish upward directions, not grazing (cos >= 0.2), so a
                        // finite occluder above covers every one.
                        let (u, v) = (rng.next_f32(), rng.next_f32());
                        let cos = 0.2 + 0.8 * u;
                        let sin = (1.0 - cos * cos).sqrt();
                        let phi = std::f32::consts::TAU * v;
                        let d = Vec3::new(sin * phi.cos(), cos, sin * phi.sin());
                        let tri = &floor[hit.tri as usize];
                        let (origin, tmin) =
                            strategy.apply(primary, (hit.t, hit.u, hit.v), tri, Vec3::Y);
                        let ray = Ray::segment(origin, d, tmin, f32::INFINITY);
                        n += 1;
                        self_hits += floor_only.occluded(&ray) as usize;
                        // The occluder is triangles 2 and 3; a floor hit or a miss both fail.
                        let hits_occluder =
                            |b: &BvhBackend| b.intersect(&ray).is_some_and(|h| h.tri >= 2);
                        missed3 += !hits_occluder(&near_b) as usize;
                        missed45 += !hits_occluder(&closer_b) as usize;
                        missed5 += !hits_occluder(&nearest_b) as usize;
                    }
                    let rate = |x: usize| x as f64 / n.max(1) as f64;
                    rows.push(OffsetRow {
                        translation: shift,
                        view,
                        strategy,
                        intersector,
                        rays: n,
                        self_hit_rate: rate(self_hits),
                        missed_at_1e3: rate(missed3),
                        missed_at_5e5: rate(missed45),
                        missed_at_1e5: rate(missed5),
                    });
                }
            }
        }
    }
    Ok(rows)
}

/// One degenerate case against one backend.
#[derive(Clone, Debug, Serialize)]
pub struct DegenerateRow {
    pub case: String,
    pub triangles: usize,
    pub backend: String,
    pub rays: usize,
    /// Hits with a non-finite t, u or v.
    pub nan_results: usize,
    /// Genuine disagreements with naive (same triangle test; Embree and
    /// the other libraries against MT).
    pub genuine_vs_naive: usize,
    /// Closest-hit and any-hit answers the exact reference judges wrong,
    /// and those it cannot decide in double precision.
    pub exact_wrong: usize,
    pub undecidable: usize,
    /// Another library's (tinybvh, obvhs, the bvh crate), not raylab's or
    /// Embree's: its NaN results do not fail `stress`.
    pub library: bool,
    /// Why the backend could not be built on this case (nothing measured).
    pub not_built: Option<String>,
}

/// One degenerate input: a name, vertex positions and index triples.
pub struct DegenerateCase {
    pub name: &'static str,
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// The degenerate inputs.
pub fn degenerate_cases() -> Vec<DegenerateCase> {
    let mut rng = Rng::for_pixel(0, 9, 0xDE6);
    let mut r = || rng.next_f32() * 2.0 - 1.0;
    let mut cases = Vec::new();
    let one = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
    cases.push((
        "zero-area",
        vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        vec![[0, 1, 2]; 50],
    ));
    cases.push((
        "collinear",
        (0..30)
            .map(|i| Vec3::new(i as f32 * 0.1, i as f32 * 0.05, 0.0))
            .collect(),
        (0..28).map(|i| [i, i + 1, i + 2]).collect(),
    ));
    cases.push((
        "repeated vertices",
        one.clone(),
        vec![[0, 0, 1], [1, 1, 1], [0, 1, 2], [2, 2, 0]],
    ));
    let slivers: Vec<Vec3> = (0..200)
        .flat_map(|i| {
            let x = i as f32 * 0.01;
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 5.0, 1e-6, 0.0),
                Vec3::new(x + 10.0, 0.0, 1e-7),
            ]
        })
        .collect();
    cases.push((
        "slivers",
        slivers,
        (0..200).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    ));
    cases.push((
        "huge and tiny",
        vec![
            Vec3::splat(-1e6),
            Vec3::new(1e6, -1e6, 0.0),
            Vec3::new(0.0, 1e6, 0.0),
            Vec3::ZERO,
            Vec3::X * 1e-6,
            Vec3::Y * 1e-6,
            Vec3::Z,
            Vec3::X,
            Vec3::Y,
        ],
        vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]],
    ));
    let plane: Vec<Vec3> = (0..900).map(|_| Vec3::new(r(), r(), 0.25)).collect();
    cases.push((
        "one plane",
        plane,
        (0..300).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    ));
    cases.push(("identical", one, vec![[0, 1, 2]; 2000]));
    cases
        .into_iter()
        .map(|(name, positions, triangles)| DegenerateCase {
            name,
            positions,
            triangles,
        })
        .collect()
}

/// The degenerate suite: every backend on every case with random rays,
/// rays parallel to the triangles' plane, axis-aligned rays and NaN/inf
/// rays, judged against naive and against the exact reference. A library
/// that refuses a case (tinybvh's BVH8_CPU conversion on `identical`, which
/// once crashed the process) gets a "not built" row.
pub fn degenerate_suite(rays_per_case: usize, specs: &[BackendSpec]) -> Result<Vec<DegenerateRow>> {
    let mut rows = Vec::new();
    for DegenerateCase {
        name,
        positions,
        triangles,
    } in degenerate_cases()
    {
        let tris: Vec<[Vec3; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| positions[i as usize]))
            .collect();
        let bounds = Aabb::from_points(&positions);
        let mut rays = crate::measure::validate::random_rays(bounds, rays_per_case, 3);
        let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
        let mut rng = Rng::for_pixel(1, 2, 3);
        for i in 0..rays_per_case / 2 {
            let o = bounds.min
                + bounds.extent() * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let d = if i % 2 == 0 {
                axes[i / 2 % 6]
            } else {
                // In the plane of a triangle: parallel to it.
                let t = &tris[i % tris.len()];
                (t[1] - t[0]).normalize_or(Vec3::X)
            };
            rays.push(Ray::new(o, d));
        }
        rays.extend([
            Ray::new(Vec3::NAN, Vec3::X),
            Ray::new(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 0.0)),
            Ray::new(Vec3::splat(f32::INFINITY), Vec3::X),
            Ray::new(Vec3::ZERO, Vec3::ZERO),
            Ray::segment(Vec3::ZERO, Vec3::X, 0.0, f32::NAN),
            Ray::segment(Vec3::ZERO, Vec3::X, f32::INFINITY, f32::INFINITY),
        ]);
        let naive_mt = Naive::from_triangles(tris.clone());
        let naive_wt =
            Naive::from_triangles(tris.clone()).with_intersector(Intersector::Watertight);
        let reference = ExactReference::new(tris.clone());
        let answers = reference.answers(&rays);
        for (spec, built, intersector) in built_or_not(&positions, &triangles, specs) {
            let backend = match built {
                Ok(b) => b,
                Err(e) => {
                    rows.push(DegenerateRow {
                        case: name.to_string(),
                        triangles: tris.len(),
                        backend: spec.name(),
                        rays: 0,
                        nan_results: 0,
                        genuine_vs_naive: 0,
                        exact_wrong: 0,
                        undecidable: 0,
                        library: spec.is_library(),
                        not_built: Some(e.to_string()),
                    });
                    continue;
                }
            };
            let reference: &dyn Backend = if intersector == "watertight" {
                &naive_wt
            } else {
                &naive_mt
            };
            let mut nan = 0;
            let mut genuine = 0;
            for ray in &rays {
                let h = backend.intersect(ray);
                if h.is_some_and(|h| !(h.t.is_finite() && h.u.is_finite() && h.v.is_finite())) {
                    nan += 1;
                }
                let agreement = classify(ray, h, reference.intersect(ray), &tris);
                genuine += (agreement == Agreement::Genuine) as usize;
            }
            let judged = judge_answers(name, &rays, &answers, backend.as_ref());
            rows.push(DegenerateRow {
                case: name.to_string(),
                triangles: tris.len(),
                backend: backend.name(),
                rays: rays.len(),
                nan_results: nan,
                genuine_vs_naive: genuine,
                exact_wrong: judged.wrong(),
                undecidable: judged.undecidable_answers(),
                library: spec.is_library(),
                not_built: None,
            });
        }
    }
    Ok(rows)
}

/// What the loader did with mutated files.
#[derive(Clone, Debug, Default, Serialize)]
pub struct HostileReport {
    pub cases: usize,
    pub loaded: usize,
    pub rejected: usize,
    pub panics: usize,
    /// Errors whose message is not a single line.
    pub multi_line_errors: usize,
    /// Loaded scenes with out-of-range indices or non-finite values (must be 0).
    pub invalid_scenes: usize,
}

const BASE_OBJ: &str = "mtllib box.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvn 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
usemtl white\nf 1/1/1 2/2/1 3/3/1 4/1/1\nv 0 1 0\nv 1 1 0\nv 0 1 1\nusemtl light\nf -3 -2 -1\ng rest\ns 1\nf 1 2 5\n";
const BASE_MTL: &str = "newmtl white\nKa 0.1 0.1 0.1\nKd 0.7 0.7 0.7\nNs 10\nnewmtl light\nKd 0.8 0.8 0.8\nKe 10 10 10\nKs 0.5 0.5 0.5\n";
const NASTY: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-1e39",
    "0",
    "-0",
    "4294967296",
    "-4294967297",
    "18446744073709551616",
    "-1",
    "99999999999",
    "1/",
    "//",
    "/1/",
    "1//1//1",
    "\u{0}",
    "\u{feff}",
    "#",
    "f",
    "v",
    "\t",
    "1e-45",
    "",
];

/// A random mutation of `base`: deleted, inserted and replaced characters,
/// nasty tokens, truncation, duplicated lines.
pub fn mutate(base: &str, rng: &mut Rng) -> String {
    let mut text: Vec<char> = base.chars().collect();
    let pick = |rng: &mut Rng, n: usize| (rng.next_f32() * n as f32) as usize % n.max(1);
    for _ in 0..1 + pick(rng, 4) {
        if text.is_empty() {
            break;
        }
        let at = pick(rng, text.len());
        match pick(rng, 6) {
            0 => {
                text.remove(at);
            }
            1 => text.insert(at, char::from_u32(pick(rng, 0x3000) as u32).unwrap_or('?')),
            2 => {
                for (k, c) in NASTY[pick(rng, NASTY.len())].chars().enumerate() {
                    text.insert(at + k, c);
                }
            }
            3 => text.truncate(at),
            4 => {
                let s: String = text.iter().collect();
                let mut words: Vec<String> = s.split(' ').map(str::to_string).collect();
                let w = pick(rng, words.len());
                words[w] = NASTY[pick(rng, NASTY.len())].to_string();
                text = words.join(" ").chars().collect();
            }
            _ => {
                let s: String = text.iter().collect();
                let lines: Vec<&str> = s.lines().collect();
                if !lines.is_empty() {
                    let line = lines[pick(rng, lines.len())].to_string();
                    text.extend(format!("\n{line}\n").chars());
                }
            }
        }
    }
    text.into_iter().collect()
}

/// Loads `cases` mutated OBJ files (every third with a mutated MTL) from a
/// scratch folder, counting outcomes; a panic is caught and counted.
pub fn hostile_suite(cases: usize, seed: u64) -> Result<HostileReport> {
    let dir = std::env::temp_dir().join(format!("raylab-stress-{}-{seed}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::io(&dir, e))?;
    let mut rng = Rng::for_pixel(0, seed, 0x4057);
    let mut report = HostileReport {
        cases,
        ..HostileReport::default()
    };
    // Silence the panic message of a caught panic: the count is the result.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for case in 0..cases {
        let obj = mutate(BASE_OBJ, &mut rng);
        let mtl = if case % 3 == 0 {
            mutate(BASE_MTL, &mut rng)
        } else {
            BASE_MTL.to_string()
        };
        if std::fs::write(dir.join("box.mtl"), &mtl).is_err() {
            continue;
        }
        match std::panic::catch_unwind(|| {
            crate::scene::obj::load_obj_str(&obj, Path::new("hostile.obj"), &dir)
        }) {
            Err(_) => report.panics += 1,
            Ok(Err(e)) => {
                report.rejected += 1;
                report.multi_line_errors += (e.to_string().lines().count() != 1) as usize;
            }
            Ok(Ok(scene)) => {
                report.loaded += 1;
                let valid = scene.triangle_count() > 0
                    && scene.positions.iter().all(|p| p.is_finite())
                    && scene
                        .triangles
                        .iter()
                        .flatten()
                        .all(|&i| (i as usize) < scene.positions.len())
                    && scene
                        .material_ids
                        .iter()
                        .all(|&m| (m as usize) < scene.materials.len())
                    && scene
                        .materials
                        .iter()
                        .all(|m| m.kd.is_finite() && m.ke.is_finite() && m.ns.is_finite());
                report.invalid_scenes += !valid as usize;
            }
        }
        let mtl_only = mutate(BASE_MTL, &mut rng);
        if std::panic::catch_unwind(|| crate::scene::obj::parse_mtl(&mtl_only, Path::new("m.mtl")))
            .is_err()
        {
            report.panics += 1;
        }
    }
    std::panic::set_hook(hook);
    std::fs::remove_dir_all(&dir).ok();
    Ok(report)
}

/// Everything one `raylab stress` run measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StressReport {
    pub leaks: Vec<LeakRow>,
    pub offset: Vec<OffsetRow>,
    pub degenerate: Vec<DegenerateRow>,
    pub hostile: Option<HostileReport>,
}

/// The leak rows as a table.
pub fn leak_table(rows: &[LeakRow]) -> Table {
    let mut t = Table::new([
        ("mesh", Left),
        ("triangles", Right),
        ("backend", Left),
        ("rays", Right),
        ("leaks", Right),
        ("leak rate", Right),
        ("wrong vs exact", Right),
        ("edge ties", Right),
        ("ns/ray", Right),
    ]);
    for r in rows {
        t.row([
            r.mesh.clone(),
            r.triangles.to_string(),
            r.backend.clone(),
            r.rays.to_string(),
            r.leaks.to_string(),
            format!("{:.2e}", r.leak_rate),
            r.exact_wrong.to_string(),
            r.edge_ties.to_string(),
            format!("{:.0}", r.ns_per_ray),
        ]);
    }
    t
}

impl StressReport {
    /// The report as Markdown tables.
    pub fn markdown(&self) -> String {
        let mut out = String::new();
        if !self.leaks.is_empty() {
            out.push_str(
                "## Leaks: rays aimed at vertices and edges of closed meshes that miss them\n\n",
            );
            out.push_str(&leak_table(&self.leaks).markdown());
            out.push('\n');
        }
        if !self.offset.is_empty() {
            out.push_str("## Offset: rays leaving a floor translated by T (rates)\n\n");
            let mut t = Table::new([
                ("T", Right),
                ("view", Left),
                ("strategy", Left),
                ("test", Left),
                ("rays", Right),
                ("false self-hits", Right),
                ("missed occluder at 1e-3", Right),
                ("at 5e-5", Right),
                ("at 1e-5", Right),
            ]);
            for r in &self.offset {
                t.row([
                    format!("{:.0e}", r.translation),
                    r.view.to_string(),
                    r.strategy.name().to_string(),
                    r.intersector.name().to_string(),
                    r.rays.to_string(),
                    format!("{:.4}", r.self_hit_rate),
                    format!("{:.4}", r.missed_at_1e3),
                    format!("{:.4}", r.missed_at_5e5),
                    format!("{:.4}", r.missed_at_1e5),
                ]);
            }
            out.push_str(&t.markdown());
            out.push('\n');
        }
        if !self.degenerate.is_empty() {
            out.push_str(
                "## Degenerate input: NaN results, genuine disagreements with naive, wrong answers against the exact reference\n\n",
            );
            let mut t = Table::new([
                ("case", Left),
                ("triangles", Right),
                ("backend", Left),
                ("rays", Right),
                ("NaN results", Right),
                ("genuine vs naive", Right),
                ("wrong vs exact", Right),
                ("undecidable", Right),
            ]);
            for r in &self.degenerate {
                if let Some(why) = &r.not_built {
                    t.row([
                        r.case.to_string(),
                        r.triangles.to_string(),
                        r.backend.clone(),
                        "-".into(),
                        "-".into(),
                        "-".into(),
                        "-".into(),
                        format!("not built: {why}"),
                    ]);
                    continue;
                }
                t.row([
                    r.case.to_string(),
                    r.triangles.to_string(),
                    r.backend.clone(),
                    r.rays.to_string(),
                    r.nan_results.to_string(),
                    r.genuine_vs_naive.to_string(),
                    r.exact_wrong.to_string(),
                    r.undecidable.to_string(),
                ]);
            }
            out.push_str(&t.markdown());
            out.push('\n');
        }
        if let Some(h) = &self.hostile {
            out.push_str(&format!(
                "## Hostile OBJ/MTL\n\n{} mutated files: {} loaded, {} rejected with an error, {} panics, {} multi-line errors, {} invalid scenes\n",
                h.cases, h.loaded, h.rejected, h.panics, h.multi_line_errors, h.invalid_scenes
            ));
        }
        out
    }
}
