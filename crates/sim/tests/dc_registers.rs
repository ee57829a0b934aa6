//! DC registers as ecsync's bring-up leaves them, against the register description and the real
//! captures (../shared/captures/README.md): the reference clock's System Time Difference 0x092C.

use ecsync_master::{BringupConfig, Engine, Network, bringup};
use ecsync_sim::model::{DcSupport, EscModel};
use ecsync_sim::transport::{MasterClock, SIM_EPOCH_NS, SimTransport};
use ecsync_sim::{Segment, SlaveSpec, preset};
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};

fn bring_up(specs: &[SlaveSpec]) -> (SimTransport, Network) {
    let mut sim = SimTransport::new(Segment::new(specs).unwrap());
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    (sim, net)
}

/// Every slave's 0x092C by FPRD, one frame, 1 ms after the bring-up ended.
fn read_092c(sim: &mut SimTransport, net: &Network) -> Vec<u32> {
    let mut buf = [0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x10; 6]).unwrap();
    for (i, s) in net.slaves.iter().enumerate() {
        let a = DatagramAddress::Configured {
            adp: s.station,
            ado: reg::DC_SYSTEM_TIME_DIFF,
        };
        b.push_zeroed(Command::Fprd, i as u8, a, 4).unwrap();
    }
    let n = b.finish();
    let t = sim.now_ps() + 1_000_000_000;
    sim.segment_mut().process(&mut buf[..n], t);
    let f = EcatFrame::new_checked(&buf[..n]).unwrap();
    f.datagrams()
        .map(|d| {
            let d = d.unwrap();
            assert_eq!(d.wkc(), 1);
            u32::from_le_bytes(d.data()[..4].try_into().unwrap())
        })
        .collect()
}

#[test]
fn the_reference_reads_zero_after_the_bring_up() {
    check_reference_and_signs(&preset::paper_2024());
    // The same drives on EBUS terminals (10 ns stamps).
    let ebus: Vec<SlaveSpec> = preset::paper_2024()
        .into_iter()
        .map(|mut s| {
            s.model = EscModel::ebus_terminal(DcSupport::Full64);
            s
        })
        .collect();
    check_reference_and_signs(&ebus);
}

fn check_reference_and_signs(specs: &[SlaveSpec]) {
    let (mut sim, net) = bring_up(specs);
    assert!(net.lock.converged);
    let raws = read_092c(&mut sim, &net);
    eprintln!("0x092C after the bring-up: {raws:08x?}");
    // The reference is read by FRMW, never compared: the reset value, as the EK1100 in
    // replay-dc.pcapng reads it (0x80000000 would say "local copy smaller than received").
    assert_eq!(raws[usize::from(net.reference)], 0x0000_0000);
    // The others were compared: each is the sign-magnitude of its filtered difference
    // `local - received`, bit 31 set exactly when that is negative.
    for (i, &raw) in raws.iter().enumerate() {
        if i == usize::from(net.reference) {
            continue;
        }
        // The model's filtered difference, local copy - received (its own record of the
        // compares), against what the register shows.
        let dt = sim
            .segment()
            .esc(i)
            .dc()
            .unwrap()
            .time_difference_ns()
            .round() as i64;
        assert_eq!(raw & 0x7fff_ffff, dt.unsigned_abs() as u32, "slave {i}");
        assert_eq!(
            raw & 0x8000_0000 != 0,
            dt < 0,
            "slave {i}: bit 31 for {dt} ns"
        );
        assert!(dt.abs() < 100, "slave {i} locked: {dt} ns");
    }
}

/// The paper-2024 drives with the drives at `dc32` replaced by the 32-bit-DC drive model
/// (servo-mii-dc32, the Kollmorgen AKD's ESC: 0x0008 = 0x0184).
fn with_dc32(dc32: &[usize]) -> Vec<SlaveSpec> {
    let mut specs = preset::paper_2024();
    for &i in dc32 {
        specs[i].model = EscModel::servo_mii_dc32();
    }
    specs
}

/// Brings `specs` up with the master's clock set so that the low 32 bits of its time, which the
/// reference's system time takes at the latch, wrap `wrap_after_ns` after the simulation's start;
/// checks the delays against the ground truth, the lock, and that the wrap fell between the
/// start of drift compensation and the declared lock.
fn check_32_bit(specs: &[SlaveSpec], wrap_after_ns: u64) {
    let mut sim = SimTransport::new(Segment::new(specs).unwrap());
    let epoch = SIM_EPOCH_NS - (SIM_EPOCH_NS + wrap_after_ns) % (1 << 32);
    sim.set_master_clock(MasterClock::ideal(epoch));
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    for s in &net.slaves {
        let i = usize::from(s.position);
        let dc32 = specs[i].model.dc == DcSupport::Full32;
        assert_eq!(s.features, if dc32 { 0x0184 } else { 0x00fc }, "slave {i}");
    }
    let truth = sim.segment().true_delays_ns(usize::from(net.reference));
    for s in &net.slaves {
        let d = s.delay_ns.unwrap();
        let t = truth[usize::from(s.position)].unwrap();
        assert!((d - t).abs() <= 20.0, "slave {}: {d} vs {t}", s.position);
    }
    eprintln!("{:?}", net.lock);
    assert!(net.lock.converged, "DC lock");
    assert!(net.lock.max_abs_092c_after_lock_ns < 100);
    let declared = net.lock.declared_ns.unwrap();
    assert!(
        net.lock.drift_start_ns >> 32 < declared >> 32,
        "the 32-bit time wrapped during drift compensation ({:#x} .. {declared:#x})",
        net.lock.drift_start_ns
    );
    let raws = read_092c(&mut sim, &net);
    assert_eq!(raws[usize::from(net.reference)], 0);
    assert!(raws.iter().all(|r| r & 0x7fff_ffff < 100), "{raws:08x?}");
    // The 32-bit units' system time is the low half of the 64-bit ones'.
    let t = sim.now_ps();
    let st: Vec<u64> = (0..specs.len())
        .map(|i| sim.segment().esc(i).dc().unwrap().system_time_ns(t))
        .collect();
    for (i, s) in specs.iter().enumerate() {
        if s.model.dc == DcSupport::Full32 {
            assert!(st[i] < 1 << 32, "slave {i}: {:#x}", st[i]);
        }
        let d = ecsync_wire::dc_time::diff_u32(st[i] as u32, st[0] as u32);
        assert!(d.abs() < 100, "slave {i}: {d} ns from the reference");
    }
}

#[test]
fn a_32_bit_reference_comes_up_locked_across_the_wrap() {
    // The first drive, the reference, has a 32-bit DC unit.
    check_32_bit(&with_dc32(&[0]), 400_000_000);
}

#[test]
fn slaves_with_32_bit_dc_come_up_locked_across_the_wrap() {
    check_32_bit(&with_dc32(&[2, 5]), 400_000_000);
    check_32_bit(&with_dc32(&[0, 1, 2, 3, 4, 5]), 100_000_000);
}
