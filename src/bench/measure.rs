//! The bench matrix: every variant on every (scene, view, AO mode) cell, with a
//! warm-up and interleaved repetitions so that machine drift hits all variants of
//! a cell alike.
//!
//! A run is what the study timed: build the backend from the loaded scene, then
//! render; both are reported separately and summed. Slow variants are capped by a
//! time budget per cell (`--max-variant-s`): a run longer than
//! [`WARMUP_COUNTS_S`] is counted even when it is the warm-up (cold caches cost
//! milliseconds, not seconds), and no run is started that would take the
//! variant's measured time in the cell past the budget, once it has one run.

use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use super::family::Family;
use super::variants::Variant;
use crate::accel::{build_backend, BackendKind};
use crate::camera::Camera;
use crate::error::Result;
use crate::progress::{Progress, StepBar};
use crate::render::{render, srgb, AoMode, Frame, RenderSettings, RenderStats, Schedule};
use crate::scene::Scene;
use crate::table::ms;

/// A run at least this long is measured even when it is the warm-up.
pub const WARMUP_COUNTS_S: f64 = 2.0;

/// A camera position looking at a point, with the scene's AO distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub eye: Vec3,
    pub look: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov: f32,
    /// The AO ray length of the scene the view belongs to.
    pub ao_dist: f32,
    /// The scene's default framing (labelled `framed`, not by its eye).
    pub framed: bool,
}

impl View {
    /// The study's two views of the box.
    pub const PAPER: [View; 2] = [View::study(0.0), View::study(2.0)];

    /// The study's view from eye (x, 1, 3) looking at (0, 1, 0).
    const fn study(x: f32) -> View {
        View {
            eye: Vec3::new(x, 1.0, 3.0),
            look: Vec3::new(0.0, 1.0, 0.0),
            up: Vec3::Y,
            fov: 60.0,
            ao_dist: 0.2,
            framed: false,
        }
    }

    /// `(x,y,z)` of the eye, as the study's tables name views; `framed` for a
    /// scene's default framing.
    pub fn label(&self) -> String {
        if self.framed {
            return "framed".into();
        }
        let f = |x: f32| format!("{x}");
        format!("({},{},{})", f(self.eye.x), f(self.eye.y), f(self.eye.z))
    }

    pub fn settings(&self, size: (u32, u32), ao: AoMode, seed: u64) -> Result<RenderSettings> {
        let camera = Camera::new(self.eye, self.look, self.up, self.fov, size.0, size.1)?;
        let settings = RenderSettings {
            width: size.0,
            height: size.1,
            camera,
            ao,
            ao_dist: self.ao_dist,
            light_samples: 1,
            seed,
            two_sided_lights: false,
        };
        settings.validate()?;
        Ok(settings)
    }
}

/// The views of `raylab bench`: what `--views`, `--eye`, `--look`, `--up` and
/// `--fov` say, made concrete per scene by [`ViewPlan::views_for`].
#[derive(Clone, Debug, PartialEq)]
pub struct ViewPlan {
    /// `--views`: eye positions, each looking at `look` (or the scene's default
    /// look-at point); `None` for the default.
    pub eyes: Option<Vec<Vec3>>,
    pub eye: Option<Vec3>,
    pub look: Option<Vec3>,
    pub up: Vec3,
    pub fov: f32,
}

impl Default for ViewPlan {
    /// The default: the study's two views of a built-in box, the framing of any
    /// other scene.
    fn default() -> Self {
        ViewPlan {
            eyes: None,
            eye: None,
            look: None,
            up: Vec3::Y,
            fov: 60.0,
        }
    }
}

impl ViewPlan {
    /// The study's two views for every scene (`--views paper`).
    pub fn paper() -> Self {
        ViewPlan {
            eyes: Some(View::PAPER.iter().map(|v| v.eye).collect()),
            look: Some(View::PAPER[0].look),
            ..ViewPlan::default()
        }
    }

    /// The concrete views of `scene` at image size `size`.
    pub fn views_for(&self, scene: &Scene, size: (u32, u32)) -> Vec<View> {
        let ao_dist = crate::render::default_ao_dist(scene);
        let view = |eye: Option<Vec3>, look: Option<Vec3>| {
            let (e, l) = crate::camera::default_view(scene, eye, look, self.up, self.fov, size);
            View {
                eye: e,
                look: l,
                up: self.up,
                fov: self.fov,
                ao_dist,
                framed: !scene.study_frame && eye.is_none() && look.is_none(),
            }
        };
        match &self.eyes {
            Some(eyes) => eyes.iter().map(|&e| view(Some(e), self.look)).collect(),
            None if self.eye.is_some() || self.look.is_some() || !scene.study_frame => {
                vec![view(self.eye, self.look)]
            }
            None => View::PAPER
                .iter()
                .map(|v| View {
                    up: self.up,
                    fov: self.fov,
                    ..*v
                })
                .collect(),
        }
    }

    /// The first view of `scene` (the one the single-view parts use).
    pub fn first_for(&self, scene: &Scene, size: (u32, u32)) -> View {
        self.views_for(scene, size)[0]
    }
}

/// Median, minimum and maximum of a set of times (ms).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Stat {
    pub n: usize,
    pub median: f64,
    pub min: f64,
    pub max: f64,
}

impl Stat {
    /// Of `xs` (the median of an even count is the mean of the middle two).
    pub fn of(xs: &[f64]) -> Stat {
        if xs.is_empty() {
            return Stat::default();
        }
        let mut v = xs.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        Stat {
            n,
            median,
            min: v[0],
            max: v[n - 1],
        }
    }

    /// `(max - min) / median`: the spread of the runs relative to the median.
    pub fn spread(&self) -> f64 {
        if self.median > 0.0 {
            (self.max - self.min) / self.median
        } else {
            0.0
        }
    }
}

/// Throughput per ray kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct KindRates {
    pub primary: f64,
    pub shadow: f64,
    pub ao: f64,
}

impl KindRates {
    /// Rays over thread time per kind of `s`, in Mrays/s.
    pub fn of(s: &RenderStats) -> KindRates {
        let rate =
            |rays: u64, t: std::time::Duration| rays as f64 / t.as_secs_f64().max(1e-12) / 1e6;
        KindRates {
            primary: rate(s.primary_rays, s.primary_time),
            shadow: rate(s.shadow_rays, s.shadow_time),
            ao: rate(s.ao_rays, s.ao_time),
        }
    }
}

/// One variant on one cell.
#[derive(Clone, Debug, Serialize)]
pub struct Measurement {
    pub scene: String,
    pub triangles: usize,
    pub view: String,
    pub ao: String,
    pub variant: String,
    pub backend: String,
    /// Whose the backend is.
    pub family: Family,
    pub schedule: String,
    pub build_threads: usize,
    pub render_threads: usize,
    pub build_ms: Stat,
    pub render_ms: Stat,
    /// Build plus render: what the study's tables report.
    pub total_ms: Stat,
    /// Whether the warm-up run was counted (it took over [`WARMUP_COUNTS_S`]).
    pub warmup_counted: bool,
    pub rays: u64,
    /// All rays over the median render time.
    pub mrays_per_s: f64,
    /// Per ray kind: rays over the thread time of that pass (shading included),
    /// summed over the measured runs: Mrays/s on one thread.
    pub thread_mrays_per_s: KindRates,
    /// FNV hash of the 8-bit image of the first run.
    pub image_hash: String,
    /// Whether every run of the variant gave the same image.
    pub deterministic: bool,
}

/// What the matrix covers.
#[derive(Clone, Debug)]
pub struct Matrix<'a> {
    pub scenes: &'a [Scene],
    pub views: &'a ViewPlan,
    pub ao_modes: &'a [AoMode],
    pub variants: &'a [Variant],
    pub size: (u32, u32),
    pub threads: usize,
    pub reps: usize,
    /// One unmeasured run per variant and cell before the measured ones.
    pub warmup: bool,
    pub max_variant_s: f64,
    pub seed: u64,
    /// The AO mode whose first-view frames are kept for the report's pictures.
    pub images_ao: Option<AoMode>,
}

/// A frame kept for the report: scene index, variant and the image.
pub struct KeptFrame {
    pub scene: usize,
    pub variant: Variant,
    pub frame: Frame,
}

impl Matrix<'_> {
    /// Expected milliseconds of one variant on one cell, all its runs, with the
    /// time cap applied: the progress bar's units.
    fn planned_ms(&self, variant: &Variant, scene: &Scene, ao: AoMode) -> u64 {
        let one = expected_ms(variant, scene, self.size, ao, self.threads);
        let runs = (self.reps + self.warmup as usize) as f64;
        let capped = (self.max_variant_s * 1e3).max(one) + one;
        (one * runs).min(capped).max(1.0) as u64
    }

    /// Expected milliseconds of the whole matrix.
    pub fn planned_units(&self) -> u64 {
        let mut total = 0;
        for scene in self.scenes {
            for &ao in self.ao_modes {
                for v in self.variants {
                    total += self.planned_ms(v, scene, ao)
                        * self.views.views_for(scene, self.size).len() as u64;
                }
            }
        }
        total
    }

    /// Whether `variant` is the one whose frames stand for its backend kind.
    fn represents(&self, variant: &Variant) -> bool {
        let first_of = |kind: BackendKind, prefer: &str| {
            self.variants
                .iter()
                .filter(|v| v.kind == kind)
                .find(|v| v.name.starts_with(prefer))
                .or_else(|| self.variants.iter().find(|v| v.kind == kind))
                .copied()
        };
        let rep = match variant.kind {
            BackendKind::Bvh => first_of(BackendKind::Bvh, "bvh-sah"),
            kind => first_of(kind, ""),
        };
        rep == Some(*variant)
    }

    /// Measures every cell. Frames of the first view at `images_ao` are kept for
    /// one variant per backend kind (naive, bvh, embree).
    pub fn run(&self, bar: &StepBar) -> Result<(Vec<Measurement>, Vec<KeptFrame>)> {
        let mut out = Vec::new();
        let mut kept = Vec::new();
        for (si, scene) in self.scenes.iter().enumerate() {
            for (vi, view) in self.views.views_for(scene, self.size).iter().enumerate() {
                for &ao in self.ao_modes {
                    let settings = view.settings(self.size, ao, self.seed)?;
                    let cell = format!("{} {} ao {ao}", scene.name, view.label());
                    let keep = vi == 0 && self.images_ao == Some(ao);
                    let results = self.cell(scene, &settings, &cell, bar)?;
                    for (variant, m, frame) in results {
                        if keep && self.represents(&variant) {
                            if let Some(frame) = frame {
                                kept.push(KeptFrame {
                                    scene: si,
                                    variant,
                                    frame,
                                });
                            }
                        }
                        out.push(Measurement {
                            view: view.label(),
                            ..m
                        });
                    }
                }
            }
        }
        Ok((out, kept))
    }

    /// All variants on one cell, interleaved.
    fn cell(
        &self,
        scene: &Scene,
        settings: &RenderSettings,
        cell: &str,
        bar: &StepBar,
    ) -> Result<Vec<(Variant, Measurement, Option<Frame>)>> {
        struct Acc {
            build: Vec<f64>,
            render: Vec<f64>,
            spent_s: f64,
            last_s: f64,
            warmup_counted: bool,
            hash: Option<String>,
            deterministic: bool,
            stats: RenderStats,
            measured: RenderStats,
            frame: Option<Frame>,
            done: bool,
        }
        let mut acc: Vec<Acc> = self
            .variants
            .iter()
            .map(|_| Acc {
                build: Vec::new(),
                render: Vec::new(),
                spent_s: 0.0,
                last_s: 0.0,
                warmup_counted: false,
                hash: None,
                deterministic: true,
                stats: RenderStats::default(),
                measured: RenderStats::default(),
                frame: None,
                done: false,
            })
            .collect();
        let planned: Vec<u64> = self
            .variants
            .iter()
            .map(|v| self.planned_ms(v, scene, settings.ao))
            .collect();
        let mut given = vec![0u64; self.variants.len()];
        for rep in (!self.warmup as usize)..=self.reps {
            for (i, (variant, a)) in self.variants.iter().zip(acc.iter_mut()).enumerate() {
                let counted = a.build.len();
                let over_budget = (counted >= 1 && a.spent_s + a.last_s > self.max_variant_s)
                    || counted >= self.reps;
                if a.done || over_budget {
                    a.done = true;
                    continue;
                }
                bar.set_message(format!(
                    "{cell}: {} {}",
                    variant.name,
                    if rep == 0 {
                        "warm-up".to_string()
                    } else {
                        format!("rep {rep}/{}", self.reps)
                    }
                ));
                let (build_ms, render_ms, frame, stats) =
                    run_once(scene, variant, settings, self.threads)?;
                let expected = expected_ms(variant, scene, self.size, settings.ao, self.threads);
                let units = (expected.max(1.0) as u64).min(planned[i] - given[i]);
                given[i] += units;
                bar.inc(units);
                let seconds = (build_ms + render_ms) / 1e3;
                a.last_s = seconds;
                let hash = srgb::image_hash(&srgb::to_srgb8(&frame));
                match &a.hash {
                    None => a.hash = Some(hash),
                    Some(h) => a.deterministic &= *h == hash,
                }
                if a.frame.is_none() {
                    a.frame = Some(frame);
                }
                a.stats = stats;
                if rep == 0 && seconds < WARMUP_COUNTS_S {
                    continue;
                }
                a.warmup_counted |= rep == 0;
                a.measured += a.stats;
                a.build.push(build_ms);
                a.render.push(render_ms);
                a.spent_s += seconds;
            }
        }
        // What the plan expected but the cap skipped.
        bar.inc(planned.iter().zip(&given).map(|(p, g)| p - g).sum());
        Ok(self
            .variants
            .iter()
            .zip(acc)
            .map(|(variant, a)| {
                let total: Vec<f64> = a.build.iter().zip(&a.render).map(|(b, r)| b + r).collect();
                let render_ms = Stat::of(&a.render);
                let rays = a.stats.total_rays();
                let m = Measurement {
                    scene: scene.name.clone(),
                    triangles: scene.triangle_count(),
                    view: String::new(),
                    ao: settings.ao.to_string(),
                    variant: variant.name.to_string(),
                    backend: variant.spec(self.threads).name(),
                    family: Family::of(&variant.spec(self.threads)),
                    schedule: variant.schedule.name().to_string(),
                    build_threads: variant.build_threads(self.threads),
                    render_threads: variant.schedule.threads_used(self.threads, settings.height),
                    build_ms: Stat::of(&a.build),
                    render_ms,
                    total_ms: Stat::of(&total),
                    warmup_counted: a.warmup_counted,
                    rays,
                    mrays_per_s: rays as f64 / (render_ms.median * 1e3).max(1e-9),
                    thread_mrays_per_s: KindRates::of(&a.measured),
                    image_hash: a.hash.unwrap_or_default(),
                    deterministic: a.deterministic,
                };
                (*variant, m, a.frame)
            })
            .collect())
    }
}

/// A rough model of one run's milliseconds, for the progress estimate only:
/// rays per pixel by AO mode times a per-ray cost (linear in triangles for
/// naive, logarithmic for the hierarchies), divided by the render threads.
pub fn expected_ms(
    variant: &Variant,
    scene: &Scene,
    size: (u32, u32),
    ao: AoMode,
    threads: usize,
) -> f64 {
    let rays_per_pixel = match ao {
        AoMode::Off => 2.0,
        AoMode::Paper => 9.0,
        AoMode::Cosine(n) => 2.0 + n as f64,
    };
    let rays = size.0 as f64 * size.1 as f64 * rays_per_pixel;
    let n = scene.triangle_count() as f64;
    let levels = n.log2().max(0.0) + 1.0;
    let ns_per_ray = match variant.kind {
        BackendKind::Naive => 2.7 * n + 50.0,
        BackendKind::Bvh
            if matches!(variant.backend, crate::accel::BackendSpec::Bvh { params, .. }
                if params.builder == crate::accel::bvh::BuilderKind::Median) =>
        {
            30.0 * levels + 50.0
        }
        BackendKind::Bvh => 12.0 * levels + 50.0,
        BackendKind::Embree => 6.0 * levels + 50.0,
        // Between the binary trees and Embree; the bvh crate's iterators
        // allocate per ray.
        BackendKind::Tinybvh | BackendKind::Obvhs => 10.0 * levels + 50.0,
        BackendKind::BvhCrate => 60.0 * levels + 200.0,
    };
    let parallel = match variant.schedule {
        crate::render::Schedule::Serial => 1.0,
        _ => threads.max(1) as f64,
    };
    rays * ns_per_ray / parallel / 1e6
}

/// One timed run: (build ms, render ms, the frame, ray statistics).
pub fn run_once(
    scene: &Scene,
    variant: &Variant,
    settings: &RenderSettings,
    threads: usize,
) -> Result<(f64, f64, Frame, RenderStats)> {
    let start = Instant::now();
    let backend = build_backend(&variant.spec(threads), scene)?;
    let build_ms = ms(start.elapsed());
    let start = Instant::now();
    let (frame, stats) = render(
        scene,
        backend.as_ref(),
        settings,
        variant.schedule,
        threads,
        &Progress::new(),
    )?;
    let render_ms = ms(start.elapsed());
    Ok((build_ms, render_ms, frame, stats))
}

/// Renders `reps` times and returns the render times and the last frame.
pub(super) fn timed_renders(
    scene: &Scene,
    backend: &dyn crate::accel::Backend,
    settings: &RenderSettings,
    schedule: Schedule,
    threads: usize,
    reps: usize,
) -> Result<(Stat, Frame)> {
    let mut times = Vec::with_capacity(reps);
    let mut frame = None;
    for _ in 0..reps.max(1) {
        let start = Instant::now();
        let (f, _) = render(
            scene,
            backend,
            settings,
            schedule,
            threads,
            &Progress::new(),
        )?;
        times.push(ms(start.elapsed()));
        frame = Some(f);
    }
    Ok((Stat::of(&times), frame.expect("at least one render")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_of_odd_even_and_empty() {
        let s = Stat::of(&[3.0, 1.0, 2.0]);
        assert_eq!((s.n, s.median, s.min, s.max), (3, 2.0, 1.0, 3.0));
        assert!((s.spread() - 1.0).abs() < 1e-12);
        assert_eq!(Stat::of(&[4.0, 1.0, 2.0, 3.0]).median, 2.5);
        assert_eq!(Stat::of(&[]).n, 0);
    }

    #[test]
    fn view_labels_are_the_studys() {
        assert_eq!(View::PAPER[0].label(), "(0,1,3)");
        assert_eq!(View::PAPER[1].label(), "(2,1,3)");
    }
}
