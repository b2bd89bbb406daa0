//! The `ao-error` part: the error of the study's 14 fixed AO directions and
//! of `cosine:N` sampling against a `cosine:1024` reference, against render
//! time, on the last two scenes.

use std::path::Path;

use serde::Serialize;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ChartSection;
use crate::accel::build_backend;
use crate::bench::charts::{
    color, legend, log_axis, log_label, log_range, save_chart, DrawResult, FONT,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::{timed_renders, Stat, View};
use crate::bench::metrics::{psnr, rmse};
use crate::bench::variants::Variant;
use crate::error::Result;
use crate::progress::StepBar;
use crate::render::AoMode;
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "AO error against time",
    stem: "ao-error",
    caption: "Error of the study's 14 fixed AO directions and of N random cosine samples against a cosine reference, against render time.",
};

/// One point of the AO error chart.
#[derive(Clone, Debug, Serialize)]
pub struct AoErrorPoint {
    pub scene: String,
    /// `paper` or `cosine:N`.
    pub ao: String,
    /// AO rays per shaded pixel: 14 candidate directions for `paper` (those in
    /// the hemisphere are cast), N for `cosine:N`.
    pub samples: u32,
    pub render_ms: Stat,
    /// Against the `cosine` reference, on display values in [0, 1].
    pub rmse: f64,
    pub psnr_db: f64,
}

/// The variant the AO error experiment renders with: Embree when built in.
pub fn fastest_variant() -> Variant {
    let name = if crate::accel::embree::AVAILABLE {
        "embree-tiles"
    } else {
        "bvh-sah-tiles"
    };
    Variant::named(name).expect("a known variant")
}

/// What the AO error experiment renders.
#[derive(Clone, Debug)]
pub struct AoErrorSetup {
    pub view: View,
    pub size: (u32, u32),
    /// The N of each `cosine:N` measured.
    pub samples: Vec<u32>,
    /// The N of the `cosine:N` reference.
    pub reference: u32,
}

/// Sample counts N of `cosine:N` and the reference's N.
fn samples(cfg: &BenchConfig) -> (Vec<u32>, u32) {
    if cfg.quick {
        (vec![1, 4, 16], 256)
    } else {
        ((0..=8).map(|k| 1 << k).collect(), 1024)
    }
}

/// Progress steps: per scene, the reference, `paper` and each N.
pub fn steps(cfg: &BenchConfig, scenes: &[Scene]) -> u64 {
    (BenchConfig::last_two(scenes).len() * (samples(cfg).0.len() + 2)) as u64
}

/// The AO error of the last two of `scenes`, each from its first view.
pub fn run(cfg: &BenchConfig, scenes: &[Scene], bar: &StepBar) -> Result<Vec<AoErrorPoint>> {
    let (samples, reference) = samples(cfg);
    let size = if cfg.quick { (48, 36) } else { (256, 192) };
    let mut out = Vec::new();
    for scene in BenchConfig::last_two(scenes) {
        let setup = AoErrorSetup {
            view: cfg.first_view(scene, size),
            size,
            samples: samples.clone(),
            reference,
        };
        out.extend(ao_error(scene, &setup, cfg.threads, cfg.extra_reps(), bar)?);
    }
    Ok(out)
}

/// Error of `paper` and `cosine:N` for each N against a `cosine:reference`
/// render of the same view, seed and light samples (so direct light is the
/// same in every image and only AO differs), with the render time of each.
fn ao_error(
    scene: &Scene,
    setup: &AoErrorSetup,
    threads: usize,
    reps: usize,
    bar: &StepBar,
) -> Result<Vec<AoErrorPoint>> {
    let AoErrorSetup {
        view,
        size,
        samples,
        reference,
    } = setup;
    let (size, reference) = (*size, *reference);
    let variant = fastest_variant();
    let backend = build_backend(&variant.spec(threads), scene)?;
    bar.set_message(format!(
        "AO error: cosine:{reference} reference of {}",
        scene.name
    ));
    let settings = |ao| view.settings(size, ao, 1);
    let (_, truth) = timed_renders(
        scene,
        backend.as_ref(),
        &settings(AoMode::Cosine(reference))?,
        variant.schedule,
        threads,
        1,
    )?;
    bar.step();
    let mut modes = vec![AoMode::Paper];
    modes.extend(samples.iter().map(|&n| AoMode::Cosine(n)));
    let mut out = Vec::new();
    for ao in modes {
        bar.set_message(format!("AO error: {ao} on {}", scene.name));
        let (t, frame) = timed_renders(
            scene,
            backend.as_ref(),
            &settings(ao)?,
            variant.schedule,
            threads,
            reps,
        )?;
        bar.step();
        let e = rmse(&frame, &truth)?;
        out.push(AoErrorPoint {
            scene: scene.name.clone(),
            ao: ao.to_string(),
            samples: match ao {
                AoMode::Cosine(n) => n,
                _ => 14,
            },
            render_ms: t,
            rmse: e,
            psnr_db: psnr(e),
        });
    }
    Ok(out)
}

/// The part's table.
pub fn markdown(points: &[AoErrorPoint]) -> String {
    let mut t = Table::new([
        ("scene", Left),
        ("ao", Left),
        ("AO rays/pixel", Right),
        ("render ms", Right),
        ("RMSE", Right),
        ("PSNR dB", Right),
    ]);
    for p in points {
        t.row([
            p.scene.clone(),
            p.ao.to_string(),
            p.samples.to_string(),
            format!("{:.1}", p.render_ms.median),
            format!("{:.5}", p.rmse),
            format!("{:.2}", p.psnr_db),
        ]);
    }
    format!(
        "### AO error against a cosine reference (display values)\n\n{}\n",
        t.markdown()
    )
}

/// The part's chart.
pub fn charts(dir: &Path, points: &[AoErrorPoint]) -> Result<Vec<String>> {
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (1200, 520),
        draw_ao_error,
        points
    )?])
}

fn draw_ao_error<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[AoErrorPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let mut scenes: Vec<&str> = Vec::new();
    for p in pts {
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    let areas = root.split_evenly((1, scenes.len().max(1)));
    for (area, scene) in areas.iter().zip(&scenes) {
        let here: Vec<&AoErrorPoint> = pts.iter().filter(|p| p.scene == *scene).collect();
        let x = log_range(here.iter().map(|p| p.render_ms.median));
        let y = log_range(here.iter().map(|p| p.rmse.max(1e-6)));
        let mut chart = ChartBuilder::on(area)
            .caption(format!("AO error against time, {scene}"), (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(log_axis(x), log_axis(y))?;
        chart
            .configure_mesh()
            .x_desc("render ms (log)")
            .y_desc("RMSE vs cosine reference (log)")
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        let cosine: Vec<(f64, f64, u32)> = here
            .iter()
            .filter(|p| p.ao.starts_with("cosine"))
            .map(|p| (p.render_ms.median, p.rmse.max(1e-6), p.samples))
            .collect();
        let c = color(0);
        chart
            .draw_series(LineSeries::new(
                cosine.iter().map(|(x, y, _)| (*x, *y)),
                c.stroke_width(2),
            ))?
            .label("cosine:N (random, unbiased)")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(cosine.iter().map(|(x, y, n)| {
            EmptyElement::at((*x, *y))
                + Circle::new((0, 0), 4, c.filled())
                + Text::new(format!("{n}"), (6, -14), (FONT, 12).into_font())
        }))?;
        let red = RGBAColor(200, 30, 30, 1.0);
        chart
            .draw_series(here.iter().filter(|p| p.ao == "paper").map(|p| {
                EmptyElement::at((p.render_ms.median, p.rmse.max(1e-6)))
                    + TriangleMarker::new((0, 0), 8, red.filled())
                    + Text::new(
                        format!("paper, {:.1} dB", p.psnr_db),
                        (8, 4),
                        (FONT, 12).into_font(),
                    )
            }))?
            .label("paper (14 fixed directions)")
            .legend(move |(x, y)| TriangleMarker::new((x + 8, y), 6, red.filled()));
        legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    }
    root.present()?;
    Ok(())
}
