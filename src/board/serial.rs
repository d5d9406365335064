//! The UARTs: the host link on USART2 (commands in, frames out) and the GNSS NMEA input on
//! USART1 (receive only).
//!
//! Transmission is interrupt-driven from [`TxRing`] (`odo_unit::protocol::tx_ring`), a byte
//! ring that producers fill with whole frames only ([`TxRing::push_frame`] refuses a frame
//! that does not fit, so a record the link cannot carry is dropped whole and counted by the
//! caller). The USART2 interrupt moves bytes to the data register while TXE is set and the ring is not empty; TXEIE is on
//! only while bytes wait. Nothing here ever waits for the UART, so sampling is never
//! blocked. Reception puts each byte into a lock-free queue for the command task.
//!
//! In QEMU the USART sends synchronously and TXE is always set: one interrupt drains the
//! ring.

use heapless::spsc::Producer;
use odo_unit::protocol::TxRing;
use odo_unit::unit::RxByte;
pub use odo_unit::unit::RxErrors;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Enable;

const SR_TXE: u16 = 1 << 7;
const CR1_RE: u16 = 1 << 2;
const CR1_TE: u16 = 1 << 3;
const CR1_RXNEIE: u16 = 1 << 5;
const CR1_TXEIE: u16 = 1 << 7;
const CR1_UE: u16 = 1 << 13;

/// USARTDIV for 16x oversampling (the BRR value), rounded.
fn brr(pclk: u32, baud: u32) -> u16 {
    ((pclk + baud / 2) / baud.max(1)).min(0xFFFF) as u16
}

/// The host link, USART2.
pub struct HostUart {
    usart: pac::USART2,
}

impl HostUart {
    /// Enables USART2 at `baud` (8N1) with the receive interrupt.
    pub fn new(usart: pac::USART2, rcc: &mut pac::RCC, pclk1: u32, baud: u32) -> Self {
        pac::USART2::enable(rcc);
        // Note(unsafe): raw BRR and CR1 values (RM0368 sec. 19.6).
        unsafe {
            usart.brr().write(|w| w.bits(brr(pclk1, baud)));
            usart
                .cr1()
                .write(|w| w.bits(CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE));
        }
        Self { usart }
    }

    /// The USART2 interrupt: received bytes to `rx`, ring bytes to the transmitter. True
    /// when a byte was received.
    pub fn on_interrupt<const N: usize>(
        &mut self,
        ring: &mut TxRing<N>,
        rx: &mut Producer<'_, u8>,
        errors: &mut RxErrors,
    ) -> bool {
        let sr = self.usart.sr().read().bits();
        let status = errors.on_status(sr);
        let received = status != RxByte::None;
        if received {
            // Reading DR after SR clears RXNE, ORE, NF, FE and PE.
            let byte = self.usart.dr().read().bits() as u8;
            if status == RxByte::Keep && rx.enqueue(byte).is_err() {
                errors.on_queue_full();
            }
        }
        while self.usart.sr().read().bits() & SR_TXE != 0 {
            let Some(b) = ring.pop() else {
                break;
            };
            // Note(unsafe): DR takes any 8-bit value.
            unsafe { self.usart.dr().write(|w| w.bits(u16::from(b))) };
        }
        self.enable_tx_interrupt(!ring.is_empty());
        received
    }

    /// Turns the TXE interrupt on (bytes wait) or off.
    pub fn enable_tx_interrupt(&mut self, on: bool) {
        // Note(unsafe): sets or clears TXEIE only.
        unsafe {
            self.usart.cr1().modify(|r, w| {
                w.bits(if on {
                    r.bits() | CR1_TXEIE
                } else {
                    r.bits() & !CR1_TXEIE
                })
            });
        }
    }
}

/// The GNSS receiver's NMEA output, USART1 (receive only).
pub struct GnssUart {
    usart: pac::USART1,
}

impl GnssUart {
    /// Enables USART1 at `baud` (8N1) with the receive interrupt.
    pub fn new(usart: pac::USART1, rcc: &mut pac::RCC, pclk2: u32, baud: u32) -> Self {
        pac::USART1::enable(rcc);
        // Note(unsafe): raw BRR and CR1 values (RM0368 sec. 19.6).
        unsafe {
            usart.brr().write(|w| w.bits(brr(pclk2, baud)));
            usart.cr1().write(|w| w.bits(CR1_UE | CR1_RE | CR1_RXNEIE));
        }
        Self { usart }
    }

    /// The USART1 interrupt: the received byte, if any and good (errors counted in
    /// `errors`).
    pub fn on_interrupt(&mut self, errors: &mut RxErrors) -> Option<u8> {
        let status = errors.on_status(self.usart.sr().read().bits());
        if status == RxByte::None {
            return None;
        }
        // Reading DR after SR clears RXNE, ORE, NF, FE and PE.
        let byte = self.usart.dr().read().bits() as u8;
        (status == RxByte::Keep).then_some(byte)
    }
}
