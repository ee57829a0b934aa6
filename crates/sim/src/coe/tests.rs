use super::device::var;
use super::*;
use crate::model::DeviceInfo;
use ecsync_wire::AlState;

fn server() -> SdoServer {
    SdoServer::new(&DeviceInfo::servo_drive(0x1234_5678))
}

/// A CoE SDO request: CoE header (service 2) and the bytes.
fn sdo(bytes: &[u8]) -> Vec<u8> {
    let mut v = vec![0x00, 0x20];
    v.extend_from_slice(bytes);
    v
}

fn ask(s: &mut SdoServer, bytes: &[u8], state: AlState) -> Vec<u8> {
    s.handle(&sdo(bytes), state, 122).unwrap().unwrap()
}

#[test]
fn expedited_uploads_answer_the_identity_and_the_sync_mode() {
    let mut s = server();
    // 0x1018:01 vendor ID, 4 bytes: 0x43.
    let r = ask(&mut s, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(r, [0x00, 0x30, 0x43, 0x18, 0x10, 1, 0x5c, 0x0e, 0, 0]);
    // 0x1C32:01 sync mode, 2 bytes: 0x4B, free run.
    let r = ask(&mut s, &[0x40, 0x32, 0x1c, 1, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(r, [0x00, 0x30, 0x4b, 0x32, 0x1c, 1, 0, 0, 0, 0]);
    // 0x1C32:0B, the SM-event-missed counter.
    let r = ask(&mut s, &[0x40, 0x32, 0x1c, 0x0b, 0, 0, 0, 0], AlState::Op);
    assert_eq!(&r[2..6], &[0x4b, 0x32, 0x1c, 0x0b]);
}

#[test]
fn the_sync_mode_is_written_in_pre_op_and_refused_after() {
    let mut s = server();
    // Expedited download of 2 bytes (0x2B): DC SYNC0; the response carries the request's
    // data bytes, as the EL3004's do (../shared/captures/replay-ek1914-el3004-mailbox.pcapng).
    let r = ask(&mut s, &[0x2b, 0x32, 0x1c, 1, 2, 0, 0, 0], AlState::PreOp);
    assert_eq!(r, [0x00, 0x30, 0x60, 0x32, 0x1c, 1, 2, 0, 0, 0]);
    assert_eq!(s.od.read_u32(0x1c32, 1), 2);
    let r = ask(&mut s, &[0x2b, 0x32, 0x1c, 1, 0, 0, 0, 0], AlState::SafeOp);
    assert_eq!(
        r,
        [0x00, 0x20, 0x80, 0x32, 0x1c, 1, 0x22, 0x00, 0x00, 0x08],
        "abort 0x08000022"
    );
    assert_eq!(s.od.read_u32(0x1c32, 1), 2);
}

#[test]
fn aborts_name_what_is_wrong() {
    let mut s = server();
    let code = |r: &[u8]| u32::from_le_bytes([r[6], r[7], r[8], r[9]]);
    let r = ask(&mut s, &[0x40, 0x00, 0x20, 0, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!((r[2], code(&r)), (0x80, 0x0602_0000), "no object");
    let r = ask(&mut s, &[0x40, 0x18, 0x10, 9, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(code(&r), 0x0609_0011, "no subindex");
    let r = ask(&mut s, &[0x23, 0x18, 0x10, 1, 1, 2, 3, 4], AlState::PreOp);
    assert_eq!(code(&r), 0x0601_0002, "read only");
    // 4 bytes into the 2-byte sync mode.
    let r = ask(&mut s, &[0x23, 0x32, 0x1c, 1, 1, 0, 0, 0], AlState::PreOp);
    assert_eq!(code(&r), 0x0607_0012, "too long");
    // A mapping entry while subindex 0 is not 0.
    let r = ask(
        &mut s,
        &[0x23, 0x00, 0x16, 1, 0x10, 0, 0x40, 0x60],
        AlState::PreOp,
    );
    assert_eq!(code(&r), 0x0601_0003, "subindex 0 first");
    let r = ask(&mut s, &[0xe0, 0, 0, 0, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(code(&r), 0x0504_0001, "unknown command");
    let r = ask(&mut s, &[0x60, 0, 0, 0, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(code(&r), 0x0504_0001, "a segment with no transfer");
}

#[test]
fn the_pdo_assignment_reads_with_complete_access_and_is_rewritten_in_pre_op() {
    let mut s = server();
    // Complete access upload of 0x1C12 (0x50): subindex 0 as 16 bits, then 0x1600; 4 bytes,
    // so expedited with the complete access bit (0x53), as the LAN9252 answers it
    // (../shared/captures/soem-single-lan9252.pcapng).
    let r = ask(&mut s, &[0x50, 0x12, 0x1c, 0, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(&r[2..], &[0x53, 0x12, 0x1c, 0, 1, 0, 0x00, 0x16]);
    // The mapping rewritten the way a master does: 0 entries, two entries, count 2.
    for (sub, v) in [
        (0u8, vec![0u8]),
        (1, 0x6040_0010u32.to_le_bytes().to_vec()),
        (2, 0x607a_0020u32.to_le_bytes().to_vec()),
        (0, vec![2]),
    ] {
        let mut req = vec![0x23 | if v.len() == 1 { 0x0c } else { 0 }, 0x00, 0x16, sub];
        let mut d = v.clone();
        d.resize(4, 0);
        req.extend_from_slice(&d);
        let r = ask(&mut s, &req, AlState::PreOp);
        assert_eq!(r[2], 0x60, "{sub}: {r:02x?}");
    }
    assert_eq!(
        s.od.assigned_entries(0x1c12),
        [(0x6040, 0, 16), (0x607a, 0, 32)]
    );
}

#[test]
fn a_long_object_uploads_in_segments_with_the_toggle() {
    let mut s = server();
    // Room for 20 bytes of CoE: the 26-byte device name does not fit.
    let ask_small =
        |s: &mut SdoServer, b: &[u8]| s.handle(&sdo(b), AlState::PreOp, 20).unwrap().unwrap();
    let r = ask_small(&mut s, &[0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
    let name = b"ecsync virtual servo drive";
    assert_eq!(r[2], 0x41);
    assert_eq!(
        u32::from_le_bytes([r[6], r[7], r[8], r[9]]),
        name.len() as u32
    );
    let mut got = r[10..].to_vec();
    let mut toggle = false;
    loop {
        let r = ask_small(
            &mut s,
            &[0x60 | (u8::from(toggle) << 4), 0, 0, 0, 0, 0, 0, 0],
        );
        assert_eq!(r[2] & 0x10 != 0, toggle, "toggle echoed");
        let short = usize::from((r[2] >> 1) & 7);
        let n = if short == 0 { r.len() - 3 } else { 7 - short };
        got.extend_from_slice(&r[3..3 + n]);
        toggle = !toggle;
        if r[2] & 1 != 0 {
            break;
        }
    }
    assert_eq!(got, name);
    // A wrong toggle aborts with 0x05030000.
    let _ = ask_small(&mut s, &[0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
    let r = ask_small(&mut s, &[0x70, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(u32::from_le_bytes([r[6], r[7], r[8], r[9]]), 0x0503_0000);
}

#[test]
fn sdo_information_lists_and_describes_the_dictionary() {
    let mut s = server();
    let info = |s: &mut SdoServer, b: &[u8]| {
        let mut v = vec![0x00, 0x80];
        v.extend_from_slice(b);
        s.handle(&v, AlState::PreOp, 122).unwrap().unwrap()
    };
    let r = info(&mut s, &[0x01, 0, 0, 0, 0x01, 0x00]);
    assert_eq!(r[2] & 0x7f, 0x02);
    let list: Vec<u16> = r[8..]
        .chunks(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    assert_eq!(&list[..5], &[0x1000, 0x1008, 0x1009, 0x100a, 0x1018]);
    assert!(
        list.contains(&0x1c32) && list.contains(&0x6064),
        "{list:04x?}"
    );
    let r = info(&mut s, &[0x03, 0, 0, 0, 0x18, 0x10]);
    assert_eq!(&r[6..12], &[0x18, 0x10, 0x07, 0x00, 4, 9]);
    assert_eq!(&r[12..], b"Identity");
    let r = info(&mut s, &[0x05, 0, 0, 0, 0x18, 0x10, 0x02, 0x00]);
    // Index, subindex, value info, UNSIGNED32, 32 bits, read-only, the name.
    assert_eq!(&r[6..16], &[0x18, 0x10, 2, 0, 0x07, 0, 32, 0, 0x07, 0]);
    assert_eq!(&r[16..], b"Product code");
    let r = info(&mut s, &[0x03, 0, 0, 0, 0x00, 0x20]);
    assert_eq!(r[2], 0x07, "SDO Info error");
    assert_eq!(u32::from_le_bytes([r[6], r[7], r[8], r[9]]), 0x0602_0000);
}

/// A dictionary of `extra` more objects than the servo drive's (0x2000, 0x2001, ...).
fn big_server(extra: u16) -> SdoServer {
    let mut s = server();
    for k in 0..extra {
        s.od.insert(var(
            0x2000 + k,
            "Manufacturer object",
            data_type::UINT32,
            Access::ReadWrite,
            vec![0; 4],
        ));
    }
    s
}

#[test]
fn a_long_od_list_comes_in_fragments_counting_down() {
    // 100 objects more than fit a 128-byte mailbox (122 bytes of CoE: 116 of data, 58
    // indices a fragment).
    let mut s = big_server(100);
    let all: Vec<u16> = s.od.objects().iter().map(|o| o.index).collect();
    let data_len = 2 + 2 * all.len();
    let want_fragments = data_len.div_ceil(116);
    assert!(want_fragments >= 3, "{} objects", all.len());
    let req = [0x00, 0x80, 0x01, 0, 0, 0, 0x01, 0x00];
    let mut got = Vec::new();
    let mut fragment = s.handle(&req, AlState::PreOp, 122).unwrap();
    let mut k = 0;
    while let Some(f) = fragment {
        assert!(f.len() <= 122, "fragment {k}: {} bytes", f.len());
        // CoE header: SDO Information; the opcode 0x02 with the incomplete bit on all but
        // the last; the fragments still to come.
        assert_eq!(&f[..2], &[0x00, 0x80]);
        let left = usize::from(u16::from_le_bytes([f[4], f[5]]));
        assert_eq!(left, want_fragments - 1 - k, "fragment {k}");
        assert_eq!(f[2], 0x02 | if left > 0 { 0x80 } else { 0 });
        assert_eq!((f.len() - 6) % 2, 0, "whole indices");
        got.extend_from_slice(&f[6..]);
        k += 1;
        fragment = s.next_fragment();
    }
    assert_eq!(k, want_fragments);
    // The list type, then every index once, in order.
    assert_eq!(&got[..2], &[0x01, 0x00]);
    let indices: Vec<u16> = got[2..]
        .chunks(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    assert_eq!(indices, all);
}

#[test]
fn a_new_request_drops_the_fragments_left_and_a_short_list_is_one_message() {
    let mut s = big_server(100);
    let req = [0x00, 0x80, 0x01, 0, 0, 0, 0x01, 0x00];
    let first = s.handle(&req, AlState::PreOp, 122).unwrap().unwrap();
    assert_eq!(first[2], 0x82, "incomplete");
    let r = ask(&mut s, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0], AlState::PreOp);
    assert_eq!(r[2], 0x43);
    assert_eq!(s.next_fragment(), None, "the SDO answer ended the OD list");
    // The servo drive's own list fits: one message, no fragment left.
    let mut s = server();
    let r = s.handle(&req, AlState::PreOp, 122).unwrap().unwrap();
    assert_eq!((r[2], &r[4..6]), (0x02, &[0u8, 0][..]));
    assert_eq!(s.next_fragment(), None);
}
