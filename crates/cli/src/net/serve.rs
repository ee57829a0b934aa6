//! `ecsync serve`: the virtual segment on a network interface.

use super::{STOP, install_stop_handler};
use crate::source::SourceArgs;
use anyhow::{Context, Result, bail};
use ecsync_net::rt;
use ecsync_net::sys::PacketSocket;
use ecsync_sim::Segment;
use ecsync_sim::pcap::PcapCapture;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// What `ecsync serve --help` says after the options: the judge's `--expect` keys.
fn serve_after_help() -> String {
    format!(
        "--expect keys (comma-separated key=value, key<=value, key>=value, key<value, key>value):\n{}",
        ecsync_lab::judge::Expect::keys()
    )
}

/// Arguments of `ecsync serve`.
#[derive(Debug, clap::Args)]
#[command(after_help = serve_after_help())]
pub struct ServeArgs {
    /// Network interface to serve the segment on (with --sandbox: the name of the served end).
    #[arg(long, required_unless_present = "sandbox", default_value = "")]
    iface: String,
    /// A ring's second interface: the one cabled to the master's second port, where the slave
    /// with `ring_port` (the scenario's) is cabled back (cable redundancy). Frames arriving
    /// there enter the ring at its far end; each frame goes back out of the interface of the
    /// port it leaves the ring by.
    /// With --sandbox: the name of the served ring end; a second veth pair is made, its other
    /// end (master1) COMMAND's second port, named in ECSYNC_RING_IFACE.
    #[arg(long, value_name = "IFACE")]
    ring_iface: Option<String>,
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
    /// Serving for a sandbox's COMMAND, which shares the terminal: status lines whole, not
    /// one line rewritten in place.
    #[arg(skip)]
    beside_command: bool,
    /// Play the faults of this schedule on the served segment (TOML `[[fault]]` entries, the
    /// format `compare --faults` reads; the segment's kinds: loss, corrupt, delay, power_cycle,
    /// link_down, second_responder). Times count from the first frame with process data
    /// unless it says `epoch = "start"`.
    #[arg(long)]
    faults: Option<PathBuf>,
    /// When replies leave: `wire`, at the segment's wire time (no earlier than the reply's
    /// last bit would reach the master: round trip, hops, the frame's length at 100 Mbit/s;
    /// how late this host sent them is reported apart), or `none`, as soon as processed.
    #[arg(long, value_enum, default_value_t = PaceArg::Wire)]
    pace: PaceArg,
    /// A control socket (Unix, one JSON object a line): inject or clear a fault now or at a
    /// time, read the counters and the judge, reset the segment to power-on, stop. `ecsync
    /// ctl` is its client.
    #[arg(long, value_name = "PATH")]
    control: Option<PathBuf>,
    /// Write the judge's summary.json and report.html (what the master did: its frames' phase
    /// against SYNC0, each drive's margin, late frames, missed pulses, faults and recovery)
    /// into this folder, on exit and every --report-every seconds.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// How often the judge's files are written while serving, s.
    #[arg(long, default_value_t = 10.0, value_name = "S", value_parser = positive_seconds)]
    report_every: f64,
    /// Thresholds on the judge's figures, e.g. `late=0,missed=0,phase_p999_us<=50`: serve
    /// exits 1 naming each one broken (with --sandbox, unless COMMAND failed: then its code).
    /// Keys: see `ecsync serve --help`'s end.
    #[arg(long, value_name = "SPEC")]
    expect: Option<ecsync_lab::judge::Expect>,
    #[command(flatten)]
    sandbox: super::sandbox::SandboxArgs,
}

fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("{s:?}: seconds > 0, e.g. 10")),
    }
}

/// `--pace`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum PaceArg {
    /// At the segment's wire time.
    Wire,
    /// As soon as processed.
    None,
}

/// Opens the segment's socket (EtherCAT frames, untagged or in a VLAN tag, which the answer
/// keeps), turning the OS's refusals into one clear line.
fn open_socket(iface: &str) -> Result<PacketSocket> {
    PacketSocket::open_vlan_aware(iface).map_err(|e| anyhow::anyhow!("{e}"))
}

pub fn serve(mut args: ServeArgs) -> Result<ExitCode> {
    if let Some(command) = args.sandbox.take_command() {
        let iface = std::mem::take(&mut args.iface);
        let ring = args.ring_iface.clone();
        return super::sandbox::run(command, &iface, ring.as_deref(), |iface| {
            serve(ServeArgs {
                iface,
                beside_command: true,
                ..args
            })
        });
    }
    let (name, specs, slave_names) = args.source.segment_named()?;
    let mut seg = Segment::new(&specs).context("building the segment")?;
    let schedule = load_schedule(&args)?;
    if let Some(f) = &schedule {
        f.check_segment(&seg, &name).map_err(anyhow::Error::msg)?;
        // How long serve runs is the master's to say: only an empty schedule is told.
        for w in f.warnings(None, "") {
            eprintln!("ecsync serve: warning: {w}");
        }
    }
    let mut faults = super::served::player(schedule);
    if let Some(dir) = &args.out {
        ecsync_lab::output::ensure_writable_dir(dir)
            .with_context(|| format!("--out {}: cannot write there", dir.display()))?;
    }
    // Held until serve returns: a second serve on these interfaces is refused meanwhile (a
    // ring on --iface itself is refused by `ring_socket`). Not in the sandbox: its network is
    // its own.
    let lock = |iface: &str, flag: &str| -> Result<Option<super::iface_lock::IfaceLock>> {
        if args.beside_command {
            return Ok(None);
        }
        super::iface_lock::take(iface, flag).map(Some)
    };
    let _locks = (
        lock(&args.iface, "--iface")?,
        match &args.ring_iface {
            Some(r) if *r != args.iface => lock(r, "--ring-iface")?,
            _ => None,
        },
    );
    let control = match &args.control {
        Some(p) => Some(super::control::ControlServer::bind(p)?),
        None => None,
    };
    let ring_sock = ring_socket(&args, &seg)?;
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
    print_start(&seg, &sock, &name, &args.iface);
    if let (Some(ring), Some((p, port))) = (&args.ring_iface, seg.ring()) {
        eprintln!(
            "ring: slave {} port {port} cabled back to the master's second port on {ring}",
            p + 1
        );
    }
    super::sandbox::ready(&args.sandbox, &args.iface, seg.len(), &args.source)?;
    let t0 = Instant::now();
    // The judge names its drives by network position; the scenario's names are in the file's
    // order, which a junction's ports (processed 0, 3, 1, 2) or a branch listed before the
    // line behind it put elsewhere.
    let names = (0..seg.len())
        .map(|p| slave_names[seg.spec_index(p)].clone())
        .collect();
    let judge_options = ecsync_lab::judge::JudgeOptions {
        names,
        preset: name.clone(),
        // The judge's late replies are the ones serve's own summary counts.
        late_reply_ns: ecsync_net::serve::HOST_LATE_NS,
        stalled_reply_ns: ecsync_net::serve::HOST_STALL_NS,
        ..Default::default()
    };
    // The status line rewritten in place on a terminal of serve's own; elsewhere (a log, a
    // pipe, a COMMAND writing to the same terminal) a whole line now and then.
    let live = std::io::IsTerminal::is_terminal(&std::io::stderr()) && !args.beside_command;
    let mut hooks = super::served::CliHooks {
        quiet: args.quiet,
        live,
        t0,
        last_print: Instant::now(),
        control,
        line_open: false,
        judge: ecsync_lab::judge::Judge::new(&seg, judge_options.clone()),
        judge_options,
        out: args.out.clone().map(|d| (d, args.report_every)),
        last_write: Instant::now(),
    };
    let config = ecsync_net::serve::ServeConfig {
        pace: match args.pace {
            PaceArg::Wire => ecsync_net::serve::Pace::Wire,
            PaceArg::None => ecsync_net::serve::Pace::None,
        },
        carrier_iface: Some(&args.iface),
        ring: ring_sock.as_ref(),
        ring_carrier_iface: args.ring_iface.as_deref(),
    };
    let quiet = args.quiet;
    let stats = ecsync_net::serve::serve(
        &sock,
        &mut seg,
        capture.as_mut(),
        &mut faults,
        config,
        &STOP,
        &mut hooks,
    )
    .map_err(|e| anyhow::anyhow!("serving on {}: {e}", args.iface))?;
    if !quiet && live {
        eprintln!();
    }
    if let Some(c) = capture {
        let n = c.frames();
        c.finish().context("writing the pcap file")?;
        eprintln!("captured {n} frames");
    }
    print_stopped(&args, &stats, &faults, t0);
    judged(&args, &hooks.judge.summary(&seg))
}

/// `--ring-iface`'s socket; refused where the segment has no ring (a frame would enter
/// nowhere); a ring served on one interface is warned of.
fn ring_socket(args: &ServeArgs, seg: &Segment) -> Result<Option<PacketSocket>> {
    let Some(iface) = &args.ring_iface else {
        if let Some((p, port)) = seg.ring() {
            eprintln!(
                "ecsync serve: warning: slave {} port {port} is cabled back to a master's second port (ring_port), which --ring-iface does not name: frames that leave the ring there are lost",
                p + 1
            );
        }
        return Ok(None);
    };
    if seg.ring().is_none() {
        bail!(
            "--ring-iface {iface}: the segment is no ring; fix: give the last slave `ring_port = 1` in the scenario (see the book's \"Cable redundancy: a ring\"), or leave --ring-iface out"
        );
    }
    if *iface == args.iface {
        bail!(
            "--ring-iface {iface}: that is --iface; fix: give the interface the ring's far end is served on, another than --iface"
        );
    }
    Ok(Some(
        open_socket(iface).with_context(|| format!("--ring-iface {iface}"))?,
    ))
}

/// `--faults`: the schedule, refused when it holds a fault of the master's host.
fn load_schedule(args: &ServeArgs) -> Result<Option<ecsync_sim::fault::FaultSchedule>> {
    Ok(match &args.faults {
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
            Some(sched)
        }
        None => None,
    })
}

/// What is served, on stderr.
fn print_start(seg: &Segment, sock: &PacketSocket, name: &str, iface: &str) {
    let reference = (0..seg.len()).find(|&i| seg.esc(i).model().dc.has_system_time());
    eprintln!(
        "ecsync serve: {name}, {} slaves, on {} (kernel timestamps: rx {}, promiscuous {}); Ctrl-C stops.",
        seg.len(),
        iface,
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
}

/// What serving did, on stderr.
fn print_stopped(
    args: &ServeArgs,
    stats: &ecsync_net::serve::ServeStats,
    faults: &ecsync_sim::fault::FaultPlayer,
    t0: Instant,
) {
    eprintln!(
        "ecsync serve: stopped after {:.1} s: {} frames received, {} answered ({} in their VLAN tag), {} not returned; {} arrived with bit 0x02 of the source address set (processed as any frame).",
        t0.elapsed().as_secs_f64(),
        stats.received,
        stats.answered,
        stats.answered_tagged,
        stats.not_returned,
        stats.marked_on_arrival
    );
    if stats.paced > 0 {
        eprintln!(
            "replies at wire time: {}; this host sent {} of them more than {} us late, {} more than {} us, the latest {:.1} us late (the host's lateness, not the model's)",
            stats.paced,
            stats.host_late,
            ecsync_net::serve::HOST_LATE_NS / 1000,
            stats.host_stalled,
            ecsync_net::serve::HOST_STALL_NS / 1000,
            stats.host_late_max_ns as f64 / 1e3
        );
    }
    if stats.ring_carrier_changes > 0 {
        eprintln!(
            "{} went down and up with the ring cable's link {} times",
            args.ring_iface.as_deref().unwrap_or_default(),
            stats.ring_carrier_changes / 2
        );
    }
    if stats.carrier_changes > 0 {
        eprintln!(
            "{} went down and up with the first slave's link {} times",
            args.iface,
            stats.carrier_changes / 2
        );
    }
    if !faults.events().is_empty() || stats.dropped_by_faults > 0 {
        eprintln!(
            "faults: {} frames dropped, {} replies deferred, the interface down {} times; events:",
            stats.dropped_by_faults, stats.deferred_sends, stats.link_down_errors
        );
        for e in faults.events() {
            eprintln!(
                "  {:>10.3} s  {} {}: {}",
                e.since_epoch_ns as f64 / 1e9,
                e.kind,
                e.edge,
                e.detail
            );
        }
    }
}

/// The judge's verdict at the end: its table, its files, the thresholds.
fn judged(args: &ServeArgs, out: &ecsync_lab::judge::JudgeOut) -> Result<ExitCode> {
    if out.frames > 0 {
        eprint!("{}", ecsync_lab::judge::per_drive_table(out));
    }
    if let Some(dir) = &args.out {
        super::served::write_judge(dir, out)
            .with_context(|| format!("writing the judge's results into {}", dir.display()))?;
        eprintln!(
            "judge: {} and {}",
            dir.join("summary.json").display(),
            dir.join("report.html").display()
        );
    }
    let Some(expect) = &args.expect else {
        return Ok(ExitCode::SUCCESS);
    };
    let broken = expect.check(out);
    if broken.is_empty() {
        eprintln!("judge: every --expect threshold holds");
        return Ok(ExitCode::SUCCESS);
    }
    for b in &broken {
        eprintln!("judge: --expect broken: {b}");
    }
    Ok(ExitCode::FAILURE)
}
