//! What a comparison writes: summary.json (the verdict first), summary.csv, the terminal's
//! tables, plots and report.html.
//!
//! # The verdict
//!
//! Methods are ranked by, in this order (each key decides only where the ones before tie):
//! 1. late frames at the configured SYNC0 shift (fewer first): a late frame is a cycle whose
//!    outputs some drive did not have at its SYNC0;
//! 2. whether the method holds its target: its mean phase within 10 % of the margin of the
//!    target (holding first). A method off its target sits where the crystals put it, so its
//!    other figures hold on this network only: the letter's `median` settles `d N / 2` away
//!    (early or late, by the sign of the master-to-reference drift `d`), and its frames being
//!    early would otherwise win the next key;
//! 3. the smallest SYNC0 shift without a late frame in any run (smaller first): the margin the
//!    method leaves for the application. It is the latest of millions of frames, which moves
//!    by microseconds from seed to seed, so it is compared in steps of [`SHIFT_TIE_PCT`] of the
//!    cycle above the best method's;
//! 4. the slaves' spread around the reference, p99.9 (smaller first): how well the drives
//!    agree with each other, in steps of [`SPREAD_TIE`] of the best (at least 2 ns);
//! 5. the true phase's deviation from the target, p99.9 of |phase - target| (smaller first).
//!
//! The first is the pick. Warnings are raised where a figure is at risk: a master-to-reference
//! crystal difference whose drift over the init frames moves the letter's methods off their
//! target by more than 10 % of the margin, a method whose mean phase sits off its target by
//! more than 10 % of the margin, jitter that takes more than half of the margin at p99.9 (or
//! late frames), a frame that needs longer than the cycle from its send to its reply.
//! "The margin" is the SYNC0 shift minus the target minus the frame's time from the reference
//! to its end at the worst slave: what is left between a frame on target and SYNC0.

use crate::compare::Comparison;
use crate::letter::{self, Row};
use crate::run::RunResult;
use crate::stats::{QUANTILE_REL_ERROR, RESOLUTION_NS, Stats, Summary, mean_of};
use ecsync_dc::MethodKind;
use ecsync_sim::send::{Entry, SendMode};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// The letter's four indicators of one error, means over runs, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Indicators {
    /// MMean.
    pub mean: f64,
    /// MStd.
    pub std: f64,
    /// MMax.
    pub max: f64,
    /// MMin.
    pub min: f64,
}

impl From<Summary> for Indicators {
    fn from(s: Summary) -> Self {
        Indicators {
            mean: s.mean,
            std: s.std,
            max: s.max,
            min: s.min,
        }
    }
}

/// One slave's SYNC0 margin, all runs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SlaveOut {
    /// Auto-increment position.
    pub position: u16,
    /// The smallest margin, ns.
    pub margin_min_ns: f64,
    /// The 0.1th percentile of the margin, ns.
    pub margin_p001_ns: f64,
    /// The mean margin, ns.
    pub margin_mean_ns: f64,
    /// Cycles this slave got its frame after SYNC0, all runs.
    pub late_frames: u64,
    /// SYNC0 pulses with no new outputs since the pulse before, all runs (the ground truth of
    /// what a drive counts in 0x1C32:0B; a late frame right after a late one is not one more).
    pub sync0_missed: u64,
    /// The drive's own SM-event-missed count (0x1C32:0B) over the same cycles, all runs; none
    /// for a slave that does not run on SYNC0 (no CoE, or not set to DC mode).
    pub drive_sm_events_missed: Option<u64>,
    /// The smallest SYNC0 shift this slave needs, % of the cycle (rounded up to 0.1 %).
    pub smallest_safe_shift_pct: f64,
}

/// The ground truth of a method, all runs pooled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroundTruth {
    /// Where the method aims the frame's arrival at the reference against the DC grid, ns.
    pub target_phase_ns: i64,
    /// The frame's arrival at the reference against its DC grid point, ns.
    pub phase: Summary,
    /// Mean phase minus the target, ns.
    pub offset_from_target_ns: f64,
    /// Whether the mean phase is within 10 % of the margin of the target.
    pub holds_target: bool,
    /// The phase minus the target, ns.
    pub phase_error: Summary,
    /// Largest |slave - reference| system time difference per frame (every 8th cycle), ns.
    pub slave_ref_diff: Summary,
    /// The worst slave's SYNC0 minus the instant the frame's last bit passed it, ns.
    pub sync0_margin: Summary,
    /// Cycles with a late frame (negative margin at some slave) at the scenario's SYNC0 shift.
    pub late_frames: u64,
    /// The scenario's SYNC0 shift, % of the cycle.
    pub sync0_shift_pct: f64,
    /// The smallest SYNC0 shift with no late frame in any run, % of the cycle (rounded up to
    /// 0.1 %).
    pub smallest_safe_shift_pct: f64,
    /// Per slave with a DC unit.
    pub per_slave: Vec<SlaveOut>,
    /// Frames lost, all runs.
    pub lost_frames: u64,
    /// Cycles with an unexpected LRW working counter, all runs.
    pub bad_wkc: u64,
}

/// The drift during the init frames, means over runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InitDriftOut {
    /// Init frames.
    pub frames: u64,
    /// The phase's drift during them, ns per cycle.
    pub drift_ns_per_cycle: f64,
    /// The same as a frequency difference, ppm.
    pub drift_ppm: f64,
    /// How far the init frames' mean phase lies from where they started, ns: the letter's
    /// averaging (eq. 7) sets the method's point there.
    pub offset_ns: f64,
}

/// A controller's own report (DCM), over runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ControllerOut {
    /// Share of the recorded cycles reported in sync.
    pub in_sync_fraction: f64,
    /// Mean time from the start of the cyclic phase to the first "in sync", ms (`None` when a
    /// run never got there).
    pub time_to_sync_ms: Option<f64>,
    /// Times it left "in sync", all runs.
    pub sync_losses: u64,
    /// Whether every run ended in sync.
    pub in_sync_at_end: bool,
    /// Errors the filter did not use, all runs.
    pub invalid_errors: u64,
    /// The drift it learnt, ppm (mean over runs).
    pub drift_ppm: f64,
}

/// One method's results.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodOut {
    /// The method and its send mode (the map's key is its [`Entry::name`]).
    #[serde(skip)]
    pub entry: Entry,
    /// What it is.
    pub description: &'static str,
    /// The letter's name for it.
    pub letter_name: &'static str,
    /// M-rS error (the letter's definition), means of the runs' statistics, ns.
    pub m_rs: Indicators,
    /// rS-IS error (|BRD of 0x092C|, as the letter reads it), means of the runs' statistics,
    /// ns.
    pub rs_is: Indicators,
    /// M-rS, all runs pooled, ns.
    pub m_rs_pooled: Summary,
    /// rS-IS, all runs pooled, ns.
    pub rs_is_pooled: Summary,
    /// The letter's Table 1 values, ns, on the letter's testbed only.
    pub letter: Option<LetterOut>,
    /// What only the simulator knows.
    pub ground_truth: GroundTruth,
    /// The drift during the method's init frames.
    pub init_drift: Option<InitDriftOut>,
    /// A controller's own report.
    pub controller: Option<ControllerOut>,
    /// Per run: M-rS and rS-IS.
    pub runs: Vec<RunOut>,
    /// Recorded cycles, all runs.
    pub cycles_done: u64,
    /// Time to DC lock in the bring-up, ms (mean over runs).
    pub lock_ms: f64,
    /// CPU time of this method's runs, s (in timing.json, not summary.json: a scenario and a
    /// seed give the same summary.json byte for byte on any machine).
    #[serde(skip)]
    pub wall_s: f64,
    /// How the host sent its frames (absent: `plain`, the letter's way).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub send: Option<SendOut>,
    /// Per run: the faults played and how the method came through them (`compare --faults`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub faults: Vec<crate::run::FaultsTruth>,
    /// The drives the master found out of OP, every run's, with their AL status code (a sync
    /// error past the configured `run.sync_error_limit`: 0x001A); absent when none did.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub left_op: Vec<crate::run::LeftOpOut>,
}

/// The letter's values of a method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LetterOut {
    /// M-rS, ns.
    pub m_rs: Row,
    /// rS-IS, ns.
    pub rs_is: Row,
}

/// One run of a method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunOut {
    /// M-rS, ns.
    pub m_rs: Indicators,
    /// rS-IS, ns.
    pub rs_is: Indicators,
}

/// The verdict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Recommendation {
    /// The pick.
    pub method: String,
    /// Why, in plain words.
    pub reason: String,
    /// Every method, best first.
    pub ranking: Vec<String>,
    /// The rule.
    pub rule: &'static str,
    /// What each send mode buys the pick's method, when the comparison ran more than one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub send_modes: Option<String>,
    /// Methods left out of the ranking, and why (their figures describe too few frames).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_ranked: Vec<NotRanked>,
}

/// A method the verdict does not rank.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NotRanked {
    /// The method.
    pub method: String,
    /// Why, in plain words.
    pub why: String,
}

/// A method that lost more than this share of its frames with no fault scheduled is not
/// ranked: its figures are those of the few frames that came back, and whatever made it
/// lose them (a cycle too short for the network, a reply timeout) is the finding.
pub const UNRANKED_LOST_SHARE: f64 = 0.1;

/// For the pick's method, each send mode's figures against `plain`'s (`None` with one mode).
fn send_note(
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

/// The methods the verdict cannot judge (see [`UNRANKED_LOST_SHARE`]).
fn not_ranked(methods: &BTreeMap<String, MethodOut>, order: &[String]) -> Vec<NotRanked> {
    order
        .iter()
        .filter_map(|m| {
            let mo = methods.get(m)?;
            let lost = mo.ground_truth.lost_frames;
            let share = lost as f64 / mo.cycles_done.max(1) as f64;
            (mo.faults.is_empty() && lost > 0 && share > UNRANKED_LOST_SHARE).then(|| NotRanked {
                method: m.clone(),
                why: format!(
                    "{m} lost {lost} of {} frames ({:.0} %) with no fault scheduled: the figures of the frames that came back do not describe it",
                    mo.cycles_done,
                    share * 100.0
                ),
            })
        })
        .collect()
}

/// The ranking rule, in words.
pub const RANKING_RULE: &str = "fewest late frames at the configured SYNC0 shift, then holding the target (mean phase within 10 % of the margin), then the smallest SYNC0 shift without a late frame (in steps of 0.5 % of the cycle above the best), then the smallest slave spread p99.9 (in steps of 10 % of the best, at least 2 ns), then the smallest p99.9 of |true phase - target|";

/// A figure at risk.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Warning {
    /// What kind: crystal_difference, off_target, jitter_eats_margin, late_frames,
    /// cycle_too_short, interrupted, samples, left_op.
    pub kind: &'static str,
    /// The method it concerns, if one.
    pub method: Option<String>,
    /// What is wrong and what it means.
    pub message: String,
}

/// How quantiles are computed and how far they can be off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct QuantileNote {
    /// Definition.
    pub definition: &'static str,
    /// Relative part of the error bound.
    pub rel_error: f64,
    /// Absolute part of the error bound, ns.
    pub abs_error_ns: f64,
}

/// summary.json.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SummaryOut {
    /// The verdict.
    pub recommendation: Recommendation,
    /// Figures at risk.
    pub warnings: Vec<Warning>,
    /// The scenario file or preset.
    pub scenario: String,
    /// Host preset.
    pub host: String,
    /// Base seed.
    pub seed: u64,
    /// Runs.
    pub runs: u32,
    /// Recorded cycles per run (the scenario's).
    pub cycles: u64,
    /// Stopped before the end: the figures are of the cycles done.
    pub interrupted: bool,
    /// Recorded cycles done, all methods and runs.
    pub cycles_done: u64,
    /// Warm-up cycles per run.
    pub warmup_cycles: u64,
    /// Cycle time, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift, %.
    pub sync0_shift_pct: f64,
    /// Target phase of every method, ns after the DC grid point.
    pub target_phase_ns: i64,
    /// The margin between a frame on target and SYNC0 at the worst slave, ns.
    pub margin_budget_ns: f64,
    /// Slaves.
    pub slaves: usize,
    /// The letter's testbed (its Table 1 values are shown only then).
    pub letter_testbed: bool,
    /// Quantiles: definition and error bound.
    pub quantiles: QuantileNote,
    /// Results by method.
    pub methods: BTreeMap<String, MethodOut>,
    /// Wall time of the comparison, s (in timing.json, see [`TimingOut`]).
    #[serde(skip)]
    pub wall_s: f64,
    /// Threads (in timing.json).
    #[serde(skip)]
    pub threads: usize,
}

/// timing.json: what a comparison measured of the machine it ran on. Kept out of
/// summary.json, which a scenario and a seed reproduce byte for byte.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimingOut {
    /// Wall time of the comparison, s.
    pub wall_s: f64,
    /// Threads the runs were spread over.
    pub threads: usize,
    /// CPU time of each method's runs, s.
    pub methods_cpu_s: BTreeMap<String, f64>,
}

impl SummaryOut {
    /// The machine's part of the comparison (timing.json).
    pub fn timing(&self) -> TimingOut {
        TimingOut {
            wall_s: self.wall_s,
            threads: self.threads,
            methods_cpu_s: self
                .methods
                .iter()
                .map(|(k, m)| (k.clone(), m.wall_s))
                .collect(),
        }
    }
}

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

fn method_out(c: &Comparison, m: usize, entry: Entry, letter_testbed: bool) -> MethodOut {
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
                .map(|i| {
                    let mut st = Stats::new();
                    let mut late = 0;
                    let mut missed = 0;
                    let mut drive: Option<u64> = None;
                    let mut latest = f64::NEG_INFINITY;
                    for r in rs {
                        if let Some(x) = r.per_slave.get(i) {
                            st.merge(&x.margin);
                            late += x.late_frames;
                            missed += x.sync0_missed;
                            if let Some(d) = x.drive_sm_events_missed {
                                drive = Some(drive.unwrap_or(0) + d);
                            }
                            latest = latest.max(x.latest_end_ns);
                        }
                    }
                    let sm = st.summary();
                    SlaveOut {
                        position: r0.per_slave[i].position,
                        margin_min_ns: sm.min,
                        margin_p001_ns: sm.p001,
                        margin_mean_ns: sm.mean,
                        late_frames: late,
                        sync0_missed: missed,
                        drive_sm_events_missed: drive,
                        smallest_safe_shift_pct: shift_pct(latest, period),
                    }
                })
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
        let done: u64 = rs.iter().map(|r| r.cycles_done).sum();
        let firsts: Vec<u64> = ctls.iter().filter_map(|t| t.first_in_sync_cycle).collect();
        ControllerOut {
            in_sync_fraction: ctls.iter().map(|t| t.in_sync_cycles).sum::<u64>() as f64
                / done.max(1) as f64,
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
            bad_wkc: rs.iter().map(|r| r.bad_wkc).sum(),
        },
        init_drift,
        controller,
        runs: sums
            .iter()
            .map(|x| RunOut {
                m_rs: x[0].into(),
                rs_is: x[1].into(),
            })
            .collect(),
        cycles_done: rs.iter().map(|r| r.cycles_done).sum(),
        lock_ms: lock.iter().sum::<f64>() / lock.len().max(1) as f64,
        wall_s: c.method_wall_s[m],
        faults: rs.iter().filter_map(|r| r.faults.clone()).collect(),
        left_op: rs.iter().flat_map(|r| r.left_op.iter().cloned()).collect(),
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

/// What a send mode did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SendOut {
    /// The mode.
    pub mode: ecsync_sim::send::SendMode,
    /// Recorded cycles whose frames were handed over after their launch time less the
    /// qdisc's delta and dropped (`txtime`'s deadline misses).
    pub launch_misses: u64,
    /// CPU time spent busy-waiting before the sends, % of the recorded cycles' time (`spin`).
    pub spin_cpu_pct: f64,
}

/// The ranking keys of a method (smaller is better), NaN last.
fn keys(m: &MethodOut) -> [f64; 5] {
    let g = &m.ground_truth;
    let nan_last = |x: f64| if x.is_nan() { f64::INFINITY } else { x };
    [
        g.late_frames as f64,
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

fn rank(methods: &BTreeMap<String, MethodOut>, order: &[String]) -> Vec<String> {
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
    idx.into_iter().map(|i| names[i].clone()).collect()
}

fn us(ns: f64) -> String {
    format!("{:.1} us", ns / 1000.0)
}

fn reason(methods: &BTreeMap<String, MethodOut>, ranking: &[String], s_pct: f64) -> String {
    let Some(pick) = ranking.first() else {
        return "no method ran".into();
    };
    let p = &methods[pick];
    let g = &p.ground_truth;
    let mut r = String::new();
    let late = if g.late_frames == 0 {
        format!("no frame reached a drive after its SYNC0 at the {s_pct} % shift")
    } else {
        format!(
            "it had the fewest late frames at the {s_pct} % shift ({}; every method had some: raise the shift)",
            g.late_frames
        )
    };
    let _ = write!(
        r,
        "{pick}: {late}; it needs a SYNC0 shift of {:.1} % at least, its frames reach the reference {} from the target on average and within {} of it in 99.9 % of cycles, and the drives stay within {:.0} ns of the reference (p99.9).",
        g.smallest_safe_shift_pct,
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
    if let Some(second) = ranking.get(1) {
        let q = &methods[second];
        let names: Vec<&String> = ranking.iter().collect();
        let compared = ranked_keys(methods, &names);
        let (ka, kb) = (keys(p), keys(q));
        let decided = (0..5).find(|&i| compared[0][i] != compared[1][i]);
        let what = [
            "late frames",
            "holding its target",
            "the smallest safe SYNC0 shift",
            "the slave spread",
            "the true phase's deviation from the target",
        ];
        let tied: Vec<&str> = (0..decided.unwrap_or(5))
            .filter(|&i| i >= 2 && ka[i] != kb[i])
            .map(|i| what[i])
            .collect();
        if !tied.is_empty() {
            let _ = write!(
                r,
                " It and {second} are within noise of each other on {}.",
                tied.join(" and ")
            );
        }
        if let Some(i) = decided {
            let fmt = |i: usize, v: f64, m: &MethodOut| match i {
                0 => format!("{v:.0}"),
                1 => format!(
                    "it sits {} from the target",
                    us(m.ground_truth.offset_from_target_ns)
                ),
                2 => format!("{v:.1} %"),
                3 => format!("{v:.0} ns"),
                _ => us(v),
            };
            if i == 1 {
                let _ = write!(
                    r,
                    " Next is {second}, which does not hold its target: {}.",
                    fmt(i, kb[i], q)
                );
            } else {
                let _ = write!(
                    r,
                    " Next is {second}, which loses on {}: {} against {}.",
                    what[i],
                    fmt(i, kb[i], q),
                    fmt(i, ka[i], p)
                );
            }
        } else {
            let _ = write!(r, " {second} ties with it on every key.");
        }
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
            " {} {} not hold {} target on this network (see the warnings) and {} ranked after the methods that do, late frames permitting.",
            off.join(", "),
            if off.len() == 1 { "does" } else { "do" },
            if off.len() == 1 { "its" } else { "their" },
            if off.len() == 1 { "is" } else { "are" }
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

fn warnings(
    c: &Comparison,
    methods: &BTreeMap<String, MethodOut>,
    order: &[String],
    budget_ns: f64,
) -> Vec<Warning> {
    let s = &c.scenario;
    let period = f64::from(s.cycle_ns);
    let mut w = Vec::new();
    if c.interrupted {
        let done: u64 = methods.values().map(|m| m.cycles_done).sum();
        w.push(Warning {
            kind: "interrupted",
            method: None,
            message: format!(
                "interrupted: the figures are of the {done} recorded cycles done, not of the {} asked for",
                s.cycles * u64::from(s.runs) * methods.len() as u64
            ),
        });
    }
    // The crystals: the reference is the first slave with a system time.
    let reference_ppm = s
        .slaves
        .iter()
        .find(|x| x.model.dc.has_system_time())
        .map(|x| x.crystal.ppm);
    let init_methods: Vec<MethodKind> = s
        .methods
        .iter()
        .copied()
        .filter(|m| {
            matches!(m, MethodKind::Median | MethodKind::PiM2s) && methods.contains_key(m.name())
        })
        .collect();
    if let (Some(r), false) = (reference_ppm, init_methods.is_empty()) {
        let d_ppm = r - s.host.master_ppm;
        let n = init_methods
            .iter()
            .map(|&m| s.init_frames(m))
            .max()
            .unwrap_or(0);
        let expected = d_ppm.abs() * 1e-6 * period * n as f64 / 2.0;
        if expected > 0.1 * budget_ns {
            w.push(Warning {
                kind: "crystal_difference",
                method: None,
                message: format!(
                    "the master's crystal and the reference's differ by {:.1} ppm: over {n} init frames the frames drift {}, and {} set their point where the frames were on average, about {} from where they were aimed ({:.0} % of the {} margin); median-fit fits the drift and holds its target",
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
            });
        }
    }
    for m in order {
        let Some(mo) = methods.get(m) else { continue };
        let g = &mo.ground_truth;
        if g.phase.n == 0 {
            continue;
        }
        let off = g.offset_from_target_ns;
        if off.abs() > 0.1 * budget_ns {
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
            w.push(Warning {
                kind: "off_target",
                method: Some(m.clone()),
                message: format!(
                    "{m} sits {} off its target on average{why}: {:.0} % of the {} margin",
                    us(off),
                    off.abs() / budget_ns * 100.0,
                    us(budget_ns)
                ),
            });
        }
        if g.late_frames > 0 {
            w.push(Warning {
                kind: "late_frames",
                method: Some(m.clone()),
                message: format!(
                    "{m}: {} cycles had a frame after SYNC0 at the {} % shift; it needs {:.1} %",
                    g.late_frames, s.sync0_shift_pct, g.smallest_safe_shift_pct
                ),
            });
        } else {
            let tail = g.phase.p999 - g.target_phase_ns as f64;
            if tail > 0.5 * budget_ns {
                w.push(Warning {
                    kind: "jitter_eats_margin",
                    method: Some(m.clone()),
                    message: format!(
                        "{m}: in 0.1 % of cycles the frame reaches the reference more than {} after the target, over half of the {} margin",
                        us(tail),
                        us(budget_ns)
                    ),
                });
            }
        }
    }
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
    if wire > period || trip > period {
        w.push(Warning {
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
    for m in order {
        let Some(mo) = methods.get(m) else { continue };
        let lost = mo.ground_truth.lost_frames;
        if lost > 0 {
            w.push(Warning {
                kind: "lost_frames",
                method: Some(m.clone()),
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
            });
        }
    }
    // Drives that left OP on their own (with a fault schedule the faults' table and
    // faults.csv tell what the faults did to whom).
    if s.faults.is_none() {
        for m in order {
            let Some(mo) = methods.get(m).filter(|mo| !mo.left_op.is_empty()) else {
                continue;
            };
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
                    format!(
                        "slave {slave} with AL status code {reason} {}, first at {:.3} s (run {run}){}",
                        if n == 1 { "once".to_string() } else { format!("{n} times") },
                        first_ms / 1e3,
                        if back { ", brought back each time" } else { ", not back in OP by the end" }
                    )
                })
                .collect();
            w.push(Warning {
                kind: "left_op",
                method: Some(m.clone()),
                message: format!(
                    "{m}: drives left OP (the summary's left_op lists each time): {}",
                    list.join("; ")
                ),
            });
        }
    }
    for m in order {
        let Some(mo) = methods.get(m) else { continue };
        // A fault a method did not come back from, in any run.
        let mut never: Vec<String> = Vec::new();
        for (run, f) in mo.faults.iter().enumerate() {
            for (k, ms) in f.relock_ms.iter().enumerate() {
                if ms.is_none() {
                    let kind = f.relock_kinds.get(k).map_or("fault", |k| k.as_str());
                    never.push(format!("{kind} (run {run})"));
                }
            }
        }
        if !never.is_empty() {
            never.dedup();
            let band = mo
                .faults
                .iter()
                .map(|f| f.lock_band_092c_ns)
                .fold(0.0f64, f64::max);
            w.push(Warning {
                kind: "no_relock",
                method: Some(m.clone()),
                message: format!(
                    "{m} did not come back to lock (|0x092C| under {band:.0} ns and M-rS within its band, the reference believed, every slave's process data, for 100 cycles) after: {}",
                    never.join(", ")
                ),
            });
        }
    }
    for r in c.results.iter().flatten() {
        if let Some(e) = &r.samples_error {
            w.push(Warning {
                kind: "samples",
                method: Some(r.method.clone()),
                message: format!("the samples could not be written: {e}"),
            });
        }
    }
    w
}

/// Builds summary.json's content.
pub fn summarize(c: &Comparison) -> SummaryOut {
    let s = &c.scenario;
    let testbed = s.is_letter_testbed();
    let mut methods = BTreeMap::new();
    let entries = s.entries();
    for (m, &e) in entries.iter().enumerate() {
        methods.insert(e.name(), method_out(c, m, e, testbed));
    }
    // The report's order, by name (the maps of summary.json are keyed by name).
    let order: Vec<String> = entries.iter().map(Entry::name).collect();
    // The margin budget: the shift minus the target minus the frame's mean transit from the
    // reference to its end at the worst slave (shift - margin - phase, the same for every
    // method up to noise: the mean over methods).
    let transits: Vec<f64> = methods
        .values()
        .filter(|m| m.ground_truth.phase.n > 0)
        .map(|m| {
            f64::from(s.sync0_shift_ns())
                - m.ground_truth.sync0_margin.mean
                - m.ground_truth.phase.mean
        })
        .collect();
    let transit = if transits.is_empty() {
        0.0
    } else if s.faults.is_some() {
        // With faults a method that lost the reference's timeline for a while carries a phase
        // far off in its mean: the median over methods is the network's transit.
        let mut t = transits.clone();
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    } else {
        transits.iter().sum::<f64>() / transits.len() as f64
    };
    let budget = (f64::from(s.sync0_shift_ns()) - s.target_phase_ns as f64 - transit).max(1.0);
    for m in methods.values_mut() {
        let g = &mut m.ground_truth;
        g.holds_target = g.phase.n > 0 && g.offset_from_target_ns.abs() <= 0.1 * budget;
    }
    let left_out = not_ranked(&methods, &order);
    let rankable: Vec<String> = order
        .iter()
        .filter(|m| !left_out.iter().any(|n| &n.method == *m))
        .cloned()
        .collect();
    let ranking = rank(&methods, &rankable);
    let reason = if ranking.is_empty() && !left_out.is_empty() {
        "none: every method lost most of its frames, so no figure here describes a method. Read the warnings: the cycle is likely too short for the network's frames (make it longer, or the reply timeout later).".to_string()
    } else {
        reason(&methods, &ranking, s.sync0_shift_pct)
    };
    let send_note = send_note(&methods, &order, ranking.first());
    let recommendation = Recommendation {
        method: ranking.first().cloned().unwrap_or_default(),
        send_modes: send_note,
        reason,
        ranking: ranking.clone(),
        rule: RANKING_RULE,
        not_ranked: left_out,
    };
    let warnings = warnings(c, &methods, &order, budget);
    SummaryOut {
        recommendation,
        warnings,
        scenario: s.name.clone(),
        host: s.host_name.clone(),
        seed: s.seed,
        runs: s.runs,
        cycles: s.cycles,
        interrupted: c.interrupted,
        cycles_done: methods.values().map(|m| m.cycles_done).sum(),
        warmup_cycles: s.warmup_cycles,
        cycle_ns: s.cycle_ns,
        sync0_shift_pct: s.sync0_shift_pct,
        target_phase_ns: s.target_phase_ns,
        margin_budget_ns: budget,
        slaves: s.slaves.len(),
        letter_testbed: testbed,
        quantiles: QuantileNote {
            definition: "the sample of rank ceil(q n) in ascending order, from HDR histograms (3 significant digits); within rel_error x |value| + abs_error_ns of it",
            rel_error: QUANTILE_REL_ERROR,
            abs_error_ns: RESOLUTION_NS,
        },
        methods,
        wall_s: c.wall_s,
        threads: c.threads,
    }
}

/// The verdict and warnings as text.
pub fn verdict_text(out: &SummaryOut) -> String {
    let mut t = String::new();
    let r = &out.recommendation;
    let pick = if r.method.is_empty() {
        "none"
    } else {
        &r.method
    };
    let _ = writeln!(t, "Recommendation: {pick}");
    let _ = writeln!(t, "  {}", r.reason);
    let _ = writeln!(t, "  Ranking: {}", r.ranking.join(" > "));
    if let Some(s) = &r.send_modes {
        let _ = writeln!(t, "  {s}");
    }
    for n in &r.not_ranked {
        let _ = writeln!(t, "  Not ranked: {}", n.why);
    }
    let _ = writeln!(t, "  (rule: {})", r.rule);
    if !out.warnings.is_empty() {
        let _ = writeln!(t);
        for w in &out.warnings {
            let _ = writeln!(t, "Warning: {}", w.message);
        }
    }
    t
}

/// Table 1's layout (the letter's values beside ours on the letter's testbed), in microseconds.
pub fn table1_text(out: &SummaryOut, order: &[String]) -> String {
    let mut t = String::new();
    let us = |v: f64| format!("{:>9.3}", v / 1000.0);
    let _ = writeln!(
        t,
        "Table 1: statistics of clock synchronization errors (us), means over {} of {} cycles{}",
        crate::scenario::plural(u64::from(out.runs), "run", "runs"),
        out.cycles,
        if out.letter_testbed {
            ", beside the letter's"
        } else {
            " (not the letter's testbed: its values are not a comparison here)"
        }
    );
    let _ = write!(t, "{:<18}", "");
    for m in order {
        let mo = &out.methods[m];
        let head = if mo.letter_name == "-" {
            m.clone()
        } else {
            format!("{} ({m})", mo.letter_name)
        };
        let _ = write!(t, "| {:<21}", head);
    }
    let _ = writeln!(t);
    let _ = write!(t, "{:<18}", "Indicator");
    for _ in order {
        let _ = write!(t, "| {:>9} {:>9}  ", "M-rS", "rS-IS");
    }
    let _ = writeln!(t);
    type Row4 = (&'static str, fn(&Indicators) -> f64, fn(&Row) -> f64);
    let rows: [Row4; 4] = [
        ("MMean", |i| i.mean, |r| r.mean),
        ("MStd", |i| i.std, |r| r.std),
        ("MMax", |i| i.max, |r| r.max),
        ("MMin", |i| i.min, |r| r.min),
    ];
    for (label, ours, theirs) in rows {
        let _ = write!(t, "{:<18}", format!("{label} ecsync"));
        for m in order {
            let mo = &out.methods[m];
            let _ = write!(t, "| {} {}  ", us(ours(&mo.m_rs)), us(ours(&mo.rs_is)));
        }
        let _ = writeln!(t);
        if !out.letter_testbed {
            continue;
        }
        let _ = write!(t, "{:<18}", format!("{label} letter"));
        for m in order {
            let mo = &out.methods[m];
            match &mo.letter {
                Some(l) => {
                    let _ = write!(t, "| {} {}  ", us(theirs(&l.m_rs)), us(theirs(&l.rs_is)));
                }
                None => {
                    let _ = write!(t, "| {:>9} {:>9}  ", "-", "-");
                }
            }
        }
        let _ = writeln!(t);
    }
    t
}

/// The ground truth table as text, us unless named.
pub fn truth_text(out: &SummaryOut, order: &[String]) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Ground truth (only a simulator has it), all runs pooled; phase = the frame's arrival at the reference after the DC grid point, target {:.1} us, SYNC0 at {:.1} us:",
        out.target_phase_ns as f64 / 1000.0,
        out.sync0_shift_pct * f64::from(out.cycle_ns) / 1e5
    );
    let _ = writeln!(
        t,
        "{:<18}{:>13}{:>11}{:>11}{:>12}{:>14}{:>12}{:>14}{:>14}{:>8}{:>12}{:>12}{:>9}",
        "method",
        "mean-target",
        "phase std",
        "RMS about",
        "min-target",
        "p99.9-target",
        "max-target",
        "|p-t| p99.9",
        "spread p99.9",
        "late",
        "safe shift",
        "margin min",
        "in sync"
    );
    let _ = writeln!(
        t,
        "{:<18}{:>13}{:>11}{:>11}{:>12}{:>14}{:>12}{:>14}{:>14}{:>8}{:>12}{:>12}{:>9}",
        "", "us", "us", "target us", "us", "us", "us", "us", "ns", "frames", "%", "us", ""
    );
    for m in order {
        let mo = &out.methods[m];
        let g = &mo.ground_truth;
        let sync = match &mo.controller {
            Some(c) => format!("{:.1} %", c.in_sync_fraction * 100.0),
            None => "-".into(),
        };
        let _ = writeln!(
            t,
            "{:<18}{:>13.3}{:>11.3}{:>11.3}{:>12.3}{:>14.3}{:>12.3}{:>14.3}{:>14.1}{:>8}{:>12.1}{:>12.1}{:>9}",
            m,
            g.offset_from_target_ns / 1000.0,
            g.phase.std / 1000.0,
            g.phase_error.rms / 1000.0,
            (g.phase.min - g.target_phase_ns as f64) / 1000.0,
            (g.phase.p999 - g.target_phase_ns as f64) / 1000.0,
            (g.phase.max - g.target_phase_ns as f64) / 1000.0,
            g.phase_error.p999_abs / 1000.0,
            g.slave_ref_diff.p999_abs,
            g.late_frames,
            g.smallest_safe_shift_pct,
            g.sync0_margin.min / 1000.0,
            sync
        );
    }
    let inits: Vec<String> = order
        .iter()
        .filter_map(|m| {
            let d = out.methods[m].init_drift?;
            Some(format!(
                "{m} {} ({:.2} ppm over {} frames)",
                us(d.offset_ns),
                d.drift_ppm,
                d.frames
            ))
        })
        .collect();
    if !inits.is_empty() {
        let _ = writeln!(
            t,
            "Init-drift offset (the mean phase of the init frames against the first's): {}",
            inits.join("; ")
        );
    }
    t
}

/// Per slave: the SYNC0 margin and the shift each needs, for the recommended method.
pub fn per_slave_text(out: &SummaryOut) -> String {
    let mut t = String::new();
    let m = &out.recommendation.method;
    let Some(mo) = out.methods.get(m) else {
        return t;
    };
    let _ = writeln!(
        t,
        "Per slave with {m}: SYNC0 margin (SYNC0 minus the frame's last bit at the slave) and the shift each needs:"
    );
    let _ = writeln!(
        t,
        "{:>9}{:>16}{:>16}{:>16}{:>8}{:>10}{:>10}{:>14}",
        "position",
        "margin min us",
        "margin p0.1 us",
        "margin mean us",
        "late",
        "missed",
        "drive",
        "safe shift %"
    );
    // A large network lists the slaves that need the largest shift (in position order), the
    // others are in summary.json.
    let all = &mo.ground_truth.per_slave;
    let mut shown: Vec<usize> = (0..all.len()).collect();
    if all.len() > PER_SLAVE_ROWS {
        shown.sort_by(|&a, &b| {
            all[b]
                .smallest_safe_shift_pct
                .total_cmp(&all[a].smallest_safe_shift_pct)
                .then(a.cmp(&b))
        });
        shown.truncate(PER_SLAVE_ROWS);
        shown.sort_unstable();
    }
    for s in shown.iter().map(|&k| &all[k]) {
        let _ = writeln!(
            t,
            "{:>9}{:>16.1}{:>16.1}{:>16.1}{:>8}{:>10}{:>10}{:>14.1}",
            s.position,
            s.margin_min_ns / 1000.0,
            s.margin_p001_ns / 1000.0,
            s.margin_mean_ns / 1000.0,
            s.late_frames,
            s.sync0_missed,
            s.drive_sm_events_missed
                .map_or("-".to_string(), |d| d.to_string()),
            s.smallest_safe_shift_pct
        );
    }
    let _ = writeln!(
        t,
        "(late: frames after the slave's SYNC0; missed: SYNC0 pulses with no new outputs since \
         the one before, the ground truth of what a drive counts; drive: the drive's own \
         SM-event-missed count, 0x1C32:0B, over the same cycles, - without CoE DC mode)"
    );
    if all.len() > shown.len() {
        let _ = writeln!(
            t,
            "({} of {} slaves shown: those that need the largest shift; every slave is in \
             summary.json, methods.{m}.ground_truth.per_slave)",
            shown.len(),
            all.len()
        );
    }
    t
}

/// Rows of the per-slave table a terminal gets at most.
const PER_SLAVE_ROWS: usize = 24;

fn csv_summary(t: &mut String, m: &str, q: &str, s: &Summary, letter: Option<&Row>) {
    let l = letter.map_or(",,,".to_string(), |r| {
        format!("{},{},{},{}", r.mean, r.std, r.max, r.min)
    });
    let _ = writeln!(
        t,
        "{m},{q},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{l}",
        s.n,
        s.mean,
        s.std,
        s.rms,
        s.min,
        s.max,
        s.max_abs,
        s.p001,
        s.p01,
        s.p50,
        s.p99,
        s.p999,
        s.p99_abs,
        s.p999_abs
    );
}

/// summary.csv: one row per method and quantity (all runs pooled; the letter's values on its
/// testbed), then one per method and slave.
pub fn csv(out: &SummaryOut, order: &[String]) -> String {
    let mut t = String::from(
        "method,quantity,n,mean_ns,std_ns,rms_ns,min_ns,max_ns,max_abs_ns,p0.1_ns,p1_ns,p50_ns,p99_ns,p99.9_ns,p99_abs_ns,p99.9_abs_ns,letter_mean_ns,letter_std_ns,letter_max_ns,letter_min_ns\n",
    );
    for m in order {
        let mo = &out.methods[m];
        csv_summary(
            &mut t,
            m,
            "m_rs",
            &mo.m_rs_pooled,
            mo.letter.as_ref().map(|l| &l.m_rs),
        );
        csv_summary(
            &mut t,
            m,
            "rs_is",
            &mo.rs_is_pooled,
            mo.letter.as_ref().map(|l| &l.rs_is),
        );
        let g = &mo.ground_truth;
        csv_summary(&mut t, m, "true_phase", &g.phase, None);
        csv_summary(&mut t, m, "true_slave_ref_diff", &g.slave_ref_diff, None);
        csv_summary(&mut t, m, "sync0_margin_worst_slave", &g.sync0_margin, None);
    }
    let _ = writeln!(
        t,
        "\nmethod,position,margin_min_ns,margin_p0.1_ns,margin_mean_ns,late_frames,sync0_missed,drive_sm_events_missed,smallest_safe_shift_pct"
    );
    for m in order {
        for s in &out.methods[m].ground_truth.per_slave {
            let _ = writeln!(
                t,
                "{m},{},{},{},{},{},{},{},{}",
                s.position,
                s.margin_min_ns,
                s.margin_p001_ns,
                s.margin_mean_ns,
                s.late_frames,
                s.sync0_missed,
                s.drive_sm_events_missed
                    .map_or(String::new(), |d| d.to_string()),
                s.smallest_safe_shift_pct
            );
        }
    }
    t
}
