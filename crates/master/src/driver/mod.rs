//! The one bring-up driver and the one cyclic driver: they run the sans-IO engine over any
//! [`Transport`], with one overrun policy, one reply matching and one loss accounting, in the
//! simulator and on a real network alike.
//!
//! * Reply matching ([`answers`]): a frame answers the one sent if it is an EtherCAT frame at
//!   least as long (a NIC may pad it) whose first datagram has the command and index sent. The
//!   cyclic frames carry a tag in that index that changes every cycle
//!   ([`CyclicEngine::tag_of`](crate::cyclic::CyclicEngine::tag_of)): a reply of an earlier cycle is counted as late, a second copy
//!   of a reply as a duplicate (a second responder), anything else as stale, and all of them
//!   are discarded.
//! * Loss: no matching reply by the deadline (the send timestamp plus the reply timeout; in the
//!   cyclic phase the next cycle's slot at the latest, so a lost frame costs its own cycle
//!   only). A procedure sends a lost frame again up to its retries before it hears of the
//!   loss; the cyclic driver counts it and goes on, and stops after `lost_in_a_row` losses in
//!   a row (if set).
//! * Overrun: a cycle whose task woke a whole period or more after its scheduled start has lost
//!   its slot; the driver skips the slots that passed and runs the cycle whose slot is now (as a
//!   PLC task skips an overrun), rather than sending the missed frames back to back.

use crate::transport::{Received, Transport};
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_wire::EcatFrame;

mod cycle;
mod jobs;
mod procedure;

pub use cycle::{CycleReport, CyclicDriver, CyclicLimits, Stopped};
pub use jobs::{RECOVERY_FRAME_TRIES, RECOVERY_RETRY_NS, RecoveryEvent, SyncCounter};
pub use procedure::{ProcedureConfig, ProcedureExchange, run_procedure};

/// Whether `reply` answers `sent` (see the module documentation).
pub fn answers(sent: &[u8], reply: &[u8]) -> bool {
    match EcatFrame::new_checked(sent) {
        Ok(s) => answers_id(s.first_datagram_id(), sent.len(), reply),
        Err(_) => false,
    }
}

/// Whether `reply` answers a frame of `sent_len` bytes whose first datagram has `sent_id`
/// (command and index): [`answers`] with the sent frame's part worked out once.
pub fn answers_id(sent_id: Option<(u8, u8)>, sent_len: usize, reply: &[u8]) -> bool {
    if reply.len() < sent_len || sent_id.is_none() {
        return false;
    }
    EcatFrame::new_checked(reply).is_ok_and(|r| r.first_datagram_id() == sent_id)
}

/// Counters of what came back.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ExchangeStats {
    /// Frames sent (retries included).
    pub sent: u64,
    /// Replies matched to the frame they answer.
    pub replies: u64,
    /// Frames whose reply did not come by the deadline.
    pub lost: u64,
    /// Frames received that answer nothing this master sent lately (other traffic, a frame
    /// too short for the one it names).
    pub stale: u64,
    /// Replies of an earlier cycle that came after their cycle's deadline: discarded.
    pub late: u64,
    /// Second copies of a reply already taken (a second responder on the wire, a looping
    /// switch): discarded.
    pub duplicates: u64,
    /// Frames too long for the buffer.
    pub truncated: u64,
}

/// A matched reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reply {
    /// The send timestamp.
    pub sent: MasterInstant,
    /// When it came back.
    pub received: Received,
}

/// Sends `frame` and waits for its reply until `timeout` after the send, into `buf`.
/// `None`: lost.
pub fn exchange<Tr: Transport>(
    tr: &mut Tr,
    frame: &[u8],
    buf: &mut Vec<u8>,
    timeout: MasterDuration,
    stats: &mut ExchangeStats,
) -> Result<Option<Reply>, Tr::Error> {
    let at = tr.send_time(frame.len());
    let sent = tr.send(frame, at)?;
    stats.sent += 1;
    let deadline = sent.saturating_add(timeout);
    while let Some(r) = tr.recv(buf, deadline)? {
        if !r.truncated && answers(frame, &buf[..r.len]) {
            stats.replies += 1;
            return Ok(Some(Reply { sent, received: r }));
        }
        stats.stale += 1;
        stats.truncated += u64::from(r.truncated);
    }
    stats.lost += 1;
    Ok(None)
}
