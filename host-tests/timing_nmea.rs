//! The NMEA time messages (`odo_unit::timing::nmea`): ZDA/RMC parsing with checksum, the
//! error table, the line buffer, leap seconds, UTC to GPS week and time of week.

use odo_unit::timing::nmea::{civil_from_days, days_from_civil, parse_sentence, MAX_SENTENCE};
use odo_unit::timing::*;
use proptest::prelude::*;

fn with_checksum(body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}")
}

fn feed(buf: &mut LineBuffer, bytes: &[u8]) -> Vec<Result<TimeMessage, NmeaError>> {
    bytes.iter().filter_map(|b| buf.push(*b)).collect()
}

#[test]
fn parses_the_classic_examples() {
    let rmc =
        parse_sentence(b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A");
    assert_eq!(
        rmc,
        Ok(TimeMessage::Rmc {
            time: UtcDateTime {
                year: 1994,
                month: 3,
                day: 23,
                hour: 12,
                minute: 35,
                second: 19,
                millis: 0
            },
            valid: true,
        })
    );
    let zda = parse_sentence(b"$GPZDA,201530.00,04,07,2002,00,00*60\r");
    assert_eq!(
        zda,
        Ok(TimeMessage::Zda(UtcDateTime {
            year: 2002,
            month: 7,
            day: 4,
            hour: 20,
            minute: 15,
            second: 30,
            millis: 0
        }))
    );
}

#[test]
fn nmea_error_table() {
    let cases: Vec<(String, NmeaError)> = vec![
        (
            "$GPZDA,201530.00,04,07,2002,00,00*61".into(),
            NmeaError::BadChecksum {
                computed: 0x60,
                received: 0x61,
            },
        ),
        (
            "$GPZDA,201530.00,04,07,2002,00,00".into(),
            NmeaError::NoChecksum,
        ),
        (
            "$GPZDA,201530.00,04,07,2002,00,00*6".into(),
            NmeaError::NoChecksum,
        ),
        (
            "$GPZDA,201530.00,04,07,2002,00,00*6G".into(),
            NmeaError::NoChecksum,
        ),
        (
            with_checksum("GPZDA,201530.00,04,07,2002,00,00").replace('$', ""),
            NmeaError::NoStart,
        ),
        (
            with_checksum("GPGGA,123519,4807.038,N"),
            NmeaError::Unsupported,
        ),
        (with_checksum("PUBX,04,073731.00"), NmeaError::Unsupported),
        (with_checksum("GP-ZDA,1"), NmeaError::Field("address")),
        (with_checksum("GPZDA,,,,,,"), NmeaError::Field("time")),
        (
            with_checksum("GPZDA,2015.00,04,07,2002,00,00"),
            NmeaError::Field("time"),
        ),
        (
            with_checksum("GPZDA,201530.x0,04,07,2002,00,00"),
            NmeaError::Field("time"),
        ),
        (
            with_checksum("GPZDA,241530.00,04,07,2002,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,206030.00,04,07,2002,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201561.00,04,07,2002,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201530.00,30,02,2024,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201530.00,29,02,2023,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201530.00,01,13,2023,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201530.00,01,01,1979,00,00"),
            NmeaError::BadDate,
        ),
        (
            with_checksum("GPZDA,201530.00,01,01"),
            NmeaError::Field("year"),
        ),
        (
            with_checksum("GPZDA,201530.00,0a,01,2020,00,00"),
            NmeaError::Field("day"),
        ),
        (
            with_checksum("GPRMC,123519,X,4807.038,N,01131.000,E,022.4,084.4,230394,,"),
            NmeaError::Field("status"),
        ),
        (
            with_checksum("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4"),
            NmeaError::Field("date"),
        ),
        (
            with_checksum("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,2303945,,"),
            NmeaError::Field("date"),
        ),
        (
            with_checksum("GPRMC,123519,A,,,,,,,320394,,"),
            NmeaError::BadDate,
        ),
    ];
    for (line, err) in cases {
        assert_eq!(parse_sentence(line.as_bytes()), Err(err), "{line}");
    }
}

#[test]
fn rmc_void_status_years_and_fractions() {
    let m = parse_sentence(with_checksum("GNRMC,000000.250,V,,,,,,,010180,,,N").as_bytes())
        .expect("parses");
    assert!(!m.valid());
    assert_eq!(
        m.time(),
        UtcDateTime {
            year: 1980,
            month: 1,
            day: 1,
            hour: 0,
            minute: 0,
            second: 0,
            millis: 250
        }
    );
    let m = parse_sentence(with_checksum("GNRMC,235959.999,A,,,,,,,311279,,,A").as_bytes())
        .expect("parses");
    assert_eq!(m.time().year, 2079);
    assert_eq!(m.time().millis, 999);
}

#[test]
fn line_buffer_splits_lines_and_bounds_length() {
    let mut buf = LineBuffer::new();
    let zda = "$GPZDA,201530.00,04,07,2002,00,00*60\r\n";
    let mut stream = Vec::new();
    stream.extend_from_slice(b"garbage before\r\n");
    stream.extend_from_slice(zda.as_bytes());
    stream.extend_from_slice(b"$GPZDA,2015"); // truncated line, restarted by the next '$'
    stream.extend_from_slice(zda.as_bytes());
    stream.extend(std::iter::repeat_n(b'A', 300));
    stream.extend_from_slice(b"\n");
    stream.extend_from_slice(zda.as_bytes());
    let out = feed(&mut buf, &stream);
    assert_eq!(out.len(), 5, "{out:?}");
    assert_eq!(out[0], Err(NmeaError::NoStart));
    assert!(out[1].is_ok() && out[2].is_ok() && out[4].is_ok());
    assert_eq!(out[3], Err(NmeaError::Overflow));
}

#[test]
fn gps_time_table() {
    // (UTC, GPS seconds, week, tow), with GPS - UTC = 18 s.
    let t = |y, mo, d, h, mi, s| UtcDateTime {
        year: y,
        month: mo,
        day: d,
        hour: h,
        minute: mi,
        second: s,
        millis: 0,
    };
    for (utc, secs, week, tow) in [
        (t(1980, 1, 6, 0, 0, 0), 18, 0, 18),
        (t(2000, 2, 29, 0, 0, 0), 635_817_618, 1051, 172_818),
        (t(2017, 1, 1, 0, 0, 0), 1_167_264_018, 1930, 18),
        (t(2024, 1, 1, 12, 30, 15), 1_388_147_433, 2295, 131_433),
        (t(2026, 11, 21, 23, 59, 59), 1_479_340_817, 2446, 17),
    ] {
        assert_eq!(utc.gps_seconds(), Ok(secs), "{utc:?}");
        assert_eq!(utc.gps_time(), Ok(GpsTime { week, tow }));
        assert_eq!(GpsTime { week, tow }.seconds(), secs);
        assert_eq!(UtcDateTime::from_gps_seconds(secs), Some(utc));
    }
    assert_eq!(
        t(1980, 1, 5, 23, 59, 0).gps_seconds(),
        Err(NmeaError::BadDate)
    );
    assert_eq!(UtcDateTime::from_gps_seconds(17), None);
    // A leap second maps onto the following second.
    assert_eq!(
        t(2016, 12, 31, 23, 59, 60).gps_seconds(),
        t(2017, 1, 1, 0, 0, 0).gps_seconds()
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Any bytes: no panic, and every line longer than the bound is an overflow.
    #[test]
    fn nmea_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut buf = LineBuffer::new();
        for r in feed(&mut buf, &bytes) {
            let _ = r;
        }
        let _ = parse_sentence(&bytes);
    }

    /// Mutating one byte of a good sentence never panics and is almost always caught.
    #[test]
    fn nmea_single_byte_corruption(pos in 0usize..36, byte in any::<u8>()) {
        let mut line = b"$GPZDA,201530.00,04,07,2002,00,00*60".to_vec();
        let original = line[pos];
        line[pos] = byte;
        let r = parse_sentence(&line);
        if byte != original && pos > 0 && pos < 33 {
            prop_assert!(r.is_err());
        }
    }

    /// Formatted valid dates parse back to themselves and round-trip through GPS seconds.
    #[test]
    fn zda_round_trip(days in 0i64..40_000, sod in 0u32..86_400, millis in 0u16..1000) {
        let (y, m, d) = civil_from_days(days + days_from_civil(1980, 1, 6));
        let (h, mi, s) = (sod / 3600, sod / 60 % 60, sod % 60);
        let line = with_checksum(&format!("GNZDA,{h:02}{mi:02}{s:02}.{millis:03},{d:02},{m:02},{y},00,00"));
        prop_assert!(line.len() <= MAX_SENTENCE);
        let utc = parse_sentence(line.as_bytes()).expect("valid").time();
        prop_assert_eq!(
            (i64::from(utc.year), u32::from(utc.month), u32::from(utc.day)),
            (y, m, d)
        );
        prop_assert_eq!(utc.millis, millis);
        let gps = utc.gps_seconds().expect("after epoch");
        let back = UtcDateTime::from_gps_seconds(gps).expect("after epoch");
        prop_assert_eq!(back, UtcDateTime { millis: 0, ..utc });
    }
}

/// Second 60 is a leap second only at 23:59:60 (`000060.00` became 00:01:00);
/// the leap second itself still parses and maps onto the next second.
#[test]
fn nmea_second_60_only_at_23_59_60() {
    assert_eq!(
        parse_sentence(b"$GPZDA,000060.00,01,01,2024,00,00*64\r"),
        Err(NmeaError::BadDate)
    );
    for t in ["000060.00", "235860.00", "225960.00", "120060"] {
        for s in [
            with_checksum(&format!("GPZDA,{t},31,12,2016,00,00")),
            with_checksum(&format!(
                "GPRMC,{t},A,4807.038,N,01131.000,E,0.0,0.0,311216,,"
            )),
        ] {
            let got = parse_sentence(format!("{s}\r").as_bytes());
            assert_eq!(got, Err(NmeaError::BadDate), "{s}");
        }
    }
    let leap = with_checksum("GPZDA,235960.00,31,12,2016,00,00");
    let Ok(TimeMessage::Zda(t)) = parse_sentence(format!("{leap}\r").as_bytes()) else {
        panic!("{leap} refused");
    };
    assert_eq!((t.hour, t.minute, t.second), (23, 59, 60));
    let next = UtcDateTime {
        year: 2017,
        month: 1,
        day: 1,
        hour: 0,
        minute: 0,
        second: 0,
        millis: 0,
    };
    assert_eq!(t.gps_seconds(), next.gps_seconds());
    let bad = UtcDateTime { minute: 58, ..t };
    assert_eq!(bad.gps_seconds(), Err(NmeaError::BadDate));
}
