//! `ecsync tsn models`: the TSN paper's UPPAAL models M1/M2/M3, explored exhaustively, with
//! the paper's Tables I and II beside ours; `ecsync tsn run`: its three networks built from
//! real parts (bridge with 802.1Qbv gates, gPTP) and measured against ground truth.

use anyhow::Result;
use ecsync_tsn::paper::{self, Table};
use ecsync_tsn::{Model, ModelReport};
use std::process::ExitCode;
use std::time::Instant;

/// `ecsync tsn ...`
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: TsnCommand,
}

#[derive(Debug, clap::Subcommand)]
enum TsnCommand {
    /// Explores every behaviour of the paper's UPPAAL models M1 (no TSN), M2 (TSN bridge, no
    /// gPTP) and M3 (bridge, master synchronized by gPTP) and prints Tables I and II of the
    /// paper beside ours.
    Models(ModelsArgs),
    /// Runs the realistic integrated network in three variants (M1: no bridge; M2: bridge, no
    /// gPTP; M3: bridge and gPTP, the master as DC reference) and reports blocked DC frames,
    /// delay measurement errors, precision and master-to-slave differences against the
    /// simulator's ground truth, with plots and report.html.
    Run(RunArgs),
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// Built-in preset (tsn-2020).
    #[arg(long, conflicts_with = "config")]
    preset: Option<String>,
    /// A TOML file describing the network, bridge and gPTP (see presets/tsn-2020.toml).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// Play the faults of this schedule on each variant's segment (TOML `[[fault]]` entries
    /// or a built-in one; the segment's kinds but a second responder).
    #[arg(long)]
    faults: Option<std::path::PathBuf>,
    /// Variants to run (default: the scenario's).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    variants: Option<Vec<String>>,
    /// Recorded seconds of cyclic operation (default: the scenario's).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Output directory for summary.json, summary.csv, table.txt, plots and report.html.
    #[arg(long, default_value = "out/tsn")]
    out: std::path::PathBuf,
    /// Capture each variant's frames at the master's port (EtherCAT and gPTP) into
    /// DIR/M1.pcap, DIR/M2.pcap, DIR/M3.pcap.
    #[arg(long)]
    pcap: Option<std::path::PathBuf>,
    /// Cyclic seconds to capture after the bring-up (the bring-up is captured whole).
    #[arg(long, default_value_t = 1.0)]
    pcap_seconds: f64,
    /// Print summary.json to standard output instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, clap::Args)]
struct ModelsArgs {
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(serde::Serialize)]
struct Out {
    models: Vec<ModelOut>,
    table_i: Table,
    table_ii: Table,
    /// Every cell of both tables equals the paper's.
    tables_match: bool,
    notes: Vec<String>,
    wall_s: f64,
}

#[derive(serde::Serialize)]
struct ModelOut {
    #[serde(flatten)]
    report: ModelReport,
    /// The bounds the XML file's queries state, and whether ours are exactly them.
    xml_delay_bounds: [i32; 2],
    xml_diff_bounds: [(i32, i32); 3],
    xml_bounds_tight: bool,
    wall_s: f64,
}

pub fn run(args: Args) -> Result<ExitCode> {
    match args.command {
        TsnCommand::Models(a) => models(a),
        TsnCommand::Run(a) => tsn_run(a),
    }
}

fn models(args: ModelsArgs) -> Result<ExitCode> {
    let t0 = Instant::now();
    if !args.json {
        eprintln!(
            "exploring M1, M2, M3 exhaustively (every oscillator rate, send instant and ordering)..."
        );
    }
    // The largest (M2) on one thread, the other two on another.
    let (m2, (m1, m3)) = std::thread::scope(|s| {
        let big = s.spawn(|| timed(Model::M2));
        let rest = (timed(Model::M1), timed(Model::M3));
        (big.join().expect("explorer thread"), rest)
    });
    let reports = [m1.0.clone(), m2.0.clone(), m3.0.clone()];
    let models: Vec<ModelOut> = [m1, m2, m3]
        .into_iter()
        .map(|(report, wall_s)| {
            let b = &paper::XML_BOUNDS[report.model as usize];
            let ours: Vec<(i32, i32)> = report
                .diff
                .iter()
                .map(|d| (d.1.max_a_minus_b, d.1.max_b_minus_a))
                .collect();
            let tight = report.delay_max == b.delay && ours == b.diff;
            ModelOut {
                xml_delay_bounds: b.delay,
                xml_diff_bounds: b.diff,
                xml_bounds_tight: tight,
                report,
                wall_s,
            }
        })
        .collect();
    let table_i = paper::table_i(&reports);
    let table_ii = paper::table_ii(&reports);
    let tables_match = [&table_i, &table_ii]
        .iter()
        .all(|t| t.cells.iter().flatten().all(|c| c.matches));
    let notes = notes(&reports, &models);
    let out = Out {
        models,
        table_i,
        table_ii,
        tables_match,
        notes,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print(&out);
    }
    Ok(ExitCode::SUCCESS)
}

fn tsn_run(args: RunArgs) -> Result<ExitCode> {
    use ecsync_lab::tsn::{TsnOptions, report, run_all, scenario};
    let t0 = Instant::now();
    let (name, text) = match (&args.preset, &args.config) {
        (_, Some(path)) => (
            path.display().to_string(),
            ecsync_sim::config::read_text(path).map_err(anyhow::Error::msg)?,
        ),
        (Some(p), None) if p == "tsn-2020" => (
            "preset tsn-2020".to_string(),
            scenario::TSN_2020_TOML.to_string(),
        ),
        (Some(p), None) => {
            anyhow::bail!("unknown preset \"{p}\"; the built-in TSN preset is: tsn-2020")
        }
        (None, None) => (
            "preset tsn-2020".to_string(),
            scenario::TSN_2020_TOML.to_string(),
        ),
    };
    let mut s = scenario::parse(&name, &text).map_err(anyhow::Error::msg)?;
    if let Some(v) = &args.variants {
        let mut out = Vec::new();
        for x in v {
            let Some(var) = [
                scenario::Variant::M1,
                scenario::Variant::M2,
                scenario::Variant::M3,
            ]
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(x)) else {
                anyhow::bail!("unknown variant \"{x}\"; the variants are M1, M2, M3");
            };
            if !out.contains(&var) {
                out.push(var);
            }
        }
        s.variants = out;
    }
    if let Some(d) = args.duration_s {
        if !(d.is_finite() && d > 0.0 && d <= 86_400.0) {
            anyhow::bail!("--duration-s must be between 0 and 86400 s");
        }
        s.cycles = ((d * 1e9 / f64::from(s.cycle_ns)).round() as u64).max(1);
    }
    if let Some(dir) = &args.pcap {
        std::fs::create_dir_all(dir)
            .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
    }
    let faults = match &args.faults {
        Some(p) => {
            let f = ecsync_sim::fault::FaultSchedule::load(p).map_err(anyhow::Error::msg)?;
            if let Some((n, x)) = f.faults.iter().enumerate().find(|(_, x)| {
                x.kind.is_host_fault()
                    || matches!(x.kind, ecsync_sim::fault::FaultKind::SecondResponder { .. })
            }) {
                anyhow::bail!(
                    "{}: fault[{n}].kind: \"{}\" is not played on the TSN network (its master's host and its one reply per frame); fix: remove it here (compare --faults plays it)",
                    p.display(),
                    x.kind.name()
                );
            }
            // The network's slaves and ports, as compare checks them: refused before any
            // variant runs.
            crate::compare::check_faults(
                &f,
                &s.slaves,
                &name,
                (s.warmup_cycles + s.cycles, s.cycle_ns),
                "run longer (--duration-s or duration_s; warmup_s)",
            )?;
            Some(f)
        }
        None => None,
    };
    // Before any work: a report folder that cannot be written fails now, not after the runs.
    ecsync_lab::output::ensure_writable_dir(&args.out).map_err(|e| {
        anyhow::anyhow!(
            "--out: cannot write into {}: {e}; fix: give a folder you can write to",
            args.out.display()
        )
    })?;
    let opts = TsnOptions {
        faults,
        pcap_dir: args.pcap.clone(),
        pcap_cycles: (args.pcap_seconds.max(0.0) * 1e9 / f64::from(s.cycle_ns)) as u64,
    };
    if !args.json {
        eprintln!(
            "running {} on {} slaves: {} s of cyclic operation after {} s warm-up...",
            s.variants
                .iter()
                .map(|v| v.name())
                .collect::<Vec<_>>()
                .join(", "),
            s.slaves.len(),
            s.cycles * u64::from(s.cycle_ns) / 1_000_000_000,
            s.warmup_cycles * u64::from(s.cycle_ns) / 1_000_000_000,
        );
    }
    let results = run_all(&s, &opts)?;
    let sum = report::summarize(&s, &results, t0.elapsed().as_secs_f64());
    report::write_all(&sum, &results, &args.out)
        .map_err(|e| anyhow::anyhow!("cannot write the report into {}: {e}", args.out.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&sum)?);
    } else {
        print!("{}", report::table_text(&sum));
        for n in &sum.findings.notes {
            println!("- {n}");
        }
        println!(
            "Report: {} ({:.1} s)",
            args.out.join("report.html").display(),
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn timed(m: Model) -> (ModelReport, f64) {
    let t = Instant::now();
    let r = ecsync_tsn::analyze(m);
    (r, t.elapsed().as_secs_f64())
}

/// What the figures mean, and every difference from the paper with its reason.
fn notes(r: &[ModelReport; 3], models: &[ModelOut]) -> Vec<String> {
    let mut n = Vec::new();
    for m in models {
        if m.xml_bounds_tight {
            n.push(format!(
                "{:?}: every bound its XML queries state is exactly the worst case over all {} states (delays {:?}, clock differences {:?}): the paper's constants are the true maxima.",
                m.report.model, m.report.states, m.report.delay_max, m.xml_diff_bounds
            ));
        } else {
            n.push(format!(
                "{:?}: the XML's query bounds (delays {:?}, differences {:?}) differ from the worst cases found (delays {:?}, differences {:?}).",
                m.report.model,
                m.xml_delay_bounds,
                m.xml_diff_bounds,
                m.report.delay_max,
                m.report
                    .diff
                    .iter()
                    .map(|d| (d.1.max_a_minus_b, d.1.max_b_minus_a))
                    .collect::<Vec<_>>()
            ));
        }
    }
    if let (Some(b2), Some(b3)) = (r[1].blocked, r[2].blocked) {
        n.push(format!(
            "Gate: in M2 the bridge's closed gate holds back SM {}, DM_T {}, DM_C {} in some behaviour; in M3 {}.",
            yes(b2.sm),
            yes(b2.dm_t),
            yes(b2.dm_c),
            if b3.any() {
                "it does too".to_string()
            } else {
                "never (the master, synchronized to the bridge by gPTP, sends inside the window)".to_string()
            }
        ));
    }
    n.push("Table II compares the width of the range of each clock difference (largest a - b plus largest b - a, the pair of one-sided queries in the XML); the largest |a - b| does not give the paper's figures.".to_string());
    n.push("Table I, last cell: M3 measures S2's delay exactly as M1 does (0 %), so the improvement is a division by zero, printed by the paper as 67/0.".to_string());
    if r.iter().all(|m| m.deadlock) {
        n.push("`A[] not deadlock` is false in all three: every run ends after the last slave's second SM, when the clocks stop (the models' own termination).".to_string());
    }
    n
}

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn print(o: &Out) {
    for m in &o.models {
        let r = &m.report;
        println!(
            "{:<18} {:>9} states in {:5.1} s; delays S1 {} (XML bound {}), S2 {} (XML bound {}); gate blocks: {}",
            r.model.title(),
            r.states,
            m.wall_s,
            r.delay_max[0],
            m.xml_delay_bounds[0],
            r.delay_max[1],
            m.xml_delay_bounds[1],
            match r.blocked {
                None => "no bridge".to_string(),
                Some(b) if b.any() => format!(
                    "yes (SM {}, DM_T {}, DM_C {})",
                    yes(b.sm),
                    yes(b.dm_t),
                    yes(b.dm_c)
                ),
                Some(_) => "never".to_string(),
            }
        );
        for (pair, d) in &r.diff {
            println!(
                "{:<18}   {:<17} a-b up to {:>4}, b-a up to {:>4}, range {:>4}",
                "",
                pair.title(),
                d.max_a_minus_b,
                d.max_b_minus_a,
                d.span()
            );
        }
    }
    for (name, t) in [
        ("Table I: delay measurement comparison", &o.table_i),
        ("Table II: clock difference comparison", &o.table_ii),
    ] {
        println!();
        println!("{name} (paper / ecsync)");
        print!("{:<34}", "");
        for c in &t.columns {
            print!("| {:^21} ", c);
        }
        println!();
        for (row, cells) in t.rows.iter().zip(&t.cells) {
            print!("{:<34}", row);
            for c in cells {
                print!(
                    "| {:>8} / {:<8} {} ",
                    c.paper,
                    c.ours_text,
                    if c.matches { " " } else { "*" }
                );
            }
            println!();
        }
    }
    println!();
    println!(
        "{} ({:.1} s)",
        if o.tables_match {
            "Every cell of Tables I and II equals the paper's."
        } else {
            "Cells marked * differ from the paper: see the notes."
        },
        o.wall_s
    );
    for n in &o.notes {
        println!("- {n}");
    }
}
