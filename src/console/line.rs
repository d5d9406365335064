//! Bytes from the host link to command lines.

use super::MAX_LINE;
use crate::decimal::Dec;
use heapless::{String, Vec};

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
            Self::TooLong => write!(f, "line too long (max {} bytes)", Dec(MAX_LINE as u64)),
            Self::BadEncoding => f.write_str("line is not valid UTF-8"),
        }
    }
}

/// Decodes `bytes` as UTF-8, handing each character to `put` (which returns false to stop);
/// true when all of `bytes` is well-formed UTF-8 (RFC 3629: shortest forms only, no
/// surrogates, at most U+10FFFF: what `core::str::from_utf8` accepts) and `put` took it all.
pub fn decode_utf8(bytes: &[u8], mut put: impl FnMut(char) -> bool) -> bool {
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        // Continuation bytes after the lead, the range of the first of them, the lead's bits.
        let (n, lo, hi, lead) = match b {
            0x00..=0x7F => (0, 0, 0, u32::from(b)),
            0xC2..=0xDF => (1, 0x80, 0xBF, u32::from(b & 0x1F)),
            0xE0 => (2, 0xA0, 0xBF, 0),
            0xE1..=0xEC | 0xEE..=0xEF => (2, 0x80, 0xBF, u32::from(b & 0x0F)),
            0xED => (2, 0x80, 0x9F, 0x0D),
            0xF0 => (3, 0x90, 0xBF, 0),
            0xF1..=0xF3 => (3, 0x80, 0xBF, u32::from(b & 0x07)),
            0xF4 => (3, 0x80, 0x8F, 4),
            _ => return false,
        };
        let Some(tail) = bytes.get(i + 1..i + 1 + n) else {
            return false;
        };
        if tail.first().is_some_and(|c| !(lo..=hi).contains(c))
            || !tail.iter().all(|c| (0x80..=0xBF).contains(c))
        {
            return false;
        }
        let cp = tail
            .iter()
            .fold(lead, |cp, c| cp << 6 | u32::from(c & 0x3F));
        match char::from_u32(cp) {
            Some(c) if put(c) => {}
            _ => return false,
        }
        i += 1 + n;
    }
    true
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
    /// The finished line, decoded.
    text: String<MAX_LINE>,
    overflow: bool,
    complete: bool,
}

impl LineAssembler {
    /// An empty assembler.
    pub const fn new() -> Self {
        Self {
            buf: Vec::new(),
            text: String::new(),
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
                self.text.clear();
                let text = &mut self.text;
                // Decoded here rather than by `core::str::from_utf8` (and its 256-byte table).
                let ok = decode_utf8(&self.buf, |c| text.push(c).is_ok());
                Some(if ok {
                    Ok(self.text.as_str())
                } else {
                    Err(LineError::BadEncoding)
                })
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
