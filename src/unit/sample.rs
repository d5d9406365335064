//! What the sample interrupt hands to the processing task.

use crate::timing::{PpsEvent, PpsStats, Sample, SyncState};

/// Both wheels' raw counters, read together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RawCounts {
    /// The left counter (32 bits on the board).
    pub left: u32,
    /// The right counter (16 bits on the board).
    pub right: u32,
}

/// One index pulse latched by a wheel's timer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IndexCapture {
    /// The wheel's raw counter at the index edge.
    pub raw: u32,
    /// An earlier pulse was overwritten before it was read (lost).
    pub overcapture: bool,
}

/// One sample, from the sample interrupt to the processing task.
#[derive(Debug, Clone, Copy)]
pub struct RawSample {
    /// The schedule's sample.
    pub sample: Sample,
    /// Raw counters.
    pub counts: RawCounts,
    /// Fault lines (left, right): true when the encoder reports a fault.
    pub faults: (bool, bool),
    /// A PPS edge seen since the previous sample: its tick and what the discipline made of it.
    pub pps: Option<(u64, PpsEvent)>,
    /// Discipline state after this interrupt.
    pub state: SyncState,
    /// Discipline counters after this interrupt.
    pub stats: PpsStats,
    /// Length of a second in use, ticks.
    pub period: u64,
    /// Raw counts of index pulses that came with the sample (left, right): the simulated
    /// drive's; on the board the timers latch them ([`IndexCapture`]).
    pub index_pulses: [Option<u32>; 2],
    /// Cycles (instructions in QEMU) the sample interrupt took up to the hand-over.
    pub isr_cycles: u32,
    /// Grid points merged into this sample because the interrupt ran late (a stall).
    pub merged: u32,
    /// Timer ticks from the sample's grid point to the interrupt's counter reading.
    pub latency: u32,
    /// A PPS edge was lost to an over-capture before this sample.
    pub pps_overcapture: bool,
    /// Samples lost so far because the queue to the processing task was full.
    pub queue_lost: u32,
}
