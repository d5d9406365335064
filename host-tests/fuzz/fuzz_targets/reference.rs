//! odoctl's reference readers (REFERENCE CSV, NMEA 0183 log, RTKLIB `.pos`, recognised from
//! the content or forced) on any bytes.
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
    let format = match choice % 4 {
        0 => None,
        1 => Some(Format::Csv),
        2 => Some(Format::Nmea),
        _ => Some(Format::Rtklib),
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
