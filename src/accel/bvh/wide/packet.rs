//! Packet traversal of the 8-wide tree: up to [`PACKET`] rays of a stream
//! walk the tree together with one shared stack, each entry carrying the mask
//! of rays that entered that child (Wald et al. 2001's packets over a wide
//! tree, with per-ray active masks). At a node every active ray is tested
//! against the eight child boxes with the single-ray node kernel, and the
//! children are pushed once for the packet, nearest (the least entry distance
//! of its rays) on top; at a leaf each active ray runs the single-ray block
//! test. Any-hit rays retire one by one as they find an occluder. When only
//! [`PACKET_MIN_RAYS`]` - 1` rays of an entry remain, they finish the subtree
//! with the single-ray traversal (Benthin et al. 2012's hybrid switch).
//!
//! Why the answers are the single-ray traversal's bit for bit: every
//! triangle test is the single-ray one (same function, same ray), the closest
//! hit is chosen by the same order ([`Hit::is_closer_than`]) whichever order
//! leaves are visited in, and a ray's box tests are the single-ray kernel's
//! with its own current cut, so no leaf that holds its closest hit is culled
//! (the argument of `CULL_SLACK`). Tests compare the two on random, adversarial
//! and recorded rays.

use arrayvec::ArrayVec;

use super::super::leaf::BlockTest;
use super::super::params::{CULL_SLACK, PACKET_MIN_RAYS, SLAB_SLACK};
use super::super::simd::NodeKernel;
use super::super::simd_packet::{bits, PacketKernel, PACKET};
use super::super::traverse::NoCount;
use super::node::{for_leaf_blocks, WideBvh, LEAF};
use crate::geometry::{Hit, Ray};

impl WideBvh<8> {
    /// The closest hits of up to [`PACKET`] rays into `hits` (as long), each
    /// as [`Self::closest_with`] answers it: packet tests `P`, and for the
    /// last rays of an entry the single-ray traversal with node kernel `K`
    /// and triangle test `T` (the ones `P` runs lane by lane); stacks of `S`
    /// entries (at least [`Self::stack_need`]).
    #[inline(always)]
    pub(crate) fn closest_packet<
        K: NodeKernel<8>,
        T: BlockTest,
        P: PacketKernel,
        const S: usize,
    >(
        &self,
        kernel: K,
        packet: P,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) {
        debug_assert!(rays.len() <= PACKET && hits.len() == rays.len());
        hits.fill(None);
        if self.nodes.is_empty() {
            return;
        }
        let prepared = packet.prepare(rays);
        let mut active = 0u32;
        // Per ray: triangles are tested below `tmax` (just above its best t),
        // boxes culled beyond `cut`, as in the single-ray traversal.
        let mut tmax = [0f32; PACKET];
        let mut cut = [0f32; PACKET];
        for (r, ray) in rays.iter().enumerate() {
            tmax[r] = ray.tmax;
            cut[r] = ray.tmax * (1.0 + CULL_SLACK);
            active |= (ray.is_valid() as u32) << r;
        }
        // (child, rays that entered it, their least entry distance)
        let mut stack: ArrayVec<(u32, u32, f32), S> = ArrayVec::new();
        let (mut current, mut mask) = (0u32, active);
        while mask != 0 {
            let mut changed = 0;
            if mask.count_ones() < PACKET_MIN_RAYS {
                for r in bits(mask) {
                    hits[r] = self.closest_from::<K, T, NoCount, S>(
                        kernel,
                        &rays[r],
                        current,
                        hits[r],
                        &mut NoCount,
                    );
                }
                changed = mask;
            } else if current & LEAF != 0 {
                for_leaf_blocks(current, |b, in_leaf| {
                    let found =
                        packet.leaf_closest(&self.blocks[b], in_leaf, &prepared, mask, &tmax, hits);
                    for r in bits(found) {
                        if let Some(hit) = hits[r] {
                            tmax[r] = hit.t.next_up();
                        }
                    }
                    changed |= found;
                    false
                });
            } else {
                let node = &self.nodes[current as usize];
                let found = packet.node(node, &prepared, mask, &cut);
                let any = found.lanes;
                if any != 0 {
                    if any & (any - 1) == 0 {
                        // One child: no stack, no sorting.
                        let c = any.trailing_zeros() as usize;
                        current = node.child[c];
                        mask = found.rays[c];
                        self.prefetch_child(current);
                        continue;
                    }
                    // Farthest first, so that the nearest is on top.
                    let base = stack.len();
                    for c in bits(any) {
                        let entry = (node.child[c], found.rays[c], found.near[c]);
                        self.prefetch_child(entry.0);
                        stack.push(entry);
                        let s = stack.as_mut_slice();
                        let mut j = s.len() - 1;
                        while j > base && s[j - 1].2 < entry.2 {
                            s[j] = s[j - 1];
                            j -= 1;
                        }
                        s[j] = entry;
                    }
                }
            }
            for r in bits(changed) {
                if let Some(hit) = hits[r] {
                    tmax[r] = hit.t.next_up();
                    cut[r] = hit.t * (1.0 + CULL_SLACK);
                }
            }
            // Next: the nearest pending entry some of whose rays can still
            // find a closer hit there.
            mask = 0;
            while let Some((child, entered, near)) = stack.pop() {
                mask = bits(entered)
                    .filter(|&r| near <= cut[r])
                    .fold(0, |m, r| m | 1 << r);
                if mask != 0 {
                    current = child;
                    break;
                }
            }
        }
    }

    /// Whether each of up to [`PACKET`] rays hits anything within its segment,
    /// into `occluded` (as long), as [`Self::any_with`] answers it (packet
    /// tests `P`; single-ray `K` and `T` for the last rays of an entry).
    #[inline(always)]
    pub(crate) fn any_packet<K: NodeKernel<8>, T: BlockTest, P: PacketKernel, const S: usize>(
        &self,
        kernel: K,
        packet: P,
        rays: &[Ray],
        occluded: &mut [bool],
    ) {
        debug_assert!(rays.len() <= PACKET && occluded.len() == rays.len());
        occluded.fill(false);
        if self.nodes.is_empty() {
            return;
        }
        let prepared = packet.prepare(rays);
        let mut tmax = [0f32; PACKET];
        // Rays still looking for an occluder.
        let mut alive = 0u32;
        for (r, ray) in rays.iter().enumerate() {
            tmax[r] = ray.tmax * (1.0 + SLAB_SLACK);
            alive |= (ray.is_valid() as u32) << r;
        }
        let mut stack: ArrayVec<(u32, u32), S> = ArrayVec::new();
        let (mut current, mut mask) = (0u32, alive);
        while mask != 0 {
            if mask.count_ones() < PACKET_MIN_RAYS {
                for r in bits(mask) {
                    if self.any_from::<K, T, NoCount, S>(kernel, &rays[r], current, &mut NoCount) {
                        alive &= !(1 << r);
                    }
                }
            } else if current & LEAF != 0 {
                for_leaf_blocks(current, |b, in_leaf| {
                    alive &= !packet.leaf_any(&self.blocks[b], in_leaf, &prepared, mask & alive);
                    mask & alive == 0
                });
            } else {
                let node = &self.nodes[current as usize];
                let found = packet.node(node, &prepared, mask, &tmax);
                let any = found.lanes;
                // Lane order, as the single-ray any-hit traversal: the first
                // hit child next, the others pushed.
                if any != 0 {
                    let first = any.trailing_zeros() as usize;
                    for c in bits(any & (any - 1)) {
                        self.prefetch_child(node.child[c]);
                        stack.push((node.child[c], found.rays[c]));
                    }
                    current = node.child[first];
                    mask = found.rays[first];
                    self.prefetch_child(current);
                    continue;
                }
            }
            mask = 0;
            while let Some((child, entered)) = stack.pop() {
                mask = entered & alive;
                if mask != 0 {
                    current = child;
                    break;
                }
            }
        }
        for (r, o) in occluded.iter_mut().enumerate() {
            *o = rays[r].is_valid() && alive & (1 << r) == 0;
        }
    }
}
