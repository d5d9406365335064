//! Wire protocol: message round trips, the documented example frame, bit-error detection,
//! streaming resynchronisation and a fuzz-style proptest of the frame decoder.

use odo_unit::crc;
use odo_unit::odometry::UncertaintyModel;
use odo_unit::protocol::*;
use odo_unit::settings::SettingsSource;
use odo_unit::timing::SyncState;
use proptest::prelude::*;

fn sample_pose() -> PoseRecord {
    PoseRecord {
        sequence: 123_456,
        flags: StatusFlags {
            sync: SyncState::Locked,
            time_valid: true,
            left: WheelStatus {
                fault: false,
                index_seen: true,
                index_mismatch: false,
                calibrated: true,
            },
            right: WheelStatus {
                fault: true,
                index_seen: true,
                index_mismatch: true,
                calibrated: false,
            },
            model: UncertaintyModel::Covariance,
            rate_switch: true,
            late: false,
        },
        mcu_time_us: 9_876_543_210,
        gnss: GnssTime {
            week: 2345,
            tow_ms: 345_600_000,
            sample_in_second: 49,
        },
        x: 12.345_678_901_234,
        y: -0.000_123_456,
        heading: -7.5 * core::f64::consts::PI,
        sigma_x: 0.0123,
        sigma_y: 0.0456,
        sigma_heading: 0.00789,
        cov_xy: -1.5e-5,
        gamma_left: -9_000_000_000,
        gamma_right: 9_000_000_001,
        index_left: -8_999_990_000,
        index_right: 0,
        dropped: 3,
    }
}

fn roundtrip(msg: &Message, seq: u32) -> Frame {
    let mut out = [0u8; MAX_ENCODED_FRAME];
    let n = encode_frame(msg, seq, &mut out).expect("encode");
    assert!(n <= MAX_ENCODED_FRAME);
    assert_eq!(out[n - 1], 0, "frame ends with the delimiter");
    assert!(
        out[..n - 1].iter().all(|&b| b != 0),
        "no 0x00 inside a frame"
    );
    let mut dec = FrameDecoder::new();
    let mut got = None;
    dec.feed(&out[..n], |r| got = Some(r.expect("decode")));
    got.expect("one frame")
}

#[test]
fn pose_record_round_trip() {
    let msg = Message::Pose(sample_pose());
    let f = roundtrip(&msg, 77);
    assert_eq!(f.seq, 77);
    assert_eq!(f.message, msg);
}

#[test]
fn status_round_trip() {
    let msg = Message::Status(Status {
        uptime_us: 1 << 40,
        flags: StatusFlags {
            sync: SyncState::Holdover,
            ..Default::default()
        },
        rate_hz: 50,
        samples: 4_000_000_000,
        dropped_total: 17,
        pps_edges: 3600,
        pps_rejected: 2,
        host_rx_lost: 1,
        settings_source: SettingsSource::Flash,
        settings_dirty: true,
        samples_lost: 3,
        gnss_rx_lost: 0xFFFF_FFFE,
        merged_samples: 99,
        reset_cause: ResetCause::Watchdog,
        output_divider: 10,
        index_lost: 5,
        host_rx_overruns: 6,
        host_rx_line_errors: 7,
        gnss_rx_overruns: 8,
        gnss_rx_line_errors: 9,
        gnss_forwarded: 10,
        gnss_not_forwarded: 11,
        gnss_bad_checksum: 12,
        gnss_overlong: 13,
    });
    assert_eq!(roundtrip(&msg, u32::MAX).message, msg);
}

/// The Status body layout of docs/PROTOCOL.md, field by field, and the lengths a reader
/// accepts: at least 92 bytes (longer is a later revision), shorter is malformed,
/// including the 40-, 52- and 76-byte bodies of earlier firmware.
#[test]
fn status_layout_and_short_bodies() {
    let st = Status {
        uptime_us: 0x0102_0304_0506_0708,
        flags: StatusFlags {
            sync: SyncState::Locked,
            time_valid: true,
            ..Default::default()
        },
        rate_hz: 50,
        samples: 0x1111_1111,
        dropped_total: 0x2222_2222,
        pps_edges: 0x3333_3333,
        pps_rejected: 0x4444_4444,
        host_rx_lost: 0x5555_5555,
        settings_source: SettingsSource::Flash,
        settings_dirty: true,
        samples_lost: 0xA1A2_A3A4,
        gnss_rx_lost: 0xB1B2_B3B4,
        merged_samples: 0xC1C2_C3C4,
        reset_cause: ResetCause::BrownOut,
        output_divider: 0xD1D2_D3D4,
        index_lost: 0xE1E2_E3E4,
        host_rx_overruns: 0xF1F2_F3F4,
        host_rx_line_errors: 0x9192_9394,
        gnss_rx_overruns: 0x8182_8384,
        gnss_rx_line_errors: 0x7172_7374,
        gnss_forwarded: 0x6162_6364,
        gnss_not_forwarded: 0x5152_5354,
        gnss_bad_checksum: 0x4142_4344,
        gnss_overlong: 0x3132_3334,
    };
    assert_eq!(Status::BODY_LEN, 92);
    let mut body = [0xEEu8; 100];
    let n = st.write_body(&mut body).unwrap();
    assert_eq!(n, Status::BODY_LEN);
    let field = |at: usize| u32::from_le_bytes(body[at..at + 4].try_into().unwrap());
    assert_eq!(&body[0..8], &0x0102_0304_0506_0708u64.to_le_bytes());
    assert_eq!(field(8), 0b101);
    assert_eq!(
        (
            field(12),
            field(16),
            field(20),
            field(24),
            field(28),
            field(32)
        ),
        (
            50,
            0x1111_1111,
            0x2222_2222,
            0x3333_3333,
            0x4444_4444,
            0x5555_5555
        )
    );
    assert_eq!(
        &body[36..40],
        &[1, 1, 3, 0],
        "source, dirty, reset cause, reserved"
    );
    assert_eq!(
        (field(40), field(44), field(48)),
        (0xA1A2_A3A4, 0xB1B2_B3B4, 0xC1C2_C3C4),
        "samples_lost, gnss_rx_lost, merged_samples"
    );
    assert_eq!(
        (field(52), field(56), field(60), field(64), field(68), field(72)),
        (0xD1D2_D3D4, 0xE1E2_E3E4, 0xF1F2_F3F4, 0x9192_9394, 0x8182_8384, 0x7172_7374),
        "output_divider, index_lost, host_rx_overruns, host_rx_line_errors, gnss_rx_overruns, gnss_rx_line_errors"
    );
    assert_eq!(
        (field(76), field(80), field(84), field(88)),
        (0x6162_6364, 0x5152_5354, 0x4142_4344, 0x3132_3334),
        "gnss_forwarded, gnss_not_forwarded, gnss_bad_checksum, gnss_overlong"
    );
    assert_eq!(Status::read_body(&body[..92]), Ok(st));
    assert_eq!(
        Status::read_body(&body[..100]),
        Ok(st),
        "appended bytes ignored"
    );
    // Through the decoder: a body one byte short, and the old 40-, 52- and 76-byte bodies,
    // are malformed; the frames around them decode and the sequence counts them.
    let mut dec = FrameDecoder::new();
    let mut got = Vec::new();
    dec.feed(&raw_frame(1, 0x02, 0, &body[..92]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x02, 1, &body[..91]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x02, 2, &body[..40]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x02, 3, &body[..100]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x02, 4, &body[..52]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x02, 5, &body[..76]), |r| got.push(r));
    assert_eq!(got[0].as_ref().unwrap().message, Message::Status(st));
    assert_eq!(got[1], Err(DecodeError::BodyTooShort(0x02)));
    assert_eq!(got[2], Err(DecodeError::BodyTooShort(0x02)));
    assert_eq!(got[3].as_ref().unwrap().message, Message::Status(st));
    assert_eq!(got[4], Err(DecodeError::BodyTooShort(0x02)));
    assert_eq!(got[5], Err(DecodeError::BodyTooShort(0x02)));
    let s = dec.stats();
    assert_eq!((s.frames, s.malformed, s.seq_gaps), (2, 4, 0));
    for len in 0..Status::BODY_LEN {
        assert_eq!(
            Status::read_body(&body[..len]),
            Err(DecodeError::BodyTooShort(0x02)),
            "{len} bytes"
        );
    }
}

#[test]
fn device_info_round_trip() {
    let mut info = DeviceInfo {
        protocol_version: PROTOCOL_VERSION,
        settings_source: SettingsSource::Defaults,
        settings_checksum: 0xDEAD_BEEF,
        uid: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
        reset_cause: ResetCause::Pin,
        ..Default::default()
    };
    info.firmware_version
        .push_str("0.1.0-dev+g1234abc")
        .unwrap();
    let msg = Message::DeviceInfo(info);
    assert_eq!(roundtrip(&msg, 0).message, msg);
}

#[test]
fn command_reply_round_trip_and_chunks() {
    let mut r = CommandReply {
        ok: false,
        more: false,
        ..Default::default()
    };
    r.text.push_str("error: unknown key 'foo'").unwrap();
    let msg = Message::Reply(r);
    assert_eq!(roundtrip(&msg, 5).message, msg);

    // A long multi-line text splits at line ends and reassembles exactly.
    let mut long = String::new();
    for i in 0..100 {
        long.push_str(&format!("key_{i} = {}\n", i as f64 * 0.1));
    }
    let parts: Vec<_> = CommandReply::chunks(true, &long).collect();
    assert!(parts.len() > 1);
    let mut joined = String::new();
    for (i, p) in parts.iter().enumerate() {
        assert!(p.ok);
        assert_eq!(p.more, i + 1 < parts.len());
        assert!(p.text.ends_with('\n'));
        let m = Message::Reply(p.clone());
        assert_eq!(roundtrip(&m, i as u32).message, m);
        joined.push_str(&p.text);
    }
    assert_eq!(joined, long);
    assert_eq!(CommandReply::chunks(true, "").count(), 1);
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn encode(msg: &Message, seq: u32) -> Vec<u8> {
    let mut out = [0u8; MAX_ENCODED_FRAME];
    let n = encode_frame(msg, seq, &mut out).unwrap();
    out[..n].to_vec()
}

fn example_reply() -> Message {
    Message::Reply(CommandReply::chunks(true, "ok\nrate = 50").next().unwrap())
}

fn example_pose() -> Message {
    Message::Pose(PoseRecord {
        sequence: 1000,
        flags: StatusFlags {
            sync: SyncState::Locked,
            time_valid: true,
            left: WheelStatus {
                index_seen: true,
                ..Default::default()
            },
            right: WheelStatus {
                index_seen: true,
                ..Default::default()
            },
            model: UncertaintyModel::Paper,
            ..Default::default()
        },
        mcu_time_us: 20_000_000,
        gnss: GnssTime {
            week: 2300,
            tow_ms: 302_400_000,
            sample_in_second: 0,
        },
        x: 1.5,
        y: -2.25,
        heading: 0.5,
        sigma_x: 0.001,
        sigma_y: 0.002,
        sigma_heading: 0.0001,
        cov_xy: 0.0,
        gamma_left: 123_456,
        gamma_right: -654_321,
        index_left: 120_000,
        index_right: -640_000,
        dropped: 0,
    })
}

/// Hex bytes of the code block after `<!-- example-frame:NAME -->` in docs/PROTOCOL.md.
fn doc_frame(name: &str) -> Vec<u8> {
    let doc = include_str!("../docs/PROTOCOL.md");
    let marker = format!("<!-- example-frame:{name} -->");
    let at = doc.find(&marker).expect("marker in PROTOCOL.md") + marker.len();
    let block = doc[at..].split("```").nth(1).expect("code block");
    block
        .split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).expect("hex byte"))
        .collect()
}

#[test]
fn doc_example_frames_decode() {
    for (name, msg, seq) in [
        ("reply", example_reply(), 7u32),
        ("pose", example_pose(), 1000),
    ] {
        let bytes = doc_frame(name);
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        dec.feed(&bytes, |r| got.push(r));
        assert_eq!(got.len(), 1, "{name}");
        let f = got.pop().unwrap().expect(name);
        assert_eq!(
            f,
            Frame {
                seq,
                message: msg.clone()
            },
            "{name}"
        );
        // And the encoder produces exactly the documented bytes.
        assert_eq!(hex(&encode(&msg, seq)), hex(&bytes), "{name}");
    }
    match example_reply() {
        Message::Reply(r) => assert_eq!(r.text.as_str(), "ok\nrate = 50"),
        _ => unreachable!(),
    }
}

fn all_kinds() -> Vec<(Message, u32)> {
    let mut info = DeviceInfo {
        protocol_version: PROTOCOL_VERSION,
        settings_source: SettingsSource::Flash,
        settings_checksum: 0x1234_5678,
        uid: [0xA5; 12],
        ..Default::default()
    };
    info.firmware_version.push_str("0.1.0").unwrap();
    vec![
        (Message::Pose(sample_pose()), 0x0102_0304),
        (example_pose(), 1000),
        (example_reply(), 7),
        (
            Message::Status(Status {
                uptime_us: 123_456_789,
                rate_hz: 50,
                samples_lost: 1,
                gnss_rx_lost: 2,
                merged_samples: 3,
                ..Default::default()
            }),
            0,
        ),
        (Message::DeviceInfo(info), u32::MAX),
        (example_sentence(), 42),
    ]
}

fn example_sentence() -> Message {
    let mut text = heapless::String::new();
    text.push_str("$GPGST,172814.0,0.006,0.023,0.020,273.6,0.023,0.020,0.031*6A")
        .unwrap();
    Message::Gnss(GnssSentence {
        mcu_time_us: 61_234_567,
        number: 17,
        text,
    })
}

#[test]
fn gnss_sentence_round_trip() {
    let msg = example_sentence();
    assert_eq!(roundtrip(&msg, 3).message, msg);
}

/// The sentence body's boundaries: lengths up to [`MAX_SENTENCE_TEXT`], printable ASCII from
/// `$`, a body cut short anywhere.
#[test]
fn gnss_sentence_boundaries() {
    let body = |n: usize, text: &[u8]| {
        let mut b = vec![0u8; 16];
        b[..8].copy_from_slice(&5u64.to_le_bytes());
        b[8..12].copy_from_slice(&9u32.to_le_bytes());
        b[12] = n as u8;
        b.extend_from_slice(text);
        b
    };
    let longest = [b"$".as_slice(), &[b'A'; MAX_SENTENCE_TEXT - 1]].concat();
    let ok = GnssSentence::read_body(&body(longest.len(), &longest)).unwrap();
    assert_eq!(ok.text.len(), MAX_SENTENCE_TEXT);
    assert_eq!((ok.mcu_time_us, ok.number), (5, 9));
    let too_long = [longest.as_slice(), b"B"].concat();
    let cases: [(&[u8], &str); 5] = [
        (&too_long, "sentence length"),
        (b"", "sentence text"),
        (b"GPGGA*00", "sentence text"),
        (b"$GP\xc3\xa9*00", "sentence text"),
        (b"$GP\r\n", "sentence text"),
    ];
    for (text, why) in cases {
        let err = GnssSentence::read_body(&body(text.len(), text)).unwrap_err();
        assert!(err.to_string().contains(why), "{text:?}: {err}");
    }
    let whole = body(6, b"$GPZDA");
    for cut in 0..whole.len() {
        assert!(
            matches!(
                GnssSentence::read_body(&whole[..cut]),
                Err(DecodeError::BodyTooShort(0x05))
            ),
            "cut at {cut}"
        );
    }
    // Appended fields are ignored.
    let longer = [whole.as_slice(), b"xyz"].concat();
    assert_eq!(
        GnssSentence::read_body(&longer).unwrap().text.as_str(),
        "$GPZDA"
    );
}

/// Flip every bit of every encoded frame (delimiter included), between intact frames: the
/// corrupted frame is never accepted, and the next frame always is.
#[test]
fn every_single_bit_error_is_detected() {
    let follower = example_reply();
    let follow_bytes = encode(&follower, 8);
    // The decoder has joined the stream: a failure of the first run would be a join.
    let primer = encode(&example_reply(), 100);
    let mut flips = 0;
    for (msg, seq) in all_kinds() {
        let good = encode(&msg, seq);
        for i in 0..good.len() {
            for bit in 0..8 {
                let mut bad = good.clone();
                bad[i] ^= 1 << bit;
                let mut dec = FrameDecoder::new();
                dec.feed(&primer, |r| assert!(r.is_ok()));
                let mut oks = Vec::new();
                let mut errs = 0;
                dec.feed(&bad, |r| match r {
                    Ok(f) => oks.push(f),
                    Err(_) => errs += 1,
                });
                dec.feed(&follow_bytes, |r| match r {
                    Ok(f) => oks.push(f),
                    Err(_) => errs += 1,
                });
                let last_is_delimiter = i == good.len() - 1;
                if last_is_delimiter {
                    // The corrupted frame runs into the next one: one rejected merged frame.
                    assert!(oks.is_empty(), "byte {i} bit {bit}");
                } else {
                    assert_eq!(oks.len(), 1, "byte {i} bit {bit}: {oks:?}");
                    assert_eq!(oks[0].message, follower);
                }
                assert!(errs >= 1, "byte {i} bit {bit} not reported");
                flips += 1;
            }
        }
    }
    assert!(flips > 2000, "{flips}");
}

#[test]
fn sequence_gaps_and_loss_are_counted() {
    let mut dec = FrameDecoder::new();
    let m = example_reply();
    for seq in [10u32, 11, 12, 15, 16, 0 /* restart */, 1] {
        dec.feed(&encode(&m, seq), |r| assert!(r.is_ok()));
    }
    let s = dec.stats();
    assert_eq!(s.frames, 7);
    assert_eq!(s.seq_gaps, 2);
    assert_eq!(s.frames_lost, 2);
    // Wrap-around is not a gap.
    let mut dec = FrameDecoder::new();
    for seq in [u32::MAX - 1, u32::MAX, 0, 1] {
        dec.feed(&encode(&m, seq), |r| assert!(r.is_ok()));
    }
    assert_eq!(dec.stats().seq_gaps, 0);
}

#[test]
fn resynchronises_after_garbage_oversize_and_mid_stream_join() {
    let frames: Vec<u8> = (0..3).flat_map(|s| encode(&example_pose(), s)).collect();
    // Join in the middle of the first frame.
    let mut dec = FrameDecoder::new();
    let mut ok = 0;
    dec.feed(&frames[40..], |r| ok += r.is_ok() as u32);
    assert_eq!(ok, 2);
    // The tail of the frame under way is a join, not a link error.
    let first_len = encode(&example_pose(), 0).len() as u32;
    assert_eq!(dec.stats().join_bytes, first_len - 40 - 1);
    assert_eq!(dec.stats().crc_errors + dec.stats().malformed, 0);
    // A stream read from its start decodes its first frame.
    let mut dec = FrameDecoder::new();
    let mut ok = 0;
    dec.feed(&frames, |r| ok += r.is_ok() as u32);
    assert_eq!((ok, dec.stats().join_bytes), (3, 0));
    // After the join, a damaged frame is an error again.
    let mut damaged = frames[40..].to_vec();
    let at = damaged.len() - 10;
    damaged[at] ^= 0x01;
    let mut dec = FrameDecoder::new();
    dec.feed(&damaged, |_| {});
    assert_eq!(dec.stats().crc_errors + dec.stats().malformed, 1);
    // Joining inside a run longer than any frame: all of it counted as join bytes.
    let mut dec = FrameDecoder::new();
    let mut stream = vec![0x55u8; 2 * MAX_WIRE_FRAME];
    stream.extend_from_slice(&frames);
    let mut ok = 0;
    dec.feed(&stream, |r| ok += r.is_ok() as u32);
    assert_eq!(ok, 2);
    assert_eq!(dec.stats().oversize, 0);
    assert_eq!(
        dec.stats().join_bytes,
        2 * MAX_WIRE_FRAME as u32 + first_len - 1
    );
    // After a frame, a long run without delimiter, then frames.
    let mut dec = FrameDecoder::new();
    let mut stream = encode(&example_pose(), 7);
    stream.extend(vec![0x55u8; 3 * MAX_WIRE_FRAME]);
    stream.push(0);
    stream.extend_from_slice(&frames);
    let mut ok = 0;
    dec.feed(&stream, |r| ok += r.is_ok() as u32);
    assert_eq!(ok, 4);
    assert_eq!(dec.stats().oversize, 1);
    assert_eq!(dec.stats().join_bytes, 0);
    // Leading and repeated delimiters are harmless.
    let mut dec = FrameDecoder::new();
    let mut stream = vec![0u8; 5];
    for f in frames.chunks(1) {
        stream.extend_from_slice(f);
        if f == [0] {
            stream.extend_from_slice(&[0, 0]);
        }
    }
    let mut ok = 0;
    dec.feed(&stream, |r| ok += r.unwrap().seq + 1);
    assert_eq!(ok, 1 + 2 + 3);
}

/// Builds a frame by hand from raw parts (for version and extension tests).
fn raw_frame(version: u8, ty: u8, seq: u32, body: &[u8]) -> Vec<u8> {
    let mut raw = vec![version, ty];
    raw.extend_from_slice(&(body.len() as u16).to_le_bytes());
    raw.extend_from_slice(&seq.to_le_bytes());
    raw.extend_from_slice(body);
    let crc = crc::crc32(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    let mut out = vec![0u8; cobs::max_encoded_len(raw.len()) + 1];
    let n = cobs::encode(&raw, &mut out).unwrap();
    out.truncate(n);
    out.push(0);
    out
}

#[test]
fn versioning_rules() {
    let mut body = [0u8; PoseRecord::BODY_LEN + 8];
    let n = sample_pose().write_body(&mut body).unwrap();
    assert_eq!(n, PoseRecord::BODY_LEN);
    body[n..].copy_from_slice(&[0xEE; 8]); // fields appended by a later revision
    let mut dec = FrameDecoder::new();
    let mut got = Vec::new();
    dec.feed(&raw_frame(1, 0x01, 0, &body), |r| got.push(r));
    dec.feed(&raw_frame(2, 0x01, 1, &body), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x7F, 2, &[1, 2, 3]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x01, 3, &body[..99]), |r| got.push(r));
    dec.feed(&raw_frame(1, 0x01, 4, &body[..100]), |r| got.push(r));
    assert_eq!(
        got[0].as_ref().unwrap().message,
        Message::Pose(sample_pose())
    );
    assert_eq!(got[1], Err(DecodeError::Version(2)));
    assert_eq!(got[2], Err(DecodeError::UnknownType(0x7F)));
    assert_eq!(got[3], Err(DecodeError::BodyTooShort(0x01)));
    assert!(got[4].is_ok());
    let s = dec.stats();
    assert_eq!(
        (s.frames, s.version_errors, s.unknown_type, s.malformed),
        (2, 1, 1, 1)
    );
    // The unknown type and short body still advanced the sequence: only seq 1 is missing.
    assert_eq!((s.seq_gaps, s.frames_lost), (1, 1));
    // Reserved status bits are ignored; sync code 3 is malformed.
    assert!(StatusFlags::from_bits(0xFFFF_F000).is_ok());
    assert!(StatusFlags::from_bits(3).is_err());
}

#[test]
fn flag_bits_positions() {
    let mut f = StatusFlags::default();
    assert_eq!(f.to_bits(), 0);
    f.sync = SyncState::Holdover;
    assert_eq!(f.to_bits(), 2);
    f.time_valid = true;
    f.left.fault = true;
    f.right.calibrated = true;
    f.model = UncertaintyModel::Covariance;
    assert_eq!(f.to_bits(), 2 | 1 << 2 | 1 << 3 | 1 << 10 | 1 << 11);
    assert_eq!(StatusFlags::from_bits(f.to_bits()).unwrap(), f);
    for bit in 2..12 {
        let g = StatusFlags::from_bits(1 << bit).unwrap();
        assert_eq!(g.to_bits(), 1 << bit);
    }
}

#[test]
fn encoder_numbers_frames_and_buffer_limits() {
    let mut enc = FrameEncoder::new();
    let mut out = [0u8; MAX_ENCODED_FRAME];
    let mut dec = FrameDecoder::new();
    for i in 0..5u32 {
        let n = enc.encode(&example_pose(), &mut out).unwrap();
        dec.feed(&out[..n], |r| assert_eq!(r.unwrap().seq, i));
    }
    assert_eq!(enc.next_seq(), 5);
    let mut small = [0u8; 50];
    assert_eq!(
        enc.encode(&example_pose(), &mut small),
        Err(EncodeError::BufferTooSmall)
    );
    assert_eq!(
        enc.next_seq(),
        5,
        "failed encode does not consume a sequence number"
    );
    // The largest message fits MAX_ENCODED_FRAME.
    let full = "é".repeat(MAX_REPLY_TEXT / 2);
    let r = CommandReply::chunks(false, &full).next().unwrap();
    assert_eq!(r.text.len(), MAX_REPLY_TEXT);
    let n = enc.encode(&Message::Reply(r), &mut out).unwrap();
    assert!(n <= MAX_ENCODED_FRAME);
    // A pose frame is 114 bytes on the wire (settings' bandwidth rule uses it).
    assert_eq!(
        encode(&example_pose(), 0).len() * 10,
        odo_unit::settings::POSE_FRAME_BITS as usize
    );
}

fn arb_pose() -> impl Strategy<Value = PoseRecord> {
    (
        (
            any::<u32>(),
            0u32..0x1000,
            any::<u64>(),
            any::<u16>(),
            any::<u32>(),
            any::<u16>(),
        ),
        (any::<f64>(), any::<f64>(), any::<f64>()),
        (any::<f32>(), any::<f32>(), any::<f32>(), any::<f32>()),
        (
            any::<i64>(),
            any::<i64>(),
            any::<i64>(),
            any::<i64>(),
            any::<u32>(),
        ),
    )
        .prop_filter_map("sync code 3", |(a, b, c, d)| {
            let flags = StatusFlags::from_bits(a.1).ok()?;
            Some(PoseRecord {
                sequence: a.0,
                flags,
                mcu_time_us: a.2,
                gnss: GnssTime {
                    week: a.3,
                    tow_ms: a.4,
                    sample_in_second: a.5,
                },
                x: b.0,
                y: b.1,
                heading: b.2,
                sigma_x: c.0,
                sigma_y: c.1,
                sigma_heading: c.2,
                cov_xy: c.3,
                gamma_left: d.0,
                gamma_right: d.1,
                index_left: d.2,
                index_right: d.3,
                dropped: d.4,
            })
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(10_000))]

    /// Any pose record (any bit patterns, NaN included) round-trips bit for bit.
    #[test]
    fn pose_round_trip_any_bits(p in arb_pose(), seq in any::<u32>()) {
        let bytes = encode(&Message::Pose(p), seq);
        let mut dec = FrameDecoder::new();
        let mut got = None;
        dec.feed(&bytes, |r| got = Some(r));
        let f = got.unwrap().unwrap();
        prop_assert_eq!(f.seq, seq);
        let Message::Pose(q) = f.message else { panic!("type") };
        let mut a = [0u8; PoseRecord::BODY_LEN];
        let mut b = [0u8; PoseRecord::BODY_LEN];
        p.write_body(&mut a).unwrap();
        q.write_body(&mut b).unwrap();
        prop_assert_eq!(a, b);
    }

    /// Arbitrary bytes, with valid frames spliced in after a delimiter: no panic, every
    /// spliced frame is recovered, nothing else is accepted unless it is a valid frame.
    #[test]
    fn fuzz_decoder(chunks in proptest::collection::vec(
        (proptest::collection::vec(any::<u8>(), 0..300), any::<bool>()), 0..6)) {
        let good = encode(&example_reply(), 7);
        let mut stream = Vec::new();
        let mut spliced = 0;
        for (junk, splice) in &chunks {
            stream.extend_from_slice(junk);
            if *splice {
                stream.push(0);
                stream.extend_from_slice(&good);
                spliced += 1;
            }
        }
        let mut dec = FrameDecoder::new();
        let mut ok = 0;
        dec.feed(&stream, |r| if let Ok(f) = r {
            if f.message == example_reply() { ok += 1; }
        });
        prop_assert!(ok >= spliced);
        let s = dec.stats();
        prop_assert!(s.frames >= spliced);
    }
}

/// DeviceInfo's byte 2 is the reset cause (it was reserved), byte 3 stays reserved.
#[test]
fn device_info_reset_cause_byte() {
    let info = DeviceInfo {
        protocol_version: PROTOCOL_VERSION,
        settings_source: SettingsSource::Flash,
        reset_cause: ResetCause::Watchdog,
        settings_checksum: 0x0403_0201,
        ..Default::default()
    };
    let mut body = [0u8; 64];
    let n = info.write_body(&mut body).unwrap();
    assert_eq!(n, DeviceInfo::FIXED_LEN);
    assert_eq!(&body[..8], &[1, 1, 5, 0, 1, 2, 3, 4]);
    assert_eq!(DeviceInfo::read_body(&body[..n]), Ok(info));
}

/// Status word bits 12 (rate switch) and 13 (late), each alone.
#[test]
fn status_word_rate_switch_and_late_bits() {
    let f = StatusFlags {
        rate_switch: true,
        ..Default::default()
    };
    assert_eq!(f.to_bits(), 1 << 12);
    let f = StatusFlags {
        late: true,
        ..Default::default()
    };
    assert_eq!(f.to_bits(), 1 << 13);
    let back = StatusFlags::from_bits(0x3000).unwrap();
    assert!(back.rate_switch && back.late);
    assert_eq!(StatusFlags::DEFINED_BITS, 0x3FFF);
    assert_eq!(
        StatusFlags::from_bits(0xFFFF_C000).unwrap(),
        StatusFlags::default()
    );
}

/// RCC_CSR (RM0368 sec. 6.3.21) to the reset cause: every reset sets PINRSTF, a power-on
/// sets BORRSTF too; the most specific flag wins. Codes round-trip.
#[test]
fn reset_cause_from_rcc_csr_table() {
    const BOR: u32 = 1 << 25;
    const PIN: u32 = 1 << 26;
    const POR: u32 = 1 << 27;
    const SFT: u32 = 1 << 28;
    const IWDG: u32 = 1 << 29;
    const WWDG: u32 = 1 << 30;
    const LPWR: u32 = 1 << 31;
    const LSION: u32 = 1;
    for (csr, want) in [
        (0, ResetCause::Unknown),
        (LSION, ResetCause::Unknown),
        (POR | BOR | PIN, ResetCause::PowerOn),
        (PIN, ResetCause::Pin),
        (BOR | PIN, ResetCause::BrownOut),
        (SFT | PIN, ResetCause::Software),
        (IWDG | PIN, ResetCause::Watchdog),
        (IWDG | POR | BOR | PIN, ResetCause::Watchdog),
        (WWDG | PIN, ResetCause::WindowWatchdog),
        (LPWR | PIN, ResetCause::LowPower),
    ] {
        assert_eq!(ResetCause::from_rcc_csr(csr), want, "{csr:#010x}");
    }
    for code in 0..=7u8 {
        assert_eq!(ResetCause::from_code(code).code(), code);
    }
    assert_eq!(ResetCause::from_code(8), ResetCause::Unknown);
    assert_eq!(ResetCause::Watchdog.name(), "watchdog");
}

/// Every count docs/PROTOCOL.md states is the code's constant: lengths, limits and sizes are
/// written from these, and this test fails when either side changes alone.
#[test]
fn doc_counts_are_the_code_constants() {
    use odo_unit::console::{MAX_LINE, MAX_SET_PAIRS, MAX_WORDS};
    use odo_unit::settings::store::{RECORD_LEN, SLOT_LEN};
    use odo_unit::settings::{Key, Settings};
    let doc = include_str!("../docs/PROTOCOL.md");
    // The settings sectors (`memory.x`): 16 KiB each.
    let slots = 16 * 1024 / SLOT_LEN;
    for phrase in [
        format!("`header` ({HEADER_LEN} bytes)"),
        format!("`body` (0..={MAX_BODY_LEN} bytes in version 1)"),
        format!("`crc` ({CRC_LEN} bytes)"),
        format!("the largest raw frame of version 1 is {MAX_RAW_FRAME} bytes"),
        format!("the largest encoded frame is {MAX_ENCODED_FRAME}\n"),
        format!("**{MAX_WIRE_FRAME} encoded bytes**"),
        format!("### 0x01 PoseRecord ({} bytes)", PoseRecord::BODY_LEN),
        format!("### 0x02 Status ({} bytes)", Status::BODY_LEN),
        format!(
            "| 0x03 | DeviceInfo | {} + n (n <= {MAX_FIRMWARE_VERSION}) |",
            DeviceInfo::FIXED_LEN
        ),
        format!(
            "| 0x04 | CommandReply | {} + n (n <= {MAX_REPLY_TEXT}) |",
            CommandReply::FIXED_LEN
        ),
        format!("At most **{MAX_LINE} bytes** per line"),
        format!("At most {MAX_WORDS} words per line"),
        format!("up to {MAX_SET_PAIRS} pairs"),
        format!("at most {MAX_SET_PAIRS} pairs"),
        format!("one in {slots}, when the current sector is full"),
        format!("16 KiB each, {slots}\nslots each"),
        format!("log of {SLOT_LEN}-byte slots"),
        format!("one {RECORD_LEN}-byte record"),
        format!("the {}-byte serialised", Settings::SERIALIZED_LEN),
        format!("version 6: {} bytes", Settings::SERIALIZED_LEN),
    ] {
        assert!(doc.contains(&phrase), "PROTOCOL.md lacks {phrase:?}");
    }
    // No stated number of keys or `get` lines: the key table is the count.
    let section = doc.split("## 4. Commands").nth(1).expect("section 4");
    for n in [Key::COUNT, Key::COUNT + 1] {
        for unit in ["lines", "keys"] {
            let phrase = format!("{n} {unit}");
            assert!(!section.contains(&phrase), "PROTOCOL.md states {phrase:?}");
        }
    }
}
