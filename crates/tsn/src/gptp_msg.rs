//! gPTP (IEEE 802.1AS) messages: the PTPv2 common header with majorSdoId 1, and Announce,
//! Sync, Follow_Up (with its information TLV), Pdelay_Req, Pdelay_Resp and
//! Pdelay_Resp_Follow_Up, encoded and decoded in network byte order. Sans-IO and allocation
//! free: [`Message::encode`] writes into a caller's buffer, [`decode`] borrows nothing.
//!
//! Layouts (802.1AS-2020 clause 10.6 and 11.4, IEEE 1588-2019 clause 13): the 34-byte header
//! (`majorSdoId | messageType`, `minorVersionPTP | versionPTP`, messageLength, domainNumber,
//! minorSdoId, flags, correctionField, messageTypeSpecific, sourcePortIdentity, sequenceId,
//! controlField, logMessageInterval), then the body. Timestamps are 48-bit seconds and 32-bit
//! nanoseconds; correctionField is nanoseconds times 2^16.

/// EtherType of PTP over Ethernet.
pub const ETHERTYPE_PTP: u16 = 0x88F7;
/// gPTP's destination address: the nearest-bridge group address (802.1AS 11.3.4).
pub const GPTP_MULTICAST: [u8; 6] = [0x01, 0x80, 0xC2, 0x00, 0x00, 0x0E];
/// Length of the common header.
pub const HEADER_LEN: usize = 34;
/// The longest message [`Message::encode`] writes: an Announce with a path trace of eight
/// clock identities, bytes.
pub const MAX_LEN: usize = HEADER_LEN + 30 + 4 + 8 * 8;

/// `messageType` values.
pub mod message_type {
    /// Sync.
    pub const SYNC: u8 = 0x0;
    /// Pdelay_Req.
    pub const PDELAY_REQ: u8 = 0x2;
    /// Pdelay_Resp.
    pub const PDELAY_RESP: u8 = 0x3;
    /// Follow_Up.
    pub const FOLLOW_UP: u8 = 0x8;
    /// Pdelay_Resp_Follow_Up.
    pub const PDELAY_RESP_FOLLOW_UP: u8 = 0xA;
    /// Announce.
    pub const ANNOUNCE: u8 = 0xB;
}

/// Flag bits (the 16-bit flags field, first octet high).
pub mod flags {
    /// twoStepFlag (octet 0 bit 1).
    pub const TWO_STEP: u16 = 0x0200;
    /// ptpTimescale (octet 1 bit 3).
    pub const PTP_TIMESCALE: u16 = 0x0008;
}

/// A port: the clock's EUI-64 identity and the port number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct PortIdentity {
    /// clockIdentity.
    pub clock_identity: [u8; 8],
    /// portNumber.
    pub port_number: u16,
}

/// A PTP timestamp: 48-bit seconds, nanoseconds below 10^9.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, PartialOrd, Ord)]
pub struct Timestamp {
    /// secondsField (48 bits).
    pub seconds: u64,
    /// nanosecondsField.
    pub nanoseconds: u32,
}

impl Timestamp {
    /// From nanoseconds since the epoch.
    pub fn from_ns(ns: u64) -> Self {
        Timestamp {
            seconds: ns / 1_000_000_000,
            nanoseconds: (ns % 1_000_000_000) as u32,
        }
    }

    /// To nanoseconds since the epoch.
    pub fn to_ns(self) -> u64 {
        self.seconds * 1_000_000_000 + u64::from(self.nanoseconds)
    }
}

/// The common header's fields that vary (the rest follow from the message).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Header {
    /// domainNumber (gPTP: 0).
    pub domain: u8,
    /// flags.
    pub flags: u16,
    /// correctionField: nanoseconds times 2^16.
    pub correction_scaled_ns: i64,
    /// sourcePortIdentity.
    pub source: PortIdentity,
    /// sequenceId.
    pub sequence_id: u16,
    /// logMessageInterval.
    pub log_message_interval: i8,
}

/// The Follow_Up information TLV (802.1AS 11.4.4.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FollowUpInfo {
    /// (rateRatio - 1) * 2^41.
    pub cumulative_scaled_rate_offset: i32,
    /// gmTimeBaseIndicator.
    pub gm_time_base_indicator: u16,
    /// lastGmPhaseChange, ScaledNs: nanoseconds * 2^16 in 96 bits (kept to 64 here; the
    /// upper 32 bits are the sign extension).
    pub last_gm_phase_change_scaled_ns: i64,
    /// scaledLastGmFreqChange.
    pub scaled_last_gm_freq_change: i32,
}

/// grandmasterClockQuality.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct ClockQuality {
    /// clockClass (248: default, 6: locked to a primary reference).
    pub clock_class: u8,
    /// clockAccuracy (0xFE: unknown).
    pub clock_accuracy: u8,
    /// offsetScaledLogVariance.
    pub offset_scaled_log_variance: u16,
}

/// The Announce body (802.1AS 10.6.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Announce {
    /// currentUtcOffset.
    pub current_utc_offset: i16,
    /// grandmasterPriority1.
    pub priority1: u8,
    /// grandmasterClockQuality.
    pub clock_quality: ClockQuality,
    /// grandmasterPriority2.
    pub priority2: u8,
    /// grandmasterIdentity.
    pub grandmaster_identity: [u8; 8],
    /// stepsRemoved.
    pub steps_removed: u16,
    /// timeSource (0xA0: internal oscillator).
    pub time_source: u8,
    /// The path trace TLV: the clock identities the Announce passed (at most 8 kept).
    pub path: [[u8; 8]; 8],
    /// Entries of `path` in use.
    pub path_len: u8,
}

/// A gPTP message body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Message {
    /// Sync (two-step: no timestamp).
    Sync,
    /// Follow_Up: when the Sync left, and the rate to the grandmaster.
    FollowUp {
        /// preciseOriginTimestamp.
        precise_origin: Timestamp,
        /// The information TLV.
        info: FollowUpInfo,
    },
    /// Pdelay_Req.
    PdelayReq,
    /// Pdelay_Resp: when the request arrived (t2).
    PdelayResp {
        /// requestReceiptTimestamp.
        request_receipt: Timestamp,
        /// requestingPortIdentity.
        requesting: PortIdentity,
    },
    /// Pdelay_Resp_Follow_Up: when the response left (t3).
    PdelayRespFollowUp {
        /// responseOriginTimestamp.
        response_origin: Timestamp,
        /// requestingPortIdentity.
        requesting: PortIdentity,
    },
    /// Announce.
    Announce(Announce),
}

/// Why bytes are not a gPTP message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// Shorter than its header or its messageLength says.
    Truncated,
    /// Not PTP version 2 or not majorSdoId 1 (gPTP).
    NotGptp,
    /// A message type this module does not handle.
    UnknownType(u8),
    /// A TLV that should be there is not (type, length).
    BadTlv,
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::Truncated => write!(f, "truncated gPTP message"),
            DecodeError::NotGptp => write!(f, "not a gPTP (PTPv2, majorSdoId 1) message"),
            DecodeError::UnknownType(t) => write!(f, "unhandled PTP message type {t:#x}"),
            DecodeError::BadTlv => write!(f, "missing or malformed TLV"),
        }
    }
}

impl std::error::Error for DecodeError {}

/// The buffer is too small.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BufferTooSmall(pub usize);

impl Message {
    /// messageType.
    pub fn message_type(&self) -> u8 {
        match self {
            Message::Sync => message_type::SYNC,
            Message::FollowUp { .. } => message_type::FOLLOW_UP,
            Message::PdelayReq => message_type::PDELAY_REQ,
            Message::PdelayResp { .. } => message_type::PDELAY_RESP,
            Message::PdelayRespFollowUp { .. } => message_type::PDELAY_RESP_FOLLOW_UP,
            Message::Announce(_) => message_type::ANNOUNCE,
        }
    }

    /// The encoded length.
    pub fn len(&self) -> usize {
        HEADER_LEN
            + match self {
                Message::Sync => 10,
                Message::FollowUp { .. } => 10 + 32,
                Message::PdelayReq => 20,
                Message::PdelayResp { .. } | Message::PdelayRespFollowUp { .. } => 20,
                // MAX_LEN is this with a full path.
                Message::Announce(a) => 30 + 4 + 8 * usize::from(a.path_len.min(8)),
            }
    }

    /// Never empty (the header alone is 34 bytes).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// controlField (1588 v1 compatibility, fixed per type).
    fn control(&self) -> u8 {
        match self {
            Message::Sync => 0,
            Message::FollowUp { .. } => 2,
            _ => 5,
        }
    }

    /// Writes header and body into `buf`, returns the length.
    pub fn encode(&self, h: &Header, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let n = self.len();
        if buf.len() < n {
            return Err(BufferTooSmall(n));
        }
        let b = &mut buf[..n];
        b.fill(0);
        b[0] = 0x10 | self.message_type();
        b[1] = 0x12; // minorVersionPTP 1 (802.1AS-2020), versionPTP 2
        b[2..4].copy_from_slice(&(n as u16).to_be_bytes());
        b[4] = h.domain;
        b[6..8].copy_from_slice(&h.flags.to_be_bytes());
        b[8..16].copy_from_slice(&h.correction_scaled_ns.to_be_bytes());
        put_port(&mut b[20..30], &h.source);
        b[30..32].copy_from_slice(&h.sequence_id.to_be_bytes());
        b[32] = self.control();
        b[33] = h.log_message_interval as u8;
        let body = &mut b[HEADER_LEN..];
        match self {
            Message::Sync | Message::PdelayReq => {}
            Message::FollowUp {
                precise_origin,
                info,
            } => {
                put_ts(&mut body[0..10], precise_origin);
                let t = &mut body[10..42];
                t[0..2].copy_from_slice(&0x0003u16.to_be_bytes()); // ORGANIZATION_EXTENSION
                t[2..4].copy_from_slice(&28u16.to_be_bytes());
                t[4..7].copy_from_slice(&[0x00, 0x80, 0xC2]);
                t[7..10].copy_from_slice(&[0x00, 0x00, 0x01]);
                t[10..14].copy_from_slice(&info.cumulative_scaled_rate_offset.to_be_bytes());
                t[14..16].copy_from_slice(&info.gm_time_base_indicator.to_be_bytes());
                let upper: u32 = if info.last_gm_phase_change_scaled_ns < 0 {
                    u32::MAX
                } else {
                    0
                };
                t[16..20].copy_from_slice(&upper.to_be_bytes());
                t[20..28].copy_from_slice(&info.last_gm_phase_change_scaled_ns.to_be_bytes());
                t[28..32].copy_from_slice(&info.scaled_last_gm_freq_change.to_be_bytes());
            }
            Message::PdelayResp {
                request_receipt: ts,
                requesting,
            }
            | Message::PdelayRespFollowUp {
                response_origin: ts,
                requesting,
            } => {
                put_ts(&mut body[0..10], ts);
                put_port(&mut body[10..20], requesting);
            }
            Message::Announce(a) => {
                body[10..12].copy_from_slice(&a.current_utc_offset.to_be_bytes());
                body[13] = a.priority1;
                body[14] = a.clock_quality.clock_class;
                body[15] = a.clock_quality.clock_accuracy;
                body[16..18]
                    .copy_from_slice(&a.clock_quality.offset_scaled_log_variance.to_be_bytes());
                body[18] = a.priority2;
                body[19..27].copy_from_slice(&a.grandmaster_identity);
                body[27..29].copy_from_slice(&a.steps_removed.to_be_bytes());
                body[29] = a.time_source;
                let k = usize::from(a.path_len.min(8));
                body[30..32].copy_from_slice(&0x0008u16.to_be_bytes()); // PATH_TRACE
                body[32..34].copy_from_slice(&((8 * k) as u16).to_be_bytes());
                for (i, id) in a.path[..k].iter().enumerate() {
                    body[34 + 8 * i..42 + 8 * i].copy_from_slice(id);
                }
            }
        }
        Ok(n)
    }
}

fn put_port(b: &mut [u8], p: &PortIdentity) {
    b[0..8].copy_from_slice(&p.clock_identity);
    b[8..10].copy_from_slice(&p.port_number.to_be_bytes());
}

fn put_ts(b: &mut [u8], t: &Timestamp) {
    b[0..6].copy_from_slice(&t.seconds.to_be_bytes()[2..8]);
    b[6..10].copy_from_slice(&t.nanoseconds.to_be_bytes());
}

fn get_port(b: &[u8]) -> PortIdentity {
    PortIdentity {
        clock_identity: b[0..8].try_into().unwrap_or_default(),
        port_number: u16::from_be_bytes([b[8], b[9]]),
    }
}

fn get_ts(b: &[u8]) -> Timestamp {
    let mut s = [0u8; 8];
    s[2..8].copy_from_slice(&b[0..6]);
    Timestamp {
        seconds: u64::from_be_bytes(s),
        nanoseconds: u32::from_be_bytes([b[6], b[7], b[8], b[9]]),
    }
}

/// Decodes one gPTP message (the PTP payload, after the Ethernet header).
pub fn decode(b: &[u8]) -> Result<(Header, Message), DecodeError> {
    if b.len() < HEADER_LEN {
        return Err(DecodeError::Truncated);
    }
    if b[0] >> 4 != 1 || b[1] & 0x0f != 2 {
        return Err(DecodeError::NotGptp);
    }
    let n = usize::from(u16::from_be_bytes([b[2], b[3]]));
    if n < HEADER_LEN || b.len() < n {
        return Err(DecodeError::Truncated);
    }
    let b = &b[..n];
    let h = Header {
        domain: b[4],
        flags: u16::from_be_bytes([b[6], b[7]]),
        correction_scaled_ns: i64::from_be_bytes(b[8..16].try_into().unwrap_or_default()),
        source: get_port(&b[20..30]),
        sequence_id: u16::from_be_bytes([b[30], b[31]]),
        log_message_interval: b[33] as i8,
    };
    let body = &b[HEADER_LEN..];
    let need = |k: usize| {
        if body.len() < k {
            Err(DecodeError::Truncated)
        } else {
            Ok(())
        }
    };
    let m = match b[0] & 0x0f {
        message_type::SYNC => {
            need(10)?;
            Message::Sync
        }
        message_type::PDELAY_REQ => {
            need(20)?;
            Message::PdelayReq
        }
        message_type::FOLLOW_UP => {
            need(42)?;
            let t = &body[10..42];
            if u16::from_be_bytes([t[0], t[1]]) != 0x0003
                || u16::from_be_bytes([t[2], t[3]]) != 28
                || t[4..7] != [0x00, 0x80, 0xC2]
                || t[7..10] != [0, 0, 1]
            {
                return Err(DecodeError::BadTlv);
            }
            Message::FollowUp {
                precise_origin: get_ts(&body[0..10]),
                info: FollowUpInfo {
                    cumulative_scaled_rate_offset: i32::from_be_bytes([t[10], t[11], t[12], t[13]]),
                    gm_time_base_indicator: u16::from_be_bytes([t[14], t[15]]),
                    last_gm_phase_change_scaled_ns: i64::from_be_bytes(
                        t[20..28].try_into().unwrap_or_default(),
                    ),
                    scaled_last_gm_freq_change: i32::from_be_bytes([t[28], t[29], t[30], t[31]]),
                },
            }
        }
        message_type::PDELAY_RESP => {
            need(20)?;
            Message::PdelayResp {
                request_receipt: get_ts(&body[0..10]),
                requesting: get_port(&body[10..20]),
            }
        }
        message_type::PDELAY_RESP_FOLLOW_UP => {
            need(20)?;
            Message::PdelayRespFollowUp {
                response_origin: get_ts(&body[0..10]),
                requesting: get_port(&body[10..20]),
            }
        }
        message_type::ANNOUNCE => {
            need(34)?;
            if u16::from_be_bytes([body[30], body[31]]) != 0x0008 {
                return Err(DecodeError::BadTlv);
            }
            let len = usize::from(u16::from_be_bytes([body[32], body[33]]));
            if len % 8 != 0 {
                return Err(DecodeError::BadTlv);
            }
            need(34 + len)?;
            let mut a = Announce {
                current_utc_offset: i16::from_be_bytes([body[10], body[11]]),
                priority1: body[13],
                clock_quality: ClockQuality {
                    clock_class: body[14],
                    clock_accuracy: body[15],
                    offset_scaled_log_variance: u16::from_be_bytes([body[16], body[17]]),
                },
                priority2: body[18],
                grandmaster_identity: body[19..27].try_into().unwrap_or_default(),
                steps_removed: u16::from_be_bytes([body[27], body[28]]),
                time_source: body[29],
                ..Announce::default()
            };
            let k = (len / 8).min(8);
            for i in 0..k {
                a.path[i] = body[34 + 8 * i..42 + 8 * i].try_into().unwrap_or_default();
            }
            a.path_len = k as u8;
            Message::Announce(a)
        }
        t => return Err(DecodeError::UnknownType(t)),
    };
    Ok((h, m))
}

/// Wraps an encoded message into an Ethernet frame to the gPTP group address.
pub fn ethernet_frame(src_mac: [u8; 6], payload: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&GPTP_MULTICAST);
    out.extend_from_slice(&src_mac);
    out.extend_from_slice(&ETHERTYPE_PTP.to_be_bytes());
    out.extend_from_slice(payload);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// MAX_LEN is the longest message: an Announce with a full path trace fits it exactly.
    #[test]
    fn max_len_holds_a_full_path_trace() {
        let a = Announce {
            path_len: 8,
            ..Announce::default()
        };
        let m = Message::Announce(a);
        assert_eq!(m.len(), MAX_LEN);
        let mut buf = [0u8; MAX_LEN];
        assert_eq!(m.encode(&Header::default(), &mut buf), Ok(MAX_LEN));
    }

    const CLOCK: [u8; 8] = [0x00, 0x1b, 0x21, 0xff, 0xfe, 0x12, 0x34, 0x56];

    fn header(seq: u16, flags: u16, log: i8) -> Header {
        Header {
            domain: 0,
            flags,
            correction_scaled_ns: 0,
            source: PortIdentity {
                clock_identity: CLOCK,
                port_number: 1,
            },
            sequence_id: seq,
            log_message_interval: log,
        }
    }

    /// The common header of the standard's layout, byte by byte.
    fn expected_header(
        ty: u8,
        len: u16,
        flags: u16,
        corr: i64,
        seq: u16,
        ctl: u8,
        log: i8,
    ) -> Vec<u8> {
        let mut v = vec![0x10 | ty, 0x12];
        v.extend_from_slice(&len.to_be_bytes()); // messageLength
        v.extend_from_slice(&[0, 0]); // domainNumber, minorSdoId
        v.extend_from_slice(&flags.to_be_bytes());
        v.extend_from_slice(&corr.to_be_bytes());
        v.extend_from_slice(&[0, 0, 0, 0]); // messageTypeSpecific
        v.extend_from_slice(&CLOCK);
        v.extend_from_slice(&[0x00, 0x01]); // portNumber
        v.extend_from_slice(&seq.to_be_bytes());
        v.push(ctl);
        v.push(log as u8);
        assert_eq!(v.len(), 34);
        v
    }

    fn roundtrip(h: &Header, m: &Message, expected: &[u8]) {
        let mut buf = [0u8; 128];
        let n = m.encode(h, &mut buf).unwrap();
        assert_eq!(&buf[..n], expected, "{m:?}");
        let (h2, m2) = decode(&buf[..n]).unwrap();
        assert_eq!((&h2, &m2), (h, m));
    }

    #[test]
    fn sync_two_step() {
        let h = header(0x1234, flags::TWO_STEP | flags::PTP_TIMESCALE, -3);
        let mut e = expected_header(0x0, 44, 0x0208, 0, 0x1234, 0, -3);
        e.extend_from_slice(&[0; 10]); // reserved originTimestamp
        roundtrip(&h, &Message::Sync, &e);
    }

    #[test]
    fn follow_up_with_its_information_tlv() {
        let mut h = header(7, flags::PTP_TIMESCALE, -3);
        h.correction_scaled_ns = 1500 << 16; // 1500 ns residence and link delay
        let m = Message::FollowUp {
            precise_origin: Timestamp {
                seconds: 0x0000_0102_0304,
                nanoseconds: 999_999_999,
            },
            info: FollowUpInfo {
                cumulative_scaled_rate_offset: -21_990, // about -0.01 ppm * 2^41
                gm_time_base_indicator: 3,
                last_gm_phase_change_scaled_ns: -(5 << 16),
                scaled_last_gm_freq_change: 17,
            },
        };
        let mut e = expected_header(0x8, 76, 0x0008, 1500 << 16, 7, 2, -3);
        e.extend_from_slice(&[0x00, 0x00, 0x01, 0x02, 0x03, 0x04]); // seconds, 48 bits
        e.extend_from_slice(&999_999_999u32.to_be_bytes());
        e.extend_from_slice(&[0x00, 0x03, 0x00, 0x1c]); // ORGANIZATION_EXTENSION, 28
        e.extend_from_slice(&[0x00, 0x80, 0xc2, 0x00, 0x00, 0x01]); // IEEE 802.1, subtype 1
        e.extend_from_slice(&(-21_990i32).to_be_bytes());
        e.extend_from_slice(&[0x00, 0x03]);
        e.extend_from_slice(&[0xff; 4]); // ScaledNs upper 32 bits: sign
        e.extend_from_slice(&(-(5i64 << 16)).to_be_bytes());
        e.extend_from_slice(&17i32.to_be_bytes());
        roundtrip(&h, &m, &e);
    }

    #[test]
    fn pdelay_req_resp_and_follow_up() {
        let requester = PortIdentity {
            clock_identity: [1, 2, 3, 4, 5, 6, 7, 8],
            port_number: 2,
        };
        let h = header(300, 0, 0);
        let mut e = expected_header(0x2, 54, 0, 0, 300, 5, 0);
        e.extend_from_slice(&[0; 20]); // reserved, reserved
        roundtrip(&h, &Message::PdelayReq, &e);

        let h = header(300, flags::TWO_STEP, 0x7f);
        let m = Message::PdelayResp {
            request_receipt: Timestamp::from_ns(5_000_000_123),
            requesting: requester,
        };
        let mut e = expected_header(0x3, 54, 0x0200, 0, 300, 5, 0x7f);
        e.extend_from_slice(&[0, 0, 0, 0, 0, 5]);
        e.extend_from_slice(&123u32.to_be_bytes());
        e.extend_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8, 0, 2]);
        roundtrip(&h, &m, &e);

        let h = header(300, 0, 0x7f);
        let m = Message::PdelayRespFollowUp {
            response_origin: Timestamp::from_ns(5_000_010_000),
            requesting: requester,
        };
        let mut e = expected_header(0xA, 54, 0, 0, 300, 5, 0x7f);
        e.extend_from_slice(&[0, 0, 0, 0, 0, 5]);
        e.extend_from_slice(&10_000u32.to_be_bytes());
        e.extend_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8, 0, 2]);
        roundtrip(&h, &m, &e);
    }

    #[test]
    fn announce_with_path_trace() {
        let h = header(9, flags::PTP_TIMESCALE, 0);
        let mut a = Announce {
            current_utc_offset: 37,
            priority1: 246,
            clock_quality: ClockQuality {
                clock_class: 248,
                clock_accuracy: 0xfe,
                offset_scaled_log_variance: 0x4e5d,
            },
            priority2: 248,
            grandmaster_identity: CLOCK,
            steps_removed: 1,
            time_source: 0xa0,
            ..Announce::default()
        };
        a.path[0] = CLOCK;
        a.path[1] = [9; 8];
        a.path_len = 2;
        let mut e = expected_header(0xB, 34 + 30 + 4 + 16, 0x0008, 0, 9, 5, 0);
        e.extend_from_slice(&[0; 10]); // reserved originTimestamp
        e.extend_from_slice(&37i16.to_be_bytes());
        e.push(0); // reserved
        e.push(246);
        e.extend_from_slice(&[248, 0xfe, 0x4e, 0x5d]);
        e.push(248);
        e.extend_from_slice(&CLOCK);
        e.extend_from_slice(&[0, 1]);
        e.push(0xa0);
        e.extend_from_slice(&[0x00, 0x08, 0x00, 0x10]); // PATH_TRACE, 16
        e.extend_from_slice(&CLOCK);
        e.extend_from_slice(&[9; 8]);
        roundtrip(&h, &Message::Announce(a), &e);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        assert_eq!(decode(&[]), Err(DecodeError::Truncated));
        let mut buf = [0u8; 128];
        let n = Message::Sync.encode(&header(1, 0, 0), &mut buf).unwrap();
        assert_eq!(decode(&buf[..n - 1]), Err(DecodeError::Truncated));
        buf[0] = 0x00; // majorSdoId 0: PTP, not gPTP
        assert_eq!(decode(&buf[..n]), Err(DecodeError::NotGptp));
        // Every prefix and every single-byte corruption of every message decodes or errs.
        let msgs = [
            Message::Sync,
            Message::PdelayReq,
            Message::FollowUp {
                precise_origin: Timestamp::from_ns(1),
                info: FollowUpInfo::default(),
            },
            Message::Announce(Announce::default()),
        ];
        for m in msgs {
            let n = m.encode(&header(1, 0, 0), &mut buf).unwrap();
            for cut in 0..=n {
                let _ = decode(&buf[..cut]);
            }
            for i in 0..n {
                for v in [0u8, 0xff, 0x0f, 0x80] {
                    let mut c = buf;
                    c[i] = v;
                    let _ = decode(&c[..n]);
                }
            }
        }
    }
}
