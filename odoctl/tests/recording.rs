//! One recording: `record` against a fake unit that forwards the receiver's sentences
//! (message 0x05) beside its pose records writes the NMEA log next to the SAMPLES CSV, counts
//! what the unit did not forward and bad checksums; `calibrate` and `validate` take the
//! recording alone; a recording whose two clocks disagree is refused; `record --calibrate`
//! shows the live estimate as log lines and ends with the batch calibration.

mod common;

use std::path::Path;
use std::time::Duration;

use common::{odoctl, scratch};
use odo_unit::protocol::GnssSentence;
use odoctl::commands::live_batch::agreement;
use odoctl::csvio::{self, Sample, SamplesLayout};
use odoctl::reference::simulated::{drive_with_sentences, ReceiverSim};
use odoctl::simulate::{self, default_truth, PathKind, SimSettings};

/// A drive at `rate` Hz with its receiver's sentences at 10 Hz: the samples (t as a unit
/// without GNSS time tags writes it: its MCU time, here the GPS time of week), and each
/// epoch's sentences with the sample after which the unit receives them.
fn drive(length: f64, rate: f64, leap: i32) -> (Vec<Sample>, Vec<(usize, String)>) {
    let settings = SimSettings {
        rate,
        seed: 7,
        ..Default::default()
    };
    let sim = simulate::simulate_path(PathKind::Estimation, length, default_truth(), settings);
    let receiver = ReceiverSim {
        heading_sigma: Some(0.5f64.to_radians()),
        float_fraction: 0.0,
        ..Default::default()
    };
    let (samples, mut sentences) = drive_with_sentences(sim, &receiver, leap).unwrap();
    // `record --count` ends at the last record: the sentences after it are never read.
    sentences.retain(|(k, _)| k + 1 < samples.len());
    (samples, sentences)
}

/// The frames of `sentences`, numbered from 0 with the numbers in `skipped` left out (not
/// forwarded), the one at `corrupt` with a wrong checksum digit.
fn frames(
    sentences: &[(usize, String)],
    skipped: &[u32],
    corrupt: Option<usize>,
) -> Vec<(usize, GnssSentence)> {
    let mut out = Vec::new();
    let mut number = 0u32;
    for (i, (k, text)) in sentences.iter().enumerate() {
        while skipped.contains(&number) {
            number += 1;
        }
        let mut text = text.clone();
        if corrupt == Some(i) {
            let last = if text.ends_with('0') { "1" } else { "0" };
            text.replace_range(text.len() - 1.., last);
        }
        out.push((*k, sentence(0, number, &text)));
        number += 1;
    }
    out
}

/// A GnssSentence message, through its documented body layout.
fn sentence(mcu_time_us: u64, number: u32, text: &str) -> GnssSentence {
    let mut body = Vec::new();
    body.extend_from_slice(&mcu_time_us.to_le_bytes());
    body.extend_from_slice(&number.to_le_bytes());
    body.push(text.len() as u8);
    body.extend_from_slice(&[0; 3]);
    body.extend_from_slice(text.as_bytes());
    GnssSentence::read_body(&body).unwrap()
}

/// `odoctl record` against a fake unit sending `samples` and `gnss`, with `extra` options.
fn record(
    samples: Vec<Sample>,
    gnss: Vec<(usize, GnssSentence)>,
    out: &Path,
    extra: &[&str],
) -> std::process::Output {
    let n = samples.len().to_string();
    let (port, unit) = common::fake_unit_with_gnss(samples, Duration::from_micros(500), gnss);
    let port = format!("tcp:127.0.0.1:{port}");
    let mut args = vec![
        "record",
        "--port",
        &port,
        "--out",
        out.to_str().unwrap(),
        "--count",
        &n,
    ];
    args.extend_from_slice(extra);
    let o = odoctl(&args);
    unit.join().unwrap();
    o
}

#[test]
fn record_writes_the_nmea_log_and_calibrate_takes_the_recording() {
    let d = scratch("recording_one_file");
    let (samples, sentences) = drive(40.0, 10.0, 18);
    let skipped = [5, 6, 7, 40];
    let corrupt = 100;
    let gnss = frames(&sentences, &skipped, Some(corrupt));
    let out = d.join("run.csv");
    let o = record(samples, gnss, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // The log holds every sentence with a valid checksum, as sent, each with CR LF.
    let expected: String = sentences
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != corrupt)
        .map(|(_, (_, t))| format!("{t}\r\n"))
        .collect();
    let log = std::fs::read_to_string(d.join("run.nmea")).unwrap();
    assert!(
        log == expected,
        "the NMEA log differs from the sentences sent"
    );
    assert!(
        err.contains(&format!(
            "GNSS sentences: {} written to",
            sentences.len() - 1
        )),
        "{err}"
    );
    assert!(
        err.contains("4 not forwarded by the unit (gaps in their numbers), 1 with a bad checksum"),
        "{err}"
    );
    // The recording alone calibrates and validates.
    let result = d.join("chassis.toml");
    let o = odoctl(&[
        "calibrate",
        "--samples",
        out.to_str().unwrap(),
        "--quiet",
        "--out",
        result.to_str().unwrap(),
    ]);
    let stdout = common::success_stdout(&o);
    assert!(
        stdout.contains("(the recording's NMEA log beside"),
        "{stdout}"
    );
    let o = odoctl(&[
        "validate",
        "--samples",
        out.to_str().unwrap(),
        "--config",
        result.to_str().unwrap(),
    ]);
    let stdout = common::success_stdout(&o);
    assert!(stdout.contains("run.nmea"), "{stdout}");
}

#[test]
fn calibrate_without_a_reference_names_both_options() {
    let d = scratch("recording_no_reference");
    let (samples, _) = drive(25.0, 10.0, 18);
    let out = d.join("alone.csv");
    let mut w = std::fs::File::create(&out).unwrap();
    csvio::write_samples(&mut w, &samples, SamplesLayout::Counts).unwrap();
    let o = odoctl(&["calibrate", "--samples", out.to_str().unwrap()]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--reference") && err.contains("alone.nmea") && err.contains("odoctl record"),
        "{err}"
    );
}

#[test]
fn a_recording_whose_clocks_disagree_is_refused_with_both_spans() {
    let d = scratch("recording_time_disagree");
    // The receiver's UTC written with 5 leap seconds too many: its epochs read 5 s early.
    let (samples, sentences) = drive(40.0, 10.0, 23);
    let out = d.join("run.csv");
    let mut w = std::fs::File::create(&out).unwrap();
    csvio::write_samples(&mut w, &samples, SamplesLayout::Counts).unwrap();
    let log: String = sentences.iter().map(|(_, t)| format!("{t}\r\n")).collect();
    std::fs::write(d.join("run.nmea"), log).unwrap();
    for cmd in ["calibrate", "validate"] {
        let o = odoctl(&[cmd, "--samples", out.to_str().unwrap()]);
        assert!(!o.status.success(), "{cmd}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("disagree in time"), "{cmd}: {err}");
        let s0 = format!("{:.3} ..", samples[0].t);
        let r0 = format!("{:.3} ..", samples[0].t - 5.0);
        assert!(err.contains(&s0) && err.contains(&r0), "{cmd}: {err}");
        assert!(err.contains("start -5.000 s"), "{cmd}: {err}");
    }
}

#[test]
fn record_calibrate_shows_log_lines_and_ends_with_the_batch_result() {
    let d = scratch("recording_live");
    let (samples, sentences) = drive(60.0, 10.0, 18);
    let gnss = frames(&sentences, &[], None);
    let out = d.join("run.csv");
    let result = d.join("chassis.toml");
    let o = record(
        samples,
        gnss,
        &out,
        &[
            "--calibrate",
            "--target-se",
            "0.02mm,0.1mm",
            "--result",
            result.to_str().unwrap(),
        ],
    );
    let stdout = common::success_stdout(&o);
    // Not a terminal: plain lines, no escape sequences.
    assert!(!stdout.contains('\u{1b}'), "{stdout}");
    assert!(stdout.contains("live: "), "{stdout}");
    let end = stdout
        .find("live estimate at the drive's end")
        .expect("the live estimate at the end");
    let tail = &stdout[end..];
    assert!(
        tail.contains("d_left ") && tail.contains("track "),
        "{tail}"
    );
    assert!(tail.contains("final calibration (the batch one"), "{tail}");
    assert!(
        tail.contains(&format!("wrote {}", result.display())),
        "{tail}"
    );
    assert!(tail.contains("final calibration printed"), "{tail}");
    let toml = std::fs::read_to_string(&result).unwrap();
    assert!(toml.contains("left_diameter"), "{toml}");
    // The final calibration, run on the rows and sentences kept in memory from the latest
    // background batch's warm start, prints and writes what `calibrate` on the two recorded
    // files does: the same keys and lines, every value with a standard error within 0.01 of
    // it and every other number within 1 % (identical when no batch had finished).
    let from_files = d.join("from_files.toml");
    let o = odoctl(&[
        "calibrate",
        "--quiet",
        "--samples",
        out.to_str().unwrap(),
        "--out",
        from_files.to_str().unwrap(),
    ]);
    let files_stdout = common::success_stdout(&o);
    let files_toml = std::fs::read_to_string(&from_files).unwrap();
    let g = agreement(&toml, &files_toml).unwrap();
    assert!(g.different.is_empty(), "{g:?}");
    assert!(g.in_se.0 <= 0.01 && g.relative.0 <= 0.01, "{g:?}");
    // Numbers aside: the digits masked.
    let report = |text: &str| -> Vec<String> {
        text.lines()
            .filter(|l| !l.starts_with("done in ") && !l.starts_with("wrote "))
            .map(|l| l.replace(|c: char| c.is_ascii_digit(), "#"))
            .collect()
    };
    let header = tail.find("final calibration (the batch one").unwrap();
    let from = header + tail[header..].find('\n').unwrap() + 1;
    let printed = &tail[from..tail.find("final calibration printed").unwrap()];
    assert_eq!(report(printed), report(&files_stdout));
}
