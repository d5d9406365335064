//! Receive errors of a UART (USART_SR, RM0368 sec. 19.6.1), counted by its interrupt: what
//! the status flags read before the data register say about the byte in it.

/// USART_SR PE: parity error.
pub const SR_PE: u16 = 1 << 0;
/// USART_SR FE: framing error (no stop bit: a baud mismatch, a break, a broken line).
pub const SR_FE: u16 = 1 << 1;
/// USART_SR NF: noise detected while sampling the byte.
pub const SR_NF: u16 = 1 << 2;
/// USART_SR ORE: overrun, bytes arrived while the data register was full and were lost.
pub const SR_ORE: u16 = 1 << 3;
/// USART_SR RXNE: a byte waits in the data register.
pub const SR_RXNE: u16 = 1 << 5;

/// Receive error counters of one UART since start (all wrapping).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RxErrors {
    /// Bytes known lost: one per overrun (at least one byte; all bytes of a CPU stall were
    /// lost in it) and one per byte refused by a full queue.
    pub lost: u32,
    /// Overruns.
    pub overruns: u32,
    /// Bytes with a framing error (dropped).
    pub framing: u32,
    /// Bytes with noise detected (kept: the majority vote of the samples decided each bit).
    pub noise: u32,
    /// Bytes with a parity error (dropped; only with parity enabled).
    pub parity: u32,
}

/// What to do with the data register after reading the status flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RxByte {
    /// Nothing received.
    None,
    /// Read the data register (it clears the flags) and pass the byte on.
    Keep,
    /// Read the data register (it clears the flags) and drop the byte (framing or parity
    /// error; counted).
    Drop,
}

impl RxErrors {
    /// Counts the errors in `sr` (USART_SR, read before the data register) and says what to
    /// do with the byte.
    pub fn on_status(&mut self, sr: u16) -> RxByte {
        if sr & (SR_RXNE | SR_ORE) == 0 {
            return RxByte::None;
        }
        let count = |n: &mut u32, flag: u16| {
            if sr & flag != 0 {
                *n = n.wrapping_add(1);
            }
        };
        count(&mut self.overruns, SR_ORE);
        count(&mut self.lost, SR_ORE);
        count(&mut self.noise, SR_NF);
        count(&mut self.framing, SR_FE);
        count(&mut self.parity, SR_PE);
        if sr & (SR_FE | SR_PE) != 0 {
            RxByte::Drop
        } else {
            RxByte::Keep
        }
    }

    /// A received byte was refused by a full queue.
    pub fn on_queue_full(&mut self) {
        self.lost = self.lost.wrapping_add(1);
    }

    /// Framing, noise and parity errors together.
    pub fn line_errors(&self) -> u32 {
        self.framing
            .wrapping_add(self.noise)
            .wrapping_add(self.parity)
    }
}
