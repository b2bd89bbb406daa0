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

/// Loads a glTF file's bytes (JSON or GLB) as stored; external buffers are
/// read from `path`'s folder, never outside it (the unit tests' entry; files
/// load through `gltf_motion::load_still`, which poses skinned and morphed
/// meshes first).
#[cfg(test)]
fn load_gltf_bytes(bytes: &[u8], path: &Path) -> Result<Scene> {
    let (doc, buffers) = read_document(bytes, path, RefPolicy::default())?;
    load_document(&doc, &buffers, path)
}

/// A loaded glTF file: the flattened scene, and what its animations are
/// evaluated on (the document, its buffers, where each placed primitive's
/// vertices went).
pub(super) struct Loaded {
    pub scene: Scene,
    pub doc: gltf::Document,
    pub buffers: Vec<Vec<u8>>,
    pub placements: Vec<Placement>,
}

/// One primitive as placed by one node: its vertices are the scene's
/// `base .. base + count`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Placement {
    pub node: usize,
    pub mesh: usize,
    pub primitive: usize,
    pub base: usize,
    pub count: usize,
}

/// [`load_document`], keeping what animations need: the scene
/// flattened, every placement its own vertices (animations move them).
pub(super) fn load_parts(bytes: &[u8], path: &Path, policy: RefPolicy) -> Result<Loaded> {
    let (doc, buffers) = read_document(bytes, path, policy)?;
    flattened_parts(doc, buffers, path)
}

/// [`load_parts`] on a document already read.
pub(super) fn flattened_parts(
    doc: gltf::Document,
    buffers: Vec<Vec<u8>>,
    path: &Path,
) -> Result<Loaded> {
    let roots = root_nodes(&doc).map_err(|m| parse_error(path, m))?;
    check_budget(&roots).map_err(|m| parse_error(path, m))?;
    let (scene, placements) = flatten(&roots, &buffers, path)?;
    drop(roots);
    Ok(Loaded {
        scene,
        doc,
        buffers,
        placements,
    })
}

/// One line naming the file.
pub(super) fn parse_error(path: &Path, msg: String) -> Error {
    Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    }
}

/// The document, validated, and its buffers, read and checked.
pub(super) fn read_document(
    bytes: &[u8],
    path: &Path,
    policy: RefPolicy,
) -> Result<(gltf::Document, Vec<Vec<u8>>)> {
    let err = |msg: String| parse_error(path, msg);
    // A UTF-8 byte order mark before the JSON: the format says there is
    // none, and JSON readers may ignore one; serde_json does not.
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let gltf = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| {
        if is_gltf1(bytes) {
            err(format!("a glTF 1.0 file: {}", super::READS))
        } else {
            err(format!("glTF: {}", first_complaint(&e)))
        }
    })?;
    let gltf::Gltf { document, blob } = gltf;
    let doc = validated(document.into_json()).map_err(|m| {
        if is_gltf1(bytes) {
            err(format!("a glTF 1.0 file: {}", super::READS))
        } else {
            err(m)
        }
    })?;
    let gltf = gltf::Gltf {
        document: doc,
        blob,
    };
    let buffers = load_buffers(&gltf, path, &Refs::new(path, policy))?;
    check_accessors(&gltf.document, &buffers).map_err(err)?;
    Ok((gltf.document, buffers))
}

/// Every mesh placed by every node, in world space, as one triangle list.
fn flatten(
    roots: &[gltf::Node],
    buffers: &[Vec<u8>],
    path: &Path,
) -> Result<(Scene, Vec<Placement>)> {
    let err = |msg: String| parse_error(path, msg);
    let mut out = Flattened::default();
    for (node, mesh, world) in mesh_nodes(roots).map_err(err)? {
        out.place(&node, &mesh, world, buffers).map_err(err)?;
    }
    if out.triangles.is_empty() {
        return Err(err(no_triangles(out.skipped_primitives)));
    }
    let warnings = skipped_warning(path, out.skipped_primitives, out.partial_primitives);
    let any_normals = out.normals.iter().any(|n| *n != Vec3::ZERO);
    let scene = Scene::from_file(
        path,
        out.positions,
        any_normals.then_some(out.normals),
        out.triangles,
        out.material_ids,
        out.materials,
        warnings,
    )?;
    Ok((scene, out.placements))
}

fn no_triangles(skipped_primitives: usize) -> String {
    let mut msg = "no triangles: nothing to render".to_string();
    if skipped_primitives > 0 {
        msg.push_str(&format!(
            " ({skipped_primitives} point or line primitives skipped)"
        ));
    }
    msg
}

fn skipped_warning(path: &Path, skipped_primitives: usize, partial: usize) -> Vec<String> {
    let mut warnings = Vec::new();
    if skipped_primitives > 0 {
        warnings.push(format!(
            "{}: skipped {skipped_primitives} point and line primitives (not surfaces)",
            path.display()
        ));
    }
    if partial > 0 {
        warnings.push(format!(
            "{}: {partial} triangle primitives have an index count that is not a multiple of 3 (the format asks for whole triangles): their last one or two indices were dropped",
            path.display()
        ));
    }
    warnings
}

/// The nodes that place a mesh, with the mesh and their world transforms (composed
/// down the node tree), depth first with roots and children in order: the
/// order of the flattened triangle list. The node graph is a tree
/// ([`root_nodes`]), so each node is reached once; nesting past
/// [`MAX_DEPTH`] is refused.
fn mesh_nodes<'a>(
    roots: &[gltf::Node<'a>],
) -> std::result::Result<Vec<(gltf::Node<'a>, gltf::Mesh<'a>, Mat4)>, String> {
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = roots
        .iter()
        .rev()
        .map(|n| (n.clone(), Mat4::IDENTITY, 0))
        .collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > MAX_DEPTH {
            return Err(format!(
                "node {} is nested over {MAX_DEPTH} levels deep, past raylab's limit",
                node.index()
            ));
        }
        let world = parent * local_matrix(&node);
        // Children in reverse, so they pop in order.
        let children: Vec<gltf::Node> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|c| (c, world, depth + 1)));
        if let Some(mesh) = node.mesh() {
            out.push((node, mesh, world));
        }
    }
    Ok(out)
}

/// A read glTF file as an instanced scene when a mesh is placed by more
/// than one node (each mesh stored once, in its own space; each node placing
/// it an instance), else flattened as [`load_parts`] does. A file that places
/// a mesh more than once loads as an instanced scene ([`Scene::instanced`]);
/// `--flatten` and the commands that trace one list bake it
/// ([`Scene::flattened`]).
pub(super) fn load_document(
    doc: &gltf::Document,
    buffers: &[Vec<u8>],
    path: &Path,
) -> Result<Scene> {
    Ok(instanced(doc, buffers, path, false)?.0)
}

/// The file `loaded` read as an instanced scene whatever its meshes' uses
/// (each node placing a mesh an instance), and the node of each instance:
/// what a file whose animations move its nodes rigidly is followed as. Its
/// document and buffers as already read, not read again.
pub(super) fn load_placed_instances(loaded: &Loaded, path: &Path) -> Result<(Scene, Vec<usize>)> {
    instanced(&loaded.doc, &loaded.buffers, path, true)
}

/// [`load_document`]'s work: instanced when a mesh is placed more than
/// once or `always`, with the node of each instance (none when flattened).
fn instanced(
    doc: &gltf::Document,
    buffers: &[Vec<u8>],
    path: &Path,
    always: bool,
) -> Result<(Scene, Vec<usize>)> {
    let err = |msg: String| parse_error(path, msg);
    let roots = root_nodes(doc).map_err(err)?;
    // Every node placing a mesh, with its world transform.
    let placed: Vec<(usize, usize, Mat4)> = mesh_nodes(&roots)
        .map_err(err)?
        .into_iter()
        .map(|(node, mesh, world)| (node.index(), mesh.index(), world))
        .collect();
    let mut uses = vec![0usize; doc.meshes().count()];
    for &(_, m, _) in &placed {
        uses[m] += 1;
    }
    if !always && uses.iter().all(|&u| u <= 1) {
        check_budget(&roots).map_err(err)?;
        return Ok((flatten(&roots, buffers, path)?.0, Vec::new()));
    }
    // Budgets: the unique triangles and vertices, and the instances.
    let (mut triangles, mut vertices) = (0u64, 0u64);
    for mesh in doc.meshes().filter(|m| uses[m.index()] > 0) {
        for prim in mesh.primitives() {
            let (t, v) = primitive_size(&prim);
            triangles = triangles.saturating_add(t);
            vertices = vertices.saturating_add(v);
        }
    }
    if let Some(msg) = super::budget::triangles_over(triangles)
        .or_else(|| super::budget::vertices_over(vertices))
        .or_else(|| super::budget::instances_over(placed.len() as u64))
    {
        return Err(err(msg));
    }
    // Each placed mesh once, in its own space, numbered by first placement.
    let mut slot: Vec<Option<u32>> = vec![None; uses.len()];
    let mut meshes = Vec::new();
    let mut skipped_primitives = 0;
    let mut partial_primitives = 0;
    let mut empty = 0;
    let mut placements = Vec::with_capacity(placed.len());
    let mut nodes = Vec::with_capacity(placed.len());
    for &(node, m, world) in &placed {
        if slot[m].is_none() {
            let mesh = doc.meshes().nth(m).expect("a mesh the nodes name");
            let mut out = Flattened::default();
            for prim in mesh.primitives() {
                out.primitive(&prim, Mat4::IDENTITY, buffers).map_err(err)?;
            }
            // Counted as placed, as the flattened file counts them.
            skipped_primitives += out.skipped_primitives * uses[m];
            partial_primitives += out.partial_primitives;
            let any_normals = out.normals.iter().any(|n| *n != Vec3::ZERO);
            // A mesh of points, lines or only degenerate triangles places
            // nothing to trace: its instances are left out.
            let has_area = out.triangles.iter().any(|t| {
                crate::geometry::triangle_unit_normal(&t.map(|i| out.positions[i as usize]))
                    != Vec3::ZERO
            });
            let scene = if has_area {
                let mesh = Scene::new(
                    format!("mesh {m}"),
                    out.positions,
                    any_normals.then_some(out.normals),
                    out.triangles,
                    out.material_ids,
                    out.materials,
                )
                .map_err(|e| match e {
                    Error::Scene { msg, .. } => err(format!("mesh {m}: {msg}")),
                    other => other,
                })?;
                Some(mesh)
            } else {
                None
            };
            match scene {
                Some(scene) => {
                    meshes.push(scene);
                    slot[m] = Some(meshes.len() as u32 - 1);
                }
                None => {
                    empty += 1;
                    slot[m] = Some(u32::MAX);
                }
            }
        }
        match slot[m] {
            Some(u32::MAX) | None => {}
            Some(s) => {
                placements.push((s, glam::Affine3A::from_mat4(world)));
                nodes.push(node);
            }
        }
    }
    if placements.is_empty() {
        return Err(err(no_triangles(skipped_primitives)));
    }
    let mut scene =
        Scene::instanced(path.display().to_string(), meshes, placements).map_err(|e| match e {
            Error::Scene { msg, .. } => err(msg),
            other => other,
        })?;
    let mut warnings = skipped_warning(path, skipped_primitives, partial_primitives);
    if empty > 0 {
        warnings.push(format!(
            "{}: {empty} meshes have no triangles with area: their instances place nothing",
            path.display()
        ));
    }
    warnings.append(&mut scene.warnings);
    scene.warnings = warnings;
    Ok((scene, nodes))
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

/// Extensions raylab reads itself, beyond those the gltf crate knows.
const READ_EXTENSIONS: &[&str] = &[
    // Quantized (integer, normalized or not) POSITION and NORMAL: read by
    // [`read_vec3s`].
    "KHR_mesh_quantization",
];

/// The document checked so that nothing the gltf crate or this reader calls
/// later can panic: every primitive's attributes name accessors that exist
/// (the crate's validation hook indexes them unchecked), every animation
/// channel a node that exists (the crate does not check it), every required
/// extension is one raylab reads (all that are not are named in one line),
/// then the crate's own validation (every index in range, every enum known).
fn validated(mut json: gltf::json::Root) -> std::result::Result<gltf::Document, String> {
    let accessors = json.accessors.len();
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let named = prim.attributes.values().chain(prim.indices.as_ref());
            if let Some(bad) = named.map(|a| a.value()).find(|&a| a >= accessors) {
                return Err(format!(
                    "mesh {m} primitive {p} names accessor {bad}, the file has {accessors}"
                ));
            }
        }
    }
    // Integer POSITION and NORMAL are KHR_mesh_quantization's; without it a
    // file's integer positions are a mistake (floats' bytes read as u8 end
    // as degenerate triangles), named here rather than left to "no
    // triangles". Attribute accessors were checked to exist just above.
    let quantized = json
        .extensions_used
        .iter()
        .chain(&json.extensions_required)
        .any(|e| e == "KHR_mesh_quantization");
    if !quantized {
        if let Some(msg) = unquantized_integer_attribute(&json) {
            return Err(msg);
        }
    }
    // A zero quaternion is no rotation at all: the crate's matrix would read
    // it as the identity, the animation code's normalising as NaN.
    for (n, node) in json.nodes.iter().enumerate() {
        if let Some(q) = &node.rotation {
            let q = glam::Vec4::from(q.0);
            if !(q.length_squared() > 1e-12) {
                return Err(format!(
                    "node {n}: rotation {:?} is not a rotation (glTF requires a unit quaternion)",
                    q.to_array()
                ));
            }
        }
    }
    // glTF allows a matrix or TRS properties, not both. Where a file has
    // both and they agree (an exporter writing the identity TRS beside its
    // matrix), the matrix is the node's transform; where they disagree,
    // which one the author meant is a guess (three.js takes the matrix,
    // others the TRS), so the file is refused rather than drawn one way.
    for (n, node) in json.nodes.iter().enumerate() {
        let Some(matrix) = node.matrix else { continue };
        if node.translation.is_none() && node.rotation.is_none() && node.scale.is_none() {
            continue;
        }
        let trs = Mat4::from_scale_rotation_translation(
            node.scale.unwrap_or([1.0; 3]).into(),
            glam::Quat::from_array(node.rotation.as_ref().map_or([0.0, 0.0, 0.0, 1.0], |q| q.0))
                .normalize(),
            node.translation.unwrap_or([0.0; 3]).into(),
        );
        // Within rounding, measured against each column's largest entry:
        // a rotation's zeros come out of the quaternion near 1e-7, and the
        // scale multiplies its column (a 90-degree turn at scale 100 is a
        // real export).
        let trs = trs.to_cols_array();
        let agree = (0..4).all(|c| {
            let col = 4 * c..4 * c + 4;
            let size = trs[col.clone()]
                .iter()
                .chain(&matrix[col.clone()])
                .fold(1.0f32, |m, v| m.max(v.abs()));
            col.clone()
                .all(|i| (trs[i] - matrix[i]).abs() <= 1e-5 * size)
        });
        if !agree {
            return Err(format!(
                "node {n}: has both a matrix and translation/rotation/scale, and they disagree (glTF allows one or the other)"
            ));
        }
    }
    // The crate checks a channel's sampler but not the node it targets.
    let nodes = json.nodes.len();
    for (a, anim) in json.animations.iter().enumerate() {
        for (c, channel) in anim.channels.iter().enumerate() {
            let node = channel.target.node.value();
            if node >= nodes {
                return Err(format!(
                    "animation {a} channel {c} targets node {node}, the file has {nodes}"
                ));
            }
        }
    }
    let unread: Vec<&str> = json
        .extensions_required
        .iter()
        .map(String::as_str)
        .filter(|e| {
            !gltf::json::extensions::ENABLED_EXTENSIONS.contains(e) && !READ_EXTENSIONS.contains(e)
        })
        .collect();
    if !unread.is_empty() {
        let compressed = unread.iter().any(|e| {
            matches!(
                *e,
                "KHR_draco_mesh_compression"
                    | "EXT_meshopt_compression"
                    | "KHR_meshopt_compression"
            )
        });
        return Err(format!(
            "requires glTF extensions raylab does not read: {}{}",
            unread.join(", "),
            if compressed {
                " (Draco- or meshopt-compressed meshes: raylab reads uncompressed glTF 2.0; e.g. gltfpack without -c, or gltf-transform decompress)"
            } else {
                ""
            }
        ));
    }
    // Read here, so not left for the crate to call unsupported.
    json.extensions_required
        .retain(|e| !READ_EXTENSIONS.contains(&e.as_str()));
    gltf::Document::from_json(json).map_err(|e| format!("glTF: {}", first_complaint(&e)))
}

/// A node's transform relative to its parent. A rotation that is not a
/// unit quaternion to within rounding is normalised first, as the animation
/// code does (the matrix of an unnormalised quaternion also scales and
/// shears); a unit one is used as written, so that the matrix is the one
/// every viewer computes.
fn local_matrix(node: &gltf::Node) -> Mat4 {
    match node.transform() {
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } if (glam::Vec4::from(rotation).length_squared() - 1.0).abs() > 1e-5 => {
            Mat4::from_scale_rotation_translation(
                scale.into(),
                glam::Quat::from_array(rotation).normalize(),
                translation.into(),
            )
        }
        t => Mat4::from_cols_array_2d(&t.matrix()),
    }
}

/// The first POSITION or NORMAL accessor (of a primitive or a morph target)
/// whose components are not FLOAT, as a refusal naming it: core glTF 2.0
/// allows only FLOAT there.
fn unquantized_integer_attribute(json: &gltf::json::Root) -> Option<String> {
    use gltf::json::accessor::{ComponentType, GenericComponentType};
    use gltf::json::validation::Checked;
    use gltf::Semantic;
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let targets = prim.targets.iter().flatten().flat_map(|t| {
                [("POSITION", t.positions), ("NORMAL", t.normals)]
                    .into_iter()
                    .filter_map(|(name, a)| Some((name, a?)))
            });
            let attributes = prim.attributes.iter().filter_map(|(sem, a)| match sem {
                Checked::Valid(Semantic::Positions) => Some(("POSITION", *a)),
                Checked::Valid(Semantic::Normals) => Some(("NORMAL", *a)),
                _ => None,
            });
            for (name, a) in attributes.chain(targets) {
                let Some(accessor) = json.accessors.get(a.value()) else {
                    continue; // named by the checks that follow
                };
                let ty = match accessor.component_type {
                    Checked::Valid(GenericComponentType(ty)) => ty,
                    Checked::Invalid => continue,
                };
                if ty != ComponentType::F32 {
                    return Some(format!(
                        "mesh {m} primitive {p}: {name} accessor {} has {ty:?} components; glTF allows them only with KHR_mesh_quantization, which the file does not declare in extensionsUsed",
                        a.value()
                    ));
                }
            }
        }
    }
    None
}

/// The nodes the scene is made of: the default scene's roots (or the first
/// scene's; every parentless node if there is no scene). The node graph must
/// be a tree, as the format says: a node with two parents (or listed twice by
/// one) would be instanced once per path, 2^40 times from a 1.4 KB file, and
/// a cycle would never end; both are refused here, before any walk.
fn root_nodes(doc: &gltf::Document) -> std::result::Result<Vec<gltf::Node<'_>>, String> {
    let mut parent: Vec<Option<usize>> = vec![None; doc.nodes().count()];
    for node in doc.nodes() {
        for child in node.children() {
            if let Some(other) = parent[child.index()].replace(node.index()) {
                return Err(format!(
                    "node {} is a child of nodes {other} and {}: glTF node graphs must be trees",
                    child.index(),
                    node.index()
                ));
            }
        }
    }
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => doc
            .nodes()
            .filter(|n| parent[n.index()].is_none())
            .collect(),
    };
    let mut listed = vec![false; parent.len()];
    for root in &roots {
        if let Some(p) = parent[root.index()] {
            return Err(format!(
                "the scene lists node {} as a root, but it is a child of node {p}: glTF node graphs must be trees",
                root.index()
            ));
        }
        if std::mem::replace(&mut listed[root.index()], true) {
            return Err(format!(
                "the scene lists node {} twice: glTF node graphs must be trees",
                root.index()
            ));
        }
    }
    // With one parent at most and parentless roots, a cycle cannot be reached
    // from a root; so the walk from the roots visits each node once.
    Ok(roots)
}

/// Counts the triangles and vertices the scene will expand to (each mesh
/// once per node instancing it) and refuses it past the budget, before
/// anything is read or allocated.
fn check_budget(roots: &[gltf::Node]) -> std::result::Result<(), String> {
    let (mut triangles, mut vertices) = (0u64, 0u64);
    let mut stack: Vec<gltf::Node> = roots.to_vec();
    while let Some(node) = stack.pop() {
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                let (t, v) = primitive_size(&prim);
                triangles = triangles.saturating_add(t);
                vertices = vertices.saturating_add(v);
            }
        }
        stack.extend(node.children());
    }
    match super::budget::triangles_over(triangles) {
        Some(msg) => Err(msg),
        None => super::budget::vertices_over(vertices).map_or(Ok(()), Err),
    }
}

/// The triangles and vertices one instance of `prim` adds (0, 0 for points
/// and lines, which are skipped).
fn primitive_size(prim: &gltf::Primitive) -> (u64, u64) {
    use gltf::mesh::Mode;
    let Some(positions) = prim.get(&gltf::Semantic::Positions) else {
        return (0, 0);
    };
    let vertices = positions.count() as u64;
    let corners = prim.indices().map_or(vertices, |a| a.count() as u64);
    match prim.mode() {
        Mode::Triangles => (corners / 3, vertices),
        Mode::TriangleStrip | Mode::TriangleFan => (corners.saturating_sub(2), vertices),
        _ => (0, 0),
    }
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
        if stride < a.size() {
            // Elements would overlap; the gltf crate's reader panics on it.
            return Err(format!(
                "accessor {}: buffer view {} has byteStride {stride}, smaller than its {}-byte elements",
                a.index(),
                view.index(),
                a.size()
            ));
        }
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

/// An accessor's elements, `n` components each, every component decoded by
/// `decode` from its bytes, sparse substitutions applied. Every read is
/// bounds-checked: the gltf crate's reader panics on component types,
/// strides and sparse data it does not expect, so raylab reads accessors
/// itself; and sparse data that cannot be read is an error, never "no data".
pub(super) fn read_elements<T: Copy + Default>(
    a: &gltf::Accessor,
    buffers: &[Vec<u8>],
    n: usize,
    decode: impl Fn(&[u8]) -> T,
) -> std::result::Result<Vec<T>, String> {
    let size = a.data_type().size();
    let count = a.count();
    let past = || format!("accessor {} runs past its buffer view", a.index());
    let mut out = Vec::new();
    match a.view() {
        Some(view) => {
            let stride = view.stride().unwrap_or(size * n);
            let data = view_bytes(&view, buffers).ok_or_else(past)?;
            out.reserve(count.saturating_mul(n).min(data.len()));
            for i in 0..count {
                let start = i
                    .checked_mul(stride)
                    .and_then(|x| x.checked_add(a.offset()))
                    .ok_or_else(past)?;
                let element = data
                    .get(start..start.saturating_add(size * n))
                    .ok_or_else(past)?;
                out.extend(element.chunks_exact(size).map(&decode));
            }
        }
        // No view: zeros, then the sparse values (the budget has bounded
        // `count` by the vertex budget before this allocates).
        None => out.resize(count.saturating_mul(n), T::default()),
    }
    if let Some(sparse) = a.sparse() {
        let bad = |what: &str| {
            format!(
                "accessor {}: sparse {what} run past their buffer view",
                a.index()
            )
        };
        let indices = sparse.indices();
        let index_bytes = view_bytes(&indices.view(), buffers)
            .and_then(|d| d.get(indices.offset()..))
            .ok_or_else(|| bad("indices"))?;
        let values = sparse.values();
        let value_bytes = view_bytes(&values.view(), buffers)
            .and_then(|d| d.get(values.offset()..))
            .ok_or_else(|| bad("values"))?;
        let index_size = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => 1,
            gltf::accessor::sparse::IndexType::U16 => 2,
            gltf::accessor::sparse::IndexType::U32 => 4,
        };
        // Both runs checked whole first, so that a short one is named as
        // such whatever its contents.
        let entries = sparse.count();
        if entries
            .checked_mul(index_size)
            .is_none_or(|l| l > index_bytes.len())
        {
            return Err(bad("indices"));
        }
        if entries
            .checked_mul(size * n)
            .is_none_or(|l| l > value_bytes.len())
        {
            return Err(bad("values"));
        }
        let mut previous = None;
        for k in 0..entries {
            let ib = index_bytes
                .get(k * index_size..(k + 1) * index_size)
                .ok_or_else(|| bad("indices"))?;
            let mut le = [0u8; 4];
            le[..index_size].copy_from_slice(ib);
            let target = u32::from_le_bytes(le) as usize;
            if target >= count {
                return Err(format!(
                    "accessor {}: sparse index {target} out of range ({count} elements)",
                    a.index()
                ));
            }
            // The format requires them strictly increasing; a repeated one
            // would make the value taken depend on the reader.
            if previous.is_some_and(|p| target <= p) {
                return Err(format!(
                    "accessor {}: sparse index {k} ({target}) does not increase on the one before it, as glTF requires",
                    a.index()
                ));
            }
            previous = Some(target);
            let vb = value_bytes
                .get(k * size * n..(k + 1) * size * n)
                .ok_or_else(|| bad("values"))?;
            for (c, b) in vb.chunks_exact(size).enumerate() {
                out[target * n + c] = decode(b);
            }
        }
    }
    Ok(out)
}

/// One component of a float attribute: f32, or an integer normalized or not
/// (`KHR_mesh_quantization`'s POSITION and NORMAL types).
pub(super) fn decode_float(ty: gltf::accessor::DataType, normalized: bool, b: &[u8]) -> f32 {
    use gltf::accessor::DataType;
    match ty {
        DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DataType::U8 if normalized => f32::from(b[0]) / 255.0,
        DataType::U8 => f32::from(b[0]),
        // Signed normalized: -128 and -127 both give -1 (the spec's max()).
        DataType::I8 if normalized => (f32::from(b[0] as i8) / 127.0).max(-1.0),
        DataType::I8 => f32::from(b[0] as i8),
        DataType::U16 if normalized => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
        DataType::U16 => f32::from(u16::from_le_bytes([b[0], b[1]])),
        DataType::I16 if normalized => {
            (f32::from(i16::from_le_bytes([b[0], b[1]])) / 32767.0).max(-1.0)
        }
        DataType::I16 => f32::from(i16::from_le_bytes([b[0], b[1]])),
        DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
    }
}

/// The bytes of a buffer view, when they lie inside its buffer.
fn view_bytes<'a>(view: &gltf::buffer::View, buffers: &'a [Vec<u8>]) -> Option<&'a [u8]> {
    let start = view.offset();
    buffers
        .get(view.buffer().index())?
        .get(start..start.checked_add(view.length())?)
}

/// A VEC3 attribute (`what`: its semantic, for messages) as finite vectors.
pub(super) fn read_vec3s(
    a: &gltf::Accessor,
    buffers: &[Vec<u8>],
    what: &str,
) -> std::result::Result<Vec<Vec3>, String> {
    if a.dimensions() != gltf::accessor::Dimensions::Vec3 {
        return Err(format!(
            "{what} accessor {} is {:?}, not VEC3",
            a.index(),
            a.dimensions()
        ));
    }
    let (ty, normalized) = (a.data_type(), a.normalized());
    let flat = read_elements(a, buffers, 3, |b| decode_float(ty, normalized, b))?;
    let v: Vec<Vec3> = flat.chunks_exact(3).map(Vec3::from_slice).collect();
    if let Some(i) = v.iter().position(|p| !p.is_finite()) {
        return Err(format!(
            "{what} accessor {} element {i} is not finite",
            a.index()
        ));
    }
    Ok(v)
}

/// A primitive's indices: unsigned SCALAR integers, as the format requires
/// (float or signed index types are refused, never cast).
fn read_indices(a: &gltf::Accessor, buffers: &[Vec<u8>]) -> std::result::Result<Vec<u32>, String> {
    use gltf::accessor::DataType;
    if a.dimensions() != gltf::accessor::Dimensions::Scalar
        || !matches!(a.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
        || a.normalized()
    {
        return Err(format!(
            "index accessor {} is {:?} {:?}{}: indices must be unsigned 8-, 16- or 32-bit SCALARs",
            a.index(),
            a.data_type(),
            a.dimensions(),
            if a.normalized() { " normalized" } else { "" }
        ));
    }
    read_elements(a, buffers, 1, |b| {
        let mut le = [0u8; 4];
        le[..b.len()].copy_from_slice(b);
        u32::from_le_bytes(le)
    })
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
    /// `TRIANGLES` primitives whose index (or vertex) count is not a
    /// multiple of 3, their last one or two dropped.
    partial_primitives: usize,
    placements: Vec<Placement>,
}

/// Node nesting deeper than this is refused. Cycles are refused before any
/// walk ([`root_nodes`]) and the walks keep their own stacks, so this only
/// bounds the work a file can ask for; 256 refused a plain 300-node chain.
pub(super) const MAX_DEPTH: usize = 4096;

impl Flattened {
    /// Every primitive of `mesh`, placed by `node` at `world`.
    fn place(
        &mut self,
        node: &gltf::Node,
        mesh: &gltf::Mesh,
        world: Mat4,
        buffers: &[Vec<u8>],
    ) -> std::result::Result<(), String> {
        for prim in mesh.primitives() {
            let base = self.positions.len();
            self.primitive(&prim, world, buffers)?;
            if self.positions.len() > base {
                self.placements.push(Placement {
                    node: node.index(),
                    mesh: mesh.index(),
                    primitive: prim.index(),
                    base,
                    count: self.positions.len() - base,
                });
            }
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
        let Some(position_accessor) = prim.get(&gltf::Semantic::Positions) else {
            self.skipped_primitives += 1;
            return Ok(());
        };
        let positions = read_vec3s(&position_accessor, buffers, "POSITION")?;
        let count = positions.len();
        // Indices are u32 in the scene: the vertices so far plus these must
        // be numbered by one (the budget keeps them far below; this keeps a
        // raised budget from wrapping an index to 0).
        let base = u32::try_from(self.positions.len())
            .ok()
            .filter(|b| u32::try_from(count).is_ok_and(|c| b.checked_add(c).is_some()))
            .ok_or("more than 2^32 vertices: raylab numbers vertices with 32 bits")?;
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        self.positions
            .extend(positions.into_iter().map(|p| world.transform_point3(p)));
        let normals = match prim.get(&gltf::Semantic::Normals) {
            Some(a) => read_vec3s(&a, buffers, "NORMAL")?,
            None => Vec::new(),
        };
        if normals.len() == count {
            self.normals.extend(
                normals
                    .into_iter()
                    .map(|n| (normal_matrix * n).normalize_or_zero()),
            );
        } else {
            self.normals.extend(std::iter::repeat_n(Vec3::ZERO, count));
        }
        let indices: Vec<u32> = match prim.indices() {
            Some(a) => read_indices(&a, buffers)?,
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
        let material = self.material(&prim.material())?;
        let mut push = |a: u32, b: u32, c: u32| {
            let t = if mirrored { [a, c, b] } else { [a, b, c] };
            self.triangles.push(t.map(|i| base + i));
            self.material_ids.push(material);
        };
        match prim.mode() {
            Mode::Triangles => {
                let whole = indices.chunks_exact(3);
                if !whole.remainder().is_empty() {
                    self.partial_primitives += 1;
                }
                for t in whole {
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

    /// The scene's material for `m`; colours must be finite and non-negative,
    /// as the MTL reader asks (a negative colour would make negative light).
    fn material(&mut self, m: &gltf::Material) -> std::result::Result<u32, String> {
        if let Some(&id) = self.material_of.get(&m.index()) {
            return Ok(id);
        }
        let mat = match m.index() {
            None => Material::default_grey(),
            Some(i) => {
                let [r, g, b, _] = m.pbr_metallic_roughness().base_color_factor();
                let kd = Vec3::new(r, g, b);
                let ke =
                    Vec3::from_array(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
                for (what, c) in [("baseColorFactor", kd), ("emissive colour", ke)] {
                    if !(c.is_finite() && c.min_element() >= 0.0) {
                        return Err(format!(
                            "material {i}: {what} {c} must be finite and non-negative"
                        ));
                    }
                }
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
        Ok(id)
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

    fn check_fixture_scene(instanced: &Scene) {
        // Two instances of the 2-triangle mesh and a 4-index strip (2
        // triangles): an instanced scene of two meshes, flattened as the
        // nodes place them.
        assert!(instanced.is_instanced());
        assert_eq!(instanced.instance_count(), 3);
        assert_eq!(instanced.triangle_count(), 4);
        let flat = instanced.flattened().unwrap();
        let s = &flat;
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

    /// The error loading the fixture GLB with `from` replaced by `to` in its
    /// JSON (the replacement must apply).
    fn fixture_error(from: &str, to: &str) -> String {
        let json = fixture_json(None);
        assert!(json.contains(from), "{from}");
        let bytes = glb(&json.replacen(from, to, 1), &fixture_buffer());
        let e = load_gltf_bytes(&bytes, Path::new("hostile.glb"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("hostile.glb: "), "{e}");
        assert_eq!(e.lines().count(), 1, "{e}");
        e
    }

    #[test]
    fn what_the_gltf_crate_would_panic_on_is_refused_first() {
        // Float and signed index types (the crate's reader: unreachable!()).
        let e = fixture_error(
            r#""componentType":5123,"count":6"#,
            r#""componentType":5126,"count":3"#,
        );
        assert!(
            e.contains("index accessor 1 is F32") && e.contains("unsigned"),
            "{e}"
        );
        let e = fixture_error(
            r#""componentType":5123,"count":6"#,
            r#""componentType":5122,"count":6"#,
        );
        assert!(e.contains("index accessor 1 is I16"), "{e}");
        // A stride smaller than the element (the crate's reader: assert!).
        let e = fixture_error(r#""byteLength":48}"#, r#""byteLength":48,"byteStride":4}"#);
        assert!(
            e.contains("byteStride 4, smaller than its 12-byte elements"),
            "{e}"
        );
        // An attribute naming an accessor past the list (the crate's
        // validation hook indexes it unchecked).
        let e = fixture_error(
            r#"{"POSITION":0},"indices":1"#,
            r#"{"POSITION":9},"indices":1"#,
        );
        assert!(
            e.contains("mesh 0 primitive 0 names accessor 9, the file has 3"),
            "{e}"
        );
    }

    #[test]
    fn node_graphs_must_be_trees() {
        let shared = fixture_error(
            r#"{"mesh":0,"translation":[5,0,0]}"#,
            r#"{"mesh":0,"translation":[5,0,0],"children":[2]}"#,
        );
        assert!(
            shared.contains("node 2 is a child of nodes 0 and 1") && shared.contains("trees"),
            "{shared}"
        );
        let twice = fixture_error(r#""children":[2]"#, r#""children":[2,2]"#);
        assert!(
            twice.contains("node 2 is a child of nodes 1 and 1"),
            "{twice}"
        );
        let cycle = fixture_error(
            r#"{"mesh":0,"translation":[10,0,0]}"#,
            r#"{"mesh":0,"translation":[10,0,0],"children":[1]}"#,
        );
        assert!(
            cycle.contains("lists node 1 as a root, but it is a child of node 2"),
            "{cycle}"
        );
        let listed_twice = fixture_error(r#""nodes":[0,1,3]"#, r#""nodes":[0,1,3,0]"#);
        assert!(
            listed_twice.contains("lists node 0 twice"),
            "{listed_twice}"
        );
    }

    #[test]
    fn expansion_past_the_triangle_budget_is_refused_before_allocating() {
        // An index accessor of 2 * 10^8 + 1000 triangles, view-less and
        // sparse, instanced twice (plus the strip's 2): a few hundred bytes
        // that would take gigabytes. Instanced, the mesh counts once.
        let huge = r#"{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}"#;
        let sparse = r#"{"componentType":5125,"count":600003000,"type":"SCALAR",
            "sparse":{"count":1,"indices":{"bufferView":2,"componentType":5123},"values":{"bufferView":2}}}"#;
        let e = fixture_error(huge, sparse);
        assert!(
            e.contains("expands to 200001002 triangles") && e.contains("--max-triangles"),
            "{e}"
        );
    }

    #[test]
    fn unreadable_sparse_data_is_an_error_not_no_data() {
        let e = fixture_error(
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#,
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0],
              "sparse":{"count":5,"indices":{"bufferView":2,"componentType":5123},"values":{"bufferView":0}}}"#,
        );
        assert!(e.contains("accessor 0: sparse indices run past"), "{e}");
    }

    #[test]
    fn sparse_indices_that_do_not_increase_are_refused() {
        // The strip's view holds [0, 1, 3, 2].
        let e = fixture_error(
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#,
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0],
              "sparse":{"count":4,"indices":{"bufferView":2,"componentType":5123},"values":{"bufferView":0}}}"#,
        );
        assert!(
            e.contains("accessor 0: sparse index 3 (2) does not increase"),
            "{e}"
        );
    }

    #[test]
    fn a_matrix_beside_trs_that_disagrees_is_refused() {
        let identity = "[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]";
        let e = fixture_error(
            r#"{"mesh":0,"translation":[5,0,0]}"#,
            &format!(r#"{{"mesh":0,"translation":[5,0,0],"matrix":{identity}}}"#),
        );
        assert!(
            e.contains(
                "node 0: has both a matrix and translation/rotation/scale, and they disagree"
            ),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
        // Both given and the same transform (the translation written in the
        // matrix's last column too, an identity scale): read as the matrix.
        let json = fixture_json(None).replacen(
            r#"{"mesh":0,"translation":[5,0,0]}"#,
            r#"{"mesh":0,"translation":[5,0,0],"scale":[1,1,1],"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,5,0,0,1]}"#,
            1,
        );
        let both = load_gltf_bytes(&glb(&json, &fixture_buffer()), Path::new("m.glb")).unwrap();
        let json = fixture_json(None);
        let trs = load_gltf_bytes(&glb(&json, &fixture_buffer()), Path::new("t.glb")).unwrap();
        assert_eq!(both.positions, trs.positions);
        // A quarter turn about z (glTF's x, y, z, w) at scale 100, with the
        // default translation, beside its matrix (column-major): agrees,
        // though the quaternion's zeros round near 1e-7 times the scale.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let node = |matrix: &str| {
            format!(
                r#"{{"mesh":0,"rotation":[0,0,{h},{h}],"scale":[100,100,100],"matrix":{matrix}}}"#
            )
        };
        let turn = "[0,100,0,0, -100,0,0,0, 0,0,100,0, 0,0,0,1]";
        let json =
            fixture_json(None).replacen(r#"{"mesh":0,"translation":[5,0,0]}"#, &node(turn), 1);
        load_gltf_bytes(&glb(&json, &fixture_buffer()), Path::new("q.glb")).unwrap();
        // Its transpose (the matrix read row by row) turns the other way.
        let transposed = "[0,-100,0,0, 100,0,0,0, 0,0,100,0, 0,0,0,1]";
        let e = fixture_error(r#"{"mesh":0,"translation":[5,0,0]}"#, &node(transposed));
        assert!(e.contains("node 0: has both a matrix"), "{e}");
    }

    #[test]
    fn rotations_are_unit_quaternions_or_refused() {
        let e = fixture_error(
            r#"{"mesh":0,"translation":[5,0,0]}"#,
            r#"{"mesh":0,"translation":[5,0,0],"rotation":[0,0,0,0]}"#,
        );
        assert!(
            e.contains("node 0: rotation [0.0, 0.0, 0.0, 0.0] is not a rotation"),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
        // A non-unit one is normalised (a quarter turn about z written at
        // twice its length), not read as a scaling shear.
        let load = |rotation: &str| {
            let json = fixture_json(None).replacen(
                r#"{"mesh":0,"translation":[5,0,0]}"#,
                &format!(r#"{{"mesh":0,"translation":[5,0,0],"rotation":{rotation}}}"#),
                1,
            );
            load_gltf_bytes(&glb(&json, &fixture_buffer()), Path::new("r.glb"))
                .unwrap()
                .flattened()
                .unwrap()
                .positions
        };
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let unit = load(&format!("[0,0,{h},{h}]"));
        let long = load(&format!("[0,0,{},{}]", 2.0 * h, 2.0 * h));
        for (a, b) in unit.iter().zip(&long) {
            assert!(a.abs_diff_eq(*b, 1e-6), "{a} {b}");
        }
        assert!(
            unit[1].abs_diff_eq(Vec3::new(5.0, 1.0, 0.0), 1e-6),
            "{}",
            unit[1]
        );
    }

    #[test]
    fn sparse_values_replace_elements() {
        // Sparse indices [0, 1] (the strip's view) take the values (1,0,0)
        // and (1,1,0) (positions 1 and 2 of the position view).
        let json = fixture_json(None).replacen(
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#,
            r#""type":"VEC3","min":[0,0,0],"max":[1,1,0],
              "sparse":{"count":2,"indices":{"bufferView":2,"componentType":5123},
                        "values":{"bufferView":0,"byteOffset":12}}}"#,
            1,
        );
        let s = load_gltf_bytes(&glb(&json, &fixture_buffer()), Path::new("s.glb"))
            .unwrap()
            .flattened()
            .unwrap();
        // Seen through the first instance's translation by 5 in x.
        assert_eq!(s.positions[0], Vec3::new(6.0, 0.0, 0.0));
        assert_eq!(s.positions[1], Vec3::new(6.0, 1.0, 0.0));
    }

    #[test]
    fn colours_must_be_finite_and_non_negative() {
        let e = fixture_error("[0.2,0.4,0.6,1]", "[-0.2,0.4,0.6,1]");
        assert!(
            e.contains("material 0: baseColorFactor") && e.contains("non-negative"),
            "{e}"
        );
        let e = fixture_error(r#""emissiveStrength":4"#, r#""emissiveStrength":1e39"#);
        assert!(e.contains("emissive colour"), "{e}");
    }

    #[test]
    fn unread_required_extensions_are_all_named() {
        let e = fixture_error(
            r#""scene":0,"#,
            r#""scene":0,"extensionsRequired":["EXT_meshopt_compression","KHR_mesh_quantization","KHR_draco_mesh_compression"],"#,
        );
        assert!(
            e.contains(
                "does not read: EXT_meshopt_compression, KHR_draco_mesh_compression (Draco- or meshopt-compressed"
            ),
            "{e}"
        );
    }

    #[test]
    fn quantized_attributes_are_read() {
        // KHR_mesh_quantization as gltfpack writes it: u16 positions (not
        // normalized, 8-byte stride), i8 normalized normals (4-byte stride).
        let mut bin = Vec::new();
        for p in [[0u16, 0, 0], [2, 0, 0], [0, 2, 0]] {
            for c in p {
                bin.extend(c.to_le_bytes());
            }
            bin.extend([0, 0]);
        }
        for _ in 0..3 {
            bin.extend([0u8, 0, 127, 0]);
        }
        let json = r#"{"asset":{"version":"2.0"},
            "extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"],
            "scenes":[{"nodes":[0]}],"nodes":[{"mesh":0,"scale":[0.5,0.5,0.5]}],
            "meshes":[{"primitives":[{"attributes":{"POSITION":0,"NORMAL":1}}]}],
            "buffers":[{"byteLength":36}],
            "bufferViews":[{"buffer":0,"byteLength":24,"byteStride":8},
                           {"buffer":0,"byteOffset":24,"byteLength":12,"byteStride":4}],
            "accessors":[
              {"bufferView":0,"componentType":5123,"count":3,"type":"VEC3","min":[0,0,0],"max":[2,2,0]},
              {"bufferView":1,"componentType":5120,"normalized":true,"count":3,"type":"VEC3"}]}"#;
        let s = load_gltf_bytes(&glb(json, &bin), Path::new("q.glb")).unwrap();
        assert_eq!(s.positions, vec![Vec3::ZERO, Vec3::X, Vec3::Y]);
        // Declared used only (not required): read the same.
        let used_only = json.replace(r#""extensionsRequired":["KHR_mesh_quantization"],"#, "");
        let s = load_gltf_bytes(&glb(&used_only, &bin), Path::new("q.glb")).unwrap();
        assert_eq!(s.positions, vec![Vec3::ZERO, Vec3::X, Vec3::Y]);
        // Not declared: integer positions are refused by name, not read.
        let undeclared = used_only.replace(r#""extensionsUsed":["KHR_mesh_quantization"],"#, "");
        let e = load_gltf_bytes(&glb(&undeclared, &bin), Path::new("q.glb"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("q.glb")
                && e.contains("mesh 0 primitive 0: POSITION accessor 0 has U16 components")
                && e.contains("KHR_mesh_quantization"),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
        assert_eq!(s.shading_normal(0, 0.2, 0.2), Some(Vec3::Z));
        assert_eq!(
            decode_float(gltf::accessor::DataType::I8, true, &[0x80]),
            -1.0
        );
        assert_eq!(
            decode_float(gltf::accessor::DataType::U16, true, &[0xff, 0xff]),
            1.0
        );
        assert_eq!(
            decode_float(gltf::accessor::DataType::I16, false, &[0xfe, 0xff]),
            -2.0
        );
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
