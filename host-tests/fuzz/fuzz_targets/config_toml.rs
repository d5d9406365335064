//! odoctl's parameter file reader (TOML with the shared key names) on any text.
//!
//! Oracles: no panic; accepted parameters pass the chassis validation, and written back as
//! TOML (every value a plain decimal, never an exponent) they read back to the same file text
//! (bit-exact values).
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_unit::odometry::ChassisParams;
use odoctl::config;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(p) = config::parse_params("fuzz.toml", text, ChassisParams::DESIGNED) else {
        return;
    };
    assert!(p.validate().is_ok(), "{p:?}");
    let written = config::render_params(&p, "fuzz", &[]);
    for line in written
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
    {
        let value = line.split_once(" = ").map_or("", |(_, v)| v);
        assert!(
            value.starts_with('"') || !value.contains(['e', 'E']),
            "{line}"
        );
    }
    let back = config::parse_params("written.toml", &written, ChassisParams::DESIGNED)
        .unwrap_or_else(|e| panic!("{e:#}\n{written}"));
    assert_eq!(config::render_params(&back, "fuzz", &[]), written);
});
