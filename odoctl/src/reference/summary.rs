//! What a user checks in a reference before a calibration drive is trusted (`odoctl
//! reference`): the epochs of every fix quality over time, the rate and gaps, the reported
//! sigmas, the origin and the heading source ([`Inspection`], [`Summary`]); and the track in
//! the formats other tools read ([`export`]: CSV, TUM, GeoJSON, GPX).

use std::collections::BTreeMap;
use std::io::Write;

use anyhow::{bail, Result};

use super::geodetic::{Geodetic, LocalFrame};
use super::{
    detect_format, gps_time, nmea, rtklib, ubx, FixQuality, Format, GeodeticLog, Reference,
    ReferenceOptions,
};
use crate::csvio;

/// A reference file read for inspection: every epoch of a receiver log, whatever its fix
/// quality, and the reference as `calibrate` would use it.
#[derive(Debug, Clone)]
pub struct Inspection {
    /// The format read.
    pub format: Format,
    /// A receiver log's epochs (`None` for a REFERENCE CSV or a trajectory).
    pub log: Option<GeodeticLog>,
    /// The used epochs in the local plane (the fix-quality filter and origin of the options).
    pub reference: Reference,
}

/// Reads a reference file's content for inspection; `file` names it in messages.
pub fn inspect(file: &str, bytes: &[u8], o: &ReferenceOptions) -> Result<Inspection> {
    let text = String::from_utf8_lossy(bytes);
    let format = o.format.unwrap_or_else(|| detect_format(bytes, &text));
    let log = match format {
        Format::Csv | Format::Tum | Format::Mcap => None,
        Format::Nmea => Some(nmea::parse(file, &text, o.leap_seconds)?),
        Format::Rtklib => Some(rtklib::parse(file, &text, o.leap_seconds)?),
        Format::Ubx => Some(ubx::parse(file, bytes, o.leap_seconds)?),
    };
    let reference = match &log {
        None if format == Format::Csv => {
            Reference::from_csv(file, csvio::parse_reference(file, &text)?)
        }
        None => super::parse(
            file,
            bytes,
            &ReferenceOptions {
                format: Some(format),
                ..o.clone()
            },
        )?,
        Some(l) => Reference::from_log(file, format, l.clone(), o)?,
    };
    Ok(Inspection {
        format,
        log,
        reference,
    })
}

/// One epoch as the summary sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Time (s): GPS seconds for a receiver log, the file's `t` for a CSV.
    pub t: f64,
    /// Solution quality.
    pub fix: FixQuality,
    /// Horizontal RMS sigma (m), when reported.
    pub sigma_h: Option<f64>,
    /// Vertical sigma (m), when reported.
    pub sigma_up: Option<f64>,
    /// Whether the epoch has a heading.
    pub heading: bool,
}

impl Inspection {
    /// Every epoch read (a log's of every fix quality, a CSV's rows).
    pub fn points(&self) -> Vec<Point> {
        match &self.log {
            Some(l) => l
                .epochs
                .iter()
                .map(|e| Point {
                    t: e.gps_time,
                    fix: e.fix,
                    sigma_h: e.sigma_north_east_up.map(|s| s[0].hypot(s[1])),
                    sigma_up: e.sigma_north_east_up.map(|s| s[2]),
                    heading: e.heading.is_some(),
                })
                .collect(),
            None => self
                .reference
                .epochs
                .iter()
                .map(|e| Point {
                    t: e.t,
                    fix: e.fix,
                    sigma_h: e.sigma_east_north.map(|s| s[0].hypot(s[1])),
                    sigma_up: None,
                    heading: e.heading.is_some(),
                })
                .collect(),
        }
    }
}

/// Epoch counts by fix quality in one time bucket.
#[derive(Debug, Clone, PartialEq)]
pub struct Bucket {
    /// Start (s from the first epoch).
    pub start: f64,
    /// Epochs by quality.
    pub counts: BTreeMap<FixQuality, usize>,
}

/// The figures `odoctl reference` prints.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Epochs.
    pub epochs: usize,
    /// First and last time (s).
    pub span: (f64, f64),
    /// Median interval between epochs (s).
    pub interval: f64,
    /// Gaps: intervals longer than twice the median, as (time before the gap, length) (s).
    pub gaps: Vec<(f64, f64)>,
    /// Bucket length (s).
    pub bucket: f64,
    /// Epochs by fix quality over time.
    pub buckets: Vec<Bucket>,
    /// Median and 95th percentile of the horizontal sigma (m), and how many epochs report it.
    pub sigma_h: Option<(f64, f64, usize)>,
    /// The same of the vertical sigma.
    pub sigma_up: Option<(f64, f64, usize)>,
    /// Epochs with a heading.
    pub headings: usize,
}

/// The `q`-quantile (0..1) of sorted values, the nearest rank.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let k = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[k - 1]
}

fn median_p95(v: impl Iterator<Item = f64>) -> Option<(f64, f64, usize)> {
    let mut v: Vec<f64> = v.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some((quantile(&v, 0.5), quantile(&v, 0.95), v.len()))
}

/// A bucket length for a span (s): a minute for spans over ten minutes, else a tenth of the
/// span rounded up to a whole second (at least 1 s).
pub fn bucket_length(span: f64) -> f64 {
    if span > 600.0 {
        60.0
    } else {
        (span / 10.0).ceil().max(1.0)
    }
}

/// The summary of `points` (times increasing).
pub fn summarize(points: &[Point]) -> Summary {
    let first = points.first().map_or(f64::NAN, |p| p.t);
    let last = points.last().map_or(f64::NAN, |p| p.t);
    let mut dt: Vec<f64> = points.windows(2).map(|w| w[1].t - w[0].t).collect();
    let gaps_from: Vec<(f64, f64)> = points
        .windows(2)
        .map(|w| (w[0].t, w[1].t - w[0].t))
        .collect();
    dt.sort_by(f64::total_cmp);
    let interval = if dt.is_empty() {
        f64::NAN
    } else {
        quantile(&dt, 0.5)
    };
    let gaps = gaps_from
        .into_iter()
        .filter(|(_, d)| *d > 2.0 * interval * (1.0 + 1e-6))
        .collect();
    let bucket = bucket_length(last - first);
    let mut buckets: Vec<Bucket> = Vec::new();
    for p in points {
        let start = ((p.t - first) / bucket).floor() * bucket;
        if buckets.last().is_none_or(|b| b.start != start) {
            buckets.push(Bucket {
                start,
                counts: BTreeMap::new(),
            });
        }
        if let Some(b) = buckets.last_mut() {
            *b.counts.entry(p.fix).or_default() += 1;
        }
    }
    Summary {
        epochs: points.len(),
        span: (first, last),
        interval,
        gaps,
        bucket,
        buckets,
        sigma_h: median_p95(points.iter().filter_map(|p| p.sigma_h)),
        sigma_up: median_p95(points.iter().filter_map(|p| p.sigma_up)),
        headings: points.iter().filter(|p| p.heading).count(),
    }
}

/// The formats `--to` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// REFERENCE CSV (`t` in GPS time of week) with `up`, `lat`, `lon`, `height`, `fix`.
    Csv,
    /// TUM trajectory: `t x y z qx qy qz qw`, local east-north-up metres.
    Tum,
    /// GeoJSON (RFC 7946): a LineString of longitude, latitude, height.
    Geojson,
    /// GPX 1.1: a track of points with ellipsoidal height and UTC time.
    Gpx,
}

/// The UTC time `yyyy-mm-ddThh:mm:ss.sssZ` of GPS seconds, with the leap seconds given or
/// those of the table at that time.
pub fn utc_text(gps: f64, leap_seconds: Option<i32>) -> String {
    let leap = leap_seconds.unwrap_or_else(|| gps_time::leap_seconds_at_gps(gps));
    let (days, sod) = gps_time::gps_to_utc(gps, leap);
    let ms = (sod * 1000.0).round() as i64;
    let (days, ms) = (days + ms / 86_400_000, ms % 86_400_000);
    let (y, m, d) = odo_unit::timing::nmea::civil_from_days(days);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{:03}Z",
        ms / 3_600_000,
        ms / 60_000 % 60,
        ms / 1000 % 60,
        ms % 1000
    )
}

/// The name GPX gives a fix quality (`<fix>`).
fn gpx_fix(q: FixQuality) -> &'static str {
    match q {
        FixQuality::RtkFixed | FixQuality::RtkFloat | FixQuality::Dgps | FixQuality::Sbas => "dgps",
        FixQuality::Ppp | FixQuality::Single => "3d",
        FixQuality::Invalid => "none",
    }
}

/// Writes the used epochs of `r` in `format`; `leap_seconds` as `--leap-seconds` (UTC times
/// of GPX and GeoJSON). A REFERENCE CSV has no latitude and longitude: only CSV and TUM.
pub fn export(
    out: &mut dyn Write,
    r: &Reference,
    format: ExportFormat,
    leap_seconds: Option<i32>,
) -> Result<()> {
    let geo: Option<Vec<Geodetic>> = r.origin.map(|o| {
        let frame = LocalFrame::new(o);
        r.epochs
            .iter()
            .map(|e| frame.to_geodetic([e.x, e.y, e.up.unwrap_or(0.0)]))
            .collect()
    });
    // Receiver logs: GPS time of week of the first epoch's week, as `record` stamps samples.
    let week_start = match (r.time, r.epochs.first()) {
        (super::TimeScale::Gps, Some(e)) => gps_time::week_tow(e.t).0 as f64 * gps_time::WEEK,
        _ => 0.0,
    };
    match (format, &geo) {
        (ExportFormat::Csv, _) => write_csv(out, r, geo.as_deref(), week_start),
        (ExportFormat::Tum, _) => write_tum(out, r, week_start),
        (ExportFormat::Geojson, Some(g)) => write_geojson(out, r, g, leap_seconds),
        (ExportFormat::Gpx, Some(g)) => write_gpx(out, r, g, leap_seconds),
        (_, None) => bail!(
            "{}: a {} holds local metres, no latitude and longitude: --to csv or tum only",
            r.file,
            r.format
        ),
    }
}

fn write_csv(
    out: &mut dyn Write,
    r: &Reference,
    geo: Option<&[Geodetic]>,
    week_start: f64,
) -> Result<()> {
    writeln!(out, "t,x,y,heading,sigma_h,up,lat,lon,height,fix")?;
    let opt = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:?}"));
    for (k, e) in r.epochs.iter().enumerate() {
        let g = geo.map(|g| g[k]);
        writeln!(
            out,
            "{:.6},{:?},{:?},{},{},{},{},{},{},{}",
            e.t - week_start,
            e.x,
            e.y,
            opt(e.heading),
            opt(e.sigma_east_north.map(|s| s[0].hypot(s[1]))),
            opt(e.up),
            g.map_or(String::new(), |g| format!("{:.10}", g.lat_deg)),
            g.map_or(String::new(), |g| format!("{:.10}", g.lon_deg)),
            g.map_or(String::new(), |g| format!("{:.4}", g.height)),
            e.fix
        )?;
    }
    Ok(())
}

fn write_tum(out: &mut dyn Write, r: &Reference, week_start: f64) -> Result<()> {
    writeln!(
        out,
        "# timestamp tx ty tz qx qy qz qw (GPS time of week or the CSV's t; east, north, up; \
         yaw from the heading, identity without one)"
    )?;
    for e in &r.epochs {
        // Yaw anticlockwise from east; the heading runs clockwise from north.
        let (qz, qw) = e.heading.map_or((0.0, 1.0), |h| {
            let yaw = std::f64::consts::FRAC_PI_2 - h;
            ((yaw / 2.0).sin(), (yaw / 2.0).cos())
        });
        writeln!(
            out,
            "{:.6} {:.4} {:.4} {:.4} 0 0 {qz:.9} {qw:.9}",
            e.t - week_start,
            e.x,
            e.y,
            e.up.unwrap_or(0.0)
        )?;
    }
    Ok(())
}

fn write_geojson(
    out: &mut dyn Write,
    r: &Reference,
    geo: &[Geodetic],
    leap_seconds: Option<i32>,
) -> Result<()> {
    let coordinates: Vec<serde_json::Value> = geo
        .iter()
        .map(|g| {
            serde_json::json!([
                (g.lon_deg * 1e9).round() / 1e9,
                (g.lat_deg * 1e9).round() / 1e9,
                (g.height * 1e4).round() / 1e4
            ])
        })
        .collect();
    let times: Vec<String> = r
        .epochs
        .iter()
        .map(|e| utc_text(e.t, leap_seconds))
        .collect();
    let fixes: Vec<String> = r.epochs.iter().map(|e| e.fix.to_string()).collect();
    let doc = serde_json::json!({
        "type": "FeatureCollection",
        "features": [{
            "type": "Feature",
            "geometry": { "type": "LineString", "coordinates": coordinates },
            "properties": {
                "name": r.file,
                "source": r.format.to_string(),
                "coordTimes": times,
                "fix": fixes,
                "height": "ellipsoidal (WGS84), m"
            }
        }]
    });
    serde_json::to_writer(&mut *out, &doc)?;
    writeln!(out)?;
    Ok(())
}

/// `&`, `<`, `>`, `"` escaped for XML text and attributes.
fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn write_gpx(
    out: &mut dyn Write,
    r: &Reference,
    geo: &[Geodetic],
    leap_seconds: Option<i32>,
) -> Result<()> {
    writeln!(out, r#"<?xml version="1.0" encoding="UTF-8"?>"#)?;
    writeln!(
        out,
        r#"<gpx version="1.1" creator="odoctl" xmlns="http://www.topografix.com/GPX/1/1">"#
    )?;
    let name = xml_escape(&r.file);
    writeln!(out, "  <trk>\n    <name>{name}</name>")?;
    writeln!(
        out,
        "    <desc>{}; ele: ellipsoidal height (WGS84)</desc>\n    <trkseg>",
        xml_escape(&r.format.to_string())
    )?;
    for (e, g) in r.epochs.iter().zip(geo) {
        writeln!(
            out,
            r#"      <trkpt lat="{:.10}" lon="{:.10}"><ele>{:.4}</ele><time>{}</time><fix>{}</fix></trkpt>"#,
            g.lat_deg,
            g.lon_deg,
            g.height,
            utc_text(e.t, leap_seconds),
            gpx_fix(e.fix)
        )?;
    }
    writeln!(out, "    </trkseg>\n  </trk>\n</gpx>")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t: f64, fix: FixQuality, sigma: f64) -> Point {
        Point {
            t,
            fix,
            sigma_h: Some(sigma),
            sigma_up: None,
            heading: t < 1.0,
        }
    }

    #[test]
    fn buckets_gaps_and_sigmas() {
        use FixQuality::*;
        // 10 Hz for 3 s, a 1-s gap, 10 Hz for 1 s; float in the second second.
        let mut pts = Vec::new();
        for k in 0..30 {
            let t = f64::from(k) * 0.1;
            let fix = if (10..20).contains(&k) {
                RtkFloat
            } else {
                RtkFixed
            };
            pts.push(point(t, fix, 0.01 * f64::from(k % 10 + 1)));
        }
        for k in 0..10 {
            pts.push(point(3.9 + f64::from(k) * 0.1, Single, 0.5));
        }
        let s = summarize(&pts);
        assert_eq!(s.epochs, 40);
        assert!((s.interval - 0.1).abs() < 1e-9);
        assert_eq!(s.gaps.len(), 1);
        assert!((s.gaps[0].0 - 2.9).abs() < 1e-9 && (s.gaps[0].1 - 1.0).abs() < 1e-9);
        assert_eq!(s.bucket, 1.0);
        // Buckets of 1 s from the first epoch: the gap leaves 3.9 s alone in its second.
        assert_eq!(s.buckets.len(), 5, "{:?}", s.buckets);
        assert_eq!(s.buckets[1].counts[&RtkFloat], 10);
        assert_eq!(s.buckets[3].counts[&Single], 1);
        assert_eq!(s.buckets[4].counts[&Single], 9);
        let (med, p95, n) = s.sigma_h.unwrap();
        assert_eq!(n, 40);
        assert!((med - 0.07).abs() < 1e-12 && p95 == 0.5, "{med} {p95}");
        assert_eq!(s.headings, 10);
        assert_eq!(bucket_length(3600.0), 60.0);
        assert_eq!(bucket_length(0.0), 1.0);
    }

    #[test]
    fn utc_times() {
        let gps = gps_time::utc_to_gps(
            odo_unit::timing::nmea::days_from_civil(2026, 11, 27),
            3_723.456_5,
            18,
        )
        .unwrap();
        assert_eq!(utc_text(gps, None), "2026-11-27T01:02:03.457Z");
        assert_eq!(utc_text(gps, Some(17)), "2026-11-27T01:02:04.457Z");
        // Rounding up to the next day.
        let g = gps_time::utc_to_gps(
            odo_unit::timing::nmea::days_from_civil(2026, 12, 31),
            86_399.999_6,
            18,
        )
        .unwrap();
        assert_eq!(utc_text(g, None), "2027-01-01T00:00:00.000Z");
    }
}
