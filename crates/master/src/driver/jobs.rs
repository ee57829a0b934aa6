//! The cyclic driver's side jobs, one frame per cycle after the cyclic frames: recovering slaves
//! that lost their configuration, and reading the drives' SYNC counters.

use crate::cyclic::CyclicEngine;
use crate::error::MasterError;
use crate::io::Engine;
use crate::network::Network;
use crate::recovery::{Recovered, RecoveryConfig};
use ecsync_dc::MasterSync;
use ecsync_dc::time::MasterInstant;

/// One recovery, for the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoveryEvent {
    /// When it started.
    pub started: MasterInstant,
    /// When it ended (`None`: still running).
    pub ended: Option<MasterInstant>,
    /// What it did, or why it failed (it is tried again [`RECOVERY_RETRY_NS`] later).
    pub outcome: Option<Result<Recovered, String>>,
}

/// A failed recovery is tried again this long after, ns.
pub const RECOVERY_RETRY_NS: u64 = 50_000_000;
/// A recovery's frame is sent again in this many cycles before the recovery hears of its
/// loss.
pub const RECOVERY_FRAME_TRIES: u32 = 10;

/// A drive's SM-event-missed counter as the master read it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncCounter {
    /// Network position, from 0.
    pub position: u16,
    /// 0x1C32:0B: SYNC0 cycles in OP without new outputs, as the drive counted them.
    pub sm_events_missed: u16,
    /// When the answer came.
    pub read: MasterInstant,
}

/// What the acyclic slot's procedure gives.
pub(super) enum JobResult {
    Recovery(Result<Recovered, MasterError>),
    /// One drive's counter read (none: it has no 0x1C32:0B), and its mailbox counter after.
    SyncCounters(Result<Option<SyncCounter>, MasterError>, u8),
}

/// Reads 0x1C32:0B of each drive of `drives` (position, station, mailbox), one after the
/// other; a drive without the object is left out.
/// One drive's read (a job per drive: a lost cycle costs the read of one drive, not a round).
pub(super) async fn read_sync_counter(link: crate::io::Link, d: SyncDrive) -> JobResult {
    let mut c = crate::coe::SdoClient::going_on_from(&link, d.station, d.mailbox, d.counter);
    let r = c.upload(0x1c32, 0x0b).await;
    let read = match r {
        Ok(v) if v.len() >= 2 => Ok(Some(SyncCounter {
            position: d.position,
            sm_events_missed: u16::from_le_bytes([v[0], v[1]]),
            read: link.now(),
        })),
        Ok(_) | Err(MasterError::SdoAbort { .. }) => Ok(None),
        Err(e) => Err(e),
    };
    JobResult::SyncCounters(read, c.counter())
}

/// The mailbox counter after `c` (1 to 7, 0 only before the first message).
pub(super) fn mailbox_counter_after(c: u8) -> u8 {
    if c >= 7 { 1 } else { c + 1 }
}

/// A drive whose counter is read.
#[derive(Debug, Clone, Copy)]
pub(super) struct SyncDrive {
    pub(super) position: u16,
    pub(super) station: u16,
    pub(super) mailbox: crate::network::MailboxInfo,
    /// The mailbox counter of the last message this driver sent it. The bring-up's last
    /// (configuring the sync mode) were 1 to 3; 0 here: the first read goes out with 1, and
    /// a drive that took three messages before does not take it for a repeat.
    pub(super) counter: u8,
}

/// The recovery the driver runs next to the cyclic frames: one frame of it per cycle.
pub(super) struct RecoverySlot {
    pub(super) net: Network,
    pub(super) cfg: RecoveryConfig,
    pub(super) running: Option<Engine<JobResult>>,
    /// The running procedure is a recovery (else a read of the drives' counters).
    pub(super) recovering: bool,
    /// The drives whose counters are read, and when next.
    pub(super) sync_drives: Vec<SyncDrive>,
    pub(super) next_sync_read_ns: Option<u64>,
    /// The drive the round reads next (`sync_drives.len()`: no round under way), and the one
    /// whose read runs.
    pub(super) sync_next: usize,
    pub(super) sync_reading: Option<usize>,
    /// Each drive's first and last read.
    pub(super) sync_counters: Vec<(SyncCounter, SyncCounter)>,
    /// The frame out, its send timestamp and its sends so far.
    pub(super) out: Option<(Vec<u8>, MasterInstant, u32)>,
    pub(super) retry_at_ns: u64,
    pub(super) log: Vec<RecoveryEvent>,
}

impl RecoverySlot {
    /// Drops the running read of a drive's counter; the round takes the same drive again with
    /// the next cycle answered. Its request may have reached the drive: the next goes out with
    /// the counter after it, which the drive cannot take for a repeat whichever it saw last.
    pub(super) fn drop_counter_read(&mut self) {
        if self.running.take().is_some()
            && let Some(d) = self
                .sync_reading
                .take()
                .and_then(|k| self.sync_drives.get_mut(k))
        {
            d.counter = mailbox_counter_after(d.counter);
        }
        self.out = None;
    }

    /// The recovery ended at `now` with `r`: logged, and the engine told what it did (or a
    /// retry planned).
    pub(super) fn finish<S: MasterSync>(
        &mut self,
        r: JobResult,
        now: u64,
        eng: &mut CyclicEngine<S>,
    ) {
        self.running = None;
        let r = match r {
            JobResult::Recovery(r) => r,
            JobResult::SyncCounters(r, counter) => {
                if let Some(d) = self
                    .sync_reading
                    .take()
                    .and_then(|k| self.sync_drives.get_mut(k))
                {
                    d.counter = counter;
                }
                // A failed read (a drive gone) is the cyclic phase's to notice; the round goes
                // on with the next drive.
                self.sync_next += 1;
                if let Ok(Some(c)) = r {
                    match self
                        .sync_counters
                        .iter_mut()
                        .find(|x| x.1.position == c.position)
                    {
                        Some(x) => x.1 = c,
                        None => self.sync_counters.push((c, c)),
                    }
                }
                return;
            }
        };
        if let Some(ev) = self.log.last_mut() {
            ev.ended = Some(MasterInstant::from_ns(now));
            ev.outcome = Some(r.clone().map_err(|e| e.to_string()));
        }
        match r {
            Ok(r) => {
                if let Some(o) = r.reference_offset {
                    eng.set_reference_offset(o);
                }
                if r.appeared > 0 {
                    eng.unmanaged_slaves_answer();
                }
                eng.recovered();
            }
            Err(_) => self.retry_at_ns = now.saturating_add(RECOVERY_RETRY_NS),
        }
    }
}

impl RecoveryEvent {
    /// The slaves it configured again, network positions counted from 1 (the next to the
    /// master), as the reports print them.
    pub fn slaves_brought_back(&self) -> Vec<u16> {
        match &self.outcome {
            Some(Ok(r)) => r.positions.iter().map(|p| p + 1).collect(),
            _ => Vec::new(),
        }
    }

    /// Why it failed, if it did.
    pub fn error(&self) -> Option<String> {
        match &self.outcome {
            Some(Err(m)) => Some(m.clone()),
            _ => None,
        }
    }

    /// Slaves it found out of OP with their configuration kept, as their AL status said
    /// ("slave 4 in SAFE-OP with AL error 0x001A (synchronization error)").
    pub fn left_op(&self) -> Vec<String> {
        match &self.outcome {
            Some(Ok(r)) => r.left_op.iter().map(|l| l.to_string()).collect(),
            _ => Vec::new(),
        }
    }

    /// Slaves it counted beyond the network as brought up.
    pub fn appeared(&self) -> u16 {
        match &self.outcome {
            Some(Ok(r)) => r.appeared,
            _ => 0,
        }
    }
}

impl std::fmt::Debug for RecoverySlot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecoverySlot")
            .field("running", &self.running.is_some())
            .field("log", &self.log)
            .finish_non_exhaustive()
    }
}
