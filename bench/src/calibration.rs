//! The calibration on the host, as Markdown tables for docs/RESULTS.md (`bench/run`):
//! `odoctl`'s fits in-process on runs made by its own simulator, exactly as `odoctl simulate`
//! makes them with its defaults (50 Hz, 0.5 m/s, slip 0.1 % over 0.1 m, RTK noise 8 mm),
//! every fit from the paper's poor first estimate 0.300/0.300/0.700 m. Figures only: nothing
//! here fails on noise.
//!
//! - `odo-bench calibrate accuracy`: errors to the truth of the geometry methods on 70 m,
//!   300 m, 1 km and 3 km logs over several seeds ([`LOGS`]; `BENCH_SEEDS` sets one seed
//!   count for every log, `BENCH_LOGS`, e.g. `70 m,300 m`, limits the logs).
//! - `odo-bench calibrate speed`: wall times, medians of `BENCH_REPS` (default 5) runs, of
//!   `BENCH_REPS_LONG` (default 3) on 3 km: the eq (16) fit, the sub-trajectory fit, the whole
//!   calibration by both methods, the stability study and the `--wheel-harmonics` fit, and the
//!   uncertainty coefficients the timed calibrations fitted.
//! - `odo-bench calibrate`: both.

use std::time::Instant;

use indicatif::ProgressBar;
use odo_unit::odometry::{ChassisParams, UncertaintyModel};
use odoctl::calib::{
    self, CalibrationOptions, Cuts, GeomOptions, GeometryRefine, Method, Run, WindowStart,
};
use odoctl::csvio::match_times;
use odoctl::simulate::{self, default_truth, PathKind, SimRun, SimSettings};

use crate::markdown::thousands;

/// The logs of the accuracy table: path, length (m), name (`BENCH_LOGS`), label, seeds by
/// default. The 70 m estimation path takes more seeds: one run's track-width error there is
/// of the order of its target.
const LOGS: [(PathKind, f64, &str, &str, u64); 4] = [
    (
        PathKind::Estimation,
        70.0,
        "70 m",
        "70 m estimation path",
        50,
    ),
    (PathKind::Random, 300.0, "300 m", "300 m random path", 5),
    (PathKind::Random, 1000.0, "1 km", "1 km random path", 5),
    (PathKind::Random, 3000.0, "3 km", "3 km random path", 5),
];

/// The geometry methods of the accuracy table: method, cuts, refinement, label.
const METHODS: [(Method, Cuts, GeometryRefine, &str); 5] = [
    (
        Method::Subtrajectory,
        Cuts::Distance,
        GeometryRefine::Filter,
        "sub-trajectories refined by the filter (default)",
    ),
    (
        Method::Subtrajectory,
        Cuts::Distance,
        GeometryRefine::None,
        "sub-trajectories, `--geometry-refine none`",
    ),
    (
        Method::Subtrajectory,
        Cuts::Straights,
        GeometryRefine::Filter,
        "sub-trajectories, `--subtrajectory-cuts straights`",
    ),
    (
        Method::Subtrajectory,
        Cuts::Straights,
        GeometryRefine::None,
        "sub-trajectories, `--subtrajectory-cuts straights --geometry-refine none`",
    ),
    (
        Method::Paper,
        Cuts::Distance,
        GeometryRefine::None,
        "`--method paper` (eq 16)",
    ),
];

fn poor() -> ChassisParams {
    ChassisParams {
        left_diameter: 0.300,
        right_diameter: 0.300,
        track_width: 0.700,
        ..ChassisParams::DESIGNED
    }
}

/// The options `odoctl calibrate` maps its defaults to: both models' coefficients fitted,
/// the covariance model selected.
fn cli_defaults() -> CalibrationOptions {
    CalibrationOptions {
        models: vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
        select: Some(UncertaintyModel::Covariance),
        ..Default::default()
    }
}

/// The run of `odoctl simulate --path KIND --length LENGTH --seed SEED` with its defaults.
fn sim(kind: PathKind, length: f64, seed: u64) -> SimRun {
    simulate::simulate_path(
        kind,
        length,
        default_truth(),
        SimSettings {
            seed,
            ..Default::default()
        },
    )
}

fn env_count(var: &str) -> Option<u64> {
    std::env::var(var)
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&n| n > 0)
}

fn reps(var: &str, default: usize) -> usize {
    env_count(var).map_or(default, |n| n as usize)
}

/// Runs `f` `n` times; the median wall time (s) and the last result.
fn timed<T>(n: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut times = Vec::with_capacity(n);
    let mut last = None;
    for _ in 0..n.max(1) {
        let t = Instant::now();
        last = Some(f());
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], last.expect("one run"))
}

/// Three lengths in mm (left / right / track), signed or not.
fn mm3(v: [f64; 3], signed: bool) -> String {
    if signed {
        format!("{:+.4} / {:+.4} / {:+.3}", v[0], v[1], v[2])
    } else {
        format!("{:.4} / {:.4} / {:.3}", v[0], v[1], v[2])
    }
}

/// One geometry estimate's errors to the truth (mm: left, right, track) and its reported
/// standard errors (mm: the geometry fit's robust ones, the filter's when it refined them).
fn geometry_errors(c: &calib::Calibration) -> ([f64; 3], [f64; 3]) {
    let t = default_truth();
    let p = &c.params;
    let se = c.geometry.robust_std_errors;
    (
        [
            (p.left_diameter - t.left_diameter) * 1e3,
            (p.right_diameter - t.right_diameter) * 1e3,
            (p.track_width - t.track_width) * 1e3,
        ],
        std::array::from_fn(|i| se[i].map_or(f64::NAN, |v| v * 1e3)),
    )
}

/// The accuracy table: per log and geometry method, seed 1's errors to the truth with its
/// reported standard errors, the RMS error and the RMS reported standard error over the
/// seeds, the share of the estimates within 2 reported standard errors, and on how many
/// seeds the filter's refinement was applied.
fn accuracy() {
    let logs: Vec<String> = std::env::var("BENCH_LOGS")
        .map(|v| v.split(',').map(|l| l.trim().to_string()).collect())
        .unwrap_or_default();
    println!("| log | method | seeds | seed 1 error, mm (left / right / track) | seed 1 reported SE, mm | RMS error, mm | RMS reported SE, mm | within 2 SE | refined |");
    println!("| --- | --- | ---: | --- | --- | --- | --- | ---: | ---: |");
    for (kind, length, name, label, default_seeds) in LOGS {
        if !logs.is_empty() && !logs.iter().any(|l| l == name) {
            continue;
        }
        let seeds = env_count("BENCH_SEEDS").unwrap_or(default_seeds);
        let runs: Vec<SimRun> = (1..=seeds).map(|seed| sim(kind, length, seed)).collect();
        for (method, cuts, refine, name) in METHODS {
            let o = CalibrationOptions {
                method,
                subtrajectory_cuts: cuts,
                geometry_refine: refine,
                fit_delta: false,
                ..Default::default()
            };
            accuracy_row(label, name, &runs, &o, refine == GeometryRefine::Filter);
        }
    }
}

/// One row of the accuracy table: `runs` (seeds 1..) calibrated with `o`.
fn accuracy_row(log: &str, method: &str, runs: &[SimRun], o: &CalibrationOptions, filter: bool) {
    let (mut sq, mut sq_se) = ([0.0; 3], [0.0; 3]);
    let (mut within2, mut refined, mut done) = (0usize, 0usize, 0usize);
    let mut first = None;
    for r in runs {
        match calib::calibrate(&r.samples, &r.reference, ("s", "r"), &poor(), o) {
            Ok(c) => {
                let (e, se) = geometry_errors(&c);
                for i in 0..3 {
                    sq[i] += e[i] * e[i];
                    sq_se[i] += se[i] * se[i];
                    within2 += usize::from(e[i].abs() <= 2.0 * se[i]);
                }
                refined += usize::from(c.refinement.as_ref().is_some_and(|r| r.skipped.is_none()));
                done += 1;
                first.get_or_insert((e, se));
            }
            Err(e) => eprintln!("{log}, {method}: a calibration failed: {e}"),
        }
    }
    let Some((e, se)) = first else {
        println!("| {log} | {method} | {} | failed | | | | | |", runs.len());
        return;
    };
    let rms = |s: [f64; 3]| s.map(|v| (v / done as f64).sqrt());
    let failed = runs.len() - done;
    println!(
        "| {log} | {method} | {}{} | {} | {} | {} | {} | {:.1} % | {} |",
        runs.len(),
        if failed > 0 {
            format!(" ({failed} failed)")
        } else {
            String::new()
        },
        mm3(e, true),
        mm3(se, false),
        mm3(rms(sq), false),
        mm3(rms(sq_se), false),
        100.0 * within2 as f64 / (3 * done) as f64,
        if filter {
            format!("{refined} of {done}")
        } else {
            "-".into()
        }
    );
}

/// The eq (16) cost's own arithmetic noise at the fit (m): its spread under `left_diameter`
/// changes of up to 3e-9 of itself. The fixed-point integrator rounds every position
/// increment to 2^-32 m and the transfer constants to 2^-48 m, so the cost is not smooth
/// below about 1e-7 of it.
fn eq16_noise(r: &Run, f: &calib::GeomFit) -> (f64, f64) {
    let last = r.len() - 1;
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for k in [-3.0, -2.0, -1.0, 1.0, 2.0, 3.0] {
        let mut p = f.params;
        p.left_diameter *= 1.0 + k * 1e-9;
        if let Some(c) = r.eq16(&p, 0, last, f.heading0) {
            lo = lo.min(c - f.cost);
            hi = hi.max(c - f.cost);
        }
    }
    (lo, hi)
}

/// The speed rows of one run (`n` repetitions each); returns the calibration with the CLI's
/// defaults, for the coefficients table.
fn speed_rows(label: &str, run: &SimRun, n: usize) -> Option<calib::Calibration> {
    let r = Run::new(
        &run.samples,
        &run.reference,
        match_times(&run.samples, &run.reference),
    );
    let last = r.len() - 1;
    let name = format!("{label} ({} samples)", thousands(run.samples.len() as u64));
    let (t, fit) = timed(n, || {
        calib::fit_geometry(
            &r,
            &poor(),
            r.heading_guess(0),
            0,
            last,
            GeomOptions::default(),
            &ProgressBar::hidden(),
        )
    });
    match fit {
        Ok(f) => {
            let (lo, hi) = eq16_noise(&r, &f);
            println!(
                "| {name}: eq (16) fit | {t:.4} s | {} iterations, {} integrator runs; eq (16) {:.6} m, its arithmetic noise {lo:+.1e} .. {hi:+.1e} m |",
                f.iterations, f.evaluations, f.cost
            );
        }
        Err(e) => println!("| {name}: eq (16) fit | failed | {e} |"),
    }
    let (t, fit) = timed(n, || {
        calib::fit_subtrajectories(&r, &poor(), calib::SubtrajectoryOptions::default())
    });
    match fit {
        Ok(f) => println!(
            "| {name}: sub-trajectory fit | {t:.4} s | {} sub-trajectories, {} iterations |",
            f.blocks.len(),
            f.iterations
        ),
        Err(e) => println!("| {name}: sub-trajectory fit | failed | {e} |"),
    }
    let calibrate = |o: &CalibrationOptions| {
        calib::calibrate(&run.samples, &run.reference, ("s", "r"), &poor(), o)
    };
    let paper = CalibrationOptions {
        method: Method::Paper,
        ..cli_defaults()
    };
    let (t, c) = timed(n, || calibrate(&paper));
    match c {
        Ok(_) => println!("| {name}: whole calibration, `--method paper` | {t:.4} s | eq (16), both models' coefficients |"),
        Err(e) => println!("| {name}: whole calibration, `--method paper` | failed | {e} |"),
    }
    let (t, c) = timed(n, || calibrate(&cli_defaults()));
    match c {
        Ok(c) => {
            println!("| {name}: whole calibration, defaults | {t:.4} s | sub-trajectories refined by the filter, both models' coefficients |");
            Some(c)
        }
        Err(e) => {
            println!("| {name}: whole calibration, defaults | failed | {e} |");
            None
        }
    }
}

/// The stability study `--windows 1,2,4,8` of `run` (fits per window from the initial
/// estimate), `n` repetitions.
fn stability_row(label: &str, run: &SimRun, n: usize) {
    let r = Run::new(
        &run.samples,
        &run.reference,
        match_times(&run.samples, &run.reference),
    );
    let Ok(full) = calib::fit_geometry(
        &r,
        &poor(),
        r.heading_guess(0),
        0,
        r.len() - 1,
        GeomOptions::default(),
        &ProgressBar::hidden(),
    ) else {
        println!(
            "| {label}: stability study `--windows 1,2,4,8` | failed | the whole-run fit failed |"
        );
        return;
    };
    let (t, est) = timed(n, || {
        calib::windows_study(
            &r,
            &full,
            &poor(),
            &[1.0, 2.0, 4.0, 8.0],
            WindowStart::Initial,
            &ProgressBar::hidden(),
        )
    });
    println!(
        "| {label}: stability study `--windows 1,2,4,8` | {t:.4} s | {} fits from the initial estimate |",
        est.map_or(0, |e| e.len())
    );
}

/// The `--wheel-harmonics` fit (`CalibrationOptions::wheel_harmonics`) on a 300 m random path
/// (seed 1, simulator defaults) whose left wheel has a first harmonic of 0.1 mm in the
/// radius: the default calibration without the uncertainty fits, with 0, 1 and 3 harmonics;
/// the difference to 0 is the harmonics fit's own time. The recovered `left_cos1` (mm of
/// radius) with its standard error is beside it.
fn harmonics_rows(n: usize) {
    let mut truth = default_truth();
    let rl = truth.left_diameter / 2.0;
    truth.left_wheel.cos[0] = (1e-4 / rl) as f32;
    let run = simulate::simulate_path(PathKind::Random, 300.0, truth, SimSettings::default());
    let label = "300 m random path, left wheel eccentric by 0.1 mm";
    let mut base = f64::NAN;
    for order in [0, 1, 3] {
        let o = CalibrationOptions {
            fit_delta: false,
            wheel_harmonics: order,
            ..Default::default()
        };
        let (t, c) = timed(n, || {
            calib::calibrate(&run.samples, &run.reference, ("s", "r"), &poor(), &o)
        });
        match c {
            Ok(_) if order == 0 => {
                base = t;
                println!("| {label}: geometry without `--wheel-harmonics` | {t:.4} s | the default geometry, no uncertainty fits |");
            }
            Ok(c) => match &c.harmonics {
                Some(h) => println!(
                    "| {label}: `--wheel-harmonics {order}` | {t:.4} s | the harmonics fit {:.4} s ({} segments of {} m, {} points); `left_cos1` {:.4} mm of radius (truth 0.1000), standard error {:.4} mm |",
                    t - base,
                    h.segments,
                    h.segment,
                    thousands(h.points as u64),
                    h.values[0] * rl * 1e3,
                    h.std_errors[0] * rl * 1e3
                ),
                None => println!("| {label}: `--wheel-harmonics {order}` | {t:.4} s | no harmonics fitted |"),
            },
            Err(e) => println!("| {label}: `--wheel-harmonics {order}` | failed | {e} |"),
        }
    }
}

/// The uncertainty coefficients a calibration with the CLI's defaults fitted.
fn coefficient_rows(label: &str, c: &calib::Calibration) {
    for u in &c.uncertainty {
        let p = &u.params;
        match u.model {
            UncertaintyModel::Paper => println!(
                "| {label} | paper (coverage) | delta {:.6e} / {:.6e}, `delta_diff` {:.6e} | {:.1} % |",
                p.delta_left, p.delta_right, p.delta_diff, 100.0 * u.coverage1
            ),
            UncertaintyModel::Covariance => println!(
                "| {label} | covariance (likelihood) | kappa {:.6e} / {:.6e}, `kappa_diff` {:.3e}, `kappa_diff_corr` {:.2} m | {:.1} % |",
                p.kappa_left, p.kappa_right, p.kappa_diff, p.kappa_diff_corr, 100.0 * u.coverage1
            ),
        }
    }
}

/// The speed tables.
fn speed() {
    let n = reps("BENCH_REPS", 5);
    let n_long = reps("BENCH_REPS_LONG", 3);
    let s70 = sim(PathKind::Estimation, 70.0, 1);
    let s3k = sim(PathKind::Random, 3000.0, 1);
    println!("| figure | wall time (median of {n}, of {n_long} on 3 km) | detail |");
    println!("| --- | ---: | --- |");
    let c70 = speed_rows("70 m estimation path", &s70, n);
    let c3k = speed_rows("3 km random path", &s3k, n_long);
    stability_row("70 m estimation path", &s70, n);
    harmonics_rows(n);
    println!();
    println!("The uncertainty coefficients the timed calibrations with the defaults fitted:");
    println!();
    println!("| run | model (criterion) | coefficients | 1-sigma coverage of the fit |");
    println!("| --- | --- | --- | ---: |");
    for (label, c) in [("70 m estimation path", &c70), ("3 km random path", &c3k)] {
        if let Some(c) = c {
            coefficient_rows(label, c);
        }
    }
}

/// `odo-bench calibrate [accuracy|speed]`: prints those tables (both without an argument).
pub fn run(what: Option<&str>) {
    match what {
        Some("accuracy") => accuracy(),
        Some("speed") => speed(),
        None => {
            accuracy();
            println!();
            speed();
        }
        Some(other) => {
            eprintln!("odo-bench calibrate: unknown table {other:?} (accuracy, speed)");
            std::process::exit(2);
        }
    }
}
