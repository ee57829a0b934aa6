//! An oversampling terminal on SYNC1 (0x1C32:01 = 3), worked out by hand: SYNC0 every
//! 250 us from 10 ms, SYNC1 750 us after a pulse, so a block is taken every 1 ms at
//! 10.75 ms + k ms; the OP checks of its DC configuration.

use super::Esc;
use super::testing::{dg, put, read};
use crate::clock::CrystalParams;
use crate::model::{DeviceInfo, EscModel};
use ecsync_wire::{AlState, Command};

const MS_PS: u64 = 1_000_000_000;

/// AL status and AL status code.
fn al(e: &mut Esc, t_ps: u64) -> (u8, u16) {
    let st = read(e, 0x0130, 6, t_ps);
    (st[0], u16::from_le_bytes([st[4], st[5]]))
}

/// An SDO download of `value` (2 bytes) to `index:sub` at `t_ps`: the answer's command byte
/// (0x60 accepted, 0x80 aborted).
fn download(e: &mut Esc, index: u16, sub: u8, value: u16, counter: u8, t_ps: u64) -> u8 {
    let [lo, hi] = index.to_le_bytes();
    let mut m = vec![
        10,
        0,
        0,
        0,
        0,
        0x03 | (counter << 4),
        0x00,
        0x20,
        0x2b,
        lo,
        hi,
        sub,
    ];
    m.extend_from_slice(&value.to_le_bytes());
    m.resize(128, 0);
    put(e, 0x1000, &m, t_ps);
    let mut d = dg(Command::Brd, 0, 0x1080, &[0; 128]);
    e.process_datagram(&mut d, t_ps + MS_PS / 2);
    d[10 + 8]
}

/// A four-sample terminal in SAFE-OP with 0x1C32:01 = `mode`; SYNC0 every `sync0_ns` from
/// 10 ms, SYNC1 `sync1_ns` after, both on (`sync1_ns` `None`: SYNC0 only).
fn terminal(mode: u16, sync0_ns: u32, sync1_ns: Option<u32>) -> Esc {
    let mut e = Esc::new(
        EscModel::servo_mii(),
        DeviceInfo::oversampling_terminal(3, 4),
        CrystalParams::default(),
    );
    e.set_links([true, false, false, false]);
    put(
        &mut e,
        0x0800,
        &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00],
        0,
    );
    put(
        &mut e,
        0x0808,
        &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00],
        0,
    );
    put(&mut e, 0x0120, &[0x02, 0], 0);
    assert_eq!(
        download(&mut e, 0x1c32, 1, mode, 1, MS_PS),
        0x60,
        "mode {mode} taken"
    );
    // Outputs: 4 samples x 2 channels x INT16 = 16 bytes at 0x1100; no inputs.
    put(
        &mut e,
        0x0810,
        &[0x00, 0x11, 16, 0, 0x64, 0, 1, 0],
        2 * MS_PS,
    );
    put(&mut e, 0x09a0, &sync0_ns.to_le_bytes(), 2 * MS_PS);
    put(&mut e, 0x0990, &10_000_000u64.to_le_bytes(), 2 * MS_PS);
    if let Some(d) = sync1_ns {
        put(&mut e, 0x09a4, &d.to_le_bytes(), 2 * MS_PS);
    }
    let activation = if sync1_ns.is_some() { 0x07 } else { 0x03 };
    put(&mut e, 0x0981, &[activation], 2 * MS_PS);
    put(&mut e, 0x0120, &[0x04, 0], 2 * MS_PS);
    assert_eq!(al(&mut e, 2 * MS_PS).0, 0x04, "SAFE-OP");
    e
}

/// 0x1C32:04 offers SYNC1 on the terminal only: the servo drive refuses mode 3 (0x06090030),
/// the terminal takes it, and runs its application on SYNC1.
#[test]
fn only_the_oversampling_terminal_takes_sync1_mode() {
    let mut drive = Esc::new(
        EscModel::servo_mii(),
        DeviceInfo::servo_drive(7),
        CrystalParams::default(),
    );
    drive.set_links([true, false, false, false]);
    put(
        &mut drive,
        0x0800,
        &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00],
        0,
    );
    put(
        &mut drive,
        0x0808,
        &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00],
        0,
    );
    put(&mut drive, 0x0120, &[0x02, 0], 0);
    assert_eq!(download(&mut drive, 0x1c32, 1, 3, 1, MS_PS), 0x80, "abort");
    assert!(!drive.runs_on_sync1());
    let e = terminal(3, 250_000, Some(750_000));
    assert!(e.runs_on_sync0() && e.runs_on_sync1());
    // SYNC1 first at 10 ms + 750 us, then every (750 / 250 + 1) x 250 us = 1 ms.
    assert_eq!(e.application_events(), Some((10_750_000, 1_000_000)));
    let od = &e.sdo_server().unwrap().od;
    assert_eq!(od.read_u32(0x1c32, 4), 0x002f);
    assert_eq!(od.read_u32(0x1c32, 5), 10_000);
}

/// OP refused as the terminal's firmware would: SYNC1 set to the cycle (1 ms: SYNC1 every
/// 1.25 ms, 5 SYNC0 pulses, not 4: ethercrab #368's first try) or off: 0x0030; 0x1C32:02
/// other than the SYNC1 period: 0x0035; SYNC0 under the 10 us a sample needs: 0x0036. The
/// right set-up (SYNC1 = 3 x 250 us, :02 = 1 ms or 0) goes to OP.
#[test]
fn op_checks_the_sync1_configuration() {
    let op = |e: &mut Esc| {
        put(e, 0x0120, &[0x08, 0], 3 * MS_PS);
        al(e, 3 * MS_PS)
    };
    assert_eq!(
        op(&mut terminal(3, 250_000, Some(1_000_000))),
        (0x14, 0x0030)
    );
    assert_eq!(op(&mut terminal(3, 250_000, None)), (0x14, 0x0030));
    assert_eq!(op(&mut terminal(3, 5_000, Some(15_000))), (0x14, 0x0036));
    for (cycle_time, want) in [
        (250_000u32, (0x14, 0x0035)),
        (1_000_000, (0x08, 0)),
        (0, (0x08, 0)),
    ] {
        let mut e = terminal(3, 250_000, Some(750_000));
        e.sdo_server_mut()
            .unwrap()
            .od
            .write(0x1c32, 2, &cycle_time.to_le_bytes(), AlState::PreOp)
            .unwrap();
        assert_eq!(op(&mut e), want, "0x1C32:02 = {cycle_time}");
    }
    // Mode 2 on the same terminal runs on SYNC0 (a block per pulse), its cycle time SYNC0's
    // (the default 1 ms would refuse OP with 0x0035).
    let mut e = terminal(2, 250_000, None);
    e.sdo_server_mut()
        .unwrap()
        .od
        .write(0x1c32, 2, &250_000u32.to_le_bytes(), AlState::PreOp)
        .unwrap();
    assert_eq!(op(&mut e), (0x08, 0));
    assert_eq!(e.application_events(), Some((10_000_000, 250_000)));
}

/// Blocks written against SYNC1 at 10.75 ms + k ms: once a cycle 100 us before the event
/// (none missed, none overwritten); every 250 us, a master stepping by SYNC0 (three of each
/// four blocks overwritten before an event took them, none missed); every 2 ms (one event
/// in two missed).
#[test]
fn sync1_events_count_missed_and_overwritten_blocks() {
    let mut e = terminal(3, 250_000, Some(750_000));
    put(&mut e, 0x0120, &[0x08, 0], 3 * MS_PS);
    assert_eq!(al(&mut e, 3 * MS_PS).0, 0x08, "OP");
    // System time = local time = real time here (default crystal, no offset).
    let local = |e: &Esc, t_ps: u64| e.dc().unwrap().system_time_split(t_ps).0;
    let t0 = 20 * MS_PS;
    let base = local(&e, t0);
    let event_ns = |k: u64| 10_750_000 + k * 1_000_000;
    let first = (base - 10_750_000) / 1_000_000 + 1;
    let at = |k: u64, before_ns: u64| t0 + (event_ns(k) - before_ns - base) * 1000;
    let write = |e: &mut Esc, t_ps: u64| put(e, 0x1100, &[0u8; 16], t_ps);
    let mut k = first + 1;
    for _ in 0..10 {
        write(&mut e, at(k, 100_000));
        k += 1;
    }
    assert_eq!((e.sm_events_missed(), e.outputs_overwritten()), (0, 0));
    // Every 250 us for 5 cycles: 20 blocks, 5 taken.
    for _ in 0..5 {
        for j in 0..4 {
            write(&mut e, at(k, 100_000 + j * 250_000));
        }
        k += 1;
    }
    assert_eq!((e.sm_events_missed(), e.outputs_overwritten()), (0, 15));
    // Every 2 ms for 4 blocks: 3 events in between without a block.
    for _ in 0..4 {
        write(&mut e, at(k, 100_000));
        k += 2;
    }
    assert_eq!((e.sm_events_missed(), e.outputs_overwritten()), (3, 15));
}
