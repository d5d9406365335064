//! TIM5 in QEMU, which models neither output compare nor input capture: the update event
//! stands for the compare, the simulated receiver's edge for the capture
//! (`src/board/sampler.rs`).

use super::gnss::SimGnss;
use crate::board::sampler::{Event, Sampler};
use core::sync::atomic::{AtomicU32, Ordering};
use odo_unit::timing::{catch_up, Sample, SyncMode};
use stm32f4xx_hal::pac;

const SR_UIF: u32 = 1 << 0;

/// Low 32 bits of [`Timeline`]'s base and TIM5's counter when the interrupt took it, for
/// [`super::tick_now`] in other interrupts.
static BASE_LOW: AtomicU32 = AtomicU32::new(0);
static BASE_CNT: AtomicU32 = AtomicU32::new(0);

/// The low 32 bits of the last sample instant's tick, and TIM5's counter when its interrupt
/// ran.
pub fn base() -> (u32, u32) {
    (
        BASE_LOW.load(Ordering::Acquire),
        BASE_CNT.load(Ordering::Acquire),
    )
}

/// TIM5's counter now.
pub fn counter() -> u32 {
    // Note(unsafe): a read of TIM5 CNT; reads have no side effect.
    unsafe { (*pac::TIM5::ptr()).cnt().read().bits() }
}

/// The restarting counter's timeline and the simulated receiver.
pub struct Timeline {
    /// The tick at which the counter last restarted (the last sample instant).
    base: u64,
    /// The ARR value last written.
    arr: u32,
    /// The simulated GNSS receiver: PPS captures and NMEA bytes (QEMU has neither).
    gnss: SimGnss,
    /// The sample whose update is programmed.
    next: Sample,
    /// Ticks of lead a new period needs: points closer than this are merged.
    guard: u64,
}

impl Timeline {
    /// DIER bit of the sample interrupt: UIE (the update event).
    pub const DIER_SAMPLE: u32 = 1 << 0;
    /// DIER bit of the PPS capture interrupt: none (the simulated receiver's edges are taken
    /// at the update).
    pub const DIER_CAPTURE: u32 = 0;

    /// ARR puts the first update at sample `s1`.
    pub fn program(tim: &pac::TIM5, s0: Sample, s1: Sample, guard: u64, gnss: SimGnss) -> Self {
        tim.arr().write(|w| w.set((s1.tick - 1) as u32));
        Self {
            base: s0.tick,
            arr: (s1.tick - s0.tick - 1) as u32,
            gnss,
            next: s1,
            guard,
        }
    }
}

impl Sampler {
    /// Handles the TIM5 interrupt (QEMU: the update event stands for the compare, the
    /// simulated receiver's edge of the period just ended for the capture).
    pub fn on_interrupt(&mut self) -> Event {
        let sr = self.tim.sr().read().bits();
        let mut event = Event::default();
        if sr & SR_UIF == 0 {
            return event;
        }
        // Note(unsafe): SR is rc_w0: clear UIF alone.
        unsafe { self.tim.sr().write(|w| w.bits(!SR_UIF & 0xFFFF)) };
        let start = self.timeline.base;
        // QEMU raises the update at the programmed instant and never runs late (no flash
        // stall); its CNT counts from the last ARR write, so the instant is taken as is.
        self.timeline.base = self.timeline.next.tick;
        let now = self.timeline.base;
        BASE_LOW.store(now as u32, Ordering::Release);
        BASE_CNT.store(counter(), Ordering::Release);
        if self.disc.config().mode == SyncMode::Pps {
            if let Some(ccr) = self.timeline.gnss.capture(start, now - start) {
                // The CC1 interrupt the board takes at the edge, before this sample.
                let edge = start + u64::from(ccr);
                event.pps = Some((edge, self.disc.on_pps(edge)));
            }
        }
        let c = catch_up(&mut self.disc, self.timeline.next, now, self.timeline.guard);
        self.timeline.next = c.next;
        event.sample = Some(c.sample);
        event.merged = c.merged;
        event.latency = u32::try_from(now - c.sample.tick).unwrap_or(u32::MAX);
        self.arm();
        self.timeline.gnss.transmit(now);
        event
    }

    /// ARR, which QEMU applies at once (restarting the period), puts the next update
    /// `self.next - base` ticks on. It is written only when it changes: in free mode at a
    /// rate that divides the tick frequency never after start, so the emulated instants
    /// stay exact; in PPS mode each change restarts QEMU's period at the write, a few
    /// hundred emulated nanoseconds after the update, and everything (the simulated drive
    /// and receiver included) runs on the software's timeline.
    fn arm(&mut self) {
        let arr = (self.timeline.next.tick - self.timeline.base - 1) as u32;
        if arr != self.timeline.arr {
            self.tim.arr().write(|w| w.set(arr));
            self.timeline.arr = arr;
        }
    }
}

impl Sampler {
    /// The simulated receiver's edges are taken in `pps` mode only (`on_interrupt`): no
    /// capture unit to switch.
    pub(crate) fn set_capture(&mut self, _on: bool) {}
}
