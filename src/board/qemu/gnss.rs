//! The simulated GNSS receiver of the `qemu` build: QEMU 7.2 models no timer input capture
//! and nothing on USART1's receive line, so the 1-PPS captures and the NMEA bytes come from
//! this deterministic receiver instead. It enters the firmware where the hardware would:
//!
//! - **PPS**: [`SimGnss::capture`] gives the TIM5 counter value (CCR1) at which an edge would
//!   have been captured in the sample period that just ended; the sampler
//!   (`src/board/sampler.rs`) treats it exactly as the CC1 interrupt the board takes at the
//!   edge, before the update event (`resolve_capture`, then `Discipline::on_pps`).
//! - **NMEA**: [`SimGnss::transmit`] puts the bytes that have "arrived" by the current sample
//!   instant (10 bits each at [`GNSS_BAUD`]) on a byte wire and pends USART1; the USART1
//!   interrupt task reads them through [`SimUart`], one byte per interrupt as from the data
//!   register, and feeds the firmware's NMEA byte queue as on the board.
//!
//! Everything downstream (resolve_capture, the discipline, the time tagger, the NMEA parser,
//! records) is the real code. The receiver runs from boot whatever the `mode` setting: in
//! `mode free` the discipline ignores its edges and the tagger its messages (they are still
//! parsed and counted, as on a board with a receiver attached).
//!
//! # The receiver
//!
//! Times are ticks of the MCU timeline (TIM5, 1 GHz in QEMU). The MCU clock runs
//! [`CRYSTAL_PPM`] = 37 ppm fast against GNSS time, so one GNSS second lasts
//! [`SECOND_TICKS`] = 1,000,037,000 ticks. Receiver second `n` (n = 0, 1, ...) starts at
//! `FIRST_EDGE + n * SECOND_TICKS` plus a jitter of at most [`JITTER`] = 40 ticks (a fixed
//! pseudo-random function of `n`), with [`FIRST_EDGE`] = 0.25 s after boot. Second `n` is
//! UTC [`START`] + `n` s, [`START`] = 2026-11-21 12:00:00 UTC: GPS week 2445, time of week
//! 561,618 s at `n = 0` (GPS = UTC + 18 s).
//!
//! After its edge, second `n` gets `$GPZDA` then `$GPRMC` (status `A`) naming second `n`
//! (the `time_tag_pps = previous` convention), starting [`NMEA_DELAY`] = 100 ms after the
//! nominal edge (about 28 ms of bytes at 38,400 baud).
//!
//! The script repeats every [`LAP`] = 20 receiver seconds (`n % 20`):
//!
//! | lap second | what happens |
//! |---|---|
//! | 5 | the RMC has one bit flipped on the line (wrong checksum: `nmea_errors`) |
//! | 8 | a second, spurious edge 300 ms after the real one (a glitch: `pps_glitches`) |
//! | 12, 13, 14 | no PPS edge (a 3 s outage: holdover, then reacquisition at 15); NMEA goes on |
//!
//! Edges are at least 300 ms apart, so no sample period holds two (the board would take a
//! CC1 interrupt for each; this model delivers at most one per period).

use heapless::spsc::{Consumer, Producer, Queue};
use odo_unit::timing::UtcDateTime;
use stm32f4xx_hal::pac::Interrupt;

use crate::board::serial::{GnssUart, RxErrors};
use crate::board::GNSS_BAUD;

/// Ticks of the MCU timeline per nominal second (QEMU's timers: 1 GHz).
const HZ: u64 = 1_000_000_000;
/// Frequency error of the MCU clock against GNSS time, ppm (the MCU counts fast).
pub const CRYSTAL_PPM: u64 = 37;
/// One GNSS second in MCU ticks.
pub const SECOND_TICKS: u64 = HZ + HZ * CRYSTAL_PPM / 1_000_000;
/// MCU tick of the nominal edge of receiver second 0.
pub const FIRST_EDGE: u64 = 250_000_000;
/// Largest PPS jitter, ticks (ns): each edge is off its nominal time by -40..=40.
pub const JITTER: u64 = 40;
/// UTC of receiver second 0.
pub const START: UtcDateTime = UtcDateTime {
    year: 2026,
    month: 11,
    day: 21,
    hour: 12,
    minute: 0,
    second: 0,
    millis: 0,
};
/// Length of the scripted lap, receiver seconds.
pub const LAP: u64 = 20;
/// Lap second whose RMC is corrupted.
pub const CORRUPT_SECOND: u64 = 5;
/// Lap second followed by a glitch edge, and the glitch's delay after the real edge, ticks.
pub const GLITCH_SECOND: u64 = 8;
/// Delay of the glitch edge after the real one, ticks.
pub const GLITCH_DELAY: u64 = 300_000_000;
/// Lap seconds without a PPS edge: `OUTAGE.0..OUTAGE.1`.
pub const OUTAGE: (u64, u64) = (12, 15);
/// Start of a second's NMEA bytes after its nominal edge, ticks.
pub const NMEA_DELAY: u64 = 100_000_000;

/// Bytes the wire (the receiver's UART to USART1) holds between two sample interrupts: at
/// 38,400 baud and 50 Hz about 77 arrive per sample period; more wait in the receiver.
const WIRE: usize = 128;
/// ZDA and RMC of one second.
const BURST: usize = 160;

/// Jitter of edge `n`, ticks, in `-JITTER..=JITTER` (splitmix64 of `n`).
fn jitter(n: u64) -> i64 {
    let mut x = n.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x % (2 * JITTER + 1)) as i64 - JITTER as i64
}

/// Nominal start of receiver second `n`, ticks.
fn nominal(n: u64) -> u64 {
    FIRST_EDGE + n * SECOND_TICKS
}

/// The PPS edge of receiver second `n`, ticks.
fn edge(n: u64) -> u64 {
    nominal(n).wrapping_add_signed(jitter(n))
}

/// One byte on the line (start, 8 data and stop bits), ticks (260,416 at 38,400 baud).
const BYTE_TICKS: u64 = 10 * HZ / GNSS_BAUD as u64;

/// Tick at which byte `i` (from 0) of a burst starting at `start` has been received.
fn byte_arrival(start: u64, i: usize) -> u64 {
    start + (i as u64 + 1) * BYTE_TICKS
}

/// The receiver: its PPS line (read by the sampler) and its NMEA transmitter.
pub struct SimGnss {
    /// Receiver second of the next edge to deliver.
    pps_second: u64,
    /// The next edge is the glitch after `pps_second`'s real edge.
    glitch_next: bool,
    /// GPS seconds of receiver second 0.
    start_gps: u32,
    /// The UTC day of the last burst: GPS seconds at its midnight, and its date.
    day: Option<(u32, UtcDateTime)>,
    /// Receiver second of the burst being sent.
    nmea_second: u64,
    /// The burst of `nmea_second` (empty until its first byte is due).
    burst: heapless::Vec<u8, BURST>,
    /// Bytes of `burst` already on the wire.
    sent: usize,
    wire: Producer<'static, u8>,
}

/// USART1's receive side in the `qemu` build: the real UART (configured as on the board;
/// QEMU gives it no input) and the wire from the simulated receiver.
pub struct SimUart {
    uart: GnssUart,
    wire: Consumer<'static, u8>,
}

/// Connects the simulated receiver to USART1: returns the interrupt's byte source and the
/// receiver (for the sampler). Panics if called twice (the wire is a singleton).
pub fn attach(uart: GnssUart) -> (SimUart, SimGnss) {
    let Some(queue) = cortex_m::singleton!(: Queue<u8, WIRE> = Queue::new()) else {
        panic!("simulated GNSS receiver attached twice");
    };
    let (tx, rx) = queue.split();
    let gnss = SimGnss {
        pps_second: 0,
        glitch_next: false,
        start_gps: START.gps_seconds().unwrap_or_default(),
        day: None,
        nmea_second: 0,
        burst: heapless::Vec::new(),
        sent: 0,
        wire: tx,
    };
    (SimUart { uart, wire: rx }, gnss)
}

impl SimUart {
    /// The USART1 interrupt: the next byte, if any. One byte per interrupt, like the data
    /// register; USART1 stays pending while more wait on the wire.
    pub fn on_interrupt(&mut self, errors: &mut RxErrors) -> Option<u8> {
        let byte = self
            .uart
            .on_interrupt(errors)
            .or_else(|| self.wire.dequeue());
        if self.wire.ready() {
            cortex_m::peripheral::NVIC::pend(Interrupt::USART1);
        }
        byte
    }
}

impl SimGnss {
    /// The next edge on the PPS line (skipping outage seconds): its tick.
    fn pending_edge(&mut self) -> u64 {
        loop {
            let n = self.pps_second;
            if self.glitch_next {
                return edge(n) + GLITCH_DELAY;
            }
            if !(OUTAGE.0..OUTAGE.1).contains(&(n % LAP)) {
                return edge(n);
            }
            self.pps_second += 1;
        }
    }

    /// Moves past the edge [`Self::pending_edge`] returned.
    fn consume_edge(&mut self) {
        if !self.glitch_next && self.pps_second % LAP == GLITCH_SECOND {
            self.glitch_next = true;
        } else {
            self.glitch_next = false;
            self.pps_second += 1;
        }
    }

    /// The PPS capture of the sample period `[period_start, period_start + period_len)`
    /// that just ended: the TIM5 counter value (CCR1) at the edge, which the board's timer
    /// would have latched in its CC1 interrupt. `None` without an edge in that period.
    pub fn capture(&mut self, period_start: u64, period_len: u64) -> Option<u32> {
        loop {
            let at = self.pending_edge();
            if at < period_start {
                // Before the timer started (never after boot): not captured.
                self.consume_edge();
                continue;
            }
            if at >= period_start + period_len {
                return None;
            }
            self.consume_edge();
            return Some((at - period_start) as u32);
        }
    }

    /// Puts the NMEA bytes received by `now` on the wire and pends USART1 when it holds any.
    pub fn transmit(&mut self, now: u64) {
        self.send_until(now);
        // The wire's consumer is USART1's interrupt (priority 3, below the sampler's).
        if !self.wire.is_empty() {
            cortex_m::peripheral::NVIC::pend(Interrupt::USART1);
        }
    }

    fn send_until(&mut self, now: u64) {
        loop {
            let start = nominal(self.nmea_second) + NMEA_DELAY;
            if now < byte_arrival(start, 0) {
                return;
            }
            if self.burst.is_empty() {
                self.build(self.nmea_second);
            }
            while self.sent < self.burst.len() {
                if byte_arrival(start, self.sent) > now {
                    return;
                }
                if self.wire.enqueue(self.burst[self.sent]).is_err() {
                    return; // the wire is full: the rest follows at the next sample
                }
                self.sent += 1;
            }
            self.burst.clear();
            self.sent = 0;
            self.nmea_second += 1;
        }
    }

    /// The ZDA and RMC of receiver second `n` into `burst`.
    fn build(&mut self, n: u64) {
        let gps = self.start_gps.wrapping_add(n as u32);
        // The date from the core's conversion once a day; the time of day in u32 arithmetic
        // (keeps the sample interrupt short in the second that composes the burst).
        let midnight = match self.day {
            Some((m, _)) if gps >= m && gps - m < 86_400 => m,
            _ => {
                let Some(d) = UtcDateTime::from_gps_seconds(gps) else {
                    return;
                };
                let sod = u32::from(d.hour) * 3600 + u32::from(d.minute) * 60 + u32::from(d.second);
                self.day = Some((gps - sod, d));
                gps - sod
            }
        };
        let Some((_, mut t)) = self.day else {
            return;
        };
        let sod = gps - midnight;
        t.hour = (sod / 3600) as u8;
        t.minute = (sod / 60 % 60) as u8;
        t.second = (sod % 60) as u8;
        let mut w = Writer(&mut self.burst);
        // $GPZDA,hhmmss.ss,dd,mm,yyyy,zh,zm*hh
        let zda = w.begin(b"GPZDA,");
        w.time(&t);
        w.byte(b',');
        w.num(u32::from(t.day), 2);
        w.byte(b',');
        w.num(u32::from(t.month), 2);
        w.byte(b',');
        w.num(u32::from(t.year), 4);
        w.bytes(b",00,00");
        w.end(zda);
        // $GPRMC,hhmmss.ss,A,lat,N,lon,E,sog,cog,ddmmyy,magvar,E/W,mode*hh
        let rmc = w.begin(b"GPRMC,");
        w.time(&t);
        w.bytes(b",A,5005.3321,N,01425.4156,E,0.02,0.00,");
        w.num(u32::from(t.day), 2);
        w.num(u32::from(t.month), 2);
        w.num(u32::from(t.year) % 100, 2);
        w.bytes(b",,,A");
        w.end(rmc);
        if n % LAP == CORRUPT_SECOND {
            // A bit error on the line inside the RMC's time field, after the checksum.
            if let Some(b) = self.burst.get_mut(rmc + 8) {
                *b ^= 0x01;
            }
        }
    }
}

/// Appends NMEA text to a burst (no formatting machinery: digits by hand).
struct Writer<'a>(&'a mut heapless::Vec<u8, BURST>);

impl Writer<'_> {
    fn byte(&mut self, b: u8) {
        let _ = self.0.push(b);
    }

    fn bytes(&mut self, s: &[u8]) {
        for &b in s {
            self.byte(b);
        }
    }

    /// `v` in `digits` decimal digits with leading zeros.
    fn num(&mut self, v: u32, digits: u32) {
        for i in (0..digits).rev() {
            self.byte(b'0' + (v / 10u32.pow(i) % 10) as u8);
        }
    }

    /// `hhmmss.00`.
    fn time(&mut self, t: &UtcDateTime) {
        self.num(u32::from(t.hour), 2);
        self.num(u32::from(t.minute), 2);
        self.num(u32::from(t.second), 2);
        self.bytes(b".00");
    }

    /// Starts a sentence (`$` and `head`); returns the index of its `$`.
    fn begin(&mut self, head: &[u8]) -> usize {
        let at = self.0.len();
        self.byte(b'$');
        self.bytes(head);
        at
    }

    /// Ends the sentence that starts at `at`: `*hh` (XOR of the bytes after `$`) and CR LF.
    fn end(&mut self, at: usize) {
        let sum = self
            .0
            .get(at + 1..)
            .unwrap_or(&[])
            .iter()
            .fold(0u8, |a, b| a ^ b);
        const HEX: &[u8; 16] = b"0123456789ABCDEF";
        self.byte(b'*');
        self.byte(HEX[usize::from(sum >> 4)]);
        self.byte(HEX[usize::from(sum & 0xF)]);
        self.bytes(b"\r\n");
    }
}
