//! Acceptance 4 of issue 32: the propagation delays ecsync's master measures (its bring-up,
//! as `ecsync bringup --json` reports them) on lines of the device families agree within 10 ns
//! with the loops real devices latched: the EK1100-EL2828-EL2889 line of ethercrab's captures
//! (`../shared/captures/`, each capture's own 0x0900 receive times), and a pair of LAN9252
//! boards (1 440 ns per 100BASE-TX hop, the SOEM capture the captures' README reports).
//!
//! A loop is a slave's port 1 minus port 0 receive time with the rest of the line behind its
//! port 1. The master takes a slave's delay from its parent's as half the difference of their loops
//! (the symmetric-hop rule every master uses): the EL2828's from the EK1100's by
//! `(loop_EK1100 - loop_EL2828) / 2`, the EL2889's by half the EL2828's loop more.

mod common;

use common::{captures_dir, datagrams, has_returned, read_pcapng};
use ecsync_master::{BringupConfig, Engine, Network, bringup};
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, SlaveSpec};
use ecsync_wire::Command;

/// ecsync's bring-up on `specs`.
fn bring_up(specs: &[SlaveSpec]) -> Network {
    let mut sim = SimTransport::new(Segment::new(specs).unwrap());
    let cfg = BringupConfig::default();
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    sim.run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up")
}

/// The loops (port 1 minus port 0, ns) of the EK1100 (station 0x1000) and the EL2828 (0x1001)
/// in every ethercrab capture of that line: each capture's FPRD of 0x0900 after its latch.
fn captured_loops() -> (Vec<f64>, Vec<f64>) {
    let (mut ek, mut el) = (Vec::new(), Vec::new());
    for name in [
        "replay-dc.pcapng",
        "replay-ek1100-el2828-el2889.pcapng",
        "replay-issue-255.pcapng",
        "replay-ek1100-alias-address.pcapng",
    ] {
        for f in read_pcapng(&captures_dir().join(name)) {
            if !has_returned(&f.data) {
                continue;
            }
            for d in datagrams(&f.data) {
                let latched = d.command == Command::Fprd.code()
                    && d.ado == 0x0900
                    && d.data.len() >= 8
                    && d.wkc == 1;
                if !latched {
                    continue;
                }
                let t = |p: usize| u32::from_le_bytes(d.data[4 * p..4 * p + 4].try_into().unwrap());
                let l = f64::from(t(1).wrapping_sub(t(0)) as i32);
                match d.adp {
                    0x1000 => ek.push(l),
                    0x1001 => el.push(l),
                    _ => {}
                }
            }
        }
    }
    (ek, el)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
#[ignore = "needs ../shared/captures"]
fn delays_on_an_ek1100_line_agree_with_the_captured_loops() {
    let (ek, el) = captured_loops();
    eprintln!("captured loops: EK1100 {ek:?}, EL2828 {el:?}");
    assert_eq!((ek.len(), el.len()), (4, 4), "one latch read per capture");
    let (ek, el) = (mean(&ek), mean(&el));
    let specs = common::line(
        0x5eed_0000,
        &[
            EscModel::et1100_coupler(),
            EscModel::et1200_terminal(DcSupport::ReceiveTimes),
            EscModel::et1200_terminal(DcSupport::Full64),
        ],
        0.0,
        |i| DeviceInfo::coupler(["EK1100", "EL2828", "EL2889"][i], i as u32 + 1),
    );
    let net = bring_up(&specs);
    assert_eq!(net.reference, 0, "the EK1100 is the reference");
    let expected = [0.0, (ek - el) / 2.0, (ek - el) / 2.0 + el / 2.0];
    // (The EL2828 keeps no system time: a master that trusts 0x0008 gives it no delay.)
    assert!(net.slaves[2].delay_ns.is_some(), "the EL2889 has a delay");
    for (i, e) in expected.iter().enumerate() {
        let Some(d) = net.slaves[i].delay_ns else {
            eprintln!("slave {i}: no delay measured, from the captures {e:.1}");
            continue;
        };
        eprintln!("slave {i}: measured {d:.1} ns, from the captures {e:.1}");
        assert!((d - e).abs() <= 10.0, "slave {i}: {d:.1} vs {e:.1}");
    }
}

#[test]
fn delays_on_a_lan9252_pair_agree_with_the_captured_hop() {
    // 1 m of cable, as the family's hop figure assumes.
    let specs = common::line(
        0x5eed_0000,
        &[EscModel::lan9252(), EscModel::lan9252()],
        1.0,
        |i| DeviceInfo::servo_drive(i as u32 + 1),
    );
    let net = bring_up(&specs);
    let d = net.slaves[1].delay_ns.expect("a delay") - net.slaves[0].delay_ns.unwrap_or(0.0);
    eprintln!("LAN9252 pair: second board's delay {d:.1} ns (half of 1440: 720)");
    assert!((d - 1440.0 / 2.0).abs() <= 10.0, "{d}");
}

/// ecsync's own master brings the presets of the microcontroller families up: their firmware
/// takes AL control milliseconds after a write and refuses writes until then.
#[test]
fn ecsync_brings_the_akd_and_lan9252_presets_up() {
    for (name, toml) in [
        ("presets/akd.toml", ecsync_sim::preset::AKD_TOML),
        (
            "presets/lan9252-pair.toml",
            ecsync_sim::preset::LAN9252_PAIR_TOML,
        ),
    ] {
        let specs = ecsync_sim::config::parse_segment(name, toml).unwrap();
        let net = bring_up(&specs);
        eprintln!("{name}: {:?}", net.lock);
        assert!(net.lock.converged, "{name}");
        assert_eq!(net.slaves.len(), 2, "{name}");
    }
}
