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

use odo_core::odometry::{
    ChassisParams, IndexRefs, Integrator, Pose, PoseSigma, UncertaintyModel, WheelCounts,
};
use std::f64::consts::PI;

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
            f64::from(s.xy),
        );
        let det = sxx * syy - sxy * sxy;
        let d2 = (syy * e[0] * e[0] - 2.0 * sxy * e[0] * e[1] + sxx * e[1] * e[1]) / det;
        if d2 <= k * k {
            inside += 1;
        }
    }
    inside as f64 / errors.len() as f64
}

/// Runs the Monte Carlo with `params` (the integrator's model) and returns final errors and
/// predicted sigmas, one per run.
fn monte_carlo(params: &ChassisParams) -> (Vec<[f64; 3]>, Vec<PoseSigma>) {
    let c = PI * params.left_diameter / f64::from(params.ticks_per_rev);
    let w = params.track_width;
    let steps = path(c);
    let mut rng = Rng::new(0x5EED_1234);
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
            let mut s = [c * d[0] as f64, c * d[1] as f64];
            for si in &mut s {
                *si += (KAPPA * si.abs()).sqrt() * rng.normal();
            }
            let (ds, da) = ((s[0] + s[1]) / 2.0, (s[0] - s[1]) / w);
            let dd = if da == 0.0 {
                ds
            } else {
                ds * 2.0 / da * (da / 2.0).sin()
            };
            x += dd * (a + da / 2.0).sin();
            y += dd * (a + da / 2.0).cos();
            a += da;
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
    let (errors, sigmas) = monte_carlo(&covariance);
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
    let (errors, sigmas) = monte_carlo(&paper);
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
