//! A 4-wide BVH collapsed from the binary tree, with the four children's boxes
//! in structure-of-arrays form so that one SIMD operation tests all four.
//!
//! Collapse: every 4-wide node takes a binary interior node and repeatedly opens
//! the interior child of largest surface area until it has four children or
//! only leaves (the usual collapse, as in Embree's BVH4 and Wald et al. 2008).
//! The boxes are the binary tree's, and leaves keep their triangle ranges in the
//! leaf-ordered arrays, so a wide tree finds exactly the binary tree's hits.
//!
//! SIMD: the lanes are `glam::Vec4`, which is one SSE register on x86_64 (and
//! NEON on aarch64, scalar elsewhere); [`slab_test_scalar`] is the per-lane
//! reference the kernel is tested against.

use glam::{Vec3, Vec4};

use super::traverse::{closest_in_leaf, Counter, Traversal};
use super::Bvh;
use crate::geometry::{safe_reciprocal, Aabb, Hit, Ray, TriangleTest, GAMMA3};

/// Children per node.
pub const WIDTH: usize = 4;

use super::traverse::{CULL_SLACK, SLAB_SLACK};

/// Nodes of the deepest path are at most the binary depth bound; each pops up to 3 siblings.
const STACK_SIZE: usize = 64 * 3 + 4;

/// Four children: their boxes by axis and bound, and what each lane holds.
/// 128 bytes, aligned to a cache line, so a node is exactly two lines.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct Node4 {
    pub min_x: Vec4,
    pub min_y: Vec4,
    pub min_z: Vec4,
    pub max_x: Vec4,
    pub max_y: Vec4,
    pub max_z: Vec4,
    /// Interior lane: index of the child node. Leaf lane: first triangle slot.
    pub child: [u32; WIDTH],
    /// Leaf lane: triangle count (leaves hold at most 255); interior lane: 0.
    pub count: [u16; WIDTH],
    /// Bit i set when lane i holds a child.
    pub lanes: u32,
}

impl Node4 {
    fn empty() -> Self {
        Node4 {
            min_x: Vec4::ZERO,
            min_y: Vec4::ZERO,
            min_z: Vec4::ZERO,
            max_x: Vec4::ZERO,
            max_y: Vec4::ZERO,
            max_z: Vec4::ZERO,
            child: [0; WIDTH],
            count: [0; WIDTH],
            lanes: 0,
        }
    }

    /// The box of lane `i`.
    pub fn lane_bounds(&self, i: usize) -> Aabb {
        Aabb {
            min: Vec3::new(self.min_x[i], self.min_y[i], self.min_z[i]),
            max: Vec3::new(self.max_x[i], self.max_y[i], self.max_z[i]),
        }
    }
}

/// A ray prepared for the 4-wide slab test: origin and reciprocal direction
/// broadcast to all lanes.
#[derive(Clone, Copy, Debug)]
pub struct Ray4 {
    pub origin: [Vec4; 3],
    pub inv_dir: [Vec4; 3],
}

impl Ray4 {
    pub fn new(origin: Vec3, inv_dir: Vec3) -> Self {
        Ray4 {
            origin: [
                Vec4::splat(origin.x),
                Vec4::splat(origin.y),
                Vec4::splat(origin.z),
            ],
            inv_dir: [
                Vec4::splat(inv_dir.x),
                Vec4::splat(inv_dir.y),
                Vec4::splat(inv_dir.z),
            ],
        }
    }
}

/// The slab test of all four lanes at once: the mask of lanes whose box overlaps
/// `(tmin, tmax)` and the entry distances. Lane for lane the same operations, in
/// the same order, as [`Aabb::intersect`], so the results are identical.
#[inline(always)]
pub fn slab_test(node: &Node4, ray: &Ray4, tmin: f32, tmax: f32) -> (u32, Vec4) {
    const GROW: f32 = 1.0 + 2.0 * GAMMA3;
    let [ox, oy, oz] = ray.origin;
    let [ix, iy, iz] = ray.inv_dir;
    let t0x = (node.min_x - ox) * ix;
    let t1x = (node.max_x - ox) * ix;
    let t0y = (node.min_y - oy) * iy;
    let t1y = (node.max_y - oy) * iy;
    let t0z = (node.min_z - oz) * iz;
    let t1z = (node.max_z - oz) * iz;
    let near = t0x
        .min(t1x)
        .max(t0y.min(t1y))
        .max(t0z.min(t1z))
        .max(Vec4::splat(tmin));
    let far = (t0x.max(t1x).min(t0y.max(t1y)).min(t0z.max(t1z)) * GROW).min(Vec4::splat(tmax));
    (near.cmple(far).bitmask() & node.lanes, near)
}

/// The reference for [`slab_test`]: [`Aabb::intersect`] lane by lane.
pub fn slab_test_scalar(
    node: &Node4,
    origin: Vec3,
    inv_dir: Vec3,
    tmin: f32,
    tmax: f32,
) -> (u32, [f32; 4]) {
    let mut mask = 0;
    let mut near = [0.0; 4];
    for (i, slot) in near.iter_mut().enumerate() {
        if node.lanes & (1 << i) == 0 {
            continue;
        }
        if let Some(t) = node.lane_bounds(i).intersect(origin, inv_dir, tmin, tmax) {
            mask |= 1 << i;
            *slot = t;
        }
    }
    (mask, near)
}

/// A 4-wide BVH over the same leaf-ordered triangles as the binary tree it came from.
#[derive(Clone, Debug, Default)]
pub struct Bvh4 {
    /// `nodes[0]` is the root; empty for an empty tree.
    pub nodes: Vec<Node4>,
    pub tri_ids: Vec<u32>,
    pub tris: Vec<[Vec3; 3]>,
}

fn area(b: &Aabb) -> f32 {
    let e = b.max - b.min;
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl Bvh4 {
    /// Collapses `bvh` (kept intact; its leaf arrays are copied).
    pub fn collapse(bvh: &Bvh) -> Bvh4 {
        let mut out = Bvh4 {
            nodes: Vec::with_capacity(bvh.nodes.len() / 2 + 1),
            tri_ids: bvh.tri_ids.clone(),
            tris: bvh.tris.clone(),
        };
        if !bvh.nodes.is_empty() {
            out.collapse_node(bvh, 0);
        }
        out
    }

    /// Makes the 4-wide node for binary node `b` (a root leaf becomes a node with
    /// one leaf lane) and returns its index.
    fn collapse_node(&mut self, bvh: &Bvh, b: u32) -> u32 {
        let node = &bvh.nodes[b as usize];
        let mut children: Vec<u32> = if node.is_leaf() {
            vec![b]
        } else {
            vec![b + 1, node.offset]
        };
        while children.len() < WIDTH {
            // Open the interior child with the largest surface area.
            let best = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| !bvh.nodes[c as usize].is_leaf())
                .max_by(|(_, &a), (_, &c)| {
                    area(&bvh.nodes[a as usize].bounds())
                        .total_cmp(&area(&bvh.nodes[c as usize].bounds()))
                })
                .map(|(i, _)| i);
            let Some(i) = best else { break };
            let c = children[i];
            let n = &bvh.nodes[c as usize];
            children.splice(i..=i, [c + 1, n.offset]);
        }
        let index = self.nodes.len() as u32;
        self.nodes.push(Node4::empty());
        let mut wide = Node4::empty();
        for (lane, &c) in children.iter().enumerate() {
            let n = bvh.nodes[c as usize];
            wide.min_x[lane] = n.min.x;
            wide.min_y[lane] = n.min.y;
            wide.min_z[lane] = n.min.z;
            wide.max_x[lane] = n.max.x;
            wide.max_y[lane] = n.max.y;
            wide.max_z[lane] = n.max.z;
            wide.lanes |= 1 << lane;
            if n.is_leaf() {
                wide.child[lane] = n.offset;
                // Leaves hold at most `max_leaf_size` <= 255 triangles.
                wide.count[lane] = u16::try_from(n.count).expect("leaf of at most 65535 triangles");
            } else {
                wide.child[lane] = self.collapse_node(bvh, c);
            }
        }
        self.nodes[index as usize] = wide;
        index
    }

    /// Bytes of nodes, index map and gathered triangles.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node4>()
            + self.tri_ids.len() * std::mem::size_of::<u32>()
            + self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
    }
}

impl Traversal for Bvh4 {
    fn closest<T: TriangleTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        if self.nodes.is_empty() || !ray.is_valid() {
            return None;
        }
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray.origin, safe_reciprocal(ray.dir));
        let tmin = ray.tmin * (1.0 - SLAB_SLACK);
        let mut best: Option<Hit> = None;
        let mut test_ray = *ray;
        // Entries: (child, leaf count or 0 for a node, entry distance).
        let mut stack = [(0u32, 0u32, 0f32); STACK_SIZE];
        let mut sp = 1usize;
        stack[0] = (0, 0, ray.tmin);
        while sp > 0 {
            sp -= 1;
            let (child, count, near) = stack[sp];
            let best_t = best.map_or(ray.tmax, |h| h.t);
            if near > best_t * (1.0 + CULL_SLACK) {
                continue;
            }
            if count > 0 {
                let leaf = child as usize..(child + count) as usize;
                closest_in_leaf::<T, C>(
                    &self.tris,
                    &self.tri_ids,
                    leaf,
                    &prepared,
                    &mut test_ray,
                    &mut best,
                    counter,
                );
                continue;
            }
            counter.node();
            let node = &self.nodes[child as usize];
            let (mut mask, nears) = slab_test(node, &ray4, tmin, best_t * (1.0 + CULL_SLACK));
            // Push the hit lanes farthest first, so the nearest is popped next.
            let base = sp;
            while mask != 0 {
                let lane = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let entry = (node.child[lane], node.count[lane] as u32, nears[lane]);
                let mut j = sp;
                while j > base && stack[j - 1].2 < entry.2 {
                    stack[j] = stack[j - 1];
                    j -= 1;
                }
                stack[j] = entry;
                sp += 1;
            }
            debug_assert!(sp <= STACK_SIZE);
        }
        best
    }

    fn any<T: TriangleTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        if self.nodes.is_empty() || !ray.is_valid() {
            return false;
        }
        let prepared = T::prepare(ray);
        let ray4 = Ray4::new(ray.origin, safe_reciprocal(ray.dir));
        let (tmin, tmax) = (ray.tmin * (1.0 - SLAB_SLACK), ray.tmax * (1.0 + SLAB_SLACK));
        let mut stack = [(0u32, 0u32); STACK_SIZE];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (child, count) = stack[sp];
            if count > 0 {
                let first = child as usize;
                for slot in first..first + count as usize {
                    counter.triangle();
                    if T::test(&prepared, ray, &self.tris[slot]).is_some() {
                        return true;
                    }
                }
                continue;
            }
            counter.node();
            let node = &self.nodes[child as usize];
            let (mut mask, _) = slab_test(node, &ray4, tmin, tmax);
            while mask != 0 {
                let lane = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                stack[sp] = (node.child[lane], node.count[lane] as u32);
                sp += 1;
            }
            debug_assert!(sp <= STACK_SIZE);
        }
        false
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
    fn simd_slab_test_equals_the_scalar_one_lane_by_lane() {
        let tris = random_tris(500, 3);
        let bvh = Bvh::build(&tris, &BuildParams::sah()).unwrap();
        let wide = Bvh4::collapse(&bvh);
        let mut rng = Rng::for_pixel(1, 5, 7);
        for k in 0..20_000 {
            let node = &wide.nodes[k % wide.nodes.len()];
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 14.0 - 2.0;
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            // Axis-parallel directions too (zero components, huge reciprocals).
            if k % 7 == 0 {
                d.y = 0.0;
            }
            let inv = safe_reciprocal(d);
            let tmax = if k % 3 == 0 {
                f32::INFINITY
            } else {
                rng.next_f32() * 20.0
            };
            let (mask, near) = slab_test(node, &Ray4::new(o, inv), 0.0, tmax);
            let (smask, snear) = slab_test_scalar(node, o, inv, 0.0, tmax);
            assert_eq!(mask, smask, "ray {k}");
            for lane in 0..4 {
                if mask & (1 << lane) != 0 {
                    assert_eq!(
                        near[lane].to_bits(),
                        snear[lane].to_bits(),
                        "ray {k} lane {lane}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_node_is_two_cache_lines() {
        assert_eq!(std::mem::size_of::<Node4>(), 128);
        assert_eq!(std::mem::align_of::<Node4>(), 64);
    }

    #[test]
    fn collapse_keeps_every_leaf_and_fills_nodes() {
        for n in [1, 2, 3, 5, 64, 1000] {
            let tris = random_tris(n, n as u64);
            let bvh = Bvh::build(&tris, &BuildParams::median()).unwrap();
            let wide = Bvh4::collapse(&bvh);
            let leaves_binary = bvh.nodes.iter().filter(|n| n.is_leaf()).count();
            let leaf_lanes: usize = wide
                .nodes
                .iter()
                .map(|n| n.count.iter().filter(|&&c| c > 0).count())
                .sum();
            assert_eq!(leaf_lanes, leaves_binary, "n = {n}");
            let covered: u32 = wide.nodes.iter().flat_map(|n| n.count).map(u32::from).sum();
            assert_eq!(covered as usize, bvh.tris.len());
            // Fewer, fuller nodes: all but nodes near leaves have four children.
            if n >= 64 {
                assert!(wide.nodes.len() * 2 < bvh.nodes.len());
            }
        }
        assert!(Bvh4::collapse(&Bvh::default()).nodes.is_empty());
    }

    #[test]
    fn wide_hits_equal_binary_hits() {
        let tris = random_tris(2000, 11);
        for params in [BuildParams::median(), BuildParams::sah()] {
            let bvh = Bvh::build(&tris, &params).unwrap();
            let wide = Bvh4::collapse(&bvh);
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
}
