//! `ecsync compare`: every master synchronization method on the same network, host and noise,
//! and which to choose.

use crate::progress::Progress;
use crate::source::SourceArgs;
use anyhow::{Context, Result, bail};
use ecsync_dc::MethodKind;
use ecsync_lab::Scenario;
use ecsync_lab::compare::{Comparison, Options};
use ecsync_lab::output::write_atomic;
use ecsync_lab::report::{
    SummaryOut, csv, per_slave_text, summarize, table1_text, truth_text, verdict_text,
};
use ecsync_lab::run::{BringupProgress, RunError};
use ecsync_lab::scenario::plural;
use ecsync_sim::config::{ConfigSource, Problem};
use ecsync_sim::send::SendMode;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

/// Every fault's start and end and every recovery, per method and run, as CSV (times in s
/// after the start of the cyclic phase).
fn faults_csv(out: &SummaryOut, order: &[String]) -> String {
    use std::fmt::Write as _;
    let mut t = String::from("method,run,what,edge,at_s,detail\n");
    let q = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    for m in order {
        let Some(mo) = out.methods.get(m) else {
            continue;
        };
        for (run, f) in mo.faults.iter().enumerate() {
            for e in &f.events {
                let _ = writeln!(
                    t,
                    "{m},{run},{},{},{:.6},{}",
                    e.kind,
                    e.edge,
                    e.since_epoch_ns as f64 / 1e9,
                    q(&e.detail)
                );
            }
            for r in &f.recoveries {
                let what = match (&r.error, r.slaves.is_empty()) {
                    (Some(e), _) => format!("failed: {e}"),
                    (None, true) => "no slave had lost its configuration".to_string(),
                    (None, false) if r.left_op.is_empty() => {
                        format!("slaves {:?} configured again", r.slaves)
                    }
                    (None, false) => format!(
                        "slaves {:?} configured again ({})",
                        r.slaves,
                        r.left_op.join("; ")
                    ),
                };
                let _ = writeln!(
                    t,
                    "{m},{run},recovery,start,{:.6},{}",
                    r.start_ms / 1e3,
                    q(&what)
                );
                if let Some(end) = r.end_ms {
                    let _ = writeln!(t, "{m},{run},recovery,end,{:.6},{}", end / 1e3, q(&what));
                }
            }
        }
    }
    t
}

/// The faults' table: per method, what the schedule did, what the master saw, DC's worst
/// |0x092C| and the re-lock time after each fault (worst run).
fn faults_text(out: &SummaryOut, order: &[String]) -> String {
    use std::fmt::Write as _;
    let mut t = String::from(
        "Faults (all runs): frames the schedule dropped, cycles lost, late and duplicate replies, skipped cycles, DC's largest |0x092C| of a cycle that came back, re-lock after each fault (100 cycles with |0x092C| in the method's lock band, 100 ns or what it holds without faults if more, and M-rS in its error band; worst run):\n",
    );
    for m in order {
        let Some(mo) = out.methods.get(m) else {
            continue;
        };
        if mo.faults.is_empty() {
            continue;
        }
        let sum =
            |f: fn(&ecsync_lab::run::FaultsTruth) -> u64| mo.faults.iter().map(f).sum::<u64>();
        let dropped = sum(|f| f.counts.lost_out + f.counts.lost_back);
        let max092c = mo.faults.iter().map(|f| f.max_rs_is_ns).max().unwrap_or(0);
        let n = mo
            .faults
            .iter()
            .map(|f| f.relock_ms.len())
            .max()
            .unwrap_or(0);
        let relock: Vec<String> = (0..n)
            .map(|k| {
                let worst = mo
                    .faults
                    .iter()
                    .map(|f| f.relock_ms.get(k).copied().flatten());
                let mut w = Some(0.0f64);
                for x in worst {
                    w = match (w, x) {
                        (Some(a), Some(b)) => Some(a.max(b)),
                        _ => None,
                    };
                }
                match w {
                    Some(ms) => format!("{ms:.1} ms"),
                    None => "never".to_string(),
                }
            })
            .collect();
        let _ = writeln!(
            t,
            "  {m:<18} dropped {dropped}, lost {}, late {}, duplicates {}, skipped {}, max |0x092C| {} ns (band {:.0}), re-lock {}",
            sum(|f| f.lost_cycles),
            sum(|f| f.late_replies),
            sum(|f| f.duplicate_replies),
            sum(|f| f.skipped_cycles),
            max092c,
            mo.faults
                .iter()
                .map(|f| f.lock_band_092c_ns)
                .fold(0.0f64, f64::max),
            if relock.is_empty() {
                "-".to_string()
            } else {
                relock.join(", ")
            }
        );
        let dups = sum(|f| f.duplicate_replies);
        if dups * 2 > mo.cycles_done {
            let _ = writeln!(
                t,
                "  {m:<18} a second responder: {dups} replies came twice (two segments on the wire, or a loop)"
            );
        }
    }
    t
}

/// What `--help` says after the options: the methods, the host presets, the defaults.
pub fn after_help() -> String {
    let mut t = String::from(
        "Methods (in report order; the first eight run unless --methods or the scenario names others):\n",
    );
    for m in MethodKind::ALL {
        t.push_str(&format!("  {:<18} {}\n", m.name(), m.summary()));
    }
    t.push_str("\nHost presets (--host; default preempt-rt-stress, the letter's testbed):\n");
    for h in ecsync_sim::host::HostParams::PRESETS {
        t.push_str(&format!("  {h}\n"));
    }
    // The defaults as the built-in preset gives them (read from it, so they cannot drift).
    if let Ok(p) = ecsync_lab::parse("paper-2024", ecsync_sim::preset::PAPER_2024_TOML) {
        let cycle_us = f64::from(p.cycle_ns) / 1000.0;
        t.push_str(&format!(
            "\nDefaults (from the scenario; the built-in preset paper-2024): {} x {} cycles after a {} s warm-up, cycle {} us, SYNC0 shift {} %, target phase {} us, seed {}.\n",
            plural(u64::from(p.runs), "run", "runs"),
            p.cycles,
            p.warmup_cycles as f64 * cycle_us / 1e6,
            cycle_us,
            p.sync0_shift_pct,
            p.target_phase_ns as f64 / 1000.0,
            p.seed
        ));
    }
    t.push_str(
        "Ctrl-C (or SIGTERM) stops the runs within a second and writes the statistics of the cycles done (exit code 130 after Ctrl-C, 143 after SIGTERM); during the bring-up it stops that, and nothing is written. Progress: a bar on a terminal, a line every 5 s otherwise (--quiet: none).",
    );
    t
}

/// Arguments of `ecsync compare`.
#[derive(Debug, clap::Args)]
#[command(after_help = after_help())]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    /// Play the faults of this schedule (TOML `[[fault]]` entries: loss, corrupt, delay,
    /// power_cycle, link_down, host_stall, clock_step, second_responder) on every run; times
    /// count from the start of the cyclic phase (warm-up included) unless it says
    /// `epoch = "start"`.
    #[arg(long)]
    faults: Option<PathBuf>,
    /// Methods to compare, comma-separated (default: the scenario's; all eight in the preset).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    methods: Option<Vec<String>>,
    /// Send modes every method runs with, comma-separated: plain (the letter's), spin (wake
    /// early, busy-wait to the instant), txtime (hand the frame over early with its launch
    /// time), hwstamp (send as plain, t_ms from the NIC's hardware transmit stamp; master-shift
    /// methods only); default: the scenario's `[send] modes`, plain alone unless it says
    /// otherwise.
    /// The modes' parameters are the scenario's `[send]` table.
    #[arg(long, value_delimiter = ',', num_args = 1.., value_parser = clap::value_parser!(SendMode))]
    send: Option<Vec<SendMode>>,
    /// Runs with different seeds.
    #[arg(long)]
    runs: Option<u32>,
    /// Recorded cycles per run.
    #[arg(long)]
    cycles: Option<u64>,
    /// Cycle time, us (the file's `run.cycle_us`); the warm-up keeps its length in seconds.
    #[arg(long, allow_negative_numbers = true)]
    cycle_us: Option<f64>,
    /// The master PC's crystal error against real time, ppm (the file's `host.master_ppm`,
    /// else the host preset's): its difference to the reference drive's crystal is the drift
    /// the methods compensate.
    #[arg(long, allow_negative_numbers = true)]
    master_ppm: Option<f64>,
    /// Warm-up per run, s (it must hold the methods' init frames: 10 s at 1 ms).
    #[arg(long, allow_negative_numbers = true)]
    warmup_s: Option<f64>,
    /// Host preset (see below), in place of the file's `[host]` table but its `master_ppm`
    /// (the machine's crystal, kept where the file gives it).
    #[arg(long)]
    host: Option<String>,
    /// Replay this host trace (`ecsync host record`, or `ecsync run --csv`) instead of the host
    /// model's j_s and e_m (and its TX delays where it has them), resampled in seeded blocks.
    #[arg(long, conflicts_with = "host")]
    host_trace: Option<PathBuf>,
    /// Cycles per replayed block of --host-trace (bursts shorter than a block stay bursts).
    #[arg(long, default_value_t = ecsync_sim::host_trace::DEFAULT_BLOCK_CYCLES, requires = "host_trace")]
    host_block_cycles: u64,
    /// SYNC0 shift after the DC grid point, % of the cycle (0 ..< 100).
    #[arg(long, allow_negative_numbers = true)]
    shift_pct: Option<f64>,
    /// Where every master-shift method aims the frame's arrival at the reference, us after the
    /// DC grid point (within half a cycle).
    #[arg(long, allow_negative_numbers = true)]
    target_phase_us: Option<f64>,
    /// Base seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Output directory for summary.json, summary.csv, plots and report.html.
    #[arg(long, default_value = "out/compare")]
    out: PathBuf,
    /// Also write every run's per-cycle ground truth and measurements as CSV to this directory
    /// (`<method>-run<r>.csv`: cycle, true phase, M-rS, rS-IS, slave spread, SYNC0 margins,
    /// late flag, and the controller's log for DCM).
    #[arg(long)]
    samples: Option<PathBuf>,
    /// Print summary.json to standard output instead of the tables.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// The command-line flag that set a scenario field, for messages.
fn flag_of(field: &str) -> Option<&'static str> {
    Some(match field {
        "run.warmup_s" => "--warmup-s",
        "run.sync0_shift_pct" => "--shift-pct",
        "run.target_phase_us" => "--target-phase-us",
        "run.runs" => "--runs",
        "run.cycles" => "--cycles",
        "run.cycle_us" => "--cycle-us",
        "host.master_ppm" => "--master-ppm",
        "run.methods" => "--methods",
        _ => return None,
    })
}

/// The problem as the user should read it: naming the flag if they gave it, else the file.
fn problem(p: Problem, given: &[&str], file: &str, text: &str) -> anyhow::Error {
    match flag_of(&p.field()) {
        Some(flag) if given.contains(&flag) => {
            anyhow::anyhow!("{flag}: {}; fix: {}", p.message, p.fix)
        }
        _ => anyhow::Error::msg(ConfigSource::new(file, text).locate(p)),
    }
}

static STOP: AtomicBool = AtomicBool::new(false);

/// Runs the comparison the arguments describe, writes its outputs and prints its tables (or
/// summary.json); exit code 128 + the signal when one stopped it (Ctrl-C 130, SIGTERM 143).
pub fn run(args: Args) -> Result<ExitCode> {
    let s = scenario(&args)?;
    if let Some(t) = args.threads
        && t == 0
    {
        bail!("--threads: 0 threads; fix: give at least 1 (default: all cores)");
    }
    // Before any work: a path that cannot take the results fails now, not after the runs.
    ecsync_lab::output::ensure_writable_dir(&args.out).map_err(|e| {
        anyhow::anyhow!(
            "--out: cannot write into {}: {e}; fix: give a folder you can write to",
            args.out.display()
        )
    })?;
    if let Some(dir) = &args.samples {
        ecsync_lab::output::ensure_writable_dir(dir).map_err(|e| {
            anyhow::anyhow!(
                "--samples: cannot write into {}: {e}; fix: give a folder you can write to",
                dir.display()
            )
        })?;
    }
    let Some(cmp) = compare(&args, &s)? else {
        eprintln!(
            "ecsync: stopped during the bring-up, before any cycle was measured; nothing written"
        );
        return Ok(crate::stop::exit_code());
    };
    let out = summarize(&cmp);
    let order: Vec<String> = s.entries().iter().map(|e| e.name()).collect();
    let written = write_outputs(&args, &cmp, &out, &order)?;
    if args.json {
        println!("{}", written.json);
    } else {
        print_tables(&args, &out, &order, &written.table1);
    }
    if out.interrupted {
        eprintln!(
            "ecsync: interrupted; wrote the statistics of the {} recorded cycles done to {}",
            out.cycles_done,
            args.out.display()
        );
        return Ok(crate::stop::exit_code());
    }
    Ok(ExitCode::SUCCESS)
}

/// The scenario: the file or preset, the fault schedule, and the flags over them, checked as
/// the file is (naming the flag where one set the value).
fn scenario(args: &Args) -> Result<Scenario> {
    let (name, text) = args.source.load()?;
    let mut s = ecsync_lab::parse(&name, &text).map_err(anyhow::Error::msg)?;
    if let Some(p) = &args.faults {
        s.faults = Some(ecsync_sim::fault::FaultSchedule::load(p).map_err(anyhow::Error::msg)?);
    }
    let mut given = Vec::new();
    if let Some(m) = &args.methods {
        given.push("--methods");
        let mut kinds = Vec::with_capacity(m.len());
        for x in m {
            match x.parse::<MethodKind>() {
                Ok(k) => kinds.push(k),
                Err(_) => bail!(
                    "--methods: unknown method \"{x}\"; fix: use one of: {}",
                    MethodKind::list()
                ),
            }
        }
        // Report order, each once.
        s.methods = MethodKind::ALL
            .into_iter()
            .filter(|k| kinds.contains(k))
            .collect();
    }
    if let Some(modes) = &args.send {
        given.push("--send");
        s.send_modes = SendMode::ALL
            .into_iter()
            .filter(|k| modes.contains(k))
            .collect();
    }
    if let Some(r) = args.runs {
        given.push("--runs");
        s.runs = r;
    }
    if let Some(c) = args.cycles {
        given.push("--cycles");
        s.cycles = c;
    }
    if let Some(us) = args.cycle_us {
        given.push("--cycle-us");
        if !(us.is_finite() && us > 0.0 && us * 1000.0 <= f64::from(u32::MAX)) {
            bail!("--cycle-us: {us} us; fix: give the cycle time in us, e.g. 1000 for 1 ms");
        }
        let cycle_ns = (us * 1000.0).round() as u32;
        // The warm-up keeps its length in time (its init frames are counted in frames, and a
        // shorter cycle sends more of them in the same seconds).
        s.warmup_cycles =
            (s.warmup_cycles as f64 * f64::from(s.cycle_ns) / f64::from(cycle_ns)).round() as u64;
        s.cycle_ns = cycle_ns;
    }
    if let Some(w) = args.warmup_s {
        given.push("--warmup-s");
        if !(w.is_finite() && (0.0..=86_400.0).contains(&w)) {
            bail!("--warmup-s: {w} s of warm-up; fix: give between 0 and 86400 s");
        }
        s.warmup_cycles = (w * 1e9 / f64::from(s.cycle_ns)).round() as u64;
    }
    if let Some(h) = &args.host {
        s.host = ecsync_sim::host::HostParams::preset(h).with_context(|| {
            format!(
                "--host: unknown host preset \"{h}\"; fix: use one of: {}",
                ecsync_sim::host::HostParams::PRESETS.join(", ")
            )
        })?;
        s.host_name = h.clone();
        // The file's own crystal stays: a preset describes a kernel and its load, the
        // file's master_ppm the machine (--master-ppm below still overrides it).
        if let Some(ppm) = s.file_master_ppm {
            s.host.master_ppm = ppm;
            s.host_name = format!("{h} (modified)");
        }
    }
    if let Some(ppm) = args.master_ppm {
        given.push("--master-ppm");
        s.host.master_ppm = ppm;
        if !s.host_name.ends_with("(modified)") {
            s.host_name = format!("{} (modified)", s.host_name);
        }
    }
    if let Some(path) = &args.host_trace {
        replay_host_trace(&mut s, path, args.host_block_cycles)?;
    }
    if let Some(p) = args.shift_pct {
        given.push("--shift-pct");
        s.sync0_shift_pct = p;
    }
    if let Some(t) = args.target_phase_us {
        given.push("--target-phase-us");
        if !t.is_finite() {
            bail!("--target-phase-us: {t}; fix: give the target in us after the DC grid point");
        }
        s.target_phase_ns = (t * 1000.0).round() as i64;
    }
    if let Some(seed) = args.seed {
        s.seed = seed;
    }
    // The same checks as for the file, naming the flag where one set the value.
    // A target at or after SYNC0 that the command line made: said of its options.
    if let Some(p) = s.target_after_sync0()
        && (given.contains(&"--shift-pct") || given.contains(&"--target-phase-us"))
    {
        bail!(
            "--shift-pct {} with --target-phase-us {}: the target {}; fix: a --target-phase-us below {:.1} (less the frames' way through the network) or a --shift-pct above {:.1}",
            s.sync0_shift_pct,
            s.target_phase_ns as f64 / 1000.0,
            p.message,
            f64::from(s.sync0_shift_ns()) / 1000.0,
            100.0 * s.target_phase_ns as f64 / f64::from(s.cycle_ns)
        );
    }
    s.check().map_err(|p| problem(p, &given, &name, &text))?;
    if let Some(f) = &s.faults {
        check_faults(
            f,
            &s.slaves,
            &s.name,
            (s.warmup_cycles + s.cycles, s.cycle_ns),
            "run longer (--cycles or run.cycles; --warmup-s or run.warmup_s)",
        )?;
    }
    Ok(s)
}

/// `--faults` against the network of `slaves` (called `network` in messages), before anything
/// runs: a fault that names a slave or a port the network lacks is refused; an empty schedule,
/// and a fault that starts after the run's end (`run_cycles` of `cycle_ns`, warm-up included,
/// for a schedule that counts from the cyclic phase), are warned about, with `how` to run
/// longer. `compare` and `tsn run` check their schedules here.
pub(crate) fn check_faults(
    f: &ecsync_sim::fault::FaultSchedule,
    slaves: &[ecsync_sim::SlaveSpec],
    network: &str,
    (run_cycles, cycle_ns): (u64, u32),
    how: &str,
) -> Result<()> {
    let seg = ecsync_sim::Segment::new(slaves).context("building the segment")?;
    f.check_segment(&seg, network).map_err(anyhow::Error::msg)?;
    // With epoch = "start" the bring-up's length (not known yet) counts too.
    let end_ns = (f.epoch == ecsync_sim::fault::Epoch::Cyclic)
        .then(|| run_cycles.saturating_mul(u64::from(cycle_ns)));
    for w in f.warnings(end_ns, how) {
        eprintln!("ecsync: warning: {w}");
    }
    Ok(())
}

/// `--host-trace`: the host's noise replayed from the trace at `path` in blocks of
/// `block_cycles`, with the model fitted to it where the simulator needs a mean.
fn replay_host_trace(s: &mut Scenario, path: &Path, block_cycles: u64) -> Result<()> {
    use ecsync_sim::host_fit::fit;
    use ecsync_sim::host_trace::{HostTrace, Replay};
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--host-trace: cannot read {file}"))?;
    let trace = HostTrace::parse(&file, &text).map_err(anyhow::Error::msg)?;
    // The model fitted to the trace stands for it where the simulator needs a mean (the
    // master's known lead), the trace gives every cycle's values.
    s.host = fit(&trace.rows, s.host).params;
    let replay = Replay::new(trace, block_cycles)
        .map_err(|e| anyhow::anyhow!("--host-block-cycles: {e}"))?;
    s.host_name = format!("trace {file} (blocks of {} cycles)", replay.block_cycles());
    s.host_trace = Some(std::sync::Arc::new(replay));
    Ok(())
}

/// The progress of the comparison's `total_cycles` (nothing with --quiet or --json).
fn progress(args: &Args, s: &Scenario, total_cycles: u64) -> Progress {
    let what = format!(
        "{} x {}",
        s.entries()
            .iter()
            .map(|e| e.name())
            .collect::<Vec<_>>()
            .join(", "),
        plural(u64::from(s.runs), "run", "runs")
    );
    Progress::new(args.quiet || args.json, what, total_cycles, s.runs)
}

/// Runs the comparison on `--threads` (default: all cores) with a progress bar; Ctrl-C (and
/// SIGTERM) stop the runs after their current slice, and what they measured is kept. `None`:
/// stopped during the bring-up, before any cycle was measured.
fn compare(args: &Args, s: &Scenario) -> Result<Option<Comparison>> {
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let total = (s.warmup_cycles + s.cycles) * u64::from(s.runs) * s.entries().len() as u64;
    let done = AtomicU64::new(0);
    let up = BringupProgress::default();
    let mut bar = progress(args, s, total);
    crate::stop::raise_on_signals(&STOP);
    let opts = Options {
        stop: Some(&STOP),
        samples_dir: args.samples.clone(),
        bringup: Some(&up),
    };
    let result = std::thread::scope(|sc| {
        let handle = sc.spawn(|| ecsync_lab::compare::compare_with(s, threads, &done, &opts));
        let mut said = false;
        while !handle.is_finished() {
            bar.update(done.load(Ordering::Relaxed), &up);
            if !said && STOP.load(Ordering::Relaxed) {
                said = true;
                bar.say("ecsync: stopping; writing what the runs measured so far");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        handle.join()
    });
    bar.finish();
    match result.map_err(|_| anyhow::anyhow!("a simulation thread panicked"))? {
        Ok(c) => Ok(Some(c)),
        Err(RunError::Interrupted) => Ok(None),
        // What the scenario file says is refused: named with the file (its field and fix are
        // in the words).
        Err(e @ (RunError::CycleTooShort { .. } | RunError::NoSync0Slave { .. })) => {
            Err(anyhow::anyhow!("{}: {e}", s.name))
        }
        Err(e) => Err(anyhow::anyhow!("{e}")),
    }
}

/// What [`write_outputs`] wrote that the terminal shows.
struct Written {
    /// summary.json.
    json: String,
    /// table1.txt.
    table1: String,
}

/// Writes summary.json, timing.json, summary.csv, faults.csv (with --faults), table1.txt, the
/// plots and report.html into --out.
fn write_outputs(
    args: &Args,
    cmp: &Comparison,
    out: &SummaryOut,
    order: &[String],
) -> Result<Written> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let json = serde_json::to_string_pretty(out)?;
    write_atomic(&args.out.join("summary.json"), json.as_bytes())?;
    write_atomic(
        &args.out.join("timing.json"),
        serde_json::to_string_pretty(&out.timing())?.as_bytes(),
    )?;
    write_atomic(&args.out.join("summary.csv"), csv(out, order).as_bytes())?;
    if args.faults.is_some() {
        write_atomic(
            &args.out.join("faults.csv"),
            faults_csv(out, order).as_bytes(),
        )?;
    }
    let table1 = table1_text(out, order);
    write_atomic(&args.out.join("table1.txt"), table1.as_bytes())?;
    ecsync_lab::plots::write_all(cmp, out, order, &args.out)
        .context("writing plots and report.html")?;
    Ok(Written { json, table1 })
}

/// The terminal's report: the scenario in a line, the verdict, the ground truth, the faults
/// (with --faults), per slave, Table 1 (`table1`), and what was written where.
fn print_tables(args: &Args, out: &SummaryOut, order: &[String], table1: &str) {
    let s_has_faults = args.faults.is_some();
    if out.interrupted {
        println!(
            "Interrupted: the statistics below are of the {} recorded cycles done.\n",
            out.cycles_done
        );
    }
    println!(
        "{}: {} slaves, host {}, master crystal {:+.1} ppm, {} x {} cycles after {} warm-up cycles, cycle {} us, SYNC0 shift {} %, target phase {:.1} us",
        out.scenario,
        out.slaves,
        out.host,
        out.master_ppm,
        plural(u64::from(out.runs), "run", "runs"),
        out.cycles,
        out.warmup_cycles,
        f64::from(out.cycle_ns) / 1000.0,
        out.sync0_shift_pct,
        out.target_phase_ns as f64 / 1000.0
    );
    println!();
    print!("{}", verdict_text(out));
    println!();
    print!("{}", truth_text(out, order));
    println!();
    if s_has_faults {
        print!("{}", faults_text(out, order));
        println!();
    }
    print!("{}", per_slave_text(out));
    println!();
    print!("{table1}");
    println!();
    println!(
        "Wrote {}/{{summary.json, timing.json, summary.csv, {}table1.txt, report.html, *.svg, *.png}} in {:.1} s on {}.",
        args.out.display(),
        if s_has_faults { "faults.csv, " } else { "" },
        out.wall_s,
        plural(out.threads as u64, "thread", "threads")
    );
    if let Some(d) = &args.samples {
        println!("Per-cycle samples in {}.", d.display());
    }
}
