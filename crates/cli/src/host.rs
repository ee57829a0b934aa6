//! `ecsync host record` (this machine's periodic loop, cycle by cycle, as a CSV trace) and
//! `ecsync host fit` (the simulator's host model fitted to a trace, as a `[host]` table).

use anyhow::{Context, Result, bail};
use ecsync_sim::host::HostParams;
use ecsync_sim::host_fit::{fit, wake_quantiles};
use ecsync_sim::host_trace::{HostTrace, TraceRow};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `ecsync host`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Sub,
}

#[derive(Debug, clap::Subcommand)]
enum Sub {
    /// Records this host's periodic real-time loop (clock_nanosleep, SCHED_FIFO if allowed):
    /// per cycle the wake-up latency, the execution time and, with --iface, the delay to the
    /// kernel's TX timestamp. The CSV's columns: cycle (index from the first slot, skipped
    /// slots counted), scheduled_ns (the slot, CLOCK_MONOTONIC), wake_latency_ns (wake-up minus
    /// slot), exec_ns (wake-up to the send timestamp), tx_delay_ns (send timestamp to the
    /// kernel's TX software timestamp; empty without --iface or when none came).
    #[cfg(target_os = "linux")]
    Record(RecordArgs),
    /// Fits the simulator's host model (j_s with bursts, e_m, j_c and the TX latency) to a
    /// trace and prints a `[host]` table for a compare scenario.
    Fit(FitArgs),
}

/// Arguments of `ecsync host record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Cycle time, us.
    #[arg(long, default_value_t = 1000)]
    cycle_us: u64,
    /// How long to record, s.
    #[arg(long, default_value_t = 60.0)]
    duration: f64,
    /// Send a frame each cycle on this interface (a broadcast read of the ESC type register)
    /// and record the delay to its kernel TX timestamp.
    #[arg(long)]
    iface: Option<String>,
    /// The trace file.
    #[arg(long, default_value = "host-trace.csv")]
    out: PathBuf,
    /// SCHED_FIFO priority (0: leave the scheduling policy alone).
    #[arg(long, default_value_t = 80)]
    priority: i32,
}

/// Arguments of `ecsync host fit`.
#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// The trace (`ecsync host record`, or `ecsync run --csv`).
    file: PathBuf,
    /// Fit on the trace's first half only.
    #[arg(long)]
    first_half: bool,
    /// Fit on the first half and compare the model's wake-up p99 and p99.9 with the second
    /// half's measured ones.
    #[arg(long)]
    check: bool,
    /// Host preset giving what a trace does not measure (crystal, receive latency; j_c and the
    /// TX latency without TX delays).
    #[arg(long, default_value = "preempt-rt-stress")]
    base: String,
    /// Also write the `[host]` table to this file.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Runs `ecsync host`.
pub fn run(args: Args) -> Result<ExitCode> {
    match args.command {
        #[cfg(target_os = "linux")]
        Sub::Record(a) => record(a),
        Sub::Fit(a) => fit_cmd(a),
    }
}

#[cfg(target_os = "linux")]
fn record(a: RecordArgs) -> Result<ExitCode> {
    use ecsync_net::host_record::{RecordConfig, record};
    use ecsync_net::rt::{Pin, setup};
    use ecsync_net::sys::PacketSocket;
    use std::sync::atomic::AtomicBool;
    static STOP: AtomicBool = AtomicBool::new(false);
    if !(10..=1_000_000).contains(&a.cycle_us) {
        bail!(
            "--cycle-us: {} us; fix: give between 10 and 1000000",
            a.cycle_us
        );
    }
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= 86_400.0) {
        bail!(
            "--duration: {} s; fix: give between 0 and 86400 s",
            a.duration
        );
    }
    let sock = match &a.iface {
        Some(i) => {
            let s = PacketSocket::open(i).map_err(|e| anyhow::anyhow!("--iface {i}: {e}"))?;
            if !s.timestamps().tx_software {
                eprintln!(
                    "ecsync host record: warning: {i} gives no software TX timestamps: tx_delay_ns stays empty"
                );
            }
            Some(s)
        }
        None => None,
    };
    crate::stop::raise_on_signals(&STOP);
    let f = std::fs::File::create(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut w = std::io::BufWriter::new(f);
    // Rows in memory, written after the loop: no file I/O between the cycles measured.
    let mut rows = Vec::with_capacity((a.duration * 1e6 / a.cycle_us as f64) as usize + 16);
    let rt = setup(a.priority, Pin::Last);
    for warn in &rt.warnings {
        eprintln!("ecsync host record: warning: {warn}");
    }
    let fifo = match rt.fifo_priority {
        Some(p) => format!("SCHED_FIFO {p}"),
        None => "SCHED_OTHER (SCHED_FIFO not granted)".to_string(),
    };
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap_or_default();
    let sum = record(
        RecordConfig {
            cycle_ns: a.cycle_us * 1000,
            duration_ns: (a.duration * 1e9) as u64,
            stop: Some(&STOP),
        },
        sock.as_ref(),
        |c| rows.push(*c),
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    writeln!(
        w,
        "# ecsync host record: cycle {} us, {}, kernel {}{}, memory locked {}, cpu {}, iface {}",
        a.cycle_us,
        fifo,
        kernel.trim(),
        if rt.preempt_rt { " (PREEMPT_RT)" } else { "" },
        rt.memory_locked,
        rt.cpu
            .map_or_else(|| "not pinned".to_string(), |c| c.to_string()),
        a.iface.as_deref().unwrap_or("none (tx_delay_ns absent)")
    )?;
    writeln!(w, "{}", ecsync_sim::host_trace::TRACE_HEADER)?;
    for c in &rows {
        write!(
            w,
            "{},{},{},{},",
            c.cycle, c.scheduled_ns, c.wake_latency_ns, c.exec_ns
        )?;
        match c.tx_delay_ns {
            Some(t) => writeln!(w, "{t}")?,
            None => writeln!(w)?,
        }
    }
    w.flush()
        .with_context(|| format!("writing {}", a.out.display()))?;
    let lat: Vec<f64> = rows.iter().map(|c| c.wake_latency_ns as f64).collect();
    let mut s = lat.clone();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| ecsync_sim::host_fit::quantile(&s, p) / 1000.0;
    println!(
        "{} cycles of {} us recorded to {} ({fifo}; {} slots skipped{}): wake-up latency p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
        sum.cycles,
        a.cycle_us,
        a.out.display(),
        sum.skipped,
        if a.iface.is_some() {
            format!(", {} TX timestamps missing", sum.tx_stamps_missing)
        } else {
            String::new()
        },
        q(0.5),
        q(0.99),
        q(0.999),
        q(1.0)
    );
    Ok(ExitCode::SUCCESS)
}

/// The fitted model's wake-up quantiles `predicted` (at `qs`: p99, p99.9) against the cycles
/// it was fitted on, and a warning when it misses them by more than a factor of two: a trace
/// whose rare long wake-ups are too few to fit (a short recording) gives a model without them.
fn fitted_against_own(
    f: &ecsync_sim::host_fit::HostFit,
    rows: &[TraceRow],
    predicted: &[f64],
    qs: &[f64],
) {
    let own = wake_quantiles(rows, qs);
    println!(
        "# the model against the cycles it was fitted on: wake-up p99 {:.1} us (the trace {:.1} us), p99.9 {:.1} us (the trace {:.1} us)",
        predicted[0] / 1000.0,
        own[0] / 1000.0,
        predicted[1] / 1000.0,
        own[1] / 1000.0
    );
    let missed = (0..qs.len()).rev().find(|&i| {
        let r = predicted[i] / own[i];
        !(0.5..=2.0).contains(&r)
    });
    if let Some(i) = missed {
        let name = if i == 0 { "p99" } else { "p99.9" };
        let why = if f.params.js.tail_p == 0.0 {
            "no pulses fitted: too few cycles stand out of the core's jitter to tell them from it"
        } else {
            "the fitted pulses do not reproduce them"
        };
        eprintln!(
            "ecsync host fit: warning: the model's wake-up {name} is {:.1} us where the {} cycles it was fitted on have {:.1} us ({why}); record longer (`ecsync host record --duration 600`) before a comparison relies on this table",
            predicted[i] / 1000.0,
            rows.len(),
            own[i] / 1000.0
        );
    }
}

fn fit_cmd(a: FitArgs) -> Result<ExitCode> {
    let base = HostParams::preset(&a.base).with_context(|| {
        format!(
            "--base: unknown host preset \"{}\"; fix: use one of: {}",
            a.base,
            HostParams::PRESETS.join(", ")
        )
    })?;
    let file = a.file.display().to_string();
    let text = std::fs::read_to_string(&a.file).with_context(|| format!("cannot read {file}"))?;
    let trace = HostTrace::parse(&file, &text).map_err(anyhow::Error::msg)?;
    let (first, second) = trace.halves();
    let rows = if a.first_half || a.check {
        first
    } else {
        &trace.rows[..]
    };
    let f = fit(rows, base);
    let source = if a.first_half || a.check {
        format!("the first half of {file}")
    } else {
        file.clone()
    };
    let table = f.to_toml(&a.base, &source);
    // The table must be one a scenario takes: checked here as compare would, in the place of
    // the letter's scenario's own.
    if let Err(e) = ecsync_lab::scenario::check_in_scenario(&table) {
        bail!("the fitted table is not one a scenario takes: {e}");
    }
    print!("{table}");
    if let Some(out) = &a.out {
        ecsync_lab::output::write_atomic(out, table.as_bytes())
            .with_context(|| format!("cannot write {}", out.display()))?;
    }
    let qs = [0.99, 0.999];
    let predicted = f.predicted_wake_quantiles(&qs, 2_000_000, 1);
    fitted_against_own(&f, rows, &predicted, &qs);
    if a.check {
        let measured = wake_quantiles(second, &qs);
        let fitted_on = wake_quantiles(first, &qs);
        println!(
            "# check: model fitted on the first half against the second half's wake-up latency"
        );
        for (i, name) in ["p99", "p99.9"].iter().enumerate() {
            // The first half's own figure beside it: no model of the first half can predict
            // the second better than the host itself stayed the same.
            println!(
                "# wake-up {name}: predicted {:.1} us, measured {:.1} us, error {:+.1} % (the first half measured {:.1} us: the host moved {:+.1} % between the halves)",
                predicted[i] / 1000.0,
                measured[i] / 1000.0,
                (predicted[i] / measured[i] - 1.0) * 100.0,
                fitted_on[i] / 1000.0,
                (measured[i] / fitted_on[i] - 1.0) * 100.0
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
