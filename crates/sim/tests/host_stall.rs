//! Issue 11, acceptance 2 (the simulator's half; the veth half is in the CLI's net tests): a
//! host stall of two and a half periods in cycle 5 makes the one cyclic driver skip the two
//! slots that passed and send one frame, for the cycle whose slot is now, then go on on
//! schedule: no burst.

use ecsync_dc::MedianSync;
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{CyclicDriver, CyclicLimits};
use ecsync_master::transport::{HostStall, Transport};
use ecsync_master::{BringupConfig, Engine, Stage, bringup};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, preset};

#[test]
fn a_stall_of_two_and_a_half_periods_skips_two_cycles_and_sends_no_burst() {
    let mut sim = SimTransport::new(Segment::new(&preset::paper_2024()).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: 1_000,
        lock_hold_checks: 50,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let net = sim.run_procedure(&mut engine, |_, _, _| {}).unwrap();
    let period = 1_000_000u64;
    let cyc = CyclicConfig::for_network(&net, period as u32, 2).expect("a reference");
    let first = (sim.now().as_ns() / period + 2) * period;
    let mut eng = CyclicEngine::new(
        MedianSync::new(11, 0.01, 2),
        cyc,
        ecsync_dc::time::MasterInstant::from_ns(first),
    )
    .unwrap();
    let mut tr = HostStall::new(
        sim,
        5,
        ecsync_dc::time::MasterDuration::from_ns(period * 5 / 2),
    );
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(12),
        ..CyclicLimits::default()
    });
    let mut seen = Vec::new();
    driver
        .run(&mut tr, &mut eng, u64::MAX, None, |_, c| {
            seen.push((c.record.cycle, c.skipped_before, c.record.send.as_ns()));
        })
        .unwrap();
    let cycles: Vec<u64> = seen.iter().map(|s| s.0).collect();
    // Twelve frames: cycles 0-4, then 7 (5 and 6 skipped), 8, ...
    assert_eq!(cycles, [0, 1, 2, 3, 4, 7, 8, 9, 10, 11, 12, 13]);
    assert_eq!(seen[5].1, 2, "{seen:?}");
    assert!(seen.iter().enumerate().all(|(i, s)| (s.1 > 0) == (i == 5)));
    // No burst: one frame for the three slots the stall took (cycle 7, half a period into
    // its slot), and every frame a good part of a period after the one before.
    for w in seen.windows(2) {
        assert!(w[1].2 - w[0].2 > period * 2 / 5, "{seen:?}");
    }
    // Cycle 7 is sent in its own slot (2.5 periods after cycle 5's: half a period into 7's).
    assert!(seen[5].2 - first >= 7 * period && seen[5].2 - first < 8 * period);
}
