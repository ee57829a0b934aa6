//! `ecsync bench`: how fast the simulator runs.

use anyhow::{Result, ensure};
use ecsync_sim::bench::CycleBench;
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
    /// Time lines of this many drives instead of paper-2024, e.g. `--slaves 6,64,512,1000`:
    /// the cost per slave-cycle of each and its ratio to the first, in one run. Each line
    /// runs `--cycles` x 6 / N cycles (the same slave-cycles as six drives), with the cyclic
    /// engine's frames: as many as the process image needs.
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u32).range(1..=65_535))]
    slaves: Vec<u32>,
}

/// One line of `--slaves`.
#[derive(Debug, Serialize)]
struct LineOut {
    slaves: usize,
    /// Frames per cycle.
    frames: usize,
    /// Cycle time, us (the whole milliseconds the frames need).
    cycle_us: u64,
    cycles: u64,
    /// Of the median repeat.
    ns_per_slave_cycle: f64,
    /// Of the slowest and the fastest repeat.
    ns_per_slave_cycle_max: f64,
    ns_per_slave_cycle_min: f64,
    /// `ns_per_slave_cycle` over the first line's.
    ratio_to_first: f64,
    /// Memory the brought-up segment holds, per slave, KiB: [`memory_kib`] before and after.
    memory_kib_per_slave: Option<f64>,
}

/// Memory this process holds, KiB: with glibc, the bytes its heap has handed out (`mallinfo2`:
/// the resident size grows in 2 MiB steps on the huge pages the simulator's heap asks for,
/// see `heap`); elsewhere the resident set (Linux /proc); `None` without either.
fn memory_kib() -> Option<u64> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallinfo2 only reads the allocator's statistics.
        let m = unsafe { libc::mallinfo2() };
        Some(((m.uordblks + m.hblkhd) / 1024) as u64)
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        let s = std::fs::read_to_string("/proc/self/status").ok()?;
        let l = s.lines().find(|l| l.starts_with("VmRSS:"))?;
        l.split_whitespace().nth(1)?.parse().ok()
    }
}

/// `--slaves`: each line timed the same way, the ratios in one run. The lines are brought up
/// first and their repeats interleaved (every line once, then every line again): the phases
/// in which a shared machine's neighbours slow it down fall on every line alike, not on
/// whichever line was running then.
fn run_lines(args: &Args) -> Result<ExitCode> {
    struct Line {
        b: CycleBench,
        work: Vec<u8>,
        cycles: u64,
        walls: Vec<f64>,
        memory_kib_per_slave: Option<f64>,
    }
    let mut lines: Vec<Line> = Vec::new();
    for &n in &args.slaves {
        let n = n as usize;
        let before = memory_kib();
        let b = CycleBench::line(n);
        let after = memory_kib();
        let longest = b.frames.iter().map(Vec::len).max().unwrap_or(0);
        lines.push(Line {
            b,
            work: vec![0u8; longest],
            cycles: (args.cycles * 6 / n as u64).max(1),
            walls: Vec::with_capacity(args.repeats as usize),
            memory_kib_per_slave: before
                .zip(after)
                .map(|(a, b)| b.saturating_sub(a) as f64 / n as f64),
        });
    }
    for l in &mut lines {
        l.b.run((l.cycles / 10).max(1), &mut l.work);
    }
    for _ in 0..args.repeats {
        for l in &mut lines {
            let t0 = Instant::now();
            let wkc = l.b.run(l.cycles, &mut l.work);
            l.walls.push(t0.elapsed().as_secs_f64());
            ensure!(
                wkc == l.b.expected_lrw_wkc,
                "{} drives: the segment answered the LRWs with working counter {wkc}, expected {}",
                l.b.slaves(),
                l.b.expected_lrw_wkc
            );
        }
    }
    let mut out: Vec<LineOut> = Vec::new();
    for l in &mut lines {
        let n = l.b.slaves();
        l.walls.sort_by(f64::total_cmp);
        let per = |w: f64| w * 1e9 / (l.cycles * n as u64) as f64;
        let ns = per(l.walls[l.walls.len() / 2]);
        let first = out.first().map_or(ns, |f| f.ns_per_slave_cycle);
        out.push(LineOut {
            slaves: n,
            frames: l.b.frames.len(),
            cycle_us: l.b.cycle_ps / 1_000_000,
            cycles: l.cycles,
            ns_per_slave_cycle: ns,
            ns_per_slave_cycle_max: per(l.walls[l.walls.len() - 1]),
            ns_per_slave_cycle_min: per(l.walls[0]),
            ratio_to_first: ns / first,
            memory_kib_per_slave: l.memory_kib_per_slave,
        });
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "lines of servo drives, the cyclic engine's frames back to back; {} repeats of every line, interleaved, the median:",
            args.repeats
        );
        println!("  drives  frames  cycle  ns/slave-cycle  ratio  memory/slave");
        for l in &out {
            let mem = l
                .memory_kib_per_slave
                .map_or("-".to_string(), |m| format!("{m:.1} KiB"));
            println!(
                "  {:>6}  {:>6}  {:>2} ms  {:>14.1}  {:>5.2}  {mem}",
                l.slaves,
                l.frames,
                l.cycle_us / 1000,
                l.ns_per_slave_cycle,
                l.ratio_to_first
            );
        }
    }
    Ok(ExitCode::SUCCESS)
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
    if !args.slaves.is_empty() {
        ensure!(
            args.part.is_none(),
            "--part times one datagram of paper-2024's frame; fix: drop --part or --slaves"
        );
        return run_lines(&args);
    }
    let mut b = CycleBench::paper_2024();
    if let Some(p) = &args.part {
        let which = ["frmw", "lrw", "brd", "nop"]
            .iter()
            .position(|x| x == p)
            .unwrap_or(3);
        b.keep_single_datagram(which);
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
        let s = ecsync_lab::parse("preset paper-2024", ecsync_sim::preset::PAPER_2024_TOML)
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
                ecsync_dc::MethodKind::DEFAULT.len(),
                ecsync_lab::scenario::plural(out.threads as u64, "thread", "threads"),
                r / 1e6
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
