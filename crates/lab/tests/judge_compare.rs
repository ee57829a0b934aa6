//! The judge agrees with `compare`'s own output: a comparison of paper-2024 (one run, a few
//! thousand cycles) is run by `ecsync_lab::compare` and summarized as summary.json has it;
//! each method's run is then run again through the lab's public API ([`Run`], the same
//! bring-up, noise and seed) with every frame of its recorded cycles handed to a [`Judge`] by
//! the simulator's frame tap. The judge knows nothing of the method: its phase (against the
//! SYNC0 pulse the frame was meant for) is compare's (against the DC grid point) less the
//! SYNC0 shift, its margins, late frames and missed pulses are compare's per drive.

use ecsync_lab::judge::{Judge, JudgeOptions, JudgeOut, Lost};
use ecsync_lab::report::{MethodOut, summarize};
use ecsync_lab::run::{Run, bring_up};
use ecsync_lab::scenario::Scenario;
use ecsync_sim::transport::TapLoss;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

/// paper-2024, one run of `cycles` recorded cycles after `warmup_s` of warm-up, SYNC0 at
/// `shift_pct`, `methods` (a TOML list).
fn scenario(shift_pct: f64, cycles: u64, warmup_s: f64, methods: &str) -> Scenario {
    let mut t = ecsync_sim::preset::PAPER_2024_TOML.to_string();
    for (from, to) in [
        (
            "sync0_shift_pct = 30",
            format!("sync0_shift_pct = {shift_pct}"),
        ),
        ("runs = 5", "runs = 1".to_string()),
        ("cycles = 1800000", format!("cycles = {cycles}")),
        ("warmup_s = 120", format!("warmup_s = {warmup_s}")),
    ] {
        assert!(t.contains(from), "the preset has `{from}`");
        t = t.replacen(from, &to, 1);
    }
    let m = t.find("\nmethods = [").expect("the preset's methods") + 1;
    let end = m + t[m..].find('\n').unwrap();
    t.replace_range(m..end, &format!("methods = {methods}"));
    ecsync_lab::parse("paper-2024-judge.toml", &t).unwrap_or_else(|e| panic!("{e}\n{t}"))
}

/// Each method's recorded cycles judged through the frame tap, with the run's own result's
/// cycle count (its recorded cycles, as compare's).
fn judged(s: &Scenario) -> Vec<(String, JudgeOut, u64)> {
    let up = bring_up(s, 0).unwrap();
    let mut out = Vec::new();
    for entry in s.entries() {
        let mut run = Run::new(s, &up, entry).unwrap();
        // The warm-up untapped: compare records nothing of it.
        while run.cycles_run() < s.warmup_cycles {
            assert!(run.step(s.warmup_cycles - run.cycles_run()) > 0);
        }
        let seg = run.sim().segment();
        let names = (0..seg.len())
            .map(|p| s.slave_names[seg.spec_index(p)].clone())
            .collect();
        let judge = Arc::new(Mutex::new(Judge::new(
            seg,
            JudgeOptions {
                names,
                preset: "paper-2024".into(),
                ..JudgeOptions::default()
            },
        )));
        let j = Arc::clone(&judge);
        run.set_frame_tap(Some(Box::new(move |seg, frame, t_ps, loss| {
            let lost = match loss {
                TapLoss::No => Lost::No,
                TapLoss::Out => Lost::Out,
                TapLoss::Back => Lost::Back,
            };
            j.lock().unwrap().frame(seg, frame, t_ps, lost);
        })));
        while run.remaining() > 0 {
            assert!(run.step(1000) > 0);
        }
        let o = judge.lock().unwrap().summary(run.sim().segment());
        let res = run.finish().unwrap();
        out.push((entry.name(), o, res.cycles_done));
    }
    out
}

/// How far the judge is from compare: (phase mean, phase std, per drive margin min), ns.
fn agreement(name: &str, j: &JudgeOut, m: &MethodOut, shift_ns: f64) -> (f64, f64, Vec<f64>) {
    let gt = &m.ground_truth;
    let d_mean = j.phase.mean_ns.unwrap() - (gt.phase.mean - shift_ns);
    let d_std = j.phase.std_ns.unwrap() - gt.phase.std;
    let d_margin = gt
        .per_slave
        .iter()
        .map(|ps| {
            let d = &j.drives[usize::from(ps.position)];
            assert_eq!(
                (d.late, d.missed),
                (ps.late_frames, ps.sync0_missed),
                "{name}: {} late / missed",
                ps.name
            );
            let dm = d.margin_mean_ns.unwrap() - ps.margin_mean_ns;
            assert!(
                dm.abs() < 2.0,
                "{name}: {}'s margin mean off by {dm} ns",
                ps.name
            );
            d.margin_min_ns.unwrap() - ps.margin_min_ns
        })
        .collect();
    (d_mean, d_std, d_margin)
}

fn check(s: &Scenario, methods: &[&str]) -> Vec<(String, JudgeOut)> {
    let c = ecsync_lab::compare(s, 2, &AtomicU64::new(0)).unwrap();
    let sum = summarize(&c);
    let shift_ns = f64::from(s.sync0_shift_ns());
    let mut outs = Vec::new();
    for (name, j, cycles) in judged(s) {
        assert!(methods.contains(&name.as_str()), "{name}");
        let m = &sum.methods[&name];
        let gt = &m.ground_truth;
        // The same cycles: one frame with process data each, none lost.
        assert_eq!(cycles, s.cycles, "{name}");
        assert_eq!(gt.phase.n, s.cycles, "{name}");
        assert_eq!((gt.lost_frames, j.lost), (0, 0), "{name}");
        assert_eq!(j.pd_frames, s.cycles, "{name}");
        assert_eq!(j.phase.n, s.cycles, "{name}");
        assert_eq!(gt.per_slave.len(), 6, "{name}");
        let (d_mean, d_std, d_margin) = agreement(&name, &j, m, shift_ns);
        eprintln!(
            "{name}: phase mean {:.3} us (compare {:.3} - shift), difference {d_mean:.6} ns, std \
             {:.3} ns, difference {d_std:.6} ns; margin min difference per drive, ns: {:?}; \
             late {} ({}), missed {}",
            j.phase.mean_ns.unwrap() / 1000.0,
            gt.phase.mean / 1000.0,
            j.phase.std_ns.unwrap(),
            d_margin,
            j.late,
            gt.late_frames,
            j.missed,
        );
        assert!(d_mean.abs() < 2.0, "{name}: phase mean off by {d_mean} ns");
        assert!(d_std.abs() < 2.0, "{name}: phase std off by {d_std} ns");
        for (p, d) in d_margin.iter().enumerate() {
            assert!(
                d.abs() < 2.0,
                "{name}: drive {p}'s margin min off by {d} ns"
            );
        }
        assert_eq!(j.late, gt.late_frames, "{name}: late frames");
        outs.push((name, j));
    }
    assert_eq!(outs.len(), methods.len());
    outs
}

/// paper-2024 as it is (SYNC0 at 30 %, median's 10 000 init frames in 10 s of warm-up): no late frame, no missed pulse, either way.
#[test]
fn the_judge_agrees_with_compares_summary_on_paper_2024() {
    let methods = ["median", "pi-m2s"];
    let s = scenario(30.0, 4_000, 10.0, "[\"median\", \"pi-m2s\"]");
    for (name, j) in check(&s, &methods) {
        assert_eq!((j.late, j.missed), (0, 0), "{name}");
    }
}

/// SYNC0 at 4 %, too little for the loaded host (see sync_deadline.rs): the late frames and
/// missed pulses the judge finds at each drive are compare's.
#[test]
fn the_judge_agrees_with_compares_late_frames_and_missed_pulses() {
    let methods = ["dcm-master-shift", "bus-shift"];
    let s = scenario(4.0, 5_000, 0.5, "[\"dcm-master-shift\", \"bus-shift\"]");
    let outs = check(&s, &methods);
    assert!(
        outs.iter().any(|(_, j)| j.late > 0),
        "no late frame to agree on"
    );
}
