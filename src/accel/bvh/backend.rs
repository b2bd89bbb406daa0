//! raylab's BVH as a render [`Backend`]: a [`Tree`] and the ray/triangle test
//! its leaves use.

use super::builder::build;
use super::leaf::BlockTest;
use super::params::BuildParams;
use super::prim::Triangles;
use super::simd_packet::{PACKET, PACKET16};
use super::traverse::Traversal;
use super::tree::Tree;
use super::wide::Bvh8;
use crate::accel::{Backend, Query};
use crate::error::Error;
use crate::geometry::{Hit, Intersector, Ray};
use crate::geometry::{MollerTrumbore, Watertight};

/// The BVH as a render [`Backend`].
pub struct BvhBackend {
    pub tree: Tree,
    intersector: Intersector,
    /// How streams are traced: single rays, or packets of [`PACKET`] or
    /// [`PACKET16`] rays (8-wide trees only).
    query: Query,
}

impl BvhBackend {
    /// Builds the tree `params` describe over `triangles` (a scene, a mesh,
    /// or raw vertex triples with degenerate ones included) with
    /// Moller-Trumbore for the triangle tests.
    pub fn new<T: Triangles + ?Sized>(triangles: &T, params: &BuildParams) -> crate::Result<Self> {
        Ok(BvhBackend {
            tree: build(triangles, params)?,
            intersector: Intersector::Mt,
            query: Query::Single,
        })
    }

    /// Traces streams with `query`: single rays, or (8-wide trees) packets of
    /// [`PACKET`] or [`PACKET16`] rays.
    pub fn with_query(mut self, query: Query) -> crate::Result<Self> {
        self.set_query(query)?;
        Ok(self)
    }

    /// [`Self::with_query`] in place (unchanged on an error).
    pub fn set_query(&mut self, query: Query) -> crate::Result<()> {
        match (query, &self.tree) {
            (Query::Single, _) => {}
            (Query::Packet(PACKET | PACKET16), Tree::Wide8(_)) => {}
            _ => {
                return Err(Error::usage(
                    "--query",
                    format!(
                        "raylab's {}-wide tree has no {query} path (single, or packet8 and packet16 with --bvh-width 8)",
                        self.tree.width()
                    ),
                ))
            }
        }
        self.query = query;
        Ok(())
    }

    /// How streams are traced.
    pub fn query(&self) -> Query {
        self.query
    }

    /// Uses `intersector` for the triangle tests.
    pub fn with_intersector(mut self, intersector: Intersector) -> Self {
        self.intersector = intersector;
        self
    }
}

impl Backend for BvhBackend {
    fn memory_bytes(&self) -> Option<usize> {
        Some(self.tree.memory_bytes())
    }

    #[inline]
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.tree.intersect_using(ray, self.intersector)
    }

    #[inline]
    fn occluded(&self, ray: &Ray) -> bool {
        self.tree.occluded_using(ray, self.intersector)
    }

    fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        match (&self.tree, self.query) {
            (Tree::Wide8(t), Query::Packet(n)) => match self.intersector {
                Intersector::Mt => closest_in_packets::<MollerTrumbore>(t, n, rays, hits),
                Intersector::Watertight => closest_in_packets::<Watertight>(t, n, rays, hits),
            },
            _ => {
                for (ray, hit) in rays.iter().zip(hits) {
                    *hit = self.intersect(ray);
                }
            }
        }
    }

    fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        match (&self.tree, self.query) {
            (Tree::Wide8(t), Query::Packet(n)) => match self.intersector {
                Intersector::Mt => any_in_packets::<MollerTrumbore>(t, n, rays, occluded),
                Intersector::Watertight => any_in_packets::<Watertight>(t, n, rays, occluded),
            },
            _ => {
                for (ray, o) in rays.iter().zip(occluded) {
                    *o = self.occluded(ray);
                }
            }
        }
    }
}

/// Closest hits of a stream in packets of `n` rays ([`PACKET`] or
/// [`PACKET16`], as `with_query` admits) with triangle test `T`.
fn closest_in_packets<T: BlockTest>(t: &Bvh8, n: usize, rays: &[Ray], hits: &mut [Option<Hit>]) {
    debug_assert!(n == PACKET || n == PACKET16);
    for (rays, hits) in rays.chunks(n).zip(hits.chunks_mut(n)) {
        t.closest_packet_with::<T>(n, rays, hits);
    }
}

/// Occlusion of a stream in packets of `n` rays, as [`closest_in_packets`].
fn any_in_packets<T: BlockTest>(t: &Bvh8, n: usize, rays: &[Ray], occluded: &mut [bool]) {
    debug_assert!(n == PACKET || n == PACKET16);
    for (rays, out) in rays.chunks(n).zip(occluded.chunks_mut(n)) {
        t.any_packet_with::<T>(n, rays, out);
    }
}
