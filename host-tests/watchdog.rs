//! Host tests of `odo_unit::unit::watchdog`: the IWDG prescaler and reload value for a
//! timeout, and the timeouts they give over the LSI's frequency range.

use odo_unit::unit::watchdog::{
    IwdgSetting, LSI_MAX_HZ, LSI_MIN_HZ, LSI_NOMINAL_HZ, MAX_PRESCALER, MAX_RELOAD,
};

/// The firmware's 4 s: /32 and reload 3999, exactly 4 s at 32 kHz, 2.72-7.53 s over the
/// LSI's range (the figures of docs/HARDWARE.md and `board::WATCHDOG_MIN_MS`).
#[test]
fn firmware_timeout() {
    let s = IwdgSetting::for_timeout(4_000, LSI_NOMINAL_HZ).expect("4 s is in range");
    assert_eq!(
        s,
        IwdgSetting {
            prescaler: 3,
            reload: 3_999
        }
    );
    assert_eq!(s.divider(), 32);
    assert_eq!(s.timeout_us(LSI_NOMINAL_HZ), 4_000_000);
    assert_eq!(s.timeout_us(LSI_MAX_HZ), 2_723_404);
    assert_eq!(s.timeout_us(LSI_MIN_HZ), 7_529_411);
    // The shortest timeout is 3.4 times the longest settings-sector erase (800 ms, x8).
    assert_eq!(s.timeout_us(LSI_MAX_HZ) / 1_000 * 10 / 800, 34);
}

/// What the counter does without the wait and the feed at start: it runs down from its
/// reset value 0xFFF at the new /256 prescaler, 32.8 s at a nominal LSI, 22-62 s over its
/// range.
#[test]
fn reset_reload_at_the_largest_prescaler() {
    let s = IwdgSetting {
        prescaler: MAX_PRESCALER,
        reload: MAX_RELOAD,
    };
    assert_eq!(s.divider(), 256);
    assert_eq!(s.timeout_us(LSI_NOMINAL_HZ), 32_768_000);
    assert_eq!(s.timeout_us(LSI_MAX_HZ) / 1_000_000, 22);
    assert_eq!(s.timeout_us(LSI_MIN_HZ) / 1_000_000, 61);
}

/// Every timeout the IWDG can give: the finest prescaler, a reload within 12 bits, and a
/// timeout that is the request rounded down to less than one counter step.
#[test]
fn every_millisecond_rounds_down_by_less_than_a_step() {
    for lsi in [LSI_MIN_HZ, LSI_NOMINAL_HZ, LSI_MAX_HZ] {
        let longest_ms = (u64::from(MAX_RELOAD) + 1) * 256 * 1_000 / u64::from(lsi);
        for ms in 1..=longest_ms as u32 {
            let Some(s) = IwdgSetting::for_timeout(ms, lsi) else {
                // Only a request shorter than one step at /4 has no setting.
                assert!(
                    u64::from(ms) * u64::from(lsi) / 1_000 < 4,
                    "{ms} ms at {lsi} Hz"
                );
                continue;
            };
            assert!(s.prescaler <= MAX_PRESCALER && s.reload <= MAX_RELOAD);
            let got = u64::from(s.timeout_us(lsi));
            let step_us = u64::from(s.divider()) * 1_000_000 / u64::from(lsi);
            assert!(
                got <= u64::from(ms) * 1_000,
                "{ms} ms at {lsi} Hz: {got} us"
            );
            assert!(
                got + step_us + 1 >= u64::from(ms) * 1_000,
                "{ms} ms at {lsi} Hz: {got} us"
            );
            if s.prescaler > 0 {
                // A finer prescaler would need more than 12 bits of reload.
                let finer_steps =
                    u64::from(ms) * u64::from(lsi) / 1_000 / (u64::from(s.divider()) / 2);
                assert!(
                    finer_steps > u64::from(MAX_RELOAD) + 1,
                    "{ms} ms at {lsi} Hz"
                );
            }
        }
        // The first request that needs 4097 steps at /256.
        let too_long = ((u64::from(MAX_RELOAD) + 2) * 256 * 1_000).div_ceil(u64::from(lsi)) as u32;
        assert!(IwdgSetting::for_timeout(too_long - 1, lsi).is_some());
        assert_eq!(
            IwdgSetting::for_timeout(too_long, lsi),
            None,
            "{too_long} ms"
        );
    }
    assert_eq!(IwdgSetting::for_timeout(0, LSI_NOMINAL_HZ), None);
}
