//! One run of one method: bring the segment up, run the cyclic phase with the host's noise,
//! measure what the letter measures and what only the simulator knows.

use crate::scenario::Scenario;
use crate::stats::{Stats, Summary};
use ecsync_dc::Method;
use ecsync_dc::fit::LineFit;
use ecsync_dc::sync::MasterSync;
use ecsync_master::bringup::{BringupConfig, Network, Stage, bringup};
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{CycleReport, CyclicDriver, CyclicLimits};
use ecsync_master::{Engine, MasterError};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::fault::{Edge, Epoch, FaultCounts, FaultEvent, FaultKind, FaultPlayer, KindName};
use ecsync_sim::host::{CycleNoise, HostNoise, SharedNoise};
use ecsync_sim::rng::splitmix64;
use ecsync_sim::send::{Entry, SendMode, SendParams};
use ecsync_sim::transport::{HostDelays, HostModel, MasterClock, SIM_EPOCH_NS, SimTransport};
use ecsync_sim::{Segment, frame_wire_time_ps};
use serde::Serialize;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::sync::Arc;

/// A point of a time series: min and max of a quantity over a block of cycles, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Envelope {
    /// First cycle of the block.
    pub cycle: u64,
    /// Smallest value.
    pub min: f32,
    /// Largest value.
    pub max: f32,
}

/// Cycles per point of a run's time series (one min..max [`Envelope`] per block).
pub const SERIES_BLOCK: u64 = 1_000;

/// Min..max envelopes per block of [`SERIES_BLOCK`] cycles (the TSN run's series).
pub(crate) struct Series {
    out: Vec<Envelope>,
    cur: Option<Envelope>,
}

impl Series {
    pub(crate) fn new(cap: usize) -> Self {
        Series {
            out: Vec::with_capacity(cap),
            cur: None,
        }
    }

    pub(crate) fn add(&mut self, cycle: u64, x: f64) {
        let block = cycle / SERIES_BLOCK * SERIES_BLOCK;
        let x = x as f32;
        match &mut self.cur {
            Some(e) if e.cycle == block => {
                // Plain comparisons (no NaN handling: the errors recorded are never NaN).
                if x < e.min {
                    e.min = x;
                }
                if x > e.max {
                    e.max = x;
                }
            }
            _ => {
                if let Some(e) = self.cur.take() {
                    self.out.push(e);
                }
                self.cur = Some(Envelope {
                    cycle: block,
                    min: x,
                    max: x,
                });
            }
        }
    }

    pub(crate) fn finish(mut self) -> Vec<Envelope> {
        if let Some(e) = self.cur.take() {
            self.out.push(e);
        }
        self.out
    }
}

/// Points of a comparison's time series whatever the number of cycles: the output stays the
/// same size at a thousand cycles and at a billion.
pub const BAND_POINTS: u64 = 600;

/// A point of a time series of percentile bands: the block's extremes, its 1st, 50th and 99th
/// percentiles (exact, from the block's samples), ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Band {
    /// First cycle of the block.
    pub cycle: u64,
    /// Cycles in the block with a sample.
    pub n: u32,
    /// Smallest value.
    pub min: f32,
    /// 1st percentile.
    pub p01: f32,
    /// Median.
    pub p50: f32,
    /// 99th percentile.
    pub p99: f32,
    /// Largest value.
    pub max: f32,
}

/// Percentile bands over blocks of a fixed number of cycles.
#[derive(Debug, Clone)]
pub struct Bands {
    block: u64,
    start: u64,
    buf: Vec<f32>,
    out: Vec<Band>,
}

impl Bands {
    /// Bands for `cycles` recorded cycles, [`BAND_POINTS`] blocks at most.
    pub fn new(cycles: u64) -> Self {
        let block = cycles.div_ceil(BAND_POINTS).max(1);
        Bands {
            block,
            start: 0,
            buf: Vec::with_capacity(block.min(1 << 20) as usize),
            out: Vec::with_capacity(BAND_POINTS as usize + 1),
        }
    }

    /// Cycles per point.
    pub fn block_cycles(&self) -> u64 {
        self.block
    }

    /// Adds the value of recorded cycle `k` (cycles come in order).
    #[inline]
    pub fn add(&mut self, k: u64, x: f64) {
        if k >= self.start + self.block {
            self.flush();
            self.start = k / self.block * self.block;
        }
        self.buf.push(x as f32);
    }

    fn flush(&mut self) {
        let n = self.buf.len();
        if n == 0 {
            return;
        }
        let at = |q: f64| ((q * n as f64).ceil() as usize).clamp(1, n) - 1;
        let b = &mut self.buf;
        let (i50, i01, i99) = (at(0.5), at(0.01), at(0.99));
        let (lo, med, hi) = b.select_nth_unstable_by(i50, f32::total_cmp);
        let med = *med;
        let p01 = if i01 < i50 {
            *lo.select_nth_unstable_by(i01, f32::total_cmp).1
        } else {
            med
        };
        let min = lo.iter().copied().fold(med, f32::min);
        let p99 = if i99 > i50 {
            *hi.select_nth_unstable_by(i99 - i50 - 1, f32::total_cmp).1
        } else {
            med
        };
        let max = hi.iter().copied().fold(med, f32::max);
        self.out.push(Band {
            cycle: self.start,
            n: n as u32,
            min,
            p01,
            p50: med,
            p99,
            max,
        });
        self.buf.clear();
    }

    /// The points.
    pub fn finish(mut self) -> Vec<Band> {
        self.flush();
        self.out
    }
}

/// What one slave's frames did against its SYNC0.
#[derive(Debug, Clone)]
pub struct SlaveTruth {
    /// Auto-increment position.
    pub position: u16,
    /// SYNC0 minus the instant the frame's last bit (its outputs, checked by the FCS) passed
    /// the slave, ns.
    pub margin: Stats,
    /// The latest end of a frame at this slave after its grid point, ns: the smallest SYNC0
    /// shift this slave needs.
    pub latest_end_ns: f64,
    /// Cycles whose frame passed it after its SYNC0.
    pub late_frames: u64,
    /// SYNC0 pulses (grid point plus shift) with no frame's outputs at this slave since the
    /// pulse before: what a drive counts as "SM event missed" (ETG.1020, 0x1C32:0B). A late
    /// frame right after a late one is not one more: its outputs are the next pulse's, as far
    /// as any drive can tell. Counted between the measured frames.
    pub sync0_missed: u64,
    /// The system time (integer ns) the last measured frame's outputs passed this slave.
    pub last_outputs_ns: Option<u64>,
    /// The drive's own 0x1C32:0B count over the same frames (its counter after the last one
    /// minus after the first), if it runs on SYNC0 (set to DC mode over CoE).
    pub drive_sm_events_missed: Option<u64>,
    /// The drive's counter after the first measured frame.
    pub drive_count_at_start: Option<u64>,
}

/// The drift the frames underwent while a method averaged its init frames: the reference's
/// system time against the master's clock over those frames (least squares on the clocks'
/// truth).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InitDrift {
    /// Init frames.
    pub frames: u64,
    /// The phase's drift, ns per cycle (ppm when the cycle is 1 ms).
    pub drift_ns_per_cycle: f64,
    /// How far the init frames' mean phase lies from the first frame's, ns: where the
    /// letter's averaging puts its set point against where the frames were aimed.
    pub offset_ns: f64,
}

/// What a controller with a log reported (DCM).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ControllerTruth {
    /// Recorded cycles reported in sync.
    pub in_sync_cycles: u64,
    /// Times the controller left "in sync" during the recorded cycles.
    pub sync_losses: u64,
    /// The first cycle of the cyclic phase (warm-up included) reported in sync.
    pub first_in_sync_cycle: Option<u64>,
    /// Whether it was in sync at the last cycle.
    pub in_sync_at_end: bool,
    /// Recorded cycles whose error the filter did not use.
    pub invalid_errors: u64,
    /// The drift the controller had learnt at the end, ppm.
    pub drift_ppm_at_end: f64,
}

/// What one run of one method measured.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// Method (and its send mode, see [`Entry::name`]).
    pub method: String,
    /// How the host sent.
    pub send: SendMode,
    /// Frames dropped because they were handed over after their launch time (`txtime`).
    pub launch_misses: u64,
    /// CPU time the host spun before its sends over the recorded cycles, ns (`spin`).
    pub spin_ns: f64,
    /// Run index.
    pub run: u32,
    /// Recorded cycles run (fewer than the scenario's when interrupted).
    pub cycles_done: u64,
    /// The letter's M-rS error, ns.
    pub m_rs: Stats,
    /// The letter's rS-IS error (|BRD of 0x092C|), ns.
    pub rs_is: Stats,
    /// Truth: the frame's arrival at the reference against its DC grid point, ns (the target
    /// is the scenario's).
    pub phase: Stats,
    /// Truth: the phase minus the target, ns.
    pub phase_error: Stats,
    /// Truth: the largest |slave - reference| system time difference at the frame's pass, ns
    /// (every 8th cycle).
    pub slave_diff: Stats,
    /// Truth: the worst slave's SYNC0 margin each cycle, ns.
    pub margin: Stats,
    /// Truth per slave with a DC unit.
    pub per_slave: Vec<SlaveTruth>,
    /// Cycles whose frame reached some slave after its SYNC0 (margin < 0).
    pub late_frames: u64,
    /// The latest end of a frame at any slave after its grid point, ns: the smallest SYNC0
    /// shift without a late frame.
    pub latest_end_ns: f64,
    /// Frames lost.
    pub lost_frames: u64,
    /// Cycles whose LRW working counter was not the expected one.
    pub bad_wkc: u64,
    /// Time series of M-rS, rS-IS and the true phase.
    pub series: [Vec<Band>; 3],
    /// Cycles per series point.
    pub series_block: u64,
    /// Bring-up: DC lock time, ms.
    pub lock_ms: Option<f64>,
    /// The drift during the method's init frames (methods with init frames).
    pub init_drift: Option<InitDrift>,
    /// A controller's own report (methods with a log).
    pub controller: Option<ControllerTruth>,
    /// The cycle's frames on the wire, back to back, ns (one frame on a small network).
    pub frame_wire_ns: f64,
    /// The longest time from the frame's send timestamp to its reply, ns (late replies
    /// included).
    pub max_round_trip_ns: f64,
    /// Why `--samples` could not be written (the run went on).
    pub samples_error: Option<String>,
    /// What the fault schedule did and how the master took it (`None`: no faults).
    pub faults: Option<FaultsTruth>,
    /// The drives the master found out of OP with their configuration kept (an AL error of
    /// their own: a sync error past the configured 0x10F1:02, a process data watchdog), in
    /// the order its recoveries found them.
    pub left_op: Vec<LeftOpOut>,
}

/// A slave the master's recovery found out of OP with its configuration kept, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LeftOpOut {
    /// The run.
    pub run: u32,
    /// Network position, 1 = next to the master.
    pub slave: u16,
    /// The state it was in ("SAFE-OP").
    pub state: String,
    /// Its AL status code (0x0134; 0x001A: synchronization error), 0 without an error
    /// indication.
    pub al_status_code: u16,
    /// What the code means (`0x001a (synchronization error)`).
    pub reason: String,
    /// When the recovery that found it started, ms after the cyclic phase's start.
    pub found_ms: f64,
    /// When that recovery had it back in OP, ms after the cyclic phase's start (`None`: not
    /// by the end of the run).
    pub back_in_op_ms: Option<f64>,
}

/// The cycles around one fault: from its start to a second after its end.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultWindow {
    /// The fault's entry in the schedule, and its kind.
    pub fault: usize,
    /// Its kind.
    pub kind: KindName,
    /// When it started, real time, ps.
    pub start_ps: u64,
    /// Until when cycles are kept, real time, ps.
    pub until_ps: u64,
    /// Per cycle: ms since the start, |0x092C| (ns; NaN: lost), and whether the reference's
    /// time was held.
    pub points: Vec<(f32, f32, bool)>,
}

/// A second after a fault's end, the window of the report's plot closes.
const WINDOW_AFTER_PS: u64 = 1_000_000_000_000;

/// One recovery of a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecoveryOut {
    /// Start, ms after the cyclic phase's start.
    pub start_ms: f64,
    /// End, ms after the cyclic phase's start (`None`: still running at the end).
    pub end_ms: Option<f64>,
    /// Slaves configured again, network positions (1 = next to the master).
    pub slaves: Vec<u16>,
    /// Why it failed (it is tried again).
    pub error: Option<String>,
    /// Slaves that answered beyond the network as brought up (hot-connected): not taken in.
    pub appeared: u16,
    /// Slaves found out of OP with their configuration kept, and why (their AL status).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub left_op: Vec<String>,
}

/// A run's faults: what the schedule did, what the master saw, and how DC came back.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct FaultsTruth {
    /// Every fault's start and end, in order.
    pub events: Vec<FaultEvent>,
    /// What the player did to frames.
    pub counts: FaultCounts,
    /// Replies the driver discarded as late (after their cycle's deadline).
    pub late_replies: u64,
    /// Second copies of replies the driver discarded.
    pub duplicate_replies: u64,
    /// Cycles skipped by host stalls.
    pub skipped_cycles: u64,
    /// The recoveries the driver ran: start and end (master time after the cyclic phase's
    /// start, ms), the slaves brought back (network positions, 1 = next to the master) or
    /// why it failed.
    pub recoveries: Vec<RecoveryOut>,
    /// Cycles whose reference time the engine did not believe (missing or jumped): the
    /// method held over.
    pub held_cycles: u64,
    /// Steps of the master's clock the engine detected (the reference ran on while the
    /// master's time jumped), and the last one's size, ns.
    pub master_clock_steps: u32,
    /// The last detected step of the master's clock, ns (positive: forward).
    pub last_master_step_ns: i64,
    /// Cycles with a late frame (after some drive's SYNC0) inside a fault's window (its start
    /// to a second after its end), recorded cycles only.
    pub late_in_windows: u64,
    /// Cycles of the whole cyclic phase (warm-up included) whose frame did not come back.
    pub lost_cycles: u64,
    /// The largest |0x092C| of a cycle whose frame came back, ns: DC held where it reads
    /// under 100 ns.
    pub max_rs_is_ns: u32,
    /// The kind of the fault each of `relock_ms` is of.
    pub relock_kinds: Vec<KindName>,
    /// Per fault start: the cycles from it to a second after its end (for the report's plot;
    /// not in summary.json).
    #[serde(skip)]
    pub windows: Vec<FaultWindow>,
    /// Per fault, from the moment it was over (the end of a window: the slave on again, the
    /// cable in; else its start) to the first of 100 cycles that came back in a row locked and
    /// running (|0x092C| within `lock_band_092c_ns`, the method's M-rS within
    /// `lock_band_m_rs_ns` of its usual value, the reference's time believed, the LRW's working
    /// counter complete), ms (`None`: not by the end).
    pub relock_ms: Vec<Option<f64>>,
    /// The bound of |0x092C| for "locked", ns: 100, or twice the 99.9th percentile the method
    /// holds outside the faults' windows if that is more (the letter's bus shift writes the
    /// master's jitter into the reference: microseconds without any fault).
    pub lock_band_092c_ns: f64,
    /// The method's error band: M-rS within this of its median outside the faults' windows,
    /// ns (twice the 99.9th percentile of the distance, at least 1 us; `None`: no M-rS
    /// outside them, not judged).
    pub lock_band_m_rs_ns: Option<f64>,
    /// The usual M-rS the band is around (its median outside the faults' windows), ns.
    pub usual_m_rs_ns: Option<f64>,
}

/// One cycle of the cyclic phase as the re-lock is judged from it (kept with faults only).
#[derive(Debug, Clone, Copy)]
struct LockSample {
    sent_ps: u64,
    /// |0x092C|, ns (NaN: none).
    rs_is_ns: f32,
    /// M-rS, ns (NaN: none).
    m_rs_ns: f32,
    /// Came back, reference believed, working counter complete.
    running: bool,
}

/// The 99.9th percentile of `v` (sorted in place; `v` not empty).
fn p999(v: &mut [f32]) -> f64 {
    v.sort_unstable_by(f32::total_cmp);
    let at = ((v.len() - 1) as f64 * 0.999).round() as usize;
    f64::from(v[at])
}

/// Cycles outside the faults' windows that make a band (fewer: the whole run's).
const QUIET_CYCLES: usize = 1_000;

impl FaultsTruth {
    /// The bands from the quiet cycles, then each fault's re-lock time.
    fn judge_relock(&mut self, samples: &[LockSample], relock: &[Relock]) {
        let in_window = |t: u64| {
            self.windows
                .iter()
                .any(|w| t >= w.start_ps && t < w.until_ps)
        };
        let running: Vec<&LockSample> = samples.iter().filter(|x| x.running).collect();
        let quiet: Vec<&LockSample> = running
            .iter()
            .copied()
            .filter(|x| !in_window(x.sent_ps))
            .collect();
        let base = if quiet.len() >= QUIET_CYCLES {
            &quiet
        } else {
            &running
        };
        let mut rs: Vec<f32> = base
            .iter()
            .map(|x| x.rs_is_ns)
            .filter(|v| v.is_finite())
            .collect();
        let band_092c = if rs.is_empty() {
            f64::from(RELOCK_NS)
        } else {
            (2.0 * p999(&mut rs)).max(f64::from(RELOCK_NS))
        };
        let mut m: Vec<f32> = base
            .iter()
            .map(|x| x.m_rs_ns)
            .filter(|v| v.is_finite())
            .collect();
        let (usual, band_m) = if m.len() < QUIET_CYCLES / 10 {
            (None, None)
        } else {
            m.sort_unstable_by(f32::total_cmp);
            let median = m[m.len() / 2];
            let mut d: Vec<f32> = m.iter().map(|v| (v - median).abs()).collect();
            (
                Some(f64::from(median)),
                Some((2.0 * p999(&mut d)).max(RELOCK_M_RS_MIN_NS)),
            )
        };
        self.lock_band_092c_ns = band_092c;
        self.lock_band_m_rs_ns = band_m;
        self.usual_m_rs_ns = usual;
        self.relock_kinds = relock.iter().map(|r| r.kind).collect();
        self.relock_ms = relock
            .iter()
            .map(|r| {
                let mut in_a_row = 0u32;
                let mut first_good_ps = 0u64;
                for x in samples.iter().filter(|x| x.sent_ps >= r.start_ps) {
                    // A lost cycle says nothing of the lock: it neither counts nor breaks a
                    // run of good cycles (random loss would otherwise never let one reach its
                    // length).
                    if x.rs_is_ns.is_nan() && !x.running {
                        continue;
                    }
                    // (No M-rS yet, a master-shift method's measurement still averaging its
                    // offset: nothing to judge the method by.)
                    let method_ok = match (usual, band_m) {
                        (Some(u), Some(b)) if x.m_rs_ns.is_finite() => {
                            (f64::from(x.m_rs_ns) - u).abs() <= b
                        }
                        _ => true,
                    };
                    let good = x.running && f64::from(x.rs_is_ns) < band_092c && method_ok;
                    if !good {
                        in_a_row = 0;
                        continue;
                    }
                    if in_a_row == 0 {
                        first_good_ps = x.sent_ps;
                    }
                    in_a_row += 1;
                    if in_a_row >= RELOCK_CYCLES {
                        return Some((first_good_ps - r.start_ps) as f64 / 1e9);
                    }
                }
                None
            })
            .collect();
    }
}

impl RunResult {
    /// Summaries of the five quantities: M-rS, rS-IS, phase, slave spread, worst margin.
    pub fn summaries(&self) -> [Summary; 5] {
        [
            self.m_rs.summary(),
            self.rs_is.summary(),
            self.phase.summary(),
            self.slave_diff.summary(),
            self.margin.summary(),
        ]
    }
}

/// Why a run could not complete.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The bring-up failed.
    #[error("bring-up failed: {0}")]
    Bringup(#[from] MasterError),
    /// The cyclic frame does not fit.
    #[error("cyclic frame: {0}")]
    Frame(ecsync_wire::WireError),
    /// The per-cycle samples could not be written.
    #[error("writing the samples to {path}: {err}")]
    Samples {
        /// The file.
        path: String,
        /// What went wrong.
        err: std::io::Error,
    },
}

/// The seed of run `run`.
pub fn run_seed(base: u64, run: u32) -> u64 {
    splitmix64(base ^ splitmix64(u64::from(run) + 1))
}

/// A run's network after its bring-up: every method of the run continues from a copy of it
/// (the bring-up does not depend on the method, and it is the same hardware and seed).
#[derive(Debug)]
pub struct BroughtUp {
    sim: SimTransport,
    net: Network,
    seed: u64,
    run: u32,
}

impl BroughtUp {
    /// The run's seed (of its noise and crystals).
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The network as the bring-up found and configured it.
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The simulator's transport after the bring-up (its segment's ground truth, its faults).
    pub fn sim(&self) -> &SimTransport {
        &self.sim
    }
}

/// The crystals of run `run` (the same hardware in every run; the wander differs).
pub fn run_specs(s: &Scenario, run: u32) -> Vec<ecsync_sim::SlaveSpec> {
    let seed = run_seed(s.seed, run);
    let mut specs = s.slaves.clone();
    for (i, sp) in specs.iter_mut().enumerate() {
        sp.crystal.seed = splitmix64(seed ^ (0x5eed_0000 + i as u64) ^ sp.crystal.seed);
    }
    specs
}

/// Brings up the network of run `run` of the scenario.
pub fn bring_up(s: &Scenario, run: u32) -> Result<BroughtUp, RunError> {
    let seed = run_seed(s.seed, run);
    let specs = run_specs(s, run);
    let segment = Segment::new(&specs).map_err(|e| MasterError::Config(e.to_string()))?;
    let mut sim = SimTransport::new(segment);
    sim.set_master_clock(MasterClock::new(CrystalParams {
        ppm: s.host.master_ppm,
        wander_ppm_per_sqrt_s: s.host.master_wander_ppm_per_sqrt_s,
        wander_step_ps: ecsync_sim::clock::DEFAULT_WANDER_STEP_PS,
        initial_local_ns: SIM_EPOCH_NS,
        seed: splitmix64(seed ^ 0x4a57_e700),
    }));
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: s.static_drift_frames,
        cycle_ns: s.cycle_ns,
        sync0_shift_ns: s.sync0_shift_ns(),
        lock_hold_checks: 200,
        monitor_cycles: 10,
        sync_error_limit: s.sync_error_limit,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    // Faults counted from the first frame play on the bring-up too: a lost datagram is then
    // waited for a few milliseconds and sent again, as on a real network.
    // Slaves that appear later are not there for the bring-up, whatever the epoch.
    if let Some(f) = &s.faults {
        FaultPlayer::new(f.clone(), seed).prepare(sim.segment_mut());
    }
    let net = match &s.faults {
        Some(f) if f.epoch == Epoch::Start => {
            sim.set_faults(FaultPlayer::new(f.clone(), seed));
            sim.run_procedure_with(&mut engine, FAULTY_PROCEDURE, |_, _, _| {})?
        }
        _ => sim.run_procedure(&mut engine, |_, _, _| {})?,
    };
    Ok(BroughtUp {
        sim,
        net,
        seed,
        run,
    })
}

/// A recovered slave's SYNC0 starts at least this long after the recovery reads the time, ns
/// (the rest of the recovery's frames, one per cycle, come first).
const RECOVERY_SYNC0_LEAD_NS: u64 = 20_000_000;
/// What a reply may take past the cycle's frames' way back before it counts as lost (the
/// host's receive path beyond its modelled latency), ns.
const REPLY_MARGIN_NS: u64 = 100_000;

/// FRMW frames of static drift compensation a recovery sends after a reset slave's offset.
const RECOVERY_STATIC_DRIFT_FRAMES: u32 = 15_000;

/// How the bring-up waits and retries on a segment with faults: 5 ms, ten times.
pub const FAULTY_PROCEDURE: ecsync_master::driver::ProcedureConfig =
    ecsync_master::driver::ProcedureConfig {
        reply_timeout_ns: 5_000_000,
        retries: 10,
    };

/// The host's noise of a block of cycles as the simulated host's timing (cycles outside the
/// block are drawn on the spot).
struct NoiseHost {
    first: u64,
    block: Arc<[CycleNoise]>,
    noise: HostNoise,
    send: SendMode,
    send_params: SendParams,
    seed: u64,
}

impl HostModel for NoiseHost {
    fn cycle(&self, cycle: u64) -> HostDelays {
        let n = cycle
            .checked_sub(self.first)
            .and_then(|k| self.block.get(k as usize).copied())
            .unwrap_or_else(|| self.noise.cycle(cycle));
        ecsync_sim::send::apply(self.send, &self.send_params, n, self.seed, cycle).delays
    }
}

/// `--samples`: one CSV row per recorded cycle.
struct SampleSink {
    path: String,
    out: std::io::BufWriter<std::fs::File>,
    line: String,
    failed: Option<String>,
}

impl SampleSink {
    fn write_line(&mut self) {
        if self.failed.is_some() {
            return;
        }
        self.line.push('\n');
        if let Err(e) = self.out.write_all(self.line.as_bytes()) {
            self.failed = Some(format!("{}: {e}", self.path));
        }
        self.line.clear();
    }
}

/// One method's run in progress: the cyclic phase, resumable in steps of any number of cycles
/// (so that a scheduler can share the cores fairly between runs; the result does not depend on
/// the steps).
pub struct Run {
    sim: SimTransport,
    eng: CyclicEngine<Method>,
    driver: CyclicDriver,
    noise: HostNoise,
    /// How the host sends, with what, and the run's seed its draws take.
    send: SendMode,
    send_params: SendParams,
    send_seed: u64,
    /// The run's noise drawn once for all methods (see [`SharedNoise`]); without it, each step
    /// draws its own.
    shared_noise: Option<Arc<SharedNoise>>,
    res: RunResult,
    series: [Bands; 3],
    grid0: Option<(u64, i64)>,
    init_fit: LineFit,
    init_frames: u64,
    next_cycle: u64,
    warmup_cycles: u64,
    total_cycles: u64,
    period_ns: u64,
    shift_ns: f64,
    target_ns: i64,
    reference: usize,
    /// Slaves with a DC unit (SYNC0), by position.
    dc_slaves: Vec<usize>,
    expected_lrw_wkc: u16,
    pdi_len: u32,
    samples: Option<SampleSink>,
    was_in_sync: bool,
    /// This cycle's margin per DC slave (NaN: none), for the samples.
    margins: Vec<f64>,
    /// Per DC slave: the frame of a cycle that carries its outputs, and that frame's wire time.
    out_frames: Vec<(usize, u64)>,
    /// The cycle's frames back to back on the wire, ps.
    cycle_wire_ps: u64,
    /// Per fault over: its real time, the good cycles in a row since, the first of them (real
    /// time), the re-lock time once found (ms).
    relock: Vec<Relock>,
    /// Per cycle of the cyclic phase, what its re-lock is judged from (with faults only).
    lock_samples: Vec<LockSample>,
    /// Fault events already looked at.
    events_seen: usize,
    /// The first cycle's scheduled start, master time, ns.
    cyclic_start_ns: u64,
}

/// The way back to lock after one fault (see [`FaultsTruth::relock_ms`]).
#[derive(Debug, Clone, Copy)]
struct Relock {
    kind: KindName,
    start_ps: u64,
}

/// Cycles in a row with |0x092C| under [`RELOCK_NS`] that count as locked again.
const RELOCK_CYCLES: u32 = 100;
/// The bound of |0x092C| for "locked", ns (at least).
const RELOCK_NS: u32 = 100;
/// The method's error band, ns (at least).
const RELOCK_M_RS_MIN_NS: f64 = 1_000.0;

impl std::fmt::Debug for Run {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Run")
            .field("method", &self.res.method)
            .field("run", &self.res.run)
            .field("next_cycle", &self.next_cycle)
            .finish_non_exhaustive()
    }
}

impl Run {
    /// Method `entry.kind`, sending as `entry.send` says, from the brought-up network `up`
    /// (which it copies).
    pub fn new(s: &Scenario, up: &BroughtUp, entry: Entry) -> Result<Run, RunError> {
        let kind = entry.kind;
        let mut sim = up.sim.fork();
        if let Some(f) = &s.faults
            && f.epoch == Epoch::Cyclic
        {
            sim.set_faults(FaultPlayer::new(f.clone(), up.seed));
        }
        let net = &up.net;
        let lock_ms = net.lock.time_to_lock_ns.map(|t| t as f64 / 1e6);
        let reference = usize::from(net.reference);
        let ref_station = net.slaves[reference].station;

        let method: Method = s.params.build(kind, &s.method_context());
        let noise = HostNoise::replaying(s.host, up.seed, s.host_trace.clone());
        let period = u64::from(s.cycle_ns);
        let init_frames = method.init_cycles().min(s.warmup_cycles);
        let cyc_cfg = CyclicConfig {
            period_ns: s.cycle_ns,
            reference_station: ref_station,
            pdi_len: net.pdi_len,
            measure_init_frames: method.init_cycles().max(10_000).min(s.warmup_cycles.max(1)),
            reference_offset_ns: net.slaves[reference].offset.unwrap_or(0),
            lrw: net.lrw.clone(),
        };
        // The first cycle: frames aimed at the target phase of the reference's grid, where
        // the bring-up's last reading put it against the master's clock, less the mean time
        // from the cycle's start to the frame's arrival at the reference that the master knows
        // of its own host (e_m and the NIC latency; j_s's mean it does not). On a real host the
        // reading holds the NIC's latency; the simulated bring-up runs with the ideal host's
        // few microseconds instead of the host model's, so the reading holds those and the
        // difference is taken off here.
        let first = ecsync_master::cyclic::first_cycle_start_ns(
            sim.master_now_ns(),
            net.reference_reading,
            method.reference_write_kind(),
            s.cycle_ns,
            s.target_phase_ns,
            ((s.host.em_ns + s.host.tx_latency_ns) as u64)
                .saturating_sub(sim.tx_latency_ps() / 1000),
        );
        let eng = CyclicEngine::new(method, cyc_cfg, first).map_err(RunError::Frame)?;
        let dc_slaves: Vec<usize> = (0..sim.segment().len())
            .filter(|&x| sim.segment().esc(x).dc().is_some())
            .collect();
        let per_slave = dc_slaves
            .iter()
            .map(|&x| SlaveTruth {
                position: x as u16,
                margin: Stats::new(),
                latest_end_ns: f64::NEG_INFINITY,
                late_frames: 0,
                sync0_missed: 0,
                last_outputs_ns: None,
                drive_sm_events_missed: None,
                drive_count_at_start: None,
            })
            .collect();
        let has_log = method.controller_log().is_some();
        let n_dc = dc_slaves.len();
        // Which frame of a cycle carries each DC slave's outputs (its SYNC0 needs that one),
        // and how long that frame is on the wire.
        let out_frames: Vec<(usize, u64)> = dc_slaves
            .iter()
            .map(|&x| {
                let k = net
                    .slaves
                    .get(x)
                    .filter(|s| s.outputs.1 > 0)
                    .and_then(|s| eng.frame_of_logical(s.outputs.0))
                    .unwrap_or(0);
                (k, frame_wire_time_ps(eng.frame_len_of(k)))
            })
            .collect();
        // The cyclic phase's host: its receive latency; a lost frame is given up half a cycle
        // after its send, or when the cycle's frames could have come back, if that is later
        // (a large network's frames take milliseconds on the wire: half a cycle would count
        // every one lost; the driver gives up at the next cycle's slot in any case).
        let rx_latency_ps = (s.host.rx_latency_ns * 1000.0) as u64;
        sim.set_rx_latency_ps(rx_latency_ps);
        let cycle_wire_ps: u64 = (0..eng.frame_count())
            .map(|k| frame_wire_time_ps(eng.frame_len_of(k)))
            .sum();
        let way_round_ps = sim.segment().round_trip_ps();
        let comes_back_ns = (cycle_wire_ps + way_round_ps + rx_latency_ps) / 1000 + REPLY_MARGIN_NS;
        let mut driver = CyclicDriver::new(CyclicLimits {
            reply_timeout_ns: (period / 2).max(comes_back_ns),
            lost_in_a_row: u64::MAX,
            // (`hwstamp` runs only master-shift methods: see `SendMode::applies_to`.)
            t_ms_from_tx_stamp: entry.send == SendMode::Hwstamp,
            ..CyclicLimits::default()
        });
        // Slaves that lose their configuration (a power cycle) are brought back while the
        // cycle goes on, as on a real network.
        driver.set_recovery(
            net.clone(),
            ecsync_master::recovery::RecoveryConfig {
                cycle_ns: s.cycle_ns,
                sync0_shift_ns: s.sync0_shift_ns(),
                sync0_lead_ns: RECOVERY_SYNC0_LEAD_NS,
                timeouts: ecsync_master::bringup::BringupTimeouts::default(),
                static_drift_frames: RECOVERY_STATIC_DRIFT_FRAMES,
                sync_error_limit: s.sync_error_limit,
            },
        );
        Ok(Run {
            sim,
            eng,
            driver,
            noise,
            send: entry.send,
            send_params: s.send,
            send_seed: up.seed,
            shared_noise: None,
            res: RunResult {
                method: entry.name(),
                send: entry.send,
                launch_misses: 0,
                spin_ns: 0.0,
                run: up.run,
                cycles_done: 0,
                m_rs: Stats::new(),
                rs_is: Stats::new(),
                phase: Stats::new(),
                phase_error: Stats::new(),
                slave_diff: Stats::new(),
                margin: Stats::new(),
                per_slave,
                late_frames: 0,
                latest_end_ns: f64::NEG_INFINITY,
                lost_frames: 0,
                bad_wkc: 0,
                series: Default::default(),
                series_block: Bands::new(s.cycles).block_cycles(),
                lock_ms,
                init_drift: None,
                controller: has_log.then(ControllerTruth::default),
                frame_wire_ns: 0.0,
                max_round_trip_ns: 0.0,
                samples_error: None,
                faults: s.faults.as_ref().map(|_| FaultsTruth::default()),
                left_op: Vec::new(),
            },
            series: [
                Bands::new(s.cycles),
                Bands::new(s.cycles),
                Bands::new(s.cycles),
            ],
            grid0: None,
            init_fit: LineFit::default(),
            init_frames,
            next_cycle: 0,
            warmup_cycles: s.warmup_cycles,
            total_cycles: s.warmup_cycles + s.cycles,
            period_ns: period,
            shift_ns: f64::from(s.sync0_shift_ns()),
            target_ns: s.target_phase_ns,
            reference,
            dc_slaves,
            expected_lrw_wkc: net.expected_lrw_wkc,
            pdi_len: net.pdi_len,
            samples: None,
            was_in_sync: false,
            margins: Vec::with_capacity(n_dc),
            out_frames,
            cycle_wire_ps,
            relock: Vec::new(),
            lock_samples: Vec::new(),
            events_seen: 0,
            cyclic_start_ns: first,
        })
    }

    /// Writes one CSV row per recorded cycle to `dir/<method>-run<r>.csv` (`--samples`).
    pub fn write_samples(&mut self, dir: &Path) -> Result<(), RunError> {
        let path = dir.join(format!("{}-run{}.csv", self.res.method, self.res.run));
        let p = path.display().to_string();
        let file = std::fs::File::create(&path).map_err(|err| RunError::Samples {
            path: p.clone(),
            err,
        })?;
        let mut line = String::from(
            "cycle,lost,true_phase_ns,m_rs_ns,rs_is_ns,slave_spread_ns,worst_margin_ns,worst_slave,late",
        );
        for x in &self.dc_slaves {
            let _ = write!(line, ",margin_{x}_ns");
        }
        if self.res.controller.is_some() {
            line.push_str(",set_value_ns,ctl_error_ns,ctl_filtered_error_ns,ctl_adjustment_ns,ctl_drift_ppm,ctl_valid,ctl_in_sync");
        }
        let mut sink = SampleSink {
            path: p,
            out: std::io::BufWriter::with_capacity(1 << 16, file),
            line,
            failed: None,
        };
        sink.write_line();
        self.samples = Some(sink);
        Ok(())
    }

    /// Takes the run's noise from `shared` (drawn once for all methods of the run) instead of
    /// drawing it; `shared` must hold this run's noise.
    pub fn share_noise(&mut self, shared: Arc<SharedNoise>) {
        debug_assert_eq!(*shared.noise(), self.noise);
        if *shared.noise() == self.noise {
            self.shared_noise = Some(shared);
        }
    }

    /// Has the master read every drive's SM-event-missed counter (0x1C32:0B) over CoE this
    /// often, in the cycles' spare slot, as `ecsync run` does (a comparison does not: its
    /// figures are the segment's own). The reads are [`Run::drive_counter_reads`].
    pub fn read_drive_counters_every(&mut self, every_ns: u64) {
        self.driver.set_sync_counters_every_ns(Some(every_ns));
    }

    /// The master's first and last read of each drive's 0x1C32:0B over CoE so far
    /// ([`Run::read_drive_counters_every`]), in network order.
    pub fn drive_counter_reads(
        &self,
    ) -> Vec<(
        ecsync_master::driver::SyncCounter,
        ecsync_master::driver::SyncCounter,
    )> {
        self.driver.sync_counters()
    }

    /// Cycles run so far (warm-up included).
    pub fn cycles_run(&self) -> u64 {
        self.next_cycle
    }

    /// Cycles still to run (warm-up included).
    pub fn remaining(&self) -> u64 {
        self.total_cycles.saturating_sub(self.next_cycle)
    }

    /// Recorded cycles run so far.
    pub fn recorded(&self) -> u64 {
        self.next_cycle.saturating_sub(self.warmup_cycles)
    }

    /// Runs up to `max_cycles` more cycles; returns how many ran.
    pub fn step(&mut self, max_cycles: u64) -> u64 {
        let start = self.next_cycle;
        let end = self.total_cycles.min(start.saturating_add(max_cycles));
        if end <= start {
            return 0;
        }
        // The noise of these cycles, drawn in one go (or taken from the other methods' draw),
        // is the simulated host's timing.
        let block: Arc<[CycleNoise]> = match &self.shared_noise {
            Some(sh) => sh.block(start, end - start),
            None => (start..end).map(|i| self.noise.cycle(i)).collect(),
        };
        // What the send mode does with the recorded cycles' noise: CPU spun, launch times
        // missed (the same pure function the transport applies).
        if self.send != SendMode::Plain {
            for (k, n) in block.iter().enumerate() {
                let i = start + k as u64;
                if i < self.warmup_cycles {
                    continue;
                }
                let o =
                    ecsync_sim::send::apply(self.send, &self.send_params, *n, self.send_seed, i);
                self.res.spin_ns += o.spin_ns;
                self.res.launch_misses += u64::from(o.delays.dropped);
            }
        }
        self.sim.set_host(Box::new(NoiseHost {
            first: start,
            block,
            noise: self.noise.clone(),
            send: self.send,
            send_params: self.send_params,
            seed: self.send_seed,
        }));
        let Run {
            sim,
            eng,
            driver,
            res,
            series,
            grid0,
            init_fit,
            samples,
            was_in_sync,
            dc_slaves,
            margins,
            out_frames,
            cycle_wire_ps,
            relock,
            lock_samples,
            events_seen,
            ..
        } = self;
        let (warmup, period, shift, target) = (
            self.warmup_cycles,
            self.period_ns,
            self.shift_ns,
            self.target_ns,
        );
        let (reference, init_frames, total) = (self.reference, self.init_frames, self.total_cycles);
        let (expected_wkc, pdi_len) = (self.expected_lrw_wkc, self.pdi_len);
        let p = period as f64;
        let with_faults = res.faults.is_some();
        let observe = |tr: &mut SimTransport, rep: &CycleReport| {
            let rec = &rep.record;
            let i = rec.cycle;
            if i >= total {
                return;
            }
            if let Some(ft) = res.faults.as_mut() {
                // Faults are judged over the whole cyclic phase (their times count from its
                // start): DC held, and how soon it came back after each fault.
                let sent_ps = tr.last_exchange().sent_ps;
                if let Some(p) = tr.faults() {
                    // The way back is timed from the moment a fault is over: the end of one
                    // with a window (the slave on again, the cable in), the start of one
                    // without (a step, a stall, loss to the end of the run).
                    for e in &p.events()[*events_seen..] {
                        let f = &p.schedule().faults[e.fault];
                        if e.edge == Edge::Start {
                            ft.windows.push(FaultWindow {
                                fault: e.fault,
                                kind: e.kind,
                                start_ps: e.t_ps,
                                until_ps: e.t_ps
                                    + f.for_ns.unwrap_or(0).min(10_000_000_000) * 1000
                                    + WINDOW_AFTER_PS,
                                points: Vec::new(),
                            });
                        }
                        let windowed = f.for_ns.is_some()
                            && !matches!(
                                f.kind,
                                FaultKind::HostStall { .. } | FaultKind::ClockStep { .. }
                            );
                        if (e.edge == Edge::End) == windowed {
                            relock.push(Relock {
                                kind: e.kind,
                                start_ps: e.t_ps,
                            });
                        }
                    }
                    *events_seen = p.events().len();
                }
                for w in ft.windows.iter_mut().filter(|w| sent_ps < w.until_ps) {
                    let v = match (rec.receive_ns, rec.rs_is_ns) {
                        (Some(_), Some(v)) => v as f32,
                        _ => f32::NAN,
                    };
                    let t = (sent_ps.saturating_sub(w.start_ps)) as f64 / 1e9;
                    w.points.push((t as f32, v, rec.reference_held));
                }
                ft.skipped_cycles += rep.skipped_before;
                ft.held_cycles += u64::from(rec.reference_held);
                // Running: came back, the reference's time believed (a reset slave's register
                // reads small before anyone writes it a time), every slave's process data
                // there. Whether it is locked is judged at the end, against the bands the
                // method holds outside the faults.
                let running = match (rec.receive_ns, rec.rs_is_ns) {
                    (Some(_), Some(v)) => {
                        ft.max_rs_is_ns = ft.max_rs_is_ns.max(v);
                        let wkc_ok = pdi_len == 0 || rec.lrw_wkc == Some(expected_wkc);
                        !rec.reference_held && wkc_ok
                    }
                    (Some(_), None) => false,
                    (None, _) => {
                        ft.lost_cycles += 1;
                        false
                    }
                };
                lock_samples.push(LockSample {
                    sent_ps,
                    rs_is_ns: match (rec.receive_ns, rec.rs_is_ns) {
                        (Some(_), Some(v)) => v as f32,
                        (Some(_), None) => f32::INFINITY,
                        (None, _) => f32::NAN,
                    },
                    m_rs_ns: rec.m_rs_ns.map_or(f32::NAN, |m| m as f32),
                    running,
                });
            }
            if let (Some(c), Some(t)) = (rec.log, res.controller.as_mut())
                && c.in_sync
                && t.first_in_sync_cycle.is_none()
            {
                t.first_in_sync_cycle = Some(i);
            }
            if i >= warmup {
                // From the wire to the reply, late replies included (a reply that came after
                // its deadline still says how long the frame needs).
                if let Some(back) = tr.last_exchange().received_ps {
                    let sent = tr.real_ps_at(rep.stamp_ns);
                    let rt = back.saturating_sub(sent) as f64 / 1000.0;
                    res.max_round_trip_ns = res.max_round_trip_ns.max(rt);
                }
                res.frame_wire_ns = *cycle_wire_ps as f64 / 1000.0;
            }
            if i < warmup {
                // The init frames' drift: how the reference's system time runs against the
                // master's clock, read at the frame's arrival (the clocks' truth, free of the
                // host's jitter).
                if i < init_frames {
                    let at = tr.frame_trace(0).pu_ps(reference).and_then(|pu| {
                        let dc = tr.segment().esc(reference).dc()?;
                        Some((pu, dc.system_time_split(pu)))
                    });
                    if let Some((pu, r)) = at {
                        let m = tr.master_clock_mut().master_ns(pu);
                        init_fit.add(i as f64, (r.0.wrapping_sub(m) as i64) as f64 + r.1);
                    }
                }
                return;
            }
            let seg = tr.segment();
            let sys =
                |slave: usize, t_ps: u64| seg.esc(slave).dc().map(|d| d.system_time_split(t_ps));
            let k = i - warmup;
            res.cycles_done = k + 1;
            if let (Some(c), Some(t)) = (rec.log, res.controller.as_mut()) {
                if c.in_sync {
                    t.in_sync_cycles += 1;
                } else if *was_in_sync {
                    t.sync_losses += 1;
                }
                if !c.valid && rec.receive_ns.is_some() {
                    t.invalid_errors += 1;
                }
                t.in_sync_at_end = c.in_sync;
                t.drift_ppm_at_end = c.drift_ppm;
                *was_in_sync = c.in_sync;
            }
            if rec.receive_ns.is_none() {
                res.lost_frames += 1;
                if let Some(sk) = samples.as_mut() {
                    let _ = write!(sk.line, "{k},1");
                    sk.write_line();
                }
                return;
            }
            if rec.lrw_wkc != Some(expected_wkc) && pdi_len > 0 {
                res.bad_wkc += 1;
            }
            if let Some(m) = rec.m_rs_ns {
                res.m_rs.add(m as f64);
                series[0].add(k, m as f64);
            }
            if let Some(v) = rec.rs_is_ns {
                res.rs_is.add(f64::from(v));
                series[1].add(k, f64::from(v));
            }
            // Ground truth from the segment: the cycle's first frame at the reference. A slave
            // without SYNC0 running (power-cycled, not configured again yet) has no grid and no
            // deadline: it is not counted until it has.
            let runs_sync0 = |x: usize| seg.esc(x).dc().is_some_and(|d| d.sync0().is_some());
            let trace = tr.frame_trace(0);
            let Some(r) = trace
                .pu_ps(reference)
                .filter(|_| runs_sync0(reference))
                .and_then(|t| sys(reference, t))
            else {
                // No grid to judge the cycle by (the reference reset, its SYNC0 not running
                // again yet): the master's own figures only.
                if let Some(sk) = samples.as_mut() {
                    let _ = write!(sk.line, "{k},0,,");
                    if let Some(m) = rec.m_rs_ns {
                        let _ = write!(sk.line, "{m}");
                    }
                    sk.line.push(',');
                    if let Some(v) = rec.rs_is_ns {
                        let _ = write!(sk.line, "{v}");
                    }
                    sk.write_line();
                }
                return;
            };
            // The grid point this frame aims at: the one nearest the target at the first
            // recorded frame, one per cycle from there. With faults, the one nearest the
            // target now: a method that lost the reference for a while (a power cycle) may
            // come back a few periods off its count, and SYNC0 fires every period.
            let (g0, k0) = *grid0.get_or_insert_with(|| {
                let g = ((r.0 as f64 + r.1 - target as f64) / p).round() as u64;
                (g, k as i64)
            });
            let grid = if with_faults {
                ((r.0 as f64 + r.1 - target as f64) / p).round() as u64 * period
            } else {
                (g0 + (k as i64 - k0) as u64) * period
            };
            let phase = (r.0.wrapping_sub(grid) as i64) as f64 + r.1;
            res.phase.add(phase);
            res.phase_error.add(phase - target as f64);
            series[2].add(k, phase);
            // The slaves' differences move slowly (the loops act once per cycle): every 8th
            // cycle is sampled.
            let mut spread = None;
            if k.is_multiple_of(8) {
                let mut worst = 0.0f64;
                for &x in dc_slaves.iter() {
                    if x == reference || !runs_sync0(x) {
                        continue;
                    }
                    if let Some(v) = sys(x, trace.pu_ps(reference).unwrap_or(0)) {
                        let d = (v.0.wrapping_sub(r.0) as i64) as f64 + (v.1 - r.1);
                        worst = worst.max(d.abs());
                    }
                }
                res.slave_diff.add(worst);
                spread = Some(worst);
            }
            // The frame has passed a slave when its last bit has: its outputs take effect
            // after the FCS check, and SYNC0 needs them by then.
            let mut worst_margin = f64::INFINITY;
            let mut worst_slave = 0u16;
            // Each slave's margin is kept for the samples file only.
            let keep = samples.is_some();
            margins.clear();
            for ((st, &x), &(k, out_wire_ps)) in res
                .per_slave
                .iter_mut()
                .zip(dc_slaves.iter())
                .zip(out_frames.iter())
            {
                let pu = if !runs_sync0(x) {
                    None
                } else if k == 0 {
                    trace.pu_ps(x)
                } else {
                    tr.frame_trace(k).pu_ps(x)
                };
                let Some(e) = pu.and_then(|pu| sys(x, pu + out_wire_ps)) else {
                    if keep {
                        margins.push(f64::NAN);
                    }
                    continue;
                };
                let end_after_grid = (e.0.wrapping_sub(grid) as i64) as f64 + e.1;
                let margin = shift - end_after_grid;
                // The pulses at m x period + shift up to the outputs: those between two
                // frames' outputs but the first found none new.
                let pulses = |t: u64| {
                    let s = shift as u64;
                    if t < s { 0 } else { (t - s) / period + 1 }
                };
                if let Some(prev) = st.last_outputs_ns.replace(e.0) {
                    st.sync0_missed += pulses(e.0).saturating_sub(pulses(prev)).saturating_sub(1);
                }
                let esc = seg.esc(x);
                if esc.runs_on_sync0() {
                    let now = esc.sm_events_missed();
                    let start = *st.drive_count_at_start.get_or_insert(now);
                    st.drive_sm_events_missed = Some(now.saturating_sub(start));
                }
                if keep {
                    margins.push(margin);
                }
                st.margin.add(margin);
                if margin < 0.0 {
                    st.late_frames += 1;
                }
                if end_after_grid > st.latest_end_ns {
                    st.latest_end_ns = end_after_grid;
                }
                if margin < worst_margin {
                    worst_margin = margin;
                    worst_slave = st.position;
                }
            }
            let late = worst_margin < 0.0;
            if late && let Some(ft) = res.faults.as_mut() {
                let sent_ps = tr.last_exchange().sent_ps;
                ft.late_in_windows += u64::from(
                    ft.windows
                        .iter()
                        .any(|w| sent_ps >= w.start_ps && sent_ps < w.until_ps),
                );
            }
            if worst_margin.is_finite() {
                res.margin.add(worst_margin);
                if late {
                    res.late_frames += 1;
                }
                res.latest_end_ns = res.latest_end_ns.max(shift - worst_margin);
            }
            if let Some(sk) = samples.as_mut() {
                let l = &mut sk.line;
                let _ = write!(l, "{k},0,{phase:.3},");
                if let Some(m) = rec.m_rs_ns {
                    let _ = write!(l, "{m}");
                }
                l.push(',');
                if let Some(v) = rec.rs_is_ns {
                    let _ = write!(l, "{v}");
                }
                l.push(',');
                if let Some(v) = spread {
                    let _ = write!(l, "{v:.3}");
                }
                if worst_margin.is_finite() {
                    let _ = write!(l, ",{worst_margin:.3},{worst_slave},{}", u8::from(late));
                } else {
                    l.push_str(",,,0");
                }
                for m in margins.iter() {
                    l.push(',');
                    if m.is_finite() {
                        let _ = write!(l, "{m:.3}");
                    }
                }
                if let Some(c) = rec.log {
                    let _ = write!(
                        l,
                        ",{},{},{:.3},{},{:.6},{},{}",
                        c.set_value_ns,
                        c.error_ns,
                        c.filtered_error_ns,
                        c.adjustment_ns,
                        c.drift_ppm,
                        u8::from(c.valid),
                        u8::from(c.in_sync)
                    );
                }
                sk.write_line();
            }
        };
        // The simulator cannot fail, and a lab run stops only at its cycle count.
        match driver.run(sim, eng, end - start, None, observe) {
            Ok(_) => {}
            Err(never) => match never {},
        }
        self.next_cycle = self.eng.cycle().max(start);
        self.next_cycle - start
    }

    /// The result (of the cycles run so far).
    pub fn finish(self) -> Result<RunResult, RunError> {
        let mut res = self.res;
        let t0 = self.cyclic_start_ns;
        let ms = |t: u64| t.saturating_sub(t0) as f64 / 1e6;
        for e in self.driver.recoveries() {
            let Some(Ok(r)) = &e.outcome else { continue };
            for l in &r.left_op {
                res.left_op.push(LeftOpOut {
                    run: res.run,
                    slave: l.position + 1,
                    state: l.state_name(),
                    al_status_code: l.al_status_code(),
                    reason: l.reason(),
                    found_ms: ms(e.started_ns),
                    // The recovery ends once every slave it took on is in OP again.
                    back_in_op_ms: e.ended_ns.map(ms),
                });
            }
        }
        if let Some(ft) = res.faults.as_mut() {
            if let Some(p) = self.sim.faults() {
                ft.events = p.events().to_vec();
                ft.counts = p.counts();
            }
            let d = self.driver.stats();
            let h = self.eng.health();
            ft.master_clock_steps = h.master_clock_steps;
            ft.last_master_step_ns = h.last_master_step_ns;
            ft.late_replies = d.late;
            ft.duplicate_replies = d.duplicates;
            ft.judge_relock(&self.lock_samples, &self.relock);
            let t0 = self.cyclic_start_ns;
            let ms = |t: u64| t.saturating_sub(t0) as f64 / 1e6;
            ft.recoveries = self
                .driver
                .recoveries()
                .iter()
                .map(|e| RecoveryOut {
                    start_ms: ms(e.started_ns),
                    end_ms: e.ended_ns.map(ms),
                    slaves: e.slaves_brought_back(),
                    error: e.error(),
                    appeared: e.appeared(),
                    left_op: e.left_op(),
                })
                .collect();
        }
        let [a, b, c] = self.series;
        res.series = [a.finish(), b.finish(), c.finish()];
        if self.init_frames >= 2 && self.next_cycle >= self.init_frames {
            let d = self.init_fit.slope().unwrap_or(0.0);
            res.init_drift = Some(InitDrift {
                frames: self.init_frames,
                drift_ns_per_cycle: d,
                offset_ns: d * (self.init_frames - 1) as f64 / 2.0,
            });
        }
        if let Some(mut sk) = self.samples {
            if sk.failed.is_none()
                && let Err(e) = sk.out.flush()
            {
                sk.failed = Some(format!("{}: {e}", sk.path));
            }
            res.samples_error = sk.failed;
        }
        Ok(res)
    }
}
