//! How the image is divided between threads (the study's section III). Every
//! schedule renders the same rectangles with the same kernel and per-pixel random
//! streams, so all give bit-identical images.
//!
//! - `serial`: the 256 tiles one after another on the calling thread.
//! - `rows`: one task per image row, each on its own OS thread, all started at once
//!   and joined in order (the study's `std::async` per row).
//! - `tiles`: the study's locked queue: the image cut into 16 x 16 = 256 blocks in a
//!   `Mutex<VecDeque>`, drained by `threads` worker threads.
//! - `rayon`: rayon's work stealing over the same 256 blocks on a pool of `threads`.

use std::collections::VecDeque;
use std::sync::Mutex;

use glam::Vec3;
use rayon::prelude::*;

use super::shade::render_rect;
use super::{Frame, Rect, RenderSettings, RenderStats, Tracer};
use crate::error::{Error, Result};
use crate::progress::Progress;
use crate::scene::Scene;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Schedule {
    Serial,
    Rows,
    Tiles,
    Rayon,
}

impl Schedule {
    pub const ALL: [Schedule; 4] = [
        Schedule::Serial,
        Schedule::Rows,
        Schedule::Tiles,
        Schedule::Rayon,
    ];

    /// Threads that run the kernel: 1 for serial, one per row for rows, else `threads`.
    pub fn threads_used(self, threads: usize, height: u32) -> usize {
        match self {
            Schedule::Serial => 1,
            Schedule::Rows => height as usize,
            Schedule::Tiles | Schedule::Rayon => threads,
        }
    }
}

/// Blocks per image side in the tiled schedules (the study's 16 x 16 = 256).
pub const TILES_PER_SIDE: u32 = 16;

/// The image cut into `TILES_PER_SIDE`^2 blocks with boundaries at `i * size / 16`;
/// empty blocks (images narrower than 16 pixels) are left out.
pub fn tile_grid(width: u32, height: u32) -> Vec<Rect> {
    let cut = |i: u32, size: u32| (i as u64 * size as u64 / TILES_PER_SIDE as u64) as u32;
    let mut tiles = Vec::with_capacity((TILES_PER_SIDE * TILES_PER_SIDE) as usize);
    for ty in 0..TILES_PER_SIDE {
        for tx in 0..TILES_PER_SIDE {
            let r = Rect {
                x0: cut(tx, width),
                x1: cut(tx + 1, width),
                y0: cut(ty, height),
                y1: cut(ty + 1, height),
            };
            if r.pixel_count() > 0 {
                tiles.push(r);
            }
        }
    }
    tiles
}

/// Renders the whole image with `schedule`. `threads` (at least 1) is used by
/// `tiles` and `rayon`. `progress` is advanced by each finished rectangle's pixels.
pub fn render<T: Tracer + ?Sized>(
    scene: &Scene,
    tracer: &T,
    settings: &RenderSettings,
    schedule: Schedule,
    threads: usize,
    progress: &Progress,
) -> Result<(Frame, RenderStats)> {
    settings.validate()?;
    if threads == 0 {
        return Err(Error::usage("--threads", "must be at least 1"));
    }
    let work = |rect: Rect| {
        let _ftz = tracer
            .flushes_denormals()
            .then(crate::os::FlushDenormals::enable);
        let mut pixels = vec![Vec3::ZERO; rect.pixel_count()];
        let stats = render_rect(scene, tracer, settings, rect, &mut pixels);
        progress.advance(rect.pixel_count() as u64);
        (rect, pixels, stats)
    };
    let (w, h) = (settings.width, settings.height);
    let pieces: Vec<(Rect, Vec<Vec3>, RenderStats)> = match schedule {
        Schedule::Serial => tile_grid(w, h).into_iter().map(work).collect(),
        Schedule::Rows => std::thread::scope(|s| {
            let handles: Vec<_> = (0..h)
                .map(|y| {
                    std::thread::Builder::new()
                        .stack_size(256 * 1024)
                        .spawn_scoped(s, move || {
                            work(Rect {
                                x0: 0,
                                x1: w,
                                y0: y,
                                y1: y + 1,
                            })
                        })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.map_err(|e| Error::Other(format!("cannot start a row thread: {e}")))?
                        .join()
                        .map_err(|_| Error::Other("a row thread panicked".into()))
                })
                .collect::<Result<Vec<_>>>()
        })?,
        Schedule::Tiles => {
            let queue = Mutex::new(tile_grid(w, h).into_iter().collect::<VecDeque<_>>());
            std::thread::scope(|s| {
                let workers: Vec<_> = (0..threads)
                    .map(|_| {
                        s.spawn(|| {
                            let mut done = Vec::new();
                            loop {
                                // The lock is held only to pop; a poisoned lock means
                                // another worker panicked, which join reports.
                                let next = match queue.lock() {
                                    Ok(mut q) => q.pop_front(),
                                    Err(_) => None,
                                };
                                match next {
                                    Some(rect) => done.push(work(rect)),
                                    None => break done,
                                }
                            }
                        })
                    })
                    .collect();
                let mut all = Vec::new();
                for worker in workers {
                    all.extend(
                        worker
                            .join()
                            .map_err(|_| Error::Other("a tile worker panicked".into()))?,
                    );
                }
                Ok::<_, Error>(all)
            })?
        }
        Schedule::Rayon => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| Error::Other(format!("cannot start the rayon pool: {e}")))?;
            let tiles = tile_grid(w, h);
            pool.install(|| tiles.into_par_iter().map(work).collect())
        }
    };

    let mut frame = Frame {
        width: w,
        height: h,
        pixels: vec![Vec3::ZERO; w as usize * h as usize],
    };
    let mut total = RenderStats::default();
    for (rect, pixels, stats) in pieces {
        let rw = (rect.x1 - rect.x0) as usize;
        for (row, chunk) in pixels.chunks_exact(rw).enumerate() {
            let start = (rect.y0 as usize + row) * w as usize + rect.x0 as usize;
            frame.pixels[start..start + rw].copy_from_slice(chunk);
        }
        total += stats;
    }
    Ok((frame, total))
}

/// All hardware threads, the default for `--threads`.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_grid_covers_every_pixel_once() {
        for (w, h) in [(1024, 768), (64, 48), (5, 3), (1, 1), (17, 100)] {
            let mut seen = vec![0u8; (w * h) as usize];
            for r in tile_grid(w, h) {
                for y in r.y0..r.y1 {
                    for x in r.x0..r.x1 {
                        seen[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{w}x{h}");
        }
        assert_eq!(tile_grid(1024, 768).len(), 256);
    }
}
