//! FMMU entries (ESC datasheet section II, registers 0x0600-0x06FF; ETG.1000.4 table
//! "Fieldbus memory management unit (FMMU) entity"): sixteen bytes per FMMU, FMMU `n` at
//! `0x0600 + 16 n` (see [`crate::register::fmmu_address`]).
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0x0 | 4 | logical start address |
//! | 0x4 | 2 | length in bytes |
//! | 0x6 | 1 | logical start bit (bits 2:0) |
//! | 0x7 | 1 | logical end bit (bits 2:0) |
//! | 0x8 | 2 | physical start address |
//! | 0xA | 1 | physical start bit (bits 2:0) |
//! | 0xB | 1 | type: bit 0 read, bit 1 write |
//! | 0xC | 1 | activate: bit 0 |
//! | 0xD | 3 | reserved |
//!
//! ```
//! use ecsync_wire::{Fmmu, FmmuRepr};
//!
//! // Logical byte 0 (bits 0..=3) mapped to the input buffer at 0x1000, for reads: what SOEM
//! // writes to an EL1004 (4 digital inputs).
//! let bytes = [0, 0, 0, 0, 1, 0, 0, 3, 0x00, 0x10, 0, 0x01, 0x01, 0, 0, 0];
//! let repr = FmmuRepr::parse(&Fmmu::new_checked(&bytes[..]).unwrap());
//! assert_eq!((repr.physical_start, repr.logical_end_bit), (0x1000, 3));
//! assert!(repr.read && !repr.write && repr.active);
//! assert_eq!(repr.to_bytes(), bytes);
//! ```

use crate::WireError;

/// Bytes of one FMMU entry.
pub const FMMU_ENTRY_LEN: usize = 16;

mod field {
    use core::ops::Range;
    pub const LOGICAL_START: Range<usize> = 0..4;
    pub const LENGTH: Range<usize> = 4..6;
    pub const LOGICAL_START_BIT: usize = 6;
    pub const LOGICAL_END_BIT: usize = 7;
    pub const PHYSICAL_START: Range<usize> = 8..10;
    pub const PHYSICAL_START_BIT: usize = 10;
    pub const TYPE: usize = 11;
    pub const ACTIVATE: usize = 12;
}

/// Bit positions are three bits wide (0..=7); the upper five bits of their bytes are reserved.
const BIT_MASK: u8 = 0x07;
/// Type register: the mapping is used for read accesses.
const TYPE_READ: u8 = 1 << 0;
/// Type register: the mapping is used for write accesses.
const TYPE_WRITE: u8 = 1 << 1;
/// Activate register: the FMMU is active.
const ACTIVATE: u8 = 1 << 0;

/// A typed view over one FMMU entry: `buffer` starts at the entry's first byte and holds at
/// least [`FMMU_ENTRY_LEN`] bytes.
#[derive(Debug, Clone, Copy)]
pub struct Fmmu<T> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Fmmu<T> {
    /// Wraps a buffer without checking it; accessors panic if it is shorter than
    /// [`FMMU_ENTRY_LEN`]. Use [`Fmmu::new_checked`] on untrusted input.
    pub const fn new_unchecked(buffer: T) -> Self {
        Fmmu { buffer }
    }

    /// Wraps a buffer after checking it holds a whole entry.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let have = buffer.as_ref().len();
        if have < FMMU_ENTRY_LEN {
            return Err(WireError::Truncated {
                needed: FMMU_ENTRY_LEN,
                have,
            });
        }
        Ok(Fmmu { buffer })
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    fn b(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Logical start address (byte address in the 4 GiB logical space).
    pub fn logical_start(&self) -> u32 {
        let b = &self.b()[field::LOGICAL_START];
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// Length of the mapping in bytes (counting the partial first and last bytes).
    pub fn length_bytes(&self) -> u16 {
        let b = &self.b()[field::LENGTH];
        u16::from_le_bytes([b[0], b[1]])
    }

    /// First bit of the first logical byte that is mapped (0..=7).
    pub fn logical_start_bit(&self) -> u8 {
        self.b()[field::LOGICAL_START_BIT] & BIT_MASK
    }

    /// Last bit of the last logical byte that is mapped (0..=7; 7 for whole bytes).
    pub fn logical_end_bit(&self) -> u8 {
        self.b()[field::LOGICAL_END_BIT] & BIT_MASK
    }

    /// Physical start address (the ESC memory the logical range maps to).
    pub fn physical_start(&self) -> u16 {
        let b = &self.b()[field::PHYSICAL_START];
        u16::from_le_bytes([b[0], b[1]])
    }

    /// First bit of the physical start byte (0..=7).
    pub fn physical_start_bit(&self) -> u8 {
        self.b()[field::PHYSICAL_START_BIT] & BIT_MASK
    }

    /// Whether the mapping is used for read accesses (LRD, the read half of LRW).
    pub fn read_enabled(&self) -> bool {
        self.b()[field::TYPE] & TYPE_READ != 0
    }

    /// Whether the mapping is used for write accesses (LWR, the write half of LRW).
    pub fn write_enabled(&self) -> bool {
        self.b()[field::TYPE] & TYPE_WRITE != 0
    }

    /// Whether the FMMU is activated.
    pub fn active(&self) -> bool {
        self.b()[field::ACTIVATE] & ACTIVATE != 0
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Fmmu<T> {
    fn bm(&mut self) -> &mut [u8] {
        self.buffer.as_mut()
    }

    /// Sets the logical start address.
    pub fn set_logical_start(&mut self, address: u32) {
        self.bm()[field::LOGICAL_START].copy_from_slice(&address.to_le_bytes());
    }

    /// Sets the length in bytes.
    pub fn set_length_bytes(&mut self, len: u16) {
        self.bm()[field::LENGTH].copy_from_slice(&len.to_le_bytes());
    }

    /// Sets the logical start bit (only its three low bits are kept).
    pub fn set_logical_start_bit(&mut self, bit: u8) {
        self.bm()[field::LOGICAL_START_BIT] = bit & BIT_MASK;
    }

    /// Sets the logical end bit (only its three low bits are kept).
    pub fn set_logical_end_bit(&mut self, bit: u8) {
        self.bm()[field::LOGICAL_END_BIT] = bit & BIT_MASK;
    }

    /// Sets the physical start address.
    pub fn set_physical_start(&mut self, address: u16) {
        self.bm()[field::PHYSICAL_START].copy_from_slice(&address.to_le_bytes());
    }

    /// Sets the physical start bit (only its three low bits are kept).
    pub fn set_physical_start_bit(&mut self, bit: u8) {
        self.bm()[field::PHYSICAL_START_BIT] = bit & BIT_MASK;
    }

    /// Sets the type register: whether the mapping is used for reads and for writes.
    pub fn set_type(&mut self, read: bool, write: bool) {
        self.bm()[field::TYPE] =
            if read { TYPE_READ } else { 0 } | if write { TYPE_WRITE } else { 0 };
    }

    /// Activates or deactivates the FMMU.
    pub fn set_active(&mut self, active: bool) {
        self.bm()[field::ACTIVATE] = if active { ACTIVATE } else { 0 };
    }
}

/// The contents of one FMMU entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct FmmuRepr {
    /// Logical start address.
    pub logical_start: u32,
    /// Length in bytes.
    pub length_bytes: u16,
    /// Logical start bit (0..=7).
    pub logical_start_bit: u8,
    /// Logical end bit (0..=7; 7 for a mapping of whole bytes).
    pub logical_end_bit: u8,
    /// Physical start address.
    pub physical_start: u16,
    /// Physical start bit (0..=7).
    pub physical_start_bit: u8,
    /// Used for read accesses.
    pub read: bool,
    /// Used for write accesses.
    pub write: bool,
    /// Activated.
    pub active: bool,
}

impl FmmuRepr {
    /// Reads an entry. Reserved bits are ignored, as the ESC ignores them; nothing else can be
    /// wrong in an entry whose length the view checked.
    pub fn parse<T: AsRef<[u8]>>(entry: &Fmmu<T>) -> Self {
        FmmuRepr {
            logical_start: entry.logical_start(),
            length_bytes: entry.length_bytes(),
            logical_start_bit: entry.logical_start_bit(),
            logical_end_bit: entry.logical_end_bit(),
            physical_start: entry.physical_start(),
            physical_start_bit: entry.physical_start_bit(),
            read: entry.read_enabled(),
            write: entry.write_enabled(),
            active: entry.active(),
        }
    }

    /// Bytes [`FmmuRepr::emit`] writes.
    pub const fn buffer_len(&self) -> usize {
        FMMU_ENTRY_LEN
    }

    /// Writes the whole entry, reserved bytes as zero. Bit positions keep their three low bits.
    pub fn emit<T: AsRef<[u8]> + AsMut<[u8]>>(&self, entry: &mut Fmmu<T>) {
        entry.bm()[..FMMU_ENTRY_LEN].fill(0);
        entry.set_logical_start(self.logical_start);
        entry.set_length_bytes(self.length_bytes);
        entry.set_logical_start_bit(self.logical_start_bit);
        entry.set_logical_end_bit(self.logical_end_bit);
        entry.set_physical_start(self.physical_start);
        entry.set_physical_start_bit(self.physical_start_bit);
        entry.set_type(self.read, self.write);
        entry.set_active(self.active);
    }

    /// The entry as the 16 bytes a master writes to `0x0600 + 16 n`.
    pub fn to_bytes(&self) -> [u8; FMMU_ENTRY_LEN] {
        let mut b = [0u8; FMMU_ENTRY_LEN];
        self.emit(&mut Fmmu::new_unchecked(&mut b[..]));
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    // FPWR 0x0600 to station 0x1002 in shared/captures/soem-sdinfo-ek1100-el1004.pcapng (frame
    // 446): SOEM maps logical byte 0, bits 0..=3, to the EL1004's input buffer at 0x1000.
    const SOEM_EL1004: [u8; 16] = [
        0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x03, 0x00, 0x10, 0x00, 0x01, 0x01, 0x00, 0x00,
        0x00,
    ];

    #[test]
    fn parses_a_real_soem_entry() {
        let r = FmmuRepr::parse(&Fmmu::new_checked(&SOEM_EL1004[..]).unwrap());
        assert_eq!(
            r,
            FmmuRepr {
                logical_start: 0,
                length_bytes: 1,
                logical_start_bit: 0,
                logical_end_bit: 3,
                physical_start: 0x1000,
                physical_start_bit: 0,
                read: true,
                write: false,
                active: true,
            }
        );
        assert_eq!(r.to_bytes(), SOEM_EL1004);
    }

    #[test]
    fn output_mapping_by_hand_from_the_datasheet_table() {
        // 18 bytes at logical 0x0000_0100 to 0x1000 for writes, whole bytes: start bit 0 at
        // 0x6, end bit 7 at 0x7, write = type bit 1 at 0xB, activate bit 0 at 0xC.
        let r = FmmuRepr {
            logical_start: 0x0000_0100,
            length_bytes: 18,
            logical_end_bit: 7,
            physical_start: 0x1000,
            write: true,
            active: true,
            ..FmmuRepr::default()
        };
        assert_eq!(
            r.to_bytes(),
            [
                0x00, 0x01, 0x00, 0x00, 0x12, 0x00, 0x00, 0x07, 0x00, 0x10, 0x00, 0x02, 0x01, 0, 0,
                0
            ]
        );
    }

    #[test]
    fn reserved_bits_are_ignored() {
        let mut b = SOEM_EL1004;
        b[6] |= 0xf8;
        b[11] |= 0xfc;
        b[12] |= 0xfe;
        b[13] = 0xff;
        let r = FmmuRepr::parse(&Fmmu::new_checked(&b[..]).unwrap());
        assert_eq!(r.to_bytes(), SOEM_EL1004);
    }

    #[test]
    fn short_buffers_are_errors() {
        for n in 0..FMMU_ENTRY_LEN {
            assert_eq!(
                Fmmu::new_checked(&SOEM_EL1004[..n]).unwrap_err(),
                WireError::Truncated {
                    needed: 16,
                    have: n
                }
            );
        }
    }

    fn repr() -> impl Strategy<Value = FmmuRepr> {
        (
            any::<u32>(),
            any::<u16>(),
            0u8..8,
            0u8..8,
            any::<u16>(),
            0u8..8,
            any::<(bool, bool, bool)>(),
        )
            .prop_map(
                |(ls, len, lsb, leb, ps, psb, (read, write, active))| FmmuRepr {
                    logical_start: ls,
                    length_bytes: len,
                    logical_start_bit: lsb,
                    logical_end_bit: leb,
                    physical_start: ps,
                    physical_start_bit: psb,
                    read,
                    write,
                    active,
                },
            )
    }

    proptest! {
        #[test]
        fn repr_round_trips(r in repr()) {
            let b = r.to_bytes();
            prop_assert_eq!(FmmuRepr::parse(&Fmmu::new_checked(&b[..]).unwrap()), r);
        }

        #[test]
        fn any_bytes_parse_without_panic(b in proptest::collection::vec(any::<u8>(), 0..40)) {
            match Fmmu::new_checked(&b[..]) {
                Ok(v) => {
                    let r = FmmuRepr::parse(&v);
                    // Emitting what was parsed gives the bytes back, reserved bits cleared.
                    let again = FmmuRepr::parse(&Fmmu::new_checked(&r.to_bytes()[..]).unwrap());
                    prop_assert_eq!(again, r);
                }
                Err(e) => prop_assert!(b.len() < FMMU_ENTRY_LEN, "{e}"),
            }
        }
    }
}
