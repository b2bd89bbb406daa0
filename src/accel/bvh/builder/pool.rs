//! The build thread pools, the helpers of shared work ([`share`]) and
//! other values kept per thread count: made once and kept for the process,
//! as Embree keeps its threads, so that starting threads is never part of a
//! timed build. The builders themselves only take `parallel` and run on
//! whatever pool they are called in; the entry point ([`super::build`])
//! chooses the pool.

/// Runs `f` on a pool of `threads` threads (on the calling thread for one).
/// Code inside passes `parallel = threads > 1` down and runs serially when
/// it is false, so one thread means no other thread at all.
///
/// Pools are made once per thread count and kept (raylab's pools, unlike
/// Embree's devices, do not widen one another): starting threads is not
/// part of a build, and a pool made
/// per build also gave each build fresh per-thread heaps whose pages all
/// faulted again (mesh:1e5 on 2 threads: 1770 page faults a build).
pub(crate) fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    match kept_pool(threads) {
        Some(pool) => pool.install(f),
        // One thread, or no threads to be had: the same result, computed
        // serially.
        None => f(),
    }
}

/// The kept pool of `threads` threads; `None` for one thread, or where no
/// threads can be started.
fn kept_pool(threads: usize) -> Option<std::sync::Arc<rayon::ThreadPool>> {
    (threads > 1)
        .then(|| pool_of(threads, Placement::Pinned))
        .flatten()
}

/// The kept pool of `helpers` threads that help a calling thread
/// ([`share`]); `None` for none.
fn helper_pool(helpers: usize) -> Option<std::sync::Arc<rayon::ThreadPool>> {
    (helpers > 0)
        .then(|| pool_of(helpers, Placement::Free))
        .flatten()
}

/// Where a pool's workers run.
#[derive(Clone, Copy, PartialEq)]
enum Placement {
    /// One CPU each, so that waking workers are not stacked on one CPU (see
    /// `os::pin_to_allowed_cpu`): the build pools, whose callers sleep
    /// while they work.
    Pinned,
    /// Where the kernel puts them: [`share`]'s helpers, whose caller works
    /// too (a helper pinned to the caller's CPU would wait for the caller).
    Free,
}

/// The kept pool of `threads` workers placed as `placement` says.
fn pool_of(threads: usize, placement: Placement) -> Option<std::sync::Arc<rayon::ThreadPool>> {
    static POOLS: KeptPerThreads<rayon::ThreadPool> = KeptPerThreads::new();
    let key = 2 * threads + usize::from(placement == Placement::Pinned);
    POOLS
        .get(key, || {
            let builder = rayon::ThreadPoolBuilder::new().num_threads(threads);
            let builder = match placement {
                Placement::Pinned => builder.start_handler(|worker| {
                    crate::os::pin_to_allowed_cpu(worker);
                }),
                Placement::Free => builder,
            };
            builder.build().map(std::sync::Arc::new)
        })
        .ok()
}

/// `work` on every item, shared between the calling thread and
/// `threads - 1` helpers (a kept pool of unpinned workers), each claiming
/// the next item until none is left; the results in the items' order.
///
/// For work of a few hundred microseconds (a refit): `in_pool` first waits
/// for a sleeping worker to wake, about 40 us a call on the 2-core machine
/// (an eighth of a cloth:20000 refit), and wakes the caller when done. Here
/// the caller starts at once, a worker that wakes late finds less to do,
/// and the caller waits for the last items by spinning, briefly, before the
/// scope's own wait. Work far shorter than a wake-up still waits for one
/// (the scope ends when its helpers have run): keep it for work well over
/// 40 us, as the callers' cut-offs do.
pub(crate) fn share<T: Send, R: Send>(
    threads: usize,
    items: Vec<T>,
    work: impl Fn(T) -> R + Sync,
) -> Vec<R> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Mutex;
    let n = items.len();
    let helpers = threads.min(n).saturating_sub(1);
    let Some(pool) = helper_pool(helpers) else {
        return items.into_iter().map(work).collect();
    };
    let items: Vec<Mutex<Option<T>>> = items.into_iter().map(|t| Mutex::new(Some(t))).collect();
    let results: Vec<Mutex<Option<R>>> = (0..n).map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    let claim = || loop {
        let i = next.fetch_add(1, Ordering::Relaxed);
        let Some(slot) = items.get(i) else { break };
        let item = slot.lock().unwrap_or_else(|p| p.into_inner()).take();
        if let Some(item) = item {
            let r = work(item);
            *results[i].lock().unwrap_or_else(|p| p.into_inner()) = Some(r);
        }
    };
    let finished = AtomicUsize::new(0);
    pool.in_place_scope(|scope| {
        for _ in 0..helpers {
            scope.spawn(|_| {
                claim();
                finished.fetch_add(1, Ordering::Release);
            });
        }
        claim();
        // Spinning, not sleeping in the scope's wait: a caller put to sleep
        // (its CPU idle) is slow to wake on a virtual machine. Bounded: a
        // helper that panicked never finishes (the scope's wait then passes
        // the panic on).
        let until = std::time::Instant::now() + crate::accel::bvh::params::SHARE_SPIN;
        while finished.load(Ordering::Acquire) < helpers && std::time::Instant::now() < until {
            std::hint::spin_loop();
        }
    });
    results
        .into_iter()
        .map(|r| {
            r.into_inner()
                .unwrap_or_else(|p| p.into_inner())
                .expect("every item was claimed and run")
        })
        .collect()
}

/// Values made once per thread count and kept for the process: the build
/// thread pools (starting threads is not part of a build).
pub(crate) struct KeptPerThreads<T>(
    std::sync::OnceLock<std::sync::Mutex<std::collections::HashMap<usize, std::sync::Arc<T>>>>,
);

impl<T> KeptPerThreads<T> {
    pub(crate) const fn new() -> Self {
        KeptPerThreads(std::sync::OnceLock::new())
    }

    /// The value for `threads`, made by `make` the first time it is asked
    /// for (a failed `make` is not kept, so a later call tries again).
    pub(crate) fn get<E>(
        &self,
        threads: usize,
        make: impl FnOnce() -> Result<std::sync::Arc<T>, E>,
    ) -> Result<std::sync::Arc<T>, E> {
        // Entries are only ever added, so a map poisoned by a panic in
        // another caller is still whole.
        let mut kept = self
            .0
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(value) = kept.get(&threads) {
            return Ok(value.clone());
        }
        let value = make()?;
        kept.insert(threads, value.clone());
        Ok(value)
    }
}

#[cfg(test)]
mod tests {
    use super::share;

    #[test]
    fn shared_work_runs_every_item_once_and_keeps_their_order() {
        for threads in [1, 2, 3, 8] {
            for n in [0, 1, 2, 5, 300] {
                let ran = std::sync::atomic::AtomicUsize::new(0);
                let items: Vec<usize> = (0..n).collect();
                let out = share(threads, items, |i| {
                    ran.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    i * 3
                });
                assert_eq!(out, (0..n).map(|i| i * 3).collect::<Vec<_>>());
                assert_eq!(ran.into_inner(), n, "{threads} threads, {n} items");
            }
        }
        // Items may borrow mutably: disjoint chunks of one array.
        let mut data = vec![1u32; 1000];
        let chunks: Vec<&mut [u32]> = data.chunks_mut(64).collect();
        let sums = share(2, chunks, |c| {
            c.iter_mut().for_each(|x| *x += 1);
            c.iter().sum::<u32>()
        });
        assert_eq!(sums.iter().sum::<u32>(), 2000);
        assert!(data.iter().all(|&x| x == 2));
    }
}
