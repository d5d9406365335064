//! UTC and GPS time for receiver logs, in f64 seconds since the GPS epoch (1980-01-06 00:00:00
//! GPS). The calendar arithmetic and the UTC -> GPS mapping are the firmware's
//! (`odo_unit::timing::nmea`); this adds the fraction of the second and GPS - UTC by date
//! ([`leap_seconds_on`]) or as given (`--leap-seconds N`).

use anyhow::{anyhow, Result};
use odo_unit::timing::nmea::{civil_from_days, days_from_civil, UtcDateTime};
pub use odo_unit::timing::nmea::{GPS_UTC_LEAP_SECONDS, SECONDS_PER_WEEK};

/// GPS minus UTC (s) now: 18 since 2017-01-01 (the last entry of the leap-second table).
pub const DEFAULT_LEAP_SECONDS: i32 = GPS_UTC_LEAP_SECONDS as i32;
/// GPS - UTC (s) from each UTC date on, (year, month, day, seconds), since the GPS epoch
/// 1980-01-06 (0 s). Checked against the IERS Bulletin C through the last bulletin we checked,
/// 2026 (no leap second after 2017-01-01); see [`LEAP_TABLE_VALID_UNTIL`].
const LEAP_TABLE: [(i64, u32, u32, i32); 19] = [
    (1980, 1, 6, 0),
    (1981, 7, 1, 1),
    (1982, 7, 1, 2),
    (1983, 7, 1, 3),
    (1985, 7, 1, 4),
    (1988, 1, 1, 5),
    (1990, 1, 1, 6),
    (1991, 1, 1, 7),
    (1992, 7, 1, 8),
    (1993, 7, 1, 9),
    (1994, 7, 1, 10),
    (1996, 1, 1, 11),
    (1997, 7, 1, 12),
    (1999, 1, 1, 13),
    (2006, 1, 1, 14),
    (2009, 1, 1, 15),
    (2012, 7, 1, 16),
    (2015, 7, 1, 17),
    (2017, 1, 1, 18),
];

/// The last UTC date (year, month, day) [`LEAP_TABLE`] is known to hold for: the end of 2026,
/// the year of the last bulletin we checked. Later dates get its last count, with a warning.
pub const LEAP_TABLE_VALID_UNTIL: (i64, u32, u32) = (2026, 12, 31);

/// GPS - UTC (s) on a UTC day (days since 1970-01-01); 0 before 1980-01-06, the last known
/// count (18) after [`LEAP_TABLE_VALID_UNTIL`].
pub fn leap_seconds_on(days: i64) -> i32 {
    LEAP_TABLE
        .iter()
        .rev()
        .find(|&&(y, m, d, _)| days >= days_from_civil(y, m, d))
        .map_or(0, |e| e.3)
}

/// Whether [`leap_seconds_on`] is known to hold on a UTC day (days since 1970-01-01).
pub fn leap_table_covers(days: i64) -> bool {
    let (y, m, d) = LEAP_TABLE_VALID_UNTIL;
    days <= days_from_civil(y, m, d)
}

/// GPS - UTC (s) on a UTC day: `given` (`--leap-seconds`) when there is one, else the table's.
pub fn leap_seconds_for(days: i64, given: Option<i32>) -> i32 {
    given.unwrap_or_else(|| leap_seconds_on(days))
}

/// The warning for a UTC day past [`LEAP_TABLE_VALID_UNTIL`] read with the table, `None`
/// when the table covers it or the leap seconds are `given`; `at` names the place (`FILE:LINE`).
pub fn leap_table_warning(
    at: impl std::fmt::Display,
    days: i64,
    given: Option<i32>,
) -> Option<String> {
    if given.is_some() || leap_table_covers(days) {
        return None;
    }
    let (y, m, d) = civil_from_days(days);
    let (vy, vm, vd) = LEAP_TABLE_VALID_UNTIL;
    Some(format!(
        "{at}: date {y:04}-{m:02}-{d:02} is past the leap-second table \
         ({vy:04}-{vm:02}-{vd:02}): GPS - UTC taken as {} s; give --leap-seconds if a leap \
         second has been inserted since",
        leap_seconds_on(days)
    ))
}

/// GPS - UTC (s) at GPS seconds by the table (for messages).
pub fn leap_seconds_at_gps(gps: f64) -> i32 {
    let first = leap_seconds_on(gps_to_utc(gps, DEFAULT_LEAP_SECONDS).0);
    leap_seconds_on(gps_to_utc(gps, first).0)
}

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
    fn leap_seconds_by_date() {
        let on = |y, m, d| leap_seconds_on(days_from_civil(y, m, d));
        assert_eq!(on(1980, 1, 6), 0);
        assert_eq!(on(1981, 6, 30), 0);
        assert_eq!(on(1981, 7, 1), 1);
        assert_eq!(on(1999, 8, 21), 13);
        assert_eq!(on(2008, 6, 1), 14);
        assert_eq!(on(2014, 3, 15), 16);
        // The 2015 leap second: 16 through 2015-06-30 23:59:60, 17 from 2015-07-01.
        assert_eq!(on(2015, 6, 30), 16);
        assert_eq!(on(2015, 7, 1), 17);
        assert_eq!(on(2016, 12, 31), 17);
        assert_eq!(on(2017, 1, 1), 18);
        assert_eq!(on(2026, 11, 27), 18);
        assert_eq!(on(2040, 1, 1), 18);
        // Across the boundary GPS time runs on by two seconds over one UTC second (the leap
        // second between them).
        let before = utc_to_gps(days_from_civil(2015, 6, 30), 86_399.0, on(2015, 6, 30)).unwrap();
        let after = utc_to_gps(days_from_civil(2015, 7, 1), 0.0, on(2015, 7, 1)).unwrap();
        assert_eq!(after - before, 2.0);
        assert_eq!(leap_seconds_at_gps(after), 17);
        assert_eq!(leap_seconds_at_gps(before), 16);
        assert!(leap_table_covers(days_from_civil(2026, 12, 31)));
        assert!(!leap_table_covers(days_from_civil(2027, 1, 1)));
        assert_eq!(leap_seconds_for(days_from_civil(2014, 1, 1), Some(18)), 18);
        assert_eq!(leap_seconds_for(days_from_civil(2014, 1, 1), None), 16);
        let w = leap_table_warning("f:3", days_from_civil(2040, 5, 1), None).unwrap();
        assert!(
            w.starts_with("f:3: date 2040-05-01 is past the leap-second table"),
            "{w}"
        );
        assert!(leap_table_warning("f:3", days_from_civil(2040, 5, 1), Some(18)).is_none());
        assert!(leap_table_warning("f:3", days_from_civil(2026, 5, 1), None).is_none());
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
