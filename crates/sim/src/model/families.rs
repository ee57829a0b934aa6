//! Device families: ESC models shaped like the silicon real devices are built on, each value
//! taken from a capture of real hardware in `../shared/captures/` (frame numbers as Wireshark
//! numbers them; the folder's README.md lists what each capture holds), a datasheet section, or
//! issue 32 where it reports a capture not kept there. The calibrated constructors
//! ([`EscModel::servo_mii`] and the others) stay as they were; these are new models.
//!
//! Times in the SOEM captures (soem-*.pcapng) are the master's: each frame is stamped when sent
//! and about 0.56 ms later when it came back, so a time between two events at the device is
//! bracketed by the send times of the last frame that did not see it and the first that did.

use super::{
    AlBehaviour, AlFirmware, DcSupport, ESC_TYPE_AKD, ESC_TYPE_ET1100, ESC_TYPE_ET1200,
    ESC_TYPE_LAN9252, EscModel, PortKind,
};
use ecsync_wire::register::sii_control;

/// How long a Beckhoff SII EEPROM stays busy for an 8-byte read, us. The polls of 0x0502 in
/// replay-dc.pcapng (EK1100, EL2828, EL2889: 478 of 722 polls after a read command saw busy),
/// soem-sdinfo-ek1100-el1004.pcapng and replay-ek1914-el3004-mailbox.pcapng saw busy up to
/// 596-720 us after the command and idle from 700-900 us on; 650 us gives every one of their
/// 1 211 polls its busy bit but two (of replay-dc's EL2828 and EK1100), as does any value in
/// 600-700 us.
pub const BECKHOFF_SII_READ_BUSY_US: f64 = 650.0;

/// 0x0502 of an ET1200 terminal when idle: 8-byte reads and bit 4 (see
/// [`EscModel::et1200_terminal`]).
pub const ET1200_SII_CONTROL_IDLE: u16 = 0x0050;

/// EBUS loop through an ET1200 terminal to the last one and back: 310 ns, the EL2828's port 1
/// minus port 0 receive time after the 0x0900 latch with an EL2889 behind it (replay-dc.pcapng
/// frame 510; the same 310 ns in replay-ek1100-el2828-el2889.pcapng, replay-issue-255.pcapng,
/// replay-ek1100-alias-address.pcapng, and for the EK1914's loop through an EL3004 in
/// replay-ek1914-el3004-mailbox.pcapng frame 362). Two processing delays and two EBUS links:
/// `2 * (ET1200_DELAY_NS + EBUS_LINK_NS)`.
pub const ET1200_LOOP_NS: f64 = 310.0;
/// EBUS link delay (LVDS drivers and receivers), ns: the calibrated EBUS terminal's, kept.
pub const EBUS_LINK_NS: f64 = 10.0;
/// Processing (= forwarding) delay of an ET1200 between EBUS ports, ns:
/// `ET1200_LOOP_NS / 2 - EBUS_LINK_NS`.
pub const ET1200_DELAY_NS: f64 = ET1200_LOOP_NS / 2.0 - EBUS_LINK_NS;
/// The EK1100's loop through an EL2828 and an EL2889, ns: its port 1 minus port 0 receive time,
/// 600 ns in replay-dc.pcapng frame 506, 590 in replay-ek1100-el2828-el2889.pcapng frame 508,
/// 600 in replay-issue-255.pcapng and replay-ek1100-alias-address.pcapng (580-601 over the
/// captures, ../shared/captures/README.md); 597.5 the mean of the four.
pub const EK1100_LOOP_NS: f64 = 597.5;
/// How much longer an ET1100 coupler's loop reads than it is, on average, ns: its port 0 (MII)
/// stamps on a 40 ns grid, 20 ns early on average; its port 1 (EBUS) on a 10 ns grid, 5 ns
/// early (datasheet section I, receive time stamps; `crate::dc_unit`'s latch does the same).
pub const ET1100_COUPLER_LOOP_READS_LONGER_NS: f64 = 20.0 - 5.0;
/// Processing (= forwarding) delay of an ET1100 coupler from its MII port 0 to its EBUS port,
/// ns: the EK1100's loop as it reads, less the stamps' mean error, is its own delay, four EBUS
/// links and three ET1200 passes (in at the EL2828, the EL2889, back through the EL2828):
/// `EK1100_LOOP_NS - ET1100_COUPLER_LOOP_READS_LONGER_NS - 3 * ET1200_DELAY_NS -
/// 4 * EBUS_LINK_NS` = 107.5 ns (the calibrated junction's 180 ns made the loop read 650-670).
pub const ET1100_COUPLER_DELAY_NS: f64 = EK1100_LOOP_NS
    - ET1100_COUPLER_LOOP_READS_LONGER_NS
    - 3.0 * ET1200_DELAY_NS
    - 4.0 * EBUS_LINK_NS;

/// Round trip of one 100BASE-TX hop between two LAN9252 boards, ns: a SOEM capture of two
/// LAN9252s (../shared/captures/README.md; the capture itself is not kept there): the first
/// board's port 1 minus port 0 receive time with the second at the end of the line.
pub const LAN9252_HOP_ROUND_TRIP_NS: f64 = 1440.0;
/// The two PHYs of a 100BASE-TX link (the LAN9252's integrated PHYs), ns: assumed as for the
/// calibrated MII drive ([`EscModel::servo_mii`]); not measured apart from the ESC.
pub const LAN9252_LINK_PHY_NS: f64 = 300.0;
/// The cable the LAN9252 hop figure is taken to have had, m (5 ns/m).
pub const LAN9252_HOP_CABLE_M: f64 = 1.0;
/// Processing (= forwarding) delay of a LAN9252, ns: half the hop's round trip less one link
/// (its PHYs and 1 m of cable): `1440 / 2 - 300 - 5` = 415 ns.
pub const LAN9252_DELAY_NS: f64 =
    LAN9252_HOP_ROUND_TRIP_NS / 2.0 - LAN9252_LINK_PHY_NS - 5.0 * LAN9252_HOP_CABLE_M;

impl EscModel {
    /// An ET1100 coupler like the EK1100: MII port 0 to the master, EBUS port 1 to the
    /// terminals, MII port 2 (X2) onwards; device emulation; 64-bit DC.
    /// - 0x0000-0x0002: type 0x11, revision 0, build 3 (issue 32; consistent with the BRD of
    ///   0x0000 in soem-sdinfo-ek1100-el1004.pcapng frame 9, 0x13/0x01, the OR of the EK1100's
    ///   and the EL1004's).
    /// - 8 FMMUs, 8 SyncManagers, 8 KiB RAM: the ET1100's (datasheet section I, "ET1100 main
    ///   features"; the EK1914, an ET1100 coupler, reads 8 FMMUs).
    /// - 0x0007 = 0x3B: MII, EBUS, MII, none (soem-sdinfo-ek1100-el1004.pcapng frame 131).
    /// - 0x0140-0x0141 = 0x00, 0x0D: no PDI, device emulation, DC SYNC and latch units
    ///   (soem-sdinfo-ek1100-el1004.pcapng frame 37). Without a PDI its watchdog is never
    ///   reloaded: DL status reads 0x5A31 (frame 129), bit 1 clear.
    /// - AL: device emulation ([`AlBehaviour::DeviceEmulation`]).
    /// - SII: 8-byte reads (0x0502 = 0x0040, frame 47), busy [`BECKHOFF_SII_READ_BUSY_US`].
    /// - Delays: [`ET1100_COUPLER_DELAY_NS`] through it, EBUS links of [`EBUS_LINK_NS`] (the
    ///   model has one PHY delay per ESC: its MII links are modelled as short as its EBUS one).
    pub fn et1100_coupler() -> Self {
        EscModel {
            esc_type: ESC_TYPE_ET1100,
            revision: 0,
            build: 3,
            fmmu_count: 8,
            sm_count: 8,
            ram_kib: 8,
            ports: [PortKind::Mii, PortKind::Ebus, PortKind::Mii, PortKind::None],
            dc: DcSupport::Full64,
            forwarding_delay_ns: ET1100_COUPLER_DELAY_NS,
            processing_delay_ns: ET1100_COUPLER_DELAY_NS,
            link_phy_delay_ns: EBUS_LINK_NS,
            sii_read_busy_us: BECKHOFF_SII_READ_BUSY_US,
            sii_control_idle: sii_control::READ_SIZE_8,
            al: AlBehaviour::DeviceEmulation,
            mailbox_response_ns: None,
            pdi_control: Some(0x0d00),
            unconfigured_ports: 0,
            enhanced_dc_sync: false,
        }
    }

    /// An ET1200 EBUS terminal like the EL1004, EL2828 and EL2889: EBUS ports 0 and 1, port 3
    /// not configured; device emulation; DC as `dc` (the EL2889 has a 64-bit system time, the
    /// EL2828 and EL1004 receive times only).
    /// - 0x0000-0x0002: type 0x12, revision 1, build 1 (issue 32; see
    ///   [`EscModel::et1100_coupler`] for the BRD that agrees).
    /// - 3 FMMUs, 4 SyncManagers, 1 KiB RAM: the ET1200's (datasheet section I, "ET1200 main
    ///   features").
    /// - 0x0007 = 0x4A: EBUS, EBUS, none, not configured (the EL1004 in
    ///   soem-sdinfo-ek1100-el1004.pcapng frame 131's pair, FPRD of 0x1002).
    /// - 0x0140-0x0141 = 0x04, 0x01: digital I/O PDI, device emulation (the EL1004,
    ///   soem-sdinfo-ek1100-el1004.pcapng frame 53). DL status as the EL2828 (0x5A33) and
    ///   EL2889 (0x5613) read it in replay-dc.pcapng.
    /// - AL: device emulation. SII: 8-byte reads, busy [`BECKHOFF_SII_READ_BUSY_US`]; 0x0502
    ///   reads 0x0050 when idle, bit 4 (reserved in the datasheet) set as on the EL2828
    ///   (replay-dc.pcapng frame 224), the EL1004 (soem-sdinfo-ek1100-el1004.pcapng frame 63)
    ///   and the EL3004 (replay-ek1914-el3004-mailbox.pcapng); the EL2889 reads 0x0040.
    /// - Delays: [`ET1200_DELAY_NS`] through it, EBUS links of [`EBUS_LINK_NS`].
    pub fn et1200_terminal(dc: DcSupport) -> Self {
        EscModel {
            esc_type: ESC_TYPE_ET1200,
            revision: 1,
            build: 1,
            fmmu_count: 3,
            sm_count: 4,
            ram_kib: 1,
            ports: [
                PortKind::Ebus,
                PortKind::Ebus,
                PortKind::None,
                PortKind::None,
            ],
            dc,
            forwarding_delay_ns: ET1200_DELAY_NS,
            processing_delay_ns: ET1200_DELAY_NS,
            link_phy_delay_ns: EBUS_LINK_NS,
            sii_read_busy_us: BECKHOFF_SII_READ_BUSY_US,
            sii_control_idle: ET1200_SII_CONTROL_IDLE,
            al: AlBehaviour::DeviceEmulation,
            mailbox_response_ns: None,
            pdi_control: Some(0x0104),
            unconfigured_ports: 1 << 3,
            enhanced_dc_sync: true,
        }
    }

    /// A Microchip LAN9252 board (soem-single-lan9252.pcapng: the evaluation board with its
    /// microcontroller on the HBI): two MII ports with integrated 100BASE-TX PHYs, port 2 not
    /// configured; 64-bit DC; a firmware runs AL and the mailbox.
    /// - 0x0000-0x0001: type 0xC0, revision 0x02 (frame 8, BRD of 0x0000 on a segment of one).
    /// - 3 FMMUs, 4 SyncManagers, 4 KiB DPRAM (LAN9252 data sheet DS00001909, "Highlights").
    /// - 0x0007 = 0x1F (frame 96): MII, MII, not configured, none.
    /// - 0x0008 = 0x01CC (frame 92, [`super::FEATURES_LAN9252`]).
    /// - 0x0140-0x0141 = 0x89, 0x0E (frame 36): device emulation off, enhanced link detection
    ///   (DL status 0x5617, frame 94, bit 2 set).
    /// - AL: a firmware taking a write 17.5 ms after it, with the AL control handshake: INIT ->
    ///   PRE-OP (frames 275-296) and PRE-OP -> SAFE-OP (frames 965-996) each showed in AL status
    ///   16.5-18.5 ms after the write; the second and third writes of 0x0120, 0.59 and 7.5 ms
    ///   after the first (frames 5 and 29), were refused with working counter 0.
    /// - SII: 4-byte reads (0x0502 = 0x0080: bit 6 clear, two address bytes; frame 46), never
    ///   seen busy at the first poll 0.56 ms after a command; 190 us assumed, the I2C read of
    ///   4 bytes with two address bytes at 400 kHz (75 bit times of 2.5 us).
    /// - Mailbox: answered 38.3 ms after the request (SM1 full first seen 38.66-38.70 ms after
    ///   the write to SM0, last seen empty 37.90-37.94 ms after it; the six requests of the
    ///   capture).
    /// - Delays: [`LAN9252_DELAY_NS`] through it, [`LAN9252_LINK_PHY_NS`] per link.
    pub fn lan9252() -> Self {
        EscModel {
            esc_type: ESC_TYPE_LAN9252,
            revision: 0x02,
            build: 0,
            fmmu_count: 3,
            sm_count: 4,
            ram_kib: 4,
            ports: [PortKind::Mii, PortKind::Mii, PortKind::None, PortKind::None],
            dc: DcSupport::Full64,
            forwarding_delay_ns: LAN9252_DELAY_NS,
            processing_delay_ns: LAN9252_DELAY_NS,
            link_phy_delay_ns: LAN9252_LINK_PHY_NS,
            sii_read_busy_us: 190.0,
            sii_control_idle: 0x0080,
            al: AlBehaviour::Firmware(AlFirmware {
                response_ns: 17_500_000,
                control_handshake: true,
            }),
            mailbox_response_ns: Some(38_300_000),
            pdi_control: Some(0x0e89),
            unconfigured_ports: 1 << 2,
            enhanced_dc_sync: true,
        }
    }

    /// A microcontroller servo drive like the Kollmorgen AKD (soem-sdinfo-akd.pcapng): two MII
    /// ports, 32-bit DC, a firmware that runs AL, emulates the SII EEPROM and answers the
    /// mailbox.
    /// - 0x0000-0x0002: type 0x04, revision 0x02 (frame 8, BRD of 0x0000 on a segment of one),
    ///   build 0x43 (issue 32, from a capture not kept in ../shared).
    /// - 3 FMMUs, 4 SyncManagers, 4 KiB RAM (issue 32, point 8).
    /// - 0x0007 = 0x0F (frame 96), 0x0008 = 0x0184 (frame 92), DL status 0x5613 (frame 94).
    /// - 0x0140-0x0141 = 0x08, 0x0C (frame 36): device emulation off.
    /// - AL: a firmware taking a write 4.5 ms after it, with the AL control handshake: the
    ///   second write of 0x0120, 0.56 ms after the first, was refused (frame 6, working counter
    ///   0) and the third, 7.35 ms after it, taken (frame 30); INIT -> PRE-OP showed 4.17-6.20
    ///   ms after the write (frames 267-290), the refusal of SAFE-OP (0x12, code 0x001D) within
    ///   4.85 ms (frames 743-746): 4.5 ms fits all three.
    /// - SII: 4-byte reads from an emulated EEPROM (0x0502 = 0x0020: bit 5 emulation, bit 6
    ///   clear; frame 46), never seen busy at the first poll 0.56 ms after a command (20 us
    ///   assumed); 0x050C-0x050F read zeros (issue 32, point 5).
    /// - Mailbox: answered 1.2 ms after the request (of its 35 requests, 19 were answered within
    ///   0.56-1.32 ms, 13 within 1.32-2.08, 3 within 2.08-2.86: the median lies near 1.3 ms).
    /// - Delays: the calibrated MII drive's ([`EscModel::servo_mii`]): one drive, no hop
    ///   measured.
    pub fn akd_drive() -> Self {
        EscModel {
            esc_type: ESC_TYPE_AKD,
            revision: 0x02,
            build: 0x43,
            fmmu_count: 3,
            sm_count: 4,
            ram_kib: 4,
            ports: [PortKind::Mii, PortKind::Mii, PortKind::None, PortKind::None],
            dc: DcSupport::Full32,
            forwarding_delay_ns: 180.0,
            processing_delay_ns: 180.0,
            link_phy_delay_ns: 300.0,
            sii_read_busy_us: 20.0,
            sii_control_idle: 0x0020,
            al: AlBehaviour::Firmware(AlFirmware {
                response_ns: 4_500_000,
                control_handshake: true,
            }),
            mailbox_response_ns: Some(1_200_000),
            pdi_control: Some(0x0c08),
            unconfigured_ports: 0,
            enhanced_dc_sync: true,
        }
    }

    /// Bytes an SII read delivers into 0x0508: 8 when 0x0502 bit 6 says so, else 4.
    pub fn sii_read_bytes(&self) -> usize {
        if self.sii_control_idle & sii_control::READ_SIZE_8 != 0 {
            8
        } else {
            4
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loops the captures show come out of the delays: the ET1200 loop, the EK1100's
    /// through two ET1200s, the LAN9252 hop, each summed from the parts by hand.
    #[test]
    fn delays_add_up_to_the_captured_loops() {
        let ek = EscModel::et1100_coupler();
        let el = EscModel::et1200_terminal(DcSupport::Full64);
        let link = (ek.link_phy_delay_ns + el.link_phy_delay_ns) / 2.0;
        assert_eq!(
            2.0 * el.processing_delay_ns + 2.0 * el.link_phy_delay_ns,
            310.0
        );
        let ek_loop = ek.processing_delay_ns
            + link
            + el.processing_delay_ns
            + 2.0 * el.link_phy_delay_ns
            + el.processing_delay_ns
            + el.forwarding_delay_ns
            + link;
        assert!((ek_loop - (597.5 - 15.0)).abs() < 1e-9, "{ek_loop}");
        let lan = EscModel::lan9252();
        let hop = lan.processing_delay_ns + lan.link_phy_delay_ns + 5.0;
        assert_eq!(2.0 * hop, 1440.0);
    }

    /// The port descriptors the real devices read (0x0007).
    #[test]
    fn port_descriptors_are_the_devices() {
        assert_eq!(EscModel::et1100_coupler().port_descriptor(), 0x3b);
        assert_eq!(
            EscModel::et1200_terminal(DcSupport::ReceiveTimes).port_descriptor(),
            0x4a
        );
        assert_eq!(EscModel::lan9252().port_descriptor(), 0x1f);
        assert_eq!(EscModel::akd_drive().port_descriptor(), 0x0f);
    }

    #[test]
    fn read_sizes() {
        assert_eq!(EscModel::et1100_coupler().sii_read_bytes(), 8);
        assert_eq!(EscModel::lan9252().sii_read_bytes(), 4);
        assert_eq!(EscModel::akd_drive().sii_read_bytes(), 4);
        assert_eq!(EscModel::servo_mii().sii_read_bytes(), 8);
    }
}
