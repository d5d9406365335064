//! The sample timer TIM5 (32-bit, free-running): its CH2 output compare fires at each
//! sample's tick from the [`Discipline`]'s grid, and its CH1 captures the GNSS 1-PPS on the
//! same counter.
//!
//! TIM5 counts timer ticks (84 MHz on the board) from 0 to 2^32 - 1 and wraps (every 51 s);
//! [`TimerExtender`] makes the 64-bit tick timeline of the discipline from it, which needs a
//! reading at least every 2^31 ticks (25 s): every sample interrupt reads it, and the
//! slowest rate is 1 Hz. Each compare interrupt reads the counter as its first action
//! (after the encoders, see `src/board/encoders.rs`), and [`catch_up`] labels that instant
//! with the latest grid point it has reached. Normally that is the point just due; after a
//! stall (a flash sector erase stops the CPU for up to [`super::flash::MAX_ERASE_MS`]) it is
//! the last of the points the stall passed over, which are merged into it: their motion is
//! in the counts (the encoder timers keep counting), the time labels stay those of the grid,
//! the GNSS seconds stay right, and the next compare goes on the first future grid point.
//! A compare value that the counter passed while it was being written is caught by reading
//! the counter back and forcing the compare event (EGR CC2G).
//!
//! The PPS capture (CH1, rising edge, input filter [`PPS_FILTER`]) latches the counter at
//! the edge; a second edge before the interrupt reads it sets the over-capture flag (one
//! edge lost, reported). Its interrupt is enabled only in `pps` mode.
//!
//! QEMU models neither output compare nor input capture: in the `qemu` build the compare is
//! emulated by the update event (the counter restarts at each sample and ARR, which QEMU
//! applies at once, is set to the next sample's distance), the PPS captures come from the
//! simulated receiver ([`super::sim_gnss`]), and the same [`catch_up`] runs on that
//! timeline (QEMU never stalls: its flash is RAM).

#[cfg(not(feature = "qemu"))]
use odo_core::timing::TimerExtender;
use odo_core::timing::{
    catch_up, ConfigError, Discipline, DisciplineConfig, PpsEvent, Sample, SyncMode,
};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Enable;

#[cfg(feature = "qemu")]
const SR_UIF: u32 = 1 << 0;
#[cfg(not(feature = "qemu"))]
const SR_CC1IF: u32 = 1 << 1;
#[cfg(not(feature = "qemu"))]
const SR_CC2IF: u32 = 1 << 2;
#[cfg(not(feature = "qemu"))]
const SR_CC1OF: u32 = 1 << 9;
const DIER_UIE: u32 = 1 << 0;
const DIER_CC1IE: u32 = 1 << 1;
#[cfg_attr(feature = "qemu", allow(dead_code))]
const DIER_CC2IE: u32 = 1 << 2;

/// Input filter of the PPS input (IC1F = 0b0011: 8 consecutive samples at 84 MHz). It
/// rejects pulses shorter than about 95 ns and delays the capture by as much, a constant
/// 8-10 ticks that is the same at every edge (so it does not change the measured period) and
/// shifts the sample grid by under 0.12 us against GNSS time.
pub const PPS_FILTER: u32 = 0b0011;

/// What one TIM5 interrupt found.
#[derive(Debug, Clone, Copy, Default)]
pub struct Event {
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

/// TIM5 and the discipline.
pub struct Sampler {
    tim: pac::TIM5,
    disc: Discipline,
    /// The sample whose compare is programmed.
    next: Sample,
    /// Ticks of lead the compare needs: points closer than this to `now` are merged.
    guard: u64,
    #[cfg(not(feature = "qemu"))]
    ext: TimerExtender,
    /// QEMU: the tick at which the counter last restarted (the last sample instant).
    #[cfg(feature = "qemu")]
    base: u64,
    /// QEMU: the ARR value last written.
    #[cfg(feature = "qemu")]
    arr: u32,
    /// The simulated GNSS receiver: PPS captures and NMEA bytes (QEMU has neither).
    #[cfg(feature = "qemu")]
    gnss: super::sim_gnss::SimGnss,
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
        let guard = u64::from(disc.config().timer_hz / 100_000).max(1);
        let pps = disc.config().mode == SyncMode::Pps;
        // Note(unsafe): raw register values from RM0368 sec. 13.4: PSC = 0; CR1 = URS (only
        // overflows raise the update flag); CCMR1 CC1S = 01 (IC1 on TI1) with IC1F, CC2S = 00
        // with OC2M = 000 (frozen: the compare only sets CC2IF); CCER CC1E (rising edge).
        unsafe {
            tim.psc().write(|w| w.bits(0));
            tim.cr1().write(|w| w.bits(1 << 2));
            tim.ccmr1_input().write(|w| w.bits(0b01 | PPS_FILTER << 4));
            tim.ccer().write(|w| w.bits(1));
        }
        #[cfg(not(feature = "qemu"))]
        {
            tim.arr().write(|w| w.set(u32::MAX));
            tim.ccr2().write(|w| w.set(s1.tick as u32));
        }
        #[cfg(feature = "qemu")]
        tim.arr().write(|w| w.set((s1.tick - 1) as u32));
        // Note(unsafe): EGR UG (bit 0) zeroes the counter and loads PSC and ARR; then clear
        // all flags (SR is rc_w0), enable the interrupts and CR1 |= CEN.
        unsafe {
            tim.egr().write(|w| w.bits(1));
            tim.sr().write(|w| w.bits(0));
            let compare = if cfg!(feature = "qemu") {
                DIER_UIE
            } else {
                DIER_CC2IE
            };
            tim.dier()
                .write(|w| w.bits(compare | if pps { DIER_CC1IE } else { 0 }));
            tim.cr1().modify(|r, w| w.bits(r.bits() | 1));
        }
        let sampler = Self {
            tim,
            disc,
            next: s1,
            guard,
            #[cfg(not(feature = "qemu"))]
            ext: TimerExtender::new(0),
            #[cfg(feature = "qemu")]
            base: s0.tick,
            #[cfg(feature = "qemu")]
            arr: (s1.tick - s0.tick - 1) as u32,
            #[cfg(feature = "qemu")]
            gnss,
        };
        (sampler, s0)
    }

    /// Handles the TIM5 interrupt: the PPS capture first (it happened before the counter
    /// reading), then the sample compare.
    #[cfg(not(feature = "qemu"))]
    pub fn on_interrupt(&mut self) -> Event {
        let cnt = self.tim.cnt().read().bits();
        let sr = self.tim.sr().read().bits();
        let now = self.ext.extend(cnt);
        let mut event = Event::default();
        if sr & SR_CC1IF != 0 {
            let ccr = self.tim.ccr1().read().bits(); // reading CCR1 clears CC1IF
            let edge = self.ext.capture(ccr);
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

    /// Handles the TIM5 interrupt (QEMU: the update event stands for the compare, the
    /// simulated receiver's edge of the period just ended for the capture).
    #[cfg(feature = "qemu")]
    pub fn on_interrupt(&mut self) -> Event {
        let sr = self.tim.sr().read().bits();
        let mut event = Event::default();
        if sr & SR_UIF == 0 {
            return event;
        }
        // Note(unsafe): SR is rc_w0: clear UIF alone.
        unsafe { self.tim.sr().write(|w| w.bits(!SR_UIF & 0xFFFF)) };
        let start = self.base;
        // QEMU raises the update at the programmed instant and never runs late (no flash
        // stall); its CNT counts from the last ARR write, so the instant is taken as is.
        self.base = self.next.tick;
        let now = self.base;
        if self.disc.config().mode == SyncMode::Pps {
            if let Some(ccr) = self.gnss.capture(start, self.base - start) {
                // The CC1 interrupt the board takes at the edge, before this sample.
                let edge = start + u64::from(ccr);
                event.pps = Some((edge, self.disc.on_pps(edge)));
            }
        }
        self.sample_due(now, &mut event);
        self.arm();
        self.gnss.transmit(now);
        event
    }

    /// The compare of `self.next` fired and the counter read `now`: labels the sample and
    /// picks the next grid point.
    fn sample_due(&mut self, now: u64, event: &mut Event) {
        let c = catch_up(&mut self.disc, self.next, now, self.guard);
        self.next = c.next;
        event.sample = Some(c.sample);
        event.merged = c.merged;
        event.latency = u32::try_from(now - c.sample.tick).unwrap_or(u32::MAX);
    }

    /// Programs the compare for `self.next`; if the counter passed it meanwhile, forces the
    /// compare event so that the interrupt comes back at once.
    #[cfg(not(feature = "qemu"))]
    fn arm(&mut self) {
        self.tim.ccr2().write(|w| w.set(self.next.tick as u32));
        let now = self.ext.extend(self.tim.cnt().read().bits());
        if now >= self.next.tick {
            // Note(unsafe): EGR CC2G (bit 2) sets CC2IF as a compare match would.
            unsafe { self.tim.egr().write(|w| w.bits(1 << 2)) };
        }
    }

    /// QEMU: ARR, which QEMU applies at once (restarting the period), puts the next update
    /// `self.next - self.base` ticks on. It is written only when it changes: in free mode at
    /// a rate that divides the tick frequency never after start, so the emulated instants
    /// stay exact; in PPS mode each change restarts QEMU's period at the write, a few
    /// hundred emulated nanoseconds after the update, and everything (the simulated drive
    /// and receiver included) runs on the software's timeline.
    #[cfg(feature = "qemu")]
    fn arm(&mut self) {
        let arr = (self.next.tick - self.base - 1) as u32;
        if arr != self.arr {
            self.tim.arr().write(|w| w.set(arr));
            self.arr = arr;
        }
    }

    /// Changes the discipline's configuration (mode at once, rate from the next second);
    /// the PPS capture interrupt is on in `pps` mode only.
    pub fn set_config(&mut self, cfg: DisciplineConfig) -> Result<(), ConfigError> {
        self.disc.set_config(cfg)?;
        let pps = cfg.mode == SyncMode::Pps;
        // Note(unsafe): DIER CC1IE (bit 1) on or off; the compare/update enable is kept.
        self.tim.dier().modify(|r, w| unsafe {
            w.bits(if pps {
                r.bits() | DIER_CC1IE
            } else {
                r.bits() & !DIER_CC1IE
            })
        });
        Ok(())
    }

    /// After the clock security system fell back to the HSI (`super::clock_source`), widens
    /// the PPS lock range to the HSI's tolerance, once; a few instructions otherwise.
    pub fn follow_clock(&mut self) {
        let tolerance = super::clock_source(super::ClockSource::Hse).tolerance_ppm();
        let cfg = *self.disc.config();
        if cfg.max_offset_ppm < tolerance {
            let _ = self.set_config(DisciplineConfig {
                max_offset_ppm: tolerance,
                ..cfg
            });
        }
    }

    /// The discipline (state, statistics).
    pub fn discipline(&self) -> &Discipline {
        &self.disc
    }
}
