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
use rayon::prelude::*;

use super::build::{Skeleton, Triangles};
use super::leaf::{BlockTest, Ray4, Tri4, LANES};
use super::simd::{prefetch, Kernel, NodeKernel, Portable, WideRay};
use super::traverse::{Counter, Traversal, CULL_SLACK, SLAB_SLACK};
use super::{Bvh, Node};
use crate::error::{Error, Result};
use crate::geometry::{safe_reciprocal, Aabb, Hit, Ray};

/// `child` of an unused lane.
pub const EMPTY: u32 = u32::MAX;
/// Set in `child` for a leaf lane.
pub(crate) const LEAF: u32 = 1 << 31;
/// A leaf reference holds the leaf's first triangle slot (block * 4 + lane)
/// in its low bits and its triangle count minus one above them.
const SLOT_BITS: u32 = 27;
/// Most triangles in one leaf of a wide tree.
pub const MAX_LEAF: usize = 16;

/// A wide node's interior child of at most this many triangles whose two
/// halves are both leaves is made one leaf of all of them (two blocks at
/// most), not a node of two leaf lanes. Such nodes were 37% of mesh:1e6's
/// 8-wide nodes, for a box test that saves at most one block test; as
/// leaves, the tree took 59.3 bytes per triangle instead of 68.6, and its
/// rays ran at the same speed or faster on one thread (cornell-sphere,
/// cornell-water, mesh:1e5, mesh:1e6, two trace runs each). The SAH with
/// pair-costed leaves would merge few of them: it prices the node's test at
/// one triangle pair, below what it costs.
pub const MERGE_MAX: usize = 8;
/// Triangle slots addressable by a leaf reference (2^27, about 134 million).
pub const MAX_SLOTS: usize = 1 << SLOT_BITS;

/// Stack entries of the traversals of ordinary trees; a tree whose deepest
/// path could need more (see [`WideBvh::stack_need`]) is traversed with
/// [`DEEP_STACK`] entries.
const STACK: usize = 64;
/// Enough for any tree of binary depth 64, the bound every builder keeps.
const DEEP_STACK: usize = 64 * 7 + 1;

/// Packs the leaves of one node, of `counts` triangles, into new blocks
/// numbered from `first_block`: first fit, largest first, so that leaves of
/// one to three triangles share blocks; a leaf of up to four triangles never
/// straddles two blocks. Returns each leaf's first slot (block * 4 + lane), in
/// the order of `counts`, and the number of blocks taken.
pub(crate) fn pack_leaves<const N: usize>(
    counts: &[usize],
    first_block: usize,
) -> Result<(ArrayVec<usize, N>, usize)> {
    let mut order: ArrayVec<usize, N> = (0..counts.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(counts[i]));
    let mut slots: ArrayVec<usize, N> = counts.iter().map(|_| 0).collect();
    let mut open: ArrayVec<(usize, usize), N> = ArrayVec::new(); // (block, lanes used)
    let mut blocks = 0;
    for i in order {
        let count = counts[i];
        if count > MAX_LEAF {
            return Err(Error::usage(
                "--leaf-size",
                format!("wide trees take leaves of at most {MAX_LEAF} triangles, not {count}"),
            ));
        }
        slots[i] = match open.iter_mut().find(|(_, used)| count <= LANES - *used) {
            Some((block, used)) => {
                *used += count;
                *block * LANES + *used - count
            }
            None => {
                let first = first_block + blocks;
                let taken = count.div_ceil(LANES);
                blocks += taken;
                if !count.is_multiple_of(LANES) {
                    open.push((first + taken - 1, count % LANES));
                }
                first * LANES
            }
        };
    }
    Ok((slots, blocks))
}

/// A leaf lane's reference to `count` triangles from slot `slot` on.
#[inline]
pub(crate) fn leaf_ref(slot: usize, count: usize) -> u32 {
    debug_assert!((1..=MAX_LEAF).contains(&count) && slot < MAX_SLOTS);
    LEAF | ((count as u32 - 1) << SLOT_BITS) | slot as u32
}

/// The slots `first..end` of a leaf reference.
#[inline(always)]
fn leaf_slots(child: u32) -> (usize, usize) {
    let first = (child & (MAX_SLOTS as u32 - 1)) as usize;
    let count = ((child & !LEAF) >> SLOT_BITS) as usize + 1;
    (first, first + count)
}

/// The part of a leaf in one block: `(block, lanes)`, `lanes` the mask of the
/// block's lanes that belong to the leaf. Calls `f` for each block in order
/// and stops early when it returns `true`; returns whether it did.
#[inline(always)]
fn for_leaf_blocks(child: u32, mut f: impl FnMut(usize, u32) -> bool) -> bool {
    let (mut slot, end) = leaf_slots(child);
    while slot < end {
        let base = slot & !(LANES - 1);
        let lo = slot - base;
        let hi = (end - base).min(LANES);
        let lanes = (0xF >> (LANES - hi)) & (0xF << lo);
        if f(base / LANES, lanes) {
            return true;
        }
        slot = base + LANES;
    }
    false
}

/// `N` children: their boxes as rows by axis and bound, and what each holds.
/// 128 bytes for `N = 4`, 224 for `N = 8`: aligned to 32 bytes, so every row
/// is one aligned AVX load; a 224-byte node spans four cache lines wherever it
/// starts, as a 256-byte one would, with 12.5% less memory.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
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

    /// The triangle slots (block * 4 + lane) of lane `lane`'s leaf (empty for
    /// other lanes).
    pub fn leaf_slots(&self, lane: usize) -> std::ops::Range<usize> {
        if self.is_leaf(lane) {
            let (first, end) = leaf_slots(self.child[lane]);
            first..end
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
    /// Leaf triangles, four to a block. A leaf's triangles are consecutive
    /// lanes; small leaves of one node share blocks.
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

impl<const N: usize> WideBvh<N> {
    /// A tree with no nodes, whose queries will use `kernel` (AVX2 serves
    /// only `N = 8`; other widths get the portable kernel).
    pub(crate) fn empty(kernel: Kernel) -> Self {
        WideBvh {
            nodes: Vec::new(),
            blocks: Vec::new(),
            stack_need: 1,
            kernel: if N == 8 { kernel } else { Kernel::Portable },
        }
    }

    /// Collapses `bvh` (left intact) with the kernel the CPU supports best.
    pub fn collapse(bvh: &Bvh) -> Result<Self> {
        Self::collapse_with(bvh, Kernel::detect())
    }

    /// Collapses `bvh` using `kernel` for queries (AVX2 serves only `N = 8`).
    pub fn collapse_with(bvh: &Bvh, kernel: Kernel) -> Result<Self> {
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
    pub fn from_skeleton<T: Triangles + ?Sized>(
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
        let leaves: ArrayVec<usize, N> = (0..children.len())
            .filter(|&lane| parts[lane].is_some())
            .collect();
        let counts: ArrayVec<usize, N> = leaves
            .iter()
            .map(|&lane| {
                let leaf = parts[lane].as_ref().expect("a leaf lane");
                leaf.iter().map(|n| n.count as usize).sum()
            })
            .collect();
        let (slots, blocks) = pack_leaves::<N>(&counts, sources.len() / LANES)?;
        sources.resize(sources.len() + blocks * LANES, EMPTY);
        if sources.len() > MAX_SLOTS {
            return Err(Error::Other(format!(
                "wide BVH: more than {MAX_SLOTS} triangle slots"
            )));
        }
        for ((&lane, &count), &slot) in leaves.iter().zip(&counts).zip(&slots) {
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

    /// Starts loading what `child` refers to: a node, or a leaf's first block.
    #[inline(always)]
    fn prefetch_child(&self, child: u32) {
        if child & LEAF == 0 {
            if let Some(node) = self.nodes.get(child as usize) {
                prefetch(node);
            }
        } else if let Some(block) = self.blocks.get(leaf_slots(child).0 / LANES) {
            prefetch(block);
        }
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
                for_leaf_blocks(current, |b, lanes| {
                    let block = &self.blocks[b];
                    counter.triangles(lanes.count_ones() as usize);
                    let mut hits = T::test4(&prepared, &ray4, &test_ray, block);
                    hits.mask &= lanes;
                    if let Some(hit) = hits.closest(&block.ids) {
                        if best.is_none_or(|b| hit.is_closer_than(&b)) {
                            best = Some(hit);
                            test_ray.tmax = hit.t.next_up();
                            cut = hit.t * (1.0 + CULL_SLACK);
                        }
                    }
                    false
                });
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
                        self.prefetch_child(current);
                        continue;
                    }
                    // Push the hit lanes farthest first, so the nearest is on top.
                    let base = stack.len();
                    let mut m = mask;
                    while m != 0 {
                        let lane = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let entry = (node.child[lane], near[lane]);
                        self.prefetch_child(entry.0);
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
                let hit = for_leaf_blocks(current, |b, lanes| {
                    counter.triangles(lanes.count_ones() as usize);
                    T::test4(&prepared, &ray4, ray, &self.blocks[b]).mask & lanes != 0
                });
                if hit {
                    return true;
                }
            } else {
                counter.node();
                let node = &self.nodes[current as usize];
                let (mut mask, _) = kernel.intersect(node, &wray, tmin, tmax);
                if mask != 0 {
                    current = node.child[mask.trailing_zeros() as usize];
                    self.prefetch_child(current);
                    mask &= mask - 1;
                    while mask != 0 {
                        let child = node.child[mask.trailing_zeros() as usize];
                        self.prefetch_child(child);
                        stack.push(child);
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
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::accel::bvh::BuildParams;
    use crate::geometry::Intersector;
    use crate::render::rng::Rng;

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
        let bvh = Bvh::build(&tris, &BuildParams::sah().with_width(8)).unwrap();
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
        let bvh = Bvh::build(&tris, &BuildParams::median().with_max_leaf_size(32)).unwrap();
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
                // Packing never takes more blocks than a block run per leaf,
                // and every leaf lane's slots hold exactly that leaf's triangles.
                let leaves: usize = bvh
                    .nodes
                    .iter()
                    .filter(|n| n.is_leaf())
                    .map(|n| (n.count as usize).div_ceil(LANES))
                    .sum();
                assert!(wide.blocks.len() <= leaves);
                let mut slots: Vec<usize> = Vec::new();
                for node in &wide.nodes {
                    for lane in 0..N {
                        for slot in node.leaf_slots(lane) {
                            let block = &wide.blocks[slot / LANES];
                            assert_ne!(block.ids[slot % LANES], u32::MAX);
                            let tri = block.triangle(slot % LANES);
                            let b = node.lane_bounds(lane);
                            assert!(tri.iter().all(|&v| b.contains(&Aabb::from_points(&[v]))));
                            slots.push(slot);
                        }
                    }
                }
                slots.sort();
                slots.dedup();
                assert_eq!(slots.len(), n, "each slot in exactly one leaf");
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

    fn check_merged<const N: usize>() {
        let tris = random_tris(5000, 21);
        // The wide trees' SAH (leaf tests in pairs): leaves of 2 to 4.
        let bvh = Bvh::build(&tris, &BuildParams::sah().with_sah_block(2)).unwrap();
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
