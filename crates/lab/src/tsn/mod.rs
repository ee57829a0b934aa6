//! The TSN paper's integrated network built from real parts and measured against ground truth:
//! an EtherCAT master whose clock is the DC reference, a time-aware bridge (802.1Qbv gates on
//! its own clock, store and forward), the virtual segment, and gPTP between bridge and master.
//!
//! The three variants of the paper:
//!
//! * **M1**: the master is wired to the first slave.
//! * **M2**: the bridge sits between master and slaves and forwards EtherCAT frames only in its
//!   window; the master knows the schedule (it is configured offline, as the paper says) but
//!   applies it on its own clock, which is not synchronized to the bridge's.
//! * **M3**: the same, and the master is a gPTP time-aware end station synchronized to the
//!   bridge (the grandmaster) before it brings the segment up, as the paper proposes.
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
//!   short latch frames) differs for the longer cyclic frame; the master, knowing it talks
//!   through one store-and-forward hop, adds the difference in wire time to its bus shift
//!   write.
//! * gPTP messages do not contend with EtherCAT frames on the master's wire (a few per second
//!   against a thousand EtherCAT frames; their timestamps are taken at the wire either way).

pub mod report;
pub mod scenario;

use crate::run::{Envelope, Series};
use crate::stats::{Stats, Summary};
use ecsync_dc::BusShift;
use ecsync_esc::clock::{CrystalParams, DEFAULT_WANDER_STEP_PS};
use ecsync_esc::pcap::PcapCapture;
use ecsync_esc::{Segment, frame_wire_time_ps};
use ecsync_master::bringup::{BringupConfig, EsiTiming, Network, Stage, bringup};
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::driver::{
    CycleReport, CyclicDriver, CyclicLimits, ExchangeStats, ProcedureConfig, run_procedure,
};
use ecsync_master::io::MASTER_MAC;
use ecsync_master::sim::MasterClock;
use ecsync_master::transport::{Never, Received, Transport};
use ecsync_master::{Engine, MasterError};
use ecsync_tsn::gptp::{Config as GptpConfig, Outgoing, SystemIdentity, TimeAwareSystem};
use ecsync_tsn::gptp_msg::{self, ClockQuality, Message};
use ecsync_tsn::qbv::{PortSchedule, Window};
pub use scenario::{TsnScenario, Variant};
use serde::Serialize;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// 100BASE-TX: two PHYs per link, ns (the segment's MII hop uses the same figure).
const PHY_PAIR_NS: f64 = 300.0;
/// Cable propagation, ns per metre.
const CABLE_NS_PER_M: f64 = 5.0;
/// How long the master waits for a frame before calling it lost, ps.
const TIMEOUT_PS: u64 = 100_000_000_000;

/// SplitMix64 (the host noise's stream): the seeded noise of launch jitter and cross traffic.
#[derive(Debug, Clone)]
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> u64 {
        let mut rng = crate::host::CycleRng(self.0);
        let v = rng.next();
        self.0 = rng.0;
        v
    }
    /// Uniform in (0, 1].
    fn unit(&mut self) -> f64 {
        crate::host::unit(self.next())
    }
    /// Standard normal (Box-Muller).
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.unit(), self.unit());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The master's hardware clock: a crystal, and in M3 a rate and phase the gPTP servo sets
/// (`value = anchor_value + (crystal - anchor_crystal) * (1 + freq)`).
#[derive(Debug, Clone)]
struct Phc {
    xtal: MasterClock,
    anchor_xtal: u64,
    anchor_value: u64,
    anchor_frac: f64,
    freq: f64,
}

impl Phc {
    fn new(xtal: MasterClock) -> Self {
        Phc {
            xtal,
            anchor_xtal: 0,
            anchor_value: 0,
            anchor_frac: 0.0,
            freq: 0.0,
        }
    }

    /// The clock's reading when the crystal reads `x`, whole ns and fraction.
    fn at_xtal(&self, x: u64) -> (u64, f64) {
        let d = (x.wrapping_sub(self.anchor_xtal) as i64) as f64;
        let v = d * (1.0 + self.freq) + self.anchor_frac;
        let w = v.floor();
        (self.anchor_value.wrapping_add(w as i64 as u64), v - w)
    }

    /// Reading at real time `t_ps`, ns.
    fn ns_at(&mut self, t_ps: u64) -> u64 {
        let x = self.xtal.master_ns(t_ps);
        self.at_xtal(x).0
    }

    /// Real time at which the clock reads `ns`, ps.
    fn real_ps_at(&mut self, ns: u64) -> u64 {
        let d = (ns.wrapping_sub(self.anchor_value) as i64) as f64 - self.anchor_frac;
        let x = (d / (1.0 + self.freq)).round();
        self.xtal
            .real_ps_at(self.anchor_xtal.wrapping_add(x as i64 as u64))
    }

    /// From now on reads `value_ns + value_frac` when the crystal reads `at_xtal`, at rate
    /// `1 + freq`.
    fn set(&mut self, at_xtal: u64, value_ns: u64, value_frac: f64, freq: f64) {
        self.anchor_xtal = at_xtal;
        self.anchor_value = value_ns;
        self.anchor_frac = value_frac;
        self.freq = freq;
    }
}

/// A gPTP message in flight.
#[derive(Debug, Clone)]
struct Delivery {
    t_ps: u64,
    to_master: bool,
    bytes: Vec<u8>,
}

/// Best-effort cross traffic on the bridge's master-facing egress (a camera streaming to the
/// PC): frames of one size arriving as a Poisson stream, queued, and sent one at a time outside
/// the EtherCAT windows with the guard band. Generated lazily, as far as the simulation needs.
#[derive(Debug)]
struct CrossTraffic {
    noise: Noise,
    frame_ps: u64,
    mean_gap_ps: f64,
    next_arrival_ps: u64,
    backlog: u64,
    busy_until_ps: u64,
    frames: u64,
}

/// gPTP between the bridge (grandmaster by priority) and the master (M3).
#[derive(Debug)]
struct Gptp {
    master: TimeAwareSystem,
    bridge: TimeAwareSystem,
    queue: Vec<Delivery>,
    next_poll_ps: u64,
    out: Vec<Outgoing>,
    more: Vec<Outgoing>,
    disciplined: bool,
    /// The bridge's master-facing egress is busy with a gPTP message until then (real ps).
    bridge_tx_free_ps: u64,
    messages: u64,
    held_by_cross_traffic: u64,
}

/// Why a variant could not run.
#[derive(Debug, thiserror::Error)]
pub enum TsnError {
    /// The bring-up failed.
    #[error("{variant}: bring-up failed: {source}")]
    Bringup {
        /// Variant.
        variant: &'static str,
        /// Why.
        source: MasterError,
    },
    /// The segment description is invalid.
    #[error("segment: {0}")]
    Segment(String),
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

/// The network of one variant.
struct Net<'a> {
    s: &'a TsnScenario,
    variant: Variant,
    segment: Segment,
    phc: Phc,
    bridge: MasterClock,
    /// The master's view of the EtherCAT windows, shrunk by the launch margin.
    master_view: Option<PortSchedule>,
    now_ps: u64,
    link_ps: u64,
    residence_ps: u64,
    noise: Noise,
    gptp: Option<Gptp>,
    cross: Option<CrossTraffic>,
    capture: Option<PcapCapture<BufWriter<File>>>,
    capture_until_ps: u64,
    blocked: Blocked,
    in_bringup: bool,
    /// The master's task: the time it woke (the cyclic phase's host is ideal and hands its
    /// frames to a NIC that launches them at their time, so it waits without real time moving).
    wake_ns: Option<u64>,
    /// The last frame's launch time (master clock) and trip, and the frame as it came back.
    last_launch_ns: u64,
    last_wait_fwd_ps: u64,
    /// Frames in flight (a cycle of several frames), in the order sent, with their replies.
    trips: std::collections::VecDeque<(Trip, Vec<u8>)>,
}

/// A hardware timestamp: the clock's reading on the timestamper's grid of `g` ns.
fn stamp(g: u64, ns: u64) -> u64 {
    let g = g.max(1);
    ns / g * g
}

fn wire_ns(len: usize) -> u64 {
    frame_wire_time_ps(len) / 1000
}

impl<'a> Net<'a> {
    fn new(s: &'a TsnScenario, variant: Variant) -> Result<Self, TsnError> {
        let segment = Segment::new(&s.slaves).map_err(|e| TsnError::Segment(e.to_string()))?;
        let master_initial = (s.bridge.initial_ns as i64 + s.master.clock_offset_ns) as u64;
        let xtal = MasterClock::new(CrystalParams {
            ppm: s.master.ppm,
            wander_ppm_per_sqrt_s: s.master.wander_ppm_per_sqrt_s,
            wander_step_ps: DEFAULT_WANDER_STEP_PS,
            initial_local_ns: master_initial,
            seed: s.seed ^ 0x6d61_7374,
        });
        let bridge = MasterClock::new(CrystalParams {
            ppm: s.bridge.ppm,
            wander_ppm_per_sqrt_s: s.bridge.wander_ppm_per_sqrt_s,
            wander_step_ps: DEFAULT_WANDER_STEP_PS,
            initial_local_ns: s.bridge.initial_ns,
            seed: s.seed ^ 0x6272_6467,
        });
        let mut phc = Phc::new(xtal);
        phc.set(master_initial, master_initial, 0.0, 0.0);
        let margin = s.master.launch_margin_ns;
        let ep = &s.bridge.ethercat_port;
        let shrunk: Vec<Window> = ep
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
        let master_view = variant
            .has_bridge()
            .then(|| PortSchedule::new(ep.cycle_ns(), s.bridge.base_ns, &shrunk, 0).ok())
            .flatten();
        let link_ps = ((s.master.cable_m * CABLE_NS_PER_M + PHY_PAIR_NS) * 1000.0).round() as u64;
        let gptp = (variant == Variant::M3).then(|| {
            let identity = |p1: u8, id: u8| SystemIdentity {
                priority1: p1,
                quality: ClockQuality {
                    clock_class: 248,
                    clock_accuracy: 0xfe,
                    offset_scaled_log_variance: 0x4e5d,
                },
                priority2: 248,
                clock_identity: [0x00, 0x1b, 0x21, 0xff, 0xfe, 0xec, 0x00, id],
            };
            let cfg = |id: SystemIdentity| GptpConfig {
                sync_interval_ns: s.gptp.sync_interval_ns,
                pdelay_interval_ns: s.gptp.pdelay_interval_ns,
                kp: s.gptp.kp,
                ki: s.gptp.ki,
                ..GptpConfig::new(id, 1)
            };
            Gptp {
                master: TimeAwareSystem::new(cfg(identity(s.master.priority1, 1))),
                bridge: TimeAwareSystem::new(cfg(identity(s.bridge.priority1, 2))),
                queue: Vec::new(),
                next_poll_ps: 0,
                out: Vec::new(),
                more: Vec::new(),
                disciplined: false,
                bridge_tx_free_ps: 0,
                messages: 0,
                held_by_cross_traffic: 0,
            }
        });
        let be_frame_ps =
            frame_wire_time_ps(s.bridge.cross_traffic_frame_bytes.saturating_sub(4) as usize);
        let busy_share = s.bridge.cross_traffic_load * (1.0 - s.bridge.master_port.open_fraction());
        let cross = (variant.has_bridge() && busy_share > 0.0).then(|| {
            let mut noise = Noise(s.seed ^ 0x6372_6f73_7374_7266);
            let mean_gap_ps = be_frame_ps as f64 / busy_share;
            let first = (-noise.unit().ln() * mean_gap_ps) as u64;
            CrossTraffic {
                noise,
                frame_ps: be_frame_ps,
                mean_gap_ps,
                next_arrival_ps: first,
                backlog: 0,
                busy_until_ps: 0,
                frames: 0,
            }
        });
        Ok(Net {
            s,
            variant,
            segment,
            phc,
            bridge,
            master_view,
            now_ps: 0,
            link_ps,
            residence_ps: s.bridge.residence_ns * 1000,
            noise: Noise(s.seed ^ (variant as u64 + 1).wrapping_mul(0x5851_f42d_4c95_7f2d)),
            gptp,
            cross,
            capture: None,
            capture_until_ps: 0,
            blocked: Blocked::default(),
            in_bringup: true,
            wake_ns: None,
            last_launch_ns: 0,
            last_wait_fwd_ps: 0,
            trips: std::collections::VecDeque::new(),
        })
    }

    fn record(&mut self, t_ps: u64, frame: &[u8]) {
        if t_ps > self.capture_until_ps {
            return;
        }
        if let Some(c) = &mut self.capture {
            let _ = c.record(t_ps, frame);
        }
    }

    /// Moves time on to `t_ps`, running gPTP on the way.
    fn advance(&mut self, t_ps: u64) {
        if self.gptp.is_some() {
            self.run_gptp(t_ps);
        }
        self.now_ps = self.now_ps.max(t_ps);
    }

    /// Time from the master's launch to the frame being ready at the bridge's egress, ns.
    fn lead_ns(&self, len: usize) -> u64 {
        if self.variant.has_bridge() {
            self.link_ps / 1000 + wire_ns(len) + self.residence_ps / 1000
        } else {
            0
        }
    }

    /// When (master clock) a frame the master wants to send at `want_ns` leaves: the first
    /// instant at which, by the schedule on the master's clock, it reaches the bridge's egress
    /// inside a window.
    fn launch_at(&self, want_ns: u64, len: usize) -> u64 {
        let Some(view) = &self.master_view else {
            return want_ns;
        };
        let lead = self.lead_ns(len);
        view.ethercat_start(want_ns + lead, wire_ns(len))
            .map_or(want_ns, |t| t - lead)
    }

    /// Sends `frame` at master time `launch_ns` and brings it back (in place).
    fn trip(&mut self, frame: &mut [u8], launch_ns: u64) -> Trip {
        let len = frame.len();
        let jitter_ps = (self.noise.normal() * self.s.master.launch_jitter_ns * 1000.0) as i64;
        let t_tx =
            (self.phc.real_ps_at(launch_ns) as i64 + jitter_ps).max(self.now_ps as i64 + 1) as u64;
        self.advance(t_tx);
        let t1 = stamp(self.s.master.timestamp_ns, self.phc.ns_at(t_tx));
        self.record(t_tx, frame);
        let wire_ps = frame_wire_time_ps(len);
        let (t_seg, wait_fwd_ps) = if self.variant.has_bridge() {
            let ready = t_tx + self.link_ps + wire_ps + self.residence_ps;
            self.gate(ready, len, true)
        } else {
            (t_tx, 0)
        };
        let out = self.segment.process(frame, t_seg);
        let Some(back_sof) = out.returned_sof_ps else {
            return Trip {
                t1_ns: t1,
                t4_ns: None,
                back_ps: t_tx + TIMEOUT_PS,
                wait_fwd_ps,
                wait_ret_ps: 0,
            };
        };
        let (back_ps, wait_ret_ps) = if self.variant.has_bridge() {
            let ready = back_sof + wire_ps + self.residence_ps;
            let (start, w) = self.gate(ready, len, false);
            (start + self.link_ps, w)
        } else {
            (back_sof, 0)
        };
        self.record(back_ps, frame);
        let t4 = stamp(self.s.master.timestamp_ns, self.phc.ns_at(back_ps));
        Trip {
            t1_ns: t1,
            t4_ns: Some(t4),
            back_ps,
            wait_fwd_ps,
            wait_ret_ps,
        }
    }

    /// The bridge's egress gate: a frame ready at real time `ready_ps` starts when (real time),
    /// after waiting how long.
    fn gate(&mut self, ready_ps: u64, len: usize, towards_slaves: bool) -> (u64, u64) {
        let sched = if towards_slaves {
            &self.s.bridge.ethercat_port
        } else {
            &self.s.bridge.master_port
        };
        let local = self.bridge.master_ns(ready_ps);
        match sched.ethercat_start(local, wire_ns(len)) {
            Some(start) if start > local => {
                let t = self.bridge.real_ps_at(start).max(ready_ps);
                (t, t - ready_ps)
            }
            _ => (ready_ps, 0),
        }
    }

    /// Runs gPTP up to real time `until_ps`.
    fn run_gptp(&mut self, until_ps: u64) {
        const POLL_PS: u64 = 1_000_000_000;
        loop {
            let Some(g) = &self.gptp else { return };
            let next_delivery = g.queue.iter().map(|d| d.t_ps).min();
            let next_poll = g.next_poll_ps;
            let t = next_delivery.map_or(next_poll, |d| d.min(next_poll));
            if t > until_ps {
                return;
            }
            if next_delivery == Some(t) {
                let g = self.gptp.as_mut().expect("gptp");
                let i = g.queue.iter().position(|d| d.t_ps == t).expect("delivery");
                let d = g.queue.swap_remove(i);
                self.deliver(d);
            } else {
                let g = self.gptp.as_mut().expect("gptp");
                g.next_poll_ps += POLL_PS;
                let mut out = std::mem::take(&mut g.out);
                let xm = self.phc.xtal.master_ns(t);
                let xm = stamp(self.s.master.timestamp_ns, xm);
                let g = self.gptp.as_mut().expect("gptp");
                g.master.poll(xm, &mut out);
                self.send(t, true, &mut out);
                let xb = stamp(self.s.master.timestamp_ns, self.bridge.master_ns(t));
                let g = self.gptp.as_mut().expect("gptp");
                g.bridge.poll(xb, &mut out);
                self.send(t, false, &mut out);
                self.gptp.as_mut().expect("gptp").out = out;
            }
        }
    }

    fn deliver(&mut self, d: Delivery) {
        let Ok((h, m)) = gptp_msg::decode(&d.bytes) else {
            return;
        };
        let mut out = std::mem::take(&mut self.gptp.as_mut().expect("gptp").out);
        if d.to_master {
            let rx = stamp(self.s.master.timestamp_ns, self.phc.xtal.master_ns(d.t_ps));
            let g = self.gptp.as_mut().expect("gptp");
            g.master.on_message(0, &h, &m, rx, &mut out);
            if matches!(m, Message::FollowUp { .. }) {
                self.discipline();
            }
            self.send(d.t_ps, true, &mut out);
        } else {
            let rx = stamp(self.s.master.timestamp_ns, self.bridge.master_ns(d.t_ps));
            let g = self.gptp.as_mut().expect("gptp");
            g.bridge.on_message(0, &h, &m, rx, &mut out);
            self.send(d.t_ps, false, &mut out);
        }
        self.gptp.as_mut().expect("gptp").out = out;
    }

    /// Applies the servo's decision to the master's clock.
    fn discipline(&mut self) {
        let g = self.gptp.as_mut().expect("gptp");
        let Some(rx) = g.master.last_sync_rx_ns() else {
            return;
        };
        let (w, f) = self.phc.at_xtal(rx);
        if let Some(adj) = g.master.servo(w, f) {
            g.disciplined = true;
            // The step is whole and fractional nanoseconds on top of an integer reading.
            let step = f + adj.step_ns;
            let whole = step.floor();
            self.phc.set(
                rx,
                w.wrapping_add(whole as i64 as u64),
                step - whole,
                adj.frequency,
            );
        }
    }

    /// Sends the cross-traffic frames that start before real time `t_ps`.
    fn cross_traffic_to(&mut self, t_ps: u64) {
        let Net {
            cross, bridge, s, ..
        } = self;
        let Some(ct) = cross else { return };
        let sched = &s.bridge.master_port;
        loop {
            let want = if ct.backlog > 0 {
                ct.busy_until_ps
            } else {
                ct.next_arrival_ps.max(ct.busy_until_ps)
            };
            if want >= t_ps {
                return;
            }
            let local = bridge.master_ns(want);
            let s_local = sched.best_effort_start(local, ct.frame_ps / 1000);
            let start = if s_local == local {
                want
            } else {
                bridge.real_ps_at(s_local).max(want)
            };
            if start >= t_ps {
                return;
            }
            while ct.next_arrival_ps <= start {
                ct.backlog += 1;
                ct.next_arrival_ps += (-ct.noise.unit().ln() * ct.mean_gap_ps) as u64 + 1;
            }
            ct.backlog = ct.backlog.saturating_sub(1);
            ct.busy_until_ps = start + ct.frame_ps;
            ct.frames += 1;
        }
    }

    /// Sends gPTP messages from the master (`from_master`) or the bridge at real time `t_ps`.
    fn send(&mut self, t_ps: u64, from_master: bool, out: &mut Vec<Outgoing>) {
        let mut buf = [0u8; 128];
        let mut t_cur = t_ps;
        let mut more = std::mem::take(&mut self.gptp.as_mut().expect("gptp").more);
        while !out.is_empty() {
            for o in out.drain(..) {
                let Ok(len) = o.message.encode(&o.header, &mut buf) else {
                    continue;
                };
                let mut eth = Vec::with_capacity(len + 14);
                let mac = if from_master {
                    MASTER_MAC
                } else {
                    [0x00, 0x1b, 0x21, 0xec, 0x00, 0x02]
                };
                gptp_msg::ethernet_frame(mac, &buf[..len], &mut eth);
                let wire = frame_wire_time_ps(eth.len());
                let (start, tx_local) = if from_master {
                    (t_cur, self.phc.xtal.master_ns(t_cur))
                } else {
                    // Best effort on the master-facing port: outside the EtherCAT window, after
                    // any cross-traffic frame in flight.
                    let free = self.gptp.as_ref().map_or(0, |g| g.bridge_tx_free_ps);
                    let mut ready_ps = t_cur.max(free);
                    self.cross_traffic_to(ready_ps);
                    if let Some(ct) = &self.cross {
                        if ct.busy_until_ps > ready_ps {
                            ready_ps = ct.busy_until_ps;
                            self.gptp.as_mut().expect("gptp").held_by_cross_traffic += 1;
                        }
                    }
                    let sched = &self.s.bridge.master_port;
                    let ready = self.bridge.master_ns(ready_ps);
                    let start = sched.best_effort_start(ready, wire / 1000);
                    let start_ps = if start == ready {
                        ready_ps
                    } else {
                        self.bridge.real_ps_at(start).max(ready_ps)
                    };
                    // The message holds the wire: cross traffic waits for its end.
                    if let Some(ct) = &mut self.cross {
                        ct.busy_until_ps = ct.busy_until_ps.max(start_ps + wire);
                    }
                    (start_ps, start)
                };
                let tx = stamp(self.s.master.timestamp_ns, tx_local);
                let g = self.gptp.as_mut().expect("gptp");
                g.messages += 1;
                if !from_master {
                    g.bridge_tx_free_ps = start + wire;
                }
                if from_master {
                    g.master
                        .on_tx_timestamp(o.port, &o.header, &o.message, tx, &mut more);
                } else {
                    g.bridge
                        .on_tx_timestamp(o.port, &o.header, &o.message, tx, &mut more);
                }
                g.queue.push(Delivery {
                    t_ps: start + self.link_ps,
                    to_master: !from_master,
                    bytes: buf[..len].to_vec(),
                });
                // The capture is at the master's port: its sends, and what arrives there.
                let at_master = if from_master {
                    start
                } else {
                    start + self.link_ps
                };
                self.record(at_master, &eth);
                t_cur = start + wire;
            }
            std::mem::swap(out, &mut more);
        }
        self.gptp.as_mut().expect("gptp").more = more;
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
    // Ethernet (14) + EtherCAT header (2) + datagram: command, index, ADP, ADO.
    frame.len() >= 22
        && frame[16] == ecsync_wire::Command::Bwr as u8
        && u16::from_le_bytes([frame[20], frame[21]])
            == ecsync_wire::register::DC_RECEIVE_TIME_PORT0
}

/// The TSN network as the master sees it: its PHC, its NIC launching frames at their time
/// (gate-aware in M2 and M3), the bridge and the segment behind it.
impl Transport for Net<'_> {
    type Error = Never;

    fn now_ns(&mut self) -> u64 {
        let now = self.phc.ns_at(self.now_ps);
        self.wake_ns.map_or(now, |w| w.max(now))
    }

    fn sleep_until(&mut self, t_ns: u64) {
        if self.in_bringup {
            // A procedure's wait: time moves (gPTP runs) to `t_ns`, by a nanosecond at least.
            let t_ps = self.phc.real_ps_at(t_ns).max(self.now_ps + 1000);
            self.advance(t_ps);
        } else {
            // The cyclic task hands its frame to the NIC for its launch time.
            let now = self.phc.ns_at(self.now_ps);
            self.wake_ns = Some(t_ns.max(now));
        }
    }

    fn send_time_ns(&mut self, len: usize) -> u64 {
        let now = self.now_ns();
        self.launch_at(now, len)
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at_ns: u64,
        fill: F,
    ) -> Result<u64, Never> {
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
        Ok(trip.t1_ns)
    }

    fn recv(&mut self, buf: &mut Vec<u8>, deadline_ns: u64) -> Result<Option<Received>, Never> {
        let Some((trip, work)) = self.trips.pop_front() else {
            return Ok(None);
        };
        self.advance(trip.back_ps);
        match trip.t4_ns {
            Some(t4) if t4 <= deadline_ns => {
                let n = work.len();
                *buf = work;
                Ok(Some(Received {
                    len: n,
                    received_ns: t4,
                    tx_stamp_ns: Some(trip.t1_ns),
                    stamped: true,
                    truncated: false,
                }))
            }
            _ => Ok(None),
        }
    }
}

/// Options of a TSN run.
#[derive(Debug, Clone, Default)]
pub struct TsnOptions {
    /// Capture each variant's frames at the master's port into `<dir>/<variant>.pcap`.
    pub pcap_dir: Option<std::path::PathBuf>,
    /// Capture only this many seconds of cyclic operation (the bring-up is always captured).
    pub pcap_cycles: u64,
}

/// Runs one variant of the scenario.
pub fn run_variant(
    s: &TsnScenario,
    variant: Variant,
    opts: &TsnOptions,
) -> Result<VariantResult, TsnError> {
    let t0 = std::time::Instant::now();
    let mut net = Net::new(s, variant)?;
    if let Some(dir) = &opts.pcap_dir {
        let path = dir.join(format!("{}.pcap", variant.name()));
        let c = PcapCapture::create(&path).map_err(|e| TsnError::Pcap {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        net.capture = Some(c);
        net.capture_until_ps = u64::MAX;
    }
    // M3: gPTP first (the paper: the master is synchronized to the TSN network before the DC
    // delay measurement).
    if variant == Variant::M3 {
        net.advance(s.gptp.settle_ns * 1000);
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
    let procedure = ProcedureConfig {
        reply_timeout_ns: TIMEOUT_PS / 1000,
        retries: 0,
    };
    let bring = run_procedure(
        &mut net,
        &mut engine,
        procedure,
        &mut ExchangeStats::default(),
        |_, _, _| {},
    );
    let net_info: Network = match bring {
        Ok(r) => r,
        Err(never) => match never {},
    }
    .map_err(|source| TsnError::Bringup {
        variant: variant.name(),
        source,
    })?;
    net.in_bringup = false;

    // Delays: measured (master delay + delay from the reference) against the truth for a
    // latch frame (60 bytes on the wire) with no hold.
    let reference = usize::from(net_info.reference);
    let pu = net.segment.pu_offsets_ps();
    let path_ps = |len: usize| {
        if variant.has_bridge() {
            net.link_ps + frame_wire_time_ps(len) + net.residence_ps
        } else {
            0
        }
    };
    let latch_path = path_ps(60);
    let mut delays = Vec::new();
    let mut max_err = 0.0f64;
    if let Some(md) = net_info.master_delay_ns {
        for (i, sl) in net_info.slaves.iter().enumerate() {
            let (Some(d), Some(p)) = (sl.delay_ns, pu[i]) else {
                continue;
            };
            let measured = md + d;
            let truth = (latch_path + p) as f64 / 1000.0;
            max_err = max_err.max((measured - truth).abs());
            delays.push(SlaveDelay {
                position: sl.position,
                measured_ns: measured,
                true_ns: truth,
                error_ns: measured - truth,
            });
        }
    }

    // The cyclic phase: bus shift with the master's time at the reference.
    let cyc_cfg = CyclicConfig {
        period_ns: s.cycle_ns,
        reference_station: net_info.slaves[reference].station,
        pdi_len: net_info.pdi_len,
        measure_init_frames: 1,
        reference_offset_ns: net_info.slaves[reference].offset.unwrap_or(0),
        lrw: net_info.lrw.clone(),
    };
    let probe = CyclicEngine::new(BusShift { write_offset_ns: 0 }, cyc_cfg.clone(), 0)
        .map_err(TsnError::Frame)?;
    let cyc_len = {
        let mut p = probe;
        p.frame_to_send(0).len()
    };
    // One store-and-forward hop: the cyclic frame's first bit reaches the slaves later than a
    // latch frame's by the difference of their wire times.
    let sf_extra_ns = if variant.has_bridge() {
        (path_ps(cyc_len) as i64 - latch_path as i64) / 1000
    } else {
        0
    };
    let write_offset_ns = net_info.master_delay_ns.map_or(0, |d| d.round() as i64) + sf_extra_ns;
    let period = u64::from(s.cycle_ns);
    let lead = net.lead_ns(cyc_len);
    let open = s.bridge.ethercat_port.windows()[0].open_ns + s.master.launch_margin_ns;
    let now = net.phc.ns_at(net.now_ps);
    let base = if variant.has_bridge() {
        s.bridge.base_ns % period
    } else {
        0
    };
    let first = (now / period + 3) * period + base + open - lead;
    let mut eng =
        CyclicEngine::new(BusShift { write_offset_ns }, cyc_cfg, first).map_err(TsnError::Frame)?;

    let mut m_rs = Stats::new();
    let mut rs_is = Stats::new();
    let mut mref = Stats::new();
    let mut spread = Stats::new();
    let mut margin = Stats::new();
    let mut wait = Stats::new();
    let mut gptp_off = Stats::new();
    let cap = (s.cycles / crate::run::SERIES_BLOCK + 2) as usize;
    let mut series = [
        Series::new(cap),
        Series::new(cap),
        Series::new(cap),
        Series::new(cap),
    ];
    let (mut late, mut overruns, mut lost) = (0u64, 0u64, 0u64);
    let shift = u64::from(s.sync0_shift_ns);
    let last = net.segment.len() - 1;
    let total = s.warmup_cycles + s.cycles;
    net.capture_until_ps = if opts.pcap_dir.is_some() {
        net.now_ps + opts.pcap_cycles * period * 1000
    } else {
        0
    };
    // One frame per cycle; a reply may take up to a cycle (held at the gates).
    let mut driver = CyclicDriver::new(CyclicLimits {
        max_cycles: Some(total),
        lost_in_a_row: u64::MAX,
        reply_timeout_ns: period,
        ..CyclicLimits::default()
    });
    let observe = |net: &mut Net<'_>, rep: &CycleReport| {
        let rec = &rep.record;
        overruns += rep.skipped_before;
        let i = rec.cycle;
        if i < s.warmup_cycles {
            return;
        }
        let k = i - s.warmup_cycles;
        if rec.receive_ns.is_none() {
            lost += 1;
            return;
        }
        let launch = net.last_launch_ns;
        let wait_fwd_ps = net.last_wait_fwd_ps;
        if wait_fwd_ps > 0 {
            wait.add(wait_fwd_ps as f64 / 1000.0);
        }
        series[3].add(k, wait_fwd_ps as f64 / 1000.0);
        if let Some(m) = rec.m_rs_ns {
            m_rs.add(m as f64);
        }
        if let Some(v) = rec.rs_is_ns {
            rs_is.add(f64::from(v));
        }
        // Ground truth at the frame's pass at the reference.
        let trace = net.segment.trace();
        let (Some(pu_ref), Some(pu_last)) = (trace.pu_ps(reference), trace.pu_ps(last)) else {
            return;
        };
        let seg = &net.segment;
        let sys = |x: usize, t: u64| seg.esc(x).dc().map(|d| d.system_time_split(t));
        let Some(r) = sys(reference, pu_ref) else {
            return;
        };
        let xm = net.phc.xtal.master_ns(pu_ref);
        let (pw, pf) = net.phc.at_xtal(xm);
        let d = (pw.wrapping_sub(r.0) as i64) as f64 + (pf - r.1);
        mref.add(d);
        series[0].add(k, d);
        let seg = &net.segment;
        let sys = |x: usize, t: u64| seg.esc(x).dc().map(|d| d.system_time_split(t));
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for x in 0..seg.len() {
            if let Some(v) = sys(x, pu_ref) {
                let d = (v.0.wrapping_sub(r.0) as i64) as f64 + (v.1 - r.1);
                lo = lo.min(d);
                hi = hi.max(d);
            }
        }
        spread.add(hi - lo);
        series[1].add(k, hi - lo);
        // SYNC0: the first grid point at or after the frame's aim (launch + lead), plus the
        // shift, on the last slave's clock.
        let aim = launch + lead;
        let grid = aim - aim % period;
        let end_ps = pu_last + frame_wire_time_ps(cyc_len);
        if let Some(e) = sys(last, end_ps) {
            let after = (e.0.wrapping_sub(grid) as i64) as f64 + e.1;
            let mg = shift as f64 - after;
            margin.add(mg);
            if mg < 0.0 {
                late += 1;
            }
        }
        if net.gptp.is_some() {
            let b = net.bridge.master_ns(pu_ref);
            let off = (pw.wrapping_sub(b) as i64) as f64 + pf;
            gptp_off.add(off);
            series[2].add(k, off);
        }
    };
    match driver.run(&mut net, &mut eng, u64::MAX, None, observe) {
        Ok(_) => {}
        Err(never) => match never {},
    }
    if let Some(c) = net.capture.take() {
        c.finish().map_err(|e| TsnError::Pcap {
            path: "capture".into(),
            message: e.to_string(),
        })?;
    }
    let now = net.now_ps;
    net.cross_traffic_to(now);
    let cross_traffic_frames = net.cross.as_ref().map(|c| c.frames);
    let gptp = net.gptp.as_ref().map(|g| GptpOut {
        offset: gptp_off.summary(),
        measured_link_delay_ns: g.master.mean_link_delay_ns(0).unwrap_or(f64::NAN),
        true_link_delay_ns: net.link_ps as f64 / 1000.0,
        bridge_is_grandmaster: g.bridge.is_grandmaster() && !g.master.is_grandmaster(),
        messages: g.messages,
        held_by_cross_traffic: g.held_by_cross_traffic,
    });
    let [a, b, c, d] = series;
    Ok(VariantResult {
        variant,
        title: variant.title(),
        converged: net_info.lock.converged,
        time_to_lock_ms: net_info.lock.time_to_lock_ns.map(|t| t as f64 / 1e6),
        master_delay_ns: net_info.master_delay_ns,
        master_delay_spread_ns: net_info.master_delay_spread_ns,
        delays,
        max_abs_delay_error_ns: max_err,
        blocked: net.blocked,
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
    })
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
            .map(|h| h.join().expect("variant thread"))
            .collect()
    });
    results.into_iter().collect()
}

/// Writes a pcap of `path` — helper for tests that want one file.
pub fn pcap_path(dir: &Path, v: Variant) -> std::path::PathBuf {
    dir.join(format!("{}.pcap", v.name()))
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let mut rng = Noise(0x7357);
        for case in 0..6 {
            let mut s = scenario::preset();
            let cycle = s.bridge.cycle_ns;
            // One or two windows, each long enough for the largest frame and the margins.
            let len = 180_000 + (rng.unit() * 200_000.0) as u64;
            let open = (rng.unit() * (cycle - len) as f64) as u64;
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
            s.master.clock_offset_ns = (rng.unit() * 1e11) as i64;
            s.master.ppm = rng.unit() * 100.0 - 50.0;
            s.bridge.ppm = rng.unit() * 100.0 - 50.0;
            s.bridge.cross_traffic_load = rng.unit() * 0.9;
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

    #[test]
    #[ignore]
    fn print_preset_run() {
        let mut s = scenario::preset();
        if let Ok(v) = std::env::var("TSN_SECS") {
            s.cycles = v.parse::<u64>().unwrap() * 1000;
        }
        let r = run_all(&s, &TsnOptions::default()).unwrap();
        println!("{}", serde_json::to_string_pretty(&r).unwrap());
    }
}
