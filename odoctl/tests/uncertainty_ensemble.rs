//! The calibrated uncertainty against the truth, over an ensemble of simulated runs.
//!
//! Per slip regime: twenty 70 m estimation runs (seeds 1-20) are each calibrated as a user
//! would (`calib::calibrate`, both models, the default criterion: sub-trajectory geometry
//! with its standard errors and correlations, which the covariance model carries), then
//! twenty runs of other seeds per calibration, both path kinds in turn, are replayed through
//! the core integrator from their true start pose with those parameters and compared with
//! the true poses at 10, 20, ..., 60 m of travel. Several calibrations, because every run
//! replayed with one calibration shares its geometry error.
//! Horizontal: `|e| <= k sigma_h`; heading: `|e| <= k sigma_heading`. Target for the model
//! `calibrate` selects by default (covariance): 1-sigma coverage in 60-76 % and 3-sigma at
//! least 97 % at every checkpoint, horizontal and heading (see [`regimes`]). The other model's
//! figures are printed (`--nocapture`) beside it;
//! `ODOCTL_ENSEMBLE_COVERAGE_CRITERION=1` adds the covariance model fitted by the paper's
//! coverage criterion; `ODOCTL_ENSEMBLE_FIGURES=DIR` draws each
//! regime's coverage and reliability figures there (`bench/run` draws them into `docs/figures/`).
//! `ODOCTL_ENSEMBLE_DEBUG=1` prints each second-generator calibration's kappa against the truth,
//! its geometry errors in standard errors and its own 3-sigma share.
//! `ODO_RESULTS_DIR=DIR` writes the tables there as Markdown (`bench/run` puts them into
//! docs/RESULTS.md with the figures).
//!
//! Slip regimes are named by the random-walk intensity `q` of a wheel's distance error
//! (m per sqrt(m) of its travel): the simulator's Gauss-Markov slip of standard deviation
//! `slip` and correlation length `L` gives a distance variance `2 slip^2 L d` for `d >> L`,
//! so `slip = q / sqrt(2 L)`.

use odo_unit::odometry::{ChassisParams, Integrator, Pose, UncertaintyModel};
use odoctl::calib::{
    self, CalibrationOptions, CheckpointCoverage, CheckpointSample, Ensemble, UncertaintyCriterion,
    CHECKPOINTS,
};
use odoctl::replay::{counts, index_refs};
use odoctl::simulate::{default_truth, simulate_path, PathKind, SimRun, SimSettings};

#[path = "generators/white_slip.rs"]
mod white_slip;

/// Runs per regime replayed against the truth.
const RUNS: u64 = 400;
/// Calibrations per regime (estimation runs of seeds 1..): each serves `RUNS /
/// CALIBRATIONS` of the replayed runs, so that the coverage also spans the calibration's own
/// error, which every run replayed with one calibration shares.
const CALIBRATIONS: u64 = 20;

/// What the coverage is held to: 1-sigma in `one_sigma..=one_sigma_max`, 3-sigma at least
/// `three_sigma`, at every checkpoint (docs/RESULTS.md, Uncertainty coverage, has the figures).
#[derive(Clone, Copy)]
struct Floor {
    one_sigma: f64,
    one_sigma_max: f64,
    three_sigma: f64,
}

const TARGET: Floor = Floor {
    one_sigma: 0.60,
    one_sigma_max: 0.76,
    three_sigma: 0.97,
};

struct Regime {
    name: &'static str,
    settings: SimSettings,
}

fn regime(name: &'static str, q: f64, corr: f64, slip_turn: f64) -> Regime {
    Regime {
        name,
        settings: SimSettings {
            slip: q / (2.0 * corr).sqrt(),
            slip_corr: corr,
            slip_turn,
            speed: 1.0,
            ..SimSettings::default()
        },
    }
}

fn regimes() -> Vec<Regime> {
    // 20 calibrations x 20 runs each: with fewer calibrations, whose geometry errors every run
    // replayed with one of them shares, 72 % cannot be told from 78 %. The figures are in
    // docs/RESULTS.md. Opposite-phase slip when turning is carried as the calibration fits it
    // (`kappa_diff` and `kappa_diff_corr`, a Gauss-Markov state, `kappa_diff` taken as its mean
    // over the likelihood); one 70 m run measures the slip rate's variance within a factor of
    // about 5 either way.
    vec![
        regime("q 0.0003", 0.0003, 0.1, 0.0),
        regime("q 0.001", 0.001, 0.1, 0.0),
        regime("q 0.003", 0.003, 0.1, 0.0),
        regime("q 0.001, Gauss-Markov 2 m", 0.001, 2.0, 0.0),
        regime("q 0.0005, turning slip 0.02", 0.0005, 0.1, 0.02),
    ]
}

/// Calibrates on the estimation run of `seed`: the parameters with both models'
/// coefficients.
fn calibrate(settings: SimSettings, criterion: UncertaintyCriterion, seed: u64) -> ChassisParams {
    let truth = default_truth();
    let run = simulate_path(
        PathKind::Estimation,
        70.0,
        truth,
        SimSettings { seed, ..settings },
    );
    let c = calib::calibrate(
        &run.samples,
        &run.reference,
        ("samples", "reference"),
        &ChassisParams::DESIGNED,
        &CalibrationOptions {
            models: vec![UncertaintyModel::Paper, UncertaintyModel::Covariance],
            criterion,
            ..CalibrationOptions::default()
        },
    )
    .expect("calibration");
    c.params
}

/// Replays the runs of `seeds` from their true start with `params` under each model (paper,
/// covariance) into `out`.
fn replay_runs(
    settings: SimSettings,
    params: &ChassisParams,
    seeds: std::ops::Range<u64>,
    out: &mut [Ensemble; 2],
) {
    let truth = default_truth();
    let models = [UncertaintyModel::Paper, UncertaintyModel::Covariance];
    for seed in seeds {
        let kind = if seed % 2 == 0 {
            PathKind::Estimation
        } else {
            PathKind::Validation
        };
        let run = simulate_path(
            kind,
            62.0,
            truth,
            SimSettings {
                seed: 1000 + seed,
                ..settings
            },
        );
        replay_run(&run, params, &models, out);
    }
}

/// Replays `run` from its true start with `params` under each of `models` into `out` (one
/// ensemble per model).
fn replay_run(
    run: &SimRun,
    params: &ChassisParams,
    models: &[UncertaintyModel],
    out: &mut [Ensemble],
) {
    let mut dist = Vec::with_capacity(run.truth.len());
    let mut d = 0.0;
    for (i, t) in run.truth.iter().enumerate() {
        if i > 0 {
            let p = run.truth[i - 1];
            d += (t.0 - p.0).hypot(t.1 - p.1);
        }
        dist.push(d);
    }
    for (m, ens) in models.iter().zip(out.iter_mut()) {
        let p = ChassisParams {
            uncertainty_model: *m,
            ..*params
        };
        let (x, y, h) = run.truth[0];
        let mut integ = Integrator::new(&p, counts(&run.samples[0]), Pose { x, y, heading: h })
            .expect("parameters");
        let mut rows = vec![CheckpointSample {
            horizontal: (0.0, 0.0),
            heading: Some((0.0, 0.0)),
        }];
        for (s, t) in run.samples[1..].iter().zip(&run.truth[1..]) {
            let _ = integ.step(counts(s), index_refs(s));
            let (o, sg) = (integ.pose(), integ.sigma());
            rows.push(CheckpointSample {
                horizontal: ((o.x - t.0).hypot(o.y - t.1), f64::from(sg.horizontal())),
                heading: Some((o.heading - t.2, f64::from(sg.heading))),
            });
        }
        ens.add_run(&dist, |i| rows[i]);
    }
}

/// Calibrates `CALIBRATIONS` times by `criterion` and replays `RUNS` runs, each with one of
/// the calibrations; prints the calibrations' geometry errors against their standard
/// errors. Returns the ensembles (paper, covariance) and the first calibration.
fn ensemble(
    name: &str,
    settings: SimSettings,
    criterion: UncertaintyCriterion,
) -> ([Ensemble; 2], ChassisParams) {
    ensemble_with(name, settings, criterion, |p| p)
}

/// [`ensemble`] with each calibration's parameters passed through `adjust` before the
/// replays.
fn ensemble_with(
    name: &str,
    settings: SimSettings,
    criterion: UncertaintyCriterion,
    adjust: impl Fn(ChassisParams) -> ChassisParams,
) -> ([Ensemble; 2], ChassisParams) {
    let t = default_truth();
    let mut out = [Ensemble::new(&CHECKPOINTS), Ensemble::new(&CHECKPOINTS)];
    let per = RUNS / CALIBRATIONS;
    let (mut first, mut err2, mut se2, mut within2) = (None, [0.0; 3], [0.0; 3], [0usize; 3]);
    let mut coefficients = Vec::new();
    for k in 0..CALIBRATIONS {
        let p = adjust(calibrate(settings, criterion, 1 + k));
        let g = p.geometry_uncertainty;
        let e = [
            p.left_diameter - t.left_diameter,
            p.right_diameter - t.right_diameter,
            p.track_width - t.track_width,
        ];
        let se = [g.left_diameter_se, g.right_diameter_se, g.track_width_se].map(f64::from);
        for i in 0..3 {
            err2[i] += e[i] * e[i];
            se2[i] += se[i] * se[i];
            within2[i] += usize::from(e[i].abs() <= 2.0 * se[i]);
        }
        first.get_or_insert(p);
        coefficients.push(format!(
            "{:.2e}/{:.2e}/{:.2}",
            p.kappa_left, p.kappa_diff, p.kappa_diff_corr
        ));
        replay_runs(settings, &p, 1000 + k * per..1000 + (k + 1) * per, &mut out);
    }
    let rms = |v: f64| (v / CALIBRATIONS as f64).sqrt() * 1e3;
    println!(
        "{name}: {CALIBRATIONS} calibrations, geometry error RMS {:.4} / {:.4} / {:.4} mm \
         (left / right / track), RMS standard error {:.4} / {:.4} / {:.4} mm, within 2 SE \
         {:?} of {CALIBRATIONS}",
        rms(err2[0]),
        rms(err2[1]),
        rms(err2[2]),
        rms(se2[0]),
        rms(se2[1]),
        rms(se2[2]),
        within2
    );
    println!(
        "{name}: kappa/kappa_diff/kappa_diff_corr per calibration {}",
        coefficients.join(" ")
    );
    (out, first.expect("one calibration"))
}

fn print_table(
    regime: &str,
    model: &str,
    criterion: &str,
    p: &ChassisParams,
    c: &[CheckpointCoverage],
) {
    let coefficient = if model == "paper" {
        format!(
            "delta {:.3e}, delta_diff {:.3e}",
            p.delta_left, p.delta_diff
        )
    } else {
        format!(
            "kappa {:.3e}, kappa_diff {:.3e}, kappa_diff_corr {:.2}",
            p.kappa_left, p.kappa_diff, p.kappa_diff_corr
        )
    };
    println!("{regime} | {model} ({criterion}; {coefficient})");
    for k in c {
        println!(
            "  {:>4.0} m  n {:>3}  horizontal {:>5.1} / {:>5.1} %   heading {:>5.1} / {:>5.1} %",
            k.distance,
            k.runs,
            100.0 * k.horizontal.0,
            100.0 * k.horizontal.1,
            100.0 * k.heading.0,
            100.0 * k.heading.1
        );
    }
}

/// Writes `text` to `$ODO_RESULTS_DIR/NAME.md` when that variable is set (`bench/run`).
fn write_results(name: &str, text: &str) {
    if let Some(dir) = std::env::var_os("ODO_RESULTS_DIR") {
        let path = std::path::Path::new(&dir).join(format!("{name}.md"));
        std::fs::write(&path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

/// The header of the coverage tables (Markdown).
fn table_header() -> String {
    let at = CHECKPOINTS.map(|d| format!("{d:.0}")).join("/");
    format!(
        "| slip regime | model (criterion) | horizontal 1σ at {at} m | heading 1σ at {at} m | 3σ lowest (horizontal / heading) |\n\
         | --- | --- | --- | --- | --- |\n"
    )
}

/// One row of the coverage tables: the 1-sigma shares at every checkpoint, the lowest
/// 3-sigma shares.
fn table_row(regime: &str, model: &str, c: &[CheckpointCoverage]) -> String {
    let one = |f: fn(&CheckpointCoverage) -> f64| {
        c.iter()
            .map(|k| format!("{:.0}", 100.0 * f(k)))
            .collect::<Vec<_>>()
            .join("/")
    };
    let lowest =
        |f: fn(&CheckpointCoverage) -> f64| 100.0 * c.iter().map(f).fold(f64::INFINITY, f64::min);
    format!(
        "| {regime} | {model} | {} % | {} % | {:.1} / {:.1} % |\n",
        one(|k| k.horizontal.0),
        one(|k| k.heading.0),
        lowest(|k| k.horizontal.1),
        lowest(|k| k.heading.1)
    )
}

/// The checkpoints where `c` is outside `floor` (1-sigma in `floor.one_sigma`..76 %, 3-sigma
/// at least `floor.three_sigma`), or not reached by every run.
fn misses(regime: &str, c: &[CheckpointCoverage], floor: Floor, runs: u64) -> Vec<String> {
    let mut out = Vec::new();
    for k in c {
        if k.runs as u64 != runs {
            out.push(format!(
                "{regime}: {} m reached by {} runs",
                k.distance, k.runs
            ));
        }
        for (what, (c1, c3)) in [("horizontal", k.horizontal), ("heading", k.heading)] {
            if !(floor.one_sigma..=floor.one_sigma_max).contains(&c1) || c3 < floor.three_sigma {
                out.push(format!(
                    "{regime}: {what} at {} m: 1-sigma {:.1} %, 3-sigma {:.1} %",
                    k.distance,
                    100.0 * c1,
                    100.0 * c3
                ));
            }
        }
    }
    out
}

#[test]
fn calibrated_uncertainty_covers_the_true_errors_across_slip_regimes() {
    // The model `calibrate` selects by default.
    let default_model = UncertaintyModel::Covariance;
    let mut failed = Vec::new();
    let mut table = format!(
        "Per slip regime, {CALIBRATIONS} calibrations on 70 m runs and {RUNS} runs replayed \
         from their true start, each with one of them. Target for the default model \
         (covariance, likelihood): 1-sigma {:.0}-{:.0} %, 3-sigma at least {:.0} %, at every \
         checkpoint (nominal 68.3 %; a round 2-D error covers 63.2 % inside `sigma_h`).\n\n{}",
        100.0 * TARGET.one_sigma,
        100.0 * TARGET.one_sigma_max,
        100.0 * TARGET.three_sigma,
        table_header()
    );
    for r in regimes() {
        let ([paper, covariance], params) =
            ensemble(r.name, r.settings, UncertaintyCriterion::Likelihood);
        if let Some(dir) = std::env::var_os("ODOCTL_ENSEMBLE_FIGURES") {
            let slug: String = r
                .name
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            odoctl::plots::ensemble_figures(
                std::path::Path::new(&dir),
                &format!("ensemble_{slug}"),
                &[("paper", &paper), ("covariance", &covariance)],
            )
            .expect("figures");
        }
        for (name, m, e) in [
            ("paper", UncertaintyModel::Paper, &paper),
            ("covariance", UncertaintyModel::Covariance, &covariance),
        ] {
            let c = e.coverage();
            // The default criterion: the filter's likelihood for kappa, the paper's coverage
            // criterion for delta.
            let criterion = match m {
                UncertaintyModel::Covariance => "likelihood",
                UncertaintyModel::Paper => "coverage",
            };
            print_table(r.name, name, criterion, &params, &c);
            let label = if m == default_model {
                format!("**{name} ({criterion}, default)**")
            } else {
                format!("{name} ({criterion})")
            };
            table.push_str(&table_row(r.name, &label, &c));
            if m == default_model {
                failed.extend(misses(r.name, &c, TARGET, RUNS));
            }
        }
        if std::env::var_os("ODOCTL_ENSEMBLE_COVERAGE_CRITERION").is_some() {
            let ([paper, covariance], params) =
                ensemble(r.name, r.settings, UncertaintyCriterion::Coverage);
            print_table(r.name, "paper", "coverage", &params, &paper.coverage());
            print_table(
                r.name,
                "covariance",
                "coverage",
                &params,
                &covariance.coverage(),
            );
        }
    }
    write_results("uncertainty_coverage", &table);
    assert!(
        failed.is_empty(),
        "the coverage target (60-76 % / >= 97 %) missed:\n{}",
        failed.join("\n")
    );
}

/// The unit's model of turning slip is the simulator's: with each calibration's `kappa_diff`
/// and `kappa_diff_corr` replaced by the simulated slip's (everything else as calibrated), the
/// covariance model meets the target. The simulator's rate of `slip_turn` over half the wheel-distance difference,
/// correlated over `slip_turn_corr` of it, is the unit's rate `slip_turn / 2` per metre of
/// the difference, correlated over `L = 2 slip_turn_corr`: `kappa_diff = 2 L (slip_turn /
/// 2)^2`. Measured: 60.5-66 % inside 1 sigma, at least 99.2 % inside 3 (calibrated: 63-74 %,
/// 97.2 %); held with a 3-point margin on the 1-sigma floor (one run of the 400 is half a
/// point).
#[test]
fn turning_slip_with_the_simulated_slips_coefficients_meets_the_target() {
    let r = regimes()
        .into_iter()
        .find(|r| r.settings.slip_turn > 0.0)
        .expect("a turning-slip regime");
    let (st, corr) = (r.settings.slip_turn, r.settings.slip_turn_corr);
    let l = 2.0 * corr;
    let kappa_diff = 2.0 * l * (0.5 * st).powi(2);
    let ([_, covariance], p) =
        ensemble_with(r.name, r.settings, UncertaintyCriterion::Likelihood, |p| {
            ChassisParams {
                kappa_diff: kappa_diff as f32,
                kappa_diff_corr: l as f32,
                ..p
            }
        });
    let c = covariance.coverage();
    print_table(r.name, "covariance", "simulated turning slip", &p, &c);
    let floor = Floor {
        one_sigma: 0.57,
        ..TARGET
    };
    write_results(
        "uncertainty_coverage_turning",
        &format!(
            "With each calibration's `kappa_diff` and `kappa_diff_corr` replaced by the simulated \
             turning slip's (`kappa_diff` {kappa_diff:.1e}, `kappa_diff_corr` {l} m; the rest as \
             calibrated; held to 1-sigma {:.0}-{:.0} %, 3-sigma at least {:.0} %):\n\n{}{}",
            100.0 * floor.one_sigma,
            100.0 * floor.one_sigma_max,
            100.0 * floor.three_sigma,
            table_header(),
            table_row(r.name, "covariance (simulated turning slip)", &c)
        ),
    );
    let failed = misses(r.name, &c, floor, RUNS);
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}

/// Without the geometry fit's own error: kappa of 70 m runs (seeds 1-20) against q^2. The
/// fit is unbiased within its standard error of the mean and about as spread as one run's
/// information allows. Measured (mean / standard deviation of `ln(kappa / q^2)`): q 0.001
/// -0.02 / 0.23, q 0.003 0.05 / 0.26; q 0.001 with L = 2 m -0.13 / 0.61. Against a motion
/// capture reference (0.5 mm at 100 Hz) with every metre's positions averaged whole, kappa
/// read about two thirds of q^2 (1.35e-7 against 2e-7 on the indoor bench's 300 m runs: the
/// along-track random walk's block means are smoother than its values); averaged over a short
/// span about the middle epoch it is held as the others.
/// Before the filter
/// was linearised about its own estimate and kept correlated slip only on a likelihood-ratio
/// test: 0.14 / 0.23 and 0.36 / 0.37 (the white-slip fit alone read 0.3-0.4 of the truth at
/// L = 2 m).
#[test]
fn the_filter_likelihood_recovers_kappa_with_the_true_geometry() {
    use odoctl::calib::{Innovations, Run};
    let mut table = String::from(
        "kappa fitted with the true geometry on 70 m runs (seeds 1-20), against the true q^2:\n\n\
         | slip | reference | mean of ln(kappa / q^2) | its standard deviation | held to (abs(mean) / sd) |\n\
         | --- | --- | ---: | ---: | ---: |\n",
    );
    // (q, L, reference: label, horizontal RMS m, rate Hz, limits).
    for (q, corr, (label, sigma, rate), mean_limit, sd_limit) in [
        (0.001, 0.1, ("RTK 8 mm, 50 Hz", 0.008, 50.0), 0.15, 0.4),
        (0.003, 0.1, ("RTK 8 mm, 50 Hz", 0.008, 50.0), 0.15, 0.4),
        (0.001, 2.0, ("RTK 8 mm, 50 Hz", 0.008, 50.0), 0.3, 0.7),
        (
            0.001,
            0.1,
            ("motion capture 0.5 mm, 100 Hz", 0.0005, 100.0),
            0.15,
            0.4,
        ),
    ] {
        let mut logs = Vec::new();
        for seed in 1u64..=20 {
            let truth = default_truth();
            let run = simulate_path(
                PathKind::Estimation,
                70.0,
                truth,
                SimSettings {
                    slip: q / (2.0f64 * corr).sqrt(),
                    slip_corr: corr,
                    speed: 1.0,
                    rtk_sigma: sigma,
                    rate,
                    seed,
                    ..SimSettings::default()
                },
            );
            let m =
                odoctl::csvio::match_or_fail(&run.samples, "s", &run.reference, "r", 10).unwrap();
            let r = Run::new(&run.samples, &run.reference, m);
            let inn = Innovations::new(&r, &truth, 0.3, sigma, 0.5f64.to_radians(), 1.0).unwrap();
            let (kappa, _) = inn.fit_correlated(1e-14, 1e-2, &Default::default());
            logs.push((kappa / (q * q)).ln());
        }
        let n = logs.len() as f64;
        let mean = logs.iter().sum::<f64>() / n;
        let sd = (logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        println!("q {q}, L {corr}: ln(kappa / q^2) mean {mean:.3}, sd {sd:.3}: {logs:.2?}");
        table.push_str(&format!(
            "| q {q}, correlated over {corr} m | {label} | {mean:+.3} | {sd:.3} | < {mean_limit} / < {sd_limit} |\n"
        ));
        assert!(
            mean.abs() < mean_limit && sd < sd_limit,
            "q {q}, L {corr}: mean {mean}, sd {sd}: {logs:?}"
        );
    }
    write_results("kappa_recovery", &table);
}

/// Calibrations per slip level on the second generator.
const SECOND_CALIBRATIONS: u64 = 20;
/// Tight-turning runs replayed with each of them.
const SECOND_RUNS_EACH: u64 = 20;

/// The least share of one calibration's errors inside 3 sigma.
const SINGLE_THREE_SIGMA: f64 = 0.90;

/// The share of the errors inside 3 sigma over all checkpoints, horizontal and heading alike.
fn three_sigma_share(c: &[CheckpointCoverage]) -> f64 {
    let (mut inside, mut all) = (0.0, 0.0);
    for k in c {
        inside += (k.horizontal.1 + k.heading.1) * k.runs as f64;
        all += 2.0 * k.runs as f64;
    }
    inside / all
}

/// The second generator ([`white_slip`]) at slip `q`: 6 mm per axis and 0.4 deg of reference
/// noise (not the first generator's 8 mm horizontal and 0.5 deg).
fn second_settings(q: f64) -> white_slip::Settings {
    white_slip::Settings {
        truth: default_truth(),
        q,
        sigma_axis: 0.006,
        heading_sigma: 0.4f64.to_radians(),
    }
}

/// A start pose of `seed`'s own: anywhere in a 100 m square, any heading.
fn second_start(seed: u64) -> (f64, f64, f64) {
    let f = |k: u64| {
        ((seed.wrapping_mul(2_654_435_761).wrapping_add(k * 40_503)) % 10_007) as f64 / 10_007.0
    };
    (
        100.0 * f(1) - 50.0,
        100.0 * f(2) - 50.0,
        2.0 * std::f64::consts::PI * f(3),
    )
}

/// The default calibration (covariance model, likelihood) of a gentle 70 m drive of the second
/// generator, told the reference noise as the options define it (horizontal RMS:
/// `sqrt(2)` times the per-axis sigma).
fn second_calibration(s: &white_slip::Settings, seed: u64) -> ChassisParams {
    let run = white_slip::run(
        white_slip::Course::Gentle,
        70.0,
        s,
        second_start(seed),
        seed,
    );
    calib::calibrate(
        &run.samples,
        &run.reference,
        ("samples", "reference"),
        &ChassisParams::DESIGNED,
        &CalibrationOptions {
            models: vec![UncertaintyModel::Covariance],
            reference_sigma: s.sigma_axis * 2f64.sqrt(),
            reference_heading_sigma: s.heading_sigma,
            ..CalibrationOptions::default()
        },
    )
    .expect("calibration")
    .params
}

/// The default model's coverage on data of a generator written apart from the simulator:
/// white slip, other paths (gentle calibration drives, tight-turning validation drives),
/// a 10 Hz reference with other noise, at three slip levels.
#[test]
fn calibrated_uncertainty_covers_the_true_errors_on_a_second_generator() {
    let mut failed = Vec::new();
    let runs = SECOND_CALIBRATIONS * SECOND_RUNS_EACH;
    let mut table = format!(
        "Second generator (odoctl/tests/generators/white_slip.rs: white slip, random-curvature \
         calibration drives, tight-turning validation drives, 10 Hz reference of 6 mm per axis \
         and 0.4 deg): per slip level, {SECOND_CALIBRATIONS} calibrations on gentle 70 m drives \
         and {runs} tight-turning runs replayed from their true start, each with one of them; \
         default model, same target.\n\n{}",
        table_header()
    );
    let mut lowest_single = f64::INFINITY;
    for q in [0.0003, 0.001, 0.003] {
        let name = format!("white q {q}");
        let s = second_settings(q);
        let mut out = [Ensemble::new(&CHECKPOINTS)];
        let (mut kappas, mut singles) = (Vec::new(), Vec::new());
        for k in 0..SECOND_CALIBRATIONS {
            let p = second_calibration(&s, 1 + k);
            kappas.push(format!("{:.2}", f64::from(p.kappa_left) / (q * q)));
            let mut single = [Ensemble::new(&CHECKPOINTS)];
            for r in 0..SECOND_RUNS_EACH {
                let seed = 500 + k * SECOND_RUNS_EACH + r;
                let run = white_slip::run(
                    white_slip::Course::Tight,
                    62.0,
                    &s,
                    second_start(seed),
                    seed,
                );
                replay_run(&run, &p, &[UncertaintyModel::Covariance], &mut out);
                replay_run(&run, &p, &[UncertaintyModel::Covariance], &mut single);
            }
            singles.push(three_sigma_share(&single[0].coverage()));
            if std::env::var_os("ODOCTL_ENSEMBLE_DEBUG").is_some() {
                let t = default_truth();
                let g = p.geometry_uncertainty;
                println!(
                    "  cal {k}: kappa/q2 {:.2} z(dl,dr,b) {:.2} {:.2} {:.2} 3sigma {:.1} %",
                    f64::from(p.kappa_left) / (q * q),
                    (p.left_diameter - t.left_diameter) / f64::from(g.left_diameter_se),
                    (p.right_diameter - t.right_diameter) / f64::from(g.right_diameter_se),
                    (p.track_width - t.track_width) / f64::from(g.track_width_se),
                    100.0 * singles.last().copied().unwrap_or(0.0)
                );
            }
        }
        println!("{name}: kappa / q^2 per calibration {}", kappas.join(" "));
        let c = out[0].coverage();
        print_table(&name, "covariance", "likelihood", &default_truth(), &c);
        let lowest = singles.iter().copied().fold(f64::INFINITY, f64::min);
        println!(
            "{name}: lowest 3-sigma share of a single calibration {:.1} %",
            100.0 * lowest
        );
        table.push_str(&table_row(
            &name,
            "**covariance (likelihood, default)**",
            &c,
        ));
        failed.extend(misses(&name, &c, TARGET, runs));
        if lowest < SINGLE_THREE_SIGMA {
            failed.push(format!(
                "{name}: a single calibration covers {:.1} % inside 3 sigma",
                100.0 * lowest
            ));
        }
        lowest_single = lowest_single.min(lowest);
    }
    table.push_str(&format!(
        "\nThe lowest share of one calibration's errors (all its runs, horizontal and heading, \
         every checkpoint) inside 3 sigma: {:.1} % (held to at least {:.0} %).\n",
        100.0 * lowest_single,
        100.0 * SINGLE_THREE_SIGMA
    ));
    write_results("uncertainty_coverage_second", &table);
    assert!(
        failed.is_empty(),
        "the coverage target (60-76 % / >= 97 %) missed on the second generator:\n{}",
        failed.join("\n")
    );
}
