//! The in-process transport: drives an [`Engine`] against a virtual [`Segment`] in virtual time.

use crate::clock::{CrystalParams, LocalClock};
use crate::fault::{FaultPlayer, FrameFate};
use crate::pcap::PcapCapture;
use crate::{FrameTrace, Segment, frame_wire_time_ps};
use ecsync_dc::time::MasterInstant;
use ecsync_master::driver::{ExchangeStats, ProcedureConfig, ProcedureExchange};
use ecsync_master::io::{Engine, Event};
use ecsync_master::redundancy::SecondPort;
use ecsync_master::transport::{Never, Received, Transport};
use std::fs::File;
use std::io::BufWriter;

/// How the simulator's procedures wait for replies: 10 s, no retries.
pub const SIM_PROCEDURE: ProcedureConfig = ProcedureConfig {
    reply_timeout_ns: 10_000_000_000,
    retries: 0,
};

/// Master clock at simulation start: 2026-11-22 00:00 UTC in DC time (ns since 2000-01-01).
pub const SIM_EPOCH_NS: u64 = 848_620_800_000_000_000;

/// The master's clock: a crystal (ppm and wander, the same model as the ESCs') mapping real time
/// to master time, ns since the DC epoch.
///
/// No control loop steers it, so between two wander steps it is one straight line; the line is
/// cached (its start and slope both ways) so that reading and inverting it every cycle costs a
/// multiplication each.
#[derive(Debug, Clone)]
pub struct MasterClock {
    clock: LocalClock,
    /// Steps of the clock so far (a fault's), ns: added to the crystal's time.
    step_ns: i64,
    line: Line,
    /// The last inversion (master ns, real ps, the line's anchor it was made on): a cycle asks
    /// for the real time of its send timestamp more than once.
    last_inverse: (u64, u64, u64),
}

/// The master clock's straight piece from `anchor_ps` up to `next_ps` (the next wander step).
#[derive(Debug, Clone, Copy)]
struct Line {
    anchor_ps: u64,
    next_ps: u64,
    /// Master time at the anchor: whole ns and fraction.
    a_ns: u64,
    a_frac: f64,
    /// Master ns per real ps, and real ps per master ns.
    ns_per_ps: f64,
    ps_per_ns: f64,
}

impl Line {
    fn of(clock: &LocalClock) -> Line {
        let anchor_ps = clock.anchor_ps();
        let (a_ns, a_frac) = clock.local_exact_ns(anchor_ps);
        let rate = clock.rate();
        Line {
            anchor_ps,
            next_ps: clock.next_wander_ps(),
            a_ns,
            a_frac,
            ns_per_ps: rate * 1e-3,
            ps_per_ns: 1e3 / rate,
        }
    }
}

impl MasterClock {
    /// An ideal clock reading `epoch_ns` at real time 0.
    pub fn ideal(epoch_ns: u64) -> Self {
        Self::new(CrystalParams {
            initial_local_ns: epoch_ns,
            ..CrystalParams::default()
        })
    }

    /// A clock with this crystal (its `initial_local_ns` is the master time at real time 0).
    pub fn new(crystal: CrystalParams) -> Self {
        let clock = LocalClock::new(crystal);
        let line = Line::of(&clock);
        MasterClock {
            clock,
            step_ns: 0,
            line,
            last_inverse: (u64::MAX, 0, u64::MAX),
        }
    }

    /// Moves to the straight piece that holds real time `t_ps` (forward only).
    #[cold]
    #[inline(never)]
    fn advance(&mut self, t_ps: u64) {
        self.clock.advance_to(t_ps);
        self.line = Line::of(&self.clock);
    }

    /// Master time at real time `t_ps`, ns (the last whole nanosecond).
    #[inline]
    pub fn master_ns(&mut self, t_ps: u64) -> u64 {
        if t_ps >= self.line.next_ps {
            self.advance(t_ps);
        }
        let l = &self.line;
        // Signed: a time slightly before the anchor reads back along the same line.
        let d = (t_ps.wrapping_sub(l.anchor_ps) as i64) as f64 * l.ns_per_ps + l.a_frac;
        l.a_ns
            .wrapping_add(crate::clock::floor_split(d).0 as u64)
            .wrapping_add(self.step_ns as u64)
    }

    /// Steps the clock by `step_ns` (an NTP step, a careless `date -s`): from now on it reads
    /// that much more.
    pub fn step(&mut self, step_ns: i64) {
        self.step_ns = self.step_ns.wrapping_add(step_ns);
        self.last_inverse = (u64::MAX, 0, u64::MAX);
    }

    /// Real time (ps) at which the master clock reads `t_ns` (the inverse of
    /// [`MasterClock::master_ns`], to a picosecond).
    #[inline]
    pub fn real_ps_at(&mut self, t_ns: u64) -> u64 {
        let (memo_ns, memo_ps, memo_anchor) = self.last_inverse;
        if memo_ns == t_ns && memo_anchor == self.line.anchor_ps {
            return memo_ps;
        }
        let r = self.invert(t_ns.wrapping_sub(self.step_ns as u64));
        self.last_inverse = (t_ns, r, self.line.anchor_ps);
        r
    }

    fn invert(&mut self, t_ns: u64) -> u64 {
        loop {
            let l = &self.line;
            // Signed 64-bit difference: an i128 conversion costs a libcall on the hot path.
            let d_ns = (t_ns.wrapping_sub(l.a_ns) as i64) as f64 - l.a_frac;
            let r = l.anchor_ps as f64 + d_ns * l.ps_per_ns;
            // Rounds half up; `r` is not negative (no libm `round` call).
            let r = (r.max(0.0) + 0.5) as u64;
            // The rate is constant up to the next wander step: beyond it, step there first.
            if r < l.next_ps || l.next_ps <= l.anchor_ps {
                return r;
            }
            let next = l.next_ps;
            self.advance(next);
        }
    }
}

/// A frame exchange as the segment saw it, in real time (for observers of the ground truth).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Exchange {
    /// Real time the frame left the master, ps.
    pub sent_ps: u64,
    /// Real time the reply was complete at the master, ps (`None`: lost).
    pub received_ps: Option<u64>,
}

/// What became of a frame a [`FrameTap`] sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TapLoss {
    /// Processed and answered (its reply may still come after the master stopped waiting).
    No,
    /// Lost on its way out (the fault player's): the segment did not process it; the tap sees
    /// the request, and the segment's trace is not this frame's.
    Out,
    /// Processed, then lost on its way back: the outputs reached the slaves, no reply came.
    Back,
}

/// Sees every frame that reaches the wire, right after the segment processed it (or the fault
/// player lost it): the segment, the frame as the segment returned it (the request when
/// [`TapLoss::Out`]), the real time its first bit left the master (ps), and its fate. Frames
/// the host dropped before the wire (a missed launch time) are not seen.
pub type FrameTap = Box<dyn FnMut(&Segment, &[u8], u64, TapLoss) + Send + Sync>;

/// A simulated host's timing of one cycle: how it delays the cyclic task's wake-up, execution
/// and send (the letter's j_s + e_m) and the NIC's path to the wire (tx latency + j_c).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HostDelays {
    /// From the scheduled start to the send timestamp, ns.
    pub wake_to_send_ns: f64,
    /// From the send timestamp to the frame's first bit on the wire, ns.
    pub tx_ns: f64,
    /// The cycle's frames never reach the wire: handed to the kernel with a launch time that
    /// had passed (SO_TXTIME's ETF qdisc drops them and reports a deadline miss).
    pub dropped: bool,
    /// The NIC stamps the cycle's first frame in hardware: the stamp is the master-clock time
    /// of its first bit on the wire plus this error, ns (the PHC's resolution and its mapping
    /// to the host's clock); `None`: no transmit stamp.
    pub tx_stamp_error_ns: Option<f64>,
}

/// Where a simulated host's per-cycle timing comes from (the lab's seeded noise).
pub trait HostModel: Send + Sync {
    /// The delays of cycle `cycle`.
    fn cycle(&self, cycle: u64) -> HostDelays;
}

/// Runs master procedures against a segment in virtual time: the [`Transport`] of the
/// simulator. Without a host model the master is ideal: it wakes on time, its send timestamp is
/// the frame's moment on the wire less `tx_latency_ps`; with one (set for a cyclic phase) each
/// cycle's task wakes, runs and sends as the model says.
pub struct SimTransport {
    segment: Segment,
    now_ps: u64,
    /// Master time now when a host wake set it exactly (else it is read off `now_ps`).
    now_master_ns: Option<u64>,
    master_clock: MasterClock,
    tx_latency_ps: u64,
    rx_latency_ps: u64,
    host: Option<Box<dyn HostModel>>,
    /// This cycle's host delays, drawn at [`Transport::start_cycle`].
    delays: Option<HostDelays>,
    /// This cycle's frames are dropped before the wire (a launch time missed), and how many
    /// frames were so far.
    drop_cycle: bool,
    launch_misses: u64,
    /// The hardware transmit stamp of this cycle's first frame, master ns (a host whose NIC
    /// stamps, see [`HostDelays::tx_stamp_error_ns`]).
    cycle_tx_stamp_ns: Option<u64>,
    /// Replies in flight, in the order they arrive: when each is complete at the master (real
    /// ps), its bytes; and spent buffers to reuse.
    inflight: std::collections::VecDeque<(u64, u8, Vec<u8>)>,
    /// The master's second port (a ring's far end, [`SimTransport::enable_second_port`]).
    second: SecondWire,
    spare: Vec<Vec<u8>>,
    /// The master's wire is busy with its last frame until then (frames leave back to back).
    wire_free_ps: u64,
    last: Exchange,
    /// The ground truth of each frame of the current cycle (a cycle of several frames).
    traces: Vec<FrameTrace>,
    frame_in_cycle: usize,
    /// Bit k: the current cycle's frame k reached the segment (not dropped by the host, not
    /// lost on its way out), so its trace is its own ([`SimTransport::frame_processed`]).
    processed_in_cycle: u64,
    /// The same past the 64th frame (a network of thousands of drives sends dozens of frames
    /// a cycle): bit k - 64. Kept between cycles, so a cycle allocates nothing.
    processed_beyond: Vec<u64>,
    cycle_mode: bool,
    capture: Option<PcapCapture<BufWriter<File>>>,
    faults: Option<FaultPlayer>,
    tap: Option<FrameTap>,
}

impl std::fmt::Debug for SimTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimTransport")
            .field("now_ps", &self.now_ps)
            .finish_non_exhaustive()
    }
}

impl SimTransport {
    /// A transport with an ideal master clock and a few microseconds of NIC latency.
    pub fn new(segment: Segment) -> Self {
        SimTransport {
            segment,
            now_ps: 0,
            now_master_ns: None,
            master_clock: MasterClock::ideal(SIM_EPOCH_NS),
            tx_latency_ps: 2_000_000,
            rx_latency_ps: 3_000_000,
            host: None,
            delays: None,
            drop_cycle: false,
            launch_misses: 0,
            cycle_tx_stamp_ns: None,
            inflight: std::collections::VecDeque::new(),
            second: SecondWire::default(),
            spare: Vec::new(),
            wire_free_ps: 0,
            last: Exchange::default(),
            traces: Vec::new(),
            frame_in_cycle: 0,
            processed_in_cycle: 0,
            processed_beyond: Vec::new(),
            cycle_mode: false,
            capture: None,
            faults: None,
            tap: None,
        }
    }

    /// A copy of this transport in its current state (segment, clocks, time) without the
    /// capture and the host model: several experiments can continue from one bring-up.
    pub fn fork(&self) -> SimTransport {
        SimTransport {
            segment: self.segment.clone(),
            now_ps: self.now_ps,
            now_master_ns: self.now_master_ns,
            master_clock: self.master_clock.clone(),
            tx_latency_ps: self.tx_latency_ps,
            rx_latency_ps: self.rx_latency_ps,
            host: None,
            delays: None,
            drop_cycle: false,
            launch_misses: 0,
            cycle_tx_stamp_ns: None,
            inflight: self.inflight.clone(),
            second: self.second,
            spare: Vec::new(),
            wire_free_ps: self.wire_free_ps,
            last: self.last,
            traces: Vec::new(),
            frame_in_cycle: 0,
            processed_in_cycle: 0,
            processed_beyond: Vec::new(),
            cycle_mode: false,
            capture: None,
            faults: self.faults.clone(),
            tap: None,
        }
    }

    /// Plays `faults` from now on: the segment's on its frames, the host's on the cyclic
    /// task's wake-ups and the master's clock.
    pub fn set_faults(&mut self, faults: FaultPlayer) {
        self.faults = Some(faults);
    }

    /// Hands every frame that reaches the wire from now on to `tap` (see [`FrameTap`]);
    /// `None` removes it. A fork does not take it.
    pub fn set_frame_tap(&mut self, tap: Option<FrameTap>) {
        self.tap = tap;
    }

    /// The fault player, if one plays.
    pub fn faults(&self) -> Option<&FaultPlayer> {
        self.faults.as_ref()
    }

    /// The segment.
    pub fn segment(&self) -> &Segment {
        &self.segment
    }

    /// The segment, to change (a test's direct frames).
    pub fn segment_mut(&mut self) -> &mut Segment {
        &mut self.segment
    }

    /// Real time now, ps since the start of the simulation.
    pub fn now_ps(&self) -> u64 {
        self.now_ps
    }

    /// The master's clock.
    pub fn master_clock_mut(&mut self) -> &mut MasterClock {
        &mut self.master_clock
    }

    /// Replaces the master's clock (before anything ran: the time does not move).
    pub fn set_master_clock(&mut self, clock: MasterClock) {
        self.master_clock = clock;
        self.now_master_ns = None;
    }

    /// The latency from the reply's last bit to the master's receive timestamp, ps.
    pub fn set_rx_latency_ps(&mut self, ps: u64) {
        self.rx_latency_ps = ps;
    }

    /// The ideal host's latency from the send timestamp to the wire (the bring-up's), ps.
    pub fn tx_latency_ps(&self) -> u64 {
        self.tx_latency_ps
    }

    /// Takes each cycle's wake-up, execution and NIC timing from `host` from now on.
    pub fn set_host(&mut self, host: Box<dyn HostModel>) {
        self.host = Some(host);
    }

    /// The last exchange in real time.
    pub fn last_exchange(&self) -> Exchange {
        self.last
    }

    /// Frames the host dropped before the wire because their launch time had passed when they
    /// were handed over (see [`HostDelays::dropped`]).
    pub fn launch_misses(&self) -> u64 {
        self.launch_misses
    }

    /// The ground truth of frame `k` of the current cycle (as the segment's trace was right
    /// after it passed); the last frame's is [`Segment::trace`].
    pub fn frame_trace(&self, k: usize) -> &FrameTrace {
        match self.traces.get(k) {
            Some(t) if k + 1 < self.frame_in_cycle => t,
            _ => self.segment.trace(),
        }
    }

    /// Whether the current cycle's frame `k` reached the segment: `false` for a frame the host
    /// dropped before the wire (a missed launch time) or a fault lost on its way out, whose
    /// [`SimTransport::frame_trace`] is an earlier frame's. A frame whose reply was lost or
    /// came too late for the master was processed: its outputs reached the slaves.
    pub fn frame_processed(&self, k: usize) -> bool {
        match k.checked_sub(64) {
            None => self.processed_in_cycle & (1 << k) != 0,
            Some(b) => self
                .processed_beyond
                .get(b / 64)
                .is_some_and(|w| w & (1 << (b % 64)) != 0),
        }
    }

    /// The current frame of the cycle reached the segment.
    fn mark_processed(&mut self) {
        let k = self.frame_in_cycle;
        match k.checked_sub(64) {
            None => self.processed_in_cycle |= 1 << k,
            Some(b) => {
                if self.processed_beyond.len() <= b / 64 {
                    self.processed_beyond.resize(b / 64 + 1, 0);
                }
                self.processed_beyond[b / 64] |= 1 << (b % 64);
            }
        }
    }

    /// Captures every frame (sent and returned) to a pcap file.
    pub fn capture_to(&mut self, path: &std::path::Path) -> Result<(), pcap_file_error::Error> {
        self.capture = Some(PcapCapture::create(path).map_err(pcap_file_error::Error)?);
        Ok(())
    }

    /// Flushes the capture, returning the number of frames written.
    pub fn finish_capture(&mut self) -> std::io::Result<u64> {
        match self.capture.take() {
            Some(c) => {
                let n = c.frames();
                c.finish()?;
                Ok(n)
            }
            None => Ok(0),
        }
    }

    /// The master's clock now.
    pub fn master_now(&mut self) -> MasterInstant {
        MasterInstant::from_ns(self.master_now_ns())
    }

    /// The master's clock now, ns (the transport's own arithmetic).
    fn master_now_ns(&mut self) -> u64 {
        match self.now_master_ns {
            Some(t) => t,
            None => {
                let t = self.now_ps;
                self.master_clock.master_ns(t)
            }
        }
    }

    /// Real time (ps) at which the master's clock reads `t`.
    pub fn real_ps_at(&mut self, t: MasterInstant) -> u64 {
        self.master_clock.real_ps_at(t.as_ns())
    }

    /// The segment, the transport consumed.
    pub fn into_segment(self) -> Segment {
        self.segment
    }

    /// Runs a procedure (the bring-up) to completion with the one bring-up driver, in virtual
    /// time: a reply is waited for 10 s and never sent again (the segment loses a frame only
    /// when told to). `observe` sees the transport after each exchange.
    pub fn run_procedure<T: 'static>(
        &mut self,
        engine: &mut Engine<T>,
        observe: impl FnMut(&mut SimTransport, &ProcedureExchange, &[Event]),
    ) -> T {
        let mut stats = ExchangeStats::default();
        match ecsync_master::driver::run_procedure(self, engine, SIM_PROCEDURE, &mut stats, observe)
        {
            Ok(v) => v,
            Err(never) => match never {},
        }
    }

    /// A reply in flight, complete at the master at real time `t_ps`: in arrival order (later
    /// frames of a cycle come back later).
    fn arrive(&mut self, t_ps: u64, port: u8, buf: Vec<u8>) {
        if port == 1 && !self.second.enabled {
            // Out at a ring's far end, where no port of this master listens.
            self.spare.push(buf);
            return;
        }
        if self.inflight.back().is_none_or(|x| x.0 <= t_ps) {
            self.inflight.push_back((t_ps, port, buf));
        } else {
            let at = self.inflight.partition_point(|x| x.0 <= t_ps);
            self.inflight.insert(at, (t_ps, port, buf));
        }
    }

    /// The master listens and sends on its second port too (a ring's far end: the segment's
    /// [`Segment::connect_ring`]); without it, what arrives there is lost to it, as to a
    /// master with one port.
    pub fn enable_second_port(&mut self) {
        self.second.enabled = true;
    }

    /// [`SimTransport::run_procedure`] with the waiting and retries of `cfg` (a bring-up on a
    /// segment that loses frames: a lost datagram is sent again).
    pub fn run_procedure_with<T: 'static>(
        &mut self,
        engine: &mut Engine<T>,
        cfg: ProcedureConfig,
        observe: impl FnMut(&mut SimTransport, &ProcedureExchange, &[Event]),
    ) -> T {
        let mut stats = ExchangeStats::default();
        match ecsync_master::driver::run_procedure(self, engine, cfg, &mut stats, observe) {
            Ok(v) => v,
            Err(never) => match never {},
        }
    }

    /// [`SimTransport::run_procedure_with`] that gives up once `stop` is set (Ctrl-C during
    /// the bring-up of a large segment): `None` then, with the segment wherever the procedure
    /// left it.
    pub fn run_procedure_until<T: 'static>(
        &mut self,
        engine: &mut Engine<T>,
        cfg: ProcedureConfig,
        stop: &std::sync::atomic::AtomicBool,
        mut observe: impl FnMut(&mut SimTransport, &ProcedureExchange, &[Event]),
    ) -> Option<T> {
        let mut stats = ExchangeStats::default();
        let mut tr = ecsync_master::transport::Interruptible::new(self, stop);
        let r =
            ecsync_master::driver::run_procedure(&mut tr, engine, cfg, &mut stats, |t, x, e| {
                observe(t.inner, x, e)
            });
        match r {
            Ok(v) => Some(v),
            Err(ecsync_master::transport::Interrupted::Stopped) => None,
            Err(ecsync_master::transport::Interrupted::Transport(never)) => match never {},
        }
    }

    /// Moves to master time `t_ns` exactly (a host's wake-up or a deadline).
    fn set_master_now(&mut self, t_ns: u64) {
        self.now_ps = self.master_clock.real_ps_at(t_ns);
        self.now_master_ns = Some(t_ns);
    }
}

impl Transport for SimTransport {
    type Error = Never;

    fn now(&mut self) -> MasterInstant {
        MasterInstant::from_ns(self.master_now_ns())
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        let t_ns = t.as_ns();
        // The host's faults due now: a stall delays this wake-up, a step moves the clock.
        let stall_ns = match &mut self.faults {
            Some(f) => {
                let (stall, step) = f.host_faults(self.now_ps);
                if step != 0 {
                    self.master_clock.step(step);
                    self.now_master_ns = None;
                }
                stall
            }
            None => 0,
        };
        let t_ns = t_ns.saturating_add(stall_ns);
        match self.delays {
            // A host's cyclic task: it wakes at the scheduled start, or when the previous
            // cycle is done if that is later, late by j_s, and runs e_m before it timestamps.
            Some(d) => {
                let wake = t_ns.max(self.master_now_ns());
                self.set_master_now(wake + d.wake_to_send_ns as u64);
            }
            // The ideal master: its clock reaches `t_ns` (time always moves on, by a
            // nanosecond at least, so a procedure that waits on the present cannot stall it).
            None => {
                let t_ps = self.master_clock.real_ps_at(t_ns).max(self.now_ps + 1000);
                self.now_ps = t_ps;
                self.now_master_ns = None;
            }
        }
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        n: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Never> {
        let at_ns = at.as_ns();
        let delays = self.delays.take();
        let tx_ps = match delays {
            Some(d) => self.master_clock.real_ps_at(at_ns) + (d.tx_ns * 1000.0) as u64,
            None => self.now_ps + self.tx_latency_ps,
        };
        // Frames leave one after the other.
        let tx_ps = tx_ps.max(self.wire_free_ps);
        if let Some(err) = delays.and_then(|d| d.tx_stamp_error_ns)
            && !self.drop_cycle
        {
            let stamp = self.master_clock.master_ns(tx_ps) as i64 + err.round() as i64;
            self.cycle_tx_stamp_ns = Some(stamp as u64);
        }
        self.wire_free_ps = tx_ps + frame_wire_time_ps(n);
        self.second.last_tx_ps = tx_ps;
        // A cycle's earlier frame keeps its ground truth before the segment's trace is
        // overwritten (one frame per cycle copies nothing).
        if self.cycle_mode && self.frame_in_cycle > 0 {
            let k = self.frame_in_cycle - 1;
            let t = self.segment.trace().clone();
            if self.traces.len() <= k {
                self.traces.push(t);
            } else {
                self.traces[k] = t;
            }
        }
        // A spare buffer of a cycle's frame has the length already: nothing to clear.
        let mut buf = self.spare.pop().unwrap_or_default();
        buf.resize(n, 0);
        fill(&mut buf);
        if self.drop_cycle {
            // Handed over too late for its launch time: the qdisc drops it; no wire time.
            self.wire_free_ps -= frame_wire_time_ps(n);
            self.launch_misses += 1;
            self.spare.push(buf);
            self.last = Exchange {
                sent_ps: tx_ps,
                received_ps: None,
            };
            if self.cycle_mode {
                self.frame_in_cycle += 1;
            }
            return Ok(at);
        }
        if let Some(c) = &mut self.capture {
            let _ = c.record(tx_ps, &buf);
        }
        let fate = match &mut self.faults {
            Some(f) => f.before_frame(&mut self.segment, &buf, tx_ps),
            None => FrameFate::default(),
        };
        let mut port = 0;
        let back = if fate.lost_out {
            None
        } else {
            if self.cycle_mode {
                self.mark_processed();
            }
            let out = self.segment.process(&mut buf, tx_ps);
            port = out.returned_port;
            out.returned_sof_ps.and_then(|t| {
                if let Some(c) = &mut self.capture {
                    let _ = c.record(t + frame_wire_time_ps(n), &buf);
                }
                (!fate.lost_back)
                    .then(|| t + frame_wire_time_ps(n) + self.rx_latency_ps + fate.extra_delay_ps)
            })
        };
        if let Some(tap) = &mut self.tap {
            let loss = match (fate.lost_out, back.is_some()) {
                (true, _) => TapLoss::Out,
                (false, true) => TapLoss::No,
                (false, false) => TapLoss::Back,
            };
            tap(&self.segment, &buf, tx_ps, loss);
        }
        match back {
            Some(t) => {
                if let Some(lag) = fate.copy_after_ps {
                    let copy = buf.clone();
                    self.arrive(t + lag, port, copy);
                }
                self.arrive(t, port, buf);
            }
            None => self.spare.push(buf),
        }
        self.last = Exchange {
            sent_ps: tx_ps,
            received_ps: back,
        };
        if self.cycle_mode {
            self.frame_in_cycle += 1;
        }
        Ok(at)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Never> {
        let deadline_ns = deadline.as_ns();
        if let Some(&(t_rx, port, _)) = self.inflight.front() {
            let rx_ns = self.master_clock.master_ns(t_rx);
            if rx_ns <= deadline_ns {
                let (_, _, mut reply) = self.inflight.pop_front().expect("a reply in flight");
                self.now_ps = t_rx;
                self.now_master_ns = Some(rx_ns);
                // The reply's buffer goes to the caller; the caller's is spare.
                std::mem::swap(buf, &mut reply);
                self.spare.push(reply);
                return Ok(Some(Received {
                    len: buf.len(),
                    received: MasterInstant::from_ns(rx_ns),
                    tx_stamp: self.cycle_tx_stamp_ns.map(MasterInstant::from_ns),
                    stamped: true,
                    truncated: false,
                    port,
                }));
            }
        }
        if deadline_ns > self.master_now_ns() {
            self.set_master_now(deadline_ns);
        }
        Ok(None)
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.delays = self.host.as_ref().map(|h| h.cycle(cycle));
        self.drop_cycle = self.delays.is_some_and(|d| d.dropped);
        self.cycle_tx_stamp_ns = None;
        self.cycle_mode = true;
        self.frame_in_cycle = 0;
        self.processed_in_cycle = 0;
        // Emptied, not zeroed: the words a cycle uses are zeroed as it marks them. The frames
        // of the drift compensation before the first cycle (thousands, in cycle mode) grew it
        // to hundreds of words, and zeroing them every cycle took a tenth of a comparison.
        self.processed_beyond.clear();
    }
}

/// The master's second port: whether it is there, and its wire.
#[derive(Debug, Clone, Copy, Default)]
struct SecondWire {
    enabled: bool,
    /// Busy with its last frame until then, ps.
    wire_free_ps: u64,
    /// When the last frame left the first port, ps: its copy leaves the second at once.
    last_tx_ps: u64,
}

impl SecondPort for SimTransport {
    /// The copy leaves the second port when the last frame left the first (a redundant
    /// master's NICs send both at once), after the second port's own last frame. No fault of
    /// a schedule touches it, and the segment's trace stays the first port's frame's (the
    /// ground truth of the cycle).
    fn send_secondary(&mut self, frame: &[u8], _at: MasterInstant) -> Result<(), Never> {
        if !self.second.enabled {
            return Ok(());
        }
        let n = frame.len();
        let tx_ps = self.second.last_tx_ps.max(self.second.wire_free_ps);
        self.second.wire_free_ps = tx_ps + frame_wire_time_ps(n);
        let mut buf = self.spare.pop().unwrap_or_default();
        buf.clear();
        buf.extend_from_slice(frame);
        let trace = self.segment.trace().clone();
        let out = self.segment.process_secondary(&mut buf, tx_ps);
        self.segment.restore_trace(trace);
        match out.returned_sof_ps {
            Some(t) => {
                let at = t + frame_wire_time_ps(n) + self.rx_latency_ps;
                self.arrive(at, out.returned_port, buf);
            }
            None => self.spare.push(buf),
        }
        Ok(())
    }
}

/// Error type for capture creation.
pub mod pcap_file_error {
    /// A pcap file could not be created.
    #[derive(Debug, thiserror::Error)]
    #[error("pcap capture: {0}")]
    pub struct Error(pub crate::pcap::CaptureError);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn master_clock_inverts() {
        let mut c = MasterClock::new(CrystalParams {
            ppm: -37.5,
            wander_ppm_per_sqrt_s: 0.1,
            wander_step_ps: 1_000_000_000,
            initial_local_ns: SIM_EPOCH_NS,
            seed: 3,
        });
        for k in 1..2_000u64 {
            let t = k * 7_777_777_777;
            let m = c.master_ns(t);
            let back = c.real_ps_at(m);
            assert!(back.abs_diff(t) <= 1_000, "{t} -> {m} -> {back}");
        }
        let m = c.master_ns(1_000_000_000_000);
        assert!((m - SIM_EPOCH_NS) < 1_000_000_000 && (m - SIM_EPOCH_NS) > 999_900_000);
    }
}
