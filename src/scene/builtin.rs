//! Built-in scenes by name: the still shapes (src/scene/shapes.rs), the
//! instanced forest and the animations at rest. The fixed scenes' triangle
//! counts match the study's (12, 36, 2188, 7088) so its numbers can be set
//! beside ours without the OBJ files.

use super::shapes::{parse_count, still};
use super::Scene;
use crate::error::{Error, Result};

/// Names accepted by [`builtin`], with a one-line description each.
pub const BUILTIN_SCENES: &[(&str, &str)] = &[
    (
        "cornell-empty",
        "walls, floor, ceiling and light (12 triangles)",
    ),
    (
        "cornell-original",
        "the classic box with a short and a tall block (36 triangles)",
    ),
    (
        "cornell-sphere",
        "two tessellated glossy spheres instead of blocks (2188 triangles)",
    ),
    (
        "cornell-water",
        "the spheres half under a wavy height-field water surface (7088 triangles)",
    ),
];

/// Parameterised built-in scenes, listed by `raylab scenes` after the fixed ones.
pub const PROCEDURAL_SCENES: &[(&str, &str)] = &[
    (
        "mesh:N",
        "a displaced UV sphere of about N triangles (1e2..=1e8) in the empty box, for scaling curves",
    ),
    (
        "grass:N",
        "N leaning grass blades (1e2..=1e7), one long thin diagonal triangle each, in the empty box",
    ),
    (
        "city:N",
        "N boxes (1e1..=1e6) of sizes over 2.5 decades on a 40x40 ground plane under the box's floor: a teapot in a stadium",
    ),
    (
        "city45:N",
        "city:N turned 45 degrees about the vertical axis: every wall diagonal to the axes",
    ),
    (
        "rooms:N",
        "an interior of about N triangles (200..=1e7): a grid of 4 x 4 m rooms, walls 10 cm thick with doorways, each room lit by a small ceiling panel; the camera stands in a room",
    ),
    (
        "pipes:N",
        "about N triangles (100..=1e7) of CAD-like pipes: long thin cylinders of 12 sides in one segment (every side two long slivers) at random angles, framed from their bounds",
    ),
    (
        "overlap:N",
        "N large triangles (10..=1e7) crossing one another at random in a 4-unit cube: every box overlaps every other, framed from their bounds",
    ),
    (
        "far:N",
        "mesh:N (its box included) moved 10^5 units from the origin along x and z, framed from its bounds: f32 coordinates 1/128 apart",
    ),
    (
        "forest:N",
        "N instances (1..=1e7) of three trees of about 10^4 triangles each, stored once, on a ground: an instanced scene (two-level trees; --flatten bakes it into one list), framed from its bounds",
    ),
    (
        "plane:N",
        "a field of about N triangles (2..=1e7), a jittered grid 100 units across, every one in the plane y = 0, under a square light: a flat export (floor plan, terrain tile, sports ground), framed from its bounds",
    ),
];

/// The built-in scene called `name`.
pub fn builtin(name: &str) -> Result<Scene> {
    // An animated built-in, as it stands at time 0.
    if let Some(animation) = super::motion::Animation::parse(name) {
        return Ok(animation?.rest().clone());
    }
    if name.starts_with("forest:") {
        let n = parse_count(name, "forest", super::forest::INSTANCES)?;
        return super::forest::forest(name, n as usize);
    }
    if let Some(scene) = still(name)? {
        return Ok(scene);
    }
    let names: Vec<&str> = BUILTIN_SCENES
        .iter()
        .chain(PROCEDURAL_SCENES)
        .chain(super::motion::ANIMATED_SCENES)
        .map(|(n, _)| *n)
        .collect();
    let files: Vec<String> = super::EXTENSIONS.iter().map(|e| format!(".{e}")).collect();
    Err(Error::usage(
        "SCENE",
        format!(
            "'{name}' is neither a scene file ({}) nor a built-in scene ({})",
            files.join(", "),
            names.join(", ")
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn builtin_triangle_counts_match_the_study() {
        for (name, count) in [
            ("cornell-empty", 12),
            ("cornell-original", 36),
            ("cornell-sphere", 2188),
            ("cornell-water", 7088),
        ] {
            let s = builtin(name).unwrap();
            assert_eq!(s.triangle_count(), count, "{name}");
            assert_eq!(s.dropped_degenerate, 0, "{name}");
            assert_eq!(s.lights.triangles.len(), 2, "{name}");
        }
    }

    #[test]
    fn builtins_stay_inside_the_box_frame() {
        for (name, _) in BUILTIN_SCENES {
            let b = builtin(name).unwrap().bounds();
            assert!(
                b.min.cmpge(Vec3::new(-1.0, 0.0, -1.0)).all(),
                "{name} {b:?}"
            );
            assert!(b.max.cmple(Vec3::new(1.0, 2.0, 1.0)).all(), "{name} {b:?}");
        }
    }

    #[test]
    fn sphere_normals_point_outwards() {
        let s = builtin("cornell-sphere").unwrap();
        let normals = s.normals.as_ref().unwrap();
        let c = Vec3::new(-0.42, 0.33, -0.28);
        for (p, n) in s.positions.iter().zip(normals) {
            if (*p - c).length() < 0.33 {
                assert!((*p - c).normalize().dot(*n) > 0.99);
            }
        }
    }

    #[test]
    fn mesh_scenes_have_about_n_triangles() {
        for n in [100u64, 1000, 12345, 100_000] {
            let s = builtin(&format!("mesh:{n}")).unwrap();
            let tris = s.triangle_count() as f64 - 12.0;
            assert!((tris / n as f64 - 1.0).abs() < 0.05, "mesh:{n} has {tris}");
        }
        assert_eq!(
            builtin("mesh:1e3").unwrap().triangle_count(),
            builtin("mesh:1000").unwrap().triangle_count()
        );
        for bad in [
            "mesh:",
            "mesh:0",
            "mesh:x",
            "mesh:1e20",
            "mesh:-5",
            "mesh:1.5",
        ] {
            assert!(
                builtin(bad).unwrap_err().to_string().contains("mesh:N"),
                "{bad}"
            );
        }
    }

    #[test]
    fn builder_scenes_have_their_triangles() {
        assert_eq!(builtin("grass:1000").unwrap().triangle_count(), 12 + 1000);
        assert_eq!(builtin("city:100").unwrap().triangle_count(), 12 + 1200 + 2);
        let straight = builtin("city:50").unwrap();
        let turned = builtin("city45:50").unwrap();
        assert_eq!(straight.triangle_count(), turned.triangle_count());
        // Turned, the ground's corners lie on the axes.
        assert!((turned.bounds().max.x - 20.0 * 2f32.sqrt()).abs() < 1e-3);
        assert!((straight.bounds().max.x - 20.0).abs() < 1e-6);
        for bad in ["grass:5", "city:x", "city45:1e7"] {
            let e = builtin(bad).unwrap_err().to_string();
            assert!(e.contains(":N must be"), "{bad}: {e}");
        }
    }

    #[test]
    fn class_scenes_have_about_n_triangles_where_they_say() {
        for (name, lo, hi) in [
            ("plane:20000", 20_000, 20_002),
            ("rooms:20000", 16_000, 24_000),
            ("pipes:20000", 20_000, 20_048),
            ("overlap:5000", 5000, 5000),
            ("far:20000", 19_000, 21_000),
        ] {
            let s = builtin(name).unwrap();
            let n = s.triangle_count();
            assert!((lo..=hi).contains(&n), "{name}: {n}");
            assert!(!s.lights.triangles.is_empty() || !name.starts_with("rooms"));
        }
        // The field lies in y = 0 but for its light; far is far.
        let field = builtin("plane:2000").unwrap();
        let flat = field.positions.iter().filter(|p| p.y == 0.0).count();
        assert_eq!(flat, field.positions.len() - 4);
        assert!(builtin("far:2000").unwrap().bounds().min.x > 9.9e4);
        // Framed from their bounds, except the rooms (the study's eye stands in one).
        assert!(!field.study_frame && builtin("rooms:2000").unwrap().study_frame);
        for bad in ["plane:1", "rooms:10", "pipes:1e8", "overlap:x", "far:5"] {
            let e = builtin(bad).unwrap_err().to_string();
            assert!(e.contains(":N must be"), "{bad}: {e}");
        }
    }

    #[test]
    fn unknown_name_lists_the_builtins() {
        let e = builtin("cornell-nope").unwrap_err().to_string();
        assert!(e.contains("cornell-water"), "{e}");
    }
}
