//! The study's builder: at each node sort the triangles by centroid along one
//! axis, the axis cycling x, y, z with depth, and split at the middle (the left
//! child gets the extra triangle when the count is odd), down to one triangle per
//! leaf. The partition is found by selection in O(n) rather than a full sort; the
//! split sets are the same (ties broken by triangle index).

use super::topdown::{median_partition, side_infos, Split, Splitter};
use crate::accel::bvh::prim::{NodeInfo, PrimRef};

pub struct Median {
    pub max_leaf: usize,
}

impl Splitter for Median {
    fn split(&self, prims: &mut [PrimRef], _info: &NodeInfo, depth: u32, parallel: bool) -> Split {
        if prims.len() <= self.max_leaf {
            return None;
        }
        let mid = prims.len().div_ceil(2);
        median_partition(prims, depth as usize % 3, mid);
        let (left, right) = side_infos(prims, mid, parallel);
        Some((mid, left, right))
    }
}
