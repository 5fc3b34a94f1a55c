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

/// Keep freed pages for reuse (`true`, the start-up setting: right for the alignment's
/// per-frame SIFT pyramids) or hand them back to the kernel after 10 s (`false`: the
/// fit allocates many differently sized buffers, and keeping every freed page raised
/// its peak on the paper preset from 4.4 GB to 7.0 GB). Applies to every arena.
pub fn retain_freed_pages(retain: bool) {
    #[cfg(all(target_os = "linux", not(target_env = "musl")))]
    #[allow(unsafe_code)]
    // SAFETY: mallctl reads `arenas.narenas` into a u32 and writes ssize_t decay
    // times, with the sizes jemalloc documents for these names; names are
    // NUL-terminated. Failures (an index without an arena) are ignored.
    unsafe {
        use std::ffi::{c_void, CString};
        let ms: isize = if retain { -1 } else { 10_000 };
        let mut narenas: u32 = 0;
        let mut len = std::mem::size_of::<u32>();
        tikv_jemalloc_sys::mallctl(
            c"arenas.narenas".as_ptr(),
            (&mut narenas as *mut u32).cast::<c_void>(),
            &mut len,
            std::ptr::null_mut(),
            0,
        );
        let mut names: Vec<String> = (0..narenas)
            .flat_map(|i| {
                [
                    format!("arena.{i}.dirty_decay_ms"),
                    format!("arena.{i}.muzzy_decay_ms"),
                ]
            })
            .collect();
        names.push("arenas.dirty_decay_ms".into());
        names.push("arenas.muzzy_decay_ms".into());
        for name in names {
            let Ok(c) = CString::new(name) else { continue };
            let mut v = ms;
            tikv_jemalloc_sys::mallctl(
                c.as_ptr(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                (&mut v as *mut isize).cast::<c_void>(),
                std::mem::size_of::<isize>(),
            );
        }
    }
    #[cfg(not(all(target_os = "linux", not(target_env = "musl"))))]
    let _ = retain;
    release_free_memory();
}
