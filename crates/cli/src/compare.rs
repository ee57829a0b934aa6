//! `ecsync compare`: every master synchronization method on the same network, host and noise.

use crate::source::SourceArgs;
use anyhow::{Context, Result, bail};
use ecsync_lab::report::{self, csv, summarize, table1_text, write_atomic};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Arguments of `ecsync compare`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    /// Methods to compare (default: the scenario's; all five in the preset).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    methods: Option<Vec<String>>,
    /// Runs with different seeds.
    #[arg(long)]
    runs: Option<u32>,
    /// Recorded cycles per run.
    #[arg(long)]
    cycles: Option<u64>,
    /// Warm-up per run, s.
    #[arg(long)]
    warmup_s: Option<f64>,
    /// Host preset (preempt-rt-stress, preempt-rt-idle, vanilla-linux, ideal).
    #[arg(long)]
    host: Option<String>,
    /// SYNC0 shift, % of the cycle.
    #[arg(long)]
    shift_pct: Option<f64>,
    /// Base seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Output directory for summary.json, summary.csv, plots and report.html.
    #[arg(long, default_value = "out/compare")]
    out: PathBuf,
    /// Print summary.json to standard output instead of the table.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(args: Args) -> Result<ExitCode> {
    let (name, text) = args.source.load()?;
    let mut s = ecsync_lab::parse(&name, &text).map_err(anyhow::Error::msg)?;
    if let Some(m) = &args.methods {
        for x in m {
            if !ecsync_lab::scenario::METHODS.contains(&x.as_str()) {
                bail!(
                    "unknown method \"{x}\"; the methods are: {}",
                    ecsync_lab::scenario::METHODS.join(", ")
                );
            }
        }
        s.methods = ecsync_lab::scenario::METHODS
            .iter()
            .filter(|x| m.iter().any(|y| y == *x))
            .map(|x| x.to_string())
            .collect();
    }
    if let Some(r) = args.runs {
        if r == 0 {
            bail!("--runs must be at least 1");
        }
        s.runs = r;
    }
    if let Some(c) = args.cycles {
        if c == 0 {
            bail!("--cycles must be at least 1");
        }
        s.cycles = c;
    }
    if let Some(w) = args.warmup_s {
        if !(w.is_finite() && w >= 0.0) {
            bail!("--warmup-s must be a number of seconds >= 0");
        }
        s.warmup_cycles = (w * 1e9 / f64::from(s.cycle_ns)).round() as u64;
    }
    if let Some(h) = &args.host {
        s.host = ecsync_lab::host::HostParams::preset(h).with_context(|| {
            format!(
                "unknown host preset \"{h}\"; use one of: {}",
                ecsync_lab::host::HostParams::PRESETS.join(", ")
            )
        })?;
        s.host_name = h.clone();
    }
    if let Some(p) = args.shift_pct {
        if !(0.0..100.0).contains(&p) {
            bail!("--shift-pct must lie in 0 ..< 100");
        }
        s.sync0_shift_pct = p;
    }
    if let Some(seed) = args.seed {
        s.seed = seed;
    }
    // Initialisation frames cannot exceed the warm-up.
    let w = s.warmup_cycles.max(1);
    s.median.init_frames = s.median.init_frames.min(w as i64);
    s.pi_m2s.init_frames = s.pi_m2s.init_frames.min(w as i64);

    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let total = (s.warmup_cycles + s.cycles) * u64::from(s.runs) * s.methods.len() as u64;
    let progress = AtomicU64::new(0);
    let bar = if args.quiet || args.json {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} {msg} [{bar:40}] {percent:>3}% {human_pos}/{human_len} cycles, {per_sec}, eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        b.set_message(format!("{} x {} runs", s.methods.join(", "), s.runs));
        b
    };
    let result = std::thread::scope(|sc| {
        let handle = sc.spawn(|| ecsync_lab::compare(&s, threads, &progress));
        while !handle.is_finished() {
            bar.set_position(progress.load(Ordering::Relaxed));
            std::thread::sleep(Duration::from_millis(100));
        }
        handle.join()
    });
    bar.finish_and_clear();
    let cmp = result
        .map_err(|_| anyhow::anyhow!("a simulation thread panicked"))?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let out = summarize(&cmp);
    let order = s.methods.clone();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let json = serde_json::to_string_pretty(&out)?;
    write_atomic(&args.out.join("summary.json"), json.as_bytes())?;
    write_atomic(&args.out.join("summary.csv"), csv(&out, &order).as_bytes())?;
    let table = table1_text(&out, &order);
    write_atomic(&args.out.join("table1.txt"), table.as_bytes())?;
    report::write_report(&cmp, &out, &order, &args.out).context("writing plots and report.html")?;
    if args.json {
        println!("{json}");
    } else {
        println!(
            "{}: {} slaves, host {}, {} runs x {} cycles after {} warm-up cycles, SYNC0 shift {} %",
            out.scenario,
            out.slaves,
            out.host,
            out.runs,
            out.cycles,
            out.warmup_cycles,
            out.sync0_shift_pct
        );
        println!();
        print!("{table}");
        println!();
        println!(
            "Wrote {}/{{summary.json, summary.csv, table1.txt, report.html, *.svg, *.png}} in {:.1} s on {} threads.",
            args.out.display(),
            out.wall_s,
            out.threads
        );
    }
    Ok(ExitCode::SUCCESS)
}
