//! `ecsync bringup`: the master engine against the virtual segment, with ground truth.

use crate::source::SourceArgs;
use anyhow::{Context, Result};
use ecsync_dc::time::MasterInstant;
use ecsync_lab::realnet::summary::SlaveIdentity;
use ecsync_master::bringup::{DcCapability, Stage};
use ecsync_master::{BringupConfig, Engine, Event, bringup};
use ecsync_sim::Segment;
use ecsync_sim::transport::SimTransport;
use serde::Serialize;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `ecsync bringup`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    source: SourceArgs,
    /// Capture every frame to this pcap file (Wireshark, tshark).
    #[arg(long)]
    pcap: Option<PathBuf>,
    /// Print a JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// FRMW frames of static drift compensation (default: the file's
    /// `run.static_drift_frames`, 15000 if it gives none). The cycle, the SYNC0 shift and the
    /// sync error limit are the file's `[run]` values too.
    #[arg(long)]
    static_drift: Option<u32>,
    /// Receive time latches averaged for the delays.
    #[arg(long, default_value_t = 16)]
    latch_rounds: u32,
    /// Cycles monitored in OP after lock.
    #[arg(long, default_value_t = 1_000)]
    monitor_cycles: u32,
    /// Play the faults of this schedule (TOML `[[fault]]` entries, or a built-in one) during
    /// the bring-up; times count from its first frame. A lost datagram is then waited for
    /// 5 ms and sent again up to ten times. The report ends with what the faults did: the
    /// frames dropped, the frames sent again, the faults' starts and ends, those not reached.
    #[arg(long)]
    faults: Option<PathBuf>,
    /// Also measure every crystal against the reference's from receive times latched over
    /// this long, s (as `ecsync run --save-network` does; 0: not measured).
    #[arg(long, default_value_t = 0.0)]
    rate_window_s: f64,
}

#[derive(Debug, Serialize)]
struct SlaveOut {
    #[serde(flatten)]
    identity: SlaveIdentity,
    /// Its name in the scenario (`name` is the device's, from its SII).
    config_name: String,
    parent: Option<(u16, u8)>,
    delay_ns: Option<f64>,
    true_delay_ns: Option<f64>,
    delay_spread_ns: Option<f64>,
    offset: Option<u64>,
    /// Written offset minus the offset that would have aligned the slave exactly, ns.
    offset_error_ns: Option<i64>,
    /// The crystal's error against the reference's as measured (`--rate-window-s`), ppm.
    ppm_vs_reference: Option<f64>,
    /// The same from the segment's crystals (their configured ppm, without the wander), ppm.
    true_ppm_vs_reference: Option<f64>,
    /// The sync unit as the bring-up left it in the slave's ESC (absent without DC).
    #[serde(skip_serializing_if = "Option::is_none")]
    sync: Option<SyncOut>,
}

/// What a slave's ESC holds of its sync unit after the bring-up (0x0981, 0x09A0, 0x09A4) and
/// what its application takes its outputs at (0x1C32:01).
#[derive(Debug, Serialize)]
struct SyncOut {
    /// SYNC0's cycle, ns (absent: SYNC0 not active).
    sync0_cycle_ns: Option<u32>,
    /// SYNC1's period, ns (absent: SYNC1 not active).
    sync1_period_ns: Option<u64>,
    /// The signal the application takes its outputs at.
    outputs_on: OutputsOn,
}

/// The signal an application takes its outputs at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum OutputsOn {
    /// Free run or SM-synchronous: no DC signal.
    NoSignal,
    Sync0,
    Sync1,
}

impl SyncOut {
    fn of(esc: &ecsync_sim::Esc) -> Option<SyncOut> {
        let dc = esc.dc()?;
        let outputs_on = if esc.runs_on_sync1() {
            OutputsOn::Sync1
        } else if esc.runs_on_sync0() {
            OutputsOn::Sync0
        } else {
            OutputsOn::NoSignal
        };
        Some(SyncOut {
            sync0_cycle_ns: dc.sync0().map(|(_, c)| c),
            sync1_period_ns: dc.sync1().map(|(_, p)| p),
            outputs_on,
        })
    }
}

#[derive(Debug, Serialize)]
struct LockOut {
    converged: bool,
    /// From the start of drift compensation until every |0x092C| stayed below 100 ns, ms.
    time_to_lock_ms: Option<f64>,
    /// From the start of drift compensation until the master had seen that hold long enough to
    /// declare the network in sync, ms.
    declared_in_sync_ms: Option<f64>,
    /// Largest true |slave - reference| system time difference after the network was declared
    /// in sync (in OP, SYNC0 running, until the end), ns.
    max_abs_diff_ns: f64,
    /// The same from the start of the run that held (includes the last of the convergence), ns.
    max_abs_diff_from_lock_start_ns: f64,
    /// Largest |0x092C| read while monitoring, ns; `null` if nothing was monitored
    /// (`--monitor-cycles 0`).
    max_abs_092c_ns: Option<u32>,
    /// 0x092C was read by one broadcast (a network whose reads per slave would not fit the
    /// cycle): `max_abs_092c_ns` is the OR of every slave's magnitude, a bound on the largest.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    max_abs_092c_by_broadcast: bool,
    frmw_frames: u64,
}

#[derive(Debug, Serialize)]
struct Out {
    source: String,
    reference: u16,
    slaves: Vec<SlaveOut>,
    lock: LockOut,
    sync0_start_ns: Option<u64>,
    pdi_bytes: u32,
    expected_lrw_wkc: u16,
    bringup_ms: f64,
    frames: u64,
    pcap: Option<String>,
    pcap_frames: u64,
    /// What `--faults` did (absent without it).
    #[serde(skip_serializing_if = "Option::is_none")]
    faults: Option<FaultsOut>,
}

/// The bring-up's exchanges that took more than one send.
#[derive(Debug, Clone, Copy, Default, Serialize)]
struct Tries {
    /// Exchanges whose frame was sent again (its reply lost, waited for, sent again).
    retried_exchanges: u64,
    /// Sends beyond the first, over all exchanges.
    retries: u64,
    /// Exchanges whose reply never came, however often sent.
    given_up: u64,
}

impl Tries {
    fn count(&mut self, x: &ecsync_master::driver::ProcedureExchange) {
        if x.attempts > 1 {
            self.retried_exchanges += 1;
            self.retries += u64::from(x.attempts - 1);
        }
        if x.received.is_none() {
            self.given_up += 1;
        }
    }
}

impl LockOut {
    /// The master's lock report beside the true differences after it declared the network in
    /// sync (`max_abs_diff_ns`) and from the start of the hold (`from_lock_start_ns`).
    fn of(
        lock: &ecsync_master::network::LockReport,
        monitored: bool,
        max_abs_diff_ns: f64,
        from_lock_start_ns: f64,
    ) -> Self {
        LockOut {
            converged: lock.converged,
            time_to_lock_ms: lock.time_to_lock_ns.map(|t| t as f64 / 1e6),
            declared_in_sync_ms: lock
                .declared_ns
                .map(|t| t.saturating_sub(lock.drift_start_ns) as f64 / 1e6),
            max_abs_diff_ns,
            max_abs_diff_from_lock_start_ns: from_lock_start_ns,
            max_abs_092c_ns: monitored.then_some(lock.max_abs_092c_after_lock_ns),
            max_abs_092c_by_broadcast: lock.max_abs_092c_by_broadcast,
            frmw_frames: lock.frmw_frames,
        }
    }
}

/// A fault of the schedule whose start the bring-up did not reach.
#[derive(Debug, Serialize)]
struct NotReached {
    fault: usize,
    kind: ecsync_sim::fault::KindName,
    at_s: f64,
}

/// What the fault schedule did during the bring-up and how the master took it.
#[derive(Debug, Serialize)]
struct FaultsOut {
    schedule: String,
    /// What the schedule did to frames.
    counts: ecsync_sim::fault::FaultCounts,
    #[serde(flatten)]
    tries: Tries,
    /// Every fault's start and end during the bring-up.
    events: Vec<ecsync_sim::fault::FaultEvent>,
    /// The faults that start after the bring-up's end.
    not_reached: Vec<NotReached>,
    /// The bring-up's length from its first frame, s.
    ended_s: f64,
}

impl FaultsOut {
    fn of(schedule: &str, f: &ecsync_sim::fault::FaultPlayer, tries: Tries, now_ps: u64) -> Self {
        let started = |n: usize| {
            f.events()
                .iter()
                .any(|e| e.fault == n && e.edge == ecsync_sim::fault::Edge::Start)
        };
        FaultsOut {
            schedule: schedule.to_string(),
            counts: f.counts(),
            tries,
            events: f.events().to_vec(),
            not_reached: (f.schedule().faults.iter().enumerate())
                .filter(|(n, _)| !started(*n))
                .map(|(n, x)| NotReached {
                    fault: n,
                    kind: x.kind.name(),
                    at_s: x.at_ns as f64 / 1e9,
                })
                .collect(),
            ended_s: now_ps.saturating_sub(f.origin_ps().unwrap_or(0)) as f64 * 1e-12,
        }
    }

    /// The faults' lines of the report.
    fn text(&self) -> String {
        let c = &self.counts;
        let t = &self.tries;
        let mut s = format!(
            "Faults ({}): the schedule dropped {} frames ({} on the way out, {} on the way back; {} corrupted), delayed {} replies and doubled {}; the bring-up sent {} frames again ({} exchanges retried) and gave up on {}.\n",
            self.schedule,
            c.lost_out + c.lost_back,
            c.lost_out,
            c.lost_back,
            c.corrupted,
            c.delayed,
            c.duplicated,
            t.retries,
            t.retried_exchanges,
            t.given_up
        );
        for e in &self.events {
            let detail = if e.detail.is_empty() {
                String::new()
            } else {
                format!(": {}", e.detail)
            };
            s += &format!(
                "  {:>9.3} s  fault[{}] {} {}{detail}\n",
                e.since_epoch_ns as f64 / 1e9,
                e.fault,
                e.kind,
                e.edge
            );
        }
        if !self.not_reached.is_empty() {
            let list: Vec<String> = (self.not_reached.iter())
                .map(|n| format!("fault[{}] {} at {} s", n.fault, n.kind, n.at_s))
                .collect();
            s += &format!(
                "  not reached (the bring-up ended {:.3} s after its first frame): {}\n",
                self.ended_s,
                list.join(", ")
            );
        }
        s
    }
}

/// True system time of slave `pos` minus the reference's at real time `t_ps`, ns (`None` for a
/// slave without a system time: receive times only, as the EL2828's, or no DC). `r` is the
/// reference's system time then (computed once for all the slaves of an exchange).
fn true_diff(seg: &Segment, pos: usize, r: (u64, f64), t_ps: u64) -> Option<f64> {
    if !seg.esc(pos).model().dc.has_system_time() {
        return None;
    }
    let a = seg.esc(pos).dc()?.system_time_split(t_ps);
    Some((a.0.wrapping_sub(r.0) as i64) as f64 + (a.1 - r.1))
}

pub fn run(args: Args) -> Result<ExitCode> {
    let (name, scenario) = args.source.scenario()?;
    let seg = Segment::new(&scenario.slaves).context("building the segment")?;
    let reference = (0..seg.len())
        .find(|&i| seg.esc(i).model().dc.has_system_time())
        .context("no slave has a DC system time to act as reference")?;
    if !(args.rate_window_s.is_finite() && (0.0..=60.0).contains(&args.rate_window_s)) {
        anyhow::bail!("--rate-window-s must lie in 0 ..= 60 s");
    }
    // The crystals' configured errors (network order), for the truth of the relative ppm.
    let crystal_ppm: Vec<Option<f64>> = (0..seg.len())
        .map(|i| seg.esc(i).dc().map(|d| d.clock().params().ppm))
        .collect();
    // The schedule before anything is written: a bad one leaves no capture behind.
    let schedule = match &args.faults {
        Some(p) => Some(load_schedule(p, &seg, &name)?),
        None => None,
    };
    // The scenario's names by network position (the tables name slaves by them).
    let names: Vec<String> = (0..seg.len())
        .map(|p| scenario.slave_names[seg.spec_index(p)].clone())
        .collect();
    let mut sim = SimTransport::new(seg);
    let procedure = match schedule {
        Some(sched) => {
            sim.set_faults(ecsync_sim::fault::FaultPlayer::new(sched, 0));
            ecsync_lab::run::FAULTY_PROCEDURE
        }
        None => ecsync_sim::transport::SIM_PROCEDURE,
    };
    if let Some(p) = &args.pcap {
        sim.capture_to(p)
            .with_context(|| format!("cannot create {}", p.display()))?;
    }
    let cfg = bringup_config(&args, &scenario, sim.segment());
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let n = sim.segment().len();
    let mut offset_error: Vec<Option<i64>> = vec![None; n];
    // (real time, worst true |slave - reference|) after the offsets are written.
    let mut samples: Vec<(u64, f64)> = Vec::new();
    let mut after_offsets = false;
    let mut frames = 0u64;
    let mut tries = Tries::default();
    // The phases as they begin, on stderr (a large segment's bring-up takes a minute).
    let started = std::time::Instant::now();
    let result = sim.run_procedure_with(&mut engine, procedure, |tr, x, events| {
        let (seg, ex) = (tr.segment(), tr.last_exchange());
        frames += 1;
        tries.count(x);
        for e in events {
            if let Event::Phase(p) = e {
                eprintln!(
                    "ecsync: {:.1} s, bring-up: {p} ({frames} frames, {:.3} s simulated)",
                    started.elapsed().as_secs_f64(),
                    ex.sent_ps as f64 * 1e-12
                );
            }
        }
        let r = seg
            .esc(reference)
            .dc()
            .map(|d| d.system_time_split(ex.sent_ps));
        if let Some(r) = r.filter(|_| events.contains(&Event::OffsetsWritten)) {
            after_offsets = true;
            for (i, e) in offset_error.iter_mut().enumerate() {
                if seg.esc(i).model().dc.has_system_time() {
                    *e = true_diff(seg, i, r, ex.sent_ps).map(|d| d.round() as i64);
                }
            }
        }
        if let Some(r) = r.filter(|_| after_offsets) {
            let worst = (0..seg.len())
                .filter_map(|i| true_diff(seg, i, r, ex.sent_ps))
                .fold(0.0f64, |w, d| w.max(d.abs()));
            samples.push((ex.sent_ps, worst));
        }
    });
    let pcap_frames = sim.finish_capture().context("writing the pcap file")?;
    let faults = args
        .faults
        .as_ref()
        .zip(sim.faults())
        .map(|(p, f)| FaultsOut::of(&p.display().to_string(), f, tries, sim.now_ps()));
    let net = match result {
        Ok(net) => net,
        Err(e) => {
            // What the faults did is the likeliest why.
            if let Some(f) = &faults {
                eprint!("{}", f.text());
            }
            anyhow::bail!("bring-up failed: {e}");
        }
    };
    let truth = sim.segment().true_delays_ns(usize::from(net.reference));
    let max_after = |t0: Option<u64>| match t0 {
        Some(t0) => samples
            .iter()
            .filter(|(t, _)| *t >= t0)
            .fold(0.0f64, |w, (_, d)| w.max(*d)),
        None => f64::NAN,
    };
    let lock_start_ps = net
        .lock
        .time_to_lock_ns
        .map(|t| sim.real_ps_at(MasterInstant::from_ns(net.lock.drift_start_ns + t)));
    let declared_ps = net
        .lock
        .declared_ns
        .map(|t| sim.real_ps_at(MasterInstant::from_ns(t)));
    let max_abs_diff_ns = max_after(declared_ps);
    let max_abs_diff_from_lock_start_ns = max_after(lock_start_ps);
    let out = Out {
        source: name,
        reference: net.reference,
        slaves: slave_rows(
            &net,
            sim.segment(),
            &names,
            &truth,
            &offset_error,
            &crystal_ppm,
        ),
        lock: LockOut::of(
            &net.lock,
            args.monitor_cycles > 0,
            max_abs_diff_ns,
            max_abs_diff_from_lock_start_ns,
        ),
        sync0_start_ns: net.sync0.map(|s| s.start_ns),
        pdi_bytes: net.pdi_len,
        expected_lrw_wkc: net.expected_lrw_wkc,
        bringup_ms: sim.now_ps() as f64 / 1e9,
        frames,
        pcap: args.pcap.as_ref().map(|p| p.display().to_string()),
        pcap_frames,
        faults,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_human(&out);
    }
    Ok(if out.lock.converged {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(2)
    })
}

/// The bring-up the file's `[run]` and the options describe (`--static-drift` over the file's
/// `run.static_drift_frames`), with the segment's oversampling terminals on SYNC1 as `compare`
/// sets them up.
fn bringup_config(args: &Args, scenario: &ecsync_lab::Scenario, seg: &Segment) -> BringupConfig {
    BringupConfig {
        until: Stage::Op,
        static_drift_frames: args.static_drift.unwrap_or(scenario.static_drift_frames),
        cycle_ns: scenario.cycle_ns,
        sync0_shift_ns: scenario.sync0_shift_ns(),
        sync_error_limit: scenario.sync_error_limit,
        latch_rounds: args.latch_rounds,
        monitor_cycles: args.monitor_cycles,
        rate_window_ns: (args.rate_window_s * 1e9) as u64,
        oversampled: ecsync_lab::run::oversampled_of(seg),
        ..BringupConfig::default()
    }
}

/// `--faults`: the schedule, checked against the network (a fault naming a slave or a port it
/// lacks is refused; an empty one is told), its times counted from the bring-up's first frame.
fn load_schedule(
    path: &std::path::Path,
    seg: &Segment,
    network: &str,
) -> Result<ecsync_sim::fault::FaultSchedule> {
    let mut sched = ecsync_sim::fault::FaultSchedule::load(path).map_err(anyhow::Error::msg)?;
    sched
        .check_segment(seg, network)
        .map_err(anyhow::Error::msg)?;
    // The bring-up's length is not known before it ends: only an empty schedule is told.
    for w in sched.warnings(None, "") {
        eprintln!("ecsync: warning: {w}");
    }
    // The bring-up's own time: from its first frame.
    sched.epoch = ecsync_sim::fault::Epoch::Start;
    Ok(sched)
}

/// The bring-up's slaves beside the segment's truth: true delays (`truth`, by position),
/// offset errors after the offsets were written, crystals (`crystal_ppm`, by position).
fn slave_rows(
    net: &ecsync_master::bringup::Network,
    seg: &Segment,
    names: &[String],
    truth: &[Option<f64>],
    offset_error: &[Option<i64>],
    crystal_ppm: &[Option<f64>],
) -> Vec<SlaveOut> {
    net.slaves
        .iter()
        .map(|s| SlaveOut {
            identity: SlaveIdentity::of(s),
            config_name: names
                .get(usize::from(s.position))
                .cloned()
                .unwrap_or_default(),
            parent: s.parent,
            delay_ns: s.delay_ns,
            true_delay_ns: truth[usize::from(s.position)].filter(|_| s.dc != DcCapability::None),
            delay_spread_ns: s.delay_spread_ns,
            offset: s.offset,
            offset_error_ns: offset_error[usize::from(s.position)],
            ppm_vs_reference: s.ppm_vs_reference,
            true_ppm_vs_reference: match (
                crystal_ppm[usize::from(s.position)],
                crystal_ppm[usize::from(net.reference)],
            ) {
                (Some(p), Some(r)) => Some(((1.0 + p * 1e-6) / (1.0 + r * 1e-6) - 1.0) * 1e6),
                _ => None,
            },
            sync: SyncOut::of(seg.esc(usize::from(s.position))),
        })
        .collect()
}

/// The slaves that take their outputs at SYNC1 (oversampling terminals), with both signals.
fn print_sync1(o: &Out) {
    for s in &o.slaves {
        let Some(y) = s.sync.as_ref().filter(|y| y.outputs_on == OutputsOn::Sync1) else {
            continue;
        };
        let (Some(c0), Some(p1)) = (y.sync0_cycle_ns, y.sync1_period_ns) else {
            continue;
        };
        println!(
            "Slave {} ({}) takes its outputs at SYNC1 every {:.1} us, with SYNC0 every {:.1} us ({} per SYNC1).",
            s.identity.position,
            s.config_name,
            p1 as f64 / 1e3,
            f64::from(c0) / 1e3,
            p1 / u64::from(c0.max(1))
        );
    }
}

fn print_human(o: &Out) {
    println!(
        "ecsync bringup: {} ({} slaves), reference clock at position {}",
        o.source,
        o.slaves.len(),
        o.reference
    );
    println!();
    // The scenario's names (as compare's tables give them), the devices' beside them.
    let w = o
        .slaves
        .iter()
        .map(|s| s.config_name.chars().count())
        .max()
        .unwrap_or(0)
        .clamp(4, 24);
    println!(
        "{:>3}  {:>7}  {:<w$} {:<28} {:<12} {:>10}  {:>12}  {:>12}  {:>7}  {:>10}",
        "pos",
        "station",
        "name",
        "device",
        "parent",
        "DC",
        "delay ns",
        "true ns",
        "err ns",
        "offset err"
    );
    for s in &o.slaves {
        let parent = match s.parent {
            Some((p, port)) => format!("{p} port {port}"),
            None => "master".to_string(),
        };
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
        let err = match (s.delay_ns, s.true_delay_ns) {
            (Some(d), Some(t)) => format!("{:+.1}", d - t),
            _ => "-".to_string(),
        };
        let dc = match s.identity.dc {
            DcCapability::SystemTime if s.identity.position == o.reference => "reference",
            DcCapability::SystemTime => "system time",
            DcCapability::ReceiveTimes => "rx times",
            DcCapability::None => "none",
        };
        let device: String = s.identity.name.chars().take(28).collect();
        let name: String = s.config_name.chars().take(w).collect();
        println!(
            "{:>3}  {:#07x}  {:<w$} {:<28} {:<12} {:>10}  {:>12}  {:>12}  {:>7}  {:>10}",
            s.identity.position,
            s.identity.station,
            name,
            device,
            parent,
            dc,
            f(s.delay_ns),
            f(s.true_delay_ns),
            err,
            s.offset_error_ns
                .map_or("-".to_string(), |e| format!("{e:+} ns")),
        );
    }
    println!();
    match (o.lock.converged, o.lock.time_to_lock_ms) {
        (true, Some(t)) => println!(
            "DC locked {t:.1} ms after drift compensation began: every |0x092C| stayed below 100 ns from then on (the drift compensation sent {} FRMW frames in all).",
            o.lock.frmw_frames
        ),
        _ => println!("DC did NOT lock."),
    }
    if let Some(d) = o.lock.declared_in_sync_ms {
        println!(
            "The master declared the network in sync at {d:.1} ms (after the hold of 1000 checks)."
        );
    }
    println!(
        "After that: largest true |slave - reference| difference {:.1} ns (from the start of the hold: {:.1} ns); {}.",
        o.lock.max_abs_diff_ns,
        o.lock.max_abs_diff_from_lock_start_ns,
        o.lock.max_abs_092c_ns.map_or(
            "0x092C not read in OP (--monitor-cycles 0)".to_string(),
            |m| if o.lock.max_abs_092c_by_broadcast {
                format!("|0x092C| read by one broadcast {m} ns (the OR of every slave's: a bound on the largest; this network's reads one by one would not fit its cycle)")
            } else {
                format!("largest |0x092C| read {m} ns")
            }
        )
    );
    if let Some(s) = o.sync0_start_ns {
        println!(
            "SYNC0 started at system time {s} ns; process data: {} bytes, LRW working counter {}.",
            o.pdi_bytes, o.expected_lrw_wkc
        );
    }
    print_sync1(o);
    println!(
        "Bring-up took {:.1} ms of simulated time, {} frames.",
        o.bringup_ms, o.frames
    );
    if let Some(p) = &o.pcap {
        println!("Captured {} frames to {p}.", o.pcap_frames);
    }
    if let Some(f) = &o.faults {
        print!("{}", f.text());
    }
}
