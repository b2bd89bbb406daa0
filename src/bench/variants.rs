//! The bench's variants: each a (backend, builder, schedule) triple with a stable
//! name, as the study combined its optimisations.
//!
//! Build threads: the study built its BVH serially and, as a separate
//! optimisation, in parallel; the `bvh-median-*` variants keep that distinction
//! (`-pbuild` builds on all bench threads). The SAH and Embree variants build on
//! all bench threads whenever they render in parallel, as a modern renderer would.

use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::accel::{BackendKind, BackendSpec, Query};
use crate::error::{Error, Result};
use crate::render::Schedule;

/// One column of the study's tables.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Variant {
    pub name: &'static str,
    pub kind: BackendKind,
    /// For `bvh` variants.
    pub builder: BuilderKind,
    pub schedule: Schedule,
    /// Build on all bench threads (else on one).
    pub parallel_build: bool,
    /// Children per node traversed: 2 (the binary tree), 4 or 8 (SIMD nodes).
    pub width: usize,
    /// How the renderer's streams are traced: single rays, or packets.
    pub query: Query,
    /// A rung of the build-quality ladder instead of `builder` (raylab's
    /// pipeline of that rung; Embree's build quality), or `None`: `builder`,
    /// and Embree MEDIUM.
    pub rung: Option<Quality>,
}

const fn v(
    name: &'static str,
    kind: BackendKind,
    builder: BuilderKind,
    schedule: Schedule,
    parallel_build: bool,
) -> Variant {
    Variant {
        name,
        kind,
        builder,
        schedule,
        parallel_build,
        width: 2,
        query: Query::Single,
        rung: None,
    }
}

const fn wide(v: Variant, width: usize) -> Variant {
    Variant { width, ..v }
}

/// The variant tracing its streams in packets of 8 rays (raylab's own 8-ray
/// packets for the 8-wide tree, rtcIntersect8/rtcOccluded8 for Embree).
const fn packets(v: Variant) -> Variant {
    Variant {
        query: Query::Packet(8),
        ..v
    }
}

/// The variant tracing its streams in packets of 16 rays (raylab's own, in
/// AVX-512 lanes where the CPU has AVX-512F; rtcIntersect16/rtcOccluded16
/// for Embree).
const fn packets16(v: Variant) -> Variant {
    Variant {
        query: Query::Packet(16),
        ..v
    }
}

/// The variant built at `rung` of the quality ladder.
const fn rung(v: Variant, rung: Quality) -> Variant {
    Variant {
        rung: Some(rung),
        ..v
    }
}

use crate::accel::bvh::params::Quality;
use crate::accel::library::{Library, ObvhsLayout, TinybvhLayout};
use BackendKind::{Bvh, BvhCrate, Embree, Naive, Obvhs, Tinybvh};
use BuilderKind::{Median, Sah};
use Schedule::{Rayon, Rows, Serial, Tiles};

/// Every variant, in the order tables list them. `naive-serial` is the baseline.
pub const VARIANTS: [Variant; 37] = [
    v("naive-serial", Naive, Sah, Serial, false),
    v("naive-rows", Naive, Sah, Rows, false),
    v("naive-tiles", Naive, Sah, Tiles, false),
    v("bvh-median-serial", Bvh, Median, Serial, false),
    v("bvh-median-rows", Bvh, Median, Rows, false),
    v("bvh-median-tiles", Bvh, Median, Tiles, false),
    v("bvh-median-pbuild-serial", Bvh, Median, Serial, true),
    v("bvh-median-pbuild-rows", Bvh, Median, Rows, true),
    v("bvh-median-pbuild-tiles", Bvh, Median, Tiles, true),
    v("bvh-sah-serial", Bvh, Sah, Serial, false),
    v("bvh-sah-tiles", Bvh, Sah, Tiles, true),
    v("bvh-sah-rayon", Bvh, Sah, Rayon, true),
    wide(v("bvh4-sah-serial", Bvh, Sah, Serial, false), 4),
    wide(v("bvh4-sah-tiles", Bvh, Sah, Tiles, true), 4),
    wide(v("bvh4-sah-rayon", Bvh, Sah, Rayon, true), 4),
    wide(v("bvh8-sah-serial", Bvh, Sah, Serial, false), 8),
    wide(v("bvh8-sah-tiles", Bvh, Sah, Tiles, true), 8),
    wide(v("bvh8-sah-rayon", Bvh, Sah, Rayon, true), 8),
    packets(wide(
        v("bvh8-sah-packet8-serial", Bvh, Sah, Serial, false),
        8,
    )),
    packets(wide(v("bvh8-sah-packet8-tiles", Bvh, Sah, Tiles, true), 8)),
    packets16(wide(v("bvh8-sah-packet16-tiles", Bvh, Sah, Tiles, true), 8)),
    rung(
        packets(wide(
            v("bvh8-lbvh-packet8-serial", Bvh, Sah, Serial, false),
            8,
        )),
        Quality::Low,
    ),
    rung(
        packets(wide(
            v("bvh8-sbvh-opt-packet8-serial", Bvh, Sah, Serial, false),
            8,
        )),
        Quality::High,
    ),
    v("embree-serial", Embree, Sah, Serial, false),
    v("embree-tiles", Embree, Sah, Tiles, true),
    v("embree-rayon", Embree, Sah, Rayon, true),
    packets(v("embree-packet8-serial", Embree, Sah, Serial, false)),
    packets(v("embree-packet8-tiles", Embree, Sah, Tiles, true)),
    packets16(v("embree-packet16-tiles", Embree, Sah, Tiles, true)),
    rung(
        packets(v("embree-low-packet8-serial", Embree, Sah, Serial, false)),
        Quality::Low,
    ),
    rung(
        packets(v("embree-high-packet8-serial", Embree, Sah, Serial, false)),
        Quality::High,
    ),
    // The other libraries, each with its own builder and kernels, one ray at
    // a time (they have no packet path). `width` picks the layout: tinybvh's
    // BVH8_CPU (8) or binary tree (2), obvhs's CwBvh (8) or Bvh2 (2).
    wide(v("tinybvh-serial", Tinybvh, Sah, Serial, false), 8),
    rung(
        wide(v("tinybvh-hq-serial", Tinybvh, Sah, Serial, false), 8),
        Quality::High,
    ),
    v("tinybvh-bvh-serial", Tinybvh, Sah, Serial, false),
    wide(v("obvhs-serial", Obvhs, Sah, Serial, false), 8),
    v("obvhs-bvh2-serial", Obvhs, Sah, Serial, false),
    v("bvh-crate-serial", BvhCrate, Sah, Serial, false),
];

/// The study's own combinations (naive, median BVH, rows, tiles, parallel build).
pub const PAPER: [&str; 9] = [
    "naive-serial",
    "naive-rows",
    "naive-tiles",
    "bvh-median-serial",
    "bvh-median-rows",
    "bvh-median-tiles",
    "bvh-median-pbuild-serial",
    "bvh-median-pbuild-rows",
    "bvh-median-pbuild-tiles",
];

/// The name speedups are relative to.
pub const BASELINE: &str = "naive-serial";

impl Variant {
    /// The variant called `name`.
    pub fn named(name: &str) -> Option<Variant> {
        VARIANTS.iter().copied().find(|v| v.name == name)
    }

    pub fn build_threads(&self, threads: usize) -> usize {
        if self.parallel_build {
            threads
        } else {
            1
        }
    }

    /// How to build this variant's backend with `threads` bench threads.
    pub fn spec(&self, threads: usize) -> BackendSpec {
        let threads = self.build_threads(threads);
        let spec = match self.kind {
            Naive => BackendSpec::naive(),
            Bvh => BackendSpec::bvh(
                self.rung
                    .map_or(
                        BuildParams::for_builder(self.builder),
                        BuildParams::for_quality,
                    )
                    .with_threads(threads)
                    .with_width(self.width),
            ),
            Embree => BackendSpec::embree_at(self.rung.unwrap_or(Quality::Medium), threads),
            Tinybvh | Obvhs | BvhCrate => BackendSpec::library(self.library(), threads),
        };
        // Every variant's query path is one its backend has (a test checks).
        spec.with_query(self.query).unwrap_or(spec)
    }

    /// The library and layout of a `tinybvh`, `obvhs` or `bvh-crate` variant.
    fn library(&self) -> Library {
        match self.kind {
            Tinybvh => Library::Tinybvh {
                layout: if self.width == 8 {
                    TinybvhLayout::Bvh8
                } else {
                    TinybvhLayout::Bvh
                },
                hq: self.rung == Some(Quality::High),
            },
            Obvhs => Library::Obvhs {
                layout: if self.width == 8 {
                    ObvhsLayout::CwBvh
                } else {
                    ObvhsLayout::Bvh2
                },
                quality: self.rung.unwrap_or(Quality::Medium),
            },
            _ => Library::BvhCrate,
        }
    }

    /// Whether this raylab was built with the variant's backend.
    pub fn available(&self) -> bool {
        match self.kind {
            Embree => crate::accel::embree::AVAILABLE,
            Tinybvh | Obvhs | BvhCrate => self.library().available(),
            Naive | Bvh => true,
        }
    }

    /// A one-line description for reports.
    pub fn describe(&self) -> String {
        let builder = match self.rung {
            Some(Quality::Low) => "LBVH (--quality low)",
            Some(Quality::High) => "SBVH with reinsertion (--quality high)",
            _ => self.builder.name(),
        };
        let embree = self.rung.map_or("MEDIUM", |q| match q {
            Quality::Low => "LOW",
            Quality::Medium => "MEDIUM",
            Quality::High => "HIGH",
        });
        let backend = match self.kind {
            Naive => "all triangles per ray".to_string(),
            Bvh if self.width > 2 => {
                format!("{builder} BVH with {}-wide SIMD nodes", self.width)
            }
            Bvh => format!("{builder} BVH"),
            Embree => match self.query {
                Query::Packet(n) => format!("Embree {embree}, rtcIntersect{n}/rtcOccluded{n}"),
                _ => format!("Embree {embree}, rtcIntersect1/rtcOccluded1"),
            },
            Tinybvh => format!(
                "tinybvh {} ({}), its own kernels",
                if self.rung == Some(Quality::High) {
                    "BuildHQ"
                } else {
                    "Build"
                },
                if self.width == 8 {
                    "BVH8_CPU"
                } else {
                    "binary BVH"
                }
            ),
            Obvhs => format!(
                "obvhs PLOC medium_build, {}",
                if self.width == 8 { "CwBvh" } else { "Bvh2" }
            ),
            BvhCrate => "bvh crate SAH, closest hit by its nearest-first iterator".into(),
        };
        let backend = match (self.kind, self.query) {
            (Bvh, Query::Packet(n)) => format!("{backend}, {n}-ray packets"),
            _ => backend,
        };
        let build = match (self.kind, self.parallel_build) {
            (Naive, _) => String::new(),
            (_, true) => ", parallel build".into(),
            (_, false) => ", serial build".into(),
        };
        format!("{backend}{build}, {} schedule", self.schedule.name())
    }
}

/// Parses `--variants`: `all`, `paper`, or a comma-separated list of names (the
/// two sets may appear in the list too). Embree variants are left out of `all`
/// in builds without Embree, and are an error when named.
pub fn parse_variants(list: &str) -> Result<Vec<Variant>> {
    let mut out: Vec<Variant> = Vec::new();
    let mut push = |v: Variant| {
        if !out.contains(&v) {
            out.push(v);
        }
    };
    for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        match item {
            "all" => VARIANTS
                .iter()
                .filter(|v| v.available())
                .for_each(|v| push(*v)),
            "paper" => PAPER
                .iter()
                .filter_map(|n| Variant::named(n))
                .for_each(&mut push),
            name => {
                let v = Variant::named(name).ok_or_else(|| {
                    let names: Vec<&str> = VARIANTS.iter().map(|v| v.name).collect();
                    Error::usage(
                        "--variants",
                        format!(
                            "unknown variant '{name}' (known: all, paper, {})",
                            names.join(", ")
                        ),
                    )
                })?;
                if !v.available() {
                    return Err(match v.kind {
                        Embree => crate::accel::embree::unavailable(),
                        _ => crate::accel::library::unavailable(&v.library()),
                    });
                }
                push(v);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--variants", "no variant given"));
    }
    // The baseline first, so a table's first column is what the others divide.
    out.sort_by_key(|v| VARIANTS.iter().position(|w| w == v));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_parse() {
        for (i, a) in VARIANTS.iter().enumerate() {
            assert!(VARIANTS[i + 1..].iter().all(|b| b.name != a.name));
        }
        let paper = parse_variants("paper").unwrap();
        assert_eq!(paper.len(), PAPER.len());
        assert_eq!(paper[0].name, BASELINE);
        let some = parse_variants("bvh-sah-tiles, naive-serial,bvh-sah-tiles").unwrap();
        assert_eq!(
            some.iter().map(|v| v.name).collect::<Vec<_>>(),
            ["naive-serial", "bvh-sah-tiles"]
        );
        let err = parse_variants("naive-serial,bogus")
            .unwrap_err()
            .to_string();
        assert!(err.contains("--variants") && err.contains("bogus"), "{err}");
        assert!(parse_variants(" , ").is_err());
    }

    #[test]
    fn build_threads_follow_the_variant() {
        let v = Variant::named("bvh-median-tiles").unwrap();
        assert_eq!(v.spec(8).build_threads(), 1);
        let v = Variant::named("bvh-median-pbuild-tiles").unwrap();
        let BackendSpec::Bvh { params, .. } = v.spec(8) else {
            panic!("{v:?} is a BVH")
        };
        assert_eq!(params.threads, 8);
        assert_eq!(params.builder, BuilderKind::Median);
        assert_eq!(params.max_leaf_size, 1);
        let v = Variant::named("embree-tiles").unwrap();
        assert_eq!(v.spec(8), BackendSpec::embree(8));
        // Each variant's query path is its backend's.
        for v in VARIANTS {
            assert_eq!(v.spec(2).query(), v.query, "{}", v.name);
        }
        assert_eq!(
            Variant::named("bvh8-sah-packet8-tiles")
                .unwrap()
                .spec(2)
                .name(),
            "bvh8-sah-packet8"
        );
        assert_eq!(
            Variant::named("embree-serial").unwrap().spec(8),
            BackendSpec::embree(1)
        );
        // The ladder's variants: the spec's name says the rung's pipeline.
        for (variant, spec) in [
            ("bvh8-lbvh-packet8-serial", "bvh8-lbvh-packet8"),
            ("bvh8-sbvh-opt-packet8-serial", "bvh8-sbvh-opt-packet8"),
            ("embree-low-packet8-serial", "embree-low-packet8"),
            ("embree-high-packet8-serial", "embree-high-packet8"),
        ] {
            let v = Variant::named(variant).unwrap();
            assert_eq!(v.spec(2).name(), spec);
            assert_eq!(v.spec(2).build_threads(), 1);
        }
        // The other libraries: the layout and build their names promise.
        for (variant, spec) in [
            ("tinybvh-serial", "tinybvh-bvh8"),
            ("tinybvh-hq-serial", "tinybvh-bvh8-hq"),
            ("tinybvh-bvh-serial", "tinybvh-bvh"),
            ("obvhs-serial", "obvhs-cwbvh-medium"),
            ("obvhs-bvh2-serial", "obvhs-bvh2-medium"),
            ("bvh-crate-serial", "bvh-crate"),
        ] {
            let v = Variant::named(variant).unwrap();
            assert_eq!(v.spec(2).name(), spec);
            assert_eq!(v.spec(2).build_threads(), 1);
        }
    }
}
