use crate::{Command, WireError};

/// Bytes before a datagram's data: command, index, address (4), length (2), IRQ (2).
pub const DATAGRAM_HEADER_LEN: usize = 10;
/// Bytes of the working counter that follows the data.
pub const WKC_LEN: usize = 2;
/// Header plus working counter: what a datagram costs beyond its data.
pub const DATAGRAM_OVERHEAD: usize = DATAGRAM_HEADER_LEN + WKC_LEN;
/// Largest value of the 11-bit length field.
pub const MAX_DATAGRAM_DATA: usize = 0x7ff;

const LEN_MASK: u16 = 0x07ff;
const ADP_AT: usize = 2;
const CIRCULATING: u16 = 1 << 14;
const MORE_FOLLOWS: u16 = 1 << 15;

/// A datagram header's shape as two words for equality: command, address, length and flags
/// (bytes 0 and 2..8) and the IRQ field, without the index (byte 1), which a master changes from
/// cycle to cycle to tell its replies apart and no slave reads. Two headers of one key make
/// every ESC act alike (a simulator recognises a cycle's frames by it).
#[inline]
pub fn header_shape_key(header: &[u8; DATAGRAM_HEADER_LEN]) -> (u64, u16) {
    let (lo, irq) = header.split_at(8);
    let mut w = [0u8; 8];
    w.copy_from_slice(lo);
    (
        u64::from_le_bytes(w) & !0xff00,
        u16::from_le_bytes([irq[0], irq[1]]),
    )
}

/// The 32-bit address field of a datagram, interpreted by the command's address mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DatagramAddress {
    /// ADP (auto-increment position, two's complement of the position) and ADO (register offset).
    Position {
        /// Position field; slave k (0-based) is addressed by `0u16.wrapping_sub(k)`.
        adp: u16,
        /// Physical memory offset.
        ado: u16,
    },
    /// ADP as configured station address or alias, and ADO.
    Configured {
        /// Configured station address (0x0010) or alias (0x0012).
        adp: u16,
        /// Physical memory offset.
        ado: u16,
    },
    /// A 32-bit logical address (LRD, LWR, LRW).
    Logical(u32),
}

impl DatagramAddress {
    /// The raw 32-bit field as it appears on the wire (little-endian ADP then ADO).
    pub const fn raw(self) -> u32 {
        match self {
            DatagramAddress::Position { adp, ado } | DatagramAddress::Configured { adp, ado } => {
                (adp as u32) | ((ado as u32) << 16)
            }
            DatagramAddress::Logical(a) => a,
        }
    }

    /// Auto-increment address of the slave at 0-based `position`.
    pub const fn position(position: u16, ado: u16) -> Self {
        DatagramAddress::Position {
            adp: 0u16.wrapping_sub(position),
            ado,
        }
    }

    /// Configured address of the slave with station address (or alias) `station`.
    pub const fn configured(station: u16, ado: u16) -> Self {
        DatagramAddress::Configured { adp: station, ado }
    }
}

/// A typed view over one datagram: `buffer` starts at the command byte and holds at least the
/// whole datagram (it may hold more, e.g. the datagrams that follow it).
#[derive(Debug, Clone, Copy)]
pub struct Datagram<T> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Datagram<T> {
    /// Wraps a buffer without checking it; accessors may panic if it is too short. Use
    /// [`Datagram::new_checked`] on untrusted input.
    pub const fn new_unchecked(buffer: T) -> Self {
        Datagram { buffer }
    }

    /// Wraps a buffer after checking it holds the header, the data its length field announces and
    /// the working counter.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let have = buffer.as_ref().len();
        if have < DATAGRAM_OVERHEAD {
            return Err(WireError::Truncated {
                needed: DATAGRAM_OVERHEAD,
                have,
            });
        }
        let dg = Datagram { buffer };
        let needed = dg.total_len();
        if have < needed {
            return Err(WireError::Truncated { needed, have });
        }
        Ok(dg)
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    fn b(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    fn u16_at(&self, at: usize) -> u16 {
        u16::from_le_bytes([self.b()[at], self.b()[at + 1]])
    }

    /// The raw command byte.
    pub fn command_code(&self) -> u8 {
        self.b()[0]
    }

    /// The decoded command.
    pub fn command(&self) -> Result<Command, WireError> {
        Command::from_code(self.command_code())
    }

    /// The index the master uses to match replies to requests.
    pub fn index(&self) -> u8 {
        self.b()[1]
    }

    /// The 32-bit address field.
    pub fn address_raw(&self) -> u32 {
        u32::from_le_bytes([self.b()[2], self.b()[3], self.b()[4], self.b()[5]])
    }

    /// ADP: position or station address (low 16 bits of the address field).
    pub fn adp(&self) -> u16 {
        self.u16_at(ADP_AT)
    }

    /// ADO: register offset (high 16 bits of the address field).
    pub fn ado(&self) -> u16 {
        self.u16_at(4)
    }

    /// The address field interpreted by the command; `None` for NOP and unknown commands.
    pub fn address(&self) -> Option<DatagramAddress> {
        let cmd = self.command().ok()?;
        Some(match cmd.address_mode() {
            crate::AddressMode::Position | crate::AddressMode::Broadcast => {
                DatagramAddress::Position {
                    adp: self.adp(),
                    ado: self.ado(),
                }
            }
            crate::AddressMode::Configured => DatagramAddress::Configured {
                adp: self.adp(),
                ado: self.ado(),
            },
            crate::AddressMode::Logical => DatagramAddress::Logical(self.address_raw()),
            crate::AddressMode::None => return None,
        })
    }

    /// The raw 16-bit length field (length, circulating bit, more-follows bit).
    pub fn len_field(&self) -> u16 {
        self.u16_at(6)
    }

    /// Data length in bytes (11 bits).
    pub fn data_len(&self) -> usize {
        usize::from(self.len_field() & LEN_MASK)
    }

    /// Whether the frame has circulated once (set by a slave that closed a port's loop on it).
    pub fn circulating(&self) -> bool {
        self.len_field() & CIRCULATING != 0
    }

    /// Whether another datagram follows this one in the frame.
    pub fn more_follows(&self) -> bool {
        self.len_field() & MORE_FOLLOWS != 0
    }

    /// The event request field (ORed by the slaves).
    pub fn irq(&self) -> u16 {
        self.u16_at(8)
    }

    /// The data bytes.
    pub fn data(&self) -> &[u8] {
        let n = self.data_len();
        &self.b()[DATAGRAM_HEADER_LEN..DATAGRAM_HEADER_LEN + n]
    }

    /// The working counter.
    pub fn wkc(&self) -> u16 {
        self.u16_at(DATAGRAM_HEADER_LEN + self.data_len())
    }

    /// Bytes the whole datagram occupies: header, data and working counter.
    pub fn total_len(&self) -> usize {
        DATAGRAM_OVERHEAD + self.data_len()
    }

    /// Offset of the working counter from the datagram's first byte.
    pub fn wkc_offset(&self) -> usize {
        DATAGRAM_HEADER_LEN + self.data_len()
    }

    /// Offset of ADP from the datagram's first byte: for code that records where a datagram's
    /// fields are in a frame and patches them later without decoding the header again.
    pub const fn adp_offset() -> usize {
        ADP_AT
    }

    /// Offset of the data from the datagram's first byte.
    pub const fn data_offset() -> usize {
        DATAGRAM_HEADER_LEN
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Datagram<T> {
    fn bm(&mut self) -> &mut [u8] {
        self.buffer.as_mut()
    }

    fn set_u16_at(&mut self, at: usize, v: u16) {
        self.bm()[at..at + 2].copy_from_slice(&v.to_le_bytes());
    }

    /// Sets the command byte.
    pub fn set_command(&mut self, cmd: Command) {
        self.bm()[0] = cmd.code();
    }

    /// Sets the index.
    pub fn set_index(&mut self, index: u8) {
        self.bm()[1] = index;
    }

    /// Sets the 32-bit address field.
    pub fn set_address_raw(&mut self, raw: u32) {
        self.bm()[2..6].copy_from_slice(&raw.to_le_bytes());
    }

    /// Sets ADP (what each slave does when it increments the position of auto-increment
    /// commands).
    pub fn set_adp(&mut self, adp: u16) {
        self.set_u16_at(ADP_AT, adp);
    }

    /// Sets the circulating bit.
    pub fn set_circulating(&mut self, on: bool) {
        let f = self.len_field();
        self.set_u16_at(
            6,
            if on {
                f | CIRCULATING
            } else {
                f & !CIRCULATING
            },
        );
    }

    /// Sets the more-follows bit.
    pub fn set_more_follows(&mut self, on: bool) {
        let f = self.len_field();
        self.set_u16_at(
            6,
            if on {
                f | MORE_FOLLOWS
            } else {
                f & !MORE_FOLLOWS
            },
        );
    }

    /// Sets the IRQ field.
    pub fn set_irq(&mut self, irq: u16) {
        self.set_u16_at(8, irq);
    }

    /// Mutable data bytes.
    pub fn data_mut(&mut self) -> &mut [u8] {
        let n = self.data_len();
        &mut self.bm()[DATAGRAM_HEADER_LEN..DATAGRAM_HEADER_LEN + n]
    }

    /// Sets the working counter.
    pub fn set_wkc(&mut self, wkc: u16) {
        let at = DATAGRAM_HEADER_LEN + self.data_len();
        self.set_u16_at(at, wkc);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // FPRD of 4 bytes at station 0x1001, register 0x0910, index 7, WKC 1, more-follows set.
    const FPRD: [u8; 16] = [
        0x04, 0x07, 0x01, 0x10, 0x10, 0x09, 0x04, 0x80, 0x00, 0x00, 0xaa, 0xbb, 0xcc, 0xdd, 0x01,
        0x00,
    ];

    #[test]
    fn a_header_s_shape_key_leaves_out_the_index_only() {
        let h: [u8; DATAGRAM_HEADER_LEN] = FPRD[..DATAGRAM_HEADER_LEN].try_into().unwrap();
        let key = header_shape_key(&h);
        let mut other = h;
        other[1] = 0x42;
        assert_eq!(
            header_shape_key(&other),
            key,
            "another index, the same shape"
        );
        for at in (0..DATAGRAM_HEADER_LEN).filter(|&at| at != 1) {
            let mut changed = h;
            changed[at] ^= 0x01;
            assert_ne!(
                header_shape_key(&changed),
                key,
                "byte {at} is part of the shape"
            );
        }
    }

    /// The setters write the header where ETG.1000.4 puts it (byte 1 index, bytes 2-5 ADP and
    /// ADO little-endian, bytes 8-9 IRQ), leaving the other bytes alone: the FPRD above
    /// rewritten into the same FPRD with index 0x42, station 0x2003, register 0x0920, IRQ 0x0506.
    #[test]
    fn setters_write_the_header_fields_in_place() {
        let mut b = FPRD;
        let mut d = Datagram::new_checked(&mut b[..]).unwrap();
        d.set_index(0x42);
        d.set_address_raw(0x0920_2003);
        d.set_irq(0x0506);
        let want: [u8; 16] = [
            0x04, 0x42, 0x03, 0x20, 0x20, 0x09, 0x04, 0x80, 0x06, 0x05, 0xaa, 0xbb, 0xcc, 0xdd,
            0x01, 0x00,
        ];
        assert_eq!(b, want);
        let d = Datagram::new_checked(&b[..]).unwrap();
        assert_eq!(
            (d.index(), d.address_raw(), d.irq()),
            (0x42, 0x0920_2003, 0x0506)
        );
        assert_eq!(
            d.address(),
            Some(DatagramAddress::configured(0x2003, 0x0920))
        );
    }

    #[test]
    fn parses_hand_built_fprd() {
        let d = Datagram::new_checked(&FPRD[..]).unwrap();
        assert_eq!(d.command(), Ok(Command::Fprd));
        assert_eq!(d.index(), 7);
        assert_eq!(d.adp(), 0x1001);
        assert_eq!(d.ado(), 0x0910);
        assert_eq!(
            d.address(),
            Some(DatagramAddress::Configured {
                adp: 0x1001,
                ado: 0x0910
            })
        );
        assert_eq!(d.data_len(), 4);
        assert!(d.more_follows());
        assert!(!d.circulating());
        assert_eq!(d.data(), &[0xaa, 0xbb, 0xcc, 0xdd]);
        assert_eq!(d.wkc(), 1);
        assert_eq!(d.total_len(), 16);
    }

    #[test]
    fn rejects_truncated() {
        assert_eq!(
            Datagram::new_checked(&FPRD[..15]).unwrap_err(),
            WireError::Truncated {
                needed: 16,
                have: 15
            }
        );
        assert!(Datagram::new_checked(&FPRD[..5]).is_err());
    }

    #[test]
    fn setters_round_trip() {
        let mut buf = FPRD;
        let mut d = Datagram::new_unchecked(&mut buf[..]);
        d.set_wkc(3);
        d.set_more_follows(false);
        d.set_circulating(true);
        d.set_adp(0xfffe);
        d.data_mut()[0] = 0x11;
        assert_eq!(d.wkc(), 3);
        assert!(!d.more_follows());
        assert!(d.circulating());
        assert_eq!(d.data_len(), 4);
        assert_eq!(d.adp(), 0xfffe);
        assert_eq!(buf[6..8], [0x04, 0x40]);
        assert_eq!(buf[10], 0x11);
    }

    #[test]
    fn position_address_is_twos_complement() {
        assert_eq!(
            DatagramAddress::position(2, 0x0130).raw(),
            0x0130_fffe,
            "slave 2 is addressed with ADP = -2"
        );
    }
}
