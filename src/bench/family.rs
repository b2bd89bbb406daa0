//! Whose a backend is: raylab's own, Embree, or one of the other libraries.
//! The report groups, compares and colours backends by it (it was the
//! strings `"raylab"`, `"embree"` and `"library"`, compared by hand).

use serde::Serialize;

use crate::accel::{BackendKind, BackendSpec};

/// Whose a backend is. In `bench.json` by its [`Family::name`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// raylab's own (its BVHs, and the naive scan).
    Raylab,
    /// Intel Embree, the industrial reference.
    Embree,
    /// tinybvh (through tinybvh-rs).
    Tinybvh,
    /// obvhs.
    Obvhs,
    /// The bvh crate (svenstaro/bvh).
    BvhCrate,
}

impl Family {
    /// Every family, in the order reports list them.
    pub const ALL: [Family; 5] = [
        Family::Raylab,
        Family::Embree,
        Family::Tinybvh,
        Family::Obvhs,
        Family::BvhCrate,
    ];

    /// The family of a backend.
    pub fn of(spec: &BackendSpec) -> Family {
        match spec.kind() {
            BackendKind::Naive | BackendKind::Bvh => Family::Raylab,
            BackendKind::Embree => Family::Embree,
            BackendKind::Tinybvh => Family::Tinybvh,
            BackendKind::Obvhs => Family::Obvhs,
            BackendKind::BvhCrate => Family::BvhCrate,
        }
    }

    /// Another library's (neither raylab's nor Embree).
    pub fn is_library(self) -> bool {
        !matches!(self, Family::Raylab | Family::Embree)
    }

    /// Its name as charts' legends write it.
    pub fn label(self) -> &'static str {
        match self {
            Family::Raylab => "raylab",
            Family::Embree => "Embree",
            Family::Tinybvh => "tinybvh",
            Family::Obvhs => "obvhs",
            Family::BvhCrate => "the bvh crate",
        }
    }

    /// Its name in tables and in `bench.json`.
    pub fn name(self) -> &'static str {
        match self {
            Family::Raylab => "raylab",
            Family::Embree => "embree",
            Family::Tinybvh => "tinybvh",
            Family::Obvhs => "obvhs",
            Family::BvhCrate => "bvh-crate",
        }
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn families_serialize_as_their_names() {
        for f in Family::ALL {
            assert_eq!(
                serde_json::to_string(&f).unwrap(),
                format!("\"{}\"", f.name())
            );
        }
        assert!(Family::Obvhs.is_library() && !Family::Embree.is_library());
        assert_eq!(Family::of(&BackendSpec::embree(1)), Family::Embree);
    }
}
