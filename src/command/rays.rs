//! `raylab rays`: writes a scene's recorded ray sets to a ray file
//! ([`crate::measure::rayfile`]), for `validate --rays` and `bench --rays`, or for
//! another tool to trace.

use std::path::PathBuf;

use clap::Args;

use super::args::{parse_threads, SceneFileArgs, ViewArgs};
use crate::accel::bvh::BuildParams;
use crate::accel::{build_scene_backend, BackendSpec};
use crate::error::Result;
use crate::measure::validate::{ray_sets, RaySet};
use crate::render::schedule::default_threads;

#[derive(Args, Debug)]
pub struct RaysArgs {
    /// A scene file or built-in name.
    #[arg(default_value = "cornell-original")]
    scene: String,
    /// The ray file to write.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// At most this many rays per set (evenly subsampled; primary rays too).
    #[arg(long, value_name = "N", default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    count: u64,
    /// Worker threads for the recording render [default: all hardware threads].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    #[command(flatten)]
    view: ViewArgs,
    #[command(flatten)]
    files: SceneFileArgs,
}

/// The sets a ray file holds: what one render asks (primary, shadow, AO) and
/// one diffuse bounce per primary hit.
const SETS: [RaySet; 4] = [RaySet::Primary, RaySet::Shadow, RaySet::Ao, RaySet::Diffuse];

pub fn run(args: &RaysArgs) -> Result<()> {
    crate::output::check_creatable(&args.out, "--out")?;
    let threads = args.threads.unwrap_or_else(default_threads);
    args.files.check(std::slice::from_ref(&args.scene))?;
    let mut scene = args.files.load_instanced(&args.scene)?;
    let settings = args.view.prepare(&mut scene)?;
    // Recorded with raylab's tree: the naive scan's hits bit for bit. An
    // instanced scene with its two-level tree, as `render` traces it: the
    // flattened scene's hits up to the transforms' rounding (a flattened
    // copy of forest:100000 would be 10^9 triangles).
    let recorder = build_scene_backend(
        &BackendSpec::bvh(BuildParams::sah().with_width(8).with_threads(threads)),
        &scene,
    )?;
    // (The rays only: the origins are judged by `validate`.)
    let sets = ray_sets(
        &scene,
        recorder.as_ref(),
        &settings,
        &SETS,
        args.count as usize,
        false,
    )?
    .0;
    crate::measure::rayfile::write(&args.out, &sets)?;
    let counts: Vec<String> = sets
        .iter()
        .map(|(s, r)| format!("{} {}", r.len(), s.name()))
        .collect();
    crate::console::outln(&format!(
        "{}: {} rays of {} ({})",
        args.out.display(),
        sets.iter().map(|(_, r)| r.len()).sum::<usize>(),
        scene.name,
        counts.join(", ")
    ))?;
    Ok(())
}
