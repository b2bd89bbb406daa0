//! Acceleration structures behind one small interface: closest hit and any hit.
//!
//! Every backend answers the same queries over the same gathered triangle data
//! with the same ray/triangle test and tie-break ([`crate::geometry::Hit::is_closer_than`]),
//! so the renderer produces the same image whichever backend it is given.

pub mod bvh;
pub mod embree;
pub(crate) mod flat_numbered;
pub mod library;
pub mod naive;
pub(crate) mod query;
pub(crate) mod spec;
pub mod update;

pub use query::Query;
pub use spec::{
    build_backend, build_scene_backend, parse_backend, BackendKind, BackendSpec, Built,
};

use crate::geometry::{Hit, Ray};

/// A ray-tracing backend over one scene: closest hit and any hit. What it is
/// and how long it took to build are its [`Built`]'s (the spec and the time
/// measured by [`build_backend`]), not the backend's.
///
/// Contract for both queries: only hits with `t` in `(ray.tmin, ray.tmax)` count;
/// invalid rays ([`Ray::is_valid`] false: NaN, infinite or zero direction) never
/// hit. Implementations are immutable after construction and shared between
/// render threads.
pub trait Backend: Send + Sync {
    /// The closest hit, ties broken by the lowest triangle index.
    fn intersect(&self, ray: &Ray) -> Option<Hit>;

    /// Whether anything is hit within `(ray.tmin, ray.tmax)`.
    fn occluded(&self, ray: &Ray) -> bool;

    /// [`Self::intersect`] for each of `rays` (each with its own `tmin` and
    /// `tmax`) into `hits`, which is as long. A stream lets a backend trace
    /// neighbouring rays together (packets); the answers must be the ones
    /// the single-ray query gives. The default asks one ray at a time.
    fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        debug_assert_eq!(rays.len(), hits.len());
        for (ray, hit) in rays.iter().zip(hits) {
            *hit = self.intersect(ray);
        }
    }

    /// [`Self::occluded`] for each of `rays` into `occluded`, as
    /// [`Self::intersect_stream`].
    fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        debug_assert_eq!(rays.len(), occluded.len());
        for (ray, o) in rays.iter().zip(occluded) {
            *o = self.occluded(ray);
        }
    }

    /// Bytes of the acceleration structure (nodes and leaf data, as the
    /// backend holds them), when it has one to speak of.
    fn memory_bytes(&self) -> Option<usize> {
        None
    }

    /// Whether render threads should flush denormals while tracing (Embree asks
    /// for it; the schedules set and restore it per work unit).
    fn flushes_denormals(&self) -> bool {
        false
    }
}
