//! Scenes that move: built-in animations whose vertices are a function of
//! time, with the topology (the triangle list) fixed, so that a tree built on
//! one frame can be refitted to the next. A frame is a [`Scene`] like any
//! other; the renderer and backends never know it moves.
//!
//! - `explode:N`: the displaced sphere of `mesh:N` flies apart into its
//!   triangles, each along its own direction from the centre and tumbling.
//!   The hardest case for refitting: triangles that were neighbours in a
//!   leaf end up far apart, so the boxes of a refitted tree swell and
//!   overlap.
//! - `cloth:N`: a cloth of about N triangles pinned along one edge, waving
//!   in travelling waves. Neighbours stay neighbours: the easy case.
//!
//! - `asteroids:N`: N rocks orbiting in a belt and tumbling: the meshes stay,
//!   the instances move ([`super::asteroids`]), so a two-level tree refits
//!   or rebuilds its instances' tree (the TLAS) alone.
//!
//! - a glTF file's animations ([`super::gltf_motion`]): node TRS keyframes,
//!   morph targets and skins, as the file's author made them. When every
//!   placed mesh moves rigidly with its node, its instances move, as the
//!   asteroids' do.
//!
//! Frames drop the rest pose's vertex normals (they would not follow the
//! motion) and shade with the geometric normal.

use std::f32::consts::TAU;

use glam::{Quat, Vec3};

use super::gltf_motion::Followed;
use super::shapes::{parse_count, still, MESH_TRIANGLES};
use super::{Material, Scene};
use crate::error::{Error, Result};

/// The animated built-ins, with a line each (`raylab scenes` lists them).
pub const ANIMATED_SCENES: &[(&str, &str)] = &[
    (
        "explode:N",
        "animated, 2 s: mesh:N's sphere flies apart into its triangles, each tumbling outwards past the sphere's bounds (the hardest motion for a refitted tree)",
    ),
    (
        "cloth:N",
        "animated, 2 s, looping: a cloth of about N triangles (100..=1e7) pinned along one edge waves in the box (neighbours stay neighbours)",
    ),
    (
        "asteroids:N",
        "animated, 2 s, instanced: N rocks (1..=1e6; three meshes of 4-6k triangles, stored once) orbit in a belt above a ground and tumble, inner ones faster, so neighbours drift apart: the instances move, the meshes do not (two-level trees update their instances' tree alone)",
    ),
];

/// An animated scene: its rest pose (time 0) and how its vertices move.
#[derive(Clone, Debug)]
pub struct Animation {
    /// The scene at time 0; every frame has its triangles and materials.
    rest: Scene,
    motion: Motion,
    /// Seconds the animation lasts; frames are defined on `0..=duration`.
    pub duration: f32,
}

#[derive(Clone, Debug)]
enum Motion {
    /// Vertices from `first` on move in triples (one unshared triangle
    /// each), each triple flying along `dirs[k]` and turning about `axes[k]`.
    Explode {
        first: usize,
        /// Per moving triangle: its centroid at rest, its velocity (units
        /// per second), its spin axis and rate (radians per second).
        centroids: Vec<Vec3>,
        velocities: Vec<Vec3>,
        axes: Vec<Vec3>,
        spins: Vec<f32>,
    },
    /// A glTF file's animations (node TRS, morph weights, skins) moving
    /// the flattened scene's vertices.
    Nodes(Box<super::gltf_motion::NodeMotion>),
    /// A glTF file's animations that move every placed mesh rigidly with
    /// its node: the instances move (the node of each instance given), the
    /// meshes do not.
    Placed(Box<(super::gltf_motion::NodeMotion, Vec<usize>)>),
    /// The instances move (each by its orbit), the meshes do not.
    Instances(Box<super::asteroids::Belt>),
    /// Vertices from `first` on are a `cols x rows` grid hanging in the
    /// plane z = `z0`, pinned at its left column.
    Cloth {
        first: usize,
        cols: usize,
        rows: usize,
        z0: f32,
        width: f32,
    },
}

/// Seconds of `explode:N`.
const EXPLODE_SECONDS: f32 = 2.0;
/// Seconds of one loop of `cloth:N`.
const CLOTH_SECONDS: f32 = 2.0;
/// Triangle counts `cloth:N` takes.
const CLOTH_TRIANGLES: std::ops::RangeInclusive<u64> = 100..=10_000_000;

/// A small hash of `k` to `[0, 1)`, so each fragment moves its own way and
/// every run the same way.
/// The still built-in `name`, which an animation starts from.
fn shape(name: &str) -> Result<Scene> {
    still(name)?.ok_or_else(|| Error::Other(format!("no still built-in scene {name}")))
}

fn unit_hash(k: u32, salt: u32) -> f32 {
    let mut x = k.wrapping_mul(0x9E37_79B9) ^ salt.wrapping_mul(0x85EB_CA6B);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846C_A68B);
    x ^= x >> 16;
    (x >> 8) as f32 / (1u32 << 24) as f32
}

/// Whether `path` names a glTF file (.gltf, .glb), the files animations are
/// read from.
fn is_gltf(path: &std::path::Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// Why scene `spec` (named by `flag`) is not an animation.
fn does_not_move(spec: &str, flag: &str) -> Error {
    if super::is_scene_file(spec) {
        let path = std::path::Path::new(spec);
        if is_gltf(path) {
            return super::gltf_motion::file_error(path, "the file has no animations".into());
        }
        return Error::usage(
            flag,
            format!("{spec} does not move: raylab reads animations from glTF files (.gltf, .glb) and has the animated built-ins explode:N, cloth:N and asteroids:N"),
        );
    }
    let names: Vec<&str> = ANIMATED_SCENES.iter().map(|(n, _)| *n).collect();
    Error::usage(
        flag,
        format!(
            "'{spec}' does not move: animated scenes are glTF files with animations and the built-ins {}",
            names.join(", ")
        ),
    )
}

impl Animation {
    /// The animation `name` names; `None` when `name` is not an animated
    /// built-in (a file or a still built-in), an error when it is one with a
    /// bad `N`.
    pub fn parse(name: &str) -> Option<Result<Animation>> {
        let (prefix, _) = name.split_once(':')?;
        match prefix {
            "explode" => Some(Self::explode(name)),
            "cloth" => Some(Self::cloth(name)),
            "asteroids" => Some(Self::asteroids(name)),
            _ => None,
        }
    }

    /// The animation `spec` names: an animated built-in, or a glTF file with
    /// animations (read where `policy` allows); an error for any other file
    /// or name, saying which scenes move.
    pub fn load(spec: &str, policy: super::refs::RefPolicy, flag: &str) -> Result<Animation> {
        Self::load_if_animated(spec, policy)?.ok_or_else(|| does_not_move(spec, flag))
    }

    /// The animation of scene `spec` if it moves: an animated built-in, or
    /// a glTF file with animations (`None` for any other scene or file, each
    /// read once); an error for a file that has animations raylab cannot
    /// follow, or that cannot be read, and for a built-in with a bad `N`.
    pub fn load_if_animated(
        spec: &str,
        policy: super::refs::RefPolicy,
    ) -> Result<Option<Animation>> {
        if !super::is_scene_file(spec) {
            return Animation::parse(spec).transpose();
        }
        let path = std::path::Path::new(spec);
        if !is_gltf(path) {
            return Ok(None);
        }
        let Some(followed) = super::gltf_motion::load(path, policy)? else {
            return Ok(None);
        };
        let file_error = |m| super::gltf_motion::file_error(path, m);
        match followed {
            Followed::Vertices(mut rest, motion) => {
                let duration = motion.duration;
                let mut positions = rest.positions.clone();
                motion
                    .positions_at(0.0, &mut positions)
                    .map_err(file_error)?;
                rest.positions = positions;
                Ok(Some(Animation {
                    rest,
                    motion: Motion::Nodes(Box::new(motion)),
                    duration,
                }))
            }
            Followed::Instances(placed, motion, nodes) => {
                let duration = motion.duration;
                let rest = placed
                    .moved_instances(&motion.transforms_at(0.0, &nodes).map_err(file_error)?)?;
                Ok(Some(Animation {
                    rest,
                    motion: Motion::Placed(Box::new((motion, nodes))),
                    duration,
                }))
            }
        }
    }

    fn explode(name: &str) -> Result<Animation> {
        let n = parse_count(name, "explode", MESH_TRIANGLES)?;
        let box_only = shape("cornell-empty")?;
        let mesh = shape(&format!("mesh:{n}"))?;
        // The box's triangles come first in every built-in: the rest is the
        // sphere, whose vertices are unshared here so its triangles can part.
        let keep = box_only.triangle_count();
        let first = mesh
            .triangles
            .iter()
            .take(keep)
            .flatten()
            .max()
            .map_or(0, |&m| m as usize + 1);
        let mut positions = mesh.positions[..first].to_vec();
        let mut triangles = mesh.triangles[..keep].to_vec();
        let centre = Vec3::new(0.0, 0.75, -0.1);
        let (mut centroids, mut velocities, mut axes, mut spins) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, tri) in mesh.triangles[keep..].iter().enumerate() {
            let verts = tri.map(|v| mesh.positions[v as usize]);
            let base = positions.len() as u32;
            positions.extend_from_slice(&verts);
            triangles.push([base, base + 1, base + 2]);
            let c = (verts[0] + verts[1] + verts[2]) / 3.0;
            let k = k as u32;
            // Outwards, at 0.15 to 0.6 units per second, a little upwards
            // or downwards of radial so that the shell does not just grow.
            let out = (c - centre).normalize_or(Vec3::Y);
            let speed = 0.15 + 0.45 * unit_hash(k, 1);
            let wobble = Vec3::new(unit_hash(k, 2), unit_hash(k, 3), unit_hash(k, 4)) - 0.5;
            centroids.push(c);
            velocities.push((out + 0.5 * wobble).normalize_or(out) * speed);
            let axis = Vec3::new(unit_hash(k, 5), unit_hash(k, 6), unit_hash(k, 7)) - 0.5;
            axes.push(axis.normalize_or(Vec3::X));
            spins.push(TAU * (0.25 + unit_hash(k, 8)));
        }
        let rest = Scene::new(
            name,
            positions,
            None,
            triangles,
            mesh.material_ids.clone(),
            mesh.materials.clone(),
        )?;
        Ok(Animation {
            rest: studied(rest, mesh.triangle_count())?,
            motion: Motion::Explode {
                first,
                centroids,
                velocities,
                axes,
                spins,
            },
            duration: EXPLODE_SECONDS,
        })
    }

    fn asteroids(name: &str) -> Result<Animation> {
        let n = parse_count(name, "asteroids", super::asteroids::INSTANCES)? as usize;
        let (rest, belt) = super::asteroids::asteroids(name, n)?;
        Ok(Animation {
            rest,
            motion: Motion::Instances(Box::new(belt)),
            duration: super::asteroids::SECONDS,
        })
    }

    /// Whether its instances move (and its meshes do not): a two-level tree
    /// follows it by updating the instances' tree alone.
    pub fn moves_instances(&self) -> bool {
        matches!(self.motion, Motion::Instances(_) | Motion::Placed(_))
    }

    fn cloth(name: &str) -> Result<Animation> {
        let n = parse_count(name, "cloth", CLOTH_TRIANGLES)? as usize;
        let base = shape("cornell-empty")?;
        // A grid of (cols - 1) x (rows - 1) quads, two triangles each, about
        // as wide as tall.
        let quads = (n / 2).max(1);
        let side = (quads as f64).sqrt().ceil() as usize;
        let (cols, rows) = (side + 1, quads.div_ceil(side) + 1);
        let (width, height, z0) = (1.4f32, 1.4f32, -0.2f32);
        let mut positions = base.positions.clone();
        let first = positions.len();
        for r in 0..rows {
            for c in 0..cols {
                positions.push(Vec3::new(
                    -0.7 + width * c as f32 / (cols - 1) as f32,
                    0.3 + height * r as f32 / (rows - 1) as f32,
                    z0,
                ));
            }
        }
        let mut triangles = base.triangles.clone();
        let mut material_ids = base.material_ids.clone();
        let mut materials = base.materials.clone();
        let cloth = materials.len() as u32;
        materials.push(Material::diffuse("cloth", Vec3::new(0.25, 0.35, 0.7)));
        let at = |r: usize, c: usize| (first + r * cols + c) as u32;
        let mut made = 0;
        'grid: for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                if made >= quads {
                    break 'grid;
                }
                triangles.push([at(r, c), at(r, c + 1), at(r + 1, c + 1)]);
                triangles.push([at(r, c), at(r + 1, c + 1), at(r + 1, c)]);
                material_ids.push(cloth);
                material_ids.push(cloth);
                made += 1;
            }
        }
        let count = triangles.len();
        let rest = Scene::new(name, positions, None, triangles, material_ids, materials)?;
        let mut anim = Animation {
            rest: studied(rest, count)?,
            motion: Motion::Cloth {
                first,
                cols,
                rows,
                z0,
                width,
            },
            duration: CLOTH_SECONDS,
        };
        // The rest pose is the cloth at time 0 (already waving).
        anim.rest.positions = anim.positions_at(0.0)?;
        Ok(anim)
    }

    /// The scene at time 0.
    pub fn rest(&self) -> &Scene {
        &self.rest
    }

    /// Refuses a time outside the animation (`flag` names where it came from).
    pub fn check_time(&self, t: f32, flag: &str) -> Result<()> {
        if !(t.is_finite() && (0.0..=self.duration).contains(&t)) {
            return Err(Error::usage(
                flag,
                format!(
                    "{} s is outside {}'s animation (0..={} s)",
                    t, self.rest.name, self.duration
                ),
            ));
        }
        Ok(())
    }

    /// Every vertex at time `t` seconds (in the rest pose's order); an
    /// error when a file's transforms overflow.
    pub fn positions_at(&self, t: f32) -> Result<Vec<Vec3>> {
        let mut p = self.rest.positions.clone();
        match &self.motion {
            Motion::Nodes(m) => m.positions_at(t, &mut p).map_err(|msg| Error::Scene {
                name: self.rest.name.clone(),
                msg,
            })?,
            // The meshes do not move; the instances do, in `frame`.
            Motion::Instances(_) | Motion::Placed(_) => {}
            Motion::Explode {
                first,
                centroids,
                velocities,
                axes,
                spins,
            } => {
                for (k, tri) in p[*first..].chunks_exact_mut(3).enumerate() {
                    let turn = Quat::from_axis_angle(axes[k], spins[k] * t);
                    let c = centroids[k];
                    let moved = c + velocities[k] * t;
                    for v in tri {
                        *v = moved + turn * (*v - c);
                    }
                }
            }
            Motion::Cloth {
                first,
                cols,
                rows,
                z0,
                width,
            } => {
                let phase = TAU * t / CLOTH_SECONDS;
                for r in 0..*rows {
                    for c in 0..*cols {
                        let v = &mut p[first + r * cols + c];
                        let along = (v.x + 0.7) / width; // 0 at the pinned edge
                        let y = v.y;
                        let wave = (3.0 * TAU * along / 2.0 - phase).sin()
                            + 0.5 * (TAU * (along + 0.7 * y) - 2.0 * phase).sin();
                        v.z = z0 + 0.18 * along * wave;
                    }
                }
            }
        }
        Ok(p)
    }

    /// The scene at time `t` seconds: the rest pose's triangles and
    /// materials, the vertices moved, no vertex normals, lights found anew;
    /// for moving instances, the rest pose's meshes with the instances moved.
    pub fn frame(&self, t: f32) -> Result<Scene> {
        match &self.motion {
            Motion::Instances(belt) => return self.rest.moved_instances(&belt.transforms_at(t)),
            Motion::Placed(placed) => {
                let (motion, nodes) = placed.as_ref();
                let transforms = motion.transforms_at(t, nodes).map_err(|msg| Error::Scene {
                    name: self.rest.name.clone(),
                    msg,
                })?;
                return self.rest.moved_instances(&transforms);
            }
            _ => {}
        }
        let mut s = self.rest.clone();
        s.positions = self.positions_at(t)?;
        s.normals = None;
        s.lights = s.find_lights();
        Ok(s)
    }
}

/// A built-in animation is framed as the study's boxes are; checks that
/// making the scene dropped no triangle (a frame must keep the topology).
fn studied(mut scene: Scene, made: usize) -> Result<Scene> {
    if scene.triangle_count() != made {
        return Err(Error::Other(format!(
            "{}: {} of {made} triangles were degenerate",
            scene.name,
            made - scene.triangle_count()
        )));
    }
    scene.study_frame = true;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_keep_the_topology_and_move_the_vertices() {
        for name in ["explode:2000", "cloth:2000"] {
            let anim = Animation::parse(name).unwrap().unwrap();
            let a = anim.frame(0.0).unwrap();
            let b = anim.frame(anim.duration * 0.5).unwrap();
            assert_eq!(a.triangles, b.triangles, "{name}");
            assert_eq!(a.material_ids, b.material_ids, "{name}");
            let moved = a
                .positions
                .iter()
                .zip(&b.positions)
                .filter(|(p, q)| (**p - **q).length() > 1e-3)
                .count();
            assert!(moved > a.positions.len() / 2, "{name}: {moved} moved");
            assert!(b.positions.iter().all(|p| p.is_finite()));
        }
    }

    #[test]
    fn the_explosion_leaves_the_sphere_bounds_and_keeps_triangle_areas() {
        let anim = Animation::parse("explode:1000").unwrap().unwrap();
        let a = anim.frame(0.0).unwrap();
        let b = anim.frame(anim.duration).unwrap();
        let area = |s: &Scene, i: usize| {
            let t = s.triangle(i);
            (t[1] - t[0]).cross(t[2] - t[0]).length()
        };
        for i in 0..a.triangle_count() {
            assert!((area(&a, i) - area(&b, i)).abs() <= 1e-4 * area(&a, i).max(1e-6));
        }
        let sphere = |s: &Scene| {
            (12..s.triangle_count())
                .flat_map(|i| s.triangle(i))
                .fold(crate::geometry::Aabb::EMPTY, |b, p| b.grown(p))
        };
        assert!(sphere(&b).extent().max_element() > 1.5 * sphere(&a).extent().max_element());
    }

    #[test]
    fn bad_names_and_times_are_refused() {
        assert!(Animation::parse("mesh:1000").is_none());
        assert!(Animation::parse("cornell-original").is_none());
        let err = Animation::parse("cloth:5")
            .unwrap()
            .unwrap_err()
            .to_string();
        assert!(err.contains("cloth:N"), "{err}");
        let anim = Animation::parse("cloth:200").unwrap().unwrap();
        let err = anim.check_time(3.0, "--time").unwrap_err().to_string();
        assert!(err.contains("--time") && err.contains("0..=2"), "{err}");
        assert!(anim.check_time(f32::NAN, "--time").is_err());
        assert!(anim.check_time(1.0, "--time").is_ok());
    }
}
