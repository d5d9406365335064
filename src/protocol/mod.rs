//! Wire protocol between the unit and its host (byte layouts in `docs/PROTOCOL.md`).
//!
//! Unit -> host: binary frames. A frame is `header (8) | body | CRC-32 (4)`, COBS-encoded and
//! followed by one 0x00 delimiter. The CRC is CRC-32/ISO-HDLC ([`crate::crc`]) over header and body,
//! little-endian. The header is `version u8 | type u8 | body length u16 | sequence u32`,
//! little-endian; the sequence counts every frame the unit sends (all types, wrapping), so a
//! receiver can count lost frames.
//!
//! Host -> unit: plain text command lines (see [`crate::console`]); each line is answered by one or
//! more [`CommandReply`] frames.

pub mod cobs;
mod decoder;
mod messages;
pub mod reset_cause;
pub mod tx_ring;

pub use decoder::{DecoderStats, FrameDecoder};
pub use messages::{
    CommandReply, DeviceInfo, GnssSentence, GnssTime, PoseRecord, ReplyChunks, Status, StatusFlags,
    WheelStatus, MAX_FIRMWARE_VERSION, MAX_REPLY_TEXT, MAX_SENTENCE_TEXT,
};
pub use reset_cause::ResetCause;
pub use tx_ring::{Queued, TxLink, TxRing};

/// Protocol version carried in every header. Bumped on any incompatible change; appending
/// fields at the end of a body keeps the version (readers ignore extra bytes).
pub const PROTOCOL_VERSION: u8 = 1;

/// Header length, bytes.
pub const HEADER_LEN: usize = 8;
/// CRC trailer length, bytes.
pub const CRC_LEN: usize = 4;
/// Largest body this protocol version sends, bytes (a [`CommandReply`] with a full text).
pub const MAX_BODY_LEN: usize = CommandReply::FIXED_LEN + MAX_REPLY_TEXT;
/// Largest raw frame (header + body + CRC) this version sends, bytes.
pub const MAX_RAW_FRAME: usize = HEADER_LEN + MAX_BODY_LEN + CRC_LEN;
/// Largest encoded frame this version sends, including the 0x00 delimiter, bytes.
/// Size transmit buffers with this.
pub const MAX_ENCODED_FRAME: usize = cobs::max_encoded_len(MAX_RAW_FRAME) + 1;
/// Largest encoded frame (without delimiter) a receiver accepts, bytes: room for fields a
/// later minor revision may append. Longer runs between delimiters count as oversize.
pub const MAX_WIRE_FRAME: usize = 512;

/// Message type codes (header byte 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum MsgType {
    /// [`PoseRecord`].
    PoseRecord = 0x01,
    /// [`Status`].
    Status = 0x02,
    /// [`DeviceInfo`].
    DeviceInfo = 0x03,
    /// [`CommandReply`].
    CommandReply = 0x04,
    /// [`GnssSentence`].
    GnssSentence = 0x05,
}

impl MsgType {
    /// From the wire code.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0x01 => Some(Self::PoseRecord),
            0x02 => Some(Self::Status),
            0x03 => Some(Self::DeviceInfo),
            0x04 => Some(Self::CommandReply),
            0x05 => Some(Self::GnssSentence),
            _ => None,
        }
    }
}

/// Why a message could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// The output buffer is too small (use [`MAX_ENCODED_FRAME`]).
    BufferTooSmall,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("output buffer too small")
    }
}

/// Why a frame was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// Invalid COBS.
    Cobs,
    /// More than [`MAX_WIRE_FRAME`] bytes between delimiters.
    Oversize,
    /// Shorter than header + CRC, or the header's body length disagrees with the frame.
    TooShort,
    /// CRC mismatch.
    Crc,
    /// The header carries another protocol version (the value).
    Version(u8),
    /// Valid frame of a message type this decoder does not know (the code).
    UnknownType(u8),
    /// The body is shorter than the layout of its type (the type code).
    BodyTooShort(u8),
    /// A field holds a value outside its defined set (the field).
    BadField(&'static str),
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Cobs => f.write_str("invalid COBS"),
            Self::Oversize => f.write_str("frame too long"),
            Self::TooShort => f.write_str("frame too short or length mismatch"),
            Self::Crc => f.write_str("CRC mismatch"),
            Self::Version(v) => write!(f, "unsupported protocol version {v}"),
            Self::UnknownType(t) => write!(f, "unknown message type 0x{t:02x}"),
            Self::BodyTooShort(t) => write!(f, "body of message type 0x{t:02x} too short"),
            Self::BadField(n) => write!(f, "bad field: {n}"),
        }
    }
}

/// The frame header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Protocol version ([`PROTOCOL_VERSION`]).
    pub version: u8,
    /// Message type code ([`MsgType`]).
    pub msg_type: u8,
    /// Body length, bytes.
    pub body_len: u16,
    /// Frame sequence number: +1 (wrapping) for every frame the unit sends, any type.
    pub seq: u32,
}

/// Any message of this protocol version.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    /// Type 0x01.
    Pose(PoseRecord),
    /// Type 0x02.
    Status(Status),
    /// Type 0x03.
    DeviceInfo(DeviceInfo),
    /// Type 0x04.
    Reply(CommandReply),
    /// Type 0x05.
    Gnss(GnssSentence),
}

impl Message {
    /// Its type code.
    pub fn msg_type(&self) -> MsgType {
        match self {
            Self::Pose(_) => MsgType::PoseRecord,
            Self::Status(_) => MsgType::Status,
            Self::DeviceInfo(_) => MsgType::DeviceInfo,
            Self::Reply(_) => MsgType::CommandReply,
            Self::Gnss(_) => MsgType::GnssSentence,
        }
    }

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        match self {
            Self::Pose(m) => m.write_body(out),
            Self::Status(m) => m.write_body(out),
            Self::DeviceInfo(m) => m.write_body(out),
            Self::Reply(m) => m.write_body(out),
            Self::Gnss(m) => m.write_body(out),
        }
    }

    /// Reads a body of type `msg_type`.
    pub fn read_body(msg_type: u8, body: &[u8]) -> Result<Self, DecodeError> {
        match MsgType::from_code(msg_type) {
            Some(MsgType::PoseRecord) => PoseRecord::read_body(body).map(Self::Pose),
            Some(MsgType::Status) => Status::read_body(body).map(Self::Status),
            Some(MsgType::DeviceInfo) => DeviceInfo::read_body(body).map(Self::DeviceInfo),
            Some(MsgType::CommandReply) => CommandReply::read_body(body).map(Self::Reply),
            Some(MsgType::GnssSentence) => GnssSentence::read_body(body).map(Self::Gnss),
            None => Err(DecodeError::UnknownType(msg_type)),
        }
    }
}

impl From<PoseRecord> for Message {
    fn from(m: PoseRecord) -> Self {
        Self::Pose(m)
    }
}
impl From<Status> for Message {
    fn from(m: Status) -> Self {
        Self::Status(m)
    }
}
impl From<DeviceInfo> for Message {
    fn from(m: DeviceInfo) -> Self {
        Self::DeviceInfo(m)
    }
}
impl From<CommandReply> for Message {
    fn from(m: CommandReply) -> Self {
        Self::Reply(m)
    }
}
impl From<GnssSentence> for Message {
    fn from(m: GnssSentence) -> Self {
        Self::Gnss(m)
    }
}

/// A decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Frame sequence number from the header.
    pub seq: u32,
    /// The message.
    pub message: Message,
}

/// Encodes one frame of `msg` with sequence `seq` into `out`: COBS-encoded header, body and
/// CRC, then the 0x00 delimiter. Returns the number of bytes written (at most
/// [`MAX_ENCODED_FRAME`]). Nothing but the output buffer is touched.
pub fn encode_frame(msg: &Message, seq: u32, out: &mut [u8]) -> Result<usize, EncodeError> {
    let mut raw = [0u8; MAX_RAW_FRAME];
    let body_len = msg.write_body(&mut raw[HEADER_LEN..HEADER_LEN + MAX_BODY_LEN])?;
    raw[0] = PROTOCOL_VERSION;
    raw[1] = msg.msg_type() as u8;
    raw[2..4].copy_from_slice(&(body_len as u16).to_le_bytes());
    raw[4..8].copy_from_slice(&seq.to_le_bytes());
    let crc_at = HEADER_LEN + body_len;
    let crc = crate::crc::crc32(&raw[..crc_at]);
    raw[crc_at..crc_at + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let raw_len = crc_at + CRC_LEN;
    let n = cobs::encode(&raw[..raw_len], out).map_err(|_| EncodeError::BufferTooSmall)?;
    let delim = out.get_mut(n).ok_or(EncodeError::BufferTooSmall)?;
    *delim = 0;
    Ok(n + 1)
}

/// Checks and parses the header and CRC of one raw (COBS-decoded) frame; returns the header
/// and the body slice.
pub fn parse_raw_frame(raw: &[u8]) -> Result<(Header, &[u8]), DecodeError> {
    if raw.len() < HEADER_LEN + CRC_LEN {
        return Err(DecodeError::TooShort);
    }
    let crc_at = raw.len() - CRC_LEN;
    let mut crc_bytes = [0u8; 4];
    crc_bytes.copy_from_slice(&raw[crc_at..]);
    if crate::crc::crc32(&raw[..crc_at]) != u32::from_le_bytes(crc_bytes) {
        return Err(DecodeError::Crc);
    }
    let header = Header {
        version: raw[0],
        msg_type: raw[1],
        body_len: u16::from_le_bytes([raw[2], raw[3]]),
        seq: u32::from_le_bytes([raw[4], raw[5], raw[6], raw[7]]),
    };
    if header.version != PROTOCOL_VERSION {
        return Err(DecodeError::Version(header.version));
    }
    if header.body_len as usize != crc_at - HEADER_LEN {
        return Err(DecodeError::TooShort);
    }
    Ok((header, &raw[HEADER_LEN..crc_at]))
}

/// Decodes one encoded frame given without its 0x00 delimiter; `buf` is decoded in place.
pub fn decode_frame(buf: &mut [u8]) -> Result<Frame, DecodeError> {
    if buf.len() > MAX_WIRE_FRAME {
        return Err(DecodeError::Oversize);
    }
    let n = cobs::decode_in_place(buf).map_err(|_| DecodeError::Cobs)?;
    let (header, body) = parse_raw_frame(&buf[..n])?;
    Ok(Frame {
        seq: header.seq,
        message: Message::read_body(header.msg_type, body)?,
    })
}

/// Sender side: numbers frames and encodes them.
#[derive(Debug, Clone, Default)]
pub struct FrameEncoder {
    next_seq: u32,
}

impl FrameEncoder {
    /// An encoder whose first frame has sequence 0.
    pub const fn new() -> Self {
        Self { next_seq: 0 }
    }

    /// The sequence number the next frame will carry.
    pub fn next_seq(&self) -> u32 {
        self.next_seq
    }

    /// Encodes `msg` as the next frame into `out` (see [`encode_frame`]); the sequence
    /// number advances only on success.
    pub fn encode(&mut self, msg: &Message, out: &mut [u8]) -> Result<usize, EncodeError> {
        let n = encode_frame(msg, self.next_seq, out)?;
        self.next_seq = self.next_seq.wrapping_add(1);
        Ok(n)
    }
}
