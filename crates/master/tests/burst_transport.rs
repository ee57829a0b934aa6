//! The simulated transport hands a cycle's frames to the segment as one burst, which a large
//! network takes ESC by ESC (`Segment::process_burst`): the cyclic phase is the same as with
//! each frame passed as it is sent — every cycle's record, the replies, the ground truth of
//! each frame, the drives' counters and clocks.

use ecsync_dc::MedianSync;
use ecsync_esc::{Segment, preset};
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{CyclicDriver, CyclicLimits};
use ecsync_master::sim::SimTransport;
use ecsync_master::transport::Transport;
use ecsync_master::{BringupConfig, Engine, Stage, bringup};

#[test]
fn a_cycle_of_several_frames_as_one_burst_is_the_same_as_frame_by_frame() {
    // 64 drives: the process image takes two frames, and the network is large enough for
    // visit plans and bursts.
    let mut sim = SimTransport::new(Segment::new(&preset::line(64, 5)).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: 500,
        lock_hold_checks: 50,
        monitor_cycles: 5,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let net = sim.run_procedure(&mut engine, |_, _, _| {}).unwrap();
    let period = 1_000_000u64;
    let cyc = CyclicConfig {
        period_ns: period as u32,
        reference_station: net.slaves[usize::from(net.reference)].station,
        pdi_len: net.pdi_len,
        measure_init_frames: 10,
        reference_offset_ns: 0,
        lrw: net.lrw.clone(),
    };
    let first = (sim.now_ns() / period + 2) * period;
    let run = |bursts: bool| {
        let mut tr = sim.fork();
        tr.set_bursts(bursts);
        let before = tr.segment().bursts_by_esc();
        let mut eng = CyclicEngine::new(MedianSync::new(11, 0.01, 2), cyc.clone(), first).unwrap();
        let frames = eng.frame_count();
        assert!(frames > 1, "{frames} frames");
        let mut driver = CyclicDriver::new(CyclicLimits {
            max_cycles: Some(400),
            ..CyclicLimits::default()
        });
        let mut seen = Vec::new();
        driver
            .run(&mut tr, &mut eng, u64::MAX, None, |t, c| {
                let ex = t.last_exchange();
                let truth: Vec<Option<u64>> = (0..frames)
                    .flat_map(|k| [0, 31, 63].map(|x| t.frame_trace(k).pu_ps(x)))
                    .collect();
                seen.push((format!("{:?}", c.record), ex, truth));
            })
            .unwrap();
        let seg = tr.segment();
        let state: Vec<_> = (0..seg.len())
            .map(|i| {
                let s = seg.esc_stats(i);
                let dc = seg.esc(i).dc().unwrap();
                (
                    s.frames,
                    s.datagrams_counted,
                    dc.system_time_split(tr.now_ps()),
                    dc.time_difference_ns(),
                )
            })
            .collect();
        (seen, state, seg.bursts_by_esc() - before)
    };
    let (a, sa, bursts_a) = run(true);
    let (b, sb, bursts_b) = run(false);
    assert_eq!(a.len(), 400);
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x, y, "cycle {i}");
    }
    assert_eq!(sa, sb, "the drives' counters and clocks");
    // The bursts were taken ESC by ESC (all but the first cycles', before the plans).
    assert!(bursts_a > 390, "{bursts_a} bursts");
    assert_eq!(bursts_b, 0);
}
