//! The bench's variants: each a backend ([`BackendSpec`]) and a schedule,
//! named from them (`bvh8-sah-packet8-tiles`), as the study combined its
//! optimisations.
//!
//! Build threads: the study built its BVH serially and, as a separate
//! optimisation, in parallel; its median tree keeps that distinction
//! (`-pbuild` builds on all bench threads). Every other backend builds on
//! all bench threads whenever it renders in parallel, as a modern renderer
//! would.

use std::sync::LazyLock;

use crate::accel::bvh::params::Quality;
use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::accel::library::{Library, ObvhsLayout, TinybvhLayout};
use crate::accel::{BackendKind, BackendSpec, Query};
use crate::error::{Error, Result};
use crate::geometry::Intersector;
use crate::render::Schedule;

/// One column of the study's tables: a backend and a schedule. The name and
/// kind are made from them ([`Variant::new`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Variant {
    /// `<backend>[-pbuild]-<schedule>`: the backend's
    /// [`BackendSpec::short_name`], `-pbuild` where it builds in parallel
    /// though that is not the default, and the schedule.
    pub name: &'static str,
    /// The backend's kind.
    pub kind: BackendKind,
    /// The backend, built on one thread ([`Variant::spec`] gives it the
    /// bench's threads).
    pub backend: BackendSpec,
    pub schedule: Schedule,
    /// Built on all bench threads where it would build on one
    /// ([`Variant::parallel_build`]).
    pub pbuild: bool,
}

/// Every variant, in the order tables list them. `naive-serial` is the baseline.
pub static VARIANTS: LazyLock<Vec<Variant>> = LazyLock::new(|| {
    use Schedule::{Rayon, Rows, Serial, Tiles};
    let v = Variant::new;
    let median = BackendSpec::bvh(BuildParams::median());
    let sah = |width| BackendSpec::bvh(BuildParams::sah().with_width(width));
    let rung = |q| BackendSpec::bvh(BuildParams::for_quality(q).with_width(8));
    let embree = |q| BackendSpec::embree_at(q, 1);
    let packets = |spec: BackendSpec, n| spec.with_query(Query::Packet(n)).expect("its path");
    let incoherent = |spec: BackendSpec, n| {
        spec.with_query(Query::IncoherentPacket(n))
            .expect("its path")
    };
    let mut out = Vec::new();
    for schedule in [Serial, Rows, Tiles] {
        out.push(v(BackendSpec::naive(), schedule, false));
    }
    for pbuild in [false, true] {
        for schedule in [Serial, Rows, Tiles] {
            out.push(v(median, schedule, pbuild));
        }
    }
    for width in [2, 4, 8] {
        for schedule in [Serial, Tiles, Rayon] {
            out.push(v(sah(width), schedule, false));
        }
    }
    out.extend([
        v(packets(sah(8), 8), Serial, false),
        v(packets(sah(8), 8), Tiles, false),
        v(packets(sah(8), 16), Tiles, false),
        v(packets(rung(Quality::Low), 8), Serial, false),
        v(packets(rung(Quality::High), 8), Serial, false),
    ]);
    for schedule in [Serial, Tiles, Rayon] {
        out.push(v(embree(Quality::Medium), schedule, false));
    }
    out.extend([
        v(packets(embree(Quality::Medium), 8), Serial, false),
        v(packets(embree(Quality::Medium), 8), Tiles, false),
        v(packets(embree(Quality::Medium), 16), Tiles, false),
        // Marked incoherent: Embree 3's faster packets on some ray kinds.
        v(incoherent(embree(Quality::Medium), 16), Serial, false),
        v(incoherent(embree(Quality::Medium), 16), Tiles, false),
        v(packets(embree(Quality::Low), 8), Serial, false),
        v(packets(embree(Quality::High), 8), Serial, false),
    ]);
    // The other libraries, each with its own builder and kernels, one ray at
    // a time (they have no packet path).
    for library in Library::ALL {
        out.push(v(BackendSpec::library(library, 1), Serial, false));
    }
    out
});

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
    /// `backend` (its build threads are the bench's) under `schedule`, built
    /// in parallel where that is the default or `pbuild` asks.
    pub fn new(backend: BackendSpec, schedule: Schedule, pbuild: bool) -> Variant {
        let backend = backend.with_build_threads(1);
        let builds_in_parallel = backend.with_build_threads(2).build_threads() > 1;
        let pbuild = pbuild && builds_in_parallel && !Self::parallel_by_default(&backend, schedule);
        let name = format!(
            "{}{}-{}",
            backend.short_name(),
            if pbuild { "-pbuild" } else { "" },
            schedule.name()
        );
        Variant {
            name: crate::names::intern(&name),
            kind: backend.kind(),
            backend,
            schedule,
            pbuild,
        }
    }

    /// Whether a backend builds on all bench threads without `-pbuild`:
    /// when it renders in parallel, except the study's median tree.
    fn parallel_by_default(backend: &BackendSpec, schedule: Schedule) -> bool {
        let studys_tree = matches!(backend, BackendSpec::Bvh { params, .. } if params.builder == BuilderKind::Median);
        schedule != Schedule::Serial && !studys_tree
    }

    /// Whether it builds on all bench threads (else on one).
    pub fn parallel_build(&self) -> bool {
        self.pbuild || Self::parallel_by_default(&self.backend, self.schedule)
    }

    /// The variant called `name`: `<backend>[-pbuild]-<schedule>`, the
    /// backend by any name [`crate::accel::parse_backend`] takes; the error
    /// says what is wrong with it.
    pub fn parse(name: &str) -> std::result::Result<Variant, String> {
        let (rest, schedule) = name
            .trim()
            .rsplit_once('-')
            .and_then(|(rest, s)| Some((rest, Schedule::ALL.into_iter().find(|x| x.name() == s)?)))
            .ok_or_else(|| {
                let schedules: Vec<&str> = Schedule::ALL.map(Schedule::name).to_vec();
                format!(
                    "'{name}' does not end in a schedule (-{})",
                    schedules.join(", -")
                )
            })?;
        let (rest, pbuild) = match rest.strip_suffix("-pbuild") {
            Some(rest) => (rest, true),
            None => (rest, false),
        };
        let backend = crate::accel::parse_backend(rest)?;
        Ok(Variant::new(backend, schedule, pbuild))
    }

    /// The variant called `name`, if it is one ([`Variant::parse`]).
    pub fn named(name: &str) -> Option<Variant> {
        Self::parse(name).ok()
    }

    /// The threads its build runs on with `threads` bench threads.
    pub fn build_threads(&self, threads: usize) -> usize {
        self.spec(threads).build_threads()
    }

    /// How to build this variant's backend with `threads` bench threads.
    pub fn spec(&self, threads: usize) -> BackendSpec {
        let threads = if self.parallel_build() { threads } else { 1 };
        self.backend.with_build_threads(threads)
    }

    /// Whether this raylab was built with the variant's backend.
    pub fn available(&self) -> bool {
        match self.backend {
            BackendSpec::Embree { .. } => crate::accel::embree::AVAILABLE,
            BackendSpec::Library { library, .. } => library.available(),
            _ => true,
        }
    }

    /// The error for a variant this raylab was built without.
    fn unavailable(&self) -> Error {
        match self.backend {
            BackendSpec::Library { library, .. } => crate::accel::library::unavailable(&library),
            _ => crate::accel::embree::unavailable(),
        }
    }

    /// A one-line description for reports.
    pub fn describe(&self) -> String {
        let backend = match self.backend {
            BackendSpec::Naive { .. } => "all triangles per ray".to_string(),
            BackendSpec::Bvh { params, .. } => {
                let builder = match (params.builder, params.optimize) {
                    (BuilderKind::Lbvh, _) => "LBVH (--quality low)".to_string(),
                    (BuilderKind::Sbvh, true) => "SBVH with reinsertion (--quality high)".into(),
                    (b, true) => format!("{} with reinsertion", b.name()),
                    (b, false) => b.name().to_string(),
                };
                match params.width {
                    2 => format!("{builder} BVH"),
                    w => format!("{builder} BVH with {w}-wide SIMD nodes"),
                }
            }
            BackendSpec::Embree {
                quality, robust, ..
            } => {
                let (n, hint) = match self.backend.query() {
                    Query::Packet(n) => (n.to_string(), ""),
                    Query::IncoherentPacket(n) => (n.to_string(), ", marked incoherent"),
                    Query::Stream => ("1M".into(), ""),
                    Query::Single => ("1".into(), ""),
                };
                format!(
                    "Embree {}{}, rtcIntersect{n}/rtcOccluded{n}{hint}",
                    quality.name().to_uppercase(),
                    if robust { " robust" } else { "" }
                )
            }
            BackendSpec::Library { library, .. } => match library {
                Library::Tinybvh { layout, hq } => format!(
                    "tinybvh {} ({}), its own kernels",
                    if hq { "BuildHQ" } else { "Build" },
                    match layout {
                        TinybvhLayout::Bvh8 => "BVH8_CPU",
                        TinybvhLayout::Bvh => "binary BVH",
                    }
                ),
                Library::Obvhs { layout, quality } => format!(
                    "obvhs PLOC {}, {}",
                    match quality {
                        Quality::Low => "fast_build",
                        Quality::Medium => "medium_build",
                        Quality::High => "slow_build",
                    },
                    match layout {
                        ObvhsLayout::CwBvh => "CwBvh",
                        ObvhsLayout::Bvh2 => "Bvh2",
                    }
                ),
                Library::BvhCrate => {
                    "bvh crate SAH, closest hit by its nearest-first iterator".into()
                }
            },
        };
        let backend = match self.backend {
            BackendSpec::Naive {
                intersector: Intersector::Watertight,
            }
            | BackendSpec::Bvh {
                intersector: Intersector::Watertight,
                ..
            } => format!("{backend}, watertight test"),
            _ => backend,
        };
        let backend = match (self.backend, self.backend.query()) {
            (BackendSpec::Bvh { .. }, Query::Packet(n)) => format!("{backend}, {n}-ray packets"),
            _ => backend,
        };
        let build = match (self.kind, self.parallel_build()) {
            (BackendKind::Naive, _) => String::new(),
            (_, true) => ", parallel build".into(),
            (_, false) => ", serial build".into(),
        };
        format!("{backend}{build}, {} schedule", self.schedule.name())
    }
}

/// Parses `--variants`: `all`, `paper`, or a comma-separated list of
/// variants (the two sets may appear in the list too): the names of
/// [`VARIANTS`], or any backend's name with `-pbuild` and a schedule
/// ([`Variant::parse`]). Embree variants are left out of `all` in builds
/// without Embree, and are an error when named.
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
                let v = Variant::parse(name).map_err(|e| {
                    let names: Vec<&str> = VARIANTS.iter().map(|v| v.name).collect();
                    Error::usage(
                        "--variants",
                        format!(
                            "unknown variant '{name}': {e} (variants: all, paper, {}; or any backend's name, -pbuild, and a schedule)",
                            names.join(", ")
                        ),
                    )
                })?;
                if !v.available() {
                    return Err(v.unavailable());
                }
                push(v);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--variants", "no variant given"));
    }
    // The baseline first, so a table's first column is what the others
    // divide; variants of no list keep their order after the listed ones.
    out.sort_by_key(|v| VARIANTS.iter().position(|w| w == v).unwrap_or(usize::MAX));
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
    fn names_are_made_from_backend_and_schedule_and_stay_as_they_were() {
        // bench.json and the recorded results name variants so: a change
        // here renames columns.
        let names: Vec<&str> = VARIANTS.iter().map(|v| v.name).collect();
        assert_eq!(
            names.join(" "),
            "naive-serial naive-rows naive-tiles bvh-median-serial bvh-median-rows \
             bvh-median-tiles bvh-median-pbuild-serial bvh-median-pbuild-rows \
             bvh-median-pbuild-tiles bvh-sah-serial bvh-sah-tiles bvh-sah-rayon \
             bvh4-sah-serial bvh4-sah-tiles bvh4-sah-rayon bvh8-sah-serial bvh8-sah-tiles \
             bvh8-sah-rayon bvh8-sah-packet8-serial bvh8-sah-packet8-tiles \
             bvh8-sah-packet16-tiles bvh8-lbvh-packet8-serial bvh8-sbvh-opt-packet8-serial \
             embree-serial embree-tiles embree-rayon embree-packet8-serial \
             embree-packet8-tiles embree-packet16-tiles embree-packet16-incoherent-serial \
             embree-packet16-incoherent-tiles embree-low-packet8-serial \
             embree-high-packet8-serial tinybvh-serial tinybvh-hq-serial \
             tinybvh-bvh-serial obvhs-serial obvhs-bvh2-serial bvh-crate-serial"
        );
        // Each parses back to itself, and by its backend's full name too.
        for v in VARIANTS.iter() {
            assert_eq!(Variant::parse(v.name), Ok(*v), "{}", v.name);
            let full = format!(
                "{}{}-{}",
                v.backend.name(),
                if v.pbuild { "-pbuild" } else { "" },
                v.schedule.name()
            );
            assert_eq!(Variant::parse(&full), Ok(*v), "{full}");
        }
        // Any backend and schedule make a variant; -pbuild only where it
        // changes the build.
        let v = Variant::parse("bvh8-sah-watertight-packet16-rayon").unwrap();
        assert_eq!(v.spec(4).name(), "bvh8-sah-watertight-packet16");
        assert_eq!(v.build_threads(4), 4);
        assert_eq!(
            Variant::parse("bvh-sah-pbuild-serial")
                .unwrap()
                .build_threads(4),
            4
        );
        assert_eq!(
            Variant::parse("bvh-sah-pbuild-tiles").unwrap().name,
            "bvh-sah-tiles"
        );
        assert_eq!(
            Variant::parse("naive-pbuild-rows").unwrap().name,
            "naive-rows"
        );
        assert_eq!(Variant::parse("bvh-tiles").unwrap().name, "bvh8-sah-tiles");
        for bad in [
            "bvh8-sah",
            "bvh8-sah-chaos",
            "warp-serial",
            "-serial",
            "bvh-sah-packet8-tiles",
        ] {
            let err = parse_variants(bad).unwrap_err().to_string();
            assert!(
                err.contains("--variants") && err.contains(bad) && !err.contains('\n'),
                "{err}"
            );
        }
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
        for v in VARIANTS.iter() {
            assert_eq!(v.spec(2).query(), v.backend.query(), "{}", v.name);
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
