//! Host tests of `odo_unit::unit`: what the firmware's tasks decide. The processing task's
//! records, drop, index-mismatch and motion accounting, heartbeats and settings
//! application; the command task's effects (settings changed, save refused while moving,
//! save, save failure, reset, status, version); start-up fallbacks; the PPS latch of the
//! sample interrupt; the host link's transmit ring and sequence numbers.

use odo_unit::console::Reply;
use odo_unit::odometry::Pose;
use odo_unit::protocol::{Queued, ResetCause, TxLink, TxRing};
use odo_unit::settings::store::{Flash, SettingsStore, SLOT_LEN};
use odo_unit::settings::{Settings, SettingsSource};
use odo_unit::timing::{
    ClockSource, PpsEvent, PpsStats, Sample, SyncMode, SyncState, TimeTagPps,
    HSE_CRYSTAL_TOLERANCE_PPM, HSI_TOLERANCE_PPM,
};
use odo_unit::unit::*;

const HZ: u32 = 84_000_000;
const BITS: [u32; 2] = [32, 16];

/// Events collected by a test.
#[derive(Default)]
struct Events(Vec<Event>);

impl Log for Events {
    fn event(&mut self, event: Event) {
        self.0.push(event);
    }
}

/// Sample `seq` of a free-running 50 Hz schedule with raw counts (left, right).
fn raw(seq: u32, left: u32, right: u32) -> RawSample {
    let rate = 50;
    let sample = Sample {
        tick: u64::from(seq) * u64::from(HZ / rate),
        second: seq / rate,
        index: seq % rate,
        rate,
        state: SyncState::FreeRunning,
    };
    let mut r = RawSample::first(
        sample,
        RawCounts { left, right },
        (false, false),
        &odo_unit::timing::Discipline::new(
            odo_unit::timing::DisciplineConfig::for_clock(HZ, HSI_TOLERANCE_PPM),
            0,
        )
        .unwrap(),
    );
    r.state = SyncState::FreeRunning;
    r.stats = PpsStats::default();
    r
}

fn processor() -> Processor {
    Processor::new(&Settings::DEFAULT, HZ, BITS)
}

/// Processes `r` and returns its record, `None` when it is skipped (panics when there is no
/// integrator).
fn record(
    p: &mut Processor,
    r: &RawSample,
    log: &mut Events,
) -> Option<odo_unit::protocol::PoseRecord> {
    match p.on_sample(r, log) {
        SampleOutcome::Record(rec) => Some(rec),
        SampleOutcome::Skipped => None,
        SampleOutcome::NoIntegrator => panic!("a sample is always integrated"),
    }
}

#[test]
fn first_sample_starts_the_counts_and_the_pose() {
    let mut p = processor();
    let mut log = Events::default();
    // Right counter 16 bits wide: 0xFFFF is -1.
    let rec = record(&mut p, &raw(0, 5, 0xFFFF), &mut log).unwrap();
    assert_eq!(rec.sequence, 0);
    assert_eq!((rec.gamma_left, rec.gamma_right), (5, -1));
    assert_eq!((rec.x, rec.y, rec.heading), (0.0, 0.0, 0.0));
    assert_eq!(rec.dropped, 0);
    assert_eq!(rec.flags.sync, SyncState::FreeRunning);
    assert!(!rec.flags.time_valid);
    assert!(log.0.is_empty(), "{:?}", log.0);
    // The right counter wraps: 0xFFFF -> 0x0010 is 17 increments forward.
    let rec = record(&mut p, &raw(1, 5, 0x0010), &mut log).unwrap();
    assert_eq!((rec.sequence, rec.gamma_left, rec.gamma_right), (1, 5, 16));
    assert!(
        rec.y != 0.0 || rec.x != 0.0 || rec.heading != 0.0,
        "right wheel moved"
    );
}

#[test]
fn mcu_time_is_the_sample_tick_in_microseconds() {
    let mut p = processor();
    let mut log = Events::default();
    let rec = record(&mut p, &raw(0, 0, 0), &mut log).unwrap();
    assert_eq!(rec.mcu_time_us, 0);
    let rec = record(&mut p, &raw(3, 0, 0), &mut log).unwrap();
    assert_eq!(rec.mcu_time_us, 60_000);
}

/// Heartbeat inputs with no errors and `store`.
fn inputs(store: StoreState) -> HeartbeatInputs {
    HeartbeatInputs {
        store,
        host: RxErrors::default(),
        gnss: RxErrors::default(),
        reset_cause: ResetCause::PowerOn,
    }
}

#[test]
fn dropped_records_are_counted_until_one_is_sent() {
    let mut p = processor();
    let mut log = Events::default();
    let r0 = record(&mut p, &raw(0, 0, 0), &mut log).unwrap();
    assert_eq!(r0.dropped, 0);
    p.sent(false);
    let r1 = record(&mut p, &raw(1, 0, 0), &mut log).unwrap();
    assert_eq!(r1.dropped, 1);
    p.sent(false);
    let r2 = record(&mut p, &raw(2, 0, 0), &mut log).unwrap();
    assert_eq!(r2.dropped, 2);
    p.sent(true);
    let r3 = record(&mut p, &raw(3, 0, 0), &mut log).unwrap();
    assert_eq!(r3.dropped, 0);
    let r = raw(3, 0, 0);
    assert_eq!(p.live(&r, 0).dropped_total, 2);
    let store = StoreState {
        source: SettingsSource::Defaults,
        dirty: false,
    };
    assert_eq!(p.heartbeat(&r, &inputs(store)).dropped_total, 2);
}

#[test]
fn output_divider_sends_every_nth_record() {
    let mut p = processor();
    let mut log = Events::default();
    let mut s = Settings::DEFAULT;
    s.output_divider = 3;
    p.apply(
        Requests {
            settings: Some(s),
            reset: None,
        },
        &mut log,
    );
    let sent: Vec<bool> = (0..7)
        .map(|k| record(&mut p, &raw(k, 0, 0), &mut log).is_some())
        .collect();
    assert_eq!(sent, [true, false, false, true, false, false, true]);
}

#[test]
fn index_pulses_mark_seen_and_mismatch_until_a_record_is_sent() {
    let mut p = processor();
    let mut log = Events::default();
    let capture = |raw| IndexCapture {
        raw,
        queue_lost: 0,
        overcapture: false,
    };
    // Before the first sample the counts are unknown: the pulse is ignored.
    p.on_index_capture(0, capture(7), &mut log);
    assert!(log.0.is_empty());
    let rec = record(&mut p, &raw(0, 0, 0), &mut log).unwrap();
    assert!(!rec.flags.left.index_seen);
    p.on_index_capture(0, capture(100), &mut log);
    assert_eq!(log.0, [Event::FirstIndex { wheel: 0 }]);
    let rec = record(&mut p, &raw(1, 200, 0), &mut log).unwrap();
    assert!(rec.flags.left.index_seen && !rec.flags.left.index_mismatch);
    assert_eq!(rec.index_left, 100);
    // One turn (20,000) plus 10 increments: beyond the tolerance of 4.
    p.on_index_capture(0, capture(100 + 20_010), &mut log);
    assert_eq!(
        log.0[1],
        Event::IndexMismatch {
            wheel: 0,
            error: 10
        }
    );
    let rec = record(&mut p, &raw(2, 20_200, 0), &mut log).unwrap();
    assert!(rec.flags.left.index_mismatch);
    assert!(!rec.flags.right.index_mismatch);
    p.sent(false);
    let rec = record(&mut p, &raw(3, 20_200, 0), &mut log).unwrap();
    assert!(rec.flags.left.index_mismatch, "kept until a record is sent");
    p.sent(true);
    let rec = record(&mut p, &raw(4, 20_200, 0), &mut log).unwrap();
    assert!(!rec.flags.left.index_mismatch);
    assert_eq!(p.live(&raw(4, 0, 0), 0).index_mismatches, [1, 0]);
    // A whole turn within the tolerance is no mismatch.
    p.on_index_capture(0, capture(100 + 40_012), &mut log);
    assert_eq!(log.0.len(), 2);
}

#[test]
fn overcaptured_index_pulses_are_counted_as_lost() {
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    p.on_index_capture(
        1,
        IndexCapture {
            raw: 50,
            overcapture: true,
            queue_lost: 0,
        },
        &mut log,
    );
    assert_eq!(
        log.0,
        [
            Event::IndexLost { wheel: 1 },
            Event::FirstIndex { wheel: 1 }
        ]
    );
    assert_eq!(p.live(&raw(0, 0, 0), 0).index_lost, [0, 1]);
}

#[test]
fn sample_index_pulses_are_applied_with_the_sample() {
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    let mut r = raw(1, 300, 300);
    r.index_pulses = [None, Some(250)];
    let rec = record(&mut p, &r, &mut log).unwrap();
    assert!(rec.flags.right.index_seen && !rec.flags.left.index_seen);
    assert_eq!(rec.index_right, 250);
    assert_eq!(log.0, [Event::FirstIndex { wheel: 1 }]);
}

#[test]
fn moving_means_a_wheel_moved_beyond_the_threshold_within_one_second() {
    let rate = Settings::DEFAULT.rate;
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    assert!(p.live(&raw(0, 0, 0), 0).moving);
    for k in 1..rate {
        record(&mut p, &raw(k, 0, 0), &mut log);
        assert!(p.live(&raw(k, 0, 0), 0).moving, "sample {k}");
    }
    record(&mut p, &raw(rate, 0, 0), &mut log);
    assert!(!p.live(&raw(rate, 0, 0), 0).moving, "a second at rest");
    // A wheel dithering on one edge of its code (+-1 count) at rest is not moving, ever.
    for k in rate + 1..5 * rate {
        let c = k % 2;
        record(&mut p, &raw(k, c, 0), &mut log);
        assert!(!p.live(&raw(k, c, 0), 0).moving, "dither at sample {k}");
    }
    // Beyond MOTION_THRESHOLD increments (8), it moves again; at the threshold it does not.
    let k = 5 * rate;
    record(&mut p, &raw(k, 0, 8), &mut log);
    assert!(!p.live(&raw(k, 0, 8), 0).moving, "8 increments");
    record(&mut p, &raw(k + 1, 0, 9), &mut log);
    assert!(p.live(&raw(k + 1, 0, 9), 0).moving, "moved again");
    assert_eq!(odo_unit::unit::processor::MOTION_THRESHOLD, 8);
}

#[test]
fn settings_dirty_means_different_from_the_stored_settings() {
    let mut c = commands(MemFlash::new(4, 0));
    assert!(!c.store_state().dirty, "defaults, nothing stored");
    line(&mut c, "set rate 60", false);
    assert!(c.store_state().dirty);
    line(&mut c, "set rate 50", false);
    assert!(!c.store_state().dirty, "back to what a reset starts with");
    line(&mut c, "set track_width 0.6", false);
    line(&mut c, "save", false);
    assert!(!c.store_state().dirty);
    line(&mut c, "defaults", false);
    assert!(c.store_state().dirty, "defaults differ from the stored 0.6");
    line(&mut c, "set track_width 0.6", false);
    assert!(!c.store_state().dirty, "equal to the stored record again");
    // Start-up replaced the stored settings: the working ones differ from the stored.
    let mut stored = Settings::DEFAULT;
    stored.rate = 7;
    let c = Commands::new(
        Settings::DEFAULT,
        SettingsSource::Flash,
        SettingsStore::new(MemFlash::new(4, 0)),
        HZ,
        ClockSource::Hse,
    )
    .with_stored(stored);
    assert!(c.store_state().dirty);
}

/// `set left_cos1 -0` from the defaults changes the stored bytes and the DeviceInfo
/// checksum: `unsaved_changes` says so too, and `set left_cos1 0` clears it again.
#[test]
fn negative_zero_is_an_unsaved_change() {
    let mut c = commands(MemFlash::new(4, 0));
    let clean = c
        .device_info([0; 12], ResetCause::Unknown)
        .settings_checksum;
    let (reply, effect) = line(&mut c, "set left_cos1 -0", false);
    assert!(reply.text.ends_with("left_cos1 = -0"), "{}", reply.text);
    assert!(
        matches!(effect, Effect::SettingsChanged { .. }),
        "{effect:?}"
    );
    let info = c.device_info([0; 12], ResetCause::Unknown);
    assert_ne!(info.settings_checksum, clean);
    assert!(c.store_state().dirty, "the bytes differ from the defaults'");
    line(&mut c, "set left_cos1 0", false);
    assert!(!c.store_state().dirty);
    // Saved as -0: +0 is then the unsaved change.
    line(&mut c, "set left_cos1 -0", false);
    line(&mut c, "save", false);
    assert!(!c.store_state().dirty);
    line(&mut c, "set left_cos1 0", false);
    assert!(c.store_state().dirty, "+0 differs from the stored -0");
}

#[test]
fn heartbeat_is_due_once_a_second_and_reports_the_counters() {
    let rate = Settings::DEFAULT.rate;
    let mut p = processor();
    let mut log = Events::default();
    let mut due = Vec::new();
    for k in 0..=rate {
        let mut r = raw(k, 0, 0);
        r.merged = u32::from(k == 7) * 3;
        r.latency = if k == 7 { 500 } else { 10 };
        record(&mut p, &r, &mut log);
        if p.heartbeat_due() {
            due.push(k);
            p.status_sent(true);
        }
    }
    assert_eq!(due, [0, rate]);
    assert_eq!(
        log.0,
        [Event::SampleLate {
            latency: 500,
            merged: 3
        }]
    );
    let mut r = raw(rate, 0, 0);
    r.queue_lost = 4;
    r.stats.accepted = 9;
    r.stats.glitches = 2;
    let store = StoreState {
        source: SettingsSource::Flash,
        dirty: true,
    };
    let mut hb = inputs(store);
    hb.host.lost = 11;
    hb.gnss.lost = 12;
    let s = p.heartbeat(&r, &hb);
    assert_eq!(s.samples, rate + 1);
    assert_eq!(s.rate_hz, rate);
    assert_eq!((s.pps_edges, s.pps_rejected), (9, 2));
    assert_eq!(
        (s.host_rx_lost, s.gnss_rx_lost, s.samples_lost),
        (11, 12, 4)
    );
    assert_eq!(
        (s.settings_source, s.settings_dirty),
        (SettingsSource::Flash, true)
    );
    assert_eq!(s.merged_samples, 3);
    let live = p.live(&r, 1234);
    assert_eq!((live.merged_samples, live.latency_max), (3, 500));
    assert_eq!(
        (live.process_cycles_last, live.process_cycles_max),
        (1234, 1234)
    );
}

#[test]
fn sync_state_changes_are_logged_and_flagged() {
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    let mut r = raw(1, 0, 0);
    r.state = SyncState::Locked;
    r.pps = Some((HZ as u64, PpsEvent::Locked { second: 1 }));
    let rec = record(&mut p, &r, &mut log).unwrap();
    assert_eq!(rec.flags.sync, SyncState::Locked);
    assert!(!rec.flags.time_valid, "no GNSS time message yet");
    assert_eq!(
        log.0,
        [
            Event::PpsLocked,
            Event::SyncChanged {
                from: SyncState::FreeRunning,
                to: SyncState::Locked
            }
        ]
    );
    let mut r = raw(2, 0, 0);
    r.state = SyncState::Holdover;
    r.pps = Some((2 * HZ as u64, PpsEvent::Glitch));
    r.pps_overcapture = true;
    r.faults = (true, false);
    let rec = record(&mut p, &r, &mut log).unwrap();
    assert_eq!(rec.flags.sync, SyncState::Holdover);
    assert!(rec.flags.left.fault && !rec.flags.right.fault);
    assert_eq!(
        log.0[2..],
        [
            Event::PpsOvercapture,
            Event::PpsGlitch,
            Event::SyncChanged {
                from: SyncState::Locked,
                to: SyncState::Holdover
            },
            Event::FaultLines {
                left: true,
                right: false
            }
        ]
    );
    assert_eq!(p.live(&r, 0).pps_overcaptures, 1);
}

#[test]
fn bad_nmea_sentences_are_counted() {
    let mut p = processor();
    for b in b"$GPZDA,120000.00,01,01,2024,00,00*00\r\n" {
        p.on_nmea_byte(*b, None);
    }
    let live = p.live(&raw(0, 0, 0), 0);
    assert_eq!((live.nmea_errors, live.time_messages), (1, 0));
}

#[test]
fn settings_and_pose_reset_apply_at_the_next_sample() {
    let mut p = processor();
    let mut log = Events::default();
    // A reset before the first sample becomes the starting pose.
    let start = Pose {
        x: 1.0,
        y: 2.0,
        heading: 0.5,
    };
    p.apply(
        Requests {
            settings: None,
            reset: Some(start),
        },
        &mut log,
    );
    let rec = record(&mut p, &raw(0, 0, 0), &mut log).unwrap();
    assert_eq!((rec.x, rec.y, rec.heading), (1.0, 2.0, 0.5));
    // Move, then reset: the pose is the requested one, the counts go on.
    let rec = record(&mut p, &raw(1, 1000, 1000), &mut log).unwrap();
    assert!(rec.y > 2.0);
    p.apply(
        Requests {
            settings: None,
            reset: Some(Pose::default()),
        },
        &mut log,
    );
    let rec = record(&mut p, &raw(2, 2000, 2000), &mut log).unwrap();
    assert_eq!((rec.x, rec.y, rec.heading), (0.0, 0.0, 0.0));
    assert_eq!((rec.gamma_left, rec.gamma_right), (2000, 2000));
    assert_eq!(log.0, [Event::PoseReset]);
    // New ticks_per_rev: the index check follows it.
    let mut s = Settings::DEFAULT;
    s.chassis.ticks_per_rev = 10_000;
    p.apply(
        Requests {
            settings: Some(s),
            reset: None,
        },
        &mut log,
    );
    record(&mut p, &raw(3, 2000, 2000), &mut log);
    let c = |raw| IndexCapture {
        raw,
        queue_lost: 0,
        overcapture: false,
    };
    p.on_index_capture(0, c(2000), &mut log);
    p.on_index_capture(0, c(12_000), &mut log);
    assert_eq!(log.0[1..], [Event::FirstIndex { wheel: 0 }]);
}

#[test]
fn motion_beyond_a_sample_is_not_integrated() {
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    let rec = record(&mut p, &raw(1, 1 << 30, 0), &mut log).unwrap();
    assert_eq!(log.0, [Event::Overrange { sequence: 1 }]);
    assert_eq!((rec.x, rec.y, rec.heading), (0.0, 0.0, 0.0));
}

// ---------------------------------------------------------------- start-up

#[test]
fn discipline_config_follows_settings_and_clock() {
    let s = Settings::DEFAULT;
    let cfg = discipline_config(&s, HZ, ClockSource::Hse);
    assert_eq!(cfg.rate_hz, s.rate);
    assert_eq!(cfg.max_offset_ppm, HSE_CRYSTAL_TOLERANCE_PPM);
    let cfg = discipline_config(&s, HZ, ClockSource::HsiFallback);
    assert_eq!(cfg.max_offset_ppm, HSI_TOLERANCE_PPM);
    let mut changed = s;
    for (line, mode) in [("mode pps", SyncMode::Pps), ("mode free", SyncMode::Free)] {
        let (_, action) = odo_unit::console::execute(line, &mut changed);
        assert_eq!(action, odo_unit::console::Action::SettingsChanged, "{line}");
        assert_eq!(discipline_config(&changed, HZ, ClockSource::Hsi).mode, mode);
    }
    for (value, tag) in [
        ("next", TimeTagPps::Next),
        ("previous", TimeTagPps::Previous),
    ] {
        let line = format!("set time_tag_pps {value}");
        let (reply, _) = odo_unit::console::execute(&line, &mut changed);
        assert!(reply.ok, "{}", reply.text);
        assert_eq!(time_tag(&changed), tag);
    }
}

#[test]
fn start_replaces_unusable_settings_and_falls_back_to_free_running() {
    let ok = start(Settings::DEFAULT, HZ, ClockSource::Hse, ClockSource::Hse).unwrap();
    assert!(!ok.settings_replaced && !ok.sampler_fallback);
    assert_eq!(ok.discipline.config().rate_hz, Settings::DEFAULT.rate);
    let mut bad = Settings::DEFAULT;
    bad.rate = 0;
    let s = start(bad, HZ, ClockSource::Hse, ClockSource::Hse).unwrap();
    assert!(s.settings_replaced);
    assert_eq!(s.settings, Settings::DEFAULT);
    // A timer too slow for any configuration.
    assert!(start(Settings::DEFAULT, 10, ClockSource::Hse, ClockSource::Hse).is_err());
}

// ---------------------------------------------------------------- sample interrupt

#[test]
fn pps_latch_keeps_an_accepted_edge_over_a_later_glitch() {
    let mut l = PpsLatch::new();
    assert_eq!(l.take(), (None, false));
    let accepted = (
        100,
        PpsEvent::Accepted {
            second: 3,
            phase_error: 0,
        },
    );
    l.on_interrupt(Some(accepted), false);
    l.on_interrupt(Some((150, PpsEvent::Glitch)), true);
    l.on_interrupt(None, false);
    assert_eq!(l.take(), (Some(accepted), true));
    assert_eq!(l.take(), (None, false), "take clears");
    // A glitch is replaced by a later accepted edge, and kept when alone.
    l.on_interrupt(Some((150, PpsEvent::Glitch)), false);
    assert_eq!(l.take().0, Some((150, PpsEvent::Glitch)));
    l.on_interrupt(Some((150, PpsEvent::Glitch)), false);
    l.on_interrupt(Some(accepted), false);
    assert_eq!(l.take().0, Some(accepted));
}

// ---------------------------------------------------------------- host link

#[test]
fn tx_ring_takes_whole_frames_and_wraps() {
    let mut r = TxRing::<8>::new();
    assert!(r.is_empty() && r.free() == 8);
    assert!(r.push_frame(&[1, 2, 3, 4, 5], 0));
    assert!(
        !r.push_frame(&[6, 7, 8, 9], 0),
        "does not fit: nothing written"
    );
    assert!(!r.push_frame(&[6, 7], 2), "fits only without the reserve");
    assert_eq!(r.free(), 3);
    assert_eq!(
        (0..4).map(|_| r.pop().unwrap()).collect::<Vec<_>>(),
        [1, 2, 3, 4]
    );
    // Across the end of the buffer.
    assert!(r.push_frame(&[6, 7, 8, 9, 10, 11], 0));
    let out: Vec<u8> = std::iter::from_fn(|| r.pop()).collect();
    assert_eq!(out, [5, 6, 7, 8, 9, 10, 11]);
    assert!(r.is_empty() && r.pop().is_none());
}

#[test]
fn tx_link_numbers_frames_in_queue_order() {
    let mut l = TxLink::<8>::new();
    assert_eq!(l.next_seq(), 0);
    assert_eq!(l.queue(0, &[1, 2, 3], 0), Queued::Queued);
    assert_eq!(l.next_seq(), 1);
    assert_eq!(
        l.queue(0, &[4], 0),
        Queued::Stale,
        "encoded with a used number"
    );
    assert_eq!(l.queue(1, &[4, 5, 6, 7, 8, 9], 0), Queued::NoRoom);
    assert_eq!(l.next_seq(), 1, "unchanged when nothing was queued");
    assert_eq!(l.queue(1, &[4, 5], 3), Queued::Queued);
    assert_eq!(l.ring().pop(), Some(1));
}

// ---------------------------------------------------------------- command task

/// Settings sectors in memory with a chosen erase stall and an optional program failure.
struct MemFlash {
    mem: [Vec<u8>; 2],
    stall_ms: u32,
    fail_program: bool,
}

impl MemFlash {
    fn new(slots: usize, stall_ms: u32) -> Self {
        Self {
            mem: [vec![0xFF; slots * SLOT_LEN], vec![0xFF; slots * SLOT_LEN]],
            stall_ms,
            fail_program: false,
        }
    }
}

impl Flash for MemFlash {
    type Error = &'static str;
    fn sector_size(&self) -> usize {
        self.mem[0].len()
    }
    fn erase(&mut self, sector: usize) -> Result<(), Self::Error> {
        self.mem[sector].fill(0xFF);
        Ok(())
    }
    fn program(&mut self, sector: usize, offset: usize, data: &[u8]) -> Result<(), Self::Error> {
        if self.fail_program {
            return Err("program failed");
        }
        for (m, d) in self.mem[sector][offset..offset + data.len()]
            .iter_mut()
            .zip(data)
        {
            *m &= *d;
        }
        Ok(())
    }
    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), Self::Error> {
        buf.copy_from_slice(&self.mem[sector][offset..offset + buf.len()]);
        Ok(())
    }
}

impl StallingFlash for MemFlash {
    fn max_stall_ms(&self) -> u32 {
        self.stall_ms
    }
}

fn commands(flash: MemFlash) -> Commands<MemFlash> {
    Commands::new(
        Settings::DEFAULT,
        SettingsSource::Defaults,
        SettingsStore::new(flash),
        HZ,
        ClockSource::Hse,
    )
}

/// Sends `line` and its terminator; the reply and effect of the line.
fn line(c: &mut Commands<MemFlash>, text: &str, moving: bool) -> (Reply, Effect) {
    let mut out = None;
    for b in text.bytes().chain([b'\n']) {
        let r = c.on_byte(b, || ClockSource::HsiFallback, || moving);
        assert!(out.is_none() || r.is_none(), "one reply per line");
        out = out.or(r);
    }
    out.expect("a reply at the end of the line")
}

#[test]
fn set_changes_the_working_settings_and_the_sampler() {
    let mut c = commands(MemFlash::new(4, 0));
    let (reply, effect) = line(&mut c, "set track_width 0.6 rate 25", false);
    assert!(reply.ok, "{}", reply.text);
    let Effect::SettingsChanged {
        settings,
        discipline,
    } = effect
    else {
        panic!("{effect:?}")
    };
    assert_eq!(settings.chassis.track_width, 0.6);
    assert_eq!(&settings, c.settings());
    assert_eq!(discipline.rate_hz, 25);
    // The clock running now sets the lock range (the closure's HSI fallback).
    assert_eq!(discipline.max_offset_ppm, HSI_TOLERANCE_PPM);
    assert_eq!(
        c.store_state(),
        StoreState {
            source: SettingsSource::Defaults,
            dirty: true
        }
    );
    // A rejected value changes nothing.
    let (reply, effect) = line(&mut c, "set track_width -1", false);
    assert!(!reply.ok);
    assert_eq!(effect, Effect::None);
    assert_eq!(c.settings().chassis.track_width, 0.6);
}

#[test]
fn save_stores_the_settings_and_marks_them_clean() {
    let mut c = commands(MemFlash::new(4, 0));
    line(&mut c, "set track_width 0.61", false);
    let (reply, effect) = line(&mut c, "save", true);
    assert!(reply.ok, "{}", reply.text);
    assert!(
        reply.text.contains("saved (generation 1)"),
        "{}",
        reply.text
    );
    assert_eq!(effect, Effect::Saved { generation: 1 });
    assert_eq!(
        c.store_state(),
        StoreState {
            source: SettingsSource::Flash,
            dirty: false
        }
    );
    let mut store = commands_store(c);
    let loaded = store.load_or_defaults();
    assert_eq!(loaded.source, SettingsSource::Flash);
    assert_eq!(loaded.settings.chassis.track_width, 0.61);
}

/// The store of a command task (its flash, by value).
fn commands_store(c: Commands<MemFlash>) -> SettingsStore<MemFlash> {
    let flash = MemFlash {
        mem: [
            c.store().flash().mem[0].clone(),
            c.store().flash().mem[1].clone(),
        ],
        stall_ms: 0,
        fail_program: false,
    };
    SettingsStore::new(flash)
}

#[test]
fn save_is_refused_while_moving_only_when_an_erase_would_stall_too_long() {
    // Sectors of one slot: the second save erases the other sector.
    let mut c = commands(MemFlash::new(1, 800));
    line(&mut c, "set max_wheel_speed 10", false);
    assert!(!c.settings().survives_stall(800));
    // The first save programs an erased slot: no erase, allowed while moving.
    let (reply, effect) = line(&mut c, "save", true);
    assert!(reply.ok, "{}", reply.text);
    assert_eq!(effect, Effect::Saved { generation: 1 });
    line(&mut c, "set track_width 0.62", false);
    let (reply, effect) = line(&mut c, "save", true);
    assert!(!reply.ok);
    assert!(
        reply.text.starts_with("error: save refused while the wheels turn: a flash erase stops the CPU for up to 800 ms"),
        "{}",
        reply.text
    );
    assert_eq!(effect, Effect::None);
    assert!(c.store_state().dirty, "nothing saved");
    // At rest the same save goes through.
    let (reply, effect) = line(&mut c, "save", false);
    assert!(reply.ok, "{}", reply.text);
    assert_eq!(effect, Effect::Saved { generation: 2 });
    // Slow enough wheels survive the stall: saving while moving is fine.
    let mut c = commands(MemFlash::new(1, 800));
    line(&mut c, "set max_wheel_speed 0.1", false);
    line(&mut c, "save", false);
    assert!(c.settings().survives_stall(800));
    let (reply, _) = line(&mut c, "save", true);
    assert!(reply.ok, "{}", reply.text);
}

#[test]
fn moving_is_asked_only_for_a_save() {
    let mut c = commands(MemFlash::new(4, 800));
    for b in b"status\n" {
        let _ = c.on_byte(*b, || ClockSource::Hse, || panic!("not a save"));
    }
}

#[test]
fn a_failed_save_says_why_and_keeps_the_settings_unsaved() {
    let mut flash = MemFlash::new(4, 0);
    flash.fail_program = true;
    let mut c = commands(flash);
    line(&mut c, "set track_width 0.63", false);
    let (reply, effect) = line(&mut c, "save", false);
    assert!(!reply.ok);
    assert!(
        reply
            .text
            .starts_with("error: save failed: flash error \"program failed\""),
        "{}",
        reply.text
    );
    assert_eq!(effect, Effect::SaveFailed);
    assert_eq!(
        c.store_state(),
        StoreState {
            source: SettingsSource::Defaults,
            dirty: true
        }
    );
}

#[test]
fn reset_status_version_and_bad_lines() {
    let mut c = commands(MemFlash::new(4, 0));
    let (reply, effect) = line(&mut c, "reset_pose 1 2 0.5", false);
    assert!(reply.ok);
    assert_eq!(
        effect,
        Effect::ResetPose(Pose {
            x: 1.0,
            y: 2.0,
            heading: 0.5
        })
    );
    let (_, effect) = line(&mut c, "status", false);
    assert_eq!(effect, Effect::Status);
    let (mut reply, effect) = line(&mut c, "version", false);
    assert_eq!(effect, Effect::Version);
    let info = c.version(&mut reply, [7; 12], ResetCause::Watchdog);
    assert_eq!(info.reset_cause, ResetCause::Watchdog);
    assert_eq!(info.uid, [7; 12]);
    assert_eq!(info.settings_source, SettingsSource::Defaults);
    assert_eq!(info.settings_checksum, Settings::DEFAULT.checksum());
    assert_eq!(info.firmware_version.as_str(), env!("CARGO_PKG_VERSION"));
    assert!(reply.text.contains(&format!(
        "firmware = odo-unit {}",
        env!("CARGO_PKG_VERSION")
    )));
    assert!(reply.text.contains("protocol = 1"), "{}", reply.text);
    let (reply, effect) = line(&mut c, "frobnicate", false);
    assert!(!reply.ok);
    assert_eq!(effect, Effect::None);
    let long = "x".repeat(300);
    let (reply, effect) = line(&mut c, &long, false);
    assert!(
        !reply.ok && reply.text.contains("line too long"),
        "{}",
        reply.text
    );
    assert_eq!(effect, Effect::None);
}

#[test]
fn status_text_reports_every_counter() {
    let mut c = commands(MemFlash::new(4, 0));
    line(&mut c, "set track_width 0.6", false);
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    let mut r = raw(1, 0, 0);
    r.state = SyncState::Locked;
    r.latency = 84; // 1 us at 84 MHz
    r.isr_cycles = 321;
    r.period = u64::from(HZ);
    r.stats.accepted = 5;
    record(&mut p, &r, &mut log);
    let live = p.live(&r, 999);
    let mut reply = Reply::ok();
    let board = BoardReport {
        clock: ClockSource::HsiFallback,
        stack: (1000, 4096),
        cycles_unit: "cycles",
        reset_cause: ResetCause::BrownOut,
    };
    let host = RxErrors {
        lost: 3,
        overruns: 2,
        framing: 1,
        noise: 0,
        parity: 0,
    };
    let gnss = RxErrors {
        lost: 4,
        overruns: 4,
        framing: 0,
        noise: 7,
        parity: 0,
    };
    c.status(&mut reply, &live, &host, &gnss, &board);
    for expected in [
        "clock = hsi-fallback (HSE failed)",
        "sync = locked",
        "time_valid = no",
        "samples = 2",
        "mcu_time_us = 20000",
        "records_dropped = 0",
        "samples_lost = 0, merged_samples = 0",
        "sample_latency_max = 1000 ns, late_samples = 0",
        "second_ticks = 84000000",
        "pps_accepted = 5, pps_glitches = 0, pps_missed = 0, pps_locks = 0, pps_overcaptures = 0",
        "reset_cause = brown-out",
        "rate = 50 Hz, output_divider = 1",
        "nmea_time_messages = 0, nmea_errors = 0",
        "gnss_forwarded = 0, gnss_not_forwarded = 0, gnss_bad_checksum = 0, gnss_overlong = 0",
        "gnss_rx_lost = 4, gnss_rx_overruns = 4, gnss_rx_framing = 0, gnss_rx_noise = 7, gnss_rx_parity = 0",
        "host_rx_lost = 3, host_rx_overruns = 2, host_rx_framing = 1, host_rx_noise = 0, host_rx_parity = 0",
        "left: fault = no, index_seen = no, index_mismatches = 0, index_lost = 0",
        "right: fault = no, index_seen = no, index_mismatches = 0, index_lost = 0",
        "sample_isr_max = 321 cycles, process_max = 999 cycles",
        "sample_isr_last = 321 cycles, process_last = 999 cycles",
        "stack_used = 1000 of 4096 bytes",
        "settings = defaults, unsaved_changes = yes",
    ] {
        assert!(
            reply.text.lines().any(|l| l == expected),
            "{expected:?} missing in\n{}",
            reply.text
        );
    }
}

/// Sample `s` of a real discipline as the sampler hands it on, with counts (left, right).
fn raw_of(s: Sample, disc: &odo_unit::timing::Discipline, left: u32, right: u32) -> RawSample {
    let mut r = RawSample::first(s, RawCounts { left, right }, (false, false), disc);
    r.state = SyncState::FreeRunning;
    r
}

/// `set rate 50 output_divider 1` at 1 kHz / 10. The sampler switches at
/// the next whole second; the records, the heartbeat and the rate reported switch at that
/// same sample, which is sent with the rate switch flag after a Status announcing it.
#[test]
fn a_rate_switch_is_one_instant_for_records_heartbeat_and_status() {
    use odo_unit::timing::{Discipline, DisciplineConfig, SyncMode};
    let mut fast = Settings::DEFAULT;
    fast.rate = 1000;
    fast.output_divider = 10;
    let mut cfg = DisciplineConfig::for_clock(HZ, HSI_TOLERANCE_PPM);
    cfg.mode = SyncMode::Free;
    cfg.rate_hz = 1000;
    let mut disc = Discipline::new(cfg, 0).unwrap();
    let mut p = Processor::new(&fast, HZ, BITS);
    let mut log = Events::default();
    let store = StoreState {
        source: SettingsSource::Defaults,
        dirty: true,
    };
    // (tick, rate switch flag) of every record sent; (tick, rate, divider) of every Status.
    let mut records: Vec<(u64, bool)> = Vec::new();
    let mut beats: Vec<(u64, u32, u32)> = Vec::new();
    let mut now = 0;
    let mut switched_at = None;
    for k in 0..3000u32 {
        let s = disc.next_sample(now);
        now = s.tick;
        if k == 1_234 {
            // The command: the processing task gets the settings, the sampler the rate
            // (it applies it from the next second).
            let mut slow = fast;
            slow.rate = 50;
            slow.output_divider = 1;
            p.apply(
                Requests {
                    settings: Some(slow),
                    reset: None,
                },
                &mut log,
            );
            let mut c = *disc.config();
            c.rate_hz = 50;
            disc.set_config(c).unwrap();
        }
        if s.rate == 50 && switched_at.is_none() {
            switched_at = Some(s.tick);
        }
        let r = raw_of(s, &disc, k, k);
        let rec = record(&mut p, &r, &mut log);
        if p.heartbeat_due() {
            let st = p.heartbeat(&r, &inputs(store));
            beats.push((s.tick, st.rate_hz, st.output_divider));
            p.status_sent(true);
        }
        if let Some(rec) = rec {
            records.push((s.tick, rec.flags.rate_switch));
            p.sent(true);
        }
    }
    let switch = switched_at.expect("the sampler switched");
    assert_eq!(switch, 2 * u64::from(HZ), "at the next whole second");
    // Exactly one flagged record: the first sample at 50 Hz.
    let flagged: Vec<u64> = records.iter().filter(|r| r.1).map(|r| r.0).collect();
    assert_eq!(flagged, [switch]);
    // The Status of that second comes with it and announces 50 Hz, divider 1; every
    // Status before it says 1000 Hz, divider 10.
    assert!(beats.contains(&(switch, 50, 1)), "{beats:?}");
    for b in beats.iter().filter(|b| b.0 < switch) {
        assert_eq!((b.1, b.2), (1000, 10), "{b:?}");
    }
    for b in beats.iter().filter(|b| b.0 >= switch) {
        assert_eq!((b.1, b.2), (50, 1), "{b:?}");
    }
    // Records per second: 100 before, 50 after, never more (the baud budget).
    let hz = u64::from(HZ);
    for second in 0..6 {
        let n = records
            .iter()
            .filter(|r| r.0 >= second * hz && r.0 < (second + 1) * hz)
            .count();
        if (second + 1) * hz <= switch {
            assert_eq!(n, 100, "second {second}");
        } else if second * hz >= switch && second * hz < now {
            assert!(n <= 50, "second {second}: {n}");
        }
    }
    let live = p.live(&raw_of(disc.next_sample(now), &disc, 0, 0), 0);
    assert_eq!((live.rate, live.output_divider), (50, 1));
}

/// A Status without room is tried again at the next sample, and comes before its record.
#[test]
fn a_heartbeat_without_room_is_retried() {
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    assert!(p.heartbeat_due());
    p.status_sent(false);
    record(&mut p, &raw(1, 0, 0), &mut log);
    assert!(p.heartbeat_due(), "still due");
    p.status_sent(true);
    record(&mut p, &raw(2, 0, 0), &mut log);
    assert!(!p.heartbeat_due());
}

/// The first record after a stall (or a late interrupt) is flagged; set once,
/// kept while records are skipped or dropped.
#[test]
fn a_late_sample_is_flagged_once() {
    let mut s = Settings::DEFAULT;
    s.output_divider = 2;
    let mut p = Processor::new(&s, HZ, BITS);
    let mut log = Events::default();
    let rec = record(&mut p, &raw(0, 0, 0), &mut log).unwrap();
    assert!(!rec.flags.late);
    p.sent(true);
    // Sample 1 ran late by a third of a period (not merged): flagged, carried past the
    // skipped sample to record 2.
    let mut r = raw(1, 0, 0);
    r.latency = HZ / 50 / 3;
    assert!(record(&mut p, &r, &mut log).is_none(), "divider 2");
    let rec = record(&mut p, &raw(2, 0, 0), &mut log).unwrap();
    assert!(rec.flags.late);
    p.sent(false);
    assert!(record(&mut p, &raw(3, 0, 0), &mut log).is_none());
    let rec = record(&mut p, &raw(4, 0, 0), &mut log).unwrap();
    assert!(rec.flags.late, "kept while the record is dropped");
    p.sent(true);
    assert!(record(&mut p, &raw(5, 0, 0), &mut log).is_none());
    let rec = record(&mut p, &raw(6, 0, 0), &mut log).unwrap();
    assert!(!rec.flags.late, "cleared once sent");
    p.sent(true);
    // A stall merged grid points into sample 7: late whatever the latency.
    let mut r = raw(7, 0, 0);
    r.merged = 2;
    assert!(record(&mut p, &r, &mut log).is_none());
    assert!(record(&mut p, &raw(8, 0, 0), &mut log).unwrap().flags.late);
    assert_eq!(p.live(&r, 0).late_samples, 2);
    // A quarter period is the limit: below it, not late.
    let mut p = processor();
    record(&mut p, &raw(0, 0, 0), &mut log);
    let mut r = raw(1, 0, 0);
    r.latency = HZ / 50 / 4;
    assert!(!record(&mut p, &r, &mut log).unwrap().flags.late);
    assert_eq!(p.live(&r, 0).late_samples, 0);
}

/// Index pulses lost to a full queue are counted with the next one queued.
#[test]
fn index_pulses_lost_to_a_full_queue_are_counted() {
    let mut lost = 0;
    let c = IndexCapture {
        raw: 1,
        overcapture: false,
        queue_lost: 0,
    };
    let mut queued = Vec::new();
    c.queue(&mut lost, |_| false);
    c.queue(&mut lost, |_| false);
    assert_eq!(lost, 2);
    c.queue(&mut lost, |c| {
        queued.push(c);
        true
    });
    assert_eq!(lost, 0);
    assert_eq!(queued[0].queue_lost, 2);
    let mut p = processor();
    let mut log = Events::default();
    record(&mut p, &raw(0, 0, 0), &mut log);
    p.on_index_capture(
        1,
        IndexCapture {
            raw: 3,
            overcapture: true,
            queue_lost: 2,
        },
        &mut log,
    );
    let r = raw(1, 0, 0);
    record(&mut p, &r, &mut log);
    assert_eq!(p.live(&r, 0).index_lost, [0, 3]);
    assert_eq!(p.heartbeat(&r, &inputs(p_store())).index_lost, 3);
}

fn p_store() -> StoreState {
    StoreState {
        source: SettingsSource::Defaults,
        dirty: false,
    }
}

/// USART_SR (RM0368 sec. 19.6.1): what each flag does to the counters and the byte.
#[test]
fn uart_status_flags_table() {
    use odo_unit::unit::rx_errors::{SR_FE, SR_NF, SR_ORE, SR_PE, SR_RXNE};
    let mut e = RxErrors::default();
    for (sr, want) in [
        (0, RxByte::None),
        (SR_FE, RxByte::None), // no byte: nothing counted
        (SR_RXNE, RxByte::Keep),
        (SR_RXNE | SR_NF, RxByte::Keep),
        (SR_RXNE | SR_FE, RxByte::Drop),
        (SR_RXNE | SR_PE, RxByte::Drop),
        (SR_ORE, RxByte::Keep),
        (SR_RXNE | SR_ORE | SR_FE, RxByte::Drop),
    ] {
        assert_eq!(e.on_status(sr), want, "{sr:#x}");
    }
    e.on_queue_full();
    assert_eq!(
        e,
        RxErrors {
            lost: 3,
            overruns: 2,
            framing: 2,
            noise: 1,
            parity: 1
        }
    );
    assert_eq!(e.line_errors(), 4);
}

/// A sample lost to a full queue does not lose its PPS edge: the edge goes
/// back into the latch and travels with the next sample (a later glitch does not hide it).
#[test]
fn a_dropped_sample_gives_its_pps_edge_to_the_next() {
    let mut latch = PpsLatch::new();
    latch.on_interrupt(
        Some((
            1000,
            PpsEvent::Accepted {
                second: 3,
                phase_error: 2,
            },
        )),
        true,
    );
    let (pps, over) = latch.take();
    let mut lost = raw(1, 0, 0);
    lost.pps = pps;
    lost.pps_overcapture = over;
    // The queue was full: put back, then a glitch comes before the next sample.
    latch.put_back(&lost);
    latch.on_interrupt(Some((1500, PpsEvent::Glitch)), false);
    let (pps, over) = latch.take();
    assert_eq!(
        pps,
        Some((
            1000,
            PpsEvent::Accepted {
                second: 3,
                phase_error: 2
            }
        ))
    );
    assert!(over);
    assert_eq!(latch.take(), (None, false));
}
