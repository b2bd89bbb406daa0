//! The naive backend: every ray is tested against every triangle, as in the
//! study's baseline. O(N) per ray; the reference the other backends must match.

use glam::Vec3;

use super::Backend;
use crate::geometry::{Hit, Intersector, MollerTrumbore, Ray, TriangleTest, Watertight};
use crate::scene::Scene;

pub struct Naive {
    triangles: Vec<[Vec3; 3]>,
    intersector: Intersector,
}

impl Naive {
    /// Over the scene's triangles (gathered in index order).
    pub fn new(scene: &Scene) -> Self {
        Self::from_triangles(scene.triangle_vertices())
    }

    /// Over raw triangles (degenerate ones included).
    pub fn from_triangles(triangles: Vec<[Vec3; 3]>) -> Self {
        Naive {
            triangles,
            intersector: Intersector::Mt,
        }
    }

    /// Uses `intersector` for the triangle tests.
    pub fn with_intersector(mut self, intersector: Intersector) -> Self {
        self.intersector = intersector;
        self
    }

    fn closest<T: TriangleTest>(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let prepared = T::prepare(ray);
        let mut ray = *ray;
        let mut best: Option<Hit> = None;
        for (i, tri) in self.triangles.iter().enumerate() {
            // Triangles are visited in index order and only a strictly nearer hit
            // replaces the best one, so equal-t ties keep the lowest index.
            if let Some((t, u, v)) = T::test(&prepared, &ray, tri) {
                ray.tmax = t;
                best = Some(Hit {
                    t,
                    u,
                    v,
                    tri: i as u32,
                    inst: 0,
                });
            }
        }
        best
    }

    fn any<T: TriangleTest>(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let prepared = T::prepare(ray);
        self.triangles
            .iter()
            .any(|tri| T::test(&prepared, ray, tri).is_some())
    }
}

impl Backend for Naive {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match self.intersector {
            Intersector::Mt => self.closest::<MollerTrumbore>(ray),
            Intersector::Watertight => self.closest::<Watertight>(ray),
        }
    }

    fn occluded(&self, ray: &Ray) -> bool {
        match self.intersector {
            Intersector::Mt => self.any::<MollerTrumbore>(ray),
            Intersector::Watertight => self.any::<Watertight>(ray),
        }
    }
}
