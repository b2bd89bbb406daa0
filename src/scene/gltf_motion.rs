//! glTF animations as the specification defines them, evaluated into the
//! flattened scene's vertex array: node translation, rotation and scale
//! channels (LINEAR, STEP and CUBICSPLINE samplers; rotations spherically
//! interpolated), morph target weights (POSITION targets), and skins
//! (JOINTS_0 and WEIGHTS_0 over the joints' world matrices and their inverse
//! bind matrices; the skinned mesh's own node transform ignored, as the
//! specification asks). Every animation in the file plays at once, from
//! time 0 to the last keyframe of any of them.
//!
//! The triangle list is the static load's: a frame moves vertices only, so a
//! tree built on one frame can be refitted to the next. A file whose placed
//! meshes all move rigidly with their nodes ([`NodeMotion::is_rigid`]) is
//! followed as an instanced scene instead, whose instances move
//! ([`NodeMotion::transforms_at`]).

use glam::{Mat4, Quat, Vec3};

use super::gltf::{decode_float, parse_error, read_elements, read_vec3s, Loaded, MAX_DEPTH};
use crate::error::{Error, Result};

#[derive(Clone, Debug)]
struct RestNode {
    /// A node given by a matrix (which no channel may target).
    matrix: Option<Mat4>,
    t: Vec3,
    r: Quat,
    s: Vec3,
    /// The morph weights it starts with (the node's, else its mesh's).
    weights: Vec<f32>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Path {
    Translation,
    Rotation,
    Scale,
    Weights,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Interpolation {
    Linear,
    Step,
    CubicSpline,
}

#[derive(Clone, Debug)]
struct Channel {
    node: usize,
    path: Path,
    interpolation: Interpolation,
    times: Vec<f32>,
    /// `width` components per key (three such per key for cubic splines:
    /// in-tangent, value, out-tangent).
    values: Vec<f32>,
    width: usize,
}

#[derive(Clone, Debug)]
struct Skinning {
    /// Node of each joint, and its inverse bind matrix.
    joints: Vec<usize>,
    inverse_bind: Vec<Mat4>,
    /// Per vertex: four joint indices (into `joints`) and their weights.
    vertex_joints: Vec<[u16; 4]>,
    vertex_weights: Vec<[f32; 4]>,
}

#[derive(Clone, Debug)]
struct Placed {
    node: usize,
    base: usize,
    /// The primitive's own vertex positions (before any transform).
    local: Vec<Vec3>,
    /// POSITION displacements of each morph target.
    targets: Vec<Vec<Vec3>>,
    skin: Option<Skinning>,
}

/// A glTF file's animations over its flattened vertices.
#[derive(Clone, Debug)]
pub struct NodeMotion {
    nodes: Vec<RestNode>,
    parents: Vec<Option<usize>>,
    channels: Vec<Channel>,
    placed: Vec<Placed>,
    /// The last keyframe's time, seconds.
    pub duration: f32,
}

fn floats(
    a: &gltf::Accessor,
    buffers: &[Vec<u8>],
    what: &str,
) -> std::result::Result<Vec<f32>, String> {
    let n = a.dimensions().multiplicity();
    let (ty, normalized) = (a.data_type(), a.normalized());
    let v = read_elements(a, buffers, n, |b| decode_float(ty, normalized, b))?;
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!(
            "{what} accessor {} component {i} is not finite",
            a.index()
        ));
    }
    Ok(v)
}

impl NodeMotion {
    /// The animations of a loaded file; `None` when it has none.
    pub(super) fn of(loaded: &Loaded) -> std::result::Result<Option<NodeMotion>, String> {
        if loaded.doc.animations().next().is_none() {
            return Ok(None);
        }
        Self::posed(loaded).map(Some)
    }

    /// The file's nodes, skins and morph targets, with its animations if it
    /// has any: what poses a static file's skinned and morphed meshes
    /// ([`needs_pose`]) at time 0, and what [`NodeMotion::of`] animates.
    pub(super) fn posed(loaded: &Loaded) -> std::result::Result<NodeMotion, String> {
        let doc = &loaded.doc;
        let buffers = &loaded.buffers;
        let count = doc.nodes().count();
        let mut parents = vec![None; count];
        for node in doc.nodes() {
            for child in node.children() {
                if parents[child.index()].replace(node.index()).is_some() {
                    return Err(format!(
                        "node {} has two parents: glTF node graphs must be trees",
                        child.index()
                    ));
                }
            }
        }
        let nodes: Vec<RestNode> = doc
            .nodes()
            .map(|n| {
                let weights = n
                    .weights()
                    .or_else(|| n.mesh().and_then(|m| m.weights()))
                    .unwrap_or(&[])
                    .to_vec();
                match n.transform() {
                    gltf::scene::Transform::Matrix { matrix } => RestNode {
                        matrix: Some(Mat4::from_cols_array_2d(&matrix)),
                        t: Vec3::ZERO,
                        r: Quat::IDENTITY,
                        s: Vec3::ONE,
                        weights,
                    },
                    gltf::scene::Transform::Decomposed {
                        translation,
                        rotation,
                        scale,
                    } => RestNode {
                        matrix: None,
                        t: Vec3::from(translation),
                        r: Quat::from_array(rotation).normalize(),
                        s: Vec3::from(scale),
                        weights,
                    },
                }
            })
            .collect();
        let mut channels = Vec::new();
        let mut duration = 0f32;
        for anim in doc.animations() {
            for ch in anim.channels() {
                let target = ch.target();
                let node = target.node().index();
                let sampler = ch.sampler();
                let path = match target.property() {
                    gltf::animation::Property::Translation => Path::Translation,
                    gltf::animation::Property::Rotation => Path::Rotation,
                    gltf::animation::Property::Scale => Path::Scale,
                    gltf::animation::Property::MorphTargetWeights => Path::Weights,
                };
                if path != Path::Weights && nodes[node].matrix.is_some() {
                    return Err(format!(
                        "animation {} targets node {node}, which has a matrix: animated nodes must have TRS properties",
                        anim.index()
                    ));
                }
                let interpolation = match sampler.interpolation() {
                    gltf::animation::Interpolation::Linear => Interpolation::Linear,
                    gltf::animation::Interpolation::Step => Interpolation::Step,
                    gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
                };
                let times = floats(&sampler.input(), buffers, "animation input")?;
                if times.is_empty() || times.windows(2).any(|w| w[1] <= w[0]) || times[0] < 0.0 {
                    return Err(format!(
                        "animation {} sampler {}: keyframe times must be non-negative and strictly increasing",
                        anim.index(),
                        sampler.index()
                    ));
                }
                let values = floats(&sampler.output(), buffers, "animation output")?;
                let per_key = if interpolation == Interpolation::CubicSpline {
                    3 * times.len()
                } else {
                    times.len()
                };
                let width = match path {
                    Path::Translation | Path::Scale => 3,
                    Path::Rotation => 4,
                    Path::Weights => values.len() / per_key.max(1),
                };
                if width == 0 || values.len() != per_key * width {
                    return Err(format!(
                        "animation {} sampler {}: {} output values for {} keyframes",
                        anim.index(),
                        sampler.index(),
                        values.len(),
                        times.len()
                    ));
                }
                duration = duration.max(*times.last().expect("non-empty"));
                channels.push(Channel {
                    node,
                    path,
                    interpolation,
                    times,
                    values,
                    width,
                });
            }
        }
        let mut placed = Vec::new();
        for p in &loaded.placements {
            let mesh = doc.meshes().nth(p.mesh).ok_or("a placed mesh is gone")?;
            let prim = mesh
                .primitives()
                .nth(p.primitive)
                .ok_or("a placed primitive is gone")?;
            let position = prim
                .get(&gltf::Semantic::Positions)
                .ok_or("a placed primitive lost its positions")?;
            let local = read_vec3s(&position, buffers, "POSITION")?;
            let mut targets = Vec::new();
            for (k, t) in prim.morph_targets().enumerate() {
                let d = match t.positions() {
                    Some(a) => read_vec3s(&a, buffers, "morph target POSITION")?,
                    None => vec![Vec3::ZERO; local.len()],
                };
                if d.len() != local.len() {
                    return Err(format!(
                        "mesh {} morph target {k}: {} positions for {} vertices",
                        p.mesh,
                        d.len(),
                        local.len()
                    ));
                }
                targets.push(d);
            }
            let node = doc.nodes().nth(p.node).ok_or("a placing node is gone")?;
            let skin = match node.skin() {
                Some(skin) => Some(skinning(&skin, &prim, buffers, local.len())?),
                None => None,
            };
            if local.len() != p.count {
                return Err(format!(
                    "mesh {} primitive {}: {} positions where {} were placed",
                    p.mesh,
                    p.primitive,
                    local.len(),
                    p.count
                ));
            }
            placed.push(Placed {
                node: p.node,
                base: p.base,
                local,
                targets,
                skin,
            });
        }
        Ok(NodeMotion {
            nodes,
            parents,
            channels,
            placed,
            duration,
        })
    }

    /// Whether every placed mesh moves rigidly with its node: no skin, no
    /// morph targets, no weight channel, and no scale channel that can pass
    /// through zero (cubic splines can overshoot; linear and step keys must
    /// keep each component's sign), so every node's transform stays
    /// invertible. Such a file is followed as moving instances.
    pub fn is_rigid(&self) -> bool {
        let placed_still = self
            .placed
            .iter()
            .all(|p| p.skin.is_none() && p.targets.is_empty());
        let channels_rigid = self.channels.iter().all(|ch| match ch.path {
            Path::Weights => false,
            Path::Scale => {
                ch.interpolation != Interpolation::CubicSpline
                    && (0..3).all(|c| {
                        let keys = ch.values.iter().skip(c).step_by(3);
                        keys.clone().all(|&v| v > 0.0) || keys.clone().all(|&v| v < 0.0)
                    })
            }
            Path::Translation | Path::Rotation => true,
        });
        placed_still && channels_rigid
    }

    /// The world transform at `t` of each node in `nodes` (the nodes of an
    /// instanced load's instances); an error when one is not finite.
    pub fn transforms_at(
        &self,
        t: f32,
        nodes: &[usize],
    ) -> std::result::Result<Vec<glam::Affine3A>, String> {
        let (world, _) = self.world_at(t)?;
        nodes
            .iter()
            .map(|&n| {
                let m = world[n];
                if m.is_finite() {
                    Ok(glam::Affine3A::from_mat4(m))
                } else {
                    Err(format!("at {t} s the transform of node {n} is not finite"))
                }
            })
            .collect()
    }

    /// Every node's world transform and morph weights at `t`.
    #[allow(clippy::type_complexity)]
    fn world_at(&self, t: f32) -> std::result::Result<(Vec<Mat4>, Vec<Vec<f32>>), String> {
        let mut trs: Vec<(Vec3, Quat, Vec3)> = self.nodes.iter().map(|n| (n.t, n.r, n.s)).collect();
        let mut weights: Vec<Vec<f32>> = self.nodes.iter().map(|n| n.weights.clone()).collect();
        for ch in &self.channels {
            let v = sample(ch, t);
            let (tr, r, s) = &mut trs[ch.node];
            match ch.path {
                Path::Translation => *tr = Vec3::from_slice(&v),
                Path::Scale => *s = Vec3::from_slice(&v),
                Path::Rotation => *r = Quat::from_slice(&v).normalize(),
                Path::Weights => weights[ch.node] = v,
            }
        }
        let local = |i: usize| match self.nodes[i].matrix {
            Some(m) => m,
            None => {
                let (t, r, s) = trs[i];
                Mat4::from_scale_rotation_translation(s, r, t)
            }
        };
        // World transforms, each node's chain up to its root.
        let mut world: Vec<Option<Mat4>> = vec![None; self.nodes.len()];
        for i in 0..self.nodes.len() {
            let mut chain = vec![i];
            while let Some(p) = self.parents[*chain.last().expect("non-empty")] {
                if world[p].is_some() {
                    chain.push(p);
                    break;
                }
                chain.push(p);
                if chain.len() > MAX_DEPTH {
                    return Err(format!(
                        "node {i} is nested over {MAX_DEPTH} levels deep, past raylab's limit"
                    ));
                }
            }
            let mut m = Mat4::IDENTITY;
            for &n in chain.iter().rev() {
                m = match world[n] {
                    Some(w) => w,
                    None => {
                        let w = m * local(n);
                        world[n] = Some(w);
                        w
                    }
                };
            }
        }
        let world: Vec<Mat4> = world.into_iter().map(|w| w.expect("every node")).collect();
        Ok((world, weights))
    }

    /// Every vertex at time `t` into `positions` (the flattened scene's
    /// array); an error when a transform overflows to a non-finite vertex.
    pub fn positions_at(&self, t: f32, positions: &mut [Vec3]) -> std::result::Result<(), String> {
        let (world, weights) = self.world_at(t)?;
        for p in &self.placed {
            let w = &weights[p.node];
            let out = &mut positions[p.base..p.base + p.local.len()];
            let joints: Vec<Mat4> = p.skin.as_ref().map_or(Vec::new(), |s| {
                s.joints
                    .iter()
                    .zip(&s.inverse_bind)
                    .map(|(&j, ib)| world[j] * *ib)
                    .collect()
            });
            for (i, (o, &l)) in out.iter_mut().zip(&p.local).enumerate() {
                let mut v = l;
                for (k, d) in p.targets.iter().enumerate() {
                    v += d[i] * w.get(k).copied().unwrap_or(0.0);
                }
                *o = match &p.skin {
                    Some(s) => {
                        let (js, ws) = (s.vertex_joints[i], s.vertex_weights[i]);
                        let sum: f32 = ws.iter().sum();
                        if sum > 0.0 {
                            let mut m = Mat4::ZERO;
                            for (j, wt) in js.iter().zip(ws) {
                                m += joints[*j as usize] * (wt / sum);
                            }
                            m.transform_point3(v)
                        } else {
                            world[p.node].transform_point3(v)
                        }
                    }
                    None => world[p.node].transform_point3(v),
                };
                if !o.is_finite() {
                    return Err(format!(
                        "at {t} s a vertex of mesh placed by node {} is not finite",
                        p.node
                    ));
                }
            }
        }
        Ok(())
    }
}

/// A skin's joints and inverse bind matrices, and a primitive's JOINTS_0
/// and WEIGHTS_0.
fn skinning(
    skin: &gltf::Skin,
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    vertices: usize,
) -> std::result::Result<Skinning, String> {
    let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
    let inverse_bind = match skin.inverse_bind_matrices() {
        Some(a) => {
            let m = floats(&a, buffers, "inverseBindMatrices")?;
            if m.len() != 16 * joints.len() {
                return Err(format!(
                    "skin {}: {} inverse bind matrices for {} joints",
                    skin.index(),
                    m.len() / 16,
                    joints.len()
                ));
            }
            m.chunks_exact(16).map(Mat4::from_cols_slice).collect()
        }
        None => vec![Mat4::IDENTITY; joints.len()],
    };
    let (Some(ja), Some(wa)) = (
        prim.get(&gltf::Semantic::Joints(0)),
        prim.get(&gltf::Semantic::Weights(0)),
    ) else {
        return Err(format!(
            "skin {}: a skinned primitive without JOINTS_0 and WEIGHTS_0",
            skin.index()
        ));
    };
    let js = read_elements(&ja, buffers, 4, |b| match b.len() {
        1 => u16::from(b[0]),
        2 => u16::from_le_bytes([b[0], b[1]]),
        _ => u16::MAX,
    })?;
    let ws = floats(&wa, buffers, "WEIGHTS_0")?;
    if js.len() != 4 * vertices || ws.len() != 4 * vertices {
        return Err(format!(
            "skin {}: JOINTS_0 and WEIGHTS_0 must give four per vertex",
            skin.index()
        ));
    }
    if let Some(&bad) = js.iter().find(|&&j| j as usize >= joints.len()) {
        return Err(format!(
            "skin {}: joint {bad} out of range ({} joints)",
            skin.index(),
            joints.len()
        ));
    }
    Ok(Skinning {
        joints,
        inverse_bind,
        vertex_joints: js
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        vertex_weights: ws
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
    })
}

/// A channel's value at `t` (clamped to its first and last keyframes), as
/// the glTF specification's interpolations define it.
fn sample(ch: &Channel, t: f32) -> Vec<f32> {
    let w = ch.width;
    let keys = ch.times.len();
    let cubic = ch.interpolation == Interpolation::CubicSpline;
    // Component `c` of key `k`'s value (the middle of a cubic triple).
    let value = |k: usize| -> &[f32] {
        let start = if cubic { (3 * k + 1) * w } else { k * w };
        &ch.values[start..start + w]
    };
    if t <= ch.times[0] || keys == 1 {
        return value(0).to_vec();
    }
    if t >= ch.times[keys - 1] {
        return value(keys - 1).to_vec();
    }
    let k = ch.times.partition_point(|&x| x <= t) - 1;
    let (t0, t1) = (ch.times[k], ch.times[k + 1]);
    let dt = t1 - t0;
    let s = (t - t0) / dt;
    match ch.interpolation {
        Interpolation::Step => value(k).to_vec(),
        Interpolation::Linear if ch.path == Path::Rotation => {
            let a = Quat::from_slice(value(k));
            let b = Quat::from_slice(value(k + 1));
            a.slerp(b, s).to_array().to_vec()
        }
        Interpolation::Linear => value(k)
            .iter()
            .zip(value(k + 1))
            .map(|(a, b)| a + (b - a) * s)
            .collect(),
        Interpolation::CubicSpline => {
            let out_tangent = &ch.values[(3 * k + 2) * w..(3 * k + 3) * w];
            let in_tangent = &ch.values[(3 * (k + 1)) * w..(3 * (k + 1) + 1) * w];
            let (s2, s3) = (s * s, s * s * s);
            (0..w)
                .map(|c| {
                    (2.0 * s3 - 3.0 * s2 + 1.0) * value(k)[c]
                        + dt * (s3 - 2.0 * s2 + s) * out_tangent[c]
                        + (-2.0 * s3 + 3.0 * s2) * value(k + 1)[c]
                        + dt * (s3 - s2) * in_tangent[c]
                })
                .collect()
        }
    }
}

/// [`NodeMotion::of`]'s error as the file's.
pub(super) fn file_error(path: &std::path::Path, msg: String) -> Error {
    Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    }
}

/// A glTF file's static scene (what `render` without `--time` shows): its
/// meshes as stored, or, where a skin or non-zero morph weights deform a
/// placed mesh, the file flattened and posed ([`posed`]).
pub(super) fn load_still(
    bytes: &[u8],
    path: &std::path::Path,
    policy: super::refs::RefPolicy,
) -> Result<super::Scene> {
    let (doc, buffers) = super::gltf::read_document(bytes, path, policy)?;
    if needs_pose(&doc) {
        return posed(doc, buffers, path);
    }
    super::gltf::load_document(&doc, &buffers, path)
}

/// Whether a node places a mesh that its skin or its morph weights deform:
/// the file's static pose is not its meshes' vertices as stored, so it is
/// loaded through [`posed`].
fn needs_pose(doc: &gltf::Document) -> bool {
    doc.nodes().any(|node| {
        let Some(mesh) = node.mesh() else {
            return false;
        };
        let morphed = mesh
            .primitives()
            .any(|p| p.morph_targets().next().is_some())
            && node
                .weights()
                .or_else(|| mesh.weights())
                .is_some_and(|w| w.iter().any(|&w| w != 0.0));
        node.skin().is_some() || morphed
    })
}

/// The file flattened with its skinned and morphed meshes posed as the
/// format defines the static scene: morph targets at the node's (else the
/// mesh's) default weights, skins over their joints' rest transforms (an
/// animation's time 0 is `render --time 0`). The shading normals are
/// dropped, as an animation's frames drop them: they were the unposed mesh's.
fn posed(
    doc: gltf::Document,
    buffers: Vec<Vec<u8>>,
    path: &std::path::Path,
) -> Result<super::Scene> {
    let mut loaded = super::gltf::flattened_parts(doc, buffers, path)?;
    let motion = NodeMotion::posed(&loaded).map_err(|m| parse_error(path, m))?;
    motion
        .positions_at(0.0, &mut loaded.scene.positions)
        .map_err(|m| parse_error(path, m))?;
    // Found anew over the posed vertices, as an animation's frames find them.
    loaded.scene.normals = None;
    loaded.scene.lights = loaded.scene.find_lights();
    Ok(loaded.scene)
}

/// A glTF file's animations, as loaded: over the flattened scene (its
/// vertices move), or, when every placed mesh moves rigidly with its node,
/// over an instanced scene whose instances move (a two-level tree follows
/// it by updating its instances' tree alone).
pub(super) enum Followed {
    Vertices(super::Scene, NodeMotion),
    /// The scene (at the file's static transforms), its instances' nodes.
    Instances(super::Scene, NodeMotion, Vec<usize>),
}

/// Loads a glTF file's animations; `None` when it has none.
pub(super) fn load(
    path: &std::path::Path,
    policy: super::refs::RefPolicy,
) -> Result<Option<Followed>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let loaded = super::gltf::load_parts(&bytes, path, policy)?;
    let Some(motion) = NodeMotion::of(&loaded).map_err(|m| file_error(path, m))? else {
        return Ok(None);
    };
    if motion.is_rigid() {
        // A static node that cannot be inverted (a zero scale) cannot be an
        // instance; its vertices are followed instead.
        if let Ok((scene, nodes)) = super::gltf::load_placed_instances(&loaded, path) {
            return Ok(Some(Followed::Instances(scene, motion, nodes)));
        }
    }
    Ok(Some(Followed::Vertices(loaded.scene, motion)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-triangle glTF whose node moves by a translation channel (and,
    /// with `matrix`, is given by a matrix instead, which the format
    /// forbids for animated nodes).
    fn translated_triangle(matrix: bool, times: [f32; 2]) -> Vec<u8> {
        use base64::Engine;
        let mut bin: Vec<u8> = Vec::new();
        for f in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
            bin.extend(f.to_le_bytes());
        }
        for f in times {
            bin.extend(f.to_le_bytes());
        }
        for f in [0.0f32, 0.0, 0.0, 2.0, 0.0, 4.0] {
            bin.extend(f.to_le_bytes());
        }
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        let node = if matrix {
            r#"{"mesh":0,"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}"#
        } else {
            r#"{"mesh":0}"#
        };
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":[{node}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "buffers":[{{"byteLength":{},"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},
                           {{"buffer":0,"byteOffset":36,"byteLength":8}},
                           {{"buffer":0,"byteOffset":44,"byteLength":24}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":2,"type":"SCALAR","min":[{}],"max":[{}]}},
                         {{"bufferView":2,"componentType":5126,"count":2,"type":"VEC3"}}],
            "animations":[{{"channels":[{{"sampler":0,"target":{{"node":0,"path":"translation"}}}}],
                            "samplers":[{{"input":1,"output":2}}]}}]}}"#,
            bin.len(),
            times[0],
            times[1]
        )
        .into_bytes()
    }

    /// A triangle (0,0,0) (1,0,0) (0,1,0) with no animation: with `morph`,
    /// one morph target moving its third vertex by (0,2,0) at the mesh's
    /// default weight 0.5; else skinned, its third vertex bound to joint
    /// node 2 at (3,3,0) and the others to joint node 1 at the origin.
    fn still_deformed_triangle(morph: bool) -> Vec<u8> {
        use base64::Engine;
        let floats: Vec<f32> = [
            // 0: the triangle, 36 bytes
            vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            // 36: the morph target's displacements, 36 bytes
            vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0],
            // 72: the joint weights, 48 bytes
            vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ]
        .concat();
        let mut bin: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
        // 120: the joints (u8 VEC4), 12 bytes
        bin.extend([0u8, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]);
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        let (node, prim, extra) = if morph {
            (
                r#"{"mesh":0}"#,
                r#"{"attributes":{"POSITION":0},"targets":[{"POSITION":1}]}],"weights":[0.5]"#,
                "",
            )
        } else {
            (
                r#"{"mesh":0,"skin":0},{"translation":[0,0,0]},{"translation":[3,3,0]}"#,
                r#"{"attributes":{"POSITION":0,"WEIGHTS_0":2,"JOINTS_0":3}}]"#,
                r#","skins":[{"joints":[1,2]}]"#,
            )
        };
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":[{node}],
            "meshes":[{{"primitives":[{prim}}}],
            "buffers":[{{"byteLength":{},"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},
                           {{"buffer":0,"byteOffset":36,"byteLength":36}},
                           {{"buffer":0,"byteOffset":72,"byteLength":48}},
                           {{"buffer":0,"byteOffset":120,"byteLength":12}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC3"}},
                         {{"bufferView":2,"componentType":5126,"count":3,"type":"VEC4"}},
                         {{"bufferView":3,"componentType":5121,"count":3,"type":"VEC4"}}]{extra}}}"#,
            bin.len(),
        )
        .into_bytes()
    }

    #[test]
    fn a_still_files_morph_weights_and_skins_pose_its_vertices() {
        let path = std::path::Path::new("still.gltf");
        for (morph, third) in [
            (true, Vec3::new(0.0, 2.0, 0.0)),
            (false, Vec3::new(3.0, 4.0, 0.0)),
        ] {
            let bytes = still_deformed_triangle(morph);
            let scene = super::load_still(&bytes, path, Default::default())
                .unwrap_or_else(|e| panic!("morph {morph}: {e}"));
            let tri = scene.triangles[0].map(|v| scene.positions[v as usize]);
            assert_eq!(tri[0], Vec3::ZERO, "morph {morph}");
            assert_eq!(tri[1], Vec3::X, "morph {morph}");
            assert_eq!(tri[2], third, "morph {morph}");
            assert!(scene.normals.is_none());
        }
    }

    fn motion_of(bytes: &[u8]) -> std::result::Result<NodeMotion, String> {
        let path = std::path::Path::new("moving.gltf");
        let loaded = super::super::gltf::load_parts(bytes, path, Default::default())
            .map_err(|e| e.to_string())?;
        Ok(NodeMotion::of(&loaded)?.expect("animated"))
    }

    /// A glTF of one triangle placed by three nodes (node 1 a child of node
    /// 0, node 2 still) whose animation turns node 0, and scales and steps
    /// node 1 (its scale keys `scale_to` at 2 s).
    fn jointed_triangles(scale_to: [f32; 3]) -> Vec<u8> {
        use base64::Engine;
        let floats: Vec<f32> = [
            // 0: the triangle, 36 bytes
            vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            // 36: the times, 8 bytes
            vec![0.0, 2.0],
            // 44: node 0's rotations (a quarter turn about y), 32 bytes
            vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.707_106_77, 0.0, 0.707_106_77],
            // 76: node 1's scales, 24 bytes
            [vec![1.0, 1.0, 1.0], scale_to.to_vec()].concat(),
            // 100: node 1's translations, 24 bytes
            vec![0.0, 1.0, 0.0, 3.0, 1.0, 0.0],
        ]
        .concat();
        let bin: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        let view = |offset: usize, len: usize| {
            format!(r#"{{"buffer":0,"byteOffset":{offset},"byteLength":{len}}}"#)
        };
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,2]}}],
            "nodes":[{{"mesh":0,"children":[1],"translation":[0,0,-1]}},
                     {{"mesh":0,"translation":[0,1,0]}},
                     {{"mesh":0,"translation":[5,0,0]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "buffers":[{{"byteLength":{},"uri":"{uri}"}}],
            "bufferViews":[{},{},{},{},{}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":2,"type":"SCALAR","min":[0],"max":[2]}},
                         {{"bufferView":2,"componentType":5126,"count":2,"type":"VEC4"}},
                         {{"bufferView":3,"componentType":5126,"count":2,"type":"VEC3"}},
                         {{"bufferView":4,"componentType":5126,"count":2,"type":"VEC3"}}],
            "animations":[{{"channels":[{{"sampler":0,"target":{{"node":0,"path":"rotation"}}}},
                                        {{"sampler":1,"target":{{"node":1,"path":"scale"}}}},
                                        {{"sampler":2,"target":{{"node":1,"path":"translation"}}}}],
                            "samplers":[{{"input":1,"output":2}},{{"input":1,"output":3}},
                                        {{"input":1,"output":4,"interpolation":"STEP"}}]}}]}}"#,
            bin.len(),
            view(0, 36),
            view(36, 8),
            view(44, 32),
            view(76, 24),
            view(100, 24),
        )
        .into_bytes()
    }

    /// The animation of `bytes` loaded from a file, as `render --time` does.
    fn animation_of(bytes: &[u8], name: &str) -> crate::scene::motion::Animation {
        let dir = std::env::temp_dir().join(format!("raylab-gltf-motion-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        crate::scene::motion::Animation::load(path.to_str().unwrap(), Default::default(), "--time")
            .unwrap()
    }

    #[test]
    fn rigidly_moving_nodes_are_followed_as_moving_instances_placed_as_the_vertices_would_be() {
        let bytes = jointed_triangles([2.0, 0.5, 1.0]);
        let animation = animation_of(&bytes, "jointed.gltf");
        assert!(animation.moves_instances());
        assert_eq!(animation.rest().instance_count(), 3);
        // The same file followed vertex by vertex, as before.
        let vertices = motion_of(&bytes).unwrap();
        assert!(vertices.is_rigid());
        for t in [0.0, 0.7, 1.0, 1.5, 2.0] {
            let frame = animation.frame(t).unwrap().flattened().unwrap();
            let mut want = vec![Vec3::ZERO; 9];
            vertices.positions_at(t, &mut want).unwrap();
            let got: Vec<Vec3> = (0..frame.triangle_count())
                .flat_map(|i| frame.triangle(i))
                .collect();
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert!((*g - *w).length() < 1e-5, "at {t} s: {g} against {w}");
            }
        }
        // The child moved by its parent's turn: at 2 s node 1's triangle is
        // turned a quarter about y (x goes to -z) and stepped to x = 3.
        let end = animation.frame(2.0).unwrap().flattened().unwrap();
        let child = end.triangle(1);
        assert!((child[1] - child[0] - Vec3::new(0.0, 0.0, -2.0)).length() < 1e-5);
    }

    #[test]
    fn a_scale_through_zero_is_followed_vertex_by_vertex() {
        let bytes = jointed_triangles([2.0, 0.0, 1.0]);
        assert!(!motion_of(&bytes).unwrap().is_rigid());
        let animation = animation_of(&bytes, "collapsing.gltf");
        assert!(!animation.moves_instances());
        // At 2 s node 1's triangle is flat in y (and still traced).
        animation.frame(2.0).unwrap();
    }

    #[test]
    fn a_translation_channel_moves_its_nodes_vertices() {
        let m = motion_of(&translated_triangle(false, [0.0, 2.0])).unwrap();
        assert_eq!(m.duration, 2.0);
        let mut p = vec![Vec3::ZERO; 3];
        m.positions_at(1.0, &mut p).unwrap();
        assert_eq!(
            p,
            [
                Vec3::new(1.0, 0.0, 2.0),
                Vec3::new(2.0, 0.0, 2.0),
                Vec3::new(1.0, 1.0, 2.0)
            ]
        );
        m.positions_at(9.0, &mut p).unwrap();
        assert_eq!(p[0], Vec3::new(2.0, 0.0, 4.0));
    }

    #[test]
    fn animated_matrices_and_unordered_keyframes_are_refused() {
        let err = motion_of(&translated_triangle(true, [0.0, 2.0])).unwrap_err();
        assert!(err.contains("matrix"), "{err}");
        let err = motion_of(&translated_triangle(false, [2.0, 1.0])).unwrap_err();
        assert!(err.contains("increasing"), "{err}");
    }

    fn channel(interpolation: Interpolation, path: Path, values: Vec<f32>) -> Channel {
        let width = if path == Path::Rotation { 4 } else { 3 };
        Channel {
            node: 0,
            path,
            interpolation,
            times: vec![1.0, 2.0],
            values,
            width,
        }
    }

    #[test]
    fn samplers_interpolate_as_the_specification_says() {
        let lin = channel(
            Interpolation::Linear,
            Path::Translation,
            vec![0.0, 0.0, 0.0, 2.0, 4.0, 6.0],
        );
        assert_eq!(sample(&lin, 0.0), vec![0.0, 0.0, 0.0]);
        assert_eq!(sample(&lin, 1.5), vec![1.0, 2.0, 3.0]);
        assert_eq!(sample(&lin, 5.0), vec![2.0, 4.0, 6.0]);
        let step = Channel {
            interpolation: Interpolation::Step,
            ..lin.clone()
        };
        assert_eq!(sample(&step, 1.99), vec![0.0, 0.0, 0.0]);
        // Cubic with zero tangents: smoothstep between the values.
        let mut v = vec![0.0; 18];
        v[12..15].copy_from_slice(&[4.0, 4.0, 4.0]);
        let cubic = channel(Interpolation::CubicSpline, Path::Translation, v);
        assert_eq!(sample(&cubic, 1.5), vec![2.0, 2.0, 2.0]);
        assert!((sample(&cubic, 1.25)[0] - 4.0 * (3.0 * 0.0625 - 2.0 * 0.015625)).abs() < 1e-6);
        // Rotation: the half-way slerp of a quarter turn is an eighth.
        let q = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let mut rv = Quat::IDENTITY.to_array().to_vec();
        rv.extend(q.to_array());
        let rot = channel(Interpolation::Linear, Path::Rotation, rv);
        let half = Quat::from_slice(&sample(&rot, 1.5));
        assert!(half.angle_between(Quat::from_rotation_y(std::f32::consts::FRAC_PI_4)) < 1e-5);
    }
}
