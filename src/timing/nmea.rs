//! NMEA 0183 time messages (ZDA and RMC) from the GNSS receiver's transmit line, and the
//! UTC to GPS time mapping.
//!
//! Bytes go into a bounded [`LineBuffer`]; each complete line is parsed by
//! [`parse_sentence`]. The checksum is required and verified. Any talker (`GP`, `GN`, `GL`,
//! `GA`, `BD`, ...) is accepted. Bad input is an [`NmeaError`], never a panic; other
//! sentence types give [`NmeaError::Unsupported`], which the caller ignores.
//!
//! GPS time is ahead of UTC by the leap seconds inserted since 1980-01-06:
//! [`GPS_UTC_LEAP_SECONDS`] = 18 since 2017-01-01 (no further leap second has been
//! announced). It is a constant of the firmware: a future leap second needs a new build.

/// GPS time minus UTC, seconds (valid from 2017-01-01 until the next leap second).
pub const GPS_UTC_LEAP_SECONDS: u32 = 18;
/// Longest line kept, bytes, from `$` to the last checksum digit. NMEA 0183 allows 82
/// characters including `$` and CR LF; some receivers exceed it slightly.
pub const MAX_SENTENCE: usize = 96;
/// Seconds in a GPS week.
pub const SECONDS_PER_WEEK: u32 = 604_800;

/// Days from 1970-01-01 to the GPS epoch 1980-01-06.
const GPS_EPOCH_DAYS: i64 = 3_657;

/// A malformed, unsupported or useless line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmeaError {
    /// The line exceeded [`MAX_SENTENCE`] bytes (it is discarded).
    Overflow,
    /// The line does not start with `$`.
    NoStart,
    /// No `*hh` checksum.
    NoChecksum,
    /// The checksum does not match.
    BadChecksum {
        /// XOR of the bytes between `$` and `*`.
        computed: u8,
        /// The checksum the line carries.
        received: u8,
    },
    /// A sentence other than ZDA or RMC (not an error of the receiver).
    Unsupported,
    /// A field is missing, empty or malformed; names it.
    Field(&'static str),
    /// The date or time is out of range (before the GPS epoch, 31 February...).
    BadDate,
}

/// A UTC date and time as the receiver reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UtcDateTime {
    /// Year, four digits.
    pub year: u16,
    /// Month, 1..=12.
    pub month: u8,
    /// Day of the month, 1..=31.
    pub day: u8,
    /// Hour, 0..=23.
    pub hour: u8,
    /// Minute, 0..=59.
    pub minute: u8,
    /// Second, 0..=60 (60 only in a leap second, at 23:59:60).
    pub second: u8,
    /// Milliseconds of the fractional second (truncated).
    pub millis: u16,
}

/// GPS time of a whole second: week number (not rolled over at 1024) and time of week.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct GpsTime {
    /// Weeks since 1980-01-06.
    pub week: u16,
    /// Seconds into the week, `0..604_800`.
    pub tow: u32,
}

impl GpsTime {
    /// From seconds since the GPS epoch.
    pub fn from_seconds(s: u32) -> Self {
        Self {
            week: (s / SECONDS_PER_WEEK) as u16,
            tow: s % SECONDS_PER_WEEK,
        }
    }

    /// Seconds since the GPS epoch.
    pub fn seconds(&self) -> u32 {
        u32::from(self.week) * SECONDS_PER_WEEK + self.tow
    }
}

/// A time message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeMessage {
    /// `$--ZDA,hhmmss.ss,dd,mm,yyyy,zh,zm*hh`.
    Zda(UtcDateTime),
    /// `$--RMC,hhmmss.ss,A|V,lat,N,lon,E,sog,cog,ddmmyy,...*hh`; `valid` is the status `A`.
    Rmc {
        /// Date and time.
        time: UtcDateTime,
        /// Status field `A` (data valid); `V` gives `false`.
        valid: bool,
    },
}

impl TimeMessage {
    /// The date and time it carries.
    pub fn time(&self) -> UtcDateTime {
        match self {
            Self::Zda(t) | Self::Rmc { time: t, .. } => *t,
        }
    }

    /// True unless an RMC says its data are not valid.
    pub fn valid(&self) -> bool {
        match self {
            Self::Zda(_) => true,
            Self::Rmc { valid, .. } => *valid,
        }
    }
}

/// Collects bytes into lines of at most [`MAX_SENTENCE`] bytes.
#[derive(Debug, Clone)]
pub struct LineBuffer {
    buf: [u8; MAX_SENTENCE],
    len: usize,
    overflow: bool,
    /// Length of the line [`Self::push`] returned last (0 after an overflow).
    done: usize,
}

impl Default for LineBuffer {
    fn default() -> Self {
        Self::new()
    }
}

impl LineBuffer {
    /// An empty buffer.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_SENTENCE],
            len: 0,
            overflow: false,
            done: 0,
        }
    }

    /// The line whose end [`Self::push`] just returned a result for, from `$` to its last
    /// byte before the line ending (empty after an overflow; valid until the next byte).
    pub fn last_line(&self) -> &[u8] {
        &self.buf[..self.done]
    }

    /// Adds one byte; at the end of a non-empty line (LF, or CR) returns what it parsed to.
    /// A `$` always starts a new line, so a receiver that lost a line end resynchronises.
    pub fn push(&mut self, byte: u8) -> Option<Result<TimeMessage, NmeaError>> {
        match byte {
            b'\r' | b'\n' => {
                let done = if self.overflow {
                    self.done = 0;
                    Some(Err(NmeaError::Overflow))
                } else if self.len > 0 {
                    self.done = self.len;
                    Some(parse_sentence(&self.buf[..self.len]))
                } else {
                    None
                };
                self.len = 0;
                self.overflow = false;
                done
            }
            b'$' => {
                self.buf[0] = b'$';
                self.len = 1;
                self.overflow = false;
                None
            }
            _ => {
                if self.len < MAX_SENTENCE {
                    self.buf[self.len] = byte;
                    self.len += 1;
                } else {
                    self.overflow = true;
                }
                None
            }
        }
    }
}

fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

/// Parses the decimal digits of `field` (all of it) as a number.
fn digits(field: &[u8], name: &'static str) -> Result<u32, NmeaError> {
    if field.is_empty() || field.len() > 9 {
        return Err(NmeaError::Field(name));
    }
    field.iter().try_fold(0u32, |acc, b| {
        if b.is_ascii_digit() {
            Ok(acc * 10 + u32::from(b - b'0'))
        } else {
            Err(NmeaError::Field(name))
        }
    })
}

/// `hhmmss` or `hhmmss.f...`: (hour, minute, second, millis).
fn parse_time(field: &[u8]) -> Result<(u8, u8, u8, u16), NmeaError> {
    const NAME: &str = "time";
    let (whole, frac) = match field.iter().position(|b| *b == b'.') {
        Some(dot) => (&field[..dot], &field[dot + 1..]),
        None => (field, &[][..]),
    };
    if whole.len() != 6 {
        return Err(NmeaError::Field(NAME));
    }
    let hour = digits(&whole[0..2], NAME)? as u8;
    let minute = digits(&whole[2..4], NAME)? as u8;
    let second = digits(&whole[4..6], NAME)? as u8;
    let mut millis = 0u16;
    let mut scale = 100u16;
    for b in frac {
        if !b.is_ascii_digit() {
            return Err(NmeaError::Field(NAME));
        }
        millis += u16::from(b - b'0') * scale;
        scale /= 10;
    }
    if !is_time_of_day(hour, minute, second) {
        return Err(NmeaError::BadDate);
    }
    Ok((hour, minute, second, millis))
}

/// A UTC time of day: 00:00:00..=23:59:59, or the leap second 23:59:60 (the only minute
/// that can have 61 seconds).
fn is_time_of_day(hour: u8, minute: u8, second: u8) -> bool {
    hour <= 23 && minute <= 59 && (second <= 59 || (second == 60 && hour == 23 && minute == 59))
}

fn is_leap(year: u32) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

fn days_in_month(year: u32, month: u32) -> u32 {
    match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        2 if is_leap(year) => 29,
        2 => 28,
        _ => 0,
    }
}

fn check_date(year: u32, month: u32, day: u32) -> Result<(), NmeaError> {
    if !(1980..=2200).contains(&year) || !(1..=12).contains(&month) {
        return Err(NmeaError::BadDate);
    }
    if day == 0 || day > days_in_month(year, month) {
        return Err(NmeaError::BadDate);
    }
    Ok(())
}

/// Splits a line into its fields after verifying `$` and the checksum.
fn checked_body(line: &[u8]) -> Result<&[u8], NmeaError> {
    let line = match line {
        [rest @ .., b'\r'] => rest,
        _ => line,
    };
    let Some((b'$', rest)) = line.split_first() else {
        return Err(NmeaError::NoStart);
    };
    let star = rest
        .iter()
        .rposition(|b| *b == b'*')
        .ok_or(NmeaError::NoChecksum)?;
    let (body, sum) = (&rest[..star], &rest[star + 1..]);
    let received = match sum {
        [h, l] => match (hex_digit(*h), hex_digit(*l)) {
            (Some(h), Some(l)) => (h << 4) | l,
            _ => return Err(NmeaError::NoChecksum),
        },
        _ => return Err(NmeaError::NoChecksum),
    };
    let computed = body.iter().fold(0u8, |acc, b| acc ^ b);
    if computed != received {
        return Err(NmeaError::BadChecksum { computed, received });
    }
    Ok(body)
}

/// Parses one line (from `$` to the checksum; a trailing CR is allowed).
pub fn parse_sentence(line: &[u8]) -> Result<TimeMessage, NmeaError> {
    let body = checked_body(line)?;
    let mut fields = body.split(|b| *b == b',');
    let address = fields.next().unwrap_or(&[]);
    if address.is_empty() || !address.iter().all(|b| b.is_ascii_alphanumeric()) {
        return Err(NmeaError::Field("address"));
    }
    if address.len() != 5 {
        return Err(NmeaError::Unsupported); // proprietary ($P...) and the like
    }
    let mut next = |name: &'static str| fields.next().ok_or(NmeaError::Field(name));
    match &address[2..] {
        b"ZDA" => {
            let (hour, minute, second, millis) = parse_time(next("time")?)?;
            let day = digits(next("day")?, "day")?;
            let month = digits(next("month")?, "month")?;
            let year = digits(next("year")?, "year")?;
            check_date(year, month, day)?;
            Ok(TimeMessage::Zda(UtcDateTime {
                year: year as u16,
                month: month as u8,
                day: day as u8,
                hour,
                minute,
                second,
                millis,
            }))
        }
        b"RMC" => {
            let (hour, minute, second, millis) = parse_time(next("time")?)?;
            let valid = match next("status")? {
                b"A" => true,
                b"V" => false,
                _ => return Err(NmeaError::Field("status")),
            };
            for name in ["latitude", "N/S", "longitude", "E/W", "speed", "course"] {
                next(name)?;
            }
            let date = next("date")?;
            if date.len() != 6 {
                return Err(NmeaError::Field("date"));
            }
            let day = digits(&date[0..2], "date")?;
            let month = digits(&date[2..4], "date")?;
            let yy = digits(&date[4..6], "date")?;
            let year = if yy >= 80 { 1900 + yy } else { 2000 + yy };
            check_date(year, month, day)?;
            Ok(TimeMessage::Rmc {
                time: UtcDateTime {
                    year: year as u16,
                    month: month as u8,
                    day: day as u8,
                    hour,
                    minute,
                    second,
                    millis,
                },
                valid,
            })
        }
        _ => Err(NmeaError::Unsupported),
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's `days_from_civil`).
pub fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(month);
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + i64::from(day) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The date of a day count since 1970-01-01: (year, month, day).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

impl UtcDateTime {
    /// GPS seconds since 1980-01-06 of the whole second (the fraction is dropped), with
    /// [`GPS_UTC_LEAP_SECONDS`]. A leap second `:60` maps onto the following second.
    pub fn gps_seconds(&self) -> Result<u32, NmeaError> {
        check_date(
            u32::from(self.year),
            u32::from(self.month),
            u32::from(self.day),
        )?;
        if !is_time_of_day(self.hour, self.minute, self.second) {
            return Err(NmeaError::BadDate);
        }
        let days = days_from_civil(
            i64::from(self.year),
            u32::from(self.month),
            u32::from(self.day),
        ) - GPS_EPOCH_DAYS;
        let sod =
            i64::from(self.hour) * 3600 + i64::from(self.minute) * 60 + i64::from(self.second);
        let s = days * 86_400 + sod + i64::from(GPS_UTC_LEAP_SECONDS);
        u32::try_from(s).map_err(|_| NmeaError::BadDate)
    }

    /// GPS week and time of week of the whole second.
    pub fn gps_time(&self) -> Result<GpsTime, NmeaError> {
        self.gps_seconds().map(GpsTime::from_seconds)
    }

    /// The UTC date and time of a GPS second (inverse of [`Self::gps_seconds`] outside leap
    /// seconds), `millis = 0`. `None` before 1980-01-06 00:00:18 GPS.
    pub fn from_gps_seconds(gps: u32) -> Option<Self> {
        let utc = i64::from(gps.checked_sub(GPS_UTC_LEAP_SECONDS)?);
        let days = utc.div_euclid(86_400) + GPS_EPOCH_DAYS;
        let sod = utc.rem_euclid(86_400);
        let (year, month, day) = civil_from_days(days);
        Some(Self {
            year: year as u16,
            month: month as u8,
            day: day as u8,
            hour: (sod / 3600) as u8,
            minute: (sod / 60 % 60) as u8,
            second: (sod % 60) as u8,
            millis: 0,
        })
    }
}
