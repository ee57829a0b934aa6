//! The host's twin: the fit recovers the parameters of a trace the model drew (an independent
//! truth), bursts are a pure function of (seed, cycle) and leave the other draws alone, a
//! replayed trace's bursts stay bursts, replay is a function of the seed, and a malformed trace
//! is refused with its file, line and column.

use ecsync_lab::scenario::check_in_scenario;
use ecsync_sim::host::{Bursts, HostNoise, HostParams, Jitter};
use ecsync_sim::host_fit::fit;
use ecsync_sim::host_trace::{HostTrace, Replay, TraceRow};

/// A host with every part of the model in use, each part identifiable from a trace.
fn truth() -> HostParams {
    HostParams {
        js: Jitter {
            sigma_ns: 3_000.0,
            folded: true,
            tail_p: 0.01,
            tail_mean_ns: 20_000.0,
            tail_sign: 1.0,
            max_abs_ns: 1e6,
            ..Jitter::ZERO
        },
        em_ns: 20_000.0,
        em_jitter: Jitter {
            sigma_ns: 300.0,
            ..Jitter::ZERO
        },
        jc: Jitter {
            sigma_ns: 400.0,
            folded: false,
            tail_p: 0.0,
            tail_mean_ns: 0.0,
            tail_sign: 1.0,
            max_abs_ns: 1e6,
            ..Jitter::ZERO
        },
        tx_latency_ns: 15_000.0,
        bursts: Bursts {
            p: 0.05,
            mean_cycles: 3_000.0,
            js_scale: 4.0,
        },
        ..HostParams::preempt_rt_stress()
    }
}

/// A trace the model draws: wake-up latency = floor + j_s, execution e_m, TX delay.
fn drawn(p: HostParams, floor_ns: f64, cycles: u64, seed: u64) -> Vec<TraceRow> {
    let n = HostNoise::new(p, seed);
    (0..cycles)
        .map(|c| {
            let x = n.cycle(c);
            TraceRow {
                wake_latency_ns: floor_ns + x.js_ns,
                exec_ns: x.em_ns,
                tx_delay_ns: Some(x.tx_ns),
            }
        })
        .collect()
}

fn near(what: &str, got: f64, want: f64, rel: f64) {
    assert!(
        (got - want).abs() <= rel * want.abs(),
        "{what}: fitted {got}, truth {want} (tolerance {} %)",
        rel * 100.0
    );
}

#[test]
fn the_fit_recovers_the_parameters_of_a_trace_drawn_from_the_model() {
    let t = truth();
    let floor = 40_000.0;
    let rows = drawn(t, floor, 600_000, 11);
    let f = fit(&rows, HostParams::preempt_rt_stress());
    let p = f.params;
    assert!(
        (f.wake_floor_ns - floor).abs() < 300.0,
        "floor {}",
        f.wake_floor_ns
    );
    near("js.sigma_ns", p.js.sigma_ns, t.js.sigma_ns, 0.05);
    near("js.tail_p", p.js.tail_p, t.js.tail_p, 0.2);
    near(
        "js.tail_mean_ns",
        p.js.tail_mean_ns,
        t.js.tail_mean_ns,
        0.15,
    );
    near("bursts.p", p.bursts.p, t.bursts.p, 0.3);
    near(
        "bursts.mean_cycles",
        p.bursts.mean_cycles,
        t.bursts.mean_cycles,
        0.3,
    );
    near(
        "bursts.js_scale",
        p.bursts.js_scale,
        t.bursts.js_scale,
        0.15,
    );
    // The floor is counted in e_m: the simulator uses j_s + e_m.
    near("em_ns", p.em_ns, t.em_ns + floor, 0.01);
    near(
        "em_jitter.sigma_ns",
        p.em_jitter.sigma_ns,
        t.em_jitter.sigma_ns,
        0.1,
    );
    assert_eq!(
        p.js.tail_heavy_share, 0.0,
        "one class of pulses: {:?}",
        p.js
    );
    near("tx_latency_ns", p.tx_latency_ns, t.tx_latency_ns, 0.01);
    near("jc.sigma_ns", p.jc.sigma_ns, t.jc.sigma_ns, 0.1);
    assert!(
        p.jc.tail_p < 0.001,
        "no pulses in the truth's j_c: {:?}",
        p.jc
    );
    // What a trace does not measure is the base's.
    assert_eq!(p.master_ppm, HostParams::preempt_rt_stress().master_ppm);
    assert_eq!(
        p.rx_latency_ns,
        HostParams::preempt_rt_stress().rx_latency_ns
    );
    // And the table it writes is one a scenario takes, with the same numbers.
    let s = check_in_scenario(&f.to_toml("preempt-rt-stress", "drawn")).unwrap();
    near(
        "parsed js.sigma_ns",
        s.host.js.sigma_ns,
        p.js.sigma_ns,
        1e-3,
    );
    near("parsed bursts.p", s.host.bursts.p, p.bursts.p, 1e-3);
}

#[test]
fn a_quiet_trace_fits_no_bursts() {
    let t = HostParams {
        bursts: Bursts::NONE,
        ..truth()
    };
    let f = fit(&drawn(t, 10_000.0, 200_000, 3), HostParams::ideal());
    assert!(f.params.bursts.is_none(), "{:?}", f.params.bursts);
}

#[test]
fn bursts_are_a_function_of_seed_and_cycle_and_leave_the_other_draws_alone() {
    let with = HostNoise::new(truth(), 5);
    let without = HostNoise::new(
        HostParams {
            bursts: Bursts::NONE,
            ..truth()
        },
        5,
    );
    let mut in_burst = 0;
    for c in (0..200_000).step_by(7) {
        let (a, b) = (with.cycle(c), without.cycle(c));
        assert_eq!(with.cycle(c), a, "a pure function of the cycle");
        assert_eq!((a.em_ns, a.tx_ns), (b.em_ns, b.tx_ns));
        if truth().bursts.in_burst(5, c) {
            in_burst += 1;
            assert_eq!(a.js_ns, (b.js_ns * 4.0));
        } else {
            assert_eq!(a.js_ns, b.js_ns);
        }
    }
    let share = f64::from(in_burst) / (200_000.0 / 7.0);
    assert!((0.02..0.1).contains(&share), "{share}");
}

/// A trace with bursts of 300 cycles, 10x the quiet latency, every 2000 cycles.
fn bursty_trace() -> HostTrace {
    let mut t = String::from("cycle,wake_latency_ns,exec_ns,tx_delay_ns\n");
    for c in 0..60_000u64 {
        let wake = if c % 2_000 < 300 {
            500_000
        } else {
            50_000 + c % 7
        };
        t.push_str(&format!("{c},{wake},1000,\n"));
    }
    HostTrace::parse("bursty.csv", &t).unwrap()
}

#[test]
fn a_replayed_traces_bursts_stay_bursts() {
    let r = Replay::new(bursty_trace(), 1_000).unwrap();
    let burst = |c: u64| r.row(9, c).wake_latency_ns > 400_000.0;
    let n = 300_000;
    let (mut in_burst, mut runs, mut long) = (0u64, 0u64, 0u64);
    let mut run = 0u64;
    for c in 0..=n {
        if c < n && burst(c) {
            in_burst += 1;
            run += 1;
        } else if run > 0 {
            runs += 1;
            if run >= 100 {
                long += run;
            }
            run = 0;
        }
    }
    // The trace's share of burst cycles (15 %), and they come in runs: a block cuts a burst at
    // most at its two ends, so most burst cycles lie in runs of 100 or more (cycle by cycle
    // resampling would leave runs of one or two).
    let share = in_burst as f64 / n as f64;
    assert!((0.1..0.2).contains(&share), "{share}");
    assert!(long as f64 > 0.8 * in_burst as f64, "{long} of {in_burst}");
    assert!(in_burst / runs > 100, "{in_burst} cycles in {runs} runs");
}

#[test]
fn replay_is_a_function_of_the_seed() {
    let r = Replay::new(bursty_trace(), 1_000).unwrap();
    let a: Vec<TraceRow> = (0..20_000).map(|c| *r.row(1, c)).collect();
    let b: Vec<TraceRow> = (0..20_000).map(|c| *r.row(1, c)).collect();
    let c: Vec<TraceRow> = (0..20_000).map(|c| *r.row(2, c)).collect();
    assert_eq!(a, b);
    assert_ne!(a, c);
    // Through the host noise too, whatever order the cycles are asked in.
    let n = HostNoise::replaying(truth(), 1, Some(std::sync::Arc::new(r)));
    let x = n.cycle(12_345);
    let _ = n.cycle(3);
    assert_eq!(n.cycle(12_345), x);
    assert!(Replay::new(bursty_trace(), 60_001).is_err());
    assert!(Replay::new(bursty_trace(), 0).is_err());
}

#[test]
fn a_malformed_trace_names_file_line_and_field() {
    let head = "# a comment\ncycle,wake_latency_ns,exec_ns,tx_delay_ns\n0,50000,900,\n";
    let e = HostTrace::parse("t.csv", &format!("{head}1,50000,abc,\n")).unwrap_err();
    assert_eq!(
        (e.file.as_str(), e.line, e.field.as_str()),
        ("t.csv", Some(4), "exec_ns")
    );
    assert!(
        e.to_string().starts_with("t.csv:4: exec_ns: \"abc\""),
        "{e}"
    );
    assert!(!e.fix.is_empty());
    let e = HostTrace::parse("t.csv", &format!("{head}1,,900,\n")).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (Some(4), "wake_latency_ns"));
    let e = HostTrace::parse("t.csv", &format!("{head}1,50000,900,-5\n")).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (Some(4), "tx_delay_ns"));
    let e = HostTrace::parse("t.csv", &format!("{head}1,50000\n")).unwrap_err();
    assert_eq!(e.line, Some(4));
    assert!(e.message.contains("2 fields"), "{e}");
    let e = HostTrace::parse("t.csv", "cycle,latency_ns,exec_ns\n0,1,2\n").unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (Some(1), "wake_latency_ns"));
    let e = HostTrace::parse("t.csv", "").unwrap_err();
    assert_eq!(e.field, "header");
    let e = HostTrace::parse("t.csv", head).unwrap_err();
    assert_eq!(e.field, "rows");
    // `ecsync run`'s CSV is a trace too: its columns are found by name.
    let run = "cycle,scheduled_ns,send_ns,ref_time_ns,error_ns,correction_ns,max_abs_092c_ns,lrw_wkc,wake_latency_ns,round_trip_ns,lost,exec_ns,tx_delay_ns\n\
               0,1,2,,3,4,,3,52000,80000,0,700,14000\n1,1,2,,3,4,,3,51000,,1,800,\n";
    let t = HostTrace::parse("run.csv", run).unwrap();
    assert_eq!(t.rows[0].exec_ns, 700.0);
    assert_eq!(t.rows[1].tx_delay_ns, None);
}

/// A tail of two pulse classes (many short preemptions, a few long stalls), drawn by the model:
/// the fit finds both classes, and its model gives the trace's wake-up p99 and p99.9.
#[test]
fn the_fit_recovers_a_tail_of_two_pulse_classes() {
    let t = HostParams {
        js: Jitter {
            sigma_ns: 3_000.0,
            folded: true,
            tail_p: 0.03,
            tail_mean_ns: 15_000.0,
            tail_sign: 1.0,
            max_abs_ns: 1e7,
            tail_heavy_share: 0.08,
            tail_heavy_mean_ns: 400_000.0,
        },
        bursts: Bursts::NONE,
        ..truth()
    };
    let floor = 20_000.0;
    let rows = drawn(t, floor, 600_000, 5);
    let f = fit(&rows, HostParams::preempt_rt_stress());
    let j = f.params.js;
    near("js.sigma_ns", j.sigma_ns, t.js.sigma_ns, 0.05);
    near("js.tail_p", j.tail_p, t.js.tail_p, 0.15);
    near("js.tail_mean_ns", j.tail_mean_ns, t.js.tail_mean_ns, 0.15);
    near(
        "js.tail_heavy_share",
        j.tail_heavy_share,
        t.js.tail_heavy_share,
        0.2,
    );
    near(
        "js.tail_heavy_mean_ns",
        j.tail_heavy_mean_ns,
        t.js.tail_heavy_mean_ns,
        0.15,
    );
    let qs = [0.99, 0.999];
    let want = ecsync_sim::host_fit::wake_quantiles(&rows, &qs);
    let got = f.predicted_wake_quantiles(&qs, 600_000, 99);
    for (k, q) in qs.iter().enumerate() {
        near(&format!("wake-up p{}", q * 100.0), got[k], want[k], 0.1);
    }
}
