//! obvhs: its PLOC builder at one of its presets, traversed as its compressed
//! 8-wide `CwBvh` or its binary `Bvh2`, with its own Moller-Trumbore test
//! (`Triangle::intersect`) on triangles laid out in the tree's order, as its
//! examples do. Closest hit is `ray_traverse`, any hit `ray_traverse_miss`.
//!
//! obvhs returns only `t`; the barycentrics are computed afterwards with the
//! expression its own test uses (edges v0 - v1 and v2 - v0, Embree's form).

use std::time::Duration;

use glam_obvhs::Vec3A;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray as ObvhsRay, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::ObvhsLayout;
use crate::accel::bvh::in_pool;
use crate::accel::embree::Quality;
use crate::accel::Backend;
use crate::geometry::{Hit, Ray};
use crate::scene::MeshRef;

enum Tree {
    CwBvh(CwBvh),
    Bvh2(Bvh2),
    Empty,
}

pub struct ObvhsBackend {
    tree: Tree,
    /// The triangles in the tree's order (`primitive_indices`).
    triangles: Vec<Triangle>,
    /// The scene's index of each of `triangles`.
    scene_index: Vec<u32>,
}

/// The obvhs preset for a rung of the quality ladder.
pub const fn preset(quality: Quality) -> BvhBuildParams {
    match quality {
        Quality::Low => BvhBuildParams::fast_build(),
        Quality::Medium => BvhBuildParams::medium_build(),
        Quality::High => BvhBuildParams::slow_build(),
    }
}

fn vec3a(v: glam::Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

impl ObvhsBackend {
    pub fn new(mesh: &MeshRef, layout: ObvhsLayout, quality: Quality, threads: usize) -> Self {
        let input: Vec<Triangle> = (0..mesh.triangle_count())
            .map(|i| {
                let [v0, v1, v2] = mesh.triangle(i);
                Triangle {
                    v0: vec3a(v0),
                    v1: vec3a(v1),
                    v2: vec3a(v2),
                }
            })
            .collect();
        if input.is_empty() {
            return ObvhsBackend {
                tree: Tree::Empty,
                triangles: Vec::new(),
                scene_index: Vec::new(),
            };
        }
        let params = preset(quality);
        let mut core_time = Duration::default();
        // obvhs's parallel parts run on the rayon pool they are called in.
        let (tree, order) = in_pool(threads, || match layout {
            ObvhsLayout::CwBvh => {
                let tree =
                    obvhs::cwbvh::builder::build_cwbvh_from_tris(&input, params, &mut core_time);
                let order = tree.primitive_indices.clone();
                (Tree::CwBvh(tree), order)
            }
            ObvhsLayout::Bvh2 => {
                let tree =
                    obvhs::bvh2::builder::build_bvh2_from_tris(&input, params, &mut core_time);
                let order = tree.primitive_indices.clone();
                (Tree::Bvh2(tree), order)
            }
        });
        let triangles = order.iter().map(|&i| input[i as usize]).collect();
        ObvhsBackend {
            tree,
            triangles,
            scene_index: order,
        }
    }

    fn ray(ray: &Ray) -> ObvhsRay {
        ObvhsRay::new(vec3a(ray.origin), vec3a(ray.dir), ray.tmin, ray.tmax)
    }
}

impl Backend for ObvhsBackend {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let r = Self::ray(ray);
        let mut hit = RayHit::none();
        let test = |r: &ObvhsRay, id: usize| self.triangles[id].intersect(r);
        let found = match &self.tree {
            Tree::CwBvh(tree) => tree.ray_traverse(r, &mut hit, test),
            Tree::Bvh2(tree) => tree.ray_traverse(r, &mut hit, test),
            Tree::Empty => false,
        };
        if !found {
            return None;
        }
        let id = hit.primitive_id as usize;
        let tri = &self.triangles[id];
        let (e1, e2) = (tri.v0 - tri.v1, tri.v2 - tri.v0);
        let r_vec = r.direction.cross(tri.v0 - r.origin);
        let inv_det = 1.0 / e1.cross(e2).dot(r.direction);
        Some(Hit {
            t: hit.t,
            u: r_vec.dot(e2) * inv_det,
            v: r_vec.dot(e1) * inv_det,
            tri: self.scene_index[id],
        })
    }

    fn occluded(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let r = Self::ray(ray);
        let test = |r: &ObvhsRay, id: usize| self.triangles[id].intersect(r);
        let missed = match &self.tree {
            Tree::CwBvh(tree) => tree.ray_traverse_miss(r, test),
            Tree::Bvh2(tree) => tree.ray_traverse_miss(r, test),
            Tree::Empty => true,
        };
        !missed
    }

    fn memory_bytes(&self) -> Option<usize> {
        let nodes = match &self.tree {
            Tree::CwBvh(tree) => std::mem::size_of_val(tree.nodes.as_slice()),
            Tree::Bvh2(tree) => std::mem::size_of_val(tree.nodes.as_slice()),
            Tree::Empty => 0,
        };
        Some(
            nodes
                + std::mem::size_of_val(self.triangles.as_slice())
                + std::mem::size_of_val(self.scene_index.as_slice()),
        )
    }
}
