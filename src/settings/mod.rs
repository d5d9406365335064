//! The unit's settings: chassis parameters plus sampling and output options, with access by
//! key name (the names shared by commands, files and the host tool), validation, a versioned
//! checksummed binary form, and the power-cut-safe flash store ([`store`]).

pub mod store;

use crate::bytes::{OutOfSpace, Reader, Writer};
use crate::crc::crc32;
use crate::decimal::{self, DecimalError, Shortest};
use crate::odometry::integrator::MAX_STEP_COUNTS;
use crate::odometry::{ChassisParams, UncertaintyModel, WHEEL_HARMONICS};
use core::fmt::{self, Write};

pub use store::SettingsSource;

/// How samples are timed (`mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SampleMode {
    /// `pps`: samples locked to the GNSS 1-PPS edges (holdover when PPS is lost); `rate`
    /// samples per second, the first on the edge.
    Pps,
    /// `free`: samples timed by the MCU clock alone at `rate` Hz.
    #[default]
    Free,
}

/// Which PPS edge an NMEA time message refers to (`time_tag_pps`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimeTagRef {
    /// `previous`: the message names the time of the PPS edge that preceded it.
    #[default]
    Previous,
    /// `next`: the message announces the time of the next PPS edge.
    Next,
}

/// Baud rates accepted by `baud`.
pub const BAUD_RATES: [u32; 8] = [
    9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];

/// Bits on the wire of one pose record frame (114 bytes, 10 bits per byte with start and
/// stop bit), used to check that the output rate fits the baud rate.
pub const POSE_FRAME_BITS: u32 = 1140;

/// Highest accepted `rate`, Hz: what the processing task sustains with a wide margin.
///
/// Derivation, from the instruction counts of the README's performance table (`bench/run`,
/// release code under QEMU) and the firmware's own `process_max` in `status`:
///
/// * a typical sample costs the processing task about 7,000 instructions (timing, flags,
///   index, odometry and uncertainty, the record's f64 fields, the 114-byte frame at
///   2,540, queueing); the per-angle wheel model adds up to 2,113 - 808 = 1,305 in its
///   worst case: about **8,300 instructions** per sample;
/// * the worst sample (`process_max`: the first one, which builds the integrator, and the
///   ones that log a state change or send the once-a-second Status) costs about
///   **24,000 instructions**;
/// * at 84 MHz the flash needs 2 wait states; the ART accelerator hides most of them, but
///   counted at **2 cycles per instruction** (no cache hits at all) a typical sample takes
///   16,600 cycles (198 us) and the worst 48,000 cycles (571 us).
///
/// At 1,000 Hz this is 999 x 16,600 + 48,000 = 16.6 million cycles per second, **20 % of the
/// CPU** (within the 25 % budget that leaves the rest to the sample interrupt, the UART
/// interrupts and the command task), and even the worst sample ends well within one 1 ms
/// sample period, so the sample queue never fills in steady state. 1,000 also divides
/// 1,000,000, so it is accepted in `pps` mode. Above it the budget would be spent on a
/// cost that has not been measured on a board.
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

/// Everything the unit keeps across resets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Chassis and encoder parameters (keys `left_diameter` .. `right_sin3`).
    pub chassis: ChassisParams,
    /// `mode`: sample timing.
    pub mode: SampleMode,
    /// `rate`: samples per second, Hz (1..=[`MAX_RATE_HZ`]; in `pps` mode it must divide
    /// 1_000_000 so that every sample falls on a whole microsecond after the PPS edge; high
    /// enough that a wheel at `max_wheel_speed` makes at most [`MAX_COUNTS_PER_SAMPLE`]
    /// increments per sample).
    pub rate: u32,
    /// `output_divider`: send every Nth sample as a record (1..=10000).
    pub output_divider: u32,
    /// `time_tag_pps`: which PPS edge an NMEA time message refers to.
    pub time_tag_pps: TimeTagRef,
    /// `baud`: UART baud rate (one of [`BAUD_RATES`]); the firmware applies it at start.
    pub baud: u32,
    /// `max_wheel_speed`: the highest surface speed either wheel is stated to reach, m/s
    /// (0.01..=20). Bounds the increments per sample ([`Settings::max_counts_per_sample`])
    /// and the time the counters may go unread ([`Settings::max_unread_interval`]).
    pub max_wheel_speed: f32,
}

impl Settings {
    /// The defaults: the paper's designed chassis ([`ChassisParams::DESIGNED`]), free-running
    /// at 50 Hz, every sample sent, NMEA time refers to the previous PPS edge, 115200 baud,
    /// wheels at most at 2 m/s.
    pub const DEFAULT: Self = Self {
        chassis: ChassisParams::DESIGNED,
        mode: SampleMode::Free,
        rate: 50,
        output_divider: 1,
        time_tag_pps: TimeTagRef::Previous,
        baud: 115_200,
        max_wheel_speed: Self::DEFAULT_MAX_WHEEL_SPEED,
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

    /// Checks every key's range and the relations between keys; names the offending key.
    pub fn validate(&self) -> Result<(), SettingError> {
        for key in Key::ALL {
            check_range(key, self)?;
        }
        self.chassis.validate().map_err(|e| match e {
            crate::odometry::ParamError::NotFinite(k) => SettingError::NotFinite(k),
            crate::odometry::ParamError::OutOfRange(k) => SettingError::Chassis(k),
        })?;
        if self.mode == SampleMode::Pps && 1_000_000 % self.rate != 0 {
            return Err(SettingError::Inconsistent(
                "rate: in pps mode the rate must divide 1000000 (e.g. 1, 10, 20, 50, 100, 200, 500, 1000)",
            ));
        }
        let records_per_s = self.rate.div_ceil(self.output_divider);
        if records_per_s as u64 * POSE_FRAME_BITS as u64 > self.baud as u64 {
            return Err(SettingError::Inconsistent(
                "rate/output_divider: records need more than the baud rate (raise output_divider or baud)",
            ));
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

    /// The value of `key`.
    pub fn get(&self, key: Key) -> Value {
        let c = &self.chassis;
        match key {
            Key::LeftDiameter => Value::F64(c.left_diameter),
            Key::RightDiameter => Value::F64(c.right_diameter),
            Key::TrackWidth => Value::F64(c.track_width),
            Key::TicksPerRev => Value::U32(c.ticks_per_rev),
            Key::DeltaLeft => Value::F32(c.delta_left),
            Key::DeltaRight => Value::F32(c.delta_right),
            Key::DeltaDiff => Value::F32(c.delta_diff),
            Key::UncertaintyModel => Value::Word(match c.uncertainty_model {
                UncertaintyModel::Paper => "paper",
                UncertaintyModel::Covariance => "covariance",
            }),
            Key::KappaLeft => Value::F32(c.kappa_left),
            Key::KappaRight => Value::F32(c.kappa_right),
            Key::LeftCos(h) => Value::F32(c.left_wheel.cos[h.index()]),
            Key::LeftSin(h) => Value::F32(c.left_wheel.sin[h.index()]),
            Key::RightCos(h) => Value::F32(c.right_wheel.cos[h.index()]),
            Key::RightSin(h) => Value::F32(c.right_wheel.sin[h.index()]),
            Key::Mode => Value::Word(match self.mode {
                SampleMode::Pps => "pps",
                SampleMode::Free => "free",
            }),
            Key::Rate => Value::U32(self.rate),
            Key::OutputDivider => Value::U32(self.output_divider),
            Key::TimeTagPps => Value::Word(match self.time_tag_pps {
                TimeTagRef::Previous => "previous",
                TimeTagRef::Next => "next",
            }),
            Key::Baud => Value::U32(self.baud),
            Key::MaxWheelSpeed => Value::F32(self.max_wheel_speed),
        }
    }

    /// Parses `text` as the value of `key` and stores it, checking that key's own range but
    /// not the relations between keys (see [`Self::validate`], [`Self::set_many`]). On error
    /// nothing changes.
    pub fn set(&mut self, key: Key, text: &str) -> Result<(), SettingError> {
        let mut next = *self;
        let name = key.name();
        let c = &mut next.chassis;
        match key.info().kind {
            Kind::F64 { .. } => {
                let v = parse_f64(name, text)?;
                match key {
                    Key::LeftDiameter => c.left_diameter = v,
                    Key::RightDiameter => c.right_diameter = v,
                    _ => c.track_width = v,
                }
            }
            Kind::F32 { .. } => {
                let v = parse_f32(name, text)?;
                match key {
                    Key::DeltaLeft => c.delta_left = v,
                    Key::DeltaRight => c.delta_right = v,
                    Key::DeltaDiff => c.delta_diff = v,
                    Key::KappaLeft => c.kappa_left = v,
                    Key::KappaRight => c.kappa_right = v,
                    Key::LeftCos(h) => c.left_wheel.cos[h.index()] = v,
                    Key::LeftSin(h) => c.left_wheel.sin[h.index()] = v,
                    Key::RightCos(h) => c.right_wheel.cos[h.index()] = v,
                    Key::MaxWheelSpeed => next.max_wheel_speed = v,
                    _ => {
                        if let Key::RightSin(h) = key {
                            c.right_wheel.sin[h.index()] = v;
                        }
                    }
                }
            }
            Kind::U32 { .. } | Kind::U32Set(_) => {
                let v = parse_u32(name, text)?;
                match key {
                    Key::TicksPerRev => c.ticks_per_rev = v,
                    Key::Rate => next.rate = v,
                    Key::OutputDivider => next.output_divider = v,
                    _ => next.baud = v,
                }
            }
            Kind::Word(words) => {
                let i = words
                    .iter()
                    .position(|w| *w == text)
                    .ok_or(SettingError::BadChoice(name, words))?;
                match key {
                    Key::UncertaintyModel => {
                        c.uncertainty_model =
                            [UncertaintyModel::Paper, UncertaintyModel::Covariance][i]
                    }
                    Key::Mode => next.mode = [SampleMode::Pps, SampleMode::Free][i],
                    _ => next.time_tag_pps = [TimeTagRef::Previous, TimeTagRef::Next][i],
                }
            }
        }
        check_range(key, &next)?;
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
            writeln!(out, "{} = {}", key.name(), self.get(key))?;
        }
        Ok(())
    }

    /// Length of the serialised form of format version [`SETTINGS_FORMAT_VERSION`] (2),
    /// bytes.
    pub const SERIALIZED_LEN: usize = 116;

    /// Length of the serialised form of format version 1, bytes: the version 2 layout
    /// without its last field, `max_wheel_speed`.
    pub const SERIALIZED_LEN_V1: usize = 112;

    /// Serialises into the fixed little-endian layout of format version
    /// [`SETTINGS_FORMAT_VERSION`] (documented in `docs/PROTOCOL.md`).
    pub fn to_bytes(&self) -> [u8; Self::SERIALIZED_LEN] {
        let mut out = [0u8; Self::SERIALIZED_LEN];
        // The buffer is exactly the layout's size, so no write can fail.
        let _ = self.write_to(&mut Writer::new(&mut out));
        out
    }

    fn write_to(&self, w: &mut Writer<'_>) -> Result<(), OutOfSpace> {
        let c = &self.chassis;
        w.f64(c.left_diameter)?;
        w.f64(c.right_diameter)?;
        w.f64(c.track_width)?;
        w.u32(c.ticks_per_rev)?;
        for v in [
            c.delta_left,
            c.delta_right,
            c.delta_diff,
            c.kappa_left,
            c.kappa_right,
        ] {
            w.f32(v)?;
        }
        for wheel in [&c.left_wheel, &c.right_wheel] {
            for v in wheel.cos.iter().chain(wheel.sin.iter()) {
                w.f32(*v)?;
            }
        }
        w.u8(match c.uncertainty_model {
            UncertaintyModel::Paper => 0,
            UncertaintyModel::Covariance => 1,
        })?;
        w.u8(match self.mode {
            SampleMode::Pps => 0,
            SampleMode::Free => 1,
        })?;
        w.u8(match self.time_tag_pps {
            TimeTagRef::Previous => 0,
            TimeTagRef::Next => 1,
        })?;
        w.u8(0)?;
        w.u32(self.rate)?;
        w.u32(self.output_divider)?;
        w.u32(self.baud)?;
        // Format version 2 appends this field.
        w.f32(self.max_wheel_speed)
    }

    /// Parses the serialised form of the current format version ([`SETTINGS_FORMAT_VERSION`],
    /// at least [`Self::SERIALIZED_LEN`] bytes; extra bytes are ignored) and validates it.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, SettingError> {
        Self::from_bytes_version(SETTINGS_FORMAT_VERSION, bytes)
    }

    /// Parses the serialised form of format `version` and validates it: version 2
    /// ([`Self::SERIALIZED_LEN`] bytes) or version 1 ([`Self::SERIALIZED_LEN_V1`] bytes,
    /// stored by firmware before `max_wheel_speed` existed; that key takes
    /// [`Self::DEFAULT_MAX_WHEEL_SPEED`]). Too few bytes, a bad code, an unknown version or
    /// settings that do not validate (including under rules added since the record was
    /// written) are errors.
    pub fn from_bytes_version(version: u16, bytes: &[u8]) -> Result<Self, SettingError> {
        if !(1..=SETTINGS_FORMAT_VERSION).contains(&version) {
            return Err(SettingError::Inconsistent(
                "serialised settings: unknown format version",
            ));
        }
        let bad = SettingError::Inconsistent("serialised settings: truncated or bad code");
        let mut r = Reader::new(bytes);
        let mut s = Self::DEFAULT;
        (|| -> Result<Option<()>, OutOfSpace> {
            let c = &mut s.chassis;
            c.left_diameter = r.f64()?;
            c.right_diameter = r.f64()?;
            c.track_width = r.f64()?;
            c.ticks_per_rev = r.u32()?;
            c.delta_left = r.f32()?;
            c.delta_right = r.f32()?;
            c.delta_diff = r.f32()?;
            c.kappa_left = r.f32()?;
            c.kappa_right = r.f32()?;
            for wheel in [&mut c.left_wheel, &mut c.right_wheel] {
                for h in 0..WHEEL_HARMONICS {
                    wheel.cos[h] = r.f32()?;
                }
                for h in 0..WHEEL_HARMONICS {
                    wheel.sin[h] = r.f32()?;
                }
            }
            c.uncertainty_model = match r.u8()? {
                0 => UncertaintyModel::Paper,
                1 => UncertaintyModel::Covariance,
                _ => return Ok(None),
            };
            s.mode = match r.u8()? {
                0 => SampleMode::Pps,
                1 => SampleMode::Free,
                _ => return Ok(None),
            };
            s.time_tag_pps = match r.u8()? {
                0 => TimeTagRef::Previous,
                1 => TimeTagRef::Next,
                _ => return Ok(None),
            };
            r.u8()?;
            s.rate = r.u32()?;
            s.output_divider = r.u32()?;
            s.baud = r.u32()?;
            if version >= 2 {
                s.max_wheel_speed = r.f32()?;
            }
            Ok(Some(()))
        })()
        .ok()
        .flatten()
        .ok_or(bad)?;
        s.validate()?;
        Ok(s)
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

/// Version of the serialised settings layout ([`Settings::to_bytes`]). Version 2 appended
/// `max_wheel_speed` to version 1; [`Settings::from_bytes_version`] reads both.
pub const SETTINGS_FORMAT_VERSION: u16 = 2;

/// Harmonic number 1..=3 of a wheel-function key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Harmonic {
    /// First harmonic (`..1`).
    H1,
    /// Second harmonic (`..2`).
    H2,
    /// Third harmonic (`..3`).
    H3,
}

impl Harmonic {
    /// Array index 0..=2.
    pub fn index(self) -> usize {
        match self {
            Self::H1 => 0,
            Self::H2 => 1,
            Self::H3 => 2,
        }
    }
}

/// A settings key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// `left_diameter`, metres.
    LeftDiameter,
    /// `right_diameter`, metres.
    RightDiameter,
    /// `track_width`, metres.
    TrackWidth,
    /// `ticks_per_rev`, increments per turn.
    TicksPerRev,
    /// `delta_left`, metres per increment.
    DeltaLeft,
    /// `delta_right`, metres per increment.
    DeltaRight,
    /// `delta_diff`, metres per increment.
    DeltaDiff,
    /// `uncertainty_model`: `paper` | `covariance`.
    UncertaintyModel,
    /// `kappa_left`, m^2/m.
    KappaLeft,
    /// `kappa_right`, m^2/m.
    KappaRight,
    /// `left_cosN`, dimensionless.
    LeftCos(Harmonic),
    /// `left_sinN`, dimensionless.
    LeftSin(Harmonic),
    /// `right_cosN`, dimensionless.
    RightCos(Harmonic),
    /// `right_sinN`, dimensionless.
    RightSin(Harmonic),
    /// `mode`: `pps` | `free`.
    Mode,
    /// `rate`, Hz.
    Rate,
    /// `output_divider`.
    OutputDivider,
    /// `time_tag_pps`: `previous` | `next`.
    TimeTagPps,
    /// `baud`, bit/s.
    Baud,
    /// `max_wheel_speed`, m/s.
    MaxWheelSpeed,
}

/// How a key's value is typed and bounded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    /// A finite f64 in `min..=max`.
    F64 {
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
    /// A finite f32 in `min..=max`.
    F32 {
        /// Smallest accepted value.
        min: f32,
        /// Largest accepted value.
        max: f32,
    },
    /// A decimal integer in `min..=max`.
    U32 {
        /// Smallest accepted value.
        min: u32,
        /// Largest accepted value.
        max: u32,
    },
    /// A decimal integer from a fixed set.
    U32Set(&'static [u32]),
    /// One of the listed words.
    Word(&'static [&'static str]),
}

/// Name, type and meaning of a key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyInfo {
    /// The shared key name.
    pub name: &'static str,
    /// Type and range.
    pub kind: Kind,
    /// Unit (empty when dimensionless or a word).
    pub unit: &'static str,
}

const LEN: Kind = Kind::F64 {
    min: ChassisParams::MIN_LENGTH,
    max: ChassisParams::MAX_LENGTH,
};
const DELTA: Kind = Kind::F32 {
    min: 0.0,
    max: ChassisParams::MAX_DELTA,
};
const KAPPA: Kind = Kind::F32 {
    min: 0.0,
    max: ChassisParams::MAX_KAPPA,
};
const HARM: Kind = Kind::F32 {
    min: -ChassisParams::MAX_HARMONIC,
    max: ChassisParams::MAX_HARMONIC,
};

impl Key {
    /// Number of keys.
    pub const COUNT: usize = 28;

    /// Every key, in the order `get` lists them.
    pub const ALL: [Key; Self::COUNT] = {
        use Harmonic::*;
        [
            Key::LeftDiameter,
            Key::RightDiameter,
            Key::TrackWidth,
            Key::TicksPerRev,
            Key::DeltaLeft,
            Key::DeltaRight,
            Key::DeltaDiff,
            Key::UncertaintyModel,
            Key::KappaLeft,
            Key::KappaRight,
            Key::LeftCos(H1),
            Key::LeftCos(H2),
            Key::LeftCos(H3),
            Key::LeftSin(H1),
            Key::LeftSin(H2),
            Key::LeftSin(H3),
            Key::RightCos(H1),
            Key::RightCos(H2),
            Key::RightCos(H3),
            Key::RightSin(H1),
            Key::RightSin(H2),
            Key::RightSin(H3),
            Key::Mode,
            Key::Rate,
            Key::OutputDivider,
            Key::TimeTagPps,
            Key::Baud,
            Key::MaxWheelSpeed,
        ]
    };

    /// Name, type, range and unit.
    pub fn info(self) -> KeyInfo {
        let (name, kind, unit) = match self {
            Key::LeftDiameter => ("left_diameter", LEN, "m"),
            Key::RightDiameter => ("right_diameter", LEN, "m"),
            Key::TrackWidth => ("track_width", LEN, "m"),
            Key::TicksPerRev => (
                "ticks_per_rev",
                Kind::U32 {
                    min: *ChassisParams::TICKS_PER_REV_RANGE.start(),
                    max: *ChassisParams::TICKS_PER_REV_RANGE.end(),
                },
                "increments/turn",
            ),
            Key::DeltaLeft => ("delta_left", DELTA, "m/increment"),
            Key::DeltaRight => ("delta_right", DELTA, "m/increment"),
            Key::DeltaDiff => ("delta_diff", DELTA, "m/increment"),
            Key::UncertaintyModel => (
                "uncertainty_model",
                Kind::Word(&["paper", "covariance"]),
                "",
            ),
            Key::KappaLeft => ("kappa_left", KAPPA, "m^2/m"),
            Key::KappaRight => ("kappa_right", KAPPA, "m^2/m"),
            Key::LeftCos(h) => (["left_cos1", "left_cos2", "left_cos3"][h.index()], HARM, ""),
            Key::LeftSin(h) => (["left_sin1", "left_sin2", "left_sin3"][h.index()], HARM, ""),
            Key::RightCos(h) => (
                ["right_cos1", "right_cos2", "right_cos3"][h.index()],
                HARM,
                "",
            ),
            Key::RightSin(h) => (
                ["right_sin1", "right_sin2", "right_sin3"][h.index()],
                HARM,
                "",
            ),
            Key::Mode => ("mode", Kind::Word(&["pps", "free"]), ""),
            Key::Rate => (
                "rate",
                Kind::U32 {
                    min: 1,
                    max: MAX_RATE_HZ,
                },
                "Hz",
            ),
            Key::OutputDivider => (
                "output_divider",
                Kind::U32 {
                    min: 1,
                    max: 10_000,
                },
                "",
            ),
            Key::TimeTagPps => ("time_tag_pps", Kind::Word(&["previous", "next"]), ""),
            Key::Baud => ("baud", Kind::U32Set(&BAUD_RATES), "bit/s"),
            Key::MaxWheelSpeed => (
                "max_wheel_speed",
                Kind::F32 {
                    min: Settings::MAX_WHEEL_SPEED_RANGE.0,
                    max: Settings::MAX_WHEEL_SPEED_RANGE.1,
                },
                "m/s",
            ),
        };
        KeyInfo { name, kind, unit }
    }

    /// The shared key name.
    pub fn name(self) -> &'static str {
        self.info().name
    }

    /// The key of a name (exact, case-sensitive).
    pub fn from_name(name: &str) -> Option<Key> {
        Key::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// A key's value, as [`Settings::get`] returns it. `Display` writes the text form that
/// [`Settings::set`] parses back to the identical value (shortest round-trip decimal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// An f64 value.
    F64(f64),
    /// An f32 value.
    F32(f32),
    /// An integer value.
    U32(u32),
    /// A word.
    Word(&'static str),
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Shortest round-trip decimal, plain for 1e-9 <= |v| < 1e9 and scientific
        // otherwise (`crate::decimal`, which keeps core's float formatting out of the
        // firmware).
        match *self {
            Value::F64(v) => decimal::write_f64(v, f),
            Value::F32(v) => decimal::write_f32(v, f),
            Value::U32(v) => write!(f, "{v}"),
            Value::Word(w) => f.write_str(w),
        }
    }
}

/// Why a value was refused; names the key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SettingError {
    /// Not a number of the key's type (the key).
    BadNumber(&'static str),
    /// NaN or infinite (the key).
    NotFinite(&'static str),
    /// Outside the key's range (the key and its kind, which holds the range).
    OutOfRange(&'static str, Kind),
    /// Not one of the accepted words (the key and the words).
    BadChoice(&'static str, &'static [&'static str]),
    /// The keys are each in range but do not fit together (an explanation naming them).
    Inconsistent(&'static str),
    /// The chassis keys are each in range but refused together by
    /// `ChassisParams::validate` (the key it named).
    Chassis(&'static str),
    /// A wheel at `max_wheel_speed` could make more than [`MAX_COUNTS_PER_SAMPLE`]
    /// increments between two samples (keys `rate`, `max_wheel_speed`, `ticks_per_rev`,
    /// `left_diameter`, `right_diameter`): the 16-bit right counter would alias.
    CountsPerSample {
        /// [`Settings::max_counts_per_sample`] rounded up (saturating), increments.
        counts: u64,
    },
}

impl fmt::Display for SettingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::BadNumber(k) => write!(f, "{k}: bad number"),
            Self::NotFinite(k) => write!(f, "{k}: NaN/inf not allowed"),
            Self::OutOfRange(k, kind) => {
                write!(f, "{k}: out of range, ")?;
                match kind {
                    Kind::F64 { min, max } => write!(f, "{}..={}", Value::F64(min), Value::F64(max)),
                    Kind::F32 { min, max } => write!(f, "{}..={}", Value::F32(min), Value::F32(max)),
                    Kind::U32 { min, max } => write!(f, "{min}..={max}"),
                    Kind::U32Set(set) => {
                        f.write_str("one of")?;
                        for v in set {
                            write!(f, " {v}")?;
                        }
                        Ok(())
                    }
                    Kind::Word(_) => f.write_str("see help"),
                }
            }
            Self::BadChoice(k, words) => {
                write!(f, "{k}: expected")?;
                for (i, w) in words.iter().enumerate() {
                    write!(f, "{}{w}", if i == 0 { " " } else { "|" })?;
                }
                Ok(())
            }
            Self::Inconsistent(why) => f.write_str(why),
            Self::Chassis(k) => write!(
                f,
                "{k}: does not fit the other chassis keys (one increment must stay within {} m and {} rad)",
                Shortest(ChassisParams::MAX_DISTANCE_PER_COUNT),
                Shortest(ChassisParams::MAX_HEADING_PER_COUNT)
            ),
            Self::CountsPerSample { counts } => write!(
                f,
                "rate/max_wheel_speed/ticks_per_rev/left_diameter/right_diameter: up to {counts} \
                 increments per sample at max_wheel_speed, above {MAX_COUNTS_PER_SAMPLE} (the \
                 16-bit right counter would alias; raise rate, or lower max_wheel_speed or \
                 ticks_per_rev)"
            ),
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
            Self::UnknownKey(k) => write!(f, "unknown key '{k}'"),
            Self::Value(e) => e.fmt(f),
        }
    }
}

fn check_range(key: Key, s: &Settings) -> Result<(), SettingError> {
    let info = key.info();
    let bad = SettingError::OutOfRange(info.name, info.kind);
    let ok = match (info.kind, s.get(key)) {
        (Kind::F64 { min, max }, Value::F64(v)) => {
            if !v.is_finite() {
                return Err(SettingError::NotFinite(info.name));
            }
            (min..=max).contains(&v)
        }
        (Kind::F32 { min, max }, Value::F32(v)) => {
            if !v.is_finite() {
                return Err(SettingError::NotFinite(info.name));
            }
            (min..=max).contains(&v)
        }
        (Kind::U32 { min, max }, Value::U32(v)) => (min..=max).contains(&v),
        (Kind::U32Set(set), Value::U32(v)) => set.contains(&v),
        (Kind::Word(_), Value::Word(_)) => true,
        _ => false,
    };
    if ok {
        Ok(())
    } else {
        Err(bad)
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

fn parse_f64(key: &'static str, text: &str) -> Result<f64, SettingError> {
    decimal::parse_f64(text).map_err(|e| match e {
        DecimalError::Invalid => SettingError::BadNumber(key),
        // NaN/inf words, or a literal too large for f64 such as 1e999.
        DecimalError::NotFinite | DecimalError::Overflow => SettingError::NotFinite(key),
    })
}

fn parse_f32(key: &'static str, text: &str) -> Result<f32, SettingError> {
    parse_f64(key, text)?;
    // Parse again directly as f32: correctly rounded, so the text form of an f32 value
    // always parses back to the identical value (no double rounding through f64).
    decimal::parse_f32(text).map_err(|_| {
        // Finite as f64 but beyond f32, such as 1e39.
        match key_info_by_name(key) {
            Some(i) => SettingError::OutOfRange(key, i.kind),
            None => SettingError::BadNumber(key),
        }
    })
}

fn parse_u32(key: &'static str, text: &str) -> Result<u32, SettingError> {
    let info = key_info_by_name(key);
    match text.parse::<i64>() {
        Ok(v) => u32::try_from(v).map_err(|_| match info {
            Some(i) => SettingError::OutOfRange(key, i.kind),
            None => SettingError::BadNumber(key),
        }),
        Err(_) => Err(SettingError::BadNumber(key)),
    }
}

fn key_info_by_name(name: &str) -> Option<KeyInfo> {
    Key::from_name(name).map(Key::info)
}
