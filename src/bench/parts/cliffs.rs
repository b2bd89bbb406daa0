//! The cliff finder: where raylab's best path is behind the best peer, per
//! scene and ray kind, read from the `libraries` part's points (every
//! backend on its fastest path, the same rays, one thread, interleaved), and
//! the scene classes `bench --cliffs` sweeps so that raylab finds its cliffs
//! before its users do.

use serde::Serialize;

use super::libraries::{LibraryPoint, KINDS};
use crate::bench::family::Family;
use crate::table::{
    Align::{Left, Right},
    Table,
};

/// The scene classes `bench --cliffs` sweeps: (class, built-in scene, the
/// smaller one `--quick` takes). All generated (`raylab scenes` describes
/// each); real exports are given beside them as SCENE arguments.
pub const CLASSES: [(&str, &str, &str); 9] = [
    ("planar (flat export)", "plane:20000", "plane:2000"),
    ("architecture interior", "rooms:20000", "rooms:2000"),
    ("closed scan", "mesh:50000", "mesh:5000"),
    ("CAD (long slivers)", "pipes:20000", "pipes:2000"),
    ("foliage (thin blades)", "grass:20000", "grass:2000"),
    ("huge and tiny", "city:3000", "city:300"),
    ("far from the origin", "far:20000", "far:2000"),
    ("heavy overlap", "overlap:5000", "overlap:500"),
    ("the study's box", "cornell-water", "cornell-sphere"),
];

/// The class of a built-in scene name, if it is one of [`CLASSES`].
pub fn class_of(scene: &str) -> Option<&'static str> {
    CLASSES
        .iter()
        .find(|(_, full, quick)| *full == scene || *quick == scene)
        .map(|(class, _, _)| *class)
}

/// One scene and ray kind: raylab's best against the best peer's.
#[derive(Clone, Debug, Serialize)]
pub struct Cliff {
    pub scene: String,
    pub class: Option<&'static str>,
    pub kind: &'static str,
    /// raylab's fastest backend and path on this kind, and its Mrays/s.
    pub raylab: String,
    pub raylab_mrays: f64,
    /// The fastest other backend (Embree on any path, or a library).
    pub peer: String,
    pub peer_mrays: f64,
    /// Embree's best path's Mrays/s (NaN without Embree).
    pub embree_mrays: f64,
    /// raylab's time per ray over the best peer's (above 1: behind).
    pub over_peer: f64,
    /// raylab's time per ray over Embree's best.
    pub over_embree: f64,
}

impl Cliff {
    pub fn behind(&self) -> bool {
        self.over_peer > 1.0
    }
}

/// Every scene and render ray kind (primary, shadow, AO, diffuse) with both a
/// raylab and a peer measurement.
pub fn cliffs(points: &[LibraryPoint]) -> Vec<Cliff> {
    cliffs_among(points, |_| true)
}

/// [`cliffs`] of the robust paths alone ([`LibraryPoint::robust`]):
/// raylab's watertight test against the peers' watertight tests (Embree's
/// robust mode; the other libraries have none).
pub fn robust_cliffs(points: &[LibraryPoint]) -> Vec<Cliff> {
    cliffs_among(points, |p| p.robust)
}

/// [`cliffs`] over the points `among` keeps.
fn cliffs_among(points: &[LibraryPoint], among: impl Fn(&LibraryPoint) -> bool) -> Vec<Cliff> {
    let points: Vec<&LibraryPoint> = points.iter().filter(|p| among(p)).collect();
    let mut scenes: Vec<&str> = Vec::new();
    for p in &points {
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    let mut out = Vec::new();
    for scene in scenes {
        for (k, kind) in KINDS.iter().enumerate().take(4) {
            let best = |family: &dyn Fn(Family) -> bool| {
                points
                    .iter()
                    .copied()
                    .filter(|p| p.scene == scene && p.failed.is_none() && family(p.family))
                    .filter_map(|p| {
                        let m = *p.mrays.get(k)?;
                        m.is_finite().then_some((m, p))
                    })
                    .max_by(|a, b| a.0.total_cmp(&b.0))
            };
            let (Some((own, own_p)), Some((peer, peer_p))) = (
                best(&|f| f == Family::Raylab),
                best(&|f| f != Family::Raylab),
            ) else {
                continue;
            };
            let embree = best(&|f| f == Family::Embree).map_or(f64::NAN, |(m, _)| m);
            let path = |p: &LibraryPoint| match p.paths.get(k) {
                Some(path) if !path.is_empty() => format!("{} {path}", p.backend),
                _ => p.backend.clone(),
            };
            out.push(Cliff {
                scene: scene.to_string(),
                class: class_of(scene),
                kind: kind.name(),
                raylab: path(own_p),
                raylab_mrays: own,
                peer: path(peer_p),
                peer_mrays: peer,
                embree_mrays: embree,
                over_peer: peer / own,
                over_embree: embree / own,
            });
        }
    }
    out
}

/// The cliff table, leading the libraries part: every cell where raylab is
/// behind marked, and a count.
pub fn markdown(points: &[LibraryPoint]) -> String {
    let cells = cliffs(points);
    if cells.is_empty() {
        return String::new();
    }
    let behind = cells.iter().filter(|c| c.behind()).count();
    let mut out = format!(
        "### Where raylab is behind\n\n{behind} of {} cells behind: raylab's fastest backend and path against the fastest other one (Embree on any path, tinybvh, obvhs, the bvh crate) per scene and ray kind, one thread, the same rays (the table below has every backend). Above 1.00 raylab takes longer per ray.\n\n{}\n",
        cells.len(),
        cells_table(&cells)
    );
    let robust = robust_cliffs(points);
    if !robust.is_empty() {
        let behind = robust.iter().filter(|c| c.behind()).count();
        out += &format!(
            "### Robust paths: where raylab's watertight test is behind\n\n{behind} of {} cells behind: raylab's fastest path with the watertight test against Embree's fastest in its robust mode (the only other backends that promise no ray passes between triangles sharing an edge; their wrong answers are in the accuracy table below), per scene and ray kind, one thread, the same rays.\n\n{}\n",
            robust.len(),
            cells_table(&robust)
        );
    }
    out
}

/// The cells as a table, each one behind marked.
fn cells_table(cells: &[Cliff]) -> String {
    let mut t = Table::new([
        ("scene", Left),
        ("class", Left),
        ("rays", Left),
        ("raylab's best (path)", Left),
        ("Mrays/s", Right),
        ("best peer (path)", Left),
        ("Mrays/s", Right),
        ("time / best peer's", Right),
        ("time / Embree's best", Right),
    ]);
    for c in cells {
        t.row([
            c.scene.clone(),
            c.class.unwrap_or("given").to_string(),
            c.kind.to_string(),
            c.raylab.clone(),
            format!("{:.1}", c.raylab_mrays),
            c.peer.clone(),
            format!("{:.1}", c.peer_mrays),
            if c.behind() {
                format!("**{:.2} behind**", c.over_peer)
            } else {
                format!("{:.2}", c.over_peer)
            },
            format!("{:.2}", c.over_embree),
        ]);
    }
    t.markdown()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::measure::Stat;

    fn point(scene: &str, backend: &str, family: Family, mrays: [f64; 4]) -> LibraryPoint {
        LibraryPoint {
            scene: scene.into(),
            triangles: 1,
            backend: backend.into(),
            family,
            robust: backend.contains("watertight") || backend.contains("robust"),
            build_ms: Stat::of(&[1.0]),
            mrays: mrays.into_iter().chain([f64::NAN, 1.0]).collect(),
            paths: vec!["single".into(); KINDS.len()],
            ns_per_ray: 1.0,
            rays: 1,
            wrong: 0,
            undecidable: 0,
            wrong_per_million: 0.0,
            edge_rays: 0,
            edge_wrong: 0,
            edge_undecidable: 0,
            edge_wrong_per_million: 0.0,
            limits: Vec::new(),
            failed: None,
        }
    }

    #[test]
    fn a_cell_is_behind_when_any_peer_is_faster_than_raylab_s_best_path() {
        let points = [
            point(
                "plane:20000",
                "bvh8-sah",
                Family::Raylab,
                [20.0, 200.0, 10.0, 5.0],
            ),
            point(
                "plane:20000",
                "bvh8-sah-watertight",
                Family::Raylab,
                [5.0, 50.0, 30.0, 1.0],
            ),
            point(
                "plane:20000",
                "embree-medium",
                Family::Embree,
                [25.0, 100.0, 20.0, 4.0],
            ),
            point(
                "plane:20000",
                "tinybvh-bvh8",
                Family::Tinybvh,
                [10.0, 300.0, 1.0, 1.0],
            ),
        ];
        let cells = cliffs(&points);
        assert_eq!(cells.len(), 4);
        let behind: Vec<&str> = cells
            .iter()
            .filter(|c| c.behind())
            .map(|c| c.kind)
            .collect();
        // Primary: Embree 25 over 20; shadow: tinybvh 300 over 200; AO:
        // raylab's watertight (30) is its best, ahead of Embree's 20.
        assert_eq!(behind, ["primary", "shadow"]);
        assert_eq!(cells[0].over_peer, 25.0 / 20.0);
        assert_eq!(cells[2].raylab, "bvh8-sah-watertight single");
        assert_eq!(cells[0].class, Some("planar (flat export)"));
        let md = markdown(&points);
        assert!(md.contains("2 of 4 cells behind"), "{md}");
        assert!(md.contains("**1.25 behind**"), "{md}");
        // No robust peer: no robust table.
        assert!(robust_cliffs(&points).is_empty());
        assert!(!md.contains("Robust paths"), "{md}");
    }

    /// The robust table sets raylab's watertight paths against Embree's
    /// robust mode alone, whatever the faster plain paths do.
    #[test]
    fn robust_cells_compare_the_watertight_paths_alone() {
        let points = [
            point(
                "rooms",
                "bvh8-sah",
                Family::Raylab,
                [90.0, 90.0, 90.0, 90.0],
            ),
            point(
                "rooms",
                "bvh8-sah-watertight",
                Family::Raylab,
                [5.0, 50.0, 30.0, 1.0],
            ),
            point(
                "rooms",
                "embree-medium",
                Family::Embree,
                [99.0, 99.0, 99.0, 99.0],
            ),
            point(
                "rooms",
                "embree-medium-robust",
                Family::Embree,
                [10.0, 40.0, 20.0, 2.0],
            ),
        ];
        let robust = robust_cliffs(&points);
        let behind: Vec<&str> = robust
            .iter()
            .filter(|c| c.behind())
            .map(|c| c.kind)
            .collect();
        assert_eq!(behind, ["primary", "diffuse"]);
        assert_eq!(robust[0].raylab, "bvh8-sah-watertight single");
        assert_eq!(robust[0].peer, "embree-medium-robust single");
        assert_eq!(robust[1].over_peer, 40.0 / 50.0);
        let md = markdown(&points);
        assert!(md.contains("### Robust paths"), "{md}");
        assert!(
            md.contains("2 of 4 cells behind: raylab's fastest path with the watertight test"),
            "{md}"
        );
        assert!(md.contains("**2.00 behind**"), "{md}");
    }
}
