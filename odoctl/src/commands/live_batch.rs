//! `record --calibrate`'s batch calibration in the background: a thread of the lowest
//! priority (nice 19 on Linux, so that the recording, the live updates and the final
//! calibration come first) runs the batch calibration of the drive's end (`odoctl calibrate`
//! with the same command line, [`calibration`]) again and again, each time on every row and
//! sentence handed to it by its start, and keeps the latest result. Nothing it does is
//! printed; a batch that fails (too little data yet) is counted and the next one tried.

use std::borrow::Cow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Result;
use odo_unit::odometry::ChassisParams;

use super::calibrate::{calibration, parse_command_line, Inputs};
use super::reference_options;
use crate::csvio::Sample;

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

/// The background batch calibration (module documentation).
pub struct BatchWorker {
    tx: Option<Sender<Chunk>>,
    latest: Arc<Mutex<Option<BatchResult>>>,
    /// Set at the drive's end: no batch starts after it.
    stopped: Arc<AtomicBool>,
    /// Rows and log bytes handed on so far.
    sent: (usize, usize),
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
        std::thread::Builder::new()
            .name("batch calibration".into())
            .spawn(move || work(&args, &rx, &slot, &stop))?;
        Ok(Self {
            tx: Some(tx),
            latest,
            stopped,
            sent: (0, 0),
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
        *self.latest.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// No batch starts after this (the one running ends on its own, at its low priority).
    pub fn stop(&mut self) {
        self.stopped.store(true, Ordering::Relaxed);
        self.tx = None;
    }
}

impl Drop for BatchWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The thread: waits for data, takes in all that has come, calibrates, keeps the result;
/// ends when `stopped` is set or the sender is gone.
fn work(
    args: &[String],
    rx: &Receiver<Chunk>,
    slot: &Mutex<Option<BatchResult>>,
    stopped: &AtomicBool,
) {
    lowest_priority();
    let Ok(a) = parse_command_line(args) else {
        return;
    };
    let (mut samples, mut nmea) = (Vec::new(), Vec::new());
    let (mut done, mut failed) = (0, 0);
    while let Ok(first) = rx.recv() {
        for (s, b) in std::iter::once(first).chain(rx.try_iter()) {
            samples.extend(s);
            nmea.extend(b);
        }
        if stopped.load(Ordering::Relaxed) {
            return;
        }
        let started = Instant::now();
        match batch(&a, &samples, &nmea) {
            Ok(mut r) => {
                done += 1;
                r.took = started.elapsed();
                (r.done, r.failed) = (done, failed);
                *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
            }
            Err(_) => failed += 1,
        }
    }
}

/// One batch calibration of `samples` against the NMEA log `nmea`, as `a` asks.
fn batch(a: &crate::cli::CalibrateArgs, samples: &[Sample], nmea: &[u8]) -> Result<BatchResult> {
    let until = samples.last().map_or(f64::NAN, |s| s.t);
    let source = crate::reference::parse("live", nmea, &reference_options(&a.reference_input)?)?;
    let inputs = Inputs::of(&source, Cow::Borrowed(samples))?;
    let names = ("samples".to_string(), "live".to_string());
    let (c, _, _) = calibration(a, &inputs, &names)?;
    let geometry = |p: &ChassisParams| [p.left_diameter, p.right_diameter, p.track_width];
    Ok(BatchResult {
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
    })
}

/// Lowers the calling thread (and the threads it starts) to nice 19 on Linux, where the
/// nice value is a thread's; elsewhere nothing.
fn lowest_priority() {
    #[cfg(target_os = "linux")]
    {
        // Note(unsafe): gettid and setpriority take no pointers and change only this
        // thread's scheduling weight; a failure leaves the priority as it was.
        #[allow(unsafe_code)]
        unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, 19);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::simulated::{drive_with_sentences, ReceiverSim};
    use crate::simulate::{default_truth, simulate_path, PathKind, SimSettings};

    /// The background batch's result is the calibration of the data handed to it, and its
    /// correction is its result minus its own sub-trajectory fit.
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
        let want = batch(&a, &samples, log.as_bytes()).unwrap();
        assert_eq!(got.result, want.result);
        assert_eq!(got.subtrajectory, want.subtrajectory);
        assert_eq!(got.std_errors, want.std_errors);
        let c = got.correction();
        assert!((0..3).all(|i| c[i] == got.result[i] - got.subtrajectory[i]));
        assert!(
            got.subtrajectory != got.result,
            "the filter refined nothing"
        );
        worker.stop();
    }
}
