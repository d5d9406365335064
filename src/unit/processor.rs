//! The processing task's work: one sample's counts to a pose record, with the drop,
//! index-mismatch and motion accounting, the time tag and the Status heartbeat.

use super::event::{Event, Log};
use super::forward::{Forwarder, GnssCounters};
use super::rx_errors::RxErrors;
use super::sample::{IndexCapture, RawSample};
use super::time_tag;
use crate::odometry::index::DEFAULT_TOLERANCE;
use crate::odometry::{
    ChassisParams, CounterExtender, IndexCheck, IndexRefs, IndexTracker, Integrator, Pose,
    StepStatus, WheelCounts,
};
use crate::protocol::{
    GnssSentence, GnssTime, PoseRecord, ResetCause, Status, StatusFlags, WheelStatus,
};
use crate::settings::{Output, Settings, SettingsSource};
use crate::timing::{LineBuffer, NmeaError, PpsEvent, PpsStats, SyncState, TimeTagger};

/// Increments a wheel must turn away from where it rests to count as moving (for the
/// save-while-moving check): an encoder dithering on one edge of its code at rest changes
/// its count by +-1 forever.
pub const MOTION_THRESHOLD: u64 = 8;

/// A sample is late when its counters were read more than 1 / `LATE_FRACTION` of a sample
/// period after its time label (or after a stall merged grid points into it).
pub const LATE_FRACTION: u64 = 4;

/// Changes the command task asks the processing task to apply at the next sample.
#[derive(Debug, Clone, Copy, Default)]
pub struct Requests {
    /// New working settings.
    pub settings: Option<Settings>,
    /// A new pose (the counts go on from where they are).
    pub reset: Option<Pose>,
}

/// Where the settings in use came from and whether they differ from the stored ones
/// (kept by the command task, reported by the heartbeat and `status`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StoreState {
    /// Flash or defaults.
    pub source: SettingsSource,
    /// The working settings differ from those a reset would start with (the stored record's,
    /// or the defaults when none is stored).
    pub dirty: bool,
}

/// What the Status heartbeat reports besides the processing task's own counters.
#[derive(Debug, Clone, Copy)]
pub struct HeartbeatInputs {
    /// Where the settings came from, whether they differ from the stored ones.
    pub store: StoreState,
    /// Host link receive errors.
    pub host: RxErrors,
    /// GNSS receiver receive errors.
    pub gnss: RxErrors,
    /// Why the unit last started.
    pub reset_cause: ResetCause,
}

/// What the processing task last knew, for `status`.
#[derive(Debug, Clone, Copy, Default)]
pub struct Live {
    /// Samples processed.
    pub samples: u32,
    /// Pose records dropped for lack of room on the link.
    pub dropped_total: u32,
    /// Status word of the latest sample.
    pub flags: StatusFlags,
    /// PPS discipline counters.
    pub stats: PpsStats,
    /// Length of a second in use, ticks.
    pub period: u64,
    /// Index pulses whose counts missed a whole turn (left, right).
    pub index_mismatches: [u32; 2],
    /// NMEA sentences rejected.
    pub nmea_errors: u32,
    /// NMEA time messages used.
    pub time_messages: u32,
    /// GNSS sentence forwarding counters.
    pub gnss: GnssCounters,
    /// MCU time of the latest sample, microseconds.
    pub mcu_time_us: u64,
    /// Most cycles of one sample interrupt.
    pub isr_cycles_max: u32,
    /// Most cycles of processing one sample.
    pub process_cycles_max: u32,
    /// Cycles of the last sample interrupt.
    pub isr_cycles_last: u32,
    /// Cycles of processing the last sample.
    pub process_cycles_last: u32,
    /// Samples lost between the sample interrupt and the processing task (queue full).
    pub samples_lost: u32,
    /// Grid points merged into later samples (late sample interrupts: flash stalls).
    pub merged_samples: u32,
    /// Largest latency from a sample's grid point to the interrupt's counter reading,
    /// timer ticks.
    pub latency_max: u32,
    /// Index pulses lost to an over-capture (left, right).
    pub index_lost: [u32; 2],
    /// PPS edges lost to an over-capture.
    pub pps_overcaptures: u32,
    /// A wheel moved more than [`MOTION_THRESHOLD`] increments within the last second.
    pub moving: bool,
    /// Samples per second of the samples now (the sampler's; a new `rate` setting applies
    /// from the next whole second).
    pub rate: u32,
    /// `output_divider` in use (switched together with the rate).
    pub output_divider: u32,
    /// Samples whose counters were read late (more than [`LATE_FRACTION`] of a period after
    /// their label, or after a stall).
    pub late_samples: u32,
}

/// What one sample gave ([`Processor::on_sample`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SampleOutcome {
    /// Integrated, and its record is due (every `output_divider`-th sample).
    Record(PoseRecord),
    /// Integrated; its record is skipped (`output_divider`).
    Skipped,
    /// A record is due but there is no integrator to fill it: neither the settings' nor the
    /// designed chassis parameters were accepted ([`Event::IntegratorRejected`]). The
    /// designed ones always are, so this does not occur.
    NoIntegrator,
}

/// State of the processing task: counts to records.
pub struct Processor {
    timer_hz: u32,
    settings: Settings,
    /// The counters' extensions, valid once `started` (the widths are kept before).
    extenders: [CounterExtender; 2],
    /// The first sample started the extensions.
    started: bool,
    integrator: Option<Integrator>,
    trackers: [IndexTracker; 2],
    /// Index mismatch not yet reported in a sent record.
    mismatch: [bool; 2],
    /// A rate switch not yet reported in a sent record.
    rate_switch: bool,
    /// A late sample not yet reported in a sent record.
    late: bool,
    late_samples: u32,
    /// Samples per second and `output_divider` in use, and samples since they were
    /// switched (the divider counts from the switch).
    rate: u32,
    divider: u32,
    since_switch: u32,
    /// Second label of the last sample, and whether the Status of the latest second is
    /// still to be sent.
    last_second: Option<u32>,
    status_pending: bool,
    tagger: TimeTagger,
    nmea: LineBuffer,
    nmea_errors: u32,
    time_messages: u32,
    forward: Forwarder,
    last_tick: u64,
    sequence: u32,
    dropped_since: u32,
    dropped_total: u32,
    last_state: SyncState,
    last_faults: (bool, bool),
    reset: Option<Pose>,
    flags: StatusFlags,
    mcu_time_us: u64,
    isr_cycles_max: u32,
    process_cycles_max: u32,
    merged_samples: u32,
    latency_max: u32,
    index_lost: [u32; 2],
    pps_overcaptures: u32,
    /// Counts where the wheels were last seen at rest (within [`MOTION_THRESHOLD`]), and
    /// the sample sequence at which they last moved beyond it.
    rest_counts: Option<WheelCounts>,
    last_motion: u32,
    /// Pose resets applied since start (wrapping).
    pose_resets: u32,
}

impl Processor {
    /// Before the first sample: `settings` in use, the sample timer at `timer_hz`, raw
    /// counters `counter_bits` wide (left, right).
    pub fn new(settings: &Settings, timer_hz: u32, counter_bits: [u32; 2]) -> Self {
        let tpr = settings.chassis.ticks_per_rev;
        Self {
            timer_hz,
            settings: *settings,
            extenders: [
                CounterExtender::new(counter_bits[0], 0),
                CounterExtender::new(counter_bits[1], 0),
            ],
            started: false,
            integrator: None,
            trackers: [IndexTracker::new(tpr, DEFAULT_TOLERANCE); 2],
            mismatch: [false; 2],
            rate_switch: false,
            late: false,
            late_samples: 0,
            rate: settings.rate,
            divider: settings.output_divider.max(1),
            since_switch: 0,
            last_second: None,
            status_pending: false,
            tagger: TimeTagger::new(time_tag(settings), u64::from(timer_hz)),
            nmea: LineBuffer::new(),
            nmea_errors: 0,
            time_messages: 0,
            forward: Forwarder::new(),
            last_tick: 0,
            sequence: 0,
            dropped_since: 0,
            dropped_total: 0,
            last_state: SyncState::FreeRunning,
            last_faults: (false, false),
            reset: None,
            flags: StatusFlags::default(),
            mcu_time_us: 0,
            isr_cycles_max: 0,
            process_cycles_max: 0,
            merged_samples: 0,
            latency_max: 0,
            index_lost: [0; 2],
            pps_overcaptures: 0,
            rest_counts: None,
            last_motion: 0,
            pose_resets: 0,
        }
    }

    /// The settings in use.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Pose resets (`reset_pose`) applied since start, wrapping.
    pub fn pose_resets(&self) -> u32 {
        self.pose_resets
    }

    /// An index pulse of `wheel` (0 left, 1 right) latched by its timer.
    pub fn on_index_capture(&mut self, wheel: usize, capture: IndexCapture, log: &mut impl Log) {
        let lost = u32::from(capture.overcapture).wrapping_add(capture.queue_lost);
        if lost > 0 {
            self.index_lost[wheel] = self.index_lost[wheel].wrapping_add(lost);
            log.event(Event::IndexLost { wheel });
        }
        self.on_index(wheel, capture.raw, log);
    }

    /// One byte from the GNSS receiver's NMEA output; `line_end` is the low 32 bits of the
    /// sample timer's tick when the interrupt received it, given for CR and LF. Time
    /// messages of a whole second (ZDA, valid RMC) tag the samples; messages of a fraction
    /// of a second (a 10-20 Hz receiver's) are forwarded but not used for the tag. Returns
    /// the GnssSentence to queue when the byte ended a line that is forwarded
    /// ([`super::forward`]); report the outcome with [`Self::gnss_sent`].
    pub fn on_nmea_byte(&mut self, byte: u8, line_end: Option<u32>) -> Option<GnssSentence> {
        let parsed = self.nmea.push(byte)?;
        match parsed {
            Err(NmeaError::Unsupported) => {}
            Err(_) => self.nmea_errors = self.nmea_errors.wrapping_add(1),
            Ok(msg) if msg.valid() && msg.time().millis == 0 => match msg.time().gps_seconds() {
                Ok(gps) => {
                    self.time_messages = self.time_messages.wrapping_add(1);
                    self.tagger.on_message(gps, self.last_tick);
                }
                Err(_) => self.nmea_errors = self.nmea_errors.wrapping_add(1),
            },
            Ok(_) => {}
        }
        let tick = line_end.map_or(self.last_tick, |low| self.tick_near(low));
        let at = self.mcu_time_us(tick);
        let forwarding = self.settings.output == Output::Frames;
        self.forward
            .on_line(&parsed, self.nmea.last_line(), at, forwarding)
    }

    /// The GnssSentence from [`Self::on_nmea_byte`] was queued (true) or found no room.
    pub fn gnss_sent(&mut self, queued: bool) {
        self.forward.sent(queued);
    }

    /// The GNSS forwarding counters.
    pub fn gnss_counters(&self) -> GnssCounters {
        self.forward.counters()
    }

    /// The tick whose low 32 bits are `low`, nearest the last sample's tick (within 2^31
    /// ticks: 25 s at 84 MHz, 2.1 s in QEMU).
    fn tick_near(&self, low: u32) -> u64 {
        let d = low.wrapping_sub(self.last_tick as u32) as i32;
        self.last_tick.wrapping_add_signed(i64::from(d))
    }

    fn on_index(&mut self, wheel: usize, raw: u32, log: &mut impl Log) {
        if !self.started {
            return;
        }
        let count = self.extenders[wheel].absolute_of(raw);
        match self.trackers[wheel].on_index(count) {
            IndexCheck::Mismatch { error } => {
                self.mismatch[wheel] = true;
                log.event(Event::IndexMismatch { wheel, error });
            }
            IndexCheck::First => log.event(Event::FirstIndex { wheel }),
            IndexCheck::Whole { .. } => {}
        }
    }

    /// Applies the command task's requests (new settings, a pose reset at the next sample).
    pub fn apply(&mut self, requests: Requests, log: &mut impl Log) {
        if let Some(settings) = requests.settings {
            if let Some(integrator) = &mut self.integrator {
                if integrator.set_params(&settings.chassis).is_err() {
                    log.event(Event::ParamsRejected);
                }
            }
            for t in &mut self.trackers {
                t.set_ticks_per_rev(settings.chassis.ticks_per_rev);
            }
            self.tagger.set_assoc(time_tag(&settings));
            self.settings = settings;
        }
        if requests.reset.is_some() {
            self.reset = requests.reset;
        }
    }

    /// MCU time of timer tick `tick`, microseconds.
    fn mcu_time_us(&self, tick: u64) -> u64 {
        let hz = u64::from(self.timer_hz);
        tick / hz * 1_000_000 + tick % hz * 1_000_000 / hz
    }

    /// The counters of `raw` extended to 64 bits (the first sample starts the extension).
    fn extend(&mut self, raw: &RawSample) -> WheelCounts {
        let ext = &mut self.extenders;
        if self.started {
            ext[0].update(raw.counts.left);
            ext[1].update(raw.counts.right);
        } else {
            ext[0] = CounterExtender::new(ext[0].bits(), raw.counts.left);
            ext[1] = CounterExtender::new(ext[1].bits(), raw.counts.right);
            self.started = true;
        }
        WheelCounts {
            left: ext[0].absolute(),
            right: ext[1].absolute(),
        }
    }

    /// Integrates `counts` (the first sample creates the integrator, a requested reset
    /// rebases it).
    fn integrate(
        &mut self,
        counts: WheelCounts,
        refs: IndexRefs,
        log: &mut impl Log,
    ) -> StepStatus {
        let mut step = StepStatus::default();
        match &mut self.integrator {
            None => {
                let pose = self.reset.take().unwrap_or_default();
                let integrator = Integrator::new(&self.settings.chassis, counts, pose)
                    .or_else(|_| Integrator::new(&ChassisParams::DESIGNED, counts, pose));
                match integrator {
                    Ok(i) => self.integrator = Some(i),
                    Err(_) => log.event(Event::IntegratorRejected),
                }
            }
            Some(integrator) => {
                if let Some(pose) = self.reset.take() {
                    integrator.rebase_counts(counts);
                    integrator.reset_pose(pose);
                    self.pose_resets = self.pose_resets.wrapping_add(1);
                    log.event(Event::PoseReset);
                } else {
                    step = integrator.step(counts, refs);
                }
            }
        }
        if step.overrange {
            log.event(Event::Overrange {
                sequence: self.sequence,
            });
        }
        step
    }

    /// Motion: a wheel more than [`MOTION_THRESHOLD`] increments from where it was last at
    /// rest moves (and rests there from now); dithering on one edge of the code does not.
    fn follow_motion(&mut self, counts: WheelCounts) {
        let moved = self.rest_counts.is_none_or(|rest| {
            (counts.left - rest.left).unsigned_abs() > MOTION_THRESHOLD
                || (counts.right - rest.right).unsigned_abs() > MOTION_THRESHOLD
        });
        if moved {
            self.rest_counts = Some(counts);
            self.last_motion = self.sequence;
        }
    }

    /// Timing of `raw`: its PPS edge, a state change, the fault lines.
    fn follow_timing(&mut self, raw: &RawSample, log: &mut impl Log) {
        if let Some((tick, event)) = raw.pps {
            match event {
                PpsEvent::Locked { second } => {
                    log.event(Event::PpsLocked);
                    self.tagger.on_edge(tick, second);
                }
                PpsEvent::Accepted { second, .. } => self.tagger.on_edge(tick, second),
                PpsEvent::Reacquired { second, missed, .. } => {
                    log.event(Event::PpsReacquired { missed });
                    self.tagger.on_edge(tick, second);
                }
                PpsEvent::Glitch => log.event(Event::PpsGlitch),
                PpsEvent::Ignored | PpsEvent::Candidate => {}
            }
        }
        if raw.state != self.last_state {
            log.event(Event::SyncChanged {
                from: self.last_state,
                to: raw.state,
            });
            if raw.state == SyncState::FreeRunning {
                self.tagger.invalidate();
            }
            self.last_state = raw.state;
        }
        if raw.faults != self.last_faults {
            log.event(Event::FaultLines {
                left: raw.faults.0,
                right: raw.faults.1,
            });
            self.last_faults = raw.faults;
        }
        self.last_tick = raw.sample.tick;
    }

    /// Integrates one sample: its record, or why there is none.
    pub fn on_sample(&mut self, raw: &RawSample, log: &mut impl Log) -> SampleOutcome {
        if raw.merged > 0 {
            self.merged_samples = self.merged_samples.wrapping_add(raw.merged);
            log.event(Event::SampleLate {
                latency: raw.latency,
                merged: raw.merged,
            });
        }
        self.latency_max = self.latency_max.max(raw.latency);
        // latency > period / rate / LATE_FRACTION, without a 64-bit division per sample.
        let late = u64::from(raw.latency) * u64::from(raw.sample.rate) * LATE_FRACTION;
        if raw.merged > 0 || late > raw.period {
            self.late = true;
            self.late_samples = self.late_samples.wrapping_add(1);
        }
        self.follow_rate(raw);
        if raw.pps_overcapture {
            self.pps_overcaptures = self.pps_overcaptures.wrapping_add(1);
            log.event(Event::PpsOvercapture);
        }
        let counts = self.extend(raw);
        self.follow_motion(counts);
        for (wheel, pulse) in raw.index_pulses.iter().enumerate() {
            if let Some(r) = pulse {
                self.on_index(wheel, *r, log);
            }
        }
        let refs = IndexRefs {
            left: self.trackers[0].reference(),
            right: self.trackers[1].reference(),
        };
        let step = self.integrate(counts, refs, log);
        self.follow_timing(raw, log);
        let gps = match raw.state {
            SyncState::FreeRunning => None,
            _ => self.tagger.gps_time(raw.sample.second),
        };

        let sequence = self.sequence;
        self.sequence = self.sequence.wrapping_add(1);
        let status = |wheel: usize, fault: bool, calibrated: bool| WheelStatus {
            fault,
            index_seen: self.trackers[wheel].seen(),
            index_mismatch: self.mismatch[wheel],
            calibrated,
        };
        self.flags = StatusFlags {
            sync: raw.state,
            time_valid: gps.is_some(),
            left: status(0, raw.faults.0, step.left_referenced),
            right: status(1, raw.faults.1, step.right_referenced),
            model: self.settings.chassis.uncertainty_model,
            rate_switch: self.rate_switch,
            late: self.late,
        };
        self.mcu_time_us = self.mcu_time_us(raw.sample.tick);
        let phase = self.since_switch;
        self.since_switch = self.since_switch.wrapping_add(1);
        if phase % self.divider != 0 {
            return SampleOutcome::Skipped;
        }
        let Some(integrator) = self.integrator.as_ref() else {
            return SampleOutcome::NoIntegrator;
        };
        let pose = integrator.pose();
        let sigma = integrator.sigma();
        SampleOutcome::Record(PoseRecord {
            sequence,
            flags: self.flags,
            mcu_time_us: self.mcu_time_us,
            gnss: gps.map_or(GnssTime::default(), |g| GnssTime {
                week: g.week,
                tow_ms: g.tow * 1000,
                sample_in_second: raw.sample.index as u16,
            }),
            x: pose.x,
            y: pose.y,
            heading: pose.heading,
            sigma_x: sigma.x,
            sigma_y: sigma.y,
            sigma_heading: sigma.heading,
            cov_xy: sigma.cov_xy,
            gamma_left: counts.left,
            gamma_right: counts.right,
            index_left: refs.left.unwrap_or(0),
            index_right: refs.right.unwrap_or(0),
            dropped: self.dropped_since,
        })
    }

    /// The rate and `output_divider` in use follow the samples: at the first sample of a
    /// second, the sampler's rate for it, and the `output_divider` setting once the samples
    /// have the `rate` setting (the sampler switches at a whole second). A change is one
    /// instant for the records, the heartbeat and the GNSS time: its sample is sent (the
    /// divider counts from it) with the rate switch flag, after a Status that announces it.
    fn follow_rate(&mut self, raw: &RawSample) {
        let second = raw.sample.second;
        if self.last_second == Some(second) {
            return;
        }
        let first = self.last_second.is_none();
        self.last_second = Some(second);
        self.status_pending = true;
        let divider = if raw.sample.rate == self.settings.rate {
            self.settings.output_divider.max(1)
        } else {
            self.divider
        };
        if (raw.sample.rate, divider) != (self.rate, self.divider) {
            self.rate = raw.sample.rate;
            self.divider = divider;
            self.since_switch = 0;
            self.rate_switch = !first;
        }
    }

    /// True while the Status of the latest second of samples is not sent: it is due at the
    /// first sample of each second, before that sample's record, and tried again at each
    /// sample until the link takes it.
    pub fn heartbeat_due(&self) -> bool {
        self.status_pending
    }

    /// The Status heartbeat after sample `raw`, with the counters kept elsewhere (`inputs`).
    pub fn heartbeat(&self, raw: &RawSample, inputs: &HeartbeatInputs) -> Status {
        let gnss = self.forward.counters();
        Status {
            uptime_us: self.mcu_time_us,
            flags: self.flags,
            rate_hz: self.rate,
            samples: self.sequence,
            dropped_total: self.dropped_total,
            pps_edges: raw.stats.accepted,
            pps_rejected: raw.stats.glitches,
            host_rx_lost: inputs.host.lost,
            settings_source: inputs.store.source,
            settings_dirty: inputs.store.dirty,
            samples_lost: raw.queue_lost,
            gnss_rx_lost: inputs.gnss.lost,
            merged_samples: self.merged_samples,
            reset_cause: inputs.reset_cause,
            output_divider: self.divider,
            index_lost: self.index_lost[0].wrapping_add(self.index_lost[1]),
            host_rx_overruns: inputs.host.overruns,
            host_rx_line_errors: inputs.host.line_errors(),
            gnss_rx_overruns: inputs.gnss.overruns,
            gnss_rx_line_errors: inputs.gnss.line_errors(),
            gnss_forwarded: gnss.forwarded,
            gnss_not_forwarded: gnss.not_forwarded,
            gnss_bad_checksum: gnss.bad_checksum,
            gnss_overlong: gnss.overlong,
        }
    }

    /// The Status heartbeat was queued (true) or found no room (false: tried again with
    /// the next sample).
    pub fn status_sent(&mut self, sent: bool) {
        if sent {
            self.status_pending = false;
        }
    }

    /// The record was queued (true) or dropped for lack of room (false).
    pub fn sent(&mut self, sent: bool) {
        if sent {
            self.dropped_since = 0;
            self.mismatch = [false; 2];
            self.rate_switch = false;
            self.late = false;
        } else {
            self.dropped_since = self.dropped_since.saturating_add(1);
            self.dropped_total = self.dropped_total.saturating_add(1);
        }
    }

    /// What `status` shows after sample `raw`, whose processing took `process_cycles`.
    pub fn live(&mut self, raw: &RawSample, process_cycles: u32) -> Live {
        self.isr_cycles_max = self.isr_cycles_max.max(raw.isr_cycles);
        self.process_cycles_max = self.process_cycles_max.max(process_cycles);
        Live {
            isr_cycles_max: self.isr_cycles_max,
            process_cycles_max: self.process_cycles_max,
            isr_cycles_last: raw.isr_cycles,
            process_cycles_last: process_cycles,
            samples: self.sequence,
            dropped_total: self.dropped_total,
            flags: self.flags,
            stats: raw.stats,
            period: raw.period,
            index_mismatches: [self.trackers[0].mismatches(), self.trackers[1].mismatches()],
            nmea_errors: self.nmea_errors,
            time_messages: self.time_messages,
            gnss: self.gnss_counters(),
            mcu_time_us: self.mcu_time_us,
            samples_lost: raw.queue_lost,
            merged_samples: self.merged_samples,
            latency_max: self.latency_max,
            index_lost: self.index_lost,
            pps_overcaptures: self.pps_overcaptures,
            moving: self.sequence.wrapping_sub(self.last_motion) <= self.rate.max(1),
            rate: self.rate,
            output_divider: self.divider,
            late_samples: self.late_samples,
        }
    }
}
