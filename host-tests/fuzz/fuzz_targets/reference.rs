//! odoctl's reference readers (REFERENCE CSV, NMEA 0183 log, RTKLIB `.pos`, u-blox UBX, TUM
//! trajectory, MCAP recording, recognised from the content or forced) on any bytes; a fifth of the inputs get a valid
//! UBX NAV-PVT frame in front, so that the UBX reader meets its frames among the fuzzed bytes.
//!
//! Oracles: no panic; an accepted reference has finite coordinates and strictly increasing
//! times, and every epoch passes the fix-quality filter; binary data starting with `%` before
//! a text never makes it RTKLIB; a date sentence before the GPS epoch put in front of an NMEA
//! log is counted and skipped, changing no epoch.
#![no_main]

use libfuzzer_sys::fuzz_target;
use odoctl::reference::{self, Format, ReferenceOptions};

fuzz_target!(|data: &[u8]| {
    let Some((&choice, bytes)) = data.split_first() else {
        return;
    };
    let format = match choice % 7 {
        0 => None,
        1 => Some(Format::Csv),
        2 => Some(Format::Nmea),
        3 => Some(Format::Rtklib),
        4 => Some(Format::Tum),
        5 => Some(Format::Mcap),
        _ => Some(Format::Ubx),
    };
    // A valid NAV-PVT (RTK fixed, dated) in front of the bytes when the high bit says so.
    let framed: Vec<u8>;
    let bytes = if choice & 0x80 != 0 {
        let mut p = [0u8; 92];
        p[4..6].copy_from_slice(&2024u16.to_le_bytes());
        p[6..11].copy_from_slice(&[3, 15, 11, 59, 42]);
        p[11] = 0x07;
        p[20] = 3;
        p[21] = 0x83;
        p[28..32].copy_from_slice(&492_000_000i32.to_le_bytes());
        framed = [reference::ubx::frame(0x01, 0x07, &p), bytes.to_vec()].concat();
        &framed[..]
    } else {
        bytes
    };
    let options = ReferenceOptions {
        format,
        ..ReferenceOptions::default()
    };
    // A `%` line of binary data is no RTKLIB header.
    let text = String::from_utf8_lossy(bytes);
    if reference::detect(&text) != Format::Rtklib {
        let prefixed = format!("%\u{1}\u{fffd}\n{text}");
        assert_ne!(reference::detect(&prefixed), Format::Rtklib, "{prefixed:?}");
    }
    let result = reference::parse("fuzz.ref", bytes, &options);
    if format == Some(Format::Nmea) {
        // One RMC dated 1980-01-01 in front: counted and skipped, the same epochs.
        let mut early = reference::nmea::with_checksum("GPRMC,120000.00,A,,,,,0.0,0.0,010180,,,A");
        early.push('\n');
        early.push_str(&text);
        let again = reference::parse("fuzz.ref", early.as_bytes(), &options);
        let key = |r: &reference::Reference| -> Vec<(u64, u64, u64)> {
            r.epochs
                .iter()
                .map(|e| (e.t.to_bits(), e.x.to_bits(), e.y.to_bits()))
                .collect()
        };
        match (&result, &again) {
            (Ok(a), Ok(b)) => assert_eq!(key(a), key(b)),
            (Err(_), Err(_)) => {}
            _ => panic!("a date before the GPS epoch changed the outcome: {result:?} {again:?}"),
        }
    }
    let Ok(r) = result else {
        return;
    };
    for w in r.epochs.windows(2) {
        assert!(w[0].t < w[1].t, "{} then {}", w[0].t, w[1].t);
    }
    for e in &r.epochs {
        assert!(
            e.t.is_finite() && e.x.is_finite() && e.y.is_finite(),
            "{e:?}"
        );
        assert!(options.min_fix.accepts(e.fix), "{e:?}");
    }
});
