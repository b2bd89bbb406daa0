//! Bounding volume hierarchies built by hand, in the order data flows through
//! them:
//!
//! - [`params`]: what to build ([`BuildParams`], presets) and every tunable;
//! - [`prim`]: the input triangles and what the builders work on;
//! - `builder`: [`build`], the one entry point (one file per builder inside);
//! - the layouts: [`node`] (the binary tree), [`wide`] (4- and 8-wide nodes,
//!   their collapse from a binary tree, their traversal), [`leaf`] (blocks of
//!   four triangles), [`tree`] (whichever of them is traversed);
//! - [`traverse`] (the binary traversal and the [`Traversal`] interface),
//!   [`simd`] (the wide trees' node kernels), [`simd_packet`] (the packet
//!   kernels of the 8-wide tree's packet traversal, written once over the
//!   AVX2 and AVX-512 lanes of `simd_lanes`);
//! - [`refit`]: a built tree's boxes recomputed for moved triangles;
//! - [`backend`]: the tree as a render backend; [`quality`]: the metrics that
//!   explain a tree's speed.

pub(crate) mod backend;
mod builder;
pub mod leaf;
pub(crate) mod node;
pub mod params;
pub(crate) mod prim;
pub mod quality;
pub(crate) mod refit;
pub mod simd;
#[cfg(target_arch = "x86_64")]
pub(crate) mod simd_lanes;
pub(crate) mod simd_packet;
pub(crate) mod simd_stack;
#[cfg(target_arch = "x86_64")]
pub(crate) mod simd_watertight;
pub(crate) mod traverse;
pub(crate) mod tree;
pub(crate) mod two_level;
pub(crate) mod wide;

pub use backend::BvhBackend;
pub use builder::build;
pub(crate) use builder::pool::in_pool;
pub use node::{Bvh, Node};
pub use params::{BuildParams, BuilderKind};
pub use prim::Triangles;
pub use traverse::Traversal;
pub use tree::Tree;

/// Triangle sets the unit tests of the trees share.
#[cfg(test)]
pub(crate) mod test_fixtures {
    use glam::Vec3;

    use crate::accel::bvh::{build, BuildParams, Bvh, Triangles};
    use crate::rng::Rng;

    /// The binary tree of `params`' splits ([`BuildParams::binary`]).
    pub fn binary<T: Triangles + ?Sized>(tris: &T, params: &BuildParams) -> Bvh {
        let tree = build(tris, &params.binary()).unwrap();
        tree.into_binary().expect("width 2 builds a binary tree")
    }

    /// `n` small random triangles (sides up to 0.5) scattered in a box of side
    /// 10; the same set for the same `seed`.
    pub fn random_tris(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = Rng::for_pixel(0, seed, 9);
        let mut v = |s: f32| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s;
        (0..n)
            .map(|_| {
                let c = v(10.0);
                [c + v(0.5), c + v(0.5), c + v(0.5)]
            })
            .collect()
    }
}
