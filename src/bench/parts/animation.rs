//! The `animation` part: scenes that move, frame by frame, each update
//! strategy of [`crate::accel::update`] (raylab's refit, rebuild per rung
//! and refit-or-rebuild policy; Embree's refit and rebuilds) updating its
//! structure to the frame and then tracing that frame's recorded rays.
//!
//! Per frame and strategy: the update's time (the build, on the first
//! frame), the SAH cost over a fresh raylab build's at the same rung, Mrays/s
//! per ray kind on the fastest query path, and the time one frame's rays
//! take at the bench's image size and one sample per pixel. Every answer is
//! checked against a fresh raylab build of the frame: raylab's strategies
//! must give the same hits bit for bit, Embree's no genuine disagreement.
//! The totals over the animation (update plus trace, at 1 and 16 samples
//! per pixel) say which strategy wins at which ray budget.

use std::path::Path;
use std::time::Instant;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::instances::EXACT_MAX;
use super::libraries::{frame_ms, recorded_windows};
use super::ChartSection;
use crate::accel::bvh::params::REBUILD_FACTOR;
use crate::accel::bvh::BuildParams;
use crate::accel::update::{fresh_cost, Follower, Strategy};
use crate::accel::{build_scene_backend, BackendSpec, Query};
use crate::bench::charts::{
    color, distinct, legend, line_with_points, log_axis, log_label, log_range, palette_entries,
    save_chart, side_legend, DrawResult, Swatch, FONT, SIDE_LEGEND,
};
use crate::bench::config::BenchConfig;
use crate::bench::measure::Stat;
use crate::bench::timing::{hits_or_occluded, median_mrays, min_run_s};
use crate::error::Result;
use crate::geometry::{Hit, Ray};
use crate::measure::exact::ExactReference;
use crate::progress::StepBar;
use crate::scene::motion::Animation;
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Scenes that move: refit against rebuild",
    stem: "animation",
    caption: "Per animated scene, per frame: left, the SAH cost of each raylab strategy's tree over a fresh build's at the same rung (a ring marks a frame the policy rebuilt on); right, update plus the frame's rays at one sample per pixel (ms, log). The second chart: total time over the animation against rays per frame (log-log), a line per strategy; where two lines cross, the cheaper update stops paying.",
};

/// The animations measured when the bench's scenes hold none (with
/// `--quick`, the second of each pair): a deforming mesh each way a refit
/// can go, and rocks whose instances move (a TLAS's refit).
pub const DEFAULT_ANIMATIONS: [(&str, &str); 3] = [
    ("cloth:20000", "cloth:2000"),
    ("explode:20000", "explode:2000"),
    ("asteroids:300", "asteroids:30"),
];

/// Samples per pixel the totals are given at.
pub const SPP: [f64; 2] = [1.0, 16.0];

/// One strategy on one frame of one animated scene.
#[derive(Clone, Debug, Serialize)]
pub struct AnimationPoint {
    pub scene: String,
    /// Triangles as placed (an instanced scene's counted per instance).
    pub triangles: usize,
    /// The instances move, not the vertices: raylab's strategies update the
    /// TLAS alone, and the SAH ratio is the TLAS's.
    pub instances_move: bool,
    pub strategy: String,
    pub embree: bool,
    pub frame: usize,
    pub time_s: f32,
    /// The update's median ms (the first frame's build on frame 0); the
    /// policy's is timed once, since its rebuild changes what it refits.
    pub update_ms: f64,
    pub rebuilt: bool,
    /// The tree's SAH cost over a fresh build's at the same rung (raylab's
    /// strategies; none for Embree's, whose tree raylab cannot read).
    pub sah_ratio: Option<f64>,
    /// Mrays/s per kind (primary, shadow, AO), on the fastest path.
    pub mrays: Vec<f64>,
    pub paths: Vec<String>,
    /// Rays of one frame at the bench's size and one sample per pixel.
    pub frame_rays: f64,
    /// The ms those rays take at the measured rates.
    pub frame_trace_ms: f64,
    /// Answers that differ from a fresh raylab build's: by a bit for
    /// raylab's strategies; for Embree's, those of them the exact reference
    /// judges wrong.
    pub wrong: usize,
    pub checked: usize,
    /// Embree's differing answers the exact reference could not judge (an
    /// instanced frame past its size).
    pub unjudged: usize,
    pub threads: usize,
}

/// The animations of `cfg`'s scenes (animated built-ins, and glTF files
/// that have animations), each with its name, or the defaults when none
/// moves. A scene file whose animations cannot be followed is an error, not
/// a scene that does not move: the part would otherwise time the defaults in
/// its place.
fn animations(cfg: &BenchConfig) -> Result<Vec<(String, Animation)>> {
    let mut named = Vec::new();
    for s in &cfg.scenes {
        if let Some(animation) = Animation::load_if_animated(s, cfg.ref_policy)? {
            named.push((s.clone(), animation));
        }
    }
    if !named.is_empty() {
        return Ok(named);
    }
    DEFAULT_ANIMATIONS
        .iter()
        .map(|(full, quick)| {
            let name = if cfg.quick { quick } else { full };
            Ok((
                name.to_string(),
                Animation::load(name, cfg.ref_policy, "SCENE")?,
            ))
        })
        .collect()
}

/// Frames per animation.
fn frames(cfg: &BenchConfig) -> usize {
    if cfg.quick {
        3
    } else {
        9
    }
}

pub fn steps(cfg: &BenchConfig, _scenes: &[Scene]) -> u64 {
    // A scene the part refuses is refused when it runs.
    (animations(cfg).map_or(1, |a| a.len()) * frames(cfg)) as u64
}

/// One frame's rays to trace: per kind (primary, shadow, AO) a window of
/// the recorded ones, a fresh build's answers to them, and how many rays a
/// whole frame at the bench's size casts.
struct FrameRays {
    rays: Vec<Vec<Ray>>,
    answers: Vec<Vec<Option<Hit>>>,
    whole: f64,
}

/// The frame's [`FrameRays`], `per_kind` of each kind at most.
fn frame_rays(frame: &Scene, cfg: &BenchConfig, per_kind: usize) -> Result<FrameRays> {
    let recorder = build_scene_backend(
        &BackendSpec::bvh(BuildParams::sah().with_width(8)).with_fastest_query(),
        frame,
    )?;
    let (rays, whole) = recorded_windows(frame, recorder.as_ref(), cfg, per_kind)?;
    // The fresh build's answers (closest hit for primary, any hit for the
    // others, as hit/miss), what every strategy is checked against.
    let fresh = rays
        .iter()
        .enumerate()
        .map(|(k, rays)| hits_or_occluded(recorder.backend.as_ref(), k == 0, rays))
        .collect();
    Ok(FrameRays {
        rays,
        answers: fresh,
        whole,
    })
}

/// What Embree's answers are judged by: the exact reference over the
/// frame's triangles as placed (built on the first answer that needs it),
/// or none for an instanced frame past [`EXACT_MAX`] placed triangles.
struct Judge<'a> {
    frame: &'a Scene,
    exact: Option<Option<ExactReference>>,
}

impl Judge<'_> {
    /// The exact reference, built on first use (`None`: too large).
    fn reference(&mut self) -> Result<Option<&ExactReference>> {
        if self.exact.is_none() {
            let frame = self.frame;
            self.exact = Some(if !frame.is_instanced() {
                Some(ExactReference::new(frame.triangle_vertices()))
            } else if frame.placed_triangle_count() <= EXACT_MAX {
                Some(ExactReference::new(frame.flattened()?.triangle_vertices()))
            } else {
                None
            });
        }
        Ok(self.exact.as_ref().and_then(|e| e.as_ref()))
    }

    /// `hit` as the exact reference numbers triangles (placed ones, for an
    /// instanced frame).
    fn numbered(&self, hit: Option<Hit>) -> Option<Hit> {
        hit.map(|h| match self.frame.is_instanced() {
            true => Hit {
                tri: self.frame.flat_index(&h) as u32,
                inst: 0,
                ..h
            },
            false => h,
        })
    }
}

/// Answers that are wrong, checked, and unjudged. For raylab's strategies,
/// every answer that differs from `want` (a fresh build's) by a bit is
/// wrong; for Embree's, an answer that differs is wrong when the exact
/// reference judges it so (not a tie at an edge or undecidable: Embree's
/// own rounding decides such rays, on every strategy alike), and unjudged
/// where the frame is too large for the reference.
fn count_wrong(
    follower: &Follower,
    rays: &[Vec<Ray>],
    want: &[Vec<Option<Hit>>],
    judge: &mut Judge,
) -> Result<(usize, usize, usize)> {
    let (mut wrong, mut checked, mut unjudged) = (0, 0, 0);
    for (k, (rays, want)) in rays.iter().zip(want).enumerate() {
        let closest = k == 0;
        let got = hits_or_occluded(follower.backend(), closest, rays);
        checked += rays.len();
        let embree = follower.strategy.is_embree();
        for ((ray, g), w) in rays.iter().zip(&got).zip(want) {
            let differs = match (g, w) {
                (Some(a), Some(b)) if closest => {
                    // Embree's own rounding moves t, u and v a little: only
                    // another triangle, or a t off by more than rounding,
                    // needs the judge.
                    if embree {
                        a.tri != b.tri
                            || a.inst != b.inst
                            || (a.t - b.t).abs() > 1e-4 * a.t.abs().max(b.t.abs()).max(1e-6)
                    } else {
                        a != b
                    }
                }
                (a, b) => a.is_some() != b.is_some(),
            };
            if !differs {
                continue;
            }
            if !embree {
                wrong += 1;
                continue;
            }
            let hit = judge.numbered(*g);
            let Some(reference) = judge.reference()? else {
                unjudged += 1;
                continue;
            };
            let answer = reference.answer(ray);
            let verdict = if closest {
                answer.judge_closest(hit)
            } else {
                answer.judge_occluded(hit.is_some())
            };
            wrong += verdict.is_wrong() as usize;
        }
    }
    Ok((wrong, checked, unjudged))
}

/// Mrays/s per kind on the fastest of the follower's paths, and the path.
fn time_kinds(
    follower: &mut Follower,
    rays: &[Vec<Ray>],
    threads: usize,
    reps: usize,
    min_run: f64,
) -> Result<(Vec<f64>, Vec<String>)> {
    let paths = follower.queries();
    let mut mrays = Vec::new();
    let mut names = Vec::new();
    for (k, rays) in rays.iter().enumerate() {
        if rays.is_empty() {
            // A frame with none of this kind (no light to cast shadow rays to).
            mrays.push(f64::NAN);
            names.push(String::new());
            continue;
        }
        let closest = k == 0;
        let mut best = (f64::NEG_INFINITY, Query::Single);
        for &q in &paths {
            follower.set_query(q)?;
            let m = median_mrays(follower.backend(), closest, rays, threads, reps, min_run);
            if m > best.0 {
                best = (m, q);
            }
        }
        mrays.push(best.0);
        names.push(best.1.name());
    }
    Ok((mrays, names))
}

pub fn run(cfg: &BenchConfig, _scenes: &[Scene], bar: &StepBar) -> Result<Vec<AnimationPoint>> {
    let reps = cfg.extra_reps();
    let min_run = min_run_s(cfg);
    let per_kind = if cfg.quick { 2_000 } else { 30_000 };
    let threads = cfg.threads.max(1);
    let factors = if cfg.rebuild_factors.is_empty() {
        vec![REBUILD_FACTOR]
    } else {
        cfg.rebuild_factors.clone()
    };
    let strategies = Strategy::compared(&factors);
    let mut out = Vec::new();
    for (name, animation) in animations(cfg)? {
        let n = frames(cfg);
        let times: Vec<f32> = (0..n)
            .map(|f| animation.duration * f as f32 / (n - 1) as f32)
            .collect();
        // One untimed build of each first, so that no strategy's timed
        // build pays for a process's first use of a library (Embree's first
        // device took 17 ms more).
        for s in &strategies {
            Follower::new(*s, animation.rest(), threads)?;
        }
        let mut followers: Vec<Follower> = Vec::new();
        for (f, &t) in times.iter().enumerate() {
            bar.set_message(format!("animation: {name} frame {f} of {n}"));
            let mut frame = animation.frame(t)?;
            // Shadow rays need a light: the default one where the scene has
            // no emitter (as the bench's still scenes get it).
            frame.set_extra_light(None, glam::Vec3::Y);
            let mut judge = Judge {
                frame: &frame,
                exact: None,
            };
            // Update (or, on the first frame, build) every strategy.
            let mut updates = Vec::new();
            for (i, s) in strategies.iter().enumerate() {
                let (ms, rebuilt) = if f == 0 {
                    let start = Instant::now();
                    followers.push(Follower::new(*s, &frame, threads)?);
                    (start.elapsed().as_secs_f64() * 1e3, true)
                } else {
                    let runs = if matches!(s, Strategy::Policy { .. }) {
                        1
                    } else {
                        reps.max(1)
                    };
                    let mut times = Vec::new();
                    let mut rebuilt = false;
                    for _ in 0..runs {
                        let start = Instant::now();
                        rebuilt = followers[i].update(&frame)?.rebuilt;
                        times.push(start.elapsed().as_secs_f64() * 1e3);
                    }
                    (Stat::of(&times).median, rebuilt)
                };
                updates.push((ms, rebuilt));
            }
            let FrameRays {
                rays,
                answers: want,
                whole: frame_rays,
            } = frame_rays(&frame, cfg, per_kind)?;
            // The fresh cost per rung raylab's strategies use.
            let mut fresh: Vec<(crate::accel::bvh::params::Quality, f64)> = Vec::new();
            for s in &strategies {
                if let Some(rung) = s.rung() {
                    if !fresh.iter().any(|(q, _)| *q == rung) {
                        fresh.push((rung, fresh_cost(&frame, rung, threads)?));
                    }
                }
            }
            for (follower, (update_ms, rebuilt)) in followers.iter_mut().zip(updates) {
                let sah_ratio = follower.strategy.rung().and_then(|rung| {
                    let fresh = fresh.iter().find(|(q, _)| *q == rung)?.1;
                    Some(follower.policy_cost()? / fresh)
                });
                let (mrays, paths) = time_kinds(follower, &rays, threads, reps, min_run)?;
                let (wrong, checked, unjudged) = count_wrong(follower, &rays, &want, &mut judge)?;
                // Each kind's share of a whole frame's rays, as recorded.
                let frame_trace_ms = frame_ms(&rays, &mrays, frame_rays);
                out.push(AnimationPoint {
                    scene: name.clone(),
                    triangles: frame.placed_triangle_count() as usize,
                    instances_move: animation.moves_instances(),
                    strategy: follower.strategy.name(),
                    embree: follower.strategy.is_embree(),
                    frame: f,
                    time_s: t,
                    update_ms,
                    rebuilt,
                    sah_ratio,
                    mrays,
                    paths,
                    frame_rays,
                    frame_trace_ms,
                    wrong,
                    checked,
                    unjudged,
                    threads,
                });
            }
            bar.step();
        }
    }
    Ok(out)
}

/// One strategy's sums over an animation.
#[derive(Clone, Debug)]
pub struct Totals {
    pub scene: String,
    pub strategy: String,
    /// Updates after the first frame.
    pub update_ms: f64,
    pub build_ms: f64,
    pub rebuilds: usize,
    pub max_sah_ratio: Option<f64>,
    /// Trace ms of all frames at one sample per pixel.
    pub trace_ms: f64,
    pub rays: f64,
    pub wrong: usize,
    pub checked: usize,
    pub unjudged: usize,
}

impl Totals {
    /// Update plus trace over the animation at `spp` samples per pixel
    /// (the first frame's build included).
    pub fn total_ms(&self, spp: f64) -> f64 {
        self.build_ms + self.update_ms + spp * self.trace_ms
    }
}

/// Totals per scene and strategy, in the points' order.
pub fn totals(points: &[AnimationPoint]) -> Vec<Totals> {
    let mut out: Vec<Totals> = Vec::new();
    for p in points {
        let i = match out
            .iter()
            .position(|t| t.scene == p.scene && t.strategy == p.strategy)
        {
            Some(i) => i,
            None => {
                out.push(Totals {
                    scene: p.scene.clone(),
                    strategy: p.strategy.clone(),
                    update_ms: 0.0,
                    build_ms: 0.0,
                    rebuilds: 0,
                    max_sah_ratio: None,
                    trace_ms: 0.0,
                    rays: 0.0,
                    wrong: 0,
                    checked: 0,
                    unjudged: 0,
                });
                out.len() - 1
            }
        };
        let t = &mut out[i];
        if p.frame == 0 {
            t.build_ms += p.update_ms;
        } else {
            t.update_ms += p.update_ms;
            t.rebuilds += p.rebuilt as usize;
        }
        t.max_sah_ratio = match (t.max_sah_ratio, p.sah_ratio) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        t.trace_ms += p.frame_trace_ms;
        t.rays += p.frame_rays;
        t.wrong += p.wrong;
        t.checked += p.checked;
        t.unjudged += p.unjudged;
    }
    out
}

pub fn markdown(points: &[AnimationPoint]) -> String {
    if points.is_empty() {
        return String::new();
    }
    let frames = points.iter().map(|p| p.frame).max().unwrap_or(0) + 1;
    let threads = points[0].threads;
    let mut t = Table::new([
        ("scene", Left),
        ("strategy", Left),
        ("build ms", Right),
        ("updates ms", Right),
        ("rebuilds", Right),
        ("max SAH / fresh", Right),
        ("trace ms, 1 spp", Right),
        ("total, 1 spp", Right),
        ("total, 16 spp", Right),
        ("wrong", Right),
    ]);
    for s in totals(points) {
        t.row([
            s.scene.clone(),
            s.strategy.clone(),
            format!("{:.2}", s.build_ms),
            format!("{:.2}", s.update_ms),
            s.rebuilds.to_string(),
            s.max_sah_ratio.map_or("-".into(), |r| format!("{r:.2}")),
            format!("{:.1}", s.trace_ms),
            format!("{:.1}", s.total_ms(SPP[0])),
            format!("{:.1}", s.total_ms(SPP[1])),
            if s.unjudged > 0 {
                format!("{} of {} ({} unjudged)", s.wrong, s.checked, s.unjudged)
            } else {
                format!("{} of {}", s.wrong, s.checked)
            },
        ]);
    }
    let mut f = Table::new([
        ("scene", Left),
        ("frame", Right),
        ("strategy", Left),
        ("update ms", Right),
        ("rebuilt", Left),
        ("SAH / fresh", Right),
        ("primary Mrays/s", Right),
        ("shadow", Right),
        ("AO", Right),
        ("paths", Left),
    ]);
    for p in points {
        f.row([
            p.scene.clone(),
            format!("{} ({:.2} s)", p.frame, p.time_s),
            p.strategy.clone(),
            format!("{:.3}", p.update_ms),
            if p.rebuilt { "yes" } else { "" }.into(),
            p.sah_ratio.map_or("-".into(), |r| format!("{r:.3}")),
            format!("{:.2}", p.mrays[0]),
            format!("{:.2}", p.mrays[1]),
            format!("{:.2}", p.mrays[2]),
            p.paths.join("/"),
        ]);
    }
    format!(
        "### Scenes that move: totals over {frames} frames ({threads} thread{})\n\n\
         Build: the first frame's. Updates: the {} frames after it. Trace: each frame's recorded rays (primary, shadow, AO) at the bench's image size, one sample per pixel, at each strategy's measured rates on its fastest path. Wrong: answers that differ from a fresh raylab build of the frame (by a bit, for raylab's trees; for Embree's, those of them the exact reference judges wrong).{}\n\n{}\n\
         ### Scenes that move: per frame\n\n{}\n",
        if threads == 1 { "" } else { "s" },
        frames - 1,
        if points.iter().any(|p| p.instances_move) {
            " Where the instances move (the meshes do not), raylab's strategies refit or rebuild the instances' tree (TLAS) alone, the meshes' trees built once, and SAH / fresh is the TLAS's; Embree has no refit of instances, so its refit is its top scene rebuilt on each commit as it advises for scenes that change every frame (RTC_SCENE_FLAG_DYNAMIC at low quality)."
        } else {
            ""
        },
        t.markdown(),
        f.markdown()
    )
}

pub fn charts(dir: &Path, points: &[AnimationPoint]) -> Result<Vec<String>> {
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let scenes = distinct(points.iter().map(|p| p.scene.as_str())).len() as u32;
    Ok(vec![
        // Wider by the legend strip the right-hand panels give up.
        save_chart!(
            dir,
            SECTION.stem,
            (1200 + SIDE_LEGEND, 420 * scenes),
            draw_frames,
            points
        )?,
        save_chart!(
            dir,
            "animation-totals",
            (600 * scenes.min(2), 460 * scenes.div_ceil(2)),
            draw_totals,
            points
        )?,
    ])
}

fn draw_frames<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    points: &[AnimationPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let scenes = distinct(points.iter().map(|p| p.scene.as_str()));
    let strategies = distinct(points.iter().map(|p| p.strategy.as_str()));
    let rows = root.split_evenly((scenes.len(), 2));
    for (s, scene) in scenes.iter().enumerate() {
        let pts: Vec<&AnimationPoint> = points.iter().filter(|p| p.scene == *scene).collect();
        let frames = pts.iter().map(|p| p.frame).max().unwrap_or(0) as f64;
        // SAH over fresh, raylab's strategies.
        let hi = pts
            .iter()
            .filter_map(|p| p.sah_ratio)
            .fold(1.0f64, f64::max);
        let mut chart = ChartBuilder::on(&rows[2 * s])
            .caption(
                format!("{scene}: SAH cost over a fresh build's"),
                (FONT, 18),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..frames.max(1.0), 0.9..(hi * 1.1))?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("SAH / fresh")
            .draw()?;
        for (i, st) in strategies.iter().enumerate() {
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.strategy == *st)
                .filter_map(|p| Some((p.frame as f64, p.sah_ratio?)))
                .collect();
            if line.is_empty() {
                continue;
            }
            let c = color(i);
            line_with_points(&mut chart, &line, c, st)?;
            let rebuilds: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.strategy == *st && p.rebuilt && p.frame > 0)
                .filter(|_| st.contains("policy"))
                .filter_map(|p| Some((p.frame as f64, p.sah_ratio?)))
                .collect();
            chart.draw_series(
                rebuilds
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), 9, c.stroke_width(2))),
            )?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        // Update plus trace per frame, log.
        let per = |p: &AnimationPoint| (p.update_ms + p.frame_trace_ms).max(1e-3);
        let y = log_range(pts.iter().map(|p| per(p)));
        let (width, _) = rows[2 * s + 1].dim_in_pixel();
        let (plot, side) = rows[2 * s + 1].split_horizontally(width.saturating_sub(SIDE_LEGEND));
        let mut chart = ChartBuilder::on(&plot)
            .caption(
                format!("{scene}: update + trace ms per frame (1 spp)"),
                (FONT, 18),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..frames.max(1.0), log_axis(y))?;
        chart
            .configure_mesh()
            .x_desc("frame (0: the build)")
            .y_desc("ms (log)")
            .y_label_formatter(&log_label)
            .draw()?;
        for (i, st) in strategies.iter().enumerate() {
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.strategy == *st)
                .map(|p| (p.frame as f64, per(p)))
                .collect();
            line_with_points(&mut chart, &line, color(i), st)?;
        }
        // Every strategy, Embree's too (the left panel's legend has
        // raylab's only: Embree reports no SAH cost), beside the plot, where
        // it covers no line.
        side_legend(&side, &palette_entries(&strategies), Swatch::Dot)?;
    }
    root.present()?;
    Ok(())
}

fn draw_totals<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    points: &[AnimationPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let scenes = distinct(points.iter().map(|p| p.scene.as_str()));
    let totals = totals(points);
    let strategies = distinct(totals.iter().map(|t| t.strategy.as_str()));
    let cols = scenes.len().min(2);
    let areas = root.split_evenly((scenes.len().div_ceil(2), cols));
    for (area, scene) in areas.iter().zip(&scenes) {
        let ts: Vec<&Totals> = totals.iter().filter(|t| t.scene == *scene).collect();
        let frames = points
            .iter()
            .filter(|p| p.scene == *scene)
            .map(|p| p.frame)
            .max()
            .unwrap_or(0)
            + 1;
        let per_frame = ts.first().map_or(1.0, |t| t.rays / frames as f64);
        // Rays per frame from 10^-4 of one sample per pixel (where the
        // updates weigh) to 64 samples.
        let xs: Vec<f64> = (0..=60)
            .map(|i| per_frame * 1e-4 * 640_000f64.powf(i as f64 / 60.0))
            .collect();
        let at = |t: &Totals, rays: f64| t.total_ms(rays / per_frame);
        let y = log_range(ts.iter().flat_map(|t| xs.iter().map(move |&x| at(t, x))));
        let mut chart = ChartBuilder::on(area)
            .caption(format!("{scene}: total over {frames} frames"), (FONT, 18))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(log_axis(xs[0]..xs[xs.len() - 1]), log_axis(y))?;
        chart
            .configure_mesh()
            .x_desc("rays per frame (log)")
            .y_desc("update + trace ms (log)")
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        for (i, st) in strategies.iter().enumerate() {
            let Some(t) = ts.iter().find(|t| t.strategy == *st) else {
                continue;
            };
            let c = color(i);
            chart
                .draw_series(LineSeries::new(xs.iter().map(|&x| (x, at(t, x))), c))?
                .label(*st)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], c));
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(strategy: &str, frame: usize, update_ms: f64, trace: f64) -> AnimationPoint {
        AnimationPoint {
            scene: "s".into(),
            triangles: 1,
            instances_move: false,
            strategy: strategy.into(),
            embree: false,
            frame,
            time_s: frame as f32,
            update_ms,
            rebuilt: frame == 0 || strategy == "rebuild",
            sah_ratio: Some(1.0 + frame as f64),
            mrays: vec![1.0; 3],
            paths: vec!["single".into(); 3],
            frame_rays: 100.0,
            frame_trace_ms: trace,
            wrong: 0,
            checked: 10,
            unjudged: 0,
            threads: 1,
        }
    }

    #[test]
    fn totals_split_the_build_from_the_updates_and_scale_the_trace_by_samples() {
        let pts = [
            point("refit", 0, 10.0, 5.0),
            point("refit", 1, 1.0, 7.0),
            point("refit", 2, 1.0, 9.0),
            point("rebuild", 0, 10.0, 5.0),
            point("rebuild", 1, 10.0, 5.0),
        ];
        let t = totals(&pts);
        assert_eq!(t.len(), 2);
        assert_eq!(
            (t[0].build_ms, t[0].update_ms, t[0].trace_ms),
            (10.0, 2.0, 21.0)
        );
        assert_eq!(t[0].rebuilds, 0);
        assert_eq!(t[1].rebuilds, 1);
        assert_eq!(t[0].max_sah_ratio, Some(3.0));
        assert_eq!(t[0].total_ms(16.0), 10.0 + 2.0 + 16.0 * 21.0);
        assert_eq!(t[0].rays, 300.0);
    }
}
