//! The process's standard output sent to a file for a while: an in-process run of a command
//! prints its report there, not into the section being printed.

use std::io::Write;
use std::os::fd::AsRawFd;
use std::path::Path;

/// Runs `f` with the standard output (descriptor 1) going to the file `path`, then restores
/// it.
pub fn stdout_to<T>(path: &Path, f: impl FnOnce() -> T) -> T {
    let file = std::fs::File::create(path).expect("the capture file");
    let _ = std::io::stdout().flush();
    // Note(unsafe): dup and dup2 on this process's own descriptors, which stay open; the
    // standard output is restored below before the saved descriptor is closed.
    let saved = unsafe { libc::dup(1) };
    assert!(saved >= 0, "dup of the standard output");
    // Note(unsafe): as above.
    unsafe { libc::dup2(file.as_raw_fd(), 1) };
    let out = f();
    let _ = std::io::stdout().flush();
    // Note(unsafe): as above.
    unsafe {
        libc::dup2(saved, 1);
        libc::close(saved);
    }
    out
}
