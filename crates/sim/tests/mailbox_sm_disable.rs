//! Issue 31: the mailbox counters start again when the master switches SM0 or SM1 off, not
//! only on the way to INIT: ETG's slave stack calls `MBX_StopMailboxHandler` when a mailbox
//! SyncManager is disabled too. A master that disables and enables the mailbox SyncManagers
//! between two sessions (without INIT) and starts its counter again at 1 is answered, not
//! dropped as a repeat.

mod common;

use common::MbxDrive as Drive;

/// An expedited upload of 0x1018:01 (the vendor ID).
const UPLOAD_VENDOR: [u8; 10] = [0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0];

/// One SDO with counter 1, as a new session's first message; its answer if any.
fn first_sdo(d: &mut Drive) -> Option<Vec<u8>> {
    d.counter = 0;
    d.send(3, &UPLOAD_VENDOR)
}

/// A drive that answered one SDO with counter 1 (the last counter it saw: 1).
fn after_one_session() -> Drive {
    let mut d = Drive::servo();
    let r = first_sdo(&mut d).expect("the first session's SDO");
    assert_eq!(&r[12..14], &[0x5c, 0x0e], "the vendor ID");
    d
}

#[test]
fn without_a_stop_the_same_counter_is_a_repeat() {
    // The control: the SyncManagers left as they are, counter 1 again is dropped.
    let mut d = after_one_session();
    assert_eq!(first_sdo(&mut d), None);
}

#[test]
fn sm0_disabled_by_its_activate_bit_resets_the_counters() {
    let mut d = after_one_session();
    // 0x0806 (SM0 activate) bit 0 cleared, then set again.
    assert_eq!(d.put(0x0806, &[0x00]), 1);
    assert_eq!(d.put(0x0806, &[0x01]), 1);
    let r = first_sdo(&mut d).expect("answered after SM0 was switched off");
    assert_eq!(&r[12..14], &[0x5c, 0x0e]);
    assert_eq!(r[5] >> 4, 1, "the slave's own counter starts again at 1");
}

#[test]
fn sm1_disabled_by_its_activate_bit_resets_the_counters() {
    let mut d = after_one_session();
    assert_eq!(d.put(0x080e, &[0x00]), 1);
    assert_eq!(d.put(0x080e, &[0x01]), 1);
    let r = first_sdo(&mut d).expect("answered after SM1 was switched off");
    assert_eq!(r[5] >> 4, 1);
}

#[test]
fn sm0_out_of_mailbox_mode_resets_the_counters() {
    let mut d = after_one_session();
    // SM0's control byte 0x0804: 0x26 (mailbox, written by the master) to 0x24 (buffered)
    // and back.
    assert_eq!(d.put(0x0804, &[0x24]), 1);
    assert_eq!(d.put(0x0804, &[0x26]), 1);
    assert!(first_sdo(&mut d).is_some());
}

#[test]
fn rewriting_the_mailbox_sync_managers_unchanged_keeps_the_counters() {
    // SM1's repeat request (0x080E bit 1) and a write of the same configuration leave both
    // SyncManagers enabled: the mailbox runs on, and a repeat is still a repeat.
    let mut d = after_one_session();
    assert_eq!(d.put(0x0806, &[0x01]), 1);
    assert_eq!(first_sdo(&mut d), None);
}
