//! The sample timer's interrupt (`odo_unit::timing::compare`) on a simulated TIM5: the race
//! of a compare firing between the handler's reads, the re-arm decision, the PPS capture off
//! in free mode, and the bounded catch-up after a stall.

use odo_unit::timing::compare::{set_capture, SR_CAPTURE, SR_COMPARE, SR_OVERCAPTURE};
use odo_unit::timing::*;
use proptest::prelude::*;

const HZ: u32 = 84_000_000;
const GUARD: u64 = 840;

/// A simulated TIM5: a free-running 32-bit counter that advances `per_access` ticks at
/// every register access (the handler's own time), a compare that sets its flag when the
/// counter passes the compare value, a PPS capture of the edges in `edges` while enabled.
struct SimTim {
    /// The 64-bit true time, ticks (the counter is its low 32 bits).
    t: u64,
    per_access: u64,
    ccr2: u32,
    ccr1: u32,
    sr: u32,
    capture_on: bool,
    edges: Vec<u64>,
}

impl SimTim {
    fn new(per_access: u64, edges: Vec<u64>) -> Self {
        Self {
            t: 0,
            per_access,
            ccr2: 0,
            ccr1: 0,
            sr: 0,
            capture_on: false,
            edges,
        }
    }

    /// Time passes to `to`: compare matches and PPS captures on the way.
    fn run_to(&mut self, to: u64) {
        let from = self.t;
        // A match when the counter steps onto CCR2 (once per 2^32 ticks).
        let mut m = (from & !0xFFFF_FFFF) | u64::from(self.ccr2);
        if m <= from {
            m += 1 << 32;
        }
        if m <= to {
            self.sr |= SR_COMPARE;
        }
        if self.capture_on {
            for &e in self.edges.iter().filter(|&&e| e > from && e <= to) {
                if self.sr & SR_CAPTURE != 0 {
                    self.sr |= SR_OVERCAPTURE;
                }
                self.sr |= SR_CAPTURE;
                self.ccr1 = e as u32;
            }
        }
        self.t = to;
    }

    fn access(&mut self) {
        let to = self.t + self.per_access;
        self.run_to(to);
    }

    /// When the next interrupt is raised after now (a flag already set: now).
    fn next_irq(&self) -> Option<u64> {
        if self.sr & (SR_COMPARE | if self.capture_on { SR_CAPTURE } else { 0 }) != 0 {
            return Some(self.t);
        }
        let mut m = (self.t & !0xFFFF_FFFF) | u64::from(self.ccr2);
        if m <= self.t {
            m += 1 << 32;
        }
        let edge = self
            .edges
            .iter()
            .copied()
            .filter(|&e| self.capture_on && e > self.t)
            .min();
        Some(edge.map_or(m, |e| e.min(m)))
    }
}

impl CompareTimer for SimTim {
    fn flags(&mut self) -> u32 {
        self.access();
        self.sr
    }
    fn clear(&mut self, flags: u32) {
        self.access();
        self.sr &= !flags;
    }
    fn counter(&mut self) -> u32 {
        self.access();
        self.t as u32
    }
    fn capture(&mut self) -> u32 {
        self.access();
        self.sr &= !SR_CAPTURE;
        self.ccr1
    }
    fn set_compare(&mut self, value: u32) {
        self.access();
        self.ccr2 = value;
    }
    fn force_compare(&mut self) {
        self.access();
        self.sr |= SR_COMPARE;
    }
    fn enable_capture(&mut self, on: bool) {
        self.access();
        self.capture_on = on;
    }
}

fn disc(mode: SyncMode, rate: u32) -> Discipline {
    let mut cfg = DisciplineConfig::new(HZ);
    cfg.mode = mode;
    cfg.rate_hz = rate;
    Discipline::new(cfg, 0).expect("valid")
}

/// Runs the interrupt handler on `tim` for `ticks` of time, an interrupt served
/// `latency` ticks after it is raised; returns the samples delivered and the events.
fn run(
    tim: &mut SimTim,
    disc: &mut Discipline,
    ticks: u64,
    latency: u64,
) -> (Vec<Sample>, Vec<TimerEvent>) {
    let s0 = disc.next_sample(0);
    let s1 = disc.next_sample(0);
    assert_eq!(s0.tick, 0);
    tim.ccr2 = s1.tick as u32;
    let mut sched = CompareSchedule {
        ext: TimerExtender::new(0),
        next: s1,
        guard: GUARD,
    };
    let (mut samples, mut events) = (vec![s0], Vec::new());
    while let Some(irq) = tim.next_irq() {
        if irq >= ticks {
            break;
        }
        let entry = irq.max(tim.t) + latency;
        tim.run_to(entry);
        let e = sched.on_interrupt(tim, disc);
        if let Some(s) = e.sample {
            samples.push(s);
        }
        events.push(e);
    }
    (samples, events)
}

#[test]
fn compare_action_table() {
    use CompareAction::*;
    for (flag, now, next, want) in [
        (false, 99, 100, None),
        (true, 99, 100, Rearm),
        (true, 100, 100, Sample),
        (false, 100, 100, Sample), // reached without the flag (forced, or its flag cleared)
        (true, 5_000_000_000, 100, Sample),
        (false, 0, u64::MAX, None),
    ] {
        assert_eq!(compare_action(flag, now, next), want, "{flag} {now} {next}");
    }
}

/// The compare race: an interrupt (a PPS capture) entered just before a compare tick, the
/// compare firing at any point of the handler's reads. Every sample is still delivered,
/// each within a few microseconds of its tick: no compare is lost for 2^32 ticks.
#[test]
fn a_compare_firing_between_the_reads_is_not_lost() {
    let rate = 50;
    let period = u64::from(HZ / rate);
    for per_access in [1u64, 3, 10] {
        for offset in 0..40u64 {
            // PPS edges whose capture interrupt is entered `offset` ticks before sample 10's
            // compare (latency 20 ticks), then one per second.
            let latency = 20;
            let first = 10 * period - offset - latency;
            let edges: Vec<u64> = (0..3).map(|k| first + k * u64::from(HZ)).collect();
            let mut tim = SimTim::new(per_access, edges);
            let mut d = disc(SyncMode::Pps, rate);
            tim.capture_on = true;
            let (samples, events) = run(&mut tim, &mut d, 3 * u64::from(HZ), latency);
            // Three seconds of samples, none missing.
            assert!(
                samples.len() >= 3 * rate as usize - 2,
                "{per_access} {offset}: {}",
                samples.len()
            );
            for e in events.iter().filter(|e| e.sample.is_some()) {
                assert!(e.latency < 2_000, "{per_access} {offset}: {e:?}");
                assert_eq!(e.merged, 0, "{per_access} {offset}: {e:?}");
            }
            for pair in samples.windows(2) {
                assert!(
                    pair[1].tick - pair[0].tick <= 2 * period,
                    "{per_access} {offset}"
                );
            }
        }
    }
}

/// The same race with the old order (counter before flags, sample only when due): the
/// simulation reproduces the loss, so the test above does test the race.
#[test]
fn the_old_order_loses_the_compare_in_this_simulation() {
    let period = u64::from(HZ / 50);
    let latency = 20;
    let mut lost = 0;
    for offset in 0..40u64 {
        let mut tim = SimTim::new(3, vec![10 * period - offset - latency]);
        tim.capture_on = true;
        tim.run_to(10 * period - offset);
        tim.ccr2 = (10 * period) as u32;
        let cnt = u64::from(tim.counter());
        let sr = tim.flags();
        tim.clear(sr & SR_COMPARE);
        if sr & SR_COMPARE != 0 && cnt < 10 * period {
            // Cleared while not yet due: not taken, not re-armed.
            lost += 1;
        }
    }
    assert!(lost > 0);
}

#[test]
fn a_stale_compare_flag_rearms() {
    let mut tim = SimTim::new(1, vec![]);
    let mut d = disc(SyncMode::Free, 50);
    let s1 = {
        let _ = d.next_sample(0);
        d.next_sample(0)
    };
    let mut sched = CompareSchedule {
        ext: TimerExtender::new(0),
        next: s1,
        guard: GUARD,
    };
    tim.run_to(1000);
    tim.sr = SR_COMPARE;
    tim.ccr2 = 0;
    let e = sched.on_interrupt(&mut tim, &mut d);
    assert_eq!(e.sample, None);
    assert_eq!(tim.ccr2, s1.tick as u32, "compare programmed again");
    assert_eq!(tim.sr & SR_COMPARE, 0);
}

/// Free mode: the capture is off, so edges of a long free run do not become a false
/// over-capture at the switch to pps.
#[test]
fn switching_to_pps_reports_no_false_overcapture() {
    let hz = u64::from(HZ);
    let edges: Vec<u64> = (1..8).map(|k| k * hz + 1000).collect();
    let mut tim = SimTim::new(1, edges);
    let mut d = disc(SyncMode::Free, 50);
    let (_, events) = run(&mut tim, &mut d, 3 * hz + hz / 2, 20);
    assert!(events.iter().all(|e| e.pps.is_none() && !e.overcapture));
    // With the capture left on in free mode the flags pile up:
    let mut left_on = SimTim::new(1, (1..4).map(|k| k * hz + 1000).collect());
    left_on.capture_on = true;
    left_on.run_to(3 * hz + hz / 2);
    assert_ne!(left_on.sr & SR_OVERCAPTURE, 0);
    // The switch: stale flags cleared, then on.
    set_capture(&mut left_on, true);
    assert_eq!(left_on.sr & (SR_CAPTURE | SR_OVERCAPTURE), 0);
    set_capture(&mut tim, true);
    let mut cfg = *d.config();
    cfg.mode = SyncMode::Pps;
    d.set_config(cfg).expect("valid");
    let to = tim.t + 3 * hz;
    let mut sched = CompareSchedule {
        ext: TimerExtender::from_tick(tim.t),
        next: d.next_sample(tim.t),
        guard: GUARD,
    };
    tim.ccr2 = sched.next.tick as u32;
    let mut edges_seen = 0;
    while let Some(irq) = tim.next_irq() {
        if irq >= to {
            break;
        }
        tim.run_to(irq.max(tim.t) + 20);
        let e = sched.on_interrupt(&mut tim, &mut d);
        assert!(!e.overcapture, "{e:?}");
        edges_seen += usize::from(e.pps.is_some());
    }
    assert_eq!(edges_seen, 3);
}

/// The reference: catch-up committing every grid point one by one.
fn catch_up_by_steps(disc: &mut Discipline, due: Sample, now: u64, guard: u64) -> CatchUp {
    let limit = now + guard;
    let (mut sample, mut merged) = (disc.begin_second(due), 0u32);
    loop {
        let next = disc.next_sample(now);
        if next.tick > limit {
            return CatchUp {
                sample,
                merged,
                next,
            };
        }
        merged += 1;
        if next.tick <= now {
            sample = next;
        }
    }
}

#[test]
fn a_long_stall_at_1khz_is_caught_up_in_one_step() {
    // 0.8 s at 1 kHz: 800 points, skipped by arithmetic (`skip_to` counts them).
    let mut d = disc(SyncMode::Free, 1_000);
    let _ = d.next_sample(0);
    let due = d.next_sample(0);
    let now = due.tick + 800 * u64::from(HZ / 1000) + 17;
    let mut probe = d.clone();
    assert_eq!(
        probe.skip_to(now),
        799,
        "points 2..=800 skipped, 801 is the sample"
    );
    let mut reference = d.clone();
    let want = catch_up_by_steps(&mut reference, due, now, GUARD);
    let got = catch_up(&mut d, due, now, GUARD);
    assert_eq!(got, want);
    assert_eq!(got.merged, 800);
    assert_eq!(
        d.next_sample(now + 10 * u64::from(HZ)),
        reference.next_sample(now + 10 * u64::from(HZ))
    );
}

proptest! {
    #[test]
    fn catch_up_equals_committing_every_point(
        rate in prop::sample::select(vec![1u32, 2, 7, 50, 333, 1000, 10_000]),
        new_rate in prop::sample::select(vec![1u32, 50, 1000]),
        stall in 0u64..5_000_000_000,
        warmup in 0u32..60,
    ) {
        let mut d = disc(SyncMode::Free, rate);
        let mut due = d.next_sample(0);
        for _ in 0..warmup {
            due = d.next_sample(due.tick);
        }
        let mut cfg = *d.config();
        cfg.rate_hz = new_rate;
        d.set_config(cfg).expect("valid");
        let now = due.tick + stall;
        let mut reference = d.clone();
        let want = catch_up_by_steps(&mut reference, due, now, GUARD);
        let got = catch_up(&mut d, due, now, GUARD);
        prop_assert_eq!(got, want);
        prop_assert_eq!(d.next_sample(now), reference.next_sample(now));
    }
}

/// A new rate reaches the sampler between two of its interrupts (the firmware applies the
/// queued configuration at the start of the next interrupt). Set after any sample of a
/// second, the last one included, it applies from the first sample of the next whole
/// second: every sample before it has the old rate and the old grid, every one from it the
/// new rate and the new grid, also when the change comes after the second-to-last sample,
/// when the second's first sample is already committed (programmed one sample ahead).
#[test]
fn a_rate_change_applies_from_the_next_whole_second() {
    let hz = u64::from(HZ);
    for (old, new) in [
        (2u32, 5u32),
        (3, 1),
        (1, 2),
        (50, 100),
        (100, 50),
        (1000, 7),
    ] {
        let picks = (0..old).filter(|k| *k < 3 || k + 3 >= old || *k == old / 2);
        for k in picks {
            let mut tim = SimTim::new(1, Vec::new());
            let mut d = disc(SyncMode::Free, old);
            let s0 = d.next_sample(0);
            let s1 = d.next_sample(0);
            tim.ccr2 = s1.tick as u32;
            let mut sched = CompareSchedule {
                ext: TimerExtender::new(0),
                next: s1,
                guard: GUARD,
            };
            let mut samples = vec![s0];
            while let Some(irq) = tim.next_irq() {
                if irq >= 4 * hz {
                    break;
                }
                tim.run_to(irq.max(tim.t) + 20);
                let Some(s) = sched.on_interrupt(&mut tim, &mut d).sample else {
                    continue;
                };
                samples.push(s);
                if (s.second, s.index) == (1, k) {
                    let mut cfg = *d.config();
                    cfg.rate_hz = new;
                    d.set_config(cfg).expect("valid");
                }
            }
            let case = format!("{old} -> {new} Hz after sample {k}");
            for s in &samples {
                let rate = if s.second <= 1 { old } else { new };
                assert_eq!(s.rate, rate, "{case}: {s:?}");
                let tick = u64::from(s.second) * hz + u64::from(s.index) * hz / u64::from(rate);
                assert_eq!(s.tick, tick, "{case}: {s:?}");
            }
            for second in 0..4 {
                let n = samples.iter().filter(|s| s.second == second).count();
                let rate = if second <= 1 { old } else { new };
                assert_eq!(n, rate as usize, "{case}: second {second}");
            }
        }
    }
}
