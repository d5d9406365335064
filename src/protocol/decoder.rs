//! Streaming frame decoder with resynchronisation and loss accounting.

use super::{decode_frame, DecodeError, Frame, MAX_WIRE_FRAME};

/// Counters kept by a [`FrameDecoder`] (all wrapping).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DecoderStats {
    /// Frames decoded successfully.
    pub frames: u32,
    /// Frames with a CRC mismatch.
    pub crc_errors: u32,
    /// Runs of more than [`MAX_WIRE_FRAME`] bytes between delimiters.
    pub oversize: u32,
    /// Invalid COBS, too short, length mismatch or a field outside its set.
    pub malformed: u32,
    /// Frames of another protocol version.
    pub version_errors: u32,
    /// Valid frames of an unknown message type (skipped).
    pub unknown_type: u32,
    /// Times the header sequence did not follow the previous valid frame's.
    pub seq_gaps: u32,
    /// Frames missing according to the sequence numbers (jumps forward by less than 2^31;
    /// larger jumps, such as a restart of the unit, count as a gap only).
    pub frames_lost: u32,
    /// Bytes before the first delimiter after [`FrameDecoder::new`] or
    /// [`FrameDecoder::reset`] that did not decode as a frame: the tail of a frame that was
    /// under way when the receiver joined the stream (not an error of the link).
    pub join_bytes: u32,
}

/// Streaming decoder: feed it the received bytes in any chunking; it returns each frame as
/// its delimiter arrives. The run before the first 0x00 is decoded like any other, but if it
/// fails it is the tail of a frame that was under way when the receiver joined the stream:
/// discarded and counted in [`DecoderStats::join_bytes`], not as an error. After garbage or a corrupted frame it resynchronises at the
/// next 0x00. Memory is fixed: one buffer of [`MAX_WIRE_FRAME`] bytes.
#[derive(Debug, Clone)]
pub struct FrameDecoder {
    buf: [u8; MAX_WIRE_FRAME],
    len: usize,
    overflow: bool,
    /// A delimiter has been seen since `new`/`reset`.
    joined: bool,
    last_seq: Option<u32>,
    stats: DecoderStats,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_WIRE_FRAME],
            len: 0,
            overflow: false,
            joined: false,
            last_seq: None,
            stats: DecoderStats {
                frames: 0,
                crc_errors: 0,
                oversize: 0,
                malformed: 0,
                version_errors: 0,
                unknown_type: 0,
                seq_gaps: 0,
                frames_lost: 0,
                join_bytes: 0,
            },
        }
    }

    /// The counters so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Forgets any partial frame and the last sequence number, and joins the stream anew at
    /// the next delimiter (counters are kept).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = false;
        self.joined = false;
        self.last_seq = None;
    }

    /// Feeds one byte. Returns `Some` when a delimiter ends a non-empty run: the frame, or
    /// why it was rejected (already counted in [`Self::stats`]).
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, DecodeError>> {
        if byte != 0 {
            if self.len < MAX_WIRE_FRAME {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
                if !self.joined {
                    self.stats.join_bytes = self.stats.join_bytes.wrapping_add(1);
                }
            }
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        let joining = !core::mem::replace(&mut self.joined, true);
        if core::mem::replace(&mut self.overflow, false) {
            if joining {
                self.stats.join_bytes = self.stats.join_bytes.wrapping_add(len as u32);
                return None;
            }
            self.stats.oversize = self.stats.oversize.wrapping_add(1);
            return Some(Err(DecodeError::Oversize));
        }
        if len == 0 {
            return None;
        }
        let result = decode_frame(&mut self.buf[..len]);
        if joining && result.is_err() {
            self.stats.join_bytes = self.stats.join_bytes.wrapping_add(len as u32);
            return None;
        }
        match &result {
            Ok(frame) => {
                self.stats.frames = self.stats.frames.wrapping_add(1);
                self.track_seq(frame.seq);
            }
            Err(e) => {
                let s = &mut self.stats;
                match e {
                    DecodeError::Crc => s.crc_errors = s.crc_errors.wrapping_add(1),
                    DecodeError::Oversize => s.oversize = s.oversize.wrapping_add(1),
                    DecodeError::Version(_) => s.version_errors = s.version_errors.wrapping_add(1),
                    DecodeError::UnknownType(_) => {
                        s.unknown_type = s.unknown_type.wrapping_add(1);
                    }
                    DecodeError::Cobs
                    | DecodeError::TooShort
                    | DecodeError::BodyTooShort(_)
                    | DecodeError::BadField(_) => s.malformed = s.malformed.wrapping_add(1),
                }
                // A frame that passed the CRC still tells where the sequence is.
                if matches!(
                    e,
                    DecodeError::UnknownType(_)
                        | DecodeError::BodyTooShort(_)
                        | DecodeError::BadField(_)
                ) {
                    if let Some(seq) = raw_seq(&self.buf[..len]) {
                        self.track_seq(seq);
                    }
                }
            }
        }
        Some(result)
    }

    /// Feeds a chunk of bytes, calling `f` for every frame or rejected frame.
    pub fn feed(&mut self, bytes: &[u8], mut f: impl FnMut(Result<Frame, DecodeError>)) {
        for &b in bytes {
            if let Some(r) = self.push(b) {
                f(r);
            }
        }
    }

    fn track_seq(&mut self, seq: u32) {
        if let Some(last) = self.last_seq {
            let expected = last.wrapping_add(1);
            if seq != expected {
                self.stats.seq_gaps = self.stats.seq_gaps.wrapping_add(1);
                let jump = seq.wrapping_sub(expected);
                if jump < 0x8000_0000 {
                    self.stats.frames_lost = self.stats.frames_lost.wrapping_add(jump);
                }
            }
        }
        self.last_seq = Some(seq);
    }
}

/// Sequence number of a frame already COBS-decoded in place by `decode_frame` (which leaves
/// the raw frame at the start of the buffer).
fn raw_seq(decoded: &[u8]) -> Option<u32> {
    let b = decoded.get(4..8)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}
