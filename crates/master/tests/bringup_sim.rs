//! The bring-up against the virtual segment, checked against the segment's ground truth.

use ecsync_esc::{Segment, preset};
use ecsync_master::sim::SimTransport;
use ecsync_master::{BringupConfig, Engine, bringup};

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
