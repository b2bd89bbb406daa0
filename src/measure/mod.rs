//! The last stage: measuring what the backends answer and how fast, and
//! writing it down. `validate` judges hits against another backend or the
//! [`exact`] reference, `stats` counts a tree's work per ray, `stress` finds
//! where intersection methods fail, and `rayfile` records rays so that every
//! backend can be judged on the same ones.

pub(crate) mod exact;
pub mod rayfile;
pub(crate) mod stats;
pub mod stress;
pub mod validate;
