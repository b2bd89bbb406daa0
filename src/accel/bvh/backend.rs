//! raylab's BVH as a render [`Backend`]: a [`Tree`] and the ray/triangle test
//! its leaves use.

use super::builder::build;
use super::params::BuildParams;
use super::prim::Triangles;
use super::traverse::Traversal;
use super::tree::Tree;
use crate::accel::Backend;
use crate::geometry::{Hit, Intersector, Ray};

/// The BVH as a render [`Backend`].
pub struct BvhBackend {
    pub tree: Tree,
    intersector: Intersector,
}

impl BvhBackend {
    /// Builds the tree `params` describe over `triangles` (a scene, a mesh,
    /// or raw vertex triples with degenerate ones included) with
    /// Moller-Trumbore for the triangle tests.
    pub fn new<T: Triangles + ?Sized>(triangles: &T, params: &BuildParams) -> crate::Result<Self> {
        Ok(BvhBackend {
            tree: build(triangles, params)?,
            intersector: Intersector::Mt,
        })
    }

    /// Uses `intersector` for the triangle tests.
    pub fn with_intersector(mut self, intersector: Intersector) -> Self {
        self.intersector = intersector;
        self
    }
}

impl Backend for BvhBackend {
    fn memory_bytes(&self) -> Option<usize> {
        Some(self.tree.memory_bytes())
    }

    #[inline]
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.tree.intersect_using(ray, self.intersector)
    }

    #[inline]
    fn occluded(&self, ray: &Ray) -> bool {
        self.tree.occluded_using(ray, self.intersector)
    }
}
