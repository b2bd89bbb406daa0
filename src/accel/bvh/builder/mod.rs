//! Building a BVH: [`build`] is the one way in. It maps [`BuildParams`] to a
//! pipeline in one place (as madmann91/bvh's default builder maps a quality
//! to one): which builder splits (one file each: [`median`], [`sah`], Embree's
//! through [`embree`]), how the splits become the traversed layout (binary
//! through the shared recursion, [`topdown`]; 4- and 8-wide directly,
//! [`nary`], or by collapsing Embree's binary tree), on which thread pool
//! ([`pool`], kept per thread count), and the serial cut-off for small scenes.
//! Everything else here is crate-private.
//!
//! Determinism: a node's partition depends only on its primitives (bins are
//! exact unions and counts, however the reduction is chunked), and the layout
//! depends only on the tree, so the tree is the same for every thread count.
//!
//! How the SAH build is made fast, step by step with what each gave:
//! `docs/design.md`, "Builders, layouts and traversal".

mod embree;
pub(crate) mod lbvh;
pub(crate) mod lbvh_wide;
pub(crate) mod median;
pub(crate) mod nary;
mod partition;
pub(crate) mod pool;
pub(crate) mod reinsert;
pub(crate) mod sah;
pub(crate) mod sbvh;
pub(crate) mod topdown;

use super::node::Skeleton;
use super::params::{BuildParams, BuilderKind, LBVH_PARALLEL_CUTOFF, PARALLEL_CUTOFF};
use super::prim::{gathered, NodeInfo, PrimRef, Triangles, MAX_TRIANGLES};
use super::simd::Kernel;
use super::tree::Tree;
use super::wide::{order_for_any_hit, WideBvh};
use topdown::{Split, Splitter};

/// Builds the tree `params` describe over `triangles` (indexed as in the
/// scene): its builder, leaf limit and SAH block, collapsed or built to
/// `params.width` (2, 4 or 8), on a pool of `params.threads` threads. raylab's
/// builders split no work off below [`PARALLEL_CUTOFF`] triangles (the
/// LBVH below [`LBVH_PARALLEL_CUTOFF`]), so a smaller scene is built on the
/// calling thread: handing it to a pool only cost the wake-up
/// (cornell-sphere's LBVH, 2 threads, paired with Embree LOW: 0.39 on the
/// calling thread, 0.67 on the pool). The tree is the same for any thread
/// count.
///
/// Fails only for more than [`MAX_TRIANGLES`] triangles or in Embree's
/// builders (no Embree in this build, or an Embree error).
pub fn build<T: Triangles + ?Sized>(triangles: &T, params: &BuildParams) -> crate::Result<Tree> {
    let own = params.builder.embree_quality().is_none();
    let serial_below = match params.builder {
        BuilderKind::Lbvh => LBVH_PARALLEL_CUTOFF,
        _ => PARALLEL_CUTOFF,
    };
    let params = if own && triangles.count() < serial_below {
        params.with_threads(1)
    } else {
        *params
    };
    pool::in_pool(params.threads, || {
        let parallel = params.threads > 1;
        Ok(match params.width {
            2 => Tree::Binary(skeleton(triangles, &params)?.gather(triangles, parallel)),
            4 => Tree::Wide4(wide(triangles, &params)?),
            _ => Tree::Wide8(wide(triangles, &params)?),
        })
    })
}

/// raylab's own splitters, chosen by [`BuilderKind`].
enum OwnSplitter {
    Median(median::Median),
    Sah(sah::BinnedSah),
}

impl OwnSplitter {
    /// The splitter of `params`' builder; `None` for Embree's builders.
    fn of(params: &BuildParams) -> Option<OwnSplitter> {
        let max_leaf = params.max_leaf_size.max(1);
        match params.builder {
            BuilderKind::Median => Some(OwnSplitter::Median(median::Median { max_leaf })),
            BuilderKind::Sah => Some(OwnSplitter::Sah(sah::BinnedSah::new(
                max_leaf,
                params.sah_block,
            ))),
            _ => None,
        }
    }
}

impl Splitter for OwnSplitter {
    fn split(&self, prims: &mut [PrimRef], info: &NodeInfo, depth: u32, parallel: bool) -> Split {
        match self {
            OwnSplitter::Median(s) => s.split(prims, info, depth, parallel),
            OwnSplitter::Sah(s) => s.split(prims, info, depth, parallel),
        }
    }
}

/// The triangle count, or the error for more than a build takes.
fn checked_count<T: Triangles + ?Sized>(triangles: &T) -> crate::Result<usize> {
    let count = triangles.count();
    if count > MAX_TRIANGLES {
        return Err(crate::Error::Other(format!(
            "BVH build: {count} triangles, at most {MAX_TRIANGLES}"
        )));
    }
    Ok(count)
}

/// The binary tree of `params`' builder without its triangles gathered, on
/// the current thread pool; reinsertion-optimised when `params.optimize`.
pub(crate) fn skeleton<T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<Skeleton> {
    let built = built_skeleton(triangles, params)?;
    Ok(if params.optimize {
        reinsert::optimize(built)
    } else {
        built
    })
}

/// The binary tree as `params`' builder makes it.
fn built_skeleton<T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<Skeleton> {
    let count = checked_count(triangles)?;
    let parallel = params.threads > 1;
    let max_leaf = params.max_leaf_size.max(1);
    match params.builder {
        BuilderKind::Lbvh => return Ok(lbvh::build(triangles, max_leaf, parallel)),
        BuilderKind::Sbvh => {
            // The spatial search and the splits read a straddling
            // reference's triangle in the references' order, at random in
            // the scene's arrays: one read of three vertices from one place
            // beats an index triple and then three vertices from elsewhere.
            let all = gathered(triangles, parallel);
            return Ok(sbvh::build(&all, max_leaf, params.sah_block, parallel));
        }
        _ => {}
    }
    let Some(splitter) = OwnSplitter::of(params) else {
        // Embree's builder splits triangles spatially: it takes a slice.
        let all = gathered(triangles, parallel);
        let quality = params.builder.embree_quality().expect("an Embree builder");
        return embree::build_with_embree(&all, params, quality);
    };
    if count == 0 {
        return Ok(Skeleton::default());
    }
    Ok(topdown::top_down(triangles, &splitter, parallel))
}

/// The `N`-wide tree of `params`' builder on the current thread pool:
/// directly top-down ([`nary`]) for the builders that split in place
/// (median, SAH), by the LBVH's own wide builder ([`lbvh_wide`]: children
/// opened by count, boxes made bottom-up), by collapsing the binary tree for
/// the others (SBVH, Embree's) and for optimised trees.
pub(crate) fn wide<const N: usize, T: Triangles + ?Sized>(
    triangles: &T,
    params: &BuildParams,
) -> crate::Result<WideBvh<N>> {
    let parallel = params.threads > 1;
    match OwnSplitter::of(params).filter(|_| !params.optimize) {
        Some(splitter) => {
            checked_count(triangles)?;
            nary::build(triangles, &splitter, parallel, Kernel::detect())
        }
        None if params.builder == BuilderKind::Lbvh && !params.optimize => {
            checked_count(triangles)?;
            lbvh_wide::build(triangles, params.max_leaf_size, parallel, Kernel::detect())
        }
        None => {
            let skeleton = skeleton(triangles, params)?.compact();
            let mut tree = WideBvh::from_skeleton(&skeleton, triangles, parallel)?;
            if params.orders_lanes() {
                order_for_any_hit(&mut tree);
            }
            Ok(tree)
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::bvh::node::UNUSED;

    #[test]
    fn wide_build_over_a_scene_equals_the_build_over_its_vertices() {
        // A mesh is read through its index list (and prefetched through it
        // in the leaf fill); the tree must not notice.
        let scene = crate::scene::builtin::builtin("cornell-water").unwrap();
        let mesh = scene.mesh();
        let vertices = scene.triangle_vertices();
        for threads in [1, 2] {
            let params = BuildParams::sah().with_width(8).with_threads(threads);
            let from_scene = pool::in_pool(threads, || wide::<8, _>(&mesh, &params)).unwrap();
            let from_vertices =
                pool::in_pool(threads, || wide::<8, _>(&vertices, &params)).unwrap();
            assert!(from_scene.nodes == from_vertices.nodes, "{threads} threads");
            assert!(
                from_scene.blocks == from_vertices.blocks,
                "{threads} threads"
            );
        }
        // Hints past the end are ignored.
        for stage in [0, 1] {
            mesh.prefetch(mesh.triangle_count(), stage);
            mesh.prefetch(usize::MAX, stage);
        }
    }

    #[test]
    fn compaction_renumbers_depth_first_without_gaps() {
        let tris: Vec<[Vec3; 3]> = (0..300)
            .map(|i| {
                let c = Vec3::new((i % 17) as f32, (i % 5) as f32, (i / 17) as f32);
                [c, c + Vec3::X * 0.5, c + Vec3::Y * 0.5]
            })
            .collect();
        for params in [
            BuildParams::sah(),
            BuildParams::sah().with_width(8),
            BuildParams::median(),
        ] {
            let s = skeleton(&tris, &params).unwrap().compact();
            assert!(s.nodes.iter().all(|n| *n != UNUSED));
            let leaves = s.nodes.iter().filter(|n| n.is_leaf()).count();
            assert_eq!(s.nodes.len(), 2 * leaves - 1);
            for (i, n) in s.nodes.iter().enumerate() {
                if !n.is_leaf() {
                    assert!(n.offset as usize > i + 1 && (n.offset as usize) < s.nodes.len());
                }
            }
            let mut ids = s.tri_ids.clone();
            ids.sort();
            assert_eq!(ids, (0..300).collect::<Vec<u32>>());
        }
    }
}
