//! The process's memory allocator, set up for the calibration's working set.
//!
//! A calibration of a long run allocates, fills and frees vectors of tens of megabytes many
//! times over (a 300,000-sample run's Jacobian is 19 MB, each evaluation a dozen columns of
//! 2.4 MB). glibc's `malloc` serves blocks above its mmap threshold (128 KiB at start) with
//! fresh `mmap`s and returns them, and the free top of its heaps, to the kernel at once, so
//! every such vector is paged in again: a first-touch page fault and a cleared page per
//! 4 KiB, about a seventh of a 3 km calibration's time. [`keep_freed_memory`] raises both
//! thresholds, so that freed blocks stay in the heap for the next allocation.

/// Largest block glibc serves from its heap instead of a private `mmap`: its ceiling on
/// 64-bit machines (32 MiB; larger values are refused). Above it, blocks are still mapped
/// one by one.
pub const MMAP_THRESHOLD: usize = 32 << 20;

/// Free memory at the top of a heap that glibc keeps instead of returning it (bytes).
pub const TRIM_THRESHOLD: usize = 512 << 20;

/// Sets glibc's mmap and trim thresholds to [`MMAP_THRESHOLD`] and [`TRIM_THRESHOLD`]
/// (true when glibc took both). Call it at the start of `main`, before any thread. On other
/// C libraries it does nothing (and returns false).
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // Note(unsafe): `mallopt` only changes two allocator parameters; it has no memory
        // effects of its own, and the values are in glibc's documented ranges (it returns 0
        // and changes nothing otherwise).
        #[allow(unsafe_code)]
        let ok = unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD as libc::c_int) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD as libc::c_int) == 1
        };
        ok
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_both_thresholds() {
        assert!(super::keep_freed_memory());
    }
}
