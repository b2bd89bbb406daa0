//! Closest-hit and any-hit traversal of the wide trees, generic over the node
//! kernel ([`super::super::simd`]) and the block triangle test; the AVX2
//! entry points (the generic traversal compiled with AVX2 enabled); and the
//! one dispatch of the packet queries, [`WideBvh::packet_query`], with its
//! AVX2 and AVX-512 entry points. Their four `unsafe` calls are the only
//! ones here, each proved by an [`Avx2`] or [`Avx512`] value (made only by
//! their `detect`, which checks the CPU).

use arrayvec::ArrayVec;

use super::super::leaf::{bits, BlockTest, Ray4, LANES};
use super::super::params::{CULL_SLACK, DEEP_STACK, SLAB_SLACK, STACK};
use super::super::simd::{
    prefetch, Avx2, Avx2Fused, Avx512, Kernel, NodeKernel, Portable, WideRay,
};
#[cfg(target_arch = "x86_64")]
use super::super::simd_lanes::Lanes;
#[cfg(target_arch = "x86_64")]
use super::super::simd_packet::{GrownPacket, SimdPacket};
use super::super::simd_packet::{PacketKernel, PerRay, PACKET, PACKET16};
use super::super::simd_stack::{nearest_lane, push_by_distance, ChildStack};
use super::super::traverse::{Counter, Traversal};
use super::node::{for_leaf_blocks, leaf_slots, WideBvh, LEAF};
use crate::geometry::{Hit, Ray, SlabRay, TriangleTest};

impl<const N: usize> WideBvh<N> {
    /// Starts loading what `child` refers to: a node, or a leaf's first block.
    #[inline(always)]
    pub(super) fn prefetch_child(&self, child: u32) {
        if child & LEAF == 0 {
            if let Some(node) = self.nodes.get(child as usize) {
                prefetch(node);
            }
        } else if let Some(block) = self.blocks.get(leaf_slots(child).0 / LANES) {
            prefetch(block);
        }
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
        self.closest_from::<K, T, C, S>(kernel, ray, 0, None, counter)
    }

    /// The closest of `best` and the hits in the subtree `start` refers to (a
    /// node or a leaf), for a valid ray in a non-empty tree: the single-ray
    /// traversal, which the packet traversal also hands its last active ray.
    #[inline(always)]
    pub(crate) fn closest_from<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        start: u32,
        best: Option<Hit>,
        counter: &mut C,
    ) -> Option<Hit> {
        let wray = WideRay::new(&SlabRay::new(ray));
        self.closest_walk::<K, T, C, S>(kernel, ray, &wray, start, best, counter)
    }

    /// [`Self::closest_from`] with the ray already prepared for the node
    /// kernel (`wray`, made from `ray`).
    #[inline(always)]
    pub(crate) fn closest_walk<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        wray: &WideRay,
        start: u32,
        mut best: Option<Hit>,
        counter: &mut C,
    ) -> Option<Hit> {
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray);
        let tmin = ray.tmin * (1.0 - SLAB_SLACK);
        // Triangles are tested with `tmax` just above the best t, so that a hit
        // at the same t with a lower index is still found; `is_closer_than`
        // decides. Boxes are culled only beyond the best t by CULL_SLACK.
        let mut test_ray = *ray;
        let mut cut = ray.tmax * (1.0 + CULL_SLACK);
        if let Some(hit) = best {
            test_ray.tmax = hit.t.next_up();
            cut = hit.t * (1.0 + CULL_SLACK);
        }
        let mut stack = ChildStack::<S>::new();
        let mut current = start;
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
                let (mask, near) = kernel.intersect_for::<T>(node, wray, tmin, cut);
                if mask != 0 {
                    // The nearest hit child is visited next (no prefetch: it
                    // is loaded next), the others pushed farthest first, so
                    // that the nearest of them is on top.
                    let next = if mask & (mask - 1) == 0 {
                        mask.trailing_zeros() as usize
                    } else {
                        let base = stack.len();
                        let next = push_by_distance(kernel, &mut stack, node, mask, &near);
                        for child in stack.children_from(base) {
                            self.prefetch_child(child);
                        }
                        next
                    };
                    current = node.child[next];
                    continue;
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
    /// saves (measured on AO rays). The order is not neutral: on Sponza,
    /// Embree's (the last hit lane first) makes shadow rays 1.25-1.4x faster
    /// and AO rays 1.1-1.3x slower, there and on other scenes (docs/results.md,
    /// "A real architecture scene: Sponza"). The spatial-split builder's trees
    /// put their lanes in an order made for this walk (`super::order`).
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
        self.any_from::<K, T, C, S>(kernel, ray, 0, counter)
    }

    /// Whether anything in the subtree `start` refers to is hit within the
    /// segment, for a valid ray in a non-empty tree (as [`Self::closest_from`]).
    #[inline(always)]
    pub(crate) fn any_from<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        start: u32,
        counter: &mut C,
    ) -> bool {
        let wray = WideRay::new(&SlabRay::new(ray));
        self.any_walk::<K, T, C, S>(kernel, ray, &wray, start, counter)
    }

    /// [`Self::any_from`] with the ray already prepared for the node kernel.
    #[inline(always)]
    pub(crate) fn any_walk<K: NodeKernel<N>, T: BlockTest, C: Counter, const S: usize>(
        &self,
        kernel: K,
        ray: &Ray,
        wray: &WideRay,
        start: u32,
        counter: &mut C,
    ) -> bool {
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray);
        let (tmin, tmax) = (ray.tmin * (1.0 - SLAB_SLACK), ray.tmax * (1.0 + SLAB_SLACK));
        let mut stack: ArrayVec<u32, S> = ArrayVec::new();
        let mut current = start;
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
                let (mut mask, _) = kernel.intersect_for::<T>(node, wray, tmin, tmax);
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

/// Pushes `entry` onto `stack`, keeping the entries from `base` on ordered
/// by `near` descending (farthest first, so the nearest is popped first):
/// the insertion step of the packet traversal's closest hits and of the
/// nearest-first id walks. The single-ray closest hit keeps its entries in
/// `simd_stack::ChildStack` (split arrays the AVX2 network stores into),
/// whose scalar `push_by_distance` is this step on those arrays.
#[inline(always)]
pub(super) fn push_sorted<E: Copy, const S: usize>(
    stack: &mut ArrayVec<E, S>,
    base: usize,
    entry: E,
    near: impl Fn(&E) -> f32,
) {
    stack.push(entry);
    let s = stack.as_mut_slice();
    let key = near(&entry);
    let mut j = s.len() - 1;
    while j > base && near(&s[j - 1]) < key {
        s[j] = s[j - 1];
        j -= 1;
    }
    s[j] = entry;
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

/// A packet query: what [`WideBvh::packet_query`] runs on a packet, the
/// closest hits ([`Closest`]) or occlusion ([`Any`]).
pub trait PacketQuery {
    /// Per ray of the packet, the answer.
    type Out: ?Sized;
    /// The query's traversal of `bvh` with packet tests `P` (for the last
    /// rays of an entry the single-ray node kernel `K` and triangle test
    /// `T`) and stacks of `S` entries.
    fn run<K: NodeKernel<8>, T: BlockTest, P: PacketKernel<R>, const R: usize, const S: usize>(
        bvh: &WideBvh<8>,
        kernel: K,
        packet: P,
        rays: &[Ray],
        out: &mut Self::Out,
    );
}

/// The closest hit of each ray of a packet ([`WideBvh::closest_packet`]).
pub enum Closest {}

/// Whether each ray of a packet is occluded ([`WideBvh::any_packet`]).
pub enum Any {}

impl PacketQuery for Closest {
    type Out = [Option<Hit>];
    #[inline(always)]
    fn run<K: NodeKernel<8>, T: BlockTest, P: PacketKernel<R>, const R: usize, const S: usize>(
        bvh: &WideBvh<8>,
        kernel: K,
        packet: P,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) {
        bvh.closest_packet::<K, T, P, R, S>(kernel, packet, rays, hits)
    }
}

impl PacketQuery for Any {
    type Out = [bool];
    #[inline(always)]
    fn run<K: NodeKernel<8>, T: BlockTest, P: PacketKernel<R>, const R: usize, const S: usize>(
        bvh: &WideBvh<8>,
        kernel: K,
        packet: P,
        rays: &[Ray],
        occluded: &mut [bool],
    ) {
        bvh.any_packet::<K, T, P, R, S>(kernel, packet, rays, occluded)
    }
}

impl WideBvh<8> {
    /// Query `Q` (closest hits or occlusion) of a packet of up to `width`
    /// rays ([`PACKET`] or [`PACKET16`]; see `super::packet`) with triangle
    /// test `T`, into `out` (as long as `rays`). The one place the packet
    /// kernels are chosen:
    ///
    /// - 8 rays and AVX2: the rays in AVX2 lanes ([`SimdPacket`]`<Avx2>`)
    ///   with Moller-Trumbore, each ray with the AVX2 single-ray kernels
    ///   with the watertight test;
    /// - 16 rays and AVX-512F: the same in AVX-512 lanes
    ///   (`SimdPacket<Avx512>`), the same kernel body;
    /// - else each ray with the portable single-ray kernels (16 rays without
    ///   AVX-512: correct, not fast).
    pub fn packet_query<Q: PacketQuery, T: BlockTest>(
        &self,
        width: usize,
        rays: &[Ray],
        out: &mut Q::Out,
    ) {
        debug_assert!(width == PACKET || width == PACKET16);
        debug_assert!(rays.len() <= width);
        #[cfg(target_arch = "x86_64")]
        if let Kernel::Avx2(avx2) = self.kernel {
            if width == PACKET {
                // SAFETY: an `Avx2` is made only by `Avx2::detect`, which
                // checked that the CPU has AVX2, FMA, BMI1 and POPCNT.
                return unsafe { packet_avx2::<Q, T>(avx2, self, rays, out) };
            }
            if let Some(avx512) = Avx512::detect() {
                // SAFETY: an `Avx512` is made only by `Avx512::detect`,
                // which checked AVX-512F besides AVX2, FMA, BMI1 and POPCNT.
                return unsafe { packet_avx512::<Q, T>(avx512, self, rays, out) };
            }
        }
        let per_ray = PerRay::<_, T>::new(Portable);
        if width == PACKET16 {
            self.packet_stack::<Q, Portable, T, _, PACKET16>(Portable, per_ray, rays, out)
        } else {
            self.packet_stack::<Q, Portable, T, _, PACKET>(Portable, per_ray, rays, out)
        }
    }

    /// The closest hits of a packet of up to `width` rays ([`PACKET`] or
    /// [`PACKET16`]), as [`Self::packet_query`] chooses its kernels.
    pub fn closest_packet_with<T: BlockTest>(
        &self,
        width: usize,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) {
        self.packet_query::<Closest, T>(width, rays, hits)
    }

    /// Whether each ray of a packet of up to `width` rays is occluded, as
    /// [`Self::packet_query`] chooses its kernels.
    pub fn any_packet_with<T: BlockTest>(&self, width: usize, rays: &[Ray], occluded: &mut [bool]) {
        self.packet_query::<Any, T>(width, rays, occluded)
    }

    /// Query `Q` with stacks as deep as the tree needs.
    #[inline(always)]
    fn packet_stack<
        Q: PacketQuery,
        K: NodeKernel<8>,
        T: BlockTest,
        P: PacketKernel<R>,
        const R: usize,
    >(
        &self,
        kernel: K,
        packet: P,
        rays: &[Ray],
        out: &mut Q::Out,
    ) {
        if self.stack_need <= STACK {
            Q::run::<K, T, P, R, STACK>(self, kernel, packet, rays, out)
        } else {
            Q::run::<K, T, P, R, DEEP_STACK>(self, kernel, packet, rays, out)
        }
    }

    /// Query `Q` with the rays in the lanes `lanes`: Moller-Trumbore on
    /// the lanes too, or else (the one other block test) the watertight
    /// test on the lanes, with grown boxes (`GrownPacket`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn packet_simd<Q: PacketQuery, T: BlockTest, L: Lanes<R>, const R: usize>(
        &self,
        lanes: L,
        rays: &[Ray],
        out: &mut Q::Out,
    ) {
        let single = lanes.avx2();
        if T::IS_MOLLER_TRUMBORE {
            self.packet_stack::<Q, Avx2, T, _, R>(single, SimdPacket(lanes), rays, out)
        } else {
            self.packet_stack::<Q, Avx2, T, _, R>(single, GrownPacket(lanes), rays, out)
        }
    }
}

/// What a packet walk over a top level hands its visitor: an id (an
/// instance), the rays that reached it (a bit per ray), and each ray's cut,
/// which the visitor lowers to its best hit's `t` widened by `CULL_SLACK`.
/// The visitor returns the rays that are done (occluded), which walk no
/// further.
pub(crate) type PacketVisit<'a> = dyn FnMut(u32, u32, &mut [f32]) -> u32 + 'a;

impl WideBvh<8> {
    /// [`Self::walk_ids_packet`] of up to `width` rays ([`PACKET`] or
    /// [`PACKET16`]), its node tests chosen as [`Self::packet_query`]
    /// chooses them: AVX2 lanes for 8 rays, AVX-512 lanes for 16 where the
    /// CPU has them, else each ray's portable test.
    pub(crate) fn walk_ids_packet_with(
        &self,
        width: usize,
        rays: &[Ray],
        nearest_first: bool,
        visit: &mut PacketVisit<'_>,
    ) {
        debug_assert!(width == PACKET || width == PACKET16);
        debug_assert!(rays.len() <= width);
        #[cfg(target_arch = "x86_64")]
        if let Kernel::Avx2(avx2) = self.kernel {
            if width == PACKET {
                // SAFETY: an `Avx2` is made only by `Avx2::detect`, which
                // checked that the CPU has AVX2, FMA, BMI1 and POPCNT.
                return unsafe { walk_packet_avx2(avx2, self, rays, nearest_first, visit) };
            }
            if let Some(avx512) = Avx512::detect() {
                // SAFETY: an `Avx512` is made only by `Avx512::detect`,
                // which checked AVX-512F besides AVX2, FMA, BMI1 and POPCNT.
                return unsafe { walk_packet_avx512(avx512, self, rays, nearest_first, visit) };
            }
        }
        let per_ray = PerRay::<_, crate::geometry::MollerTrumbore>::new(Portable);
        if width == PACKET16 {
            self.walk_ids_packet::<_, PACKET16>(per_ray, rays, nearest_first, visit)
        } else {
            self.walk_ids_packet::<_, PACKET>(per_ray, rays, nearest_first, visit)
        }
    }
}

/// [`WideBvh::walk_ids_packet`] of 8 rays compiled with AVX2 enabled, as
/// [`packet_avx2`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn walk_packet_avx2(
    avx2: Avx2,
    bvh: &WideBvh<8>,
    rays: &[Ray],
    nearest_first: bool,
    visit: &mut PacketVisit<'_>,
) {
    bvh.walk_ids_packet::<_, PACKET>(SimdPacket(avx2), rays, nearest_first, visit)
}

/// [`WideBvh::walk_ids_packet`] of 16 rays compiled with AVX-512F enabled.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma,bmi1,popcnt")]
fn walk_packet_avx512(
    avx512: Avx512,
    bvh: &WideBvh<8>,
    rays: &[Ray],
    nearest_first: bool,
    visit: &mut PacketVisit<'_>,
) {
    bvh.walk_ids_packet::<_, PACKET16>(SimdPacket(avx512), rays, nearest_first, visit)
}

/// [`WideBvh::packet_query`] of 8 rays compiled with AVX2 enabled: the
/// generic traversal and kernels are `#[inline(always)]`, so they are
/// compiled into this function with every intrinsic inlined.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn packet_avx2<Q: PacketQuery, T: BlockTest>(
    avx2: Avx2,
    bvh: &WideBvh<8>,
    rays: &[Ray],
    out: &mut Q::Out,
) {
    bvh.packet_simd::<Q, T, _, PACKET>(avx2, rays, out)
}

/// [`WideBvh::packet_query`] of 16 rays compiled with AVX-512F enabled, as
/// [`packet_avx2`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma,bmi1,popcnt")]
fn packet_avx512<Q: PacketQuery, T: BlockTest>(
    avx512: Avx512,
    bvh: &WideBvh<8>,
    rays: &[Ray],
    out: &mut Q::Out,
) {
    bvh.packet_simd::<Q, T, _, PACKET16>(avx512, rays, out)
}

impl WideBvh<8> {
    /// Walks the tree as a top level over other structures: visits the ids
    /// of the leaf slots (what the leaves' `ids` hold: instance indices in a
    /// TLAS) whose lanes' boxes the ray reaches within `(tmin, tmax)`,
    /// nearest node first, until `visit` returns `true`. `visit` is handed
    /// the id and the distance beyond which nothing is wanted any more (the
    /// ray's `tmax`, then whatever `visit` lowers it to: the best hit), and
    /// boxes beyond it are skipped. The node tests use AVX2 where the tree's
    /// kernel is AVX2. With `nearest_first` false the children are visited
    /// as the any-hit traversal visits them (the first hit lane, then the
    /// others as pushed), which is what an occlusion query wants.
    pub(crate) fn walk_ids<F: FnMut(u32, &mut f32) -> bool>(
        &self,
        ray: &Ray,
        nearest_first: bool,
        visit: &mut F,
    ) {
        if self.nodes.is_empty() || !ray.is_valid() {
            return;
        }
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the kernel value proves the CPU has AVX2, FMA, BMI1 and POPCNT.
            Kernel::Avx2(k) => unsafe { walk_ids_avx2(k, self, ray, nearest_first, visit) },
            _ => {
                let wray = WideRay::new(&SlabRay::new(ray));
                self.walk_ids_with(Portable, ray, &wray, nearest_first, visit)
            }
        }
    }

    #[inline(always)]
    fn walk_ids_with<K: NodeKernel<8>, F: FnMut(u32, &mut f32) -> bool>(
        &self,
        kernel: K,
        ray: &Ray,
        wray: &WideRay,
        nearest_first: bool,
        visit: &mut F,
    ) {
        let tmin = ray.tmin * (1.0 - SLAB_SLACK);
        let mut tmax = ray.tmax;
        let mut cut = tmax * (1.0 + CULL_SLACK);
        let mut stack: ArrayVec<(u32, f32), DEEP_STACK> = ArrayVec::new();
        let mut current = 0u32;
        loop {
            if current & LEAF != 0 {
                let stop = for_leaf_blocks(current, |b, lanes| {
                    let ids = &self.blocks[b].ids;
                    for lane in bits(lanes) {
                        if visit(ids[lane], &mut tmax) {
                            return true;
                        }
                    }
                    false
                });
                if stop {
                    return;
                }
                cut = tmax * (1.0 + CULL_SLACK);
            } else {
                let node = &self.nodes[current as usize];
                let (mask, near) = kernel.intersect(node, wray, tmin, cut);
                if mask != 0 {
                    let next = if nearest_first {
                        nearest_lane(mask, &near)
                    } else {
                        mask.trailing_zeros() as usize
                    };
                    let base = stack.len();
                    for lane in bits(mask & !(1 << next)) {
                        let entry = (node.child[lane], near[lane]);
                        self.prefetch_child(entry.0);
                        if nearest_first {
                            push_sorted(&mut stack, base, entry, |e| e.1);
                        } else {
                            stack.push(entry);
                        }
                    }
                    current = node.child[next];
                    continue;
                }
            }
            loop {
                let Some((child, near)) = stack.pop() else {
                    return;
                };
                if near <= cut {
                    current = child;
                    break;
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn walk_ids_avx2<F: FnMut(u32, &mut f32) -> bool>(
    kernel: Avx2,
    bvh: &WideBvh<8>,
    ray: &Ray,
    nearest_first: bool,
    visit: &mut F,
) {
    // The fused kernel where the ray allows it, as `closest_avx2` chooses.
    let slab = SlabRay::new(ray);
    match WideRay::fused(&slab, bvh.fused_origin_limit) {
        Some(wray) => bvh.walk_ids_with(Avx2Fused(kernel), ray, &wray, nearest_first, visit),
        None => bvh.walk_ids_with(kernel, ray, &WideRay::new(&slab), nearest_first, visit),
    }
}

/// The wide trees' queries compiled with AVX2 enabled: the generic traversal
/// is `#[inline(always)]`, so it is compiled into these functions and every
/// operation in it (node tests, triangle tests, bit scans) uses AVX2 and VEX
/// encoding.
impl Avx2 {
    #[inline(always)]
    pub fn closest<T: BlockTest, C: Counter, const S: usize>(
        self,
        bvh: &WideBvh<8>,
        ray: &Ray,
        counter: &mut C,
    ) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: `self` proves the CPU has AVX2, FMA, BMI1 and POPCNT.
            unsafe { closest_avx2::<T, C, S>(self, bvh, ray, counter) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        bvh.closest_with::<Portable, T, C, S>(Portable, ray, counter)
    }

    #[inline(always)]
    pub fn any<T: BlockTest, C: Counter, const S: usize>(
        self,
        bvh: &WideBvh<8>,
        ray: &Ray,
        counter: &mut C,
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: as in `closest`.
            unsafe { any_avx2::<T, C, S>(self, bvh, ray, counter) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        bvh.any_with::<Portable, T, C, S>(Portable, ray, counter)
    }
}

/// The ray for the fused kernel where the ray allows it
/// ([`WideRay::fused`]) and test `T` does not grow the boxes (the fused
/// kernel has no grown form: such tests take the unfused kernel's).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn fused_ray<T: TriangleTest>(bvh: &WideBvh<8>, slab: &SlabRay) -> Option<WideRay> {
    if T::GROWS_BOXES {
        None
    } else {
        WideRay::fused(slab, bvh.fused_origin_limit)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn closest_avx2<T: BlockTest, C: Counter, const S: usize>(
    kernel: Avx2,
    bvh: &WideBvh<8>,
    ray: &Ray,
    counter: &mut C,
) -> Option<Hit> {
    if bvh.nodes.is_empty() || !ray.is_valid() {
        return None;
    }
    // The fused kernel where the ray allows it ([`WideRay::fused`]), else
    // the unfused one: the same hits either way (the fused test keeps every
    // box the other keeps). Two loops, not a branch per node (which spilled
    // registers), and the ray made for the one chosen only (making both
    // cost short rays their gain, docs/results.md). The packets' last rays
    // keep the unfused kernel: with the fused one their packets lost 1-8%.
    let slab = SlabRay::new(ray);
    match fused_ray::<T>(bvh, &slab) {
        Some(wray) => {
            bvh.closest_walk::<_, T, C, S>(Avx2Fused(kernel), ray, &wray, 0, None, counter)
        }
        None => bvh.closest_walk::<_, T, C, S>(kernel, ray, &WideRay::new(&slab), 0, None, counter),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,popcnt")]
fn any_avx2<T: BlockTest, C: Counter, const S: usize>(
    kernel: Avx2,
    bvh: &WideBvh<8>,
    ray: &Ray,
    counter: &mut C,
) -> bool {
    if bvh.nodes.is_empty() || !ray.is_valid() {
        return false;
    }
    // As `closest_avx2` chooses.
    let slab = SlabRay::new(ray);
    match fused_ray::<T>(bvh, &slab) {
        Some(wray) => bvh.any_walk::<_, T, C, S>(Avx2Fused(kernel), ray, &wray, 0, counter),
        None => bvh.any_walk::<_, T, C, S>(kernel, ray, &WideRay::new(&slab), 0, counter),
    }
}
