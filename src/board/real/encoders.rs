//! The two quadrature encoders: TIM2 (left, 32-bit) and TIM3 (right, 16-bit) in encoder
//! mode 3 (x4: both edges of A and B), read together at each sample, and their index (N)
//! lines latched by the same timers in hardware.
//!
//! Snapshot skew: [`Encoders::snapshot`] is two consecutive volatile loads (TIM2 CNT, then
//! TIM3 CNT) on APB1, the first action of the TIM5 interrupt (priority 4, the highest):
//! a few bus cycles apart, under 100 ns at 84 MHz (nothing can preempt between them but a
//! fault). Against a 20 ms sample period that is a 5e-6 relative timing difference between
//! the wheels. The latency from the sample instant (the TIM5 compare match) to the first
//! read is the interrupt entry (12 cycles plus flash wait states) unless another priority-4
//! handler is running (an index capture: a few dozen cycles); the firmware measures it
//! (`sample_latency_max` in `status`).
//!
//! Index latching: the left index line drives TIM2 CH3 (PB10) and the right one TIM3 CH4
//! (PB1), both in input capture on the rising edge, so the counter value at the index edge
//! is latched by the timer itself, with no interrupt latency: the capture interrupt only
//! has to read it before the next index pulse (one wheel turn later). Two pulses before the
//! read set the over-capture flag, reported as a lost pulse.

use odo_unit::unit::{IndexCapture, RawCounts};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Enable;

/// Width of the left counter (TIM2), bits.
pub const LEFT_BITS: u32 = 32;
/// Width of the right counter (TIM3), bits.
pub const RIGHT_BITS: u32 = 16;

/// Invert the left encoder's count direction (CC1P), e.g. for a mirror-mounted encoder so
/// that forward motion counts up on both wheels.
pub const INVERT_LEFT: bool = false;
/// Invert the right encoder's count direction.
pub const INVERT_RIGHT: bool = false;

/// Input filter of the A/B inputs (ICxF = 0b0011: 8 samples at 84 MHz, rejects glitches
/// shorter than about 95 ns; allows edge rates up to about 5 MHz).
const INPUT_FILTER: u32 = 0b0011;

/// Input filter of the index inputs (ICxF = 0b0011, as the A/B inputs).
const INDEX_FILTER: u32 = 0b0011;

const SR_CC3IF: u32 = 1 << 3;
const SR_CC4IF: u32 = 1 << 4;
const SR_CC3OF: u32 = 1 << 11;
const SR_CC4OF: u32 = 1 << 12;

/// The two encoder timers.
pub struct Encoders {
    left: pac::TIM2,
    right: pac::TIM3,
}

impl Encoders {
    /// Enables and configures both timers in encoder mode 3 and starts them.
    pub fn new(left: pac::TIM2, right: pac::TIM3, rcc: &mut pac::RCC) -> Self {
        pac::TIM2::enable(rcc);
        pac::TIM3::enable(rcc);
        let ccmr1 = 0b01 | INPUT_FILTER << 4 | 0b01 << 8 | INPUT_FILTER << 12;
        // Index captures: TIM2 CC3S = 01 (IC3 on TI3, PB10), TIM3 CC4S = 01 (IC4 on TI4, PB1).
        let ccmr2_left = 0b01 | INDEX_FILTER << 4;
        let ccmr2_right = (0b01 | INDEX_FILTER << 4) << 8;
        // Note(unsafe): raw register values from RM0368 sec. 13.4 (encoder interface mode
        // and input capture): CC1S = CC2S = 01 (TI1/TI2 inputs), SMS = 011 (x4), CC1P for the
        // direction; CC3E (TIM2) / CC4E (TIM3) rising edge with CC3IE / CC4IE.
        unsafe {
            left.ccmr1_input().write(|w| w.bits(ccmr1));
            left.ccmr2_input().write(|w| w.bits(ccmr2_left));
            left.ccer()
                .write(|w| w.bits(u32::from(INVERT_LEFT) << 1 | 1 << 8));
            left.smcr().write(|w| w.bits(0b011));
            left.sr().write(|w| w.bits(0));
            left.dier().write(|w| w.bits(SR_CC3IF));
            right.ccmr1_input().write(|w| w.bits(ccmr1));
            right.ccmr2_input().write(|w| w.bits(ccmr2_right));
            right
                .ccer()
                .write(|w| w.bits(u32::from(INVERT_RIGHT) << 1 | 1 << 12));
            right.smcr().write(|w| w.bits(0b011));
            right.arr().write(|w| w.bits(0xFFFF));
            right.sr().write(|w| w.bits(0));
            right.dier().write(|w| w.bits(SR_CC4IF));
            left.cr1().write(|w| w.bits(1));
            right.cr1().write(|w| w.bits(1));
        }
        left.arr().write(|w| w.set(u32::MAX));
        Self { left, right }
    }

    /// Both counters, left first (see the module documentation for the skew).
    #[inline(always)]
    pub fn snapshot(&self) -> RawCounts {
        let left = self.left.cnt().read().bits();
        let right = self.right.cnt().read().bits() & 0xFFFF;
        RawCounts { left, right }
    }

    /// The left index pulse latched by TIM2 CH3, if one came since the last call (TIM2
    /// interrupt).
    pub fn take_index_left(&self) -> Option<IndexCapture> {
        let sr = self.left.sr().read().bits();
        if sr & SR_CC3IF == 0 {
            return None;
        }
        let raw = self.left.ccr3().read().bits(); // clears CC3IF
        let overcapture = sr & SR_CC3OF != 0;
        if overcapture {
            // Note(unsafe): SR is rc_w0: writing 0 to CC3OF alone clears it.
            unsafe { self.left.sr().write(|w| w.bits(!SR_CC3OF & 0xFFFF)) };
        }
        Some(IndexCapture {
            raw,
            overcapture,
            queue_lost: 0,
        })
    }

    /// The right index pulse latched by TIM3 CH4, if one came since the last call (TIM3
    /// interrupt).
    pub fn take_index_right(&self) -> Option<IndexCapture> {
        let sr = self.right.sr().read().bits();
        if sr & SR_CC4IF == 0 {
            return None;
        }
        let raw = self.right.ccr4().read().bits() & 0xFFFF; // clears CC4IF
        let overcapture = sr & SR_CC4OF != 0;
        if overcapture {
            // Note(unsafe): SR is rc_w0: writing 0 to CC4OF alone clears it.
            unsafe { self.right.sr().write(|w| w.bits(!SR_CC4OF & 0xFFFF)) };
        }
        Some(IndexCapture {
            raw,
            overcapture,
            queue_lost: 0,
        })
    }
}
