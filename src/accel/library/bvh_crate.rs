//! The bvh crate (svenstaro/bvh 0.13): its SAH builder (in parallel through
//! its rayon executor), one triangle per leaf, and its Moller-Trumbore test
//! (`Ray::intersects_triangle`, which culls back faces and needs t > f32
//! epsilon).
//!
//! The crate has no closest-hit or any-hit query; both are built here on the
//! traversals it offers, as a user of it would:
//! - closest hit walks `nearest_traverse_iterator`, which yields leaves in
//!   the order their boxes are entered, and stops once the next leaf's box
//!   is entered beyond the best hit;
//! - any hit walks `traverse_iterator` (every leaf whose box the ray meets)
//!   until a triangle is hit within `(0, tmax)`.
//!
//! Its rays have no `tmin` or `tmax` and its `Ray::new` normalises the
//! direction; the ray is made field by field instead, so `t` stays in the
//! caller's units.

use bvh::aabb::{Aabb, Bounded};
use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
use bvh::bvh::Bvh;
use bvh::ray::Ray as BvhRay;
use nalgebra::{Point3, Vector3};

use super::started_at_tmin;
use crate::accel::bvh::in_pool;
use crate::accel::Backend;
use crate::geometry::{Hit, Ray};
use crate::scene::MeshRef;

/// A scene triangle as the crate builds over it.
struct Shape {
    vertices: [Point3<f32>; 3],
    bounds: Aabb<f32, 3>,
    scene_index: u32,
    node_index: usize,
}

impl Bounded<f32, 3> for Shape {
    fn aabb(&self) -> Aabb<f32, 3> {
        self.bounds
    }
}

impl BHShape<f32, 3> for Shape {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node_index = index;
    }

    fn bh_node_index(&self) -> usize {
        self.node_index
    }
}

pub struct BvhCrateBackend {
    tree: Bvh<f32, 3>,
    shapes: Vec<Shape>,
}

fn point(v: glam::Vec3) -> Point3<f32> {
    Point3::new(v.x, v.y, v.z)
}

impl BvhCrateBackend {
    pub fn new(mesh: &MeshRef, threads: usize) -> Self {
        let mut shapes: Vec<Shape> = (0..mesh.triangle_count())
            .map(|i| {
                let vertices = mesh.triangle(i).map(point);
                let bounds = Aabb::empty()
                    .grow(&vertices[0])
                    .grow(&vertices[1])
                    .grow(&vertices[2]);
                Shape {
                    vertices,
                    bounds,
                    scene_index: i as u32,
                    node_index: 0,
                }
            })
            .collect();
        let tree = in_pool(threads, || {
            if threads > 1 {
                Bvh::build_par(&mut shapes)
            } else {
                Bvh::build(&mut shapes)
            }
        });
        BvhCrateBackend { tree, shapes }
    }

    /// The crate's ray for `ray` started at its tmin, the tmax left after
    /// the move, and the `t` to add back; `None` for a ray it cannot take
    /// (invalid, or moved out of f32's range).
    fn ray(ray: &Ray) -> Option<(BvhRay<f32, 3>, f32, f32)> {
        if !ray.is_valid() {
            return None;
        }
        let (origin, tmax, shift) = started_at_tmin(ray)?;
        let dir = Vector3::new(ray.dir.x, ray.dir.y, ray.dir.z);
        let r = BvhRay {
            origin: point(origin),
            direction: dir,
            inv_direction: dir.map(|x| 1.0 / x),
        };
        Some((r, tmax, shift))
    }
}

impl Backend for BvhCrateBackend {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let (r, tmax, shift) = Self::ray(ray)?;
        let mut best: Option<Hit> = None;
        let mut best_t = tmax;
        for shape in self.tree.nearest_traverse_iterator(&r, &self.shapes) {
            // Leaves come in the order their boxes are entered: none after
            // one entered beyond the best hit can be nearer.
            match r.intersection_slice_for_aabb(&shape.bounds) {
                Some((entry, _)) if entry > best_t => break,
                _ => {}
            }
            let [a, b, c] = &shape.vertices;
            let hit = r.intersects_triangle(a, b, c);
            if hit.distance < best_t {
                best_t = hit.distance;
                best = Some(Hit {
                    t: hit.distance + shift,
                    u: hit.u,
                    v: hit.v,
                    tri: shape.scene_index,
                    inst: 0,
                });
            }
        }
        best
    }

    fn occluded(&self, ray: &Ray) -> bool {
        let Some((r, tmax, _)) = Self::ray(ray) else {
            return false;
        };
        self.tree.traverse_iterator(&r, &self.shapes).any(|shape| {
            let [a, b, c] = &shape.vertices;
            r.intersects_triangle(a, b, c).distance < tmax
        })
    }

    fn memory_bytes(&self) -> Option<usize> {
        Some(
            std::mem::size_of_val(self.tree.nodes.as_slice())
                + std::mem::size_of_val(self.shapes.as_slice()),
        )
    }
}
