//! Sentences arriving one by one (`record --calibrate`) to reference points on the samples'
//! time base, each update costing what the new sentences cost.
//!
//! The sentences of the last [`WINDOW`] seconds (unit time of reception) are read by the
//! NMEA log reader ([`nmea::parse`], the same rules as for a file) and put into the local
//! plane of the first used epoch (`OriginChoice::Given`); an epoch is handed on once a later
//! GGA (of any fix quality) has arrived (its GST and HDT are in by then), and only once. The minimum fix quality
//! is the file reader's default (RTK fixed).

use std::collections::VecDeque;

use super::{nmea, Format, OriginChoice, Reference, ReferenceOptions};
use crate::csvio::RefPoint;

/// Seconds of sentences (unit time of reception) read at each update.
pub const WINDOW: f64 = 3.0;

/// The streaming reader.
pub struct NmeaStream {
    /// (reception time s, sentence) of the last [`WINDOW`] seconds.
    window: VecDeque<(f64, String)>,
    options: ReferenceOptions,
    /// GPS time of the last epoch handed on (s).
    last: f64,
    /// Epochs handed on.
    pub points: usize,
    /// Reference points the samples' time span did not cover when they were read (before the
    /// first sample): left out.
    pub before_samples: usize,
}

impl Default for NmeaStream {
    fn default() -> Self {
        Self::new()
    }
}

impl NmeaStream {
    /// An empty reader with the file reader's default options.
    pub fn new() -> Self {
        Self {
            window: VecDeque::new(),
            options: ReferenceOptions {
                format: Some(Format::Nmea),
                origin: OriginChoice::FirstEpoch,
                ..ReferenceOptions::default()
            },
            last: f64::NEG_INFINITY,
            points: 0,
            before_samples: 0,
        }
    }

    /// One sentence received at unit time `at` (s).
    pub fn push(&mut self, at: f64, sentence: &str) {
        self.window.push_back((at, sentence.to_string()));
        while self.window.front().is_some_and(|(t, _)| *t < at - WINDOW) {
            self.window.pop_front();
        }
    }

    /// The epochs complete since the last call, as reference points on the samples' time
    /// base, given the samples' first and last time (s). At the end of the drive
    /// (`end`), the newest epoch too.
    pub fn take(&mut self, samples: (f64, f64), end: bool) -> Vec<RefPoint> {
        if self.window.is_empty() {
            return Vec::new();
        }
        let mut text = String::new();
        for (_, s) in &self.window {
            text.push_str(s);
            text.push_str("\r\n");
        }
        let Ok(log) = nmea::parse("live", &text, self.options.leap_seconds) else {
            return Vec::new();
        };
        // Complete: an epoch with a later GGA of any fix quality.
        let newest = log.epochs.last().map_or(f64::NEG_INFINITY, |e| e.gps_time);
        let Ok(r) = Reference::from_log("live", Format::Nmea, log, &self.options) else {
            return Vec::new();
        };
        if let (OriginChoice::FirstEpoch, Some(o)) = (self.options.origin, r.origin) {
            // Every later window in the plane of this first epoch.
            self.options.origin = OriginChoice::Given(o);
        }
        // Times on the samples' base (the GPS week that puts the window over the samples): a
        // window's epochs may come a little before the first sample or after the last.
        let margin = WINDOW + 1.0;
        let span = (samples.0 - margin, samples.1 + margin);
        let Ok(points) = r.ref_points(span) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (e, p) in r.epochs.iter().zip(points) {
            if e.t > self.last && (end || e.t < newest) {
                self.last = e.t;
                if p.t < samples.0 {
                    self.before_samples += 1;
                    continue;
                }
                out.push(p);
            }
        }
        self.points += out.len();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::{gps_time, parse, simulated};

    /// The sentences fed one epoch at a time give the file reader's points (in the plane of
    /// the first epoch), each once.
    #[test]
    fn stream_gives_the_file_readers_points() {
        let settings = crate::simulate::SimSettings {
            seed: 3,
            ..Default::default()
        };
        let mut sim = crate::simulate::simulate_path(
            crate::simulate::PathKind::Estimation,
            20.0,
            crate::simulate::default_truth(),
            settings,
        );
        let receiver = simulated::ReceiverSim {
            heading_sigma: Some(0.01),
            ..Default::default()
        };
        let times: Vec<f64> = sim.samples.iter().map(|s| s.t).collect();
        let epochs = simulated::receiver_epochs(&times, &sim.truth, &receiver);
        let mut bytes = Vec::new();
        simulated::write_nmea(&mut bytes, &epochs, 18).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let (_, tow0) = gps_time::week_tow(receiver.gps_start);
        for s in &mut sim.samples {
            s.t += tow0;
        }
        let whole = parse(
            "whole",
            text.as_bytes(),
            &ReferenceOptions {
                origin: OriginChoice::FirstEpoch,
                ..ReferenceOptions::default()
            },
        )
        .unwrap();
        let span = (sim.samples[0].t, sim.samples.last().unwrap().t);
        let expected = whole.ref_points(span).unwrap();
        let mut stream = NmeaStream::new();
        let mut got = Vec::new();
        for (k, line) in text.lines().enumerate() {
            stream.push(k as f64 * 0.025, line);
            if k % 7 == 0 {
                got.extend(stream.take(span, false));
            }
        }
        got.extend(stream.take(span, true));
        assert_eq!(got.len(), expected.len());
        for (g, e) in got.iter().zip(&expected) {
            assert_eq!(g.t, e.t);
            assert!((g.x - e.x).abs() < 1e-9 && (g.y - e.y).abs() < 1e-9);
            assert_eq!(g.heading, e.heading);
            assert_eq!(g.sigma_h, e.sigma_h);
        }
    }
}
