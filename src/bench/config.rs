//! What a bench run is asked to do: the parts (`--parts`) and the settings
//! the CLI builds from its flags, with the helpers every part uses to size
//! its work.

use std::path::PathBuf;

use super::measure::{View, ViewPlan};
use super::variants::Variant;
use crate::render::AoMode;
use crate::scene::Scene;

/// The parts of a bench run (`--parts`), in the order they run. Each part's
/// name, report title, chart and caption are here, in one place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// The study's matrix: every variant on every scene, view and AO mode.
    Tables,
    /// Query throughput per backend and ray kind on recorded rays, and builds.
    Trace,
    /// Render speedup over one thread, per schedule.
    Scaling,
    /// Build time and time per ray against triangle count.
    Growth,
    /// AO error against render time.
    AoError,
    /// Tree quality against build and render time, per builder.
    Builders,
    /// Each rung of the build-quality ladder, raylab's and Embree's.
    Ladder,
    /// Every CPU BVH side by side: speed against wrong answers.
    Libraries,
    /// Rays that leak through closed meshes, per intersection method.
    Leaks,
    /// Every BVH's hits against Embree's (or naive's).
    Validate,
    /// Scenes that move: refit against rebuild, raylab's and Embree's.
    Animation,
    /// Instanced scenes: two-level trees against flattening.
    Instances,
}

impl Part {
    pub const ALL: [Part; 12] = [
        Part::Tables,
        Part::Trace,
        Part::Scaling,
        Part::Growth,
        Part::AoError,
        Part::Builders,
        Part::Ladder,
        Part::Libraries,
        Part::Leaks,
        Part::Validate,
        Part::Animation,
        Part::Instances,
    ];

    /// The name `--parts` takes.
    pub fn name(self) -> &'static str {
        match self {
            Part::Tables => "tables",
            Part::Trace => "trace",
            Part::Scaling => "scaling",
            Part::Growth => "growth",
            Part::AoError => "ao-error",
            Part::Builders => "builders",
            Part::Ladder => "ladder",
            Part::Libraries => "libraries",
            Part::Leaks => "leaks",
            Part::Validate => "validate",
            Part::Animation => "animation",
            Part::Instances => "instances",
        }
    }
}

impl std::str::FromStr for Part {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Part, String> {
        Part::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Part::ALL.iter().map(|p| p.name()).collect();
                format!("unknown part '{s}' (known: all, {})", names.join(", "))
            })
    }
}

/// Everything a bench run needs; built by the CLI from its flags.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub scenes: Vec<String>,
    pub views: ViewPlan,
    pub variants: Vec<Variant>,
    pub ao_modes: Vec<AoMode>,
    pub reps: usize,
    pub size: (u32, u32),
    pub threads: usize,
    pub quick: bool,
    pub max_variant_s: f64,
    pub parts: Vec<Part>,
    pub out: PathBuf,
    /// Write into `out` even when it holds files bench did not write.
    pub force: bool,
    pub quiet: bool,
    /// Rays from a ray file (`--rays`), traced by the `libraries` part
    /// instead of the first view's recorded rays.
    pub rays: Option<crate::measure::rayfile::RaySets>,
    /// The command line that asked for the run, as the report quotes it.
    pub command: String,
    /// The refit policy's factors for the `animation` part
    /// (`--rebuild-factor`; empty: the default, `REBUILD_FACTOR`).
    pub rebuild_factors: Vec<f32>,
    /// Where scene files' references may be read (`--allow-outside-refs`).
    pub ref_policy: crate::scene::refs::RefPolicy,
}

impl BenchConfig {
    pub(crate) fn wants(&self, part: Part) -> bool {
        self.parts.contains(&part)
    }

    /// Repetitions of the parts other than the matrix (medians of these).
    pub(crate) fn extra_reps(&self) -> usize {
        if self.quick {
            1
        } else {
            self.reps.clamp(1, 3)
        }
    }

    /// An image size `divisor` times smaller than the bench's (at least 16 x 12).
    pub(crate) fn smaller(&self, divisor: u32) -> (u32, u32) {
        (
            (self.size.0 / divisor).max(16),
            (self.size.1 / divisor).max(12),
        )
    }

    /// The first view of `scene` at `size`: the one the parts that render a
    /// single view use.
    pub(crate) fn first_view(&self, scene: &Scene, size: (u32, u32)) -> View {
        self.views.first_for(scene, size)
    }

    /// The last two of `scenes` (the largest of the defaults): what the
    /// slower parts measure.
    pub(crate) fn last_two(scenes: &[Scene]) -> &[Scene] {
        &scenes[scenes.len().saturating_sub(2)..]
    }
}
