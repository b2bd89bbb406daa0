//! One module per command: its flags (clap `Args`), its `run`, and its report.
//! [`crate::cli`] only parses the command line and dispatches here.

pub mod args;
pub mod bench;
pub mod rays;
pub mod render;
pub mod stats;
pub mod stress;
pub mod validate;
