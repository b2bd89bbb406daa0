//! Wide BVHs (4 or 8 children per node) with the children's boxes in
//! structure-of-arrays rows so that one SIMD operation tests all of them
//! ([`super::simd`]), and leaf triangles in blocks of four tested together
//! ([`super::leaf`]). [`node`] is the layout, `collapse` makes a wide tree
//! from a binary one, `order` arranges the lanes for the any-hit walk,
//! `traverse` answers the queries.
//!
//! The layout, kernels and traversal choices and their measurements:
//! `docs/design.md`, "Wide trees".

mod collapse;
pub(crate) mod cost;
pub(crate) mod node;
mod order;
mod packet;
mod traverse;

pub use cost::TraversalCosts;
pub use node::{Bvh4, Bvh8, WideBvh, WideNode, EMPTY, MAX_SLOTS};
pub(crate) use order::order_for_any_hit;

#[cfg(test)]
pub(crate) mod tests {
    use super::node::{for_leaf_blocks, leaf_ref, leaf_slots, LEAF};
    use super::*;
    use crate::accel::bvh::leaf::{Tri4, LANES};
    use crate::accel::bvh::params::{DEEP_STACK, MERGE_MAX, STACK};
    use crate::accel::bvh::simd::Kernel;
    use crate::accel::bvh::test_fixtures::{binary, random_tris};
    use crate::accel::bvh::traverse::Traversal;
    use crate::accel::bvh::BuildParams;
    use crate::accel::bvh::Bvh;
    use crate::geometry::Intersector;
    use crate::geometry::{Aabb, Ray};
    use crate::rng::Rng;
    use glam::Vec3;

    #[test]
    fn nodes_have_no_padding_beyond_row_alignment() {
        assert_eq!(std::mem::size_of::<WideNode<4>>(), 128);
        assert_eq!(std::mem::size_of::<WideNode<8>>(), 224);
        assert_eq!(std::mem::align_of::<WideNode<8>>(), 32);
        assert_eq!(std::mem::size_of::<Tri4>(), 160);
    }

    #[test]
    fn small_leaves_share_blocks() {
        let tris = random_tris(4000, 5);
        let bvh = binary(&tris, &BuildParams::sah().with_width(8));
        let wide = Bvh8::collapse(&bvh).unwrap();
        let fill = wide.triangle_count() as f64 / (wide.blocks.len() * LANES) as f64;
        let mean_leaf = tris.len() as f64 / bvh.nodes.iter().filter(|n| n.is_leaf()).count() as f64;
        // Without sharing, fill could not exceed mean leaf size / 4.
        assert!(
            fill > mean_leaf / 4.0 + 0.05,
            "fill {fill}, mean leaf {mean_leaf}"
        );
    }

    #[test]
    fn leaves_over_sixteen_triangles_are_refused_for_wide_trees() {
        // 200 triangles halved down to at most 32 per leaf: leaves of 25.
        let tris = random_tris(200, 1);
        let bvh = binary(&tris, &BuildParams::median().with_max_leaf_size(32));
        let Err(err) = Bvh8::collapse(&bvh) else {
            panic!("a leaf of 25 triangles was accepted");
        };
        let err = err.to_string();
        assert!(err.contains("--leaf-size") && err.contains("16"), "{err}");
    }

    #[test]
    fn leaf_references_round_trip() {
        for (slot, count) in [(0, 1), (7, 16), (MAX_SLOTS - 3, 3)] {
            let r = leaf_ref(slot, count);
            assert!(r & LEAF != 0 && r != EMPTY);
            assert_eq!(leaf_slots(r), (slot, slot + count));
        }
    }

    #[test]
    fn leaf_blocks_cover_exactly_the_leaf_lanes() {
        let parts = |slot, count| {
            let mut v = Vec::new();
            for_leaf_blocks(leaf_ref(slot, count), |b, lanes| {
                v.push((b, lanes));
                false
            });
            v
        };
        assert_eq!(parts(0, 4), [(0, 0b1111)]);
        assert_eq!(parts(5, 2), [(1, 0b0110)]);
        assert_eq!(parts(7, 1), [(1, 0b1000)]);
        assert_eq!(parts(8, 9), [(2, 0b1111), (3, 0b1111), (4, 0b0001)]);
        assert_eq!(parts(6, 4), [(1, 0b1100), (2, 0b0011)]);
        // Stops at the first block whose call says so.
        let mut calls = 0;
        assert!(for_leaf_blocks(leaf_ref(0, 12), |_, _| {
            calls += 1;
            true
        }));
        assert_eq!(calls, 1);
    }

    /// Checks what every wide tree over `tris` must be: each triangle in
    /// exactly one block lane and one leaf slot, every leaf lane's slots
    /// holding triangles inside its box, every child node inside its
    /// parent's lane box, and a stack need within [`STACK`].
    pub(crate) fn assert_sound<const N: usize>(wide: &WideBvh<N>, tris: &[[Vec3; 3]]) {
        let n = tris.len();
        let mut ids: Vec<u32> = wide
            .blocks
            .iter()
            .flat_map(|b| b.ids)
            .filter(|&i| i != u32::MAX)
            .collect();
        ids.sort();
        assert_eq!(ids, (0..n as u32).collect::<Vec<_>>(), "n = {n}");
        assert_eq!(wide.triangle_count(), n);
        let mut slots: Vec<usize> = Vec::new();
        for node in &wide.nodes {
            for lane in 0..N {
                for slot in node.leaf_slots(lane) {
                    let block = &wide.blocks[slot / LANES];
                    assert_ne!(block.ids[slot % LANES], u32::MAX);
                    let tri = block.triangle(slot % LANES);
                    assert_eq!(tri, tris[block.ids[slot % LANES] as usize]);
                    let b = node.lane_bounds(lane);
                    assert!(tri.iter().all(|&v| b.contains(&Aabb::from_points(&[v]))));
                    slots.push(slot);
                }
            }
        }
        slots.sort();
        slots.dedup();
        assert_eq!(slots.len(), n, "each slot in exactly one leaf");
        for node in &wide.nodes {
            for lane in 0..N {
                let c = node.child[lane];
                if c != EMPTY && c & LEAF == 0 {
                    let child = &wide.nodes[c as usize];
                    for l in 0..child.used() {
                        assert!(node.lane_bounds(lane).contains(&child.lane_bounds(l)));
                    }
                }
            }
        }
        assert!(wide.stack_need <= STACK);
    }

    fn check_collapse<const N: usize>() {
        for n in [1, 2, 3, 5, 9, 64, 1000] {
            let tris = random_tris(n, n as u64);
            for params in [
                BuildParams::median(),
                BuildParams::sah().with_max_leaf_size(9),
            ] {
                let bvh = binary(&tris, &params);
                let wide = WideBvh::<N>::collapse(&bvh).unwrap();
                assert_sound(&wide, &tris);
                // Packing never takes more blocks than a block run per leaf.
                let leaves: usize = bvh
                    .nodes
                    .iter()
                    .filter(|n| n.is_leaf())
                    .map(|n| (n.count as usize).div_ceil(LANES))
                    .sum();
                assert!(wide.blocks.len() <= leaves);
                if n >= 64 {
                    assert!(wide.nodes.len() * (N / 2) < bvh.nodes.len());
                }
            }
        }
        assert!(WideBvh::<N>::collapse(&Bvh::default())
            .unwrap()
            .nodes
            .is_empty());
    }

    #[test]
    fn collapse_keeps_every_triangle_and_nests_boxes() {
        check_collapse::<4>();
        check_collapse::<8>();
    }

    fn check_merged<const N: usize>() {
        let tris = random_tris(5000, 21);
        // The wide trees' SAH (leaf tests in pairs): leaves of 2 to 4.
        let bvh = binary(&tris, &BuildParams::sah().with_sah_block(2));
        let binary_small = (1..bvh.nodes.len())
            .filter(|&i| {
                let n = bvh.nodes[i];
                !n.is_leaf() && {
                    let (l, r) = (bvh.nodes[i + 1], bvh.nodes[n.offset as usize]);
                    l.is_leaf() && r.is_leaf() && (l.count + r.count) as usize <= MERGE_MAX
                }
            })
            .count();
        assert!(
            binary_small > 100,
            "too few small binary nodes: {binary_small}"
        );
        let wide = WideBvh::<N>::collapse(&bvh).unwrap();
        let mut merged = 0;
        for node in &wide.nodes {
            for lane in 0..N {
                let c = node.child[lane];
                if c == EMPTY {
                    continue;
                }
                if node.is_leaf(lane) {
                    merged += (node.leaf_slots(lane).len() > 4) as usize;
                    continue;
                }
                // No child node is only two leaves small enough to be one.
                let child = &wide.nodes[c as usize];
                let leaf_lanes: Vec<usize> = (0..N).filter(|&l| child.is_leaf(l)).collect();
                let tris: usize = leaf_lanes.iter().map(|&l| child.leaf_slots(l).len()).sum();
                assert!(
                    !(child.used() == 2 && leaf_lanes.len() == 2 && tris <= MERGE_MAX),
                    "a node of two small leaves under a full node"
                );
            }
        }
        // Leaves of the binary tree hold at most 4 (the default leaf size):
        // larger ones are merged pairs of leaves.
        assert!(merged > 5, "too few merged leaves: {merged}");
        assert_eq!(wide.triangle_count(), tris.len());
    }

    #[test]
    fn small_children_of_two_leaves_become_one_leaf() {
        check_merged::<4>();
        check_merged::<8>();
    }

    fn check_hits<const N: usize>(kernel: Kernel)
    where
        WideBvh<N>: Traversal,
    {
        let tris = random_tris(2000, 11);
        for params in [BuildParams::median(), BuildParams::sah()] {
            let bvh = binary(&tris, &params);
            let wide = WideBvh::<N>::collapse_with(&bvh, kernel).unwrap();
            let mut rng = Rng::for_pixel(2, 13, 1);
            for k in 0..20_000 {
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 16.0 - 3.0;
                let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
                let mut ray = Ray::new(o, d.normalize());
                if k % 4 == 0 {
                    ray.tmax = rng.next_f32() * 8.0;
                }
                for i in [Intersector::Mt, Intersector::Watertight] {
                    assert_eq!(
                        wide.intersect_using(&ray, i),
                        bvh.intersect_using(&ray, i),
                        "ray {k}"
                    );
                    assert_eq!(
                        wide.occluded_using(&ray, i),
                        bvh.occluded_using(&ray, i),
                        "ray {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn wide_hits_equal_binary_hits() {
        check_hits::<4>(Kernel::Portable);
        check_hits::<8>(Kernel::Portable);
        check_hits::<8>(Kernel::detect());
    }

    #[test]
    fn deep_trees_use_the_deep_stack_and_still_agree() {
        // A chain of nested slivers: the median builder makes a deep tree.
        let tris: Vec<[Vec3; 3]> = (0..3000)
            .map(|i| {
                let s = 1.0 + i as f32 * 1e-3;
                [
                    Vec3::new(-s, 0.0, s),
                    Vec3::new(s, 0.0, s),
                    Vec3::new(0.0, s, s),
                ]
            })
            .collect();
        let bvh = binary(&tris, &BuildParams::median());
        let wide = Bvh8::collapse(&bvh).unwrap();
        assert!(wide.stack_need <= DEEP_STACK);
        let ray = Ray::new(Vec3::new(0.0, 0.5, -1.0), Vec3::Z);
        assert_eq!(
            wide.intersect_using(&ray, Intersector::Mt),
            bvh.intersect_using(&ray, Intersector::Mt)
        );
    }
}
