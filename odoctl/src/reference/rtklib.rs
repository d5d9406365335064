//! An RTKLIB solution file (`.pos`, RTKPOST / RTKNAVI / rnx2rtkp): `%` header lines, then one
//! row per epoch: time, latitude, longitude, height, `Q`, `ns`, `sdn sde sdu sdne sdeu sdun`,
//! `age`, `ratio`.
//!
//! Time as `yyyy/mm/dd hh:mm:ss.sss` or `week tow`, in GPST (or in UTC when the column header
//! says `UTC`: converted with the leap seconds of the date, or `--leap-seconds` when given). Latitude and longitude in degrees, or in
//! degrees minutes seconds (`latitude(d'")`, three columns each). Q: 1 fix, 2 float, 3 SBAS,
//! 4 DGPS, 5 single, 6 PPP. Heights are ellipsoidal unless the header says geodetic (then
//! only the local up changes, not east and north). Solutions in ECEF or ENU (`x-ecef(m)`,
//! `e-baseline(m)`) are refused with the setting that writes latitude and longitude.
//! Malformed rows are counted and skipped; the file fails only when no row is usable.
//! Hand-written: no crate on the registry reads `.pos` files.

use anyhow::{bail, Result};
use odo_unit::timing::nmea::days_from_civil;

use super::geodetic::Geodetic;
use super::{gps_time, Epoch, FixQuality, GeodeticLog, ReadReport};
use crate::text::excerpt;

/// The Q column's meaning.
pub fn fix_quality(q: u32) -> FixQuality {
    match q {
        1 => FixQuality::RtkFixed,
        2 => FixQuality::RtkFloat,
        3 => FixQuality::Sbas,
        4 => FixQuality::Dgps,
        5 => FixQuality::Single,
        6 => FixQuality::Ppp,
        _ => FixQuality::Invalid,
    }
}

/// What the column header says.
#[derive(Debug, Clone, Copy, Default)]
struct Layout {
    /// Times are UTC (else GPST).
    utc: bool,
    /// Latitude and longitude in degrees, minutes, seconds.
    dms: bool,
}

/// Reads a column header line (`%  GPST  latitude(deg) ...`); `Err` for layouts not read.
fn header(file: &str, line: usize, h: &str) -> Result<Option<Layout>> {
    let h = h.trim_start_matches('%').trim();
    let Some(first) = h.split_whitespace().next() else {
        return Ok(None);
    };
    if !matches!(first, "GPST" | "UTC" | "JST") {
        return Ok(None);
    }
    if first == "JST" {
        bail!("{file}:{line}: times in JST: write the solution in GPST (RTKLIB out-timesys=gpst)");
    }
    if h.contains("ecef") || h.contains("baseline") {
        bail!(
            "{file}:{line}: the solution is not latitude/longitude/height (RTKLIB out-solformat=llh)"
        );
    }
    Ok(Some(Layout {
        utc: first == "UTC",
        dms: h.contains("(d'\")"),
    }))
}

/// One data row: (GPS time, position, Q, sigmas).
fn row(tokens: &[&str], layout: Layout, leap_seconds: Option<i32>) -> Result<Epoch, String> {
    let num = |i: usize, what: &str| -> Result<f64, String> {
        let v = tokens
            .get(i)
            .ok_or_else(|| format!("{} columns, no {what}", tokens.len()))?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{what} `{}` is not a number", excerpt(v)))
    };
    let first = tokens.first().copied().unwrap_or("");
    let gps_time = if first.contains('/') {
        let clock = tokens.get(1).copied().unwrap_or("");
        let fields = || -> Option<(i64, u32, u32, u32, u32, f64)> {
            let mut d = first.split('/');
            let mut t = clock.split(':');
            let v = (
                d.next()?.parse().ok()?,
                d.next()?.parse().ok()?,
                d.next()?.parse().ok()?,
                t.next()?.parse().ok()?,
                t.next()?.parse().ok()?,
                t.next()?.parse().ok()?,
            );
            (d.next().is_none() && t.next().is_none()).then_some(v)
        };
        let Some((y, m, dd, hh, mm, ss)) = fields() else {
            return Err(format!(
                "time `{}` is not yyyy/mm/dd hh:mm:ss",
                excerpt(&format!("{first} {clock}"))
            ));
        };
        if !(1..=12).contains(&m)
            || !(1..=31).contains(&dd)
            || hh > 23
            || mm > 59
            || !(0.0..61.0).contains(&ss)
        {
            return Err(format!(
                "time `{}` is out of range",
                excerpt(&format!("{first} {clock}"))
            ));
        }
        let days = days_from_civil(y, m, dd);
        if odo_unit::timing::nmea::civil_from_days(days) != (y, m, dd) {
            return Err(format!("date `{}` does not exist", excerpt(first)));
        }
        let sod = f64::from(hh * 3600 + mm * 60) + ss;
        let leap = if layout.utc {
            gps_time::leap_seconds_for(days, leap_seconds)
        } else {
            0
        };
        gps_time::utc_to_gps(days, sod, leap).map_err(|e| e.to_string())?
    } else {
        let week = first
            .parse::<u32>()
            .map_err(|_| format!("`{}` is neither a date nor a GPS week", excerpt(first)))?;
        let tow = num(1, "time of week")?;
        if !(0.0..gps_time::WEEK).contains(&tow) {
            return Err(format!("time of week {tow} is outside 0..604800 s"));
        }
        f64::from(week) * gps_time::WEEK + tow
    };
    let angle = |i: usize, what: &str| -> Result<(f64, usize), String> {
        if layout.dms {
            let d = num(i, what)?;
            let m = num(i + 1, what)?;
            let s = num(i + 2, what)?;
            let sign = if tokens[i].starts_with('-') {
                -1.0
            } else {
                1.0
            };
            Ok((sign * (d.abs() + m / 60.0 + s / 3600.0), i + 3))
        } else {
            Ok((num(i, what)?, i + 1))
        }
    };
    let (lat, i) = angle(2, "latitude")?;
    let (lon, i) = angle(i, "longitude")?;
    let height = num(i, "height")?;
    let q = tokens
        .get(i + 1)
        .and_then(|v| v.parse::<u32>().ok())
        .ok_or_else(|| {
            format!(
                "Q `{}` is not an integer",
                excerpt(tokens.get(i + 1).unwrap_or(&""))
            )
        })?;
    let position = Geodetic {
        lat_deg: lat,
        lon_deg: lon,
        height,
    }
    .checked()
    .map_err(|e| e.to_string())?;
    // sdn, sde, sdu after ns.
    let sigma = match (num(i + 3, "sdn"), num(i + 4, "sde"), num(i + 5, "sdu")) {
        (Ok(n), Ok(e), Ok(u)) => Some([n, e, u]),
        _ => None,
    };
    Ok(Epoch {
        gps_time,
        position,
        heading: None,
        sigma_north_east_up: sigma,
        fix: fix_quality(q),
        line: 0,
    })
}

/// Parses a `.pos` file; `file` names it in messages. UTC times become GPS time with
/// `leap_seconds` when given, else with those of their date (GPST times need none).
pub fn parse(file: &str, text: &str, leap_seconds: Option<i32>) -> Result<GeodeticLog> {
    let mut report = ReadReport::default();
    let mut layout = Layout::default();
    let mut epochs: Vec<Epoch> = Vec::new();
    for (line, raw) in crate::text::lines(text) {
        let l = raw.trim();
        if l.is_empty() {
            continue;
        }
        if l.starts_with('%') {
            if let Some(h) = header(file, line, l)? {
                layout = h;
            }
            continue;
        }
        let tokens: Vec<&str> = l.split_whitespace().collect();
        match row(&tokens, layout, leap_seconds) {
            Ok(mut e) => {
                e.line = line;
                if let Some(last) = epochs.last() {
                    if e.gps_time <= last.gps_time {
                        report.unusable(format!(
                            "{file}:{line}: time is not after the previous epoch's (line {}): skipped",
                            last.line
                        ));
                        continue;
                    }
                }
                if layout.utc && report.warnings.is_empty() {
                    let (days, _) =
                        gps_time::gps_to_utc(e.gps_time, gps_time::DEFAULT_LEAP_SECONDS);
                    report.warnings.extend(gps_time::leap_table_warning(
                        format_args!("{file}:{line}"),
                        days,
                        leap_seconds,
                    ));
                }
                report.used("pos");
                epochs.push(e);
            }
            Err(why) => report.corrupt(format!("{file}:{line}: {why}")),
        }
    }
    if epochs.is_empty() {
        bail!("{file}: no usable solution row: {report}");
    }
    Ok(GeodeticLog { epochs, report })
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "% program   : RTKPOST ver.2.4.3 b34\n\
        % (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n";

    #[test]
    fn calendar_and_week_tow_agree() {
        let cal = format!(
            "{HEADER}%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n\
             2024/02/04 00:00:00.000   49.200000000   16.600000000   300.0000   1  12   0.0057   0.0058   0.0113  -0.0010   0.0000   0.0000   1.00  999.9\n\
             2024/02/04 00:00:00.100  -49.200000000  -16.600000000   300.0000   2  12   0.0557   0.0558   0.1113   0.0000   0.0000   0.0000   1.10    2.1\n"
        );
        let wt = format!(
            "{HEADER}%  GPST          latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n\
             2300      0.000   49.200000000   16.600000000   300.0000   1  12   0.0057   0.0058   0.0113  -0.0010   0.0000   0.0000   1.00  999.9\n\
             2300      0.100  -49.200000000  -16.600000000   300.0000   2  12   0.0557   0.0558   0.1113   0.0000   0.0000   0.0000   1.10    2.1\n"
        );
        let a = parse("c.pos", &cal, Some(18)).unwrap();
        let b = parse("w.pos", &wt, Some(18)).unwrap();
        for l in [&a, &b] {
            assert_eq!(l.epochs.len(), 2);
            assert_eq!(l.epochs[0].gps_time, 2300.0 * gps_time::WEEK);
            assert!((l.epochs[1].gps_time - 2300.0 * gps_time::WEEK - 0.1).abs() < 1e-6);
            assert_eq!(l.epochs[0].fix, FixQuality::RtkFixed);
            assert_eq!(l.epochs[1].fix, FixQuality::RtkFloat);
            assert_eq!(
                l.epochs[0].sigma_north_east_up,
                Some([0.0057, 0.0058, 0.0113])
            );
            assert_eq!(l.epochs[1].position.lat_deg, -49.2);
            assert_eq!(l.epochs[1].position.lon_deg, -16.6);
            assert_eq!(l.epochs[0].line, 4);
        }
    }

    #[test]
    fn utc_header_applies_the_leap_seconds_and_dms_is_read() {
        let t = "%  UTC                   latitude(d'\")   longitude(d'\")  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n\
                 2024/02/03 23:59:42.000  -49 12 00.0000  -16 36 36.0000   300.0000   1  12   0.0057   0.0058   0.0113  0 0 0 1.0 999.9\n";
        let l = parse("u.pos", t, Some(18)).unwrap();
        assert_eq!(l.epochs[0].gps_time, 2300.0 * gps_time::WEEK);
        assert!((l.epochs[0].position.lat_deg + 49.2).abs() < 1e-12);
        assert!((l.epochs[0].position.lon_deg + 16.61).abs() < 1e-12);
    }

    #[test]
    fn utc_times_take_the_leap_seconds_of_their_date() {
        let head = "%  UTC                   latitude(deg) longitude(deg)  height(m)   Q  ns\n";
        let pos = |date: &str| format!("{head}{date} 12:00:00.000  49.2  16.6  300.0  1  12\n");
        let gps =
            |y, m, d, leap| gps_time::utc_to_gps(days_from_civil(y, m, d), 43_200.0, leap).unwrap();
        let l = parse("u.pos", &pos("2014/03/15"), None).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps(2014, 3, 15, 16));
        assert!(l.report.warnings.is_empty());
        let l = parse("u.pos", &pos("2014/03/15"), Some(18)).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps(2014, 3, 15, 18));
        let l = parse("u.pos", &pos("2040/05/01"), None).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps(2040, 5, 1, 18));
        assert!(l.report.warnings[0].starts_with("u.pos:2: date 2040-05-01"));
        // GPST needs no leap seconds, whatever the date.
        let g = pos("2040/05/01").replace("UTC ", "GPST");
        let l = parse("g.pos", &g, None).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps(2040, 5, 1, 0));
        assert!(l.report.warnings.is_empty());
    }

    #[test]
    fn q_table() {
        use FixQuality::*;
        let want = [
            Invalid, RtkFixed, RtkFloat, Sbas, Dgps, Single, Ppp, Invalid,
        ];
        for (q, w) in want.iter().enumerate() {
            assert_eq!(fix_quality(q as u32), *w);
        }
    }

    #[test]
    fn bad_rows_counted_and_layouts_refused() {
        let t = format!(
            "{HEADER}2300 1.0 49.2 16.6 300 1 12 0.01 0.01 0.02 0 0 0 1 9\n\
             2300 x 49.2 16.6 300 1 12 0.01 0.01 0.02 0 0 0 1 9\n\
             2300 604800.0 49.2 16.6 300 1 12\n\
             2024/13/01 00:00:00.0 49.2 16.6 300 1 12\n\
             2300 2.0 95.0 16.6 300 1 12\n\
             2300 0.5 49.2 16.6 300 1 12\n\
             2300 3.0 49.2 16.6 300 4\n"
        );
        let l = parse("b.pos", &t, Some(18)).unwrap();
        assert_eq!(l.epochs.len(), 2);
        assert_eq!(l.epochs[1].sigma_north_east_up, None);
        assert_eq!(l.epochs[1].fix, FixQuality::Dgps);
        assert_eq!(
            (l.report.corrupt, l.report.unusable),
            (4, 1),
            "{}",
            l.report
        );
        assert!(
            l.report.problems[0].starts_with("b.pos:4: time of week `x`"),
            "{:?}",
            l.report.problems
        );
        assert!(
            l.report.problems[3].contains("latitude 95"),
            "{:?}",
            l.report.problems
        );
        let e = parse(
            "b.pos",
            "%  GPST  x-ecef(m) y-ecef(m) z-ecef(m) Q\n",
            Some(18),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("b.pos:1:") && e.contains("out-solformat=llh"),
            "{e}"
        );
        let e = parse("b.pos", &format!("{HEADER}garbage\n"), Some(18))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("b.pos: no usable") && e.contains("b.pos:3:"),
            "{e}"
        );
    }

    #[test]
    fn errors_quote_binary_tokens_short_and_escaped() {
        let bin: String = (0..600u32)
            .map(|i| char::from_u32(i % 0x7f + 0x80).unwrap_or('?'))
            .collect();
        let text = format!(
            "2024/02/04 00:00:00.000 {bin} 16.6 300 1 12 0.01 0.01 0.02 0 0 0 1.0 99.9\r\n"
        );
        let e = parse("b.pos", &text, None).unwrap_err().to_string();
        assert!(e.contains("b.pos:1: latitude `"), "{e}");
        assert!(
            e.len() < 400 && !e.chars().any(|c| c.is_control() && c != '\n'),
            "{e}"
        );
    }
}
