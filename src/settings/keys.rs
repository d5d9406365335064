//! The settings key table: every key declared once, with its name, unit, range, default,
//! meaning, place in [`Settings`], text form and record encoding.
//!
//! Everything else derives from this table: `get`/`set`/`help` on the unit
//! ([`crate::console`]), the flash record codec ([`super::record`]), and the host
//! tool's TOML files and `config push`. Adding a key: a field in [`Settings`] and one entry
//! below (a new record offset means a new format version, [`super::SETTINGS_FORMAT_VERSION`]),
//! plus its row in `docs/PROTOCOL.md` (a test checks the docs name every key).

use super::{Output, Settings, BAUD_RATES, MAX_RATE_HZ};
use crate::decimal::{self, Dec};
use crate::odometry::{ChassisParams, GeometryUncertainty, UncertaintyModel};
use crate::timing::{SyncMode, TimeTagPps};
use core::fmt;

/// How a key's value is typed and bounded; also its text form and record encoding:
/// `F64` is 8 bytes, `F32`, `U32` and `U32Set` 4 bytes (little-endian), `Word` one byte
/// (the word's position in the list).
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

impl Kind {
    /// Bytes of the value in the settings record.
    pub const fn record_size(self) -> usize {
        match self {
            Kind::F64 { .. } => 8,
            Kind::F32 { .. } | Kind::U32 { .. } | Kind::U32Set(_) => 4,
            Kind::Word(_) => 1,
        }
    }
}

impl fmt::Display for Kind {
    /// The accepted values: `min..=max`, or the set or words separated by `|` (the text of
    /// `help` and of an out-of-range error).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Kind::F64 { min, max } => write!(f, "{}..={}", Value::F64(min), Value::F64(max)),
            Kind::F32 { min, max } => write!(f, "{}..={}", Value::F32(min), Value::F32(max)),
            Kind::U32 { min, max } => {
                write!(f, "{}..={}", Dec(u64::from(min)), Dec(u64::from(max)))
            }
            Kind::U32Set(set) => {
                for (i, v) in set.iter().enumerate() {
                    f.write_str(if i == 0 { "" } else { "|" })?;
                    write!(f, "{}", Dec(u64::from(*v)))?;
                }
                Ok(())
            }
            Kind::Word(words) => {
                for (i, w) in words.iter().enumerate() {
                    f.write_str(if i == 0 { "" } else { "|" })?;
                    f.write_str(w)?;
                }
                Ok(())
            }
        }
    }
}

/// Which part of the unit a key configures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Group {
    /// A chassis parameter ([`ChassisParams`]): also in odoctl's parameter files.
    Chassis,
    /// Sampling and output of the unit itself.
    Unit,
}

/// Where a key's value sits in the serialised settings ([`Settings::to_bytes`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordField {
    /// Byte offset in the payload.
    pub offset: u8,
    /// First format version that holds the key (older records load its default).
    pub since: u16,
}

/// Name, type, unit and record place of a key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyInfo {
    /// The shared key name.
    pub name: &'static str,
    /// Type and range.
    pub kind: Kind,
    /// Unit (empty when dimensionless or a word).
    pub unit: &'static str,
    /// Chassis parameter or unit option.
    pub group: Group,
    /// Place in the serialised settings.
    pub record: RecordField,
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
        // Shortest round-trip decimal, plain, never an exponent (`crate::decimal`, which
        // keeps core's float formatting out of the firmware).
        match *self {
            Value::F64(v) => decimal::write_f64(v, f),
            Value::F32(v) => decimal::write_f32(v, f),
            Value::U32(v) => write!(f, "{}", Dec(u64::from(v))),
            Value::Word(w) => f.write_str(w),
        }
    }
}

/// An enumeration set by a word (`uncertainty_model`, `mode`, `time_tag_pps`); the record
/// stores the word's position.
pub trait Choice: Copy + PartialEq + 'static {
    /// The variants, in the order of [`Self::WORDS`].
    const VARIANTS: &'static [Self];
    /// The words that name them.
    const WORDS: &'static [&'static str];

    /// Position of `self` in [`Self::VARIANTS`].
    fn index(self) -> usize {
        Self::VARIANTS
            .iter()
            .position(|v| *v == self)
            .unwrap_or_default()
    }

    /// The word of `self`.
    fn word(self) -> &'static str {
        Self::WORDS.get(self.index()).copied().unwrap_or_default()
    }

    /// The variant a word names.
    fn from_word(word: &str) -> Option<Self> {
        let i = Self::WORDS.iter().position(|w| *w == word)?;
        Self::VARIANTS.get(i).copied()
    }
}

impl Choice for UncertaintyModel {
    const VARIANTS: &'static [Self] = &[Self::Paper, Self::Covariance];
    const WORDS: &'static [&'static str] = &["paper", "covariance"];
}

impl Choice for SyncMode {
    const VARIANTS: &'static [Self] = &[Self::Pps, Self::Free];
    const WORDS: &'static [&'static str] = &["pps", "free"];
}

impl Choice for Output {
    const VARIANTS: &'static [Self] = &[Self::Frames, Self::Mavlink];
    const WORDS: &'static [&'static str] = &["frames", "mavlink"];
}

impl Choice for TimeTagPps {
    const VARIANTS: &'static [Self] = &[Self::Previous, Self::Next];
    const WORDS: &'static [&'static str] = &["previous", "next"];
}

/// A field of [`Settings`] that a key reads and writes.
trait Field: Copy {
    fn to_value(self) -> Value;
    fn slot(&mut self) -> Slot<'_>;
}

/// A field of [`Settings`] to store a [`Value`] into (one `match` on the key finds it; the
/// storing is shared by all keys of a type).
enum Slot<'a> {
    F64(&'a mut f64),
    F32(&'a mut f32),
    U32(&'a mut u32),
    Word(&'a mut dyn WordField),
}

/// A [`Choice`] field set by the position of its word.
trait WordField {
    /// Sets the variant at `index` of [`Choice::VARIANTS`]; false when there is none.
    fn set_index(&mut self, index: usize) -> bool;
}

impl<T: Choice> WordField for T {
    fn set_index(&mut self, index: usize) -> bool {
        match T::VARIANTS.get(index) {
            Some(v) => {
                *self = *v;
                true
            }
            None => false,
        }
    }
}

impl Field for f64 {
    fn to_value(self) -> Value {
        Value::F64(self)
    }
    fn slot(&mut self) -> Slot<'_> {
        Slot::F64(self)
    }
}

impl Field for f32 {
    fn to_value(self) -> Value {
        Value::F32(self)
    }
    fn slot(&mut self) -> Slot<'_> {
        Slot::F32(self)
    }
}

impl Field for u32 {
    fn to_value(self) -> Value {
        Value::U32(self)
    }
    fn slot(&mut self) -> Slot<'_> {
        Slot::U32(self)
    }
}

impl<T: Choice> Field for T {
    fn to_value(self) -> Value {
        Value::Word(self.word())
    }
    fn slot(&mut self) -> Slot<'_> {
        Slot::Word(self)
    }
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
const TURN_CORR: Kind = Kind::F32 {
    min: 0.0,
    max: ChassisParams::MAX_KAPPA_DIFF_CORR,
};
const HARM: Kind = Kind::F32 {
    min: -ChassisParams::MAX_HARMONIC,
    max: ChassisParams::MAX_HARMONIC,
};
const SE: Kind = Kind::F32 {
    min: 0.0,
    max: GeometryUncertainty::MAX_SE,
};
const CORRELATION: Kind = Kind::F32 {
    min: -1.0,
    max: 1.0,
};
const D: ChassisParams = ChassisParams::DESIGNED;

/// Generates [`Key`], its tables, `Settings::get`/`put` and
/// [`Settings::DEFAULT`] from one entry per key.
macro_rules! key_table {
    ($(
        $(#[doc = $doc:literal])+
        $variant:ident {
            name: $name:literal,
            unit: $unit:literal,
            kind: $kind:expr,
            default: $default:expr,
            field: [$($field:tt)+],
            record: $offset:literal since $since:literal,
            group: $group:ident $(,)?
        }
    )+) => {
        /// A settings key.
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum Key {
            $( $(#[doc = $doc])+ $variant, )+
        }

        /// Every key's [`KeyInfo`], in the order of [`Key::ALL`].
        pub const KEY_TABLE: [KeyInfo; Key::COUNT] = [$(
            KeyInfo {
                name: $name,
                kind: $kind,
                unit: $unit,
                group: Group::$group,
                record: RecordField { offset: $offset, since: $since },
            },
        )+];

        /// The table as the firmware reads it: the same entries with each [`Kind`] behind a
        /// reference (shared between keys of one kind; a third of the flash of
        /// [`KEY_TABLE`]).
        static ENTRIES: [Entry; Key::COUNT] = [$(
            Entry {
                name: $name,
                kind: &$kind,
                unit: unit_index($unit),
                group: Group::$group,
                offset: $offset,
                since: $since,
            },
        )+];

        impl Key {
            /// Number of keys.
            pub const COUNT: usize = [$(Key::$variant),+].len();

            /// Every key, in the order `get` lists them.
            pub const ALL: [Key; Self::COUNT] = [$(Key::$variant),+];

            /// What the key means (its documentation, for host tools).
            pub fn doc(self) -> &'static str {
                match self {
                    $( Key::$variant => concat!($($doc),+).trim_ascii(), )+
                }
            }
        }

        impl Settings {
            /// The defaults, one per key: the paper's designed chassis
            /// ([`ChassisParams::DESIGNED`]), free-running at 50 Hz, every sample sent, NMEA
            /// time refers to the previous PPS edge, 115200 baud, wheels at most at 2 m/s.
            pub const DEFAULT: Self = {
                let mut s = Settings::UNSET;
                $( s.$($field)+ = $default; )+
                s
            };

            /// The value of `key`.
            pub fn get(&self, key: Key) -> Value {
                match key {
                    $( Key::$variant => Field::to_value(self.$($field)+), )+
                }
            }

            /// Stores `value` (of the key's type, unchecked) as `key`; `None` when the value
            /// has another type or names no variant.
            pub(super) fn put(&mut self, key: Key, value: Value) -> Option<()> {
                let slot = match key {
                    $( Key::$variant => Field::slot(&mut self.$($field)+), )+
                };
                match (slot, value) {
                    (Slot::F64(p), Value::F64(v)) => *p = v,
                    (Slot::F32(p), Value::F32(v)) => *p = v,
                    (Slot::U32(p), Value::U32(v)) => *p = v,
                    (Slot::Word(p), Value::Word(w)) => {
                        let Kind::Word(words) = *key.kind() else {
                            return None;
                        };
                        let i = words.iter().position(|x| *x == w)?;
                        p.set_index(i).then_some(())?;
                    }
                    _ => return None,
                }
                Some(())
            }
        }
    };
}

key_table! {
    /// `left_diameter`: effective diameter of wheel 1 (left), metres.
    LeftDiameter {
        name: "left_diameter", unit: "m", kind: LEN, default: D.left_diameter,
        field: [chassis.left_diameter], record: 0 since 1, group: Chassis,
    }
    /// `right_diameter`: effective diameter of wheel 2 (right), metres.
    RightDiameter {
        name: "right_diameter", unit: "m", kind: LEN, default: D.right_diameter,
        field: [chassis.right_diameter], record: 8 since 1, group: Chassis,
    }
    /// `track_width`: distance between the wheels' contact points, metres.
    TrackWidth {
        name: "track_width", unit: "m", kind: LEN, default: D.track_width,
        field: [chassis.track_width], record: 16 since 1, group: Chassis,
    }
    /// `ticks_per_rev`: encoder increments per wheel turn after x4 decoding.
    TicksPerRev {
        name: "ticks_per_rev", unit: "increments/turn",
        kind: Kind::U32 {
            min: *ChassisParams::TICKS_PER_REV_RANGE.start(),
            max: *ChassisParams::TICKS_PER_REV_RANGE.end(),
        },
        default: D.ticks_per_rev,
        field: [chassis.ticks_per_rev], record: 24 since 1, group: Chassis,
    }
    /// `delta_left`: uncertainty coefficient of wheel 1, metres per increment (eq 19).
    DeltaLeft {
        name: "delta_left", unit: "m/increment", kind: DELTA, default: D.delta_left,
        field: [chassis.delta_left], record: 28 since 1, group: Chassis,
    }
    /// `delta_right`: uncertainty coefficient of wheel 2, metres per increment.
    DeltaRight {
        name: "delta_right", unit: "m/increment", kind: DELTA, default: D.delta_right,
        field: [chassis.delta_right], record: 32 since 1, group: Chassis,
    }
    /// `delta_diff`: uncertainty of opposite-phase slip, metres per increment of the
    /// difference (0: the paper's model).
    DeltaDiff {
        name: "delta_diff", unit: "m/increment", kind: DELTA, default: D.delta_diff,
        field: [chassis.delta_diff], record: 36 since 1, group: Chassis,
    }
    /// `uncertainty_model`: `paper` (eqs 19-28) or `covariance` (Chong & Kleeman).
    UncertaintyModel {
        name: "uncertainty_model", unit: "", kind: Kind::Word(UncertaintyModel::WORDS),
        default: D.uncertainty_model,
        field: [chassis.uncertainty_model], record: 96 since 1, group: Chassis,
    }
    /// `kappa_left`: covariance model, variance of wheel 1's distance per metre, m^2/m.
    KappaLeft {
        name: "kappa_left", unit: "m^2/m", kind: KAPPA, default: D.kappa_left,
        field: [chassis.kappa_left], record: 40 since 1, group: Chassis,
    }
    /// `kappa_right`: covariance model, variance of wheel 2's distance per metre, m^2/m.
    KappaRight {
        name: "kappa_right", unit: "m^2/m", kind: KAPPA, default: D.kappa_right,
        field: [chassis.kappa_right], record: 44 since 1, group: Chassis,
    }
    /// `kappa_diff`: covariance model, variance of opposite-phase slip per metre of
    /// wheel-distance difference, m^2/m.
    KappaDiff {
        name: "kappa_diff", unit: "m^2/m", kind: KAPPA, default: D.kappa_diff,
        field: [chassis.kappa_diff], record: 140 since 3, group: Chassis,
    }
    /// `kappa_diff_corr`: covariance model, correlation length of the opposite-phase slip,
    /// metres of wheel-distance difference (0, or below 0.001: white).
    KappaDiffCorr {
        name: "kappa_diff_corr", unit: "m", kind: TURN_CORR, default: D.kappa_diff_corr,
        field: [chassis.kappa_diff_corr], record: 144 since 4, group: Chassis,
    }
    /// `left_cos1`: wheel 1's radius function, first cosine harmonic (relative).
    LeftCos1 {
        name: "left_cos1", unit: "", kind: HARM, default: D.left_wheel.cos[0],
        field: [chassis.left_wheel.cos[0]], record: 48 since 1, group: Chassis,
    }
    /// `left_cos2`: wheel 1's radius function, second cosine harmonic (relative).
    LeftCos2 {
        name: "left_cos2", unit: "", kind: HARM, default: D.left_wheel.cos[1],
        field: [chassis.left_wheel.cos[1]], record: 52 since 1, group: Chassis,
    }
    /// `left_cos3`: wheel 1's radius function, third cosine harmonic (relative).
    LeftCos3 {
        name: "left_cos3", unit: "", kind: HARM, default: D.left_wheel.cos[2],
        field: [chassis.left_wheel.cos[2]], record: 56 since 1, group: Chassis,
    }
    /// `left_sin1`: wheel 1's radius function, first sine harmonic (relative).
    LeftSin1 {
        name: "left_sin1", unit: "", kind: HARM, default: D.left_wheel.sin[0],
        field: [chassis.left_wheel.sin[0]], record: 60 since 1, group: Chassis,
    }
    /// `left_sin2`: wheel 1's radius function, second sine harmonic (relative).
    LeftSin2 {
        name: "left_sin2", unit: "", kind: HARM, default: D.left_wheel.sin[1],
        field: [chassis.left_wheel.sin[1]], record: 64 since 1, group: Chassis,
    }
    /// `left_sin3`: wheel 1's radius function, third sine harmonic (relative).
    LeftSin3 {
        name: "left_sin3", unit: "", kind: HARM, default: D.left_wheel.sin[2],
        field: [chassis.left_wheel.sin[2]], record: 68 since 1, group: Chassis,
    }
    /// `right_cos1`: wheel 2's radius function, first cosine harmonic (relative).
    RightCos1 {
        name: "right_cos1", unit: "", kind: HARM, default: D.right_wheel.cos[0],
        field: [chassis.right_wheel.cos[0]], record: 72 since 1, group: Chassis,
    }
    /// `right_cos2`: wheel 2's radius function, second cosine harmonic (relative).
    RightCos2 {
        name: "right_cos2", unit: "", kind: HARM, default: D.right_wheel.cos[1],
        field: [chassis.right_wheel.cos[1]], record: 76 since 1, group: Chassis,
    }
    /// `right_cos3`: wheel 2's radius function, third cosine harmonic (relative).
    RightCos3 {
        name: "right_cos3", unit: "", kind: HARM, default: D.right_wheel.cos[2],
        field: [chassis.right_wheel.cos[2]], record: 80 since 1, group: Chassis,
    }
    /// `right_sin1`: wheel 2's radius function, first sine harmonic (relative).
    RightSin1 {
        name: "right_sin1", unit: "", kind: HARM, default: D.right_wheel.sin[0],
        field: [chassis.right_wheel.sin[0]], record: 84 since 1, group: Chassis,
    }
    /// `right_sin2`: wheel 2's radius function, second sine harmonic (relative).
    RightSin2 {
        name: "right_sin2", unit: "", kind: HARM, default: D.right_wheel.sin[1],
        field: [chassis.right_wheel.sin[1]], record: 88 since 1, group: Chassis,
    }
    /// `right_sin3`: wheel 2's radius function, third sine harmonic (relative).
    RightSin3 {
        name: "right_sin3", unit: "", kind: HARM, default: D.right_wheel.sin[2],
        field: [chassis.right_wheel.sin[2]], record: 92 since 1, group: Chassis,
    }
    /// `left_diameter_se`: standard error of `left_diameter` from the calibration, metres (covariance model).
    LeftDiameterSe {
        name: "left_diameter_se", unit: "m", kind: SE, default: D.geometry_uncertainty.left_diameter_se,
        field: [chassis.geometry_uncertainty.left_diameter_se], record: 116 since 3, group: Chassis,
    }
    /// `right_diameter_se`: standard error of `right_diameter` from the calibration, metres.
    RightDiameterSe {
        name: "right_diameter_se", unit: "m", kind: SE, default: D.geometry_uncertainty.right_diameter_se,
        field: [chassis.geometry_uncertainty.right_diameter_se], record: 120 since 3, group: Chassis,
    }
    /// `track_width_se`: standard error of `track_width` from the calibration, metres.
    TrackWidthSe {
        name: "track_width_se", unit: "m", kind: SE, default: D.geometry_uncertainty.track_width_se,
        field: [chassis.geometry_uncertainty.track_width_se], record: 124 since 3, group: Chassis,
    }
    /// `diameters_correlation`: correlation of the two diameters' calibration errors.
    DiametersCorrelation {
        name: "diameters_correlation", unit: "", kind: CORRELATION, default: D.geometry_uncertainty.diameters_correlation,
        field: [chassis.geometry_uncertainty.diameters_correlation], record: 128 since 3, group: Chassis,
    }
    /// `left_track_correlation`: correlation of `left_diameter`'s and `track_width`'s calibration errors.
    LeftTrackCorrelation {
        name: "left_track_correlation", unit: "", kind: CORRELATION, default: D.geometry_uncertainty.left_track_correlation,
        field: [chassis.geometry_uncertainty.left_track_correlation], record: 132 since 3, group: Chassis,
    }
    /// `right_track_correlation`: correlation of `right_diameter`'s and `track_width`'s calibration errors.
    RightTrackCorrelation {
        name: "right_track_correlation", unit: "", kind: CORRELATION, default: D.geometry_uncertainty.right_track_correlation,
        field: [chassis.geometry_uncertainty.right_track_correlation], record: 136 since 3, group: Chassis,
    }
    /// `mode`: `pps` (samples locked to the GNSS 1-PPS) or `free` (MCU clock alone).
    Mode {
        name: "mode", unit: "", kind: Kind::Word(SyncMode::WORDS), default: SyncMode::Free,
        field: [mode], record: 97 since 1, group: Unit,
    }
    /// `rate`: samples per second, Hz.
    Rate {
        name: "rate", unit: "Hz", kind: Kind::U32 { min: 1, max: MAX_RATE_HZ }, default: 50,
        field: [rate], record: 100 since 1, group: Unit,
    }
    /// `output_divider`: send every Nth sample as a record.
    OutputDivider {
        name: "output_divider", unit: "", kind: Kind::U32 { min: 1, max: 10_000 }, default: 1,
        field: [output_divider], record: 104 since 1, group: Unit,
    }
    /// `time_tag_pps`: the NMEA time message names the PPS edge before it (`previous`) or
    /// after it (`next`).
    TimeTagPps {
        name: "time_tag_pps", unit: "", kind: Kind::Word(TimeTagPps::WORDS),
        default: TimeTagPps::Previous,
        field: [time_tag_pps], record: 98 since 1, group: Unit,
    }
    /// `baud`: UART baud rate, bit/s (applied at the next start).
    Baud {
        name: "baud", unit: "bit/s", kind: Kind::U32Set(&BAUD_RATES), default: 115_200,
        field: [baud], record: 108 since 1, group: Unit,
    }
    /// `max_wheel_speed`: the highest surface speed either wheel is stated to reach, m/s.
    MaxWheelSpeed {
        name: "max_wheel_speed", unit: "m/s",
        kind: Kind::F32 {
            min: Settings::MAX_WHEEL_SPEED_RANGE.0,
            max: Settings::MAX_WHEEL_SPEED_RANGE.1,
        },
        default: Settings::DEFAULT_MAX_WHEEL_SPEED,
        field: [max_wheel_speed], record: 112 since 2, group: Unit,
    }
    /// `output`: what the host link streams: `frames` (pose records and Status, docs/PROTOCOL.md)
    /// or `mavlink` (MAVLink 2 `ODOMETRY` and `HEARTBEAT` for a flight controller,
    /// docs/MAVLINK.md); replies to commands are frames either way.
    Output {
        name: "output", unit: "", kind: Kind::Word(Output::WORDS), default: Output::Frames,
        field: [output], record: 99 since 5, group: Unit,
    }
    /// `mavlink_sysid`: MAVLink system id of the unit's frames (the vehicle's, as the flight
    /// controller's `SYSID_THISMAV` / `MAV_SYS_ID`).
    MavlinkSysid {
        name: "mavlink_sysid", unit: "", kind: Kind::U32 { min: 1, max: 255 }, default: 1,
        field: [mavlink_sysid], record: 148 since 5, group: Unit,
    }
    /// `mavlink_compid`: MAVLink component id of the unit's frames (197,
    /// `MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY`, by default).
    MavlinkCompid {
        name: "mavlink_compid", unit: "", kind: Kind::U32 { min: 1, max: 255 }, default: 197,
        field: [mavlink_compid], record: 152 since 5, group: Unit,
    }
    /// `gnss_baud`: baud rate of the GNSS receiver's NMEA output (USART1), bit/s (applied at
    /// the next start).
    GnssBaud {
        name: "gnss_baud", unit: "bit/s", kind: Kind::U32Set(&BAUD_RATES), default: 38_400,
        field: [gnss_baud], record: 156 since 6, group: Unit,
    }
}

/// An entry of the firmware's copy of the key table (16 bytes on the target).
struct Entry {
    name: &'static str,
    kind: &'static Kind,
    /// Index in [`UNITS`].
    unit: u8,
    group: Group,
    offset: u8,
    since: u8,
}

/// The units of the keys, each once.
const UNITS: [&str; 8] = [
    "",
    "m",
    "increments/turn",
    "m/increment",
    "m^2/m",
    "Hz",
    "bit/s",
    "m/s",
];

/// Index of `unit` in [`UNITS`] (a unit missing there fails the build).
const fn unit_index(unit: &str) -> u8 {
    let mut i = 0;
    while i < UNITS.len() {
        let (a, b) = (UNITS[i].as_bytes(), unit.as_bytes());
        let mut same = a.len() == b.len();
        let mut j = 0;
        while same && j < a.len() {
            same = a[j] == b[j];
            j += 1;
        }
        if same {
            return i as u8;
        }
        i += 1;
    }
    panic!("a key's unit is missing from UNITS")
}

impl Key {
    /// Name, type, unit and record place.
    pub fn info(self) -> KeyInfo {
        static UNIT_TEXT: [&str; UNITS.len()] = UNITS;
        let e = &ENTRIES[self as usize];
        KeyInfo {
            name: e.name,
            kind: *e.kind,
            unit: UNIT_TEXT
                .get(usize::from(e.unit))
                .copied()
                .unwrap_or_default(),
            group: e.group,
            record: RecordField {
                offset: e.offset,
                since: u16::from(e.since),
            },
        }
    }

    /// The shared key name.
    pub fn name(self) -> &'static str {
        ENTRIES[self as usize].name
    }

    /// Type and range (as [`KeyInfo::kind`]).
    pub fn kind(self) -> &'static Kind {
        ENTRIES[self as usize].kind
    }

    /// The key of a name (exact, case-sensitive).
    pub fn from_name(name: &str) -> Option<Key> {
        Key::ALL.into_iter().find(|k| k.name() == name)
    }
}
