//! Bytes from the host link to command lines.

use super::MAX_LINE;
use heapless::Vec;

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
/// CR, LF and CRLF end a line; empty lines, and lines of only spaces and tabs, are ignored. Backspace (0x08) and DEL (0x7F)
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
                if self.buf.iter().all(|&b| b == b' ') {
                    // Empty, or blank (TAB is stored as a space): ignored like an empty line.
                    self.buf.clear();
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
