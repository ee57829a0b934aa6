//! Issue 31, point 1: a master session after INIT starts its mailbox counters anew. ETG's slave
//! stack resets its write and read counters when the mailbox stops on the way to INIT
//! (`MBX_StopMailboxHandler`); a slave that kept the last counter dropped a new session's
//! first message as a repeat whenever the two counters met (one-SDO SOEM sessions back to back:
//! ok, timeout, ok, ...).

mod common;

use common::MbxDrive as Drive;

/// An expedited upload of 0x1018:01 (the vendor ID).
const UPLOAD_VENDOR: [u8; 10] = [0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0];

/// The drive back to PRE-OP through INIT, as a new master session brings it: INIT, the
/// mailbox SyncManagers written again, PRE-OP; the master's counter starts again too.
fn new_session(d: &mut Drive) {
    d.put(0x0120, &[0x01, 0x00]);
    assert_eq!(d.get(0x0130, 2).1, [0x01, 0x00], "INIT");
    d.mailbox_to_preop();
    d.counter = 0;
}

#[test]
fn a_new_session_with_the_last_sessions_counter_is_answered() {
    let mut d = Drive::servo();
    // Session 1: one SDO with counter 1.
    let r = d.coe(&UPLOAD_VENDOR);
    assert_eq!(&r[12..14], &[0x5c, 0x0e], "the vendor ID");
    // Within a session the same counter again is a repeat: not served a second time.
    d.counter = 0;
    assert_eq!(
        d.send(3, &UPLOAD_VENDOR),
        None,
        "a repeat within the session"
    );
    // Sessions 2 to 8, each one SDO with counter 1 after INIT: every one answered.
    for k in 2..=8 {
        new_session(&mut d);
        let r = d
            .send(3, &UPLOAD_VENDOR)
            .unwrap_or_else(|| panic!("session {k}: the first SDO was dropped"));
        assert_eq!(&r[12..14], &[0x5c, 0x0e], "session {k}");
        // The slave's own counter starts again as well: its first answer counts 1.
        assert_eq!(r[5] >> 4, 1, "session {k}: the slave's counter");
    }
}
