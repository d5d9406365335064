//! The text of the `status` command.

use super::{Live, RxErrors};
use crate::bytes::Text;
use crate::console::Reply;
use crate::decimal::Dec;
use crate::mavlink::RxCounts;
use crate::protocol::ResetCause;
use crate::settings::SettingsSource;
use crate::timing::{ClockSource, SyncState};

/// What only the board knows for `status`.
#[derive(Debug, Clone, Copy)]
pub struct BoardReport {
    /// The clock running now.
    pub clock: ClockSource,
    /// Most stack used since start, and the stack's size, bytes.
    pub stack: (usize, usize),
    /// Unit of the cycle counts: `cycles` on the board, `instructions (QEMU)` in QEMU.
    pub cycles_unit: &'static str,
    /// Why the unit last started.
    pub reset_cause: ResetCause,
}

/// Everything `status` reports.
pub(crate) struct StatusInputs<'a> {
    pub live: &'a Live,
    pub host: &'a RxErrors,
    pub gnss: &'a RxErrors,
    pub board: &'a BoardReport,
    pub mavlink_rx: RxCounts,
    pub timer_hz: u32,
    pub source: SettingsSource,
    pub dirty: bool,
}

/// Appends the `status` lines to `reply`.
pub(crate) fn write(reply: &mut Reply, s: &StatusInputs<'_>) {
    let live = s.live;
    let sync = match live.flags.sync {
        SyncState::FreeRunning => "free",
        SyncState::Locked => "locked",
        SyncState::Holdover => "holdover",
    };
    let on = |b: bool| Text(if b { "yes" } else { "no" });
    let clock = match s.board.clock {
        ClockSource::Hse => "hse",
        ClockSource::Hsi => "hsi",
        ClockSource::HsiFallback => "hsi-fallback (HSE failed)",
    };
    reply.push_line(format_args!("clock = {}", Text(clock)));
    reply.push_line(format_args!(
        "reset_cause = {}",
        Text(s.board.reset_cause.name())
    ));
    reply.push_line(format_args!("sync = {}", Text(sync)));
    reply.push_line(format_args!("time_valid = {}", on(live.flags.time_valid)));
    let dec = |v: u32| Dec(u64::from(v));
    reply.push_line(format_args!("samples = {}", dec(live.samples)));
    reply.push_line(format_args!("mcu_time_us = {}", Dec(live.mcu_time_us)));
    reply.push_line(format_args!(
        "rate = {} Hz, output_divider = {}",
        dec(live.rate),
        dec(live.output_divider)
    ));
    reply.push_line(format_args!(
        "records_dropped = {}",
        dec(live.dropped_total)
    ));
    reply.push_line(format_args!(
        "samples_lost = {}, merged_samples = {}",
        dec(live.samples_lost),
        dec(live.merged_samples)
    ));
    let latency_ns = Dec(u64::from(live.latency_max) * 1_000_000_000 / u64::from(s.timer_hz));
    reply.push_line(format_args!(
        "sample_latency_max = {latency_ns} ns, late_samples = {}",
        dec(live.late_samples)
    ));
    reply.push_line(format_args!("second_ticks = {}", Dec(live.period)));
    reply.push_line(format_args!(
        "pps_accepted = {}, pps_glitches = {}, pps_missed = {}, pps_locks = {}, pps_overcaptures = {}",
        dec(live.stats.accepted),
        dec(live.stats.glitches),
        dec(live.stats.missed),
        dec(live.stats.locks),
        dec(live.pps_overcaptures)
    ));
    reply.push_line(format_args!(
        "nmea_time_messages = {}, nmea_errors = {}",
        dec(live.time_messages),
        dec(live.nmea_errors)
    ));
    reply.push_line(format_args!(
        "gnss_forwarded = {}, gnss_not_forwarded = {}, gnss_bad_checksum = {}, gnss_overlong = {}",
        dec(live.gnss.forwarded),
        dec(live.gnss.not_forwarded),
        dec(live.gnss.bad_checksum),
        dec(live.gnss.overlong)
    ));
    for (name, e) in [(Text("gnss"), s.gnss), (Text("host"), s.host)] {
        reply.push_line(format_args!(
            "{name}_rx_lost = {}, {name}_rx_overruns = {}, {name}_rx_framing = {}, {name}_rx_noise = {}, {name}_rx_parity = {}",
            dec(e.lost), dec(e.overruns), dec(e.framing), dec(e.noise), dec(e.parity)
        ));
    }
    reply.push_line(format_args!(
        "host_rx_mavlink_ignored = {}, host_rx_mavlink1_ignored = {}",
        dec(s.mavlink_rx.v2),
        dec(s.mavlink_rx.v1)
    ));
    for (name, w, m, lost) in [
        (
            Text("left"),
            live.flags.left,
            live.index_mismatches[0],
            live.index_lost[0],
        ),
        (
            Text("right"),
            live.flags.right,
            live.index_mismatches[1],
            live.index_lost[1],
        ),
    ] {
        reply.push_line(format_args!(
            "{name}: fault = {}, index_seen = {}, index_mismatches = {}, index_lost = {}",
            on(w.fault),
            on(w.index_seen),
            dec(m),
            dec(lost)
        ));
    }
    let unit = Text(s.board.cycles_unit);
    reply.push_line(format_args!(
        "sample_isr_max = {} {unit}, process_max = {} {unit}",
        dec(live.isr_cycles_max),
        dec(live.process_cycles_max)
    ));
    reply.push_line(format_args!(
        "sample_isr_last = {} {unit}, process_last = {} {unit}",
        dec(live.isr_cycles_last),
        dec(live.process_cycles_last)
    ));
    let (used, size) = s.board.stack;
    reply.push_line(format_args!(
        "stack_used = {} of {} bytes",
        Dec(used as u64),
        Dec(size as u64)
    ));
    let source = match s.source {
        SettingsSource::Flash => "flash",
        SettingsSource::Defaults => "defaults",
    };
    reply.push_line(format_args!(
        "settings = {}, unsaved_changes = {}",
        Text(source),
        on(s.dirty)
    ));
}
