//! Malformed input never panics: random bytes, and random corruptions of valid frames, through
//! the wire parser and the whole segment (every ESC processes what reaches it). The same checks
//! run under libFuzzer in `fuzz/` (cargo fuzz run segment).

use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};
use proptest::prelude::*;

fn valid_cyclic_frame() -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0, 1, 2, 3, 4, 5]).unwrap();
    b.push_zeroed(
        Command::Frmw,
        0,
        DatagramAddress::Configured {
            adp: 0x1000,
            ado: 0x0910,
        },
        8,
    )
    .unwrap();
    b.push_zeroed(Command::Lrw, 1, DatagramAddress::Logical(0), 204)
        .unwrap();
    b.push_zeroed(Command::Bwr, 2, DatagramAddress::position(0, 0x0900), 4)
        .unwrap();
    b.push_zeroed(Command::Aprw, 3, DatagramAddress::position(1, 0x0502), 6)
        .unwrap();
    b.push_zeroed(Command::Brd, 4, DatagramAddress::position(0, 0x092c), 4)
        .unwrap();
    let n = b.finish();
    buf.truncate(n);
    buf
}

/// Everything the parsers and the segment do with a frame; must not panic.
fn exercise(seg: &mut Segment, bytes: &mut [u8], t_ps: u64) {
    if let Ok(f) = EcatFrame::new_checked(&bytes[..]) {
        for d in f.datagrams().flatten() {
            let _ = (d.command(), d.address(), d.data(), d.wkc(), d.irq());
        }
    }
    let _ = seg.process(bytes, t_ps);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2_000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes(mut bytes in proptest::collection::vec(any::<u8>(), 0..1600), t in any::<u32>()) {
        let mut seg = Segment::new(&preset::line(3, 9)).unwrap();
        exercise(&mut seg, &mut bytes, u64::from(t) * 1000);
    }

    #[test]
    fn random_bytes_behind_a_valid_header(mut tail in proptest::collection::vec(any::<u8>(), 0..1500), len in 0u16..0x800) {
        // An Ethernet + EtherCAT header whose length field claims anything.
        let mut bytes = vec![0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0, 1, 2, 3, 4, 5, 0x88, 0xa4];
        bytes.extend_from_slice(&(len | 0x1000).to_le_bytes());
        bytes.append(&mut tail);
        let mut seg = Segment::new(&preset::line(4, 3)).unwrap();
        exercise(&mut seg, &mut bytes, 1_000_000);
    }

    #[test]
    fn corrupted_valid_frames(flips in proptest::collection::vec((any::<u16>(), any::<u8>()), 1..16), cut in any::<u16>()) {
        let mut frame = valid_cyclic_frame();
        for (at, v) in flips {
            let i = usize::from(at) % frame.len();
            frame[i] = v;
        }
        let keep = usize::from(cut) % (frame.len() + 1);
        frame.truncate(keep.max(frame.len() / 2));
        let mut seg = Segment::new(&preset::paper_2024()).unwrap();
        // Several frames in a row, so state changes by one (addresses, FMMUs, EEPROM commands,
        // AL requests) meet the next.
        for k in 0..4u64 {
            let mut f = frame.clone();
            exercise(&mut seg, &mut f, (k + 1) * 1_000_000_000);
        }
    }
}

#[test]
fn a_frame_with_a_broken_chain_is_forwarded_untouched() {
    let mut frame = valid_cyclic_frame();
    // Claim 2000 bytes of data in the second datagram: the chain overruns the frame.
    let at = 16 + 20 + 6;
    frame[at..at + 2].copy_from_slice(&(2000u16 | 0x8000).to_le_bytes());
    let before = frame.clone();
    let mut seg = Segment::new(&preset::paper_2024()).unwrap();
    let out = seg.process(&mut frame, 1_000_000);
    assert!(!out.processed);
    assert!(out.returned_sof_ps.is_some(), "forwarded, not lost");
    assert_eq!(&frame[12..], &before[12..], "datagrams untouched");
    assert_eq!(seg.frame_counts().1, 1, "counted as malformed");
}

#[test]
fn a_non_ethercat_frame_is_destroyed() {
    let mut frame = valid_cyclic_frame();
    frame[12] = 0x08;
    frame[13] = 0x00;
    let mut seg = Segment::new(&preset::paper_2024()).unwrap();
    let out = seg.process(&mut frame, 1_000_000);
    assert_eq!(out.returned_sof_ps, None);
}
