//! `record --calibrate`'s batch calibration in the background: a thread of the lowest
//! priority, kept off one core (on Linux, [`to_the_background`]), so that the recording, the
//! live updates and the final calibration come first, runs the batch calibration of the
//! drive's end (`odoctl calibrate` with the same command line, [`calibration`]) again and
//! again, each time on every row and sentence handed to it by its start, each from where the
//! one before left its searches ([`WarmStart`]), and keeps the latest result and warm start
//! (the final calibration's). The log's lines are read as they are handed on ([`LogLines`]),
//! so that a batch dates the epochs but does not read the whole log again. Nothing it does
//! is printed; a batch that fails (too little data yet) is counted and the next one tried. At
//! the drive's end ([`BatchWorker::stop`]) the batch under way is cancelled (its thread's
//! flag, `cancel::cancel_this_thread_on`) at its next check, between its phases and
//! inside its fits and its reading of the log, and the thread is waited for
//! (docs/CALIBRATION.md).

use std::borrow::Cow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Result;
use odo_unit::odometry::ChassisParams;

use super::calibrate::{calibration_with, parse_command_line, Inputs};
use super::reference_options;
#[cfg(target_os = "linux")]
use crate::calib::pipeline::cores;
use crate::calib::{Extras, WarmStart};
use crate::cancel::cancel_this_thread_on;
use crate::csvio::Sample;
use crate::reference::nmea::LogLines;

/// The latest batch calibration of the drive so far.
#[derive(Debug, Clone, Copy)]
pub struct BatchResult {
    /// Time of the last sample it saw (s, the samples' time base).
    pub until: f64,
    /// The sub-trajectory fit's left diameter, right diameter, track width (m).
    pub subtrajectory: [f64; 3],
    /// The result's (filter-refined where the refinement applied) (m).
    pub result: [f64; 3],
    /// The result's cluster-robust standard errors (m).
    pub std_errors: [Option<f64>; 3],
    /// The result's parameters (the uncertainty model's coefficients among them).
    pub params: ChassisParams,
    /// Wall time the batch took.
    pub took: Duration,
    /// Batches done, and failed, so far.
    pub done: usize,
    /// See `done`.
    pub failed: usize,
}

impl BatchResult {
    /// What the batch adds to its own sub-trajectory fit: result - sub-trajectory fit (m).
    pub fn correction(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| self.result[i] - self.subtrajectory[i])
    }
}

/// Rows (as read back) and log bytes since the last hand-over.
type Chunk = (Vec<Sample>, Vec<u8>);

/// The latest batch's result and warm start.
type Slot = Mutex<Option<(BatchResult, Option<WarmStart>)>>;

/// The background batch calibration (module documentation).
pub struct BatchWorker {
    tx: Option<Sender<Chunk>>,
    latest: Arc<Slot>,
    /// Set at the drive's end: no batch starts after it, the one under way is cancelled.
    stopped: Arc<AtomicBool>,
    /// Rows and log bytes handed on so far.
    sent: (usize, usize),
    /// The thread, until it is stopped.
    thread: Option<JoinHandle<()>>,
}

impl BatchWorker {
    /// Starts the thread; `args` is the `odoctl calibrate` command line of the final
    /// calibration (its `--out` is not written).
    pub fn start(args: Vec<String>) -> Result<Self> {
        // Refused here, not on the thread.
        parse_command_line(&args)?;
        let (tx, rx) = channel();
        let latest = Arc::new(Mutex::new(None));
        let slot = Arc::clone(&latest);
        let stopped = Arc::new(AtomicBool::new(false));
        let stop = Arc::clone(&stopped);
        let thread = std::thread::Builder::new()
            .name("batch calibration".into())
            .spawn(move || work(&args, &rx, &slot, &stop))?;
        Ok(Self {
            tx: Some(tx),
            latest,
            stopped,
            sent: (0, 0),
            thread: Some(thread),
        })
    }

    /// Hands on what of `samples` (every row so far) and `nmea` (the log so far) is new.
    pub fn feed(&mut self, samples: &[Sample], nmea: &[u8]) {
        let (s, b) = self.sent;
        if s >= samples.len() && b >= nmea.len() {
            return;
        }
        let chunk = (samples[s..].to_vec(), nmea[b.min(nmea.len())..].to_vec());
        self.sent = (samples.len(), nmea.len().max(b));
        if let Some(tx) = &self.tx {
            if tx.send(chunk).is_err() {
                self.tx = None;
            }
        }
    }

    /// The latest result, if a batch has succeeded.
    pub fn latest(&self) -> Option<BatchResult> {
        let slot = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        slot.as_ref().map(|(r, _)| *r)
    }

    /// Where the latest successful batch left its searches.
    pub fn warm_start(&self) -> Option<WarmStart> {
        let slot = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        slot.as_ref().and_then(|(_, w)| w.clone())
    }

    /// No batch starts after this, and the one under way ends at its next check of its
    /// threads' cancel flag (module documentation); does not wait for it ([`BatchWorker::stop`]
    /// does).
    pub fn cancel(&mut self) {
        self.stopped.store(true, Ordering::Relaxed);
        self.tx = None;
    }

    /// [`BatchWorker::cancel`], then waits for the thread to end, so that nothing of it runs
    /// beside what follows and its freed memory is there for the next thread to take.
    pub fn stop(&mut self) {
        self.cancel();
        if let Some(t) = self.thread.take() {
            // A batch that panicked left no result: the latest stays.
            let _ = t.join();
        }
    }
}

impl Drop for BatchWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// What the thread has been handed: the rows, the log's bytes and its lines read as they
/// came (a batch pays for the dating of the epochs only, not for a reading of the whole log).
struct Received {
    samples: Vec<Sample>,
    nmea: Vec<u8>,
    lines: LogLines,
    /// Bytes of `nmea` given to `lines` (up to the last CR LF).
    read: usize,
}

impl Received {
    /// Nothing yet, the log read with `leap_seconds` as the reference options give them.
    fn new(leap_seconds: Option<i32>) -> Self {
        Self {
            samples: Vec::new(),
            nmea: Vec::new(),
            lines: LogLines::new(LOG_NAME, leap_seconds),
            read: 0,
        }
    }

    /// Takes in `chunk`: its rows, its bytes, and each line its bytes complete.
    fn take(&mut self, (samples, bytes): Chunk) {
        self.samples.extend(samples);
        self.nmea.extend(bytes);
        while let Some(n) = memchr::memmem::find(&self.nmea[self.read..], b"\r\n") {
            let line = &self.nmea[self.read..self.read + n];
            // A line that is not UTF-8 is left out: the finish then reads the log whole.
            if let Ok(text) = std::str::from_utf8(line) {
                self.lines.line(text);
            }
            self.read += n + 2;
        }
    }
}

/// The log's name in a batch's messages.
const LOG_NAME: &str = "live";

/// The thread: waits for data, takes in all that has come, calibrates, keeps the result;
/// ends when `stopped` is set or the sender is gone.
fn work(args: &[String], rx: &Receiver<Chunk>, slot: &Slot, stopped: &Arc<AtomicBool>) {
    to_the_background();
    cancel_this_thread_on(Some(Arc::clone(stopped)));
    let Ok(a) = parse_command_line(args) else {
        return;
    };
    let Ok(o) = reference_options(&a.reference_input) else {
        return;
    };
    let mut received = Received::new(o.leap_seconds);
    let (mut done, mut failed) = (0, 0);
    let mut warm = None;
    while let Ok(first) = rx.recv() {
        for chunk in std::iter::once(first).chain(rx.try_iter()) {
            received.take(chunk);
        }
        if stopped.load(Ordering::Relaxed) {
            return;
        }
        let started = Instant::now();
        let extras = Extras {
            warm: warm.as_ref(),
            cancel: Some(stopped),
        };
        match batch(&a, &received, extras) {
            Ok((mut r, w)) => {
                done += 1;
                r.took = started.elapsed();
                (r.done, r.failed) = (done, failed);
                warm.clone_from(&w);
                *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some((r, w));
            }
            Err(_) if stopped.load(Ordering::Relaxed) => return,
            Err(_) => failed += 1,
        }
    }
}

/// One batch calibration of what was `received`, as `a` asks, with `extras`; with the warm
/// start it leaves.
fn batch(
    a: &crate::cli::CalibrateArgs,
    received: &Received,
    extras: Extras,
) -> Result<(BatchResult, Option<WarmStart>)> {
    let samples = &received.samples;
    let until = samples.last().map_or(f64::NAN, |s| s.t);
    let o = reference_options(&a.reference_input)?;
    extras.check()?;
    let lines = received.lines.clone();
    let source = crate::reference::parse_read(LOG_NAME, &received.nmea, lines, &o)?;
    extras.check()?;
    let inputs = Inputs::of(&source, Cow::Borrowed(samples))?;
    extras.check()?;
    let names = ("samples".to_string(), LOG_NAME.to_string());
    let (c, _, _) = calibration_with(a, &inputs, &names, extras)?;
    let geometry = |p: &ChassisParams| [p.left_diameter, p.right_diameter, p.track_width];
    let result = BatchResult {
        until,
        subtrajectory: c
            .subtrajectories
            .as_ref()
            .map_or(geometry(&c.params), |s| geometry(&s.params)),
        result: geometry(&c.params),
        std_errors: [0, 1, 2].map(|i| c.geometry.robust_std_errors[i]),
        params: c.params,
        took: Duration::ZERO,
        done: 0,
        failed: 0,
    };
    Ok((result, c.warm_start()))
}

/// How far two result files of one recording are apart (the final calibration's, from a
/// warm start, against `odoctl calibrate`'s on the files, [`agreement`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Agreement {
    /// The texts are the same.
    pub identical: bool,
    /// The largest difference of a value that has a standard error (`KEY` beside `KEY_se`
    /// in the same table), in that standard error, and its key.
    pub in_se: (f64, String),
    /// The largest difference of any other number, relative to the larger of the two, and
    /// its key.
    pub relative: (f64, String),
    /// Keys on one side only, or whose strings, integers or booleans differ.
    pub different: Vec<String>,
}

/// The [`Agreement`] of the result files `a` and `b` (TOML text).
pub fn agreement(a: &str, b: &str) -> Result<Agreement> {
    let (ta, tb): (toml::Table, toml::Table) = (a.parse()?, b.parse()?);
    let mut out = Agreement {
        identical: a == b,
        in_se: (0.0, String::new()),
        relative: (0.0, String::new()),
        different: Vec::new(),
    };
    compare_tables(&ta, &tb, "", &mut out);
    Ok(out)
}

/// [`agreement`] of the tables `a` and `b` at `path` (`""` or `"table."`), into `out`.
fn compare_tables(a: &toml::Table, b: &toml::Table, path: &str, out: &mut Agreement) {
    use toml::Value;
    let keys = a.keys().chain(b.keys().filter(|k| !a.contains_key(*k)));
    for key in keys {
        let name = format!("{path}{key}");
        let (x, y) = match (a.get(key), b.get(key)) {
            (Some(Value::Table(x)), Some(Value::Table(y))) => {
                compare_tables(x, y, &format!("{name}."), out);
                continue;
            }
            (Some(Value::Float(x)), Some(Value::Float(y))) => (*x, *y),
            (Some(x), Some(y)) if x == y => continue,
            _ => {
                out.different.push(name);
                continue;
            }
        };
        let se = a.get(&format!("{key}_se")).and_then(Value::as_float);
        let d = (x - y).abs();
        let (worst, v) = match se {
            Some(se) if se > 0.0 => (&mut out.in_se, d / se),
            _ => (
                &mut out.relative,
                d / x.abs().max(y.abs()).max(f64::MIN_POSITIVE),
            ),
        };
        if v > worst.0 || v.is_nan() {
            *worst = (v, name);
        }
    }
}

/// The time slice the background batch's threads ask of the scheduler (ns): its shortest.
const BATCH_SLICE_NS: u64 = 100_000;

/// Moves the calling thread (and the threads it starts, which inherit all three) to the
/// background on Linux: off one of the cores it may run on, so that a live update finds a core
/// the batch does not hold, to nice 19, and to a time slice of [`BATCH_SLICE_NS`] (Linux 6.12
/// and later; an older kernel ignores it), so that an update woken on the batch's core
/// preempts it at once instead of waiting for the end of the default slice (about 3 ms).
/// [`cores`] is asked first, so that the calibration's parallel parts keep the process's
/// count. Elsewhere nothing.
///
/// Not the idle scheduling class (`SCHED_IDLE`): the scheduler counts a core that runs only
/// such threads as idle and wakes an update there, where it measurably waited a scheduler
/// tick (4 ms) for a core more often than beside a nice 19 thread.
fn to_the_background() {
    #[cfg(target_os = "linux")]
    {
        let all = cores();
        let size = std::mem::size_of::<libc::cpu_set_t>();
        // Note(unsafe): the affinity calls read and write one cpu_set_t of `size` bytes on
        // this stack frame, sched_setattr reads one sched_attr of the size it is told on this
        // stack frame; gettid and setpriority take no pointers. Each changes only this
        // thread's scheduling (pid 0, the thread's id); a failure leaves it as it was.
        #[allow(unsafe_code)]
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            if all > 1
                && libc::sched_getaffinity(0, size, &mut set) == 0
                && libc::CPU_COUNT(&set) > 1
            {
                let setsize = libc::CPU_SETSIZE as usize;
                if let Some(c) = (0..setsize).find(|&c| libc::CPU_ISSET(c, &set)) {
                    libc::CPU_CLR(c, &mut set);
                    libc::sched_setaffinity(0, size, &set);
                }
            }
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, 19);
            let mut attr: libc::sched_attr = std::mem::zeroed();
            attr.size = std::mem::size_of::<libc::sched_attr>() as u32;
            attr.sched_policy = libc::SCHED_OTHER as u32;
            attr.sched_nice = 19;
            attr.sched_runtime = BATCH_SLICE_NS;
            let flags: libc::c_uint = 0;
            libc::syscall(
                libc::SYS_sched_setattr,
                0,
                &attr as *const libc::sched_attr,
                flags,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cores a thread may run on, its nice value and its time slice (ns; what the kernel
    /// reports for it, 0 where it reports none).
    #[cfg(target_os = "linux")]
    fn scheduling() -> (i32, i32, u64) {
        let size = std::mem::size_of::<libc::cpu_set_t>();
        // Note(unsafe): reads this thread's affinity into one cpu_set_t and its scheduling
        // attributes into one sched_attr of the size given, both on this stack frame; gettid
        // and getpriority take no pointers.
        #[allow(unsafe_code)]
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(libc::sched_getaffinity(0, size, &mut set), 0);
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            let mut attr: libc::sched_attr = std::mem::zeroed();
            let attr_size = std::mem::size_of::<libc::sched_attr>() as libc::c_uint;
            let flags: libc::c_uint = 0;
            let got = libc::syscall(
                libc::SYS_sched_getattr,
                0,
                &mut attr as *mut libc::sched_attr,
                attr_size,
                flags,
            );
            (
                libc::CPU_COUNT(&set),
                libc::getpriority(libc::PRIO_PROCESS, tid),
                if got == 0 { attr.sched_runtime } else { 0 },
            )
        }
    }

    /// The background thread gives up one core (of several) and takes nice 19; its threads
    /// inherit both, the thread that started it keeps its own.
    #[cfg(target_os = "linux")]
    #[test]
    fn the_batch_thread_leaves_a_core() {
        let before = scheduling();
        let (own, child) = std::thread::spawn(|| {
            to_the_background();
            (scheduling(), std::thread::spawn(scheduling).join().unwrap())
        })
        .join()
        .unwrap();
        let expected = if before.0 > 1 && cores() > 1 {
            before.0 - 1
        } else {
            before.0
        };
        assert_eq!((own.0, own.1), (expected, 19));
        // A kernel that grants custom slices (6.12 and later) reports the one asked for.
        let slices = own.2 == BATCH_SLICE_NS;
        assert!(slices || before.2 == own.2, "{before:?} {own:?}");
        assert_eq!(child, own);
        assert_eq!(scheduling(), before);
    }
    use crate::reference::simulated::{drive_with_sentences, ReceiverSim};
    use crate::simulate::{default_truth, simulate_path, PathKind, SimSettings};

    /// The background batch's result is the calibration of the data handed to it (a second
    /// batch warm-started from the first: within 0.01 of the standard errors of the cold
    /// one), and its correction is its result minus its own sub-trajectory fit.
    #[test]
    fn agreement_in_standard_errors_and_relative() {
        let a = "x = 1.0\nx_se = 0.1\nn = 3\n[fit]\ny = 2.0\ns = \"a\"\n";
        let same = agreement(a, a).unwrap();
        assert!(same.identical && same.different.is_empty());
        assert_eq!((same.in_se.0, same.relative.0), (0.0, 0.0));
        let b = "x = 1.002\nx_se = 0.1\nn = 4\n[fit]\ny = 2.2\ns = \"a\"\nz = 1.0\n";
        let g = agreement(a, b).unwrap();
        assert!(!g.identical);
        assert!((g.in_se.0 - 0.02).abs() < 1e-9 && g.in_se.1 == "x", "{g:?}");
        assert!((g.relative.0 - 0.2 / 2.2).abs() < 1e-9 && g.relative.1 == "fit.y");
        let mut different = g.different;
        different.sort();
        assert_eq!(different, ["fit.z", "n"]);
    }

    /// The NMEA log (CR LF lines) of a simulated 20 m drive with a 10 Hz receiver (`seed`),
    /// and the reference options of a plain `calibrate`.
    fn simulated_log(seed: u64) -> (Vec<u8>, crate::reference::ReferenceOptions) {
        let settings = SimSettings {
            rate: 10.0,
            seed,
            ..Default::default()
        };
        let sim = simulate_path(PathKind::Estimation, 20.0, default_truth(), settings);
        let (_, sentences) = drive_with_sentences(sim, &ReceiverSim::default(), 18).unwrap();
        let log = sentences
            .iter()
            .flat_map(|(_, s)| format!("{s}\r\n").into_bytes())
            .collect();
        let args = ["odoctl", "calibrate", "--samples", "x.csv"].map(String::from);
        let o = reference_options(&parse_command_line(&args).unwrap().reference_input).unwrap();
        (log, o)
    }

    /// The log handed on in chunks cut anywhere (inside a line, inside a CR LF) reads as the
    /// whole log does, a line that is not UTF-8 among them.
    #[test]
    fn the_log_handed_on_in_pieces_reads_as_the_whole() {
        let (mut log, o) = simulated_log(3);
        let whole = |log: &[u8]| crate::reference::parse(LOG_NAME, log, &o).unwrap();
        for binary in [false, true] {
            if binary {
                let at = log.len() / 3;
                let at = at + log[at..].windows(2).position(|w| w == b"\r\n").unwrap() + 2;
                log.splice(at..at, b"\xb5\x62\x01\r\n".iter().copied());
            }
            let mut received = Received::new(None);
            let mut cut = 0;
            for (k, step) in [1, 7, 80, 81, 1000, 2, 3].iter().cycle().enumerate() {
                let end = (cut + step).min(log.len());
                received.take((Vec::new(), log[cut..end].to_vec()));
                cut = end;
                if k % 50 == 0 || cut == log.len() {
                    let so_far = crate::reference::parse_read(
                        LOG_NAME,
                        &received.nmea,
                        received.lines.clone(),
                        &o,
                    );
                    let want = crate::reference::parse(LOG_NAME, &log[..cut], &o);
                    assert_eq!(so_far.ok(), want.ok(), "{binary} at {cut}");
                }
                if cut == log.len() {
                    break;
                }
            }
            assert_eq!(received.read, log.len());
            let read = received.lines.clone();
            let got = crate::reference::parse_read(LOG_NAME, &received.nmea, read, &o).unwrap();
            assert_eq!(got, whole(&log));
        }
    }

    /// The thread's cancel flag ends a reading of the log (the batch's first step) with an
    /// error, and leaves other threads' readings alone.
    #[test]
    fn the_threads_flag_ends_the_logs_reading() {
        let (log, o) = simulated_log(4);
        let mut received = Received::new(None);
        received.take((Vec::new(), log.clone()));
        let read = || crate::reference::parse_read(LOG_NAME, &log, received.lines.clone(), &o);
        let flag = Arc::new(AtomicBool::new(true));
        cancel_this_thread_on(Some(Arc::clone(&flag)));
        let cancelled = read().unwrap_err().to_string();
        assert!(cancelled.contains("cancelled"), "{cancelled}");
        assert!(std::thread::scope(|s| s.spawn(read).join().unwrap()).is_ok());
        cancel_this_thread_on(None);
        assert_eq!(
            read().unwrap(),
            crate::reference::parse(LOG_NAME, &log, &o).unwrap()
        );
    }

    #[test]
    fn batch_is_the_calibration_of_what_it_was_given() {
        let settings = SimSettings {
            rate: 10.0,
            seed: 5,
            ..Default::default()
        };
        let sim = simulate_path(PathKind::Estimation, 40.0, default_truth(), settings);
        let receiver = ReceiverSim {
            heading_sigma: Some(0.5f64.to_radians()),
            ..Default::default()
        };
        let (samples, sentences) = drive_with_sentences(sim, &receiver, 18).unwrap();
        let log: String = sentences.iter().map(|(_, s)| format!("{s}\r\n")).collect();
        let args: Vec<String> = ["odoctl", "calibrate", "--quiet", "--samples", "x.csv"]
            .map(String::from)
            .to_vec();
        let mut worker = BatchWorker::start(args.clone()).unwrap();
        let half = samples.len() / 2;
        worker.feed(&samples[..half], &log.as_bytes()[..log.len() / 2]);
        worker.feed(&samples, log.as_bytes());
        let started = Instant::now();
        let got = loop {
            match worker.latest() {
                Some(b) if b.until == samples[samples.len() - 1].t => break b,
                _ if started.elapsed() > Duration::from_secs(120) => panic!("no batch"),
                _ => std::thread::sleep(Duration::from_millis(20)),
            }
        };
        let a = parse_command_line(&args).unwrap();
        let mut all = Received::new(None);
        all.take((samples.clone(), log.clone().into_bytes()));
        let (want, _) = batch(&a, &all, Extras::default()).unwrap();
        for i in 0..3 {
            let se = want.std_errors[i].unwrap();
            let near = |x: f64, y: f64| (x - y).abs() <= 0.01 * se;
            assert!(near(got.result[i], want.result[i]), "{got:?} {want:?}");
            assert!(near(got.subtrajectory[i], want.subtrajectory[i]));
            let got_se = got.std_errors[i].unwrap();
            assert!((got_se / se - 1.0).abs() < 0.01, "{got:?} {want:?}");
        }
        assert!(worker.warm_start().is_some());
        let c = got.correction();
        assert!((0..3).all(|i| c[i] == got.result[i] - got.subtrajectory[i]));
        assert!(
            got.subtrajectory != got.result,
            "the filter refined nothing"
        );
        worker.stop();
        // A batch whose flag is set ends with an error.
        let cancelled = AtomicBool::new(true);
        let extras = Extras {
            warm: None,
            cancel: Some(&cancelled),
        };
        assert!(batch(&a, &all, extras).is_err());
    }
}
