use crate::{DATAGRAM_OVERHEAD, Datagram, WireError};

/// EtherType of EtherCAT frames.
pub const ETHERTYPE_ETHERCAT: u16 = 0x88a4;
/// Destination MAC, source MAC, EtherType.
pub const ETH_HEADER_LEN: usize = 14;
/// The 2-byte EtherCAT header: 11-bit length, reserved bit, 4-bit type.
pub const ECAT_HEADER_LEN: usize = 2;
/// EtherCAT header type for datagram (command) frames.
pub const ECAT_TYPE_COMMANDS: u8 = 1;
/// Minimum Ethernet frame without FCS; shorter frames are padded.
pub const MIN_FRAME_LEN: usize = 60;
/// Maximum Ethernet frame without FCS.
pub const MAX_FRAME_LEN: usize = 1514;

const ECAT_LEN_MASK: u16 = 0x07ff;
/// The source MAC byte the first ESC marks on frames it sends back, and the mark: bit 1
/// (locally administered) of the first source MAC byte.
const RETURNED_MARK_AT: usize = 6;
const RETURNED_MARK: u8 = 0x02;

/// Whether an Ethernet frame (any EtherType, VLAN-tagged or not: the source MAC comes first)
/// carries the mark the first ESC sets on every frame it sends back to the master; false if
/// the buffer does not reach the source MAC.
pub fn is_returned_frame(frame: &[u8]) -> bool {
    frame
        .get(RETURNED_MARK_AT)
        .is_some_and(|b| b & RETURNED_MARK != 0)
}

/// Sets the returned mark (see [`is_returned_frame`]) on an Ethernet frame; does nothing to a
/// buffer that does not reach the source MAC.
#[inline]
pub fn mark_returned_frame(frame: &mut [u8]) {
    if let Some(b) = frame.get_mut(RETURNED_MARK_AT) {
        *b |= RETURNED_MARK;
    }
}

/// A typed view over an Ethernet frame that carries EtherCAT datagrams. `buffer` starts at the
/// destination MAC; no FCS.
#[derive(Debug, Clone, Copy)]
pub struct EcatFrame<T> {
    buffer: T,
}

impl<T: AsRef<[u8]>> EcatFrame<T> {
    /// Wraps a buffer without checks.
    pub const fn new_unchecked(buffer: T) -> Self {
        EcatFrame { buffer }
    }

    /// Checks the Ethernet and EtherCAT headers and that the announced EtherCAT length fits the
    /// buffer. Datagrams are checked as they are iterated.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let have = buffer.as_ref().len();
        let needed = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        if have < needed {
            return Err(WireError::Truncated { needed, have });
        }
        let f = EcatFrame { buffer };
        if f.ethertype() != ETHERTYPE_ETHERCAT {
            return Err(WireError::NotEthercat(f.ethertype()));
        }
        if f.ecat_type() != ECAT_TYPE_COMMANDS {
            return Err(WireError::UnsupportedType(f.ecat_type()));
        }
        let len = f.ecat_len();
        if len < DATAGRAM_OVERHEAD {
            return Err(WireError::BadFrameLength(len as u16));
        }
        let needed = ETH_HEADER_LEN + ECAT_HEADER_LEN + len;
        if have < needed {
            return Err(WireError::Truncated { needed, have });
        }
        Ok(f)
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    /// The command code and index of the first datagram, if the frame holds one: what tells a
    /// reply from other frames (the index changes from frame to frame, the command does not
    /// change on the way).
    pub fn first_datagram_id(&self) -> Option<(u8, u8)> {
        let p = self.payload();
        if p.len() < 2 {
            return None;
        }
        Some((p[0], p[1]))
    }

    fn b(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Destination MAC address.
    pub fn dst_mac(&self) -> [u8; 6] {
        let mut m = [0; 6];
        m.copy_from_slice(&self.b()[0..6]);
        m
    }

    /// Source MAC address.
    pub fn src_mac(&self) -> [u8; 6] {
        let mut m = [0; 6];
        m.copy_from_slice(&self.b()[6..12]);
        m
    }

    /// EtherType.
    pub fn ethertype(&self) -> u16 {
        u16::from_be_bytes([self.b()[12], self.b()[13]])
    }

    fn ecat_header(&self) -> u16 {
        u16::from_le_bytes([self.b()[14], self.b()[15]])
    }

    /// Length of the datagrams that follow the EtherCAT header, in bytes.
    pub fn ecat_len(&self) -> usize {
        usize::from(self.ecat_header() & ECAT_LEN_MASK)
    }

    /// EtherCAT header type (1 = commands).
    pub fn ecat_type(&self) -> u8 {
        (self.ecat_header() >> 12) as u8
    }

    /// The bytes that hold the datagrams (exactly `ecat_len()` of them).
    pub fn payload(&self) -> &[u8] {
        let start = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        &self.b()[start..start + self.ecat_len()]
    }

    /// Iterates over the datagram chain (following the more-follows bits). Yields an error and
    /// stops if a datagram overruns the EtherCAT length.
    pub fn datagrams(&self) -> DatagramIter<'_> {
        DatagramIter {
            payload: self.payload(),
            offset: 0,
            done: false,
        }
    }

    /// Offset of the first datagram from the start of the frame.
    pub const fn first_datagram_offset() -> usize {
        ETH_HEADER_LEN + ECAT_HEADER_LEN
    }

    /// Whether the first ESC marked the frame on its way back (see [`is_returned_frame`]).
    pub fn is_returned(&self) -> bool {
        is_returned_frame(self.b())
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> EcatFrame<T> {
    /// Sets the source MAC address.
    pub fn set_src_mac(&mut self, mac: [u8; 6]) {
        self.buffer.as_mut()[6..12].copy_from_slice(&mac);
    }

    /// Sets the index of the first datagram (a master's tag of the frame, see
    /// [`EcatFrame::first_datagram_id`]); a frame without a datagram is left as it is.
    pub fn set_first_datagram_index(&mut self, index: u8) {
        if let Some(i) = self.payload_mut().get_mut(1) {
            *i = index;
        }
    }

    /// Mutable bytes of the datagrams.
    pub fn payload_mut(&mut self) -> &mut [u8] {
        let start = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        let len = self.ecat_len();
        &mut self.buffer.as_mut()[start..start + len]
    }

    /// Sets bit 1 of the first source MAC byte (locally administered), as the first ESC does to
    /// every frame it forwards back to the master, so that the master tells its own sent frames
    /// from returning ones.
    pub fn mark_returned(&mut self) {
        mark_returned_frame(self.buffer.as_mut());
    }
}

/// Iterator over the datagrams of a frame. Each item carries its offset within the payload so
/// that a mutable pass can revisit the same datagram.
#[derive(Debug, Clone)]
pub struct DatagramIter<'a> {
    payload: &'a [u8],
    offset: usize,
    done: bool,
}

impl<'a> DatagramIter<'a> {
    /// Offset within the payload of the datagram the next call to `next` yields.
    pub fn offset(&self) -> usize {
        self.offset
    }

    /// Each datagram with its offset from the start of the frame (what a frame's bytes are
    /// indexed by), as [`EcatFrame::datagrams`] yields them.
    pub fn with_frame_offsets(
        mut self,
    ) -> impl Iterator<Item = (usize, Result<Datagram<&'a [u8]>, WireError>)> + 'a {
        core::iter::from_fn(move || {
            let at = ETH_HEADER_LEN + ECAT_HEADER_LEN + self.offset;
            self.next().map(|d| (at, d))
        })
    }
}

impl<'a> Iterator for DatagramIter<'a> {
    type Item = Result<Datagram<&'a [u8]>, WireError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let rest = &self.payload[self.offset..];
        match Datagram::new_checked(rest) {
            Ok(dg) => {
                let total = dg.total_len();
                let more = dg.more_follows();
                let dg = Datagram::new_unchecked(&rest[..total]);
                self.offset += total;
                if !more || self.offset >= self.payload.len() {
                    self.done = true;
                }
                Some(Ok(dg))
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The source MAC is bytes 6-11 of the Ethernet header (after the destination's 0-5).
    #[test]
    fn set_src_mac_writes_the_ethernet_source() {
        let mut buf = [0u8; 64];
        let n = {
            let mut b = crate::FrameBuilder::new(&mut buf, [0xff; 6], [1, 2, 3, 4, 5, 6]).unwrap();
            b.push_zeroed(Command::Brd, 0, crate::DatagramAddress::position(0, 0), 2)
                .unwrap();
            b.finish()
        };
        let mut f = EcatFrame::new_checked(&mut buf[..n]).unwrap();
        f.set_src_mac([0x02, 0x00, 0x00, 0x0e, 0xca, 0x75]);
        assert_eq!(
            &buf[..12],
            &[
                0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x02, 0x00, 0x00, 0x0e, 0xca, 0x75
            ]
        );
        assert_eq!(
            EcatFrame::new_checked(&buf[..n]).unwrap().src_mac(),
            [0x02, 0, 0, 0x0e, 0xca, 0x75]
        );
    }
    use crate::Command;

    // A BRD of AL status (0x0130, 2 bytes) as a master sends it: broadcast destination, source
    // 02:00:00:00:00:01, EtherType 0x88A4, EtherCAT header length 14 type 1 (0x100e), padded.
    fn brd_frame() -> [u8; 60] {
        let mut f = [0u8; 60];
        f[0..6].copy_from_slice(&[0xff; 6]);
        f[6..12].copy_from_slice(&[0x00, 0, 0, 0, 0, 1]);
        f[12..14].copy_from_slice(&[0x88, 0xa4]);
        f[14..16].copy_from_slice(&[0x0e, 0x10]);
        f[16..30].copy_from_slice(&[
            0x07, 0x01, 0x00, 0x00, 0x30, 0x01, 0x02, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
        ]);
        f
    }

    #[test]
    fn parses_hand_built_frame() {
        let bytes = brd_frame();
        let f = EcatFrame::new_checked(&bytes[..]).unwrap();
        assert_eq!(f.ethertype(), 0x88a4);
        assert_eq!(f.ecat_len(), 14);
        assert_eq!(f.ecat_type(), 1);
        let all: std::vec::Vec<_> = f.datagrams().collect();
        assert_eq!(all.len(), 1);
        let d = all[0].unwrap();
        assert_eq!(d.command(), Ok(Command::Brd));
        assert_eq!(d.ado(), 0x0130);
        assert_eq!(d.data_len(), 2);
    }

    #[test]
    fn returned_mark() {
        let mut bytes = brd_frame();
        assert!(!is_returned_frame(&bytes));
        EcatFrame::new_unchecked(&mut bytes[..]).mark_returned();
        assert_eq!(bytes[6], 0x02);
        assert!(EcatFrame::new_checked(&bytes[..]).unwrap().is_returned());
        assert!(!is_returned_frame(&bytes[..6]));
        mark_returned_frame(&mut bytes[..6]);
    }

    #[test]
    fn rejects_bad_headers() {
        let mut bytes = brd_frame();
        bytes[12] = 0x08;
        bytes[13] = 0x00;
        assert_eq!(
            EcatFrame::new_checked(&bytes[..]).unwrap_err(),
            WireError::NotEthercat(0x0800)
        );
        let mut bytes = brd_frame();
        bytes[15] = 0x40; // type 4
        assert_eq!(
            EcatFrame::new_checked(&bytes[..]).unwrap_err(),
            WireError::UnsupportedType(4)
        );
        let mut bytes = brd_frame();
        bytes[14] = 0xff;
        bytes[15] = 0x17; // length 0x7ff
        assert!(matches!(
            EcatFrame::new_checked(&bytes[..]),
            Err(WireError::Truncated { .. })
        ));
    }

    #[test]
    fn chain_overrunning_the_length_is_an_error() {
        let mut bytes = brd_frame();
        bytes[22] = 0x02;
        bytes[23] = 0x80; // more follows, but nothing follows within the header length
        let f = EcatFrame::new_checked(&bytes[..]).unwrap();
        let all: std::vec::Vec<_> = f.datagrams().collect();
        assert_eq!(all.len(), 1, "the chain ends at the EtherCAT length");
        let mut bytes = brd_frame();
        bytes[14] = 0x0d; // length 13 < datagram of 14
        let f = EcatFrame::new_checked(&bytes[..]).unwrap();
        assert!(f.datagrams().next().unwrap().is_err());
    }
}
