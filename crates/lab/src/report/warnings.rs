//! The warnings: the figures at risk, each kind in a step of its own.

use super::{MethodOut, Warning, us};
use crate::compare::Comparison;
use crate::run::{RecordingStopped, StopCause};
use crate::scenario::Scenario;
use ecsync_dc::MethodKind;
use ecsync_sim::fault::{FaultKind, FaultSchedule, KindName};
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
    w.extend(ran().flat_map(|(m, mo)| mo.recording_stopped.iter().map(|r| stopped(m, r))));
    w.extend(few_cycles(methods));
    w.extend(crystal_difference(s, methods, budget_ns));
    for (m, mo) in ran().filter(|(_, mo)| mo.ground_truth.phase.n > 0) {
        w.extend(off_target(m, mo, budget_ns));
        w.extend(late_frames(s, m, mo, budget_ns));
    }
    w.extend(settling(c, methods, budget_ns));
    w.extend(cycle_too_short(c));
    w.extend(ran().filter_map(|(m, mo)| lost_frames(m, mo, s.faults.as_ref())));
    // Drives that left OP on their own (with a fault schedule the faults' table and
    // faults.csv tell what the faults did to whom).
    if s.faults.is_none() {
        w.extend(ran().filter_map(|(m, mo)| left_op(m, mo)));
    }
    w.extend(ran().filter_map(|(m, mo)| no_relock(m, mo)));
    w.extend(ran().filter_map(|(m, mo)| held_for_steps(m, mo)));
    w.extend(not_played(s, methods));
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

/// A run whose recording stopped before its last cycle: where, of how many, and why.
fn stopped(m: &str, r: &RecordingStopped) -> Warning {
    let at = |ns: u64| format!("{:.3} s", ns as f64 / 1e9);
    let why = match r.cause {
        StopCause::ClockStep {
            fault,
            step_ns,
            at_ns,
        } => format!(
            "fault[{fault}] (clock_step) stepped the master's clock {:+.3} ms at {}, and its task, waking on that clock, skipped the {} cycle slots the step jumped over",
            step_ns as f64 / 1e6,
            at(at_ns),
            r.skipped_slots
        ),
        StopCause::HostStall {
            fault,
            stall_ns,
            at_ns,
        } => format!(
            "fault[{fault}] (host_stall) held the master's task {:.3} ms at {}, and it skipped the {} cycle slots that passed",
            stall_ns as f64 / 1e6,
            at(at_ns),
            r.skipped_slots
        ),
        StopCause::HostLate => format!(
            "the master's task woke {} cycle slots late and skipped them",
            r.skipped_slots
        ),
    };
    Warning {
        kind: "recording_stopped",
        method: Some(m.to_string()),
        message: format!(
            "{m}: recording stopped at cycle {} of {} (run {}): {why}, past the run's last (its cycles count in the master's slots); the figures are of the {} cycles recorded before",
            r.recorded, r.of, r.run, r.recorded
        ),
    }
}

/// Starts the engine held while the master's clock stepped (see
/// [`super::verdict::held_for_clock_steps`]): the method is ranked with them, and says so.
fn held_for_steps(m: &str, mo: &MethodOut) -> Option<Warning> {
    if !super::verdict::held_for_clock_steps(mo) {
        return None;
    }
    let slots: u64 = mo.faults.iter().map(|f| f.clock_step_slots).sum();
    let steps: u32 = mo.faults.iter().map(|f| f.master_clock_steps).sum();
    Some(Warning {
        kind: "held_for_clock_steps",
        method: Some(m.to_string()),
        message: format!(
            "{m}: the engine held {} of the starts it asked for (more than two cycles away, or before the cycle's own) while the master's clock stepped ({} detected; the steps moved its time by {slots} cycle slots): the method asked on the clock's old time until the engine took the step out; it is ranked with the figures of those cycles",
            mo.wild_schedule_cycles,
            crate::scenario::plural(u64::from(steps), "step", "steps"),
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
        (Some(d), MethodKind::Median | MethodKind::PiM2s) if plain => {
            // The method holds where its init frames were on average: the drift's part, and
            // the host's send jitter in them (its mean past the first frame's aim: +12.6 us
            // on the loaded host at 250 us, +1.2 on the idle one, where the drift was -1.1).
            let rest = off - d.offset_ns;
            let jitter = if rest.abs() >= 1000.0 && rest.abs() >= 0.1 * off.abs() {
                format!(", the host's send jitter in them for the other {}", us(rest))
            } else {
                String::new()
            };
            format!(
                " (the drift over its {} init frames accounts for {}{jitter}: it holds where they were on average)",
                d.frames,
                us(d.offset_ns)
            )
        }
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

/// How a run's recording began, from its true phase's bands: the cycles at its start whose
/// blocks reach outside where every later block stays (beyond a quarter of that range), and
/// the farthest phase in them, ns; `None` when the first block is within.
///
/// A method whose init ends as the warm-up does starts the recording where its init frames
/// left the phase and pulls in from there: median-fit on lan9252-pair with the preset's
/// former 10 s warm-up began 90 us off its target and took some 300 cycles at its gain of
/// 0.01, and that start alone set its max and its smallest safe shift (12.9 % against 7.2 %).
/// The last nine tenths of the blocks are the reference, so a transient shorter than a tenth
/// of the run is found and a method that settles nowhere is not.
pub(super) fn start_transient(bands: &[crate::run::Band]) -> Option<(u64, f64)> {
    let n = bands.len();
    if n < 20 {
        return None;
    }
    let rest = &bands[n / 10..];
    let hi = rest.iter().map(|b| b.p99).fold(f32::NEG_INFINITY, f32::max);
    let lo = rest.iter().map(|b| b.p01).fold(f32::INFINITY, f32::min);
    let slack = 0.25 * (hi - lo);
    let outside = |b: &&crate::run::Band| b.p99 > hi + slack || b.p01 < lo - slack;
    let lead = bands[..n / 10].iter().take_while(outside).count();
    if lead == 0 {
        return None;
    }
    let far = bands[..lead]
        .iter()
        .flat_map(|b| [b.min, b.max])
        .max_by(|a, b| {
            let d = |v: f32| (v - hi).max(lo - v);
            d(*a).total_cmp(&d(*b))
        })?;
    Some((bands[lead].cycle, f64::from(far)))
}

/// A method still settling when the recording began: a controller (DCM) that first reported
/// in sync after the warm-up, in its slowest run, or one whose phase started outside where it
/// stayed later (see [`start_transient`]), in the run whose start took longest. The figures
/// that take extremes, and with a controller the others too, hold its approach.
fn settling(c: &Comparison, methods: &BTreeMap<String, MethodOut>, budget_ns: f64) -> Vec<Warning> {
    let s = &c.scenario;
    // Faults move the phase on purpose.
    if s.faults.is_some() {
        return Vec::new();
    }
    let period_s = f64::from(s.cycle_ns) * 1e-9;
    let warmup_s = s.warmup_cycles as f64 * period_s;
    let mut w = Vec::new();
    for (e, runs) in s.entries().iter().zip(&c.results) {
        let m = e.name();
        let Some(mo) = methods.get(&m) else { continue };
        if let Some(ctl) = &mo.controller {
            let firsts: Vec<Option<u64>> = runs
                .iter()
                .filter_map(|r| r.controller.map(|t| t.first_in_sync_cycle))
                .collect();
            let pulling_in = match firsts.iter().copied().collect::<Option<Vec<u64>>>() {
                // Never in sync and off its target: off_target says it.
                None if mo.ground_truth.offset_from_target_ns.abs() > 0.1 * budget_ns => None,
                None => Some(format!(
                    "{m}'s controller never reported in sync in {}: its figures are of its pull-in; a longer warm-up (--warmup-s, or run.warmup_s in the file: now {warmup_s:.0} s) shows where it settles",
                    if ctl.in_sync_fraction > 0.0 { "some runs" } else { "the recorded cycles" }
                )),
                Some(f) => f.into_iter().max().filter(|&k| k > s.warmup_cycles).map(|k| {
                    let t = k as f64 * period_s;
                    format!(
                        "{m}'s controller first reported in sync {t:.1} s into the cyclic phase (its slowest run), after the {warmup_s:.0} s warm-up: its figures hold its pull-in ({:.1} % of the recorded cycles in sync); a warm-up of {:.0} s (--warmup-s, or run.warmup_s in the file) leaves it out",
                        ctl.in_sync_fraction * 100.0,
                        (t * 1.1).ceil()
                    )
                }),
            };
            if let Some(message) = pulling_in {
                w.push(Warning {
                    kind: "settling",
                    method: Some(m.clone()),
                    message,
                });
                continue;
            }
        }
        let Some((cycles, far_ns)) = runs
            .iter()
            .filter_map(|r| start_transient(&r.series[2]))
            .max_by_key(|t| t.0)
        else {
            continue;
        };
        // Twice what the transient took, in whole seconds.
        let more_s = (2.0 * cycles as f64 * period_s).ceil().max(1.0);
        w.push(Warning {
            kind: "settling",
            method: Some(m.clone()),
            message: format!(
                "{m} was still settling when the recording began: in its first {cycles} cycles the frames reached the reference up to {} from the target, beyond anything later, and its extremes, smallest safe shift and least SYNC0 margin hold that start; a warm-up {more_s:.0} s longer (--warmup-s, or run.warmup_s in the file: now {warmup_s:.0} s) leaves it out",
                us(far_ns - s.target_phase_ns as f64),
            ),
        });
    }
    w
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
                "{m}: {} cycles had a frame after SYNC0 at the {} % shift; it needs {}",
                g.late_frames,
                s.sync0_shift_pct,
                super::verdict::shift_needed(g.smallest_safe_shift_pct)
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
/// to the last one's reply, in any run; or, when only frames inside the window of a fault that
/// holds replies back took that long, the fault (the cycle is not to blame).
fn cycle_too_short(c: &Comparison) -> Option<Warning> {
    let period = f64::from(c.scenario.cycle_ns);
    let runs = || c.results.iter().flatten();
    let trip = runs()
        .map(|r| r.max_round_trip_unfaulted_ns)
        .fold(0.0, f64::max);
    let wire = runs().map(|r| r.frame_wire_ns).fold(0.0, f64::max);
    if wire > period || trip > period {
        return Some(Warning {
            kind: "cycle_too_short",
            method: None,
            message: format!(
                "the cycle's frames take {} on the wire and up to {} from the first one's send to the last one's reply, more than the {} cycle: frames overlap cycles (make the cycle longer)",
                us(wire),
                us(trip),
                us(period)
            ),
        });
    }
    // The longest frame of all, inside a fault's window.
    let longest = runs()
        .filter(|r| r.longest_frame_fault.is_some())
        .max_by(|a, b| a.max_round_trip_ns.total_cmp(&b.max_round_trip_ns))?;
    let f = longest.longest_frame_fault?;
    let kind = c.scenario.faults.as_ref()?.faults.get(f)?.kind;
    let what = match kind {
        FaultKind::Delay { extra_ns } => format!("its delay of {}", us(extra_ns as f64)),
        FaultKind::SecondResponder { lag_ns } => {
            format!("its second reply {} later", us(lag_ns as f64))
        }
        _ => "it".to_string(),
    };
    (longest.max_round_trip_ns > period).then(|| Warning {
        kind: "fault_long_frames",
        method: None,
        message: format!(
            "frames took up to {} from the first one's send to the last one's reply, more than the {} cycle, inside the window of fault[{f}] ({}): the fault did it ({what}), not the cycle; outside its window they take up to {}",
            us(longest.max_round_trip_ns),
            us(period),
            kind.name(),
            us(trip)
        ),
    })
}

/// A method that lost frames, with the likeliest cause: txtime's missed launch times, the
/// reply timeout, or the faults of the schedule `faults` that lose frames.
fn lost_frames(m: &str, mo: &MethodOut, faults: Option<&FaultSchedule>) -> Option<Warning> {
    let lost = mo.ground_truth.lost_frames;
    if lost == 0 {
        return None;
    }
    let timeout = "their replies came after the reply timeout (half a cycle, or the cycle's frames' way back if longer) or the next cycle's start, whichever was first, or not at all; a frame whose reply was late still passed the drives, and the ground truth judges it with the others";
    let late: u64 = mo.faults.iter().map(|f| f.late_replies).sum();
    let cause = faults
        .filter(|_| !mo.faults.is_empty())
        .map(|f| losing_faults(f, late));
    let g = &mo.ground_truth;
    let lost_of = if g.frames_per_cycle > 1 {
        format!(
            "{lost} of {} recorded cycles lost one or more of their {} frames",
            mo.cycles_done, g.frames_per_cycle
        )
    } else {
        format!("{lost} of {} recorded frames were lost", mo.cycles_done)
    };
    Some(Warning {
        kind: "lost_frames",
        method: Some(m.to_string()),
        message: if let Some(s) = mo.send.as_ref().filter(|s| s.launch_misses > 0) {
            format!(
                "{m}: {lost_of}, {} of them handed to the kernel after their launch time (the host's jitter beyond the txtime lead: raise [send] txtime_lead_us)",
                s.launch_misses
            )
        } else if let Some(Some(cause)) = cause {
            format!("{m}: {lost_of} ({cause})")
        } else if let Some(None) = cause {
            format!("{m}: {lost_of}: {timeout} (no fault of the schedule drops frames)")
        } else {
            format!("{m}: {lost_of}: {timeout}")
        },
    })
}

/// The faults of `schedule` that lose frames, in words ("the fault schedule's loss, and the
/// cycles its power cycles and cable pulls cut off"; a delay when `late` replies came after
/// the reply timeout): only the kinds it has; `None` if it has none of them (stalls, clock
/// steps, hot connects, AL errors and second replies lose none, nor a delay within the
/// timeout).
fn losing_faults(schedule: &FaultSchedule, late: u64) -> Option<String> {
    let kinds = |want: fn(&FaultKind) -> bool| schedule.faults.iter().any(|f| want(&f.kind));
    let delays: Vec<u64> = (schedule.faults.iter())
        .filter_map(|f| match f.kind {
            FaultKind::Delay { extra_ns } => Some(extra_ns),
            _ => None,
        })
        .collect();
    let mut dropped = Vec::new();
    if kinds(|k| matches!(k, FaultKind::Loss { .. })) {
        dropped.push("loss".to_string());
    }
    if kinds(|k| matches!(k, FaultKind::Corrupt { .. })) {
        dropped.push("corrupted frames".to_string());
    }
    if let Some(&most) = delays.iter().max().filter(|_| late > 0) {
        dropped.push(format!(
            "{} of {}{}, which held replies past the reply timeout",
            if delays.len() == 1 { "delay" } else { "delays" },
            if delays.len() == 1 { "" } else { "up to " },
            us(most as f64)
        ));
    }
    let mut cut = Vec::new();
    if kinds(|k| matches!(k, FaultKind::PowerCycle { .. })) {
        cut.push("power cycles");
    }
    if kinds(|k| matches!(k, FaultKind::LinkDown { .. })) {
        cut.push("cable pulls");
    }
    let and = |v: &[&str]| match v {
        [] => String::new(),
        [one] => one.to_string(),
        [rest @ .., last] => format!("{} and {last}", rest.join(", ")),
    };
    let dropped: Vec<&str> = dropped.iter().map(String::as_str).collect();
    match (dropped.is_empty(), cut.is_empty()) {
        (true, true) => None,
        (false, true) => Some(format!("the fault schedule's {}", and(&dropped))),
        (true, false) => Some(format!(
            "the cycles the fault schedule's {} cut off",
            and(&cut)
        )),
        (false, false) => Some(format!(
            "the fault schedule's {}, and the cycles its {} cut off",
            and(&dropped),
            and(&cut)
        )),
    }
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

/// The faults of the schedule that started in no run of any method (they come after the
/// run's end): nothing of theirs is measured, their re-lock is "-".
fn not_played(s: &Scenario, methods: &BTreeMap<String, MethodOut>) -> Option<Warning> {
    let sched = s.faults.as_ref()?;
    let ran = methods.values().any(|mo| !mo.faults.is_empty());
    let started = |n: usize| {
        methods.values().any(|mo| {
            (mo.faults.iter().flat_map(|f| &f.events))
                .any(|e| e.fault == n && e.edge == ecsync_sim::fault::Edge::Start)
        })
    };
    let never: Vec<String> = (sched.faults.iter().enumerate())
        .filter(|(n, _)| !started(*n))
        .map(|(n, f)| {
            format!(
                "fault[{n}] ({} at {} s)",
                f.kind.name(),
                f.at_ns as f64 / 1e9
            )
        })
        .collect();
    (ran && !never.is_empty()).then(|| Warning {
        kind: "fault_not_played",
        method: None,
        message: format!(
            "{} started in no run: the runs ended first ({} s of warm-up and recorded cycles{}), so nothing of theirs is measured (their re-lock: -)",
            never.join(", "),
            (s.warmup_cycles + s.cycles) as f64 * f64::from(s.cycle_ns) / 1e9,
            if sched.epoch == ecsync_sim::fault::Epoch::Start {
                " after the bring-up"
            } else {
                ""
            }
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

#[cfg(test)]
mod tests {
    #[test]
    fn a_shift_past_the_cycle_is_said_to_hold_nothing() {
        use crate::report::verdict::shift_needed;
        assert_eq!(shift_needed(72.4), "72.4 %");
        let past = shift_needed(116.3);
        assert!(
            past.starts_with("116.3 %, more than the whole cycle"),
            "{past}"
        );
        assert!(shift_needed(100.0).contains("no SYNC0 shift holds"));
    }

    use super::start_transient;
    use crate::run::Band;

    /// Bands of 100 cycles around `mid` ns, +-20 us at p01/p99, +-30 us at the extremes.
    fn bands(mids: &[f32]) -> Vec<Band> {
        mids.iter()
            .enumerate()
            .map(|(i, &m)| Band {
                cycle: 100 * i as u64,
                n: 100,
                min: m - 30_000.0,
                p01: m - 20_000.0,
                p50: m,
                p99: m + 20_000.0,
                max: m + 30_000.0,
            })
            .collect()
    }

    #[test]
    fn a_start_outside_the_later_blocks_by_hand() {
        // Steady at 0: the band of the later blocks is -20..20 us, a quarter of it 10 us.
        let mut mids = vec![0.0f32; 100];
        assert_eq!(start_transient(&bands(&mids)), None);
        // 90, 60, 40 and 15 us up at the start are outside (p99 110, 80, 60 and 35 us against
        // 20 + 10), 5 us up is within (p99 25 us): the start is the first 400 cycles, and the
        // farthest phase in it block 0's max.
        mids[..5].copy_from_slice(&[90_000.0, 60_000.0, 40_000.0, 15_000.0, 5_000.0]);
        assert_eq!(start_transient(&bands(&mids)), Some((400, 120_000.0)));
        // Below: the farthest is the minimum.
        let low: Vec<f32> = mids.iter().map(|m| -m).collect();
        assert_eq!(start_transient(&bands(&low)), Some((400, -120_000.0)));
        // A phase that moves over the whole run has no start apart from the rest.
        let ramp: Vec<f32> = (0..20).map(|i| 90_000.0 - 4_500.0 * i as f32).collect();
        assert_eq!(start_transient(&bands(&ramp)), None);
        // Fewer than 20 blocks: nothing said.
        assert_eq!(start_transient(&bands(&mids[..19])), None);
    }
}
