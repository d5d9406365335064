//! odoctl's reference readers (REFERENCE CSV, NMEA 0183 log, RTKLIB `.pos`, recognised from
//! the content or forced) on any bytes.
//!
//! Oracles: no panic; an accepted reference has finite coordinates and strictly increasing
//! times, and every epoch passes the fix-quality filter.
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
    let Ok(r) = reference::parse("fuzz.ref", bytes, &options) else {
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
