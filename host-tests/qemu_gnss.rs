//! End-to-end test of GNSS sentence forwarding in QEMU (`netduinoplus2`), run by `.ci/run`
//! after it has built the `qemu` image (see `host-tests/qemu_e2e.rs` for how, and when the
//! test is skipped).
//!
//! The simulated receiver (`src/board/qemu/gnss.rs`) sends RMC, GGA, GST and HDT at 10 Hz
//! (and ZDA once a second) at 38,400 baud; the unit samples at 50 Hz and sends every sample
//! (`output_divider` 1) on its 115,200-baud link. Over 12 s of emulated time: every pose
//! record arrives (no gap in the sequence, nothing dropped), the sentences arrive whole with
//! valid checksums, numbered without a gap, 10 a second of each kind, timed on the records'
//! clock as the receiver sent them, and the Status counters agree with what arrived.

use std::path::Path;
use std::time::Duration;

use odo_unit::protocol::{GnssSentence, Message, Status};

mod support;
use support::qemu::UnitLink;

/// Emulated time to read, microseconds.
const READ_US: u64 = 12_000_000;
/// Wall-clock limit of the whole test.
const DEADLINE: Duration = Duration::from_secs(120);
/// The simulated receiver (src/board/qemu/gnss.rs): MCU ticks (ns) of GNSS second 0, one
/// GNSS second, the delay of an epoch's sentences, epochs per second, one byte at 38,400
/// baud.
const FIRST_EDGE_NS: u64 = 250_000_000;
const SECOND_NS: u64 = 1_000_037_000;
const NMEA_DELAY_NS: u64 = 100_000_000;
const EPOCH_HZ: u64 = 10;
const BYTE_NS: u64 = 10 * 1_000_000_000 / 38_400;

/// True when the text's `*hh` is the XOR of the bytes between `$` and `*`.
fn checksum_ok(text: &str) -> bool {
    let Some((body, sum)) = text[1..].rsplit_once('*') else {
        return false;
    };
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    u8::from_str_radix(sum, 16) == Ok(x) && sum.len() == 2
}

/// Seconds of day of an NMEA `hhmmss.ss` field.
fn seconds_of_day(field: &str) -> f64 {
    let h: f64 = field[0..2].parse().unwrap();
    let m: f64 = field[2..4].parse().unwrap();
    let s: f64 = field[4..].parse().unwrap();
    h * 3600.0 + m * 60.0 + s
}

#[test]
fn qemu_gnss_forwarding() {
    let Some(qemu) = support::qemu::boot(Path::new(env!("CARGO_MANIFEST_DIR")), "qemu_gnss") else {
        return;
    };
    let mut link = UnitLink::connect(qemu.port, DEADLINE);
    // Records flow from boot: the unit listens from then on.
    while link.records.len() < 5 {
        link.next_frame();
    }
    let (ok, text) = link.command("set rate 50 output_divider 1 baud 115200 output frames");
    assert!(ok, "{text}");
    // Read until 12 s of records, then one more Status.
    while link.records.last().is_none_or(|r| r.mcu_time_us < READ_US) {
        link.next_frame();
    }
    let until = link.heartbeats.len();
    while link.heartbeats.len() == until {
        link.next_frame();
    }

    // Every record: consecutive sequence numbers, none dropped.
    let seqs: Vec<u32> = link.records.iter().map(|r| r.sequence).collect();
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "record sequence gap"
    );
    assert!(link.records.iter().all(|r| r.dropped == 0));
    let last_status: &Status = link.heartbeats.last().unwrap();
    assert_eq!(last_status.dropped_total, 0);
    assert_eq!(last_status.samples_lost, 0);

    // The sentences, in stream order, with the Status after them.
    let mut sentences: Vec<GnssSentence> = Vec::new();
    let mut checked_status = 0;
    for f in &link.frames {
        match &f.message {
            Message::Gnss(s) => sentences.push(s.clone()),
            Message::Status(st) => {
                // Each Status counts exactly the sentences before it in the stream.
                assert_eq!(st.gnss_forwarded as usize, sentences.len());
                assert_eq!(st.gnss_not_forwarded, 0);
                assert_eq!(st.gnss_overlong, 0);
                checked_status += 1;
            }
            _ => {}
        }
    }
    assert!(checked_status >= 12);
    let numbers: Vec<u32> = sentences.iter().map(|s| s.number).collect();
    assert_eq!(numbers, (0..sentences.len() as u32).collect::<Vec<_>>());
    assert!(
        sentences.iter().all(|s| checksum_ok(&s.text)),
        "bad checksum forwarded"
    );

    // 10 a second of each kind: every epoch from the first, none missing (HDT carries no
    // time: as many as RMC, give or take the epoch on the line at the end).
    let epochs = |kind: &str| -> Vec<i64> {
        sentences
            .iter()
            .filter(|s| &s.text[3..6] == kind)
            .map(|s| {
                let sod = seconds_of_day(s.text.split(',').nth(1).unwrap()) - 12.0 * 3600.0;
                (sod * EPOCH_HZ as f64).round() as i64
            })
            .collect()
    };
    let rmc = epochs("RMC");
    assert!(
        rmc.len() as u64 > READ_US / 1_000_000 * EPOCH_HZ,
        "{} RMC",
        rmc.len()
    );
    // The RMC of each 20 s lap's second 5 is corrupted on the line (not forwarded).
    let corrupt = |e: &i64| *e % (20 * EPOCH_HZ as i64) == 5 * EPOCH_HZ as i64;
    for kind in ["RMC", "GGA", "GST"] {
        let e = epochs(kind);
        let last = *e.last().unwrap();
        let expect: Vec<i64> = (0..=last)
            .filter(|e| kind != "RMC" || !corrupt(e))
            .collect();
        assert_eq!(e, expect, "{kind}: epochs missing");
    }
    let gga = epochs("GGA").len();
    let hdt = sentences.iter().filter(|s| &s.text[3..6] == "HDT").count();
    assert!(hdt.abs_diff(gga) <= 1 && rmc.len().abs_diff(gga) <= 2);
    // GGA: RTK fixed; GST: the simulated sigmas.
    for s in sentences.iter().filter(|s| s.text.starts_with("$GPGGA")) {
        assert_eq!(s.text.split(',').nth(6), Some("4"), "{}", s.text);
    }
    for s in sentences.iter().filter(|s| s.text.starts_with("$GPGST")) {
        assert!(s.text.contains(",0.005,0.005,0.010*"), "{}", s.text);
    }

    // Timing: a sentence of epoch e (its UTC time from 12:00:00) leaves the receiver 100 ms
    // after the epoch; its line end reaches the unit within the bytes of its epoch plus one
    // 20 ms sample period (QEMU delivers bytes at the sample instants).
    let mut checked = 0;
    for s in sentences.iter().filter(|s| !s.text.starts_with("$GPHDT")) {
        let time = s.text.split(',').nth(1).unwrap();
        let e = ((seconds_of_day(time) - 12.0 * 3600.0) * EPOCH_HZ as f64).round() as u64;
        let epoch_ns =
            FIRST_EDGE_NS + e / EPOCH_HZ * SECOND_NS + e % EPOCH_HZ * SECOND_NS / EPOCH_HZ;
        let sent_ns = epoch_ns + NMEA_DELAY_NS;
        let at_ns = s.mcu_time_us * 1000;
        assert!(
            at_ns > sent_ns && at_ns < sent_ns + 400 * BYTE_NS + 20_000_000,
            "{}: at {} us, epoch sent at {} us",
            s.text,
            s.mcu_time_us,
            sent_ns / 1000
        );
        checked += 1;
    }
    assert!(checked > 300);

    // `status` agrees: the corrupted RMC of lap second 5 is the only bad line.
    let (_, status) = link.command("status");
    let line = status
        .lines()
        .find(|l| l.starts_with("gnss_forwarded = "))
        .expect("gnss line in status");
    println!("{line}");
    assert!(line.contains("gnss_not_forwarded = 0, gnss_bad_checksum = 1, gnss_overlong = 0"));
    drop(qemu);
}
