//! The unit's settings: chassis parameters plus sampling and output options, with access by
//! key name (the names shared by commands, files and the host tool), validation, a versioned
//! checksummed binary form, and the power-cut-safe flash store ([`store`]).
//!
//! - [`keys`]: the key table, each key declared once (name, unit, range, default, place in
//!   [`Settings`], text form, record encoding); everything below derives from it.
//! - [`record`]: the serialised settings (flash record payload, checksum).
//! - [`store`]: the flash store.

pub mod keys;
pub mod record;
pub mod store;

use crate::bytes::Text;
use crate::crc::crc32;
use crate::decimal::{self, Dec, DecimalError, Shortest};
use crate::odometry::integrator::MAX_STEP_COUNTS;
use crate::odometry::{
    ChassisParams, GeometryUncertainty, ParamError, UncertaintyModel, WheelHarmonics,
};
use crate::timing::{SyncMode, TimeTagPps};
use core::fmt::{self, Write};

pub use keys::{Choice, Group, Key, KeyInfo, Kind, RecordField, Value, KEY_TABLE};
pub use record::{serialized_len, SETTINGS_FORMAT_VERSION};
pub use store::SettingsSource;

/// Baud rates accepted by `baud` and `gnss_baud`.
pub const BAUD_RATES: [u32; 8] = [
    9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];

/// Bits on the wire of one pose record frame (114 bytes, 10 bits per byte with start and
/// stop bit), used to check that the output rate fits the baud rate.
pub const POSE_FRAME_BITS: u32 = 1140;

/// Bits on the wire of the longest `ODOMETRY` frame (245 bytes with MAVLink 2 framing, and
/// the `0x00` after it: 246 bytes, 10 bits per byte), used to check that the output rate
/// fits the baud rate in `output = mavlink`.
pub const MAVLINK_FRAME_BITS: u32 = 2460;

/// Bits on the wire of the `HEARTBEAT` frame sent once a second (21 bytes and the `0x00`).
pub const MAVLINK_HEARTBEAT_BITS: u32 = 220;

/// Bits on the wire of the Status frame sent once a second in `output = frames` (92-byte
/// body: 106 bytes encoded with its delimiter, 10 bits per byte).
pub const STATUS_FRAME_BITS: u32 = 1060;

/// Text bytes assumed per forwarded GNSS sentence in the bandwidth budget: NMEA 0183's
/// longest sentence (82 characters with `$` and CR LF: 80 forwarded).
pub const GNSS_SENTENCE_BYTES: u32 = 80;

/// Forwarded sentences per GNSS epoch in the budget: GGA, GST, RMC and HDT.
pub const GNSS_SENTENCES_PER_EPOCH: u32 = 4;

/// GNSS epochs per second in the budget (a 10 Hz receiver).
pub const GNSS_EPOCHS_PER_S: u32 = 10;

/// Bits per second on the wire of the forwarded GNSS sentences the budget assumes:
/// [`GNSS_EPOCHS_PER_S`] epochs of [`GNSS_SENTENCES_PER_EPOCH`] GnssSentence frames of
/// [`GNSS_SENTENCE_BYTES`] text each (16-byte fixed part, 12 bytes of header and CRC, one
/// COBS code byte, the delimiter: 110 bytes a frame, 440 an epoch): 44,000 bit/s.
pub const GNSS_FORWARD_BITS: u32 =
    GNSS_EPOCHS_PER_S * GNSS_SENTENCES_PER_EPOCH * (GNSS_SENTENCE_BYTES + 30) * 10;

/// What the host link streams (`output`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Output {
    /// Our frames: pose records and Status (docs/PROTOCOL.md).
    #[default]
    Frames,
    /// MAVLink 2: `ODOMETRY` per record, `HEARTBEAT` per second (docs/MAVLINK.md).
    Mavlink,
}

/// Highest accepted `rate`, Hz: what the processing task sustains with a wide margin.
///
/// Derivation, from the instruction counts in docs/RESULTS.md (`bench/run`, Instructions on the
/// Cortex-M4F: release code under QEMU) and the firmware's own `process_max` in `status`:
///
/// * a typical sample costs the processing task about 9,400 instructions in the release
///   build (`opt-level = "z"`: timing, flags, index, odometry and uncertainty, the record's
///   f64 fields, the 114-byte frame, queueing); the per-angle wheel model adds up to about
///   1,450 in its worst case: about **10,900 instructions** per sample;
/// * the worst sample (`process_max`: the first one, which builds the integrator, and the
///   ones that log a state change or send the once-a-second Status) costs about
///   **31,100 instructions**;
/// * at 84 MHz the flash needs 2 wait states; the ART accelerator hides most of them, but
///   counted at **2 cycles per instruction** (no cache hits at all) a typical sample takes
///   21,800 cycles (260 us) and the worst 62,200 cycles (740 us).
///
/// At 1,000 Hz this is 999 x 21,800 + 62,200 = 21.8 million cycles per second, **26 % of the
/// CPU** without a single cache hit (the ART accelerator's hits bring the cycles per
/// instruction towards 1, and the share towards half that), which leaves the rest to the
/// sample interrupt, the UART interrupts and the command task; even the worst sample ends
/// well within one 1 ms sample period, so the sample queue never fills in steady state.
/// 1,000 also divides 1,000,000, so it is accepted in `pps` mode. Above it the margin would
/// be spent on a cost that has not been measured on a board.
pub const MAX_RATE_HZ: u32 = 1_000;

/// Most counts the 16-bit right encoder counter (TIM3) may advance between two reads and
/// still be extended without ambiguity: half its range, 2^15 - 1 = 32,767 increments. One
/// more and a turn forward cannot be told from a turn backward (the count aliases).
/// The left encoder's 32-bit counter (TIM2) allows 2^31 - 1.
pub const COUNTER16_MAX_UNREAD: u64 = (1 << 15) - 1;

/// Most increments one wheel may make between two samples, by design: the smaller of
/// [`COUNTER16_MAX_UNREAD`] (aliasing of the right counter) and the integrator's per-sample
/// limit [`MAX_STEP_COUNTS`] (2^18; a larger step is refused as a fault). 32,767.
pub const MAX_COUNTS_PER_SAMPLE: u64 = if COUNTER16_MAX_UNREAD < MAX_STEP_COUNTS {
    COUNTER16_MAX_UNREAD
} else {
    MAX_STEP_COUNTS
};

/// Increments per second of a wheel of `diameter` (m) with `ticks_per_rev` increments per
/// turn whose surface moves at `wheel_speed` (m/s): `wheel_speed * ticks_per_rev /
/// (pi * diameter)`, increments/s. A non-positive or NaN diameter gives infinity or NaN.
pub fn counts_per_second(wheel_speed: f64, ticks_per_rev: u32, diameter: f64) -> f64 {
    wheel_speed * f64::from(ticks_per_rev) / (core::f64::consts::PI * diameter)
}

/// Most increments a wheel can make between two samples at `rate_hz` when its surface moves
/// at most at `max_wheel_speed` (m/s): [`counts_per_second`] / `rate_hz`, increments (not
/// rounded). Pass the smaller wheel diameter (m) to bound both wheels. The settings refuse
/// any combination where this exceeds [`MAX_COUNTS_PER_SAMPLE`]; `rate_hz = 0` gives
/// infinity.
///
/// The paper's chassis (0.26 m wheels, 20,000 increments per turn) at 2 m/s and 1 Hz:
/// 48,971 increments, refused; at 2 Hz 24,485, accepted.
pub fn max_counts_per_sample(
    max_wheel_speed: f64,
    ticks_per_rev: u32,
    diameter: f64,
    rate_hz: u32,
) -> f64 {
    counts_per_second(max_wheel_speed, ticks_per_rev, diameter) / f64::from(rate_hz)
}

/// Longest time, seconds, the encoder counters can go unread (no sample taken, for example
/// while a flash erase stalls the CPU) without the 16-bit right counter aliasing or a step
/// exceeding the integrator's limit, with the wheels at most at `max_wheel_speed` (m/s):
/// [`MAX_COUNTS_PER_SAMPLE`] / [`counts_per_second`], with the smaller wheel `diameter` (m).
///
/// Infinity when `max_wheel_speed` is 0 (nothing moves); 0 when the arguments give no
/// positive count rate otherwise (negative or NaN), so that a caller comparing a stall
/// against it refuses. The paper's chassis at 2 m/s: 0.669 s.
pub fn max_unread_interval(max_wheel_speed: f64, ticks_per_rev: u32, diameter: f64) -> f64 {
    let cps = counts_per_second(max_wheel_speed, ticks_per_rev, diameter);
    if cps == 0.0 {
        f64::INFINITY
    } else if cps > 0.0 {
        MAX_COUNTS_PER_SAMPLE as f64 / cps
    } else {
        0.0
    }
}

/// Everything the unit keeps across resets. Each field is one or more keys of the key table
/// ([`keys`]), which also gives [`Settings::DEFAULT`], [`Settings::get`] and the record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Chassis and encoder parameters (keys `left_diameter` .. `right_sin3`).
    pub chassis: ChassisParams,
    /// `mode`: sample timing (PPS-locked or free-running).
    pub mode: SyncMode,
    /// `rate`: samples per second, Hz (1..=[`MAX_RATE_HZ`]; in `pps` mode it must divide
    /// 1_000_000 so that every sample falls on a whole microsecond after the PPS edge; high
    /// enough that a wheel at `max_wheel_speed` makes at most [`MAX_COUNTS_PER_SAMPLE`]
    /// increments per sample).
    pub rate: u32,
    /// `output_divider`: send every Nth sample as a record (1..=10000).
    pub output_divider: u32,
    /// `time_tag_pps`: which PPS edge an NMEA time message refers to.
    pub time_tag_pps: TimeTagPps,
    /// `baud`: UART baud rate (one of [`BAUD_RATES`]); the firmware applies it at start.
    pub baud: u32,
    /// `max_wheel_speed`: the highest surface speed either wheel is stated to reach, m/s
    /// (0.01..=20). Bounds the increments per sample ([`Settings::max_counts_per_sample`])
    /// and the time the counters may go unread ([`Settings::max_unread_interval`]).
    pub max_wheel_speed: f32,
    /// `output`: what the host link streams.
    pub output: Output,
    /// `mavlink_sysid`: MAVLink system id (1..=255).
    pub mavlink_sysid: u32,
    /// `mavlink_compid`: MAVLink component id (1..=255).
    pub mavlink_compid: u32,
    /// `gnss_baud`: baud rate of the GNSS receiver's NMEA output (one of [`BAUD_RATES`]);
    /// the firmware applies it at start.
    pub gnss_baud: u32,
}

impl Settings {
    /// Every field zero (first variants): the base the key table's defaults are written
    /// over ([`Settings::DEFAULT`]).
    const UNSET: Self = Self {
        chassis: ChassisParams {
            left_diameter: 0.0,
            right_diameter: 0.0,
            track_width: 0.0,
            ticks_per_rev: 0,
            delta_left: 0.0,
            delta_right: 0.0,
            delta_diff: 0.0,
            uncertainty_model: UncertaintyModel::Paper,
            kappa_left: 0.0,
            kappa_right: 0.0,
            kappa_diff: 0.0,
            kappa_diff_corr: 0.0,
            left_wheel: WheelHarmonics::ROUND,
            right_wheel: WheelHarmonics::ROUND,
            geometry_uncertainty: GeometryUncertainty::EXACT,
        },
        mode: SyncMode::Pps,
        rate: 0,
        output_divider: 0,
        time_tag_pps: TimeTagPps::Previous,
        baud: 0,
        max_wheel_speed: 0.0,
        output: Output::Frames,
        mavlink_sysid: 0,
        mavlink_compid: 0,
        gnss_baud: 0,
    };

    /// Default `max_wheel_speed`, m/s; also what a stored record of format version 1
    /// (which predates the key) loads with.
    pub const DEFAULT_MAX_WHEEL_SPEED: f32 = 2.0;

    /// Accepted `max_wheel_speed`, m/s, as (min, max): 0.01..=20, from a creeping robot to
    /// well beyond a mapping chassis (72 km/h).
    pub const MAX_WHEEL_SPEED_RANGE: (f32, f32) = (0.01, 20.0);

    /// The smaller of the two wheel diameters, m: the wheel that turns faster at a given
    /// surface speed.
    pub fn smaller_diameter(&self) -> f64 {
        self.chassis.left_diameter.min(self.chassis.right_diameter)
    }

    /// [`max_counts_per_sample`] for these settings (`max_wheel_speed`, `ticks_per_rev`, the
    /// smaller diameter, `rate`): the most increments either wheel can make between two
    /// samples, increments. [`Self::validate`] refuses settings where it exceeds
    /// [`MAX_COUNTS_PER_SAMPLE`].
    pub fn max_counts_per_sample(&self) -> f64 {
        max_counts_per_sample(
            f64::from(self.max_wheel_speed),
            self.chassis.ticks_per_rev,
            self.smaller_diameter(),
            self.rate,
        )
    }

    /// [`max_unread_interval`] for these settings: the longest time, seconds, the counters may
    /// go unread with the wheels at `max_wheel_speed` without aliasing. For valid settings
    /// it is at least one sample period, `1 / rate`.
    pub fn max_unread_interval(&self) -> f64 {
        max_unread_interval(
            f64::from(self.max_wheel_speed),
            self.chassis.ticks_per_rev,
            self.smaller_diameter(),
        )
    }

    /// True when the counters survive a CPU stall of `stall_ms` milliseconds (a flash erase)
    /// with the wheels at `max_wheel_speed`: the longest gap between two counter reads, one
    /// sample period (`1 / rate`) plus the stall, is shorter than
    /// [`Self::max_unread_interval`]. The firmware refuses an erasing `save` while the
    /// wheels turn when this is false.
    pub fn survives_stall(&self, stall_ms: u32) -> bool {
        let gap_ms = f64::from(stall_ms) + 1000.0 / f64::from(self.rate.max(1));
        self.max_unread_interval() * 1000.0 > gap_ms
    }

    /// Bits per second the host link must carry (10 bits per byte): the records, each
    /// `rate / output_divider` second, and the once-a-second Status or HEARTBEAT; in
    /// `output = frames` with `mode = pps` also the forwarded GNSS sentences
    /// ([`GNSS_FORWARD_BITS`]). Free-running they are forwarded only into room left over, so
    /// they are not counted. docs/PROTOCOL.md, *Bandwidth budget of the host link*.
    pub fn link_bits_per_second(&self) -> u64 {
        let records_per_s = u64::from(self.rate.div_ceil(self.output_divider.max(1)));
        match self.output {
            Output::Frames => {
                let gnss = match self.mode {
                    SyncMode::Pps => GNSS_FORWARD_BITS,
                    SyncMode::Free => 0,
                };
                records_per_s * u64::from(POSE_FRAME_BITS) + u64::from(STATUS_FRAME_BITS + gnss)
            }
            Output::Mavlink => {
                records_per_s * u64::from(MAVLINK_FRAME_BITS) + u64::from(MAVLINK_HEARTBEAT_BITS)
            }
        }
    }

    /// Checks every key's range and the relations between keys; names the offending key.
    pub fn validate(&self) -> Result<(), SettingError> {
        for key in Key::ALL {
            check_value(key, self.get(key))?;
        }
        self.chassis.validate().map_err(SettingError::from)?;
        if self.mode == SyncMode::Pps && 1_000_000 % self.rate != 0 {
            return Err(SettingError::PpsRate);
        }
        let bits = self.link_bits_per_second();
        if bits > u64::from(self.baud) {
            return Err(SettingError::RecordsOverBaud);
        }
        let counts = self.max_counts_per_sample();
        // NaN is refused too.
        if counts.is_nan() || counts > MAX_COUNTS_PER_SAMPLE as f64 {
            return Err(SettingError::CountsPerSample {
                // Saturating conversion; rounded up so that the text never shows the limit.
                counts: ceil_u64(counts),
            });
        }
        Ok(())
    }

    /// Parses `text` as the value of `key` and stores it, checking that key's own range but
    /// not the relations between keys (see [`Self::validate`], [`Self::set_many`]). On error
    /// nothing changes.
    pub fn set(&mut self, key: Key, text: &str) -> Result<(), SettingError> {
        let value = parse_value(key, text)?;
        check_value(key, value)?;
        let mut next = *self;
        next.put(key, value).ok_or(SettingError::BadChoice(key))?;
        *self = next;
        Ok(())
    }

    /// Sets several `(key name, value text)` pairs atomically: every pair is parsed, then the
    /// whole result is validated ([`Self::validate`]); on any error nothing changes and the
    /// error names the first offending key. A key given twice takes the last value.
    pub fn set_many<'a, I>(&mut self, pairs: I) -> Result<(), SetManyError<'a>>
    where
        I: IntoIterator<Item = (&'a str, &'a str)>,
    {
        let mut next = *self;
        for (name, value) in pairs {
            let key = Key::from_name(name).ok_or(SetManyError::UnknownKey(name))?;
            next.set(key, value).map_err(SetManyError::Value)?;
        }
        next.validate().map_err(SetManyError::Value)?;
        *self = next;
        Ok(())
    }

    /// Writes `key = value` lines for every key into `out`.
    pub fn write_all(&self, out: &mut impl Write) -> fmt::Result {
        for key in Key::ALL {
            writeln!(out, "{} = {}", Text(key.name()), self.get(key))?;
        }
        Ok(())
    }

    /// CRC-32/ISO-HDLC of [`Self::to_bytes`]: the settings checksum reported in
    /// `DeviceInfo`.
    pub fn checksum(&self) -> u32 {
        crc32(&self.to_bytes())
    }
}

impl Default for Settings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The keys that [`Settings::validate`] checks against each other (chassis relations, pps
/// rate, records per baud, the counts rule), in table order: a host sending many keys puts
/// these in one atomic `set` so that no intermediate combination is refused.
pub const RELATED_KEYS: [Key; 10] = [
    Key::LeftDiameter,
    Key::RightDiameter,
    Key::TrackWidth,
    Key::TicksPerRev,
    Key::Mode,
    Key::Rate,
    Key::OutputDivider,
    Key::Baud,
    Key::MaxWheelSpeed,
    Key::Output,
];

/// Checks chassis parameters alone, as [`Settings::validate`] checks them: each chassis key's
/// range ([`Group::Chassis`]), then the relations between them (`ChassisParams::validate`).
/// For host tools that handle the chassis without the unit's options.
pub fn validate_chassis(chassis: &ChassisParams) -> Result<(), SettingError> {
    let s = Settings {
        chassis: *chassis,
        ..Settings::DEFAULT
    };
    for key in Key::ALL {
        if key.info().group == Group::Chassis {
            check_value(key, s.get(key))?;
        }
    }
    chassis.validate().map_err(SettingError::from)
}

/// Why a value or a set of settings was refused; names the key (see [`SettingError::key`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SettingError {
    /// Not a number of the key's type.
    BadNumber(Key),
    /// NaN or infinite.
    NotFinite(Key),
    /// Outside the key's range ([`KeyInfo::kind`]).
    OutOfRange(Key),
    /// Not one of the key's words.
    BadChoice(Key),
    /// The chassis keys are each in range but refused together by
    /// `ChassisParams::validate` (the key it named).
    Chassis(Key),
    /// `diameters_correlation`, `left_track_correlation` and `right_track_correlation`
    /// are each in -1..=1 but no covariance has all three (set them together).
    Correlations,
    /// `ChassisParams::validate` refused a key the table does not know (not expected).
    Params(ParamError),
    /// `mode pps` with a `rate` that does not divide 1,000,000.
    PpsRate,
    /// `rate / output_divider` records per second need more than `baud` (with the Status and
    /// the forwarded GNSS sentences in `output = frames`, [`GNSS_FORWARD_BITS`]).
    RecordsOverBaud,
    /// A wheel at `max_wheel_speed` could make more than [`MAX_COUNTS_PER_SAMPLE`]
    /// increments between two samples (keys `rate`, `max_wheel_speed`, `ticks_per_rev`,
    /// `left_diameter`, `right_diameter`): the 16-bit right counter would alias.
    CountsPerSample {
        /// [`Settings::max_counts_per_sample`] rounded up (saturating), increments.
        counts: u64,
    },
    /// Serialised settings of a format version this firmware does not know.
    UnknownFormatVersion(u16),
    /// Serialised settings too short, or with a code that names no word.
    BadRecord,
}

impl SettingError {
    /// The one key the error is about, if it names exactly one.
    pub fn key(&self) -> Option<Key> {
        match *self {
            Self::BadNumber(k)
            | Self::NotFinite(k)
            | Self::OutOfRange(k)
            | Self::BadChoice(k)
            | Self::Chassis(k) => Some(k),
            _ => None,
        }
    }
}

impl From<ParamError> for SettingError {
    /// The error of `ChassisParams::validate` as the key it names: [`SettingError::Chassis`]
    /// (or [`SettingError::NotFinite`]).
    fn from(e: ParamError) -> Self {
        match e {
            ParamError::NotFinite(name) => Key::from_name(name).map(Self::NotFinite),
            ParamError::OutOfRange(name) => Key::from_name(name).map(Self::Chassis),
            ParamError::Inconsistent(_) => Some(Self::Correlations),
        }
        .unwrap_or(Self::Params(e))
    }
}

impl fmt::Display for SettingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Errors about one key start with its name.
        if let Some(k) = self.key() {
            f.write_str(k.name())?;
            f.write_str(": ")?;
        }
        match *self {
            Self::BadNumber(_) => f.write_str("bad number"),
            Self::NotFinite(_) => f.write_str("NaN/inf not allowed"),
            Self::OutOfRange(k) => write!(f, "out of range, {}", k.kind()),
            Self::BadChoice(k) => write!(f, "expected {}", k.kind()),
            Self::Chassis(_) => write!(
                f,
                "does not fit the other chassis keys (one increment must stay within {} m and {} rad)",
                Shortest(ChassisParams::MAX_DISTANCE_PER_COUNT),
                Shortest(ChassisParams::MAX_HEADING_PER_COUNT)
            ),
            Self::Correlations => f.write_str(
                "diameters_correlation/left_track_correlation/right_track_correlation: no \
                 covariance has these three correlations (set them together in one line)",
            ),
            Self::Params(e) => e.fmt(f),
            Self::PpsRate => f.write_str(
                "rate: in pps mode the rate must divide 1000000 (e.g. 1, 10, 20, 50, 100, 200, 500, 1000)",
            ),
            Self::RecordsOverBaud => f.write_str(
                "rate/output_divider: records need more than the baud rate (raise output_divider or \
                 baud; output frames in pps mode also carries GNSS sentences, 44000 bit/s)",
            ),
            Self::CountsPerSample { counts } => write!(
                f,
                "rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter: up to {} \
                 increments per sample at max_wheel_speed, above {} (the \
                 16-bit right counter would alias; raise rate, or lower max_wheel_speed or \
                 ticks_per_rev)",
                Dec(counts),
                Dec(MAX_COUNTS_PER_SAMPLE)
            ),
            Self::UnknownFormatVersion(_) => {
                f.write_str("serialised settings: unknown format version")
            }
            Self::BadRecord => f.write_str("serialised settings: truncated or bad code"),
        }
    }
}

/// Why [`Settings::set_many`] changed nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SetManyError<'a> {
    /// No key of that name.
    UnknownKey(&'a str),
    /// A value was refused, or the result did not validate.
    Value(SettingError),
}

impl fmt::Display for SetManyError<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UnknownKey(k) => write!(f, "unknown key '{}'", Text(k)),
            Self::Value(e) => e.fmt(f),
        }
    }
}

/// Parses `text` as a value of `key`'s type, as the unit does (the same parser serves the
/// host tool): decimal floats correctly rounded to the key's type (`crate::decimal`, f32
/// directly, never through f64), integers without fraction or exponent, words exactly.
/// The key's range is not checked ([`check_value`]).
pub fn parse_value(key: Key, text: &str) -> Result<Value, SettingError> {
    match *key.kind() {
        Kind::F64 { .. } => decimal::parse_f64(text)
            .map(Value::F64)
            .map_err(|e| decimal_error(key, e)),
        Kind::F32 { .. } => {
            // Refuse what is not a finite f64 first (so 1e999 is NaN/inf, 1e39 out of range);
            // then parse again directly as f32: correctly rounded, so the text form of an f32
            // value always parses back to the identical value (no double rounding).
            decimal::parse_f64(text).map_err(|e| decimal_error(key, e))?;
            decimal::parse_f32(text)
                .map(Value::F32)
                .map_err(|_| SettingError::OutOfRange(key))
        }
        Kind::U32 { .. } | Kind::U32Set(_) => {
            let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return Err(SettingError::BadNumber(key));
            }
            // An integer beyond u32, even beyond 64 bits, is out of range.
            text.parse::<i64>()
                .ok()
                .and_then(|v| u32::try_from(v).ok())
                .map(Value::U32)
                .ok_or(SettingError::OutOfRange(key))
        }
        Kind::Word(words) => words
            .iter()
            .find(|w| **w == text)
            .map(|w| Value::Word(w))
            .ok_or(SettingError::BadChoice(key)),
    }
}

/// Checks a value against `key`'s type and range ([`KeyInfo::kind`]).
pub fn check_value(key: Key, value: Value) -> Result<(), SettingError> {
    let ok = match (*key.kind(), value) {
        (Kind::F64 { min, max }, Value::F64(v)) => {
            if !v.is_finite() {
                return Err(SettingError::NotFinite(key));
            }
            (min..=max).contains(&v)
        }
        (Kind::F32 { min, max }, Value::F32(v)) => {
            if !v.is_finite() {
                return Err(SettingError::NotFinite(key));
            }
            (min..=max).contains(&v)
        }
        (Kind::U32 { min, max }, Value::U32(v)) => (min..=max).contains(&v),
        (Kind::U32Set(set), Value::U32(v)) => set.contains(&v),
        (Kind::Word(words), Value::Word(w)) => words.contains(&w),
        _ => false,
    };
    if ok {
        Ok(())
    } else {
        Err(SettingError::OutOfRange(key))
    }
}

fn decimal_error(key: Key, e: DecimalError) -> SettingError {
    match e {
        DecimalError::Invalid => SettingError::BadNumber(key),
        // NaN/inf words, or a literal too large for f64 such as 1e999.
        DecimalError::NotFinite | DecimalError::Overflow => SettingError::NotFinite(key),
    }
}

/// `v` rounded up to an integer, saturating at 0 and `u64::MAX` (NaN gives `u64::MAX`).
fn ceil_u64(v: f64) -> u64 {
    if v.is_nan() {
        return u64::MAX;
    }
    // `as` saturates; add 1 unless the value is already whole (no `f64::ceil` in core).
    let t = v as u64;
    if (t as f64) < v {
        t.saturating_add(1)
    } else {
        t
    }
}
