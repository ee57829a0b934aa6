//! Any bytes through the wire views: no panic.
#![no_main]

use ecsync_wire::{EcatFrame, sii};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(f) = EcatFrame::new_checked(data) {
        for d in f.datagrams().flatten() {
            let _ = (d.command(), d.address(), d.data(), d.wkc(), d.more_follows());
        }
    }
    let _ = sii::identity(data);
    let _ = sii::checksum_ok(data);
    for c in sii::categories(data).flatten() {
        let _ = sii::string(c.data, c.data.first().copied().unwrap_or(1));
    }
});
