//! Any bytes through the gPTP decoder: no panic, and whatever decodes re-encodes to a message
//! that decodes the same.
#![no_main]

use ecsync_tsn::gptp_msg;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((h, m)) = gptp_msg::decode(data) {
        let mut buf = [0u8; 256];
        if let Ok(n) = m.encode(&h, &mut buf) {
            assert_eq!(gptp_msg::decode(&buf[..n]), Ok((h, m)));
        }
    }
});
