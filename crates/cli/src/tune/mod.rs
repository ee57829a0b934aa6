//! `ecsync tune`: one method's gains searched on the user's network and host for the smallest
//! SYNC0 shift that no frame misses, holding the target: a coarse grid around the defaults,
//! then a finer one around the best; the winner weighed against the defaults run by run (the
//! same seeds, so the same noise); optionally the shortest cycle the host holds, by bisection.

use crate::source::SourceArgs;
use crate::sweep::{grid, point};
use anyhow::{Result, bail};
use ecsync_dc::MethodKind;
use ecsync_lab::report::{SHIFT_TIE_PCT, SummaryOut};
use ecsync_master::transport::SendMode;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use toml::Value;

mod fragment;
use fragment::fragment;

/// Set by Ctrl-C or SIGTERM.
static STOP: AtomicBool = AtomicBool::new(false);

/// `ecsync tune`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    /// The method to tune (median, median-fit, pi-m2s, dcm-bus-shift, dcm-master-shift have
    /// gains; the others only get their shift and cycle).
    #[arg(long)]
    method: String,
    /// Runs per point: the spread between them is the noise the tuned figure is weighed
    /// against (at least 2 to weigh it).
    #[arg(long, default_value_t = 3)]
    runs: u32,
    /// Recorded cycles per run (default: the scenario's).
    #[arg(long)]
    cycles: Option<u64>,
    /// Warm-up per run, s (default: the scenario's).
    #[arg(long)]
    warmup_s: Option<f64>,
    /// Also find the shortest cycle this host holds with the tuned parameters and the
    /// fragment's SYNC0 shift, kept in us after the grid point (no late or lost frame), by
    /// bisection over run.cycle_us.
    #[arg(long)]
    shortest_cycle: bool,
    /// Also weigh the host's other send modes (spin, txtime, and hwstamp for a master-shift
    /// method) with the chosen gains against the scenario's plain sends, run by run: what the
    /// send jitter after the method's decision costs, which no gain can filter.
    #[arg(long)]
    send_modes: bool,
    /// The shortest-cycle search's resolution, us.
    #[arg(long, default_value_t = 10.0)]
    cycle_step_us: f64,
    /// Simulation threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// No line per point.
    #[arg(long)]
    quiet: bool,
}

/// A parameter the search moves: its key in the scenario file and the values it tries
/// around `centre`.
#[derive(Debug, Clone)]
struct Knob {
    key: String,
    /// Odd integers from a list (a median window), else a positive real.
    window: bool,
}

/// The knobs of a method and their defaults in the base scenario.
fn knobs(kind: MethodKind, s: &ecsync_lab::Scenario) -> Vec<(Knob, f64)> {
    let p = &s.params;
    let k = |name: &str, window: bool, v: f64| {
        (
            Knob {
                key: format!("methods.{kind}.{name}"),
                window,
            },
            v,
        )
    };
    match kind {
        MethodKind::Median => vec![
            k("gain", false, p.median.gain),
            k("window", true, p.median.window as f64),
        ],
        MethodKind::MedianFit => vec![
            k("gain", false, p.median_fit.gain),
            k("window", true, p.median_fit.window as f64),
        ],
        MethodKind::PiM2s => vec![k("kp", false, p.pi_m2s.kp), k("ki", false, p.pi_m2s.ki)],
        MethodKind::DcmBusShift => vec![
            k("kp", false, p.dcm_bus_shift.kp),
            k("ki", false, p.dcm_bus_shift.ki),
        ],
        MethodKind::DcmMasterShift => vec![
            k("kp", false, p.dcm_master_shift.kp),
            k("ki", false, p.dcm_master_shift.ki),
        ],
        MethodKind::KickcatPll => vec![
            k("kp", false, p.kickcat_pll.kp),
            k("ki", false, p.kickcat_pll.ki),
        ],
        MethodKind::Des => vec![k("alpha", false, p.des.alpha), k("beta", false, p.des.beta)],
        MethodKind::Kalman => vec![
            k("meas_sigma_ns", false, p.kalman.meas_sigma_ns),
            k("drift_walk_ns", false, p.kalman.drift_walk_ns),
        ],
        MethodKind::BusShift
        | MethodKind::Snap
        | MethodKind::SoemPi
        | MethodKind::IghAppTime
        | MethodKind::LinuxcncPll => Vec::new(),
    }
}

/// A knob's values around `centre`: a real times each factor (rounded to 4 significant
/// digits, so the fragment reads as typed), a window from 5, 11, 21 and the centre.
fn values(knob: &Knob, centre: f64, factors: &[f64]) -> Vec<Value> {
    if knob.window {
        let mut w: Vec<i64> = vec![5, 11, 21, centre as i64];
        w.sort_unstable();
        w.dedup();
        return w.into_iter().map(Value::Integer).collect();
    }
    let mut v: Vec<f64> = factors.iter().map(|f| round4(centre * f)).collect();
    v.dedup();
    v.into_iter().map(Value::Float).collect()
}

fn round4(x: f64) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let e = 10f64.powi(3 - x.abs().log10().floor() as i32);
    (x * e).round() / e
}

/// What a point gave the method.
#[derive(Debug, Clone)]
struct Outcome {
    /// Ranked, no late or lost frame, on target.
    good: bool,
    safe_shift_pct: f64,
    phase_error_p999_ns: f64,
    late_frames: u64,
    lost_frames: u64,
    /// Each run's smallest safe shift, %.
    per_run_pct: Vec<f64>,
    /// The smallest SYNC0 shift, % of the cycle, at which the method holds its target by
    /// compare's rule (its mean phase within 10 % of the margin the shift leaves): a tight
    /// shift leaves a small margin, and an offset a wide one forgives ranks it off target.
    hold_shift_pct: f64,
    /// The mean phase's distance from the target, ns.
    offset_ns: f64,
    /// The comparison's warning that the method was still settling as the recording began
    /// (its start is in the figures: a gain that pulls in slowly looks worse than it holds).
    settling: Option<String>,
    /// Why it does not hold, in `compare`'s words (empty when it holds).
    why_not: String,
}

impl Outcome {
    fn of(out: &SummaryOut, method: &str) -> Option<Outcome> {
        let m = out.methods.get(method)?;
        let g = &m.ground_truth;
        let ranked = out.recommendation.ranking.iter().any(|r| r == method);
        let good = ranked && g.late_frames == 0 && g.lost_frames == 0 && g.holds_target;
        Some(Outcome {
            good,
            safe_shift_pct: g.smallest_safe_shift_pct,
            phase_error_p999_ns: g.phase_error.p999_abs,
            late_frames: g.late_frames,
            lost_frames: g.lost_frames,
            hold_shift_pct: hold_shift_pct(out, g),
            offset_ns: g.offset_from_target_ns,
            per_run_pct: m
                .runs
                .iter()
                .map(|r| r.keys.smallest_safe_shift_pct)
                .collect(),
            settling: out
                .warnings
                .iter()
                .find(|w| w.kind == "settling" && w.method.as_deref() == Some(method))
                .map(|w| w.message.clone()),
            why_not: if good {
                String::new()
            } else {
                why_not(out, method)
            },
        })
    }

    /// Smaller is better: good first, then the safe shift, then the phase error.
    fn key(&self) -> (u8, f64, f64) {
        let nan = |x: f64| if x.is_nan() { f64::INFINITY } else { x };
        (
            u8::from(!self.good),
            nan(self.safe_shift_pct),
            nan(self.phase_error_p999_ns),
        )
    }
}

/// [`Outcome::hold_shift_pct`] from a point's figures: the shift whose margin (the shift less
/// the target and the frame's transit from the reference to the last drive, here this
/// method's own) is ten times the method's offset from its target.
fn hold_shift_pct(out: &SummaryOut, g: &ecsync_lab::report::GroundTruth) -> f64 {
    let shift_ns = out.sync0_shift_pct / 100.0 * f64::from(out.cycle_ns);
    let transit_ns = shift_ns - g.sync0_margin.mean - g.phase.mean;
    let need_ns = out.target_phase_ns as f64 + transit_ns + 10.0 * g.offset_from_target_ns.abs();
    need_ns / f64::from(out.cycle_ns) * 100.0
}

/// Why `method` does not hold in `out`, in `compare`'s words: why it is not ranked, or its late
/// and lost frames and the warning that it sits off its target.
fn why_not(out: &SummaryOut, method: &str) -> String {
    let rec = &out.recommendation;
    if let Some(n) = rec.not_ranked.iter().find(|n| n.method == method) {
        return n.why.clone();
    }
    let Some(m) = out.methods.get(method) else {
        return format!("{method} did not run");
    };
    let g = &m.ground_truth;
    let mut parts = Vec::new();
    if g.late_frames > 0 {
        parts.push(format!(
            "{} with a frame after SYNC0 at the {} % shift",
            ecsync_lab::scenario::plural(g.late_frames, "cycle", "cycles"),
            g.sync0_shift_pct
        ));
    }
    if g.lost_frames > 0 {
        parts.push(ecsync_lab::scenario::plural(
            g.lost_frames,
            "lost frame",
            "lost frames",
        ));
    }
    if !g.holds_target {
        parts.push(
            out.warnings
                .iter()
                .find(|w| w.kind == "off_target" && w.method.as_deref() == Some(method))
                .map_or_else(
                    || format!("{method} sits off its target"),
                    |w| w.message.clone(),
                ),
        );
    }
    parts.join("; ")
}

/// What a comparison tune runs is for, in the order tune runs them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// The defaults and the gains' grids.
    Gains,
    /// `--send-modes`: each other send mode with the chosen gains.
    SendModes,
    /// The fragment's SYNC0 shift confirmed.
    Confirm,
    /// `--shortest-cycle`: the bisection and the step below.
    ShortestCycle,
}

impl Phase {
    const ALL: [Phase; 4] = [
        Phase::Gains,
        Phase::SendModes,
        Phase::Confirm,
        Phase::ShortestCycle,
    ];

    /// What the comparisons of this phase were for, after their number.
    fn words(self) -> &'static str {
        match self {
            Phase::Gains => "in the gain search",
            Phase::SendModes => "weighing the send modes",
            Phase::Confirm => "confirming the fragment's shift",
            Phase::ShortestCycle => "searching the shortest cycle",
        }
    }
}

/// The search's state: the base, what ran, how to say it.
struct Search<'a> {
    name: String,
    base: toml::Table,
    method: String,
    threads: usize,
    quiet: bool,
    /// Every point run, by its values' text.
    seen: BTreeMap<String, Option<Outcome>>,
    /// What the comparisons [`Search::eval`] runs now are for.
    phase: Phase,
    /// The comparisons run (a point asked for again is not run again), per [`Phase`] in
    /// [`Phase::ALL`]'s order.
    ran: [usize; 4],
    /// The points the scenario refused (a gain x 4 past what the method takes), how many and
    /// the first's words: they are in `seen` but never ran.
    refused: (usize, Option<String>),
    args: &'a Args,
}

impl Search<'_> {
    /// The outcome at `keys` = `vals` (`None`: the scenario refuses the values, or the point
    /// never ran a cycle). `Err` with the stop flag set: stopped.
    fn eval(&mut self, keys: &[String], vals: &[Value]) -> Result<Option<Outcome>> {
        let what: Vec<String> = keys
            .iter()
            .zip(vals)
            .map(|(k, v)| format!("{k}={}", grid::show(v)))
            .collect();
        let what = what.join(", ");
        if let Some(o) = self.seen.get(&what) {
            return Ok(o.clone());
        }
        let mut refused = None;
        let o = match point::scenario_text(&self.name, &self.base, keys, vals, &what) {
            Err(e) => {
                self.refused.0 += 1;
                if self.refused.1.is_none() {
                    self.refused.1 = Some(format!("{e:#}"));
                }
                refused = Some(e);
                None
            }
            Ok(text) => {
                let Some(out) = point::run(&self.name, &text, self.threads, &STOP)? else {
                    bail!("stopped");
                };
                self.ran[self.phase as usize] += 1;
                Outcome::of(&out, &self.method)
            }
        };
        if !self.quiet {
            match &o {
                Some(o) => eprintln!(
                    "  {what}: safe shift {:.1} %, phase error p99.9 {:.0} ns, {} late, {} lost{}",
                    o.safe_shift_pct,
                    o.phase_error_p999_ns,
                    o.late_frames,
                    o.lost_frames,
                    if o.good { "" } else { " (not a candidate)" }
                ),
                None => match &refused {
                    Some(e) => eprintln!("  refused: {e:#}"),
                    None => eprintln!("  {what}: no cycle ran"),
                },
            }
        }
        self.seen.insert(what, o.clone());
        Ok(o)
    }

    /// Every combination of `grid`'s values; the best (values, outcome).
    fn best_of(
        &mut self,
        keys: &[String],
        grid: &[Vec<Value>],
    ) -> Result<Option<(Vec<Value>, Outcome)>> {
        let mut rows: Vec<Vec<Value>> = vec![Vec::new()];
        for vals in grid {
            rows = rows
                .into_iter()
                .flat_map(|r| {
                    vals.iter().map(move |v| {
                        let mut r = r.clone();
                        r.push(v.clone());
                        r
                    })
                })
                .collect();
        }
        let mut best: Option<(Vec<Value>, Outcome)> = None;
        for r in rows {
            if let Some(o) = self.eval(keys, &r)?
                && best.as_ref().is_none_or(|(_, b)| o.key() < b.key())
            {
                best = Some((r, o));
            }
        }
        Ok(best)
    }
}

/// Student's t at 95 % (two-sided) for `df` degrees of freedom.
fn t95(df: usize) -> f64 {
    const T: [f64; 9] = [12.71, 4.30, 3.18, 2.78, 2.57, 2.45, 2.36, 2.31, 2.26];
    T.get(df.wrapping_sub(1)).copied().unwrap_or(2.0)
}

/// Runs `ecsync tune`.
pub fn run(args: Args) -> Result<ExitCode> {
    let Ok(kind) = args.method.parse::<MethodKind>() else {
        bail!(
            "--method: unknown method \"{}\"; fix: use one of: {}",
            args.method,
            MethodKind::list()
        );
    };
    if args.threads == Some(0) {
        bail!("--threads: 0 threads; fix: give at least 1 (default: all cores)");
    }
    if !(args.cycle_step_us.is_finite() && args.cycle_step_us >= 1.0) {
        bail!(
            "--cycle-step-us: {}; fix: give at least 1 us",
            args.cycle_step_us
        );
    }
    let (name, text) = args.source.load()?;
    let mut run_set = vec![
        (
            "methods",
            Value::Array(vec![Value::String(kind.to_string())]),
        ),
        ("runs", Value::Integer(i64::from(args.runs))),
    ];
    if let Some(c) = args.cycles {
        run_set.push(("cycles", Value::Integer(c as i64)));
    }
    if let Some(w) = args.warmup_s {
        run_set.push(("warmup_s", Value::Float(w)));
    }
    let base = point::base_table(&name, &text, &run_set)?;
    let base_s = ecsync_lab::parse(&name, &toml::to_string(&base)?).map_err(anyhow::Error::msg)?;
    crate::stop::raise_on_signals(&STOP);
    let mut search = Search {
        name: name.clone(),
        base,
        method: kind.to_string(),
        threads: args
            .threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        quiet: args.quiet,
        seen: BTreeMap::new(),
        phase: Phase::Gains,
        ran: [0; 4],
        refused: (0, None),
        args: &args,
    };
    match tune(&mut search, kind, &base_s) {
        Ok(t) => {
            print!("{t}{}", comparisons_run(&search));
            Ok(ExitCode::SUCCESS)
        }
        Err(e) if STOP.load(Ordering::Relaxed) => {
            // What the points run so far say is kept: the best of them, unrefined.
            match best_so_far(&search) {
                Some(line) => print!("{line}"),
                None => eprintln!("ecsync tune: {e}; nothing to report"),
            }
            Ok(crate::stop::exit_code())
        }
        Err(e) => Err(e),
    }
}

/// After Ctrl-C: the best point the search ran before it stopped, in words (`None`: no point
/// ran to the end).
fn best_so_far(search: &Search) -> Option<String> {
    let ran = search.seen.values().flatten().count();
    let (what, o) = search
        .seen
        .iter()
        .filter_map(|(w, o)| Some((w, o.as_ref()?)))
        .min_by(|a, b| {
            a.1.key()
                .partial_cmp(&b.1.key())
                .unwrap_or(std::cmp::Ordering::Equal)
        })?;
    let holds = if o.good {
        "holds the target without a late or lost frame"
    } else {
        "does not hold (late, lost or off target), nor did any other point"
    };
    Some(format!(
        "Stopped after {ran} of the search's points: the best so far is {what} (safe shift {:.1} %, phase error p99.9 {:.0} ns), which {holds}; not refined, nor weighed against the defaults run by run: run `ecsync tune` again to finish.\n",
        o.safe_shift_pct, o.phase_error_p999_ns
    ))
}

/// The search and its report.
fn tune(search: &mut Search, kind: MethodKind, base_s: &ecsync_lab::Scenario) -> Result<String> {
    let knobs = knobs(kind, base_s);
    let keys: Vec<String> = knobs.iter().map(|(k, _)| k.key.clone()).collect();
    let gainless = keys.is_empty();
    let defaults: Vec<Value> = knobs
        .iter()
        .map(|(k, v)| {
            if k.window {
                Value::Integer(*v as i64)
            } else {
                Value::Float(*v)
            }
        })
        .collect();
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Tuning {kind} on {} ({} x {} cycles per point, SYNC0 shift {} %, target phase {:.1} us):",
        search.name,
        plural_runs(base_s.runs),
        base_s.cycles,
        base_s.sync0_shift_pct,
        base_s.target_phase_ns as f64 / 1000.0
    );
    if !search.quiet {
        eprintln!("ecsync tune: the defaults");
    }
    let Some(def) = search.eval(&keys, &defaults)? else {
        bail!("the scenario with the defaults ran no cycle");
    };
    let (best_vals, best) = if keys.is_empty() {
        (defaults.clone(), def.clone())
    } else {
        if !search.quiet {
            eprintln!("ecsync tune: coarse grid around the defaults (x 1/4, 1/2, 1, 2, 4)");
        }
        let coarse: Vec<Vec<Value>> = knobs
            .iter()
            .map(|(k, v)| values(k, *v, &[0.25, 0.5, 1.0, 2.0, 4.0]))
            .collect();
        let (cv, co) = search
            .best_of(&keys, &coarse)?
            .unwrap_or((defaults.clone(), def.clone()));
        if !search.quiet {
            eprintln!("ecsync tune: finer grid around the best (x 0.7, 1, 1.4)");
        }
        let fine: Vec<Vec<Value>> = knobs
            .iter()
            .zip(&cv)
            .map(|((k, _), v)| match v {
                Value::Float(x) => values(k, *x, &[0.7, 1.0, 1.4]),
                v => vec![v.clone()],
            })
            .collect();
        let best = search.best_of(&keys, &fine)?.unwrap_or((cv, co));
        // The defaults stay the answer unless something beat them.
        if best.1.key() < def.key() {
            best
        } else {
            (defaults.clone(), def.clone())
        }
    };
    let describe = |vals: &[Value]| -> String {
        if vals.is_empty() {
            return "no gains of its own".into();
        }
        keys.iter()
            .zip(vals)
            .map(|(k, v)| format!("{} {}", k.rsplit('.').next().unwrap_or(k), grid::show(v)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for (what, vals, o) in [("defaults", &defaults, &def), ("tuned", &best_vals, &best)] {
        let _ = writeln!(
            t,
            "  {what:<8} ({}): smallest safe shift {:.1} %, phase error p99.9 {:.0} ns, {} late, {} lost{}",
            describe(vals),
            o.safe_shift_pct,
            o.phase_error_p999_ns,
            o.late_frames,
            o.lost_frames,
            if o.good {
                ""
            } else {
                ", not holding (late, lost or off target)"
            }
        );
        if let Some(w) = &o.settling {
            let _ = writeln!(t, "    (warning: {w})");
        }
    }
    let (verdict, beats) = weigh(&def, &best, best_vals == defaults);
    let _ = writeln!(t, "{verdict}");
    // The fragment gives what the verdict chose: the defaults unless the tuned point beat
    // them beyond noise.
    let (best_vals, best) = if beats {
        (best_vals, best)
    } else {
        (defaults.clone(), def.clone())
    };
    let (mut keys, mut best_vals, mut best) = (keys, best_vals, best);
    if search.args.send_modes {
        let (text, pick) = send_modes(search, kind, &keys, &best_vals, &best)?;
        t.push_str(&text);
        if let Some((mode, o)) = pick {
            // From here on (the shortest cycle) the method runs with that mode, under its
            // name in the summary.
            search.method = format!("{kind}+{mode}");
            keys.push("send.modes".into());
            best_vals.push(Value::Array(vec![Value::String(mode.name().into())]));
            best = o;
        }
    }
    if !best.good {
        t.push_str(&nothing_held(
            kind,
            gainless,
            &best,
            search.args.shortest_cycle,
        ));
        return Ok(t);
    }
    t.push_str(&fragment(search, &keys, &best_vals, &best, base_s)?);
    Ok(t)
}

/// `--send-modes`: each other send mode the method runs with, at `vals`, against the
/// scenario's plain sends (`plain`, the same seeds: the same noise before the send mode acts
/// on it); the best that beats plain beyond run-to-run noise, with its outcome.
fn send_modes(
    search: &mut Search,
    kind: MethodKind,
    keys: &[String],
    vals: &[Value],
    plain: &Outcome,
) -> Result<(String, Option<(SendMode, Outcome)>)> {
    if !search.quiet {
        eprintln!("ecsync tune: the send modes with these gains");
    }
    search.phase = Phase::SendModes;
    let mut keys = keys.to_vec();
    keys.push("send.modes".into());
    let mut t = String::from(
        "Send modes with these gains (the send jitter after the method's decision, which no gain filters):\n",
    );
    let mut pick: Option<(SendMode, Outcome)> = None;
    let method = std::mem::take(&mut search.method);
    for mode in SendMode::ALL {
        if mode == SendMode::Plain || !mode.applies_to(kind) {
            continue;
        }
        let mut v = vals.to_vec();
        v.push(Value::Array(vec![Value::String(mode.name().into())]));
        search.method = format!("{method}+{mode}");
        let o = search.eval(&keys, &v);
        search.method.clone_from(&method);
        let Some(o) = o? else {
            let _ = writeln!(t, "  {mode}: refused or never ran");
            continue;
        };
        let (verdict, beats) = against_plain(plain, &o, mode);
        let _ = writeln!(
            t,
            "  {mode}: smallest safe shift {:.1} % (plain {:.1} %), phase error p99.9 {:.0} ns, {} late, {} lost: {verdict}",
            o.safe_shift_pct,
            plain.safe_shift_pct,
            o.phase_error_p999_ns,
            o.late_frames,
            o.lost_frames
        );
        if beats && o.good && pick.as_ref().is_none_or(|(_, b)| o.key() < b.key()) {
            pick = Some((mode, o));
        }
    }
    search.method = method;
    let _ = match &pick {
        Some((mode, _)) => writeln!(
            t,
            "Send mode: {mode} (in the fragment below; it {}).",
            match mode {
                SendMode::Spin =>
                    "busy-waits up to [send] spin_margin_us each cycle on the master's core",
                SendMode::Txtime =>
                    "needs SO_TXTIME and the ETF qdisc on the master's interface (a NIC with launch time for the [send] launch_jitter_ns figure); `ecsync run` says which is missing",
                _ => "needs a NIC with hardware transmit stamps",
            }
        ),
        None => writeln!(
            t,
            "Send mode: plain; no other mode beat it beyond run-to-run noise."
        ),
    };
    Ok((t, pick))
}

/// How many comparisons tune ran, for what, and how many points the scenario refused (with
/// the first's words): every comparison, not the gain search's alone.
fn comparisons_run(search: &Search) -> String {
    let parts: Vec<String> = Phase::ALL
        .iter()
        .filter(|&&p| search.ran[p as usize] > 0)
        .map(|&p| format!("{} {}", search.ran[p as usize], p.words()))
        .collect();
    let total: usize = search.ran.iter().sum();
    let mut t = format!("Comparisons run: {total} ({})", parts.join(", "));
    if let (n, Some(first)) = &search.refused {
        let _ = write!(
            t,
            "; {n} more points refused by the scenario's checks, the first: {first}"
        );
    }
    t.push_str(".\n");
    t
}

/// What tune says when nothing held (`def`: the defaults' outcome, which the verdict kept):
/// why, in `compare`'s words, and, when `--shortest-cycle` asked for it, that no cycle was
/// searched and why.
fn nothing_held(kind: MethodKind, gainless: bool, def: &Outcome, shortest: bool) -> String {
    let mut t = if gainless {
        format!(
            "Nothing to paste: {kind} has no gains to tune, and on this network and host it does not hold: {}.\n",
            def.why_not
        )
    } else {
        format!(
            "Nothing to paste: {kind} holds at no point of the search on this network and host; with the defaults: {}.\n",
            def.why_not
        )
    };
    if shortest {
        t.push_str(
            "Shortest cycle: not searched: the method does not hold at the scenario's own cycle, and a shorter one leaves it less of the cycle.\n",
        );
    }
    t
}

fn plural_runs(n: u32) -> String {
    ecsync_lab::scenario::plural(u64::from(n), "run", "runs")
}

/// A send mode's outcome against plain sends', run by run (as [`weigh`] does): the verdict's
/// words and whether it beats plain beyond run-to-run noise.
fn against_plain(plain: &Outcome, o: &Outcome, mode: SendMode) -> (String, bool) {
    if !o.good {
        return (
            "does not hold (late or lost frames, or off target).".into(),
            false,
        );
    }
    if !plain.good {
        return ("holds where plain does not.".into(), true);
    }
    let (d, mean, half) = paired(plain, o);
    let runs: Vec<String> = d.iter().map(|x| format!("{x:.1}")).collect();
    let runs = runs.join(", ");
    if within_tie(mean) {
        return (
            format!(
                "within the comparison's tie step ({SHIFT_TIE_PCT} % of the cycle) of plain, which compare and sweep call as good ({mean:.2} %; per run, plain minus {mode}: {runs})."
            ),
            false,
        );
    }
    match half {
        None => (
            format!(
                "{mean:.1} % of the cycle smaller from 1 run: weighing it needs --runs 2 or more."
            ),
            false,
        ),
        Some(h) if mean - h > 0.0 => (
            format!(
                "{mean:.2} % of the cycle smaller, beyond run-to-run noise (per run, plain minus {mode}: {runs}; 95 % interval +-{h:.2})."
            ),
            true,
        ),
        Some(h) => (
            format!(
                "within run-to-run noise of plain ({mean:.2} %; per run, plain minus {mode}: {runs}; 95 % interval +-{h:.2})."
            ),
            false,
        ),
    }
}

/// The step the per-run smallest safe shift is rounded up to, % of the cycle (the comparison
/// reports it in tenths of a percent).
const SHIFT_STEP_PCT: f64 = 0.1;

/// Each run's smallest safe shift of `a` minus `b`'s, % of the cycle, their mean and the half
/// width of its 95 % interval (`None` from one run). Each difference is of two figures rounded
/// to [`SHIFT_STEP_PCT`], so runs whose differences print alike may differ by up to a step: the
/// spread is taken as at least the rounding's own (a step over the square root of 6, two
/// uniform roundings), never as none.
fn paired(a: &Outcome, b: &Outcome) -> (Vec<f64>, f64, Option<f64>) {
    let d: Vec<f64> = a
        .per_run_pct
        .iter()
        .zip(&b.per_run_pct)
        .map(|(x, y)| x - y)
        .collect();
    let n = d.len();
    let mean = d.iter().sum::<f64>() / n.max(1) as f64;
    if n < 2 {
        return (d, mean, None);
    }
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    let sd = sd.max(SHIFT_STEP_PCT / 6f64.sqrt());
    (d, mean, Some(t95(n - 1) * sd / (n as f64).sqrt()))
}

/// Whether `mean`, a gain in % of the cycle, is within the comparison's tie step: what
/// `compare` ranks alike and `sweep` calls as good is no gain, however the runs agree.
fn within_tie(mean: f64) -> bool {
    mean <= SHIFT_TIE_PCT
}

/// The tuned point against the defaults, run by run: the same seeds give both the same
/// noise, so each run's difference of the smallest safe shift is the tuning's effect plus
/// what the method's own response does with that noise; their mean against its 95 % interval.
fn weigh(def: &Outcome, best: &Outcome, same: bool) -> (String, bool) {
    if !def.good && !best.good {
        return (
            "Verdict: neither the defaults nor any point of the search held.".into(),
            false,
        );
    }
    if same {
        return (
            "Verdict: the defaults are the best point found; keep them.".into(),
            false,
        );
    }
    let (d, mean, half) = paired(def, best);
    let runs: Vec<String> = d.iter().map(|x| format!("{x:.1}")).collect();
    if !def.good && best.good {
        return (
            format!(
                "Verdict: the tuned parameters hold where the defaults do not (late or lost frames, or off target); use them (per run, defaults minus tuned: {} % of the cycle).",
                runs.join(", ")
            ),
            true,
        );
    }
    if within_tie(mean) {
        return (
            format!(
                "Verdict: the tuned parameters' {mean:.2} % of the cycle is within the comparison's tie step ({SHIFT_TIE_PCT} %), which compare and sweep call as good: no gain; keep the defaults (per run, defaults minus tuned: {}).",
                runs.join(", ")
            ),
            false,
        );
    }
    let Some(half) = half else {
        return (
            format!(
                "Verdict: the tuned point's shift is {mean:.1} % of the cycle smaller, from 1 run: whether that is more than run-to-run noise needs --runs 2 or more; keep the defaults until then."
            ),
            false,
        );
    };
    if mean - half > 0.0 {
        (
            format!(
                "Verdict: the tuned parameters beat the defaults by {mean:.2} % of the cycle on the smallest safe shift, beyond run-to-run noise (per run, defaults minus tuned: {}; 95 % interval +-{half:.2}); use them.",
                runs.join(", ")
            ),
            true,
        )
    } else {
        (
            format!(
                "Verdict: the tuned parameters' {mean:.2} % of the cycle is within run-to-run noise (per run, defaults minus tuned: {}; 95 % interval +-{half:.2}): keep the defaults.",
                runs.join(", ")
            ),
            false,
        )
    }
}
