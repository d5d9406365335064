//! The MAVLink 2 frame: `0xFD`, payload length, incompatibility and compatibility flags
//! (both 0: unsigned), sequence, system id, component id, message id (3 bytes, little
//! endian), the payload with its trailing zero bytes removed (the first byte is always
//! kept), and the CRC-16/MCRF4XX of everything after `0xFD` followed by the message's
//! `CRC_EXTRA` byte (little endian).

/// First byte of a MAVLink 2 frame.
pub const STX_V2: u8 = 0xFD;
/// First byte of a MAVLink 1 frame.
pub const STX_V1: u8 = 0xFE;
/// Header bytes after the start byte (MAVLink 2).
pub const HEADER_LEN: usize = 9;
/// Longest frame the unit sends: an untruncated `ODOMETRY`, 1 + 9 + 233 + 2 = 245 bytes.
pub const MAX_FRAME_LEN: usize = 1 + HEADER_LEN + super::odometry::ODOMETRY_LEN + 2;

/// A buffer for one frame and the `0x00` the firmware sends after it (the delimiter of our
/// own frames: a reader of our frames resynchronises before the next reply).
pub type FrameBuf = [u8; MAX_FRAME_LEN + 1];

/// A message's id and `CRC_EXTRA` (from the dialect's definition of its fields).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageId {
    /// Message id (24 bits).
    pub id: u32,
    /// `CRC_EXTRA` seed byte.
    pub crc_extra: u8,
}

/// The per-frame header fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    /// Sequence number (wraps at 256).
    pub seq: u8,
    /// System id.
    pub sysid: u8,
    /// Component id.
    pub compid: u8,
}

/// One step of CRC-16/MCRF4XX (the X.25 accumulate of MAVLink's `checksum.h`).
pub fn crc_accumulate(crc: u16, byte: u8) -> u16 {
    let mut t = byte ^ (crc as u8);
    t ^= t << 4;
    let t = u16::from(t);
    (crc >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4)
}

/// CRC-16/MCRF4XX of `bytes` (initial value 0xFFFF).
pub fn crc16(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0xFFFF, |c, b| crc_accumulate(c, *b))
}

/// Writes `payload` of message `msg` as a MAVLink 2 frame into `out`; returns the frame's
/// length. Trailing zero bytes of the payload are left out (at least one byte stays).
pub fn encode_frame(
    msg: &MessageId,
    payload: &[u8],
    header: FrameHeader,
    out: &mut FrameBuf,
) -> usize {
    let keep = payload.iter().rposition(|b| *b != 0).map_or(1, |i| i + 1);
    let len = keep.min(payload.len()).min(MAX_FRAME_LEN - HEADER_LEN - 3);
    let id = msg.id.to_le_bytes();
    out[..10].copy_from_slice(&[
        STX_V2,
        len as u8,
        0,
        0,
        header.seq,
        header.sysid,
        header.compid,
        id[0],
        id[1],
        id[2],
    ]);
    out[10..10 + len].copy_from_slice(&payload[..len]);
    let crc = crc_accumulate(crc16(&out[1..10 + len]), msg.crc_extra);
    out[10 + len..12 + len].copy_from_slice(&crc.to_le_bytes());
    12 + len
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_of_check_string() {
        // CRC-16/MCRF4XX check value.
        assert_eq!(crc16(b"123456789"), 0x6F91);
    }

    #[test]
    fn all_zero_payload_keeps_one_byte() {
        let mut out = [0u8; MAX_FRAME_LEN + 1];
        let msg = MessageId {
            id: 0,
            crc_extra: 50,
        };
        let h = FrameHeader {
            seq: 1,
            sysid: 2,
            compid: 3,
        };
        assert_eq!(encode_frame(&msg, &[0; 9], h, &mut out), 13);
        assert_eq!(out[1], 1);
    }
}
