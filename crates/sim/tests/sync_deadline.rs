//! Issue 13, acceptance 3, in virtual time with the master's own cyclic driver: frames sent
//! after the drives' SYNC0 in chosen cycles, and cycles the host skipped, make every drive
//! count exactly the SYNC0 pulses that found no new outputs (worked out by hand below) in
//! 0x1C32:0B; the master reads the counter over CoE in the cyclic phase and gets that count.
//! Past a configured sync error limit (0x10F1:02) the drives leave OP with 0x001A, and the
//! master reports it and brings them back.

use ecsync_dc::MedianSync;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_master::bringup::BringupTimeouts;
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{CyclicDriver, CyclicLimits};
use ecsync_master::recovery::RecoveryConfig;
use ecsync_master::transport::{HostStall, Received, Transport};
use ecsync_master::{BringupConfig, Engine, Network, Stage, bringup};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, preset};

const PERIOD_NS: u64 = 1_000_000;
const SHIFT_NS: u32 = 300_000;

/// paper-2024 brought up to OP with SYNC0 at `SHIFT_NS` (the drives set to DC SYNC0 over
/// CoE), and the cyclic engine whose first cycle starts two periods on.
fn paper_2024_in_op() -> (SimTransport, Network, CyclicEngine<MedianSync>) {
    paper_2024_in_op_with(None)
}

/// [`paper_2024_in_op`] with the bring-up configured to write the sync error counter limit.
fn paper_2024_in_op_with(
    sync_error_limit: Option<u16>,
) -> (SimTransport, Network, CyclicEngine<MedianSync>) {
    let mut sim = SimTransport::new(Segment::new(&preset::paper_2024()).unwrap());
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: 1_000,
        lock_hold_checks: 50,
        sync0_shift_ns: SHIFT_NS,
        sync_error_limit,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let net = sim.run_procedure(&mut engine, |_, _, _| {}).unwrap();
    let cyc = CyclicConfig::for_network(&net, PERIOD_NS as u32, 2).expect("a reference");
    // Sent at the grid point: the frames pass the drives a few us after it, ~295 us before
    // SYNC0.
    let first = (sim.now().as_ns() / PERIOD_NS + 2) * PERIOD_NS;
    let eng = CyclicEngine::new(
        MedianSync::new(11, 0.01, 2),
        cyc,
        MasterInstant::from_ns(first),
    )
    .unwrap();
    (sim, net, eng)
}

/// The recovery the drivers run beside the cycle (and the counters' reads in its slot).
fn recovery() -> RecoveryConfig {
    RecoveryConfig {
        cycle_ns: PERIOD_NS as u32,
        sync0_shift_ns: SHIFT_NS,
        sync0_lead_ns: 20_000_000,
        timeouts: BringupTimeouts::default(),
        static_drift_frames: 1_000,
        sync_error_limit: None,
        oversampled: Vec::new(),
    }
}

#[test]
fn drives_count_sync0_pulses_without_outputs_and_the_master_reads_them() {
    let (sim, net, mut eng) = paper_2024_in_op();
    let drives: Vec<usize> = (0..sim.segment().len())
        .filter(|&x| sim.segment().esc(x).runs_on_sync0())
        .collect();
    assert_eq!(
        drives.len(),
        6,
        "every drive set to DC SYNC0 over CoE by the bring-up"
    );
    // Worked out by hand, pulses at grid + 300 us:
    // - cycle 100 sent 500 us late: after its SYNC0, before the next: 1 missed;
    // - cycles 200 and 201 both 500 us late: 1 missed (pulse 201 takes cycle 200's outputs,
    //   as far as the drive can tell);
    // - cycle 300: the host 2.1 periods late: slots 300 and 301 skipped, cycle 302's frame
    //   100 us after its grid point, before its SYNC0: pulses 300 and 301 found nothing: 2.
    let expected_new = 1 + 1 + 2;
    let mut tr = HostStall::at_cycles(
        sim,
        vec![
            (100, MasterDuration::from_ns(500_000)),
            (200, MasterDuration::from_ns(500_000)),
            (201, MasterDuration::from_ns(500_000)),
            (300, MasterDuration::from_ns(2 * PERIOD_NS + PERIOD_NS / 10)),
            // The second part: with the limit set, a host 2.1 periods late.
            (800, MasterDuration::from_ns(2 * PERIOD_NS + PERIOD_NS / 10)),
        ],
    );
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(1_400),
        sync_counters_every: Some(MasterDuration::from_ms(100)),
        ..CyclicLimits::default()
    });
    driver.set_recovery(net.clone(), recovery());
    // The count after cycle 20 (the hand-over from the bring-up to the cyclic phase may have
    // cost a pulse or two, counted as a drive would).
    let mut base: Vec<u64> = Vec::new();
    driver
        .run(&mut tr, &mut eng, 700, None, |t, c| {
            if c.record.cycle == 20 {
                base = drives
                    .iter()
                    .map(|&x| t.inner.segment().esc(x).sm_events_missed())
                    .collect();
            }
        })
        .unwrap();
    assert_eq!(base.len(), drives.len());
    let reads = driver.sync_counters();
    assert_eq!(reads.len(), drives.len(), "{reads:?}");
    for (k, &x) in drives.iter().enumerate() {
        let count = tr.inner.segment().esc(x).sm_events_missed();
        assert_eq!(count - base[k], expected_new, "drive at {x}");
        // The master's last read (after cycle 600) is the drive's count.
        let r = &reads
            .iter()
            .find(|r| usize::from(r.1.position) == x)
            .unwrap()
            .1;
        assert_eq!(u64::from(r.sm_events_missed), count, "drive at {x}: {r:?}");
    }
    assert!(driver.recoveries().is_empty(), "{:?}", driver.recoveries());

    // Past the limit: SSC's default of 4; two pulses missed at once add 6.
    for &x in &drives {
        tr.inner.segment_mut().esc_mut(x).set_sync_error_limit(4);
    }
    driver.run(&mut tr, &mut eng, 700, None, |_, _| {}).unwrap();
    let rec = driver.recoveries();
    assert!(!rec.is_empty(), "the drives' sync error was not noticed");
    let left: Vec<String> = rec.iter().flat_map(|e| e.left_op()).collect();
    for &x in &drives {
        let who = format!("slave {} in SAFE-OP with AL error 0x001a", x + 1);
        assert!(
            left.iter().any(|l| l.starts_with(&who)),
            "drive at {x} not reported: {left:?}"
        );
    }
    // Brought back: in OP again at the end.
    for &x in &drives {
        assert_eq!(
            tr.inner.segment().esc(x).al_state(),
            ecsync_wire::AlState::Op,
            "drive at {x}"
        );
    }
}

/// A host whose replies vanish in one cycle out of `every` (a busy host reading them after
/// the next slot, or a lossy wire).
struct LossyHost {
    inner: SimTransport,
    every: u64,
    cycle: u64,
}

impl Transport for LossyHost {
    type Error = <SimTransport as Transport>::Error;

    // What it changes first: the replies of one cycle in `every`, and which cycle runs.
    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Self::Error> {
        if self.cycle % self.every == self.every / 2 {
            // Everything this cycle would have read is gone.
            while self.inner.recv(buf, deadline)?.is_some() {}
            return Ok(None);
        }
        self.inner.recv(buf, deadline)
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.cycle = cycle;
        self.inner.start_cycle(cycle);
    }

    // The rest is the segment's.
    fn now(&mut self) -> MasterInstant {
        self.inner.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        self.inner.sleep_until(t);
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Self::Error> {
        self.inner.send_with(len, at, fill)
    }
}

/// A read of the counters that a lost cycle interrupts starts again with the next cycle
/// answered: on a host that loses a cycle in seven the master still reads every drive each
/// period, and its last read is the drive's count at the end.
#[test]
fn a_counter_read_cut_by_a_lost_cycle_starts_again_at_once() {
    let (sim, net, mut eng) = paper_2024_in_op();
    let mut tr = LossyHost {
        inner: sim,
        every: 7,
        cycle: 0,
    };
    let every_ns = 50_000_000;
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(1_000),
        sync_counters_every: Some(MasterDuration::from_ns(every_ns)),
        ..CyclicLimits::default()
    });
    driver.set_recovery(net.clone(), recovery());
    let mut end_ns = 0;
    driver
        .run(&mut tr, &mut eng, 1_000, None, |t, _| {
            end_ns = t.now().as_ns()
        })
        .unwrap();
    let stats = driver.stats();
    assert!(stats.lost >= 1_000 / 7, "the host lost cycles: {stats:?}");
    let reads = driver.sync_counters();
    assert_eq!(reads.len(), 6, "{reads:?}");
    for (first, last) in &reads {
        assert!(first.read < last.read, "{first:?} {last:?}");
        // Read within the last period (and a few cycles for the read itself).
        assert!(
            last.read.as_ns() + every_ns + 10 * PERIOD_NS >= end_ns,
            "drive at {}: last read {} ms before the end",
            last.position,
            (end_ns - last.read.as_ns()) / 1_000_000
        );
    }
}

/// The limit as a master configures it: the bring-up writes 0x10F1:02 = 4 over CoE in PRE-OP
/// (no firmware setter), each drive's dictionary holds it, and a host 2.1 periods late once
/// (two pulses missed at once: 3 + 3 > 4, SSC's counting) takes every drive out of OP with
/// 0x001A; the master reports it and its recovery, which writes the limit again only to a
/// reset drive, brings them back. Without the configured limit the same host costs no OP.
#[test]
fn a_sync_error_limit_the_bring_up_writes_takes_the_drives_out_of_op() {
    for limit in [None, Some(4u16)] {
        let (sim, net, mut eng) = paper_2024_in_op_with(limit);
        for x in 0..sim.segment().len() {
            let od = &sim.segment().esc(x).sdo_server().unwrap().od;
            // The virtual drive's own default is 0 (count, do not react).
            assert_eq!(
                od.read_u32(0x10f1, 2),
                u32::from(limit.unwrap_or(0)),
                "drive at {x}"
            );
        }
        let mut tr = HostStall::at_cycles(
            sim,
            vec![(300, MasterDuration::from_ns(2 * PERIOD_NS + PERIOD_NS / 10))],
        );
        let mut driver = CyclicDriver::new(CyclicLimits {
            max_cycles: Some(700),
            ..CyclicLimits::default()
        });
        driver.set_recovery(
            net.clone(),
            RecoveryConfig {
                sync_error_limit: limit,
                ..recovery()
            },
        );
        driver.run(&mut tr, &mut eng, 700, None, |_, _| {}).unwrap();
        let left: Vec<String> = driver
            .recoveries()
            .iter()
            .flat_map(|e| e.left_op())
            .collect();
        if limit.is_none() {
            assert!(left.is_empty(), "no limit, no reaction: {left:?}");
            continue;
        }
        for x in 0..tr.inner.segment().len() {
            let who = format!("slave {} in SAFE-OP with AL error 0x001a", x + 1);
            assert!(
                left.iter().any(|l| l.starts_with(&who)),
                "drive at {x} not reported: {left:?}"
            );
            assert_eq!(
                tr.inner.segment().esc(x).al_state(),
                ecsync_wire::AlState::Op,
                "drive at {x} brought back"
            );
        }
    }
}

/// A drive whose supported sync modes (0x1C32:04 and 0x1C33:04) lack DC SYNC0 refuses
/// 0x1C32:01 = 2 with 0x06090030 (as SSC's `CheckSyncTypeValue`): the bring-up leaves it in
/// free run, as a drive without the objects, and brings the network to OP with the others
/// on SYNC0.
#[test]
fn a_drive_without_dc_sync0_among_its_modes_stays_in_free_run() {
    let mut sim = SimTransport::new(Segment::new(&preset::paper_2024()).unwrap());
    for index in [0x1c32, 0x1c33] {
        // Free run and SM-synchronous only.
        sim.segment_mut()
            .esc_mut(4)
            .sdo_server_mut()
            .unwrap()
            .od
            .set(index, 4, &0x0003u16.to_le_bytes());
    }
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: 1_000,
        lock_hold_checks: 50,
        sync0_shift_ns: SHIFT_NS,
        sync_error_limit: Some(4),
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    sim.run_procedure(&mut engine, |_, _, _| {}).unwrap();
    for x in 0..sim.segment().len() {
        let e = sim.segment().esc(x);
        assert_eq!(e.al_state(), ecsync_wire::AlState::Op, "drive at {x}");
        assert_eq!(e.runs_on_sync0(), x != 4, "drive at {x}");
        let od = &e.sdo_server().unwrap().od;
        assert_eq!(od.read_u32(0x1c32, 1), if x == 4 { 0 } else { 2 });
    }
}

/// The system time a drive took for its outputs' SYNC0 check, which the comparison's ground
/// truth reads instead of reading the clock again, is the unit's reading at that instant to
/// the bit, cycle after cycle (the end of the frame at the drive), and there is none at
/// another instant.
#[test]
fn the_time_a_drive_checked_its_outputs_at_is_its_clock_s_reading_there() {
    let (sim, _net, mut eng) = paper_2024_in_op();
    let drives: Vec<usize> = (0..sim.segment().len())
        .filter(|&x| sim.segment().esc(x).runs_on_sync0())
        .collect();
    let wire_ps = ecsync_sim::phy::frame_wire_time_ps(eng.frame_len_of(0));
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(300),
        ..CyclicLimits::default()
    });
    let mut taken = 0;
    let mut tr = HostStall::at_cycles(sim, Vec::new());
    driver
        .run(&mut tr, &mut eng, 300, None, |t, _| {
            let seg = t.inner.segment();
            for &x in &drives {
                let Some(pu) = t.inner.frame_trace(0).pu_ps(x) else {
                    continue;
                };
                let end = pu + wire_ps;
                let esc = seg.esc(x);
                let fresh = esc.dc().unwrap().system_time_split(end);
                if let Some(kept) = esc.system_time_at_outputs(end) {
                    assert_eq!((kept.0, kept.1.to_bits()), (fresh.0, fresh.1.to_bits()));
                    taken += 1;
                }
                assert_eq!(esc.system_time_at_outputs(end - 1), None);
            }
        })
        .unwrap();
    assert_eq!(taken, 300 * drives.len(), "every drive, every cycle");
}

/// A host stalled 150 ms (longer than the drives' 100 ms process data watchdog): each drive
/// counts the pulses without outputs up to its watchdog's expiry, worked out by hand: the last
/// outputs ~295 us before a pulse, that pulse takes them, the next 99 (up to 100 ms after the
/// outputs) find none: 99. It leaves OP there (0x001B), counts nothing in SAFE-OP, and the
/// master's recovery takes it back to OP with no burst of misses (before, its first outputs
/// back in OP counted every pulse it had spent out of OP).
#[test]
fn a_drive_cut_off_longer_than_its_watchdog_counts_up_to_the_expiry_only() {
    let (sim, net, mut eng) = paper_2024_in_op();
    let drives: Vec<usize> = (0..sim.segment().len())
        .filter(|&x| sim.segment().esc(x).runs_on_sync0())
        .collect();
    let mut tr = HostStall::at_cycles(sim, vec![(100, MasterDuration::from_ns(150_100_000))]);
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(700),
        ..CyclicLimits::default()
    });
    driver.set_recovery(net.clone(), recovery());
    let mut base: Vec<u64> = Vec::new();
    driver
        .run(&mut tr, &mut eng, 700, None, |t, c| {
            if c.record.cycle == 20 {
                base = drives
                    .iter()
                    .map(|&x| t.inner.segment().esc(x).sm_events_missed())
                    .collect();
            }
        })
        .unwrap();
    let left: Vec<String> = driver
        .recoveries()
        .iter()
        .flat_map(|e| e.left_op())
        .collect();
    for (k, &x) in drives.iter().enumerate() {
        let esc = tr.inner.segment().esc(x);
        assert_eq!(esc.sm_events_missed() - base[k], 99, "drive at {x}");
        assert_eq!(esc.al_state(), ecsync_wire::AlState::Op, "drive at {x}");
        let who = format!("slave {} in SAFE-OP with AL error 0x001b", x + 1);
        assert!(left.iter().any(|l| l.starts_with(&who)), "{x}: {left:?}");
    }
}
