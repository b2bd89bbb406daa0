//! Reinsertion optimisation (Bittner, Hapala and Havran 2013, in the
//! batched form of Meister and Bittner and of madmann91/bvh v2): applied to
//! the binary tree of any builder (`--optimize`). Leaves stay as they are;
//! interior nodes move. A round takes the [`OPTIMIZE_BATCH`] share of the
//! nodes with the largest boxes, and moves each, with its subtree, to the
//! place in the tree where it lowers the sum of the interior boxes' areas
//! most (the SAH cost with the leaves fixed), if any. The place is found by
//! branch and bound from the node's old place upwards: removing it shrinks
//! its ancestors, inserting it beside a node grows that node's ancestors.
//! [`OPTIMIZE_ROUNDS`] rounds at most, fewer when a round gains nothing.
//!
//! Serial, so the tree is the same for any thread count; boxes are unions,
//! so a parent still contains its children (the leaves' margins are kept).

use crate::accel::bvh::node::{Skeleton, UNUSED};
use crate::accel::bvh::params::{OPTIMIZE_BATCH, OPTIMIZE_ROUNDS};
use crate::accel::bvh::prim::Box4;
use crate::accel::bvh::Node;

/// No node (the root's parent).
const NONE: u32 = u32::MAX;

/// A node while the tree changes shape: its box, children or leaf range,
/// and parent.
#[derive(Clone, Copy, Debug)]
struct Slot {
    bounds: Box4,
    /// Interior: the two children; leaf: `[first triangle slot, count]`.
    kids: [u32; 2],
    leaf: bool,
    parent: u32,
}

/// `skeleton` (compact or not) optimised; the result is compact.
pub(crate) fn optimize(skeleton: Skeleton) -> Skeleton {
    if skeleton.nodes.is_empty() {
        return skeleton;
    }
    let mut tree = Tree::of(&skeleton.nodes);
    for _ in 0..OPTIMIZE_ROUNDS {
        if !tree.round() {
            break;
        }
    }
    Skeleton {
        nodes: tree.flatten(),
        tri_ids: skeleton.tri_ids,
    }
}

/// Half the surface area (the factor cancels in every comparison).
#[inline]
fn area(b: Box4) -> f32 {
    let e = (b.hi - b.lo).max(glam::Vec4::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

struct Tree {
    slots: Vec<Slot>,
    root: u32,
}

impl Tree {
    fn of(nodes: &[Node]) -> Tree {
        let mut slots = Vec::with_capacity(nodes.len());
        // (skeleton index, parent slot)
        let mut stack = vec![(0usize, NONE)];
        while let Some((i, parent)) = stack.pop() {
            let n = nodes[i];
            debug_assert!(n != UNUSED);
            let index = slots.len() as u32;
            slots.push(Slot {
                bounds: Box4 {
                    lo: n.min.extend(0.0),
                    hi: n.max.extend(0.0),
                },
                kids: if n.is_leaf() {
                    [n.offset, n.count]
                } else {
                    [NONE; 2]
                },
                leaf: n.is_leaf(),
                parent,
            });
            if parent != NONE {
                let p = &mut slots[parent as usize];
                let k = if p.kids[0] == NONE { 0 } else { 1 };
                p.kids[k] = index;
            }
            if !n.is_leaf() {
                // Left first: it fills kids[0].
                stack.push((n.offset as usize, index));
                stack.push((i + 1, index));
            }
        }
        let mut tree = Tree { slots, root: 0 };
        // Interior boxes as the unions of their children's, as moves make
        // them (the builders' are padded a little more): a move is then
        // never made to shed padding. Children follow their parents.
        for i in (0..tree.slots.len()).rev() {
            if !tree.slots[i].leaf {
                let [a, b] = tree.slots[i].kids;
                tree.slots[i].bounds = tree.bounds(a).union(tree.bounds(b));
            }
        }
        tree
    }

    fn sibling(&self, i: u32) -> u32 {
        let p = &self.slots[self.slots[i as usize].parent as usize];
        if p.kids[0] == i {
            p.kids[1]
        } else {
            p.kids[0]
        }
    }

    fn bounds(&self, i: u32) -> Box4 {
        self.slots[i as usize].bounds
    }

    /// One round; whether it moved anything.
    fn round(&mut self) -> bool {
        // The interior nodes two levels down and more (a child of the root
        // has no place to go that keeps the root), largest boxes first; ties
        // by index so the order is fixed.
        let mut candidates: Vec<(f32, u32)> = (0..self.slots.len() as u32)
            .filter(|&i| {
                let p = self.slots[i as usize].parent;
                p != NONE && self.slots[p as usize].parent != NONE
            })
            .map(|i| (area(self.bounds(i)), i))
            .collect();
        let batch = ((candidates.len() as f64 * OPTIMIZE_BATCH as f64).ceil() as usize).max(1);
        // The largest first, ties by index: a total order, so selecting the
        // batch and then sorting it gives the full sort's batch (a full sort
        // of every node each round was 7% of a high-rung build).
        let order = |a: &(f32, u32), b: &(f32, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        if batch < candidates.len() {
            candidates.select_nth_unstable_by(batch, order);
            candidates.truncate(batch);
        }
        candidates.sort_unstable_by(order);
        let mut moved = false;
        for &(_, node) in &candidates {
            // Earlier moves may have made it a child of the root.
            let p = self.slots[node as usize].parent;
            if p == NONE || self.slots[p as usize].parent == NONE {
                continue;
            }
            if let Some(target) = self.best_place(node) {
                self.reinsert(node, target);
                moved = true;
            }
        }
        moved
    }

    /// Where moving `node` lowers the interior area sum most, if anywhere.
    ///
    /// Moved beside a node in the subtree of a sibling of one of its
    /// ancestors `A`, the node's parent disappears and the ancestors below
    /// `A` shrink to what is left in them (`gain`); `A` and those above keep
    /// their boxes. The new parent costs the merged box, and each node passed
    /// on the way down to the new place grows: a subtree is searched only
    /// while what is left of the gain could still beat the best place found.
    fn best_place(&self, node: u32) -> Option<u32> {
        let node_box = self.bounds(node);
        let node_area = area(node_box);
        let parent = self.slots[node as usize].parent;
        let sibling = self.sibling(node);
        // Gains below this are rounding, not a better tree.
        let mut best: (f32, u32) = (area(self.bounds(self.root)) * 1e-6, NONE);
        let mut stack: Vec<(f32, u32)> = Vec::new();
        let mut gain = area(self.bounds(parent));
        let mut remaining = self.bounds(sibling);
        let mut search = |gain: f32, from: u32, best: &mut (f32, u32)| {
            stack.push((gain, from));
            while let Some((budget, at)) = stack.pop() {
                if budget - node_area <= best.0 {
                    continue;
                }
                let at_box = self.bounds(at);
                let net = budget - area(at_box.union(node_box));
                if net > best.0 {
                    *best = (net, at);
                }
                let slot = &self.slots[at as usize];
                if !slot.leaf {
                    let below = net + area(at_box);
                    stack.push((below, slot.kids[0]));
                    stack.push((below, slot.kids[1]));
                }
            }
        };
        search(gain, sibling, &mut best);
        let mut pivot = parent;
        loop {
            let up = self.slots[pivot as usize].parent;
            if up == NONE {
                break;
            }
            if pivot != parent {
                gain += area(self.bounds(pivot)) - area(remaining);
            }
            let side = self.sibling(pivot);
            search(gain, side, &mut best);
            remaining = remaining.union(self.bounds(side));
            pivot = up;
        }
        let target = best.1;
        (target != NONE && target != sibling).then_some(target)
    }

    /// Moves `node` (with its subtree) beside `target`: its parent slot is
    /// reused as the new parent of the two.
    fn reinsert(&mut self, node: u32, target: u32) {
        let parent = self.slots[node as usize].parent;
        let sibling = self.sibling(node);
        let grand = self.slots[parent as usize].parent;
        // Detach: the sibling takes the parent's place.
        self.replace_child(grand, parent, sibling);
        self.refit(grand);
        // Attach: the freed parent slot holds `target` and `node`, in
        // `target`'s old place.
        let above = self.slots[target as usize].parent;
        self.replace_child(above, target, parent);
        let p = &mut self.slots[parent as usize];
        p.kids = [target, node];
        p.parent = above;
        self.slots[target as usize].parent = parent;
        self.slots[node as usize].parent = parent;
        self.refit(parent);
    }

    fn replace_child(&mut self, of: u32, old: u32, new: u32) {
        let p = &mut self.slots[of as usize];
        let k = if p.kids[0] == old { 0 } else { 1 };
        debug_assert_eq!(p.kids[k], old);
        p.kids[k] = new;
        self.slots[new as usize].parent = of;
    }

    /// Recomputes the boxes from `from` up to the root.
    fn refit(&mut self, from: u32) {
        let mut i = from;
        while i != NONE {
            let [a, b] = self.slots[i as usize].kids;
            self.slots[i as usize].bounds = self.bounds(a).union(self.bounds(b));
            i = self.slots[i as usize].parent;
        }
    }

    /// The tree in the skeleton layout, depth-first without gaps.
    fn flatten(&self) -> Vec<Node> {
        let mut out: Vec<Node> = Vec::with_capacity(self.slots.len());
        let mut stack: Vec<(u32, Option<usize>)> = vec![(self.root, None)];
        while let Some((i, right_of)) = stack.pop() {
            let index = out.len();
            if let Some(p) = right_of {
                out[p].offset = index as u32;
            }
            let s = &self.slots[i as usize];
            let b = s.bounds.to_aabb();
            if s.leaf {
                out.push(Node {
                    min: b.min,
                    offset: s.kids[0],
                    max: b.max,
                    count: s.kids[1],
                });
            } else {
                out.push(Node {
                    min: b.min,
                    offset: 0,
                    max: b.max,
                    count: 0,
                });
                stack.push((s.kids[1], Some(index)));
                stack.push((s.kids[0], None));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::builder::lbvh;
    use crate::accel::bvh::node::Bvh;
    use crate::accel::bvh::quality::TreeStats;

    #[test]
    fn reinsertion_keeps_every_leaf_and_lowers_the_cost() {
        let tris = crate::scene::builtin::builtin("cornell-water")
            .unwrap()
            .triangle_vertices();
        // The LBVH's Morton splits leave much to gain (measured: an SAH
        // cost of 23.1 down to 19.4).
        let before = lbvh::build(&tris, 4, false).compact();
        let after = optimize(before.clone());
        let cost = |s: &Skeleton| {
            let bvh: Bvh = s.clone().gather(&tris, false);
            TreeStats::with_block(&bvh, tris.len(), 2)
        };
        let (b, a) = (cost(&before), cost(&after));
        assert_eq!(a.nodes, b.nodes);
        assert_eq!(a.leaves, b.leaves);
        assert!(
            a.sah_cost < b.sah_cost * 0.9,
            "{} -> {}",
            b.sah_cost,
            a.sah_cost
        );
        // Every leaf keeps its range; every parent holds its children.
        let leaf_ranges = |s: &Skeleton| {
            let mut r: Vec<(u32, u32)> = s
                .nodes
                .iter()
                .filter(|n| n.is_leaf())
                .map(|n| (n.offset, n.count))
                .collect();
            r.sort();
            r
        };
        let (ranges, want) = (leaf_ranges(&after), leaf_ranges(&before));
        assert_eq!(ranges, want);
        for (i, n) in after.nodes.iter().enumerate() {
            if !n.is_leaf() {
                for c in [i + 1, n.offset as usize] {
                    assert!(n.bounds().contains(&after.nodes[c].bounds()));
                }
            }
        }
    }
}
