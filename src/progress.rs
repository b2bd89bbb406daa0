//! Progress on stderr for long work. The work only bumps an atomic counter; a
//! monitor thread shows an `indicatif` bar once the work has run for about a second,
//! so short renders print nothing and the hot loop never touches the terminal.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
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
    ///
    /// Returns as soon as `f` has returned: the monitor waits on a channel that
    /// closes when `f` is done, so no sleep of the monitor's is added to the work
    /// (a render timed around this call once read in 50 ms steps).
    pub fn watch<T>(
        &self,
        label: &str,
        total: u64,
        quiet: bool,
        delay: Duration,
        f: impl FnOnce() -> T,
    ) -> T {
        let start = Instant::now();
        std::thread::scope(|s| {
            let (finished, finished_rx) = mpsc::channel::<()>();
            if !quiet {
                s.spawn(move || self.monitor(label, total, start, delay, finished_rx));
            }
            let result = f();
            // Dropping the sender wakes the monitor at once.
            drop(finished);
            result
        })
    }

    fn monitor(
        &self,
        label: &str,
        total: u64,
        start: Instant,
        delay: Duration,
        finished: mpsc::Receiver<()>,
    ) {
        let mut bar: Option<ProgressBar> = None;
        // Disconnected (the work is done) ends the loop; a timeout is a tick.
        while let Err(mpsc::RecvTimeoutError::Timeout) = finished.recv_timeout(TICK) {
            let elapsed = start.elapsed();
            if bar.is_none() && elapsed >= delay {
                // Draws only when stderr is a terminal (indicatif checks).
                let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                b.set_style(
                    ProgressStyle::with_template("{prefix} [{bar:40}] {percent:>3}% {msg}")
                        .unwrap_or_else(|_| ProgressStyle::default_bar())
                        .progress_chars("=> "),
                );
                b.set_prefix(label.to_string());
                bar = Some(b);
            }
            if let Some(b) = &bar {
                let done = self.done().min(total);
                b.set_position(done);
                b.set_message(elapsed_and_eta(elapsed, done, total));
            }
        }
        if let Some(b) = bar {
            b.finish_and_clear();
        }
    }
}

/// How often the monitor redraws the bar.
const TICK: Duration = Duration::from_millis(100);

/// "12 s, eta 30 s": time since the work started and the time left at the
/// average rate so far. The bar's own clock would start when the bar appears,
/// a second into the work, and its rate estimate would count the work done
/// before that as done in no time (the ETA read about half the truth).
pub fn elapsed_and_eta(elapsed: Duration, done: u64, total: u64) -> String {
    let secs = elapsed.as_secs_f64();
    let eta = if done == 0 {
        "?".to_string()
    } else {
        let left = secs / done as f64 * total.saturating_sub(done) as f64;
        format!("{left:.0} s")
    };
    format!("{secs:.0} s, eta {eta}")
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
                crate::console::say(&format!("bench [{percent:.0}%, {elapsed:.0} s{eta}] {msg}"));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn watch_returns_as_soon_as_the_work_is_done() {
        // The monitor of a visible (not quiet) watch used to sleep in 50 ms
        // steps and was joined after the work: 20 instant jobs took >= 1 s.
        let progress = Progress::new();
        let start = Instant::now();
        for i in 0..20 {
            let got = progress.watch("t", 10, false, Duration::from_secs(3600), || i * 2);
            assert_eq!(got, i * 2);
        }
        let took = start.elapsed();
        assert!(
            took < Duration::from_millis(500),
            "20 watches took {took:?}"
        );
    }

    #[test]
    fn eta_is_the_average_rate_over_the_whole_work() {
        // A quarter done in 10 s: 30 s left, whenever the bar appeared.
        assert_eq!(
            elapsed_and_eta(Duration::from_secs(10), 25, 100),
            "10 s, eta 30 s"
        );
        assert_eq!(
            elapsed_and_eta(Duration::from_secs(2), 0, 100),
            "2 s, eta ?"
        );
        assert_eq!(
            elapsed_and_eta(Duration::from_secs(4), 100, 100),
            "4 s, eta 0 s"
        );
    }
}
