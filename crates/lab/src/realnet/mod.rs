//! `ecsync run`'s cyclic phase on a real network (Linux raw socket), as a library: the session
//! loop of [`crate::session`] over a [`RealLink`], what each cycle shows ([`RealCycles`]), and
//! the summary it makes ([`summary::RunOut`]). The binary parses the flags, brings the network
//! up and prints; a test drives the same function in-process over a veth pair.

pub mod summary;

use crate::session::{Aim, CycleObserver, Session, SessionConfig, SessionError};
use crate::stats::Stats;
use ecsync_dc::Method;
use ecsync_dc::sync::MasterSync as _;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_master::bringup::BringupTimeouts;
use ecsync_master::driver::{CycleReport, CyclicLimits, ExchangeStats, Stopped};
use ecsync_master::network::Network;
use ecsync_master::recovery::RecoveryConfig;
use ecsync_master::redundancy::{RedundancyStats, Redundant};
use ecsync_master::transport::{SendMode, Transport};
use ecsync_net::rt::RtReport;
use ecsync_net::tx_stamp::TxStampSource;
use ecsync_net::{NetError, RealLink, SendControl};
use std::io::Write;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use summary::{
    ControllerOut, DcmLimitsOut, LeftOpRow, RateFit, RecoveryRow, RedundancyOut, RunOut, SendOut,
    SyncCounterRow, TmsOut, controller_warnings, csv_row, latency,
};

/// How the cyclic phase runs.
#[derive(Debug, Clone, PartialEq)]
pub struct CyclicOptions {
    /// Cycle time, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift after the grid point, ns (a recovered slave's).
    pub sync0_shift_ns: u32,
    /// Where in the cycle the frames aim, ns after the reference's grid point.
    pub target_phase_ns: i64,
    /// Cycles the engine measures the reference's drift over first.
    pub measure_init_frames: u64,
    /// Stop after this long (`None`: at the stop flag or the network's loss).
    pub duration: Option<MasterDuration>,
    /// Stop after this many cycles.
    pub max_cycles: Option<u64>,
    /// Give up after this many frames lost in a row.
    pub lost_in_a_row: u64,
    /// How long a reply is waited for.
    pub reply_timeout: MasterDuration,
    /// The method's t_ms is the transmit stamp ([`CyclicLimits::t_ms_from_tx_stamp`]).
    pub t_ms_from_tx_stamp: bool,
    /// The sync error counter limit a recovered drive gets again.
    pub sync_error_limit: Option<u16>,
    /// The slaves run on SYNC1 with oversampling (a recovered one gets its set-up again).
    pub oversampled: Vec<ecsync_master::bringup::Oversampled>,
}

/// What the cycles of a real network showed (the session's observer).
pub struct RealCycles {
    /// Cycles run.
    pub cycles: u64,
    /// Cycles skipped because the task woke after their slots (host stalls).
    pub skipped: u64,
    /// Cycles whose frame did not come back.
    pub lost: u64,
    /// Answered cycles whose LRW working counter was not the expected one.
    pub bad_wkc: u64,
    /// Cycles whose reference time the engine did not believe.
    pub held: u64,
    /// The letter's M-rS and rS-IS, ns.
    pub m_rs: Stats,
    /// |0x092C| by BRD, ns.
    pub rs_is: Stats,
    /// Wake-up latency, ns.
    pub wake: Stats,
    /// From the scheduled start to the send timestamp, in cycles that slept and that spun, ns.
    pub wake_to_send_plain: Stats,
    /// The same in cycles that spun.
    pub wake_to_send_spin: Stats,
    /// From the send timestamp to the transmit stamp, ns.
    pub tx_path: Stats,
    /// From the send timestamp to the reply, ns.
    pub round_trip: Stats,
    /// The reference's time against the master's send stamps: under a master-shift method
    /// the reference runs free, so the slope over the run is its crystal against this host's
    /// clock (seconds of cycles: far better than the bring-up's 2 s of latches).
    pub ref_rate: RateFit,
    /// What a controller with a log (DCM) reported over the run.
    pub controller: ControllerTrack,
    csv: Option<Box<dyn Write>>,
    csv_err: Option<std::io::Error>,
    expected_wkc: u16,
    pdi_len: u32,
    control: SendControl,
}

impl RealCycles {
    fn new(net: &Network, control: SendControl, csv: Option<Box<dyn Write>>) -> Self {
        RealCycles {
            cycles: 0,
            skipped: 0,
            lost: 0,
            bad_wkc: 0,
            held: 0,
            // Statistics without ranges: quantiles of bounded error however large a stall.
            m_rs: Stats::new(),
            rs_is: Stats::new(),
            wake: Stats::new(),
            wake_to_send_plain: Stats::new(),
            wake_to_send_spin: Stats::new(),
            tx_path: Stats::new(),
            round_trip: Stats::new(),
            ref_rate: RateFit::default(),
            controller: ControllerTrack::default(),
            csv,
            csv_err: None,
            expected_wkc: net.expected_lrw_wkc,
            pdi_len: net.pdi_len,
            control,
        }
    }
}

impl<T> CycleObserver<T> for RealCycles {
    fn on_cycle(&mut self, _: &mut T, c: &CycleReport) {
        self.cycles += 1;
        self.skipped += c.skipped_before;
        let r = &c.record;
        self.wake.add(c.wake_latency_ns as f64);
        if let (Some(t), Some(_), false) = (r.ref_time, r.receive, r.reference_held) {
            self.ref_rate.add(r.send.as_ns(), t.as_ns());
        }
        let w2s = c.stamp.signed_since(r.scheduled) as f64;
        if c.skipped_before == 0 {
            if self.control.spins(r.cycle) {
                self.wake_to_send_spin.add(w2s);
            } else {
                self.wake_to_send_plain.add(w2s);
            }
        }
        self.held += u64::from(r.reference_held);
        if let Some(log) = r.log {
            self.controller.cycle(log.in_sync, r.scheduled);
        }
        if r.receive.is_none() {
            self.lost += 1;
        } else {
            if r.lrw_wkc != Some(self.expected_wkc) && self.pdi_len > 0 {
                self.bad_wkc += 1;
            }
            if let Some(m) = r.m_rs_ns {
                self.m_rs.add(m as f64);
            }
            if let Some(v) = r.rs_is_ns {
                self.rs_is.add(f64::from(v));
            }
            if let Some(t) = c.round_trip {
                self.round_trip.add(t.as_ns() as f64);
            }
            if let Some(tx) = c.tx_stamp {
                self.tx_path.add(tx.signed_since(c.stamp) as f64);
            }
        }
        if let (Some(w), None) = (self.csv.as_mut(), self.csv_err.as_ref())
            && let Err(e) = csv_row(w, c)
        {
            self.csv_err = Some(e);
        }
    }
}

/// What a controller with a log (DCM) reported over the cycles it ran: a run that ends out
/// of sync may never have locked, or have lost its lock, and its end alone cannot say which.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct ControllerTrack {
    /// Cycles the controller ran (a slot the task skipped is none).
    pub cycles_run: u64,
    /// Of them, cycles it reported in sync.
    pub in_sync_cycles: u64,
    /// The scheduled start of the first cycle it reported in sync.
    pub first_in_sync: Option<MasterInstant>,
    /// Times it left "in sync".
    pub sync_losses: u64,
    was_in_sync: bool,
}

impl ControllerTrack {
    /// A cycle the controller ran, scheduled at `scheduled`: in sync or not.
    pub fn cycle(&mut self, in_sync: bool, scheduled: MasterInstant) {
        self.cycles_run += 1;
        if in_sync {
            self.in_sync_cycles += 1;
            self.first_in_sync.get_or_insert(scheduled);
        } else if self.was_in_sync {
            self.sync_losses += 1;
        }
        self.was_in_sync = in_sync;
    }
}

/// A real network's transport: a [`RealLink`], or a ring's two ports in redundancy
/// ([`Redundant`] over a link with its second port open, [`RealLink::open_ring`]).
pub trait RealTransport: Transport<Error = NetError> {
    /// The link (its first port's socket, its clock and counters).
    fn link(&self) -> &RealLink;
    /// What the ring did, in redundancy.
    fn redundancy(&self) -> Option<RedundancyStats> {
        None
    }
}

impl RealTransport for RealLink {
    fn link(&self) -> &RealLink {
        self
    }
}

impl RealTransport for Redundant<'_, RealLink> {
    fn link(&self) -> &RealLink {
        self.get_ref()
    }
    fn redundancy(&self) -> Option<RedundancyStats> {
        Some(self.stats())
    }
}

/// A cyclic phase as it ended.
pub struct CyclicPhase {
    /// The session: its engine (the method, its health) and driver (counters, recoveries).
    pub session: Session<Method>,
    /// What the cycles showed.
    pub cycles: RealCycles,
    /// Why it stopped, or the link's error.
    pub stopped: Result<Option<Stopped>, NetError>,
    /// Its wall-clock length, s.
    pub duration_s: f64,
}

impl CyclicPhase {
    /// Flushes the per-cycle CSV: the first error writing it, if any.
    pub fn finish_csv(&mut self) -> std::io::Result<()> {
        if let Some(mut w) = self.cycles.csv.take() {
            w.flush()?;
        }
        match self.cycles.csv_err.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// Runs the cyclic phase of `net` (brought up on `link`) under `method` until a limit of
/// `o`, the `stop` flag or the network's loss, writing each cycle to `csv` (with its header
/// already written) if given.
pub fn run_cyclic<T: RealTransport>(
    link: &mut T,
    net: &Network,
    method: Method,
    o: &CyclicOptions,
    csv: Option<Box<dyn Write>>,
    stop: Option<&AtomicBool>,
) -> Result<CyclicPhase, SessionError> {
    let cfg = SessionConfig {
        cycle_ns: o.cycle_ns,
        measure_init_frames: o.measure_init_frames,
        // Slaves that lose their configuration (power-cycled) are brought back while the
        // cycle goes on.
        recovery: Some(RecoveryConfig {
            cycle_ns: o.cycle_ns,
            sync0_shift_ns: o.sync0_shift_ns,
            sync0_lead_ns: 20_000_000,
            timeouts: BringupTimeouts::default(),
            static_drift_frames: 15_000,
            sync_error_limit: o.sync_error_limit,
            oversampled: o.oversampled.clone(),
        }),
    };
    // Aim at the reference's grid, at the target phase, where the bring-up's last reading
    // put it against the master's clock.
    let aim = Aim::ReferenceGrid {
        now: link.now(),
        target_phase_ns: o.target_phase_ns,
        lead: MasterDuration::ZERO,
    };
    let limits = CyclicLimits {
        duration: o.duration,
        max_cycles: o.max_cycles,
        lost_in_a_row: o.lost_in_a_row,
        reply_timeout: o.reply_timeout,
        // The drives' own count of SYNC0 cycles without new outputs, once a second.
        sync_counters_every: Some(MasterDuration::from_ms(1_000)),
        t_ms_from_tx_stamp: o.t_ms_from_tx_stamp,
    };
    let mut session = Session::new(net, method, aim, cfg, |_| limits)?;
    let mut cycles = RealCycles::new(net, link.link().send_control(), csv);
    let t0 = Instant::now();
    let stopped = session.run(link, u64::MAX, stop, &mut cycles);
    Ok(CyclicPhase {
        session,
        cycles,
        stopped,
        duration_s: t0.elapsed().as_secs_f64(),
    })
}

/// How a cyclic phase stopped, as the summary says it.
pub fn stopped_name(stopped: &Result<Option<Stopped>, NetError>) -> String {
    match stopped {
        Ok(Some(Stopped::Duration)) => "duration".to_string(),
        Ok(Some(Stopped::Cycles)) | Ok(None) => "cycles".to_string(),
        Ok(Some(Stopped::Interrupted)) => "interrupted".to_string(),
        Ok(Some(Stopped::NetworkGone { .. })) => "network-gone".to_string(),
        Err(e) => format!("error: {e}"),
    }
}

/// What the summary says besides the cyclic phase: the run's settings and its bring-up.
pub struct RunHead {
    /// The interface.
    pub iface: String,
    /// The method's name.
    pub method: String,
    /// Cycle time and SYNC0 shift, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift, ns.
    pub sync0_shift_ns: u32,
    /// The bring-up's exchanges (the cyclic phase's are added).
    pub bringup_link: ExchangeStats,
    /// The real-time setup.
    pub rt: RtReport,
    /// The bring-up.
    pub bringup: summary::BringupOut,
    /// How the task sent (`--send`), and its spin margin if it spun, us.
    pub send: SendMode,
    /// The spin margin, us, when the task spun.
    pub spin_margin_us: Option<u32>,
    /// `--tx-stamp` as asked, where t_ms came from, and why auto settled for less.
    pub tx_stamp_mode: String,
    /// Where t_ms came from.
    pub t_ms_source: TxStampSource,
    /// Why auto settled for less.
    pub t_ms_note: Option<String>,
    /// The per-cycle CSV's path.
    pub csv: Option<String>,
    /// The ring's second interface, in redundancy.
    pub ring_iface: Option<String>,
}

impl RunOut {
    /// The summary of a run: its head, its cyclic phase `c` on `link`.
    pub fn new<T: RealTransport>(h: RunHead, c: &CyclicPhase, tr: &T) -> RunOut {
        let link = tr.link();
        let driver = c.session.driver();
        let eng = c.session.engine();
        let first = c.session.first().as_ns();
        let f = &c.cycles;
        let d = driver.stats();
        let mut exchanges = h.bringup_link;
        exchanges.sent += d.sent;
        exchanges.replies += d.replies;
        exchanges.lost += d.lost;
        exchanges.stale += d.stale;
        exchanges.late += d.late;
        exchanges.duplicates += d.duplicates;
        exchanges.truncated += d.truncated;
        let s_of = move |t: u64| t.saturating_sub(first) as f64 / 1e9;
        let track = &f.controller;
        let controller = eng.sync().controller_log().map(|c| ControllerOut {
            in_sync: c.in_sync,
            drift_ppm: c.drift_ppm,
            filtered_error_ns: c.filtered_error_ns,
            adjustment_ns: c.adjustment_ns,
            cycles_run: track.cycles_run,
            in_sync_share: track.in_sync_cycles as f64 / track.cycles_run.max(1) as f64,
            first_in_sync_s: track.first_in_sync.map(|t| s_of(t.as_ns())),
            sync_losses: track.sync_losses,
            limits: match eng.sync() {
                Method::Dcm(d) => Some(DcmLimitsOut::new(&d.params, h.cycle_ns)),
                _ => None,
            },
        });
        let warnings = controller_warnings(
            &h.method,
            controller.as_ref(),
            f.cycles,
            latency(&f.wake).p999_us,
        );
        RunOut {
            warnings,
            iface: h.iface,
            method: h.method,
            cycle_ns: h.cycle_ns,
            sync0_shift_ns: h.sync0_shift_ns,
            stopped: stopped_name(&c.stopped),
            cycles: f.cycles,
            skipped_cycles: f.skipped,
            duration_s: c.duration_s,
            lost_frames: f.lost,
            late_replies: d.late,
            duplicate_replies: d.duplicates,
            bad_wkc: f.bad_wkc,
            link: exchanges,
            timestamps: link.timestamps(),
            rt: h.rt,
            bringup: h.bringup,
            m_rs: f.m_rs.summary(),
            rs_is: f.rs_is.summary(),
            wake_latency: latency(&f.wake),
            send: send_out(h.send, h.spin_margin_us, f, link, c.duration_s),
            tx_path: f.tx_path.summary(),
            t_ms: TmsOut {
                mode: h.tx_stamp_mode,
                source: h.t_ms_source,
                note: h.t_ms_note,
                cycles_from_tx_stamp: driver.t_ms_sources().0,
                cycles_without_tx_stamp: driver.t_ms_sources().1,
            },
            round_trip: f.round_trip.summary(),
            controller,
            reference_held_cycles: f.held,
            recoveries: driver
                .recoveries()
                .iter()
                .map(|e| RecoveryRow {
                    start_s: s_of(e.started.as_ns()),
                    end_s: e.ended.map(MasterInstant::as_ns).map(s_of),
                    slaves: e.slaves_brought_back(),
                    error: e.error(),
                    appeared: e.appeared(),
                    left_op: e.left_op(),
                })
                .collect(),
            left_op: driver
                .recoveries()
                .iter()
                .flat_map(|e| {
                    let found = s_of(e.started.as_ns());
                    let back = e.ended.map(MasterInstant::as_ns).map(s_of);
                    let l = match &e.outcome {
                        Some(Ok(r)) => r.left_op.clone(),
                        _ => Vec::new(),
                    };
                    l.into_iter().map(move |l| LeftOpRow {
                        slave: l.position + 1,
                        state: l.state_name(),
                        al_status_code: l.al_status_code(),
                        reason: l.reason(),
                        found_s: found,
                        back_in_op_s: back,
                    })
                })
                .collect(),
            sm_events_missed: driver
                .sync_counters()
                .iter()
                .map(|(f, c)| SyncCounterRow {
                    position: c.position + 1,
                    sm_events_missed: c.sm_events_missed,
                    read_s: s_of(c.read.as_ns()),
                    first_sm_events_missed: f.sm_events_missed,
                    first_read_s: s_of(f.read.as_ns()),
                    missed_between_reads: c.sm_events_missed.wrapping_sub(f.sm_events_missed),
                })
                .collect(),
            link_down_errors: link.link_down_errors(),
            redundancy: tr.redundancy().map(|r| RedundancyOut {
                ring_iface: h.ring_iface.clone().unwrap_or_default(),
                intact: r.intact,
                merged: r.merged,
                partial: r.partial,
                breaks: r.breaks,
                restores: r.restores,
                broken_at_end: r.broken,
                ring_link_down_errors: link.ring_link_down_errors(),
            }),
            master_clock_steps: eng.health().master_clock_steps,
            csv: h.csv,
        }
    }
}

/// How the task reached its send instants, and what spinning cost.
fn send_out(
    mode: SendMode,
    spin_margin_us: Option<u32>,
    f: &RealCycles,
    link: &RealLink,
    duration_s: f64,
) -> SendOut {
    let spun = link.send_control();
    let some = |s: &Stats| (s.summary().n > 0).then(|| latency(s));
    let (p, sp) = (some(&f.wake_to_send_plain), some(&f.wake_to_send_spin));
    SendOut {
        mode,
        spin_margin_us,
        alternate: f.control.alternate,
        spin_over_plain_p99: match (&p, &sp) {
            (Some(p), Some(s)) if p.p99_us > 0.0 => Some(s.p99_us / p.p99_us),
            _ => None,
        },
        wake_to_send_plain: p,
        wake_to_send_spin: sp,
        spin_cpu_pct: 100.0 * spun.spun_ns as f64 / (duration_s * 1e9).max(1.0),
        spin_us_per_cycle: spun.spun_ns as f64 / 1e3 / spun.spun_cycles.max(1) as f64,
    }
}
