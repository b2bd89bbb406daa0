//! The parts of a bench run, one file each. A part's file owns what it
//! measures (its points, and the progress steps it takes), its Markdown
//! table, its chart and the chart's caption; this file only lists them.
//! Adding a part: a file here with `SECTION`, `steps`, `run`, `markdown` and
//! (if it draws) `charts`, a variant of [`Part`] and its line in [`section`],
//! a field of the report, and its calls in `bench::run`, `bench::markdown` and
//! `bench::write_charts`.

pub mod ao_error;
pub mod builders;
pub mod cliffs;
pub mod growth;
pub mod ladder;
pub mod leaks;
pub mod libraries;
pub mod scaling;
pub mod tables;
pub mod trace;
pub mod validate;

use super::config::Part;

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

/// `part`'s section of the HTML report: its title, the stem of its chart
/// files and the chart's caption (each kept in the part's file).
pub fn section(part: Part) -> &'static ChartSection {
    match part {
        Part::Tables => &tables::SECTION,
        Part::Trace => &trace::SECTION,
        Part::Scaling => &scaling::SECTION,
        Part::Growth => &growth::SECTION,
        Part::AoError => &ao_error::SECTION,
        Part::Builders => &builders::SECTION,
        Part::Ladder => &ladder::SECTION,
        Part::Libraries => &libraries::SECTION,
        Part::Leaks => &leaks::SECTION,
        Part::Validate => &validate::SECTION,
    }
}

/// Whether `part` draws a chart (and so needs the chart font).
pub fn draws(part: Part) -> bool {
    !section(part).stem.is_empty()
}
