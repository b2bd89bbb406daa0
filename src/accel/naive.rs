//! The naive backend: every ray is tested against every triangle, as in the
//! study's baseline. O(N) per ray; the reference the other backends must match.

use std::time::{Duration, Instant};

use glam::Vec3;

use super::Backend;
use crate::geometry::{intersect_triangle, Hit, Ray};
use crate::scene::Scene;

pub struct Naive {
    triangles: Vec<[Vec3; 3]>,
    build_time: Duration,
}

impl Naive {
    pub fn new(scene: &Scene) -> Self {
        let start = Instant::now();
        let triangles = scene.triangle_vertices();
        Naive {
            triangles,
            build_time: start.elapsed(),
        }
    }

    /// A naive backend over raw triangles (tests and benches).
    pub fn from_triangles(triangles: Vec<[Vec3; 3]>) -> Self {
        Naive {
            triangles,
            build_time: Duration::ZERO,
        }
    }
}

impl Backend for Naive {
    fn name(&self) -> String {
        "naive".into()
    }

    fn build_time(&self) -> Duration {
        self.build_time
    }

    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let mut ray = *ray;
        let mut best: Option<Hit> = None;
        for (i, tri) in self.triangles.iter().enumerate() {
            // Triangles are visited in index order and only a strictly nearer hit
            // replaces the best one, so equal-t ties keep the lowest index.
            if let Some((t, u, v)) = intersect_triangle(&ray, tri) {
                ray.tmax = t;
                best = Some(Hit {
                    t,
                    u,
                    v,
                    tri: i as u32,
                });
            }
        }
        best
    }

    fn occluded(&self, ray: &Ray) -> bool {
        ray.is_valid()
            && self
                .triangles
                .iter()
                .any(|tri| intersect_triangle(ray, tri).is_some())
    }
}
