//! The EtherCAT mailbox (ETG.1000.4 section 5.6, ETG.1000.6 section 5.6): the 6-byte header
//! every mailbox message starts with, the mailbox error reply, and the CoE protocol carried in
//! it (ETG.1000.6 section 5.6.2): its 2-byte header, the SDO services (expedited, normal and
//! segmented transfer, complete access, abort) and SDO Information.
//!
//! A mailbox message travels in a SyncManager's buffer (SM0 master to slave, SM1 back), written
//! and read whole by one datagram; the buffer is longer than most messages, and `length` says how
//! much of it counts.
//!
//! ```
//! use ecsync_wire::mailbox::{Mailbox, MailboxType, coe::{CoeService, Sdo, SdoRequest}};
//!
//! // SOEM's SDO upload of 0x1C32:01 (expedited, as its ecx_SDOread sends it).
//! let msg = [10, 0, 0, 0, 0, 0x13, 0x00, 0x20, 0x40, 0x32, 0x1c, 0x01, 0, 0, 0, 0];
//! let m = Mailbox::new_checked(&msg[..]).unwrap();
//! assert_eq!(m.mailbox_type(), Ok(MailboxType::Coe));
//! assert_eq!(m.counter(), 1);
//! let coe = ecsync_wire::mailbox::coe::Coe::new_checked(m.payload()).unwrap();
//! assert_eq!(coe.service(), Ok(CoeService::SdoRequest));
//! let req = Sdo::new_checked(coe.payload()).unwrap().request().unwrap();
//! assert_eq!(
//!     req,
//!     SdoRequest::InitiateUpload { index: 0x1c32, subindex: 1, complete_access: false }
//! );
//! ```

use crate::error::WireError;

/// Bytes of the mailbox header.
pub const MAILBOX_HEADER_LEN: usize = 6;

/// The protocol a mailbox message carries (header byte 5, bits 3:0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum MailboxType {
    /// A mailbox error reply (ETG.1000.4 table 29).
    Error = 0x00,
    /// ADS over EtherCAT.
    Aoe = 0x01,
    /// Ethernet over EtherCAT.
    Eoe = 0x02,
    /// CAN application protocol over EtherCAT.
    Coe = 0x03,
    /// File access over EtherCAT.
    Foe = 0x04,
    /// Servo drive profile over EtherCAT.
    Soe = 0x05,
    /// Vendor specific.
    Voe = 0x0f,
}

impl MailboxType {
    /// The type of the 4-bit code.
    pub const fn from_code(code: u8) -> Result<Self, WireError> {
        match code & 0x0f {
            0x00 => Ok(MailboxType::Error),
            0x01 => Ok(MailboxType::Aoe),
            0x02 => Ok(MailboxType::Eoe),
            0x03 => Ok(MailboxType::Coe),
            0x04 => Ok(MailboxType::Foe),
            0x05 => Ok(MailboxType::Soe),
            0x0f => Ok(MailboxType::Voe),
            v => Err(WireError::UnknownMailboxType(v)),
        }
    }

    /// The SII's mailbox protocol bit of this protocol (word 0x1C), 0 for the error type.
    pub const fn protocol_bit(self) -> u16 {
        match self {
            MailboxType::Error => 0,
            MailboxType::Aoe => 0x0001,
            MailboxType::Eoe => 0x0002,
            MailboxType::Coe => 0x0004,
            MailboxType::Foe => 0x0008,
            MailboxType::Soe => 0x0010,
            MailboxType::Voe => 0x0020,
        }
    }
}

/// A mailbox message: the header and the protocol's data, over a buffer at least as long as
/// the header says.
#[derive(Debug, Clone, Copy)]
pub struct Mailbox<T: AsRef<[u8]>> {
    buf: T,
}

impl<T: AsRef<[u8]>> Mailbox<T> {
    /// Wraps without checks (accessors may panic on a short buffer).
    pub const fn new_unchecked(buf: T) -> Self {
        Mailbox { buf }
    }

    /// Wraps a buffer that holds a header and the `length` bytes it announces.
    pub fn new_checked(buf: T) -> Result<Self, WireError> {
        let m = Mailbox { buf };
        let b = m.buf.as_ref();
        if b.len() < MAILBOX_HEADER_LEN {
            return Err(WireError::Truncated {
                needed: MAILBOX_HEADER_LEN,
                have: b.len(),
            });
        }
        if MAILBOX_HEADER_LEN + usize::from(m.length()) > b.len() {
            return Err(WireError::MailboxLength {
                length: m.length(),
                room: (b.len() - MAILBOX_HEADER_LEN) as u16,
            });
        }
        Ok(m)
    }

    /// Bytes of data after the header.
    pub fn length(&self) -> u16 {
        let b = self.buf.as_ref();
        u16::from_le_bytes([b[0], b[1]])
    }

    /// Station address of the source (a slave's reply) or destination (0 from the master).
    pub fn address(&self) -> u16 {
        let b = self.buf.as_ref();
        u16::from_le_bytes([b[2], b[3]])
    }

    /// Channel (byte 4, bits 5:0).
    pub fn channel(&self) -> u8 {
        self.buf.as_ref()[4] & 0x3f
    }

    /// Priority (byte 4, bits 7:6).
    pub fn priority(&self) -> u8 {
        self.buf.as_ref()[4] >> 6
    }

    /// The protocol.
    pub fn mailbox_type(&self) -> Result<MailboxType, WireError> {
        MailboxType::from_code(self.buf.as_ref()[5])
    }

    /// The 4-bit type code as sent.
    pub fn type_code(&self) -> u8 {
        self.buf.as_ref()[5] & 0x0f
    }

    /// The counter (byte 5, bits 6:4): 1 to 7 in turn, 0 from a master that does not count; a
    /// slave that sees the same counter twice takes the message as a repeat.
    pub fn counter(&self) -> u8 {
        (self.buf.as_ref()[5] >> 4) & 0x07
    }

    /// The protocol's data (`length` bytes).
    pub fn payload(&self) -> &[u8] {
        let n = usize::from(self.length());
        &self.buf.as_ref()[MAILBOX_HEADER_LEN..MAILBOX_HEADER_LEN + n]
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Mailbox<T> {
    /// Writes the header.
    pub fn set_header(&mut self, h: &MailboxRepr) {
        let b = self.buf.as_mut();
        b[0..2].copy_from_slice(&h.length.to_le_bytes());
        b[2..4].copy_from_slice(&h.address.to_le_bytes());
        b[4] = (h.channel & 0x3f) | (h.priority << 6);
        b[5] = (h.mailbox_type as u8 & 0x0f) | ((h.counter & 0x07) << 4);
    }

    /// The protocol's data, to write (everything after the header).
    pub fn payload_mut(&mut self) -> &mut [u8] {
        &mut self.buf.as_mut()[MAILBOX_HEADER_LEN..]
    }
}

/// A mailbox header's fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MailboxRepr {
    /// Bytes of data after the header.
    pub length: u16,
    /// Station address.
    pub address: u16,
    /// Channel, 0 to 63.
    pub channel: u8,
    /// Priority, 0 to 3.
    pub priority: u8,
    /// Protocol.
    pub mailbox_type: MailboxType,
    /// Counter, 0 to 7.
    pub counter: u8,
}

/// The detail code of a mailbox error reply (ETG.1000.4 table 30).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum MailboxErrorCode {
    /// Syntax of the 6-byte header wrong.
    Syntax = 0x0001,
    /// The protocol is not supported.
    UnsupportedProtocol = 0x0002,
    /// The channel field is not 0.
    InvalidChannel = 0x0003,
    /// The service in the protocol is not supported.
    ServiceNotSupported = 0x0004,
    /// The protocol header is wrong (beyond the mailbox header).
    InvalidHeader = 0x0005,
    /// The received data is too short.
    SizeTooShort = 0x0006,
    /// The slave cannot take the message (no memory).
    NoMoreMemory = 0x0007,
    /// The length is inconsistent.
    InvalidSize = 0x0008,
}

/// Bytes of a mailbox error reply's data: service 0x0001 and the detail.
pub const MAILBOX_ERROR_LEN: usize = 4;

/// Writes a mailbox error reply from station `address` into `out` (at least
/// [`MAILBOX_HEADER_LEN`] + [`MAILBOX_ERROR_LEN`] bytes); returns its length.
pub fn emit_mailbox_error(
    out: &mut [u8],
    address: u16,
    counter: u8,
    code: MailboxErrorCode,
) -> Result<usize, WireError> {
    let n = MAILBOX_HEADER_LEN + MAILBOX_ERROR_LEN;
    if out.len() < n {
        return Err(WireError::Truncated {
            needed: n,
            have: out.len(),
        });
    }
    let mut m = Mailbox::new_unchecked(&mut out[..n]);
    m.set_header(&MailboxRepr {
        length: MAILBOX_ERROR_LEN as u16,
        address,
        channel: 0,
        priority: 0,
        mailbox_type: MailboxType::Error,
        counter,
    });
    let p = m.payload_mut();
    p[0..2].copy_from_slice(&1u16.to_le_bytes());
    p[2..4].copy_from_slice(&(code as u16).to_le_bytes());
    Ok(n)
}

pub mod coe {
    //! CoE (ETG.1000.6 section 5.6.2): the 2-byte CoE header, SDO requests and responses,
    //! abort codes, SDO Information and emergency messages.

    use crate::error::WireError;

    /// Bytes of the CoE header.
    pub const COE_HEADER_LEN: usize = 2;
    /// Bytes of an SDO's fixed part after the CoE header: command, index, subindex, 4 data.
    pub const SDO_LEN: usize = 8;
    /// Bytes of an SDO segment's header (the command byte) after the CoE header.
    pub const SDO_SEGMENT_HEADER_LEN: usize = 1;
    /// The smallest segment data an SDO segment carries (padded), bytes.
    pub const SDO_SEGMENT_MIN_DATA: usize = 7;

    /// The CoE service (CoE header bits 15:12).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
    #[repr(u8)]
    pub enum CoeService {
        /// Emergency message from the slave.
        Emergency = 1,
        /// SDO request (master to slave).
        SdoRequest = 2,
        /// SDO response (slave to master).
        SdoResponse = 3,
        /// TxPDO.
        TxPdo = 4,
        /// RxPDO.
        RxPdo = 5,
        /// TxPDO remote request.
        TxPdoRemoteRequest = 6,
        /// RxPDO remote request.
        RxPdoRemoteRequest = 7,
        /// SDO Information.
        SdoInformation = 8,
    }

    impl CoeService {
        /// The service of the 4-bit code.
        pub const fn from_code(code: u8) -> Result<Self, WireError> {
            match code {
                1 => Ok(CoeService::Emergency),
                2 => Ok(CoeService::SdoRequest),
                3 => Ok(CoeService::SdoResponse),
                4 => Ok(CoeService::TxPdo),
                5 => Ok(CoeService::RxPdo),
                6 => Ok(CoeService::TxPdoRemoteRequest),
                7 => Ok(CoeService::RxPdoRemoteRequest),
                8 => Ok(CoeService::SdoInformation),
                v => Err(WireError::UnknownCoeService(v)),
            }
        }
    }

    /// The CoE header and what follows it (a mailbox message's payload).
    #[derive(Debug, Clone, Copy)]
    pub struct Coe<T: AsRef<[u8]>> {
        buf: T,
    }

    impl<T: AsRef<[u8]>> Coe<T> {
        /// Wraps a mailbox payload that holds at least the CoE header.
        pub fn new_checked(buf: T) -> Result<Self, WireError> {
            if buf.as_ref().len() < COE_HEADER_LEN {
                return Err(WireError::Truncated {
                    needed: COE_HEADER_LEN,
                    have: buf.as_ref().len(),
                });
            }
            Ok(Coe { buf })
        }

        /// The PDO number (bits 8:0; 0 for SDO services).
        pub fn number(&self) -> u16 {
            let b = self.buf.as_ref();
            u16::from_le_bytes([b[0], b[1]]) & 0x01ff
        }

        /// The service.
        pub fn service(&self) -> Result<CoeService, WireError> {
            CoeService::from_code(self.buf.as_ref()[1] >> 4)
        }

        /// Everything after the CoE header.
        pub fn payload(&self) -> &[u8] {
            &self.buf.as_ref()[COE_HEADER_LEN..]
        }
    }

    /// Writes a CoE header into `out[..2]`.
    pub fn emit_coe_header(out: &mut [u8], service: CoeService, number: u16) {
        let v = (number & 0x01ff) | (u16::from(service as u8) << 12);
        out[..2].copy_from_slice(&v.to_le_bytes());
    }

    /// An SDO request as a master sends it (ETG.1000.6 tables 39-49).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum SdoRequest {
        /// Initiate download (ccs 1): an expedited one carries its 1-4 bytes in the request, a
        /// normal one the complete size (and its first data after it).
        InitiateDownload {
            /// Object index.
            index: u16,
            /// Subindex (with complete access: 0 or 1, where the access starts).
            subindex: u8,
            /// Complete access: the whole object at once.
            complete_access: bool,
            /// Expedited: the data is in the 4 bytes of the request.
            expedited: bool,
            /// The size is given: the expedited data's (1-4) or the complete size.
            size: Option<u32>,
        },
        /// Download segment (ccs 0).
        DownloadSegment {
            /// Toggle bit, alternating from 0.
            toggle: bool,
            /// No more segments follow.
            last: bool,
            /// Bytes of data when fewer than 7 (`None`: the mailbox length says).
            short_size: Option<u8>,
        },
        /// Initiate upload (ccs 2).
        InitiateUpload {
            /// Object index.
            index: u16,
            /// Subindex.
            subindex: u8,
            /// Complete access.
            complete_access: bool,
        },
        /// Upload segment (ccs 3).
        UploadSegment {
            /// Toggle bit, alternating from 0.
            toggle: bool,
        },
        /// Abort transfer (ccs 4).
        Abort {
            /// Object index.
            index: u16,
            /// Subindex.
            subindex: u8,
            /// The reason.
            code: u32,
        },
    }

    /// An SDO request or response after the CoE header.
    #[derive(Debug, Clone, Copy)]
    pub struct Sdo<T: AsRef<[u8]>> {
        buf: T,
    }

    impl<T: AsRef<[u8]>> Sdo<T> {
        /// Wraps at least the command byte (a segment) or the 8 fixed bytes (the others; checked
        /// by [`Sdo::request`]).
        pub fn new_checked(buf: T) -> Result<Self, WireError> {
            if buf.as_ref().is_empty() {
                return Err(WireError::Truncated { needed: 1, have: 0 });
            }
            Ok(Sdo { buf })
        }

        /// The command byte.
        pub fn command(&self) -> u8 {
            self.buf.as_ref()[0]
        }

        /// Object index (bytes 1-2).
        pub fn index(&self) -> Option<u16> {
            let b = self.buf.as_ref();
            (b.len() >= 3).then(|| u16::from_le_bytes([b[1], b[2]]))
        }

        /// Subindex (byte 3).
        pub fn subindex(&self) -> Option<u8> {
            self.buf.as_ref().get(3).copied()
        }

        /// The 4 data bytes of an initiate (bytes 4-7).
        pub fn data4(&self) -> Option<[u8; 4]> {
            let b = self.buf.as_ref();
            (b.len() >= SDO_LEN).then(|| [b[4], b[5], b[6], b[7]])
        }

        /// Bytes after the fixed 8 (a normal transfer's first data).
        pub fn rest(&self) -> &[u8] {
            let b = self.buf.as_ref();
            if b.len() > SDO_LEN {
                &b[SDO_LEN..]
            } else {
                &[]
            }
        }

        /// Bytes after the command byte (a segment's data).
        pub fn segment_data(&self) -> &[u8] {
            &self.buf.as_ref()[SDO_SEGMENT_HEADER_LEN..]
        }

        /// The request a master sent: an error for a command specifier that names none, or a
        /// request too short for what it names.
        pub fn request(&self) -> Result<SdoRequest, WireError> {
            let c = self.command();
            let ccs = c >> 5;
            let fixed = || -> Result<(u16, u8, [u8; 4]), WireError> {
                match (self.index(), self.subindex(), self.data4()) {
                    (Some(i), Some(s), Some(d)) => Ok((i, s, d)),
                    _ => Err(WireError::Truncated {
                        needed: SDO_LEN,
                        have: self.buf.as_ref().len(),
                    }),
                }
            };
            match ccs {
                0 => Ok(SdoRequest::DownloadSegment {
                    toggle: c & 0x10 != 0,
                    last: c & 0x01 != 0,
                    short_size: match (c >> 1) & 0x07 {
                        0 => None,
                        n => Some(7 - n),
                    },
                }),
                1 => {
                    let (index, subindex, d) = fixed()?;
                    let expedited = c & 0x02 != 0;
                    let sized = c & 0x01 != 0;
                    let size = match (sized, expedited) {
                        (false, _) => None,
                        (true, true) => Some(4 - u32::from((c >> 2) & 0x03)),
                        (true, false) => Some(u32::from_le_bytes(d)),
                    };
                    Ok(SdoRequest::InitiateDownload {
                        index,
                        subindex,
                        complete_access: c & 0x10 != 0,
                        expedited,
                        size,
                    })
                }
                2 => {
                    let (index, subindex, _) = fixed()?;
                    Ok(SdoRequest::InitiateUpload {
                        index,
                        subindex,
                        complete_access: c & 0x10 != 0,
                    })
                }
                3 => Ok(SdoRequest::UploadSegment {
                    toggle: c & 0x10 != 0,
                }),
                4 => {
                    let (index, subindex, d) = fixed()?;
                    Ok(SdoRequest::Abort {
                        index,
                        subindex,
                        code: u32::from_le_bytes(d),
                    })
                }
                v => Err(WireError::UnknownSdoCommand(v)),
            }
        }
    }

    /// Command byte of an initiate download response (scs 3).
    pub const SDO_DOWNLOAD_RESPONSE: u8 = 0x60;
    /// Command byte of an abort (cs 4).
    pub const SDO_ABORT: u8 = 0x80;

    /// Command byte of an expedited initiate upload response with `n` (1-4) bytes.
    pub const fn upload_expedited_command(n: usize, complete_access: bool) -> u8 {
        0x40 | 0x02 | 0x01 | (((4 - n as u8) & 0x03) << 2) | ((complete_access as u8) << 4)
    }

    /// Command byte of a normal initiate upload response (the complete size in the data).
    pub const fn upload_normal_command(complete_access: bool) -> u8 {
        0x40 | 0x01 | ((complete_access as u8) << 4)
    }

    /// Command byte of a download segment response.
    pub const fn download_segment_response(toggle: bool) -> u8 {
        0x20 | ((toggle as u8) << 4)
    }

    /// Command byte of an upload segment response with `n` bytes (padded to 7 when fewer).
    pub const fn upload_segment_command(toggle: bool, last: bool, n: usize) -> u8 {
        let short = if n < SDO_SEGMENT_MIN_DATA {
            (7 - n as u8) << 1
        } else {
            0
        };
        ((toggle as u8) << 4) | short | (last as u8)
    }

    /// The SDO abort codes (ETG.1000.6 table 41).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    #[repr(u32)]
    pub enum SdoAbortCode {
        /// Toggle bit not changed.
        ToggleBit = 0x0503_0000,
        /// SDO protocol timeout.
        Timeout = 0x0504_0000,
        /// Client/server command specifier not valid or unknown.
        UnknownCommand = 0x0504_0001,
        /// Out of memory.
        OutOfMemory = 0x0504_0005,
        /// Unsupported access to an object.
        UnsupportedAccess = 0x0601_0000,
        /// Attempt to read a write-only object.
        WriteOnly = 0x0601_0001,
        /// Attempt to write a read-only object.
        ReadOnly = 0x0601_0002,
        /// Subindex cannot be written, subindex 0 must be 0 for write access.
        SubindexZeroMustBeZero = 0x0601_0003,
        /// Complete access not supported for objects of variable length.
        CompleteAccessUnsupported = 0x0601_0004,
        /// Object length exceeds the mailbox size.
        ObjectTooLong = 0x0601_0005,
        /// Object mapped to RxPDO, SDO download blocked.
        MappedToRxPdo = 0x0601_0006,
        /// The object does not exist in the object dictionary.
        NoObject = 0x0602_0000,
        /// The object cannot be mapped into the PDO.
        NotMappable = 0x0604_0041,
        /// The number and length of the objects to be mapped would exceed the PDO length.
        PdoTooLong = 0x0604_0042,
        /// General parameter incompatibility.
        ParameterIncompatible = 0x0604_0043,
        /// General internal incompatibility in the device.
        InternalIncompatible = 0x0604_0047,
        /// Access failed due to a hardware error.
        HardwareError = 0x0606_0000,
        /// Data type does not match, length of service parameter does not match.
        LengthMismatch = 0x0607_0010,
        /// Data type does not match, length of service parameter too high.
        LengthTooHigh = 0x0607_0012,
        /// Data type does not match, length of service parameter too low.
        LengthTooLow = 0x0607_0013,
        /// Subindex does not exist.
        NoSubindex = 0x0609_0011,
        /// Value range of parameter exceeded (only for write access).
        ValueRange = 0x0609_0030,
        /// Value of parameter written too high.
        ValueTooHigh = 0x0609_0031,
        /// Value of parameter written too low.
        ValueTooLow = 0x0609_0032,
        /// Maximum value is less than minimum value.
        MaxBelowMin = 0x0609_0036,
        /// General error.
        General = 0x0800_0000,
        /// Data cannot be transferred or stored to the application.
        CannotTransfer = 0x0800_0020,
        /// Data cannot be transferred because of local control.
        LocalControl = 0x0800_0021,
        /// Data cannot be transferred because of the present device state.
        DeviceState = 0x0800_0022,
        /// Object dictionary dynamic generation fails or no object dictionary is present.
        NoDictionary = 0x0800_0023,
    }

    impl SdoAbortCode {
        /// The 32-bit code.
        pub const fn code(self) -> u32 {
            self as u32
        }
    }

    /// Writes an SDO abort (CoE header, command 0x80, index, subindex, code) into `out` (at
    /// least [`COE_HEADER_LEN`] + [`SDO_LEN`] bytes); returns its length.
    pub fn emit_abort(
        out: &mut [u8],
        service: CoeService,
        index: u16,
        subindex: u8,
        code: SdoAbortCode,
    ) -> Result<usize, WireError> {
        let n = COE_HEADER_LEN + SDO_LEN;
        if out.len() < n {
            return Err(WireError::Truncated {
                needed: n,
                have: out.len(),
            });
        }
        emit_coe_header(out, service, 0);
        out[2] = SDO_ABORT;
        out[3..5].copy_from_slice(&index.to_le_bytes());
        out[5] = subindex;
        out[6..10].copy_from_slice(&code.code().to_le_bytes());
        Ok(n)
    }

    /// The SDO Information opcodes (ETG.1000.6 table 43).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    #[repr(u8)]
    pub enum SdoInfoOpcode {
        /// Get OD List request.
        GetOdListRequest = 1,
        /// Get OD List response.
        GetOdListResponse = 2,
        /// Get Object Description request.
        GetObjectDescriptionRequest = 3,
        /// Get Object Description response.
        GetObjectDescriptionResponse = 4,
        /// Get Entry Description request.
        GetEntryDescriptionRequest = 5,
        /// Get Entry Description response.
        GetEntryDescriptionResponse = 6,
        /// SDO Info error request.
        Error = 7,
    }

    impl SdoInfoOpcode {
        /// The opcode of the 7-bit value.
        pub const fn from_code(code: u8) -> Result<Self, WireError> {
            match code & 0x7f {
                1 => Ok(SdoInfoOpcode::GetOdListRequest),
                2 => Ok(SdoInfoOpcode::GetOdListResponse),
                3 => Ok(SdoInfoOpcode::GetObjectDescriptionRequest),
                4 => Ok(SdoInfoOpcode::GetObjectDescriptionResponse),
                5 => Ok(SdoInfoOpcode::GetEntryDescriptionRequest),
                6 => Ok(SdoInfoOpcode::GetEntryDescriptionResponse),
                7 => Ok(SdoInfoOpcode::Error),
                v => Err(WireError::UnknownSdoInfoOpcode(v)),
            }
        }
    }

    /// Bytes of the SDO Information header: opcode (bit 7: incomplete), reserved, fragments
    /// left.
    pub const SDO_INFO_HEADER_LEN: usize = 4;

    /// An SDO Information request as a master sends it.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum SdoInfoRequest {
        /// The list of indices of a kind (0: the count per kind, 1: all, 2: RxPDO-mappable, 3:
        /// TxPDO-mappable, 4: stored for replacement, 5: startup parameters).
        GetOdList {
            /// The list type.
            list_type: u16,
        },
        /// One object's description.
        GetObjectDescription {
            /// Object index.
            index: u16,
        },
        /// One entry's description.
        GetEntryDescription {
            /// Object index.
            index: u16,
            /// Subindex.
            subindex: u8,
            /// The value info bits asked for (unit, default, minimum, maximum).
            value_info: u8,
        },
    }

    /// Reads an SDO Information request (after the CoE header).
    pub fn sdo_info_request(p: &[u8]) -> Result<SdoInfoRequest, WireError> {
        let short = |needed: usize| WireError::Truncated {
            needed,
            have: p.len(),
        };
        if p.len() < SDO_INFO_HEADER_LEN {
            return Err(short(SDO_INFO_HEADER_LEN));
        }
        let body = &p[SDO_INFO_HEADER_LEN..];
        let u16_at = |at: usize| -> Result<u16, WireError> {
            body.get(at..at + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
                .ok_or(short(SDO_INFO_HEADER_LEN + at + 2))
        };
        match SdoInfoOpcode::from_code(p[0])? {
            SdoInfoOpcode::GetOdListRequest => Ok(SdoInfoRequest::GetOdList {
                list_type: u16_at(0)?,
            }),
            SdoInfoOpcode::GetObjectDescriptionRequest => {
                Ok(SdoInfoRequest::GetObjectDescription { index: u16_at(0)? })
            }
            SdoInfoOpcode::GetEntryDescriptionRequest => {
                let index = u16_at(0)?;
                let (Some(&subindex), Some(&value_info)) = (body.get(2), body.get(3)) else {
                    return Err(short(SDO_INFO_HEADER_LEN + 4));
                };
                Ok(SdoInfoRequest::GetEntryDescription {
                    index,
                    subindex,
                    value_info,
                })
            }
            other => Err(WireError::UnknownSdoInfoOpcode(other as u8)),
        }
    }

    /// Writes an SDO Information header (opcode, incomplete flag, fragments left) into
    /// `out[..4]`.
    pub fn emit_sdo_info_header(
        out: &mut [u8],
        opcode: SdoInfoOpcode,
        incomplete: bool,
        fragments_left: u16,
    ) {
        out[0] = opcode as u8 | ((incomplete as u8) << 7);
        out[1] = 0;
        out[2..4].copy_from_slice(&fragments_left.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::coe::*;
    use super::*;

    #[test]
    fn a_header_round_trips_and_a_short_buffer_is_refused() {
        let mut buf = [0u8; 16];
        let h = MailboxRepr {
            length: 10,
            address: 0x1001,
            channel: 0,
            priority: 0,
            mailbox_type: MailboxType::Coe,
            counter: 3,
        };
        Mailbox::new_unchecked(&mut buf[..]).set_header(&h);
        assert_eq!(&buf[..6], &[10, 0, 0x01, 0x10, 0, 0x33]);
        let m = Mailbox::new_checked(&buf[..]).unwrap();
        assert_eq!(
            (m.length(), m.address(), m.counter(), m.mailbox_type()),
            (10, 0x1001, 3, Ok(MailboxType::Coe))
        );
        // Byte 5: the counter in bits 6:4, the type in bits 3:0 (CoE = 3).
        assert_eq!(m.type_code(), 3);
        assert_eq!(m.payload().len(), 10);
        assert!(matches!(
            Mailbox::new_checked(&buf[..15]),
            Err(WireError::MailboxLength {
                length: 10,
                room: 9
            })
        ));
        assert!(Mailbox::new_checked(&buf[..5]).is_err());
    }

    #[test]
    fn the_sdo_requests_of_the_standard_decode() {
        let req = |b: &[u8]| Sdo::new_checked(b).unwrap().request();
        // Expedited download of 2 bytes to 0x1C32:01 (0x2B: ccs 1, n = 2, e, s).
        assert_eq!(
            req(&[0x2b, 0x32, 0x1c, 0x01, 0x02, 0x00, 0, 0]),
            Ok(SdoRequest::InitiateDownload {
                index: 0x1c32,
                subindex: 1,
                complete_access: false,
                expedited: true,
                size: Some(2)
            })
        );
        // Normal download with complete access of 0x1C12, 4 bytes in all (0x31).
        assert_eq!(
            req(&[0x31, 0x12, 0x1c, 0x00, 4, 0, 0, 0, 1, 0, 0, 0x16]),
            Ok(SdoRequest::InitiateDownload {
                index: 0x1c12,
                subindex: 0,
                complete_access: true,
                expedited: false,
                size: Some(4)
            })
        );
        assert_eq!(
            req(&[0x60]),
            Ok(SdoRequest::UploadSegment { toggle: false })
        );
        assert_eq!(req(&[0x70]), Ok(SdoRequest::UploadSegment { toggle: true }));
        // A last download segment of 3 bytes, toggle 1: 0x10 | (7-3)<<1 | 1.
        assert_eq!(
            req(&[0x19, 1, 2, 3, 0, 0, 0, 0]),
            Ok(SdoRequest::DownloadSegment {
                toggle: true,
                last: true,
                short_size: Some(3)
            })
        );
        assert_eq!(
            req(&[0x80, 0x00, 0x10, 0, 0, 0, 2, 6]),
            Ok(SdoRequest::Abort {
                index: 0x1000,
                subindex: 0,
                code: 0x0602_0000
            })
        );
        assert_eq!(
            req(&[0xe0, 0, 0, 0, 0, 0, 0, 0]),
            Err(WireError::UnknownSdoCommand(7))
        );
        assert_eq!(
            req(&[0x40, 0x00]),
            Err(WireError::Truncated { needed: 8, have: 2 })
        );
    }

    #[test]
    fn response_commands_are_the_standards() {
        // Expedited upload responses: 4 bytes 0x43, 2 bytes 0x4B, 1 byte 0x4F.
        assert_eq!(upload_expedited_command(4, false), 0x43);
        assert_eq!(upload_expedited_command(2, false), 0x4b);
        assert_eq!(upload_expedited_command(1, false), 0x4f);
        assert_eq!(upload_normal_command(false), 0x41);
        assert_eq!(upload_normal_command(true), 0x51);
        assert_eq!(download_segment_response(true), 0x30);
        // A last upload segment of 3 bytes with toggle 0: (7-3)<<1 | 1 = 0x09.
        assert_eq!(upload_segment_command(false, true, 3), 0x09);
        assert_eq!(upload_segment_command(true, false, 100), 0x10);
        let mut out = [0u8; 10];
        let n = emit_abort(
            &mut out,
            CoeService::SdoRequest,
            0x1c32,
            1,
            SdoAbortCode::NoSubindex,
        )
        .unwrap();
        assert_eq!(
            &out[..n],
            &[0, 0x20, 0x80, 0x32, 0x1c, 1, 0x11, 0, 0x09, 0x06]
        );
        let mut out = [0u8; 10];
        let n =
            emit_mailbox_error(&mut out, 0x1001, 2, MailboxErrorCode::UnsupportedProtocol).unwrap();
        assert_eq!(&out[..n], &[4, 0, 1, 0x10, 0, 0x20, 1, 0, 2, 0]);
    }

    #[test]
    fn sdo_information_requests_decode() {
        assert_eq!(
            sdo_info_request(&[0x01, 0, 0, 0, 0x01, 0x00]),
            Ok(SdoInfoRequest::GetOdList { list_type: 1 })
        );
        assert_eq!(
            sdo_info_request(&[0x05, 0, 0, 0, 0x18, 0x10, 0x02, 0x00]),
            Ok(SdoInfoRequest::GetEntryDescription {
                index: 0x1018,
                subindex: 2,
                value_info: 0
            })
        );
        assert_eq!(
            sdo_info_request(&[0x03, 0, 0, 0, 0x18]),
            Err(WireError::Truncated { needed: 6, have: 5 })
        );
        assert!(sdo_info_request(&[0x02, 0, 0, 0, 0, 0]).is_err());
    }
}
