//! The parts of a bench run, one file each. A part's file owns what it
//! measures (its points, and the progress steps it takes), its Markdown
//! table, its chart and the chart's caption; this file lists them once, as
//! [`BenchPart`] types and the variants of [`PartReport`], and `bench::run`
//! loops over them.
//! Adding a part: a file here with `SECTION`, `steps`, `run`, `markdown` and
//! (if it draws) `charts`, a variant of [`Part`], its [`BenchPart`] type
//! below and its line in `reports!` (the tables part, the matrix, is run and
//! reported by `bench` itself).

pub(crate) mod animation;
pub(crate) mod ao_error;
pub(crate) mod builders;
pub(crate) mod cliffs;
pub(crate) mod growth;
pub(crate) mod instances;
pub(crate) mod ladder;
pub(crate) mod leaks;
pub(crate) mod libraries;
pub(crate) mod scaling;
pub(crate) mod tables;
pub(crate) mod trace;
pub(crate) mod validate;

use std::path::Path;

use serde::ser::{SerializeMap, Serializer};
use serde::Serialize;

use super::config::{BenchConfig, Part};
use crate::error::Result;
use crate::progress::StepBar;
use crate::scene::Scene;

/// A part's section of the HTML report.
#[derive(Debug)]
pub struct ChartSection {
    /// The section's title.
    pub title: &'static str,
    /// The stem of the part's chart files (empty: the part draws none).
    pub stem: &'static str,
    /// The chart's caption.
    pub caption: &'static str,
}

/// What a part of the bench is: how many progress steps it takes, how it
/// runs, its Markdown, its charts and its section of the HTML report.
pub trait BenchPart {
    /// What it measures, one per row of its table.
    type Point: Clone + std::fmt::Debug + Serialize;
    /// Which part it is.
    const PART: Part;
    /// Its section of the HTML report (title, chart stem, caption).
    const SECTION: &'static ChartSection;
    /// Progress steps it takes on `scenes`.
    fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64;
    /// Measures.
    fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<Self::Point>>;
    /// Its tables.
    fn markdown(points: &[Self::Point]) -> String;
    /// Draws its charts into `dir`; returns their PNG file names.
    fn charts(dir: &Path, points: &[Self::Point]) -> Result<Vec<String>>;
}

/// A [`BenchPart`] whose file has `SECTION`, `steps`, `run`, `markdown` and
/// `charts`.
macro_rules! plain_part {
    ($unit:ident, $variant:ident, $module:ident, $point:ty) => {
        #[doc = concat!("The `", stringify!($module), "` part.")]
        pub struct $unit;
        impl BenchPart for $unit {
            type Point = $point;
            const PART: Part = Part::$variant;
            const SECTION: &'static ChartSection = &$module::SECTION;
            fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
                $module::steps(cfg, scenes)
            }
            fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<$point>> {
                $module::run(cfg, scenes, bar)
            }
            fn markdown(points: &[$point]) -> String {
                $module::markdown(points)
            }
            fn charts(dir: &Path, points: &[$point]) -> Result<Vec<String>> {
                $module::charts(dir, points)
            }
        }
    };
}

plain_part!(TracePart, Trace, trace, trace::TracePoint);
plain_part!(ScalingPart, Scaling, scaling, scaling::ScalingPoint);
plain_part!(GrowthPart, Growth, growth, growth::GrowthPoint);
plain_part!(AoErrorPart, AoError, ao_error, ao_error::AoErrorPoint);
plain_part!(BuildersPart, Builders, builders, builders::BuilderPoint);
plain_part!(LadderPart, Ladder, ladder, ladder::LadderPoint);
plain_part!(LeaksPart, Leaks, leaks, crate::measure::stress::LeakRow);
plain_part!(
    AnimationPart,
    Animation,
    animation,
    animation::AnimationPoint
);
plain_part!(
    InstancesPart,
    Instances,
    instances,
    instances::InstancesPoint
);

/// The `libraries` part, led by the cliff table (which reads its points;
/// here, so that neither file imports the other both ways).
pub struct LibrariesPart;
impl BenchPart for LibrariesPart {
    type Point = libraries::LibraryPoint;
    const PART: Part = Part::Libraries;
    const SECTION: &'static ChartSection = &libraries::SECTION;
    fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
        libraries::steps(cfg, scenes)
    }
    fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<Self::Point>> {
        libraries::run(cfg, scenes, bar)
    }
    fn markdown(points: &[Self::Point]) -> String {
        format!(
            "{}{}",
            cliffs::markdown(points),
            libraries::markdown(points)
        )
    }
    fn charts(dir: &Path, points: &[Self::Point]) -> Result<Vec<String>> {
        libraries::charts(dir, points)
    }
}

/// The `validate` part: a table, no chart.
pub struct ValidatePart;
impl BenchPart for ValidatePart {
    type Point = validate::ValidationRow;
    const PART: Part = Part::Validate;
    const SECTION: &'static ChartSection = &validate::SECTION;
    fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
        validate::steps(cfg, scenes)
    }
    fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<Self::Point>> {
        validate::run(cfg, scenes, bar)
    }
    fn markdown(points: &[Self::Point]) -> String {
        validate::markdown(points)
    }
    fn charts(_dir: &Path, _points: &[Self::Point]) -> Result<Vec<String>> {
        Ok(Vec::new())
    }
}

/// The one list of the parts besides the tables: each variant of
/// [`PartReport`], its [`BenchPart`] type and the key of its points in
/// `bench.json`; from it, the dispatch of every part by [`Part`].
macro_rules! reports {
    ($($variant:ident($unit:ident) = $key:literal as $getter:ident),* $(,)?) => {
        /// One part's points.
        #[derive(Clone, Debug)]
        pub enum PartReport {
            $($variant(Vec<<$unit as BenchPart>::Point>)),*
        }

        impl PartReport {
            pub fn part(&self) -> Part {
                match self {
                    $(PartReport::$variant(_) => <$unit as BenchPart>::PART),*
                }
            }

            /// Whether it measured nothing (no table, no chart).
            pub fn is_empty(&self) -> bool {
                match self {
                    $(PartReport::$variant(p) => p.is_empty()),*
                }
            }

            pub fn markdown(&self) -> String {
                match self {
                    $(PartReport::$variant(p) => <$unit as BenchPart>::markdown(p)),*
                }
            }

            pub fn charts(&self, dir: &Path) -> Result<Vec<String>> {
                match self {
                    $(PartReport::$variant(p) => <$unit as BenchPart>::charts(dir, p)),*
                }
            }

            fn entry<M: SerializeMap>(&self, map: &mut M) -> std::result::Result<(), M::Error> {
                match self {
                    $(PartReport::$variant(p) => map.serialize_entry($key, p)),*
                }
            }

            fn key(&self) -> &'static str {
                match self {
                    $(PartReport::$variant(_) => $key),*
                }
            }
        }

        /// The keys of the parts' points in `bench.json`, every part's.
        const KEYS: &[&str] = &[$($key),*];

        /// `part`'s progress steps (none for the tables, which the matrix
        /// counts).
        pub fn steps(part: Part, cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
            match part {
                $(Part::$variant => <$unit as BenchPart>::steps(cfg, scenes),)*
                Part::Tables => 0,
            }
        }

        /// Runs `part` (none for the tables, which `bench` runs itself).
        pub fn run(
            part: Part,
            cfg: &BenchConfig,
            scenes: &[Scene],
            bar: &StepBar,
        ) -> Result<Option<PartReport>> {
            match part {
                $(Part::$variant => {
                    <$unit as BenchPart>::run(cfg, scenes, bar).map(|p| Some(PartReport::$variant(p)))
                })*
                Part::Tables => Ok(None),
            }
        }

        /// `part`'s section of the HTML report: its title, the stem of its
        /// chart files and the chart's caption (each kept in the part's file).
        pub fn section(part: Part) -> &'static ChartSection {
            match part {
                $(Part::$variant => <$unit as BenchPart>::SECTION,)*
                Part::Tables => &tables::SECTION,
            }
        }

        /// The points of one part, when it ran.
        impl Reports {
            $(
                #[doc = concat!("The `", $key, "` points (none when the part did not run).")]
                pub fn $getter(&self) -> &[<$unit as BenchPart>::Point] {
                    self.0
                        .iter()
                        .find_map(|r| match r {
                            PartReport::$variant(p) => Some(p.as_slice()),
                            #[allow(unreachable_patterns)]
                            _ => None,
                        })
                        .unwrap_or(&[])
                }
            )*
        }
    };
}

reports! {
    Trace(TracePart) = "trace" as trace,
    Scaling(ScalingPart) = "scaling" as scaling,
    Growth(GrowthPart) = "growth" as growth,
    AoError(AoErrorPart) = "ao_error" as ao_error,
    Builders(BuildersPart) = "builders" as builders,
    Ladder(LadderPart) = "ladder" as ladder,
    Libraries(LibrariesPart) = "libraries" as libraries,
    Leaks(LeaksPart) = "leaks" as leaks,
    Validate(ValidatePart) = "validation" as validation,
    Animation(AnimationPart) = "animation" as animation,
    Instances(InstancesPart) = "instances" as instances,
}

/// The reports of the parts that ran, in the order they ran. In
/// `bench.json` each part's points under its key (an empty list for a part
/// that did not run), as when each was a field of the report.
#[derive(Clone, Debug, Default)]
pub struct Reports(pub Vec<PartReport>);

impl Serialize for Reports {
    fn serialize<S: Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(KEYS.len()))?;
        for key in KEYS {
            match self.0.iter().find(|r| r.key() == *key) {
                Some(r) => r.entry(&mut map)?,
                None => map.serialize_entry(key, &[(); 0])?,
            }
        }
        map.end()
    }
}

/// Whether `part` draws a chart (and so needs the chart font).
pub fn draws(part: Part) -> bool {
    !section(part).stem.is_empty()
}
