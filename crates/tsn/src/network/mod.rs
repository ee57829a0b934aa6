//! The TSN paper's integrated network built from real parts, as the EtherCAT master's
//! [`Transport`]: the master's hardware clock ([`Phc`]), a time-aware bridge (802.1Qbv gates
//! on its own clock, store and forward, cross traffic), the virtual segment behind it, and
//! gPTP between bridge and master (the exchange of [`crate::gptp_net`]). The simulator's ground
//! truth stays readable (every clock at any real time, the segment's trace), so a run can be
//! measured against it; running a variant and measuring it is the lab's (`ecsync-lab`'s `tsn`
//! module).
//!
//! The three variants of the paper ([`Variant`]):
//!
//! * **M1**: the master is wired to the first slave.
//! * **M2**: the bridge sits between master and slaves and forwards EtherCAT frames only in its
//!   window; the master knows the schedule (it is configured offline, as the paper says) but
//!   applies it on its own clock, which is not synchronized to the bridge's.
//! * **M3**: the same, and the master is a gPTP time-aware end station synchronized to the
//!   bridge (the grandmaster) before it brings the segment up, as the paper proposes.
//!
//! # What is modelled, and what is not
//!
//! * The master's NIC launches each frame at a scheduled time of its hardware clock (launch
//!   time) with a small Gaussian jitter, and stamps the first bit of every frame it sends and
//!   receives on an 8 ns grid. In M2 and M3 it places every EtherCAT frame so that it reaches
//!   the bridge's egress in the window's interior, by the schedule it knows, in its own time.
//! * The bridge stores and forwards (egress ready `residence_ns` after the last bit arrived),
//!   forwards an EtherCAT frame only when its gate is open and the frame ends before it closes
//!   (802.1Qbv), and holds it to the next opening otherwise. Best-effort traffic, gPTP
//!   included, goes outside the windows with a guard band. Cross traffic on the master-facing
//!   egress is a Poisson stream of frames of one size, sent one at a time in the best-effort
//!   time; gPTP goes before queued cross traffic but waits for a frame in flight.
//! * A store-and-forward hop adds the frame's wire time, so the master's delay (measured with
//!   short latch frames) differs for the longer cyclic frame ([`TsnNetwork::path_ps`]).
//! * gPTP messages do not contend with EtherCAT frames on the master's wire (a few per second
//!   against a thousand EtherCAT frames; their timestamps are taken at the wire either way).
//! * A gPTP message that does not decode is counted and dropped, as a real stack drops it.

mod bridge;
mod phc;
mod wire;

pub use bridge::{BRIDGE_MAC, BridgeParams};
pub use phc::Phc;

use crate::gptp::{Config as GptpConfig, SystemIdentity, TimeAwareSystem};
use crate::gptp_net::{ExchangeCounts, GptpNetwork};
use crate::qbv::{PortSchedule, Window};
use bridge::{BRIDGE, Bridge, CrossTraffic, GptpWire, MASTER};
use ecsync_dc::time::MasterInstant;
use ecsync_master::transport::{Never, Received, Transport};
use ecsync_sim::clock::{CrystalParams, DEFAULT_WANDER_STEP_PS};
use ecsync_sim::pcap::PcapCapture;
use ecsync_sim::transport::MasterClock;
use ecsync_sim::{Segment, SlaveSpec, TopologyError, frame_wire_time_ps};
use serde::Serialize;
use std::collections::VecDeque;
use std::fs::File;
use std::io::BufWriter;
use wire::{Capture, Noise, stamp, wire_ns};

/// 100BASE-TX: two PHYs per link, ns (the segment's MII hop uses the same figure).
pub const PHY_PAIR_NS: f64 = 300.0;
/// Cable propagation, ns per metre.
pub const CABLE_NS_PER_M: f64 = 5.0;
/// How long the master waits for a frame before calling it lost, ps.
pub const TIMEOUT_PS: u64 = 100_000_000_000;
/// How often gPTP's timers are polled, ps (1 ms: finer than any interval it keeps).
const GPTP_POLL_PS: u64 = 1_000_000_000;

/// The three networks of the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum Variant {
    /// No TSN: the master drives the segment directly.
    M1,
    /// A time-aware bridge between master and slaves; the master is not synchronized to it.
    M2,
    /// The bridge, and the master synchronized to it by gPTP, as the paper proposes.
    M3,
}

impl Variant {
    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Variant::M1 => "M1",
            Variant::M2 => "M2",
            Variant::M3 => "M3",
        }
    }

    /// What it is, in words.
    pub fn title(self) -> &'static str {
        match self {
            Variant::M1 => "no TSN (master wired to the slaves)",
            Variant::M2 => "TSN bridge, master not synchronized (no gPTP)",
            Variant::M3 => "TSN bridge, master synchronized by gPTP (the paper's proposal)",
        }
    }

    /// Whether a bridge sits between master and slaves.
    pub fn has_bridge(self) -> bool {
        self != Variant::M1
    }

    /// The variant of a name, `M1` to `M3` (or in lower case).
    pub fn from_name(s: &str) -> Option<Variant> {
        match s {
            "M1" | "m1" => Some(Variant::M1),
            "M2" | "m2" => Some(Variant::M2),
            "M3" | "m3" => Some(Variant::M3),
            _ => None,
        }
    }
}

/// The master.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MasterParams {
    /// Crystal error, ppm.
    pub ppm: f64,
    /// Crystal wander, ppm per sqrt(s).
    pub wander_ppm_per_sqrt_s: f64,
    /// Master clock minus bridge clock at the start, ns.
    pub clock_offset_ns: i64,
    /// Hardware timestamp granularity, ns.
    pub timestamp_ns: u64,
    /// Standard deviation of the launch instant around the scheduled one, ns.
    pub launch_jitter_ns: f64,
    /// Cable from the master to the bridge, m.
    pub cable_m: f64,
    /// How far into the EtherCAT window (bridge side) the master aims its frames, ns.
    pub launch_margin_ns: u64,
    /// gPTP priority1.
    pub priority1: u8,
}

/// gPTP.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GptpParams {
    /// Sync interval, ns.
    pub sync_interval_ns: u64,
    /// Pdelay_Req interval, ns.
    pub pdelay_interval_ns: u64,
    /// gPTP runs this long before the EtherCAT bring-up starts (M3), ns.
    pub settle_ns: u64,
    /// Servo proportional gain.
    pub kp: f64,
    /// Servo integral gain.
    pub ki: f64,
}

/// What a network is made of (borrowed from the scenario that describes it).
#[derive(Debug, Clone, Copy)]
pub struct NetworkParams<'a> {
    /// The EtherCAT segment.
    pub slaves: &'a [SlaveSpec],
    /// Seed of the crystals' wander, the launch jitter and the cross traffic.
    pub seed: u64,
    /// The master.
    pub master: &'a MasterParams,
    /// The bridge.
    pub bridge: &'a BridgeParams,
    /// gPTP.
    pub gptp: &'a GptpParams,
}

/// Why a network cannot be built or its capture not written.
#[derive(Debug, thiserror::Error)]
pub enum NetworkError {
    /// The segment description is invalid.
    #[error("segment: {0}")]
    Segment(#[from] TopologyError),
    /// The capture could not be written.
    #[error("pcap capture: {0}")]
    Capture(String),
}

/// Frames held at a closed gate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Blocked {
    /// Bring-up frames sent (scan, SII, delay measurement, drift compensation, ...).
    pub bringup_frames: u64,
    /// Of those, held at the gate towards the slaves (the paper's DM_T and its kin).
    pub bringup_forward: u64,
    /// Held at the gate towards the master on the way back (the paper's DM_R).
    pub bringup_return: u64,
    /// Delay measurement (latch) frames held on the way out: the paper's blocked DM_T.
    pub latch_forward: u64,
    /// Latch frames sent.
    pub latch_frames: u64,
    /// Cyclic frames sent (warm-up and recorded).
    pub cyclic_frames: u64,
    /// Of those, held on the way out (the paper's SM).
    pub cyclic_forward: u64,
    /// Held on the way back.
    pub cyclic_return: u64,
    /// Longest hold, ns.
    pub max_wait_ns: f64,
}

impl Blocked {
    /// Every DC frame held, either way.
    pub fn total(&self) -> u64 {
        self.bringup_forward + self.bringup_return + self.cyclic_forward + self.cyclic_return
    }
}

/// gPTP between bridge and master as it stands (M3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GptpFigures {
    /// Mean link delay the master measured, ns (`None`: not yet).
    pub measured_link_delay_ns: Option<f64>,
    /// True one-way delay between the ports (first bit to first bit), ns.
    pub true_link_delay_ns: f64,
    /// Whether the bridge won the BMCA (and the master knows it).
    pub bridge_is_grandmaster: bool,
    /// What the exchange counted: messages sent, received, dropped.
    pub counts: ExchangeCounts,
    /// Messages that waited for cross traffic in flight.
    pub held_by_cross_traffic: u64,
}

/// One frame's trip.
#[derive(Debug, Clone, Copy)]
struct Trip {
    /// Master's send stamp (PHC, hardware).
    t1_ns: u64,
    /// Master's receive stamp; `None`: lost.
    t4_ns: Option<u64>,
    /// Real time the reply was at the master (first bit), ps.
    back_ps: u64,
    /// Hold at the gate towards the slaves, ps.
    wait_fwd_ps: u64,
    /// Hold at the gate towards the master, ps.
    wait_ret_ps: u64,
}

/// The network of one variant: the master's PHC and NIC, in M2 and M3 the bridge (and in M3
/// gPTP), the segment. The master drives it as its [`Transport`]; its ground truth is open.
#[derive(Debug)]
pub struct TsnNetwork<'a> {
    p: NetworkParams<'a>,
    variant: Variant,
    segment: Segment,
    phc: Phc,
    bridge: Bridge<'a>,
    /// The master's view of the EtherCAT windows, shrunk by the launch margin.
    master_view: Option<PortSchedule>,
    /// The same of the return windows (the bridge's master-facing port).
    master_view_back: Option<PortSchedule>,
    /// The longest a frame's first bit took from the bridge through the segment and back,
    /// ps: what the master has measured of the segment (it aims its frames by it).
    segment_round_trip_ps: u64,
    now_ps: u64,
    link_ps: u64,
    noise: Noise,
    gptp: Option<GptpNetwork<u64>>,
    capture: Capture,
    blocked: Blocked,
    in_bringup: bool,
    /// The master's task: the time it woke (the cyclic phase's host is ideal and hands its
    /// frames to a NIC that launches them at their time, so it waits without real time moving).
    wake_ns: Option<u64>,
    /// The first frame of the last cycle: its launch time (master clock) and its hold on the
    /// way out.
    last_launch_ns: u64,
    last_wait_fwd_ps: u64,
    /// Frames in flight (a cycle of several frames), in the order sent, with their replies.
    trips: VecDeque<(Trip, Vec<u8>)>,
    /// A fault schedule played on the segment's frames (the segment's kinds; a second
    /// responder's copy and the master host's faults are not played on this network).
    faults: Option<ecsync_sim::fault::FaultPlayer>,
}

impl<'a> TsnNetwork<'a> {
    /// Plays `faults` on the segment's frames from now on.
    pub fn set_faults(&mut self, faults: ecsync_sim::fault::FaultPlayer) {
        self.faults = Some(faults);
    }

    /// The fault player, if one plays.
    pub fn faults(&self) -> Option<&ecsync_sim::fault::FaultPlayer> {
        self.faults.as_ref()
    }

    /// The network of `variant`, at real time 0.
    pub fn new(p: NetworkParams<'a>, variant: Variant) -> Result<Self, NetworkError> {
        let (m, b, g) = (p.master, p.bridge, p.gptp);
        let segment = Segment::new(p.slaves)?;
        let master_initial = (b.initial_ns as i64 + m.clock_offset_ns) as u64;
        let crystal = MasterClock::new(CrystalParams {
            ppm: m.ppm,
            wander_ppm_per_sqrt_s: m.wander_ppm_per_sqrt_s,
            wander_step_ps: DEFAULT_WANDER_STEP_PS,
            initial_local_ns: master_initial,
            seed: p.seed ^ 0x6d61_7374,
        });
        let bridge_clock = MasterClock::new(CrystalParams {
            ppm: b.ppm,
            wander_ppm_per_sqrt_s: b.wander_ppm_per_sqrt_s,
            wander_step_ps: DEFAULT_WANDER_STEP_PS,
            initial_local_ns: b.initial_ns,
            seed: p.seed ^ 0x6272_6467,
        });
        let phc = Phc::new(crystal, master_initial);
        let margin = m.launch_margin_ns;
        let view = |port: &PortSchedule| {
            let shrunk: Vec<Window> = port
                .windows()
                .iter()
                .map(|w| {
                    if w.close_ns - w.open_ns > 2 * margin + wire_ns(1514) {
                        Window {
                            open_ns: w.open_ns + margin,
                            close_ns: w.close_ns - margin,
                        }
                    } else {
                        *w
                    }
                })
                .collect();
            variant
                .has_bridge()
                .then(|| PortSchedule::new(port.cycle_ns(), b.base_ns, &shrunk, 0).ok())
                .flatten()
        };
        let master_view = view(&b.ethercat_port);
        let master_view_back = view(&b.master_port);
        let link_ps = ((m.cable_m * CABLE_NS_PER_M + PHY_PAIR_NS) * 1000.0).round() as u64;
        let gptp = (variant == Variant::M3).then(|| {
            let identity = |p1: u8, id: u8| {
                SystemIdentity::with_default_quality(
                    p1,
                    [0x00, 0x1b, 0x21, 0xff, 0xfe, 0xec, 0x00, id],
                )
            };
            let cfg = |id: SystemIdentity| GptpConfig {
                sync_interval_ns: g.sync_interval_ns,
                pdelay_interval_ns: g.pdelay_interval_ns,
                kp: g.kp,
                ki: g.ki,
                ..GptpConfig::new(id, 1)
            };
            // Indexed as the wire knows them: the master, then the bridge (polled in that
            // order).
            const { assert!(MASTER == 0 && BRIDGE == 1) };
            let systems = vec![
                TimeAwareSystem::new(cfg(identity(m.priority1, 1))),
                TimeAwareSystem::new(cfg(identity(b.priority1, 2))),
            ];
            GptpNetwork::new(systems, 0, GPTP_POLL_PS)
        });
        let cross = variant
            .has_bridge()
            .then(|| CrossTraffic::of(b, p.seed))
            .flatten();
        Ok(TsnNetwork {
            p,
            variant,
            segment,
            phc,
            bridge: Bridge::new(b, bridge_clock, cross),
            master_view,
            master_view_back,
            segment_round_trip_ps: 0,
            now_ps: 0,
            link_ps,
            noise: Noise::new(p.seed ^ (variant as u64 + 1).wrapping_mul(0x5851_f42d_4c95_7f2d)),
            gptp,
            capture: Capture::default(),
            blocked: Blocked::default(),
            in_bringup: true,
            wake_ns: None,
            last_launch_ns: 0,
            last_wait_fwd_ps: 0,
            trips: VecDeque::new(),
            faults: None,
        })
    }

    /// Which variant.
    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// Captures the frames at the master's port (EtherCAT and gPTP) into `file`, all of them
    /// until [`Self::capture_until`] limits it.
    pub fn capture_to(&mut self, file: PcapCapture<BufWriter<File>>) {
        self.capture.file = Some(file);
        self.capture.until_ps = u64::MAX;
    }

    /// Captures only up to real time `t_ps`.
    pub fn capture_until(&mut self, t_ps: u64) {
        self.capture.until_ps = t_ps;
    }

    /// Ends the capture and flushes its file (nothing without one).
    pub fn finish_capture(&mut self) -> Result<(), NetworkError> {
        let Some(file) = self.capture.file.take() else {
            return Ok(());
        };
        if let Some(e) = self.capture.error.take() {
            return Err(NetworkError::Capture(e));
        }
        file.finish()
            .map(|_| ())
            .map_err(|e| NetworkError::Capture(e.to_string()))
    }

    /// Real time now, ps.
    pub fn now_ps(&self) -> u64 {
        self.now_ps
    }

    /// Moves real time on to `t_ps` (never back), running gPTP on the way.
    pub fn run_to(&mut self, t_ps: u64) {
        if let Some(g) = &mut self.gptp {
            let mut wire = GptpWire {
                phc: &mut self.phc,
                bridge: &mut self.bridge,
                capture: &mut self.capture,
                link_ps: self.link_ps,
                timestamp_ns: self.p.master.timestamp_ns,
            };
            g.run_until(t_ps, &mut wire);
        }
        self.now_ps = self.now_ps.max(t_ps);
    }

    /// The bring-up is over: frames from now on are the cyclic phase's (counted apart), and
    /// the master's task hands each to the NIC for its launch time without real time moving.
    pub fn end_bringup(&mut self) {
        self.in_bringup = false;
    }

    /// The segment, its ground truth.
    pub fn segment(&self) -> &Segment {
        &self.segment
    }

    /// The master's hardware clock at real time `t_ps`, ns.
    pub fn phc_ns_at(&mut self, t_ps: u64) -> u64 {
        self.phc.ns_at(t_ps)
    }

    /// The master's hardware clock at real time `t_ps`: whole ns and fraction.
    pub fn phc_exact_at(&mut self, t_ps: u64) -> (u64, f64) {
        self.phc.exact_at(t_ps)
    }

    /// The bridge's clock (the grandmaster's in M3) at real time `t_ps`, ns.
    pub fn bridge_ns_at(&mut self, t_ps: u64) -> u64 {
        self.bridge.clock.master_ns(t_ps)
    }

    /// The master-bridge link's one-way delay (cable and PHYs), ps.
    pub fn link_ps(&self) -> u64 {
        self.link_ps
    }

    /// True time from the master's first bit of a frame of `len` bytes to its first bit
    /// leaving towards the slaves, with no hold at a gate, ps: the link, the frame's wire time
    /// (store and forward) and the residence; nothing without a bridge.
    pub fn path_ps(&self, len: usize) -> u64 {
        if self.variant.has_bridge() {
            self.link_ps + frame_wire_time_ps(len) + self.bridge.residence_ps
        } else {
            0
        }
    }

    /// Time from the master's launch of a frame of `len` bytes to its being ready at the
    /// bridge's egress, whole ns (what the master allows for when it aims at a window).
    pub fn lead_ns(&self, len: usize) -> u64 {
        if self.variant.has_bridge() {
            self.link_ps / 1000 + wire_ns(len) + self.bridge.residence_ps / 1000
        } else {
            0
        }
    }

    /// The launch time (master clock, ns) of the first frame of the last cycle.
    pub fn last_launch_ns(&self) -> u64 {
        self.last_launch_ns
    }

    /// How long that frame was held at the gate towards the slaves, ps.
    pub fn last_wait_fwd_ps(&self) -> u64 {
        self.last_wait_fwd_ps
    }

    /// Whether gPTP runs (M3).
    pub fn runs_gptp(&self) -> bool {
        self.gptp.is_some()
    }

    /// Frames held at a closed gate so far.
    pub fn blocked(&self) -> Blocked {
        self.blocked
    }

    /// Cross-traffic frames the bridge sent towards the master up to now (M2, M3 with a load).
    pub fn cross_traffic_frames(&mut self) -> Option<u64> {
        let now = self.now_ps;
        self.bridge.cross_traffic_to(now);
        self.bridge.cross.as_ref().map(|c| c.frames)
    }

    /// gPTP as it stands (M3).
    pub fn gptp_figures(&self) -> Option<GptpFigures> {
        let g = self.gptp.as_ref()?;
        let s = g.systems();
        let (master, bridge) = (&s[MASTER], &s[BRIDGE]);
        Some(GptpFigures {
            measured_link_delay_ns: master.mean_link_delay_ns(0),
            true_link_delay_ns: self.link_ps as f64 / 1000.0,
            bridge_is_grandmaster: bridge.is_grandmaster() && !master.is_grandmaster(),
            counts: g.counts(),
            held_by_cross_traffic: self.bridge.held_by_cross_traffic,
        })
    }

    /// When (master clock) a frame the master wants to send at `want_ns` leaves: the first
    /// instant at which, by the schedule on the master's clock, it reaches the bridge's egress
    /// inside a window.
    /// The frame's way back counts too: it must come to the bridge's master-facing port
    /// inside a return window (by the segment's round trip as measured so far), else the
    /// next start that brings it back inside one (a long frame sent late in its window would
    /// wait at the return gate: the bring-up's merged exchanges are such frames).
    fn launch_at(&self, want_ns: u64, len: usize) -> u64 {
        let Some(view) = &self.master_view else {
            return want_ns;
        };
        let (lead, frame_ns) = (self.lead_ns(len), wire_ns(len));
        let Some(first) = view.ethercat_start(want_ns + lead, frame_ns) else {
            return want_ns;
        };
        let back_after_ns =
            (self.segment_round_trip_ps + frame_wire_time_ps(len) + self.bridge.residence_ps)
                .div_ceil(1000);
        let comes_back = |t: u64| {
            self.master_view_back.as_ref().is_none_or(|back| {
                back.ethercat_start(t + back_after_ns, frame_ns) == Some(t + back_after_ns)
            })
        };
        // Later starts a frame's length apart, over two gate cycles at most.
        let mut t = first;
        let step_ns = frame_ns.max(1_000);
        let limit = first + 2 * view.cycle_ns();
        while !comes_back(t) {
            match view.ethercat_start(t + step_ns, frame_ns) {
                Some(next) if next <= limit => t = next,
                _ => return first - lead,
            }
        }
        t - lead
    }

    /// Sends `frame` at master time `launch_ns` and brings it back (in place).
    fn trip(&mut self, frame: &mut [u8], launch_ns: u64) -> Trip {
        let len = frame.len();
        let m = self.p.master;
        let jitter_ps = (self.noise.normal() * m.launch_jitter_ns * 1000.0) as i64;
        let t_tx =
            (self.phc.real_ps_at(launch_ns) as i64 + jitter_ps).max(self.now_ps as i64 + 1) as u64;
        self.run_to(t_tx);
        let t1 = stamp(m.timestamp_ns, self.phc.ns_at(t_tx));
        self.capture.record(t_tx, frame);
        let wire_ps = frame_wire_time_ps(len);
        let residence_ps = self.bridge.residence_ps;
        let (t_seg, wait_fwd_ps) = if self.variant.has_bridge() {
            let ready = t_tx + self.link_ps + wire_ps + residence_ps;
            self.bridge.gate(ready, len, true)
        } else {
            (t_tx, 0)
        };
        let fate = match &mut self.faults {
            Some(f) => f.before_frame(&mut self.segment, frame, t_seg),
            None => ecsync_sim::fault::FrameFate::default(),
        };
        let returned = if fate.lost_out {
            None
        } else {
            let out = self.segment.process(frame, t_seg);
            // The segment's own round trip, without a fault's extra delay (one delayed
            // frame would otherwise move every later frame's aim).
            if let Some(t) = out.returned_sof_ps {
                self.segment_round_trip_ps = self.segment_round_trip_ps.max(t - t_seg);
            }
            out.returned_sof_ps
                .filter(|_| !fate.lost_back)
                .map(|t| t + fate.extra_delay_ps)
        };
        let Some(back_sof) = returned else {
            return Trip {
                t1_ns: t1,
                t4_ns: None,
                back_ps: t_tx + TIMEOUT_PS,
                wait_fwd_ps,
                wait_ret_ps: 0,
            };
        };
        let (back_ps, wait_ret_ps) = if self.variant.has_bridge() {
            let ready = back_sof + wire_ps + residence_ps;
            let (start, w) = self.bridge.gate(ready, len, false);
            (start + self.link_ps, w)
        } else {
            (back_sof, 0)
        };
        self.capture.record(back_ps, frame);
        let t4 = stamp(m.timestamp_ns, self.phc.ns_at(back_ps));
        Trip {
            t1_ns: t1,
            t4_ns: Some(t4),
            back_ps,
            wait_fwd_ps,
            wait_ret_ps,
        }
    }

    fn count(&mut self, trip: &Trip, is_latch: bool) {
        let b = &mut self.blocked;
        let fwd = trip.wait_fwd_ps > 0;
        let ret = trip.wait_ret_ps > 0;
        if self.in_bringup {
            b.bringup_frames += 1;
            b.bringup_forward += u64::from(fwd);
            b.bringup_return += u64::from(ret);
            if is_latch {
                b.latch_frames += 1;
                b.latch_forward += u64::from(fwd);
            }
        } else {
            b.cyclic_frames += 1;
            b.cyclic_forward += u64::from(fwd);
            b.cyclic_return += u64::from(ret);
        }
        b.max_wait_ns = b
            .max_wait_ns
            .max(trip.wait_fwd_ps.max(trip.wait_ret_ps) as f64 / 1000.0);
    }
}

/// Whether a frame is the delay measurement's latch (a BWR to 0x0900).
fn is_latch_frame(frame: &[u8]) -> bool {
    let Ok(f) = ecsync_wire::EcatFrame::new_checked(frame) else {
        return false;
    };
    matches!(
        f.datagrams().next(),
        Some(Ok(d)) if d.command() == Ok(ecsync_wire::Command::Bwr)
            && d.ado() == ecsync_wire::register::DC_RECEIVE_TIME_PORT0
    )
}

/// The TSN network as the master sees it: its PHC, its NIC launching frames at their time
/// (gate-aware in M2 and M3), the bridge and the segment behind it.
impl Transport for TsnNetwork<'_> {
    type Error = Never;

    fn now(&mut self) -> MasterInstant {
        let now = self.phc.ns_at(self.now_ps);
        MasterInstant::from_ns(self.wake_ns.map_or(now, |w| w.max(now)))
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        let t_ns = t.as_ns();
        if self.in_bringup {
            // A procedure's wait: time moves (gPTP runs) to `t_ns`, by a nanosecond at least.
            let t_ps = self.phc.real_ps_at(t_ns).max(self.now_ps + 1000);
            self.run_to(t_ps);
        } else {
            // The cyclic task hands its frame to the NIC for its launch time.
            let now = self.phc.ns_at(self.now_ps);
            self.wake_ns = Some(t_ns.max(now));
        }
    }

    fn send_time(&mut self, len: usize) -> MasterInstant {
        let now = self.now().as_ns();
        MasterInstant::from_ns(self.launch_at(now, len))
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Never> {
        let at_ns = at.as_ns();
        let mut work = vec![0u8; len];
        fill(&mut work);
        let is_latch = is_latch_frame(&work);
        let trip = self.trip(&mut work, at_ns);
        self.count(&trip, is_latch && self.in_bringup);
        self.wake_ns = None;
        if self.trips.is_empty() {
            self.last_launch_ns = at_ns;
            self.last_wait_fwd_ps = trip.wait_fwd_ps;
        }
        self.trips.push_back((trip, work));
        Ok(MasterInstant::from_ns(trip.t1_ns))
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Never> {
        let deadline_ns = deadline.as_ns();
        let Some((trip, work)) = self.trips.pop_front() else {
            return Ok(None);
        };
        self.run_to(trip.back_ps);
        match trip.t4_ns {
            Some(t4) if t4 <= deadline_ns => {
                let n = work.len();
                *buf = work;
                Ok(Some(Received {
                    len: n,
                    received: MasterInstant::from_ns(t4),
                    tx_stamp: Some(MasterInstant::from_ns(trip.t1_ns)),
                    stamped: true,
                    truncated: false,
                    port: 0,
                }))
            }
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parts of the preset `tsn-2020` (the lab's scenario file describes each number).
    fn parts() -> (Vec<SlaveSpec>, MasterParams, BridgeParams, GptpParams) {
        let guard_ns = (8 + 1500 + 12) * 80;
        let window = |close_ns| Window {
            open_ns: 0,
            close_ns,
        };
        let schedule = |close_ns| {
            PortSchedule::new(1_000_000, 0, &[window(close_ns)], guard_ns)
                .expect("a window of 300 us or more in 1 ms is a schedule")
        };
        let master = MasterParams {
            ppm: 25.0,
            wander_ppm_per_sqrt_s: 0.005,
            clock_offset_ns: 77_000_450_000,
            timestamp_ns: 8,
            launch_jitter_ns: 10.0,
            cable_m: 2.0,
            launch_margin_ns: 20_000,
            priority1: 246,
        };
        let bridge = BridgeParams {
            ppm: -15.0,
            wander_ppm_per_sqrt_s: 0.005,
            initial_ns: 1_000_000_000_000,
            residence_ns: 2_000,
            cycle_ns: 1_000_000,
            base_ns: 0,
            ethercat_port: schedule(300_000),
            master_port: schedule(350_000),
            cross_traffic_load: 0.5,
            cross_traffic_frame_bytes: 1500,
            priority1: 100,
        };
        let gptp = GptpParams {
            sync_interval_ns: 125_000_000,
            pdelay_interval_ns: 1_000_000_000,
            settle_ns: 10_000_000_000,
            kp: 0.7,
            ki: 0.3,
        };
        (ecsync_sim::preset::paper_2024(), master, bridge, gptp)
    }

    fn params<'a>(
        slaves: &'a [SlaveSpec],
        master: &'a MasterParams,
        bridge: &'a BridgeParams,
        gptp: &'a GptpParams,
    ) -> NetworkParams<'a> {
        NetworkParams {
            slaves,
            seed: 2020,
            master,
            bridge,
            gptp,
        }
    }

    /// In M3 the master's PHC follows the bridge by gPTP within 5 s, through cross traffic:
    /// the bridge is the grandmaster, the link delay is measured within a timestamp's grain,
    /// every message decodes.
    #[test]
    fn gptp_synchronizes_the_master_to_the_bridge() {
        let (slaves, m, b, g) = parts();
        let mut net = TsnNetwork::new(params(&slaves, &m, &b, &g), Variant::M3)
            .expect("the paper's segment builds");
        let t_ps = 5_000_000_000_000;
        net.run_to(t_ps);
        let f = net.gptp_figures().expect("M3 runs gPTP");
        assert!(f.bridge_is_grandmaster, "{f:?}");
        let measured = f.measured_link_delay_ns.expect("measured");
        assert!((measured - f.true_link_delay_ns).abs() < 8.0, "{f:?}");
        assert_eq!(f.counts.undecodable + f.counts.unencodable, 0, "{f:?}");
        assert!(f.counts.sent > 100 && f.counts.received > 100, "{f:?}");
        let (w, frac) = net.phc_exact_at(t_ps);
        let offset_ns = (w.wrapping_sub(net.bridge_ns_at(t_ps)) as i64) as f64 + frac;
        assert!(offset_ns.abs() < 50.0, "master - bridge {offset_ns} ns");
        assert!(net.cross_traffic_frames().is_some_and(|n| n > 1_000));
    }

    /// M1 has neither bridge nor gPTP: no path, no lead, no cross traffic; M2 has the bridge
    /// without gPTP.
    #[test]
    fn the_variants_have_their_parts() {
        let (slaves, m, b, g) = parts();
        let p = params(&slaves, &m, &b, &g);
        let mut m1 = TsnNetwork::new(p, Variant::M1).expect("builds");
        assert_eq!((m1.path_ps(60), m1.lead_ns(60)), (0, 0));
        assert!(!m1.runs_gptp() && m1.gptp_figures().is_none());
        assert_eq!(m1.cross_traffic_frames(), None);
        let m2 = TsnNetwork::new(p, Variant::M2).expect("builds");
        assert!(!m2.runs_gptp());
        // Cable and PHYs, the frame's wire time (store and forward), the residence.
        assert_eq!(
            m2.path_ps(60),
            m2.link_ps() + frame_wire_time_ps(60) + 2_000_000
        );
    }

    /// A segment without slaves is a typed error, not a panic.
    #[test]
    fn an_empty_segment_is_an_error() {
        let (_, m, b, g) = parts();
        let e = TsnNetwork::new(params(&[], &m, &b, &g), Variant::M1).unwrap_err();
        assert!(
            matches!(e, NetworkError::Segment(TopologyError::Empty)),
            "{e}"
        );
    }
}
