//! Forwarding of the GNSS receiver's position and time sentences to the host link
//! (GnssSentence frames, message type 0x05): which lines are forwarded, the room rule that
//! keeps them from displacing the pose stream, and their counters.
//!
//! A line ended by CR or LF is forwarded when it is one of the kinds in [`FORWARDED_KINDS`]
//! (any two-character talker), its checksum is present and right, and every byte is
//! printable ASCII. Its frame is queued only when the transmit ring keeps
//! [`sentence_reserve`] bytes free after it: the command reserve that pose records leave,
//! plus one Status and one pose record frame (the most the pose stream queues at its next
//! sample). Otherwise it is counted as not forwarded. Nothing is ever forwarded in part.

use crate::protocol::{cobs, GnssSentence, PoseRecord, Status, CRC_LEN, HEADER_LEN};
use crate::timing::NmeaError;
use heapless::String;

/// The sentence kinds forwarded (the three letters after the two-character talker).
pub const FORWARDED_KINDS: [&[u8; 3]; 5] = [b"GGA", b"GST", b"HDT", b"RMC", b"ZDA"];

/// Encoded size of a frame with a body of `body` bytes, delimiter included, bytes (the
/// longest COBS encoding).
pub const fn encoded_frame_len(body: usize) -> usize {
    cobs::max_encoded_len(HEADER_LEN + body + CRC_LEN) + 1
}

/// What the pose stream queues at most at one sample: a Status frame and a pose record
/// frame, encoded, bytes (106 + 114 = 220).
pub const POSE_STREAM_NEED: usize =
    encoded_frame_len(Status::BODY_LEN) + encoded_frame_len(PoseRecord::BODY_LEN);

// The settings' bandwidth budget counts the Status frame and the sentence frames as here.
const _: () = assert!(
    crate::settings::STATUS_FRAME_BITS as usize == encoded_frame_len(Status::BODY_LEN) * 10
);
const _: () = assert!(
    crate::settings::GNSS_SENTENCE_BYTES as usize + 30
        == encoded_frame_len(
            GnssSentence::FIXED_LEN + crate::settings::GNSS_SENTENCE_BYTES as usize
        )
);
const _: () = assert!(crate::settings::GNSS_FORWARD_BITS == 44_000);

/// Free bytes the transmit ring must keep after a GnssSentence frame for the frame to be
/// queued: `record_reserve` (the room pose records leave for command replies) plus
/// [`POSE_STREAM_NEED`].
pub const fn sentence_reserve(record_reserve: usize) -> usize {
    record_reserve + POSE_STREAM_NEED
}

/// True when `line` (from `$`, without the line ending) names one of [`FORWARDED_KINDS`]:
/// `$`, two talker characters, the kind, then `,` or `*`.
pub fn is_forwarded_kind(line: &[u8]) -> bool {
    match line {
        [b'$', t1, t2, a, b, c, b',' | b'*', ..] => {
            t1.is_ascii_alphanumeric()
                && t2.is_ascii_alphanumeric()
                && FORWARDED_KINDS.contains(&&[*a, *b, *c])
        }
        _ => false,
    }
}

/// Counters of the forwarding, since start (wrapping).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GnssCounters {
    /// Sentences queued as GnssSentence frames.
    pub forwarded: u32,
    /// Checksum-valid sentences of the forwarded kinds not queued: no room by the rule
    /// ([`sentence_reserve`]), or `output = mavlink`.
    pub not_forwarded: u32,
    /// Lines (any kind) whose checksum is missing or wrong, or that hold a byte outside
    /// printable ASCII.
    pub bad_checksum: u32,
    /// Lines longer than the line buffer ([`crate::protocol::MAX_SENTENCE_TEXT`] bytes),
    /// discarded.
    pub overlong: u32,
}

/// Decides which received lines become GnssSentence frames, numbers them and counts.
#[derive(Debug, Clone, Default)]
pub struct Forwarder {
    number: u32,
    counters: GnssCounters,
}

impl Forwarder {
    /// No sentence received yet.
    pub const fn new() -> Self {
        Self {
            number: 0,
            counters: GnssCounters {
                forwarded: 0,
                not_forwarded: 0,
                bad_checksum: 0,
                overlong: 0,
            },
        }
    }

    /// The counters.
    pub fn counters(&self) -> GnssCounters {
        self.counters
    }

    /// A line ended: `parsed` is what the line buffer made of it, `line` its text (from `$`,
    /// no line ending), `mcu_time_us` the unit time of its line ending. `forwarding`: the
    /// link carries our frames (`output = frames`). Returns the frame to queue; the caller
    /// reports whether it was queued with [`Self::sent`].
    pub fn on_line(
        &mut self,
        parsed: &Result<impl Sized, NmeaError>,
        line: &[u8],
        mcu_time_us: u64,
        forwarding: bool,
    ) -> Option<GnssSentence> {
        let c = &mut self.counters;
        match parsed {
            Err(NmeaError::Overflow) => {
                c.overlong = c.overlong.wrapping_add(1);
                return None;
            }
            Err(NmeaError::BadChecksum { .. } | NmeaError::NoChecksum) => {
                c.bad_checksum = c.bad_checksum.wrapping_add(1);
                return None;
            }
            Err(NmeaError::NoStart) => return None,
            _ => {}
        }
        if !is_forwarded_kind(line) {
            return None;
        }
        if !line.iter().all(|b| (0x20..0x7f).contains(b)) {
            c.bad_checksum = c.bad_checksum.wrapping_add(1);
            return None;
        }
        let number = self.number;
        self.number = self.number.wrapping_add(1);
        let mut text = String::new();
        // Printable ASCII is UTF-8; the line buffer holds at most MAX_SENTENCE_TEXT bytes.
        let fits = line.iter().all(|&b| text.push(b as char).is_ok());
        if !forwarding || !fits {
            c.not_forwarded = c.not_forwarded.wrapping_add(1);
            return None;
        }
        Some(GnssSentence {
            mcu_time_us,
            number,
            text,
        })
    }

    /// The frame [`Self::on_line`] returned was queued (true) or found no room (false).
    pub fn sent(&mut self, queued: bool) {
        let c = &mut self.counters;
        if queued {
            c.forwarded = c.forwarded.wrapping_add(1);
        } else {
            c.not_forwarded = c.not_forwarded.wrapping_add(1);
        }
    }
}
