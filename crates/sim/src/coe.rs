//! A drive's CoE server: its object dictionary and the SDO services on it (ETG.1000.6 section
//! 5.6.2), as the application behind the mailbox answers them.
//!
//! The dictionary has the communication objects every EtherCAT device with CoE has (ETG.1000.6
//! table 73; ETG.1020 for 0x1C32/0x1C33): 0x1000 device type, 0x1008-0x100A names and versions,
//! 0x1018 identity, 0x1C00 the SyncManager communication types, 0x1600/0x1A00 the PDO
//! mappings and 0x1C12/0x1C13 their assignment (writable in PRE-OP), 0x1C32/0x1C33 the
//! SyncManager parameters (sync mode, cycle time, shift time, supported modes, minimum cycle
//! time, calc-and-copy time, SM-event-missed counter :0B, cycle-time-too-small :0C, sync error
//! :20); and the application's objects that its PDOs map (for a servo drive the CiA 402
//! objects).
//!
//! Transfers: expedited (up to 4 bytes), normal (in one mailbox) and segmented (longer than the
//! mailbox) upload and download, complete access (a whole record or array at once, subindex 0
//! as 16 bits), and the aborts a real drive gives: object or subindex missing, length wrong,
//! read-only, written outside PRE-OP, subindex 0 not 0 while a mapping is written, toggle bit
//! not alternated, unknown command. SDO Information: the OD list, object and entry
//! descriptions, so `slaveinfo -sdo` lists the dictionary; an OD list longer than the mailbox
//! goes in fragments, the fragments left counting down (a drive's dictionary of hundreds of
//! objects needs several).
//!
//! Allocation happens here (a mailbox message is not on the cyclic path).

use crate::model::DeviceInfo;
use ecsync_wire::AlState;
use ecsync_wire::mailbox::coe::{
    self, COE_HEADER_LEN, CoeService, SDO_INFO_HEADER_LEN, SDO_LEN, SDO_SEGMENT_MIN_DATA, Sdo,
    SdoAbortCode, SdoInfoOpcode, SdoInfoRequest, SdoRequest,
};

/// CiA data types (ETG.1000.6 table 64; BYTE, WORD, DWORD and the bit strings from ETG.1020
/// table 98), the codes SDO Information and the SII's PDO entries carry.
pub mod data_type {
    /// BOOLEAN.
    pub const BOOL: u16 = 0x0001;
    /// INTEGER8.
    pub const INT8: u16 = 0x0002;
    /// INTEGER16.
    pub const INT16: u16 = 0x0003;
    /// INTEGER32.
    pub const INT32: u16 = 0x0004;
    /// UNSIGNED8.
    pub const UINT8: u16 = 0x0005;
    /// UNSIGNED16.
    pub const UINT16: u16 = 0x0006;
    /// UNSIGNED32.
    pub const UINT32: u16 = 0x0007;
    /// REAL32.
    pub const REAL32: u16 = 0x0008;
    /// VISIBLE_STRING.
    pub const VISIBLE_STRING: u16 = 0x0009;
    /// OCTET_STRING.
    pub const OCTET_STRING: u16 = 0x000a;
    /// UNICODE_STRING.
    pub const UNICODE_STRING: u16 = 0x000b;
    /// TIME_OF_DAY.
    pub const TIME_OF_DAY: u16 = 0x000c;
    /// TIME_DIFFERENCE.
    pub const TIME_DIFFERENCE: u16 = 0x000d;
    /// DOMAIN.
    pub const DOMAIN: u16 = 0x000f;
    /// INTEGER24.
    pub const INT24: u16 = 0x0010;
    /// REAL64.
    pub const REAL64: u16 = 0x0011;
    /// INTEGER40.
    pub const INT40: u16 = 0x0012;
    /// INTEGER48.
    pub const INT48: u16 = 0x0013;
    /// INTEGER56.
    pub const INT56: u16 = 0x0014;
    /// INTEGER64.
    pub const INT64: u16 = 0x0015;
    /// UNSIGNED24.
    pub const UINT24: u16 = 0x0016;
    /// UNSIGNED40.
    pub const UINT40: u16 = 0x0018;
    /// UNSIGNED48.
    pub const UINT48: u16 = 0x0019;
    /// UNSIGNED56.
    pub const UINT56: u16 = 0x001a;
    /// UNSIGNED64.
    pub const UINT64: u16 = 0x001b;
    /// BYTE.
    pub const BYTE: u16 = 0x001e;
    /// WORD.
    pub const WORD: u16 = 0x001f;
    /// DWORD.
    pub const DWORD: u16 = 0x0020;
    /// BITARR8.
    pub const BITARR8: u16 = 0x002d;
    /// BITARR16.
    pub const BITARR16: u16 = 0x002e;
    /// BITARR32.
    pub const BITARR32: u16 = 0x002f;
    /// BIT1; BIT2 to BIT8 follow (0x0031-0x0037).
    pub const BIT1: u16 = 0x0030;

    /// The code of an ESI data type name (ETG.2000 writes the IEC 61131 names: BOOL, SINT,
    /// INT, DINT, USINT, UINT, UDINT, REAL, STRING(n), ...), `None` for a name that is not a
    /// base type (a DT... record or array of the dictionary, an enum).
    pub fn from_esi_name(name: &str) -> Option<u16> {
        let name = name.trim();
        if name.starts_with("STRING(") && name.ends_with(')') {
            return Some(VISIBLE_STRING);
        }
        if name.starts_with("OCTET_STRING")
            || (name.starts_with("ARRAY [")
                && (name.ends_with("OF BYTE") || name.ends_with("OF USINT")))
        {
            return Some(OCTET_STRING);
        }
        if name.starts_with("UNICODE_STRING") || name.starts_with("WSTRING") {
            return Some(UNICODE_STRING);
        }
        if let Some(n) = name.strip_prefix("BIT")
            && let Ok(n) = n.parse::<u16>()
            && (1..=8).contains(&n)
        {
            return Some(BIT1 + n - 1);
        }
        Some(match name {
            "BOOL" | "BOOLEAN" => BOOL,
            "SINT" | "INT8" | "INTEGER8" => INT8,
            "INT" | "INT16" | "INTEGER16" => INT16,
            "DINT" | "INT32" | "INTEGER32" => INT32,
            "USINT" | "UINT8" | "UNSIGNED8" => UINT8,
            "UINT" | "UINT16" | "UNSIGNED16" => UINT16,
            "UDINT" | "UINT32" | "UNSIGNED32" => UINT32,
            "REAL" | "REAL32" | "FLOAT" => REAL32,
            "LREAL" | "REAL64" => REAL64,
            "INT24" | "INTEGER24" => INT24,
            "INT40" | "INTEGER40" => INT40,
            "INT48" | "INTEGER48" => INT48,
            "INT56" | "INTEGER56" => INT56,
            "LINT" | "INT64" | "INTEGER64" => INT64,
            "UINT24" | "UNSIGNED24" => UINT24,
            "UINT40" | "UNSIGNED40" => UINT40,
            "UINT48" | "UNSIGNED48" => UINT48,
            "UINT56" | "UNSIGNED56" => UINT56,
            "ULINT" | "UINT64" | "UNSIGNED64" => UINT64,
            "BYTE" => BYTE,
            "WORD" => WORD,
            "DWORD" => DWORD,
            "BITARR8" => BITARR8,
            "BITARR16" => BITARR16,
            "BITARR32" => BITARR32,
            "TIME_OF_DAY" => TIME_OF_DAY,
            "TIME_DIFFERENCE" => TIME_DIFFERENCE,
            "DOMAIN" => DOMAIN,
            _ => return None,
        })
    }

    /// Whether values of this type are read as signed integers (for an ESI's DefaultValue).
    pub fn is_signed(code: u16) -> bool {
        matches!(
            code,
            INT8 | INT16 | INT24 | INT32 | INT40 | INT48 | INT56 | INT64
        )
    }
}

/// Who may write an entry when.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only.
    ReadOnly,
    /// Read and write in every state from PRE-OP on.
    ReadWrite,
    /// Read always, write in PRE-OP only (the PDO mapping and assignment, the sync mode).
    ReadWritePreOp,
}

impl Access {
    /// The ObjAccess bits of an entry description (ETG.1000.6 table 48): read in PRE-OP,
    /// SAFE-OP, OP (bits 0-2), write in PRE-OP, SAFE-OP, OP (bits 3-5).
    pub fn bits(self) -> u16 {
        match self {
            Access::ReadOnly => 0x0007,
            Access::ReadWrite => 0x003f,
            Access::ReadWritePreOp => 0x000f,
        }
    }
}

/// An object's kind (ETG.1000.6 table 62).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ObjectCode {
    /// One value (subindex 0).
    Var = 7,
    /// Entries of one type, subindex 0 their count.
    Array = 8,
    /// Entries of several types, subindex 0 their count.
    Record = 9,
}

/// One entry (subindex) of an object.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// Subindex.
    pub subindex: u8,
    /// Name.
    pub name: String,
    /// CiA data type.
    pub data_type: u16,
    /// Length in bits.
    pub bits: u16,
    /// Access.
    pub access: Access,
    /// The value, little-endian, `bits / 8` bytes (a string: its bytes).
    pub value: Vec<u8>,
    /// Mappable into a PDO (0x0040 RxPDO, 0x0080 TxPDO in the access bits).
    pub pdo_mapping: u16,
}

/// One object of the dictionary.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    /// Index.
    pub index: u16,
    /// Name.
    pub name: String,
    /// Kind.
    pub code: ObjectCode,
    /// Entries in subindex order (a VAR has subindex 0 only; an ARRAY or RECORD has its count
    /// at subindex 0).
    pub entries: Vec<Entry>,
}

impl Object {
    fn entry(&self, sub: u8) -> Option<&Entry> {
        self.entries.iter().find(|e| e.subindex == sub)
    }

    fn entry_mut(&mut self, sub: u8) -> Option<&mut Entry> {
        self.entries.iter_mut().find(|e| e.subindex == sub)
    }

    /// The entries a complete access covers from `sub` (0 or 1): subindex 0 as 16 bits, then
    /// the entries up to the count subindex 0 holds.
    fn complete(&self, sub: u8) -> Vec<u8> {
        let count = self
            .entries
            .first()
            .and_then(|e| e.value.first().copied())
            .unwrap_or(0);
        let mut out = Vec::new();
        for e in &self.entries {
            if e.subindex < sub || e.subindex > count {
                continue;
            }
            if e.subindex == 0 {
                out.extend_from_slice(&[e.value.first().copied().unwrap_or(0), 0]);
            } else {
                out.extend_from_slice(&e.value);
            }
        }
        out
    }
}

fn var(index: u16, name: &str, data_type: u16, access: Access, value: Vec<u8>) -> Object {
    let bits = (value.len() * 8) as u16;
    Object {
        index,
        name: name.to_string(),
        code: ObjectCode::Var,
        entries: vec![Entry {
            subindex: 0,
            name: name.to_string(),
            data_type,
            bits,
            access,
            value,
            pdo_mapping: 0,
        }],
    }
}

fn entry(subindex: u8, name: &str, data_type: u16, access: Access, value: Vec<u8>) -> Entry {
    Entry {
        subindex,
        name: name.to_string(),
        data_type,
        bits: (value.len() * 8) as u16,
        access,
        value,
        pdo_mapping: 0,
    }
}

fn record(index: u16, name: &str, code: ObjectCode, access0: Access, rest: Vec<Entry>) -> Object {
    let count = rest.iter().map(|e| e.subindex).max().unwrap_or(0);
    let mut entries = vec![entry(
        0,
        "Subindex 000",
        data_type::UINT8,
        access0,
        vec![count],
    )];
    entries.extend(rest);
    Object {
        index,
        name: name.to_string(),
        code,
        entries,
    }
}

fn signed_type(bits: u8) -> u16 {
    match bits {
        8 => data_type::INT8,
        16 => data_type::INT16,
        _ => data_type::INT32,
    }
}

/// The SyncManager parameter object 0x1C32 (outputs) or 0x1C33 (inputs) of ETG.1020 (section
/// 12, "Synchronization"): the sync mode is written by the master in PRE-OP, the rest is the
/// drive's.
fn sm_parameters(index: u16, name: &str, cycle_ns: u32) -> Object {
    let rw = Access::ReadWritePreOp;
    let ro = Access::ReadOnly;
    let u16v = |v: u16| v.to_le_bytes().to_vec();
    let u32v = |v: u32| v.to_le_bytes().to_vec();
    record(
        index,
        name,
        ObjectCode::Record,
        Access::ReadOnly,
        vec![
            // 0 free run, 1 synchronous with the SM event, 2 DC SYNC0, 3 DC SYNC1.
            entry(1, "Sync mode", data_type::UINT16, rw, u16v(0)),
            entry(2, "Cycle time", data_type::UINT32, rw, u32v(cycle_ns)),
            entry(3, "Shift time", data_type::UINT32, ro, u32v(0)),
            // Bits 0 free run, 1 SM-synchronous, 2-4 DC (SYNC0, SYNC1, subordinated): free run,
            // SM and DC SYNC0 (0x0007), with the shift settable (bit 5). DC SYNC1 (3) is not
            // among them: a write of 3 to :01 is refused (0x06090030, see `check_sync_mode`).
            entry(
                4,
                "Sync modes supported",
                data_type::UINT16,
                ro,
                u16v(0x0027),
            ),
            // 31.25 us: the virtual drive's application (calc and copy 20 us) keeps up with
            // the fastest cycles fast drives take; SYNC0 faster than this refuses OP (0x0036).
            entry(5, "Minimum cycle time", data_type::UINT32, ro, u32v(31_250)),
            entry(6, "Calc and copy time", data_type::UINT32, ro, u32v(20_000)),
            entry(8, "Get cycle time", data_type::UINT16, rw, u16v(0)),
            entry(9, "Delay time", data_type::UINT32, ro, u32v(0)),
            entry(10, "Sync0 cycle time", data_type::UINT32, rw, u32v(0)),
            entry(11, "SM event missed", data_type::UINT16, ro, u16v(0)),
            entry(12, "Cycle time too small", data_type::UINT16, ro, u16v(0)),
            entry(32, "Sync error", data_type::BOOL, ro, vec![0]),
        ],
    )
}

/// The object dictionary of a device.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectDictionary {
    objects: Vec<Object>,
}

/// CiA 402 device type of a servo drive: profile 402, type 2 (servo) in bits 16-23.
pub const DEVICE_TYPE_SERVO: u32 = 0x0002_0192;

impl ObjectDictionary {
    /// The dictionary of `dev`: the communication objects and an object per PDO entry.
    pub fn for_device(dev: &DeviceInfo) -> Self {
        let rw = Access::ReadWritePreOp;
        let ro = Access::ReadOnly;
        let u32v = |v: u32| v.to_le_bytes().to_vec();
        let mut objects = vec![
            var(
                0x1000,
                "Device type",
                data_type::UINT32,
                ro,
                u32v(DEVICE_TYPE_SERVO),
            ),
            var(
                0x1008,
                "Device name",
                data_type::VISIBLE_STRING,
                ro,
                dev.name.as_bytes().to_vec(),
            ),
            var(
                0x1009,
                "Hardware version",
                data_type::VISIBLE_STRING,
                ro,
                b"1.0".to_vec(),
            ),
            var(
                0x100a,
                "Software version",
                data_type::VISIBLE_STRING,
                ro,
                b"ecsync".to_vec(),
            ),
            record(
                0x1018,
                "Identity",
                ObjectCode::Record,
                ro,
                vec![
                    entry(1, "Vendor ID", data_type::UINT32, ro, u32v(dev.vendor_id)),
                    entry(
                        2,
                        "Product code",
                        data_type::UINT32,
                        ro,
                        u32v(dev.product_code),
                    ),
                    entry(3, "Revision", data_type::UINT32, ro, u32v(dev.revision)),
                    entry(4, "Serial number", data_type::UINT32, ro, u32v(dev.serial)),
                ],
            ),
        ];
        // ETG.1020's error settings: the local error reaction (0: the ESM's default, to
        // SAFE-OP) and the sync error counter limit past which the drive leaves OP with 0x001A
        // (see esc/sync.rs; 0 here: count, do not react, the virtual drive's default).
        objects.push(record(
            0x10f1,
            "Error settings",
            ObjectCode::Record,
            ro,
            vec![
                entry(
                    1,
                    "Local error reaction",
                    data_type::UINT32,
                    Access::ReadWrite,
                    u32v(0),
                ),
                entry(
                    2,
                    "Sync error counter limit",
                    data_type::UINT16,
                    Access::ReadWrite,
                    0u16.to_le_bytes().to_vec(),
                ),
            ],
        ));
        let mapping = |index: u16, name: &str, pdos: &[crate::model::PdoEntry]| {
            record(
                index,
                name,
                ObjectCode::Record,
                rw,
                pdos.iter()
                    .enumerate()
                    .map(|(k, e)| {
                        let v = (u32::from(e.index) << 16)
                            | (u32::from(e.subindex) << 8)
                            | u32::from(e.bits);
                        entry(
                            (k + 1) as u8,
                            &format!("SubIndex {:03}", k + 1),
                            data_type::UINT32,
                            rw,
                            u32v(v),
                        )
                    })
                    .collect(),
            )
        };
        if !dev.outputs.is_empty() {
            objects.push(mapping(0x1600, "RxPDO map", &dev.outputs));
        }
        if !dev.inputs.is_empty() {
            objects.push(mapping(0x1a00, "TxPDO map", &dev.inputs));
        }
        let u8v = |v: u8| vec![v];
        objects.push(record(
            0x1c00,
            "Sync manager type",
            ObjectCode::Array,
            ro,
            vec![
                entry(1, "SubIndex 001", data_type::UINT8, ro, u8v(1)),
                entry(2, "SubIndex 002", data_type::UINT8, ro, u8v(2)),
                entry(3, "SubIndex 003", data_type::UINT8, ro, u8v(3)),
                entry(4, "SubIndex 004", data_type::UINT8, ro, u8v(4)),
            ],
        ));
        let assign = |index: u16, name: &str, pdo: Option<u16>| {
            record(
                index,
                name,
                ObjectCode::Array,
                rw,
                pdo.map(|p| {
                    entry(
                        1,
                        "SubIndex 001",
                        data_type::UINT16,
                        rw,
                        p.to_le_bytes().to_vec(),
                    )
                })
                .into_iter()
                .collect(),
            )
        };
        objects.push(assign(
            0x1c12,
            "RxPDO assign",
            (!dev.outputs.is_empty()).then_some(0x1600),
        ));
        objects.push(assign(
            0x1c13,
            "TxPDO assign",
            (!dev.inputs.is_empty()).then_some(0x1a00),
        ));
        objects.push(sm_parameters(0x1c32, "SM output parameter", 1_000_000));
        objects.push(sm_parameters(0x1c33, "SM input parameter", 1_000_000));
        // The application's objects its PDOs map.
        let mut app: Vec<Object> = Vec::new();
        for (e, mapping) in dev
            .outputs
            .iter()
            .map(|e| (e, 0x0040u16))
            .chain(dev.inputs.iter().map(|e| (e, 0x0080u16)))
        {
            if e.index == 0 || app.iter().any(|o| o.index == e.index) {
                continue;
            }
            let access = if mapping == 0x0040 {
                Access::ReadWrite
            } else {
                Access::ReadOnly
            };
            let dt = match (e.index, e.bits) {
                // The CiA 402 words are unsigned, the positions and velocities signed.
                (0x6040 | 0x6041 | 0x60b8, _) => data_type::UINT16,
                (_, 8) if e.index == 0x6060 || e.index == 0x6061 => data_type::INT8,
                (_, b) => signed_type(b),
            };
            let mut o = var(
                e.index,
                &e.name,
                dt,
                access,
                vec![0; usize::from(e.bits).div_ceil(8)],
            );
            o.entries[0].pdo_mapping = mapping;
            app.push(o);
        }
        objects.extend(app);
        objects.sort_by_key(|o| o.index);
        ObjectDictionary { objects }
    }

    /// A dictionary of `objects` (a device description's), in index order; of two objects with
    /// one index the first is kept.
    pub fn from_objects(mut objects: Vec<Object>) -> Self {
        objects.sort_by_key(|o| o.index);
        objects.dedup_by_key(|o| o.index);
        ObjectDictionary { objects }
    }

    /// This dictionary (a device description's) made fit to serve `dev`: the communication
    /// objects (below 0x2000) that [`ObjectDictionary::for_device`] has and this one lacks are
    /// added (the ESC reads 0x1C32:01, a master 0x1018 and the PDO assignment), and the identity
    /// 0x1018:01-04 is the device's own (its SII's): a real device answers its identity there,
    /// while an ESI's DefaultData for 0x1018 are what its generator wrote (Ingenia's EVS-NET-01
    /// gives product code 0x32 and revision 0 beside a `Type` of 0x03B11002 / 0x00050005).
    pub fn completed_for(mut self, dev: &DeviceInfo) -> Self {
        for o in ObjectDictionary::for_device(dev).objects {
            if o.index < 0x2000 && self.object(o.index).is_none() {
                self.objects.push(o);
            }
        }
        self.objects.sort_by_key(|o| o.index);
        for (sub, v) in [
            (1u8, dev.vendor_id),
            (2, dev.product_code),
            (3, dev.revision),
            (4, dev.serial),
        ] {
            self.set(0x1018, sub, &v.to_le_bytes());
        }
        self
    }

    /// The objects, in index order.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    /// Object `index`.
    pub fn object(&self, index: u16) -> Option<&Object> {
        self.objects.iter().find(|o| o.index == index)
    }

    fn object_mut(&mut self, index: u16) -> Option<&mut Object> {
        self.objects.iter_mut().find(|o| o.index == index)
    }

    /// The value of `index:sub`.
    pub fn read(&self, index: u16, sub: u8) -> Result<Vec<u8>, SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        let e = o.entry(sub).ok_or(SdoAbortCode::NoSubindex)?;
        Ok(e.value.clone())
    }

    /// An unsigned value of up to 32 bits at `index:sub` (0 if absent).
    pub fn read_u32(&self, index: u16, sub: u8) -> u32 {
        self.read(index, sub).map_or(0, |v| {
            let mut b = [0u8; 4];
            let n = v.len().min(4);
            b[..n].copy_from_slice(&v[..n]);
            u32::from_le_bytes(b)
        })
    }

    /// Sets `index:sub` from the drive's side (counters, status), whatever its access.
    pub fn set(&mut self, index: u16, sub: u8, value: &[u8]) {
        if let Some(e) = self.object_mut(index).and_then(|o| o.entry_mut(sub))
            && e.value.len() == value.len()
        {
            e.value.copy_from_slice(value);
        }
    }

    /// The master writes `data` to `index:sub` in state `state`.
    pub fn write(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        let mapping_object = matches!(index, 0x1600..=0x17ff | 0x1a00..=0x1bff | 0x1c12 | 0x1c13);
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        let count = o
            .entries
            .first()
            .and_then(|e| e.value.first().copied())
            .unwrap_or(0);
        let max = o_max_sub(Some(o));
        let e = o.entry(sub).ok_or(SdoAbortCode::NoSubindex)?;
        match e.access {
            Access::ReadOnly => return Err(SdoAbortCode::ReadOnly),
            Access::ReadWritePreOp if state != AlState::PreOp => {
                return Err(SdoAbortCode::DeviceState);
            }
            _ => {}
        }
        let is_string = e.data_type == data_type::VISIBLE_STRING;
        if !is_string && data.len() != e.value.len() {
            return Err(if data.len() > e.value.len() {
                SdoAbortCode::LengthTooHigh
            } else {
                SdoAbortCode::LengthTooLow
            });
        }
        if mapping_object && sub > 0 && count != 0 {
            // ETG.1000.6: a mapping or assignment is changed with subindex 0 set to 0 first.
            return Err(SdoAbortCode::SubindexZeroMustBeZero);
        }
        if mapping_object && sub == 0 && data.first().is_some_and(|&c| c > max) {
            return Err(SdoAbortCode::ValueTooHigh);
        }
        if matches!(index, 0x1c32 | 0x1c33) && sub == 1 && data.len() == 2 {
            self.check_sync_mode(index, u16::from_le_bytes([data[0], data[1]]))?;
        }
        if let Some(e) = self.object_mut(index).and_then(|o| o.entry_mut(sub)) {
            if is_string {
                e.value = data.to_vec();
                e.bits = (data.len() * 8) as u16;
            } else {
                e.value.copy_from_slice(data);
            }
        }
        Ok(())
    }

    /// Whether the drive takes sync mode `mode` in 0x1C32:01 or 0x1C33:01 (`index`), as SSC's
    /// `CheckSyncTypeValue` decides from the supported modes of :04 (ETG.1020, "Sync modes
    /// supported": bit 0 free run, bit 1 synchronous with the SM event, bit 2 DC SYNC0, bit 3
    /// DC SYNC1): free run always; 1 (SM-synchronous) on 0x1C32 with outputs mapped, on 0x1C33
    /// of an input-only device; 0x22 (synchronous with SM2) on 0x1C33 with outputs mapped; 2
    /// and 3 where :04 has their bit. Any other value: 0x06090030, value range exceeded
    /// (SSC's ABORTIDX_VALUE_EXCEEDED). A dictionary without :04 (a device description that
    /// leaves it out) is not checked.
    fn check_sync_mode(&self, index: u16, mode: u16) -> Result<(), SdoAbortCode> {
        let Ok(supported) = self.read(index, 4) else {
            return Ok(());
        };
        let bits = supported.first().copied().unwrap_or(0);
        let outputs = !self.assigned_entries(0x1c12).is_empty();
        let inputs = !self.assigned_entries(0x1c13).is_empty();
        let ok = match mode {
            0 => true,
            1 if index == 0x1c32 => outputs && bits & 0x02 != 0,
            1 => !outputs && inputs && bits & 0x02 != 0,
            0x22 => index == 0x1c33 && outputs && bits & 0x02 != 0,
            2 => bits & 0x04 != 0,
            3 => bits & 0x08 != 0,
            _ => false,
        };
        if ok {
            Ok(())
        } else {
            Err(SdoAbortCode::ValueRange)
        }
    }

    /// A write of one entry, or with `complete_access` of the object from `sub`.
    pub fn write_access(
        &mut self,
        index: u16,
        sub: u8,
        complete_access: bool,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        if complete_access {
            self.write_complete(index, sub, data, state)
        } else {
            self.write(index, sub, data, state)
        }
    }

    /// A complete access read from `sub` (0 or 1).
    pub fn read_complete(&self, index: u16, sub: u8) -> Result<Vec<u8>, SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        if o.code == ObjectCode::Var || sub > 1 {
            return Err(SdoAbortCode::UnsupportedAccess);
        }
        Ok(o.complete(sub))
    }

    /// A complete access write from `sub` (0 or 1): subindex 0 (16 bits) and the entries up
    /// to the count it gives, each as long as it is.
    pub fn write_complete(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        if o.code == ObjectCode::Var || sub > 1 {
            return Err(SdoAbortCode::UnsupportedAccess);
        }
        let mut at = 0usize;
        let mut writes: Vec<(u8, Vec<u8>)> = Vec::new();
        let count = if sub == 0 {
            let Some(&c) = data.first() else {
                return Err(SdoAbortCode::LengthTooLow);
            };
            at = 2;
            c
        } else {
            o.entries
                .first()
                .and_then(|e| e.value.first().copied())
                .unwrap_or(0)
        };
        for s in 1..=count {
            let e = o.entry(s).ok_or(SdoAbortCode::ValueTooHigh)?;
            let n = e.value.len();
            let Some(v) = data.get(at..at + n) else {
                return Err(SdoAbortCode::LengthTooLow);
            };
            writes.push((s, v.to_vec()));
            at += n;
        }
        if at != data.len() {
            return Err(SdoAbortCode::LengthTooHigh);
        }
        // Subindex 0 to 0, the entries, then the count: the order a master writes them in.
        if sub == 0 {
            self.write(index, 0, &[0], state)?;
        }
        for (s, v) in &writes {
            self.write(index, *s, v, state)?;
        }
        if sub == 0 {
            self.write(index, 0, &[count], state)?;
        }
        Ok(())
    }

    /// The PDO entries (index, subindex, bits) the assignment `assign` (0x1C12 or 0x1C13)
    /// and the mappings it names lay out, in order.
    pub fn assigned_entries(&self, assign: u16) -> Vec<(u16, u8, u8)> {
        let mut out = Vec::new();
        let n = self.read_u32(assign, 0) as u8;
        for s in 1..=n {
            let pdo = self.read_u32(assign, s) as u16;
            let m = self.read_u32(pdo, 0) as u8;
            for k in 1..=m {
                let v = self.read_u32(pdo, k);
                out.push(((v >> 16) as u16, (v >> 8) as u8, v as u8));
            }
        }
        out
    }

    /// Adds `object`, in index order, in place of one with the same index (a device
    /// description's own objects over the communication objects [`Self::for_device`] makes).
    pub fn insert(&mut self, object: Object) {
        match self
            .objects
            .binary_search_by_key(&object.index, |o| o.index)
        {
            Ok(i) => self.objects[i] = object,
            Err(i) => self.objects.insert(i, object),
        }
    }
}

fn o_max_sub(o: Option<&Object>) -> u8 {
    o.and_then(|o| o.entries.iter().map(|e| e.subindex).max())
        .unwrap_or(0)
}

/// A transfer in progress over several mailbox messages.
#[derive(Debug, Clone, PartialEq)]
enum Transfer {
    /// Upload segments still to send.
    Upload {
        data: Vec<u8>,
        at: usize,
        toggle: bool,
    },
    /// Download segments still to come.
    Download {
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: usize,
        data: Vec<u8>,
        toggle: bool,
    },
}

/// The SDO server of one drive: its dictionary and the transfer in progress.
#[derive(Debug, Clone, PartialEq)]
pub struct SdoServer {
    /// The dictionary.
    pub od: ObjectDictionary,
    transfer: Option<Transfer>,
    /// The fragments of an SDO Information response still to send, in order (see
    /// [`SdoServer::next_fragment`]).
    fragments: std::collections::VecDeque<Vec<u8>>,
    /// [`SdoServer::set_request_room`].
    request_room: Option<usize>,
}

impl SdoServer {
    /// A server for `dev`: on the dictionary its description gives, completed
    /// ([`ObjectDictionary::completed_for`]), else on the one built for it.
    pub fn new(dev: &DeviceInfo) -> Self {
        let od = match &dev.dictionary {
            Some(d) => ObjectDictionary::clone(d).completed_for(dev),
            None => ObjectDictionary::for_device(dev),
        };
        SdoServer {
            od,
            transfer: None,
            fragments: std::collections::VecDeque::new(),
            request_room: None,
        }
    }

    /// Answers the CoE message `req` (the mailbox payload) in `state`, with at most `room`
    /// bytes of CoE data (the mailbox in's size less its header). `None`: a message that gets
    /// no answer (an abort from the master, an emergency). An SDO Information answer longer
    /// than `room` comes as its first fragment; [`SdoServer::next_fragment`] gives the others.
    pub fn handle(
        &mut self,
        req: &[u8],
        state: AlState,
        room: usize,
    ) -> Result<Option<Vec<u8>>, MailboxFault> {
        // A new message: what was left of an earlier answer is not sent any more.
        self.fragments.clear();
        let c = coe::Coe::new_checked(req).map_err(|_| MailboxFault::SizeTooShort)?;
        // SSC's `COE_ServiceInd`: the two services a slave serves, the others a master has no
        // business sending (0x04), and numbers that are no service at all (0x05).
        match c.service() {
            Ok(CoeService::SdoRequest) => self.sdo(c.payload(), state, room).map(Some),
            Ok(CoeService::SdoInformation) => self.sdo_info(c.payload(), room).map(Some),
            Ok(_) => Err(MailboxFault::ServiceNotSupported),
            Err(_) => Err(MailboxFault::InvalidHeader),
        }
    }

    /// The size of the mailbox the master writes to, less its header (SM0's length - 6): an
    /// SDO download longer than it fits is segmented, and its initiate fills the mailbox
    /// (SSC checks this; `None`, the default: not checked).
    pub fn set_request_room(&mut self, room: usize) {
        self.request_room = Some(room);
    }

    /// SSC's length checks of an initiate request (`SDOS_SdoInd`): `p` is the SDO part, so
    /// the mailbox length is `p.len() + 2`.
    fn check_sdo_length(&self, req: &SdoRequest, p: &[u8]) -> Result<(), MailboxFault> {
        let length = COE_HEADER_LEN + p.len();
        // "a SDO Upload request has always a fixed size (2 Byte CoE-Header plus 8 Byte
        // SDO-Header)", and so has an expedited download.
        let fixed = COE_HEADER_LEN + SDO_LEN;
        match *req {
            SdoRequest::InitiateUpload { .. }
            | SdoRequest::InitiateDownload {
                expedited: true, ..
            } if length != fixed => Err(MailboxFault::InvalidSize),
            SdoRequest::InitiateDownload {
                expedited: false,
                size: Some(size),
                ..
            } => {
                let size = size as usize;
                let ok = match self.request_room {
                    // Longer than the mailbox: segmented, the initiate fills the mailbox.
                    Some(room) if fixed + size > room => length == room,
                    // In one message: exactly the header and the data.
                    _ => length == fixed + size,
                };
                if ok {
                    Ok(())
                } else {
                    Err(MailboxFault::InvalidSize)
                }
            }
            _ => Ok(()),
        }
    }

    fn sdo(&mut self, p: &[u8], state: AlState, room: usize) -> Result<Vec<u8>, MailboxFault> {
        let s = Sdo::new_checked(p).map_err(|_| MailboxFault::SizeTooShort)?;
        let (index, sub) = (s.index().unwrap_or(0), s.subindex().unwrap_or(0));
        let abort = |code: SdoAbortCode| {
            let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
            let _ = coe::emit_abort(&mut out, CoeService::SdoRequest, index, sub, code);
            out
        };
        let req = match s.request() {
            Ok(r) => r,
            // An initiate (or abort) shorter than its 8 bytes: its length is not 10 (SSC).
            Err(ecsync_wire::WireError::Truncated { .. }) => {
                return Err(MailboxFault::InvalidSize);
            }
            Err(_) => {
                self.transfer = None;
                return Ok(abort(SdoAbortCode::UnknownCommand));
            }
        };
        self.check_sdo_length(&req, p)?;
        Ok(match self.sdo_request(req, &s, state, room) {
            Ok(out) => out,
            Err((i, si, code)) => {
                self.transfer = None;
                let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
                let _ = coe::emit_abort(&mut out, CoeService::SdoRequest, i, si, code);
                out
            }
        })
    }

    fn sdo_request<T: AsRef<[u8]>>(
        &mut self,
        req: SdoRequest,
        s: &Sdo<T>,
        state: AlState,
        room: usize,
    ) -> Result<Vec<u8>, (u16, u8, SdoAbortCode)> {
        let response = |cmd: u8, index: u16, sub: u8, data4: [u8; 4], rest: &[u8]| {
            let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
            coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
            out[2] = cmd;
            out[3..5].copy_from_slice(&index.to_le_bytes());
            out[5] = sub;
            out[6..10].copy_from_slice(&data4);
            out.extend_from_slice(rest);
            out
        };
        match req {
            SdoRequest::InitiateUpload {
                index,
                subindex,
                complete_access,
            } => {
                self.transfer = None;
                let data = if complete_access {
                    self.od.read_complete(index, subindex)
                } else {
                    self.od.read(index, subindex)
                }
                .map_err(|c| (index, subindex, c))?;
                if data.len() <= 4 && !complete_access {
                    let mut d = [0u8; 4];
                    d[..data.len()].copy_from_slice(&data);
                    let cmd = coe::upload_expedited_command(data.len().max(1), false);
                    return Ok(response(cmd, index, subindex, d, &[]));
                }
                let size = (data.len() as u32).to_le_bytes();
                let fits = room.saturating_sub(COE_HEADER_LEN + SDO_LEN);
                let cmd = coe::upload_normal_command(complete_access);
                if data.len() <= fits {
                    return Ok(response(cmd, index, subindex, size, &data));
                }
                // Segmented: the first part in the initiate response, the rest in segments.
                let first = data[..fits].to_vec();
                self.transfer = Some(Transfer::Upload {
                    data,
                    at: fits,
                    toggle: false,
                });
                Ok(response(cmd, index, subindex, size, &first))
            }
            SdoRequest::UploadSegment { toggle } => {
                let Some(Transfer::Upload {
                    data,
                    at,
                    toggle: expected,
                }) = self.transfer.as_mut()
                else {
                    return Err((0, 0, SdoAbortCode::UnknownCommand));
                };
                if toggle != *expected {
                    return Err((0, 0, SdoAbortCode::ToggleBit));
                }
                let fits = room
                    .saturating_sub(COE_HEADER_LEN + 1)
                    .max(SDO_SEGMENT_MIN_DATA);
                let n = (data.len() - *at).min(fits);
                let last = *at + n >= data.len();
                let mut out = vec![0u8; COE_HEADER_LEN + 1];
                coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
                out[2] = coe::upload_segment_command(toggle, last, n);
                out.extend_from_slice(&data[*at..*at + n]);
                if n < SDO_SEGMENT_MIN_DATA {
                    out.resize(COE_HEADER_LEN + 1 + SDO_SEGMENT_MIN_DATA, 0);
                }
                *at += n;
                *expected = !toggle;
                if last {
                    self.transfer = None;
                }
                Ok(out)
            }
            SdoRequest::InitiateDownload {
                index,
                subindex,
                complete_access,
                expedited,
                size,
            } => {
                self.transfer = None;
                let d4 = s.data4().unwrap_or([0; 4]);
                if expedited {
                    let n = size.unwrap_or(4) as usize;
                    let v = &d4[..n.min(4)];
                    let r = if complete_access {
                        self.od.write_complete(index, subindex, v, state)
                    } else {
                        // An unsized expedited write takes the entry's own length.
                        let want = self
                            .od
                            .read(index, subindex)
                            .map_err(|c| (index, subindex, c))?
                            .len();
                        let v = if size.is_none() {
                            &d4[..want.min(4)]
                        } else {
                            v
                        };
                        self.od.write(index, subindex, v, state)
                    };
                    r.map_err(|c| (index, subindex, c))?;
                    return Ok(response(
                        coe::SDO_DOWNLOAD_RESPONSE,
                        index,
                        subindex,
                        [0; 4],
                        &[],
                    ));
                }
                let total = size.unwrap_or(0) as usize;
                let got = s.rest();
                if got.len() >= total {
                    self.od
                        .write_access(index, subindex, complete_access, &got[..total], state)
                        .map_err(|c| (index, subindex, c))?;
                } else {
                    self.transfer = Some(Transfer::Download {
                        index,
                        subindex,
                        complete_access,
                        size: total,
                        data: got.to_vec(),
                        toggle: false,
                    });
                }
                Ok(response(
                    coe::SDO_DOWNLOAD_RESPONSE,
                    index,
                    subindex,
                    [0; 4],
                    &[],
                ))
            }
            SdoRequest::DownloadSegment {
                toggle,
                last,
                short_size,
            } => {
                let Some(Transfer::Download {
                    index,
                    subindex,
                    complete_access,
                    size,
                    data,
                    toggle: expected,
                }) = self.transfer.as_mut()
                else {
                    return Err((0, 0, SdoAbortCode::UnknownCommand));
                };
                let (index, subindex) = (*index, *subindex);
                if toggle != *expected {
                    return Err((index, subindex, SdoAbortCode::ToggleBit));
                }
                let seg = s.segment_data();
                let n = match short_size {
                    Some(n) => usize::from(n).min(seg.len()),
                    None => seg.len(),
                };
                data.extend_from_slice(&seg[..n]);
                *expected = !toggle;
                let mut out = vec![0u8; COE_HEADER_LEN + 1];
                coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
                out[2] = coe::download_segment_response(toggle);
                out.resize(COE_HEADER_LEN + SDO_LEN, 0);
                if last {
                    let (ca, size) = (*complete_access, *size);
                    let v = std::mem::take(data);
                    self.transfer = None;
                    if v.len() < size {
                        return Err((index, subindex, SdoAbortCode::LengthTooLow));
                    }
                    self.od
                        .write_access(index, subindex, ca, &v[..size], state)
                        .map_err(|c| (index, subindex, c))?;
                }
                Ok(out)
            }
            SdoRequest::Abort { .. } => {
                self.transfer = None;
                Err((0, 0, SdoAbortCode::General))
            }
        }
    }

    /// An SDO Information request's answer (an SDO Info error for what it cannot answer), or
    /// the mailbox error of one too short for its opcode.
    fn sdo_info(&mut self, p: &[u8], room: usize) -> Result<Vec<u8>, MailboxFault> {
        // SSC's `SDOS_SdoInfoInd` checks the length first, against the opcode's fixed part:
        // an entry description request has 10 bytes (CoE and SDO Information headers, index,
        // subindex, value info), the others at least 8 (the headers and an index or list type).
        let need = match p.first().map(|&op| op & 0x7f) {
            Some(5) => 10,
            _ => 8,
        };
        if COE_HEADER_LEN + p.len() < need {
            return Err(MailboxFault::SizeTooShort);
        }
        Ok(self.sdo_info_answer(p, room))
    }

    fn sdo_info_answer(&mut self, p: &[u8], room: usize) -> Vec<u8> {
        let mut out = vec![0u8; COE_HEADER_LEN + SDO_INFO_HEADER_LEN];
        coe::emit_coe_header(&mut out, CoeService::SdoInformation, 0);
        let error = |code: SdoAbortCode| {
            let mut e = vec![0u8; COE_HEADER_LEN + SDO_INFO_HEADER_LEN];
            coe::emit_coe_header(&mut e, CoeService::SdoInformation, 0);
            coe::emit_sdo_info_header(&mut e[2..], SdoInfoOpcode::Error, false, 0);
            e.extend_from_slice(&code.code().to_le_bytes());
            e
        };
        // An opcode that is no request (a response's, the error's, an unknown one): SSC
        // answers ABORTIDX_COMMAND_SPECIFIER_UNKNOWN, 0x05040001, in an SDO Info error.
        let Ok(req) = coe::sdo_info_request(p) else {
            return error(SdoAbortCode::UnknownCommand);
        };
        match req {
            SdoInfoRequest::GetOdList { list_type } => {
                let indices: Vec<u16> = match list_type {
                    0 => {
                        // The number of objects of each list type 1-5.
                        let all = self.od.objects.len() as u16;
                        let rx = self.pdo_mappable(0x0040);
                        let tx = self.pdo_mappable(0x0080);
                        vec![all, rx, tx, 0, 0]
                    }
                    1 => self.od.objects.iter().map(|o| o.index).collect(),
                    2 | 3 => {
                        let bit = if list_type == 2 { 0x0040 } else { 0x0080 };
                        self.od
                            .objects
                            .iter()
                            .filter(|o| o.entries.iter().any(|e| e.pdo_mapping & bit != 0))
                            .map(|o| o.index)
                            .collect()
                    }
                    4 | 5 => Vec::new(),
                    _ => return error(SdoAbortCode::UnsupportedAccess),
                };
                // The list type, then the indices; in fragments when longer than the mailbox.
                let mut data = Vec::with_capacity(2 + 2 * indices.len());
                data.extend_from_slice(&list_type.to_le_bytes());
                for i in &indices {
                    data.extend_from_slice(&i.to_le_bytes());
                }
                self.fragmented(SdoInfoOpcode::GetOdListResponse, &data, room)
            }
            // "SDO Info access is only allowed for objects >= 0x1000" (SSC): below are the
            // data type definitions, which this dictionary does not describe.
            SdoInfoRequest::GetObjectDescription { index }
            | SdoInfoRequest::GetEntryDescription { index, .. }
                if index < 0x1000 =>
            {
                error(SdoAbortCode::UnsupportedAccess)
            }
            SdoInfoRequest::GetObjectDescription { index } => {
                let Some(o) = self.od.object(index) else {
                    return error(SdoAbortCode::NoObject);
                };
                coe::emit_sdo_info_header(
                    &mut out[2..],
                    SdoInfoOpcode::GetObjectDescriptionResponse,
                    false,
                    0,
                );
                let dt = o.entries.last().map_or(0, |e| e.data_type);
                out.extend_from_slice(&index.to_le_bytes());
                out.extend_from_slice(&dt.to_le_bytes());
                out.push(o_max_sub(Some(o)));
                out.push(o.code as u8);
                let name = o.name.as_bytes();
                let n = name.len().min(room.saturating_sub(out.len()));
                out.extend_from_slice(&name[..n]);
                out
            }
            SdoInfoRequest::GetEntryDescription {
                index,
                subindex,
                value_info,
            } => {
                let Some(o) = self.od.object(index) else {
                    return error(SdoAbortCode::NoObject);
                };
                let Some(e) = o.entry(subindex) else {
                    return error(SdoAbortCode::NoSubindex);
                };
                coe::emit_sdo_info_header(
                    &mut out[2..],
                    SdoInfoOpcode::GetEntryDescriptionResponse,
                    false,
                    0,
                );
                out.extend_from_slice(&index.to_le_bytes());
                out.push(subindex);
                // Only the description is given (no unit, default, minimum or maximum),
                // whatever `value_info` asked for.
                let _ = value_info;
                out.push(0);
                out.extend_from_slice(&e.data_type.to_le_bytes());
                out.extend_from_slice(&e.bits.to_le_bytes());
                out.extend_from_slice(&(e.access.bits() | e.pdo_mapping).to_le_bytes());
                let name = e.name.as_bytes();
                let n = name.len().min(room.saturating_sub(out.len()));
                out.extend_from_slice(&name[..n]);
                out
            }
        }
    }

    /// The SDO Information response `opcode` with `data` (what follows the SDO Information
    /// header), in as many fragments as `room` bytes of CoE per mailbox need (ETG.1000.6
    /// section 5.6.3): each fragment has the CoE and SDO Information headers, the incomplete
    /// bit on all but the last and the fragments still to come after it (counting down to 0),
    /// and the data goes on from one to the next. Returns the first; the others wait for
    /// [`SdoServer::next_fragment`]. Each fragment carries an even number of data bytes: SOEM
    /// (`ec_readODlist`) takes an OD list fragment as whole 16-bit indices.
    fn fragmented(&mut self, opcode: SdoInfoOpcode, data: &[u8], room: usize) -> Vec<u8> {
        let head = COE_HEADER_LEN + SDO_INFO_HEADER_LEN;
        // At least one index per fragment, whatever the mailbox.
        let per_fragment = (room.saturating_sub(head) & !1).max(2);
        let chunks: Vec<&[u8]> = if data.is_empty() {
            vec![data]
        } else {
            data.chunks(per_fragment).collect()
        };
        let n = chunks.len();
        let mut all = chunks.into_iter().enumerate().map(|(k, c)| {
            let mut out = vec![0u8; head];
            coe::emit_coe_header(&mut out, CoeService::SdoInformation, 0);
            let left = (n - 1 - k) as u16;
            coe::emit_sdo_info_header(&mut out[2..], opcode, left > 0, left);
            out.extend_from_slice(c);
            out
        });
        let first = all.next().unwrap_or_default();
        self.fragments = all.collect();
        first
    }

    /// The next fragment of the SDO Information response being sent, once the master has read
    /// the one before; `None` when it was the last (or the answer was not fragmented).
    pub fn next_fragment(&mut self) -> Option<Vec<u8>> {
        self.fragments.pop_front()
    }

    fn pdo_mappable(&self, bit: u16) -> u16 {
        self.od
            .objects
            .iter()
            .filter(|o| o.entries.iter().any(|e| e.pdo_mapping & bit != 0))
            .count() as u16
    }
}

/// Why a mailbox message gets a mailbox error (ETG.1000.4 table 30, SSC's `MBXERR_*`) instead
/// of a CoE answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MailboxFault {
    /// Too short for what it carries (0x06): a CoE message without its CoE header (this
    /// drive's reading: SSC reads the header past the length), an SDO Information request
    /// shorter than its opcode's fixed part (SSC, `SDOS_SdoInfoInd`).
    SizeTooShort,
    /// A CoE service a slave does not take from a master (0x04): emergency, SDO response, the
    /// PDO services (SSC, `COE_ServiceInd`).
    ServiceNotSupported,
    /// A CoE service number no service has (0x05: 0, 9-15; SSC, `COE_ServiceInd`).
    InvalidHeader,
    /// A length the SDO service does not have (0x08): an initiate upload or expedited
    /// download whose mailbox length is not 10, a normal download whose length disagrees with
    /// its complete size (SSC, `SDOS_SdoInd`).
    InvalidSize,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn server() -> SdoServer {
        SdoServer::new(&DeviceInfo::servo_drive(0x1234_5678))
    }

    /// A CoE SDO request: CoE header (service 2) and the bytes.
    fn sdo(bytes: &[u8]) -> Vec<u8> {
        let mut v = vec![0x00, 0x20];
        v.extend_from_slice(bytes);
        v
    }

    fn ask(s: &mut SdoServer, bytes: &[u8], state: AlState) -> Vec<u8> {
        s.handle(&sdo(bytes), state, 122).unwrap().unwrap()
    }

    #[test]
    fn expedited_uploads_answer_the_identity_and_the_sync_mode() {
        let mut s = server();
        // 0x1018:01 vendor ID, 4 bytes: 0x43.
        let r = ask(&mut s, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(r, [0x00, 0x30, 0x43, 0x18, 0x10, 1, 0x5c, 0x0e, 0, 0]);
        // 0x1C32:01 sync mode, 2 bytes: 0x4B, free run.
        let r = ask(&mut s, &[0x40, 0x32, 0x1c, 1, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(r, [0x00, 0x30, 0x4b, 0x32, 0x1c, 1, 0, 0, 0, 0]);
        // 0x1C32:0B, the SM-event-missed counter.
        let r = ask(&mut s, &[0x40, 0x32, 0x1c, 0x0b, 0, 0, 0, 0], AlState::Op);
        assert_eq!(&r[2..6], &[0x4b, 0x32, 0x1c, 0x0b]);
    }

    #[test]
    fn the_sync_mode_is_written_in_pre_op_and_refused_after() {
        let mut s = server();
        // Expedited download of 2 bytes (0x2B): DC SYNC0.
        let r = ask(&mut s, &[0x2b, 0x32, 0x1c, 1, 2, 0, 0, 0], AlState::PreOp);
        assert_eq!(r, [0x00, 0x30, 0x60, 0x32, 0x1c, 1, 0, 0, 0, 0]);
        assert_eq!(s.od.read_u32(0x1c32, 1), 2);
        let r = ask(&mut s, &[0x2b, 0x32, 0x1c, 1, 0, 0, 0, 0], AlState::SafeOp);
        assert_eq!(
            r,
            [0x00, 0x20, 0x80, 0x32, 0x1c, 1, 0x22, 0x00, 0x00, 0x08],
            "abort 0x08000022"
        );
        assert_eq!(s.od.read_u32(0x1c32, 1), 2);
    }

    #[test]
    fn aborts_name_what_is_wrong() {
        let mut s = server();
        let code = |r: &[u8]| u32::from_le_bytes([r[6], r[7], r[8], r[9]]);
        let r = ask(&mut s, &[0x40, 0x00, 0x20, 0, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!((r[2], code(&r)), (0x80, 0x0602_0000), "no object");
        let r = ask(&mut s, &[0x40, 0x18, 0x10, 9, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(code(&r), 0x0609_0011, "no subindex");
        let r = ask(&mut s, &[0x23, 0x18, 0x10, 1, 1, 2, 3, 4], AlState::PreOp);
        assert_eq!(code(&r), 0x0601_0002, "read only");
        // 4 bytes into the 2-byte sync mode.
        let r = ask(&mut s, &[0x23, 0x32, 0x1c, 1, 1, 0, 0, 0], AlState::PreOp);
        assert_eq!(code(&r), 0x0607_0012, "too long");
        // A mapping entry while subindex 0 is not 0.
        let r = ask(
            &mut s,
            &[0x23, 0x00, 0x16, 1, 0x10, 0, 0x40, 0x60],
            AlState::PreOp,
        );
        assert_eq!(code(&r), 0x0601_0003, "subindex 0 first");
        let r = ask(&mut s, &[0xe0, 0, 0, 0, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(code(&r), 0x0504_0001, "unknown command");
        let r = ask(&mut s, &[0x60, 0, 0, 0, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(code(&r), 0x0504_0001, "a segment with no transfer");
    }

    #[test]
    fn the_pdo_assignment_reads_with_complete_access_and_is_rewritten_in_pre_op() {
        let mut s = server();
        // Complete access upload of 0x1C12 (0x50): subindex 0 as 16 bits, then 0x1600.
        let r = ask(&mut s, &[0x50, 0x12, 0x1c, 0, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(
            &r[2..],
            &[0x51, 0x12, 0x1c, 0, 4, 0, 0, 0, 1, 0, 0x00, 0x16]
        );
        // The mapping rewritten the way a master does: 0 entries, two entries, count 2.
        for (sub, v) in [
            (0u8, vec![0u8]),
            (1, 0x6040_0010u32.to_le_bytes().to_vec()),
            (2, 0x607a_0020u32.to_le_bytes().to_vec()),
            (0, vec![2]),
        ] {
            let mut req = vec![0x23 | if v.len() == 1 { 0x0c } else { 0 }, 0x00, 0x16, sub];
            let mut d = v.clone();
            d.resize(4, 0);
            req.extend_from_slice(&d);
            let r = ask(&mut s, &req, AlState::PreOp);
            assert_eq!(r[2], 0x60, "{sub}: {r:02x?}");
        }
        assert_eq!(
            s.od.assigned_entries(0x1c12),
            [(0x6040, 0, 16), (0x607a, 0, 32)]
        );
    }

    #[test]
    fn a_long_object_uploads_in_segments_with_the_toggle() {
        let mut s = server();
        // Room for 20 bytes of CoE: the 26-byte device name does not fit.
        let ask_small =
            |s: &mut SdoServer, b: &[u8]| s.handle(&sdo(b), AlState::PreOp, 20).unwrap().unwrap();
        let r = ask_small(&mut s, &[0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
        let name = b"ecsync virtual servo drive";
        assert_eq!(r[2], 0x41);
        assert_eq!(
            u32::from_le_bytes([r[6], r[7], r[8], r[9]]),
            name.len() as u32
        );
        let mut got = r[10..].to_vec();
        let mut toggle = false;
        loop {
            let r = ask_small(
                &mut s,
                &[0x60 | (u8::from(toggle) << 4), 0, 0, 0, 0, 0, 0, 0],
            );
            assert_eq!(r[2] & 0x10 != 0, toggle, "toggle echoed");
            let short = usize::from((r[2] >> 1) & 7);
            let n = if short == 0 { r.len() - 3 } else { 7 - short };
            got.extend_from_slice(&r[3..3 + n]);
            toggle = !toggle;
            if r[2] & 1 != 0 {
                break;
            }
        }
        assert_eq!(got, name);
        // A wrong toggle aborts with 0x05030000.
        let _ = ask_small(&mut s, &[0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
        let r = ask_small(&mut s, &[0x70, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(u32::from_le_bytes([r[6], r[7], r[8], r[9]]), 0x0503_0000);
    }

    #[test]
    fn sdo_information_lists_and_describes_the_dictionary() {
        let mut s = server();
        let info = |s: &mut SdoServer, b: &[u8]| {
            let mut v = vec![0x00, 0x80];
            v.extend_from_slice(b);
            s.handle(&v, AlState::PreOp, 122).unwrap().unwrap()
        };
        let r = info(&mut s, &[0x01, 0, 0, 0, 0x01, 0x00]);
        assert_eq!(r[2] & 0x7f, 0x02);
        let list: Vec<u16> = r[8..]
            .chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(&list[..5], &[0x1000, 0x1008, 0x1009, 0x100a, 0x1018]);
        assert!(
            list.contains(&0x1c32) && list.contains(&0x6064),
            "{list:04x?}"
        );
        let r = info(&mut s, &[0x03, 0, 0, 0, 0x18, 0x10]);
        assert_eq!(&r[6..12], &[0x18, 0x10, 0x07, 0x00, 4, 9]);
        assert_eq!(&r[12..], b"Identity");
        let r = info(&mut s, &[0x05, 0, 0, 0, 0x18, 0x10, 0x02, 0x00]);
        // Index, subindex, value info, UNSIGNED32, 32 bits, read-only, the name.
        assert_eq!(&r[6..16], &[0x18, 0x10, 2, 0, 0x07, 0, 32, 0, 0x07, 0]);
        assert_eq!(&r[16..], b"Product code");
        let r = info(&mut s, &[0x03, 0, 0, 0, 0x00, 0x20]);
        assert_eq!(r[2], 0x07, "SDO Info error");
        assert_eq!(u32::from_le_bytes([r[6], r[7], r[8], r[9]]), 0x0602_0000);
    }

    /// A dictionary of `extra` more objects than the servo drive's (0x2000, 0x2001, ...).
    fn big_server(extra: u16) -> SdoServer {
        let mut s = server();
        for k in 0..extra {
            s.od.insert(var(
                0x2000 + k,
                "Manufacturer object",
                data_type::UINT32,
                Access::ReadWrite,
                vec![0; 4],
            ));
        }
        s
    }

    #[test]
    fn a_long_od_list_comes_in_fragments_counting_down() {
        // 100 objects more than fit a 128-byte mailbox (122 bytes of CoE: 116 of data, 58
        // indices a fragment).
        let mut s = big_server(100);
        let all: Vec<u16> = s.od.objects().iter().map(|o| o.index).collect();
        let data_len = 2 + 2 * all.len();
        let want_fragments = data_len.div_ceil(116);
        assert!(want_fragments >= 3, "{} objects", all.len());
        let req = [0x00, 0x80, 0x01, 0, 0, 0, 0x01, 0x00];
        let mut got = Vec::new();
        let mut fragment = s.handle(&req, AlState::PreOp, 122).unwrap();
        let mut k = 0;
        while let Some(f) = fragment {
            assert!(f.len() <= 122, "fragment {k}: {} bytes", f.len());
            // CoE header: SDO Information; the opcode 0x02 with the incomplete bit on all but
            // the last; the fragments still to come.
            assert_eq!(&f[..2], &[0x00, 0x80]);
            let left = usize::from(u16::from_le_bytes([f[4], f[5]]));
            assert_eq!(left, want_fragments - 1 - k, "fragment {k}");
            assert_eq!(f[2], 0x02 | if left > 0 { 0x80 } else { 0 });
            assert_eq!((f.len() - 6) % 2, 0, "whole indices");
            got.extend_from_slice(&f[6..]);
            k += 1;
            fragment = s.next_fragment();
        }
        assert_eq!(k, want_fragments);
        // The list type, then every index once, in order.
        assert_eq!(&got[..2], &[0x01, 0x00]);
        let indices: Vec<u16> = got[2..]
            .chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(indices, all);
    }

    #[test]
    fn a_new_request_drops_the_fragments_left_and_a_short_list_is_one_message() {
        let mut s = big_server(100);
        let req = [0x00, 0x80, 0x01, 0, 0, 0, 0x01, 0x00];
        let first = s.handle(&req, AlState::PreOp, 122).unwrap().unwrap();
        assert_eq!(first[2], 0x82, "incomplete");
        let r = ask(&mut s, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0], AlState::PreOp);
        assert_eq!(r[2], 0x43);
        assert_eq!(s.next_fragment(), None, "the SDO answer ended the OD list");
        // The servo drive's own list fits: one message, no fragment left.
        let mut s = server();
        let r = s.handle(&req, AlState::PreOp, 122).unwrap().unwrap();
        assert_eq!((r[2], &r[4..6]), (0x02, &[0u8, 0][..]));
        assert_eq!(s.next_fragment(), None);
    }
}
