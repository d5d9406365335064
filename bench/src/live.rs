//! Live calibration (`odoctl record --calibrate`), as Markdown for docs/RESULTS.md
//! (`bench/run`): `odo-bench live DIR`. Figures only: nothing here fails on noise.
//!
//! A simulated 3 km random drive at 50 Hz with a 10 Hz receiver (GGA, GST, HDT, RMC, ZDA as
//! `simulate --nmea` writes them) is fed as `record --calibrate` feeds it, one second of drive
//! every [`PACE`] of wall time: one update per second of drive, the second's rows (as the
//! reader gives them back from the CSV) and sentences through the streaming NMEA reader and
//! the live sub-trajectory fit, and handed to the background batch calibration
//! ([`BatchWorker`], on its own thread beside the updates). Measured: the cost of each
//! update; at the drive's end, as `record` does it, the live fit's last update and beside it
//! the final batch calibration in this process on the rows and the log in memory from the
//! latest background batch's warm start (`calibrate::read_inputs`, `calibrate_inputs`), then
//! its report (`calibrate::run_calibrated`, sent to DIR/final.txt), from the last data to the
//! result printed and written, and for comparison the same final from the initial estimate
//! (no warm start) after the drive; that result against the release `odoctl calibrate --samples
//! live.csv` on the files (`$ODOCTL` or the `odoctl` beside this binary; from the initial
//! estimate), in the standard errors ([`agreement`]); the live estimate
//! and the refined one (the live fit + the latest background batch's refinement) against
//! the batch calibration's sub-trajectory fit and its default (filter-refined) result, in
//! their standard errors.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use odo_unit::odometry::ChassisParams;
use odoctl::calib::live::LiveCalibration;
use odoctl::calib::{fit_subtrajectories, Run, SubtrajectoryOptions, SUBTRAJECTORY_LENGTH};
use odoctl::commands::calibrate::{
    calibrate_inputs, parse_command_line, read_inputs, run_calibrated, run_read, Recorded,
};
use odoctl::commands::live::refined;
use odoctl::commands::live_batch::{agreement, Agreement, BatchResult, BatchWorker};
use odoctl::commands::recording::nmea_path;
use odoctl::csvio::{self, Sample, SamplesLayout};
use odoctl::memory::{for_drive, DRIVE_LOG_BYTES_PER_S, DRIVE_SAMPLES_PER_S};
use odoctl::reference::nmea::LogLines;
use odoctl::reference::simulated::{drive_with_sentences, ReceiverSim};
use odoctl::reference::stream::NmeaStream;
use odoctl::simulate::{default_truth, simulate_path, PathKind, SimSettings};

use crate::cpu_time::{machine_ticks, stolen_share, thread_cpu, thread_run_delay};
use crate::markdown::{number, thousands};
use crate::odoctl_binary::odoctl;
use crate::stdout_capture::stdout_to;

/// Length of the drive (m).
const LENGTH: f64 = 3000.0;

/// Wall time of one second of drive: the drive is replayed 200 times as fast as driven (the
/// background batch falls about 200 times as far behind, in drive seconds, as on a real
/// drive) but for its last [`REAL_TIME_END`] seconds.
const PACE: Duration = Duration::from_millis(5);

/// Seconds at the drive's end replayed at the pace driven: the background batch catches up
/// to where it is at the end of a real drive.
const REAL_TIME_END: usize = 10;

/// Runs the drive in `dir` and prints the section.
pub fn run(dir: &Path) {
    std::fs::create_dir_all(dir).expect("the bench directory");
    let (samples, sentences) = drive();
    let csv = dir.join("live.csv");
    let mut w = std::io::BufWriter::new(std::fs::File::create(&csv).expect("live.csv"));
    csvio::write_samples(&mut w, &samples, SamplesLayout::Counts).expect("live.csv");
    drop(w);
    let log: String = sentences.iter().map(|(_, s)| format!("{s}\r\n")).collect();
    std::fs::write(dir.join("live.nmea"), log).expect("live.nmea");
    let result = dir.join("live.toml");
    let args = calibrate_args(&csv, &result);
    let rows: Vec<Sample> = samples
        .iter()
        .map(|s| SamplesLayout::Counts.read_back(s, None))
        .collect();
    let mut fed = feed(&rows, &sentences, &args);
    let mut end = drive_end(&mut fed, &args, &dir.join("final.txt"));
    end.cold = cold_final(&fed, &sentences, &csv, dir);
    let files = dir.join("live_files.toml");
    let started = Instant::now();
    let o = Command::new(odoctl())
        .args(&args[1..args.len() - 1])
        .arg(&files)
        .output()
        .expect("odoctl runs");
    let process = started.elapsed();
    assert!(
        o.status.success(),
        "odoctl calibrate: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = |p: &Path| std::fs::read_to_string(p).expect("a result file");
    let g = agreement(&text(&result), &text(&files)).expect("result files");
    print_section(&samples, &fed, &end, (process, g));
    print_agreement(&fed.live, &end, &csv, &result);
}

/// `odoctl calibrate --quiet --samples CSV --out RESULT`, as `record --calibrate` builds it.
fn calibrate_args(csv: &Path, result: &Path) -> Vec<String> {
    ["odoctl", "calibrate", "--quiet", "--samples"]
        .map(String::from)
        .into_iter()
        .chain([
            csv.display().to_string(),
            "--out".into(),
            result.display().to_string(),
        ])
        .collect()
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

/// One update's cost.
struct Cost {
    /// Reference path driven then (m).
    distance: f64,
    /// Wall time of the whole update and of the fit alone.
    whole: Duration,
    fit: Duration,
    /// The updating thread's CPU time in the whole update, and its wait for a core.
    cpu: Duration,
    waited: Option<Duration>,
}

/// What the drive's feed leaves: the cost of each update, the live fit, the streaming
/// reader, the background batch, the rows and the log handed on, the log's lines read as
/// they came.
struct Fed {
    costs: Vec<Cost>,
    /// The share of the machine's CPU time stolen by the hypervisor during the drive.
    stolen: Option<f64>,
    live: LiveCalibration,
    stream: NmeaStream,
    batch: BatchWorker,
    rows: Vec<Sample>,
    log: Vec<u8>,
    lines: Option<LogLines>,
}

/// One update per second of drive (its rows and sentences), one every [`PACE`], the
/// background batch (`args`, the final's command line) running beside.
fn feed(rows: &[Sample], sentences: &[(usize, String)], args: &[String]) -> Fed {
    let mut f = Fed {
        costs: Vec::new(),
        stolen: None,
        live: LiveCalibration::new(&ChassisParams::DESIGNED, SUBTRAJECTORY_LENGTH),
        stream: NmeaStream::new(),
        batch: BatchWorker::start(args.to_vec()).expect("the background batch"),
        rows: for_drive(DRIVE_SAMPLES_PER_S),
        log: for_drive(DRIVE_LOG_BYTES_PER_S),
        lines: Some(LogLines::new(
            &nmea_path(Path::new(&args[4])).display().to_string(),
            None,
        )),
    };
    let per_second = 50;
    let mut next = 0;
    let seconds = rows.len().div_ceil(per_second);
    let mut due = Instant::now();
    let ticks = machine_ticks();
    for (c, chunk) in rows.chunks(per_second).enumerate() {
        due += if c + REAL_TIME_END >= seconds {
            Duration::from_secs(1)
        } else {
            PACE
        };
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let last = c * per_second + chunk.len() - 1;
        let delay = thread_run_delay();
        let (started, cpu) = (Instant::now(), thread_cpu());
        for s in chunk {
            f.live.push_sample(*s);
            f.rows.push(*s);
        }
        while next < sentences.len() && sentences[next].0 <= last {
            let (k, text) = &sentences[next];
            f.stream.push(rows[*k].t, text);
            f.log.extend_from_slice(text.as_bytes());
            f.log.extend_from_slice(b"\r\n");
            if let Some(l) = &mut f.lines {
                l.line(text);
            }
            next += 1;
        }
        let span = (rows[0].t, chunk[chunk.len() - 1].t);
        for p in f.stream.take(span, false) {
            f.live.push_reference(p);
        }
        f.batch.feed(&f.rows, &f.log);
        let fit = Instant::now();
        f.live.update();
        let (whole, fit, cpu) = (started.elapsed(), fit.elapsed(), thread_cpu() - cpu);
        f.costs.push(Cost {
            distance: f.live.estimate().distance,
            whole,
            fit,
            cpu,
            waited: delay.zip(thread_run_delay()).map(|(a, b)| b - a),
        });
    }
    f.stolen = stolen_share(ticks, machine_ticks());
    f
}

/// The drive's end as `record --calibrate` meets it: the times from the last data to the
/// live fit's last update and to the final calibration printed and written; the refined
/// live estimate then, with its batch.
struct End {
    /// From the drive's end to the background batch's thread ended.
    batch_stopped: Duration,
    last_update: Duration,
    final_printed: Duration,
    refined: Option<([f64; 3], BatchResult)>,
    last_t: f64,
    /// The same final calibration in process from the initial estimate, after the drive.
    cold: Duration,
}

/// The final calibration of `f`'s rows and log in process, as at the drive's end but from
/// the initial estimate (no warm start) and after it (nothing beside it; the log's lines
/// read again from `sentences` beforehand), written to DIR/live_cold.toml: the time from the
/// dating of the epochs to the result printed and written.
fn cold_final(f: &Fed, sentences: &[(usize, String)], csv: &Path, dir: &Path) -> Duration {
    let args = calibrate_args(csv, &dir.join("live_cold.toml"));
    let c = parse_command_line(&args).expect("a calibrate command line");
    let mut lines = LogLines::new(&nmea_path(csv).display().to_string(), None);
    for (_, text) in sentences {
        lines.line(text);
    }
    let started = Instant::now();
    let recorded = Recorded {
        samples: &f.rows,
        nmea: &f.log,
        lines,
    };
    let read = read_inputs(&c, Some(recorded)).expect("the recording's inputs");
    stdout_to(&dir.join("cold.txt"), || run_read(&c, read)).expect("the cold final");
    started.elapsed()
}

/// The drive's end of `f`, as `record` meets it: the background batch cancelled, the log's
/// epochs dated while it ends, then (its thread ended) the live fit's last update and, on a
/// thread beside it, the final calibration `args` in this process on the rows and the log
/// in memory from the latest background batch's warm start; then its report printed (sent to
/// `report`) and its result written.
fn drive_end(f: &mut Fed, args: &[String], report: &Path) -> End {
    let ended = Instant::now();
    let last_t = f.rows[f.rows.len() - 1].t;
    let c = parse_command_line(args).expect("a calibrate command line");
    let Fed {
        live,
        stream,
        batch,
        rows,
        log,
        lines,
        ..
    } = f;
    batch.cancel();
    let recorded = Recorded {
        samples: rows,
        nmea: log,
        lines: lines.take().expect("the log's lines"),
    };
    let read = read_inputs(&c, Some(recorded));
    batch.stop();
    let batch_stopped = ended.elapsed();
    let warm = batch.warm_start();
    let (done, last_update) = std::thread::scope(|scope| {
        let calibrating = scope.spawn(|| {
            read.map(|mut read| {
                read.start_from(warm);
                calibrate_inputs(&c, read)
            })
        });
        for p in stream.take((rows[0].t, last_t), true) {
            live.push_reference(p);
        }
        live.finish();
        let last_update = ended.elapsed();
        (calibrating.join().expect("the final's thread"), last_update)
    });
    let refined = batch.latest().map(|b| (refined(&live.estimate(), &b), b));
    let done = done.expect("the recording's inputs");
    stdout_to(report, || run_calibrated(&c, done)).expect("the final calibration");
    End {
        batch_stopped,
        last_update,
        final_printed: ended.elapsed(),
        refined,
        last_t,
        cold: Duration::ZERO,
    }
}

/// The cost table by tenth of the drive and the end-to-final figures; `process` the time
/// of `odoctl calibrate` on the files and how far its result file is from the final's.
fn print_section(samples: &[Sample], f: &Fed, end: &End, process: (Duration, Agreement)) {
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
        "feeds them, one second of drive every {} ms of wall time (the drive replayed {:.0} times",
        PACE.as_millis(),
        1.0 / PACE.as_secs_f64()
    );
    println!(
        "as fast as driven): one update per second of drive through the streaming NMEA reader and"
    );
    println!(
        "the live sub-trajectory fit, from the designed geometry, the rows and the log handed to"
    );
    println!(
        "the background batch calibration, which runs the final's calibration again and again on"
    );
    println!(
        "its own thread (nice 19, off one core, a 0.1 ms time slice) beside the updates, each run"
    );
    println!(
        "from where the one before left its searches; at the drive's end the run under way is"
    );
    println!("cancelled at its next check and its thread waited for (docs/CALIBRATION.md).");
    println!();
    print_costs(&f.costs);
    println!(
        "An update: the second's samples and sentences taken in (each sentence also read by the"
    );
    println!(
        "log's reader for the final calibration, `LogLines`), the sentences of the last 3 s read"
    );
    println!(
        "(the streaming NMEA reader), the new rows and sentences handed to the background batch,"
    );
    println!("then the fit's update (`LiveCalibration::update`: matching, a sub-trajectory");
    println!("closed about every 20 s, relinearisations, the estimate and its jackknife when they");
    println!("changed). An update's wall time is the updating thread's own CPU time");
    println!("(`CLOCK_THREAD_CPUTIME_ID`) and its wait for a core, runnable on a run queue while");
    println!("others ran (/proc/thread-self/schedstat): the background batch, the machine's other");
    match f.stolen {
        Some(share) => {
            println!(
                "processes and kernel threads; the hypervisor took {:.2} % of the machine's CPU",
                share * 100.0
            );
            println!("time during the drive (steal in /proc/stat).");
        }
        None => println!("processes and kernel threads."),
    }
    println!();
    print_end(end, process);
}

/// The update costs by tenth of the drive.
fn print_costs(costs: &[Cost]) {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!("| part of the drive | updates | median update | 99 % of updates within | slowest update | its CPU time | its wait for a core | most CPU time of an update | median of the fit alone | slowest of the fit alone |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    let n = costs.len();
    let at = |v: &[f64], q: f64| number(v[((v.len() - 1) as f64 * q).round() as usize]);
    let sorted = |part: &[Cost], of: fn(&Cost) -> Duration| {
        let mut v: Vec<f64> = part.iter().map(|c| ms(of(c))).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    for tenth in 0..10 {
        let part = &costs[tenth * n / 10..(tenth + 1) * n / 10];
        let (whole, cpu, fit) = (
            sorted(part, |c| c.whole),
            sorted(part, |c| c.cpu),
            sorted(part, |c| c.fit),
        );
        let Some(slowest) = part.iter().max_by_key(|c| c.whole) else {
            continue;
        };
        println!(
            "| {:.0} .. {:.0} m | {} | {} ms | {} ms | {} ms | {} ms | {} | {} ms | {} ms | {} ms |",
            part[0].distance,
            part[part.len() - 1].distance,
            part.len(),
            at(&whole, 0.5),
            at(&whole, 0.99),
            number(ms(slowest.whole)),
            number(ms(slowest.cpu)),
            slowest
                .waited
                .map_or("-".into(), |w| format!("{} ms", number(ms(w)))),
            at(&cpu, 1.0),
            at(&fit, 0.5),
            at(&fit, 1.0)
        );
    }
    println!();
}

/// The drive's end: the background batch so far, the times to the final calibration, the
/// final's result against `odoctl calibrate`'s on the files.
fn print_end(end: &End, (process, g): (Duration, Agreement)) {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    if let Some((_, b)) = &end.refined {
        println!(
            "The background batch calibration: {} batches done along the drive ({} failed, too",
            b.done, b.failed
        );
        println!(
            "little data yet), the last on the drive up to {:.0} s before its end, which took {} ms.",
            end.last_t - b.until,
            number(ms(b.took))
        );
        println!();
    }
    println!("| at the drive's end (from the last sample and sentence taken in) | wall time |");
    println!("| --- | ---: |");
    println!(
        "| the background batch stopped (cancelled, the log's epochs dated while the run under way ends at its next check, its thread ended) | {} ms |",
        number(ms(end.batch_stopped))
    );
    println!(
        "| the live fit's last update (relinearised to the end, after the batch stopped) | {} ms |",
        number(ms(end.last_update))
    );
    println!(
        "| the final calibration printed and written (`calibrate` in process, on the rows and log in memory, from the latest background batch's warm start, beside the live fit's last update) | {} ms |",
        number(ms(end.final_printed))
    );
    println!(
        "| for comparison: the same in process from the initial estimate (no warm start; after the drive, nothing beside it; the epochs' dating included) | {} ms |",
        number(ms(end.cold))
    );
    println!(
        "| for comparison: `odoctl calibrate --samples live.csv` on the files (a separate process) | {} ms |",
        number(ms(process))
    );
    println!();
    print_agreement_with_files(&g);
}

/// The final's result file against the cold `odoctl calibrate`'s on the files.
fn print_agreement_with_files(g: &Agreement) {
    if g.identical {
        println!(
            "The in-process result file and the one of `odoctl calibrate` on the files are identical."
        );
        println!();
        return;
    }
    println!(
        "The final calibration's searches start where the latest background batch left them (the"
    );
    println!(
        "warm start); `odoctl calibrate` on the files starts from the initial estimate. Its result"
    );
    println!(
        "file against the final's: the largest difference of a value with a standard error {} of",
        number(g.in_se.0)
    );
    println!(
        "that standard error (`{}`), of any other number {} relative (`{}`){}.",
        g.in_se.1,
        number(g.relative.0),
        g.relative.1,
        if g.different.is_empty() {
            String::new()
        } else {
            format!("; keys that differ otherwise: {}", g.different.join(", "))
        }
    );
    println!();
}

/// The live estimate and the refined one against the batch's sub-trajectory fit and its
/// default result.
fn print_agreement(live: &LiveCalibration, end: &End, csv: &Path, result: &Path) {
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
        "The live estimate after the last update ({} sub-trajectories, {:.0} m) and the refined one",
        e.subtrajectories, e.distance
    );
    println!(
        "(the live fit + the filter refinement's correction of the latest background batch) against"
    );
    println!("the batch calibration of the same recording, in the batch's standard errors (SE):");
    println!();
    println!("| unknown | live | batch sub-trajectory fit (SE) | live - batch | default result, filter-refined (SE) | live - default | refined | refined - default |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for i in 0..3 {
        let se = sub.std_errors[i].unwrap_or(f64::NAN);
        let (v, d_se) = (key(names[i]), key(&format!("{}_se", names[i])));
        let r = end.refined.as_ref().map_or(f64::NAN, |r| r.0[i]);
        println!(
            "| {} | {:.7} m | {:.7} m ({}) | {} SE | {:.7} m ({}) | {} SE | {:.7} m | {} SE |",
            names[i],
            e.values[i],
            sub_values[i],
            number(se),
            number((e.values[i] - sub_values[i]) / se),
            v,
            number(d_se),
            number((e.values[i] - v) / d_se),
            r,
            number((r - v) / d_se)
        );
    }
    println!();
}
