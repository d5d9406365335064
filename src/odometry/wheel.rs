//! Wheel distance: eq (6) with the transfer constant `c_i = pi * diameter_i / ticks_per_rev`,
//! and the calibrated per-angle wheel function of eqs (3)-(5), referenced to the index line.
//!
//! The sum `F_w` of eq (4) of a wheel whose distance per increment is
//! `c * (1 + sum_h a_h cos(h theta) + b_h sin(h theta))` (see [`WheelHarmonics`]) is, over
//! whole increments, `c * Gamma + R(theta)` with the bounded periodic part
//! `R(theta) = (diameter / 2) * sum_h (a_h / h) sin(h theta) - (b_h / h) cos(h theta)`,
//! `theta = 2 pi ((Gamma - Gamma_index) mod P) / P`. Eq (5) then gives a sample's distance
//! as `c * dGamma + R(theta_now) - R(theta_before)`: the exact, drift-free linear part plus a
//! difference of two evaluations of a bounded function, never a running sum of corrections.
//! Before the wheel's first index pulse its phase is unknown and eq (6) is used alone.

use super::params::{WheelHarmonics, WHEEL_HARMONICS};
use super::trig;

/// Fixed-point scale of distances: 2^48 units per metre (3.6e-15 m).
pub const DISTANCE_SCALE: f64 = 281_474_976_710_656.0;

/// One wheel's distance model, precomputed from its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelModel {
    /// Transfer constant `c` in units of 2^-48 m per increment (eq 6).
    c_fixed: i64,
    /// Transfer constant `c`, metres per increment.
    c: f64,
    /// Increments per wheel turn `P`.
    ticks_per_rev: u32,
    /// Binary-angle units (2^-64 turn) per increment of phase.
    phase_step: u64,
    /// `diameter/2 * a_h / h` (metres), sine terms of R.
    r_sin: [f32; WHEEL_HARMONICS],
    /// `-diameter/2 * b_h / h` (metres), cosine terms of R.
    r_cos: [f32; WHEEL_HARMONICS],
    /// True when all harmonics are zero: R is identically zero.
    round: bool,
}

impl WheelModel {
    /// The model of a wheel of `diameter` metres, `ticks_per_rev` increments per turn and
    /// per-angle function `harmonics`. The parameters must have been validated.
    pub fn new(diameter: f64, ticks_per_rev: u32, harmonics: &WheelHarmonics) -> Self {
        let c = core::f64::consts::PI * diameter / f64::from(ticks_per_rev);
        let mut r_sin = [0.0; WHEEL_HARMONICS];
        let mut r_cos = [0.0; WHEEL_HARMONICS];
        for h in 0..WHEEL_HARMONICS {
            let scale = diameter / 2.0 / (h + 1) as f64;
            r_sin[h] = (scale * f64::from(harmonics.cos[h])) as f32;
            r_cos[h] = (-scale * f64::from(harmonics.sin[h])) as f32;
        }
        Self {
            c_fixed: round_f64_to_i64(c * DISTANCE_SCALE),
            c,
            ticks_per_rev,
            phase_step: round_f64_to_u64(18_446_744_073_709_551_616.0 / f64::from(ticks_per_rev)),
            r_sin,
            r_cos,
            round: harmonics.is_round(),
        }
    }

    /// Transfer constant `c`, metres per increment.
    pub fn transfer_constant(&self) -> f64 {
        self.c
    }

    /// Transfer constant in units of 2^-48 m per increment.
    pub fn transfer_constant_fixed(&self) -> i64 {
        self.c_fixed
    }

    /// True when the wheel is modelled as round (eq 6 alone, whatever the index says).
    pub fn is_round(&self) -> bool {
        self.round
    }

    /// The phase of absolute count `gamma` within the turn, `(gamma - index) mod P`, in
    /// increments (0..P).
    pub fn phase(&self, gamma: i64, index: i64) -> u32 {
        let d = gamma.wrapping_sub(index);
        let p = self.ticks_per_rev;
        // The index latch is refreshed every turn, so the difference nearly always fits an i32
        // and the hardware divider does the work; the i64 path is the rare fallback.
        match i32::try_from(d) {
            Ok(d) => d.rem_euclid(p as i32) as u32,
            Err(_) => d.rem_euclid(i64::from(p)) as u32,
        }
    }

    /// The periodic part `R(theta)` of the summed wheel function at phase `phase`
    /// increments past the index, metres.
    pub fn periodic(&self, phase: u32) -> f32 {
        if self.round {
            return 0.0;
        }
        let angle = self.phase_step.wrapping_mul(u64::from(phase));
        let (s1, c1) = trig::sin_cos(angle);
        let (s1, c1) = (trig::q30_to_f32(s1), trig::q30_to_f32(c1));
        // Harmonics h = 2, 3 by the angle-addition recurrence.
        let mut r = self.r_sin[0] * s1 + self.r_cos[0] * c1;
        let (mut sh, mut ch) = (s1, c1);
        for h in 1..WHEEL_HARMONICS {
            let s_next = sh * c1 + ch * s1;
            let c_next = ch * c1 - sh * s1;
            sh = s_next;
            ch = c_next;
            r += self.r_sin[h] * sh + self.r_cos[h] * ch;
        }
        r
    }
}

/// Rounds to the nearest integer without `libm` (for values well inside the i64 range).
fn round_f64_to_i64(v: f64) -> i64 {
    if v >= 0.0 {
        (v + 0.5) as i64
    } else {
        (v - 0.5) as i64
    }
}

/// Rounds a non-negative value to the nearest u64 (saturating).
fn round_f64_to_u64(v: f64) -> u64 {
    (v + 0.5) as u64
}
