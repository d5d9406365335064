//! Header stamps: the sample's UTC time when the unit's GNSS time tag is valid (GPS time minus
//! the leap seconds), else the unit's MCU time; one source per recording, named in the file's
//! metadata.

use crate::csvio::Sample;

/// GPS time of the GPS epoch (1980-01-06 00:00:00 UTC) as Unix time, seconds.
pub const GPS_EPOCH_UNIX: i64 = 315_964_800;
/// Seconds per GPS week.
pub const WEEK_SECONDS: i64 = 604_800;

/// UTC dates (year, month) from which GPS - UTC grew by one second (IERS Bulletin C; the
/// last is 2017-01-01, GPS - UTC = 18 s). A leap second announced later needs this table
/// extended.
const LEAP_DATES: [(i64, u32); 18] = [
    (1981, 7),
    (1982, 7),
    (1983, 7),
    (1985, 7),
    (1988, 1),
    (1990, 1),
    (1991, 1),
    (1992, 7),
    (1993, 7),
    (1994, 7),
    (1996, 1),
    (1997, 7),
    (1999, 1),
    (2006, 1),
    (2009, 1),
    (2012, 7),
    (2015, 7),
    (2017, 1),
];

/// Days from 1970-01-01 to the first of `month` in `year` (proleptic Gregorian).
fn days_from_civil(year: i64, month: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(month);
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// GPS - UTC (s) at GPS time `gps_seconds` since the GPS epoch.
pub fn leap_seconds(gps_seconds: f64) -> i64 {
    let mut leap = 0;
    for (i, &(y, m)) in LEAP_DATES.iter().enumerate() {
        let n = i as i64 + 1;
        // At that UTC midnight GPS time reads UTC + n.
        let at = days_from_civil(y, m) * 86_400 - GPS_EPOCH_UNIX + n;
        if gps_seconds >= at as f64 {
            leap = n;
        }
    }
    leap
}

/// Unix UTC nanoseconds of GPS week `week`, `tow_ms` milliseconds plus `sub` seconds
/// (`0 <= sub`, the sample's place in its second); `None` before 1970.
pub fn gps_to_unix_nanos(week: u16, tow_ms: u32, sub: f64) -> Option<u64> {
    let whole_ms = i64::from(week) * WEEK_SECONDS * 1000 + i64::from(tow_ms);
    let leap = leap_seconds(whole_ms as f64 * 1e-3 + sub);
    let unix_ms = whole_ms + (GPS_EPOCH_UNIX - leap) * 1000;
    let ns = u64::try_from(unix_ms).ok()? * 1_000_000;
    Some(ns + (sub * 1e9).round() as u64)
}

/// Where the header stamps of a recording come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampSource {
    /// UTC from the unit's GNSS time tag (GPS time minus the leap seconds), Unix epoch.
    Utc,
    /// The unit's MCU time, seconds since it started.
    McuTime,
    /// The SAMPLES file's `t` column as it stands (a file without the unit's time columns,
    /// such as a simulated run).
    SamplesT,
}

impl StampSource {
    /// Name written into the recording's metadata (`stamp_source`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Utc => "utc_from_gps_time_tag",
            Self::McuTime => "mcu_time",
            Self::SamplesT => "samples_t",
        }
    }
}

/// Bit 2 of the status word: the GNSS time fields hold the sample's time.
const TIME_VALID: u64 = 1 << 2;

/// The stamps of a SAMPLES file.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamps {
    /// Their source.
    pub source: StampSource,
    /// One per sample, nanoseconds (Unix epoch for [`StampSource::Utc`]).
    pub nanos: Vec<u64>,
    /// Samples of a UTC recording without a valid tag, stamped by MCU time from the last
    /// tagged sample.
    pub extrapolated: usize,
    /// GPS - UTC used (s), for UTC stamps.
    pub leap_seconds: Option<i64>,
}

/// Chooses the stamp source of `samples` and stamps every sample.
///
/// UTC when the first sample's time tag is valid and its `t` is the tag's time (`record`
/// writes GNSS time of week when it knew the sample rate): the sub-second part is `t` minus
/// the second's time of week. Samples in between without a valid tag continue from the last
/// tagged one by MCU time (counted). MCU time when the file has the unit's time columns but
/// no usable tag; the file's `t` otherwise. Stamps must increase, as `t` does.
pub fn stamp(samples: &[Sample]) -> Stamps {
    let tag = |s: &Sample| {
        let time = s.unit.and_then(|u| u.time)?;
        let valid = s.flags.is_some_and(|f| f & TIME_VALID != 0);
        let tow = f64::from(time.gps_tow_ms) * 1e-3;
        let sub = s.t - tow;
        (valid && (0.0..1.0 + 1e-9).contains(&sub)).then_some((time.gps_week, time.gps_tow_ms, sub))
    };
    let mcu = |s: &Sample| s.unit.and_then(|u| u.time).map(|t| t.mcu_time_us);
    let first = samples.first();
    if let Some((week, tow_ms, sub)) = first.and_then(tag) {
        if let Some(ns0) = gps_to_unix_nanos(week, tow_ms, sub) {
            let mut nanos = Vec::with_capacity(samples.len());
            let mut last = (ns0, first.and_then(mcu));
            let mut extrapolated = 0;
            for s in samples {
                let ns = match tag(s).and_then(|(w, tow, sub)| gps_to_unix_nanos(w, tow, sub)) {
                    Some(ns) => ns,
                    None => {
                        extrapolated += 1;
                        match (last.1, mcu(s)) {
                            (Some(m0), Some(m1)) if m1 >= m0 => last.0 + (m1 - m0) * 1000,
                            _ => last.0 + ((s.t - samples[0].t).max(0.0) * 1e9) as u64,
                        }
                    }
                };
                last = (ns, mcu(s));
                nanos.push(ns);
            }
            let gps = f64::from(week) * WEEK_SECONDS as f64 + f64::from(tow_ms) * 1e-3;
            return Stamps {
                source: StampSource::Utc,
                nanos,
                extrapolated,
                leap_seconds: Some(leap_seconds(gps)),
            };
        }
    }
    if samples.iter().all(|s| mcu(s).is_some()) && !samples.is_empty() {
        return Stamps {
            source: StampSource::McuTime,
            nanos: samples.iter().map(|s| mcu(s).unwrap_or(0) * 1000).collect(),
            extrapolated: 0,
            leap_seconds: None,
        };
    }
    Stamps {
        source: StampSource::SamplesT,
        nanos: samples
            .iter()
            .map(|s| (s.t.max(0.0) * 1e9).round() as u64)
            .collect(),
        extrapolated: 0,
        leap_seconds: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csvio::{RecordTime, UnitPose};

    #[test]
    fn leap_second_table() {
        // GPS time at the epoch: 0; GPS-UTC was 0 until 1981-07-01, 18 since 2017-01-01.
        assert_eq!(leap_seconds(0.0), 0);
        let at_2017 = (days_from_civil(2017, 1) * 86_400 - GPS_EPOCH_UNIX) as f64;
        assert_eq!(leap_seconds(at_2017 + 17.0), 17);
        assert_eq!(leap_seconds(at_2017 + 18.0), 18);
        assert_eq!(leap_seconds(2.0e9), 18);
        assert_eq!(days_from_civil(1980, 1) + 5, GPS_EPOCH_UNIX / 86_400);
    }

    #[test]
    fn gps_week_to_utc() {
        // GPS week 2296, 0 s = 2024-01-07 00:00:00 GPS = 2024-01-06 23:59:42 UTC.
        let ns = gps_to_unix_nanos(2296, 0, 0.0).unwrap();
        assert_eq!(
            ns,
            (days_from_civil(2024, 1) * 86_400 + 6 * 86_400 - 18) as u64 * 1_000_000_000
        );
    }

    fn sample(t: f64, flags: u64, mcu: u64, tow_ms: u32) -> Sample {
        Sample {
            t,
            flags: Some(flags),
            unit: Some(UnitPose {
                time: Some(RecordTime {
                    mcu_time_us: mcu,
                    gps_week: 2295,
                    gps_tow_ms: tow_ms,
                }),
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    #[test]
    fn utc_with_a_gap_in_the_tag() {
        let s = [
            sample(100.98, 5, 1_000_000, 100_000),
            sample(101.0, 5, 1_020_000, 101_000),
            sample(101.02, 1, 1_040_000, 0),
            sample(101.04, 5, 1_060_000, 101_000),
        ];
        let st = stamp(&s);
        assert_eq!(st.source, StampSource::Utc);
        assert_eq!(st.extrapolated, 1);
        let base = gps_to_unix_nanos(2295, 0, 0.0).unwrap();
        let ms = [100_980, 101_000, 101_020, 101_040];
        // The untagged sample continues from the previous one by MCU time (20 ms).
        for (g, w) in st.nanos.iter().zip(ms) {
            assert_eq!(*g, base + w * 1_000_000);
        }
    }

    #[test]
    fn mcu_and_plain_t() {
        // Valid tag but `t` is MCU time (the rate was unknown to `record`): MCU stamps.
        let s = [
            sample(1.0, 5, 1_000_000, 100_000),
            sample(1.02, 4, 1_020_000, 100_000),
        ];
        let st = stamp(&s);
        assert_eq!(st.source, StampSource::McuTime);
        assert_eq!(st.nanos, vec![1_000_000_000, 1_020_000_000]);
        let plain = [
            Sample::default(),
            Sample {
                t: 0.5,
                ..Default::default()
            },
        ];
        let st = stamp(&plain);
        assert_eq!(st.source, StampSource::SamplesT);
        assert_eq!(st.nanos, vec![0, 500_000_000]);
    }
}
