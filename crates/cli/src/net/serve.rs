//! `ecsync serve`: the virtual segment on a network interface.

use super::{STOP, install_stop_handler};
use crate::source::SourceArgs;
use anyhow::{Context, Result};
use ecsync_net::rt;
use ecsync_net::sys::PacketSocket;
use ecsync_sim::Segment;
use ecsync_sim::pcap::PcapCapture;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Arguments of `ecsync serve`.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Network interface to serve the segment on (with --sandbox: the name of the served end).
    #[arg(long, required_unless_present = "sandbox", default_value = "")]
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
    #[command(flatten)]
    sandbox: super::sandbox::SandboxArgs,
}

/// Opens the segment's socket (EtherCAT frames, untagged or in a VLAN tag, which the answer
/// keeps), turning the OS's refusals into one clear line.
fn open_socket(iface: &str) -> Result<PacketSocket> {
    PacketSocket::open_vlan_aware(iface).map_err(|e| anyhow::anyhow!("{e}"))
}

pub fn serve(mut args: ServeArgs) -> Result<ExitCode> {
    if let Some(command) = args.sandbox.take_command() {
        let iface = std::mem::take(&mut args.iface);
        return super::sandbox::run(command, &iface, |iface| serve(ServeArgs { iface, ..args }));
    }
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
    super::sandbox::ready(&args.sandbox, &args.iface, seg.len(), &args.source)?;
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
