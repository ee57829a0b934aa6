//! Every command's working counter and data effect on a three-slave line, each case worked out by
//! hand from the datasheet's rules (section I, tables "EtherCAT command types" and "Working
//! counter increment"):
//! - a slave counts an access when at least one addressed byte exists (reads) or is writable;
//! - auto-increment commands address the slave that receives ADP = 0 and every slave increments
//!   ADP; broadcast commands increment it too;
//! - read-write commands read before they write (+1 read, +2 write);
//! - BRD ORs every slave's memory into the data;
//! - ARMW/FRMW: the addressed slave reads, every other slave writes the data as it arrives.

use ecsync_sim::{Segment, preset};
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};

/// User RAM, plain read/write memory on every ESC.
const USER_RAM: u16 = 0x0f80;

struct Bus {
    seg: Segment,
    t_ps: u64,
}

struct Reply {
    adp: u16,
    data: Vec<u8>,
    wkc: u16,
}

impl Bus {
    fn new() -> Self {
        let mut bus = Bus {
            seg: Segment::new(&preset::line(3, 42)).unwrap(),
            t_ps: 0,
        };
        for i in 0..3u16 {
            let r = bus.send(
                Command::Apwr,
                DatagramAddress::position(i, 0x0010).raw(),
                &(0x1000 + i).to_le_bytes(),
            );
            assert_eq!(r.wkc, 1);
        }
        bus
    }

    fn send(&mut self, cmd: Command, address: u32, data: &[u8]) -> Reply {
        let mut buf = [0u8; 1514];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x00, 1, 2, 3, 4, 5]).unwrap();
        let addr = DatagramAddress::Logical(address);
        b.push(cmd, 0x5a, addr, data).unwrap();
        let n = b.finish();
        self.t_ps += 100_000_000; // 100 us between frames
        let out = self.seg.process(&mut buf[..n], self.t_ps);
        assert!(out.returned_sof_ps.is_some());
        let f = EcatFrame::new_checked(&buf[..n]).unwrap();
        assert_eq!(
            f.src_mac()[0] & 0x02,
            0x02,
            "first ESC marks the returning frame"
        );
        let d = f.datagrams().next().unwrap().unwrap();
        assert_eq!(d.index(), 0x5a);
        assert_eq!(d.command(), Ok(cmd));
        Reply {
            adp: d.adp(),
            data: d.data().to_vec(),
            wkc: d.wkc(),
        }
    }

    fn fp(station: u16, ado: u16) -> u32 {
        DatagramAddress::Configured { adp: station, ado }.raw()
    }

    fn user_ram(&mut self, slave: u16) -> [u8; 4] {
        let r = self.send(Command::Fprd, Self::fp(0x1000 + slave, USER_RAM), &[0; 4]);
        assert_eq!(r.wkc, 1);
        r.data.try_into().unwrap()
    }

    fn set_user_ram(&mut self, slave: u16, v: [u8; 4]) {
        let r = self.send(Command::Fpwr, Self::fp(0x1000 + slave, USER_RAM), &v);
        assert_eq!(r.wkc, 1);
    }
}

#[test]
fn nop_touches_nothing() {
    let mut bus = Bus::new();
    let r = bus.send(Command::Nop, Bus::fp(0x1001, USER_RAM), &[9, 9, 9, 9]);
    assert_eq!(
        (r.wkc, r.data.as_slice(), r.adp),
        (0, &[9u8, 9, 9, 9][..], 0x1001)
    );
    assert_eq!(bus.user_ram(1), [0; 4]);
}

#[test]
fn auto_increment_commands() {
    let mut bus = Bus::new();
    // APRD of slave 1's station address: ADP -1 arrives at slave 0 as 0xffff, at slave 1 as 0.
    let r = bus.send(
        Command::Aprd,
        DatagramAddress::position(1, 0x0010).raw(),
        &[0, 0],
    );
    assert_eq!(r.wkc, 1);
    assert_eq!(r.data, 0x1001u16.to_le_bytes());
    assert_eq!(r.adp, 2, "three slaves incremented -1 to 2");
    // APWR to slave 2's user RAM.
    let r = bus.send(
        Command::Apwr,
        DatagramAddress::position(2, USER_RAM).raw(),
        &[1, 2, 3, 4],
    );
    assert_eq!(r.wkc, 1);
    assert_eq!(bus.user_ram(2), [1, 2, 3, 4]);
    assert_eq!(bus.user_ram(1), [0; 4]);
    // APRW on slave 2: returns the old value, stores the new, WKC 1 + 2.
    let r = bus.send(
        Command::Aprw,
        DatagramAddress::position(2, USER_RAM).raw(),
        &[5, 6, 7, 8],
    );
    assert_eq!((r.wkc, r.data.as_slice()), (3, &[1u8, 2, 3, 4][..]));
    assert_eq!(bus.user_ram(2), [5, 6, 7, 8]);
    // A position beyond the segment addresses nobody.
    let r = bus.send(
        Command::Aprd,
        DatagramAddress::position(3, 0x0010).raw(),
        &[0, 0],
    );
    assert_eq!((r.wkc, r.data.as_slice()), (0, &[0u8, 0][..]));
}

#[test]
fn configured_address_commands() {
    let mut bus = Bus::new();
    let r = bus.send(Command::Fprd, Bus::fp(0x1002, 0x0010), &[0, 0]);
    assert_eq!((r.wkc, r.data.as_slice()), (1, &[0x02u8, 0x10][..]));
    assert_eq!(r.adp, 0x1002, "configured addressing leaves ADP alone");
    let r = bus.send(
        Command::Fpwr,
        Bus::fp(0x1001, USER_RAM),
        &[0xde, 0xad, 0xbe, 0xef],
    );
    assert_eq!(r.wkc, 1);
    assert_eq!(bus.user_ram(1), [0xde, 0xad, 0xbe, 0xef]);
    let r = bus.send(Command::Fprw, Bus::fp(0x1001, USER_RAM), &[1, 1, 1, 1]);
    assert_eq!(
        (r.wkc, r.data.as_slice()),
        (3, &[0xdeu8, 0xad, 0xbe, 0xef][..])
    );
    assert_eq!(bus.user_ram(1), [1, 1, 1, 1]);
    // No slave has station address 0x2000.
    let r = bus.send(Command::Fprd, Bus::fp(0x2000, 0x0010), &[0, 0]);
    assert_eq!(r.wkc, 0);
}

#[test]
fn broadcast_commands() {
    let mut bus = Bus::new();
    bus.set_user_ram(0, [0x01, 0, 0, 0x80]);
    bus.set_user_ram(1, [0x02, 0, 0, 0x00]);
    bus.set_user_ram(2, [0x04, 0x10, 0, 0x00]);
    // BRD ORs: 0x01 | 0x02 | 0x04, and ORs into what the master sent (0x20 in byte 2).
    let r = bus.send(
        Command::Brd,
        DatagramAddress::position(0, USER_RAM).raw(),
        &[0, 0, 0x20, 0],
    );
    assert_eq!(
        (r.wkc, r.data.as_slice()),
        (3, &[0x07u8, 0x10, 0x20, 0x80][..])
    );
    assert_eq!(r.adp, 3);
    // BWR writes everywhere.
    let r = bus.send(
        Command::Bwr,
        DatagramAddress::position(0, USER_RAM).raw(),
        &[9, 8, 7, 6],
    );
    assert_eq!(r.wkc, 3);
    for s in 0..3 {
        assert_eq!(bus.user_ram(s), [9, 8, 7, 6]);
    }
    // BRW: each slave ORs its memory into the data and writes the data as it arrived, so slave
    // k stores the master's data ORed with the memories of slaves 0..k.
    bus.set_user_ram(0, [0x01, 0, 0, 0]);
    bus.set_user_ram(1, [0x02, 0, 0, 0]);
    bus.set_user_ram(2, [0x04, 0, 0, 0]);
    let r = bus.send(
        Command::Brw,
        DatagramAddress::position(0, USER_RAM).raw(),
        &[0x10, 0, 0, 0],
    );
    assert_eq!((r.wkc, r.data[0]), (9, 0x17));
    assert_eq!(bus.user_ram(0)[0], 0x10);
    assert_eq!(bus.user_ram(1)[0], 0x11);
    assert_eq!(bus.user_ram(2)[0], 0x13);
}

#[test]
fn read_multiple_write_commands() {
    let mut bus = Bus::new();
    bus.set_user_ram(0, [0xa0, 0, 0, 0]);
    bus.set_user_ram(1, [0xb1, 0, 0, 0]);
    bus.set_user_ram(2, [0xc2, 0, 0, 0]);
    // ARMW addressed at slave 0: it reads 0xa0 into the data, slaves 1 and 2 store it.
    let r = bus.send(
        Command::Armw,
        DatagramAddress::position(0, USER_RAM).raw(),
        &[0; 4],
    );
    assert_eq!((r.wkc, r.data[0]), (3, 0xa0));
    assert_eq!([bus.user_ram(1)[0], bus.user_ram(2)[0]], [0xa0, 0xa0]);
    // FRMW addressed at slave 1: slave 0 (before it) stores what the master sent, slave 1 reads,
    // slave 2 stores slave 1's value.
    bus.set_user_ram(1, [0xb1, 0, 0, 0]);
    let r = bus.send(Command::Frmw, Bus::fp(0x1001, USER_RAM), &[0x55, 0, 0, 0]);
    assert_eq!((r.wkc, r.data[0]), (3, 0xb1));
    assert_eq!(
        [bus.user_ram(0)[0], bus.user_ram(1)[0], bus.user_ram(2)[0]],
        [0x55, 0xb1, 0xb1]
    );
}

#[test]
fn logical_commands_through_fmmus() {
    let mut bus = Bus::new();
    // Each slave k: FMMU0 writes logical 0x10000 + 8k .. +4 to physical 0x1800, FMMU1 reads
    // physical 0x1804 .. +4 to logical 0x10000 + 8k + 4. Plain RAM (no SyncManager).
    for k in 0..3u16 {
        let st = 0x1000 + k;
        let lw = 0x0001_0000u32 + 8 * u32::from(k);
        let mut f0 = [0u8; 16];
        f0[0..4].copy_from_slice(&lw.to_le_bytes());
        f0[4..6].copy_from_slice(&4u16.to_le_bytes());
        f0[7] = 7;
        f0[8..10].copy_from_slice(&0x1800u16.to_le_bytes());
        f0[11] = 0x02;
        f0[12] = 0x01;
        assert_eq!(bus.send(Command::Fpwr, Bus::fp(st, 0x0600), &f0).wkc, 1);
        let mut f1 = f0;
        f1[0..4].copy_from_slice(&(lw + 4).to_le_bytes());
        f1[8..10].copy_from_slice(&0x1804u16.to_le_bytes());
        f1[11] = 0x01;
        assert_eq!(bus.send(Command::Fpwr, Bus::fp(st, 0x0610), &f1).wkc, 1);
        let inputs = [0x10 * (k as u8 + 1); 4];
        assert_eq!(bus.send(Command::Fpwr, Bus::fp(st, 0x1804), &inputs).wkc, 1);
    }
    let outputs: Vec<u8> = (0..24).collect();
    // LWR: three write matches.
    let r = bus.send(Command::Lwr, 0x0001_0000, &outputs);
    assert_eq!(r.wkc, 3);
    let r = bus.send(Command::Fprd, Bus::fp(0x1002, 0x1800), &[0; 4]);
    assert_eq!(r.data, [16, 17, 18, 19]);
    // LRD: three read matches, unmapped bytes untouched.
    let r = bus.send(Command::Lrd, 0x0001_0000, &[0xee; 24]);
    assert_eq!(r.wkc, 3);
    assert_eq!(
        &r.data[0..8],
        &[0xee, 0xee, 0xee, 0xee, 0x10, 0x10, 0x10, 0x10]
    );
    assert_eq!(&r.data[20..24], &[0x30; 4]);
    // LRW: +1 read and +2 write per slave.
    let r = bus.send(Command::Lrw, 0x0001_0000, &[0x77; 24]);
    assert_eq!(r.wkc, 9);
    assert_eq!(
        &r.data[8..16],
        &[0x77, 0x77, 0x77, 0x77, 0x20, 0x20, 0x20, 0x20]
    );
    let r = bus.send(Command::Fprd, Bus::fp(0x1000, 0x1800), &[0; 4]);
    assert_eq!(r.data, [0x77; 4]);
    // A logical range nobody maps.
    let r = bus.send(Command::Lrw, 0x0002_0000, &[1; 8]);
    assert_eq!((r.wkc, r.data.as_slice()), (0, &[1u8; 8][..]));
}

#[test]
fn dc_registers_follow_the_datasheet() {
    let mut bus = Bus::new();
    // BWR to 0x0900 latches on every DC slave: WKC 3.
    let r = bus.send(
        Command::Bwr,
        DatagramAddress::position(0, 0x0900).raw(),
        &[0; 4],
    );
    assert_eq!(r.wkc, 3);
    // Slave 0: port 0 and port 1 stamps. Between them the frame went down to slave 2 and back:
    // 4 x (processing or forwarding 180 ns + PHYs 300 ns + 1 m of cable 5 ns) = 1940 ns, stamped
    // with the MII ports' 40 ns resolution.
    let r = bus.send(Command::Fprd, Bus::fp(0x1000, 0x0900), &[0; 16]);
    let p0 = u32::from_le_bytes(r.data[0..4].try_into().unwrap());
    let p1 = u32::from_le_bytes(r.data[4..8].try_into().unwrap());
    assert!(p1.wrapping_sub(p0).abs_diff(1940) <= 40, "{p0} {p1}");
    // 0x0918 equals the port 0 stamp (datasheet: the processing unit's stamp when port 0 is
    // open).
    let r = bus.send(Command::Fprd, Bus::fp(0x1000, 0x0918), &[0; 8]);
    assert_eq!(u64::from_le_bytes(r.data.try_into().unwrap()) as u32, p0);
    // Writing read-only 0x092C does not count.
    let r = bus.send(
        Command::Bwr,
        DatagramAddress::position(0, 0x092c).raw(),
        &[0; 4],
    );
    assert_eq!(r.wkc, 0);
    // FRMW of system time: the reference (slave 0) reads, the two others write: WKC 3.
    let r = bus.send(Command::Frmw, Bus::fp(0x1000, 0x0910), &[0; 8]);
    assert_eq!(r.wkc, 3);
    assert_ne!(r.data, [0; 8]);
}
