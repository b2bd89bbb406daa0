//! One module per command: its flags (clap `Args`), its `run`, and its report.
//! [`crate::cli`] only parses the command line and dispatches here.

pub(crate) mod args;
pub(crate) mod bench;
pub(crate) mod rays;
pub(crate) mod render;
pub(crate) mod stats;
pub(crate) mod stress;
pub(crate) mod validate;
