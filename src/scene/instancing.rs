//! Instanced scenes: meshes stored once, placed by instances (a mesh and an
//! affine transform), as glTF nodes place meshes and as Embree's instance
//! geometry, tinybvh's TLAS and every GPU API's TLAS/BLAS split trace them.
//!
//! The model stays flat: a [`Scene`] whose triangle arrays hold the unique
//! meshes one after another (each mesh a range of triangles, in its own
//! space), and an [`Instancing`] beside them listing the ranges and the
//! instances. A hit names the triangle and the instance it was hit through
//! ([`crate::geometry::Hit::inst`]); the shader asks the scene for the world
//! triangle ([`Scene::hit_triangle`]). [`Scene::flattened`] bakes the
//! instances into one world-space list, numbered instance by instance, which
//! is the order the closest-hit tie-break follows, so a two-level tree and a
//! flattened one answer alike up to the transform's rounding.

use std::sync::Arc;

use glam::{Affine3A, Vec3, Vec3A};
use rayon::prelude::*;

pub use super::placement::{Instance, Instancing};
use super::{budget, Lights, Scene};
use crate::error::{Error, Result};
use crate::geometry::{spawn_origin_padded, triangle_area, Aabb, Hit};

impl Scene {
    /// An instanced scene: `meshes` (each a scene in its own space: its
    /// degenerate triangles already dropped, its materials its own) placed
    /// by `placements` (mesh index and mesh-to-world transform). Fails for a
    /// placement naming no mesh, a transform that cannot be inverted, more
    /// than 2^32 instances, or none.
    pub fn instanced(
        name: impl Into<String>,
        meshes: Vec<Scene>,
        placements: Vec<(u32, Affine3A)>,
    ) -> Result<Scene> {
        let name = name.into();
        let fail = |msg: String| Error::Scene {
            name: name.clone(),
            msg,
        };
        if placements.is_empty() {
            return Err(fail("no instances".into()));
        }
        if u32::try_from(placements.len()).is_err() {
            return Err(fail(format!("{} instances, over 2^32", placements.len())));
        }
        let has_normals = meshes.iter().any(|m| m.normals.is_some());
        let mut positions = Vec::new();
        let mut normals = has_normals.then(Vec::new);
        let mut triangles = Vec::new();
        let mut material_ids = Vec::new();
        let mut materials = Vec::new();
        let mut ranges = Vec::with_capacity(meshes.len());
        let mut mesh_bounds = Vec::with_capacity(meshes.len());
        let mut warnings = Vec::new();
        let mut mesh_dropped = Vec::with_capacity(meshes.len());
        for mesh in meshes {
            let (v0, m0, t0) = (
                positions.len() as u32,
                materials.len() as u32,
                triangles.len() as u32,
            );
            mesh_bounds.push(mesh.bounds());
            if let Some(n) = &mut normals {
                match &mesh.normals {
                    Some(own) => n.extend_from_slice(own),
                    None => n.extend(std::iter::repeat_n(Vec3::ZERO, mesh.positions.len())),
                }
            }
            positions.extend_from_slice(&mesh.positions);
            triangles.extend(mesh.triangles.iter().map(|t| t.map(|v| v + v0)));
            material_ids.extend(mesh.material_ids.iter().map(|m| m + m0));
            materials.extend(mesh.materials);
            ranges.push(t0..triangles.len() as u32);
            mesh_dropped.push(mesh.dropped_degenerate);
            // Its dropped triangles are counted once for the scene, as placed.
            let own = super::dropped_warning(mesh.dropped_degenerate);
            warnings.extend(mesh.warnings.into_iter().filter(|w| *w != own));
        }
        let mut instances = Vec::with_capacity(placements.len());
        let mut first = Vec::with_capacity(placements.len());
        // Counted as placed, as a flattened copy would have dropped them.
        let mut dropped = 0;
        let mut placed = 0u64;
        for (i, (mesh, to_world)) in placements.into_iter().enumerate() {
            let Some(range) = ranges.get(mesh as usize) else {
                return Err(fail(format!(
                    "instance {i} places mesh {mesh}, which does not exist"
                )));
            };
            let inst =
                Instance::new(mesh, to_world).map_err(|e| fail(format!("instance {i}: {e}")))?;
            first.push(placed);
            placed += range.len() as u64;
            dropped += mesh_dropped[mesh as usize];
            instances.push(inst);
        }
        if placed == 0 {
            return Err(fail("its instances place no triangles".into()));
        }
        if dropped > 0 {
            warnings.push(format!(
                "{} (as placed by the instances; {} in the meshes)",
                super::dropped_warning(dropped),
                mesh_dropped.iter().sum::<usize>()
            ));
        }
        let mut scene = Scene {
            name,
            positions,
            normals,
            triangles,
            material_ids,
            materials,
            lights: Lights::default(),
            dropped_degenerate: dropped,
            warnings,
            study_frame: false,
            framed_bounds: None,
            instancing: Some(Arc::new(Instancing {
                meshes: ranges,
                instances,
                mesh_bounds,
                first,
            })),
        };
        scene.lights = scene.find_instanced_lights();
        Ok(scene)
    }

    /// The same meshes and instances, each instance moved to its transform
    /// in `transforms` (one per instance, in order): a frame of a scene whose
    /// instances move. Lights are found anew (their world areas change with a
    /// scale); fails for a count that is not the instances' or a transform
    /// [`Instance::new`] refuses.
    pub fn moved_instances(&self, transforms: &[Affine3A]) -> Result<Scene> {
        let Some(inst) = &self.instancing else {
            return Err(Error::Scene {
                name: self.name.clone(),
                msg: "has no instances to move".into(),
            });
        };
        if transforms.len() != inst.instances.len() {
            return Err(Error::Scene {
                name: self.name.clone(),
                msg: format!(
                    "{} transforms for {} instances",
                    transforms.len(),
                    inst.instances.len()
                ),
            });
        }
        let instances = inst
            .instances
            .par_iter()
            .zip(transforms)
            .enumerate()
            .map(|(i, (old, m))| {
                Instance::new(old.mesh, *m).map_err(|e| Error::Scene {
                    name: self.name.clone(),
                    msg: format!("instance {i}: {e}"),
                })
            })
            .collect::<Result<Vec<Instance>>>()?;
        let mut scene = self.clone();
        scene.instancing = Some(Arc::new(Instancing {
            meshes: inst.meshes.clone(),
            instances,
            mesh_bounds: inst.mesh_bounds.clone(),
            first: inst.first.clone(),
        }));
        scene.framed_bounds = None;
        scene.lights = scene.find_instanced_lights();
        Ok(scene)
    }

    /// Whether the scene places meshes by instances.
    pub fn is_instanced(&self) -> bool {
        self.instancing.is_some()
    }

    /// Triangles as traced: each instance's mesh counted once per instance
    /// (the triangle count of a scene without instances).
    pub fn placed_triangle_count(&self) -> u64 {
        match &self.instancing {
            Some(i) => i.placed_triangles(),
            None => self.triangle_count() as u64,
        }
    }

    /// Instances (1 for a scene without instances).
    pub fn instance_count(&self) -> usize {
        self.instancing.as_ref().map_or(1, |i| i.instances.len())
    }

    /// The world-space vertices of the triangle `hit` names.
    #[inline]
    pub fn hit_triangle(&self, hit: &Hit) -> [Vec3; 3] {
        self.placed_triangle(hit.tri, hit.inst)
    }

    /// The world-space vertices of triangle `tri` as instance `inst` places
    /// it (in a flat scene, `inst` is unused and the triangle is its own).
    #[inline]
    pub fn placed_triangle(&self, tri: u32, inst: u32) -> [Vec3; 3] {
        let tri = self.triangle(tri as usize);
        match &self.instancing {
            Some(i) => {
                let inst = &i.instances[inst as usize];
                let [a, b, c] = tri.map(|p| inst.to_world.transform_point3(p));
                if inst.mirrored {
                    [a, c, b]
                } else {
                    [a, b, c]
                }
            }
            None => tri,
        }
    }

    /// [`Scene::shading_normal`] at `hit`, in world space (normals move by
    /// the inverse transpose of the instance's transform).
    pub fn hit_shading_normal(&self, hit: &Hit) -> Option<Vec3> {
        let n = self.shading_normal(hit.tri, hit.u, hit.v)?;
        match &self.instancing {
            Some(i) => {
                let inv = i.instances[hit.inst as usize].to_local.matrix3;
                let w = Vec3::from(inv.transpose() * Vec3A::from(n)).normalize_or_zero();
                (w != Vec3::ZERO && w.is_finite()).then_some(w)
            }
            None => Some(n),
        }
    }

    /// Where the secondary rays of `hit` start, leaving on the side of the
    /// world-space unit normal `n`: [`crate::geometry::spawn_origin`] in the
    /// mesh's space, padded by the error of moving the point to world space
    /// and back (what an instanced backend does to the ray), so the ray also
    /// starts on the right side of the triangle as the instance's tree sees it.
    pub fn spawn_point(&self, hit: &Hit, n: Vec3) -> Vec3 {
        let tri = self.triangle(hit.tri as usize);
        let Some(i) = &self.instancing else {
            return spawn_origin_padded(&tri, hit.u, hit.v, n, Vec3::ZERO);
        };
        let inst = &i.instances[hit.inst as usize];
        let n_local =
            Vec3::from(inst.to_world.matrix3.transpose() * Vec3A::from(n)).normalize_or_zero();
        let far = tri[0].abs().max(tri[1].abs()).max(tri[2].abs());
        let local = spawn_origin_padded(&tri, hit.u, hit.v, n_local, inst.round_trip_error(far));
        inst.to_world.transform_point3(local)
    }

    /// The world-space vertices of light `k` (an index into
    /// `lights.triangles`).
    pub fn light_triangle(&self, k: usize) -> [Vec3; 3] {
        let tri = self.lights.triangles[k];
        let inst = self.lights.instances.get(k).copied().unwrap_or(0);
        self.hit_triangle(&Hit {
            t: 0.0,
            u: 0.0,
            v: 0.0,
            tri,
            inst,
        })
    }

    /// Emissive triangles once per instance, with their world areas.
    fn find_instanced_lights(&self) -> Lights {
        let Some(inst) = &self.instancing else {
            return self.find_lights();
        };
        let emissive: Vec<Vec<u32>> = inst
            .meshes
            .iter()
            .map(|r| {
                r.clone()
                    .filter(|&t| self.material_of(t).is_emissive())
                    .collect()
            })
            .collect();
        let (mut triangles, mut instances, mut cumulative) = (Vec::new(), Vec::new(), Vec::new());
        let mut total = 0.0f64;
        for (i, placed) in inst.instances.iter().enumerate() {
            for &t in &emissive[placed.mesh as usize] {
                let world = self.hit_triangle(&Hit {
                    t: 0.0,
                    u: 0.0,
                    v: 0.0,
                    tri: t,
                    inst: i as u32,
                });
                total += triangle_area(&world) as f64;
                triangles.push(t);
                instances.push(i as u32);
                cumulative.push(total);
            }
        }
        Lights {
            extra: None,
            triangles,
            instances,
            cdf: cumulative.iter().map(|&c| (c / total) as f32).collect(),
            total_area: total as f32,
        }
    }

    /// World bounds of an instanced scene: each instance's mesh box moved
    /// by its transform.
    pub(super) fn instanced_bounds(inst: &Instancing) -> Aabb {
        (0..inst.instances.len())
            .into_par_iter()
            .map(|i| inst.world_box(i))
            .reduce(|| Aabb::EMPTY, Aabb::union)
    }

    /// The scene with its instances baked into one world-space triangle
    /// list, numbered instance by instance (instance `i`'s triangle `t` is
    /// triangle `first[i] + t - mesh start`); the scene itself when it has
    /// no instances. Fails past the triangle budget, naming it.
    pub fn flattened(&self) -> Result<Scene> {
        let Some(inst) = &self.instancing else {
            return Ok(self.clone());
        };
        let placed = inst.placed_triangles();
        if let Some(msg) = budget::triangles_over(placed) {
            return Err(Error::Scene {
                name: self.name.clone(),
                msg: format!("flattened, {msg}; trace its instances with a two-level tree instead of flattening it"),
            });
        }
        let n = placed as usize;
        let mut positions = Vec::with_capacity(3 * n);
        let mut normals = self.normals.as_ref().map(|_| Vec::with_capacity(3 * n));
        let mut triangles = Vec::with_capacity(n);
        let mut material_ids = Vec::with_capacity(n);
        for placed in &inst.instances {
            let normal_matrix = placed.to_local.matrix3.transpose();
            for t in inst.meshes[placed.mesh as usize].clone() {
                let v0 = positions.len() as u32;
                for v in self.triangles[t as usize] {
                    positions.push(placed.to_world.transform_point3(self.positions[v as usize]));
                    if let (Some(out), Some(own)) = (&mut normals, &self.normals) {
                        let n = own[v as usize];
                        out.push(Vec3::from(normal_matrix * Vec3A::from(n)).normalize_or_zero());
                    }
                }
                triangles.push(if placed.mirrored {
                    [v0, v0 + 2, v0 + 1]
                } else {
                    [v0, v0 + 1, v0 + 2]
                });
                material_ids.push(self.material_ids[t as usize]);
            }
        }
        let mut flat = Scene {
            name: self.name.clone(),
            positions,
            normals,
            triangles,
            material_ids,
            materials: self.materials.clone(),
            lights: Lights::default(),
            dropped_degenerate: self.dropped_degenerate,
            warnings: self.warnings.clone(),
            study_frame: self.study_frame,
            instancing: None,
            framed_bounds: Some(self.bounds()),
        };
        flat.lights = flat.find_lights();
        flat.lights.extra = self.lights.extra;
        Ok(flat)
    }

    /// The index `hit` has in [`Scene::flattened`]'s triangle list.
    pub fn flat_index(&self, hit: &Hit) -> u64 {
        match &self.instancing {
            Some(i) => i.flat_index(hit),
            None => u64::from(hit.tri),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Material;

    fn quad() -> Scene {
        Scene::new(
            "quad",
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            None,
            vec![[0, 1, 2], [0, 2, 3]],
            vec![0, 0],
            vec![Material::default_grey()],
        )
        .unwrap()
    }

    #[test]
    fn instances_place_meshes_and_flatten_in_instance_order() {
        let moved = Affine3A::from_translation(Vec3::new(5.0, 0.0, 0.0))
            * Affine3A::from_scale(Vec3::splat(2.0));
        let s = Scene::instanced(
            "t",
            vec![quad(), quad()],
            vec![(0, Affine3A::IDENTITY), (1, moved), (0, moved)],
        )
        .unwrap();
        assert_eq!(s.triangle_count(), 4);
        assert_eq!(s.placed_triangle_count(), 6);
        assert_eq!(s.instance_count(), 3);
        let b = s.bounds();
        assert_eq!((b.min, b.max), (Vec3::ZERO, Vec3::new(7.0, 2.0, 0.0)));
        let flat = s.flattened().unwrap();
        assert_eq!(flat.triangle_count(), 6);
        // Instance 1 places mesh 1 (triangles 2 and 3): its second triangle
        // is the flattened scene's fourth.
        let hit = Hit {
            t: 1.0,
            u: 0.0,
            v: 0.0,
            tri: 3,
            inst: 1,
        };
        assert_eq!(s.flat_index(&hit), 3);
        assert_eq!(s.hit_triangle(&hit), flat.triangle(3));
        let hit = Hit {
            tri: 0,
            inst: 2,
            ..hit
        };
        assert_eq!(s.flat_index(&hit), 4);
        assert_eq!(s.hit_triangle(&hit), flat.triangle(4));
    }

    #[test]
    fn bad_instances_are_refused() {
        let flat = Affine3A::from_scale(Vec3::new(1.0, 1.0, 0.0));
        let err = Scene::instanced("t", vec![quad()], vec![(0, flat)]).unwrap_err();
        assert!(
            err.to_string()
                .contains("instance 0: its transform is not invertible"),
            "{err}"
        );
        let err = Scene::instanced("t", vec![quad()], vec![(1, Affine3A::IDENTITY)]).unwrap_err();
        assert!(
            err.to_string().contains("mesh 1, which does not exist"),
            "{err}"
        );
        let nan = Affine3A::from_translation(Vec3::NAN);
        assert!(Scene::instanced("t", vec![quad()], vec![(0, nan)]).is_err());
        assert!(Scene::instanced("t", vec![quad()], vec![]).is_err());
    }

    #[test]
    fn lights_are_placed_once_per_instance_with_world_areas() {
        let mut light = quad();
        light.materials[0].ke = Vec3::ONE;
        let light = Scene::new(
            "l",
            light.positions,
            None,
            light.triangles,
            light.material_ids,
            light.materials,
        )
        .unwrap();
        let big = Affine3A::from_scale(Vec3::splat(3.0));
        let s =
            Scene::instanced("t", vec![light], vec![(0, Affine3A::IDENTITY), (0, big)]).unwrap();
        assert_eq!(s.lights.triangles, vec![0, 1, 0, 1]);
        assert_eq!(s.lights.instances, vec![0, 0, 1, 1]);
        assert!((s.lights.total_area - 10.0).abs() < 1e-5);
        assert_eq!(s.light_triangle(2), s.flattened().unwrap().triangle(2));
    }

    #[test]
    fn spawn_points_survive_the_round_trip_into_the_instance() {
        let mut rng = crate::rng::Rng::for_pixel(7, 1, 0);
        // A mesh near its origin placed far from the world's: the round trip
        // rounds at the world's coarse spacing, far above the mesh's own.
        let tri = [
            Vec3::new(0.1, 0.3, -0.2),
            Vec3::new(1.5, 0.2, -0.2),
            Vec3::new(0.2, 1.9, 0.3),
        ];
        let mesh = Scene::new(
            "m",
            tri.to_vec(),
            None,
            vec![[0, 1, 2]],
            vec![0],
            vec![Material::default_grey()],
        )
        .unwrap();
        for _ in 0..200 {
            let axis = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32() + 0.1).normalize();
            let m = Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.01 + 100.0 * rng.next_f32()),
                glam::Quat::from_axis_angle(axis, 6.0 * rng.next_f32()),
                Vec3::new(1e6 * rng.next_f32(), -3e5, 7e5 * rng.next_f32()),
            );
            let s = Scene::instanced("t", vec![mesh.clone()], vec![(0, m)]).unwrap();
            let world = s.hit_triangle(&Hit {
                t: 0.0,
                u: 0.0,
                v: 0.0,
                tri: 0,
                inst: 0,
            });
            let n = crate::geometry::triangle_unit_normal(&world);
            let (u, v) = (rng.next_f32() * 0.5, rng.next_f32() * 0.5);
            let hit = Hit {
                t: 1.0,
                u,
                v,
                tri: 0,
                inst: 0,
            };
            for side in [n, -n] {
                let o = s.spawn_point(&hit, side);
                // The instance's tree sees the origin moved back into mesh
                // space; in f64 it must lie on `side`'s side of the plane.
                let local = s.instancing.as_ref().unwrap().instances[0]
                    .to_local
                    .transform_point3(o);
                let d = |p: Vec3| p.as_dvec3();
                let plane_n = (d(tri[1]) - d(tri[0])).cross(d(tri[2]) - d(tri[0]));
                let side_local = d(Vec3::from(m.matrix3.transpose() * Vec3A::from(side)));
                let dist = (d(local) - d(tri[0])).dot(plane_n) * plane_n.dot(side_local).signum();
                assert!(dist > 0.0, "{dist} at scale {:?}", m.matrix3);
            }
        }
    }
}
