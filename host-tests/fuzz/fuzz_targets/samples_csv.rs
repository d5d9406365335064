//! odoctl's SAMPLES CSV reader on any text.
//!
//! Oracles: no panic; an accepted file has finite, strictly increasing times and finite
//! pose columns.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(samples) = odoctl::csvio::parse_samples("fuzz.csv", text) else {
        return;
    };
    for w in samples.windows(2) {
        assert!(w[0].t < w[1].t, "{} then {}", w[0].t, w[1].t);
    }
    for s in &samples {
        assert!(s.t.is_finite());
        if let Some(u) = &s.unit {
            let v = [u.x, u.y, u.heading];
            assert!(v.iter().all(|v| v.is_finite()), "{u:?}");
        }
    }
});
