//! Issue 11, acceptance 4: networks of any size. A 1000-drive line and a 512-slave tree of 3-
//! and 4-port junctions come up with every propagation delay within 20 ns of the segment's
//! truth and DC locked; the engine splits what does not fit a frame into as many frames as it
//! needs (the receive times, the offsets, the lock checks, the process image's LRWs).

use ecsync_master::{BringupConfig, Engine, Network, Stage, bringup};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DeviceInfo, EscModel};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, preset};
use ecsync_sim::{SlaveSpec, Upstream};

fn bring_up(specs: &[SlaveSpec]) -> (Network, SimTransport) {
    let mut sim = SimTransport::new(Segment::new(specs).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        // A frame takes a millisecond around a thousand drives: a shorter hold and monitoring
        // keep the test to seconds.
        lock_hold_checks: 100,
        monitor_cycles: 5,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    (net, sim)
}

fn check(net: &Network, sim: &SimTransport, n: usize) {
    assert_eq!(net.slaves.len(), n);
    assert!(net.lock.converged, "{:?}", net.lock);
    let truth = sim.segment().true_delays_ns(usize::from(net.reference));
    let mut worst = 0.0f64;
    for (s, t) in net.slaves.iter().zip(&truth) {
        if let (Some(d), Some(t)) = (s.delay_ns, t) {
            worst = worst.max((d - t).abs());
        }
    }
    println!(
        "{n} slaves: worst delay error {worst:.1} ns, {} LRWs",
        net.lrw.len()
    );
    assert!(worst <= 20.0, "worst delay error {worst} ns");
    // The process image did not fit one frame: split into LRWs on slave boundaries, whose
    // working counters add up to the one the network returns (checked in the bring-up's OP
    // monitoring).
    let total: u32 = net.lrw.iter().map(|c| c.len).sum();
    assert_eq!(total, net.pdi_len);
    assert!(net.lrw.len() > 1);
}

#[test]
fn a_thousand_drives_in_a_line() {
    let specs = preset::line(1000, 11);
    let (net, sim) = bring_up(&specs);
    check(&net, &sim, 1000);
}

#[test]
fn a_tree_of_512_slaves_with_3_and_4_port_junctions() {
    // Junctions with four ports (three branches), each branch a line of drives; some branches
    // hold a 3-port junction (two of its ports used) of their own.
    let mut specs: Vec<SlaveSpec> = Vec::new();
    let drive = |i: u32, up: Upstream, ppm: f64| SlaveSpec {
        model: EscModel::servo_mii(),
        device: DeviceInfo::servo_drive(i + 1),
        crystal: CrystalParams {
            ppm,
            initial_local_ns: 1_000_000_000 + u64::from(i) * 7_777_777,
            seed: u64::from(i),
            ..Default::default()
        },
        upstream: up,
        entry_port: 0,
        cable_m: 0.5 + f64::from(i % 7),
        ring: None,
    };
    let junction = |i: u32, up: Upstream| SlaveSpec {
        model: EscModel::junction_mii(),
        device: DeviceInfo::coupler("junction", i + 1),
        crystal: CrystalParams {
            ppm: f64::from(i % 41) - 20.0,
            initial_local_ns: 2_000_000_000 + u64::from(i) * 3_333_333,
            seed: 1000 + u64::from(i),
            ..Default::default()
        },
        upstream: up,
        entry_port: 0,
        cable_m: 1.0,
        ring: None,
    };
    fn push(specs: &mut Vec<SlaveSpec>, s: SlaveSpec) -> usize {
        specs.push(s);
        specs.len() - 1
    }
    // A spine of 4-port junctions: ports 1 and 2 hold lines of drives (those on port 2 pass a
    // 3-port junction, ports 0, 1 and 3, with a drive on its port 3), port 3 continues the
    // spine through a line of drives to the next junction.
    let mut spine_up = Upstream::Master;
    while specs.len() < 512 {
        let jn = junction(specs.len() as u32, spine_up);
        let j = push(&mut specs, jn);
        let mut spine_next = spine_up;
        for port in [1u8, 2, 3] {
            let mut prev = Upstream::Slave { index: j, port };
            for k in 0..(6 + specs.len() % 5) {
                if specs.len() >= 512 {
                    break;
                }
                let n = specs.len() as u32;
                let ppm = f64::from((n * 37) % 100) - 50.0;
                let i = push(&mut specs, drive(n, prev, ppm));
                prev = Upstream::Slave { index: i, port: 1 };
                if port == 2 && k == 2 && specs.len() < 510 {
                    let jn = junction(specs.len() as u32, prev);
                    let jj = push(&mut specs, jn);
                    let n = specs.len() as u32;
                    push(
                        &mut specs,
                        drive(n, Upstream::Slave { index: jj, port: 3 }, 12.0),
                    );
                    prev = Upstream::Slave { index: jj, port: 1 };
                }
            }
            if port == 3 {
                spine_next = prev;
            }
        }
        spine_up = spine_next;
    }
    specs.truncate(512);
    let (net, sim) = bring_up(&specs);
    check(&net, &sim, 512);
}

/// The bench's lines whose frames take longer than a millisecond run SYNC0 on their own cycle
/// (`CycleBench::line` brings them up on it): over a hundred cycles no drive counts a missed
/// SYNC0 pulse, and every LRW comes back with its full working counter. Brought up on the
/// default millisecond, a 2 ms cycle's drives counted one missed pulse each every cycle.
#[test]
fn a_bench_line_longer_than_a_millisecond_runs_sync0_on_its_cycle() {
    let mut b = ecsync_sim::bench::CycleBench::line(512);
    assert!(b.cycle_ps > 1_000_000_000, "cycle {} ps", b.cycle_ps);
    let longest = b.frames.iter().map(Vec::len).max().unwrap();
    let mut work = vec![0u8; longest];
    // (Counted from the second cycle on: a drive counts the pulses it missed when its next
    // outputs come, and the pause between the bring-up's last frames and the first cycle
    // falls on the first.)
    b.run(1, &mut work);
    let missed_before: Vec<u64> = (0..b.segment.len())
        .map(|i| b.segment.esc(i).sm_events_missed())
        .collect();
    let wkc = b.run(100, &mut work);
    assert_eq!(wkc, b.expected_lrw_wkc);
    let missed: Vec<(usize, u64)> = (0..b.segment.len())
        .map(|i| (i, b.segment.esc(i).sm_events_missed() - missed_before[i]))
        .filter(|&(_, m)| m > 0)
        .collect();
    assert!(
        missed.is_empty(),
        "drives that missed SYNC0 pulses: {missed:?}"
    );
}

/// A 512-drive line's bring-up (2 ms cycle, frames ~1.7 ms) programs SYNC0 on every drive, four
/// writes each: one slave at a time that took ~2 s, longer than the start time's 100 ms lead,
/// and every drive after the 49th got a start already past (it fires only 2^32 ns later, the
/// ESC comparing the low 32 bits, off the grid); the starts then moved on by whole cycles, and
/// now the drives are programmed side by side in four rounds. Every drive runs SYNC0 on one
/// grid, and by the end of the bring-up it has started.
#[test]
fn a_large_line_runs_sync0_everywhere() {
    let specs = preset::line(512, 11);
    let cycle_ns = 2_000_000u32;
    let mut sim = SimTransport::new(Segment::new(&specs).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        cycle_ns,
        lock_hold_checks: 100,
        monitor_cycles: 2,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    sim.run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    let seg = sim.segment();
    let now_ps = sim.now_ps();
    let first = seg.esc(0).dc().and_then(|d| d.sync0()).expect("SYNC0 on");
    for i in 0..seg.len() {
        let dc = seg.esc(i).dc().expect("a DC unit");
        let (start, cycle) = dc.sync0().expect("SYNC0 on");
        assert_eq!(cycle, cycle_ns, "drive {i}");
        assert_eq!(
            start % u64::from(cycle),
            first.0 % u64::from(cycle),
            "drive {i}: SYNC0 off the grid"
        );
        let sys_now_ns = dc.system_time_split(now_ps).0;
        assert!(
            start <= sys_now_ns,
            "drive {i}: SYNC0 starts {} ms after the bring-up",
            (start - sys_now_ns) / 1_000_000
        );
    }
}

/// A large line's bring-up asks every drive for OP at once, after a cycle's process data
/// (`enter_op`), and sends an exchange's frames back to back: one by one, a 512-drive line's
/// OP requests took a round trip each (~0.8 s) and its first drives sat in OP with their
/// outputs late, counting 793 missed SYNC0 pulses each (a drive with SSC's error limit of 4
/// would have left OP); with OP at once but a cycle's frames still sent each after the
/// last one's reply (~12 ms of the 2 ms cycle), 54; with them back to back but a read of
/// 0x092C per slave in every cycle's exchange (2.6 ms of the 2 ms cycle), 4. Now none: where the
/// reads would not fit, the OP wait and the monitoring read 0x092C and AL status by one BRD
/// each, in the cycle's exchange. Counted at the end of the bring-up, before any bench cycle.
#[test]
fn a_large_line_goes_to_op_at_once() {
    for n in [512, 1000] {
        let b = ecsync_sim::bench::CycleBench::line(n);
        let worst = (0..b.segment.len())
            .map(|i| (b.segment.esc(i).sm_events_missed(), i))
            .max()
            .unwrap();
        println!(
            "{n} drives: drive {} missed {} SYNC0 pulses",
            worst.1, worst.0
        );
        assert!(
            worst.0 == 0,
            "{n} drives: drive {} missed {} SYNC0 pulses",
            worst.1,
            worst.0
        );
    }
}

/// From the moment the master declares DC in sync, every slave's true system time stays
/// within the lock threshold (100 ns) of the reference's, through the configuration that
/// follows (mailboxes, PRE-OP, sync mode, process data, SYNC0, SAFE-OP, OP) and the
/// monitoring. Those phases take seconds in a 256-drive line; the bring-up used to send no
/// FRMW in them, and the drives ran free on the frequency the static drift compensation had
/// left them with (2.8 us from the reference at the start of OP). The truth is the segment's:
/// each clock's system time at the same real instant.
#[test]
fn a_large_lines_clocks_stay_together_through_the_configuration() {
    let specs = preset::line(256, 11);
    let mut sim = SimTransport::new(Segment::new(&specs).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        monitor_cycles: 50,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    // (real time, the largest |slave - reference| then), every 8th exchange.
    let mut samples: Vec<(u64, f64)> = Vec::new();
    let mut exchanges = 0u64;
    let net = sim
        .run_procedure(&mut engine, |tr, _, _| {
            exchanges += 1;
            if !exchanges.is_multiple_of(8) {
                return;
            }
            let (seg, t_ps) = (tr.segment(), tr.last_exchange().sent_ps);
            let Some(r) = seg.esc(0).dc().map(|d| d.system_time_split(t_ps)) else {
                return;
            };
            let worst = (1..seg.len())
                .filter_map(|i| seg.esc(i).dc().map(|d| d.system_time_split(t_ps)))
                .map(|a| ((a.0.wrapping_sub(r.0) as i64) as f64 + (a.1 - r.1)).abs())
                .fold(0.0f64, f64::max);
            samples.push((t_ps, worst));
        })
        .expect("bring-up");
    assert_eq!(net.reference, 0);
    let declared_ps = sim.real_ps_at(ecsync_dc::time::MasterInstant::from_ns(
        net.lock.declared_ns.expect("DC declared in sync"),
    ));
    let after: Vec<f64> = samples
        .iter()
        .filter(|(t, _)| *t >= declared_ps)
        .map(|s| s.1)
        .collect();
    let worst = after.iter().copied().fold(0.0f64, f64::max);
    println!(
        "256 drives: largest true |slave - reference| after the lock {worst:.1} ns ({} samples)",
        after.len()
    );
    assert!(after.len() > 100, "{} samples", after.len());
    assert!(
        worst <= 100.0,
        "a drive {worst:.1} ns from the reference after the lock"
    );
}
