//! The LBVH's wide trees, made as Embree's Morton builder makes its BVH8
//! (`bvh_builder_morton.h`): the low rung's traversed trees.
//!
//! The triangles' (Morton code, index) keys are sorted once
//! ([`lbvh::sorted_keys`]); a wide node then splits the range of its child
//! with the most triangles at [`lbvh::split_by_code`]'s point (the binary
//! LBVH's split) until it has `N` children, so opening children needs no
//! boxes. Boxes are made bottom-up: a leaf's from its triangles, a node's
//! as the union of its children's; a serial build makes them as it goes, a
//! parallel one in its final pass ([`nary::finish_bounding`]), once every
//! piece's place in the tree's arrays is known. The binary LBVH
//! ([`lbvh::build`]) opens children by area as the collapse does, which
//! needs every binary node's box first: made top-down from the references,
//! that scanned each reference once per level of the tree (O(n log n), the
//! largest part of the low rung's build).
//!
//! Leaves and layout are the wide builder's ([`nary`]'s pieces and final
//! pass): small interior children whose halves are both leaves become one
//! leaf ([`MERGE_MAX`]), a subtree under [`LBVH_PARALLEL_CUTOFF`] triangles is a
//! piece of its own, and the arrays are written once at the end.
//!
//! Determinism: the keys are sorted by code then index, and the splits and
//! opening order depend only on the keys, so the tree is the same for any
//! thread count.

use arrayvec::ArrayVec;
use glam::Vec4;
use rayon::prelude::*;

use super::lbvh;
use super::nary::{self, Built, Piece, Slots};
use crate::accel::bvh::leaf::LANES;
use crate::accel::bvh::node::padded;
use crate::accel::bvh::params::{FILL_AHEAD, LBVH_PARALLEL_CUTOFF, MERGE_MAX};
use crate::accel::bvh::prim::{Box4, Triangles};
use crate::accel::bvh::simd::Kernel;
use crate::accel::bvh::wide::node::{leaf_ref, LeafLanes};
use crate::accel::bvh::wide::{WideBvh, WideNode, EMPTY};
use crate::error::Result;

/// A child of the node being made: a range of the sorted keys, and whether
/// it is a leaf.
#[derive(Clone, Copy)]
struct Kid {
    start: usize,
    len: usize,
    leaf: bool,
}

struct Ctx<'a, T: ?Sized> {
    triangles: &'a T,
    /// `code << 32 | index`, sorted.
    keys: &'a [u64],
    max_leaf: usize,
    /// Whether leaves read their triangles and fill their blocks as they
    /// are made (a serial build: its one piece's blocks are the tree's).
    /// In a parallel build the pieces keep scene indices and no boxes, and
    /// the final pass fills each piece's blocks in place and bounds its
    /// nodes from them ([`nary::finish_bounding`]): the triangles are read
    /// once after the keys, as in a serial build. The boxes the tree's
    /// functions set and return are then empty: placeholders the final pass
    /// overwrites.
    fills: bool,
}

impl<T: Triangles + ?Sized> Ctx<'_, T> {
    fn kid(&self, start: usize, len: usize) -> Kid {
        Kid {
            start,
            len,
            leaf: len <= self.max_leaf,
        }
    }

    /// Where the range `start..start + len` splits, from its start.
    fn split(&self, start: usize, len: usize) -> usize {
        lbvh::split_by_code(&self.keys[start..start + len], |&k| (k >> 32) as u32)
    }

    /// The children of the node over `start..start + len`: its open child of
    /// most triangles is split until there are `N` (the first of equals, so
    /// the order is the keys'); then a small interior child whose halves are
    /// both leaves becomes one leaf.
    fn children<const N: usize>(&self, start: usize, len: usize) -> ArrayVec<Kid, N> {
        let mut kids = ArrayVec::new();
        kids.push(self.kid(start, len));
        while kids.len() < N {
            let mut open = None;
            for (i, k) in kids.iter().enumerate() {
                if !k.leaf && open.is_none_or(|o: usize| k.len > kids[o].len) {
                    open = Some(i);
                }
            }
            let Some(i) = open else { break };
            let k = kids[i];
            let mid = self.split(k.start, k.len);
            kids[i] = self.kid(k.start, mid);
            kids.push(self.kid(k.start + mid, k.len - mid));
        }
        for k in kids.iter_mut().filter(|k| !k.leaf && k.len <= MERGE_MAX) {
            let mid = self.split(k.start, k.len);
            k.leaf = mid <= self.max_leaf && k.len - mid <= self.max_leaf;
        }
        kids
    }

    /// Puts leaf `kid`'s triangles into `slots` from slot `slot` on: filled
    /// blocks when filling, returning their box; else their scene indices,
    /// returning no box (the final pass bounds every leaf as it fills its
    /// blocks, [`nary::finish_bounding`]). Leaves come in key order, so what
    /// the leaves [`FILL_AHEAD`] on read is asked for now (the triangles'
    /// index triples twice as far): scene order is not key order, and the
    /// fill waited on the reads.
    fn leaf(&self, kid: &Kid, slot: usize, slots: &mut Slots) -> Box4 {
        let keys = &self.keys[kid.start..kid.start + kid.len];
        if !self.fills {
            for (id, &key) in slots.ids[slot..slot + kid.len].iter_mut().zip(keys) {
                *id = key as u32;
            }
            return Box4::EMPTY;
        }
        let end = kid.start + kid.len;
        let ahead = |from: usize, stage: u8| {
            for &key in self.keys.get(from..from + kid.len).unwrap_or_default() {
                self.triangles.prefetch(key as u32 as usize, stage);
            }
        };
        ahead(end + 2 * FILL_AHEAD * kid.len, 0);
        ahead(end + FILL_AHEAD * kid.len, 1);
        let mut b = Box4::EMPTY;
        for (s, &key) in (slot..).zip(keys) {
            let id = key as u32;
            let tri = self.triangles.get(id as usize);
            for v in tri {
                b.grow(Vec4::from((v, 0.0)));
            }
            slots.blocks[s / LANES].set_lane(s % LANES, &tri, id);
        }
        b
    }

    /// The node of `kids` with its leaves packed into new blocks at the end of
    /// `slots` (as [`nary`] packs them) and their lanes set; the interior
    /// lanes are left for the caller. Returns the node and its leaves' box.
    fn node_with_leaves<const N: usize>(
        &self,
        kids: &ArrayVec<Kid, N>,
        slots: &mut Slots,
    ) -> Result<(WideNode<N>, Box4)> {
        let mut node = WideNode::empty();
        let mut bounds = Box4::EMPTY;
        let leaves = LeafLanes::<N>::of(kids.iter().map(|k| k.leaf.then_some(k.len)));
        let starts = slots.pack::<N>(leaves.counts(), self.fills)?;
        for (&lane, &slot) in leaves.lanes().iter().zip(&starts) {
            let kid = &kids[lane];
            let b = self.leaf(kid, slot, slots);
            node.set_lane(lane, &padded(b.to_aabb()), leaf_ref(slot, kid.len));
            bounds = bounds.union(b);
        }
        Ok((node, bounds))
    }

    /// Makes the node of `kids` and its whole subtree into `piece`; returns
    /// the node's index there, the stack its subtree can need and its box.
    fn serial<const N: usize>(
        &self,
        kids: &ArrayVec<Kid, N>,
        piece: &mut Piece<N>,
    ) -> Result<(u32, usize, Box4)> {
        let index = piece.nodes.len();
        piece.nodes.push(WideNode::empty());
        let (mut node, mut bounds) = self.node_with_leaves(kids, &mut piece.slots)?;
        let mut deepest = 0;
        for (lane, kid) in kids.iter().enumerate().filter(|(_, k)| !k.leaf) {
            let grand = self.children::<N>(kid.start, kid.len);
            let (child, need, b) = self.serial(&grand, piece)?;
            node.set_lane(lane, &padded(b.to_aabb()), child);
            bounds = bounds.union(b);
            deepest = deepest.max(need);
        }
        piece.nodes[index] = node;
        Ok((index as u32, kids.len() - 1 + deepest, bounds))
    }

    /// A subtree of `kids` built as one piece.
    fn piece<const N: usize>(
        &self,
        kids: &ArrayVec<Kid, N>,
        len: usize,
    ) -> Result<(Built<N>, Box4)> {
        let mut piece = Piece::with_capacity(len, self.fills);
        let (_, need, b) = self.serial(kids, &mut piece)?;
        piece.need = need;
        Ok((Built::Piece(piece), b))
    }

    /// Makes the node of `kids` with its interior children built in parallel
    /// (each a piece, or a parallel node where large); returns it and its box.
    fn parallel<const N: usize>(&self, kids: &ArrayVec<Kid, N>) -> Result<(Built<N>, Box4)> {
        let mut slots = Slots::default();
        let (mut node, mut bounds) = self.node_with_leaves(kids, &mut slots)?;
        let lanes: ArrayVec<usize, N> = (0..kids.len()).filter(|&l| !kids[l].leaf).collect();
        let built: Vec<Result<(Built<N>, Box4)>> = lanes
            .par_iter()
            .map(|&lane| {
                let kid = &kids[lane];
                let grand = self.children::<N>(kid.start, kid.len);
                if kid.len >= LBVH_PARALLEL_CUTOFF {
                    self.parallel(&grand)
                } else {
                    self.piece(&grand, kid.len)
                }
            })
            .collect();
        let mut children = Vec::with_capacity(N);
        let mut deepest = 0;
        for (&lane, b) in lanes.iter().zip(built) {
            let (child, b) = b?;
            node.set_lane(lane, &padded(b.to_aabb()), EMPTY);
            bounds = bounds.union(b);
            deepest = deepest.max(child.need());
            children.push((lane, child));
        }
        let need = kids.len() - 1 + deepest;
        Ok((
            Built::Node {
                node,
                slots,
                children,
                need,
            },
            bounds,
        ))
    }
}

/// The `N`-wide LBVH over `triangles` with leaves of at most `max_leaf`
/// triangles (up to [`MERGE_MAX`] where two leaves merge), in parallel on the
/// current rayon pool when `parallel`.
pub(crate) fn build<const N: usize, T: Triangles + ?Sized>(
    triangles: &T,
    max_leaf: usize,
    parallel: bool,
    kernel: Kernel,
) -> Result<WideBvh<N>> {
    let split = parallel && triangles.count() >= LBVH_PARALLEL_CUTOFF;
    let keys = lbvh::sorted_keys(triangles, parallel);
    if keys.is_empty() {
        return Ok(WideBvh::empty(kernel));
    }
    let ctx = Ctx {
        triangles,
        keys: &keys,
        max_leaf: max_leaf.max(1),
        fills: !split,
    };
    let kids = ctx.children::<N>(0, keys.len());
    let (built, _) = if split {
        ctx.parallel(&kids)?
    } else {
        ctx.piece(&kids, keys.len())?
    };
    drop(keys);
    if split {
        nary::finish_bounding(triangles, built, parallel, kernel)
    } else {
        nary::finish(triangles, built, parallel, kernel)
    }
}

#[cfg(test)]
mod tests {
    use super::super::pool::in_pool;
    use crate::accel::bvh::params::MERGE_MAX;
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::accel::bvh::wide::tests::assert_sound;
    use crate::accel::bvh::wide::{node::LEAF, WideBvh, EMPTY};
    use crate::accel::bvh::{BuildParams, BuilderKind};

    fn lbvh<const N: usize>(
        tris: &Vec<[glam::Vec3; 3]>,
        max_leaf: usize,
        threads: usize,
    ) -> WideBvh<N> {
        let params = BuildParams::for_builder(BuilderKind::Lbvh)
            .with_width(N)
            .with_max_leaf_size(max_leaf)
            .with_threads(threads);
        in_pool(threads, || super::super::wide::<N, _>(tris, &params)).unwrap()
    }

    /// Sound, the same on one and two threads (12,000 triangles pass the
    /// parallel cut-off, 60,000 pass it below the root too, so parallel
    /// nodes have parallel children: the serial build fills and bounds its
    /// leaves as it goes, the parallel one at the end, with the same boxes
    /// to the bit), every node full unless all its children
    /// are leaves (children are opened by count, never stopped by a box),
    /// and leaves no larger than the limit, or [`MERGE_MAX`] where two
    /// leaves merged.
    fn check<const N: usize>(max_leaf: usize) {
        for n in [1, 2, 5, 17, 300, 12_000, 60_000] {
            let tris = random_tris(n, n as u64 + 7);
            let one = lbvh::<N>(&tris, max_leaf, 1);
            assert_sound(&one, &tris);
            let two = lbvh::<N>(&tris, max_leaf, 2);
            assert!(
                one.nodes == two.nodes,
                "n = {n}: nodes differ on two threads"
            );
            assert!(
                one.blocks == two.blocks,
                "n = {n}: blocks differ on two threads"
            );
            assert_eq!(one.stack_need, two.stack_need);
            for node in &one.nodes {
                let used = node.used();
                let interior =
                    (0..used).any(|l| node.child[l] != EMPTY && node.child[l] & LEAF == 0);
                if interior {
                    assert_eq!(used, N, "n = {n}: a node with an interior child is full");
                }
                for lane in 0..used {
                    let count = node.leaf_slots(lane).len();
                    assert!(count <= max_leaf.max(MERGE_MAX), "leaf of {count}");
                }
            }
        }
    }

    #[test]
    fn trees_are_sound_full_and_the_same_on_any_thread_count() {
        check::<8>(4);
        check::<8>(7);
        check::<4>(4);
        check::<8>(1);
    }
}
