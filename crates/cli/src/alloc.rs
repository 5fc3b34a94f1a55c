//! The process's memory allocator.
//!
//! jemalloc serves the whole process, OpenCV's C++ allocations included (the
//! unprefixed build replaces `malloc` and `posix_memalign` for the shared libraries
//! too). SIFT on a 4K frame allocates about 1 GB of short-lived pyramid images. glibc
//! hands every block above 32 MB back to the kernel with `munmap`, so each frame paid
//! for about 250,000 fresh zeroed pages: 30% of the alignment's wall time was spent in
//! the kernel (measured with `perf`), and jemalloc's default (a separate arena for
//! blocks above 8 MB that returns them at once) saved only a little. Keeping freed
//! pages (`dirty_decay_ms:-1`) cut decode + features on the paper preset from 233 s to
//! 138 s. The kept pages are handed back at every stage boundary
//! ([`release_free_memory`]) so one stage's peak does not add to the next one's.

#[cfg(all(target_os = "linux", not(target_env = "musl")))]
#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// jemalloc's start-up options (read once by jemalloc; `MALLOC_CONF` in the
/// environment still overrides them).
#[cfg(all(target_os = "linux", not(target_env = "musl")))]
#[allow(unsafe_code, non_upper_case_globals)]
#[unsafe(export_name = "malloc_conf")]
pub static malloc_conf: &[u8; 36] = b"dirty_decay_ms:-1,muzzy_decay_ms:-1\0";

/// Give the pages that jemalloc keeps for reuse back to the operating system.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", not(target_env = "musl")))]
    #[allow(unsafe_code)]
    // SAFETY: `arena.<MALLCTL_ARENAS_ALL>.purge` takes no old or new value, so null
    // pointers and length 0 are its documented arguments; the name is NUL-terminated.
    unsafe {
        let name = c"arena.4096.purge";
        tikv_jemalloc_sys::mallctl(
            name.as_ptr(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            0,
        );
    }
}
