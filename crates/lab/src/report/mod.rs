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

mod method;
mod noise;
mod summary;
mod text;
mod verdict;
mod warnings;

pub use summary::{
    ControllerOut, GroundTruth, Indicators, InitDriftOut, LetterOut, MethodOut, NotRanked,
    QuantileNote, Recommendation, RunKeys, RunOut, SendOut, SlaveOut, SummaryOut, TimingOut,
    Warning,
};
pub use text::{csv, m_rs_aim_note, per_slave_text, table1_text, truth_text, verdict_text};
pub use verdict::{
    RANKING_RULE, RANKING_RULE_DRIVE_ERRORS, SHIFT_TIE_PCT, SPREAD_TIE, UNRANKED_LOST_SHARE,
};

use crate::compare::Comparison;
use crate::stats::{QUANTILE_REL_ERROR, RESOLUTION_NS};
use ecsync_sim::send::Entry;
use method::method_out;
use std::collections::BTreeMap;
use verdict::{not_ranked, rank, reason, send_note, within_noise};
use warnings::warnings;

/// Nanoseconds as microseconds with one decimal, for the messages.
fn us(ns: f64) -> String {
    format!("{:.1} us", ns / 1000.0)
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
    let mut recommendation = recommend(&methods, &order, s.sync0_shift_pct, s.runs);
    let warnings = warnings(c, &methods, &order, budget);
    // The pick's figures that take extremes hold a start it was still settling from: the
    // verdict says so where the reader looks first, not only among the warnings.
    let pick = Some(recommendation.method.as_str());
    if warnings
        .iter()
        .any(|w| w.kind == "settling" && w.method.as_deref() == pick)
    {
        recommendation.reason.push_str(
            " It was still settling when the recording began (see the warnings): its extremes and smallest safe shift hold that start, and the warm-up the warning names leaves it out.",
        );
    }
    SummaryOut {
        recommendation,
        warnings,
        scenario: s.name.clone(),
        host: s.host_name.clone(),
        master_ppm: s.host.master_ppm,
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

/// The verdict on `methods` (in report `order`; `holds_target` set), a SYNC0 shift of
/// `shift_pct` % and `runs` runs each: the ranking, the pick and why, the methods within
/// run-to-run noise of it, those not ranked. A function of the figures alone, so that it can
/// be checked on figures made by hand.
pub fn recommend(
    methods: &BTreeMap<String, MethodOut>,
    order: &[String],
    shift_pct: f64,
    runs: u32,
) -> Recommendation {
    let left_out = not_ranked(methods, order);
    let rankable: Vec<String> = order
        .iter()
        .filter(|m| !left_out.iter().any(|n| &n.method == *m))
        .cloned()
        .collect();
    // Too few cycles for the p99.9 figures the ranking rests on: no ranking at all (a
    // maximum of a few frames would decide it).
    let fewest = rankable
        .iter()
        .filter_map(|m| methods.get(m))
        .map(|m| m.cycles_done)
        .min();
    let too_few = fewest.filter(|&n| n < noise::MIN_RANKED_CYCLES);
    let ranking = if too_few.is_some() {
        Vec::new()
    } else {
        rank(methods, &rankable)
    };
    let reason = if let Some(n) = too_few {
        format!(
            "none: {n} measured {} per method (at the fewest) {} too few for the p99.9 figures the ranking rests on (at least {}; {} put ten samples beyond a p99.9). Run --cycles {} or more.",
            if n == 1 { "cycle" } else { "cycles" },
            if n == 1 { "is" } else { "are" },
            noise::MIN_RANKED_CYCLES,
            noise::FEW_CYCLES,
            noise::FEW_CYCLES.div_ceil(u64::from(runs.max(1)))
        )
    } else if ranking.is_empty() && !left_out.is_empty() {
        if left_out.iter().all(|n| n.lost_frames) {
            "none: every method lost most of its frames, so no figure here describes a method. Read the warnings: the cycle is likely too short for the network's frames (make it longer, or the reply timeout later).".to_string()
        } else {
            "none: no method could be ranked; why each was not is said under \"Not ranked\"."
                .to_string()
        }
    } else {
        reason(methods, &ranking, shift_pct)
    };
    let tied: Vec<String> = within_noise(methods, &ranking)
        .into_iter()
        .cloned()
        .collect();
    let rule = if ranking
        .iter()
        .any(|m| verdict::drive_errors(&methods[m]) > 0)
    {
        RANKING_RULE_DRIVE_ERRORS
    } else {
        RANKING_RULE
    };
    Recommendation {
        method: ranking.first().cloned().unwrap_or_default(),
        send_modes: send_note(methods, order, ranking.first()),
        reason,
        ranking,
        within_noise: tied,
        rule,
        not_ranked: left_out,
    }
}
