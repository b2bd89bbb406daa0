//! The operating-system and CPU state raylab sets itself, the only `unsafe`
//! outside the Embree FFI and the SIMD kernels: asking Linux to back large
//! arrays with transparent huge pages (FFI to the C library that `std` already
//! links), pinning the build pools' workers to CPUs
//! ([`pin_to_allowed_cpu`]), SIGPIPE's disposition ([`ignore_closed_pipe`],
//! [`end_on_closed_pipe`]), removing a half-written file when a signal ends
//! the process ([`RemoveOnSignal`]), keeping freed memory for reuse
//! ([`keep_freed_memory`]), flushing denormals on render threads
//! ([`FlushDenormals`]), and the binary's allocator, which ends the process
//! with one line when memory runs out ([`OutOfMemoryIsAnError`]).
//!
//! Why: a build writes hundreds of megabytes of fresh memory (primitive
//! references, nodes, leaf blocks), and with 4 KiB pages every page is a
//! fault on first touch; 2 MiB pages need 512 times fewer, and a traversal
//! of a large tree misses the TLB less. Embree asks the same for its own
//! allocations (`madvise(MADV_HUGEPAGE)`, seen with strace), so the two
//! builds are compared on equal terms. Where the kernel ignores the advice
//! (THP `never`, other systems) nothing changes but the speed.

/// Arrays smaller than this keep ordinary pages: no 2 MiB-aligned stretch
/// would fit inside them anyway.
const HUGE_PAGE: usize = 2 << 20;

/// An empty vector with room for `n` items whose memory the kernel is asked
/// to back with huge pages when first touched (on Linux; elsewhere a plain
/// `Vec::with_capacity`).
pub fn huge_vec<T>(n: usize) -> Vec<T> {
    let v = Vec::with_capacity(n);
    advise_huge_pages(v.as_ptr() as usize, v.capacity() * std::mem::size_of::<T>());
    v
}

#[cfg(target_os = "linux")]
fn advise_huge_pages(addr: usize, len: usize) {
    // Only whole 2 MiB-aligned stretches can become huge pages.
    let start = addr.next_multiple_of(HUGE_PAGE);
    let end = (addr + len) / HUGE_PAGE * HUGE_PAGE;
    if end <= start {
        return;
    }
    extern "C" {
        fn madvise(
            addr: *mut std::ffi::c_void,
            len: usize,
            advice: std::ffi::c_int,
        ) -> std::ffi::c_int;
    }
    const MADV_HUGEPAGE: std::ffi::c_int = 14;
    // SAFETY: `start..end` lies inside one live allocation of ours (the
    // vector's capacity), and MADV_HUGEPAGE changes only how the kernel backs
    // those pages, never their contents or the mapping's validity. A failure
    // (EINVAL where THP is compiled out) leaves the memory as it was, so the
    // result is ignored.
    unsafe {
        madvise(start as *mut std::ffi::c_void, end - start, MADV_HUGEPAGE);
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages(_addr: usize, _len: usize) {}

/// Pins the calling thread to the `index`-th of the CPUs it may run on
/// (counted modulo their number); returns whether it did. Linux only.
///
/// Why: the build pools' workers sleep between builds, and a sleeping thread
/// woken by another is put on the waker's CPU first; with two workers on two
/// CPUs, both often ran on one CPU for most of a 10 ms build (Linux
/// schedstat: each runnable but waiting half the time) while the other CPU
/// was idle, so a two-thread build took as long as a one-thread build.
/// Embree's TBB workers spin between tasks and do not meet this.
#[cfg(target_os = "linux")]
pub fn pin_to_allowed_cpu(index: usize) -> bool {
    // glibc's cpu_set_t: 1024 bits.
    const WORDS: usize = 16;
    extern "C" {
        fn sched_getaffinity(pid: std::ffi::c_int, size: usize, mask: *mut u64) -> std::ffi::c_int;
        fn sched_setaffinity(
            pid: std::ffi::c_int,
            size: usize,
            mask: *const u64,
        ) -> std::ffi::c_int;
    }
    let mut allowed = [0u64; WORDS];
    // SAFETY: pid 0 is the calling thread; `allowed` is a live, writable
    // buffer of exactly the size passed, which the call fills and nothing
    // else reads.
    if unsafe { sched_getaffinity(0, std::mem::size_of_val(&allowed), allowed.as_mut_ptr()) } != 0 {
        return false;
    }
    let cpus: Vec<usize> = (0..WORDS * 64)
        .filter(|&c| allowed[c / 64] >> (c % 64) & 1 == 1)
        .collect();
    let Some(&cpu) = cpus.get(index % cpus.len().max(1)) else {
        return false;
    };
    let mut mask = [0u64; WORDS];
    mask[cpu / 64] |= 1 << (cpu % 64);
    // SAFETY: pid 0 is the calling thread; `mask` is a live buffer of the
    // size passed, read only; the CPU is one the thread is allowed, so the
    // call cannot leave it with none.
    unsafe { sched_setaffinity(0, std::mem::size_of_val(&mask), mask.as_ptr()) == 0 }
}

#[cfg(not(target_os = "linux"))]
pub fn pin_to_allowed_cpu(_index: usize) -> bool {
    false
}

/// Ignores SIGPIPE (as Rust's runtime does before `main`; said here, since
/// the binary once restored its default action), so that a write to a closed
/// pipe fails with EPIPE instead of ending the process: a closed stderr must
/// not stop a render before its image is written. A closed stdout still ends
/// raylab quietly, through [`end_on_closed_pipe`] (see [`crate::console`]).
#[cfg(unix)]
pub fn ignore_closed_pipe() {
    // SAFETY: signal(2) with SIG_IGN installs no handler of ours (no code runs
    // at signal time). It is called once, at start-up, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
}

#[cfg(not(unix))]
pub fn ignore_closed_pipe() {}

/// Ends the process as SIGPIPE's default action would: quietly, status
/// 128 + 13 in a shell. Used when stdout's reader has gone (`raylab validate
/// ... | head -1`), as git, ripgrep and every C tool end there.
#[cfg(unix)]
pub fn end_on_closed_pipe() -> ! {
    // SAFETY: signal(2) with SIG_DFL installs no handler, and raise(3) sends
    // the signal to this thread, whose default action ends the process; no
    // memory is touched.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        libc::raise(libc::SIGPIPE);
    }
    // Not reached where SIGPIPE ends the process; the same status otherwise.
    std::process::exit(128 + libc::SIGPIPE)
}

#[cfg(not(unix))]
pub fn end_on_closed_pipe() -> ! {
    std::process::exit(0)
}

/// The temporary file being written ([`RemoveOnSignal`]), as a C string for
/// the signal handler; null when none.
#[cfg(unix)]
static PENDING_TEMP: std::sync::atomic::AtomicPtr<std::ffi::c_char> =
    std::sync::atomic::AtomicPtr::new(std::ptr::null_mut());

/// While alive, a SIGINT, SIGTERM or SIGHUP that ends raylab first removes
/// the temporary file it names, so that an interrupted write (Ctrl-C during
/// a large PNG) leaves no `NAME.tmp-...` behind. The signal then ends the
/// process as it would have (its default action, raised again). Signals the
/// process was started ignoring (`nohup`, a background job's SIGINT) stay
/// ignored. One file at a time: raylab writes its files one after another.
/// SIGKILL, or a crash, can still leave the file.
pub struct RemoveOnSignal {
    _private: (),
}

impl RemoveOnSignal {
    #[cfg(unix)]
    pub fn new(path: &std::path::Path) -> Self {
        use std::os::unix::ffi::OsStrExt;
        use std::sync::atomic::Ordering;
        static INSTALL: std::sync::Once = std::sync::Once::new();
        INSTALL.call_once(install_temp_removal);
        if let Ok(c) = std::ffi::CString::new(path.as_os_str().as_bytes()) {
            // Leaked, never freed: a handler may still read a pointer that
            // was just replaced (a few bytes per file written).
            PENDING_TEMP.store(c.into_raw(), Ordering::SeqCst);
        }
        RemoveOnSignal { _private: () }
    }

    #[cfg(not(unix))]
    pub fn new(_path: &std::path::Path) -> Self {
        RemoveOnSignal { _private: () }
    }
}

impl Drop for RemoveOnSignal {
    fn drop(&mut self) {
        #[cfg(unix)]
        PENDING_TEMP.store(std::ptr::null_mut(), std::sync::atomic::Ordering::SeqCst);
    }
}

#[cfg(unix)]
extern "C" fn remove_temp_and_end(sig: std::ffi::c_int) {
    let path = PENDING_TEMP.swap(std::ptr::null_mut(), std::sync::atomic::Ordering::SeqCst);
    // SAFETY: unlink(2) and raise(3) are async-signal-safe; `path` is null or
    // a NUL-terminated string that is never freed. SA_RESETHAND restored the
    // default action before this ran, and the signal is blocked until the
    // handler returns, so the raised one then ends the process as the
    // original would have.
    unsafe {
        if !path.is_null() {
            libc::unlink(path);
        }
        libc::raise(sig);
    }
}

#[cfg(unix)]
fn install_temp_removal() {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: sigaction(2) with a zeroed struct as the output reads the
        // current action; the new action runs only async-signal-safe code
        // (remove_temp_and_end) and is installed only over the default one,
        // so an ignored signal stays ignored and nobody else's handler is
        // replaced.
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(sig, std::ptr::null(), &mut old) != 0
                || old.sa_sigaction != libc::SIG_DFL
            {
                continue;
            }
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = remove_temp_and_end as extern "C" fn(std::ffi::c_int) as usize;
            action.sa_flags = libc::SA_RESETHAND;
            libc::sigemptyset(&mut action.sa_mask);
            libc::sigaction(sig, &action, std::ptr::null_mut());
        }
    }
}

/// Most bytes glibc's allocator hands out from its heaps, reusing freed
/// memory, rather than mapping fresh pages per allocation (glibc's upper
/// limit for the setting on 64-bit targets).
const MMAP_THRESHOLD: std::ffi::c_int = 32 << 20;

/// Free memory glibc may keep at the top of a heap before it hands pages back
/// to the kernel.
const TRIM_THRESHOLD: std::ffi::c_int = 1 << 30;

/// Asks glibc's allocator to keep freed memory for reuse: allocations up to
/// [`MMAP_THRESHOLD`] come from its heaps, and up to [`TRIM_THRESHOLD`] of
/// free heap stays mapped.
///
/// Why: a build's large arrays are allocated on the build pool's worker
/// threads, whose glibc arenas hand freed pages back to the kernel
/// (`MADV_DONTNEED`), so every two-thread build faulted its memory in afresh,
/// while a one-thread build, on the main thread's heap, reused it. Warm LBVH
/// builds of mesh:50000 on two threads took 1,120 page faults each and 4.0
/// ms, 2.0 ms without the faults; Embree LOW's 540 and 2.3 ms, 1.6 ms
/// without. A repeated build now costs what its work costs on any thread
/// count, for raylab's builders and Embree's alike (Embree allocates through
/// the same `malloc`). Called once, at start-up, by the binary and the
/// criterion benches; the price is memory kept after a large build is
/// dropped.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn keep_freed_memory() {
    extern "C" {
        fn mallopt(param: std::ffi::c_int, value: std::ffi::c_int) -> std::ffi::c_int;
    }
    const M_TRIM_THRESHOLD: std::ffi::c_int = -1;
    const M_MMAP_THRESHOLD: std::ffi::c_int = -3;
    // SAFETY: mallopt(3) only sets glibc malloc's tuning parameters (under
    // its own lock); no memory is touched, and a value it refuses leaves the
    // setting as it was (the result is ignored: the settings change speed,
    // never behaviour).
    unsafe {
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD);
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn keep_freed_memory() {}

// Flush-to-zero and denormals-are-zero for threads that call Embree, as its
// documentation advises (denormal floats make its kernels much slower). The
// guard restores the thread's previous MXCSR, so code that runs later on the
// same thread (another backend's render) is unaffected.

/// While alive, the current thread flushes denormals (x86-64; no-op elsewhere).
pub struct FlushDenormals {
    #[cfg(target_arch = "x86_64")]
    saved: u32,
    /// MXCSR is per thread: the guard must be dropped where it was made.
    _not_send: std::marker::PhantomData<*const ()>,
}

#[cfg(target_arch = "x86_64")]
const FTZ_DAZ: u32 = 0x8040;

impl FlushDenormals {
    pub fn enable() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let mut saved: u32 = 0;
            // SAFETY: stmxcsr/ldmxcsr read and write this thread's SSE control
            // register only; setting FTZ and DAZ changes rounding of denormals, not
            // memory safety.
            unsafe {
                std::arch::asm!("stmxcsr [{}]", in(reg) &mut saved, options(nostack));
                let new = saved | FTZ_DAZ;
                std::arch::asm!("ldmxcsr [{}]", in(reg) &new, options(nostack));
            }
            FlushDenormals {
                saved,
                _not_send: std::marker::PhantomData,
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        FlushDenormals {
            _not_send: std::marker::PhantomData,
        }
    }
}

impl Drop for FlushDenormals {
    fn drop(&mut self) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: restores the value read in `enable` on the same thread (the
        // guard is not Send).
        unsafe {
            std::arch::asm!("ldmxcsr [{}]", in(reg) &self.saved, options(nostack));
        }
    }
}

/// The process's peak resident memory in bytes (Linux's `VmHWM` in
/// /proc/self/status); `None` where the system does not say.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The binary's global allocator: the system's, except that an allocation
/// it cannot make ends raylab with one line on stderr and exit status 1,
/// where Rust would abort (SIGABRT, a backtrace). A scene within the
/// triangle budget can still need more memory than the machine (or a
/// `ulimit -v`) gives: 10^8 instanced triangles flattened are 1.2 GB of
/// vertices before any tree. Every allocation is infallible to raylab's
/// code (it never calls `try_reserve`), so ending here loses nothing a
/// caller could have handled.
pub struct OutOfMemoryIsAnError;

impl OutOfMemoryIsAnError {
    /// `ptr` when it is not null; else the one line, and the end.
    #[inline]
    fn checked(ptr: *mut u8, size: usize) -> *mut u8 {
        if ptr.is_null() {
            out_of_memory(size);
        }
        ptr
    }
}

// SAFETY: every method forwards its arguments unchanged to `System`, whose
// implementation upholds `GlobalAlloc`'s contract; a null result ends the
// process instead of being returned, which no caller can observe.
unsafe impl std::alloc::GlobalAlloc for OutOfMemoryIsAnError {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: the caller's `layout` contract is `System.alloc`'s.
        Self::checked(unsafe { std::alloc::System.alloc(layout) }, layout.size())
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: as `alloc`.
        Self::checked(
            unsafe { std::alloc::System.alloc_zeroed(layout) },
            layout.size(),
        )
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        // SAFETY: `ptr` came from this allocator, which is `System`'s, with
        // `layout`; the caller's contract is `System.realloc`'s.
        Self::checked(
            unsafe { std::alloc::System.realloc(ptr, layout, new_size) },
            new_size,
        )
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: `ptr` came from `System` through this allocator with `layout`.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
}

/// Writes the out-of-memory line to stderr and ends the process, without
/// allocating (the line is formatted on the stack) and without running
/// anything that might (`_exit`, not `exit`).
#[cold]
fn out_of_memory(size: usize) -> ! {
    use std::io::Write;
    let mut line = [0u8; 320];
    let mut cursor = std::io::Cursor::new(&mut line[..]);
    let _ = writeln!(
        cursor,
        "raylab: out of memory: {size} bytes could not be allocated; lower --max-triangles or --max-pixels, or trace an instanced scene without --flatten (its two-level tree holds each mesh once)"
    );
    let len = cursor.position() as usize;
    // SAFETY: `line[..len]` is initialised and lives across the call; fd 2
    // is stderr (a closed one makes write fail, which is ignored). `_exit`
    // ends the process at once.
    unsafe {
        libc::write(2, line.as_ptr().cast(), len);
        libc::_exit(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Page faults the calling thread has taken that needed no disk read
    /// (`ru_minflt` of getrusage(RUSAGE_THREAD)).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn minor_faults() -> i64 {
        extern "C" {
            fn getrusage(who: std::ffi::c_int, usage: *mut i64) -> std::ffi::c_int;
        }
        const RUSAGE_THREAD: std::ffi::c_int = 1;
        // struct rusage on 64-bit Linux: two timevals (four longs), then
        // fourteen longs, ru_minflt the fifth of them.
        let mut usage = [0i64; 18];
        // SAFETY: `usage` is 144 bytes, the size of struct rusage on 64-bit
        // Linux, and getrusage only writes into it.
        let rc = unsafe { getrusage(RUSAGE_THREAD, usage.as_mut_ptr()) };
        assert_eq!(rc, 0);
        usage[8]
    }

    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn freed_memory_is_reused_on_other_threads() {
        keep_freed_memory();
        // On a thread of its own, as a build pool's worker: glibc gave such a
        // thread's freed pages back to the kernel, and the next allocation of
        // the same size faulted every page in again (2,048 for 8 MiB).
        std::thread::spawn(|| {
            let touch = || {
                let mut v = vec![1u8; 8 << 20];
                for i in (0..v.len()).step_by(4096) {
                    v[i] = 2;
                }
                std::hint::black_box(&v);
            };
            touch();
            let before = minor_faults();
            touch();
            let faults = minor_faults() - before;
            assert!(faults < 256, "{faults} page faults reallocating 8 MiB");
        })
        .join()
        .unwrap();
    }

    /// The CPUs the calling thread may run on, from /proc.
    #[cfg(target_os = "linux")]
    fn allowed_cpus() -> String {
        let status = std::fs::read_to_string("/proc/thread-self/status").unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
            .unwrap()
            .trim()
            .to_string()
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn pinning_leaves_a_thread_one_of_its_cpus() {
        let all = allowed_cpus();
        for index in [0, 1, 7] {
            let (pinned, cpus) = std::thread::spawn(move || {
                let pinned = pin_to_allowed_cpu(index);
                (pinned, allowed_cpus())
            })
            .join()
            .unwrap();
            assert!(pinned, "index {index}");
            let cpu: usize = cpus.parse().expect("a single CPU");
            assert!(
                all.split(',').any(|range| {
                    let mut ends = range.split('-').map(|x| x.parse::<usize>().unwrap());
                    let lo = ends.next().unwrap();
                    let hi = ends.next().unwrap_or(lo);
                    (lo..=hi).contains(&cpu)
                }),
                "CPU {cpu} not among {all}"
            );
        }
        // The calling thread is not affected.
        assert_eq!(allowed_cpus(), all);
    }

    #[test]
    fn huge_vectors_are_ordinary_vectors() {
        for n in [0, 1, 1000, 3 << 20] {
            let mut v: Vec<u64> = huge_vec(n);
            assert!(v.capacity() >= n && v.is_empty());
            v.extend(0..n as u64);
            assert_eq!(
                v.iter().sum::<u64>(),
                (n as u64) * (n as u64).saturating_sub(1) / 2
            );
        }
    }
}
