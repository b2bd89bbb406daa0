//! The tree a BVH backend traverses: the binary tree as built, or the 4- or
//! 8-wide tree, whichever [`super::build`] made for `BuildParams::width`.

use super::leaf::BlockTest;
use super::node::Bvh;
use super::simd::Kernel;
use super::traverse::{Counter, Traversal};
use super::wide::{Bvh4, Bvh8};
use crate::geometry::{Hit, Ray};

/// A built tree, ready to traverse.
#[derive(Clone, Debug)]
pub enum Tree {
    /// The binary tree as built.
    Binary(Bvh),
    /// 4-wide nodes.
    Wide4(Bvh4),
    /// 8-wide nodes.
    Wide8(Bvh8),
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

    /// The same tree, its 8-wide nodes tested with `kernel` (an AVX2 kernel
    /// only exists on a CPU that has AVX2); binary and 4-wide trees have one
    /// kernel each and are returned unchanged.
    pub fn with_kernel(mut self, kernel: Kernel) -> Tree {
        if let Tree::Wide8(t) = &mut self {
            t.kernel = kernel;
        }
        self
    }

    /// The binary tree, when this is one.
    pub fn binary(&self) -> Option<&Bvh> {
        match self {
            Tree::Binary(t) => Some(t),
            _ => None,
        }
    }

    /// The binary tree, when this is one (a build of width 2 always is).
    pub fn into_binary(self) -> Option<Bvh> {
        match self {
            Tree::Binary(t) => Some(t),
            _ => None,
        }
    }
}

impl Traversal for Tree {
    #[inline]
    fn closest<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        match self {
            Tree::Binary(t) => t.closest::<T, C>(ray, counter),
            Tree::Wide4(t) => t.closest::<T, C>(ray, counter),
            Tree::Wide8(t) => t.closest::<T, C>(ray, counter),
        }
    }

    #[inline]
    fn any<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        match self {
            Tree::Binary(t) => t.any::<T, C>(ray, counter),
            Tree::Wide4(t) => t.any::<T, C>(ray, counter),
            Tree::Wide8(t) => t.any::<T, C>(ray, counter),
        }
    }
}
