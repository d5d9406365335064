//! A u-blox UBX log (a ZED-F9P's `.ubx`, as u-center or a driver records it), in any mix with
//! NMEA sentences and RTCM 3 frames.
//!
//! The stream is split into frames ([`split`]): UBX (`B5 62`, class, id, little-endian
//! length, payload, Fletcher-8 checksum over class to payload), RTCM 3 (`D3`, six zero bits,
//! a 10-bit length, payload, CRC-24Q) and NMEA sentences (`$`...`*hh`, checksum checked);
//! bytes in none of them are counted and skipped. A UBX frame with a bad checksum or cut off
//! is counted as corrupt and the search resumes two bytes after its start. RTCM 3 frames and
//! NMEA sentences are counted by message type and skipped, as are UBX messages not read here
//! (by class and id).
//!
//! Read, with the offsets of the u-blox F9 interface description:
//! * NAV-PVT (0x01 0x07, 92 bytes): iTOW, the UTC date (used when `validDate` and `validTime`
//!   are set, only to find the GPS week), `fixType`, `flags` (`gnssFixOK`, `diffSoln`,
//!   `carrSoln`), longitude, latitude, ellipsoidal height, `hAcc`, `vAcc`, `flags3`
//!   (`invalidLlh`).
//! * NAV-HPPOSLLH (0x01 0x14, 36 bytes): the position to 1e-9 degree and 0.1 mm with `hAcc`
//!   and `vAcc` in 0.1 mm; it replaces NAV-PVT's position of the same iTOW unless its
//!   `invalidLlh` flag is set.
//! * NAV-RELPOSNED (0x01 0x3C, version 1, 64 bytes): `relPosHeading` is the epoch's heading
//!   when `gnssFixOK`, `relPosValid` and `relPosHeadingValid` are set and `isMoving` (a moving
//!   base on the vehicle); with a static base it is the bearing from the base to the rover,
//!   not the vehicle's heading, and is not used (counted). Version 0 (40 bytes) has no heading.
//! * NAV-TIMEGPS (0x01 0x20, 16 bytes): the GPS week, when `weekValid`.
//! * MON-VER (0x0A 0x04): the receiver's software and hardware versions, for the report.
//!
//! An epoch is the messages of one iTOW; it needs a NAV-PVT (fix quality). Its GPS time is
//! week * 604,800 s + iTOW; the week comes from NAV-TIMEGPS, else from NAV-PVT's UTC date
//! (the week whose time of week is iTOW nearest the date's GPS time, so leap seconds do not
//! matter), else from the nearest dated epoch, carried over week rollovers by iTOW. Fix
//! quality follows the receiver's flags, not `fixType` alone: without `gnssFixOK`, with
//! `fixType` other than 2D, 3D or GNSS + dead reckoning, the epoch is "no valid fix"; else
//! `carrSoln` fixed or float is RTK fixed or float, `diffSoln` DGPS, the rest single. The
//! sigmas are `hAcc / sqrt 2` north and east (their root sum of squares is `hAcc`) and `vAcc`
//! up. A log with NAV-RELPOSNED only (positions relative to a base, no absolute position and
//! no GPS date) is refused, naming what is missing.

use anyhow::{bail, Result};

use super::geodetic::Geodetic;
use super::{gps_time, Epoch, FixQuality, GeodeticLog, ReadReport};
use crate::text::excerpt;

/// The two sync bytes of a UBX frame.
pub const SYNC: [u8; 2] = [0xB5, 0x62];

/// The longest UBX payload taken as a frame (bytes); a longer length field is no frame.
pub const MAX_PAYLOAD: usize = 8192;

/// The Fletcher-8 checksum (CK_A, CK_B) of a frame's class, id, length and payload.
pub fn checksum(data: &[u8]) -> [u8; 2] {
    let (mut a, mut b) = (0u8, 0u8);
    for &x in data {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    [a, b]
}

/// A UBX frame of `class`, `id` and `payload`, with sync bytes and checksum.
pub fn frame(class: u8, id: u8, payload: &[u8]) -> Vec<u8> {
    let mut f = SYNC.to_vec();
    f.extend([class, id]);
    f.extend((payload.len() as u16).to_le_bytes());
    f.extend(payload);
    let ck = checksum(&f[2..]);
    f.extend(ck);
    f
}

/// The CRC-24Q of RTCM 3 (polynomial 0x1864CFB, initial 0).
pub fn crc24q(data: &[u8]) -> u32 {
    let mut crc = 0u32;
    for &x in data {
        crc ^= u32::from(x) << 16;
        for _ in 0..8 {
            crc <<= 1;
            if crc & 0x100_0000 != 0 {
                crc ^= 0x186_4CFB;
            }
        }
    }
    crc & 0xFF_FFFF
}

/// One piece of a mixed stream.
#[derive(Debug, Clone, PartialEq)]
pub enum Piece<'a> {
    /// A UBX frame with a valid checksum.
    Ubx {
        /// Class.
        class: u8,
        /// Id.
        id: u8,
        /// Payload.
        payload: &'a [u8],
    },
    /// A UBX frame with a bad checksum, or cut off (why).
    BadUbx(String),
    /// An RTCM 3 frame with a valid CRC-24Q, by message type (0 for an empty payload).
    Rtcm3(u16),
    /// An NMEA sentence with a valid checksum (without its line ending).
    Nmea(&'a str),
    /// Bytes in no frame.
    Stray(usize),
}

/// Splits `bytes` into pieces, each with its byte offset; consecutive stray bytes make one
/// [`Piece::Stray`].
pub fn split(bytes: &[u8]) -> Vec<(usize, Piece<'_>)> {
    let mut out: Vec<(usize, Piece<'_>)> = Vec::new();
    let mut pos = 0;
    while pos < bytes.len() {
        let (piece, len) = piece_at(bytes, pos);
        match (piece, out.last_mut()) {
            (Piece::Stray(n), Some((_, Piece::Stray(m)))) => *m += n,
            (p, _) => out.push((pos, p)),
        }
        pos += len;
    }
    out
}

/// The piece at `pos` and how many bytes it takes.
fn piece_at(bytes: &[u8], pos: usize) -> (Piece<'_>, usize) {
    let rest = &bytes[pos..];
    match rest[0] {
        0xB5 if rest.get(1) == Some(&0x62) => ubx_at(rest),
        0xD3 => rtcm3_at(rest).unwrap_or((Piece::Stray(1), 1)),
        b'$' => nmea_at(rest).unwrap_or((Piece::Stray(1), 1)),
        _ => (Piece::Stray(1), 1),
    }
}

fn ubx_at(rest: &[u8]) -> (Piece<'_>, usize) {
    if rest.len() < 8 {
        return (Piece::BadUbx("frame cut off at the end".into()), rest.len());
    }
    let (class, id) = (rest[2], rest[3]);
    let len = usize::from(u16::from_le_bytes([rest[4], rest[5]]));
    let name = message_name(class, id);
    if len > MAX_PAYLOAD {
        return (
            Piece::BadUbx(format!("{name}: length {len} is no frame's")),
            2,
        );
    }
    let Some(frame) = rest.get(..8 + len) else {
        return (
            Piece::BadUbx(format!(
                "{name}: frame of {len} payload bytes cut off ({} bytes left)",
                rest.len() - 6
            )),
            2,
        );
    };
    let ck = checksum(&frame[2..6 + len]);
    if ck != [frame[6 + len], frame[7 + len]] {
        return (
            Piece::BadUbx(format!(
                "{name}: checksum {:02X} {:02X}, but the frame's is {:02X} {:02X}",
                frame[6 + len],
                frame[7 + len],
                ck[0],
                ck[1]
            )),
            2,
        );
    }
    (
        Piece::Ubx {
            class,
            id,
            payload: &frame[6..6 + len],
        },
        8 + len,
    )
}

fn rtcm3_at(rest: &[u8]) -> Option<(Piece<'_>, usize)> {
    if rest.len() < 6 || rest[1] & 0xFC != 0 {
        return None;
    }
    let len = usize::from(rest[1] & 0x03) << 8 | usize::from(rest[2]);
    let frame = rest.get(..6 + len)?;
    let crc = u32::from(frame[3 + len]) << 16
        | u32::from(frame[4 + len]) << 8
        | u32::from(frame[5 + len]);
    if crc24q(&frame[..3 + len]) != crc {
        return None;
    }
    let kind = if len >= 2 {
        u16::from(frame[3]) << 4 | u16::from(frame[4]) >> 4
    } else {
        0
    };
    Some((Piece::Rtcm3(kind), 6 + len))
}

fn nmea_at(rest: &[u8]) -> Option<(Piece<'_>, usize)> {
    let window = &rest[..rest.len().min(120)];
    let star = window.iter().position(|&b| b == b'*')?;
    let end = star + 3;
    let s = std::str::from_utf8(window.get(..end)?).ok()?;
    if !s.bytes().all(|b| (b' '..=b'~').contains(&b)) {
        return None;
    }
    let sum = u8::from_str_radix(&s[star + 1..], 16).ok()?;
    if s[1..star].bytes().fold(0u8, |a, b| a ^ b) != sum {
        return None;
    }
    let ending = rest[end..]
        .iter()
        .take(2)
        .take_while(|&&b| b == b'\r' || b == b'\n')
        .count();
    Some((Piece::Nmea(s), end + ending))
}

/// `NAV-PVT` for the messages read here, else class name and id (`RXM 0x15`).
pub fn message_name(class: u8, id: u8) -> String {
    match (class, id) {
        (0x01, 0x07) => "NAV-PVT".into(),
        (0x01, 0x14) => "NAV-HPPOSLLH".into(),
        (0x01, 0x3C) => "NAV-RELPOSNED".into(),
        (0x01, 0x20) => "NAV-TIMEGPS".into(),
        (0x0A, 0x04) => "MON-VER".into(),
        _ => {
            let c = match class {
                0x01 => "NAV",
                0x02 => "RXM",
                0x04 => "INF",
                0x05 => "ACK",
                0x06 => "CFG",
                0x09 => "UPD",
                0x0A => "MON",
                0x0D => "TIM",
                0x10 => "ESF",
                0x13 => "MGA",
                0x21 => "LOG",
                0x27 => "SEC",
                0x28 => "HNR",
                _ => return format!("UBX 0x{class:02X} 0x{id:02X}"),
            };
            format!("{c} 0x{id:02X}")
        }
    }
}

/// True when `bytes` hold a checksum-valid NAV-PVT, NAV-HPPOSLLH or NAV-RELPOSNED frame: a
/// UBX log (NMEA sentences in it are then skipped).
pub fn sniff(bytes: &[u8]) -> bool {
    let mut from = 0;
    while let Some(i) = memchr::memmem::find(&bytes[from..], &SYNC) {
        let at = from + i;
        if let (
            Piece::Ubx {
                class: 0x01, id, ..
            },
            _,
        ) = ubx_at(&bytes[at..])
        {
            if matches!(id, 0x07 | 0x14 | 0x3C) {
                return true;
            }
        }
        from = at + 1;
    }
    false
}

fn u16_at(p: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([p[i], p[i + 1]])
}

fn u32_at(p: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}

fn i32_at(p: &[u8], i: usize) -> i32 {
    i32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}

/// NAV-PVT, as read.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pvt {
    /// UTC date and time (days since 1970-01-01, seconds of the day), when valid.
    utc: Option<(i64, f64)>,
    fix: FixQuality,
    /// Position, unless `invalidLlh`.
    position: Option<Geodetic>,
    /// hAcc, vAcc (m).
    acc: [f64; 2],
}

fn pvt(p: &[u8]) -> Pvt {
    let valid = p[11];
    let (year, month, day) = (i64::from(u16_at(p, 4)), u32::from(p[6]), u32::from(p[7]));
    let utc = (valid & 0x03 == 0x03
        && (1..=12).contains(&month)
        && (1..=31).contains(&day)
        && p[8] < 24
        && p[9] < 60
        && p[10] < 61)
        .then(|| {
            let sod = f64::from(p[8]) * 3600.0 + f64::from(p[9]) * 60.0 + f64::from(p[10]);
            let days = odo_unit::timing::nmea::days_from_civil(year, month, day);
            (days, sod + f64::from(i32_at(p, 16)) * 1e-9)
        });
    let (fix_type, flags) = (p[20], p[21]);
    let fix = if flags & 0x01 == 0 || !matches!(fix_type, 2..=4) {
        FixQuality::Invalid
    } else {
        match (flags >> 6) & 0x03 {
            2 => FixQuality::RtkFixed,
            1 => FixQuality::RtkFloat,
            _ if flags & 0x02 != 0 => FixQuality::Dgps,
            _ => FixQuality::Single,
        }
    };
    let invalid_llh = p[78] & 0x01 != 0;
    let position = (!invalid_llh).then(|| Geodetic {
        lat_deg: f64::from(i32_at(p, 28)) * 1e-7,
        lon_deg: f64::from(i32_at(p, 24)) * 1e-7,
        height: f64::from(i32_at(p, 32)) * 1e-3,
    });
    Pvt {
        utc,
        fix,
        position,
        acc: [
            f64::from(u32_at(p, 40)) * 1e-3,
            f64::from(u32_at(p, 44)) * 1e-3,
        ],
    }
}

/// NAV-HPPOSLLH: the position and hAcc, vAcc (m), unless `invalidLlh`.
fn hpposllh(p: &[u8]) -> Option<(Geodetic, [f64; 2])> {
    if p[3] & 0x01 != 0 {
        return None;
    }
    let hp = |i: usize| f64::from(p[i] as i8);
    let position = Geodetic {
        lat_deg: f64::from(i32_at(p, 12)) * 1e-7 + hp(25) * 1e-9,
        lon_deg: f64::from(i32_at(p, 8)) * 1e-7 + hp(24) * 1e-9,
        height: f64::from(i32_at(p, 16)) * 1e-3 + hp(26) * 1e-4,
    };
    let acc = [
        f64::from(u32_at(p, 28)) * 1e-4,
        f64::from(u32_at(p, 32)) * 1e-4,
    ];
    Some((position, acc))
}

/// What NAV-RELPOSNED says about the heading.
#[derive(Debug, Clone, Copy, PartialEq)]
enum RelHeading {
    /// A moving base's valid heading (rad, clockwise from north).
    Vehicle(f64),
    /// A valid heading with a static base: the bearing from the base, not used.
    StaticBase,
    /// Not valid, or version 0 (no heading).
    None,
}

fn relposned(p: &[u8]) -> RelHeading {
    if p[0] != 1 || p.len() != 64 {
        return RelHeading::None;
    }
    let flags = u32_at(p, 60);
    let ok = |bit: u32| flags & (1 << bit) != 0;
    // gnssFixOK, relPosValid, relPosHeadingValid.
    if !(ok(0) && ok(2) && ok(8)) {
        return RelHeading::None;
    }
    if !ok(5) {
        return RelHeading::StaticBase;
    }
    let deg = f64::from(i32_at(p, 24)) * 1e-5;
    RelHeading::Vehicle(crate::stats::wrap_angle(deg.to_radians()))
}

/// The messages of one iTOW.
#[derive(Debug, Clone, Default)]
struct Parts {
    itow: u32,
    /// Byte offset of the NAV-PVT.
    offset: usize,
    pvt: Option<Pvt>,
    hp: Option<(Geodetic, [f64; 2])>,
    heading: Option<f64>,
    /// GPS week from NAV-TIMEGPS.
    week: Option<i64>,
}

/// What the splitter gave, gathered by epoch.
#[derive(Default)]
struct Gathered {
    parts: Vec<Parts>,
    relposned: usize,
    static_base: usize,
    report: ReadReport,
}

impl Gathered {
    /// The parts of `itow` among the last few epochs, or new ones.
    fn at(&mut self, itow: u32) -> &mut Parts {
        let n = self.parts.len();
        let k = (n.saturating_sub(4)..n)
            .rev()
            .find(|&k| self.parts[k].itow == itow);
        let k = k.unwrap_or_else(|| {
            self.parts.push(Parts {
                itow,
                ..Parts::default()
            });
            n
        });
        &mut self.parts[k]
    }

    /// A checksum-valid UBX message at byte `offset`.
    fn ubx(&mut self, file: &str, offset: usize, class: u8, id: u8, p: &[u8]) {
        let name = message_name(class, id);
        let want = match (class, id) {
            (0x01, 0x07) => Some(92),
            (0x01, 0x14) => Some(36),
            (0x01, 0x3C) => Some(if p.first() == Some(&0) { 40 } else { 64 }),
            (0x01, 0x20) => Some(16),
            (0x0A, 0x04) => None,
            _ => {
                self.report.other(&name);
                return;
            }
        };
        if want.is_some_and(|w| p.len() != w) || (class, id) == (0x0A, 0x04) && p.len() < 40 {
            self.report.corrupt(format!(
                "{file}: byte {offset}: {name}: {} payload bytes, not {}",
                p.len(),
                want.unwrap_or(40)
            ));
            return;
        }
        self.report.used(&name);
        match (class, id) {
            (0x01, 0x07) => {
                let parts = self.at(u32_at(p, 0));
                parts.pvt = Some(pvt(p));
                parts.offset = offset;
            }
            (0x01, 0x14) => self.at(u32_at(p, 4)).hp = hpposllh(p),
            (0x01, 0x3C) => {
                self.relposned += 1;
                match relposned(p) {
                    RelHeading::Vehicle(h) => self.at(u32_at(p, 4)).heading = Some(h),
                    RelHeading::StaticBase => self.static_base += 1,
                    RelHeading::None => {}
                }
            }
            (0x01, 0x20) => {
                if p[11] & 0x02 != 0 {
                    self.at(u32_at(p, 0)).week = Some(i64::from(u16_at(p, 8) as i16));
                }
            }
            _ => {
                let text = |b: &[u8]| {
                    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
                    excerpt(&String::from_utf8_lossy(&b[..end]))
                };
                self.report.receiver = Some(format!(
                    "u-blox, software {}, hardware {}",
                    text(&p[..30]),
                    text(&p[30..40])
                ));
            }
        }
    }
}

/// Parses a UBX log; `file` names it in messages. `leap_seconds` (GPS - UTC, s) serves only
/// to find the GPS week from NAV-PVT's UTC date (any value within days gives the same week).
pub fn parse(file: &str, bytes: &[u8], leap_seconds: Option<i32>) -> Result<GeodeticLog> {
    let mut g = Gathered::default();
    for (offset, piece) in split(bytes) {
        match piece {
            Piece::Ubx { class, id, payload } => g.ubx(file, offset, class, id, payload),
            Piece::BadUbx(why) => g.report.corrupt(format!("{file}: byte {offset}: {why}")),
            Piece::Rtcm3(t) => g.report.other(&format!("RTCM3 {t}")),
            Piece::Nmea(s) => {
                let address = s[1..].split(',').next().unwrap_or("");
                g.report.other(&format!("NMEA {address}"));
            }
            Piece::Stray(n) => g.report.skipped_bytes += n,
        }
    }
    if g.static_base > 0 {
        g.report.notes.push(format!(
            "{} NAV-RELPOSNED headings with a static base (isMoving clear) not used: the \
             bearing from the base, not the vehicle's heading",
            g.static_base
        ));
    }
    let has_pvt = g.parts.iter().any(|p| p.pvt.is_some());
    if !has_pvt && g.relposned > 0 {
        bail!(
            "{file}: {} NAV-RELPOSNED but no NAV-PVT: positions relative to a base station, \
             without an absolute position or a GPS date; log NAV-PVT (and NAV-HPPOSLLH) too: {}",
            g.relposned,
            g.report
        );
    }
    let epochs = epochs(file, &g.parts, leap_seconds, &mut g.report);
    if epochs.is_empty() {
        bail!(
            "{file}: no usable position (no NAV-PVT with a position): {}",
            g.report
        );
    }
    Ok(GeodeticLog {
        epochs,
        report: g.report,
    })
}

/// The GPS week of each epoch (see the module doc), `None` where no epoch is dated.
fn weeks(parts: &[Parts], leap_seconds: Option<i32>) -> Vec<Option<i64>> {
    let mut w: Vec<Option<i64>> = parts
        .iter()
        .map(|p| {
            p.week.or_else(|| {
                let (days, sod) = p.pvt?.utc?;
                let leap = gps_time::leap_seconds_for(days, leap_seconds);
                let t = gps_time::utc_to_gps(days, sod, leap).ok()?;
                Some(((t - f64::from(p.itow) * 1e-3) / gps_time::WEEK).round() as i64)
            })
        })
        .collect();
    // Forward, then backward, carrying the week over rollovers by iTOW.
    for k in 1..w.len() {
        if w[k].is_none() {
            w[k] = w[k - 1].map(|x| x + i64::from(parts[k].itow < parts[k - 1].itow));
        }
    }
    for k in (0..w.len().saturating_sub(1)).rev() {
        if w[k].is_none() {
            w[k] = w[k + 1].map(|x| x - i64::from(parts[k].itow > parts[k + 1].itow));
        }
    }
    w
}

/// The epochs with a NAV-PVT, a position and a GPS week, times strictly increasing; the rest
/// counted as unusable.
fn epochs(
    file: &str,
    parts: &[Parts],
    leap_seconds: Option<i32>,
    report: &mut ReadReport,
) -> Vec<Epoch> {
    let weeks = weeks(parts, leap_seconds);
    let mut out: Vec<Epoch> = Vec::new();
    for (p, week) in parts.iter().zip(weeks) {
        let Some(pvt) = p.pvt else {
            report.unusable(format!(
                "{file}: iTOW {} ms: no NAV-PVT (fix quality) for this epoch: skipped",
                p.itow
            ));
            continue;
        };
        let at = p.offset;
        let Some((position, acc)) = p.hp.or(pvt.position.map(|g| (g, pvt.acc))) else {
            report.unusable(format!(
                "{file}: byte {at}: NAV-PVT flags its position invalid (invalidLlh): skipped"
            ));
            continue;
        };
        let Some(week) = week else {
            report.unusable(format!(
                "{file}: byte {at}: no GPS week (no valid date in the log): skipped"
            ));
            continue;
        };
        let position = match position.checked() {
            Ok(g) => g,
            Err(e) => {
                report.unusable(format!("{file}: byte {at}: NAV-PVT position: {e}"));
                continue;
            }
        };
        let gps_time = week as f64 * gps_time::WEEK + f64::from(p.itow) * 1e-3;
        if let Some(last) = out.last() {
            if gps_time <= last.gps_time {
                report.unusable(format!(
                    "{file}: byte {at}: time is not after the previous epoch's: skipped"
                ));
                continue;
            }
        }
        let h = acc[0] / std::f64::consts::SQRT_2;
        out.push(Epoch {
            gps_time,
            position,
            heading: p.heading,
            sigma_north_east_up: Some([h, h, acc[1]]),
            fix: pvt.fix,
            line: at,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// A NAV-PVT payload: 2024-03-15 11:59:42 UTC at iTOW 388,800,100 ms (week 2305), RTK
    /// fixed with `gnssFixOK`, 49.2 N 16.6 E, 300 m, hAcc 14 mm, vAcc 21 mm.
    fn pvt_payload(itow: u32) -> Vec<u8> {
        let mut p = vec![0u8; 92];
        p[0..4].copy_from_slice(&itow.to_le_bytes());
        p[4..6].copy_from_slice(&2024u16.to_le_bytes());
        p[6..11].copy_from_slice(&[3, 15, 11, 59, 42]);
        p[11] = 0x07;
        p[20] = 3;
        p[21] = 0x01 | 0x02 | (2 << 6);
        p[24..28].copy_from_slice(&166_000_000i32.to_le_bytes());
        p[28..32].copy_from_slice(&492_000_000i32.to_le_bytes());
        p[32..36].copy_from_slice(&300_000i32.to_le_bytes());
        p[40..44].copy_from_slice(&14u32.to_le_bytes());
        p[44..48].copy_from_slice(&21u32.to_le_bytes());
        p
    }

    fn relposned_payload(itow: u32, heading_deg: f64, flags: u32) -> Vec<u8> {
        let mut p = vec![0u8; 64];
        p[0] = 1;
        p[4..8].copy_from_slice(&itow.to_le_bytes());
        p[24..28].copy_from_slice(&((heading_deg * 1e5).round() as i32).to_le_bytes());
        p[60..64].copy_from_slice(&flags.to_le_bytes());
        p
    }

    const MOVING_VALID: u32 = 0x01 | 0x04 | 0x20 | 0x100;

    #[test]
    fn checksums_of_independent_frames() {
        // NAV-HPPOSLLH as pyubx2 writes it.
        let f = hex(
            "b5620114240000000000649e2c17b925e5093983531d5b94040018e403000000000082050000ee070000e43d",
        );
        assert_eq!(checksum(&f[2..f.len() - 2]), [0xE4, 0x3D]);
        assert_eq!(frame(0x01, 0x14, &f[6..f.len() - 2]), f);
        // CRC-24Q of the check string "123456789".
        assert_eq!(crc24q(b"123456789"), 0xCDE703);
    }

    #[test]
    fn time_position_and_flags() {
        let itow = 388_800_100;
        let mut log = frame(0x01, 0x07, &pvt_payload(itow));
        log.extend(frame(
            0x01,
            0x3C,
            &relposned_payload(itow, 270.5, MOVING_VALID),
        ));
        let l = parse("a.ubx", &log, None).unwrap();
        let e = &l.epochs[0];
        assert_eq!(e.gps_time, 2305.0 * gps_time::WEEK + 388_800.1);
        assert!((e.position.lat_deg - 49.2).abs() < 1e-12);
        assert!((e.position.lon_deg - 16.6).abs() < 1e-12);
        assert_eq!(e.position.height, 300.0);
        assert_eq!(e.fix, FixQuality::RtkFixed);
        assert!((e.heading.unwrap() + 89.5f64.to_radians()).abs() < 1e-9);
        assert_eq!(e.line, 0);
        // Fix quality by the flags: (fixType, flags) -> quality.
        let table = [
            (3, 0x01 | (2 << 6), FixQuality::RtkFixed),
            (4, 0x01 | (1 << 6), FixQuality::RtkFloat),
            (3, 0x01 | 0x02, FixQuality::Dgps),
            (2, 0x01, FixQuality::Single),
            (3, 2 << 6, FixQuality::Invalid),
            (1, 0x01, FixQuality::Invalid),
            (5, 0x01, FixQuality::Invalid),
            (0, 0x01, FixQuality::Invalid),
        ];
        for (fix_type, flags, q) in table {
            let mut p = pvt_payload(itow);
            p[20] = fix_type;
            p[21] = flags;
            assert_eq!(pvt(&p).fix, q, "{fix_type} {flags:#x}");
        }
        // Heading flags: a static base's bearing and invalid headings are not used.
        for (flags, want) in [
            (MOVING_VALID, RelHeading::Vehicle(0.5f64.to_radians())),
            (MOVING_VALID & !0x20, RelHeading::StaticBase),
            (MOVING_VALID & !0x100, RelHeading::None),
            (MOVING_VALID & !0x04, RelHeading::None),
            (MOVING_VALID & !0x01, RelHeading::None),
        ] {
            let h = relposned(&relposned_payload(itow, 0.5, flags));
            match (h, want) {
                (RelHeading::Vehicle(a), RelHeading::Vehicle(b)) => assert!((a - b).abs() < 1e-12),
                _ => assert_eq!(h, want, "{flags:#x}"),
            }
        }
    }

    #[test]
    fn bad_frames_are_counted_and_the_rest_read() {
        let good = frame(0x01, 0x07, &pvt_payload(388_800_100));
        let next = frame(0x01, 0x07, &pvt_payload(388_800_200));
        let mut bad = good.clone();
        bad[20] ^= 0x01;
        let mut rtcm_bad = vec![0xD3, 0x00, 0x02, 0x3E, 0xD0, 0, 0, 0];
        let rtcm_good = {
            let mut f = vec![0xD3, 0x00, 0x02, 0x3E, 0xD0];
            let c = crc24q(&f);
            f.extend([(c >> 16) as u8, (c >> 8) as u8, c as u8]);
            f
        };
        rtcm_bad[5] = 1;
        let mut log = Vec::new();
        log.extend(b"junk");
        log.extend(&bad); // checksum
        log.extend(&good);
        log.extend(frame(0x02, 0x15, &[0; 16])); // RXM-RAWX: other
        log.extend(frame(0x77, 0x01, &[])); // unknown class: other
        log.extend(frame(0x01, 0x07, &[0; 40])); // NAV-PVT of a wrong length
        log.extend(&rtcm_good);
        log.extend(&rtcm_bad); // bad CRC: stray bytes
        log.extend(b"$GPZDA,120000.00,15,03,2024,00,00*6F\r\n");
        log.extend(&next);
        log.extend(&next[..30]); // cut off at the end
        let l = parse("m.ubx", &log, None).unwrap();
        assert_eq!(l.epochs.len(), 2, "{}", l.report);
        let r = &l.report;
        assert_eq!(r.corrupt, 3, "{r}");
        assert_eq!(r.other["RXM 0x15"], 1);
        assert_eq!(r.other["UBX 0x77 0x01"], 1);
        assert_eq!(r.other["RTCM3 1005"], 1);
        assert_eq!(r.used["NAV-PVT"], 2);
        assert!(
            r.problems[0].starts_with("m.ubx: byte 4: NAV-PVT: checksum"),
            "{r}"
        );
        assert!(
            r.problems[1].contains("NAV-PVT: 40 payload bytes, not 92"),
            "{r}"
        );
        assert!(r.problems[2].contains("cut off"), "{r}");
        assert!(r.skipped_bytes >= 4 + bad.len() - 2 + rtcm_bad.len(), "{r}");
        assert!(sniff(&log) && !sniff(&bad) && !sniff(b"$GPGGA,1*00"));
    }

    #[test]
    fn relposned_alone_or_undated_is_refused_with_what_is_missing() {
        let log = frame(0x01, 0x3C, &relposned_payload(1000, 10.0, MOVING_VALID));
        let e = parse("r.ubx", &log, None).unwrap_err().to_string();
        assert!(
            e.starts_with("r.ubx: 1 NAV-RELPOSNED but no NAV-PVT")
                && e.contains("without an absolute position or a GPS date"),
            "{e}"
        );
        let mut p = pvt_payload(1000);
        p[11] = 0; // no valid date
        let e = parse("u.ubx", &frame(0x01, 0x07, &p), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("u.ubx: byte 0: no GPS week"), "{e}");
        // NAV-TIMEGPS gives the week instead.
        let mut t = vec![0u8; 16];
        t[0..4].copy_from_slice(&1000u32.to_le_bytes());
        t[8..10].copy_from_slice(&2300u16.to_le_bytes());
        t[11] = 0x03;
        let mut log = frame(0x01, 0x20, &t);
        log.extend(frame(0x01, 0x07, &p));
        let l = parse("w.ubx", &log, None).unwrap();
        assert_eq!(l.epochs[0].gps_time, 2300.0 * gps_time::WEEK + 1.0);
    }

    #[test]
    fn high_precision_position_and_receiver_name() {
        let itow: u32 = 388_800_100;
        let mut hp = vec![0u8; 36];
        hp[4..8].copy_from_slice(&itow.to_le_bytes());
        hp[8..12].copy_from_slice(&166_000_000i32.to_le_bytes());
        hp[12..16].copy_from_slice(&492_000_000i32.to_le_bytes());
        hp[16..20].copy_from_slice(&300_000i32.to_le_bytes());
        hp[24] = (-5i8) as u8;
        hp[25] = 7;
        hp[26] = 9;
        hp[28..32].copy_from_slice(&85u32.to_le_bytes());
        hp[32..36].copy_from_slice(&120u32.to_le_bytes());
        let mut ver = b"EXT CORE 1.00 (3fda8e)".to_vec();
        ver.resize(30, 0);
        ver.extend(b"00190000\0\0");
        let mut log = frame(0x0A, 0x04, &ver);
        log.extend(frame(0x01, 0x07, &pvt_payload(itow)));
        log.extend(frame(0x01, 0x14, &hp));
        let l = parse("h.ubx", &log, None).unwrap();
        let e = &l.epochs[0];
        assert!((e.position.lat_deg - (49.2 + 7e-9)).abs() < 1e-13);
        assert!((e.position.lon_deg - (16.6 - 5e-9)).abs() < 1e-13);
        assert!((e.position.height - 300.0009).abs() < 1e-9);
        let s = e.sigma_north_east_up.unwrap();
        assert!((s[0].hypot(s[1]) - 0.0085).abs() < 1e-12 && (s[2] - 0.012).abs() < 1e-12);
        assert_eq!(
            l.report.receiver.as_deref(),
            Some("u-blox, software EXT CORE 1.00 (3fda8e), hardware 00190000")
        );
        // Flagged invalid: NAV-PVT's position and accuracies stay.
        hp[3] = 1;
        let mut log = frame(0x01, 0x07, &pvt_payload(itow));
        log.extend(frame(0x01, 0x14, &hp));
        let e = parse("h.ubx", &log, None).unwrap().epochs[0];
        assert_eq!(e.position.height, 300.0);
    }
}
