//! UTC and GPS time for receiver logs, in f64 seconds since the GPS epoch (1980-01-06 00:00:00
//! GPS). The calendar arithmetic and the UTC -> GPS mapping are the firmware's
//! (`odo_unit::timing::nmea`); this only adds the fraction of the second and a leap-second count
//! other than the core's built-in [`GPS_UTC_LEAP_SECONDS`] (`--leap-seconds N`).

use anyhow::{anyhow, Result};
use odo_unit::timing::nmea::{civil_from_days, days_from_civil, UtcDateTime};
pub use odo_unit::timing::nmea::{GPS_UTC_LEAP_SECONDS, SECONDS_PER_WEEK};

/// GPS minus UTC (s) unless `--leap-seconds` says otherwise: 18 since 2017-01-01.
pub const DEFAULT_LEAP_SECONDS: i32 = GPS_UTC_LEAP_SECONDS as i32;
/// Seconds in a day.
pub const DAY: f64 = 86_400.0;
/// A GPS week (s).
pub const WEEK: f64 = SECONDS_PER_WEEK as f64;

/// Days from 1970-01-01 to the GPS epoch 1980-01-06.
pub fn gps_epoch_days() -> i64 {
    days_from_civil(1980, 1, 6)
}

/// GPS seconds of a UTC instant given as a day (days since 1970-01-01) and the seconds of that
/// day (`0 <= sod < 86_401`; 86_400.x is the leap second 23:59:60.x), with `leap_seconds` =
/// GPS - UTC. With `leap_seconds = 0` it converts a GPST calendar time.
pub fn utc_to_gps(days: i64, sod: f64, leap_seconds: i32) -> Result<f64> {
    if !(0.0..86_401.0).contains(&sod) {
        return Err(anyhow!("time of day {sod} s is out of range"));
    }
    let whole = sod.floor();
    let s = whole as u32;
    let (year, month, day) = civil_from_days(days);
    let utc = UtcDateTime {
        year: u16::try_from(year).map_err(|_| anyhow!("year {year} out of range"))?,
        month: month as u8,
        day: day as u8,
        hour: (s / 3600).min(23) as u8,
        minute: if s >= 86_400 { 59 } else { (s / 60 % 60) as u8 },
        second: if s >= 86_400 { 60 } else { (s % 60) as u8 },
        millis: 0,
    };
    // The core maps 23:59:60 onto the following second, as GPS time counts it.
    let gps = utc.gps_seconds().map_err(|e| {
        anyhow!("{year:04}-{month:02}-{day:02}: {e:?} (GPS time starts 1980-01-06)")
    })?;
    Ok(f64::from(gps) - f64::from(GPS_UTC_LEAP_SECONDS) + f64::from(leap_seconds) + (sod - whole))
}

/// The UTC calendar of GPS seconds, with `leap_seconds` = GPS - UTC: (days since 1970-01-01,
/// seconds of the day). Inverse of [`utc_to_gps`] outside leap seconds.
pub fn gps_to_utc(gps: f64, leap_seconds: i32) -> (i64, f64) {
    let utc = gps - f64::from(leap_seconds);
    let d = (utc / DAY).floor();
    (d as i64 + gps_epoch_days(), utc - d * DAY)
}

/// GPS week and time of week (s) of GPS seconds.
pub fn week_tow(gps: f64) -> (i64, f64) {
    let w = (gps / WEEK).floor();
    (w as i64, gps - w * WEEK)
}

/// `week W TOW s (UTC yyyy-mm-dd hh:mm:ss.sss)` for messages.
pub fn describe(gps: f64, leap_seconds: i32) -> String {
    let (w, tow) = week_tow(gps);
    let (days, sod) = gps_to_utc(gps, leap_seconds);
    let (y, m, d) = civil_from_days(days);
    let ms = (sod * 1000.0).round() as i64;
    format!(
        "GPS week {w} TOW {tow:.3} s (UTC {y:04}-{m:02}-{d:02} {:02}:{:02}:{:02}.{:03})",
        ms / 3_600_000,
        ms / 60_000 % 60,
        ms / 1000 % 60,
        ms % 1000
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boundary_table() {
        let day = |y, m, d| days_from_civil(y, m, d);
        // (days, sod, leap, GPS seconds) from the calendar by hand: GPS week 0 day 0; week
        // 1024 (1999-08-22, 13 leap seconds) and 2048 (2019-04-07); the 2017 leap second.
        let table: [(i64, f64, i32, f64); 6] = [
            (day(1980, 1, 6), 0.0, 0, 0.0),
            (day(1980, 1, 6), 0.5, 0, 0.5),
            (day(1999, 8, 21), 86_400.0 - 13.0, 13, 1024.0 * WEEK),
            (day(2019, 4, 7), 0.0, 18, 2048.0 * WEEK + 18.0),
            (day(2016, 12, 31), 86_399.5, 17, 1_167_264_016.5),
            (day(2017, 1, 1), 0.0, 18, 1_167_264_018.0),
        ];
        for (d, sod, leap, gps) in table {
            assert_eq!(utc_to_gps(d, sod, leap).unwrap(), gps, "{d} {sod} {leap}");
            let (d2, sod2) = gps_to_utc(gps, leap);
            assert_eq!((d2, sod2), (d, sod));
        }
        // 23:59:60.5 of the 2016 leap second with the old count is the same GPS second as the
        // first half of 2017 with the new one, as the receiver counts it.
        let leap = utc_to_gps(day(2016, 12, 31), 86_400.5, 17).unwrap();
        assert_eq!(leap, 1_167_264_017.5);
        // The leap-second count shifts everything by whole seconds.
        let a = utc_to_gps(day(2026, 11, 23), 3600.25, 18).unwrap();
        let b = utc_to_gps(day(2026, 11, 23), 3600.25, 19).unwrap();
        assert_eq!(b - a, 1.0);
        assert!(utc_to_gps(day(1979, 12, 31), 0.0, 18).is_err());
        assert!(utc_to_gps(day(2026, 1, 1), -0.1, 18).is_err());
    }

    #[test]
    fn week_rollover_and_description() {
        let (w, tow) = week_tow(2300.0 * WEEK - 0.25);
        assert_eq!((w, tow), (2299, WEEK - 0.25));
        assert_eq!(week_tow(2300.0 * WEEK), (2300, 0.0));
        let s = describe(2300.0 * WEEK + 18.0, 18);
        // Week 2300 begins on Sunday 2024-02-04 00:00:00 GPS.
        assert_eq!(
            s,
            "GPS week 2300 TOW 18.000 s (UTC 2024-02-04 00:00:00.000)"
        );
    }
}
