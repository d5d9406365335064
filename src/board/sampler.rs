//! The sample timer TIM5 (32-bit): one update event per sample, its period programmed
//! sample by sample from the [`Discipline`]'s grid, and the GNSS 1-PPS captured on its CH1.
//!
//! TIM5 counts timer ticks (84 MHz on the board, 1 GHz in QEMU) from 0 to ARR and restarts:
//! the update event *is* the sample instant. ARR is preloaded (ARPE), so the value written in
//! the interrupt of sample `n` sets the period from sample `n + 1` to `n + 2`: the
//! discipline is asked for sample `n + 2` then. The software keeps the 64-bit tick of the last
//! update event; a PPS capture is that plus CCR1 (or, when the update flag was already
//! pending, see [`resolve_capture`]).
//!
//! QEMU models TIM5's update interrupt but not input capture, and applies ARR writes at once;
//! ARR is only written when it changes, which in free mode at a rate that divides the tick
//! frequency is never after start (in PPS mode QEMU's interrupts then drift from the
//! software's tick timeline by the ARR changes; everything, the simulated drive and GNSS
//! receiver included, runs on that timeline). In the `qemu` build the PPS captures come from
//! the simulated receiver ([`super::sim_gnss`]): at each update event, an edge that fell in
//! the period just ended is handled as the CC1 interrupt the board takes at the edge (CC1IF
//! alone, the simulated CCR1), before the update; the sampler also lets the receiver send
//! the NMEA bytes due by the sample instant.

use odo_core::timing::{
    resolve_capture, ConfigError, Discipline, DisciplineConfig, PpsEvent, Sample,
};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Enable;

const SR_UIF: u32 = 1 << 0;
const SR_CC1IF: u32 = 1 << 1;
const SR_CC1OF: u32 = 1 << 9;

/// What one TIM5 interrupt found.
#[derive(Debug, Clone, Copy, Default)]
pub struct Event {
    /// A sample instant passed: the sample.
    pub sample: Option<Sample>,
    /// A PPS edge was captured: its tick and what the discipline made of it.
    pub pps: Option<(u64, PpsEvent)>,
    /// A PPS edge was lost to an over-capture (two edges before the interrupt ran).
    pub overcapture: bool,
}

/// TIM5 and the discipline.
pub struct Sampler {
    tim: pac::TIM5,
    disc: Discipline,
    /// Tick of the last update event processed.
    period_start: u64,
    /// Length of the running period (ARR + 1).
    cur_len: u64,
    /// The two samples committed to the hardware: the next update event, and the one after.
    committed: [Sample; 2],
    arr: u32,
    /// The simulated GNSS receiver: PPS captures and NMEA bytes (QEMU has neither).
    #[cfg(feature = "qemu")]
    gnss: super::sim_gnss::SimGnss,
}

fn arr_of(len: u64) -> u32 {
    len.saturating_sub(1).min(u64::from(u32::MAX)) as u32
}

impl Sampler {
    /// Configures TIM5 and starts it; returns the sampler and sample 0 (tick 0: now).
    pub fn start(
        tim: pac::TIM5,
        rcc: &mut pac::RCC,
        mut disc: Discipline,
        #[cfg(feature = "qemu")] gnss: super::sim_gnss::SimGnss,
    ) -> (Self, Sample) {
        pac::TIM5::enable(rcc);
        let s0 = disc.next_sample(0);
        let s1 = disc.next_sample(0);
        let s2 = disc.next_sample(0);
        let first = arr_of(s1.tick - s0.tick);
        let second = arr_of(s2.tick - s1.tick);
        // Note(unsafe): raw register values from RM0368 sec. 13.4: PSC = 0; CR1 = ARPE | URS
        // (only overflows raise the update flag); CCMR1 CC1S = 01 (IC1 on TI1, no filter);
        // CCER CC1E (rising edge); DIER = UIE | CC1IE; EGR UG loads PSC and ARR.
        unsafe {
            tim.psc().write(|w| w.bits(0));
            tim.cr1().write(|w| w.bits(1 << 7 | 1 << 2));
            tim.ccmr1_input().write(|w| w.bits(0b01));
            tim.ccer().write(|w| w.bits(1));
        }
        tim.arr().write(|w| w.set(first));
        // Note(unsafe): EGR UG (bit 0), then clear all flags (SR is rc_w0).
        unsafe {
            tim.egr().write(|w| w.bits(1));
            tim.sr().write(|w| w.bits(0));
        }
        tim.arr().write(|w| w.set(second));
        // Note(unsafe): DIER = UIE | CC1IE, then CR1 |= CEN.
        unsafe {
            tim.dier().write(|w| w.bits(1 | 1 << 1));
            tim.cr1().modify(|r, w| w.bits(r.bits() | 1));
        }
        let sampler = Self {
            tim,
            disc,
            period_start: s0.tick,
            cur_len: s1.tick - s0.tick,
            committed: [s1, s2],
            arr: second,
            #[cfg(feature = "qemu")]
            gnss,
        };
        (sampler, s0)
    }

    /// Handles the TIM5 interrupt: the PPS capture first (it may belong to the period that
    /// just ended), then the update event.
    pub fn on_interrupt(&mut self) -> Event {
        let sr = self.tim.sr().read().bits();
        let mut event = Event::default();
        #[cfg(feature = "qemu")]
        if sr & SR_UIF != 0 {
            if let Some(ccr) = self.gnss.capture(self.period_start, self.cur_len) {
                // The CC1 interrupt the board takes at the edge, before this update event.
                self.on_capture(SR_CC1IF, ccr, &mut event);
            }
        }
        if sr & SR_CC1IF != 0 {
            let ccr = self.tim.ccr1().read().bits(); // reading CCR1 clears CC1IF
            self.on_capture(sr, ccr, &mut event);
        }
        let clear = SR_UIF | if event.overcapture { SR_CC1OF } else { 0 };
        if sr & clear != 0 {
            // Note(unsafe): SR is rc_w0: writing 0 clears a flag, 1 leaves it.
            unsafe { self.tim.sr().write(|w| w.bits(!clear & 0xFFFF)) };
        }
        if sr & SR_UIF != 0 {
            self.period_start += self.cur_len;
            let sample = self.committed[0];
            let next = self.committed[1];
            self.cur_len = next.tick - sample.tick;
            let after = self.disc.next_sample(self.period_start);
            self.committed = [next, after];
            let arr = arr_of(after.tick - next.tick);
            if arr != self.arr {
                self.tim.arr().write(|w| w.set(arr));
                self.arr = arr;
            }
            event.sample = Some(sample);
            #[cfg(feature = "qemu")]
            self.gnss.transmit(self.period_start);
        }
        event
    }

    /// A PPS capture: `ccr` latched with the status flags `sr`.
    fn on_capture(&mut self, sr: u32, ccr: u32, event: &mut Event) {
        let tick = resolve_capture(self.period_start, self.cur_len, ccr, sr & SR_UIF != 0);
        event.pps = Some((tick, self.disc.on_pps(tick)));
        event.overcapture = sr & SR_CC1OF != 0;
    }

    /// Changes the discipline's configuration (mode at once, rate from the next second).
    pub fn set_config(&mut self, cfg: DisciplineConfig) -> Result<(), ConfigError> {
        self.disc.set_config(cfg)
    }

    /// The discipline (state, statistics).
    pub fn discipline(&self) -> &Discipline {
        &self.disc
    }
}
