//! OBJ/MTL loading, by raylab's own reader: every record is checked as it is
//! read, so every error names its file and line, and the reader does what
//! users' exports need (Blender's, scanners', old tools'):
//!
//! - `f` records of 3 or more vertices; convex polygons are fanned, concave ones
//!   ear-clipped in their best-fit plane ([`super::polygon`]); faces of fewer
//!   than 3 vertices (Blender 2.6x wrote loose edges as 2-vertex faces) are
//!   skipped with one counted warning, like degenerate triangles;
//! - `l` and `p` records (lines and points) never become triangles;
//! - vertex normals per face corner: a face without `vn` leaves only its own
//!   corners without a shading normal;
//! - texture indices are checked for syntax (raylab uses no texture
//!   coordinates): one out of range is a warning, not an error;
//! - a `\` at the end of a line continues the record on the next line;
//! - MTL files: `Ka`, `Kd`, `Ks`, `Ns`, `Ke`, nothing else.
//!
//! (tobj, used before, fan-triangulated concave polygons, filled `l` polylines,
//! rejected 2-vertex faces, dropped a whole object's normals when one face had
//! none, and could not name the line of an error.)
//!
//! Contract: returns a valid [`Scene`] or an [`Error`] naming the file (and line
//! where there is one). A missing MTL file or an unknown `usemtl` name is a
//! warning (the faces get [`Material::default_grey`]), not an error.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::refs::{RefError, RefPolicy, Refs};
use super::{polygon, Material, Scene};
use crate::error::{Error, Result};

/// Loads an OBJ file (and the MTL files it names, relative to its folder).
pub fn load_obj(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&bytes);
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_obj_str(&text, path, &base)
}

/// Loads OBJ text; `path` names it in messages and `mtl_dir` is where `mtllib`
/// names are looked up (never outside it). Used by [`load_obj`] and by tests with fixture strings.
pub fn load_obj_str(text: &str, path: &Path, mtl_dir: &Path) -> Result<Scene> {
    load_obj_str_with(text, path, mtl_dir, RefPolicy::default())
}

/// [`load_obj_str`], MTL files read where `policy` allows.
pub fn load_obj_str_with(
    text: &str,
    path: &Path,
    mtl_dir: &Path,
    policy: RefPolicy,
) -> Result<Scene> {
    let mut reader = ObjReader {
        path,
        refs: Refs::in_dir(mtl_dir, policy),
        positions: Vec::new(),
        normals: Vec::new(),
        texcoords: 0,
        max_texcoord_ref: (0, 0),
        faces: Vec::new(),
        short_faces: 0,
        lines_and_points: 0,
        materials: Vec::new(),
        by_name: HashMap::new(),
        current: None,
        warnings: Vec::new(),
        mtl_read: std::collections::HashSet::new(),
        triangles: 0,
    };
    for (line_no, line) in logical_lines(text) {
        reader.record(line_no, &line)?;
    }
    reader.finish()
}

/// A face corner as written, resolved to 1-based indices (0: none given).
#[derive(Clone, Copy)]
struct Corner {
    position: i64,
    normal: i64,
}

struct Face {
    corners: Vec<Corner>,
    /// Index into the MTL materials; `None` before any `usemtl` or for an
    /// unknown name.
    material: Option<u32>,
    line: usize,
}

/// The reader's state between records.
struct ObjReader<'a> {
    path: &'a Path,
    /// Where `mtllib` files may be read from.
    refs: Refs,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    texcoords: i64,
    /// The largest texture index any corner names, and its line.
    max_texcoord_ref: (i64, usize),
    faces: Vec<Face>,
    short_faces: usize,
    lines_and_points: usize,
    materials: Vec<Material>,
    by_name: HashMap<String, u32>,
    current: Option<u32>,
    warnings: Vec<String>,
    /// MTL files read so far: a file named again is not read again (a 16 KB
    /// OBJ repeating `mtllib` made 40 million materials).
    mtl_read: std::collections::HashSet<PathBuf>,
    /// Triangles the faces so far will make, for the budget.
    triangles: u64,
}

impl ObjReader<'_> {
    fn err(&self, line: usize, msg: String) -> Error {
        Error::Parse {
            path: self.path.to_path_buf(),
            line,
            msg,
        }
    }

    /// Reads one record (a line, continuations joined).
    fn record(&mut self, line_no: usize, line: &str) -> Result<()> {
        let line = line.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else {
            return Ok(());
        };
        let rest = line[key.len()..].trim();
        match key {
            "v" | "vn" => {
                let mut xyz = [0f32; 3];
                let mut found = 0;
                for (slot, w) in xyz.iter_mut().zip(words.by_ref()) {
                    *slot = number(w, key).map_err(|m| self.err(line_no, m))?;
                    found += 1;
                }
                if found < 3 {
                    return Err(self.err(
                        line_no,
                        format!("'{key}' record needs 3 numbers, found {found}"),
                    ));
                }
                let v = Vec3::from_array(xyz);
                if key == "v" {
                    self.positions.push(v);
                } else {
                    self.normals.push(v);
                }
            }
            "vt" => {
                let mut found = 0;
                for w in words.by_ref().take(2) {
                    number(w, key).map_err(|m| self.err(line_no, m))?;
                    found += 1;
                }
                if found == 0 {
                    return Err(self.err(line_no, "'vt' record needs a number".into()));
                }
                self.texcoords += 1;
            }
            "f" => {
                let corners = words
                    .map(|r| self.corner(r, line_no))
                    .collect::<Result<Vec<_>>>()?;
                if corners.len() < 3 {
                    self.short_faces += 1;
                } else {
                    // Checked as the faces come: a face makes corners - 2
                    // triangles (and the file's size bounds the rest).
                    self.triangles += corners.len() as u64 - 2;
                    if let Some(msg) = super::budget::triangles_over(self.triangles) {
                        return Err(self.err(line_no, msg));
                    }
                    self.faces.push(Face {
                        corners,
                        material: self.current,
                        line: line_no,
                    });
                }
            }
            "l" | "p" => self.lines_and_points += 1,
            "usemtl" => self.current = self.by_name.get(rest).copied(),
            "mtllib" => {
                for file in mtl_names(rest, &self.refs) {
                    self.read_mtl(&file, line_no)?;
                }
            }
            _ => {} // o, g, s, and keys raylab has no use for
        }
        Ok(())
    }

    /// Parses a face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`; negative indices
    /// count back from the records read so far.
    fn corner(&mut self, r: &str, line_no: usize) -> Result<Corner> {
        let parts: Vec<&str> = r.split('/').collect();
        if parts.len() > 3 || parts[0].is_empty() {
            return Err(self.err(line_no, format!("malformed face vertex '{r}'")));
        }
        let counts = [
            self.positions.len() as i64,
            self.texcoords,
            self.normals.len() as i64,
        ];
        let mut resolved = [0i64; 3];
        for (kind, part) in parts.iter().enumerate() {
            if part.is_empty() {
                continue; // "v//vn" has no texture index
            }
            let i: i64 = part.parse().map_err(|_| {
                self.err(line_no, format!("malformed face index '{part}' in '{r}'"))
            })?;
            let name = ["vertex", "texture", "normal"][kind];
            if i == 0 {
                return Err(self.err(line_no, format!("{name} index 0 (OBJ counts from 1)")));
            }
            // `i < -count`, not `-i > count`: -i overflows for i64::MIN.
            if i < 0 && i < -counts[kind] {
                return Err(self.err(
                    line_no,
                    format!(
                        "{name} index {i} points before the first {name} ({} defined so far)",
                        counts[kind]
                    ),
                ));
            }
            resolved[kind] = if i < 0 { counts[kind] + i + 1 } else { i };
        }
        if resolved[1] > self.max_texcoord_ref.0 {
            self.max_texcoord_ref = (resolved[1], line_no);
        }
        Ok(Corner {
            position: resolved[0],
            normal: resolved[2],
        })
    }

    /// Reads the material library `name` (as the `mtllib` record on line
    /// `line_no` writes it), once: the same file named again (or under
    /// another spelling, ./a.mtl) is not read again. One that cannot be read
    /// is a warning (the faces get the default grey); one refused by the
    /// folder and file rules of [`Refs`] is an error.
    fn read_mtl(&mut self, name: &str, line_no: usize) -> Result<()> {
        let joined = self.refs.dir().join(name);
        let key = joined.canonicalize().unwrap_or(joined);
        if !self.mtl_read.insert(key) {
            return Ok(());
        }
        match self.refs.read_whole(name, MTL_CAP) {
            Ok(bytes) => {
                let mtl_path = self.refs.dir().join(name);
                let (mats, mut warnings) = parse_mtl(&String::from_utf8_lossy(&bytes), &mtl_path)?;
                self.warnings.append(&mut warnings);
                for m in mats {
                    self.by_name
                        .insert(m.name.clone(), self.materials.len() as u32);
                    self.materials.push(m);
                }
            }
            Err(RefError::Refused(e)) => {
                return Err(self.err(line_no, format!("material library {name:?}: {e}")))
            }
            Err(RefError::Unreadable(e)) => self.warnings.push(format!(
                "{}: material library {name:?}: {e}; using default grey",
                self.path.display(),
            )),
        }
        Ok(())
    }

    /// Checks the indices against the whole file, triangulates and makes the scene.
    fn finish(mut self) -> Result<Scene> {
        let path = self.path;
        if self.faces.is_empty() {
            let mut msg = "no faces: nothing to render".to_string();
            if self.short_faces + self.lines_and_points == 0 && !self.positions.is_empty() {
                msg = format!(
                    "a point cloud ({} vertices, no faces): nothing to render",
                    self.positions.len()
                );
            } else if self.short_faces + self.lines_and_points > 0 {
                msg = format!(
                    "no faces of 3 or more vertices: nothing to render ({} shorter faces, {} line and point records)",
                    self.short_faces, self.lines_and_points
                );
            }
            return Err(self.err(0, msg));
        }
        let (np, nn) = (self.positions.len() as i64, self.normals.len() as i64);
        for f in &self.faces {
            for c in &f.corners {
                if c.position > np {
                    return Err(self.err(
                        f.line,
                        format!("vertex index {} out of range (file has {np})", c.position),
                    ));
                }
                if c.normal > nn {
                    return Err(self.err(
                        f.line,
                        format!("normal index {} out of range (file has {nn})", c.normal),
                    ));
                }
            }
        }
        let (max_vt, vt_line) = self.max_texcoord_ref;
        if max_vt > self.texcoords {
            self.warnings.push(format!(
                "{}:{vt_line}: texture index {max_vt} out of range (file has {}); ignored, raylab uses no texture coordinates",
                path.display(),
                self.texcoords
            ));
        }
        if self.short_faces > 0 {
            self.warnings.push(format!(
                "{}: skipped {} faces of fewer than 3 vertices (loose edges, as Blender 2.6x exports them)",
                path.display(),
                self.short_faces
            ));
        }
        if self.lines_and_points > 0 {
            self.warnings.push(format!(
                "{}: ignored {} line and point records (l, p): they are not surfaces",
                path.display(),
                self.lines_and_points
            ));
        }

        // One output vertex per distinct (position, normal) pair when any corner
        // has a normal; otherwise the positions as they are.
        let any_normals = self
            .faces
            .iter()
            .flat_map(|f| &f.corners)
            .any(|c| c.normal > 0);
        let mut positions = Vec::new();
        let mut normals = Vec::new();
        let mut vertex_of: HashMap<(i64, i64), u32> = HashMap::new();
        if !any_normals {
            positions = std::mem::take(&mut self.positions);
        }
        let grey = self.materials.len() as u32;
        let mut unnamed = 0usize;
        let mut triangles = Vec::new();
        let mut material_ids = Vec::new();
        let mut triangulator = polygon::FaceTriangulator::default();
        for f in &self.faces {
            let ids: Vec<u32> = f
                .corners
                .iter()
                .map(|c| {
                    if !any_normals {
                        return (c.position - 1) as u32;
                    }
                    *vertex_of.entry((c.position, c.normal)).or_insert_with(|| {
                        positions.push(self.positions[(c.position - 1) as usize]);
                        normals.push(if c.normal > 0 {
                            self.normals[(c.normal - 1) as usize]
                        } else {
                            Vec3::ZERO
                        });
                        (positions.len() - 1) as u32
                    })
                })
                .collect();
            let added = triangulator.face(&positions, &ids, &mut triangles);
            let material = f.material.unwrap_or(grey);
            if f.material.is_none() {
                unnamed += added;
            }
            material_ids.extend(std::iter::repeat_n(material, added));
        }
        if triangulator.huge_faces > 0 {
            self.warnings
                .push(huge_faces_warning(path, triangulator.huge_faces));
        }
        if unnamed > 0 && grey > 0 {
            self.warnings.push(format!(
                "{}: {unnamed} triangles name no known material; using default grey",
                path.display()
            ));
        }
        let mut materials = std::mem::take(&mut self.materials);
        materials.push(Material::default_grey());
        Scene::from_file(
            path,
            positions,
            any_normals.then_some(normals),
            triangles,
            material_ids,
            materials,
            self.warnings,
        )
    }
}

/// The warning for `count` concave faces too large to ear-clip, fanned.
pub(crate) fn huge_faces_warning(path: &Path, count: usize) -> String {
    format!(
        "{}: {count} concave faces of more than {} corners fanned, not ear-clipped (its time grows with the square of the corners); they may be covered wrongly",
        path.display(),
        polygon::MAX_EAR_CLIPPED
    )
}

/// The file's lines, ended by `\n`, `\r\n` or a lone `\r`: classic Mac OS
/// exporters end OBJ and MTL lines with `\r` alone, and `str::lines` would
/// read such a file as one line.
fn physical_lines(text: &str) -> impl Iterator<Item = &str> + '_ {
    let mut rest = text;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let Some(end) = rest.find(['\n', '\r']) else {
            return Some(std::mem::take(&mut rest));
        };
        let line = &rest[..end];
        let skip = if rest[end..].starts_with("\r\n") {
            2
        } else {
            1
        };
        rest = &rest[end + skip..];
        Some(line)
    })
}

/// The file's records with their 1-based line numbers: a line ending in `\`
/// continues on the next one (the record keeps the first line's number).
fn logical_lines(text: &str) -> impl Iterator<Item = (usize, String)> + '_ {
    let mut lines = physical_lines(text).enumerate();
    std::iter::from_fn(move || {
        let (n, first) = lines.next()?;
        let mut record = String::from(first);
        while record.trim_end().ends_with('\\') {
            let keep = record.trim_end().len() - 1;
            record.truncate(keep);
            record.push(' ');
            match lines.next() {
                Some((_, next)) => record.push_str(next),
                None => break,
            }
        }
        Some((n + 1, record))
    })
}

/// A finite f32 of a `key` record.
fn number(w: &str, key: &str) -> std::result::Result<f32, String> {
    let x: f32 = w
        .parse()
        .map_err(|_| format!("'{key}' record: '{w}' is not a number"))?;
    if !x.is_finite() {
        return Err(format!("'{key}' record: coordinate '{w}' is not finite"));
    }
    Ok(x)
}

/// The longest material library read: a hand-written or exported MTL is
/// kilobytes; this only keeps a hostile reference from filling memory.
const MTL_CAP: u64 = 64 << 20;

/// The files of an `mtllib` record: the whole rest of the line when a file of
/// that name exists (names with spaces), else its words.
fn mtl_names(rest: &str, refs: &Refs) -> Vec<String> {
    if rest.contains(char::is_whitespace) && refs.resolve(rest).is_ok_and(|p| p.is_file()) {
        return vec![rest.to_string()];
    }
    rest.split_whitespace().map(str::to_string).collect()
}

/// Reads the MTL values raylab uses, and warnings about what it skipped. Colours
/// take one or three non-negative numbers. The ambient reflectance is `Ka`, or
/// `Kd` where `Ka` is absent or zero (Blender writes `Ka 0 0 0`, which would
/// switch AO off), so AO has an ambient term to darken. A `newmtl` without a
/// name is a warning, and the values under it are ignored.
pub fn parse_mtl(text: &str, path: &Path) -> Result<(Vec<Material>, Vec<String>)> {
    let err = |line: usize, msg: String| Error::Parse {
        path: PathBuf::from(path),
        line,
        msg,
    };
    let mut out: Vec<Material> = Vec::new();
    let mut warnings = Vec::new();
    // Under a nameless newmtl: its values go nowhere.
    let mut skipping = false;
    for (line_no, raw) in logical_lines(text) {
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        if key == "newmtl" {
            let name = line["newmtl".len()..].trim();
            skipping = name.is_empty();
            if skipping {
                warnings.push(format!(
                    "{}:{line_no}: newmtl without a name; its values are ignored",
                    path.display()
                ));
                continue;
            }
            out.push(Material {
                name: name.to_string(),
                ka: Vec3::ZERO,
                kd: Vec3::splat(0.8),
                ks: Vec3::ZERO,
                ns: 10.0,
                ke: Vec3::ZERO,
            });
            continue;
        }
        if !matches!(key, "Ka" | "Kd" | "Ks" | "Ke" | "Ns") || skipping {
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
            if key == "Ns" && x.is_finite() && x < 0.0 {
                // Blender 2.79 wrote negative exponents (Ns -1.960784); the
                // MTL is advisory, and tinyobjloader and Blender read them,
                // so clamp to 0 (no highlight) and say so.
                warnings.push(format!(
                    "{}:{line_no}: 'Ns' {w} is negative; read as 0",
                    path.display()
                ));
                values.push(0.0);
                continue;
            }
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
            "Ka" => mat.ka = colour,
            "Kd" => mat.kd = colour,
            "Ks" => mat.ks = colour,
            _ => mat.ke = colour,
        }
    }
    for m in &mut out {
        if m.ka == Vec3::ZERO {
            m.ka = m.kd;
        }
    }
    Ok((out, warnings))
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
    fn the_most_negative_index_is_an_error_not_an_overflow() {
        let e = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("fixture.obj:4:") && e.contains("before the first"),
            "{e}"
        );
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

    #[test]
    fn lines_may_end_in_cr_alone_or_crlf() {
        // Classic Mac OS exporters end lines with CR alone; error lines are
        // counted the same way.
        for nl in ["\r", "\r\n", "\n"] {
            let text = [
                "v 0 0 0", "v 1 0 0", "v 0 1 0", "", "f 1 2 3", "f 1 2 9", "",
            ]
            .join(nl);
            let e = error_of(&text);
            assert!(e.starts_with("fixture.obj:6:"), "{nl:?}: {e}");
            let s = load(&text.replace("f 1 2 9", "v 1 1 0")).unwrap();
            assert_eq!(s.triangle_count(), 1, "{nl:?}");
        }
        let s = load("v 0 0 0\rv 1 0 0\r\nv 0 1 0\nf 1 2 3").unwrap();
        assert_eq!(s.triangle_count(), 1);
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
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\n");
        assert!(
            e.contains(":4:") && e.contains("normal index 1 out of range"),
            "{e}"
        );
    }

    #[test]
    fn unused_texture_indices_out_of_range_are_a_warning() {
        let s = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/7\n").unwrap();
        assert_eq!(s.triangle_count(), 1);
        assert!(
            s.warnings
                .iter()
                .any(|w| w.contains(":4: texture index 7 out of range")),
            "{:?}",
            s.warnings
        );
    }

    #[test]
    fn two_vertex_faces_are_skipped_with_one_counted_warning() {
        // Blender 2.6x wrote loose edges as 2-vertex faces.
        let s = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 2 3\nf 1 2 3\nf 3\n").unwrap();
        assert_eq!(s.triangle_count(), 1);
        let w: Vec<_> = s
            .warnings
            .iter()
            .filter(|w| w.contains("fewer than 3"))
            .collect();
        assert_eq!(w.len(), 1, "{:?}", s.warnings);
        assert!(w[0].contains("skipped 3 faces"), "{w:?}");
    }

    #[test]
    fn lines_and_points_never_become_triangles() {
        let s = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nl 1 2 3 4\np 1 2 3\nf 1 2 3\n").unwrap();
        assert_eq!(s.triangle_count(), 1);
        assert!(s
            .warnings
            .iter()
            .any(|w| w.contains("2 line and point records")));
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\n");
        assert!(e.contains("no faces of 3 or more vertices"), "{e}");
    }

    #[test]
    fn concave_polygons_are_ear_clipped_not_fanned() {
        // A U whose fan from vertex 1 would cover the notch.
        let u = "v 0 0 0\nv 3 0 0\nv 3 3 0\nv 2 3 0\nv 2 1 0\nv 1 1 0\nv 1 3 0\nv 0 3 0\nf 1 2 3 4 5 6 7 8\n";
        let s = load(u).unwrap();
        assert_eq!(s.triangle_count(), 6);
        let area: f32 = (0..6)
            .map(|i| crate::geometry::triangle_area(&s.triangle(i)))
            .sum();
        assert!((area - 7.0).abs() < 1e-5, "{area}");
    }

    #[test]
    fn a_face_without_normals_leaves_the_others_their_normals() {
        let s = load(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\n\
             f 1//1 2//1 3//1\nf 2 4 3\n",
        )
        .unwrap();
        assert_eq!(s.triangle_count(), 2);
        assert_eq!(s.shading_normal(0, 0.2, 0.2), Some(Vec3::Z));
        assert_eq!(s.shading_normal(1, 0.2, 0.2), None);
    }

    #[test]
    fn backslash_continues_a_record() {
        let s = load("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 \\\n  4 3\n").unwrap();
        assert_eq!(s.triangle_count(), 2);
        let e = error_of("v 0 0 \\\n0\nv 1 x 0\n");
        assert!(e.starts_with("fixture.obj:3:"), "{e}");
    }

    #[test]
    fn malformed_faces_are_rejected() {
        let e = error_of("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n");
        assert!(e.contains("malformed face index"), "{e}");
    }

    #[test]
    fn no_triangles_is_an_error() {
        assert!(error_of("v 0 0 0\n").contains("a point cloud (1 vertices, no faces)"));
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
        let (m, _) = parse_mtl(
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
        // Blender's Ka 0 0 0 means "none": the ambient term uses Kd.
        let (m, _) = parse_mtl("newmtl b\nKa 0 0 0\nKd 0.5 0.4 0.3\n", Path::new("x.mtl")).unwrap();
        assert_eq!(m[0].ka, Vec3::new(0.5, 0.4, 0.3));
    }

    #[test]
    fn blenders_negative_ns_is_clamped_with_a_warning() {
        let (m, w) = parse_mtl("newmtl a\nNs -1.960784\nKd 1 1 1\n", Path::new("x.mtl")).unwrap();
        assert_eq!(m[0].ns, 0.0);
        assert_eq!(w.len(), 1);
        assert!(
            w[0].starts_with("x.mtl:2: 'Ns' -1.960784 is negative"),
            "{w:?}"
        );
        // Other negatives still name their line.
        let e = parse_mtl("newmtl a\nKd -1 1 1\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().starts_with("x.mtl:2:"), "{e}");
    }

    #[test]
    fn a_repeated_mtllib_is_read_once() {
        let dir = std::env::temp_dir().join(format!("raylab-mtllib-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("m.mtl"),
            "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n",
        )
        .unwrap();
        let text = "mtllib m.mtl\n".repeat(10_000)
            + "mtllib ./m.mtl\nusemtl blue\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let s = load_obj_str(&text, Path::new("r.obj"), &dir);
        std::fs::remove_dir_all(&dir).ok();
        let s = s.unwrap();
        // red, blue and the default grey.
        assert_eq!(s.materials.len(), 3);
        assert_eq!(s.material_of(0).name, "blue");
    }

    #[test]
    fn malformed_mtl_names_its_line() {
        let e = parse_mtl("newmtl a\nKd 0.5 0.5\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().starts_with("x.mtl:2:"), "{e}");
        let e = parse_mtl("Kd 1 1 1\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().contains("before any newmtl"), "{e}");
        let e = parse_mtl("newmtl a\nKe nan 1 1\n", Path::new("x.mtl")).unwrap_err();
        assert!(e.to_string().contains("finite"), "{e}");
        // A nameless newmtl is skipped with its values, with a warning.
        let (m, w) = parse_mtl("newmtl\nKd 1 1 1\nnewmtl b\nKd 0.5\n", Path::new("x.mtl")).unwrap();
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].kd, Vec3::splat(0.5));
        assert!(
            w[0].starts_with("x.mtl:1:") && w[0].contains("without a name"),
            "{w:?}"
        );
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
