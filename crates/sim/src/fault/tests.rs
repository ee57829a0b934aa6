use super::*;
use crate::segment::Segment;
use ecsync_wire::{Command, EcatFrame};

const DEMO: &str = r#"
epoch = "cyclic"
[[fault]]
at_s = 0
kind = "loss"
probability = 0.05

[[fault]]
at_s = 20
kind = "power_cycle"
slave = "reference"

[[fault]]
at_s = 40
for_s = 0.05
kind = "link_down"
slave = 3

[[fault]]
at_s = 60
kind = "host_stall"
stall_ms = 10
"#;

#[test]
fn the_built_in_demo_parses() {
    let s = FaultSchedule::load(std::path::Path::new("faults-demo")).unwrap();
    assert_eq!(s.faults.len(), 4);
    assert_eq!(s.faults[1].at_ns, 20_000_000_000);
}

#[test]
fn parses_the_demo() {
    let s = FaultSchedule::parse("f.toml", DEMO).unwrap();
    assert_eq!(s.faults.len(), 4);
    assert_eq!(
        s.faults[1],
        Fault {
            at_ns: 20_000_000_000,
            for_ns: Some(DEFAULT_OFF_NS),
            kind: FaultKind::PowerCycle {
                slave: SlaveRef::Reference
            }
        }
    );
    assert_eq!(
        s.faults[2].kind,
        FaultKind::LinkDown {
            slave: SlaveRef::Position(2),
            port: 1
        }
    );
    assert!(s.has_host_faults());
}

#[test]
fn an_al_error_takes_a_code_and_refuses_none() {
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"al_error\"\nslave = 2\n\n[[fault]]\nat_s = 2\nkind = \"al_error\"\nslave = \"reference\"\ncode = 0x002C\n",
    )
    .unwrap();
    assert_eq!(
        s.faults[0].kind,
        FaultKind::AlError {
            slave: SlaveRef::Position(1),
            code: 0x001A
        }
    );
    assert_eq!(
        s.faults[1].kind,
        FaultKind::AlError {
            slave: SlaveRef::Reference,
            code: 0x002C
        }
    );
    for bad in ["0", "65536", "-1"] {
        let e = FaultSchedule::parse(
            "f.toml",
            &format!("[[fault]]\nat_s = 1\nkind = \"al_error\"\nslave = 2\ncode = {bad}\n"),
        )
        .unwrap_err();
        assert_eq!(e.field, "fault[0].code", "{bad}: {e}");
        assert!(e.fix.contains("0x001A"), "{e}");
    }
    // A parameter it does not take.
    let e = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"al_error\"\nport = 1\nslave = 2\n",
    )
    .unwrap_err();
    assert_eq!(e.field, "fault[0].port", "{e}");
}

#[test]
fn errors_name_the_entry_the_field_and_the_fix() {
    let text = "[[fault]]\nat_s = 1\nkind = \"loss\"\nframes = 2\n\n[[fault]]\nat_s = 2\nkind = \"loss\"\nprobability = 1.5\n";
    let e = FaultSchedule::parse("f.toml", text).unwrap_err();
    assert_eq!(e.field, "fault[1].probability");
    assert_eq!(e.line, Some(9));
    assert!(e.fix.contains("0 to 1"), "{e}");
    let e = FaultSchedule::parse("f.toml", "[[fault]]\nat_s = 1\nkind = \"loss\"\n").unwrap_err();
    assert_eq!(e.field, "fault[0].probability");
    let e = FaultSchedule::parse("f.toml", "[[fault]]\nat_s = 1\nkind = \"lost\"\n").unwrap_err();
    assert!(e.to_string().contains("unknown fault kind \"lost\""), "{e}");
    assert_eq!(e.line, Some(3));
    let e = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"delay\"\nextra_us = 5\nslave = 2\n",
    )
    .unwrap_err();
    assert_eq!(e.field, "fault[0].slave");
    assert!(e.message.contains("takes no slave"), "{e}");
    let e = FaultSchedule::parse("f.toml", "[[fault]]\nat_s = -1\nkind = \"delay\"\n").unwrap_err();
    assert_eq!(e.field, "fault[0].at_s");
    let e = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"power_cycle\"\nslave = 0\n",
    )
    .unwrap_err();
    assert!(e.fix.contains("reference"), "{e}");
}

#[test]
fn the_same_frames_are_lost_whatever_else_happens() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.3\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(3, 1)).unwrap();
    let frame = [0u8; 60];
    let mut a = FaultPlayer::new(s.clone(), 5);
    let mut b = FaultPlayer::new(s, 5);
    let fa: Vec<bool> = (0..10_000)
        .map(|k| {
            let f = a.before_frame(&mut seg, &frame, k * 1_000_000_000);
            f.lost_out || f.lost_back
        })
        .collect();
    // The other player's frames come at other times: the same ones are lost.
    let fb: Vec<bool> = (0..10_000)
        .map(|k| {
            let f = b.before_frame(&mut seg, &frame, k * 1_000_000_000 + 7_777);
            f.lost_out || f.lost_back
        })
        .collect();
    assert_eq!(fa, fb);
    let lost = fa.iter().filter(|&&l| l).count();
    assert!((2_700..3_300).contains(&lost), "{lost} of 10 000 at 30 %");
}

/// A broadcast read's working counter: the slaves it reached.
fn count(seg: &mut Segment, p: &mut FaultPlayer, t_ps: u64) -> u16 {
    let mut buf = [0u8; 60];
    let mut b = ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
    b.push_zeroed(
        Command::Brd,
        0,
        ecsync_wire::DatagramAddress::position(0, 0),
        1,
    )
    .unwrap();
    let n = b.finish();
    let fate = p.before_frame(seg, &buf[..n], t_ps);
    assert!(!fate.lost_out && !fate.lost_back);
    seg.process(&mut buf[..n], t_ps);
    let f = EcatFrame::new_checked(&buf[..n]).unwrap();
    f.datagrams().next().unwrap().unwrap().wkc()
}

#[test]
fn hot_connected_slaves_appear_at_their_time() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0.01\nkind = \"hot_connect\"\nslaves = 2\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    assert_eq!(
        count(&mut seg, &mut p, 0),
        3,
        "the last two are not connected yet"
    );
    assert_eq!(count(&mut seg, &mut p, 5_000_000_000), 3);
    assert_eq!(
        count(&mut seg, &mut p, 20_000_000_000),
        5,
        "connected at 10 ms"
    );
    assert_eq!(p.events()[0].detail, "slaves 4 to 5 connected");
}

#[test]
fn a_pulled_cable_and_a_power_cycle_cut_the_segment_behind() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0.01\nfor_s = 0.01\nkind = \"link_down\"\nslave = 2\n\n[[fault]]\nat_s = 0.03\nfor_s = 0.01\nkind = \"power_cycle\"\nslave = 4\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    let ms = |m: u64| m * 1_000_000_000;
    assert_eq!(count(&mut seg, &mut p, 0), 5);
    assert_eq!(
        count(&mut seg, &mut p, ms(15)),
        2,
        "slaves 3-5 behind the cable"
    );
    assert_eq!(count(&mut seg, &mut p, ms(25)), 5, "plugged in again");
    assert_eq!(
        count(&mut seg, &mut p, ms(35)),
        3,
        "slave 4 off: 4 and 5 gone"
    );
    assert!(seg.is_powered_off(3));
    assert_eq!(count(&mut seg, &mut p, ms(45)), 5, "on again");
    assert_eq!(
        seg.esc(3).al_state(),
        ecsync_wire::AlState::Init,
        "from reset"
    );
}

#[test]
fn a_burst_takes_its_frames_in_a_row() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0.0105\nkind = \"loss\"\nframes = 3\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(2, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    let lost: Vec<u64> = (0..30u64)
        .filter(|&k| {
            let f = p.before_frame(&mut seg, &[0u8; 60], k * 1_000_000_000);
            f.lost_out || f.lost_back
        })
        .collect();
    assert_eq!(lost, vec![11, 12, 13]);
}
