//! The standard errors `calibrate` reports hold: over many simulated runs with correlated
//! slip, the truth lies within 2 reported standard errors about 95 % of the time and within 3
//! nearly always, for the sub-trajectory estimator and for its refinement by the
//! filter on the 70 m estimation path; and the lever arm is recovered from simulated receiver
//! logs.
//!
//! `ODO_RESULTS_DIR=DIR` writes the coverage table there as Markdown, a file per row under
//! `DIR/standard_errors/` (`bench/run` puts it into docs/RESULTS.md).

mod common;

use odo_unit::odometry::ChassisParams;
use odoctl::calib::{self, CalibrationOptions, GeometryRefine, Run, SubtrajectoryOptions};
use odoctl::csvio::match_times;
use odoctl::simulate::{self, PathKind, SimSettings};

/// Runs over which the coverage is counted (each 3 parameters).
const SEEDS: u64 = 60;
/// Runs of the paper method's figures.
const PAPER_SEEDS: u64 = 30;

/// A random path of `length` metres with the simulator's correlated slip (0.2 % over 0.5 m)
/// and opposite-phase slip when turning (0.5 % over 0.2 m of differential travel). (Slip
/// correlated over more than a sub-trajectory breaks the sandwich's independence of the
/// clusters: turning slip over 1 m of differential travel, several sub-trajectories on gentle
/// arcs, brings the coverage at 2 SE down to about 90 %.)
fn slippy(length: f64, seed: u64) -> simulate::SimRun {
    simulate::simulate_path(
        PathKind::Random,
        length,
        common::truth(),
        SimSettings {
            seed,
            slip: 0.002,
            slip_corr: 0.5,
            slip_turn: 0.005,
            slip_turn_corr: 0.2,
            ..Default::default()
        },
    )
}

/// The coverage table's header (Markdown).
const TABLE_HEADER: &str = "| estimator | runs | estimates | within 2 SE | within 3 SE | formal errors within 2 SE | held to |\n\
                            | --- | --- | ---: | ---: | ---: | ---: | --- |\n";

/// Writes `text` as `$ODO_RESULTS_DIR/standard_errors/NAME.md` when that variable is set
/// (`bench/run` joins the files in name order), with the table's header as `0_header.md`.
fn write_results(name: &str, text: &str) {
    let Some(dir) = std::env::var_os("ODO_RESULTS_DIR") else {
        return;
    };
    let dir = std::path::Path::new(&dir).join("standard_errors");
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    // The first test to get here writes the header; the others find it written.
    let header = dir.join("0_header.md");
    if let Ok(mut f) = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&header)
    {
        use std::io::Write;
        f.write_all(TABLE_HEADER.as_bytes())
            .unwrap_or_else(|e| panic!("{}: {e}", header.display()));
    }
    let path = dir.join(format!("{name}.md"));
    std::fs::write(&path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// A percentage of `k` in `n`.
fn pct(k: usize, n: usize) -> f64 {
    100.0 * k as f64 / n as f64
}

fn errors_in_se(fit: &calib::SubtrajectoryFit, truth: &ChassisParams) -> [f64; 3] {
    let t = common::lengths(truth);
    let p = common::lengths(&fit.params);
    std::array::from_fn(|i| (p[i] - t[i]).abs() / fit.std_errors[i].unwrap())
}

#[test]
fn subtrajectory_standard_errors_cover_the_truth_over_many_seeds() {
    let truth = common::truth();
    let (mut within2, mut within3, mut n) = (0, 0, 0);
    let mut formal_within2 = 0;
    let started = std::time::Instant::now();
    let (length, seeds) = (250.0, SEEDS);
    for seed in 1..=seeds {
        let sim = slippy(length, 1000 + seed);
        let run = Run::new(
            &sim.samples,
            &sim.reference,
            match_times(&sim.samples, &sim.reference),
        );
        let fit =
            calib::fit_subtrajectories(&run, &truth, SubtrajectoryOptions::default()).unwrap();
        for (i, z) in errors_in_se(&fit, &truth).into_iter().enumerate() {
            n += 1;
            within2 += usize::from(z <= 2.0);
            within3 += usize::from(z <= 3.0);
            let t = common::lengths(&truth)[i];
            let e = common::lengths(&fit.params)[i] - t;
            formal_within2 += usize::from(e.abs() <= 2.0 * fit.independent_std_errors[i].unwrap());
        }
    }
    let (c2, c3) = (within2 as f64 / n as f64, within3 as f64 / n as f64);
    let formal = formal_within2 as f64 / n as f64;
    eprintln!(
        "{seeds} runs of {length} m, {n} estimates: within 2 SE {:.1} %, within 3 SE {:.1} % (formal (J^T J)^-1 s^2: within 2 SE {:.1} %); {:.1} s",
        100.0 * c2,
        100.0 * c3,
        100.0 * formal,
        started.elapsed().as_secs_f64()
    );
    write_results(
        "1_subtrajectory",
        &format!(
            "| sub-trajectories (the default geometry fit, unrefined), cluster-robust | {seeds} \
             random paths of {length} m, slip 0.2 % over 0.5 m and turning slip 0.5 % over 0.2 m \
             | {n} | {:.1} % | {:.1} % | {:.1} % | 2 SE 85-100 %, 3 SE at least 97 %, formal \
             below 70 % |\n",
            pct(within2, n),
            pct(within3, n),
            pct(formal_within2, n)
        ),
    );
    assert!((0.85..=1.0).contains(&c2), "within 2 SE: {c2}");
    assert!(c3 >= 0.97, "within 3 SE: {c3}");
    // The formal errors, which take the residuals as independent, do not hold.
    assert!(formal < 0.7, "formal within 2 SE: {formal}");
}

/// The paper's method: eq (16)'s cluster-robust errors over consecutive stretches, against
/// the formal ones (figures for the README; the drift spans the whole run, so stretches are
/// not independent and these errors hold only roughly).
#[test]
fn paper_method_cluster_errors_against_the_formal_ones() {
    let truth = common::truth();
    let (mut robust2, mut formal2, mut robust3, mut n) = (0, 0, 0, 0);
    for seed in 1..=PAPER_SEEDS {
        let sim = slippy(250.0, 1000 + seed);
        let run = Run::new(
            &sim.samples,
            &sim.reference,
            match_times(&sim.samples, &sim.reference),
        );
        let fit = calib::fit_geometry(
            &run,
            &truth,
            run.heading_guess(0),
            0,
            run.len() - 1,
            calib::GeomOptions::default(),
            &indicatif::ProgressBar::hidden(),
        )
        .unwrap();
        let t = common::lengths(&truth);
        let p = common::lengths(&fit.params);
        for i in 0..3 {
            let e = (p[i] - t[i]).abs();
            n += 1;
            robust2 += usize::from(e <= 2.0 * fit.robust_std_errors[i].unwrap());
            robust3 += usize::from(e <= 3.0 * fit.robust_std_errors[i].unwrap());
            formal2 += usize::from(e <= 2.0 * fit.std_errors[i].unwrap());
        }
    }
    eprintln!(
        "paper method, {PAPER_SEEDS} runs of 250 m: cluster-robust within 2 SE {:.1} %, within 3 SE {:.1} %; formal within 2 SE {:.1} %",
        pct(robust2, n),
        pct(robust3, n),
        pct(formal2, n)
    );
    write_results(
        "2_paper",
        &format!(
            "| `--method paper` (eq 16), cluster-robust over stretches | the first {PAPER_SEEDS} of \
             those runs | {n} | {:.1} % | {:.1} % | {:.1} % | more than the formal errors within \
             2 SE |\n",
            pct(robust2, n),
            pct(robust3, n),
            pct(formal2, n)
        ),
    );
    assert!(robust2 > formal2, "{robust2} {formal2}");
}

/// The default geometry step on the 70 m estimation path (the simulator's defaults, 0.1 %
/// slip over 0.1 m, from 0.300/0.300/0.700): the filter refines the sub-trajectory estimate
/// on every seed, its track width is closer to the truth than the sub-trajectory fit's over
/// the seeds (RMS; 0.26 against 0.43 mm over 50 seeds, README), the diameters are no worse,
/// and its standard errors (written to the output's `*_se` keys) hold.
#[test]
fn filter_refinement_on_the_70_m_path_beats_the_subtrajectory_track_and_its_errors_hold() {
    let truth = common::truth();
    let poor = ChassisParams {
        left_diameter: 0.300,
        right_diameter: 0.300,
        track_width: 0.700,
        ..ChassisParams::DESIGNED
    };
    let t = common::lengths(&truth);
    let seeds = 30;
    let (mut sq_refined, mut sq_plain) = ([0.0f64; 3], [0.0f64; 3]);
    let (mut within2, mut within3, mut n) = (0, 0, 0);
    for seed in 1..=seeds {
        let sim = common::sim(simulate::PathKind::Estimation, 70.0, seed);
        let run = |refine| {
            calib::calibrate(
                &sim.samples,
                &sim.reference,
                ("s", "r"),
                &poor,
                &CalibrationOptions {
                    fit_delta: false,
                    geometry_refine: refine,
                    ..Default::default()
                },
            )
            .unwrap()
        };
        let refined = run(GeometryRefine::Filter);
        let plain = run(GeometryRefine::None);
        let r = refined.refinement.as_ref().expect("refinement ran");
        assert!(r.skipped.is_none(), "seed {seed}: {:?}", r.skipped);
        assert!(plain.refinement.is_none());
        let g = refined.params.geometry_uncertainty;
        let se = [g.left_diameter_se, g.right_diameter_se, g.track_width_se].map(f64::from);
        let values = |c: &calib::Calibration| common::lengths(&c.params);
        let (vr, vp) = (values(&refined), values(&plain));
        for i in 0..3 {
            let e = vr[i] - t[i];
            sq_refined[i] += e * e;
            sq_plain[i] += (vp[i] - t[i]).powi(2);
            // The unit's keys are the reported errors, the geometry fit's the same.
            let reported = refined.geometry.robust_std_errors[i].unwrap();
            assert!(
                (reported - se[i]).abs() <= 1e-6 * reported,
                "{reported} {}",
                se[i]
            );
            n += 1;
            within2 += usize::from(e.abs() <= 2.0 * se[i]);
            within3 += usize::from(e.abs() <= 3.0 * se[i]);
        }
    }
    let rms = |sq: [f64; 3]| sq.map(|v| 1e3 * (v / seeds as f64).sqrt());
    let (rr, rp) = (rms(sq_refined), rms(sq_plain));
    let (c2, c3) = (within2 as f64 / n as f64, within3 as f64 / n as f64);
    eprintln!(
        "70 m, {seeds} seeds: RMS error refined {:.4} / {:.4} / {:.3} mm, sub-trajectory {:.4} / {:.4} / {:.3} mm; refined within 2 SE {:.1} %, 3 SE {:.1} %",
        rr[0], rr[1], rr[2], rp[0], rp[1], rp[2], 100.0 * c2, 100.0 * c3
    );
    write_results(
        "3_filter",
        &format!(
            "| sub-trajectories refined by the filter (the default), the filter's covariance | \
             {seeds} runs of the 70 m estimation path, simulator defaults, from \
             0.300/0.300/0.700 | {n} | {:.1} % | {:.1} % | - | 2 SE 85-100 %, 3 SE at least \
             97 % |\n",
            pct(within2, n),
            pct(within3, n)
        ),
    );
    write_results(
        "9_filter_rms",
        &format!(
            "\nOn those {seeds} runs of the 70 m path the refined estimate's RMS error is \
             {:.4} / {:.4} / {:.3} mm (left / right / track), the unrefined sub-trajectory \
             fit's {:.4} / {:.4} / {:.3} mm (held to: refined track below 0.8 times the \
             unrefined and below 0.32 mm; diameters below 0.025 mm and 1.3 times the unrefined).\n",
            rr[0], rr[1], rr[2], rp[0], rp[1], rp[2]
        ),
    );
    assert!(
        rr[2] < 0.8 * rp[2],
        "track: refined {} mm, sub-trajectory {} mm",
        rr[2],
        rp[2]
    );
    assert!(rr[2] < 0.32, "track: refined {} mm", rr[2]);
    for i in 0..2 {
        assert!(
            rr[i] < 0.025 && rr[i] < 1.3 * rp[i],
            "diameter {i}: {rr:?} {rp:?}"
        );
    }
    assert!((0.85..=1.0).contains(&c2), "within 2 SE: {c2}");
    assert!(c3 >= 0.97, "within 3 SE: {c3}");
}

/// The filter is linearised about its own estimate, so a long log is refined too (before,
/// linearised about the open-loop odometry, it refused a 1 km log at the default slip): the
/// linearisation bound is a small share of the diameters' standard errors, and the refined
/// geometry is within 3 of them of the truth.
#[test]
fn filter_refinement_holds_on_a_long_log() {
    let sim = common::sim(simulate::PathKind::Random, 1000.0, 1);
    let o = CalibrationOptions {
        fit_delta: false,
        ..Default::default()
    };
    let truth = common::truth();
    let c = calib::calibrate(&sim.samples, &sim.reference, ("s", "r"), &truth, &o).unwrap();
    let r = c.refinement.as_ref().unwrap();
    assert!(r.skipped.is_none(), "{:?}", r.skipped);
    let se = r.std_errors();
    println!(
        "1 km: linearisation bound {:.2e} of the lengths, diameters' standard errors {:.2e} / {:.2e} m",
        r.linearisation, se[0], se[1]
    );
    write_results(
        "9_long_log",
        &format!(
            "\nOn a 1 km random path (seed 1, simulator defaults) the filter's linearisation \
             bound is {:.1e} of the lengths ({:.3} um of the left diameter), against the \
             diameters' standard errors of {:.2} / {:.2} um (held to below a tenth of them).\n",
            r.linearisation,
            r.linearisation * truth.left_diameter * 1e6,
            se[0] * 1e6,
            se[1] * 1e6
        ),
    );
    assert!(
        r.linearisation > 0.0 && r.linearisation * truth.left_diameter < 0.1 * se[0],
        "{} against {se:?}",
        r.linearisation
    );
    let t = common::lengths(&truth);
    let v = common::lengths(&c.params);
    for i in 0..3 {
        assert!(
            (v[i] - t[i]).abs() < 3.0 * se[i],
            "{i}: {} {} {}",
            v[i],
            t[i],
            se[i]
        );
    }
}
