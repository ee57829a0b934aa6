//! The warnings: the figures at risk, each kind in a step of its own.

use super::{MethodOut, Warning, us};
use crate::compare::Comparison;
use crate::scenario::Scenario;
use ecsync_dc::MethodKind;
use ecsync_sim::fault::KindName;
use ecsync_sim::send::SendMode;
use std::collections::BTreeMap;

/// Every warning of a comparison, in the report's order: the comparison's (interrupted, the
/// crystals), each method's phase, the cycle, then each method's lost frames, drives out of
/// OP, faults it did not come back from, and the samples that could not be written.
pub(super) fn warnings(
    c: &Comparison,
    methods: &BTreeMap<String, MethodOut>,
    order: &[String],
    budget_ns: f64,
) -> Vec<Warning> {
    let s = &c.scenario;
    // The methods that ran, in the report's order.
    let ran = || order.iter().filter_map(|m| Some((m, methods.get(m)?)));
    let mut w = Vec::new();
    w.extend(interrupted(c, methods));
    w.extend(few_cycles(methods));
    w.extend(crystal_difference(s, methods, budget_ns));
    for (m, mo) in ran().filter(|(_, mo)| mo.ground_truth.phase.n > 0) {
        w.extend(off_target(m, mo, budget_ns));
        w.extend(late_frames(s, m, mo, budget_ns));
    }
    w.extend(cycle_too_short(c));
    w.extend(ran().filter_map(|(m, mo)| lost_frames(m, mo)));
    // Drives that left OP on their own (with a fault schedule the faults' table and
    // faults.csv tell what the faults did to whom).
    if s.faults.is_none() {
        w.extend(ran().filter_map(|(m, mo)| left_op(m, mo)));
    }
    w.extend(ran().filter_map(|(m, mo)| no_relock(m, mo)));
    w.extend(hot_connected(methods));
    w.extend(samples(c));
    w
}

/// A comparison stopped before the end: its figures are of the cycles done.
fn interrupted(c: &Comparison, methods: &BTreeMap<String, MethodOut>) -> Option<Warning> {
    let s = &c.scenario;
    if !c.interrupted {
        return None;
    }
    let done: u64 = methods.values().map(|m| m.cycles_done).sum();
    Some(Warning {
        kind: "interrupted",
        method: None,
        message: format!(
            "interrupted: the figures are of the {done} recorded cycles done, not of the {} asked for",
            s.cycles * u64::from(s.runs) * methods.len() as u64
        ),
    })
}

/// Fewer measured cycles than put ten samples beyond a p99.9: the percentiles quoted are of
/// the largest few samples (below [`super::noise::MIN_RANKED_CYCLES`] nothing is ranked).
fn few_cycles(methods: &BTreeMap<String, MethodOut>) -> Option<Warning> {
    let n = methods.values().map(|m| m.cycles_done).min()?;
    if n >= super::noise::FEW_CYCLES {
        return None;
    }
    let beyond = n as f64 * 0.001;
    Some(Warning {
        kind: "few_cycles",
        method: None,
        message: format!(
            "too few cycles: {n} measured per method (the fewest) leave {beyond:.1} samples beyond each p99.9 (ten need {}), so the p99.9 figures and the smallest safe shifts are those of the largest few frames and {}; run --cycles {} or more per run",
            super::noise::FEW_CYCLES,
            if n < super::noise::MIN_RANKED_CYCLES {
                "the verdict ranks nothing"
            } else {
                "the ranking's last keys are uncertain"
            },
            super::noise::FEW_CYCLES
        ),
    })
}

/// The master's and the reference's crystals differ by so much that the drift over the init
/// frames moves the letter's averaging methods off their target by more than 10 % of the
/// margin.
fn crystal_difference(
    s: &Scenario,
    methods: &BTreeMap<String, MethodOut>,
    budget_ns: f64,
) -> Option<Warning> {
    let period = f64::from(s.cycle_ns);
    // The crystals: the reference is the first slave with a system time.
    let reference_ppm = s
        .slaves
        .iter()
        .find(|x| x.model.dc.has_system_time())
        .map(|x| x.crystal.ppm)?;
    let init_methods: Vec<MethodKind> = s
        .methods
        .iter()
        .copied()
        .filter(|m| {
            matches!(m, MethodKind::Median | MethodKind::PiM2s) && methods.contains_key(m.name())
        })
        .collect();
    if init_methods.is_empty() {
        return None;
    }
    let d_ppm = reference_ppm - s.host.master_ppm;
    let n = init_methods
        .iter()
        .map(|&m| s.init_frames(m))
        .max()
        .unwrap_or(0);
    let expected = d_ppm.abs() * 1e-6 * period * n as f64 / 2.0;
    (expected > 0.1 * budget_ns).then(|| Warning {
        kind: "crystal_difference",
        method: None,
        message: format!(
            "the master's crystal and the reference's differ by {:.1} ppm: over {n} init frames the frames drift {}, and {} set their point where the frames were on average, about {} from where they were aimed ({:.0} % of the {} margin); median-fit fits the drift and holds its target (the master's crystal is [host] master_ppm in the file, or --master-ppm)",
            d_ppm.abs(),
            us(d_ppm.abs() * 1e-6 * period * n as f64),
            init_methods
                .iter()
                .map(|m| m.name())
                .collect::<Vec<_>>()
                .join(" and "),
            us(expected),
            expected / budget_ns * 100.0,
            us(budget_ns)
        ),
    })
}

/// A method whose mean phase sits off its target by more than 10 % of the margin, with what
/// explains it where something does.
fn off_target(m: &str, mo: &MethodOut, budget_ns: f64) -> Option<Warning> {
    let off = mo.ground_truth.offset_from_target_ns;
    if off.abs() <= 0.1 * budget_ns {
        return None;
    }
    // The init drift explains a plain send's offset; under another send mode the
    // mode's own lead dominates it, and the drift's part would read as the reason.
    let plain = mo.entry.send == SendMode::Plain;
    let why = match (&mo.init_drift, mo.entry.kind) {
        (Some(d), MethodKind::Median | MethodKind::PiM2s) if plain => format!(
            " (the drift over its {} init frames accounts for {})",
            d.frames,
            us(d.offset_ns)
        ),
        (_, MethodKind::Snap) if plain => " (it counts its wait from the send, so the scheduling jitter and execution time land on the phase)".into(),
        // A controller that says it was still pulling in: the figure is its approach,
        // not where it settles.
        _ => match &mo.controller {
            Some(c) if c.time_to_sync_ms.is_none() => format!(
                " (its controller never reported in sync in {}: still pulling in; a longer warm-up, --warmup-s, shows where it settles)",
                if c.in_sync_fraction > 0.0 { "some runs" } else { "the recorded cycles" }
            ),
            _ => String::new(),
        },
    };
    Some(Warning {
        kind: "off_target",
        method: Some(m.to_string()),
        message: format!(
            "{m} sits {} off its target on average{why}: {:.0} % of the {} margin",
            us(off),
            off.abs() / budget_ns * 100.0,
            us(budget_ns)
        ),
    })
}

/// A method with frames after SYNC0 at the scenario's shift or, short of that, whose
/// p99.9 phase takes more than half of the margin.
fn late_frames(s: &Scenario, m: &str, mo: &MethodOut, budget_ns: f64) -> Option<Warning> {
    let g = &mo.ground_truth;
    if g.late_frames > 0 {
        return Some(Warning {
            kind: "late_frames",
            method: Some(m.to_string()),
            message: format!(
                "{m}: {} cycles had a frame after SYNC0 at the {} % shift; it needs {:.1} %",
                g.late_frames, s.sync0_shift_pct, g.smallest_safe_shift_pct
            ),
        });
    }
    let tail = g.phase.p999 - g.target_phase_ns as f64;
    (tail > 0.5 * budget_ns).then(|| Warning {
        kind: "jitter_eats_margin",
        method: Some(m.to_string()),
        message: format!(
            "{m}: in 0.1 % of cycles the frame reaches the reference more than {} after the target, over half of the {} margin",
            us(tail),
            us(budget_ns)
        ),
    })
}

/// A cycle's frames that take longer than the cycle, on the wire or from the first one's send
/// to the last one's reply, in any run.
fn cycle_too_short(c: &Comparison) -> Option<Warning> {
    let period = f64::from(c.scenario.cycle_ns);
    let trip = c
        .results
        .iter()
        .flatten()
        .map(|r| r.max_round_trip_ns)
        .fold(0.0, f64::max);
    let wire = c
        .results
        .iter()
        .flatten()
        .map(|r| r.frame_wire_ns)
        .fold(0.0, f64::max);
    (wire > period || trip > period).then(|| Warning {
        kind: "cycle_too_short",
        method: None,
        message: format!(
            "the cycle's frames take {} on the wire and up to {} from the first one's send to the last one's reply, more than the {} cycle: frames overlap cycles (make the cycle longer)",
            us(wire),
            us(trip),
            us(period)
        ),
    })
}

/// A method that lost frames, with the likeliest cause: txtime's missed launch times, the
/// reply timeout, or the fault schedule.
fn lost_frames(m: &str, mo: &MethodOut) -> Option<Warning> {
    let lost = mo.ground_truth.lost_frames;
    if lost == 0 {
        return None;
    }
    Some(Warning {
        kind: "lost_frames",
        method: Some(m.to_string()),
        message: if let Some(s) = mo.send.as_ref().filter(|s| s.launch_misses > 0) {
            format!(
                "{m}: {lost} of {} recorded frames were lost, {} of them handed to the kernel after their launch time (the host's jitter beyond the txtime lead: raise [send] txtime_lead_us)",
                mo.cycles_done, s.launch_misses
            )
        } else if mo.faults.is_empty() {
            format!(
                "{m}: {lost} of {} recorded frames were lost: their replies came after the reply timeout (half a cycle, or the cycle's frames' way back if longer) or not at all",
                mo.cycles_done
            )
        } else {
            format!(
                "{m}: {lost} of {} recorded frames were lost (the fault schedule's loss, and the cycles its power cycles and cable pulls cut off)",
                mo.cycles_done
            )
        },
    })
}

/// A method under which drives left OP: per slave and AL status code, how often, the first
/// time, and whether every one came back.
fn left_op(m: &str, mo: &MethodOut) -> Option<Warning> {
    if mo.left_op.is_empty() {
        return None;
    }
    // Per slave and code: how often, the first time, and whether every one came back.
    let mut groups: Vec<(u16, u16, &str, u32, f64, u32, bool)> = Vec::new();
    for l in &mo.left_op {
        match groups
            .iter_mut()
            .find(|g| (g.0, g.1) == (l.slave, l.al_status_code))
        {
            Some(g) => {
                g.3 += 1;
                g.6 &= l.back_in_op_ms.is_some();
            }
            None => groups.push((
                l.slave,
                l.al_status_code,
                &l.reason,
                1,
                l.found_ms,
                l.run,
                l.back_in_op_ms.is_some(),
            )),
        }
    }
    groups.sort_by_key(|g| (g.0, g.1));
    let list: Vec<String> = groups
        .iter()
        .map(|&(slave, _, reason, n, first_ms, run, back)| {
            // The name the scenario gives the slave, where the ground truth has it (drives;
            // its positions count from 0, these from 1 = next to the master).
            let name = mo
                .ground_truth
                .per_slave
                .iter()
                .find(|s| s.position + 1 == slave)
                .map_or(String::new(), |s| format!(" ({})", s.name));
            format!(
                "slave {slave}{name} with AL status code {reason} {}, first at {:.3} s (run {run}){}",
                if n == 1 {
                    "once".to_string()
                } else {
                    format!("{n} times")
                },
                first_ms / 1e3,
                if back {
                    ", brought back each time"
                } else {
                    ", not back in OP by the end"
                }
            )
        })
        .collect();
    Some(Warning {
        kind: "left_op",
        method: Some(m.to_string()),
        message: format!(
            "{m}: drives left OP (the summary's left_op lists each time): {}",
            list.join("; ")
        ),
    })
}

/// A method that did not come back to lock after a fault, in any run.
fn no_relock(m: &str, mo: &MethodOut) -> Option<Warning> {
    let mut never: Vec<String> = Vec::new();
    for (run, f) in mo.faults.iter().enumerate() {
        for (k, ms) in f.relock_ms.iter().enumerate() {
            if ms.is_none() {
                let kind = f.relock_kinds.get(k).map_or("fault", |k| k.as_str());
                never.push(format!("{kind} (run {run})"));
            }
        }
    }
    if never.is_empty() {
        return None;
    }
    never.dedup();
    let band = mo
        .faults
        .iter()
        .map(|f| f.lock_band_092c_ns)
        .fold(0.0f64, f64::max);
    Some(Warning {
        kind: "no_relock",
        method: Some(m.to_string()),
        message: format!(
            "{m} did not come back to lock (|0x092C| under {band:.0} ns and M-rS within its band, the reference believed, every slave's process data, for 100 cycles) after: {}",
            never.join(", ")
        ),
    })
}

/// Slaves hot-connected during the runs: the master counts them but does not take them in,
/// so their unsynchronized clocks are in every BRD of 0x092C from then on (the letter's rS-IS
/// and DC's largest |0x092C|), while the slaves of the bring-up stay synchronized.
fn hot_connected(methods: &BTreeMap<String, MethodOut>) -> Option<Warning> {
    let hot = methods.values().any(|mo| {
        mo.faults
            .iter()
            .any(|f| f.windows.iter().any(|w| w.kind == KindName::HotConnect))
    });
    if !hot {
        return None;
    }
    let spread = methods
        .values()
        .map(|mo| mo.ground_truth.slave_ref_diff.max)
        .filter(|x| x.is_finite())
        .fold(0.0f64, f64::max);
    Some(Warning {
        kind: "hot_connect",
        method: None,
        message: format!(
            "slaves hot-connected during the runs are counted but not taken in (a new bring-up would): their clocks are not synchronized, so from the connect on rS-IS and DC's largest |0x092C| (BRDs of 0x092C, the OR of every slave's) read them, not the method; the slaves of the bring-up stayed within {spread:.0} ns of the reference (ground truth, every method)"
        ),
    })
}

/// The runs whose samples could not be written.
fn samples(c: &Comparison) -> impl Iterator<Item = Warning> + '_ {
    c.results.iter().flatten().filter_map(|r| {
        let e = r.samples_error.as_ref()?;
        Some(Warning {
            kind: "samples",
            method: Some(r.method.clone()),
            message: format!("the samples could not be written: {e}"),
        })
    })
}
