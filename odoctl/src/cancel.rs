//! A thread's cancel flag: set by whoever started the thread's work (the background batch's
//! worker at the drive's end), read inside that work, where an error ends it early.

use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{bail, Result};

thread_local! {
    /// The flag that cancels this thread's work.
    static CANCEL: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
}

/// Makes `flag` cancel the work this thread runs from now on (none: no flag): once it is set,
/// the calibration's phases end with an error between and inside them (an evaluation of the
/// restarted sub-trajectories, of the sub-trajectories (the sub-trajectory fit's trial steps),
/// a pass of the filter's preparation; a score of the filter's likelihood is NaN without
/// running the filter, a result no search keeps), and so does the reading of an NMEA log
/// (every 4,096 epochs). What runs between two checks (a few integrations of the drive at
/// most) runs to its end. A thread started for the same work takes the flag over
/// ([`this_thread_cancel`]).
pub fn cancel_this_thread_on(flag: Option<Arc<AtomicBool>>) {
    CANCEL.with(|c| *c.borrow_mut() = flag);
}

/// This thread's cancel flag ([`cancel_this_thread_on`]).
pub fn this_thread_cancel() -> Option<Arc<AtomicBool>> {
    CANCEL.with(|c| c.borrow().clone())
}

/// Whether this thread's cancel flag is set.
pub fn this_thread_cancelled() -> bool {
    CANCEL.with(|c| {
        c.borrow()
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    })
}

/// An error once this thread's cancel flag is set.
pub fn check_this_thread() -> Result<()> {
    if this_thread_cancelled() {
        bail!("the calibration was cancelled");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The thread's flag cancels this thread's work, not another's; a thread given the flag
    /// is cancelled with it.
    #[test]
    fn the_threads_flag_cancels_its_work_alone() {
        let flag = Arc::new(AtomicBool::new(false));
        cancel_this_thread_on(Some(Arc::clone(&flag)));
        assert!(check_this_thread().is_ok());
        flag.store(true, Ordering::Relaxed);
        assert!(check_this_thread().is_err());
        assert!(std::thread::spawn(this_thread_cancelled)
            .join()
            .is_ok_and(|c| !c));
        let taken = this_thread_cancel();
        let other = std::thread::spawn(move || {
            cancel_this_thread_on(taken);
            this_thread_cancelled()
        });
        assert!(other.join().is_ok_and(|c| c));
        cancel_this_thread_on(None);
        assert!(check_this_thread().is_ok());
    }
}
