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

/// Length of drive (s) a vector of [`for_drive`] holds before it grows.
pub const DRIVE_RESERVED_S: usize = 4 * 3600;

/// Samples a second of a calibration drive (the PPS-locked rate).
pub const DRIVE_SAMPLES_PER_S: usize = 50;

/// Reference epochs a second of a calibration drive (a receiver at up to 20 Hz).
pub const DRIVE_EPOCHS_PER_S: usize = 20;

/// Bytes a second of a calibration drive's NMEA log (GGA, GST, HDT and RMC at 20 Hz).
pub const DRIVE_LOG_BYTES_PER_S: usize = 6_000;

/// An empty vector for what grows as long as a drive lasts (a recording's rows, its log, the
/// live fit's matches), `per_second` items a second: its capacity holds [`DRIVE_RESERVED_S`]
/// of them and is above [`MMAP_THRESHOLD`], so glibc maps it on its own. Its pages are
/// touched only as written, and it grows, if ever, by remapping them. A vector in the heap
/// copies all it holds whenever its capacity doubles: milliseconds at a few megabytes, inside
/// one live update. Where the address space is refused (strict overcommit), the capacity is
/// the mmap threshold's alone.
pub fn for_drive<T>(per_second: usize) -> Vec<T> {
    let mapped = MMAP_THRESHOLD / std::mem::size_of::<T>().max(1) + 1;
    let mut v = Vec::new();
    if v.try_reserve_exact(per_second.saturating_mul(DRIVE_RESERVED_S).max(mapped))
        .is_err()
    {
        v.reserve_exact(mapped);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::{for_drive, DRIVE_RESERVED_S, MMAP_THRESHOLD};

    /// Above the mmap threshold whatever the rate, and the drive's length at its rate.
    #[test]
    fn a_drive_vector_is_mapped_and_holds_the_drive() {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        assert!(bytes(&for_drive::<u8>(0)) > MMAP_THRESHOLD);
        assert!(bytes(&for_drive::<u8>(1)) > MMAP_THRESHOLD);
        assert!(bytes(&for_drive::<[u8; 3]>(1)) > MMAP_THRESHOLD);
        assert_eq!(for_drive::<[u8; 152]>(50).capacity(), 50 * DRIVE_RESERVED_S);
        assert_eq!(for_drive::<u8>(4_000).capacity(), 4_000 * DRIVE_RESERVED_S);
        assert!(for_drive::<()>(50).is_empty());
        // More than the address space: the mmap threshold's capacity.
        assert!(bytes(&for_drive::<[u8; 1024]>(usize::MAX)) > MMAP_THRESHOLD);
    }

    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_both_thresholds() {
        assert!(super::keep_freed_memory());
    }
}
