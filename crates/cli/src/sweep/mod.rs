//! `ecsync sweep`: a deterministic comparison at every point of a grid (or list) over any
//! scenario or method parameter, the results in an SQLite database that resumes, shards and
//! merges, and the answer: which point, for which method.

mod answer;
mod db;
pub(crate) mod grid;
pub(crate) mod point;
mod report;

use crate::source::SourceArgs;
use anyhow::{Context, Result, bail};
use db::{Meta, Store};
use grid::{Param, Points};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Set by Ctrl-C or SIGTERM: the point in progress is dropped, the ones done are kept.
static STOP: AtomicBool = AtomicBool::new(false);

/// Set for stdout (0) and stderr (1) when a write to it failed: its reader went away.
static CLOSED: [AtomicBool; 2] = [const { AtomicBool::new(false) }; 2];

/// Writes `text` to stdout (`err` false) or stderr. A stream whose reader went away (`2>&1 |
/// head -2`) is not written again, and the sweep stops as Ctrl-C stops it: the point in
/// progress dropped, the ones done kept, the invocation's log row written, the same command
/// goes on. (Going on unseen would hold the pipeline's shell for the sweep's hours; dying of
/// SIGPIPE as `cat` does would leave no log row.) Never a panic, as `println!` would.
fn say(err: bool, text: std::fmt::Arguments) {
    use std::io::Write as _;
    let closed = &CLOSED[usize::from(err)];
    if closed.load(Ordering::Relaxed) {
        return;
    }
    let r = if err {
        std::io::stderr().lock().write_fmt(text)
    } else {
        let mut o = std::io::stdout().lock();
        o.write_fmt(text).and_then(|()| o.flush())
    };
    if r.is_err() {
        closed.store(true, Ordering::Relaxed);
        STOP.store(true, Ordering::Relaxed);
    }
}

/// `print!` through [`say`].
macro_rules! out {
    ($($t:tt)*) => { say(false, format_args!($($t)*)) };
}

/// `eprintln!` through [`say`].
macro_rules! note {
    ($($t:tt)*) => { say(true, format_args!("{}\n", format_args!($($t)*))) };
}

/// `ecsync sweep` and `ecsync sweep merge`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true, after_help = after_help())]
pub struct Args {
    #[command(subcommand)]
    command: Option<Sub>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Debug, clap::Subcommand)]
enum Sub {
    /// Joins the databases of a sweep's shards into one, equal to the sweep run whole.
    Merge(MergeArgs),
    /// Writes the report of a sweep's database (run whole, or shards merged): tradeoff.svg,
    /// heatmap-METHOD.svg when two keys are swept, sweep.html.
    Report(ReportArgs),
}

/// Writes a sweep's report from its database.
#[derive(Debug, clap::Args)]
struct ReportArgs {
    /// The sweep's database.
    #[arg(long, default_value = "sweep.db")]
    db: PathBuf,
    /// The report's folder (made when absent; the files in it replaced).
    #[arg(long, default_value = "out/sweep")]
    out: PathBuf,
}

/// Merges shard databases.
#[derive(Debug, clap::Args)]
struct MergeArgs {
    /// The merged database (made, or extended when it holds the same sweep).
    #[arg(long)]
    db: PathBuf,
    /// The shards' databases.
    #[arg(required = true)]
    shards: Vec<PathBuf>,
}

/// Runs a sweep.
#[derive(Debug, clap::Args)]
struct RunArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// A swept parameter: KEY=V1,V2,... or KEY=START:STOP:STEP (both ends included), KEY a
    /// field of the scenario file (run.sync0_shift_pct, methods.median-fit.gain,
    /// segment.slave.2.ppm, host.preset). Repeat it for a grid: every combination, the last
    /// one changing fastest. One value sets it for every point.
    #[arg(long = "grid", value_name = "KEY=VALUES")]
    grid: Vec<String>,
    /// The points as a CSV list instead of a grid: a header of keys, one point per line.
    #[arg(long, conflicts_with = "grid", value_name = "FILE")]
    list: Option<PathBuf>,
    /// The results database (SQLite): made when absent; a rerun of the same sweep skips the
    /// points it holds.
    #[arg(long, default_value = "sweep.db")]
    db: PathBuf,
    /// Run only the points whose number modulo N is I (0 <= I < N), e.g.
    /// `--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT`; `sweep merge` joins the shards.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Methods compared at every point (default: the scenario's).
    #[arg(long, value_delimiter = ',')]
    methods: Option<Vec<String>>,
    /// Runs per point (default: the scenario's).
    #[arg(long)]
    runs: Option<u32>,
    /// Recorded cycles per run (default: the scenario's).
    #[arg(long)]
    cycles: Option<u64>,
    /// Warm-up per run, s (default: the scenario's).
    #[arg(long)]
    warmup_s: Option<f64>,
    /// Simulation threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// No line per point.
    #[arg(long)]
    quiet: bool,
    /// Also write the report into this folder when the sweep is done: tradeoff.svg (every
    /// point's safe shift against its phase error), heatmap-METHOD.svg (two swept keys),
    /// sweep.html. From the database alone, as `ecsync sweep report` writes it.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

fn after_help() -> String {
    "A point's scenario is the base with the point's values written into it, checked as \
     `compare --config` checks a file. Every point runs with the scenario's seed: the methods \
     and the points see the same noise (sweep run.seed for run-to-run noise). The database's \
     view sweep_results has one row per point and method; `sqlite3 sweep.db 'select * from \
     sweep_results'`. Ctrl-C keeps the points done; the same command goes on."
        .to_string()
}

/// Runs `ecsync sweep`.
pub fn run(args: Args) -> Result<ExitCode> {
    match args.command {
        Some(Sub::Merge(m)) => merge(&m),
        Some(Sub::Report(r)) => write_report(&r),
        None => sweep(&args.run),
    }
}

/// "1 point", "6 points".
fn points_text(n: usize) -> String {
    ecsync_lab::scenario::plural(n as u64, "point", "points")
}

/// `--shard I/N`.
fn shard(arg: Option<&str>) -> Result<(usize, usize)> {
    let Some(s) = arg else { return Ok((0, 1)) };
    let bad = || {
        anyhow::anyhow!(
            "--shard {s}: not I/N with 0 <= I < N; fix: e.g. --shard 0/4 for the first of four shards"
        )
    };
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (i, n) = (
        i.trim().parse::<usize>().map_err(|_| bad())?,
        n.trim().parse::<usize>().map_err(|_| bad())?,
    );
    if n == 0 || i >= n {
        return Err(bad());
    }
    Ok((i, n))
}

/// The base scenario as a TOML table with the command line's settings written in.
fn base(a: &RunArgs) -> Result<(String, toml::Table)> {
    let (name, text) = a.source.load()?;
    let mut run: Vec<(&str, toml::Value)> = Vec::new();
    if let Some(m) = &a.methods {
        run.push(("methods", m.clone().into()));
    }
    if let Some(r) = a.runs {
        run.push(("runs", i64::from(r).into()));
    }
    if let Some(c) = a.cycles {
        run.push(("cycles", (c as i64).into()));
    }
    if let Some(w) = a.warmup_s {
        run.push(("warmup_s", w.into()));
    }
    let t = point::base_table(&name, &text, &run)?;
    Ok((name, t))
}

fn points(a: &RunArgs) -> Result<Points> {
    if let Some(path) = &a.list {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("--list: cannot read {}", path.display()))?;
        return Points::list(&path.display().to_string(), &text);
    }
    if a.grid.is_empty() {
        bail!("no points; fix: give --grid KEY=V1,V2,... (repeat it for a grid) or --list FILE");
    }
    let params: Vec<Param> = a
        .grid
        .iter()
        .map(|g| grid::parse_param(g))
        .collect::<Result<_>>()?;
    Points::grid(&params)
}

/// Every point's scenario, checked before any runs: a bad value is refused now, naming it.
fn scenarios(name: &str, base: &toml::Table, pts: &Points) -> Result<Vec<String>> {
    (0..pts.rows.len())
        .map(|i| {
            let what = format!("point {i} ({})", pts.describe(i));
            point::scenario_text(name, base, &pts.keys, &pts.rows[i], &what)
        })
        .collect()
}

fn sweep(a: &RunArgs) -> Result<ExitCode> {
    let (shard_i, shard_n) = shard(a.shard.as_deref())?;
    if a.threads == Some(0) {
        bail!("--threads: 0 threads; fix: give at least 1 (default: all cores)");
    }
    let (name, base) = base(a)?;
    let pts = points(a)?;
    let texts = scenarios(&name, &base, &pts)?;
    // Before the database is made and any point runs: a report that cannot be written fails
    // now, not after the sweep.
    if let Some(dir) = &a.report {
        report::check_dir("--report", dir)?;
    }
    let meta = Meta {
        base_name: name.clone(),
        base_toml: toml::to_string(&base)?,
        points: pts.clone(),
    };
    let mut store = Store::open(&a.db, &meta)?;
    let done = store.done()?;
    let mine: Vec<usize> = (0..pts.rows.len())
        .filter(|p| p % shard_n == shard_i)
        .collect();
    let todo: Vec<usize> = mine.iter().copied().filter(|p| !done.contains(p)).collect();
    let shard_text = format!("{shard_i}/{shard_n}");
    if !a.quiet {
        // The shard only when sharding: a sweep run whole is no shard of one.
        let share = if a.shard.is_some() {
            format!("; shard {shard_text}: {}", points_text(mine.len()))
        } else {
            String::new()
        };
        note!(
            "ecsync sweep: {} over {}{share}, {} already in {}, {} to run",
            points_text(pts.rows.len()),
            pts.keys.join(", "),
            mine.len() - todo.len(),
            a.db.display(),
            todo.len()
        );
    }
    crate::stop::raise_on_signals(&STOP);
    let threads = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let started = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs() as i64);
    let t0 = Instant::now();
    let mut ran = 0;
    for (k, &p) in todo.iter().enumerate() {
        if STOP.load(Ordering::Relaxed) {
            break;
        }
        // Another sweep on this database (the same command run twice, shards side by side
        // into one file) may have stored it since we looked: its rows stand (they are these).
        if store.has(p)? {
            continue;
        }
        let t = Instant::now();
        let out = match point::run(&format!("{name} at point {p}"), &texts[p], threads, &STOP) {
            Ok(Some(out)) => out,
            Ok(None) => break,
            Err(e) => bail!("point {p} ({}): {e}", pts.describe(p)),
        };
        let stored = store.put(p, &pts.rows[p], &texts[p], &out)?;
        ran += usize::from(stored);
        if !a.quiet {
            note!(
                "point {p} [{}/{}] {}: {} ({:.1} s){}",
                k + 1,
                todo.len(),
                pts.describe(p),
                answer::point_line(&out),
                t.elapsed().as_secs_f64(),
                if stored {
                    ""
                } else {
                    "; another sweep on this database stored it first"
                }
            );
        }
    }
    let stopped = STOP.load(Ordering::Relaxed);
    store.log(
        &shard_text,
        started,
        ran,
        t0.elapsed().as_secs_f64(),
        stopped,
    )?;
    if stopped {
        let now = store.done()?;
        note!(
            "ecsync sweep: stopped; {} of the {}'s {} are in {} ({ran} this time); the same command goes on with the rest",
            mine.iter().filter(|p| now.contains(p)).count(),
            if a.shard.is_some() { "shard" } else { "sweep" },
            points_text(mine.len()),
            a.db.display()
        );
        if a.report.is_some() {
            note!(
                "ecsync sweep: no report written (stopped); `ecsync sweep report --db {}` writes it from the points done",
                a.db.display()
            );
        }
        return Ok(crate::stop::exit_code());
    }
    out!("{}", answer::text(&store, &pts)?);
    if let Some(dir) = &a.report {
        report::write(&store, &meta, "--report", dir)?;
        if !a.quiet {
            note!(
                "ecsync sweep: report in {}",
                dir.join("sweep.html").display()
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `ecsync sweep report`: the database is checked first (a wrong path is named as --db), then
/// the folder, then the report is written.
fn write_report(r: &ReportArgs) -> Result<ExitCode> {
    if !r.db.is_file() {
        bail!(
            "--db: {}: no such file; fix: give the sweep's database (`ecsync sweep --db F`, or `ecsync sweep merge --db F` of its shards)",
            r.db.display()
        );
    }
    let (store, meta) = db::read(&r.db).map_err(|e| anyhow::anyhow!("--db: {e:#}"))?;
    report::check_dir("--out", &r.out)?;
    let files = report::write(&store, &meta, "--out", &r.out)?;
    let done = store.done()?.len();
    let total = meta.points.rows.len();
    out!("{}", answer::text(&store, &meta.points)?);
    note!(
        "ecsync sweep report: {done} of {}; wrote {} into {}",
        points_text(total),
        files.join(", "),
        r.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn merge(m: &MergeArgs) -> Result<ExitCode> {
    let meta = db::read_meta(&m.shards[0])?;
    for s in &m.shards[1..] {
        let other = db::read_meta(s)?;
        if other != meta {
            bail!(
                "{} is of another sweep than {}: it differs in {}; fix: merge the shards of one sweep (same scenario and points)",
                s.display(),
                m.shards[0].display(),
                other.differences(
                    &meta,
                    &format!("in {}", s.display()),
                    &format!("in {}", m.shards[0].display())
                )
            );
        }
    }
    let mut out = Store::open(&m.db, &meta)?;
    for s in &m.shards {
        let n = out.merge_from(s)?;
        note!("ecsync sweep merge: {}: {}", s.display(), points_text(n));
    }
    let done = out.done()?.len();
    let total = meta.points.rows.len();
    note!(
        "ecsync sweep merge: {done} of {} in {}",
        points_text(total),
        m.db.display()
    );
    out!("{}", answer::text(&out, &meta.points)?);
    if done < total {
        note!(
            "ecsync sweep merge: {} missing; fix: run the shards that hold them again (each goes on where it stopped)",
            points_text(total - done)
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
