//! The master side of real captures replayed into a segment built like the captured one.
//!
//! `../shared/captures/replay-dc.pcapng`, `replay-issue-255.pcapng`,
//! `replay-ek1100-alias-address.pcapng` and `replay-ek1100-el2828-el2889.pcapng` (recorded by the ethercrab project on real hardware,
//! see that folder's README.md) hold ethercrab's scan, configuration and, in the first two, DC
//! bring-up and cyclic process data of an EK1100 coupler (ET1100, port 0 MII to the master,
//! port 1 EBUS) with an EL2828 and an EL2889 (EBUS digital output terminals) in a line: every
//! frame ethercrab sent, each followed by the frame that came back (the first ESC sets bit 1 of
//! the source address's first byte). The frames ethercrab sent are fed, at their captured
//! instants, into a segment of the same three devices ([`ecsync_sim::catalog`]); every datagram
//! of every frame must come back with the working counter and the ADP the real devices gave it.
//! That covers which registers exist on which device (the EL2828 has receive times but no
//! system time: 0x0910-0x09FF do not count there), which are read-only (0x092C), BRD/BWR/FRMW
//! counting, the latch, offsets, delays, drift compensation, SYNC0 configuration, station
//! addresses and aliases, SII access, AL control, and the process data: the terminals' outputs
//! go through SyncManagers and FMMUs at the digital output register 0x0F00, and every LRW
//! counts, from PRE-OP on.
//!
//! Beyond the working counters, what the captures fix independently of the clocks is checked
//! too: the reference's 0x092C (0x00000000), that every frame came back, 0x0008 as each device
//! reads it, and that the outputs the last LRW wrote are the terminals' outputs. Out of scope,
//! and so not compared: the values of time registers (they depend on the crystals and power-up
//! instants of the real devices) and the SII contents past what the devices' descriptions
//! hold.

mod common;

use common::{CapturedFrame, Dg, captures_dir, datagrams, has_returned, read_pcapng, u32_of};
use ecsync_sim::catalog;
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use ecsync_wire::Command;
use ecsync_wire::register as reg;

/// The captured segment: EK1100, EL2828, EL2889 in a line (DL status in the captures: EK1100
/// ports 0 and 1 open, EL2828 ports 0 and 1, EL2889 port 0 only).
fn captured_segment() -> Vec<SlaveSpec> {
    [
        (catalog::ek1100_model(), catalog::ek1100(1)),
        (catalog::el2828_model(), catalog::el2828(2)),
        (catalog::el2889_model(), catalog::el2889(3)),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, (model, device))| SlaveSpec {
        model,
        device,
        crystal: CrystalParams {
            ppm: [3.0, -7.0, 11.0][i],
            initial_local_ns: [1_000_000_000, 2_345_678_901, 3_456_789_012][i],
            seed: i as u64,
            ..Default::default()
        },
        upstream: Upstream::in_line(i),
        entry_port: 0,
        cable_m: 0.0,
        ring: None,
    })
    .collect()
}

fn name(code: u8) -> String {
    Command::from_code(code).map_or(format!("{code:#04x}"), |c| format!("{c:?}"))
}

/// One datagram as the segment answered it beside the real devices' answer.
struct Answered {
    /// The number of the captured frame that came back.
    frame: usize,
    mine: Dg,
    real: Dg,
}

impl Answered {
    fn what(&self) -> String {
        let r = &self.real;
        format!(
            "frame {} {} adp {:#06x} ado {:#06x} len {}",
            self.frame,
            name(r.command),
            r.adp,
            r.ado,
            r.data.len()
        )
    }

    fn is(&self, c: Command) -> bool {
        self.real.command == c.code()
    }
}

/// A capture replayed: every datagram answered, and the segment after the last frame.
struct Replay {
    pairs: usize,
    answered: Vec<Answered>,
    seg: Segment,
}

impl Replay {
    /// The datagrams whose working counter or ADP differs from the real devices', described.
    fn differing(&self) -> Vec<String> {
        self.answered
            .iter()
            .filter(|a| (a.mine.adp, a.mine.wkc) != (a.real.adp, a.real.wkc))
            .map(|a| {
                format!(
                    "{}: wkc {} (real {}), adp {:#06x} (real {:#06x})",
                    a.what(),
                    a.mine.wkc,
                    a.real.wkc,
                    a.mine.adp,
                    a.real.adp
                )
            })
            .collect()
    }

    /// The real devices' answers to the datagrams `f` picks.
    fn real<'a>(&'a self, f: impl Fn(&Answered) -> bool + 'a) -> impl Iterator<Item = &'a Dg> {
        self.answered.iter().filter(move |a| f(a)).map(|a| &a.real)
    }
}

/// Feeds every frame ethercrab sent in `file` into the captured segment at its captured
/// instant (the segment's time line starting 1 ms before the first frame), and pairs each
/// answered datagram with the real devices' answer.
fn replay(file: &str) -> Replay {
    let frames = read_pcapng(&captures_dir().join(file));
    let mut seg = Segment::new(&captured_segment()).unwrap();
    let mut answered = Vec::new();
    let mut pairs = 0;
    let mut i = 0;
    while i < frames.len() {
        // Every frame ethercrab sent is followed by the one that came back (checked here).
        let sent: &CapturedFrame = &frames[i];
        assert!(
            !has_returned(&sent.data),
            "{file}: frame {} is a request",
            sent.number
        );
        let back = frames
            .get(i + 1)
            .filter(|f| has_returned(&f.data))
            .unwrap_or_else(|| panic!("{file}: frame {} has its answer next", sent.number));
        i += 2;
        pairs += 1;
        let mut frame = sent.data.clone();
        let out = seg.process(&mut frame, 1_000_000_000 + sent.t_ns * 1000);
        assert!(
            out.returned_sof_ps.is_some(),
            "{file}: frame {} came back from the real devices but not from the segment",
            sent.number
        );
        assert!(
            has_returned(&frame),
            "the first ESC marks the source address"
        );
        let mine = datagrams(&frame);
        let real = datagrams(&back.data);
        assert_eq!(mine.len(), real.len(), "{file}: frame {}", back.number);
        for (m, r) in mine.into_iter().zip(real) {
            assert_eq!(
                (m.command, m.index, m.ado),
                (r.command, r.index, r.ado),
                "{file}: frame {}: the same datagram",
                back.number
            );
            answered.push(Answered {
                frame: back.number,
                mine: m,
                real: r,
            });
        }
    }
    Replay {
        pairs,
        answered,
        seg,
    }
}

/// Every datagram of the replay came back with the real devices' working counter and ADP.
fn assert_all_equal(file: &str, r: &Replay) {
    let differing = r.differing();
    eprintln!(
        "{file}: {} frames replayed, {} datagrams, {} differing in working counter or ADP",
        r.pairs,
        r.answered.len(),
        differing.len()
    );
    assert!(
        differing.is_empty(),
        "{file}: datagrams answered differently from the real devices:\n{}",
        differing.join("\n")
    );
}

/// 0x0008 as the capture's reads of it return it (station, value) and as the segment's
/// devices answered them.
fn features(r: &Replay) -> Vec<(u16, u16, u16)> {
    r.answered
        .iter()
        .filter(|a| a.is(Command::Fprd) && a.real.ado == reg::FEATURES)
        .map(|a| (a.real.adp, u16_of(&a.mine.data), u16_of(&a.real.data)))
        .collect()
}

/// The outputs the capture's last LRW wrote to each terminal, by the FMMUs ethercrab set up in
/// the capture (its FPWRs of 0x0600-0x062F: logical start, length, physical start 0x0F00 +
/// k): (station, bytes in SyncManager order).
fn last_outputs(r: &Replay) -> Vec<(u16, Vec<u8>)> {
    let lrw = r
        .real(|a| a.is(Command::Lrw))
        .last()
        .expect("the capture has LRWs");
    let logical = u32::from(lrw.adp) | (u32::from(lrw.ado) << 16);
    let mut out: Vec<(u16, Vec<(u16, u8)>)> = Vec::new();
    for f in r.real(|a| {
        a.is(Command::Fpwr) && (reg::FMMU_BASE..reg::FMMU_BASE + 0x30).contains(&a.real.ado)
    }) {
        let start = u32_of(&f.data);
        let len = u32::from(u16_of(&f.data[4..]));
        let phys = u16_of(&f.data[8..]);
        let mut bytes = Vec::new();
        for k in 0..len {
            let at = (start + k).wrapping_sub(logical) as usize;
            bytes.push((phys + k as u16, lrw.data[at]));
        }
        match out.iter_mut().find(|(s, _)| *s == f.adp) {
            Some((_, v)) => v.extend(bytes),
            None => out.push((f.adp, bytes)),
        }
    }
    out.into_iter()
        .map(|(s, mut v)| {
            v.sort();
            (s, v.into_iter().map(|(_, b)| b).collect())
        })
        .collect()
}

/// The last LRW's outputs are the terminals' (their SyncManagers' buffers at 0x0F00).
fn assert_outputs_taken(file: &str, r: &Replay) {
    let written = last_outputs(r);
    assert_eq!(written.len(), 2, "{file}: two terminals with outputs");
    for (station, bytes) in written {
        let i = usize::from(station - 0x1000);
        assert_eq!(
            r.seg.esc(i).outputs(),
            bytes,
            "{file}: station {station:#06x}'s outputs"
        );
    }
}

#[test]
#[ignore = "needs ../shared/captures"]
fn every_datagram_of_replay_dc_matches_the_real_devices() {
    let file = "replay-dc.pcapng";
    let r = replay(file);
    assert_eq!(r.pairs, 1802, "the capture as recorded");
    assert_all_equal(file, &r);
    let dc = r
        .real(|a| {
            (0x0900..0x0a00).contains(&a.real.ado)
                && !matches!(
                    Command::from_code(a.real.command),
                    Ok(Command::Lrd | Command::Lwr | Command::Lrw | Command::Nop)
                )
        })
        .count();
    assert_eq!(dc, 396, "DC datagrams in the capture");
    // The reference, read by FRMW and never compared, reads 0 on the EK1100 and on the
    // segment; where no device answered a read of 0x092C, the data comes back as sent.
    let diff_reads: Vec<&Answered> = r
        .answered
        .iter()
        .filter(|a| a.is(Command::Fprd) && a.real.ado == reg::DC_SYSTEM_TIME_DIFF)
        .collect();
    let reference: Vec<_> = diff_reads
        .iter()
        .filter(|a| a.real.adp == 0x1000)
        .map(|a| (u32_of(&a.real.data), u32_of(&a.mine.data)))
        .collect();
    assert_eq!(reference, [(0, 0)]);
    for a in diff_reads.iter().filter(|a| a.real.wkc == 0) {
        assert_eq!(a.mine.data, a.real.data, "{}", a.what());
    }
    // Every LRW counted 4 at the real terminals (2 per terminal that took the write), the
    // first in PRE-OP, and so at the segment's.
    let lrws: Vec<u16> = r.real(|a| a.is(Command::Lrw)).map(|d| d.wkc).collect();
    assert_eq!(lrws.len(), 257);
    assert!(lrws.iter().all(|&w| w == 4));
    // 0x0008 as the three devices read it, and as the models show it.
    assert_eq!(
        features(&r),
        [
            (0x1000, 0x00fc, 0x00fc),
            (0x1001, 0x01fc, 0x01fc),
            (0x1002, 0x00fc, 0x00fc)
        ],
        "(station, segment, real)"
    );
    assert_outputs_taken(file, &r);
}

#[test]
#[ignore = "needs ../shared/captures"]
fn every_datagram_of_replay_issue_255_matches_the_real_devices() {
    let file = "replay-issue-255.pcapng";
    let r = replay(file);
    assert_all_equal(file, &r);
    assert_eq!(r.real(|a| a.is(Command::Lrw)).count(), 64, "its LRWs");
    assert_outputs_taken(file, &r);
}

#[test]
#[ignore = "needs ../shared/captures"]
fn every_datagram_of_replay_ek1100_alias_address_matches_the_real_devices() {
    let file = "replay-ek1100-alias-address.pcapng";
    let r = replay(file);
    assert_all_equal(file, &r);
    assert_eq!(
        features(&r),
        [
            (0x1000, 0x00fc, 0x00fc),
            (0x1001, 0x01fc, 0x01fc),
            (0x1002, 0x00fc, 0x00fc)
        ],
        "(station, segment, real)"
    );
}

fn u16_of(d: &[u8]) -> u16 {
    u16::from_le_bytes([d[0], d[1]])
}

#[test]
#[ignore = "needs ../shared/captures"]
fn every_datagram_of_replay_ek1100_el2828_el2889_matches_the_real_devices() {
    let file = "replay-ek1100-el2828-el2889.pcapng";
    let r = replay(file);
    assert_all_equal(file, &r);
    // ethercrab's two groups: 255 LRWs of the EL2828's byte, 8 of the EL2889's two, each
    // counted 2 (584 LRWs in the four captures, none counted by the model before it let FMMUs
    // reach 0x0F00).
    let lrws: Vec<(usize, u16)> = r
        .real(|a| a.is(Command::Lrw))
        .map(|d| (d.data.len(), d.wkc))
        .collect();
    assert_eq!(lrws.iter().filter(|&&l| l == (1, 2)).count(), 255);
    assert_eq!(lrws.iter().filter(|&&l| l == (2, 2)).count(), 8);
}
