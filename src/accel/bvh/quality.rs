//! Quality metrics of a built tree, independent of any ray: size, depth, leaf
//! fill, memory and the SAH cost. Measured traversal work per ray comes from
//! rendering with the counting tracer of [`crate::measure::stats`].

use serde::Serialize;

use super::node::Bvh;
use super::params::{C_INTERSECT, C_TRAVERSAL};

/// What `raylab stats` reports of a tree's shape.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TreeStats {
    pub nodes: usize,
    pub leaves: usize,
    /// Depth of the deepest leaf (the root has depth 0).
    pub max_depth: u32,
    /// Mean depth of leaves.
    pub mean_leaf_depth: f64,
    pub mean_leaf_size: f64,
    pub max_leaf_size: u32,
    /// Leaf slots (equals the triangle count unless triangles were split).
    pub leaf_references: usize,
    pub memory_bytes: usize,
    pub bytes_per_triangle: f64,
    /// `sum over interior nodes of C_t * A(n) + sum over leaves of C_i * B(N) * A(n)`,
    /// divided by `A(root)`, with `C_t = C_i = 1` and `B(N)` the leaf's
    /// triangle tests: `N`, or `ceil(N / sah_block)` for blocked leaves.
    pub sah_cost: f64,
    /// Triangles tested together in the cost above (1, or 4 for wide trees).
    pub sah_block: usize,
}

impl TreeStats {
    /// Measures `bvh`; `triangles` is the scene's triangle count (for bytes per
    /// triangle). The SAH cost counts one test per triangle.
    pub fn of(bvh: &Bvh, triangles: usize) -> TreeStats {
        Self::with_block(bvh, triangles, 1)
    }

    /// As [`TreeStats::of`], with leaf tests counted in blocks of `sah_block`.
    pub fn with_block(bvh: &Bvh, triangles: usize, sah_block: usize) -> TreeStats {
        let sah_block = sah_block.max(1);
        let mut s = TreeStats {
            sah_block,
            nodes: bvh.nodes.len(),
            leaf_references: bvh.tri_ids.len(),
            memory_bytes: bvh.memory_bytes(),
            bytes_per_triangle: bvh.memory_bytes() as f64 / triangles.max(1) as f64,
            ..TreeStats::default()
        };
        if bvh.nodes.is_empty() {
            return s;
        }
        let root_area = bvh.nodes[0].bounds().surface_area().max(f32::MIN_POSITIVE) as f64;
        let mut depth_sum = 0u64;
        let mut cost = 0f64;
        let mut stack = vec![(0u32, 0u32)];
        while let Some((i, depth)) = stack.pop() {
            let n = &bvh.nodes[i as usize];
            let area = n.bounds().surface_area() as f64 / root_area;
            if n.is_leaf() {
                s.leaves += 1;
                s.max_depth = s.max_depth.max(depth);
                s.max_leaf_size = s.max_leaf_size.max(n.count);
                depth_sum += depth as u64;
                cost += C_INTERSECT as f64 * n.count.div_ceil(sah_block as u32) as f64 * area;
            } else {
                cost += C_TRAVERSAL as f64 * area;
                stack.push((i + 1, depth + 1));
                stack.push((n.offset, depth + 1));
            }
        }
        s.mean_leaf_depth = depth_sum as f64 / s.leaves as f64;
        s.mean_leaf_size = s.leaf_references as f64 / s.leaves as f64;
        s.sah_cost = cost;
        s
    }
}
