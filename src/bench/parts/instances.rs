//! The `instances` part: instanced scenes traced with two levels (raylab's
//! two-level tree, Embree's instance geometry) against the same scenes
//! flattened into one triangle list (raylab's tree, Embree's scene), where
//! flattening fits.
//!
//! Per scene and structure: the build's time, the structure's memory (as
//! the backend counts it), Mrays/s per ray kind on the fastest query path
//! of the same recorded rays, and the answers that differ from raylab's
//! two-level tree's (the same triangle as placed, `t` within rounding);
//! where the scene is small enough for the exact reference, the differing
//! answers it judges wrong. The chart: trace time of one frame's rays, and
//! memory, against the number of instances (the `forest:N` built-ins),
//! with the crossing where two levels beat flattening, if there is one.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::libraries::{frame_ms, recorded_windows};
use super::ChartSection;
use crate::accel::{build_backend, build_scene_backend, BackendSpec, Built, Query};
use crate::bench::charts::{
    color, distinct, legend, line_with_points, log_axis, log_label, log_range, save_chart,
    DrawResult, FONT,
};
use crate::bench::config::BenchConfig;
use crate::bench::timing::{hits_or_occluded, median_mrays, min_run_s};
use crate::error::Result;
use crate::geometry::{Hit, Ray};
use crate::measure::exact::ExactReference;
use crate::progress::StepBar;
use crate::scene::load::load_scene_with;
use crate::scene::Scene;
use crate::table::{
    Align::{Left, Right},
    Table,
};

pub const SECTION: ChartSection = ChartSection {
    title: "Instanced scenes: two levels against flattening",
    stem: "instances",
    caption: "forest:N, against its number of instances (log-log): left, the time one frame's recorded rays take at the bench's size and one sample per pixel, on each structure's fastest path; right, the structure's memory. Flattened lines stop where flattening no longer fits; where a two-level line falls under its flattened one, two levels trace faster.",
};

/// The forests measured when the bench's scenes hold no instanced scene.
const DEFAULT_FORESTS: [usize; 5] = [10, 100, 1_000, 10_000, 100_000];
/// With `--quick`.
const QUICK_FORESTS: [usize; 3] = [10, 100, 1_000];

/// Placed triangles up to which a scene is also flattened and traced as one
/// list (forest:1000's 10.4 million take 2 GB and 3 s to build here);
/// `--quick` flattens up to a tenth of it.
const FLATTEN_MAX: u64 = 12_000_000;
/// Placed triangles up to which differing answers are judged by the exact
/// reference (it holds every flattened triangle in f64).
pub(crate) const EXACT_MAX: u64 = 2_000_000;

/// One structure over one instanced scene.
#[derive(Clone, Debug, Serialize)]
pub struct InstancesPoint {
    pub scene: String,
    pub instances: usize,
    pub unique_triangles: usize,
    pub placed_triangles: u64,
    /// "raylab two-level", "raylab flattened", "embree instances",
    /// "embree flattened".
    pub structure: String,
    pub embree: bool,
    pub two_level: bool,
    pub build_ms: f64,
    pub memory_bytes: Option<usize>,
    /// Mrays/s per kind (primary, shadow, AO), on the fastest path.
    pub mrays: Vec<f64>,
    pub paths: Vec<String>,
    /// Rays of one frame at the bench's size and one sample per pixel.
    pub frame_rays: f64,
    /// The ms those rays take at the measured rates.
    pub frame_trace_ms: f64,
    /// Answers that differ from raylab's two-level tree's (another
    /// triangle as placed, or a hit against a miss); for raylab's
    /// two-level tree itself, those that differ from raylab's flattened.
    pub differ: usize,
    /// Of those, the ones the exact reference judges wrong (none when the
    /// scene is too large for it).
    pub wrong: Option<usize>,
    pub checked: usize,
    pub threads: usize,
}

/// The instanced scenes among `cfg`'s, or the default forests.
fn scene_names(cfg: &BenchConfig) -> Vec<String> {
    let named: Vec<String> = cfg
        .scenes
        .iter()
        .filter(|s| load_scene_with(s, cfg.ref_policy).is_ok_and(|s| s.is_instanced()))
        .cloned()
        .collect();
    if !named.is_empty() {
        return named;
    }
    let forests: &[usize] = if cfg.quick {
        &QUICK_FORESTS
    } else {
        &DEFAULT_FORESTS
    };
    forests.iter().map(|n| format!("forest:{n}")).collect()
}

pub fn steps(cfg: &BenchConfig, _scenes: &[Scene]) -> u64 {
    scene_names(cfg).len() as u64
}

/// A hit as the flattened scene numbers it.
fn as_flat(scene: &Scene, hit: Option<Hit>, two_level: bool) -> Option<(u64, f32)> {
    hit.map(|h| {
        let index = if two_level {
            scene.flat_index(&h)
        } else {
            u64::from(h.tri)
        };
        (index, h.t)
    })
}

/// Whether two answers agree: both miss, or both hit the same triangle as
/// placed at `t` within the transform's rounding (a relative 1e-4), or (an
/// any-hit kind) both hit.
fn agree(a: Option<(u64, f32)>, b: Option<(u64, f32)>, closest: bool) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some((ia, ta)), Some((ib, tb))) => {
            !closest || (ia == ib && (ta - tb).abs() <= 1e-4 * ta.abs().max(tb.abs()).max(1e-6))
        }
        _ => false,
    }
}

/// Mrays/s per kind on the fastest of the built paths, and the path.
fn rates(
    built: &[(Query, Built)],
    rays: &[Vec<Ray>],
    threads: usize,
    reps: usize,
    min_run: f64,
) -> (Vec<f64>, Vec<String>) {
    let mut mrays = Vec::new();
    let mut names = Vec::new();
    for (k, rays) in rays.iter().enumerate() {
        if rays.is_empty() {
            mrays.push(f64::NAN);
            names.push(String::new());
            continue;
        }
        let closest = k == 0;
        let mut best = (f64::NEG_INFINITY, Query::Single);
        for (q, b) in built.iter() {
            let m = median_mrays(b.backend.as_ref(), closest, rays, threads, reps, min_run);
            if m > best.0 {
                best = (m, *q);
            }
        }
        mrays.push(best.0);
        names.push(best.1.name());
    }
    (mrays, names)
}

/// The query paths a structure is timed on: single rays, and its fastest
/// packets besides (raylab's and Embree's packets walk the instances too),
/// for Embree both coherent and incoherent.
fn queries(spec: &BackendSpec) -> Vec<Query> {
    let fastest = spec.with_fastest_query().query();
    match fastest {
        Query::Single => vec![Query::Single],
        Query::Packet(n) if spec.is_embree() => {
            vec![Query::Single, fastest, Query::IncoherentPacket(n)]
        }
        _ => vec![Query::Single, fastest],
    }
}

pub fn run(cfg: &BenchConfig, _scenes: &[Scene], bar: &StepBar) -> Result<Vec<InstancesPoint>> {
    let reps = cfg.extra_reps();
    let min_run = min_run_s(cfg);
    let per_kind = if cfg.quick { 2_000 } else { 30_000 };
    let threads = cfg.threads.max(1);
    let flatten_max = if cfg.quick {
        FLATTEN_MAX / 10
    } else {
        FLATTEN_MAX
    };
    let raylab = BackendSpec::DEFAULT.with_build_threads(threads);
    let embree = crate::accel::embree::AVAILABLE.then(|| BackendSpec::embree(threads));
    let mut out = Vec::new();
    for name in scene_names(cfg) {
        bar.set_message(format!("instances: {name}"));
        let mut scene = load_scene_with(&name, cfg.ref_policy)?;
        scene.set_extra_light(None, glam::Vec3::Y);
        let recorder = build_scene_backend(&raylab.with_query(Query::Single)?, &scene)?;
        let (rays, frame_rays) = recorded_windows(&scene, recorder.as_ref(), cfg, per_kind)?;
        let reference: Vec<Vec<Option<(u64, f32)>>> = rays
            .iter()
            .enumerate()
            .map(|(k, r)| {
                hits_or_occluded(recorder.as_ref(), k == 0, r)
                    .into_iter()
                    .map(|h| as_flat(&scene, h, true))
                    .collect()
            })
            .collect();
        drop(recorder);
        let placed = scene.placed_triangle_count();
        let flat = (placed <= flatten_max)
            .then(|| scene.flattened())
            .transpose()?;
        let mut exact = None;
        let mut structures: Vec<(&str, BackendSpec, bool)> =
            vec![("raylab two-level", raylab, true)];
        if let Some(e) = embree {
            structures.push(("embree instances", e, true));
        }
        if flat.is_some() {
            structures.push(("raylab flattened", raylab, false));
            if let Some(e) = embree {
                structures.push(("embree flattened", e, false));
            }
        }
        // Embree's first device in a process costs more than its build:
        // paid here, untimed.
        if let Some(e) = embree {
            build_scene_backend(&e.with_query(Query::Single)?, &scene)?;
        }
        let mut points: Vec<InstancesPoint> = Vec::new();
        for (label, spec, two_level) in structures {
            let mut built = Vec::new();
            for q in queries(&spec) {
                let spec = spec.with_query(q)?;
                let b = match (&flat, two_level) {
                    (Some(flat), false) => build_backend(&spec, flat)?,
                    _ => build_scene_backend(&spec, &scene)?,
                };
                built.push((q, b));
            }
            let (mrays, paths) = rates(&built, &rays, threads, reps, min_run);
            let first = &built[0].1;
            // Answers against the reference (raylab's two-level), and for
            // the reference itself against raylab's flattened tree, which
            // the loop reaches after it.
            let mut differ = 0;
            let mut wrong = 0;
            let mut judged = placed <= EXACT_MAX && flat.is_some();
            let mut checked = 0;
            for (k, (rays, want)) in rays.iter().zip(&reference).enumerate() {
                let closest = k == 0;
                let got = hits_or_occluded(first.as_ref(), closest, rays);
                checked += rays.len();
                for ((ray, g), w) in rays.iter().zip(got).zip(want) {
                    let g_flat = as_flat(&scene, g, two_level);
                    if agree(g_flat, *w, closest) {
                        continue;
                    }
                    differ += 1;
                    let Some(flat) = &flat else {
                        judged = false;
                        continue;
                    };
                    if !judged {
                        continue;
                    }
                    let reference =
                        exact.get_or_insert_with(|| ExactReference::new(flat.triangle_vertices()));
                    let answer = reference.answer(ray);
                    let judge = |h: Option<(u64, f32)>| {
                        let hit = h.map(|(i, t)| Hit {
                            t,
                            u: 0.0,
                            v: 0.0,
                            tri: i as u32,
                            inst: 0,
                        });
                        if closest {
                            answer.judge_closest(hit).is_wrong()
                        } else {
                            answer.judge_occluded(hit.is_some()).is_wrong()
                        }
                    };
                    // The structure's answer; and for the flattened raylab
                    // tree, the two-level tree's too (it has no other judge).
                    wrong += judge(g_flat) as usize;
                    if label == "raylab flattened" {
                        if let Some(p) = points
                            .iter_mut()
                            .find(|p| p.structure == "raylab two-level")
                        {
                            p.differ += 1;
                            if let Some(w2) = &mut p.wrong {
                                *w2 += judge(*w) as usize;
                            }
                        }
                    }
                }
            }
            let frame_trace_ms = frame_ms(&rays, &mrays, frame_rays);
            let two_level_reference = label == "raylab two-level";
            points.push(InstancesPoint {
                scene: name.clone(),
                instances: scene.instance_count(),
                unique_triangles: scene.triangle_count(),
                placed_triangles: placed,
                structure: label.to_string(),
                embree: spec.is_embree(),
                two_level,
                build_ms: first.build_time.as_secs_f64() * 1e3,
                memory_bytes: first.memory_bytes(),
                mrays,
                paths,
                frame_rays,
                frame_trace_ms,
                // The reference's own disagreements are counted when the
                // flattened tree is compared with it (above).
                differ: if two_level_reference { 0 } else { differ },
                wrong: if two_level_reference {
                    (placed <= EXACT_MAX && flat.is_some()).then_some(0)
                } else {
                    judged.then_some(wrong)
                },
                checked,
                threads,
            });
        }
        out.extend(points);
        bar.step();
    }
    Ok(out)
}

/// The smallest instance count from which a two-level structure traces a
/// frame faster than the same library's flattened one, on every measured
/// scene from there up to the largest flattened.
fn crossing(points: &[InstancesPoint], embree: bool) -> Option<usize> {
    let mut pairs: Vec<(usize, f64, f64)> = Vec::new();
    for p in points.iter().filter(|p| p.embree == embree && p.two_level) {
        if let Some(f) = points
            .iter()
            .find(|f| f.scene == p.scene && f.embree == embree && !f.two_level)
        {
            pairs.push((p.instances, p.frame_trace_ms, f.frame_trace_ms));
        }
    }
    pairs.sort_by_key(|p| p.0);
    let last_slower = pairs.iter().rposition(|&(_, two, flat)| two > flat);
    match last_slower {
        Some(i) => pairs.get(i + 1).map(|p| p.0),
        None => pairs.first().map(|p| p.0),
    }
}

pub fn markdown(points: &[InstancesPoint]) -> String {
    if points.is_empty() {
        return String::new();
    }
    let mut table = Table::new([
        ("scene", Left),
        ("instances", Right),
        ("placed triangles", Right),
        ("structure", Left),
        ("build ms", Right),
        ("memory MB", Right),
        ("primary Mrays/s", Right),
        ("shadow", Right),
        ("AO", Right),
        ("frame ms (1 spp)", Right),
        ("differ / wrong", Right),
    ]);
    for p in points {
        let rate = |k: usize| {
            let m = p.mrays[k];
            if m.is_finite() {
                format!("{m:.2} ({})", p.paths[k])
            } else {
                "-".into()
            }
        };
        table.row([
            p.scene.clone(),
            p.instances.to_string(),
            format!("{:.3e}", p.placed_triangles as f64),
            p.structure.clone(),
            format!("{:.1}", p.build_ms),
            p.memory_bytes
                .map_or("-".into(), |b| format!("{:.1}", b as f64 / 1e6)),
            rate(0),
            rate(1),
            rate(2),
            format!("{:.1}", p.frame_trace_ms),
            format!(
                "{} / {} of {}",
                p.differ,
                p.wrong.map_or("-".into(), |w| w.to_string()),
                p.checked
            ),
        ]);
    }
    let mut md = String::from("## Instanced scenes: two levels against flattening\n\n");
    md.push_str(&format!(
        "Each structure traces the same recorded rays ({} threads); frame ms is one frame's rays at the bench's size and one sample per pixel at the measured rates. \"differ\": answers that differ from raylab's two-level tree's (for the two-level tree, from raylab's flattened tree's); \"wrong\": those the exact reference judges wrong (\"-\": the scene is too large for it).\n\n",
        points[0].threads
    ));
    md.push_str(&table.markdown());
    for (embree, name) in [(false, "raylab"), (true, "Embree")] {
        let has_pairs = points.iter().any(|p| p.embree == embree && !p.two_level);
        if !has_pairs {
            continue;
        }
        md.push_str(&match crossing(points, embree) {
            Some(n) => format!(
                "\n{name}: two levels trace a frame at least as fast as flattening from {n} instances on, on these scenes.\n"
            ),
            None => format!(
                "\n{name}: flattening traces faster on every scene measured here that could be flattened.\n"
            ),
        });
    }
    md
}

pub fn charts(dir: &Path, points: &[InstancesPoint]) -> Result<Vec<String>> {
    let forests: Vec<&InstancesPoint> = points
        .iter()
        .filter(|p| p.scene.starts_with("forest:"))
        .collect();
    if forests.len() < 2 {
        return Ok(Vec::new());
    }
    Ok(vec![save_chart!(
        dir,
        SECTION.stem,
        (1200, 460),
        draw,
        &forests
    )?])
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, points: &[&InstancesPoint]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let halves = root.split_evenly((1, 2));
    let structures = distinct(points.iter().map(|p| p.structure.as_str()));
    let x = log_range(points.iter().map(|p| p.instances as f64));
    type Value = fn(&InstancesPoint) -> Option<f64>;
    let panels: [(&str, &str, Value); 2] = [
        ("trace ms per frame (1 spp)", "ms (log)", |p| {
            Some(p.frame_trace_ms).filter(|v| v.is_finite() && *v > 0.0)
        }),
        ("structure memory", "MB (log)", |p| {
            p.memory_bytes.map(|b| b as f64 / 1e6).filter(|v| *v > 0.0)
        }),
    ];
    for (area, (title, y_desc, value)) in halves.iter().zip(panels) {
        let y = log_range(points.iter().filter_map(|p| value(p)));
        let mut chart = ChartBuilder::on(area)
            .caption(format!("forest:N, {title}"), (FONT, 18))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(log_axis(x.clone()), log_axis(y))?;
        chart
            .configure_mesh()
            .x_desc("instances (log)")
            .y_desc(y_desc)
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        for (i, st) in structures.iter().enumerate() {
            let mut line: Vec<(f64, f64)> = points
                .iter()
                .filter(|p| p.structure == *st)
                .filter_map(|p| Some((p.instances as f64, value(p)?)))
                .collect();
            line.sort_by(|a, b| a.0.total_cmp(&b.0));
            if !line.is_empty() {
                line_with_points(&mut chart, &line, color(i), st)?;
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(scene: &str, instances: usize, two_level: bool, ms: f64) -> InstancesPoint {
        InstancesPoint {
            scene: scene.into(),
            instances,
            unique_triangles: 10,
            placed_triangles: 10 * instances as u64,
            structure: if two_level {
                "raylab two-level"
            } else {
                "raylab flattened"
            }
            .into(),
            embree: false,
            two_level,
            build_ms: 1.0,
            memory_bytes: Some(1000),
            mrays: vec![1.0; 3],
            paths: vec!["single".into(); 3],
            frame_rays: 100.0,
            frame_trace_ms: ms,
            differ: 0,
            wrong: Some(0),
            checked: 10,
            threads: 1,
        }
    }

    #[test]
    fn the_crossing_is_where_two_levels_stay_ahead() {
        let pts = [
            point("a", 10, true, 5.0),
            point("a", 10, false, 4.0),
            point("b", 100, true, 6.0),
            point("b", 100, false, 7.0),
            point("c", 1000, true, 8.0),
            point("c", 1000, false, 9.0),
        ];
        assert_eq!(crossing(&pts, false), Some(100));
        // Slower again at the largest: no crossing.
        let mut late = pts.to_vec();
        late[4].frame_trace_ms = 10.0;
        assert_eq!(crossing(&late, false), None);
        assert!(markdown(&pts).contains("from 100 instances on"));
    }

    #[test]
    fn answers_agree_on_the_placed_triangle_within_rounding() {
        assert!(agree(Some((3, 1.0)), Some((3, 1.00005)), true));
        assert!(!agree(Some((3, 1.0)), Some((4, 1.0)), true));
        assert!(!agree(Some((3, 1.0)), Some((3, 1.01)), true));
        assert!(agree(Some((3, 1.0)), Some((4, 2.0)), false));
        assert!(!agree(None, Some((4, 2.0)), false));
    }
}
