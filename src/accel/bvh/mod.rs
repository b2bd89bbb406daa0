//! Bounding volume hierarchies built by hand: one flat layout shared by every
//! builder ([`build`]), one traversal ([`traverse`]) and the quality metrics that
//! explain their speed ([`quality`]).
//!
//! Layout (pbrt-v4 style): nodes in a flat array in depth-first order, 32 bytes
//! each. An interior node's left child is the next node and its right child is at
//! `offset`; a leaf (`count > 0`) holds triangles `offset .. offset + count` of the
//! leaf-ordered arrays. Triangle vertices are gathered in leaf order so a leaf's
//! triangles are contiguous in memory; `tri_ids` maps them back to scene indices
//! (an index may repeat when a builder splits triangles spatially).

pub mod build;
pub mod quality;
pub mod traverse;
pub mod wide;

use std::time::{Duration, Instant};

use glam::Vec3;

pub use build::{BuildParams, BuilderKind};
pub use traverse::Traversal;

use super::Backend;
use crate::geometry::{Aabb, Hit, Intersector, Ray};
use crate::scene::Scene;

/// A BVH node: bounds, and either two children or a range of leaf triangles.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    pub min: Vec3,
    /// Interior: index of the right child (the left child is `self + 1`).
    /// Leaf: first triangle in the leaf-ordered arrays.
    pub offset: u32,
    pub max: Vec3,
    /// Number of triangles; 0 marks an interior node.
    pub count: u32,
}

impl Node {
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }

    #[inline]
    pub fn bounds(&self) -> Aabb {
        Aabb {
            min: self.min,
            max: self.max,
        }
    }
}

/// A built hierarchy over a triangle list.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// Depth-first; `nodes[0]` is the root. Empty only for an empty triangle list.
    pub nodes: Vec<Node>,
    /// Scene triangle index of each leaf slot.
    pub tri_ids: Vec<u32>,
    /// Vertices of each leaf slot (gathered copy of the scene's triangles).
    pub tris: Vec<[Vec3; 3]>,
}

impl Bvh {
    /// Builds over `triangles` (indexed as in the scene) with `params`. Only the
    /// Embree builders can fail.
    pub fn build(triangles: &[[Vec3; 3]], params: &BuildParams) -> crate::Result<Bvh> {
        build::build(triangles, params)
    }

    /// Bytes of nodes, index map and gathered triangles.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>()
            + self.tri_ids.len() * std::mem::size_of::<u32>()
            + self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
    }
}

/// The BVH as a render [`Backend`].
pub struct BvhBackend {
    pub bvh: Bvh,
    /// The 4-wide tree traversed instead of `bvh` when built with width 4.
    pub wide: Option<wide::Bvh4>,
    builder: BuilderKind,
    intersector: Intersector,
    build_time: Duration,
}

impl BvhBackend {
    /// Builds a BVH over the scene's triangles; like every backend's, the build
    /// time runs from the scene to a ready structure (vertex gather included).
    pub fn new(scene: &Scene, params: &BuildParams) -> crate::Result<Self> {
        let start = Instant::now();
        Self::build_timed(&scene.triangle_vertices(), params, start)
    }

    /// Builds over raw triangles (degenerate ones included), for stress tests.
    pub fn from_triangles(triangles: &[[Vec3; 3]], params: &BuildParams) -> crate::Result<Self> {
        Self::build_timed(triangles, params, Instant::now())
    }

    /// The build, with its time counted from `start`; width 4 adds the collapse.
    fn build_timed(
        triangles: &[[Vec3; 3]],
        params: &BuildParams,
        start: Instant,
    ) -> crate::Result<Self> {
        let bvh = Bvh::build(triangles, params)?;
        let wide = (params.width == 4).then(|| wide::Bvh4::collapse(&bvh));
        Ok(BvhBackend {
            bvh,
            wide,
            builder: params.builder,
            intersector: Intersector::Mt,
            build_time: start.elapsed(),
        })
    }

    /// Uses `intersector` for the triangle tests.
    pub fn with_intersector(mut self, intersector: Intersector) -> Self {
        self.intersector = intersector;
        self
    }
}

impl Backend for BvhBackend {
    /// `bvh-<builder>` (`bvh4-` for the 4-wide tree), with `-watertight` for the
    /// watertight triangle test.
    fn name(&self) -> String {
        let kind = if self.wide.is_some() { "bvh4" } else { "bvh" };
        match self.intersector {
            Intersector::Mt => format!("{kind}-{}", self.builder.name()),
            other => format!("{kind}-{}-{}", self.builder.name(), other.name()),
        }
    }

    fn build_time(&self) -> Duration {
        self.build_time
    }

    #[inline]
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match &self.wide {
            Some(w) => w.intersect_using(ray, self.intersector),
            None => self.bvh.intersect_using(ray, self.intersector),
        }
    }

    #[inline]
    fn occluded(&self, ray: &Ray) -> bool {
        match &self.wide {
            Some(w) => w.occluded_using(ray, self.intersector),
            None => self.bvh.occluded_using(ray, self.intersector),
        }
    }
}
