//! The cyclic phase: one frame per cycle carrying the reference's system time (FRMW of 0x0910,
//! preceded for bus shift by the master's time written to the reference), the process data
//! (LRW) and the system time difference of the slaves (BRD of 0x092C, as the letter reads it),
//! and a [`MasterSync`] method deciding when the next cycle starts.
//!
//! Sans-IO and allocation-free per cycle: the driver asks [`CyclicEngine::scheduled_start`]
//! when to wake, timestamps right before sending, takes the frame from
//! [`CyclicEngine::frame_to_send`], and hands the reply (or its loss) to
//! [`CyclicEngine::complete`]. The same engine runs against the virtual segment and on a raw
//! socket.

use crate::io::MASTER_MAC;
use crate::network::{Network, ReferenceReading};
use crate::pdi::LrwChunk;
use ecsync_dc::sync::{
    ControllerLog, CycleInput, CycleOutput, MasterSync, ReferenceWrite, WriteTimes,
    reference_time_from_read,
};
use ecsync_dc::time::{MasterDuration, MasterInstant, SystemTime};
use ecsync_wire::dc_time::diff_u64;
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DATAGRAM_HEADER_LEN, DatagramAddress, FrameBuilder, WireError};

/// The master time at which the cyclic phase's first cycle starts: its frame, sent `lead`
/// after the cycle's start (the host's execution time, as far as the master knows it), passes
/// the reference at a point of the reference's grid (the multiples of the period in its system
/// time, on which SYNC0 fires) plus `target_phase_ns`: the second grid point after `now`
/// (more than one period and at most two after it, before the target and the lead).
///
/// `reading` is where the bring-up last read the reference's time
/// ([`Network::reference_reading`](crate::network::Network)): the offsets made the reference's
/// time the master's, but its crystal has run against the master's since. A method that writes
/// the master's time into the reference (`write` is [`ReferenceWrite::SystemTime`], the
/// letter's bus shift) brings the reference's time back to the master's, so its frames aim at
/// the master's grid; every other method aims at the reference's grid where it stands.
pub fn first_cycle_start(
    now: MasterInstant,
    reading: Option<ReferenceReading>,
    write: ReferenceWrite,
    period_ns: u32,
    target_phase_ns: i64,
    lead: MasterDuration,
) -> MasterInstant {
    let (now_ns, lead_ns) = (now.as_ns(), lead.as_ns());
    let p = u64::from(period_ns.max(1));
    let d = match (reading, write) {
        (Some(r), ReferenceWrite::None | ReferenceWrite::OffsetAdjust) => {
            r.reference_minus_master_ns() as u64
        }
        (None, _) | (_, ReferenceWrite::SystemTime) => 0,
    };
    let reference_now = now_ns.wrapping_add(d);
    MasterInstant::from_ns(
        (reference_now / p + 2)
            .wrapping_mul(p)
            .wrapping_add(target_phase_ns as u64)
            .wrapping_sub(d)
            .wrapping_sub(lead_ns),
    )
}

/// How the cyclic frame is laid out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CyclicConfig {
    /// Cycle time and SYNC0 period, ns.
    pub period_ns: u32,
    /// Station address of the reference clock.
    pub reference_station: u16,
    /// Bytes of process data (LRW at logical address 0); 0 for none.
    pub pdi_len: u32,
    /// Frames averaged at the start for the measurement offset `h_mr` of the letter's M-rS
    /// error (eq. 5-7); the methods keep their own.
    pub measure_init_frames: u64,
    /// The System Time Offset (0x0920) the bring-up wrote to the reference: a method that
    /// adjusts the offset ([`ReferenceWrite::OffsetAdjust`]) writes this plus its adjustment.
    pub reference_offset_ns: u64,
    /// The process image's LRWs ([`crate::network::Network::lrw`]); empty: one LRW of
    /// `pdi_len` bytes at logical address 0.
    pub lrw: Vec<LrwChunk>,
}

impl CyclicConfig {
    /// The cyclic frames' layout for `net` as its bring-up left it (its reference's station
    /// and offset, its process data's datagrams); `None` without a reference.
    pub fn for_network(net: &Network, period_ns: u32, measure_init_frames: u64) -> Option<Self> {
        let reference = net.slaves.get(usize::from(net.reference))?;
        Some(CyclicConfig {
            period_ns,
            reference_station: reference.station,
            pdi_len: net.pdi_len,
            measure_init_frames,
            reference_offset_ns: reference.offset.unwrap_or(0),
            lrw: net.lrw.clone(),
        })
    }
}

/// Everything one cycle produced.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleRecord {
    /// Cycle index.
    pub cycle: u64,
    /// `t_mt`: scheduled start.
    pub scheduled: MasterInstant,
    /// `t_ms`: send timestamp.
    pub send: MasterInstant,
    /// Reply arrival (`None`: lost).
    pub receive: Option<MasterInstant>,
    /// `t_ra`: the reference's system time from the FRMW, 64-bit.
    pub ref_time: Option<SystemTime>,
    /// The BRD of 0x092C as returned (the OR of every slave's register).
    pub brd_092c_raw: Option<u32>,
    /// Its magnitude (bits 30:0), ns: the letter's rS-IS error.
    pub rs_is_ns: Option<u32>,
    /// LRW working counter.
    pub lrw_wkc: Option<u16>,
    /// The letter's M-rS error, ns: φ (eq. 10) for master shift once `h_mr` is known,
    /// `t_ra - t_ms` for bus shift.
    pub m_rs_ns: Option<i64>,
    /// The method's decision.
    pub output: CycleOutput,
    /// The method's log after it decided (methods that keep one, DCM).
    pub log: Option<ControllerLog>,
    /// The reference's time was not believed this cycle (missing or jumped): the method held
    /// over and no slave was handed a time.
    pub reference_held: bool,
}

/// One frame of the cyclic exchange: its template and where its datagrams' fields are.
#[derive(Debug, Clone, Default)]
struct FramePlan {
    template: Vec<u8>,
    /// The first datagram's command and index.
    id: Option<(u8, u8)>,
    bus_write_at: Option<usize>,
    frmw_data_at: Option<usize>,
    /// Working counter offsets of its LRWs.
    lrw_wkc_at: Vec<usize>,
    brd_data_at: Option<usize>,
}

/// The cyclic engine.
#[derive(Debug, Clone)]
pub struct CyclicEngine<S> {
    sync: S,
    cfg: CyclicConfig,
    plans: Vec<FramePlan>,
    frames: Vec<Vec<u8>>,
    cycle: u64,
    first_start_ns: u64,
    scheduled_ns: u64,
    last_ref_ns: Option<u64>,
    /// The cycle `last_ref_ns` was read in.
    last_ref_cycle: u64,
    /// The send timestamp of the cycle `last_ref_ns` was read in.
    last_ref_send_ns: u64,
    /// That cycle's round trip (send to reply), master time, ns.
    last_ref_round_trip_ns: u64,
    /// The reference's last reading had no upper half: a 32-bit DC unit, whose time is the
    /// master's written time modulo 2^32 under bus shift.
    reference_32bit: bool,
    /// A reference time not believed and the cycle it came in: a new timeline if it goes on.
    candidate: Option<(u64, u64)>,
    /// The send timestamp of the candidate's cycle.
    candidate_send_ns: u64,
    h_sum: i128,
    h_n: u64,
    h_mr: f64,
    health: Health,
    /// A step of the master's clock seen in one cycle, ns, waiting for the next reference time
    /// to confirm it (a frame held up on the way looks like one for a cycle).
    pending_step_ns: Option<i64>,
}

/// What the engine makes of the replies beyond the method's inputs: whether the reference's
/// time can be believed and distributed, and whether slaves have lost their configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Health {
    /// The LRWs' working counter every cycle should return (0: not checked).
    pub expected_lrw_wkc: u16,
    /// The reference's time is not believed (it did not answer, or it jumped): the method
    /// holds over and the FRMW is sent as an FPRD, so that no slave takes a wrong time.
    pub reference_held: bool,
    /// Cycles in a row whose LRW working counter came back short.
    pub short_wkc_cycles: u32,
    /// Cycles in a row whose |0x092C| was beyond [`FAR_092C_NS`].
    pub far_092c_cycles: u32,
    /// Times the reference's time jumped (a reset, a step).
    pub reference_jumps: u32,
    /// Cycles the reference did not answer in (FRMW working counter 0).
    pub reference_missing_cycles: u64,
    /// Cycles in a row whose frame with the reference's time was lost.
    pub reference_lost_cycles: u32,
    /// Steps of the master's own clock seen (the reference ran on while the master's time
    /// between two cycles jumped), and the last one's size, ns (positive: forward).
    pub master_clock_steps: u32,
    /// The last step of the master's clock, ns.
    pub last_master_step_ns: i64,
    /// The master's clock steps taken out so far, ns: the engine and its method run on the
    /// master's clock minus this, the timeline it had before (the schedule the task sleeps to
    /// and the reported timestamps stay the clock's own).
    pub master_clock_correction_ns: i64,
    /// Cycles whose method asked for the next start less than nothing or more than two
    /// periods after this one's (an unstable controller): the start was held to that range,
    /// as a task's timer can be, and the method saw what was done.
    pub wild_schedule_cycles: u64,
    /// Slaves seem to have lost their configuration: a recovery should run.
    pub needs_recovery: bool,
    /// Slaves answer that the bring-up did not take in (hot-connected): their |0x092C| is not
    /// the network's.
    pub unmanaged_slaves: bool,
    /// A recovery is configuring slaves (the driver says so): a method that adjusts the
    /// reference's offset holds its writes, which would undo the recovery's new offset.
    pub recovery_running: bool,
}

/// What the engine makes of a reference time that came back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Belief {
    /// On the reference's timeline (or a new one taken): used, and the base the next times are
    /// compared with.
    Anchor,
    /// Used by the method, but off the timeline (a bus-shift method's write that reached the
    /// reference late): not a base for the next comparisons.
    Used,
    /// Not believed: held over.
    Rejected,
}

/// |0x092C| beyond this is no slave's lock (a reset slave's register saturates), ns.
pub const FAR_092C_NS: u32 = 1_000_000;
/// A reference time this far from its extrapolation is a jump, ns (plus 200 ppm of the time
/// since the last one believed).
pub const REFERENCE_JUMP_NS: u64 = 100_000;
/// Cycles in a row without the reference that may have been a power cycle (a bus-shift
/// method's reference is then looked at by a recovery before it is believed again).
pub const OUTAGE_CYCLES: u32 = 5;
/// Cycles a new timeline of the reference must run on by itself before it is taken.
pub const ADOPT_CYCLES: u64 = 20;
/// Cycles in a row of a short working counter or a far |0x092C| before a recovery is asked.
pub const SUSPECT_CYCLES: u32 = 3;

/// Builds the frames: a bus-shift write and the FRMW first, then the LRWs in as many frames as
/// they need, the BRD of 0x092C last (the same single frame as always when everything fits).
fn plan_frames(cfg: &CyclicConfig, bus_register: Option<u16>) -> Result<Vec<FramePlan>, WireError> {
    let room = crate::pdi::FRAME_PAYLOAD;
    let over = ecsync_wire::DATAGRAM_OVERHEAD;
    let chunks: Vec<LrwChunk> = if !cfg.lrw.is_empty() {
        cfg.lrw.clone()
    } else if cfg.pdi_len > 0 {
        vec![LrwChunk {
            logical: 0,
            len: cfg.pdi_len,
            expected_wkc: 0,
        }]
    } else {
        Vec::new()
    };
    let system_time = DatagramAddress::Configured {
        adp: cfg.reference_station,
        ado: reg::DC_SYSTEM_TIME,
    };
    let mut plans = Vec::new();
    let mut buf = vec![0u8; ecsync_wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC)?;
    let mut used = 0usize;
    let mut plan = FramePlan::default();
    // A bus-shift method's write to the reference goes first, so that the same frame's FRMW
    // already reads (and distributes) the reference's time it set.
    if let Some(ado) = bus_register {
        let at = DatagramAddress::Configured {
            adp: cfg.reference_station,
            ado,
        };
        plan.bus_write_at = Some(b.push_zeroed(Command::Fpwr, 0, at, 8)? + DATAGRAM_HEADER_LEN);
        used += over + 8;
    }
    plan.frmw_data_at =
        Some(b.push_zeroed(Command::Frmw, 1, system_time, 8)? + DATAGRAM_HEADER_LEN);
    used += over + 8;
    let time_difference = DatagramAddress::Position {
        adp: 0,
        ado: reg::DC_SYSTEM_TIME_DIFF,
    };
    // When the image takes several frames, the BRD of the time difference goes into the first
    // one with the FRMW: every slave then acts in the first frame only, and in the others only
    // where they carry its process data (the simulator passes a frame by the slaves it does
    // nothing at). A cycle of one frame keeps the old order: FRMW, LRW, BRD.
    let one_frame =
        used + chunks.iter().map(|c| over + c.len as usize).sum::<usize>() + over + 4 <= room;
    let mut index = 2u8;
    if !one_frame {
        plan.brd_data_at =
            Some(b.push_zeroed(Command::Brd, index, time_difference, 4)? + DATAGRAM_HEADER_LEN);
        used += over + 4;
        index += 1;
    }
    for c in &chunks {
        let need = over + c.len as usize;
        if used + need > room {
            let n = b.finish();
            plan.template = buf[..n].to_vec();
            plans.push(std::mem::take(&mut plan));
            b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC)?;
            used = 0;
        }
        let at = b.push_zeroed(
            Command::Lrw,
            index,
            DatagramAddress::Logical(c.logical),
            c.len as usize,
        )?;
        plan.lrw_wkc_at
            .push(at + DATAGRAM_HEADER_LEN + c.len as usize);
        index = index.wrapping_add(1);
        used += need;
    }
    if one_frame {
        // The BRD's index follows the LRWs' (3 in the single frame of old).
        let brd_index = if chunks.len() <= 1 { 3 } else { index };
        plan.brd_data_at =
            Some(b.push_zeroed(Command::Brd, brd_index, time_difference, 4)? + DATAGRAM_HEADER_LEN);
    }
    let n = b.finish();
    plan.template = buf[..n].to_vec();
    plans.push(plan);
    Ok(plans)
}

/// The lengths of the frames a cycle sends, bytes, as [`CyclicEngine::new`] plans them
/// (`bus_shift`: with a bus-shift method's 8-byte write to the reference in the first frame):
/// how long a cycle's frames take on the wire is known before any engine runs.
pub fn cycle_frame_lens(cfg: &CyclicConfig, bus_shift: bool) -> Result<Vec<usize>, WireError> {
    let bus_register = bus_shift.then_some(reg::DC_SYSTEM_TIME);
    Ok(plan_frames(cfg, bus_register)?
        .iter()
        .map(|p| p.template.len())
        .collect())
}

impl<S: MasterSync> CyclicEngine<S> {
    /// An engine whose first cycle starts at `first_start`.
    pub fn new(sync: S, cfg: CyclicConfig, first_start: MasterInstant) -> Result<Self, WireError> {
        let first_start_ns = first_start.as_ns();
        let bus_register = match sync.reference_write_kind() {
            ReferenceWrite::None => None,
            ReferenceWrite::SystemTime => Some(reg::DC_SYSTEM_TIME),
            ReferenceWrite::OffsetAdjust => Some(reg::DC_SYSTEM_TIME_OFFSET),
        };
        let mut plans = plan_frames(&cfg, bus_register)?;
        for p in &mut plans {
            p.id = ecsync_wire::EcatFrame::new_checked(&p.template[..])?.first_datagram_id();
        }
        let frames = plans.iter().map(|p| p.template.clone()).collect();
        let cfg_expected_wkc = cfg
            .lrw
            .iter()
            .fold(0u16, |a, c| a.wrapping_add(c.expected_wkc));
        Ok(CyclicEngine {
            sync,
            cfg,
            plans,
            frames,
            cycle: 0,
            first_start_ns,
            scheduled_ns: first_start_ns,
            last_ref_ns: None,
            last_ref_cycle: 0,
            last_ref_send_ns: 0,
            last_ref_round_trip_ns: 0,
            reference_32bit: false,
            candidate: None,
            candidate_send_ns: 0,
            h_sum: 0,
            h_n: 0,
            h_mr: 0.0,
            health: Health {
                expected_lrw_wkc: cfg_expected_wkc,
                ..Health::default()
            },
            pending_step_ns: None,
        })
    }

    /// What the engine made of the replies so far.
    pub fn health(&self) -> &Health {
        &self.health
    }

    /// The reference's System Time Offset was written anew (a recovery of the reset
    /// reference): a method that adjusts the offset adjusts this one from now on.
    pub fn set_reference_offset(&mut self, offset_ns: u64) {
        // The new offset continues the timeline the method's adjustments had made: they are in
        // it already, so the base the adjustments go onto is the offset minus the adjustment
        // so far (the next write then writes the offset as the recovery did, not the
        // adjustment twice).
        let adjusted = match self.sync.reference_write_kind() {
            ReferenceWrite::OffsetAdjust => self
                .sync
                .reference_write(WriteTimes::default())
                .unwrap_or(0),
            _ => 0,
        };
        self.cfg.reference_offset_ns = offset_ns.wrapping_sub(adjusted);
    }

    /// Slaves answer that the bring-up did not take in (a recovery counted them): their
    /// |0x092C| no longer asks for recoveries.
    pub fn unmanaged_slaves_answer(&mut self) {
        self.health.unmanaged_slaves = true;
    }

    /// Whether a recovery is running now (the driver tells the engine before each cycle).
    pub fn set_recovery_running(&mut self, running: bool) {
        self.health.recovery_running = running;
    }

    /// A recovery brought slaves back (or found none to bring back): the counts start again.
    pub fn recovered(&mut self) {
        if self.sync.reference_write_kind() == ReferenceWrite::SystemTime {
            // The reference is set up again (or was fine): the master's writes make its time.
            self.health.reference_held = false;
        }
        self.health.needs_recovery = false;
        self.health.short_wkc_cycles = 0;
        self.health.far_092c_cycles = 0;
    }

    /// The method.
    pub fn sync(&self) -> &S {
        &self.sync
    }

    /// The configuration.
    pub fn config(&self) -> &CyclicConfig {
        &self.cfg
    }

    /// When the current cycle is scheduled to start (wake the task then).
    pub fn scheduled_start(&self) -> MasterInstant {
        MasterInstant::from_ns(self.scheduled_ns)
    }

    /// The cycle about to run.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Frames per cycle: one, unless the process image needs more.
    pub fn frame_count(&self) -> usize {
        self.plans.len()
    }

    /// Length of the cyclic frame (the first), bytes.
    pub fn frame_len(&self) -> usize {
        self.plans[0].template.len()
    }

    /// Offsets of the working counters of frame `k`'s LRWs.
    pub fn lrw_wkc_offsets(&self, k: usize) -> &[usize] {
        &self.plans[k].lrw_wkc_at
    }

    /// Length of frame `k`, bytes.
    pub fn frame_len_of(&self, k: usize) -> usize {
        self.plans[k].template.len()
    }

    /// The frame in which the process image's byte `logical` travels (`None`: no LRW holds
    /// it).
    pub fn frame_of_logical(&self, logical: u32) -> Option<usize> {
        let mut k = 0;
        let chunks = if self.cfg.lrw.is_empty() {
            return (self.cfg.pdi_len > logical).then_some(0);
        } else {
            &self.cfg.lrw
        };
        for (f, plan) in self.plans.iter().enumerate() {
            for _ in &plan.lrw_wkc_at {
                let c = chunks[k];
                if logical >= c.logical && logical < c.logical + c.len {
                    return Some(f);
                }
                k += 1;
            }
        }
        None
    }

    /// The frame as last handed out by [`CyclicEngine::frame_to_send`] (what a reply must
    /// answer).
    pub fn frame(&self) -> &[u8] {
        &self.frames[0]
    }

    /// The tag of frame `k` of cycle `cycle`: the index its first datagram carries. It changes
    /// from frame to frame and cycle to cycle (modulo 256), so that a reply names the cycle it
    /// answers: a late reply of an earlier cycle, or a second copy of one, is told from the
    /// one awaited (SOEM and ethercrab number their frames the same way).
    pub fn tag_of(&self, cycle: u64, k: usize) -> u8 {
        cycle
            .wrapping_mul(self.plans.len() as u64)
            .wrapping_add(k as u64) as u8
    }

    /// Which frame of which of the last cycles a reply with first datagram `id` answers:
    /// `Some((cycles_ago, k))` (0: the current cycle), looking back over the cycles whose tags
    /// are still unique; `None` if none of them sent it (another master's frame, noise).
    pub fn match_tag(&self, id: (u8, u8)) -> Option<(u64, usize)> {
        let n = self.plans.len() as u64;
        let window = (256 / n.max(1)).max(1);
        (0..window.min(self.cycle + 1)).find_map(|ago| {
            let cycle = self.cycle - ago;
            (0..self.plans.len()).find_map(|k| {
                let (cmd, _) = self.plans[k].id?;
                // An FRMW (or an offset adjustment's FPWR) first goes out as an FPRD while
                // the reference is held.
                let held_cmd = (cmd == Command::Frmw.code() || cmd == Command::Fpwr.code())
                    .then_some(Command::Fprd.code());
                let tag = self.tag_of(cycle, k);
                (id == (cmd, tag) || Some(id) == held_cmd.map(|c| (c, tag))).then_some((ago, k))
            })
        })
    }

    /// Skips `cycles` whole cycles without a frame: the task woke so late that their slots had
    /// passed (a host stall). The schedule moves on by whole periods, so every method keeps its
    /// phase to the grid; sending the missed frames back to back instead would put several
    /// frames into one SYNC0 period and feed the method instants it never chose.
    pub fn skip_cycles(&mut self, cycles: u64) {
        let span = cycles.wrapping_mul(u64::from(self.cfg.period_ns));
        self.cycle = self.cycle.wrapping_add(cycles);
        self.scheduled_ns = self.scheduled_ns.wrapping_add(span);
        // The reference time expected next, for extending a 32-bit reference, moves on too
        // (and with it the cycle and send it stands for, which the jump check reckons from).
        self.last_ref_ns = self.last_ref_ns.map(|t| t.wrapping_add(span));
        self.last_ref_cycle = self.last_ref_cycle.wrapping_add(cycles);
        self.last_ref_send_ns = self.last_ref_send_ns.wrapping_add(span);
        if let Some((t, at)) = self.candidate {
            self.candidate = Some((t.wrapping_add(span), at.wrapping_add(cycles)));
            self.candidate_send_ns = self.candidate_send_ns.wrapping_add(span);
        }
    }

    /// The (first) frame to send now; `send` is the timestamp taken right before sending
    /// (bus shift writes it to the reference).
    pub fn frame_to_send(&mut self, send: MasterInstant) -> &mut [u8] {
        self.frame_to_send_of(0, send)
    }

    /// Frame `k` to send now (the bus-shift write is in the first).
    pub fn frame_to_send_of(&mut self, k: usize, send: MasterInstant) -> &mut [u8] {
        let mut frame = std::mem::take(&mut self.frames[k]);
        self.write_frame(k, send, &mut frame);
        self.frames[k] = frame;
        &mut self.frames[k]
    }

    /// Writes frame `k`, sent at `send`, into `out` ([`CyclicEngine::frame_len_of`] bytes):
    /// the cyclic driver builds it in the transport's buffer.
    pub fn write_frame(&mut self, k: usize, send: MasterInstant, out: &mut [u8]) {
        let tag = self.tag_of(self.cycle, k);
        let plan = &self.plans[k];
        out.copy_from_slice(&plan.template);
        // (The template is a valid frame: the views check only what they read.)
        ecsync_wire::EcatFrame::new_unchecked(&mut *out).set_first_datagram_index(tag);
        if self.health.reference_held
            && let Some(at) = plan.frmw_data_at
        {
            // Read the reference's time without handing it on: no slave takes a time that is
            // not believed.
            ecsync_wire::Datagram::new_unchecked(&mut out[at - DATAGRAM_HEADER_LEN..])
                .set_command(Command::Fprd);
        }
        // (A step of the master's clock is taken out: the reference keeps the timeline.)
        let send_ns = send
            .as_ns()
            .wrapping_sub(self.health.master_clock_correction_ns as u64);
        let kind = self.sync.reference_write_kind();
        let hold_write = match kind {
            ReferenceWrite::OffsetAdjust => {
                self.health.reference_held || self.health.recovery_running
            }
            ReferenceWrite::SystemTime => self.health.recovery_running,
            ReferenceWrite::None => false,
        };
        let Some(at) = plan.bus_write_at else {
            return;
        };
        // The reference's offset is not adjusted while its time is not believed or a recovery
        // may be writing it anew (an adjustment of the old offset would throw a reset
        // reference onto a timeline of its own), and the master's time is not written into it
        // while a recovery waits for the slaves' |0x092C| to settle (the reference's own would
        // be the master's jitter, which never does): the reference holds over. A method that
        // writes only some cycles holds it over in the others.
        let scheduled_ns = self
            .scheduled_ns
            .wrapping_sub(self.health.master_clock_correction_ns as u64);
        let value = if hold_write {
            None
        } else {
            self.sync.reference_write(WriteTimes {
                scheduled: MasterInstant::from_ns(scheduled_ns),
                send: MasterInstant::from_ns(send_ns),
            })
        };
        match value {
            Some(v) => {
                let v = match kind {
                    ReferenceWrite::OffsetAdjust => self.cfg.reference_offset_ns.wrapping_add(v),
                    _ => v,
                };
                out[at..at + 8].copy_from_slice(&v.to_le_bytes());
            }
            // The write becomes a read.
            None => ecsync_wire::Datagram::new_unchecked(&mut out[at - DATAGRAM_HEADER_LEN..])
                .set_command(Command::Fprd),
        }
    }

    /// Completes a cycle of one frame with its reply (`None` if the frame was lost).
    pub fn complete(
        &mut self,
        reply: Option<&[u8]>,
        send: MasterInstant,
        receive: MasterInstant,
    ) -> CycleRecord {
        self.complete_frames(&[reply], send, receive)
    }

    /// Completes the cycle with the replies of its frames in order (`None` for a lost one):
    /// reads the reference time, the system time difference and the working counters, runs the
    /// method and schedules the next cycle. `send` is the first frame's send timestamp.
    pub fn complete_frames(
        &mut self,
        replies: &[Option<&[u8]>],
        send: MasterInstant,
        receive: MasterInstant,
    ) -> CycleRecord {
        self.complete_by(|k| replies.get(k).copied().flatten(), send, receive)
    }

    /// [`CyclicEngine::complete_frames`] with frame `k`'s reply from `reply(k)` (no list to
    /// build per cycle).
    pub fn complete_by<'r>(
        &mut self,
        reply: impl Fn(usize) -> Option<&'r [u8]>,
        send: MasterInstant,
        receive: MasterInstant,
    ) -> CycleRecord {
        let (send_ns, receive_ns) = (send.as_ns(), receive.as_ns());
        let mut rec = CycleRecord {
            cycle: self.cycle,
            scheduled: MasterInstant::from_ns(self.scheduled_ns),
            send: MasterInstant::from_ns(send_ns),
            ..CycleRecord::default()
        };
        // The engine runs on the master's clock with its steps taken out (the correction as
        // it was when this cycle was planned, and as it is once the replies are read).
        let planned_correction = self.health.master_clock_correction_ns;
        let (raw_send_ns, raw_receive_ns) = (send_ns, receive_ns);
        let corrected = |raw: u64, c: i64| raw.wrapping_sub(c as u64);
        let mut all = true;
        let mut lrw_wkc: Option<u16> = Some(0);
        // (Out of `self` while the replies are read: reading the reference's time updates the
        // engine's health.)
        let plans = std::mem::take(&mut self.plans);
        for (k, plan) in plans.iter().enumerate() {
            let n = plan.template.len();
            let Some(r) = reply(k).filter(|r| r.len() >= n) else {
                all = false;
                if plan.frmw_data_at.is_some() {
                    // Gone for more than a lost frame: the reference may come back reset, and
                    // its first answer must not reach the other slaves before it is believed.
                    self.health.reference_lost_cycles += 1;
                    if self.health.reference_lost_cycles >= 2 {
                        self.health.reference_held = true;
                    }
                }
                if !plan.lrw_wkc_at.is_empty() {
                    lrw_wkc = None;
                }
                continue;
            };
            if let Some(at) = plan.frmw_data_at {
                let outage = std::mem::take(&mut self.health.reference_lost_cycles);
                let frmw_wkc = r
                    .get(at - DATAGRAM_HEADER_LEN..)
                    .and_then(|d| ecsync_wire::Datagram::new_checked(d).ok())
                    .map_or(0, |d| d.wkc());
                if frmw_wkc > 0 {
                    let raw = u64::from_le_bytes(r[at..at + 8].try_into().unwrap_or([0; 8]));
                    self.reference_32bit = raw >> 32 == 0;
                    // A 32-bit reference reads 0 in the upper half: extend next to the
                    // expectation, the first reading next to the master's time (where the
                    // bring-up extended it and put SYNC0's grid).
                    let estimate = self.last_ref_ns.map_or(raw_send_ns, |prev| {
                        prev.wrapping_add(u64::from(self.cfg.period_ns))
                    });
                    let t = reference_time_from_read(estimate, raw);
                    let send_ns = corrected(raw_send_ns, self.health.master_clock_correction_ns);
                    let round_trip_ns = raw_receive_ns.wrapping_sub(raw_send_ns);
                    let belief = self.believe_reference(t, send_ns, round_trip_ns, outage);
                    if belief != Belief::Rejected {
                        rec.ref_time = Some(SystemTime::from_ns(t));
                    }
                    if belief == Belief::Anchor {
                        self.last_ref_ns = Some(t);
                        self.last_ref_cycle = self.cycle;
                        self.last_ref_send_ns =
                            corrected(raw_send_ns, self.health.master_clock_correction_ns);
                        self.last_ref_round_trip_ns = round_trip_ns;
                    }
                } else {
                    // The reference is gone (off, cut off): hold over, and hand nothing on
                    // until its time is believed again.
                    self.health.reference_missing_cycles += 1;
                    self.health.reference_held = true;
                }
            }
            if let Some(b) = plan.brd_data_at {
                let raw = u32::from_le_bytes(r[b..b + 4].try_into().unwrap_or([0; 4]));
                rec.brd_092c_raw = Some(raw);
                rec.rs_is_ns = Some(raw & 0x7fff_ffff);
            }
            for &w in &plan.lrw_wkc_at {
                lrw_wkc = lrw_wkc.map(|s| s.wrapping_add(u16::from_le_bytes([r[w], r[w + 1]])));
            }
        }
        if all {
            self.check_slaves(lrw_wkc, rec.rs_is_ns);
        }
        rec.reference_held = self.health.reference_held;
        // Received when every frame came back (a cycle with a lost frame is a lost cycle).
        rec.receive = all.then_some(MasterInstant::from_ns(receive_ns));
        self.plans = plans;
        if self.plans.iter().all(|p| p.lrw_wkc_at.is_empty()) {
            lrw_wkc = None;
        }
        rec.lrw_wkc = if all { lrw_wkc } else { None };
        let correction = self.health.master_clock_correction_ns;
        let send_ns = corrected(raw_send_ns, correction);
        let receive_ns = corrected(raw_receive_ns, correction);
        let nominal = self
            .first_start_ns
            .wrapping_add(self.cycle.wrapping_mul(u64::from(self.cfg.period_ns)));
        let input = CycleInput {
            cycle: self.cycle,
            period_ns: self.cfg.period_ns,
            nominal_start: MasterInstant::from_ns(nominal),
            scheduled_start: MasterInstant::from_ns(corrected(
                self.scheduled_ns,
                planned_correction,
            )),
            send: MasterInstant::from_ns(send_ns),
            receive: MasterInstant::from_ns(receive_ns),
            ref_time: rec.ref_time,
        };
        rec.output = self.sync.update(&input);
        rec.log = self.sync.controller_log();
        // The letter's M-rS error (not in a cycle whose send the master's clock may have
        // stepped under: its time is not known until the next cycle says).
        if let Some(t_ra) = rec
            .ref_time
            .map(SystemTime::as_ns)
            .filter(|_| self.pending_step_ns.is_none())
        {
            rec.m_rs_ns = self.m_rs_ns(t_ra, send_ns, nominal);
        }
        let asked = rec
            .output
            .next_start
            .as_ns()
            .wrapping_add(correction as u64);
        self.scheduled_ns = self.held_to_range(asked);
        self.cycle += 1;
        rec
    }

    /// The next start a method asked for (`asked`, on the master's clock), held within two
    /// periods after the current cycle's start: a controller gone unstable would otherwise
    /// put the task to sleep for hours (or schedule a cycle before this one), and with it the
    /// network. The method sees the start it got in the next cycle's input.
    #[inline]
    fn held_to_range(&mut self, asked: u64) -> u64 {
        let two_periods = 2 * u64::from(self.cfg.period_ns);
        let step = asked.wrapping_sub(self.scheduled_ns);
        if step <= two_periods {
            return asked;
        }
        self.health.wild_schedule_cycles += 1;
        // Back in time (a wrapped difference) holds to this start, forward to two periods.
        if (step as i64) < 0 {
            self.scheduled_ns
        } else {
            self.scheduled_ns.wrapping_add(two_periods)
        }
    }

    /// The letter's M-rS error of this cycle, ns, from the reference's time `t_ra` and the
    /// send timestamp (step-corrected): for master shift φ once `h_mr` is known (during the
    /// init frames `h_mr` is averaged and there is none), `t_ra - t_ms` for bus shift.
    #[inline]
    fn m_rs_ns(&mut self, t_ra: u64, send_ns: u64, nominal: u64) -> Option<i64> {
        if !self.sync.is_master_shift() {
            // Bus shift writes the master's time into the reference; a 32-bit reference keeps
            // its lower half, so the two compare modulo 2^32 (the reference's time extended
            // from its first reading has none of the master's upper half).
            let d = diff_u64(t_ra, send_ns);
            return Some(if self.reference_32bit {
                i64::from(d as i32)
            } else {
                d
            });
        }
        if self.cycle < self.cfg.measure_init_frames {
            self.h_sum += i128::from(diff_u64(send_ns, t_ra));
            self.h_n += 1;
            self.h_mr = self.h_sum as f64 / self.h_n as f64;
            return None;
        }
        // φ = t_ra + h_mr - (t_ms + δ̂), δ̂ = nominal - scheduled: the correction applied to
        // this cycle. A phase error is one modulo P: a method that drops or doubles a cycle
        // (ethercrab's snap when a frame reaches the reference just before its grid point)
        // moves δ̂ by whole periods, which are not an error of the phase, so φ is wrapped into
        // [-P/2, P/2).
        let delta_hat = diff_u64(nominal, self.scheduled_ns) as f64;
        let phi = diff_u64(t_ra, send_ns) as f64 + self.h_mr - delta_hat;
        let p = f64::from(self.cfg.period_ns.max(1));
        let wrapped = if phi.abs() < p / 2.0 {
            phi
        } else {
            phi - p * ((phi + p / 2.0) / p).floor()
        };
        Some(ecsync_dc::offset::round_ns(wrapped))
    }

    /// Whether the reference's time `t` continues its timeline: within [`REFERENCE_JUMP_NS`]
    /// (and 200 ppm of the time since) of the last time believed, moved on by the cycles
    /// since. A jump (the reference reset, its offset rewritten) holds the time until one
    /// continues the old timeline again (a recovery sets the reset reference's offset so).
    fn believe_reference(
        &mut self,
        t: u64,
        send_ns: u64,
        round_trip_ns: u64,
        outage: u32,
    ) -> Belief {
        // A method that writes the master's time into the reference every cycle (bus shift)
        // makes the reference's timeline itself: a jump is its own write (a frame held by a
        // bridge delivers an old time), and a reset reference takes the master's time again
        // with the next write.
        let writes_time = self.sync.reference_write_kind() == ReferenceWrite::SystemTime;
        if writes_time && self.health.reference_held {
            if outage >= OUTAGE_CYCLES || self.health.needs_recovery {
                // Back after it was gone a while: it may have been reset, and a reset
                // reference keeps its own time however the master writes it (the writes steer
                // its rate only) until a recovery has looked.
                self.health.needs_recovery = true;
                return Belief::Rejected;
            }
            // A few frames lost: nothing to look at.
            self.health.reference_held = false;
        }
        let Some(prev) = self.last_ref_ns else {
            self.health.reference_held = false;
            return Belief::Anchor;
        };
        // Moved on by the cycles since, or by the master's time between the sends (a method
        // that drops or doubles a cycle sends a period early or late; a master whose own
        // clock stepped sends on the cycles): either way the reference kept its timeline.
        let cycles = self.cycle.wrapping_sub(self.last_ref_cycle);
        let span = cycles.wrapping_mul(u64::from(self.cfg.period_ns));
        let sent_span = send_ns.wrapping_sub(self.last_ref_send_ns);
        let near = |span: u64| {
            t.abs_diff(prev.wrapping_add(span))
                <= REFERENCE_JUMP_NS + (span as i64).unsigned_abs() / 5_000
        };
        let mut ok = near(span) || near(sent_span);
        // Neither, but both alike while frames kept coming: the reference ran on and the
        // master's own clock stepped (its wake-up and its timestamps moved together). A
        // reference that jumps comes back after an outage (a reset slave loses its address
        // and answers nothing until a recovery), a master's step does not: a step is looked
        // for only in a reference time a few cycles after the last one believed. A frame held up on its way to the
        // reference (a bridge's closed gate) reads a later time too, but comes back later by
        // as much: a step leaves the round trip as it was.
        let both_alike =
            (sent_span as i64).wrapping_sub(span as i64).unsigned_abs() <= REFERENCE_JUMP_NS;
        let seen_step = (sent_span as i64).wrapping_sub(t.wrapping_sub(prev) as i64);
        let same_trip =
            round_trip_ns.abs_diff(self.last_ref_round_trip_ns) < seen_step.unsigned_abs() / 2;
        if ok {
            if let Some(step) = self.pending_step_ns.take() {
                // The reference runs on from the stepped cycle: the master's clock did step.
                // From now on it is taken out of everything the engine and the method see.
                self.health.master_clock_steps += 1;
                self.health.last_master_step_ns = step;
                self.health.master_clock_correction_ns =
                    self.health.master_clock_correction_ns.wrapping_add(step);
            }
        } else if cycles <= u64::from(OUTAGE_CYCLES) && both_alike && same_trip {
            let step = seen_step;
            match self.pending_step_ns.take() {
                // Back to the old relation: the last frame was held up on its way (a bridge),
                // the clock did not step.
                Some(p) if p.wrapping_add(step).unsigned_abs() <= REFERENCE_JUMP_NS => {}
                _ => self.pending_step_ns = Some(step),
            }
            ok = true;
        }
        if !ok {
            // A new timeline: taken once it runs on by itself for a while and no recovery is
            // wanted (a recovery that found no slave reset: the master's own time stepped
            // into a bus-shift method's writes).
            let period = u64::from(self.cfg.period_ns);
            let steady = self.candidate.is_some_and(|(c, at)| {
                let span = self.cycle.wrapping_sub(at).wrapping_mul(period);
                let sent_span = send_ns.wrapping_sub(self.candidate_send_ns);
                let near = |span: u64| {
                    t.abs_diff(c.wrapping_add(span))
                        <= REFERENCE_JUMP_NS + (span as i64).unsigned_abs() / 5_000
                };
                near(span) || near(sent_span)
            });
            match self.candidate {
                Some((_, at)) if steady => {
                    if self.cycle.wrapping_sub(at) >= ADOPT_CYCLES
                        && (writes_time || !self.health.needs_recovery)
                    {
                        ok = true;
                        self.candidate = None;
                    }
                }
                _ => {
                    self.candidate = Some((t, self.cycle));
                    self.candidate_send_ns = send_ns;
                }
            }
        } else {
            self.candidate = None;
        }
        if writes_time {
            // The method's own writes make the timeline: its time is used, and only the
            // master's step is looked for. A time off the timeline (the frame left late after
            // its timestamp, or was held up on its way: the write carried an old time) is no
            // base to look for a step from, until it runs on by itself: the next frame back
            // on the old timeline would look like a step of the master's clock.
            self.health.reference_held = false;
            return if ok { Belief::Anchor } else { Belief::Used };
        }
        if ok {
            self.health.reference_held = false;
        } else {
            if !self.health.reference_held {
                self.health.reference_jumps += 1;
            }
            if self.candidate.is_some_and(|(_, at)| at == self.cycle) {
                // The timeline changed (again): someone must look.
                self.health.needs_recovery = true;
            }
            self.health.reference_held = true;
        }
        if ok { Belief::Anchor } else { Belief::Rejected }
    }

    /// The working counter and |0x092C| of a cycle that came back: slaves that lost their
    /// configuration show as a short counter or a far difference, cycles in a row.
    fn check_slaves(&mut self, lrw_wkc: Option<u16>, rs_is_ns: Option<u32>) {
        let h = &mut self.health;
        let short = h.expected_lrw_wkc > 0 && lrw_wkc.is_some_and(|w| w < h.expected_lrw_wkc);
        h.short_wkc_cycles = if short { h.short_wkc_cycles + 1 } else { 0 };
        // (Not while slaves the master does not manage answer: a hot-connected slave's time
        // control loop takes the FRMW's time from far away, and the BRD ORs it in.)
        let far = rs_is_ns.is_some_and(|v| v >= FAR_092C_NS) && !h.unmanaged_slaves;
        h.far_092c_cycles = if far { h.far_092c_cycles + 1 } else { 0 };
        if h.short_wkc_cycles >= SUSPECT_CYCLES || h.far_092c_cycles >= SUSPECT_CYCLES {
            h.needs_recovery = true;
        }
    }
}

#[cfg(test)]
mod tests;
