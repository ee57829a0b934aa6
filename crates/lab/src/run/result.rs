//! What one run of one method measured: the statistics, the series, the ground truth per
//! slave, the faults and the way back to lock.

use super::*;

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
    /// The block's values as [`order_key`]s: selected as integers, in `f32::total_cmp`'s
    /// order (a comparison of keys is one instruction, total_cmp's a few more).
    buf: Vec<i32>,
    out: Vec<Band>,
}

/// `x`'s key in `f32::total_cmp`'s order: the integer comparison `total_cmp` makes (its bits,
/// the magnitude's flipped for negatives). Its own inverse.
#[inline]
fn order_key(bits: i32) -> i32 {
    bits ^ (((bits >> 31) as u32) >> 1) as i32
}

/// The value of a key.
fn of_key(key: i32) -> f32 {
    f32::from_bits(order_key(key) as u32)
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
        self.buf.push(order_key((x as f32).to_bits() as i32));
    }

    fn flush(&mut self) {
        let n = self.buf.len();
        if n == 0 {
            return;
        }
        let at = |q: f64| ((q * n as f64).ceil() as usize).clamp(1, n) - 1;
        let b = &mut self.buf;
        let (i50, i01, i99) = (at(0.5), at(0.01), at(0.99));
        let (lo, med, hi) = b.select_nth_unstable(i50);
        let med = of_key(*med);
        let p01 = if i01 < i50 {
            of_key(*lo.select_nth_unstable(i01).1)
        } else {
            med
        };
        let min = lo.iter().map(|&k| of_key(k)).fold(med, f32::min);
        let p99 = if i99 > i50 {
            of_key(*hi.select_nth_unstable(i99 - i50 - 1).1)
        } else {
            med
        };
        let max = hi.iter().map(|&k| of_key(k)).fold(med, f32::max);
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
    /// The name the scenario gives the slave.
    pub name: String,
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
    /// The drive's counter after the first measured frame (0 after a power cycle: the count
    /// restarted there).
    pub drive_count_at_start: Option<u64>,
    /// Power cycles of the drive in the measured cycles: 0x1C32:0B is a RAM value, 0 at each
    /// power-up, so `drive_sm_events_missed` counts from the last of them.
    pub drive_restarts: u32,
    /// `sync0_missed` when the drive last restarted (0 without a restart): what its own count
    /// compares with is `sync0_missed` less this.
    pub sync0_missed_at_restart: u64,
    /// It takes its outputs at SYNC1 events (an oversampling terminal, 0x1C32:01 = 3): the
    /// pulses above are SYNC1's, on the cycle's grid where the others' SYNC0 is.
    pub on_sync1: bool,
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
    /// Recorded cycles the controller ran: the slots the driver skipped (its task woke after
    /// them: a host stall, a step of the master's clock) are not among them.
    pub cycles_run: u64,
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
    /// Recorded cycles run (fewer than the scenario's when interrupted, or when the master
    /// skipped the last ones' slots).
    pub cycles_done: u64,
    /// The run went to its last cycle (its slot, if the master skipped it: a host stall or a
    /// step of its clock past it): not interrupted.
    pub reached_end: bool,
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
    /// Recorded cycles that lost their frame (one or more of them in a cycle of several).
    pub lost_frames: u64,
    /// Recorded cycles whose process data exchange failed: a frame late at some slave, or
    /// lost (a frame can be both: its reply lost after it passed the slaves late).
    pub late_or_lost_frames: u64,
    /// Frames a cycle sends (one unless the process image needs more).
    pub frames_per_cycle: usize,
    /// Cycles whose method asked for a next start the engine held (more than two periods
    /// on, or before the cycle's own): a controller gone unstable (warm-up included).
    pub wild_schedule_cycles: u64,
    /// Grid points the master's schedule aimed at twice or left out: recorded cycles whose
    /// start it put more than half a cycle off a whole number of periods after the last one's
    /// (a cycle sent twice or left out). Not counted with faults (the grid is found anew each
    /// cycle there).
    pub grid_slips: u64,
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
    /// The same outside the windows of the faults that hold replies back (`delay`,
    /// `second_responder`): what the network and the cycle take; `max_round_trip_ns` without
    /// such faults.
    pub max_round_trip_unfaulted_ns: f64,
    /// The fault whose window held the longest frame (its index in the schedule), when one
    /// did: the longest time is the fault's, not the network's.
    pub longest_frame_fault: Option<usize>,
    /// Why `--samples` could not be written (the run went on).
    pub samples_error: Option<String>,
    /// What the fault schedule did and how the master took it (`None`: no faults).
    pub faults: Option<FaultsTruth>,
    /// The drives the master found out of OP with their configuration kept (an AL error of
    /// their own: a sync error past the configured 0x10F1:02, a process data watchdog), in
    /// the order its recoveries found them.
    pub left_op: Vec<LeftOpOut>,
    /// Recording stopped before the run's last cycle because the master's task skipped the
    /// slots past it (`None`: it recorded every cycle, or was interrupted).
    pub recording_stopped: Option<RecordingStopped>,
}

/// A run whose recording stopped early: the master's task woke so late on its own clock (a
/// step of that clock forward, a stall) that the slots it skipped reached past the run's last
/// cycle, which counts in the master's slots.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RecordingStopped {
    /// The run.
    pub run: u32,
    /// Recorded cycles before it stopped.
    pub recorded: u64,
    /// Recorded cycles the run was to have.
    pub of: u64,
    /// Slots the task skipped at once, on the master's clock.
    pub skipped_slots: u64,
    /// Why the task woke that late.
    pub cause: StopCause,
}

/// What made the master's task skip slots past a run's end.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum StopCause {
    /// The schedule's `clock_step` moved the master's clock forward.
    ClockStep {
        /// Its entry in the schedule.
        fault: usize,
        /// The step, ns.
        step_ns: i64,
        /// When it was played, ns after the schedule's epoch.
        at_ns: u64,
    },
    /// The schedule's `host_stall` held the task.
    HostStall {
        /// Its entry in the schedule.
        fault: usize,
        /// The stall, ns.
        stall_ns: u64,
        /// When it was played, ns after the schedule's epoch.
        at_ns: u64,
    },
    /// No fault of the schedule: the host's own lateness.
    HostLate,
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
pub(super) const WINDOW_AFTER_PS: u64 = 1_000_000_000_000;

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
    /// The cycle slots the schedule's clock steps that played moved the master's time by
    /// (|step| over the period, plus two each): how many starts the engine may hold while a
    /// method still asks on the old time, before the step is detected and taken out (absent
    /// when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub clock_step_slots: u64,
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
pub(super) struct LockSample {
    pub(super) sent_ps: u64,
    /// |0x092C|, ns (NaN: none).
    pub(super) rs_is_ns: f32,
    /// M-rS, ns (NaN: none).
    pub(super) m_rs_ns: f32,
    /// Came back, reference believed, working counter complete.
    pub(super) running: bool,
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
    pub(super) fn judge_relock(&mut self, samples: &[LockSample], relock: &[Relock]) {
        // A hot connect changes the segment for good (the master counts the new slaves but
        // does not take them in: their clocks stay unsynchronized and the BRD of 0x092C reads
        // them), so nothing after it is quiet.
        let changed_from = self
            .windows
            .iter()
            .filter(|w| w.kind == KindName::HotConnect)
            .map(|w| w.start_ps)
            .min()
            .unwrap_or(u64::MAX);
        let in_window = |t: u64| {
            t >= changed_from
                || self
                    .windows
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

/// The way back to lock after one fault (see [`FaultsTruth::relock_ms`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Relock {
    pub(super) kind: KindName,
    pub(super) start_ps: u64,
}

/// Cycles in a row with |0x092C| under [`RELOCK_NS`] that count as locked again.
pub(super) const RELOCK_CYCLES: u32 = 100;
/// The bound of |0x092C| for "locked", ns (at least).
pub(super) const RELOCK_NS: u32 = 100;
/// The method's error band, ns (at least).
pub(super) const RELOCK_M_RS_MIN_NS: f64 = 1_000.0;

fn is_zero(v: &u64) -> bool {
    *v == 0
}

#[cfg(test)]
mod band_tests {
    use super::*;

    /// The keys sort as `f32::total_cmp` does, and back to the same bits.
    #[test]
    fn keys_order_as_total_cmp() {
        let v = [
            f32::NEG_INFINITY,
            -3.4e38,
            -1.0,
            -1e-45,
            -0.0,
            0.0,
            1e-45,
            2.0,
            f32::INFINITY,
            f32::NAN,
            -f32::NAN,
        ];
        for a in v {
            let ka = order_key(a.to_bits() as i32);
            assert_eq!(of_key(ka).to_bits(), a.to_bits());
            for b in v {
                assert_eq!(
                    ka.cmp(&order_key(b.to_bits() as i32)),
                    a.total_cmp(&b),
                    "{a} {b}"
                );
            }
        }
    }

    /// A block's band: its extremes and percentiles by sorting the values (the definition:
    /// the sample of rank ceil(q n)).
    #[test]
    fn a_band_is_the_sorted_blocks_ranks() {
        let mut x = 0x5eedu64;
        let mut next = || {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            ((x >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 2e4
        };
        let cycles = 1_000 * BAND_POINTS;
        let mut bands = Bands::new(cycles);
        let mut all = Vec::new();
        for k in 0..cycles {
            let v = next();
            bands.add(k, v);
            all.push(v as f32);
        }
        let out = bands.finish();
        assert_eq!(out.len() as u64, BAND_POINTS);
        for (i, b) in out.iter().enumerate() {
            let mut block: Vec<f32> = all[i * 1000..(i + 1) * 1000].to_vec();
            block.sort_by(f32::total_cmp);
            let rank = |q: f64| block[((q * 1000.0).ceil() as usize).clamp(1, 1000) - 1];
            assert_eq!(b.cycle, i as u64 * 1000);
            assert_eq!(
                (b.min, b.p01, b.p50, b.p99, b.max),
                (block[0], rank(0.01), rank(0.5), rank(0.99), block[999])
            );
        }
    }
}
