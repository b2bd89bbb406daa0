//! Wide trees built top-down directly, as Embree's BVH4/BVH8 builders do: a
//! node keeps splitting its open child of largest surface area with the
//! binary builders' [`Splitter`] until it has `N` children; its leaves are
//! then packed into blocks and filled, and its other children become nodes in
//! turn, in parallel where they are large.
//!
//! A split depends only on a node's primitives and depth, so the tree is the
//! one [`WideBvh::collapse`] makes of the binary tree of the same splitter,
//! node for node and block for block (tested), without making that binary
//! tree or reading it back: collapsing it was a pass of cache misses over
//! nodes that existed only to be read once.
//!
//! Memory: a subtree below [`PARALLEL_CUTOFF`] primitives (or any subtree in
//! a serial build) is made into a piece of its own, indices relative to it;
//! the parallel top's nodes and the pieces are laid out in depth-first order
//! at the end ([`Layout`]). Pieces hold nodes and, for the leaves, only the
//! scene index of each triangle slot (4 bytes, not a 40-byte share of a
//! block). The final arrays are then written once each, in parallel, by
//! index: node `i` is read from its segment with its references made global,
//! block `b` is filled from its segment's slot indices and the scene. Nothing
//! is written twice (no zero fill, no copy of pieces into place), and a
//! serial build's one piece keeps its node array.

use arrayvec::ArrayVec;
use rayon::prelude::*;

use super::topdown::{prim_refs, try_split, Split, Splitter};
use crate::accel::bvh::leaf::{prefetch_triangles, Tri4, EMPTY_ID, LANES};
use crate::accel::bvh::node::padded;
use crate::accel::bvh::params::{FILL_AHEAD, MERGE_MAX, PARALLEL_CUTOFF};
use crate::accel::bvh::prim::{Box4, NodeInfo, PrimRef, Triangles};
use crate::accel::bvh::simd::Kernel;
use crate::accel::bvh::wide::node::{leaf_ref, pack_leaves, LeafLanes, LEAF};
use crate::accel::bvh::wide::{WideBvh, WideNode, EMPTY, MAX_SLOTS};
use crate::error::{Error, Result};

/// A child of the node being made: a range of the node's primitives, and its
/// split (`None`: a leaf). Kept small and passed by reference: a node's
/// eight of them were copied whole at every call.
#[derive(Clone, Copy)]
struct Kid {
    start: usize,
    len: usize,
    depth: u32,
    split: Split,
    /// The splits of the two halves of `split`, when already tried (to see
    /// whether the child is small enough to be one leaf, [`MERGE_MAX`]).
    halves: Option<(Split, Split)>,
    /// The lane box (the node box the binary tree would store) and its area,
    /// which orders the opening as in the collapse.
    bounds: crate::geometry::Aabb,
    area: f32,
}

impl Kid {
    fn new(start: usize, len: usize, info: &NodeInfo, depth: u32, split: Split) -> Kid {
        let bounds = padded(info.bounds.to_aabb());
        Kid {
            start,
            len,
            depth,
            split,
            halves: None,
            bounds,
            area: bounds.surface_area(),
        }
    }

    fn is_leaf(&self) -> bool {
        self.split.is_none()
    }

    /// The same child as the first of its own range (to be opened there).
    fn rebased(&self) -> Kid {
        Kid { start: 0, ..*self }
    }
}

/// What the builders need at every node.
struct Ctx<'a, S> {
    splitter: &'a S,
    parallel: bool,
}

impl<S: Splitter> Ctx<'_, S> {
    fn split(&self, prims: &mut [PrimRef], info: &NodeInfo, depth: u32) -> Split {
        try_split(self.splitter, prims, info, depth, self.parallel)
    }

    /// The children of the wide node made of binary node `prims` (whose
    /// split is `split`): the open child of largest area is split until there
    /// are `N`, as the collapse opens the binary tree's children.
    ///
    /// Every child made gets its split tried (to be opened here, or to become
    /// a node of its own), so both halves of an opened child are split as
    /// soon as they exist, at once on two threads where they are large: the
    /// top of the tree would otherwise partition its largest nodes one after
    /// another on one thread.
    fn open_children<const N: usize>(
        &self,
        prims: &mut [PrimRef],
        root: Kid,
        kids: &mut ArrayVec<Kid, N>,
    ) {
        debug_assert!(root.start == 0 && root.len == prims.len());
        kids.clear();
        kids.push(root);
        while kids.len() < N {
            let Some(i) = kids
                .iter()
                .enumerate()
                .filter(|(_, k)| !k.is_leaf())
                .max_by(|a, b| a.1.area.total_cmp(&b.1.area))
                .map(|(i, _)| i)
            else {
                break;
            };
            let k = &kids[i];
            let Some((mid, left, right)) = k.split else {
                unreachable!("only split children are opened");
            };
            let (start, len, depth) = (k.start, k.len, k.depth + 1);
            let (left_split, right_split) = match k.halves {
                Some(halves) => halves,
                None => {
                    let (lp, rp) = prims[start..start + len].split_at_mut(mid);
                    let mut split_left = || self.split(lp, &left, depth);
                    let mut split_right = || self.split(rp, &right, depth);
                    if self.parallel && len >= PARALLEL_CUTOFF {
                        rayon::join(split_left, split_right)
                    } else {
                        (split_left(), split_right())
                    }
                }
            };
            kids[i] = Kid::new(start, mid, &left, depth, left_split);
            kids.push(Kid::new(start + mid, len - mid, &right, depth, right_split));
        }
        // A full node's small interior children whose halves are both leaves
        // become one leaf each (the collapse does the same, [`MERGE_MAX`]).
        for k in kids.iter_mut() {
            let Some((mid, left, right)) = k.split else {
                continue;
            };
            if k.len > MERGE_MAX {
                continue;
            }
            let (lp, rp) = prims[k.start..k.start + k.len].split_at_mut(mid);
            let halves = (
                self.split(lp, &left, k.depth + 1),
                self.split(rp, &right, k.depth + 1),
            );
            if halves.0.is_none() && halves.1.is_none() {
                k.split = None;
            } else {
                k.halves = Some(halves);
            }
        }
    }

    /// The node of `kids` over `prims`, its leaves packed into new blocks at
    /// the end of `slots`' scene indices (leaf references count from their
    /// start); interior lanes get their box, and their child is left
    /// [`EMPTY`] for the caller to set.
    fn node_with_leaves<const N: usize>(
        &self,
        prims: &[PrimRef],
        kids: &ArrayVec<Kid, N>,
        slots: &mut Slots,
    ) -> Result<WideNode<N>> {
        let mut node = WideNode::empty();
        let leaves = LeafLanes::<N>::of(kids.iter().map(|k| k.is_leaf().then_some(k.len)));
        let starts = slots.pack::<N>(leaves.counts(), false)?;
        for (&lane, &slot) in leaves.lanes().iter().zip(&starts) {
            let kid = &kids[lane];
            let leaf = &prims[kid.start..kid.start + kid.len];
            for (id, p) in slots.ids[slot..slot + kid.len].iter_mut().zip(leaf) {
                *id = p.index();
            }
            node.set_lane(lane, &kid.bounds, leaf_ref(slot, kid.len));
        }
        for (lane, kid) in kids.iter().enumerate().filter(|(_, k)| !k.is_leaf()) {
            node.set_lane(lane, &kid.bounds, EMPTY);
        }
        Ok(node)
    }

    /// Makes the node of `kids` and its whole subtree serially into `piece`;
    /// returns the node's index there and the stack the subtree can need.
    fn serial<const N: usize>(
        &self,
        prims: &mut [PrimRef],
        kids: &ArrayVec<Kid, N>,
        piece: &mut Piece<N>,
    ) -> Result<(u32, usize)> {
        let index = piece.nodes.len();
        piece.nodes.push(WideNode::empty());
        let mut node = self.node_with_leaves(prims, kids, &mut piece.slots)?;
        let mut deepest = 0;
        let mut grand = ArrayVec::new();
        for (lane, kid) in kids.iter().enumerate().filter(|(_, k)| !k.is_leaf()) {
            let sub = &mut prims[kid.start..kid.start + kid.len];
            self.open_children(sub, kid.rebased(), &mut grand);
            let (child, need) = self.serial(sub, &grand, piece)?;
            deepest = deepest.max(need);
            node.child[lane] = child;
        }
        piece.nodes[index] = node;
        Ok((index as u32, kids.len() - 1 + deepest))
    }

    /// Makes the node of `kids` with its large interior children built in
    /// parallel (each into its own piece or parallel node).
    fn parallel<const N: usize>(
        &self,
        prims: &mut [PrimRef],
        kids: &ArrayVec<Kid, N>,
    ) -> Result<Built<N>> {
        let mut slots = Slots::default();
        let node = self.node_with_leaves(prims, kids, &mut slots)?;
        // The interior children's primitive ranges, carved apart so that each
        // task owns its own.
        let mut order: ArrayVec<usize, N> = (0..kids.len()).collect();
        order.sort_by_key(|&l| kids[l].start);
        let mut rest: &mut [PrimRef] = prims;
        let mut at = 0;
        let mut jobs: Vec<(usize, &mut [PrimRef])> = Vec::with_capacity(N);
        for lane in order {
            let kid = &kids[lane];
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(kid.start - at);
            let (mine, tail) = tail.split_at_mut(kid.len);
            rest = tail;
            at = kid.start + kid.len;
            if !kid.is_leaf() {
                jobs.push((lane, mine));
            }
        }
        let built: Vec<(usize, Result<Built<N>>)> = jobs
            .into_par_iter()
            .map(|(lane, sub)| {
                let kid = &kids[lane];
                let mut grand = ArrayVec::new();
                self.open_children(sub, kid.rebased(), &mut grand);
                let b = if kid.len >= PARALLEL_CUTOFF {
                    self.parallel(sub, &grand)
                } else {
                    let mut piece = Piece::with_capacity(kid.len, false);
                    self.serial(sub, &grand, &mut piece).map(|(_, need)| {
                        piece.need = need;
                        Built::Piece(piece)
                    })
                };
                (lane, b)
            })
            .collect();
        let mut children: Vec<(usize, Built<N>)> = Vec::with_capacity(N);
        let mut deepest = 0;
        for (lane, b) in built {
            let b = b?;
            deepest = deepest.max(b.need());
            children.push((lane, b));
        }
        // Emitted in lane order, as the serial build and the collapse do.
        children.sort_by_key(|&(lane, _)| lane);
        Ok(Built::Node {
            node,
            slots,
            children,
            need: kids.len() - 1 + deepest,
        })
    }
}

/// The triangle slots of a segment's leaves, four to a block: either the
/// scene index of each (the final pass fills the blocks: the top-down
/// builders' references carry boxes, not vertices; the parallel LBVH's
/// pieces have no boxes yet, [`finish_bounding`]) or the blocks already
/// filled (the serial LBVH reads every leaf triangle for its box and fills
/// its blocks then, [`super::lbvh_wide`]). A build uses one of the two.
#[derive(Default)]
pub(super) struct Slots {
    /// [`EMPTY_ID`] where a slot is unused.
    pub ids: Vec<u32>,
    pub blocks: Vec<Tri4>,
}

impl Slots {
    fn count(&self) -> usize {
        self.ids.len() + self.blocks.len() * LANES
    }

    /// Appends the blocks of one node's leaves of `counts` triangles, packed
    /// by [`pack_leaves`]: as empty blocks to fill when `filled`, else as
    /// scene indices ([`EMPTY_ID`] until set). Returns each leaf's first
    /// slot.
    #[inline]
    pub fn pack<const N: usize>(&mut self, counts: &[usize], filled: bool) -> Result<[usize; N]> {
        let first = if filled {
            self.blocks.len()
        } else {
            self.ids.len() / LANES
        };
        let (starts, taken) = pack_leaves::<N>(counts, first)?;
        if filled {
            self.blocks.resize(first + taken, Tri4::empty());
        } else {
            self.ids.resize((first + taken) * LANES, EMPTY_ID);
        }
        Ok(starts)
    }
}

/// A subtree made serially: nodes and leaf slots indexed from its own
/// arrays' starts, its root node first.
pub(super) struct Piece<const N: usize> {
    pub nodes: Vec<WideNode<N>>,
    pub slots: Slots,
    pub need: usize,
}

impl<const N: usize> Piece<N> {
    /// Room for the subtree of `prims` triangles as trees usually come out
    /// (more than that is a regrowth, not an error; reserving touches no
    /// memory), its slots as filled blocks when `filled` (asked of the
    /// kernel in huge pages: a serial build's blocks are the tree's), else as
    /// scene indices.
    pub fn with_capacity(prims: usize, filled: bool) -> Self {
        let slots = if filled {
            Slots {
                ids: Vec::new(),
                blocks: crate::os::huge_vec(prims / 2 + 1),
            }
        } else {
            Slots {
                ids: Vec::with_capacity(2 * prims + LANES),
                blocks: Vec::new(),
            }
        };
        Piece {
            nodes: Vec::with_capacity(prims / (N - 1) + 1),
            slots,
            need: 0,
        }
    }
}

/// A subtree: a piece, or a node whose children were made in parallel.
pub(super) enum Built<const N: usize> {
    Piece(Piece<N>),
    Node {
        /// Leaf lanes refer to `slots`; interior lanes' children are set
        /// when laid out ([`Layout::node`]).
        node: WideNode<N>,
        slots: Slots,
        children: Vec<(usize, Built<N>)>,
        need: usize,
    },
}

impl<const N: usize> Built<N> {
    pub fn need(&self) -> usize {
        match self {
            Built::Piece(p) => p.need,
            Built::Node { need, .. } => *need,
        }
    }

    /// Lists the subtree's segments depth-first (a parallel node before its
    /// children, children in lane order: the collapse's order); returns the
    /// index of its own segment.
    fn segments(self, out: &mut Vec<Segment<N>>) -> usize {
        let index = out.len();
        match self {
            Built::Piece(p) => out.push(Segment::Piece(p)),
            Built::Node {
                node,
                slots,
                children,
                ..
            } => {
                out.push(Segment::Node {
                    node,
                    slots,
                    children: Vec::new(),
                });
                let ids: Vec<(usize, usize)> = children
                    .into_iter()
                    .map(|(lane, child)| (lane, child.segments(out)))
                    .collect();
                if let Segment::Node { children, .. } = &mut out[index] {
                    *children = ids;
                }
            }
        }
        index
    }
}

/// One contiguous run of the final arrays: a parallel node with its own
/// leaf slots (children by segment index), or a piece.
enum Segment<const N: usize> {
    Node {
        node: WideNode<N>,
        slots: Slots,
        children: Vec<(usize, usize)>,
    },
    Piece(Piece<N>),
}

impl<const N: usize> Segment<N> {
    /// Nodes and triangle slots.
    fn size(&self) -> (usize, usize) {
        match self {
            Segment::Node { slots, .. } => (1, slots.count()),
            Segment::Piece(p) => (p.nodes.len(), p.slots.count()),
        }
    }
}

/// `node` with its node references moved up by `first_node` and its leaf
/// references by `first_slot` triangle slots.
fn shifted<const N: usize>(
    mut node: WideNode<N>,
    first_node: usize,
    first_slot: usize,
) -> WideNode<N> {
    for c in &mut node.child {
        if *c == EMPTY {
        } else if *c & LEAF != 0 {
            *c += first_slot as u32;
        } else {
            *c += first_node as u32;
        }
    }
    node
}

/// Where a block of the final array comes from ([`Layout::block_source`]).
enum BlockSource<'a> {
    Filled(&'a Tri4),
    Ids(&'a [u32]),
}

/// The segments in their final order and where each one's nodes and
/// triangle slots start in the tree's arrays.
struct Layout<const N: usize> {
    segments: Vec<Segment<N>>,
    /// `first_node[s]`, `first_slot[s]`: segment `s`'s first node and slot;
    /// one more entry holds the totals.
    first_node: Vec<usize>,
    first_slot: Vec<usize>,
}

/// The segment whose run `[starts[s], starts[s + 1])` holds `i`, found from
/// `hint` (the last answer): the nodes and blocks are written in increasing
/// order within each parallel job, so this is nearly always `hint` or the next.
#[inline]
fn segment_of(starts: &[usize], i: usize, hint: &mut usize) -> usize {
    let s = *hint;
    if !(s + 1 < starts.len() && starts[s] <= i && i < starts[s + 1]) {
        *hint = starts.partition_point(|&start| start <= i) - 1;
    }
    *hint
}

impl<const N: usize> Layout<N> {
    fn new(segments: Vec<Segment<N>>) -> Result<Self> {
        let (mut first_node, mut first_slot) = (vec![0], vec![0]);
        for s in &segments {
            let (n, b) = s.size();
            first_node.push(first_node.last().unwrap() + n);
            first_slot.push(first_slot.last().unwrap() + b);
        }
        if *first_slot.last().unwrap() > MAX_SLOTS {
            return Err(Error::Other(format!(
                "wide BVH: more than {MAX_SLOTS} triangle slots"
            )));
        }
        Ok(Layout {
            segments,
            first_node,
            first_slot,
        })
    }

    /// Node `i` of the tree, its references made global.
    fn node(&self, i: usize, hint: &mut usize) -> WideNode<N> {
        let s = segment_of(&self.first_node, i, hint);
        let (n0, s0) = (self.first_node[s], self.first_slot[s]);
        match &self.segments[s] {
            Segment::Piece(p) => shifted(p.nodes[i - n0], n0, s0),
            Segment::Node { node, children, .. } => {
                let mut node = shifted(*node, 0, s0);
                for &(lane, child) in children {
                    node.child[lane] = self.first_node[child] as u32;
                }
                node
            }
        }
    }

    /// Block `b`: filled already, or the scene indices of its four slots.
    fn block_source(&self, b: usize, hint: &mut usize) -> BlockSource<'_> {
        let slot = b * LANES;
        let s = segment_of(&self.first_slot, slot, hint);
        let local = slot - self.first_slot[s];
        let slots = match &self.segments[s] {
            Segment::Piece(p) => &p.slots,
            Segment::Node { slots, .. } => slots,
        };
        if slots.blocks.is_empty() {
            BlockSource::Ids(&slots.ids[local..local + LANES])
        } else {
            BlockSource::Filled(&slots.blocks[local / LANES])
        }
    }

    /// The tree's nodes, each written once into a fresh array, in parallel
    /// when `parallel`; a lone piece (a serial build) is taken as it is.
    fn nodes(&mut self, parallel: bool) -> Vec<WideNode<N>> {
        let total = *self.first_node.last().unwrap();
        if let [Segment::Piece(p)] = &mut self.segments[..] {
            return std::mem::take(&mut p.nodes);
        }
        let mut nodes = crate::os::huge_vec(total);
        if parallel {
            (0..total)
                .into_par_iter()
                .with_min_len(256)
                .map_init(|| 0, |hint, i| self.node(i, hint))
                .collect_into_vec(&mut nodes);
        } else {
            let mut hint = 0;
            nodes.extend((0..total).map(|i| self.node(i, &mut hint)));
        }
        nodes
    }

    /// Writes segment `s`'s blocks, filled from `triangles`, and its nodes
    /// (references made global) with every used lane's box into `blocks`
    /// and `nodes`, its parts of the tree's arrays; returns the unpadded box
    /// of its root's subtree. Interior children outside the segment (a
    /// parallel node's) have the box `outside` gives for their node index.
    fn write_bounded<T: Triangles + ?Sized>(
        &self,
        s: usize,
        nodes: &mut [WideNode<N>],
        blocks: &mut [Tri4],
        triangles: &T,
        outside: impl Fn(usize) -> Box4,
    ) -> Box4 {
        let (first_node, first_slot) = (self.first_node[s], self.first_slot[s]);
        let ids = match &self.segments[s] {
            Segment::Piece(p) => &p.slots.ids,
            Segment::Node { slots, .. } => &slots.ids,
        };
        // Leaf order jumps about the scene's triangle order: each block's
        // reads are asked for FILL_AHEAD blocks early, as in `blocks`.
        let ask = |b: usize, stage: u8| {
            if let Some(ids) = ids.get(b * LANES..(b + 1) * LANES) {
                prefetch_triangles(triangles, ids, stage);
            }
        };
        for (b, block) in blocks.iter_mut().enumerate() {
            ask(b + 2 * FILL_AHEAD, 0);
            ask(b + FILL_AHEAD, 1);
            block.fill(&ids[b * LANES..(b + 1) * LANES], triangles);
        }
        let mut hint = s;
        for (i, node) in nodes.iter_mut().enumerate() {
            *node = self.node(first_node + i, &mut hint);
        }
        // Bottom-up: in depth-first order a node's children come after it.
        let mut subtree = vec![Box4::EMPTY; nodes.len()];
        for i in (0..nodes.len()).rev() {
            let node = &mut nodes[i];
            let mut all = Box4::EMPTY;
            for lane in 0..N {
                let child = node.child[lane];
                if child == EMPTY {
                    continue;
                }
                let b = if node.is_leaf(lane) {
                    let mut b = Box4::EMPTY;
                    for slot in node.leaf_slots(lane) {
                        let local = slot - first_slot;
                        for v in blocks[local / LANES].triangle(local % LANES) {
                            b.grow(v.extend(0.0));
                        }
                    }
                    b
                } else {
                    match (child as usize).checked_sub(first_node) {
                        Some(local) if local < subtree.len() => subtree[local],
                        _ => outside(child as usize),
                    }
                };
                node.set_lane(lane, &padded(b.to_aabb()), child);
                all = all.union(b);
            }
            subtree[i] = all;
        }
        subtree.first().copied().unwrap_or(Box4::EMPTY)
    }

    /// The leaf blocks, each written once into a fresh array (copied where
    /// a builder filled them), in parallel when `parallel`; a lone piece's
    /// filled blocks are taken as they are. Leaf order jumps about the
    /// scene's triangle order, so each block's reads are asked for
    /// [`FILL_AHEAD`] blocks early: the fill was bound by waiting for them.
    fn blocks<T: Triangles + ?Sized>(&mut self, triangles: &T, parallel: bool) -> Vec<Tri4> {
        let count = *self.first_slot.last().unwrap() / LANES;
        if let [Segment::Piece(p)] = &mut self.segments[..] {
            if !p.slots.blocks.is_empty() {
                return std::mem::take(&mut p.slots.blocks);
            }
        }
        let this = &*self;
        let ask = |b: usize, stage: u8, hint: &mut usize| {
            if b >= count {
                return;
            }
            if let BlockSource::Ids(ids) = this.block_source(b, hint) {
                prefetch_triangles(triangles, ids, stage);
            }
        };
        let block = |hints: &mut [usize; 3], b: usize| {
            ask(b + 2 * FILL_AHEAD, 0, &mut hints[0]);
            ask(b + FILL_AHEAD, 1, &mut hints[1]);
            match this.block_source(b, &mut hints[2]) {
                BlockSource::Filled(block) => *block,
                BlockSource::Ids(ids) => {
                    let mut block = Tri4::empty();
                    block.fill(ids, triangles);
                    block
                }
            }
        };
        let mut blocks = crate::os::huge_vec(count);
        if parallel {
            (0..count)
                .into_par_iter()
                .with_min_len(1024)
                .map_init(|| [0; 3], block)
                .collect_into_vec(&mut blocks);
        } else {
            let mut hints = [0; 3];
            blocks.extend((0..count).map(|b| block(&mut hints, b)));
        }
        blocks
    }
}

/// Builds the `N`-wide tree over `triangles` with `splitter`, in parallel on
/// the current rayon pool when `parallel`.
pub fn build<const N: usize, T: Triangles + ?Sized, S: Splitter>(
    triangles: &T,
    splitter: &S,
    parallel: bool,
    kernel: Kernel,
) -> Result<WideBvh<N>> {
    let mut prims = prim_refs(triangles, parallel);
    if prims.is_empty() {
        return Ok(WideBvh::empty(kernel));
    }
    let ctx = Ctx { splitter, parallel };
    let info = NodeInfo::of(&prims, parallel);
    let split = ctx.split(&mut prims, &info, 0);
    let mut kids = ArrayVec::<Kid, N>::new();
    let root = Kid::new(0, prims.len(), &info, 0, split);
    ctx.open_children(&mut prims, root, &mut kids);
    let built = if parallel && prims.len() >= PARALLEL_CUTOFF {
        ctx.parallel(&mut prims, &kids)?
    } else {
        let mut piece = Piece::with_capacity(prims.len(), false);
        let (_, need) = ctx.serial(&mut prims, &kids, &mut piece)?;
        piece.need = need;
        Built::Piece(piece)
    };
    drop(prims);
    finish(triangles, built, parallel, kernel)
}

/// [`finish`] for a tree whose pieces hold scene indices and no boxes (the
/// LBVH's parallel build, whose splits need none): each segment's blocks are
/// filled in place and its nodes written with their boxes, bottom-up, a
/// leaf's from its triangles as just filled (the vertices a serial build
/// bounds its leaves with, so the same boxes): the pieces in parallel, then
/// the parallel nodes above them, children first.
pub(super) fn finish_bounding<const N: usize, T: Triangles + ?Sized>(
    triangles: &T,
    built: Built<N>,
    parallel: bool,
    kernel: Kernel,
) -> Result<WideBvh<N>> {
    let (mut out, layout) = laid_out(built, kernel)?;
    let (node_count, block_count) = (
        *layout.first_node.last().unwrap(),
        *layout.first_slot.last().unwrap() / LANES,
    );
    // Written whole here (a memset), so that each segment can be handed its
    // own part of both arrays.
    out.nodes = crate::os::huge_vec(node_count);
    out.nodes.resize(node_count, WideNode::empty());
    out.blocks = crate::os::huge_vec(block_count);
    out.blocks.resize(block_count, Tri4::empty());
    let mut parts = Vec::with_capacity(layout.segments.len());
    let (mut nodes, mut blocks) = (&mut out.nodes[..], &mut out.blocks[..]);
    for s in 0..layout.segments.len() {
        let (n, b) = layout.segments[s].size();
        let (mine, rest) = std::mem::take(&mut nodes).split_at_mut(n);
        nodes = rest;
        let (my_blocks, rest) = std::mem::take(&mut blocks).split_at_mut(b / LANES);
        blocks = rest;
        parts.push((s, mine, my_blocks));
    }
    let (pieces, tops): (Vec<_>, Vec<_>) = parts
        .into_iter()
        .partition(|(s, ..)| matches!(layout.segments[*s], Segment::Piece(_)));
    // The unpadded box of each segment's root's subtree.
    let mut boxes = vec![Box4::EMPTY; layout.segments.len()];
    let write = |(s, nodes, blocks): (usize, &mut [WideNode<N>], &mut [Tri4])| {
        let b = layout.write_bounded(s, nodes, blocks, triangles, |_| {
            unreachable!("a piece's interior children lie inside it")
        });
        (s, b)
    };
    let written: Vec<(usize, Box4)> = if parallel {
        pieces.into_par_iter().map(write).collect()
    } else {
        pieces.into_iter().map(write).collect()
    };
    for (s, b) in written {
        boxes[s] = b;
    }
    // A parallel node's segment comes before its children's.
    for (s, nodes, blocks) in tops.into_iter().rev() {
        let Segment::Node { children, .. } = &layout.segments[s] else {
            unreachable!("tops are parallel nodes");
        };
        let child_box = |node: usize| {
            let &(_, c) = children
                .iter()
                .find(|&&(_, c)| layout.first_node[c] == node)
                .expect("a parallel node's interior children are segment roots");
            boxes[c]
        };
        boxes[s] = layout.write_bounded(s, nodes, blocks, triangles, child_box);
    }
    out.fit_fused_reach();
    Ok(out)
}

/// The tree of `built` (its root's subtree, from a wide builder): nodes and
/// blocks laid out and filled, in parallel when `parallel`.
pub(super) fn finish<const N: usize, T: Triangles + ?Sized>(
    triangles: &T,
    built: Built<N>,
    parallel: bool,
    kernel: Kernel,
) -> Result<WideBvh<N>> {
    let (mut out, mut layout) = laid_out(built, kernel)?;
    out.blocks = layout.blocks(triangles, parallel);
    out.nodes = layout.nodes(parallel);
    out.fit_fused_reach();
    Ok(out)
}

/// An empty tree with the stack `built` needs, and where `built`'s
/// segments go in its arrays.
fn laid_out<const N: usize>(built: Built<N>, kernel: Kernel) -> Result<(WideBvh<N>, Layout<N>)> {
    let mut out = WideBvh::empty(kernel);
    out.stack_need = built.need() + 1;
    let mut segments = Vec::new();
    built.segments(&mut segments);
    Ok((out, Layout::new(segments)?))
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::super::pool::in_pool;
    use super::super::{skeleton, wide};
    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::accel::bvh::wide::WideBvh;
    use crate::accel::bvh::BuildParams;

    fn same_as_collapse<const N: usize>(tris: &Vec<[Vec3; 3]>, params: &BuildParams) {
        let direct = in_pool(params.threads, || wide::<N, _>(tris, params)).unwrap();
        let skeleton = in_pool(params.threads, || skeleton(tris, params)).unwrap();
        let collapsed = WideBvh::<N>::from_skeleton(&skeleton, tris, false).unwrap();
        let what = format!("N = {N}, {} triangles, {params:?}", tris.len());
        assert_eq!(direct.nodes.len(), collapsed.nodes.len(), "{what}");
        assert!(direct.nodes == collapsed.nodes, "{what}: nodes differ");
        assert!(direct.blocks == collapsed.blocks, "{what}: blocks differ");
        assert_eq!(direct.stack_need, collapsed.stack_need, "{what}");
    }

    #[test]
    fn direct_build_equals_the_collapsed_binary_tree() {
        // 12000 triangles pass the parallel cut-off: parallel nodes and pieces.
        for n in [1, 2, 5, 17, 300, 12_000] {
            let tris = random_tris(n, n as u64);
            for threads in [1, 2] {
                for params in [
                    BuildParams::sah().with_width(8),
                    BuildParams::sah().with_width(8).with_max_leaf_size(9),
                    BuildParams::median().with_width(8),
                ] {
                    same_as_collapse::<8>(&tris, &params.with_threads(threads));
                }
                same_as_collapse::<4>(
                    &tris,
                    &BuildParams::sah().with_width(4).with_threads(threads),
                );
            }
        }
    }
}
