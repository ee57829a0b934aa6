//! The ESCs' error counters (datasheet section II, 0x0300-0x0313), and what makes them count
//! in a segment: a link lost (a cable pulled, a neighbour switched off) and a frame whose FCS
//! broke on its way back (a `corrupt` fault; where it breaks: [`Segment::break_fcs_of_next_frame`]).

use super::{Peer, Segment};
use ecsync_wire::register as reg;

/// An error counter of the ESC (datasheet section II, 0x0300-0x0313) a fault makes count. Every
/// one counts up to 0xFF and stays there (no wrap-around). The physical layer's RX error
/// counters (0x0301 + 2p, MII RX_ER: symbol errors) do not count: no fault breaks symbols, a
/// `corrupt` fault breaks the FCS (a CRC error, the invalid frame counter's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ErrorCounter {
    /// 0x0300 + 2p: an invalid frame first detected at port p (a CRC error, say).
    InvalidFrame(usize),
    /// 0x0308 + p: an invalid frame already marked by an ESC before (a forwarded error).
    ForwardedRxError(usize),
    /// 0x030C: an invalid frame passed the processing unit.
    ProcessingUnit,
    /// 0x0310 + p: the link of port p lost.
    LostLink(usize),
}

impl ErrorCounter {
    /// The counter's register.
    pub(crate) const fn address(self) -> u16 {
        const fn port(p: usize) -> u16 {
            assert!(p < 4, "an ESC has ports 0 to 3");
            p as u16
        }
        match self {
            ErrorCounter::InvalidFrame(p) => reg::RX_ERROR_COUNTER + 2 * port(p),
            ErrorCounter::ForwardedRxError(p) => reg::RX_ERROR_COUNTER + 8 + port(p),
            ErrorCounter::ProcessingUnit => 0x030c,
            ErrorCounter::LostLink(p) => reg::LOST_LINK_COUNTER + port(p),
        }
    }
}

impl Segment {
    /// The next frame [`Segment::process`] takes has its FCS broken on its way back (a
    /// `corrupt` fault): the ESCs act on it on its way out, then it breaks on the first cable
    /// of its way back, the one from the last ESC it reaches (in network order) to that ESC's
    /// upstream neighbour. The neighbour is the first to see the bad FCS: it counts an invalid
    /// frame at the port it received it through (0x0300 + 2p) and marks the frame; every ESC
    /// after it on the way to the master counts a forwarded RX error at its receiving port
    /// (0x0308 + p). The frame comes back through ports, not processing units, so no ESC counts
    /// 0x030C. With one slave the cable is the master's: no ESC sees the break.
    pub fn break_fcs_of_next_frame(&mut self) {
        self.fcs_break_pending = true;
    }

    /// Counts the broken FCS of the frame whose way was `flat` (its processing units in
    /// order), as [`Segment::break_fcs_of_next_frame`] says.
    pub(super) fn count_broken_fcs(&mut self, flat: &[(usize, u64)]) {
        let Some(&(mut at, _)) = flat.last() else {
            return;
        };
        let mut marked = false;
        loop {
            let node = &self.nodes[at];
            let Some(link) = node.links[usize::from(node.entry_port)] else {
                return;
            };
            let Peer::Slave(up) = link.peer else {
                return;
            };
            let (up, port) = (usize::from(up), usize::from(link.peer_port));
            self.nodes[up].esc.count_error(if marked {
                ErrorCounter::ForwardedRxError(port)
            } else {
                ErrorCounter::InvalidFrame(port)
            });
            marked = true;
            at = up;
        }
    }

    /// Whether the master's network interface has a link: the cable at the entry port of the
    /// slave at position 0 is in and that slave is switched on (its PHY up). A served interface
    /// takes its carrier down while this is false.
    pub fn master_link_up(&self) -> bool {
        let node = &self.nodes[usize::from(self.first)];
        !node.off && node.esc.links()[usize::from(node.entry_port)]
    }

    /// Whether the master's second interface has a link, in a ring: the ring cable is in and
    /// its slave switched on (`None`: no ring).
    pub fn ring_link_up(&self) -> Option<bool> {
        let (pos, port) = self.ring?;
        let node = &self.nodes[usize::from(pos)];
        Some(!node.off && node.esc.links()[usize::from(port)])
    }
}
