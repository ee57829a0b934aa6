//! The fragment tune prints (its SYNC0 shift confirmed by a comparison at it) and the
//! shortest cycle that holds with it.

use super::{Outcome, Phase, Search};
use anyhow::Result;
use ecsync_lab::report::SHIFT_TIE_PCT;
use std::fmt::Write as _;
use toml::Value;

/// How many steps of the tie step above the first candidate the fragment's shift is looked for.
const FRAGMENT_SHIFT_TRIES: u32 = 6;

/// The SYNC0 shift the fragment gives, and the comment that says why: the smallest safe shift
/// plus the comparison's tie step as margin, or more where the method would not hold its
/// target there ([`Outcome::hold_shift_pct`]), confirmed by a comparison at that shift (the
/// search ran at the scenario's shift: pasted, the fragment must hold in `compare` as it is).
/// `None`: no shift of the few above the first held.
fn fragment_shift(
    search: &mut Search,
    keys: &[String],
    vals: &[Value],
    best: &Outcome,
) -> Result<Option<(f64, String)>> {
    let round_up = |pct: f64| (pct * 10.0 - 1e-6).ceil() / 10.0;
    let safe = round_up(best.safe_shift_pct + SHIFT_TIE_PCT);
    let first = safe.max(round_up(best.hold_shift_pct));
    search.phase = Phase::Confirm;
    let mut keys = keys.to_vec();
    keys.push("run.sync0_shift_pct".into());
    for i in 0..FRAGMENT_SHIFT_TRIES {
        let pct = round_up(first + f64::from(i) * SHIFT_TIE_PCT);
        if pct >= 100.0 {
            break;
        }
        let mut v = vals.to_vec();
        v.push(Value::Float(pct));
        if !search.eval(&keys, &v)?.is_some_and(|o| o.good) {
            continue;
        }
        let mut why = format!(
            "the smallest safe shift {:.1} % plus {SHIFT_TIE_PCT} % (the comparison's tie step) as margin",
            best.safe_shift_pct
        );
        if first > safe {
            let _ = write!(
                why,
                ", raised so that the method's mean phase, {:.1} us from its target, is within 10 % of the margin (compare's rule for holding the target)",
                best.offset_ns.abs() / 1000.0
            );
        }
        if i > 0 {
            let _ = write!(
                why,
                ", and by {:.1} % more: the comparison at {:.1} % did not hold (late or lost frames, or off target)",
                pct - first,
                round_up(pct - SHIFT_TIE_PCT)
            );
        }
        why.push_str("; confirmed by a comparison at this shift");
        return Ok(Some((pct, why)));
    }
    Ok(None)
}

/// The scenario fragment to paste (the shift [`fragment_shift`] confirmed, the parameters),
/// and with `--shortest-cycle` the shortest cycle it holds at.
pub(super) fn fragment(
    search: &mut Search,
    keys: &[String],
    vals: &[Value],
    best: &Outcome,
    base_s: &ecsync_lab::Scenario,
) -> Result<String> {
    let mut t = String::new();
    let Some((shift_pct, why)) = fragment_shift(search, keys, vals, best)? else {
        let _ = writeln!(
            t,
            "Nothing to paste: with these parameters no SYNC0 shift from {:.1} % up held in a confirming comparison (late or lost frames, or off target); the scenario's own {} % is what held.",
            best.safe_shift_pct + SHIFT_TIE_PCT,
            base_s.sync0_shift_pct
        );
        return Ok(t);
    };
    let _ = writeln!(t, "Scenario fragment (paste into the scenario file):");
    let _ = writeln!(t, "  [run]\n  sync0_shift_pct = {shift_pct:.1}   # {why}");
    let mut table = "";
    for (k, v) in keys.iter().zip(vals) {
        let (head, field) = k.rsplit_once('.').unwrap_or(("", k));
        if head != table {
            let _ = writeln!(t, "  [{head}]");
            table = head;
        }
        let _ = writeln!(t, "  {field} = {v}");
    }
    if search.args.shortest_cycle {
        t.push_str(&shortest_cycle(search, keys, vals, base_s, shift_pct)?);
    }
    Ok(t)
}

/// The fragment's SYNC0 shift at a cycle of `cycle_us`: the same time after the grid point
/// (`shift_us`) as a share of that cycle, rounded up to 0.1 % (the digit the fragment gives);
/// `None` where it is the whole cycle or more.
fn shift_pct_at(shift_us: f64, cycle_us: f64) -> Option<f64> {
    // Less a hair, so that a share that is whole in 0.1 % is not rounded up by the division's
    // last bit (90 us of 300 us is 30.0 %, not 30.1 %).
    let pct = (shift_us / cycle_us * 1000.0 - 1e-6).ceil() / 10.0;
    (pct < 100.0).then_some(pct)
}

/// The shortest cycle the host holds with `vals` and the fragment's SYNC0 shift (`shift_pct`
/// of the scenario's cycle: no late or lost frame, on target), by bisection over run.cycle_us,
/// then confirmed one step below. The shift is held in time, not in share: a frame's margin
/// before SYNC0 is time after the grid point whatever the cycle, so a share fixed while the
/// cycle shrinks would find late frames the fragment's own shift does not make.
fn shortest_cycle(
    search: &mut Search,
    keys: &[String],
    vals: &[Value],
    base_s: &ecsync_lab::Scenario,
    shift_pct: f64,
) -> Result<String> {
    let step = search.args.cycle_step_us;
    let hi0 = f64::from(base_s.cycle_ns) / 1000.0;
    let shift_us = shift_pct * hi0 / 100.0;
    search.phase = Phase::ShortestCycle;
    let mut keys = keys.to_vec();
    keys.push("run.sync0_shift_pct".into());
    keys.push("run.cycle_us".into());
    let holds = |search: &mut Search, us: f64| -> Result<Option<Outcome>> {
        let Some(pct) = shift_pct_at(shift_us, us) else {
            return Ok(None);
        };
        let mut v = vals.to_vec();
        v.push(Value::Float(pct));
        v.push(Value::Float(us));
        search.eval(&keys, &v)
    };
    let mut t = String::new();
    if !search.quiet {
        eprintln!(
            "ecsync tune: the shortest cycle with SYNC0 {shift_us:.1} us after the grid point, by bisection in steps of {step} us"
        );
    }
    if !holds(search, hi0)?.is_some_and(|o| o.good) {
        let _ = writeln!(
            t,
            "Shortest cycle: the scenario's own {hi0} us does not hold at the fragment's {shift_pct:.1} % (late or lost frames): nothing shorter will."
        );
        return Ok(t);
    }
    let (mut lo, mut hi) = (0.0f64, hi0);
    while hi - lo > step {
        let mid = ((lo + hi) / 2.0 / step).round() * step;
        // A step of a cycle or more (--cycle-step-us 499 on a 500 us cycle) leaves lo + step
        // above hi - step: the one step inside (lo, hi) is lo + step (clamp panicked).
        let mid = mid.clamp(lo + step, (hi - step).max(lo + step));
        if holds(search, mid)?.is_some_and(|o| o.good) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let below = hi - step;
    let min_us = ecsync_lab::scenario::CYCLE_US_RANGE.0;
    let b = if below >= min_us {
        holds(search, below)?
    } else {
        None
    };
    let at = holds(search, hi)?.expect("held");
    let at_pct = shift_pct_at(shift_us, hi).expect("held");
    let _ = writeln!(
        t,
        "Shortest cycle this host holds with these parameters and SYNC0 {shift_us:.1} us after the grid point (the fragment's shift): {hi} us, with sync0_shift_pct = {at_pct:.1} there (no late or lost frame, safe shift {:.1} %); {}.",
        at.safe_shift_pct,
        if below < min_us {
            format!(
                "a step of {step} us below it is no cycle (a cycle is {min_us} us at least): give a smaller --cycle-step-us to look closer"
            )
        } else {
            format!(
                "at {below} us: {}",
                match &b {
                    Some(o) if o.good =>
                        "it held too (noise near the edge: run more cycles)".to_string(),
                    Some(o) => format!(
                        "{} late and {} lost frames{}",
                        o.late_frames,
                        o.lost_frames,
                        if o.late_frames + o.lost_frames == 0 {
                            ", off target"
                        } else {
                            ""
                        }
                    ),
                    None if shift_pct_at(shift_us, below).is_none() => format!(
                        "no cycle for the fragment's shift (SYNC0 {shift_us:.1} us after the grid point is past a {below} us cycle)"
                    ),
                    None => "refused or never ran (below what the network takes)".to_string(),
                }
            )
        }
    );
    Ok(t)
}
