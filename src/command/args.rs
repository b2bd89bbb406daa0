//! Flags shared by several commands (camera and lighting, BVH and Embree
//! options) and the value parsers clap calls.

use clap::Args;
use glam::Vec3;

use crate::accel::bvh::{BuildParams, BuilderKind};
use crate::accel::embree::Quality;
use crate::accel::{BackendKind, BackendSpec, Query};
use crate::camera::default_view;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::Intersector;
use crate::render::default_ao_dist;
use crate::render::{AoMode, RenderSettings};
use crate::scene::is_scene_file;
use crate::scene::light::LightArg;
use crate::scene::load::load_scene_with;
use crate::scene::refs::RefPolicy;
use crate::scene::Scene;

/// Camera, lighting and shading flags shared by commands that render.
#[derive(Args, Debug, Clone)]
pub struct ViewArgs {
    /// Eye position [default: (0,1,3) for the built-in boxes; for other scenes
    /// the framing rule (docs/reference.md)].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    pub eye: Option<Vec3>,
    /// Point looked at [default: (0,1,0) for the built-in boxes; the centre of
    /// the scene's bounding box for other scenes].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_vec3)]
    pub look: Option<Vec3>,
    /// Up vector (also the axis the default light and view are placed along).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, default_value = "0,1,0", value_parser = parse_vec3)]
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180), and no narrower than f32 rays resolve at the image's height (0.042 at 768 pixels).
    #[arg(long, value_name = "DEG", default_value_t = 60.0, allow_negative_numbers = true, value_parser = parse_fov)]
    pub fov: f32,
    /// Image size.
    #[arg(long, value_name = "WxH", default_value = "1024x768", value_parser = parse_size)]
    pub size: (u32, u32),
    /// The most pixels an image may have, checked before its buffers (about
    /// 24 bytes a pixel) are allocated: the default, 100 million (2.4 GB),
    /// takes 10000x10000.
    #[arg(long, value_name = "N", default_value_t = crate::scene::budget::DEFAULT_MAX_PIXELS, value_parser = parse_budget)]
    pub max_pixels: u64,
    /// Ambient occlusion: off, paper (the study's 14 fixed directions) or cosine:N.
    #[arg(long, value_name = "MODE", default_value = "paper")]
    pub ao: AoMode,
    /// Length of AO rays in scene units [default: 0.2 for the built-in boxes,
    /// 1/16 of the bounding box's diagonal for other scenes].
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    pub ao_dist: Option<f32>,
    /// Shadow rays per pixel towards the lights.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub light_samples: u32,
    /// A light that is not geometry: point:X,Y,Z (or point:X,Y,Z:INTENSITY), or
    /// quad:X,Y,Z:SIZE (or quad:X,Y,Z:SIZE:RADIANCE), a square facing down
    /// the --up axis;
    /// without a power it gives the default light's irradiance at the scene's
    /// centre. It is added to the scene's emitters, and replaces the default
    /// light of a scene without.
    #[arg(long, value_name = "SPEC", allow_hyphen_values = true)]
    pub light: Option<LightArg>,
    /// Emitters shine from both faces, not only from the side their winding's
    /// normal points to.
    #[arg(long)]
    pub two_sided_lights: bool,
    /// Seed of the per-pixel random streams.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
}

impl ViewArgs {
    /// Lights `scene` as the flags say (a `--light`, or the default light of a
    /// scene without emissive triangles, with a warning) and makes the render
    /// settings: the camera from the flags or, where they are not given, the
    /// scene's default view.
    pub fn prepare(&self, scene: &mut Scene) -> Result<RenderSettings> {
        self.check()?;
        crate::scene::budget::set_max_pixels(self.max_pixels);
        if let Some(msg) = crate::scene::budget::pixels_over(self.size.0, self.size.1) {
            return Err(Error::usage("--size", msg));
        }
        scene.check_traceable()?;
        if let Some(w) = scene.precision_warning() {
            scene.warnings.push(w);
        }
        let light = self.light.map(|l| l.emitter(&scene.bounds(), self.up));
        scene.set_extra_light(light, self.up);
        self.check_lights(scene)?;
        let (width, height) = self.size;
        let (eye, look) = default_view(scene, self.eye, self.look, self.up, self.fov, self.size);
        if !(eye.is_finite() && look.is_finite()) {
            return Err(Error::Scene {
                name: scene.name.clone(),
                msg: "too large to frame with f32 rays (the default view's eye is beyond f32): give --eye and --look".into(),
            });
        }
        let camera = Camera::new(eye, look, self.up, self.fov, width, height)?;
        let settings = RenderSettings {
            width,
            height,
            camera,
            ao: self.ao,
            ao_dist: self.ao_dist.unwrap_or_else(|| default_ao_dist(scene)),
            light_samples: self.light_samples,
            seed: self.seed,
            two_sided_lights: self.two_sided_lights,
        };
        settings.validate()?;
        Ok(settings)
    }
}

impl ViewArgs {
    /// Refuses flags that another flag makes meaningless (they used to be
    /// ignored silently); called before any scene is loaded, and again by
    /// [`ViewArgs::prepare`].
    pub fn check(&self) -> Result<()> {
        if self.ao == AoMode::Off && self.ao_dist.is_some() {
            return Err(Error::usage(
                "--ao-dist",
                "sets the length of AO rays, and --ao off casts none",
            ));
        }
        Ok(())
    }

    /// Refuses lighting flags that change nothing in `scene` once lit.
    fn check_lights(&self, scene: &Scene) -> Result<()> {
        let lights = &scene.lights;
        let only_point = lights.triangles.is_empty()
            && matches!(
                lights.extra,
                Some(crate::scene::light::Emitter::Point { .. })
            );
        if only_point && self.light_samples > 1 {
            // Every sample of a point light is the same ray: N of them only
            // inflate the ray counts and Mrays/s.
            return Err(Error::usage(
                "--light-samples",
                format!(
                    "a point light is sampled by one shadow ray (its {} samples would be identical rays), and scene {} has no emissive triangles: give --light-samples 1",
                    self.light_samples, scene.name
                ),
            ));
        }
        let user_quad = matches!(
            lights.extra,
            Some(crate::scene::light::Emitter::Quad { .. })
        ) && self.light.is_some();
        if self.two_sided_lights && lights.triangles.is_empty() && !user_quad {
            return Err(Error::usage(
                "--two-sided-lights",
                format!(
                    "scene {} has no emissive triangles, and its light ({}) has no second face to shine from",
                    scene.name,
                    if self.light.is_some() { "--light point" } else { "the default light above the scene, facing it" }
                ),
            ));
        }
        Ok(())
    }
}

/// The argument ids of [`ViewArgs`]' flags, with the flags.
pub const VIEW_FLAGS: &[(&str, &str)] = &[
    ("eye", "--eye"),
    ("look", "--look"),
    ("up", "--up"),
    ("fov", "--fov"),
    ("size", "--size"),
    ("ao", "--ao"),
    ("ao_dist", "--ao-dist"),
    ("light_samples", "--light-samples"),
    ("light", "--light"),
    ("two_sided_lights", "--two-sided-lights"),
    ("seed", "--seed"),
];

/// The first of `flags` (argument id, flag) given on the command line
/// (defaults do not count).
pub fn first_given<'a>(m: &clap::ArgMatches, flags: &[(&str, &'a str)]) -> Option<&'a str> {
    use clap::parser::ValueSource;
    flags
        .iter()
        .find(|(id, _)| m.value_source(id) == Some(ValueSource::CommandLine))
        .map(|(_, flag)| *flag)
}

/// How scene files are read, for the commands that load them.
#[derive(Args, Debug, Clone, Default)]
pub struct SceneFileArgs {
    /// Let a scene file's references (glTF buffer URIs, OBJ mtllib names)
    /// lead outside its folder: absolute paths, `..`, symbolic links out.
    /// Off by default, because a downloaded scene could otherwise make
    /// raylab read (and show parts of) any file you can read.
    #[arg(long)]
    pub allow_outside_refs: bool,
}

impl SceneFileArgs {
    pub fn policy(&self) -> RefPolicy {
        RefPolicy {
            allow_outside: self.allow_outside_refs,
        }
    }

    /// Refuses `--allow-outside-refs` when none of `scenes` is a file: the
    /// built-in scenes refer to nothing, and a flag that changes nothing is
    /// not accepted silently.
    pub fn check(&self, scenes: &[String]) -> Result<()> {
        if self.allow_outside_refs && !scenes.iter().any(|s| is_scene_file(s)) {
            return Err(Error::usage(
                "--allow-outside-refs",
                "applies to scene files' references; built-in scenes have none",
            ));
        }
        Ok(())
    }

    /// Loads `spec` under these flags, an instanced scene baked into one
    /// triangle list ([`Scene::flattened`]): for the commands that trace one
    /// list (within the triangle budget, else an error naming it).
    pub fn load(&self, spec: &str) -> Result<Scene> {
        load_scene_with(spec, self.policy())?.flattened()
    }

    /// Loads `spec` under these flags, its instances kept: for the commands
    /// that trace instances with two-level trees.
    pub fn load_instanced(&self, spec: &str) -> Result<Scene> {
        load_scene_with(spec, self.policy())
    }
}

/// The default backend's tree and test ([`BackendSpec::DEFAULT`]), which
/// the BVH flags' defaults are read from.
const DEFAULT_BVH: (BuildParams, Intersector) = match BackendSpec::DEFAULT {
    BackendSpec::Bvh {
        params,
        intersector,
        ..
    } => (params, intersector),
    _ => panic!("the default backend is raylab's BVH"),
};

/// How a BVH is built (used with `--backend bvh`).
#[derive(Args, Debug, Clone)]
pub struct BvhArgs {
    /// BVH builder: median (the study's), lbvh (Morton codes, the fastest
    /// build), sah (binned SAH), sbvh (spatial splits, the best trees), or
    /// Embree's builders in raylab's layout (embree-low, -medium, -high).
    #[arg(long, value_enum, default_value_t = DEFAULT_BVH.0.builder)]
    pub builder: BuilderKind,
    /// Reinsertion optimisation of the BVH after the build (Bittner et al.
    /// 2013): the nodes with the largest boxes move to where they lower the
    /// SAH cost most (3 rounds of 5% of the nodes at most).
    #[arg(long)]
    pub optimize: bool,
    /// Most triangles per BVH leaf [default: 1 for median, 4 for sah].
    #[arg(long, value_name = "N", value_parser = parse_leaf_size)]
    pub leaf_size: Option<usize>,
    /// Threads for the BVH build [default: --threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub build_threads: Option<usize>,
    /// Ray/triangle test of the naive and bvh backends.
    #[arg(long, value_enum, default_value_t = DEFAULT_BVH.1)]
    pub intersector: Intersector,
    /// Children per BVH node traversed: 8 (8-wide nodes tested with AVX2 where
    /// the CPU has it; the fastest), 4 (4-wide nodes tested with SSE), or 2 (the
    /// binary tree). Wide trees are built directly (Embree's builders: collapsed).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_BVH.0.width, value_parser = parse_bvh_width)]
    pub bvh_width: usize,
}

fn parse_bvh_width(s: &str) -> std::result::Result<usize, String> {
    match s {
        "2" => Ok(2),
        "4" => Ok(4),
        "8" => Ok(8),
        _ => Err(format!("'{s}' must be 2, 4 or 8")),
    }
}

impl BvhArgs {
    pub fn params(&self, builder: BuilderKind, threads: usize) -> BuildParams {
        let p = BuildParams::for_builder(builder)
            .with_threads(self.build_threads.unwrap_or(threads))
            .with_width(self.bvh_width)
            .with_optimize(self.optimize);
        match self.leaf_size {
            Some(n) => p.with_max_leaf_size(n),
            None => p,
        }
    }
}

/// How the Embree backend builds its scene (used with `--backend embree`).
#[derive(Args, Debug, Clone)]
pub struct EmbreeArgs {
    /// Embree's scene build quality (high: with raylab's SBVH reference
    /// budget, 2 references per triangle, not Embree's default 1.2).
    #[arg(long, value_enum, default_value_t = Quality::Medium, conflicts_with = "quality")]
    pub embree_quality: Quality,
    /// Set RTC_SCENE_FLAG_ROBUST (watertight-leaning traversal, slower).
    #[arg(long)]
    pub embree_robust: bool,
}

/// The backend a command builds, and how (`--backend` and the options of each
/// backend).
#[derive(Args, Debug, Clone)]
pub struct BackendArgs {
    /// Acceleration structure [default: bvh, raylab's fastest; naive is the
    /// study's O(N) baseline, hours on a large model].
    #[arg(long, value_enum, default_value_t = BackendSpec::DEFAULT.kind())]
    pub backend: BackendKind,
    #[command(flatten)]
    pub bvh: BvhArgs,
    #[command(flatten)]
    pub embree: EmbreeArgs,
    /// How the renderer's streams of rays are traced: single (one ray at a
    /// time), packet4, packet8 or packet16 (packets of neighbouring rays: Embree
    /// has all three, raylab's 8-wide tree packet8 and packet16, the latter
    /// in AVX-512 lanes where the CPU has it), or stream (Embree 3's
    /// rtcIntersect1M). The image is the same whichever path [default: the
    /// backend's fastest, see docs/reference.md].
    #[arg(long, value_name = "PATH")]
    pub query: Option<Query>,
    /// The rung of the build-quality ladder, for raylab's BVH and Embree
    /// alike: low (raylab's LBVH; Embree's Morton builder), medium (binned
    /// SAH, the default) or high (spatial splits: raylab's SBVH; Embree's
    /// high quality; raylab's reinsertion-optimised). Instead of --builder
    /// or --embree-quality.
    #[arg(long, value_enum, conflicts_with = "builder")]
    pub quality: Option<Quality>,
    /// The tree layout of another library's BVH: for tinybvh bvh8 (its
    /// BVH8_CPU, the default) or bvh (its binary tree); for obvhs cwbvh (the
    /// default) or bvh2.
    #[arg(long, value_enum)]
    pub layout: Option<LibraryLayout>,
}

/// `--layout`: the tree layouts of the other libraries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LibraryLayout {
    /// tinybvh's 8-wide BVH8_CPU.
    Bvh8,
    /// tinybvh's binary tree.
    Bvh,
    /// obvhs's compressed 8-wide tree.
    Cwbvh,
    /// obvhs's binary tree.
    Bvh2,
}

crate::names::value_names!(LibraryLayout);

impl BackendArgs {
    /// The backend these flags describe, built on `threads`.
    pub fn spec(&self, threads: usize) -> Result<BackendSpec> {
        let spec = match self.backend {
            kind if kind.is_library() => library_spec(kind, self.layout, self.quality, threads)?,
            kind => backend_spec(kind, &self.bvh, &self.embree, self.quality, threads),
        };
        match self.query {
            Some(q) => spec.with_query(q),
            None => Ok(spec.with_fastest_query()),
        }
    }
}

/// The backend a command's flags describe.
fn backend_spec(
    kind: BackendKind,
    bvh: &BvhArgs,
    embree: &EmbreeArgs,
    quality: Option<Quality>,
    threads: usize,
) -> BackendSpec {
    // A rung is a builder and whether it optimises (BuildParams::for_quality).
    let rung = quality.map(BuildParams::for_quality);
    let builder = rung.map_or(bvh.builder, |r| r.builder);
    let params = bvh.params(builder, threads);
    let params = params.with_optimize(params.optimize || rung.is_some_and(|r| r.optimize));
    match kind {
        BackendKind::Naive => BackendSpec::Naive {
            intersector: bvh.intersector,
        },
        BackendKind::Bvh => BackendSpec::Bvh {
            params,
            intersector: bvh.intersector,
            query: Query::Single,
        },
        BackendKind::Embree => BackendSpec::Embree {
            quality: quality.unwrap_or(embree.embree_quality),
            robust: embree.embree_robust,
            threads: params.threads,
            query: Query::Single,
        },
        library => BackendSpec::default_for(library, params.threads),
    }
}

/// Another library's BVH as `--layout` and `--quality` describe it; a layout
/// or rung the library does not have is a one-line error.
fn library_spec(
    kind: BackendKind,
    layout: Option<LibraryLayout>,
    quality: Option<Quality>,
    threads: usize,
) -> Result<BackendSpec> {
    use crate::accel::library::{Library, ObvhsLayout, TinybvhLayout};
    let no_layout = |have: &str| {
        Error::usage(
            "--layout",
            format!(
                "--backend {} has no {} layout (it has: {have})",
                kind.name(),
                layout.map_or("", LibraryLayout::name)
            ),
        )
    };
    let library = match kind {
        BackendKind::Tinybvh => {
            let layout = match layout {
                None | Some(LibraryLayout::Bvh8) => TinybvhLayout::Bvh8,
                Some(LibraryLayout::Bvh) => TinybvhLayout::Bvh,
                Some(_) => return Err(no_layout("bvh8, bvh")),
            };
            let hq = match quality {
                None | Some(Quality::Medium) => false,
                Some(Quality::High) => true,
                Some(Quality::Low) => {
                    return Err(Error::usage(
                        "--quality",
                        "tinybvh-rs has no low-quality build (it wraps Build, medium, and BuildHQ, high)",
                    ))
                }
            };
            Library::Tinybvh { layout, hq }
        }
        BackendKind::Obvhs => {
            let layout = match layout {
                None | Some(LibraryLayout::Cwbvh) => ObvhsLayout::CwBvh,
                Some(LibraryLayout::Bvh2) => ObvhsLayout::Bvh2,
                Some(_) => return Err(no_layout("cwbvh, bvh2")),
            };
            Library::Obvhs {
                layout,
                quality: quality.unwrap_or(Quality::Medium),
            }
        }
        _ => {
            if layout.is_some() {
                return Err(no_layout("one binary tree, no --layout"));
            }
            if quality.is_some() {
                return Err(Error::usage(
                    "--quality",
                    "the bvh crate has one builder (binned SAH): no quality ladder",
                ));
            }
            Library::BvhCrate
        }
    };
    Ok(BackendSpec::library(library, threads))
}

pub fn parse_leaf_size(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=255).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' must be a whole number in 1..=255")),
    }
}

pub fn parse_vec3(s: &str) -> std::result::Result<Vec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers X,Y,Z, got {}",
            parts.len()
        ));
    }
    let mut v = [0.0f32; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p.parse().map_err(|_| format!("'{p}' is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("'{p}' is not finite"));
        }
    }
    Ok(Vec3::from_array(v))
}

pub fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| "expected WIDTHxHEIGHT, e.g. 1024x768".to_string())?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("width '{w}' is not a whole number"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("height '{h}' is not a whole number"))?;
    if w == 0 || h == 0 {
        return Err("width and height must be at least 1".into());
    }
    if w > 16384 || h > 16384 {
        return Err("width and height must be at most 16384".into());
    }
    Ok((w, h))
}

/// A budget (`--max-triangles`, `--max-pixels`): a whole number from 1.
pub fn parse_budget(s: &str) -> std::result::Result<u64, String> {
    match s.parse::<u64>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("'{s}' is not a whole number of at least 1")),
    }
}

pub fn parse_fov(s: &str) -> std::result::Result<f32, String> {
    let f: f32 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(f > 0.0 && f < 180.0) {
        return Err(format!("{f} is outside (0, 180) degrees"));
    }
    Ok(f)
}

pub fn parse_threads(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=1024).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' must be a whole number in 1..=1024")),
    }
}

/// Refuses backend flags given on the command line that the chosen backend
/// would ignore (they used to be ignored silently).
pub fn check_backend_flags(m: &clap::ArgMatches, backend: BackendKind) -> Result<()> {
    use clap::parser::ValueSource;
    // (argument id, flag, the backends it applies to)
    const FLAGS: &[(&str, &str, &[BackendKind])] = &[
        ("builder", "--builder", &[BackendKind::Bvh]),
        ("leaf_size", "--leaf-size", &[BackendKind::Bvh]),
        ("optimize", "--optimize", &[BackendKind::Bvh]),
        ("bvh_width", "--bvh-width", &[BackendKind::Bvh]),
        (
            "build_threads",
            "--build-threads",
            &[
                BackendKind::Bvh,
                BackendKind::Embree,
                BackendKind::Obvhs,
                BackendKind::BvhCrate,
            ],
        ),
        (
            "intersector",
            "--intersector",
            &[BackendKind::Naive, BackendKind::Bvh],
        ),
        ("embree_quality", "--embree-quality", &[BackendKind::Embree]),
        (
            "quality",
            "--quality",
            &[
                BackendKind::Bvh,
                BackendKind::Embree,
                BackendKind::Tinybvh,
                BackendKind::Obvhs,
            ],
        ),
        (
            "layout",
            "--layout",
            &[BackendKind::Tinybvh, BackendKind::Obvhs],
        ),
        ("embree_robust", "--embree-robust", &[BackendKind::Embree]),
    ];
    let name = |k: &BackendKind| k.name();
    for (id, flag, applies) in FLAGS {
        let given = m.value_source(id) == Some(ValueSource::CommandLine);
        if given && !applies.contains(&backend) {
            let to: Vec<String> = applies
                .iter()
                .map(|k| format!("--backend {}", name(k)))
                .collect();
            return Err(Error::usage(
                flag,
                format!(
                    "applies only to {}, not to --backend {}",
                    to.join(" or "),
                    name(&backend)
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Flags {
        #[command(flatten)]
        backend: BackendArgs,
    }

    #[test]
    fn no_flags_build_the_default_backend() {
        let flags = Flags::try_parse_from(["raylab"]).unwrap();
        let spec = flags.backend.spec(3).unwrap();
        assert_eq!(
            spec,
            BackendSpec::DEFAULT
                .with_build_threads(3)
                .with_fastest_query()
        );
    }
}
