//! GNSS sentence forwarding (`odo_unit::unit::forward`): which received lines become
//! GnssSentence frames, their numbers, times and counters, the room rule against the transmit
//! ring, and the settings that go with it (`gnss_baud`, the bandwidth budget).

use odo_unit::protocol::{
    encode_frame, GnssSentence, Message, PoseRecord, Queued, Status, TxLink, MAX_ENCODED_FRAME,
};
use odo_unit::settings::{Key, SetManyError, SettingError, Settings, Value};
use odo_unit::timing::SyncMode;
use odo_unit::unit::forward::{
    encoded_frame_len, is_forwarded_kind, sentence_reserve, POSE_STREAM_NEED,
};
use odo_unit::unit::{GnssCounters, Processor};

mod support;
use support::budget::assert_budget_row;

/// Sample timer ticks per second.
const HZ: u32 = 84_000_000;
/// The firmware's transmit ring and the room pose records leave for replies (src/host_link.rs).
const TX_BUF: usize = 4096;
const RECORD_RESERVE: usize = 1024;

/// `$body*hh` with the right checksum.
fn nmea(body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}")
}

fn processor(settings: &Settings) -> Processor {
    Processor::new(settings, HZ, [32, 16])
}

/// Feeds `bytes` (each line ending stamped at tick `at`); returns the sentences to queue,
/// reporting each as queued (`queued`).
fn feed(p: &mut Processor, bytes: &[u8], at: u32, queued: bool) -> Vec<GnssSentence> {
    let mut out = Vec::new();
    for &b in bytes {
        let line_end = matches!(b, b'\r' | b'\n').then_some(at);
        if let Some(s) = p.on_nmea_byte(b, line_end) {
            p.gnss_sent(queued);
            out.push(s);
        }
    }
    out
}

fn counters(p: &mut Processor) -> GnssCounters {
    p.gnss_counters()
}

#[test]
fn kinds_forwarded_by_address() {
    for (line, forwarded) in [
        ("$GPGGA,1", true),
        ("$GNGGA,1", true),
        ("$GAGST,1", true),
        ("$HEHDT,1", true),
        ("$GNRMC,1", true),
        ("$GPZDA,1", true),
        ("$GPGGA*00", true),
        ("$GPGSV,1", false),
        ("$GPGSA,1", false),
        ("$GPVTG,1", false),
        ("$PUBX,00", false),
        ("$GPGGAX,1", false),
        ("$GPGG,1", false),
        ("GPGGA,1", false),
        ("$G-GGA,1", false),
        ("", false),
    ] {
        assert_eq!(is_forwarded_kind(line.as_bytes()), forwarded, "{line}");
    }
}

/// What each kind of line does: forwarded (with its number), counted, or ignored; line
/// endings CR, LF, CR LF and LF CR all end a line once.
#[test]
fn lines_forwarded_counted_or_ignored() {
    let gga =
        nmea("GPGGA,120000.10,5005.3321000,N,01425.4156000,E,4,12,0.7,300.000,M,45.000,M,1.0,0001");
    let gst = nmea("GNGST,120000.10,0.007,0.005,0.005,0.0,0.005,0.005,0.010");
    let hdt = nmea("GPHDT,123.45,T");
    let gsv = nmea("GPGSV,3,1,12,01,40,083,46");
    let mut bad =
        nmea("GPGGA,120000.20,5005.3321000,N,01425.4156000,E,4,12,0.7,300.000,M,45.000,M,1.0,0001");
    bad.replace_range(10..11, "1"); // a bit error after the checksum was computed
    let no_sum = "$GPGGA,120000.30,5005.3321000,N".to_string();
    let long = nmea(&format!("GPGGA,{}", "1".repeat(100)));
    let stream = format!("{gga}\r\n{gsv}\n{bad}\r{no_sum}\n\r{gst}\n{long}\r\n{hdt}\n\r\n\n");
    let mut p = processor(&Settings::DEFAULT);
    let got = feed(&mut p, stream.as_bytes(), 84_000, true);
    let texts: Vec<&str> = got.iter().map(|s| s.text.as_str()).collect();
    assert_eq!(texts, [gga.as_str(), gst.as_str(), hdt.as_str()]);
    assert_eq!(got.iter().map(|s| s.number).collect::<Vec<_>>(), [0, 1, 2]);
    // The line ending at tick 84,000 of an 84 MHz timer: 1 ms after start.
    assert!(got.iter().all(|s| s.mcu_time_us == 1000));
    assert_eq!(
        counters(&mut p),
        GnssCounters {
            forwarded: 3,
            not_forwarded: 0,
            bad_checksum: 2,
            overlong: 1,
        }
    );
}

/// A sentence the link had no room for keeps its number: the next frame's number jumps,
/// and the counters add up to the sentences received.
#[test]
fn not_forwarded_sentences_leave_a_gap_in_the_numbers() {
    let mut p = processor(&Settings::DEFAULT);
    let line = format!(
        "{}\r\n",
        nmea("GPRMC,120000.00,A,5005.3321,N,01425.4156,E,0.02,0.00,211126,,,A")
    );
    let mut numbers = Vec::new();
    for queued in [true, false, false, true] {
        numbers.extend(
            feed(&mut p, line.as_bytes(), 0, queued)
                .iter()
                .map(|s| s.number),
        );
    }
    assert_eq!(numbers, [0, 1, 2, 3]);
    let c = counters(&mut p);
    assert_eq!((c.forwarded, c.not_forwarded), (2, 2));
}

/// `output = mavlink`: nothing is forwarded; every sentence counts as not forwarded.
#[test]
fn mavlink_output_forwards_nothing() {
    let mut s = Settings::DEFAULT;
    s.set_many([("output", "mavlink"), ("rate", "40")]).unwrap();
    let mut p = processor(&s);
    let line = format!("{}\n", nmea("GPHDT,1.00,T"));
    assert!(feed(&mut p, line.repeat(3).as_bytes(), 0, true).is_empty());
    assert_eq!(counters(&mut p).not_forwarded, 3);
    assert_eq!(counters(&mut p).forwarded, 0);
}

/// The line-end tick is the low 32 bits of the timeline, extended next to the last
/// sample's tick (here tick 0): a tick just before the wrap is a little before start.
#[test]
fn line_end_time_is_the_interrupts_tick() {
    let mut p = processor(&Settings::DEFAULT);
    let line = format!("{}\n", nmea("GPHDT,1.00,T"));
    let got = feed(&mut p, line.as_bytes(), 8_400_000, true);
    assert_eq!(got[0].mcu_time_us, 100_000);
}

/// Encoded frame of `msg`.
fn frame(msg: &Message) -> Vec<u8> {
    let mut buf = [0u8; MAX_ENCODED_FRAME];
    let n = encode_frame(msg, 0, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// A link whose ring has exactly `free` bytes free.
fn link_with_free(free: usize) -> TxLink<TX_BUF> {
    let mut link = TxLink::new();
    assert!(link.queue_raw(&vec![1u8; TX_BUF - free], 0));
    link
}

/// The room rule at its boundary: a sentence frame is queued when the ring keeps
/// `sentence_reserve` bytes after it, not one byte less; and when it is queued, the next
/// Status and pose record still fit with the records' own reserve.
#[test]
fn room_rule_boundary() {
    assert_eq!(POSE_STREAM_NEED, 106 + 114);
    assert_eq!(
        encoded_frame_len(Status::BODY_LEN),
        frame(&Status::default().into()).len()
    );
    assert_eq!(
        encoded_frame_len(PoseRecord::BODY_LEN),
        frame(&PoseRecord::default().into()).len()
    );
    let mut s = GnssSentence::default();
    s.text
        .push_str(&nmea(
            "GPGGA,120000.10,5005.3321000,N,01425.4156000,E,4,12,0.7,300.000,M,45.000,M,1.0,0001",
        ))
        .unwrap();
    let sentence = frame(&Message::Gnss(s));
    let reserve = sentence_reserve(RECORD_RESERVE);
    for (free, queued) in [
        (sentence.len() + reserve, true),
        (sentence.len() + reserve - 1, false),
        (TX_BUF, true),
        (reserve, false),
    ] {
        let mut link = link_with_free(free);
        let got = link.queue(0, &sentence, reserve);
        assert_eq!(got == Queued::Queued, queued, "free {free}");
        if queued {
            // What the pose stream queues at its next sample still fits.
            let status = frame(&Status::default().into());
            let record = frame(&PoseRecord::default().into());
            assert_eq!(link.queue(1, &status, RECORD_RESERVE), Queued::Queued);
            assert_eq!(link.queue(2, &record, RECORD_RESERVE), Queued::Queued);
        }
    }
}

#[test]
fn gnss_baud_setting() {
    let mut s = Settings::DEFAULT;
    assert_eq!(s.get(Key::GnssBaud), Value::U32(38_400));
    s.set_many([("gnss_baud", "115200")]).unwrap();
    assert_eq!(s.gnss_baud, 115_200);
    for bad in ["115201", "0", "1000000"] {
        let before = s;
        assert_eq!(
            s.set_many([("gnss_baud", bad)]),
            Err(SetManyError::Value(SettingError::OutOfRange(Key::GnssBaud)))
        );
        assert_eq!(s, before, "{bad}");
    }
    // Stored and loaded (format version 6), and a version 5 record loads at the default.
    let loaded = Settings::from_bytes(&s.to_bytes()).unwrap();
    assert_eq!(loaded.gnss_baud, 115_200);
    let v5 = &Settings::DEFAULT.to_bytes()[..Settings::SERIALIZED_LEN_V5];
    assert_eq!(
        Settings::from_bytes_version(5, v5).unwrap().gnss_baud,
        38_400
    );
    assert_eq!(Settings::SERIALIZED_LEN - Settings::SERIALIZED_LEN_V5, 4);
}

/// The budget at 115,200 baud in `output = frames`, `mode = pps`: records x 1140, Status 1060
/// and GNSS sentences 44,000 bit/s (61 records per second fit, 62 do not: the table test).
/// A refused `set` changes nothing and says why.
#[test]
fn bandwidth_budget_refuses_what_cannot_fit() {
    let mut s = Settings::DEFAULT;
    s.set_many([("mode", "pps"), ("rate", "50")]).unwrap();
    let before = s;
    let err = s.set_many([("rate", "100")]).unwrap_err();
    assert_eq!(err, SetManyError::Value(SettingError::RecordsOverBaud));
    assert_eq!(s, before);
    let text = err.to_string();
    assert!(
        text.starts_with("rate/output_divider: records need more than the baud rate"),
        "{text}"
    );
    assert!(
        text.contains("in pps mode also carries GNSS sentences, 44000 bit/s"),
        "{text}"
    );
    // Every second sample of 100 Hz fits; 50 Hz, every sample (the end-to-end test's
    // configuration), fits; 38,400 baud carries no frames output at all; MAVLink output
    // forwards no sentences, so its budget is as before (46 ODOMETRY frames a second fit
    // 115,200 baud, 47 do not).
    s.set_many([("rate", "100"), ("output_divider", "2")])
        .unwrap();
    s.set_many([("rate", "50"), ("output_divider", "1")])
        .unwrap();
    assert!(s.set_many([("baud", "38400")]).is_err());
    s.set_many([("rate", "40"), ("output", "mavlink")]).unwrap();
    assert!(s.set_many([("rate", "50")]).is_err());
    // Free-running (indoors) the sentences are not budgeted: they take only room left over,
    // so 100 records a second fit 115,200 baud (1140 bits each, plus Status), 101 do not.
    let mut free = Settings::DEFAULT;
    free.set_many([("mode", "free"), ("rate", "100")]).unwrap();
    assert!(free.set_many([("rate", "101")]).is_err());
    let mut free = Settings {
        rate: 1000,
        max_wheel_speed: 0.5,
        ..Settings::DEFAULT
    };
    free.set_many([("mode", "free"), ("output_divider", "10")])
        .unwrap();
    assert!(free.set_many([("output_divider", "9")]).is_err());
}

/// Our frames at `baud`, `rate`, `output_divider` in `mode = pps`: within the budget or not.
fn fits(baud: u32, rate: u32, divider: u32) -> bool {
    let s = Settings {
        baud,
        rate,
        output_divider: divider,
        mode: SyncMode::Pps,
        ..Settings::DEFAULT
    };
    s.link_bits_per_second() <= u64::from(baud)
}

/// The table of docs/PROTOCOL.md, *Bandwidth budget of the host link*, is the settings check.
#[test]
fn the_documented_budget_table_is_the_settings_check() {
    for baud in [9_600, 19_200, 38_400] {
        assert!(!fits(baud, 1, 1000), "{baud}");
    }
    // (baud, most records per second, divider at rate 50, divider at rate 1000)
    for (baud, most, at50, at1000) in [
        (57_600, 11, 5, 91),
        (115_200, 61, 1, 17),
        (230_400, 162, 1, 7),
        (460_800, 364, 1, 3),
        (921_600, 768, 1, 2),
    ] {
        assert_budget_row(fits, (baud, most, at50, at1000));
        let row = if at50 == 1 && baud != 115_200 {
            format!("| {baud} | {most} | 1 | {at1000} |")
        } else {
            format!("| {baud} | {most} | {at50} | {at1000} |")
        };
        let doc = include_str!("../docs/PROTOCOL.md");
        assert!(doc.contains(&row), "PROTOCOL.md lacks {row:?}");
    }
}
