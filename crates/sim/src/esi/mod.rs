//! Devices from ESI files: the vendor's EtherCATInfo XML (ETG.2000, "EtherCAT Slave
//! Information Specification") as a device description.
//!
//! What is read, per `Descriptions/Devices/Device`:
//! - the identity: `Vendor/Id`, `Type@ProductCode`, `Type@RevisionNo`, the `Type` text (the
//!   name a network file selects the device by) and `Name`;
//! - the SyncManagers (`Sm`: `StartAddress`, `DefaultSize`, `ControlByte`, `Enable`, the text
//!   MBoxOut / MBoxIn / Outputs / Inputs), the FMMU usage (`Fmmu`), the mailbox protocols
//!   (`Mailbox/AoE|EoE|CoE|FoE|SoE|VoE`) and CoE's details (`CoE@SdoInfo`, `PdoAssign`, ...);
//! - the PDOs (`RxPdo`/`TxPdo`: `Index`, `Name`, `Entry` with `Index`, `SubIndex`, `BitLen`,
//!   `Name`, `DataType`; `@Sm` assigns the PDO to that SyncManager by default, `@Fixed`,
//!   `@Mandatory`);
//! - the DC operation modes (`Dc/OpMode`: `Name`, `Desc`, `AssignActivate`, `CycleTimeSync0`
//!   with its `Factor`, `ShiftTimeSync0`);
//! - the EEPROM (`Eeprom`: `ByteSize`, `ConfigData`, SII words 0-6 or 0-7, bytes in EEPROM
//!   order);
//! - the object dictionary (`Profile/Dictionary`): `DataTypes` (base types, records with their
//!   `SubItem`s, arrays with `ArrayInfo`, enums and aliases with a `BaseType`) and `Objects`
//!   (`Index`, `Name`, `Type`, `BitSize`, `Info/DefaultData` as hex bytes, little-endian as
//!   ETG.2000 writes them, or `Info/DefaultValue` as a number; the `Info/SubItem`s of a record
//!   or array; `Flags/Access` ro/rw/wo with `WriteRestrictions`, `Flags/PdoMapping` R/T).
//!
//! Numbers are written `#x1A00` (hex) or decimal (ETG.2000's HexDecValue). Errors name the
//! file, the line and the element (its path from the root); no input makes the parser panic.
//!
//! ```
//! let xml = r##"<EtherCATInfo><Vendor><Id>#x0E5C</Id></Vendor><Descriptions><Devices>
//!   <Device><Type ProductCode="#x10" RevisionNo="1">demo</Type><Name>Demo</Name></Device>
//!   </Devices></Descriptions></EtherCATInfo>"##;
//! let esi = ecsync_sim::esi::parse("demo.xml", xml).unwrap();
//! let dev = esi.devices[0].device_info(7);
//! assert_eq!((dev.vendor_id, dev.product_code, dev.serial), (0x0e5c, 0x10, 7));
//!
//! let e = ecsync_sim::esi::parse("bad.xml", "<EtherCATInfo>\n<Vendor>").unwrap_err();
//! assert_eq!(e.line, Some(2));
//! ```

use crate::coe::{Access, Entry, Object, ObjectCode, ObjectDictionary, data_type};
use crate::model::{
    DcOpMode, DeviceInfo, MailboxLayout, PdoDescription, PdoEntry, SiiContents, SmDescription,
};
use ecsync_wire::sii::sm_type;
use std::fmt;
use std::path::Path;
use std::sync::Arc;

mod doc;
mod types;
mod values;

use doc::Doc;

pub use values::{parse_hex, parse_int};

/// What kind of problem an ESI file has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EsiErrorKind {
    /// The file cannot be read.
    Io,
    /// Not well-formed XML.
    Xml,
    /// Well-formed, but not an EtherCATInfo file (another root element, no device).
    Schema,
    /// An element or attribute the description needs is missing.
    Missing,
    /// A value that is not what the element holds (a bad number, hex string or flag).
    BadValue,
}

/// An ESI file that cannot be used: where (file, line, element) and what.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct EsiError {
    /// The file, as given.
    pub file: String,
    /// 1-based line, if known.
    pub line: Option<usize>,
    /// The element, as its path from the root (`EtherCATInfo/Vendor/Id`), an attribute as
    /// `...@Name`.
    pub element: String,
    /// What kind of problem.
    pub kind: EsiErrorKind,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for EsiError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(l) => write!(f, "{}:{}: ", self.file, l)?,
            None => write!(f, "{}: ", self.file)?,
        }
        if self.element.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(f, "<{}>: {}", self.element, self.message)
        }
    }
}

/// A parsed ESI file: its vendor and its devices.
#[derive(Debug, Clone, PartialEq)]
pub struct EsiFile {
    /// The file, as given.
    pub file: String,
    /// `Vendor/Id`.
    pub vendor_id: u32,
    /// `Vendor/Name`.
    pub vendor_name: String,
    /// The devices, in file order.
    pub devices: Vec<EsiDevice>,
}

impl EsiFile {
    /// The device whose `Type` text is `type_name`.
    pub fn device(&self, type_name: &str) -> Option<&EsiDevice> {
        self.devices.iter().find(|d| d.type_name == type_name)
    }

    /// The `Type` texts of the devices, in file order.
    pub fn device_names(&self) -> Vec<&str> {
        self.devices.iter().map(|d| d.type_name.as_str()).collect()
    }
}

/// What a SyncManager of an ESI is for (the `Sm` element's text).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SmKind {
    /// `MBoxOut`: master to slave mailbox.
    MailboxOut,
    /// `MBoxIn`: slave to master mailbox.
    MailboxIn,
    /// `Outputs`: the RxPDOs.
    Outputs,
    /// `Inputs`: the TxPDOs.
    Inputs,
    /// Anything else (empty or unknown): not used.
    Unused,
}

impl SmKind {
    /// The SII SyncManager type.
    pub fn sii_type(self) -> u8 {
        match self {
            SmKind::MailboxOut => sm_type::MAILBOX_OUT,
            SmKind::MailboxIn => sm_type::MAILBOX_IN,
            SmKind::Outputs => sm_type::OUTPUTS,
            SmKind::Inputs => sm_type::INPUTS,
            SmKind::Unused => sm_type::UNUSED,
        }
    }
}

/// One `Sm` element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EsiSm {
    /// What it is for.
    pub kind: SmKind,
    /// `StartAddress`.
    pub start: u16,
    /// `DefaultSize`, bytes (0 if absent).
    pub default_size: u16,
    /// `ControlByte`.
    pub control: u8,
    /// `Enable`.
    pub enable: bool,
}

/// The `Mailbox/CoE` element's details.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CoeDetails {
    /// `SdoInfo`.
    pub sdo_info: bool,
    /// `PdoAssign`.
    pub pdo_assign: bool,
    /// `PdoConfig`.
    pub pdo_config: bool,
    /// `PdoUpload`.
    pub pdo_upload: bool,
    /// `CompleteAccess`.
    pub complete_access: bool,
}

impl CoeDetails {
    /// The SII general category's CoE details byte (ETG.2010 table 6): bit 0 SDO, 1 SDO
    /// Information, 2 PDO assignment, 3 PDO configuration, 4 PDO upload, 5 complete access.
    pub fn sii_byte(self) -> u8 {
        1 | (u8::from(self.sdo_info) << 1)
            | (u8::from(self.pdo_assign) << 2)
            | (u8::from(self.pdo_config) << 3)
            | (u8::from(self.pdo_upload) << 4)
            | (u8::from(self.complete_access) << 5)
    }
}

/// The SII mailbox protocol word's bits (ETG.1000.6 table 18), by the ESI's element names.
pub const MAILBOX_PROTOCOLS: [(&str, u16); 6] = [
    ("AoE", 0x0001),
    ("EoE", 0x0002),
    ("CoE", MAILBOX_COE),
    ("FoE", 0x0008),
    ("SoE", 0x0010),
    ("VoE", 0x0020),
];

/// CoE's bit in the mailbox protocol word.
pub const MAILBOX_COE: u16 = 0x0004;

/// One `Device` of an ESI file.
#[derive(Debug, Clone, PartialEq)]
pub struct EsiDevice {
    /// The file's `Vendor/Id`.
    pub vendor_id: u32,
    /// The `Type` text (e.g. `EVS-NET-01`).
    pub type_name: String,
    /// `Name` (the English one, `LcId` 1033, when there are several).
    pub name: String,
    /// `Type@ProductCode`.
    pub product_code: u32,
    /// `Type@RevisionNo`.
    pub revision: u32,
    /// `GroupType`.
    pub group: String,
    /// `Profile/ProfileNo`, if given.
    pub profile_no: Option<u32>,
    /// The SyncManagers, in order (SM0 first).
    pub sync_managers: Vec<EsiSm>,
    /// FMMU usage, one SII byte per `Fmmu`: 1 outputs, 2 inputs, 3 mailbox state, 0 unused.
    pub fmmus: Vec<u8>,
    /// The protocols under `Mailbox` (SII word 0x1C bits, [`MAILBOX_PROTOCOLS`]).
    pub mailbox_protocols: u16,
    /// `Mailbox/CoE`, if present.
    pub coe: Option<CoeDetails>,
    /// The RxPDOs.
    pub rx_pdos: Vec<PdoDescription>,
    /// The TxPDOs.
    pub tx_pdos: Vec<PdoDescription>,
    /// `Dc/OpMode`s.
    pub dc_opmodes: Vec<DcOpMode>,
    /// `Eeprom/ByteSize`, bytes, if given.
    pub eeprom_bytes: Option<usize>,
    /// `Eeprom/ConfigData` as SII words 0-6 (a word 7 given is dropped: the checksum is
    /// computed), if given.
    pub config_words: Option<[u16; 7]>,
    /// The dictionary's objects, with the ESI's defaults, as written (no completion).
    pub objects: Vec<Object>,
    /// 1-based line of the `Device` element.
    pub line: usize,
}

/// EEPROM size when the ESI gives none: 2 KiB, as [`crate::sii_image::EEPROM_BYTES`].
const DEFAULT_EEPROM_BYTES: usize = crate::sii_image::EEPROM_BYTES;
/// The largest EEPROM accepted, bytes: 64 KiB (512 Kbit; the SII size word 0x3E counts
/// Kbit - 1 in 16 bits, but real ESCs' EEPROMs stop at 4 Mbit and ESIs at 32 KiB).
const MAX_EEPROM_BYTES: usize = 65_536;
/// The smallest: the 64 words of the fixed area before the categories.
const MIN_EEPROM_BYTES: usize = 128;

impl EsiDevice {
    /// The indices of the PDOs of `pdos` assigned by default (those with an `Sm` attribute).
    fn assigned(&self, pdos: &[PdoDescription]) -> Vec<u16> {
        pdos.iter()
            .filter(|p| p.sm.is_some())
            .map(|p| p.index)
            .collect()
    }

    /// The entries of the default-assigned PDOs, in order.
    fn assigned_entries(pdos: &[PdoDescription]) -> Vec<PdoEntry> {
        pdos.iter()
            .filter(|p| p.sm.is_some())
            .flat_map(|p| p.entries.iter().cloned())
            .collect()
    }

    /// The mailbox layout: SM `MBoxOut` and `MBoxIn` with their default sizes, answered in the
    /// standard mailbox's time.
    pub fn mailbox_layout(&self) -> Option<MailboxLayout> {
        let out = self
            .sync_managers
            .iter()
            .find(|s| s.kind == SmKind::MailboxOut)?;
        let inp = self
            .sync_managers
            .iter()
            .find(|s| s.kind == SmKind::MailboxIn)?;
        Some(MailboxLayout {
            out_start: out.start,
            out_len: out.default_size,
            in_start: inp.start,
            in_len: inp.default_size,
            response_ns: MailboxLayout::STANDARD.response_ns,
        })
    }

    /// The dictionary the device serves: the ESI's objects; a mapping object (0x1600.., 0x1A00..)
    /// for each PDO the dictionary lacks, from the PDO's entries; and the assignment objects
    /// 0x1C12/0x1C13 set to the default assignment, the PDOs with an `Sm` attribute (ETG.2000:
    /// `RxPdo@Sm` is the default assignment). The ESI's DefaultData for 0x1C12/0x1C13 are
    /// replaced because generators write them independently of the PDO elements: Ingenia's
    /// EVS-NET-01 gives 0x1C12:00 = 0 beside `RxPdo Sm="2"` 0x1600, which would leave the drive
    /// without process data while its SII and SyncManagers give it 11 bytes each way. The
    /// communication objects the ESC needs and the ESI lacks are added when the SDO server is
    /// made ([`ObjectDictionary::completed_for`]).
    pub fn dictionary(&self) -> ObjectDictionary {
        let mut objects = self.objects.clone();
        let ro = Access::ReadOnly;
        let rw = Access::ReadWritePreOp;
        let u8_entry = |sub: u8, name: &str, access: Access, v: u8| Entry {
            subindex: sub,
            name: name.to_string(),
            data_type: data_type::UINT8,
            bits: 8,
            access,
            value: vec![v],
            pdo_mapping: 0,
        };
        for p in self.rx_pdos.iter().chain(&self.tx_pdos) {
            if objects.iter().any(|o| o.index == p.index) {
                continue;
            }
            let access = if p.fixed { ro } else { rw };
            // A mapping has at most 255 entries (subindices 1-255).
            let n = p.entries.len().min(255);
            let mut entries = vec![u8_entry(0, "SubIndex 000", access, n as u8)];
            for (k, e) in p.entries.iter().take(n).enumerate() {
                let v =
                    (u32::from(e.index) << 16) | (u32::from(e.subindex) << 8) | u32::from(e.bits);
                entries.push(Entry {
                    subindex: (k + 1) as u8,
                    name: format!("SubIndex {:03}", k + 1),
                    data_type: data_type::UINT32,
                    bits: 32,
                    access,
                    value: v.to_le_bytes().to_vec(),
                    pdo_mapping: 0,
                });
            }
            objects.push(Object {
                index: p.index,
                name: p.name.clone(),
                code: ObjectCode::Record,
                entries,
            });
        }
        for (index, name, mut assigned) in [
            (0x1c12u16, "RxPDO assign", self.assigned(&self.rx_pdos)),
            (0x1c13, "TxPDO assign", self.assigned(&self.tx_pdos)),
        ] {
            assigned.truncate(255);
            let pos = match objects.iter().position(|o| o.index == index) {
                Some(p) => p,
                None => {
                    objects.push(Object {
                        index,
                        name: name.to_string(),
                        code: ObjectCode::Array,
                        entries: vec![u8_entry(0, "SubIndex 000", rw, 0)],
                    });
                    objects.len() - 1
                }
            };
            let o = &mut objects[pos];
            let access = o.entries.first().map_or(rw, |e| e.access);
            for (k, pdo) in assigned.iter().enumerate() {
                let sub = (k + 1) as u8;
                let v = pdo.to_le_bytes().to_vec();
                match o.entries.iter_mut().find(|e| e.subindex == sub) {
                    Some(e) => {
                        e.value = v;
                        e.bits = 16;
                    }
                    None => o.entries.push(Entry {
                        subindex: sub,
                        name: format!("SubIndex {sub:03}"),
                        data_type: data_type::UINT16,
                        bits: 16,
                        access,
                        value: v,
                        pdo_mapping: 0,
                    }),
                }
            }
            // Elements past the assignment read 0, as an unassigned PDO slot does.
            for e in o
                .entries
                .iter_mut()
                .filter(|e| usize::from(e.subindex) > assigned.len())
            {
                e.value.fill(0);
            }
            o.entries.sort_by_key(|e| e.subindex);
            if let Some(e0) = o.entries.iter_mut().find(|e| e.subindex == 0) {
                e0.value = vec![assigned.len() as u8];
                e0.bits = 8;
            }
        }
        ObjectDictionary::from_objects(objects)
    }

    /// The device as the segment runs it, with serial number `serial`: identity and name, the
    /// default-assigned PDOs' entries as outputs and inputs, the mailbox layout, the dictionary
    /// with the ESI's defaults, the DC operation modes, and the SII's contents (ConfigData
    /// words, SyncManagers, FMMUs, every PDO, CoE). The SII advertises, of the ESI's mailbox
    /// protocols, CoE only: it is the one the virtual device serves, and a master reading EoE
    /// or FoE there would try them.
    pub fn device_info(&self, serial: u32) -> DeviceInfo {
        let mailbox = self.mailbox_layout();
        let sii = SiiContents {
            config_words: self.config_words,
            eeprom_bytes: self.eeprom_bytes.unwrap_or(DEFAULT_EEPROM_BYTES),
            mailbox_protocols: if mailbox.is_some() {
                self.mailbox_protocols & MAILBOX_COE
            } else {
                0
            },
            coe_details: self.coe.map_or(0, CoeDetails::sii_byte),
            group: truncated(&self.group, MAX_SII_STRING_BYTES).to_string(),
            order: truncated(&self.type_name, MAX_SII_STRING_BYTES).to_string(),
            fmmus: self.fmmus.clone(),
            sync_managers: self
                .sync_managers
                .iter()
                .map(|s| SmDescription {
                    start: s.start,
                    default_len: s.default_size,
                    control: s.control,
                    enable: s.enable,
                    sm_type: s.kind.sii_type(),
                })
                .collect(),
            rx_pdos: self.rx_pdos.clone(),
            tx_pdos: self.tx_pdos.clone(),
        };
        DeviceInfo {
            vendor_id: self.vendor_id,
            product_code: self.product_code,
            revision: self.revision,
            serial,
            name: truncated(&self.name, MAX_SII_STRING_BYTES).to_string(),
            alias: self.config_words.map_or(0, |w| w[4]),
            outputs: Self::assigned_entries(&self.rx_pdos),
            inputs: Self::assigned_entries(&self.tx_pdos),
            mailbox,
            dictionary: Some(Arc::new(self.dictionary())),
            dc_opmodes: self.dc_opmodes.clone(),
            sii: Some(Arc::new(sii)),
            pll_limit_ns: 0,
            oversampling: 0,
        }
    }
}

/// The longest name the SII gets, bytes: ethercrab reads the SII's strings into 64-byte strings
/// and refuses a device with a longer one (see [`DeviceInfo::name`]).
const MAX_SII_STRING_BYTES: usize = 64;

/// `s` cut to at most `max` bytes, at a character boundary.
fn truncated(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

/// Reads and parses the ESI file at `path`.
pub fn load(path: &Path) -> Result<EsiFile, EsiError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| EsiError {
        file: file.clone(),
        line: None,
        element: String::new(),
        kind: EsiErrorKind::Io,
        message: format!("cannot read the file: {e}"),
    })?;
    parse_bytes(&file, &bytes)
}

/// Parses an ESI file's bytes: UTF-8, or ISO-8859-1 when the XML declaration says so (many
/// vendors' ESIs are written in it).
pub fn parse_bytes(file: &str, bytes: &[u8]) -> Result<EsiFile, EsiError> {
    match std::str::from_utf8(bytes) {
        Ok(text) => parse(file, text),
        Err(e) => {
            let head = String::from_utf8_lossy(&bytes[..bytes.len().min(200)]).to_ascii_lowercase();
            if head.contains("iso-8859-1") || head.contains("latin1") {
                let text: String = bytes.iter().map(|&b| char::from(b)).collect();
                parse(file, &text)
            } else {
                let at = e.valid_up_to();
                Err(EsiError {
                    file: file.to_string(),
                    line: Some(bytes[..at].iter().filter(|&&b| b == b'\n').count() + 1),
                    element: String::new(),
                    kind: EsiErrorKind::Xml,
                    message: "the file is not UTF-8 (nor declared ISO-8859-1)".into(),
                })
            }
        }
    }
}

/// Parses the text of an ESI file named `file`.
pub fn parse(file: &str, text: &str) -> Result<EsiFile, EsiError> {
    // A byte order mark (Windows tools write one) is not part of the document; it holds no
    // newline, so the lines stay those of the file.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let doc = Doc::parse(file, text)?;
    doc.ethercat_info()
}

#[cfg(test)]
mod tests;
