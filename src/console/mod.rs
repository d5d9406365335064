//! Text commands from the host (`docs/PROTOCOL.md`, "Commands").
//!
//! Host -> unit: plain text lines (ASCII/UTF-8, ended by CR, LF or CRLF), which a person can
//! type in a terminal. Unit -> host: each line is answered by one or more
//! [`crate::protocol::CommandReply`] frames whose text starts with `ok` or `error: <what was wrong>`.
//! A command that fails changes nothing.
//!
//! The firmware feeds UART bytes to a [`LineAssembler`], passes each line to [`execute()`]
//! together with its working [`Settings`](crate::settings::Settings), performs the returned [`Action`] (which may
//! rewrite the reply, for example when `save` fails) and sends the reply with
//! [`crate::protocol::CommandReply::chunks`].
//!
//! - [`line`](mod@line): bytes to lines ([`LineAssembler`]).
//! - [`parse`](mod@parse): a line to a [`Command`].
//! - [`execute`](mod@execute): a command applied to the working [`Settings`](crate::settings::Settings),
//!   with its [`Reply`] and the [`Action`] left to the firmware.

pub mod execute;
pub mod line;
pub mod parse;

pub use execute::{execute, Action, Reply};
pub use line::{LineAssembler, LineError};
pub use parse::{parse, Command, CommandError};

/// Longest accepted command line, bytes (without its terminator).
pub const MAX_LINE: usize = 256;
/// Most `KEY VALUE` pairs in one `set`.
pub const MAX_SET_PAIRS: usize = 16;
/// Most whitespace-separated words in a line.
pub const MAX_WORDS: usize = 1 + 2 * MAX_SET_PAIRS;
/// Capacity of a reply text, bytes (sent in [`crate::protocol::MAX_REPLY_TEXT`]-byte frames).
pub const MAX_REPLY: usize = 2560;
