//! The frame decoder on any byte stream (what a serial link delivers).
//!
//! Oracles: no panic; every frame it accepts re-encodes to a frame that decodes to the same
//! bytes again; the counters add up to the results returned; after any garbage, a 0x00 and
//! a valid frame, that frame is decoded (the decoder resynchronises).
#![no_main]

use libfuzzer_sys::fuzz_target;
use odo_unit::protocol::FrameDecoder;
use odo_unit::protocol::{encode_frame, CommandReply, Frame, Message, MAX_ENCODED_FRAME};

fn encode(frame: &Frame) -> Vec<u8> {
    let mut out = [0u8; MAX_ENCODED_FRAME];
    let n = encode_frame(&frame.message, frame.seq, &mut out).expect("a decoded frame encodes");
    out[..n].to_vec()
}

fuzz_target!(|data: &[u8]| {
    let mut d = FrameDecoder::new();
    let (mut ok, mut errors) = (0u32, 0u32);
    d.feed(data, |r| match r {
        Ok(frame) => {
            ok += 1;
            let bytes = encode(&frame);
            let mut again = FrameDecoder::new();
            let mut back = Vec::new();
            again.feed(&bytes, |r| back.push(r));
            assert_eq!(back.len(), 1, "{frame:?}");
            let back = back.pop().unwrap().expect("re-encoded frame decodes");
            assert_eq!(encode(&back), bytes, "{frame:?}");
        }
        Err(_) => errors += 1,
    });
    let s = d.stats();
    assert_eq!(s.frames, ok);
    let counted = s.crc_errors + s.oversize + s.malformed + s.version_errors + s.unknown_type;
    assert_eq!(counted, errors, "{s:?}");

    // Resynchronisation: a delimiter and one valid frame after the garbage.
    let reply = CommandReply::chunks(true, "ok\nrate = 50").next().unwrap();
    let known = Frame {
        seq: 7,
        message: Message::Reply(reply),
    };
    let mut tail = vec![0u8];
    tail.extend(encode(&known));
    let mut last = None;
    d.feed(&tail, |r| last = Some(r));
    assert_eq!(last, Some(Ok(known)));
});
