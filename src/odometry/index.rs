//! Index (N) pulse tracking: the count latched at each wheel's index pulse, and the check
//! that the count between two index pulses is a whole number of turns.
//!
//! The index line of an encoder pulses once per turn at the same angle, whichever way the
//! wheel turns, so the absolute counts latched at two index pulses differ by a multiple of
//! `ticks_per_rev`. When they do not (beyond `tolerance` increments, which absorbs the
//! pulse's width and the latching latency), counts were lost or gained: an encoder fault,
//! flagged until reported ([`IndexTracker::take_mismatch`]). The newest latch always
//! becomes the reference of the per-angle wheel function.

/// Default tolerance of the whole-turn check, increments: the index pulse is one quadrature
/// cycle wide (4 increments after x4 decoding) and is latched on its rising edge, which
/// moves by up to 3 increments when the wheel reverses; one more for the latching latency.
pub const DEFAULT_TOLERANCE: u32 = 4;

/// Result of one index pulse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IndexCheck {
    /// The first pulse seen: it becomes the reference.
    First,
    /// A whole number of turns (signed) since the previous pulse, within the tolerance.
    Whole {
        /// Turns since the previous pulse (negative when turning backwards).
        turns: i64,
    },
    /// Not a whole number of turns: counts were lost or gained.
    Mismatch {
        /// Counts since the previous pulse minus the nearest whole number of turns.
        error: i64,
    },
}

/// Index state of one wheel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IndexTracker {
    ticks_per_rev: u32,
    tolerance: u32,
    last: Option<i64>,
    mismatch: bool,
    mismatches: u32,
}

impl IndexTracker {
    /// A tracker for an encoder of `ticks_per_rev` increments per turn (at least 1), with
    /// the given tolerance in increments.
    pub fn new(ticks_per_rev: u32, tolerance: u32) -> Self {
        Self {
            ticks_per_rev: ticks_per_rev.max(1),
            tolerance,
            last: None,
            mismatch: false,
            mismatches: 0,
        }
    }

    /// Changes `ticks_per_rev`; the reference is kept (index positions do not move).
    pub fn set_ticks_per_rev(&mut self, ticks_per_rev: u32) {
        self.ticks_per_rev = ticks_per_rev.max(1);
    }

    /// Feeds the absolute count latched at an index pulse.
    pub fn on_index(&mut self, count: i64) -> IndexCheck {
        let previous = self.last.replace(count);
        let Some(previous) = previous else {
            return IndexCheck::First;
        };
        let tpr = i64::from(self.ticks_per_rev);
        // Turns to the nearest whole number and the remainder from it, in -tpr/2..=tpr/2;
        // checked: latched counts 2^63 apart (no board reaches them) take the exact path.
        let (turns, error) = count
            .checked_sub(previous)
            .and_then(|diff| {
                let rem = diff.rem_euclid(tpr);
                let error = if rem > tpr / 2 { rem - tpr } else { rem };
                Some(((diff.checked_sub(error)?) / tpr, error))
            })
            .unwrap_or_else(|| nearest_turns_wide(previous, count, tpr));
        if error.unsigned_abs() <= u64::from(self.tolerance) {
            IndexCheck::Whole { turns }
        } else {
            self.mismatch = true;
            self.mismatches = self.mismatches.saturating_add(1);
            IndexCheck::Mismatch { error }
        }
    }

    /// Count latched at the last index pulse (the per-angle reference).
    pub fn reference(&self) -> Option<i64> {
        self.last
    }

    /// True once an index pulse was seen.
    pub fn seen(&self) -> bool {
        self.last.is_some()
    }

    /// True when a mismatch happened since the last call; clears it.
    pub fn take_mismatch(&mut self) -> bool {
        core::mem::take(&mut self.mismatch)
    }

    /// Mismatches since start.
    pub fn mismatches(&self) -> u32 {
        self.mismatches
    }
}

/// [`IndexTracker::on_index`]'s (turns, error) from `previous` to `count` when their
/// difference overflows i64, exactly, turns saturated to i64 (more than 2^63 turns only at one
/// increment per turn). In i64 (an i128 division cost 1.8 KiB of flash): with
/// `count = qc tpr + rc` and `previous = qp tpr + rp`, the difference is
/// `(qc - qp) tpr + (rc - rp)`, and `rc - rp` is rounded to whole turns alone.
#[cold]
fn nearest_turns_wide(previous: i64, count: i64, tpr: i64) -> (i64, i64) {
    let (qc, qp) = (count.div_euclid(tpr), previous.div_euclid(tpr));
    // In -(tpr - 1)..=tpr - 1.
    let d = count.rem_euclid(tpr) - previous.rem_euclid(tpr);
    let rem = d.rem_euclid(tpr);
    let error = if rem > tpr / 2 { rem - tpr } else { rem };
    // d - error is -tpr, 0 or tpr.
    let adjust = (d - error) / tpr;
    let saturated = if qc > qp { i64::MAX } else { i64::MIN };
    let turns = qc
        .checked_sub(qp)
        .and_then(|t| t.checked_add(adjust))
        .unwrap_or(saturated);
    (turns, error)
}

/// The absolute count of a raw counter value read close in time to a reference reading:
/// `reference_abs` is the absolute count that raw value `reference_raw` stood for, and the
/// counter (`bits` wide, 1..=32) moved by less than half its range in between. Used for a
/// count latched by an index interrupt between two samples.
pub fn extend_near(bits: u32, reference_raw: u32, reference_abs: i64, raw: u32) -> i64 {
    let bits = bits.clamp(1, 32);
    let shift = 64 - bits;
    let delta = (u64::from(raw.wrapping_sub(reference_raw)) << shift) as i64 >> shift;
    reference_abs.wrapping_add(delta)
}
