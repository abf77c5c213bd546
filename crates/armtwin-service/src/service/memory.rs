//! Giving freed memory back to the system after robots are retired.
//!
//! glibc's malloc keeps what its per-thread arenas free for reuse, so after a flood of robots is
//! retired most of the service's RSS is free heap; `malloc_trim` returns those pages
//! (benches/python/README.md, "Robots that come and go", with the allocators tried instead).
//! Elsewhere this does nothing.
#![allow(
    unsafe_code,
    reason = "malloc_trim is a C function of glibc; this module is the service's only unsafe code"
)]

/// Returns the allocator's free pages to the system, where the allocator is glibc's.
pub(super) fn give_back_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim takes no pointer and only reorganises glibc's own free lists; any
    // thread may call it at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}
