//! The simulated drive of the `qemu` build: QEMU's timers ignore encoder mode, so the two
//! counters, index pulses and fault lines come from this deterministic path instead.
//! Everything downstream (counter extension, index tracking, integration, records, link) is
//! the real code.
//!
//! The path repeats every 20 s; wheel speeds in increments per second (20,000 increments per
//! turn of a 0.260 m wheel: 12,243 increments/s is 0.5 m/s):
//!
//! | from | to   | left    | right   | motion |
//! |------|------|---------|---------|--------|
//! | 0 s  | 2 s  | 12,000  | 12,000  | straight ahead |
//! | 2 s  | 5 s  | 14,000  | 8,000   | curve to the right |
//! | 5 s  | 7 s  | 6,000   | -6,000  | spin clockwise on the spot |
//! | 7 s  | 10 s | -10,000 | -10,000 | straight back (reversing) |
//! | 10 s | 13 s | -4,000  | -9,000  | curve backwards |
//! | 13 s | 16 s | 7,000   | 13,000  | curve to the left |
//! | 16 s | 18 s | 0       | 0       | standing |
//! | 18 s | 20 s | 20,000  | 20,000  | straight ahead at 1 m/s |
//!
//! Counter wraps: the left (32-bit) counter starts 40,000 below its wrap, so it wraps in the
//! first seconds; the right (16-bit) counter wraps every few seconds. Index pulses fall at
//! whole turns of each wheel (20,000 increments, whatever `ticks_per_rev` says). Faults: at
//! 7.5 s of every lap the right counter gains 25 spurious increments (the next right index
//! pulse is flagged as a count mismatch), and the right fault line is active from 12.0 s to
//! 12.5 s.

/// Increments per wheel turn of the simulated encoders.
pub const TICKS_PER_REV: i64 = 20_000;
/// Ticks of the sample timeline per second (QEMU's timers: 1 GHz).
const HZ: i64 = 1_000_000_000;
/// Left raw counter value at absolute count 0.
const LEFT_RAW0: u32 = u32::MAX - 40_000;
/// Right raw counter value at absolute count 0.
const RIGHT_RAW0: u32 = 1_000;
/// Index phase of each wheel (absolute count of its first index pulse).
const INDEX_OFFSET: [i64; 2] = [7_000, 13_000];

/// (duration ms, left increments/s, right increments/s).
const PATH: [(i64, i64, i64); 8] = [
    (2_000, 12_000, 12_000),
    (3_000, 14_000, 8_000),
    (2_000, 6_000, -6_000),
    (3_000, -10_000, -10_000),
    (3_000, -4_000, -9_000),
    (3_000, 7_000, 13_000),
    (2_000, 0, 0),
    (2_000, 20_000, 20_000),
];
const LAP_MS: i64 = 20_000;
const GLITCH_AT_MS: i64 = 7_500;
const GLITCH_COUNTS: i64 = 25;
const FAULT_MS: (i64, i64) = (12_000, 12_500);

/// Physical wheel positions (increments) at `t` ticks.
fn position(t: i64) -> [i64; 2] {
    let lap_ticks = LAP_MS * (HZ / 1_000);
    let laps = t.div_euclid(lap_ticks);
    let mut rest = t.rem_euclid(lap_ticks);
    let mut pos = [0i64; 2];
    for (ms, l, r) in PATH {
        let d = ms * (HZ / 1_000);
        let dt = rest.min(d);
        pos[0] += laps * l * ms / 1_000 + l * dt / HZ;
        pos[1] += laps * r * ms / 1_000 + r * dt / HZ;
        rest -= dt;
    }
    pos
}

/// Spurious increments of the right counter up to `t` ticks.
fn glitch(t: i64) -> i64 {
    let lap_ticks = LAP_MS * (HZ / 1_000);
    let laps = t.div_euclid(lap_ticks);
    let passed = t.rem_euclid(lap_ticks) >= GLITCH_AT_MS * (HZ / 1_000);
    GLITCH_COUNTS * (laps + i64::from(passed))
}

/// An index pulse: the wheel (0 left, 1 right) and the raw counter value it latched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IndexPulse {
    /// 0 = left, 1 = right.
    pub wheel: usize,
    /// Raw counter value at the pulse.
    pub raw: u32,
}

/// The simulated encoders.
pub struct SimDrive {
    last: [i64; 2],
    pending: heapless::Vec<IndexPulse, 8>,
}

impl Default for SimDrive {
    fn default() -> Self {
        Self::new()
    }
}

impl SimDrive {
    /// The drive at rest at t = 0.
    pub const fn new() -> Self {
        Self {
            last: [0, 0],
            pending: heapless::Vec::new(),
        }
    }

    fn raw(wheel: usize, counts: i64) -> u32 {
        if wheel == 0 {
            LEFT_RAW0.wrapping_add(counts as u32)
        } else {
            RIGHT_RAW0.wrapping_add(counts as u32) & 0xFFFF
        }
    }

    /// The raw counters at `tick` (left 32-bit, right 16-bit); index pulses passed since the
    /// previous call are kept for [`Self::take_index`].
    pub fn snapshot(&mut self, tick: u64) -> odo_unit::unit::RawCounts {
        let t = tick as i64;
        let now = position(t);
        let counts = [now[0], now[1] + glitch(t)];
        for wheel in 0..2 {
            let (lo, hi) = if now[wheel] >= self.last[wheel] {
                (self.last[wheel], now[wheel])
            } else {
                (now[wheel], self.last[wheel])
            };
            // Index positions k * TICKS_PER_REV + offset in (lo, hi].
            let mut k = (lo - INDEX_OFFSET[wheel]).div_euclid(TICKS_PER_REV) + 1;
            while k * TICKS_PER_REV + INDEX_OFFSET[wheel] <= hi {
                let at = k * TICKS_PER_REV + INDEX_OFFSET[wheel] + (counts[wheel] - now[wheel]);
                let _ = self.pending.push(IndexPulse {
                    wheel,
                    raw: Self::raw(wheel, at),
                });
                k += 1;
            }
            self.last[wheel] = now[wheel];
        }
        odo_unit::unit::RawCounts {
            left: Self::raw(0, counts[0]),
            right: Self::raw(1, counts[1]),
        }
    }

    /// The index pulses found by the last snapshots, oldest first.
    pub fn take_index(&mut self) -> impl Iterator<Item = IndexPulse> + '_ {
        self.pending.drain(..)
    }

    /// The fault lines at `tick`: (left, right).
    pub fn faults(&self, tick: u64) -> (bool, bool) {
        let ms = (tick as i64 / (HZ / 1_000)).rem_euclid(LAP_MS);
        (false, (FAULT_MS.0..FAULT_MS.1).contains(&ms))
    }
}

/// True effective diameter of the simulated left wheel, metres (the settings' default, the
/// designed 0.26 m, is 0.5 mm short of it: a calibration has something to find).
pub const TRUE_LEFT_DIAMETER: f64 = 0.2605;
/// True effective diameter of the right wheel, metres.
pub const TRUE_RIGHT_DIAMETER: f64 = 0.2597;
/// True track width, metres.
pub const TRUE_TRACK_WIDTH: f64 = 0.5655;

/// Pose of the chassis reference point (the axle centre): x east, y north (metres), heading
/// (radians, 0 along +y, clockwise, reduced to one turn).
#[derive(Debug, Clone, Copy, Default)]
pub struct TruePose {
    /// East, metres.
    pub x: f64,
    /// North, metres.
    pub y: f64,
    /// Heading, radians.
    pub heading: f64,
}

/// The simulated chassis's true motion: the wheel positions of [`position`] (without the
/// spurious counts) through the true geometry, integrated exactly (constant wheel speeds
/// make arcs), from (0, 0, 0) at tick 0.
pub struct Truth {
    /// Tick the pose is of.
    at: i64,
    pose: TruePose,
}

impl Default for Truth {
    fn default() -> Self {
        Self::new()
    }
}

impl Truth {
    /// At rest at the origin, tick 0.
    pub const fn new() -> Self {
        Self {
            at: 0,
            pose: TruePose {
                x: 0.0,
                y: 0.0,
                heading: 0.0,
            },
        }
    }

    /// The pose at tick `t` (not before the last one asked for).
    pub fn pose_at(&mut self, t: i64) -> TruePose {
        let lap_ticks = LAP_MS * (HZ / 1_000);
        while self.at < t {
            // The segment holding `self.at` and its end.
            let mut seg_end = self.at.div_euclid(lap_ticks) * lap_ticks;
            let mut speeds = (0, 0);
            for (ms, l, r) in PATH {
                seg_end += ms * (HZ / 1_000);
                if seg_end > self.at {
                    speeds = (l, r);
                    break;
                }
            }
            let to = t.min(seg_end);
            self.advance(speeds, (to - self.at) as f64 / HZ as f64);
            self.at = to;
        }
        self.pose
    }

    /// Moves along an arc: wheel speeds (increments/s) for `dt` seconds.
    fn advance(&mut self, (l, r): (i64, i64), dt: f64) {
        use core::f64::consts::PI;
        let per_count = PI / TICKS_PER_REV as f64;
        let sl = l as f64 * dt * per_count * TRUE_LEFT_DIAMETER;
        let sr = r as f64 * dt * per_count * TRUE_RIGHT_DIAMETER;
        let ds = 0.5 * (sl + sr);
        let half = 0.5 * (sl - sr) / TRUE_TRACK_WIDTH;
        // The chord of the arc: ds * sin(half) / half, along the mean heading.
        let (s_half, _) = sin_cos(half);
        let sinc = if half.abs() < 0.25 {
            let u = half * half;
            1.0 - u / 6.0 * (1.0 - u / 20.0 * (1.0 - u / 42.0 * (1.0 - u / 72.0)))
        } else {
            s_half / half
        };
        let (s, c) = sin_cos(self.pose.heading + half);
        let p = &mut self.pose;
        p.x += ds * sinc * s;
        p.y += ds * sinc * c;
        p.heading += 2.0 * half;
        let turns = (p.heading / (2.0 * PI)) as i64;
        p.heading -= turns as f64 * 2.0 * PI;
    }
}

/// Sine and cosine of `angle` (radians) by the core's fixed-point routine (error below
/// 1e-9).
pub fn sin_cos(angle: f64) -> (f64, f64) {
    use core::f64::consts::PI;
    let turns = angle / (2.0 * PI);
    let frac = turns - (turns as i64) as f64;
    // One turn is 2^64: frac * 2^63, doubled with wrap-around.
    let binary = ((frac * (1u64 << 63) as f64) as i64 as u64).wrapping_mul(2);
    let (s, c) = odo_unit::odometry::trig::sin_cos(binary);
    let q30 = (1u32 << 30) as f64;
    (f64::from(s) / q30, f64::from(c) / q30)
}
