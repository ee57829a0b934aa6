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

mod device;
mod dictionary;
mod eoe;
mod server;

pub use dictionary::{DEVICE_TYPE_SERVO, ObjectDictionary};
pub use eoe::EoeServer;
pub use server::{MailboxFault, SdoServer};

/// CiA data types: the wire crate's codes ([`ecsync_wire::data_type`]: those SDO Information
/// and the SII's PDO entries carry), and the names an ESI file gives them.
pub mod data_type {
    pub use ecsync_wire::data_type::*;

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

#[cfg(test)]
mod tests;
