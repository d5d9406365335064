//! The PPS discipline and sample scheduler (`odo_unit::timing::pps`) on a crystal: lock,
//! holdover and reacquisition against simulated crystal offsets, jitter, lost and spurious
//! pulses; the glitch and acquisition windows; free mode; configuration; capture resolution.

use odo_unit::timing::*;
use proptest::prelude::*;

mod support;
use support::pps_sim::*;

#[test]
fn locks_and_follows_the_pps_with_crystal_offsets() {
    for ppm in [-100.0, -37.5, 0.0, 12.0, 100.0] {
        let sc = Scenario::new(ppm, 8, 120);
        let mut disc = pps_disc();
        let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
        check_structure(&r);
        assert_eq!(disc.state(), SyncState::Locked, "ppm {ppm}");
        assert_eq!(disc.stats().locks, 1);
        assert_eq!(disc.stats().glitches, 0);
        // Locks at the second edge (t = 2 s), 50 samples per second from then.
        let locked = r
            .samples
            .iter()
            .filter(|s| s.state == SyncState::Locked)
            .count();
        assert!((116 * 50..=118 * 50 + 2).contains(&locked), "{locked}");
        // Bound: the samples committed before an edge is captured sit at the previous edge
        // (one jitter) plus the measured period (two jitters) times (1 + k/rate), k <= 2:
        // 3.08 jitters, plus rounding.
        let err = locked_error(&r, sc.crystal);
        assert!(
            err < (3.1 * 8.0 + 3.0) / f64::from(HZ),
            "ppm {ppm}: error {err}"
        );
        let measured = disc.period() as f64;
        let expected = f64::from(HZ) * (1.0 + ppm * 1e-6);
        assert!(
            (measured - expected).abs() <= 2.0 * 8.0 + 1.0,
            "{measured} vs {expected}"
        );
    }
}

#[test]
fn no_cumulative_drift_over_an_hour() {
    let sc = Scenario::new(100.0, 0, 3_600);
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    // Without jitter the grid is exact to the rounding of one tick.
    let err = locked_error(&r, sc.crystal);
    assert!(err <= 1.5 / f64::from(HZ), "{err}");
    assert_eq!(
        r.samples
            .iter()
            .filter(|s| s.state == SyncState::Locked)
            .count(),
        3_598 * 50 - 3 + 1
    );
}

#[test]
fn locked_sample_k_is_at_edge_plus_k_period_over_rate() {
    let sc = Scenario::new(-63.0, 5, 20);
    let mut disc = pps_disc();
    let edges = sc.edges();
    let r = run(&mut disc, &edges, sc.crystal, sc.seconds);
    // In every locked second after the first, samples k >= 3 (committed after the edge was
    // captured: two samples are committed ahead, and the edge may come just after sample 0)
    // sit exactly at edge + floor(k * P / 50), with P the edge-to-edge period.
    let offset = label_offset(&r).expect("locked");
    for s in r
        .samples
        .iter()
        .filter(|s| s.state == SyncState::Locked && s.index >= 3)
    {
        let truth = (i64::from(s.second) + offset) as u32;
        let i = edges
            .iter()
            .position(|e| e.second == Some(truth))
            .expect("edge");
        if i == 0 {
            continue;
        }
        let period = edges[i].tick - edges[i - 1].tick;
        assert_eq!(
            s.tick,
            edges[i].tick + u64::from(s.index) * period / 50,
            "{s:?}"
        );
    }
}

#[test]
fn lost_pulses_give_holdover_then_reacquisition() {
    let mut sc = Scenario::new(80.0, 10, 60);
    sc.lost = (20..26).collect(); // six seconds without PPS (holdover_s = 10)
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    let holdover: Vec<_> = r
        .samples
        .iter()
        .filter(|s| s.state == SyncState::Holdover)
        .collect();
    assert!(!holdover.is_empty());
    assert_eq!(reacquisitions(&r), vec![6]);
    assert_eq!(disc.stats().missed, 6);
    assert_eq!(disc.stats().locks, 1, "holdover must not need a new lock");
    assert_eq!(disc.state(), SyncState::Locked);
    // Holdover samples stay on the grid within the period error times the seconds held.
    let offset = label_offset(&r).expect("locked");
    for s in &holdover {
        let truth = (i64::from(s.second) + offset) as f64 + f64::from(s.index) / 50.0;
        let err = (sc.crystal.time(s.tick) - truth).abs();
        assert!(err < 7.0 * 25.0 / f64::from(HZ), "{s:?}: {err}");
    }
    assert!(locked_error(&r, sc.crystal) < 35.0 / f64::from(HZ));
}

#[test]
fn long_loss_falls_back_to_free_running_and_relocks() {
    let mut sc = Scenario::new(-100.0, 10, 60);
    sc.lost = (15..35).collect(); // 20 s > holdover_s
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    let states: Vec<SyncState> = r.samples.iter().map(|s| s.state).collect();
    let mut transitions = states.clone();
    transitions.dedup();
    use SyncState::*;
    assert_eq!(
        transitions,
        vec![FreeRunning, Locked, Holdover, FreeRunning, Locked]
    );
    let holdover = states.iter().filter(|s| **s == Holdover).count();
    // Holdover from the first missed edge (t = 15 s) to the eleventh (t = 25 s).
    assert!(
        (10 * 50 - 2..=10 * 50 + 2).contains(&holdover),
        "{holdover}"
    );
    assert_eq!(disc.stats().locks, 2);
    assert_eq!(disc.state(), Locked);
    // After the relock the grid is again on the true seconds (new labels, new offset).
    let relock = r
        .events
        .iter()
        .rposition(|(_, e)| matches!(e, PpsEvent::Locked { .. }))
        .expect("relock");
    let tail = Run {
        samples: r
            .samples
            .iter()
            .copied()
            .filter(|s| s.tick > r.events[relock].0.tick)
            .collect(),
        events: r.events[relock..].to_vec(),
    };
    assert!(locked_error(&tail, sc.crystal) < 35.0 / f64::from(HZ));
}

#[test]
fn spurious_pulses_are_rejected_as_glitches() {
    let mut sc = Scenario::new(42.0, 10, 40);
    sc.spurious = vec![10.3, 10.7, 17.000_5, 22.999_7, 30.5];
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    assert_eq!(disc.stats().glitches, 5);
    assert_eq!(disc.stats().locks, 1);
    assert!(all_locked_after(&r, 200));
    assert!(locked_error(&r, sc.crystal) < 35.0 / f64::from(HZ));
}

#[test]
fn spurious_pulses_before_lock_delay_it_but_do_not_mislock() {
    let mut sc = Scenario::new(0.0, 0, 10);
    sc.spurious = vec![0.4, 1.25, 2.9];
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    assert_eq!(disc.state(), SyncState::Locked);
    label_offset(&r); // panics if a spurious edge was accepted
    assert!(locked_error(&r, sc.crystal) < 2.0 / f64::from(HZ));
}

#[test]
fn glitch_window_boundaries() {
    // Edges at 1 s and 2 s lock; the third edge is moved by d ticks from its prediction.
    let w = i64::from(DisciplineConfig::new(HZ).glitch_window_ticks);
    for (d, accepted) in [
        (0, true),
        (w, true),
        (-w, true),
        (w + 1, false),
        (-w - 1, false),
        (HZ as i64 / 2, false),
    ] {
        let mut disc = pps_disc();
        let p = u64::from(HZ);
        assert_eq!(disc.on_pps(p), PpsEvent::Candidate);
        assert!(matches!(disc.on_pps(2 * p), PpsEvent::Locked { .. }));
        let e = disc.on_pps((3 * p as i64 + d) as u64);
        assert_eq!(
            matches!(e, PpsEvent::Accepted { .. }),
            accepted,
            "d = {d}: {e:?}"
        );
        if let PpsEvent::Accepted { phase_error, .. } = e {
            assert_eq!(phase_error, d);
        }
    }
}

#[test]
fn acquisition_period_boundaries() {
    // Two edges lock only when their interval is within max_offset_ppm (+ window) of 1 s.
    let cfg = DisciplineConfig::new(HZ);
    let limit = u64::from(HZ) * u64::from(cfg.max_offset_ppm) / 1_000_000
        + u64::from(cfg.glitch_window_ticks);
    for (interval, locks) in [
        (u64::from(HZ), true),
        (u64::from(HZ) + limit, true),
        (u64::from(HZ) - limit, true),
        (u64::from(HZ) + limit + 1, false),
        (u64::from(HZ) - limit - 1, false),
        (u64::from(HZ) / 2, false),
    ] {
        let mut disc = pps_disc();
        disc.on_pps(5_000);
        let e = disc.on_pps(5_000 + interval);
        assert_eq!(
            matches!(e, PpsEvent::Locked { .. }),
            locks,
            "{interval}: {e:?}"
        );
    }
}

#[test]
fn duplicate_and_backwards_edges_are_glitches() {
    let mut disc = pps_disc();
    let p = u64::from(HZ);
    disc.on_pps(p);
    disc.on_pps(2 * p);
    assert!(matches!(disc.on_pps(3 * p), PpsEvent::Accepted { .. }));
    assert_eq!(disc.on_pps(3 * p + 10), PpsEvent::Glitch);
    assert_eq!(disc.on_pps(3 * p), PpsEvent::Glitch);
    assert_eq!(disc.on_pps(p), PpsEvent::Glitch);
    assert_eq!(disc.stats().glitches, 3);
}

#[test]
fn free_mode_ignores_pps_and_schedules_exactly() {
    for rate in [1, 7, 10, 13, 50, 333, 999, 1000, 10_000] {
        let mut cfg = DisciplineConfig::new(HZ);
        cfg.mode = SyncMode::Free;
        cfg.rate_hz = rate;
        let mut disc = Discipline::new(cfg, 0).expect("valid");
        assert_eq!(disc.on_pps(u64::from(HZ)), PpsEvent::Ignored);
        let mut prev: Option<Sample> = None;
        for n in 0..(3 * rate) {
            let s = disc.next_sample(prev.map_or(0, |p| p.tick));
            assert_eq!(s.state, SyncState::FreeRunning);
            assert_eq!((s.second, s.index), (n / rate, n % rate));
            let k = u64::from(s.index);
            assert_eq!(
                s.tick,
                u64::from(s.second) * u64::from(HZ) + k * u64::from(HZ) / u64::from(rate)
            );
            if let Some(p) = prev {
                let gap = s.tick - p.tick;
                let floor = u64::from(HZ) / u64::from(rate);
                assert!(gap == floor || gap == floor + 1, "rate {rate}: gap {gap}");
            }
            prev = Some(s);
        }
    }
}

#[test]
fn rate_change_applies_at_the_next_second() {
    let mut cfg = DisciplineConfig::new(HZ);
    cfg.mode = SyncMode::Free;
    let mut disc = Discipline::new(cfg, 0).expect("valid");
    for _ in 0..10 {
        disc.next_sample(0);
    }
    cfg.rate_hz = 100;
    disc.set_config(cfg).expect("valid");
    let rest: Vec<Sample> = (0..45).map(|_| disc.next_sample(0)).collect();
    assert!(rest[..40].iter().all(|s| s.rate == 50 && s.second == 0));
    assert_eq!(
        (rest[40].second, rest[40].index, rest[40].rate),
        (1, 0, 100)
    );
    assert_eq!(rest[41].tick - rest[40].tick, u64::from(HZ) / 100);
}

type ConfigEdit = fn(&mut DisciplineConfig);

#[test]
fn config_validation_boundaries() {
    let ok = DisciplineConfig::new(HZ);
    assert_eq!(ok.validate(), Ok(()));
    let table: [(ConfigEdit, Result<(), ConfigError>); 9] = [
        (|c| c.rate_hz = 0, Err(ConfigError::Rate)),
        (|c| c.rate_hz = 1, Ok(())),
        (|c| c.rate_hz = 10_000, Ok(())),
        (|c| c.rate_hz = 10_001, Err(ConfigError::Rate)),
        (|c| c.timer_hz = 999, Err(ConfigError::TimerHz)),
        (|c| c.glitch_window_ticks = 0, Err(ConfigError::Window)),
        (|c| c.glitch_window_ticks = HZ / 4, Err(ConfigError::Window)),
        (|c| c.max_offset_ppm = 0, Err(ConfigError::Offset)),
        (|c| c.holdover_s = 0, Err(ConfigError::Holdover)),
    ];
    for (edit, expected) in table {
        let mut c = ok;
        edit(&mut c);
        assert_eq!(c.validate(), expected, "{c:?}");
    }
}

#[test]
fn switching_to_free_mode_drops_the_lock() {
    let sc = Scenario::new(20.0, 0, 5);
    let mut disc = pps_disc();
    run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    assert_eq!(disc.state(), SyncState::Locked);
    let mut cfg = *disc.config();
    cfg.mode = SyncMode::Free;
    disc.set_config(cfg).expect("valid");
    assert_eq!(disc.state(), SyncState::FreeRunning);
    assert_eq!(disc.period(), u64::from(HZ));
}

#[test]
fn capture_resolution_table() {
    // (period start, length, ccr, update pending) -> tick
    for (start, len, ccr, pending, tick) in [
        (1_000u64, 1_680_000u64, 10u32, false, 1_010u64),
        (1_000, 1_680_000, 1_679_999, false, 1_681_000 - 1),
        (1_000, 1_680_000, 1_679_999, true, 1_681_000 - 1),
        (1_000, 1_680_000, 5, true, 1_681_005),
        (1_000, 1_680_000, 839_999, true, 1_681_000 + 839_999),
        (1_000, 1_680_000, 840_000, true, 841_000),
    ] {
        assert_eq!(
            resolve_capture(start, len, ccr, pending),
            tick,
            "{start} {len} {ccr} {pending}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Random crystals, jitter, losses and spurious edges: the structure always holds, no
    /// spurious edge is ever accepted, and locked samples are on the true grid.
    // Spurious edges within 6e-4 s of a true second are left out: one within the glitch
    // window of a real edge cannot be told apart; with a crystal tolerance two edges lock at
    // once, so one within the acquisition window (500 ppm + 50 us) of a real edge, before the
    // lock, can pair with a real one and lock on a period that far off
    // (`hsi_spurious_edges_before_lock_do_not_mislock` shows the confirmed acquisition of a
    // wide tolerance, which avoids it).
    #[test]
    fn discipline_invariants(sc in scenario(-100.0..100.0, 6e-4)) {
        let (_, err) = run_checked(&mut pps_disc(), &sc);
        // As in `locks_and_follows_the_pps_with_crystal_offsets`: 3.08 jitters plus rounding.
        prop_assert!(err < (3.1 * sc.jitter as f64 + 3.0) / f64::from(HZ), "error {}", err);
    }
}
