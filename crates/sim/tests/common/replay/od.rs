//! A device's object dictionary as far as the capture's CoE traffic shows it: every object and
//! entry an SDO answer revealed, with the value it first had, its length, whether a download
//! to it was taken; what an abort said is missing is left out.
//!
//! SDO layout: ETG.1000.6 section 5.6.2 (mailbox header 6 bytes, CoE header 2, then the SDO's
//! command byte, index, subindex and four data bytes), parsed here from the bytes.

use super::capture::{Addressing, Exchange};
use super::network::Network;
use crate::common::datagrams;
use ecsync_sim::coe::{Access, Entry, Object, ObjectCode, ObjectDictionary, data_type};
use ecsync_wire::Command;
use std::collections::BTreeMap;

/// SDO abort codes (ETG.1000.6 table 41) that say what is not there or not writable.
const ABORT_NO_OBJECT: u32 = 0x0602_0000;
const ABORT_NO_SUBINDEX: u32 = 0x0609_0011;
const ABORT_READ_ONLY: u32 = 0x0601_0002;

/// What the traffic showed of one entry.
#[derive(Debug, Clone, Default)]
struct EntryFacts {
    value: Vec<u8>,
    writable: bool,
    read_only: bool,
}

/// What the traffic showed of one device's dictionary.
#[derive(Debug, Clone, Default)]
struct Facts {
    entries: BTreeMap<(u16, u8), EntryFacts>,
    /// Objects read or written whole (complete access).
    whole: BTreeMap<u16, bool>,
    missing_objects: Vec<u16>,
    missing_entries: Vec<(u16, u8)>,
}

impl Facts {
    fn seen(&mut self, index: u16, sub: u8, value: &[u8], write: bool) {
        let e = self
            .entries
            .entry((index, sub))
            .or_insert_with(|| EntryFacts {
                value: value.to_vec(),
                ..EntryFacts::default()
            });
        if e.value.len() != value.len() && !write {
            e.value = value.to_vec();
        }
        e.writable |= write;
    }

    /// A complete access's data from `sub` (0: the count as 16 bits first): the entries split
    /// by the lengths known from single accesses, else by the object's kind (assignments
    /// 16 bits, mappings 32), else evenly.
    fn whole_object(&mut self, index: u16, sub: u8, data: &[u8], write: bool) {
        self.whole.insert(index, true);
        let (count, mut rest) = if sub == 0 {
            let Some(&c) = data.first() else { return };
            self.seen(index, 0, &[c], write);
            (c, data.get(2..).unwrap_or_default())
        } else {
            let c = self
                .entries
                .get(&(index, 0))
                .and_then(|e| e.value.first().copied())
                .unwrap_or(0);
            (c, data)
        };
        for s in 1..=count {
            let known = self.entries.get(&(index, s)).map(|e| e.value.len());
            let by_kind = match index {
                0x1c10..=0x1c2f => Some(2),
                0x1600..=0x17ff | 0x1a00..=0x1bff => Some(4),
                _ => None,
            };
            let left = usize::from(count - s + 1);
            let n = known
                .or(by_kind)
                .unwrap_or(rest.len() / left.max(1))
                .min(rest.len());
            let (v, r) = rest.split_at(n);
            self.seen(index, s, v, write);
            rest = r;
        }
    }
}

/// The messages of one station's mailbox in order: `true` for the master's requests.
fn messages(exchanges: &[Exchange], net: &Network, pos: usize) -> Vec<(bool, Vec<u8>)> {
    let Some(m) = net.slaves[pos].mailbox else {
        return Vec::new();
    };
    let mut addressing = Addressing::default();
    let mut out = Vec::new();
    for ex in exchanges {
        let Some(back) = &ex.back else { continue };
        for (s, d) in datagrams(&ex.sent).iter().zip(datagrams(back)) {
            addressing.learn(s.adp, &d);
            if d.wkc == 0 || addressing.position(d.command, s.adp) != Some(pos) {
                continue;
            }
            if d.command == Command::Fpwr.code() && m.is_out(d.ado, d.data.len()) {
                out.push((true, d.data.clone()));
            } else if d.command == Command::Fprd.code() && m.is_in(d.ado, d.data.len()) {
                out.push((false, d.data.clone()));
            }
        }
    }
    out
}

/// The mailbox message's CoE part (CoE header on) if it is CoE and long enough.
fn coe(msg: &[u8]) -> Option<&[u8]> {
    let len = usize::from(u16::from_le_bytes([*msg.first()?, *msg.get(1)?]));
    (msg.get(5)? & 0x0f == 3 && len >= 2).then(|| &msg[6..(6 + len).min(msg.len())])
}

fn le32(b: &[u8]) -> u32 {
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// The dictionary of the slave at `pos`, if it has a mailbox and its traffic shows objects.
pub fn dictionary(exchanges: &[Exchange], net: &Network, pos: usize) -> Option<ObjectDictionary> {
    let msgs = messages(exchanges, net, pos);
    let mut f = Facts::default();
    // The request an answer belongs to, and a segmented upload's data so far.
    let mut request: Option<Vec<u8>> = None;
    let mut upload: Option<(u16, u8, bool, Vec<u8>)> = None;
    for (is_request, msg) in msgs {
        if is_request {
            request = Some(msg);
            continue;
        }
        let (Some(req), Some(ans)) = (request.as_deref().and_then(coe), coe(&msg)) else {
            continue;
        };
        answered(&mut f, req, ans, &mut upload);
    }
    (!f.entries.is_empty()).then(|| build(&f))
}

/// One SDO request `req` and its answer `ans` (both from the CoE header on).
fn answered(f: &mut Facts, req: &[u8], ans: &[u8], upload: &mut Option<(u16, u8, bool, Vec<u8>)>) {
    if req.len() < 3 || ans.len() < 3 || req[1] >> 4 != 2 {
        return;
    }
    let service = ans[1] >> 4;
    let (rc, ac) = (req[2], ans[2]);
    let at = |b: &[u8]| (b.len() >= 6).then(|| (u16::from_le_bytes([b[3], b[4]]), b[5]));
    if service == 2 && ac == 0x80 && ans.len() >= 10 {
        let Some((index, sub)) = at(ans) else { return };
        match le32(&ans[6..10]) {
            ABORT_NO_OBJECT => f.missing_objects.push(index),
            ABORT_NO_SUBINDEX => f.missing_entries.push((index, sub)),
            ABORT_READ_ONLY => {
                f.entries.entry((index, sub)).or_default().read_only = true;
            }
            _ => {}
        }
        return;
    }
    if service != 3 || ans.len() < 10 {
        return;
    }
    let ca = rc & 0x10 != 0;
    match (rc >> 5, ac >> 5) {
        // Initiate upload and its response: expedited (bit 1) with 4 - n bytes when the size
        // is indicated, else normal: the size, the data (the rest in segments if it is longer).
        (2, 2) => {
            let Some((index, sub)) = at(ans) else { return };
            let data = if ac & 0x02 != 0 {
                let n = if ac & 0x01 != 0 {
                    4 - usize::from((ac >> 2) & 3)
                } else {
                    4
                };
                ans[6..6 + n].to_vec()
            } else {
                let size = le32(&ans[6..10]) as usize;
                let d = ans[10..].to_vec();
                if d.len() < size {
                    *upload = Some((index, sub, ca, d));
                    return;
                }
                d[..size].to_vec()
            };
            stored(f, index, sub, ca, &data, false);
        }
        // Upload segment: 7 - n bytes of a 7-byte segment, or all that follows; the last bit.
        (3, 0) => {
            let Some((index, sub, ca, mut d)) = upload.take() else {
                return;
            };
            let seg = &ans[3..];
            let n = usize::from((ac >> 1) & 7);
            d.extend_from_slice(if seg.len() <= 7 {
                &seg[..7 - n.min(7)]
            } else {
                seg
            });
            if ac & 0x01 != 0 {
                stored(f, index, sub, ca, &d, false);
            } else {
                *upload = Some((index, sub, ca, d));
            }
        }
        // Initiate download and its response: the value the request carried was taken.
        (1, 3) => {
            let Some((index, sub)) = at(req) else { return };
            let data = if rc & 0x02 != 0 {
                let n = if rc & 0x01 != 0 {
                    4 - usize::from((rc >> 2) & 3)
                } else {
                    4
                };
                req[6..6 + n].to_vec()
            } else {
                let size = le32(&req[6..10]) as usize;
                req.get(10..10 + size).unwrap_or_default().to_vec()
            };
            stored(f, index, sub, ca, &data, true);
        }
        _ => {}
    }
}

fn stored(f: &mut Facts, index: u16, sub: u8, ca: bool, data: &[u8], write: bool) {
    if ca {
        f.whole_object(index, sub, data, write);
    } else {
        f.seen(index, sub, data, write);
    }
}

/// The CiA data type of an entry `n` bytes long (the names and versions strings).
fn type_of(index: u16, n: usize) -> (u16, u16) {
    let t = match (index, n) {
        (0x1008..=0x100a, _) => data_type::VISIBLE_STRING,
        (_, 1) => data_type::UINT8,
        (_, 2) => data_type::UINT16,
        (_, 4) => data_type::UINT32,
        (_, 8) => data_type::UINT64,
        _ => data_type::OCTET_STRING,
    };
    (t, (n * 8) as u16)
}

fn build(f: &Facts) -> ObjectDictionary {
    let mut objects: BTreeMap<u16, Vec<Entry>> = BTreeMap::new();
    for (&(index, sub), e) in &f.entries {
        if f.missing_objects.contains(&index) || f.missing_entries.contains(&(index, sub)) {
            continue;
        }
        let (dt, bits) = type_of(index, e.value.len());
        // The PDO mapping and assignment are written in PRE-OP only (ETG.1000.6).
        let pdo = matches!(index, 0x1600..=0x17ff | 0x1a00..=0x1bff | 0x1c12 | 0x1c13);
        let access = match (e.writable && !e.read_only, pdo) {
            (false, _) => Access::ReadOnly,
            (true, true) => Access::ReadWritePreOp,
            (true, false) => Access::ReadWrite,
        };
        objects.entry(index).or_default().push(Entry {
            subindex: sub,
            name: format!("{index:04X}:{sub:02X}"),
            data_type: dt,
            bits,
            access,
            value: e.value.clone(),
            pdo_mapping: 0,
        });
    }
    let objects = objects
        .into_iter()
        .map(|(index, mut entries)| {
            let has_subs = entries.iter().any(|e| e.subindex > 0) || f.whole.contains_key(&index);
            if has_subs && entries[0].subindex != 0 {
                // Subindex 0 of a record never read: the highest subindex seen.
                let max = entries.iter().map(|e| e.subindex).max().unwrap_or(0);
                entries.insert(0, count_entry(index, max));
            }
            let same = entries.iter().skip(1).all(|e| e.bits == entries[1].bits);
            Object {
                index,
                name: format!("{index:04X}"),
                code: match (has_subs, same) {
                    (false, _) => ObjectCode::Var,
                    (true, true) => ObjectCode::Array,
                    (true, false) => ObjectCode::Record,
                },
                entries,
            }
        })
        .collect();
    ObjectDictionary::from_objects(objects)
}

fn count_entry(index: u16, max: u8) -> Entry {
    Entry {
        subindex: 0,
        name: format!("{index:04X}:00"),
        data_type: data_type::UINT8,
        bits: 8,
        access: Access::ReadOnly,
        value: vec![max],
        pdo_mapping: 0,
    }
}
