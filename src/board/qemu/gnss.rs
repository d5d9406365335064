//! The simulated GNSS receiver of the `qemu` build: QEMU 7.2 models no timer input capture
//! and nothing on USART1's receive line, so the 1-PPS captures and the NMEA bytes come from
//! this deterministic receiver instead. It enters the firmware where the hardware would:
//!
//! - **PPS**: [`SimGnss::capture`] gives the TIM5 counter value (CCR1) at which an edge would
//!   have been captured in the sample period that just ended; the sampler
//!   (`src/board/sampler.rs`) treats it exactly as the CC1 interrupt the board takes at the
//!   edge, before the update event (`resolve_capture`, then `Discipline::on_pps`).
//! - **NMEA**: [`SimGnss::transmit`] puts the bytes that have "arrived" by the current sample
//!   instant (10 bits each at the `gnss_baud` setting) on a byte wire and pends USART1; the
//!   USART1 interrupt task reads them through [`SimUart`], one byte per interrupt as from the
//!   data register, and feeds the firmware's NMEA byte queue as on the board.
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
//! Epoch `e` ([`EPOCH_HZ`] = 10 a second; `e = n * EPOCH_HZ + k`) is GNSS time `n + k / 10`
//! s, at tick `FIRST_EDGE + n * SECOND_TICKS + k * SECOND_TICKS / 10`. [`NMEA_DELAY`] = 100
//! ms after it the receiver sends (back to back when the line is still busy): `$GPZDA` (at
//! `k = 0` only), `$GPRMC` (status `A`), `$GPGGA` (fix quality 4), `$GPGST` and `$GPHDT`,
//! naming the epoch. The whole-second ZDA and RMC name second `n` (the `time_tag_pps =
//! previous` convention). The position is the simulated drive's true pose at the epoch
//! ([`super::drive::Truth`]: the antenna at the axle centre, the true geometry there) around
//! the origin [`ORIGIN_LAT`], [`ORIGIN_LON`] ([`RADIUS_NORTH`], [`RADIUS_EAST`]), plus a
//! deterministic noise of [`SIGMA_HORIZONTAL_MM`], [`SIGMA_VERTICAL_MM`] and
//! [`SIGMA_HEADING_CDEG`] (the sigmas GST reports). docs/HARDWARE.md gives the exact
//! conversion, for hosts that check a calibration against the truth.
//!
//! The script repeats every [`LAP`] = 20 receiver seconds (`n % 20`):
//!
//! | lap second | what happens |
//! |---|---|
//! | 5 | the RMC of epoch `k = 0` has one bit flipped on the line (wrong checksum: `nmea_errors`, `gnss_bad_checksum`) |
//! | 8 | a second, spurious edge 300 ms after the real one (a glitch: `pps_glitches`) |
//! | 12, 13, 14 | no PPS edge (a 3 s outage: holdover, then reacquisition at 15); NMEA goes on |
//!
//! Edges are at least 300 ms apart, so no sample period holds two (the board would take a
//! CC1 interrupt for each; this model delivers at most one per period).

use heapless::spsc::{Consumer, Producer, Queue};
use odo_unit::timing::UtcDateTime;
use stm32f4xx_hal::pac::Interrupt;

use super::drive::{TruePose, Truth};
use crate::board::serial::{GnssUart, RxErrors};

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
/// Start of an epoch's NMEA bytes after its nominal instant, ticks.
pub const NMEA_DELAY: u64 = 100_000_000;
/// Position epochs per receiver second (1, 2, 5, 10 or 20): RMC, GGA, GST and HDT each.
pub const EPOCH_HZ: u64 = 10;
/// Latitude of the local origin (x = y = 0), 50 deg 05.3321 min N, in 1e-7 minutes.
pub const ORIGIN_LAT: i64 = 30_053_321_000;
/// Longitude of the local origin, 14 deg 25.4156 min E, in 1e-7 minutes.
pub const ORIGIN_LON: i64 = 8_654_156_000;
/// Height of the antenna above mean sea level at the origin (GGA altitude), millimetres.
pub const ORIGIN_ALT_MM: i64 = 300_000;
/// WGS84 meridian radius of curvature at the origin's latitude, metres.
pub const RADIUS_NORTH: f64 = 6_373_054.036;
/// WGS84 prime-vertical radius of curvature times cos(latitude) at the origin, metres.
pub const RADIUS_EAST: f64 = 4_100_286.957;
/// Standard deviation of the position noise, east and north, millimetres.
pub const SIGMA_HORIZONTAL_MM: f64 = 5.0;
/// Standard deviation of the height noise, millimetres.
pub const SIGMA_VERTICAL_MM: f64 = 10.0;
/// Standard deviation of the heading noise (HDT), centidegrees.
pub const SIGMA_HEADING_CDEG: f64 = 10.0;

/// Bytes the wire (the receiver's UART to USART1) holds between two sample interrupts: at
/// 38,400 baud and 50 Hz about 77 arrive per sample period; more wait in the receiver.
const WIRE: usize = 256;
/// The sentences of one epoch (ZDA, RMC, GGA, GST, HDT: about 290 bytes).
const BURST: usize = 384;

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

/// Nominal instant of epoch `e` (epoch `n * EPOCH_HZ + k` is receiver second `n` plus
/// `k / EPOCH_HZ` s), ticks.
fn epoch_tick(e: u64) -> u64 {
    nominal(e / EPOCH_HZ) + e % EPOCH_HZ * SECOND_TICKS / EPOCH_HZ
}

/// A standard normal deviate, approximately (the sum of 12 uniform deviates minus 6), a
/// fixed function of `seed` (splitmix64).
fn gauss(seed: u64) -> f64 {
    let mut sum = 0.0;
    for i in 0..3u64 {
        let mut x = seed
            .wrapping_mul(3)
            .wrapping_add(i)
            .wrapping_add(0x9E37_79B9_7F4A_7C15);
        x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        x ^= x >> 31;
        for j in 0..4 {
            sum += ((x >> (16 * j)) & 0xFFFF) as f64 / 65_536.0;
        }
    }
    sum - 6.0
}

/// `v` rounded to the nearest integer.
fn round(v: f64) -> i64 {
    (if v >= 0.0 { v + 0.5 } else { v - 0.5 }) as i64
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
    /// Epoch of the burst being sent.
    epoch: u64,
    /// The burst of `epoch` (empty until its first byte is due).
    burst: heapless::Vec<u8, BURST>,
    /// Tick the burst's first byte started on the line.
    burst_start: u64,
    /// Tick the line is free after the last burst.
    line_free: u64,
    /// Bytes of `burst` already on the wire.
    sent: usize,
    /// One byte on the line (start, 8 data and stop bits) at `gnss_baud`, ticks.
    byte_ticks: u64,
    /// The simulated chassis's true pose.
    truth: Truth,
    wire: Producer<'static, u8>,
}

/// USART1's receive side in the `qemu` build: the real UART (configured as on the board;
/// QEMU gives it no input) and the wire from the simulated receiver.
pub struct SimUart {
    uart: GnssUart,
    wire: Consumer<'static, u8>,
}

/// Connects the simulated receiver, sending at `baud`, to USART1: returns the interrupt's
/// byte source and the receiver (for the sampler). Panics if called twice (the wire is a
/// singleton).
pub fn attach(uart: GnssUart, baud: u32) -> (SimUart, SimGnss) {
    let Some(queue) = cortex_m::singleton!(: Queue<u8, WIRE> = Queue::new()) else {
        panic!("simulated GNSS receiver attached twice");
    };
    let (tx, rx) = queue.split();
    let gnss = SimGnss {
        pps_second: 0,
        glitch_next: false,
        start_gps: START.gps_seconds().unwrap_or_default(),
        day: None,
        epoch: 0,
        burst: heapless::Vec::new(),
        burst_start: 0,
        line_free: 0,
        sent: 0,
        byte_ticks: 10 * HZ / u64::from(baud.max(1)),
        truth: Truth::new(),
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

    /// Tick at which byte `i` (from 0) of the burst being sent has been received.
    fn byte_arrival(&self, i: usize) -> u64 {
        self.burst_start + (i as u64 + 1) * self.byte_ticks
    }

    fn send_until(&mut self, now: u64) {
        loop {
            if self.burst.is_empty() {
                // Back to back when the line is slower than the epochs.
                let start = (epoch_tick(self.epoch) + NMEA_DELAY).max(self.line_free);
                if now < start + self.byte_ticks {
                    return;
                }
                self.burst_start = start;
                self.build(self.epoch);
            }
            while self.sent < self.burst.len() {
                if self.byte_arrival(self.sent) > now {
                    return;
                }
                if self.wire.enqueue(self.burst[self.sent]).is_err() {
                    return; // the wire is full: the rest follows at the next sample
                }
                self.sent += 1;
            }
            self.line_free = self.burst_start + self.burst.len() as u64 * self.byte_ticks;
            self.burst.clear();
            self.sent = 0;
            self.epoch += 1;
        }
    }

    /// The UTC date and time of receiver second `n` (the date from the core's conversion
    /// once a day; the time of day in u32 arithmetic, which keeps the sample interrupt short).
    fn utc(&mut self, n: u64) -> Option<UtcDateTime> {
        let gps = self.start_gps.wrapping_add(n as u32);
        let midnight = match self.day {
            Some((m, _)) if gps >= m && gps - m < 86_400 => m,
            _ => {
                let d = UtcDateTime::from_gps_seconds(gps)?;
                let sod = u32::from(d.hour) * 3600 + u32::from(d.minute) * 60 + u32::from(d.second);
                self.day = Some((gps - sod, d));
                gps - sod
            }
        };
        let (_, mut t) = self.day?;
        let sod = gps - midnight;
        t.hour = (sod / 3600) as u8;
        t.minute = (sod / 60 % 60) as u8;
        t.second = (sod % 60) as u8;
        Some(t)
    }

    /// The sentences of epoch `e` into `burst`: ZDA (whole seconds only), RMC, GGA, GST and
    /// HDT, the position from the true pose at the epoch's instant plus noise.
    fn build(&mut self, e: u64) {
        let (n, k) = (e / EPOCH_HZ, e % EPOCH_HZ);
        let Some(t) = self.utc(n) else {
            return;
        };
        let centis = (k * 100 / EPOCH_HZ) as u32;
        let pose = self.truth.pose_at(epoch_tick(e) as i64);
        let fix = Fix::of(&pose, e);
        let mut w = Writer(&mut self.burst);
        if k == 0 {
            // $GPZDA,hhmmss.ss,dd,mm,yyyy,zh,zm*hh
            let zda = w.begin(b"GPZDA,");
            w.time(&t, centis);
            w.byte(b',');
            w.num(u32::from(t.day), 2);
            w.byte(b',');
            w.num(u32::from(t.month), 2);
            w.byte(b',');
            w.num(u32::from(t.year), 4);
            w.bytes(b",00,00");
            w.end(zda);
        }
        // $GPRMC,hhmmss.ss,A,lat,N,lon,E,sog,cog,ddmmyy,magvar,E/W,mode*hh
        let rmc = w.begin(b"GPRMC,");
        w.time(&t, centis);
        w.bytes(b",A,");
        w.lat_lon(&fix);
        w.bytes(b",0.02,0.00,");
        w.num(u32::from(t.day), 2);
        w.num(u32::from(t.month), 2);
        w.num(u32::from(t.year) % 100, 2);
        w.bytes(b",,,A");
        w.end(rmc);
        // $GPGGA,time,lat,N,lon,E,quality 4 (RTK fixed),satellites,HDOP,alt,M,sep,M,age,station*hh
        let gga = w.begin(b"GPGGA,");
        w.time(&t, centis);
        w.byte(b',');
        w.lat_lon(&fix);
        w.bytes(b",4,12,0.7,");
        w.num((fix.alt_mm / 1000) as u32, 3);
        w.byte(b'.');
        w.num((fix.alt_mm % 1000) as u32, 3);
        w.bytes(b",M,45.000,M,1.0,0001");
        w.end(gga);
        // $GPGST,time,rms,major,minor,orientation,sd lat,sd lon,sd alt*hh (metres)
        let gst = w.begin(b"GPGST,");
        w.time(&t, centis);
        w.bytes(b",0.007,0.005,0.005,0.0,0.005,0.005,0.010");
        w.end(gst);
        // $GPHDT,heading,T*hh (degrees true)
        let hdt = w.begin(b"GPHDT,");
        w.num(fix.heading_cdeg / 100, 3);
        w.byte(b'.');
        w.num(fix.heading_cdeg % 100, 2);
        w.bytes(b",T");
        w.end(hdt);
        if n % LAP == CORRUPT_SECOND && k == 0 {
            // A bit error on the line inside the RMC's time field, after the checksum.
            if let Some(b) = self.burst.get_mut(rmc + 8) {
                *b ^= 0x01;
            }
        }
    }
}

/// What one epoch reports: the true pose plus noise, in the sentences' units.
struct Fix {
    /// Latitude, 1e-7 minutes.
    lat: u64,
    /// Longitude, 1e-7 minutes.
    lon: u64,
    /// Altitude above mean sea level, millimetres.
    alt_mm: u64,
    /// Heading, centidegrees, 0..36000.
    heading_cdeg: u32,
}

impl Fix {
    /// The antenna (at the axle centre) of `pose` at epoch `e`, with the epoch's noise.
    fn of(pose: &TruePose, e: u64) -> Self {
        use core::f64::consts::PI;
        // 1e-7 minutes per radian of latitude or longitude.
        const UNITS_PER_RAD: f64 = 180.0 / PI * 60.0 * 1e7;
        let east = pose.x + gauss(4 * e) * SIGMA_HORIZONTAL_MM * 1e-3;
        let north = pose.y + gauss(4 * e + 1) * SIGMA_HORIZONTAL_MM * 1e-3;
        let up_mm = gauss(4 * e + 2) * SIGMA_VERTICAL_MM;
        let cdeg = pose.heading * 18_000.0 / PI + gauss(4 * e + 3) * SIGMA_HEADING_CDEG;
        Self {
            lat: (ORIGIN_LAT + round(north / RADIUS_NORTH * UNITS_PER_RAD)) as u64,
            lon: (ORIGIN_LON + round(east / RADIUS_EAST * UNITS_PER_RAD)) as u64,
            alt_mm: (ORIGIN_ALT_MM + round(up_mm)) as u64,
            heading_cdeg: round(cdeg).rem_euclid(36_000) as u32,
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

    /// `hhmmss.cc`.
    fn time(&mut self, t: &UtcDateTime, centis: u32) {
        self.num(u32::from(t.hour), 2);
        self.num(u32::from(t.minute), 2);
        self.num(u32::from(t.second), 2);
        self.byte(b'.');
        self.num(centis, 2);
    }

    /// `ddmm.mmmmmmm,N,dddmm.mmmmmmm,E` of `fix`.
    fn lat_lon(&mut self, fix: &Fix) {
        for (units, deg_digits, hemisphere) in [(fix.lat, 2, b",N,"), (fix.lon, 3, b",E\0")] {
            let (deg, rest) = (units / 600_000_000, units % 600_000_000);
            self.num(deg as u32, deg_digits);
            self.num((rest / 10_000_000) as u32, 2);
            self.byte(b'.');
            self.num((rest % 10_000_000) as u32, 7);
            let n = if hemisphere[2] == 0 { 2 } else { 3 };
            self.bytes(&hemisphere[..n]);
        }
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
