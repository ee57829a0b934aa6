//! `ecsync serve` (the virtual segment on a network interface) and `ecsync run` (the master, its
//! DC bring-up and a synchronization method on a network interface).

mod control;
mod iface_lock;
mod sandbox;
mod serve;
mod served;
mod text;

pub use control::{CtlArgs, ctl};
pub use serve::{ServeArgs, serve};

use anyhow::{Context, Result, bail};
use ecsync_dc::MasterSync as _;
use ecsync_dc::method::{Method, MethodContext, MethodKind, MethodParams, ParamError};
use ecsync_dc::time::MasterDuration;
use ecsync_lab::output::write_atomic;
use ecsync_lab::realnet::summary::{BringupOut, CSV_HEADER, RATE_FIT_MIN_CYCLES, RunOut};
use ecsync_lab::realnet::{self, CyclicOptions, CyclicPhase, RealTransport, RunHead};
use ecsync_master::bringup::{Phase, Stage};
use ecsync_master::driver::{ExchangeStats, ProcedureConfig, Stopped, run_procedure};
use ecsync_master::redundancy::Redundant;
use ecsync_master::transport::SendMode;
use ecsync_master::transport::{Interrupted, Interruptible};
use ecsync_master::{BringupConfig, Engine, Event, MasterError, Network, bringup};
use ecsync_net::rt;
use ecsync_net::tx_stamp::{TxStampMode, TxStampSource};
use ecsync_net::{NetError, RealLink, SendControl};
use ecsync_sim::config::{ConfigSource, Problem};
use serde::Deserialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use text::{print_bringup, print_run, stopped_in_bring_up};

/// Raised by Ctrl-C (SIGINT) and SIGTERM.
static STOP: AtomicBool = AtomicBool::new(false);

fn install_stop_handler() {
    crate::stop::raise_on_signals(&STOP);
}

/// `run --send`: the modes a real send has (a hardware transmit stamp is `--tx-stamp`), as
/// [`SendMode`]s.
fn real_send_mode() -> impl clap::builder::TypedValueParser<Value = SendMode> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(["plain", "spin", "txtime"])
        .try_map(|s| s.parse::<SendMode>())
}

/// What `ecsync run --help` says after the options: the methods, from the registry.
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
    /// Cable redundancy: the master's second port, where the last slave's free port is cabled
    /// back (a ring). Every frame leaves on both ports and the two copies that come back are
    /// made one, so a cable pulled anywhere in the ring loses no slave; the bring-up closes
    /// the last slave's port while it measures the line. The summary says what the ring did.
    #[arg(long, value_name = "IFACE")]
    ring_iface: Option<String>,
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
    /// Run the slave at auto-increment position POS (from 0) on SYNC1 with SAMPLES samples
    /// per cycle, as an oversampling terminal's DC mode asks (EL4732, EL3702): SYNC0 every
    /// cycle / SAMPLES, SYNC1 on the cycle's grid, 0x1C32:01 = 3. Repeat for more slaves.
    #[arg(long, value_name = "POS:SAMPLES", value_parser = parse_oversample)]
    oversample: Vec<ecsync_master::bringup::Oversampled>,
}

/// `--oversample POS:SAMPLES`.
fn parse_oversample(s: &str) -> Result<ecsync_master::bringup::Oversampled, String> {
    let bad = || format!("{s:?}: give POS:SAMPLES, e.g. 1:4 (position from 0, 1 to 100 samples)");
    let (pos, samples) = s.split_once(':').ok_or_else(bad)?;
    let position = pos.trim().parse::<u16>().map_err(|_| bad())?;
    let samples = samples.trim().parse::<u8>().map_err(|_| bad())?;
    if !(1..=100).contains(&samples) {
        return Err(bad());
    }
    Ok(ecsync_master::bringup::Oversampled { position, samples })
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
            ecsync_sim::config::read_text(p).map_err(anyhow::Error::msg)?,
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

/// `ecsync run`: the master on `--iface`, its DC bring-up, then the method's cyclic phase
/// until `--duration` or Ctrl-C; exit code 3 when the network stopped answering.
pub fn run(args: RunArgs) -> Result<ExitCode> {
    check_run_args(&args)?;
    let cycle_ns = args.cycle_us * 1000;
    let (method, target_phase_ns, sync_error_limit) = method_for(&args, cycle_ns)?;
    let csv = create_outputs(&args)?;
    let (mut link, t_ms_source, t_ms_note) = open_link(&args, method.is_master_shift())?;
    let ms = MethodSetup {
        method,
        target_phase_ns,
        sync_error_limit,
        t_ms_source,
        t_ms_note,
    };
    match &args.ring_iface {
        Some(ring) => {
            link.open_ring(ring)
                .map_err(|e| anyhow::anyhow!("--ring-iface {ring}: {e}"))?;
            let mut red = Redundant::new(&mut link);
            run_on(&args, &mut red, csv, ms)
        }
        None => run_on(&args, &mut link, csv, ms),
    }
}

/// The method and where its send times come from, as `run` set them up.
struct MethodSetup {
    method: Method,
    target_phase_ns: i64,
    sync_error_limit: Option<u16>,
    t_ms_source: TxStampSource,
    t_ms_note: Option<String>,
}

/// `run` on its transport (the link, or the ring's two ports in redundancy): the bring-up,
/// the cyclic phase, the summary.
fn run_on<T: RealTransport>(
    args: &RunArgs,
    link: &mut T,
    csv: Option<std::io::BufWriter<std::fs::File>>,
    ms: MethodSetup,
) -> Result<ExitCode> {
    let cycle_ns = args.cycle_us * 1000;
    let shift_ns = (f64::from(cycle_ns) * args.shift_pct / 100.0).round() as u32;
    let MethodSetup {
        method,
        target_phase_ns,
        sync_error_limit,
        t_ms_source,
        t_ms_note,
    } = ms;
    let mut exchanges = ExchangeStats::default();
    install_stop_handler();
    let rt = rt::setup(args.priority, args.cpu.map_or(rt::Pin::Last, rt::Pin::Cpu));
    for w in &rt.warnings {
        eprintln!("ecsync run: warning: {w}");
    }

    // Bring-up.
    let t_up = Instant::now();
    let net = match bring_up(
        args,
        link,
        &mut exchanges,
        cycle_ns,
        shift_ns,
        sync_error_limit,
    )? {
        Ok(net) => net,
        Err(started) => {
            eprintln!("{}", stopped_in_bring_up(&started));
            return Ok(crate::stop::exit_code());
        }
    };
    let bring = BringupOut::of(&net, t_up.elapsed().as_secs_f64());
    if let Some(path) = &args.save_network {
        save_twin(args, path, &net)?;
        if args.scan_only {
            if args.json {
                println!("{}", serde_json::to_string_pretty(&net)?);
            }
            return Ok(ExitCode::SUCCESS);
        }
    }
    if !args.json {
        print_bringup(&bring);
    }

    // Cyclic phase.
    if net.slaves.get(usize::from(net.reference)).is_none() {
        bail!("the bring-up found no reference clock");
    }
    if !args.json {
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
        oversampled: args.oversample.clone(),
    };
    let csv = csv.map(|w| Box::new(w) as Box<dyn Write>);
    let mut phase = realnet::run_cyclic(link, &net, method, &opts, csv, Some(&STOP))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    if let Some(path) = &args.save_network {
        save_twin_with_rate(args, path, &net, &phase)?;
    }
    phase.finish_csv().context("writing the CSV file")?;
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
        ring_iface: args.ring_iface.clone(),
    };
    report_run(args, head, phase, link)
}

/// Refuses the flags `run` cannot use before anything is opened.
fn check_run_args(args: &RunArgs) -> Result<()> {
    if args.ring_iface.as_deref() == Some(args.iface.as_str()) {
        bail!(
            "--ring-iface {}: that is --iface; fix: give the interface the ring's far end is cabled to, another than --iface",
            args.iface
        );
    }
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
    Ok(())
}

/// The output files: `--summary` and `--save-network` checked writable, `--csv` created with
/// its header.
fn create_outputs(args: &RunArgs) -> Result<Option<std::io::BufWriter<std::fs::File>>> {
    // The files written after the run are checked before it: a path that cannot take them
    // fails now, not after the bring-up and the cyclic phase.
    for (flag, path) in [
        ("--summary", &args.summary),
        ("--save-network", &args.save_network),
    ] {
        if let Some(p) = path {
            ecsync_lab::output::ensure_writable_file(p).map_err(|e| {
                anyhow::anyhow!(
                    "{flag}: cannot write {}: {e}; fix: give a file in a folder you can write to",
                    p.display()
                )
            })?;
        }
    }
    let Some(p) = &args.csv else {
        return Ok(None);
    };
    let f = std::fs::File::create(p).with_context(|| format!("cannot create {}", p.display()))?;
    let mut w = std::io::BufWriter::new(f);
    writeln!(w, "{CSV_HEADER}")?;
    Ok(Some(w))
}

/// The link on `--iface`, set up to send as `--send` asks, with where t_ms comes from (and why
/// auto settled for less): what the interface cannot give is refused before anything goes out.
fn open_link(
    args: &RunArgs,
    master_shift: bool,
) -> Result<(RealLink, TxStampSource, Option<String>)> {
    if args.send == SendMode::Txtime {
        // Before anything goes out: a launch time the kernel ignores would be a lie.
        ecsync_net::txtime::txtime_support(&args.iface).map_err(anyhow::Error::msg)?;
    }
    let mut link = RealLink::open(&args.iface).map_err(|e| anyhow::anyhow!("{e}"))?;
    // Before anything goes out: a t_ms source the interface cannot give is refused.
    let (t_ms_source, t_ms_note) = tx_stamp_source(args, master_shift, &mut link)?;
    let spin = args.send == SendMode::Spin;
    link.set_send_control(SendControl {
        spin_margin_ns: spin.then_some(u64::from(args.spin_margin_us) * 1000),
        alternate: spin && args.spin_alternate,
        ..SendControl::default()
    });
    Ok((link, t_ms_source, t_ms_note))
}

/// The DC bring-up on the link, to OP (to the delays with `--scan-only`), its phases on the
/// terminal; a network that does not answer is named as such. `Err`: Ctrl-C or SIGTERM
/// stopped it (every exchange looks at the flag first), with the phases it had started.
fn bring_up<T: RealTransport>(
    args: &RunArgs,
    link: &mut T,
    exchanges: &mut ExchangeStats,
    cycle_ns: u32,
    shift_ns: u32,
    sync_error_limit: Option<u16>,
) -> Result<Result<Network, Vec<Phase>>> {
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
        oversampled: args.oversample.clone(),
        ring: args.ring_iface.is_some(),
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
    let mut link = Interruptible::new(link, &STOP);
    let mut started = Vec::new();
    let net: Network = match run_procedure(
        &mut link,
        &mut engine,
        procedure,
        exchanges,
        |_, _, events| {
            for e in events {
                if let Event::Phase(p) = e {
                    started.push(*p);
                    if !json {
                        eprintln!("  {p}");
                    }
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
        Err(Interrupted::Stopped) => return Ok(Err(started)),
        Err(Interrupted::Transport(NetError::Open(e))) => bail!("{e}"),
        Err(Interrupted::Transport(e)) => bail!("bring-up on {}: {e}", args.iface),
    };
    Ok(Ok(net))
}

/// Writes the network's twin to `path` with the reference's crystal `reference_ppm` (`None`:
/// as the bring-up measured it); the notes the twin has on what it could not tell.
fn write_twin(
    args: &RunArgs,
    path: &Path,
    net: &Network,
    reference_ppm: Option<f64>,
) -> Result<Vec<String>> {
    let t = ecsync_sim::twin::twin_toml(net, &format!("interface {}", args.iface), reference_ppm)
        .map_err(|e| anyhow::anyhow!("cannot write a twin of the network: {e}"))?;
    write_atomic(path, t.toml.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(t.notes)
}

/// `--save-network` after the bring-up: the twin with `--reference-ppm`, or the reference's
/// crystal as the bring-up measured it.
fn save_twin(args: &RunArgs, path: &Path, net: &Network) -> Result<()> {
    let notes = write_twin(args, path, net, args.reference_ppm)?;
    eprintln!(
        "network twin: {} slaves written to {} (reference {}; its crystal {} against this host's clock)",
        net.slaves.len(),
        path.display(),
        net.reference,
        net.reference_ppm_vs_master
            .map_or("not measured".to_string(), |p| format!("{p:+.2} ppm")),
    );
    for n in &notes {
        eprintln!("  note: {n}");
    }
    Ok(())
}

/// `--save-network` after the cyclic phase: the twin again, with the reference's crystal
/// fitted on every cycle's reference time, where a master-shift method ran long enough and
/// `--reference-ppm` did not set it.
fn save_twin_with_rate(
    args: &RunArgs,
    path: &Path,
    net: &Network,
    phase: &CyclicPhase,
) -> Result<()> {
    let ref_rate = &phase.cycles.ref_rate;
    if args.reference_ppm.is_none()
        && phase.session.engine().sync().is_master_shift()
        && ref_rate.len() >= RATE_FIT_MIN_CYCLES
        && let Some(ppm) = ref_rate.ppm()
    {
        write_twin(args, path, net, Some(ppm))?;
        eprintln!(
            "network twin: the reference's crystal {ppm:+.2} ppm against this host's clock over {} cycles of the run, written to {}",
            ref_rate.len(),
            path.display()
        );
    }
    Ok(())
}

/// The run's summary: written to `--summary`, printed (as JSON with `--json`); the link's
/// error fails the command, a network that stopped answering gives exit code 3.
fn report_run<T: RealTransport>(
    args: &RunArgs,
    head: RunHead,
    phase: CyclicPhase,
    link: &T,
) -> Result<ExitCode> {
    let gone = match &phase.stopped {
        Ok(Some(Stopped::NetworkGone {
            last_good_cycle,
            lost_in_a_row,
        })) => Some((*last_good_cycle, *lost_in_a_row)),
        _ => None,
    };
    let out = RunOut::new(head, &phase, link);
    let cycles = out.cycles;
    let stopped = phase.stopped;
    let text = serde_json::to_string_pretty(&out)?;
    if let Some(p) = &args.summary {
        write_atomic(p, text.as_bytes())
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if args.json {
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
