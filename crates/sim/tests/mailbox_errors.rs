//! Issue 13, acceptance 7: malformed mailbox messages never panic and get the answer a real
//! slave gives. The reference is ETG's slave stack code (SSC), which most real slaves run:
//! its `mailbox.c` (`MBX_MailboxWriteInd`, `MailboxServiceInd`), `ecatcoe.c`
//! (`COE_ServiceInd`) and `sdoserv.c` (`SDOS_SdoInd`, `SDOS_SdoInfoInd`). Each case below says
//! where its answer comes from; the codes are ETG.1000.4's mailbox error codes (table 30:
//! a reply of type 0, service 0x0001, the code) and ETG.1000.6's SDO abort codes.
//!
//! The codes SSC never sends to a master that behaves are not made up either: 0x01 (syntax:
//! only SSC's TEST_APPLICATION, when the master's counter does not go up by one), 0x03
//! (invalid channel: SSC does not look at the channel), 0x07 (no more memory: only when SSC's
//! mailbox queue cannot allocate, which a virtual drive never runs out of). The tests check
//! that those messages are served as SSC serves them.
//!
//! Every message is written into SM0 (0x1000, 128 bytes) of a drive in PRE-OP by a broadcast
//! write built byte by byte, its answer read from SM1 (0x1080) 1 ms later.

mod common;

use common::MbxDrive as Drive;
use proptest::prelude::*;

/// The mailbox error code of answer `r` (a type 0 reply: length 4, service 0x0001, the code).
fn mailbox_error(r: &[u8]) -> Option<u16> {
    (r.len() == 10 && r[5] & 0x0f == 0 && r[0..2] == [4, 0] && r[6..8] == [1, 0])
        .then(|| u16::from_le_bytes([r[8], r[9]]))
}

/// The abort code of an SDO abort answer (CoE service 2, command 0x80).
fn sdo_abort(r: &[u8]) -> Option<u32> {
    (r[5] & 0x0f == 3 && r.len() >= 16 && r[7] >> 4 == 2 && r[8] == 0x80)
        .then(|| u32::from_le_bytes([r[12], r[13], r[14], r[15]]))
}

/// The code of an SDO Information error answer (CoE service 8, opcode 7).
fn sdo_info_error(r: &[u8]) -> Option<u32> {
    (r[5] & 0x0f == 3 && r.len() >= 16 && r[7] >> 4 == 8 && r[8] & 0x7f == 7)
        .then(|| u32::from_le_bytes([r[12], r[13], r[14], r[15]]))
}

/// An expedited upload of 0x1018:01 (the vendor ID), as SOEM sends it: CoE header 0x2000
/// (SDO request), command 0x40, index, subindex, 4 zero bytes.
const UPLOAD_VENDOR: [u8; 10] = [0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0];

#[test]
fn a_well_formed_upload_is_answered_as_the_reference() {
    let mut d = Drive::servo();
    let r = d.coe(&UPLOAD_VENDOR);
    // SDO response (service 3), expedited 4 bytes (0x43), the vendor ID 0x00000E5C.
    assert_eq!(
        &r[6..16],
        &[0x00, 0x30, 0x43, 0x18, 0x10, 0x01, 0x5c, 0x0e, 0, 0]
    );
}

/// 0x02, unsupported protocol: every type but CoE (this drive's only one), the error type
/// from the master and the reserved codes included (SSC `MailboxServiceInd`, default case).
#[test]
fn a_protocol_the_drive_lacks_is_0x02() {
    let mut d = Drive::servo();
    for ty in [0x0, 0x1, 0x2, 0x4, 0x5, 0x6, 0xe, 0xf] {
        let r = d.send(ty, &UPLOAD_VENDOR).expect("an answer");
        assert_eq!(mailbox_error(&r), Some(0x0002), "type {ty:#x}: {r:02x?}");
    }
}

/// 0x04, service not supported: the CoE services a slave does not take from a master
/// (emergency 1, SDO response 3, TxPDO 4, RxPDO 5, their remote requests 6 and 7); 0x05,
/// invalid header: CoE service numbers that are none (0, 9-15). SSC `COE_ServiceInd`.
#[test]
fn coe_services_a_slave_does_not_serve_are_0x04_and_numbers_without_one_0x05() {
    let mut d = Drive::servo();
    for service in 0u8..16 {
        let mut m = UPLOAD_VENDOR;
        m[1] = service << 4;
        let r = d.coe(&m);
        let want = match service {
            2 => None, // SDO request: served
            8 => None, // SDO Information: served (an SDO Info error here)
            1 | 3..=7 => Some(0x0004),
            _ => Some(0x0005),
        };
        assert_eq!(mailbox_error(&r), want, "service {service}: {r:02x?}");
    }
}

/// 0x06, size too short: an SDO Information request shorter than its opcode's fixed part
/// (SSC `SDOS_SdoInfoInd`: 8 bytes for the OD list and the object description, 10 for the
/// entry description), and a CoE message without its 2-byte CoE header (this drive's
/// reading of ETG.1000.4's "size too short"; SSC would read the header past the length).
#[test]
fn messages_too_short_for_their_header_are_0x06() {
    let mut d = Drive::servo();
    // Get OD list without the list type: CoE header 0x8000, opcode 1, reserved, fragments.
    let r = d.coe(&[0x00, 0x80, 0x01, 0x00, 0x00, 0x00]);
    assert_eq!(mailbox_error(&r), Some(0x0006), "{r:02x?}");
    // Object description without its index.
    let r = d.coe(&[0x00, 0x80, 0x03, 0x00, 0x00, 0x00, 0x18]);
    assert_eq!(mailbox_error(&r), Some(0x0006), "{r:02x?}");
    // Entry description of 0x1018 without subindex and value info (8 of its 10 bytes).
    let r = d.coe(&[0x00, 0x80, 0x05, 0x00, 0x00, 0x00, 0x18, 0x10]);
    assert_eq!(mailbox_error(&r), Some(0x0006), "{r:02x?}");
    // The full 10 bytes are answered: index, subindex 1, UNSIGNED32, 32 bits.
    let r = d.coe(&[0x00, 0x80, 0x05, 0x00, 0x00, 0x00, 0x18, 0x10, 0x01, 0x00]);
    assert_eq!((r[8] & 0x7f, &r[12..15]), (0x06, &[0x18, 0x10, 0x01][..]));
    // One byte of CoE header.
    let r = d.coe(&[0x00]);
    assert_eq!(mailbox_error(&r), Some(0x0006), "{r:02x?}");
    let r = d.coe(&[]);
    assert_eq!(mailbox_error(&r), Some(0x0006), "{r:02x?}");
}

/// 0x08, invalid size: a header length past the mailbox (SSC `MBX_MailboxWriteInd`, "size
/// specified in mailbox header too large"); an initiate upload or expedited download whose
/// length is not 10, shorter or longer, and a normal download whose length disagrees with its
/// complete size (SSC `SDOS_SdoInd`). A too-short SDO is thus a mailbox error, not an abort,
/// on a real slave.
#[test]
fn lengths_the_service_does_not_have_are_0x08() {
    let mut d = Drive::servo();
    // Length 123 in a 128-byte mailbox (room for 122).
    let c = d.next_counter();
    let mut m = vec![123, 0, 0, 0, 0, 0x03 | (c << 4)];
    m.extend_from_slice(&UPLOAD_VENDOR);
    let r = d.send_raw(&m).unwrap();
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    // The upload cut to 6 bytes (index and subindex there, no data bytes), and padded to 12.
    let r = d.coe(&UPLOAD_VENDOR[..6]);
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    let r = d.coe(&UPLOAD_VENDOR[..4]);
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    let mut long = UPLOAD_VENDOR.to_vec();
    long.extend_from_slice(&[0, 0]);
    let r = d.coe(&long);
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    // Expedited download of 2 bytes (0x2B) to 0x10F1:02 in 9 bytes.
    let r = d.coe(&[0x00, 0x20, 0x2b, 0xf1, 0x10, 0x02, 4, 0, 0]);
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    // Normal download (0x21, size given) of 2 bytes with 3 data bytes (length 13, not 12).
    let r = d.coe(&[0x00, 0x20, 0x21, 0xf1, 0x10, 0x02, 2, 0, 0, 0, 4, 0, 0]);
    assert_eq!(mailbox_error(&r), Some(0x0008), "{r:02x?}");
    // Nothing of these was written: 0x10F1:02 is still the drive's 0.
    let r = d.coe(&[0x00, 0x20, 0x40, 0xf1, 0x10, 0x02, 0, 0, 0, 0]);
    assert_eq!(&r[8..12], &[0x4b, 0xf1, 0x10, 0x02]);
    assert_eq!(&r[12..14], &[0, 0]);
}

/// What SSC never answers with an error: a channel other than 0 (0x03 in ETG.1000.4's table,
/// but SSC's `MBX_MailboxWriteInd` does not look at the channel), a counter that skips (0x01
/// only in SSC's TEST_APPLICATION), many messages in a row (0x07: SSC's queue out of memory).
/// A repeated counter is the repeat of a lost answer: not processed again (SSC: "a repeated
/// mailbox write request will be detected, if the counter is unequal zero and unchanged").
#[test]
fn what_ssc_serves_without_an_error_is_served() {
    let mut d = Drive::servo();
    let c = d.next_counter();
    let mut m = vec![10, 0, 0, 0, 0x05, 0x03 | (c << 4)];
    m.extend_from_slice(&UPLOAD_VENDOR);
    let r = d.send_raw(&m).unwrap();
    assert_eq!(r[8], 0x43, "channel 5 served: {r:02x?}");
    // The counter jumps from c to c + 2.
    d.next_counter();
    let r = d.coe(&UPLOAD_VENDOR);
    assert_eq!(r[8], 0x43, "counter skipped, served: {r:02x?}");
    // The same counter again: no answer.
    let c = d.counter;
    let mut m = vec![10, 0, 0, 0, 0, 0x03 | (c << 4)];
    m.extend_from_slice(&UPLOAD_VENDOR);
    assert_eq!(d.send_raw(&m), None, "a repeat is not answered twice");
    for k in 0..40 {
        let r = d.coe(&UPLOAD_VENDOR);
        assert_eq!(r[8], 0x43, "message {k}: {r:02x?}");
    }
}

/// CoE-level errors, from `sdoserv.c`: a command specifier no SDO service has (5, 6, 7) and a
/// segment with no transfer running get the abort 0x05040001 (ABORTIDX_COMMAND_SPECIFIER_
/// UNKNOWN); an SDO Information opcode that is no request (a response's, the error's, an
/// unknown one) gets an SDO Info error with 0x05040001; a description of an index below
/// 0x1000 gets 0x06010000 (SSC: "SDO Info access is only allowed for objects >= 0x1000");
/// a subindex the object lacks, 0x06090011.
#[test]
fn sdo_and_sdo_information_errors_are_the_references_aborts() {
    let mut d = Drive::servo();
    for cmd in [0xa0u8, 0xc0, 0xe0, 0x00, 0x60] {
        let mut m = UPLOAD_VENDOR;
        m[2] = cmd;
        let r = d.coe(&m);
        assert_eq!(
            sdo_abort(&r),
            Some(0x0504_0001),
            "command {cmd:#04x}: {r:02x?}"
        );
    }
    for op in [0x00u8, 0x02, 0x04, 0x06, 0x07, 0x08, 0x7f] {
        let r = d.coe(&[0x00, 0x80, op, 0x00, 0x00, 0x00, 0x01, 0x00]);
        assert_eq!(
            sdo_info_error(&r),
            Some(0x0504_0001),
            "opcode {op:#04x}: {r:02x?}"
        );
    }
    let r = d.coe(&[0x00, 0x80, 0x03, 0x00, 0x00, 0x00, 0x07, 0x00]);
    assert_eq!(sdo_info_error(&r), Some(0x0601_0000), "{r:02x?}");
    let r = d.coe(&[0x00, 0x80, 0x05, 0x00, 0x00, 0x00, 0x18, 0x10, 0x09, 0x00]);
    assert_eq!(sdo_info_error(&r), Some(0x0609_0011), "{r:02x?}");
    // And the drive serves on.
    assert_eq!(d.coe(&UPLOAD_VENDOR)[8], 0x43);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Any bytes in the mailbox: no panic, and the answer is none (a repeat), a mailbox error
    /// or a CoE message whose length fits SM1; the drive answers a good upload afterwards.
    #[test]
    fn any_mailbox_bytes_get_an_answer_that_fits_or_none(
        bytes in proptest::collection::vec(any::<u8>(), 0..128),
        length in prop_oneof![Just(None), (0u16..200).prop_map(Some)],
    ) {
        let mut d = Drive::servo();
        let mut m = bytes.clone();
        m.resize(6.max(m.len()), 0);
        if let Some(l) = length {
            m[..2].copy_from_slice(&l.to_le_bytes());
        }
        if let Some(r) = d.send_raw(&m) {
            let len = usize::from(u16::from_le_bytes([r[0], r[1]]));
            prop_assert!(len <= 122, "{r:02x?}");
            prop_assert!(matches!(r[5] & 0x0f, 0 | 3), "{r:02x?}");
        }
        // A counter the random message cannot have had.
        d.counter = (m[5] >> 4) % 7 + 1;
        let r = d.coe(&UPLOAD_VENDOR);
        prop_assert_eq!(r[8], 0x43);
    }
}
