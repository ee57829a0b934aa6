//! The cyclic driver: one overrun policy, one reply matching, one deadline, one loss
//! accounting, over any transport.

use super::jobs::{JobResult, RecoverySlot, SyncDrive, read_sync_counter};
use super::*;
use crate::cyclic::{CycleRecord, CyclicEngine};
use crate::io::{Action, Engine};
use crate::network::Network;
use crate::recovery::{RecoveryConfig, recover};
use crate::transport::{Received, Transport};
use ecsync_dc::MasterSync;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_wire::EcatFrame;
use std::sync::atomic::{AtomicBool, Ordering};

/// When the cyclic driver stops by itself, and how long it waits for a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CyclicLimits {
    /// Stop after this much master time from the first scheduled start.
    pub duration: Option<MasterDuration>,
    /// Stop after this many cycles.
    pub max_cycles: Option<u64>,
    /// Give up when this many frames in a row were lost: the network is gone.
    pub lost_in_a_row: u64,
    /// How long to wait for a cycle's reply after its send.
    pub reply_timeout: MasterDuration,
    /// Read every drive's SM-event-missed counter (0x1C32:0B) over CoE this often, in
    /// the cycles' spare time (`None`: never). Drives with CoE and a system time only, as
    /// the bring-up set them to DC mode.
    pub sync_counters_every: Option<MasterDuration>,
    /// Hand the method the transport's transmit timestamp of the cycle's first frame as its
    /// send time t_ms (the NIC's or the kernel's, taken after the scheduling and the stack's
    /// latency, see [`Received::tx_stamp`]) instead of the timestamp taken before the send;
    /// a cycle whose stamp did not come keeps the latter and is counted
    /// ([`CyclicDriver::t_ms_sources`]). For master-shift methods only: a bus-shift method
    /// writes its send time into the frame before it leaves.
    pub t_ms_from_tx_stamp: bool,
}

impl Default for CyclicLimits {
    fn default() -> Self {
        CyclicLimits {
            duration: None,
            max_cycles: None,
            lost_in_a_row: 100,
            reply_timeout: MasterDuration::from_ms(10),
            sync_counters_every: None,
            t_ms_from_tx_stamp: false,
        }
    }
}

/// One cycle as it happened.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleReport {
    /// What the engine and the method made of it.
    pub record: CycleRecord,
    /// When the task woke.
    pub woke: MasterInstant,
    /// Wake-up latency: woke minus scheduled, ns. When the task woke a whole period or more
    /// late, from the slot it missed first.
    pub wake_latency_ns: i64,
    /// Cycles skipped right before this one because the task woke after their slots had passed.
    pub skipped_before: u64,
    /// The transmit timestamp of the transport (kernel or NIC).
    pub tx_stamp: Option<MasterInstant>,
    /// The send timestamp taken before the cycle's first frame went to the transport (the
    /// record's `send_ns` unless t_ms came from the transmit timestamp).
    pub stamp: MasterInstant,
    /// Send timestamp to reply.
    pub round_trip: Option<MasterDuration>,
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

/// The cyclic driver: resumable, so a scheduler can run a cyclic phase in slices.
#[derive(Debug)]
pub struct CyclicDriver {
    pub(super) limits: CyclicLimits,
    pub(super) buf: Vec<u8>,
    /// Each frame's reply buffer and length.
    pub(super) replies: Vec<(Vec<u8>, Option<usize>)>,
    /// Which frames of the last cycle were answered (a copy of one that was is a duplicate).
    pub(super) answered_before: Vec<bool>,
    pub(super) start_ns: Option<u64>,
    pub(super) cycles: u64,
    pub(super) lost_row: u64,
    pub(super) last_good: Option<u64>,
    pub(super) stats: ExchangeStats,
    pub(super) recovery: Option<RecoverySlot>,
    /// Cycles whose t_ms was the transmit timestamp, and those that had none to take.
    pub(super) t_ms_sources: (u64, u64),
    /// The cycle's report, filled in place each cycle: a record is a few hundred bytes, and
    /// returned and moved into a new report it was copied twice a cycle.
    pub(super) report: CycleReport,
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
            report: CycleReport::default(),
        }
    }

    /// With [`CyclicLimits::t_ms_from_tx_stamp`]: the cycles whose t_ms was the transport's
    /// transmit timestamp, and the answered cycles that had none and kept the send timestamp.
    pub fn t_ms_sources(&self) -> (u64, u64) {
        self.t_ms_sources
    }

    /// Reads the drives' SM-event-missed counters over CoE this often from now on
    /// ([`CyclicLimits::sync_counters_every`]; `None`: no more reads).
    pub fn set_sync_counters_every(&mut self, every: Option<MasterDuration>) {
        self.limits.sync_counters_every = every;
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
    pub(super) fn recovery_burst<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        until: MasterInstant,
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
        while rs.out.is_none() && tr.now() < until {
            let Some(e) = rs.running.as_mut() else {
                break;
            };
            let now = tr.now();
            let frame = match e.poll(now) {
                Action::Send(f) => f.to_vec(),
                // Not asked for (`send_back_to_back`): never comes; told as not sent.
                Action::SendAll(f) => {
                    let n = f.len();
                    e.handle_replies(vec![Err(0); n]);
                    continue;
                }
                Action::WaitUntil(t) if t < until => {
                    tr.sleep_until(t);
                    continue;
                }
                Action::WaitUntil(_) => break,
                Action::Done(r) => {
                    rs.finish(r, now.as_ns(), eng);
                    break;
                }
            };
            let at = tr.send_time(frame.len());
            let sent = tr.send(&frame, at)?;
            self.stats.sent += 1;
            let mut answered = false;
            while let Some(r) = tr.recv(&mut self.buf, until.max(sent))? {
                if !r.truncated && answers(&frame, &self.buf[..r.len]) {
                    e.handle_reply(&self.buf[..r.len], sent, r.received);
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
    /// [`CyclicLimits::sync_counters_every`]), in network order. The first read holds what
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
    ///
    /// A cycle, step by step: `stop_reason`; `wake` at the cycle's slot (skipping
    /// the slots that passed); `send_cyclic`; `send_job_frame` (a recovery's or
    /// a counter read's frame); `collect_replies` until the deadline;
    /// `job_frame_lost`; `complete` hands the replies to the engine; the
    /// observer; `recovery_burst` in the rest of the cycle.
    pub fn run<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        slice: u64,
        stop: Option<&AtomicBool>,
        mut on_cycle: impl FnMut(&mut Tr, &CycleReport),
    ) -> Result<Option<Stopped>, Tr::Error> {
        let period_ns = u64::from(eng.config().period_ns.max(1));
        let start = *self.start_ns.get_or_insert(eng.scheduled_start().as_ns());
        for _ in 0..slice {
            if let Some(why) = self.stop_reason(eng, start, stop) {
                return Ok(Some(why));
            }
            let (scheduled, woke, skipped) = self.wake(tr, eng, period_ns);
            // The cycle's frames, back to back (one unless the process image needs more);
            // the first carries the reference's time and is the cycle's send timestamp.
            let n = eng.frame_count();
            let len = eng.frame_len();
            let sent = self.send_cyclic(tr, eng)?;
            let job_pending = self.send_job_frame(tr, eng)?;
            let (pending, last, job_pending) =
                self.collect_replies(tr, eng, n, sent, period_ns, job_pending)?;
            self.stats.lost += pending as u64;
            if job_pending {
                self.job_frame_lost();
            }
            self.complete(tr, eng, pending, last, sent);
            self.cycles += 1;
            let r = &mut self.report;
            r.woke = woke;
            r.wake_latency_ns = woke.signed_since(scheduled);
            r.skipped_before = skipped;
            r.stamp = sent;
            r.frame_len = len;
            on_cycle(tr, &self.report);
            // The rest of the cycle is the recovery's, up to a quarter cycle before the next
            // slot: its frames one after the other (a static drift compensation of a reset
            // slave is thousands of them).
            let until = eng
                .scheduled_start()
                .saturating_sub(MasterDuration::from_ns(period_ns / 4));
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

    /// Why the phase ends before the next cycle, if it does: the stop flag, the cycle count,
    /// the duration from `start` (master time, ns).
    fn stop_reason<S: MasterSync>(
        &self,
        eng: &CyclicEngine<S>,
        start: u64,
        stop: Option<&AtomicBool>,
    ) -> Option<Stopped> {
        if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            return Some(Stopped::Interrupted);
        }
        if self.limits.max_cycles.is_some_and(|m| self.cycles >= m) {
            return Some(Stopped::Cycles);
        }
        let scheduled = eng.scheduled_start().as_ns();
        self.limits
            .duration
            .is_some_and(|d| scheduled.wrapping_sub(start) >= d.as_ns())
            .then_some(Stopped::Duration)
    }

    /// Sleeps to the cycle's slot: (scheduled, woke, slots skipped). A task that woke a whole
    /// period late or more has lost those slots: the engine skips them.
    fn wake<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        period_ns: u64,
    ) -> (MasterInstant, MasterInstant, u64) {
        let scheduled = eng.scheduled_start();
        tr.start_cycle(eng.cycle());
        tr.sleep_until(scheduled);
        let woke = tr.now();
        let skipped = woke.saturating_since(scheduled).as_ns() / period_ns;
        if skipped > 0 {
            eng.skip_cycles(skipped);
        }
        (scheduled, woke, skipped)
    }

    /// Sends the cycle's frames back to back: the first one's send timestamp.
    fn send_cyclic<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
    ) -> Result<MasterInstant, Tr::Error> {
        let mut sent = MasterInstant::default();
        eng.set_recovery_running(
            self.recovery
                .as_ref()
                .is_some_and(|r| r.running.is_some() && r.recovering),
        );
        for k in 0..eng.frame_count() {
            let len = eng.frame_len_of(k);
            let at = tr.send_time(len);
            let s = tr.send_with(len, at, |buf| eng.write_frame(k, at, buf))?;
            if k == 0 {
                sent = s;
            }
            self.stats.sent += 1;
        }
        Ok(sent)
    }

    /// The side job's frame after the cyclic ones: a recovery starts if the engine asks for
    /// one, a read of the drives' counters if one is due; the running job's next frame (or
    /// the one lost last cycle) goes out. Whether a frame went out.
    fn send_job_frame<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
    ) -> Result<bool, Tr::Error> {
        let lost_row = self.lost_row;
        let every = self.limits.sync_counters_every.map(MasterDuration::as_ns);
        let Some(rs) = self.recovery.as_mut() else {
            return Ok(false);
        };
        let now_at = tr.now();
        let now = now_at.as_ns();
        if rs.running.is_none() && eng.health().needs_recovery && now >= rs.retry_at_ns {
            let (net, cfg) = (rs.net.clone(), rs.cfg.clone());
            rs.running = Some(Engine::new(move |link| async move {
                JobResult::Recovery(recover(link, net, cfg).await)
            }));
            rs.recovering = true;
            rs.log.push(RecoveryEvent {
                started: now_at,
                ended: None,
                outcome: None,
            });
        }
        // A read of the drives' counters is not for a network that lost the last cycle's
        // frames: one running is dropped (its frames would only queue up on a dead link) and
        // starts again with the first cycle answered (not a period later: on a host whose
        // stalls come in bursts a read each period could be dropped for seconds).
        if !rs.recovering && rs.running.is_some() && lost_row > 0 {
            rs.drop_counter_read();
        }
        if let Some(every) = every
            && rs.running.is_none()
            && lost_row == 0
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
            match e.poll(now_at) {
                Action::Send(f) => rs.out = Some((f.to_vec(), MasterInstant::default(), 0)),
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
            let at = tr.send_time(f.len());
            *sent = tr.send(f, at)?;
            *tries += 1;
            self.stats.sent += 1;
            return Ok(true);
        }
        Ok(false)
    }

    /// Receives until every cyclic frame (and the job's frame, if `job_pending`) is answered
    /// or the deadline passed: a reply is awaited until the next cycle's slot at the latest,
    /// so a lost frame costs its own cycle only, and a reply that comes later is discarded
    /// as late. (cyclic frames unanswered, the last reply, the job's frame still unanswered).
    fn collect_replies<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        n: usize,
        sent: MasterInstant,
        period_ns: u64,
        mut job_pending: bool,
    ) -> Result<(usize, Option<Received>, bool), Tr::Error> {
        if self.replies.len() < n {
            self.replies.resize_with(n, || (vec![0u8; 2048], None));
        }
        self.answered_before.clear();
        self.answered_before
            .extend(self.replies.iter().map(|r| r.1.is_some()));
        for r in self.replies.iter_mut() {
            r.1 = None;
        }
        let next_slot = eng
            .scheduled_start()
            .saturating_add(MasterDuration::from_ns(period_ns));
        let deadline = sent
            .saturating_add(self.limits.reply_timeout)
            .min(next_slot.max(sent));
        let mut pending = n;
        let mut last: Option<Received> = None;
        while pending > 0 || job_pending {
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
            if job_pending && !cyclic_now && self.take_job_reply(&r) {
                job_pending = false;
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
        Ok((pending, last, job_pending))
    }

    /// Whether the frame in the buffer (`r`) answers the side job's frame: then the job has
    /// it.
    fn take_job_reply(&mut self, r: &Received) -> bool {
        let Some(rs) = self.recovery.as_mut() else {
            return false;
        };
        let Some((f, sent, _)) = &rs.out else {
            return false;
        };
        if !answers(f, &self.buf[..r.len]) {
            return false;
        }
        if let Some(e) = rs.running.as_mut() {
            e.handle_reply(&self.buf[..r.len], *sent, r.received);
        }
        rs.out = None;
        self.stats.replies += 1;
        true
    }

    /// The side job's frame did not come back: sent again next cycle, up to its tries; then
    /// the procedure hears of it.
    fn job_frame_lost(&mut self) {
        if let Some(rs) = self.recovery.as_mut()
            && let Some((_, _, tries)) = rs.out
        {
            self.stats.lost += 1;
            if tries >= RECOVERY_FRAME_TRIES {
                rs.out = None;
                if let Some(e) = rs.running.as_mut() {
                    e.handle_lost_after(tries);
                }
            }
        }
    }

    /// Hands the cycle's replies to the engine: the record, the transmit stamp and the round
    /// trip into the report (with `pending` frames unanswered: a lost cycle, timed now).
    fn complete<S: MasterSync, Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        eng: &mut CyclicEngine<S>,
        pending: usize,
        last: Option<Received>,
        sent: MasterInstant,
    ) {
        let replies = &self.replies;
        let views = |k: usize| replies[k].1.map(|l| &replies[k].0[..l]);
        if pending == 0 {
            let r = last.expect("every frame answered");
            let t_ms = match (self.limits.t_ms_from_tx_stamp, r.tx_stamp) {
                (false, _) => sent,
                (true, Some(t)) => {
                    self.t_ms_sources.0 += 1;
                    t
                }
                (true, None) => {
                    self.t_ms_sources.1 += 1;
                    sent
                }
            };
            self.report.record = eng.complete_by(views, t_ms, r.received);
            self.lost_row = 0;
            self.last_good = Some(self.report.record.cycle);
            self.report.tx_stamp = r.tx_stamp;
            self.report.round_trip = Some(r.received.saturating_since(sent));
        } else {
            self.lost_row += 1;
            let now = tr.now();
            self.report.record = eng.complete_by(views, sent, now);
            self.report.tx_stamp = None;
            self.report.round_trip = None;
        }
    }
}
