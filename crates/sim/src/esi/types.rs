//! An ESI's data types (`DataTypes`): the objects' entries, with their sizes and defaults,
//! resolved through the types they are built from.

use super::values::{parse_bool, shorten, zero_value};
use super::*;
use crate::coe::{Access, Entry, Object, ObjectCode, data_type};
use std::collections::HashMap;

/// The dictionary's data types, by name.
pub(super) struct Types<'d, 'a> {
    pub(super) doc: &'d Doc<'a>,
    pub(super) types: HashMap<&'d str, usize>,
}

/// How deep a data type may refer to others (alias of an alias ...): a loop in a file ends here.
pub(super) const MAX_TYPE_DEPTH: usize = 8;

/// A record's or array's entry before its defaults are applied.
pub(super) struct Slot {
    pub(super) subindex: u8,
    pub(super) name: String,
    pub(super) data_type: u16,
    pub(super) bits: u16,
    pub(super) access: Access,
    pub(super) pdo_mapping: u16,
}

impl<'d, 'a> Types<'d, 'a> {
    /// The CiA code of a data type name: a base type's, or that of its `BaseType` chain (enums,
    /// aliases, array element types); 0 (unknown) for anything else.
    pub(super) fn code(&self, name: &str, depth: usize) -> u16 {
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
    pub(super) fn flags(&self, id: usize, fallback: Option<usize>) -> (Access, u16) {
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
    pub(super) fn slots(&self, t: usize, object: usize) -> Result<(Vec<Slot>, bool), EsiError> {
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

    pub(super) fn object(&self, o: usize) -> Result<Object, EsiError> {
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
    pub(super) fn default(&self, info: usize, e: &Entry) -> Result<Option<Vec<u8>>, EsiError> {
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
