//! Host tests of the odometry core against an f64 implementation of the paper's equations.
//!
//! The reference below is written straight from Jilek, Burian, Kriz: eqs (1)-(15) for the
//! pose, eqs (19)-(28) for the uncertainty, eqs (3)-(5) for the per-angle wheel function, in
//! f64 with `libm`-free std trigonometry. The firmware's integrator (fixed point, f32 and an
//! integer sin/cos kernel) must agree with it.

use odo_unit::odometry::trig;
use odo_unit::odometry::uncertainty::{StepGeometry, StepJacobian};
use odo_unit::odometry::{
    ChassisParams, CounterExtender, IndexRefs, Integrator, Pose, PoseSigma, UncertaintyModel,
    WheelCounts,
};
use proptest::prelude::*;

use odo_testkit::drive::drive_increments;
use odo_testkit::reference::{chord, increments, Reference};
use odo_testkit::{wobbly_wheels, Rng};
use std::f64::consts::{PI, TAU};

fn counts(c: [i64; 2]) -> WheelCounts {
    WheelCounts {
        left: c[0],
        right: c[1],
    }
}

fn refs(r: [Option<i64>; 2]) -> IndexRefs {
    IndexRefs {
        left: r[0],
        right: r[1],
    }
}

fn run_both(p: &ChassisParams, steps: &[[i64; 2]]) -> (Integrator, Reference) {
    let mut integ = Integrator::new(p, counts([0, 0]), Pose::default()).unwrap();
    let mut reference = Reference::new(p, [0, 0], Pose::default());
    let mut g = [0i64; 2];
    for d in steps {
        g = [g[0] + d[0], g[1] + d[1]];
        integ.step(counts(g), IndexRefs::default());
        reference.step(g, [None, None]);
    }
    (integ, reference)
}

fn heading_error(a: f64, b: f64) -> f64 {
    (a - b).abs()
}

// ---------------------------------------------------------------------------------------
// Encoder arithmetic, eq (1).

#[test]
fn counter_wraps_at_every_boundary_of_16_and_32_bits() {
    for bits in [16u32, 32] {
        let modulus: u64 = 1 << bits;
        let half = (modulus / 2) as i64;
        let mask = (modulus - 1) as u32;
        // Starting raw values at and around every wrap boundary; steps forward and backward
        // up to just under half the range.
        let starts = [
            0u64,
            1,
            modulus - 1,
            modulus - 2,
            modulus / 2,
            modulus / 2 - 1,
            modulus / 2 + 1,
        ];
        let deltas = [
            0i64,
            1,
            -1,
            2,
            -2,
            1000,
            -1000,
            half - 1,
            -(half - 1),
            -half,
        ];
        for &start in &starts {
            for &delta in &deltas {
                let start = start as u32 & mask;
                let mut ext = CounterExtender::new(bits, start);
                let base = ext.absolute();
                let raw = ((i64::from(start) + delta).rem_euclid(modulus as i64)) as u32;
                assert_eq!(
                    i64::from(ext.update(raw)),
                    delta,
                    "bits {bits} start {start} delta {delta}"
                );
                assert_eq!(ext.absolute(), base + delta);
            }
        }
    }
}

#[test]
fn counter_starts_signed_and_extends_far_beyond_its_width() {
    let mut ext = CounterExtender::new(16, 0xFFFF);
    assert_eq!(ext.absolute(), -1);
    // Five million increments forward in steps of 30,000, through 16-bit wraps.
    let mut raw = 0xFFFFu32;
    for _ in 0..(5_000_000 / 30_000) {
        raw = (raw + 30_000) & 0xFFFF;
        assert_eq!(ext.update(raw), 30_000);
    }
    assert_eq!(ext.absolute(), -1 + 30_000 * (5_000_000 / 30_000));
    assert_eq!(ext.bits(), 16);
    // A latched index count just after the last read maps onto the absolute count.
    assert_eq!(ext.absolute_of((raw + 5) & 0xFFFF), ext.absolute() + 5);
    assert_eq!(
        ext.absolute_of(raw.wrapping_sub(7) & 0xFFFF),
        ext.absolute() - 7
    );
}

proptest! {
    #[test]
    fn counter_extension_matches_true_count(bits in 2u32..=32, start in any::<i64>(), moves in prop::collection::vec(any::<i64>(), 1..200)) {
        let modulus = 1i128 << bits;
        let max = (1i64 << (bits - 1)) - 1;
        let raw_of = |g: i64| (i128::from(g).rem_euclid(modulus)) as u32;
        let start = start >> 2;
        let mut ext = CounterExtender::new(bits, raw_of(start));
        let offset = i128::from(start) - i128::from(ext.absolute());
        let mut truth = start;
        for m in moves {
            let step = if max == 0 { 0 } else { m % (max + 1) };
            truth = truth.wrapping_add(step);
            prop_assert_eq!(i64::from(ext.update(raw_of(truth))), step);
        }
        prop_assert_eq!(i128::from(ext.absolute()) + offset, i128::from(truth));
    }
}

// ---------------------------------------------------------------------------------------
// Trigonometry kernels.

#[test]
fn integer_sin_cos_is_within_its_bound_over_the_whole_circle() {
    let mut worst = 0.0f64;
    let n = 1u64 << 20;
    for k in 0..n {
        // Dense grid plus an irrational offset so the reduction boundaries are all exercised.
        let angle = k
            .wrapping_mul(u64::MAX / n)
            .wrapping_add(k.wrapping_mul(0x9E37_79B9));
        let (s, c) = trig::sin_cos(angle);
        let rad = angle as f64 * trig::RAD_PER_BINARY;
        worst = worst.max((f64::from(s) / f64::from(trig::Q30_ONE) - rad.sin()).abs());
        worst = worst.max((f64::from(c) / f64::from(trig::Q30_ONE) - rad.cos()).abs());
    }
    assert!(worst < trig::SIN_COS_MAX_ERROR, "worst error {worst:e}");
    // Exact at the cardinal directions, with the paper's orientation (0 = +y, clockwise).
    assert_eq!(trig::sin_cos(0), (0, trig::Q30_ONE));
    assert_eq!(trig::sin_cos(1 << 62), (trig::Q30_ONE, 0)); // quarter turn: east
    assert_eq!(trig::sin_cos(1 << 63), (0, -trig::Q30_ONE));
    assert_eq!(trig::sin_cos(3 << 62), (-trig::Q30_ONE, 0));
}

#[test]
fn chord_series_matches_sinc_and_is_smooth_at_zero() {
    let mut x = -PI / 2.0;
    while x <= PI / 2.0 {
        let exact = if x == 0.0 { 0.0 } else { 1.0 - x.sin() / x };
        let got = f64::from(trig::chord_defect(x as f32));
        assert!(
            (got - exact).abs() < 1e-7,
            "chord_defect({x}) = {got}, want {exact}"
        );
        let dexact = if x.abs() < 1e-6 {
            -x / 3.0
        } else {
            (x * x.cos() - x.sin()) / (x * x)
        };
        let dgot = f64::from(trig::sinc_derivative(x as f32));
        assert!(
            (dgot - dexact).abs() < 1e-7,
            "sinc'({x}) = {dgot}, want {dexact}"
        );
        x += 1e-3;
    }
    assert_eq!(trig::chord_defect(0.0), 0.0);
    assert_eq!(trig::sinc_derivative(0.0), 0.0);
}

#[test]
fn exp_neg_is_accurate_from_zero_to_underflow() {
    // Boundary table: zero, negative, NaN, infinity, the series' edge, the underflow edge.
    assert_eq!(trig::exp_neg(0.0), 1.0);
    assert_eq!(trig::exp_neg(-1.0), 1.0);
    assert_eq!(trig::exp_neg(f32::NAN), 0.0);
    assert_eq!(trig::exp_neg(f32::INFINITY), 0.0);
    assert_eq!(trig::exp_neg(87.0), 0.0);
    assert!(trig::exp_neg(86.9) > 0.0);
    let mut worst = 0.0f64;
    // Tiny arguments (a sample's wheel-distance difference over a correlation length) up to
    // the underflow edge, both sides of the series' edge 1/16.
    let mut x = 1e-12f32;
    while x < 86.9 {
        for v in [x, x.next_up(), 0.0625f32.next_down(), 0.0625] {
            let got = f64::from(trig::exp_neg(v));
            let want = (-f64::from(v)).exp();
            worst = worst.max(((got - want) / want).abs());
        }
        x *= 1.01;
    }
    assert!(worst < 3e-7, "worst relative error {worst:e}");
    // Monotone non-increasing over a fine grid of [0, 2].
    let mut prev = 1.0f32;
    for i in 0..=20_000 {
        let v = trig::exp_neg(i as f32 * 1e-4);
        assert!(v <= prev && (0.0..=1.0).contains(&v), "{i}: {v} > {prev}");
        prev = v;
    }
}

#[test]
fn square_root_is_accurate_over_the_f32_range() {
    assert_eq!(trig::sqrt(0.0), 0.0);
    assert_eq!(trig::sqrt(-1.0), 0.0);
    assert_eq!(trig::sqrt(f32::NAN), 0.0);
    let mut x = 1e-30f32;
    while x < 1e30 {
        let got = f64::from(trig::sqrt(x));
        let want = f64::from(x).sqrt();
        assert!(
            ((got - want) / want).abs() < 3e-7,
            "sqrt({x}) = {got}, want {want}"
        );
        x *= 1.0371;
    }
}

// ---------------------------------------------------------------------------------------
// Pose: boundary cases.

#[test]
fn straight_line_along_each_axis() {
    // Heading 0 drives north (+y); heading pi/2 drives east (+x): clockwise from +y.
    let p = ChassisParams::DESIGNED;
    for (heading, dir) in [
        (0.0, (0.0, 1.0)),
        (PI / 2.0, (1.0, 0.0)),
        (PI, (0.0, -1.0)),
        (-PI / 2.0, (-1.0, 0.0)),
    ] {
        let mut integ = Integrator::new(
            &p,
            counts([0, 0]),
            Pose {
                x: 0.0,
                y: 0.0,
                heading,
            },
        )
        .unwrap();
        let per_step = 500;
        for k in 1..=1000 {
            integ.step(counts([k * per_step, k * per_step]), IndexRefs::default());
        }
        let d = PI * 0.26 / 20_000.0 * 500_000.0;
        let pose = integ.pose();
        assert!(
            (pose.x - d * dir.0).abs() < 1e-6 && (pose.y - d * dir.1).abs() < 1e-6,
            "{pose:?}"
        );
        assert!((pose.heading - heading).abs() < 1e-12);
    }
}

#[test]
fn pure_rotation_in_place_keeps_position_and_turns_clockwise() {
    let p = ChassisParams::DESIGNED;
    let mut integ = Integrator::new(
        &p,
        counts([0, 0]),
        Pose {
            x: 3.0,
            y: -2.0,
            heading: 0.0,
        },
    )
    .unwrap();
    // Left forward, right backward: the chassis turns clockwise (alpha grows).
    for k in 1..=2000 {
        integ.step(counts([k * 37, -k * 37]), IndexRefs::default());
    }
    let c = PI * 0.26 / 20_000.0;
    let pose = integ.pose();
    assert_eq!(pose.x, 3.0);
    assert_eq!(pose.y, -2.0);
    assert!((pose.heading - 2.0 * c * 74_000.0 / 0.563).abs() < 1e-9);
    assert!(
        pose.heading > TAU,
        "more than a turn, unwrapped: {}",
        pose.heading
    );
}

#[test]
fn full_circle_of_known_radius_closes() {
    // Constant wheel ratio: every sample is an arc of the same circle, so the chord formula
    // puts each sample exactly on it. Radius R of the centre point, turning clockwise (left
    // wheel outside), starting north: centre at (R, 0).
    let p = ChassisParams::DESIGNED;
    let c = PI * 0.26 / 20_000.0;
    let w = 0.563;
    for r in [0.5f64, 2.0, 10.0] {
        let (ratio_l, ratio_r) = (r + w / 2.0, r - w / 2.0);
        // Samples of 200 (outer) increments; enough of them for one whole turn.
        let per_turn_outer = TAU * ratio_l / c;
        let steps = (per_turn_outer / 200.0).round() as i64;
        let inner = (200.0 * ratio_r / ratio_l).round() as i64;
        let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
        for k in 1..=steps {
            integ.step(counts([k * 200, k * inner]), IndexRefs::default());
        }
        // The circle actually driven, from the integer counts.
        let (s1, s2) = (c * (steps * 200) as f64, c * (steps * inner) as f64);
        let alpha = (s1 - s2) / w;
        let radius = (s1 + s2) / 2.0 / alpha;
        let pose = integ.pose();
        assert!((pose.heading - alpha).abs() < 1e-9);
        assert!(
            (pose.x - radius * (1.0 - alpha.cos())).abs() < 1e-6,
            "R {r}: {pose:?}"
        );
        assert!(
            (pose.y - radius * alpha.sin()).abs() < 1e-6,
            "R {r}: {pose:?}"
        );
        // About one whole turn: the chassis is back near its start.
        assert!((alpha - TAU).abs() < 0.05, "R {r}: turned {alpha} rad");
        assert!(pose.x.hypot(pose.y) < 2.0 * radius * (alpha / 2.0).sin().abs() + 1e-6);
    }
}

#[test]
fn reversing_retraces_exactly() {
    let p = ChassisParams::DESIGNED;
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let mut rng = Rng::new(7);
    let path = drive_increments(&mut rng, 5000, 1.0 / (PI * 0.26 / 20_000.0), 50.0);
    let mut g = [0i64; 2];
    for d in &path {
        g = [g[0] + d[0], g[1] + d[1]];
        integ.step(counts(g), IndexRefs::default());
    }
    let far = integ.pose();
    assert!(far.x.hypot(far.y) > 1.0);
    for d in path.iter().rev() {
        g = [g[0] - d[0], g[1] - d[1]];
        integ.step(counts(g), IndexRefs::default());
    }
    let pose = integ.pose();
    assert!(pose.x.abs() < 1e-8 && pose.y.abs() < 1e-8, "{pose:?}");
    assert!(pose.heading.abs() < 1e-15);
    // Uncertainty only grows: backing up does not undo it.
    assert!(integ.sigma().horizontal() > 0.0);
}

#[test]
fn zero_length_samples_change_nothing() {
    let p = ChassisParams::DESIGNED;
    let mut integ = Integrator::new(
        &p,
        counts([100, 200]),
        Pose {
            x: 1.0,
            y: 2.0,
            heading: 0.3,
        },
    )
    .unwrap();
    integ.step(counts([5100, 4200]), IndexRefs::default());
    let (pose, sigma) = (integ.pose(), integ.sigma());
    for _ in 0..1000 {
        let st = integ.step(counts([5100, 4200]), IndexRefs::default());
        assert!(!st.overrange);
    }
    assert_eq!(integ.pose(), pose);
    assert_eq!(integ.sigma(), sigma);
}

#[test]
fn overrange_sample_is_flagged_and_not_integrated() {
    let p = ChassisParams::DESIGNED;
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let st = integ.step(counts([1 << 19, 0]), IndexRefs::default());
    assert!(st.overrange);
    assert_eq!(integ.pose(), Pose::default());
    // The counts are the new starting point.
    let st = integ.step(counts([(1 << 19) + 100, 100]), IndexRefs::default());
    assert!(!st.overrange);
    assert!(integ.pose().y > 0.0 && integ.pose().heading.abs() < 1e-12);
    // A sample whose heading change would exceed pi/2.
    let st = integ.step(
        counts([(1 << 19) + 100 + 120_000, 100 - 120_000]),
        IndexRefs::default(),
    );
    assert!(st.overrange);
}

/// A pose beyond the fixed-point range is reported by `check_range` and
/// clamped by `reset_pose`, so the steps after it cannot overflow (they wrapped in release
/// and panicked with overflow checks before).
#[test]
fn pose_beyond_the_fixed_point_range_is_refused_or_clamped() {
    use odo_unit::odometry::integrator::{MAX_HEADING, MAX_POSITION};
    use odo_unit::odometry::PoseRangeError;
    let pose = |x, y, heading| Pose { x, y, heading };
    assert_eq!(
        pose(MAX_POSITION, -MAX_POSITION, -MAX_HEADING).check_range(),
        Ok(())
    );
    assert_eq!(pose(2.2e9, 0.0, 0.0).check_range(), Err(PoseRangeError::X));
    assert_eq!(
        pose(f64::NAN, 0.0, 0.0).check_range(),
        Err(PoseRangeError::X)
    );
    assert_eq!(pose(0.0, -1e300, 0.0).check_range(), Err(PoseRangeError::Y));
    assert_eq!(
        pose(0.0, 0.0, -6e19).check_range(),
        Err(PoseRangeError::Heading)
    );
    assert_eq!(
        pose(0.0, 0.0, f64::INFINITY).check_range(),
        Err(PoseRangeError::Heading)
    );

    let p = ChassisParams::DESIGNED;
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    for start in [
        pose(1e300, -1e300, -6e19),
        pose(-2.2e9, 2.2e9, 6e19),
        pose(MAX_POSITION, MAX_POSITION, MAX_HEADING),
    ] {
        integ.reset_pose(start);
        let at = integ.pose();
        assert_eq!(at.x.abs(), MAX_POSITION, "{start:?} -> {at:?}");
        assert_eq!(at.y.abs(), MAX_POSITION, "{start:?} -> {at:?}");
        assert!(
            (at.heading.abs() - MAX_HEADING).abs() < 1e-3,
            "{start:?} -> {at:?}"
        );
        // Full-range samples in every direction: no overflow, the pose moves.
        let mut g = integ.counts();
        for d in [[200_000, 200_000], [-200_000, -200_000], [10_000, -10_000]] {
            g = counts([g.left + d[0], g.right + d[1]]);
            assert!(!integ.step(g, IndexRefs::default()).overrange);
        }
        assert!(integ.pose().x.is_finite() && integ.pose().heading.is_finite());
    }
}

#[test]
fn bad_parameters_are_refused_and_change_nothing() {
    let mut p = ChassisParams::DESIGNED;
    p.track_width = f64::NAN;
    assert!(Integrator::new(&p, counts([0, 0]), Pose::default()).is_err());
    let mut integ =
        Integrator::new(&ChassisParams::DESIGNED, counts([0, 0]), Pose::default()).unwrap();
    integ.step(counts([1000, 900]), IndexRefs::default());
    let before = (integ.pose(), integ.sigma(), *integ.params());
    for bad in [
        ChassisParams {
            left_diameter: -0.26,
            ..ChassisParams::DESIGNED
        },
        ChassisParams {
            ticks_per_rev: 0,
            ..ChassisParams::DESIGNED
        },
        ChassisParams {
            ticks_per_rev: 8,
            ..ChassisParams::DESIGNED
        },
        ChassisParams {
            delta_left: f32::INFINITY,
            ..ChassisParams::DESIGNED
        },
        ChassisParams {
            track_width: 1e9,
            ..ChassisParams::DESIGNED
        },
    ] {
        assert!(integ.set_params(&bad).is_err(), "{bad:?}");
        assert_eq!((integ.pose(), integ.sigma(), *integ.params()), before);
    }
}

// ---------------------------------------------------------------------------------------
// Per-angle wheel function, eqs (3)-(5), referenced by the index line.

#[test]
fn wheel_function_needs_the_index_and_matches_eq_5() {
    let p = wobbly_wheels();
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let mut reference = Reference::new(&p, [0, 0], Pose::default());
    let mut g = [0i64; 2];
    // Before any index pulse: eq (6), and the status says the function is not in use.
    for _ in 0..50 {
        g = [g[0] + 313, g[1] + 297];
        let st = integ.step(counts(g), IndexRefs::default());
        assert!(!st.left_referenced && !st.right_referenced);
        reference.step(g, [None, None]);
    }
    assert!((integ.pose().y - reference.y).abs() < 1e-9);
    // Index pulses latched at these counts; re-latched every turn as the wheel passes them.
    let mut idx = [4_321i64, 17_000];
    for _ in 0..3000 {
        g = [g[0] + 313, g[1] + 297];
        while g[0] - idx[0] >= 20_000 {
            idx[0] += 20_000;
        }
        while g[1] - idx[1] >= 20_000 {
            idx[1] += 20_000;
        }
        let st = integ.step(counts(g), refs([Some(idx[0]), Some(idx[1])]));
        assert!(st.left_referenced && st.right_referenced);
        reference.step(g, [Some(idx[0]), Some(idx[1])]);
    }
    let (a, b) = (integ.pose(), reference);
    assert!(
        (a.x - b.x).abs() < 1e-6 && (a.y - b.y).abs() < 1e-6,
        "{a:?} vs ({}, {})",
        b.x,
        b.y
    );
    assert!((a.heading - b.alpha).abs() < 1e-8);
}

#[test]
fn wheel_function_cancels_over_whole_turns_and_differs_within_one() {
    let p = wobbly_wheels();
    // Straight-ish: both wheels exactly one turn, from a referenced phase.
    let start = [1_234i64, 5_678];
    let index = refs([Some(0), Some(0)]);
    let mut integ = Integrator::new(&p, counts(start), Pose::default()).unwrap();
    for k in 1..=100 {
        integ.step(counts([start[0] + 200 * k, start[1] + 200 * k]), index);
    }
    let round =
        Integrator::new(&ChassisParams::DESIGNED, counts(start), Pose::default()).map(|mut r| {
            for k in 1..=100 {
                r.step(counts([start[0] + 200 * k, start[1] + 200 * k]), index);
            }
            r.pose()
        });
    let round = round.unwrap();
    // Same total distance per wheel over a whole turn: nearly the same end point.
    assert!((integ.pose().heading - round.heading).abs() < 1e-9);
    // But half a turn differs by the periodic part.
    let mut half = Integrator::new(&p, counts(start), Pose::default()).unwrap();
    half.step(counts([start[0] + 10_000, start[1]]), index);
    let mut half_round =
        Integrator::new(&ChassisParams::DESIGNED, counts(start), Pose::default()).unwrap();
    half_round.step(counts([start[0] + 10_000, start[1]]), index);
    assert!((half.pose().heading - half_round.pose().heading).abs() > 1e-6);
}

#[test]
fn index_changing_by_non_whole_turns_is_followed() {
    // A re-latched index that moved by counts that are not a whole turn (a fault the firmware
    // flags): the integrator follows the newest latch without a jump beyond the periodic term.
    let p = wobbly_wheels();
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let mut g = 0i64;
    for k in 0..400 {
        g += 250;
        let idx = if k < 200 { 0 } else { 137 };
        integ.step(counts([g, g]), refs([Some(idx), Some(idx)]));
    }
    let pose = integ.pose();
    let straight = PI * 0.26 / 20_000.0 * g as f64;
    assert!((pose.y.hypot(pose.x) - straight).abs() < 0.01, "{pose:?}");
}

// ---------------------------------------------------------------------------------------
// Uncertainty, eqs (19)-(28).

#[test]
fn jacobian_matches_finite_differences() {
    let w = 0.563f64;
    let mut rng = Rng::new(42);
    for _ in 0..2000 {
        let s = [(rng.uniform() - 0.5) * 0.2, (rng.uniform() - 0.5) * 0.2];
        let alpha = rng.uniform() * TAU * 3.0 - TAU;
        let inc = increments(s, alpha, w);
        let theta = alpha + inc[0] / 2.0;
        let ds = (s[0] + s[1]) / 2.0;
        let chord_len = chord(ds, inc[0]);
        let g = StepGeometry {
            abs_counts: [0.0; 2],
            abs_count_difference: 0.0,
            wheel_distance: [s[0] as f32, s[1] as f32],
            ds: ds as f32,
            dalpha: inc[0] as f32,
            chord: chord_len as f32,
            sin: theta.sin() as f32,
            cos: theta.cos() as f32,
            inv_track: (1.0 / w) as f32,
        };
        let j = StepJacobian::of(&g);
        let h = 1e-7;
        for i in 0..2 {
            let (mut up, mut down) = (s, s);
            up[i] += h;
            down[i] -= h;
            let (fu, fd) = (increments(up, alpha, w), increments(down, alpha, w));
            let fd_row: Vec<f64> = (0..3).map(|r| (fu[r] - fd[r]) / (2.0 * h)).collect();
            let got = [j.dalpha[i], j.dx[i], j.dy[i]];
            for r in 0..3 {
                assert!(
                    (f64::from(got[r]) - fd_row[r]).abs() < 2e-6,
                    "d{r}/ds{i}: {} vs {}",
                    got[r],
                    fd_row[r]
                );
            }
        }
        // With respect to the previous heading.
        let fu = increments(s, alpha + 1e-7, w);
        let fd = increments(s, alpha - 1e-7, w);
        assert!((f64::from(j.dx_dalpha) - (fu[1] - fd[1]) / 2e-7).abs() < 1e-6);
        assert!((f64::from(j.dy_dalpha) - (fu[2] - fd[2]) / 2e-7).abs() < 1e-6);
    }
}

#[test]
fn paper_uncertainty_matches_f64_reference_and_table_3_scale() {
    let p = ChassisParams::DESIGNED;
    let mut rng = Rng::new(3);
    let steps = drive_increments(&mut rng, 200_000, 1.0 / (PI * 0.26 / 20_000.0), 50.0);
    let (integ, reference) = run_both(&p, &steps);
    let sigma = integ.sigma();
    for (got, want) in [
        (sigma.x, reference.sigma_x),
        (sigma.y, reference.sigma_y),
        (sigma.heading, reference.sigma_alpha),
    ] {
        assert!(
            ((f64::from(got) - want) / want).abs() < 1e-4,
            "{got} vs {want}"
        );
    }
    assert_eq!(sigma.cov_xy, 0.0);
    // Straight north only, 100 m at delta = 3.9e-8 m/increment: closed forms of the paper's
    // sums. Per step sigma_dy = sqrt(2)/2 * delta * n; sigma_dalpha = sqrt(2) * delta * n / w;
    // sigma_dx = sqrt(2) * dd/(2w) * delta * n + dd * sigma_alpha(before), which is where
    // the paper's linear sums make x (across the track) grow quadratically.
    let mut straight = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let per_step = 400i64;
    let n = (100.0 / (PI * 0.26 / 20_000.0) / per_step as f64) as i64;
    for k in 1..=n {
        straight.step(counts([k * per_step, k * per_step]), IndexRefs::default());
    }
    let sn = 3.9e-8 * per_step as f64;
    let dd = PI * 0.26 / 20_000.0 * per_step as f64;
    let (w, r2) = (0.563, 2.0f64.sqrt());
    let (mut want_x, mut want_a) = (0.0, 0.0);
    for _ in 0..n {
        want_x += r2 * dd / (2.0 * w) * sn + dd * want_a;
        want_a += r2 * sn / w;
    }
    let want_y = n as f64 * 0.5 * r2 * sn;
    let got = straight.sigma();
    for (got, want) in [(got.y, want_y), (got.x, want_x), (got.heading, want_a)] {
        assert!(
            ((f64::from(got) - want) / want).abs() < 1e-5,
            "{got} vs {want}"
        );
    }
}

#[test]
fn delta_diff_adds_heading_uncertainty_only_when_turning() {
    let base = ChassisParams::DESIGNED;
    let with = ChassisParams {
        delta_diff: 2e-8,
        ..base
    };
    let straight: Vec<[i64; 2]> = (0..1000).map(|_| [300, 300]).collect();
    let turning: Vec<[i64; 2]> = (0..1000).map(|_| [300, 100]).collect();
    let (a, _) = run_both(&base, &straight);
    let (b, _) = run_both(&with, &straight);
    assert_eq!(a.sigma(), b.sigma());
    let (a, _) = run_both(&base, &turning);
    let (b, _) = run_both(&with, &turning);
    assert!(b.sigma().heading > a.sigma().heading * 1.1);
}

#[test]
fn covariance_model_is_independent_of_the_sampling_rate() {
    let p = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        ..ChassisParams::DESIGNED
    };
    let counts_per_metre = 1.0 / (PI * 0.26 / 20_000.0);
    let mut sigmas = vec![];
    for rate in [50.0, 1000.0] {
        let mut rng = Rng::new(11);
        // The same path at two rates: one sample per 20 ms, or 20 per 20 ms.
        let coarse = drive_increments(&mut rng, 20_000, counts_per_metre, 50.0);
        let factor = (rate / 50.0) as i64;
        let mut steps = vec![];
        for d in coarse {
            let mut done = [0i64; 2];
            for k in 1..=factor {
                let part = [d[0] * k / factor - done[0], d[1] * k / factor - done[1]];
                done = [done[0] + part[0], done[1] + part[1]];
                steps.push(part);
            }
        }
        let (integ, _) = run_both(&p, &steps);
        sigmas.push(integ.sigma());
    }
    let (a, b) = (sigmas[0], sigmas[1]);
    assert!(a.x > 0.0 && a.heading > 0.0);
    for (u, v) in [(a.x, b.x), (a.y, b.y), (a.heading, b.heading)] {
        assert!(((u - v) / u).abs() < 0.01, "{a:?} vs {b:?}");
    }
}

// ---------------------------------------------------------------------------------------
// Long drives against the f64 reference.

#[test]
fn ten_kilometre_drive_at_50_hz_matches_f64_reference() {
    let p = ChassisParams {
        left_diameter: 0.2608,
        right_diameter: 0.2607,
        track_width: 0.5656,
        ..ChassisParams::DESIGNED
    };
    let counts_per_metre = 20_000.0 / (PI * 0.2608);
    let mut rng = Rng::new(2024);
    // About 1 m/s for 10 km of path: count the path as we go.
    let mut steps = vec![];
    let mut path = 0.0;
    while path < 10_000.0 {
        let chunk = drive_increments(&mut rng, 10_000, counts_per_metre, 50.0);
        for d in chunk {
            path += (d[0].abs() + d[1].abs()) as f64 / 2.0 / counts_per_metre;
            steps.push(d);
        }
    }
    // Read the counts through 16-bit counters, as the hardware does.
    let mut ext = [CounterExtender::new(16, 0), CounterExtender::new(16, 0)];
    let mut integ = Integrator::new(&p, counts([0, 0]), Pose::default()).unwrap();
    let mut reference = Reference::new(&p, [0, 0], Pose::default());
    let mut g = [0i64; 2];
    for d in &steps {
        g = [g[0] + d[0], g[1] + d[1]];
        let raw = [(g[0] as u64 & 0xFFFF) as u32, (g[1] as u64 & 0xFFFF) as u32];
        ext[0].update(raw[0]);
        ext[1].update(raw[1]);
        assert_eq!([ext[0].absolute(), ext[1].absolute()], g);
        integ.step(counts(g), IndexRefs::default());
        reference.step(g, [None, None]);
    }
    let pose = integ.pose();
    let (ex, ey) = (pose.x - reference.x, pose.y - reference.y);
    let ea = heading_error(pose.heading, reference.alpha);
    println!(
        "10 km, {} samples: position error {:.3e} m, heading error {:.3e} rad; far from origin: {:.0} m",
        steps.len(),
        ex.hypot(ey),
        ea,
        reference.x.hypot(reference.y)
    );
    assert!(ex.hypot(ey) < 1e-3, "position error {ex} {ey}");
    assert!(ea < 1e-6, "heading error {ea}");
    assert!(reference.alpha.abs() > 1.0, "the drive turned");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random chassis, random starting pose, random sample sequences: the integrator follows
    /// the f64 reference within a bound that scales with the path.
    #[test]
    fn integrator_follows_f64_reference(
        dl in 0.1f64..0.6,
        dr in 0.1f64..0.6,
        w in 0.3f64..1.5,
        ticks in prop::sample::select(vec![2048u32, 4096, 10_000, 20_000, 40_000]),
        x0 in -1000.0f64..1000.0,
        y0 in -1000.0f64..1000.0,
        a0 in -10.0f64..10.0,
        steps in prop::collection::vec((-3000i64..3000, -3000i64..3000), 1..400),
    ) {
        let p = ChassisParams { left_diameter: dl, right_diameter: dr, track_width: w, ticks_per_rev: ticks, ..ChassisParams::DESIGNED };
        prop_assume!(p.validate().is_ok());
        let start = Pose { x: x0, y: y0, heading: a0 };
        let mut integ = Integrator::new(&p, counts([0, 0]), start).unwrap();
        let mut reference = Reference::new(&p, [0, 0], start);
        let mut g = [0i64; 2];
        let mut path = 0.0;
        for (a, b) in steps {
            g = [g[0] + a, g[1] + b];
            let st = integ.step(counts(g), IndexRefs::default());
            if st.overrange {
                return Ok(());
            }
            reference.step(g, [None, None]);
            path += (a.abs() as f64 * dl + b.abs() as f64 * dr) * PI / f64::from(ticks);
        }
        let pose = integ.pose();
        let tol = 1e-8 + 1e-8 * path;
        prop_assert!((pose.x - reference.x).abs() < tol, "x {} vs {}", pose.x, reference.x);
        prop_assert!((pose.y - reference.y).abs() < tol, "y {} vs {}", pose.y, reference.y);
        prop_assert!((pose.heading - reference.alpha).abs() < 1e-9 + 1e-12 * path / w);
        let sigma = integ.sigma();
        for (got, want) in [(sigma.x, reference.sigma_x), (sigma.y, reference.sigma_y), (sigma.heading, reference.sigma_alpha)] {
            prop_assert!((f64::from(got) - want).abs() <= 1e-5 * want + 1e-12, "{} vs {}", got, want);
        }
    }

    /// The pose depends only on the counts, not on how a motion is split into samples, when
    /// the motion is straight.
    #[test]
    fn straight_motion_is_independent_of_sampling(n in 1i64..5000, parts in 1i64..50) {
        let p = ChassisParams::DESIGNED;
        let mut one = Integrator::new(&p, counts([0, 0]), Pose { heading: 0.7, ..Pose::default() }).unwrap();
        one.step(counts([n * parts, n * parts]), IndexRefs::default());
        let mut many = Integrator::new(&p, counts([0, 0]), Pose { heading: 0.7, ..Pose::default() }).unwrap();
        for k in 1..=parts {
            many.step(counts([n * k, n * k]), IndexRefs::default());
        }
        prop_assert!((one.pose().x - many.pose().x).abs() < 1e-9 * parts as f64);
        prop_assert!((one.pose().y - many.pose().y).abs() < 1e-9 * parts as f64);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// `step_pose` (the host tools' pose-only step) moves the pose exactly as `step` does,
    /// bit for bit, through over-range samples, counter wrap and per-angle wheel functions
    /// referenced by moving index latches, leaves the sigmas at zero, and reports the motion
    /// that moved the pose: the position moved by the chord along its direction (rounded to
    /// 2^-32 m), the heading by the increment, and `direction = heading + increment / 2`.
    #[test]
    fn step_pose_moves_the_pose_as_step_does(
        dl in 0.1f64..0.6,
        dr in 0.1f64..0.6,
        w in 0.3f64..1.5,
        harmonic in -0.002f32..0.002,
        a0 in -10.0f64..10.0,
        base in prop::sample::select(vec![0i64, i64::MAX - 50_000, -(1i64 << 31) + 20_000]),
        steps in prop::collection::vec((-6000i64..6000, -6000i64..6000, 0u8..8), 1..300),
    ) {
        let mut p = ChassisParams { left_diameter: dl, right_diameter: dr, track_width: w, ..ChassisParams::DESIGNED };
        p.left_wheel.cos[0] = harmonic;
        p.right_wheel.sin[1] = -harmonic;
        prop_assume!(p.validate().is_ok());
        let start = Pose { x: 3.5, y: -7.25, heading: a0 };
        let mut full = Integrator::new(&p, counts([base, base]), start).unwrap();
        let mut pose_only = full.clone();
        let mut g = [base, base];
        let mut index = IndexRefs::default();
        for (a, b, event) in steps {
            // Now and then an over-range jump (2^19 increments), and index latches that move.
            let jump = if event == 0 { 1i64 << 19 } else { 0 };
            g = [g[0].wrapping_add(a + jump), g[1].wrapping_add(b)];
            if event == 1 {
                index = IndexRefs { left: Some(g[0].wrapping_sub(17)), right: Some(g[1].wrapping_add(5)) };
            }
            let (fixed0, heading0) = (pose_only.position_fixed(), pose_only.heading_binary());
            let status = full.step(counts(g), index);
            let (status_pose, motion) = pose_only.step_pose(counts(g), index);
            prop_assert_eq!(status, status_pose);
            prop_assert_eq!(full.pose(), pose_only.pose());
            prop_assert_eq!(full.position_fixed(), pose_only.position_fixed());
            prop_assert_eq!(full.heading_binary(), pose_only.heading_binary());
            prop_assert_eq!(motion.is_none(), status.overrange);
            if let Some(m) = motion {
                let moved = |q: i32| ((i128::from(m.chord) * i128::from(q) + (1 << 45)) >> 46) as i64;
                let (x1, y1) = pose_only.position_fixed();
                prop_assert_eq!(x1 - fixed0.0, moved(m.sin));
                prop_assert_eq!(y1 - fixed0.1, moved(m.cos));
                prop_assert_eq!(pose_only.heading_binary().1, heading0.1.wrapping_add(m.heading_increment as u64));
                prop_assert_eq!(m.direction, heading0.1.wrapping_add((m.heading_increment >> 1) as u64));
                prop_assert_eq!((m.sin, m.cos), trig::sin_cos(m.direction));
            }
        }
        prop_assert_eq!(pose_only.sigma(), PoseSigma::default());
    }
}

proptest! {
    /// The integer f32-to-i64 conversion equals Rust's `as` over the range it serves.
    #[test]
    fn fast_f32_to_i64_matches_cast(bits in any::<u32>()) {
        let v = f32::from_bits(bits);
        prop_assume!(v.is_finite() && v.abs() < 9.2e18);
        prop_assert_eq!(trig::f32_to_i64(v), v as i64);
    }
}

#[test]
fn parameter_errors_name_the_exact_key() {
    use odo_unit::odometry::ParamError;
    let mut p = ChassisParams::DESIGNED;
    p.right_wheel.sin[1] = 0.2;
    assert_eq!(p.validate(), Err(ParamError::OutOfRange("right_sin2")));
    p.right_wheel.sin[1] = f32::NAN;
    assert_eq!(p.validate(), Err(ParamError::NotFinite("right_sin2")));
    let p = ChassisParams {
        kappa_left: -1.0,
        ..ChassisParams::DESIGNED
    };
    assert_eq!(p.validate(), Err(ParamError::OutOfRange("kappa_left")));
    let p = ChassisParams {
        track_width: f64::INFINITY,
        ..ChassisParams::DESIGNED
    };
    assert_eq!(p.validate(), Err(ParamError::NotFinite("track_width")));
    assert_eq!(ChassisParams::DESIGNED.validate(), Ok(()));
}

/// Every single-precision parameter, out of range (above its maximum, and infinite) and NaN,
/// is refused under its own key: the key table of `ChassisParams::validate` lines up with
/// the fields, and the first offending key (in the documented order) is the one named.
#[test]
fn every_f32_parameter_names_its_key() {
    use odo_unit::odometry::params::HARMONIC_KEYS;
    use odo_unit::odometry::ParamError;
    type Field = fn(&mut ChassisParams) -> &mut f32;
    let mut fields: Vec<(Field, &str, f32)> = vec![
        (
            |p| &mut p.delta_left,
            "delta_left",
            ChassisParams::MAX_DELTA,
        ),
        (
            |p| &mut p.delta_right,
            "delta_right",
            ChassisParams::MAX_DELTA,
        ),
        (
            |p| &mut p.delta_diff,
            "delta_diff",
            ChassisParams::MAX_DELTA,
        ),
        (
            |p| &mut p.kappa_left,
            "kappa_left",
            ChassisParams::MAX_KAPPA,
        ),
        (
            |p| &mut p.kappa_right,
            "kappa_right",
            ChassisParams::MAX_KAPPA,
        ),
        (
            |p| &mut p.kappa_diff,
            "kappa_diff",
            ChassisParams::MAX_KAPPA,
        ),
        (
            |p| &mut p.kappa_diff_corr,
            "kappa_diff_corr",
            ChassisParams::MAX_KAPPA_DIFF_CORR,
        ),
    ];
    let harmonics: [[Field; 6]; 2] = [
        [
            |p| &mut p.left_wheel.cos[0],
            |p| &mut p.left_wheel.sin[0],
            |p| &mut p.left_wheel.cos[1],
            |p| &mut p.left_wheel.sin[1],
            |p| &mut p.left_wheel.cos[2],
            |p| &mut p.left_wheel.sin[2],
        ],
        [
            |p| &mut p.right_wheel.cos[0],
            |p| &mut p.right_wheel.sin[0],
            |p| &mut p.right_wheel.cos[1],
            |p| &mut p.right_wheel.sin[1],
            |p| &mut p.right_wheel.cos[2],
            |p| &mut p.right_wheel.sin[2],
        ],
    ];
    for (wheel, fs) in harmonics.iter().enumerate() {
        for (i, f) in fs.iter().enumerate() {
            let key = HARMONIC_KEYS[wheel][i % 2][i / 2];
            fields.push((*f, key, ChassisParams::MAX_HARMONIC));
        }
    }
    let se = odo_unit::odometry::GeometryUncertainty::MAX_SE;
    fields.extend([
        (
            (|p| &mut p.geometry_uncertainty.left_diameter_se) as Field,
            "left_diameter_se",
            se,
        ),
        (
            |p| &mut p.geometry_uncertainty.right_diameter_se,
            "right_diameter_se",
            se,
        ),
        (
            |p| &mut p.geometry_uncertainty.track_width_se,
            "track_width_se",
            se,
        ),
        (
            |p| &mut p.geometry_uncertainty.diameters_correlation,
            "diameters_correlation",
            1.0,
        ),
        (
            |p| &mut p.geometry_uncertainty.left_track_correlation,
            "left_track_correlation",
            1.0,
        ),
        (
            |p| &mut p.geometry_uncertainty.right_track_correlation,
            "right_track_correlation",
            1.0,
        ),
    ]);
    assert_eq!(fields.len(), 25);
    for (i, &(field, key, max)) in fields.iter().enumerate() {
        for (value, error) in [
            (max * 1.5, ParamError::OutOfRange(key)),
            (f32::INFINITY, ParamError::NotFinite(key)),
            (f32::NAN, ParamError::NotFinite(key)),
        ] {
            let mut p = ChassisParams::DESIGNED;
            *field(&mut p) = value;
            assert_eq!(p.validate(), Err(error), "{key} = {value}");
            // A later parameter out of range as well: the earlier key is named.
            if let Some(&(later, _, later_max)) = fields.get(i + 1) {
                *later(&mut p) = later_max * 2.0;
                assert_eq!(p.validate(), Err(error), "{key} before the next");
            }
        }
        let mut p = ChassisParams::DESIGNED;
        *field(&mut p) = max;
        // At the limit: accepted (a correlation of 1 with the others at 0 is a valid
        // correlation matrix).
        assert_eq!(p.validate(), Ok(()), "{key} = {max}");
    }
}
