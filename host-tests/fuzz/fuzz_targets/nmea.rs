//! The firmware's NMEA time parser (ZDA, RMC) on any bytes from the receiver's UART.
//!
//! Oracles: no panic; a parsed time is a time of day (second 60 only at 23:59:60) with
//! millis below 1000; its GPS time converts back to the same UTC date and time (a leap
//! second to the next second); the GPS week and time of week give the same GPS second.
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_unit::timing::nmea::{parse_sentence, GpsTime, LineBuffer, UtcDateTime};

fuzz_target!(|data: &[u8]| {
    // One sentence as a whole, then the stream through the line buffer.
    let _ = parse_sentence(data);
    let mut lines = LineBuffer::new();
    for &b in data {
        let Some(Ok(msg)) = lines.push(b) else {
            continue;
        };
        let t = msg.time();
        assert!(t.hour <= 23 && t.minute <= 59 && t.millis < 1000, "{t:?}");
        assert!(
            t.second <= 59 || (t.second == 60 && t.hour == 23 && t.minute == 59),
            "{t:?}"
        );
        let Ok(gps) = t.gps_seconds() else {
            continue;
        };
        let back = UtcDateTime::from_gps_seconds(gps).expect("after the GPS epoch");
        if t.second == 60 {
            assert_eq!((back.hour, back.minute, back.second), (0, 0, 0), "{t:?}");
        } else {
            assert_eq!(back, UtcDateTime { millis: 0, ..t }, "{t:?}");
        }
        assert_eq!(GpsTime::from_seconds(gps).seconds(), gps);
        assert_eq!(t.gps_time().map(|g| g.seconds()), Ok(gps));
    }
});
