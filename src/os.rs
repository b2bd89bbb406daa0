//! The two operating-system calls raylab makes itself (FFI to the C library
//! that `std` already links): asking Linux to back large arrays with
//! transparent huge pages, and letting a closed output pipe end the process
//! quietly ([`quiet_on_closed_pipe`]).
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
