//! Issue 34, acceptance 1, with ecsync's own master in virtual time: the `oversampling`
//! preset (a coupler, a four-sample terminal, a servo drive) on a 1 ms cycle. The master runs
//! the terminal on SYNC1 (SYNC0 every 250 us, SYNC1 every 1 ms on the grid where the drive's
//! SYNC0 pulse is), its 0x1C32 consistent with the SYNC registers, and every SYNC1 event
//! takes a new block: none missed, none overwritten, over 3 000 cycles.

use ecsync_dc::MedianSync;
use ecsync_dc::time::MasterInstant;
use ecsync_master::bringup::Oversampled;
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{CyclicDriver, CyclicLimits};
use ecsync_master::transport::Transport;
use ecsync_master::{BringupConfig, Engine, Stage, bringup};
use ecsync_sim::Segment;
use ecsync_sim::config::parse_segment;
use ecsync_sim::preset::OVERSAMPLING_TOML;
use ecsync_sim::transport::SimTransport;

const PERIOD_NS: u64 = 1_000_000;
const SHIFT_NS: u32 = 300_000;

/// The preset brought up to OP by ecsync's master told of `oversampled`.
fn brought_up(
    oversampled: Vec<Oversampled>,
) -> Result<(SimTransport, ecsync_master::Network), String> {
    let specs = parse_segment("presets/oversampling.toml", OVERSAMPLING_TOML).unwrap();
    let mut sim = SimTransport::new(Segment::new(&specs).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: 1_000,
        lock_hold_checks: 50,
        sync0_shift_ns: SHIFT_NS,
        oversampled,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .map_err(|e| e.to_string())?;
    Ok((sim, net))
}

#[test]
fn ecsync_runs_an_oversampling_terminal_on_sync1_with_no_missed_event() {
    let (mut sim, net) = brought_up(vec![Oversampled {
        position: 1,
        samples: 4,
    }])
    .unwrap();
    let seg = sim.segment();
    let (terminal, drive) = (seg.esc(1), seg.esc(2));
    assert!(terminal.runs_on_sync1(), "the terminal on SYNC1");
    assert!(
        drive.runs_on_sync0() && !drive.runs_on_sync1(),
        "the drive on SYNC0"
    );
    let dc = terminal.dc().unwrap();
    let (s0_start, s0_cycle) = dc.sync0().unwrap();
    assert_eq!(s0_cycle, 250_000, "SYNC0 four times a cycle");
    let (first, period) = terminal.application_events().unwrap();
    assert_eq!(period, 1_000_000, "SYNC1 once a cycle");
    assert_eq!(
        first,
        s0_start + 750_000,
        "SYNC1 = SYNC0 x 3 after the start"
    );
    // SYNC1 on the drive's SYNC0 grid (both in system time): the same deadline.
    let (d_start, d_cycle) = drive.dc().unwrap().sync0().unwrap();
    assert_eq!(d_cycle, 1_000_000);
    assert_eq!(first % PERIOD_NS, d_start % PERIOD_NS, "SYNC1 on the grid");
    assert_eq!(
        d_start % PERIOD_NS,
        u64::from(SHIFT_NS),
        "the grid: cycle + shift"
    );
    let od = &terminal.sdo_server().unwrap().od;
    assert_eq!(od.read_u32(0x1c32, 1), 3, "0x1C32:01 DC SYNC1");
    assert_eq!(
        od.read_u32(0x1c32, 2),
        1_000_000,
        "0x1C32:02 the cycle = SYNC1's period"
    );

    // 3 000 cycles of median on the grid.
    let cyc = CyclicConfig::for_network(&net, PERIOD_NS as u32, 2).expect("a reference");
    let first_cycle = (sim.now().as_ns() / PERIOD_NS + 2) * PERIOD_NS;
    let mut eng = CyclicEngine::new(
        MedianSync::new(11, 0.01, 2),
        cyc,
        MasterInstant::from_ns(first_cycle),
    )
    .unwrap();
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(3_002),
        ..CyclicLimits::default()
    });
    // (The test's own gap between the bring-up and the first cycle costs the events in it:
    // counted from the second cycle on.)
    driver.run(&mut sim, &mut eng, 2, None, |_, _| {}).unwrap();
    let counts = |sim: &SimTransport, p: usize| {
        let e = sim.segment().esc(p);
        (e.sm_events_missed(), e.outputs_overwritten())
    };
    let (t0, d0) = (counts(&sim, 1), counts(&sim, 2));
    driver
        .run(&mut sim, &mut eng, 3_000, None, |_, _| {})
        .unwrap();
    let (t1, d1) = (counts(&sim, 1), counts(&sim, 2));
    assert_eq!(
        (t1.0 - t0.0, t1.1 - t0.1),
        (0, 0),
        "terminal: SYNC1 events missed, blocks overwritten"
    );
    assert_eq!(
        (d1.0 - d0.0, d1.1 - d0.1),
        (0, 0),
        "drive: SYNC0 pulses missed, outputs overwritten"
    );
    let t = sim.segment().esc(1);
    assert_eq!(t.al_state(), ecsync_wire::AlState::Op);
}

/// A master that does not know the terminal oversamples sets it to DC SYNC0 (mode 2) on the
/// cycle, as it does every drive: the terminal then takes a block per SYNC0 and never plays
/// more than one sample a cycle; with the SYNC1 set-up and the wrong samples (3 where the
/// terminal has 4: SYNC1 every 3 SYNC0) it refuses OP with 0x0030.
#[test]
fn a_wrong_sync1_set_up_keeps_the_terminal_out_of_op() {
    let (sim, _) = brought_up(Vec::new()).unwrap();
    let t = sim.segment().esc(1);
    assert!(t.runs_on_sync0() && !t.runs_on_sync1());
    let Err(e) = brought_up(vec![Oversampled {
        position: 1,
        samples: 5,
    }]) else {
        panic!("five samples on a four-sample terminal went to OP");
    };
    assert!(e.contains("0x0030") || e.contains("invalid DC"), "{e}");
}
