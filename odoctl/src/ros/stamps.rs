//! Header stamps: the sample's UTC time when the unit's GNSS time tag is valid (GPS time minus
//! the leap seconds of its date, [`gps_time::leap_seconds_at_gps`]), else the unit's MCU time;
//! one source per recording, named in the file's metadata.

use crate::csvio::Sample;
use crate::reference::gps_time;

/// GPS time of the GPS epoch (1980-01-06 00:00:00 UTC) as Unix time, seconds.
pub const GPS_EPOCH_UNIX: i64 = 315_964_800;
/// Seconds per GPS week.
pub const WEEK_SECONDS: i64 = 604_800;

/// GPS - UTC (s) at GPS week `week`, `tow_ms` milliseconds, by the leap-second table.
pub fn leap_seconds(week: u16, tow_ms: u32) -> i64 {
    let gps = f64::from(week) * WEEK_SECONDS as f64 + f64::from(tow_ms) * 1e-3;
    i64::from(gps_time::leap_seconds_at_gps(gps))
}

/// Unix UTC nanoseconds of GPS week `week`, `tow_ms` milliseconds plus `sub` seconds
/// (`0 <= sub`, the sample's place in its second), GPS - UTC taken from the table by the
/// date; `None` before 1970.
pub fn gps_to_unix_nanos(week: u16, tow_ms: u32, sub: f64) -> Option<u64> {
    let whole_ms = i64::from(week) * WEEK_SECONDS * 1000 + i64::from(tow_ms);
    let unix_ms = whole_ms + (GPS_EPOCH_UNIX - leap_seconds(week, tow_ms)) * 1000;
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
    /// GPS - UTC used (s) at the first sample, for UTC stamps.
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
            return Stamps {
                source: StampSource::Utc,
                nanos,
                extrapolated,
                leap_seconds: Some(leap_seconds(week, tow_ms)),
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
    fn gps_epoch() {
        let days = odo_unit::timing::nmea::days_from_civil(1980, 1, 6);
        assert_eq!(days * 86_400, GPS_EPOCH_UNIX);
    }

    /// UTC stamps take GPS - UTC of their date: 14 s in 2008, 16 s in 2014, 17 s up to the
    /// leap second at the end of 2016, 18 s from 2017-01-01 (GPS week 1930 starts on it).
    #[test]
    fn leap_seconds_by_date() {
        let day = |y, m, d| odo_unit::timing::nmea::days_from_civil(y, m, d) * 86_400;
        let unix_s =
            |week: u16, tow_ms: u32| gps_to_unix_nanos(week, tow_ms, 0.0).unwrap() / 1_000_000_000;
        // 2008-06-01 00:00:00 UTC: GPS week 1481 (from 2008-05-25), 7 days + 14 s.
        assert_eq!(
            unix_s(1481, (7 * 86_400 + 14) * 1000) as i64,
            day(2008, 6, 1)
        );
        // 2014-06-01 00:00:00 UTC: GPS week 1794 (from 2014-05-25).
        assert_eq!(
            unix_s(1794, (7 * 86_400 + 16) * 1000) as i64,
            day(2014, 6, 1)
        );
        // Across the leap second 2016-12-31 23:59:60.
        assert_eq!(unix_s(1930, 16_000) as i64, day(2017, 1, 1) - 1);
        assert_eq!(unix_s(1930, 18_000) as i64, day(2017, 1, 1));
        assert_eq!(
            (leap_seconds(1930, 16_000), leap_seconds(1930, 18_000)),
            (17, 18)
        );
    }

    #[test]
    fn gps_week_to_utc() {
        // GPS week 2296, 0 s = 2024-01-07 00:00:00 GPS = 2024-01-06 23:59:42 UTC.
        let ns = gps_to_unix_nanos(2296, 0, 0.0).unwrap();
        assert_eq!(
            ns,
            (odo_unit::timing::nmea::days_from_civil(2024, 1, 7) * 86_400 - 18) as u64
                * 1_000_000_000
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
