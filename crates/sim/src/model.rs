//! What a virtual slave is: its ESC model (ports, delays, DC capability, memory sizes) and its
//! device description (identity, name, process data), from which the SII image is built.

pub mod families;

/// Physical start of the output SyncManager (SM0) buffer of a device without a mailbox.
pub const SM_OUTPUT_START: u16 = 0x1000;
/// Physical start of the input SyncManager (SM1) buffer of a device without a mailbox.
pub const SM_INPUT_START: u16 = 0x1100;

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

/// ESC type (0x0000) of the ET1100.
pub const ESC_TYPE_ET1100: u8 = 0x11;
/// ESC type (0x0000) of the ET1200.
pub const ESC_TYPE_ET1200: u8 = 0x12;
/// ESC type (0x0000) the Kollmorgen AKD reports (soem-sdinfo-akd.pcapng, BRD of 0x0000).
pub const ESC_TYPE_AKD: u8 = 0x04;
/// 0x0008 as ET1100-based devices show it (EK1100, EK1914 in ../shared/captures/).
pub const FEATURES_ET1100: u16 = 0x00fc;
/// 0x0008 as ET1200 terminals show it (EL2828, EL3004, EL1004 in ../shared/captures/).
pub const FEATURES_ET1200: u16 = 0x01fc;
/// 0x0008 as the Kollmorgen AKD shows it (soem-sdinfo-akd.pcapng): 32-bit DC.
pub const FEATURES_AKD: u16 = 0x0184;
/// ESC type (0x0000) of the Microchip LAN9252 (soem-single-lan9252.pcapng, frame 8: BRD of
/// 0x0000 on a segment of one LAN9252 reads 0xC0, revision 0x02).
pub const ESC_TYPE_LAN9252: u8 = 0xc0;
/// 0x0008 as the LAN9252 shows it (soem-single-lan9252.pcapng, frame 92: FPRD of 0x0008 =
/// 0x01CC): DC with 64-bit system time, enhanced link detection MII, enhanced DC SYNC
/// activation; no EBUS bits (it has no EBUS).
pub const FEATURES_LAN9252: u16 = 0x01cc;

/// How the AL state machine is run: by the ESC itself (device emulation) or by a firmware on
/// a microcontroller behind the PDI (ESC datasheet section II, 0x0140 bit 8 "Device
/// emulation" and 0x0120 "AL Control").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlBehaviour {
    /// Device emulation (0x0140 bit 8 set, no application processor): the ESC copies AL
    /// control into AL status within the frame, the acknowledge bit included, and checks
    /// nothing (section II, 0x0120). The EK1100, EL1004, EL2828 and EL2889 do so: written
    /// 0x11, AL status reads 0x11 (soem-sdinfo-ek1100-el1004.pcapng frames 4-9 and
    /// replay-dc.pcapng); written 0x12, 0x12.
    DeviceEmulation,
    /// A firmware reads AL control, checks the request and writes AL status and the AL status
    /// code (the acknowledge bit is not shown: written 0x11, a LAN9252 and an AKD read 0x01).
    Firmware(AlFirmware),
}

/// A firmware's AL handling (see [`AlBehaviour::Firmware`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AlFirmware {
    /// Time from an AL control write until the firmware has read it and AL status shows the
    /// outcome, ns. 0: within the frame (the models calibrated before the device families).
    pub response_ns: u64,
    /// AL control is a mailbox (device emulation off, section II, 0x0120: "The PDI has to read
    /// the AL Control register after ECAT has written it. Otherwise ECAT can not write again
    /// to the AL Control register"): a write before the firmware has read the previous one is
    /// not taken and does not count (working counter 0).
    pub control_handshake: bool,
}

impl AlFirmware {
    /// The application answers within the frame: what every model did before the device
    /// families, kept by the calibrated constructors.
    pub const INSTANT: AlFirmware = AlFirmware {
        response_ns: 0,
        control_handshake: false,
    };
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
    /// 0x0008 bit 8, enhanced DC SYNC activation: set on the ET1200 terminals and the AKD the
    /// captures show, clear on ET1100s and on the EL2889 (see [`EscModel::features`]).
    pub enhanced_dc_sync: bool,
    /// SII control/status 0x0502-0x0503 when idle: the static bits, of which bit 6 says how
    /// many bytes a read delivers (set: 8 into 0x0508-0x050F; clear: 4 into 0x0508-0x050B),
    /// bit 5 EEPROM emulation by the PDI, bit 7 two address bytes (section II, 0x0502).
    pub sii_control_idle: u16,
    /// Who runs the AL state machine, and how fast.
    pub al: AlBehaviour,
    /// The time the application takes to answer a mailbox message, ns, over the device's
    /// ([`MailboxLayout::response_ns`]); `None`: the device's.
    pub mailbox_response_ns: Option<u64>,
    /// SII word 0 (PDI control, loaded into 0x0140-0x0141 at power-up): PDI type in the low
    /// byte, ESC configuration in the high byte (bit 8: device emulation). `None`: the SII
    /// image's default ([`crate::sii_image::build`]: 0x0005, SPI, with the DC units).
    pub pdi_control: Option<u16>,
    /// Ports (bit p: port p) that do not exist but read "not configured" (0b01) in the port
    /// descriptor 0x0007 rather than "not implemented" (0b00), as an unused port of a real ESC
    /// configured by its SII does.
    pub unconfigured_ports: u8,
}

impl EscModel {
    /// What every model was before the device families, kept byte for byte by the calibrated
    /// constructors ([`EscModel::servo_mii`], [`EscModel::ebus_terminal`],
    /// [`EscModel::junction_mii`]; the presets paper-2024, twelve-drives and tsn-2020 are built
    /// on them): 8-byte SII reads (0x0502 = 0x0040), AL handled within the frame, the device's
    /// mailbox response time, the SII image's PDI control, unused ports "not implemented".
    /// Its other fields are [`EscModel::servo_mii`]'s.
    const CALIBRATED_DEFAULTS: EscModel = EscModel {
        esc_type: ESC_TYPE_ET1100,
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
        sii_control_idle: ecsync_wire::register::sii_control::READ_SIZE_8,
        al: AlBehaviour::Firmware(AlFirmware::INSTANT),
        mailbox_response_ns: None,
        pdi_control: None,
        unconfigured_ports: 0,
        enhanced_dc_sync: false,
    };

    /// An ET1100-class ESC with MII ports 0 and 1 to 100BASE-TX PHYs, as in a servo drive with
    /// two RJ45 sockets. Delays, assumed: about 485 ns per direction per hop, 180 ns through the
    /// ESC plus 300 ns for the two PHYs of the 100BASE-TX link plus 5 ns/m of cable; tDiff = 0
    /// (not published for the ET1100). No capture at hand measures an MII hop between two such
    /// ESCs. The one measured MII hop available, LAN9252 to LAN9252 over 100BASE-TX (a SOEM
    /// capture, ../shared/captures/README.md), shows about 1440 ns round trip, ~720 ns per
    /// direction: real hops may be up to ~235 ns longer per direction than this model's, and
    /// SYNC0 margins computed on it shrink by that much per hop. The numbers are kept so that
    /// every calibrated figure stays the same.
    pub fn servo_mii() -> Self {
        EscModel {
            esc_type: ESC_TYPE_ET1100,
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
            enhanced_dc_sync: false,
            ..Self::CALIBRATED_DEFAULTS
        }
    }

    /// A servo drive whose ESC has a 32-bit DC unit, as the Kollmorgen AKD in
    /// ../shared/captures/soem-sdinfo-akd.pcapng: ESC type 0x04, revision 0x02 (its BRD of
    /// 0x0000), features 0x0184 (DC without the 64-bit bit). Its system time, 0x0910 and every
    /// DC time register wrap every 2^32 ns (4.295 s), so masters' 32-bit wrap handling is
    /// exercised. Ports and delays as [`EscModel::servo_mii`] (two MII ports to 100BASE-TX PHYs;
    /// the capture has a single drive, so no hop delay is measured).
    pub fn servo_mii_dc32() -> Self {
        EscModel {
            esc_type: ESC_TYPE_AKD,
            revision: 0x02,
            dc: DcSupport::Full32,
            enhanced_dc_sync: true,
            ..Self::servo_mii()
        }
    }

    /// An ET1200-class EBUS terminal (ports 0 and 1), about 150 ns per hop each way; 0x0008
    /// as ET1200 terminals read it (0x01FC with DC, see [`EscModel::features`]).
    pub fn ebus_terminal(dc: DcSupport) -> Self {
        EscModel {
            esc_type: ESC_TYPE_ET1200,
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
            enhanced_dc_sync: true,
            ..Self::CALIBRATED_DEFAULTS
        }
    }

    /// An ET1100-class junction with four MII ports (star coupler), with the ET1100's 64-bit DC
    /// unit (0x0008 = 0x00FC as on the EK1100).
    pub fn junction_mii() -> Self {
        EscModel {
            esc_type: ESC_TYPE_ET1100,
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
            enhanced_dc_sync: false,
            ..Self::CALIBRATED_DEFAULTS
        }
    }

    /// The ESC features register 0x0008 for this model: the value real chips of its ESC type
    /// show (read from the captures of real devices in ../shared/captures/), with bit 8 from
    /// [`EscModel::enhanced_dc_sync`] and the DC bits following the model's [`DcSupport`]:
    /// - ET1100 (type 0x11): 0x00FC, read from the EK1100 (replay-dc.pcapng,
    ///   soem-sdinfo-ek1100-el1004.pcapng) and the EK1914 (replay-ek1914-el3004-mailbox.pcapng;
    ///   both have 8 FMMUs, so ET1100s): FMMU bit 0 clear (bit oriented), DC, 64-bit DC, low
    ///   jitter EBUS, enhanced link detection EBUS and MII, separate FCS error handling; no
    ///   enhanced DC SYNC activation (bit 8). Models: servo-mii, junction-mii.
    /// - ET1200 (type 0x12): 0x01FC, read from the EL2828 (replay-dc.pcapng), EL3004
    ///   (replay-ek1914-el3004-mailbox.pcapng) and EL1004 (soem-sdinfo-ek1100-el1004.pcapng):
    ///   the ET1100's bits plus enhanced DC SYNC activation. Model: ebus-terminal. Not every
    ///   ET1200 device shows bit 8: the EL2889 (replay-dc.pcapng,
    ///   replay-ek1100-alias-address.pcapng) reads 0x00FC ([`crate::catalog::el2889_model`]).
    /// - The AKD's ESC (type 0x04): 0x0184, read from the Kollmorgen AKD
    ///   (soem-sdinfo-akd.pcapng): DC (32 bit), separate FCS error handling, enhanced DC SYNC
    ///   activation. Model: servo-mii-dc32.
    /// - The LAN9252 (type 0xC0): 0x01CC, read from soem-single-lan9252.pcapng
    ///   ([`FEATURES_LAN9252`]). Model: lan9252.
    /// - Any other type (a model built in code): the ET1100's value.
    ///
    /// DC (bit 2) and 64-bit DC (bit 3) mean "DC available" and "64-bit DC" as ETG.1000.4
    /// defines them, which real chips set whenever they latch receive times, system time or
    /// not: [`DcSupport::ReceiveTimes`] reads the class's DC bits as the EL2828, EL1004, EK1914
    /// and EL3004 do (0x01FC/0x00FC), though every access to 0x0910-0x0930 gets working counter
    /// 0 there (replay-dc.pcapng: the EL2828's 0x0910, 0x0918, 0x0920 and 0x092C do not count).
    /// A master learns whether a slave keeps a system time from whether a read of 0x0910
    /// counts, never from this register. [`DcSupport::Full32`] sets bit 2 without bit 3,
    /// [`DcSupport::Full64`] both; [`DcSupport::None`] clears both (ebus-terminal-no-dc reads
    /// 0x01F0: no real ET1200 lacks DC, the other bits are the ET1200's).
    pub fn features(&self) -> u16 {
        use ecsync_wire::register::features;
        let observed = match self.esc_type {
            ESC_TYPE_ET1200 => FEATURES_ET1200,
            ESC_TYPE_AKD => FEATURES_AKD,
            ESC_TYPE_LAN9252 => FEATURES_LAN9252,
            _ => FEATURES_ET1100,
        };
        let dc_bits = features::DC | features::DC_64BIT;
        let mut f = observed & !(dc_bits | features::ENHANCED_DC_SYNC);
        if self.enhanced_dc_sync {
            f |= features::ENHANCED_DC_SYNC;
        }
        match self.dc {
            DcSupport::None => {}
            DcSupport::ReceiveTimes => f |= observed & dc_bits,
            DcSupport::Full32 => f |= features::DC,
            DcSupport::Full64 => f |= dc_bits,
        }
        f
    }

    /// The port descriptor register 0x0007: each port's kind, 0b01 ("not configured") for the
    /// [`EscModel::unconfigured_ports`] that do not exist.
    pub fn port_descriptor(&self) -> u8 {
        self.ports.iter().enumerate().fold(0, |acc, (p, k)| {
            let unconfigured = *k == PortKind::None && self.unconfigured_ports & (1 << p) != 0;
            let code = if unconfigured { 0b01 } else { k.descriptor() };
            acc | (code << (2 * p))
        })
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

/// One PDO as a device description lists it (ETG.2000 `RxPdo`/`TxPdo`), for the SII's PDO
/// categories.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PdoDescription {
    /// The PDO's index (0x1600-0x17FF RxPDO, 0x1A00-0x1BFF TxPDO).
    pub index: u16,
    /// Name.
    pub name: String,
    /// The SyncManager it is assigned to by default (the ESI's `Sm` attribute); `None`: not
    /// assigned by default.
    pub sm: Option<u8>,
    /// Its content cannot be changed (`Fixed`).
    pub fixed: bool,
    /// It must be assigned (`Mandatory`).
    pub mandatory: bool,
    /// Its entries.
    pub entries: Vec<PdoEntry>,
    /// The CiA data type code of each entry (0 where the description gives none).
    pub entry_data_types: Vec<u16>,
}

/// One SyncManager as a device description lists it (ETG.2000 `Sm`), for the SII's
/// SyncManager category.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SmDescription {
    /// Physical start address.
    pub start: u16,
    /// Default length, bytes (`DefaultSize`).
    pub default_len: u16,
    /// Control byte (register 0x0804 of the SyncManager).
    pub control: u8,
    /// Enabled at start-up (`Enable`).
    pub enable: bool,
    /// The SII SyncManager type: 1 mailbox out, 2 mailbox in, 3 outputs, 4 inputs, 0 unused
    /// (`ecsync_wire::sii::sm_type`).
    pub sm_type: u8,
}

/// What a device's SII holds beyond its identity and mailbox words, when a device description
/// (an ESI file) gives it: `None` in [`DeviceInfo::sii`] for the built-in devices, whose SII
/// [`crate::sii_image::build`] derives from the other fields.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SiiContents {
    /// SII words 0-6 (ESI `Eeprom/ConfigData`): PDI control, PDI configuration, SYNC pulse
    /// length, extended PDI configuration, alias, reserved; word 7, the checksum, is computed.
    /// `None`: the built-in defaults.
    pub config_words: Option<[u16; 7]>,
    /// EEPROM size, bytes (ESI `Eeprom/ByteSize`).
    pub eeprom_bytes: usize,
    /// The mailbox protocol word 0x1C (bit 0 AoE, 1 EoE, 2 CoE, 3 FoE, 4 SoE, 5 VoE).
    pub mailbox_protocols: u16,
    /// The general category's CoE details (ETG.2010 table 6).
    pub coe_details: u8,
    /// The group's name (the general category's group string).
    pub group: String,
    /// The order number string (the ESI's device type name).
    pub order: String,
    /// FMMU usage, one byte per FMMU: 1 outputs, 2 inputs, 3 mailbox state, 0 unused.
    pub fmmus: Vec<u8>,
    /// The SyncManagers in order.
    pub sync_managers: Vec<SmDescription>,
    /// Every RxPDO the description lists, assigned by default or not.
    pub rx_pdos: Vec<PdoDescription>,
    /// Every TxPDO the description lists.
    pub tx_pdos: Vec<PdoDescription>,
}

/// A DC operation mode as an ESI lists it (ETG.2000 `Dc/OpMode`): what a master writes to the
/// DC activation register 0x0980 in this mode, and the SYNC0 timing it sets up.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DcOpMode {
    /// Name (e.g. `DC`, `FreeRun`).
    pub name: String,
    /// Description (`Desc`).
    pub description: String,
    /// `AssignActivate`: the value of 0x0980-0x0981 (0x0300: cyclic unit and SYNC0 active; 0:
    /// no DC).
    pub assign_activate: u16,
    /// `CycleTimeSync0`, ns; 0 with a factor: the bus cycle times the factor.
    pub cycle_time_sync0_ns: u32,
    /// `CycleTimeSync0@Factor`: SYNC0's cycle as a multiple of the bus cycle, if given.
    pub cycle_time_sync0_factor: Option<i32>,
    /// `ShiftTimeSync0`, ns (may be negative).
    pub shift_time_sync0_ns: i32,
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
    /// The mailbox (SM0 out, SM1 in) with CoE behind it, as real drives have: the process
    /// data then sits on SM2 and SM3. `None`: no mailbox, the process data on SM0 and SM1.
    pub mailbox: Option<MailboxLayout>,
    /// The object dictionary a device description gives, with its defaults (shared by the
    /// copies of the device; each ESC's SDO server works on its own copy). `None`:
    /// [`crate::coe::ObjectDictionary::for_device`] builds it from the fields above.
    pub dictionary: Option<std::sync::Arc<crate::coe::ObjectDictionary>>,
    /// The DC operation modes a device description lists (empty for the built-in devices).
    pub dc_opmodes: Vec<DcOpMode>,
    /// The SII's contents a device description gives; `None`: derived (see [`SiiContents`]).
    pub sii: Option<std::sync::Arc<SiiContents>>,
    /// The limit on |0x092C| past which the application's SYNC PLL loses lock and the drive
    /// leaves OP with AL status code 0x0032, ns; 0: none (a firmware setting, no object: see
    /// [`crate::esc::Esc::set_pll_error_limit_ns`]).
    pub pll_limit_ns: u32,
    /// Samples per cycle of an oversampling terminal (its outputs are that many samples a
    /// channel; it runs on SYNC1, a sample per SYNC0: see
    /// [`DeviceInfo::oversampling_terminal`]); 0: the device does not oversample.
    pub oversampling: u8,
}

/// Where a device's mailbox buffers are (the SII's standard mailbox words 0x18-0x1B).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MailboxLayout {
    /// SM0: master to slave, physical start.
    pub out_start: u16,
    /// SM0 length, bytes.
    pub out_len: u16,
    /// SM1: slave to master, physical start.
    pub in_start: u16,
    /// SM1 length, bytes.
    pub in_len: u16,
    /// The time the application takes to answer a mailbox message, ns.
    pub response_ns: u64,
}

impl MailboxLayout {
    /// 128-byte mailboxes at 0x1000 and 0x1080 (the layout of Beckhoff terminals and most
    /// drives), answered within 200 us.
    pub const STANDARD: MailboxLayout = MailboxLayout {
        out_start: 0x1000,
        out_len: 128,
        in_start: 0x1080,
        in_len: 128,
        response_ns: 200_000,
    };

    /// Where the process data goes behind it: outputs (SM2), inputs (SM3).
    pub fn process_data_starts(&self) -> (u16, u16) {
        let end = self
            .out_start
            .saturating_add(self.out_len)
            .max(self.in_start.saturating_add(self.in_len));
        let outputs = end.next_multiple_of(0x80);
        (outputs, outputs + 0x80)
    }
}

impl DeviceInfo {
    /// The physical starts of the output and input buffers (SM2/SM3 behind a mailbox, else
    /// SM0/SM1).
    pub fn process_data_starts(&self) -> (u16, u16) {
        // A description that places the process data SyncManagers (an ESI's Sm elements).
        let described = |kind: u8| {
            self.sii.as_ref().and_then(|c| {
                c.sync_managers
                    .iter()
                    .find(|s| s.sm_type == kind)
                    .map(|s| s.start)
            })
        };
        let derived = match &self.mailbox {
            Some(m) => m.process_data_starts(),
            None => (SM_OUTPUT_START, SM_INPUT_START),
        };
        (
            described(ecsync_wire::sii::sm_type::OUTPUTS).unwrap_or(derived.0),
            described(ecsync_wire::sii::sm_type::INPUTS).unwrap_or(derived.1),
        )
    }

    /// The same device with a standard mailbox and CoE (a real drive's layout).
    pub fn with_mailbox(mut self) -> Self {
        self.mailbox = Some(MailboxLayout::STANDARD);
        self
    }

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
    /// bytes of inputs (34 bytes per drive; six drives exchange the letter's 204 bytes), with a
    /// standard mailbox and CoE.
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
            // A drive has a mailbox with CoE, its process data on SM2/SM3.
            mailbox: Some(MailboxLayout::STANDARD),
            dictionary: None,
            dc_opmodes: Vec::new(),
            sii: None,
            pll_limit_ns: 0,
            oversampling: 0,
        }
    }

    /// An analog output terminal that oversamples, like Beckhoff's EL4732 (two channels,
    /// INT16, up to 100 samples per cycle): `samples` values a channel each cycle, taken as a
    /// block at SYNC1 and played one per SYNC0, so SYNC0 runs `samples` times per cycle and
    /// SYNC1 once (ethercrab #368: SYNC1 = SYNC0 x (samples - 1)). It has CoE, no inputs,
    /// and its 0x1C32:04 offers DC SYNC1 (0x1C32:01 = 3). Outputs sample `i` of channel 1 at
    /// 0x7000 + i, of channel 2 at 0x7100 + i (the real terminal assigns one PDO per sample
    /// of the same objects, 0x1600 onwards; one object a sample keeps the virtual
    /// dictionary's one-object-per-entry rule). ecsync's identity, not Beckhoff's: it is a
    /// model of the behaviour, not a twin of the terminal.
    pub fn oversampling_terminal(serial: u32, samples: u8) -> Self {
        let samples = samples.clamp(1, 100);
        let e = |index: u16, name: String| PdoEntry {
            index,
            subindex: 0,
            bits: 16,
            name,
        };
        let outputs = (0..u16::from(samples))
            .flat_map(|i| {
                [
                    e(0x7000 + i, format!("Ch1 sample {}", i + 1)),
                    e(0x7100 + i, format!("Ch2 sample {}", i + 1)),
                ]
            })
            .collect();
        DeviceInfo {
            vendor_id: 0x0000_0e5c,
            product_code: 0x0000_4732,
            revision: 0x0001_0000,
            serial,
            name: "ecsync virtual oversampling analog output".to_string(),
            alias: 0,
            outputs,
            inputs: vec![],
            mailbox: Some(MailboxLayout::STANDARD),
            dictionary: None,
            dc_opmodes: Vec::new(),
            sii: None,
            pll_limit_ns: 0,
            oversampling: samples,
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
            mailbox: None,
            dictionary: None,
            dc_opmodes: Vec::new(),
            sii: None,
            pll_limit_ns: 0,
            oversampling: 0,
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
    }

    /// 0x0008 per model against the values real chips of each class show
    /// (../shared/captures/README.md).
    #[test]
    fn features_are_those_of_real_chips() {
        use ecsync_wire::register::features as f;
        // ET1100 class (the EK1100 reads 0x00FC).
        assert_eq!(EscModel::servo_mii().features(), 0x00fc);
        assert_eq!(EscModel::junction_mii().features(), 0x00fc);
        // ET1200 terminals (EL2828, EL3004, EL1004 read 0x01FC).
        assert_eq!(
            EscModel::ebus_terminal(DcSupport::Full64).features(),
            0x01fc
        );
        // The AKD (32-bit DC) reads 0x0184: DC set, 64-bit DC clear.
        let akd = EscModel::servo_mii_dc32();
        assert_eq!(akd.features(), 0x0184);
        assert_eq!(akd.features() & (f::DC | f::DC_64BIT), f::DC);
        assert_eq!(akd.dc, DcSupport::Full32);
        assert_eq!((akd.esc_type, akd.revision), (0x04, 0x02));
        // Without DC at all the DC bits are clear, the rest is the class's.
        assert_eq!(EscModel::ebus_terminal(DcSupport::None).features(), 0x01f0);
        // Receive times only: the DC bits as the EL2828 reads them (0x01FC), the EK1914's
        // ET1100 (0x00FC).
        assert_eq!(
            EscModel::ebus_terminal(DcSupport::ReceiveTimes).features(),
            0x01fc
        );
        let mut et1100_rx = EscModel::junction_mii();
        et1100_rx.dc = DcSupport::ReceiveTimes;
        assert_eq!(et1100_rx.features(), 0x00fc);
        // The EL2889's ET1200: no enhanced DC SYNC activation (0x00FC).
        assert_eq!(crate::catalog::el2889_model().features(), 0x00fc);
        assert_eq!(crate::catalog::el2828_model().features(), 0x01fc);
        assert_eq!(crate::catalog::ek1100_model().features(), 0x00fc);
        let mut et1100_32 = EscModel::servo_mii();
        et1100_32.dc = DcSupport::Full32;
        assert_eq!(et1100_32.features(), 0x00f4);
        // Bit 0 clear on every model: FMMUs are bit oriented, as on every real ESC here.
        for m in [EscModel::servo_mii(), EscModel::servo_mii_dc32()] {
            assert_eq!(m.features() & f::FMMU_BYTE_ORIENTED, 0);
            assert_eq!(m.features() & (f::NO_LRW | f::NO_READ_WRITE), 0);
        }
    }
}
