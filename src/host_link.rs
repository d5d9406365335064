//! Frames from the tasks to the host link: encoded outside the lock, queued whole.

use odo_unit::mavlink::FrameBuf;
use odo_unit::protocol::{self, Message, Queued, TxLink};
use rtic::Mutex;
use stm32f4xx_hal::pac::Interrupt;

/// Host link transmit buffer, bytes.
pub const TX_BUF: usize = 4096;
/// Transmit space a pose record leaves free for command replies, bytes.
pub const RECORD_RESERVE: usize = 1024;

/// Transmit space a GNSS sentence frame leaves free: [`RECORD_RESERVE`] plus one Status and
/// one pose record frame (`odo_unit::unit::forward::sentence_reserve`).
pub const SENTENCE_RESERVE: usize = odo_unit::unit::forward::sentence_reserve(RECORD_RESERVE);

/// The host link's transmit side.
pub type Link = TxLink<TX_BUF>;

/// Encodes `msg` as the next frame and queues it whole if it fits with `reserve` bytes to
/// spare; false when it did not fit (nothing queued, sequence number unchanged). The
/// frame is encoded outside the lock; if another task sent a frame meanwhile, it is
/// encoded again with the new sequence number.
pub fn send(link: &mut impl Mutex<T = Link>, msg: &Message, reserve: usize) -> bool {
    let mut buf = [0u8; protocol::MAX_ENCODED_FRAME];
    loop {
        let seq = link.lock(|l| l.next_seq());
        let Ok(n) = protocol::encode_frame(msg, seq, &mut buf) else {
            return false;
        };
        match link.lock(|l| l.queue(seq, &buf[..n], reserve)) {
            Queued::Queued => {
                rtic::pend(Interrupt::USART2);
                return true;
            }
            Queued::NoRoom => return false,
            Queued::Stale => {}
        }
    }
}

/// Queues `msg` as the next frame before the tasks run (in `init`: no lock); false when it
/// did not fit.
pub fn queue_now(link: &mut Link, msg: &Message) -> bool {
    let mut buf = [0u8; protocol::MAX_ENCODED_FRAME];
    let seq = link.next_seq();
    let Ok(n) = protocol::encode_frame(msg, seq, &mut buf) else {
        return false;
    };
    let queued = link.queue(seq, &buf[..n], 0) == Queued::Queued;
    if queued {
        rtic::pend(Interrupt::USART2);
    }
    queued
}

/// Sends a reply frame, waiting for room (only the command task, the lowest priority,
/// waits; the ring drains in the USART2 interrupt meanwhile).
pub fn send_blocking(link: &mut impl Mutex<T = Link>, msg: &Message) {
    while !send(link, msg, 0) {
        cortex_m::asm::nop();
    }
}

/// Queues the MAVLink frame of `n` bytes in `frame` and a `0x00` after it (the delimiter
/// of our frames: a reader of our frames resynchronises before the next reply), whole if it
/// fits with `reserve` bytes to spare; false when it did not fit (nothing queued). Only the
/// processing task sends MAVLink frames.
pub fn send_mavlink(
    link: &mut impl Mutex<T = Link>,
    frame: &mut FrameBuf,
    n: usize,
    reserve: usize,
) -> bool {
    let Some(bytes) = frame.get_mut(..=n) else {
        return false;
    };
    bytes[n] = 0;
    let queued = link.lock(|l| l.queue_raw(bytes, reserve));
    if queued {
        rtic::pend(Interrupt::USART2);
    }
    queued
}
