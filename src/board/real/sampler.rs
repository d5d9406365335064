//! TIM5 on the board: CH2 output compare at each sample's tick on the free-running 32-bit
//! counter, CH1 input capture of the PPS (`src/board/sampler.rs`). The interrupt's logic is
//! [`odo_unit::timing::compare`]; this file gives it TIM5's registers.

use crate::board::sampler::{Event, Sampler};
use odo_unit::timing::{compare, CompareSchedule, CompareTimer, Sample, TimerExtender};
use stm32f4xx_hal::pac;

/// The counter's 64-bit timeline and the programmed compare.
pub struct Timeline {
    sched: CompareSchedule,
}

impl Timeline {
    /// DIER bit of the sample interrupt: CC2IE (the compare).
    pub const DIER_SAMPLE: u32 = 1 << 2;
    /// DIER bit of the PPS capture interrupt: CC1IE.
    pub const DIER_CAPTURE: u32 = 1 << 1;

    /// ARR = 2^32 - 1 (free-running) and the compare on sample `s1`.
    pub fn program(tim: &pac::TIM5, _s0: Sample, s1: Sample, guard: u64, _extra: ()) -> Self {
        tim.arr().write(|w| w.set(u32::MAX));
        tim.ccr2().write(|w| w.set(s1.tick as u32));
        Self {
            sched: CompareSchedule {
                ext: TimerExtender::new(0),
                next: s1,
                guard,
            },
        }
    }
}

/// TIM5's registers as [`CompareTimer`].
struct Tim5<'a>(&'a pac::TIM5);

impl CompareTimer for Tim5<'_> {
    fn flags(&mut self) -> u32 {
        self.0.sr().read().bits()
    }
    fn clear(&mut self, flags: u32) {
        // Note(unsafe): SR is rc_w0: writing 0 clears a flag, 1 leaves it.
        unsafe { self.0.sr().write(|w| w.bits(!flags & 0xFFFF)) };
    }
    fn counter(&mut self) -> u32 {
        self.0.cnt().read().bits()
    }
    fn capture(&mut self) -> u32 {
        self.0.ccr1().read().bits()
    }
    fn set_compare(&mut self, value: u32) {
        self.0.ccr2().write(|w| w.set(value));
    }
    fn force_compare(&mut self) {
        // Note(unsafe): EGR CC2G (bit 2) sets CC2IF as a compare match would.
        unsafe { self.0.egr().write(|w| w.bits(1 << 2)) };
    }
    fn enable_capture(&mut self, on: bool) {
        let bit = |r: u32, mask: u32| if on { r | mask } else { r & !mask };
        // Note(unsafe): CCER CC1E (bit 0) and DIER CC1IE (bit 1); the other bits are kept.
        unsafe {
            self.0.ccer().modify(|r, w| w.bits(bit(r.bits(), 1)));
            self.0
                .dier()
                .modify(|r, w| w.bits(bit(r.bits(), Timeline::DIER_CAPTURE)));
        }
    }
}

impl Sampler {
    /// Handles the TIM5 interrupt ([`CompareSchedule::on_interrupt`]).
    pub fn on_interrupt(&mut self) -> Event {
        self.timeline
            .sched
            .on_interrupt(&mut Tim5(&self.tim), &mut self.disc)
    }

    /// Turns the PPS capture on (its stale flags cleared) or off.
    pub(crate) fn set_capture(&mut self, on: bool) {
        compare::set_capture(&mut Tim5(&self.tim), on);
    }
}
