//! What the terminal and summary.csv get: the verdict, Table 1, the ground truth, per slave.

use super::{Indicators, SlaveOut, SummaryOut, us};
use crate::letter::Row;
use crate::stats::Summary;
use std::fmt::Write as _;

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
    if r.ranking.is_empty() {
        let _ = writeln!(t, "  Ranking: none");
    } else {
        let _ = writeln!(t, "  Ranking: {}", r.ranking.join(" > "));
    }
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
    if let Some(note) = m_rs_aim_note(out, order) {
        let _ = writeln!(t, "{note}");
    }
    t
}

/// Why an M-rS mean far from zero is no error: M-rS counts from h_mr (the init frames' mean
/// phase, the letter's eq. 10) or from the send stamp (bus shift), and a method that aims at
/// another point (the target phase on the DC grid) sits a constant distance from it. `None`
/// when every method's M-rS mean is within its spread of zero.
pub fn m_rs_aim_note(out: &SummaryOut, order: &[String]) -> Option<String> {
    let far: Vec<String> = order
        .iter()
        .filter_map(|m| Some((m, out.methods.get(m)?)))
        .filter(|(_, mo)| {
            let (mean, std) = (mo.m_rs.mean, mo.m_rs.std);
            mean.abs() > 1000.0_f64.max(2.0 * std)
        })
        .map(|(m, mo)| {
            format!(
                "{m} {:.1} us (its true phase: {:+.1} us from the target)",
                mo.m_rs.mean / 1000.0,
                mo.ground_truth.offset_from_target_ns / 1000.0
            )
        })
        .collect();
    if far.is_empty() {
        return None;
    }
    Some(format!(
        "M-rS counts from h_mr, the mean phase of the init frames (the letter's eq. 10; for bus shift from the send stamp): a method that aims elsewhere (at the target phase on the DC grid) has an M-rS mean that is the distance of its aim from h_mr, not an error. Means far from 0 here: {}. Its error is the ground truth's mean-target.",
        far.join(", ")
    ))
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
        let _ = write!(t, "{m:<18}");
        let t_ns = g.target_phase_ns as f64;
        for (v, w) in [
            (g.offset_from_target_ns, 13),
            (g.phase.std, 11),
            (g.phase_error.rms, 11),
            (g.phase.min - t_ns, 12),
            (g.phase.p999 - t_ns, 14),
            (g.phase.max - t_ns, 12),
            (g.phase_error.p999_abs, 14),
        ] {
            cell(&mut t, &format!("{:.3}", v / 1000.0), w);
        }
        cell(&mut t, &format!("{:.1}", g.slave_ref_diff.p999_abs), 14);
        cell(&mut t, &g.late_frames.to_string(), 8);
        cell(&mut t, &format!("{:.1}", g.smallest_safe_shift_pct), 12);
        cell(&mut t, &format!("{:.1}", g.sync0_margin.min / 1000.0), 12);
        cell(&mut t, &sync, 9);
        t.push('\n');
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
    let skips: Vec<String> = order
        .iter()
        .filter_map(|m| {
            let c = out.methods[m].controller?;
            (c.skipped_slots > 0).then(|| {
                format!(
                    "{m} of {} cycles run, {} slots skipped",
                    c.cycles_run, c.skipped_slots
                )
            })
        })
        .collect();
    if !skips.is_empty() {
        let _ = writeln!(
            t,
            "In sync: of the cycles each controller ran, not of the slots its task skipped (a host stall, a step of the master's clock): {}",
            skips.join("; ")
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
    let all = &mo.ground_truth.per_slave;
    let shown_name = |s: &SlaveOut| {
        if s.on_sync1 {
            format!("{} [SYNC1]", s.name)
        } else {
            s.name.clone()
        }
    };
    let name_w = all
        .iter()
        .map(|s| shown_name(s).chars().count())
        .max()
        .unwrap_or(0)
        .max(5);
    let _ = writeln!(
        t,
        "{:<name_w$}{:>9}{:>16}{:>16}{:>16}{:>8}{:>10}{:>10}{:>14}",
        "slave",
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
            "{:<name_w$}{:>9}{:>16.1}{:>16.1}{:>16.1}{:>8}{:>10}{:>10}{:>14.1}",
            shown_name(s),
            s.position,
            s.margin_min_ns / 1000.0,
            s.margin_p001_ns / 1000.0,
            s.margin_mean_ns / 1000.0,
            s.late_frames,
            s.sync0_missed,
            s.drive_count_shown(),
            s.smallest_safe_shift_pct
        );
    }
    let _ = writeln!(
        t,
        "(late: frames after the slave's SYNC0; missed: SYNC0 pulses in OP with no new outputs \
         since the one before, the ground truth of what a drive counts; drive: the drive's own \
         SM-event-missed count, 0x1C32:0B, over the same cycles, - without CoE DC mode)"
    );
    for note in all.iter().filter_map(|s| s.restart_note()) {
        let _ = writeln!(t, "({note})");
    }
    if all.iter().any(|s| s.on_sync1) {
        let _ = writeln!(
            t,
            "([SYNC1]: an oversampling terminal, which takes its outputs at SYNC1 events: its \
             margin, late frames and missed pulses are SYNC1's, on the cycle's grid where the \
             others' SYNC0 pulses are, and its own count is of SYNC1 events)"
        );
    }
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

/// `x` as one CSV field: quoted when it holds a comma, a quote or a line break (RFC 4180).
fn csv_field(x: &str) -> std::borrow::Cow<'_, str> {
    if x.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", x.replace('"', "\"\"")).into()
    } else {
        x.into()
    }
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
        "\nmethod,slave,position,margin_min_ns,margin_p0.1_ns,margin_mean_ns,late_frames,sync0_missed,drive_sm_events_missed,smallest_safe_shift_pct,drive_restarts,sync0_missed_since_drive_restart"
    );
    for m in order {
        for s in &out.methods[m].ground_truth.per_slave {
            let _ = writeln!(
                t,
                "{m},{},{},{},{},{},{},{},{},{},{},{}",
                csv_field(&s.name),
                s.position,
                s.margin_min_ns,
                s.margin_p001_ns,
                s.margin_mean_ns,
                s.late_frames,
                s.sync0_missed,
                s.drive_sm_events_missed
                    .map_or(String::new(), |d| d.to_string()),
                s.smallest_safe_shift_pct,
                s.drive_restarts,
                s.sync0_missed_since_drive_restart
                    .map_or(String::new(), |d| d.to_string()),
            );
        }
    }
    t
}

/// `v` right-aligned in `width` columns, and one space before it where it fills them or more
/// (a figure out of all proportion stays apart from its neighbour).
fn cell(t: &mut String, v: &str, width: usize) {
    if v.len() >= width {
        t.push(' ');
    }
    let _ = write!(t, "{v:>width$}");
}
