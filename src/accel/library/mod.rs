//! The other CPU BVH libraries people use, as backends: tinybvh (through
//! tinybvh-rs), obvhs and the bvh crate. Each is built with its own builder
//! and traversed with its own kernels and its own ray/triangle test, so the
//! same loop measures what a user of that library gets, and `validate` and
//! `stress` find where its answers differ from an exact one.
//!
//! Each is a cargo feature (on by default). What a library cannot do is said
//! where a user meets it ([`Library::limits`]): a flag it has no use for is
//! refused, and the bench's rows name the missing query.

use crate::accel::embree::Quality;

#[cfg(feature = "bvh-crate")]
pub(crate) mod bvh_crate;
#[cfg(feature = "obvhs")]
pub(crate) mod obvhs;
#[cfg(feature = "tinybvh")]
pub(crate) mod tinybvh;

/// tinybvh's CPU layouts that tinybvh-rs can traverse.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TinybvhLayout {
    /// `BVH8_CPU`: 8-wide nodes and 4-triangle SIMD leaves, its fastest CPU
    /// layout (Fuetterling et al. 2017), converted from the binary tree.
    Bvh8,
    /// `BVH`: the binary 32-byte-node tree ("Wald" layout) it builds first.
    Bvh,
}

/// obvhs's two trees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ObvhsLayout {
    /// `CwBvh`: compressed 8-wide nodes (Ylitie et al. 2017).
    CwBvh,
    /// `Bvh2`: the binary tree its PLOC builder makes.
    Bvh2,
}

/// Another library's BVH and how it is built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Library {
    /// tinybvh: `Build` (binned SAH) or, `hq`, `BuildHQ` (with spatial splits).
    Tinybvh { layout: TinybvhLayout, hq: bool },
    /// obvhs: PLOC, with its build presets mapped onto the quality ladder
    /// (low = `fast_build`, medium = `medium_build`, high = `slow_build`).
    Obvhs {
        layout: ObvhsLayout,
        quality: Quality,
    },
    /// The bvh crate (svenstaro/bvh): its SAH builder, binary tree.
    BvhCrate,
}

impl Library {
    /// Every library and layout raylab wraps, at each library's default
    /// build, plus tinybvh's BuildHQ: what `stress` and the bench's
    /// `libraries` part compare.
    pub const ALL: [Library; 6] = [
        Library::Tinybvh {
            layout: TinybvhLayout::Bvh8,
            hq: false,
        },
        Library::Tinybvh {
            layout: TinybvhLayout::Bvh8,
            hq: true,
        },
        Library::Tinybvh {
            layout: TinybvhLayout::Bvh,
            hq: false,
        },
        Library::Obvhs {
            layout: ObvhsLayout::CwBvh,
            quality: Quality::Medium,
        },
        Library::Obvhs {
            layout: ObvhsLayout::Bvh2,
            quality: Quality::Medium,
        },
        Library::BvhCrate,
    ];

    /// The name reports use.
    pub fn name(&self) -> String {
        match self {
            Library::Tinybvh { layout, hq } => format!(
                "tinybvh-{}{}",
                match layout {
                    TinybvhLayout::Bvh8 => "bvh8",
                    TinybvhLayout::Bvh => "bvh",
                },
                if *hq { "-hq" } else { "" }
            ),
            Library::Obvhs { layout, quality } => format!(
                "obvhs-{}-{}",
                match layout {
                    ObvhsLayout::CwBvh => "cwbvh",
                    ObvhsLayout::Bvh2 => "bvh2",
                },
                quality.name()
            ),
            Library::BvhCrate => "bvh-crate".into(),
        }
    }

    /// Whether the build can use more than one thread.
    pub const fn builds_in_parallel(&self) -> bool {
        !matches!(self, Library::Tinybvh { .. })
    }

    /// What this library cannot do that raylab's loop asks of it, and what
    /// the backend does instead: one line per gap, shown in reports.
    pub fn limits(&self) -> &'static [&'static str] {
        match self {
            Library::Tinybvh { .. } => &[
                "no any-hit query in tinybvh-rs: occlusion is a closest-hit query with tmax",
                "no tmin: a ray with tmin > 0 starts at origin + tmin * dir",
                "builds on one thread (tinybvh-rs has no parallel build)",
            ],
            Library::Obvhs { .. } => &[],
            Library::BvhCrate => &[
                "no closest-hit or any-hit traversal: closest hit walks its nearest-first iterator, any hit its iterator",
                "its ray/triangle test culls back faces",
                "no tmin: a ray with tmin > 0 starts at origin + tmin * dir",
            ],
        }
    }

    /// Whether the linked raylab has this library (its cargo feature).
    pub const fn available(&self) -> bool {
        match self {
            Library::Tinybvh { .. } => cfg!(feature = "tinybvh"),
            Library::Obvhs { .. } => cfg!(feature = "obvhs"),
            Library::BvhCrate => cfg!(feature = "bvh-crate"),
        }
    }

    /// The cargo feature that links it.
    pub const fn feature(&self) -> &'static str {
        match self {
            Library::Tinybvh { .. } => "tinybvh",
            Library::Obvhs { .. } => "obvhs",
            Library::BvhCrate => "bvh-crate",
        }
    }
}

/// The error a build without the library's feature gets.
pub fn unavailable(library: &Library) -> crate::Error {
    crate::Error::Other(format!(
        "this raylab was built without {} (cargo feature `{}`); rebuild with default features",
        library.name(),
        library.feature()
    ))
}

/// For the libraries whose rays have no `tmin`: the ray moved to start at
/// `tmin` (origin + tmin * dir, tmax - tmin), the way their users write it,
/// and the `t` to add back to their hits. Exact for tmin = 0, which is every
/// ray the renderer traces; other rays get the rounding of the move. `None`
/// where the moved origin is not finite (a finite ray whose tmin * dir
/// overflows f32): no ray of the library's can say it, so it is a miss.
#[allow(dead_code)] // used by the library modules that are compiled in
pub(crate) fn started_at_tmin(ray: &crate::geometry::Ray) -> Option<(glam::Vec3, f32, f32)> {
    if ray.tmin == 0.0 {
        return Some((ray.origin, ray.tmax, 0.0));
    }
    let origin = ray.origin + ray.dir * ray.tmin;
    origin
        .is_finite()
        .then_some((origin, ray.tmax - ray.tmin, ray.tmin))
}
