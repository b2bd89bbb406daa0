//! The command line: parses flags with clap and dispatches to the command's
//! module in [`crate::command`], which runs the library and reports. Every
//! error is one line on stderr and a non-zero exit status.

use clap::{Parser, Subcommand};

use crate::command::{bench, rays, render, stats, stress, validate};
use crate::scene::builtin::{BUILTIN_SCENES, PROCEDURAL_SCENES};

#[derive(Parser, Debug)]
#[command(
    name = "raylab",
    version,
    about = "Compare ray-tracing acceleration structures on the CPU"
)]
struct Cli {
    /// The most triangles a scene may expand to (glTF instances times their
    /// meshes, OBJ and PLY faces after triangulation), checked before they
    /// are allocated; the default, 200 million, is about 10 GB loaded and
    /// built.
    #[arg(long, global = true, value_name = "N", default_value_t = crate::scene::budget::DEFAULT_MAX_TRIANGLES, value_parser = crate::command::args::parse_budget)]
    max_triangles: u64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene with one backend and schedule, write a PNG and print timings.
    Render(render::RenderArgs),
    /// Check one backend's hits against another's on the same ray sets.
    Validate(validate::ValidateArgs),
    /// Find where intersection methods fail: leaks, self-intersection offsets,
    /// degenerate and hostile input.
    Stress(stress::StressArgs),
    /// BVH quality per scene and builder: build times, shape, SAH cost, and
    /// traversal work per ray measured over a render.
    Stats(stats::StatsArgs),
    /// The study's tables (times and speedups of every variant over scenes,
    /// views and AO modes), scaling and accuracy charts, and an HTML report.
    Bench(bench::BenchArgs),
    /// Write a scene's recorded rays (primary, shadow, AO, diffuse) to a ray
    /// file for `validate --rays`, `bench --rays` or another tool.
    Rays(rays::RaysArgs),
    /// List the built-in scenes.
    Scenes,
}

/// Runs the command line and returns the process exit status.
pub fn main() -> i32 {
    // A bug must still end in one line, not a backtrace over the user's terminal.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        crate::console::say(&format!(
            "raylab: internal error{place}: {msg} (please report this)"
        ));
    }));
    crate::os::ignore_closed_pipe();
    crate::os::keep_freed_memory();
    use clap::{CommandFactory, FromArgMatches};
    let parsed = Cli::command()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m).map(|cli| (cli, m)));
    let (cli, matches) = match parsed {
        Ok(parsed) => parsed,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion)
                || e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            {
                let _ = e.print();
                return if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                    2
                } else {
                    0
                };
            }
            crate::console::say(&format!(
                "raylab: {}",
                one_line_clap_error(&e.render().to_string())
            ));
            return 2;
        }
    };
    crate::scene::budget::set_max_triangles(cli.max_triangles);
    let sub = matches.subcommand().map(|(_, m)| m);
    let result = match &cli.command {
        Command::Render(args) => sub
            .map_or(Ok(()), |m| {
                crate::command::args::check_backend_flags(m, args.accel.backend)
            })
            .and_then(|()| render::run(args)),
        Command::Stats(args) => stats::run(args),
        Command::Validate(args) => sub
            .map_or(Ok(()), |m| {
                crate::command::args::check_backend_flags(m, args.accel.backend)
                    .and_then(|()| validate::check_ray_file_flags(m, args))
            })
            .and_then(|()| validate::run(args)),
        Command::Stress(args) => stress::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Rays(args) => rays::run(args),
        Command::Scenes => BUILTIN_SCENES
            .iter()
            .chain(PROCEDURAL_SCENES)
            .chain(crate::scene::motion::ANIMATED_SCENES)
            .try_for_each(|(name, about)| crate::console::outln(&format!("{name:18} {about}"))),
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            crate::console::say(&format!("raylab: {e}"));
            // Flag and usage errors exit 2, as clap's own; bad input 1.
            if matches!(e, crate::Error::Usage { .. }) {
                2
            } else {
                1
            }
        }
    }
}

/// clap's message in one line: its first line, then its tips and possible
/// values in brackets ("did you mean ..."), without the usage block.
fn one_line_clap_error(text: &str) -> String {
    let mut lines = text
        .lines()
        .take_while(|l| !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .map(str::trim)
        .filter(|l| !l.is_empty());
    let first = lines
        .next()
        .unwrap_or("invalid arguments")
        .trim_start_matches("error: ")
        .to_string();
    let rest: Vec<&str> = lines.collect();
    if rest.is_empty() {
        first
    } else {
        format!("{first} ({})", rest.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clap_messages_become_one_line_with_their_tips() {
        let text = "error: unrecognized subcommand 'rendr'\n\n  tip: a similar subcommand exists: 'render'\n\nUsage: raylab <COMMAND>\n\nFor more information, try '--help'.\n";
        assert_eq!(
            one_line_clap_error(text),
            "unrecognized subcommand 'rendr' (tip: a similar subcommand exists: 'render')"
        );
    }
}
