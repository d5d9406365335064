//! A command line to a [`Command`] (no effect on anything).

use super::LineError;
use super::{MAX_SET_PAIRS, MAX_WORDS};
use crate::bytes::Text;
use crate::odometry::{Pose, PoseRangeError};
use crate::settings::{Key, SettingError};
use heapless::Vec;

/// A parsed command line.
// No allocator: the pairs of `Set` live inline; a `Command` only lives briefly on the stack.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Command<'a> {
    /// `help`: list commands and keys.
    Help,
    /// `version`: firmware and protocol version (the unit also sends a DeviceInfo frame).
    Version,
    /// `status`: state of the unit.
    Status,
    /// `get [KEY]`: one key, or all keys when `None`.
    Get(Option<Key>),
    /// `set KEY VALUE [KEY VALUE ...]`, also `mode M` and `rate HZ`: applied atomically.
    Set(Vec<(Key, &'a str), MAX_SET_PAIRS>),
    /// `save`: write the working settings to flash.
    Save,
    /// `defaults`: replace the working settings with the defaults (not saved until `save`).
    Defaults,
    /// `reset_pose [X Y HEADING]`: set the pose (metres, metres, radians; default 0 0 0).
    ResetPose {
        /// x (east), metres.
        x: f64,
        /// y (north), metres.
        y: f64,
        /// Heading, radians, 0 along +y, clockwise.
        heading: f64,
    },
}

/// Why a command line was rejected (nothing was changed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CommandError<'a> {
    /// The line was dropped by the [`LineAssembler`](super::LineAssembler).
    Line(LineError),
    /// The first word is not a command.
    UnknownCommand(&'a str),
    /// No key of that name.
    UnknownKey(&'a str),
    /// Too few arguments; the usage of the command.
    MissingArgument(&'static str),
    /// `set` names a key without a value (the key).
    MissingValue(&'a str),
    /// Too many arguments; the usage of the command.
    TooManyArguments(&'static str),
    /// Not a number (the word).
    BadNumber(&'a str),
    /// NaN or infinite (the word).
    NotFinite(&'a str),
    /// A value refused by the settings.
    Setting(SettingError),
    /// `reset_pose` with a coordinate the integrator cannot hold.
    PoseRange(PoseRangeError),
}

impl core::fmt::Display for CommandError<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Line(e) => e.fmt(f),
            Self::UnknownCommand(c) => write!(f, "unknown command '{}' (try help)", Text(c)),
            Self::UnknownKey(k) => write!(f, "unknown key '{}' (try help)", Text(k)),
            Self::MissingArgument(u) => write!(f, "missing argument, usage: {}", Text(u)),
            Self::MissingValue(k) => {
                write!(
                    f,
                    "missing value for '{}', usage: {}",
                    Text(k),
                    Text(USAGE_SET)
                )
            }
            Self::TooManyArguments(u) => write!(f, "too many arguments, usage: {}", Text(u)),
            Self::BadNumber(w) => write!(f, "bad number '{}'", Text(w)),
            Self::NotFinite(w) => write!(f, "NaN/inf not allowed: '{}'", Text(w)),
            Self::Setting(e) => e.fmt(f),
            Self::PoseRange(e) => write!(f, "reset_pose: {e}; pose unchanged"),
        }
    }
}

const USAGE_GET: &str = "get [KEY]";
const USAGE_SET: &str = "set KEY VALUE [KEY VALUE ...] (at most 16 pairs)";
const USAGE_RESET: &str = "reset_pose [X Y HEADING]";
const USAGE_MODE: &str = "mode pps|free";
const USAGE_RATE: &str = "rate HZ";

/// Parses one line (without terminator). Words are separated by spaces; command words and
/// keys are lower case and matched exactly.
pub fn parse(line: &str) -> Result<Command<'_>, CommandError<'_>> {
    let mut words: Vec<&str, MAX_WORDS> = Vec::new();
    let mut it = line.split_ascii_whitespace();
    let cmd = it.next().unwrap_or("");
    for w in it {
        if words.push(w).is_err() {
            return Err(CommandError::TooManyArguments(usage_of(cmd)));
        }
    }
    let no_args = |c: Command<'static>, usage| {
        if words.is_empty() {
            Ok(c)
        } else {
            Err(CommandError::TooManyArguments(usage))
        }
    };
    match cmd {
        "help" => no_args(Command::Help, "help"),
        "version" => no_args(Command::Version, "version"),
        "status" => no_args(Command::Status, "status"),
        "save" => no_args(Command::Save, "save"),
        "defaults" => no_args(Command::Defaults, "defaults"),
        "get" => match words.as_slice() {
            [] => Ok(Command::Get(None)),
            [k] => Key::from_name(k)
                .map(|k| Command::Get(Some(k)))
                .ok_or(CommandError::UnknownKey(k)),
            _ => Err(CommandError::TooManyArguments(USAGE_GET)),
        },
        "set" => {
            if words.is_empty() {
                return Err(CommandError::MissingArgument(USAGE_SET));
            }
            if words.len() % 2 != 0 {
                // A key without its value: name the key if it is one.
                let last = words[words.len() - 1];
                return Err(match Key::from_name(last) {
                    Some(_) => CommandError::MissingValue(last),
                    None => CommandError::UnknownKey(last),
                });
            }
            let mut pairs = Vec::new();
            for pair in words.chunks(2) {
                let k = Key::from_name(pair[0]).ok_or(CommandError::UnknownKey(pair[0]))?;
                pairs
                    .push((k, pair[1]))
                    .map_err(|_| CommandError::TooManyArguments(USAGE_SET))?;
            }
            Ok(Command::Set(pairs))
        }
        "mode" | "rate" => {
            let (key, usage) = if cmd == "mode" {
                (Key::Mode, USAGE_MODE)
            } else {
                (Key::Rate, USAGE_RATE)
            };
            match words.as_slice() {
                [] => Err(CommandError::MissingArgument(usage)),
                [v] => {
                    let mut pairs = Vec::new();
                    // One pair always fits.
                    let _ = pairs.push((key, *v));
                    Ok(Command::Set(pairs))
                }
                _ => Err(CommandError::TooManyArguments(usage)),
            }
        }
        "reset_pose" => match words.as_slice() {
            [] => Ok(Command::ResetPose {
                x: 0.0,
                y: 0.0,
                heading: 0.0,
            }),
            [x, y, h] => {
                let pose = Pose {
                    x: number(x)?,
                    y: number(y)?,
                    heading: number(h)?,
                };
                pose.check_range().map_err(CommandError::PoseRange)?;
                Ok(Command::ResetPose {
                    x: pose.x,
                    y: pose.y,
                    heading: pose.heading,
                })
            }
            [_] | [_, _] => Err(CommandError::MissingArgument(USAGE_RESET)),
            _ => Err(CommandError::TooManyArguments(USAGE_RESET)),
        },
        _ => Err(CommandError::UnknownCommand(cmd)),
    }
}

fn usage_of(cmd: &str) -> &'static str {
    match cmd {
        "set" => USAGE_SET,
        "get" => USAGE_GET,
        "reset_pose" => USAGE_RESET,
        "mode" => USAGE_MODE,
        "rate" => USAGE_RATE,
        _ => "help",
    }
}

fn number(w: &str) -> Result<f64, CommandError<'_>> {
    crate::decimal::parse_f64(w).map_err(|e| match e {
        crate::decimal::DecimalError::Invalid => CommandError::BadNumber(w),
        // NaN/inf words, or a literal too large for f64 such as 1e999.
        _ => CommandError::NotFinite(w),
    })
}
