//! The master side of a real capture replayed into a segment built like the captured one.
//!
//! `../shared/captures/replay-dc.pcapng` (recorded by the ethercrab project on real hardware,
//! see that folder's README.md) holds ethercrab's scan and DC bring-up of an EK1100 coupler
//! (ET1100, port 0 MII to the master, port 1 EBUS) with an EL2828 and an EL2889 (EBUS
//! terminals) in a line: every frame ethercrab sent, each followed by the frame that came back
//! (the first ESC sets bit 1 of the source address's first byte). The frames ethercrab sent are
//! fed, at their captured instants, into a segment of the same three devices; every datagram
//! that addresses the DC block (0x0900-0x09FF) must come back with the working counter the real
//! devices gave it. That covers which registers of the block exist on which device (the EL2828
//! has receive times but no system time: 0x0910-0x09FF do not count there), which are read-only
//! (0x092C), BRD/BWR/FRMW counting, the latch, offsets, delays, drift compensation and SYNC0
//! configuration.
//!
//! Beyond the DC working counters, what the capture fixes independently of the clocks is checked
//! too: the ADP every DC datagram came back with, the reference's 0x092C (0x00000000), that
//! every frame came back, the working counters and ADPs of every datagram outside the DC block
//! but the process data (LRW, explained at the end of the test), and 0x0008 as each device reads
//! it (two known differences, explained there). Out of scope, and so not compared: the values of
//! time registers (they depend on the crystals and power-up instants of the real devices) and
//! the SII contents (the segment's devices have ecsync's images, not Beckhoff's).

mod common;

use common::{captures_dir, datagrams, has_returned, read_pcapng, u32_of};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel, PdoEntry, PortKind};
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use ecsync_wire::Command;
use ecsync_wire::register as reg;

/// Beckhoff's vendor ID.
const BECKHOFF: u32 = 0x0000_0002;

fn outputs(n: u8) -> Vec<PdoEntry> {
    (0..n)
        .map(|i| PdoEntry {
            index: 0x7000 + 0x10 * u16::from(i),
            subindex: 1,
            bits: 1,
            name: format!("Output {}", i + 1),
        })
        .collect()
}

/// The captured segment: EK1100, EL2828, EL2889 in a line (DL status in the capture: EK1100
/// ports 0 and 1 open, EL2828 ports 0 and 1, EL2889 port 0 only).
fn captured_segment() -> Vec<SlaveSpec> {
    // The EK1100: an ET1100 with MII towards the master and EBUS towards the terminals.
    let mut ek1100 = EscModel::junction_mii();
    ek1100.ports = [
        PortKind::Mii,
        PortKind::Ebus,
        PortKind::None,
        PortKind::None,
    ];
    ek1100.link_phy_delay_ns = 10.0;
    let mut ek1100_dev = DeviceInfo::coupler("EK1100", 1);
    (ek1100_dev.vendor_id, ek1100_dev.product_code) = (BECKHOFF, 0x044c_2c52);
    // The EL2828: receive times, no system time (0x0910, 0x0918, 0x0920 and 0x092C do not
    // count there in the capture). 8 digital outputs.
    let el2828 = EscModel::ebus_terminal(DcSupport::ReceiveTimes);
    let mut el2828_dev = DeviceInfo::coupler("EL2828", 2);
    (el2828_dev.vendor_id, el2828_dev.product_code) = (BECKHOFF, 0x0b0c_3052);
    el2828_dev.outputs = outputs(8);
    // The EL2889: full DC. 16 digital outputs.
    let el2889 = EscModel::ebus_terminal(DcSupport::Full64);
    let mut el2889_dev = DeviceInfo::coupler("EL2889", 3);
    (el2889_dev.vendor_id, el2889_dev.product_code) = (BECKHOFF, 0x0b49_3052);
    el2889_dev.outputs = outputs(16);
    [
        (ek1100, ek1100_dev),
        (el2828, el2828_dev),
        (el2889, el2889_dev),
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
        upstream: if i == 0 {
            Upstream::Master
        } else {
            Upstream::Slave {
                index: i - 1,
                port: 1,
            }
        },
        entry_port: 0,
        cable_m: 0.0,
    })
    .collect()
}

fn name(code: u8) -> String {
    Command::from_code(code).map_or(format!("{code:#04x}"), |c| format!("{c:?}"))
}

#[test]
#[ignore = "needs ../shared/captures"]
fn dc_working_counters_of_replay_dc_match_the_real_devices() {
    let dir = captures_dir();
    let frames = read_pcapng(&dir.join("replay-dc.pcapng"));
    assert_eq!(frames.len(), 3604, "the capture as recorded");
    let mut seg = Segment::new(&captured_segment()).unwrap();

    let mut dc_datagrams = 0;
    let mut dc_mismatches = Vec::new();
    let mut other = (0usize, Vec::new());
    let mut reference_092c = Vec::new();
    let mut features = Vec::new();
    let mut pairs = 0;
    let mut i = 0;
    while i < frames.len() {
        // Every frame ethercrab sent is followed by the one that came back (checked here).
        let sent = &frames[i];
        assert!(
            !has_returned(&sent.data),
            "frame {} is a request",
            sent.number
        );
        let back = frames
            .get(i + 1)
            .filter(|f| has_returned(&f.data))
            .unwrap_or_else(|| panic!("frame {} has its answer next", sent.number));
        i += 2;
        pairs += 1;

        let mut frame = sent.data.clone();
        // The segment's time line starts 1 ms before the first frame.
        let out = seg.process(&mut frame, 1_000_000_000 + sent.t_ns * 1000);
        assert!(
            out.returned_sof_ps.is_some(),
            "frame {} came back from the real devices but not from the segment",
            sent.number
        );
        assert!(
            has_returned(&frame),
            "the first ESC marks the source address"
        );
        let mine = datagrams(&frame);
        let real = datagrams(&back.data);
        assert_eq!(mine.len(), real.len(), "frame {}", back.number);
        for (m, r) in mine.iter().zip(&real) {
            assert_eq!(
                (m.command, m.index, m.ado),
                (r.command, r.index, r.ado),
                "frame {}: the same datagram",
                back.number
            );
            let what = format!(
                "frame {} {} adp {:#06x} ado {:#06x} len {}",
                back.number,
                name(r.command),
                r.adp,
                r.ado,
                r.data.len()
            );
            let is_dc = (0x0900..0x0a00).contains(&r.ado)
                && !matches!(
                    Command::from_code(r.command),
                    Ok(Command::Lrd | Command::Lwr | Command::Lrw | Command::Nop)
                );
            if is_dc {
                dc_datagrams += 1;
                // The ADP as it came back (incremented by every slave for auto-increment and
                // broadcast commands) and the working counter.
                if (m.adp, m.wkc) != (r.adp, r.wkc) {
                    dc_mismatches.push(format!(
                        "{what}: wkc {} (real {}), adp {:#06x} (real {:#06x})",
                        m.wkc, r.wkc, m.adp, r.adp
                    ));
                }
                if r.command == Command::Fprd.code() && r.ado == reg::DC_SYSTEM_TIME_DIFF {
                    if r.adp == 0x1000 {
                        reference_092c.push((u32_of(&r.data), u32_of(&m.data)));
                    }
                    if r.wkc == 0 {
                        // Where no device answered, the data comes back as sent.
                        assert_eq!(m.data, r.data, "{what}");
                    }
                }
            } else {
                if r.command == Command::Fprd.code() && r.ado == reg::FEATURES {
                    features.push((r.adp, u16_of(&m.data), u16_of(&r.data)));
                }
                other.0 += 1;
                if (m.adp, m.wkc) != (r.adp, r.wkc) {
                    other
                        .1
                        .push((r.command, format!("{what}: wkc {} (real {})", m.wkc, r.wkc)));
                }
            }
        }
    }
    eprintln!(
        "{pairs} frames replayed; {dc_datagrams} DC datagrams, {} of them differing; \
         {} other datagrams, {} of them differing in working counter or ADP",
        dc_mismatches.len(),
        other.0,
        other.1.len()
    );
    assert_eq!(pairs, 1802);
    assert_eq!(dc_datagrams, 396, "DC datagrams in the capture");
    assert!(
        dc_mismatches.is_empty(),
        "DC datagrams answered differently from the real devices:\n{}",
        dc_mismatches.join("\n")
    );
    // The reference, read by FRMW and never compared, reads 0 on the EK1100 and on the segment.
    assert_eq!(reference_092c, [(0, 0)]);

    // Outside the DC block, out of scope and documented: the process data. ethercrab
    // configured the terminals' SyncManagers from the real devices' SII (SM0 at 0x0F00, the
    // digital outputs: FPWR 0x0800 = 00 0f 01 00 44 00 01 00), which the segment's devices,
    // with ecsync's SII images (outputs at 0x1000), refuse on the way to SAFE-OP (AL status
    // 0x12, code 0x001D): their LRWs then do not count. Every other datagram of the capture
    // (scan, station addresses, FMMU and SyncManager resets, SII access, AL control) comes back
    // with the real devices' working counter and ADP.
    let not_lrw: Vec<_> = other
        .1
        .iter()
        .filter(|(c, _)| *c != Command::Lrw.code())
        .map(|(_, m)| m.as_str())
        .collect();
    assert!(not_lrw.is_empty(), "{}", not_lrw.join("\n"));
    assert_eq!(other.1.len(), 257, "the LRWs of the cyclic phase");

    // 0x0008 as the three devices read it and as the models show it: the EK1100 exactly
    // (0x00FC); the EL2889 reads 0x00FC, an ET1200 (3 FMMUs, 4 SyncManagers) without
    // enhanced DC SYNC activation, where the ebus-terminal model shows the majority's 0x01FC;
    // the EL2828 reads 0x01FC without a system time, where a receive-times-only model clears
    // the DC bits (see EscModel::features).
    assert_eq!(
        features,
        [
            (0x1000, 0x00fc, 0x00fc),
            (0x1001, 0x01f0, 0x01fc),
            (0x1002, 0x01fc, 0x00fc)
        ],
        "(station, segment, real)"
    );
}

fn u16_of(d: &[u8]) -> u16 {
    u16::from_le_bytes([d[0], d[1]])
}
