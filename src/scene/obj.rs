//! OBJ/MTL loading: `tobj` triangulates and single-indexes the OBJ; a line-by-line
//! check runs first so that every error carries its file and line, and the MTL
//! files are read here (only Ka, Kd, Ks, Ns, Ke), because tobj's MTL reader panics on
//! short colour lines and cannot name a line.
//!
//! Contract: returns a valid [`Scene`] or an [`Error`] naming the file (and line
//! where there is one). A missing MTL file or an unknown `usemtl` name is a warning
//! (the faces get [`Material::default_grey`]), not an error.

use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{Material, Scene};
use crate::error::{Error, Result};

/// Loads an OBJ file (and the MTL files it names, relative to its folder).
pub fn load_obj(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&bytes);
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_obj_str(&text, path, &base)
}

/// Loads OBJ text; `path` names it in messages and `mtl_dir` is where `mtllib`
/// names are looked up. Used by [`load_obj`] and by tests with fixture strings.
pub fn load_obj_str(text: &str, path: &Path, mtl_dir: &Path) -> Result<Scene> {
    check_obj_lines(text, path)?;

    let materials: RefCell<Vec<Material>> = RefCell::new(Vec::new());
    let warnings: RefCell<Vec<String>> = RefCell::new(Vec::new());
    let mtl_error: RefCell<Option<Error>> = RefCell::new(None);
    let load_options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let loader = |mtl_name: &Path| -> tobj::MTLLoadResult {
        let mtl_path = mtl_dir.join(mtl_name);
        match std::fs::read(&mtl_path) {
            Ok(bytes) => match parse_mtl(&String::from_utf8_lossy(&bytes), &mtl_path) {
                Ok(mats) => {
                    let map: HashMap<String, usize> = mats
                        .iter()
                        .enumerate()
                        .map(|(i, m)| (m.name.clone(), i))
                        .collect();
                    let stubs = mats
                        .iter()
                        .map(|m| tobj::Material {
                            name: m.name.clone(),
                            ..Default::default()
                        })
                        .collect();
                    materials.borrow_mut().extend(mats);
                    Ok((stubs, map))
                }
                Err(e) => {
                    mtl_error.borrow_mut().get_or_insert(e);
                    Err(tobj::LoadError::MaterialParseError)
                }
            },
            Err(e) => {
                warnings.borrow_mut().push(format!(
                    "{}: material library {}: {e}; using default grey",
                    path.display(),
                    mtl_path.display()
                ));
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    };
    let mut reader = std::io::BufReader::new(text.as_bytes());
    let loaded = tobj::load_obj_buf(&mut reader, &load_options, loader);
    if let Some(e) = mtl_error.into_inner() {
        return Err(e);
    }
    let (models, _) = loaded.map_err(|e| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg: format!("OBJ parser: {e}"),
    })?;

    let mut materials = materials.into_inner();
    let mut warnings = warnings.into_inner();
    let grey = materials.len() as u32;
    materials.push(Material::default_grey());
    let mut unnamed_faces = 0usize;

    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut any_normals = false;
    let mut triangles = Vec::new();
    let mut material_ids = Vec::new();
    for model in &models {
        let mesh = &model.mesh;
        let base = positions.len() as u32;
        let count = mesh.positions.len() / 3;
        positions.extend(
            mesh.positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        if mesh.normals.len() == mesh.positions.len() {
            any_normals = true;
            normals.extend(
                mesh.normals
                    .chunks_exact(3)
                    .map(|n| Vec3::new(n[0], n[1], n[2])),
            );
        } else {
            normals.extend(std::iter::repeat_n(Vec3::ZERO, count));
        }
        let mat = match mesh.material_id {
            Some(id) if id < grey as usize => id as u32,
            _ => {
                unnamed_faces += mesh.indices.len() / 3;
                grey
            }
        };
        for idx in mesh.indices.chunks_exact(3) {
            triangles.push([idx[0] + base, idx[1] + base, idx[2] + base]);
            material_ids.push(mat);
        }
    }
    if unnamed_faces > 0 && grey > 0 {
        warnings.push(format!(
            "{}: {unnamed_faces} triangles name no known material; using default grey",
            path.display()
        ));
    }
    let mut scene = Scene::new(
        path.display().to_string(),
        positions,
        any_normals.then_some(normals),
        triangles,
        material_ids,
        materials,
    )
    .map_err(|e| match e {
        Error::Scene { msg, .. } => Error::Parse {
            path: path.to_path_buf(),
            line: 0,
            msg,
        },
        other => other,
    })?;
    warnings.append(&mut scene.warnings);
    scene.warnings = warnings;
    Ok(scene)
}

/// Checks every OBJ line tobj will read, so errors name their line: vertex
/// records need finite numbers, face records need valid, in-range indices.
fn check_obj_lines(text: &str, path: &Path) -> Result<()> {
    let err = |line: usize, msg: String| Error::Parse {
        path: path.to_path_buf(),
        line,
        msg,
    };
    // Counts of v, vt, vn seen so far (negative indices are relative to these).
    let mut counts = [0i64; 3];
    // The largest positive index of each kind and the line it is on, checked at the end.
    let mut max_ref = [(0i64, 0usize); 3];
    let mut faces = 0usize;
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let (kind, need) = match key {
            "v" => (0, 3),
            "vt" => (1, 2),
            "vn" => (2, 3),
            "f" => {
                let refs: Vec<&str> = words.collect();
                if refs.len() < 3 {
                    return Err(err(line_no, "face needs at least 3 vertices".into()));
                }
                for r in refs {
                    let parts: Vec<&str> = r.split('/').collect();
                    if parts.len() > 3 || parts[0].is_empty() {
                        return Err(err(line_no, format!("malformed face vertex '{r}'")));
                    }
                    for (kind, part) in parts.iter().enumerate() {
                        if part.is_empty() {
                            continue; // "v//vn" has no texture index
                        }
                        let i: i64 = part.parse().map_err(|_| {
                            err(line_no, format!("malformed face index '{part}' in '{r}'"))
                        })?;
                        let name = ["vertex", "texture", "normal"][kind];
                        if i == 0 {
                            return Err(err(
                                line_no,
                                format!("{name} index 0 (OBJ counts from 1)"),
                            ));
                        }
                        if i < 0 && -i > counts[kind] {
                            return Err(err(
                                line_no,
                                format!(
                                    "{name} index {i} points before the first {name} ({} defined so far)",
                                    counts[kind]
                                ),
                            ));
                        }
                        if i > max_ref[kind].0 {
                            max_ref[kind] = (i, line_no);
                        }
                    }
                }
                faces += 1;
                continue;
            }
            _ => continue, // g, o, s, usemtl, mtllib, l, p and unknown keys
        };
        let mut numbers = 0;
        for w in words.by_ref().take(need) {
            let x: f32 = w
                .parse()
                .map_err(|_| err(line_no, format!("'{key}' record: '{w}' is not a number")))?;
            if !x.is_finite() {
                return Err(err(
                    line_no,
                    format!("'{key}' record: coordinate '{w}' is not finite"),
                ));
            }
            numbers += 1;
        }
        if numbers < need {
            return Err(err(
                line_no,
                format!("'{key}' record needs {need} numbers, found {numbers}"),
            ));
        }
        counts[kind] += 1;
    }
    for (kind, &(i, line_no)) in max_ref.iter().enumerate() {
        if i > counts[kind] {
            let name = ["vertex", "texture", "normal"][kind];
            return Err(err(
                line_no,
                format!("{name} index {i} out of range (file has {})", counts[kind]),
            ));
        }
    }
    if faces == 0 {
        return Err(err(0, "no faces: nothing to render".into()));
    }
    Ok(())
}

/// Reads the MTL values raylab uses. Colours take one or three non-negative
/// numbers; `Ka` defaults to `Kd` when a material gives none, so AO has an ambient
/// term to darken.
pub fn parse_mtl(text: &str, path: &Path) -> Result<Vec<Material>> {
    let err = |line: usize, msg: String| Error::Parse {
        path: PathBuf::from(path),
        line,
        msg,
    };
    let mut out: Vec<Material> = Vec::new();
    let mut ka_given = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        if key == "newmtl" {
            let name = line["newmtl".len()..].trim();
            if name.is_empty() {
                return Err(err(line_no, "newmtl without a name".into()));
            }
            out.push(Material {
                name: name.to_string(),
                ka: Vec3::ZERO,
                kd: Vec3::splat(0.8),
                ks: Vec3::ZERO,
                ns: 10.0,
                ke: Vec3::ZERO,
            });
            ka_given.push(false);
            continue;
        }
        if !matches!(key, "Ka" | "Kd" | "Ks" | "Ke" | "Ns") {
            continue;
        }
        let Some(mat) = out.last_mut() else {
            return Err(err(line_no, format!("'{key}' before any newmtl")));
        };
        let mut values = Vec::with_capacity(3);
        for w in words.take(3) {
            let x: f32 = w
                .parse()
                .map_err(|_| err(line_no, format!("'{key}': '{w}' is not a number")))?;
            if !(x.is_finite() && x >= 0.0) {
                return Err(err(
                    line_no,
                    format!("'{key}': '{w}' must be finite and non-negative"),
                ));
            }
            values.push(x);
        }
        if key == "Ns" {
            match values.first() {
                Some(&ns) => mat.ns = ns,
                None => return Err(err(line_no, "'Ns' needs a number".into())),
            }
            continue;
        }
        let colour = match values[..] {
            [g] => Vec3::splat(g),
            [r, g, b] => Vec3::new(r, g, b),
            _ => {
                return Err(err(
                    line_no,
                    format!("'{key}' needs 1 or 3 numbers, found {}", values.len()),
                ))
            }
        };
        match key {
            "Ka" => {
                mat.ka = colour;
                *ka_given.last_mut().unwrap() = true;
            }
            "Kd" => mat.kd = colour,
            "Ks" => mat.ks = colour,
            _ => mat.ke = colour,
        }
    }
    for (m, given) in out.iter_mut().zip(ka_given) {
        if !given {
            m.ka = m.kd;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> Result<Scene> {
        load_obj_str(text, Path::new("fixture.obj"), Path::new("/nonexistent"))
    }

    #[test]
    fn quads_are_triangulated() {
        let s = load("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        assert_eq!(s.triangle_count(), 2);
        assert!(s.normals.is_none());
    }

    #[test]
    fn negative_indices_and_slashes_are_read() {
        let s = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf -3//1 -2//1 -1//1\n").unwrap();
        assert_eq!(s.triangle_count(), 1);
        assert_eq!(s.shading_normal(0, 0.2, 0.2), Some(Vec3::Z));
    }

    #[test]
    fn missing_mtl_warns_and_uses_grey() {
        let s =
            load("mtllib nothere.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert!(
            s.warnings.iter().any(|w| w.contains("nothere.mtl")),
            "{:?}",
            s.warnings
        );
        assert_eq!(*s.material_of(0), Material::default_grey());
    }

    fn error_of(text: &str) -> String {
        load(text).unwrap_err().to_string()
    }

    #[test]
    fn malformed_vertex_names_its_line() {
        let e = error_of("v 0 0 0\nv 1 x 0\n");
        assert!(e.starts_with("fixture.obj:2:"), "{e}");
        let e = error_of("v 0 0\n");
        assert!(e.contains(":1:") && e.contains("needs 3 numbers"), "{e}");
    }

    #[test]
    fn non_finite_coordinates_are_rejected() {
        for bad in ["nan", "inf", "-inf", "1e39"] {
            let e = error_of(&format!("v 0 0 0\nv 1 0 0\nv 0 {bad} 0\nf 1 2 3\n"));
            assert!(e.contains(":3:") && e.contains("not finite"), "{bad}: {e}");
        }
    }

    #[test]
    fn out_of_range_indices_are_rejected() {
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
        assert!(e.contains(":4:") && e.contains("out of range"), "{e}");
        let e = error_of("v 0 0 0\nv 1 0 0\nf 1 2 -3\n");
        assert!(e.contains(":3:") && e.contains("before the first"), "{e}");
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
        assert!(e.contains("index 0"), "{e}");
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n");
        assert!(e.contains("texture index 1 out of range"), "{e}");
    }

    #[test]
    fn malformed_faces_are_rejected() {
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n");
        assert!(e.contains(":4:") && e.contains("at least 3"), "{e}");
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n");
        assert!(e.contains("malformed face index"), "{e}");
    }

    #[test]
    fn no_triangles_is_an_error() {
        assert!(error_of("v 0 0 0\n").contains("no faces"));
        assert!(error_of("").contains("no faces"));
        // Only degenerate triangles: nothing left to render.
        let e = error_of("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
        assert!(e.contains("degenerate"), "{e}");
    }

    #[test]
    fn unreadable_file_is_an_io_error_naming_it() {
        let e = load_obj(Path::new("/nonexistent/scene.obj"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/nonexistent/scene.obj:"), "{e}");
    }

    #[test]
    fn mtl_values_are_read() {
        let m = parse_mtl(
            "newmtl red\nKa 0.1 0.2 0.3 # comment\nKd 0.63 0.065 0.05\nNs 20\n\
             newmtl light\nKd 0.78 0.78 0.78\nKe 17 12 4\nKs 0.5\n",
            Path::new("x.mtl"),
        )
        .unwrap();
        assert_eq!(m.len(), 2);
        assert_eq!(m[0].ka, Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(m[0].ns, 20.0);
        assert_eq!(m[1].ke, Vec3::new(17.0, 12.0, 4.0));
        assert_eq!(m[1].ka, m[1].kd, "Ka defaults to Kd");
        assert_eq!(m[1].ks, Vec3::splat(0.5));
        assert!(m[1].is_emissive() && !m[0].is_emissive());
    }

    #[test]
    fn malformed_mtl_names_its_line() {
        let e = parse_mtl("newmtl a\nKd 0.5 0.5\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().starts_with("x.mtl:2:"), "{e}");
        let e = parse_mtl("Kd 1 1 1\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().contains("before any newmtl"), "{e}");
        let e = parse_mtl("newmtl a\nKe nan 1 1\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().contains("finite"), "{e}");
    }

    #[test]
    fn materials_and_lights_come_from_the_mtl() {
        let dir = std::env::temp_dir().join(format!("raylab-obj-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("box.mtl"),
            "newmtl white\nKd 0.7 0.7 0.7\nnewmtl light\nKd 0.8 0.8 0.8\nKe 10 10 10\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("box.obj"),
            "mtllib box.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl white\nf 1 2 3 4\n\
             v 0 0 1\nv 1 0 1\nv 0 1 1\nusemtl light\nf -3 -2 -1\n",
        )
        .unwrap();
        let s = load_obj(&dir.join("box.obj")).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(s.triangle_count(), 3);
        assert_eq!(s.lights.triangles.len(), 1);
        assert_eq!(s.material_of(0).name, "white");
        assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    }
}
