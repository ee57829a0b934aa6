//! A segment of virtual ESCs joined by cables, and the path a frame takes through it.
//!
//! A frame sent by the master at real time `t` enters the first ESC's entry port after the
//! master cable's delay. In each ESC the frame visits the ports in the datasheet's processing
//! order 0 -> processing unit -> 3 -> 1 -> 2 -> 0: an open port sends it down the cable and
//! receives it back later, a closed or unconnected port loops it back inside the ESC. Leaving a
//! port costs the forwarding delay tF, or the processing delay tP when the frame came through the
//! processing unit. The first bit's arrival at each port is what the receive time latches see,
//! and the arrival at the processing unit is when its datagrams act: all in picoseconds of real
//! time, so cable lengths of centimetres and frame lengths (80 ns per byte) are exact.

use crate::clock::{CrystalParams, PS_PER_NS};
use crate::esc::{Deferred, Esc, EscStats};
use crate::model::{DeviceInfo, EscModel, PortKind};
use ecsync_wire::register as reg;
use ecsync_wire::{
    AddressMode, Command, DATAGRAM_HEADER_LEN, ETH_HEADER_LEN, ETHERTYPE_ETHERCAT, EcatFrame,
    header_shape_key, mark_returned_frame,
};
use std::sync::Arc;

mod counters;
mod plans;
mod process;
mod topology;
pub(crate) use counters::ErrorCounter;
use plans::{SHAPE_SLOTS, ShapeCache, VisitPlan};
use process::LongIndex;
use topology::{
    Node, Peer, Timing, build_nodes, build_plan, check_one_master, link_slaves, network_order,
};

// A shape is compared byte for byte (never decoded): the Ethernet type and EtherCAT header as
// one word, then each datagram header.
const HEAD_AT: usize = ETH_HEADER_LEN - 2;
const FIRST_DATAGRAM: usize = EcatFrame::<&[u8]>::first_datagram_offset();

use crate::phy::CABLE_PS_PER_M;

/// Where a slave's entry port is connected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Upstream {
    /// The master's network interface.
    Master,
    /// Port `port` of slave `index` (an index into the spec's list).
    Slave {
        /// Index of the upstream slave in the spec.
        index: usize,
        /// Port of the upstream slave.
        port: u8,
    },
}

impl Upstream {
    /// The entry of slave `i` (from 0) of a line: the master's interface for the first, port 1
    /// of the slave before for each other.
    pub fn in_line(i: usize) -> Upstream {
        match i.checked_sub(1) {
            None => Upstream::Master,
            Some(index) => Upstream::Slave { index, port: 1 },
        }
    }
}

/// One slave of a segment description.
#[derive(Debug, Clone, PartialEq)]
pub struct SlaveSpec {
    /// The ESC model.
    pub model: EscModel,
    /// The device.
    pub device: DeviceInfo,
    /// The DC unit's crystal.
    pub crystal: CrystalParams,
    /// What the entry port is connected to.
    pub upstream: Upstream,
    /// This slave's port towards the master (normally 0).
    pub entry_port: u8,
    /// Cable length to the upstream device, m.
    pub cable_m: f64,
    /// A cable from one of this slave's ports back to the master's second port: the segment
    /// is a ring for cable redundancy ([`Segment::connect_ring`]). At most one slave has one.
    pub ring: Option<RingCable>,
}

/// The cable that closes a ring: from a slave's port to the master's second port.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RingCable {
    /// The slave's port (a line's last slave: 1).
    pub port: u8,
    /// Its length, m.
    pub cable_m: f64,
}

/// Why a segment description cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TopologyError {
    /// No slaves.
    #[error("the segment has no slaves")]
    Empty,
    /// Not exactly one slave connected to the master.
    #[error("exactly one slave must be connected to the master, found {0}")]
    MasterLinks(usize),
    /// More than one ring cable to the master's second port.
    #[error("the master has one second port: {0} slaves have a ring cable to it, at most one may")]
    RingCables(usize),
    /// An upstream index that does not name an earlier slave.
    #[error("slave {slave}: upstream slave {upstream} does not exist or is not listed before it")]
    BadUpstream {
        /// The slave.
        slave: usize,
        /// Its upstream index.
        upstream: usize,
    },
    /// A port that the model does not implement.
    #[error("slave {slave}: port {port} is not implemented by its ESC model")]
    NoSuchPort {
        /// The slave.
        slave: usize,
        /// The port.
        port: u8,
    },
    /// Two cables on one port.
    #[error("slave {slave}: port {port} is connected twice")]
    PortInUse {
        /// The slave.
        slave: usize,
        /// The port.
        port: u8,
    },
    /// A negative or non-finite cable length or delay.
    #[error("slave {slave}: {what} must be a finite number >= 0")]
    BadNumber {
        /// The slave.
        slave: usize,
        /// Which number.
        what: &'static str,
    },
}

/// The ground truth of one frame's way: when its first bit reached each slave's processing
/// unit. Cheap to keep (it shares the segment's timing, which every frame of an unchanged
/// segment follows), so a cycle of several frames keeps each one's.
#[derive(Debug, Clone)]
pub struct FrameTrace {
    sent_ps: u64,
    timing: Arc<Timing>,
}

impl FrameTrace {
    /// Real time the frame's first bit reached the processing unit of the slave at network
    /// position `pos`, ps (`None`: it did not).
    #[inline]
    pub fn pu_ps(&self, pos: usize) -> Option<u64> {
        self.timing
            .pu
            .get(pos)
            .copied()
            .flatten()
            .map(|o| self.sent_ps + o)
    }

    /// When the frame left the master, ps.
    pub fn sent_ps(&self) -> u64 {
        self.sent_ps
    }

    /// Number of slaves.
    pub fn len(&self) -> usize {
        self.timing.pu.len()
    }

    /// Whether the segment has no slaves.
    pub fn is_empty(&self) -> bool {
        self.timing.pu.is_empty()
    }
}

/// What happened to a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameOutcome {
    /// Real time the returned frame's first bit reaches the master, ps; `None` if it was lost.
    pub returned_sof_ps: Option<u64>,
    /// Whether the datagrams were processed (a malformed frame is forwarded untouched).
    pub processed: bool,
    /// The master's port it returns on: 0 its first, 1 its second (a ring: see
    /// [`Segment::connect_ring`]).
    pub returned_port: u8,
}

/// A virtual EtherCAT segment.
#[derive(Debug, Clone)]
pub struct Segment {
    nodes: Vec<Node>,
    first: u16,
    /// The last frame's way.
    trace: FrameTrace,
    /// The way of a frame that reaches no slave (destroyed at the first port).
    unreached: Arc<Timing>,
    /// Slave index in network (auto-increment) order -> index in the spec.
    spec_index: Vec<usize>,
    frames: u64,
    malformed: u64,
    lost: u64,
    /// The frame shapes seen recently (a cycle's frames each have their own).
    shapes: ShapeCache,
    replay: bool,
    /// The frame's timing through the segment, relative to its send time: the same for every
    /// frame while the loops do not change (see [`Timing`]).
    timing: Option<Arc<Timing>>,
    /// Per shape slot: the ESCs a frame of that shape does something at ([`VisitPlan`]).
    plans: Box<[Option<VisitPlan>]>,
    /// The datagrams of the long frame being passed, by the station they name.
    long: LongIndex,
    /// Bumped whenever an ESC's configuration generation changes or an ESC is handed out
    /// mutably: a visit plan holds only in the epoch it was made in.
    epoch: u64,
    /// The next frame's FCS breaks on its way back ([`Segment::break_fcs_of_next_frame`]).
    fcs_break_pending: bool,
    /// A ring: the slave (network position) and its port cabled to the master's second port.
    ring: Option<(u16, u8)>,
    /// The timing of a frame the master sends on its second port (walked again whenever
    /// `timing` is).
    timing_secondary: Option<Arc<Timing>>,
}

// A visit on one cache line's worth of the plan.

impl Segment {
    /// Builds a segment. Slaves are renumbered in network order: the order in which a frame
    /// passes their processing units, which is their auto-increment position.
    pub fn new(spec: &[SlaveSpec]) -> Result<Self, TopologyError> {
        check_one_master(spec)?;
        let links = link_slaves(spec)?;
        let order = network_order(spec, &links);
        let nodes = build_nodes(spec, &links, &order);
        let n = nodes.len();
        let unreached = Arc::new(Timing::unreached(n));
        let rings: Vec<(usize, RingCable)> = order
            .iter()
            .enumerate()
            .filter_map(|(pos, &i)| spec[i].ring.map(|r| (pos, r)))
            .collect();
        if rings.len() > 1 {
            return Err(TopologyError::RingCables(rings.len()));
        }
        let mut seg = Segment {
            trace: FrameTrace {
                sent_ps: 0,
                timing: unreached.clone(),
            },
            unreached,
            nodes,
            first: 0,
            spec_index: order,
            frames: 0,
            malformed: 0,
            lost: 0,
            shapes: ShapeCache::new(),
            replay: true,
            timing: None,
            plans: vec![None; SHAPE_SLOTS].into_boxed_slice(),
            long: LongIndex::default(),
            epoch: 0,
            fcs_break_pending: false,
            ring: None,
            timing_secondary: None,
        };
        if let Some(&(pos, r)) = rings.first() {
            seg.connect_ring(pos, r.port, r.cable_m)?;
        }
        Ok(seg)
    }

    /// Number of slaves.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Puts back the trace of an earlier frame (the transport's second port keeps the first
    /// port's frame as the cycle's ground truth).
    pub(crate) fn restore_trace(&mut self, trace: FrameTrace) {
        self.trace = trace;
    }

    /// Whether the segment has no slaves (never true for a built segment).
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The ESC at network position `pos`.
    pub fn esc(&self, pos: usize) -> &Esc {
        &self.nodes[pos].esc
    }

    /// Mutable ESC at network position `pos`. A change to its loops is seen by the next frame
    /// (the way through the segment is worked out again).
    pub fn esc_mut(&mut self, pos: usize) -> &mut Esc {
        let node = &mut self.nodes[pos];
        // The caller may change anything: the way is walked again, from the plan again.
        node.plan = build_plan(&node.esc, &node.links, usize::from(node.entry_port));
        self.timing = None;
        self.timing_secondary = None;
        // Its counters are brought up to date first, and no plan holds past this.
        self.end_plans();
        self.epoch += 1;
        &mut self.nodes[pos].esc
    }

    /// Pulls (`up` false) or plugs in again the cable at port `port` of the slave at network
    /// position `pos`: both ends lose or regain their link, and a port in auto mode closes or
    /// opens (the datasheet's loop control), so the segment behind a pulled cable is gone and
    /// the port loops frames back. A slave that is switched off keeps its links down. Returns
    /// false if there is no cable there. A link lost counts in the lost link counters of both
    /// ends (0x0310 + port, [`Esc::set_links`]).
    pub fn set_link(&mut self, pos: usize, port: usize, up: bool) -> bool {
        self.set_link_counted(pos, port, up, true)
    }

    /// Leaves the cable at port `port` of the slave at network position `pos` unplugged from
    /// the start (a slave that appears later, hot connect): as [`Segment::set_link`] with `up`
    /// false, but no link was ever there to be lost, so no counter counts.
    pub fn start_unplugged(&mut self, pos: usize, port: usize) -> bool {
        self.set_link_counted(pos, port, false, false)
    }

    /// Whether a cable is plugged into port `port` of the slave at network position `pos` (to
    /// another slave or to the master), as the segment was built: what [`Segment::set_link`]
    /// can pull.
    pub fn has_cable(&self, pos: usize, port: usize) -> bool {
        self.nodes
            .get(pos)
            .is_some_and(|n| n.links.get(port).copied().flatten().is_some())
    }

    fn set_link_counted(&mut self, pos: usize, port: usize, up: bool, count: bool) -> bool {
        let Some(l) = self
            .nodes
            .get(pos)
            .and_then(|n| n.links.get(port).copied().flatten())
        else {
            return false;
        };
        let here = up && !self.nodes[pos].off;
        self.set_port_link(pos, port, here, count);
        if let Peer::Slave(q) = l.peer {
            let q = usize::from(q);
            let there = up && !self.nodes[q].off;
            self.set_port_link(q, usize::from(l.peer_port), there, count);
        }
        true
    }

    fn set_port_link(&mut self, pos: usize, port: usize, up: bool, count: bool) {
        let esc = self.esc_mut(pos);
        let mut links = esc.links();
        links[port] = up;
        if count {
            esc.set_links(links);
        } else {
            esc.set_links_uncounted(links);
        }
        let node = &mut self.nodes[pos];
        node.plan = build_plan(&node.esc, &node.links, usize::from(node.entry_port));
    }

    /// Makes the segment a ring for cable redundancy: port `port` of the slave at network
    /// position `pos` (a line's last slave, its port 1) is cabled (`cable_m`) to the master's
    /// second port. Its port then has a link: a frame the master sends on its first port that
    /// reaches it leaves the segment to the master's second port (the ring intact: every
    /// processing unit on the way), and one sent on the second port
    /// ([`Segment::process_secondary`]) runs the ring the other way through the ports alone
    /// (the processing unit follows port 0 in the processing order) back to the first. With a
    /// cable pulled (`set_link`) the ports on both sides close, and each frame is processed by
    /// the slaves on its side and returns on the port it left by (ETG.1500's cable
    /// redundancy; the ESC datasheet's loop control).
    pub fn connect_ring(
        &mut self,
        pos: usize,
        port: u8,
        cable_m: f64,
    ) -> Result<(), TopologyError> {
        let p = usize::from(port);
        let Some(node) = self.nodes.get(pos) else {
            return Err(TopologyError::BadUpstream {
                slave: pos,
                upstream: pos,
            });
        };
        if p > 3 || node.esc.model().ports[p] == PortKind::None {
            return Err(TopologyError::NoSuchPort { slave: pos, port });
        }
        if node.links[p].is_some() {
            return Err(TopologyError::PortInUse { slave: pos, port });
        }
        if !(cable_m.is_finite() && cable_m >= 0.0) {
            return Err(TopologyError::BadNumber {
                slave: pos,
                what: "cable_m",
            });
        }
        let delay_ps = topology::ps(node.esc.model().link_phy_delay_ns)
            + (cable_m * CABLE_PS_PER_M).round() as u64;
        self.nodes[pos].links[p] = Some(topology::Link {
            peer: topology::Peer::Master,
            peer_port: 1,
            delay_ps,
        });
        self.ring = Some((pos as u16, port));
        let off = self.nodes[pos].off;
        self.set_port_link(pos, p, !off, false);
        Ok(())
    }

    /// The ring's slave and port cabled to the master's second port, if the segment is one.
    pub fn ring(&self) -> Option<(usize, u8)> {
        self.ring.map(|(p, port)| (usize::from(p), port))
    }

    /// Switches the slave at network position `pos` off at real time `t_ps`: its links go
    /// down (the slaves behind it are cut off) until [`Segment::power_on`].
    pub fn power_off(&mut self, pos: usize, _t_ps: u64) {
        for port in 0..4 {
            self.set_link(pos, port, false);
        }
        self.nodes[pos].off = true;
    }

    /// Switches the slave at network position `pos` on again at real time `t_ps`: it starts
    /// from reset ([`Esc::power_cycled`]) and its cables link again.
    pub fn power_on(&mut self, pos: usize, t_ps: u64) {
        self.end_plans();
        self.epoch += 1;
        self.timing = None;
        self.timing_secondary = None;
        let node = &mut self.nodes[pos];
        node.esc = node.esc.power_cycled(t_ps);
        node.off = false;
        for port in 0..4 {
            self.set_link(pos, port, true);
        }
    }

    /// The port through which frames enter the slave at network position `pos` (its upstream
    /// cable).
    pub fn entry_port(&self, pos: usize) -> usize {
        usize::from(self.nodes[pos].entry_port)
    }

    /// Whether the slave at network position `pos` is switched off.
    pub fn is_powered_off(&self, pos: usize) -> bool {
        self.nodes[pos].off
    }

    /// The counters of the ESC at network position `pos`, with the frames that passed it by
    /// (frames of a shape that does nothing at this ESC skip it in large networks and are
    /// counted here) and those its visit plans replayed (a plan counts them until it ends:
    /// [`Esc::stats`] alone leaves both out).
    pub fn esc_stats(&self, pos: usize) -> EscStats {
        let mut s = self.nodes[pos].esc.stats();
        for p in self.plans.iter().flatten() {
            if p.idle.get(pos).copied().unwrap_or(false) {
                s.frames += p.idle_frames;
                s.replayed_frames += p.idle_frames;
            }
            for v in p.visits.iter().filter(|v| v.slave as usize == pos) {
                if let Some(steps) = &v.steps {
                    steps.add_replays_to(&mut s, v.replays);
                }
            }
        }
        s
    }

    /// Index in the spec of the slave at network position `pos`.
    pub fn spec_index(&self, pos: usize) -> usize {
        self.spec_index[pos]
    }

    /// Turns the replay of recorded frame shapes on or off (on by default; off runs every
    /// datagram through the full decoding at every ESC, long frames' too, for equivalence
    /// tests).
    pub fn set_replay(&mut self, on: bool) {
        self.replay = on;
    }

    /// Ground truth of the last processed frame.
    pub fn trace(&self) -> &FrameTrace {
        &self.trace
    }

    /// Frames processed, malformed frames forwarded untouched, frames lost.
    pub fn frame_counts(&self) -> (u64, u64, u64) {
        (self.frames, self.malformed, self.lost)
    }

    /// Plays every powered slave's process data watchdog up to `t_ps` (between frames: a
    /// master that stopped sending finds its drives in SAFE-OP with 0x001B, and so does anyone
    /// who looks at them meanwhile). How many watchdogs expired by it; nothing allocated (serve
    /// calls it between every two frames).
    pub fn expire_watchdogs(&mut self, t_ps: u64) -> usize {
        let mut expired = 0;
        for n in &mut self.nodes {
            // Every node's watchdog is played: no short-circuit past the first expiry.
            if !n.off && n.esc.expire_watchdog(t_ps) {
                expired += 1;
            }
        }
        expired
    }

    /// Advances every clock to `t_ps` (wander, slews); call between frames when time passes.
    pub fn advance_to(&mut self, t_ps: u64) {
        for n in &mut self.nodes {
            if let Some(dc) = n.esc.dc_mut() {
                dc.advance_to(t_ps);
            }
        }
    }
}

/// Whether a frame is an EtherCAT command frame whose datagram chain is well formed.
pub fn frame_is_processable(frame: &[u8]) -> bool {
    let Ok(f) = EcatFrame::new_checked(frame) else {
        return false;
    };
    f.datagrams().all(|d| d.is_ok())
}
