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

const S: u64 = 1_000_000_000_000;
const MS: u64 = 1_000_000_000;

/// A frame of one datagram of each command given (4 bytes each), for the epoch and the draws.
fn frame_of(commands: &[Command]) -> Vec<u8> {
    let mut buf = vec![0u8; 128];
    let mut b = ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
    for (i, &c) in commands.iter().enumerate() {
        let address = match c {
            Command::Lrd | Command::Lwr | Command::Lrw => {
                ecsync_wire::DatagramAddress::Logical(0x1_0000)
            }
            _ => ecsync_wire::DatagramAddress::position(0, 0x0130),
        };
        b.push_zeroed(c, i as u8, address, 4).unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

#[test]
fn a_power_cycle_between_two_frames_happens_at_its_time() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 3.0\nfor_s = 0.5\nkind = \"power_cycle\"\nslave = 2\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    assert_eq!(p.next_due_ps(), None, "no epoch yet");
    assert_eq!(count(&mut seg, &mut p, 0), 5, "the epoch: the first frame");
    assert_eq!(p.next_due_ps(), Some(3 * S));
    assert_eq!(count(&mut seg, &mut p, 2_805 * MS), 5);
    // No frame until 3.506 s: the clock plays the window.
    p.advance_to(&mut seg, 3_200 * MS);
    assert!(seg.is_powered_off(1));
    assert_eq!(p.events().len(), 1);
    let e = &p.events()[0];
    assert_eq!(
        (e.edge, e.t_ps, e.since_epoch_ns),
        (Edge::Start, 3 * S, 3_000_000_000)
    );
    assert_eq!(e.detail, "slave 2 switched off");
    assert_eq!(p.next_due_ps(), Some(3_500 * MS));
    p.advance_to(&mut seg, 3_400 * MS);
    assert!(seg.is_powered_off(1), "off for 0.5 s");
    p.advance_to(&mut seg, 3_600 * MS);
    assert!(!seg.is_powered_off(1));
    let e = &p.events()[1];
    assert_eq!(
        (e.edge, e.t_ps, e.since_epoch_ns),
        (Edge::End, 3_500 * MS, 3_500_000_000)
    );
    assert_eq!(p.next_due_ps(), None, "nothing left");
    assert_eq!(count(&mut seg, &mut p, 3_700 * MS), 5);
    assert_eq!(
        seg.esc(1).al_state(),
        ecsync_wire::AlState::Init,
        "from reset"
    );
    assert_eq!(p.events().len(), 2, "each edge once");
}

#[test]
fn frames_alone_still_play_a_window_between_them_at_the_next_frame() {
    // A frame-driven caller (the simulator's transport) has its edges at the frame after them,
    // as before; a window with no frame in it now happens there rather than never.
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 3.0\nfor_s = 0.5\nkind = \"power_cycle\"\nslave = 2\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    count(&mut seg, &mut p, 0);
    count(&mut seg, &mut p, 2_805 * MS);
    // The master gives slave 2 a station address (APWR 0x0010), which a reset clears.
    let mut buf = [0u8; 60];
    let mut b = ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
    b.push(
        Command::Apwr,
        0,
        ecsync_wire::DatagramAddress::position(1, 0x0010),
        &0x1002u16.to_le_bytes(),
    )
    .unwrap();
    let n = b.finish();
    seg.process(&mut buf[..n], 2_806 * MS);
    assert_eq!(seg.esc(1).station_address(), 0x1002);
    assert_eq!(count(&mut seg, &mut p, 3_506 * MS), 5);
    let at: Vec<(Edge, u64)> = p.events().iter().map(|e| (e.edge, e.t_ps)).collect();
    assert_eq!(at, [(Edge::Start, 3_506 * MS), (Edge::End, 3_506 * MS)]);
    assert_eq!(seg.esc(1).station_address(), 0, "it was reset");
}

#[test]
fn a_master_exchanging_lrd_and_lwr_starts_the_default_epoch() {
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.5\n",
    )
    .unwrap();
    assert_eq!(s.epoch, Epoch::Cyclic);
    let mut seg = Segment::new(&crate::preset::line(3, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 3);
    let lost = |p: &mut FaultPlayer, seg: &mut Segment, f: &[u8], t: u64| {
        let fate = p.before_frame(seg, f, t);
        fate.lost_out || fate.lost_back
    };
    // The bring-up (no process data): no epoch, nothing lost.
    let brd = frame_of(&[Command::Brd]);
    assert!((0..1_000).all(|k| !lost(&mut p, &mut seg, &brd, k * MS)));
    assert_eq!(p.origin_ps(), None);
    // The cyclic frames: an LRD and an LWR in one frame.
    let pd = frame_of(&[Command::Lrd, Command::Lwr]);
    let n_lost = (0..2_000u64)
        .filter(|k| lost(&mut p, &mut seg, &pd, (1_000 + k) * MS))
        .count();
    assert_eq!(p.origin_ps(), Some(1_000 * MS), "the first LRD+LWR frame");
    assert!((900..1_100).contains(&n_lost), "{n_lost} of 2 000 at 50 %");
    assert_eq!(
        p.counts().lost_with_process_data,
        n_lost as u64,
        "LRD+LWR frames carry process data"
    );
    // A frame with an LRD alone, or an LWR alone, is the epoch too.
    for c in [Command::Lrd, Command::Lwr] {
        let mut q = FaultPlayer::new(FaultSchedule::default(), 1);
        q.before_frame(&mut seg, &brd, 5);
        assert_eq!(q.origin_ps(), None);
        q.before_frame(&mut seg, &frame_of(&[Command::Brd, c]), 7);
        assert_eq!(q.origin_ps(), Some(7), "{c:?}");
    }
}

#[test]
fn an_lrw_master_draws_as_an_lrd_lwr_master() {
    // Frames are numbered by process-data frames, whatever their command: a master with LRW
    // loses the same cycles as one with LRD+LWR (the LRW numbering is the one compare has
    // always had).
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.3\n",
    )
    .unwrap();
    let seg = Segment::new(&crate::preset::line(3, 1)).unwrap();
    let run = |frame: &[u8]| {
        let mut p = FaultPlayer::new(s.clone(), 9);
        let mut seg = seg.clone();
        (0..3_000u64)
            .map(|k| {
                let f = if k % 10 == 5 {
                    frame_of(&[Command::Fprd])
                } else {
                    frame.to_vec()
                };
                let fate = p.before_frame(&mut seg, &f, k * MS);
                fate.lost_out || fate.lost_back
            })
            .collect::<Vec<bool>>()
    };
    assert_eq!(
        run(&frame_of(&[Command::Lrw])),
        run(&frame_of(&[Command::Lrd, Command::Lwr]))
    );
}

#[test]
fn injected_faults_play_at_their_real_time_even_before_the_epoch() {
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    // A schedule that waits for process data, which never comes.
    let mut p = FaultPlayer::new(FaultSchedule::default(), 1);
    let brd = frame_of(&[Command::Brd]);
    p.before_frame(&mut seg, &brd, 0);
    let mut t = toml::Table::new();
    t.insert("kind".into(), "link_down".into());
    t.insert("slave".into(), 2.into());
    t.insert("for_s".into(), 0.25.into());
    let fault = parse_fault_entry(&t).unwrap();
    let f = p.inject(fault, 1_000 * MS);
    assert_eq!(f, 0);
    assert_eq!(p.next_due_ps(), Some(1_000 * MS));
    p.advance_to(&mut seg, 1_100 * MS);
    assert_eq!(
        count(&mut seg, &mut p, 1_100 * MS),
        2,
        "slaves 3-5 behind the cable"
    );
    assert_eq!(p.events()[0].t_ps, 1_000 * MS);
    assert_eq!(p.next_due_ps(), Some(1_250 * MS));
    p.advance_to(&mut seg, 1_300 * MS);
    assert_eq!(count(&mut seg, &mut p, 1_300 * MS), 5);
    assert_eq!(p.events()[1].t_ps, 1_250 * MS);

    // A loss to the end, injected now, cleared a while later.
    let mut t = toml::Table::new();
    t.insert("kind".into(), "loss".into());
    t.insert("probability".into(), 1.0.into());
    let g = p.inject(parse_fault_entry(&t).unwrap(), 2_000 * MS);
    assert_eq!(g, 1);
    let fate = p.before_frame(&mut seg, &brd, 2_001 * MS);
    assert!(fate.lost_out || fate.lost_back);
    assert!(p.is_active(g));
    assert_eq!(p.clear(&mut seg, Some(g), 2_500 * MS), 1);
    assert!(!p.is_active(g));
    let e = p.events().last().unwrap();
    assert_eq!((e.fault, e.edge, e.t_ps), (g, Edge::End, 2_500 * MS));
    let fate = p.before_frame(&mut seg, &brd, 2_501 * MS);
    assert!(!fate.lost_out && !fate.lost_back, "cleared");
    assert_eq!(p.clear(&mut seg, None, 2_600 * MS), 0, "nothing is active");
    assert_eq!(p.next_due_ps(), None);
}

#[test]
fn clear_ends_a_power_cycle_early() {
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 1\nfor_s = 10\nkind = \"power_cycle\"\nslave = 3\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    count(&mut seg, &mut p, 0);
    p.advance_to(&mut seg, 2 * S);
    assert_eq!(count(&mut seg, &mut p, 2 * S), 2);
    assert_eq!(p.clear(&mut seg, None, 3 * S), 1);
    assert_eq!(count(&mut seg, &mut p, 3 * S), 5);
    assert_eq!(p.events()[1].t_ps, 3 * S);
    p.advance_to(&mut seg, 20 * S);
    assert_eq!(p.events().len(), 2, "its end is not played again at 11 s");
}

#[test]
fn an_explicit_epoch_starts_the_schedule() {
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 0.5\nfor_s = 0.1\nkind = \"power_cycle\"\nslave = 1\n",
    )
    .unwrap();
    let mut seg = Segment::new(&crate::preset::line(2, 1)).unwrap();
    let mut p = FaultPlayer::new(s, 1);
    assert_eq!(p.next_due_ps(), None);
    p.set_epoch(4 * S);
    assert_eq!(p.next_due_ps(), Some(4_500 * MS));
    // A process-data frame later does not move it.
    p.before_frame(&mut seg, &frame_of(&[Command::Lrw]), 4_100 * MS);
    assert_eq!(p.origin_ps(), Some(4 * S));
    p.advance_to(&mut seg, 5 * S);
    let at: Vec<(Edge, u64, u64)> = p
        .events()
        .iter()
        .map(|e| (e.edge, e.t_ps, e.since_epoch_ns))
        .collect();
    assert_eq!(
        at,
        [
            (Edge::Start, 4_500 * MS, 500_000_000),
            (Edge::End, 4_600 * MS, 600_000_000)
        ]
    );
}

#[test]
fn a_single_entry_parses_as_in_a_file() {
    let t: toml::Table = toml::from_str("kind = \"delay\"\nextra_us = 5\nslave = 2\n").unwrap();
    let e = parse_fault_entry(&t).unwrap_err();
    let file = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"delay\"\nextra_us = 5\nslave = 2\n",
    )
    .unwrap_err();
    assert_eq!(e, format!("slave: {}; fix: {}", file.message, file.fix));
    assert_eq!(
        e,
        "slave: kind \"delay\" takes no slave; fix: remove it; \"delay\" takes extra_us"
    );
    let t: toml::Table = toml::from_str("kind = \"loss\"\n").unwrap();
    assert!(
        parse_fault_entry(&t)
            .unwrap_err()
            .starts_with("probability: kind \"loss\" needs")
    );
    let t: toml::Table =
        toml::from_str("kind = \"power_cycle\"\nslave = \"reference\"\nat_s = 2.5\n").unwrap();
    assert_eq!(
        parse_fault_entry(&t).unwrap(),
        Fault {
            at_ns: 2_500_000_000,
            for_ns: Some(DEFAULT_OFF_NS),
            kind: FaultKind::PowerCycle {
                slave: SlaveRef::Reference
            }
        }
    );
    let t: toml::Table = toml::from_str("kind = \"loss\"\nfrmes = 3\n").unwrap();
    let e = parse_fault_entry(&t).unwrap_err();
    assert!(e.contains("frmes"), "{e}");
}

/// Every fault that names a slave or a port is checked against the network, and the check
/// agrees with what the player then does: a fault it accepts acts (a slave switched off, a
/// cable pulled), one it refuses would have done nothing ("is not in the segment", "no cable").
#[test]
fn the_network_check_refuses_exactly_what_the_player_would_skip() {
    let n = 4;
    let seg0 = Segment::new(&crate::preset::line(n, 1)).unwrap();
    for slave in 1..=n + 2 {
        for (kind, port) in [
            ("power_cycle", None),
            ("al_error", None),
            ("link_down", Some(0u8)),
            ("link_down", Some(1)),
            ("link_down", Some(2)),
        ] {
            let port_line = port.map_or(String::new(), |p| format!("port = {p}\n"));
            let text = format!(
                "epoch = \"start\"\n# a comment\n[[fault]]\nat_s = 0.001\nfor_s = 0.001\nkind = \"{kind}\"\nslave = {slave}\n{port_line}"
            );
            let s = FaultSchedule::parse("f.toml", &text).unwrap();
            let checked = s.check_segment(&seg0, "the line");
            let mut seg = seg0.clone();
            let mut p = FaultPlayer::new(s, 1);
            count(&mut seg, &mut p, 0);
            p.advance_to(&mut seg, 1_500_000_000);
            let detail = &p.events()[0].detail;
            let skipped = detail.contains("is not in the segment") || detail.contains("no cable");
            assert_eq!(
                checked.is_err(),
                skipped,
                "{kind} {slave} {port:?}: {detail}"
            );
            if let Err(e) = checked {
                assert_eq!((e.file.as_str(), e.line), ("f.toml", Some(3)), "{e}");
                let key = if slave > n { "slave" } else { "port" };
                assert_eq!(e.field, format!("fault[0].{key}"), "{e}");
                assert!(e.to_string().contains("fix: give a"), "{e}");
            }
        }
    }
    // The line's last slave has one cable (port 0): the fix names it.
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"link_down\"\nslave = 4\nport = 1\n",
    )
    .unwrap();
    let e = s.check_segment(&seg0, "the line").unwrap_err();
    assert!(e.fix.ends_with("with a cable: 0"), "{e}");
    let e = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 1\nkind = \"power_cycle\"\nslave = 9\n",
    )
    .unwrap()
    .check_segment(&seg0, "the line")
    .unwrap_err();
    assert!(
        e.message.contains("slave 9") && e.message.contains("has 4 slaves"),
        "{e}"
    );
    assert!(e.fix.contains("from 1 to 4"), "{e}");
    // Hot connect: all but the first may appear late.
    for (slaves, ok) in [(3, true), (4, false), (9, false)] {
        let s = FaultSchedule::parse(
            "f.toml",
            &format!("[[fault]]\nat_s = 1\nkind = \"hot_connect\"\nslaves = {slaves}\n"),
        )
        .unwrap();
        assert_eq!(s.check_segment(&seg0, "the line").is_ok(), ok, "{slaves}");
    }
}

/// An empty schedule and a fault past the run's end are told; a fault before the end is not.
#[test]
fn warnings_tell_an_empty_schedule_and_a_fault_past_the_end() {
    let s = FaultSchedule::parse("e.toml", "seed = 3\n").unwrap();
    let w = s.warnings(Some(10_000_000_000), "run longer");
    assert_eq!(w.len(), 1);
    assert!(w[0].starts_with("e.toml: no [[fault]] entry"), "{w:?}");
    let s = FaultSchedule::parse(
        "f.toml",
        "[[fault]]\nat_s = 5\nkind = \"loss\"\nprobability = 0.1\n\n[[fault]]\nat_s = 32\nkind = \"loss\"\nframes = 2\n",
    )
    .unwrap();
    assert!(s.warnings(Some(32_000_000_001), "x").is_empty());
    assert!(s.warnings(None, "x").is_empty());
    let w = s.warnings(Some(32_000_000_000), "run longer");
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].starts_with(
            "f.toml:6: fault[1].at_s: the loss fault at 32 s starts after the run's end, 32 s"
        ) && w[0].ends_with("fix: give at_s below 32 or run longer"),
        "{w:?}"
    );
}

/// A missing `at_s` or `kind` names the entry and points at files with faults, not at a
/// scenario preset; a bad epoch lists the accepted values.
#[test]
fn a_missing_field_and_a_bad_epoch_say_what_to_write() {
    let text = "[[fault]]\nat_s = 1\nkind = \"loss\"\nframes = 2\n\n[[fault]]\nat_s = 2\n";
    let e = FaultSchedule::parse("f.toml", text).unwrap_err();
    assert_eq!(
        (e.field.as_str(), e.line),
        ("fault[1].kind", Some(6)),
        "{e}"
    );
    assert!(
        e.fix.contains("kind = \"loss\"") && e.fix.contains("presets/faults-demo.toml"),
        "{e}"
    );
    assert!(!e.fix.contains("paper-2024"), "{e}");
    let e = FaultSchedule::parse("f.toml", "[[fault]]\nkind = \"loss\"\nframes = 2\n").unwrap_err();
    assert_eq!(e.field, "fault[0].at_s", "{e}");
    assert!(e.fix.contains("add at_s = "), "{e}");
    let e = FaultSchedule::parse("f.toml", "epoch = \"begin\"\n").unwrap_err();
    assert_eq!(e.line, Some(1));
    assert!(e.fix.contains("`cyclic` or `start`"), "{e}");
    assert!(!e.fix.contains("TOML syntax"), "{e}");
}
