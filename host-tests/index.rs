//! Host tests of `odo_unit::odometry::index`: the whole-turn check of the counts between
//! index pulses, and the extension of a latched raw count near a reference.

use odo_unit::odometry::index::{self, extend_near, IndexCheck, IndexTracker};
use proptest::prelude::*;

#[test]
fn index_boundary_table() {
    let tpr = 20_000i64;
    for (diff, expected) in [
        (0, IndexCheck::Whole { turns: 0 }),
        (tpr, IndexCheck::Whole { turns: 1 }),
        (-tpr, IndexCheck::Whole { turns: -1 }),
        (tpr + 4, IndexCheck::Whole { turns: 1 }),
        (tpr - 4, IndexCheck::Whole { turns: 1 }),
        (-tpr - 4, IndexCheck::Whole { turns: -1 }),
        (tpr + 5, IndexCheck::Mismatch { error: 5 }),
        (tpr - 5, IndexCheck::Mismatch { error: -5 }),
        (3 * tpr + 1_000, IndexCheck::Mismatch { error: 1_000 }),
        (tpr / 2, IndexCheck::Mismatch { error: tpr / 2 }),
        (
            tpr / 2 + 1,
            IndexCheck::Mismatch {
                error: -tpr / 2 + 1,
            },
        ),
        (-7 * tpr + 3, IndexCheck::Whole { turns: -7 }),
    ] {
        let mut t = IndexTracker::new(20_000, index::DEFAULT_TOLERANCE);
        assert_eq!(t.on_index(123_456), IndexCheck::First);
        assert_eq!(t.on_index(123_456 + diff), expected, "diff {diff}");
        assert_eq!(t.reference(), Some(123_456 + diff));
        assert_eq!(
            t.take_mismatch(),
            matches!(expected, IndexCheck::Mismatch { .. })
        );
        assert!(!t.take_mismatch());
    }
}

#[test]
fn extend_near_table() {
    for (bits, ref_raw, ref_abs, raw, abs) in [
        (16, 65_530u32, 100i64, 5u32, 111i64),
        (16, 5, 100, 65_530, 89),
        (16, 0, 0, 32_767, 32_767),
        (16, 0, 0, 32_768, -32_768),
        (32, u32::MAX, -1, 0, 0),
        (32, 0, 1 << 40, u32::MAX, (1 << 40) - 1),
        (32, 0, 0, 0x7fff_ffff, 0x7fff_ffff),
    ] {
        assert_eq!(
            extend_near(bits, ref_raw, ref_abs, raw),
            abs,
            "{bits} {ref_raw} {raw}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    /// Whole turns plus an error: flagged exactly when the error exceeds the tolerance.
    #[test]
    fn index_whole_turns(
        tpr in 4u32..1_048_576,
        turns in -1000i64..1000,
        err in -20i64..20,
        start in -1_000_000_000i64..1_000_000_000,
    ) {
        let mut t = IndexTracker::new(tpr, index::DEFAULT_TOLERANCE);
        t.on_index(start);
        let err = if tpr < 64 { 0 } else { err };
        let r = t.on_index(start + turns * i64::from(tpr) + err);
        if err.unsigned_abs() <= u64::from(index::DEFAULT_TOLERANCE) {
            prop_assert_eq!(r, IndexCheck::Whole { turns });
        } else {
            prop_assert_eq!(r, IndexCheck::Mismatch { error: err });
        }
    }

    /// Extending a raw reading near a reference gives back the true absolute count.
    #[test]
    fn extend_near_recovers(bits in prop::sample::select(vec![16u32, 32]), abs in -(1i64 << 50)..(1i64 << 50), step in -30_000i64..30_000) {
        let mask = if bits == 32 { u64::from(u32::MAX) } else { (1u64 << bits) - 1 };
        let raw_of = |a: i64| (a as u64 & mask) as u32;
        prop_assert_eq!(extend_near(bits, raw_of(abs), abs, raw_of(abs + step)), abs + step);
    }

    /// Any two latched counts, near or 2^63 and more apart (the wide path), any
    /// ticks_per_rev and tolerance: the turns and error of the exact i128 arithmetic (turns
    /// rounded to the nearest, a half turn down; saturated to i64).
    #[test]
    fn index_any_counts_match_i128(
        a in prop_oneof![any::<i64>(), Just(i64::MIN), Just(i64::MAX), -4i64..4],
        b in prop_oneof![any::<i64>(), Just(i64::MIN), Just(i64::MAX), -4i64..4],
        tpr in prop_oneof![1u32..=8, 4u32..=1_048_576, Just(u32::MAX), any::<u32>()],
        tolerance in prop_oneof![Just(index::DEFAULT_TOLERANCE), any::<u32>()],
    ) {
        let tpr = tpr.max(1);
        let mut t = IndexTracker::new(tpr, tolerance);
        prop_assert_eq!(t.on_index(a), IndexCheck::First);
        let (diff, w) = (i128::from(b) - i128::from(a), i128::from(tpr));
        let rem = diff.rem_euclid(w);
        let error = if rem > w / 2 { rem - w } else { rem };
        let turns = ((diff - error) / w).clamp(i64::MIN.into(), i64::MAX.into());
        let expected = if error.unsigned_abs() <= u128::from(tolerance) {
            IndexCheck::Whole { turns: turns as i64 }
        } else {
            IndexCheck::Mismatch { error: error as i64 }
        };
        prop_assert_eq!(t.on_index(b), expected, "{} -> {} at {}", a, b, tpr);
    }
}

/// Latched counts about 2^63 apart (unreachable on a board, but the core
/// promises no panic) multiplied with overflow; now exact, with saturated turns.
#[test]
fn index_counts_far_apart_do_not_overflow() {
    for (tpr, a, b, expected) in [
        (20_000u32, i64::MIN, i64::MAX, None),
        (20_000, i64::MAX, i64::MIN, None),
        (20_000, 0, i64::MAX, None),
        (20_000, -9_223_372_036_854_760_000, 0, None),
        (
            1,
            i64::MIN,
            i64::MAX,
            Some(IndexCheck::Whole { turns: i64::MAX }),
        ),
        (
            1,
            i64::MAX,
            i64::MIN,
            Some(IndexCheck::Whole { turns: i64::MIN }),
        ),
        (
            2,
            i64::MIN,
            i64::MAX,
            Some(IndexCheck::Whole { turns: i64::MAX }),
        ),
        (
            1 << 30,
            0,
            (1 << 62) + 3,
            Some(IndexCheck::Whole { turns: 1 << 32 }),
        ),
    ] {
        let mut t = IndexTracker::new(tpr, index::DEFAULT_TOLERANCE);
        assert_eq!(t.on_index(a), IndexCheck::First);
        let got = t.on_index(b);
        // The exact answer from i128.
        let diff = i128::from(b) - i128::from(a);
        let turns = (diff + i128::from(tpr) / 2).div_euclid(i128::from(tpr));
        let error = diff - turns * i128::from(tpr);
        match got {
            IndexCheck::Whole { turns: t } => {
                assert!(error.abs() <= 4, "{a} -> {b}: {got:?}");
                assert_eq!(i128::from(t), turns.clamp(i64::MIN.into(), i64::MAX.into()));
            }
            IndexCheck::Mismatch { error: e } => assert_eq!(i128::from(e), error, "{a} -> {b}"),
            IndexCheck::First => panic!("second pulse reported as first"),
        }
        if let Some(expected) = expected {
            assert_eq!(got, expected, "{a} -> {b}");
        }
        assert_eq!(t.reference(), Some(b));
    }
}
