//! Any text as a fault schedule: parsed without a panic, and a schedule that parses played on a
//! small segment for a few hundred frames without one either.
#![no_main]

use ecsync_sim::fault::{FaultPlayer, FaultSchedule};
use ecsync_sim::{Segment, preset};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(s) = FaultSchedule::parse("fuzz.toml", text) else {
        return;
    };
    let Ok(mut seg) = Segment::new(&preset::line(4, 1)) else {
        return;
    };
    let mut p = FaultPlayer::new(s, 1);
    // An LRW (the cyclic epoch) every 10 ms.
    let mut frame = [0u8; 60];
    let mut b = ecsync_wire::FrameBuilder::new(&mut frame, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
    b.push_zeroed(
        ecsync_wire::Command::Lrw,
        0,
        ecsync_wire::DatagramAddress::Logical(0),
        8,
    )
    .unwrap();
    let n = b.finish();
    for k in 0..300u64 {
        let t = k * 10_000_000_000;
        let _ = p.before_frame(&mut seg, &frame[..n], t);
        let _ = p.host_faults(t);
        let mut f = frame;
        let _ = seg.process(&mut f[..n], t);
    }
});
