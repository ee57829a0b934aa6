//! The Slave Information Interface (SII) EEPROM image: word layout, checksum and categories
//! (ETG.1000.6 table "Slave Information Interface area", ESC datasheet section I "SII EEPROM").
//!
//! Addresses here are in 16-bit words, as the ESC's EEPROM interface addresses them.

use crate::WireError;

/// Word address of the PDI control word.
pub const WORD_PDI_CONTROL: u16 = 0x0000;
/// Word address of the configured station alias.
pub const WORD_ALIAS: u16 = 0x0004;
/// Word address of the checksum over words 0..=6.
pub const WORD_CHECKSUM: u16 = 0x0007;
/// Word address of the vendor ID (u32).
pub const WORD_VENDOR_ID: u16 = 0x0008;
/// Word address of the product code (u32).
pub const WORD_PRODUCT_CODE: u16 = 0x000a;
/// Word address of the revision number (u32).
pub const WORD_REVISION: u16 = 0x000c;
/// Word address of the serial number (u32).
pub const WORD_SERIAL: u16 = 0x000e;
/// Word address of the standard receive mailbox offset.
pub const WORD_STD_RX_MAILBOX_OFFSET: u16 = 0x0018;
/// Word address of the supported mailbox protocols.
pub const WORD_MAILBOX_PROTOCOL: u16 = 0x001c;
/// Word address of the EEPROM size (KiBit - 1).
pub const WORD_SIZE: u16 = 0x003e;
/// Word address of the SII version.
pub const WORD_VERSION: u16 = 0x003f;
/// Word address of the first category header.
pub const WORD_FIRST_CATEGORY: u16 = 0x0040;

/// Category types.
pub mod category {
    /// No operation (skip).
    pub const NOP: u16 = 0;
    /// Strings: a count byte, then length-prefixed strings (index 1-based).
    pub const STRINGS: u16 = 10;
    /// Data types.
    pub const DATA_TYPES: u16 = 20;
    /// General information.
    pub const GENERAL: u16 = 30;
    /// FMMU usage, one byte per FMMU.
    pub const FMMU: u16 = 40;
    /// SyncManager configuration, 8 bytes per SyncManager.
    pub const SYNC_MANAGER: u16 = 41;
    /// TxPDO (inputs) descriptions.
    pub const TXPDO: u16 = 50;
    /// RxPDO (outputs) descriptions.
    pub const RXPDO: u16 = 51;
    /// Distributed clocks.
    pub const DC: u16 = 60;
    /// End of the category list.
    pub const END: u16 = 0xffff;
}

/// CRC-8 of the ESC configuration area: polynomial x^8 + x^2 + x + 1 (0x07), initial value 0xFF,
/// no reflection, no final XOR, over the 14 bytes of words 0..=6 (low byte first). The result is
/// stored in the low byte of word 7.
pub const fn config_checksum(words_0_to_6: &[u8; 14]) -> u8 {
    let mut crc: u8 = 0xff;
    let mut i = 0;
    while i < 14 {
        crc ^= words_0_to_6[i];
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0x07
            } else {
                crc << 1
            };
            bit += 1;
        }
        i += 1;
    }
    crc
}

/// The identity words of an SII image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct Identity {
    /// Vendor ID (ETG-assigned).
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Revision number.
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
}

/// Word `word` of an SII image.
pub fn word(image: &[u8], word: u16) -> Result<u16, WireError> {
    let at = usize::from(word) * 2;
    match image.get(at..at + 2) {
        Some(b) => Ok(u16::from_le_bytes([b[0], b[1]])),
        None => Err(WireError::Truncated {
            needed: at + 2,
            have: image.len(),
        }),
    }
}

fn dword(image: &[u8], w: u16) -> Result<u32, WireError> {
    Ok(u32::from(word(image, w)?) | (u32::from(word(image, w + 1)?) << 16))
}

/// Reads the identity from an image (bytes, starting at word 0).
pub fn identity(image: &[u8]) -> Result<Identity, WireError> {
    Ok(Identity {
        vendor_id: dword(image, WORD_VENDOR_ID)?,
        product_code: dword(image, WORD_PRODUCT_CODE)?,
        revision: dword(image, WORD_REVISION)?,
        serial: dword(image, WORD_SERIAL)?,
    })
}

/// Whether word 7 holds the correct checksum of words 0..=6.
pub fn checksum_ok(image: &[u8]) -> bool {
    if image.len() < 16 {
        return false;
    }
    let mut head = [0u8; 14];
    head.copy_from_slice(&image[..14]);
    image[14] == config_checksum(&head) && image[15] == 0
}

/// One category: its type and its data bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Category<'a> {
    /// Category type (see [`category`]); bit 15 marks vendor-specific types.
    pub kind: u16,
    /// Word address of the category's data (after its 2-word header).
    pub data_word: u16,
    /// The category's data.
    pub data: &'a [u8],
}

/// Iterates over the categories of an image starting at word 0x40 until the end marker, the end
/// of the image, or a malformed header.
pub fn categories(image: &[u8]) -> impl Iterator<Item = Result<Category<'_>, WireError>> + '_ {
    let mut w = WORD_FIRST_CATEGORY;
    let mut done = false;
    core::iter::from_fn(move || {
        if done {
            return None;
        }
        let kind = match word(image, w) {
            Ok(k) => k,
            Err(_) => {
                done = true;
                return None;
            }
        };
        if kind == category::END {
            done = true;
            return None;
        }
        let size_words = match word(image, w.wrapping_add(1)) {
            Ok(s) => s,
            Err(e) => {
                done = true;
                return Some(Err(e));
            }
        };
        let start = (usize::from(w) + 2) * 2;
        let end = start + usize::from(size_words) * 2;
        if end > image.len() {
            done = true;
            return Some(Err(WireError::Truncated {
                needed: end,
                have: image.len(),
            }));
        }
        let cat = Category {
            kind,
            data_word: w + 2,
            data: &image[start..end],
        };
        match w.checked_add(2 + size_words) {
            Some(next) => w = next,
            None => done = true,
        }
        Some(Ok(cat))
    })
}

/// Finds the first category of a type.
pub fn find_category(image: &[u8], kind: u16) -> Option<Category<'_>> {
    categories(image)
        .filter_map(Result::ok)
        .find(|c| c.kind == kind)
}

/// The string with 1-based `index` from a strings category's data; index 0 is the empty string.
pub fn string(strings_category: &[u8], index: u8) -> Option<&[u8]> {
    if index == 0 {
        return Some(&[]);
    }
    let count = *strings_category.first()?;
    if index > count {
        return None;
    }
    let mut at = 1usize;
    for i in 1..=index {
        let len = usize::from(*strings_category.get(at)?);
        let s = strings_category.get(at + 1..at + 1 + len)?;
        if i == index {
            return Some(s);
        }
        at += 1 + len;
    }
    None
}

/// Bytes of a category header: type, then size in words.
pub const CATEGORY_HEADER_LEN: usize = 4;

/// A category header (two words before the category's data).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CategoryHeader {
    /// Category type (see [`category`]).
    pub kind: u16,
    /// Size of the data in words.
    pub size_words: u16,
}

impl CategoryHeader {
    /// Reads a header from its first byte; an error if fewer than four bytes are given.
    pub fn parse(bytes: &[u8]) -> Result<Self, WireError> {
        match bytes {
            [k0, k1, s0, s1, ..] => Ok(CategoryHeader {
                kind: u16::from_le_bytes([*k0, *k1]),
                size_words: u16::from_le_bytes([*s0, *s1]),
            }),
            _ => Err(WireError::Truncated {
                needed: CATEGORY_HEADER_LEN,
                have: bytes.len(),
            }),
        }
    }

    /// The header's four bytes.
    pub fn to_bytes(&self) -> [u8; CATEGORY_HEADER_LEN] {
        let [k0, k1] = self.kind.to_le_bytes();
        let [s0, s1] = self.size_words.to_le_bytes();
        [k0, k1, s0, s1]
    }
}

/// Bytes of one entry of the SyncManager category.
pub const SM_CATEGORY_ENTRY_LEN: usize = 8;

/// SyncManager types of the SyncManager category (entry byte 7).
pub mod sm_type {
    /// Not used.
    pub const UNUSED: u8 = 0;
    /// Mailbox out (master to slave).
    pub const MAILBOX_OUT: u8 = 1;
    /// Mailbox in (slave to master).
    pub const MAILBOX_IN: u8 = 2;
    /// Process data outputs.
    pub const OUTPUTS: u8 = 3;
    /// Process data inputs.
    pub const INPUTS: u8 = 4;
}

/// One entry of the SyncManager category (ETG.1000.6 table "Structure category
/// SyncManager"): the register entry's first five bytes as the slave wants them, then what the
/// SyncManager is for. Unlike the register entry ([`crate::SyncManagerRepr`]), byte 5 (status)
/// is don't-care and byte 7 is the SyncManager's type.
///
/// The control and enable bytes are kept raw: an EEPROM may hold anything, and the master
/// decides what to do with a value it cannot use ([`crate::SmControl::from_bits`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SmCategoryEntry {
    /// Physical start address of the buffer.
    pub physical_start: u16,
    /// Default length in bytes (0: computed from the PDOs).
    pub length_bytes: u16,
    /// Control register value.
    pub control: u8,
    /// Enable byte: bit 0 enable, bit 1 fixed content, bit 2 virtual, bit 3 OP only.
    pub enable: u8,
    /// SyncManager type, see [`sm_type`].
    pub kind: u8,
}

impl SmCategoryEntry {
    /// Reads an entry from its first byte; an error if fewer than eight bytes are given.
    pub fn parse(bytes: &[u8]) -> Result<Self, WireError> {
        match bytes {
            [a0, a1, l0, l1, control, _status, enable, kind, ..] => Ok(SmCategoryEntry {
                physical_start: u16::from_le_bytes([*a0, *a1]),
                length_bytes: u16::from_le_bytes([*l0, *l1]),
                control: *control,
                enable: *enable,
                kind: *kind,
            }),
            _ => Err(WireError::Truncated {
                needed: SM_CATEGORY_ENTRY_LEN,
                have: bytes.len(),
            }),
        }
    }

    /// The entry's eight bytes (status as 0).
    pub fn to_bytes(&self) -> [u8; SM_CATEGORY_ENTRY_LEN] {
        let [a0, a1] = self.physical_start.to_le_bytes();
        let [l0, l1] = self.length_bytes.to_le_bytes();
        [a0, a1, l0, l1, self.control, 0, self.enable, self.kind]
    }

    /// The entries of a SyncManager category's data, in SyncManager order (a trailing partial
    /// entry is ignored).
    pub fn entries(category_data: &[u8]) -> impl Iterator<Item = SmCategoryEntry> + '_ {
        category_data
            .chunks_exact(SM_CATEGORY_ENTRY_LEN)
            .filter_map(|e| SmCategoryEntry::parse(e).ok())
    }
}

/// Byte offsets within the general category.
pub mod general {
    /// String index of the group.
    pub const GROUP_IDX: usize = 0;
    /// String index of the image name.
    pub const IMAGE_IDX: usize = 1;
    /// String index of the order number.
    pub const ORDER_IDX: usize = 2;
    /// String index of the device name.
    pub const NAME_IDX: usize = 3;
    /// CoE details.
    pub const COE_DETAILS: usize = 5;
    /// Flags.
    pub const FLAGS: usize = 11;
    /// Current consumption on EBUS in mA (i16).
    pub const EBUS_CURRENT: usize = 12;
    /// Physical port types, 4 bits per port (u16): 0 unused, 1 MII, 3 EBUS.
    pub const PHYSICAL_PORT: usize = 16;
    /// Length of the category in bytes.
    pub const LEN: usize = 32;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc8_reference_vectors() {
        // CRC-8 (poly 0x07, init 0xFF, no reflection) of "123456789" is 0xFB (the CRC catalogue's
        // check value for CRC-8/... with init 0xFF, refin false, xorout 0: "CRC-8/ROHC" is
        // reflected, so the unreflected variant is computed by hand here). We pin the algorithm
        // with a byte-at-a-time reference written independently.
        fn reference(data: &[u8]) -> u8 {
            let mut crc = 0xffu8;
            for &b in data {
                for i in (0..8).rev() {
                    let top = (crc >> 7) ^ ((b >> i) & 1);
                    crc <<= 1;
                    if top == 1 {
                        crc ^= 0x07;
                    }
                }
            }
            crc
        }
        let samples: [[u8; 14]; 3] = [
            [0; 14],
            [0xff; 14],
            [
                0x80, 0x0c, 0x00, 0x6e, 0x10, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
            ],
        ];
        for s in samples {
            assert_eq!(config_checksum(&s), reference(&s));
        }
    }

    #[test]
    fn walks_categories_and_strings() {
        // words 0..0x40 zero, then strings category with 2 strings, then end marker.
        let mut img = [0u8; 0x80 + 4 + 12 + 2];
        let c = 0x80;
        img[c..c + 2].copy_from_slice(&category::STRINGS.to_le_bytes());
        img[c + 2..c + 4].copy_from_slice(&6u16.to_le_bytes()); // 12 bytes
        img[c + 4..c + 16].copy_from_slice(&[2, 3, b'a', b'b', b'c', 2, b'x', b'y', 0, 0, 0, 0]);
        img[c + 16..c + 18].copy_from_slice(&0xffffu16.to_le_bytes());
        let cats: std::vec::Vec<_> = categories(&img).collect();
        assert_eq!(cats.len(), 1);
        let s = cats[0].unwrap();
        assert_eq!(s.kind, category::STRINGS);
        assert_eq!(s.data_word, 0x42);
        assert_eq!(string(s.data, 1), Some(&b"abc"[..]));
        assert_eq!(string(s.data, 2), Some(&b"xy"[..]));
        assert_eq!(string(s.data, 3), None);
        assert_eq!(string(s.data, 0), Some(&b""[..]));
    }

    #[test]
    fn sync_manager_entry_of_a_real_el2004() {
        // The SyncManager category (41, 4 words) of shared/captures/el2004-eeprom-dump.bin:
        // outputs at 0x0F00, length 0 (from the PDOs), control 0x44 (buffered, EtherCAT
        // writes, watchdog), enable 0x09 (enabled, OP only), type 3 (outputs).
        let data = [0x00, 0x0f, 0x00, 0x00, 0x44, 0x00, 0x09, 0x03];
        let e: std::vec::Vec<_> = SmCategoryEntry::entries(&data).collect();
        let want = SmCategoryEntry {
            physical_start: 0x0f00,
            length_bytes: 0,
            control: 0x44,
            enable: 0x09,
            kind: sm_type::OUTPUTS,
        };
        assert_eq!(e, [want]);
        assert_eq!(want.to_bytes(), data);
        let c = crate::SmControl::from_bits(want.control).unwrap();
        assert_eq!(c.direction, crate::SmDirection::Write);
        assert!(c.watchdog);
        assert!(SmCategoryEntry::parse(&data[..7]).is_err());
        assert_eq!(SmCategoryEntry::entries(&data[..7]).count(), 0);
        let h = CategoryHeader {
            kind: category::SYNC_MANAGER,
            size_words: 4,
        };
        assert_eq!(h.to_bytes(), [41, 0, 4, 0]);
        assert_eq!(CategoryHeader::parse(&h.to_bytes()), Ok(h));
        assert!(CategoryHeader::parse(&[41, 0, 4]).is_err());
    }

    #[test]
    fn truncated_category_is_an_error() {
        let mut img = [0u8; 0x84];
        img[0x80..0x82].copy_from_slice(&category::GENERAL.to_le_bytes());
        img[0x82..0x84].copy_from_slice(&16u16.to_le_bytes());
        let first = categories(&img).next().unwrap();
        assert!(first.is_err());
    }
}
