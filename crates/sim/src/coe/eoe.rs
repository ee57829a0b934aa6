//! Ethernet over EtherCAT as far as a master configures it (ETG.1000.6 section 5.7): the IP
//! parameters a master sets and reads back, and the address filter, answered by a device
//! whose SII declares EoE (mailbox protocol word 0x1C, bit 1). The Kollmorgen AKD does (word
//! 0x1C = 0x000E in ../shared/captures/soem-sdinfo-akd.pcapng) and answers TwinCAT's Set IP
//! Parameter request; the model answered it with a mailbox error (issue 32 point 7). Ethernet
//! frames themselves (EoE fragments) are taken and dropped: the device has no network stack
//! here.
//!
//! The EoE header (4 bytes after the mailbox header; SOEM's `ec_EOEt`): frame type (bits 0-3)
//! and port (4-7) in byte 0, last fragment (bit 0), time appended (1) and time request (2) in
//! byte 1; bytes 2-3 the fragment information, or in a response the result (0: success). The
//! IP parameters (Set IP Parameter request, Get IP Parameter response) sit at fixed offsets
//! behind a 32-bit flags word, whether included or not: MAC address (6 bytes, flag bit 0), IP
//! address (4, bit 1), subnet mask (4, bit 2), default gateway (4, bit 3), DNS server (4, bit
//! 4), DNS name (32, bit 5).

/// EoE frame types (ETG.1000.6 table 77).
const FRAGMENT: u8 = 0;
const SET_IP_REQUEST: u8 = 2;
const SET_IP_RESPONSE: u8 = 3;
const SET_FILTER_REQUEST: u8 = 4;
const SET_FILTER_RESPONSE: u8 = 5;
const GET_IP_REQUEST: u8 = 6;
const GET_IP_RESPONSE: u8 = 7;
/// Result of a request of a frame type the device does not serve (ETG.1000.6: unsupported
/// frame type).
const RESULT_UNSUPPORTED_FRAME_TYPE: u16 = 0x0001;
/// The EoE header's length, and the IP parameters' behind it (flags and the fields).
const HEADER_LEN: usize = 4;
const IP_PARAMETERS_LEN: usize = 4 + 6 + 4 + 4 + 4 + 4 + 32;

/// The EoE side of a device: the IP parameters as last set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EoeServer {
    /// Flags word and fields, as the last Set IP Parameter request left them (each field
    /// replaced only where its flag was set).
    ip: [u8; IP_PARAMETERS_LEN],
}

impl Default for EoeServer {
    fn default() -> Self {
        EoeServer {
            ip: [0; IP_PARAMETERS_LEN],
        }
    }
}

/// Where each IP parameter lies behind the flags word, by flag bit.
const FIELDS: [(usize, usize); 6] = [(4, 6), (10, 4), (14, 4), (18, 4), (22, 4), (26, 32)];

impl EoeServer {
    /// The answer to the EoE message `req` (the mailbox payload), `None` for one that gets
    /// none (a fragment of an Ethernet frame).
    pub fn handle(&mut self, req: &[u8]) -> Option<Vec<u8>> {
        let b0 = *req.first()?;
        let (frame_type, port) = (b0 & 0x0f, b0 & 0xf0);
        let response = |ty: u8, result: u16| {
            // Last fragment set, the port kept, the result in bytes 2-3.
            let mut out = vec![ty | port, 0x01];
            out.extend_from_slice(&result.to_le_bytes());
            out
        };
        match frame_type {
            FRAGMENT => None,
            SET_IP_REQUEST => {
                let p = req.get(HEADER_LEN..).unwrap_or_default();
                let flags = p
                    .get(..4)
                    .map_or(0, |f| u32::from_le_bytes([f[0], f[1], f[2], f[3]]));
                for (bit, &(at, n)) in FIELDS.iter().enumerate() {
                    if flags & (1 << bit) != 0
                        && let Some(v) = p.get(at..at + n)
                    {
                        self.ip[at..at + n].copy_from_slice(v);
                    }
                }
                // The flags of every parameter set so far.
                let known = u32::from_le_bytes([self.ip[0], self.ip[1], self.ip[2], self.ip[3]]);
                self.ip[..4].copy_from_slice(&(known | (flags & 0x3f)).to_le_bytes());
                Some(response(SET_IP_RESPONSE, 0))
            }
            SET_FILTER_REQUEST => Some(response(SET_FILTER_RESPONSE, 0)),
            GET_IP_REQUEST => {
                let mut out = response(GET_IP_RESPONSE, 0);
                out.extend_from_slice(&self.ip);
                Some(out)
            }
            // A response type from the master, or a type without a service.
            t => Some(response(t, RESULT_UNSUPPORTED_FRAME_TYPE)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// TwinCAT's and SOEM's Set IP Parameter request (ETG.1000.6; SOEM `ec_EOEsetIp`): the
    /// IP address and subnet mask set, answered with frame type 3 and result 0; read back by
    /// Get IP Parameter (frame type 7) with their flags.
    #[test]
    fn set_ip_is_answered_and_read_back() {
        let mut s = EoeServer::default();
        let mut req = vec![SET_IP_REQUEST, 0x01, 0x00, 0x00];
        let mut p = [0u8; IP_PARAMETERS_LEN];
        p[..4].copy_from_slice(&0x0000_0006u32.to_le_bytes());
        p[10..14].copy_from_slice(&[192, 168, 1, 20]);
        p[14..18].copy_from_slice(&[255, 255, 255, 0]);
        req.extend_from_slice(&p);
        assert_eq!(s.handle(&req), Some(vec![0x03, 0x01, 0x00, 0x00]));
        let r = s.handle(&[GET_IP_REQUEST, 0x01, 0, 0]).unwrap();
        assert_eq!(&r[..4], &[0x07, 0x01, 0x00, 0x00]);
        assert_eq!(&r[4..8], &[0x06, 0, 0, 0], "the flags of what is known");
        assert_eq!(&r[14..22], &[192, 168, 1, 20, 255, 255, 255, 0]);
        // A fragment of an Ethernet frame: taken, no answer.
        assert_eq!(s.handle(&[FRAGMENT, 0x01, 0, 0, 0xff, 0xff]), None);
        // A response type from the master: unsupported frame type.
        assert_eq!(
            s.handle(&[SET_IP_RESPONSE, 0x01, 0, 0]),
            Some(vec![0x03, 0x01, 0x01, 0x00])
        );
    }
}
