//! What an estimated clock offset contributes to the geometry's standard errors: the
//! sub-trajectory fit repeated on the trajectory resampled with the offset moved by its
//! standard error, and each estimate's change added in quadrature.

use anyhow::Result;

use crate::calib::{fit_subtrajectories, Calibration, CalibrationOptions, Run};
use crate::calib::{LeverArm, SubtrajectoryOptions};
use crate::csvio::{self, RefPoint, Sample};

/// The changes of the sub-trajectory estimate (left and right diameter, track width, lever
/// arm forward and left; m) when the reference is `moved`: the same trajectory resampled with
/// the clock offset moved by its standard error. `None` without a sub-trajectory fit.
pub fn offset_shares(
    c: &Calibration,
    samples: &[Sample],
    moved: &[RefPoint],
    o: &CalibrationOptions,
) -> Result<Option<[f64; 5]>> {
    let Some(s) = &c.subtrajectories else {
        return Ok(None);
    };
    let matches = csvio::match_or_fail(samples, "samples", moved, "moved reference", 10)?;
    let run = Run::new(samples, moved, matches).with_antenna(s.antenna);
    let antenna = match o.antenna {
        LeverArm::Fitted(..) => LeverArm::Fitted(s.antenna.0, s.antenna.1),
        held => held,
    };
    let m = fit_subtrajectories(
        &run,
        &s.params,
        SubtrajectoryOptions {
            length: o.subtrajectory_length,
            antenna,
            cuts: o.subtrajectory_cuts,
            ..Default::default()
        },
    )?;
    let (a, b) = (&s.params, &m.params);
    Ok(Some([
        b.left_diameter - a.left_diameter,
        b.right_diameter - a.right_diameter,
        b.track_width - a.track_width,
        m.antenna.0 - s.antenna.0,
        m.antenna.1 - s.antenna.1,
    ]))
}

/// Adds `shares` ([`offset_shares`]) in quadrature to the reported standard errors of the
/// diameters, the track width and a fitted lever arm.
pub fn add_offset_shares(c: &mut Calibration, shares: [f64; 5]) {
    let g = &mut c.geometry;
    for (k, extra) in shares.iter().take(3).enumerate() {
        for v in [&mut g.std_errors[k], &mut g.robust_std_errors[k]]
            .into_iter()
            .flatten()
        {
            *v = v.hypot(*extra);
        }
    }
    if let Some(se) = &mut g.antenna_std_errors {
        se[0] = se[0].hypot(shares[3]);
        se[1] = se[1].hypot(shares[4]);
    }
    if let Some(s) = &mut c.subtrajectories {
        for (k, extra) in shares.iter().enumerate() {
            if let Some(v) = &mut s.std_errors[k] {
                *v = v.hypot(*extra);
            }
        }
    }
}
