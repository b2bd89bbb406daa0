//! The minimal scene every backend and the renderer read: flat arrays of vertex
//! positions, optional vertex normals, index triples, a material per triangle, the
//! material table (only what MTL files give and the shader uses) and the emissive
//! triangles with their areas for light sampling. No scene graph.

pub(crate) mod asteroids;
pub(crate) mod budget;
pub mod builtin;
pub(crate) mod forest;
pub(crate) mod gltf;
pub(crate) mod gltf_motion;
pub(crate) mod instancing;
pub(crate) mod light;
pub mod load;
pub mod motion;
pub mod obj;
pub(crate) mod placement;
pub(crate) mod ply;
pub(crate) mod polygon;
pub(crate) mod refs;
mod shapes;

use std::sync::Arc;

use glam::Vec3;

use crate::error::{Error, Result};
use crate::geometry::{triangle_area, triangle_unit_normal, Aabb};

/// What raylab reads, for messages.
pub const READS: &str = "raylab reads OBJ (.obj), PLY (.ply) and glTF 2.0 (.gltf, .glb)";

/// File extensions of scene formats raylab reads, in lower case.
pub const EXTENSIONS: &[&str] = &["obj", "ply", "gltf", "glb"];

/// Whether [`load::load_scene`] takes `spec` for a file rather than a built-in name.
pub fn is_scene_file(spec: &str) -> bool {
    let path = std::path::Path::new(spec);
    let has_scene_extension = path.extension().is_some_and(|e| {
        let e = e.to_string_lossy().to_ascii_lowercase();
        EXTENSIONS.contains(&e.as_str())
    });
    has_scene_extension || spec.contains(std::path::MAIN_SEPARATOR) || path.is_file()
}

/// The largest coordinate a scene may have to be rendered: Moller-Trumbore
/// and the watertight test multiply three coordinates (edge x edge . offset),
/// which overflow f32 (3.4e38) near 7e12. The Cornell box scaled until its
/// coordinates reach 4e12 renders as at 1 with every test; at 6e12 it is dim
/// with raylab's tests, at 2e13 black (Embree's still lit, wrongly); so half
/// of the largest that rendered right.
pub const MAX_TRACEABLE_COORDINATE: f32 = 2e12;

/// The smallest extent (bounding-box diagonal) a scene may have to be
/// rendered: products of three lengths underflow into denormals, which
/// Embree flushes to zero (the Cornell box scaled to 1e-13 renders dim with
/// Embree, at 1e-20 black with every backend), and the default view's eye
/// rounds onto the point it looks at.
pub const MIN_TRACEABLE_EXTENT: f32 = 1e-10;

/// Fewer f32 steps of its coordinates than this across, and a scene is
/// rendered with a warning ([`Scene::precision_warning`]): far:N (a mesh
/// about 10 units across at 1e5, where a step is 0.0078) has about 1,300.
pub const MIN_STEPS_ACROSS: f32 = 256.0;

/// A box's farthest coordinate from the origin and its diagonal: what f32
/// rays can and cannot trace ([`Scene::check_traceable`],
/// [`Scene::precision_warning`]).
fn reach_and_extent(b: &Aabb) -> (f32, f32) {
    (
        b.min.abs().max(b.max.abs()).max_element(),
        (b.max - b.min).length(),
    )
}

/// The MTL values the shader uses; everything else in an MTL file is ignored.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    /// Ambient reflectance (MTL `Ka`), scaled by the ambient light and AO.
    pub ka: Vec3,
    /// Diffuse reflectance (MTL `Kd`).
    pub kd: Vec3,
    /// Specular reflectance (MTL `Ks`) of the Blinn-Phong lobe.
    pub ks: Vec3,
    /// Blinn-Phong exponent (MTL `Ns`).
    pub ns: f32,
    /// Emitted radiance (MTL `Ke`); a triangle is a light when any component is > 0.
    pub ke: Vec3,
}

impl Material {
    /// The grey used when an MTL file is missing or a face names no material.
    pub fn default_grey() -> Self {
        Material {
            name: "default".into(),
            ka: Vec3::splat(0.6),
            kd: Vec3::splat(0.6),
            ks: Vec3::ZERO,
            ns: 10.0,
            ke: Vec3::ZERO,
        }
    }

    pub fn diffuse(name: &str, kd: Vec3) -> Self {
        Material {
            name: name.into(),
            ka: kd,
            kd,
            ks: Vec3::ZERO,
            ns: 10.0,
            ke: Vec3::ZERO,
        }
    }

    pub fn is_emissive(&self) -> bool {
        self.ke.max_element() > 0.0
    }
}

/// The emissive triangles and a cumulative distribution over their areas, so a
/// light sample picks a triangle with probability proportional to its area; and
/// at most one light that is not geometry (the default light of a scene without
/// emitters, or `--light`).
#[derive(Clone, Debug, Default)]
pub struct Lights {
    /// A light outside the triangles; a shadow sample picks it or the emissive
    /// triangles with probability 1/2 each when both exist.
    pub extra: Option<light::Emitter>,
    /// Indices of emissive triangles.
    pub triangles: Vec<u32>,
    /// In an instanced scene, the instance each of `triangles` is placed by
    /// (a light per emissive triangle per instance); empty otherwise.
    pub instances: Vec<u32>,
    /// `cdf[i]` = (area of lights 0..=i) / total area; the last entry is 1.
    pub cdf: Vec<f32>,
    /// Summed area of all emissive triangles.
    pub total_area: f32,
}

impl Lights {
    /// No light at all: neither emissive triangles nor an extra light.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty() && self.extra.is_none()
    }

    /// The light (an index into `triangles`) for a uniform `u` in [0, 1).
    pub fn pick(&self, u: f32) -> usize {
        let i = self.cdf.partition_point(|&c| c <= u);
        i.min(self.triangles.len() - 1)
    }
}

/// The geometry backends are built over: vertex positions and index
/// triples, borrowed from a [`Scene`] or from raw arrays (the stress suites
/// keep degenerate triangles a scene would drop). Indices must be in range.
#[derive(Clone, Copy, Debug)]
pub struct MeshRef<'a> {
    pub positions: &'a [Vec3],
    pub triangles: &'a [[u32; 3]],
}

impl MeshRef<'_> {
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The three vertex positions of triangle `i`.
    #[inline]
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        self.triangles[i].map(|v| self.positions[v as usize])
    }

    /// All triangles' vertices gathered in index order.
    pub fn triangle_vertices(&self) -> Vec<[Vec3; 3]> {
        (0..self.triangles.len())
            .map(|i| self.triangle(i))
            .collect()
    }
}

impl<'a> From<&'a Scene> for MeshRef<'a> {
    fn from(scene: &'a Scene) -> Self {
        scene.mesh()
    }
}

/// The warning for `n` degenerate triangles dropped.
pub(crate) fn dropped_warning(n: usize) -> String {
    format!("dropped {n} degenerate (zero-area) triangles")
}

/// A triangle scene in flat arrays.
#[derive(Clone, Debug)]
pub struct Scene {
    /// A name for reports: the built-in name or the file path.
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Per-vertex normals, indexed like `positions`; a zero vector means "none for
    /// this vertex" (then the shader uses the geometric normal).
    pub normals: Option<Vec<Vec3>>,
    pub triangles: Vec<[u32; 3]>,
    /// Material index per triangle.
    pub material_ids: Vec<u32>,
    pub materials: Vec<Material>,
    pub lights: Lights,
    /// Zero-area triangles removed when the scene was made.
    pub dropped_degenerate: usize,
    /// Non-fatal problems met while loading, one line each (shown to the user).
    pub warnings: Vec<String>,
    /// The scene is one of the built-in boxes, in the study's frame: the study's
    /// view (eye (0,1,3) looking at (0,1,0)) and AO distance (0.2) are its
    /// defaults. Other scenes are framed by their bounds ([`crate::camera::framing`]).
    pub study_frame: bool,
    /// The meshes and their instances, for a scene that places meshes by
    /// instances ([`instancing`]): then the arrays above hold each mesh once,
    /// in its own space. `None`: the triangles are in world space, placed once.
    pub instancing: Option<Arc<placement::Instancing>>,
    /// The bounds [`Scene::bounds`] reports instead of its vertices' own: a
    /// flattened instanced scene keeps its instanced bounds (boxes of the
    /// instances' boxes), so the camera and default light frame it as they
    /// frame its instances and `--flatten` renders the same view.
    pub framed_bounds: Option<Aabb>,
}

impl Scene {
    /// Makes a scene from raw arrays: checks that indices and material ids are in
    /// range and positions finite, drops zero-area triangles (counted in
    /// `dropped_degenerate`) and finds the lights.
    ///
    /// Errors when no triangle is left, so every scene handed to a backend has at
    /// least one triangle with non-zero area.
    pub fn new(
        name: impl Into<String>,
        positions: Vec<Vec3>,
        normals: Option<Vec<Vec3>>,
        triangles: Vec<[u32; 3]>,
        material_ids: Vec<u32>,
        materials: Vec<Material>,
    ) -> Result<Scene> {
        let name = name.into();
        let fail = |msg: String| Error::Scene {
            name: name.clone(),
            msg,
        };
        if material_ids.len() != triangles.len() {
            return Err(fail("one material id per triangle expected".into()));
        }
        if let Some(n) = &normals {
            if n.len() != positions.len() {
                return Err(fail("one normal per vertex expected".into()));
            }
        }
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(fail(format!("vertex {i} is not finite")));
        }
        let mut kept_tris = Vec::with_capacity(triangles.len());
        let mut kept_mats = Vec::with_capacity(triangles.len());
        let mut dropped = 0;
        for (i, (tri, &m)) in triangles.iter().zip(&material_ids).enumerate() {
            if tri.iter().any(|&v| v as usize >= positions.len()) {
                return Err(fail(format!(
                    "triangle {i} has a vertex index out of range"
                )));
            }
            if m as usize >= materials.len() {
                return Err(fail(format!("triangle {i} has a material id out of range")));
            }
            let verts = tri.map(|v| positions[v as usize]);
            // Zero area: no ray can hit it, and it has no normal to shade with.
            if triangle_unit_normal(&verts) == Vec3::ZERO {
                dropped += 1;
                continue;
            }
            kept_tris.push(*tri);
            kept_mats.push(m);
        }
        if kept_tris.is_empty() {
            let msg = if dropped > 0 {
                format!("no triangles left ({dropped} degenerate ones dropped)")
            } else {
                "no triangles".to_string()
            };
            return Err(fail(msg));
        }
        let mut scene = Scene {
            name,
            positions,
            normals,
            triangles: kept_tris,
            material_ids: kept_mats,
            materials,
            lights: Lights::default(),
            dropped_degenerate: dropped,
            warnings: Vec::new(),
            study_frame: false,
            instancing: None,
            framed_bounds: None,
        };
        scene.lights = scene.find_lights();
        if dropped > 0 {
            scene.warnings.push(dropped_warning(dropped));
        }
        Ok(scene)
    }

    /// [`Scene::new`] for a loader: the scene is named by `path`, an error names
    /// the file, and the loader's own `warnings` come before the scene's.
    pub(crate) fn from_file(
        path: &std::path::Path,
        positions: Vec<Vec3>,
        normals: Option<Vec<Vec3>>,
        triangles: Vec<[u32; 3]>,
        material_ids: Vec<u32>,
        materials: Vec<Material>,
        mut warnings: Vec<String>,
    ) -> Result<Scene> {
        let mut scene = Scene::new(
            path.display().to_string(),
            positions,
            normals,
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

    fn find_lights(&self) -> Lights {
        let mut triangles = Vec::new();
        let mut cumulative = Vec::new();
        let mut total = 0.0f64;
        for (i, &m) in self.material_ids.iter().enumerate() {
            if self.materials[m as usize].is_emissive() {
                total += triangle_area(&self.triangle(i)) as f64;
                triangles.push(i as u32);
                cumulative.push(total);
            }
        }
        let cdf = cumulative.iter().map(|&c| (c / total) as f32).collect();
        Lights {
            extra: None,
            triangles,
            instances: Vec::new(),
            cdf,
            total_area: total as f32,
        }
    }

    /// Gives the scene its light outside the triangles: `light` when given, else
    /// the default area light ([`light::Emitter::default_for`], placed along
    /// `up`) when it has no emissive triangles, with a warning saying so.
    pub fn set_extra_light(&mut self, light: Option<light::Emitter>, up: Vec3) {
        self.lights.extra = light;
        if light.is_none() && self.lights.triangles.is_empty() {
            self.lights.extra = Some(light::Emitter::default_for(&self.bounds(), up));
            self.warnings.push(
                "the scene has no emissive triangles: lit by the default area light above it (--light places one)"
                    .into(),
            );
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Its geometry, as backends are built over it: world-space triangles
    /// only in a scene without instances (an instanced scene's are its
    /// meshes, each in its own space; [`Scene::flattened`] places them).
    pub fn mesh(&self) -> MeshRef<'_> {
        debug_assert!(
            self.instancing.is_none(),
            "a flat backend over an instanced scene's meshes"
        );
        MeshRef {
            positions: &self.positions,
            triangles: &self.triangles,
        }
    }

    /// The three vertex positions of triangle `i`.
    #[inline]
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        self.triangles[i].map(|v| self.positions[v as usize])
    }

    /// All triangles' vertices gathered in index order: what backends intersect.
    pub fn triangle_vertices(&self) -> Vec<[Vec3; 3]> {
        self.mesh().triangle_vertices()
    }

    #[inline]
    pub fn material_of(&self, tri: u32) -> &Material {
        &self.materials[self.material_ids[tri as usize] as usize]
    }

    /// Whether f32 rays can render the scene: its coordinates within
    /// [`MAX_TRACEABLE_COORDINATE`] and its extent at least
    /// [`MIN_TRACEABLE_EXTENT`]; else the error says which, and what to do.
    pub fn check_traceable(&self) -> Result<()> {
        let (reach, extent) = reach_and_extent(&self.bounds());
        let msg = if reach > MAX_TRACEABLE_COORDINATE {
            format!(
                "too large to frame and trace with f32 rays: its coordinates reach {reach:e}, past {MAX_TRACEABLE_COORDINATE:e}, where ray/triangle tests (products of three coordinates) overflow; scale the scene down (and move it near the origin)"
            )
        } else if !(extent >= MIN_TRACEABLE_EXTENT) {
            format!(
                "too small to frame and trace with f32 rays: it is {extent:e} across, under {MIN_TRACEABLE_EXTENT:e}, where ray/triangle tests (products of three lengths) underflow; scale the scene up"
            )
        } else {
            return Ok(());
        };
        Err(Error::Scene {
            name: self.name.clone(),
            msg,
        })
    }

    /// A warning when the scene is so small for where it lies that f32
    /// rounds its shape, its shading points and the lights placed by its
    /// size coarsely: fewer than [`MIN_STEPS_ACROSS`] f32 steps of its
    /// farthest coordinate across (a 0.125-unit triangle at 1e6, where a
    /// step is 0.0625, was 3 steps across, and the default light, a third of
    /// a step above it, rounded into its plane: no direct light at all).
    pub fn precision_warning(&self) -> Option<String> {
        let (reach, extent) = reach_and_extent(&self.bounds());
        let step = reach.next_up() - reach;
        let steps = extent / step;
        (steps < MIN_STEPS_ACROSS).then(|| {
            format!(
                "the scene is {extent:.3e} across where its coordinates reach {reach:.3e}, and f32 steps there are {step:.3e}: {steps:.0} steps across, so its shape, shading and lighting are rounded coarsely (move it near the origin)"
            )
        })
    }

    /// Bounds of all referenced vertices, in world space (an instanced
    /// scene's: every instance's mesh box, moved by its transform).
    pub fn bounds(&self) -> Aabb {
        if let Some(b) = self.framed_bounds {
            return b;
        }
        if let Some(inst) = &self.instancing {
            return Scene::instanced_bounds(inst);
        }
        self.triangles
            .iter()
            .flatten()
            .fold(Aabb::EMPTY, |b, &v| b.grown(self.positions[v as usize]))
    }

    /// The points the camera frames in an instanced scene (and its flattened
    /// copy, which frames as it does): its bounds' corners; `None` for a
    /// scene framed by its vertices.
    pub fn framed_corners(&self) -> Option<[Vec3; 8]> {
        if self.instancing.is_none() && self.framed_bounds.is_none() {
            return None;
        }
        let b = self.bounds();
        Some(std::array::from_fn(|c| {
            Vec3::new(
                if c & 1 == 0 { b.min.x } else { b.max.x },
                if c & 2 == 0 { b.min.y } else { b.max.y },
                if c & 4 == 0 { b.min.z } else { b.max.z },
            )
        }))
    }

    /// The interpolated vertex normal at barycentrics `(u, v)` of `tri`, if the
    /// scene has usable normals there (non-zero, finite after interpolation).
    pub fn shading_normal(&self, tri: u32, u: f32, v: f32) -> Option<Vec3> {
        let normals = self.normals.as_ref()?;
        let [a, b, c] = self.triangles[tri as usize].map(|i| normals[i as usize]);
        let n = a * (1.0 - u - v) + b * u + c * v;
        let n = n.normalize_or_zero();
        (n != Vec3::ZERO).then_some(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_scene(emissive: bool) -> Result<Scene> {
        let mut light = Material::diffuse("light", Vec3::ONE);
        if emissive {
            light.ke = Vec3::splat(5.0);
        }
        Scene::new(
            "t",
            vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::Y,
                Vec3::X * 2.0,
            ],
            None,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]],
            vec![0, 1, 0],
            vec![Material::default_grey(), light],
        )
    }

    #[test]
    fn a_scene_few_f32_steps_across_where_it_lies_gets_a_warning() {
        let at = |offset: f32, size: f32| {
            let o = Vec3::splat(offset);
            Scene::new(
                "t",
                vec![o, o + Vec3::X * size, o + Vec3::Y * size],
                None,
                vec![[0, 1, 2]],
                vec![0],
                vec![Material::default_grey()],
            )
            .unwrap()
            .precision_warning()
        };
        let w = at(1e6, 0.125).expect("3 steps across at 1e6");
        assert!(w.contains("3 steps across"), "{w}");
        assert!(at(1e5, 0.125).is_some());
        assert!(at(0.0, 0.125).is_none());
        assert!(at(1e6, 1000.0).is_none());
        assert!(crate::scene::builtin::builtin("far:2000")
            .unwrap()
            .precision_warning()
            .is_none());
    }

    #[test]
    fn degenerate_triangles_are_dropped_and_counted() {
        let s = quad_scene(true).unwrap();
        assert_eq!(s.triangle_count(), 2);
        assert_eq!(s.dropped_degenerate, 1);
        assert_eq!(s.warnings.len(), 1);
    }

    #[test]
    fn lights_are_found_with_areas() {
        let s = quad_scene(true).unwrap();
        assert_eq!(s.lights.triangles, vec![1]);
        assert!((s.lights.total_area - 0.5).abs() < 1e-6);
        assert_eq!(s.lights.pick(0.0), 0);
        assert_eq!(s.lights.pick(0.9999), 0);
        assert!(quad_scene(false).unwrap().lights.triangles.is_empty());
    }

    #[test]
    fn out_of_range_and_empty_input_is_an_error() {
        let bad = Scene::new(
            "t",
            vec![Vec3::ZERO],
            None,
            vec![[0, 1, 2]],
            vec![0],
            vec![Material::default_grey()],
        );
        assert!(bad.unwrap_err().to_string().contains("out of range"));
        let empty = Scene::new("t", vec![], None, vec![], vec![], vec![]);
        assert!(empty.unwrap_err().to_string().contains("no triangles"));
        let nan = Scene::new(
            "t",
            vec![Vec3::NAN, Vec3::X, Vec3::Y],
            None,
            vec![[0, 1, 2]],
            vec![0],
            vec![Material::default_grey()],
        );
        assert!(nan.unwrap_err().to_string().contains("not finite"));
    }
}
