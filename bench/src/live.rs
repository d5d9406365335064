//! Live calibration (`odoctl record --calibrate`), as Markdown for docs/RESULTS.md
//! (`bench/run`): `odo-bench live DIR`. Figures only: nothing here fails on noise.
//!
//! A simulated 3 km random drive at 50 Hz with a 10 Hz receiver (GGA, GST, HDT, RMC, ZDA as
//! `simulate --nmea` writes them) is fed as `record --calibrate` feeds it: one update per
//! second of drive, the second's samples and sentences, through the streaming NMEA reader
//! and the live sub-trajectory fit. Measured: the cost of each update along the drive; at the
//! drive's end the live fit's last update and the batch calibration as `record` runs it
//! (the release `odoctl calibrate --samples run.csv`, `$ODOCTL` or the `odoctl` beside this
//! binary, the recording's NMEA log as the reference); the live estimate against the batch's
//! sub-trajectory fit and its default (filter-refined) result, in their standard errors.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use odo_unit::odometry::ChassisParams;
use odoctl::calib::live::LiveCalibration;
use odoctl::calib::{fit_subtrajectories, Run, SubtrajectoryOptions, SUBTRAJECTORY_LENGTH};
use odoctl::csvio::{self, Sample, SamplesLayout};
use odoctl::reference::simulated::{drive_with_sentences, ReceiverSim};
use odoctl::reference::stream::NmeaStream;
use odoctl::simulate::{default_truth, simulate_path, PathKind, SimSettings};

use crate::markdown::{number, thousands};
use crate::odoctl_binary::odoctl;

/// Length of the drive (m).
const LENGTH: f64 = 3000.0;

/// Runs the drive in `dir` and prints the section.
pub fn run(dir: &Path) {
    std::fs::create_dir_all(dir).expect("the bench directory");
    let (samples, sentences) = drive();
    let (costs, live, finish) = feed(&samples, &sentences);
    let csv = dir.join("live.csv");
    let mut w = std::io::BufWriter::new(std::fs::File::create(&csv).expect("live.csv"));
    csvio::write_samples(&mut w, &samples, SamplesLayout::Counts).expect("live.csv");
    drop(w);
    let log: String = sentences.iter().map(|(_, s)| format!("{s}\r\n")).collect();
    std::fs::write(dir.join("live.nmea"), log).expect("live.nmea");
    let result = dir.join("live.toml");
    let started = Instant::now();
    let o = Command::new(odoctl())
        .args(["calibrate", "--quiet", "--samples"])
        .arg(&csv)
        .arg("--out")
        .arg(&result)
        .output()
        .expect("odoctl runs");
    let batch_time = started.elapsed();
    assert!(
        o.status.success(),
        "odoctl calibrate: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    print_section(&samples, &costs, finish, batch_time);
    print_agreement(&live, &csv, &result);
}

/// The drive: samples (t GPS time of week) and the receiver's sentences, each with the
/// sample after which it arrives.
fn drive() -> (Vec<Sample>, Vec<(usize, String)>) {
    let settings = SimSettings {
        seed: 1,
        ..Default::default()
    };
    let sim = simulate_path(PathKind::Random, LENGTH, default_truth(), settings);
    let receiver = ReceiverSim {
        heading_sigma: Some(0.5f64.to_radians()),
        ..Default::default()
    };
    drive_with_sentences(sim, &receiver, 18).expect("NMEA in memory")
}

/// One update per second of drive (its samples and sentences); the cost of each (with the
/// distance driven then), the live fit, and the cost of its last update at the end.
fn feed(
    samples: &[Sample],
    sentences: &[(usize, String)],
) -> (Vec<(f64, Duration, Duration)>, LiveCalibration, Duration) {
    let mut live = LiveCalibration::new(&ChassisParams::DESIGNED, SUBTRAJECTORY_LENGTH);
    let mut stream = NmeaStream::new();
    let per_second = 50;
    let mut next = 0;
    let mut costs = Vec::new();
    for (c, chunk) in samples.chunks(per_second).enumerate() {
        let last = c * per_second + chunk.len() - 1;
        let started = Instant::now();
        for s in chunk {
            live.push_sample(*s);
        }
        while next < sentences.len() && sentences[next].0 <= last {
            stream.push(samples[sentences[next].0].t, &sentences[next].1);
            next += 1;
        }
        let span = (samples[0].t, chunk[chunk.len() - 1].t);
        for p in stream.take(span, false) {
            live.push_reference(p);
        }
        let fit = Instant::now();
        live.update();
        costs.push((live.estimate().distance, started.elapsed(), fit.elapsed()));
    }
    let started = Instant::now();
    let span = (samples[0].t, samples[samples.len() - 1].t);
    for p in stream.take(span, true) {
        live.push_reference(p);
    }
    live.finish();
    (costs, live, started.elapsed())
}

/// The cost table by tenth of the drive and the end-to-final figures.
fn print_section(
    samples: &[Sample],
    costs: &[(f64, Duration, Duration)],
    finish: Duration,
    batch: Duration,
) {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "Harness: `cargo run --release --target x86_64-unknown-linux-gnu -p odo-bench -- live DIR`"
    );
    println!(
        "(bench/src/live.rs): a simulated {LENGTH:.0} m random drive, {} samples at 50 Hz, with a",
        thousands(samples.len() as u64)
    );
    println!(
        "10 Hz receiver's GGA, GST, HDT, RMC (and ZDA once a second), fed as `record --calibrate`"
    );
    println!(
        "feeds them: one update per second of drive through the streaming NMEA reader and the"
    );
    println!("live sub-trajectory fit; from the designed geometry. Then the batch calibration as");
    println!(
        "`record --calibrate` runs it at the drive's end: the release `odoctl calibrate --samples"
    );
    println!("live.csv` with the NMEA log beside it (the CSV read, the default calibration, the");
    println!("report and the result file).");
    println!();
    println!("| part of the drive | updates | median update | 99 % of updates within | slowest update | median of the fit alone | slowest of the fit alone |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: |");
    let n = costs.len();
    let at = |v: &[f64], q: f64| number(v[((v.len() - 1) as f64 * q).round() as usize]);
    for tenth in 0..10 {
        let part = &costs[tenth * n / 10..(tenth + 1) * n / 10];
        let mut whole: Vec<f64> = part.iter().map(|c| ms(c.1)).collect();
        let mut fit: Vec<f64> = part.iter().map(|c| ms(c.2)).collect();
        whole.sort_by(f64::total_cmp);
        fit.sort_by(f64::total_cmp);
        let (from, to) = (
            part.first().map_or(0.0, |c| c.0),
            part.last().map_or(0.0, |c| c.0),
        );
        println!(
            "| {from:.0} .. {to:.0} m | {} | {} ms | {} ms | {} ms | {} ms | {} ms |",
            part.len(),
            at(&whole, 0.5),
            at(&whole, 0.99),
            at(&whole, 1.0),
            at(&fit, 0.5),
            at(&fit, 1.0)
        );
    }
    println!();
    println!(
        "An update: the second's samples and sentences taken in, the sentences of the last 3 s"
    );
    println!("read (the streaming NMEA reader), then the fit's update (`LiveCalibration::update`:");
    println!(
        "matching, a sub-trajectory closed about every 20 s, relinearisations, the estimate and"
    );
    println!(
        "its jackknife when they changed). The machine is shared (other builds run beside the"
    );
    println!("benchmark): the slowest updates are the operating system's as much as the code's.");
    println!();
    println!("| at the drive's end | wall time |");
    println!("| --- | ---: |");
    println!(
        "| the live fit's last update (relinearised to the end) | {} ms |",
        number(ms(finish))
    );
    println!(
        "| the batch calibration printed (`odoctl calibrate`, a separate process) | {} ms |",
        number(ms(batch))
    );
    println!(
        "| drive's end to the final calibration printed | {} ms |",
        number(ms(finish + batch))
    );
    println!();
}

/// The live estimate against the batch's sub-trajectory fit and its default result.
fn print_agreement(live: &LiveCalibration, csv: &Path, result: &Path) {
    let samples = csvio::read_samples(csv).expect("live.csv");
    let source = odoctl::reference::load(
        &csv.with_extension("nmea"),
        &odoctl::reference::ReferenceOptions::default(),
    )
    .expect("live.nmea");
    let (reference, _) = source.points_for(&samples).expect("the reference");
    let run = Run::new(
        &samples,
        &reference,
        csvio::match_times(&samples, &reference),
    );
    let sub = fit_subtrajectories(
        &run,
        &ChassisParams::DESIGNED,
        SubtrajectoryOptions::default(),
    )
    .expect("the sub-trajectory fit");
    let text = std::fs::read_to_string(result).expect("live.toml");
    let table: toml::Table = text.parse().expect("live.toml parses");
    let key = |k: &str| table.get(k).and_then(|v| v.as_float()).expect(k);
    let e = live.estimate();
    let names = ["left_diameter", "right_diameter", "track_width"];
    let sub_values = [
        sub.params.left_diameter,
        sub.params.right_diameter,
        sub.params.track_width,
    ];
    println!(
        "The live estimate after the last update ({} sub-trajectories, {:.0} m) against the batch",
        e.subtrajectories, e.distance
    );
    println!("calibration of the same recording, in the batch's standard errors (SE):");
    println!();
    println!("| unknown | live | batch sub-trajectory fit (SE) | live - batch | default result, filter-refined (SE) | live - default |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: |");
    for i in 0..3 {
        let se = sub.std_errors[i].unwrap_or(f64::NAN);
        let (v, d_se) = (key(names[i]), key(&format!("{}_se", names[i])));
        println!(
            "| {} | {:.7} m | {:.7} m ({}) | {} SE | {:.7} m ({}) | {} SE |",
            names[i],
            e.values[i],
            sub_values[i],
            number(se),
            number((e.values[i] - sub_values[i]) / se),
            v,
            number(d_se),
            number((e.values[i] - v) / d_se)
        );
    }
    println!();
}
