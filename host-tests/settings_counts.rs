//! Counts per sample: the 16-bit right counter (TIM3) must not alias. The limit's
//! constants, its boundary through `set_many` on either wheel, the unread interval it gives,
//! and the flash erase stall it allows.

use odo_unit::odometry::integrator::MAX_STEP_COUNTS;
use odo_unit::odometry::ChassisParams;
use odo_unit::settings::*;

mod support;
use support::settings::variant;

#[test]
fn counts_limit_constants() {
    assert_eq!(COUNTER16_MAX_UNREAD, 32_767);
    assert_eq!(MAX_STEP_COUNTS, 1 << 18);
    assert_eq!(
        MAX_COUNTS_PER_SAMPLE, 32_767,
        "the 16-bit counter binds first"
    );
    assert_eq!(MAX_RATE_HZ, 1_000);
    assert_eq!(1_000_000 % MAX_RATE_HZ, 0, "usable in pps mode");
    // The documented examples.
    let c = max_counts_per_sample(2.0, 20_000, 0.26, 1);
    assert!((c - 48_970.75).abs() < 0.01, "{c}");
    assert_eq!(Settings::DEFAULT.max_counts_per_sample(), c / 50.0);
    let t = Settings::DEFAULT.max_unread_interval();
    assert!((t - 0.669_1).abs() < 1e-4, "{t}");
    assert_eq!(max_unread_interval(0.0, 20_000, 0.26), f64::INFINITY);
    assert_eq!(max_unread_interval(-1.0, 20_000, 0.26), 0.0);
    assert_eq!(max_unread_interval(f64::NAN, 20_000, 0.26), 0.0);
    assert_eq!(max_counts_per_sample(2.0, 20_000, 0.26, 0), f64::INFINITY);
}

/// The largest diameter `d` (m) for which `max_counts_per_sample(v, tpr, d, rate)` exceeds
/// the limit: the next f64 above it gives at most the limit. Found by bisection on the bits
/// of positive f64 (ordered like the values).
fn boundary_diameter(v: f64, tpr: u32, rate: u32) -> f64 {
    let limit = MAX_COUNTS_PER_SAMPLE as f64;
    let (mut lo, mut hi) = (1e-3f64.to_bits(), 100f64.to_bits());
    assert!(max_counts_per_sample(v, tpr, f64::from_bits(lo), rate) > limit);
    assert!(max_counts_per_sample(v, tpr, f64::from_bits(hi), rate) <= limit);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if max_counts_per_sample(v, tpr, f64::from_bits(mid), rate) > limit {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    f64::from_bits(lo)
}

/// Boundary table at 1 Hz with a fine encoder: just below, at and just above the limit of
/// 32,767 increments per sample, through `set_many` (which names the keys and leaves the
/// settings intact), on either wheel, and with the smaller wheel deciding.
#[test]
fn counts_per_sample_boundary_table() {
    let tpr = 1_048_576; // the largest ticks_per_rev
    let base = Settings {
        rate: 1,
        max_wheel_speed: 0.05, // m/s
        chassis: ChassisParams {
            ticks_per_rev: tpr,
            ..ChassisParams::DESIGNED
        },
        ..Settings::DEFAULT
    };
    // The f32 value of max_wheel_speed, exactly.
    let v = f64::from(base.max_wheel_speed);
    let d_over = boundary_diameter(v, tpr, 1);
    let d_at = f64::from_bits(d_over.to_bits() + 1);
    // The exact diameter: 0.05 * 2^20 / (pi * 32767) = 0.50931... m.
    assert!((d_at - 0.509_31).abs() < 1e-5, "{d_at}");
    let at = max_counts_per_sample(v, tpr, d_at, 1);
    assert!(at <= 32_767.0 && at > 32_767.0 - 1e-9, "{at}");
    assert!(max_counts_per_sample(v, tpr, d_over, 1) > 32_767.0);
    let rows: &[(f64, f64, bool, &str)] = &[
        // (left_diameter, right_diameter, accepted, what)
        (0.6, 0.6, true, "well below: 27,814 increments"),
        (d_at * 1.000_001, d_at * 1.000_001, true, "just below"),
        (d_at, d_at, true, "at the limit"),
        (d_over, d_over, false, "one ulp above"),
        (d_at * 0.999_999, d_at * 0.999_999, false, "just above"),
        (d_over, 0.6, false, "left wheel smaller"),
        (0.6, d_over, false, "right wheel smaller"),
        (0.6, d_at, true, "right wheel smaller, at the limit"),
        (0.26, 0.26, false, "well above: 64,187 increments"),
    ];
    for &(l, r, ok, what) in rows {
        let mut s = base;
        // Debug form: the shortest text that parses back to the same f64.
        let (lt, rt) = (format!("{l:?}"), format!("{r:?}"));
        let res = s.set_many([
            ("left_diameter", lt.as_str()),
            ("right_diameter", rt.as_str()),
        ]);
        assert_eq!(res.is_ok(), ok, "{what}: {l} {r}: {res:?}");
        if ok {
            assert_eq!((s.chassis.left_diameter, s.chassis.right_diameter), (l, r));
            assert!(s.max_counts_per_sample() <= 32_767.0);
            assert!(
                s.max_unread_interval() >= 1.0,
                "{what}: a whole 1 Hz period"
            );
        } else {
            assert_eq!(s, base, "{what}: changed something");
            let e = res.unwrap_err().to_string();
            assert!(
                e.starts_with("rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter")
                    && e.contains("above 32767"),
                "{e}"
            );
            // validate() agrees on the settings as they would have been.
            let mut t = base;
            t.chassis.left_diameter = l;
            t.chassis.right_diameter = r;
            assert!(matches!(
                t.validate(),
                Err(SettingError::CountsPerSample { counts }) if counts >= 32_768
            ));
        }
    }
    // The rate scales it: 64,187 increments at 1 Hz are 32,093 at 2 Hz.
    let mut s = base;
    s.set_many([("left_diameter", "0.26"), ("right_diameter", "0.26")])
        .unwrap_err();
    s.set_many([
        ("left_diameter", "0.26"),
        ("right_diameter", "0.26"),
        ("rate", "2"),
    ])
    .unwrap();
    assert!((s.max_counts_per_sample() - 32_093.47).abs() < 0.01);
}

/// The unread interval is the limit's time at max_wheel_speed, and a sample period of
/// valid settings always fits in it.
#[test]
fn max_unread_interval_matches_counts() {
    for (v, tpr, d) in [(2.0, 20_000, 0.26), (0.5, 1_048_576, 0.4), (20.0, 4, 10.0)] {
        let t = max_unread_interval(v, tpr, d);
        let c = max_counts_per_sample(v, tpr, d, 1) * t;
        assert!((c - 32_767.0).abs() < 1e-6, "{v} {tpr} {d}: {c}");
    }
    for i in 0..50 {
        let s = variant(i);
        assert!(s.max_unread_interval() >= 1.0 / f64::from(s.rate));
    }
}

/// The save guard: one sample period plus the erase stall must stay below
/// `max_unread_interval` (0.669 s for the designed chassis at 2 m/s), so at 50 Hz the x32
/// erase (500 ms) is survivable, the x8 erase (800 ms) is not; slower wheels make the x8 erase
/// survivable too, and a stall of zero always is.
#[test]
fn erase_stall_against_the_counter_range() {
    let d = Settings::DEFAULT;
    assert!(d.survives_stall(0));
    assert!(d.survives_stall(500));
    // 669 ms - 20 ms (one period at 50 Hz) = 649 ms.
    assert!(d.survives_stall(648));
    assert!(!d.survives_stall(650));
    assert!(!d.survives_stall(800));
    // At 2 Hz the gap is 500 ms + the stall: the x32 erase (BOR level 3) no longer
    // passes (counts 48,971 > 32,767 would alias TIM3).
    let mut two_hz = d;
    two_hz.rate = 2;
    assert!(!two_hz.survives_stall(500));
    assert!(two_hz.survives_stall(168));
    assert!(!two_hz.survives_stall(170));
    let mut slow = d;
    slow.max_wheel_speed = 1.0;
    assert!(slow.survives_stall(800));
    assert!(!slow.survives_stall(1_400));
}
