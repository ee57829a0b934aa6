//! `ecsync bench`: how fast the simulator runs.

use anyhow::{Result, ensure};
use ecsync_master::bench::CycleBench;
use serde::Serialize;
use std::process::ExitCode;
use std::time::Instant;

/// Arguments of `ecsync bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated cycles to time.
    #[arg(long, default_value_t = 2_000_000)]
    cycles: u64,
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
    cycles: u64,
    wall_s: f64,
    cycles_per_s: f64,
    slave_cycles_per_s: f64,
    ns_per_slave_cycle: f64,
    /// Wall time of the default `ecsync compare` (paper-2024, 5 runs x 1.8 M cycles after
    /// 2 min of warm-up, five methods), s.
    default_compare_wall_s: Option<f64>,
    /// Simulated cycles per second of the default comparison, all threads.
    default_compare_cycles_per_s: Option<f64>,
    /// Threads the comparison used.
    threads: usize,
}

pub fn run(args: Args) -> Result<ExitCode> {
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
    let t0 = Instant::now();
    let wkc = b.run(args.cycles, &mut work);
    let wall = t0.elapsed().as_secs_f64();
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
        wall_s: wall,
        cycles_per_s: args.cycles as f64 / wall,
        slave_cycles_per_s: (args.cycles * slaves as u64) as f64 / wall,
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
            "{} cycles in {:.3} s on one core: {:.2} M cycles/s, {:.2} M slave-cycles/s ({:.1} ns per slave-cycle)",
            out.cycles,
            out.wall_s,
            out.cycles_per_s / 1e6,
            out.slave_cycles_per_s / 1e6,
            out.ns_per_slave_cycle
        );
        if let (Some(w), Some(r)) = (out.default_compare_wall_s, out.default_compare_cycles_per_s) {
            println!(
                "default comparison (paper-2024, 5 methods x 5 runs x 1.92 M cycles): {w:.1} s wall on {} threads, {:.2} M cycles/s",
                out.threads,
                r / 1e6
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
