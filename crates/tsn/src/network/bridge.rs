//! The time-aware bridge: its clock, its egress gates (802.1Qbv) with store and forward, the
//! best-effort cross traffic on its master-facing egress, and the wire gPTP runs on between it
//! and the master.

use super::phc::Phc;
use super::wire::{Capture, Noise, stamp, wire_ns};
use crate::gptp::TimeAwareSystem;
use crate::gptp_msg;
use crate::gptp_net::{GptpMedium, Transmission};
use crate::qbv::PortSchedule;
use ecsync_master::io::MASTER_MAC;
use ecsync_sim::frame_wire_time_ps;
use ecsync_sim::transport::MasterClock;

/// The bridge.
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeParams {
    /// Crystal error, ppm.
    pub ppm: f64,
    /// Crystal wander, ppm per sqrt(s).
    pub wander_ppm_per_sqrt_s: f64,
    /// Bridge clock at the start, ns.
    pub initial_ns: u64,
    /// Store-and-forward residence after a frame is received, before its egress, ns.
    pub residence_ns: u64,
    /// Gate cycle, ns.
    pub cycle_ns: u64,
    /// Local time at which gate cycles start (modulo the cycle), ns.
    pub base_ns: u64,
    /// Egress towards the slaves.
    pub ethercat_port: PortSchedule,
    /// Egress towards the master.
    pub master_port: PortSchedule,
    /// Share of the best-effort time the master-facing wire carries cross traffic.
    pub cross_traffic_load: f64,
    /// Size of a cross-traffic frame, bytes.
    pub cross_traffic_frame_bytes: u64,
    /// gPTP priority1.
    pub priority1: u8,
}

/// The bridge's MAC address (the source of its gPTP messages).
pub const BRIDGE_MAC: [u8; 6] = [0x00, 0x1b, 0x21, 0xec, 0x00, 0x02];

/// The master's index in the gPTP pair.
pub(super) const MASTER: usize = 0;
/// The bridge's.
pub(super) const BRIDGE: usize = 1;

/// Best-effort cross traffic on the bridge's master-facing egress (a camera streaming to the
/// PC): frames of one size arriving as a Poisson stream, queued, and sent one at a time outside
/// the EtherCAT windows with the guard band. Generated lazily, as far as the simulation needs.
#[derive(Debug)]
pub(super) struct CrossTraffic {
    noise: Noise,
    frame_ps: u64,
    mean_gap_ps: f64,
    next_arrival_ps: u64,
    backlog: u64,
    /// The wire is busy with a cross-traffic frame (or a gPTP message) until then, real ps.
    busy_until_ps: u64,
    /// Frames sent.
    pub(super) frames: u64,
}

impl CrossTraffic {
    /// The stream of `p`, or none where it would not load the wire.
    pub(super) fn of(p: &BridgeParams, seed: u64) -> Option<Self> {
        let frame_ps = frame_wire_time_ps(p.cross_traffic_frame_bytes.saturating_sub(4) as usize);
        let busy_share = p.cross_traffic_load * (1.0 - p.master_port.open_fraction());
        (busy_share > 0.0).then(|| {
            let mut noise = Noise::new(seed ^ 0x6372_6f73_7374_7266);
            let mean_gap_ps = frame_ps as f64 / busy_share;
            let first = (-noise.unit().ln() * mean_gap_ps) as u64;
            CrossTraffic {
                noise,
                frame_ps,
                mean_gap_ps,
                next_arrival_ps: first,
                backlog: 0,
                busy_until_ps: 0,
                frames: 0,
            }
        })
    }
}

/// The bridge: its clock, its gate schedules, its residence, and what its master-facing egress
/// carries besides EtherCAT.
#[derive(Debug)]
pub(super) struct Bridge<'a> {
    pub(super) clock: MasterClock,
    params: &'a BridgeParams,
    pub(super) residence_ps: u64,
    pub(super) cross: Option<CrossTraffic>,
    /// The master-facing egress is busy with a gPTP message until then (real ps).
    gptp_tx_free_ps: u64,
    /// gPTP messages that waited for cross traffic in flight.
    pub(super) held_by_cross_traffic: u64,
}

impl<'a> Bridge<'a> {
    pub(super) fn new(
        params: &'a BridgeParams,
        clock: MasterClock,
        cross: Option<CrossTraffic>,
    ) -> Self {
        Bridge {
            clock,
            params,
            residence_ps: params.residence_ns * 1000,
            cross,
            gptp_tx_free_ps: 0,
            held_by_cross_traffic: 0,
        }
    }

    /// The egress gate: an EtherCAT frame of `len` bytes ready at real time `ready_ps` starts
    /// when (real time), after waiting how long (ps).
    pub(super) fn gate(&mut self, ready_ps: u64, len: usize, towards_slaves: bool) -> (u64, u64) {
        let sched = if towards_slaves {
            &self.params.ethercat_port
        } else {
            &self.params.master_port
        };
        let local = self.clock.master_ns(ready_ps);
        match sched.ethercat_start(local, wire_ns(len)) {
            Some(start) if start > local => {
                let t = self.clock.real_ps_at(start).max(ready_ps);
                (t, t - ready_ps)
            }
            _ => (ready_ps, 0),
        }
    }

    /// Sends the cross-traffic frames that start before real time `t_ps`.
    pub(super) fn cross_traffic_to(&mut self, t_ps: u64) {
        let Bridge {
            cross,
            clock,
            params,
            ..
        } = self;
        let Some(ct) = cross else { return };
        let sched = &params.master_port;
        loop {
            let want = if ct.backlog > 0 {
                ct.busy_until_ps
            } else {
                ct.next_arrival_ps.max(ct.busy_until_ps)
            };
            if want >= t_ps {
                return;
            }
            let local = clock.master_ns(want);
            let s_local = sched.best_effort_start(local, ct.frame_ps / 1000);
            let start = if s_local == local {
                want
            } else {
                clock.real_ps_at(s_local).max(want)
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

    /// A gPTP message of `wire_ps` on the wire, ready at real time `ready_ps`, on the
    /// master-facing port: best effort, outside the EtherCAT window, after any cross-traffic
    /// frame in flight and the bridge's previous message. When it starts: real ps and the
    /// bridge's clock.
    fn send_best_effort(&mut self, ready_ps: u64, wire_ps: u64) -> (u64, u64) {
        let mut ready_ps = ready_ps.max(self.gptp_tx_free_ps);
        self.cross_traffic_to(ready_ps);
        if let Some(ct) = &self.cross
            && ct.busy_until_ps > ready_ps
        {
            ready_ps = ct.busy_until_ps;
            self.held_by_cross_traffic += 1;
        }
        let ready = self.clock.master_ns(ready_ps);
        let start = self
            .params
            .master_port
            .best_effort_start(ready, wire_ps / 1000);
        let start_ps = if start == ready {
            ready_ps
        } else {
            self.clock.real_ps_at(start).max(ready_ps)
        };
        // The message holds the wire: cross traffic waits for its end.
        if let Some(ct) = &mut self.cross {
            ct.busy_until_ps = ct.busy_until_ps.max(start_ps + wire_ps);
        }
        self.gptp_tx_free_ps = start_ps + wire_ps;
        (start_ps, start)
    }
}

/// The link between master and bridge as gPTP sees it ([`GptpMedium`] in real ps): the
/// master's messages leave when ready, the bridge's as best effort; both stamp their own
/// free-running clocks (the master its PHC's crystal) on the master's timestamper grid; the
/// capture at the master's port records what leaves and arrives there.
pub(super) struct GptpWire<'n, 'a> {
    pub(super) phc: &'n mut Phc,
    pub(super) bridge: &'n mut Bridge<'a>,
    pub(super) capture: &'n mut Capture,
    pub(super) link_ps: u64,
    pub(super) timestamp_ns: u64,
}

impl GptpMedium<u64> for GptpWire<'_, '_> {
    fn timestamp_ns(&mut self, node: usize, t_ps: u64) -> u64 {
        let local = if node == MASTER {
            self.phc.crystal_ns(t_ps)
        } else {
            self.bridge.clock.master_ns(t_ps)
        };
        stamp(self.timestamp_ns, local)
    }

    fn transmit(
        &mut self,
        node: usize,
        _: usize,
        ready_ps: u64,
        payload: &[u8],
    ) -> Transmission<u64> {
        let from_master = node == MASTER;
        let mut eth = Vec::with_capacity(payload.len() + 14);
        let mac = if from_master { MASTER_MAC } else { BRIDGE_MAC };
        gptp_msg::ethernet_frame(mac, payload, &mut eth);
        let wire_ps = frame_wire_time_ps(eth.len());
        let (start_ps, tx_local) = if from_master {
            (ready_ps, self.phc.crystal_ns(ready_ps))
        } else {
            self.bridge.send_best_effort(ready_ps, wire_ps)
        };
        let arrival = start_ps + self.link_ps;
        // The capture is at the master's port: its sends, and what arrives there.
        self.capture
            .record(if from_master { start_ps } else { arrival }, &eth);
        Transmission {
            tx_ns: stamp(self.timestamp_ns, tx_local),
            arrival,
            peer: if from_master { BRIDGE } else { MASTER },
            peer_port: 0,
            next_ready: start_ps + wire_ps,
        }
    }

    fn follow_up(&mut self, node: usize, system: &mut TimeAwareSystem) {
        // The bridge is the grandmaster: only the master's clock follows.
        if node == MASTER {
            self.phc.discipline(system);
        }
    }
}
