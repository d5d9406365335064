//! PPS discipline: the sample schedule, phase-locked to the GNSS 1-PPS or free-running.
//!
//! Time is counted in ticks of one MCU timer (84 MHz on the board, 1 GHz in QEMU), extended
//! by the driver to 64 bits. The discipline is pure: the driver feeds it PPS capture
//! timestamps ([`Discipline::on_pps`]) and asks it for the instant of each sample
//! ([`Discipline::next_sample`]); it programs the timer to fire there.
//!
//! # The grid
//! Samples are grouped in *seconds*, numbered by a `u32` label. Second `s` starts at its
//! anchor `A(s)`; sample `k` of it (`0 <= k < rate`) falls at `A(s) + floor(k * P / rate)`,
//! where `P` is the length of the second in ticks. The arithmetic is exact integer
//! arithmetic re-anchored every second, so nothing drifts however long the unit runs.
//!
//! - [`SyncState::Locked`]: `A(s)` is the captured PPS edge of second `s` and `P` the last
//!   measured PPS period (edge to edge), so the MCU crystal's error is removed and the
//!   samples fall on the 20 ms grid (at 50 Hz) of the GNSS second. Second `s + 1` is first
//!   predicted at `A(s) + P`; samples already committed to the hardware keep that
//!   prediction and the following ones move to the real edge once it is captured (the
//!   difference is the edge's jitter plus the crystal's drift over one second: nanoseconds).
//! - [`SyncState::Holdover`]: the PPS was lost. The grid goes on with the last measured
//!   period from the last real edge, flagged. An edge found again within the window of its
//!   predicted time re-locks (`Reacquired`).
//! - [`SyncState::FreeRunning`]: `mode = free`, or the holdover lasted longer than
//!   `holdover_s`, or no PPS was ever seen. `P` is the nominal timer frequency (after a
//!   holdover that ran out in `mode = pps`: the last measured period, which is closer to the
//!   truth than nominal on an RC clock): the grid runs off the MCU clock alone. In
//!   `mode = pps` it locks again on the PPS (see *Acquisition*).
//!
//! # Clock tolerance
//! `max_offset_ppm` is how far the timer's real frequency may be from `timer_hz`: it must
//! cover the clock's whole error, or the PPS never locks. [`DisciplineConfig::for_clock`]
//! sets it from the clock's tolerance: [`HSE_CRYSTAL_TOLERANCE_PPM`] for a crystal,
//! [`HSI_TOLERANCE_PPM`] for the STM32's internal RC oscillator (+-4 % from -10 to 85 C).
//! Nothing else assumes a small offset: once locked, every prediction, window and rounding
//! uses the measured period, not `timer_hz`; `timer_hz` only sets the free-running period,
//! the acquisition test and the length in ticks of the default glitch window (50 us of
//! *nominal* time, 48-52 us of real time at +-4 %).
//!
//! # Acquisition
//! From free-running in `mode = pps`, an interval between two edges within
//! `max_offset_ppm` (plus the glitch window) of one nominal second is a candidate period.
//! With a crystal tolerance (`max_offset_ppm <=` [`DIRECT_LOCK_MAX_PPM`]) the pair locks at
//! once (the second edge). With a wider tolerance a pair is not selective (a spurious edge
//! within +-5 % of a second after a real one would pass), so a third edge must confirm the
//! candidate period: it must fall within `glitch_window_ticks` of the candidate's
//! prediction, exactly as an edge does when locked. The schedule locks at that third edge.
//!
//! # Glitches
//! While locked (or in holdover) an edge farther than `glitch_window_ticks` from its
//! predicted time, or one giving a period outside `max_offset_ppm` of nominal, or a second
//! edge in the same second, is rejected and counted; it changes nothing.

use core::ops::RangeInclusive;

/// Accepted sample rates, samples per second (both modes).
pub const RATE_RANGE: RangeInclusive<u32> = 1..=10_000;

/// Frequency tolerance to configure for a timer clocked from an HSE crystal (or an external
/// clock of crystal accuracy), ppm: a +-100 ppm part (initial tolerance, temperature, ageing)
/// with a wide margin. The default of [`DisciplineConfig::new`].
pub const HSE_CRYSTAL_TOLERANCE_PPM: u32 = 500;

/// Frequency tolerance to configure for a timer clocked from the STM32F401's internal 16 MHz
/// RC oscillator (HSI), ppm: +-1 % at 25 C, +-4 % from -10 to 85 C (datasheet DS10086), plus
/// a 1 % margin. From -40 to 105 C the HSI may be -8/+4.5 %, beyond this bound and beyond the
/// UARTs' tolerance as well: the HSI's range is -10 to 85 C (docs/HARDWARE.md, Clocks).
pub const HSI_TOLERANCE_PPM: u32 = 50_000;

/// Where the MCU's clock (and so the sample timer's) comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockSource {
    /// PLL from the HSE: crystal or external clock accuracy.
    Hse,
    /// PLL from the 16 MHz HSI (+-1 % at 25 C, +-4 % from -10 to 85 C): a build without
    /// the `hse` feature, or QEMU.
    Hsi,
    /// The build asked for the HSE but it did not start, the PLL did not lock on it, or the
    /// clock security system saw it fail later: PLL from the HSI, reported in `status`.
    HsiFallback,
}

impl ClockSource {
    /// Largest frequency error of the timer clock, ppm: what the PPS discipline must accept
    /// to lock ([`HSE_CRYSTAL_TOLERANCE_PPM`], [`HSI_TOLERANCE_PPM`]).
    pub fn tolerance_ppm(self) -> u32 {
        match self {
            Self::Hse => HSE_CRYSTAL_TOLERANCE_PPM,
            Self::Hsi | Self::HsiFallback => HSI_TOLERANCE_PPM,
        }
    }
}

/// Largest `max_offset_ppm` [`DisciplineConfig::validate`] accepts, ppm (10 %): beyond it
/// whole seconds could no longer be told apart reliably from one interval.
pub const MAX_OFFSET_LIMIT_PPM: u32 = 100_000;

/// Widest `max_offset_ppm` with which two edges lock at once; above it a third edge must
/// confirm the period (see the module documentation, *Acquisition*), ppm.
pub const DIRECT_LOCK_MAX_PPM: u32 = 1_000;

/// Where the samples' timing comes from (the `mode` setting).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SyncMode {
    /// Calibration mode: phase-locked to the GNSS 1-PPS (holdover, then free-running, when
    /// the PPS is lost).
    Pps,
    /// Indoor mode: free-running off the MCU clock.
    Free,
}

/// The state of the sample schedule, reported in every record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SyncState {
    /// Off the MCU clock alone (nominal timer frequency).
    #[default]
    FreeRunning,
    /// On the PPS: grid anchored at the last captured edge, period measured.
    Locked,
    /// PPS lost for at most `holdover_s` seconds: last measured period, predicted edges.
    Holdover,
}

/// Parameters of the discipline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DisciplineConfig {
    /// Nominal frequency of the timer ticks, Hz.
    pub timer_hz: u32,
    /// Samples per second ([`RATE_RANGE`]); a change takes effect at the first second that
    /// begins after it ([`Discipline::begin_second`]).
    pub rate_hz: u32,
    /// PPS-locked or free-running.
    pub mode: SyncMode,
    /// Largest accepted difference of a measured PPS period from `timer_hz`, ppm: the
    /// timer clock's frequency tolerance (1..=[`MAX_OFFSET_LIMIT_PPM`]; see
    /// [`DisciplineConfig::for_clock`]).
    pub max_offset_ppm: u32,
    /// Largest accepted distance of a PPS edge from its predicted time, ticks.
    pub glitch_window_ticks: u32,
    /// Seconds of holdover before the schedule falls back to free-running.
    pub holdover_s: u32,
}

/// A [`DisciplineConfig`] that cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConfigError {
    /// `timer_hz` below 1 kHz.
    TimerHz,
    /// `rate_hz` outside [`RATE_RANGE`].
    Rate,
    /// `max_offset_ppm` zero or above [`MAX_OFFSET_LIMIT_PPM`].
    Offset,
    /// `glitch_window_ticks` zero or not below a quarter of a second.
    Window,
    /// `holdover_s` zero or above one day.
    Holdover,
}

impl DisciplineConfig {
    /// The defaults for a timer at nominally `timer_hz`: 50 Hz, PPS mode, +-500 ppm
    /// ([`HSE_CRYSTAL_TOLERANCE_PPM`]: a crystal), a 50 us glitch window (in nominal ticks),
    /// 10 s of holdover. For another clock use [`DisciplineConfig::for_clock`].
    pub const fn new(timer_hz: u32) -> Self {
        Self::for_clock(timer_hz, HSE_CRYSTAL_TOLERANCE_PPM)
    }

    /// The defaults of [`DisciplineConfig::new`] for a timer whose real frequency is within
    /// `tolerance_ppm` of `timer_hz`: [`HSE_CRYSTAL_TOLERANCE_PPM`] for a crystal,
    /// [`HSI_TOLERANCE_PPM`] for the internal RC oscillator. It becomes `max_offset_ppm`
    /// (validated: at most [`MAX_OFFSET_LIMIT_PPM`]).
    pub const fn for_clock(timer_hz: u32, tolerance_ppm: u32) -> Self {
        Self {
            timer_hz,
            rate_hz: 50,
            mode: SyncMode::Pps,
            max_offset_ppm: tolerance_ppm,
            glitch_window_ticks: timer_hz / 20_000,
            holdover_s: 10,
        }
    }

    /// Checks the ranges documented on each field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.timer_hz < 1_000 {
            return Err(ConfigError::TimerHz);
        }
        if !RATE_RANGE.contains(&self.rate_hz) {
            return Err(ConfigError::Rate);
        }
        if self.max_offset_ppm == 0 || self.max_offset_ppm > MAX_OFFSET_LIMIT_PPM {
            return Err(ConfigError::Offset);
        }
        if self.glitch_window_ticks == 0 || self.glitch_window_ticks >= self.timer_hz / 4 {
            return Err(ConfigError::Window);
        }
        if self.holdover_s == 0 || self.holdover_s > 86_400 {
            return Err(ConfigError::Holdover);
        }
        Ok(())
    }

    /// Largest accepted deviation of a measured period from nominal, ticks.
    fn max_offset_ticks(&self) -> u64 {
        u64::from(self.timer_hz) * u64::from(self.max_offset_ppm) / 1_000_000
    }

    /// Whether acquisition needs a third edge to confirm the period (wide tolerance).
    fn lock_needs_confirmation(&self) -> bool {
        self.max_offset_ppm > DIRECT_LOCK_MAX_PPM
    }
}

/// One scheduled sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sample {
    /// Timer tick at which the sample is taken.
    pub tick: u64,
    /// Label of the second it belongs to (the PPS edge's label when locked).
    pub second: u32,
    /// Index of the sample in its second, `0..rate`.
    pub index: u32,
    /// Samples per second of that second.
    pub rate: u32,
    /// Schedule state when it was committed.
    pub state: SyncState,
}

/// What one PPS edge did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PpsEvent {
    /// `mode = free`: edges are not used.
    Ignored,
    /// Free-running: kept as a candidate, waiting for the edge(s) one second later that
    /// lock (see the module documentation, *Acquisition*).
    Candidate,
    /// Lock acquired from free-running; the edge starts second `second`.
    Locked {
        /// Label of the second the edge starts.
        second: u32,
    },
    /// Locked and the edge came within the window of its prediction.
    Accepted {
        /// Label of the second the edge starts.
        second: u32,
        /// Edge minus its predicted time, ticks.
        phase_error: i64,
    },
    /// Holdover ended: the edge came within the window after `missed` lost seconds.
    Reacquired {
        /// Label of the second the edge starts.
        second: u32,
        /// Edge minus its predicted time, ticks.
        phase_error: i64,
        /// Seconds without an edge before this one.
        missed: u32,
    },
    /// Rejected as a glitch (counted).
    Glitch,
}

/// Counters of the discipline since start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PpsStats {
    /// Edges accepted (locked, accepted, reacquired).
    pub accepted: u32,
    /// Edges rejected as glitches.
    pub glitches: u32,
    /// Seconds whose edge never came while locked or in holdover.
    pub missed: u32,
    /// Times the schedule went from free-running to locked.
    pub locks: u32,
    /// Grid points skipped to keep samples at least half a sample period apart (at lock).
    pub skipped: u32,
}

/// The PPS discipline and sample scheduler (see the module documentation).
#[derive(Debug, Clone)]
pub struct Discipline {
    cfg: DisciplineConfig,
    state: SyncState,
    /// Anchor of the grid: tick at which second `anchor_second` starts.
    anchor: u64,
    anchor_second: u32,
    /// Length of a second in use, ticks.
    period: u64,
    /// Rate of the second the cursor is in.
    rate: u32,
    /// The next sample to commit.
    cursor_second: u32,
    cursor_index: u32,
    /// Tick and rate of the last committed sample.
    last_tick: Option<(u64, u32)>,
    /// Last accepted edge: tick and label.
    last_edge: Option<(u64, u32)>,
    /// Seconds lost since `last_edge` (holdover).
    missed: u32,
    /// Free-running in PPS mode: the last edge not yet part of a lock.
    candidate: Option<u64>,
    /// Free-running in PPS mode, wide tolerance: the interval ending at `candidate` when it
    /// was within tolerance (the period a third edge must confirm).
    candidate_period: Option<u64>,
    stats: PpsStats,
}

impl Discipline {
    /// A schedule that starts free-running with its first second at tick `start`.
    pub fn new(cfg: DisciplineConfig, start: u64) -> Result<Self, ConfigError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            state: SyncState::FreeRunning,
            anchor: start,
            anchor_second: 0,
            period: u64::from(cfg.timer_hz),
            rate: cfg.rate_hz,
            cursor_second: 0,
            cursor_index: 0,
            last_tick: None,
            last_edge: None,
            missed: 0,
            candidate: None,
            candidate_period: None,
            stats: PpsStats::default(),
        })
    }

    /// The configuration in use (a new rate applies from the next second that begins).
    pub fn config(&self) -> &DisciplineConfig {
        &self.cfg
    }

    /// Changes the configuration. A mode change applies at once (to `free`: free-running;
    /// to `pps`: acquisition starts from free-running); a rate change at the first second
    /// that begins after it ([`Discipline::begin_second`]).
    pub fn set_config(&mut self, cfg: DisciplineConfig) -> Result<(), ConfigError> {
        cfg.validate()?;
        let mode_changed = cfg.mode != self.cfg.mode || cfg.timer_hz != self.cfg.timer_hz;
        self.cfg = cfg;
        if mode_changed {
            self.free_run(u64::from(cfg.timer_hz));
        }
        Ok(())
    }

    /// State of the schedule.
    pub fn state(&self) -> SyncState {
        self.state
    }

    /// Length of a second in use, ticks (the measured PPS period when locked or in holdover).
    pub fn period(&self) -> u64 {
        self.period
    }

    /// Counters since start.
    pub fn stats(&self) -> PpsStats {
        self.stats
    }

    /// The last accepted PPS edge: tick and second label.
    pub fn last_edge(&self) -> Option<(u64, u32)> {
        self.last_edge
    }

    /// Start tick of second `second` on the current grid.
    fn second_start(&self, second: u32) -> u64 {
        let d = i64::from(second.wrapping_sub(self.anchor_second) as i32);
        (self.anchor as i64 + d * self.period as i64) as u64
    }

    /// Moves the cursor past a second whose samples are all committed, and gives a second
    /// none of whose samples is committed the configured rate.
    fn advance_cursor(&mut self) {
        if self.cursor_index >= self.rate {
            self.cursor_index = 0;
            self.cursor_second = self.cursor_second.wrapping_add(1);
        }
        if self.cursor_index == 0 {
            self.rate = self.cfg.rate_hz;
        }
    }

    /// The rate of a second is open until a sample after its first is committed: the first
    /// sample's tick (the second's start) does not depend on it. Called at the instant of
    /// `first`, the last committed sample, before the next commit: if `first` begins its
    /// second, that second takes the rate configured now ([`Discipline::set_config`] may
    /// have changed it since `first` was committed), and `first` is returned with it. Any
    /// other sample is returned as it is. So a rate set before the first sample of a second
    /// is taken applies from that sample on.
    pub fn begin_second(&mut self, first: Sample) -> Sample {
        let open = first.index == 0
            && first.second == self.cursor_second
            && self.cursor_index == 1
            && self.last_tick.is_some_and(|(t, _)| t == first.tick);
        if !open {
            return first;
        }
        self.rate = self.cfg.rate_hz;
        self.last_tick = Some((first.tick, self.rate));
        Sample {
            rate: self.rate,
            ..first
        }
    }

    /// Re-anchors the grid at the start of the cursor's second and changes the period
    /// from there, so committed samples stay where they are.
    fn change_period(&mut self, period: u64) {
        self.advance_cursor();
        self.anchor = self.second_start(self.cursor_second);
        self.anchor_second = self.cursor_second;
        self.period = period;
    }

    /// Falls back to free-running with `period`, forgetting all edges.
    fn free_run(&mut self, period: u64) {
        self.change_period(period);
        self.state = SyncState::FreeRunning;
        self.last_edge = None;
        self.candidate = None;
        self.candidate_period = None;
        self.missed = 0;
    }

    /// Declares lost the edges whose window has passed by `now`.
    fn check_deadline(&mut self, now: u64) {
        let Some((edge, _)) = self.last_edge else {
            return;
        };
        if self.state == SyncState::FreeRunning {
            return;
        }
        let window = u64::from(self.cfg.glitch_window_ticks);
        while now > edge + u64::from(self.missed + 1) * self.period + window {
            self.missed += 1;
            self.stats.missed += 1;
            if self.missed > self.cfg.holdover_s {
                // The last measured period is the best estimate of the clock there is.
                self.free_run(self.period);
                return;
            }
            self.state = SyncState::Holdover;
        }
    }

    /// Commits the next sample. `now` is the current tick (the driver's view of time; it
    /// must not decrease), used to notice lost PPS edges. Grid points closer than half a
    /// sample period (of this sample and the previous one: they differ at a rate change) after the
    /// previous committed sample are skipped (only ever at lock).
    pub fn next_sample(&mut self, now: u64) -> Sample {
        self.check_deadline(now);
        loop {
            self.advance_cursor();
            let second = self.cursor_second;
            let index = self.cursor_index;
            let rate = self.rate;
            let tick = self.second_start(second) + u64::from(index) * self.period / u64::from(rate);
            self.cursor_index += 1;
            // Half the shorter of the two sample periods (the rates differ at a rate change).
            let fastest = self.last_tick.map_or(rate, |(_, r)| r.max(rate));
            let min_gap = self.period / (2 * u64::from(fastest));
            match self.last_tick {
                Some((last, _)) if tick < last + min_gap => {
                    self.stats.skipped += 1;
                    continue;
                }
                _ => {}
            }
            self.last_tick = Some((tick, rate));
            return Sample {
                tick,
                second,
                index,
                rate,
                state: self.state,
            };
        }
    }

    /// Moves the cursor, without committing, to the latest grid point at or before `now`
    /// (after noticing lost edges as [`Discipline::next_sample`] does), so that the next
    /// [`Discipline::next_sample`] commits it; returns the grid points passed over. A few
    /// integer operations per grid second crossed, whatever the rate: what [`catch_up`]
    /// does after a stall instead of committing every point of it.
    ///
    /// [`catch_up`]: super::clock::catch_up
    pub fn skip_to(&mut self, now: u64) -> u32 {
        self.check_deadline(now);
        let mut skipped: u32 = 0;
        loop {
            self.advance_cursor();
            let start = self.second_start(self.cursor_second);
            if now < start {
                return skipped;
            }
            let rate = u64::from(self.rate);
            if self.second_start(self.cursor_second.wrapping_add(1)) <= now {
                // The rest of this second and the start of the next one have passed.
                skipped = skipped.saturating_add(self.rate - self.cursor_index);
                self.cursor_index = self.rate;
                continue;
            }
            // The latest k with floor(k * period / rate) <= now - start.
            let k = (((now - start + 1) * rate - 1) / self.period).min(rate - 1) as u32;
            if k > self.cursor_index {
                skipped = skipped.saturating_add(k - self.cursor_index);
                self.cursor_index = k;
            }
            return skipped;
        }
    }

    /// Feeds one PPS capture timestamp (ticks, on the same timeline as the samples).
    pub fn on_pps(&mut self, edge: u64) -> PpsEvent {
        if self.cfg.mode == SyncMode::Free {
            return PpsEvent::Ignored;
        }
        let nominal = u64::from(self.cfg.timer_hz);
        let max_offset = self.cfg.max_offset_ticks();
        let window = u64::from(self.cfg.glitch_window_ticks);
        match (self.state, self.last_edge) {
            (SyncState::FreeRunning, _) | (_, None) => {
                let Some(candidate) = self.candidate.replace(edge) else {
                    return PpsEvent::Candidate;
                };
                let interval = edge.wrapping_sub(candidate);
                if edge <= candidate || interval.abs_diff(nominal) > max_offset + window {
                    self.candidate_period = None;
                    return PpsEvent::Candidate;
                }
                if self.cfg.lock_needs_confirmation() {
                    // The edge must fall within the window of the candidate's prediction.
                    let confirmed = self
                        .candidate_period
                        .is_some_and(|p| interval.abs_diff(p) <= window);
                    if !confirmed {
                        self.candidate_period = Some(interval);
                        return PpsEvent::Candidate;
                    }
                }
                // Lock: the edge starts a new second after the ones already committed.
                let second = if self.cursor_index == 0 {
                    self.cursor_second
                } else {
                    self.cursor_second.wrapping_add(1)
                };
                self.cursor_second = second;
                self.cursor_index = 0;
                self.rate = self.cfg.rate_hz;
                self.anchor = edge;
                self.anchor_second = second;
                self.period = interval;
                self.last_edge = Some((edge, second));
                self.candidate = None;
                self.candidate_period = None;
                self.missed = 0;
                self.state = SyncState::Locked;
                self.stats.accepted += 1;
                self.stats.locks += 1;
                PpsEvent::Locked { second }
            }
            (_, Some((last, last_second))) => {
                if edge <= last {
                    self.stats.glitches += 1;
                    return PpsEvent::Glitch;
                }
                let elapsed = edge - last;
                // Whole seconds since the last edge, rounded to nearest.
                let n = (elapsed + self.period / 2) / self.period;
                if n == 0 || n > u64::from(self.cfg.holdover_s) + 1 {
                    self.stats.glitches += 1;
                    return PpsEvent::Glitch;
                }
                let predicted = last + n * self.period;
                let phase_error = edge as i64 - predicted as i64;
                let measured = (elapsed + n / 2) / n;
                if phase_error.unsigned_abs() > window || measured.abs_diff(nominal) > max_offset {
                    self.stats.glitches += 1;
                    return PpsEvent::Glitch;
                }
                let second = last_second.wrapping_add(n as u32);
                let missed = n as u32 - 1;
                if missed > self.missed {
                    self.stats.missed += missed - self.missed;
                }
                self.anchor = edge;
                self.anchor_second = second;
                self.period = measured;
                self.last_edge = Some((edge, second));
                self.missed = 0;
                self.stats.accepted += 1;
                if self.state == SyncState::Holdover || missed > 0 {
                    self.state = SyncState::Locked;
                    PpsEvent::Reacquired {
                        second,
                        phase_error,
                        missed,
                    }
                } else {
                    PpsEvent::Accepted {
                        second,
                        phase_error,
                    }
                }
            }
        }
    }
}

/// Timestamp of an input capture on a timer that restarts from 0 at every sample (update
/// event), as the board's sample timer does.
///
/// `period_start` is the tick of the update event the software has processed last and
/// `period_len` the length of that period (ARR + 1); `ccr` is the captured counter value and
/// `update_pending` tells whether the next update event's flag was already set when the
/// capture was read. In that case a small `ccr` (below half the period) was captured after
/// the counter restarted, so it belongs to the next period.
pub fn resolve_capture(period_start: u64, period_len: u64, ccr: u32, update_pending: bool) -> u64 {
    let ccr = u64::from(ccr);
    if update_pending && ccr < period_len / 2 {
        period_start + period_len + ccr
    } else {
        period_start + ccr
    }
}
