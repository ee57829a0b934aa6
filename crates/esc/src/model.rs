//! What a virtual slave is: its ESC model (ports, delays, DC capability, memory sizes) and its
//! device description (identity, name, process data), from which the SII image is built.

/// Physical layer of a port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PortKind {
    /// Not implemented on this ESC.
    None,
    /// EBUS (LVDS between terminals): receive time stamps with 10 ns resolution.
    Ebus,
    /// MII with a 100BASE-TX PHY: receive time stamps with 40 ns resolution (25 MHz RX clock,
    /// datasheet section I, 18.14).
    Mii,
}

impl PortKind {
    /// Resolution of receive time stamps on this port, ns.
    pub const fn stamp_resolution_ns(self) -> u64 {
        match self {
            PortKind::Mii => 40,
            _ => 10,
        }
    }

    /// The 2-bit code in the port descriptor register 0x0007.
    pub const fn descriptor(self) -> u8 {
        match self {
            PortKind::None => 0b00,
            PortKind::Ebus => 0b10,
            PortKind::Mii => 0b11,
        }
    }

    /// The nibble in the SII general category's physical port field.
    pub const fn sii_nibble(self) -> u16 {
        match self {
            PortKind::None => 0,
            PortKind::Mii => 1,
            PortKind::Ebus => 3,
        }
    }
}

/// How much of the DC unit an ESC has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DcSupport {
    /// No DC registers at all (0x0900-0x09FF do not exist; accesses do not count).
    None,
    /// Receive time stamps (0x0900-0x090F) only, as junctions must have; no system time.
    ReceiveTimes,
    /// Full DC unit with 32-bit system time.
    Full32,
    /// Full DC unit with 64-bit system time.
    Full64,
}

impl DcSupport {
    /// Whether the ESC has a system time (can be a reference clock and be synchronised).
    pub const fn has_system_time(self) -> bool {
        matches!(self, DcSupport::Full32 | DcSupport::Full64)
    }

    /// Whether port receive times exist.
    pub const fn has_receive_times(self) -> bool {
        !matches!(self, DcSupport::None)
    }
}

/// An ESC model: the silicon and the board around it.
#[derive(Debug, Clone, PartialEq)]
pub struct EscModel {
    /// ESC type (0x0000), e.g. 0x11 for ET1100.
    pub esc_type: u8,
    /// Revision (0x0001).
    pub revision: u8,
    /// Build (0x0002).
    pub build: u16,
    /// FMMUs implemented.
    pub fmmu_count: u8,
    /// SyncManagers implemented.
    pub sm_count: u8,
    /// Process RAM in KiB (0x0006).
    pub ram_kib: u8,
    /// Physical layer per port.
    pub ports: [PortKind; 4],
    /// DC capability.
    pub dc: DcSupport,
    /// Forwarding delay tF: a frame's first bit from a port's receive stamp point to the next
    /// port's transmit, not through the processing unit, ns.
    pub forwarding_delay_ns: f64,
    /// Processing delay tP: the same through the processing unit (port 0 to the next port). The
    /// datasheet calls `tP - tF` tDiff and leaves it to the ESI; masters that ignore it (SOEM,
    /// ethercrab) are off by tDiff / 2 per hop.
    pub processing_delay_ns: f64,
    /// Transmit plus receive PHY delay added to each link leaving a port of this kind, ns
    /// (MII: the two PHYs of a 100BASE-TX hop; EBUS: LVDS drivers).
    pub link_phy_delay_ns: f64,
    /// How long the EEPROM interface stays busy for a read, us.
    pub sii_read_busy_us: f64,
}

impl EscModel {
    /// An ET1100-class ESC with MII ports 0 and 1 to 100BASE-TX PHYs, as in a servo drive with
    /// two RJ45 sockets. Delays: about 485 ns per direction per hop including both PHYs (measured
    /// EK1100 -> EK1914 over 100BASE-TX in ethercrab's captures), split into 180 ns through the
    /// ESC and 300 ns for the two PHYs; tDiff = 0 (not published for the ET1100).
    pub fn servo_mii() -> Self {
        EscModel {
            esc_type: 0x11,
            revision: 0,
            build: 0,
            fmmu_count: 8,
            sm_count: 8,
            ram_kib: 8,
            ports: [PortKind::Mii, PortKind::Mii, PortKind::None, PortKind::None],
            dc: DcSupport::Full64,
            forwarding_delay_ns: 180.0,
            processing_delay_ns: 180.0,
            link_phy_delay_ns: 300.0,
            sii_read_busy_us: 20.0,
        }
    }

    /// An ET1200-class EBUS terminal (ports 0 and 1), about 150 ns per hop each way.
    pub fn ebus_terminal(dc: DcSupport) -> Self {
        EscModel {
            esc_type: 0x12,
            revision: 0,
            build: 0,
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
            forwarding_delay_ns: 140.0,
            processing_delay_ns: 140.0,
            link_phy_delay_ns: 10.0,
            sii_read_busy_us: 20.0,
        }
    }

    /// An ET1100-class junction with four MII ports (star coupler), receive times only.
    pub fn junction_mii() -> Self {
        EscModel {
            esc_type: 0x11,
            revision: 0,
            build: 0,
            fmmu_count: 8,
            sm_count: 8,
            ram_kib: 8,
            ports: [PortKind::Mii; 4],
            dc: DcSupport::Full64,
            forwarding_delay_ns: 180.0,
            processing_delay_ns: 180.0,
            link_phy_delay_ns: 300.0,
            sii_read_busy_us: 20.0,
        }
    }

    /// The ESC features register 0x0008 for this model.
    pub fn features(&self) -> u16 {
        use ecsync_wire::register::features;
        // Byte-oriented FMMUs are reported as bit 0 = 1; enhanced link detection; separate FCS.
        let mut f =
            features::ENHANCED_LINK_EBUS | features::ENHANCED_LINK_MII | features::SEPARATE_FCS;
        f |= features::LOW_JITTER_EBUS;
        match self.dc {
            DcSupport::None | DcSupport::ReceiveTimes => {}
            DcSupport::Full32 => f |= features::DC | features::ENHANCED_DC_SYNC,
            DcSupport::Full64 => {
                f |= features::DC | features::DC_64BIT | features::ENHANCED_DC_SYNC
            }
        }
        f
    }

    /// The port descriptor register 0x0007.
    pub fn port_descriptor(&self) -> u8 {
        self.ports
            .iter()
            .enumerate()
            .fold(0, |acc, (p, k)| acc | (k.descriptor() << (2 * p)))
    }
}

/// One process data object entry in the device description.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PdoEntry {
    /// Object index.
    pub index: u16,
    /// Subindex.
    pub subindex: u8,
    /// Length in bits.
    pub bits: u8,
    /// Name.
    pub name: String,
}

/// The device behind the ESC: what its SII EEPROM says.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// Vendor ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Revision.
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
    /// Device name (at most 64 bytes: ethercrab refuses longer strings).
    pub name: String,
    /// Configured station alias (SII word 4).
    pub alias: u16,
    /// Outputs (RxPDO, master to slave) entries.
    pub outputs: Vec<PdoEntry>,
    /// Inputs (TxPDO, slave to master) entries.
    pub inputs: Vec<PdoEntry>,
}

impl DeviceInfo {
    /// Bytes of outputs.
    pub fn output_bytes(&self) -> usize {
        self.outputs
            .iter()
            .map(|e| usize::from(e.bits))
            .sum::<usize>()
            .div_ceil(8)
    }

    /// Bytes of inputs.
    pub fn input_bytes(&self) -> usize {
        self.inputs
            .iter()
            .map(|e| usize::from(e.bits))
            .sum::<usize>()
            .div_ceil(8)
    }

    /// A CiA 402 servo drive in cyclic synchronous position mode with 16 bytes of outputs and 18
    /// bytes of inputs (34 bytes per drive; six drives exchange the letter's 204 bytes).
    pub fn servo_drive(serial: u32) -> Self {
        let e = |index: u16, subindex: u8, bits: u8, name: &str| PdoEntry {
            index,
            subindex,
            bits,
            name: name.to_string(),
        };
        DeviceInfo {
            vendor_id: 0x0000_0e5c,
            product_code: 0x0000_4024,
            revision: 0x0001_0000,
            serial,
            name: "ecsync virtual servo drive".to_string(),
            alias: 0,
            outputs: vec![
                e(0x6040, 0, 16, "Controlword"),
                e(0x6060, 0, 8, "Modes of operation"),
                e(0x0000, 0, 8, "Padding"),
                e(0x607a, 0, 32, "Target position"),
                e(0x60ff, 0, 32, "Target velocity"),
                e(0x6071, 0, 16, "Target torque"),
                e(0x60b8, 0, 16, "Touch probe function"),
            ],
            inputs: vec![
                e(0x6041, 0, 16, "Statusword"),
                e(0x6061, 0, 8, "Modes of operation display"),
                e(0x0000, 0, 8, "Padding"),
                e(0x6064, 0, 32, "Position actual value"),
                e(0x606c, 0, 32, "Velocity actual value"),
                e(0x6077, 0, 16, "Torque actual value"),
                e(0x60f4, 0, 32, "Following error actual value"),
            ],
        }
    }

    /// A device without process data (a junction or coupler).
    pub fn coupler(name: &str, serial: u32) -> Self {
        DeviceInfo {
            vendor_id: 0x0000_0e5c,
            product_code: 0x0000_1100,
            revision: 0x0001_0000,
            serial,
            name: name.to_string(),
            alias: 0,
            outputs: vec![],
            inputs: vec![],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn servo_drive_exchanges_34_bytes() {
        let d = DeviceInfo::servo_drive(1);
        assert_eq!(d.output_bytes(), 16);
        assert_eq!(d.input_bytes(), 18);
    }

    #[test]
    fn register_values() {
        let m = EscModel::servo_mii();
        assert_eq!(m.port_descriptor(), 0b0000_1111);
        assert_eq!(
            m.features() & 0x010c,
            0x010c,
            "DC, 64 bit, enhanced SYNC activation"
        );
        assert_eq!(
            EscModel::ebus_terminal(DcSupport::None).features() & 0x0004,
            0
        );
    }
}
