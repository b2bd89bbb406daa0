//! The lane order of a wide tree's nodes, for the any-hit traversals.
//!
//! The any-hit traversals (single-ray and packet, `traverse` and `packet`)
//! take a node's hit lanes in a fixed order: the lowest next, then the others
//! from the highest down. The closest-hit traversals sort by distance, so
//! lane order changes only which child an any-hit ray tries first, never an
//! answer. [`order_for_any_hit`] puts the child that is cheapest to finish
//! in lane 0, so it is tried first (a leaf when the node has one: one block
//! test that may end the ray), and the others in rising cost, so that the
//! traversal then tries the most expensive first: the largest subtrees,
//! which hold the most surface and so most likely an occluder.
//!
//! A child's cost is the SAH estimate of the work a ray does in it: a node
//! visit plus its children's costs weighted by their surface area over the
//! node's, and [`ORDER_BLOCK_COST`] per block of a leaf.
//!
//! The spatial-split builder's trees get this order (`BuildParams::
//! orders_lanes`); measured there, and why the other builders keep theirs:
//! `ORDER_BLOCK_COST`'s notes.

use arrayvec::ArrayVec;

use super::node::{leaf_block_count, WideBvh, WideNode, EMPTY, LEAF};
use crate::accel::bvh::params::ORDER_BLOCK_COST;

/// Reorders every node's lanes of `tree` as the module notes say. The tree
/// holds the same boxes and leaves, and every query's answer is unchanged.
pub(crate) fn order_for_any_hit<const N: usize>(tree: &mut WideBvh<N>) {
    if tree.nodes.is_empty() {
        return;
    }
    // Its reverse reaches every child before its parent, whatever the
    // builder's node numbering.
    let preorder = tree.preorder();
    let mut cost = vec![0f32; tree.nodes.len()];
    for &i in preorder.iter().rev() {
        let node = &mut tree.nodes[i as usize];
        cost[i as usize] = order_node(node, &cost);
    }
}

/// Reorders the lanes of `node` by the costs of its children (`costs` holds
/// those of its child nodes) and returns the node's own cost.
fn order_node<const N: usize>(node: &mut WideNode<N>, costs: &[f32]) -> f32 {
    // (lane, cost of the child, its box's surface area)
    let mut lanes: ArrayVec<(usize, f32, f32), N> = ArrayVec::new();
    for lane in (0..N).filter(|&l| node.child[l] != EMPTY) {
        let child = node.child[lane];
        let cost = if child & LEAF != 0 {
            ORDER_BLOCK_COST * leaf_block_count(child) as f32
        } else {
            costs[child as usize]
        };
        lanes.push((lane, cost, node.lane_bounds(lane).surface_area()));
    }
    let area = node.used_box().surface_area();
    let own = 1.0
        + lanes
            .iter()
            .map(|&(_, cost, a)| {
                if area > 0.0 {
                    cost * (a / area).min(1.0)
                } else {
                    cost
                }
            })
            .sum::<f32>();
    // Rising cost, ties by the builder's lane order (a stable sort), so the
    // order is the same for any thread count.
    lanes.sort_by(|a, b| a.1.total_cmp(&b.1));
    let old = *node;
    let mut new = WideNode::empty();
    for (slot, &(lane, ..)) in lanes.iter().enumerate() {
        for row in 0..6 {
            new.bounds[row][slot] = old.bounds[row][lane];
        }
        new.child[slot] = old.child[lane];
    }
    *node = new;
    own
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::params::BuildParams;
    use crate::accel::bvh::test_fixtures::{binary, random_tris};
    use crate::accel::bvh::wide::node::leaf_ref;
    use crate::geometry::Aabb;
    use glam::Vec3;

    fn cube(lo: f32, hi: f32) -> Aabb {
        Aabb {
            min: Vec3::splat(lo),
            max: Vec3::splat(hi),
        }
    }

    #[test]
    fn the_cheapest_child_comes_first_then_rising_cost() {
        // Lane 0: a node of cost 5; lane 1: a leaf of two blocks; lane 2: a
        // node of cost 9; lane 3: a leaf of one block.
        let mut node = WideNode::<8>::empty();
        node.set_lane(0, &cube(0.0, 1.0), 1);
        node.set_lane(1, &cube(1.0, 2.0), leaf_ref(0, 8));
        node.set_lane(2, &cube(2.0, 3.0), 2);
        node.set_lane(3, &cube(3.0, 4.0), leaf_ref(8, 1));
        let costs = [0.0, 5.0, 9.0];
        let own = order_node(&mut node, &costs);
        let expect = [leaf_ref(8, 1), leaf_ref(0, 8), 1, 2];
        assert_eq!(node.child[..4], expect);
        assert!(node.child[4..].iter().all(|&c| c == EMPTY));
        // Each lane kept its box.
        assert_eq!(node.lane_bounds(0), cube(3.0, 4.0));
        assert_eq!(node.lane_bounds(3), cube(2.0, 3.0));
        // One visit plus the children's costs weighted by area over the
        // node's (each unit cube has 6/96 of the area of the 4-cube around
        // them).
        let w = 6.0 / 96.0;
        let want = 1.0 + w * (ORDER_BLOCK_COST * 3.0 + 5.0 + 9.0);
        assert!((own - want).abs() < 1e-4, "{own} against {want}");
    }

    #[test]
    fn reordering_keeps_every_lane_box_and_block() {
        let tris = random_tris(3000, 11);
        let bvh = binary(&tris, &BuildParams::sah().with_width(8));
        let before = WideBvh::<8>::collapse(&bvh).unwrap();
        let mut after = before.clone();
        order_for_any_hit(&mut after);
        assert_eq!(after.blocks, before.blocks);
        assert_eq!(after.nodes.len(), before.nodes.len());
        for (a, b) in after.nodes.iter().zip(&before.nodes) {
            let lanes = |n: &WideNode<8>| {
                let mut v: Vec<(u32, [u32; 6])> = (0..8)
                    .map(|l| {
                        let bx = n.lane_bounds(l);
                        let bits = [bx.min, bx.max].map(|v| v.to_array().map(f32::to_bits));
                        (
                            n.child[l],
                            [
                                bits[0][0], bits[0][1], bits[0][2], bits[1][0], bits[1][1],
                                bits[1][2],
                            ],
                        )
                    })
                    .collect();
                v.sort();
                v
            };
            assert_eq!(lanes(a), lanes(b));
        }
        assert_ne!(after.nodes, before.nodes, "some node was reordered");
    }
}
