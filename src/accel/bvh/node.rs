//! The binary tree's layout (pbrt-v4 style): nodes in a flat array in
//! depth-first order, 32 bytes each. An interior node's left child is the next
//! node and its right child is at `offset`; a leaf (`count > 0`) holds
//! triangles `offset .. offset + count` of the leaf-ordered arrays. Triangle
//! vertices are gathered in leaf order so a leaf's triangles are contiguous in
//! memory; `tri_ids` maps them back to scene indices (an index may repeat when
//! a builder splits triangles spatially).
//!
//! Also the two forms a tree takes on the way there: a [`Skeleton`] (nodes
//! and scene indices, before the gather), and a [`BuildNode`] tree that
//! builders working through callbacks (Embree's) make and flatten once.

use glam::Vec3;
use rayon::prelude::*;

use super::params::BOX_MARGIN;
use super::prim::Triangles;
use crate::geometry::Aabb;

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
    /// Bytes of nodes, index map and gathered triangles.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>()
            + self.tri_ids.len() * std::mem::size_of::<u32>()
            + self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
    }
}

/// A built binary tree before its triangles are gathered: nodes in the
/// [`Bvh`] layout, except that slots no subtree used may lie between them
/// (nothing points there; [`Skeleton::compact`] squeezes them out), and the
/// scene index of each leaf slot.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Skeleton {
    pub nodes: Vec<Node>,
    pub tri_ids: Vec<u32>,
}

impl Skeleton {
    /// The same tree with its nodes renumbered depth-first without gaps.
    pub fn compact(self) -> Skeleton {
        if self.nodes.is_empty() {
            return self;
        }
        Skeleton {
            nodes: compact(&self.nodes),
            tri_ids: self.tri_ids,
        }
    }

    /// The [`Bvh`]: the skeleton, compacted, with each leaf slot's vertices
    /// gathered.
    pub fn gather<T: Triangles + ?Sized>(self, triangles: &T, parallel: bool) -> Bvh {
        let s = self.compact();
        let tris = if parallel {
            s.tri_ids
                .par_iter()
                .map(|&i| triangles.get(i as usize))
                .collect()
        } else {
            s.tri_ids
                .iter()
                .map(|&i| triangles.get(i as usize))
                .collect()
        };
        Bvh {
            nodes: s.nodes,
            tri_ids: s.tri_ids,
            tris,
        }
    }
}

/// Temporary tree, flattened once into the compact layout (the Embree
/// builder's callbacks make one). Leaves refer to a range of `tri_ids`.
// Only Embree's builder makes one (none in a build without Embree).
#[cfg_attr(not(feature = "embree"), allow(dead_code))]
pub(crate) enum BuildNode {
    Leaf {
        bounds: Aabb,
        start: u32,
        count: u32,
    },
    Interior {
        bounds: Aabb,
        children: Box<[BuildNode; 2]>,
    },
}

/// A node slot no subtree wrote.
pub(crate) const UNUSED: Node = Node {
    min: Vec3::ZERO,
    offset: u32::MAX,
    max: Vec3::ZERO,
    count: 0,
};

/// The nodes reachable from slot 0, renumbered depth-first without gaps.
fn compact(slots: &[Node]) -> Vec<Node> {
    let mut out: Vec<Node> = Vec::with_capacity(slots.len());
    // (slot, the output node whose right-child offset points here)
    let mut stack: Vec<(usize, Option<usize>)> = vec![(0, None)];
    while let Some((slot, parent)) = stack.pop() {
        let index = out.len();
        if let Some(p) = parent {
            out[p].offset = index as u32;
        }
        let node = slots[slot];
        debug_assert!(node != UNUSED);
        out.push(node);
        if !node.is_leaf() {
            stack.push((node.offset as usize, Some(index)));
            stack.push((slot + 1, None));
        }
    }
    out
}

/// Flattens a temporary tree whose leaves index `tri_ids` into the compact
/// layout.
#[cfg_attr(not(feature = "embree"), allow(dead_code))]
pub(crate) fn skeleton_of(root: BuildNode, tri_ids: Vec<u32>) -> Skeleton {
    let mut nodes = Vec::with_capacity(2 * tri_ids.len());
    flatten(root, &mut nodes);
    Skeleton { nodes, tri_ids }
}

/// `b` grown on every axis in which it has an extent by [`BOX_MARGIN`] of
/// that extent; not on an axis in which it is flat. A flat box bounds
/// triangles that all lie in one axis-aligned plane, and a ray meets such a
/// triangle only where it crosses that plane, which the zero-width slab
/// admits exactly (its entry and exit are the same rounded `t`, and the exit
/// is grown by [`crate::geometry::SLAB_GROW`], through the far planes'
/// reciprocal); a margin there only lets in
/// rays that leave the plane. Grown, every flat box of a flat export (a field
/// 100 units across: +-4.8e-5) held the secondary rays leaving it, which then
/// walked every box around their origin down to the leaves: 3-5x the time of
/// Embree's and every library's shadow and AO rays (`plane:N`).
///
/// Nothing in proportion to the coordinates. A margin of 2^-22 of the
/// coordinates (two ulps), as this was until 2026-12-05, swelled every leaf
/// of `far:20000` (triangles 0.03 across at 1e5, where an ulp is 0.008) to
/// several times its triangles: 5.0/12.1/3.0 triangles tested per
/// primary/shadow/AO ray against mesh:20000's 1.6/1.1/0.9, and 1.9-2.3x
/// Embree's time per ray kind; a floor of one ulp still 2.9/6.2/1.1 and
/// 1.4-1.6x. The floor was there for rays with a zero direction component
/// whose origin lies exactly in a leaf box's face plane (at 1e5 origins land
/// on vertex coordinates often): measured from the origin, that face's slab
/// distance is `0 * RECIPROCAL_MAX = 0`, and the box was culled (17 AO hits
/// lost on far:20000 without it). The slab tests now measure such faces from
/// either side of the plane ([`crate::geometry::SlabRay`]), and far:20000's
/// shadow rays test 1.0 triangles per ray, its traversal 0.8-1.0x Embree's
/// time, with 0 wrong answers by the exact reference (docs/results.md,
/// 2026-12-05).
pub(crate) fn padded(b: Aabb) -> Aabb {
    let magnitude = b.extent().max_element();
    let flat = b.min.cmpeq(b.max);
    let pad = glam::Vec3::select(
        flat,
        glam::Vec3::ZERO,
        glam::Vec3::splat(magnitude * BOX_MARGIN),
    );
    Aabb {
        min: b.min - pad,
        max: b.max + pad,
    }
}

#[cfg_attr(not(feature = "embree"), allow(dead_code))]
fn flatten(node: BuildNode, nodes: &mut Vec<Node>) -> u32 {
    let index = nodes.len();
    nodes.push(UNUSED);
    nodes[index] = match node {
        BuildNode::Leaf {
            bounds,
            start,
            count,
        } => {
            let b = padded(bounds);
            Node {
                min: b.min,
                offset: start,
                max: b.max,
                count,
            }
        }
        BuildNode::Interior { bounds, children } => {
            let [left, right] = *children;
            flatten(left, nodes);
            let right_index = flatten(right, nodes);
            let b = padded(bounds);
            Node {
                min: b.min,
                offset: right_index,
                max: b.max,
                count: 0,
            }
        }
    };
    index as u32
}
