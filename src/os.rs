//! The operating-system and CPU state raylab sets itself, the only `unsafe`
//! outside the Embree FFI and the SIMD kernels: asking Linux to back large
//! arrays with transparent huge pages (FFI to the C library that `std` already
//! links), letting a closed output pipe end the process quietly
//! ([`quiet_on_closed_pipe`]), and flushing denormals on render threads
//! ([`FlushDenormals`]).
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

/// Restores the default action of SIGPIPE (Rust's runtime ignores it), so that
/// `raylab validate ... | head -1` ends quietly when `head` closes the pipe, as
/// git, ripgrep and every C tool do, instead of panicking in `println!` on the
/// EPIPE error ("failed printing to stdout: Broken pipe").
#[cfg(unix)]
pub fn quiet_on_closed_pipe() {
    extern "C" {
        fn signal(signum: std::ffi::c_int, handler: usize) -> usize;
    }
    const SIGPIPE: std::ffi::c_int = 13;
    const SIG_DFL: usize = 0;
    // SAFETY: signal(2) with SIG_DFL installs no handler of ours (no code runs
    // at signal time), and SIGPIPE is 13 on every Unix Rust targets (Linux, the
    // BSDs, macOS). It is called once, at start-up, before any thread exists.
    unsafe {
        signal(SIGPIPE, SIG_DFL);
    }
}

#[cfg(not(unix))]
pub fn quiet_on_closed_pipe() {}

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

#[cfg(test)]
mod tests {
    use super::*;

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
