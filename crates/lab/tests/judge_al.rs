//! The judge counts AL errors from the segment's truth, not only those the master read: a
//! master written here sends one LRW a cycle and never reads AL status; errors raised by the
//! fault player's schedule and by the application (`raise_al_error`) between its frames are
//! counted at the next frame, each with its code, once per clear-to-set edge of the ESC's
//! error flag; an error acknowledged in the very frame that read it is counted too. Every
//! expected count is worked out by hand from the instants below.

use ecsync_lab::judge::{Expect, Judge, JudgeOptions, Lost};
use ecsync_sim::Segment;
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::fault::{FaultPlayer, FaultSchedule};
use ecsync_wire::register as reg;
use ecsync_wire::{AlStatusCode, Command, DatagramAddress, FrameBuilder};

const CYCLE_PS: u64 = 1_000_000_000;

fn frame(dgs: &[(Command, DatagramAddress, &[u8])]) -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
    for (i, (c, a, d)) in dgs.iter().enumerate() {
        b.push(*c, i as u8, *a, d).unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

fn lrw() -> Vec<u8> {
    frame(&[(Command::Lrw, DatagramAddress::Logical(0x1000), &[0u8; 12])])
}

struct Rig {
    seg: Segment,
    judge: Judge,
    player: FaultPlayer,
    events: usize,
    t_ps: u64,
}

impl Rig {
    /// The next cycle's frame, through the fault player (its edges at the frame, as the
    /// simulator plays them) and the segment, to the judge.
    fn send(&mut self, f: &[u8]) -> Vec<u8> {
        self.t_ps += CYCLE_PS;
        let t = self.t_ps;
        let mut f = f.to_vec();
        self.seg.advance_to(t);
        let fate = self.player.before_frame(&mut self.seg, &f, t);
        for e in &self.player.events()[self.events..] {
            self.judge.fault_event(e);
        }
        self.events = self.player.events().len();
        assert!(!fate.lost_out && !fate.lost_back);
        self.seg.process(&mut f, t);
        self.judge.frame(&self.seg, &f, t, Lost::No);
        f
    }

    fn cycles(&mut self, n: usize) {
        for _ in 0..n {
            self.send(&lrw());
        }
    }

    /// (al_errors, al_errors_read, codes) of drive `p`.
    fn drive(&self, p: usize) -> (u64, u64, Vec<String>) {
        let out = self.judge.summary(&self.seg);
        let d = &out.drives[p];
        (d.al_errors, d.al_errors_read, d.al_codes.clone())
    }
}

#[test]
fn al_errors_from_the_truth_with_their_codes_by_hand() {
    let mut specs = ecsync_sim::preset::paper_2024();
    for s in &mut specs {
        s.crystal = CrystalParams::default();
    }
    let seg = Segment::new(&specs).unwrap();
    let judge = Judge::new(&seg, JudgeOptions::default());
    // At 10.5 ms after the first frame with process data (the schedule's epoch): between
    // frames 10 and 11 (frames every 1 ms from the first).
    let schedule = FaultSchedule::parse(
        "faults.toml",
        "[[fault]]\nat_s = 0.0105\nkind = \"al_error\"\nslave = 3\ncode = 0x002C\n",
    )
    .unwrap();
    let mut r = Rig {
        seg,
        judge,
        player: FaultPlayer::new(schedule, 1),
        events: 0,
        t_ps: 0,
    };
    r.cycles(11);
    // Frames 1 to 11 (the first at 1 ms, the epoch): the fault is due at 11.5 ms.
    assert!(r.player.events().is_empty());
    assert_eq!(r.judge.summary(&r.seg).al_errors, 0);
    r.cycles(1);
    assert_eq!(r.player.events().len(), 1);
    // Slave 3 is position 2: its error with code 0x002C, never read.
    assert_eq!(r.drive(2), (1, 0, vec!["0x002C".to_string()]));
    assert_eq!(
        r.seg.esc(2).al_status(),
        (ecsync_wire::AlState::Init, true, 0x002C)
    );
    // The flag stays set: no new error, however many frames see it.
    r.cycles(20);
    assert_eq!(r.drive(2), (1, 0, vec!["0x002C".to_string()]));

    // The application of position 4 raises 0x001A between two frames: seen at the next.
    r.seg.esc_mut(4).raise_al_error(AlStatusCode::from(0x001A));
    assert_eq!(r.drive(4).0, 0);
    r.cycles(1);
    assert_eq!(r.drive(4), (1, 0, vec!["0x001A".to_string()]));

    // The master acknowledges position 2's error (AL control: INIT with the acknowledge
    // bit, by position: the stations have no address): clear; raised again (0x002C, then
    // 0x0032 on top while it is set: one edge), counted again, both codes listed once.
    let ack = |adp: u16| {
        frame(&[(
            Command::Apwr,
            DatagramAddress::position(adp, reg::AL_CONTROL),
            &[0x11, 0x00],
        )])
    };
    r.send(&ack(2));
    assert!(!r.seg.esc(2).al_status().1);
    r.cycles(3);
    r.seg.esc_mut(2).raise_al_error(AlStatusCode::from(0x002C));
    r.cycles(2);
    r.seg.esc_mut(2).raise_al_error(AlStatusCode::from(0x0032));
    r.cycles(2);
    assert_eq!(
        r.drive(2),
        (2, 0, vec!["0x002C".to_string(), "0x0032".to_string()])
    );

    // Position 5 raises 0x001B; the next frame reads its AL status (APRD 0x0130, 6 bytes)
    // and acknowledges it in the same frame: the truth after that frame is clear again, the
    // read saw it set: one error, read once.
    r.seg.esc_mut(5).raise_al_error(AlStatusCode::from(0x001B));
    let f = frame(&[
        (
            Command::Aprd,
            DatagramAddress::position(5, reg::AL_STATUS),
            &[0u8; 6],
        ),
        (
            Command::Apwr,
            DatagramAddress::position(5, reg::AL_CONTROL),
            &[0x11, 0x00],
        ),
    ]);
    r.send(&f);
    assert!(!r.seg.esc(5).al_status().1);
    assert_eq!(r.drive(5), (1, 1, vec!["0x001B".to_string()]));
    r.cycles(5);
    assert_eq!(r.drive(5), (1, 1, vec!["0x001B".to_string()]));

    // Position 4's error is still set and has been since: read now, it counts as read, not
    // as raised again.
    let f = frame(&[(
        Command::Aprd,
        DatagramAddress::position(4, reg::AL_STATUS),
        &[0u8; 6],
    )]);
    r.send(&f);
    assert_eq!(r.drive(4), (1, 1, vec!["0x001A".to_string()]));

    let out = r.judge.summary(&r.seg);
    assert_eq!((out.al_errors, out.al_errors_read), (4, 2));
    for (p, d) in out.drives.iter().enumerate() {
        if ![2, 4, 5].contains(&p) {
            assert_eq!((d.al_errors, d.al_errors_read), (0, 0), "{d:?}");
            assert!(d.al_codes.is_empty());
        }
    }
    let e: Expect = "al_errors<=3,al_errors_read=2".parse().unwrap();
    assert_eq!(
        e.check(&out),
        vec!["al_errors = 4, expected <= 3".to_string()]
    );
}

/// The captured network (EK1100, EL2828, EL2889 of the catalog) as SOEM starts it: BWR of AL
/// control 0x11 (INIT, acknowledge). The EK1100 and the ET1200 terminals are device emulation
/// ESCs: AL status then reads 0x11, the acknowledge copied (the captures' README), with code 0.
/// That is no error of a device: the judge counts none, from the truth or from the master's
/// read. SOEM then switches SYNC0 on in every slave with a system time, the EK1100 included;
/// the coupler has no outputs, so no frame is meant for its pulses: 0 frames, no margin, where
/// the EL2889 with its output SyncManager at 0x0F00 counts every frame.
#[test]
fn an_echoed_acknowledge_and_a_coupler_without_outputs_are_not_judged() {
    use ecsync_sim::{SlaveSpec, Upstream, catalog};
    let specs: Vec<SlaveSpec> = [
        (catalog::ek1100_model(), catalog::ek1100(1)),
        (catalog::el2828_model(), catalog::el2828(2)),
        (catalog::el2889_model(), catalog::el2889(3)),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, (model, device))| SlaveSpec {
        model,
        device,
        crystal: CrystalParams::default(),
        upstream: Upstream::in_line(i),
        entry_port: 0,
        cable_m: 0.0,
        ring: None,
    })
    .collect();
    let seg = Segment::new(&specs).unwrap();
    let judge = Judge::new(&seg, JudgeOptions::default());
    let mut r = Rig {
        seg,
        judge,
        player: FaultPlayer::new(FaultSchedule::default(), 1),
        events: 0,
        t_ps: 0,
    };
    let all = |ado: u16| DatagramAddress::position(0, ado);
    r.send(&frame(&[(
        Command::Bwr,
        all(reg::AL_CONTROL),
        &[0x11, 0x00],
    )]));
    for p in [0, 2] {
        assert!(r.seg.esc(p).al_status().1, "position {p}: the flag as read");
        assert!(r.seg.esc(p).al_error_is_echo());
    }
    let reads = frame(&[
        (
            Command::Aprd,
            DatagramAddress::position(0, reg::AL_STATUS),
            &[0u8; 6],
        ),
        (
            Command::Aprd,
            DatagramAddress::position(2, reg::AL_STATUS),
            &[0u8; 6],
        ),
    ]);
    let back = r.send(&reads);
    // The master reads 0x11 from both.
    assert_eq!(back[14 + 2 + 10], 0x11);
    // SYNC0 every 1 ms from 10.5 ms on (the frames come every 1 ms from 1 ms; system time 0
    // at power-up: the crystals start at 0).
    let sync0 = frame(&[
        (
            Command::Bwr,
            all(reg::DC_SYNC0_CYCLE),
            &1_000_000u32.to_le_bytes(),
        ),
        (
            Command::Bwr,
            all(reg::DC_START_TIME),
            &10_500_000u64.to_le_bytes(),
        ),
        (Command::Bwr, all(reg::DC_ACTIVATION), &[0x03]),
        // The EL2889's outputs: SM2 at 0x0F00, 2 bytes, written by EtherCAT, enabled.
        (
            Command::Apwr,
            DatagramAddress::position(2, reg::SM_BASE + 2 * reg::SM_LEN),
            &[0x00, 0x0f, 0x02, 0x00, 0x44, 0x00, 0x01, 0x00],
        ),
    ]);
    r.send(&sync0);
    assert!(r.seg.esc(2).has_outputs() && !r.seg.esc(0).has_outputs());
    // Its FMMU 0: logical 0x1000, 2 bytes, to 0x0F00, written.
    let mut fmmu = [0u8; 16];
    fmmu[..4].copy_from_slice(&0x1000u32.to_le_bytes());
    fmmu[4] = 2;
    fmmu[7] = 7;
    fmmu[8..10].copy_from_slice(&0x0f00u16.to_le_bytes());
    (fmmu[11], fmmu[12]) = (0x02, 0x01);
    r.send(&frame(&[(
        Command::Apwr,
        DatagramAddress::position(2, 0x0600),
        &fmmu,
    )]));
    // The process data, one LRW a cycle.
    r.cycles(20);
    assert_eq!(r.seg.esc(2).outputs(), vec![0, 0]);
    let out = r.judge.summary(&r.seg);
    assert_eq!(
        (out.al_errors, out.al_errors_read),
        (0, 0),
        "{:?}",
        out.drives
    );
    assert_eq!(out.drives[0].frames, 0, "the EK1100: {:?}", out.drives[0]);
    assert!(out.drives[0].margin_min_ns.is_none());
    assert!(out.drives[2].frames >= 9, "the EL2889: {:?}", out.drives[2]);
}
