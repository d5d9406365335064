//! What the sample interrupt hands to the processing task.

use crate::timing::{Discipline, PpsEvent, PpsStats, Sample, SyncState};

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
    /// Pulses lost before this one because the queue to the processing task was full.
    pub queue_lost: u32,
}

impl IndexCapture {
    /// Queues the capture with `enqueue` (false: the queue is full), carrying the pulses
    /// lost to a full queue since the last one queued (`lost`, kept by the interrupt).
    pub fn queue(mut self, lost: &mut u32, enqueue: impl FnOnce(Self) -> bool) {
        self.queue_lost = *lost;
        *lost = if enqueue(self) {
            0
        } else {
            lost.wrapping_add(1)
        };
    }
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

impl RawSample {
    /// Sample 0, taken when the sampler started (`disc`): the integration's starting point.
    pub fn first(
        sample: Sample,
        counts: RawCounts,
        faults: (bool, bool),
        disc: &Discipline,
    ) -> Self {
        Self {
            sample,
            counts,
            faults,
            pps: None,
            state: disc.state(),
            stats: disc.stats(),
            period: disc.period(),
            index_pulses: [None, None],
            isr_cycles: 0,
            merged: 0,
            latency: 0,
            pps_overcapture: false,
            queue_lost: 0,
        }
    }
}

/// The PPS edge and over-capture seen by sample interrupts that carried no sample, kept for
/// the next sample.
#[derive(Debug, Clone, Copy, Default)]
pub struct PpsLatch {
    edge: Option<(u64, PpsEvent)>,
    overcapture: bool,
}

impl PpsLatch {
    /// Nothing seen.
    pub const fn new() -> Self {
        Self {
            edge: None,
            overcapture: false,
        }
    }

    /// One interrupt's PPS `edge` (tick and event) and over-capture flag. A newer edge
    /// replaces the kept one, except that a glitch does not hide an accepted edge.
    pub fn on_interrupt(&mut self, edge: Option<(u64, PpsEvent)>, overcapture: bool) {
        if let Some(pps) = edge {
            let keep = matches!(self.edge, Some((_, e)) if e != PpsEvent::Glitch)
                && pps.1 == PpsEvent::Glitch;
            if !keep {
                self.edge = Some(pps);
            }
        }
        self.overcapture |= overcapture;
    }

    /// The kept edge and whether an edge was lost, for the sample being handed on; clears
    /// both.
    pub fn take(&mut self) -> (Option<(u64, PpsEvent)>, bool) {
        (self.edge.take(), core::mem::take(&mut self.overcapture))
    }

    /// `raw` could not be handed on (the queue was full): its PPS edge and over-capture go
    /// with the next sample instead of being lost with it.
    pub fn put_back(&mut self, raw: &RawSample) {
        self.on_interrupt(raw.pps, raw.pps_overcapture);
    }
}
