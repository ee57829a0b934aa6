//! The ESCs' error counters as a master reads them (FPRD of 0x0300-0x0313), against the ESC
//! datasheet (section I "Error Counters", section II 0x0300-0x0313): a pulled cable counts one
//! lost link at both of its ends, a frame whose FCS broke on its way back counts an invalid
//! frame at the first ESC that receives it and a forwarded error at every ESC after it, every
//! counter stops at 0xFF, a write clears them, a power cycle starts them at 0. Expected values
//! are worked out by hand from the line's cabling (slave k's port 1 to slave k+1's port 0).

mod common;

use common::{Bus, fp};
use ecsync_sim::fault::{FaultPlayer, FaultSchedule};
use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress};

const S: u64 = 1_000_000_000_000;
const MS: u64 = 1_000_000_000;

/// Station address of the slave at 1-based position `k`.
fn station(k: u16) -> u16 {
    0x1000 + k
}

/// A line of `n` drives with station addresses 0x1001.. (APWR 0x0010, as a master's scan).
fn line(n: usize) -> Bus {
    let mut bus = Bus::new(Segment::new(&preset::line(n, 1)).unwrap());
    for k in 0..n as u16 {
        let d = bus.one(
            Command::Apwr,
            DatagramAddress::position(k, 0x0010),
            &station(k + 1).to_le_bytes(),
        );
        assert_eq!(d.wkc, 1);
    }
    bus
}

/// Registers 0x0300-0x0313 of the slave at 1-based position `k`, read with an FPRD.
fn counters(bus: &mut Bus, k: u16) -> [u8; 0x14] {
    let d = bus.one(Command::Fprd, fp(station(k), 0x0300), &[0; 0x14]);
    assert_eq!(d.wkc, 1, "slave {k} answers");
    d.data.try_into().unwrap()
}

/// The lost link counters 0x0310-0x0313 of the slave at 1-based position `k`.
fn lost_links(bus: &mut Bus, k: u16) -> [u8; 4] {
    counters(bus, k)[0x10..].try_into().unwrap()
}

/// A broadcast read through the player: the slaves the frame reached.
fn brd(bus: &mut Bus, p: &mut FaultPlayer, t_ps: u64) -> u16 {
    let mut buf = [0u8; 60];
    let mut b = ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
    b.push_zeroed(Command::Brd, 0, DatagramAddress::position(0, 0), 1)
        .unwrap();
    let n = b.finish();
    p.before_frame(&mut bus.seg, &buf[..n], t_ps);
    bus.seg.process(&mut buf[..n], t_ps);
    bus.t_ps = t_ps;
    common::datagrams(&buf[..n])[0].wkc
}

#[test]
fn a_pulled_cable_counts_one_lost_link_at_both_ends() {
    let mut bus = line(6);
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 1.0\nfor_s = 0.5\nkind = \"link_down\"\nslave = 3\nport = 1\n",
    )
    .unwrap();
    let mut p = FaultPlayer::new(s, 1);
    let t0 = bus.t_ps + MS;
    assert_eq!(brd(&mut bus, &mut p, t0), 6);
    // The cyclic frames every 100 ms; the window's edges by the clock.
    let mut t = t0;
    while t < t0 + 2 * S {
        t += 100 * MS;
        p.advance_to(&mut bus.seg, t);
        let reached = brd(&mut bus, &mut p, t);
        let inside = t >= t0 + S && t < t0 + 1_500 * MS;
        assert_eq!(reached, if inside { 3 } else { 6 }, "at {t} ps");
    }
    // The cable between slave 3 (port 1) and slave 4 (port 0): one lost link at each end.
    assert_eq!(lost_links(&mut bus, 3), [0, 1, 0, 0]);
    assert_eq!(lost_links(&mut bus, 4), [1, 0, 0, 0]);
    for k in [1, 2, 5, 6] {
        assert_eq!(lost_links(&mut bus, k), [0; 4], "slave {k}");
    }
    // Nothing else counted: no frame broke.
    for k in 1..=6 {
        assert_eq!(counters(&mut bus, k)[..0x0e], [0; 0x0e], "slave {k}");
    }
}

#[test]
fn a_lost_link_counter_stops_at_0xff() {
    let mut bus = line(4);
    for n in 1..=300u32 {
        assert!(bus.seg.set_link(2, 1, false));
        assert!(bus.seg.set_link(2, 1, true));
        if n == 254 {
            assert_eq!(lost_links(&mut bus, 3), [0, 254, 0, 0]);
        }
    }
    // 300 losses: 0xFF, not 300 mod 256 = 44.
    assert_eq!(lost_links(&mut bus, 3), [0, 0xff, 0, 0]);
    assert_eq!(lost_links(&mut bus, 4), [0xff, 0, 0, 0]);
    assert_eq!(bus.seg.esc(2).error_counters()[0x11], 0xff);
}

#[test]
fn a_port_the_master_closed_counts_no_lost_link() {
    let mut bus = line(4);
    // DL control 0x0101 bits 2-3: port 1's loop "closed" (0b11).
    let d = bus.one(Command::Fpwr, fp(station(3), 0x0101), &[0x0c]);
    assert_eq!(d.wkc, 1);
    bus.seg.set_link(2, 1, false);
    bus.seg.set_link(2, 1, true);
    // Slave 4's port 0 (auto) counts; slave 3's port 1 (closed) does not.
    assert_eq!(lost_links(&mut bus, 3), [0; 4]);
    bus.one(Command::Fpwr, fp(station(3), 0x0101), &[0x00]);
    assert_eq!(lost_links(&mut bus, 4), [1, 0, 0, 0]);
}

#[test]
fn a_write_clears_the_counters_as_the_datasheet_groups_them() {
    let mut bus = line(5);
    // Slave 3 loses the links of both its ports: 0x0310 = 0x0311 = 1.
    bus.seg.set_link(1, 1, false);
    bus.seg.set_link(1, 1, true);
    bus.seg.set_link(2, 1, false);
    bus.seg.set_link(2, 1, true);
    assert_eq!(lost_links(&mut bus, 3), [1, 1, 0, 0]);
    // A corrupt frame: slave 4 counts an invalid frame at port 1 (0x0302), slaves 1-3 a
    // forwarded error at port 1 (0x0309).
    bus.seg.break_fcs_of_next_frame();
    bus.one(Command::Brd, DatagramAddress::position(0, 0), &[0]);
    assert_eq!(counters(&mut bus, 3)[0x09], 1);
    // A write to one lost link counter (0x0312, any value) clears all four, and nothing else.
    let d = bus.one(Command::Fpwr, fp(station(3), 0x0312), &[0x55]);
    assert_eq!(d.wkc, 1, "0x0312 exists and is writable");
    let c = counters(&mut bus, 3);
    assert_eq!(c[0x10..], [0; 4]);
    assert_eq!(c[0x09], 1, "the RX error group is not cleared");
    // A write to one of 0x0300-0x030B (0x0305) clears all twelve.
    let d = bus.one(Command::Fpwr, fp(station(3), 0x0305), &[0x77]);
    assert_eq!(d.wkc, 1);
    assert_eq!(counters(&mut bus, 3)[..0x0c], [0; 0x0c]);
    // 0x030C and 0x030D: a write clears, whatever it writes.
    let d = bus.one(Command::Fpwr, fp(station(3), 0x030c), &[0x12, 0x34]);
    assert_eq!(d.wkc, 1);
    assert_eq!(counters(&mut bus, 3)[0x0c..0x0e], [0, 0]);
}

#[test]
fn a_corrupt_frame_counts_where_its_fcs_broke_and_after() {
    let mut bus = line(6);
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0\nkind = \"corrupt\"\nframes = 3\n",
    )
    .unwrap();
    let mut p = FaultPlayer::new(s, 1);
    for _ in 1..=5 {
        let t = bus.t_ps + MS;
        assert_eq!(brd(&mut bus, &mut p, t), 6, "the slaves acted on it");
    }
    assert_eq!(p.counts().corrupted, 3);
    // The break: the cable from slave 6 (the last) back to slave 5's port 1. Slave 5 counts
    // three invalid frames at port 1 (0x0302); slaves 4 to 1 three forwarded errors at port 1
    // (0x0309); slave 6 and every processing unit (0x030C) nothing.
    let mut expected = [[0u8; 0x14]; 7];
    expected[5][0x02] = 3;
    for slave in &mut expected[1..=4] {
        slave[0x09] = 3;
    }
    for k in 1..=6u16 {
        assert_eq!(counters(&mut bus, k), expected[usize::from(k)], "slave {k}");
    }
}

#[test]
fn with_one_slave_no_esc_sees_the_broken_fcs() {
    let mut bus = line(1);
    bus.seg.break_fcs_of_next_frame();
    bus.one(Command::Brd, DatagramAddress::position(0, 0), &[0]);
    assert_eq!(counters(&mut bus, 1), [0; 0x14]);
}

#[test]
fn a_power_cycle_starts_the_counters_at_zero() {
    let mut bus = line(4);
    bus.seg.set_link(2, 1, false);
    bus.seg.set_link(2, 1, true);
    assert_eq!(lost_links(&mut bus, 3), [0, 1, 0, 0]);
    bus.seg.power_off(2, bus.t_ps);
    bus.seg.power_on(2, bus.t_ps + MS);
    bus.one(
        Command::Apwr,
        DatagramAddress::position(2, 0x0010),
        &station(3).to_le_bytes(),
    );
    assert_eq!(counters(&mut bus, 3), [0; 0x14], "power-on values");
    // Its neighbours saw their links go: slave 2's port 1, slave 4's port 0 (twice now).
    assert_eq!(lost_links(&mut bus, 2), [0, 1, 0, 0]);
    assert_eq!(lost_links(&mut bus, 4), [2, 0, 0, 0]);
}

#[test]
fn the_master_link_goes_with_the_first_cable_and_the_first_slave() {
    let mut seg = Segment::new(&preset::line(3, 1)).unwrap();
    assert!(seg.master_link_up());
    assert!(seg.set_link(0, 0, false));
    assert!(
        !seg.master_link_up(),
        "the cable at slave 1's port 0 pulled"
    );
    seg.set_link(0, 0, true);
    assert!(seg.master_link_up());
    seg.power_off(1, 0);
    assert!(seg.master_link_up(), "slave 2 off: the master's link stays");
    seg.power_on(1, 1);
    seg.power_off(0, 2);
    assert!(!seg.master_link_up(), "slave 1 off: its PHY is off");
    seg.power_on(0, 3);
    assert!(seg.master_link_up());
}

#[test]
fn hot_connected_slaves_count_no_lost_link_before_they_appear() {
    // Slaves that appear later never had a link: the player's start leaves them unplugged
    // without a count; plugging them in counts nothing either.
    let mut bus = line(4);
    let s = FaultSchedule::parse(
        "f.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0.01\nkind = \"hot_connect\"\nslaves = 1\n",
    )
    .unwrap();
    let mut p = FaultPlayer::new(s, 1);
    let t = bus.t_ps + MS;
    assert_eq!(brd(&mut bus, &mut p, t), 3);
    assert_eq!(lost_links(&mut bus, 3), [0; 4]);
    let t = bus.t_ps + 20 * MS;
    assert_eq!(brd(&mut bus, &mut p, t), 4);
    for k in 1..=4 {
        assert_eq!(lost_links(&mut bus, k), [0; 4], "slave {k}");
    }
}
