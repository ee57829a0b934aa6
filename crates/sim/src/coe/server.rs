//! The SDO server: the mailbox's CoE requests answered from the dictionary (upload, download,
//! segmented and complete access, SDO Information).

use super::dictionary::o_max_sub;
use super::eoe::EoeServer;
use super::*;
use crate::model::DeviceInfo;
use ecsync_wire::AlState;
use ecsync_wire::mailbox::coe::{
    self, COE_HEADER_LEN, CoeService, SDO_INFO_HEADER_LEN, SDO_LEN, SDO_SEGMENT_MIN_DATA, Sdo,
    SdoAbortCode, SdoInfoOpcode, SdoInfoRequest, SdoRequest,
};

/// A transfer in progress over several mailbox messages.
#[derive(Debug, Clone, PartialEq)]
enum Transfer {
    /// Upload segments still to send.
    Upload {
        data: Vec<u8>,
        at: usize,
        toggle: bool,
    },
    /// Download segments still to come.
    Download {
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: usize,
        data: Vec<u8>,
        toggle: bool,
    },
}

/// An SDO abort: the index and subindex it names, and its code.
type SdoAbort = (u16, u8, SdoAbortCode);

/// An SDO response: command `cmd`, the object's `index` and `sub`, the four data bytes
/// `data4`, then `rest`.
fn sdo_response(cmd: u8, index: u16, sub: u8, data4: [u8; 4], rest: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
    coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
    out[2] = cmd;
    out[3..5].copy_from_slice(&index.to_le_bytes());
    out[5] = sub;
    out[6..10].copy_from_slice(&data4);
    out.extend_from_slice(rest);
    out
}

/// A download's initiate response (expedited or normal), bytes 6-9 those of the request
/// (`request4`: its data, or a normal download's size). Real devices answer so: the EL3004's
/// and EK1914's responses carry the request's data (../shared/captures/
/// replay-ek1914-el3004-configure.pcapng, replay-ek1914-el3004-mailbox.pcapng: 0x1A00 after a
/// download of 0x1A00 to 0x1C13:01, 1 after 0xF008:00 = 1), as ETG's slave stack code does,
/// which builds the response in the request's buffer and changes the command byte only.
fn download_response(index: u16, subindex: u8, request4: [u8; 4]) -> Vec<u8> {
    sdo_response(coe::SDO_DOWNLOAD_RESPONSE, index, subindex, request4, &[])
}

/// The SDO server of one drive: its dictionary and the transfer in progress.
#[derive(Debug, Clone, PartialEq)]
pub struct SdoServer {
    /// The dictionary.
    pub od: ObjectDictionary,
    transfer: Option<Transfer>,
    /// The fragments of an SDO Information response still to send, in order (see
    /// [`SdoServer::next_fragment`]).
    fragments: std::collections::VecDeque<Vec<u8>>,
    /// [`SdoServer::set_request_room`].
    request_room: Option<usize>,
    /// EoE, for a device whose SII declares it (see [`SdoServer::eoe`]).
    eoe: Option<EoeServer>,
}

impl SdoServer {
    /// A server for `dev`: on the dictionary its description gives, completed
    /// ([`ObjectDictionary::completed_for`]), else on the one built for it.
    pub fn new(dev: &DeviceInfo) -> Self {
        let od = match &dev.dictionary {
            Some(d) => ObjectDictionary::clone(d).completed_for(dev),
            None => ObjectDictionary::for_device(dev),
        };
        // EoE where the SII's mailbox protocols (word 0x1C) have its bit.
        let eoe_bit = ecsync_wire::mailbox::MailboxType::Eoe.protocol_bit();
        let eoe = dev
            .sii
            .as_ref()
            .is_some_and(|c| c.mailbox_protocols & eoe_bit != 0)
            .then(EoeServer::default);
        SdoServer {
            od,
            transfer: None,
            fragments: std::collections::VecDeque::new(),
            request_room: None,
            eoe,
        }
    }

    /// Answers the EoE message `req` (the mailbox payload): `None` for a device without EoE
    /// (the mailbox answers with an error), `Some(None)` for a message that gets no answer.
    pub fn eoe(&mut self, req: &[u8]) -> Option<Option<Vec<u8>>> {
        self.eoe.as_mut().map(|e| e.handle(req))
    }

    /// Answers the CoE message `req` (the mailbox payload) in `state`, with at most `room`
    /// bytes of CoE data (the mailbox in's size less its header). `None`: a message that gets
    /// no answer (an abort from the master, an emergency). An SDO Information answer longer
    /// than `room` comes as its first fragment; [`SdoServer::next_fragment`] gives the others.
    pub fn handle(
        &mut self,
        req: &[u8],
        state: AlState,
        room: usize,
    ) -> Result<Option<Vec<u8>>, MailboxFault> {
        // A new message: what was left of an earlier answer is not sent any more.
        self.fragments.clear();
        let c = coe::Coe::new_checked(req).map_err(|_| MailboxFault::SizeTooShort)?;
        // SSC's `COE_ServiceInd`: the two services a slave serves, the others a master has no
        // business sending (0x04), and numbers that are no service at all (0x05).
        match c.service() {
            Ok(CoeService::SdoRequest) => self.sdo(c.payload(), state, room).map(Some),
            Ok(CoeService::SdoInformation) => self.sdo_info(c.payload(), room).map(Some),
            Ok(_) => Err(MailboxFault::ServiceNotSupported),
            Err(_) => Err(MailboxFault::InvalidHeader),
        }
    }

    /// The size of the mailbox the master writes to, less its header (SM0's length - 6): an
    /// SDO download longer than it fits is segmented, and its initiate fills the mailbox
    /// (SSC checks this; `None`, the default: not checked).
    pub fn set_request_room(&mut self, room: usize) {
        self.request_room = Some(room);
    }

    /// SSC's length checks of an initiate request (`SDOS_SdoInd`): `p` is the SDO part, so
    /// the mailbox length is `p.len() + 2`.
    fn check_sdo_length(&self, req: &SdoRequest, p: &[u8]) -> Result<(), MailboxFault> {
        let length = COE_HEADER_LEN + p.len();
        // "a SDO Upload request has always a fixed size (2 Byte CoE-Header plus 8 Byte
        // SDO-Header)", and so has an expedited download.
        let fixed = COE_HEADER_LEN + SDO_LEN;
        match *req {
            SdoRequest::InitiateUpload { .. }
            | SdoRequest::InitiateDownload {
                expedited: true, ..
            } if length != fixed => Err(MailboxFault::InvalidSize),
            SdoRequest::InitiateDownload {
                expedited: false,
                size: Some(size),
                ..
            } => {
                let size = size as usize;
                let ok = match self.request_room {
                    // Longer than the mailbox: segmented, the initiate fills the mailbox.
                    Some(room) if fixed + size > room => length == room,
                    // In one message: exactly the header and the data.
                    _ => length == fixed + size,
                };
                if ok {
                    Ok(())
                } else {
                    Err(MailboxFault::InvalidSize)
                }
            }
            _ => Ok(()),
        }
    }

    fn sdo(&mut self, p: &[u8], state: AlState, room: usize) -> Result<Vec<u8>, MailboxFault> {
        let s = Sdo::new_checked(p).map_err(|_| MailboxFault::SizeTooShort)?;
        let (index, sub) = (s.index().unwrap_or(0), s.subindex().unwrap_or(0));
        let abort = |code: SdoAbortCode| {
            let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
            let _ = coe::emit_abort(&mut out, CoeService::SdoRequest, index, sub, code);
            out
        };
        let req = match s.request() {
            Ok(r) => r,
            // An initiate (or abort) shorter than its 8 bytes: its length is not 10 (SSC).
            Err(ecsync_wire::WireError::Truncated { .. }) => {
                return Err(MailboxFault::InvalidSize);
            }
            Err(_) => {
                self.transfer = None;
                return Ok(abort(SdoAbortCode::UnknownCommand));
            }
        };
        self.check_sdo_length(&req, p)?;
        Ok(match self.sdo_request(req, &s, state, room) {
            Ok(out) => out,
            Err((i, si, code)) => {
                self.transfer = None;
                let mut out = vec![0u8; COE_HEADER_LEN + SDO_LEN];
                let _ = coe::emit_abort(&mut out, CoeService::SdoRequest, i, si, code);
                out
            }
        })
    }

    /// One SDO request answered: the response, or the abort (its index, subindex and code).
    fn sdo_request<T: AsRef<[u8]>>(
        &mut self,
        req: SdoRequest,
        s: &Sdo<T>,
        state: AlState,
        room: usize,
    ) -> Result<Vec<u8>, SdoAbort> {
        match req {
            SdoRequest::InitiateUpload {
                index,
                subindex,
                complete_access,
            } => self.initiate_upload(index, subindex, complete_access, room),
            SdoRequest::UploadSegment { toggle } => self.upload_segment(toggle, room),
            SdoRequest::InitiateDownload {
                index,
                subindex,
                complete_access,
                expedited,
                size,
            } => {
                self.transfer = None;
                let d4 = s.data4().unwrap_or([0; 4]);
                if expedited {
                    self.expedited_download(index, subindex, complete_access, size, d4, state)
                } else {
                    let total = size.unwrap_or(0) as usize;
                    self.initiate_download(index, subindex, complete_access, total, s.rest(), state)
                        .map(|()| download_response(index, subindex, d4))
                }
            }
            SdoRequest::DownloadSegment {
                toggle,
                last,
                short_size,
            } => self.download_segment(toggle, last, short_size, s.segment_data(), state),
            SdoRequest::Abort { .. } => {
                self.transfer = None;
                Err((0, 0, SdoAbortCode::General))
            }
        }
    }

    /// An upload's initiate: the value in the response (expedited up to 4 bytes, else normal),
    /// or as much of it as `room` takes and a segmented transfer for the rest.
    fn initiate_upload(
        &mut self,
        index: u16,
        subindex: u8,
        complete_access: bool,
        room: usize,
    ) -> Result<Vec<u8>, SdoAbort> {
        self.transfer = None;
        let data = if complete_access {
            self.od.read_complete(index, subindex)
        } else {
            self.od.read(index, subindex)
        }
        .map_err(|c| (index, subindex, c))?;
        // Up to 4 bytes go expedited, a complete access's too (its command byte with the
        // complete access bit): the LAN9252 (ETG's slave stack code) answers a complete
        // access of a 4-byte 0x1C12 so, 0x53 with length 10
        // (../shared/captures/soem-single-lan9252.pcapng), where a normal answer (0x51,
        // length 14) would carry the same bytes; ETG.1000.6 allows either.
        if data.len() <= 4 {
            let mut d = [0u8; 4];
            d[..data.len()].copy_from_slice(&data);
            let cmd = coe::upload_expedited_command(data.len().max(1), complete_access);
            return Ok(sdo_response(cmd, index, subindex, d, &[]));
        }
        let size = (data.len() as u32).to_le_bytes();
        let fits = room.saturating_sub(COE_HEADER_LEN + SDO_LEN);
        let cmd = coe::upload_normal_command(complete_access);
        if data.len() <= fits {
            return Ok(sdo_response(cmd, index, subindex, size, &data));
        }
        // Segmented: the first part in the initiate response, the rest in segments.
        let first = data[..fits].to_vec();
        self.transfer = Some(Transfer::Upload {
            data,
            at: fits,
            toggle: false,
        });
        Ok(sdo_response(cmd, index, subindex, size, &first))
    }

    /// The next segment of the upload in progress, as much as `room` takes (padded to the
    /// segment's minimum).
    fn upload_segment(&mut self, toggle: bool, room: usize) -> Result<Vec<u8>, SdoAbort> {
        let Some(Transfer::Upload {
            data,
            at,
            toggle: expected,
        }) = self.transfer.as_mut()
        else {
            return Err((0, 0, SdoAbortCode::UnknownCommand));
        };
        if toggle != *expected {
            return Err((0, 0, SdoAbortCode::ToggleBit));
        }
        let fits = room
            .saturating_sub(COE_HEADER_LEN + 1)
            .max(SDO_SEGMENT_MIN_DATA);
        let n = (data.len() - *at).min(fits);
        let last = *at + n >= data.len();
        let mut out = vec![0u8; COE_HEADER_LEN + 1];
        coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
        out[2] = coe::upload_segment_command(toggle, last, n);
        out.extend_from_slice(&data[*at..*at + n]);
        if n < SDO_SEGMENT_MIN_DATA {
            out.resize(COE_HEADER_LEN + 1 + SDO_SEGMENT_MIN_DATA, 0);
        }
        *at += n;
        *expected = !toggle;
        if last {
            self.transfer = None;
        }
        Ok(out)
    }

    /// An expedited download: `size` bytes of the request's four (`d4`) written; unsized, as
    /// many as the entry has.
    fn expedited_download(
        &mut self,
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: Option<u32>,
        d4: [u8; 4],
        state: AlState,
    ) -> Result<Vec<u8>, SdoAbort> {
        let n = size.unwrap_or(4) as usize;
        let v = &d4[..n.min(4)];
        let r = if complete_access {
            self.od.write_complete(index, subindex, v, state)
        } else {
            // An unsized expedited write takes the entry's own length.
            let want = self
                .od
                .read(index, subindex)
                .map_err(|c| (index, subindex, c))?
                .len();
            let v = if size.is_none() {
                &d4[..want.min(4)]
            } else {
                v
            };
            self.od.write(index, subindex, v, state)
        };
        r.map_err(|c| (index, subindex, c))?;
        Ok(download_response(index, subindex, d4))
    }

    /// A normal download's initiate: `total` bytes written if the request carries them all
    /// (`got`), else the start of a segmented transfer; `Ok`: the response is due.
    fn initiate_download(
        &mut self,
        index: u16,
        subindex: u8,
        complete_access: bool,
        total: usize,
        got: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbort> {
        if got.len() >= total {
            self.od
                .write_access(index, subindex, complete_access, &got[..total], state)
                .map_err(|c| (index, subindex, c))?;
        } else {
            self.transfer = Some(Transfer::Download {
                index,
                subindex,
                complete_access,
                size: total,
                data: got.to_vec(),
                toggle: false,
            });
        }
        Ok(())
    }

    /// A segment of the download in progress (`seg`, of which `short_size` bytes count if
    /// given); the last one writes the whole value.
    fn download_segment(
        &mut self,
        toggle: bool,
        last: bool,
        short_size: Option<u8>,
        seg: &[u8],
        state: AlState,
    ) -> Result<Vec<u8>, SdoAbort> {
        let Some(Transfer::Download {
            index,
            subindex,
            complete_access,
            size,
            data,
            toggle: expected,
        }) = self.transfer.as_mut()
        else {
            return Err((0, 0, SdoAbortCode::UnknownCommand));
        };
        let (index, subindex) = (*index, *subindex);
        if toggle != *expected {
            return Err((index, subindex, SdoAbortCode::ToggleBit));
        }
        let n = match short_size {
            Some(n) => usize::from(n).min(seg.len()),
            None => seg.len(),
        };
        data.extend_from_slice(&seg[..n]);
        *expected = !toggle;
        let mut out = vec![0u8; COE_HEADER_LEN + 1];
        coe::emit_coe_header(&mut out, CoeService::SdoResponse, 0);
        out[2] = coe::download_segment_response(toggle);
        out.resize(COE_HEADER_LEN + SDO_LEN, 0);
        if last {
            let (ca, size) = (*complete_access, *size);
            let v = std::mem::take(data);
            self.transfer = None;
            if v.len() < size {
                return Err((index, subindex, SdoAbortCode::LengthTooLow));
            }
            self.od
                .write_access(index, subindex, ca, &v[..size], state)
                .map_err(|c| (index, subindex, c))?;
        }
        Ok(out)
    }

    /// An SDO Information request's answer (an SDO Info error for what it cannot answer), or
    /// the mailbox error of one too short for its opcode.
    fn sdo_info(&mut self, p: &[u8], room: usize) -> Result<Vec<u8>, MailboxFault> {
        // SSC's `SDOS_SdoInfoInd` checks the length first, against the opcode's fixed part:
        // an entry description request has 10 bytes (CoE and SDO Information headers, index,
        // subindex, value info), the others at least 8 (the headers and an index or list type).
        let need = match p.first().map(|&op| op & 0x7f) {
            Some(5) => 10,
            _ => 8,
        };
        if COE_HEADER_LEN + p.len() < need {
            return Err(MailboxFault::SizeTooShort);
        }
        Ok(self.sdo_info_answer(p, room))
    }

    fn sdo_info_answer(&mut self, p: &[u8], room: usize) -> Vec<u8> {
        let mut out = vec![0u8; COE_HEADER_LEN + SDO_INFO_HEADER_LEN];
        coe::emit_coe_header(&mut out, CoeService::SdoInformation, 0);
        let error = |code: SdoAbortCode| {
            let mut e = vec![0u8; COE_HEADER_LEN + SDO_INFO_HEADER_LEN];
            coe::emit_coe_header(&mut e, CoeService::SdoInformation, 0);
            coe::emit_sdo_info_header(&mut e[2..], SdoInfoOpcode::Error, false, 0);
            e.extend_from_slice(&code.code().to_le_bytes());
            e
        };
        // An opcode that is no request (a response's, the error's, an unknown one): SSC
        // answers ABORTIDX_COMMAND_SPECIFIER_UNKNOWN, 0x05040001, in an SDO Info error.
        let Ok(req) = coe::sdo_info_request(p) else {
            return error(SdoAbortCode::UnknownCommand);
        };
        match req {
            SdoInfoRequest::GetOdList { list_type } => {
                let indices: Vec<u16> = match list_type {
                    0 => {
                        // The number of objects of each list type 1-5.
                        let all = self.od.objects.len() as u16;
                        let rx = self.pdo_mappable(0x0040);
                        let tx = self.pdo_mappable(0x0080);
                        vec![all, rx, tx, 0, 0]
                    }
                    1 => self.od.objects.iter().map(|o| o.index).collect(),
                    2 | 3 => {
                        let bit = if list_type == 2 { 0x0040 } else { 0x0080 };
                        self.od
                            .objects
                            .iter()
                            .filter(|o| o.entries.iter().any(|e| e.pdo_mapping & bit != 0))
                            .map(|o| o.index)
                            .collect()
                    }
                    4 | 5 => Vec::new(),
                    _ => return error(SdoAbortCode::UnsupportedAccess),
                };
                // The list type, then the indices; in fragments when longer than the mailbox.
                let mut data = Vec::with_capacity(2 + 2 * indices.len());
                data.extend_from_slice(&list_type.to_le_bytes());
                for i in &indices {
                    data.extend_from_slice(&i.to_le_bytes());
                }
                self.fragmented(SdoInfoOpcode::GetOdListResponse, &data, room)
            }
            // "SDO Info access is only allowed for objects >= 0x1000" (SSC): below are the
            // data type definitions, which this dictionary does not describe.
            SdoInfoRequest::GetObjectDescription { index }
            | SdoInfoRequest::GetEntryDescription { index, .. }
                if index < 0x1000 =>
            {
                error(SdoAbortCode::UnsupportedAccess)
            }
            SdoInfoRequest::GetObjectDescription { index } => {
                let Some(o) = self.od.object(index) else {
                    return error(SdoAbortCode::NoObject);
                };
                coe::emit_sdo_info_header(
                    &mut out[2..],
                    SdoInfoOpcode::GetObjectDescriptionResponse,
                    false,
                    0,
                );
                let dt = o.entries.last().map_or(0, |e| e.data_type);
                out.extend_from_slice(&index.to_le_bytes());
                out.extend_from_slice(&dt.to_le_bytes());
                out.push(o_max_sub(Some(o)));
                out.push(o.code as u8);
                let name = o.name.as_bytes();
                let n = name.len().min(room.saturating_sub(out.len()));
                out.extend_from_slice(&name[..n]);
                out
            }
            SdoInfoRequest::GetEntryDescription {
                index,
                subindex,
                value_info,
            } => {
                let Some(o) = self.od.object(index) else {
                    return error(SdoAbortCode::NoObject);
                };
                let Some(e) = o.entry(subindex) else {
                    return error(SdoAbortCode::NoSubindex);
                };
                coe::emit_sdo_info_header(
                    &mut out[2..],
                    SdoInfoOpcode::GetEntryDescriptionResponse,
                    false,
                    0,
                );
                out.extend_from_slice(&index.to_le_bytes());
                out.push(subindex);
                // Only the description is given (no unit, default, minimum or maximum),
                // whatever `value_info` asked for.
                let _ = value_info;
                out.push(0);
                out.extend_from_slice(&e.data_type.to_le_bytes());
                out.extend_from_slice(&e.bits.to_le_bytes());
                out.extend_from_slice(&(e.access.bits() | e.pdo_mapping).to_le_bytes());
                let name = e.name.as_bytes();
                let n = name.len().min(room.saturating_sub(out.len()));
                out.extend_from_slice(&name[..n]);
                out
            }
        }
    }

    /// The SDO Information response `opcode` with `data` (what follows the SDO Information
    /// header), in as many fragments as `room` bytes of CoE per mailbox need (ETG.1000.6
    /// section 5.6.3): each fragment has the CoE and SDO Information headers, the incomplete
    /// bit on all but the last and the fragments still to come after it (counting down to 0),
    /// and the data goes on from one to the next. Returns the first; the others wait for
    /// [`SdoServer::next_fragment`]. Each fragment carries an even number of data bytes: SOEM
    /// (`ec_readODlist`) takes an OD list fragment as whole 16-bit indices.
    fn fragmented(&mut self, opcode: SdoInfoOpcode, data: &[u8], room: usize) -> Vec<u8> {
        let head = COE_HEADER_LEN + SDO_INFO_HEADER_LEN;
        // At least one index per fragment, whatever the mailbox.
        let per_fragment = (room.saturating_sub(head) & !1).max(2);
        let chunks: Vec<&[u8]> = if data.is_empty() {
            vec![data]
        } else {
            data.chunks(per_fragment).collect()
        };
        let n = chunks.len();
        let mut all = chunks.into_iter().enumerate().map(|(k, c)| {
            let mut out = vec![0u8; head];
            coe::emit_coe_header(&mut out, CoeService::SdoInformation, 0);
            let left = (n - 1 - k) as u16;
            coe::emit_sdo_info_header(&mut out[2..], opcode, left > 0, left);
            out.extend_from_slice(c);
            out
        });
        let first = all.next().unwrap_or_default();
        self.fragments = all.collect();
        first
    }

    /// The next fragment of the SDO Information response being sent, once the master has read
    /// the one before; `None` when it was the last (or the answer was not fragmented).
    pub fn next_fragment(&mut self) -> Option<Vec<u8>> {
        self.fragments.pop_front()
    }

    fn pdo_mappable(&self, bit: u16) -> u16 {
        self.od
            .objects
            .iter()
            .filter(|o| o.entries.iter().any(|e| e.pdo_mapping & bit != 0))
            .count() as u16
    }
}

/// Why a mailbox message gets a mailbox error (ETG.1000.4 table 30, SSC's `MBXERR_*`) instead
/// of a CoE answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MailboxFault {
    /// Too short for what it carries (0x06): a CoE message without its CoE header (this
    /// drive's reading: SSC reads the header past the length), an SDO Information request
    /// shorter than its opcode's fixed part (SSC, `SDOS_SdoInfoInd`).
    SizeTooShort,
    /// A CoE service a slave does not take from a master (0x04): emergency, SDO response, the
    /// PDO services (SSC, `COE_ServiceInd`).
    ServiceNotSupported,
    /// A CoE service number no service has (0x05: 0, 9-15; SSC, `COE_ServiceInd`).
    InvalidHeader,
    /// A length the SDO service does not have (0x08): an initiate upload or expedited
    /// download whose mailbox length is not 10, a normal download whose length disagrees with
    /// its complete size (SSC, `SDOS_SdoInd`).
    InvalidSize,
}
