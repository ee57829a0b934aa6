use crate::{
    Command, DATAGRAM_HEADER_LEN, DATAGRAM_OVERHEAD, DatagramAddress, ECAT_HEADER_LEN,
    ECAT_TYPE_COMMANDS, ETH_HEADER_LEN, ETHERTYPE_ETHERCAT, MAX_DATAGRAM_DATA, MIN_FRAME_LEN,
    WireError,
};

/// Writes an EtherCAT frame into a caller's buffer, datagram by datagram, chaining them with the
/// more-follows bit and filling in the EtherCAT header length when finished.
#[derive(Debug)]
pub struct FrameBuilder<'a> {
    buf: &'a mut [u8],
    len: usize,
    last_datagram: Option<usize>,
}

impl<'a> FrameBuilder<'a> {
    /// Starts a frame with the given Ethernet addresses.
    pub fn new(buf: &'a mut [u8], dst_mac: [u8; 6], src_mac: [u8; 6]) -> Result<Self, WireError> {
        let needed = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        if buf.len() < needed.max(MIN_FRAME_LEN) {
            return Err(WireError::Truncated {
                needed: needed.max(MIN_FRAME_LEN),
                have: buf.len(),
            });
        }
        buf[0..6].copy_from_slice(&dst_mac);
        buf[6..12].copy_from_slice(&src_mac);
        buf[12..14].copy_from_slice(&ETHERTYPE_ETHERCAT.to_be_bytes());
        Ok(FrameBuilder {
            buf,
            len: needed,
            last_datagram: None,
        })
    }

    /// Bytes still free for datagrams.
    pub fn free(&self) -> usize {
        self.buf.len() - self.len
    }

    /// Number of datagrams pushed.
    pub fn is_empty(&self) -> bool {
        self.last_datagram.is_none()
    }

    /// Appends a datagram whose data is `data` (for reads, the bytes the slaves overwrite; pass
    /// zeros). Returns the offset of the datagram's first byte within the frame.
    pub fn push(
        &mut self,
        command: Command,
        index: u8,
        address: DatagramAddress,
        data: &[u8],
    ) -> Result<usize, WireError> {
        let at = self.push_zeroed(command, index, address, data.len())?;
        self.buf[at + DATAGRAM_HEADER_LEN..at + DATAGRAM_HEADER_LEN + data.len()]
            .copy_from_slice(data);
        Ok(at)
    }

    /// Appends a datagram with `len` zero data bytes. Returns its offset within the frame.
    pub fn push_zeroed(
        &mut self,
        command: Command,
        index: u8,
        address: DatagramAddress,
        len: usize,
    ) -> Result<usize, WireError> {
        if len > MAX_DATAGRAM_DATA {
            return Err(WireError::DataTooLong(len));
        }
        let needed = DATAGRAM_OVERHEAD + len;
        let ecat_len = self.len - ETH_HEADER_LEN - ECAT_HEADER_LEN + needed;
        if needed > self.free() || ecat_len > MAX_DATAGRAM_DATA {
            return Err(WireError::BufferFull {
                needed,
                free: self.free(),
            });
        }
        if let Some(prev) = self.last_datagram {
            self.buf[prev + 7] |= 0x80;
        }
        let at = self.len;
        let d = &mut self.buf[at..at + needed];
        d[0] = command.code();
        d[1] = index;
        d[2..6].copy_from_slice(&address.raw().to_le_bytes());
        d[6..8].copy_from_slice(&(len as u16).to_le_bytes());
        d[8..10].fill(0);
        d[DATAGRAM_HEADER_LEN..].fill(0);
        self.len += needed;
        self.last_datagram = Some(at);
        Ok(at)
    }

    /// Writes the EtherCAT header, pads to the 60-byte Ethernet minimum and returns the frame's
    /// length.
    pub fn finish(self) -> usize {
        let ecat_len = (self.len - ETH_HEADER_LEN - ECAT_HEADER_LEN) as u16;
        let header = ecat_len | (u16::from(ECAT_TYPE_COMMANDS) << 12);
        self.buf[ETH_HEADER_LEN..ETH_HEADER_LEN + 2].copy_from_slice(&header.to_le_bytes());
        if self.len < MIN_FRAME_LEN {
            self.buf[self.len..MIN_FRAME_LEN].fill(0);
            MIN_FRAME_LEN
        } else {
            self.len
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::EcatFrame;

    #[test]
    fn builds_the_bytes_a_master_sends() {
        let mut buf = [0u8; 128];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0, 0, 0, 0, 0, 1]).unwrap();
        b.push_zeroed(
            Command::Frmw,
            1,
            DatagramAddress::Configured {
                adp: 0x1000,
                ado: 0x0910,
            },
            8,
        )
        .unwrap();
        b.push(
            Command::Brd,
            2,
            DatagramAddress::Position {
                adp: 0,
                ado: 0x092c,
            },
            &[0; 4],
        )
        .unwrap();
        let n = b.finish();
        assert_eq!(n, 60);
        #[rustfmt::skip]
        let expected: [u8; 52] = [
            0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0, 0, 1, 0x88, 0xa4,
            // EtherCAT header: length 20 + 16 = 36 = 0x24, type 1
            0x24, 0x10,
            // FRMW idx 1, ADP 0x1000, ADO 0x0910, len 8 | more follows
            0x0e, 0x01, 0x00, 0x10, 0x10, 0x09, 0x08, 0x80, 0x00, 0x00,
            0, 0, 0, 0, 0, 0, 0, 0, 0x00, 0x00,
            // BRD idx 2, ADP 0, ADO 0x092C, len 4
            0x07, 0x02, 0x00, 0x00, 0x2c, 0x09, 0x04, 0x00, 0x00, 0x00,
            0, 0, 0, 0, 0x00, 0x00,
        ];
        assert_eq!(&buf[..52], &expected[..]);
        assert!(buf[52..60].iter().all(|&b| b == 0));
        let f = EcatFrame::new_checked(&buf[..n]).unwrap();
        assert_eq!(f.datagrams().count(), 2);
    }

    #[test]
    fn refuses_overflow() {
        let mut buf = [0u8; 64];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0; 6]).unwrap();
        assert!(
            b.push_zeroed(Command::Lrw, 0, DatagramAddress::Logical(0), 40)
                .is_err()
        );
        assert_eq!(
            b.push_zeroed(Command::Lrw, 0, DatagramAddress::Logical(0), 3000),
            Err(WireError::DataTooLong(3000))
        );
        assert!(b.is_empty());
    }
}
