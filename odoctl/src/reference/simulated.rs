//! A simulated RTK receiver on the simulated chassis, and the NMEA and `.pos` writers
//! (`odoctl simulate --nmea FILE --pos FILE --antenna F,L`): what a BD982 or ZED-F9P would log
//! for the run, so that tests can go through the whole path from a receiver log.
//!
//! The antenna sits at (forward, left) metres from the axle centre: its position is
//! centre + R(heading) (forward, left) ([`super::antenna_position`]). Epochs at `rate` Hz
//! (10 by default) on the samples' instants; RTK-fixed epochs carry normal noise of
//! `rtk_sigma / sqrt 2` per horizontal axis (`rtk_sigma` per axis up), RTK-float epochs
//! `float_sigma / sqrt 2`: the run is cut into blocks of [`FLOAT_BLOCK`] seconds, each float
//! with probability `float_fraction` (never the first: the opening standstill stays fixed).

use std::f64::consts::SQRT_2;
use std::io::Write;

use anyhow::Result;
use odo_unit::timing::nmea::civil_from_days;

use super::geodetic::{Geodetic, LocalFrame};
use super::nmea::with_checksum;
use super::{antenna_position, gps_time, Epoch, FixQuality};
use crate::simulate::Rng;

/// Length of a block of epochs of one fix quality (s).
pub const FLOAT_BLOCK: f64 = 2.0;
/// Geoid separation written in GGA (m): height above mean sea level = ellipsoidal - this.
pub const GEOID_SEPARATION: f64 = 45.0;

/// How the simulated receiver logs the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReceiverSim {
    /// WGS84 position of the local plane's origin (x = y = 0).
    pub origin: Geodetic,
    /// GPS time of the samples' t = 0 (s since 1980-01-06).
    pub gps_start: f64,
    /// Epoch rate (Hz); epochs fall on the samples' instants that are whole multiples of 1/rate.
    pub rate: f64,
    /// Antenna position in the chassis frame: forward, left (m).
    pub antenna: (f64, f64),
    /// Horizontal RMS noise of RTK-fixed epochs (m).
    pub rtk_sigma: f64,
    /// Horizontal RMS noise of RTK-float epochs (m).
    pub float_sigma: f64,
    /// Probability of a [`FLOAT_BLOCK`] being float.
    pub float_fraction: f64,
    /// Noise of the true heading (rad); `None` logs no heading.
    pub heading_sigma: Option<f64>,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for ReceiverSim {
    fn default() -> Self {
        Self {
            origin: Geodetic {
                lat_deg: 49.2,
                lon_deg: 16.6,
                height: 300.0,
            },
            // GPS week 2400, Wednesday 12:00:00 GPS (2026-01-07).
            gps_start: 2400.0 * gps_time::WEEK + 3.5 * gps_time::DAY,
            rate: 10.0,
            antenna: (0.0, 0.0),
            rtk_sigma: 0.008,
            float_sigma: 0.05,
            float_fraction: 0.1,
            heading_sigma: None,
            seed: 1,
        }
    }
}

/// The receiver's epochs for a run: `times` are the samples' times (s from the run's start),
/// `truth` the true centre pose at each (x east, y north, heading clockwise from north).
pub fn receiver_epochs(times: &[f64], truth: &[(f64, f64, f64)], sim: &ReceiverSim) -> Vec<Epoch> {
    let mut rng = Rng::new(sim.seed ^ 0x05EE_D0FA_7E77);
    let frame = LocalFrame::new(sim.origin);
    let mut block = -1i64;
    let mut float = false;
    let mut out = Vec::new();
    for (t, &(x, y, h)) in times.iter().zip(truth) {
        let k = t * sim.rate;
        if (k - k.round()).abs() > 1e-6 {
            continue;
        }
        let b = (t / FLOAT_BLOCK).floor() as i64;
        if b != block {
            block = b;
            float = b > 0 && rng.uniform() < sim.float_fraction;
        }
        let (fix, s) = if float {
            (FixQuality::RtkFloat, sim.float_sigma)
        } else {
            (FixQuality::RtkFixed, sim.rtk_sigma)
        };
        let (ax, ay) = antenna_position(x, y, h, sim.antenna.0, sim.antenna.1);
        let noise = [
            s / SQRT_2 * rng.normal(),
            s / SQRT_2 * rng.normal(),
            s * rng.normal(),
        ];
        let position = frame.to_geodetic([ax + noise[0], ay + noise[1], noise[2]]);
        let heading = sim
            .heading_sigma
            .map(|hs| crate::stats::wrap_angle(h + hs * rng.normal()));
        out.push(Epoch {
            gps_time: sim.gps_start + t,
            position,
            heading,
            sigma_north_east_up: Some([s / SQRT_2, s / SQRT_2, s]),
            fix,
            line: 0,
        });
    }
    out
}

/// UTC of GPS seconds to the centisecond: (year, month, day, `hhmmss.ss`, whole second?).
fn utc_fields(gps: f64, leap_seconds: i32) -> (i64, u32, u32, String, bool) {
    let cs = ((gps - f64::from(leap_seconds)) * 100.0).round() as i64;
    let days = cs.div_euclid(8_640_000) + gps_time::gps_epoch_days();
    let c = cs.rem_euclid(8_640_000);
    let (y, m, d) = civil_from_days(days);
    let time = format!(
        "{:02}{:02}{:02}.{:02}",
        c / 360_000,
        c / 6000 % 60,
        c / 100 % 60,
        c % 100
    );
    (y, m, d, time, c % 100 == 0)
}

/// `ddmm.mmmmmmmm` (or `dddmm...` with `deg_digits` 3) and the hemisphere letter.
fn nmea_angle(v: f64, deg_digits: usize, pos: char, neg: char) -> (String, char) {
    const SCALE: i64 = 100_000_000; // 1e-8 minute: 0.02 mm
    let total = (v.abs() * 60.0 * SCALE as f64).round() as i64;
    let (deg, rem) = (total / (60 * SCALE), total % (60 * SCALE));
    (
        format!("{deg:0deg_digits$}{:02}.{:08}", rem / SCALE, rem % SCALE),
        if v < 0.0 { neg } else { pos },
    )
}

/// Writes the epochs as an NMEA 0183 log: per epoch GGA, GST, HDT (with a heading) and RMC;
/// at whole seconds also ZDA and a GSV (a sentence readers skip). UTC = GPS - `leap_seconds`.
pub fn write_nmea(w: &mut dyn Write, epochs: &[Epoch], leap_seconds: i32) -> Result<()> {
    let mut out = String::new();
    for e in epochs {
        let (y, m, d, time, whole) = utc_fields(e.gps_time, leap_seconds);
        let (lat, ns) = nmea_angle(e.position.lat_deg, 2, 'N', 'S');
        let (lon, ew) = nmea_angle(e.position.lon_deg, 3, 'E', 'W');
        let (q, mode) = match e.fix {
            FixQuality::RtkFixed => (4, 'R'),
            FixQuality::RtkFloat => (5, 'F'),
            FixQuality::Dgps => (2, 'D'),
            FixQuality::Single | FixQuality::Sbas | FixQuality::Ppp => (1, 'A'),
            FixQuality::Invalid => (0, 'N'),
        };
        let alt = e.position.height - GEOID_SEPARATION;
        let lines = [
            Some(format!(
                "GNGGA,{time},{lat},{ns},{lon},{ew},{q},12,0.6,{alt:.4},M,{GEOID_SEPARATION:.3},M,1.0,0000"
            )),
            e.sigma_north_east_up.map(|s| {
                let h = s[0].hypot(s[1]);
                format!(
                    "GNGST,{time},{:.4},{h:.4},{h:.4},0.0,{:.4},{:.4},{:.4}",
                    h, s[0], s[1], s[2]
                )
            }),
            e.heading.map(|h| {
                format!("GNHDT,{:.3},T", h.to_degrees().rem_euclid(360.0))
            }),
            Some(format!(
                "GNRMC,{time},A,{lat},{ns},{lon},{ew},0.00,0.00,{d:02}{m:02}{:02},,,{mode}",
                y % 100
            )),
            whole.then(|| format!("GNZDA,{time},{d:02},{m:02},{y:04},00,00")),
            whole.then(|| "GPGSV,1,1,01,05,45,120,40".to_string()),
        ];
        for body in lines.into_iter().flatten() {
            out.push_str(&with_checksum(&body));
            out.push_str("\r\n");
        }
        if out.len() > 1 << 16 {
            w.write_all(out.as_bytes())?;
            out.clear();
        }
    }
    w.write_all(out.as_bytes())?;
    Ok(())
}

/// The time column(s) of a `.pos` file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PosTime {
    /// `yyyy/mm/dd hh:mm:ss.sss` GPST.
    Calendar,
    /// `week tow`.
    WeekTow,
}

/// Writes the epochs as an RTKLIB `.pos` file (latitude/longitude in degrees, ellipsoidal
/// height, GPST).
pub fn write_pos(w: &mut dyn Write, epochs: &[Epoch], time: PosTime) -> Result<()> {
    let mut out = String::from(
        "% program   : odoctl simulate (RTKLIB .pos layout)\n\
         % (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n",
    );
    out.push_str(match time {
        PosTime::Calendar => "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n",
        PosTime::WeekTow => "%  GPST          latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n",
    });
    for e in epochs {
        let ms = (e.gps_time * 1000.0).round() as i64;
        let t = match time {
            PosTime::Calendar => {
                let days = ms.div_euclid(86_400_000) + gps_time::gps_epoch_days();
                let c = ms.rem_euclid(86_400_000);
                let (y, m, d) = civil_from_days(days);
                format!(
                    "{y:04}/{m:02}/{d:02} {:02}:{:02}:{:02}.{:03}",
                    c / 3_600_000,
                    c / 60_000 % 60,
                    c / 1000 % 60,
                    c % 1000
                )
            }
            PosTime::WeekTow => {
                let wk = ms.div_euclid(604_800_000);
                let tow = ms.rem_euclid(604_800_000);
                format!("{wk:4} {:6}.{:03}", tow / 1000, tow % 1000)
            }
        };
        let q = match e.fix {
            FixQuality::RtkFixed => 1,
            FixQuality::RtkFloat => 2,
            FixQuality::Sbas => 3,
            FixQuality::Dgps => 4,
            FixQuality::Single => 5,
            FixQuality::Ppp => 6,
            FixQuality::Invalid => 0,
        };
        let s = e.sigma_north_east_up.unwrap_or([0.0; 3]);
        out.push_str(&format!(
            "{t} {:14.9} {:14.9} {:10.4} {q:3} {:3} {:8.4} {:8.4} {:8.4} {:8.4} {:8.4} {:8.4} {:6.2} {:6.1}\n",
            e.position.lat_deg, e.position.lon_deg, e.position.height, 12, s[0], s[1], s[2], 0.0, 0.0, 0.0, 1.0, 999.9
        ));
        if out.len() > 1 << 16 {
            w.write_all(out.as_bytes())?;
            out.clear();
        }
    }
    w.write_all(out.as_bytes())?;
    Ok(())
}

/// Sentences each with the index of the sample after which the unit receives it.
pub type TimedSentences = Vec<(usize, String)>;

/// A simulated drive as a unit locked to its receiver records it: `sim`'s samples with `t` the
/// GPS time of week of the receiver's start (`sim.gps_start`), and the receiver's NMEA
/// sentences (leap seconds `leap`), each with the index of the sample after which the unit
/// receives it.
pub fn drive_with_sentences(
    mut run: crate::simulate::SimRun,
    sim: &ReceiverSim,
    leap: i32,
) -> Result<(Vec<crate::csvio::Sample>, TimedSentences)> {
    let times: Vec<f64> = run.samples.iter().map(|s| s.t).collect();
    let epochs = receiver_epochs(&times, &run.truth, sim);
    let mut sentences = Vec::new();
    let mut k = 0;
    for e in &epochs {
        let t = e.gps_time - sim.gps_start;
        while k + 1 < times.len() && times[k] < t - 1e-9 {
            k += 1;
        }
        let mut bytes = Vec::new();
        write_nmea(&mut bytes, std::slice::from_ref(e), leap)?;
        for line in String::from_utf8_lossy(&bytes).lines() {
            sentences.push((k, line.to_string()));
        }
    }
    let (_, tow0) = gps_time::week_tow(sim.gps_start);
    for s in &mut run.samples {
        s.t += tow0;
    }
    Ok((run.samples, sentences))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_and_time_fields_carry_over() {
        assert_eq!(nmea_angle(49.2, 2, 'N', 'S'), ("4912.00000000".into(), 'N'));
        assert_eq!(
            nmea_angle(-16.6, 3, 'E', 'W'),
            ("01636.00000000".into(), 'W')
        );
        // 59.999999999 minutes rounds up into the next degree, not to "60.00000000".
        assert_eq!(
            nmea_angle(-(7.0 + 59.999_999_999 / 60.0), 3, 'E', 'W'),
            ("00800.00000000".into(), 'W')
        );
        // 23:59:59.996 UTC rounds into the next day.
        let gps = gps_time::utc_to_gps(civil_days(2026, 12, 31), 86_399.996, 18).unwrap();
        let (y, m, d, t, whole) = utc_fields(gps, 18);
        assert_eq!(
            (y, m, d, t.as_str(), whole),
            (2027, 1, 1, "000000.00", true)
        );
    }

    fn civil_days(y: i64, m: u32, d: u32) -> i64 {
        odo_unit::timing::nmea::days_from_civil(y, m, d)
    }

    #[test]
    fn epochs_on_the_rate_with_float_blocks_and_the_lever_arm() {
        let n = 50 * 60; // 60 s at 50 Hz, standing still facing east
        let times: Vec<f64> = (0..n).map(|k| k as f64 / 50.0).collect();
        let truth = vec![(3.0, 4.0, std::f64::consts::FRAC_PI_2); n];
        let sim = ReceiverSim {
            antenna: (0.5, 0.2),
            rtk_sigma: 0.0,
            float_sigma: 0.0,
            float_fraction: 0.3,
            ..ReceiverSim::default()
        };
        let e = receiver_epochs(&times, &truth, &sim);
        assert_eq!(e.len(), 600);
        let floats = e.iter().filter(|e| e.fix == FixQuality::RtkFloat).count();
        assert!(floats % 20 == 0 && (60..=300).contains(&floats), "{floats}");
        assert!(e[..20].iter().all(|e| e.fix == FixQuality::RtkFixed));
        // Facing east: forward is +x, left is +y.
        let enu = LocalFrame::new(sim.origin).to_enu(&e[7].position);
        assert!(
            (enu[0] - 3.5).abs() < 1e-6 && (enu[1] - 4.2).abs() < 1e-6,
            "{enu:?}"
        );
        assert!((e[7].gps_time - sim.gps_start - 0.7).abs() < 1e-6);
    }
}
