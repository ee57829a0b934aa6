//! Any bytes as a mailbox message: the header, the CoE header, an SDO request and an SDO
//! Information request are read without a panic; and the same bytes, cut into messages, go
//! through a virtual drive's mailbox (SM0 in, SM1 out) and its CoE server, transfers in
//! progress included, without a panic and always with an answer a real drive gives (a CoE
//! response, an abort or a mailbox error) or none.
#![no_main]

use ecsync_sim::Esc;
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DeviceInfo, EscModel};
use ecsync_wire::mailbox::coe::{Coe, CoeService, Sdo, sdo_info_request};
use ecsync_wire::mailbox::{Mailbox, MailboxType};
use libfuzzer_sys::fuzz_target;

/// A datagram by hand: command, index, address, data, working counter.
fn dg(cmd: u8, ado: u16, data: &[u8]) -> Vec<u8> {
    let mut v = vec![cmd, 0, 0, 0];
    v.extend_from_slice(&ado.to_le_bytes());
    v.extend_from_slice(&(data.len() as u16).to_le_bytes());
    v.extend_from_slice(&[0, 0]);
    v.extend_from_slice(data);
    v.extend_from_slice(&[0, 0]);
    v
}

fn parse(data: &[u8]) {
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
}

fuzz_target!(|data: &[u8]| {
    parse(data);
    let mut e = Esc::new(
        EscModel::servo_mii(),
        DeviceInfo::servo_drive(1),
        CrystalParams::default(),
    );
    e.set_links([true, false, false, false]);
    let mut t = 0u64;
    let run = |e: &mut Esc, cmd: u8, ado: u16, d: &[u8], t: u64| {
        let mut x = dg(cmd, ado, d);
        e.process_datagram(&mut x, t);
        x
    };
    // The mailbox set up as the SII says, PRE-OP.
    run(&mut e, 0x08, 0x0800, &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00], t);
    run(&mut e, 0x08, 0x0808, &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00], t);
    run(&mut e, 0x08, 0x0120, &[0x02, 0x00], t);
    // Each 128-byte piece of the input is one message (a short one padded), then the answer
    // read 1 ms later; every answer is a CoE message or a mailbox error.
    for chunk in data.chunks(128).take(16) {
        let mut msg = chunk.to_vec();
        msg.resize(128, 0);
        run(&mut e, 0x08, 0x1000, &msg, t);
        t += 1_000_000_000;
        let r = run(&mut e, 0x07, 0x1080, &[0u8; 128], t);
        let wkc = u16::from_le_bytes([r[r.len() - 2], r[r.len() - 1]]);
        if wkc == 1 {
            let m = Mailbox::new_checked(&r[10..138]).expect("an answer with a valid header");
            assert!(
                matches!(m.mailbox_type(), Ok(MailboxType::Coe | MailboxType::Error)),
                "answered with {:?}",
                m.mailbox_type()
            );
        }
        t += 1_000_000_000;
    }
});
