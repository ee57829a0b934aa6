//! The TSN paper's integrated network, run and measured against ground truth: an EtherCAT
//! master whose clock is the DC reference, a time-aware bridge (802.1Qbv gates on its own
//! clock, store and forward), the virtual segment, and gPTP between bridge and master. The
//! network itself — the master's PHC, the bridge, gPTP, the segment behind them as the
//! master's transport — is [`ecsync_tsn::network`]; here are the scenario, the runs of its
//! variants ([`Variant`]: M1 without TSN, M2 with the bridge, M3 with the master synchronized
//! to it by gPTP), what they measure, and the report.
//!
//! In all three the master is the DC reference (the paper's design, section V): its delay to
//! the first slave is measured from the round trips of the latch frames with hardware
//! timestamps, the slaves' system time is set to the master's clock, and every cycle the master
//! writes its time to the reference slave (bus shift) which the others follow by FRMW. What
//! the paper asks of its UPPAAL models is measured here against the simulator's ground truth:
//! whether DC frames are held at a closed gate, the error of the delay measurement, the
//! precision among the slaves, the difference between master and slaves, and the gPTP offset
//! of the master from the grandmaster.
//!
//! A store-and-forward hop adds the frame's wire time, so the master's delay (measured with
//! short latch frames) differs for the longer cyclic frame; the master, knowing it talks
//! through one store-and-forward hop, adds the difference in wire time to its bus shift write.

pub mod report;
pub mod scenario;

use crate::run::{Envelope, Series};
use crate::session::{Aim, CycleObserver, Session, SessionConfig, SessionError};
use crate::stats::{Stats, Summary};
use ecsync_dc::BusShift;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_master::bringup::{BringupConfig, EsiTiming, Network, Stage, bringup};
use ecsync_master::driver::{
    CycleReport, CyclicLimits, ExchangeStats, ProcedureConfig, run_procedure,
};
use ecsync_master::{Engine, MasterError};
use ecsync_sim::frame_wire_time_ps;
use ecsync_sim::pcap::PcapCapture;
pub use ecsync_tsn::network::Blocked;
use ecsync_tsn::network::{NetworkError, TIMEOUT_PS, TsnNetwork};
pub use scenario::{TsnScenario, Variant};
use serde::Serialize;
use std::path::Path;

/// Why a variant could not run.
#[derive(Debug, thiserror::Error)]
pub enum TsnError {
    /// The bring-up failed.
    #[error("{variant}: bring-up failed: {cause}")]
    Bringup {
        /// Variant.
        variant: &'static str,
        /// Why (in the message, not a source of its own: said once).
        cause: MasterError,
    },
    /// The network cannot be built (its segment), or its capture not written.
    #[error(transparent)]
    Network(#[from] NetworkError),
    /// The cyclic frame does not fit.
    #[error("cyclic frame: {0}")]
    Frame(ecsync_wire::WireError),
    /// The pcap file cannot be written.
    #[error("pcap {path}: {message}")]
    Pcap {
        /// File.
        path: String,
        /// Why.
        message: String,
    },
}

/// One slave's delay from the master: measured and true.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SlaveDelay {
    /// Position.
    pub position: u16,
    /// Master delay plus the slave's delay from the reference, ns.
    pub measured_ns: f64,
    /// True time from the master's send stamp to the slave's processing unit for a latch
    /// frame with no wait at a gate, ns.
    pub true_ns: f64,
    /// measured - true, ns.
    pub error_ns: f64,
}

/// gPTP figures of M3.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GptpOut {
    /// Master clock minus grandmaster (bridge) clock over the recorded cycles, ns.
    pub offset: Summary,
    /// Mean link delay the master measured, ns.
    pub measured_link_delay_ns: f64,
    /// True one-way delay between the ports (first bit to first bit), ns.
    pub true_link_delay_ns: f64,
    /// Whether the bridge won the BMCA.
    pub bridge_is_grandmaster: bool,
    /// gPTP messages exchanged.
    pub messages: u64,
    /// Messages that waited for cross traffic in flight.
    pub held_by_cross_traffic: u64,
}

/// What one variant measured.
#[derive(Debug, Clone, Serialize)]
pub struct VariantResult {
    /// Which.
    pub variant: Variant,
    /// In words.
    pub title: &'static str,
    /// DC lock after bring-up.
    pub converged: bool,
    /// Time to lock, ms.
    pub time_to_lock_ms: Option<f64>,
    /// Master delay to the reference as measured, ns.
    pub master_delay_ns: Option<f64>,
    /// Spread of that over the latch rounds, ns.
    pub master_delay_spread_ns: Option<f64>,
    /// Per slave: measured and true delay from the master.
    pub delays: Vec<SlaveDelay>,
    /// Largest |measured - true| delay, ns.
    pub max_abs_delay_error_ns: f64,
    /// Frames held at a closed gate.
    pub blocked: Blocked,
    /// The letter's M-rS error for bus shift (`t_ra - t_ms`), ns.
    pub m_rs: Summary,
    /// The letter's rS-IS error (|0x092C| by BRD), ns.
    pub rs_is: Summary,
    /// Truth: master clock minus the reference slave's system time at the frame's pass, ns.
    pub master_minus_reference: Summary,
    /// Truth: precision, the spread (largest minus smallest) of the slaves' system times at
    /// one instant, ns.
    pub slave_spread: Summary,
    /// Truth: time from the frame's end at the last slave to its SYNC0, ns.
    pub sync0_margin: Summary,
    /// Cyclic frames that reached the last slave after its SYNC0.
    pub late_frames: u64,
    /// Cycles skipped because a reply came back after the next cycle's start.
    pub overrun_cycles: u64,
    /// Frames lost.
    pub lost_frames: u64,
    /// Cross-traffic frames the bridge sent towards the master (M2, M3).
    pub cross_traffic_frames: Option<u64>,
    /// gPTP (M3).
    pub gptp: Option<GptpOut>,
    /// Wall time of this variant, s.
    pub wall_s: f64,
    /// Histograms and series for plots.
    #[serde(skip)]
    pub plots: VariantPlots,
}

/// The distributions and time series of one variant, for plots.
#[derive(Debug, Clone)]
pub struct VariantPlots {
    /// Master minus reference.
    pub master_minus_reference: Stats,
    /// Slave spread.
    pub slave_spread: Stats,
    /// Hold at the gate of held cyclic frames, ns.
    pub wait: Stats,
    /// gPTP offset.
    pub gptp_offset: Stats,
    /// Series: master minus reference, slave spread, gPTP offset, gate hold.
    pub series: [Vec<Envelope>; 4],
}

/// Options of a TSN run.
#[derive(Debug, Clone, Default)]
pub struct TsnOptions {
    /// Capture each variant's frames at the master's port into `<dir>/<variant>.pcap`.
    pub pcap_dir: Option<std::path::PathBuf>,
    /// Capture only this many seconds of cyclic operation (the bring-up is always captured).
    pub pcap_cycles: u64,
    /// A fault schedule played on each variant's segment (`tsn run --faults`).
    pub faults: Option<ecsync_sim::fault::FaultSchedule>,
}

/// What a variant's cycles measure against the ground truth: the letter's figures, the
/// master against the reference, the slaves' spread, the last slave's SYNC0 margin, the hold
/// at the gate and the gPTP offset (the session's observer).
struct VariantTruth {
    warmup: u64,
    reference: usize,
    last: usize,
    /// The cyclic frame's lead before its grid point, ns, and its length, bytes.
    lead_ns: u64,
    frame_len: usize,
    period_ns: u64,
    shift_ns: u64,
    m_rs: Stats,
    rs_is: Stats,
    mref: Stats,
    spread: Stats,
    margin: Stats,
    wait: Stats,
    gptp_off: Stats,
    /// Master minus reference, slave spread, gPTP offset, gate hold.
    series: [Series; 4],
    late: u64,
    overruns: u64,
    lost: u64,
}

impl VariantTruth {
    fn new(s: &TsnScenario, reference: usize, last: usize, lead_ns: u64, frame_len: usize) -> Self {
        let cap = (s.cycles / crate::run::SERIES_BLOCK + 2) as usize;
        VariantTruth {
            warmup: s.warmup_cycles,
            reference,
            last,
            lead_ns,
            frame_len,
            period_ns: u64::from(s.cycle_ns),
            shift_ns: u64::from(s.sync0_shift_ns),
            m_rs: Stats::new(),
            rs_is: Stats::new(),
            mref: Stats::new(),
            spread: Stats::new(),
            margin: Stats::new(),
            wait: Stats::new(),
            gptp_off: Stats::new(),
            series: [
                Series::new(cap),
                Series::new(cap),
                Series::new(cap),
                Series::new(cap),
            ],
            late: 0,
            overruns: 0,
            lost: 0,
        }
    }
}

impl CycleObserver<TsnNetwork<'_>> for VariantTruth {
    fn on_cycle(&mut self, net: &mut TsnNetwork<'_>, rep: &CycleReport) {
        let rec = &rep.record;
        self.overruns += rep.skipped_before;
        let i = rec.cycle;
        if i < self.warmup {
            return;
        }
        let k = i - self.warmup;
        if rec.receive.is_none() {
            self.lost += 1;
            return;
        }
        let (reference, last, period) = (self.reference, self.last, self.period_ns);
        let launch = net.last_launch_ns();
        let wait_fwd_ps = net.last_wait_fwd_ps();
        if wait_fwd_ps > 0 {
            self.wait.add(wait_fwd_ps as f64 / 1000.0);
        }
        self.series[3].add(k, wait_fwd_ps as f64 / 1000.0);
        if let Some(m) = rec.m_rs_ns {
            self.m_rs.add(m as f64);
        }
        if let Some(v) = rec.rs_is_ns {
            self.rs_is.add(f64::from(v));
        }
        // Ground truth at the frame's pass at the reference.
        let trace = net.segment().trace();
        let (Some(pu_ref), Some(pu_last)) = (trace.pu_ps(reference), trace.pu_ps(last)) else {
            return;
        };
        let seg = net.segment();
        let sys = |x: usize, t: u64| seg.esc(x).dc().map(|d| d.system_time_split(t));
        let Some(r) = sys(reference, pu_ref) else {
            return;
        };
        let (pw, pf) = net.phc_exact_at(pu_ref);
        let d = (pw.wrapping_sub(r.0) as i64) as f64 + (pf - r.1);
        self.mref.add(d);
        self.series[0].add(k, d);
        let seg = net.segment();
        let sys = |x: usize, t: u64| seg.esc(x).dc().map(|d| d.system_time_split(t));
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for x in 0..seg.len() {
            if let Some(v) = sys(x, pu_ref) {
                let d = (v.0.wrapping_sub(r.0) as i64) as f64 + (v.1 - r.1);
                lo = lo.min(d);
                hi = hi.max(d);
            }
        }
        self.spread.add(hi - lo);
        self.series[1].add(k, hi - lo);
        // SYNC0: the first grid point at or after the frame's aim (launch + lead), plus the
        // shift, on the last slave's clock.
        let aim = launch + self.lead_ns;
        let grid = aim - aim % period;
        let end_ps = pu_last + frame_wire_time_ps(self.frame_len);
        if let Some(e) = sys(last, end_ps) {
            let after = (e.0.wrapping_sub(grid) as i64) as f64 + e.1;
            let mg = self.shift_ns as f64 - after;
            self.margin.add(mg);
            if mg < 0.0 {
                self.late += 1;
            }
        }
        if net.runs_gptp() {
            let b = net.bridge_ns_at(pu_ref);
            let off = (pw.wrapping_sub(b) as i64) as f64 + pf;
            self.gptp_off.add(off);
            self.series[2].add(k, off);
        }
    }
}

impl VariantTruth {
    /// The variant's result: what the bring-up found, the measured `delays` (the largest
    /// |error| `max_err`, ns), this cyclic phase's figures, and what the network counted
    /// (cross traffic, gPTP, frames held at a gate); timed from `t0`.
    fn into_result(
        self,
        net: &mut TsnNetwork<'_>,
        net_info: &Network,
        variant: Variant,
        delays: Vec<SlaveDelay>,
        max_err: f64,
        t0: std::time::Instant,
    ) -> VariantResult {
        let cross_traffic_frames = net.cross_traffic_frames();
        let VariantTruth {
            m_rs,
            rs_is,
            mref,
            spread,
            margin,
            wait,
            gptp_off,
            series,
            late,
            overruns,
            lost,
            ..
        } = self;
        let gptp = net.gptp_figures().map(|g| GptpOut {
            offset: gptp_off.summary(),
            measured_link_delay_ns: g.measured_link_delay_ns.unwrap_or(f64::NAN),
            true_link_delay_ns: g.true_link_delay_ns,
            bridge_is_grandmaster: g.bridge_is_grandmaster,
            messages: g.counts.sent,
            held_by_cross_traffic: g.held_by_cross_traffic,
        });
        let [a, b, c, d] = series;
        VariantResult {
            variant,
            title: variant.title(),
            converged: net_info.lock.converged,
            time_to_lock_ms: net_info.lock.time_to_lock_ns.map(|t| t as f64 / 1e6),
            master_delay_ns: net_info.master_delay_ns,
            master_delay_spread_ns: net_info.master_delay_spread_ns,
            delays,
            max_abs_delay_error_ns: max_err,
            blocked: net.blocked(),
            m_rs: m_rs.summary(),
            rs_is: rs_is.summary(),
            master_minus_reference: mref.summary(),
            slave_spread: spread.summary(),
            sync0_margin: margin.summary(),
            late_frames: late,
            overrun_cycles: overruns,
            lost_frames: lost,
            cross_traffic_frames,
            gptp,
            wall_s: t0.elapsed().as_secs_f64(),
            plots: VariantPlots {
                master_minus_reference: mref,
                slave_spread: spread,
                wait,
                gptp_offset: gptp_off,
                series: [a.finish(), b.finish(), c.finish(), d.finish()],
            },
        }
    }
}

/// Why `variant`'s session could not start.
fn session_error(variant: Variant) -> impl Fn(SessionError) -> TsnError {
    move |e| match e {
        SessionError::Frame(w) => TsnError::Frame(w),
        SessionError::NoReference => TsnError::Bringup {
            variant: variant.name(),
            cause: MasterError::Config(e.to_string()),
        },
    }
}

/// Runs one variant of the scenario: its network, the bring-up with the master as the DC
/// reference, the delays it measured against the truth, then the cyclic phase against the
/// ground truth.
pub fn run_variant(
    s: &TsnScenario,
    variant: Variant,
    opts: &TsnOptions,
) -> Result<VariantResult, TsnError> {
    let t0 = std::time::Instant::now();
    let pcap = opts.pcap_dir.as_ref().map(|dir| pcap_path(dir, variant));
    let mut net = open_network(s, variant, opts, pcap.as_deref())?;
    let net_info = bring_up(&mut net, s, variant, opts)?;
    // The truth for a latch frame (60 bytes on the wire) with no hold.
    let latch_path_ps = net.path_ps(60);
    let (delays, max_err) = measured_delays(&net, &net_info, latch_path_ps);
    let obs = run_cyclic(
        &mut net,
        &net_info,
        s,
        variant,
        latch_path_ps,
        pcap.is_some().then_some(opts.pcap_cycles),
    )?;
    if let Some(path) = &pcap {
        net.finish_capture().map_err(pcap_error(path))?;
    }
    Ok(obs.into_result(&mut net, &net_info, variant, delays, max_err, t0))
}

/// The variant's network with the fault schedule on its segment, capturing into `pcap` if
/// one is given.
fn open_network<'a>(
    s: &'a TsnScenario,
    variant: Variant,
    opts: &TsnOptions,
    pcap: Option<&Path>,
) -> Result<TsnNetwork<'a>, TsnError> {
    let mut net = TsnNetwork::new(s.network_params(), variant)?;
    if let Some(f) = &opts.faults {
        net.set_faults(ecsync_sim::fault::FaultPlayer::new(f.clone(), s.seed));
    }
    if let Some(path) = pcap {
        let c = PcapCapture::create(path).map_err(pcap_error(path))?;
        net.capture_to(c);
    }
    Ok(net)
}

/// Why the capture at `path` cannot be written.
fn pcap_error<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> TsnError + '_ {
    move |e| TsnError::Pcap {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// gPTP's settling (M3) and the bring-up to OP with the master as the DC reference; what the
/// bring-up found of the network.
fn bring_up(
    net: &mut TsnNetwork<'_>,
    s: &TsnScenario,
    variant: Variant,
    opts: &TsnOptions,
) -> Result<Network, TsnError> {
    // M3: gPTP first (the paper: the master is synchronized to the TSN network before the DC
    // delay measurement).
    if variant == Variant::M3 {
        net.run_to(s.gptp.settle_ns * 1000);
    }
    // Bring-up with the master as the DC reference.
    let esi: Vec<EsiTiming> = s
        .slaves
        .iter()
        .map(|sp| EsiTiming {
            vendor_id: sp.device.vendor_id,
            product_code: sp.device.product_code,
            forwarding_ns: sp.model.forwarding_delay_ns.round() as i32,
            processing_ns: sp.model.processing_delay_ns.round() as i32,
        })
        .collect();
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: s.static_drift_frames,
        cycle_ns: s.cycle_ns,
        sync0_shift_ns: s.sync0_shift_ns,
        lock_hold_checks: 200,
        monitor_cycles: 10,
        esi,
        master_is_reference: true,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    // A segment with faults loses datagrams: they are sent again, as on a real network.
    let procedure = ProcedureConfig {
        reply_timeout_ns: TIMEOUT_PS / 1000,
        retries: if opts.faults.is_some() { 10 } else { 0 },
    };
    let bring = run_procedure(
        net,
        &mut engine,
        procedure,
        &mut ExchangeStats::default(),
        |_, _, _| {},
    );
    let net_info: Network = match bring {
        Ok(r) => r,
        Err(never) => match never {},
    }
    .map_err(|cause| TsnError::Bringup {
        variant: variant.name(),
        cause,
    })?;
    net.end_bringup();
    Ok(net_info)
}

/// Each slave's delay as the bring-up measured it (master delay + delay from the reference)
/// against the truth for a latch frame whose path to the first slave takes `latch_path_ps`,
/// and the largest |error|, ns.
fn measured_delays(
    net: &TsnNetwork<'_>,
    net_info: &Network,
    latch_path_ps: u64,
) -> (Vec<SlaveDelay>, f64) {
    let pu = net.segment().pu_offsets_ps();
    let mut delays = Vec::new();
    let mut max_err = 0.0f64;
    if let Some(md) = net_info.master_delay_ns {
        for (i, sl) in net_info.slaves.iter().enumerate() {
            let (Some(d), Some(p)) = (sl.delay_ns, pu[i]) else {
                continue;
            };
            let measured = md + d;
            let truth = (latch_path_ps + p) as f64 / 1000.0;
            max_err = max_err.max((measured - truth).abs());
            delays.push(SlaveDelay {
                position: sl.position,
                measured_ns: measured,
                true_ns: truth,
                error_ns: measured - truth,
            });
        }
    }
    (delays, max_err)
}

/// The cyclic phase: bus shift with the master's time at the reference, one frame a cycle
/// from the bridge's window on, its cycles measured by a [`VariantTruth`]; the capture goes on
/// for `capture_cycles` of it.
fn run_cyclic(
    net: &mut TsnNetwork<'_>,
    net_info: &Network,
    s: &TsnScenario,
    variant: Variant,
    latch_path_ps: u64,
    capture_cycles: Option<u64>,
) -> Result<VariantTruth, TsnError> {
    let cfg = SessionConfig {
        cycle_ns: s.cycle_ns,
        measure_init_frames: 1,
        recovery: None,
    };
    let cyc_len = Session::first_frame_len(net_info, BusShift { write_offset_ns: 0 }, s.cycle_ns)
        .map_err(session_error(variant))?;
    // One store-and-forward hop: the cyclic frame's first bit reaches the slaves later than a
    // latch frame's by the difference of their wire times.
    let sf_extra_ns = if variant.has_bridge() {
        (net.path_ps(cyc_len) as i64 - latch_path_ps as i64) / 1000
    } else {
        0
    };
    let write_offset_ns = net_info.master_delay_ns.map_or(0, |d| d.round() as i64) + sf_extra_ns;
    let period = u64::from(s.cycle_ns);
    let lead = net.lead_ns(cyc_len);
    let first = first_send_ns(net, s, variant, lead);
    let total = s.warmup_cycles + s.cycles;
    // One frame per cycle; a reply may take up to a cycle (held at the gates).
    let mut session = Session::new(
        net_info,
        BusShift { write_offset_ns },
        Aim::At(MasterInstant::from_ns(first)),
        cfg,
        |_| CyclicLimits {
            max_cycles: Some(total),
            lost_in_a_row: u64::MAX,
            reply_timeout: MasterDuration::from_ns(period),
            ..CyclicLimits::default()
        },
    )
    .map_err(session_error(variant))?;
    net.capture_until(match capture_cycles {
        Some(n) => net.now_ps() + n * period * 1000,
        None => 0,
    });
    let reference = usize::from(net_info.reference);
    let mut obs = VariantTruth::new(s, reference, net.segment().len() - 1, lead, cyc_len);
    match session.run(net, u64::MAX, None, &mut obs) {
        Ok(_) => {}
        Err(never) => match never {},
    }
    Ok(obs)
}

/// The master's first cyclic send, on its clock, ns: three cycles on, at the bridge's window
/// (its base and opening, plus the master's launch margin) less the frame's `lead_ns`.
fn first_send_ns(net: &mut TsnNetwork<'_>, s: &TsnScenario, variant: Variant, lead_ns: u64) -> u64 {
    let period = u64::from(s.cycle_ns);
    let open = s.bridge.ethercat_port.windows()[0].open_ns + s.master.launch_margin_ns;
    let now = net.phc_ns_at(net.now_ps());
    let base = if variant.has_bridge() {
        s.bridge.base_ns % period
    } else {
        0
    };
    (now / period + 3) * period + base + open - lead_ns
}

/// Runs every variant of the scenario (in parallel on the available cores).
pub fn run_all(s: &TsnScenario, opts: &TsnOptions) -> Result<Vec<VariantResult>, TsnError> {
    let results: Vec<Result<VariantResult, TsnError>> = std::thread::scope(|sc| {
        let handles: Vec<_> = s
            .variants
            .iter()
            .map(|&v| sc.spawn(move || run_variant(s, v, opts)))
            .collect();
        handles
            .into_iter()
            // A variant that panicked panics the run with its own message.
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    results.into_iter().collect()
}

/// Where [`run_variant`] writes variant `v`'s capture in `dir`.
pub fn pcap_path(dir: &Path, v: Variant) -> std::path::PathBuf {
    dir.join(format!("{}.pcap", v.name()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecsync_tsn::qbv::{PortSchedule, Window};

    /// gPTP on PTP's own timescale (TAI, 1.8e18 ns): absolute times must stay exact integers;
    /// as floats they would be quantised to 256 ns.
    #[test]
    fn gptp_holds_at_the_tai_epoch() {
        let mut s = scenario::preset();
        s.bridge.initial_ns = 1_795_000_000_000_000_000;
        s.warmup_cycles = 1_000;
        s.cycles = 4_000;
        s.gptp.settle_ns = 5_000_000_000;
        let r = run_variant(&s, Variant::M3, &TsnOptions::default()).unwrap();
        let g = r.gptp.expect("M3 runs gPTP");
        assert!(g.offset.rms < 20.0, "{g:?}");
        assert!(g.bridge_is_grandmaster);
        assert_eq!(r.blocked.total(), 0, "{:?}", r.blocked);
        assert!(r.max_abs_delay_error_ns <= 20.0, "{:?}", r.delays);
    }

    /// Wherever the master's clock stands against the bridge's, M3 holds no DC frame and
    /// measures every delay within 20 ns; M2 holds frames at every offset (within 30 s its
    /// frames walk through the whole gate cycle).
    #[test]
    fn m3_holds_nothing_at_any_clock_offset() {
        for k in 0..5u64 {
            let mut s = scenario::preset();
            s.master.clock_offset_ns = 77_000_000_000 + (k * 200_000 + 37_000) as i64;
            s.warmup_cycles = 500;
            s.cycles = 30_000;
            s.gptp.settle_ns = 4_000_000_000;
            let m3 = run_variant(&s, Variant::M3, &TsnOptions::default()).unwrap();
            assert_eq!(m3.blocked.total(), 0, "offset {k}: {:?}", m3.blocked);
            assert!(
                m3.max_abs_delay_error_ns <= 20.0,
                "offset {k}: {:?}",
                m3.delays
            );
            let m2 = run_variant(&s, Variant::M2, &TsnOptions::default()).unwrap();
            assert!(
                m2.blocked.cyclic_forward > 0,
                "offset {k}: {:?}",
                m2.blocked
            );
        }
    }

    /// Random gate schedules, clock offsets, crystals and cross traffic: every variant runs to
    /// the end (no panic, no lost frame), M3 never holds a frame, and whatever M2 holds is
    /// counted consistently.
    #[test]
    fn random_networks_run_and_m3_never_holds() {
        let mut rng = ecsync_sim::rng::SplitMix64(0x7357);
        for case in 0..6 {
            let mut s = scenario::preset();
            let cycle = s.bridge.cycle_ns;
            // One or two windows, each long enough for the largest frame and the margins.
            let len = 180_000 + (rng.next_unit() * 200_000.0) as u64;
            let open = (rng.next_unit() * (cycle - len) as f64) as u64;
            let mut ws = vec![Window {
                open_ns: open,
                close_ns: open + len,
            }];
            if case % 2 == 1 && open + len + 200_000 < cycle {
                ws.push(Window {
                    open_ns: open + len + 10_000,
                    close_ns: open + len + 200_000,
                });
            }
            let guard = (8 + 1500 + 12) * 80;
            s.bridge.ethercat_port = PortSchedule::new(cycle, 0, &ws, guard).unwrap();
            // The return window: the same, 50 us longer, not beyond the cycle.
            let back: Vec<Window> = ws
                .iter()
                .map(|w| Window {
                    open_ns: w.open_ns,
                    close_ns: (w.close_ns + 50_000).min(cycle),
                })
                .collect();
            let back = if back.len() == 2 && back[0].close_ns > back[1].open_ns {
                vec![Window {
                    open_ns: back[0].open_ns,
                    close_ns: back[1].close_ns,
                }]
            } else {
                back
            };
            s.bridge.master_port = PortSchedule::new(cycle, 0, &back, guard).unwrap();
            s.master.clock_offset_ns = (rng.next_unit() * 1e11) as i64;
            s.master.ppm = rng.next_unit() * 100.0 - 50.0;
            s.bridge.ppm = rng.next_unit() * 100.0 - 50.0;
            s.bridge.cross_traffic_load = rng.next_unit() * 0.9;
            s.warmup_cycles = 200;
            s.cycles = 2_000;
            s.gptp.settle_ns = 4_000_000_000;
            for v in [Variant::M1, Variant::M2, Variant::M3] {
                let r = run_variant(&s, v, &TsnOptions::default())
                    .unwrap_or_else(|e| panic!("case {case} {v:?}: {e}"));
                assert_eq!(r.lost_frames, 0, "case {case} {v:?}");
                assert!(r.converged, "case {case} {v:?}");
                let b = r.blocked;
                assert!(b.total() <= b.bringup_frames + b.cyclic_frames * 2);
                if v != Variant::M2 {
                    assert_eq!(b.total(), 0, "case {case} {v:?}: {b:?} windows {ws:?}");
                    assert!(r.max_abs_delay_error_ns <= 20.0, "case {case} {v:?}");
                }
            }
        }
    }
}
