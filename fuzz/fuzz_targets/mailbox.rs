//! Any bytes as a mailbox message: the header, the CoE header, an SDO request and an SDO
//! Information request are read without a panic, whatever they hold.
#![no_main]

use ecsync_wire::mailbox::coe::{Coe, CoeService, Sdo, sdo_info_request};
use ecsync_wire::mailbox::{Mailbox, MailboxType};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(m) = Mailbox::new_checked(data) else {
        return;
    };
    let _ = (m.address(), m.channel(), m.priority(), m.counter());
    if m.mailbox_type() != Ok(MailboxType::Coe) {
        return;
    }
    let Ok(c) = Coe::new_checked(m.payload()) else {
        return;
    };
    let _ = c.number();
    match c.service() {
        Ok(CoeService::SdoRequest | CoeService::SdoResponse) => {
            if let Ok(s) = Sdo::new_checked(c.payload()) {
                let _ = (s.request(), s.index(), s.subindex(), s.data4(), s.rest().len());
                let _ = s.segment_data().len();
            }
        }
        Ok(CoeService::SdoInformation) => {
            let _ = sdo_info_request(c.payload());
        }
        _ => {}
    }
});
