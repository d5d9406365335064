//! The sample timer's interrupt on the board: a free-running 32-bit counter whose output
//! compare (CH2) fires at each sample's tick and whose input capture (CH1) latches the PPS.
//! What the handler reads, in which order, and what it decides, over any timer that offers
//! [`CompareTimer`] (TIM5 on the board, a simulated timer in `host-tests/compare.rs`).
//!
//! # The order of the reads
//! The status flags are read **before** the counter. A compare that fires between the two
//! reads then leaves its flag for the next interrupt (which comes at once, the flag being
//! set), instead of being seen as set while the counter reading is still before the compare
//! value: a handler that clears the flag then and takes the sample only when the counter has
//! reached it loses the compare for 2^32 ticks (51 s at 84 MHz), and the watchdog resets the
//! board. The decision does not rest on the flag alone either: a sample is taken whenever the
//! counter has reached the programmed tick (a forced or late compare), and a set flag whose
//! tick is still ahead re-arms the compare ([`CompareAction`]).
//!
//! # The PPS capture
//! The capture (CC1E) and its interrupt are on in `pps` mode only. In `free` mode the capture
//! is off: edges captured and never read would set the over-capture flag, which would be
//! reported as a lost edge at the switch to `pps`. Switching the capture on clears both
//! capture flags first ([`set_capture`]).

use super::clock::{catch_up, TimerExtender};
use super::pps::{Discipline, PpsEvent, Sample};

/// SR flag of the PPS capture (CC1IF).
pub const SR_CAPTURE: u32 = 1 << 1;
/// SR flag of the sample compare (CC2IF).
pub const SR_COMPARE: u32 = 1 << 2;
/// SR flag of a PPS over-capture (CC1OF).
pub const SR_OVERCAPTURE: u32 = 1 << 9;

/// The sample timer's registers as the interrupt uses them.
pub trait CompareTimer {
    /// The status flags (SR; [`SR_CAPTURE`], [`SR_COMPARE`], [`SR_OVERCAPTURE`]).
    fn flags(&mut self) -> u32;
    /// Clears `flags` (SR bits, rc_w0), leaving the others.
    fn clear(&mut self, flags: u32);
    /// The counter (CNT).
    fn counter(&mut self) -> u32;
    /// The capture register (CCR1; reading it clears the capture flag).
    fn capture(&mut self) -> u32;
    /// Programs the compare register (CCR2).
    fn set_compare(&mut self, value: u32);
    /// Sets the compare flag as a match would (EGR CC2G).
    fn force_compare(&mut self);
    /// Turns the capture and its interrupt on or off (CCER CC1E, DIER CC1IE).
    fn enable_capture(&mut self, on: bool);
}

/// What the interrupt does about the compare, from the flags read first and the counter
/// read after them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompareAction {
    /// Nothing due: the counter is before the programmed tick and the compare flag is clear.
    None,
    /// The counter reached the programmed tick: take the sample and program the next one.
    Sample,
    /// The compare flag is set but the counter is before the programmed tick (a stale flag):
    /// program the compare again.
    Rearm,
}

/// The compare decision: `compare_flag` read before `now` (the extended counter), `next` the
/// programmed sample's tick.
pub fn compare_action(compare_flag: bool, now: u64, next: u64) -> CompareAction {
    if now >= next {
        CompareAction::Sample
    } else if compare_flag {
        CompareAction::Rearm
    } else {
        CompareAction::None
    }
}

/// What one interrupt found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TimerEvent {
    /// A sample instant passed: the sample (the latest grid point reached).
    pub sample: Option<Sample>,
    /// Grid points merged into `sample` because the interrupt ran late (a stall).
    pub merged: u32,
    /// Ticks from the sample's grid point to the interrupt's counter reading.
    pub latency: u32,
    /// A PPS edge was captured: its tick and what the discipline made of it.
    pub pps: Option<(u64, PpsEvent)>,
    /// A PPS edge was lost to an over-capture (two edges before the interrupt ran).
    pub overcapture: bool,
}

/// The compare schedule: the counter's 64-bit timeline, the programmed sample, the lead a
/// compare value needs.
#[derive(Debug, Clone, Copy)]
pub struct CompareSchedule {
    /// The counter's timeline.
    pub ext: TimerExtender,
    /// The sample whose compare is programmed.
    pub next: Sample,
    /// Ticks of lead the compare needs: points closer than this to `now` are merged.
    pub guard: u64,
}

impl CompareSchedule {
    /// Handles one interrupt of `tim`: flags, then counter, then the PPS capture (it happened
    /// before the counter reading), then the compare ([`compare_action`]).
    pub fn on_interrupt<T: CompareTimer>(
        &mut self,
        tim: &mut T,
        disc: &mut Discipline,
    ) -> TimerEvent {
        let sr = tim.flags();
        let now = self.ext.extend(tim.counter());
        let mut event = TimerEvent::default();
        if sr & SR_CAPTURE != 0 {
            let edge = self.ext.capture(tim.capture());
            event.pps = Some((edge, disc.on_pps(edge)));
            event.overcapture = sr & SR_OVERCAPTURE != 0;
        }
        let clear = sr & (SR_COMPARE | SR_OVERCAPTURE);
        if clear != 0 {
            tim.clear(clear);
        }
        match compare_action(sr & SR_COMPARE != 0, now, self.next.tick) {
            CompareAction::None => {}
            CompareAction::Rearm => self.arm(tim),
            CompareAction::Sample => {
                let c = catch_up(disc, self.next, now, self.guard);
                self.next = c.next;
                event.sample = Some(c.sample);
                event.merged = c.merged;
                event.latency = u32::try_from(now - c.sample.tick).unwrap_or(u32::MAX);
                self.arm(tim);
            }
        }
        event
    }

    /// Programs the compare for `self.next`; if the counter passed it meanwhile, forces the
    /// compare event so that the interrupt comes back at once.
    pub fn arm<T: CompareTimer>(&mut self, tim: &mut T) {
        tim.set_compare(self.next.tick as u32);
        let now = self.ext.extend(tim.counter());
        if now >= self.next.tick {
            tim.force_compare();
        }
    }
}

/// Turns the PPS capture on (clearing the capture and over-capture flags first, so that
/// edges of before do not count) or off.
pub fn set_capture<T: CompareTimer>(tim: &mut T, on: bool) {
    if on {
        let _ = tim.capture();
        tim.clear(SR_CAPTURE | SR_OVERCAPTURE);
    }
    tim.enable_capture(on);
}
