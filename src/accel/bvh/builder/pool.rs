//! The build thread pools and other values kept per thread count: made once
//! and kept for the process, as Embree keeps its threads, so that starting
//! threads is never part of a timed build. The builders themselves only take
//! `parallel` and run on whatever pool they are called in; the entry point
//! ([`super::build`]) chooses the pool.

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
    if threads <= 1 {
        return f();
    }
    static POOLS: KeptPerThreads<rayon::ThreadPool> = KeptPerThreads::new();
    let pool = POOLS
        .get(threads, || {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                // One CPU each, so that waking workers are not stacked on
                // one CPU (see `os::pin_to_allowed_cpu`).
                .start_handler(|worker| {
                    crate::os::pin_to_allowed_cpu(worker);
                })
                .build()
                .map(std::sync::Arc::new)
        })
        .ok();
    match pool {
        Some(pool) => pool.install(f),
        // No threads to be had: the same result, computed serially.
        None => f(),
    }
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
