//! What the unit reports to its log (the firmware prints these with defmt).

use crate::timing::SyncState;

/// One loggable event of the processing task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// The sample interrupt ran late by `latency` ticks and merged `merged` grid points.
    SampleLate {
        /// Ticks from the grid point to the counter reading.
        latency: u32,
        /// Grid points merged.
        merged: u32,
    },
    /// A PPS edge was lost to an over-capture (two edges in one interrupt).
    PpsOvercapture,
    /// An index pulse of `wheel` (0 left, 1 right) was lost to an over-capture.
    IndexLost {
        /// 0 left, 1 right.
        wheel: usize,
    },
    /// The first index pulse of `wheel`.
    FirstIndex {
        /// 0 left, 1 right.
        wheel: usize,
    },
    /// The counts between two index pulses of `wheel` missed a whole turn by `error`.
    IndexMismatch {
        /// 0 left, 1 right.
        wheel: usize,
        /// Increments off the nearest whole number of turns.
        error: i64,
    },
    /// New chassis parameters were rejected by the integrator (it keeps the old ones).
    ParamsRejected,
    /// The integrator rejected even the designed parameters: nothing is integrated.
    IntegratorRejected,
    /// The pose was reset on request.
    PoseReset,
    /// Sample `sequence` moved beyond one sample's limits and was not integrated.
    Overrange {
        /// The sample's sequence number.
        sequence: u32,
    },
    /// The discipline locked to the PPS.
    PpsLocked,
    /// The discipline found the PPS again after `missed` lost pulses.
    PpsReacquired {
        /// Pulses lost.
        missed: u32,
    },
    /// A PPS glitch was rejected.
    PpsGlitch,
    /// The sampling state changed.
    SyncChanged {
        /// State before.
        from: SyncState,
        /// State now.
        to: SyncState,
    },
    /// The encoder fault lines changed.
    FaultLines {
        /// Left line active.
        left: bool,
        /// Right line active.
        right: bool,
    },
}

/// Where the unit's events go (the firmware's defmt log; a list in tests).
pub trait Log {
    /// Records `event`.
    fn event(&mut self, event: Event);
}

/// Events dropped (nothing to log to).
impl Log for () {
    fn event(&mut self, _: Event) {}
}
