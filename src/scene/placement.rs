//! Where meshes are placed: an instance is a mesh and its affine transform,
//! and [`Instancing`] lists each mesh's triangle range and the instances. The
//! scene holds one beside its flat arrays; src/scene/instancing.rs is what an
//! instanced scene does with it.

use std::ops::Range;

use glam::{Affine3A, Mat3A, Vec3, Vec3A};

use crate::geometry::{Aabb, Hit, GAMMA3};

/// One placement of a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index into [`Instancing::meshes`].
    pub mesh: u32,
    /// Mesh space to world space.
    pub to_world: Affine3A,
    /// World space to mesh space (the inverse, computed once).
    pub to_local: Affine3A,
    /// The transform mirrors (negative determinant): the world triangle's
    /// winding is the mesh's reversed, so the scene turns it back (a glTF
    /// mirrored node's triangles keep their front faces, as when flattened).
    pub mirrored: bool,
}

impl Instance {
    /// An instance of `mesh` placed by `to_world`; fails for a transform that
    /// is not finite or not invertible (a zero scale flattens the mesh into a
    /// plane or a point no ray can be moved into).
    pub fn new(mesh: u32, to_world: Affine3A) -> std::result::Result<Instance, String> {
        let m = to_world.matrix3;
        let finite = m.is_finite() && to_world.translation.is_finite();
        let det = m.determinant();
        if !finite || !det.is_normal() {
            return Err(format!(
                "its transform is {} (determinant {det:e})",
                if finite {
                    "not invertible"
                } else {
                    "not finite"
                }
            ));
        }
        let to_local = to_world.inverse();
        if !(to_local.matrix3.is_finite() && to_local.translation.is_finite()) {
            return Err("its transform's inverse is not finite".into());
        }
        Ok(Instance {
            mesh,
            to_world,
            to_local,
            mirrored: det < 0.0,
        })
    }

    /// A bound on the error of moving a point near `p` (mesh space) to world
    /// space and back in f32, per component: each affine transform's
    /// rounding is at most gamma(3) of |M| |x| + |t| (pbrt-v4's transform
    /// error bound), and the way back scales the first error by |M^-1|.
    pub fn round_trip_error(&self, p: Vec3) -> Vec3 {
        let abs = |m: Mat3A| Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let (m, inv) = (abs(self.to_world.matrix3), abs(self.to_local.matrix3));
        let p = Vec3A::from(p).abs();
        let world = m * p + self.to_world.translation.abs();
        let out = world * (1.0 + GAMMA3);
        let back = inv * (out * GAMMA3) + (inv * out + self.to_local.translation.abs()) * GAMMA3;
        Vec3::from(back * 2.0)
    }
}

/// The meshes and their instances.
#[derive(Clone, Debug, Default)]
pub struct Instancing {
    /// Each mesh's triangles in the scene's arrays.
    pub meshes: Vec<Range<u32>>,
    pub instances: Vec<Instance>,
    /// Each mesh's bounds in its own space.
    pub mesh_bounds: Vec<Aabb>,
    /// `first[i]`: the flattened index of instance `i`'s first triangle.
    pub first: Vec<u64>,
}

impl Instancing {
    /// Triangles the instances place, counted once per instance.
    pub fn placed_triangles(&self) -> u64 {
        match self.instances.last() {
            Some(last) => {
                self.first[self.first.len() - 1] + self.meshes[last.mesh as usize].len() as u64
            }
            None => 0,
        }
    }

    /// The index `hit` has in the flattened scene's triangle list.
    pub fn flat_index(&self, hit: &Hit) -> u64 {
        let placed = &self.instances[hit.inst as usize];
        self.first[hit.inst as usize] + u64::from(hit.tri - self.meshes[placed.mesh as usize].start)
    }

    /// Instance `i`'s box in world space (its mesh's box, transformed).
    pub fn world_box(&self, i: usize) -> Aabb {
        let inst = &self.instances[i];
        transformed_box(&inst.to_world, &self.mesh_bounds[inst.mesh as usize])
    }
}

/// The box around `b`'s eight corners moved by `m`.
pub fn transformed_box(m: &Affine3A, b: &Aabb) -> Aabb {
    if b.is_empty() {
        return Aabb::EMPTY;
    }
    let mut out = Aabb::EMPTY;
    for corner in 0..8 {
        let p = Vec3::new(
            if corner & 1 == 0 { b.min.x } else { b.max.x },
            if corner & 2 == 0 { b.min.y } else { b.max.y },
            if corner & 4 == 0 { b.min.z } else { b.max.z },
        );
        out = out.grown(m.transform_point3(p));
    }
    out
}
