//! The one bring-up driver and the one cyclic driver: they run the sans-IO engine over any
//! [`Transport`], with one overrun policy, one reply matching and one loss accounting, in the
//! simulator and on a real network alike.
//!
//! * Reply matching ([`answers`]): a frame answers the one sent if it is an EtherCAT frame at
//!   least as long (a NIC may pad it) whose first datagram has the command and index sent. The
//!   cyclic frames carry a tag in that index that changes every cycle
//!   ([`CyclicEngine::tag_of`]): a reply of an earlier cycle is counted as late, a second copy
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

use crate::cyclic::{CycleRecord, CyclicEngine};
use crate::error::MasterError;
use crate::io::{Action, Engine, Event};
use crate::network::Network;
use crate::recovery::{Recovered, RecoveryConfig, recover};
use crate::transport::{Received, Transport};
use ecsync_dc::MasterSync;
use ecsync_wire::EcatFrame;
use std::sync::atomic::{AtomicBool, Ordering};

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
    /// The send timestamp, master time, ns.
    pub sent_ns: u64,
    /// When it came back, master time, ns.
    pub received: Received,
}

/// Sends `frame` and waits for its reply until `timeout_ns` after the send, into `buf`.
/// `None`: lost.
pub fn exchange<Tr: Transport>(
    tr: &mut Tr,
    frame: &[u8],
    buf: &mut Vec<u8>,
    timeout_ns: u64,
    stats: &mut ExchangeStats,
) -> Result<Option<Reply>, Tr::Error> {
    let at = tr.send_time_ns(frame.len());
    let sent_ns = tr.send(frame, at)?;
    stats.sent += 1;
    let deadline = sent_ns.saturating_add(timeout_ns);
    while let Some(r) = tr.recv(buf, deadline)? {
        if !r.truncated && answers(frame, &buf[..r.len]) {
            stats.replies += 1;
            return Ok(Some(Reply {
                sent_ns,
                received: r,
            }));
        }
        stats.stale += 1;
        stats.truncated += u64::from(r.truncated);
    }
    stats.lost += 1;
    Ok(None)
}

/// How a procedure's frames are waited for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProcedureConfig {
    /// How long to wait for a reply, ns.
    pub reply_timeout_ns: u64,
    /// How often a lost frame is sent again before the procedure hears of the loss (the first
    /// frames on a real network meet cold caches and page faults on both ends).
    pub retries: u32,
}

impl Default for ProcedureConfig {
    fn default() -> Self {
        ProcedureConfig {
            reply_timeout_ns: 20_000_000,
            retries: 3,
        }
    }
}

/// One exchange of a procedure, for observers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProcedureExchange {
    /// Send timestamp of the last attempt, master time, ns.
    pub sent_ns: u64,
    /// When its reply came, master time, ns (`None`: lost every time).
    pub received_ns: Option<u64>,
    /// Sends, the first included.
    pub attempts: u32,
}

/// Runs a sans-IO procedure (the DC bring-up, say) to completion over `tr`. `observe` sees the
/// transport after every exchange, with the events the procedure reported.
pub fn run_procedure<T: 'static, Tr: Transport>(
    tr: &mut Tr,
    engine: &mut Engine<T>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
    mut observe: impl FnMut(&mut Tr, &ProcedureExchange, &[Event]),
) -> Result<T, Tr::Error> {
    let mut buf = vec![0u8; 2048];
    engine.send_back_to_back();
    loop {
        let now = tr.now_ns();
        let frame = match engine.poll(now) {
            Action::Done(v) => return Ok(v),
            Action::WaitUntil(t) => {
                tr.sleep_until(t);
                continue;
            }
            Action::Send(f) => f.to_vec(),
            Action::SendAll(frames) => {
                let frames = frames.to_vec();
                let done = exchange_all(tr, &frames, &mut buf, cfg, stats)?;
                let exchanges: Vec<ProcedureExchange> = done
                    .iter()
                    .map(|(sent_ns, r, attempts)| ProcedureExchange {
                        sent_ns: *sent_ns,
                        received_ns: r.as_ref().ok().map(|r| r.received_ns),
                        attempts: *attempts,
                    })
                    .collect();
                engine.handle_replies(done.into_iter().map(|(_, r, _)| r).collect());
                let events = engine.take_events();
                for (k, ex) in exchanges.iter().enumerate() {
                    observe(tr, ex, if k == 0 { &events } else { &[] });
                }
                continue;
            }
        };
        let (got, attempts, sent_ns) =
            exchange_tries(tr, &frame, &mut buf, cfg, stats, cfg.retries + 1)?;
        match got {
            Some(r) => {
                engine.handle_reply(&buf[..r.received.len], r.sent_ns, r.received.received_ns)
            }
            None => engine.handle_lost_after(attempts),
        }
        let events = engine.take_events();
        observe(
            tr,
            &ProcedureExchange {
                sent_ns,
                received_ns: got.map(|r| r.received.received_ns),
                attempts,
            },
            &events,
        );
    }
}

/// Sends `frame` up to `tries` times, each after the last one was lost: its reply (`None`: lost
/// every time), the sends made, and the last send's timestamp (after a loss, the time it was
/// given up).
fn exchange_tries<Tr: Transport>(
    tr: &mut Tr,
    frame: &[u8],
    buf: &mut Vec<u8>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
    tries: u32,
) -> Result<(Option<Reply>, u32, u64), Tr::Error> {
    let (mut sends, mut sent_ns) = (0, 0);
    for _ in 0..tries {
        sends += 1;
        match exchange(tr, frame, buf, cfg.reply_timeout_ns, stats)? {
            Some(r) => return Ok((Some(r), sends, r.sent_ns)),
            None => sent_ns = tr.now_ns(),
        }
    }
    Ok((None, sends, sent_ns))
}

/// Sends `frames` back to back and waits for their replies until `cfg.reply_timeout_ns` after
/// the last send; a frame whose reply did not come is sent again alone, up to `cfg.retries`
/// times. Per frame, in order: its last send timestamp, its reply (`Err(sends)`: lost after
/// that many), its sends. Replies are matched to the earliest unanswered frame they answer (a
/// line returns frames in the order sent).
#[allow(clippy::type_complexity)]
fn exchange_all<Tr: Transport>(
    tr: &mut Tr,
    frames: &[Vec<u8>],
    buf: &mut Vec<u8>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
) -> Result<Vec<(u64, Result<crate::io::Reply, u32>, u32)>, Tr::Error> {
    let mut sent = Vec::with_capacity(frames.len());
    for f in frames {
        let at = tr.send_time_ns(f.len());
        sent.push(tr.send(f, at)?);
        stats.sent += 1;
    }
    let mut got: Vec<Option<crate::io::Reply>> = vec![None; frames.len()];
    let mut pending = frames.len();
    let deadline = sent
        .last()
        .copied()
        .unwrap_or(0)
        .saturating_add(cfg.reply_timeout_ns);
    while pending > 0 {
        let Some(r) = tr.recv(buf, deadline)? else {
            break;
        };
        let k = (!r.truncated)
            .then(|| {
                (0..frames.len()).find(|&k| got[k].is_none() && answers(&frames[k], &buf[..r.len]))
            })
            .flatten();
        match k {
            Some(k) => {
                got[k] = Some(crate::io::Reply {
                    frame: buf[..r.len].to_vec(),
                    sent_ns: sent[k],
                    received_ns: r.received_ns,
                });
                stats.replies += 1;
                pending -= 1;
            }
            None => {
                stats.stale += 1;
                stats.truncated += u64::from(r.truncated);
            }
        }
    }
    let mut out = Vec::with_capacity(frames.len());
    for (k, g) in got.into_iter().enumerate() {
        if let Some(r) = g {
            out.push((sent[k], Ok(r), 1));
            continue;
        }
        stats.lost += 1;
        let (again, tries, last_ns) = exchange_tries(tr, &frames[k], buf, cfg, stats, cfg.retries)?;
        let reply = again.map(|r| crate::io::Reply {
            frame: buf[..r.received.len].to_vec(),
            sent_ns: r.sent_ns,
            received_ns: r.received.received_ns,
        });
        let sent_ns = if tries == 0 { sent[k] } else { last_ns };
        out.push((sent_ns, reply.ok_or(1 + tries), 1 + tries));
    }
    Ok(out)
}

/// When the cyclic driver stops by itself, and how long it waits for a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CyclicLimits {
    /// Stop after this much master time from the first scheduled start, ns.
    pub duration_ns: Option<u64>,
    /// Stop after this many cycles.
    pub max_cycles: Option<u64>,
    /// Give up when this many frames in a row were lost: the network is gone.
    pub lost_in_a_row: u64,
    /// How long to wait for a cycle's reply after its send, ns.
    pub reply_timeout_ns: u64,
    /// Read every drive's SM-event-missed counter (0x1C32:0B) over CoE this often, ns, in
    /// the cycles' spare time (`None`: never). Drives with CoE and a system time only, as
    /// the bring-up set them to DC mode.
    pub sync_counters_every_ns: Option<u64>,
    /// Hand the method the transport's transmit timestamp of the cycle's first frame as its
    /// send time t_ms (the NIC's or the kernel's, taken after the scheduling and the stack's
    /// latency, see [`Received::tx_stamp_ns`]) instead of the timestamp taken before the send;
    /// a cycle whose stamp did not come keeps the latter and is counted
    /// ([`CyclicDriver::t_ms_sources`]). For master-shift methods only: a bus-shift method
    /// writes its send time into the frame before it leaves.
    pub t_ms_from_tx_stamp: bool,
}

impl Default for CyclicLimits {
    fn default() -> Self {
        CyclicLimits {
            duration_ns: None,
            max_cycles: None,
            lost_in_a_row: 100,
            reply_timeout_ns: 10_000_000,
            sync_counters_every_ns: None,
            t_ms_from_tx_stamp: false,
        }
    }
}

/// One cycle as it happened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleReport {
    /// What the engine and the method made of it.
    pub record: CycleRecord,
    /// When the task woke, master time, ns.
    pub woke_ns: u64,
    /// Wake-up latency: woke minus scheduled, ns. When the task woke a whole period or more
    /// late, from the slot it missed first.
    pub wake_latency_ns: i64,
    /// Cycles skipped right before this one because the task woke after their slots had passed.
    pub skipped_before: u64,
    /// The transmit timestamp of the transport (kernel or NIC), master time, ns.
    pub tx_stamp_ns: Option<u64>,
    /// The send timestamp taken before the cycle's first frame went to the transport, master
    /// time, ns (the record's `send_ns` unless t_ms came from the transmit timestamp).
    pub stamp_ns: u64,
    /// Send timestamp to reply, ns.
    pub round_trip_ns: Option<u64>,
    /// Length of the cyclic frame, bytes.
    pub frame_len: usize,
}

/// Why the cyclic driver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stopped {
    /// The duration passed.
    Duration,
    /// The cycle count was reached.
    Cycles,
    /// The stop flag was raised (Ctrl-C).
    Interrupted,
    /// Frames stopped coming back.
    NetworkGone {
        /// The cycle of the last frame that came back (`None`: none did).
        last_good_cycle: Option<u64>,
        /// Frames lost in a row.
        lost_in_a_row: u64,
    },
}

/// One recovery, for the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoveryEvent {
    /// When it started, master time, ns.
    pub started_ns: u64,
    /// When it ended, master time, ns (`None`: still running).
    pub ended_ns: Option<u64>,
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
    /// When the answer came, master time, ns.
    pub read_ns: u64,
}

/// What the acyclic slot's procedure gives.
enum JobResult {
    Recovery(Result<Recovered, MasterError>),
    /// One drive's counter read (none: it has no 0x1C32:0B), and its mailbox counter after.
    SyncCounters(Result<Option<SyncCounter>, MasterError>, u8),
}

/// Reads 0x1C32:0B of each drive of `drives` (position, station, mailbox), one after the
/// other; a drive without the object is left out.
/// One drive's read (a job per drive: a lost cycle costs the read of one drive, not a round).
async fn read_sync_counter(link: crate::io::Link, d: SyncDrive) -> JobResult {
    let mut c = crate::coe::SdoClient::going_on_from(&link, d.station, d.mailbox, d.counter);
    let r = c.upload(0x1c32, 0x0b).await;
    let read = match r {
        Ok(v) if v.len() >= 2 => Ok(Some(SyncCounter {
            position: d.position,
            sm_events_missed: u16::from_le_bytes([v[0], v[1]]),
            read_ns: link.now_ns(),
        })),
        Ok(_) | Err(MasterError::SdoAbort { .. }) => Ok(None),
        Err(e) => Err(e),
    };
    JobResult::SyncCounters(read, c.counter())
}

/// The mailbox counter after `c` (1 to 7, 0 only before the first message).
fn mailbox_counter_after(c: u8) -> u8 {
    if c >= 7 { 1 } else { c + 1 }
}

/// A drive whose counter is read.
#[derive(Debug, Clone, Copy)]
struct SyncDrive {
    position: u16,
    station: u16,
    mailbox: crate::network::MailboxInfo,
    /// The mailbox counter of the last message this driver sent it. The bring-up's last
    /// (configuring the sync mode) were 1 to 3; 0 here: the first read goes out with 1, and
    /// a drive that took three messages before does not take it for a repeat.
    counter: u8,
}

/// The recovery the driver runs next to the cyclic frames: one frame of it per cycle.
struct RecoverySlot {
    net: Network,
    cfg: RecoveryConfig,
    running: Option<Engine<JobResult>>,
    /// The running procedure is a recovery (else a read of the drives' counters).
    recovering: bool,
    /// The drives whose counters are read, and when next.
    sync_drives: Vec<SyncDrive>,
    next_sync_read_ns: Option<u64>,
    /// The drive the round reads next (`sync_drives.len()`: no round under way), and the one
    /// whose read runs.
    sync_next: usize,
    sync_reading: Option<usize>,
    /// Each drive's first and last read.
    sync_counters: Vec<(SyncCounter, SyncCounter)>,
    /// The frame out, its send timestamp and its sends so far.
    out: Option<(Vec<u8>, u64, u32)>,
    retry_at_ns: u64,
    log: Vec<RecoveryEvent>,
}

impl RecoverySlot {
    /// Drops the running read of a drive's counter; the round takes the same drive again with
    /// the next cycle answered. Its request may have reached the drive: the next goes out with
    /// the counter after it, which the drive cannot take for a repeat whichever it saw last.
    fn drop_counter_read(&mut self) {
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
    fn finish<S: MasterSync>(&mut self, r: JobResult, now: u64, eng: &mut CyclicEngine<S>) {
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
            ev.ended_ns = Some(now);
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

/// The cyclic driver: resumable, so a scheduler can run a cyclic phase in slices.
#[derive(Debug)]
pub struct CyclicDriver {
    limits: CyclicLimits,
    buf: Vec<u8>,
    /// Each frame's reply buffer and length.
    replies: Vec<(Vec<u8>, Option<usize>)>,
    /// Which frames of the last cycle were answered (a copy of one that was is a duplicate).
    answered_before: Vec<bool>,
    start_ns: Option<u64>,
    cycles: u64,
    lost_row: u64,
    last_good: Option<u64>,
    stats: ExchangeStats,
    recovery: Option<RecoverySlot>,
    /// Cycles whose t_ms was the transmit timestamp, and those that had none to take.
    t_ms_sources: (u64, u64),
}

impl CyclicDriver {
    /// A driver with these limits.
    pub fn new(limits: CyclicLimits) -> Self {
        CyclicDriver {
            limits,
            buf: vec![0u8; 2048],
            replies: Vec::new(),
            answered_before: Vec::new(),
            start_ns: None,
            cycles: 0,
            lost_row: 0,
            last_good: None,
            stats: ExchangeStats::default(),
            recovery: None,
            t_ms_sources: (0, 0),
        }
    }

    /// With [`CyclicLimits::t_ms_from_tx_stamp`]: the cycles whose t_ms was the transport's
    /// transmit timestamp, and the answered cycles that had none and kept the send timestamp.
    pub fn t_ms_sources(&self) -> (u64, u64) {
        self.t_ms_sources
    }

    /// Reads the drives' SM-event-missed counters over CoE this often from now on
    /// ([`CyclicLimits::sync_counters_every_ns`]; `None`: no more reads).
    pub fn set_sync_counters_every_ns(&mut self, every_ns: Option<u64>) {
        self.limits.sync_counters_every_ns = every_ns;
    }

    /// Lets the driver bring slaves of `net` back when the engine sees them lose their
    /// configuration ([`crate::cyclic::Health::needs_recovery`]): a [`recover`] procedure runs
    /// one frame per cycle after the cyclic frames, while the cycle goes on for the rest.
    pub fn set_recovery(&mut self, net: Network, cfg: RecoveryConfig) {
        let sync_drives = net
            .slaves
            .iter()
            .enumerate()
            .filter(|(_, s)| s.dc == crate::network::DcCapability::SystemTime)
            .filter_map(|(k, s)| {
                let m = s.mailbox.filter(|m| m.coe())?;
                Some(SyncDrive {
                    position: k as u16,
                    station: s.station,
                    mailbox: m,
                    counter: 0,
                })
            })
            .collect();
        self.recovery = Some(RecoverySlot {
            net,
            cfg,
            running: None,
            recovering: false,
            sync_drives,
            next_sync_read_ns: None,
            sync_next: usize::MAX,
            sync_reading: None,
            sync_counters: Vec::new(),
            out: None,
            retry_at_ns: 0,
            log: Vec::new(),
        });
    }

    /// Exchanges the running recovery's frames one after the other until master time
    /// `until_ns` (or it waits past it, or a frame is lost: that one goes with the next cycle).
    fn recovery_burst<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        until_ns: u64,
    ) -> Result<(), Tr::Error> {
        let lost_row = self.lost_row;
        let Some(rs) = self.recovery.as_mut() else {
            return Ok(());
        };
        if !rs.recovering && lost_row > 0 {
            // The counters' read waits for a network that answers (see `run`).
            rs.drop_counter_read();
            return Ok(());
        }
        while rs.out.is_none() && tr.now_ns() < until_ns {
            let Some(e) = rs.running.as_mut() else {
                break;
            };
            let now = tr.now_ns();
            let frame = match e.poll(now) {
                Action::Send(f) => f.to_vec(),
                // Not asked for (`send_back_to_back`): never comes; told as not sent.
                Action::SendAll(f) => {
                    let n = f.len();
                    e.handle_replies(vec![Err(0); n]);
                    continue;
                }
                Action::WaitUntil(t) if t < until_ns => {
                    tr.sleep_until(t);
                    continue;
                }
                Action::WaitUntil(_) => break,
                Action::Done(r) => {
                    rs.finish(r, now, eng);
                    break;
                }
            };
            let at = tr.send_time_ns(frame.len());
            let sent = tr.send(&frame, at)?;
            self.stats.sent += 1;
            let mut answered = false;
            while let Some(r) = tr.recv(&mut self.buf, until_ns.max(sent))? {
                if !r.truncated && answers(&frame, &self.buf[..r.len]) {
                    e.handle_reply(&self.buf[..r.len], sent, r.received_ns);
                    self.stats.replies += 1;
                    answered = true;
                    break;
                }
                // A late cyclic reply or other traffic: counted as the cycle would.
                self.stats.stale += 1;
            }
            if !answered {
                // Lost (or not back before the cycle's end): sent again with the next cycle.
                self.stats.lost += 1;
                rs.out = Some((frame, sent, 1));
                break;
            }
        }
        Ok(())
    }

    /// The drives' SM-event-missed counters as first and as last read (see
    /// [`CyclicLimits::sync_counters_every_ns`]), in network order. The first read holds what
    /// the drive counted since OP, the hand-over from the bring-up to the cyclic phase
    /// included; the difference is the cyclic phase's own.
    pub fn sync_counters(&self) -> Vec<(SyncCounter, SyncCounter)> {
        let mut v = self
            .recovery
            .as_ref()
            .map_or_else(Vec::new, |r| r.sync_counters.clone());
        v.sort_by_key(|c| c.0.position);
        v
    }

    /// The recoveries so far.
    pub fn recoveries(&self) -> &[RecoveryEvent] {
        self.recovery.as_ref().map_or(&[], |r| &r.log[..])
    }

    /// Counters so far.
    pub fn stats(&self) -> ExchangeStats {
        self.stats
    }

    /// Cycles run so far.
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// Runs up to `slice` more cycles, or until a limit, the stop flag or the network's loss:
    /// `Some(why)` when the phase ended, `None` when the slice was done. `on_cycle` sees every
    /// cycle with the transport (a simulator's observer reads its ground truth there).
    pub fn run<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        slice: u64,
        stop: Option<&AtomicBool>,
        mut on_cycle: impl FnMut(&mut Tr, &CycleReport),
    ) -> Result<Option<Stopped>, Tr::Error> {
        let period_ns = u64::from(eng.config().period_ns.max(1));
        let start = *self.start_ns.get_or_insert(eng.scheduled_start_ns());
        for _ in 0..slice {
            if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
                return Ok(Some(Stopped::Interrupted));
            }
            if self.limits.max_cycles.is_some_and(|m| self.cycles >= m) {
                return Ok(Some(Stopped::Cycles));
            }
            let scheduled = eng.scheduled_start_ns();
            if self
                .limits
                .duration_ns
                .is_some_and(|d| scheduled.wrapping_sub(start) >= d)
            {
                return Ok(Some(Stopped::Duration));
            }
            tr.start_cycle(eng.cycle());
            tr.sleep_until(scheduled);
            let woke = tr.now_ns();
            // Woke a whole period late or more: those slots are gone.
            let skipped = woke.saturating_sub(scheduled) / period_ns;
            if skipped > 0 {
                eng.skip_cycles(skipped);
            }
            // The cycle's frames, back to back (one unless the process image needs more);
            // the first carries the reference's time and is the cycle's send timestamp.
            let n = eng.frame_count();
            let len = eng.frame_len();
            let mut sent_ns = 0;
            eng.set_recovery_running(
                self.recovery
                    .as_ref()
                    .is_some_and(|r| r.running.is_some() && r.recovering),
            );
            for k in 0..n {
                let len = eng.frame_len_of(k);
                let at = tr.send_time_ns(len);
                let s = tr.send_with(len, at, |buf| eng.write_frame(k, at, buf))?;
                if k == 0 {
                    sent_ns = s;
                }
                self.stats.sent += 1;
            }
            // The recovery's frame, if one runs (or starts now).
            let mut recovery_pending = false;
            if let Some(rs) = self.recovery.as_mut() {
                let now = tr.now_ns();
                if rs.running.is_none() && eng.health().needs_recovery && now >= rs.retry_at_ns {
                    let (net, cfg) = (rs.net.clone(), rs.cfg);
                    rs.running = Some(Engine::new(move |link| async move {
                        JobResult::Recovery(recover(link, net, cfg).await)
                    }));
                    rs.recovering = true;
                    rs.log.push(RecoveryEvent {
                        started_ns: now,
                        ended_ns: None,
                        outcome: None,
                    });
                }
                // A read of the drives' counters is not for a network that lost the last
                // cycle's frames: one running is dropped (its frames would only queue up on a
                // dead link) and starts again with the first cycle answered (not a period
                // later: on a host whose stalls come in bursts a read each period could be
                // dropped for seconds).
                if !rs.recovering && rs.running.is_some() && self.lost_row > 0 {
                    rs.drop_counter_read();
                }
                if let Some(every) = self.limits.sync_counters_every_ns
                    && rs.running.is_none()
                    && self.lost_row == 0
                    && !eng.health().needs_recovery
                    && !rs.sync_drives.is_empty()
                {
                    let due = *rs
                        .next_sync_read_ns
                        .get_or_insert(now.saturating_add(every));
                    if rs.sync_next >= rs.sync_drives.len() && now >= due {
                        // A round: every drive, one after the other.
                        rs.next_sync_read_ns = Some(now.saturating_add(every));
                        rs.sync_next = 0;
                    }
                    if let Some(&d) = rs.sync_drives.get(rs.sync_next) {
                        rs.sync_reading = Some(rs.sync_next);
                        rs.running = Some(Engine::new(move |link| read_sync_counter(link, d)));
                        rs.recovering = false;
                    }
                }
                if rs.out.is_none()
                    && let Some(e) = rs.running.as_mut()
                {
                    match e.poll(now) {
                        Action::Send(f) => rs.out = Some((f.to_vec(), 0, 0)),
                        // Not asked for (`send_back_to_back`): never comes; told as not sent.
                        Action::SendAll(f) => {
                            let n = f.len();
                            e.handle_replies(vec![Err(0); n]);
                        }
                        Action::WaitUntil(_) => {}
                        Action::Done(r) => rs.finish(r, now, eng),
                    }
                }
                if let Some((f, sent, tries)) = rs.out.as_mut() {
                    let at = tr.send_time_ns(f.len());
                    *sent = tr.send(f, at)?;
                    *tries += 1;
                    self.stats.sent += 1;
                    recovery_pending = true;
                }
            }
            if self.replies.len() < n {
                self.replies.resize_with(n, || (vec![0u8; 2048], None));
            }
            self.answered_before.clear();
            self.answered_before
                .extend(self.replies.iter().map(|r| r.1.is_some()));
            for r in self.replies.iter_mut() {
                r.1 = None;
            }
            // A reply is awaited until the next cycle's slot at the latest: a lost frame costs
            // its own cycle only, and a reply that comes later is discarded as late.
            let next_slot = eng.scheduled_start_ns().saturating_add(period_ns);
            let deadline = sent_ns
                .saturating_add(self.limits.reply_timeout_ns)
                .min(next_slot.max(sent_ns));
            let mut pending = n;
            let mut last: Option<Received> = None;
            while pending > 0 || recovery_pending {
                let Some(r) = tr.recv(&mut self.buf, deadline)? else {
                    break;
                };
                if r.truncated {
                    self.stats.truncated += 1;
                    self.stats.stale += 1;
                    continue;
                }
                let id = EcatFrame::new_checked(&self.buf[..r.len])
                    .ok()
                    .and_then(|f| f.first_datagram_id());
                let tagged = id.and_then(|id| eng.match_tag(id));
                let cyclic_now = matches!(tagged, Some((0, k)) if r.len >= eng.frame_len_of(k));
                if recovery_pending
                    && !cyclic_now
                    && let Some(rs) = self.recovery.as_mut()
                    && let Some((f, sent, _)) = &rs.out
                    && answers(f, &self.buf[..r.len])
                {
                    if let Some(e) = rs.running.as_mut() {
                        e.handle_reply(&self.buf[..r.len], *sent, r.received_ns);
                    }
                    rs.out = None;
                    recovery_pending = false;
                    self.stats.replies += 1;
                    continue;
                }
                match tagged {
                    Some((0, k)) if r.len >= eng.frame_len_of(k) => {
                        if self.replies[k].1.is_some() {
                            // The same frame answered twice: a second responder on the wire.
                            self.stats.duplicates += 1;
                            continue;
                        }
                        // The reply's bytes go to its slot without a copy.
                        std::mem::swap(&mut self.buf, &mut self.replies[k].0);
                        self.replies[k].1 = Some(r.len);
                        self.stats.replies += 1;
                        pending -= 1;
                        last = Some(r);
                    }
                    // A second copy of the last cycle's reply, or the reply itself too late.
                    Some((1, k)) if self.answered_before.get(k) == Some(&true) => {
                        self.stats.duplicates += 1;
                    }
                    Some((ago, _)) if ago > 0 => self.stats.late += 1,
                    _ => self.stats.stale += 1,
                }
            }
            self.stats.lost += pending as u64;
            if recovery_pending
                && let Some(rs) = self.recovery.as_mut()
                && let Some((_, _, tries)) = rs.out
            {
                // Sent again next cycle, up to its tries; then the procedure hears of it.
                self.stats.lost += 1;
                if tries >= RECOVERY_FRAME_TRIES {
                    rs.out = None;
                    if let Some(e) = rs.running.as_mut() {
                        e.handle_lost_after(tries);
                    }
                }
            }
            let replies = &self.replies;
            let views = |k: usize| replies[k].1.map(|l| &replies[k].0[..l]);
            let (record, tx_stamp_ns, round_trip_ns) = if pending == 0 {
                let r = last.expect("every frame answered");
                let t_ms = match (self.limits.t_ms_from_tx_stamp, r.tx_stamp_ns) {
                    (false, _) => sent_ns,
                    (true, Some(t)) => {
                        self.t_ms_sources.0 += 1;
                        t
                    }
                    (true, None) => {
                        self.t_ms_sources.1 += 1;
                        sent_ns
                    }
                };
                let rec = eng.complete_by(views, t_ms, r.received_ns);
                self.lost_row = 0;
                self.last_good = Some(rec.cycle);
                (
                    rec,
                    r.tx_stamp_ns,
                    Some(r.received_ns.saturating_sub(sent_ns)),
                )
            } else {
                self.lost_row += 1;
                let now = tr.now_ns();
                (eng.complete_by(views, sent_ns, now), None, None)
            };
            self.cycles += 1;
            on_cycle(
                tr,
                &CycleReport {
                    record,
                    woke_ns: woke,
                    wake_latency_ns: woke.wrapping_sub(scheduled) as i64,
                    skipped_before: skipped,
                    tx_stamp_ns,
                    stamp_ns: sent_ns,
                    round_trip_ns,
                    frame_len: len,
                },
            );
            // The rest of the cycle is the recovery's, up to a quarter cycle before the next
            // slot: its frames one after the other (a static drift compensation of a reset
            // slave is thousands of them).
            let until = eng.scheduled_start_ns().saturating_sub(period_ns / 4);
            self.recovery_burst(tr, eng, until)?;
            if self.lost_row >= self.limits.lost_in_a_row.max(1) {
                return Ok(Some(Stopped::NetworkGone {
                    last_good_cycle: self.last_good,
                    lost_in_a_row: self.lost_row,
                }));
            }
        }
        Ok(None)
    }
}
