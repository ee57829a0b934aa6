//! Any bytes, as a sequence of frames, through a six-slave segment: no panic, whatever the
//! frames do to the ESCs' state (addresses, FMMUs, EEPROM commands, AL requests, DC registers).
#![no_main]

use ecsync_sim::{Segment, preset};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

static SEGMENT: OnceLock<Segment> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let mut seg = SEGMENT
        .get_or_init(|| Segment::new(&preset::paper_2024()).expect("preset"))
        .clone();
    // Frames separated by 0xFF 0xFE; each processed 100 us after the previous.
    let mut t = 1_000_000u64;
    for chunk in data.split(|&b| b == 0xfe) {
        let mut frame = chunk.to_vec();
        let _ = seg.process(&mut frame, t);
        t += 100_000_000;
    }
});
