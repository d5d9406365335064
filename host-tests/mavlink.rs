//! The MAVLink output's pure parts (`odo_unit::mavlink`): the baud table of docs/MAVLINK.md
//! through the settings check, the frame layout and truncation against the CRC, the
//! quaternion of any heading. pymavlink's reading of the frames is in odoctl/tests/mavlink.rs.

use odo_unit::mavlink::frame::{crc16, crc_accumulate, MessageId, STX_V2};
use odo_unit::mavlink::odometry::quaternion_of_heading;
use odo_unit::mavlink::{encode_frame, FrameHeader, MAX_FRAME_LEN};
use odo_unit::settings::{Output, SettingError, Settings};
use proptest::prelude::*;

mod support;
use support::budget::assert_budget_row;

/// MAVLink output at `baud`, `rate`, `output_divider`: accepted or not.
fn fits(baud: u32, rate: u32, divider: u32) -> bool {
    let s = Settings {
        output: Output::Mavlink,
        baud,
        rate,
        output_divider: divider,
        max_wheel_speed: 0.5,
        ..Settings::DEFAULT
    };
    match s.validate() {
        Ok(()) => true,
        Err(SettingError::RecordsOverBaud) => false,
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn the_documented_baud_table_is_the_settings_check() {
    // (baud, most frames per second, divider at rate 50, divider at rate 1000)
    for (baud, most, at50, at1000) in [
        (57_600, 23, 3, 44),
        (115_200, 46, 2, 22),
        (921_600, 374, 1, 3),
    ] {
        assert_budget_row(fits, (baud, most, at50, at1000));
    }
    // Our frames at the same settings: 114-byte records fit where 245-byte frames do not.
    let frames = Settings {
        rate: 50,
        ..Settings::DEFAULT
    };
    assert_eq!(frames.validate(), Ok(()));
    assert!(!fits(115_200, 50, 1));
}

proptest! {
    /// Header, truncation (trailing zeros out, one byte kept), CRC over all after the start
    /// byte and the CRC_EXTRA.
    #[test]
    fn frame_layout(payload in proptest::collection::vec(any::<u8>(), 1..=233),
                    zeros in 0usize..40, seq: u8, sysid: u8, compid: u8,
                    id in 0u32..(1 << 24), extra: u8) {
        let mut p = payload.clone();
        p.extend(std::iter::repeat_n(0, zeros));
        p.truncate(233);
        let mut out = [0u8; MAX_FRAME_LEN + 1];
        let msg = MessageId { id, crc_extra: extra };
        let n = encode_frame(&msg, &p, FrameHeader { seq, sysid, compid }, &mut out);
        let kept = p.iter().rposition(|b| *b != 0).map_or(1, |i| i + 1);
        prop_assert_eq!(n, 12 + kept);
        prop_assert_eq!(out[0], STX_V2);
        prop_assert_eq!(usize::from(out[1]), kept);
        prop_assert_eq!(&out[2..7], &[0, 0, seq, sysid, compid]);
        prop_assert_eq!(&out[7..10], &id.to_le_bytes()[..3]);
        prop_assert_eq!(&out[10..10 + kept], &p[..kept]);
        let crc = crc_accumulate(crc16(&out[1..10 + kept]), extra);
        prop_assert_eq!(&out[10 + kept..n], &crc.to_le_bytes());
    }

    /// q = (cos(h/2), 0, 0, sin(h/2)) up to sign, w >= 0, unit length, for any heading.
    #[test]
    fn quaternion_of_any_heading(h in -1.0e4f64..1.0e4) {
        let q = quaternion_of_heading(h);
        let (s, c) = (0.5 * h).sin_cos();
        let sign = if c < 0.0 { -1.0 } else { 1.0 };
        prop_assert!(q[0] >= 0.0);
        prop_assert!((f64::from(q[0]) - sign * c).abs() < 1e-6);
        prop_assert!((f64::from(q[3]) - sign * s).abs() < 1e-6);
        prop_assert_eq!((q[1], q[2]), (0.0, 0.0));
    }
}
