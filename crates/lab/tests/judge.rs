//! The judge against independent truth: a master written here, frame by frame, on the
//! letter's segment with ideal crystals (system time = real time, exactly), whose SYNC0 it
//! programs itself; every expected phase, margin, late frame and missed pulse is worked out by
//! hand from the instants it sends at and the segment's trace.

use ecsync_lab::judge::{Expect, Judge, JudgeOptions, Lost, per_drive_table, report_html};
use ecsync_sim::Segment;
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::phy::frame_wire_time_ps;
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};

const CYCLE_NS: u64 = 1_000_000;
const START_NS: u64 = 10_000_000;
const LEAD_NS: u64 = 300_000;

fn frame(dgs: &[(Command, u8, DatagramAddress, &[u8])]) -> Vec<u8> {
    let mut buf = vec![0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
    for (c, i, a, d) in dgs {
        b.push(*c, *i, *a, d).unwrap();
    }
    let n = b.finish();
    buf.truncate(n);
    buf
}

fn segment() -> Segment {
    let mut specs = ecsync_sim::preset::paper_2024();
    for s in &mut specs {
        s.crystal = CrystalParams::default();
    }
    Segment::new(&specs).unwrap()
}

fn lrw(index: u8) -> Vec<u8> {
    frame(&[(
        Command::Lrw,
        index,
        DatagramAddress::Logical(0x1000),
        &[0u8; 12],
    )])
}

struct Rig {
    seg: Segment,
    judge: Judge,
    /// From a frame's send to its first bit at the reference, ps.
    to_ref_ps: u64,
}

impl Rig {
    /// The segment with SYNC0 programmed on every slave (one frame of broadcast writes at
    /// 1 ms): pulses at 10 ms + n x 1 ms of system time, which is real time here.
    fn new() -> Rig {
        let mut seg = segment();
        let names = (1..=6).map(|i| format!("drive-{i}")).collect();
        let mut judge = Judge::new(
            &seg,
            JudgeOptions {
                names,
                preset: "paper-2024 (ideal crystals)".into(),
                ..JudgeOptions::default()
            },
        );
        let b = |ado| DatagramAddress::Position { adp: 0, ado };
        let mut f = frame(&[
            (
                Command::Bwr,
                1,
                b(reg::DC_START_TIME),
                &START_NS.to_le_bytes(),
            ),
            (
                Command::Bwr,
                2,
                b(reg::DC_SYNC0_CYCLE),
                &(CYCLE_NS as u32).to_le_bytes(),
            ),
            (Command::Bwr, 3, b(reg::DC_ACTIVATION), &[0x03]),
        ]);
        seg.process(&mut f, 1_000_000_000);
        judge.frame(&seg, &f, 1_000_000_000, Lost::No);
        for x in 0..seg.len() {
            assert_eq!(
                seg.esc(x).dc().unwrap().sync0(),
                Some((START_NS, CYCLE_NS as u32))
            );
        }
        let to_ref_ps = seg.trace().pu_ps(0).unwrap() - 1_000_000_000;
        Rig {
            seg,
            judge,
            to_ref_ps,
        }
    }

    /// The instant to send so that the frame's first bit reaches the reference `lead_ns`
    /// before pulse `n`, ps.
    fn send_ps(&self, n: u64, lead_ns: u64) -> u64 {
        (START_NS + n * CYCLE_NS - lead_ns) * 1000 - self.to_ref_ps
    }

    fn send(&mut self, f: &[u8], t_ps: u64, lost: Lost) -> Vec<u8> {
        let mut f = f.to_vec();
        if lost != Lost::Out {
            self.seg.process(&mut f, t_ps);
        }
        self.judge.frame(&self.seg, &f, t_ps, lost);
        f
    }
}

#[test]
fn phase_margin_late_missed_by_hand() {
    let mut r = Rig::new();
    let f = lrw(0);
    let wire_ps = frame_wire_time_ps(f.len());
    // Frames 300 us before each pulse at the reference.
    let mut hops_ps = Vec::new();
    for n in 1..=100u64 {
        let f = lrw(n as u8);
        r.send(&f, r.send_ps(n, LEAD_NS), Lost::No);
        if n == 1 {
            let t = r.seg.trace();
            hops_ps = (0..6)
                .map(|x| t.pu_ps(x).unwrap() - t.pu_ps(0).unwrap())
                .collect();
        }
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!(out.pd_frames, 100);
    assert_eq!(out.reference, Some(0));
    assert_eq!(out.cycle_ns, Some(CYCLE_NS as u32));
    let ph = out.phase;
    assert!((ph.mean_ns.unwrap() + 300_000.0).abs() < 1e-3, "{ph:?}");
    assert!(ph.std_ns.unwrap() < 1e-3);
    assert!(ph.drift_ns_per_s.unwrap().abs() < 1e-3);
    for (x, d) in out.drives.iter().enumerate() {
        // SYNC0 at the drive minus the frame's last bit there: 300 us less the hops from the
        // reference and the frame's wire time.
        let want = LEAD_NS as f64 - (hops_ps[x] + wire_ps) as f64 / 1000.0;
        let got = d.margin_min_ns.unwrap();
        assert!((got - want).abs() < 1e-3, "drive {x}: {got} vs {want}");
        assert!((d.margin_mean_ns.unwrap() - want).abs() < 1e-3);
        assert_eq!((d.late, d.missed, d.frames), (0, 0, 100));
        assert_eq!(d.name, format!("drive-{}", x + 1));
    }
    assert!(hops_ps[5] > 0);
    assert_eq!(
        (out.late, out.missed, out.lost, out.duplicates),
        (0, 0, 0, 0)
    );
    let keep: Expect = "late=0,missed=0,phase_p999_us<=1,margin_min_us>=290"
        .parse()
        .unwrap();
    assert_eq!(keep.check(&out), Vec::<String>::new());

    // Frame 101 reaches the reference 10 us after its pulse: late at every drive, and pulse
    // 101 finds no new outputs (the last came before pulse 100).
    let f = lrw(101);
    let t_late = r.send_ps(101, 0) + 10_000_000;
    r.send(&f, t_late, Lost::No);
    for n in 102..=110u64 {
        r.send(&lrw(n as u8), r.send_ps(n, LEAD_NS), Lost::No);
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed), (1, 1));
    for (x, d) in out.drives.iter().enumerate() {
        assert_eq!((d.late, d.missed), (1, 1), "drive {x}");
        let want = -10_000.0 - (hops_ps[x] + wire_ps) as f64 / 1000.0;
        assert!((d.margin_min_ns.unwrap() - want).abs() < 1e-3);
    }
    assert!((out.phase.max_ns.unwrap() - 10_000.0).abs() < 1e-3);
    let broken = keep.check(&out);
    assert!(
        broken.contains(&"late = 1, expected 0".to_string()),
        "{broken:?}"
    );
    assert!(broken.contains(&"missed = 1, expected 0".to_string()));
    assert!(
        broken.iter().any(|b| b.starts_with("margin_min_us = -1")),
        "{broken:?}"
    );

    // Frame 111 lost on the way out: pulse 112 finds no new outputs. Frame 113 lost on the way
    // back: its outputs arrived, nothing missed.
    r.send(&lrw(111), r.send_ps(111, LEAD_NS), Lost::Out);
    r.send(&lrw(112), r.send_ps(112, LEAD_NS), Lost::No);
    r.send(&lrw(113), r.send_ps(113, LEAD_NS), Lost::Back);
    r.send(&lrw(114), r.send_ps(114, LEAD_NS), Lost::No);
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed, out.lost, out.lost_pd), (1, 2, 2, 2));
    assert_eq!(
        out.pd_frames, 113,
        "a frame lost on the way out reached no drive"
    );
    assert!(out.drives.iter().all(|d| d.missed == 2));

    // A retry: frame 114 again 100 us later, the same index and datagrams.
    r.send(&lrw(114), r.send_ps(114, LEAD_NS) + 100_000_000, Lost::No);
    let out = r.judge.summary(&r.seg);
    assert_eq!(out.duplicates, 1);

    // The serving host's lateness.
    r.judge.reply_late(3_000);
    r.judge.reply_late(25_000);
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late_replies, out.late_reply_max_ns), (1, 25_000));
    assert_eq!(out.stalled_replies, 0);
    // A stall: late past the stall threshold (1 ms by default), counted late too.
    r.judge.reply_late(1_500_000);
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late_replies, out.stalled_replies), (2, 1));
    assert_eq!(out.stalled_reply_threshold_ns, 1_000_000);
    let table = per_drive_table(&out);
    assert!(table.contains("drive-6"), "{table}");
    let html = report_html(&out);
    assert!(html.contains("<svg") && html.contains("Broken") && html.contains("drive-6"));
    let json = serde_json::to_string(&out).unwrap();
    assert!(json.contains("\"late\":1"));
}

#[test]
fn a_master_fixed_on_one_index_does_not_retry_each_cycle() {
    let mut r = Rig::new();
    for n in 1..=50u64 {
        r.send(&lrw(7), r.send_ps(n, LEAD_NS), Lost::No);
    }
    r.send(&lrw(7), r.send_ps(51, LEAD_NS), Lost::Out);
    for n in 52..=60u64 {
        r.send(&lrw(7), r.send_ps(n, LEAD_NS), Lost::No);
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!(out.duplicates, 0);
    assert_eq!(out.missed, 1);
}

#[test]
fn frames_aimed_after_a_pulse_mean_the_next_one() {
    // A master whose frames reach the reference 20 us after each pulse: their outputs are for
    // the next pulse, 980 us on; not late.
    let mut r = Rig::new();
    for n in 1..=40u64 {
        r.send(&lrw(n as u8), r.send_ps(n, 0) + 20_000_000, Lost::No);
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed), (0, 0));
    assert!((out.phase.mean_ns.unwrap() + 980_000.0).abs() < 1e-3);
}

#[test]
fn expect_says_what_broke() {
    let e: Expect = "late=0,recovery_ms<=100".parse().unwrap();
    let mut r = Rig::new();
    r.send(&lrw(1), r.send_ps(1, LEAD_NS), Lost::No);
    assert!(e.check(&r.judge.summary(&r.seg)).is_empty());
    let err = "late=0,jitter<5".parse::<Expect>().unwrap_err().to_string();
    assert!(err.contains("unknown key `jitter`") && err.contains("margin_min_us"));
    // Nothing measured: said so, not passed.
    let r = Rig::new();
    let b = "phase_std_us<=1"
        .parse::<Expect>()
        .unwrap()
        .check(&r.judge.summary(&r.seg));
    assert_eq!(b.len(), 1);
    assert!(b[0].starts_with("phase_std_us: not measured"), "{b:?}");
}

#[test]
fn two_late_frames_in_a_row_of_a_steady_master_are_both_late() {
    // Frames 300 us before each pulse at the reference; frames 20 and 21 both 5 us after
    // theirs (a loaded host's two bad cycles), then 300 us before again. Each came after the
    // pulse it was meant for at every drive: two late frames; pulse 20 found no new outputs
    // (pulse 21 took frame 20's, pulse 22 frame 21's and 22's): one missed pulse. The master
    // did not drift over the grid (its frames did not march over the pulse): the second late
    // frame is not taken for an early one for the next pulse, and no margin is a cycle long.
    let mut r = Rig::new();
    for n in 1..=40u64 {
        let t = if n == 20 || n == 21 {
            r.send_ps(n, 0) + 5_000_000
        } else {
            r.send_ps(n, LEAD_NS)
        };
        r.send(&lrw(n as u8), t, Lost::No);
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed), (2, 1));
    for d in &out.drives {
        assert_eq!((d.late, d.missed), (2, 1), "{}", d.name);
        let m = d.margin_mean_ns.unwrap();
        assert!(m < LEAD_NS as f64, "{}: margin mean {m}", d.name);
    }
}

#[test]
fn a_master_drifting_over_the_grid_misses_one_pulse_once() {
    // A master not synchronized to DC: each frame 5 us later against the pulses than the one
    // before. Where its frames pass the pulse, one pulse finds no new outputs and one frame
    // came after its pulse; the frames after it are meant for the next pulse, not late.
    let mut r = Rig::new();
    let mut t = r.send_ps(1, 24_000);
    for n in 1..=60u64 {
        r.send(&lrw(n as u8), t, Lost::No);
        t += (CYCLE_NS + 5_000) * 1000;
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed), (1, 1));
    for d in &out.drives {
        assert_eq!((d.late, d.missed), (1, 1), "{}", d.name);
        // The smallest margin: the frame that came after its pulse, 4 us before the pulse at
        // the reference (its last bit passed every drive after it: 5.8 us on the wire).
        assert!(d.margin_min_ns.unwrap() < 0.0);
    }
    // At the reference the phase follows the frames over the pulse to the next one: its
    // figures span most of a cycle (a master not synchronized has no phase to hold).
    assert!(out.phase.max_ns.unwrap() - out.phase.min_ns.unwrap() > 250_000.0);
}

#[test]
fn a_master_drifting_over_the_grid_has_the_drift_it_drifts_at() {
    // Each frame 5 us later against the pulses than the one before, sent every 1.005 ms: the
    // phase moves +5 us a frame, 4 975 124 ns/s (worked out from the send instants). Its
    // frames pass a pulse and are then meant for the next one, so the phase the judge keeps
    // jumps back a cycle: the drift is not that sawtooth's slope (which was 1.17e6 ns/s, a
    // quarter of the truth; dcm-bus-shift through serve, drifting -48 000 ns/s, had +1 596).
    let mut r = Rig::new();
    let mut t = r.send_ps(1, 24_000);
    for n in 1..=120u64 {
        r.send(&lrw(n as u8), t, Lost::No);
        t += (CYCLE_NS + 5_000) * 1000;
    }
    let out = r.judge.summary(&r.seg);
    let truth = 5_000.0 / 1.005e-3;
    let drift = out.phase.drift_ns_per_s.unwrap();
    assert!(
        (drift - truth).abs() < 1e-6 * truth,
        "drift {drift} ns/s, the master's {truth}"
    );
}

#[test]
fn a_jittery_master_that_does_not_drift_has_the_drift_of_its_send_instants() {
    // pysoem's sleep loop through serve: frames 380 us before the pulses on average, up to
    // 300 us either side, one after the other up to 600 us apart on the grid, but not
    // drifting. Its drift is the least-squares slope of its frames' offsets from the pulses
    // over their send instants, worked out here from those instants; unwrapping the phase by
    // the steps between frames made it +888 000 ns/s through serve.
    let mut r = Rig::new();
    let f = lrw(0);
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for k in 1..=1000u64 {
        let j = 300_000.0 * (((k * 7919) % 19) as f64 - 9.0) / 9.0;
        let off_ns = -380_000.0 + j;
        let t = (r.send_ps(k, 0) as f64 + off_ns * 1000.0) as u64;
        r.send(&f, t, Lost::No);
        xs.push(t as f64 / 1e12);
        ys.push(off_ns);
    }
    let n = xs.len() as f64;
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    let truth = sxy / sxx;
    let drift = r.judge.summary(&r.seg).phase.drift_ns_per_s.unwrap();
    assert!(
        (drift - truth).abs() < 1.0 + 1e-6 * truth.abs(),
        "drift {drift} ns/s, the send instants' {truth}"
    );
}

#[test]
fn a_retry_of_a_frame_lost_on_its_way_out_is_one() {
    // An APRD of slave 3's AL status lost before the first slave (the request), sent again
    // 2 ms later (SOEM's timeout): the answer's position field has been counted up by every
    // slave, and it is still the same datagram.
    let mut r = Rig::new();
    let aprd = frame(&[(
        Command::Aprd,
        0x42,
        DatagramAddress::position(3, reg::AL_STATUS),
        &[0u8; 6],
    )]);
    r.send(&aprd, 50_000_000_000, Lost::Out);
    let back = r.send(&aprd, 52_000_000_000, Lost::No);
    assert_ne!(
        back[18..20],
        aprd[18..20],
        "the position field came back counted up"
    );
    // Not EtherCAT: no datagram, no retry.
    let mut other = vec![0u8; 60];
    other[12..14].copy_from_slice(&0x0800u16.to_be_bytes());
    r.judge.frame(&r.seg, &other, 53_000_000_000, Lost::No);
    r.judge.frame(&r.seg, &other, 53_000_100_000, Lost::No);
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.duplicates, out.lost, out.pd_frames), (1, 1, 0));
}

#[test]
fn a_frame_delayed_most_of_a_cycle_is_late_for_the_pulse_it_missed() {
    // Frames 300 us before each pulse; frame 21 is 800 us late: it reaches the reference 500 us
    // after pulse 21, which is 500 us before pulse 22 (nearer the usual 300 us before a pulse
    // than 800 us after one). Pulse 21 found no new outputs, and the interval before pulse 22
    // got two frames (21 and 22): frame 21 was late for pulse 21, counted when frame 22 shows
    // it. A frame the master did not send (23) is a missed pulse, not a late frame.
    let mut r = Rig::new();
    for n in 1..=20u64 {
        r.send(&lrw(n as u8), r.send_ps(n, LEAD_NS), Lost::No);
    }
    r.send(&lrw(21), r.send_ps(21, LEAD_NS) + 800_000_000, Lost::No);
    for n in 22..=30u64 {
        if n != 25 {
            r.send(&lrw(n as u8), r.send_ps(n, LEAD_NS), Lost::No);
        }
    }
    let out = r.judge.summary(&r.seg);
    assert_eq!((out.late, out.missed), (1, 2), "late 21; missed 21 and 25");
    for d in &out.drives {
        assert_eq!((d.late, d.missed), (1, 2), "{}", d.name);
    }
    let broken = "late=0".parse::<Expect>().unwrap().check(&out);
    assert_eq!(broken, vec!["late = 1, expected 0".to_string()]);
}

#[test]
fn a_master_that_stalls_and_sends_the_cycles_it_owes_at_once_is_late_for_each() {
    // Frames 31-33 held back by a stall and sent at once, 10 us apart: pulses 31, 32 and 33
    // find no new outputs, and each of those frames came after the pulse it was for. Sent
    // right after pulse 33, the tracker sees them late; sent 600 us before pulse 34 (nearer its
    // usual 300 us than pulse 33's), the interval before pulse 34 gets four frames where a
    // steady one gets one: three of them were late.
    for after_pulse_33 in [true, false] {
        let mut r = Rig::new();
        for n in 1..=30u64 {
            r.send(&lrw(n as u8), r.send_ps(n, LEAD_NS), Lost::No);
        }
        let t0 = if after_pulse_33 {
            r.send_ps(33, 0) + 100_000_000
        } else {
            r.send_ps(34, 600_000)
        };
        for (i, n) in (31..=33u64).enumerate() {
            r.send(&lrw(n as u8), t0 + i as u64 * 10_000_000, Lost::No);
        }
        for n in 34..=40u64 {
            r.send(&lrw(n as u8), r.send_ps(n, LEAD_NS), Lost::No);
        }
        let out = r.judge.summary(&r.seg);
        assert_eq!(
            (out.late, out.missed),
            (3, 3),
            "after pulse 33: {after_pulse_33}"
        );
        for d in &out.drives {
            assert_eq!((d.late, d.missed), (3, 3), "{}", d.name);
        }
    }
}
