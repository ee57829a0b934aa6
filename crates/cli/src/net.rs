//! `ecsync serve` (the virtual segment on a network interface) and `ecsync run` (the master, its
//! DC bring-up and a synchronization method on a network interface).

use crate::source::SourceArgs;
use anyhow::{Context, Result, bail};
use ecsync_dc::MasterSync as _;
use ecsync_dc::method::{Method, MethodContext, MethodKind, MethodParams, ParamError};
use ecsync_dc::time::MasterDuration;
use ecsync_lab::output::write_atomic;
use ecsync_lab::realnet::summary::{BringupOut, CSV_HEADER, RATE_FIT_MIN_CYCLES, RunOut};
use ecsync_lab::realnet::{self, CyclicOptions, RunHead};
use ecsync_master::bringup::{DcCapability, Stage};
use ecsync_master::driver::{ExchangeStats, ProcedureConfig, Stopped, run_procedure};
use ecsync_master::transport::SendMode;
use ecsync_master::{BringupConfig, Engine, Event, MasterError, Network, bringup};
use ecsync_net::rt;
use ecsync_net::sys::PacketSocket;
use ecsync_net::tx_stamp::{TxStampMode, TxStampSource};
use ecsync_net::{NetError, RealLink, SendControl};
use ecsync_sim::Segment;
use ecsync_sim::config::{ConfigSource, Problem};
use ecsync_sim::pcap::PcapCapture;
use serde::Deserialize;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Raised by Ctrl-C (SIGINT) and SIGTERM.
static STOP: AtomicBool = AtomicBool::new(false);

fn install_stop_handler() {
    // A second installation (tests calling twice in one process) is harmless to ignore.
    let _ = ctrlc::set_handler(|| STOP.store(true, Ordering::Relaxed));
}

/// Arguments of `ecsync serve`.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Network interface to serve the segment on.
    #[arg(long)]
    iface: String,
    #[command(flatten)]
    source: SourceArgs,
    /// Capture every frame in and out to this pcap file.
    #[arg(long)]
    pcap: Option<PathBuf>,
    /// SCHED_FIFO priority of the serving thread (0: normal scheduling).
    #[arg(long, default_value_t = 70)]
    priority: i32,
    /// No status line.
    #[arg(long)]
    quiet: bool,
    /// Play the faults of this schedule on the served segment (TOML `[[fault]]` entries, the
    /// format `compare --faults` reads; the segment's kinds: loss, corrupt, delay, power_cycle,
    /// link_down, second_responder). Times count from the first frame with process data
    /// unless it says `epoch = "start"`.
    #[arg(long)]
    faults: Option<PathBuf>,
}

/// Opens the segment's socket (EtherCAT frames, untagged or in a VLAN tag, which the answer
/// keeps), turning the OS's refusals into one clear line.
fn open_socket(iface: &str) -> Result<PacketSocket> {
    PacketSocket::open_vlan_aware(iface).map_err(|e| anyhow::anyhow!("{e}"))
}

pub fn serve(args: ServeArgs) -> Result<ExitCode> {
    let (name, specs) = args.source.segment()?;
    let mut seg = Segment::new(&specs).context("building the segment")?;
    let mut faults = match &args.faults {
        Some(p) => {
            let sched = ecsync_sim::fault::FaultSchedule::load(p).map_err(anyhow::Error::msg)?;
            if let Some((n, f)) = sched
                .faults
                .iter()
                .enumerate()
                .find(|(_, f)| f.kind.is_host_fault())
            {
                anyhow::bail!(
                    "{}: fault[{n}].kind: \"{}\" is a fault of the master's host, which serve cannot play; fix: remove it here (compare --faults plays it in virtual time)",
                    p.display(),
                    f.kind.name()
                );
            }
            Some(ecsync_sim::fault::FaultPlayer::new(sched, 0))
        }
        None => None,
    };
    let sock = open_socket(&args.iface)?;
    install_stop_handler();
    let rt = rt::setup(args.priority, rt::Pin::No);
    for w in &rt.warnings {
        eprintln!("ecsync serve: warning: {w}");
    }
    let mut capture = match &args.pcap {
        Some(p) => Some(
            PcapCapture::create(p)
                .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", p.display()))?,
        ),
        None => None,
    };
    let reference = (0..seg.len()).find(|&i| seg.esc(i).model().dc.has_system_time());
    eprintln!(
        "ecsync serve: {name}, {} slaves, on {} (kernel timestamps: rx {}, promiscuous {}); Ctrl-C stops.",
        seg.len(),
        args.iface,
        if sock.timestamps().rx_software {
            "yes"
        } else {
            "no"
        },
        if sock.promiscuous() { "yes" } else { "no" },
    );
    if let Some(r) = reference {
        let truth = seg.true_delays_ns(r);
        let list: Vec<String> = truth
            .iter()
            .enumerate()
            .map(|(i, d)| match d {
                Some(d) => format!("{i}: {d:.1}"),
                None => format!("{i}: -"),
            })
            .collect();
        eprintln!(
            "true propagation delays from the reference (position {r}), ns: {}",
            list.join(", ")
        );
    }
    let t0 = Instant::now();
    let mut last_print = Instant::now();
    let quiet = args.quiet;
    let stats = ecsync_net::serve::serve(
        &sock,
        &mut seg,
        capture.as_mut(),
        faults.as_mut(),
        &STOP,
        |s| {
            if !quiet && last_print.elapsed().as_secs_f64() >= 1.0 {
                last_print = Instant::now();
                eprint!(
                    "\r{:>8.1} s: {} frames answered, {} not returned",
                    t0.elapsed().as_secs_f64(),
                    s.answered,
                    s.not_returned
                );
            }
        },
    )
    .map_err(|e| anyhow::anyhow!("serving on {}: {e}", args.iface))?;
    if !quiet {
        eprintln!();
    }
    if let Some(c) = capture {
        let n = c.frames();
        c.finish().context("writing the pcap file")?;
        eprintln!("captured {n} frames");
    }
    eprintln!(
        "ecsync serve: stopped after {:.1} s: {} frames received, {} answered ({} in their VLAN tag), {} not returned; {} arrived with bit 0x02 of the source address set (processed as any frame).",
        t0.elapsed().as_secs_f64(),
        stats.received,
        stats.answered,
        stats.answered_tagged,
        stats.not_returned,
        stats.marked_on_arrival
    );
    if let Some(f) = &faults {
        eprintln!(
            "faults: {} frames dropped, {} replies deferred, the interface down {} times; events:",
            stats.dropped_by_faults, stats.deferred_sends, stats.link_down_errors
        );
        for e in f.events() {
            eprintln!(
                "  {:>10.3} s  {} {}: {}",
                e.since_epoch_ns as f64 / 1e9,
                e.kind,
                e.edge,
                e.detail
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// What `ecsync run --help` says after the options: the methods, from the registry.
/// `run --send`: the modes a real send has (a hardware transmit stamp is `--tx-stamp`), as
/// [`SendMode`]s.
fn real_send_mode() -> impl clap::builder::TypedValueParser<Value = SendMode> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(["plain", "spin", "txtime"])
        .try_map(|s| s.parse::<SendMode>())
}

fn run_after_help() -> String {
    let mut t = String::from("Methods (--method):\n");
    for m in MethodKind::ALL {
        t.push_str(&format!("  {:<18} {}\n", m.name(), m.summary()));
    }
    t
}

/// Arguments of `ecsync run`.
#[derive(Debug, clap::Args)]
#[command(after_help = run_after_help())]
pub struct RunArgs {
    /// Network interface the EtherCAT segment is on.
    #[arg(long)]
    iface: String,
    /// Master synchronization method (see below).
    #[arg(long, default_value = "median")]
    method: MethodKind,
    /// Cycle time and SYNC0 period, microseconds.
    #[arg(long, default_value_t = 1000)]
    cycle_us: u32,
    /// How long to run the cyclic phase, s (default: until Ctrl-C).
    #[arg(long)]
    duration: Option<f64>,
    /// SYNC0 shift after the grid point the frames aim at, % of the cycle.
    #[arg(long, default_value_t = 30.0)]
    shift_pct: f64,
    /// Write one row per cycle to this CSV file.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    /// Also write the JSON summary to this file.
    #[arg(long)]
    summary: Option<PathBuf>,
    /// Initialisation of the master-shift methods (h_mr averaged over this long), s.
    #[arg(long, default_value_t = 1.0)]
    init_s: f64,
    /// FRMW frames of static drift compensation in the bring-up.
    #[arg(long, default_value_t = 15_000)]
    static_drift: u32,
    /// A reply not back this long after the send counts as lost, microseconds; in the cyclic
    /// phase a reply is awaited until the next cycle's slot at the latest, and one that comes
    /// later is discarded and counted as late.
    #[arg(long, default_value_t = 10_000)]
    timeout_us: u32,
    /// End the run when this many frames in a row were lost (default: never; the run keeps
    /// trying, recovering slaves that come back).
    #[arg(long)]
    give_up_after: Option<u64>,
    /// How often the bring-up sends a lost datagram again before it fails.
    #[arg(long, default_value_t = 10)]
    retries: u32,
    /// SCHED_FIFO priority of the cycle task (0: normal scheduling).
    #[arg(long, default_value_t = 80)]
    priority: i32,
    /// CPU to pin the cycle task to (default: the last).
    #[arg(long)]
    cpu: Option<usize>,
    /// How the cycle task reaches its send instant: plain (sleep to it: late by the kernel's
    /// wake-up latency), spin (wake --spin-margin-us early and busy-wait to the instant; the
    /// CPU it costs is reported), txtime (hand the frame to the kernel early with its launch
    /// time: needs the ETF qdisc, refused with what is missing where there is none).
    #[arg(long, default_value = "plain", value_parser = real_send_mode())]
    send: SendMode,
    /// Which transmit timestamp a master-shift method takes as its send time t_ms: off (the
    /// timestamp right before the send, the letter's), software (the kernel's, taken as the
    /// frame goes to the device: the stack's latency leaves the measurement), hardware (the
    /// NIC's, as the frame leaves: refused, naming what is missing, where the NIC has none),
    /// auto (hardware where the NIC has it, else software). Bus-shift methods write their
    /// send time into the frame before it leaves: off for them (auto), refused otherwise.
    #[arg(long, default_value = "auto", value_parser = ["off", "software", "hardware", "auto"])]
    tx_stamp: String,
    /// `--send spin`: how early the task wakes before each send instant, microseconds.
    #[arg(long, default_value_t = 50)]
    spin_margin_us: u32,
    /// `--send spin`: spin in odd cycles only, plain in even ones: the two side by side in one
    /// run (same host, same moments), each one's wake-to-send jitter reported and their ratio.
    #[arg(long)]
    spin_alternate: bool,
    /// Method parameters from a scenario file instead of the preset's: its [methods.*] tables
    /// and run.target_phase_us (its segment and host describe a simulated network and are not
    /// read).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Write a twin of the network to this file after the bring-up: a network TOML (the
    /// format `compare`, `bringup` and `serve --config` read) with the topology, the SII's
    /// identity and names, ESC models from 0x0000/0x0007/0x0008, cables solved from the
    /// measured delays and the crystals measured against the reference.
    #[arg(long)]
    save_network: Option<PathBuf>,
    /// Only scan: bring the network up to the delays, measure the crystals, write
    /// --save-network and exit (nothing is written to the slaves but the latches).
    #[arg(long, requires = "save_network")]
    scan_only: bool,
    /// With --save-network: the crystals are measured from receive times latched over this
    /// long, s (0.05 ..= 2; 2 s resolves 0.02 ppm with 40 ns stamps).
    #[arg(long, default_value_t = 2.0)]
    rate_window_s: f64,
    /// With --save-network: write the reference's crystal error as this, ppm, and every other
    /// slave's from its measured error against the reference (default: the reference as
    /// measured against this host's clock: after a run of 10 000 cycles or more under a
    /// master-shift method, fitted on every cycle's reference time; after a scan, on the
    /// bring-up's 2 s of latches, only as good as their send stamps).
    #[arg(long, allow_negative_numbers = true)]
    reference_ppm: Option<f64>,
    /// The sync error counter limit (0x10F1:02) to write over CoE to every drive set to DC
    /// SYNC0, in PRE-OP: past it a drive leaves OP with AL status code 0x001A, which the run
    /// reports and recovers (0: the drives only count; default: the scenario's
    /// run.sync_error_limit with --config, else not written: each drive keeps its own).
    #[arg(long)]
    sync_error_limit: Option<u16>,
}

/// What `ecsync run` reads of a scenario file: the methods' tables and where the frames aim.
/// The file's other tables are the simulator's (its segment and host, its comparison's runs),
/// which a real network does not use: they are allowed and not read, so `ecsync run --config`
/// takes any `compare` scenario (or a file holding only `[methods.*]` tables). Their order is
/// the scenario's, so an unknown table is refused with the words `compare` uses.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RunScenario {
    #[serde(default, rename = "segment")]
    _segment: serde::de::IgnoredAny,
    #[serde(default, rename = "host")]
    _host: serde::de::IgnoredAny,
    #[serde(default)]
    run: RunTable,
    #[serde(default)]
    methods: MethodParams,
}

/// The `[run]` table's values `ecsync run` takes (the cycle and the shift come from its
/// flags): where the frames aim, and the drives' sync error counter limit.
#[derive(Debug, Default, Deserialize)]
struct RunTable {
    #[serde(default)]
    target_phase_us: f64,
    #[serde(default)]
    sync_error_limit: Option<i64>,
}

/// A refused method parameter, located in the scenario file.
fn param_error(src: &ConfigSource<'_>, e: ParamError) -> anyhow::Error {
    let p = Problem::new(
        e.table.to_string(),
        e.key,
        e.message().to_string(),
        e.fix().to_string(),
    );
    anyhow::Error::msg(src.locate(p))
}

/// The method with the scenario's parameters, the scenario's target phase, ns, and the sync
/// error counter limit to write (`--sync-error-limit`, else the scenario's).
fn method_for(args: &RunArgs, cycle_ns: u32) -> Result<(Method, i64, Option<u16>)> {
    let (name, text) = match &args.config {
        Some(p) => (
            p.display().to_string(),
            std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?,
        ),
        None => (
            "preset paper-2024".to_string(),
            ecsync_sim::preset::PAPER_2024_TOML.to_string(),
        ),
    };
    let src = ConfigSource::new(&name, &text);
    let file: RunScenario = src.deserialize().map_err(anyhow::Error::msg)?;
    // The words `compare` has for it (ecsync_lab::scenario), located in the file.
    let file_limit = match file.run.sync_error_limit {
        None => None,
        Some(v) => Some(u16::try_from(v).map_err(|_| {
            anyhow::Error::msg(src.locate(Problem::new(
                "run",
                "sync_error_limit",
                format!("{v} is not a sync error counter limit (0x10F1:02 is an UNSIGNED16)"),
                "give 0 to 65535 (4: ETG's slave stack code's default; 0: the drives only count), or leave it out to keep the drives' own",
            )))
        })?),
    };
    let ctx = MethodContext {
        cycle_ns,
        target_phase_ns: MethodContext::target_phase_from_us(file.run.target_phase_us)
            .map_err(|e| param_error(&src, e))?,
    };
    let mut params = file.methods;
    params.check().map_err(|e| param_error(&src, e))?;
    // Against the cycle this run uses (--cycle-us), not the file's.
    ctx.check().map_err(|e| param_error(&src, e))?;
    if !(args.init_s.is_finite() && args.init_s > 0.0) {
        bail!("--init-s must be a number of seconds > 0");
    }
    let init = ((args.init_s * 1e9 / f64::from(cycle_ns)).round() as i64).max(1);
    params.set_init_frames(init);
    params
        .check_use(args.method, &ctx)
        .map_err(|e| param_error(&src, e))?;
    Ok((
        params.build(args.method, &ctx),
        ctx.target_phase_ns,
        args.sync_error_limit.or(file_limit),
    ))
}

/// Where t_ms comes from, for `--tx-stamp` on this interface and method (hardware stamps
/// switched on here), and why auto settled for less; an error naming what is missing when the
/// mode asked for cannot be had.
fn tx_stamp_source(
    args: &RunArgs,
    master_shift: bool,
    link: &mut RealLink,
) -> Result<(TxStampSource, Option<String>)> {
    let mode: TxStampMode = args.tx_stamp.parse().map_err(anyhow::Error::msg)?;
    let iface = &args.iface;
    if mode == TxStampMode::Off {
        return Ok((TxStampSource::SendTimestamp, None));
    }
    if !master_shift {
        if mode == TxStampMode::Auto {
            return Ok((
                TxStampSource::SendTimestamp,
                Some(format!(
                    "{} writes its send time into the frame before it leaves: no transmit stamp can be its t_ms",
                    args.method
                )),
            ));
        }
        bail!(
            "--tx-stamp {mode}: {} is a bus-shift method, which writes its send time into the frame before it leaves; a transmit stamp comes after; fix: --tx-stamp off, or a master-shift method",
            args.method
        );
    }
    let mut note = None;
    if matches!(mode, TxStampMode::Hardware | TxStampMode::Auto) {
        let caps = ecsync_net::sys::nic_timestamping(iface)
            .map_err(|e| anyhow::anyhow!("ethtool -T {iface} (ETHTOOL_GET_TS_INFO): {e}"))?;
        if caps.hardware_tx() {
            match link.enable_hardware_tx_stamps(iface) {
                Ok(_) => return Ok((TxStampSource::NicHardware, None)),
                Err(e) if mode == TxStampMode::Hardware => bail!("--tx-stamp hardware: {e}"),
                Err(e) => note = Some(e),
            }
        } else {
            let missing = caps.hardware_missing().join(", ");
            if mode == TxStampMode::Hardware {
                bail!(
                    "--tx-stamp hardware: {iface} has no hardware transmit timestamps: its driver lacks {missing} (ethtool -T {iface}); fix: a NIC with hardware timestamping, or --tx-stamp software"
                );
            }
            note = Some(format!(
                "{iface} has no hardware transmit timestamps: its driver lacks {missing}"
            ));
        }
    }
    if !link.timestamps().tx_software {
        if mode == TxStampMode::Software {
            bail!(
                "--tx-stamp software: the kernel gives no software transmit timestamps on {iface} (SO_TIMESTAMPING refused); fix: --tx-stamp off"
            );
        }
        return Ok((TxStampSource::SendTimestamp, note));
    }
    Ok((TxStampSource::KernelSoftware, note))
}

pub fn run(args: RunArgs) -> Result<ExitCode> {
    if !(1..=1_000_000).contains(&args.cycle_us) {
        bail!("--cycle-us must lie in 1 ..= 1000000");
    }
    if !(0.0..100.0).contains(&args.shift_pct) {
        bail!("--shift-pct must lie in 0 ..< 100");
    }
    if let Some(d) = args.duration
        && !(d.is_finite() && d > 0.0)
    {
        bail!("--duration must be a number of seconds > 0");
    }
    // Below 2^31 ns: a 32-bit receive time's difference between two latches stays unambiguous
    // only for that long, and the latches are 20 ms apart at most anyway.
    if let Some(p) = args.reference_ppm
        && !(p.is_finite() && p.abs() <= 1000.0)
    {
        bail!("--reference-ppm must lie in -1000 ..= 1000");
    }
    if args.save_network.is_some()
        && !(args.rate_window_s.is_finite() && (0.05..=2.0).contains(&args.rate_window_s))
    {
        bail!("--rate-window-s must lie in 0.05 ..= 2 s");
    }
    let cycle_ns = args.cycle_us * 1000;
    let shift_ns = (f64::from(cycle_ns) * args.shift_pct / 100.0).round() as u32;
    let (method, target_phase_ns, sync_error_limit) = method_for(&args, cycle_ns)?;
    let csv = match &args.csv {
        Some(p) => {
            let f = std::fs::File::create(p)
                .with_context(|| format!("cannot create {}", p.display()))?;
            let mut w = std::io::BufWriter::new(f);
            writeln!(w, "{CSV_HEADER}")?;
            Some(w)
        }
        None => None,
    };
    if args.send == SendMode::Txtime {
        // Before anything goes out: a launch time the kernel ignores would be a lie.
        ecsync_net::txtime::txtime_support(&args.iface).map_err(anyhow::Error::msg)?;
    }
    let mut link = RealLink::open(&args.iface).map_err(|e| anyhow::anyhow!("{e}"))?;
    // Before anything goes out: a t_ms source the interface cannot give is refused.
    let (t_ms_source, t_ms_note) = tx_stamp_source(&args, method.is_master_shift(), &mut link)?;
    let spin = args.send == SendMode::Spin;
    link.set_send_control(SendControl {
        spin_margin_ns: spin.then_some(u64::from(args.spin_margin_us) * 1000),
        alternate: spin && args.spin_alternate,
        ..SendControl::default()
    });
    let mut exchanges = ExchangeStats::default();
    install_stop_handler();
    let rt = rt::setup(args.priority, args.cpu.map_or(rt::Pin::Last, rt::Pin::Cpu));
    for w in &rt.warnings {
        eprintln!("ecsync run: warning: {w}");
    }

    // Bring-up.
    let t_up = Instant::now();
    let twin = args.save_network.is_some();
    let cfg = BringupConfig {
        until: if args.scan_only {
            Stage::Delays
        } else {
            Stage::Op
        },
        static_drift_frames: args.static_drift,
        cycle_ns,
        sync0_shift_ns: shift_ns,
        monitor_cycles: 100,
        lock_hold_checks: 200,
        rate_window_ns: if twin {
            (args.rate_window_s * 1e9) as u64
        } else {
            0
        },
        read_sii_details: twin,
        sync_error_limit,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let json = args.json;
    // The first frames on a real network meet cold caches and page faults on both ends, and a
    // network loses frames: a procedure waits 20 ms for a reply and sends a lost frame again
    // (`--retries`, ten by default: at 10 % loss a frame fails once in 10^11).
    let procedure = ProcedureConfig {
        reply_timeout_ns: 20_000_000,
        retries: args.retries,
    };
    let net: Network = match run_procedure(
        &mut link,
        &mut engine,
        procedure,
        &mut exchanges,
        |_, _, events| {
            for e in events {
                if let (Event::Phase(p), false) = (e, json) {
                    eprintln!("  {p}");
                }
            }
        },
    ) {
        Ok(Ok(n)) => n,
        Ok(Err(e)) => match e.root() {
            MasterError::FrameLost { .. } => bail!(
                "no answer on {} during the bring-up ({e}): is a segment (or `ecsync serve`) connected?",
                args.iface
            ),
            _ => bail!("bring-up on {} failed: {e}", args.iface),
        },
        Err(NetError::Open(e)) => bail!("{e}"),
        Err(e) => bail!("bring-up on {}: {e}", args.iface),
    };
    let bring = BringupOut::of(&net, t_up.elapsed().as_secs_f64());
    if let Some(path) = &args.save_network {
        let t = ecsync_sim::twin::twin_toml(
            &net,
            &format!("interface {}", args.iface),
            args.reference_ppm,
        )
        .map_err(|e| anyhow::anyhow!("cannot write a twin of the network: {e}"))?;
        write_atomic(path, t.toml.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!(
            "network twin: {} slaves written to {} (reference {}; its crystal {} against this host's clock)",
            net.slaves.len(),
            path.display(),
            net.reference,
            net.reference_ppm_vs_master
                .map_or("not measured".to_string(), |p| format!("{p:+.2} ppm")),
        );
        for n in &t.notes {
            eprintln!("  note: {n}");
        }
        if args.scan_only {
            if json {
                println!("{}", serde_json::to_string_pretty(&net)?);
            }
            return Ok(ExitCode::SUCCESS);
        }
    }
    if !json {
        print_bringup(&bring);
    }

    // Cyclic phase.
    if net.slaves.get(usize::from(net.reference)).is_none() {
        bail!("the bring-up found no reference clock");
    }
    if !json {
        eprintln!(
            "cyclic phase: {} with {} at {} us, SYNC0 shift {} us{}; Ctrl-C stops",
            args.iface,
            args.method,
            args.cycle_us,
            shift_ns / 1000,
            args.duration
                .map_or(String::new(), |d| format!(", for {d} s"))
        );
    }
    let opts = CyclicOptions {
        cycle_ns,
        sync0_shift_ns: shift_ns,
        target_phase_ns,
        measure_init_frames: ((args.init_s * 1e9 / f64::from(cycle_ns)).round() as u64).max(1),
        duration: args
            .duration
            .map(|d| MasterDuration::from_ns((d * 1e9) as u64)),
        max_cycles: None,
        lost_in_a_row: args.give_up_after.unwrap_or(u64::MAX),
        reply_timeout: MasterDuration::from_us(u64::from(args.timeout_us.max(1))),
        t_ms_from_tx_stamp: t_ms_source != TxStampSource::SendTimestamp,
        sync_error_limit,
    };
    let csv = csv.map(|w| Box::new(w) as Box<dyn Write>);
    let mut phase = realnet::run_cyclic(&mut link, &net, method, &opts, csv, Some(&STOP))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let ref_rate = &phase.cycles.ref_rate;
    if let Some(path) = &args.save_network
        && args.reference_ppm.is_none()
        && phase.session.engine().sync().is_master_shift()
        && ref_rate.len() >= RATE_FIT_MIN_CYCLES
        && let Some(ppm) = ref_rate.ppm()
    {
        // The twin again, with the reference's crystal from the cyclic phase.
        let t = ecsync_sim::twin::twin_toml(&net, &format!("interface {}", args.iface), Some(ppm))
            .map_err(|e| anyhow::anyhow!("cannot write a twin of the network: {e}"))?;
        write_atomic(path, t.toml.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!(
            "network twin: the reference's crystal {ppm:+.2} ppm against this host's clock over {} cycles of the run, written to {}",
            ref_rate.len(),
            path.display()
        );
    }
    phase.finish_csv().context("writing the CSV file")?;
    let gone = match &phase.stopped {
        Ok(Some(Stopped::NetworkGone {
            last_good_cycle,
            lost_in_a_row,
        })) => Some((*last_good_cycle, *lost_in_a_row)),
        _ => None,
    };
    let spin = args.send == SendMode::Spin;
    let head = RunHead {
        iface: args.iface.clone(),
        method: args.method.to_string(),
        cycle_ns,
        sync0_shift_ns: shift_ns,
        bringup_link: exchanges,
        rt,
        bringup: bring,
        send: args.send,
        spin_margin_us: spin.then_some(args.spin_margin_us),
        tx_stamp_mode: args.tx_stamp.clone(),
        t_ms_source,
        t_ms_note,
        csv: args.csv.as_ref().map(|p| p.display().to_string()),
    };
    let out = RunOut::new(head, &phase, &link);
    let cycles = out.cycles;
    let stopped = phase.stopped;
    let text = serde_json::to_string_pretty(&out)?;
    if let Some(p) = &args.summary {
        write_atomic(p, text.as_bytes())
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if json {
        println!("{text}");
    } else {
        print_run(&out);
    }
    if let Err(e) = stopped {
        bail!("cyclic phase on {} stopped: {e}", args.iface);
    }
    if let Some((last, n)) = gone {
        let after = last.map_or("before any frame came back".to_string(), |c| {
            format!("after cycle {c}")
        });
        eprintln!(
            "ecsync run: error: the network stopped answering {after}: {n} frames in a row lost (is the segment or `ecsync serve` still there?); the summary and CSV hold the {cycles} cycles run"
        );
        return Ok(ExitCode::from(3));
    }
    Ok(ExitCode::SUCCESS)
}

fn print_bringup(b: &BringupOut) {
    println!(
        "bring-up: {} slaves, reference at position {}, {:.2} s",
        b.slaves.len(),
        b.reference,
        b.wall_s
    );
    println!(
        "{:>3}  {:>7}  {:<28} {:>12}  {:>10}",
        "pos", "station", "name", "delay ns", "DC"
    );
    for s in &b.slaves {
        let mut name = s.name.clone();
        name.truncate(28);
        let dc = match s.dc {
            DcCapability::SystemTime if s.position == b.reference => "reference",
            DcCapability::SystemTime => "system time",
            DcCapability::ReceiveTimes => "rx times",
            DcCapability::None => "none",
        };
        println!(
            "{:>3}  {:#07x}  {:<28} {:>12}  {:>10}",
            s.position,
            s.station,
            name,
            s.delay_ns.map_or("-".to_string(), |d| format!("{d:.1}")),
            dc
        );
    }
    match (b.converged, b.time_to_lock_ms) {
        (true, Some(t)) => println!(
            "DC locked {t:.1} ms after drift compensation began; {} after lock {} ns.",
            if b.max_abs_092c_by_broadcast {
                "|0x092C| by one broadcast (the OR of every slave's: a bound on the largest)"
            } else {
                "largest |0x092C|"
            },
            b.max_abs_092c_after_lock_ns
        ),
        _ => println!("DC did NOT lock."),
    }
}

fn print_run(o: &RunOut) {
    let us = |x: f64| x / 1e3;
    println!();
    println!(
        "{} cycles of {} at {} us on {} in {:.1} s ({}); {} skipped by host stalls, {} frames lost, {} replies after their cycle's deadline, {} duplicate replies, {} bad working counters.",
        o.cycles,
        o.method,
        o.cycle_ns / 1000,
        o.iface,
        o.duration_s,
        o.stopped,
        o.skipped_cycles,
        o.lost_frames,
        o.late_replies,
        o.duplicate_replies,
        o.bad_wkc
    );
    for r in o.recoveries.iter().filter(|r| !r.slaves.is_empty()) {
        let why = if r.left_op.is_empty() {
            String::new()
        } else {
            format!(" ({})", r.left_op.join("; "))
        };
        println!(
            "Recovered slave(s) {:?} (reset or out of OP: configured again) at {:.3} s, in {:.0} ms{why}.",
            r.slaves,
            r.start_s,
            r.end_s.map_or(f64::NAN, |e| (e - r.start_s) * 1e3)
        );
    }
    for l in &o.left_op {
        println!(
            "Drive {} left OP for {} with AL status code {} at {:.3} s{}.",
            l.slave,
            l.state,
            l.reason,
            l.found_s,
            match l.back_in_op_s {
                Some(t) => format!(", back in OP at {t:.3} s"),
                None => ", not back in OP by the end".to_string(),
            }
        );
    }
    if let Some(r) = o.recoveries.iter().find(|r| r.appeared > 0) {
        println!(
            "{} slave(s) appeared at the end of the network at {:.3} s (hot connect): counted, not taken in (bring the network up again to use them).",
            r.appeared, r.start_s
        );
    }
    if !o.sm_events_missed.is_empty() {
        let missed: Vec<String> = o
            .sm_events_missed
            .iter()
            .map(|c| format!("{}: {}", c.position, c.missed_between_reads))
            .collect();
        let total: u64 = o
            .sm_events_missed
            .iter()
            .map(|c| u64::from(c.missed_between_reads))
            .sum();
        println!(
            "SM events missed (0x1C32:0B, the drives' own count of SYNC0 cycles without new outputs, between its reads {:.1} s and {:.1} s in){}: {}",
            o.sm_events_missed
                .iter()
                .map(|c| c.first_read_s)
                .fold(f64::INFINITY, f64::min),
            o.sm_events_missed
                .iter()
                .map(|c| c.read_s)
                .fold(0.0, f64::max),
            if total > 0 {
                " -- SYNC0 came before the outputs: a SYNC0 shift too small for this host's jitter, or frames lost"
            } else {
                ""
            },
            missed.join(", ")
        );
    }
    if o.reference_held_cycles > 0 {
        println!(
            "The reference's time was gone or not believed in {} cycles: the method held over meanwhile.",
            o.reference_held_cycles
        );
    }
    if o.link_down_errors > 0 {
        println!(
            "The interface was down or refused frames {} times (frames lost meanwhile; the run went on).",
            o.link_down_errors
        );
    }
    if o.duplicate_replies * 2 > o.cycles {
        println!(
            "A second responder: {} of {} cycles' frames were answered twice (two segments on the wire, or a loop).",
            o.duplicate_replies, o.cycles
        );
    }
    println!(
        "{:<22} {:>10} {:>10} {:>10} {:>10}",
        "us", "mean", "std", "max", "min"
    );
    for (name, s) in [("M-rS", &o.m_rs), ("rS-IS |0x092C|", &o.rs_is)] {
        println!(
            "{:<22} {:>10.3} {:>10.3} {:>10.3} {:>10.3}",
            name,
            us(s.mean),
            us(s.std),
            us(s.max),
            us(s.min)
        );
    }
    let w = &o.wake_latency;
    println!(
        "wake-up latency, us:   p50 {:.1}  p99 {:.1}  p99.9 {:.1}  max {:.1}",
        w.p50_us, w.p99_us, w.p999_us, w.max_us
    );
    for (name, l) in [
        ("sleeping", &o.send.wake_to_send_plain),
        ("spinning", &o.send.wake_to_send_spin),
    ] {
        if let Some(l) = l {
            println!(
                "wake to send ({name}), us: p50 {:.1}  p99 {:.1}  p99.9 {:.1}  max {:.1}",
                l.p50_us, l.p99_us, l.p999_us, l.max_us
            );
        }
    }
    if let Some(m) = o.send.spin_margin_us {
        println!(
            "spin: {m} us margin, {:.1} % of a core ({:.1} us per spinning cycle){}",
            o.send.spin_cpu_pct,
            o.send.spin_us_per_cycle,
            o.send
                .spin_over_plain_p99
                .map_or(String::new(), |r| format!(
                    ", p99 spinning / sleeping {r:.3}"
                ))
        );
    }
    println!(
        "round trip, us:        mean {:.1}  p99 {:.1}  max {:.1}",
        us(o.round_trip.mean),
        us(o.round_trip.p99_abs),
        us(o.round_trip.max_abs)
    );
    if o.tx_path.n > 0 {
        println!(
            "send to kernel TX timestamp, us: mean {:.1}  std {:.1}  max {:.1}",
            us(o.tx_path.mean),
            us(o.tx_path.std),
            us(o.tx_path.max)
        );
    }
    let t = &o.t_ms;
    let source = match t.source {
        TxStampSource::SendTimestamp => "the send timestamp (before the send)",
        TxStampSource::KernelSoftware => "the kernel's software transmit stamp",
        TxStampSource::NicHardware => "the NIC's hardware transmit stamp",
    };
    print!("t_ms (--tx-stamp {}): {source}", t.mode);
    if t.source != TxStampSource::SendTimestamp {
        print!(
            ", {} cycles ({} without a stamp kept the send timestamp)",
            t.cycles_from_tx_stamp, t.cycles_without_tx_stamp
        );
    }
    println!();
    if let Some(n) = &t.note {
        println!("  ({n})");
    }
    if let Some(p) = &o.csv {
        println!("per-cycle CSV: {p}");
    }
}
