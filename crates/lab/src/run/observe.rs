//! What a run measures each cycle, one observer per concern: the faults and the way back to
//! lock ([`FaultWatch`]), the segment's ground truth (the reference's grid, every slave's
//! margin before its SYNC0: [`GroundTruth`]), the samples file ([`SampleSink`]), and the
//! statistics and series they feed ([`Observers`], the session's observer that runs them in
//! order).

use super::*;
use crate::session::CycleObserver;
use ecsync_master::cyclic::{CycleRecord, Health};
use ecsync_master::driver::CyclicDriver;
use ecsync_sim::Esc;
use ecsync_wire::AlState;

/// `--samples`: one CSV row per recorded cycle.
pub(super) struct SampleSink {
    path: String,
    out: std::io::BufWriter<std::fs::File>,
    line: String,
    failed: Option<String>,
}

impl SampleSink {
    /// The file at `path` with its header: one margin column per DC slave, the controller's
    /// columns if the method has a log.
    pub(super) fn create(
        path: &Path,
        dc_slaves: &[usize],
        controller: bool,
    ) -> Result<Self, RunError> {
        let p = path.display().to_string();
        let file = std::fs::File::create(path).map_err(|err| RunError::Samples {
            path: p.clone(),
            err,
        })?;
        let mut line = String::from(
            "cycle,lost,true_phase_ns,m_rs_ns,rs_is_ns,slave_spread_ns,worst_margin_ns,worst_slave,late",
        );
        for x in dc_slaves {
            let _ = write!(line, ",margin_{x}_ns");
        }
        if controller {
            line.push_str(",set_value_ns,ctl_error_ns,ctl_filtered_error_ns,ctl_adjustment_ns,ctl_drift_ppm,ctl_valid,ctl_in_sync");
        }
        let mut sink = SampleSink {
            path: p,
            out: std::io::BufWriter::with_capacity(1 << 16, file),
            line,
            failed: None,
        };
        sink.write_line();
        Ok(sink)
    }

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

    /// A recorded cycle whose frame did not come back and cannot be judged (it never reached
    /// the segment, or there was no grid to judge it by).
    fn lost(&mut self, k: u64) {
        let _ = write!(self.line, "{k},1");
        self.write_line();
    }

    /// A recorded cycle without a grid to judge it by: the master's own figures only.
    fn without_grid(&mut self, k: u64, rec: &CycleRecord) {
        let _ = write!(self.line, "{k},0,,");
        if let Some(m) = rec.m_rs_ns {
            let _ = write!(self.line, "{m}");
        }
        self.line.push(',');
        if let Some(v) = rec.rs_is_ns {
            let _ = write!(self.line, "{v}");
        }
        self.write_line();
    }

    /// A recorded cycle judged against the ground truth (`lost`: its reply did not come back
    /// in time, yet the frame passed the slaves); `margins` per DC slave.
    fn judged(&mut self, k: u64, lost: bool, rec: &CycleRecord, t: &CycleTruth, margins: &[f64]) {
        let l = &mut self.line;
        let _ = write!(l, "{k},{},", u8::from(lost));
        if let Some(phase) = t.phase {
            let _ = write!(l, "{phase:.3}");
        }
        l.push(',');
        if let Some(m) = rec.m_rs_ns {
            let _ = write!(l, "{m}");
        }
        l.push(',');
        if let Some(v) = rec.rs_is_ns {
            let _ = write!(l, "{v}");
        }
        l.push(',');
        if let Some(v) = t.spread {
            let _ = write!(l, "{v:.3}");
        }
        if t.worst_margin.is_finite() {
            let _ = write!(
                l,
                ",{:.3},{},{}",
                t.worst_margin,
                t.worst_slave,
                u8::from(t.late())
            );
        } else {
            l.push_str(",,,0");
        }
        for m in margins {
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
        self.write_line();
    }

    /// Flushed: what went wrong writing it, if anything did.
    pub(super) fn finish(mut self) -> Option<String> {
        if self.failed.is_none()
            && let Err(e) = self.out.flush()
        {
            self.failed = Some(format!("{}: {e}", self.path));
        }
        self.failed
    }
}

/// The faults of a run as the cycles meet them: a window of cycles around each, the cycles
/// it held, lost or skipped, and what the re-lock is judged from at the end.
#[derive(Default)]
pub(super) struct FaultWatch {
    truth: FaultsTruth,
    /// Per fault over: its kind and real time (the re-lock is timed from there).
    relock: Vec<Relock>,
    /// Per cycle of the cyclic phase, what its re-lock is judged from.
    lock_samples: Vec<LockSample>,
    /// Fault events already looked at.
    events_seen: usize,
}

impl FaultWatch {
    /// One cycle of the cyclic phase (warm-up included: faults count from its start).
    fn observe(&mut self, tr: &SimTransport, rep: &CycleReport, expected_wkc: u16, pdi_len: u32) {
        let rec = &rep.record;
        let ft = &mut self.truth;
        let sent_ps = tr.last_exchange().sent_ps;
        if let Some(p) = tr.faults() {
            // The way back is timed from the moment a fault is over: the end of one with a
            // window (the slave on again, the cable in), the start of one without (a step, a
            // stall, loss to the end of the run).
            for e in &p.events()[self.events_seen..] {
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
                // A hot connect is not a disturbance the master comes back from: it counts
                // the new slaves and leaves them out, so there is no re-lock to time.
                let judged = !matches!(f.kind, FaultKind::HotConnect { .. });
                if judged && (e.edge == Edge::End) == windowed {
                    self.relock.push(Relock {
                        kind: e.kind,
                        start_ps: e.t_ps,
                    });
                }
            }
            self.events_seen = p.events().len();
        }
        for w in ft.windows.iter_mut().filter(|w| sent_ps < w.until_ps) {
            let v = match (rec.receive, rec.rs_is_ns) {
                (Some(_), Some(v)) => v as f32,
                _ => f32::NAN,
            };
            let t = (sent_ps.saturating_sub(w.start_ps)) as f64 / 1e9;
            w.points.push((t as f32, v, rec.reference_held));
        }
        ft.skipped_cycles += rep.skipped_before;
        ft.held_cycles += u64::from(rec.reference_held);
        // Running: came back, the reference's time believed (a reset slave's register reads
        // small before anyone writes it a time), every slave's process data there. Whether it
        // is locked is judged at the end, against the bands the method holds outside the
        // faults.
        let running = match (rec.receive, rec.rs_is_ns) {
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
        self.lock_samples.push(LockSample {
            sent_ps,
            rs_is_ns: match (rec.receive, rec.rs_is_ns) {
                (Some(_), Some(v)) => v as f32,
                (Some(_), None) => f32::INFINITY,
                (None, _) => f32::NAN,
            },
            m_rs_ns: rec.m_rs_ns.map_or(f32::NAN, |m| m as f32),
            running,
        });
    }

    /// A recorded cycle whose frame came after some drive's SYNC0.
    fn late_frame(&mut self, tr: &SimTransport) {
        let sent_ps = tr.last_exchange().sent_ps;
        let ft = &mut self.truth;
        ft.late_in_windows += u64::from(
            ft.windows
                .iter()
                .any(|w| sent_ps >= w.start_ps && sent_ps < w.until_ps),
        );
    }

    /// What the faults did, the master saw and the re-lock took, with the player's log, the
    /// driver's counters and recoveries and the engine's health; times after the cyclic
    /// phase's start `t0` (master time, ns).
    pub(super) fn finish(
        self,
        tr: &SimTransport,
        driver: &CyclicDriver,
        health: &Health,
        t0: u64,
    ) -> FaultsTruth {
        let mut ft = self.truth;
        if let Some(p) = tr.faults() {
            ft.events = p.events().to_vec();
            ft.counts = p.counts();
        }
        let d = driver.stats();
        ft.master_clock_steps = health.master_clock_steps;
        ft.last_master_step_ns = health.last_master_step_ns;
        ft.late_replies = d.late;
        ft.duplicate_replies = d.duplicates;
        ft.judge_relock(&self.lock_samples, &self.relock);
        let ms = |t: u64| t.saturating_sub(t0) as f64 / 1e6;
        ft.recoveries = driver
            .recoveries()
            .iter()
            .map(|e| RecoveryOut {
                start_ms: ms(e.started.as_ns()),
                end_ms: e.ended.map(MasterInstant::as_ns).map(ms),
                slaves: e.slaves_brought_back(),
                error: e.error(),
                appeared: e.appeared(),
                left_op: e.left_op(),
            })
            .collect();
        ft
    }
}

/// One recorded cycle against the segment's truth.
pub(super) struct CycleTruth {
    /// The reference's system time at the frame's arrival after its grid point, ns; `None`
    /// when the cycle's first frame, which carries the reference's time, did not reach the
    /// segment (a cycle of several frames: the others' drives are judged all the same).
    phase: Option<f64>,
    /// The largest difference of a slave's system time from the reference's (every 8th
    /// cycle), ns.
    spread: Option<f64>,
    /// The smallest margin of the frame's outputs before a slave's SYNC0 (infinite: no slave
    /// judged), ns, and that slave's position.
    worst_margin: f64,
    worst_slave: u16,
}

impl CycleTruth {
    /// Some slave's outputs came after its SYNC0.
    fn late(&self) -> bool {
        self.worst_margin < 0.0
    }
}

/// The segment's ground truth of a run: the reference's grid and each DC slave's deadline.
pub(super) struct GroundTruth {
    reference: usize,
    /// Slaves with a DC unit (SYNC0), by position.
    pub(super) dc_slaves: Vec<usize>,
    /// Per DC slave: the frame of a cycle that carries its outputs, and that frame's wire time.
    out_frames: Vec<(usize, u64)>,
    period_ns: u64,
    shift_ns: f64,
    target_ns: i64,
    /// Find the grid point anew each cycle (with faults: a method that lost the reference for
    /// a while may come back a few periods off its count).
    regrid: bool,
    /// The grid point of the first recorded frame, that frame's recorded cycle, and the
    /// grid's base (the reference's SYNC0 start less the shift, modulo the cycle).
    grid0: Option<(u64, i64, u64)>,
    /// Grid points the master's schedule left out (positive) or aimed at twice (negative)
    /// since the first recorded frame: added to the count of its cycles (without faults).
    grid_shift: i64,
    /// Recorded cycles whose start the master put more than half a cycle from a whole number
    /// of periods after the last one's: two frames for one SYNC0 cycle, or none for one
    /// (ethercrab's snap sends again at once when its frame reached the reference just before
    /// the grid point). The frames after it aim at the grid point that schedule leads to.
    pub(super) grid_slips: u64,
    /// The last recorded cycle and its scheduled start on the master's clock, ns.
    last_scheduled: Option<(u64, u64)>,
    /// The last judged cycle's grid point (system time, ns) and its recorded cycle: a cycle
    /// whose first frame was lost on its way out has its grid point a period per cycle on.
    last_grid: Option<(u64, u64)>,
    /// This cycle's margin per DC slave (NaN: none), for the samples.
    pub(super) margins: Vec<f64>,
    /// Per DC slave: the first SYNC0 pulse after its last outputs (`SlaveTruth::
    /// last_outputs_ns`), ns: the pulses since then counted without a division in most cycles.
    next_pulse_ns: Vec<u64>,
    /// Per DC slave: the drive's (power-ups, exits from OP) when last judged (`count_drive`).
    drive_marks: Vec<Option<(u32, u32)>>,
    /// The init frames' drift: the reference's time against the master's clock.
    pub(super) init_fit: LineFit,
    pub(super) init_frames: u64,
}

/// How [`GroundTruth`] is set up.
pub(super) struct GridSpec {
    pub(super) reference: usize,
    pub(super) dc_slaves: Vec<usize>,
    pub(super) out_frames: Vec<(usize, u64)>,
    pub(super) period_ns: u64,
    pub(super) shift_ns: f64,
    pub(super) target_ns: i64,
    pub(super) regrid: bool,
    pub(super) init_frames: u64,
}

/// The SYNC0 pulses at m x period + `shift_ns` up to outputs at system time `outputs_ns`:
/// those between two frames' outputs but the first found none new (`st.sync0_missed`);
/// `next_pulse` is the first pulse after the last outputs.
fn count_pulses(
    st: &mut SlaveTruth,
    next_pulse: &mut u64,
    outputs_ns: u64,
    shift_ns: u64,
    period: u64,
) {
    match st.last_outputs_ns.replace(outputs_ns) {
        // Pulses in (prev, e]: none before the next pulse, one up to a period after it (a
        // division only for more), none when the time went back (a clock step).
        Some(prev) if outputs_ns >= prev => {
            let n = if outputs_ns < *next_pulse {
                0
            } else if outputs_ns - *next_pulse < period {
                1
            } else {
                (outputs_ns - *next_pulse) / period + 1
            };
            *next_pulse += n * period;
            st.sync0_missed += n.saturating_sub(1);
        }
        // The first pulse after the outputs.
        _ if outputs_ns < shift_ns => *next_pulse = shift_ns,
        _ => *next_pulse = shift_ns + ((outputs_ns - shift_ns) / period + 1) * period,
    }
}

/// One DC slave's count of missed SYNC0 pulses at outputs at system time `outputs_ns` (see
/// [`count_pulses`]) as ETG.1020 has a drive count them, and the drive's own count beside it.
/// The drive counts in OP only: a counting sequence ends where it left OP (the simulator's
/// truth of that instant: its last outputs, or its watchdog's expiry when they stopped
/// coming), and starts again with the first outputs back in OP; a power cycle restarts its
/// counter from 0, so its own count is compared from there (`sync0_missed_at_restart`).
/// `seen`: the drive's (power-ups, exits from OP) when last looked at.
#[inline]
fn count_drive(
    st: &mut SlaveTruth,
    next_pulse: &mut u64,
    seen: &mut Option<(u32, u32)>,
    esc: &Esc,
    outputs_ns: u64,
    shift_ns: u64,
    period: u64,
) {
    let marks = esc.sync_sequence_marks();
    let in_op = esc.al_state() == AlState::Op;
    if in_op && *seen == Some(marks) {
        // The common cycle: in OP, neither powered up nor out of OP since the last look.
        count_pulses(st, next_pulse, outputs_ns, shift_ns, period);
    } else {
        count_drive_changed(
            st, next_pulse, seen, esc, marks, in_op, outputs_ns, shift_ns, period,
        );
    }
    if esc.runs_on_sync0() {
        let now = esc.sm_events_missed();
        let start = *st.drive_count_at_start.get_or_insert(now);
        st.drive_sm_events_missed = Some(now.saturating_sub(start));
        st.on_sync1 = esc.runs_on_sync1();
    }
}

/// [`count_drive`] where the drive left OP, was powered up again, is not in OP, or is looked
/// at for the first time (`marks`: its power-ups and exits from OP now).
#[cold]
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn count_drive_changed(
    st: &mut SlaveTruth,
    next_pulse: &mut u64,
    seen: &mut Option<(u32, u32)>,
    esc: &Esc,
    marks: (u32, u32),
    in_op: bool,
    outputs_ns: u64,
    shift_ns: u64,
    period: u64,
) {
    let changed = seen.replace(marks).filter(|&m| m != marks);
    match changed {
        None if in_op => count_pulses(st, next_pulse, outputs_ns, shift_ns, period),
        None => st.last_outputs_ns = None,
        Some((power_ups, _)) if power_ups != marks.0 => {
            // Powered off and on: nothing counted in between, the drive's count from 0.
            st.last_outputs_ns = None;
            if st.drive_count_at_start.is_some() {
                st.drive_restarts += 1;
                st.drive_count_at_start = Some(0);
                st.drive_sm_events_missed = Some(0);
                st.sync0_missed_at_restart = st.sync0_missed;
            }
            if in_op {
                count_pulses(st, next_pulse, outputs_ns, shift_ns, period);
            }
        }
        Some(_) => {
            // It left OP since the last look: the pulses up to then (these outputs' if it took
            // them before it left), none after.
            let left = esc.left_op_ns();
            count_pulses(st, next_pulse, left.min(outputs_ns), shift_ns, period);
            st.last_outputs_ns = None;
            if in_op {
                count_pulses(st, next_pulse, outputs_ns, shift_ns, period);
            }
        }
    }
}

impl GroundTruth {
    pub(super) fn new(g: GridSpec) -> Self {
        let n_dc = g.dc_slaves.len();
        GroundTruth {
            reference: g.reference,
            dc_slaves: g.dc_slaves,
            out_frames: g.out_frames,
            period_ns: g.period_ns,
            shift_ns: g.shift_ns,
            target_ns: g.target_ns,
            regrid: g.regrid,
            grid0: None,
            grid_shift: 0,
            grid_slips: 0,
            last_scheduled: None,
            last_grid: None,
            margins: Vec::with_capacity(n_dc),
            next_pulse_ns: vec![0; n_dc],
            drive_marks: vec![None; n_dc],
            init_fit: LineFit::default(),
            init_frames: g.init_frames,
        }
    }

    /// Recorded cycle `k`, scheduled at `scheduled_ns` on the master's clock: a start more
    /// than half a cycle off a whole number of periods after the last recorded cycle's
    /// (skipped cycles count as periods) moves the grid point this and the later frames aim
    /// at by the periods it is off.
    fn schedule(&mut self, k: u64, scheduled_ns: u64) {
        if self.regrid {
            // (Found anew each cycle: a fault may move the master's clock or cut cycles.)
            return;
        }
        if let Some((k_last, s_last)) = self.last_scheduled.replace((k, scheduled_ns)) {
            let p = self.period_ns as i64;
            let expected = (k.wrapping_sub(k_last) as i64).wrapping_mul(p);
            let off = (scheduled_ns.wrapping_sub(s_last) as i64).wrapping_sub(expected);
            if off.abs() > p / 2 {
                let periods = (off + off.signum() * p / 2) / p;
                self.grid_shift += periods;
                self.grid_slips += periods.unsigned_abs();
            }
        }
    }

    /// A warm-up cycle: while the method averages its init frames, how the reference's
    /// system time runs against the master's clock, read at the frame's arrival (the clocks'
    /// truth, free of the host's jitter).
    fn warmup(&mut self, tr: &mut SimTransport, i: u64) {
        // (A frame that never reached the segment has an earlier frame's trace: its reading
        // is of that frame's time, not this cycle's.)
        if i >= self.init_frames || !tr.frame_processed(0) {
            return;
        }
        let reference = self.reference;
        let at = tr.frame_trace(0).pu_ps(reference).and_then(|pu| {
            let dc = tr.segment().esc(reference).dc()?;
            Some((pu, dc.system_time_split(pu)))
        });
        if let Some((pu, r)) = at {
            let m = tr.master_clock_mut().master_ns(pu);
            self.init_fit
                .add(i as f64, (r.0.wrapping_sub(m) as i64) as f64 + r.1);
        }
    }

    /// The grid point recorded cycle `k`'s frames aim at (system time, ns), from the cycle's
    /// first frame at the reference (which reached the segment): with the reference's phase
    /// after it and, every 8th cycle, the slaves' spread. `None`: the reference has no
    /// SYNC0 running (reset, not configured again yet).
    fn reference_grid(&mut self, tr: &SimTransport, k: u64) -> Option<(u64, f64, Option<f64>)> {
        let (reference, period, shift, target) = (
            self.reference,
            self.period_ns,
            self.shift_ns,
            self.target_ns,
        );
        let p = period as f64;
        let seg = tr.segment();
        let sys = |slave: usize, t_ps: u64| seg.esc(slave).dc().map(|d| d.system_time_split(t_ps));
        // Ground truth from the segment: the cycle's first frame at the reference.
        let runs_sync0 = |x: usize| seg.esc(x).dc().is_some_and(|d| d.sync0().is_some());
        let trace = tr.frame_trace(0);
        let r = trace
            .pu_ps(reference)
            .filter(|_| runs_sync0(reference))
            .and_then(|t| sys(reference, t))?;
        // The grid point this frame aims at: the one nearest the target at the first
        // recorded frame, one per cycle from there. With faults, the one nearest the target
        // now: a method that lost the reference for a while (a power cycle) may come back a
        // few periods off its count, and SYNC0 fires every period.
        // The grid points are the reference's SYNC0 pulses less the shift: a cycle apart
        // from its start (a multiple of the cycle plus the shift where the master wrote it on
        // a 64-bit unit, so the base is 0; a 32-bit unit's start is on its 64-bit time line,
        // whose upper half the register does not show).
        let base = || {
            seg.esc(reference)
                .dc()
                .and_then(|d| d.sync0())
                .map_or(0, |(s, _)| s.wrapping_sub(shift as u64) % period)
        };
        let nearest = |b: u64| ((r.0 as f64 + r.1 - target as f64 - b as f64) / p).round() as u64;
        let (g0, k0, b0) = *self.grid0.get_or_insert_with(|| {
            let b = base();
            (nearest(b), k as i64, b)
        });
        if k as i64 == k0 {
            self.grid_shift = 0;
        }
        let grid = if self.regrid {
            let b = base();
            nearest(b) * period + b
        } else {
            (g0 + (k as i64 - k0 + self.grid_shift) as u64) * period + b0
        };
        let phase = (r.0.wrapping_sub(grid) as i64) as f64 + r.1;
        // The slaves' differences move slowly (the loops act once per cycle): every 8th
        // cycle is sampled.
        let mut spread = None;
        if k.is_multiple_of(8) {
            let mut worst = 0.0f64;
            for &x in self.dc_slaves.iter() {
                if x == reference || !runs_sync0(x) {
                    continue;
                }
                if let Some(v) = sys(x, trace.pu_ps(reference).unwrap_or(0)) {
                    let d = (v.0.wrapping_sub(r.0) as i64) as f64 + (v.1 - r.1);
                    worst = worst.max(d.abs());
                }
            }
            spread = Some(worst);
        }
        Some((grid, phase, spread))
    }

    /// Recorded cycle `k` against the segment: the reference's phase, the slaves' spread,
    /// each DC slave's margin (into `per_slave`; kept in `margins` if `keep`). `None`: no grid
    /// to judge it by (the reference reset, its SYNC0 not running again yet).
    fn judge(
        &mut self,
        tr: &SimTransport,
        k: u64,
        per_slave: &mut [SlaveTruth],
        keep: bool,
    ) -> Option<CycleTruth> {
        let (period, shift) = (self.period_ns, self.shift_ns);
        let seg = tr.segment();
        let sys = |slave: usize, t_ps: u64| seg.esc(slave).dc().map(|d| d.system_time_split(t_ps));
        // A slave without SYNC0 running (power-cycled, not configured again yet) has no grid
        // and no deadline: it is not counted until it has.
        let runs_sync0 = |x: usize| seg.esc(x).dc().is_some_and(|d| d.sync0().is_some());
        let (grid, phase, spread) = if tr.frame_processed(0) {
            let (grid, phase, spread) = self.reference_grid(tr, k)?;
            (grid, Some(phase), spread)
        } else {
            // The cycle's first frame, which carries the reference's time, did not reach the
            // segment (a frame that never did has an earlier frame's trace). In a cycle of
            // several frames the others did, and their drives took their outputs: they are
            // judged at the grid point the count of cycles gives (with faults: a period per
            // cycle after the last one judged).
            let grid = match self.grid0 {
                Some((g0, k0, b0)) if !self.regrid => {
                    (g0 + (k as i64 - k0 + self.grid_shift) as u64) * period + b0
                }
                _ => {
                    let (k_last, g_last) = self.last_grid?;
                    g_last.wrapping_add((k - k_last).wrapping_mul(period))
                }
            };
            (grid, None, None)
        };
        self.last_grid = Some((k, grid));
        let trace = tr.frame_trace(0);
        // The frame has passed a slave when its last bit has: its outputs take effect after
        // the FCS check, and SYNC0 needs them by then.
        let mut worst_margin = f64::INFINITY;
        let mut worst_slave = 0u16;
        self.margins.clear();
        for ((((st, &x), &(k, out_wire_ps)), next_pulse), seen) in per_slave
            .iter_mut()
            .zip(self.dc_slaves.iter())
            .zip(self.out_frames.iter())
            .zip(self.next_pulse_ns.iter_mut())
            .zip(self.drive_marks.iter_mut())
        {
            let pu = if !runs_sync0(x) || !tr.frame_processed(k) {
                None
            } else if k == 0 {
                trace.pu_ps(x)
            } else {
                tr.frame_trace(k).pu_ps(x)
            };
            // (The reading the drive took there for its SYNC0 check, else a new one.)
            let esc = seg.esc(x);
            let Some(e) = pu
                .map(|pu| pu + out_wire_ps)
                .and_then(|t| esc.system_time_at_outputs(t).or_else(|| sys(x, t)))
            else {
                if keep {
                    self.margins.push(f64::NAN);
                }
                continue;
            };
            let end_after_grid = (e.0.wrapping_sub(grid) as i64) as f64 + e.1;
            let margin = shift - end_after_grid;
            count_drive(st, next_pulse, seen, esc, e.0, shift as u64, period);
            if keep {
                self.margins.push(margin);
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
        Some(CycleTruth {
            phase,
            spread,
            worst_margin,
            worst_slave,
        })
    }
}

/// The run's observers in the order each cycle meets them, and the statistics and series
/// they feed (the session's [`CycleObserver`]).
pub(super) struct Observers {
    pub(super) res: RunResult,
    /// M-rS, rS-IS and the true phase, per block of recorded cycles.
    pub(super) series: [Bands; 3],
    pub(super) truth: GroundTruth,
    pub(super) faults: Option<FaultWatch>,
    pub(super) samples: Option<SampleSink>,
    was_in_sync: bool,
    warmup: u64,
    total: u64,
    expected_wkc: u16,
    pdi_len: u32,
    /// The cycle's frames back to back on the wire, ps.
    cycle_wire_ps: u64,
}

impl Observers {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        res: RunResult,
        cycles: u64,
        truth: GroundTruth,
        faults: bool,
        warmup: u64,
        expected_wkc: u16,
        pdi_len: u32,
        cycle_wire_ps: u64,
    ) -> Self {
        Observers {
            res,
            series: [Bands::new(cycles), Bands::new(cycles), Bands::new(cycles)],
            truth,
            faults: faults.then(FaultWatch::default),
            samples: None,
            was_in_sync: false,
            warmup,
            total: warmup + cycles,
            expected_wkc,
            pdi_len,
            cycle_wire_ps,
        }
    }

    /// The controller's log of a recorded cycle (DCM): in sync, losses, what it learnt.
    fn controller(&mut self, rec: &CycleRecord) {
        if let (Some(c), Some(t)) = (rec.log, self.res.controller.as_mut()) {
            t.cycles_run += 1;
            if c.in_sync {
                t.in_sync_cycles += 1;
            } else if self.was_in_sync {
                t.sync_losses += 1;
            }
            if !c.valid && rec.receive.is_some() {
                t.invalid_errors += 1;
            }
            t.in_sync_at_end = c.in_sync;
            t.drift_ppm_at_end = c.drift_ppm;
            self.was_in_sync = c.in_sync;
        }
    }

    /// Why a cycle past the run's end came after a skip: the slots skipped, and the
    /// schedule's host fault played last (the one this cycle's wake-up played).
    fn stopped(&self, tr: &SimTransport, rep: &CycleReport) -> RecordingStopped {
        let last_host_fault = tr.faults().and_then(|p| {
            (p.events().iter().rev())
                .filter(|e| e.edge == Edge::Start)
                .find_map(|e| match p.schedule().faults.get(e.fault)?.kind {
                    FaultKind::ClockStep { step_ns } => Some(StopCause::ClockStep {
                        fault: e.fault,
                        step_ns,
                        at_ns: e.since_epoch_ns,
                    }),
                    FaultKind::HostStall { stall_ns } => Some(StopCause::HostStall {
                        fault: e.fault,
                        stall_ns,
                        at_ns: e.since_epoch_ns,
                    }),
                    _ => None,
                })
        });
        RecordingStopped {
            run: self.res.run,
            recorded: self.res.cycles_done,
            of: self.total - self.warmup,
            skipped_slots: rep.skipped_before,
            cause: last_host_fault.unwrap_or(StopCause::HostLate),
        }
    }

    /// A recorded cycle: the master's figures, then the ground truth's.
    fn recorded(&mut self, tr: &SimTransport, rec: &CycleRecord, k: u64) {
        self.truth.schedule(k, rec.scheduled.as_ns());
        let res = &mut self.res;
        res.cycles_done = k + 1;
        self.controller(rec);
        let res = &mut self.res;
        // A frame the master did not get back (its reply came after the next cycle's start,
        // or a fault lost it on the way back) still passed the slaves it reached: its outputs
        // were taken, early or late, and the ground truth judges it. Only a frame that never
        // reached the segment (dropped by the host, lost on the way out) is not judged; in a
        // cycle of several frames, the others still are.
        let lost = rec.receive.is_none();
        if lost {
            res.lost_frames += 1;
            res.late_or_lost_frames += 1;
        } else if rec.lrw_wkc != Some(self.expected_wkc) && self.pdi_len > 0 {
            res.bad_wkc += 1;
        }
        if !lost || tr.frame_processed(0) {
            if let Some(m) = rec.m_rs_ns {
                res.m_rs.add(m as f64);
                self.series[0].add(k, m as f64);
            }
            if let Some(v) = rec.rs_is_ns {
                res.rs_is.add(f64::from(v));
                self.series[1].add(k, f64::from(v));
            }
        }
        let keep = self.samples.is_some();
        let judged = self
            .truth
            .judge(tr, k, &mut res.per_slave, keep)
            .filter(|t| t.phase.is_some() || t.worst_margin.is_finite());
        let Some(t) = judged else {
            // No grid, or none of the cycle's frames reached a slave it judges.
            if let Some(sk) = self.samples.as_mut() {
                if lost {
                    sk.lost(k);
                } else {
                    sk.without_grid(k, rec);
                }
            }
            return;
        };
        if let Some(phase) = t.phase {
            let target = self.truth.target_ns;
            res.phase.add(phase);
            res.phase_error.add(phase - target as f64);
            self.series[2].add(k, phase);
        }
        if let Some(worst) = t.spread {
            res.slave_diff.add(worst);
        }
        if t.late()
            && let Some(f) = self.faults.as_mut()
        {
            f.late_frame(tr);
        }
        if t.worst_margin.is_finite() {
            res.margin.add(t.worst_margin);
            if t.late() {
                res.late_frames += 1;
                res.late_or_lost_frames += u64::from(!lost);
            }
            res.latest_end_ns = res.latest_end_ns.max(self.truth.shift_ns - t.worst_margin);
        }
        if let Some(sk) = self.samples.as_mut() {
            sk.judged(k, lost, rec, &t, &self.truth.margins);
        }
    }
}

impl CycleObserver<SimTransport> for Observers {
    fn on_cycle(&mut self, tr: &mut SimTransport, rep: &CycleReport) {
        let rec = &rep.record;
        let i = rec.cycle;
        if i >= self.total {
            // Only a skip past the end runs a cycle numbered there (the driver runs the
            // cycles asked for, whose numbers the skipped slots moved on): the first says why.
            if self.res.recording_stopped.is_none() {
                self.res.recording_stopped = Some(self.stopped(tr, rep));
            }
            return;
        }
        if let Some(f) = self.faults.as_mut() {
            // Faults are judged over the whole cyclic phase (their times count from its
            // start): DC held, and how soon it came back after each fault.
            f.observe(tr, rep, self.expected_wkc, self.pdi_len);
        }
        if let (Some(c), Some(t)) = (rec.log, self.res.controller.as_mut())
            && c.in_sync
            && t.first_in_sync_cycle.is_none()
        {
            t.first_in_sync_cycle = Some(i);
        }
        if i < self.warmup {
            self.truth.warmup(tr, i);
            return;
        }
        // From the wire to the reply, late replies included (a reply that came after its
        // deadline still says how long the frame needs).
        if let Some(back) = tr.last_exchange().received_ps {
            let sent = tr.real_ps_at(rep.stamp);
            let rt = back.saturating_sub(sent) as f64 / 1000.0;
            let holding = tr.faults().and_then(holding_fault);
            if rt > self.res.max_round_trip_ns {
                self.res.max_round_trip_ns = rt;
                self.res.longest_frame_fault = holding;
            }
            if holding.is_none() {
                self.res.max_round_trip_unfaulted_ns = self.res.max_round_trip_unfaulted_ns.max(rt);
            }
        }
        self.res.frame_wire_ns = self.cycle_wire_ps as f64 / 1000.0;
        self.recorded(tr, rec, i - self.warmup);
    }
}

/// The first fault whose window is open that holds replies back (`delay`, `second_responder`):
/// a frame's long way then is the fault's.
fn holding_fault(p: &ecsync_sim::fault::FaultPlayer) -> Option<usize> {
    use ecsync_sim::fault::FaultKind;
    (p.schedule().faults.iter().enumerate()).find_map(|(f, x)| {
        let holds = matches!(
            x.kind,
            FaultKind::Delay { .. } | FaultKind::SecondResponder { .. }
        );
        (holds && p.is_active(f)).then_some(f)
    })
}
