//! Packet traversal of the 8-wide tree: up to 8 or 16 rays of a stream
//! walk the tree together with one shared stack, each entry carrying the mask
//! of rays that entered that child (Wald et al. 2001's packets over a wide
//! tree, with per-ray active masks). At a node every active ray is tested
//! against the child boxes with the single-ray node kernel (the SIMD kernels
//! first skip the children the packet's frustum rules out), and the
//! children are pushed once for the packet, nearest (the least entry distance
//! of its rays; for a coherent packet the least its frustum allows, as
//! Embree's coherent packets order theirs) on top; at a leaf each active ray runs the single-ray block
//! test. Any-hit rays retire one by one as they find an occluder. When only
//! [`PACKET_MIN_RAYS`]` - 1` rays of an entry remain
//! ([`PACKET_MIN_RAYS_INCOHERENT`]` - 1` in packets whose rays differ in
//! sign), they finish the subtree with the single-ray traversal (Benthin et
//! al. 2012's hybrid switch).
//!
//! Why the answers are the single-ray traversal's bit for bit: every
//! triangle test is the single-ray one (same function, same ray), the closest
//! hit is chosen by the same order ([`Hit::is_closer_than`]) whichever order
//! leaves are visited in, and a ray's box tests are the single-ray kernel's
//! with its own current cut, so no leaf that holds its closest hit is culled
//! (the argument of `CULL_SLACK`; the frustum only skips children every
//! ray's own test misses). Tests compare the two on random, adversarial
//! and recorded rays.

use arrayvec::ArrayVec;

use super::super::leaf::{bits, BlockTest};
use super::super::params::{
    CULL_SLACK, DEEP_STACK, PACKET_MIN_RAYS, PACKET_MIN_RAYS_INCOHERENT, SLAB_SLACK,
};
use super::super::simd::NodeKernel;
use super::super::simd_packet::{PacketHits, PacketKernel};
use super::super::simd_stack::nearest_lane;
use super::super::traverse::NoCount;
use super::node::{for_leaf_blocks, WideBvh, LEAF};
use super::traverse::{push_sorted, PacketVisit};
use crate::geometry::{Hit, Ray};

/// Below how many rays an entry of the packet `prepared` finishes ray by
/// ray: [`PACKET_MIN_RAYS`], or [`PACKET_MIN_RAYS_INCOHERENT`] when its rays
/// differ in sign.
#[inline(always)]
fn min_rays<P: PacketKernel<R>, const R: usize>(prepared: &P::Rays) -> u32 {
    if P::coherent(prepared) {
        PACKET_MIN_RAYS
    } else {
        PACKET_MIN_RAYS_INCOHERENT
    }
}

impl WideBvh<8> {
    /// The closest hits of up to `R` rays (8 or 16) into
    /// `hits` (as long), each as [`Self::closest_with`] answers it: packet
    /// tests `P`, and for the last rays of an entry the single-ray traversal
    /// with node kernel `K` and triangle test `T` (the ones `P` runs lane by
    /// lane); stacks of `S` entries (at least [`Self::stack_need`]).
    #[inline(always)]
    pub(crate) fn closest_packet<
        K: NodeKernel<8>,
        T: BlockTest,
        P: PacketKernel<R>,
        const R: usize,
        const S: usize,
    >(
        &self,
        kernel: K,
        packet: P,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) {
        debug_assert!(rays.len() <= R && R <= 32 && hits.len() == rays.len());
        hits.fill(None);
        if self.nodes.is_empty() {
            return;
        }
        let mut best = PacketHits::<R>::none();
        let (prepared, active) = packet.prepare(rays);
        let min_rays = min_rays::<P, R>(&prepared);
        // Per ray: triangles are tested below `tmax` (just above its best t),
        // boxes culled beyond `cut`, as in the single-ray traversal.
        let mut tmax = [0f32; R];
        let mut cut = [0f32; R];
        for (r, ray) in rays.iter().enumerate() {
            tmax[r] = ray.tmax;
            cut[r] = ray.tmax * (1.0 + CULL_SLACK);
        }
        // (child, rays that entered it, a lower bound on their entry distances)
        let mut stack: ArrayVec<(u32, u32, f32), S> = ArrayVec::new();
        let (mut current, mut mask) = (0u32, active);
        while mask != 0 {
            if mask.count_ones() < min_rays {
                for r in bits(mask) {
                    let hit = self.closest_from::<K, T, NoCount, S>(
                        kernel,
                        &rays[r],
                        current,
                        best.get(r),
                        &mut NoCount,
                    );
                    best.set(r, hit);
                }
                packet.tighten(&best, mask, &mut tmax, &mut cut);
            } else if current & LEAF != 0 {
                for_leaf_blocks(current, |b, in_leaf| {
                    let found = packet.leaf_closest(
                        &self.blocks[b],
                        in_leaf,
                        &prepared,
                        mask,
                        &tmax,
                        &mut best,
                    );
                    packet.tighten(&best, found, &mut tmax, &mut cut);
                    false
                });
            } else {
                let node = &self.nodes[current as usize];
                let found = packet.node::<true>(node, &prepared, mask, &cut);
                let any = found.lanes;
                if any != 0 {
                    // The nearest child is visited next (its rays entered
                    // it: no cull to check; no prefetch, it is loaded next),
                    // the others pushed farthest first, so that the nearest
                    // of them is on top.
                    let next = nearest_lane(any, &found.near);
                    let base = stack.len();
                    for c in bits(any & !(1 << next)) {
                        let entry = (node.child[c], found.rays[c], found.near[c]);
                        self.prefetch_child(entry.0);
                        push_sorted(&mut stack, base, entry, |e| e.2);
                    }
                    current = node.child[next];
                    mask = found.rays[next];
                    continue;
                }
            }
            // Next: the nearest pending entry some of whose rays can still
            // find a closer hit there.
            mask = 0;
            while let Some((child, entered, near)) = stack.pop() {
                mask = entered & packet.reach(near, &cut);
                if mask != 0 {
                    current = child;
                    break;
                }
            }
        }
        for (r, hit) in hits.iter_mut().enumerate() {
            *hit = best.get(r);
        }
    }

    /// Whether each of up to `R` rays hits anything within its segment,
    /// into `occluded` (as long), as [`Self::any_with`] answers it (packet
    /// tests `P`; single-ray `K` and `T` for the last rays of an entry).
    #[inline(always)]
    pub(crate) fn any_packet<
        K: NodeKernel<8>,
        T: BlockTest,
        P: PacketKernel<R>,
        const R: usize,
        const S: usize,
    >(
        &self,
        kernel: K,
        packet: P,
        rays: &[Ray],
        occluded: &mut [bool],
    ) {
        debug_assert!(rays.len() <= R && R <= 32 && occluded.len() == rays.len());
        occluded.fill(false);
        if self.nodes.is_empty() {
            return;
        }
        // `alive`: the rays still looking for an occluder.
        let (prepared, valid) = packet.prepare(rays);
        let min_rays = min_rays::<P, R>(&prepared);
        let mut alive = valid;
        let mut tmax = [0f32; R];
        for (r, ray) in rays.iter().enumerate() {
            tmax[r] = ray.tmax * (1.0 + SLAB_SLACK);
        }
        let mut stack: ArrayVec<(u32, u32), S> = ArrayVec::new();
        let (mut current, mut mask) = (0u32, alive);
        while mask != 0 {
            if mask.count_ones() < min_rays {
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
                let found = packet.node::<false>(node, &prepared, mask, &tmax);
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
            *o = (valid & !alive) >> r & 1 == 1;
        }
    }
}

impl WideBvh<8> {
    /// The packet form of [`Self::walk_ids`]: up to `R` rays walk the tree
    /// together (node tests `P`, one shared stack whose entries carry the
    /// rays that entered them, as [`Self::closest_packet`]), and `visit` is
    /// handed each leaf slot's id with the rays that reached its leaf. With
    /// `nearest_first` the nearest child goes first and an entry is skipped
    /// for the rays whose cut it starts beyond; else the any-hit order.
    /// Every ray's box tests are its single-ray tests with its own cut, so
    /// each ray reaches every id its single walk would reach before its
    /// answer (the order differs).
    #[inline(always)]
    pub(crate) fn walk_ids_packet<P: PacketKernel<R>, const R: usize>(
        &self,
        packet: P,
        rays: &[Ray],
        nearest_first: bool,
        visit: &mut PacketVisit<'_>,
    ) {
        debug_assert!(rays.len() <= R && R <= 32);
        if self.nodes.is_empty() {
            return;
        }
        let (prepared, valid) = packet.prepare(rays);
        let mut alive = valid;
        let mut cut = [0f32; R];
        for (r, ray) in rays.iter().enumerate() {
            cut[r] = ray.tmax * (1.0 + CULL_SLACK);
        }
        let mut stack: ArrayVec<(u32, u32, f32), DEEP_STACK> = ArrayVec::new();
        let (mut current, mut mask) = (0u32, alive);
        while mask != 0 {
            if current & LEAF != 0 {
                for_leaf_blocks(current, |b, in_leaf| {
                    let ids = &self.blocks[b].ids;
                    for lane in bits(in_leaf) {
                        alive &= !visit(ids[lane], mask & alive, &mut cut);
                        if mask & alive == 0 {
                            return true;
                        }
                    }
                    false
                });
            } else {
                let node = &self.nodes[current as usize];
                let found = if nearest_first {
                    packet.node::<true>(node, &prepared, mask, &cut)
                } else {
                    packet.node::<false>(node, &prepared, mask, &cut)
                };
                let any = found.lanes;
                if any != 0 {
                    let next = if nearest_first {
                        nearest_lane(any, &found.near)
                    } else {
                        any.trailing_zeros() as usize
                    };
                    let base = stack.len();
                    for c in bits(any & !(1 << next)) {
                        let entry = (node.child[c], found.rays[c], found.near[c]);
                        self.prefetch_child(entry.0);
                        if nearest_first {
                            push_sorted(&mut stack, base, entry, |e| e.2);
                        } else {
                            stack.push(entry);
                        }
                    }
                    current = node.child[next];
                    mask = found.rays[next] & alive;
                    continue;
                }
            }
            mask = 0;
            while let Some((child, entered, near)) = stack.pop() {
                mask = entered & alive;
                if nearest_first {
                    mask &= packet.reach(near, &cut);
                }
                if mask != 0 {
                    current = child;
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::super::Bvh8;
    use crate::accel::bvh::leaf::BlockTest;
    use crate::accel::bvh::params::BuildParams;
    use crate::accel::bvh::simd::{Avx512, Kernel};
    use crate::accel::bvh::simd_packet::{PACKET, PACKET16};
    use crate::accel::bvh::test_fixtures::{binary, random_tris};
    use crate::accel::bvh::traverse::{NoCount, Traversal};
    use crate::geometry::{Hit, MollerTrumbore, Ray, Watertight};
    use crate::rng::Rng;

    /// Packets as a stream brings them: coherent groups of eight (nearby
    /// origins, nearly parallel directions, as a pixel block), groups aimed
    /// at one vertex or edge from spread origins, incoherent rays, rays with
    /// zero and negative-zero direction components, mixed signs, short and
    /// long segments, and invalid rays among valid ones.
    fn stream(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
        let mut rng = Rng::for_pixel(seed, 5, 77);
        let v =
            |rng: &mut Rng, s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        let mut rays = Vec::with_capacity(n);
        while rays.len() < n {
            let group = rays.len() / PACKET;
            let base_o = v(&mut rng, 16.0) - Vec3::splat(3.0);
            let target = tris[(rng.next_f32() * tris.len() as f32) as usize % tris.len()];
            let base_d = (v(&mut rng, 10.0) - base_o).normalize_or(Vec3::X);
            for lane in 0..PACKET {
                let mut ray = match group % 5 {
                    // A pixel block: nearby origins, nearly parallel.
                    0 => Ray::new(
                        base_o + v(&mut rng, 0.05),
                        (base_d + (v(&mut rng, 0.02) - Vec3::splat(0.01))).normalize(),
                    ),
                    // Aimed exactly at a vertex or an edge's midpoint.
                    1 => {
                        let aim = match lane % 3 {
                            0 => target[0],
                            1 => (target[0] + target[1]) * 0.5,
                            _ => target[2],
                        };
                        let o = base_o + v(&mut rng, 2.0);
                        Ray::new(o, (aim - o).normalize_or(Vec3::Y))
                    }
                    // Incoherent: signs differ within the packet.
                    2 => Ray::new(
                        v(&mut rng, 16.0) - Vec3::splat(3.0),
                        (v(&mut rng, 2.0) - Vec3::ONE).normalize_or(Vec3::Z),
                    ),
                    // Axis-parallel, with zero and negative-zero components.
                    3 => {
                        let axes = [Vec3::X, -Vec3::Y, Vec3::new(0.0, -0.0, 1.0), -Vec3::X];
                        Ray::new(base_o + v(&mut rng, 0.5), axes[lane % 4])
                    }
                    // Short segments from near surfaces (as AO and shadow rays).
                    _ => {
                        let p = target[0] * 0.3 + target[1] * 0.3 + target[2] * 0.4;
                        Ray::segment(
                            p,
                            (v(&mut rng, 2.0) - Vec3::ONE).normalize_or(Vec3::X),
                            0.0,
                            0.3,
                        )
                    }
                };
                if rng.next_f32() < 0.3 {
                    ray.tmax = rng.next_f32() * 6.0;
                }
                if rng.next_f32() < 0.02 {
                    ray.dir = [Vec3::ZERO, Vec3::splat(f32::NAN)][lane % 2];
                }
                rays.push(ray);
            }
        }
        rays.truncate(n);
        rays
    }

    fn bits(h: Option<Hit>) -> Option<[u32; 4]> {
        h.map(|h| [h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.tri])
    }

    /// Packets of every size from 1 to 8 (`--query packet8`) and from 1 to
    /// 16 (`packet16`) against the single-ray traversal.
    fn check<T: BlockTest>(tree: &Bvh8, rays: &[Ray], label: &str) {
        let sizes = (1..=PACKET).map(|s| (s, false));
        for (size, sixteen) in sizes.chain((1..=PACKET16).map(|s| (s, true))) {
            let label = format!("{label} packet{}", if sixteen { 16 } else { 8 });
            for (k, chunk) in rays.chunks(size).enumerate() {
                let mut hits = vec![None; chunk.len()];
                let mut occluded = vec![true; chunk.len()];
                let width = if sixteen { PACKET16 } else { PACKET };
                tree.closest_packet_with::<T>(width, chunk, &mut hits);
                tree.any_packet_with::<T>(width, chunk, &mut occluded);
                for (r, ray) in chunk.iter().enumerate() {
                    let want = tree.closest::<T, _>(ray, &mut NoCount);
                    assert_eq!(
                        bits(hits[r]),
                        bits(want),
                        "{label}: packet of {size}, #{k} lane {r}: {ray:?}"
                    );
                    assert_eq!(
                        occluded[r],
                        tree.any::<T, _>(ray, &mut NoCount),
                        "{label}: any-hit packet of {size}, #{k} lane {r}: {ray:?}"
                    );
                }
            }
        }
    }

    /// The AVX-512 traversal (`--query packet16`) answers every ray as the
    /// AVX2 one (`packet8`, the same rays as two packets) bit for bit, on
    /// the test stream (coherent, vertex-aimed, incoherent, axis-parallel,
    /// short and invalid rays), closest hit and any hit, both triangle
    /// tests, packets of every size.
    #[test]
    fn avx2_and_avx512_packets_agree_bit_for_bit() {
        let (Kernel::Avx2(k), Some(_)) = (Kernel::detect(), Avx512::detect()) else {
            eprintln!("no AVX-512 on this CPU: packet16 and packet8 are not compared");
            return;
        };
        let tris = random_tris(2000, 8);
        let rays = stream(&tris, 4000, 11);
        let tree =
            Bvh8::collapse_with(&binary(&tris, &BuildParams::sah()), Kernel::Avx2(k)).unwrap();
        fn both<T: BlockTest>(tree: &Bvh8, rays: &[Ray], size: usize) {
            for (n, chunk) in rays.chunks(size).enumerate() {
                let mut hits16 = vec![None; chunk.len()];
                let mut occluded16 = vec![false; chunk.len()];
                tree.closest_packet_with::<T>(PACKET16, chunk, &mut hits16);
                tree.any_packet_with::<T>(PACKET16, chunk, &mut occluded16);
                let (mut hits8, mut occluded8) = (vec![], vec![]);
                for half in chunk.chunks(PACKET) {
                    let mut h = vec![None; half.len()];
                    let mut o = vec![false; half.len()];
                    tree.closest_packet_with::<T>(PACKET, half, &mut h);
                    tree.any_packet_with::<T>(PACKET, half, &mut o);
                    hits8.extend(h);
                    occluded8.extend(o);
                }
                for r in 0..chunk.len() {
                    let label = format!("packet of {size}, #{n} ray {r}: {:?}", chunk[r]);
                    assert_eq!(bits(hits16[r]), bits(hits8[r]), "{label}");
                    assert_eq!(occluded16[r], occluded8[r], "{label}");
                }
            }
        }
        for size in [1, 5, 9, 16] {
            both::<MollerTrumbore>(&tree, &rays, size);
            both::<Watertight>(&tree, &rays, size);
        }
    }

    #[test]
    fn packets_answer_as_single_rays_bit_for_bit() {
        let tris = random_tris(3000, 21);
        let rays = stream(&tris, 6000, 3);
        for params in [
            BuildParams::sah(),
            BuildParams::median().with_max_leaf_size(3),
        ] {
            let bvh = binary(&tris, &params);
            let mut kernels = vec![Kernel::Portable];
            if let Kernel::Avx2(k) = Kernel::detect() {
                kernels.push(Kernel::Avx2(k));
            } else {
                eprintln!("no AVX2 on this CPU: the AVX2 packet kernel is not tested");
            }
            if crate::accel::bvh::simd::Avx512::detect().is_none() {
                eprintln!("no AVX-512 on this CPU: the AVX-512 packet kernel is not tested");
            }
            for kernel in kernels {
                let tree = Bvh8::collapse_with(&bvh, kernel).unwrap();
                let label = format!("{params:?} {}", kernel.name());
                check::<MollerTrumbore>(&tree, &rays, &format!("{label} mt"));
                check::<Watertight>(&tree, &rays, &format!("{label} watertight"));
            }
        }
    }

    #[test]
    fn an_empty_tree_and_invalid_rays_answer_misses() {
        let tree = Bvh8::collapse(&binary(&Vec::<[Vec3; 3]>::new(), &BuildParams::sah()));
        if let Ok(tree) = tree {
            let rays = [Ray::new(Vec3::ZERO, Vec3::X); 3];
            let mut hits = [Some(Hit {
                t: 1.0,
                u: 0.0,
                v: 0.0,
                tri: 0,
                inst: 0,
            }); 3];
            let mut occluded = [true; 3];
            tree.closest_packet_with::<MollerTrumbore>(PACKET, &rays, &mut hits);
            tree.any_packet_with::<MollerTrumbore>(PACKET, &rays, &mut occluded);
            assert_eq!(hits, [None; 3]);
            assert_eq!(occluded, [false; 3]);
        }
        let tris = random_tris(50, 2);
        let tree = Bvh8::collapse(&binary(&tris, &BuildParams::sah())).unwrap();
        let bad = [
            Ray::new(Vec3::ZERO, Vec3::ZERO),
            Ray::new(Vec3::splat(f32::NAN), Vec3::X),
            Ray::new(Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0)),
        ];
        let mut hits = [None; 3];
        let mut occluded = [true; 3];
        tree.closest_packet_with::<MollerTrumbore>(PACKET, &bad, &mut hits);
        tree.any_packet_with::<MollerTrumbore>(PACKET, &bad, &mut occluded);
        assert_eq!(hits, [None; 3]);
        assert_eq!(occluded, [false; 3]);
    }
}
