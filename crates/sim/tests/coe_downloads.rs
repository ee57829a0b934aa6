//! Issue 13: the CoE downloads besides the expedited one, each message written byte by byte
//! from ETG.1000.6 section 5.6.2 (SDO Download Normal Request, Download SDO Segment Request,
//! complete access) and its effect checked on the drive: the value uploaded back, and a
//! remapping written with complete access in PRE-OP that the process image follows (the
//! SyncManager length SAFE-OP wants, the controlword the CiA 402 application reads where the
//! new mapping puts it).
//!
//! The SDO command byte (ETG.1000.6 table 39 ff.): bits 7-5 the command specifier (1:
//! initiate download, 0: download segment), bit 4 complete access (initiate) or toggle
//! (segment), bits 3-2 the unused bytes of an expedited transfer, bit 1 expedited, bit 0
//! size indicated (initiate) or last segment; a segment's bits 3-1 the bytes of fewer than 7.

mod common;

use common::MbxDrive;
use ecsync_sim::model::{DeviceInfo, MailboxLayout};

/// The CoE header of an SDO request (number 0, service 2), little-endian.
const SDO_REQ: [u8; 2] = [0x00, 0x20];
/// An SDO download response (service 3, command 0x60) to `index:sub`, bytes 6-9 those of
/// the request (`request4`: an expedited request's data, a normal one's size), as the real
/// EL3004 and EK1914 answer (../shared/captures/replay-ek1914-el3004-configure.pcapng).
fn download_response(index: u16, sub: u8, request4: [u8; 4]) -> Vec<u8> {
    let [lo, hi] = index.to_le_bytes();
    let mut r = vec![0x00, 0x30, 0x60, lo, hi, sub];
    r.extend_from_slice(&request4);
    r
}

/// The CoE part of an answer (after the mailbox header).
fn coe_of(r: &[u8]) -> &[u8] {
    &r[6..]
}

/// An expedited upload of `index:sub`: its 4 data bytes.
fn upload4(d: &mut MbxDrive, index: u16, sub: u8) -> [u8; 4] {
    let [lo, hi] = index.to_le_bytes();
    let r = d.coe(&[0x00, 0x20, 0x40, lo, hi, sub, 0, 0, 0, 0]);
    assert_eq!(r[8] & 0xe3, 0x43, "expedited upload answered: {r:02x?}");
    [r[12], r[13], r[14], r[15]]
}

/// A normal download of 0x10F1:02 (the sync error counter limit, UNSIGNED16) = 4: command
/// 0x21 (initiate download, size indicated, not expedited), index F1 10, subindex 02, the
/// complete size 2 as 4 bytes, then the 2 data bytes: 12 bytes of CoE.
#[test]
fn a_normal_download_writes_the_entry() {
    let mut d = MbxDrive::servo();
    assert_eq!(upload4(&mut d, 0x10f1, 2), [0, 0, 0, 0], "the drive's own");
    let mut m = SDO_REQ.to_vec();
    m.extend_from_slice(&[0x21, 0xf1, 0x10, 0x02, 0x02, 0x00, 0x00, 0x00, 0x04, 0x00]);
    let r = d.coe(&m);
    assert_eq!(coe_of(&r), download_response(0x10f1, 2, [2, 0, 0, 0]));
    assert_eq!(upload4(&mut d, 0x10f1, 2), [4, 0, 0, 0]);
    // The complete size says 4 where the entry has 2: 0x06070012 (length too high), and the
    // value stays.
    let mut m = SDO_REQ.to_vec();
    m.extend_from_slice(&[0x21, 0xf1, 0x10, 0x02, 0x04, 0, 0, 0, 9, 0, 0, 0]);
    let r = d.coe(&m);
    assert_eq!(
        coe_of(&r),
        [0x00, 0x20, 0x80, 0xf1, 0x10, 0x02, 0x12, 0x00, 0x07, 0x06]
    );
    assert_eq!(upload4(&mut d, 0x10f1, 2), [4, 0, 0, 0]);
}

/// 0x1600 (the RxPDO mapping) with target position first, controlword after: two entries
/// (index << 16 | subindex << 8 | bits), subindex 0 as 16 bits, as complete access lays an
/// object out: 10 bytes.
fn remap_target_then_controlword() -> Vec<u8> {
    let mut v = vec![0x02, 0x00];
    v.extend_from_slice(&0x607a_0020u32.to_le_bytes());
    v.extend_from_slice(&0x6040_0010u32.to_le_bytes());
    v
}

/// The SyncManagers of the process data: SM2 (0x1100, `out_len` bytes, control 0x64:
/// buffered, written by the master, watchdog) and SM3 (0x1180, 18 bytes, control 0x20).
fn process_data_sms(d: &mut MbxDrive, out_len: u16) {
    let mut sm2 = vec![0x00, 0x11];
    sm2.extend_from_slice(&out_len.to_le_bytes());
    sm2.extend_from_slice(&[0x64, 0x00, 0x01, 0x00]);
    d.put(0x0810, &sm2);
    d.put(0x0818, &[0x80, 0x11, 18, 0, 0x20, 0x00, 0x01, 0x00]);
}

/// AL status: state and status code.
fn al(d: &mut MbxDrive) -> (u8, u16) {
    let s = d.get(0x0130, 6).1;
    (s[0], u16::from_le_bytes([s[4], s[5]]))
}

/// A logical datagram (LWR 0x0B, LRD 0x0A) at logical address `laddr`: its data and WKC.
fn logical(d: &mut MbxDrive, cmd: u8, laddr: u32, data: &[u8]) -> (Vec<u8>, u16) {
    let mut v = vec![cmd, 0];
    v.extend_from_slice(&laddr.to_le_bytes());
    v.extend_from_slice(&(data.len() as u16).to_le_bytes());
    v.extend_from_slice(&[0, 0]);
    v.extend_from_slice(data);
    v.extend_from_slice(&[0, 0]);
    d.e.process_datagram(&mut v, d.t_ps);
    (v[10..10 + data.len()].to_vec(), common::wkc(&v))
}

/// The drive in OP with SM2 of `out_len` bytes, mapped by FMMU 0 at logical 0 (written) and
/// SM3 by FMMU 1 at logical 0x100 (read): the statusword it answers outputs `out` with, two
/// cycles (1 ms apart) of LWR then LRD (the application runs as its inputs are read).
fn statusword_after(d: &mut MbxDrive, out_len: u16, out: &[u8]) -> u16 {
    process_data_sms(d, out_len);
    // FMMU: logical start (4), length (2), start bit 0, stop bit 7, physical start (2),
    // physical start bit 0, type (1 read, 2 write), activate.
    let fmmu = |log: u32, len: u16, phys: u16, ty: u8| {
        let mut f = log.to_le_bytes().to_vec();
        f.extend_from_slice(&len.to_le_bytes());
        f.extend_from_slice(&[0, 7]);
        f.extend_from_slice(&phys.to_le_bytes());
        f.extend_from_slice(&[0, ty, 1, 0, 0, 0]);
        f
    };
    d.put(0x0600, &fmmu(0, out_len, 0x1100, 0x02));
    d.put(0x0610, &fmmu(0x100, 18, 0x1180, 0x01));
    d.put(0x0120, &[0x04, 0x00]);
    assert_eq!(al(d), (0x04, 0), "SAFE-OP");
    d.put(0x0120, &[0x08, 0x00]);
    assert_eq!(al(d).0, 0x08, "OP");
    let mut inputs = Vec::new();
    for _ in 0..2 {
        d.t_ps += common::MS;
        assert_eq!(logical(d, 0x0b, 0, out).1, 1, "LWR");
        let (i, w) = logical(d, 0x0a, 0x100, &[0; 18]);
        assert_eq!(w, 1, "LRD");
        inputs = i;
    }
    u16::from_le_bytes([inputs[0], inputs[1]])
}

/// Complete access downloads in PRE-OP: 0x1600 as a normal download (command 0x31: initiate,
/// complete access, size indicated; complete size 10), then 0x1C12 as an expedited one
/// (command 0x33: 4 bytes, subindex 0 = 1 as 16 bits and 0x1600). The process image follows:
/// SAFE-OP wants SM2 of 6 bytes now (16 refused with 0x001D, invalid output configuration),
/// and the drive reads its controlword at byte 4: Shutdown (6) there takes it to Ready to
/// switch on (statusword 0x0021 in bits 0-6), the same word at byte 0 (the old place) does
/// not.
#[test]
fn a_remapping_written_with_complete_access_is_the_process_image() {
    for cw_at in [4usize, 0] {
        let mut d = MbxDrive::servo();
        let mut m = SDO_REQ.to_vec();
        m.extend_from_slice(&[0x31, 0x00, 0x16, 0x00, 0x0a, 0x00, 0x00, 0x00]);
        m.extend_from_slice(&remap_target_then_controlword());
        let r = d.coe(&m);
        assert_eq!(coe_of(&r), download_response(0x1600, 0, [10, 0, 0, 0]));
        let mut m = SDO_REQ.to_vec();
        m.extend_from_slice(&[0x33, 0x12, 0x1c, 0x00, 0x01, 0x00, 0x00, 0x16]);
        let r = d.coe(&m);
        assert_eq!(coe_of(&r), download_response(0x1c12, 0, [1, 0, 0, 0x16]));
        // Read back with complete access (command 0x50): 0x43-less normal answer 0x41, size
        // 10, the bytes written.
        let r = d.coe(&[0x00, 0x20, 0x50, 0x00, 0x16, 0x00, 0, 0, 0, 0]);
        assert_eq!(r[8], 0x51, "normal upload, complete access: {r:02x?}");
        assert_eq!(&r[12..16], &[10, 0, 0, 0]);
        assert_eq!(&r[16..26], &remap_target_then_controlword()[..]);
        // The old SM2 length is refused.
        process_data_sms(&mut d, 16);
        d.put(0x0120, &[0x04, 0x00]);
        assert_eq!(al(&mut d), (0x12, 0x001d), "PRE-OP + error, 0x001D");
        d.put(0x0120, &[0x12, 0x00]);
        let mut out = [0u8; 6];
        out[cw_at..cw_at + 2].copy_from_slice(&6u16.to_le_bytes());
        let sw = statusword_after(&mut d, 6, &out);
        if cw_at == 4 {
            assert_eq!(sw & 0x6f, 0x21, "Ready to switch on: {sw:#06x}");
        } else {
            assert_eq!(sw & 0x6f, 0x40, "Switch on disabled: {sw:#06x}");
        }
    }
}

/// A segmented download on a drive whose mailboxes are 32 bytes (26 of CoE, 16 of data in an
/// initiate): 0x1600 whole with complete access, 30 bytes (subindex 0 as 16 bits and seven
/// entries in a new order, the controlword at byte 4). The initiate (0x31, complete size 30)
/// fills the mailbox with its first 16 bytes (SSC: a segmented initiate is as long as the
/// mailbox; one shorter is 0x08, invalid size); a segment with toggle 0 (command 0x00, 7
/// bytes), answered 0x20; one with the toggle not changed aborts with 0x05030000; the
/// transfer again, its last segment with toggle 1 (0x11), answered 0x30. The drive then reads
/// its controlword at byte 4.
#[test]
fn a_segmented_download_alternates_the_toggle_and_writes_the_object() {
    let dev = DeviceInfo {
        mailbox: Some(MailboxLayout {
            out_start: 0x1000,
            out_len: 32,
            in_start: 0x1080,
            in_len: 32,
            ..MailboxLayout::STANDARD
        }),
        ..DeviceInfo::servo_drive(7)
    };
    let mut data = vec![0x07, 0x00];
    for e in [
        0x607a_0020u32, // target position, bytes 0-3
        0x6040_0010,    // controlword, 4-5
        0x6060_0008,    // modes of operation, 6
        0x0000_0008,    // padding, 7
        0x60ff_0020,    // target velocity
        0x6071_0010,    // target torque
        0x60b8_0010,    // touch probe function
    ] {
        data.extend_from_slice(&e.to_le_bytes());
    }
    assert_eq!(data.len(), 30);
    let initiate = |first: usize| {
        let mut m = SDO_REQ.to_vec();
        m.extend_from_slice(&[0x31, 0x00, 0x16, 0x00, 30, 0, 0, 0]);
        m.extend_from_slice(&data[..first]);
        m
    };
    let segment = |cmd: u8, part: &[u8]| {
        let mut m = SDO_REQ.to_vec();
        m.push(cmd);
        m.extend_from_slice(part);
        m
    };
    let seg_response = |toggle: u8| vec![0x00, 0x30, 0x20 | (toggle << 4), 0, 0, 0, 0, 0, 0, 0];
    let mut d = MbxDrive::with(dev);
    // Short of the mailbox: refused (SSC sdoserv.c).
    let r = d.coe(&initiate(10));
    assert_eq!(
        &r[5..10],
        &[r[5] & 0xf0, 0x01, 0x00, 0x08, 0x00],
        "0x08: {r:02x?}"
    );
    let r = d.coe(&initiate(16));
    assert_eq!(coe_of(&r), download_response(0x1600, 0, [30, 0, 0, 0]));
    let r = d.coe(&segment(0x00, &data[16..23]));
    assert_eq!(coe_of(&r), seg_response(0));
    // The toggle again 0: aborted, the transfer gone.
    let r = d.coe(&segment(0x01, &data[23..30]));
    assert_eq!(
        &coe_of(&r)[..2],
        &[0x00, 0x20],
        "an abort is an SDO request: {r:02x?}"
    );
    assert_eq!(
        coe_of(&r)[2..],
        [0x80, 0x00, 0x16, 0x00, 0x00, 0x00, 0x03, 0x05]
    );
    // Anew, right this time.
    let r = d.coe(&initiate(16));
    assert_eq!(coe_of(&r), download_response(0x1600, 0, [30, 0, 0, 0]));
    let r = d.coe(&segment(0x00, &data[16..23]));
    assert_eq!(coe_of(&r), seg_response(0));
    let r = d.coe(&segment(0x11, &data[23..30]));
    assert_eq!(coe_of(&r), seg_response(1));
    // 16 bytes of outputs as before, the controlword now at byte 4.
    let mut out = [0u8; 16];
    out[4..6].copy_from_slice(&6u16.to_le_bytes());
    let sw = statusword_after(&mut d, 16, &out);
    assert_eq!(sw & 0x6f, 0x21, "Ready to switch on: {sw:#06x}");
}
