//! The verdict: which methods are ranked, the ranking by its keys, and why, in words.

use super::noise::{Difference, paired};
use super::{MethodOut, NotRanked, us};
use ecsync_sim::send::SendMode;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A method that lost more than this share of its frames with no fault scheduled is not
/// ranked: its figures are those of the few frames that came back, and whatever made it
/// lose them (a cycle too short for the network, a reply timeout) is the finding.
pub const UNRANKED_LOST_SHARE: f64 = 0.1;

/// For the pick's method, each send mode's figures against `plain`'s (`None` with one mode).
pub(super) fn send_note(
    methods: &BTreeMap<String, MethodOut>,
    order: &[String],
    pick: Option<&String>,
) -> Option<String> {
    let pick = methods.get(pick?)?.entry.kind;
    let same: Vec<&String> = order
        .iter()
        .filter(|m| methods.get(*m).is_some_and(|mo| mo.entry.kind == pick))
        .collect();
    if same.len() < 2 {
        return None;
    }
    let base = pick.name();
    let mut t = format!("Send modes with {base}: ");
    let parts: Vec<String> = same
        .iter()
        .map(|m| {
            let mo = &methods[*m];
            let g = &mo.ground_truth;
            let mode = mo.send.as_ref().map_or("plain".to_string(), |s| s.mode.to_string());
            let cost = match &mo.send {
                Some(s) if s.mode == SendMode::Spin => {
                    format!(", {:.1} % of a core spun", s.spin_cpu_pct)
                }
                Some(s) if s.mode == SendMode::Txtime => {
                    format!(", {} launch times missed (frames dropped)", s.launch_misses)
                }
                Some(s) if s.mode == SendMode::Hwstamp => {
                    format!(
                        ", the method's M-rS std {:.3} us (t_ms from the NIC's stamp)",
                        mo.m_rs_pooled.std / 1e3
                    )
                }
                _ => String::new(),
            };
            format!(
                "{mode}: true phase RMS {} about the target, p99.9 {}, smallest safe shift {:.1} %, {} late frames{cost}",
                us(g.phase_error.rms),
                us(g.phase_error.p999_abs),
                g.smallest_safe_shift_pct,
                g.late_frames
            )
        })
        .collect();
    t.push_str(&parts.join("; "));
    t.push_str(". What a mode buys is the send jitter after the method's decision (j_s, and j_c with txtime), which no method can filter: the phase spread and the shift it needs shrink by it.");
    if same
        .iter()
        .any(|m| methods[*m].entry.send == SendMode::Hwstamp)
    {
        t.push_str(" A hardware transmit stamp buys a truer measurement, not a truer send: j_c leaves the method's t_ms, j_s still moves the frame.");
    }
    Some(t)
}

/// Whether the starts the engine held of `mo` (some) are no more than the cycle slots the
/// schedule's clock steps moved the master's time by: while a step is not yet detected, a
/// method asks for starts on the old time (a slot of the step each), which the engine holds;
/// an unstable controller holds every cycle from its start on.
pub(crate) fn held_for_clock_steps(mo: &MethodOut) -> bool {
    let steps: u32 = mo.faults.iter().map(|f| f.master_clock_steps).sum();
    let slots: u64 = mo.faults.iter().map(|f| f.clock_step_slots).sum();
    mo.wild_schedule_cycles > 0 && steps > 0 && mo.wild_schedule_cycles <= slots
}

/// The methods the verdict cannot judge (see [`UNRANKED_LOST_SHARE`]).
pub(super) fn not_ranked(
    methods: &BTreeMap<String, MethodOut>,
    order: &[String],
) -> Vec<NotRanked> {
    order
        .iter()
        .filter_map(|m| {
            let mo = methods.get(m)?;
            // A fault of the host (its clock stepped, its task stalled) puts the schedule out
            // of range for every method: said so, not blamed on the gains.
            let steps: u32 = mo.faults.iter().map(|f| f.master_clock_steps).sum();
            let skipped: u64 = mo.faults.iter().map(|f| f.skipped_cycles).sum();
            if held_for_clock_steps(mo) {
                // The starts a method asks on its clock's old time until the engine takes the
                // step out: the method's answer to the step, ranked (a warning says so).
            } else if mo.wild_schedule_cycles > 0 && (steps > 0 || skipped > 0) {
                let largest_step_ms = mo
                    .faults
                    .iter()
                    .map(|f| f.last_master_step_ns as f64 / 1e6)
                    .fold(0.0f64, |a, b| if b.abs() > a.abs() { b } else { a });
                return Some(NotRanked {
                    method: m.clone(),
                    why: format!(
                        "{m}: the engine held {} of the starts it asked for (more than two cycles away, or before the cycle's own) after the fault schedule moved the master's time ({} step(s) of its clock detected, the last {:+.3} ms; {} cycles skipped by the host): its figures describe the master's clock out of step, not the method at work",
                        mo.wild_schedule_cycles, steps, largest_step_ms, skipped
                    ),
                    lost_frames: false,
                });
            }
            if mo.wild_schedule_cycles > 0 && !held_for_clock_steps(mo) {
                return Some(NotRanked {
                    method: m.clone(),
                    why: format!(
                        "{m} went unstable: in {} it asked for the next start more than two cycles away (or before the cycle's own), which the engine held; its figures describe a broken schedule, not the method at work (smaller gains?)",
                        crate::scenario::plural(mo.wild_schedule_cycles, "cycle", "cycles")
                    ),
                    lost_frames: false,
                });
            }
            if mo.grid_slips > 0 {
                return Some(NotRanked {
                    method: m.clone(),
                    why: format!(
                        "{m} did not keep to one frame per SYNC0 cycle: {} times its schedule sent two frames for one grid point or none for one (a cycle started less than half a period after the one before, or more than one and a half: ethercrab's snap sends again at once when its frame reaches the reference just before the grid point); its application runs an uneven cycle, and its frames are judged against the grid point its schedule led to",
                        mo.grid_slips
                    ),
                    lost_frames: false,
                });
            }
            // A controller that never said it was in sync in a recorded cycle: its figures are
            // its pull-in, and where it settles is not in them (with a short warm-up such a
            // method was recommended for the late frames its moving phase happened to miss).
            // Under a fault schedule losing sync is what is measured.
            if let Some(c) = &mo.controller
                && mo.faults.is_empty()
                && c.time_to_sync_ms.is_none()
                && c.in_sync_fraction == 0.0
            {
                return Some(NotRanked {
                    method: m.clone(),
                    why: format!(
                        "{m}'s controller never reported in sync in the recorded cycles: its figures are of its pull-in, not of where it settles; a longer warm-up (--warmup-s, or run.warmup_s in the file) shows that"
                    ),
                    lost_frames: false,
                });
            }
            let lost = mo.ground_truth.lost_frames;
            let share = lost as f64 / mo.cycles_done.max(1) as f64;
            (mo.faults.is_empty() && lost > 0 && share > UNRANKED_LOST_SHARE).then(|| NotRanked {
                method: m.clone(),
                why: if mo.ground_truth.frames_per_cycle > 1 {
                    format!(
                        "{m} lost a frame in {lost} of {} cycles ({:.0} %) with no fault scheduled: the figures of the cycles that came back do not describe it",
                        mo.cycles_done,
                        share * 100.0
                    )
                } else {
                    format!(
                        "{m} lost {lost} of {} frames ({:.0} %) with no fault scheduled: the figures of the frames that came back do not describe it",
                        mo.cycles_done,
                        share * 100.0
                    )
                },
                lost_frames: true,
            })
        })
        .collect()
}

/// The ranking rule when a drive left OP with an AL error under some method (with nothing to
/// separate it is left out of the rule's words: the ranking is [`RANKING_RULE`]'s).
pub const RANKING_RULE_DRIVE_ERRORS: &str = "methods under which no drive left OP with an AL error (a PLL or synchronization error: it stops a machine) first, then fewest cycles with a frame late at a drive or (with no fault scheduled) lost at the configured SYNC0 shift, then holding the target (mean phase within 10 % of the margin), then the smallest SYNC0 shift without a late frame (in steps of 0.5 % of the cycle above the best), then the smallest slave spread p99.9 (in steps of 10 % of the best, at least 2 ns), then the smallest p99.9 of |true phase - target|; a difference the runs do not confirm (each run's difference between the two methods, which meet the same noise, against its 95 % interval) is reported as within run-to-run noise";

/// The ranking rule, in words.
pub const RANKING_RULE: &str = "fewest cycles with a frame late at a drive or (with no fault scheduled) lost at the configured SYNC0 shift, then holding the target (mean phase within 10 % of the margin), then the smallest SYNC0 shift without a late frame (in steps of 0.5 % of the cycle above the best), then the smallest slave spread p99.9 (in steps of 10 % of the best, at least 2 ns), then the smallest p99.9 of |true phase - target|; a difference the runs do not confirm (each run's difference between the two methods, which meet the same noise, against its 95 % interval) is reported as within run-to-run noise";

/// The ranking's first key: the cycles whose drives kept the outputs before (a frame late at
/// one) or whose exchange failed (a frame lost: dropped by the host, on the wire, or its reply
/// too late). With a fault schedule only the late ones: the faults' losses are the schedule's,
/// the same for every method, and what a method does about them is judged by the re-lock.
pub(super) fn failed_cycles(m: &MethodOut) -> u64 {
    if m.faults.is_empty() {
        m.ground_truth.late_or_lost_frames
    } else {
        m.ground_truth.late_frames
    }
}

/// The ranking keys of a method (smaller is better), NaN last.
fn keys(m: &MethodOut) -> [f64; 5] {
    let g = &m.ground_truth;
    let nan_last = |x: f64| if x.is_nan() { f64::INFINITY } else { x };
    [
        failed_cycles(m) as f64,
        if g.holds_target { 0.0 } else { 1.0 },
        nan_last(g.smallest_safe_shift_pct),
        nan_last(g.slave_ref_diff.p999_abs),
        nan_last(g.phase_error.p999_abs),
    ]
}

/// Differences of the smallest safe shift below this many % of the cycle are noise: the
/// shift comes from the latest frame of millions, which moves by microseconds between seeds.
pub const SHIFT_TIE_PCT: f64 = 0.5;
/// Differences of the slave spread's p99.9 below this share of the best (and 2 ns) are noise.
pub const SPREAD_TIE: f64 = 0.1;

/// The keys as compared: the shift and the spread in steps of their noise above the best
/// method's (a strict comparison of maxima over millions of cycles would rank noise).
fn ranked_keys(methods: &BTreeMap<String, MethodOut>, names: &[&String]) -> Vec<[f64; 5]> {
    let raw: Vec<[f64; 5]> = names.iter().map(|m| keys(&methods[*m])).collect();
    let best = |i: usize| raw.iter().map(|k| k[i]).fold(f64::INFINITY, f64::min);
    let (b2, b3) = (best(2), best(3));
    let spread_step = (SPREAD_TIE * b3).max(2.0);
    raw.iter()
        .map(|k| {
            let mut k = *k;
            if k[2].is_finite() && b2.is_finite() {
                k[2] = ((k[2] - b2) / SHIFT_TIE_PCT).floor();
            }
            if k[3].is_finite() && b3.is_finite() {
                k[3] = ((k[3] - b3) / spread_step).floor();
            }
            k
        })
        .collect()
}

/// The methods of `order` that ran, best first by their compared keys.
pub(super) fn rank(methods: &BTreeMap<String, MethodOut>, order: &[String]) -> Vec<String> {
    let names: Vec<&String> = order.iter().filter(|m| methods.contains_key(*m)).collect();
    let keys = ranked_keys(methods, &names);
    let mut idx: Vec<usize> = (0..names.len()).collect();
    // A stable sort keeps the report order among exact ties.
    idx.sort_by(|&a, &b| {
        keys[a]
            .iter()
            .zip(keys[b].iter())
            .map(|(x, y)| x.total_cmp(y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    // Drives that left OP with an error stop a machine: such methods go after the others,
    // in the keys' order among themselves (a stable sort).
    idx.sort_by_key(|&i| drive_errors(&methods[names[i]]) > 0);
    idx.into_iter().map(|i| names[i].clone()).collect()
}

/// How often a drive left OP with an AL error (a code other than 0) under the method, with no
/// fault scheduled: a PLL error (0x0032) of a reference pushed by bus shift, a synchronization
/// error (0x001A) of late frames. (With a fault schedule, drives that leave OP are the faults'
/// doing, which every method meets alike: the warnings list them, the ranking does not count
/// them, as it does not count the frames the faults lose.)
pub(super) fn drive_errors(m: &MethodOut) -> usize {
    if !m.faults.is_empty() {
        return 0;
    }
    m.left_op.iter().filter(|l| l.al_status_code != 0).count()
}

/// The distinct AL codes of the method's drive errors, as the summary words them.
fn drive_error_codes(m: &MethodOut) -> String {
    let mut codes: Vec<&str> = Vec::new();
    for l in m.left_op.iter().filter(|l| l.al_status_code != 0) {
        if !codes.contains(&l.reason.as_str()) {
            codes.push(&l.reason);
        }
    }
    codes.join(", ")
}

/// The pick's `late` and `lost` frames at the `s_pct` % shift, in words: none, or the fewest of
/// any method and what to do about them.
/// (`others_lost`: some method lost frames, so "the fewest" counts both.)
fn failed_exchanges(
    (late, lost): (u64, u64),
    s_pct: f64,
    no_shift_holds: bool,
    others_lost: bool,
) -> String {
    let raise = if no_shift_holds {
        "no shift holds them"
    } else {
        "raise the shift"
    };
    match (late, lost) {
        (0, 0) => format!("no frame reached a drive after its SYNC0 at the {s_pct} % shift"),
        (late, 0) if !others_lost => format!(
            "it had the fewest late frames at the {s_pct} % shift ({late}; every method had some: {raise})"
        ),
        (0, lost) => format!(
            "no frame reached a drive after its SYNC0 at the {s_pct} % shift, but {lost} of its frames were lost (every method had late or lost frames; the warnings say why they were lost)"
        ),
        (late, lost) => format!(
            "it had the fewest late or lost frames at the {s_pct} % shift ({late} late, {lost} lost; every method had some: {raise}, and the warnings say why frames were lost)"
        ),
    }
}

/// Why the pick, in words: its figures at the `s_pct` % shift, whether it holds its target,
/// the key it beats the next one on, the methods off their target, its rS-IS spread.
pub(super) fn reason(
    methods: &BTreeMap<String, MethodOut>,
    ranking: &[String],
    s_pct: f64,
) -> String {
    let Some(pick) = ranking.first() else {
        return "no method ran".into();
    };
    let p = &methods[pick];
    let g = &p.ground_truth;
    let mut r = String::new();
    // Past the whole cycle no shift helps: the cycle must grow.
    let no_shift_holds = g.smallest_safe_shift_pct >= 100.0;
    // (Under a fault schedule the losses are the faults': the key counts late frames only.)
    let lost_of = |m: &MethodOut| {
        if m.faults.is_empty() {
            m.ground_truth.lost_frames
        } else {
            0
        }
    };
    let others_lost = methods.values().any(|m| lost_of(m) > 0);
    let late = failed_exchanges(
        (g.late_frames, lost_of(p)),
        s_pct,
        no_shift_holds,
        others_lost,
    );
    let needs = if no_shift_holds {
        format!("{};", shift_needed(g.smallest_safe_shift_pct))
    } else {
        format!("{} at least,", shift_needed(g.smallest_safe_shift_pct))
    };
    let _ = write!(
        r,
        "{pick}: {late}; it needs a SYNC0 shift of {needs} its frames reach the reference {} from the target on average and within {} of it in 99.9 % of cycles, and the drives stay within {:.0} ns of the reference (p99.9).",
        us(g.offset_from_target_ns),
        us(g.phase_error.p999_abs),
        g.slave_ref_diff.p999_abs
    );
    if !g.holds_target && g.phase.n > 0 {
        let _ = write!(
            r,
            " It does not hold its target: its frames sit {} {} it, which is what {} here; on a network whose crystals drift the other way they would sit as far on the other side.",
            us(g.offset_from_target_ns.abs()),
            if g.offset_from_target_ns < 0.0 {
                "before"
            } else {
                "after"
            },
            if g.offset_from_target_ns < 0.0 {
                "keeps them clear of SYNC0"
            } else {
                "the shift has to make up for"
            }
        );
    }
    if drive_errors(p) > 0 {
        let _ = write!(
            r,
            " Under it too drives left OP with an AL error ({}, {} times; see the warnings): every method here had some.",
            drive_error_codes(p),
            drive_errors(p)
        );
    }
    match ranking.get(1) {
        Some(second) if drive_errors(&methods[second]) > 0 && drive_errors(p) == 0 => {
            let q = &methods[second];
            let _ = write!(
                r,
                " Next is {second}, under which drives left OP with an AL error ({}, {} times; see the warnings).",
                drive_error_codes(q),
                drive_errors(q)
            );
        }
        Some(second) => second_note(&mut r, methods, ranking, pick, second),
        None => {}
    }
    let failing: Vec<&str> = ranking
        .iter()
        .skip(2)
        .filter(|m| drive_errors(&methods[*m]) > 0 && drive_errors(p) == 0)
        .map(|m| m.as_str())
        .collect();
    if !failing.is_empty() {
        let n = failing.len();
        let list = match failing.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
            _ => failing.join(""),
        };
        let _ = write!(
            r,
            " Under {list} drives left OP with an AL error (see the warnings): {} ranked after the methods under which none did.",
            if n == 1 { "it is" } else { "they are" }
        );
    }
    let off: Vec<&str> = ranking
        .iter()
        .filter(|m| *m != pick)
        .filter(|m| !methods[*m].ground_truth.holds_target && methods[*m].ground_truth.phase.n > 0)
        .map(|m| m.as_str())
        .collect();
    if !off.is_empty() {
        let _ = write!(
            r,
            " {} {} not hold {} target on this network (see the warnings) and {} ranked after the methods that do, late or lost frames permitting.",
            off.join(", "),
            if off.len() == 1 { "does" } else { "do" },
            if off.len() == 1 { "its" } else { "their" },
            if off.len() == 1 { "is" } else { "are" }
        );
    }
    let dropped: Vec<&str> = ranking
        .iter()
        .filter(|m| *m != pick && lost_of(&methods[*m]) > 0)
        .map(|m| m.as_str())
        .collect();
    if lost_of(p) == 0 && !dropped.is_empty() {
        let one = dropped.len() == 1;
        let _ = write!(
            r,
            " {} lost frames (see the warnings): a lost frame leaves the drives' outputs as a late one does, and {} ranked by the two together.",
            dropped.join(", "),
            if one { "it is" } else { "they are" }
        );
    }
    if p.rs_is.std > 0.0 {
        let best_rs = ranking
            .iter()
            .map(|m| methods[m].rs_is.std)
            .fold(f64::INFINITY, f64::min);
        if p.rs_is.std > 5.0 * best_rs {
            let _ = write!(
                r,
                " Its rS-IS spread (the drives' own 0x092C, {:.0} ns) is more than five times the best one's ({:.0} ns).",
                p.rs_is.std, best_rs
            );
        }
    }
    r
}

/// What the ranking's keys say of `b` against `a`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Versus {
    /// Key `i` separates them beyond run-to-run noise (`None`: holding the target, a yes or
    /// no).
    Decided(usize, Option<Difference>),
    /// Key `i` separates them, and with one run nobody can tell whether by more than noise.
    Unmeasured(usize),
    /// Every key the ranking separates them on is within run-to-run noise.
    WithinNoise,
    /// Equal on every key, to the ranking's steps.
    Equal,
}

/// `b` against `a`: the first key, in the ranking's order, on which their compared values
/// differ beyond run-to-run noise; keys whose difference the runs do not confirm are passed.
/// Keys are compared as the ranking compares them, in steps above the best of `ranking`.
pub(super) fn versus(
    methods: &BTreeMap<String, MethodOut>,
    ranking: &[String],
    a: usize,
    b: usize,
) -> Versus {
    let names: Vec<&String> = ranking.iter().collect();
    let compared = ranked_keys(methods, &names);
    let (ma, mb) = (&methods[names[a]], &methods[names[b]]);
    let mut noise = false;
    let separating = compared[a]
        .iter()
        .zip(&compared[b])
        .enumerate()
        .filter(|(_, (x, y))| x != y)
        .map(|(i, _)| i);
    for i in separating {
        if i == 1 {
            return Versus::Decided(1, None);
        }
        match paired(ma, mb, i) {
            Some(d) if d.significant() => return Versus::Decided(i, Some(d)),
            Some(_) => noise = true,
            None => return Versus::Unmeasured(i),
        }
    }
    if noise {
        Versus::WithinNoise
    } else {
        Versus::Equal
    }
}

/// The keys' names, in the ranking's order.
const KEY_NAMES: [&str; 5] = [
    "late or lost frames",
    "holding its target",
    "the smallest safe SYNC0 shift",
    "the slave spread",
    "the true phase's deviation from the target",
];

/// Key `i`'s name for method `m` (under a fault schedule the first counts late frames only).
fn key_name(i: usize, m: &MethodOut) -> &'static str {
    if i == 0 && !m.faults.is_empty() {
        "late frames"
    } else {
        KEY_NAMES[i]
    }
}

/// Key `i`'s value `v` of method `m` in words, with `fine` digits where the coarse ones would
/// print two different values alike.
fn key_text(i: usize, v: f64, m: &MethodOut, fine: bool) -> String {
    match (i, fine) {
        (0, _) => format!("{v:.0}"),
        (1, _) => format!(
            "it sits {} from the target",
            us(m.ground_truth.offset_from_target_ns)
        ),
        (2, false) => format!("{v:.1} %"),
        (2, true) => format!("{v:.2} %"),
        (3, false) => format!("{v:.0} ns"),
        (3, true) => format!("{v:.1} ns"),
        (_, false) => us(v),
        (_, true) => format!("{v:.0} ns"),
    }
}

/// The sentence on the runner-up `second` against the pick: the key that separates them and
/// whether the runs confirm it, or that they are within run-to-run noise (and which other
/// methods are too).
fn second_note(
    r: &mut String,
    methods: &BTreeMap<String, MethodOut>,
    ranking: &[String],
    pick: &String,
    second: &String,
) {
    let (p, q) = (&methods[pick], &methods[second]);
    let (ka, kb) = (keys(p), keys(q));
    let runs = p.runs.len().min(q.runs.len());
    let vs = versus(methods, ranking, 0, 1);
    let both = |i: usize| {
        let coarse = (key_text(i, kb[i], q, false), key_text(i, ka[i], p, false));
        if coarse.0 == coarse.1 {
            (key_text(i, kb[i], q, true), key_text(i, ka[i], p, true))
        } else {
            coarse
        }
    };
    match vs {
        Versus::Decided(1, _) => {
            let _ = write!(
                r,
                " Next is {second}, which does not hold its target: {}.",
                key_text(1, kb[1], q, false)
            );
        }
        Versus::Decided(i, d) => {
            let (b, a) = both(i);
            let _ = write!(
                r,
                " Next is {second}, which loses on {}: {b} against {a}",
                key_name(i, p)
            );
            if let Some(d) = d {
                let _ = write!(
                    r,
                    ", more than run-to-run noise (the runs' differences {} +- {} at 95 %, {} runs)",
                    key_text(i, d.mean.abs(), p, true),
                    key_text(i, d.half_width, p, true),
                    d.runs
                );
            }
            r.push('.');
        }
        Versus::Unmeasured(i) => {
            let (b, a) = both(i);
            let _ = write!(
                r,
                " Next is {second}, which loses on {}: {b} against {a}; with {} nobody can tell whether that is more than run-to-run noise (run --runs 3 or more).",
                key_name(i, p),
                crate::scenario::plural(runs as u64, "run", "runs")
            );
        }
        Versus::WithinNoise => {
            let _ = write!(
                r,
                " It and {second} are within run-to-run noise of each other on every key ({runs} runs): choose either; the order between them is that of figures the runs do not confirm."
            );
        }
        Versus::Equal => {
            let _ = write!(r, " {second} ties with it on every key.");
        }
    }
    let also: Vec<&str> = within_noise(methods, ranking)
        .into_iter()
        .filter(|m| *m != second)
        .map(String::as_str)
        .collect();
    if !also.is_empty() {
        let _ = write!(
            r,
            " Within run-to-run noise of it as well: {}.",
            also.join(", ")
        );
    }
}

/// The ranked methods after the pick that are within run-to-run noise of it (or equal).
pub(super) fn within_noise<'a>(
    methods: &BTreeMap<String, MethodOut>,
    ranking: &'a [String],
) -> Vec<&'a String> {
    if ranking.is_empty() {
        return Vec::new();
    }
    let pick_errors = drive_errors(&methods[&ranking[0]]) > 0;
    (1..ranking.len())
        .filter(|&k| (drive_errors(&methods[&ranking[k]]) > 0) == pick_errors)
        .filter(|&k| {
            matches!(
                versus(methods, ranking, 0, k),
                Versus::WithinNoise | Versus::Equal
            )
        })
        .map(|k| &ranking[k])
        .collect()
}

/// The smallest safe shift as the text says it: past the whole cycle no shift holds the
/// frames (SYNC0 would have to come a cycle later than the grid point they aim at).
pub(super) fn shift_needed(pct: f64) -> String {
    if pct >= 100.0 {
        format!(
            "{pct:.1} %, more than the whole cycle: no SYNC0 shift holds its frames on this host (a longer cycle can)"
        )
    } else {
        format!("{pct:.1} %")
    }
}
