//! Text commands from the host (`docs/PROTOCOL.md`, "Commands").
//!
//! Host -> unit: plain text lines (ASCII/UTF-8, ended by CR, LF or CRLF), which a person can
//! type in a terminal. Unit -> host: each line is answered by one or more
//! [`super::CommandReply`] frames whose text starts with `ok` or `error: <what was wrong>`.
//! A command that fails changes nothing.
//!
//! The firmware feeds UART bytes to a [`LineAssembler`], passes each line to [`execute`]
//! together with its working [`Settings`], performs the returned [`Action`] (which may
//! rewrite the reply, for example when `save` fails) and sends the reply with
//! [`super::CommandReply::chunks`].

use crate::settings::{Key, SetManyError, SettingError, Settings};
use core::fmt::Write;
use heapless::{String, Vec};

/// Longest accepted command line, bytes (without its terminator).
pub const MAX_LINE: usize = 256;
/// Most `KEY VALUE` pairs in one `set`.
pub const MAX_SET_PAIRS: usize = 16;
/// Most whitespace-separated words in a line.
pub const MAX_WORDS: usize = 1 + 2 * MAX_SET_PAIRS;
/// Capacity of a reply text, bytes (sent in [`super::MAX_REPLY_TEXT`]-byte frames).
pub const MAX_REPLY: usize = 2560;

/// Why a received line was discarded by the [`LineAssembler`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineError {
    /// More than [`MAX_LINE`] bytes before the terminator; the whole line was dropped.
    TooLong,
    /// The line is not valid UTF-8.
    BadEncoding,
}

impl core::fmt::Display for LineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooLong => write!(f, "line too long (max {MAX_LINE} bytes)"),
            Self::BadEncoding => f.write_str("line is not valid UTF-8"),
        }
    }
}

/// Assembles lines from received bytes.
///
/// CR, LF and CRLF end a line; empty lines are ignored. Backspace (0x08) and DEL (0x7F)
/// remove the last byte; TAB counts as a space; other control bytes (including 0x00) are
/// ignored. A line longer than [`MAX_LINE`] is discarded up to its terminator and reported
/// once as [`LineError::TooLong`], so the next line is received intact. Memory is fixed.
#[derive(Debug, Clone, Default)]
pub struct LineAssembler {
    buf: Vec<u8, MAX_LINE>,
    overflow: bool,
    complete: bool,
}

impl LineAssembler {
    /// An empty assembler.
    pub const fn new() -> Self {
        Self {
            buf: Vec::new(),
            overflow: false,
            complete: false,
        }
    }

    /// Feeds one byte; returns a finished line (valid until the next call) or an error.
    pub fn push(&mut self, byte: u8) -> Option<Result<&str, LineError>> {
        if self.complete {
            self.buf.clear();
            self.complete = false;
        }
        match byte {
            b'\r' | b'\n' => {
                if core::mem::replace(&mut self.overflow, false) {
                    self.buf.clear();
                    return Some(Err(LineError::TooLong));
                }
                if self.buf.is_empty() {
                    return None;
                }
                self.complete = true;
                Some(core::str::from_utf8(&self.buf).map_err(|_| LineError::BadEncoding))
            }
            0x08 | 0x7F => {
                if !self.overflow {
                    self.buf.pop();
                }
                None
            }
            b'\t' => self.store(b' '),
            0x00..=0x1F => None,
            _ => self.store(byte),
        }
    }

    fn store(&mut self, byte: u8) -> Option<Result<&str, LineError>> {
        if !self.overflow && self.buf.push(byte).is_err() {
            self.overflow = true;
        }
        None
    }
}

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
    /// The line was dropped by the [`LineAssembler`].
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
}

impl core::fmt::Display for CommandError<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Line(e) => e.fmt(f),
            Self::UnknownCommand(c) => write!(f, "unknown command '{c}' (try help)"),
            Self::UnknownKey(k) => write!(f, "unknown key '{k}' (try help)"),
            Self::MissingArgument(u) => write!(f, "missing argument, usage: {u}"),
            Self::MissingValue(k) => write!(f, "missing value for '{k}', usage: {USAGE_SET}"),
            Self::TooManyArguments(u) => write!(f, "too many arguments, usage: {u}"),
            Self::BadNumber(w) => write!(f, "bad number '{w}'"),
            Self::NotFinite(w) => write!(f, "NaN/inf not allowed: '{w}'"),
            Self::Setting(e) => e.fmt(f),
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
            [x, y, h] => Ok(Command::ResetPose {
                x: number(x)?,
                y: number(y)?,
                heading: number(h)?,
            }),
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

/// What the firmware must do after [`execute`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Nothing (the reply is complete).
    None,
    /// The working settings changed (already applied to the `Settings` passed in); apply
    /// them to the running integrator/timing. The reply is complete.
    SettingsChanged,
    /// Save the working settings to flash; on failure replace the reply by an error.
    Save,
    /// Set the pose to (x, y, heading) (metres, metres, radians); the reply is `ok`.
    ResetPose {
        /// x (east), metres.
        x: f64,
        /// y (north), metres.
        y: f64,
        /// Heading, radians.
        heading: f64,
    },
    /// Append `key = value` status lines to the reply (it holds `ok`).
    Status,
    /// Append the firmware and protocol version to the reply (it holds `ok`) and send a
    /// DeviceInfo frame.
    Version,
}

/// A reply being built: `ok` and its text.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Reply {
    /// Success.
    pub ok: bool,
    /// Text, first line `ok` or `error: ...`, lines separated by `\n`.
    pub text: String<MAX_REPLY>,
}

impl Reply {
    /// A reply `ok`.
    pub fn ok() -> Self {
        let mut text = String::new();
        let _ = text.push_str("ok");
        Self { ok: true, text }
    }

    /// A reply `error: <what>` (cut with `...` if longer than [`MAX_REPLY`]).
    pub fn error(what: impl core::fmt::Display) -> Self {
        let mut r = Self {
            ok: false,
            text: String::new(),
        };
        if write!(Truncating(&mut r.text), "error: {what}").is_err() {
            r.ellipsis();
        }
        r
    }

    fn ellipsis(&mut self) {
        while self.text.len() > MAX_REPLY - 3 {
            self.text.pop();
        }
        let _ = self.text.push_str("...");
    }

    /// Appends `\n` and a line; a line that does not fit is cut and the reply ends with
    /// `...`.
    pub fn push_line(&mut self, line: core::fmt::Arguments<'_>) {
        let mut w = Truncating(&mut self.text);
        if w.write_str("\n").and_then(|_| w.write_fmt(line)).is_err() {
            self.ellipsis();
        }
    }
}

/// `fmt::Write` into a heapless string that fails (keeping what fitted) when full.
struct Truncating<'a, const N: usize>(&'a mut String<N>);

impl<const N: usize> Write for Truncating<'_, N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            self.0.push(c).map_err(|_| core::fmt::Error)?;
        }
        Ok(())
    }
}

/// Parses and executes `line` against the working `settings`.
///
/// `get`, `set`, `mode`, `rate`, `defaults` and `help` are complete here; `save`, `status`,
/// `version` and `reset_pose` return an [`Action`] for the firmware. On any error the
/// reply starts with `error:` and `settings` is unchanged.
pub fn execute(line: &str, settings: &mut Settings) -> (Reply, Action) {
    let cmd = match parse(line) {
        Ok(c) => c,
        Err(e) => return (Reply::error(e), Action::None),
    };
    match cmd {
        Command::Help => (help(), Action::None),
        Command::Version => (Reply::ok(), Action::Version),
        Command::Status => (Reply::ok(), Action::Status),
        Command::Save => (Reply::ok(), Action::Save),
        Command::ResetPose { x, y, heading } => (Reply::ok(), Action::ResetPose { x, y, heading }),
        Command::Get(key) => {
            let mut r = Reply::ok();
            match key {
                Some(k) => r.push_line(format_args!("{} = {}", k.name(), settings.get(k))),
                None => {
                    for k in Key::ALL {
                        r.push_line(format_args!("{} = {}", k.name(), settings.get(k)));
                    }
                }
            }
            (r, Action::None)
        }
        Command::Defaults => {
            let changed = *settings != Settings::DEFAULT;
            *settings = Settings::DEFAULT;
            let mut r = Reply::ok();
            r.push_line(format_args!("defaults loaded (not saved; use save)"));
            (
                r,
                if changed {
                    Action::SettingsChanged
                } else {
                    Action::None
                },
            )
        }
        Command::Set(pairs) => {
            let before = *settings;
            match settings.set_many(pairs.iter().map(|(k, v)| (k.name(), *v))) {
                Ok(()) => {
                    let mut r = Reply::ok();
                    for (k, _) in &pairs {
                        r.push_line(format_args!("{} = {}", k.name(), settings.get(*k)));
                    }
                    let action = if *settings != before {
                        Action::SettingsChanged
                    } else {
                        Action::None
                    };
                    (r, action)
                }
                Err(SetManyError::UnknownKey(k)) => {
                    (Reply::error(CommandError::UnknownKey(k)), Action::None)
                }
                Err(SetManyError::Value(e)) => (
                    Reply::error(format_args!("{e}; nothing changed")),
                    Action::None,
                ),
            }
        }
    }
}

fn help() -> Reply {
    let mut r = Reply::ok();
    for line in [
        "commands (one per line; replies start with ok or error):",
        "  help | version | status",
        "  get [KEY]                      show one key or all",
        "  set KEY VALUE [KEY VALUE ...]  change keys together, all or none",
        "  mode pps|free                  = set mode ...",
        "  rate HZ                        = set rate ...",
        "  save                           store the working settings in flash",
        "  defaults                       load the defaults (then save to keep)",
        "  reset_pose [X Y HEADING]       metres, metres, radians (default 0 0 0)",
        "keys (unit, range):",
    ] {
        r.push_line(format_args!("{line}"));
    }
    for k in Key::ALL {
        let info = k.info();
        r.push_line(format_args!(
            "  {} {} {}",
            info.name,
            info.unit,
            RangeText(info.kind)
        ));
    }
    r
}

/// Displays the accepted values of a key kind.
struct RangeText(crate::settings::Kind);

impl core::fmt::Display for RangeText {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        use crate::settings::{Kind, Value};
        match self.0 {
            Kind::F64 { min, max } => write!(f, "{}..={}", Value::F64(min), Value::F64(max)),
            Kind::F32 { min, max } => write!(f, "{}..={}", Value::F32(min), Value::F32(max)),
            Kind::U32 { min, max } => write!(f, "{min}..={max}"),
            Kind::U32Set(set) => {
                for (i, v) in set.iter().enumerate() {
                    write!(f, "{}{v}", if i == 0 { "" } else { "|" })?;
                }
                Ok(())
            }
            Kind::Word(words) => {
                for (i, w) in words.iter().enumerate() {
                    write!(f, "{}{w}", if i == 0 { "" } else { "|" })?;
                }
                Ok(())
            }
        }
    }
}
