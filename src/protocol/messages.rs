//! Message bodies: fixed little-endian layouts, written and read field by field.
//!
//! Every body layout is given with byte offsets in `docs/PROTOCOL.md`. A reader accepts a body
//! longer than the layout it knows (fields appended by a later minor revision) and ignores the
//! extra bytes; a shorter body is an error.

use super::{DecodeError, EncodeError, MsgType, ResetCause};
use crate::bytes::{Reader, Writer};
use crate::odometry::UncertaintyModel;
use crate::settings::SettingsSource;
use crate::timing::SyncState;
use heapless::String;

/// Wire code of the sample schedule's state (bits 0-1 of [`StatusFlags`]): free-running 0,
/// PPS-locked 1, holdover 2.
fn sync_code(s: SyncState) -> u32 {
    match s {
        SyncState::FreeRunning => 0,
        SyncState::Locked => 1,
        SyncState::Holdover => 2,
    }
}

/// The state of wire code `code`; 3 is reserved and gives `None`.
fn sync_from_code(code: u32) -> Option<SyncState> {
    match code {
        0 => Some(SyncState::FreeRunning),
        1 => Some(SyncState::Locked),
        2 => Some(SyncState::Holdover),
        _ => None,
    }
}

/// Per-wheel status bits (4 bits per wheel in [`StatusFlags`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WheelStatus {
    /// The encoder's fault (state) line is active.
    pub fault: bool,
    /// At least one index (N) pulse has been seen since start, so the latched index count
    /// is meaningful.
    pub index_seen: bool,
    /// The count between the last two index pulses differed from `ticks_per_rev`
    /// (missed or spurious increments).
    pub index_mismatch: bool,
    /// The calibrated per-angle wheel function (non-zero harmonics, referenced to the index)
    /// was used for this sample; otherwise the constant transfer constant of eq (6).
    pub calibrated: bool,
}

impl WheelStatus {
    fn bits(self) -> u32 {
        (self.fault as u32)
            | (self.index_seen as u32) << 1
            | (self.index_mismatch as u32) << 2
            | (self.calibrated as u32) << 3
    }
    fn from_bits(b: u32) -> Self {
        Self {
            fault: b & 1 != 0,
            index_seen: b & 2 != 0,
            index_mismatch: b & 4 != 0,
            calibrated: b & 8 != 0,
        }
    }
}

/// The 32-bit status word of a [`PoseRecord`] and a [`Status`] message.
///
/// Bits: 0-1 [`SyncState`] code; 2 time tag valid; 3-6 left wheel (fault, index seen, index
/// mismatch, calibrated); 7-10 right wheel (same order); 11 uncertainty model (0 = paper,
/// 1 = covariance); 12 rate switch; 13 late sample; 14-31 reserved, sent as 0, ignored by
/// readers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatusFlags {
    /// Sample clock discipline.
    pub sync: SyncState,
    /// The GNSS time fields hold the time of the sample.
    pub time_valid: bool,
    /// Wheel 1 (left).
    pub left: WheelStatus,
    /// Wheel 2 (right).
    pub right: WheelStatus,
    /// Which uncertainty propagation filled the sigmas.
    pub model: UncertaintyModel,
    /// The first record at a new `rate` or `output_divider` (announced by the Status sent
    /// just before it); set once, in the next record sent.
    pub rate_switch: bool,
    /// The counters were read late (the sample interrupt ran after a stall): they belong to
    /// an instant up to one sample period after the time label.
    pub late: bool,
}

impl StatusFlags {
    /// Mask of the bits defined by this protocol version.
    pub const DEFINED_BITS: u32 = 0x3FFF;

    /// The wire word.
    pub fn to_bits(&self) -> u32 {
        sync_code(self.sync)
            | (self.time_valid as u32) << 2
            | self.left.bits() << 3
            | self.right.bits() << 7
            | (matches!(self.model, UncertaintyModel::Covariance) as u32) << 11
            | (self.rate_switch as u32) << 12
            | (self.late as u32) << 13
    }

    /// From the wire word; reserved bits are ignored, the reserved sync code 3 is an error.
    pub fn from_bits(bits: u32) -> Result<Self, DecodeError> {
        Ok(Self {
            sync: sync_from_code(bits & 3).ok_or(DecodeError::BadField("sync mode"))?,
            time_valid: bits & (1 << 2) != 0,
            left: WheelStatus::from_bits((bits >> 3) & 0xF),
            right: WheelStatus::from_bits((bits >> 7) & 0xF),
            model: if bits & (1 << 11) != 0 {
                UncertaintyModel::Covariance
            } else {
                UncertaintyModel::Paper
            },
            rate_switch: bits & (1 << 12) != 0,
            late: bits & (1 << 13) != 0,
        })
    }
}

/// GNSS time of a sample (meaningful when [`StatusFlags::time_valid`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GnssTime {
    /// GPS week number (weeks since 1980-01-06, not rolled over at 1024).
    pub week: u16,
    /// Time of week of the PPS edge that starts the sample's second, milliseconds
    /// (0..604_800_000; a multiple of 1000 in normal operation).
    pub tow_ms: u32,
    /// Index of the sample within that second: 0 is the sample on the PPS edge, `k` is
    /// `k / rate` seconds after it.
    pub sample_in_second: u16,
}

/// One odometry sample (message type 0x01). Body length [`PoseRecord::BODY_LEN`] bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PoseRecord {
    /// Sample sequence number: counts every sample the unit computed since start (wrapping),
    /// whether or not it was sent; consecutive records differ by `output_divider` unless
    /// records were dropped.
    pub sequence: u32,
    /// Status word.
    pub flags: StatusFlags,
    /// MCU time of the sample (counter snapshot), microseconds since start.
    pub mcu_time_us: u64,
    /// GNSS time of the sample; valid when `flags.time_valid`, otherwise all zero.
    pub gnss: GnssTime,
    /// x (east) of the chassis reference point, metres.
    pub x: f64,
    /// y (north), metres.
    pub y: f64,
    /// Heading alpha, radians: 0 along +y (north), growing clockwise; cumulative, not
    /// wrapped (eq 15).
    pub heading: f64,
    /// Standard uncertainty of x, metres.
    pub sigma_x: f32,
    /// Standard uncertainty of y, metres.
    pub sigma_y: f32,
    /// Standard uncertainty of heading, radians.
    pub sigma_heading: f32,
    /// Covariance of x and y, m^2 (0 unless the covariance model filled the record).
    pub cov_xy: f32,
    /// Absolute count of encoder 1 (left), Gamma_1, increments (x4 decoded, 64-bit).
    pub gamma_left: i64,
    /// Absolute count of encoder 2 (right), Gamma_2, increments.
    pub gamma_right: i64,
    /// Gamma_1 latched at the left wheel's last index pulse (valid when
    /// `flags.left.index_seen`, 0 otherwise).
    pub index_left: i64,
    /// Gamma_2 latched at the right wheel's last index pulse (valid when
    /// `flags.right.index_seen`).
    pub index_right: i64,
    /// Records computed but not sent (queue full) since the previous sent record
    /// (saturating). Records skipped by `output_divider` are not counted.
    pub dropped: u32,
}

impl PoseRecord {
    /// Body length in bytes.
    pub const BODY_LEN: usize = 100;

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer::new(out);
        (|| {
            w.u32(self.sequence)?;
            w.u32(self.flags.to_bits())?;
            w.u64(self.mcu_time_us)?;
            w.u32(self.gnss.tow_ms)?;
            w.u16(self.gnss.week)?;
            w.u16(self.gnss.sample_in_second)?;
            w.f64(self.x)?;
            w.f64(self.y)?;
            w.f64(self.heading)?;
            w.f32(self.sigma_x)?;
            w.f32(self.sigma_y)?;
            w.f32(self.sigma_heading)?;
            w.f32(self.cov_xy)?;
            w.i64(self.gamma_left)?;
            w.i64(self.gamma_right)?;
            w.i64(self.index_left)?;
            w.i64(self.index_right)?;
            w.u32(self.dropped)
        })()
        .map_err(|_| EncodeError::BufferTooSmall)?;
        Ok(w.pos())
    }

    /// Reads a body (at least [`Self::BODY_LEN`] bytes; extra bytes are ignored).
    pub fn read_body(body: &[u8]) -> Result<Self, DecodeError> {
        let short = DecodeError::BodyTooShort(MsgType::PoseRecord as u8);
        let mut r = Reader::new(body);
        let sequence = r.u32().map_err(|_| short)?;
        let flags = r.u32().map_err(|_| short)?;
        let mut rest = || -> Result<Self, crate::bytes::OutOfSpace> {
            Ok(Self {
                sequence,
                flags: StatusFlags::default(),
                mcu_time_us: r.u64()?,
                gnss: GnssTime {
                    tow_ms: r.u32()?,
                    week: r.u16()?,
                    sample_in_second: r.u16()?,
                },
                x: r.f64()?,
                y: r.f64()?,
                heading: r.f64()?,
                sigma_x: r.f32()?,
                sigma_y: r.f32()?,
                sigma_heading: r.f32()?,
                cov_xy: r.f32()?,
                gamma_left: r.i64()?,
                gamma_right: r.i64()?,
                index_left: r.i64()?,
                index_right: r.i64()?,
                dropped: r.u32()?,
            })
        };
        let mut rec = rest().map_err(|_| short)?;
        rec.flags = StatusFlags::from_bits(flags)?;
        Ok(rec)
    }
}

/// Wire code of a [`SettingsSource`] (0 defaults, 1 flash).
fn settings_source_code(s: SettingsSource) -> u8 {
    match s {
        SettingsSource::Defaults => 0,
        SettingsSource::Flash => 1,
    }
}

/// The [`SettingsSource`] of wire code `c`.
fn settings_source_from_code(c: u8) -> Result<SettingsSource, DecodeError> {
    match c {
        0 => Ok(SettingsSource::Defaults),
        1 => Ok(SettingsSource::Flash),
        _ => Err(DecodeError::BadField("settings source")),
    }
}

/// Periodic heartbeat (message type 0x02, about once per second). Body length
/// [`Status::BODY_LEN`] bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Status {
    /// MCU time since start, microseconds.
    pub uptime_us: u64,
    /// Status word of the latest sample.
    pub flags: StatusFlags,
    /// Current sample rate, Hz.
    pub rate_hz: u32,
    /// Samples computed since start (wrapping).
    pub samples: u32,
    /// Records dropped since start (queue full), saturating.
    pub dropped_total: u32,
    /// PPS edges accepted since start.
    pub pps_edges: u32,
    /// PPS edges rejected as glitches since start.
    pub pps_rejected: u32,
    /// Host-link receive bytes lost (UART overrun or a full receive queue) since start.
    pub host_rx_lost: u32,
    /// Where the settings in use came from.
    pub settings_source: SettingsSource,
    /// The settings in use differ from the ones stored (a `save` is pending).
    pub settings_dirty: bool,
    /// Samples dropped since start because the queue from the sample interrupt to the
    /// processing task was full (wrapping): the processing task never saw them, and the
    /// next sample it processes spans their periods too.
    pub samples_lost: u32,
    /// GNSS receiver UART bytes lost since start: receive overrun or a full NMEA byte
    /// queue (wrapping). A lost byte can cost a time message.
    pub gnss_rx_lost: u32,
    /// Samples merged since start because the sample interrupt ran late, for example while
    /// a flash erase stalled the CPU: periods whose counts were folded into the next sample
    /// (wrapping).
    pub merged_samples: u32,
    /// Why the unit last started (in the byte that was reserved at offset 38).
    pub reset_cause: ResetCause,
    /// Every `output_divider`-th sample is sent as a record (with `rate_hz`: the
    /// configuration of the records that follow).
    pub output_divider: u32,
    /// Index pulses lost since start, both wheels: over-captures (two pulses before the
    /// interrupt) and a full queue to the processing task (wrapping).
    pub index_lost: u32,
    /// Host-link receive overruns since start: each lost at least one byte, a CPU stall
    /// (flash erase) all bytes that arrived during it (wrapping).
    pub host_rx_overruns: u32,
    /// Host-link bytes received with a framing, noise or parity error (wrapping).
    pub host_rx_line_errors: u32,
    /// GNSS receiver UART overruns since start (as `host_rx_overruns`).
    pub gnss_rx_overruns: u32,
    /// GNSS receiver bytes with a framing, noise or parity error (wrapping).
    pub gnss_rx_line_errors: u32,
    /// GNSS sentences forwarded as [`GnssSentence`] frames since start (wrapping).
    pub gnss_forwarded: u32,
    /// Checksum-valid GNSS sentences of the forwarded kinds not forwarded since start: no
    /// room on the link for them beside the pose stream, or `output = mavlink` (wrapping).
    pub gnss_not_forwarded: u32,
    /// GNSS lines with a missing or wrong checksum, or a byte outside printable ASCII, since
    /// start (wrapping).
    pub gnss_bad_checksum: u32,
    /// GNSS lines longer than the line buffer (96 bytes), discarded, since start (wrapping).
    pub gnss_overlong: u32,
}

impl Status {
    /// Body length in bytes. Version 1 of the protocol first had 40 bytes (up to
    /// `settings_dirty` and 2 reserved bytes); `samples_lost`, `gnss_rx_lost` and
    /// `merged_samples` were appended (52), then `output_divider` and the index and UART
    /// error counters (76), then the GNSS forwarding counters (92); `reset_cause` took the
    /// reserved byte at 38.
    pub const BODY_LEN: usize = 92;

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer::new(out);
        (|| {
            w.u64(self.uptime_us)?;
            w.u32(self.flags.to_bits())?;
            w.u32(self.rate_hz)?;
            w.u32(self.samples)?;
            w.u32(self.dropped_total)?;
            w.u32(self.pps_edges)?;
            w.u32(self.pps_rejected)?;
            w.u32(self.host_rx_lost)?;
            w.u8(settings_source_code(self.settings_source))?;
            w.u8(self.settings_dirty as u8)?;
            w.u8(self.reset_cause.code())?;
            w.u8(0)?;
            w.u32(self.samples_lost)?;
            w.u32(self.gnss_rx_lost)?;
            w.u32(self.merged_samples)?;
            w.u32(self.output_divider)?;
            w.u32(self.index_lost)?;
            w.u32(self.host_rx_overruns)?;
            w.u32(self.host_rx_line_errors)?;
            w.u32(self.gnss_rx_overruns)?;
            w.u32(self.gnss_rx_line_errors)?;
            w.u32(self.gnss_forwarded)?;
            w.u32(self.gnss_not_forwarded)?;
            w.u32(self.gnss_bad_checksum)?;
            w.u32(self.gnss_overlong)
        })()
        .map_err(|_| EncodeError::BufferTooSmall)?;
        Ok(w.pos())
    }

    /// Reads a body (at least [`Self::BODY_LEN`] bytes; extra bytes are ignored). The
    /// shorter bodies of earlier firmware are too short: the counters they lack cannot be
    /// told from zero.
    pub fn read_body(body: &[u8]) -> Result<Self, DecodeError> {
        if body.len() < Self::BODY_LEN {
            return Err(DecodeError::BodyTooShort(MsgType::Status as u8));
        }
        let mut r = Reader::new(body);
        let short = |_| DecodeError::BodyTooShort(MsgType::Status as u8);
        let uptime_us = r.u64().map_err(short)?;
        let flags = StatusFlags::from_bits(r.u32().map_err(short)?)?;
        let rate_hz = r.u32().map_err(short)?;
        let samples = r.u32().map_err(short)?;
        let dropped_total = r.u32().map_err(short)?;
        let pps_edges = r.u32().map_err(short)?;
        let pps_rejected = r.u32().map_err(short)?;
        let host_rx_lost = r.u32().map_err(short)?;
        let settings_source = settings_source_from_code(r.u8().map_err(short)?)?;
        let settings_dirty = match r.u8().map_err(short)? {
            0 => false,
            1 => true,
            _ => return Err(DecodeError::BadField("settings dirty")),
        };
        let reset_cause = ResetCause::from_code(r.u8().map_err(short)?);
        r.u8().map_err(short)?;
        let samples_lost = r.u32().map_err(short)?;
        let gnss_rx_lost = r.u32().map_err(short)?;
        let merged_samples = r.u32().map_err(short)?;
        let mut u32s = [0u32; 10];
        for v in &mut u32s {
            *v = r.u32().map_err(short)?;
        }
        let [output_divider, index_lost, host_rx_overruns, host_rx_line_errors, gnss_rx_overruns, gnss_rx_line_errors, gnss_forwarded, gnss_not_forwarded, gnss_bad_checksum, gnss_overlong] =
            u32s;
        Ok(Self {
            uptime_us,
            flags,
            rate_hz,
            samples,
            dropped_total,
            pps_edges,
            pps_rejected,
            host_rx_lost,
            settings_source,
            settings_dirty,
            samples_lost,
            gnss_rx_lost,
            merged_samples,
            reset_cause,
            output_divider,
            index_lost,
            host_rx_overruns,
            host_rx_line_errors,
            gnss_rx_overruns,
            gnss_rx_line_errors,
            gnss_forwarded,
            gnss_not_forwarded,
            gnss_bad_checksum,
            gnss_overlong,
        })
    }
}

/// Longest firmware version string in [`DeviceInfo`], bytes.
pub const MAX_FIRMWARE_VERSION: usize = 32;

/// Identity of the unit (message type 0x03): sent at start and in reply to `version`.
/// Body length [`DeviceInfo::FIXED_LEN`] + length of the version string.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct DeviceInfo {
    /// Protocol version the unit speaks ([`super::PROTOCOL_VERSION`]).
    pub protocol_version: u8,
    /// Where the settings in use came from.
    pub settings_source: SettingsSource,
    /// Why the unit last started (in the byte that was reserved at offset 2).
    pub reset_cause: ResetCause,
    /// CRC-32/ISO-HDLC of the settings in use, serialised (see `settings::Settings::checksum`).
    pub settings_checksum: u32,
    /// The MCU's 96-bit unique device ID (all zero if unknown).
    pub uid: [u8; 12],
    /// Firmware version, UTF-8 (e.g. `"0.1.0"`), at most [`MAX_FIRMWARE_VERSION`] bytes.
    pub firmware_version: String<MAX_FIRMWARE_VERSION>,
}

impl DeviceInfo {
    /// Length of the fixed part of the body, bytes.
    pub const FIXED_LEN: usize = 21;

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer::new(out);
        (|| {
            w.u8(self.protocol_version)?;
            w.u8(settings_source_code(self.settings_source))?;
            w.u8(self.reset_cause.code())?;
            w.u8(0)?;
            w.u32(self.settings_checksum)?;
            w.bytes(&self.uid)?;
            w.u8(self.firmware_version.len() as u8)?;
            w.bytes(self.firmware_version.as_bytes())
        })()
        .map_err(|_| EncodeError::BufferTooSmall)?;
        Ok(w.pos())
    }

    /// Reads a body.
    pub fn read_body(body: &[u8]) -> Result<Self, DecodeError> {
        let short = |_| DecodeError::BodyTooShort(MsgType::DeviceInfo as u8);
        let mut r = Reader::new(body);
        let protocol_version = r.u8().map_err(short)?;
        let settings_source = settings_source_from_code(r.u8().map_err(short)?)?;
        let reset_cause = ResetCause::from_code(r.u8().map_err(short)?);
        r.u8().map_err(short)?;
        let settings_checksum = r.u32().map_err(short)?;
        let mut uid = [0u8; 12];
        uid.copy_from_slice(r.bytes(12).map_err(short)?);
        let n = r.u8().map_err(short)? as usize;
        if n > MAX_FIRMWARE_VERSION {
            return Err(DecodeError::BadField("firmware version length"));
        }
        let text = core::str::from_utf8(r.bytes(n).map_err(short)?)
            .map_err(|_| DecodeError::BadField("firmware version utf-8"))?;
        let mut firmware_version = String::new();
        firmware_version
            .push_str(text)
            .map_err(|_| DecodeError::BadField("firmware version length"))?;
        Ok(Self {
            protocol_version,
            settings_source,
            reset_cause,
            settings_checksum,
            uid,
            firmware_version,
        })
    }
}

/// Longest text of one [`CommandReply`] frame, bytes. Longer replies are split into several
/// frames at line boundaries (see [`CommandReply::chunks`]).
pub const MAX_REPLY_TEXT: usize = 256;

/// Reply to one command line (message type 0x04). Body length [`CommandReply::FIXED_LEN`] +
/// text length.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CommandReply {
    /// The command succeeded (`ok`) or was rejected and changed nothing (`error`).
    pub ok: bool,
    /// More reply frames for the same command follow; the host concatenates the texts.
    pub more: bool,
    /// Reply text, UTF-8, lines separated by `\n`. The first frame of a reply starts with
    /// `ok` or `error: <what was wrong>`.
    pub text: String<MAX_REPLY_TEXT>,
}

impl CommandReply {
    /// Length of the fixed part of the body, bytes.
    pub const FIXED_LEN: usize = 4;

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer::new(out);
        (|| {
            w.u8(if self.ok { 0 } else { 1 })?;
            w.u8(self.more as u8)?;
            w.u16(self.text.len() as u16)?;
            w.bytes(self.text.as_bytes())
        })()
        .map_err(|_| EncodeError::BufferTooSmall)?;
        Ok(w.pos())
    }

    /// Reads a body.
    pub fn read_body(body: &[u8]) -> Result<Self, DecodeError> {
        let short = |_| DecodeError::BodyTooShort(MsgType::CommandReply as u8);
        let mut r = Reader::new(body);
        let ok = match r.u8().map_err(short)? {
            0 => true,
            1 => false,
            _ => return Err(DecodeError::BadField("reply status")),
        };
        let more = r.u8().map_err(short)? & 1 != 0;
        let n = r.u16().map_err(short)? as usize;
        if n > MAX_REPLY_TEXT {
            return Err(DecodeError::BadField("reply text length"));
        }
        let text = core::str::from_utf8(r.bytes(n).map_err(short)?)
            .map_err(|_| DecodeError::BadField("reply text utf-8"))?;
        let mut s = String::new();
        s.push_str(text)
            .map_err(|_| DecodeError::BadField("reply text length"))?;
        Ok(Self { ok, more, text: s })
    }

    /// Splits a reply text of any length into frames of at most [`MAX_REPLY_TEXT`] bytes,
    /// cutting after a `\n` where possible (else at a UTF-8 character boundary). All frames
    /// carry `ok`; all but the last have `more` set. An empty text gives one empty frame.
    pub fn chunks(ok: bool, text: &str) -> ReplyChunks<'_> {
        ReplyChunks {
            ok,
            rest: text,
            first: true,
        }
    }
}

/// Iterator returned by [`CommandReply::chunks`].
#[derive(Debug, Clone)]
pub struct ReplyChunks<'a> {
    ok: bool,
    rest: &'a str,
    first: bool,
}

impl Iterator for ReplyChunks<'_> {
    type Item = CommandReply;

    fn next(&mut self) -> Option<CommandReply> {
        if self.rest.is_empty() && !self.first {
            return None;
        }
        self.first = false;
        let cut = if self.rest.len() <= MAX_REPLY_TEXT {
            self.rest.len()
        } else {
            let window = &self.rest.as_bytes()[..MAX_REPLY_TEXT];
            match window.iter().rposition(|&b| b == b'\n') {
                Some(i) => i + 1,
                None => {
                    let mut i = MAX_REPLY_TEXT;
                    while !self.rest.is_char_boundary(i) {
                        i -= 1;
                    }
                    i
                }
            }
        };
        // `cut` is a char boundary by construction; the checked split keeps the panic path (and
        // the string-formatting code it drags into the firmware) out of the image.
        let (head, tail) = self.rest.split_at_checked(cut).unwrap_or((self.rest, ""));
        self.rest = tail;
        let mut text = String::new();
        // `head` is at most MAX_REPLY_TEXT bytes by construction.
        let _ = text.push_str(head);
        Some(CommandReply {
            ok: self.ok,
            more: !tail.is_empty(),
            text,
        })
    }
}

/// Longest sentence text of one [`GnssSentence`], bytes: the GNSS line buffer's length
/// ([`crate::timing::nmea::MAX_SENTENCE`]), which covers the high-precision sentences some
/// receivers send beyond NMEA 0183's 82 characters.
pub const MAX_SENTENCE_TEXT: usize = crate::timing::nmea::MAX_SENTENCE;

/// One NMEA sentence received from the GNSS receiver and forwarded to the host (message type
/// 0x05). Body length [`GnssSentence::FIXED_LEN`] + text length.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct GnssSentence {
    /// Unit time at which the sentence's line ending arrived, microseconds since start: the
    /// clock of [`PoseRecord::mcu_time_us`].
    pub mcu_time_us: u64,
    /// Number of the sentence among the checksum-valid sentences of the forwarded kinds received
    /// since start, the first being 0 (wrapping). A jump of `k + 1` between two consecutive
    /// GnssSentence frames means `k` sentences were received but not forwarded.
    pub number: u32,
    /// The sentence as received, ASCII from `$` through the two checksum digits, without the
    /// line ending, e.g. `$GPGGA,...*47`.
    pub text: String<MAX_SENTENCE_TEXT>,
}

impl GnssSentence {
    /// Length of the fixed part of the body, bytes.
    pub const FIXED_LEN: usize = 16;

    /// Writes the body into `out`; returns its length.
    pub fn write_body(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer::new(out);
        (|| {
            w.u64(self.mcu_time_us)?;
            w.u32(self.number)?;
            w.u8(self.text.len() as u8)?;
            w.bytes(&[0; 3])?;
            w.bytes(self.text.as_bytes())
        })()
        .map_err(|_| EncodeError::BufferTooSmall)?;
        Ok(w.pos())
    }

    /// Reads a body. The text must be printable ASCII starting with `$`; its checksum is the
    /// reader's to check.
    pub fn read_body(body: &[u8]) -> Result<Self, DecodeError> {
        let short = |_| DecodeError::BodyTooShort(MsgType::GnssSentence as u8);
        let mut r = Reader::new(body);
        let mcu_time_us = r.u64().map_err(short)?;
        let number = r.u32().map_err(short)?;
        let n = r.u8().map_err(short)? as usize;
        r.bytes(3).map_err(short)?;
        if n > MAX_SENTENCE_TEXT {
            return Err(DecodeError::BadField("sentence length"));
        }
        let bytes = r.bytes(n).map_err(short)?;
        if bytes.first() != Some(&b'$') || !bytes.iter().all(|b| (0x20..0x7f).contains(b)) {
            return Err(DecodeError::BadField("sentence text"));
        }
        let mut text = String::new();
        // Printable ASCII (checked above) is UTF-8, and `n` fits the capacity.
        for &b in bytes {
            text.push(b as char)
                .map_err(|_| DecodeError::BadField("sentence length"))?;
        }
        Ok(Self {
            mcu_time_us,
            number,
            text,
        })
    }
}
