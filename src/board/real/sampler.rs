//! TIM5 on the board: CH2 output compare at each sample's tick on the free-running 32-bit
//! counter, CH1 input capture of the PPS (`src/board/sampler.rs`).

use crate::board::sampler::{Event, Sampler};
use odo_core::timing::{Sample, TimerExtender};
use stm32f4xx_hal::pac;

const SR_CC1IF: u32 = 1 << 1;
const SR_CC2IF: u32 = 1 << 2;
const SR_CC1OF: u32 = 1 << 9;

/// The counter's 64-bit timeline.
pub struct Timeline {
    ext: TimerExtender,
}

impl Timeline {
    /// DIER bit of the sample interrupt: CC2IE (the compare).
    pub const DIER_SAMPLE: u32 = 1 << 2;

    /// ARR = 2^32 - 1 (free-running) and the compare on sample `s1`.
    pub fn program(tim: &pac::TIM5, _s0: Sample, s1: Sample, _extra: ()) -> Self {
        tim.arr().write(|w| w.set(u32::MAX));
        tim.ccr2().write(|w| w.set(s1.tick as u32));
        Self {
            ext: TimerExtender::new(0),
        }
    }
}

impl Sampler {
    /// Handles the TIM5 interrupt: the PPS capture first (it happened before the counter
    /// reading), then the sample compare.
    pub fn on_interrupt(&mut self) -> Event {
        let cnt = self.tim.cnt().read().bits();
        let sr = self.tim.sr().read().bits();
        let now = self.timeline.ext.extend(cnt);
        let mut event = Event::default();
        if sr & SR_CC1IF != 0 {
            let ccr = self.tim.ccr1().read().bits(); // reading CCR1 clears CC1IF
            let edge = self.timeline.ext.capture(ccr);
            event.pps = Some((edge, self.disc.on_pps(edge)));
            event.overcapture = sr & SR_CC1OF != 0;
        }
        let clear = (sr & SR_CC2IF) | (sr & SR_CC1OF);
        if clear != 0 {
            // Note(unsafe): SR is rc_w0: writing 0 clears a flag, 1 leaves it.
            unsafe { self.tim.sr().write(|w| w.bits(!clear & 0xFFFF)) };
        }
        if sr & SR_CC2IF != 0 && now >= self.next.tick {
            self.sample_due(now, &mut event);
            self.arm();
        }
        event
    }

    /// Programs the compare for `self.next`; if the counter passed it meanwhile, forces the
    /// compare event so that the interrupt comes back at once.
    fn arm(&mut self) {
        self.tim.ccr2().write(|w| w.set(self.next.tick as u32));
        let now = self.timeline.ext.extend(self.tim.cnt().read().bits());
        if now >= self.next.tick {
            // Note(unsafe): EGR CC2G (bit 2) sets CC2IF as a compare match would.
            unsafe { self.tim.egr().write(|w| w.bits(1 << 2)) };
        }
    }
}
