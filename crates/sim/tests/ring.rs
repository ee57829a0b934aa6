//! Issue 34, cable redundancy, the segment's part: a line of twelve drives made a ring (the
//! last drive's port 1 cabled to the master's second port), each case worked out by hand from
//! the ESC's processing order (port 0 -> processing unit -> port 3 -> port 1 -> port 2) and
//! its loop control (a port without link closes and loops the frame back):
//!
//! * intact, a frame sent on the first port passes every processing unit and leaves the
//!   segment to the second port, one hop after the last drive's; one sent on the second runs
//!   the ring backwards through the ports alone (no processing unit: each follows port 0) and
//!   comes back on the first;
//! * with the cable between drives 5 and 6 pulled, each frame is processed by the drives on
//!   its side, in its order, and comes back on the port it left by; the working counters of
//!   the two add up to the intact ring's; both ends count the lost link (0x0310 + port);
//! * plugged in again, the ring is whole again.

use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};

const N: usize = 12;

/// One datagram in a frame, sent on the master's first port (`secondary` false) or second at
/// `t_ps`: the returned port, the time back (ps after the send), the working counter and the
/// data.
fn send(
    seg: &mut Segment,
    secondary: bool,
    cmd: Command,
    addr: DatagramAddress,
    len: usize,
    t_ps: u64,
) -> (Option<(u8, u64)>, u16, Vec<u8>) {
    let mut buf = [0u8; 1514];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x00, 1, 2, 3, 4, 5]).unwrap();
    b.push(cmd, 0x11, addr, &vec![0u8; len]).unwrap();
    let n = b.finish();
    let out = if secondary {
        seg.process_secondary(&mut buf[..n], t_ps)
    } else {
        seg.process(&mut buf[..n], t_ps)
    };
    let f = EcatFrame::new_checked(&buf[..n]).unwrap();
    let d = f.datagrams().next().unwrap().unwrap();
    (
        out.returned_sof_ps.map(|t| (out.returned_port, t - t_ps)),
        d.wkc(),
        d.data().to_vec(),
    )
}

fn brd(seg: &mut Segment, secondary: bool, t_ps: u64) -> (Option<(u8, u64)>, u16) {
    let (back, wkc, _) = send(
        seg,
        secondary,
        Command::Brd,
        DatagramAddress::position(0, 0x0000),
        2,
        t_ps,
    );
    (back, wkc)
}

/// The lost link counters (0x0310-0x0313) of the drive `k` processing units into a frame
/// sent on the given port.
fn lost_links(seg: &mut Segment, secondary: bool, k: u16, t_ps: u64) -> Vec<u8> {
    let addr = DatagramAddress::position(k, 0x0310);
    let (_, wkc, data) = send(seg, secondary, Command::Aprd, addr, 4, t_ps);
    assert_eq!(wkc, 1);
    data
}

#[test]
fn a_ring_of_twelve_drives_before_during_and_after_a_pulled_cable() {
    let mut seg = Segment::new(&preset::line(N, 34)).unwrap();
    // Without the ring, the second port reaches nothing.
    assert_eq!(brd(&mut seg, true, 1_000_000).0, None);
    seg.connect_ring(N - 1, 1, 2.0).unwrap();
    assert_eq!(seg.ring(), Some((N - 1, 1)));
    // The port is taken now; a second ring cable is refused.
    assert!(seg.connect_ring(N - 1, 1, 2.0).is_err());

    // Intact, the first port: every drive, out at the second port.
    let (back, wkc) = brd(&mut seg, false, 10_000_000);
    assert_eq!(wkc, N as u16);
    let (port, t_back) = back.expect("the frame comes back");
    assert_eq!(port, 1, "to the master's second port");
    let pu: Vec<u64> = (0..N)
        .map(|p| seg.trace().pu_ps(p).unwrap() - 10_000_000)
        .collect();
    let models: Vec<_> = (0..N).map(|p| seg.esc(p).model().clone()).collect();
    let m = |p: usize| models[p].clone();
    let ps = |ns: f64| (ns * 1000.0).round() as u64;
    // By hand: the last drive's processing unit, its processing to port 1, the ring cable
    // (its PHY and 2 m at 5 ns/m).
    let ring_ps = ps(m(N - 1).link_phy_delay_ns) + 10_000;
    assert_eq!(
        t_back,
        pu[N - 1] + ps(m(N - 1).processing_delay_ns) + ring_ps
    );

    // Intact, the second port: backwards through the ports, no processing unit, out at the
    // first: the ring cable, each hop's cable (the first port's frame told them: pu[k+1] -
    // pu[k] less the processing), each drive's forwarding, the first drive's cable.
    let (back, wkc) = brd(&mut seg, true, 20_000_000);
    assert_eq!(wkc, 0, "no processing unit on the way back");
    assert!((0..N).all(|p| seg.trace().pu_ps(p).is_none()));
    let hops: u64 = (0..N - 1)
        .map(|k| pu[k + 1] - pu[k] - ps(m(k).processing_delay_ns))
        .sum();
    let forwarding: u64 = (0..N).map(|k| ps(m(k).forwarding_delay_ns)).sum();
    assert_eq!(back, Some((0, ring_ps + hops + forwarding + pu[0])));

    // The cable between drives 5 and 6 (positions 4 and 5) pulled.
    assert!(seg.set_link(4, 1, false));
    let (back_a, wkc_a) = brd(&mut seg, false, 30_000_000);
    let (back_b, wkc_b) = brd(&mut seg, true, 30_100_000);
    assert_eq!((wkc_a, wkc_b), (5, 7), "each side its drives");
    assert_eq!(wkc_a + wkc_b, N as u16, "together the ring's");
    assert_eq!(back_a.map(|b| b.0), Some(0), "back on the first port");
    assert_eq!(back_b.map(|b| b.0), Some(1), "back on the second port");
    // The second port's frame: drives 6 to 12 in that order (each processes it on its way
    // back, after its port 0), drives 1 to 5 not at all.
    let t: Vec<Option<u64>> = (0..N).map(|p| seg.trace().pu_ps(p)).collect();
    assert!(t[..5].iter().all(Option::is_none), "{t:?}");
    assert!(t[5..].windows(2).all(|w| w[0] < w[1]), "{t:?}");
    // Both ends of the pulled cable counted one lost link: drive 5 on port 1, drive 6 on
    // port 0 (the first processing unit the second port's frame meets).
    assert_eq!(lost_links(&mut seg, false, 4, 40_000_000), [0, 1, 0, 0]);
    assert_eq!(lost_links(&mut seg, true, 0, 40_100_000), [1, 0, 0, 0]);

    // Plugged in again: the ring is whole.
    assert!(seg.set_link(4, 1, true));
    let (back, wkc) = brd(&mut seg, false, 50_000_000);
    assert_eq!((back.map(|b| b.0), wkc), (Some(1), N as u16));
    let (back, wkc) = brd(&mut seg, true, 50_100_000);
    assert_eq!((back.map(|b| b.0), wkc), (Some(0), 0));
}

/// A ring cable to a port the model lacks or one in use is refused, naming it.
#[test]
fn a_ring_cable_needs_a_free_port() {
    let mut seg = Segment::new(&preset::line(3, 1)).unwrap();
    // Port 0 of the last drive is its cable up the line.
    let e = seg.connect_ring(2, 0, 1.0).unwrap_err().to_string();
    assert!(e.contains("port 0"), "{e}");
    // servo-mii has ports 0 and 1 only.
    let e = seg.connect_ring(2, 2, 1.0).unwrap_err().to_string();
    assert!(e.contains("port 2"), "{e}");
    assert!(seg.connect_ring(2, 1, f64::NAN).is_err());
}
