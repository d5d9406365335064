//! End-to-end test of calibration mode (`mode pps`) in QEMU, against the simulated GNSS
//! receiver of the `qemu` build (`src/board/qemu/gnss.rs`, docs/HARDWARE.md): PPS captures
//! from a receiver whose second is 1,000,037,000 MCU ticks (the MCU clock 37 ppm fast) with
//! up to 40 ns of jitter, ZDA and RMC 100 ms after each edge naming 2026-11-21 12:00:00 UTC +
//! `n` s, and a 20 s script: a corrupted RMC at lap second 5, a glitch edge 300 ms after the
//! edge of lap second 8, no edge at lap seconds 12-14.
//!
//! ```text
//! cargo build --release --features qemu --target-dir target/qemu
//! cargo test --target x86_64-unknown-linux-gnu --test qemu_pps -- --nocapture
//! ```
//!
//! It boots the image (free-running, as always), sends a `reset_pose` and `mode pps`, reads
//! records over more than one lap of the script after the lock and checks: the sync state goes
//! FreeRunning -> Locked, then Holdover for the 3 s outage and Locked again; from the
//! first time-tagged record on, every record carries GPS week/time of week of the simulated
//! date (odo_unit's own UTC-to-GPS conversion) with `sample_in_second` stepping 0..49 and
//! wrapping at each second; sample `k` of GNSS second `n` falls on the receiver's edge plus
//! `k/50` of its second, to the microsecond; consecutive samples are 20,000.74 us of MCU time
//! apart on average (the +37 ppm removed); the glitch is rejected (heartbeats'
//! `pps_rejected`, `status` `pps_glitches`), the outage counted (`pps_missed`), the corrupted
//! sentence counted (`nmea_errors`); and the raw counts replayed through the core integrator
//! reproduce every pose and sigma bit for bit.
//!
//! Skipped without QEMU or the image unless `ODO_QEMU_REQUIRED=1` (see `support/qemu.rs`).

use std::path::Path;
use std::time::{Duration, Instant};

use odo_unit::protocol::{PoseRecord, Status};
use odo_unit::settings::Settings;
use odo_unit::timing::SyncState;
use odo_unit::timing::UtcDateTime;

mod support;
use support::qemu::UnitLink;

// The simulated receiver, as documented in src/board/qemu/gnss.rs (MCU ticks are ns in QEMU).
/// One GNSS second in MCU ticks: the MCU clock is 37 ppm fast.
const SECOND_NS: u64 = 1_000_037_000;
/// MCU time of the nominal edge of receiver second 0.
const FIRST_EDGE_NS: u64 = 250_000_000;
/// UTC of receiver second 0.
const START: UtcDateTime = UtcDateTime {
    year: 2026,
    month: 11,
    day: 21,
    hour: 12,
    minute: 0,
    second: 0,
    millis: 0,
};
const LAP: u64 = 20;
const CORRUPT_SECOND: u64 = 5;
const GLITCH_SECOND: u64 = 8;
const GLITCH_DELAY_NS: u64 = 300_000_000;
const OUTAGE: (u64, u64) = (12, 15);
const NMEA_DELAY_NS: u64 = 100_000_000;
/// Samples per second.
const RATE: u64 = 50;

/// Wall-clock limit of the whole test.
const DEADLINE: Duration = Duration::from_secs(120);
/// Emulated time after which the test gives up waiting for the script, us.
const MAX_EMULATED_US: u64 = 90_000_000;

/// `line` must be answered ok, with `contains` in the reply.
fn expect(link: &mut UnitLink, line: &str, contains: &str) -> String {
    let (ok, text) = link.command(line);
    assert!(ok && text.contains(contains), "`{line}` answered {text:?}");
    text
}

/// Nominal MCU time of the edge of receiver second `n`, ns.
fn edge_ns(n: u64) -> u64 {
    FIRST_EDGE_NS + n * SECOND_NS
}

/// Receiver seconds whose event (`offset` ns after the nominal edge, in lap seconds that
/// `pick` selects) lies before `t_ns`: (surely before `t_ns - margin`, possibly before
/// `t_ns + margin`).
fn events_before(
    t_ns: u64,
    from_ns: u64,
    offset: u64,
    margin: u64,
    pick: impl Fn(u64) -> bool,
) -> (u64, u64) {
    let (mut lo, mut hi) = (0, 0);
    let mut n = 0;
    while edge_ns(n) + offset < t_ns + margin {
        let at = edge_ns(n) + offset;
        if pick(n % LAP) && at > from_ns {
            hi += 1;
            if at + margin < t_ns {
                lo += 1;
            }
        }
        n += 1;
    }
    (lo, hi)
}

/// The number after `key = ` in a `status` reply.
fn field(text: &str, key: &str) -> u64 {
    let at = text
        .find(&format!("{key} = "))
        .unwrap_or_else(|| panic!("{key} missing in {text:?}"));
    text[at + key.len() + 3..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|d| d.parse().ok())
        .unwrap_or_else(|| panic!("{key} unreadable in {text:?}"))
}

#[test]
fn qemu_pps_calibration_mode() {
    let Some(qemu) = support::qemu::boot(
        Path::new(env!("CARGO_MANIFEST_DIR")),
        "qemu_pps_calibration_mode",
    ) else {
        return;
    };
    let start = Instant::now();
    let mut link = UnitLink::connect(qemu.port, DEADLINE);

    // GPS time of receiver second 0 by the core's conversion; the week and time of week by
    // hand (2026-11-21 is a Saturday: 6 days and 12 h into GPS week 2445, plus 18 s).
    let start_gps = START.gps_seconds().expect("valid date");
    let t0 = START.gps_time().expect("valid date");
    assert_eq!((t0.week, t0.tow), (2445, 6 * 86_400 + 12 * 3600 + 18));

    // Boot: free-running, no time.
    while link.records.len() < 5 {
        link.next_frame();
    }
    expect(&mut link, "get time_tag_pps", "time_tag_pps = previous");
    // The reset first: emulated time runs ahead while a reply crosses the socket, so only
    // this order guarantees that the replay from the reset covers the lock.
    let reset_from = link.records.len();
    expect(&mut link, "reset_pose 10 20 0.5", "ok");
    expect(&mut link, "mode pps", "ok");

    // Records until one whole lap of the script after the first time-tagged record, with an
    // outage (holdover, reacquisition) behind.
    let receiver_second = |r: &PoseRecord| -> Option<u64> {
        r.flags.time_valid.then(|| {
            let gps = u64::from(r.gnss.week) * 604_800 + u64::from(r.gnss.tow_ms / 1000);
            gps - u64::from(start_gps)
        })
    };
    loop {
        let recs = &link.records;
        let first = recs.iter().find_map(receiver_second);
        let last = recs.last().and_then(receiver_second);
        let reacquired = recs.windows(2).any(|w| {
            w[0].flags.sync == SyncState::Holdover && w[1].flags.sync == SyncState::Locked
        });
        if let (Some(a), Some(b)) = (first, last) {
            if b >= a + LAP + 2 && reacquired {
                break;
            }
        }
        let t = recs.last().map_or(0, |r| r.mcu_time_us);
        assert!(
            t < MAX_EMULATED_US,
            "script not seen after {} s of emulated time",
            t / 1_000_000
        );
        link.next_frame();
    }
    let before_status = link.records.len();
    let status = expect(&mut link, "status", "pps_glitches");
    let records = link.records.clone();
    let t_lo = records[before_status - 1].mcu_time_us * 1000;
    let t_hi = records.last().expect("records").mcu_time_us * 1000;
    println!(
        "{} records, {} heartbeats; status between {:.3} s and {:.3} s; {:.1} s wall",
        records.len(),
        link.heartbeats.len(),
        t_lo as f64 * 1e-9,
        t_hi as f64 * 1e-9,
        start.elapsed().as_secs_f64()
    );

    // Frames and records consecutive, nothing dropped.
    for w in link.seqs.windows(2) {
        assert_eq!(w[1], w[0].wrapping_add(1), "frame sequence gap");
    }
    for w in records.windows(2) {
        assert_eq!(w[1].sequence, w[0].sequence + 1, "record sequence gap");
    }
    assert!(records.iter().all(|r| r.dropped == 0));

    // Sync state: FreeRunning -> Locked, then Holdover <-> Locked only.
    let mut runs: Vec<(SyncState, usize, usize)> = Vec::new(); // (mode, first index, length)
    for (i, r) in records.iter().enumerate() {
        match runs.last_mut() {
            Some((m, _, len)) if *m == r.flags.sync => *len += 1,
            _ => runs.push((r.flags.sync, i, 1)),
        }
    }
    let names: Vec<String> = runs.iter().map(|(m, _, l)| format!("{m:?} x{l}")).collect();
    println!("sync runs: {}", names.join(" -> "));
    assert_eq!(runs[0].0, SyncState::FreeRunning, "boots free-running");
    assert_eq!(runs[1].0, SyncState::Locked, "FreeRunning -> Locked");
    for w in runs[1..].windows(2) {
        assert!(
            matches!(
                (w[0].0, w[1].0),
                (SyncState::Locked, SyncState::Holdover) | (SyncState::Holdover, SyncState::Locked)
            ),
            "transition {:?} -> {:?}",
            w[0].0,
            w[1].0
        );
    }
    let lock_at = runs[1].1;
    let lock_ns = records[lock_at].mcu_time_us * 1000;
    assert!(records[..lock_at].iter().all(|r| !r.flags.time_valid));

    // Holdover exactly over the outage: from sample 1 of lap second 12 (the first sample after
    // the edge's window closed) to the reacquired edge of lap second 15.
    let mut holdovers = 0;
    for (m, i, len) in &runs {
        if *m != SyncState::Holdover || i + len >= records.len() {
            continue;
        }
        let (first, after) = (&records[*i], &records[i + len]);
        let (n0, n1) = (
            receiver_second(first).expect("holdover keeps the time"),
            receiver_second(after).expect("time after reacquisition"),
        );
        println!(
            "holdover: {len} samples, from GNSS second {n0} sample {} to second {n1} sample {}",
            first.gnss.sample_in_second, after.gnss.sample_in_second
        );
        assert_eq!(
            n0 % LAP,
            OUTAGE.0,
            "holdover starts in the first second without edge"
        );
        assert_eq!(first.gnss.sample_in_second, 1);
        assert_eq!(n1 % LAP, OUTAGE.1, "reacquired at the next edge");
        assert!(after.gnss.sample_in_second <= 1);
        assert!((148..=151).contains(len), "holdover of {len} samples");
        holdovers += 1;
    }
    assert!(holdovers >= 1, "an outage was seen and ended");

    // GNSS time from the first tagged record on (within a second of the lock).
    let tagged = records
        .iter()
        .position(|r| r.flags.time_valid)
        .expect("time-tagged records");
    assert!(
        tagged > lock_at && tagged - lock_at <= RATE as usize,
        "time tag {} samples after the lock",
        tagged - lock_at
    );
    let span = &records[tagged..];
    let mut one_second_deltas = Vec::new();
    for (i, r) in span.iter().enumerate() {
        assert!(r.flags.time_valid, "record {}: time lost", r.sequence);
        assert_ne!(r.flags.sync, SyncState::FreeRunning);
        assert_eq!(r.gnss.tow_ms % 1000, 0);
        assert!(u64::from(r.gnss.sample_in_second) < RATE);
        let n = receiver_second(r).expect("tagged");
        let k = u64::from(r.gnss.sample_in_second);
        // Sample k of GNSS second n: on the receiver's edge plus k/50 of its second (the
        // edge's jitter and truncation to us within 2 us).
        let want = edge_ns(n) + k * SECOND_NS / RATE;
        let got = r.mcu_time_us * 1000;
        assert!(
            got.abs_diff(want) < 2_000,
            "record {}: second {n} sample {k} at {got} ns, receiver grid {want} ns",
            r.sequence
        );
        if let Some(next) = span.get(i + 1) {
            let (n1, k1) = (
                receiver_second(next).expect("tagged"),
                next.gnss.sample_in_second,
            );
            if k + 1 < RATE {
                assert_eq!((n1, u64::from(k1)), (n, k + 1), "record {}", next.sequence);
            } else {
                assert_eq!((n1, k1), (n + 1, 0), "wrap at record {}", next.sequence);
            }
            let d = next.mcu_time_us - r.mcu_time_us;
            assert!(
                d == 20_000 || d == 20_001,
                "record {}: {d} us",
                next.sequence
            );
        }
        if k == 0 {
            if let Some(prev) = span[..i].iter().rev().nth(RATE as usize - 1) {
                if prev.gnss.sample_in_second == 0 {
                    one_second_deltas.push(r.mcu_time_us - prev.mcu_time_us);
                }
            }
        }
    }
    let (first, last) = (&span[0], span.last().expect("span"));
    let mean = (last.mcu_time_us - first.mcu_time_us) as f64 / (span.len() - 1) as f64;
    let ppm = (mean / 20_000.0 - 1.0) * 1e6;
    println!(
        "{} tagged records: GPS week {} tow {}..{} s; mean sample spacing {mean:.5} us ({ppm:+.3} ppm), \
         GNSS second = {:?} us",
        span.len(),
        first.gnss.week,
        first.gnss.tow_ms / 1000,
        last.gnss.tow_ms / 1000,
        one_second_deltas
    );
    assert!(span.len() as u64 > (LAP + 1) * RATE);
    assert!((mean - 20_000.74).abs() < 0.01, "mean spacing {mean} us");
    assert!(!one_second_deltas.is_empty());
    assert!(one_second_deltas.iter().all(|d| d.abs_diff(1_000_037) <= 1));

    // Heartbeats: glitches rejected one per lap while locked, edges accepted one per second
    // outside the outage. A heartbeat comes with the first sample of each second, which sits
    // on the PPS edge when locked: whether that edge is already counted depends on
    // nanoseconds, so an edge within 2 us of either heartbeat is allowed on either side
    // (`events_before` gives (surely before, possibly before)); glitches come 300 ms after
    // an edge and are judged exactly.
    let beats: Vec<&Status> = link
        .heartbeats
        .iter()
        .filter(|b| b.uptime_us * 1000 > lock_ns + 1_000_000_000)
        .collect();
    let mut judged = 0;
    let mut glitches_seen = 0;
    for w in beats.windows(2) {
        let (a, b) = (w[0].uptime_us * 1000, w[1].uptime_us * 1000);
        let glitch = |t| events_before(t, a, GLITCH_DELAY_NS, 2_000, |s| s == GLITCH_SECOND);
        let edges = |t| {
            events_before(t, a - 2_000, 0, 2_000, |s| {
                !(OUTAGE.0..OUTAGE.1).contains(&s)
            })
        };
        let (g, e, e_a) = (glitch(b), edges(b), edges(a));
        if g.0 != g.1 || glitch(a) != (0, 0) {
            continue;
        }
        judged += 1;
        glitches_seen += g.0;
        assert_eq!(
            u64::from(w[1].pps_rejected - w[0].pps_rejected),
            g.0,
            "glitches between heartbeats at {a} and {b} ns"
        );
        let counted = u64::from(w[1].pps_edges - w[0].pps_edges);
        assert!(
            (e.0.saturating_sub(e_a.1)..=e.1 - e_a.0).contains(&counted),
            "{counted} edges between heartbeats at {a} and {b} ns, expected {}..={}",
            e.0.saturating_sub(e_a.1),
            e.1 - e_a.0
        );
    }
    println!("{judged} heartbeat intervals judged, {glitches_seen} glitches in them");
    assert!(judged >= 10 && glitches_seen >= 1);

    // The status counters against the script, between the last record before the command
    // and the last before its reply.
    let in_range = |key: &str, (lo, _): (u64, u64), (_, hi): (u64, u64)| {
        let v = field(&status, key);
        assert!((lo..=hi).contains(&v), "{key} = {v}, expected {lo}..={hi}");
        v
    };
    let since_lock = |offset, pick: fn(u64) -> bool, margin| {
        (
            events_before(t_lo, lock_ns, offset, margin, pick),
            events_before(t_hi, lock_ns, offset, margin, pick),
        )
    };
    let (a, b) = since_lock(GLITCH_DELAY_NS, |s| s == GLITCH_SECOND, 1_000_000);
    let glitches = in_range("pps_glitches", a, b);
    // A missed second is counted at the first sample after its edge's window closes.
    let (a, b) = since_lock(0, |s| (OUTAGE.0..OUTAGE.1).contains(&s), 30_000_000);
    let missed = in_range("pps_missed", a, b);
    // Corrupted RMCs since boot (the receiver runs in free mode too): complete 100..130 ms
    // after their edge.
    let corrupt = |t| {
        let lo = events_before(t, 0, NMEA_DELAY_NS + 200_000_000, 0, |s| {
            s == CORRUPT_SECOND
        })
        .0;
        let hi = events_before(t, 0, NMEA_DELAY_NS, 0, |s| s == CORRUPT_SECOND).1;
        (lo, hi)
    };
    let errors = in_range("nmea_errors", corrupt(t_lo), corrupt(t_hi));
    assert_eq!(field(&status, "pps_locks"), 1);
    // The capture path lost nothing: one edge per interrupt, no sample merged.
    assert_eq!(field(&status, "pps_overcaptures"), 0);
    assert_eq!(field(&status, "merged_samples"), 0);
    assert_eq!(field(&status, "samples_lost"), 0);
    assert!(glitches >= 1 && missed >= 3 && errors >= 1);
    let second_ticks = field(&status, "second_ticks");
    assert!(
        second_ticks.abs_diff(SECOND_NS) <= 100,
        "measured second {second_ticks} ticks"
    );
    println!(
        "status: pps_glitches = {glitches}, pps_missed = {missed}, nmea_errors = {errors}, \
         second_ticks = {second_ticks} (receiver: {SECOND_NS})"
    );

    // Replay the counts through the core integrator from the reset: bit-exact across the
    // lock, the holdover and the reacquisition.
    let r0 = (reset_from..records.len())
        .find(|&i| {
            let r = &records[i];
            r.x == 10.0 && r.y == 20.0 && r.heading == 0.5 && r.sigma_x == 0.0
        })
        .expect("a record carries the reset pose");
    support::qemu::assert_replay_bit_exact(&Settings::DEFAULT.chassis, &records[r0..]);
    println!(
        "replayed {} records bit-exact from record {}",
        records.len() - r0 - 1,
        records[r0].sequence
    );
    assert!(r0 < lock_at, "the replay covers the lock");
}
