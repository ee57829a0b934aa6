//! `ecsync bench`: how fast the simulator runs.

use anyhow::{Result, ensure};
use ecsync_master::bench::CycleBench;
use serde::Serialize;
use std::process::ExitCode;
use std::time::Instant;

/// Arguments of `ecsync bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated cycles to time, per repeat.
    #[arg(long, default_value_t = 2_000_000)]
    cycles: u64,
    /// Timed repeats of `--cycles` cycles each: the figure is their median, printed with the
    /// slowest and the fastest (on a shared machine the neighbours slow single runs down).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    repeats: u32,
    /// Print JSON.
    #[arg(long)]
    json: bool,
    /// Time only one datagram of the frame (frmw, lrw, brd) or an empty NOP frame (nop), to see
    /// where the time goes.
    #[arg(long, value_parser = ["frmw", "lrw", "brd", "nop"])]
    part: Option<String>,
    /// Skip timing the default comparison (`ecsync compare` on paper-2024).
    #[arg(long)]
    skip_compare: bool,
}

#[derive(Debug, Serialize)]
struct Out {
    workload: &'static str,
    slaves: usize,
    /// Cycles per repeat.
    cycles: u64,
    repeats: u32,
    /// Wall time of the median repeat, s.
    wall_s: f64,
    /// Of the median repeat.
    cycles_per_s: f64,
    /// Of the median repeat.
    slave_cycles_per_s: f64,
    /// Of the slowest and the fastest repeat.
    slave_cycles_per_s_min: f64,
    slave_cycles_per_s_max: f64,
    /// Of the median repeat.
    ns_per_slave_cycle: f64,
    /// Wall time of the default `ecsync compare` (paper-2024, 5 runs x 1.8 M cycles after
    /// 2 min of warm-up, every method), s.
    default_compare_wall_s: Option<f64>,
    /// Simulated cycles per second of the default comparison, all threads.
    default_compare_cycles_per_s: Option<f64>,
    /// Threads the comparison used.
    threads: usize,
}

pub fn run(args: Args) -> Result<ExitCode> {
    if args.cycles == 0 {
        anyhow::bail!(
            "--cycles: 0 cycles cannot be timed; fix: give at least 1 (default 2000000; 500000 times in about a second)"
        );
    }
    let mut b = CycleBench::paper_2024();
    if let Some(p) = &args.part {
        let which = ["frmw", "lrw", "brd", "nop"]
            .iter()
            .position(|x| x == p)
            .unwrap_or(3);
        b.frame = b.single_datagram_frame(which);
    }
    let mut work = vec![0u8; 1514];
    // Warm up caches and the branch predictor.
    b.run(10_000, &mut work);
    let mut walls = Vec::with_capacity(args.repeats as usize);
    let mut wkc = 0;
    for _ in 0..args.repeats {
        let t0 = Instant::now();
        wkc = b.run(args.cycles, &mut work);
        walls.push(t0.elapsed().as_secs_f64());
    }
    walls.sort_by(f64::total_cmp);
    let wall = walls[walls.len() / 2];
    let (fastest, slowest) = (walls[0], walls[walls.len() - 1]);
    ensure!(
        args.part.is_some() || wkc == b.expected_lrw_wkc,
        "the segment answered the LRW with working counter {wkc}, expected {}",
        b.expected_lrw_wkc
    );
    let slaves = b.slaves();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let (cmp_wall, cmp_rate) = if args.skip_compare || args.part.is_some() {
        (None, None)
    } else {
        let s = ecsync_lab::parse("preset paper-2024", ecsync_esc::preset::PAPER_2024_TOML)
            .map_err(anyhow::Error::msg)?;
        let cycles = (s.cycles + s.warmup_cycles) * u64::from(s.runs) * s.methods.len() as u64;
        let progress = std::sync::atomic::AtomicU64::new(0);
        let t = Instant::now();
        ecsync_lab::compare(&s, threads, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
        let w = t.elapsed().as_secs_f64();
        (Some(w), Some(cycles as f64 / w))
    };
    let out = Out {
        workload: "paper-2024: 6 slaves, 1 ms cycle, FRMW 0x0910 + LRW 204 B + BRD 0x092C per frame",
        slaves,
        cycles: args.cycles,
        repeats: args.repeats,
        wall_s: wall,
        cycles_per_s: args.cycles as f64 / wall,
        slave_cycles_per_s: (args.cycles * slaves as u64) as f64 / wall,
        slave_cycles_per_s_min: (args.cycles * slaves as u64) as f64 / slowest,
        slave_cycles_per_s_max: (args.cycles * slaves as u64) as f64 / fastest,
        ns_per_slave_cycle: wall * 1e9 / (args.cycles * slaves as u64) as f64,
        default_compare_wall_s: cmp_wall,
        default_compare_cycles_per_s: cmp_rate,
        threads,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!("{}", out.workload);
        println!(
            "{} x {} cycles on one core, median {:.3} s: {:.2} M cycles/s, {:.2} M slave-cycles/s ({:.1} ns per slave-cycle); slowest and fastest repeat {:.2} and {:.2} M slave-cycles/s",
            out.repeats,
            out.cycles,
            out.wall_s,
            out.cycles_per_s / 1e6,
            out.slave_cycles_per_s / 1e6,
            out.ns_per_slave_cycle,
            out.slave_cycles_per_s_min / 1e6,
            out.slave_cycles_per_s_max / 1e6
        );
        if let (Some(w), Some(r)) = (out.default_compare_wall_s, out.default_compare_cycles_per_s) {
            println!(
                "default comparison (paper-2024, {} methods x 5 runs x 1.92 M cycles): {w:.1} s wall on {}, {:.2} M cycles/s",
                ecsync_dc::MethodKind::ALL.len(),
                ecsync_lab::scenario::plural(out.threads as u64, "thread", "threads"),
                r / 1e6
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
