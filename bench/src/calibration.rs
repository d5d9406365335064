//! Calibration speed on the host (`odo-bench calibrate`): `odoctl`'s eq (16) fit and its whole
//! calibration (eq 16, then the uncertainty coefficients) on runs made by `odoctl`'s own
//! simulator, exactly as `odoctl simulate` makes them with its defaults (seed 1, 50 Hz,
//! 0.5 m/s, default slip and RTK noise): the 70 m estimation path and a 3 km random path
//! (`odoctl simulate --path random --length 3000`). Every fit starts from the paper's poor
//! first estimate 0.300/0.300/0.700 m. Wall times are medians of several runs (in-process,
//! no CSV parsing); the eq (16) cost, iterations and integrator runs are printed next to the
//! figures measured before issue 11 (analytic sensitivities), on the same deterministic
//! inputs, so the cost comparison is part of the output. Figures only: nothing here fails on
//! noise.
//!
//! First the accuracy table of both geometry methods (sub-trajectories, the default, and the
//! paper's eq 16) over 70 m, 300 m, 1 km and 3 km logs with correlated slip, and the wall time
//! of the default calibration on 3 km; the speed figures below it are those of
//! `--method paper` (the eq 16 fit, comparable with the figures before issue 11).
//!
//! Then the time of the `--wheel-harmonics` fit on a 300 m run with an eccentric wheel.
//!
//! `BENCH_REPS` (default 5) sets the repetitions of the 70 m figures; the 3 km figures use
//! `BENCH_REPS_LONG` (default 3); `BENCH_SEEDS` (default 5) the seeds of the accuracy table,
//! `BENCH_LOGS` its logs (default all: `70 m,300 m,1 km,3 km`).

use std::time::Instant;

use indicatif::ProgressBar;
use odo_core::odometry::{ChassisParams, UncertaintyModel};
use odoctl::calib::{
    self, CalibrationOptions, Cuts, GeomOptions, GeometryRefine, Method, Run, WindowStart,
};
use odoctl::csvio::match_times;
use odoctl::simulate::{self, default_truth, PathKind, SimRun, SimSettings};

/// Figures measured before issue 11 on the same inputs and machine (commit 0b32b1c:
/// central-difference Jacobian, IRLS, and the Nelder-Mead polish that was then the default):
/// eq (16) fit seconds, eq (16) cost, iterations, integrator runs; whole calibration seconds.
/// Both then and now the options are `odoctl calibrate`'s defaults.
struct Before {
    fit_s: f64,
    cost: f64,
    iterations: usize,
    runs: usize,
    calibrate_s: f64,
}

const BEFORE_70: Before = Before {
    fit_s: 0.3443,
    cost: 56.958589,
    iterations: 344,
    runs: 1587,
    calibrate_s: 0.4392,
};
const BEFORE_3K: Before = Before {
    fit_s: 21.5147,
    cost: 156_080.073_140,
    iterations: 477,
    runs: 3342,
    calibrate_s: 27.2369,
};
/// Stability study `--windows 1,2,4,8` on the 70 m run before issue 11 (s).
const BEFORE_WINDOWS_70: f64 = 0.4162;

fn poor() -> ChassisParams {
    ChassisParams {
        left_diameter: 0.300,
        right_diameter: 0.300,
        track_width: 0.700,
        ..ChassisParams::DESIGNED
    }
}

/// The run of `odoctl simulate --path KIND --length LENGTH` with its defaults.
fn sim(kind: PathKind, length: f64) -> SimRun {
    simulate::simulate_path(kind, length, default_truth(), SimSettings::default())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn reps(var: &str, default: usize) -> usize {
    std::env::var(var)
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(default)
}

fn ratio(before: f64, now: f64) -> String {
    if before.is_finite() {
        format!("{:.1}x faster", before / now)
    } else {
        "no earlier figure".into()
    }
}

fn case(name: &str, run: &SimRun, n: usize, before: &Before) {
    let r = Run::new(
        &run.samples,
        &run.reference,
        match_times(&run.samples, &run.reference),
    );
    let last = r.len() - 1;
    let mut times = Vec::new();
    let mut fit = None;
    for _ in 0..n {
        let t = Instant::now();
        let f = calib::fit_geometry(
            &r,
            &poor(),
            r.heading_guess(0),
            0,
            last,
            GeomOptions::default(),
            &ProgressBar::hidden(),
        );
        times.push(t.elapsed().as_secs_f64());
        fit = Some(f);
    }
    let f = match fit {
        Some(Ok(f)) => f,
        Some(Err(e)) => {
            println!("{name}: eq (16) fit failed: {e}");
            return;
        }
        None => return,
    };
    let t_fit = median(times);
    println!(
        "{name}: {} samples, eq (16) fit from 0.300/0.300/0.700: {:.4} s (median of {n}; before {:.4} s, {})",
        run.samples.len(),
        t_fit,
        before.fit_s,
        ratio(before.fit_s, t_fit)
    );
    println!(
        "{name}:   eq (16) {:.6} m (before {:.6} m, difference {:+.2e} m); {} iterations (before {}), {} integrator runs (before {}); estimate {:.6}/{:.6}/{:.6} m",
        f.cost,
        before.cost,
        f.cost - before.cost,
        f.iterations,
        before.iterations,
        f.evaluations,
        before.runs,
        f.params.left_diameter,
        f.params.right_diameter,
        f.params.track_width
    );
    // The resolution of eq (16) itself: the fixed-point integrator rounds every position
    // increment to 2^-32 m and the transfer constants to 2^-48 m, so the cost is not smooth
    // below about 1e-7 of it. Its spread under diameter changes of a few 1e-9 (nanometres)
    // around the estimate, where the smooth cost changes by far less:
    let mut lo: f64 = 0.0;
    let mut hi: f64 = 0.0;
    for k in [-3.0, -2.0, -1.0, 1.0, 2.0, 3.0] {
        let mut p = f.params;
        p.left_diameter *= 1.0 + k * 1e-9;
        if let Some(c) = r.eq16(&p, 0, last, f.heading0) {
            lo = lo.min(c - f.cost);
            hi = hi.max(c - f.cost);
        }
    }
    println!(
        "{name}:   eq (16) arithmetic noise: {lo:+.1e} .. {hi:+.1e} m for left_diameter changed by up to 3e-9 of itself"
    );
    let mut times = Vec::new();
    for _ in 0..n {
        let t = Instant::now();
        let c = calib::calibrate(
            &run.samples,
            &run.reference,
            ("s", "r"),
            &poor(),
            &CalibrationOptions {
                method: Method::Paper,
                ..Default::default()
            },
        );
        times.push(t.elapsed().as_secs_f64());
        if let Err(e) = c {
            println!("{name}: calibration failed: {e}");
            return;
        }
    }
    let t_all = median(times);
    println!(
        "{name}:   whole calibration with --method paper (eq 16 + delta + delta_diff, in-process): {:.4} s (median of {n}; before {:.4} s, {})",
        t_all,
        before.calibrate_s,
        ratio(before.calibrate_s, t_all)
    );
    // The fitted coefficients, both models (the paper's with delta_diff), so that a change of
    // the uncertainty fits can be checked against the bisection's tolerance.
    let all = CalibrationOptions {
        models: vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
        method: Method::Paper,
        ..Default::default()
    };
    match calib::calibrate(&run.samples, &run.reference, ("s", "r"), &poor(), &all) {
        Ok(c) => {
            for u in &c.uncertainty {
                let p = &u.params;
                match u.model {
                    UncertaintyModel::Paper => println!(
                        "{name}:   paper model: delta {:.9e} / {:.9e}, delta_diff {:.9e} (1-sigma coverage {:.4})",
                        p.delta_left, p.delta_right, p.delta_diff, u.coverage1
                    ),
                    UncertaintyModel::Covariance => println!(
                        "{name}:   covariance model: kappa {:.9e} / {:.9e} (1-sigma coverage {:.4})",
                        p.kappa_left, p.kappa_right, u.coverage1
                    ),
                }
            }
        }
        Err(e) => println!("{name}: calibration with both models failed: {e}"),
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

/// The accuracy table of issue 16: errors to the truth of the geometry methods from
/// 0.300/0.300/0.700 on logs of 70 m (the estimation path), 300 m, 1 km and 3 km (random
/// paths), all with the simulator's correlated slip (`odoctl simulate` defaults: 0.1 % over
/// 0.1 m): the default (sub-trajectories cut by distance, refined by the filter where its
/// linearisation holds), the same without the refinement (`--geometry-refine none`), both with
/// the cuts on straights, and the paper's eq (16); seed 1 (what `odoctl simulate` writes) with
/// its reported standard errors, the RMS error and the RMS reported standard error over seeds
/// 1-`BENCH_SEEDS` (default 5), the share of the estimates within 2 reported standard errors,
/// and on how many seeds the filter
/// refined the estimate (`BENCH_LOGS`, e.g. `70 m,300 m`, limits the logs). Then the wall time
/// of the whole default calibration on 3 km.
fn accuracy_table() {
    let seeds = reps("BENCH_SEEDS", 5) as u64;
    let logs: Vec<String> = std::env::var("BENCH_LOGS")
        .map(|v| v.split(',').map(|l| l.trim().to_string()).collect())
        .unwrap_or_default();
    println!(
        "accuracy from 0.300/0.300/0.700, simulator defaults (slip 0.1 % over 0.1 m, RTK 8 mm); errors to the truth in mm (left / right / track), seed 1 with its reported standard errors, RMS over seeds 1-{seeds}:"
    );
    println!(
        "  {:<6} {:<26} {:>28} {:>28} {:>28} {:>28} {:>9} {:>8}",
        "log",
        "method",
        "seed 1 error",
        "seed 1 std. error",
        "RMS error",
        "RMS std. error",
        "in 2 SE",
        "refined"
    );
    for (kind, length, label) in [
        (PathKind::Estimation, 70.0, "70 m"),
        (PathKind::Random, 300.0, "300 m"),
        (PathKind::Random, 1000.0, "1 km"),
        (PathKind::Random, 3000.0, "3 km"),
    ] {
        if !logs.is_empty() && !logs.iter().any(|l| l == label) {
            continue;
        }
        let runs: Vec<SimRun> = (1..=seeds)
            .map(|seed| {
                simulate::simulate_path(
                    kind,
                    length,
                    default_truth(),
                    SimSettings {
                        seed,
                        ..Default::default()
                    },
                )
            })
            .collect();
        for (method, cuts, refine, mname) in [
            (
                Method::Subtrajectory,
                Cuts::Distance,
                GeometryRefine::Filter,
                "subtrajectory+filter",
            ),
            (
                Method::Subtrajectory,
                Cuts::Distance,
                GeometryRefine::None,
                "subtrajectory",
            ),
            (
                Method::Subtrajectory,
                Cuts::Straights,
                GeometryRefine::Filter,
                "straights+filter",
            ),
            (
                Method::Subtrajectory,
                Cuts::Straights,
                GeometryRefine::None,
                "straights",
            ),
            (Method::Paper, Cuts::Distance, GeometryRefine::None, "paper"),
        ] {
            let o = CalibrationOptions {
                method,
                subtrajectory_cuts: cuts,
                geometry_refine: refine,
                fit_delta: false,
                ..Default::default()
            };
            let (mut sq, mut sq_se) = ([0.0; 3], [0.0; 3]);
            let (mut within2, mut refined) = (0usize, 0usize);
            let mut first = None;
            for r in &runs {
                match calib::calibrate(&r.samples, &r.reference, ("s", "r"), &poor(), &o) {
                    Ok(c) => {
                        let (e, se) = geometry_errors(&c);
                        for i in 0..3 {
                            sq[i] += e[i] * e[i];
                            sq_se[i] += se[i] * se[i];
                            within2 += usize::from(e[i].abs() <= 2.0 * se[i]);
                        }
                        refined +=
                            usize::from(c.refinement.as_ref().is_some_and(|r| r.skipped.is_none()));
                        first.get_or_insert((e, se));
                    }
                    Err(e) => println!("  {label} {mname}: failed: {e}"),
                }
            }
            let Some((e, se)) = first else { continue };
            let rms = sq.map(|v| (v / seeds as f64).sqrt());
            let rms_se = sq_se.map(|v| (v / seeds as f64).sqrt());
            let f = |v: [f64; 3], sign: bool| {
                if sign {
                    format!("{:+.4} / {:+.4} / {:+.3}", v[0], v[1], v[2])
                } else {
                    format!("{:.4} / {:.4} / {:.3}", v[0], v[1], v[2])
                }
            };
            println!(
                "  {label:<6} {mname:<26} {:>28} {:>28} {:>28} {:>28} {:>8.1}% {:>8}",
                f(e, true),
                f(se, false),
                f(rms, false),
                f(rms_se, false),
                100.0 * within2 as f64 / (3 * runs.len()) as f64,
                format!("{refined}/{}", runs.len())
            );
        }
    }
    // The whole default calibration (sub-trajectory fit, filter refinement, delta, delta_diff)
    // on the 3 km log.
    let s3k = sim(PathKind::Random, 3000.0);
    let n = reps("BENCH_REPS_LONG", 3);
    let mut times = Vec::new();
    let mut fit_times = Vec::new();
    for _ in 0..n {
        let t = Instant::now();
        let c = calib::calibrate(
            &s3k.samples,
            &s3k.reference,
            ("s", "r"),
            &poor(),
            &CalibrationOptions::default(),
        );
        times.push(t.elapsed().as_secs_f64());
        if let Err(e) = c {
            println!("3 km default calibration failed: {e}");
            return;
        }
        let r = Run::new(
            &s3k.samples,
            &s3k.reference,
            match_times(&s3k.samples, &s3k.reference),
        );
        let t = Instant::now();
        let _ = calib::fit_subtrajectories(&r, &poor(), calib::SubtrajectoryOptions::default());
        fit_times.push(t.elapsed().as_secs_f64());
    }
    println!(
        "3 km random path, default method from 0.300/0.300/0.700: sub-trajectory fit {:.4} s, whole calibration (fit + delta + delta_diff, in-process) {:.4} s (medians of {n})",
        median(fit_times),
        median(times)
    );
}

/// The `--wheel-harmonics` fit (`calib::fit_harmonics`, `CalibrationOptions::wheel_harmonics`)
/// on a 300 m random path (seed 1, simulator defaults) whose left wheel has a first harmonic
/// of 0.1 mm in the radius: the default calibration without the uncertainty fits, with 0, 1
/// and 3 harmonics, medians of `n`; the difference to 0 is the harmonics fit's own time. The
/// recovered `left_cos1` (mm of radius) with its standard error is printed beside it.
fn harmonics_timing(n: usize) {
    let mut truth = default_truth();
    let rl = truth.left_diameter / 2.0;
    truth.left_wheel.cos[0] = (1e-4 / rl) as f32;
    let run = simulate::simulate_path(PathKind::Random, 300.0, truth, SimSettings::default());
    let mut base = f64::NAN;
    for order in [0, 1, 3] {
        let o = CalibrationOptions {
            fit_delta: false,
            wheel_harmonics: order,
            ..Default::default()
        };
        let mut times = Vec::new();
        let mut last = None;
        for _ in 0..n {
            let t = Instant::now();
            let c = calib::calibrate(&run.samples, &run.reference, ("s", "r"), &poor(), &o);
            times.push(t.elapsed().as_secs_f64());
            last = Some(c);
        }
        let t = median(times);
        match last {
            Some(Ok(c)) => {
                if order == 0 {
                    base = t;
                    println!(
                        "300 m random path, left wheel eccentric by 0.1 mm: default geometry fit without --wheel-harmonics {t:.4} s (median of {n})"
                    );
                } else if let Some(h) = &c.harmonics {
                    println!(
                        "  --wheel-harmonics {order}: {t:.4} s, the harmonics fit {:.4} s ({} segments of {} m, {} points); left_cos1 {:.4} mm of radius (truth 0.1000), standard error {:.4} mm",
                        t - base,
                        h.segments,
                        h.segment,
                        h.points,
                        h.values[0] * rl * 1e3,
                        h.std_errors[0] * rl * 1e3
                    );
                }
            }
            Some(Err(e)) => println!("  --wheel-harmonics {order}: failed: {e}"),
            None => {}
        }
    }
}

/// Prints the calibration figures.
pub fn run() {
    let n = reps("BENCH_REPS", 5);
    let n_long = reps("BENCH_REPS_LONG", 3);
    accuracy_table();
    harmonics_timing(n);
    let s70 = sim(PathKind::Estimation, 70.0);
    case("70 m estimation path", &s70, n, &BEFORE_70);
    let s3k = sim(PathKind::Random, 3000.0);
    case("3 km random path", &s3k, n_long, &BEFORE_3K);

    // The stability study of the 70 m run (fits per window from the initial estimate).
    let r = Run::new(
        &s70.samples,
        &s70.reference,
        match_times(&s70.samples, &s70.reference),
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
        println!("stability study: the full fit failed");
        return;
    };
    let mut times = Vec::new();
    let mut fits = 0;
    for _ in 0..n {
        let t = Instant::now();
        let est = calib::windows_study(
            &r,
            &full,
            &poor(),
            &[1.0, 2.0, 4.0, 8.0],
            WindowStart::Initial,
            &ProgressBar::hidden(),
        );
        times.push(t.elapsed().as_secs_f64());
        fits = est.map_or(0, |e| e.len());
    }
    let t = median(times);
    println!(
        "70 m stability study --windows 1,2,4,8 ({fits} fits): {t:.4} s (median of {n}; before {BEFORE_WINDOWS_70:.4} s, {})",
        ratio(BEFORE_WINDOWS_70, t)
    );
}
