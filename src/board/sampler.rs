//! The sample timer TIM5 (32-bit, free-running): its CH2 output compare fires at each
//! sample's tick from the [`Discipline`]'s grid, and its CH1 captures the GNSS 1-PPS on the
//! same counter.
//!
//! TIM5 counts timer ticks (84 MHz on the board) from 0 to 2^32 - 1 and wraps (every 51 s);
//! [`TimerExtender`](odo_unit::timing::TimerExtender) makes the 64-bit tick timeline of the
//! discipline from it, which needs a reading at least every 2^31 ticks (25 s): every sample
//! interrupt reads it, and the slowest rate is 1 Hz. Each compare interrupt reads the counter as
//! its first action (after the encoders, see `src/board/real/encoders.rs`), and [`catch_up`] labels
//! that instant with the latest grid point it has reached. Normally that is the point just due;
//! after a stall (a flash sector erase stops the CPU for up to [`super::flash::MAX_ERASE_MS`]) it
//! is the last of the points the stall passed over, which are merged into it: their motion is in
//! the counts (the encoder timers keep counting), the time labels stay those of the grid, the GNSS
//! seconds stay right, and the next compare goes on the first future grid point. A compare value
//! that the counter passed while it was being written is caught by reading the counter back and
//! forcing the compare event (EGR CC2G). The handler's reads, their order (flags before the
//! counter, so that a compare firing between them is not lost) and its decisions are
//! [`odo_unit::timing::compare`], host-tested on a simulated timer.
//!
//! The PPS capture (CH1, rising edge, input filter [`PPS_FILTER`]) latches the counter at
//! the edge; a second edge before the interrupt reads it sets the over-capture flag (one
//! edge lost, reported). The capture and its interrupt are enabled only in `pps` mode.
//!
//! QEMU models neither output compare nor input capture: in the `qemu` build the compare is
//! emulated by the update event (the counter restarts at each sample and ARR, which QEMU
//! applies at once, is set to the next sample's distance), the PPS captures come from the
//! simulated receiver, and the same [`catch_up`] runs on that timeline (QEMU never stalls:
//! its flash is RAM).
//!
//! This file holds what both share; the interrupt handler and the compare programming of
//! each are in `real/sampler.rs` and `qemu/sampler.rs` ([`Timeline`]).

use super::variant::sampler::Timeline;
use super::SamplerExtra;
use odo_unit::timing::{ConfigError, Discipline, DisciplineConfig, Sample, SyncMode};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Enable;

pub use odo_unit::timing::TimerEvent as Event;

/// Input filter of the PPS input (IC1F = 0b0011: 8 consecutive samples at 84 MHz). It
/// rejects pulses shorter than about 95 ns and delays the capture by as much, a constant
/// 8-10 ticks that is the same at every edge (so it does not change the measured period) and
/// shifts the sample grid by under 0.12 us against GNSS time.
pub const PPS_FILTER: u32 = 0b0011;

/// TIM5 and the discipline.
pub struct Sampler {
    pub(super) tim: pac::TIM5,
    pub(super) disc: Discipline,
    /// The board variant's view of the timer and the programmed sample ([`Timeline`]).
    pub(super) timeline: Timeline,
}

impl Sampler {
    /// Configures TIM5 and starts it; returns the sampler and sample 0 (tick 0: now).
    /// `extra`: what the board variant's timeline needs besides TIM5.
    pub fn start(
        tim: pac::TIM5,
        rcc: &mut pac::RCC,
        mut disc: Discipline,
        extra: SamplerExtra,
    ) -> (Self, Sample) {
        pac::TIM5::enable(rcc);
        let s0 = disc.next_sample(0);
        let s1 = disc.next_sample(0);
        // Ticks of lead the compare needs: points closer than this to `now` are merged.
        let guard = u64::from(disc.config().timer_hz / 100_000).max(1);
        let pps = disc.config().mode == SyncMode::Pps;
        // Note(unsafe): raw register values from RM0368 sec. 13.4: PSC = 0; CR1 = URS (only
        // overflows raise the update flag); CCMR1 CC1S = 01 (IC1 on TI1) with IC1F, CC2S = 00
        // with OC2M = 000 (frozen: the compare only sets CC2IF); CCER CC1E (rising edge) in
        // pps mode only.
        unsafe {
            tim.psc().write(|w| w.bits(0));
            tim.cr1().write(|w| w.bits(1 << 2));
            tim.ccmr1_input().write(|w| w.bits(0b01 | PPS_FILTER << 4));
            tim.ccer().write(|w| w.bits(u32::from(pps)));
        }
        let timeline = Timeline::program(&tim, s0, s1, guard, extra);
        // Note(unsafe): EGR UG (bit 0) zeroes the counter and loads PSC and ARR; then clear
        // all flags (SR is rc_w0), enable the interrupts and CR1 |= CEN.
        unsafe {
            tim.egr().write(|w| w.bits(1));
            tim.sr().write(|w| w.bits(0));
            tim.dier().write(|w| {
                w.bits(Timeline::DIER_SAMPLE | if pps { Timeline::DIER_CAPTURE } else { 0 })
            });
            tim.cr1().modify(|r, w| w.bits(r.bits() | 1));
        }
        let sampler = Self {
            tim,
            disc,
            timeline,
        };
        (sampler, s0)
    }

    /// Changes the discipline's configuration (mode at once, rate from the next second);
    /// the PPS capture and its interrupt are on in `pps` mode only.
    pub fn set_config(&mut self, cfg: DisciplineConfig) -> Result<(), ConfigError> {
        let was_pps = self.disc.config().mode == SyncMode::Pps;
        self.disc.set_config(cfg)?;
        let pps = cfg.mode == SyncMode::Pps;
        if pps != was_pps {
            self.set_capture(pps);
        }
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
