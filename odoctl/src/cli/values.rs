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
}
