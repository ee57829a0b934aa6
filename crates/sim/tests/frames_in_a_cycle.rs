//! Which of a cycle's frames reached the segment, past the 64th too: a network of thousands
//! of drives sends dozens of frames a cycle, and the ground truth judges only those its
//! slaves saw.

use ecsync_dc::time::MasterInstant;
use ecsync_master::transport::Transport;
use ecsync_sim::fault::{FaultPlayer, FaultSchedule};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress};

#[test]
fn frames_past_the_64th_lost_on_the_way_out_were_not_processed() {
    let schedule = FaultSchedule::parse(
        "loss.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.4\n",
    )
    .unwrap();
    let mut sim = SimTransport::new(Segment::new(&preset::line(2, 1)).unwrap());
    sim.set_faults(FaultPlayer::new(schedule, 7));
    let lost_out = |sim: &SimTransport| sim.faults().unwrap().counts().lost_out;
    for cycle in 0..3 {
        sim.start_cycle(cycle);
        let mut reached = Vec::new();
        let mut rx = Vec::new();
        for _ in 0..200 {
            let mut buf = [0u8; 60];
            let mut b =
                ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
            b.push_zeroed(Command::Brd, 0, DatagramAddress::position(0, 0x0130), 2)
                .unwrap();
            let n = b.finish();
            let before = lost_out(&sim);
            let now = sim.now();
            sim.send(&buf[..n], MasterInstant::from_ns(now.as_ns() + 1_000))
                .unwrap();
            reached.push(lost_out(&sim) == before);
            let deadline = MasterInstant::from_ns(sim.now().as_ns() + 100_000);
            while sim.recv(&mut rx, deadline).unwrap().is_some() {}
        }
        let late_lost = reached[64..].iter().filter(|r| !**r).count();
        assert!(
            late_lost > 10,
            "the fault took {late_lost} frames past the 64th"
        );
        for (k, &r) in reached.iter().enumerate() {
            assert_eq!(sim.frame_processed(k), r, "cycle {cycle}, frame {k}");
        }
    }
}
