//! Progress on stderr for long work. The work only bumps an atomic counter; a
//! monitor thread shows an `indicatif` bar once the work has run for about a second,
//! so short renders print nothing and the hot loop never touches the terminal.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A shared counter of finished work units.
#[derive(Debug, Default)]
pub struct Progress {
    done: AtomicU64,
}

impl Progress {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn advance(&self, n: u64) {
        self.done.fetch_add(n, Ordering::Relaxed);
    }

    pub fn done(&self) -> u64 {
        self.done.load(Ordering::Relaxed)
    }

    /// Runs `f` while a monitor shows a bar for `progress` out of `total` units on
    /// stderr after `delay`, unless `quiet` or stderr is not a terminal.
    pub fn watch<T>(
        &self,
        label: &str,
        total: u64,
        quiet: bool,
        delay: Duration,
        f: impl FnOnce() -> T,
    ) -> T {
        let finished = AtomicBool::new(false);
        std::thread::scope(|s| {
            if !quiet {
                s.spawn(|| self.monitor(label, total, delay, &finished));
            }
            let result = f();
            finished.store(true, Ordering::Relaxed);
            result
        })
    }

    fn monitor(&self, label: &str, total: u64, delay: Duration, finished: &AtomicBool) {
        let start = Instant::now();
        let mut bar: Option<ProgressBar> = None;
        while !finished.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(50));
            if bar.is_none() && start.elapsed() >= delay {
                // Draws only when stderr is a terminal (indicatif checks).
                let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                b.set_style(
                    ProgressStyle::with_template(
                        "{msg} [{bar:40}] {percent:>3}% {elapsed} eta {eta}",
                    )
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
                );
                b.set_message(label.to_string());
                bar = Some(b);
            }
            if let Some(b) = &bar {
                b.set_position(self.done().min(total));
            }
        }
        if let Some(b) = bar {
            b.finish_and_clear();
        }
    }
}

/// Progress through a list of steps of uneven length (the bench matrix), counted
/// in units of expected work (the bench uses expected milliseconds), so that the
/// estimate of the time left holds when a naive run takes a thousand times
/// longer than a BVH run. On a terminal: a bar with the running step's name and
/// the estimate; otherwise one line on stderr per step, so logs show the same.
pub struct StepBar {
    bar: Option<ProgressBar>,
    quiet: bool,
    start: Instant,
    total: u64,
    done: AtomicU64,
    step_units: u64,
}

impl StepBar {
    pub fn new(total_units: u64, quiet: bool) -> Self {
        let target = ProgressDrawTarget::stderr();
        let bar = (!quiet && !target.is_hidden()).then(|| {
            let b = ProgressBar::with_draw_target(Some(total_units), target);
            b.set_style(
                ProgressStyle::with_template(
                    "[{bar:30}] {percent:>3}% {elapsed} eta {eta} {wide_msg}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            b.enable_steady_tick(Duration::from_millis(500));
            b
        });
        StepBar {
            bar,
            quiet,
            start: Instant::now(),
            total: total_units,
            done: AtomicU64::new(0),
            step_units: 1,
        }
    }

    /// The units [`StepBar::step`] marks done.
    pub fn with_step(mut self, units: u64) -> Self {
        self.step_units = units;
        self
    }

    /// Marks one step of the default size done.
    pub fn step(&self) {
        self.inc(self.step_units);
    }

    /// Names the step now running.
    pub fn set_message(&self, msg: String) {
        match &self.bar {
            Some(b) => b.set_message(msg),
            None if !self.quiet => {
                let done = self.done.load(Ordering::Relaxed).min(self.total);
                let elapsed = self.start.elapsed().as_secs_f64();
                let percent = 100.0 * done as f64 / self.total.max(1) as f64;
                let eta = if done > 0 {
                    format!(
                        ", ~{:.0} s left",
                        elapsed / done as f64 * (self.total - done) as f64
                    )
                } else {
                    String::new()
                };
                eprintln!("bench [{percent:.0}%, {elapsed:.0} s{eta}] {msg}");
            }
            None => {}
        }
    }

    /// Marks `units` of expected work done.
    pub fn inc(&self, units: u64) {
        self.done.fetch_add(units, Ordering::Relaxed);
        if let Some(b) = &self.bar {
            b.inc(units);
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
