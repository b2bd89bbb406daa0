//! Acceleration structures behind one small interface: closest hit and any hit.
//!
//! Every backend answers the same queries over the same gathered triangle data
//! with the same ray/triangle test and tie-break ([`crate::geometry::Hit::is_closer_than`]),
//! so the renderer produces the same image whichever backend it is given.

pub mod bvh;
pub mod naive;

use std::time::Duration;

use crate::geometry::{Hit, Ray};
use crate::scene::Scene;

/// A ray-tracing backend over one scene.
///
/// Contract for both queries: only hits with `t` in `(ray.tmin, ray.tmax)` count;
/// invalid rays ([`Ray::is_valid`] false: NaN, infinite or zero direction) never
/// hit. Implementations are immutable after construction and shared between
/// render threads.
pub trait Backend: Send + Sync {
    /// A short name for reports (`naive`, `bvh-sah`, ...).
    fn name(&self) -> String;

    /// Wall time from the scene to a ready structure (zero-ish for `naive`).
    fn build_time(&self) -> Duration;

    /// The closest hit, ties broken by the lowest triangle index.
    fn intersect(&self, ray: &Ray) -> Option<Hit>;

    /// Whether anything is hit within `(ray.tmin, ray.tmax)`.
    fn occluded(&self, ray: &Ray) -> bool;
}

/// The backends a user can pick with `--backend`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    /// Every triangle for every ray (the study's O(N) baseline).
    Naive,
    /// A hand-built BVH (`--builder` chooses how).
    Bvh,
}

/// A backend and, for BVHs, how to build it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackendSpec {
    pub kind: BackendKind,
    pub bvh: bvh::BuildParams,
}

/// Builds the chosen backend over `scene`.
pub fn build_backend(spec: &BackendSpec, scene: &Scene) -> Box<dyn Backend> {
    match spec.kind {
        BackendKind::Naive => Box::new(naive::Naive::new(scene)),
        BackendKind::Bvh => Box::new(bvh::BvhBackend::new(scene, &spec.bvh)),
    }
}
