//! Real devices as the captures of real hardware show them (`../shared/captures/`, recorded by
//! the ethercrab project on a Beckhoff EK1100 coupler with an EL2828 and an EL2889 digital
//! output terminal): their ESC (type, 0x0008, ports, FMMUs, SyncManagers, DC), their identity
//! and the layout of their SII, each value read from a capture (the frame or register named
//! beside it). What the captures do not show (the delays through the ESCs, the strings past the
//! order number, SII words 0-7) is the model's, and said so.
//!
//! The network of the captures, `presets/ek1100-el2828-el2889.toml`, is built from these.

use crate::model::{
    DcSupport, DeviceInfo, EscModel, PdoDescription, PdoEntry, SiiContents, SmDescription,
};
use ecsync_wire::sii::sm_type;
use std::sync::Arc;

/// Beckhoff's vendor ID (SII word 0x08 of all three devices).
pub const BECKHOFF: u32 = 0x0000_0002;
/// The EK1100's product code and revision (SII words 0x0A-0x0D, replay-dc.pcapng).
pub const EK1100_PRODUCT: (u32, u32) = (0x044c_2c52, 0x0012_0000);
/// The EL2828's product code and revision (SII words 0x0A-0x0D, replay-dc.pcapng).
pub const EL2828_PRODUCT: (u32, u32) = (0x0b0c_3052, 0x0011_0000);
/// The EL2889's product code and revision (SII words 0x0A-0x0D, replay-dc.pcapng).
pub const EL2889_PRODUCT: (u32, u32) = (0x0b49_3052, 0x0011_0000);

/// The digital output register (ESC datasheet section II, 0x0F00-0x0F03), where the terminals'
/// output SyncManagers sit (their SII's SyncManager category, and ethercrab's FPWR 0x0800 =
/// `00 0f 01 00 44 00 01 00` in replay-dc.pcapng, frame 2381).
pub const DIGITAL_OUTPUTS: u16 = 0x0f00;
/// The output SyncManagers' control byte in the terminals' SII: buffered, EtherCAT writes,
/// watchdog trigger (0x44).
const SM_CONTROL_OUTPUTS: u8 = 0x44;
/// SII size of Beckhoff terminals, bytes: 16 Kbit, as the EK1100's dump
/// (../shared/captures/ek1100-eeprom-dump.bin) holds.
const EEPROM_BYTES: usize = 2048;
/// The CiA data type code of BOOL, the terminals' output entries' (SII RxPDO category).
const BOOL: u16 = 0x0001;

/// The EK1100's ESC: an ET1100 coupler ([`EscModel::et1100_coupler`]: its registers, ports,
/// delays, SII timing and device emulation from the captures). As the captures show it: 8 FMMUs
/// and 8 SyncManagers (BWR 0x0630 and 0x0838 count at it alone, replay-issue-255.pcapng frames
/// 12 and 52), a 64-bit system time (0x0008 = 0x00FC, BWR 0x0910 counts there), port 0 MII
/// (X1, towards the master), port 1 EBUS (the terminals), port 2 MII (X2; port descriptor 0x3B
/// in soem-sdinfo-ek1100-el1004.pcapng, the SII's physical ports 0x0131), port 3 absent.
pub fn ek1100_model() -> EscModel {
    EscModel::et1100_coupler()
}

/// The EL2828's ESC: an ET1200 terminal ([`EscModel::et1200_terminal`]) that latches receive
/// times but keeps no system time (0x0910, 0x0918, 0x0920, 0x092C and 0x0981 never count there
/// in replay-dc.pcapng and replay-issue-255.pcapng) and reads 0x0008 = 0x01FC all the same.
pub fn el2828_model() -> EscModel {
    EscModel::et1200_terminal(DcSupport::ReceiveTimes)
}

/// The EL2889's ESC: an ET1200 terminal with a 64-bit system time (BWR 0x0910 counts 2, at the
/// EK1100 and here) whose 0x0008 reads 0x00FC, without enhanced DC SYNC activation
/// (replay-dc.pcapng, replay-ek1100-alias-address.pcapng: FPRD 0x0008 of station 0x1002).
pub fn el2889_model() -> EscModel {
    EscModel {
        enhanced_dc_sync: false,
        ..EscModel::et1200_terminal(DcSupport::Full64)
    }
}

/// The EK1100 EtherCAT coupler: no process data, no mailbox (SII words 0x18-0x1B are 0).
pub fn ek1100(serial: u32) -> DeviceInfo {
    let mut d = DeviceInfo::coupler("EK1100", serial);
    (d.vendor_id, d.product_code, d.revision) = (BECKHOFF, EK1100_PRODUCT.0, EK1100_PRODUCT.1);
    d
}

/// The EL2828, 8 digital outputs: 8 RxPDOs 0x1600-0x1607 of one BOOL each (0x7000:01 ...
/// 0x7070:01), all on SM0 at 0x0F00 (1 byte), fixed and mandatory (the SII's RxPDO and
/// SyncManager categories as read in replay-dc.pcapng).
pub fn el2828(serial: u32) -> DeviceInfo {
    digital_outputs("EL2828", EL2828_PRODUCT, serial, 1)
}

/// The EL2889, 16 digital outputs: 16 RxPDOs 0x1600-0x160F of one BOOL each, the first eight
/// on SM0 at 0x0F00, the others on SM1 at 0x0F01, one byte each (its SII as read in
/// replay-dc.pcapng; ethercrab maps them with two FMMUs, frames 3013 and 3019).
pub fn el2889(serial: u32) -> DeviceInfo {
    digital_outputs("EL2889", EL2889_PRODUCT, serial, 2)
}

/// A Beckhoff digital output terminal with `bytes` output SyncManagers of 8 channels each at
/// 0x0F00, 0x0F01, ... The SII's FMMU category reads `01 ff` (one FMMU for outputs) on both
/// terminals, though the EL2889 needs two. The names of the PDOs and entries are not read in
/// the captures; "Channel n" and "Output" are Beckhoff's usual ones.
fn digital_outputs(
    name: &str,
    (product, revision): (u32, u32),
    serial: u32,
    bytes: u8,
) -> DeviceInfo {
    let channels = 8 * u16::from(bytes);
    let rx_pdos: Vec<PdoDescription> = (0..channels)
        .map(|i| PdoDescription {
            index: 0x1600 + i,
            name: format!("Channel {}", i + 1),
            sm: Some((i / 8) as u8),
            fixed: true,
            mandatory: true,
            entries: vec![PdoEntry {
                index: 0x7000 + 0x10 * i,
                subindex: 1,
                bits: 1,
                name: "Output".to_string(),
            }],
            entry_data_types: vec![BOOL],
        })
        .collect();
    let sii = SiiContents {
        config_words: None,
        eeprom_bytes: EEPROM_BYTES,
        mailbox_protocols: 0,
        coe_details: 0,
        group: String::new(),
        order: name.to_string(),
        fmmus: vec![0x01, 0xff],
        sync_managers: (0..bytes)
            .map(|k| SmDescription {
                start: DIGITAL_OUTPUTS + u16::from(k),
                default_len: 1,
                control: SM_CONTROL_OUTPUTS,
                enable: true,
                sm_type: sm_type::OUTPUTS,
            })
            .collect(),
        rx_pdos: rx_pdos.clone(),
        tx_pdos: Vec::new(),
    };
    let mut d = DeviceInfo::coupler(name, serial);
    (d.vendor_id, d.product_code, d.revision) = (BECKHOFF, product, revision);
    d.outputs = rx_pdos.iter().flat_map(|p| p.entries.clone()).collect();
    d.sii = Some(Arc::new(sii));
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecsync_wire::sii;

    /// The terminals' SII images say what the real ones say about their process data: the
    /// SyncManagers at 0x0F00 (one byte each), type outputs, control 0x44; 8 RxPDOs per
    /// SyncManager.
    #[test]
    fn terminal_sii_describes_the_outputs_at_0x0f00() {
        for (dev, sms) in [(el2828(1), 1usize), (el2889(1), 2)] {
            let model = EscModel::ebus_terminal(DcSupport::Full64);
            let img = crate::sii_image::build(&model, &dev);
            let smcat = sii::find_category(&img, sii::category::SYNC_MANAGER)
                .expect("a SyncManager category")
                .data;
            assert_eq!(smcat.len(), 8 * sms, "{}", dev.name);
            for (k, e) in smcat.chunks_exact(8).enumerate() {
                assert_eq!(
                    (
                        u16::from_le_bytes([e[0], e[1]]),
                        u16::from_le_bytes([e[2], e[3]])
                    ),
                    (0x0f00 + k as u16, 1),
                    "{} SM{k}",
                    dev.name
                );
                assert_eq!((e[4], e[7]), (0x44, sm_type::OUTPUTS));
            }
            assert_eq!(dev.output_bytes(), sms);
        }
    }
}
