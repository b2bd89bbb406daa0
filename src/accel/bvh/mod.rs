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
pub mod leaf;
pub mod quality;
pub mod simd;
pub mod traverse;
pub mod wide;

/// Triangle sets the unit tests of the trees share.
#[cfg(test)]
pub(crate) mod test_fixtures {
    use glam::Vec3;

    use crate::render::rng::Rng;

    /// `n` small random triangles (sides up to 0.5) scattered in a box of side
    /// 10; the same set for the same `seed`.
    pub fn random_tris(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = Rng::for_pixel(0, seed, 9);
        let mut v = |s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        (0..n)
            .map(|_| {
                let c = v(10.0);
                [c + v(0.5), c + v(0.5), c + v(0.5)]
            })
            .collect()
    }
}

use std::time::{Duration, Instant};

use glam::Vec3;

pub use build::{BuildParams, BuilderKind, Triangles};
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
    pub fn build<T: Triangles + ?Sized>(triangles: &T, params: &BuildParams) -> crate::Result<Bvh> {
        build::build(triangles, params)
    }

    /// Bytes of nodes, index map and gathered triangles.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>()
            + self.tri_ids.len() * std::mem::size_of::<u32>()
            + self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
    }
}

/// The tree a [`BvhBackend`] traverses.
#[derive(Clone, Debug)]
pub enum Tree {
    /// The binary tree as built.
    Binary(Bvh),
    /// Collapsed into 4-wide nodes.
    Wide4(wide::Bvh4),
    /// Collapsed into 8-wide nodes.
    Wide8(wide::Bvh8),
}

impl Tree {
    /// Bytes of nodes and leaf data.
    pub fn memory_bytes(&self) -> usize {
        match self {
            Tree::Binary(t) => t.memory_bytes(),
            Tree::Wide4(t) => t.memory_bytes(),
            Tree::Wide8(t) => t.memory_bytes(),
        }
    }

    /// Children per node.
    pub fn width(&self) -> usize {
        match self {
            Tree::Binary(_) => 2,
            Tree::Wide4(_) => 4,
            Tree::Wide8(_) => 8,
        }
    }

    /// The node kernel its queries use (`scalar` for the binary tree).
    pub fn kernel(&self) -> &'static str {
        match self {
            Tree::Binary(_) => "scalar",
            Tree::Wide4(t) => t.kernel.name(),
            Tree::Wide8(t) => t.kernel.name(),
        }
    }

    /// Closest hit with the chosen ray/triangle test.
    #[inline]
    pub fn intersect_using(&self, ray: &Ray, intersector: Intersector) -> Option<Hit> {
        match self {
            Tree::Binary(t) => t.intersect_using(ray, intersector),
            Tree::Wide4(t) => t.intersect_using(ray, intersector),
            Tree::Wide8(t) => t.intersect_using(ray, intersector),
        }
    }

    /// Any hit with the chosen ray/triangle test.
    #[inline]
    pub fn occluded_using(&self, ray: &Ray, intersector: Intersector) -> bool {
        match self {
            Tree::Binary(t) => t.occluded_using(ray, intersector),
            Tree::Wide4(t) => t.occluded_using(ray, intersector),
            Tree::Wide8(t) => t.occluded_using(ray, intersector),
        }
    }

    /// Builds over `triangles` with `params` and collapses to `params.width`
    /// (the binary tree is dropped once collapsed).
    pub fn build<T: Triangles + ?Sized>(
        triangles: &T,
        params: &BuildParams,
    ) -> crate::Result<Tree> {
        // raylab's builders split no work off below the parallel cut-off, so
        // a small scene is built on the calling thread: handing it to a pool
        // only cost the wake-up (cornell-sphere, 2 threads: 0.41 ms against
        // 0.31 on one). The tree is the same for any thread count.
        let own = matches!(params.builder, BuilderKind::Median | BuilderKind::Sah);
        let params = if own && triangles.count() < build::PARALLEL_CUTOFF {
            params.with_threads(1)
        } else {
            *params
        };
        build::in_pool(params.threads, || Tree::build_here(triangles, &params))
    }

    /// [`Tree::build`] on the current thread pool.
    fn build_here<T: Triangles + ?Sized>(
        triangles: &T,
        params: &BuildParams,
    ) -> crate::Result<Tree> {
        Ok(match params.width {
            2 => {
                let skeleton = build::skeleton_here(triangles, params)?;
                Tree::Binary(skeleton.gather(triangles, params.threads > 1))
            }
            4 => Tree::Wide4(build::wide_here(triangles, params)?),
            _ => Tree::Wide8(build::wide_here(triangles, params)?),
        })
    }
}

/// The BVH as a render [`Backend`].
pub struct BvhBackend {
    pub tree: Tree,
    builder: BuilderKind,
    intersector: Intersector,
    build_time: Duration,
}

impl BvhBackend {
    /// Builds a BVH over the scene's triangles; like every backend's, the build
    /// time runs from the scene to a ready structure (collapse to a wide tree
    /// included).
    pub fn new(scene: &Scene, params: &BuildParams) -> crate::Result<Self> {
        Self::build_timed(scene, params, Instant::now())
    }

    /// Builds over raw triangles (degenerate ones included), for stress tests.
    pub fn from_triangles(triangles: &[[Vec3; 3]], params: &BuildParams) -> crate::Result<Self> {
        Self::build_timed(triangles, params, Instant::now())
    }

    fn build_timed<T: Triangles + ?Sized>(
        triangles: &T,
        params: &BuildParams,
        start: Instant,
    ) -> crate::Result<Self> {
        let tree = Tree::build(triangles, params)?;
        Ok(BvhBackend {
            tree,
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

    /// The binary tree, when this backend traverses it (width 2).
    pub fn binary(&self) -> Option<&Bvh> {
        match &self.tree {
            Tree::Binary(t) => Some(t),
            _ => None,
        }
    }
}

impl Backend for BvhBackend {
    /// `bvh-<builder>` (`bvh4-`, `bvh8-` for the wide trees), with
    /// `-watertight` for the watertight triangle test.
    fn name(&self) -> String {
        let kind = match self.tree.width() {
            2 => "bvh".to_string(),
            w => format!("bvh{w}"),
        };
        match self.intersector {
            Intersector::Mt => format!("{kind}-{}", self.builder.name()),
            other => format!("{kind}-{}-{}", self.builder.name(), other.name()),
        }
    }

    fn build_time(&self) -> Duration {
        self.build_time
    }

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
