//! raylab: a CPU ray tracer for comparing ray-tracing acceleration structures.
//!
//! Data flows one way: [`scene`] -> [`accel`] (a [`accel::Backend`]) -> [`render`]
//! (the shared shading/AO loop and its schedules) -> image and report. The binary
//! is a thin wrapper over [`cli`].

pub mod accel;
pub mod camera;
pub mod cli;
pub mod error;
pub mod geometry;
pub mod progress;
pub mod render;
pub mod scene;

pub use error::{Error, Result};
