//! Shared by the integration tests that read the real captures in `../shared/captures/`
//! (Wireshark captures of real EtherCAT hardware recorded by the ethercrab project; see that
//! folder's README.md) or the vendors' ESI files in `../shared/esi/`, and by those that drive
//! a segment frame by frame.

#![allow(dead_code)] // each test binary uses its own part

use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DeviceInfo, EscModel};
use ecsync_sim::rng::SplitMix64;
use ecsync_sim::{Esc, Segment, SlaveSpec, Upstream};
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};
use pcap_file::pcapng::blocks::interface_description::InterfaceDescriptionOption;
use pcap_file::pcapng::{Block, PcapNgReader};
use std::path::PathBuf;

/// The folder of the shared data (`../shared/`: captures of real hardware, vendors' ESI
/// files): `$ECSYNC_SHARED` if set (then only it: a wrong value fails rather than falling
/// back), else `shared/` beside the repository. Its sub-folder `sub` holding `probe`, or a
/// panic naming both places: the tests that call this are `#[ignore = "needs ../shared/..."]`,
/// so they run only when asked for (`--ignored`), and then a missing folder is a failure.
pub fn shared_dir(sub: &str, probe: &str) -> PathBuf {
    let (dir, from) = match std::env::var_os("ECSYNC_SHARED") {
        Some(d) => (PathBuf::from(d).join(sub), "$ECSYNC_SHARED"),
        // CARGO_MANIFEST_DIR is crates/sim: the repository is two folders up.
        None => (
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../../../shared")
                .join(sub),
            "the repository's ../shared",
        ),
    };
    assert!(
        dir.join(probe).is_file(),
        "this test needs ../shared/{sub} (no {probe} in {} from {from}): set ECSYNC_SHARED to \
         the shared folder, or put it beside the repository",
        dir.display()
    );
    dir
}

/// The folder of the real captures (`../shared/captures/`, see its README.md); a panic when
/// it is missing (see [`shared_dir`]).
pub fn captures_dir() -> PathBuf {
    shared_dir("captures", "replay-dc.pcapng")
}

/// The folder of the vendors' ESI files (`../shared/esi/`, see its README.md); a panic when
/// it is missing (see [`shared_dir`]).
pub fn esi_dir() -> PathBuf {
    shared_dir("esi", "ingenia-evs-net-01.xml")
}

/// The ESI the project ships for its own virtual drive (`esi/` at the repository's root).
pub fn shipped_esi() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../esi/ecsync-virtual-drive.xml")
}

/// One Ethernet frame of a capture.
pub struct CapturedFrame {
    /// 1-based frame number, as Wireshark numbers it.
    pub number: usize,
    /// Capture time since the first frame, ns.
    pub t_ns: u64,
    /// The bytes as captured.
    pub data: Vec<u8>,
}

/// Every enhanced packet of a pcapng file, in order.
///
/// Timestamps are in the units of the packet's interface (its `if_tsresol` option; pcapng's
/// default, microseconds, without one): the ethercrab captures count nanoseconds, SOEM's
/// microseconds. pcap-file hands the raw count over as if it were nanoseconds, so it is
/// scaled here.
pub fn read_pcapng(path: &std::path::Path) -> Vec<CapturedFrame> {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut r = PcapNgReader::new(std::io::BufReader::new(file)).expect("pcapng header");
    let mut out = Vec::new();
    let mut t0 = None;
    // Per interface: the timestamp unit as (numerator, denominator) of a nanosecond.
    let mut units: Vec<(u128, u128)> = Vec::new();
    while let Some(b) = r.next_block() {
        let b = b.expect("pcapng block");
        if let Block::InterfaceDescription(i) = &b {
            let resol = i
                .options
                .iter()
                .find_map(|o| match o {
                    InterfaceDescriptionOption::IfTsResol(r) => Some(*r),
                    _ => None,
                })
                .unwrap_or(6);
            // Bit 7 clear: 10^-n s; set: 2^-n s.
            let n = u32::from(resol & 0x7f);
            let per_s: u128 = if resol & 0x80 == 0 {
                10u128.pow(n)
            } else {
                1u128 << n
            };
            units.push((1_000_000_000, per_s));
        }
        if let Block::EnhancedPacket(p) = b {
            let (num, den) = units
                .get(p.interface_id as usize)
                .copied()
                .unwrap_or((1_000, 1));
            let t = (p.timestamp.as_nanos() * num / den) as u64;
            let t0 = *t0.get_or_insert(t);
            out.push(CapturedFrame {
                number: out.len() + 1,
                t_ns: t - t0,
                data: p.data.into_owned(),
            });
        }
    }
    out
}

/// Whether a captured EtherCAT frame has passed the segment: the first ESC sets bit 1 of the
/// source MAC's first byte on the way through (ESC datasheet section I, "Frame processing").
pub fn has_returned(frame: &[u8]) -> bool {
    frame.len() >= 12 && frame[6] & 0x02 != 0
}

/// One datagram as captured or answered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dg {
    pub command: u8,
    pub index: u8,
    pub adp: u16,
    pub ado: u16,
    pub data: Vec<u8>,
    pub wkc: u16,
}

/// The datagrams of an EtherCAT frame (empty if it is not one).
pub fn datagrams(frame: &[u8]) -> Vec<Dg> {
    let Ok(f) = EcatFrame::new_checked(frame) else {
        return Vec::new();
    };
    f.datagrams()
        .map_while(Result::ok)
        .map(|d| Dg {
            command: d.command_code(),
            index: d.index(),
            adp: d.adp(),
            ado: d.ado(),
            data: d.data().to_vec(),
            wkc: d.wkc(),
        })
        .collect()
}

/// A segment driven one frame at a time, `step_ps` apart.
pub struct Bus {
    pub seg: Segment,
    pub t_ps: u64,
}

impl Bus {
    pub fn new(seg: Segment) -> Self {
        Bus { seg, t_ps: 0 }
    }

    /// Sends one frame holding `dgs` (command, address, data) at `t_ps` and returns the answered
    /// datagrams.
    pub fn frame(&mut self, t_ps: u64, dgs: &[(Command, DatagramAddress, &[u8])]) -> Vec<Dg> {
        let mut buf = [0u8; 1514];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x10; 6]).unwrap();
        for (i, (c, a, d)) in dgs.iter().enumerate() {
            b.push(*c, i as u8, *a, d).unwrap();
        }
        let n = b.finish();
        self.t_ps = t_ps;
        let out = self.seg.process(&mut buf[..n], t_ps);
        assert!(out.returned_sof_ps.is_some(), "the frame returns");
        datagrams(&buf[..n])
    }

    /// One datagram in its own frame, 100 us after the previous frame.
    pub fn one(&mut self, c: Command, a: DatagramAddress, d: &[u8]) -> Dg {
        let t = self.t_ps + 100_000_000;
        self.frame(t, &[(c, a, d)]).remove(0)
    }
}

/// Configured-address addressing.
pub fn fp(station: u16, ado: u16) -> DatagramAddress {
    DatagramAddress::Configured { adp: station, ado }
}

/// The little-endian u32 at the start of `d`.
pub fn u32_of(d: &[u8]) -> u32 {
    u32::from_le_bytes(d[..4].try_into().unwrap())
}

/// The little-endian u64 at the start of `d`.
pub fn u64_of(d: &[u8]) -> u64 {
    u64::from_le_bytes(d[..8].try_into().unwrap())
}

// One drive's mailbox driven datagram by datagram (the mailbox and CoE tests).

pub const BRD: u8 = 0x07;
pub const BWR: u8 = 0x08;
pub const MS: u64 = 1_000_000_000;

/// A datagram of the datasheet's layout: command, index, ADP, ADO, length, IRQ, data, WKC.
pub fn dg(cmd: u8, ado: u16, data: &[u8]) -> Vec<u8> {
    let mut v = vec![cmd, 0, 0, 0];
    v.extend_from_slice(&ado.to_le_bytes());
    v.extend_from_slice(&(data.len() as u16).to_le_bytes());
    v.extend_from_slice(&[0, 0]);
    v.extend_from_slice(data);
    v.extend_from_slice(&[0, 0]);
    v
}

pub fn wkc(d: &[u8]) -> u16 {
    u16::from_le_bytes([d[d.len() - 2], d[d.len() - 1]])
}

/// One drive (its ESC alone, driven datagram by datagram) with its mailbox SyncManagers set
/// up, in PRE-OP; messages written into SM0 and answers read from SM1 1 ms later.
pub struct MbxDrive {
    pub e: Esc,
    pub t_ps: u64,
    /// The master's mailbox counter, 1 to 7 in turn.
    pub counter: u8,
    /// SM0's and SM1's start and length.
    mbx: (u16, u16, u16, u16),
}

impl MbxDrive {
    /// The servo drive.
    pub fn servo() -> Self {
        Self::with(DeviceInfo::servo_drive(7))
    }

    /// A drive of `dev` (its mailbox, 128 bytes at 0x1000 and 0x1080 unless it says
    /// otherwise), the mailbox SyncManagers set up as its layout says, in PRE-OP.
    pub fn with(dev: DeviceInfo) -> Self {
        let l = dev.mailbox.expect("a mailbox");
        let mut e = Esc::new(EscModel::servo_mii(), dev, CrystalParams::default());
        e.set_links([true, false, false, false]);
        let mut d = MbxDrive {
            e,
            t_ps: 0,
            counter: 0,
            mbx: (0, 0, 0, 0),
        };
        d.mbx = (l.out_start, l.out_len, l.in_start, l.in_len);
        d.mailbox_to_preop();
        d
    }

    /// The mailbox SyncManagers set up as the layout says (SM0 written by the master, control
    /// 0x26; SM1 read, 0x22; both enabled), then PRE-OP requested and reached.
    pub fn mailbox_to_preop(&mut self) {
        let (out_start, out_len, in_start, in_len) = self.mbx;
        let sm = |start: u16, len: u16, control: u8| {
            let mut v = start.to_le_bytes().to_vec();
            v.extend_from_slice(&len.to_le_bytes());
            v.extend_from_slice(&[control, 0x00, 0x01, 0x00]);
            v
        };
        self.put(0x0800, &sm(out_start, out_len, 0x26));
        self.put(0x0808, &sm(in_start, in_len, 0x22));
        self.put(0x0120, &[0x02, 0x00]);
        assert_eq!(self.get(0x0130, 2).1, [0x02, 0x00], "PRE-OP");
    }

    pub fn put(&mut self, ado: u16, data: &[u8]) -> u16 {
        let mut d = dg(BWR, ado, data);
        self.e.process_datagram(&mut d, self.t_ps);
        wkc(&d)
    }

    pub fn get(&mut self, ado: u16, n: usize) -> (u16, Vec<u8>) {
        let mut d = dg(BRD, ado, &vec![0; n]);
        self.e.process_datagram(&mut d, self.t_ps);
        (wkc(&d), d[10..10 + n].to_vec())
    }

    /// The next master counter (1 to 7).
    pub fn next_counter(&mut self) -> u8 {
        self.counter = self.counter % 7 + 1;
        self.counter
    }

    /// Writes mailbox message `msg` (header included, padded to the mailbox) and returns the
    /// answer 1 ms later (`None`: SM1 stayed empty), cut to its header's length.
    pub fn send_raw(&mut self, msg: &[u8]) -> Option<Vec<u8>> {
        let (out_start, out_len, in_start, in_len) = self.mbx;
        let mut m = msg.to_vec();
        m.resize(usize::from(out_len), 0);
        self.t_ps += MS;
        assert_eq!(self.put(out_start, &m), 1, "SM0 takes the message");
        self.t_ps += MS;
        let (w, r) = self.get(in_start, usize::from(in_len));
        if w == 0 {
            return None;
        }
        let len = usize::from(u16::from_le_bytes([r[0], r[1]]));
        Some(r[..6 + len.min(usize::from(in_len) - 6)].to_vec())
    }

    /// A message of type `ty` (4 bits) with `data` after the header, the length its own, the
    /// next counter; its answer.
    pub fn send(&mut self, ty: u8, data: &[u8]) -> Option<Vec<u8>> {
        let c = self.next_counter();
        let mut m = (data.len() as u16).to_le_bytes().to_vec();
        m.extend_from_slice(&[0, 0, 0, ty | (c << 4)]);
        m.extend_from_slice(data);
        self.send_raw(&m)
    }

    /// A CoE message (type 3) with `data` after the mailbox header.
    pub fn coe(&mut self, data: &[u8]) -> Vec<u8> {
        self.send(3, data).expect("an answer")
    }
}

/// A line of `models` to the master, each slave on port 1 of the one before (cable `cable_m`
/// each), devices built by `device`; crystals a few ppm apart, their wander seeded from
/// `seed` on.
pub fn line(
    seed: u64,
    models: &[EscModel],
    cable_m: f64,
    device: impl Fn(usize) -> DeviceInfo,
) -> Vec<SlaveSpec> {
    models
        .iter()
        .enumerate()
        .map(|(i, model)| SlaveSpec {
            model: model.clone(),
            device: device(i),
            crystal: CrystalParams {
                ppm: [3.0, -7.0, 11.0, -2.0][i % 4],
                initial_local_ns: 1_000_000_000 + 123_456_789 * i as u64,
                seed: seed + i as u64,
                ..Default::default()
            },
            upstream: Upstream::in_line(i),
            entry_port: 0,
            cable_m,
            ring: None,
        })
        .collect()
}

/// The random draws of the tests that make networks: the simulator's SplitMix64 stream from a
/// fixed seed (a failure reproduces), with a bounded integer and a uniform real.
pub struct Rng(SplitMix64);

impl Rng {
    /// The stream from `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(SplitMix64(seed))
    }

    /// The next 64 random bits.
    pub fn next(&mut self) -> u64 {
        self.0.next()
    }

    /// Uniform in `0..n` (0 for `n` = 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }

    /// Uniform in `[lo, hi)`.
    pub fn f(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (self.next() >> 11) as f64 / (1u64 << 53) as f64 * (hi - lo)
    }
}
