//! Acceleration structures behind one small interface: closest hit and any hit.
//!
//! Every backend answers the same queries over the same gathered triangle data
//! with the same ray/triangle test and tie-break ([`crate::geometry::Hit::is_closer_than`]),
//! so the renderer produces the same image whichever backend it is given.

pub mod bvh;
pub mod embree;
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

/// The backends a user can pick with `--backend`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    /// Every triangle for every ray (the study's O(N) baseline).
    Naive,
    /// A hand-built BVH (`--builder` chooses how).
    Bvh,
    /// Intel Embree's single-ray queries (rtcIntersect1/rtcOccluded1).
    Embree,
}

/// A backend and how to build it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackendSpec {
    pub kind: BackendKind,
    /// For `bvh`: the builder and its parameters (also the build threads for Embree).
    pub bvh: bvh::BuildParams,
    /// For `naive` and `bvh`: the ray/triangle test.
    pub intersector: crate::geometry::Intersector,
    /// For `embree`: scene build quality and the robust flag.
    pub embree_quality: embree::Quality,
    pub embree_robust: bool,
}

impl BackendSpec {
    pub fn bvh(params: bvh::BuildParams) -> Self {
        BackendSpec {
            kind: BackendKind::Bvh,
            bvh: params,
            intersector: crate::geometry::Intersector::Mt,
            embree_quality: embree::Quality::Medium,
            embree_robust: false,
        }
    }

    pub fn with_kind(mut self, kind: BackendKind) -> Self {
        self.kind = kind;
        self
    }

    pub fn with_intersector(mut self, intersector: crate::geometry::Intersector) -> Self {
        self.intersector = intersector;
        self
    }
}

/// Builds the chosen backend over `scene`.
pub fn build_backend(spec: &BackendSpec, scene: &Scene) -> crate::Result<Box<dyn Backend>> {
    Ok(match spec.kind {
        BackendKind::Naive => Box::new(naive::Naive::new(scene).with_intersector(spec.intersector)),
        BackendKind::Bvh => {
            Box::new(bvh::BvhBackend::new(scene, &spec.bvh)?.with_intersector(spec.intersector))
        }
        #[cfg(feature = "embree")]
        BackendKind::Embree => Box::new(embree::EmbreeBackend::new(
            scene,
            spec.embree_quality,
            spec.embree_robust,
            spec.bvh.threads,
        )?),
        #[cfg(not(feature = "embree"))]
        BackendKind::Embree => return Err(embree::unavailable()),
    })
}
