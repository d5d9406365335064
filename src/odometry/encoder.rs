//! Encoder arithmetic, eq (1): wrap-safe increments of a hardware quadrature counter, extended
//! to a 64-bit absolute increment count `Gamma_i`.
//!
//! The STM32F401's timers count 16 bits (TIM3, TIM4) or 32 bits (TIM2, TIM5) and wrap. As long
//! as a wheel moves less than half the counter's range between two reads (32,767 increments
//! for a 16-bit counter: 1.6 wheel turns at 20,000 increments per turn), the signed difference
//! of two raw reads, taken modulo the counter's width, is the true increment count.

/// Extends a wrapping `BITS`-wide hardware counter (1..=32 bits) to a 64-bit absolute count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CounterExtender {
    /// Left shift that moves the counter's top bit to bit 31.
    shift: u32,
    /// Last raw reading.
    last_raw: u32,
    /// Absolute increment count `Gamma` (increments).
    absolute: i64,
}

impl CounterExtender {
    /// A counter `bits` wide (1..=32; clamped into that range) whose current raw reading is
    /// `raw`; the absolute count starts at `raw` read as a signed `bits`-wide number, so a
    /// counter that starts at 0 and goes backwards reads negative.
    pub const fn new(bits: u32, raw: u32) -> Self {
        let bits = if bits == 0 {
            1
        } else if bits > 32 {
            32
        } else {
            bits
        };
        let shift = 32 - bits;
        Self {
            shift,
            last_raw: raw,
            absolute: (((raw << shift) as i32) >> shift) as i64,
        }
    }

    /// Takes a new raw reading and returns the increments since the previous one (eq 1),
    /// wrap-safe while the true motion between reads is under half the counter's range.
    pub fn update(&mut self, raw: u32) -> i32 {
        let delta = ((raw.wrapping_sub(self.last_raw) << self.shift) as i32) >> self.shift;
        self.last_raw = raw;
        self.absolute += i64::from(delta);
        delta
    }

    /// The absolute increment count `Gamma` (increments).
    pub const fn absolute(&self) -> i64 {
        self.absolute
    }

    /// The absolute count that corresponds to a raw value `raw` latched by hardware after the
    /// last [`update`](Self::update) (for example the counter captured at an index pulse),
    /// assuming it lies within half the counter's range of the last reading.
    pub const fn absolute_of(&self, raw: u32) -> i64 {
        let delta = ((raw.wrapping_sub(self.last_raw) << self.shift) as i32) >> self.shift;
        self.absolute + delta as i64
    }

    /// Width of the counter in bits.
    pub const fn bits(&self) -> u32 {
        32 - self.shift
    }
}
