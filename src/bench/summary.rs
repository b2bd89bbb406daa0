//! The report's answer, which it leads with: per scene and ray kind the
//! fastest backend, raylab's best path against Embree's best and the best
//! other library's (time per ray, naming the paths), the wrong answers
//! counted, and what was wrong in the run. `summary.md` is this with the
//! date, the machine and the command, for `docs/results.md`.

use serde::Serialize;

use super::family::Family;
use super::measure::Measurement;
use super::parts::animation::{self, AnimationPoint};
use super::parts::instances::InstancesPoint;
use super::parts::libraries::{LibraryPoint, KINDS};
use super::parts::trace::TracePoint;
use super::parts::validate::ValidationRow;
use super::Machine;
use crate::measure::validate::RaySet;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// One backend on one query path, and its speed on one scene and ray kind.
#[derive(Clone, Debug, Serialize)]
pub struct Entry {
    /// The backend with its query path (`bvh8-sah packet8`).
    pub backend: String,
    pub family: Family,
    pub mrays: f64,
}

/// One scene and ray kind.
#[derive(Clone, Debug, Serialize)]
pub struct SummaryRow {
    pub scene: String,
    pub kind: RaySet,
    pub fastest: Entry,
    pub raylab: Option<Entry>,
    pub embree: Option<Entry>,
    /// The fastest of the other libraries.
    pub library: Option<Entry>,
    /// raylab's best time per ray over Embree's best (above 1: raylab is slower).
    pub raylab_over_embree: Option<f64>,
    /// raylab's best time per ray over the best library's.
    pub raylab_over_library: Option<f64>,
}

/// One backend's wrong answers against the exact reference, over every scene.
#[derive(Clone, Debug, Serialize)]
pub struct WrongRow {
    pub backend: String,
    pub family: Family,
    /// The render's rays (every kind but edges), and how many were answered wrong.
    pub rays: usize,
    pub wrong: usize,
    pub undecidable: usize,
    /// Rays aimed at vertices and edges (each asked two queries).
    pub edge_rays: usize,
    pub edge_wrong: usize,
}

/// raylab's BVHs against Embree (or the naive scan), over every scene.
#[derive(Clone, Debug, Serialize)]
pub struct ValidationCount {
    pub reference: String,
    pub rays: usize,
    pub ties: usize,
    pub genuine: usize,
}

/// The report's answer.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// The part the speeds come from: `libraries` (one thread, every
    /// backend on its fastest path per kind) or `trace` (its one-thread
    /// runs); empty when neither ran.
    pub source: String,
    pub rows: Vec<SummaryRow>,
    pub wrong: Vec<WrongRow>,
    pub validation: Option<ValidationCount>,
    /// What was wrong, one sentence each (empty: nothing).
    pub problems: Vec<String>,
}

impl Summary {
    /// The summary of a run's points. The animation and instances parts
    /// add no rows (their measures are not per ray kind alone), only what
    /// was wrong in them.
    pub fn of(
        libraries: &[LibraryPoint],
        trace: &[TracePoint],
        validation: &[ValidationRow],
        measurements: &[Measurement],
        animation: &[AnimationPoint],
        instances: &[InstancesPoint],
    ) -> Summary {
        let (source, entries) = if !libraries.is_empty() {
            ("libraries", library_entries(libraries))
        } else if !trace.is_empty() {
            ("trace", trace_entries(trace))
        } else {
            ("", Vec::new())
        };
        let rows = rows(&entries);
        let wrong = wrong_rows(libraries);
        let validation = (!validation.is_empty()).then(|| ValidationCount {
            reference: validation[0].reference.clone(),
            rays: validation.iter().map(|v| v.rays).sum(),
            ties: validation.iter().map(|v| v.ties).sum(),
            genuine: validation.iter().map(|v| v.genuine).sum(),
        });
        let mut s = Summary {
            source: source.to_string(),
            rows,
            wrong,
            validation,
            problems: Vec::new(),
        };
        s.problems = problems(&s, libraries, measurements);
        s.problems.extend(animation_problems(animation));
        s.problems.extend(instances_problems(instances));
        s
    }

    /// The Summary table, the wrong answers and "What was wrong", as
    /// Markdown (`###` headings).
    pub fn markdown(&self) -> String {
        let mut out = String::from("### Summary\n\n");
        if self.rows.is_empty() {
            out.push_str("No backend was timed on recorded rays (neither the libraries nor the trace part ran); what the other parts found behind or wrong is under What was wrong.\n\n");
        } else {
            out.push_str(&match self.source.as_str() {
                "libraries" => "One thread, the same recorded rays for every backend, each on its fastest query path for the kind (the libraries part). Time: raylab's best path's time per ray over the other's best (below 1.00: raylab is faster).\n\n".to_string(),
                _ => "One thread, the same recorded rays for every backend and query path (the trace part). Time: raylab's best path's time per ray over the other's best (below 1.00: raylab is faster).\n\n".to_string(),
            });
            let mut t = Table::new([
                ("scene", Left),
                ("rays", Left),
                ("fastest", Left),
                ("Mrays/s", Right),
                ("raylab's best", Left),
                ("Mrays/s", Right),
                ("Embree's best", Left),
                ("raylab/Embree time", Right),
                ("best library", Left),
                ("raylab/library time", Right),
            ]);
            let name =
                |e: &Option<Entry>| e.as_ref().map_or("-".to_string(), |e| e.backend.clone());
            let ratio = |r: Option<f64>| r.map_or("-".to_string(), |r| format!("{r:.2}"));
            for r in &self.rows {
                t.row([
                    r.scene.clone(),
                    r.kind.name().to_string(),
                    r.fastest.backend.clone(),
                    format!("{:.1}", r.fastest.mrays),
                    name(&r.raylab),
                    r.raylab
                        .as_ref()
                        .map_or("-".to_string(), |e| format!("{:.1}", e.mrays)),
                    name(&r.embree),
                    ratio(r.raylab_over_embree),
                    name(&r.library),
                    ratio(r.raylab_over_library),
                ]);
            }
            let won = |f: &dyn Fn(&SummaryRow) -> Option<f64>| {
                let all: Vec<f64> = self.rows.iter().filter_map(f).collect();
                (all.iter().filter(|r| **r <= 1.0).count(), all.len())
            };
            let (e_won, e_all) = won(&|r| r.raylab_over_embree);
            let (l_won, l_all) = won(&|r| r.raylab_over_library);
            let raylab_first = self
                .rows
                .iter()
                .filter(|r| r.fastest.family == Family::Raylab)
                .count();
            out.push_str(&format!(
                "raylab is the fastest in {raylab_first} of {} cells; as fast as Embree or faster in {e_won} of {e_all}, as the best library in {l_won} of {l_all}.\n\n{}\n",
                self.rows.len(),
                t.markdown()
            ));
        }
        if !self.wrong.is_empty() {
            let mut t = Table::new([
                ("backend", Left),
                ("family", Left),
                ("render rays", Right),
                ("wrong", Right),
                ("undecidable", Right),
                ("edge rays", Right),
                ("wrong answers", Right),
            ]);
            for w in &self.wrong {
                t.row([
                    w.backend.clone(),
                    w.family.to_string(),
                    w.rays.to_string(),
                    w.wrong.to_string(),
                    w.undecidable.to_string(),
                    w.edge_rays.to_string(),
                    w.edge_wrong.to_string(),
                ]);
            }
            out.push_str(&format!(
                "Wrong answers against the exact reference, every scene (render rays: the query each kind asks; edge rays: aimed at vertices and edges, closest and any hit both asked):\n\n{}\n",
                t.markdown()
            ));
        }
        if let Some(v) = &self.validation {
            out.push_str(&format!(
                "Validation: raylab's BVHs against {} on {} rays: {} ties on shared edges, {} genuine disagreements.\n\n",
                v.reference, v.rays, v.ties, v.genuine
            ));
        }
        out.push_str("### What was wrong\n\n");
        if self.problems.is_empty() {
            out.push_str("Nothing: raylab was nowhere behind, no answer was wrong, every run repeated its image.\n\n");
        } else {
            for p in &self.problems {
                out.push_str(&format!("- {p}\n"));
            }
            out.push('\n');
        }
        out
    }

    /// `summary.md`: "Where things stand", dated, naming the machine and the
    /// command (and that `--quick` figures are a smoke test), then
    /// [`Summary::markdown`].
    pub fn page(&self, date: &str, machine: &Machine, command: &str, quick: bool) -> String {
        format!(
            "## Where things stand\n\n{date}, on {} ({} hardware threads{}, {} used by the bench), {}; raylab {}, its kernels {}; Embree {}.\n\nCommand: `{command}`{}\n\n{}",
            machine.cpu,
            machine.hardware_threads,
            machine
                .physical_cores
                .map_or(String::new(), |c| format!(", {c} cores")),
            machine.bench_threads,
            machine.os,
            machine.raylab_version,
            machine.simd,
            machine.embree_version,
            if quick {
                " (--quick: small images, one rep, no warm-up; the figures only show that every path runs)"
            } else {
                ""
            },
            self.markdown()
        )
    }
}

/// (scene, ray kind, entry) of every backend, path and kind of the
/// libraries part: its best path per kind, the edge rays left out.
fn library_entries(points: &[LibraryPoint]) -> Vec<(String, RaySet, Entry)> {
    let mut out = Vec::new();
    for p in points.iter().filter(|p| p.failed.is_none()) {
        for (k, kind) in KINDS.iter().enumerate() {
            if *kind == RaySet::Edges {
                continue;
            }
            let Some(&mrays) = p.mrays.get(k).filter(|m| m.is_finite()) else {
                continue;
            };
            let backend = match p.paths.get(k) {
                Some(path) if !path.is_empty() => format!("{} {path}", p.backend),
                _ => p.backend.clone(),
            };
            out.push((
                p.scene.clone(),
                *kind,
                Entry {
                    backend,
                    family: p.family,
                    mrays,
                },
            ));
        }
    }
    out
}

/// The same from the trace part's one-thread runs (every path its own entry).
fn trace_entries(points: &[TracePoint]) -> Vec<(String, RaySet, Entry)> {
    points
        .iter()
        .filter(|p| p.threads == 1 && p.mrays.median.is_finite())
        .map(|p| {
            (
                p.scene.clone(),
                p.kind,
                Entry {
                    backend: p.backend.clone(),
                    family: p.family,
                    mrays: p.mrays.median,
                },
            )
        })
        .collect()
}

fn rows(entries: &[(String, RaySet, Entry)]) -> Vec<SummaryRow> {
    let mut cells: Vec<(&str, RaySet)> = Vec::new();
    for (scene, kind, _) in entries {
        if !cells.contains(&(scene.as_str(), *kind)) {
            cells.push((scene, *kind));
        }
    }
    let mut out = Vec::new();
    for (scene, kind) in cells {
        let best = |which: &dyn Fn(Family) -> bool| {
            entries
                .iter()
                .filter(|(s, k, e)| s == scene && *k == kind && which(e.family))
                .map(|(_, _, e)| e)
                .max_by(|a, b| a.mrays.total_cmp(&b.mrays))
                .cloned()
        };
        let Some(fastest) = best(&|_| true) else {
            continue;
        };
        let raylab = best(&|f| f == Family::Raylab);
        let embree = best(&|f| f == Family::Embree);
        let library = best(&Family::is_library);
        let over = |other: &Option<Entry>| match (&raylab, other) {
            (Some(r), Some(o)) if r.mrays > 0.0 => Some(o.mrays / r.mrays),
            _ => None,
        };
        out.push(SummaryRow {
            scene: scene.to_string(),
            kind,
            raylab_over_embree: over(&embree),
            raylab_over_library: over(&library),
            fastest,
            raylab,
            embree,
            library,
        });
    }
    out
}

/// Each backend's wrong answers summed over the scenes, in the part's order.
fn wrong_rows(points: &[LibraryPoint]) -> Vec<WrongRow> {
    let mut out: Vec<WrongRow> = Vec::new();
    for p in points.iter().filter(|p| p.failed.is_none()) {
        let i = match out.iter().position(|w| w.backend == p.backend) {
            Some(i) => i,
            None => {
                out.push(WrongRow {
                    backend: p.backend.clone(),
                    family: p.family,
                    rays: 0,
                    wrong: 0,
                    undecidable: 0,
                    edge_rays: 0,
                    edge_wrong: 0,
                });
                out.len() - 1
            }
        };
        let w = &mut out[i];
        w.rays += p.rays;
        w.wrong += p.wrong;
        w.undecidable += p.undecidable;
        w.edge_rays += p.edge_rays;
        w.edge_wrong += p.edge_wrong;
    }
    out
}

/// The most cells "What was wrong" names one by one.
const MOST_NAMED: usize = 12;

/// What was wrong: where raylab is behind, wrong answers (raylab's first),
/// genuine disagreements, runs that did not repeat their image, backends
/// that could not be built.
fn problems(s: &Summary, libraries: &[LibraryPoint], measurements: &[Measurement]) -> Vec<String> {
    let mut out = Vec::new();
    let behind: Vec<String> = s
        .rows
        .iter()
        .filter_map(|r| {
            let raylab = r.raylab.as_ref()?;
            let (other, ratio) = [
                (&r.embree, r.raylab_over_embree),
                (&r.library, r.raylab_over_library),
            ]
            .into_iter()
            .filter_map(|(e, x)| Some((e.as_ref()?, x?)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
            (ratio > 1.0).then(|| {
                format!(
                    "{} {}: {} takes {ratio:.2}x the time of {}",
                    r.scene,
                    r.kind.name(),
                    raylab.backend,
                    other.backend
                )
            })
        })
        .collect();
    if !behind.is_empty() {
        let more = behind.len().saturating_sub(MOST_NAMED);
        out.push(format!(
            "raylab is behind in {} of {} cells: {}{}.",
            behind.len(),
            s.rows.len(),
            behind[..behind.len().min(MOST_NAMED)].join("; "),
            if more > 0 {
                format!("; and {more} more (the table above)")
            } else {
                String::new()
            }
        ));
    }
    let wrong = |raylab: bool| -> Vec<String> {
        s.wrong
            .iter()
            .filter(|w| (w.family == Family::Raylab) == raylab)
            .filter(|w| w.wrong > 0 || w.edge_wrong > 0)
            .map(|w| {
                format!(
                    "{} ({} of {} render rays, {} of {} answers on edge rays)",
                    w.backend,
                    w.wrong,
                    w.rays,
                    w.edge_wrong,
                    2 * w.edge_rays
                )
            })
            .collect()
    };
    let own = wrong(true);
    if !own.is_empty() {
        out.push(format!(
            "raylab answered wrong against the exact reference: {}.",
            own.join("; ")
        ));
    }
    let others = wrong(false);
    if !others.is_empty() {
        out.push(format!(
            "Other backends answered wrong against the exact reference: {}.",
            others.join("; ")
        ));
    }
    if let Some(v) = s.validation.as_ref().filter(|v| v.genuine > 0) {
        out.push(format!(
            "raylab's BVHs disagree with {} on {} of {} rays (not ties).",
            v.reference, v.genuine, v.rays
        ));
    }
    let repeated: Vec<String> = measurements
        .iter()
        .filter(|m| !m.deterministic)
        .map(|m| format!("{} on {} {} ao {}", m.variant, m.scene, m.view, m.ao))
        .collect();
    if !repeated.is_empty() {
        out.push(format!(
            "Repeated runs gave different images: {}.",
            repeated.join("; ")
        ));
    }
    for p in libraries {
        if let Some(why) = &p.failed {
            out.push(format!(
                "{} was not built on {}: {why}.",
                p.backend, p.scene
            ));
        }
    }
    out
}

/// Where the animation part found raylab behind or wrong, per scene and
/// thread count: its best strategy's update-plus-trace total against
/// Embree's best at 1 and 16 samples per pixel, its refit's update time
/// against Embree's refit, and raylab strategies whose answers differ from
/// a fresh build's.
fn animation_problems(points: &[AnimationPoint]) -> Vec<String> {
    let mut out = Vec::new();
    let mut runs: Vec<(&str, usize)> = Vec::new();
    for p in points {
        if !runs.contains(&(p.scene.as_str(), p.threads)) {
            runs.push((&p.scene, p.threads));
        }
    }
    for (scene, threads) in runs {
        let here: Vec<AnimationPoint> = points
            .iter()
            .filter(|p| p.scene == scene && p.threads == threads)
            .cloned()
            .collect();
        let embree_of = |strategy: &str| here.iter().any(|p| p.strategy == strategy && p.embree);
        let totals = animation::totals(&here);
        let (ours, theirs): (Vec<_>, Vec<_>) = totals.iter().partition(|t| !embree_of(&t.strategy));
        let at = format!(
            "{scene} ({threads} thread{})",
            if threads == 1 { "" } else { "s" }
        );
        let behind: Vec<String> = [1.0, 16.0]
            .into_iter()
            .filter_map(|spp| {
                let best = |side: &[&animation::Totals]| {
                    side.iter()
                        .min_by(|a, b| a.total_ms(spp).total_cmp(&b.total_ms(spp)))
                        .map(|t| (t.strategy.clone(), t.total_ms(spp)))
                };
                let ((r, r_ms), (e, e_ms)) = (best(&ours)?, best(&theirs)?);
                (r_ms > e_ms).then(|| {
                    format!(
                        "{:.2}x the time at {spp} spp ({r} {r_ms:.1} ms against {e} {e_ms:.1})",
                        r_ms / e_ms
                    )
                })
            })
            .collect();
        if !behind.is_empty() {
            out.push(format!(
                "{at}: update plus trace over the animation, raylab's best strategy against Embree's best: {}.",
                behind.join(", ")
            ));
        }
        let refit = |embree: bool| {
            totals
                .iter()
                .find(|t| embree_of(&t.strategy) == embree && t.strategy.ends_with("-refit"))
        };
        if let (Some(r), Some(e)) = (refit(false), refit(true)) {
            if r.update_ms > e.update_ms {
                out.push(format!(
                    "{at}: raylab's refit took {:.2}x Embree's refit time ({:.2} ms against {:.2} over the updates).",
                    r.update_ms / e.update_ms,
                    r.update_ms,
                    e.update_ms
                ));
            }
        }
        for t in ours.iter().filter(|t| t.wrong > 0) {
            out.push(format!(
                "{at}: {} answered {} of {} rays otherwise than a fresh build of the frame.",
                t.strategy, t.wrong, t.checked
            ));
        }
    }
    out
}

/// Where the instances part found raylab's two-level tree behind Embree's
/// instances (a frame's trace time, the build) or wrong.
fn instances_problems(points: &[InstancesPoint]) -> Vec<String> {
    let mut out = Vec::new();
    for ours in points.iter().filter(|p| p.two_level && !p.embree) {
        let at = format!(
            "{} ({} thread{})",
            ours.scene,
            ours.threads,
            if ours.threads == 1 { "" } else { "s" }
        );
        let theirs = points.iter().find(|p| {
            p.two_level && p.embree && p.scene == ours.scene && p.threads == ours.threads
        });
        if let Some(e) = theirs {
            if ours.frame_trace_ms > e.frame_trace_ms {
                out.push(format!(
                    "{at}: raylab's two-level tree traces a frame in {:.2}x the time of Embree's instances ({:.1} ms against {:.1}).",
                    ours.frame_trace_ms / e.frame_trace_ms,
                    ours.frame_trace_ms,
                    e.frame_trace_ms
                ));
            }
            if ours.build_ms > e.build_ms {
                out.push(format!(
                    "{at}: raylab's two-level tree builds in {:.2}x the time of Embree's instances ({:.1} ms against {:.1}).",
                    ours.build_ms / e.build_ms,
                    ours.build_ms,
                    e.build_ms
                ));
            }
        }
        if let Some(wrong) = ours.wrong.filter(|w| *w > 0) {
            out.push(format!(
                "{at}: raylab's two-level tree answered {wrong} of {} rays wrong by the exact reference.",
                ours.checked
            ));
        }
    }
    out
}

/// Today's date (UTC) as `YYYY-MM-DD`, from the system clock.
pub fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (y, m, d) = civil_from_days((secs / 86_400) as i64);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The proleptic Gregorian date of a day counted from 1970-01-01 (Howard
/// Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// A command line as typed: each argument quoted for the shell where it
/// needs to be, the program as `raylab`.
pub fn command_line(args: impl IntoIterator<Item = String>) -> String {
    let mut out = vec!["raylab".to_string()];
    for a in args.into_iter().skip(1) {
        let plain = !a.is_empty()
            && a.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_./,:=+@%".contains(c));
        out.push(if plain {
            a
        } else {
            format!("'{}'", a.replace('\'', "'\\''"))
        });
    }
    out.join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::measure::Stat;

    fn point(
        scene: &str,
        backend: &str,
        family: Family,
        mrays: [f64; 4],
        wrong: usize,
    ) -> LibraryPoint {
        LibraryPoint {
            scene: scene.into(),
            triangles: 1,
            backend: backend.into(),
            family,
            robust: backend.contains("watertight") || backend.contains("robust"),
            build_ms: Stat::of(&[1.0]),
            mrays: mrays.into_iter().chain([f64::NAN, 1.0]).collect(),
            paths: vec!["packet8".into(); KINDS.len()],
            ns_per_ray: 1.0,
            rays: 100,
            wrong,
            undecidable: 0,
            wrong_per_million: 0.0,
            edge_rays: 10,
            edge_wrong: 0,
            edge_undecidable: 0,
            edge_wrong_per_million: 0.0,
            limits: Vec::new(),
            failed: None,
        }
    }

    #[test]
    fn rows_name_the_fastest_and_raylab_s_best_against_each_reference() {
        let points = [
            point("s", "bvh8-sah", Family::Raylab, [20.0, 200.0, 10.0, 5.0], 0),
            point(
                "s",
                "embree-medium",
                Family::Embree,
                [25.0, 100.0, 20.0, 4.0],
                0,
            ),
            point(
                "s",
                "tinybvh-bvh8",
                Family::Tinybvh,
                [10.0, 300.0, 1.0, 1.0],
                3,
            ),
        ];
        let s = Summary::of(&points, &[], &[], &[], &[], &[]);
        assert_eq!(s.source, "libraries");
        assert_eq!(s.rows.len(), 4);
        let primary = &s.rows[0];
        assert_eq!(primary.kind, RaySet::Primary);
        assert_eq!(primary.fastest.backend, "embree-medium packet8");
        assert_eq!(primary.raylab.as_ref().unwrap().backend, "bvh8-sah packet8");
        assert_eq!(primary.raylab_over_embree, Some(25.0 / 20.0));
        assert_eq!(primary.raylab_over_library, Some(10.0 / 20.0));
        assert_eq!(s.rows[1].fastest.family, Family::Tinybvh);
        assert_eq!(s.rows[3].fastest.family, Family::Raylab);
        let md = s.markdown();
        assert!(md.starts_with("### Summary"), "{md}");
        assert!(md.contains("raylab is the fastest in 1 of 4 cells"), "{md}");
        assert!(md.contains("| s | primary | embree-medium packet8 | 25.0 | bvh8-sah packet8 | 20.0 | embree-medium packet8 | 1.25 |"), "{md}");
        // Behind on primary (Embree), shadow (tinybvh) and AO (Embree);
        // tinybvh's wrong answers named.
        assert!(md.contains("raylab is behind in 3 of 4 cells"), "{md}");
        assert!(
            md.contains("tinybvh-bvh8 (3 of 100 render rays, 0 of 20 answers on edge rays)"),
            "{md}"
        );
        let page = s.page(
            "2025-01-02",
            &crate::bench::Machine::detect(2),
            "raylab bench --quick",
            true,
        );
        assert!(
            page.starts_with("## Where things stand\n\n2025-01-02, on "),
            "{page}"
        );
        assert!(
            page.contains("Command: `raylab bench --quick` (--quick: small images"),
            "{page}"
        );
    }

    #[test]
    fn the_animation_and_instances_parts_report_where_raylab_is_behind() {
        let frame = |strategy: &str, embree: bool, frame: usize, update_ms: f64, trace: f64| {
            AnimationPoint {
                scene: "belt".into(),
                triangles: 1,
                instances_move: true,
                strategy: strategy.into(),
                embree,
                frame,
                time_s: frame as f32,
                update_ms,
                rebuilt: frame == 0,
                sah_ratio: None,
                mrays: vec![1.0; 3],
                paths: vec!["single".into(); 3],
                frame_rays: 100.0,
                frame_trace_ms: trace,
                wrong: usize::from(strategy == "raylab-rebuild-medium" && frame == 1),
                checked: 10,
                unjudged: 0,
                threads: 1,
            }
        };
        // raylab's best strategy is level with Embree's at 1 spp and
        // behind at 16; its refit updates faster than Embree's.
        let animation = [
            frame("raylab-refit", false, 0, 1.0, 12.0),
            frame("raylab-refit", false, 1, 0.5, 12.0),
            frame("raylab-rebuild-medium", false, 0, 1.0, 10.0),
            frame("raylab-rebuild-medium", false, 1, 2.0, 10.0),
            frame("embree-refit", true, 0, 1.0, 9.0),
            frame("embree-refit", true, 1, 4.0, 9.0),
        ];
        let instance = |structure: &str, embree: bool, build_ms: f64, trace: f64| InstancesPoint {
            scene: "forest:10".into(),
            instances: 10,
            unique_triangles: 1,
            placed_triangles: 10,
            structure: structure.into(),
            embree,
            two_level: true,
            build_ms,
            memory_bytes: None,
            mrays: vec![1.0; 3],
            paths: vec!["single".into(); 3],
            frame_rays: 100.0,
            frame_trace_ms: trace,
            differ: 0,
            wrong: Some(0),
            checked: 10,
            threads: 2,
        };
        let instances = [
            instance("raylab two-level", false, 5.0, 12.0),
            instance("embree instances", true, 8.0, 10.0),
        ];
        let s = Summary::of(&[], &[], &[], &[], &animation, &instances);
        let md = s.markdown();
        assert_eq!(s.problems.len(), 3, "{md}");
        // 1 spp: raylab 1 + 2 + 20 = 23, Embree 1 + 4 + 18 = 23: level.
        // 16 spp: raylab 3 + 320 = 323 against 5 + 288 = 293.
        assert!(md.contains("- belt (1 thread): update plus trace over the animation, raylab's best strategy against Embree's best: 1.10x the time at 16 spp (raylab-rebuild-medium 323.0 ms against embree-refit 293.0)"), "{md}");
        assert!(!md.contains("refit took"), "{md}");
        assert!(
            md.contains("raylab-rebuild-medium answered 1 of 20 rays otherwise"),
            "{md}"
        );
        assert!(md.contains("- forest:10 (2 threads): raylab's two-level tree traces a frame in 1.20x the time of Embree's instances (12.0 ms against 10.0)"), "{md}");
        assert!(!md.contains("builds in"), "{md}");
    }

    #[test]
    fn nothing_measured_says_so() {
        let md = Summary::of(&[], &[], &[], &[], &[], &[]).markdown();
        assert!(md.contains("No backend was timed"), "{md}");
        assert!(md.contains("### What was wrong\n\nNothing"), "{md}");
    }

    #[test]
    fn dates_and_command_lines() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(19_723), (2024, 1, 1));
        assert_eq!(civil_from_days(19_782), (2024, 2, 29));
        assert_eq!(today().len(), 10);
        let args = [
            "/x/raylab",
            "bench",
            "--quick",
            "--views",
            "0,1,3;2,1,3",
            "--out",
            "my dir",
        ];
        assert_eq!(
            command_line(args.map(String::from)),
            "raylab bench --quick --views '0,1,3;2,1,3' --out 'my dir'"
        );
    }
}
