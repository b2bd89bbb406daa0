//! glTF 2.0 loading (`.gltf` with external or embedded base64 buffers, `.glb`)
//! through the gltf crate, flattened into the scene's arrays: every node of the
//! default scene (or the first; every root node if the file has no scene) is
//! walked with its transform, and every mesh it instances becomes triangles in
//! world space, once per instance. TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN
//! primitives are read; points and lines are counted and skipped. A node whose
//! transform mirrors (negative determinant) has its winding reversed, as the
//! glTF specification says, so one-sided emitters still face the right way.
//!
//! Materials carry what raylab shades with: `baseColorFactor` as Kd (and Ka),
//! `emissiveFactor` times `KHR_materials_emissive_strength` as Ke. Textures are
//! not read. A primitive without a material gets the default grey.

use std::collections::HashMap;
use std::path::Path;

use base64::Engine;
use glam::{Mat3, Mat4, Vec3};

use super::refs::{RefPolicy, Refs};
use super::{Material, Scene};
use crate::error::{Error, Result};

/// Loads a glTF file's bytes (JSON or GLB); external buffers are read from
/// `path`'s folder, never outside it.
pub fn load_gltf_bytes(bytes: &[u8], path: &Path) -> Result<Scene> {
    load_gltf_bytes_with(bytes, path, RefPolicy::default())
}

/// [`load_gltf_bytes`], external buffers read where `policy` allows.
pub fn load_gltf_bytes_with(bytes: &[u8], path: &Path, policy: RefPolicy) -> Result<Scene> {
    let err = |msg: String| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    };
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| {
        if is_gltf1(bytes) {
            err(format!("a glTF 1.0 file: {}", super::READS))
        } else if uses_draco(bytes) {
            err("Draco-compressed meshes (KHR_draco_mesh_compression) are not read: raylab reads uncompressed glTF 2.0".into())
        } else {
            err(format!("glTF: {}", first_complaint(&e)))
        }
    })?;
    let buffers = load_buffers(&gltf, path, &Refs::new(path, policy))?;
    check_accessors(&gltf.document, &buffers).map_err(err)?;

    let mut out = Flattened::default();
    let doc = &gltf.document;
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => {
            // No scene: every node that is nobody's child.
            let children: std::collections::HashSet<usize> = doc
                .nodes()
                .flat_map(|n| n.children().map(|c| c.index()).collect::<Vec<_>>())
                .collect();
            doc.nodes()
                .filter(|n| !children.contains(&n.index()))
                .collect()
        }
    };
    for node in roots {
        out.node(&node, Mat4::IDENTITY, &buffers, 0).map_err(err)?;
    }
    if out.triangles.is_empty() {
        let mut msg = "no triangles: nothing to render".to_string();
        if out.skipped_primitives > 0 {
            msg.push_str(&format!(
                " ({} point or line primitives skipped)",
                out.skipped_primitives
            ));
        }
        return Err(err(msg));
    }
    let mut warnings = Vec::new();
    if out.skipped_primitives > 0 {
        warnings.push(format!(
            "{}: skipped {} point and line primitives (not surfaces)",
            path.display(),
            out.skipped_primitives
        ));
    }
    let any_normals = out.normals.iter().any(|n| *n != Vec3::ZERO);
    Scene::from_file(
        path,
        out.positions,
        any_normals.then_some(out.normals),
        out.triangles,
        out.material_ids,
        out.materials,
        warnings,
    )
}

/// Whether `bytes` declare glTF 1.0 (`"version": "1.0"` in the asset, or a
/// version-1 GLB header), which the 2.0 reader cannot read.
fn is_gltf1(bytes: &[u8]) -> bool {
    if bytes.starts_with(b"glTF") && bytes.get(4..8) == Some(&1u32.to_le_bytes()[..]) {
        return true;
    }
    let Some(v) = gltf_json(bytes) else {
        return false;
    };
    // 1.0 files name their version "1.0" (or 1), and key their arrays by id.
    let version = &v["asset"]["version"];
    version.as_str().is_some_and(|s| s.starts_with('1'))
        || version.as_f64() == Some(1.0)
        || v["accessors"].is_object()
        || v["meshes"].is_object()
}

/// Whether the file's JSON lists the Draco extension as used or required.
fn uses_draco(bytes: &[u8]) -> bool {
    let Some(v) = gltf_json(bytes) else {
        return false;
    };
    ["extensionsUsed", "extensionsRequired"].iter().any(|k| {
        v[k].as_array()
            .is_some_and(|a| a.iter().any(|e| e == "KHR_draco_mesh_compression"))
    })
}

/// The JSON of a .gltf, or of a .glb's first chunk.
fn gltf_json(bytes: &[u8]) -> Option<serde_json::Value> {
    let json = if bytes.starts_with(b"glTF") {
        let len = u32::from_le_bytes(bytes.get(12..16)?.try_into().ok()?) as usize;
        bytes.get(20..20usize.checked_add(len)?)?
    } else {
        bytes
    };
    serde_json::from_slice(json).ok()
}

/// The gltf crate's message, cut to its first complaint: its validation lists
/// every failing field, hundreds for one missing extension.
fn first_complaint(e: &gltf::Error) -> String {
    let text = e.to_string();
    let parts: Vec<&str> = text.split("; ").filter(|p| !p.trim().is_empty()).collect();
    match parts.len() {
        0 | 1 => text.trim_end_matches(';').to_string(),
        n => format!("{} (and {} more problems)", parts[0], n - 1),
    }
}

/// Every buffer's bytes: the GLB's binary chunk, a base64 data URI, or a file
/// beside the glTF (its first `byteLength` bytes, read as [`Refs`] allows).
///
/// Images are not read (raylab reads no textures), so their URIs are never
/// opened.
fn load_buffers(gltf: &gltf::Gltf, path: &Path, refs: &Refs) -> Result<Vec<Vec<u8>>> {
    let err = |msg: String| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    };
    let mut out = Vec::new();
    for buffer in gltf.document.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => gltf.blob.clone().ok_or_else(|| {
                err(format!(
                    "buffer {} names a GLB binary chunk the file lacks",
                    buffer.index()
                ))
            })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                let (_, payload) = uri.split_once(";base64,").ok_or_else(|| {
                    err(format!(
                        "buffer {}: a data URI that is not base64",
                        buffer.index()
                    ))
                })?;
                base64::engine::general_purpose::STANDARD
                    .decode(payload)
                    .map_err(|e| err(format!("buffer {}: bad base64 data: {e}", buffer.index())))?
            }
            gltf::buffer::Source::Uri(uri) => {
                // Named as written (quoted: one line whatever it holds);
                // decoded before the folder rule, so %2e%2e%2f is ../ there.
                refs.read_prefix(&percent_decode(uri), buffer.length() as u64)
                    .map_err(|e| err(format!("buffer {} {uri:?}: {e}", buffer.index())))?
            }
        };
        // The file's own bytes (GLB chunk, data URI): their count is the
        // scene's, and worth telling.
        if data.len() < buffer.length() {
            return Err(err(format!(
                "buffer {} has {} bytes, the file says {}",
                buffer.index(),
                data.len(),
                buffer.length()
            )));
        }
        out.push(data);
    }
    Ok(out)
}

/// Whether all of `a`'s data lies in the glTF file itself (its GLB chunk or a
/// data URI), whose values an error message may show; values read from a
/// file beside it are not shown (with `--allow-outside-refs` that file could
/// be any file of the user's).
fn in_scene_file(a: &gltf::Accessor) -> bool {
    let own = |v: &gltf::buffer::View| match v.buffer().source() {
        gltf::buffer::Source::Bin => true,
        gltf::buffer::Source::Uri(uri) => uri.starts_with("data:"),
    };
    a.view().is_none_or(|v| own(&v)) && a.sparse().is_none()
}

/// `%20`-style escapes in a relative URI.
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            let hex = std::str::from_utf8(&bytes[i + 1..i + 3]).unwrap_or("");
            if let Ok(b) = u8::from_str_radix(hex, 16) {
                out.push(b);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Every accessor's elements lie inside its buffer view and every view inside
/// its buffer, so reading them cannot run past the data.
fn check_accessors(doc: &gltf::Document, buffers: &[Vec<u8>]) -> std::result::Result<(), String> {
    for view in doc.views() {
        let end = view.offset().checked_add(view.length());
        if end.is_none_or(|e| e > buffers[view.buffer().index()].len()) {
            return Err(format!("buffer view {} runs past its buffer", view.index()));
        }
    }
    for a in doc.accessors() {
        let (Some(view), count) = (a.view(), a.count()) else {
            continue;
        };
        if count == 0 {
            continue;
        }
        let stride = view.stride().unwrap_or(a.size());
        let end = stride
            .checked_mul(count - 1)
            .and_then(|x| x.checked_add(a.offset()))
            .and_then(|x| x.checked_add(a.size()));
        if end.is_none_or(|e| e > view.length()) {
            return Err(format!("accessor {} runs past its buffer view", a.index()));
        }
    }
    Ok(())
}

/// The flattened geometry, gathered node by node.
#[derive(Default)]
struct Flattened {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    material_ids: Vec<u32>,
    materials: Vec<Material>,
    /// glTF material index (None: the default) -> index into `materials`.
    material_of: HashMap<Option<usize>, u32>,
    skipped_primitives: usize,
}

/// Node nesting deeper than this is taken for a cycle (the format forbids them).
const MAX_DEPTH: usize = 256;

impl Flattened {
    fn node(
        &mut self,
        node: &gltf::Node,
        parent: Mat4,
        buffers: &[Vec<u8>],
        depth: usize,
    ) -> std::result::Result<(), String> {
        if depth > MAX_DEPTH {
            return Err(format!(
                "node {} is nested over {MAX_DEPTH} deep (a cycle?)",
                node.index()
            ));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                self.primitive(&prim, world, buffers)?;
            }
        }
        for child in node.children() {
            self.node(&child, world, buffers, depth + 1)?;
        }
        Ok(())
    }

    fn primitive(
        &mut self,
        prim: &gltf::Primitive,
        world: Mat4,
        buffers: &[Vec<u8>],
    ) -> std::result::Result<(), String> {
        use gltf::mesh::Mode;
        if !matches!(
            prim.mode(),
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            self.skipped_primitives += 1;
            return Ok(());
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
        let Some(positions) = reader.read_positions() else {
            self.skipped_primitives += 1;
            return Ok(());
        };
        let base = self.positions.len() as u32;
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        let count = positions.len();
        self.positions
            .extend(positions.map(|p| world.transform_point3(Vec3::from_array(p))));
        match reader.read_normals() {
            Some(normals) if normals.len() == count => self
                .normals
                .extend(normals.map(|n| (normal_matrix * Vec3::from_array(n)).normalize_or_zero())),
            _ => self.normals.extend(std::iter::repeat_n(Vec3::ZERO, count)),
        }
        let indices: Vec<u32> = match reader.read_indices() {
            Some(ix) => ix.into_u32().collect(),
            None => (0..count as u32).collect(),
        };
        if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
            // The value only when it is the scene file's own (see in_scene_file).
            let (accessor, value) = match prim.indices() {
                Some(a) if in_scene_file(&a) => (a.index().to_string(), format!(" {bad}")),
                Some(a) => (a.index().to_string(), String::new()),
                None => ("?".into(), String::new()),
            };
            return Err(format!(
                "accessor {accessor}: mesh primitive index{value} out of range ({count} vertices)"
            ));
        }
        let mirrored = world.determinant() < 0.0;
        let material = self.material(&prim.material());
        let mut push = |a: u32, b: u32, c: u32| {
            let t = if mirrored { [a, c, b] } else { [a, b, c] };
            self.triangles.push(t.map(|i| base + i));
            self.material_ids.push(material);
        };
        match prim.mode() {
            Mode::Triangles => {
                for t in indices.chunks_exact(3) {
                    push(t[0], t[1], t[2]);
                }
            }
            Mode::TriangleStrip => {
                for i in 2..indices.len() {
                    // Every other triangle of a strip turns the other way.
                    if i % 2 == 0 {
                        push(indices[i - 2], indices[i - 1], indices[i]);
                    } else {
                        push(indices[i - 1], indices[i - 2], indices[i]);
                    }
                }
            }
            _ => {
                for i in 2..indices.len() {
                    push(indices[0], indices[i - 1], indices[i]);
                }
            }
        }
        Ok(())
    }

    fn material(&mut self, m: &gltf::Material) -> u32 {
        if let Some(&id) = self.material_of.get(&m.index()) {
            return id;
        }
        let mat = match m.index() {
            None => Material::default_grey(),
            Some(i) => {
                let [r, g, b, _] = m.pbr_metallic_roughness().base_color_factor();
                let kd = Vec3::new(r, g, b);
                let ke =
                    Vec3::from_array(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
                Material {
                    name: m
                        .name()
                        .map_or_else(|| format!("material {i}"), str::to_string),
                    ka: kd,
                    kd,
                    ks: Vec3::ZERO,
                    ns: 10.0,
                    ke,
                }
            }
        };
        let id = self.materials.len() as u32;
        self.materials.push(mat);
        self.material_of.insert(m.index(), id);
        id
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The binary buffer of the fixtures: 4 positions (a unit square in z = 0),
    /// then 6 u16 indices (two triangles), then 4 u16 strip indices.
    fn fixture_buffer() -> Vec<u8> {
        let mut b = Vec::new();
        for p in [
            [0f32, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ] {
            for x in p {
                b.extend(x.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2, 0, 2, 3, 0, 1, 3, 2] {
            b.extend(i.to_le_bytes());
        }
        b
    }

    /// A glTF document over `fixture_buffer()` (`buffer_uri` None: the GLB chunk):
    /// one mesh instanced by two nodes (translated by 5 and 10 in x; the second
    /// a child of a node scaling by (-1, 1, 1), which mirrors it), a strip mesh,
    /// a points primitive, and an emissive material with an emissive strength.
    fn fixture_json(buffer_uri: Option<&str>) -> String {
        let uri = buffer_uri.map_or(String::new(), |u| format!(r#""uri":"{u}","#));
        format!(
            r#"{{"asset":{{"version":"2.0"}},
            "extensionsUsed":["KHR_materials_emissive_strength"],
            "scene":0,
            "scenes":[{{"nodes":[0,1,3]}}],
            "nodes":[
              {{"mesh":0,"translation":[5,0,0]}},
              {{"scale":[-1,1,1],"children":[2]}},
              {{"mesh":0,"translation":[10,0,0]}},
              {{"mesh":1,"translation":[0,0,-3]}}
            ],
            "meshes":[
              {{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}},
                              {{"attributes":{{"POSITION":0}},"mode":0}}]}},
              {{"primitives":[{{"attributes":{{"POSITION":0}},"indices":2,"mode":5}}]}}
            ],
            "materials":[{{"name":"lamp","pbrMetallicRoughness":{{"baseColorFactor":[0.2,0.4,0.6,1]}},
              "emissiveFactor":[1,0.5,0.25],"extensions":{{"KHR_materials_emissive_strength":{{"emissiveStrength":4}}}}}}],
            "buffers":[{{{uri}"byteLength":68}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},
                           {{"buffer":0,"byteOffset":48,"byteLength":12}},
                           {{"buffer":0,"byteOffset":60,"byteLength":8}}],
            "accessors":[
              {{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
              {{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}},
              {{"bufferView":2,"componentType":5123,"count":4,"type":"SCALAR"}}
            ]}}"#
        )
    }

    /// A GLB container of `json` and `bin`.
    pub fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        let mut j = json.as_bytes().to_vec();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut b = bin.to_vec();
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
        let total = 12 + 8 + j.len() + 8 + b.len();
        let mut out = Vec::new();
        out.extend(b"glTF");
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((j.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(j);
        out.extend((b.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(b);
        out
    }

    fn check_fixture_scene(s: &Scene) {
        // Two instances of the 2-triangle mesh and a 4-index strip (2 triangles).
        assert_eq!(s.triangle_count(), 6, "{:?}", s.warnings);
        let bounds = s.bounds();
        assert_eq!(bounds.min, Vec3::new(-11.0, 0.0, -3.0));
        assert_eq!(bounds.max, Vec3::new(6.0, 1.0, 0.0));
        // Instance one is translated, the mirrored one keeps facing +z by winding.
        for t in 0..4 {
            let n = crate::geometry::triangle_unit_normal(&s.triangle(t));
            assert_eq!(n, Vec3::Z, "triangle {t}");
        }
        // Both strip triangles face the same way.
        let n4 = crate::geometry::triangle_unit_normal(&s.triangle(4));
        let n5 = crate::geometry::triangle_unit_normal(&s.triangle(5));
        assert_eq!(n4, n5);
        let lamp = s.material_of(0);
        assert_eq!(lamp.name, "lamp");
        assert_eq!(lamp.kd, Vec3::new(0.2, 0.4, 0.6));
        assert_eq!(lamp.ke, Vec3::new(4.0, 2.0, 1.0));
        assert_eq!(s.lights.triangles.len(), 4);
        assert_eq!(*s.material_of(4), Material::default_grey());
        assert!(
            s.warnings
                .iter()
                .any(|w| w.contains("skipped 2 point and line primitives")),
            "{:?}",
            s.warnings
        );
    }

    #[test]
    fn glb_with_instances_transforms_and_emission_is_flattened() {
        let bytes = glb(&fixture_json(None), &fixture_buffer());
        let s = load_gltf_bytes(&bytes, Path::new("fixture.glb")).unwrap();
        check_fixture_scene(&s);
    }

    #[test]
    fn gltf_with_embedded_and_external_buffers_gives_the_same_scene() {
        let data = base64::engine::general_purpose::STANDARD.encode(fixture_buffer());
        let uri = format!("data:application/octet-stream;base64,{data}");
        let s = load_gltf_bytes(
            fixture_json(Some(&uri)).as_bytes(),
            Path::new("fixture.gltf"),
        )
        .unwrap();
        check_fixture_scene(&s);

        let dir = std::env::temp_dir().join(format!("raylab-gltf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("my mesh.bin"), fixture_buffer()).unwrap();
        let path = dir.join("external.gltf");
        let external = load_gltf_bytes(fixture_json(Some("my%20mesh.bin")).as_bytes(), &path);
        let missing = load_gltf_bytes(fixture_json(Some("gone.bin")).as_bytes(), &path);
        std::fs::remove_dir_all(&dir).ok();
        check_fixture_scene(&external.unwrap());
        let e = missing.unwrap_err().to_string();
        assert!(e.contains("external.gltf") && e.contains("gone.bin"), "{e}");
    }

    #[test]
    fn malformed_gltf_is_one_line_naming_the_file() {
        let short = glb(&fixture_json(None), &fixture_buffer()[..40]);
        let e = load_gltf_bytes(&short, Path::new("short.glb"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("short.glb") && e.contains("buffer 0 has"),
            "{e}"
        );
        let past = fixture_json(None).replace(
            r#""byteOffset":60,"byteLength":8"#,
            r#""byteOffset":64,"byteLength":8"#,
        );
        let e = load_gltf_bytes(&glb(&past, &fixture_buffer()), Path::new("p.glb"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("runs past"), "{e}");
        for bad in [&b"{ not json"[..], b"glTF\x02\0\0\0\x10\0\0\0"] {
            let e = load_gltf_bytes(bad, Path::new("b.gltf"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("b.gltf: glTF"), "{e}");
            assert_eq!(e.lines().count(), 1, "{e}");
        }
    }

    #[test]
    fn gltf_1_is_named() {
        let v1 = r#"{"asset":{"version":"1.0"},"meshes":{"m":{}}}"#;
        let e = load_gltf_bytes(v1.as_bytes(), Path::new("old.gltf"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a glTF 1.0 file") && e.contains("glTF 2.0"),
            "{e}"
        );
    }

    #[test]
    fn percent_escapes_are_decoded() {
        assert_eq!(percent_decode("my%20mesh.bin"), "my mesh.bin");
        assert_eq!(percent_decode("plain.bin"), "plain.bin");
        assert_eq!(percent_decode("odd%2"), "odd%2");
        assert_eq!(percent_decode("é%"), "é%");
    }
}
