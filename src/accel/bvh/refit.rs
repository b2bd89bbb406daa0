//! Refitting: a built tree's boxes recomputed bottom-up for triangles that
//! moved, its topology and leaves kept (the per-frame update of an animated
//! scene, against a rebuild). Each box is `padded(union of its triangles'
//! boxes)`, exactly as the builders make it, so a refitted tree holds boxes
//! that bound its triangles as tightly as a build of the same topology would,
//! and it finds the same hits: hits are decided by the triangle tests, which
//! read the updated leaf vertices, and the boxes only prune.
//!
//! Two passes: the leaf vertices (and each leaf slot's box) in parallel,
//! since they read the scene's triangles at random; then the node boxes from
//! the leaves up, serially (a few operations per node). A tree a spatial-split
//! builder made refits to whole-triangle boxes, never the clipped ones it was
//! built with: the refit cannot know where the moved triangle's clipped parts
//! lie, and the whole box is the safe bound.

use rayon::prelude::*;

use super::leaf::{Tri4, EMPTY_ID, LANES};
use super::node::{padded, Bvh};
use super::prim::Triangles;
use super::tree::Tree;
use super::wide::node::{leaf_slots, EMPTY, LEAF};
use super::wide::WideBvh;
use crate::error::{Error, Result};
use crate::geometry::Aabb;

/// The box of a triangle.
#[inline]
fn triangle_box(t: &[glam::Vec3; 3]) -> Aabb {
    Aabb {
        min: t[0].min(t[1]).min(t[2]),
        max: t[0].max(t[1]).max(t[2]),
    }
}

/// Refuses triangles that are not the ones the tree was built over (another
/// count cannot be the same topology).
fn check_count(tree_tris: usize, triangles: usize) -> Result<()> {
    if triangles < tree_tris {
        return Err(Error::Other(format!(
            "refit: the tree indexes {tree_tris} triangles, the update has {triangles}"
        )));
    }
    Ok(())
}

impl Tree {
    /// Refits the tree to `triangles` (the same triangles by index as it was
    /// built over, moved), in parallel when `parallel` (on the current rayon
    /// pool).
    pub fn refit<T: Triangles + ?Sized>(&mut self, triangles: &T, parallel: bool) -> Result<()> {
        match self {
            Tree::Binary(t) => t.refit(triangles, parallel),
            Tree::Wide4(t) => t.refit(triangles, parallel),
            Tree::Wide8(t) => t.refit(triangles, parallel),
        }
    }
}

impl Bvh {
    /// Refits the binary tree (see the module notes).
    pub fn refit<T: Triangles + ?Sized>(&mut self, triangles: &T, parallel: bool) -> Result<()> {
        let highest = self.tri_ids.iter().max().map_or(0, |&m| m as usize + 1);
        check_count(highest, triangles.count())?;
        let ids = &self.tri_ids;
        let fill = |(slot, tri): (usize, &mut [glam::Vec3; 3])| {
            *tri = triangles.get(ids[slot] as usize);
        };
        if parallel {
            self.tris.par_iter_mut().enumerate().for_each(fill);
        } else {
            self.tris.iter_mut().enumerate().for_each(fill);
        }
        // Depth-first order: both children of node `i` come after it, so a
        // sweep from the last node up meets every child before its parent.
        let mut raw = vec![Aabb::EMPTY; self.nodes.len()];
        for i in (0..self.nodes.len()).rev() {
            let node = self.nodes[i];
            let b = if node.is_leaf() {
                let slots = node.offset as usize..(node.offset + node.count) as usize;
                self.tris[slots]
                    .iter()
                    .fold(Aabb::EMPTY, |b, t| b.union(triangle_box(t)))
            } else {
                raw[i + 1].union(raw[node.offset as usize])
            };
            raw[i] = b;
            let p = padded(b);
            self.nodes[i].min = p.min;
            self.nodes[i].max = p.max;
        }
        Ok(())
    }
}

impl<const N: usize> WideBvh<N> {
    /// Refits the wide tree (see the module notes). Lane order is kept: the
    /// order the any-hit walk takes lanes in changes how soon an occluder is
    /// found, never whether.
    pub fn refit<T: Triangles + ?Sized>(&mut self, triangles: &T, parallel: bool) -> Result<()> {
        let highest = self
            .blocks
            .iter()
            .flat_map(|b| b.ids)
            .filter(|&id| id != EMPTY_ID)
            .max()
            .map_or(0, |m| m as usize + 1);
        check_count(highest, triangles.count())?;
        // Pass 1: each block's vertices, and each used lane's triangle box.
        let update = |block: &mut Tri4| -> [Aabb; LANES] {
            let mut boxes = [Aabb::EMPTY; LANES];
            for (lane, b) in boxes.iter_mut().enumerate() {
                let id = block.ids[lane];
                if id != EMPTY_ID {
                    let tri = triangles.get(id as usize);
                    block.set_lane(lane, &tri, id);
                    *b = triangle_box(&tri);
                }
            }
            boxes
        };
        let slot_boxes: Vec<[Aabb; LANES]> = if parallel {
            self.blocks.par_iter_mut().map(update).collect()
        } else {
            self.blocks.iter_mut().map(update).collect()
        };
        if self.nodes.is_empty() {
            return Ok(());
        }
        // Pass 2: preorder from the root, whose reverse reaches every child
        // before its parent whatever the builder's numbering.
        let mut preorder = Vec::with_capacity(self.nodes.len());
        let mut pending = vec![0u32];
        while let Some(i) = pending.pop() {
            preorder.push(i);
            for &child in &self.nodes[i as usize].child {
                if child != EMPTY && child & LEAF == 0 {
                    pending.push(child);
                }
            }
        }
        let mut raw = vec![Aabb::EMPTY; self.nodes.len()];
        for &i in preorder.iter().rev() {
            let mut node_box = Aabb::EMPTY;
            let node = &mut self.nodes[i as usize];
            for lane in 0..N {
                let child = node.child[lane];
                if child == EMPTY {
                    continue;
                }
                let b = if child & LEAF != 0 {
                    let (first, end) = leaf_slots(child);
                    (first..end).fold(Aabb::EMPTY, |b, slot| {
                        b.union(slot_boxes[slot / LANES][slot % LANES])
                    })
                } else {
                    raw[child as usize]
                };
                node_box = node_box.union(b);
                node.set_lane(lane, &padded(b), child);
            }
            raw[i as usize] = node_box;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use crate::accel::bvh::test_fixtures::random_tris;
    use crate::accel::bvh::traverse::Traversal;
    use crate::accel::bvh::{build, BuildParams, BuilderKind, Tree};
    use crate::accel::naive::Naive;
    use crate::accel::Backend;
    use crate::geometry::{Intersector, Ray};
    use crate::rng::Rng;

    /// Every triangle moved its own way: translated up to 3 units (out of
    /// the original bounds, box side 10) and its vertices jittered.
    fn moved(tris: &[[Vec3; 3]], seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = Rng::for_pixel(1, seed, 3);
        let mut v = |s: f32| {
            Vec3::new(
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
            ) * s
        };
        tris.iter()
            .map(|t| {
                let shift = v(6.0) + Vec3::new(4.0, 0.0, 0.0);
                [t[0] + shift, t[1] + shift + v(0.3), t[2] + shift + v(0.3)]
            })
            .collect()
    }

    fn rays(n: usize, seed: u64) -> Vec<Ray> {
        let mut rng = Rng::for_pixel(2, seed, 5);
        (0..n)
            .map(|_| {
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 18.0
                    - Vec3::splat(4.0);
                let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
                Ray::new(o, d)
            })
            .collect()
    }

    #[test]
    fn refitted_trees_answer_as_the_naive_scan_and_a_rebuild_after_motion_out_of_bounds() {
        let rest = random_tris(1500, 11);
        let frame = moved(&rest, 4);
        let rays = rays(3000, 9);
        let naive = Naive::from_triangles(frame.clone());
        for builder in [BuilderKind::Sah, BuilderKind::Lbvh, BuilderKind::Sbvh] {
            for width in [2, 4, 8] {
                for parallel in [false, true] {
                    let params = BuildParams::for_builder(builder).with_width(width);
                    let mut tree = build(&rest, &params).unwrap();
                    tree.refit(&frame, parallel).unwrap();
                    let fresh = build(&frame, &params).unwrap();
                    for ray in &rays {
                        let want = naive.intersect(ray);
                        let got = tree.intersect_using(ray, Intersector::Mt);
                        assert_eq!(got, want, "{builder:?} width {width}");
                        assert_eq!(got, fresh.intersect_using(ray, Intersector::Mt));
                        assert_eq!(
                            tree.occluded_using(ray, Intersector::Mt),
                            want.is_some(),
                            "{builder:?} width {width}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn refit_back_to_the_rest_pose_gives_the_built_boxes() {
        // Same topology, same triangles: every box as built (the builders
        // pad the union of the triangles' boxes, as the refit does).
        let rest = random_tris(800, 3);
        let params = BuildParams::sah().with_width(2);
        let built = build(&rest, &params).unwrap();
        let mut tree = build(&rest, &params).unwrap();
        tree.refit(&moved(&rest, 1), false).unwrap();
        tree.refit(&rest, false).unwrap();
        let (Tree::Binary(a), Tree::Binary(b)) = (&built, &tree) else {
            panic!("width 2 is binary")
        };
        assert_eq!(a.nodes, b.nodes);
        assert_eq!(a.tris, b.tris);
    }

    #[test]
    fn a_refit_with_fewer_triangles_is_refused() {
        let rest = random_tris(100, 3);
        let mut tree = build(&rest, &BuildParams::sah().with_width(8)).unwrap();
        let err = tree.refit(&rest[..50], false).unwrap_err().to_string();
        assert!(err.contains("refit") && err.contains("100"), "{err}");
    }
}
