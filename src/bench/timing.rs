//! The shared timing harness of the parts that trace recorded rays (`trace`,
//! `ladder`, `libraries`): a run of a backend's stream queries over rays on
//! N threads, the calling thread one of them, timed from the last thread's
//! arrival at the start line to the last one's finish; how many passes make
//! a run long enough; and the answers a query gives, comparable across
//! backends. (It lived in the trace part, which the others imported.)

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use crate::accel::Backend;
use crate::bench::config::BenchConfig;
use crate::bench::measure::Stat;
use crate::geometry::{Hit, Ray};
use crate::os::FlushDenormals;

/// Rays handed to a thread at a time: small enough to balance two threads,
/// large enough that the shared counter is touched rarely.
pub(crate) const CHUNK: usize = 512;

/// What a query answered, comparable across backends: the hit triangle and the
/// bits of `t` for closest hits, hit or not for any-hit queries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    Closest(Option<(u32, u32)>),
    Any(bool),
}

/// Answers each ray of `rays` as the ray kind asks (closest or any hit),
/// through the backend's stream queries (its query path).
pub(crate) fn answers(backend: &dyn Backend, closest: bool, rays: &[Ray], out: &mut Vec<Answer>) {
    out.clear();
    if closest {
        let mut hits = vec![None; rays.len()];
        backend.intersect_stream(rays, &mut hits);
        out.extend(
            hits.iter()
                .map(|h| Answer::Closest(h.map(|h| (h.tri, h.t.to_bits())))),
        );
    } else {
        let mut occluded = vec![false; rays.len()];
        backend.occluded_stream(rays, &mut occluded);
        out.extend(occluded.iter().map(|&o| Answer::Any(o)));
    }
}

/// A number that depends on every answer, so the timed loop cannot be elided.
#[inline]
pub(crate) fn digest(a: Answer) -> u64 {
    match a {
        Answer::Closest(Some((tri, _))) => tri as u64 + 1,
        Answer::Closest(None) | Answer::Any(false) => 0,
        Answer::Any(true) => 1,
    }
}

/// A timed run lasts at least about this long: its rays are traced as many
/// times over as the warm-up run says it takes. Runs of a millisecond (a small
/// scene's shadow rays on the fastest paths) measured thread start-up more
/// than tracing: raylab's fastest packets seemed to gain 0.9-1.3x from a
/// second thread where Embree's slower ones gained 1.6-1.9x.
pub const MIN_RUN_S: f64 = 0.02;

/// How many passes over its rays make a run last `min_run_s` (the bench's
/// [`MIN_RUN_S`], 0 for `--quick`), from one pass's `seconds`.
/// `backend`'s median Mrays/s over `reps` runs on `rays` (closest hits, or
/// any hit), each run long enough to take `min_run` seconds on `threads`.
pub fn median_mrays(
    backend: &dyn Backend,
    closest: bool,
    rays: &[Ray],
    threads: usize,
    reps: usize,
    min_run: f64,
) -> f64 {
    let passes = passes_for(trace(backend, closest, rays, threads, 1).0, min_run);
    let rates: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let secs = trace(backend, closest, rays, threads, passes).0.max(1e-12);
            (rays.len() * passes) as f64 / secs / 1e6
        })
        .collect();
    Stat::of(&rates).median
}

/// `backend`'s answers to `rays` as hits: closest hits, or (any-hit kinds)
/// a placeholder hit for each occluded ray ([`answers`] keeps only what
/// compares bit for bit; the parts that judge answers need the hits).
pub fn hits_or_occluded(backend: &dyn Backend, closest: bool, rays: &[Ray]) -> Vec<Option<Hit>> {
    if closest {
        let mut hits = vec![None; rays.len()];
        backend.intersect_stream(rays, &mut hits);
        return hits;
    }
    let mut occluded = vec![false; rays.len()];
    backend.occluded_stream(rays, &mut occluded);
    occluded
        .into_iter()
        .map(|o| {
            o.then_some(Hit {
                t: 0.0,
                u: 0.0,
                v: 0.0,
                tri: 0,
                inst: 0,
            })
        })
        .collect()
}

pub fn passes_for(seconds: f64, min_run_s: f64) -> usize {
    (min_run_s / seconds.max(1e-9)).ceil().clamp(1.0, 10_000.0) as usize
}

/// The least duration of a timed run for `cfg`: none for `--quick`, whose
/// figures only show that every path runs.
pub fn min_run_s(cfg: &BenchConfig) -> f64 {
    if cfg.quick {
        0.0
    } else {
        MIN_RUN_S
    }
}

/// Traces `rays` `passes` times on `threads` threads, streams of [`CHUNK`]
/// rays taken from a shared counter, and returns the wall time in seconds
/// and the sum of the first pass's answers' digests.
///
/// The calling thread is one of the `threads`, so no more threads exist than
/// trace. The clock starts when the last thread arrives at the start line
/// (the others are spinning on it then) and stops when the last one
/// finishes, so neither thread start-up nor joining is timed. It used to
/// start when the calling thread released workers it then waited for: three
/// threads on two CPUs, and a worker off its CPU for a scheduler tick inside
/// the clock. Wuson's rays in 20 ms runs on two threads gained 1.2-2.1x from
/// the second thread that way (8 runs, both backends), 1.7-2.0x this way.
pub fn trace(
    backend: &dyn Backend,
    closest: bool,
    rays: &[Ray],
    threads: usize,
    passes: usize,
) -> (f64, u64) {
    let threads = threads.max(1);
    let chunks_per_pass = rays.len().div_ceil(CHUNK);
    let chunks = chunks_per_pass * passes;
    let next = AtomicUsize::new(0);
    let arrived = AtomicUsize::new(0);
    let started = std::sync::OnceLock::new();
    let work = || {
        let _ftz = backend.flushes_denormals().then(FlushDenormals::enable);
        let mut sum = 0u64;
        let mut hits = vec![None; CHUNK];
        let mut occluded = vec![false; CHUNK];
        if arrived.fetch_add(1, Ordering::AcqRel) + 1 == threads {
            started.get_or_init(Instant::now);
        }
        // Yielding while waiting costs nothing when every thread has a CPU,
        // and lets a thread that lost its CPU have it back sooner.
        while started.get().is_none() {
            std::thread::yield_now();
        }
        loop {
            let k = next.fetch_add(1, Ordering::Relaxed);
            if k >= chunks {
                break (sum, Instant::now());
            }
            let start = k % chunks_per_pass * CHUNK;
            let chunk = &rays[start..(start + CHUNK).min(rays.len())];
            let n = chunk.len();
            // Only the first pass's answers are read: reading every pass's
            // cost a fast backend about 10% of its two-thread throughput
            // (a per-ray cost inside the clock), and one pass already shows
            // answers that depend on the thread count.
            let check = k < chunks_per_pass;
            if closest {
                backend.intersect_stream(chunk, &mut hits[..n]);
                if check {
                    for h in &hits[..n] {
                        // The digest reads only the triangle.
                        sum = sum.wrapping_add(digest(Answer::Closest(h.map(|h| (h.tri, 0)))));
                    }
                }
            } else {
                backend.occluded_stream(chunk, &mut occluded[..n]);
                if check {
                    sum = sum.wrapping_add(occluded[..n].iter().filter(|&&o| o).count() as u64);
                }
            }
        }
    };
    let (sum, finished) = std::thread::scope(|s| {
        let helpers: Vec<_> = (1..threads).map(|_| s.spawn(work)).collect();
        let own = work();
        helpers
            .into_iter()
            .filter_map(|h| h.join().ok())
            .fold(own, |(sum, last), (s, at)| {
                (sum.wrapping_add(s), last.max(at))
            })
    });
    let started = started.get().copied().unwrap_or(finished);
    (finished.duration_since(started).as_secs_f64(), sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::{BuildParams, BvhBackend};
    use crate::accel::{build_backend, BackendSpec};
    use crate::bench::measure::View;
    use crate::geometry::Hit;
    use crate::measure::validate::recorded_rays;
    use crate::render::{AoMode, RenderSettings};
    use crate::scene::Scene;

    fn setup() -> (Scene, RenderSettings) {
        let scene = crate::scene::builtin::builtin("cornell-sphere").unwrap();
        let settings = View::PAPER[0].settings((48, 36), AoMode::Paper, 1).unwrap();
        (scene, settings)
    }

    /// On any thread count the first pass traces every ray once (its digest
    /// sum is one pass's), and the clock moves with the passes.
    #[test]
    fn passes_multiply_the_work_on_any_thread_count() {
        let (scene, settings) = setup();
        let built = build_backend(&BackendSpec::bvh(BuildParams::sah()), &scene).unwrap();
        let backend = built.as_ref();
        let rays = recorded_rays(&scene, backend, &settings).unwrap().primary;
        // One pass's time, the fastest of three: the first pass alone ran
        // cold once in CI (2.1 ms against 40 passes' 5.4).
        let (mut one_s, one) = trace(backend, true, &rays, 1, 1);
        for _ in 0..2 {
            one_s = one_s.min(trace(backend, true, &rays, 1, 1).0);
        }
        assert!(one > 0, "some primary rays hit");
        for threads in [1, 2, 3] {
            let (s, sum) = trace(backend, true, &rays, threads, 40);
            assert_eq!(sum, one, "{threads} threads");
            assert!(s > 5.0 * one_s, "40 passes took {s} s, one {one_s} s");
        }
        assert_eq!(passes_for(0.004, MIN_RUN_S), 5);
        assert_eq!(passes_for(1.0, MIN_RUN_S), 1);
        assert_eq!(passes_for(0.004, 0.0), 1);
    }

    /// The SAH tree, noting which threads ask it streams (each a
    /// millisecond slowly, so that every thread of a run gets some: a thread
    /// would have to wait for its CPU through most of the run to miss out).
    struct Noted(BvhBackend, std::sync::Mutex<Vec<std::thread::ThreadId>>);

    impl Backend for Noted {
        fn intersect(&self, ray: &Ray) -> Option<Hit> {
            self.0.intersect(ray)
        }
        fn occluded(&self, ray: &Ray) -> bool {
            self.0.occluded(ray)
        }
        fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
            let mut seen = self.1.lock().unwrap();
            let me = std::thread::current().id();
            if !seen.contains(&me) {
                seen.push(me);
            }
            drop(seen);
            std::thread::sleep(std::time::Duration::from_millis(1));
            self.0.intersect_stream(rays, hits);
        }
    }

    /// A run on N threads traces on the calling thread and N - 1 others:
    /// no more threads than CPUs when N is the CPU count (a main thread
    /// waiting beside N workers made the two-thread figures random).
    #[test]
    fn the_calling_thread_is_one_of_the_tracing_threads() {
        let (scene, settings) = setup();
        let tree = BvhBackend::new(&scene.mesh(), &BuildParams::sah()).unwrap();
        let noted = Noted(tree, std::sync::Mutex::new(Vec::new()));
        let rays = recorded_rays(&scene, &noted, &settings).unwrap().primary;
        assert!(rays.len() > 3 * CHUNK, "enough chunks for three threads");
        let me = std::thread::current().id();
        for threads in [1, 2, 3] {
            noted.1.lock().unwrap().clear();
            // 16 passes: over 60 chunks.
            trace(&noted, true, &rays, threads, 16);
            let seen = noted.1.lock().unwrap().clone();
            assert_eq!(seen.len(), threads, "{threads} threads: {seen:?}");
            assert!(seen.contains(&me), "{threads} threads: not the caller");
        }
    }
}
