//! The XML read into a tree of elements, and the device description read from the tree.

use super::types::Types;
use super::values::{parse_bool, shorten};
use super::*;
use crate::coe::{Object, data_type};
use crate::model::{DcOpMode, PdoDescription, PdoEntry};
use quick_xml::XmlVersion;
use quick_xml::events::Event;
use std::collections::HashMap;

/// One element of the document.
#[derive(Debug)]
pub(super) struct Node {
    pub(super) name: String,
    pub(super) attrs: Vec<(String, String)>,
    pub(super) text: String,
    pub(super) children: Vec<usize>,
    pub(super) parent: Option<usize>,
    /// Byte offset of its `<`.
    pub(super) offset: usize,
}

/// The document as a flat tree (no recursion, so no input nests deep enough to overflow the
/// stack, in parsing or in dropping).
pub(super) struct Doc<'a> {
    pub(super) file: &'a str,
    pub(super) text: &'a str,
    pub(super) nodes: Vec<Node>,
}

/// Deepest nesting accepted; ETG.2000 files nest about 12 deep.
pub(super) const MAX_DEPTH: usize = 64;

impl<'a> Doc<'a> {
    pub(super) fn parse(file: &'a str, text: &'a str) -> Result<Self, EsiError> {
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
    pub(super) fn open(
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

    pub(super) fn line(&self, offset: usize) -> usize {
        let end = offset.min(self.text.len());
        self.text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    }

    pub(super) fn path(&self, id: usize) -> String {
        let mut parts = vec![self.nodes[id].name.as_str()];
        let mut at = self.nodes[id].parent;
        while let Some(p) = at {
            parts.push(self.nodes[p].name.as_str());
            at = self.nodes[p].parent;
        }
        parts.reverse();
        parts.join("/")
    }

    pub(super) fn xml_error(
        &self,
        stack: &[usize],
        offset: usize,
        message: impl Into<String>,
    ) -> EsiError {
        EsiError {
            file: self.file.to_string(),
            line: Some(self.line(offset)),
            element: stack.last().map(|&id| self.path(id)).unwrap_or_default(),
            kind: EsiErrorKind::Xml,
            message: message.into(),
        }
    }

    pub(super) fn err(
        &self,
        id: usize,
        kind: EsiErrorKind,
        message: impl Into<String>,
    ) -> EsiError {
        EsiError {
            file: self.file.to_string(),
            line: Some(self.line(self.nodes[id].offset)),
            element: self.path(id),
            kind,
            message: message.into(),
        }
    }

    pub(super) fn attr_err(&self, id: usize, attr: &str, message: impl Into<String>) -> EsiError {
        let mut e = self.err(id, EsiErrorKind::BadValue, message);
        e.element = format!("{}@{attr}", e.element);
        e
    }

    pub(super) fn children<'s>(
        &'s self,
        id: usize,
        name: &'s str,
    ) -> impl Iterator<Item = usize> + 's {
        self.nodes[id]
            .children
            .iter()
            .copied()
            .filter(move |&c| self.nodes[c].name == name)
    }

    pub(super) fn child(&self, id: usize, name: &str) -> Option<usize> {
        self.children(id, name).next()
    }

    pub(super) fn required(&self, id: usize, name: &str) -> Result<usize, EsiError> {
        self.child(id, name).ok_or_else(|| {
            self.err(
                id,
                EsiErrorKind::Missing,
                format!("has no <{name}>, which ETG.2000 requires here"),
            )
        })
    }

    pub(super) fn text(&self, id: usize) -> &str {
        self.nodes[id].text.trim()
    }

    pub(super) fn child_text(&self, id: usize, name: &str) -> Option<&str> {
        self.child(id, name).map(|c| self.text(c))
    }

    pub(super) fn attr(&self, id: usize, name: &str) -> Option<&str> {
        self.nodes[id]
            .attrs
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.trim())
    }

    /// An element's text as a number of type `T`.
    pub(super) fn number<T: TryFrom<i128>>(&self, id: usize) -> Result<T, EsiError> {
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

    pub(super) fn child_number<T: TryFrom<i128>>(
        &self,
        id: usize,
        name: &str,
    ) -> Result<T, EsiError> {
        self.number(self.required(id, name)?)
    }

    pub(super) fn opt_child_number<T: TryFrom<i128>>(
        &self,
        id: usize,
        name: &str,
    ) -> Result<Option<T>, EsiError> {
        self.child(id, name).map(|c| self.number(c)).transpose()
    }

    /// An attribute as a number of type `T`, if present.
    pub(super) fn attr_number<T: TryFrom<i128>>(
        &self,
        id: usize,
        name: &str,
    ) -> Result<Option<T>, EsiError> {
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

    pub(super) fn required_attr_number<T: TryFrom<i128>>(
        &self,
        id: usize,
        name: &str,
    ) -> Result<T, EsiError> {
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
    pub(super) fn attr_bool(&self, id: usize, name: &str) -> Result<bool, EsiError> {
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
    pub(super) fn hex(&self, id: usize) -> Result<Vec<u8>, EsiError> {
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
    pub(super) fn name_of(&self, id: usize) -> String {
        let mut names = self.children(id, "Name");
        let first = names.next();
        self.children(id, "Name")
            .find(|&n| self.attr(n, "LcId") == Some("1033"))
            .or(first)
            .map(|n| self.text(n).to_string())
            .unwrap_or_default()
    }

    pub(super) fn ethercat_info(&self) -> Result<EsiFile, EsiError> {
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
    pub(super) fn group_names(&self, descriptions: usize) -> HashMap<String, String> {
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

    /// The `<Device>` element `d` of a file of vendor `vendor_id`, its group named from
    /// `groups`: each part read in document order (the first error found is the first in the
    /// file).
    pub(super) fn device(
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
        let sync_managers = self.sync_managers(d)?;
        let fmmus = self.fmmus(d);
        let (mailbox_protocols, coe) = self.mailbox(d)?;
        let rx_pdos = self
            .children(d, "RxPdo")
            .map(|p| self.pdo(p))
            .collect::<Result<Vec<_>, _>>()?;
        let tx_pdos = self
            .children(d, "TxPdo")
            .map(|p| self.pdo(p))
            .collect::<Result<Vec<_>, _>>()?;
        let dc_opmodes = self.dc_opmodes(d)?;
        let (eeprom_bytes, config_words) = self.eeprom(d)?;
        let (profile_no, objects) = self.profile(d)?;
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

    /// The device's `<Sm>` elements: each SyncManager's kind, start, size, control byte and
    /// whether it is enabled.
    fn sync_managers(&self, d: usize) -> Result<Vec<EsiSm>, EsiError> {
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
        Ok(sync_managers)
    }

    /// The device's `<Fmmu>` elements as the SII's FMMU category codes them (1 outputs, 2
    /// inputs, 3 mailbox state, 0 unused).
    fn fmmus(&self, d: usize) -> Vec<u8> {
        self.children(d, "Fmmu")
            .map(|f| match self.text(f) {
                "Outputs" => 1,
                "Inputs" => 2,
                "MBoxState" => 3,
                _ => 0,
            })
            .collect()
    }

    /// The device's `<Mailbox>`: the protocols it names (SII word 0x1C bits) and its CoE
    /// details, if any.
    fn mailbox(&self, d: usize) -> Result<(u16, Option<CoeDetails>), EsiError> {
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
        Ok((mailbox_protocols, coe))
    }

    /// The DC operation modes under the device's `<Dc>`.
    fn dc_opmodes(&self, d: usize) -> Result<Vec<DcOpMode>, EsiError> {
        let mut dc_opmodes = Vec::new();
        if let Some(dc) = self.child(d, "Dc") {
            for m in self.children(dc, "OpMode") {
                dc_opmodes.push(self.opmode(m)?);
            }
        }
        Ok(dc_opmodes)
    }

    /// The device's `<Eeprom>`: its size in bytes and the SII words 0-6 its `ConfigData`
    /// gives, each checked.
    fn eeprom(&self, d: usize) -> Result<(Option<usize>, Option<[u16; 7]>), EsiError> {
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
        Ok((eeprom_bytes, config_words))
    }

    /// The device's `<Profile>`s: the first profile number given, and the first dictionary.
    fn profile(&self, d: usize) -> Result<(Option<u32>, Vec<Object>), EsiError> {
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
        Ok((profile_no, objects))
    }

    pub(super) fn pdo(&self, p: usize) -> Result<PdoDescription, EsiError> {
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

    pub(super) fn opmode(&self, m: usize) -> Result<DcOpMode, EsiError> {
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

    pub(super) fn dictionary(&self, dict: usize) -> Result<Vec<Object>, EsiError> {
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
