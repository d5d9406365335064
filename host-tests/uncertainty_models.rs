//! Monte Carlo check of the uncertainty models against simulated wheel slip.
//!
//! The same path is driven hundreds of times. Each run's true wheel distances are the
//! nominal `c_i dGamma_i` plus independent slip noise with variance `kappa_i |ds_i|` per
//! sample (the covariance model's assumption: variance proportional to distance rolled).
//! The integrator sees only the encoder counts; the truth is integrated in f64 from the
//! noisy distances. Over the runs, the fraction of final errors inside the predicted 1-sigma
//! and 3-sigma bands is compared with the nominal 68.3 % and 99.7 %.
//!
//! The paper's model is run on the same data with `delta` chosen so that its per-sample
//! wheel sigma equals the true per-sample slip sigma at the path's typical sample; its
//! coverage is printed and bounded to state how far it is from nominal.

use odo_unit::odometry::{
    ChassisParams, IndexRefs, Integrator, Pose, PoseSigma, UncertaintyModel, WheelCounts,
};
use std::f64::consts::PI;

use odo_testkit::reference::increments;
use odo_testkit::Rng;

const KAPPA: f64 = 2.0e-6; // m^2 per metre rolled: 1.4 mm after 1 m, 4.5 mm after 10 m
const RUNS: usize = 600;

/// The path: per-sample increments at 50 Hz, about 0.8 m/s, 40 m with turns both ways.
fn path(c: f64) -> Vec<[i64; 2]> {
    let per_sample = 0.8 / 50.0 / c; // counts per sample at 0.8 m/s
    let mut out = vec![];
    let segments: [(f64, f64, usize); 6] = [
        (1.0, 1.0, 500),  // straight 8 m
        (1.0, 0.5, 400),  // clockwise arc
        (1.0, 1.0, 500),  // straight
        (0.4, 1.0, 600),  // counter-clockwise arc
        (0.5, -0.5, 200), // pivot
        (1.0, 1.0, 500),  // straight
    ];
    let mut acc = [0.0f64; 2];
    for (l, r, n) in segments {
        for _ in 0..n {
            acc[0] += per_sample * l;
            acc[1] += per_sample * r;
            let d = [acc[0].round() as i64, acc[1].round() as i64];
            acc[0] -= d[0] as f64;
            acc[1] -= d[1] as f64;
            out.push(d);
        }
    }
    out
}

/// Fraction of runs whose |error| is within k sigma, for x, y, heading.
fn coverage(errors: &[[f64; 3]], sigmas: &[PoseSigma], k: f64) -> [f64; 3] {
    let mut inside = [0usize; 3];
    for (e, s) in errors.iter().zip(sigmas) {
        let s = [f64::from(s.x), f64::from(s.y), f64::from(s.heading)];
        for i in 0..3 {
            if e[i].abs() <= k * s[i] {
                inside[i] += 1;
            }
        }
    }
    inside.map(|n| n as f64 / errors.len() as f64)
}

/// Fraction of runs whose horizontal error lies inside the k-sigma ellipse of the x-y
/// covariance (nominal 39.3 % for k = 1, 98.9 % for k = 3).
fn ellipse_coverage(errors: &[[f64; 3]], sigmas: &[PoseSigma], k: f64) -> f64 {
    let mut inside = 0usize;
    for (e, s) in errors.iter().zip(sigmas) {
        let (sxx, syy, sxy) = (
            f64::from(s.x).powi(2),
            f64::from(s.y).powi(2),
            f64::from(s.cov_xy),
        );
        let det = sxx * syy - sxy * sxy;
        let d2 = (syy * e[0] * e[0] - 2.0 * sxy * e[0] * e[1] + sxx * e[1] * e[1]) / det;
        if d2 <= k * k {
            inside += 1;
        }
    }
    inside as f64 / errors.len() as f64
}

/// Independent slip of variance `KAPPA |s_i|` on each wheel's distances `s` of one sample.
fn wheel_slip(rng: &mut Rng, mut s: [f64; 2]) -> [f64; 2] {
    for si in &mut s {
        *si += (KAPPA * si.abs()).sqrt() * rng.normal();
    }
    s
}

/// Runs the Monte Carlo with `params` (the integrator's model), the truth's wheel distances
/// of each sample being the nominal ones through `slip`, from the generator's `seed`; returns
/// final errors and predicted sigmas, one per run.
fn monte_carlo(
    params: &ChassisParams,
    seed: u64,
    slip: impl Fn(&mut Rng, [f64; 2]) -> [f64; 2],
) -> (Vec<[f64; 3]>, Vec<PoseSigma>) {
    let c = PI * params.left_diameter / f64::from(params.ticks_per_rev);
    let w = params.track_width;
    let steps = path(c);
    let mut rng = Rng::new(seed);
    let (mut errors, mut sigmas) = (vec![], vec![]);
    for _ in 0..RUNS {
        let mut integ = Integrator::new(params, WheelCounts::default(), Pose::default()).unwrap();
        let (mut x, mut y, mut a) = (0.0f64, 0.0f64, 0.0f64);
        let mut g = [0i64; 2];
        for d in &steps {
            g = [g[0] + d[0], g[1] + d[1]];
            integ.step(
                WheelCounts {
                    left: g[0],
                    right: g[1],
                },
                IndexRefs::default(),
            );
            // Truth: nominal distances plus slip.
            let s = slip(&mut rng, [c * d[0] as f64, c * d[1] as f64]);
            let [da, dx, dy] = increments(s, a, w);
            (x, y, a) = (x + dx, y + dy, a + da);
        }
        let pose = integ.pose();
        errors.push([pose.x - x, pose.y - y, pose.heading - a]);
        sigmas.push(integ.sigma());
    }
    (errors, sigmas)
}

#[test]
fn covariance_model_coverage_is_near_nominal_and_paper_model_is_stated() {
    let covariance = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        kappa_left: KAPPA as f32,
        kappa_right: KAPPA as f32,
        ..ChassisParams::DESIGNED
    };
    let (errors, sigmas) = monte_carlo(&covariance, 0x5EED_1234, wheel_slip);
    let one = coverage(&errors, &sigmas, 1.0);
    let three = coverage(&errors, &sigmas, 3.0);
    let ellipse = ellipse_coverage(&errors, &sigmas, 1.0);
    println!("covariance model, {RUNS} runs: 1-sigma coverage x {:.3} y {:.3} heading {:.3} (nominal 0.683)", one[0], one[1], one[2]);
    println!(
        "covariance model: 3-sigma coverage x {:.3} y {:.3} heading {:.3} (nominal 0.997)",
        three[0], three[1], three[2]
    );
    println!("covariance model: 1-sigma ellipse coverage {ellipse:.3} (nominal 0.393)");
    // With 600 runs the binomial standard error of a 68.3 % fraction is 1.9 %: allow 3.5 of it.
    for i in 0..3 {
        assert!((one[i] - 0.683).abs() < 0.065, "1-sigma coverage {one:?}");
        assert!(three[i] > 0.98, "3-sigma coverage {three:?}");
    }
    assert!((ellipse - 0.393).abs() < 0.07, "ellipse coverage {ellipse}");

    // The paper's model with delta matched to the per-sample slip sigma of a full-speed sample
    // (sigma_s = sqrt(kappa * ds) = delta * dGamma).
    let c = PI * 0.26 / 20_000.0;
    let ds = 0.8 / 50.0;
    let delta = ((KAPPA * ds).sqrt() / (ds / c)) as f32;
    let paper = ChassisParams {
        delta_left: delta,
        delta_right: delta,
        ..ChassisParams::DESIGNED
    };
    let (errors, sigmas) = monte_carlo(&paper, 0x5EED_1234, wheel_slip);
    let one = coverage(&errors, &sigmas, 1.0);
    let three = coverage(&errors, &sigmas, 3.0);
    let mean_ratio: f64 = errors
        .iter()
        .zip(&sigmas)
        .map(|(e, s)| e[0].hypot(e[1]) / f64::from(s.horizontal()))
        .sum::<f64>()
        / RUNS as f64;
    println!(
        "paper model (delta {delta:.3e}): 1-sigma coverage x {:.3} y {:.3} heading {:.3}",
        one[0], one[1], one[2]
    );
    println!("paper model: 3-sigma coverage x {:.3} y {:.3} heading {:.3}; mean |e_h|/sigma_h {mean_ratio:.3}", three[0], three[1], three[2]);
    // The linear sums of eqs (26)-(28) add per-sample sigmas that are independent in truth:
    // the paper's bands are far wider than the errors (a worst case, as the paper says).
    for i in 0..3 {
        assert!(one[i] > 0.95, "paper 1-sigma coverage {one:?}");
    }
    assert!(mean_ratio < 0.2);
}

/// The calibration's geometry error in the covariance model: each run's true chassis has
/// diameters and a track width off by a draw from the stated standard errors and
/// correlations (`left_diameter_se`.. `right_track_correlation`); the integrator, with the
/// nominal values and no slip, must cover the resulting errors at the nominal rates.
#[test]
fn covariance_model_covers_the_calibrations_geometry_error() {
    use odo_unit::odometry::GeometryUncertainty;
    let g = GeometryUncertainty {
        left_diameter_se: 2.0e-5,
        right_diameter_se: 2.5e-5,
        track_width_se: 5.0e-4,
        diameters_correlation: 0.8,
        left_track_correlation: 0.3,
        right_track_correlation: -0.2,
    };
    let params = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        kappa_left: 0.0,
        kappa_right: 0.0,
        geometry_uncertainty: g,
        ..ChassisParams::DESIGNED
    };
    let c = PI * params.left_diameter / f64::from(params.ticks_per_rev);
    let w = params.track_width;
    let steps = path(c);
    // The integrator sees the same counts every run: one prediction.
    let mut integ = Integrator::new(&params, WheelCounts::default(), Pose::default()).unwrap();
    let mut gc = [0i64; 2];
    for d in &steps {
        gc = [gc[0] + d[0], gc[1] + d[1]];
        integ.step(
            WheelCounts {
                left: gc[0],
                right: gc[1],
            },
            IndexRefs::default(),
        );
    }
    let (nominal, sigma) = (integ.pose(), integ.sigma());
    // Relative standard errors and their Cholesky factor.
    let sd = [
        f64::from(g.left_diameter_se) / params.left_diameter,
        f64::from(g.right_diameter_se) / params.right_diameter,
        f64::from(g.track_width_se) / w,
    ];
    let r = [
        [
            1.0,
            f64::from(g.diameters_correlation),
            f64::from(g.left_track_correlation),
        ],
        [
            f64::from(g.diameters_correlation),
            1.0,
            f64::from(g.right_track_correlation),
        ],
        [
            f64::from(g.left_track_correlation),
            f64::from(g.right_track_correlation),
            1.0,
        ],
    ];
    let cov: Vec<Vec<f64>> = (0..3)
        .map(|i| (0..3).map(|j| r[i][j] * sd[i] * sd[j]).collect())
        .collect();
    let mut l = [[0.0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let s: f64 = (0..j).map(|k| l[i][k] * l[j][k]).sum();
            l[i][j] = if i == j {
                (cov[i][i] - s).sqrt()
            } else {
                (cov[i][j] - s) / l[j][j]
            };
        }
    }
    let mut rng = Rng::new(0x6E0_0001);
    let mut errors = vec![];
    for _ in 0..RUNS {
        let z = [rng.normal(), rng.normal(), rng.normal()];
        let e: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|k| l[i][k] * z[k]).sum())
            .collect();
        let (cl, cr, wt) = (c * (1.0 + e[0]), c * (1.0 + e[1]), w * (1.0 + e[2]));
        let (mut x, mut y, mut a) = (0.0f64, 0.0f64, 0.0f64);
        for d in &steps {
            let s = [cl * d[0] as f64, cr * d[1] as f64];
            let [da, dx, dy] = increments(s, a, wt);
            (x, y, a) = (x + dx, y + dy, a + da);
        }
        errors.push([nominal.x - x, nominal.y - y, nominal.heading - a]);
    }
    let sigmas = vec![sigma; errors.len()];
    let (c1, c3) = (
        coverage(&errors, &sigmas, 1.0),
        coverage(&errors, &sigmas, 3.0),
    );
    println!("geometry error: 1-sigma {c1:.3?}, 3-sigma {c3:.3?}, sigma {sigma:?}");
    for i in 0..3 {
        assert!((0.63..=0.74).contains(&c1[i]), "1-sigma {c1:?}");
        assert!(c3[i] >= 0.99, "3-sigma {c3:?}");
    }
    let e = ellipse_coverage(&errors, &sigmas, 1.0);
    assert!((0.34..=0.45).contains(&e), "1-sigma ellipse {e}");
    // An exact geometry adds nothing: the same steps give zero sigmas without slip.
    let exact = ChassisParams {
        geometry_uncertainty: GeometryUncertainty::EXACT,
        ..params
    };
    let mut integ = Integrator::new(&exact, WheelCounts::default(), Pose::default()).unwrap();
    integ.step(
        WheelCounts {
            left: 1000,
            right: 900,
        },
        IndexRefs::default(),
    );
    let s = integ.sigma();
    assert_eq!([s.x, s.y, s.heading, s.cov_xy], [0.0; 4]);
}

/// Opposite-phase slip in the covariance model (`kappa_diff`): each sample's true wheel
/// distances are `s_1 + e`, `s_2 - e` with `e` of variance `kappa_diff |s_1 - s_2|`; the
/// model's bands must cover the errors at the nominal rates, and a straight drive must add
/// nothing.
#[test]
fn covariance_model_covers_opposite_phase_slip() {
    const KAPPA_DIFF: f64 = 4.0e-5;
    let params = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        kappa_left: 0.0,
        kappa_right: 0.0,
        kappa_diff: KAPPA_DIFF as f32,
        ..ChassisParams::DESIGNED
    };
    let (errors, sigmas) = monte_carlo(&params, 0x0DD_0002, |rng, s| {
        let e = (KAPPA_DIFF * (s[0] - s[1]).abs()).sqrt() * rng.normal();
        [s[0] + e, s[1] - e]
    });
    let (c1, c3) = (
        coverage(&errors, &sigmas, 1.0),
        coverage(&errors, &sigmas, 3.0),
    );
    println!("opposite-phase slip: 1-sigma {c1:.3?}, 3-sigma {c3:.3?}");
    for i in 0..3 {
        assert!((0.63..=0.74).contains(&c1[i]), "1-sigma {c1:?}");
        assert!(c3[i] >= 0.99, "3-sigma {c3:?}");
    }
    // Equal wheel distances: no opposite-phase term.
    let mut integ = Integrator::new(&params, WheelCounts::default(), Pose::default()).unwrap();
    integ.step(
        WheelCounts {
            left: 1000,
            right: 1000,
        },
        IndexRefs::default(),
    );
    let s = integ.sigma();
    assert_eq!([s.x, s.y, s.heading, s.cov_xy], [0.0; 4]);
}

/// Gauss-Markov opposite-phase slip (`kappa_diff_corr`): each run's slip rate `eps` is a
/// Gauss-Markov process over the wheel-distance difference, of correlation length `L` and
/// stationary variance `kappa_diff / (2 L)`, and each sample's true wheel distances are
/// `s_1 + e`, `s_2 - e` with `e = eps |s_1 - s_2|` (as `odoctl`'s simulator makes turning
/// slip and its calibration filter fits it). The model with the matching `kappa_diff` and
/// `kappa_diff_corr` must cover the errors at the nominal rates at every checkpoint, early in
/// the first turn and after all of them; the white model of the same long-range rate
/// (`kappa_diff_corr` 0) is far too wide early in a turn, which is why the state exists.
#[test]
fn covariance_model_covers_gauss_markov_opposite_phase_slip() {
    const KAPPA_DIFF: f64 = 4.0e-4;
    const CORR: f64 = 2.0;
    let correlated = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        kappa_left: 0.0,
        kappa_right: 0.0,
        kappa_diff: KAPPA_DIFF as f32,
        kappa_diff_corr: CORR as f32,
        ..ChassisParams::DESIGNED
    };
    let white = ChassisParams {
        kappa_diff_corr: 0.0,
        ..correlated
    };
    let c = PI * correlated.left_diameter / f64::from(correlated.ticks_per_rev);
    let w = correlated.track_width;
    let steps = path(c);
    // Sample counts after which the errors are compared: 100 samples (0.8 m of wheel-distance
    // difference, 0.4 L) into the first arc, its end (3.2 m), the end of the second arc
    // (9 m) and of the path (12.2 m, after the pivot and 8 m straight).
    let checkpoints = [600, 900, 2000, steps.len()];
    let sigma_rate = (KAPPA_DIFF / (2.0 * CORR)).sqrt();
    let mut rng = Rng::new(0x0006_A055_0003);
    // Per model, per checkpoint: errors and sigmas.
    let mut errors = vec![vec![vec![]; checkpoints.len()]; 2];
    let mut sigmas = vec![vec![vec![]; checkpoints.len()]; 2];
    for _ in 0..RUNS {
        let mut integ = [&correlated, &white]
            .map(|p| Integrator::new(p, WheelCounts::default(), Pose::default()).unwrap());
        let (mut x, mut y, mut a) = (0.0f64, 0.0f64, 0.0f64);
        let mut g = [0i64; 2];
        // Stationary from the start.
        let mut eps = sigma_rate * rng.normal();
        let mut next = 0;
        for (k, d) in steps.iter().enumerate() {
            g = [g[0] + d[0], g[1] + d[1]];
            for i in &mut integ {
                i.step(
                    WheelCounts {
                        left: g[0],
                        right: g[1],
                    },
                    IndexRefs::default(),
                );
            }
            let s = [c * d[0] as f64, c * d[1] as f64];
            let diff = (s[0] - s[1]).abs();
            let rho = (-diff / CORR).exp();
            eps = rho * eps + (1.0 - rho * rho).sqrt() * sigma_rate * rng.normal();
            let e = eps * diff;
            let [da, dx, dy] = increments([s[0] + e, s[1] - e], a, w);
            (x, y, a) = (x + dx, y + dy, a + da);
            if k + 1 == checkpoints[next] {
                for (m, i) in integ.iter().enumerate() {
                    let p = i.pose();
                    errors[m][next].push([p.x - x, p.y - y, p.heading - a]);
                    sigmas[m][next].push(i.sigma());
                }
                next = (next + 1).min(checkpoints.len() - 1);
            }
        }
    }
    for (n, &at) in checkpoints.iter().enumerate() {
        let [c1, c3, w1, w3] = [(0, 1.0), (0, 3.0), (1, 1.0), (1, 3.0)]
            .map(|(m, k)| coverage(&errors[m][n], &sigmas[m][n], k));
        println!(
            "Gauss-Markov turning slip after {at} samples: 1-sigma {c1:.3?}, 3-sigma {c3:.3?}; \
             white model of the same kappa_diff: 1-sigma {w1:.3?}, 3-sigma {w3:.3?}"
        );
        for i in 0..3 {
            assert!((0.63..=0.74).contains(&c1[i]), "{at}: 1-sigma {c1:?}");
            assert!(c3[i] >= 0.99, "{at}: 3-sigma {c3:?}");
        }
        if at == checkpoints[0] {
            // Early in a turn the white model's sigma is several times the error's.
            for i in 0..3 {
                assert!(w1[i] > 0.9, "{at}: white 1-sigma {w1:?}");
            }
        }
    }
}

/// `kappa_diff_corr` 0 is the white model exactly, and so is a correlation length below
/// `MIN_TURN_CORRELATION` (its limit); a Gauss-Markov one gives other sigmas on a turn and
/// none on a straight line.
#[test]
fn turning_correlation_zero_or_tiny_is_the_white_model() {
    use odo_unit::odometry::uncertainty::MIN_TURN_CORRELATION;
    let run = |corr: f32, right: i64| {
        let p = ChassisParams {
            uncertainty_model: UncertaintyModel::Covariance,
            kappa_diff: 4.0e-4,
            kappa_diff_corr: corr,
            ..ChassisParams::DESIGNED
        };
        let mut integ = Integrator::new(&p, WheelCounts::default(), Pose::default()).unwrap();
        for k in 1..=500 {
            integ.step(
                WheelCounts {
                    left: 400 * k,
                    right: right * k,
                },
                IndexRefs::default(),
            );
        }
        (integ.sigma(), integ.heading_covariance())
    };
    let white = run(0.0, 200);
    assert_eq!(run(MIN_TURN_CORRELATION * 0.5, 200), white);
    let gm = run(2.0, 200);
    assert!(gm.0.heading < white.0.heading, "{gm:?} vs {white:?}");
    assert!(gm.0.heading > 0.0);
    // Straight: the opposite-phase slip adds nothing in either form.
    assert_eq!(run(2.0, 400), run(0.0, 400));
}

/// The uncertainty replayed over one integration's step geometries
/// (`Integrator::step_geometry`, then `PoseUncertainty::step`) is the integrator's own, bit
/// for bit, at any coefficients of either model: the geometries are recorded at other
/// coefficients than those replayed, and an over-range sample is skipped by both.
#[test]
fn replayed_uncertainty_is_the_integrators() {
    use odo_unit::odometry::{GeometryUncertainty, PoseUncertainty};
    let base = ChassisParams::DESIGNED;
    let mut counts = path(PI * base.left_diameter / f64::from(base.ticks_per_rev));
    // A counter misread: one sample over range, then the path goes on from it.
    counts.insert(1500, [1 << 20, 0]);
    let geometry = GeometryUncertainty {
        left_diameter_se: 3e-6,
        right_diameter_se: 4e-6,
        track_width_se: 4e-5,
        diameters_correlation: 0.3,
        left_track_correlation: -0.2,
        right_track_correlation: 0.1,
    };
    let cases = [
        ChassisParams {
            delta_left: 2e-6,
            delta_right: 3e-6,
            delta_diff: 1e-6,
            ..base
        },
        ChassisParams {
            uncertainty_model: UncertaintyModel::Covariance,
            kappa_left: 2e-6,
            kappa_right: 3e-6,
            kappa_diff: 1e-5,
            geometry_uncertainty: geometry,
            ..base
        },
        ChassisParams {
            uncertainty_model: UncertaintyModel::Covariance,
            kappa_left: 1e-6,
            kappa_diff: 2e-5,
            kappa_diff_corr: 0.5,
            ..base
        },
    ];
    let start = Pose {
        x: 1.0,
        y: -2.0,
        heading: 0.3,
    };
    let mut recorder = Integrator::new(&base, WheelCounts::default(), start).unwrap();
    let mut geometries = Vec::new();
    let mut total = [0i64; 2];
    for d in &counts {
        total = [total[0] + d[0], total[1] + d[1]];
        let c = WheelCounts {
            left: total[0],
            right: total[1],
        };
        geometries.push(recorder.step_geometry(c, IndexRefs::default()));
    }
    assert!(geometries[1500].0.overrange && geometries[1500].1.is_none());
    for p in cases {
        let mut integ = Integrator::new(&p, WheelCounts::default(), start).unwrap();
        let mut replay = PoseUncertainty::new(&p);
        let mut total = [0i64; 2];
        for (d, (status, g)) in counts.iter().zip(&geometries) {
            total = [total[0] + d[0], total[1] + d[1]];
            let c = WheelCounts {
                left: total[0],
                right: total[1],
            };
            assert_eq!(integ.step(c, IndexRefs::default()), *status);
            if let Some(g) = g {
                replay.step(g);
            }
            assert_eq!(replay.sigma(), integ.sigma(), "{p:?}");
            assert_eq!(replay.heading_covariance(), integ.heading_covariance());
        }
        assert!(integ.sigma().horizontal() > 0.0);
        assert_eq!(integ.pose(), recorder.pose());
    }
}
