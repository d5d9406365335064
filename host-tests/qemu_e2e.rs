//! End-to-end test of the firmware in QEMU (`netduinoplus2`), run by `.ci/run` after it has
//! built the `qemu` image:
//!
//! ```text
//! cargo build --release --features qemu --target-dir target/qemu
//! cargo test --target x86_64-unknown-linux-gnu --test qemu_e2e -- --nocapture
//! ```
//!
//! It boots the image with `-icount shift=0,sleep=off` (deterministic, faster than real
//! time), connects to USART2 over a TCP socket on 127.0.0.1, sends configuration commands
//! and checks the replies (errors included), reads pose records covering more than 10 s of
//! emulated time after a `reset_pose`, decodes them with the core's frame decoder, checks
//! the sequence numbers and timing, and replays the raw counts they carry through the core
//! integrator with the same settings: poses and sigmas must match bit for bit (tolerance 0:
//! the firmware and this test run the same integer and IEEE-754 arithmetic).
//!
//! Without `qemu-system-arm` (or `$QEMU_SYSTEM_ARM`) or without the image
//! (`target/qemu/thumbv7em-none-eabihf/release/odo-unit`, or `$ODO_QEMU_IMAGE`) the test is
//! skipped with a message, unless `ODO_QEMU_REQUIRED=1` (as in CI), which makes it fail.

use std::path::Path;
use std::time::{Duration, Instant};

use odo_unit::protocol::{Message, ResetCause};
use odo_unit::settings::Settings;
use odo_unit::settings::SettingsSource;
use odo_unit::timing::SyncState;

mod support;
use support::qemu::UnitLink;

/// Emulated time the replay must cover after the pose reset, microseconds.
const REPLAY_US: u64 = 12_000_000;
/// Wall-clock limit of the whole test.
const DEADLINE: Duration = Duration::from_secs(120);

fn expect(link: &mut UnitLink, line: &str, ok: bool, contains: &str) -> String {
    let (got_ok, text) = link.command(line);
    assert_eq!(got_ok, ok, "`{line}` answered {text:?}");
    assert_eq!(
        text.starts_with("ok"),
        ok,
        "`{line}`: reply must start with ok/error: {text:?}"
    );
    assert!(
        text.contains(contains),
        "`{line}`: {text:?} lacks {contains:?}"
    );
    text
}

#[test]
fn qemu_end_to_end() {
    let Some(qemu) = support::qemu::boot(Path::new(env!("CARGO_MANIFEST_DIR")), "qemu_end_to_end")
    else {
        return;
    };
    let start = Instant::now();
    let mut link = UnitLink::connect(qemu.port, DEADLINE);

    // DeviceInfo first (frame 0): how a receiver sees that the unit (re)started.
    let first = link.next_frame();
    assert_eq!(first.seq, 0, "the first frame after start");
    let Message::DeviceInfo(info) = &first.message else {
        panic!("the first frame is {:?}, not DeviceInfo", first.message)
    };
    assert_eq!(info.protocol_version, 1);
    assert_eq!(info.settings_source, SettingsSource::Defaults);
    assert_eq!(info.settings_checksum, Settings::DEFAULT.checksum());
    assert_eq!(info.firmware_version.as_str(), env!("CARGO_PKG_VERSION"));
    // QEMU models no reset flags (RCC_CSR reads 0).
    assert_eq!(info.reset_cause, ResetCause::Unknown);

    // Records flow from boot.
    while link.records.len() < 5 {
        link.next_frame();
    }

    // Configuration commands, the host's copy of the settings follows the accepted ones.
    let mut settings = Settings::DEFAULT;
    expect(&mut link, "get track_width", true, "track_width = 0.563");
    let set = [
        ("track_width", "0.5512"),
        ("left_diameter", "0.2605"),
        ("right_diameter", "0.2597"),
        ("delta_left", "4.5e-8"),
        ("delta_right", "3.2e-8"),
    ];
    let line = set
        .iter()
        .fold(String::from("set"), |l, (k, v)| format!("{l} {k} {v}"));
    expect(&mut link, &line, true, "track_width = 0.5512");
    settings
        .set_many(set)
        .expect("host accepts the same settings");
    // Errors change nothing.
    expect(&mut link, "frobnicate", false, "error");
    expect(&mut link, "set no_such_key 1", false, "no_such_key");
    expect(&mut link, "set ticks_per_rev 3", false, "ticks_per_rev");
    expect(&mut link, "set left_diameter nan", false, "left_diameter");
    expect(&mut link, "set track_width abc", false, "track_width");
    expect(&mut link, "rate 0", false, "rate");
    expect(
        &mut link,
        "set track_width 0.6 left_diameter 99",
        false,
        "left_diameter",
    );
    expect(&mut link, "get track_width", true, "track_width = 0.5512");
    let long = "x".repeat(400);
    expect(&mut link, &long, false, "too long");
    expect(&mut link, "mode free", true, "ok");
    expect(&mut link, "status", true, "sync = free");
    expect(&mut link, "version", true, "protocol = 1");
    assert_eq!(link.device_info, 2, "one at start, one for version");
    expect(&mut link, "save", true, "saved");
    let all = expect(&mut link, "get", true, "right_sin3");
    assert!(all.contains("delta_left = 0.000000045"), "{all}");
    // The reset applies at the next sample, whose record may precede the reply frame.
    let reset_from = link.records.len();
    expect(&mut link, "reset_pose 1.5 -2 0.25", true, "ok");
    let replied_at = link.records.len();

    // Records until 12 s of emulated time after the reset.
    let r0 = loop {
        if let Some(i) = (reset_from..link.records.len()).find(|&i| {
            let r = &link.records[i];
            r.x == 1.5 && r.y == -2.0 && (r.heading - 0.25).abs() < 1e-12 && r.sigma_x == 0.0
        }) {
            break i;
        }
        assert!(
            link.records.len() < replied_at + 100,
            "no record carries the reset pose"
        );
        link.next_frame();
    };
    let t0 = link.records[r0].mcu_time_us;
    while link
        .records
        .last()
        .is_none_or(|r| r.mcu_time_us < t0 + REPLAY_US)
    {
        link.next_frame();
    }
    let records = link.records.clone();
    println!(
        "{} frames, {} records; replay from record {} (t = {:.3} s) over {:.1} s, {:.1} s wall",
        link.seqs.len(),
        records.len(),
        records[r0].sequence,
        t0 as f64 * 1e-6,
        REPLAY_US as f64 * 1e-6,
        start.elapsed().as_secs_f64()
    );

    // Sequence numbers: frames and records consecutive, nothing dropped, 50 Hz exactly.
    for w in link.seqs.windows(2) {
        assert_eq!(w[1], w[0].wrapping_add(1), "frame sequence gap");
    }
    for w in records.windows(2) {
        assert_eq!(
            w[1].sequence,
            w[0].sequence.wrapping_add(1),
            "record sequence gap"
        );
        assert_eq!(
            w[1].mcu_time_us - w[0].mcu_time_us,
            20_000,
            "50 Hz in emulated time"
        );
    }
    assert_eq!(records[0].sequence, 0, "the first record is sample 0");

    // The once-a-second Status heartbeat: one per 50 samples, counting them.
    let beats = &link.heartbeats;
    assert!(beats.len() >= 10, "{} heartbeats in over 10 s", beats.len());
    for w in beats.windows(2) {
        assert_eq!(
            w[1].samples - w[0].samples,
            50,
            "one heartbeat per second of samples"
        );
        assert_eq!(w[1].uptime_us - w[0].uptime_us, 1_000_000);
    }
    assert!(beats
        .iter()
        .all(|b| b.rate_hz == 50 && b.dropped_total == 0));
    assert!(beats
        .last()
        .is_some_and(|b| b.settings_source == SettingsSource::Flash && !b.settings_dirty));
    assert!(records.iter().all(|r| r.dropped == 0));
    assert!(records
        .iter()
        .all(|r| r.flags.sync == SyncState::FreeRunning && !r.flags.time_valid));

    // The simulated drive: reversing, both counters wrapped (left 32-bit near its wrap at
    // boot, right 16-bit every few seconds), fault line and index mismatch on the right.
    let dl: Vec<i64> = records
        .windows(2)
        .map(|w| w[1].gamma_left - w[0].gamma_left)
        .collect();
    assert!(
        dl.iter().any(|d| *d > 0) && dl.iter().any(|d| *d < 0),
        "forward and reverse"
    );
    assert!(
        records[0].gamma_left < 0 && records.iter().any(|r| r.gamma_left > 0),
        "left wrap"
    );
    let (rmin, rmax) = records.iter().fold((i64::MAX, i64::MIN), |(a, b), r| {
        (a.min(r.gamma_right), b.max(r.gamma_right))
    });
    assert!(
        rmax - rmin > 65_536,
        "right counter range {rmin}..{rmax} crosses a 16-bit wrap"
    );
    assert!(
        records.iter().any(|r| r.flags.right.fault) && records.iter().any(|r| !r.flags.right.fault)
    );
    assert!(
        records.iter().any(|r| r.flags.right.index_mismatch),
        "right index mismatch"
    );
    assert!(!records
        .iter()
        .any(|r| r.flags.left.index_mismatch || r.flags.left.fault));
    assert!(records
        .last()
        .is_some_and(|r| r.flags.left.index_seen && r.flags.right.index_seen));

    // Replay the counts through the core integrator: bit-exact poses and sigmas.
    let distance = support::qemu::assert_replay_bit_exact(&settings.chassis, &records[r0..]);
    let replayed = records.len() - r0 - 1;
    let last = records.last().expect("records");
    println!(
        "replayed {replayed} records bit-exact: {distance:.2} m driven, final pose ({:.4}, {:.4}, {:.4} rad), sigma ({:.2e}, {:.2e}, {:.2e})",
        last.x, last.y, last.heading, last.sigma_x, last.sigma_y, last.sigma_heading
    );
    assert!(replayed >= 500, "at least 10 s at 50 Hz");
    // The unit's own measurement of its per-sample cost (instructions under -icount).
    let status = expect(&mut link, "status", true, "sample_isr_max");
    assert!(status.contains("records_dropped = 0"), "{status}");
    // Nothing lost or merged on the way: no sample queue overflow, no late sample interrupt
    // (QEMU never stalls), no GNSS byte or index pulse lost; the QEMU build runs on the HSI.
    for line in [
        "samples_lost = 0, merged_samples = 0",
        "gnss_rx_lost = 0",
        "index_lost = 0",
        "pps_overcaptures = 0",
        "clock = hsi",
    ] {
        assert!(status.contains(line), "{line:?} missing in {status}");
    }
    assert!(distance > 1.0, "the drive moved");
    // Stack high-water mark after every command, error path and 12 s of sampling: well
    // inside the stack region.
    let stack: Vec<usize> = status
        .lines()
        .find_map(|l| l.strip_prefix("stack_used = "))
        .map(|l| l.split(' ').filter_map(|w| w.parse().ok()).collect())
        .unwrap_or_default();
    assert!(
        matches!(stack[..], [used, size] if used > 1024 && used < size / 2),
        "stack: {stack:?}"
    );

    rate_switch(&mut link);
}

/// `set rate 100 output_divider 4` at 50 Hz / 1 switches everything at
/// one whole second: the Status just before the flagged record announces 100 Hz / 4; the
/// records before it are 20 ms apart, those after it 40 ms (every 4th sample at 100 Hz).
fn rate_switch(link: &mut UnitLink) {
    let from_record = link.records.len();
    let from_frame = link.frames.len();
    let t_sent = link.records.last().expect("records").mcu_time_us;
    expect(
        link,
        "set rate 100 output_divider 4",
        true,
        "output_divider = 4",
    );
    let t_cmd = link.records.last().expect("records").mcu_time_us;
    while link
        .records
        .last()
        .is_none_or(|r| r.mcu_time_us < t_cmd + 3_500_000)
    {
        link.next_frame();
    }
    let records = &link.records[from_record..];
    let flagged: Vec<usize> = (0..records.len())
        .filter(|&i| records[i].flags.rate_switch)
        .collect();
    assert_eq!(flagged.len(), 1, "one record marks the switch");
    let k = flagged[0];
    let switch = records[k];
    assert_eq!(switch.mcu_time_us % 1_000_000, 0, "at a whole second");
    // At the first whole second after the command ran: it ran before the sample after
    // `t_cmd` (whose record follows the reply), so at the latest at the first second that
    // begins with or after that sample.
    let latest = (t_cmd + 20_000).next_multiple_of(1_000_000);
    assert!(
        switch.mcu_time_us > t_sent && switch.mcu_time_us <= latest,
        "switch at {} us, command sent after {t_sent} us, answered by {t_cmd} us",
        switch.mcu_time_us
    );
    for w in records[..k].windows(2) {
        assert_eq!(
            w[1].mcu_time_us - w[0].mcu_time_us,
            20_000,
            "50 Hz, every sample"
        );
        assert_eq!(w[1].sequence - w[0].sequence, 1);
    }
    assert_eq!(switch.mcu_time_us - records[k - 1].mcu_time_us, 20_000);
    assert_eq!(switch.sequence - records[k - 1].sequence, 1);
    for w in records[k..].windows(2) {
        assert_eq!(
            w[1].mcu_time_us - w[0].mcu_time_us,
            40_000,
            "100 Hz, every 4th"
        );
        assert_eq!(w[1].sequence - w[0].sequence, 4);
    }
    assert!(records[k + 1..].iter().all(|r| !r.flags.rate_switch));
    // The frame before the flagged record is the Status announcing the new configuration.
    let frames = &link.frames[from_frame..];
    let at = frames
        .iter()
        .position(|f| matches!(&f.message, Message::Pose(r) if r.flags.rate_switch))
        .expect("the flagged record's frame");
    let Message::Status(announce) = &frames[at - 1].message else {
        panic!("frame before the switch: {:?}", frames[at - 1].message)
    };
    assert_eq!((announce.rate_hz, announce.output_divider), (100, 4));
    assert_eq!(announce.uptime_us, switch.mcu_time_us);
    // Every Status: 50 Hz / 1 before, 100 Hz / 4 from the switch on, one per second.
    let beats: Vec<_> = frames
        .iter()
        .filter_map(|f| match &f.message {
            Message::Status(s) => Some(*s),
            _ => None,
        })
        .collect();
    for b in &beats {
        let want = if b.uptime_us < switch.mcu_time_us {
            (50, 1)
        } else {
            (100, 4)
        };
        assert_eq!((b.rate_hz, b.output_divider), want, "{b:?}");
    }
    for w in beats.windows(2) {
        assert_eq!(w[1].uptime_us - w[0].uptime_us, 1_000_000);
    }
    println!(
        "rate switch at {:.3} s (sample {}): {} records at 50 Hz / 1, then {} at 100 Hz / 4",
        switch.mcu_time_us as f64 * 1e-6,
        switch.sequence,
        k,
        records.len() - k
    );
}

/// Rate switches at 2 and 3 Hz, where every command lands within two sample periods of the
/// next whole second: each takes effect at the first second that begins after the command
/// ran. The Status announcing the new rate is the first one after the reply (or, when a
/// second began between the command and its reply, the one just before it), at a whole
/// second, and the record after it is the first at the new rate, flagged.
#[test]
fn qemu_rate_switch_at_low_rates() {
    let Some(qemu) = support::qemu::boot(
        Path::new(env!("CARGO_MANIFEST_DIR")),
        "qemu_rate_switch_at_low_rates",
    ) else {
        return;
    };
    let mut link = UnitLink::connect(qemu.port, DEADLINE);
    while link.records.len() < 3 {
        link.next_frame();
    }
    let mut old = Settings::DEFAULT.rate;
    for rate in [2u32, 3, 2, 3, 2, 3, 1, 2] {
        let sent_at = link.frames.len();
        let line = if rate == 1 {
            // 1 Hz needs a lower stated wheel speed (the counts rule).
            "set rate 1 max_wheel_speed 1".to_string()
        } else {
            format!("rate {rate}")
        };
        expect(&mut link, &line, true, &format!("rate = {rate}"));
        let reply_at = link.frames.len() - 1;
        // Frames up to the second Status after the reply.
        let mut after = 0;
        while after < 2 {
            if matches!(link.next_frame().message, Message::Status(_)) {
                after += 1;
            }
        }
        let frames = &link.frames[sent_at..];
        let status_at: Vec<usize> = (0..frames.len())
            .filter(|&i| matches!(frames[i].message, Message::Status(_)))
            .collect();
        let status = |i: usize| match &frames[i].message {
            Message::Status(s) => *s,
            _ => unreachable!(),
        };
        let switch = *status_at
            .iter()
            .find(|&&i| status(i).rate_hz == rate)
            .unwrap_or_else(|| panic!("`{line}`: no Status at {rate} Hz"));
        let first_after = *status_at
            .iter()
            .find(|&&i| i > reply_at - sent_at)
            .expect("a Status after the reply");
        let last_before = status_at.iter().rev().find(|&&i| i < reply_at - sent_at);
        assert!(
            switch == first_after || Some(&switch) == last_before,
            "`{line}`: the switch's Status is frame {switch}, the reply frame {}, the first \
             Status after it frame {first_after}",
            reply_at - sent_at
        );
        for &i in status_at.iter().filter(|&&i| i < switch) {
            assert_eq!(status(i).rate_hz, old, "`{line}`: {:?}", status(i));
        }
        let announce = status(switch);
        assert_eq!(announce.uptime_us % 1_000_000, 0, "{announce:?}");
        let Message::Pose(first) = &frames[switch + 1].message else {
            panic!(
                "after the switch's Status: {:?}",
                frames[switch + 1].message
            )
        };
        assert!(first.flags.rate_switch, "{first:?}");
        assert_eq!(first.mcu_time_us, announce.uptime_us);
        let flagged = frames
            .iter()
            .filter(|f| matches!(&f.message, Message::Pose(r) if r.flags.rate_switch))
            .count();
        assert_eq!(flagged, 1, "`{line}`: one record marks the switch");
        println!(
            "`{line}`: reply frame {}, switch at {:.3} s (frame {switch})",
            reply_at - sent_at,
            announce.uptime_us as f64 * 1e-6
        );
        old = rate;
    }
}
