//! `odoctl record --calibrate`: the calibration drive with the answer on screen. The pose
//! records and the forwarded sentences feed the live sub-trajectory fit
//! ([`LiveCalibration`]) through the streaming NMEA reader ([`NmeaStream`]); once a second
//! the estimates, their standard errors, the distance and turning so far and what is still
//! missing against the targets are shown, and once the background batch calibration
//! ([`BatchWorker`]) has a result the refined estimate ([`refined`]) and that batch's kappa:
//! redrawn in place on a terminal, as log lines otherwise. The session keeps the rows and
//! the log as written for the final calibration ([`LiveSession::recorded`]).

use std::io::{IsTerminal, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use odo_unit::odometry::ChassisParams;

use super::calibrate::parse_command_line;
use super::live_batch::{BatchResult, BatchWorker};
use super::reference_options;
use crate::calib::live::{LiveCalibration, LiveEstimate, MIN_TURNING_DEG};
use crate::calib::{WarmStart, SUBTRAJECTORY_LENGTH};
use crate::cli::values::Targets;
use crate::csvio::Sample;
use crate::memory::{for_drive, DRIVE_LOG_BYTES_PER_S, DRIVE_SAMPLES_PER_S};
use crate::reference::nmea::LogLines;
use crate::reference::stream::NmeaStream;

/// Sub-trajectories before the hints project how much more driving the targets need.
pub const SETTLED: usize = 5;

/// How often the display is refreshed.
pub const REFRESH: Duration = Duration::from_secs(1);

/// What is still missing against the targets, one hint a line, and whether the data suffice.
pub fn advice(e: &LiveEstimate, t: &Targets) -> (Vec<String>, bool) {
    let mut out = Vec::new();
    if e.subtrajectories < 2 {
        out.push(format!(
            "drive on: the first estimate needs two sub-trajectories of {SUBTRAJECTORY_LENGTH} m ({} so far, {:.0} m driven)",
            e.subtrajectories, e.distance
        ));
        return (out, false);
    }
    let turned = e.turned_left + e.turned_right;
    let se_d = match (e.std_errors[0], e.std_errors[1]) {
        (Some(l), Some(r)) => l.max(r),
        _ => f64::INFINITY,
    };
    // Standard errors fall as one over the root of the distance (or of the turning); with a
    // few sub-trajectories they are too rough for a projection.
    let settled = e.subtrajectories >= SETTLED;
    let about = |what: String| {
        if settled {
            format!(" (about {what} more at this mix)")
        } else {
            format!(" (how much more shows after {SETTLED} sub-trajectories)")
        }
    };
    if se_d > t.diameter {
        let more = e.distance * ((se_d / t.diameter).powi(2) - 1.0);
        out.push(format!(
            "diameters: drive a longer straight{}",
            about(format!("{:.0} m", more.min(1e6)))
        ));
    }
    if !e.track_estimated {
        out.push(format!(
            "track width: turn (it needs {MIN_TURNING_DEG:.0} deg of turning in all, {:.0} so far)",
            turned.to_degrees()
        ));
    } else {
        let se_t = e.std_errors[2].unwrap_or(f64::INFINITY);
        if se_t > t.track {
            let more = turned.to_degrees() * ((se_t / t.track).powi(2) - 1.0);
            let way = if e.turned_left < 0.5 * e.turned_right {
                "turn left more"
            } else if e.turned_right < 0.5 * e.turned_left {
                "turn right more"
            } else {
                "turn more, both ways"
            };
            out.push(format!(
                "track width: {way}{}",
                about(format!("{:.0} deg of turning", more.min(1e7)))
            ));
        }
    }
    let enough = out.is_empty();
    if enough {
        out.push("the data suffice for the targets: stop when you like (Ctrl-C)".into());
    }
    (out, enough)
}

/// The display's lines for an estimate.
pub fn render(e: &LiveEstimate, t: &Targets) -> Vec<String> {
    let mm = |v: f64| v * 1e3;
    let se = |s: Option<f64>| s.map_or("-".to_string(), |s| format!("{:.4}", mm(s)));
    let mut lines = vec![
        format!(
            "live: {:.1} m driven, turned {:.0} deg left, {:.0} deg right; {} sub-trajectories, {} common times",
            e.distance,
            e.turned_left.to_degrees(),
            e.turned_right.to_degrees(),
            e.subtrajectories,
            e.matches
        ),
        format!(
            "  d_left {:.4} mm (se {}), d_right {:.4} mm (se {}), track {:.4} mm (se {}{}); targets {:.4} / {:.4} mm",
            mm(e.values[0]),
            se(e.std_errors[0]),
            mm(e.values[1]),
            se(e.std_errors[1]),
            mm(e.values[2]),
            se(e.std_errors[2]),
            if e.track_estimated { "" } else { ", held" },
            mm(t.diameter),
            mm(t.track)
        ),
    ];
    let (hints, _) = advice(e, t);
    lines.extend(hints.into_iter().map(|h| format!("  {h}")));
    lines
}

/// The live estimate refined: the live sub-trajectory fit plus what the batch calibration
/// `b` (of the drive up to `b.until`) adds to its own sub-trajectory fit, the filter
/// refinement's correction (m).
pub fn refined(e: &LiveEstimate, b: &BatchResult) -> [f64; 3] {
    let c = b.correction();
    [0, 1, 2].map(|i| e.values[i] + c[i])
}

/// The display's lines for the refined estimate ([`refined`]) and the batch's uncertainty
/// model, once a batch has succeeded; `last` is the time of the last sample (s).
pub fn render_refined(e: &LiveEstimate, b: Option<BatchResult>, last: f64) -> Vec<String> {
    let Some(b) = b else {
        return Vec::new();
    };
    let mm = |v: f64| v * 1e3;
    let v = refined(e, &b);
    let se = |s: Option<f64>| s.map_or("-".to_string(), |s| format!("{:.4}", mm(s)));
    vec![
        format!(
            "  refined: d_left {:.4} mm, d_right {:.4} mm, track {:.4} mm: the live fit + the filter refinement's correction from the batch calibration of the drive up to {:.0} s before its last sample (se {} / {} / {} mm, took {:.2} s)",
            mm(v[0]),
            mm(v[1]),
            mm(v[2]),
            last - b.until,
            se(b.std_errors[0]),
            se(b.std_errors[1]),
            se(b.std_errors[2]),
            b.took.as_secs_f64()
        ),
        format!(
            "  uncertainty (that batch): kappa_left {:.3e}, kappa_right {:.3e} m^2/m, kappa_diff {:.3e}",
            b.params.kappa_left, b.params.kappa_right, b.params.kappa_diff
        ),
    ]
}

/// The live calibration of one recording and its display.
pub struct LiveSession {
    live: LiveCalibration,
    stream: NmeaStream,
    targets: Targets,
    next: Instant,
    tty: bool,
    drawn: usize,
    /// The rows of the first SAMPLES file as the reader gives them back, and the NMEA log's
    /// bytes as written: the final calibration's input.
    recording: (Vec<Sample>, Vec<u8>),
    /// The NMEA log's lines read as they come (taken by the final calibration).
    log_lines: Option<LogLines>,
    batch: BatchWorker,
    /// Largest cost of one update so far.
    pub slowest_update: Duration,
}

impl LiveSession {
    /// A session from the initial estimate `initial`, against `targets`; `calibrate` is the
    /// `odoctl calibrate` command line of the final calibration, which the background batch
    /// runs along the drive; `log` the NMEA log's path.
    pub fn new(
        initial: &ChassisParams,
        targets: Targets,
        calibrate: Vec<String>,
        log: &Path,
    ) -> Result<Self> {
        let leap =
            reference_options(&parse_command_line(&calibrate)?.reference_input)?.leap_seconds;
        Ok(Self {
            log_lines: Some(LogLines::new(&log.display().to_string(), leap)),
            live: LiveCalibration::new(initial, SUBTRAJECTORY_LENGTH),
            stream: NmeaStream::new(),
            targets,
            next: Instant::now() + REFRESH,
            tty: std::io::stdout().is_terminal(),
            drawn: 0,
            recording: (
                for_drive(DRIVE_SAMPLES_PER_S),
                for_drive(DRIVE_LOG_BYTES_PER_S),
            ),
            batch: BatchWorker::start(calibrate)?,
            slowest_update: Duration::ZERO,
        })
    }

    /// A recorded sample (a row as read back), of the first SAMPLES file or not
    /// (`first_file`).
    pub fn on_sample(&mut self, s: Sample, first_file: bool) {
        self.live.push_sample(s);
        if first_file {
            self.recording.0.push(s);
        }
    }

    /// A forwarded sentence (checksum held, written to the log with CR LF), received at unit
    /// time `at` (s).
    pub fn on_sentence(&mut self, at: f64, text: &str) {
        self.stream.push(at, text);
        self.recording.1.extend_from_slice(text.as_bytes());
        self.recording.1.extend_from_slice(b"\r\n");
        if let Some(l) = &mut self.log_lines {
            l.line(text);
        }
    }

    /// Updates and shows the estimate when a second has passed.
    pub fn tick(&mut self) {
        if Instant::now() < self.next {
            return;
        }
        self.next = Instant::now() + REFRESH;
        self.update(false);
        self.show();
    }

    fn update(&mut self, end: bool) {
        let started = Instant::now();
        let Some(span) = self.live.time_span() else {
            return;
        };
        for p in self.stream.take(span, end) {
            self.live.push_reference(p);
        }
        if end {
            self.batch.stop();
            self.live.finish();
        } else {
            self.batch.feed(&self.recording.0, &self.recording.1);
            self.live.update();
        }
        self.slowest_update = self.slowest_update.max(started.elapsed());
    }

    /// Time of the last sample (s).
    fn last_t(&self) -> f64 {
        self.live.time_span().map_or(f64::NAN, |s| s.1)
    }

    /// The recording as the two files hold it, for the final calibration (once): the rows,
    /// the log's bytes and its lines as read; `None` without a row.
    pub fn take_recording(&mut self) -> Option<(Vec<Sample>, Vec<u8>, LogLines)> {
        let lines = self.log_lines.take()?;
        let (rows, log) = std::mem::take(&mut self.recording);
        (!rows.is_empty()).then_some((rows, log, lines))
    }

    /// Cancels the background batch (the drive ended): none starts after it, the one under
    /// way ends at its next check; does not wait for it ([`LiveSession::stop_batch`] does).
    pub fn cancel_batch(&mut self) {
        self.batch.cancel();
    }

    /// Stops the background batch: cancelled, its thread waited for.
    pub fn stop_batch(&mut self) {
        self.batch.stop();
    }

    /// Where the latest background batch left its searches: the final calibration's warm
    /// start.
    pub fn warm_start(&self) -> Option<WarmStart> {
        self.batch.warm_start()
    }

    fn show(&mut self) {
        let mut lines = render(&self.live.estimate(), &self.targets);
        lines.extend(render_refined(
            &self.live.estimate(),
            self.batch.latest(),
            self.last_t(),
        ));
        let mut out = std::io::stdout().lock();
        if self.tty && self.drawn > 0 {
            // Back to the first line drawn, and clear to the end of the screen.
            let _ = write!(out, "\x1b[{}F\x1b[J", self.drawn);
        }
        for l in &lines {
            let _ = writeln!(out, "{l}");
        }
        let _ = out.flush();
        self.drawn = if self.tty { lines.len() } else { 0 };
    }

    /// The drive ended: the last data taken in, the live estimate shown once more (kept on
    /// screen); its figures.
    pub fn finish(&mut self) -> LiveEstimate {
        self.update(true);
        self.drawn = 0;
        let e = self.live.estimate();
        crate::outln!("live estimate at the drive's end (the sub-trajectory fit):");
        for l in render(&e, &self.targets) {
            crate::outln!("{l}");
        }
        for l in render_refined(&e, self.batch.latest(), self.last_t()) {
            crate::outln!("{l}");
        }
        e
    }

    /// The live estimate with the latest background batch's refinement added
    /// ([`refined`]), and that batch.
    pub fn refined(&self) -> Option<([f64; 3], BatchResult)> {
        let b = self.batch.latest()?;
        Some((refined(&self.live.estimate(), &b), b))
    }

    /// Refuses to calibrate a drive without reference epochs.
    pub fn check(&self) -> Result<()> {
        let e = self.live.estimate();
        if e.reference_points == 0 {
            bail!(
                "no RTK-fixed GGA epoch arrived from the receiver: nothing to calibrate against \
                 (is the receiver on the unit's GNSS port, sending GGA with an RTK fix?)"
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(dist: f64, left_deg: f64, right_deg: f64, se: [Option<f64>; 3]) -> LiveEstimate {
        LiveEstimate {
            values: [0.25, 0.25, 0.57],
            std_errors: se,
            subtrajectories: (dist / 10.0) as usize,
            distance: dist,
            turned_left: left_deg.to_radians(),
            turned_right: right_deg.to_radians(),
            track_estimated: left_deg + right_deg >= MIN_TURNING_DEG,
            samples: 0,
            reference_points: 0,
            matches: 0,
            reference_out_of_order: 0,
        }
    }

    /// Boundary table of the hints: (distance, left, right, se d, se t) -> hint words.
    #[test]
    fn advice_table() {
        let t = Targets {
            diameter: 2e-5,
            track: 1e-4,
        };
        for (dist, l, r, sd, st, want, enough) in [
            (15.0, 0.0, 0.0, None, None, "drive on", false),
            (
                100.0,
                10.0,
                10.0,
                Some(1e-5),
                None,
                "it needs 30 deg",
                false,
            ),
            (
                100.0,
                20.0,
                200.0,
                Some(1e-5),
                Some(2e-4),
                "turn left more",
                false,
            ),
            (
                100.0,
                200.0,
                20.0,
                Some(1e-5),
                Some(2e-4),
                "turn right more",
                false,
            ),
            (
                100.0,
                200.0,
                200.0,
                Some(1e-5),
                Some(2e-4),
                "both ways",
                false,
            ),
            (
                100.0,
                200.0,
                200.0,
                Some(4e-5),
                Some(5e-5),
                "about 300 m more",
                false,
            ),
            (
                100.0,
                200.0,
                200.0,
                Some(2e-5),
                Some(1e-4),
                "data suffice",
                true,
            ),
        ] {
            let e = estimate(dist, l, r, [sd, sd, st]);
            let (hints, ok) = advice(&e, &t);
            assert_eq!(ok, enough, "{hints:?}");
            assert!(hints.iter().any(|h| h.contains(want)), "{want}: {hints:?}");
        }
    }
}
