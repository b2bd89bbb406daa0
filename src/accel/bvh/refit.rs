//! Refitting: a built tree's boxes recomputed bottom-up for triangles that
//! moved, its topology and leaves kept (the per-frame update of an animated
//! scene, against a rebuild). Each box is `padded(union of its triangles'
//! boxes)`, exactly as the builders make it, so a refitted tree holds boxes
//! that bound its triangles as tightly as a build of the same topology would,
//! and it finds the same hits: hits are decided by the triangle tests, which
//! read the updated leaf vertices, and the boxes only prune.
//!
//! Two passes: the leaf vertices in parallel, since they read the scene's
//! triangles at random; then the node boxes from the leaves up, a leaf's box
//! from its blocks four lanes at a time, the top levels' subtrees in
//! parallel (on the depth-first layout the builders make, where every
//! subtree is a run of nodes that can be handed to a thread of its own). A tree a spatial-split
//! builder made refits to whole-triangle boxes, never the clipped ones it was
//! built with: the refit cannot know where the moved triangle's clipped parts
//! lie, and the whole box is the safe bound.

use arrayvec::ArrayVec;
use glam::Vec4;
use rayon::prelude::*;

use super::builder::pool::share;
use super::in_pool;

use super::leaf::{prefetch_triangles, Tri4, EMPTY_ID};
use super::node::{padded, Bvh};
use super::params::{FILL_AHEAD, REFIT_CHUNK, REFIT_PARALLEL_DEPTH};
use super::prim::Triangles;
use super::tree::Tree;
use super::wide::node::{for_leaf_blocks, EMPTY, LEAF};
use super::wide::{WideBvh, WideNode};
use crate::error::{Error, Result};
use crate::geometry::Aabb;

/// The box of the triangles in `block`'s lanes set in `lanes` (a mask),
/// four lanes at a time: the rows of the three vertices per axis, unused
/// lanes replaced by +inf (for the minimum) and -inf (for the maximum).
#[inline]
fn lanes_box(block: &Tri4, lanes: u32) -> Aabb {
    let used = glam::BVec4A::new(
        lanes & 1 != 0,
        lanes & 2 != 0,
        lanes & 4 != 0,
        lanes & 8 != 0,
    );
    let (inf, neg) = (Vec4::splat(f32::INFINITY), Vec4::splat(f32::NEG_INFINITY));
    let mut lo = [0f32; 3];
    let mut hi = [0f32; 3];
    for axis in 0..3 {
        let [a, b, c] = [block.v[0][axis], block.v[1][axis], block.v[2][axis]];
        lo[axis] = Vec4::select(used, a.min(b).min(c), inf).min_element();
        hi[axis] = Vec4::select(used, a.max(b).max(c), neg).max_element();
    }
    Aabb {
        min: glam::Vec3::from(lo),
        max: glam::Vec3::from(hi),
    }
}

/// The runs of `head`'s interior children in `rest` (the nodes after it in
/// a depth-first layout: each child's subtree a run, in index order), as
/// (lane, child, run); `None` when the layout is not so.
#[allow(clippy::type_complexity)]
fn child_runs<'a, const N: usize>(
    head: &WideNode<N>,
    first: u32,
    mut rest: &'a mut [WideNode<N>],
) -> Option<ArrayVec<(usize, u32, &'a mut [WideNode<N>]), N>> {
    // Interior lanes by child index: their runs follow one another.
    let mut kids: ArrayVec<(usize, u32), N> = (0..N)
        .filter(|&l| head.child[l] != EMPTY && head.child[l] & LEAF == 0)
        .map(|l| (l, head.child[l]))
        .collect();
    kids.sort_unstable_by_key(|&(_, c)| c);
    let mut runs = ArrayVec::new();
    let mut at = first.checked_add(1)?;
    for (i, &(lane, child)) in kids.iter().enumerate() {
        if child != at {
            return None;
        }
        let len = match kids.get(i + 1) {
            Some(&(_, next)) => (next - child) as usize,
            None => rest.len(),
        };
        if len == 0 || len > rest.len() {
            return None;
        }
        let (run, tail) = std::mem::take(&mut rest).split_at_mut(len);
        runs.push((lane, child, run));
        rest = tail;
        at = at.checked_add(len as u32)?;
    }
    rest.is_empty().then_some(runs)
}

/// Sets the lane boxes of the subtree whose root is node `first`, laid out
/// depth-first in `nodes`, from the blocks' vertices; returns its unpadded
/// box, or `None` as soon as the layout is not so (boxes set so far are
/// right, and the caller refits the rest another way).
fn refit_run<const N: usize>(
    nodes: &mut [WideNode<N>],
    first: u32,
    blocks: &[Tri4],
) -> Option<Aabb> {
    let (head, rest) = nodes.split_first_mut()?;
    let runs = child_runs(head, first, rest)?;
    let boxes: ArrayVec<(usize, Option<Aabb>), N> = runs
        .into_iter()
        .map(|(lane, child, run)| (lane, refit_run(run, child, blocks)))
        .collect();
    fit_lanes(head, blocks, |lane, _| {
        boxes.iter().find(|(l, _)| *l == lane)?.1
    })
}

/// What a lane of a top node has below it: a run (by its index in the
/// runs) or another top node (by its index in the tops).
#[derive(Clone, Copy)]
enum Below {
    Run(usize),
    Top(usize),
}

/// A node of a tree's top levels, fitted after the runs below it.
struct Top<'a, const N: usize> {
    node: &'a mut WideNode<N>,
    kids: ArrayVec<(usize, Below), N>,
}

/// The top `depth` levels of the subtree at `nodes` (root `first`, laid
/// out depth-first) into `tops`, parents before children, and the subtrees
/// under them into `runs` as (root, nodes); `None` when the layout is not
/// depth-first (nothing is changed then).
#[allow(clippy::type_complexity)]
fn split_top<'a, const N: usize>(
    nodes: &'a mut [WideNode<N>],
    first: u32,
    depth: u32,
    tops: &mut Vec<Top<'a, N>>,
    runs: &mut Vec<(u32, &'a mut [WideNode<N>])>,
) -> Option<Below> {
    if depth == 0 {
        runs.push((first, nodes));
        return Some(Below::Run(runs.len() - 1));
    }
    let (head, rest) = nodes.split_first_mut()?;
    let children = child_runs(head, first, rest)?;
    let me = tops.len();
    tops.push(Top {
        node: head,
        kids: ArrayVec::new(),
    });
    for (lane, child, run) in children {
        let below = split_top(run, child, depth - 1, tops, runs)?;
        tops[me].kids.push((lane, below));
    }
    Some(Below::Top(me))
}

/// Pass 2 on a depth-first layout: the subtrees under the top `depth`
/// levels refitted on their own slices, shared among `threads` threads
/// (each claims the next subtree), then the top levels' nodes from their
/// boxes. `false` when the layout is not depth-first (the caller refits the
/// rest another way; boxes set so far are right).
fn refit_depth_first<const N: usize>(
    nodes: &mut [WideNode<N>],
    blocks: &[Tri4],
    depth: u32,
    threads: usize,
) -> bool {
    let (mut tops, mut runs) = (Vec::new(), Vec::new());
    let Some(root) = split_top(nodes, 0, depth, &mut tops, &mut runs) else {
        return false;
    };
    let run_boxes = share(threads, runs, |(first, run)| refit_run(run, first, blocks));
    // Parents were listed before their children: fitted in reverse. A box
    // is `None` when the layout failed below it, so the root's says whether
    // the whole tree was refitted.
    let mut top_boxes: Vec<Option<Aabb>> = vec![None; tops.len()];
    let box_of = |below: Below, top_boxes: &[Option<Aabb>]| match below {
        Below::Run(r) => run_boxes[r],
        Below::Top(t) => top_boxes[t],
    };
    for (i, top) in tops.into_iter().enumerate().rev() {
        let kids = top.kids;
        let b = fit_lanes(top.node, blocks, |lane, _| {
            box_of(kids.iter().find(|(l, _)| *l == lane)?.1, &top_boxes)
        });
        top_boxes[i] = b;
    }
    box_of(root, &top_boxes).is_some()
}

/// Sets every used lane of `node` to its padded box, a leaf's from
/// `blocks`, a child node's unpadded box from `child_box(lane, child)`;
/// returns the node's unpadded box (`None` when a child's box is missing).
fn fit_lanes<const N: usize>(
    node: &mut WideNode<N>,
    blocks: &[Tri4],
    child_box: impl Fn(usize, u32) -> Option<Aabb>,
) -> Option<Aabb> {
    let mut node_box = Aabb::EMPTY;
    for lane in 0..N {
        let child = node.child[lane];
        if child == EMPTY {
            continue;
        }
        let b = if child & LEAF != 0 {
            let mut b = Aabb::EMPTY;
            for_leaf_blocks(child, |block, lanes| {
                b = b.union(lanes_box(&blocks[block], lanes));
                false
            });
            b
        } else {
            child_box(lane, child)?
        };
        node_box = node_box.union(b);
        node.set_lane(lane, &padded(b), child);
    }
    Some(node_box)
}

/// Pass 1 over a run of blocks: each block's lanes set to its triangles as
/// they are now, their reads asked for [`FILL_AHEAD`] blocks early (twice as
/// early, the index triples), as the build's leaf fill does. Without it the
/// pass waited on those reads: a refit after a trace had evicted the scene
/// took 1.1-1.3x Embree's refit time (cloth:20000, explode:20000). Returns
/// one more than the highest triangle index the run holds; lanes whose
/// triangle is not among the `count` given are left as they were.
fn update_blocks<T: Triangles + ?Sized>(run: &mut [Tri4], triangles: &T, count: usize) -> usize {
    let ask = |run: &[Tri4], b: usize, stage: u8| {
        if let Some(block) = run.get(b) {
            prefetch_triangles(triangles, &block.ids, stage);
        }
    };
    let mut indexed = 0;
    for b in 0..run.len() {
        ask(run, b + 2 * FILL_AHEAD, 0);
        ask(run, b + FILL_AHEAD, 1);
        let mut ids = run[b].ids;
        for id in &mut ids {
            if *id != EMPTY_ID {
                indexed = indexed.max(*id as usize + 1);
                if *id as usize >= count {
                    *id = EMPTY_ID;
                }
            }
        }
        run[b].fill(&ids, triangles);
    }
    indexed
}

/// Refuses triangles that are not the ones the tree was built over (another
/// count cannot be the same topology). A wide tree refused this way has
/// been refitted in part (pass 1 counts as it goes): build it anew.
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
    /// built over, moved) on `threads` threads: the caller and the kept
    /// pool's workers.
    pub fn refit<T: Triangles + ?Sized>(&mut self, triangles: &T, threads: usize) -> Result<()> {
        match self {
            Tree::Binary(t) => in_pool(threads, || t.refit(triangles, threads > 1)),
            Tree::Wide4(t) => t.refit(triangles, threads),
            Tree::Wide8(t) => t.refit(triangles, threads),
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
                    .fold(Aabb::EMPTY, |b, t| b.union(Aabb::from_points(t)))
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
    pub fn refit<T: Triangles + ?Sized>(&mut self, triangles: &T, threads: usize) -> Result<()> {
        // Pass 1: each block's vertices, and the triangles the tree indexes
        // (counted here rather than in a pass of their own over the blocks:
        // that pass was a tenth of a two-thread refit of cloth:20000).
        // Runs of blocks, not single ones: a task per block cost more than
        // it saved at 20k triangles.
        let count = triangles.count();
        let runs: Vec<&mut [Tri4]> = self.blocks.chunks_mut(REFIT_CHUNK).collect();
        let indexed = share(threads, runs, |run| update_blocks(run, triangles, count))
            .into_iter()
            .max()
            .unwrap_or(0);
        check_count(indexed, count)?;
        if self.nodes.is_empty() {
            return Ok(());
        }
        // Pass 2 on a depth-first layout (every subtree a run of nodes, as
        // the builders lay them out): the top levels' subtrees shared among
        // the threads.
        let depth = if threads > 1 { REFIT_PARALLEL_DEPTH } else { 0 };
        if !refit_depth_first(&mut self.nodes, &self.blocks, depth, threads) {
            self.refit_nodes_any_layout();
        }
        self.fit_fused_reach();
        Ok(())
    }

    /// Pass 2 on any layout: preorder from the root, whose reverse reaches
    /// every child before its parent whatever the builder's numbering.
    fn refit_nodes_any_layout(&mut self) {
        let preorder = self.preorder();
        let mut raw = vec![Aabb::EMPTY; self.nodes.len()];
        for &i in preorder.iter().rev() {
            let node = &mut self.nodes[i as usize];
            raw[i as usize] = fit_lanes(node, &self.blocks, |_, child| Some(raw[child as usize]))
                .expect("children come first");
        }
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
                for threads in [1, 2] {
                    let params = BuildParams::for_builder(builder).with_width(width);
                    let mut tree = build(&rest, &params).unwrap();
                    tree.refit(&frame, threads).unwrap();
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

    /// The fused node test's reach (`WideBvh::fused_origin_limit`) is set
    /// by every builder and followed by the refit: a scene near the origin
    /// takes it, the same scene 1e5 away (where the fused test's error,
    /// about 12 ulps of the coordinates, is 6 times the triangles' size)
    /// does not, whether built there or refitted there.
    #[test]
    fn the_fused_tests_reach_follows_the_tree_through_builds_and_refits() {
        use crate::accel::bvh::params::Quality;
        use crate::accel::bvh::params::FUSED_ORIGIN_REACH;
        let near: Vec<[Vec3; 3]> = random_tris(600, 5)
            .iter()
            .map(|t| t.map(|v| v * 0.05))
            .collect();
        let far: Vec<[Vec3; 3]> = near
            .iter()
            .map(|t| t.map(|v| v + Vec3::new(1e5, 0.0, 1e5)))
            .collect();
        let (lo, hi) = near
            .iter()
            .flatten()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let extent = (hi - lo).max_element();
        let limit = |tree: &Tree| match tree {
            Tree::Wide8(t) => t.fused_origin_limit,
            _ => panic!("an 8-wide tree was asked for"),
        };
        let mut params: Vec<BuildParams> = BuilderKind::ALL
            .iter()
            .flat_map(|&b| [1, 2].map(|t| BuildParams::for_builder(b).with_threads(t)))
            .collect();
        params.extend([Quality::Low, Quality::Medium, Quality::High].map(BuildParams::for_quality));
        for params in params.iter().map(|p| p.with_width(8)) {
            let mut tree = build(&near, &params).unwrap();
            let reach = limit(&tree);
            assert!(reach > 0.0 && reach.is_finite(), "{params:?}: {reach}");
            // The reach of the triangles' box (the node boxes' margins
            // aside).
            let want = extent * FUSED_ORIGIN_REACH;
            assert!(
                (reach - want).abs() <= want * 1e-4,
                "{params:?}: {reach}, {want}"
            );
            assert_eq!(
                limit(&build(&far, &params).unwrap()),
                f32::NEG_INFINITY,
                "{params:?}"
            );
            tree.refit(&far, params.threads).unwrap();
            assert_eq!(limit(&tree), f32::NEG_INFINITY, "{params:?}");
            // Back: the reach again (the spatial splits' refitted boxes
            // may differ from the built ones by their margin's rounding).
            tree.refit(&near, params.threads).unwrap();
            assert!((limit(&tree) - reach).abs() <= reach * 1e-4, "{params:?}");
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
        tree.refit(&moved(&rest, 1), 1).unwrap();
        tree.refit(&rest, 1).unwrap();
        let (Tree::Binary(a), Tree::Binary(b)) = (&built, &tree) else {
            panic!("width 2 is binary")
        };
        assert_eq!(a.nodes, b.nodes);
        assert_eq!(a.tris, b.tris);
    }

    #[test]
    fn the_builders_wide_trees_refit_by_runs_as_by_the_preorder_sweep() {
        let rest = random_tris(3000, 8);
        let frame = moved(&rest, 2);
        for builder in [BuilderKind::Sah, BuilderKind::Lbvh, BuilderKind::Sbvh] {
            for optimize in [false, true] {
                let params = BuildParams::for_builder(builder)
                    .with_width(8)
                    .with_optimize(optimize);
                let Tree::Wide8(mut runs) = build(&rest, &params).unwrap() else {
                    panic!("width 8")
                };
                let mut sweep = runs.clone();
                runs.refit(&frame, 2).unwrap();
                sweep.refit(&frame, 1).unwrap();
                sweep.refit_nodes_any_layout();
                assert_eq!(runs.nodes, sweep.nodes, "{builder:?} optimize {optimize}");
                // Every builder lays its tree out depth-first, so the runs
                // path (not the fallback) did the work.
                assert!(
                    super::refit_run(&mut sweep.nodes, 0, &sweep.blocks).is_some(),
                    "{builder:?} optimize {optimize}: not depth-first"
                );
            }
        }
    }

    #[test]
    fn a_refit_with_fewer_triangles_is_refused() {
        let rest = random_tris(100, 3);
        for width in [2, 8] {
            for threads in [1, 2] {
                let mut tree = build(&rest, &BuildParams::sah().with_width(width)).unwrap();
                let err = tree.refit(&rest[..50], threads).unwrap_err().to_string();
                assert!(err.contains("refit") && err.contains("100"), "{err}");
                // Every triangle is counted, the highest index included.
                tree.refit(&rest, threads).unwrap();
            }
        }
    }
}
