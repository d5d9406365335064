//! Where the wall time of a measurement went: the measuring thread's own CPU time and its wait
//! for a core, and the share of the machine's CPU time the hypervisor gave to other guests
//! (steal).

use std::time::Duration;

/// CPU time the calling thread has run (`CLOCK_THREAD_CPUTIME_ID`).
pub fn thread_cpu() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // Note(unsafe): clock_gettime writes one timespec, which lives on this stack frame.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Time the calling thread has waited on a run queue, runnable but without a core (the
/// second field of /proc/thread-self/schedstat); `None` where there is no such file.
pub fn thread_run_delay() -> Option<Duration> {
    let stat = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = stat.split_whitespace().nth(1)?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

/// The machine's CPU time so far from the `cpu` line of /proc/stat (clock ticks): stolen
/// by the hypervisor, and in all. `None` where there is no such file.
pub fn machine_ticks() -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat.lines().find(|l| l.starts_with("cpu "))?;
    let ticks: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .map(|v| v.parse().ok())
        .collect::<Option<_>>()?;
    // user nice system idle iowait irq softirq steal (guest times are inside user and nice).
    let total = ticks.iter().take(8).sum();
    Some((*ticks.get(7)?, total))
}

/// The share of the machine's CPU time stolen between two readings of [`machine_ticks`].
pub fn stolen_share(before: Option<(u64, u64)>, after: Option<(u64, u64)>) -> Option<f64> {
    let ((s0, t0), (s1, t1)) = (before?, after?);
    (t1 > t0).then(|| (s1 - s0) as f64 / (t1 - t0) as f64)
}
