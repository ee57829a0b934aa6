//! A capture as exchanges: every EtherCAT frame the master sent, with the frame that came back.

use crate::common::{CapturedFrame, Dg, datagrams, has_returned, read_pcapng};
use ecsync_wire::Command;
use std::path::Path;

/// The EtherType of EtherCAT frames (ETG.1000.4): other frames in a capture (a host's DHCP,
/// ARP, TLS; SOEM's captures have them) are not the master's.
const ETHERTYPE_ETHERCAT: u16 = 0x88a4;

/// One frame the master sent and the frame that came back, if the capture holds it.
#[derive(Debug, Clone)]
pub struct Exchange {
    /// The sent frame's number in the capture (1-based, as Wireshark counts).
    pub number: usize,
    /// When it was sent, ns since the capture's first frame.
    pub t_ns: u64,
    /// The frame as sent.
    pub sent: Vec<u8>,
    /// The frame as it came back: `None` when the capture lost it (SOEM's AKD capture has
    /// three, each beside a frame of the host's own).
    pub back: Option<Vec<u8>>,
}

impl Exchange {
    /// The datagrams as they came back, `None` without an answer.
    pub fn replies(&self) -> Option<Vec<Dg>> {
        self.back.as_deref().map(datagrams)
    }
}

fn is_ethercat(frame: &[u8]) -> bool {
    frame.len() >= 14 && u16::from_be_bytes([frame[12], frame[13]]) == ETHERTYPE_ETHERCAT
}

/// The exchanges of the pcapng file at `path`: each EtherCAT frame the master sent (the source
/// address's bit 1 clear) paired with the next one if that came back (the first ESC sets the
/// bit: ESC datasheet section I, "Frame processing"). Both masters' captures (ethercrab's and
/// SOEM's) have one frame in flight at a time; a returned frame without a sent one before it
/// fails.
pub fn load(path: &Path) -> Vec<Exchange> {
    let frames: Vec<CapturedFrame> = read_pcapng(path)
        .into_iter()
        .filter(|f| is_ethercat(&f.data))
        .collect();
    let mut out: Vec<Exchange> = Vec::new();
    for f in frames {
        if has_returned(&f.data) {
            let last = out
                .last_mut()
                .filter(|e| e.back.is_none())
                .unwrap_or_else(|| panic!("frame {}: returned, but sent by nobody", f.number));
            last.back = Some(f.data);
        } else {
            out.push(Exchange {
                number: f.number,
                t_ns: f.t_ns,
                sent: f.data,
                back: None,
            });
        }
    }
    out
}

/// A command's name as the datasheet writes it.
pub fn name(code: u8) -> String {
    Command::from_code(code).map_or(format!("{code:#04x}"), |c| format!("{c:?}").to_uppercase())
}

/// Whether `code` is an auto-increment command (APxx, ARMW): its ADP counts positions.
pub fn is_auto_increment(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Aprd | Command::Apwr | Command::Aprw | Command::Armw)
    )
}

/// Whether `code` is a configured-address command (FPxx, FRMW).
pub fn is_configured(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Fprd | Command::Fpwr | Command::Fprw | Command::Frmw)
    )
}

/// Whether `code` is a broadcast command.
pub fn is_broadcast(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Brd | Command::Bwr | Command::Brw)
    )
}

/// Whether `code` is a logical command.
pub fn is_logical(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Lrd | Command::Lwr | Command::Lrw)
    )
}

/// Whether `code` reads (APRD, FPRD, BRD, their RW forms, FRMW and ARMW at their slaves).
pub fn reads(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Aprd
            | Command::Fprd
            | Command::Brd
            | Command::Aprw
            | Command::Fprw
            | Command::Brw
            | Command::Armw
            | Command::Frmw)
    )
}

/// Whether `code` writes at every slave it addresses.
pub fn writes(code: u8) -> bool {
    matches!(
        Command::from_code(code),
        Ok(Command::Apwr
            | Command::Fpwr
            | Command::Bwr
            | Command::Aprw
            | Command::Fprw
            | Command::Brw)
    )
}

/// Who a datagram addresses, as far as the master's addressing of the capture tells.
#[derive(Debug, Default, Clone)]
pub struct Addressing {
    /// Station addresses by position (from the master's APWR of 0x0010 that counted).
    pub stations: Vec<Option<u16>>,
    /// Station aliases by position (0x0012 as read back).
    pub aliases: Vec<Option<u16>>,
}

impl Addressing {
    /// Learns from one datagram as it came back (`d`, with the sent ADP `adp`).
    pub fn learn(&mut self, sent_adp: u16, d: &Dg) {
        let Some(p) = self.position(d.command, sent_adp) else {
            return;
        };
        if d.wkc == 0 {
            return;
        }
        let grow = |v: &mut Vec<Option<u16>>| {
            if v.len() <= p {
                v.resize(p + 1, None);
            }
        };
        grow(&mut self.stations);
        grow(&mut self.aliases);
        let word = |at: usize| {
            d.data
                .get(at..at + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
        };
        // A write of 0x0010 (or a read covering it) names the station; 0x0012 the alias.
        if d.ado <= 0x0010 && d.ado as usize + d.data.len() >= 0x0012 && writes(d.command) {
            self.stations[p] = word(usize::from(0x0010 - d.ado));
        }
        if d.ado <= 0x0012 && d.ado as usize + d.data.len() >= 0x0014 && reads(d.command) {
            self.aliases[p] = word(usize::from(0x0012 - d.ado));
        }
    }

    /// The position a single-slave datagram addresses: auto-increment by its sent ADP,
    /// configured by station address (or alias). `None`: broadcast, logical, or unknown.
    pub fn position(&self, command: u8, sent_adp: u16) -> Option<usize> {
        if is_auto_increment(command) {
            return Some(usize::from(sent_adp.wrapping_neg()));
        }
        if !is_configured(command) {
            return None;
        }
        self.stations
            .iter()
            .position(|s| *s == Some(sent_adp))
            .or_else(|| {
                self.aliases
                    .iter()
                    .position(|a| *a == Some(sent_adp) && sent_adp != 0)
            })
    }
}
