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
use quick_xml::XmlVersion;
use quick_xml::events::Event;
use std::collections::HashMap;
use std::fmt;
use std::path::Path;
use std::sync::Arc;

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

/// One element of the document.
#[derive(Debug)]
struct Node {
    name: String,
    attrs: Vec<(String, String)>,
    text: String,
    children: Vec<usize>,
    parent: Option<usize>,
    /// Byte offset of its `<`.
    offset: usize,
}

/// The document as a flat tree (no recursion, so no input nests deep enough to overflow the
/// stack, in parsing or in dropping).
struct Doc<'a> {
    file: &'a str,
    text: &'a str,
    nodes: Vec<Node>,
}

/// Deepest nesting accepted; ETG.2000 files nest about 12 deep.
const MAX_DEPTH: usize = 64;

impl<'a> Doc<'a> {
    fn parse(file: &'a str, text: &'a str) -> Result<Self, EsiError> {
        let mut reader = quick_xml::Reader::from_str(text);
        let mut doc = Doc {
            file,
            text,
            nodes: Vec::new(),
        };
        let mut stack: Vec<usize> = Vec::new();
        loop {
            let at = reader.buffer_position() as usize;
            let ev = match reader.read_event() {
                Ok(ev) => ev,
                Err(e) => {
                    let pos = reader.error_position() as usize;
                    return Err(doc.xml_error(&stack, pos, e.to_string()));
                }
            };
            match ev {
                Event::Start(s) => {
                    let id = doc.open(&s, &stack, at)?;
                    stack.push(id);
                }
                Event::Empty(s) => {
                    doc.open(&s, &stack, at)?;
                }
                Event::End(_) => {
                    stack.pop();
                }
                Event::Text(t) => {
                    let s = t
                        .xml10_content()
                        .map_err(|e| doc.xml_error(&stack, at, e.to_string()))?;
                    match stack.last() {
                        Some(&top) => doc.nodes[top].text.push_str(&s),
                        None if s.trim().is_empty() => {}
                        None => {
                            return Err(doc.xml_error(&stack, at, "text outside the root element"));
                        }
                    }
                }
                Event::CData(t) => {
                    if let Some(&top) = stack.last() {
                        let s = t
                            .decode()
                            .map_err(|e| doc.xml_error(&stack, at, e.to_string()))?;
                        doc.nodes[top].text.push_str(&s);
                    }
                }
                Event::GeneralRef(r) => {
                    let resolved = match r.resolve_char_ref() {
                        Ok(Some(c)) => c.to_string(),
                        Ok(None) => {
                            let name = r
                                .decode()
                                .map_err(|e| doc.xml_error(&stack, at, e.to_string()))?;
                            match quick_xml::escape::resolve_predefined_entity(&name) {
                                Some(s) => s.to_string(),
                                None => {
                                    return Err(doc.xml_error(
                                        &stack,
                                        at,
                                        format!("unknown entity &{name};"),
                                    ));
                                }
                            }
                        }
                        Err(e) => return Err(doc.xml_error(&stack, at, e.to_string())),
                    };
                    if let Some(&top) = stack.last() {
                        doc.nodes[top].text.push_str(&resolved);
                    }
                }
                Event::Eof => {
                    if let Some(&open) = stack.last() {
                        let name = doc.nodes[open].name.clone();
                        let off = doc.nodes[open].offset;
                        return Err(doc.xml_error(
                            &stack,
                            off,
                            format!("<{name}> is not closed (the file ends inside it)"),
                        ));
                    }
                    break;
                }
                Event::Comment(_) | Event::Decl(_) | Event::PI(_) | Event::DocType(_) => {}
            }
        }
        if doc.nodes.is_empty() {
            return Err(EsiError {
                file: file.to_string(),
                line: Some(1),
                element: String::new(),
                kind: EsiErrorKind::Schema,
                message: "no XML element: not an EtherCATInfo file".into(),
            });
        }
        Ok(doc)
    }

    /// Adds the element `s` starting at byte `at` under the innermost open one.
    fn open(
        &mut self,
        s: &quick_xml::events::BytesStart<'_>,
        stack: &[usize],
        at: usize,
    ) -> Result<usize, EsiError> {
        let name = String::from_utf8_lossy(s.local_name().as_ref()).into_owned();
        if stack.is_empty() && !self.nodes.is_empty() {
            return Err(self.xml_error(stack, at, format!("a second root element <{name}>")));
        }
        if stack.len() >= MAX_DEPTH {
            return Err(self.xml_error(
                stack,
                at,
                format!("elements nested deeper than {MAX_DEPTH}"),
            ));
        }
        let mut attrs = Vec::new();
        for a in s.attributes() {
            let a = a.map_err(|e| self.xml_error(stack, at, e.to_string()))?;
            let key = String::from_utf8_lossy(a.key.local_name().as_ref()).into_owned();
            let value = a
                .normalized_value(XmlVersion::Implicit1_0)
                .map_err(|e| self.xml_error(stack, at, e.to_string()))?
                .into_owned();
            attrs.push((key, value));
        }
        let id = self.nodes.len();
        self.nodes.push(Node {
            name,
            attrs,
            text: String::new(),
            children: Vec::new(),
            parent: stack.last().copied(),
            offset: at,
        });
        if let Some(&p) = stack.last() {
            self.nodes[p].children.push(id);
        }
        Ok(id)
    }

    fn line(&self, offset: usize) -> usize {
        let end = offset.min(self.text.len());
        self.text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    }

    fn path(&self, id: usize) -> String {
        let mut parts = vec![self.nodes[id].name.as_str()];
        let mut at = self.nodes[id].parent;
        while let Some(p) = at {
            parts.push(self.nodes[p].name.as_str());
            at = self.nodes[p].parent;
        }
        parts.reverse();
        parts.join("/")
    }

    fn xml_error(&self, stack: &[usize], offset: usize, message: impl Into<String>) -> EsiError {
        EsiError {
            file: self.file.to_string(),
            line: Some(self.line(offset)),
            element: stack.last().map(|&id| self.path(id)).unwrap_or_default(),
            kind: EsiErrorKind::Xml,
            message: message.into(),
        }
    }

    fn err(&self, id: usize, kind: EsiErrorKind, message: impl Into<String>) -> EsiError {
        EsiError {
            file: self.file.to_string(),
            line: Some(self.line(self.nodes[id].offset)),
            element: self.path(id),
            kind,
            message: message.into(),
        }
    }

    fn attr_err(&self, id: usize, attr: &str, message: impl Into<String>) -> EsiError {
        let mut e = self.err(id, EsiErrorKind::BadValue, message);
        e.element = format!("{}@{attr}", e.element);
        e
    }

    fn children<'s>(&'s self, id: usize, name: &'s str) -> impl Iterator<Item = usize> + 's {
        self.nodes[id]
            .children
            .iter()
            .copied()
            .filter(move |&c| self.nodes[c].name == name)
    }

    fn child(&self, id: usize, name: &str) -> Option<usize> {
        self.children(id, name).next()
    }

    fn required(&self, id: usize, name: &str) -> Result<usize, EsiError> {
        self.child(id, name).ok_or_else(|| {
            self.err(
                id,
                EsiErrorKind::Missing,
                format!("has no <{name}>, which ETG.2000 requires here"),
            )
        })
    }

    fn text(&self, id: usize) -> &str {
        self.nodes[id].text.trim()
    }

    fn child_text(&self, id: usize, name: &str) -> Option<&str> {
        self.child(id, name).map(|c| self.text(c))
    }

    fn attr(&self, id: usize, name: &str) -> Option<&str> {
        self.nodes[id]
            .attrs
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.trim())
    }

    /// An element's text as a number of type `T`.
    fn number<T: TryFrom<i128>>(&self, id: usize) -> Result<T, EsiError> {
        let s = self.text(id);
        parse_int(s)
            .and_then(|v| T::try_from(v).ok())
            .ok_or_else(|| {
                self.err(
                    id,
                    EsiErrorKind::BadValue,
                    format!(
                        "\"{s}\" is not a number of {} bits here (write #x1A00 or decimal)",
                        std::mem::size_of::<T>() * 8
                    ),
                )
            })
    }

    fn child_number<T: TryFrom<i128>>(&self, id: usize, name: &str) -> Result<T, EsiError> {
        self.number(self.required(id, name)?)
    }

    fn opt_child_number<T: TryFrom<i128>>(
        &self,
        id: usize,
        name: &str,
    ) -> Result<Option<T>, EsiError> {
        self.child(id, name).map(|c| self.number(c)).transpose()
    }

    /// An attribute as a number of type `T`, if present.
    fn attr_number<T: TryFrom<i128>>(&self, id: usize, name: &str) -> Result<Option<T>, EsiError> {
        let Some(s) = self.attr(id, name) else {
            return Ok(None);
        };
        parse_int(s)
            .and_then(|v| T::try_from(v).ok())
            .map(Some)
            .ok_or_else(|| {
                self.attr_err(
                    id,
                    name,
                    format!(
                        "\"{s}\" is not a number of {} bits here (write #x1A00 or decimal)",
                        std::mem::size_of::<T>() * 8
                    ),
                )
            })
    }

    fn required_attr_number<T: TryFrom<i128>>(&self, id: usize, name: &str) -> Result<T, EsiError> {
        self.attr_number(id, name)?.ok_or_else(|| {
            let mut e = self.err(
                id,
                EsiErrorKind::Missing,
                format!("has no {name} attribute, which ETG.2000 requires here"),
            );
            e.element = format!("{}@{name}", e.element);
            e
        })
    }

    /// An xs:boolean attribute (`true`/`false`/`1`/`0`), false if absent.
    fn attr_bool(&self, id: usize, name: &str) -> Result<bool, EsiError> {
        match self.attr(id, name) {
            None => Ok(false),
            Some(s) => parse_bool(s).ok_or_else(|| {
                self.attr_err(
                    id,
                    name,
                    format!("\"{s}\" is not a boolean (true, false, 1, 0)"),
                )
            }),
        }
    }

    /// An element's text as hex bytes (xs:hexBinary).
    fn hex(&self, id: usize) -> Result<Vec<u8>, EsiError> {
        let s = self.text(id);
        parse_hex(s).ok_or_else(|| {
            self.err(
                id,
                EsiErrorKind::BadValue,
                format!("\"{}\" is not an even number of hex digits", shorten(s)),
            )
        })
    }

    /// The `Name` child: the English one (`LcId` 1033) if several, else the first.
    fn name_of(&self, id: usize) -> String {
        let mut names = self.children(id, "Name");
        let first = names.next();
        self.children(id, "Name")
            .find(|&n| self.attr(n, "LcId") == Some("1033"))
            .or(first)
            .map(|n| self.text(n).to_string())
            .unwrap_or_default()
    }

    fn ethercat_info(&self) -> Result<EsiFile, EsiError> {
        let root = 0;
        if self.nodes[root].name != "EtherCATInfo" {
            return Err(self.err(
                root,
                EsiErrorKind::Schema,
                format!(
                    "the root element is <{}>, not <EtherCATInfo>: not an ESI file (ETG.2000)",
                    self.nodes[root].name
                ),
            ));
        }
        let vendor = self.required(root, "Vendor")?;
        let vendor_id: u32 = self.child_number(vendor, "Id")?;
        let vendor_name = self.name_of(vendor);
        let descriptions = self.required(root, "Descriptions")?;
        let devices_el = self.required(descriptions, "Devices")?;
        let groups = self.group_names(descriptions);
        let mut devices = Vec::new();
        for d in self.children(devices_el, "Device") {
            devices.push(self.device(d, vendor_id, &groups)?);
        }
        if devices.is_empty() {
            return Err(self.err(
                devices_el,
                EsiErrorKind::Schema,
                "has no <Device>: the file describes no device",
            ));
        }
        Ok(EsiFile {
            file: self.file.to_string(),
            vendor_id,
            vendor_name,
            devices,
        })
    }

    /// Group type -> group name.
    fn group_names(&self, descriptions: usize) -> HashMap<String, String> {
        let mut out = HashMap::new();
        if let Some(groups) = self.child(descriptions, "Groups") {
            for g in self.children(groups, "Group") {
                if let Some(t) = self.child_text(g, "Type") {
                    out.insert(t.to_string(), self.name_of(g));
                }
            }
        }
        out
    }

    fn device(
        &self,
        d: usize,
        vendor_id: u32,
        groups: &HashMap<String, String>,
    ) -> Result<EsiDevice, EsiError> {
        let ty = self.required(d, "Type")?;
        let type_name = self.text(ty).to_string();
        if type_name.is_empty() {
            return Err(self.err(
                ty,
                EsiErrorKind::Missing,
                "is empty: the device has no type name",
            ));
        }
        let product_code: u32 = self.required_attr_number(ty, "ProductCode")?;
        let revision: u32 = self.required_attr_number(ty, "RevisionNo")?;
        let mut name = self.name_of(d);
        if name.is_empty() {
            name = type_name.clone();
        }
        let group_type = self.child_text(d, "GroupType").unwrap_or("").to_string();
        let group = groups.get(&group_type).cloned().unwrap_or(group_type);

        let mut sync_managers = Vec::new();
        for sm in self.children(d, "Sm") {
            let kind = match self.text(sm) {
                "MBoxOut" => SmKind::MailboxOut,
                "MBoxIn" => SmKind::MailboxIn,
                "Outputs" => SmKind::Outputs,
                "Inputs" => SmKind::Inputs,
                _ => SmKind::Unused,
            };
            sync_managers.push(EsiSm {
                kind,
                start: self.attr_number(sm, "StartAddress")?.unwrap_or(0),
                default_size: self.attr_number(sm, "DefaultSize")?.unwrap_or(0),
                control: self.attr_number(sm, "ControlByte")?.unwrap_or(0),
                enable: match self.attr(sm, "Enable") {
                    None => false,
                    Some(s) => parse_bool(s)
                        .or_else(|| parse_int(s).map(|v| v != 0))
                        .ok_or_else(|| {
                            self.attr_err(sm, "Enable", format!("\"{s}\" is not 0 or 1"))
                        })?,
                },
            });
        }
        let fmmus = self
            .children(d, "Fmmu")
            .map(|f| match self.text(f) {
                "Outputs" => 1,
                "Inputs" => 2,
                "MBoxState" => 3,
                _ => 0,
            })
            .collect();

        let mut mailbox_protocols = 0;
        let mut coe = None;
        if let Some(m) = self.child(d, "Mailbox") {
            for (el, bit) in MAILBOX_PROTOCOLS {
                if self.child(m, el).is_some() {
                    mailbox_protocols |= bit;
                }
            }
            if let Some(c) = self.child(m, "CoE") {
                coe = Some(CoeDetails {
                    sdo_info: self.attr_bool(c, "SdoInfo")?,
                    pdo_assign: self.attr_bool(c, "PdoAssign")?,
                    pdo_config: self.attr_bool(c, "PdoConfig")?,
                    pdo_upload: self.attr_bool(c, "PdoUpload")?,
                    complete_access: self.attr_bool(c, "CompleteAccess")?,
                });
            }
        }

        let rx_pdos = self
            .children(d, "RxPdo")
            .map(|p| self.pdo(p))
            .collect::<Result<Vec<_>, _>>()?;
        let tx_pdos = self
            .children(d, "TxPdo")
            .map(|p| self.pdo(p))
            .collect::<Result<Vec<_>, _>>()?;

        let mut dc_opmodes = Vec::new();
        if let Some(dc) = self.child(d, "Dc") {
            for m in self.children(dc, "OpMode") {
                dc_opmodes.push(self.opmode(m)?);
            }
        }

        let mut eeprom_bytes = None;
        let mut config_words = None;
        if let Some(e) = self.child(d, "Eeprom") {
            if let Some(b) = self.child(e, "ByteSize") {
                let n: usize = self.number(b)?;
                if !(MIN_EEPROM_BYTES..=MAX_EEPROM_BYTES).contains(&n) {
                    return Err(self.err(
                        b,
                        EsiErrorKind::BadValue,
                        format!(
                            "{n} bytes: give an EEPROM of {MIN_EEPROM_BYTES} to {MAX_EEPROM_BYTES} bytes"
                        ),
                    ));
                }
                eeprom_bytes = Some(n);
            }
            if let Some(c) = self.child(e, "ConfigData") {
                let bytes = self.hex(c)?;
                if bytes.len() > 16 {
                    return Err(self.err(
                        c,
                        EsiErrorKind::BadValue,
                        format!(
                            "{} bytes: ConfigData holds SII words 0-7, at most 16 bytes",
                            bytes.len()
                        ),
                    ));
                }
                let mut words = [0u16; 7];
                for (i, w) in words.iter_mut().enumerate() {
                    let b = |k: usize| bytes.get(k).copied().unwrap_or(0);
                    *w = u16::from_le_bytes([b(2 * i), b(2 * i + 1)]);
                }
                config_words = Some(words);
            }
        }

        let mut profile_no = None;
        let mut objects = Vec::new();
        for p in self.children(d, "Profile") {
            if profile_no.is_none() {
                profile_no = self.opt_child_number(p, "ProfileNo")?;
            }
            if let Some(dict) = self.child(p, "Dictionary")
                && objects.is_empty()
            {
                objects = self.dictionary(dict)?;
            }
        }

        Ok(EsiDevice {
            vendor_id,
            type_name,
            name,
            product_code,
            revision,
            group,
            profile_no,
            sync_managers,
            fmmus,
            mailbox_protocols,
            coe,
            rx_pdos,
            tx_pdos,
            dc_opmodes,
            eeprom_bytes,
            config_words,
            objects,
            line: self.line(self.nodes[d].offset),
        })
    }

    fn pdo(&self, p: usize) -> Result<PdoDescription, EsiError> {
        let index: u16 = self.child_number(p, "Index")?;
        let mut entries = Vec::new();
        let mut entry_data_types = Vec::new();
        for e in self.children(p, "Entry") {
            let bits: u8 = self.child_number(e, "BitLen")?;
            let idx: u16 = self.child_number(e, "Index")?;
            // Padding entries (index 0) may leave out the subindex.
            let sub: u8 = self.opt_child_number(e, "SubIndex")?.unwrap_or(0);
            entries.push(PdoEntry {
                index: idx,
                subindex: sub,
                bits,
                name: self.child_text(e, "Name").unwrap_or("").to_string(),
            });
            entry_data_types.push(
                self.child_text(e, "DataType")
                    .and_then(data_type::from_esi_name)
                    .unwrap_or(0),
            );
        }
        Ok(PdoDescription {
            index,
            name: self.name_of(p),
            sm: self.attr_number(p, "Sm")?,
            fixed: self.attr_bool(p, "Fixed")?,
            mandatory: self.attr_bool(p, "Mandatory")?,
            entries,
            entry_data_types,
        })
    }

    fn opmode(&self, m: usize) -> Result<DcOpMode, EsiError> {
        let name = self.child_text(m, "Name").unwrap_or("").to_string();
        let description = self.child_text(m, "Desc").unwrap_or("").to_string();
        let assign_activate: u16 = self.child_number(m, "AssignActivate")?;
        let (cycle_time_sync0_ns, cycle_time_sync0_factor) = match self.child(m, "CycleTimeSync0") {
            Some(c) => (self.number(c)?, self.attr_number(c, "Factor")?),
            None => (0, None),
        };
        let shift_time_sync0_ns = self.opt_child_number(m, "ShiftTimeSync0")?.unwrap_or(0);
        Ok(DcOpMode {
            name,
            description,
            assign_activate,
            cycle_time_sync0_ns,
            cycle_time_sync0_factor,
            shift_time_sync0_ns,
        })
    }

    fn dictionary(&self, dict: usize) -> Result<Vec<Object>, EsiError> {
        let mut types: HashMap<&str, usize> = HashMap::new();
        if let Some(dts) = self.child(dict, "DataTypes") {
            for t in self.children(dts, "DataType") {
                if let Some(n) = self.child(t, "Name") {
                    types.entry(self.text(n)).or_insert(t);
                }
            }
        }
        let dt = Types { doc: self, types };
        let mut objects = Vec::new();
        if let Some(objs) = self.child(dict, "Objects") {
            for o in self.children(objs, "Object") {
                objects.push(dt.object(o)?);
            }
        }
        Ok(objects)
    }
}

/// The dictionary's data types, by name.
struct Types<'d, 'a> {
    doc: &'d Doc<'a>,
    types: HashMap<&'d str, usize>,
}

/// How deep a data type may refer to others (alias of an alias ...): a loop in a file ends here.
const MAX_TYPE_DEPTH: usize = 8;

/// A record's or array's entry before its defaults are applied.
struct Slot {
    subindex: u8,
    name: String,
    data_type: u16,
    bits: u16,
    access: Access,
    pdo_mapping: u16,
}

impl<'d, 'a> Types<'d, 'a> {
    /// The CiA code of a data type name: a base type's, or that of its `BaseType` chain (enums,
    /// aliases, array element types); 0 (unknown) for anything else.
    fn code(&self, name: &str, depth: usize) -> u16 {
        if let Some(c) = data_type::from_esi_name(name) {
            return c;
        }
        if depth >= MAX_TYPE_DEPTH {
            return 0;
        }
        self.types
            .get(name)
            .and_then(|&t| self.doc.child_text(t, "BaseType"))
            .map_or(0, |b| self.code(b, depth + 1))
    }

    /// The flags of an element (an Object or a SubItem): access and PDO mapping; those of
    /// `fallback` (the object's) when it has none, read-only at last.
    fn flags(&self, id: usize, fallback: Option<usize>) -> (Access, u16) {
        let doc = self.doc;
        let Some(f) = doc
            .child(id, "Flags")
            .or_else(|| fallback.and_then(|o| doc.child(o, "Flags")))
        else {
            return (Access::ReadOnly, 0);
        };
        let access = match doc.child(f, "Access") {
            Some(a) => match doc.text(a) {
                // rw with writes restricted to PRE-OP (the PDO mapping and assignment objects
                // of ETG.2000 files) is the dictionary's ReadWritePreOp; wo is served as rw.
                "rw" | "wo" if doc.attr(a, "WriteRestrictions") == Some("PreOP") => {
                    Access::ReadWritePreOp
                }
                "rw" | "wo" => Access::ReadWrite,
                _ => Access::ReadOnly,
            },
            None => Access::ReadOnly,
        };
        let mapping = doc.child_text(f, "PdoMapping").map_or(0, |m| {
            let m = m.to_ascii_uppercase();
            (if m.contains('R') { 0x0040 } else { 0 }) | (if m.contains('T') { 0x0080 } else { 0 })
        });
        (access, mapping)
    }

    /// The entries a data type with SubItems lays out (subindex 0 first), and whether it is an
    /// array (a SubItem whose type has `ArrayInfo`).
    fn slots(&self, t: usize, object: usize) -> Result<(Vec<Slot>, bool), EsiError> {
        let doc = self.doc;
        let mut out = Vec::new();
        let mut is_array = false;
        let mut next_sub: u16 = 0;
        for si in doc.children(t, "SubItem") {
            let name = doc.child_text(si, "Name").unwrap_or("").to_string();
            let type_name = doc.child_text(si, "Type").unwrap_or("");
            let bits: u16 = doc.opt_child_number(si, "BitSize")?.unwrap_or(0);
            let (access, pdo_mapping) = self.flags(si, Some(object));
            // ETG.2000 arrays: subindex 0 (the count), then one SubItem without a SubIdx whose
            // type is an array of `Elements` from `LBound` of the `BaseType`. A SubItem with a
            // SubIdx is one entry whatever its type (Ingenia's 0x58B2:01, an ARRAY [0..511] OF
            // BYTE, is one 512-byte entry).
            let array = self
                .types
                .get(type_name)
                .filter(|_| doc.child(si, "SubIdx").is_none())
                .and_then(|&at| doc.child(at, "ArrayInfo").map(|ai| (at, ai)));
            if let Some((at, ai)) = array {
                is_array = true;
                let lbound: u16 = doc.opt_child_number(ai, "LBound")?.unwrap_or(1);
                let elements: u16 = doc.child_number(ai, "Elements")?;
                if usize::from(lbound) + usize::from(elements) > 256 {
                    return Err(doc.err(
                        ai,
                        EsiErrorKind::BadValue,
                        format!("{elements} elements from {lbound} go past subindex 255"),
                    ));
                }
                let base = doc.child_text(at, "BaseType").unwrap_or("");
                let code = self.code(base, 0);
                let elem_bits = bits.checked_div(elements).unwrap_or(0);
                for k in 0..elements {
                    out.push(Slot {
                        subindex: (lbound + k) as u8,
                        name: format!("{name} {}", k + 1),
                        data_type: code,
                        bits: elem_bits,
                        access,
                        pdo_mapping,
                    });
                }
                next_sub = lbound + elements;
            } else {
                let sub: u16 = doc.opt_child_number(si, "SubIdx")?.unwrap_or(next_sub);
                if sub > 255 {
                    return Err(doc.err(
                        si,
                        EsiErrorKind::BadValue,
                        format!("subindex {sub} > 255"),
                    ));
                }
                out.push(Slot {
                    subindex: sub as u8,
                    name,
                    data_type: self.code(type_name, 0),
                    bits,
                    access,
                    pdo_mapping,
                });
                next_sub = sub + 1;
            }
        }
        Ok((out, is_array))
    }

    fn object(&self, o: usize) -> Result<Object, EsiError> {
        let doc = self.doc;
        let index: u16 = doc.child_number(o, "Index")?;
        let name = doc.child_text(o, "Name").unwrap_or("").to_string();
        let type_name = doc.text(doc.required(o, "Type")?);
        let bit_size: Option<u16> = doc.opt_child_number(o, "BitSize")?;
        let info = doc.child(o, "Info");
        let def = self.types.get(type_name).copied();
        let has_subitems = def.is_some_and(|t| doc.child(t, "SubItem").is_some());
        if !has_subitems {
            // A VAR: one entry, subindex 0.
            let (access, pdo_mapping) = self.flags(o, None);
            let code = self.code(type_name, 0);
            let bits = bit_size
                .or_else(|| def.and_then(|t| doc.opt_child_number(t, "BitSize").ok().flatten()))
                .unwrap_or(0);
            let mut e = Entry {
                subindex: 0,
                name: name.clone(),
                data_type: code,
                bits,
                access,
                value: Vec::new(),
                pdo_mapping,
            };
            e.value = match info {
                Some(i) => self.default(i, &e)?,
                None => None,
            }
            .unwrap_or_else(|| zero_value(&e));
            return Ok(Object {
                index,
                name,
                code: ObjectCode::Var,
                entries: vec![e],
            });
        }
        let (slots, is_array) = self.slots(def.unwrap_or(o), o)?;
        let mut entries: Vec<Entry> = slots
            .into_iter()
            .map(|s| Entry {
                subindex: s.subindex,
                name: s.name,
                data_type: s.data_type,
                bits: s.bits,
                access: s.access,
                value: Vec::new(),
                pdo_mapping: s.pdo_mapping,
            })
            .collect();
        let mut given = vec![false; entries.len()];
        if let Some(i) = info {
            // The Info's SubItems name the entry they give defaults for; array elements, whose
            // names the type does not spell out, go by position.
            for (k, si) in doc.children(i, "SubItem").enumerate() {
                let si_name = doc.child_text(si, "Name").unwrap_or("");
                let by_name = entries.iter().position(|e| e.name == si_name);
                let Some(at) = by_name.or((k < entries.len()).then_some(k)) else {
                    continue;
                };
                if by_name.is_none() && !si_name.is_empty() {
                    entries[at].name = si_name.to_string();
                }
                if let Some(si_info) = doc.child(si, "Info")
                    && let Some(v) = self.default(si_info, &entries[at])?
                {
                    entries[at].value = v;
                    given[at] = true;
                }
            }
        }
        let max_sub = entries.iter().map(|e| e.subindex).max().unwrap_or(0);
        for (e, given) in entries.iter_mut().zip(given) {
            if !given {
                e.value = zero_value(e);
                if e.subindex == 0 {
                    // Subindex 0 without a default counts the entries.
                    e.value = vec![max_sub];
                }
            }
        }
        entries.sort_by_key(|e| e.subindex);
        entries.dedup_by_key(|e| e.subindex);
        if entries.first().is_none_or(|e| e.subindex != 0) {
            entries.insert(
                0,
                Entry {
                    subindex: 0,
                    name: "SubIndex 000".into(),
                    data_type: data_type::UINT8,
                    bits: 8,
                    access: Access::ReadOnly,
                    value: vec![max_sub],
                    pdo_mapping: 0,
                },
            );
        }
        if entries[0].value.is_empty() {
            entries[0].value = vec![max_sub];
        }
        Ok(Object {
            index,
            name,
            code: if is_array {
                ObjectCode::Array
            } else {
                ObjectCode::Record
            },
            entries,
        })
    }

    /// The default an `Info` element gives for entry `e`: `DefaultData` (hex bytes as stored,
    /// little-endian), `DefaultValue` (a number, or a string's text), or `DefaultString`.
    fn default(&self, info: usize, e: &Entry) -> Result<Option<Vec<u8>>, EsiError> {
        let doc = self.doc;
        let is_string = matches!(
            e.data_type,
            data_type::VISIBLE_STRING | data_type::OCTET_STRING | data_type::UNICODE_STRING
        );
        let len = usize::from(e.bits).div_ceil(8);
        if let Some(d) = doc.child(info, "DefaultData") {
            let mut v = doc.hex(d)?;
            if !is_string {
                if v.len() > len && len > 0 {
                    return Err(doc.err(
                        d,
                        EsiErrorKind::BadValue,
                        format!(
                            "{} bytes of default for an entry of {} bits",
                            v.len(),
                            e.bits
                        ),
                    ));
                }
                // Shorter: the missing high bytes are 0 (little-endian).
                v.resize(len.max(v.len()), 0);
            }
            return Ok(Some(v));
        }
        if let Some(s) = doc.child(info, "DefaultString") {
            return Ok(Some(doc.text(s).as_bytes().to_vec()));
        }
        let Some(d) = doc.child(info, "DefaultValue") else {
            return Ok(None);
        };
        let s = doc.text(d);
        if is_string {
            return Ok(Some(s.as_bytes().to_vec()));
        }
        let bad = || {
            doc.err(
                d,
                EsiErrorKind::BadValue,
                format!("\"{}\" is not a value of {} bits", shorten(s), e.bits),
            )
        };
        let v = match e.data_type {
            data_type::REAL32 => s.parse::<f32>().map_err(|_| bad())?.to_le_bytes().to_vec(),
            data_type::REAL64 => s.parse::<f64>().map_err(|_| bad())?.to_le_bytes().to_vec(),
            _ => {
                let n = match parse_bool(s) {
                    Some(b) if !s.chars().all(|c| c.is_ascii_digit()) => i128::from(b),
                    _ => parse_int(s).ok_or_else(bad)?,
                };
                let bits = u32::from(e.bits).min(64);
                let fits = if bits == 0 {
                    n == 0
                } else if n < 0 {
                    n >= -(1i128 << (bits - 1))
                } else {
                    n < (1i128 << bits)
                };
                if !fits {
                    return Err(bad());
                }
                n.to_le_bytes()[..len.min(16)].to_vec()
            }
        };
        Ok(Some(v))
    }
}

/// An entry's value without a default: zeros of its size (a string: empty).
fn zero_value(e: &Entry) -> Vec<u8> {
    match e.data_type {
        data_type::VISIBLE_STRING | data_type::OCTET_STRING | data_type::UNICODE_STRING => {
            Vec::new()
        }
        _ => vec![0; usize::from(e.bits).div_ceil(8)],
    }
}

/// A HexDecValue (ETG.2000): `#x` then hex digits, or a decimal number with an optional sign.
pub fn parse_int(s: &str) -> Option<i128> {
    let s = s.trim();
    if let Some(h) = s
        .strip_prefix("#x")
        .or_else(|| s.strip_prefix("#X"))
        .or_else(|| s.strip_prefix("0x"))
        .or_else(|| s.strip_prefix("0X"))
    {
        if h.is_empty() || h.len() > 32 {
            return None;
        }
        return u128::from_str_radix(h, 16)
            .ok()
            .and_then(|v| i128::try_from(v).ok());
    }
    if s.is_empty() || s.len() > 38 {
        return None;
    }
    s.parse::<i128>().ok()
}

/// xs:hexBinary, whitespace ignored.
pub fn parse_hex(s: &str) -> Option<Vec<u8>> {
    let digits: Vec<u8> = s.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    if !digits.len().is_multiple_of(2) {
        return None;
    }
    digits
        .chunks(2)
        .map(|p| {
            let h = char::from(p[0]).to_digit(16)?;
            let l = char::from(p[1]).to_digit(16)?;
            Some((h * 16 + l) as u8)
        })
        .collect()
}

fn parse_bool(s: &str) -> Option<bool> {
    match s.trim() {
        "true" | "1" | "TRUE" | "True" => Some(true),
        "false" | "0" | "FALSE" | "False" => Some(false),
        _ => None,
    }
}

/// At most 40 characters of a value, for a message.
fn shorten(s: &str) -> String {
    if s.chars().count() <= 40 {
        s.to_string()
    } else {
        format!("{}...", s.chars().take(40).collect::<String>())
    }
}

#[cfg(test)]
mod tests;
