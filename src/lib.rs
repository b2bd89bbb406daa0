//! raylab: a CPU ray tracer for comparing ray-tracing acceleration structures.
//!
//! Data flows one way: [`scene`] -> [`accel`] (a [`accel::Backend`]) -> [`render`]
//! (the shared shading/AO loop and its schedules) -> image and report. The binary
//! is a thin wrapper over [`cli`], which dispatches to one module per command in
//! [`command`].

// `!(x > 0.0)` is how this crate rejects NaN together with the out-of-range values;
// clippy's suggested `partial_cmp` form hides that intent.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod bench;
pub mod camera;
pub mod cli;
pub mod command;
pub mod console;
pub mod error;
pub mod geometry;
pub mod measure;
pub mod names;
pub mod os;
pub mod output;
pub mod progress;
pub mod render;
pub mod rng;
pub mod scene;
pub mod table;

pub use error::{Error, Result};
