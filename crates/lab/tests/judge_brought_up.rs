//! The judge on the letter's segment as ecsync's bring-up left it (OP, DC locked, SYNC0
//! running, its crystals drifting), driven by a master written here: each cycle one frame with
//! the process data (LRW over the bring-up's logical image), the reference's time distributed
//! (FRMW 0x0910) and every drive's AL status read (FPRD 0x0130). The frames are aimed, through
//! the reference's true clock, 300 us before its SYNC0 pulses; the working counter the judge
//! finds usual is the one the bring-up expects; an AL error fault from the schedule is read,
//! costs the working counter and is recovered from when the master acknowledges it.

use ecsync_lab::judge::{Expect, Judge, JudgeOptions, Lost};
use ecsync_sim::Segment;
use ecsync_sim::fault::{FaultPlayer, FaultSchedule};
use ecsync_sim::preset::PAPER_2024_TOML;
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};

const LEAD_NS: f64 = 300_000.0;

struct Master {
    seg: Segment,
    judge: Judge,
    player: FaultPlayer,
    events: usize,
    stations: Vec<u16>,
    reference: usize,
    logical: u32,
    pdi_len: usize,
    /// From the send to the first bit at the reference, ps.
    to_ref_ps: u64,
    sync0: (u64, u32),
    now_ps: u64,
    index: u8,
    /// Also send, 400 us after each cycle's frame (100 us after the pulse), a frame whose LRW
    /// maps no drive's outputs (a master's second frame for other devices).
    unmapped: bool,
}

impl Master {
    fn frame(&mut self, ack_station: Option<u16>) -> Vec<u8> {
        let mut buf = vec![0u8; 1514];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
        let i = self.index;
        self.index = self.index.wrapping_add(1);
        let r = self.stations[self.reference];
        b.push_zeroed(
            Command::Frmw,
            i,
            DatagramAddress::configured(r, reg::DC_SYSTEM_TIME),
            8,
        )
        .unwrap();
        b.push_zeroed(
            Command::Lrw,
            i,
            DatagramAddress::Logical(self.logical),
            self.pdi_len,
        )
        .unwrap();
        for &st in &self.stations {
            b.push_zeroed(
                Command::Fprd,
                i,
                DatagramAddress::configured(st, reg::AL_STATUS),
                6,
            )
            .unwrap();
        }
        if let Some(st) = ack_station {
            // OP, with the error acknowledged.
            b.push(
                Command::Fpwr,
                i,
                DatagramAddress::configured(st, reg::AL_CONTROL),
                &[0x18, 0x00],
            )
            .unwrap();
        }
        let n = b.finish();
        buf.truncate(n);
        buf
    }

    /// The real time at which the reference's system time reads `target` ns.
    fn when_reference_reads(&self, target: u64) -> u64 {
        let dc = self.seg.esc(self.reference).dc().unwrap();
        let mut t = self.now_ps;
        for _ in 0..4 {
            let (ns, frac) = dc.system_time_split(t);
            let err = (target as i64 - ns as i64) as f64 - frac;
            t = (t as i64 + (err * 1000.0).round() as i64) as u64;
        }
        t
    }

    /// Cycle `n` of the grid: a frame whose first bit reaches the reference `LEAD_NS` before
    /// pulse `n` (plus `late_ns`).
    fn cycle(&mut self, n: u64, late_ns: f64, ack: Option<u16>) {
        let (s, c) = self.sync0;
        let pulse = s + n * u64::from(c);
        let at_ref = self.when_reference_reads(pulse) as f64 - (LEAD_NS - late_ns) * 1000.0;
        let t = at_ref as u64 - self.to_ref_ps;
        assert!(t > self.now_ps);
        self.now_ps = t;
        let mut f = self.frame(ack);
        self.seg.advance_to(t);
        let fate = self.player.before_frame(&mut self.seg, &f, t);
        for e in &self.player.events()[self.events..] {
            self.judge.fault_event(e);
        }
        self.events = self.player.events().len();
        let lost = if fate.lost_out {
            Lost::Out
        } else {
            self.seg.process(&mut f, t);
            if fate.lost_back { Lost::Back } else { Lost::No }
        };
        self.judge.frame(&self.seg, &f, t, lost);
        if self.unmapped {
            let mut buf = vec![0u8; 128];
            let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
            b.push_zeroed(
                Command::Lrw,
                0xee,
                DatagramAddress::Logical(0x4000_0000),
                16,
            )
            .unwrap();
            let n = b.finish();
            buf.truncate(n);
            let t = t + 400_000_000;
            self.seg.advance_to(t);
            self.seg.process(&mut buf, t);
            self.judge.frame(&self.seg, &buf, t, Lost::No);
        }
    }
}

/// The segment as the bring-up left it, a master of ours on it, the first pulse to aim at;
/// the bring-up's process data chunk.
fn brought_up() -> (Master, u64, ecsync_master::pdi::LrwChunk) {
    let s = ecsync_lab::parse("paper-2024.toml", PAPER_2024_TOML).unwrap();
    let up = ecsync_lab::run::bring_up(&s, 0).unwrap();
    let net = up.network().clone();
    let tr = up.sim().fork();
    let now_ps = tr.now_ps();
    let seg = tr.into_segment();
    let reference = usize::from(net.reference);
    let sync0 = seg.esc(reference).dc().unwrap().sync0().unwrap();
    assert_eq!(sync0.1, 1_000_000);
    let names: Vec<String> = (0..seg.len())
        .map(|p| s.slave_names[seg.spec_index(p)].clone())
        .collect();
    let judge = Judge::new(
        &seg,
        JudgeOptions {
            names: names.clone(),
            preset: "paper-2024".into(),
            ..JudgeOptions::default()
        },
    );
    let schedule = FaultSchedule::parse(
        "faults.toml",
        "[[fault]]\nat_s = 0.5\nkind = \"al_error\"\nslave = 3\n",
    )
    .unwrap();
    let chunk = net.lrw[0];
    assert_eq!(net.lrw.len(), 1);
    let mut m = Master {
        seg,
        judge,
        player: FaultPlayer::new(schedule, 1),
        events: 0,
        stations: net.slaves.iter().map(|x| x.station).collect(),
        reference,
        logical: chunk.logical,
        pdi_len: chunk.len as usize,
        to_ref_ps: 0,
        sync0,
        now_ps,
        index: 0,
        unmapped: false,
    };
    // The way to the reference, from one frame of the cycle's shape sent now.
    let mut f = m.frame(None);
    let t = now_ps + 1_000_000;
    m.seg.advance_to(t);
    m.seg.process(&mut f, t);
    m.to_ref_ps = m.seg.trace().pu_ps(reference).unwrap() - t;
    m.now_ps = t;
    // The first pulse at least 2 ms on (SYNC0 may not have started yet: the bring-up starts
    // it a few ms ahead).
    let (s0, c) = sync0;
    let sys = m.seg.esc(reference).dc().unwrap().system_time_ns(t);
    let first = sys.saturating_sub(s0) / u64::from(c) + 2;
    (m, first, chunk)
}

#[test]
fn a_master_of_our_own_on_the_brought_up_segment() {
    let (mut m, first, chunk) = brought_up();
    for n in first..first + 400 {
        m.cycle(n, 0.0, None);
    }
    let out = m.judge.summary(&m.seg);
    // What the bring-up expects of the process data, and the phase it was aimed at.
    assert_eq!(out.wkc_usual, Some(u32::from(chunk.expected_wkc)));
    assert_eq!(
        (out.wkc_errors, out.late, out.missed, out.lost),
        (0, 0, 0, 0)
    );
    let ph = out.phase;
    // (Aimed through the reference's clock as it runs before each frame; the time control
    // loop's slews between that and the send leave a few ns.)
    assert!((ph.mean_ns.unwrap() + LEAD_NS).abs() < 10.0, "{ph:?}");
    assert!(ph.std_ns.unwrap() < 2.0, "{ph:?}");
    // Locked by the bring-up, held by the FRMW every cycle (the first cycles, after the pause
    // since the bring-up, the widest).
    assert!(
        out.spread_max_ns.unwrap() < 200.0,
        "{:?}",
        out.spread_max_ns
    );
    for d in &out.drives {
        assert_eq!(d.al_state, "Op");
        let m = d.margin_min_ns.unwrap();
        // 300 us less the way from the reference and the frame's wire time (tens of us).
        assert!(m < LEAD_NS && m > LEAD_NS - 60_000.0, "{}: {m}", d.name);
        // Within one 40 ns MII stamp on average: the stamps sit on the crystals' grids,
        // which the loops cannot steer onto each other (11.6 ns on drive-3).
        assert!(d.time_diff_mean_ns.unwrap() < 40.0, "{d:?}");
        assert!(d.time_diff_max_ns.unwrap() < 200.0, "{d:?}");
    }
    // One frame 5 us past its pulse at the reference.
    m.cycle(first + 400, LEAD_NS + 5_000.0, None);
    for n in first + 401..first + 450 {
        m.cycle(n, 0.0, None);
    }
    let out = m.judge.summary(&m.seg);
    assert_eq!((out.late, out.missed), (1, 1));
    assert!(out.drives.iter().all(|d| (d.late, d.missed) == (1, 1)));

    // The AL error at 0.5 s after the first frame with process data: the drive falls to
    // SAFE-OP with the error flag, its outputs no longer count.
    let mut n = first + 450;
    while m.player.events().is_empty() {
        m.cycle(n, 0.0, None);
        n += 1;
    }
    for _ in 0..50 {
        m.cycle(n, 0.0, None);
        n += 1;
    }
    let out = m.judge.summary(&m.seg);
    assert_eq!(out.al_errors, 1);
    let hit: Vec<_> = out.drives.iter().filter(|d| d.al_errors == 1).collect();
    assert_eq!(hit.len(), 1);
    assert_eq!(hit[0].al_codes, vec!["0x001A".to_string()]);
    assert_eq!(hit[0].al_state, "SafeOp");
    assert!(out.wkc_errors >= 50);
    assert_eq!(out.faults.len(), 1);
    assert_eq!(out.faults[0].recovery_ms, None);
    let e: Expect = "al_errors=0,recovery_ms<=100".parse().unwrap();
    let broken = e.check(&out);
    assert_eq!(
        broken,
        vec![
            "al_errors = 1, expected 0".to_string(),
            "recovery_ms = never, expected <= 100".to_string()
        ]
    );
    // The master acknowledges: OP again, the working counter as before.
    let st = m.stations[hit[0].position];
    m.cycle(n, 0.0, Some(st));
    for k in 1..20 {
        m.cycle(n + k, 0.0, None);
    }
    let out = m.judge.summary(&m.seg);
    let r = out.faults[0].recovery_ms.expect("back in OP");
    assert!(r > 50.0 && r < 55.0, "{r}");
    assert!(out.drives.iter().all(|d| d.al_state == "Op"));
    assert!(e.check(&out).len() == 1);
}

#[test]
fn a_frame_that_maps_no_drive_s_outputs_is_not_judged_as_theirs() {
    // Each cycle a second frame 100 us after the pulse whose LRW writes no drive (its logical
    // address is in no FMMU): the drives' applications take no outputs from it, and the judge,
    // which asks them, finds no late frame and the margins of the cycle's own frame.
    let (mut m, first, _) = brought_up();
    m.unmapped = true;
    for n in first..first + 400 {
        m.cycle(n, 0.0, None);
    }
    let out = m.judge.summary(&m.seg);
    assert_eq!(out.pd_frames, 800);
    assert_eq!((out.late, out.missed), (0, 0));
    for d in &out.drives {
        let mm = d.margin_min_ns.unwrap();
        assert!(mm < LEAD_NS && mm > LEAD_NS - 60_000.0, "{}: {mm}", d.name);
        assert_eq!(d.frames, 400, "{}", d.name);
    }
}
