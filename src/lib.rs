//! raylab: a CPU ray tracer for comparing ray-tracing acceleration structures.
//!
//! Data flows one way: [`scene`] -> [`accel`] (a [`accel::Backend`]) -> [`render`]
//! (the shared shading/AO loop and its schedules) -> image and report. The binary
//! is a thin wrapper over [`cli::main`], which parses the command line and runs
//! one command.

// `!(x > 0.0)` is how this crate rejects NaN together with the out-of-range values;
// clippy's suggested `partial_cmp` form hides that intent.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

// The pipeline's stages and what they are made of: the library's API, which
// the tests, the criterion benches and a program built on raylab use.
pub mod accel;
pub mod bench;
pub mod camera;
pub mod geometry;
pub mod measure;
pub mod os;
pub mod progress;
pub mod render;
pub mod scene;

// The binary's entry (`cli::main`), and behind it the command line and the
// plumbing of its reports, crate-private.
pub mod cli;
mod command;
mod console;
mod error;
mod names;
mod output;
mod rng;
mod table;

pub use error::{Error, Result};
