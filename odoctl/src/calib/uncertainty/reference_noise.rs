//! The reference's noise: as stated (each epoch's own sigma where its log gives one, else the
//! options), the predicted bands widened by it, and what the data show of it.
//!
//! One meaning everywhere: the horizontal noise is the horizontal RMS `hypot(sigma_east,
//! sigma_north)` (m), each axis carrying `1/sqrt 2` of it. GST's latitude and longitude sigmas
//! and `.pos`'s `sdn`/`sde` are per-axis standard deviations, combined that way; a REFERENCE
//! CSV's `sigma_h` and `--reference-sigma` are the horizontal RMS itself. The heading noise is
//! the standard deviation of one reference heading (rad).
//!
//! The scatter ([`ReferenceNoise::check`]): between consecutive evaluated epochs at most
//! [`SCATTER_MAX_GAP`] apart the odometry's own error hardly changes, so the change of the
//! error `odometry - reference` from one epoch to the next is the difference of two
//! reference noises. Its robust standard deviation (1.4826 times the median absolute value)
//! over both axes is `sqrt 2` times the per-axis sigma, which is the horizontal RMS; over the
//! heading errors it is `sqrt 2` times the heading sigma. A receiver whose errors are
//! correlated from epoch to epoch (most RTK receivers) scatters less than its sigma, so the
//! scatter can show a stated noise too small, never too large.

use crate::calib::evaluation::Evaluation;
use crate::calib::{DEFAULT_REFERENCE_HEADING_SIGMA_DEG, DEFAULT_REFERENCE_SIGMA};
use crate::reference::trajectory_noise::TrajectoryNoise;
use crate::stats::{median, wrap_angle, MAD_TO_SIGMA};

use super::coverage::{heading_coverage, horizontal_coverage, reference_sigma_at};

/// Largest time between two epochs whose error change counts in the scatter (s).
pub const SCATTER_MAX_GAP: f64 = 0.25;

/// The scatter is said to disagree with the stated noise above this ratio.
pub const SCATTER_RATIO_WARNING: f64 = 2.0;

/// Fewest epoch pairs for a scatter figure.
pub const SCATTER_MIN_PAIRS: usize = 20;

/// The reference's stated noise, where the log gives none per epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceNoise {
    /// Horizontal RMS noise (m), `hypot(sigma_east, sigma_north)`.
    pub horizontal: f64,
    /// Heading noise of one reference heading (rad, 1 sigma).
    pub heading: f64,
}

/// The stated noise beside the scatter the data show ([`ReferenceNoise::check`]).
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseCheck {
    /// Stated horizontal RMS noise (m): the median of the epochs' own, else the option.
    pub stated_horizontal: f64,
    /// True when `stated_horizontal` comes from the log's own sigmas.
    pub from_log: bool,
    /// Horizontal RMS noise (m) shown by the epoch-to-epoch scatter.
    pub scatter_horizontal: Option<f64>,
    /// Stated heading noise (rad).
    pub stated_heading: f64,
    /// Heading noise (rad) shown by the epoch-to-epoch scatter, where the reference has headings.
    pub scatter_heading: Option<f64>,
    /// Epoch pairs behind the horizontal scatter.
    pub pairs: usize,
}

impl ReferenceNoise {
    /// The noise of a reference: `sigma` (m, horizontal RMS) and `heading_deg` where given
    /// (the options), else a trajectory's own (`own`, [`TrajectoryNoise`]), else
    /// [`DEFAULT_REFERENCE_SIGMA`] and [`DEFAULT_REFERENCE_HEADING_SIGMA_DEG`].
    pub fn resolve(
        sigma: Option<f64>,
        heading_deg: Option<f64>,
        own: Option<&TrajectoryNoise>,
    ) -> Self {
        Self {
            horizontal: sigma
                .or(own.map(|n| n.horizontal))
                .unwrap_or(DEFAULT_REFERENCE_SIGMA),
            heading: heading_deg
                .map(f64::to_radians)
                .or(own.and_then(|n| n.heading))
                .unwrap_or(DEFAULT_REFERENCE_HEADING_SIGMA_DEG.to_radians()),
        }
    }

    /// Share of horizontal errors, the start left out, inside `k` sigma_h widened by the
    /// reference noise (each epoch's own where the log gives it).
    pub fn horizontal_coverage(&self, ev: &Evaluation, k: f64) -> f64 {
        horizontal_coverage(ev, self.horizontal, k, 1)
    }

    /// Share of errors of the heading change since the start (what sigma_heading, zero at the
    /// start, predicts), the start left out, inside `k` sigma_heading widened by the reference
    /// heading noise; NaN without reference headings.
    pub fn heading_coverage(&self, ev: &Evaluation, k: f64) -> f64 {
        heading_coverage(ev, self.heading, k, 1)
    }

    /// The stated noise beside the epoch-to-epoch scatter of the errors along `ev`.
    pub fn check(&self, ev: &Evaluation) -> NoiseCheck {
        let from_log = ev.reference_sigma_h.iter().any(Option::is_some);
        let mut stated: Vec<f64> = (0..ev.horizontal.len())
            .map(|i| reference_sigma_at(ev, i, self.horizontal))
            .collect();
        let stated_horizontal = median(&mut stated).unwrap_or(self.horizontal);
        let mut axes = Vec::new();
        let mut headings = Vec::new();
        for i in 1..ev.t.len() {
            let gap = ev.t[i] - ev.t[i - 1];
            if gap.is_nan() || gap > SCATTER_MAX_GAP {
                continue;
            }
            let error = |j: usize| {
                (
                    ev.odo[j].0 - ev.reference[j].0,
                    ev.odo[j].1 - ev.reference[j].1,
                )
            };
            let (a, b) = (error(i - 1), error(i));
            axes.push((b.0 - a.0).abs());
            axes.push((b.1 - a.1).abs());
            if let (Some(ha), Some(hb)) = (ev.heading_err[i - 1], ev.heading_err[i]) {
                headings.push(wrap_angle(hb - ha).abs());
            }
        }
        let pairs = axes.len() / 2;
        let robust = |v: &mut Vec<f64>, pairs: usize| {
            (pairs >= SCATTER_MIN_PAIRS)
                .then(|| median(v))
                .flatten()
                .map(|m| MAD_TO_SIGMA * m)
        };
        let heading_pairs = headings.len();
        NoiseCheck {
            stated_horizontal,
            from_log,
            scatter_horizontal: robust(&mut axes, pairs),
            stated_heading: self.heading,
            scatter_heading: robust(&mut headings, heading_pairs).map(|s| s / 2f64.sqrt()),
            pairs,
        }
    }
}

impl NoiseCheck {
    /// One line: the stated noise and the scatter.
    pub fn describe(&self) -> String {
        let source = if self.from_log {
            "the log's own sigmas, median"
        } else {
            "--reference-sigma, else a trajectory's own"
        };
        let mut s = format!(
            "reference noise: stated {:.4} m horizontal RMS ({source})",
            self.stated_horizontal
        );
        match self.scatter_horizontal {
            Some(h) => {
                s += &format!(
                    ", epoch-to-epoch scatter {h:.4} m over {} pairs",
                    self.pairs
                )
            }
            None => s += ", no scatter figure (too few epochs within 0.25 s of each other)",
        }
        if let Some(a) = self.scatter_heading {
            s += &format!(
                "; heading stated {:.3} deg, scatter {:.3} deg",
                self.stated_heading.to_degrees(),
                a.to_degrees()
            );
        }
        s
    }

    /// What disagrees: a scatter more than [`SCATTER_RATIO_WARNING`] times the stated noise.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if let Some(h) = self.scatter_horizontal {
            if h > SCATTER_RATIO_WARNING * self.stated_horizontal {
                w.push(format!(
                    "the reference scatters {h:.4} m (horizontal RMS) from epoch to epoch, {:.1} times its stated noise {:.4} m: the bands and kappa take the stated figure; {}",
                    h / self.stated_horizontal,
                    self.stated_horizontal,
                    if self.from_log {
                        "the log's sigmas understate its noise, or fixes are mixed with float ones (check the fix quality)"
                    } else {
                        "give the receiver's horizontal RMS as --reference-sigma"
                    }
                ));
            }
        }
        if let Some(a) = self.scatter_heading {
            if a > SCATTER_RATIO_WARNING * self.stated_heading {
                w.push(format!(
                    "the reference heading scatters {:.3} deg from epoch to epoch, {:.1} times the stated {:.3} deg: give it as --reference-heading-sigma-deg",
                    a.to_degrees(),
                    a / self.stated_heading,
                    self.stated_heading.to_degrees()
                ));
            }
        }
        w
    }

    /// A hint, not a warning: a horizontal scatter below a [`SCATTER_RATIO_WARNING`]th of the
    /// stated noise. A receiver's correlated errors scatter less than its sigma, but a
    /// reference whose errors are independent from epoch to epoch (motion capture, most
    /// trajectory references) is then far less noisy than stated, and the fits would ascribe
    /// the odometry's own errors to it.
    pub fn hint(&self) -> Option<String> {
        let h = self.scatter_horizontal?;
        (h * SCATTER_RATIO_WARNING < self.stated_horizontal && !self.from_log).then(|| {
            format!(
                "note: the reference scatters only {h:.4} m from epoch to epoch against the stated {:.4} m: if its errors are independent from epoch to epoch (motion capture), give --reference-sigma {h:.4}",
                self.stated_horizontal
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The options where given, else a trajectory's own, else the defaults; each of the two
    /// on its own.
    #[test]
    fn the_options_then_the_trajectorys_own_then_the_defaults() {
        let own = TrajectoryNoise {
            horizontal: 0.0004,
            heading: Some(0.002),
            triples: 100,
        };
        let positions_only = TrajectoryNoise {
            heading: None,
            ..own
        };
        let d = (
            DEFAULT_REFERENCE_SIGMA,
            DEFAULT_REFERENCE_HEADING_SIGMA_DEG.to_radians(),
        );
        // sigma option, heading option (deg), own noise: horizontal, heading.
        type Row<'a> = (
            Option<f64>,
            Option<f64>,
            Option<&'a TrajectoryNoise>,
            (f64, f64),
        );
        let table: [Row; 6] = [
            (None, None, None, d),
            (Some(0.02), Some(1.0), None, (0.02, 1f64.to_radians())),
            (None, None, Some(&own), (0.0004, 0.002)),
            (Some(0.02), None, Some(&own), (0.02, 0.002)),
            (None, Some(1.0), Some(&own), (0.0004, 1f64.to_radians())),
            (None, None, Some(&positions_only), (0.0004, d.1)),
        ];
        for (sigma, heading, noise, want) in table {
            let n = ReferenceNoise::resolve(sigma, heading, noise);
            assert_eq!(
                (n.horizontal, n.heading),
                want,
                "{sigma:?} {heading:?} {noise:?}"
            );
        }
    }

    /// An evaluation with a perfect odometry and a reference with white noise of horizontal
    /// RMS `h` (m) and heading noise `a` (rad), epochs every `dt` s.
    fn noisy(seed: u64, n: usize, dt: f64, h: f64, a: f64) -> Evaluation {
        let mut rng = odo_testkit::Rng::new(seed);
        let mut ev = Evaluation::default();
        for i in 0..n {
            let truth = (0.05 * i as f64, 0.0);
            let axis = h / 2f64.sqrt();
            ev.t.push(i as f64 * dt);
            ev.odo.push(truth);
            ev.reference
                .push((truth.0 + axis * rng.normal(), truth.1 + axis * rng.normal()));
            ev.horizontal.push(0.0);
            ev.sigma_h.push(0.0);
            ev.heading_err.push(Some(a * rng.normal()));
            ev.reference_sigma_h.push(None);
        }
        ev
    }

    #[test]
    fn scatter_recovers_white_noise_over_seeds() {
        for seed in 0..20 {
            let ev = noisy(seed, 2000, 0.1, 0.008, 0.5f64.to_radians());
            let noise = ReferenceNoise {
                horizontal: 0.008,
                heading: 0.5f64.to_radians(),
            };
            let c = noise.check(&ev);
            let h = c.scatter_horizontal.unwrap();
            let a = c.scatter_heading.unwrap();
            // Robust sigma over 4000 values: about 2 % standard error.
            assert!((h / 0.008 - 1.0).abs() < 0.08, "seed {seed}: {h}");
            assert!(
                (a / 0.5f64.to_radians() - 1.0).abs() < 0.1,
                "seed {seed}: {a}"
            );
            assert!(c.warnings().is_empty(), "{:?}", c.warnings());
            assert_eq!(c.pairs, 1999);
        }
    }

    #[test]
    fn understated_noise_is_named_overstated_is_not() {
        let ev = noisy(7, 2000, 0.1, 0.024, 0.5f64.to_radians());
        let under = ReferenceNoise {
            horizontal: 0.008,
            heading: 0.1f64.to_radians(),
        };
        let w = under.check(&ev).warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].contains("--reference-sigma"), "{}", w[0]);
        assert!(w[1].contains("--reference-heading-sigma-deg"), "{}", w[1]);
        let over = ReferenceNoise {
            horizontal: 0.1,
            heading: 5f64.to_radians(),
        };
        assert!(over.check(&ev).warnings().is_empty());
    }

    #[test]
    fn a_reference_far_quieter_than_stated_gets_a_hint() {
        let ev = noisy(5, 2000, 0.1, 0.0007, 0.001);
        let stated = |horizontal| ReferenceNoise {
            horizontal,
            heading: 0.001,
        };
        let hint = stated(0.008).check(&ev).hint().expect("a hint");
        assert!(hint.contains("--reference-sigma 0.0007"), "{hint}");
        assert_eq!(stated(0.0007).check(&ev).hint(), None);
        assert_eq!(stated(0.0012).check(&ev).hint(), None);
    }

    #[test]
    fn gaps_and_short_runs_give_no_scatter() {
        // Epochs 1 s apart: none within SCATTER_MAX_GAP.
        let ev = noisy(1, 500, 1.0, 0.008, 0.01);
        let c = ReferenceNoise {
            horizontal: 0.008,
            heading: 0.01,
        }
        .check(&ev);
        assert_eq!((c.scatter_horizontal, c.pairs), (None, 0));
        assert!(c.describe().contains("no scatter figure"));
        let short = noisy(1, SCATTER_MIN_PAIRS, 0.1, 0.008, 0.01);
        let c = ReferenceNoise {
            horizontal: 0.008,
            heading: 0.01,
        }
        .check(&short);
        assert_eq!(c.scatter_horizontal, None);
    }

    #[test]
    fn the_logs_own_sigmas_are_stated() {
        let mut ev = noisy(3, 100, 0.1, 0.02, 0.01);
        for s in ev.reference_sigma_h.iter_mut() {
            *s = Some(0.02);
        }
        let c = ReferenceNoise {
            horizontal: 0.008,
            heading: 0.01,
        }
        .check(&ev);
        assert!(c.from_log);
        assert_eq!(c.stated_horizontal, 0.02);
        assert!(c.describe().contains("the log's own sigmas"));
    }

    #[test]
    fn widened_coverage_takes_each_epochs_own_sigma() {
        // Errors of 0.01 m, no odometry sigma: inside the 1-sigma band only where the
        // reference's sigma is at least 0.01 m.
        let mut ev = noisy(3, 5, 0.1, 0.0, 0.0);
        ev.horizontal = vec![0.0, 0.01, 0.01, 0.01, 0.01];
        ev.reference_sigma_h = vec![None, Some(0.02), None, Some(0.005), None];
        let noise = ReferenceNoise {
            horizontal: 0.01,
            heading: 0.0,
        };
        // Points 1..: 0.02 (in), option 0.01 (in, on the boundary), 0.005 (out), 0.01 (in).
        assert_eq!(noise.horizontal_coverage(&ev, 1.0), 0.75);
        assert_eq!(noise.horizontal_coverage(&ev, 3.0), 1.0);
    }
}
