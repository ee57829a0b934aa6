//! The captured network as the capture itself shows it: how many slaves, each one's registers
//! as the master read them, its SII EEPROM's words, whether its DC registers answered, its
//! mailbox and how long its answers took.

use super::capture::{Addressing, Exchange, is_broadcast, reads, writes};
use crate::common::{Dg, datagrams};
use ecsync_wire::Command;
use std::collections::BTreeMap;

/// SII EEPROM interface registers (ESC datasheet section II, 0x0502-0x050F).
const SII_CONTROL: u16 = 0x0502;
const SII_ADDRESS: u16 = 0x0504;
const SII_DATA: u16 = 0x0508;
/// SII control: busy (bit 15), read command (bit 8).
const SII_BUSY: u16 = 0x8000;
const SII_CMD_READ: u16 = 0x0100;

/// A mailbox's two SyncManagers as the master set them up (start, length of SM0 and SM1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mailbox {
    pub out_start: u16,
    pub out_len: u16,
    pub in_start: u16,
    pub in_len: u16,
}

impl Mailbox {
    pub fn is_out(&self, ado: u16, len: usize) -> bool {
        ado == self.out_start && len > 0
    }

    pub fn is_in(&self, ado: u16, len: usize) -> bool {
        ado == self.in_start && len > 0
    }
}

/// What the capture shows of one slave.
#[derive(Debug, Clone, Default)]
pub struct SlaveFacts {
    /// Its station address, as the master set it.
    pub station: Option<u16>,
    /// Register bytes as first read from this slave alone (a counted APRD or FPRD).
    pub regs: BTreeMap<u16, u8>,
    /// SII words as first read (before any write of the master's).
    pub sii: BTreeMap<u16, u16>,
    /// SII control as first read when idle (its read-size bit 6: 8 or 4 bytes per read).
    pub sii_control: Option<u16>,
    /// Whether an access of the system time registers (0x0910-0x0937) to this slave alone
    /// counted (`Some(false)`: one did not count).
    pub system_time: Option<bool>,
    /// The same for the receive times (0x0900-0x090F).
    pub receive_times: Option<bool>,
    /// The mailbox as the master set up SM0 and SM1 in mailbox mode.
    pub mailbox: Option<Mailbox>,
    /// For each mailbox request: when its answer was there, ns after the request: after the
    /// last SM1 status poll that found SM1 empty (lower bound) and no later than the first
    /// that found it full (upper bound).
    pub response_windows: Vec<(u64, u64)>,
    /// For each AL control write to this slave alone that asked for another state: when AL
    /// status showed it, ns after the write (after the last read that still showed the old
    /// state, no later than the first that showed the new one).
    pub al_windows: Vec<(u64, u64)>,
    /// For each answer the master read, what the SM1 status polls showed after it until the
    /// next answer (see [`Habit`]).
    pub habits: Vec<Habit>,
}

/// What the SM1 status polls after the master read an answer show the application did with
/// its answer buffer (ecsync_sim::AnswerBufferHabit) until its next answer: the read
/// interrupt (0x02) kept all along, or taken (cleared, and the buffer opened: 0x80, or not:
/// 0x00) in a window after the read (ns: after the last poll that still showed 0x02, no
/// later than the first that did not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Habit {
    Keeps,
    Takes { opens: bool, window: (u64, u64) },
}

impl SlaveFacts {
    /// The register `addr` as read (2 bytes, little-endian) if both bytes were.
    pub fn reg16(&self, addr: u16) -> Option<u16> {
        Some(u16::from_le_bytes([
            *self.regs.get(&addr)?,
            *self.regs.get(&(addr + 1))?,
        ]))
    }

    /// The SII word `w`, if read.
    pub fn sii_word(&self, w: u16) -> Option<u16> {
        self.sii.get(&w).copied()
    }

    /// The SII double word at `w`, if both words were read.
    pub fn sii_dword(&self, w: u16) -> Option<u32> {
        Some(u32::from(self.sii_word(w)?) | (u32::from(self.sii_word(w + 1)?) << 16))
    }
}

/// The captured network.
#[derive(Debug, Clone, Default)]
pub struct Network {
    pub slaves: Vec<SlaveFacts>,
    /// BRD of 0x0000 as it came back (the OR of every ESC's type and revision) and its count.
    pub brd_type: Option<(Vec<u8>, u16)>,
    /// The addressing the master set up.
    pub addressing: Addressing,
}

/// Per slave while reading the capture.
#[derive(Debug, Default, Clone, Copy)]
struct Track {
    /// The SII word address of the read in progress.
    sii_addr: Option<u16>,
    /// A write of the master's to the EEPROM was seen (words read after it may be changed).
    sii_written: bool,
    /// The pending mailbox request: when it was written and the last empty poll after it, ns.
    request_ns: Option<(u64, u64)>,
    /// The AL state requested by the last write of AL control, when, and the last read after
    /// it that still showed another state (ns).
    al_request: Option<(u8, u64, u64)>,
    /// AL status (state bits) as last read.
    al_shown: Option<u8>,
    /// Since the master's last read of an answer: when it read; the last SM1 status poll that
    /// still showed the read interrupt, and the first that did not (time, status).
    after_read: Option<u64>,
    polls: [Option<(u64, u8)>; 2],
}

/// Reads the network out of the capture's exchanges.
pub fn derive(exchanges: &[Exchange]) -> Network {
    let mut net = Network::default();
    let mut track: Vec<Track> = Vec::new();
    for ex in exchanges {
        let Some(back) = &ex.back else { continue };
        let sent = datagrams(&ex.sent);
        for (s, d) in sent.iter().zip(datagrams(back)) {
            net.addressing.learn(s.adp, &d);
            if is_broadcast(d.command) {
                broadcast(&mut net, &d);
                continue;
            }
            let Some(p) = net.addressing.position(d.command, s.adp) else {
                continue;
            };
            if net.slaves.len() <= p {
                net.slaves.resize(p + 1, SlaveFacts::default());
            }
            track.resize(net.slaves.len(), Track::default());
            net.slaves[p].station = net.addressing.stations.get(p).copied().flatten();
            one_slave(&mut net.slaves[p], &mut track[p], &d, ex.t_ns);
        }
    }
    // One slave alone: the broadcast read of its type and revision is its own.
    if let ([f], Some((data, 1))) = (net.slaves.as_mut_slice(), &net.brd_type) {
        for (i, b) in data.iter().enumerate() {
            f.regs.entry(i as u16).or_insert(*b);
        }
    }
    net
}

/// A broadcast: the slave count (the most slaves any BRD of the ESC information counted) and
/// the OR of their types.
fn broadcast(net: &mut Network, d: &Dg) {
    if d.command == Command::Brd.code() && d.ado == 0x0000 && net.brd_type.is_none() {
        net.brd_type = Some((d.data.clone(), d.wkc));
    }
    if d.command == Command::Brd.code() && d.ado < 0x0010 {
        let n = usize::from(d.wkc);
        if net.slaves.len() < n {
            net.slaves.resize(n, SlaveFacts::default());
        }
    }
}

/// A datagram that addressed slave `f` alone, as it came back.
fn one_slave(f: &mut SlaveFacts, t: &mut Track, d: &Dg, t_ns: u64) {
    let counted = d.wkc > 0;
    let rd = reads(d.command);
    let wr = writes(d.command);
    // DC: which parts of the block answer.
    let end = d.ado as usize + d.data.len();
    if d.ado < 0x0938 && end > 0x0910 && !d.data.is_empty() {
        f.system_time.get_or_insert(counted);
    } else if d.ado < 0x0910 && end > 0x0900 {
        f.receive_times.get_or_insert(counted);
    }
    if !counted {
        return;
    }
    if rd && d.ado < 0x0500 {
        for (i, b) in d.data.iter().enumerate() {
            f.regs.entry(d.ado + i as u16).or_insert(*b);
        }
    }
    sii(f, t, d, rd, wr);
    if wr && (0x0800..0x0880).contains(&d.ado) {
        sync_managers(f, d);
    }
    al_timing(f, t, d, rd, wr, t_ns);
    mailbox_timing(f, t, d, rd, wr, t_ns);
}

/// The EEPROM interface: the address of each read, the words it returned.
fn sii(f: &mut SlaveFacts, t: &mut Track, d: &Dg, rd: bool, wr: bool) {
    let le16 = |at: usize| u16::from_le_bytes([d.data[at], d.data[at + 1]]);
    if wr && d.ado == SII_CONTROL && d.data.len() >= 6 {
        let control = le16(0);
        if control & 0x0700 == SII_CMD_READ {
            t.sii_addr = Some(le16(2));
        } else if control & 0x0700 != 0 {
            t.sii_written = true;
        }
    }
    if wr && d.ado == SII_ADDRESS && d.data.len() >= 2 {
        t.sii_addr = Some(le16(0));
    }
    if rd && d.ado == SII_CONTROL && d.data.len() >= 2 && le16(0) & SII_BUSY == 0 {
        f.sii_control.get_or_insert(le16(0));
    }
    if rd
        && d.ado == SII_DATA
        && !t.sii_written
        && let Some(a) = t.sii_addr
    {
        for (j, w) in d.data.chunks_exact(2).enumerate() {
            f.sii
                .entry(a + j as u16)
                .or_insert(u16::from_le_bytes([w[0], w[1]]));
        }
    }
}

/// SM0 and SM1 in mailbox mode (control bits 0-1 = 2; bits 2-3: 1 the master writes, 0 it
/// reads), from the master's writes of the SyncManager registers.
fn sync_managers(f: &mut SlaveFacts, d: &Dg) {
    let first = usize::from(d.ado - 0x0800);
    if first % 8 != 0 {
        return;
    }
    for (k, e) in d.data.chunks_exact(8).enumerate() {
        let start = u16::from_le_bytes([e[0], e[1]]);
        let len = u16::from_le_bytes([e[2], e[3]]);
        let (control, enabled) = (e[4], e[6] & 1 != 0);
        if control & 0x03 != 0x02 || !enabled || len == 0 {
            continue;
        }
        let m = f.mailbox.get_or_insert(Mailbox {
            out_start: 0,
            out_len: 0,
            in_start: 0,
            in_len: 0,
        });
        let _sm = first / 8 + k;
        if control & 0x0c == 0x04 {
            (m.out_start, m.out_len) = (start, len);
        } else {
            (m.in_start, m.in_len) = (start, len);
        }
    }
}

/// When each mailbox answer came: a request written into SM0, the SM1 status polls (bit 3,
/// mailbox full) after it.
fn mailbox_timing(f: &mut SlaveFacts, t: &mut Track, d: &Dg, rd: bool, wr: bool, t_ns: u64) {
    let Some(m) = f.mailbox else { return };
    if wr && m.is_out(d.ado, d.data.len()) {
        t.request_ns = Some((t_ns, 0));
        return;
    }
    if rd && m.is_in(d.ado, d.data.len()) {
        t.after_read = Some(t_ns);
        t.polls = [None, None];
        return;
    }
    if rd && d.ado == 0x080d && !d.data.is_empty() {
        habit(f, t, d.data[0], t_ns);
    }
    let Some((req, lower)) = t.request_ns else {
        return;
    };
    if rd && d.ado == 0x080d && !d.data.is_empty() {
        let after = t_ns.saturating_sub(req);
        if d.data[0] & 0x08 == 0 {
            t.request_ns = Some((req, after));
        } else {
            f.response_windows.push((lower, after));
            t.request_ns = None;
        }
    }
}

/// An SM1 status poll `status` at `t_ns` after the master read an answer: the application's
/// habit with its buffer, decided at its next answer (full).
fn habit(f: &mut SlaveFacts, t: &mut Track, status: u8, t_ns: u64) {
    let Some(read) = t.after_read else {
        return;
    };
    if status & 0x08 == 0 {
        match (status & 0x83, t.polls[1]) {
            (0x02, None) => t.polls[0] = Some((t_ns, 0x02)),
            (bits @ (0x00 | 0x80), None) => t.polls[1] = Some((t_ns, bits)),
            _ => {}
        }
        return;
    }
    t.after_read = None;
    let lo = t.polls[0].map_or(0, |p| p.0 - read);
    f.habits.push(match t.polls[1] {
        Some((at, bits)) => Habit::Takes {
            opens: bits == 0x80,
            window: (lo, at - read),
        },
        None => Habit::Keeps,
    });
}

/// When AL status showed the state an AL control write asked for (state bits 0-3; a write of
/// the state already shown is no transition).
fn al_timing(f: &mut SlaveFacts, t: &mut Track, d: &Dg, rd: bool, wr: bool, t_ns: u64) {
    let state = |b: u8| b & 0x0f;
    if wr && d.ado == 0x0120 && !d.data.is_empty() {
        let want = state(d.data[0]);
        t.al_request = (t.al_shown != Some(want)).then_some((want, t_ns, 0));
        return;
    }
    if !(rd && d.ado == 0x0130 && !d.data.is_empty()) {
        return;
    }
    t.al_shown = Some(state(d.data[0]));
    let Some((want, at, lower)) = t.al_request else {
        return;
    };
    let after = t_ns.saturating_sub(at);
    if state(d.data[0]) == want || d.data[0] & 0x10 != 0 {
        // Reached, or refused (the error indication): the firmware has answered.
        f.al_windows.push((lower, after));
        t.al_request = None;
    } else {
        t.al_request = Some((want, at, after));
    }
}
