//! PLY loading (ASCII, binary little- and big-endian) through the ply-rs-bw
//! crate, read straight into raylab's own vertex and face records: `x y z` of
//! any numeric type, optional `nx ny nz` normals, and faces as a
//! `vertex_indices` (or `vertex_index`) list of any length and integer type,
//! triangulated like OBJ polygons ([`super::polygon`]). Other elements and
//! properties (colours, edges, materials) are read past and ignored.
//!
//! Contract: a valid [`Scene`] (every triangle the default grey) or an
//! [`Error`] naming the file and, where the parser gives one, the line. A PLY
//! without faces is a point cloud, and says so.

use std::io::BufReader;
use std::path::Path;

use glam::Vec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{Property, PropertyAccess, PropertyAccessResult};

use super::{polygon, Material, Scene};
use crate::error::{Error, Result};

#[derive(Default)]
struct PlyVertex {
    position: [f64; 3],
    normal: [f64; 3],
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let slot = match name {
            "x" => &mut self.position[0],
            "y" => &mut self.position[1],
            "z" => &mut self.position[2],
            "nx" => &mut self.normal[0],
            "ny" => &mut self.normal[1],
            "nz" => &mut self.normal[2],
            _ => return PropertyAccessResult::Ignored,
        };
        match scalar(&property) {
            Some(x) => {
                *slot = x;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

#[derive(Default)]
struct PlyFace {
    indices: Vec<i64>,
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if !is_index_list(name) {
            return PropertyAccessResult::Ignored;
        }
        self.indices = match property {
            Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// An element raylab does not read (edges, materials, ...): read past.
struct Skipped;

impl PropertyAccess for Skipped {
    fn new() -> Self {
        Skipped
    }
}

fn is_index_list(name: &str) -> bool {
    matches!(name, "vertex_indices" | "vertex_index")
}

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(x) => x.into(),
        Property::UChar(x) => x.into(),
        Property::Short(x) => x.into(),
        Property::UShort(x) => x.into(),
        Property::Int(x) => x.into(),
        Property::UInt(x) => x.into(),
        Property::Float(x) => x.into(),
        Property::Double(x) => x,
        _ => return None,
    })
}

/// Loads a PLY file's bytes; `path` names it in messages.
pub fn load_ply_bytes(bytes: &[u8], path: &Path) -> Result<Scene> {
    let parse_err = |e: ply_rs_bw::parser::ParseError| Error::Parse {
        path: path.to_path_buf(),
        line: e.line().unwrap_or(0),
        // The parser's message can run over several lines (its grammar's
        // expectations): its first line says what went wrong.
        msg: format!(
            "PLY: {}",
            strip_line_prefix(e.to_string().lines().next().unwrap_or("malformed"))
        ),
    };
    let err = |msg: String| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    };
    let (fixed, stray_lines) = header_with_stray_lines_as_comments(bytes);
    let bytes = fixed.as_deref().unwrap_or(bytes);
    let mut reader = Reader::new(BufReader::new(bytes));
    let header = Parser::<PlyVertex>::new()
        .read_header(&mut reader)
        .map_err(parse_err)?;
    let Some(vertex_def) = header.elements.get("vertex") else {
        return Err(err("PLY: no 'vertex' element".into()));
    };
    for axis in ["x", "y", "z"] {
        if !vertex_def.properties.contains_key(axis) {
            return Err(err(format!(
                "PLY: the vertex element has no '{axis}' property"
            )));
        }
    }
    let has_normals = ["nx", "ny", "nz"]
        .iter()
        .all(|n| vertex_def.properties.contains_key(*n));

    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for (name, def) in &header.elements {
        match name.as_str() {
            "vertex" => {
                vertices = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(parse_err)?;
            }
            "face" if def.properties.keys().any(|k| is_index_list(k)) => {
                faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(parse_err)?;
            }
            _ => {
                Parser::<Skipped>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(parse_err)?;
            }
        }
    }
    if faces.is_empty() {
        return Err(err(format!(
            "a point cloud ({} vertices, no faces): nothing to render",
            vertices.len()
        )));
    }

    let mut positions = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let p = Vec3::from_array(v.position.map(|x| x as f32));
        if !p.is_finite() {
            return Err(err(format!("vertex {i} is not finite (or beyond f32)")));
        }
        positions.push(p);
    }
    let normals = has_normals.then(|| {
        vertices
            .iter()
            .map(|v| {
                let n = Vec3::from_array(v.normal.map(|x| x as f32));
                if n.is_finite() {
                    n
                } else {
                    Vec3::ZERO
                }
            })
            .collect()
    });
    // The file's size bounds the faces read; the budget still holds.
    let expands_to: u64 = faces
        .iter()
        .map(|f| f.indices.len().saturating_sub(2) as u64)
        .sum();
    if let Some(msg) = super::budget::triangles_over(expands_to) {
        return Err(err(msg));
    }
    let mut triangles = Vec::with_capacity(faces.len() * 2);
    let mut short_faces = 0usize;
    let mut triangulator = polygon::FaceTriangulator::default();
    let mut ids: Vec<u32> = Vec::new();
    for (fi, f) in faces.iter().enumerate() {
        if f.indices.len() < 3 {
            short_faces += 1;
            continue;
        }
        if let Some(&bad) = f
            .indices
            .iter()
            .find(|&&i| i < 0 || i as usize >= positions.len())
        {
            return Err(err(format!(
                "face {fi}: vertex index {bad} out of range (file has {} vertices)",
                positions.len()
            )));
        }
        // In range (checked above), so they fit u32.
        ids.clear();
        ids.extend(f.indices.iter().map(|&i| i as u32));
        triangulator.face(&positions, &ids, &mut triangles);
    }
    let mut warnings = Vec::new();
    if triangulator.huge_faces > 0 {
        warnings.push(super::obj::huge_faces_warning(
            path,
            triangulator.huge_faces,
        ));
    }
    if stray_lines > 0 {
        warnings.push(format!(
            "{}: {stray_lines} header lines without a keyword read as comments (old Blender exports write them)",
            path.display()
        ));
    }
    if short_faces > 0 {
        warnings.push(format!(
            "{}: skipped {short_faces} faces of fewer than 3 vertices",
            path.display()
        ));
    }
    let count = triangles.len();
    Scene::from_file(
        path,
        positions,
        normals,
        triangles,
        vec![0; count],
        vec![Material::default_grey()],
        warnings,
    )
}

/// Header keywords of the PLY format.
const HEADER_KEYWORDS: &[&str] = &[
    "ply",
    "format",
    "comment",
    "element",
    "property",
    "obj_info",
    "end_header",
];

/// Blender 2.4x wrote "Created by Blender3D ..." as a header line without the
/// `comment` keyword, which the format's grammar refuses. Such lines become
/// comments: returns the mended file (None when nothing needed mending) and how
/// many lines were mended.
fn header_with_stray_lines_as_comments(bytes: &[u8]) -> (Option<Vec<u8>>, usize) {
    let Some(end) = find(bytes, b"end_header") else {
        return (None, 0);
    };
    let Ok(header) = std::str::from_utf8(&bytes[..end]) else {
        return (None, 0);
    };
    let stray = |line: &str| {
        let key = line.split_whitespace().next();
        key.is_some_and(|k| !HEADER_KEYWORDS.contains(&k))
    };
    let count = header.lines().filter(|l| stray(l)).count();
    if count == 0 {
        return (None, 0);
    }
    let mut out = Vec::with_capacity(bytes.len() + 8 * count);
    for line in header.split_inclusive('\n') {
        if stray(line) {
            out.extend_from_slice(b"comment ");
        }
        out.extend_from_slice(line.as_bytes());
    }
    out.extend_from_slice(&bytes[end..]);
    (Some(out), count)
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// The parser's messages start "Line N: " where it knows the line; the line
/// goes into the error's own `path:line:` prefix instead.
fn strip_line_prefix(msg: &str) -> &str {
    match msg.split_once(": ") {
        Some((head, rest)) if head.starts_with("Line ") => rest,
        _ => msg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER_TAIL: &str =
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n";

    /// A unit square as a quad and a triangle over it, with normals, in `encoding`.
    fn square(encoding: &str) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat {encoding} 1.0\ncomment made by raylab's tests\nelement vertex 5\n\
             property float x\nproperty float y\nproperty double z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             property uchar red\n{HEADER_TAIL}"
        )
        .into_bytes();
        let verts: [[f32; 3]; 5] = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.5, 0.5, 1.0],
        ];
        let faces: [&[i32]; 2] = [&[0, 1, 2, 3], &[0, 1, 4]];
        if encoding == "ascii" {
            for v in verts {
                out.extend(format!("{} {} {} 0 0 1 200\n", v[0], v[1], v[2]).bytes());
            }
            for f in faces {
                let idx: Vec<String> = f.iter().map(|i| i.to_string()).collect();
                out.extend(format!("{} {}\n", f.len(), idx.join(" ")).bytes());
            }
            return out;
        }
        let big = encoding == "binary_big_endian";
        let f32b = |x: f32| {
            if big {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            }
        };
        let f64b = |x: f64| {
            if big {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            }
        };
        let i32b = |x: i32| {
            if big {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            }
        };
        for v in verts {
            out.extend(f32b(v[0]));
            out.extend(f32b(v[1]));
            out.extend(f64b(v[2] as f64));
            for n in [0.0, 0.0, 1.0] {
                out.extend(f32b(n));
            }
            out.push(200);
        }
        for f in faces {
            out.push(f.len() as u8);
            for &i in f {
                out.extend(i32b(i));
            }
        }
        out
    }

    #[test]
    fn all_three_encodings_give_the_same_scene() {
        let mut scenes = Vec::new();
        for enc in ["ascii", "binary_little_endian", "binary_big_endian"] {
            let s = load_ply_bytes(&square(enc), Path::new("square.ply")).unwrap();
            assert_eq!(s.triangle_count(), 3, "{enc}");
            assert_eq!(s.positions.len(), 5, "{enc}");
            assert_eq!(s.shading_normal(0, 0.3, 0.3), Some(Vec3::Z), "{enc}");
            scenes.push((s.positions, s.triangles));
        }
        assert_eq!(scenes[0], scenes[1]);
        assert_eq!(scenes[0], scenes[2]);
    }

    #[test]
    fn vertex_index_lists_and_no_normals_are_read() {
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty int x\nproperty int y\nproperty int z\n\
                    element face 1\nproperty list uint short vertex_index\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let s = load_ply_bytes(text.as_bytes(), Path::new("t.ply")).unwrap();
        assert_eq!(s.triangle_count(), 1);
        assert!(s.normals.is_none());
    }

    #[test]
    fn stray_header_lines_of_old_blender_exports_are_comments() {
        let text = "ply\nformat ascii 1.0\nCreated by Blender3D 247 - www.blender.org, source file: \n\
                    element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let s = load_ply_bytes(text.as_bytes(), Path::new("w.ply")).unwrap();
        assert_eq!(s.triangle_count(), 1);
        assert!(
            s.warnings[0].contains("1 header lines without a keyword"),
            "{:?}",
            s.warnings
        );
    }

    #[test]
    fn a_point_cloud_says_so() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 1 1\n";
        let e = load_ply_bytes(text.as_bytes(), Path::new("cloud.ply")).unwrap_err();
        assert!(e.to_string().contains("point cloud (2 vertices"), "{e}");
    }

    #[test]
    fn bad_files_name_the_file_and_what_is_wrong() {
        let bad_index = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                         element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
        let e = load_ply_bytes(bad_index.as_bytes(), Path::new("b.ply"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("b.ply") && e.contains("vertex index 7 out of range"),
            "{e}"
        );
        let mut truncated = square("binary_little_endian");
        truncated.truncate(truncated.len() - 7);
        let e = load_ply_bytes(&truncated, Path::new("t.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.ply") && e.contains("PLY"), "{e}");
        let no_z = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n";
        let e = load_ply_bytes(no_z.as_bytes(), Path::new("z.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no 'z' property"), "{e}");
        let e = load_ply_bytes(
            b"ply\nformat ascii 1.0\nbogus line\nend_header\n",
            Path::new("h.ply"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("h.ply"), "{e}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
}
