//! The replay: every frame the master sent fed into the segment at its captured instant, each
//! datagram as the segment returned it compared with the real devices' answer, and every
//! difference put in a class (command, register range, what differs).

use super::capture::{Addressing, Exchange, is_logical, name, reads};
use super::network::Mailbox;
use crate::common::{Dg, datagrams};
use ecsync_sim::Segment;
use std::collections::BTreeMap;

/// The segment's time line starts 1 ms before the capture's first frame, ps.
const T0_PS: u64 = 1_000_000_000;

/// SM status bit 3: the mailbox is full (ESC datasheet section II, 0x0805 + 8n).
const SM_MAILBOX_FULL: u8 = 0x08;

/// What a replay found.
#[derive(Debug, Default)]
pub struct Outcome {
    /// Frames fed, and those of them the capture has no answer for (fed, not compared).
    pub frames: usize,
    pub unanswered: usize,
    /// Datagrams compared, and those whose working counter and ADP came back as the real
    /// devices' did.
    pub datagrams: usize,
    pub equal: usize,
    /// Working counter or ADP differences by class, each with the frames it happened in.
    pub differing: BTreeMap<String, Vec<String>>,
    /// SM1 status polls that differ only in the mailbox-full bit, in an exchange whose answer
    /// both the device and the segment then delivered: the answer came at another time.
    pub timing: BTreeMap<String, Vec<String>>,
    /// Differences of the values read (registers the captures' README states facts about,
    /// the mailbox answers), by class.
    pub values: BTreeMap<String, Vec<String>>,
}

impl Outcome {
    /// Datagrams differing in working counter or ADP.
    pub fn differing_total(&self) -> usize {
        self.differing.values().map(Vec::len).sum()
    }

    /// A report: the figures and every class with its count and first instance.
    pub fn report(&self, capture: &str) -> String {
        let mut s = format!(
            "{capture}: {} frames ({} without an answer), {} datagrams, {} equal, {} differing \
             ({} mailbox polls differ by response time only)\n",
            self.frames,
            self.unanswered,
            self.datagrams,
            self.equal,
            self.differing_total(),
            self.timing.values().map(Vec::len).sum::<usize>(),
        );
        for (title, map) in [
            ("wkc/adp", &self.differing),
            ("timing", &self.timing),
            ("value", &self.values),
        ] {
            for (k, v) in map {
                s += &format!("  [{title}] {k}: {} (first: {})\n", v.len(), v[0]);
            }
        }
        s
    }
}

/// The register range a datagram falls in, named (a slave's mailbox buffers by its layout).
fn region(command: u8, ado: u16, mailbox: Option<Mailbox>) -> &'static str {
    if is_logical(command) {
        return "logical";
    }
    if let Some(m) = mailbox {
        if ado == m.out_start {
            return "mailbox out (SM0 buffer)";
        }
        if ado == m.in_start {
            return "mailbox in (SM1 buffer)";
        }
    }
    match ado {
        0x0000..=0x000f => "ESC information 0x0000-0x000F",
        0x0010..=0x0013 => "station address 0x0010-0x0013",
        0x0100..=0x0103 => "DL control 0x0100",
        0x0110..=0x0111 => "DL status 0x0110",
        0x0120..=0x0121 => "AL control 0x0120",
        0x0130..=0x0135 => "AL status 0x0130-0x0135",
        0x0140..=0x0141 => "PDI control 0x0140",
        0x0200..=0x0205 => "event mask 0x0200",
        0x0300..=0x0313 => "error counters 0x0300",
        0x0400..=0x0443 => "watchdogs 0x0400",
        0x0500..=0x0501 => "SII access 0x0500",
        0x0502..=0x0507 => "SII control/address 0x0502",
        0x0508..=0x050f => "SII data 0x0508",
        0x0600..=0x06ff => "FMMU 0x0600",
        0x0805 | 0x080d | 0x0815 | 0x081d => "SM status 0x0805+8n",
        0x0800..=0x087f => "SM 0x0800",
        0x0900..=0x090f => "DC receive times 0x0900",
        0x0910..=0x0917 => "DC system time 0x0910",
        0x0918..=0x091f => "DC receive time PU 0x0918",
        0x0920..=0x092f => "DC offset/delay/difference 0x0920-0x092F",
        0x0930..=0x0937 => "DC speed counter/filters 0x0930",
        0x0980..=0x09ff => "DC SYNC 0x0980",
        0x1000.. => "process RAM",
        _ => "other registers",
    }
}

/// Per station during the replay: the mailbox exchange in progress.
#[derive(Debug, Default, Clone)]
struct Pending {
    /// SM1 status polls since the last request whose mailbox-full bit differed.
    polls: Vec<(String, String)>,
}

/// Replays `exchanges` into `seg`; `mailboxes[p]` is the mailbox of the slave at position `p`.
pub fn replay(exchanges: &[Exchange], seg: &mut Segment, mailboxes: &[Option<Mailbox>]) -> Outcome {
    let mut o = Outcome::default();
    let mut addressing = Addressing::default();
    let mut pending = vec![Pending::default(); mailboxes.len()];
    for ex in exchanges {
        let mut frame = ex.sent.clone();
        let out = seg.process(&mut frame, T0_PS + ex.t_ns * 1000);
        o.frames += 1;
        let Some(real) = ex.replies() else {
            o.unanswered += 1;
            continue;
        };
        assert!(
            out.returned_sof_ps.is_some(),
            "frame {} came back from the real devices, not from the segment",
            ex.number
        );
        let sent = datagrams(&ex.sent);
        let mine = datagrams(&frame);
        assert_eq!(mine.len(), real.len(), "frame {}", ex.number);
        for ((s, m), r) in sent.iter().zip(&mine).zip(&real) {
            addressing.learn(s.adp, r);
            let pos = addressing.position(r.command, s.adp);
            let mailbox = pos.and_then(|p| mailboxes.get(p).copied().flatten());
            let class = format!("{} {}", name(r.command), region(r.command, r.ado, mailbox));
            let what = format!(
                "frame {} {} adp {:#06x} ado {:#06x} len {}",
                ex.number,
                name(r.command),
                s.adp,
                r.ado,
                r.data.len()
            );
            o.datagrams += 1;
            if (m.wkc, m.adp) == (r.wkc, r.adp) {
                o.equal += 1;
            } else {
                let field = if m.wkc != r.wkc { "wkc" } else { "adp" };
                o.differing
                    .entry(format!("{class}: {field}"))
                    .or_default()
                    .push(format!("{what}: wkc {} (real {})", m.wkc, r.wkc));
            }
            if m.wkc == 0 || r.wkc == 0 || !reads(r.command) {
                continue;
            }
            let p = pos.map(|p| &mut pending[p]);
            values(&mut o, p, mailbox, &class, &what, m, r);
        }
    }
    // Polls of an exchange whose answer was never read.
    for p in &mut pending {
        for (k, v) in p.polls.drain(..) {
            o.values.entry(k).or_default().push(v);
        }
    }
    o
}

/// The values read, where the captures' README states facts about them: ESC information, DL
/// status, AL status, SII control and data, SM status, the mailbox answers.
fn values(
    o: &mut Outcome,
    pending: Option<&mut Pending>,
    mailbox: Option<Mailbox>,
    class: &str,
    what: &str,
    m: &Dg,
    r: &Dg,
) {
    let mut differ = |field: &str, mine: String, real: String| {
        o.values
            .entry(format!("{class}: {field}"))
            .or_default()
            .push(format!("{what}: {mine} (real {real})"));
    };
    let hex = |d: &[u8]| d.iter().map(|b| format!("{b:02x}")).collect::<String>();
    if let Some(mb) = mailbox {
        if mb.is_in(r.ado, r.data.len()) {
            if let Some(p) = pending {
                // The answer delivered on both sides: the polls before it differed in time.
                for (k, v) in p.polls.drain(..) {
                    o.timing.entry(k).or_default().push(v);
                }
            }
            let len = |d: &[u8]| 6 + usize::from(u16::from_le_bytes([d[0], d[1]]));
            let (a, b) = (
                &m.data[..len(&m.data).min(m.data.len())],
                &r.data[..len(&r.data).min(r.data.len())],
            );
            if a != b {
                differ("answer", hex(a), hex(b));
            }
            return;
        }
        if mb.is_out(r.ado, r.data.len()) {
            if let Some(p) = pending {
                // A new request: polls of the last exchange that never saw its answer read.
                for (k, v) in p.polls.drain(..) {
                    o.values.entry(k).or_default().push(v);
                }
            }
            return;
        }
    }
    match r.ado {
        0x0000..=0x000f | 0x0110 | 0x0140 if m.data != r.data => {
            differ("value", hex(&m.data), hex(&r.data));
        }
        0x0130 => {
            // State and error indication (bits 0-4).
            let (a, b) = (m.data[0] & 0x1f, r.data[0] & 0x1f);
            if a ^ b == 0x10 {
                differ("bit 4 alone", format!("{a:#04x}"), format!("{b:#04x}"));
            } else if a != b {
                differ("state", format!("{a:#04x}"), format!("{b:#04x}"));
            }
            if r.data.len() >= 6 && m.data[4..6] != r.data[4..6] {
                differ("status code", hex(&m.data[4..6]), hex(&r.data[4..6]));
            }
        }
        0x0502 => {
            // Busy (bit 15), errors (13, 14), read size (6).
            let bits = |d: &[u8]| u16::from_le_bytes([d[0], d[1]]) & 0xe040;
            if bits(&m.data) & 0x8000 != bits(&r.data) & 0x8000 {
                differ(
                    "busy",
                    format!("{:#06x}", bits(&m.data)),
                    format!("{:#06x}", bits(&r.data)),
                );
            } else if bits(&m.data) != bits(&r.data) {
                differ(
                    "read size/errors",
                    format!("{:#06x}", bits(&m.data)),
                    format!("{:#06x}", bits(&r.data)),
                );
            }
        }
        0x0508 if m.data != r.data => differ("data", hex(&m.data), hex(&r.data)),
        0x0805 | 0x080d => {
            let (a, b) = (m.data[0], r.data[0]);
            // With the full bit alike, the others; else the answer's time (the other bits
            // follow the full bit).
            if (a ^ b) & SM_MAILBOX_FULL == 0 && a != b {
                differ("other bits", format!("{a:#04x}"), format!("{b:#04x}"));
            }
            if (a ^ b) & SM_MAILBOX_FULL != 0 {
                let entry = (
                    format!("{class}: mailbox full bit"),
                    format!("{what}: {a:#04x} (real {b:#04x})"),
                );
                match pending {
                    Some(p) if r.ado == 0x080d => p.polls.push(entry),
                    _ => o.values.entry(entry.0).or_default().push(entry.1),
                }
            }
        }
        _ => {}
    }
}
