//! The PPS simulation of the timing tests: a crystal (or HSI) `ppm` off nominal, PPS edges
//! with jitter, lost and spurious pulses ([`Scenario`]; random ones for the property tests:
//! [`scenario`]), the board's sample loop around a [`Discipline`] ([`run`]), and the checks
//! of a run (structure, labels, error against the true GNSS grid).

use std::collections::VecDeque;
use std::ops::Range;

use odo_unit::timing::*;
use proptest::collection::vec;
use proptest::prelude::*;

/// The sample timer's clock, Hz.
pub const HZ: u32 = 84_000_000;

/// A deterministic xorshift generator for jitter and spurious edges.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in `-j..=j`.
    fn jitter(&mut self, j: i64) -> i64 {
        if j == 0 {
            0
        } else {
            (self.next() % (2 * j as u64 + 1)) as i64 - j
        }
    }
}

/// An MCU crystal `ppm` off nominal: true seconds to timer ticks.
#[derive(Clone, Copy, Debug)]
pub struct Crystal {
    pub ppm: f64,
    pub origin: u64,
}
impl Crystal {
    pub fn tick(&self, t: f64) -> u64 {
        self.origin + (t * f64::from(HZ) * (1.0 + self.ppm * 1e-6)).round() as u64
    }
    pub fn time(&self, tick: u64) -> f64 {
        (tick - self.origin) as f64 / (f64::from(HZ) * (1.0 + self.ppm * 1e-6))
    }
}

/// One PPS edge of the simulation: tick and the true second it marks (`None`: spurious).
#[derive(Clone, Copy, Debug)]
pub struct Edge {
    pub tick: u64,
    pub second: Option<u32>,
}

#[derive(Debug)]
pub struct Scenario {
    pub crystal: Crystal,
    pub jitter: i64,
    pub seconds: u32,
    pub lost: Vec<u32>,
    pub spurious: Vec<f64>,
    pub seed: u64,
}

impl Scenario {
    pub fn new(ppm: f64, jitter: i64, seconds: u32) -> Self {
        Self {
            crystal: Crystal { ppm, origin: 1_000 },
            jitter,
            seconds,
            lost: Vec::new(),
            spurious: Vec::new(),
            seed: 0x2545_f491_4f6c_dd1d,
        }
    }

    pub fn edges(&self) -> Vec<Edge> {
        let mut rng = Rng(self.seed);
        let mut edges: Vec<Edge> = (1..self.seconds)
            .filter(|s| !self.lost.contains(s))
            .map(|s| Edge {
                tick: (self.crystal.tick(f64::from(s)) as i64 + rng.jitter(self.jitter)) as u64,
                second: Some(s),
            })
            .collect();
        edges.extend(self.spurious.iter().map(|t| Edge {
            tick: self.crystal.tick(*t),
            second: None,
        }));
        edges.sort_by_key(|e| e.tick);
        edges
    }
}

/// The property tests' scenarios: 60 s of a clock off nominal by a `ppm` drawn from `ppm`,
/// jitter up to 40 ticks, up to 12 lost pulses (seconds 2-59) and 6 spurious edges, any
/// seed. Spurious edges within `glitch` seconds of a true second are left out: the
/// discipline cannot tell them from the real edge (the glitch window, or the acquisition
/// window before the lock).
pub fn scenario(ppm: Range<f64>, glitch: f64) -> impl Strategy<Value = Scenario> {
    (
        ppm,
        0i64..40,
        vec(2u32..60, 0..12),
        vec(0.5f64..59.0, 0..6),
        1u64..u64::MAX,
    )
        .prop_map(move |(ppm, jitter, lost, spurious, seed)| Scenario {
            lost,
            spurious: spurious
                .into_iter()
                .filter(|t| (t - t.round()).abs() > glitch)
                .collect(),
            seed,
            ..Scenario::new(ppm, jitter, 60)
        })
}

/// What a run produced: the samples in order, with the events delivered before each.
pub struct Run {
    pub samples: Vec<Sample>,
    pub events: Vec<(Edge, PpsEvent)>,
}

/// Runs the discipline the way the board does: two samples committed ahead of the timer,
/// PPS edges delivered as they happen, until the true time `seconds`.
pub fn run(disc: &mut Discipline, edges: &[Edge], crystal: Crystal, seconds: u32) -> Run {
    let end = crystal.tick(f64::from(seconds));
    let mut now = crystal.origin;
    let mut ahead: VecDeque<Sample> = VecDeque::new();
    ahead.push_back(disc.next_sample(now));
    ahead.push_back(disc.next_sample(now));
    let mut pending = edges.iter().peekable();
    let mut out = Run {
        samples: Vec::new(),
        events: Vec::new(),
    };
    while let Some(sample) = ahead.pop_front() {
        if sample.tick > end {
            break;
        }
        while let Some(edge) = pending.next_if(|e| e.tick <= sample.tick) {
            out.events.push((*edge, disc.on_pps(edge.tick)));
        }
        now = now.max(sample.tick);
        out.samples.push(sample);
        ahead.push_back(disc.next_sample(now));
    }
    out
}

/// Runs `sc` on `disc` (as [`run`]) and checks the run's structure ([`check_structure`]);
/// returns the run and its [`locked_error`] (s).
pub fn run_checked(disc: &mut Discipline, sc: &Scenario) -> (Run, f64) {
    let r = run(disc, &sc.edges(), sc.crystal, sc.seconds);
    check_structure(&r);
    let err = locked_error(&r, sc.crystal);
    (r, err)
}

/// The pulses missed before each reacquisition of a run, in order.
pub fn reacquisitions(run: &Run) -> Vec<u32> {
    run.events
        .iter()
        .filter_map(|(_, e)| match e {
            PpsEvent::Reacquired { missed, .. } => Some(*missed),
            _ => None,
        })
        .collect()
}

/// Whether every sample of a run after the first `n` is locked.
pub fn all_locked_after(run: &Run, n: usize) -> bool {
    run.samples
        .iter()
        .skip(n)
        .all(|s| s.state == SyncState::Locked)
}

pub fn pps_disc() -> Discipline {
    Discipline::new(DisciplineConfig::new(HZ), 1_000).expect("valid config")
}

/// The true second of label `label` (from the events), checking the offset is unique.
pub fn label_offset(run: &Run) -> Option<i64> {
    let mut offset = None;
    for (edge, event) in &run.events {
        let second = match event {
            PpsEvent::Locked { second }
            | PpsEvent::Accepted { second, .. }
            | PpsEvent::Reacquired { second, .. } => *second,
            _ => continue,
        };
        let truth = edge.second.expect("a spurious edge was accepted") as i64;
        let o = truth - i64::from(second);
        if let Some(prev) = offset {
            assert_eq!(prev, o, "labels must count true seconds while locked");
        }
        offset = Some(o);
    }
    offset
}

/// Structural invariants of any run: ticks increasing with gaps of at least half a sample
/// period (of a timer up to 5 % slow), labels (second, index) increasing, index below the
/// rate.
pub fn check_structure(run: &Run) {
    for pair in run.samples.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let half = u64::from(HZ) / (2 * u64::from(a.rate)) * 95 / 100;
        assert!(b.tick >= a.tick + half, "gap too short: {a:?} -> {b:?}");
        assert!(
            (b.second, b.index) > (a.second, a.index),
            "labels must increase: {a:?} -> {b:?}"
        );
        assert!(b.index < b.rate);
    }
}

/// Largest error (seconds) of locked samples against the true GNSS grid.
pub fn locked_error(run: &Run, crystal: Crystal) -> f64 {
    let Some(offset) = label_offset(run) else {
        return 0.0;
    };
    run.samples
        .iter()
        .filter(|s| s.state == SyncState::Locked)
        .map(|s| {
            let truth =
                (i64::from(s.second) + offset) as f64 + f64::from(s.index) / f64::from(s.rate);
            (crystal.time(s.tick) - truth).abs()
        })
        .fold(0.0, f64::max)
}

/// The bound on `locked_error` of `locks_and_follows_the_pps_with_crystal_offsets`
/// generalised to any rate: the samples committed before an edge is fed sit at the previous
/// edge (one jitter) plus the measured period (two jitters) times `1 + k / rate`, k <= 2:
/// 3.08 jitters at 50 Hz (3.1 taken), 3.4 at 10 Hz; plus rounding. In seconds of a timer off
/// by the crystal's offset (a tick of a timer 4 % slow lasts 4 % longer).
pub fn grid_bound(crystal: Crystal, jitter: i64, rate: u32) -> f64 {
    let jitters = (1.0 + 2.0 * (1.0 + 2.0 / f64::from(rate))).max(3.1);
    (jitters * jitter as f64 + 3.0) / (f64::from(HZ) * (1.0 + crystal.ppm * 1e-6))
}
