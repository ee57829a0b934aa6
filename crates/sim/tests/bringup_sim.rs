//! The bring-up against the virtual segment, checked against the segment's ground truth.

use ecsync_master::{BringupConfig, Engine, bringup};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, preset};

#[test]
fn paper_2024_comes_up_locked_with_true_delays() {
    let seg = Segment::new(&preset::paper_2024()).unwrap();
    let mut sim = SimTransport::new(seg);
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    let truth = sim.segment().true_delays_ns(usize::from(net.reference));
    for s in &net.slaves {
        let d = s.delay_ns.unwrap();
        let t = truth[usize::from(s.position)].unwrap();
        eprintln!(
            "slave {} delay {d:.1} true {t:.1} spread {:?}",
            s.position, s.delay_spread_ns
        );
        assert!((d - t).abs() <= 20.0, "slave {}: {d} vs {t}", s.position);
    }
    eprintln!("{:?}", net.lock);
    assert!(net.lock.converged);
    assert!(net.lock.max_abs_092c_after_lock_ns < 100);
    assert_eq!(net.expected_lrw_wkc, 18);
    assert_eq!(net.pdi_len, 204);
}

/// A drive whose cycle time 0x1C32:02 is read-only (Ingenia's EVS-NET-01 ESI has it `ro`): the
/// master's switch to DC SYNC0 in PRE-OP takes the abort (0x06010002) as "the drive sets its
/// own cycle" and the bring-up goes on to OP. The drives are the project's virtual drive built
/// from its ESI (esi/ecsync-virtual-drive.xml), with that one entry made read-only.
#[test]
fn drives_with_a_read_only_cycle_time_come_up_in_dc_sync0() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../esi/ecsync-virtual-drive.xml"
    );
    let text = std::fs::read_to_string(path).unwrap();
    let rw = "<Name>Cycle time</Name><Type>UDINT</Type><BitSize>32</BitSize><BitOffs>32</BitOffs><Flags><Access WriteRestrictions=\"PreOP\">rw</Access>";
    assert!(text.contains(rw), "the shipped ESI's 0x1C32:02");
    let ro = text.replace(
        rw,
        &rw.replace("<Access WriteRestrictions=\"PreOP\">rw", "<Access>ro"),
    );
    let esi = ecsync_sim::esi::parse("read-only-cycle.xml", &ro).unwrap();
    let mut specs = preset::line(3, 1);
    for (i, s) in specs.iter_mut().enumerate() {
        s.device = esi.devices[0].device_info(i as u32 + 1);
    }
    let seg = Segment::new(&specs).unwrap();
    for i in 0..3 {
        let mut od = seg.esc(i).sdo_server().unwrap().od.clone();
        assert!(
            od.write(
                0x1c32,
                2,
                &500_000u32.to_le_bytes(),
                ecsync_wire::AlState::PreOp
            )
            .is_err(),
            "0x1C32:02 is read-only"
        );
    }
    let mut sim = SimTransport::new(seg);
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up");
    assert!(net.lock.converged);
    for i in 0..3 {
        let od = &sim.segment().esc(i).sdo_server().unwrap().od;
        assert_eq!(od.read_u32(0x1c32, 1), 2, "drive {i}: DC SYNC0");
        assert_eq!(od.read_u32(0x1c33, 1), 2, "drive {i}: DC SYNC0 (inputs)");
        assert_eq!(
            od.read_u32(0x1c32, 2),
            1_000_000,
            "drive {i}: its own cycle time"
        );
        assert_eq!(sim.segment().esc(i).al_state(), ecsync_wire::AlState::Op);
    }
}
