//! `raylab render`: its flags, the render, the summary on stderr and the JSON
//! report on stdout.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use serde::Serialize;

use super::args::{parse_threads, BackendArgs, SceneFileArgs, ViewArgs};
use crate::accel::build_scene_backend;
use crate::accel::embree::version_or_none as embree_version;
use crate::error::{Error, Result};
use crate::output;
use crate::progress::Progress;
use crate::render::schedule::default_threads;
use crate::render::{self, srgb, RenderSettings, Schedule};
use crate::table::ms;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// A scene file (.obj, .ply, .gltf, .glb) or a built-in scene name (see
    /// `raylab scenes`).
    #[arg(default_value = "cornell-original")]
    scene: String,
    #[command(flatten)]
    pub accel: BackendArgs,
    /// How the image is divided between threads.
    #[arg(long, value_enum, default_value_t = Schedule::Tiles)]
    schedule: Schedule,
    /// Worker threads for the tiles and rayon schedules [default: all hardware
    /// threads]; refused with serial (one thread) and rows (a thread per row).
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    #[command(flatten)]
    view: ViewArgs,
    #[command(flatten)]
    files: SceneFileArgs,
    /// Output PNG.
    #[arg(
        short = 'o',
        long = "output",
        value_name = "PNG",
        default_value = "out.png"
    )]
    output: PathBuf,
    /// For an animated scene (explode:N, cloth:N): render it as it stands
    /// this many seconds into its animation.
    #[arg(
        long,
        value_name = "SECONDS",
        allow_negative_numbers = true,
        conflicts_with = "frames"
    )]
    time: Option<f32>,
    /// For an animated scene: render frames A to B (inclusive, numbered from
    /// 0 at time 0) at --fps frames per second, each to the output's name
    /// with the frame number added (out.png: out_0000.png, ...), the camera
    /// and default light set from the first frame (see --follow).
    #[arg(long, value_name = "A..B", value_parser = parse_frames)]
    frames: Option<(u32, u32)>,
    /// Frames per second of --frames.
    #[arg(long, value_name = "F", requires = "frames", value_parser = parse_fps)]
    fps: Option<f32>,
    /// With --frames: frame every image from its own bounds (camera and
    /// default light follow the motion) instead of from the first frame's.
    #[arg(long, requires = "frames")]
    follow: bool,
    /// Trace an instanced scene (forest:N, a glTF file that places a mesh
    /// more than once) as one triangle list, its instances baked in, instead
    /// of with a two-level tree (bvh: raylab's; embree: Embree's instances).
    #[arg(long)]
    flatten: bool,
    /// Print one JSON object with the results on stdout (one per frame).
    #[arg(long)]
    json: bool,
    /// No progress bar and no summary on stderr.
    #[arg(long, short = 'q')]
    quiet: bool,
}

/// A rate with three significant digits (the naive scan's 0.0041 Mrays/s read
/// "0.00" with two decimals).
fn significant(x: f64) -> String {
    if !(x.is_finite() && x > 0.0) {
        return format!("{x}");
    }
    let decimals = (2 - x.log10().floor() as i32).clamp(0, 9) as usize;
    format!("{x:.decimals$}")
}

#[derive(Serialize)]
struct RayCounts {
    primary: u64,
    /// Primary rays that hit the scene.
    primary_hits: u64,
    shadow: u64,
    ao: u64,
}

#[derive(Serialize)]
struct KindTimes {
    primary: f64,
    shadow: f64,
    ao: f64,
}

#[derive(Serialize)]
struct RenderReport {
    scene: String,
    /// Triangles as traced: an instanced scene's counted once per instance.
    triangles: u64,
    /// Triangles stored: an instanced scene's meshes, each once.
    unique_triangles: usize,
    instances: usize,
    /// The process's peak resident memory (Linux's VmHWM).
    peak_memory_bytes: Option<u64>,
    emissive_triangles: usize,
    dropped_degenerate: usize,
    backend: String,
    schedule: Schedule,
    threads: usize,
    width: u32,
    height: u32,
    ao: String,
    light_samples: u32,
    seed: u64,
    load_ms: f64,
    build_ms: f64,
    /// Bytes of the acceleration structure (BVH nodes and leaf triangles;
    /// for Embree, what its memory monitor reports the build left allocated).
    #[serde(skip_serializing_if = "Option::is_none")]
    memory_bytes: Option<usize>,
    render_ms: f64,
    rays: RayCounts,
    /// Time spent in each pass, summed over threads (includes that pass's shading).
    thread_ms: KindTimes,
    /// All rays over render wall time.
    mrays_per_s: f64,
    output: String,
    image_hash: String,
    warnings: Vec<String>,
    /// The linked Embree's version, for the embree backend.
    #[serde(skip_serializing_if = "Option::is_none")]
    embree_version: Option<String>,
}

pub fn run(args: &RenderArgs) -> Result<()> {
    output::check_writable(&args.output)?;
    let threads = args.threads.unwrap_or_else(default_threads);
    // The flags are checked before any work.
    let spec = args.accel.spec(threads)?;
    if let (Some(_), Schedule::Serial | Schedule::Rows) = (args.threads, args.schedule) {
        return Err(crate::Error::usage(
            "--threads",
            format!(
                "applies to --schedule tiles and rayon; {} runs {} (give --build-threads for the build's threads)",
                args.schedule.name(),
                if args.schedule == Schedule::Serial {
                    "on one thread"
                } else {
                    "one thread per image row"
                }
            ),
        ));
    }
    args.view.check()?;
    args.files.check(std::slice::from_ref(&args.scene))?;

    if args.time.is_none() && args.frames.is_none() {
        let start = Instant::now();
        let scene = args.files.load_instanced(&args.scene)?;
        if args.flatten && !scene.is_instanced() {
            return Err(Error::usage(
                "--flatten",
                format!(
                    "{} has no instances to flatten (each mesh is placed once)",
                    scene.name
                ),
            ));
        }
        let scene = if args.flatten {
            scene.flattened()?
        } else {
            scene
        };
        return render_scene(
            args,
            &spec,
            threads,
            scene,
            start.elapsed(),
            &args.output,
            None,
        );
    }
    let start = Instant::now();
    let flag = if args.time.is_some() {
        "--time"
    } else {
        "--frames"
    };
    let animation = crate::scene::motion::Animation::load(&args.scene, args.files.policy(), flag)?;
    if args.flatten && !animation.moves_instances() {
        return Err(Error::usage(
            "--flatten",
            format!("{} is traced as one triangle list already (its vertices move); --flatten is for instanced scenes", args.scene),
        ));
    }
    // A frame as traced: --flatten bakes its instances into one list.
    let frame_at = |t: f32| -> Result<crate::scene::Scene> {
        let frame = animation.frame(t)?;
        if args.flatten {
            frame.flattened()
        } else {
            Ok(frame)
        }
    };
    let load_time = start.elapsed();
    if let Some(t) = args.time {
        animation.check_time(t, "--time")?;
        let frame = frame_at(t)?;
        return render_scene(args, &spec, threads, frame, load_time, &args.output, None);
    }
    let (first, last) = args.frames.expect("--time or --frames");
    let fps = args.fps.unwrap_or(DEFAULT_FPS);
    animation.check_time(last as f32 / fps, "--frames")?;
    // The view and default light of the first frame, kept for all of them
    // unless --follow.
    let mut framing = frame_at(first as f32 / fps)?;
    let fixed = (args.view.prepare(&mut framing)?, framing.lights.extra);
    for f in first..=last {
        let start = Instant::now();
        let t = f as f32 / fps;
        let output = numbered(&args.output, f);
        let fixed = (!args.follow).then_some(&fixed);
        // Which frame failed, and which were written: a frame's scene can
        // fail (a node scaled through zero cannot be framed) after earlier
        // frames rendered.
        frame_at(t)
            .and_then(|frame| {
                render_scene(args, &spec, threads, frame, start.elapsed(), &output, fixed)
            })
            .map_err(|e| {
                let written = if f > first {
                    format!("frames {first}..{} written", f - 1)
                } else {
                    "no frame written".into()
                };
                Error::Other(format!("--frames: frame {f} (at {t} s): {e} ({written})"))
            })?;
    }
    Ok(())
}

/// Frames per second of `--frames` without `--fps`.
const DEFAULT_FPS: f32 = 24.0;

/// `out.png` with frame `f`'s number: `out_0007.png`.
fn numbered(output: &std::path::Path, f: u32) -> PathBuf {
    let stem = output
        .file_stem()
        .map_or("frame".into(), |s| s.to_string_lossy().into_owned());
    let ext = output
        .extension()
        .map_or("png".into(), |e| e.to_string_lossy().into_owned());
    output.with_file_name(format!("{stem}_{f:04}.{ext}"))
}

/// `A..B` of `--frames`: whole numbers, A at most B.
fn parse_frames(s: &str) -> std::result::Result<(u32, u32), String> {
    let bad = || format!("'{s}' is not A..B (frame numbers from 0, A at most B: 0..47)");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let a: u32 = a.trim().parse().map_err(|_| bad())?;
    let b: u32 = b.trim().parse().map_err(|_| bad())?;
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
}

/// `--fps`: a positive finite number.
fn parse_fps(s: &str) -> std::result::Result<f32, String> {
    match s.parse::<f32>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!(
            "'{s}' is not a positive number of frames per second"
        )),
    }
}

/// The settings and outside light of a fixed view, kept across frames.
type FixedView = (RenderSettings, Option<crate::scene::light::Emitter>);

/// Builds the backend over `scene`, renders it to `output` and reports;
/// with `fixed`, in that view and light, else in the one the flags and the
/// scene's bounds give.
fn render_scene(
    args: &RenderArgs,
    spec: &crate::accel::BackendSpec,
    threads: usize,
    mut scene: crate::scene::Scene,
    load_time: Duration,
    output: &std::path::Path,
    fixed: Option<&FixedView>,
) -> Result<()> {
    let say = |line: String| {
        if !args.quiet {
            crate::console::say(&line);
        }
    };
    let settings = match fixed {
        Some((settings, light)) => {
            scene.check_traceable()?;
            scene.lights.extra = *light;
            settings.clone()
        }
        None => args.view.prepare(&mut scene)?,
    };
    for w in &scene.warnings {
        say(format!("warning: {w}"));
    }
    match &scene.instancing {
        Some(inst) => say(format!(
            "scene {}: {} instances of {} meshes place {} triangles ({} unique, {} emissive placed), loaded in {:.1} ms",
            scene.name,
            inst.instances.len(),
            inst.meshes.len(),
            scene.placed_triangle_count(),
            scene.triangle_count(),
            scene.lights.triangles.len(),
            ms(load_time)
        )),
        None => say(format!(
            "scene {}: {} triangles ({} emissive), loaded in {:.1} ms",
            scene.name,
            scene.triangle_count(),
            scene.lights.triangles.len(),
            ms(load_time)
        )),
    }

    let backend = build_scene_backend(spec, &scene)?;
    say(format!(
        "backend {}: built in {:.1} ms",
        backend.name(),
        ms(backend.build_time)
    ));

    let progress = Progress::new();
    let total_pixels = settings.width as u64 * settings.height as u64;
    // The clock stops inside the watched work, so the progress monitor's
    // shutdown is never part of the render time.
    let (rendered, render_time) = progress.watch(
        "render",
        total_pixels,
        args.quiet,
        Duration::from_secs(1),
        || {
            let start = Instant::now();
            let rendered = render::render(
                &scene,
                backend.as_ref(),
                &settings,
                args.schedule,
                threads,
                &progress,
            );
            (rendered, start.elapsed())
        },
    );
    let (frame, stats) = rendered?;

    let mut warnings = scene.warnings.clone();
    if stats.primary_hits * 100 < stats.primary_rays {
        let w = format!(
            "only {} of {} primary rays hit the scene (under 1%): check --eye, --look and --up",
            stats.primary_hits, stats.primary_rays
        );
        say(format!("warning: {w}"));
        warnings.push(w);
    }
    let rgb8 = srgb::to_srgb8(&frame);
    let hash = srgb::image_hash(&rgb8);
    output::write_png(output, frame.width, frame.height, &rgb8)?;

    let threads_used = args.schedule.threads_used(threads, settings.height);
    let mrays = stats.total_rays() as f64 / render_time.as_secs_f64().max(1e-9) / 1e6;
    let per_thread = |rays: u64, t: Duration| rays as f64 / t.as_secs_f64().max(1e-9) / 1e6;
    say(format!(
        "render {}x{} {} ({} thread{}), ao {}: {:.1} ms, {:.2} M rays, {} Mrays/s",
        settings.width,
        settings.height,
        args.schedule.name(),
        threads_used,
        if threads_used == 1 { "" } else { "s" },
        settings.ao,
        ms(render_time),
        stats.total_rays() as f64 / 1e6,
        significant(mrays)
    ));
    say(format!(
        "  per thread: primary {} rays {} Mrays/s | shadow {} rays {} Mrays/s | ao {} rays {} Mrays/s",
        stats.primary_rays,
        significant(per_thread(stats.primary_rays, stats.primary_time)),
        stats.shadow_rays,
        significant(per_thread(stats.shadow_rays, stats.shadow_time)),
        stats.ao_rays,
        significant(per_thread(stats.ao_rays, stats.ao_time)),
    ));
    let peak = crate::os::peak_memory_bytes();
    if let Some(peak) = peak {
        say(format!(
            "memory: peak {:.1} MB resident{}",
            peak as f64 / 1e6,
            match &scene.instancing {
                Some(_) => format!(
                    " ({:.1} bytes per unique triangle, {:.3} per placed triangle)",
                    peak as f64 / scene.triangle_count() as f64,
                    peak as f64 / scene.placed_triangle_count() as f64
                ),
                None => String::new(),
            }
        ));
    }
    say(format!("wrote {} (image hash {hash})", output.display()));

    if args.json {
        let report = RenderReport {
            scene: scene.name.clone(),
            triangles: scene.placed_triangle_count(),
            unique_triangles: scene.triangle_count(),
            instances: scene.instance_count(),
            peak_memory_bytes: peak,
            emissive_triangles: scene.lights.triangles.len(),
            dropped_degenerate: scene.dropped_degenerate,
            backend: backend.name(),
            schedule: args.schedule,
            threads: threads_used,
            width: settings.width,
            height: settings.height,
            ao: settings.ao.to_string(),
            light_samples: settings.light_samples,
            seed: settings.seed,
            load_ms: ms(load_time),
            build_ms: ms(backend.build_time),
            memory_bytes: backend.memory_bytes(),
            render_ms: ms(render_time),
            rays: RayCounts {
                primary: stats.primary_rays,
                primary_hits: stats.primary_hits,
                shadow: stats.shadow_rays,
                ao: stats.ao_rays,
            },
            thread_ms: KindTimes {
                primary: ms(stats.primary_time),
                shadow: ms(stats.shadow_time),
                ao: ms(stats.ao_time),
            },
            mrays_per_s: mrays,
            output: output.display().to_string(),
            image_hash: hash,
            warnings,
            embree_version: backend.spec.is_embree().then(embree_version),
        };
        let text = serde_json::to_string(&report)?;
        crate::console::outln(&text)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_keep_three_significant_digits() {
        assert_eq!(significant(44.4612), "44.5");
        assert_eq!(significant(0.004123), "0.00412");
        assert_eq!(significant(1234.5), "1234");
        assert_eq!(significant(0.0), "0");
    }
}
