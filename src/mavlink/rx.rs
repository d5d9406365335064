//! MAVLink bytes received on the host link (a flight controller's heartbeats and requests):
//! skipped before the command line assembler and counted, never answered.
//!
//! A frame starts with `0xFD` (MAVLink 2) or `0xFE` (MAVLink 1), bytes that never occur in a
//! command line (they are not UTF-8). From its length byte the frame's end is known: MAVLink
//! 2 has 9 header bytes after the start byte, the payload, 2 CRC bytes and 13 signature
//! bytes when incompatibility flag 0x01 is set; MAVLink 1 has 5 header bytes, the payload and
//! 2 CRC bytes. The frame is neither checked nor parsed: whatever it is (another system's,
//! a request, corrupted), the unit ignores it. A truncated frame takes the bytes after it as
//! its own, up to its length (at most 280 bytes).

use super::frame::{STX_V1, STX_V2};

/// Frames skipped since start (wrapping).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RxCounts {
    /// MAVLink 2 frames.
    pub v2: u32,
    /// MAVLink 1 frames.
    pub v1: u32,
}

/// Where the filter is in a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum State {
    /// Outside any frame: bytes go to the command line.
    #[default]
    Text,
    /// After a MAVLink 2 start byte: its length byte is next.
    Len2,
    /// After a MAVLink 2 length byte: the incompatibility flags are next.
    Flags2(u8),
    /// After a MAVLink 1 start byte: its length byte is next.
    Len1,
    /// Skipping the rest of a frame: bytes left (at least 1).
    Skip(u16),
}

/// Separates MAVLink frames from command text.
#[derive(Debug, Clone, Copy, Default)]
pub struct MavlinkRx {
    state: State,
    counts: RxCounts,
}

impl MavlinkRx {
    /// Outside any frame, nothing counted.
    pub const fn new() -> Self {
        Self {
            state: State::Text,
            counts: RxCounts { v2: 0, v1: 0 },
        }
    }

    /// Frames skipped so far.
    pub fn counts(&self) -> RxCounts {
        self.counts
    }

    /// One received byte: true when it is command text, false when it belongs to a frame.
    pub fn text(&mut self, byte: u8) -> bool {
        self.state = match self.state {
            State::Text if byte == STX_V2 => {
                self.counts.v2 = self.counts.v2.wrapping_add(1);
                State::Len2
            }
            State::Text if byte == STX_V1 => {
                self.counts.v1 = self.counts.v1.wrapping_add(1);
                State::Len1
            }
            State::Text => return true,
            State::Len2 => State::Flags2(byte),
            // 7 header bytes after the flags, the payload, the CRC, the signature.
            State::Flags2(len) => {
                State::Skip(7 + u16::from(len) + 2 + if byte & 0x01 != 0 { 13 } else { 0 })
            }
            // 4 header bytes after the length, the payload, the CRC.
            State::Len1 => State::Skip(4 + u16::from(byte) + 2),
            State::Skip(n) if n <= 1 => State::Text,
            State::Skip(n) => State::Skip(n - 1),
        };
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds `bytes`; returns the text bytes that came through.
    fn text(rx: &mut MavlinkRx, bytes: &[u8]) -> Vec<u8> {
        bytes.iter().copied().filter(|b| rx.text(*b)).collect()
    }

    #[test]
    fn frames_of_both_versions_are_skipped_whole_and_counted() {
        let mut rx = MavlinkRx::new();
        // MAVLink 2, 3-byte payload: 10 + 3 + 2 bytes.
        let mut v2 = vec![0xFD, 3, 0, 0, 1, 1, 1, 0, 0, 0, b'a', b'b', b'c', 9, 9];
        v2.extend_from_slice(b"get\n");
        assert_eq!(text(&mut rx, &v2), b"get\n");
        // Signed: 13 more bytes.
        let mut signed = vec![0xFD, 1, 1, 0, 1, 1, 1, 0, 0, 0, 0, 9, 9];
        signed.extend_from_slice(&[b'x'; 13]);
        signed.push(b'k');
        assert_eq!(text(&mut rx, &signed), b"k");
        // MAVLink 1, 2-byte payload: 6 + 2 + 2 bytes.
        let v1 = [0xFE, 2, 0, 1, 1, 0, b'p', b'q', 9, 9, b'z'];
        assert_eq!(text(&mut rx, &v1), b"z");
        assert_eq!(rx.counts(), RxCounts { v2: 2, v1: 1 });
    }
}
