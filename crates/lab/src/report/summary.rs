//! summary.json's types: a method's figures, the verdict, the warnings, the machine's part.

use crate::letter::Row;
use crate::stats::Summary;
use ecsync_sim::send::Entry;
use serde::Serialize;
use std::collections::BTreeMap;

/// For `skip_serializing_if`: a count that is 0 is left out of summary.json.
fn is_zero(n: &u64) -> bool {
    *n == 0
}

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
    /// The name the scenario gives the slave.
    pub name: String,
    /// The smallest margin, ns.
    pub margin_min_ns: f64,
    /// The 0.1th percentile of the margin, ns.
    pub margin_p001_ns: f64,
    /// The mean margin, ns.
    pub margin_mean_ns: f64,
    /// Cycles this slave got its frame after SYNC0, all runs.
    pub late_frames: u64,
    /// SYNC0 pulses in OP with no new outputs since the pulse before, all runs (the ground truth of
    /// what a drive counts in 0x1C32:0B; a late frame right after a late one is not one more).
    pub sync0_missed: u64,
    /// The drive's own SM-event-missed count (0x1C32:0B) over the same cycles, all runs; none
    /// for a slave that does not run on SYNC0 (no CoE, or not set to DC mode).
    pub drive_sm_events_missed: Option<u64>,
    /// Power cycles of the drive in the measured cycles, all runs: 0x1C32:0B is a RAM value,
    /// 0 at each power-up, so `drive_sm_events_missed` counts from a run's last one.
    #[serde(skip_serializing_if = "is_zero_u32")]
    pub drive_restarts: u32,
    /// With restarts: the ground truth's `sync0_missed` since the drive's last power cycle in
    /// each run, all runs: what `drive_sm_events_missed` compares with.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sync0_missed_since_drive_restart: Option<u64>,
    /// The smallest SYNC0 shift this slave needs, % of the cycle (rounded up to 0.1 %).
    pub smallest_safe_shift_pct: f64,
    /// It runs on SYNC1 (an oversampling terminal): its margin, late frames and missed
    /// pulses are its SYNC1 events', which fall where the others' SYNC0 pulses do.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub on_sync1: bool,
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
    /// Recorded cycles that lost their frame, all runs (in a cycle of several frames: one or
    /// more of them).
    pub lost_frames: u64,
    /// Recorded cycles whose process data exchange failed, all runs: a frame late at some
    /// slave or lost (the first key of the ranking; a frame both is counted once).
    pub late_or_lost_frames: u64,
    /// Frames a cycle sends (the most of any run); not in summary.json.
    #[serde(skip)]
    pub frames_per_cycle: usize,
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
    /// Share of the recorded cycles the controller ran that it reported in sync (the slots
    /// the driver skipped are not among them: `skipped_slots`).
    pub in_sync_fraction: f64,
    /// Recorded cycles the controller ran, all runs.
    pub cycles_run: u64,
    /// Recorded cycle slots the driver skipped (its task woke after them: a host stall, a
    /// step of the master's clock), all runs: no controller ran in them.
    pub skipped_slots: u64,
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
    /// Cycles whose next start the method asked for more than two periods on (or before the
    /// cycle's own) and the engine held: an unstable controller, all runs (absent when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub wild_schedule_cycles: u64,
    /// Grid points the master's schedule aimed at twice or left out (a cycle started less than
    /// half a period after the one before, or more than one and a half), all runs (absent
    /// when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub grid_slips: u64,
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
    /// The runs whose recording stopped before their last cycle, where and why (the master's
    /// task skipped the slots past it: its clock stepped forward, or it stalled); absent when
    /// every run recorded all its cycles.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub recording_stopped: Vec<crate::run::RecordingStopped>,
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
    /// The ranking's keys in this run alone: their spread over the runs is the noise the
    /// verdict weighs differences against.
    pub keys: RunKeys,
}

/// The ranking's keys of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunKeys {
    /// Frames after a drive's SYNC0.
    pub late_frames: u64,
    /// Cycles with a frame late at a drive or lost: the ranking's first key.
    pub late_or_lost_frames: u64,
    /// The smallest SYNC0 shift without a late frame, % of the cycle.
    pub smallest_safe_shift_pct: f64,
    /// p99.9 of |slave - reference|, ns.
    pub slave_spread_p999_ns: f64,
    /// p99.9 of |true phase - target|, ns.
    pub phase_error_p999_ns: f64,
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
    /// The methods after the pick that are within run-to-run noise of it on every key the
    /// ranking separates them on: as good a choice, as far as the runs can tell.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub within_noise: Vec<String>,
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
    /// It lost most of its frames (the words of a verdict with nothing ranked depend on it).
    #[serde(skip)]
    pub lost_frames: bool,
}

/// A figure at risk.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Warning {
    /// What kind: crystal_difference, off_target, jitter_eats_margin, late_frames,
    /// cycle_too_short, fault_long_frames, fault_not_played, interrupted, recording_stopped,
    /// samples, left_op, settling.
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
    /// The master PC's crystal error against real time, ppm (`[host] master_ppm`, else the
    /// host preset's).
    pub master_ppm: f64,
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

fn is_zero_u32(n: &u32) -> bool {
    *n == 0
}

impl SlaveOut {
    /// The drive's own count as the tables show it: - without CoE DC mode, marked * when its
    /// counter restarted at a power cycle (see [`SlaveOut::restart_note`]).
    pub fn drive_count_shown(&self) -> String {
        match self.drive_sm_events_missed {
            None => "-".to_string(),
            Some(d) if self.drive_restarts > 0 => format!("{d}*"),
            Some(d) => d.to_string(),
        }
    }

    /// For a drive whose counter restarted: what its count is against.
    pub fn restart_note(&self) -> Option<String> {
        let since = self.sync0_missed_since_drive_restart?;
        let times = match self.drive_restarts {
            1 => "a power cycle".to_string(),
            n => format!("{n} power cycles"),
        };
        Some(format!(
            "*{}: 0x1C32:0B restarted from 0 at {times} (a RAM value): its count is since the \
             last, against {since} pulses missed since then by the ground truth",
            self.name
        ))
    }
}
