//! Ctrl-C (SIGINT) as a request to stop: `record` ends cleanly on it (files flushed, the
//! calibration of `--calibrate` run); a second Ctrl-C ends the process at once.

use std::sync::atomic::{AtomicBool, Ordering};

/// Set by the first Ctrl-C after [`catch_ctrl_c`].
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_interrupt(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
}

/// From now on the first Ctrl-C sets [`interrupted`] instead of ending the process.
pub fn catch_ctrl_c() {
    // Note(unsafe): sigaction with a zeroed (valid) struct and a handler that only stores to
    // an atomic, which is async-signal-safe; SA_RESETHAND restores the default action after
    // the first signal. No SA_RESTART: a blocking read returns (EINTR, taken as no data).
    #[allow(unsafe_code)]
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_interrupt as extern "C" fn(libc::c_int) as usize;
        sa.sa_flags = libc::SA_RESETHAND;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGINT, &sa, std::ptr::null_mut());
    }
}

/// True once Ctrl-C was pressed.
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}
