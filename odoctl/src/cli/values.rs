//! The command line's numeric values, checked when the options are parsed (clap
//! `value_parser`s): each function accepts its kind of value in a stated range and refuses
//! anything else (NaN, infinities, out of range) with a message giving the range; clap names
//! the option.

use odo_unit::odometry::integrator::{MAX_HEADING, MAX_POSITION};

/// A finite number in `lo..=hi` (or `lo < v` when `open_lo`), in `unit`.
fn real(text: &str, lo: f64, hi: f64, open_lo: bool, unit: &str) -> Result<f64, String> {
    let range = format!("{}{lo}, {hi}] {unit}", if open_lo { "(" } else { "[" });
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("not a number; expected a value in {range}"))?;
    let above_lo = if open_lo { v > lo } else { v >= lo };
    if v.is_finite() && above_lo && v <= hi {
        Ok(v)
    } else {
        Err(format!("out of range; expected a value in {range}"))
    }
}

/// An integer in `lo..=hi`.
fn integer<T>(text: &str, lo: T, hi: T) -> Result<T, String>
where
    T: std::str::FromStr + PartialOrd + std::fmt::Display + Copy,
{
    let v: T = text
        .trim()
        .parse()
        .map_err(|_| format!("not an integer; expected {lo}..={hi}"))?;
    if v >= lo && v <= hi {
        Ok(v)
    } else {
        Err(format!("out of range; expected {lo}..={hi}"))
    }
}

/// A run time in seconds, (0, 1e7] s (115 days).
pub fn duration(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1e7, true, "s")
}

/// A time between retries, [0.01, 3600] s.
pub fn retry(text: &str) -> Result<f64, String> {
    real(text, 0.01, 3600.0, false, "s")
}

/// A count of records or rows, at least 1.
pub fn count(text: &str) -> Result<u64, String> {
    integer(text, 1, u64::MAX)
}

/// A serial baud rate, 1..=20000000 bit/s.
pub fn baud(text: &str) -> Result<u32, String> {
    integer(text, 1, 20_000_000)
}

/// An x or y the unit's integrator can hold, metres (+-2^30 m,
/// `odo_unit::odometry::integrator::MAX_POSITION`).
pub fn position(text: &str) -> Result<f64, String> {
    real(text, -MAX_POSITION, MAX_POSITION, false, "m")
}

/// A heading the unit's integrator can hold, radians (+-2^32 rad,
/// `odo_unit::odometry::integrator::MAX_HEADING`).
pub fn heading(text: &str) -> Result<f64, String> {
    real(text, -MAX_HEADING, MAX_HEADING, false, "rad")
}

/// A standard deviation of a position, [0, 100] m.
pub fn sigma_m(text: &str) -> Result<f64, String> {
    real(text, 0.0, 100.0, false, "m")
}

/// A standard deviation of a heading, [0, 180] degrees.
pub fn sigma_deg(text: &str) -> Result<f64, String> {
    real(text, 0.0, 180.0, false, "deg")
}

/// A sub-trajectory length, [0, 1e6] m (0: the whole run).
pub fn window(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1e6, false, "m")
}

/// A stability-study sub-trajectory length, (0, 1e6] m.
pub fn window_length(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1e6, true, "m")
}

/// A simulated path length, (0, 1e5] m.
pub fn path_length(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1e5, true, "m")
}

/// A simulated speed, [0.01, 10] m/s.
pub fn speed(text: &str) -> Result<f64, String> {
    real(text, 0.01, 10.0, false, "m/s")
}

/// A sample rate, [0.1, 10000] Hz.
pub fn sample_rate(text: &str) -> Result<f64, String> {
    real(text, 0.1, 10_000.0, false, "Hz")
}

/// A receiver's epoch rate, (0, 100] Hz.
pub fn gnss_rate(text: &str) -> Result<f64, String> {
    real(text, 0.0, 100.0, true, "Hz")
}

/// A fraction, [0, 1].
pub fn fraction(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1.0, false, "")
}

/// A correlation length, (0, 1e4] m.
pub fn correlation_length(text: &str) -> Result<f64, String> {
    real(text, 0.0, 1e4, true, "m")
}

/// GPS - UTC, 0..=100 s.
pub fn leap_seconds(text: &str) -> Result<i32, String> {
    integer(text, 0, 100)
}

/// An angle, [-360, 360] degrees.
pub fn angle_deg(text: &str) -> Result<f64, String> {
    real(text, -360.0, 360.0, false, "deg")
}

/// A clock rate error, [-10000, 10000] ppm.
pub fn clock_ppm(text: &str) -> Result<f64, String> {
    real(text, -1e4, 1e4, false, "ppm")
}

/// A clock offset, [-1e10, 1e10] s (Unix time on a clock counting from zero).
pub fn time_offset(text: &str) -> Result<f64, String> {
    real(text, -1e10, 1e10, false, "s")
}

/// Default standard-error targets (m): the diameters', the track width's.
pub const DEFAULT_TARGETS: Targets = Targets {
    diameter: 0.05e-3,
    track: 0.5e-3,
};

/// The standard errors the user asks for (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Targets {
    /// Largest standard error of each wheel diameter (m).
    pub diameter: f64,
    /// Largest standard error of the track width (m).
    pub track: f64,
}

/// `--target-se D,T`: two lengths, each a number with `mm`, `um` or `m` (no unit: mm), in
/// (0, 1] m.
pub fn target_se(text: &str) -> Result<Targets, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [d, t] = parts.as_slice() else {
        return Err("expected two standard errors, DIAMETER,TRACK, e.g. 0.02mm,0.1mm".into());
    };
    Ok(Targets {
        diameter: length(d)?,
        track: length(t)?,
    })
}

/// One length of `--target-se` in metres.
fn length(text: &str) -> Result<f64, String> {
    let (number, scale) = if let Some(n) = text.strip_suffix("mm") {
        (n, 1e-3)
    } else if let Some(n) = text.strip_suffix("um") {
        (n, 1e-6)
    } else if let Some(n) = text.strip_suffix('m') {
        (n, 1.0)
    } else {
        (text, 1e-3)
    };
    let v: f64 = number
        .trim()
        .parse()
        .map_err(|_| format!("{text}: not a length (e.g. 0.02mm)"))?;
    let m = v * scale;
    if m.is_finite() && m > 0.0 && m <= 1.0 {
        Ok(m)
    } else {
        Err(format!(
            "{text}: out of range; expected a length in (0, 1] m"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_non_finite_and_out_of_range_naming_the_range() {
        for bad in ["nan", "NaN", "inf", "-inf", "1e300", "-1", "0", "x", ""] {
            let e = duration(bad).unwrap_err();
            assert!(e.contains("(0, 10000000] s"), "{bad}: {e}");
        }
        assert_eq!(duration("0.5"), Ok(0.5));
        assert_eq!(position("-1073741824"), Ok(-MAX_POSITION));
        assert!(position("1073741825").is_err());
        assert!(heading("-6e19").unwrap_err().contains("rad"));
        assert_eq!(window("0"), Ok(0.0));
        assert!(window_length("0").is_err());
        assert!(count("0").unwrap_err().contains("1..="));
        assert!(leap_seconds("-1").is_err());
        assert_eq!(speed("0.01"), Ok(0.01));
        assert!(speed("1e-300").is_err());
    }
    #[test]
    fn targets_parse_with_units() {
        let t = target_se("0.02mm,0.1mm").unwrap();
        assert!((t.diameter - 2e-5).abs() < 1e-12 && (t.track - 1e-4).abs() < 1e-12);
        let t = target_se("20um, 0.0001m").unwrap();
        assert!((t.diameter - 2e-5).abs() < 1e-12 && (t.track - 1e-4).abs() < 1e-12);
        assert_eq!(target_se("0.05,0.5").unwrap(), DEFAULT_TARGETS);
        for bad in [
            "0.02mm",
            "0mm,1mm",
            "-1mm,1mm",
            "nanmm,1mm",
            "2m,1mm",
            "a,b",
            "1,2,3",
        ] {
            assert!(target_se(bad).is_err(), "{bad}");
        }
    }
}
