//! Wire protocol: message round trips, the documented example frame, bit-error detection,
//! streaming resynchronisation and a fuzz-style proptest of the frame decoder.

use odo_core::odometry::UncertaintyModel;
use odo_core::protocol::*;

fn sample_pose() -> PoseRecord {
    PoseRecord {
        sequence: 123_456,
        flags: StatusFlags {
            sync: SyncMode::PpsLocked,
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
        sigma_xy: -1.5e-5,
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
            sync: SyncMode::Holdover,
            ..Default::default()
        },
        rate_hz: 50,
        samples: 4_000_000_000,
        dropped_total: 17,
        pps_edges: 3600,
        pps_rejected: 2,
        rx_errors: 1,
        settings_source: SettingsSource::Flash,
        settings_dirty: true,
    });
    assert_eq!(roundtrip(&msg, u32::MAX).message, msg);
}

#[test]
fn device_info_round_trip() {
    let mut info = DeviceInfo {
        protocol_version: PROTOCOL_VERSION,
        settings_source: SettingsSource::Defaults,
        settings_checksum: 0xDEAD_BEEF,
        uid: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
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
