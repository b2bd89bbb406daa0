//! Collapse: every wide node takes a binary interior node and repeatedly opens
//! the interior child of largest surface area until it has `N` children or only
//! leaves (as Embree's BVH4/BVH8 and Wald et al. 2008). The boxes are the
//! binary tree's and leaves keep their triangles, so a wide tree finds exactly
//! the binary tree's hits.

use arrayvec::ArrayVec;
use glam::Vec3;
use rayon::prelude::*;

use super::super::leaf::{Tri4, LANES};
#[cfg(test)]
use super::super::node::Bvh;
use super::super::node::{Node, Skeleton};
use super::super::params::MERGE_MAX;
use super::super::prim::Triangles;
use super::super::simd::Kernel;
use super::node::{leaf_ref, pack_leaves, LeafLanes, WideBvh, WideNode, EMPTY, MAX_SLOTS};
use crate::error::{Error, Result};

impl<const N: usize> WideBvh<N> {
    /// Collapses `bvh` (left intact) with the kernel the CPU supports best
    /// (the tests check the collapse against the direct wide build and the
    /// binary tree; the renderer builds wide trees through `bvh::build`).
    #[cfg(test)]
    pub(crate) fn collapse(bvh: &Bvh) -> Result<Self> {
        Self::collapse_with(bvh, Kernel::detect())
    }

    /// Collapses `bvh` using `kernel` for queries (AVX2 serves only `N = 8`).
    #[cfg(test)]
    pub(crate) fn collapse_with(bvh: &Bvh, kernel: Kernel) -> Result<Self> {
        Self::collapse_parts(
            &bvh.nodes,
            &bvh.tri_ids,
            |slot| bvh.tris[slot],
            kernel,
            false,
        )
    }

    /// Collapses a tree whose triangles were not gathered: leaf slot `i` holds
    /// `triangles[skeleton.tri_ids[i]]`. The leaf blocks are filled in
    /// parallel on the current rayon pool when `parallel`.
    pub(crate) fn from_skeleton<T: Triangles + ?Sized>(
        skeleton: &Skeleton,
        triangles: &T,
        parallel: bool,
    ) -> Result<Self> {
        let ids = &skeleton.tri_ids;
        Self::collapse_parts(
            &skeleton.nodes,
            ids,
            |slot| triangles.get(ids[slot] as usize),
            Kernel::detect(),
            parallel,
        )
    }

    /// Two passes: the wide nodes and, for every lane of every leaf block, the
    /// binary leaf slot it takes its triangle from (cheap, serial); then the
    /// blocks, whose triangle reads are scattered over memory (in parallel).
    fn collapse_parts(
        nodes: &[Node],
        tri_ids: &[u32],
        triangle: impl Fn(usize) -> [Vec3; 3] + Sync,
        kernel: Kernel,
        parallel: bool,
    ) -> Result<Self> {
        let mut out = Self::empty(kernel);
        if nodes.is_empty() {
            return Ok(out);
        }
        // Enough for leaves of one triangle; reserving touches no memory,
        // while growing would copy the nodes made so far.
        out.nodes.reserve(tri_ids.len() / (N - 1) + 1);
        let mut sources: Vec<u32> = Vec::with_capacity(tri_ids.len() + tri_ids.len() / 2);
        let (_, need) = out.collapse_node(nodes, &mut sources, 0)?;
        out.stack_need = need + 1;
        let block = |lanes: &[u32]| {
            let mut b = Tri4::empty();
            for (lane, &from) in lanes.iter().enumerate() {
                if from != EMPTY {
                    b.set_lane(lane, &triangle(from as usize), tri_ids[from as usize]);
                }
            }
            b
        };
        out.blocks = if parallel {
            sources.par_chunks(LANES).map(block).collect()
        } else {
            sources.chunks(LANES).map(block).collect()
        };
        out.fit_fused_reach();
        Ok(out)
    }

    /// Makes the wide node for binary node `b` (a root leaf becomes a node with
    /// one leaf lane), and the source slots of its leaves' lanes in `sources`;
    /// returns its index and the stack its subtree can need.
    fn collapse_node(
        &mut self,
        nodes: &[Node],
        sources: &mut Vec<u32>,
        b: u32,
    ) -> Result<(u32, usize)> {
        let node = &nodes[b as usize];
        let mut children: ArrayVec<u32, N> = ArrayVec::new();
        if node.is_leaf() {
            children.push(b);
        } else {
            children.push(b + 1);
            children.push(node.offset);
        }
        while children.len() < N {
            // Open the interior child with the largest surface area.
            let best = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| !nodes[c as usize].is_leaf())
                .max_by(|(_, &a), (_, &c)| {
                    nodes[a as usize]
                        .bounds()
                        .surface_area()
                        .total_cmp(&nodes[c as usize].bounds().surface_area())
                })
                .map(|(i, _)| i);
            let Some(i) = best else { break };
            let c = children[i];
            children[i] = c + 1;
            children.push(nodes[c as usize].offset);
        }
        let index = self.nodes.len();
        self.nodes.push(WideNode::empty());
        let mut wide = WideNode::empty();
        // The binary leaves each lane's leaf is made of: the lane's node if
        // it is a leaf, or both halves of a small child made one leaf.
        let leaf_parts = |c: u32| -> Option<ArrayVec<Node, 2>> {
            let n = nodes[c as usize];
            if n.is_leaf() {
                return Some([n].into_iter().collect());
            }
            let (l, r) = (nodes[c as usize + 1], nodes[n.offset as usize]);
            // A full node only: one with free lanes has no interior child.
            let small = children.len() == N && (l.count + r.count) as usize <= MERGE_MAX;
            (small && l.is_leaf() && r.is_leaf()).then(|| [l, r].into_iter().collect())
        };
        let parts: ArrayVec<Option<ArrayVec<Node, 2>>, N> =
            children.iter().map(|&c| leaf_parts(c)).collect();
        // Leaves first, packed into shared blocks.
        let leaves = LeafLanes::<N>::of(parts.iter().map(|leaf| {
            leaf.as_ref()
                .map(|leaf| leaf.iter().map(|n| n.count as usize).sum())
        }));
        let (slots, blocks) = pack_leaves::<N>(leaves.counts(), sources.len() / LANES)?;
        sources.resize(sources.len() + blocks * LANES, EMPTY);
        if sources.len() > MAX_SLOTS {
            return Err(Error::Other(format!(
                "wide BVH: more than {MAX_SLOTS} triangle slots"
            )));
        }
        for ((&lane, &count), &slot) in leaves.lanes().iter().zip(leaves.counts()).zip(&slots) {
            let leaf = parts[lane].as_ref().expect("a leaf lane");
            let from = leaf.iter().flat_map(|n| n.offset..n.offset + n.count);
            for (source, from) in sources[slot..slot + count].iter_mut().zip(from) {
                *source = from;
            }
            let bounds = nodes[children[lane] as usize].bounds();
            wide.set_lane(lane, &bounds, leaf_ref(slot, count));
        }
        let mut deepest = 0;
        for (lane, &c) in children.iter().enumerate() {
            let n = nodes[c as usize];
            if parts[lane].is_some() {
                continue;
            }
            let (i, need) = self.collapse_node(nodes, sources, c)?;
            deepest = deepest.max(need);
            wide.set_lane(lane, &n.bounds(), i);
        }
        self.nodes[index] = wide;
        Ok((index as u32, children.len() - 1 + deepest))
    }
}
