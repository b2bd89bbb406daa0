//! The `validate` part: every hit of the median and SAH BVHs against Embree
//! (naive without Embree) on each scene's primary, shadow, AO and random rays.

use serde::Serialize;

use super::ChartSection;
use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::accel::{build_backend, BackendKind, BackendSpec};
use crate::bench::config::BenchConfig;
use crate::error::Result;
use crate::progress::StepBar;
use crate::render::{AoMode, RenderSettings};
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// No chart: the table says it all.
pub const SECTION: ChartSection = ChartSection {
    title: "Validation",
    stem: "",
    caption: "",
};

/// One scene's validation against the reference backend.
#[derive(Clone, Debug, Serialize)]
pub struct ValidationRow {
    pub scene: String,
    pub tested: String,
    pub reference: String,
    pub rays: usize,
    pub ties: usize,
    pub genuine: usize,
}

/// Progress steps: two per scene (one per builder).
pub fn steps(_cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    2 * scenes.len() as u64
}

/// Validation on each of `scenes` from its first view at a quarter size.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<ValidationRow>> {
    let count = if cfg.quick { 2_000 } else { 20_000 };
    let size = cfg.smaller(4);
    let mut out = Vec::new();
    for scene in scenes {
        let settings = cfg
            .first_view(scene, size)
            .settings(size, AoMode::Paper, 1)?;
        out.extend(validation(scene, &settings, count, cfg.threads, bar)?);
    }
    Ok(out)
}

/// Every hit of the median and SAH BVHs against Embree (naive without Embree)
/// on the primary, shadow, AO and random ray sets of `settings`, `count` rays each.
fn validation(
    scene: &Scene,
    settings: &RenderSettings,
    count: usize,
    threads: usize,
    bar: &StepBar,
) -> Result<Vec<ValidationRow>> {
    use crate::measure::validate::{compare, ray_sets, RaySet};
    let against = if crate::accel::embree::AVAILABLE {
        BackendKind::Embree
    } else {
        BackendKind::Naive
    };
    let reference = build_backend(&BackendSpec::default_for(against, threads), scene)?;
    let triangles = scene.triangle_vertices();
    // (The rays only: the origins are judged by `validate`.)
    let sets = ray_sets(
        scene,
        reference.as_ref(),
        settings,
        &RaySet::ALL,
        count,
        false,
    )?
    .0;
    let mut out = Vec::new();
    for builder in [BuilderKind::Median, BuilderKind::Sah] {
        bar.set_message(format!(
            "validate: bvh-{} on {}",
            builder.name(),
            scene.name
        ));
        let tested = build_backend(
            &BackendSpec::bvh(BuildParams::for_builder(builder).with_threads(threads)),
            scene,
        )?;
        let mut row = ValidationRow {
            scene: scene.name.clone(),
            tested: tested.name(),
            reference: reference.name(),
            rays: 0,
            ties: 0,
            genuine: 0,
        };
        for (set, rays) in &sets {
            let (r, _) = compare(
                set.name(),
                rays,
                tested.as_ref(),
                reference.as_ref(),
                &triangles,
            );
            row.rays += r.rays;
            row.ties += r.ties;
            row.genuine += r.genuine;
        }
        bar.step();
        out.push(row);
    }
    Ok(out)
}

/// The part's table.
pub fn markdown(points: &[ValidationRow]) -> String {
    let mut t = Table::new([
        ("scene", Left),
        ("tested", Left),
        ("reference", Left),
        ("rays", Right),
        ("ties", Right),
        ("genuine", Right),
    ]);
    for v in points {
        t.row([
            v.scene.clone(),
            v.tested.clone(),
            v.reference.clone(),
            v.rays.to_string(),
            v.ties.to_string(),
            v.genuine.to_string(),
        ]);
    }
    format!(
        "### Validation (primary, shadow, AO and random rays)\n\n{}\n",
        t.markdown()
    )
}
