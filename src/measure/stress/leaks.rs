//! The leak suite: closed meshes and rays aimed exactly at their vertices and
//! edges, from inside and outside; a ray that misses a mesh it must hit leaks.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use super::backends::{default_stress_specs, stress_backends};
use crate::accel::BackendSpec;
use crate::error::{Error, Result};
use crate::geometry::{Aabb, Ray};
use crate::measure::exact::{judge_answers, ExactReference};
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
