//! The command task's decisions: a command line from the host to a reply and to what the
//! other tasks must do (new settings, a pose reset), the settings saved to flash.

use super::discipline_config;
use crate::console::{self, Action, LineAssembler, Reply};
use crate::decimal::Dec;
use crate::mavlink::MavlinkRx;
use crate::odometry::Pose;
use crate::protocol::{DeviceInfo, ResetCause, PROTOCOL_VERSION};
use crate::settings::store::{Flash, SettingsStore};
use crate::settings::{Settings, SettingsSource};
use crate::timing::{ClockSource, DisciplineConfig};

/// The settings flash as the command task sees it: a [`Flash`] whose erase stalls the CPU.
pub trait StallingFlash: Flash {
    /// Longest CPU stall of one sector erase, milliseconds (0 when erasing does not stall).
    fn max_stall_ms(&self) -> u32;
}

/// What the other tasks must do after a command line (the reply aside).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Effect {
    /// Nothing.
    None,
    /// The working settings changed (see [`Commands::store_state`] for whether they now
    /// differ from the stored ones): the processing task takes `settings`, the sampler
    /// `discipline`.
    SettingsChanged {
        /// The new working settings.
        settings: Settings,
        /// The sampler's configuration for them.
        discipline: DisciplineConfig,
    },
    /// The settings were saved as record `generation`: they now come from flash and
    /// match it.
    Saved {
        /// Generation of the record written.
        generation: u32,
    },
    /// Saving failed (the reply says why); nothing changed.
    SaveFailed,
    /// Set the pose at the next sample.
    ResetPose(Pose),
    /// `status`: the caller fills the reply with [`Commands::status`].
    Status,
    /// `version`: the caller sends [`Commands::version`]'s device information.
    Version,
}

/// State of the command task.
pub struct Commands<F> {
    /// MAVLink frames received (a flight controller's) are skipped before the assembler.
    mavlink_rx: MavlinkRx,
    assembler: LineAssembler,
    settings: Settings,
    store: SettingsStore<F>,
    source: SettingsSource,
    /// The settings a reset would start with: the stored record's, or the defaults when
    /// none is stored.
    stored: Settings,
    timer_hz: u32,
    /// The clock source found at start.
    clock: ClockSource,
}

impl<F: StallingFlash> Commands<F> {
    /// Working on `settings` (from `source`, kept in `store`), the sample timer at
    /// `timer_hz` from the clock found at start, `clock`.
    pub fn new(
        settings: Settings,
        source: SettingsSource,
        store: SettingsStore<F>,
        timer_hz: u32,
        clock: ClockSource,
    ) -> Self {
        let stored = match source {
            SettingsSource::Flash => settings,
            SettingsSource::Defaults => Settings::DEFAULT,
        };
        Self {
            mavlink_rx: MavlinkRx::new(),
            assembler: LineAssembler::new(),
            settings,
            store,
            source,
            stored,
            timer_hz,
            clock,
        }
    }

    /// The settings loaded at start were `stored` (they differ from the working ones when
    /// start-up replaced them, `unit::Start::settings_replaced`).
    pub fn with_stored(mut self, stored: Settings) -> Self {
        self.stored = stored;
        self
    }

    /// The working settings differ from those the unit would start with after a reset
    /// (the stored record's, or the defaults when none is stored): `save` is pending.
    /// Compared as the stored bytes (and the DeviceInfo checksum), so `-0` differs from `0`.
    pub fn dirty(&self) -> bool {
        self.settings.to_bytes() != self.stored.to_bytes()
    }

    /// The working settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The settings store.
    pub fn store(&self) -> &SettingsStore<F> {
        &self.store
    }

    /// The clock source found at start.
    pub fn clock_at_start(&self) -> ClockSource {
        self.clock
    }

    /// Where the settings came from and whether they differ from the stored ones.
    pub fn store_state(&self) -> super::StoreState {
        super::StoreState {
            source: self.source,
            dirty: self.dirty(),
        }
    }

    /// One byte from the host: at the end of a line, its reply and effect. `clock` says
    /// which clock runs now; `moving` whether the wheels turned within the last second
    /// (asked only for a `save` that would erase a sector). Bytes of MAVLink frames are
    /// skipped and counted ([`MavlinkRx`]).
    #[inline(never)]
    pub fn on_byte(
        &mut self,
        byte: u8,
        clock: impl FnOnce() -> ClockSource,
        moving: impl FnOnce() -> bool,
    ) -> Option<(Reply, Effect)> {
        if !self.mavlink_rx.text(byte) {
            return None;
        }
        let (reply, action) = match self.assembler.push(byte)? {
            Ok(line) => console::execute(line, &mut self.settings),
            Err(e) => (Reply::error(e), Action::None),
        };
        Some(self.perform(reply, action, clock, moving))
    }

    fn perform(
        &mut self,
        mut reply: Reply,
        action: Action,
        clock: impl FnOnce() -> ClockSource,
        moving: impl FnOnce() -> bool,
    ) -> (Reply, Effect) {
        let effect = match action {
            Action::None => Effect::None,
            Action::SettingsChanged => Effect::SettingsChanged {
                settings: self.settings,
                discipline: discipline_config(&self.settings, self.timer_hz, clock()),
            },
            Action::Save
                if moving()
                    && !self
                        .settings
                        .survives_stall(self.store.flash().max_stall_ms())
                    && self.store.next_save_erases().unwrap_or(true) =>
            {
                reply = Reply::error(format_args!(
                    "save refused while the wheels turn: a flash erase stops the CPU for up to {} ms, longer than the right counter can go unread at max_wheel_speed; save at rest",
                    Dec(u64::from(self.store.flash().max_stall_ms()))
                ));
                Effect::None
            }
            Action::Save => match self.store.save(&self.settings) {
                Ok(generation) => {
                    self.stored = self.settings;
                    self.source = SettingsSource::Flash;
                    reply.push_line(format_args!(
                        "saved (generation {})",
                        Dec(u64::from(generation))
                    ));
                    Effect::Saved { generation }
                }
                Err(e) => {
                    reply = Reply::error(format_args!("save failed: {e}"));
                    Effect::SaveFailed
                }
            },
            Action::ResetPose { x, y, heading } => Effect::ResetPose(Pose { x, y, heading }),
            Action::Status => Effect::Status,
            Action::Version => Effect::Version,
        };
        (reply, effect)
    }

    /// `version`: the reply lines, and the device information frame for the unit with
    /// unique ID `uid`, last started by `reset_cause`.
    pub fn version(&self, reply: &mut Reply, uid: [u8; 12], reset_cause: ResetCause) -> DeviceInfo {
        reply.push_line(format_args!(concat!(
            "firmware = odo-unit ",
            env!("CARGO_PKG_VERSION")
        )));
        reply.push_line(format_args!(
            "protocol = {}",
            Dec(u64::from(PROTOCOL_VERSION))
        ));
        self.device_info(uid, reset_cause)
    }

    /// The device information frame (sent at start and after `version`) for the unit with
    /// unique ID `uid`, last started by `reset_cause`.
    pub fn device_info(&self, uid: [u8; 12], reset_cause: ResetCause) -> DeviceInfo {
        let mut info = DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            settings_source: self.source,
            reset_cause,
            settings_checksum: self.settings.checksum(),
            uid,
            firmware_version: heapless::String::new(),
        };
        let _ = info.firmware_version.push_str(env!("CARGO_PKG_VERSION"));
        info
    }

    /// `status`: the unit's counters (`live`, the host and receiver UARTs' errors) and the
    /// board's figures (`board`).
    pub fn status(
        &self,
        reply: &mut Reply,
        live: &super::Live,
        host: &super::RxErrors,
        gnss: &super::RxErrors,
        board: &super::BoardReport,
    ) {
        super::status::write(
            reply,
            &super::status::StatusInputs {
                live,
                host,
                gnss,
                board,
                mavlink_rx: self.mavlink_rx.counts(),
                timer_hz: self.timer_hz,
                source: self.source,
                dirty: self.dirty(),
            },
        );
    }
}
