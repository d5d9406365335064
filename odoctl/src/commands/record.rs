//! `odoctl record`: the live pose stream to a SAMPLES CSV, the forwarded GNSS sentences to
//! the NMEA log beside it ([`recording`](super::recording)), and with `--mcap` ROS 2 topics.

use std::collections::VecDeque;
use std::path::Path;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use odo_unit::protocol::{Frame, Message, PoseRecord};

use super::recording::{nmea_path, NmeaWriter};
use crate::cli::RecordArgs;
use crate::link::{describe, health, open, SegmentWriter, Session, REPLY_TIMEOUT};

/// `odoctl record`: the recording, then its MCAP export when `--mcap` is given.
pub fn run(a: &RecordArgs) -> Result<ExitCode> {
    // A bad name is refused before recording.
    let names = crate::ros::names::RosNames::resolve(&a.ros.options("odoctl"))?;
    let code = record(
        &a.port.port,
        a.port.baud,
        &a.out,
        a.raw.as_deref(),
        a.duration,
        a.count,
        a.reset_pose,
    )?;
    if let Some(m) = &a.mcap {
        let params = (a.params.config.as_deref(), a.params.sets.as_slice());
        crate::ros::export::record_hook(m, &a.out, params, names)?;
    }
    Ok(code)
}

/// The sample rate in a `get rate` reply.
fn parse_rate(text: &str) -> Option<f64> {
    text.lines().find_map(|l| {
        l.trim()
            .strip_prefix("rate")
            .and_then(|r| r.trim().strip_prefix('='))
            .and_then(|v| v.trim().parse().ok())
    })
}

/// Records the live pose stream to `out` (and the raw bytes to `raw`) until `duration`,
/// `count` records or the end of the link; reports on stderr.
pub fn record(
    port: &str,
    baud: u32,
    out: &Path,
    raw: Option<&Path>,
    duration: Option<f64>,
    count: Option<u64>,
    reset_pose: bool,
) -> Result<ExitCode> {
    let mut s = Session::new(open(port, baud)?, raw)?;
    // The sample rate turns the GNSS time tag (second + sample index) into seconds.
    // Sentences that arrive while a command waits for its reply go to the log too.
    let mut early_gnss = Vec::new();
    let (ok, text) = s.command_with("get rate", REPLY_TIMEOUT, |f| {
        if let Message::Gnss(g) = &f.message {
            early_gnss.push(g.clone());
        }
    })?;
    let rate = if ok { parse_rate(&text) } else { None };
    let mut early = Vec::new();
    let mut started = !reset_pose;
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
    let is_start = |r: &PoseRecord| {
        r.x == 0.0
            && r.y == 0.0
            && r.heading == 0.0
            && r.sigma_x == 0.0
            && r.sigma_y == 0.0
            && r.sigma_heading == 0.0
    };
    let mut writer = SegmentWriter::new(Some(out), None, rate);
    let mut nmea = NmeaWriter::create(&nmea_path(out))?;
    for g in &early_gnss {
        nmea.push(g)?;
    }
    let end = duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let start_deadline = Instant::now() + REPLY_TIMEOUT;
    let mut queue: VecDeque<PoseRecord> = early.into();
    let mut received = 0u64;
    loop {
        let r = match queue.pop_front() {
            Some(r) => r,
            None => match s.next_frame(end)? {
                Some(Frame {
                    message: Message::Pose(r),
                    ..
                }) => r,
                Some(Frame {
                    message: Message::Gnss(g),
                    ..
                }) => {
                    nmea.push(&g)?;
                    continue;
                }
                Some(f) => {
                    if let Message::Status(st) = &f.message {
                        writer.on_status(st);
                    }
                    if let Some(d) = describe(&f) {
                        eprintln!("{d}");
                    }
                    continue;
                }
                None => break,
            },
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
        writer.push(&r)?;
        received += 1;
        if count.is_some_and(|c| received >= c) {
            break;
        }
    }
    s.finish()?;
    let recorded = writer.finish()?;
    let rows = recorded.rows();
    eprint!("recorded {}", recorded.report());
    eprintln!("{}", nmea.finish()?);
    eprintln!("link: {}", health(&s.decoder_stats(), &s.stats));
    if s.stats.record_gaps > 0 || s.stats.dropped_by_unit > 0 {
        eprintln!("warning: records are missing; a replay integrates across the gaps and will differ from the unit there");
    }
    if s.closed() && count.is_none_or(|c| received < c) {
        bail!(
            "the unit closed the connection after {received} pose records{}",
            if rows > 0 {
                " (those received are kept)"
            } else {
                ""
            }
        );
    }
    if rows == 0 {
        bail!("no pose record received");
    }
    Ok(ExitCode::SUCCESS)
}
