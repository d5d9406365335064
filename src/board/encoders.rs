//! The two quadrature encoders: TIM2 (left, 32-bit) and TIM3 (right, 16-bit) in encoder
//! mode 3 (x4: both edges of A and B), read together at each sample.
//!
//! Snapshot skew: [`Encoders::snapshot`] is two consecutive volatile loads (TIM2 CNT, then
//! TIM3 CNT) on APB1, inlined at the top of the TIM5 interrupt (priority 4, the highest):
//! a few bus cycles apart, under 100 ns at 84 MHz (nothing can preempt between them but a
//! fault). Against a 20 ms sample period that is a 5e-6 relative timing difference between
//! the wheels. The latency from the sample instant (TIM5 update event) to the first read is
//! the interrupt entry (12 cycles) plus whatever priority-4 handler is running (an index
//! interrupt: well under 2 us); it is the same for both wheels.

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

/// Raw counter values read together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub struct Snapshot {
    /// TIM2 CNT (left).
    pub left: u32,
    /// TIM3 CNT (right, 16 bits).
    pub right: u32,
}

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
        // Note(unsafe): raw register values from RM0368 sec. 13.4 (encoder interface mode):
        // CC1S = CC2S = 01 (TI1/TI2 inputs), SMS = 011 (x4), CC1P for the direction.
        unsafe {
            left.ccmr1_input().write(|w| w.bits(ccmr1));
            left.ccer().write(|w| w.bits(u32::from(INVERT_LEFT) << 1));
            left.smcr().write(|w| w.bits(0b011));
            right.ccmr1_input().write(|w| w.bits(ccmr1));
            right.ccer().write(|w| w.bits(u32::from(INVERT_RIGHT) << 1));
            right.smcr().write(|w| w.bits(0b011));
            right.arr().write(|w| w.bits(0xFFFF));
            left.cr1().write(|w| w.bits(1));
            right.cr1().write(|w| w.bits(1));
        }
        left.arr().write(|w| w.set(u32::MAX));
        Self { left, right }
    }

    /// Both counters, left first (see the module documentation for the skew).
    #[inline(always)]
    pub fn snapshot(&self) -> Snapshot {
        let left = self.left.cnt().read().bits();
        let right = self.right.cnt().read().bits() & 0xFFFF;
        Snapshot { left, right }
    }

    /// The left counter alone (index interrupt).
    #[inline(always)]
    pub fn left(&self) -> u32 {
        self.left.cnt().read().bits()
    }

    /// The right counter alone (index interrupt).
    #[inline(always)]
    pub fn right(&self) -> u32 {
        self.right.cnt().read().bits() & 0xFFFF
    }
}
