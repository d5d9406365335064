//! `odoctl record`: the live pose stream to a SAMPLES CSV, the forwarded GNSS sentences to
//! the NMEA log beside it ([`recording`](super::recording)), and with `--mcap` ROS 2 topics.

use std::collections::VecDeque;
use std::path::Path;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use odo_unit::protocol::{Frame, GnssSentence, Message, PoseRecord};

use super::live::LiveSession;
use super::recording::{nmea_path, NmeaWriter, ReceiverWatch};
use crate::cli::values::DEFAULT_TARGETS;
use crate::cli::RecordArgs;
use crate::link::{describe, health, open, SegmentWriter, Session, REPLY_TIMEOUT};

/// `odoctl record`: the recording (with `--calibrate`, calibrated as it goes and at its end),
/// then its MCAP export when `--mcap` is given.
pub fn run(a: &RecordArgs) -> Result<ExitCode> {
    // A bad name is refused before recording.
    let names = crate::ros::names::RosNames::resolve(&a.ros.options("odoctl"))?;
    let mut live = if a.calibrate {
        let initial = crate::config::load(a.params.config.as_deref(), &a.params.sets)?;
        Some(LiveSession::new(
            &initial,
            a.target_se.unwrap_or(DEFAULT_TARGETS),
            calibrate_args(a, false),
            &nmea_path(&a.out),
        )?)
    } else {
        None
    };
    crate::interrupt::catch_ctrl_c();
    let stop = Stop {
        duration: a.duration,
        count: a.count,
    };
    let mut code = record(
        (&a.port.port, a.port.baud),
        &a.out,
        a.raw.as_deref(),
        stop,
        a.reset_pose,
        live.as_mut(),
    )?;
    if let Some(session) = &mut live {
        let calibrated = final_calibration(a, session)?;
        // The recording's own failure comes first.
        if code == ExitCode::SUCCESS {
            code = calibrated;
        }
    }
    if let Some(m) = &a.mcap {
        let params = (a.params.config.as_deref(), a.params.sets.as_slice());
        crate::ros::export::record_hook(m, &a.out, params, names)?;
    }
    Ok(code)
}

/// The batch calibration of the recording at the drive's end, printed at once and written
/// to `--result`: `odoctl calibrate --samples OUT` (the NMEA log beside it as the reference)
/// with `--config` as `--initial` and the `--set`s, run on the rows and sentences the
/// session kept as written to the two files (the files are not read again), its searches
/// started from the latest background batch's warm start. The background batch is cancelled
/// and, while it ends, the log's epochs are dated; once its thread has ended, the calibration
/// runs on a thread beside the live fit's last update; its report follows the live estimate.
fn final_calibration(a: &RecordArgs, session: &mut LiveSession) -> Result<ExitCode> {
    use super::calibrate::Recorded;
    use super::calibrate::{calibrate_inputs, parse_command_line, read_inputs, run_calibrated};
    let ended = Instant::now();
    let args = calibrate_args(a, true);
    let c = parse_command_line(&args)?;
    session.cancel_batch();
    let (rows, log, lines) = match session.take_recording() {
        Some((rows, log, lines)) => (rows, log, Some(lines)),
        None => (Vec::new(), Vec::new(), None),
    };
    let recorded = lines.map(|lines| Recorded {
        samples: &rows,
        nmea: &log,
        lines,
    });
    let read = read_inputs(&c, recorded);
    session.stop_batch();
    let warm = session.warm_start();
    let done = std::thread::scope(|scope| {
        let calibrating = scope.spawn(|| {
            read.map(|mut read| {
                read.start_from(warm);
                calibrate_inputs(&c, read)
            })
        });
        session.finish();
        calibrating.join()
    });
    session.check()?;
    crate::outln!(
        "final calibration (the batch one on the whole recording): {}",
        args[1..].join(" ")
    );
    let done = done.map_err(|_| anyhow::anyhow!("the final calibration panicked"))??;
    let code = run_calibrated(&c, done)?;
    crate::outln!(
        "final calibration printed {:.3} s after the drive's end (slowest live update {:.1} ms)",
        ended.elapsed().as_secs_f64(),
        session.slowest_update.as_secs_f64() * 1e3
    );
    Ok(code)
}

/// The `odoctl calibrate` command line of the final calibration: `--samples OUT` with
/// `--config` as `--initial`, the `--set`s and, with `result`, `--result` as `--out`.
fn calibrate_args(a: &RecordArgs, result: bool) -> Vec<String> {
    let mut args: Vec<String> = vec![
        "odoctl".into(),
        "calibrate".into(),
        "--quiet".into(),
        "--samples".into(),
        a.out.display().to_string(),
    ];
    if let Some(c) = &a.params.config {
        args.extend(["--initial".into(), c.display().to_string()]);
    }
    for s in &a.params.sets {
        args.extend(["--set".into(), s.clone()]);
    }
    if let (true, Some(r)) = (result, &a.result) {
        args.extend(["--out".into(), r.display().to_string()]);
    }
    args
}

/// When the recording ends (besides Ctrl-C and the end of the link).
#[derive(Debug, Clone, Copy)]
pub struct Stop {
    /// After this many seconds.
    pub duration: Option<f64>,
    /// After this many pose records.
    pub count: Option<u64>,
}

/// The sample rate in a `get rate` reply.
fn parse_rate(text: &str) -> Option<f64> {
    parse_value(text, "rate").and_then(|v| v.parse().ok())
}

/// The value of `key` in a `get` reply (`key = value` lines).
fn parse_value(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|l| {
        l.trim()
            .strip_prefix(key)
            .and_then(|r| r.trim().strip_prefix('='))
            .map(|v| v.trim().to_string())
    })
}

/// Records the live pose stream from `port` (name, baud) to `out`, the forwarded sentences to
/// the NMEA log beside it (and the raw bytes to `raw`) until `stop`, Ctrl-C or the end of the
/// link, feeding `live` when given; reports on stderr.
pub fn record(
    port: (&str, u32),
    out: &Path,
    raw: Option<&Path>,
    stop: Stop,
    reset_pose: bool,
    mut live: Option<&mut LiveSession>,
) -> Result<ExitCode> {
    let mut s = Session::new(open(port.0, port.1)?, raw)?;
    // Sentences that arrive while a command waits for its reply go to the log too.
    let mut early_gnss = Vec::new();
    // The sample rate turns the GNSS time tag (second + sample index) into seconds.
    let (ok, text) = s.command_with("get rate", REPLY_TIMEOUT, |f| {
        if let Message::Gnss(g) = &f.message {
            early_gnss.push(g.clone());
        }
    })?;
    let rate = if ok { parse_rate(&text) } else { None };
    // The drive is matched to the receiver's epochs by the records' GNSS time tags: in pps
    // mode the recording waits for them.
    let mut on_gnss_time = false;
    if live.is_some() {
        let (ok, text) = s.command_with("get mode", REPLY_TIMEOUT, |f| {
            if let Message::Gnss(g) = &f.message {
                early_gnss.push(g.clone());
            }
        })?;
        let mode = if ok { parse_value(&text, "mode") } else { None };
        on_gnss_time = mode.as_deref() == Some("pps");
        if let Some(m) = mode.filter(|m| m != "pps") {
            eprintln!("warning: the unit is in mode {m}: its records carry no GNSS time, so the receiver's epochs can be matched to them only if its clock is GNSS time (`odoctl config --port {} set mode pps`)", port.0);
        }
    }
    let mut early = Vec::new();
    if reset_pose {
        // The unit answers and applies the reset at its next sample, whose record carries
        // the reset pose with zero sigmas: the recording starts there.
        let (ok, text) = s.command_with("reset_pose", REPLY_TIMEOUT, |f| match &f.message {
            Message::Pose(r) => early.push(*r),
            Message::Gnss(g) => early_gnss.push(g.clone()),
            _ => {}
        })?;
        if !ok {
            bail!("reset_pose: {}", crate::text::excerpt_n(text.trim(), 80));
        }
    }
    let mut sink = Sink {
        writer: SegmentWriter::new(Some(out), None, rate),
        nmea: NmeaWriter::create(&nmea_path(out))?,
        watch: ReceiverWatch::default(),
        wait_for_time: on_gnss_time,
        live: live.as_deref_mut(),
        received: 0,
        before_time: 0,
    };
    for g in &early_gnss {
        sink.sentence(g)?;
    }
    let mut queue: VecDeque<PoseRecord> = early.into();
    stream(&mut s, &mut queue, &mut sink, stop, reset_pose)?;
    let Sink {
        writer,
        nmea,
        received,
        ..
    } = sink;
    s.finish()?;
    let recorded = writer.finish()?;
    let rows = recorded.rows();
    eprint!("recorded {}", recorded.report());
    eprintln!("{}", nmea.finish()?);
    eprintln!("link: {}", health(&s.decoder_stats(), &s.stats));
    if s.stats.record_gaps > 0 || s.stats.dropped_by_unit > 0 {
        eprintln!("warning: records are missing; a replay integrates across the gaps and will differ from the unit there");
    }
    if s.closed() && stop.count.is_none_or(|c| received < c) {
        let what = format!(
            "the unit closed the connection after {received} pose records{}",
            if rows > 0 {
                " (those received are kept)"
            } else {
                ""
            }
        );
        if live.is_none() || rows == 0 {
            bail!(what);
        }
        // With --calibrate, the end of the link ends the drive.
        eprintln!("{what}");
    }
    if rows == 0 {
        bail!("no pose record received");
    }
    Ok(ExitCode::SUCCESS)
}

/// Where the frames of a recording go: the SAMPLES CSV, the NMEA log, the receiver's watch,
/// the live calibration.
struct Sink<'a, 'b> {
    writer: SegmentWriter<'a>,
    nmea: NmeaWriter,
    watch: ReceiverWatch,
    live: Option<&'b mut LiveSession>,
    received: u64,
    /// Leave out the records before the first on GNSS time (`--calibrate`: the unit has not
    /// locked to the PPS yet).
    wait_for_time: bool,
    /// Records left out so.
    before_time: u64,
}

impl Sink<'_, '_> {
    fn record(&mut self, r: &PoseRecord) -> Result<()> {
        if self.wait_for_time && self.received == 0 && !r.flags.time_valid {
            if self.before_time == 0 {
                eprintln!("waiting for the unit's GNSS time (its lock to the receiver's PPS) before the first record");
            }
            self.before_time += 1;
            return Ok(());
        }
        if self.before_time > 0 && self.received == 0 {
            eprintln!(
                "GNSS time from record {}: the {} records before it are left out",
                r.sequence, self.before_time
            );
        }
        let before = self.writer.position();
        self.writer.push(r)?;
        self.received += 1;
        let (segment, rows) = self.writer.position();
        if (segment, rows) == before {
            // Left out (a duplicate): no row.
            return Ok(());
        }
        if let (Some(live), Some(row)) = (self.live.as_deref_mut(), self.writer.last_row()) {
            live.on_sample(row, segment == 1);
        }
        Ok(())
    }

    fn sentence(&mut self, g: &GnssSentence) -> Result<()> {
        if self.nmea.push(g)? {
            if let Some(note) = self.watch.sentence(g.mcu_time_us, &g.text, Instant::now()) {
                eprintln!("{note}");
            }
            if let Some(live) = self.live.as_deref_mut() {
                live.on_sentence(g.mcu_time_us as f64 * 1e-6, &g.text);
            }
        }
        Ok(())
    }

    /// Once per frame or tick: the receiver's silence, the live display.
    fn tick(&mut self) {
        if let Some(note) = self.watch.silence(Instant::now()) {
            eprintln!("{note}");
        }
        if let Some(live) = self.live.as_deref_mut() {
            live.tick();
        }
    }
}

/// The frames until `stop`, Ctrl-C or the end of the link: pose records (after the reset
/// pose's record with `reset_pose`) and sentences into `sink`.
fn stream(
    s: &mut Session,
    queue: &mut VecDeque<PoseRecord>,
    sink: &mut Sink,
    stop: Stop,
    reset_pose: bool,
) -> Result<()> {
    let is_start = |r: &PoseRecord| {
        r.x == 0.0
            && r.y == 0.0
            && r.heading == 0.0
            && r.sigma_x == 0.0
            && r.sigma_y == 0.0
            && r.sigma_heading == 0.0
    };
    let mut started = !reset_pose;
    let end = stop
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d));
    let start_deadline = Instant::now() + REPLY_TIMEOUT;
    while !crate::interrupt::interrupted() {
        sink.tick();
        let r = match queue.pop_front() {
            Some(r) => r,
            None => {
                // Wake at least every TICK for the display and Ctrl-C.
                let wake = Instant::now() + TICK;
                let deadline = Some(end.map_or(wake, |e| e.min(wake)));
                match s.next_frame(deadline)? {
                    Some(Frame {
                        message: Message::Pose(r),
                        ..
                    }) => r,
                    Some(Frame {
                        message: Message::Gnss(g),
                        ..
                    }) => {
                        sink.sentence(&g)?;
                        continue;
                    }
                    Some(f) => {
                        if let Message::Status(st) = &f.message {
                            sink.writer.on_status(st);
                        }
                        if let Some(d) = describe(&f) {
                            eprintln!("{d}");
                        }
                        continue;
                    }
                    None if s.closed() || end.is_some_and(|e| Instant::now() >= e) => break,
                    None => continue,
                }
            }
        };
        if !started {
            if is_start(&r) {
                started = true;
            } else if Instant::now() > start_deadline {
                bail!(
                    "reset_pose: no record with the reset pose and zero sigmas within {} s",
                    REPLY_TIMEOUT.as_secs()
                );
            } else {
                continue;
            }
        }
        sink.record(&r)?;
        if stop.count.is_some_and(|c| sink.received >= c) {
            break;
        }
    }
    Ok(())
}

/// Longest wait for a frame before the display and Ctrl-C are looked at.
const TICK: Duration = Duration::from_millis(200);
