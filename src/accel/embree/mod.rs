//! Intel Embree through FFI: the industrial reference backend, and Embree's BVH
//! builder producing trees in raylab's own layout (`builder`).
//!
//! `unsafe` lives only in this module tree: `ffi` (generated bindings), `api`
//! (the Embree 3/4 difference), this safe wrapper, `builder`, and `lanes`
//! (packets laid out with raylab's SIMD transposes).

#[cfg(feature = "embree")]
pub mod api;
#[cfg(feature = "embree")]
pub(crate) mod builder;
#[cfg(feature = "embree")]
mod ffi;
#[cfg(feature = "embree")]
mod instances;
#[cfg(feature = "embree")]
mod lanes;
#[cfg(feature = "embree")]
mod wrapper;

#[cfg(feature = "embree")]
pub use instances::EmbreeInstanced;
#[cfg(feature = "embree")]
pub use wrapper::{
    native_packets, tasking_threads, version, Device, EmbreeBackend, EmbreeScene, EmbreeUpdate,
};

/// Embree's build quality (`--embree-quality`, and the `embree-*` builders).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    Low,
    Medium,
    High,
}

/// Whether this build of raylab links Embree.
pub const AVAILABLE: bool = cfg!(feature = "embree");

/// The error for Embree features in a build without Embree.
pub fn unavailable() -> crate::Error {
    crate::Error::Other(
        "this raylab was built without Embree (cargo feature `embree`); install libembree-dev and rebuild".into(),
    )
}

/// Packet widths the linked Embree traces natively here (none without
/// Embree); asked of a device once per process.
pub fn native_packets_or_none() -> Vec<usize> {
    static NATIVE: std::sync::OnceLock<Vec<usize>> = std::sync::OnceLock::new();
    NATIVE
        .get_or_init(|| {
            #[cfg(feature = "embree")]
            return native_packets();
            #[cfg(not(feature = "embree"))]
            Vec::new()
        })
        .clone()
}

/// The linked Embree's version ("none" in a build without Embree).
pub fn version_or_none() -> String {
    #[cfg(feature = "embree")]
    return version();
    #[cfg(not(feature = "embree"))]
    "none".to_string()
}
