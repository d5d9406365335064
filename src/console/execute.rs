//! A parsed command applied to the working settings: the reply and what is left to the
//! firmware.

use super::parse::{parse, Command, CommandError};
use super::MAX_REPLY;
use crate::bytes::Text;
use crate::settings::{Key, SetManyError, Settings};
use core::fmt::Write;
use heapless::String;

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
        Self::error_args(format_args!("{what}"))
    }

    /// [`Reply::error`] of formatted text (one copy for every caller).
    #[inline(never)]
    fn error_args(what: core::fmt::Arguments<'_>) -> Self {
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
    /// Appends what fits of `s`, whole characters only; an error when not all did.
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let mut end = s.len().min(N - self.0.len());
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        match s.get(..end).map(|head| self.0.push_str(head)) {
            Some(Ok(())) if end == s.len() => Ok(()),
            _ => Err(core::fmt::Error),
        }
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
                Some(k) => r.push_line(format_args!("{} = {}", Text(k.name()), settings.get(k))),
                None => {
                    for k in Key::ALL {
                        r.push_line(format_args!("{} = {}", Text(k.name()), settings.get(k)));
                    }
                }
            }
            (r, Action::None)
        }
        Command::Defaults => {
            // Bitwise (the stored record), so that -0 against 0 counts as a change.
            let changed = settings.to_bytes() != Settings::DEFAULT.to_bytes();
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
                        r.push_line(format_args!("{} = {}", Text(k.name()), settings.get(*k)));
                    }
                    // Bitwise (the stored record): `set left_cos1 -0` changes the bytes and
                    // the checksum though -0.0 == 0.0.
                    let action = if settings.to_bytes() != before.to_bytes() {
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
        r.push_line(format_args!("{}", Text(line)));
    }
    for k in Key::ALL {
        let info = k.info();
        r.push_line(format_args!(
            "  {} {} {}",
            Text(info.name),
            Text(info.unit),
            info.kind
        ));
    }
    r
}
