//! The judge agrees with compare's ground truth on ecsync's own master: the letter's segment
//! brought up, the median-fit method's session run on it with a jittery host, every frame it
//! sends fed to a judge through a transport that taps the replies; beside it, each cycle
//! measured as compare's ground truth measures it (`run/observe.rs`: the reference's system
//! time at the frame's arrival after the grid point nearest the target, each drive's margin
//! = SYNC0 shift - the instant the frame's last bit passed it after the grid point). The
//! judge knows neither the target nor the shift: it finds the pulses from the drives' SYNC0
//! registers, so its phase is compare's less the shift, and its margins are compare's.

use ecsync_dc::MethodKind;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_lab::judge::{Judge, JudgeOptions, Lost};
use ecsync_lab::session::{Aim, Session, SessionConfig};
use ecsync_lab::stats::Stats;
use ecsync_master::driver::{CycleReport, CyclicLimits};
use ecsync_master::transport::{Received, Transport};
use ecsync_sim::phy::frame_wire_time_ps;
use ecsync_sim::preset::PAPER_2024_TOML;
use ecsync_sim::transport::{HostDelays, HostModel, SimTransport};

/// ecsync's simulated transport, every reply also handed to the judge.
struct Tap {
    tr: SimTransport,
    judge: Judge,
}

impl Transport for Tap {
    type Error = <SimTransport as Transport>::Error;

    fn now(&mut self) -> MasterInstant {
        self.tr.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        self.tr.sleep_until(t);
    }

    fn send_time(&mut self, len: usize) -> MasterInstant {
        self.tr.send_time(len)
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Self::Error> {
        self.tr.send_with(len, at, fill)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Self::Error> {
        let r = self.tr.recv(buf, deadline)?;
        if let Some(rx) = &r {
            // One frame a cycle: the segment's last trace is this frame's.
            let sent = self.tr.last_exchange().sent_ps;
            self.judge
                .frame(self.tr.segment(), &buf[..rx.len], sent, Lost::No);
        }
        Ok(r)
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.tr.start_cycle(cycle);
    }
}

/// A host that wakes 5 to 45 us late (a hash of the cycle).
struct Jitter;

impl HostModel for Jitter {
    fn cycle(&self, cycle: u64) -> HostDelays {
        let h = ecsync_sim::rng::splitmix64(cycle ^ 0x1234_5678);
        HostDelays {
            wake_to_send_ns: 5_000.0 + (h % 40_000) as f64,
            tx_ns: 3_000.0,
            ..HostDelays::default()
        }
    }
}

#[test]
fn the_judge_agrees_with_compares_ground_truth() {
    let s = ecsync_lab::parse("paper-2024.toml", PAPER_2024_TOML).unwrap();
    let up = ecsync_lab::run::bring_up(&s, 0).unwrap();
    let net = up.network().clone();
    let mut tr = up.sim().fork();
    let method = s.params.build(MethodKind::MedianFit, &s.method_context());
    let aim = Aim::ReferenceGrid {
        now: tr.master_now(),
        target_phase_ns: s.target_phase_ns,
        lead: MasterDuration::from_ns(0),
    };
    let cfg = SessionConfig {
        cycle_ns: s.cycle_ns,
        measure_init_frames: 500,
        recovery: None,
    };
    let mut session = Session::new(&net, method, aim, cfg, |_| CyclicLimits {
        reply_timeout: MasterDuration::from_ns(500_000),
        ..CyclicLimits::default()
    })
    .unwrap();
    tr.set_host(Box::new(Jitter));
    let names = (0..tr.segment().len())
        .map(|p| s.slave_names[tr.segment().spec_index(p)].clone())
        .collect();
    let judge = Judge::new(
        tr.segment(),
        JudgeOptions {
            names,
            preset: "paper-2024".into(),
            ..JudgeOptions::default()
        },
    );
    let mut tap = Tap { tr, judge };

    // Compare's ground truth, as observe.rs measures it.
    let reference = usize::from(net.reference);
    let period = f64::from(s.cycle_ns);
    let shift = f64::from(s.sync0_shift_ns());
    let target = s.target_phase_ns as f64;
    let n = tap.tr.segment().len();
    let mut phase = Stats::new();
    let mut margin: Vec<Stats> = (0..n).map(|_| Stats::new()).collect();
    let mut answered = 0u64;
    let mut obs = |tap: &mut Tap, rep: &CycleReport| {
        if rep.record.receive.is_none() {
            return;
        }
        answered += 1;
        let seg = tap.tr.segment();
        let trace = tap.tr.frame_trace(0);
        let sys = |x: usize, t: u64| seg.esc(x).dc().unwrap().system_time_split(t);
        let r = sys(reference, trace.pu_ps(reference).unwrap());
        let grid = ((r.0 as f64 + r.1 - target) / period).round() as u64 * s.cycle_ns as u64;
        phase.add((r.0.wrapping_sub(grid) as i64) as f64 + r.1);
        let wire = frame_wire_time_ps(rep.frame_len);
        for (x, m) in margin.iter_mut().enumerate() {
            let e = sys(x, trace.pu_ps(x).unwrap() + wire);
            m.add(shift - ((e.0.wrapping_sub(grid) as i64) as f64 + e.1));
        }
    };
    session.run(&mut tap, 3000, None, &mut obs).unwrap();
    let out = tap.judge.summary(tap.tr.segment());
    assert_eq!(out.pd_frames, answered);
    assert!(answered > 2900, "{answered}");
    // The pulses the judge found are compare's grid points plus the shift.
    let sync0 = tap
        .tr
        .segment()
        .esc(reference)
        .dc()
        .unwrap()
        .sync0()
        .unwrap();
    assert_eq!(sync0.0 % u64::from(sync0.1), s.sync0_shift_ns() as u64);
    let cmp = phase.summary();
    let j = out.phase;
    assert!(cmp.std > 1_000.0, "the host's jitter shows: {}", cmp.std);
    assert!(
        (j.mean_ns.unwrap() - (cmp.mean - shift)).abs() < 1.0,
        "{j:?} vs {cmp:?}"
    );
    assert!(
        (j.std_ns.unwrap() - cmp.std).abs() < 1.0,
        "{j:?} vs {cmp:?}"
    );
    assert!((j.max_ns.unwrap() - (cmp.max - shift)).abs() < 1.0);
    for (d, m) in out.drives.iter().zip(&margin) {
        let m = m.summary();
        assert!(
            (d.margin_min_ns.unwrap() - m.min).abs() < 1.0,
            "{}: {:?} vs {}",
            d.name,
            d.margin_min_ns,
            m.min
        );
        assert!((d.margin_mean_ns.unwrap() - m.mean).abs() < 1.0);
        assert_eq!(d.late, 0);
    }
    assert_eq!((out.late, out.missed, out.wkc_errors), (0, 0, 0));
    assert_eq!(out.wkc_usual, Some(u32::from(net.expected_lrw_wkc)));
    let html = ecsync_lab::judge::report_html(&out);
    assert!(html.contains("The master kept every drive's outputs before SYNC0 (margin min"));
    assert_eq!(html.matches("<svg").count(), 2);
    if let Some(p) = std::env::var_os("ECSYNC_JUDGE_REPORT") {
        std::fs::write(p, &html).unwrap();
    }
}
