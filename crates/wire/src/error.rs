/// Why a byte string is not a valid EtherCAT frame or datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// The buffer ends before the structure it should hold.
    #[error("truncated: needed {needed} bytes, have {have}")]
    Truncated {
        /// Bytes the structure needs.
        needed: usize,
        /// Bytes the buffer has.
        have: usize,
    },
    /// The Ethernet frame does not carry EtherType 0x88A4.
    #[error("not an EtherCAT frame (EtherType {0:#06x})")]
    NotEthercat(u16),
    /// The EtherCAT header type is not 1 (EtherCAT commands); network variables and mailbox
    /// gateway frames are not processed by ESCs.
    #[error("unsupported EtherCAT frame type {0}")]
    UnsupportedType(u8),
    /// The EtherCAT header's length does not cover at least one datagram.
    #[error("EtherCAT header length {0} is too short for a datagram")]
    BadFrameLength(u16),
    /// A command byte outside 0..=14.
    #[error("unknown EtherCAT command {0:#04x}")]
    UnknownCommand(u8),
    /// The frame's datagram chain would need more room than the output buffer has.
    #[error("frame buffer full: datagram of {needed} bytes, {free} free")]
    BufferFull {
        /// Bytes the datagram needs.
        needed: usize,
        /// Bytes left in the buffer.
        free: usize,
    },
    /// A datagram's data is longer than the 11-bit length field allows (2035 bytes in a
    /// maximum-size frame).
    #[error("datagram data of {0} bytes exceeds the 11-bit length field")]
    DataTooLong(usize),
    /// AL control or AL status bits 3:0 that name no AL state (valid: 1, 2, 3, 4, 8).
    #[error("unknown AL state {0:#04x}")]
    UnknownAlState(u8),
    /// A mailbox header's type names no protocol (valid: 0-5, 15).
    #[error("unknown mailbox type {0:#04x}")]
    UnknownMailboxType(u8),
    /// A mailbox header announces more data than the buffer holds.
    #[error("mailbox length {length} exceeds the {room} bytes after the header")]
    MailboxLength {
        /// The header's length field.
        length: u16,
        /// Bytes after the header.
        room: u16,
    },
    /// A CoE header's service names none (valid: 1-8).
    #[error("unknown CoE service {0}")]
    UnknownCoeService(u8),
    /// An SDO command specifier names no request (valid: 0-4).
    #[error("unknown SDO command specifier {0}")]
    UnknownSdoCommand(u8),
    /// An SDO Information opcode that names no request.
    #[error("unknown SDO Information opcode {0}")]
    UnknownSdoInfoOpcode(u8),
    /// A register field holds a value the datasheet reserves.
    #[error("reserved value {value:#04x} in the {field}")]
    Reserved {
        /// The field (e.g. "SyncManager direction").
        field: &'static str,
        /// The value found.
        value: u8,
    },
}
