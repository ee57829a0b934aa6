//! The mailbox exchanges of real captures replayed against devices built to match (issue 13,
//! acceptance 6).
//!
//! Four captures of real hardware in `../shared/captures/` (recorded by the ethercrab project,
//! see that folder's README.md) hold the master's side of CoE mailbox traffic: every frame the
//! master sent, each followed by the frame that came back. What they contain (read with tshark
//! and checked again by the tests below):
//! - `replay-ek1914-el3004-mailbox.pcapng` (ethercrab): an EK1914 coupler (station 0x1000,
//!   mailbox SM0 0x1000/256, SM1 0x1100/256, not used) and an EL3004 (0x1001, SM0 0x1000/128,
//!   SM1 0x1080/128). Three SDO exchanges with the EL3004 in PRE-OP: an expedited upload of
//!   0x100A:00 (software version, 2 bytes), an expedited download of 4 bytes to 0xF008:00 (the
//!   code word) and its upload again.
//! - `replay-ek1914-segmented-upload.pcapng` (ethercrab): the same segment; one upload of the
//!   EK1914's 0x1008:00 (device name, 6 bytes), answered as a normal (not segmented) upload
//!   with the size indicated, the name fitting its 256-byte mailbox.
//! - `soem-sdinfo-akd.pcapng` (SOEM `slaveinfo`): a Kollmorgen AKD (0x1001, SM0 0x1800/1024,
//!   SM1 0x1C00/1024). 35 expedited uploads: SOEM reading the PDO assignment and mapping
//!   (0x1C00:00/03/04, 0x1C12:00-04, 0x1600-0x1603, 0x1C13:00-04, 0x1A00-0x1A03), then SM2/SM3
//!   and SAFE-OP, refused by the drive with AL status code 0x001D. There is no SDO Information
//!   in it: slaveinfo stopped before `-sdo` got its turn.
//! - `soem-sdinfo-ek1100-el1004.pcapng` (SOEM `slaveinfo -sdo`): an EK1100 and an EL1004,
//!   neither with a mailbox (the SII's mailbox words, as SOEM read them, are 0): no mailbox
//!   exchange at all, which [`soem_ek1100_el1004_has_no_mailbox_and_neither_has_the_segment`]
//!   checks.
//!
//! What differed, and was fixed: the address in the mailbox header of every answer. The three
//! devices answer with 0 (the master's address); the ESC put its station address there.
//!
//! In none of them does a master read an empty SM1 (both poll SM1's status 0x080D until the
//! mailbox-full bit is set, then read), write a full SM0, repeat a message or get an abort or a
//! mailbox error.
//!
//! The replay: every frame the master sent is fed, at its captured instant, into a segment of
//! the same devices (station addresses, SyncManagers and AL states then come from the
//! master's own register writes, as they did on the real devices). The devices are built to
//! match: the mailbox layout the capture's SM writes show (and the SII words 0x18-0x1B SOEM
//! read), and an object dictionary holding the objects the capture reads, with the types and
//! sizes its answers show (the device description, written out below from the answers). What
//! is then compared is the ESC's behaviour, datagram by datagram:
//! - every datagram of a mailbox station that touches the mailbox: the SM0 writes (requests),
//!   the SM1 reads (answers), the SM0 and SM1 status polls (0x0805, 0x080D): working counter;
//!   of a status poll the mailbox-full bit (bit 3) and, where the master read 2 bytes, the SM1
//!   activate byte 0x080E;
//! - the SyncManager configuration writes (0x0800-0x080F), AL control writes (0x0120), AL
//!   status reads (0x0130: working counter, state and error bits, and the status code where
//!   read), the broadcast AL status polls: working counter and state;
//! - of every answer read from SM1 ([`Answer`]): the mailbox header (length, address,
//!   channel/priority byte, type, counter), the CoE header (number, service), and for an SDO
//!   response the whole command byte (command specifier scs, expedited, size indicated, the
//!   size bits, complete access; for a segment toggle, last-segment bit and size), index,
//!   subindex, the complete size of a normal upload, the abort code of an abort, the data's
//!   length and the data; for SDO Information the opcode, the incomplete bit and the
//!   fragments left; for a mailbox error its code.
//!
//! Not compared, and why:
//! - the bytes of the SM1 buffer behind the message (the real devices leave old bytes there,
//!   the ESC zeroes them; a master reads `length` bytes);
//! - the other bits of the SM status bytes (interrupt and buffer-state bits: 0x09, 0x80, 0x02
//!   on the EL3004 and AKD after the same accesses; ecsync shows the mailbox-full bit only);
//! - the data of the answers is compared, but it is the description's: the values were read
//!   from the captured answers, so a match shows that the ESC hands a value over unchanged
//!   (byte order, length), not that it knew the value;
//! - the response time of a poll where the real device was still busy but the ESC had
//!   answered (see [`Replay::slower_polls`]): the ESC answers `MailboxLayout::response_ns`
//!   after the request; the EL3004 and EK1914 answered 588-828 us after it in every exchange
//!   (the last poll that found SM1 empty and the first that found it full bound it), so
//!   700 us reproduces every poll; the AKD took between 0.6 and 2.9 ms, no single time fits
//!   all 35, and with 1 ms the polls where the AKD was slower show full on the ESC. Every other
//!   poll, every request and every answer is compared, and a poll the real device answered
//!   full must be full on the ESC;
//! - an AL status read while the real device was still on its way to the state the master
//!   had asked for (the EK1914 took 2 ms from INIT to PRE-OP, the EL3004 0.3 ms, the AKD about
//!   6 ms; the ESC changes state at once): it must show the requested state, and the real
//!   device the one it left; counted in [`Replay::slower_al`]. The error indication bit of a
//!   device in device emulation (see [`Station::al_mask`]);
//! - everything that is not the mailbox: SII contents (the segment's devices carry ecsync's
//!   images; only the mailbox words 0x18-0x1B are compared), DC registers (tests/replay.rs),
//!   process data.

mod common;

use common::{CapturedFrame, Dg, captures_dir, datagrams, has_returned, read_pcapng};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::coe::{Access, Entry, Object, ObjectCode, data_type};
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel, MailboxLayout, PdoEntry, PortKind};
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use ecsync_wire::Command;

/// The segment's time line starts 1 ms before the first frame, ps.
const T0_PS: u64 = 1_000_000_000;

/// How long the ESC takes to answer a message for the Beckhoff terminals: 700 us, inside the
/// 588-828 us every EL3004 and EK1914 answer of the captures lies in.
const BECKHOFF_RESPONSE_NS: u64 = 700_000;

/// The same for the AKD: 1 ms. Its answers came 0.6-2.9 ms after the request.
const AKD_RESPONSE_NS: u64 = 1_000_000;

/// A station of the capture with a mailbox, as its SM0/SM1 writes set it up.
#[derive(Debug, Clone, Copy)]
struct Station {
    address: u16,
    layout: MailboxLayout,
    /// The AL status bits compared: 0x1F (state and error indication), or 0x0F (state) for a
    /// device without a microcontroller, whose ESC runs in device emulation and copies AL
    /// control into AL status bit for bit, the acknowledge bit 4 too (the EK1100 and EL1004
    /// show 0x11 and 0x12 after SOEM's 0x11 and 0x12 with status code 0).
    al_mask: u8,
}

impl Station {
    fn is_out(&self, ado: u16) -> bool {
        (self.layout.out_start..self.layout.out_start + self.layout.out_len).contains(&ado)
    }

    fn is_in(&self, ado: u16) -> bool {
        (self.layout.in_start..self.layout.in_start + self.layout.in_len).contains(&ado)
    }
}

/// The structure of a slave's mailbox message (ETG.1000.4 table 29, ETG.1000.6 section
/// 5.6.2), parsed here from the bytes, independently of ecsync-wire.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Answer {
    /// Mailbox header: length of the data behind it, address, channel and priority (byte 4),
    /// type (0 error, 3 CoE) and counter.
    length: u16,
    address: u16,
    channel_priority: u8,
    mailbox_type: u8,
    counter: u8,
    body: Body,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Body {
    /// A mailbox error (type 0): its code.
    MailboxError { code: u16 },
    /// CoE: the number (bits 0-8 of the CoE header), the service (bits 12-15).
    Coe {
        number: u16,
        service: u8,
        coe: CoeBody,
    },
    /// Another protocol, or too short to say.
    Other,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum CoeBody {
    /// An SDO response (service 3) or an SDO request (service 2, an abort): the command byte
    /// whole, index and subindex (initiate and abort), the complete size of a normal upload,
    /// the abort code, the data.
    Sdo {
        command: u8,
        index: Option<u16>,
        subindex: Option<u8>,
        size: Option<u32>,
        abort: Option<u32>,
        data: Vec<u8>,
    },
    /// SDO Information (service 8): opcode (bits 0-6), incomplete (bit 7), fragments left,
    /// the length of what follows.
    SdoInfo {
        opcode: u8,
        incomplete: bool,
        fragments_left: u16,
        payload_len: usize,
    },
    Other,
}

impl Answer {
    fn parse(buf: &[u8]) -> Answer {
        let le16 = |b: &[u8], at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
        let length = le16(buf, 0);
        let end = (6 + usize::from(length)).min(buf.len());
        let m = &buf[..end];
        let mailbox_type = buf[5] & 0x0f;
        let body = match mailbox_type {
            0 if m.len() >= 10 => Body::MailboxError { code: le16(m, 8) },
            3 if m.len() >= 8 => {
                let c = &m[6..];
                let number = le16(c, 0) & 0x01ff;
                let service = c[1] >> 4;
                let coe = match service {
                    2 | 3 => sdo_body(c),
                    8 if c.len() >= 6 => CoeBody::SdoInfo {
                        opcode: c[2] & 0x7f,
                        incomplete: c[2] & 0x80 != 0,
                        fragments_left: le16(c, 4),
                        payload_len: c.len() - 6,
                    },
                    _ => CoeBody::Other,
                };
                Body::Coe {
                    number,
                    service,
                    coe,
                }
            }
            _ => Body::Other,
        };
        Answer {
            length,
            address: le16(buf, 2),
            channel_priority: buf[4],
            mailbox_type,
            counter: buf[5] >> 4,
            body,
        }
    }
}

/// An SDO frame after the CoE header: `c` is CoE header, command byte, and the rest.
fn sdo_body(c: &[u8]) -> CoeBody {
    let Some(&command) = c.get(2) else {
        return CoeBody::Other;
    };
    let le32 = |at: usize| {
        c.get(at..at + 4)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
    };
    let index = c
        .get(3..5)
        .map(|b| u16::from_le_bytes(b.try_into().unwrap()));
    let subindex = c.get(5).copied();
    let scs = command >> 5;
    let (index, subindex, size, abort, data) = match scs {
        // Initiate upload response: expedited (bit 1) with 4 - n bytes in bytes 6-9 when the
        // size is indicated (bit 0), else normal with the size in bytes 6-9 and the data after.
        2 => {
            if command & 0x02 != 0 {
                let n = if command & 0x01 != 0 {
                    4 - usize::from((command >> 2) & 3)
                } else {
                    4
                };
                let d = c.get(6..6 + n).map(<[u8]>::to_vec).unwrap_or_default();
                (index, subindex, None, None, d)
            } else {
                let d = c.get(10..).map(<[u8]>::to_vec).unwrap_or_default();
                (index, subindex, le32(6), None, d)
            }
        }
        // Initiate download response.
        3 => (index, subindex, None, None, Vec::new()),
        // Upload segment: 7 - n bytes (bits 1-3) of a 7-byte segment, or all that follows.
        0 => {
            let n = usize::from((command >> 1) & 7);
            let seg = c.get(3..).unwrap_or_default();
            let d = if seg.len() <= 7 {
                &seg[..7 - n.min(7)]
            } else {
                seg
            };
            (None, None, None, None, d.to_vec())
        }
        // Download segment response.
        1 => (None, None, None, None, Vec::new()),
        // Abort.
        4 => (index, subindex, None, le32(6), Vec::new()),
        _ => (None, None, None, None, Vec::new()),
    };
    CoeBody::Sdo {
        command,
        index,
        subindex,
        size,
        abort,
        data,
    }
}

/// What a replay found.
#[derive(Debug, Default)]
struct Replay {
    /// Frames fed into the segment, and those without an answer in the capture (fed, not
    /// compared).
    frames: usize,
    unanswered: usize,
    /// Mailbox datagrams compared: SM0 writes, SM1 reads, status polls.
    requests: usize,
    answers: Vec<Answer>,
    polls: usize,
    /// SM1 status polls where the real device had not answered yet but the ESC, answering
    /// `response_ns` after the request, had.
    slower_polls: usize,
    /// AL status reads where the real device still showed the state it had been asked to
    /// leave and the ESC, which changes state at once, the requested one.
    slower_al: usize,
    /// Set-up datagrams compared (SM configuration, AL control and status).
    setup: usize,
    /// SII words 0x18-0x1B (the mailbox layout) as read from the real device and from the
    /// segment's: (station, word, segment, real).
    sii_mailbox_words: Vec<(u16, u16, u16, u16)>,
    mismatches: Vec<String>,
}

/// Per station: the mailbox's state as the real device's answers show it.
#[derive(Debug, Default, Clone, Copy)]
struct Track {
    /// When the pending request was written, ps.
    request_ps: Option<u64>,
    /// The SII word address last written to 0x0504.
    sii_word: Option<u16>,
    /// The AL state last requested (0x0120), and the real device's state before the request.
    al_requested: Option<(u8, u8)>,
    /// The real device's AL state as last read.
    al_real: u8,
}

fn name(code: u8) -> String {
    Command::from_code(code).map_or(format!("{code:#04x}"), |c| format!("{c:?}"))
}

/// Feeds every frame the master sent into `seg` at its captured instant and compares the
/// mailbox datagrams of `stations` as the module's doc lists.
fn replay(frames: &[CapturedFrame], seg: &mut Segment, stations: &[Station]) -> Replay {
    let mut r = Replay::default();
    let mut track = vec![Track::default(); stations.len()];
    let mut i = 0;
    while i < frames.len() {
        let sent = &frames[i];
        assert!(
            !has_returned(&sent.data),
            "frame {} is a request",
            sent.number
        );
        let back = frames.get(i + 1).filter(|f| has_returned(&f.data));
        i += if back.is_some() { 2 } else { 1 };
        let t_ps = T0_PS + sent.t_ns * 1000;
        let mut frame = sent.data.clone();
        let out = seg.process(&mut frame, t_ps);
        r.frames += 1;
        let Some(back) = back else {
            // Lost on the way (SOEM's captures have a few, all AL status polls and SII
            // reads): fed all the same, nothing to compare it with.
            r.unanswered += 1;
            continue;
        };
        assert!(
            out.returned_sof_ps.is_some(),
            "frame {} came back from the real devices but not from the segment",
            sent.number
        );
        let mine = datagrams(&frame);
        let real = datagrams(&back.data);
        assert_eq!(mine.len(), real.len(), "frame {}", back.number);
        for (m, d) in mine.iter().zip(&real) {
            assert_eq!(
                (m.command, m.index, m.ado, m.data.len()),
                (d.command, d.index, d.ado, d.data.len()),
                "frame {}: the same datagram",
                back.number
            );
            compare(&mut r, &mut track, stations, back.number, t_ps, m, d);
        }
    }
    r
}

fn compare(
    r: &mut Replay,
    track: &mut [Track],
    stations: &[Station],
    number: usize,
    t_ps: u64,
    m: &Dg,
    d: &Dg,
) {
    let cmd = Command::from_code(d.command).ok();
    let what = format!(
        "frame {number} {} adp {:#06x} ado {:#06x} len {}",
        name(d.command),
        d.adp,
        d.ado,
        d.data.len()
    );
    let differ = |r: &mut Replay, field: &str, mine: String, real: String| {
        if mine != real {
            r.mismatches
                .push(format!("{what}: {field} {mine} (real {real})"));
        }
    };
    // Broadcast AL status polls (a master waiting for every slave to reach a state).
    if cmd == Some(Command::Brd) && d.ado == 0x0130 {
        r.setup += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        differ(
            r,
            "AL status",
            format!("{:#04x}", m.data[0]),
            format!("{:#04x}", d.data[0]),
        );
        return;
    }
    let (write, read) = match cmd {
        Some(Command::Fpwr) => (true, false),
        Some(Command::Fprd) => (false, true),
        _ => return,
    };
    let Some(k) = stations.iter().position(|s| s.address == d.adp) else {
        return;
    };
    let s = stations[k];
    let t = &mut track[k];
    let ado = d.ado;
    if write && ado == 0x0502 && d.data.len() >= 4 {
        t.sii_word = Some(u16::from_le_bytes([d.data[2], d.data[3]]));
    }
    if read && ado == 0x0508 {
        // The mailbox words of the SII (0x18 out start, 0x19 out size, 0x1A in start, 0x1B in
        // size), wherever a read covers them.
        if let Some(w0) = t.sii_word {
            for (j, c) in d.data.chunks_exact(2).enumerate() {
                let w = w0 + j as u16;
                if (0x18..=0x1b).contains(&w) {
                    let mw = u16::from_le_bytes([m.data[2 * j], m.data[2 * j + 1]]);
                    r.sii_mailbox_words
                        .push((s.address, w, mw, u16::from_le_bytes([c[0], c[1]])));
                }
            }
        }
        return;
    }
    if s.is_out(ado) && write {
        r.requests += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        if d.wkc == 1 {
            t.request_ps = Some(t_ps);
        }
    } else if s.is_in(ado) && read {
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        if d.wkc == 1 && m.wkc == 1 {
            let (mine, real) = (Answer::parse(&m.data), Answer::parse(&d.data));
            differ(r, "answer", format!("{mine:?}"), format!("{real:?}"));
            r.answers.push(real);
            t.request_ps = None;
        }
    } else if read && (ado == 0x0805 || ado == 0x080d) {
        r.polls += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        let full = |dg: &Dg| dg.data[0] & 0x08 != 0;
        let (mine_full, real_full) = (full(m), full(d));
        if ado == 0x080d && mine_full && !real_full {
            // The ESC answered; the real device was still busy. Allowed only once the ESC's
            // response time has passed since the request.
            let response_ps = s.layout.response_ns * 1000;
            let due = t
                .request_ps
                .is_some_and(|at| t_ps.saturating_sub(at) >= response_ps);
            if due {
                r.slower_polls += 1;
            } else {
                differ(r, "SM1 full", "true".into(), "false (not yet due)".into());
            }
        } else {
            differ(
                r,
                "mailbox full",
                mine_full.to_string(),
                real_full.to_string(),
            );
        }
        if ado == 0x080d && d.data.len() >= 2 {
            differ(
                r,
                "SM1 activate",
                format!("{:#04x}", m.data[1]),
                format!("{:#04x}", d.data[1]),
            );
        }
    } else if write && ado == 0x0120 {
        r.setup += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        t.al_requested = Some((d.data[0] & 0x0f, t.al_real));
    } else if write && (0x0800..0x0810).contains(&ado) {
        r.setup += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
    } else if read && ado == 0x0130 {
        r.setup += 1;
        differ(r, "wkc", m.wkc.to_string(), d.wkc.to_string());
        let (mine_state, real_state) = (m.data[0] & s.al_mask, d.data[0] & s.al_mask);
        match t.al_requested {
            // The real device on its way (the EK1914 took 2 ms from INIT to PRE-OP, the
            // EL3004 and the AKD 0.3-6 ms): the ESC is there already.
            Some((to, from)) if mine_state == to && real_state == from && from != to => {
                r.slower_al += 1;
            }
            _ => differ(
                r,
                "AL status",
                format!("{mine_state:#04x}"),
                format!("{real_state:#04x}"),
            ),
        }
        t.al_real = real_state;
        if d.data.len() >= 6 {
            differ(
                r,
                "AL status code",
                format!("{:#06x}", u16::from_le_bytes([m.data[4], m.data[5]])),
                format!("{:#06x}", u16::from_le_bytes([d.data[4], d.data[5]])),
            );
        }
    }
}

// The device descriptions.

fn entry(subindex: u8, name: &str, data_type: u16, access: Access, value: Vec<u8>) -> Entry {
    Entry {
        subindex,
        name: name.to_string(),
        data_type,
        bits: (value.len() * 8) as u16,
        access,
        value,
        pdo_mapping: 0,
    }
}

fn var(index: u16, name: &str, data_type: u16, access: Access, value: Vec<u8>) -> Object {
    Object {
        index,
        name: name.to_string(),
        code: ObjectCode::Var,
        entries: vec![entry(0, name, data_type, access, value)],
    }
}

/// An ARRAY or RECORD of 32-bit (mapping) or 16-bit (assignment) or 8-bit entries, subindex 0
/// the count.
fn list(index: u16, name: &str, code: ObjectCode, data_type: u16, values: &[u32]) -> Object {
    let bytes = match data_type {
        data_type::UINT8 => 1,
        data_type::UINT16 => 2,
        _ => 4,
    };
    let mut entries = vec![entry(
        0,
        "SubIndex 000",
        data_type::UINT8,
        Access::ReadWritePreOp,
        vec![values.len() as u8],
    )];
    for (k, v) in values.iter().enumerate() {
        entries.push(entry(
            k as u8 + 1,
            &format!("SubIndex {:03}", k + 1),
            data_type,
            Access::ReadWritePreOp,
            v.to_le_bytes()[..bytes].to_vec(),
        ));
    }
    Object {
        index,
        name: name.to_string(),
        code,
        entries,
    }
}

fn spec(model: EscModel, device: DeviceInfo, upstream: Upstream, seed: u64) -> SlaveSpec {
    SlaveSpec {
        model,
        device,
        crystal: CrystalParams {
            seed,
            ..Default::default()
        },
        upstream,
        entry_port: 0,
        cable_m: 0.0,
        ring: None,
    }
}

/// The EK1914 (station 0x1000) and the EL3004 (0x1001) of the ethercrab captures, with the
/// objects those captures read: the EK1914's 0x1008 "EK1914" (6 bytes), the EL3004's 0x100A
/// "08" (2 bytes, the answer's expedited size) and its code word 0xF008 (UNSIGNED32, written
/// and read back in PRE-OP).
fn ek1914_el3004() -> (Segment, Vec<Station>) {
    let ek1914_mbx = MailboxLayout {
        out_start: 0x1000,
        out_len: 256,
        in_start: 0x1100,
        in_len: 256,
        response_ns: BECKHOFF_RESPONSE_NS,
    };
    let el3004_mbx = MailboxLayout {
        out_start: 0x1000,
        out_len: 128,
        in_start: 0x1080,
        in_len: 128,
        response_ns: BECKHOFF_RESPONSE_NS,
    };
    // The EK1914: an ET1100 (0x0008 = 0x00FC in the capture), MII towards the master, EBUS
    // towards the terminals (DL status 0x5A33: ports 0 and 1).
    let mut ek1914 = EscModel::junction_mii();
    ek1914.ports = [
        PortKind::Mii,
        PortKind::Ebus,
        PortKind::None,
        PortKind::None,
    ];
    let mut ek1914_dev = DeviceInfo::coupler("EK1914", 1);
    (ek1914_dev.vendor_id, ek1914_dev.product_code) = (0x2, 0x077a_2c52);
    ek1914_dev.mailbox = Some(ek1914_mbx);
    // The EL3004: an ET1200 terminal (0x0008 = 0x01FC), EBUS port 0 only (DL status 0x5613).
    let el3004 = EscModel::ebus_terminal(DcSupport::Full64);
    let mut el3004_dev = DeviceInfo::coupler("EL3004", 2);
    (el3004_dev.vendor_id, el3004_dev.product_code) = (0x2, 0x0bbc_3052);
    el3004_dev.mailbox = Some(el3004_mbx);
    let mut seg = Segment::new(&[
        spec(ek1914, ek1914_dev, Upstream::Master, 1),
        spec(el3004, el3004_dev, Upstream::Slave { index: 0, port: 1 }, 2),
    ])
    .unwrap();
    let ro = Access::ReadOnly;
    let od = &mut seg.esc_mut(0).sdo_server_mut().unwrap().od;
    od.insert(var(
        0x1008,
        "Device name",
        data_type::VISIBLE_STRING,
        ro,
        b"EK1914".to_vec(),
    ));
    let od = &mut seg.esc_mut(1).sdo_server_mut().unwrap().od;
    od.insert(var(
        0x100a,
        "Software version",
        data_type::VISIBLE_STRING,
        ro,
        b"08".to_vec(),
    ));
    od.insert(var(
        0xf008,
        "Code word",
        data_type::UINT32,
        Access::ReadWrite,
        vec![0; 4],
    ));
    (
        seg,
        vec![
            Station {
                address: 0x1000,
                layout: ek1914_mbx,
                al_mask: 0x1f,
            },
            Station {
                address: 0x1001,
                layout: el3004_mbx,
                al_mask: 0x1f,
            },
        ],
    )
}

fn assert_clean(r: &Replay, what: &str) {
    eprintln!(
        "{what}: {} frames ({} unanswered), {} requests, {} answers, {} status polls ({} where \
         the real device was slower), {} set-up datagrams compared ({} AL status reads where \
         the real device was still changing state), {} differences",
        r.frames,
        r.unanswered,
        r.requests,
        r.answers.len(),
        r.polls,
        r.slower_polls,
        r.setup,
        r.slower_al,
        r.mismatches.len()
    );
    assert!(
        r.mismatches.is_empty(),
        "{what}: answered differently from the real devices:\n{}",
        r.mismatches.join("\n")
    );
}

/// The structure of the captured answers, as the test expects them: (counter, command byte,
/// index, subindex, data length).
fn sdo_summary(answers: &[Answer]) -> Vec<(u8, u8, u16, u8, usize)> {
    answers
        .iter()
        .map(|a| match &a.body {
            Body::Coe {
                service: 3,
                coe:
                    CoeBody::Sdo {
                        command,
                        index,
                        subindex,
                        data,
                        ..
                    },
                ..
            } => (
                a.counter,
                *command,
                index.unwrap_or(0),
                subindex.unwrap_or(0),
                data.len(),
            ),
            other => panic!("not an SDO response: {other:?}"),
        })
        .collect()
}

#[test]
#[ignore = "needs ../shared/captures"]
fn el3004_sdo_exchanges_of_replay_ek1914_el3004_mailbox_match_the_real_device() {
    let dir = captures_dir();
    let frames = read_pcapng(&dir.join("replay-ek1914-el3004-mailbox.pcapng"));
    assert_eq!(frames.len(), 994, "the capture as recorded");
    let (mut seg, stations) = ek1914_el3004();
    let r = replay(&frames, &mut seg, &stations);
    assert_clean(&r, "replay-ek1914-el3004-mailbox");
    assert_eq!((r.requests, r.polls, r.slower_polls), (3, 15, 0));
    // The EK1914 showed INIT for 5 polls (2 ms) after PRE-OP was requested, the EL3004 for 1.
    assert_eq!(r.slower_al, 6);
    // Upload of 0x100A:00, expedited 2 bytes (0x4B); download of 0xF008:00 (0x60); upload of
    // 0xF008:00, expedited 4 bytes (0x43); the counter 1, 2, 3.
    assert_eq!(
        sdo_summary(&r.answers),
        [
            (1, 0x4b, 0x100a, 0, 2),
            (2, 0x60, 0xf008, 0, 0),
            (3, 0x43, 0xf008, 0, 4)
        ]
    );
}

#[test]
#[ignore = "needs ../shared/captures"]
fn ek1914_upload_of_replay_ek1914_segmented_upload_matches_the_real_device() {
    let dir = captures_dir();
    let frames = read_pcapng(&dir.join("replay-ek1914-segmented-upload.pcapng"));
    assert_eq!(frames.len(), 964, "the capture as recorded");
    let (mut seg, stations) = ek1914_el3004();
    let r = replay(&frames, &mut seg, &stations);
    assert_clean(&r, "replay-ek1914-segmented-upload");
    assert_eq!((r.requests, r.polls, r.slower_polls), (1, 5, 0));
    assert_eq!(r.slower_al, 5);
    // 0x1008:00, a normal upload with the size indicated (0x41): 6 bytes, in one message.
    assert_eq!(sdo_summary(&r.answers), [(1, 0x41, 0x1008, 0, 6)]);
    let Body::Coe {
        coe: CoeBody::Sdo { size, .. },
        ..
    } = &r.answers[0].body
    else {
        unreachable!()
    };
    assert_eq!(*size, Some(6));
    assert_eq!(r.answers[0].length, 16);
}

/// The Kollmorgen AKD of soem-sdinfo-akd.pcapng (station 0x1001): 1024-byte mailboxes at
/// 0x1800 and 0x1C00, and the PDO assignment and mapping SOEM read from it.
fn akd() -> (Segment, Vec<Station>) {
    let mbx = MailboxLayout {
        out_start: 0x1800,
        out_len: 1024,
        in_start: 0x1c00,
        in_len: 1024,
        response_ns: AKD_RESPONSE_NS,
    };
    let e = |index: u16, bits: u8| PdoEntry {
        index,
        subindex: 0,
        bits,
        name: format!("{index:#06x}"),
    };
    // Identity as SOEM read it from the SII (words 8, 0xA, 0xC).
    let dev = DeviceInfo {
        vendor_id: 0x0000_006a,
        product_code: 0x0041_4b44,
        revision: 0x0000_0002,
        serial: 1,
        name: "AKD".to_string(),
        alias: 0,
        // The assigned PDOs' entries, 17 bytes each way as SOEM sized SM2 and SM3.
        outputs: vec![
            e(0x6040, 16),
            e(0x6040, 16),
            e(0x6060, 8),
            e(0x6040, 16),
            e(0x607a, 32),
            e(0x6040, 16),
            e(0x60ff, 32),
        ],
        inputs: vec![
            e(0x6041, 16),
            e(0x6041, 16),
            e(0x6061, 8),
            e(0x6041, 16),
            e(0x6064, 32),
            e(0x6041, 16),
            e(0x606c, 32),
        ],
        mailbox: Some(mbx),
        dictionary: None,
        dc_opmodes: Vec::new(),
        sii: None,
        pll_limit_ns: 0,
        oversampling: 0,
    };
    let mut seg =
        Segment::new(&[spec(EscModel::servo_mii_dc32(), dev, Upstream::Master, 3)]).unwrap();
    let od = &mut seg.esc_mut(0).sdo_server_mut().unwrap().od;
    let (array, record) = (ObjectCode::Array, ObjectCode::Record);
    od.insert(list(
        0x1c00,
        "Sync manager type",
        array,
        data_type::UINT8,
        &[1, 2, 3, 4],
    ));
    od.insert(list(
        0x1c12,
        "RxPDO assign",
        array,
        data_type::UINT16,
        &[0x1600, 0x1601, 0x1602, 0x1603],
    ));
    od.insert(list(
        0x1c13,
        "TxPDO assign",
        array,
        data_type::UINT16,
        &[0x1a00, 0x1a01, 0x1a02, 0x1a03],
    ));
    for (index, entries) in [
        (0x1600u16, &[0x6040_0010u32][..]),
        (0x1601, &[0x6040_0010, 0x6060_0008]),
        (0x1602, &[0x6040_0010, 0x607a_0020]),
        (0x1603, &[0x6040_0010, 0x60ff_0020]),
        (0x1a00, &[0x6041_0010]),
        (0x1a01, &[0x6041_0010, 0x6061_0008]),
        (0x1a02, &[0x6041_0010, 0x6064_0020]),
        (0x1a03, &[0x6041_0010, 0x606c_0020]),
    ] {
        od.insert(list(
            index,
            "PDO mapping",
            record,
            data_type::UINT32,
            entries,
        ));
    }
    (
        seg,
        vec![Station {
            address: 0x1001,
            layout: mbx,
            al_mask: 0x1f,
        }],
    )
}

#[test]
#[ignore = "needs ../shared/captures"]
fn akd_pdo_uploads_of_soem_sdinfo_akd_match_the_real_drive() {
    let dir = captures_dir();
    let frames = read_pcapng(&dir.join("soem-sdinfo-akd.pcapng"));
    assert_eq!(frames.len(), 6762, "the capture as recorded");
    assert!(
        frames.last().unwrap().t_ns > 6_000_000_000,
        "SOEM's capture counts microseconds (if_tsresol): 6.24 s"
    );
    let (mut seg, stations) = akd();
    let r = replay(&frames, &mut seg, &stations);
    assert_clean(&r, "soem-sdinfo-akd");
    assert_eq!(r.requests, 35);
    // Polls of SM1 where the AKD had not answered yet but the ESC, after 1 ms, had; AL status
    // reads where the AKD still showed INIT after PRE-OP was requested (6 ms).
    assert_eq!((r.polls, r.slower_polls, r.slower_al), (159, 19, 3));
    let summary = sdo_summary(&r.answers);
    // Every answer an expedited upload response with the size indicated: 1 byte (0x4F) for a
    // count, 2 (0x4B) for an assigned PDO, 4 (0x43) for a mapping entry; the counter 1 to 7
    // in turn.
    for (k, (counter, command, index, _, len)) in summary.iter().enumerate() {
        assert_eq!(usize::from(*counter), k % 7 + 1);
        let want = match (index, len) {
            (_, 1) => 0x4f,
            (0x1c12 | 0x1c13, 2) => 0x4b,
            (0x1600..=0x1a03, 4) => 0x43,
            _ => panic!("answer {k}: {index:#06x} with {len} bytes"),
        };
        assert_eq!(*command, want, "answer {k}");
    }
    // The mailbox layout of the SII as SOEM read it.
    assert_eq!(
        r.sii_mailbox_words,
        [
            (0x1001, 0x18, 0x1800, 0x1800),
            (0x1001, 0x19, 0x0400, 0x0400),
            (0x1001, 0x1a, 0x1c00, 0x1c00),
            (0x1001, 0x1b, 0x0400, 0x0400)
        ]
    );
}

#[test]
#[ignore = "needs ../shared/captures"]
fn soem_ek1100_el1004_has_no_mailbox_and_neither_has_the_segment() {
    let dir = captures_dir();
    let frames = read_pcapng(&dir.join("soem-sdinfo-ek1100-el1004.pcapng"));
    assert_eq!(frames.len(), 594, "the capture as recorded");
    // No SyncManager set to mailbox mode (control bits 0-1 = 2), no SM status poll, nothing
    // written to or read from 0x1000 and above but through the process data.
    let mut sm_writes = 0;
    for f in &frames {
        for d in datagrams(&f.data) {
            let fp = matches!(
                Command::from_code(d.command),
                Ok(Command::Fpwr | Command::Fprd | Command::Aprd | Command::Apwr)
            );
            assert!(
                !(fp && (d.ado == 0x0805 || d.ado == 0x080d || d.ado >= 0x1000)),
                "frame {}: a mailbox access",
                f.number
            );
            if d.command == Command::Fpwr.code() && (0x0800..0x0880).contains(&d.ado) {
                sm_writes += 1;
                for sm in d.data.chunks_exact(8) {
                    assert_ne!(sm[4] & 0x03, 0x02, "frame {}: a mailbox SM", f.number);
                }
            }
        }
    }
    assert!(sm_writes > 0, "SOEM set up the EL1004's process data SM");
    // The devices built to match (no mailbox) say so in the SII words SOEM read: 0x18-0x19 of
    // both are 0, so SOEM never asks for CoE or SDO Information.
    let mut seg = Segment::new(&[
        spec(
            EscModel::junction_mii(),
            DeviceInfo::coupler("EK1100", 1),
            Upstream::Master,
            1,
        ),
        spec(
            EscModel::ebus_terminal(DcSupport::Full64),
            DeviceInfo::coupler("EL1004", 2),
            Upstream::Slave { index: 0, port: 1 },
            2,
        ),
    ])
    .unwrap();
    let stations = [0x1001u16, 0x1002].map(|address| Station {
        address,
        // No mailbox: no buffer addresses match.
        layout: MailboxLayout {
            out_start: 0,
            out_len: 0,
            in_start: 0,
            in_len: 0,
            response_ns: 0,
        },
        al_mask: 0x0f,
    });
    let r = replay(&frames, &mut seg, &stations);
    assert_clean(&r, "soem-sdinfo-ek1100-el1004");
    assert_eq!((r.requests, r.answers.len(), r.polls), (0, 0, 0));
    assert_eq!(
        r.sii_mailbox_words,
        [
            (0x1001, 0x18, 0, 0),
            (0x1001, 0x19, 0, 0),
            (0x1002, 0x18, 0, 0),
            (0x1002, 0x19, 0, 0)
        ]
    );
}
