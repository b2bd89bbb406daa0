//! Wide BVHs (4 or 8 children per node) collapsed from the binary tree, with
//! the children's boxes in structure-of-arrays rows so that one SIMD operation
//! tests all of them ([`super::simd`]), and leaf triangles in blocks of four
//! tested together ([`super::leaf`]).
//!
//! Collapse: every wide node takes a binary interior node and repeatedly opens
//! the interior child of largest surface area until it has `N` children or only
//! leaves (as Embree's BVH4/BVH8 and Wald et al. 2008). The boxes are the
//! binary tree's and leaves keep their triangles, so a wide tree finds exactly
//! the binary tree's hits.
//!
//! Layout: nodes in depth-first order, `N` lanes each; a lane's `child` is a
//! node index, or (bit 31 set) a leaf: a run of [`Tri4`] blocks. Unused lanes
//! hold an inverted box, which the slab test rejects, so no lane mask is read.

use arrayvec::ArrayVec;
use glam::Vec3;

use super::leaf::{BlockTest, Ray4, Tri4, LANES};
use super::simd::{Kernel, NodeKernel, Portable, WideRay};
use super::traverse::{Counter, Traversal, CULL_SLACK, SLAB_SLACK};
use super::Bvh;
use crate::error::{Error, Result};
use crate::geometry::{safe_reciprocal, Aabb, Hit, Ray};

/// `child` of an unused lane.
pub const EMPTY: u32 = u32::MAX;
/// Set in `child` for a leaf lane.
const LEAF: u32 = 1 << 31;
const BLOCKS_SHIFT: u32 = 25;
/// Most blocks in one leaf (leaves of up to 256 triangles).
pub const MAX_LEAF_BLOCKS: usize = 64;
/// Blocks addressable by a leaf reference (2^25, about 134 million triangles).
pub const MAX_BLOCKS: usize = 1 << BLOCKS_SHIFT;

/// Stack entries of the traversals of ordinary trees; a tree whose deepest
/// path could need more (see [`WideBvh::stack_need`]) is traversed with
/// [`DEEP_STACK`] entries.
const STACK: usize = 64;
/// Enough for any tree of binary depth 64, the bound every builder keeps.
const DEEP_STACK: usize = 64 * 7 + 1;

/// A leaf lane's reference to `blocks` blocks starting at `first`.
#[inline]
fn leaf_ref(first: usize, blocks: usize) -> u32 {
    debug_assert!((1..=MAX_LEAF_BLOCKS).contains(&blocks) && first < MAX_BLOCKS);
    LEAF | ((blocks as u32 - 1) << BLOCKS_SHIFT) | first as u32
}

/// The block range of a leaf reference.
#[inline(always)]
fn leaf_blocks(child: u32) -> std::ops::Range<usize> {
    let first = (child & ((1 << BLOCKS_SHIFT) - 1)) as usize;
    let count = ((child & !LEAF) >> BLOCKS_SHIFT) as usize + 1;
    first..first + count
}

/// `N` children: their boxes as rows by axis and bound, and what each holds.
/// 128 bytes for `N = 4`, 256 for `N = 8`: whole cache lines.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct WideNode<const N: usize> {
    /// Rows `min_x, max_x, min_y, max_y, min_z, max_z`, one lane per child.
    pub bounds: [[f32; N]; 6],
    /// A node index, a leaf reference (bit 31 set), or [`EMPTY`].
    pub child: [u32; N],
}

impl<const N: usize> WideNode<N> {
    /// A node with every lane unused (inverted boxes).
    pub fn empty() -> Self {
        let mut bounds = [[f32::INFINITY; N]; 6];
        for row in [1, 3, 5] {
            bounds[row] = [f32::NEG_INFINITY; N];
        }
        WideNode {
            bounds,
            child: [EMPTY; N],
        }
    }

    pub fn set_lane(&mut self, lane: usize, b: &Aabb, child: u32) {
        for axis in 0..3 {
            self.bounds[2 * axis][lane] = b.min[axis];
            self.bounds[2 * axis + 1][lane] = b.max[axis];
        }
        self.child[lane] = child;
    }

    /// The box of lane `lane`.
    pub fn lane_bounds(&self, lane: usize) -> Aabb {
        let b = |row: usize| {
            Vec3::new(
                self.bounds[row][lane],
                self.bounds[row + 2][lane],
                self.bounds[row + 4][lane],
            )
        };
        Aabb {
            min: b(0),
            max: b(1),
        }
    }

    /// Whether lane `lane` holds a leaf.
    #[inline]
    pub fn is_leaf(&self, lane: usize) -> bool {
        self.child[lane] != EMPTY && self.child[lane] & LEAF != 0
    }

    /// Lanes in use.
    pub fn used(&self) -> usize {
        self.child.iter().filter(|&&c| c != EMPTY).count()
    }

    /// The leaf blocks of lane `lane` (empty for other lanes).
    pub fn leaf_blocks(&self, lane: usize) -> std::ops::Range<usize> {
        if self.is_leaf(lane) {
            leaf_blocks(self.child[lane])
        } else {
            0..0
        }
    }
}

/// A wide BVH over triangles in blocks of four.
#[derive(Clone, Debug)]
pub struct WideBvh<const N: usize> {
    /// `nodes[0]` is the root; empty for an empty tree.
    pub nodes: Vec<WideNode<N>>,
    /// Leaf triangles, leaf by leaf, four to a block.
    pub blocks: Vec<Tri4>,
    /// The most stack entries a traversal can need (pending siblings along the
    /// deepest path, plus one).
    pub stack_need: usize,
    /// The node kernel its queries use.
    pub kernel: Kernel,
}

/// The 4-wide tree (portable SIMD: one SSE register per row on x86-64).
pub type Bvh4 = WideBvh<4>;
/// The 8-wide tree (AVX2 where the CPU has it).
pub type Bvh8 = WideBvh<8>;

fn half_area(b: &Aabb) -> f32 {
    let e = b.max - b.min;
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl<const N: usize> WideBvh<N> {
    /// Collapses `bvh` (left intact) with the kernel the CPU supports best.
    pub fn collapse(bvh: &Bvh) -> Result<Self> {
        Self::collapse_with(
            bvh,
            if N == 8 {
                Kernel::detect()
            } else {
                Kernel::Portable
            },
        )
    }

    /// Collapses `bvh` using `kernel` for queries (AVX2 serves only `N = 8`).
    pub fn collapse_with(bvh: &Bvh, kernel: Kernel) -> Result<Self> {
        let kernel = if N == 8 { kernel } else { Kernel::Portable };
        let mut out = WideBvh {
            nodes: Vec::with_capacity(bvh.nodes.len() / (N - 1) + 1),
            blocks: Vec::with_capacity(bvh.tris.len() / LANES + bvh.nodes.len() / 4 + 1),
            stack_need: 1,
            kernel,
        };
        if !bvh.nodes.is_empty() {
            let (_, need) = out.collapse_node(bvh, 0)?;
            out.stack_need = need + 1;
        }
        Ok(out)
    }

    /// Makes the wide node for binary node `b` (a root leaf becomes a node with
    /// one leaf lane); returns its index and the stack its subtree can need.
    fn collapse_node(&mut self, bvh: &Bvh, b: u32) -> Result<(u32, usize)> {
        let node = &bvh.nodes[b as usize];
        let mut children: Vec<u32> = if node.is_leaf() {
            vec![b]
        } else {
            vec![b + 1, node.offset]
        };
        while children.len() < N {
            // Open the interior child with the largest surface area.
            let best = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| !bvh.nodes[c as usize].is_leaf())
                .max_by(|(_, &a), (_, &c)| {
                    half_area(&bvh.nodes[a as usize].bounds())
                        .total_cmp(&half_area(&bvh.nodes[c as usize].bounds()))
                })
                .map(|(i, _)| i);
            let Some(i) = best else { break };
            let c = children[i];
            let n = &bvh.nodes[c as usize];
            children.splice(i..=i, [c + 1, n.offset]);
        }
        let index = self.nodes.len();
        self.nodes.push(WideNode::empty());
        let mut wide = WideNode::empty();
        let mut deepest = 0;
        for (lane, &c) in children.iter().enumerate() {
            let n = bvh.nodes[c as usize];
            let child = if n.is_leaf() {
                let first = self.blocks.len();
                let range = n.offset as usize..(n.offset + n.count) as usize;
                for (tris, ids) in bvh.tris[range.clone()]
                    .chunks(LANES)
                    .zip(bvh.tri_ids[range].chunks(LANES))
                {
                    self.blocks.push(Tri4::new(tris, ids));
                }
                let blocks = self.blocks.len() - first;
                if blocks > MAX_LEAF_BLOCKS {
                    return Err(Error::Other(format!(
                        "wide BVH: a leaf of {} triangles (at most {} per leaf)",
                        n.count,
                        MAX_LEAF_BLOCKS * LANES
                    )));
                }
                if self.blocks.len() > MAX_BLOCKS {
                    return Err(Error::Other(format!(
                        "wide BVH: more than {} triangles",
                        MAX_BLOCKS * LANES
                    )));
                }
                leaf_ref(first, blocks)
            } else {
                let (i, need) = self.collapse_node(bvh, c)?;
                deepest = deepest.max(need);
                i
            };
            wide.set_lane(lane, &n.bounds(), child);
        }
        self.nodes[index] = wide;
        Ok((index as u32, children.len() - 1 + deepest))
    }

    /// Bytes of nodes and leaf blocks (scene indices included).
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<WideNode<N>>()
            + self.blocks.len() * std::mem::size_of::<Tri4>()
    }

    /// Triangles in the leaves.
    pub fn triangle_count(&self) -> usize {
        self.blocks.iter().map(Tri4::len).sum()
    }

    /// Closest hit with node kernel `K` and a stack of `S` entries, which must
    /// be at least [`Self::stack_need`].
    #[inline(always)]
    pub(crate) fn closest_with<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        counter: &mut C,
    ) -> Option<Hit> {
        if self.nodes.is_empty() || !ray.is_valid() {
            return None;
        }
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray);
        let wray = WideRay::new(ray, safe_reciprocal(ray.dir));
        let tmin = ray.tmin * (1.0 - SLAB_SLACK);
        let mut best: Option<Hit> = None;
        // Triangles are tested with `tmax` just above the best t, so that a hit
        // at the same t with a lower index is still found; `is_closer_than`
        // decides. Boxes are culled only beyond the best t by CULL_SLACK.
        let mut test_ray = *ray;
        let mut cut = ray.tmax * (1.0 + CULL_SLACK);
        // Not zero-filled: a cleared 64-entry stack per ray was 8% of the time.
        let mut stack: ArrayVec<(u32, f32), S> = ArrayVec::new();
        let mut current = 0u32;
        loop {
            if current & LEAF != 0 {
                for block in &self.blocks[leaf_blocks(current)] {
                    counter.triangles(block.len());
                    let hits = T::test4(&prepared, &ray4, &test_ray, block);
                    if hits.mask == 0 {
                        continue;
                    }
                    if let Some(hit) = hits.closest(&block.ids) {
                        if best.is_none_or(|b| hit.is_closer_than(&b)) {
                            best = Some(hit);
                            test_ray.tmax = hit.t.next_up();
                            cut = hit.t * (1.0 + CULL_SLACK);
                        }
                    }
                }
            } else {
                counter.node();
                let node = &self.nodes[current as usize];
                let (mask, near) = kernel.intersect(node, &wray, tmin, cut);
                if mask != 0 {
                    let first = mask.trailing_zeros() as usize;
                    let rest = mask & (mask - 1);
                    if rest == 0 {
                        // One child: no stack, no sorting.
                        current = node.child[first];
                        continue;
                    }
                    // Push the hit lanes farthest first, so the nearest is on top.
                    let base = stack.len();
                    let mut m = mask;
                    while m != 0 {
                        let lane = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let entry = (node.child[lane], near[lane]);
                        stack.push(entry);
                        let s = stack.as_mut_slice();
                        let mut j = s.len() - 1;
                        while j > base && s[j - 1].1 < entry.1 {
                            s[j] = s[j - 1];
                            j -= 1;
                        }
                        s[j] = entry;
                    }
                }
            }
            // Next: the nearest pending entry that can still hold a closer hit.
            loop {
                let Some((child, near)) = stack.pop() else {
                    return best;
                };
                if near <= cut {
                    current = child;
                    break;
                }
            }
        }
    }

    /// Any hit within the segment, with node kernel `K` and a stack of `S`
    /// entries (at least [`Self::stack_need`]). Children are visited in lane
    /// order: for short occlusion rays sorting by distance costs more than it
    /// saves (measured on AO rays).
    #[inline(always)]
    pub(crate) fn any_with<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        counter: &mut C,
    ) -> bool {
        if self.nodes.is_empty() || !ray.is_valid() {
            return false;
        }
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray);
        let wray = WideRay::new(ray, safe_reciprocal(ray.dir));
        let (tmin, tmax) = (ray.tmin * (1.0 - SLAB_SLACK), ray.tmax * (1.0 + SLAB_SLACK));
        let mut stack: ArrayVec<u32, S> = ArrayVec::new();
        let mut current = 0u32;
        loop {
            if current & LEAF != 0 {
                for block in &self.blocks[leaf_blocks(current)] {
                    counter.triangles(block.len());
                    if T::test4(&prepared, &ray4, ray, block).mask != 0 {
                        return true;
                    }
                }
            } else {
                counter.node();
                let node = &self.nodes[current as usize];
                let (mut mask, _) = kernel.intersect(node, &wray, tmin, tmax);
                if mask != 0 {
                    current = node.child[mask.trailing_zeros() as usize];
                    mask &= mask - 1;
                    while mask != 0 {
                        stack.push(node.child[mask.trailing_zeros() as usize]);
                        mask &= mask - 1;
                    }
                    continue;
                }
            }
            match stack.pop() {
                Some(c) => current = c,
                None => return false,
            }
        }
    }
}

impl Traversal for WideBvh<4> {
    fn closest<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        if self.stack_need <= STACK {
            self.closest_with::<Portable, T, C, STACK>(Portable, ray, counter)
        } else {
            self.closest_with::<Portable, T, C, DEEP_STACK>(Portable, ray, counter)
        }
    }

    fn any<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        if self.stack_need <= STACK {
            self.any_with::<Portable, T, C, STACK>(Portable, ray, counter)
        } else {
            self.any_with::<Portable, T, C, DEEP_STACK>(Portable, ray, counter)
        }
    }
}

impl Traversal for WideBvh<8> {
    fn closest<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        match (self.kernel, self.stack_need <= STACK) {
            (Kernel::Avx2(k), true) => k.closest::<T, C, STACK>(self, ray, counter),
            (Kernel::Avx2(k), false) => k.closest::<T, C, DEEP_STACK>(self, ray, counter),
            (Kernel::Portable, true) => {
                self.closest_with::<Portable, T, C, STACK>(Portable, ray, counter)
            }
            (Kernel::Portable, false) => {
                self.closest_with::<Portable, T, C, DEEP_STACK>(Portable, ray, counter)
            }
        }
    }

    fn any<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        match (self.kernel, self.stack_need <= STACK) {
            (Kernel::Avx2(k), true) => k.any::<T, C, STACK>(self, ray, counter),
            (Kernel::Avx2(k), false) => k.any::<T, C, DEEP_STACK>(self, ray, counter),
            (Kernel::Portable, true) => {
                self.any_with::<Portable, T, C, STACK>(Portable, ray, counter)
            }
            (Kernel::Portable, false) => {
                self.any_with::<Portable, T, C, DEEP_STACK>(Portable, ray, counter)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::BuildParams;
    use crate::geometry::Intersector;
    use crate::render::rng::Rng;

    fn random_tris(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = Rng::for_pixel(0, seed, 9);
        let mut v = |s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        (0..n)
            .map(|_| {
                let c = v(10.0);
                [c + v(0.5), c + v(0.5), c + v(0.5)]
            })
            .collect()
    }

    #[test]
    fn nodes_are_whole_cache_lines() {
        assert_eq!(std::mem::size_of::<WideNode<4>>(), 128);
        assert_eq!(std::mem::size_of::<WideNode<8>>(), 256);
        assert_eq!(std::mem::align_of::<WideNode<8>>(), 64);
        assert_eq!(std::mem::size_of::<Tri4>(), 160);
    }

    #[test]
    fn leaf_references_round_trip() {
        for (first, blocks) in [(0, 1), (7, 64), (MAX_BLOCKS - 1, 3)] {
            let r = leaf_ref(first, blocks);
            assert!(r & LEAF != 0 && r != EMPTY);
            assert_eq!(leaf_blocks(r), first..first + blocks);
        }
    }

    fn check_collapse<const N: usize>() {
        for n in [1, 2, 3, 5, 9, 64, 1000] {
            let tris = random_tris(n, n as u64);
            for params in [
                BuildParams::median(),
                BuildParams::sah().with_max_leaf_size(9),
            ] {
                let bvh = Bvh::build(&tris, &params).unwrap();
                let wide = WideBvh::<N>::collapse(&bvh).unwrap();
                // Every triangle lands in exactly one block lane.
                let mut ids: Vec<u32> = wide
                    .blocks
                    .iter()
                    .flat_map(|b| b.ids)
                    .filter(|&i| i != u32::MAX)
                    .collect();
                ids.sort();
                assert_eq!(ids, (0..n as u32).collect::<Vec<_>>(), "n = {n}");
                assert_eq!(wide.triangle_count(), n);
                // Leaves become ceil(count / 4) blocks each.
                let leaves: usize = bvh
                    .nodes
                    .iter()
                    .filter(|n| n.is_leaf())
                    .map(|n| (n.count as usize).div_ceil(LANES))
                    .sum();
                assert_eq!(wide.blocks.len(), leaves);
                // Each child's box lies inside its parent's lane box.
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
                if n >= 64 {
                    assert!(wide.nodes.len() * (N / 2) < bvh.nodes.len());
                }
                assert!(wide.stack_need <= STACK);
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

    fn check_hits<const N: usize>(kernel: Kernel)
    where
        WideBvh<N>: Traversal,
    {
        let tris = random_tris(2000, 11);
        for params in [BuildParams::median(), BuildParams::sah()] {
            let bvh = Bvh::build(&tris, &params).unwrap();
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
        let bvh = Bvh::build(&tris, &BuildParams::median()).unwrap();
        let wide = Bvh8::collapse(&bvh).unwrap();
        assert!(wide.stack_need <= DEEP_STACK);
        let ray = Ray::new(Vec3::new(0.0, 0.5, -1.0), Vec3::Z);
        assert_eq!(
            wide.intersect_using(&ray, Intersector::Mt),
            bvh.intersect_using(&ray, Intersector::Mt)
        );
    }
}
