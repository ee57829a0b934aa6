//! What a sweep says: per method its best point, and the best of them.
//!
//! A point is good for a method when the method had no late and no lost frame there and held
//! its target; the best good point is the one with the smallest safe SYNC0 shift (the margin
//! a design can spend elsewhere), then the smallest phase error p99.9.

use super::db::{ResultRow, Store};
use super::grid::{self, Points};
use anyhow::Result;
use ecsync_lab::report::{SHIFT_TIE_PCT, SummaryOut};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// `n` and the noun for it.
fn plural(n: usize, one: &str, many: &str) -> String {
    ecsync_lab::scenario::plural(n as u64, one, many)
}

/// One point's comparison in a line: its pick and the pick's figures.
pub fn point_line(out: &SummaryOut) -> String {
    let rec = &out.recommendation;
    match out.methods.get(&rec.method) {
        Some(m) if !rec.ranking.is_empty() => format!(
            "pick {} (smallest safe shift {:.1} %, phase error p99.9 {:.0} ns, {} late, {} lost)",
            rec.method,
            m.ground_truth.smallest_safe_shift_pct,
            m.ground_truth.phase_error.p999_abs,
            m.ground_truth.late_frames,
            m.ground_truth.lost_frames
        ),
        _ => format!("no pick: {}", rec.reason),
    }
}

/// Whether `r` counts for the answer: what the report draws filled.
pub fn good(r: &ResultRow) -> bool {
    r.rank.is_some()
        && r.late_frames == 0
        && r.lost_frames == 0
        && r.holds_target
        && r.safe_shift_pct.is_finite()
}

fn better(a: &ResultRow, b: &ResultRow) -> bool {
    (a.safe_shift_pct, a.phase_error_p999_ns) < (b.safe_shift_pct, b.phase_error_p999_ns)
}

/// The points of `method` as good as its best `best` on the smallest safe shift: within the
/// comparison's tie step ([`SHIFT_TIE_PCT`] of the cycle), which the verdict counts as no
/// difference either.
fn ties<'a>(rows: &'a [ResultRow], best: &ResultRow) -> Vec<&'a ResultRow> {
    rows.iter()
        .filter(|r| {
            r.method == best.method
                && r.point != best.point
                && good(r)
                && r.safe_shift_pct <= best.safe_shift_pct + SHIFT_TIE_PCT
        })
        .collect()
}

/// Point numbers, the first few.
fn some_points(rows: &[&ResultRow]) -> String {
    let mut s: Vec<String> = rows.iter().take(8).map(|r| r.point.to_string()).collect();
    if rows.len() > 8 {
        s.push(format!("and {} more", rows.len() - 8));
    }
    s.join(", ")
}

/// Each method's best good point (`None`: it has none), and the best of them: what the
/// answer names and the report marks, decided here only so that the two never disagree.
pub struct Best<'a> {
    /// Per method, by name.
    pub per_method: BTreeMap<&'a str, Option<&'a ResultRow>>,
    /// The answer's point.
    pub overall: Option<&'a ResultRow>,
}

/// The best points of `rows`.
pub fn best(rows: &[ResultRow]) -> Best<'_> {
    let mut per_method: BTreeMap<&str, Option<&ResultRow>> = BTreeMap::new();
    for r in rows {
        let slot = per_method.entry(r.method.as_str()).or_insert(None);
        if good(r) && slot.is_none_or(|b| better(r, b)) {
            *slot = Some(r);
        }
    }
    let overall = per_method
        .values()
        .flatten()
        .copied()
        .reduce(|a, b| if better(b, a) { b } else { a });
    Best {
        per_method,
        overall,
    }
}

/// Whether the sweep's points differ by their seed only (`run.seed` swept, every other key at
/// one value): what moves between them is run-to-run noise, and no point is a design's to pick.
pub fn seed_only(store: &Store, pts: &Points) -> Result<bool> {
    Ok(seeds_vary(store, pts)?
        && (0..pts.keys.len()).all(|i| pts.keys[i] == SEED_KEY || !varies(pts, i)))
}

/// Whether key `i` takes more than one value over the sweep's points.
fn varies(pts: &Points, i: usize) -> bool {
    pts.rows.iter().any(|r| r[i] != pts.rows[0][i])
}

/// Whether the points run with different seeds: `run.seed` is swept, or the points done ran
/// with more than one.
fn seeds_vary(store: &Store, pts: &Points) -> Result<bool> {
    let swept = (0..pts.keys.len()).any(|i| pts.keys[i] == SEED_KEY && varies(pts, i));
    Ok(swept || store.seeds()? > 1)
}

/// Why `method` has no good point, counted over its points: not ranked, with late or lost
/// frames, off its target (a point may count under more than one).
fn why_no_point(rows: &[ResultRow], method: &str) -> String {
    let mine: Vec<&ResultRow> = rows.iter().filter(|r| r.method == method).collect();
    let count = |f: &dyn Fn(&ResultRow) -> bool| mine.iter().filter(|r| f(r)).count();
    let parts: Vec<String> = [
        (count(&|r| r.rank.is_none()), "not ranked"),
        (
            count(&|r| r.late_frames > 0 || r.lost_frames > 0),
            "late or lost frames",
        ),
        (count(&|r| !r.holds_target), "off its target"),
    ]
    .into_iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("{what} at {n}"))
    .collect();
    format!(
        "{} of its {}",
        parts.join(", "),
        plural(mine.len(), "point", "points")
    )
}

/// The cycle time as a swept key.
const CYCLE_KEY: &str = "run.cycle_us";

/// When the points differ in cycle time: that their shifts are shares of different cycles
/// (the same time is a smaller share of a longer one, so the answer leans to the longest
/// cycle), and the shortest cycle each method held, what a sweep over the cycle is run for.
fn cycles_text(rows: &[ResultRow], pts: &Points) -> String {
    let Some(i) = (0..pts.keys.len()).find(|&i| pts.keys[i] == CYCLE_KEY && varies(pts, i)) else {
        return String::new();
    };
    let cycle = |p: usize| match &pts.rows[p][i] {
        toml::Value::Integer(n) => *n as f64,
        toml::Value::Float(x) => *x,
        _ => f64::NAN,
    };
    let mut shortest: BTreeMap<&str, Option<&ResultRow>> = BTreeMap::new();
    for r in rows {
        let slot = shortest.entry(r.method.as_str()).or_insert(None);
        if good(r) && slot.is_none_or(|b| cycle(r.point) < cycle(b.point)) {
            *slot = Some(r);
        }
    }
    let each: Vec<String> = shortest
        .iter()
        .map(|(m, r)| match r {
            Some(r) => format!(
                "{m} {} us (point {})",
                grid::show(&pts.rows[r.point][i]),
                r.point
            ),
            None => format!("{m} none"),
        })
        .collect();
    format!(
        "The points differ in cycle time ({CYCLE_KEY}): each safe shift is a share of its own point's cycle, and the same time is a smaller share of a longer cycle, so the answer leans to the longest. The shortest cycle each method held (no late or lost frame, on target): {}.\n",
        each.join(", ")
    )
}

/// The scenario's seed as a swept key.
const SEED_KEY: &str = "run.seed";

/// The smallest and largest of `xs` (NaN left out), in words with `places` digits.
fn range(xs: impl Iterator<Item = f64>, places: usize, unit: &str) -> String {
    let (lo, hi) = xs
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
    if !lo.is_finite() {
        return "none".into();
    }
    format!("{lo:.places$} to {hi:.places$}{unit}")
}

/// The answer of a sweep over the seed alone: no point to pick, each method's spread over
/// the seeds (the noise a single comparison's figures carry).
fn seeds_text(rows: &[ResultRow], done: usize, total: usize) -> String {
    let so_far = if done < total {
        format!(" ({done} of the {total} points ran)")
    } else {
        String::new()
    };
    let mut t = format!(
        "Answer: no point to pick: the points differ by their seed ({SEED_KEY}) only, so what moves between them is run-to-run noise, not a design choice.\nEach method over the {}{so_far} (the spread is the noise of one comparison's figures; a design difference smaller than it is none):\n",
        plural(done, "seed", "seeds")
    );
    let mut methods: Vec<&str> = rows.iter().map(|r| r.method.as_str()).collect();
    methods.dedup();
    methods.sort_unstable();
    methods.dedup();
    let width = methods.iter().map(|m| m.len()).max().unwrap_or(0);
    for m in methods {
        let mine: Vec<&ResultRow> = rows.iter().filter(|r| r.method == m).collect();
        let bad = mine.iter().filter(|r| !good(r)).count();
        let _ = writeln!(
            t,
            "  {m:<width$}  safe shift {}, phase error p99.9 {}; {}",
            range(mine.iter().map(|r| r.safe_shift_pct), 1, " %"),
            range(mine.iter().map(|r| r.phase_error_p999_ns), 0, " ns"),
            if bad == 0 {
                "no late or lost frame at any seed, on target".to_string()
            } else {
                format!(
                    "late or lost frames, off target or not ranked at {bad} of {} seeds",
                    mine.len()
                )
            }
        );
    }
    t
}

/// The sweep's answer from the database's rows.
pub fn text(store: &Store, pts: &Points) -> Result<String> {
    let rows = store.rows()?;
    let done = store.done()?.len();
    let total = pts.rows.len();
    if done == 0 {
        return Ok(format!(
            "Answer: none yet: no point of this sweep has run yet (0 of its {}).\n",
            plural(total, "point", "points")
        ));
    }
    if seed_only(store, pts)? {
        return Ok(seeds_text(&rows, done, total));
    }
    let Best {
        per_method: best,
        overall,
    } = best(&rows);
    let mut t = String::new();
    let tie_words = format!("within {SHIFT_TIE_PCT} % of the cycle, the comparison's tie step");
    match overall {
        Some(r) => {
            let _ = writeln!(
                t,
                "Answer: {} at point {} ({}): smallest safe SYNC0 shift {:.1} %, phase error p99.9 {:.0} ns, slave spread p99.9 {:.0} ns, no late or lost frame.",
                r.method,
                r.point,
                pts.describe(r.point),
                r.safe_shift_pct,
                r.phase_error_p999_ns,
                r.slave_spread_p999_ns
            );
            if r.settling {
                let _ = writeln!(
                    t,
                    "  Warning: {} was still settling at point {} when the recording began (compare's `settling` warning): its figures hold the pull-in, not only where it settles; a longer warm-up (run.warmup_s) at that point shows whether the answer stands.",
                    r.method, r.point
                );
            }
            let same = ties(&rows, r);
            let points_of = rows.iter().filter(|x| x.method == r.method).count();
            // Every point: of the sweep, not of those run so far.
            if same.len() + 1 == points_of && points_of > 1 && done == total {
                let _ = writeln!(
                    t,
                    "  Every point of {} is as good ({tie_words}): the swept parameters make no difference to it here beyond noise.",
                    r.method
                );
            } else if !same.is_empty() {
                let _ = writeln!(t, "  As good ({tie_words}): points {}.", some_points(&same));
            }
            let others: Vec<String> = best
                .iter()
                .filter_map(|(m, b)| b.map(|b| (m, b)))
                .filter(|(m, b)| {
                    **m != r.method && b.safe_shift_pct <= r.safe_shift_pct + SHIFT_TIE_PCT
                })
                .map(|(m, b)| format!("{m} ({:.1} % at point {})", b.safe_shift_pct, b.point))
                .collect();
            if !others.is_empty() {
                let _ = writeln!(
                    t,
                    "  Other methods as good at their best ({tie_words}): {}.",
                    others.join(", ")
                );
            }
        }
        None if done < total => {
            let _ = writeln!(
                t,
                "Answer: none so far: {done} of the {total} points ran, and no method at any of them ran without late or lost frames on its target."
            );
        }
        None => {
            let _ = writeln!(
                t,
                "Answer: none: no method at any of the {} ran without late or lost frames on its target.",
                plural(done, "point", "points")
            );
        }
    }
    if done < total {
        let _ = writeln!(
            t,
            "Each method's best point ({done} of the {total} points ran):"
        );
    } else {
        let _ = writeln!(t, "Each method's best point of {done} ({total} swept):");
    }
    let width = best.keys().map(|m| m.len()).max().unwrap_or(0);
    for (m, r) in &best {
        match r {
            Some(r) => {
                let _ = writeln!(
                    t,
                    "  {m:<width$}  point {}: safe shift {:.1} %, phase error p99.9 {:.0} ns ({}){}",
                    r.point,
                    r.safe_shift_pct,
                    r.phase_error_p999_ns,
                    pts.describe(r.point),
                    if r.settling {
                        "; still settling as the recording began"
                    } else {
                        ""
                    }
                );
            }
            None => {
                let _ = writeln!(
                    t,
                    "  {m:<width$}  no point without late or lost frames on target ({})",
                    why_no_point(&rows, m)
                );
            }
        }
    }
    t.push_str(&cycles_text(&rows, pts));
    if seeds_vary(store, pts)? {
        let _ = writeln!(
            t,
            "The points ran with different seeds ({SEED_KEY} swept): a point's figures hold its seed's noise as well as its parameters, so the best point is partly a lucky seed; weigh a parameter by its figures over every seed (their spread is the noise), not by one point."
        );
    } else {
        let _ = writeln!(
            t,
            "Every point ran with the same seed (its noise the same): sweep run.seed, or give --runs 3 or more, to see how far the figures move from run to run."
        );
    }
    Ok(t)
}
