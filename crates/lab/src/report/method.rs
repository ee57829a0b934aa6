//! A method's figures over its runs: the letter's indicators, the ground truth pooled, per
//! slave, the init drift, the controller's own report, the send mode.

use super::{
    ControllerOut, GroundTruth, InitDriftOut, LetterOut, MethodOut, RunKeys, RunOut, SendOut,
    SlaveOut,
};
use crate::compare::Comparison;
use crate::letter;
use crate::run::RunResult;
use crate::stats::{Stats, Summary, mean_of};
use ecsync_sim::send::Entry;

/// One statistic of every run, pooled.
fn pooled(rs: &[RunResult], pick: fn(&RunResult) -> &Stats) -> Stats {
    let mut s = Stats::new();
    for r in rs {
        s.merge(pick(r));
    }
    s
}

/// Shift needed for an end `latest_ns` after the grid point, % of the cycle, rounded up to
/// 0.1 %.
fn shift_pct(latest_ns: f64, period: f64) -> f64 {
    if latest_ns.is_finite() {
        ((latest_ns / period * 1000.0).ceil() / 10.0).max(0.0)
    } else {
        f64::NAN
    }
}

/// Slave `i`'s figures over the runs `rs` (`r0` the first), the cycle `period` ns.
fn slave_out(rs: &[RunResult], r0: &RunResult, i: usize, period: f64) -> SlaveOut {
    let mut st = Stats::new();
    let mut late = 0;
    let mut missed = 0;
    let mut drive: Option<u64> = None;
    let (mut restarts, mut since_restart) = (0, 0);
    let mut latest = f64::NEG_INFINITY;
    let mut on_sync1 = false;
    for r in rs {
        if let Some(x) = r.per_slave.get(i) {
            on_sync1 |= x.on_sync1;
            st.merge(&x.margin);
            late += x.late_frames;
            missed += x.sync0_missed;
            restarts += x.drive_restarts;
            since_restart += x.sync0_missed - x.sync0_missed_at_restart;
            if let Some(d) = x.drive_sm_events_missed {
                drive = Some(drive.unwrap_or(0) + d);
            }
            latest = latest.max(x.latest_end_ns);
        }
    }
    let sm = st.summary();
    SlaveOut {
        position: r0.per_slave[i].position,
        name: r0.per_slave[i].name.clone(),
        margin_min_ns: sm.min,
        margin_p001_ns: sm.p001,
        margin_mean_ns: sm.mean,
        late_frames: late,
        sync0_missed: missed,
        drive_sm_events_missed: drive,
        drive_restarts: restarts,
        sync0_missed_since_drive_restart: (restarts > 0).then_some(since_restart),
        smallest_safe_shift_pct: shift_pct(latest, period),
        on_sync1,
    }
}

/// Method `m`'s figures over its runs (`holds_target` is set by `summarize` once the margin
/// is known).
pub(super) fn method_out(
    c: &Comparison,
    m: usize,
    entry: Entry,
    letter_testbed: bool,
) -> MethodOut {
    let kind = entry.kind;
    let s = &c.scenario;
    let period = f64::from(s.cycle_ns);
    let rs = &c.results[m];
    let sums: Vec<[Summary; 5]> = rs.iter().map(|r| r.summaries()).collect();
    let col = |k: usize| mean_of(&sums.iter().map(|x| x[k]).collect::<Vec<_>>());
    let latest = rs
        .iter()
        .map(|r| r.latest_end_ns)
        .fold(f64::NEG_INFINITY, f64::max);
    let lock: Vec<f64> = rs.iter().filter_map(|r| r.lock_ms).collect();
    let phase = pooled(rs, |r| &r.phase).summary();
    let per_slave = rs
        .first()
        .map(|r0| {
            (0..r0.per_slave.len())
                .map(|i| slave_out(rs, r0, i, period))
                .collect()
        })
        .unwrap_or_default();
    let drifts: Vec<_> = rs.iter().filter_map(|r| r.init_drift).collect();
    let init_drift = (!drifts.is_empty()).then(|| {
        let k = drifts.len() as f64;
        let d = drifts.iter().map(|x| x.drift_ns_per_cycle).sum::<f64>() / k;
        InitDriftOut {
            frames: drifts[0].frames,
            drift_ns_per_cycle: d,
            drift_ppm: d / period * 1e6,
            offset_ns: drifts.iter().map(|x| x.offset_ns).sum::<f64>() / k,
        }
    });
    let ctls: Vec<_> = rs.iter().filter_map(|r| r.controller).collect();
    let controller = (!ctls.is_empty()).then(|| {
        // The recorded slots (a skipped slot moved the cycle numbers on) against the cycles
        // the controller ran: a slot the driver skipped (a host stall, a step of the master's
        // clock) is no cycle the controller was out of sync in, so the share leaves it out.
        let slots: u64 = rs.iter().map(|r| r.cycles_done).sum();
        let run: u64 = ctls.iter().map(|t| t.cycles_run).sum();
        let firsts: Vec<u64> = ctls.iter().filter_map(|t| t.first_in_sync_cycle).collect();
        ControllerOut {
            in_sync_fraction: ctls.iter().map(|t| t.in_sync_cycles).sum::<u64>() as f64
                / run.max(1) as f64,
            cycles_run: run,
            skipped_slots: slots.saturating_sub(run),
            time_to_sync_ms: (firsts.len() == ctls.len())
                .then(|| firsts.iter().sum::<u64>() as f64 / firsts.len() as f64 * period / 1e6),
            sync_losses: ctls.iter().map(|t| t.sync_losses).sum(),
            in_sync_at_end: ctls.iter().all(|t| t.in_sync_at_end),
            invalid_errors: ctls.iter().map(|t| t.invalid_errors).sum(),
            drift_ppm: ctls.iter().map(|t| t.drift_ppm_at_end).sum::<f64>() / ctls.len() as f64,
        }
    });
    MethodOut {
        entry,
        description: kind.summary(),
        letter_name: letter::letter_name(kind),
        m_rs: col(0).into(),
        rs_is: col(1).into(),
        m_rs_pooled: pooled(rs, |r| &r.m_rs).summary(),
        rs_is_pooled: pooled(rs, |r| &r.rs_is).summary(),
        letter: if letter_testbed {
            letter::table1(kind).map(|(m_rs, rs_is)| LetterOut { m_rs, rs_is })
        } else {
            None
        },
        ground_truth: GroundTruth {
            target_phase_ns: s.target_phase_ns,
            offset_from_target_ns: phase.mean - s.target_phase_ns as f64,
            // Set by `summarize` once the margin is known.
            holds_target: true,
            phase_error: pooled(rs, |r| &r.phase_error).summary(),
            phase,
            slave_ref_diff: pooled(rs, |r| &r.slave_diff).summary(),
            sync0_margin: pooled(rs, |r| &r.margin).summary(),
            late_frames: rs.iter().map(|r| r.late_frames).sum(),
            sync0_shift_pct: s.sync0_shift_pct,
            smallest_safe_shift_pct: shift_pct(latest, period),
            per_slave,
            lost_frames: rs.iter().map(|r| r.lost_frames).sum(),
            late_or_lost_frames: rs.iter().map(|r| r.late_or_lost_frames).sum(),
            frames_per_cycle: rs.iter().map(|r| r.frames_per_cycle).max().unwrap_or(1),
            bad_wkc: rs.iter().map(|r| r.bad_wkc).sum(),
        },
        init_drift,
        controller,
        runs: sums
            .iter()
            .zip(rs)
            .map(|(x, r)| RunOut {
                m_rs: x[0].into(),
                rs_is: x[1].into(),
                keys: RunKeys {
                    late_frames: r.late_frames,
                    late_or_lost_frames: r.late_or_lost_frames,
                    smallest_safe_shift_pct: shift_pct(r.latest_end_ns, period),
                    slave_spread_p999_ns: r.slave_diff.summary().p999_abs,
                    phase_error_p999_ns: r.phase_error.summary().p999_abs,
                },
            })
            .collect(),
        cycles_done: rs.iter().map(|r| r.cycles_done).sum(),
        lock_ms: lock.iter().sum::<f64>() / lock.len().max(1) as f64,
        wild_schedule_cycles: rs.iter().map(|r| r.wild_schedule_cycles).sum(),
        grid_slips: rs.iter().map(|r| r.grid_slips).sum(),
        wall_s: c.method_wall_s[m],
        faults: rs.iter().filter_map(|r| r.faults.clone()).collect(),
        left_op: rs.iter().flat_map(|r| r.left_op.iter().cloned()).collect(),
        recording_stopped: rs.iter().filter_map(|r| r.recording_stopped).collect(),
        send: (entry.send != ecsync_sim::send::SendMode::Plain).then(|| {
            let cycles: u64 = rs.iter().map(|r| r.cycles_done).sum();
            SendOut {
                mode: entry.send,
                launch_misses: rs.iter().map(|r| r.launch_misses).sum(),
                spin_cpu_pct: 100.0 * rs.iter().map(|r| r.spin_ns).sum::<f64>()
                    / (cycles.max(1) as f64 * period),
            }
        }),
    }
}
