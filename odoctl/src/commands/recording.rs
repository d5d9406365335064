//! One recording: `record` writes the forwarded GNSS sentences (message 0x05) as an NMEA log
//! beside the SAMPLES CSV (`run.csv` -> `run.nmea`, [`nmea_path`]), and `calibrate` /
//! `validate` take that log as the reference when `--reference` is not given
//! ([`reference_for`]), refusing a pair whose times disagree ([`check_recording_times`]).
//!
//! The NMEA log holds each sentence as received, `$` through the checksum digits, and CR LF:
//! what RTKLIB, any NMEA tool and `odoctl reference` read.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use odo_unit::protocol::GnssSentence;

use crate::csvio::{RefPoint, Sample};

/// Largest difference (s) between the first (or last) reference epoch and the first (or
/// last) sample of a recording at which the two still agree in time: a receiver's epoch
/// interval at 1 Hz plus its output latency. A recording whose start and end both differ
/// by more, in the same direction, has its two clocks apart.
pub const RECORDING_TIME_TOLERANCE: f64 = 2.0;

/// The NMEA log of a recording beside its SAMPLES CSV: `run.csv` -> `run.nmea`.
pub fn nmea_path(samples: &Path) -> PathBuf {
    samples.with_extension("nmea")
}

/// The sentences of a recording and their counts.
pub struct NmeaWriter {
    w: BufWriter<File>,
    path: PathBuf,
    /// Sentences written.
    pub written: u64,
    /// Sentences the unit received but did not forward (jumps of `number`).
    pub not_forwarded: u64,
    /// Sentences whose checksum does not hold (not written).
    pub bad_checksum: u64,
    /// Sentences written, by kind (`GGA`, `GST`...).
    pub kinds: std::collections::BTreeMap<String, u64>,
    next_number: Option<u32>,
}

impl NmeaWriter {
    /// A new log at `path`.
    pub fn create(path: &Path) -> Result<Self> {
        let f = File::create(path).with_context(|| format!("{}: cannot create", path.display()))?;
        Ok(Self {
            w: BufWriter::new(f),
            path: path.to_path_buf(),
            written: 0,
            not_forwarded: 0,
            bad_checksum: 0,
            kinds: Default::default(),
            next_number: None,
        })
    }

    /// One forwarded sentence: counted, and written with CR LF when its checksum holds
    /// (then true).
    pub fn push(&mut self, g: &GnssSentence) -> Result<bool> {
        if let Some(n) = self.next_number {
            self.not_forwarded += u64::from(g.number.wrapping_sub(n));
        }
        self.next_number = Some(g.number.wrapping_add(1));
        if !checksum_holds(&g.text) {
            self.bad_checksum += 1;
            return Ok(false);
        }
        write!(self.w, "{}\r\n", g.text)?;
        self.written += 1;
        *self.kinds.entry(kind(&g.text).to_string()).or_default() += 1;
        Ok(true)
    }

    /// Flushes; the report line. A log without any sentence is removed (a unit without a
    /// receiver, or one that does not forward), so that `calibrate` asks for `--reference`.
    pub fn finish(mut self) -> Result<String> {
        self.w
            .flush()
            .with_context(|| format!("{}: cannot write", self.path.display()))?;
        if self.written == 0 {
            drop(self.w);
            let _ = std::fs::remove_file(&self.path);
            return Ok(format!(
                "GNSS sentences: none forwarded ({} not forwarded, {} with a bad checksum); no {} written",
                self.not_forwarded,
                self.bad_checksum,
                self.path.display()
            ));
        }
        let kinds: Vec<String> = self.kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
        Ok(format!(
            "GNSS sentences: {} written to {}{}; {} not forwarded by the unit (gaps in their numbers), {} with a bad checksum (left out)",
            self.written,
            self.path.display(),
            if kinds.is_empty() {
                String::new()
            } else {
                format!(" ({})", kinds.join(", "))
            },
            self.not_forwarded,
            self.bad_checksum
        ))
    }
}

/// How long the receiver may send no GGA before `record` says so.
pub const SILENCE: Duration = Duration::from_secs(3);

/// GGA intervals in a row that make a new rate.
const RATE_CHANGE_RUN: u32 = 3;

/// The receiver's GGA as `record` sees them: a silence longer than [`SILENCE`] and a change
/// of its rate (an interval 25 % off the established one [`RATE_CHANGE_RUN`] times in a row),
/// each reported once, as they happen.
#[derive(Debug, Default)]
pub struct ReceiverWatch {
    /// Unit time (us) and wall time of the last GGA.
    last: Option<(u64, Instant)>,
    /// The established GGA interval (s).
    interval: Option<f64>,
    /// A different interval (s) and how often in a row it came.
    candidate: Option<(f64, u32)>,
    silent: bool,
}

impl ReceiverWatch {
    /// A forwarded sentence received at unit time `mcu_us`, wall time `now`: a line to show
    /// when it ends a silence or establishes a new rate.
    pub fn sentence(&mut self, mcu_us: u64, text: &str, now: Instant) -> Option<String> {
        if kind(text) != "GGA" {
            return None;
        }
        let mut note = None;
        if let Some((t0, w0)) = self.last {
            let dt = mcu_us.saturating_sub(t0) as f64 * 1e-6;
            let similar = |a: f64, b: f64| (a / b - 1.0).abs() <= 0.25;
            if self.silent {
                self.silent = false;
                note = Some(format!(
                    "the receiver sends GGA again, after {:.1} s",
                    now.duration_since(w0).as_secs_f64()
                ));
            } else if dt > 0.0 {
                match (self.interval, self.candidate) {
                    (Some(i), _) if similar(dt, i) => self.candidate = None,
                    (_, Some((c, n))) if similar(dt, c) => {
                        if n + 1 >= RATE_CHANGE_RUN {
                            if let Some(i) = self.interval {
                                note = Some(format!(
                                    "warning: the receiver's GGA rate changed from {:.2} Hz to {:.2} Hz",
                                    1.0 / i,
                                    1.0 / c
                                ));
                            }
                            self.interval = Some(c);
                            self.candidate = None;
                        } else {
                            self.candidate = Some((c, n + 1));
                        }
                    }
                    _ => self.candidate = Some((dt, 1)),
                }
            }
        }
        self.last = Some((mcu_us, now));
        note
    }

    /// A warning once the receiver has sent no GGA for [`SILENCE`] (once per silence).
    pub fn silence(&mut self, now: Instant) -> Option<String> {
        let (_, w0) = self.last?;
        if self.silent || now.duration_since(w0) < SILENCE {
            return None;
        }
        self.silent = true;
        Some(format!(
            "warning: the receiver has sent no GGA for {} s (is it still connected and powered?)",
            SILENCE.as_secs()
        ))
    }
}

/// True when `text` is `$BODY*hh` with `hh` the XOR of BODY's bytes (hex, either case).
pub fn checksum_holds(text: &str) -> bool {
    let Some(body) = text.strip_prefix('$') else {
        return false;
    };
    let Some((body, sum)) = body.rsplit_once('*') else {
        return false;
    };
    sum.len() == 2
        && u8::from_str_radix(sum, 16).is_ok_and(|s| s == body.bytes().fold(0u8, |a, b| a ^ b))
}

/// The sentence kind: `GGA` of `$GNGGA,...`, the whole address of a proprietary sentence.
fn kind(text: &str) -> &str {
    let address = text[1..].split([',', '*']).next().unwrap_or("");
    if address.len() == 5 && !address.starts_with('P') {
        &address[2..]
    } else {
        address
    }
}

/// The reference of `calibrate` / `validate`: `--reference` when given; else the
/// recording's NMEA log beside `samples` ([`nmea_path`]) when it exists, said on stdout
/// ([`say_own_reference`]); else an error naming both. The flag says the reference is the
/// recording's own.
pub fn reference_for(samples: &Path, reference: Option<&Path>) -> Result<(PathBuf, bool)> {
    let found = resolve_reference(samples, reference)?;
    if found.1 {
        say_own_reference(&found.0, samples);
    }
    Ok(found)
}

/// [`reference_for`] with nothing said.
pub fn resolve_reference(samples: &Path, reference: Option<&Path>) -> Result<(PathBuf, bool)> {
    if let Some(r) = reference {
        return Ok((r.to_path_buf(), false));
    }
    let own = nmea_path(samples);
    if own.is_file() {
        return Ok((own, true));
    }
    bail!(
        "no reference: give --reference FILE, or record with `odoctl record`, which writes the receiver's sentences to {} beside {}",
        own.display(),
        samples.display()
    )
}

/// The line on stdout saying that the reference is `log`, the recording's own beside
/// `samples`.
pub fn say_own_reference(log: &Path, samples: &Path) {
    crate::outln!(
        "reference: {} (the recording's NMEA log beside {})",
        log.display(),
        samples.display()
    );
}

/// Refuses a recording whose reference epochs (on the samples' time base) and samples
/// disagree in time: no common span, or the first and the last epoch both more than
/// [`RECORDING_TIME_TOLERANCE`] from the first and the last sample in the same direction
/// (the two clocks apart: a receiver's time in a different scale, or records with MCU time
/// only). The message gives both spans.
pub fn check_recording_times(samples: &[Sample], reference: &[RefPoint]) -> Result<()> {
    let (Some(s0), Some(s1), Some(r0), Some(r1)) = (
        samples.first(),
        samples.last(),
        reference.first(),
        reference.last(),
    ) else {
        return Ok(());
    };
    let (d0, d1) = (r0.t - s0.t, r1.t - s1.t);
    let overlap = r0.t <= s1.t && r1.t >= s0.t;
    let shifted = d0.abs() > RECORDING_TIME_TOLERANCE
        && d1.abs() > RECORDING_TIME_TOLERANCE
        && d0.signum() == d1.signum();
    if !overlap || shifted {
        bail!(
            "the recording's sentences and records disagree in time: reference epochs t = {:.3} .. {:.3} s, \
             samples t = {:.3} .. {:.3} s (start {:+.3} s, end {:+.3} s apart; at most {} s allowed): \
             the records' GNSS time tags and the receiver's UTC times are not on one clock",
            r0.t,
            r1.t,
            s0.t,
            s1.t,
            d0,
            d1,
            RECORDING_TIME_TOLERANCE
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::nmea::with_checksum;

    fn sample(t: f64) -> Sample {
        Sample {
            t,
            ..Default::default()
        }
    }

    fn point(t: f64) -> RefPoint {
        RefPoint {
            t,
            x: 0.0,
            y: 0.0,
            heading: None,
            sigma_h: None,
        }
    }

    #[test]
    fn checksums_and_kinds() {
        let s = with_checksum("GPGGA,1,2");
        assert!(checksum_holds(&s));
        assert!(checksum_holds(
            &s.to_lowercase().replacen("$gpgga", "$GPGGA", 1)
        ));
        assert!(!checksum_holds(&s.replace('1', "3")));
        assert!(!checksum_holds("GPGGA,1*00"));
        assert!(!checksum_holds("$GPGGA,1*0"));
        assert_eq!(kind(&s), "GGA");
        assert_eq!(kind("$PUBX,00*33"), "PUBX");
    }

    #[test]
    fn receiver_watch_reports_silence_and_rate_changes() {
        let gga = with_checksum("GNGGA,120000.00,4912.0,N");
        let t0 = Instant::now();
        let mut w = ReceiverWatch::default();
        let mut notes = Vec::new();
        // 10 Hz, one GGA lost (no change), then 5 Hz.
        let mut us = 0u64;
        for step in [100_000u64; 5]
            .into_iter()
            .chain([200_000])
            .chain([100_000; 3])
            .chain([200_000; 4])
        {
            us += step;
            notes.extend(w.sentence(us, &gga, t0));
            assert_eq!(w.sentence(us, "$GNGST,1*00", t0), None);
        }
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("from 10.00 Hz to 5.00 Hz"), "{notes:?}");
        assert_eq!(w.silence(t0 + Duration::from_millis(2900)), None);
        assert!(w.silence(t0 + SILENCE).unwrap().contains("no GGA for 3 s"));
        assert_eq!(w.silence(t0 + 2 * SILENCE), None);
        let back = w.sentence(us + 5_000_000, &gga, t0 + Duration::from_secs(5));
        assert!(back.unwrap().contains("again, after 5.0 s"));
    }

    /// Boundary table of the time check: (reference span, samples span, refused).
    #[test]
    fn recording_time_check_table() {
        for ((r0, r1), (s0, s1), refused) in [
            ((10.0, 100.0), (10.0, 100.0), false),
            ((11.9, 101.9), (10.0, 100.0), false),
            ((12.1, 102.1), (10.0, 100.0), true),
            ((7.9, 97.9), (10.0, 100.0), true),
            // A late start of the fixes alone is no clock offset.
            ((40.0, 100.0), (10.0, 100.0), false),
            ((10.0, 60.0), (10.0, 100.0), false),
            ((200.0, 300.0), (10.0, 100.0), true),
        ] {
            let r = check_recording_times(&[sample(s0), sample(s1)], &[point(r0), point(r1)]);
            assert_eq!(r.is_err(), refused, "{r0}..{r1} vs {s0}..{s1}: {r:?}");
            if let Err(e) = r {
                let m = e.to_string();
                assert!(m.contains(&format!("{r0:.3} .. {r1:.3}")), "{m}");
                assert!(m.contains(&format!("{s0:.3} .. {s1:.3}")), "{m}");
            }
        }
    }
}
