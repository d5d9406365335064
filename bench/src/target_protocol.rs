//! Instruction counts of the frame encoder, the frame decoder and the command parser on the
//! Cortex-M4F (see `target.rs` for the method), as rows of its instruction table.

use core::hint::black_box;
use odo_unit::console::{execute, parse};
use odo_unit::protocol::{encode_frame, FrameDecoder, Message, PoseRecord, MAX_ENCODED_FRAME};
use odo_unit::settings::Settings;

use crate::target::{count, report, stack_used};

/// What the protocol benchmarks measure besides instructions.
pub struct Protocol {
    /// A pose frame on the wire, bytes.
    pub frame_bytes: usize,
    /// Stack of one frame encoding with its output buffer, bytes.
    pub encode_stack: usize,
}

/// Runs the protocol benchmarks: prints their rows of the instruction table.
pub fn run(overhead: u32) -> Protocol {
    let mut v = [0u32; 64];
    let mut frame = [0u8; MAX_ENCODED_FRAME];
    let mut len = 0;
    for (k, slot) in v.iter_mut().enumerate() {
        let record = PoseRecord {
            sequence: k as u32,
            mcu_time_us: 20_000 * k as u64,
            x: 12.345 + k as f64,
            y: -3.25 * k as f64,
            heading: 0.1 * k as f64,
            sigma_x: 1e-3,
            sigma_y: 2e-3,
            sigma_heading: 1e-4,
            gamma_left: 1_000_000 + 137 * k as i64,
            gamma_right: -5 * k as i64,
            ..PoseRecord::default()
        };
        let msg = Message::Pose(record);
        *slot = count(overhead, || {
            len = encode_frame(black_box(&msg), k as u32, &mut frame).unwrap_or(0);
            black_box(&frame);
        });
    }
    report("frame encoder, one pose frame (COBS + CRC-32)", &mut v);

    let mut decoder = FrameDecoder::new();
    for slot in v.iter_mut() {
        *slot = count(overhead, || {
            decoder.feed(black_box(&frame[..len]), |f| {
                black_box(f.is_ok());
            });
        });
    }
    report("frame decoder, one pose frame", &mut v);

    let lines = [
        "set left_diameter 0.2608",
        "set left_diameter 0.2608 right_diameter 0.2607 track_width 0.5656",
        "get track_width",
        "reset_pose 1.5 -2 0.25",
        "mode pps",
        "rate 100",
        "set track_width nan",
        "frobnicate",
    ];
    let mut parse_counts = [0u32; 8];
    for (slot, line) in parse_counts.iter_mut().zip(lines) {
        *slot = count(overhead, || {
            black_box(parse(black_box(line)).is_ok());
        });
    }
    report("command parser, 8 lines", &mut parse_counts);
    let mut settings = Settings::DEFAULT;
    for (slot, line) in parse_counts.iter_mut().zip(lines) {
        *slot = count(overhead, || {
            let (reply, action) = execute(black_box(line), &mut settings);
            black_box((&reply, &action));
        });
    }
    report(
        "command execution with its reply, 8 lines",
        &mut parse_counts,
    );

    let record = Message::Pose(PoseRecord {
        x: 1.0,
        ..PoseRecord::default()
    });
    let used = stack_used(|| {
        let mut out = [0u8; MAX_ENCODED_FRAME];
        black_box(encode_frame(black_box(&record), 7, &mut out).is_ok());
        black_box(&out);
    });
    Protocol {
        frame_bytes: len,
        encode_stack: used,
    }
}
