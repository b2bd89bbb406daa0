//! The SAH cost of a wide tree as its traversal walks it, in nanoseconds per
//! ray, with the cost of a node visit and of a leaf block test measured on
//! this machine through the traversal itself.
//!
//! A binary tree's SAH cost (`quality::TreeStats`) charges every binary node
//! and every pair of triangles one unit. The 8-wide tree the renderer
//! traverses is different: one visit tests eight boxes, the small children
//! merged into leaves are tested in blocks of four triangles, and several
//! small leaves of a node share a block. So the cost here walks the wide tree:
//! a ray that reaches a node (with the probability `A(node) / A(root)`) pays
//! one node visit, and a ray that reaches a leaf lane (probability
//! `A(lane) / A(root)`) pays one block test per block the leaf spans. Summed,
//! that is the expected time per ray a ray spends in node and block tests,
//! when no hit ends the walk early (the usual SAH assumption).
//!
//! The two unit costs come from [`TraversalCosts::measure`]: closest-hit
//! queries through [`Traversal`] on tiny hand-made trees, a chain of nodes
//! ending in a leaf whose triangles the rays miss, so everything stays in the
//! L1 cache. Lengthening the chain by `d` nodes adds `d` node visits per ray,
//! adding blocks to the leaf adds block tests; the differences of the median
//! times are the unit costs, with the ray's set-up cancelled out. They are
//! the costs of a hot cache: a real tree's cache misses come on top, which is
//! why the estimate is below a measured trace time.

use std::sync::OnceLock;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use super::node::{leaf_block_count, leaf_ref, WideBvh, WideNode, EMPTY};
use crate::accel::bvh::leaf::{BlockTest, Tri4, LANES};
use crate::accel::bvh::simd::Kernel;
use crate::accel::bvh::traverse::{NoCount, Traversal};
use crate::geometry::{Aabb, MollerTrumbore, Ray};
use crate::rng::Rng;

/// Rays per timed pass of a probe tree.
const PROBE_RAYS: usize = 4096;
/// Timed passes per probe tree (interleaved over the trees; medians taken).
const PROBE_REPS: usize = 15;
/// Node visits the long chain adds over the short one.
const PROBE_EXTRA_NODES: usize = 8;
/// Blocks in the large probe leaf (the most a leaf of 16 triangles spans).
const PROBE_BLOCKS: usize = 4;

/// The measured time of one node visit and one leaf block test in the 8-wide
/// traversal, with the triangle test and kernel they were measured with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TraversalCosts {
    pub node_ns: f64,
    pub block_ns: f64,
    /// `avx2` or `portable`.
    pub kernel: &'static str,
}

impl TraversalCosts {
    /// The costs of the renderer's default path (the 8-wide tree with the
    /// detected kernel, Moller-Trumbore), measured once per process.
    pub fn of_default_path() -> TraversalCosts {
        static COSTS: OnceLock<TraversalCosts> = OnceLock::new();
        *COSTS.get_or_init(|| Self::measure::<MollerTrumbore>(Kernel::detect()))
    }

    /// Measures a node visit and a block test of the 8-wide tree with
    /// `kernel` and the triangle test `T` (see the module notes). Takes a
    /// few tens of milliseconds. Each cost is at least 0.01 ns, so that a
    /// noisy difference never makes a cost negative.
    pub fn measure<T: BlockTest>(kernel: Kernel) -> TraversalCosts {
        let rays = probe_rays();
        let short = probe_tree(kernel, 1, 1);
        let long = probe_tree(kernel, 1 + PROBE_EXTRA_NODES, 1);
        let full = probe_tree(kernel, 1, PROBE_BLOCKS);
        let trees = [&short, &long, &full];
        let mut times: [Vec<f64>; 3] = Default::default();
        // One untimed pass each, then the trees in turn, so that a slow
        // moment of a shared machine falls on all three alike.
        for tree in trees {
            time_pass::<T>(tree, &rays);
        }
        for _ in 0..PROBE_REPS {
            for (tree, times) in trees.iter().zip(&mut times) {
                times.push(time_pass::<T>(tree, &rays));
            }
        }
        let [short, long, full] = times.map(|mut t| {
            t.sort_by(f64::total_cmp);
            t[t.len() / 2]
        });
        TraversalCosts {
            node_ns: ((long - short) / PROBE_EXTRA_NODES as f64).max(0.01),
            block_ns: ((full - short) / (PROBE_BLOCKS - 1) as f64).max(0.01),
            kernel: kernel.name(),
        }
    }

    /// One line for a report: what the costs are and their values.
    pub fn describe(&self) -> String {
        format!(
            "node visit {:.2} ns, block test {:.2} ns ({} kernel, Moller-Trumbore, measured in cache)",
            self.node_ns, self.block_ns, self.kernel
        )
    }
}

/// Nanoseconds per ray of closest-hit queries of `rays` on `tree`.
fn time_pass<T: BlockTest>(tree: &WideBvh<8>, rays: &[Ray]) -> f64 {
    let start = Instant::now();
    for ray in rays {
        std::hint::black_box(tree.closest::<T, NoCount>(std::hint::black_box(ray), &mut NoCount));
    }
    start.elapsed().as_secs_f64() * 1e9 / rays.len() as f64
}

/// Rays down the z axis through the unit square around the origin, slightly
/// tilted, each a different one so that no branch is learnt by heart.
fn probe_rays() -> Vec<Ray> {
    let mut rng = Rng::for_pixel(0, 0x5A4_C057, 0);
    (0..PROBE_RAYS)
        .map(|_| {
            let mut r = || rng.next_f32() - 0.5;
            let origin = Vec3::new(r(), r(), 2.0);
            let dir = Vec3::new(0.1 * r(), 0.1 * r(), -1.0);
            Ray::new(origin, dir)
        })
        .collect()
}

/// A chain of `nodes` nodes, each with one used lane whose box every probe
/// ray enters (the other seven lanes empty, which the kernels test all the
/// same), the last lane a leaf of `blocks` full blocks of triangles in the
/// plane z = 0 beside the rays' path, so every triangle test misses.
fn probe_tree(kernel: Kernel, nodes: usize, blocks: usize) -> WideBvh<8> {
    let lane_box = Aabb {
        min: Vec3::splat(-1.0),
        max: Vec3::splat(1.0),
    };
    let mut tree = WideBvh::<8>::empty(kernel);
    for i in 0..nodes {
        let mut node = WideNode::<8>::empty();
        let child = if i + 1 < nodes {
            (i + 1) as u32
        } else {
            leaf_ref(0, blocks * LANES)
        };
        node.set_lane(0, &lane_box, child);
        tree.nodes.push(node);
    }
    // Triangles in the corner x, y in [0.8, 0.95]: the rays cross their
    // plane inside the leaf's box but outside every triangle.
    let tri = [
        Vec3::new(0.8, 0.8, 0.0),
        Vec3::new(0.95, 0.8, 0.0),
        Vec3::new(0.8, 0.95, 0.0),
    ];
    for b in 0..blocks {
        let ids: Vec<u32> = (0..LANES as u32).map(|l| b as u32 * 4 + l).collect();
        tree.blocks.push(Tri4::new(&[tri; LANES], &ids));
    }
    tree.stack_need = 2;
    // As a built tree: single rays take the fused node test where the
    // kernel has it.
    tree.fit_fused_reach();
    tree
}

impl<const N: usize> WideBvh<N> {
    /// The expected nanoseconds per ray in node visits and block tests (see
    /// the module notes): every node visit costs `costs.node_ns`, weighted by
    /// its box's area over the root's, every leaf lane `costs.block_ns` per
    /// block it spans, weighted by the lane's box. The root's box is the
    /// union of its lanes'. 0 for an empty tree.
    pub fn sah_cost(&self, costs: &TraversalCosts) -> f64 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        let root_area = (root.used_box().surface_area() as f64).max(f64::MIN_POSITIVE);
        let mut cost = 0.0;
        let mut stack = vec![(0usize, 1.0f64)];
        while let Some((i, reach)) = stack.pop() {
            cost += reach * costs.node_ns;
            let node = &self.nodes[i];
            for lane in 0..N {
                let child = node.child[lane];
                if child == EMPTY {
                    continue;
                }
                let lane_reach = node.lane_bounds(lane).surface_area() as f64 / root_area;
                if node.is_leaf(lane) {
                    let blocks = leaf_block_count(child);
                    cost += lane_reach * blocks as f64 * costs.block_ns;
                } else {
                    stack.push((child as usize, lane_reach));
                }
            }
        }
        cost
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::accel::bvh::{build, BuildParams, Tree};

    const UNIT: TraversalCosts = TraversalCosts {
        node_ns: 1.0,
        block_ns: 10.0,
        kernel: "test",
    };

    fn cube(lo: f32, hi: f32) -> Aabb {
        Aabb {
            min: Vec3::splat(lo),
            max: Vec3::splat(hi),
        }
    }

    #[test]
    fn cost_of_a_hand_made_tree_is_the_area_weighted_sum() {
        // Root: lane 0 the unit cube [0, 2]^3 -> node 1; lane 1 [0, 1]^3 a
        // leaf of 6 triangles (two blocks: slots 0..6). Node 1: lane 0
        // [0, 1]^3 a leaf of 3 triangles in block 2, lane 3 [1, 2]^3 a leaf of
        // 1 triangle sharing block 2 (slot 11).
        let mut tree = WideBvh::<8>::empty(Kernel::Portable);
        let mut root = WideNode::<8>::empty();
        root.set_lane(0, &cube(0.0, 2.0), 1);
        root.set_lane(1, &cube(0.0, 1.0), leaf_ref(0, 6));
        let mut inner = WideNode::<8>::empty();
        inner.set_lane(0, &cube(0.0, 1.0), leaf_ref(8, 3));
        inner.set_lane(3, &cube(1.0, 2.0), leaf_ref(11, 1));
        tree.nodes = vec![root, inner];
        // Root box area 24, the small cubes 6: reach 1/4.
        // root visit 1 + node 1 (reach 1) + leaf of two blocks at 1/4 +
        // two one-block leaves at 1/4.
        let expected = 1.0 + 1.0 + 0.25 * 2.0 * 10.0 + 2.0 * 0.25 * 10.0;
        assert!((tree.sah_cost(&UNIT) - expected).abs() < 1e-12);
        assert_eq!(WideBvh::<8>::empty(Kernel::Portable).sah_cost(&UNIT), 0.0);
    }

    #[test]
    fn cost_of_a_built_tree_counts_every_node_and_block_at_least_once_in_reach() {
        let tris = random_tris(3000, 4);
        let tree = match build(&tris, &BuildParams::sah().with_width(8)).unwrap() {
            Tree::Wide8(t) => t,
            _ => unreachable!("width 8 builds an 8-wide tree"),
        };
        // With node visits alone free, the cost is the expected block tests;
        // with block tests free, the expected node visits: the root counts 1,
        // and no more than every node at full reach.
        let nodes_only = tree.sah_cost(&TraversalCosts {
            block_ns: 0.0,
            ..UNIT
        });
        assert!(nodes_only > 1.0 && nodes_only <= tree.nodes.len() as f64);
        let blocks_only = tree.sah_cost(&TraversalCosts {
            node_ns: 0.0,
            block_ns: 1.0,
            ..UNIT
        });
        assert!(blocks_only > 0.0 && blocks_only <= tree.blocks.len() as f64 * 2.0);
        // Linear in the unit costs.
        let sum = nodes_only + 10.0 * blocks_only;
        assert!((tree.sah_cost(&UNIT) - sum).abs() < 1e-9 * sum);
    }

    #[test]
    fn probe_trees_are_walked_as_built() {
        use crate::accel::bvh::traverse::Counts;
        // Every probe ray visits every node of the chain and tests every
        // block of the leaf, and hits nothing: the differences of the probe
        // times are node visits and block tests, nothing else.
        let kernel = Kernel::detect();
        for (nodes, blocks) in [(1, 1), (1 + PROBE_EXTRA_NODES, 1), (1, PROBE_BLOCKS)] {
            let tree = probe_tree(kernel, nodes, blocks);
            for ray in probe_rays().iter().take(200) {
                let mut counts = Counts::default();
                assert_eq!(tree.closest::<MollerTrumbore, _>(ray, &mut counts), None);
                assert_eq!(counts.nodes, nodes as u64);
                assert_eq!(counts.triangles, (blocks * LANES) as u64);
            }
        }
        let costs = TraversalCosts::measure::<MollerTrumbore>(kernel);
        assert!(costs.node_ns > 0.0 && costs.block_ns > 0.0);
    }
}
