//! The free-running 32-bit sample timer (`odo_unit::timing::clock`): counter and capture
//! extension to 64 bits, and the catch-up of the sample grid after a CPU stall, in free mode
//! and locked to the PPS.

use odo_unit::timing::*;
use proptest::prelude::*;

mod support;
use support::pps_sim::*;

#[test]
fn timer_extender_boundary_table() {
    const W: u64 = 1 << 32;
    // (start tick, counter readings in order, their ticks)
    let table: [(u64, &[u32], &[u64]); 5] = [
        // Through a wrap.
        (
            W - 6,
            &[u32::MAX, 0, 10, 0x8000_0009],
            &[W - 1, W, W + 10, W + 0x8000_0009],
        ),
        // The largest forward step, 2^31 - 1, twice.
        (0, &[0x7fff_ffff, 0xffff_fffe], &[0x7fff_ffff, 0xffff_fffe]),
        // A stale reading (taken before a preempting extend) keeps its own, earlier tick.
        (W + 10, &[5, 12], &[W + 5, W + 12]),
        // Far along the timeline: 1,000 wraps.
        (
            1_000 * W + 3,
            &[0x8000_0000, u32::MAX, 4],
            &[1_000 * W + 0x8000_0000, 1_001 * W - 1, 1_001 * W + 4],
        ),
        // The same reading twice.
        (7, &[7, 7], &[7, 7]),
    ];
    for (start, readings, ticks) in table {
        let mut ext = TimerExtender::from_tick(start);
        for (cnt, tick) in readings.iter().zip(ticks) {
            assert_eq!(ext.extend(*cnt), *tick, "start {start}, reading {cnt:#x}");
        }
        assert_eq!(ext.last(), *ticks.iter().max().expect("ticks"));
    }
    assert_eq!(TimerExtender::new(123).last(), 123);

    // Captures around the reading.
    let half = 1u64 << 31;
    for (last, ccr, tick) in [
        (W + 10, 10u32, W + 10),                              // equal to the reading
        (W + 10, 5, W + 5),                                   // after the wrap, before the reading
        (W + 10, u32::MAX, W - 1),                            // just before the wrap
        (W + 10, 0, W),                                       // at the wrap
        (W + 10, 20, W + 20),                                 // latched after the reading
        (W + 10, 10u32.wrapping_sub(1 << 31), W + 10 - half), // the oldest
        (W + 10, 10 + (1 << 31) - 1, W + 10 + half - 1),      // the latest
        (2 * W - 3, 2, 2 * W + 2), // reading just before a wrap, capture just after it
        (2 * W - 3, u32::MAX - 5, 2 * W - 6),
        (5, u32::MAX, 0), // before the timeline's start: clamped
    ] {
        let ext = TimerExtender::from_tick(last);
        assert_eq!(ext.capture(ccr), tick, "last {last:#x}, ccr {ccr:#x}");
        assert_eq!(ext.last(), last);
    }
}

/// Interrupt latency of the simulated board, ticks (12 cycles plus a little).
const LATENCY: u64 = 40;
/// Least lead for programming a compare, ticks (2 us at 84 MHz).
const GUARD: u64 = 168;

/// A CPU stall: from true second `at`, `len` seconds long; no interrupt is served in it.
#[derive(Clone, Copy, Debug)]
struct Stall {
    at: f64,
    len: f64,
}

/// One compare interrupt: the counter read at entry, the sample that was due, the result.
#[derive(Clone, Copy, Debug)]
struct Delivery {
    now: u64,
    due: Sample,
    c: CatchUp,
}

struct CompareRun {
    deliveries: Vec<Delivery>,
    events: Vec<(Edge, PpsEvent)>,
    /// Edges lost to an over-capture (overwritten in the capture register in a stall).
    overcaptured: u32,
}

impl CompareRun {
    /// The delivered samples as a [`Run`], for the structural and grid checks.
    fn as_run(&self) -> Run {
        Run {
            samples: self.deliveries.iter().map(|d| d.c.sample).collect(),
            events: self.events.clone(),
        }
    }
}

/// Runs the discipline as the board will with TIM5 free-running: one sample committed ahead
/// in the compare register; its interrupt served `LATENCY` ticks after the compare tick, or
/// after the end of a stall; the counter and the PPS captures seen only as 32-bit values,
/// extended by a [`TimerExtender`]; all edges captured since the last interrupt fed at the
/// next one, except that of several edges in one stall only the latest survives (the
/// capture register is overwritten, the over-capture flag set).
fn run_compare(
    disc: &mut Discipline,
    edges: &[Edge],
    crystal: Crystal,
    seconds: u32,
    stalls: &[Stall],
) -> CompareRun {
    let end = crystal.tick(f64::from(seconds));
    let stalls: Vec<(u64, u64)> = stalls
        .iter()
        .map(|s| (crystal.tick(s.at), crystal.tick(s.at + s.len)))
        .collect();
    // When an interrupt raised at `t` is served (the end of the stall it falls in).
    let served = |t: u64| {
        stalls
            .iter()
            .find(|(a, b)| t >= *a && t < *b)
            .map_or(t, |(_, b)| *b)
    };
    let mut ext = TimerExtender::from_tick(crystal.origin);
    let mut due = disc.next_sample(crystal.origin);
    let mut pending = edges.iter().peekable();
    let mut out = CompareRun {
        deliveries: Vec::new(),
        events: Vec::new(),
        overcaptured: 0,
    };
    while due.tick <= end {
        let entry = served(due.tick) + LATENCY;
        let now = ext.extend(entry as u32);
        assert_eq!(now, entry, "counter extension");
        let mut fed: Vec<Edge> = Vec::new();
        while let Some(edge) = pending.next_if(|e| e.tick <= entry) {
            if let Some(last) = fed.last() {
                if served(last.tick) == served(edge.tick) && served(edge.tick) != edge.tick {
                    fed.pop();
                    out.overcaptured += 1;
                }
            }
            fed.push(*edge);
        }
        for edge in fed {
            let tick = ext.capture(edge.tick as u32);
            assert_eq!(tick, edge.tick, "capture extension");
            out.events.push((edge, disc.on_pps(tick)));
        }
        let c = catch_up(disc, due, now, GUARD);
        assert!(c.sample.tick <= now, "{c:?}");
        assert!(c.next.tick > now + GUARD, "{c:?}");
        out.deliveries.push(Delivery { now, due, c });
        due = c.next;
    }
    out
}

/// Position of a sample's label on a grid of constant rate.
fn pos(s: &Sample) -> i64 {
    i64::from(s.second) * i64::from(s.rate) + i64::from(s.index)
}

/// From delivery `from` on (no relabelling after it): every grid point is delivered or
/// merged once, in order, and the labels strictly increase.
fn check_accounting(run: &CompareRun, from: usize) {
    let ds = &run.deliveries[from..];
    for pair in ds.windows(2) {
        assert_eq!(pair[0].c.next, pair[1].due);
        assert!(pos(&pair[1].c.sample) > pos(&pair[0].c.sample));
    }
    for d in ds {
        assert_eq!(
            i64::from(d.c.merged),
            pos(&d.c.next) - pos(&d.due) - 1,
            "{d:?}"
        );
    }
    let first = ds.first().expect("deliveries");
    let last = ds.last().expect("deliveries");
    let merged: i64 = ds.iter().map(|d| i64::from(d.c.merged)).sum();
    assert_eq!(
        ds.len() as i64 + merged,
        pos(&last.c.next) - pos(&first.due),
        "delivered + merged = grid points"
    );
}

/// The delivery served at the end of stall `stall`.
fn after_stall(run: &CompareRun, crystal: Crystal, stall: Stall) -> usize {
    let end = crystal.tick(stall.at + stall.len);
    run.deliveries
        .iter()
        .position(|d| d.now >= end)
        .expect("a delivery after the stall")
}

fn free_disc(rate: u32, start: u64) -> Discipline {
    let mut cfg = DisciplineConfig::new(HZ);
    cfg.mode = SyncMode::Free;
    cfg.rate_hz = rate;
    Discipline::new(cfg, start).expect("valid")
}

#[test]
fn stall_in_free_mode_is_caught_up_on_the_grid() {
    // A 2 s stall at 50 Hz and at 1 kHz, with the 32-bit counter wrapping inside it.
    for rate in [50u32, 1_000] {
        let stall = Stall {
            at: 10.0055,
            len: 2.0,
        };
        let crystal = Crystal {
            ppm: 0.0,
            origin: (1u64 << 32) - 11 * u64::from(HZ),
        };
        let mut disc = free_disc(rate, crystal.origin);
        let r = run_compare(&mut disc, &[], crystal, 20, &[stall]);
        check_structure(&r.as_run());
        check_accounting(&r, 0);
        // The exact free-running grid, independently.
        let grid = |k: u64| {
            let r = u64::from(rate);
            crystal.origin + k / r * u64::from(HZ) + k % r * u64::from(HZ) / r
        };
        let i = after_stall(&r, crystal, stall);
        let d = r.deliveries[i];
        let k_due = pos(&d.due) as u64;
        assert!(grid(k_due) >= crystal.tick(stall.at) && grid(k_due - 1) < crystal.tick(stall.at));
        // Points in (due, now + guard], counted from the grid.
        let expected = (k_due + 1..)
            .take_while(|k| grid(*k) <= d.now + GUARD)
            .count() as u32;
        assert_eq!(d.c.merged, expected, "rate {rate}");
        // The 2 s of grid points in the stall: one delivered, the others merged.
        assert_eq!(d.c.merged + 1, 2 * rate);
        // The snapshot is labelled with the last point before `now`, the next is the first
        // after `now + guard`: no lag.
        let k = pos(&d.c.sample) as u64;
        assert!(grid(k) <= d.now && grid(k + 1) > d.now, "{d:?}");
        assert_eq!(d.c.next.tick, grid(pos(&d.c.next) as u64));
        // Every other interrupt is on time: its sample is the due one, `LATENCY` late.
        for (j, d) in r.deliveries.iter().enumerate() {
            if j != i {
                assert_eq!((d.c.sample, d.c.merged), (d.due, 0));
                assert_eq!(d.now - d.c.sample.tick, LATENCY);
            }
        }
        assert!(
            d.due.tick < 1 << 32 && d.now > 1 << 32,
            "the wrap is inside the stall"
        );
        assert_eq!(r.deliveries.len() as u32 + d.c.merged, 20 * rate + 1);
    }
}

#[test]
fn stall_when_locked_keeps_the_gnss_seconds() {
    // HSE (+37 ppm) and HSI (-4 %, +3 %), 50 Hz and 1 kHz; stalls of 2 s (two edges inside:
    // one over-captured), 0.5 s (none or one edge) and 1.2 s; the counter wraps in the
    // first stall.
    for (tolerance, ppm) in [
        (HSE_CRYSTAL_TOLERANCE_PPM, 37.0),
        (HSI_TOLERANCE_PPM, -40_000.0),
        (HSI_TOLERANCE_PPM, 30_000.0),
    ] {
        for rate in [50u32, 1_000] {
            let stalls = [
                Stall { at: 20.3, len: 2.0 },
                Stall { at: 30.9, len: 0.5 },
                Stall {
                    at: 40.01,
                    len: 1.2,
                },
            ];
            let mut sc = Scenario::new(ppm, 8, 60);
            // Tick 2^32 (the counter wraps) at 21 s, inside the first stall.
            sc.crystal.origin += (1u64 << 32) - sc.crystal.tick(21.0);
            let mut cfg = DisciplineConfig::for_clock(HZ, tolerance);
            cfg.rate_hz = rate;
            let mut disc = Discipline::new(cfg, sc.crystal.origin).expect("valid");
            let r = run_compare(&mut disc, &sc.edges(), sc.crystal, sc.seconds, &stalls);
            let run = r.as_run();
            check_structure(&run);
            let what = format!("{tolerance} ppm tolerance, {ppm} ppm, {rate} Hz");
            // Labels count true seconds throughout (panics otherwise); the lock is kept.
            let offset = label_offset(&run).expect("locked");
            assert_eq!(disc.stats().locks, 1, "{what}");
            assert_eq!(disc.stats().glitches, 0, "{what}");
            assert_eq!(disc.state(), SyncState::Locked);
            // Edges 21 and 22 fall in the first stall: 21 is over-captured, 22 reacquires
            // (one missed second); the others are accepted.
            assert_eq!(r.overcaptured, 1, "{what}");
            assert_eq!(disc.stats().missed, 1, "{what}");
            let reacquired: Vec<_> = r
                .events
                .iter()
                .filter_map(|(e, ev)| match ev {
                    PpsEvent::Reacquired { missed, .. } => Some((e.second, *missed)),
                    _ => None,
                })
                .collect();
            assert_eq!(reacquired, vec![(Some(22), 1)], "{what}");
            // Every locked sample, those after the stalls included, on the GNSS grid.
            let err = locked_error(&run, sc.crystal);
            assert!(err < grid_bound(sc.crystal, 8, rate), "{what}: {err}");
            // Accounting from the first locked interrupt on.
            let from = r
                .deliveries
                .iter()
                .position(|d| d.due.state == SyncState::Locked)
                .expect("locked");
            check_accounting(&r, from);
            for stall in stalls {
                let i = after_stall(&r, sc.crystal, stall);
                let d = r.deliveries[i];
                // The snapshot's label: the last GNSS grid point before `now`; the next:
                // the first after `now + guard` (to within the jitter bound).
                let t_now = sc.crystal.time(d.now);
                let truth = |s: &Sample| {
                    (i64::from(s.second) + offset) as f64 + f64::from(s.index) / f64::from(rate)
                };
                let slack = 30.0 / f64::from(HZ);
                assert!(truth(&d.c.sample) <= t_now + slack, "{what}: {d:?}");
                assert!(
                    truth(&d.c.sample) + 1.0 / f64::from(rate) > t_now - slack,
                    "{what}: {d:?}"
                );
                assert!(truth(&d.c.next) > sc.crystal.time(d.now + GUARD) - slack);
                // The points passed over: the stall's length in grid points, about.
                let passed = f64::from(d.c.merged) / f64::from(rate);
                assert!(
                    (passed - stall.len).abs() <= 2.0 / f64::from(rate) + 1e-9,
                    "{what}: {} merged in a {} s stall",
                    d.c.merged,
                    stall.len
                );
                // Back on time from the next interrupt on.
                let next = r.deliveries[i + 1];
                assert_eq!((next.c.sample, next.c.merged), (next.due, 0));
                assert_eq!(next.now - next.c.sample.tick, LATENCY);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random stalls (1-3, 5 ms to 2.5 s, anywhere after the lock), counter origin (wraps
    /// anywhere), mode, rate, clock: labels of delivered samples strictly increase, delivered
    /// + merged = every grid point, never a panic; PPS mode keeps the lock and the GNSS
    /// seconds.
    #[test]
    fn stalls_deliver_or_merge_every_grid_point(
        stalls in proptest::collection::vec((0.0f64..5.0, 0.005f64..2.5), 1..4),
        origin in 0u64..(1 << 32),
        pps in any::<bool>(),
        hsi in any::<bool>(),
        rate in prop::sample::select(vec![10u32, 50, 100, 1_000]),
        ppm_fraction in -1.0f64..1.0,
        jitter in 0i64..40,
        seed in 1u64..u64::MAX,
    ) {
        let (tolerance, ppm) = if hsi {
            (HSI_TOLERANCE_PPM, ppm_fraction * 45_000.0)
        } else {
            (HSE_CRYSTAL_TOLERANCE_PPM, ppm_fraction * 100.0)
        };
        let stalls: Vec<Stall> = stalls
            .iter()
            .enumerate()
            .map(|(i, (at, len))| Stall { at: 4.0 + 8.0 * i as f64 + at, len: *len })
            .collect();
        let mut sc = Scenario::new(ppm, jitter, 30);
        sc.seed = seed;
        sc.crystal.origin = origin;
        let mut cfg = DisciplineConfig::for_clock(HZ, tolerance);
        cfg.rate_hz = rate;
        cfg.mode = if pps { SyncMode::Pps } else { SyncMode::Free };
        let mut disc = Discipline::new(cfg, origin).expect("valid");
        let r = run_compare(&mut disc, &sc.edges(), sc.crystal, sc.seconds, &stalls);
        let run = r.as_run();
        check_structure(&run);
        let from = if pps {
            label_offset(&run).expect("locked");
            prop_assert_eq!(disc.stats().locks, 1);
            prop_assert_eq!(disc.stats().glitches, 0);
            prop_assert_eq!(disc.state(), SyncState::Locked);
            let err = locked_error(&run, sc.crystal);
            prop_assert!(err < grid_bound(sc.crystal, jitter, rate), "error {}", err);
            r.deliveries
                .iter()
                .position(|d| d.due.state == SyncState::Locked)
                .expect("locked")
        } else {
            0
        };
        check_accounting(&r, from);
    }
}
