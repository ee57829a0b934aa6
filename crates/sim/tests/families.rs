//! The device families (`ecsync_sim::model::families`) against the captures of the devices
//! they are shaped like (`../shared/captures/`, see its README.md): the SOEM captures of a
//! single LAN9252 board and a single Kollmorgen AKD replayed, frame by frame at their captured
//! instants, into a segment of one device of the family, and the working counters of AL control,
//! the AL states read back, the SII interface's status and working counters compared with what
//! the real device gave; the Beckhoff EEPROM's busy time against ethercrab's polls of the
//! EK1100, EL2828 and EL2889 in replay-dc.pcapng; and AL status under device emulation.

mod common;

use common::{CapturedFrame, Dg, captures_dir, datagrams, has_returned, read_pcapng};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DeviceInfo, EscModel, MailboxLayout};
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use ecsync_wire::Command;

/// A segment of one slave of `model` (device `device`), to the master.
fn single(model: EscModel, device: DeviceInfo) -> Segment {
    Segment::new(&[SlaveSpec {
        model,
        device,
        crystal: CrystalParams::default(),
        upstream: Upstream::Master,
        entry_port: 0,
        cable_m: 1.0,
        ring: None,
    }])
    .unwrap()
}

/// One datagram the master sent, as the real device and the segment answered it.
struct Answered {
    /// The frame that came back from the real device.
    frame: usize,
    /// Capture time of the request, ns.
    t_ns: u64,
    real: Dg,
    mine: Dg,
}

/// Every request of `frames` sent into `seg` at its captured instant (the segment's time line
/// starts 1 s before the capture), paired with the real device's answer.
fn replay(frames: &[CapturedFrame], seg: &mut Segment) -> Vec<Answered> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let sent = &frames[i];
        if has_returned(&sent.data) {
            i += 1;
            continue;
        }
        let Some(back) = frames.get(i + 1).filter(|f| has_returned(&f.data)) else {
            i += 1;
            continue;
        };
        i += 2;
        let mut frame = sent.data.clone();
        let r = seg.process(&mut frame, (1_000_000_000 + sent.t_ns) * 1000);
        assert!(r.returned_sof_ps.is_some(), "frame {}", sent.number);
        for (mine, real) in datagrams(&frame).into_iter().zip(datagrams(&back.data)) {
            assert_eq!((mine.command, mine.ado), (real.command, real.ado));
            out.push(Answered {
                frame: back.number,
                t_ns: sent.t_ns,
                real,
                mine,
            });
        }
    }
    out
}

fn is(cmd: Command) -> impl Fn(&Answered) -> bool {
    move |a| a.real.command == cmd.code()
}

/// The mismatches of `what` among `answered`, one line each.
fn differing<'a>(
    answered: &'a [Answered],
    keep: impl Fn(&Answered) -> bool,
    what: impl Fn(&Dg) -> Vec<u8>,
) -> (usize, Vec<String>) {
    let kept: Vec<&'a Answered> = answered.iter().filter(|a| keep(a)).collect();
    let bad = kept
        .iter()
        .filter(|a| (what(&a.mine), a.mine.wkc) != (what(&a.real), a.real.wkc))
        .map(|a| {
            format!(
                "frame {} (t {:.3} ms) cmd {:#04x} ado {:#06x}: model {:02x?} wkc {}, real {:02x?} wkc {}",
                a.frame,
                a.t_ns as f64 / 1e6,
                a.real.command,
                a.real.ado,
                what(&a.mine),
                a.mine.wkc,
                what(&a.real),
                a.real.wkc
            )
        })
        .collect();
    (kept.len(), bad)
}

/// The AL and SII facts of a single-device SOEM capture hold on the family's model: every
/// write of AL control counts as the real one did (the handshake), AL status reads the same
/// state at every poll (the firmware's time) up to the request that needs the device's own
/// process data, and 0x0502 reads the same status with the same working counter.
fn check_al_and_sii(capture: &str, model: EscModel, device: DeviceInfo, al_until_ns: u64) {
    let frames = read_pcapng(&captures_dir().join(capture));
    let mut seg = single(model, device);
    let answered = replay(&frames, &mut seg);
    let none = |_: &Dg| Vec::new();
    let (n, bad) = differing(&answered, |a| a.real.ado == 0x0120, none);
    assert!(n >= 5, "{capture}: AL control writes");
    assert!(bad.is_empty(), "{capture}: AL control\n{}", bad.join("\n"));
    // AL status: the state byte (0x0130) at every poll.
    let (n, bad) = differing(
        &answered,
        |a| a.real.ado == 0x0130 && a.t_ns < al_until_ns,
        |d| d.data[..1].to_vec(),
    );
    assert!(n >= 5, "{capture}: AL status polls ({n})");
    assert!(bad.is_empty(), "{capture}: AL status\n{}", bad.join("\n"));
    // SII: the status word (busy, read size, emulation, address bytes) and the counts.
    let (n, bad) = differing(
        &answered,
        |a| a.real.ado == 0x0502 && is(Command::Fprd)(a),
        |d| d.data[..2].to_vec(),
    );
    assert!(n >= 20, "{capture}: SII status polls");
    assert!(bad.is_empty(), "{capture}: SII status\n{}", bad.join("\n"));
    let (n, bad) = differing(&answered, |a| a.real.ado == 0x0508, none);
    assert!(n >= 20, "{capture}: SII data reads");
    assert!(bad.is_empty(), "{capture}: SII data\n{}", bad.join("\n"));
    // The static registers the scan read: 0x0000 (BRD), 0x0007, 0x0008, 0x0110 (DL status),
    // 0x0140 (PDI control).
    for ado in [0x0000, 0x0007, 0x0008, 0x0110, 0x0140] {
        let (n, bad) = differing(
            &answered,
            |a| a.real.ado == ado && a.real.command != Command::Bwr.code(),
            |d| d.data.clone(),
        );
        assert!(n >= 1, "{capture}: reads of {ado:#06x}");
        assert!(bad.is_empty(), "{capture}: {ado:#06x}\n{}", bad.join("\n"));
    }
}

/// The LAN9252 evaluation board's device: its identity and mailbox as its SII reads in the
/// capture (vendor 0x09, product 0x9252, revision 1; mailboxes of 128 bytes at 0x1000 and
/// 0x1080, words 0x18-0x1B).
fn lan9252_board() -> DeviceInfo {
    let mut d = DeviceInfo::servo_drive(1);
    (d.vendor_id, d.product_code, d.revision) = (0x09, 0x9252, 1);
    d.mailbox = Some(MailboxLayout::STANDARD);
    d
}

/// The Kollmorgen AKD's device: identity and mailbox as its SII reads in the capture (vendor
/// 0x6A, product 0x00414B44, revision 2; mailboxes of 1 KiB at 0x1800 and 0x1C00, words
/// 0x18-0x1B), ecsync's drive behind them.
fn akd() -> DeviceInfo {
    let mut d = DeviceInfo::servo_drive(1);
    (d.vendor_id, d.product_code, d.revision) = (0x6a, 0x0041_4b44, 2);
    d.mailbox = Some(MailboxLayout {
        out_start: 0x1800,
        out_len: 0x400,
        in_start: 0x1c00,
        in_len: 0x400,
        ..MailboxLayout::STANDARD
    });
    d
}

#[test]
#[ignore = "needs ../shared/captures"]
fn the_lan9252_family_answers_soem_as_the_board_did() {
    // Up to the request of SAFE-OP, which checks the board's own process data (2 bytes out at
    // 0x1100, 6 in at 0x1400: another device than ecsync's drive).
    check_al_and_sii(
        "soem-single-lan9252.pcapng",
        EscModel::lan9252(),
        lan9252_board(),
        348_000_000,
    );
}

#[test]
#[ignore = "needs ../shared/captures"]
fn the_akd_family_answers_soem_as_the_drive_did() {
    // The whole capture: SOEM's request of SAFE-OP is refused by the drive (0x12, code
    // 0x001D: its SyncManagers are not the drive's), as by ecsync's drive, 4.5 ms after it.
    check_al_and_sii(
        "soem-sdinfo-akd.pcapng",
        EscModel::akd_drive(),
        akd(),
        u64::MAX,
    );
}

/// The network of replay-dc.pcapng in the families: an EK1100-like coupler, an EL2828-like
/// terminal (receive times only), an EL2889-like one (64-bit system time).
fn ek1100_el2828_el2889() -> Vec<SlaveSpec> {
    // The EL2889 reads 0x0040 in 0x0502 where the family's other terminals read 0x0050.
    let mut el2889 = EscModel::et1200_terminal(ecsync_sim::model::DcSupport::Full64);
    el2889.sii_control_idle = 0x0040;
    common::line(
        0,
        &[
            EscModel::et1100_coupler(),
            EscModel::et1200_terminal(ecsync_sim::model::DcSupport::ReceiveTimes),
            el2889,
        ],
        0.0,
        |i| DeviceInfo::coupler(["EK1100", "EL2828", "EL2889"][i], i as u32 + 1),
    )
}

/// Each slave's loop (port 1 minus port 0 receive time) at every FPRD of 0x0900 in `answered`
/// with at least 8 bytes, by station address: (model, real).
fn loops(answered: &[Answered]) -> Vec<(u16, i64, i64)> {
    let port_diff = |d: &Dg| {
        let t = |p: usize| u32::from_le_bytes(d.data[4 * p..4 * p + 4].try_into().unwrap());
        i64::from(t(1).wrapping_sub(t(0)) as i32)
    };
    answered
        .iter()
        .filter(|a| a.real.ado == 0x0900 && a.real.data.len() >= 8 && a.real.wkc == 1)
        .filter(|a| is(Command::Fprd)(a))
        .map(|a| (a.real.adp, port_diff(&a.mine), port_diff(&a.real)))
        .collect()
}

/// ethercrab's bring-up of the EK1100, EL2828 and EL2889 (replay-dc.pcapng) replayed into the
/// families: AL control and AL status under device emulation (0x11 read after 0x11 written),
/// the EEPROM's busy bit at every poll but the two the busy time cannot give, DL status, and
/// the loops the 0x0900 latch measures, within 10 ns of the real ones.
#[test]
#[ignore = "needs ../shared/captures"]
fn the_beckhoff_families_answer_ethercrab_as_the_devices_did() {
    let frames = read_pcapng(&captures_dir().join("replay-dc.pcapng"));
    let mut seg = Segment::new(&ek1100_el2828_el2889()).unwrap();
    let answered = replay(&frames, &mut seg);
    let none = |_: &Dg| Vec::new();
    let (n, bad) = differing(&answered, |a| a.real.ado == 0x0120, none);
    assert!(n >= 4 && bad.is_empty(), "AL control\n{}", bad.join("\n"));
    let (n, bad) = differing(
        &answered,
        |a| a.real.ado == 0x0130,
        |d| d.data[..1].to_vec(),
    );
    assert!(n >= 10, "AL status polls");
    assert!(bad.is_empty(), "AL status\n{}", bad.join("\n"));
    assert!(
        answered
            .iter()
            .any(|a| a.real.ado == 0x0130 && a.real.data[0] == 0x11),
        "the capture shows the acknowledge copied"
    );
    // The busy bit of 0x0502 at each of ethercrab's polls (and the rest of the word).
    let (n, bad) = differing(
        &answered,
        |a| a.real.ado == 0x0502 && is(Command::Fprd)(a),
        |d| d.data[..2].to_vec(),
    );
    assert!(n > 700, "SII polls ({n})");
    let busy = answered
        .iter()
        .filter(|a| a.real.ado == 0x0502 && is(Command::Fprd)(a))
        .filter(|a| a.mine.data[1] & 0x80 != 0)
        .count();
    eprintln!(
        "{n} SII polls, {busy} busy on the model, {} differing",
        bad.len()
    );
    assert!(bad.len() <= 2, "SII status\n{}", bad.join("\n"));
    let (n, bad) = differing(&answered, |a| a.real.ado == 0x0110, |d| d.data.clone());
    assert!(n == 3 && bad.is_empty(), "DL status\n{}", bad.join("\n"));
    let l = loops(&answered);
    eprintln!("loops (station, model, real): {l:?}");
    assert_eq!(l.len(), 3, "one latch read per device");
    // The EL2828 stamps both ports on one 10 ns grid: its loop reads the same. The EK1100's
    // port 0 stamps on a 40 ns grid (MII): one reading is within that of the real one (the
    // mean over many latches, within 10 ns: tests/families_delays.rs).
    let (_, mine, real) = l[1];
    assert!((mine - real).abs() <= 10, "EL2828: {mine} vs {real} ns");
    let (_, mine, real) = l[0];
    assert!((mine - real).abs() < 40, "EK1100: {mine} vs {real} ns");
}
