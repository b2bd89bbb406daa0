//! The wide tree's layout: nodes of `N` lanes whose boxes are rows by axis
//! and bound, leaf references packing a run of triangle slots into a lane's
//! `child`, and the tree itself (nodes in depth-first order, leaf blocks).
//! A lane's `child` is a node index, or (bit 31 set) a leaf: a run of
//! [`Tri4`] blocks. Unused lanes hold an inverted box, which the slab test
//! rejects, so no lane mask is read.

use glam::Vec3;

use super::super::leaf::{Tri4, LANES};
use super::super::params::FUSED_ORIGIN_REACH;
use super::super::simd::Kernel;
use crate::error::{Error, Result};
use crate::geometry::Aabb;

/// `child` of an unused lane.
pub const EMPTY: u32 = u32::MAX;
/// Set in `child` for a leaf lane.
pub(crate) const LEAF: u32 = 1 << 31;
/// A leaf reference holds the leaf's first triangle slot (block * 4 + lane)
/// in its low bits and its triangle count minus one above them.
pub(super) const SLOT_BITS: u32 = 27;
/// Most triangles in one leaf of a wide tree (the count's four bits above
/// the slot).
pub const MAX_LEAF: usize = 16;
/// Triangle slots addressable by a leaf reference (2^27, about 134 million).
pub const MAX_SLOTS: usize = 1 << SLOT_BITS;

/// Packs the leaves of one node, of `counts` triangles, into new blocks
/// numbered from `first_block`: first fit, largest first, so that leaves of
/// one to three triangles share blocks; a leaf of up to four triangles never
/// straddles two blocks. Returns each leaf's first slot (block * 4 + lane), in
/// the order of `counts`, and the number of blocks taken.
///
/// Inlined and on plain arrays: called out of line and returning an
/// `ArrayVec`, its result was written a lane at a time and read back whole,
/// a store-forwarding stall in every node of the builds (inlining it took
/// the low rung's one-thread engine build to 0.95-0.97 of its time).
#[inline]
pub(crate) fn pack_leaves<const N: usize>(
    counts: &[usize],
    first_block: usize,
) -> Result<([usize; N], usize)> {
    let n = counts.len();
    let mut order = [0; N];
    for (i, o) in order[..n].iter_mut().enumerate() {
        *o = i;
    }
    order[..n].sort_by_key(|&i| std::cmp::Reverse(counts[i]));
    let mut slots = [0; N];
    let mut open = [(0, 0); N]; // (block, lanes used)
    let mut opened = 0;
    let mut blocks = 0;
    for &i in &order[..n] {
        let count = counts[i];
        if count > MAX_LEAF {
            return Err(Error::usage(
                "--leaf-size",
                format!("wide trees take leaves of at most {MAX_LEAF} triangles, not {count}"),
            ));
        }
        let fit = open[..opened]
            .iter_mut()
            .find(|(_, used)| count <= LANES - *used);
        slots[i] = match fit {
            Some((block, used)) => {
                *used += count;
                *block * LANES + *used - count
            }
            None => {
                let first = first_block + blocks;
                let taken = count.div_ceil(LANES);
                blocks += taken;
                if !count.is_multiple_of(LANES) {
                    open[opened] = (first + taken - 1, count % LANES);
                    opened += 1;
                }
                first * LANES
            }
        };
    }
    Ok((slots, blocks))
}

/// A node's leaf children: their lanes and triangle counts, in lane order.
/// Plain arrays for the reason [`pack_leaves`] gives (against `ArrayVec`s,
/// a further 0.97-0.98 of the time).
pub(crate) struct LeafLanes<const N: usize> {
    lanes: [usize; N],
    counts: [usize; N],
    len: usize,
}

impl<const N: usize> LeafLanes<N> {
    /// From each lane's child: its triangle count if it is a leaf, else
    /// `None`.
    #[inline]
    pub fn of(children: impl IntoIterator<Item = Option<usize>>) -> Self {
        let mut leaves = LeafLanes {
            lanes: [0; N],
            counts: [0; N],
            len: 0,
        };
        for (lane, count) in children.into_iter().enumerate() {
            if let Some(count) = count {
                leaves.lanes[leaves.len] = lane;
                leaves.counts[leaves.len] = count;
                leaves.len += 1;
            }
        }
        leaves
    }

    /// The leaves' lanes.
    pub fn lanes(&self) -> &[usize] {
        &self.lanes[..self.len]
    }

    /// The leaves' triangle counts, as [`Self::lanes`].
    pub fn counts(&self) -> &[usize] {
        &self.counts[..self.len]
    }
}

/// A leaf lane's reference to `count` triangles from slot `slot` on.
#[inline]
pub(crate) fn leaf_ref(slot: usize, count: usize) -> u32 {
    debug_assert!((1..=MAX_LEAF).contains(&count) && slot < MAX_SLOTS);
    LEAF | ((count as u32 - 1) << SLOT_BITS) | slot as u32
}

/// The slots `first..end` of a leaf reference.
#[inline(always)]
pub(super) fn leaf_slots(child: u32) -> (usize, usize) {
    let first = (child & (MAX_SLOTS as u32 - 1)) as usize;
    let count = ((child & !LEAF) >> SLOT_BITS) as usize + 1;
    (first, first + count)
}

/// The blocks a leaf reference's triangles span (what [`for_leaf_blocks`]
/// visits).
#[inline]
pub(super) fn leaf_block_count(child: u32) -> usize {
    let (first, end) = leaf_slots(child);
    (end - 1) / LANES - first / LANES + 1
}

/// The part of a leaf in one block: `(block, lanes)`, `lanes` the mask of the
/// block's lanes that belong to the leaf. Calls `f` for each block in order
/// and stops early when it returns `true`; returns whether it did.
#[inline(always)]
pub(crate) fn for_leaf_blocks(child: u32, mut f: impl FnMut(usize, u32) -> bool) -> bool {
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

    /// The union of the used lanes' boxes (the node's own box).
    pub fn used_box(&self) -> Aabb {
        (0..N)
            .filter(|&lane| self.child[lane] != EMPTY)
            .fold(Aabb::EMPTY, |b, lane| b.union(self.lane_bounds(lane)))
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
    /// The largest origin coordinate (by magnitude) a single ray may have
    /// for the walk to take the fused node test; minus infinity (no ray)
    /// when the boxes themselves lie too far from the origin for their size
    /// ([`FUSED_ORIGIN_REACH`]). Set by [`WideBvh::fit_fused_reach`] when
    /// a tree is built or refitted; minus infinity until then, which only
    /// costs speed.
    pub fused_origin_limit: f32,
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
            fused_origin_limit: f32::NEG_INFINITY,
        }
    }

    /// Sets [`Self::fused_origin_limit`] from the root's box: rays from
    /// within [`FUSED_ORIGIN_REACH`] times its largest extent of the origin,
    /// if the box itself lies within that reach; none otherwise (an empty
    /// tree, or a small scene far from the origin).
    pub(crate) fn fit_fused_reach(&mut self) {
        self.fused_origin_limit = f32::NEG_INFINITY;
        let Some(root) = self.nodes.first() else {
            return;
        };
        let b = root.used_box();
        let reach = (b.max - b.min).max_element() * FUSED_ORIGIN_REACH;
        let farthest = b.min.abs().max(b.max.abs()).max_element();
        if reach.is_finite() && farthest <= reach {
            self.fused_origin_limit = reach;
        }
    }

    /// Bytes of nodes and leaf blocks (scene indices included).
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<WideNode<N>>()
            + self.blocks.len() * std::mem::size_of::<Tri4>()
    }

    /// The node indices in preorder from the root (empty for an empty tree).
    pub(crate) fn preorder(&self) -> Vec<u32> {
        let mut preorder = Vec::with_capacity(self.nodes.len());
        if self.nodes.is_empty() {
            return preorder;
        }
        let mut pending = vec![0u32];
        while let Some(i) = pending.pop() {
            preorder.push(i);
            for &child in &self.nodes[i as usize].child {
                if child != EMPTY && child & LEAF == 0 {
                    pending.push(child);
                }
            }
        }
        preorder
    }

    /// Triangles in the leaves.
    pub fn triangle_count(&self) -> usize {
        self.blocks.iter().map(Tri4::len).sum()
    }
}
