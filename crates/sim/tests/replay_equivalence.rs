//! The segment's replay of recorded frame shapes (`Esc::process_frame`) changes nothing: a
//! bring-up and thousands of cycles give byte-identical frames, clocks and counters with the
//! replay on and off, including frames that change the ESCs' configuration between cycles.

use ecsync_sim::bench::CycleBench;
use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};

fn frame(dgs: &[(Command, u32, Vec<u8>)]) -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0, 1, 2, 3, 4, 5]).unwrap();
    for (i, (c, a, d)) in dgs.iter().enumerate() {
        b.push(*c, i as u8, DatagramAddress::Logical(*a), d)
            .unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

/// The data of a frame's first datagram.
fn first_datagram_data(frame: &[u8]) -> Vec<u8> {
    ecsync_wire::EcatFrame::new_checked(frame)
        .unwrap()
        .datagrams()
        .next()
        .unwrap()
        .unwrap()
        .data()
        .to_vec()
}

/// Every ESC's counters and clock (at `t_ps`) the same with the replay on and off.
fn same_counters_and_clocks(on: &Segment, off: &Segment, t_ps: u64) {
    for i in 0..on.len() {
        let (sa, sb) = (on.esc_stats(i), off.esc_stats(i));
        assert_eq!(
            (sa.frames, sa.datagrams_counted),
            (sb.frames, sb.datagrams_counted),
            "slave {i} counters"
        );
        let (da, db) = (on.esc(i).dc().unwrap(), off.esc(i).dc().unwrap());
        assert_eq!(
            da.system_time_split(t_ps),
            db.system_time_split(t_ps),
            "slave {i}"
        );
    }
}

/// `frame` through both segments at `t_ps`: the same outcome and the same bytes back (`what`
/// names it in a failure). Returns when the frame's last bit has left, the next one's send time.
fn same_both_ways(on: &mut Segment, off: &mut Segment, frame: &[u8], t_ps: u64, what: &str) -> u64 {
    let (mut a, mut b) = (frame.to_vec(), frame.to_vec());
    assert_eq!(
        on.process(&mut a, t_ps),
        off.process(&mut b, t_ps),
        "{what}"
    );
    assert_eq!(a, b, "{what}");
    t_ps + ecsync_sim::frame_wire_time_ps(frame.len())
}

/// Whether frames passed some drive by under a visit plan that still holds: frames not yet in
/// that drive's own counters (a plan that ends brings them up to date).
fn plans_passed_drives_by(on: &Segment) -> bool {
    (0..on.len()).any(|i| on.esc_stats(i).frames > on.esc(i).stats().frames)
}

#[test]
fn replay_is_exact() {
    let base = CycleBench::paper_2024();
    let mut on: Segment = base.segment.clone();
    let mut off: Segment = base.segment.clone();
    off.set_replay(false);
    let fp = |st: u16, ado: u16| DatagramAddress::Configured { adp: st, ado }.raw();
    let bp = |ado: u16| DatagramAddress::Position { adp: 0, ado }.raw();
    // Interludes that change configuration between runs of the cyclic frame: AL state
    // changes, FMMU rewrites, a station address change, loop closing, an EEPROM read.
    let interludes = [
        frame(&[(Command::Fpwr, fp(0x1002, 0x0120), vec![0x04, 0])]),
        frame(&[(Command::Fpwr, fp(0x1002, 0x0120), vec![0x08, 0])]),
        frame(&[(Command::Fprd, fp(0x1003, 0x0610), vec![0; 16])]),
        frame(&[(Command::Fpwr, fp(0x1004, 0x0600), {
            let mut f = vec![0u8; 16];
            f[4] = 8; // shorter output mapping
            f[7] = 7;
            f[8..10].copy_from_slice(&0x1000u16.to_le_bytes());
            f[11] = 2;
            f[12] = 1;
            f
        })]),
        frame(&[(Command::Bwr, bp(0x0f80), vec![1, 2, 3, 4])]),
        frame(&[(Command::Fpwr, fp(0x1005, 0x0502), vec![0, 1, 8, 0, 0, 0])]),
        frame(&[(Command::Fpwr, fp(0x1003, 0x0101), vec![0x0c])]), // close port 1 of drive 4
        frame(&[(Command::Fpwr, fp(0x1003, 0x0101), vec![0x00])]), // and open it again
    ];
    let mut t = base.start_ps;
    let mut differences = 0;
    let mut run = |f: &[u8], t: u64| {
        let (mut a, mut b) = (f.to_vec(), f.to_vec());
        let oa = on.process(&mut a, t);
        let ob = off.process(&mut b, t);
        if a != b || oa != ob {
            differences += 1;
        }
    };
    for round in 0..40 {
        for _ in 0..200 {
            run(&base.frames[0], t);
            t += base.cycle_ps;
        }
        run(&interludes[round % interludes.len()], t);
        t += 100_000_000;
    }
    assert_eq!(
        differences, 0,
        "frames differ between replay and full decoding"
    );
    for i in 0..on.len() {
        let (a, b) = (on.esc(i), off.esc(i));
        let (sa, sb) = (on.esc_stats(i), off.esc_stats(i));
        assert_eq!(
            (sa.frames, sa.datagrams_counted),
            (sb.frames, sb.datagrams_counted),
            "slave {i} counters"
        );
        // (The bring-up replayed its repeated frames already: nothing more with replay off.)
        let before = base.segment.esc_stats(i).replayed_frames;
        assert_eq!(
            sb.replayed_frames, before,
            "slave {i}: replayed with replay off"
        );
        assert!(
            sa.replayed_frames - before > 6_000,
            "slave {i}: the replay ran ({} of 8040 frames)",
            sa.replayed_frames - before
        );
        assert_eq!(a.al_state(), b.al_state());
        let (da, db) = (a.dc().unwrap(), b.dc().unwrap());
        assert_eq!(
            da.system_time_split(t),
            db.system_time_split(t),
            "slave {i} clock"
        );
        assert_eq!(da.time_difference_ns(), db.time_difference_ns());
    }
    let _ = preset::paper_2024;
}

/// A cycle of several frames (160 drives: the process image's LRWs spread over five frames,
/// outputs first, then inputs, as SOEM maps them), each of its own shape: the replay of every
/// shape, and the frames passing by the drives they do nothing at, change nothing either, and
/// each frame's ground truth is the way it took.
#[test]
fn replay_of_a_cycle_of_several_frames_is_exact() {
    let base = CycleBench::line(160);
    assert!(base.frames.len() > 1, "{} frames", base.frames.len());
    let mut on: Segment = base.segment.clone();
    let mut off: Segment = base.segment.clone();
    off.set_replay(false);
    let mut t = base.start_ps;
    let fp = |st: u16, ado: u16| DatagramAddress::Configured { adp: st, ado }.raw();
    for cycle in 0..300 {
        // Between runs of cycles, changes of configuration that make an ESC act in a frame it
        // did nothing in (the frames then visit it again): drive 60's output FMMU set to drive
        // 150's (read back first), in the second frame's image, which carries neither drive
        // 60's outputs nor its inputs; then an AL state change at drive 30 and back.
        let interlude: Vec<Vec<u8>> = match cycle {
            100 => {
                let mut read = frame(&[(Command::Fprd, fp(0x1000 + 150, 0x0600), vec![0; 16])]);
                let mut read_off = read.clone();
                on.process(&mut read, t);
                off.process(&mut read_off, t);
                assert_eq!(read, read_off);
                let entry = first_datagram_data(&read);
                assert_ne!(entry[12], 0, "drive 150's FMMU 0 is active");
                vec![frame(&[(Command::Fpwr, fp(0x1000 + 60, 0x0600), entry)])]
            }
            150 => vec![frame(&[(
                Command::Fpwr,
                fp(0x1000 + 30, 0x0120),
                vec![0x04, 0],
            )])],
            200 => vec![frame(&[(
                Command::Fpwr,
                fp(0x1000 + 30, 0x0120),
                vec![0x08, 0],
            )])],
            _ => Vec::new(),
        };
        for f in interlude {
            let (mut a, mut b) = (f.clone(), f);
            assert_eq!(on.process(&mut a, t), off.process(&mut b, t));
            assert_eq!(a, b);
            t += 10_000_000;
        }
        let mut t_frame = t;
        for f in &base.frames {
            let (mut a, mut b) = (f.clone(), f.clone());
            let oa = on.process(&mut a, t_frame);
            let ob = off.process(&mut b, t_frame);
            assert_eq!(a, b);
            assert_eq!(oa, ob);
            // Every drive's processing unit saw the frame, at the same time both ways.
            for i in 0..on.len() {
                let pu = on.trace().pu_ps(i);
                assert!(pu.is_some_and(|p| p > t_frame), "slave {i}");
                assert_eq!(pu, off.trace().pu_ps(i));
            }
            t_frame += ecsync_sim::frame_wire_time_ps(f.len());
        }
        t += base.cycle_ps;
    }
    // The frames passed drives by: frames not yet in those drives' own counters.
    assert!(plans_passed_drives_by(&on), "no frame passed a drive by");
    same_counters_and_clocks(&on, &off, t);
}

/// DCM in bus shift writes the reference's System Time Offset (0x0920) every cycle: in a large
/// network the frames keep passing the drives they do nothing at (the write leaves every
/// recorded program valid), and the replay with its visit plans still changes nothing: frames,
/// outcomes, clocks and counters as with the replay off.
#[test]
fn an_offset_write_every_cycle_keeps_the_visit_plans_and_changes_nothing() {
    let base = CycleBench::line(160);
    let mut on: Segment = base.segment.clone();
    let mut off: Segment = base.segment.clone();
    off.set_replay(false);
    let reference = 0x1000u16;
    let fp = |ado: u16| {
        DatagramAddress::Configured {
            adp: reference,
            ado,
        }
        .raw()
    };
    let mut read = frame(&[(Command::Fprd, fp(0x0920), vec![0; 8])]);
    on.process(&mut read, base.start_ps);
    let mut read_off = frame(&[(Command::Fprd, fp(0x0920), vec![0; 8])]);
    off.process(&mut read_off, base.start_ps);
    assert_eq!(read, read_off);
    let offset = u64::from_le_bytes(first_datagram_data(&read).try_into().unwrap());
    let mut t = base.start_ps + base.cycle_ps;
    for cycle in 0..200u64 {
        // The re-adjustment: a few ns either way, as DCM's filtered PI moves it.
        let moved = offset.wrapping_add((cycle % 7) * 3).wrapping_sub(9);
        let w = frame(&[(Command::Fpwr, fp(0x0920), moved.to_le_bytes().to_vec())]);
        let what = format!("cycle {cycle}: the offset write");
        let mut t_frame = same_both_ways(&mut on, &mut off, &w, t, &what);
        for (k, f) in base.frames.iter().enumerate() {
            let what = format!("cycle {cycle}, frame {k}");
            t_frame = same_both_ways(&mut on, &mut off, f, t_frame, &what);
        }
        t += base.cycle_ps;
    }
    // The plans held through the writes.
    assert!(
        plans_passed_drives_by(&on),
        "no frame passed a drive by: the offset writes ended the visit plans"
    );
    same_counters_and_clocks(&on, &off, t);
}

fn mixed_frame(dgs: &[(Command, u32, Vec<u8>)]) -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0, 1, 2, 3, 4, 5]).unwrap();
    for (i, (c, a, d)) in dgs.iter().enumerate() {
        let addr = match c.address_mode() {
            ecsync_wire::AddressMode::Logical => DatagramAddress::Logical(*a),
            ecsync_wire::AddressMode::Configured => DatagramAddress::Configured {
                adp: *a as u16,
                ado: (*a >> 16) as u16,
            },
            _ => DatagramAddress::Position {
                adp: *a as u16,
                ado: (*a >> 16) as u16,
            },
        };
        b.push(*c, i as u8, addr, d).unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

/// Long frames (more datagrams than a shape holds: the bring-up's per-slave exchanges),
/// which each ESC takes by the station they name: byte-identical frames and ESC states with
/// the index and without it (replay off walks every datagram at every ESC), for frames of
/// FPRD, FPWR, FRMW, APRD and BRD to stations that exist, that do not, and twice the same, and
/// for the frames the index leaves alone: one that writes a station address before an FPRD to
/// the new one in the same frame.
#[test]
fn long_frames_by_station_are_exact() {
    let base = CycleBench::line(160);
    let mut on: Segment = base.segment.clone();
    let mut off: Segment = base.segment.clone();
    off.set_replay(false);
    let at = |st: u16, ado: u16| u32::from(st) | (u32::from(ado) << 16);
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut next = |n: u64| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x % n
    };
    let mut t = base.start_ps;
    for round in 0..40 {
        let mut dgs = Vec::new();
        for _ in 0..30 + next(50) {
            let st = 0x1000 + next(170) as u16;
            dgs.push(match next(10) {
                0 => (Command::Frmw, at(0x1000, 0x0910), vec![0; 8]),
                1 => (
                    Command::Aprd,
                    at(0u16.wrapping_sub(next(160) as u16), 0x0130),
                    vec![0; 2],
                ),
                2 => (Command::Brd, at(0, 0x0000), vec![0; 4]),
                // A user RAM register every ESC has (ESC RAM, writable).
                3 | 4 => (
                    Command::Fpwr,
                    at(st, 0x0f80),
                    vec![round as u8, next(256) as u8],
                ),
                _ => (Command::Fprd, at(st, 0x0f80), vec![0; 2]),
            });
        }
        if round == 20 {
            // The station address of drive 5 moved (0x2000) and read at the new one.
            dgs.insert(
                0,
                (
                    Command::Fpwr,
                    at(0x1005, 0x0010),
                    0x2000u16.to_le_bytes().to_vec(),
                ),
            );
            dgs.push((Command::Fprd, at(0x2000, 0x0010), vec![0; 2]));
        }
        if round == 21 {
            dgs.insert(
                0,
                (
                    Command::Fpwr,
                    at(0x2000, 0x0010),
                    0x1005u16.to_le_bytes().to_vec(),
                ),
            );
        }
        let f = mixed_frame(&dgs);
        let (mut a, mut b) = (f.clone(), f);
        assert_eq!(
            on.process(&mut a, t),
            off.process(&mut b, t),
            "round {round}"
        );
        assert_eq!(a, b, "round {round}");
        t += 1_000_000_000;
    }
    for pos in 0..on.len() {
        assert_eq!(
            on.esc_stats(pos).frames,
            off.esc_stats(pos).frames,
            "slave {pos}"
        );
        assert_eq!(
            on.esc(pos).station_address(),
            off.esc(pos).station_address()
        );
    }
}

/// Frames of other shapes between the cycles take the program slots the cyclic frames' visit
/// plans were made from (each ESC keeps four; five reads of other registers record five more
/// programs every cycle): the plans' steps still hold (nothing changed the ESCs), their replays
/// are counted straight into the counters, and everything stays as with the replay off.
#[test]
fn visit_plans_outlive_their_program_slots() {
    let base = CycleBench::line(160);
    let mut on: Segment = base.segment.clone();
    let mut off: Segment = base.segment.clone();
    off.set_replay(false);
    let brd =
        |ado: u16, len: usize| mixed_frame(&[(Command::Brd, u32::from(ado) << 16, vec![0; len])]);
    let reads = [
        brd(0x0130, 2),
        brd(0x0000, 1),
        brd(0x0008, 2),
        brd(0x0110, 2),
        brd(0x0010, 2),
    ];
    let mut t = base.start_ps;
    for cycle in 0..120u64 {
        let mut t_frame = t;
        for (k, f) in base.frames.iter().enumerate() {
            let what = format!("cycle {cycle}, frame {k}");
            t_frame = same_both_ways(&mut on, &mut off, f, t_frame, &what);
        }
        // Every tenth cycle from the 30th on, the five reads (the plans are made by then).
        if cycle >= 30 && cycle % 10 == 0 {
            for r in &reads {
                let what = format!("cycle {cycle}: a read");
                t_frame = same_both_ways(&mut on, &mut off, r, t_frame, &what);
            }
        }
        t += base.cycle_ps;
    }
    assert!(
        plans_passed_drives_by(&on),
        "no frame passed a drive by: the reads ended the visit plans"
    );
    same_counters_and_clocks(&on, &off, t);
}
