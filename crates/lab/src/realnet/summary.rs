//! What `ecsync run` reports: the bring-up, the cyclic phase's figures, the link, the host's
//! timing, the recoveries, in `summary.json` and the per-cycle CSV.

use crate::stats::{Stats, Summary};
use ecsync_dc::fit::LineFit;
use ecsync_dc::time::{MasterDuration, SystemTime};
use ecsync_master::bringup::DcCapability;
use ecsync_master::driver::{CycleReport, ExchangeStats};
use ecsync_master::network::{Network, SlaveInfo};
use ecsync_master::transport::SendMode;
use ecsync_net::rt::RtReport;
use ecsync_net::sys::TimestampSupport;
use ecsync_net::tx_stamp::TxStampSource;
use serde::Serialize;
use std::io::Write;

/// Who a slave is, as every summary of a bring-up says it first (`run`'s, `bringup --json`).
#[derive(Debug, Serialize)]
pub struct SlaveIdentity {
    /// Network position, 0 = next to the master.
    pub position: u16,
    /// Configured station address.
    pub station: u16,
    /// Its name from the SII.
    pub name: String,
    /// Vendor ID (SII).
    pub vendor_id: u32,
    /// Product code (SII).
    pub product_code: u32,
    /// Serial number (SII).
    pub serial: u32,
    /// What its DC unit can do.
    pub dc: DcCapability,
}

impl SlaveIdentity {
    /// Slave `s` as the bring-up found it.
    pub fn of(s: &SlaveInfo) -> SlaveIdentity {
        SlaveIdentity {
            position: s.position,
            station: s.station,
            name: s.name.clone(),
            vendor_id: s.vendor_id,
            product_code: s.product_code,
            serial: s.serial,
            dc: s.dc,
        }
    }
}

/// One slave as the bring-up found it.
#[derive(Debug, Serialize)]
pub struct SlaveOut {
    /// Who it is.
    #[serde(flatten)]
    pub identity: SlaveIdentity,
    /// Its propagation delay from the reference, ns.
    pub delay_ns: Option<f64>,
    /// The system time offset written to it, ns.
    pub offset: Option<u64>,
}

/// The bring-up in `run`'s summary.
#[derive(Debug, Serialize)]
pub struct BringupOut {
    /// The reference clock's position.
    pub reference: u16,
    /// Every slave, in network order.
    pub slaves: Vec<SlaveOut>,
    /// Whether DC locked.
    pub converged: bool,
    /// From the static drift compensation's start to lock, ms.
    pub time_to_lock_ms: Option<f64>,
    /// The largest |0x092C| read after lock, ns.
    pub max_abs_092c_after_lock_ns: u32,
    /// 0x092C was read by one broadcast (a network whose reads per slave would not fit the
    /// cycle): the figure above is the OR of every slave's magnitude, a bound.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub max_abs_092c_by_broadcast: bool,
    /// FRMW frames of static drift compensation sent.
    pub frmw_frames: u64,
    /// Bytes of process data.
    pub pdi_bytes: u32,
    /// The LRW's expected working counter.
    pub expected_lrw_wkc: u16,
    /// SYNC0's first pulse, system time, ns.
    pub sync0_start_ns: Option<u64>,
    /// How long the bring-up took, s.
    pub wall_s: f64,
}

impl BringupOut {
    /// The bring-up of `net`, which took `wall_s`.
    pub fn of(net: &Network, wall_s: f64) -> BringupOut {
        BringupOut {
            reference: net.reference,
            slaves: net
                .slaves
                .iter()
                .map(|s| SlaveOut {
                    identity: SlaveIdentity::of(s),
                    delay_ns: s.delay_ns,
                    offset: s.offset,
                })
                .collect(),
            converged: net.lock.converged,
            time_to_lock_ms: net.lock.time_to_lock_ns.map(|t| t as f64 / 1e6),
            max_abs_092c_after_lock_ns: net.lock.max_abs_092c_after_lock_ns,
            max_abs_092c_by_broadcast: net.lock.max_abs_092c_by_broadcast,
            frmw_frames: net.lock.frmw_frames,
            pdi_bytes: net.pdi_len,
            expected_lrw_wkc: net.expected_lrw_wkc,
            sync0_start_ns: net.sync0.map(|s| s.start_ns),
            wall_s,
        }
    }
}

/// One recovery in `run`'s summary.
#[derive(Debug, Serialize)]
pub struct RecoveryRow {
    /// Start, s after the cyclic phase's start.
    pub start_s: f64,
    /// End, s after the cyclic phase's start (`None`: still running).
    pub end_s: Option<f64>,
    /// Slaves brought back (network positions, 1 = next to the master).
    pub slaves: Vec<u16>,
    /// Why it failed (tried again 50 ms later).
    pub error: Option<String>,
    /// Slaves that answered beyond the network as brought up (hot-connected): not taken in.
    pub appeared: u16,
    /// Slaves found out of OP with their configuration kept, and why (their AL status).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub left_op: Vec<String>,
}

/// A drive the recoveries found out of OP with its configuration kept, and why.
#[derive(Debug, Serialize)]
pub struct LeftOpRow {
    /// Network position, 1 = next to the master.
    pub slave: u16,
    /// The state it was in.
    pub state: String,
    /// Its AL status code (0x001A: a sync error past --sync-error-limit), 0 without an
    /// error indication.
    pub al_status_code: u16,
    /// What the code means.
    pub reason: String,
    /// When the recovery that found it started, and when it had it back in OP, s after the
    /// cyclic phase's start.
    pub found_s: f64,
    /// When the recovery had it back in OP, s after the cyclic phase's start.
    pub back_in_op_s: Option<f64>,
}

/// Wake-up latency figures, µs.
#[derive(Debug, Serialize)]
pub struct LatencyOut {
    /// Cycles.
    pub n: u64,
    /// Mean, us.
    pub mean_us: f64,
    /// Median, us.
    pub p50_us: f64,
    /// 99th percentile, us.
    pub p99_us: f64,
    /// 99.9th percentile, us.
    pub p999_us: f64,
    /// Largest, us.
    pub max_us: f64,
}

/// A drive's SM-event-missed counter (0x1C32:0B) as the master read it over CoE.
#[derive(Debug, Serialize)]
pub struct SyncCounterRow {
    /// Network position, 1 = next to the master.
    pub position: u16,
    /// 0x1C32:0B as last read.
    pub sm_events_missed: u16,
    /// When it was read, s after the cyclic phase's start.
    pub read_s: f64,
    /// 0x1C32:0B as first read (its count since OP, the hand-over from the bring-up
    /// included), and when.
    pub first_sm_events_missed: u16,
    /// When it was first read, s after the cyclic phase's start.
    pub first_read_s: f64,
    /// Counted between the two reads: the cyclic phase's own.
    pub missed_between_reads: u16,
}

/// `ecsync run`'s summary (`--summary`, `--json`).
#[derive(Debug, Serialize)]
pub struct RunOut {
    /// The interface.
    pub iface: String,
    /// The synchronization method.
    pub method: String,
    /// Cycle time, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift, ns.
    pub sync0_shift_ns: u32,
    /// Why the cyclic phase stopped: duration, cycles, interrupted, network-gone or an error.
    pub stopped: String,
    /// Cycles run.
    pub cycles: u64,
    /// Cycles skipped because the task woke after their slots had passed (host stalls).
    pub skipped_cycles: u64,
    /// The cyclic phase's wall-clock length, s.
    pub duration_s: f64,
    /// Cycles whose frame did not come back.
    pub lost_frames: u64,
    /// Replies that came after their cycle's deadline (the next cycle's slot), discarded: each
    /// is also a lost frame (on a host without PREEMPT_RT the process, not the network, is
    /// usually what was late).
    pub late_replies: u64,
    /// Second copies of replies (a second responder on the wire), discarded.
    pub duplicate_replies: u64,
    /// Answered cycles whose LRW working counter was not the expected one.
    pub bad_wkc: u64,
    /// Frames sent, replies matched, lost, stale (replies to nothing pending), truncated; the
    /// bring-up's and the cyclic phase's.
    pub link: ExchangeStats,
    /// The kernel's timestamping on the interface.
    pub timestamps: TimestampSupport,
    /// The real-time setup (scheduling, CPU, memory lock).
    pub rt: RtReport,
    /// The bring-up.
    pub bringup: BringupOut,
    /// The letter's M-rS error, ns (φ for master shift, t_ra - t_ms for bus shift).
    pub m_rs: Summary,
    /// The letter's rS-IS error (|0x092C| by BRD), ns.
    pub rs_is: Summary,
    /// Wake-up latency of the cycle task.
    pub wake_latency: LatencyOut,
    /// How the task reached its send instants, and what it cost.
    pub send: SendOut,
    /// From the send timestamp to the kernel's transmit timestamp (the NIC path's j_c), ns.
    pub tx_path: Summary,
    /// Where the master-shift method's send time t_ms came from (`--tx-stamp`).
    pub t_ms: TmsOut,
    /// From the send timestamp to the reply, ns.
    pub round_trip: Summary,
    /// A controller's state at the end (DCM): in sync, the drift it learnt, its error.
    pub controller: Option<ControllerOut>,
    /// What the figures do not show by themselves, as `compare` warns of it: a controller
    /// (DCM) not in sync at the end. Absent when there is nothing to say.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// Cycles whose reference time the engine did not believe (gone, or jumped): the method
    /// held over, the FRMW went out as an FPRD.
    pub reference_held_cycles: u64,
    /// The recoveries of slaves that lost their configuration (power-cycled): start and end,
    /// s after the cyclic phase's start, slaves brought back (positions, 1 = next to the
    /// master) or why it failed (tried again 50 ms later).
    pub recoveries: Vec<RecoveryRow>,
    /// The drives that left OP on their own (an AL error: a sync error past the configured
    /// limit, a process data watchdog), as the recoveries found them; absent when none did.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub left_op: Vec<LeftOpRow>,
    /// Each drive's SM-event-missed counter (0x1C32:0B) as last read over CoE in the cyclic
    /// phase (once a second): SYNC0 cycles the drive ran without new outputs, by its own
    /// count since it went to OP.
    pub sm_events_missed: Vec<SyncCounterRow>,
    /// Sends and receives the interface refused: it was down, or its send queue stayed full.
    pub link_down_errors: u64,
    /// Steps of the host's clock the engine saw (the reference ran on while the master's time
    /// jumped: an NTP step, a `date -s`).
    pub master_clock_steps: u32,
    /// The per-cycle CSV's path.
    pub csv: Option<String>,
    /// Cable redundancy (`run --ring-iface`): what the ring did; absent on a line.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub redundancy: Option<RedundancyOut>,
}

/// What a ring did under `run --ring-iface`, as the frames showed it (every frame sent on
/// both ports, the copies made one: `ecsync_master::redundancy`).
#[derive(Debug, Serialize)]
pub struct RedundancyOut {
    /// The master's second port.
    pub ring_iface: String,
    /// Frames that went round the intact ring.
    pub intact: u64,
    /// Frames made of two copies, one from each side of a break.
    pub merged: u64,
    /// Frames of which only one copy came back by the deadline.
    pub partial: u64,
    /// Times the ring was found broken.
    pub breaks: u64,
    /// Times it was found whole again after a break.
    pub restores: u64,
    /// Broken at the end of the run.
    pub broken_at_end: bool,
    /// Sends and receives the second port's interface refused (it was down).
    pub ring_link_down_errors: u64,
}

/// The last cycle's controller log, and what the controller reported over the run.
#[derive(Debug, Serialize)]
pub struct ControllerOut {
    /// In sync at the end.
    pub in_sync: bool,
    /// The drift it learnt, ppm.
    pub drift_ppm: f64,
    /// Its filtered error, ns.
    pub filtered_error_ns: f64,
    /// Its last adjustment, ns.
    pub adjustment_ns: i64,
    /// Cycles it ran (the slots the task skipped are not among them).
    pub cycles_run: u64,
    /// Share of those it reported in sync.
    pub in_sync_share: f64,
    /// When it first reported in sync, s after the cyclic phase's first cycle (`None`: never).
    pub first_in_sync_s: Option<f64>,
    /// Times it left "in sync".
    pub sync_losses: u64,
    /// The limits its pull-in and its "in sync" depend on (`None`: not a DCM controller).
    pub limits: Option<DcmLimitsOut>,
}

/// A DCM controller's parameters that set how fast it pulls in and when it says "in sync".
#[derive(Debug, Clone, Copy, Serialize)]
pub struct DcmLimitsOut {
    /// The most its proportional part moves the re-adjustment, ppm (0: no limit).
    pub max_slew_ppm: f64,
    /// The validity gate (used once in sync only), us.
    pub max_valid_us: f64,
    /// The filter's depth: an error moves the filtered error by `2^-depth` of itself.
    pub filter_depth: u8,
    /// The in-sync band, us.
    pub in_sync_limit_us: f64,
    /// How long the filtered error must stay in the band, s.
    pub in_sync_hold_s: f64,
}

impl DcmLimitsOut {
    /// The limits of `p` at a cycle of `cycle_ns`.
    pub fn new(p: &ecsync_dc::dcm::DcmParams, cycle_ns: u32) -> Self {
        DcmLimitsOut {
            max_slew_ppm: p.max_slew_ppm,
            max_valid_us: p.max_valid_ns as f64 / 1e3,
            filter_depth: p.filter_depth,
            in_sync_limit_us: p.in_sync_limit_ns as f64 / 1e3,
            in_sync_hold_s: p.in_sync_hold_cycles as f64 * f64::from(cycle_ns) / 1e9,
        }
    }
}

/// Why a DCM controller `c` pulled in slowly or kept leaving "in sync", as far as the run
/// shows: a learnt drift beyond its slew limit (bus shift), and wake-ups later than its
/// validity gate (`wake_p999_us`, the 99.9th percentile of the task's wake-up latency).
///
/// Measured on paper-2024's segment served on a veth pair of this non-PREEMPT_RT VM: the
/// reference's crystal (12.4 ppm) against the host's clock, not against compare's master at
/// 13.3 ppm (0.9 ppm apart), and wake-ups up to 273 us late (p99.9) took dcm-bus-shift to its
/// first "in sync" after 14.5 s and out of it again; compare with `--master-ppm 0 --host
/// vanilla-linux` shows the same (14.7 s, three losses in 40 s), and with `--master-ppm 0`
/// alone the pull-in (11.1 s, none lost).
fn slow_lock_causes(c: &ControllerOut, wake_p999_us: f64) -> Vec<String> {
    let Some(l) = c.limits else {
        return Vec::new();
    };
    let mut why = Vec::new();
    if l.max_slew_ppm > 0.0 && c.drift_ppm.abs() > l.max_slew_ppm {
        why.push(format!(
            "the reference's crystal runs about {:.1} ppm from this host's clock (the drift it learnt), beyond its {} ppm slew limit: it learns the rest of the drift by a ramp of {} ppm/s and pulls the phase in no faster than the limit, so its pull-in takes seconds to tens of seconds where crystals within the limit lock in a few",
            c.drift_ppm,
            l.max_slew_ppm,
            ecsync_dc::dcm::DRIFT_RAMP_PPM_PER_S
        ));
    }
    if wake_p999_us > l.max_valid_us {
        why.push(format!(
            "this host's task woke up to {wake_p999_us:.0} us late (p99.9), beyond its {} us validity gate, which drops such errors only once in sync: until then each moves its filtered error by 1/{} of itself, out of its {} us in-sync band, and restarts the {} s hold (a PREEMPT_RT kernel, or --send spin, keeps the wake-ups within the gate)",
            l.max_valid_us,
            1u32 << l.filter_depth.min(20),
            l.in_sync_limit_us,
            l.in_sync_hold_s
        ));
    }
    why
}

/// The warnings of a run whose method `method` ended with the controller state `c` after
/// `cycles` cycles: a controller that reports "in sync" (DCM) and was not at the end. Its
/// figures then hold a pull-in (or a loss of sync), not the lock the method is run for, and
/// nothing else in the summary says so: `compare` warns of the same.
///
/// The state at the end alone cannot tell a controller that never locked from one that lost
/// its lock: the warning says which, with the share of the run in sync and when it first was.
/// When it can tell, it says why (`slow_lock_causes`: a DCM pulling in past its slew limit,
/// late wake-ups before the lock).
pub fn controller_warnings(
    method: &str,
    c: Option<&ControllerOut>,
    cycles: u64,
    wake_p999_us: f64,
) -> Vec<String> {
    let Some(c) = c.filter(|c| !c.in_sync && cycles > 0) else {
        return Vec::new();
    };
    let why = slow_lock_causes(c, wake_p999_us);
    let why = if why.is_empty() {
        String::new()
    } else {
        format!("; likely why: {}", why.join("; and "))
    };
    let over_the_run = match c.first_in_sync_s {
        None => format!(
            "it never reported in sync in the {} cycles it ran: its figures are of its pull-in, not of a lock",
            c.cycles_run
        ),
        Some(t) => format!(
            "it was in sync {:.1} % of the {} cycles it ran, first {t:.1} s into the cyclic phase, and left it {} time{}: it locked and lost its lock, so its figures hold a loss of sync",
            c.in_sync_share * 100.0,
            c.cycles_run,
            c.sync_losses,
            if c.sync_losses == 1 { "" } else { "s" }
        ),
    };
    vec![format!(
        "{method}'s controller did not report in sync at the end of the run (filtered error {:.1} us, learnt drift {:.2} ppm); {over_the_run}{why}; a longer --duration shows whether it settles (its error must stay in its in-sync band for the hold time, 1.5 s by default)",
        c.filtered_error_ns / 1e3,
        c.drift_ppm
    )]
}

/// Cycles of the run a twin's reference crystal is fitted over at least (10 s at 1 ms).
pub const RATE_FIT_MIN_CYCLES: u64 = 10_000;

/// The reference's time against the master's send stamps, fitted as the samples come (the one
/// least-squares line, [`LineFit`]), x and y taken from their first sample so that the fit
/// works on offsets, not on nanosecond timestamps since the epoch.
#[derive(Debug, Default)]
pub struct RateFit {
    first: Option<(u64, u64)>,
    fit: LineFit,
}

impl RateFit {
    /// Adds one sample: the master's send stamp `x` and the reference's time `y`, ns.
    pub fn add(&mut self, x: u64, y: u64) {
        let (x0, y0) = *self.first.get_or_insert((x, y));
        self.fit.add(
            x.wrapping_sub(x0) as i64 as f64,
            y.wrapping_sub(y0) as i64 as f64,
        );
    }

    /// Samples fitted.
    pub fn len(&self) -> u64 {
        self.fit.len()
    }

    /// No sample yet.
    pub fn is_empty(&self) -> bool {
        self.fit.len() == 0
    }

    /// (slope - 1) in ppm.
    pub fn ppm(&self) -> Option<f64> {
        self.fit.slope().map(|b| (b - 1.0) * 1e6)
    }
}

/// `--tx-stamp` and what it did.
#[derive(Debug, Serialize)]
pub struct TmsOut {
    /// The mode asked for.
    pub mode: String,
    /// What t_ms was: the send timestamp, the kernel's software stamp or the NIC's.
    pub source: TxStampSource,
    /// Why auto fell back (no hardware stamps: what the NIC lacks; a bus-shift method).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// Cycles whose t_ms was the transmit stamp.
    pub cycles_from_tx_stamp: u64,
    /// Answered cycles whose stamp had not come: they kept the send timestamp.
    pub cycles_without_tx_stamp: u64,
}

/// `--send` and what it did.
#[derive(Debug, Serialize)]
pub struct SendOut {
    /// The send mode (`--send`).
    pub mode: SendMode,
    /// How long before the instant the task stopped sleeping to spin, us.
    pub spin_margin_us: Option<u32>,
    /// Spinning in odd cycles only (`--spin-alternate`).
    pub alternate: bool,
    /// From the cycle's scheduled start to its send timestamp (wake-up latency, the wait and
    /// the frame's assembly), in cycles that slept to the instant.
    pub wake_to_send_plain: Option<LatencyOut>,
    /// The same in cycles that spun.
    pub wake_to_send_spin: Option<LatencyOut>,
    /// p99 of the spinning cycles over p99 of the sleeping ones (`--spin-alternate`).
    pub spin_over_plain_p99: Option<f64>,
    /// CPU time spent busy-waiting, % of the cyclic phase's time.
    pub spin_cpu_pct: f64,
    /// CPU time per spinning cycle, us.
    pub spin_us_per_cycle: f64,
}

/// Wake-up latency figures of `s` (ns) in us.
pub fn latency(s: &Stats) -> LatencyOut {
    let m = s.summary();
    LatencyOut {
        n: m.n,
        mean_us: m.mean / 1e3,
        p50_us: s.abs_quantile(0.5) / 1e3,
        p99_us: m.p99_abs / 1e3,
        p999_us: m.p999_abs / 1e3,
        max_us: m.max_abs / 1e3,
    }
}

/// Writes `v` or nothing, then the separator (no allocation: this runs every cycle).
fn field<T: std::fmt::Display>(w: &mut impl Write, v: Option<T>, sep: char) -> std::io::Result<()> {
    if let Some(v) = v {
        write!(w, "{v}")?;
    }
    write!(w, "{sep}")
}

/// One cycle as a row of the per-cycle CSV ([`CSV_HEADER`]).
pub fn csv_row(w: &mut impl Write, c: &CycleReport) -> std::io::Result<()> {
    let r = &c.record;
    write!(w, "{},{},{},", r.cycle, r.scheduled.as_ns(), r.send.as_ns())?;
    field(w, r.ref_time.map(SystemTime::as_ns), ',')?;
    write!(w, "{},{},", r.output.error_ns, r.output.correction_ns)?;
    field(w, r.rs_is_ns, ',')?;
    field(w, r.lrw_wkc, ',')?;
    write!(w, "{},", c.wake_latency_ns)?;
    field(w, c.round_trip.map(MasterDuration::as_ns), ',')?;
    write!(w, "{},", u8::from(r.receive.is_none()))?;
    // The host's twin (`ecsync host fit` reads these as a trace): wake-up to the send
    // timestamp, and the send timestamp to the transport's TX stamp.
    write!(w, "{},", c.stamp.saturating_since(c.woke).as_ns())?;
    field(
        w,
        c.tx_stamp
            .map(|t| t.as_ns() as i64 - c.stamp.as_ns() as i64),
        '\n',
    )
}

/// The per-cycle CSV's columns; `exec_ns` and `tx_delay_ns` were appended after `lost` (a
/// reader of the older file keeps its columns where they were).
pub const CSV_HEADER: &str = "cycle,scheduled_ns,send_ns,ref_time_ns,error_ns,correction_ns,max_abs_092c_ns,lrw_wkc,wake_latency_ns,round_trip_ns,lost,exec_ns,tx_delay_ns";

#[cfg(test)]
mod tests {
    use super::{ControllerOut, DcmLimitsOut, RateFit, controller_warnings};

    /// A DCM controller out of sync at the end is warned of, with its error and drift; one in
    /// sync, a method without a controller, and a run of no cycles are not.
    #[test]
    fn a_controller_not_in_sync_at_the_end_is_warned_of() {
        let c = |in_sync| ControllerOut {
            in_sync,
            drift_ppm: -44.46,
            filtered_error_ns: -506_796.0,
            adjustment_ns: 0,
            cycles_run: 20_000,
            in_sync_share: 0.0,
            first_in_sync_s: None,
            sync_losses: 0,
            limits: None,
        };
        let w = controller_warnings("dcm-bus-shift", Some(&c(false)), 20_000, 0.0);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with("dcm-bus-shift's controller did not report in sync at the end")
                && w[0].contains("filtered error -506.8 us, learnt drift -44.46 ppm")
                && w[0].contains("it never reported in sync in the 20000 cycles it ran"),
            "{}",
            w[0]
        );
        // One that locked after 3.2 s and lost it once: the share and the time, no "never".
        let lost = ControllerOut {
            in_sync_share: 0.623,
            first_in_sync_s: Some(3.2),
            sync_losses: 1,
            ..c(false)
        };
        let w = controller_warnings("dcm-bus-shift", Some(&lost), 20_000, 0.0);
        assert!(
            w.len() == 1
                && w[0].contains("it was in sync 62.3 % of the 20000 cycles it ran, first 3.2 s into the cyclic phase, and left it 1 time: it locked and lost its lock")
                && !w[0].contains("never"),
            "{w:?}"
        );
        assert!(controller_warnings("dcm-bus-shift", Some(&c(true)), 20_000, 0.0).is_empty());
        assert!(controller_warnings("snap", None, 20_000, 0.0).is_empty());
        assert!(controller_warnings("dcm-bus-shift", Some(&c(false)), 0, 0.0).is_empty());
    }

    /// Why a DCM controller is slow to lock, from its limits (bus shift's defaults at 1 ms:
    /// 5 ppm, 50 us gate, depth 6, 5 us for 1.5 s): a learnt drift beyond the slew limit and
    /// wake-ups beyond the gate are named, each alone and both; within them, neither is.
    #[test]
    fn a_slow_lock_names_the_slew_limit_and_the_host_s_wake_ups() {
        use ecsync_dc::dcm::DcmParams;
        let limits = DcmLimitsOut::new(&DcmParams::default_bus_shift(0, 1_000_000), 1_000_000);
        let c = |drift_ppm| ControllerOut {
            in_sync: false,
            drift_ppm,
            filtered_error_ns: -3_498.0,
            adjustment_ns: 0,
            cycles_run: 19_995,
            in_sync_share: 0.12,
            first_in_sync_s: Some(14.5),
            sync_losses: 1,
            limits: Some(limits),
        };
        let slew = "the reference's crystal runs about 13.4 ppm from this host's clock (the drift it learnt), beyond its 5 ppm slew limit: it learns the rest of the drift by a ramp of 2 ppm/s";
        let wake = "this host's task woke up to 273 us late (p99.9), beyond its 50 us validity gate, which drops such errors only once in sync: until then each moves its filtered error by 1/64 of itself, out of its 5 us in-sync band, and restarts the 1.5 s hold";
        for (drift, p999, has_slew, has_wake) in [
            (13.36, 273.0, true, true),
            (-13.36, 20.0, true, false),
            (3.0, 273.0, false, true),
            (3.0, 20.0, false, false),
        ] {
            let w = controller_warnings("dcm-bus-shift", Some(&c(drift)), 19_995, p999);
            assert_eq!(w.len(), 1, "{w:?}");
            let slew = slew.replace("13.4", &format!("{drift:.1}"));
            assert_eq!(w[0].contains(&slew), has_slew, "{drift} {p999}: {}", w[0]);
            assert_eq!(w[0].contains(wake), has_wake, "{drift} {p999}: {}", w[0]);
            assert_eq!(
                w[0].contains("likely why"),
                has_slew || has_wake,
                "{}",
                w[0]
            );
        }
        // Master shift has no slew limit.
        let free = ControllerOut {
            limits: Some(DcmLimitsOut {
                max_slew_ppm: 0.0,
                ..limits
            }),
            ..c(40.0)
        };
        let w = controller_warnings("dcm-master-shift", Some(&free), 19_995, 20.0);
        assert!(!w[0].contains("likely why"), "{}", w[0]);
    }

    /// The track over a run by hand: out for 3 cycles, in for 4, out for 2, in for 1, out at
    /// the end: 5 of 11 in sync, first at the 4th cycle's slot, left twice.
    #[test]
    fn the_controller_track_counts_the_share_the_first_lock_and_the_losses() {
        use crate::realnet::ControllerTrack;
        use ecsync_dc::time::MasterInstant;
        let mut t = ControllerTrack::default();
        let pattern = [0, 0, 0, 1, 1, 1, 1, 0, 0, 1, 0];
        for (k, s) in pattern.iter().enumerate() {
            t.cycle(
                *s == 1,
                MasterInstant::from_ns(1_000 + k as u64 * 1_000_000),
            );
        }
        assert_eq!(t.cycles_run, 11);
        assert_eq!(t.in_sync_cycles, 5);
        assert_eq!(t.first_in_sync, Some(MasterInstant::from_ns(3_001_000)));
        assert_eq!(t.sync_losses, 2);
    }

    #[test]
    fn the_rate_fit_finds_a_crystal_under_jitter() {
        // 12.4 ppm fast, nanosecond timestamps around 2^60, +-20 us of jitter on the send
        // stamps: 20 000 cycles of 1 ms give the slope within 0.05 ppm.
        let mut f = RateFit::default();
        let mut state = 0x1234_5678_u64;
        for k in 0..20_000u64 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let jitter = (state >> 40) as i64 % 20_000;
            let x = (1u64 << 60) + k * 1_000_000;
            let y = (1u64 << 59) + ((k * 1_000_000) as f64 * (1.0 + 12.4e-6)) as u64;
            f.add(x.wrapping_add_signed(jitter), y);
        }
        let ppm = f.ppm().unwrap();
        assert!((ppm - 12.4).abs() < 0.05, "{ppm}");
    }
}
