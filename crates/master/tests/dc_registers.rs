//! DC registers as ecsync's bring-up leaves them, against the register description and the real
//! captures (../shared/captures/README.md): the reference clock's System Time Difference 0x092C.

use ecsync_esc::model::{DcSupport, EscModel};
use ecsync_esc::{Segment, SlaveSpec, preset};
use ecsync_master::sim::SimTransport;
use ecsync_master::{BringupConfig, Engine, Network, bringup};
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};

fn bring_up(specs: &[SlaveSpec]) -> (SimTransport, Network) {
    let mut sim = SimTransport::new(Segment::new(specs).unwrap());
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim.run(&mut engine, |_, _, _| {}).expect("bring-up");
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
    let t = sim.now_ps + 1_000_000_000;
    sim.segment.process(&mut buf[..n], t);
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
            .segment
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
