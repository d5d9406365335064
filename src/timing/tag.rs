//! The GNSS time tag: which PPS edge a time message names (the `time_tag_pps` setting),
//! and so the GNSS time of every second label of the sample grid.
//!
//! Receivers differ: most (u-blox, Trimble by default) send the ZDA/RMC of second `T`
//! *after* the PPS edge that marks `T` ([`TimeTagPps::Previous`]); some send it before the
//! edge it announces ([`TimeTagPps::Next`]). A message is only associated when it arrives
//! less than one second after (`Previous`) or before (`Next`) its edge; otherwise it
//! is ignored. That second is measured in timer ticks from the accepted edges themselves
//! (edge to edge over consecutive labels), not taken as the nominal timer frequency: on a
//! timer 4 % slow a message 1.01 s after a (lost) edge would otherwise still fall within
//! "one nominal second" and name the wrong label. Until two edges have been seen, the
//! nominal second is used. Once an edge label `s0` is tied to GPS second `g0`, label `s` is GPS second
//! `g0 + (s - s0)` as long as the discipline stays locked or in holdover (the labels count
//! seconds). Every later message is checked against that mapping and replaces it when it
//! disagrees (counted in `mismatches`).

use super::nmea::GpsTime;

/// Which PPS edge a time message refers to (the `time_tag_pps` setting).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimeTagPps {
    /// The message names the edge that preceded it (the common case).
    #[default]
    Previous,
    /// The message announces the edge that follows it.
    Next,
}

/// Ties second labels of the sample grid to GPS seconds.
#[derive(Debug, Clone)]
pub struct TimeTagger {
    assoc: TimeTagPps,
    /// One second in timer ticks (measured from the edges, nominal until then): the
    /// association window.
    second_ticks: u64,
    /// Last accepted PPS edge: tick and label.
    last_edge: Option<(u64, u32)>,
    /// `Next`: a message waiting for its edge (GPS second, arrival tick).
    pending: Option<(u32, u64)>,
    /// The mapping: label `base.0` is GPS second `base.1`.
    base: Option<(u32, u32)>,
    mismatches: u32,
}

impl TimeTagger {
    /// A tagger with no mapping yet; `second_ticks` is the timer's nominal frequency (the
    /// second's length until it is measured from two accepted edges).
    pub fn new(assoc: TimeTagPps, second_ticks: u64) -> Self {
        Self {
            assoc,
            second_ticks,
            last_edge: None,
            pending: None,
            base: None,
            mismatches: 0,
        }
    }

    /// Changes the association rule; forgets the mapping.
    pub fn set_assoc(&mut self, assoc: TimeTagPps) {
        if assoc != self.assoc {
            self.assoc = assoc;
            self.invalidate();
        }
    }

    /// The association rule in use.
    pub fn assoc(&self) -> TimeTagPps {
        self.assoc
    }

    /// Forgets the mapping and the edges (call when the discipline falls back to
    /// free-running: its labels no longer count GNSS seconds).
    pub fn invalidate(&mut self) {
        self.last_edge = None;
        self.pending = None;
        self.base = None;
    }

    /// The length of a second in use, ticks: measured between the last two accepted edges
    /// of consecutive labels (averaged when labels were skipped), else nominal.
    pub fn second_ticks(&self) -> u64 {
        self.second_ticks
    }

    /// Times a message disagreed with the mapping in force.
    pub fn mismatches(&self) -> u32 {
        self.mismatches
    }

    fn associate(&mut self, label: u32, gps: u32) {
        if let Some(g) = self.gps_second(label) {
            if g == gps {
                return;
            }
            self.mismatches += 1;
        }
        self.base = Some((label, gps));
    }

    /// An accepted PPS edge (tick, label) from the discipline. Edges of later labels also
    /// measure the second (a gap of up to 16 labels is averaged).
    pub fn on_edge(&mut self, tick: u64, label: u32) {
        if let Some((t0, l0)) = self.last_edge {
            let n = label.wrapping_sub(l0);
            if (1..=16).contains(&n) && tick > t0 {
                self.second_ticks = (tick - t0) / u64::from(n);
            }
        }
        self.last_edge = Some((tick, label));
        if let Some((gps, at)) = self.pending.take() {
            if tick >= at && tick - at < self.second_ticks {
                self.associate(label, gps);
            }
        }
    }

    /// A valid time message naming GPS second `gps`, whose first byte arrived at `tick`.
    /// Returns true when it was associated with an edge (or is waiting for it, `Next`).
    pub fn on_message(&mut self, gps: u32, tick: u64) -> bool {
        match self.assoc {
            TimeTagPps::Previous => match self.last_edge {
                Some((edge, label)) if tick >= edge && tick - edge < self.second_ticks => {
                    self.associate(label, gps);
                    true
                }
                _ => false,
            },
            TimeTagPps::Next => {
                self.pending = Some((gps, tick));
                true
            }
        }
    }

    /// GPS second of grid second `label`, if the mapping is known.
    pub fn gps_second(&self, label: u32) -> Option<u32> {
        let (s0, g0) = self.base?;
        let d = label.wrapping_sub(s0) as i32;
        g0.checked_add_signed(d)
    }

    /// GPS week and time of week of grid second `label`, if known.
    pub fn gps_time(&self, label: u32) -> Option<GpsTime> {
        self.gps_second(label).map(GpsTime::from_seconds)
    }
}
