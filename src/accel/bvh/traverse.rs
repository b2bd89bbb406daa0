//! Iterative BVH traversal with a small fixed stack: closest hit (ordered: the
//! nearer child first, nodes beyond the current closest hit skipped) and any hit
//! (stops at the first hit within the segment).
//!
//! Both are generic over a [`Counter`]; the fast path uses [`NoCount`], whose
//! empty methods compile away, and `raylab stats` uses [`Counts`].

use super::leaf::BlockTest;
use super::node::Bvh;
use super::params::{CULL_SLACK, SLAB_SLACK, STACK};
use crate::geometry::{Hit, Intersector, MollerTrumbore, Ray, SlabRay, TriangleTest, Watertight};

/// Receives traversal events.
pub trait Counter {
    fn node(&mut self);
    fn triangle(&mut self);
    /// `n` triangles tested at once (a block of the wide trees).
    #[inline(always)]
    fn triangles(&mut self, n: usize) {
        for _ in 0..n {
            self.triangle();
        }
    }
}

/// Counts nothing, at no cost.
pub struct NoCount;

impl Counter for NoCount {
    #[inline(always)]
    fn node(&mut self) {}
    #[inline(always)]
    fn triangle(&mut self) {}
}

/// Nodes visited and triangles tested.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub nodes: u64,
    pub triangles: u64,
}

impl Counter for Counts {
    #[inline]
    fn node(&mut self) {
        self.nodes += 1;
    }
    #[inline]
    fn triangle(&mut self) {
        self.triangles += 1;
    }
    #[inline]
    fn triangles(&mut self, n: usize) {
        self.triangles += n as u64;
    }
}

/// Tests the leaf slots `slots` for a hit closer than `best`; on one, updates
/// `best` and shortens `test_ray` to just past it (so that a hit at the same t
/// with a lower triangle index is still found; `is_closer_than` decides).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn closest_in_leaf<T: TriangleTest, C: Counter>(
    tris: &[[glam::Vec3; 3]],
    tri_ids: &[u32],
    slots: std::ops::Range<usize>,
    prepared: &T::Prepared,
    test_ray: &mut Ray,
    best: &mut Option<Hit>,
    counter: &mut C,
) {
    for slot in slots {
        counter.triangle();
        if let Some((t, u, v)) = T::test(prepared, test_ray, &tris[slot]) {
            let hit = Hit {
                t,
                u,
                v,
                tri: tri_ids[slot],
                inst: 0,
            };
            if best.is_none_or(|b| hit.is_closer_than(&b)) {
                *best = Some(hit);
                test_ray.tmax = t.next_up();
            }
        }
    }
}

/// The two queries of a hierarchy, generic over the triangle test and a work
/// counter; the binary tree and the 4-wide tree implement `closest` and `any`,
/// and share the dispatch below.
pub trait Traversal {
    /// Closest hit (ties: lowest triangle index) with triangle test `T`.
    fn closest<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit>;

    /// Any hit within the segment with triangle test `T`.
    fn any<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool;

    /// Closest hit with the chosen ray/triangle test.
    #[inline]
    fn intersect_using(&self, ray: &Ray, intersector: Intersector) -> Option<Hit> {
        match intersector {
            Intersector::Mt => self.closest::<MollerTrumbore, _>(ray, &mut NoCount),
            Intersector::Watertight => self.closest::<Watertight, _>(ray, &mut NoCount),
        }
    }

    /// Any hit with the chosen ray/triangle test.
    #[inline]
    fn occluded_using(&self, ray: &Ray, intersector: Intersector) -> bool {
        match intersector {
            Intersector::Mt => self.any::<MollerTrumbore, _>(ray, &mut NoCount),
            Intersector::Watertight => self.any::<Watertight, _>(ray, &mut NoCount),
        }
    }

    /// Closest hit with Moller-Trumbore, counting work.
    fn intersect_counted<C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        self.closest::<MollerTrumbore, C>(ray, counter)
    }

    /// Any hit with Moller-Trumbore, counting work.
    fn occluded_counted<C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        self.any::<MollerTrumbore, C>(ray, counter)
    }
}

impl Bvh {
    /// Closest hit (ties: lowest triangle index), as [`crate::accel::Backend::intersect`],
    /// with Moller-Trumbore.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.intersect_counted(ray, &mut NoCount)
    }

    /// Any hit within the segment, as [`crate::accel::Backend::occluded`],
    /// with Moller-Trumbore.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.occluded_counted(ray, &mut NoCount)
    }

    /// The entry distance of node `i` if its box overlaps `(tmin, tmax)`,
    /// the box grown where triangle test `T` needs it.
    #[inline(always)]
    fn enter<T: TriangleTest>(&self, i: u32, ray: &Ray, slab: &SlabRay, tmax: f32) -> Option<f32> {
        let b = self.nodes[i as usize].bounds();
        let (tmin, tmax) = (ray.tmin * (1.0 - SLAB_SLACK), tmax * (1.0 + SLAB_SLACK));
        if T::GROWS_BOXES {
            b.intersect_grown(slab, tmin, tmax)
        } else {
            b.intersect(slab, tmin, tmax)
        }
    }
}

impl Traversal for Bvh {
    fn closest<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        if self.nodes.is_empty() || !ray.is_valid() {
            return None;
        }
        let prepared = T::prepare(ray);
        let slab = SlabRay::new(ray);
        let mut best: Option<Hit> = None;
        // Triangle tests use `tmax` just above the best t so that a hit at the same
        // t with a lower index is still found; `is_closer_than` decides.
        let mut test_ray = *ray;
        let mut stack = [(0u32, 0f32); STACK];
        let mut sp = 0usize;
        let root_t = self.enter::<T>(0, ray, &slab, ray.tmax)?;
        let mut current = Some((0u32, root_t));
        loop {
            let (index, near) = match current.take() {
                Some(c) => c,
                None => {
                    if sp == 0 {
                        break;
                    }
                    sp -= 1;
                    stack[sp]
                }
            };
            let best_t = best.map_or(ray.tmax, |h| h.t);
            if near > best_t * (1.0 + CULL_SLACK) {
                continue;
            }
            counter.node();
            let node = &self.nodes[index as usize];
            if node.is_leaf() {
                let first = node.offset as usize;
                let leaf = first..first + node.count as usize;
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
            let (left, right) = (index + 1, node.offset);
            let cut = best_t * (1.0 + CULL_SLACK);
            let tl = self.enter::<T>(left, ray, &slab, cut);
            let tr = self.enter::<T>(right, ray, &slab, cut);
            match (tl, tr) {
                (Some(a), Some(b)) => {
                    let (first, second) = if a <= b {
                        ((left, a), (right, b))
                    } else {
                        ((right, b), (left, a))
                    };
                    debug_assert!(sp < STACK);
                    stack[sp] = second;
                    sp += 1;
                    current = Some(first);
                }
                (Some(a), None) => current = Some((left, a)),
                (None, Some(b)) => current = Some((right, b)),
                (None, None) => {}
            }
        }
        best
    }

    fn any<T: BlockTest, C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        if self.nodes.is_empty() || !ray.is_valid() {
            return false;
        }
        let prepared = T::prepare(ray);
        let slab = SlabRay::new(ray);
        if self.enter::<T>(0, ray, &slab, ray.tmax).is_none() {
            return false;
        }
        let mut stack = [0u32; STACK];
        let mut sp = 0usize;
        let mut current = Some(0u32);
        loop {
            let index = match current.take() {
                Some(i) => i,
                None => {
                    if sp == 0 {
                        return false;
                    }
                    sp -= 1;
                    stack[sp]
                }
            };
            counter.node();
            let node = &self.nodes[index as usize];
            if node.is_leaf() {
                let first = node.offset as usize;
                for slot in first..first + node.count as usize {
                    counter.triangle();
                    if T::test(&prepared, ray, &self.tris[slot]).is_some() {
                        return true;
                    }
                }
                continue;
            }
            let (left, right) = (index + 1, node.offset);
            let hit_left = self.enter::<T>(left, ray, &slab, ray.tmax).is_some();
            let hit_right = self.enter::<T>(right, ray, &slab, ray.tmax).is_some();
            match (hit_left, hit_right) {
                (true, true) => {
                    debug_assert!(sp < STACK);
                    stack[sp] = right;
                    sp += 1;
                    current = Some(left);
                }
                (true, false) => current = Some(left),
                (false, true) => current = Some(right),
                (false, false) => {}
            }
        }
    }
}
