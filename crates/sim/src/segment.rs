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
    MIN_FRAME_LEN, header_shape_key, mark_returned_frame,
};
use std::sync::Arc;

// A shape is compared byte for byte (never decoded): the Ethernet type and EtherCAT header as
// one word, then each datagram header.
const HEAD_AT: usize = ETH_HEADER_LEN - 2;
const FIRST_DATAGRAM: usize = EcatFrame::<&[u8]>::first_datagram_offset();

/// Wire time of one byte at 100 Mbit/s, ps.
pub const BYTE_TIME_PS: u64 = 80_000;
/// Preamble and start-of-frame delimiter, bytes.
pub const PREAMBLE_BYTES: u64 = 8;
/// Frame check sequence, bytes.
pub const FCS_BYTES: u64 = 4;
/// Signal propagation in a cable, ps per metre (5 ns/m, datasheet section I, 9.3).
pub const CABLE_PS_PER_M: f64 = 5_000.0;

/// Wire time of a frame of `len` bytes (without FCS, before padding): preamble, padded frame,
/// FCS.
pub fn frame_wire_time_ps(len: usize) -> u64 {
    (PREAMBLE_BYTES + len.max(MIN_FRAME_LEN) as u64 + FCS_BYTES) * BYTE_TIME_PS
}

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

#[derive(Debug, Clone, Copy)]
enum Peer {
    Master,
    Slave(u16),
}

#[derive(Debug, Clone, Copy)]
struct Link {
    peer: Peer,
    peer_port: u8,
    delay_ps: u64,
}

#[derive(Debug, Clone)]
struct Node {
    esc: Esc,
    links: [Option<Link>; 4],
    entry_port: u8,
    forwarding_ps: u64,
    processing_ps: u64,
    /// What a frame entering at `entry_port` meets, in processing order (rebuilt when the
    /// master changes the loop settings).
    plan: Plan,
    /// Switched off (a power cycle in progress): its links are down.
    off: bool,
}

/// One element of a frame's way through an ESC.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// The processing unit.
    Pu,
    /// An open port with a cable: out and back.
    Port(u8, Link),
    /// A port forced open without a link: the frame is lost there.
    Lost,
}

#[derive(Debug, Clone, Copy)]
struct Plan {
    steps: [Step; 5],
    len: u8,
}

fn build_plan(esc: &Esc, links: &[Option<Link>; 4], entry: usize) -> Plan {
    let mut plan = Plan {
        steps: [Step::Pu; 5],
        len: 0,
    };
    let start = ring_pos(entry);
    for k in 1..5 {
        let step = match RING[(start + k) % 5] {
            None => Step::Pu,
            Some(p) => match esc.port_forwards(p) {
                Ok(true) => match links[p] {
                    Some(l) => Step::Port(p as u8, l),
                    None => continue,
                },
                Ok(false) => continue,
                Err(()) => Step::Lost,
            },
        };
        plan.steps[usize::from(plan.len)] = step;
        plan.len += 1;
    }
    plan
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
}

/// The smallest network whose frames follow visit plans. Below, a cycle's one or few frames do
/// something at nearly every ESC, and the replay of an empty program costs less than the plan's
/// upkeep; the results are the same either way.
const PLAN_MIN_SLAVES: usize = 32;

/// Which ESCs a frame of one shape does something at. In a large network most of a cycle's
/// frames carry the process data of a few slaves: the others would only replay an empty
/// program. The frame passes them by (their timing, and so the ground truth, is the walk's),
/// and their frame counters are brought up to date when the plan ends
/// ([`Segment::end_plan`]) or read ([`Segment::esc_stats`]).
///
/// A plan is made after a frame of the shape found every ESC with a program for it recorded in
/// the current generation, and holds while no ESC's generation changes (the [`Segment`]'s
/// epoch) and the frame follows the same way (the same [`Timing`]): an empty program stays
/// empty while nothing in its ESC changes, and a frame's data never adds a step (the steps
/// depend on the datagram headers and the ESC's configuration only).
#[derive(Debug, Clone)]
struct VisitPlan {
    shape: u32,
    epoch: u64,
    timing: Arc<Timing>,
    /// The ESCs the frame does something at, in the walk's order, with their steps.
    visits: Vec<PlannedVisit>,
    /// Per slave: the frame passes by it doing nothing.
    idle: Vec<bool>,
    /// Frames passed by the idle ESCs and not yet in their counters.
    idle_frames: u64,
}

/// One visit of a [`VisitPlan`]: the slave, when the frame reaches its processing unit, and
/// its one-step program for the frame (`None`: looked up by program slot, replayed op by op
/// or decoded, as without a plan). The plan's visits lie one after the other in the order
/// they are made, so a large network's cycle reads its steps as a stream rather than from
/// each ESC's program slots.
#[derive(Debug, Clone, Copy)]
struct PlannedVisit {
    slave: u32,
    pu_ps: u64,
    steps: Option<crate::esc::PlannedSteps>,
    /// Frames its steps replayed and not yet in the ESC's counters (brought up to date as the
    /// idle frames are: the visit touches nothing of the ESC's counters).
    replays: u64,
}

// A visit on one cache line's worth of the plan.
const _: () = assert!(size_of::<PlannedVisit>() <= 64);

impl VisitPlan {
    fn holds(&self, shape: u32, epoch: u64, tm: &Arc<Timing>) -> bool {
        self.shape == shape && self.epoch == epoch && Arc::ptr_eq(&self.timing, tm)
    }
}

/// Where a frame's first bit is, relative to the moment it left the master: the traversal's
/// timing depends on the topology, the delays and the loop settings only, never on the frame.
/// One walk of the ports ([`Segment::walk`]) computes it; every frame, replayed or decoded,
/// then meets the processing units in its order at its times.
#[derive(Debug)]
struct Timing {
    /// Per slave: arrival at the processing unit, ps after the send (`None`: not reached).
    pu: Vec<Option<u64>>,
    /// Per slave: arrival at each port, ps after the send.
    ports: Vec<[Option<u64>; 4]>,
    /// Per slave: the port the frame came in through.
    in_port: Vec<u8>,
    /// Back at the master, ps after the send; `None` if the frame is lost on the way.
    back: Option<u64>,
    /// The slaves in the order their processing units see the frame, with their `pu`.
    flat: Vec<(usize, u64)>,
}

impl Timing {
    fn unreached(n: usize) -> Timing {
        Timing {
            pu: vec![None; n],
            ports: vec![[None; 4]; n],
            in_port: vec![0; n],
            back: None,
            flat: Vec::new(),
        }
    }
}

/// A frame shape: the Ethernet type and EtherCAT header, then per datagram its first 8 header
/// bytes but the index, and the last 2 (command, address, length and flags, IRQ), as words for the
/// comparison every cyclic frame makes; where the datagrams are; and the id the ESCs key their
/// recorded programs on.
#[derive(Debug, Clone, Copy)]
struct Shape {
    head: u32,
    words: [(u64, u16); MAX_SHAPE_DATAGRAMS],
    offsets: [u16; MAX_SHAPE_DATAGRAMS],
    n: u8,
    /// The frame length the chain needs.
    min_len: usize,
    id: u32,
}

/// Recently seen frame shapes, two-way set-associative on the first datagram's command and
/// address (which the frames of one cycle do not share): a cycle of several frames finds each of
/// its shapes again without decoding, where one remembered shape would be replaced at every
/// frame; the second way keeps two shapes whose command and index fall in one set (the first
/// frame's FRMW and an LRW of a 1 000-drive cycle) from replacing each other every cycle.
#[derive(Debug, Clone)]
struct ShapeCache {
    slots: Box<[Option<Shape>; SHAPE_SLOTS]>,
    /// Per set: the way filled last (the other one is replaced first).
    recent: Box<[u8; SHAPE_SETS]>,
    last_id: u32,
}

/// Sets of the shape cache, and the shapes remembered at once.
const SHAPE_SETS: usize = 128;
const SHAPE_SLOTS: usize = 2 * SHAPE_SETS;

impl ShapeCache {
    fn new() -> Self {
        ShapeCache {
            slots: Box::new([None; SHAPE_SLOTS]),
            recent: Box::new([0; SHAPE_SETS]),
            last_id: 0,
        }
    }

    /// The set of a frame: its first datagram's command and address (never its index, which
    /// a master changes every cycle to tell its replies apart). A logical command's set is
    /// its address's kilobyte: the LRWs of a large network's cycle, a frame's worth of
    /// logical addresses apart, then fall into sets of their own (a hash of the address put
    /// three of a 1 000-drive cycle's LRWs into one set when each frame held a group of
    /// slaves, and two of them were then decoded every cycle).
    #[inline]
    fn set_of(frame: &[u8]) -> usize {
        match frame.get(FIRST_DATAGRAM..FIRST_DATAGRAM + DATAGRAM_HEADER_LEN) {
            Some(h) => {
                let d = ecsync_wire::Datagram::new_unchecked(h);
                let addr = d.address_raw();
                let cmd = usize::from(d.command_code());
                let logical = d
                    .command()
                    .is_ok_and(|c| c.address_mode() == ecsync_wire::AddressMode::Logical);
                let spread = if logical {
                    (addr >> 10) as usize
                } else {
                    (addr ^ addr >> 16 ^ addr >> 8) as usize
                };
                (cmd * 7 + spread) % SHAPE_SETS
            }
            None => 0,
        }
    }

    /// The slot of `frame`'s remembered shape and how its ESCs take it, if its headers are
    /// that shape's.
    #[inline]
    fn find(&self, frame: &[u8]) -> Option<(usize, FrameCtx)> {
        let set = Self::set_of(frame);
        for way in 0..2 {
            let k = 2 * set + way;
            if let Some(s) = &self.slots[k]
                && frame.len() >= s.min_len
                && s.matches(frame)
            {
                return Some((k, s.ctx()));
            }
        }
        None
    }

    /// Remembers the shape of a valid frame whose datagrams start at `offsets`; its slot and
    /// id. A new shape takes an empty way of its set, else the one used less recently.
    fn insert(&mut self, frame: &[u8], offsets: &[u16]) -> (usize, u32) {
        let mut s = Shape {
            head: u32::from_le_bytes(frame[HEAD_AT..FIRST_DATAGRAM].try_into().unwrap_or([0; 4])),
            words: [(0, 0); MAX_SHAPE_DATAGRAMS],
            offsets: [0; MAX_SHAPE_DATAGRAMS],
            n: offsets.len() as u8,
            // The chain ends at the EtherCAT length; the frame must hold that much.
            min_len: EcatFrame::<&[u8]>::first_datagram_offset()
                + EcatFrame::new_unchecked(frame).ecat_len(),
            id: 0,
        };
        for (k, &at) in offsets.iter().enumerate() {
            let at = usize::from(at);
            let h: &[u8; DATAGRAM_HEADER_LEN] = frame[at..at + DATAGRAM_HEADER_LEN]
                .try_into()
                .expect("a header's length");
            s.words[k] = header_shape_key(h);
        }
        s.offsets[..offsets.len()].copy_from_slice(offsets);
        let set = Self::set_of(frame);
        for way in 0..2 {
            if let Some(old) = &self.slots[2 * set + way]
                && old.n == s.n
                && old.offsets == s.offsets
                && old.matches(frame)
            {
                self.recent[set] = way as u8;
                return (2 * set + way, old.id);
            }
        }
        let way = match (&self.slots[2 * set], &self.slots[2 * set + 1]) {
            (None, _) => 0,
            (_, None) => 1,
            _ => 1 - usize::from(self.recent[set]),
        };
        self.recent[set] = way as u8;
        self.last_id = self.last_id.wrapping_add(1).max(1);
        s.id = self.last_id;
        self.slots[2 * set + way] = Some(s);
        (2 * set + way, s.id)
    }
}

impl Shape {
    /// Whether the frame's Ethernet type, EtherCAT header and datagram headers are this
    /// shape's.
    #[inline]
    fn matches(&self, frame: &[u8]) -> bool {
        let word = |at: usize| -> Option<(u64, u16)> {
            let h: &[u8; DATAGRAM_HEADER_LEN] =
                frame.get(at..at + DATAGRAM_HEADER_LEN)?.try_into().ok()?;
            Some(header_shape_key(h))
        };
        let head = frame
            .get(HEAD_AT..FIRST_DATAGRAM)
            .map(|h| u32::from_le_bytes([h[0], h[1], h[2], h[3]]));
        head == Some(self.head)
            && self.offsets[..usize::from(self.n)]
                .iter()
                .zip(&self.words)
                .all(|(&at, &w)| word(usize::from(at)) == Some(w))
    }

    fn ctx(&self) -> FrameCtx {
        FrameCtx {
            offsets: self.offsets,
            n: self.n,
            shape: self.id,
        }
    }
}

fn ps(ns: f64) -> u64 {
    (ns * PS_PER_NS as f64).round() as u64
}

/// Frames with more datagrams than this are never replayed (see `Esc::process_frame`).
const MAX_SHAPE_DATAGRAMS: usize = 8;

/// The processing order after port `p`: 0 -> PU -> 3 -> 1 -> 2 -> 0. `None` stands for the
/// processing unit.
const RING: [Option<usize>; 5] = [Some(0), None, Some(3), Some(1), Some(2)];

fn ring_pos(port: usize) -> usize {
    RING.iter().position(|x| *x == Some(port)).unwrap_or(0)
}

/// How the ESCs take a frame.
#[derive(Debug, Clone, Copy)]
enum FrameKind {
    /// A well-formed chain of at most [`MAX_SHAPE_DATAGRAMS`] datagrams.
    Chain(FrameCtx),
    /// A well-formed chain of more: each ESC walks it.
    Long,
    /// A malformed chain: forwarded untouched (each ESC counts the frame).
    Malformed,
}

impl Segment {
    /// Builds a segment. Slaves are renumbered in network order: the order in which a frame
    /// passes their processing units, which is their auto-increment position.
    pub fn new(spec: &[SlaveSpec]) -> Result<Self, TopologyError> {
        if spec.is_empty() {
            return Err(TopologyError::Empty);
        }
        let masters = spec
            .iter()
            .filter(|s| s.upstream == Upstream::Master)
            .count();
        if masters != 1 {
            return Err(TopologyError::MasterLinks(masters));
        }
        let mut links: Vec<[Option<Link>; 4]> = vec![[None; 4]; spec.len()];
        for (i, s) in spec.iter().enumerate() {
            if !(s.cable_m.is_finite() && s.cable_m >= 0.0) {
                return Err(TopologyError::BadNumber {
                    slave: i,
                    what: "cable_m",
                });
            }
            for (what, v) in [
                ("forwarding_delay_ns", s.model.forwarding_delay_ns),
                ("processing_delay_ns", s.model.processing_delay_ns),
                ("link_phy_delay_ns", s.model.link_phy_delay_ns),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(TopologyError::BadNumber { slave: i, what });
                }
            }
            let ep = s.entry_port;
            if ep > 3 || s.model.ports[usize::from(ep)] == PortKind::None {
                return Err(TopologyError::NoSuchPort { slave: i, port: ep });
            }
            if links[i][usize::from(ep)].is_some() {
                return Err(TopologyError::PortInUse { slave: i, port: ep });
            }
            let cable = s.cable_m * CABLE_PS_PER_M;
            match s.upstream {
                Upstream::Master => {
                    let delay = ps(s.model.link_phy_delay_ns) + cable.round() as u64;
                    links[i][usize::from(ep)] = Some(Link {
                        peer: Peer::Master,
                        peer_port: 0,
                        delay_ps: delay,
                    });
                }
                Upstream::Slave { index, port } => {
                    if index >= i {
                        return Err(TopologyError::BadUpstream {
                            slave: i,
                            upstream: index,
                        });
                    }
                    let up = &spec[index];
                    if port > 3 || up.model.ports[usize::from(port)] == PortKind::None {
                        return Err(TopologyError::NoSuchPort { slave: index, port });
                    }
                    if links[index][usize::from(port)].is_some() {
                        return Err(TopologyError::PortInUse { slave: index, port });
                    }
                    let phy = (s.model.link_phy_delay_ns + up.model.link_phy_delay_ns) / 2.0;
                    let delay = ps(phy) + cable.round() as u64;
                    links[i][usize::from(ep)] = Some(Link {
                        peer: Peer::Slave(index as u16),
                        peer_port: port,
                        delay_ps: delay,
                    });
                    links[index][usize::from(port)] = Some(Link {
                        peer: Peer::Slave(i as u16),
                        peer_port: ep,
                        delay_ps: delay,
                    });
                }
            }
        }
        // Network order: depth-first in processing order from the master's slave.
        let first = spec
            .iter()
            .position(|s| s.upstream == Upstream::Master)
            .unwrap_or(0);
        let mut order = Vec::with_capacity(spec.len());
        let mut stack = vec![(first, usize::from(spec[first].entry_port))];
        while let Some((i, entry)) = stack.pop() {
            order.push(i);
            // Children in processing order after the entry port, pushed in reverse so the first
            // is visited first.
            let start = ring_pos(entry);
            let mut children = Vec::new();
            for k in 1..5 {
                if let Some(p) = RING[(start + k) % 5]
                    && let Some(l) = links[i][p]
                    && let Peer::Slave(c) = l.peer
                {
                    children.push((usize::from(c), usize::from(l.peer_port)));
                }
            }
            for c in children.into_iter().rev() {
                stack.push(c);
            }
        }
        let mut new_index = vec![0u16; spec.len()];
        for (pos, &i) in order.iter().enumerate() {
            new_index[i] = pos as u16;
        }
        let nodes: Vec<Node> = order
            .iter()
            .map(|&i| {
                let s = &spec[i];
                let mut l = links[i];
                for link in l.iter_mut().flatten() {
                    if let Peer::Slave(p) = link.peer {
                        link.peer = Peer::Slave(new_index[usize::from(p)]);
                    }
                }
                let mut esc = Esc::new(s.model.clone(), s.device.clone(), s.crystal);
                esc.set_links([
                    l[0].is_some(),
                    l[1].is_some(),
                    l[2].is_some(),
                    l[3].is_some(),
                ]);
                let plan = build_plan(&esc, &l, usize::from(s.entry_port));
                Node {
                    esc,
                    links: l,
                    entry_port: s.entry_port,
                    forwarding_ps: ps(s.model.forwarding_delay_ns),
                    processing_ps: ps(s.model.processing_delay_ns),
                    plan,
                    off: false,
                }
            })
            .collect();
        let n = nodes.len();
        let unreached = Arc::new(Timing::unreached(n));
        Ok(Segment {
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
        })
    }

    /// Number of slaves.
    pub fn len(&self) -> usize {
        self.nodes.len()
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
        // Its counters are brought up to date first, and no plan holds past this.
        self.end_plans();
        self.epoch += 1;
        &mut self.nodes[pos].esc
    }

    /// Pulls (`up` false) or plugs in again the cable at port `port` of the slave at network
    /// position `pos`: both ends lose or regain their link, and a port in auto mode closes or
    /// opens (the datasheet's loop control), so the segment behind a pulled cable is gone and
    /// the port loops frames back. A slave that is switched off keeps its links down. Returns
    /// false if there is no cable there.
    pub fn set_link(&mut self, pos: usize, port: usize, up: bool) -> bool {
        let Some(l) = self
            .nodes
            .get(pos)
            .and_then(|n| n.links.get(port).copied().flatten())
        else {
            return false;
        };
        let here = up && !self.nodes[pos].off;
        self.set_port_link(pos, port, here);
        if let Peer::Slave(q) = l.peer {
            let q = usize::from(q);
            let there = up && !self.nodes[q].off;
            self.set_port_link(q, usize::from(l.peer_port), there);
        }
        true
    }

    fn set_port_link(&mut self, pos: usize, port: usize, up: bool) {
        let esc = self.esc_mut(pos);
        let mut links = esc.links();
        links[port] = up;
        esc.set_links(links);
        let node = &mut self.nodes[pos];
        node.plan = build_plan(&node.esc, &node.links, usize::from(node.entry_port));
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

    /// Ends the plan of shape slot `k`: the frames it passed by its idle ESCs go into their
    /// counters. Returns it, for its buffers.
    fn end_plan(&mut self, k: usize) -> Option<VisitPlan> {
        let mut p = self.plans[k].take()?;
        if p.idle_frames > 0 {
            for (node, _) in self
                .nodes
                .iter_mut()
                .zip(&p.idle)
                .filter(|(_, idle)| **idle)
            {
                node.esc.count_passed_frames(p.idle_frames);
            }
            p.idle_frames = 0;
        }
        for v in &mut p.visits {
            if let Some(steps) = &v.steps
                && v.replays > 0
            {
                self.nodes[v.slave as usize]
                    .esc
                    .count_planned_replays(steps, v.replays);
                v.replays = 0;
            }
        }
        Some(p)
    }

    fn end_plans(&mut self) {
        for k in 0..self.plans.len() {
            self.end_plan(k);
        }
    }

    /// Makes the visit plan of shape slot `k` for frames of `shape` after one has passed, if
    /// every ESC on the way has a program for it (see [`VisitPlan`]).
    fn make_plan(&mut self, k: usize, shape: u32, tm: &Arc<Timing>) {
        let all_recorded = tm
            .flat
            .iter()
            .all(|&(i, _)| self.nodes[i].esc.replays_nothing(shape).is_some());
        if !all_recorded {
            return;
        }
        // The old plan's buffers are reused: a plan is remade after every change of
        // configuration, and the cyclic phase allocates nothing.
        let mut p = self.end_plan(k).unwrap_or_else(|| VisitPlan {
            shape,
            epoch: self.epoch,
            timing: tm.clone(),
            visits: Vec::new(),
            idle: Vec::new(),
            idle_frames: 0,
        });
        p.shape = shape;
        p.epoch = self.epoch;
        p.timing = tm.clone();
        p.visits.clear();
        p.idle.clear();
        p.idle.resize(self.nodes.len(), false);
        for &(i, pu_ps) in &tm.flat {
            let esc = &self.nodes[i].esc;
            if esc.replays_nothing(shape) == Some(true) {
                p.idle[i] = true;
            } else {
                p.visits.push(PlannedVisit {
                    slave: i as u32,
                    pu_ps,
                    steps: esc.planned_steps(shape),
                    replays: 0,
                });
            }
        }
        self.plans[k] = Some(p);
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

    /// Passes a frame (Ethernet, no FCS) through the segment: every ESC processes it in place,
    /// as the wire would hand it back. `t_send_ps` is when its first bit leaves the master.
    pub fn process(&mut self, frame: &mut [u8], t_send_ps: u64) -> FrameOutcome {
        self.frames += 1;
        // The cyclic frames repeat: if the headers are those of a remembered shape, the chain
        // is the same and already validated (and it is an EtherCAT frame: the shape's first
        // bytes are the Ethernet type).
        let (kind, slot) = match self.shapes.find(frame) {
            Some((k, ctx)) if self.replay => (FrameKind::Chain(ctx), Some(k)),
            _ => match self.classify(frame) {
                Some(k) => k,
                None => {
                    // Forwarding rule (DL control bit 0 = 1, the default): non-EtherCAT
                    // frames are destroyed at the first port.
                    self.lost += 1;
                    self.trace = FrameTrace {
                        sent_ps: t_send_ps,
                        timing: self.unreached.clone(),
                    };
                    return FrameOutcome {
                        returned_sof_ps: None,
                        processed: false,
                    };
                }
            },
        };
        // Taken out while the ESCs run (no reference count moves per frame), put back unless
        // the frame changed a loop.
        let tm = match self.timing.take() {
            Some(t) => t,
            None => Arc::new(self.walk()),
        };
        self.trace.sent_ps = t_send_ps;
        if !Arc::ptr_eq(&self.trace.timing, &tm) {
            self.trace.timing = tm.clone();
        }
        // Visit plans pay where frames pass many ESCs by (see `PLAN_MIN_SLAVES`).
        // (Two copies of the pass: the small network's has no plan code at all.)
        let loops_changed = if self.nodes.len() >= PLAN_MIN_SLAVES {
            self.process_flat::<true>(frame, kind, slot, &tm, t_send_ps)
        } else {
            self.process_flat::<false>(frame, kind, None, &tm, t_send_ps)
        };
        let back = tm.back;
        if !loops_changed {
            self.timing = Some(tm);
        }
        match back {
            Some(back) => FrameOutcome {
                returned_sof_ps: Some(t_send_ps + back),
                processed: !matches!(kind, FrameKind::Malformed),
            },
            None => {
                self.lost += 1;
                FrameOutcome {
                    returned_sof_ps: None,
                    processed: !matches!(kind, FrameKind::Malformed),
                }
            }
        }
    }

    /// How the ESCs take a frame that is not of a remembered shape (`None`: not EtherCAT),
    /// remembering its shape (and its slot in the shape cache, whose plan then ends).
    fn classify(&mut self, frame: &[u8]) -> Option<(FrameKind, Option<usize>)> {
        if frame.len() < ETH_HEADER_LEN
            || EcatFrame::new_unchecked(frame).ethertype() != ETHERTYPE_ETHERCAT
        {
            return None;
        }
        let mut offsets = [0u16; MAX_SHAPE_DATAGRAMS];
        Some(match datagram_offsets(frame, &mut offsets) {
            Some(n) if n <= MAX_SHAPE_DATAGRAMS => {
                let (slot, shape) = if self.replay && n > 0 {
                    let (k, id) = self.shapes.insert(frame, &offsets[..n]);
                    if self.plans[k].as_ref().is_some_and(|p| p.shape != id) {
                        self.end_plan(k);
                    }
                    (Some(k), id)
                } else {
                    (None, 0)
                };
                let ctx = FrameCtx {
                    offsets,
                    n: n as u8,
                    shape,
                };
                (FrameKind::Chain(ctx), slot)
            }
            Some(_) => (FrameKind::Long, None),
            None => {
                self.malformed += 1;
                (FrameKind::Malformed, None)
            }
        })
    }

    /// Every processing unit the frame reaches, in turn at its time. Loop changes take effect
    /// after the frame has passed (datasheet section II, 0x0100): the frame follows the way it
    /// started on, the next one the new way. Returns whether a loop changed.
    fn process_flat<const PLANS: bool>(
        &mut self,
        frame: &mut [u8],
        kind: FrameKind,
        slot: Option<usize>,
        tm: &Arc<Timing>,
        t_send: u64,
    ) -> bool {
        if tm.flat.is_empty() {
            return false;
        }
        // Port 0 of the first ESC marks the source address as locally administered (every
        // later one sets the same bit again).
        mark_returned_frame(frame);
        self.long.usable = self.replay && matches!(kind, FrameKind::Long) && self.long.build(frame);
        let shape = match kind {
            FrameKind::Chain(ctx) => ctx.shape,
            _ => 0,
        };
        let mut pass = Pass {
            deferred: Deferred::default(),
            generation_changed: false,
            loops_changed: false,
        };
        // A frame of a shape with a plan that holds visits only the ESCs it does something at.
        let mut planned = false;
        let plan = match slot {
            Some(k) if PLANS && shape != 0 => match &mut self.plans[k] {
                Some(p) if p.holds(shape, self.epoch, tm) => {
                    planned = true;
                    p.idle_frames += 1;
                    // Only the visit list leaves the plan while the ESCs run (no copy of it).
                    Some((k, std::mem::take(&mut p.visits)))
                }
                Some(_) => {
                    self.end_plan(k);
                    None
                }
                None => None,
            },
            _ => None,
        };
        match plan {
            Some((k, mut visits)) => {
                self.visit_some(&mut visits, frame, kind, tm, t_send, &mut pass);
                if let Some(p) = &mut self.plans[k] {
                    p.visits = visits;
                }
            }
            None => {
                for &(i, pu) in &tm.flat {
                    self.visit(i, pu, frame, kind, tm, t_send, &mut pass);
                }
            }
        }
        pass.deferred.flush(frame);
        if pass.generation_changed || pass.loops_changed {
            // Some ESC acts differently from now on: no plan holds.
            self.epoch += 1;
        } else if PLANS
            && !planned
            && let Some(k) = slot
            && shape != 0
        {
            self.make_plan(k, shape, tm);
        }
        pass.loops_changed
    }

    /// The frame at the processing units of a plan's `visits`, each by its planned steps.
    /// Out of line: a small network's frames visit every ESC, in the loop above.
    #[inline(never)]
    fn visit_some(
        &mut self,
        visits: &mut [PlannedVisit],
        frame: &mut [u8],
        kind: FrameKind,
        tm: &Timing,
        t_send: u64,
        pass: &mut Pass,
    ) {
        for v in visits {
            let i = v.slave as usize;
            let t = t_send + v.pu_ps;
            let Some(steps) = &v.steps else {
                // No one-step program: by the ESC's program slot, as without a plan.
                self.visit(i, v.pu_ps, frame, kind, tm, t_send, pass);
                continue;
            };
            let esc = &mut self.nodes[i].esc;
            if esc.replay_planned(steps, frame, t, &mut pass.deferred) {
                v.replays += 1;
                continue;
            }
            // Steps that no longer hold (the ESC changed since the plan was made, outside a
            // frame's pass): the next frame makes the plan again.
            pass.generation_changed |= esc.planned_stale(steps);
            self.visit_in_full(i, t, frame, kind, tm, t_send, pass);
        }
    }

    /// The frame at the processing unit of slave `i`, `pu` ps after it was sent.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn visit(
        &mut self,
        i: usize,
        pu: u64,
        frame: &mut [u8],
        kind: FrameKind,
        tm: &Timing,
        t_send: u64,
        pass: &mut Pass,
    ) {
        let t = t_send + pu;
        if let FrameKind::Chain(ctx) = kind
            && self.nodes[i]
                .esc
                .replay_cyclic(frame, ctx.shape, t, &mut pass.deferred)
        {
            return;
        }
        self.visit_in_full(i, t, frame, kind, tm, t_send, pass);
    }

    /// The frame at slave `i`'s processing unit at `t` when no straight-through replay takes
    /// it: decoded (or replayed op by op), receive times latched, loops changed. Out of line:
    /// the cyclic frames' visits are the inline part above.
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn visit_in_full(
        &mut self,
        i: usize,
        t: u64,
        frame: &mut [u8],
        kind: FrameKind,
        tm: &Timing,
        t_send: u64,
        pass: &mut Pass,
    ) {
        let node = &mut self.nodes[i];
        let fx = match kind {
            FrameKind::Chain(ctx) => {
                pass.deferred.flush(frame);
                let offs = &ctx.offsets[..usize::from(ctx.n)];
                let generation = node.esc.generation();
                let e = node.esc.process_frame(frame, offs, ctx.shape, t);
                pass.generation_changed |= node.esc.generation() != generation;
                FrameEffects {
                    latch: e.latch_receive_times,
                    loops_changed: e.loops_changed,
                }
            }
            FrameKind::Long => {
                let generation = node.esc.generation();
                let fx = if self.long.usable {
                    let offs = self.long.for_esc(node.esc.configured_addresses());
                    let e = node.esc.process_frame(frame, offs, 0, t);
                    FrameEffects {
                        latch: e.latch_receive_times,
                        loops_changed: e.loops_changed,
                    }
                } else {
                    process_long_frame(&mut node.esc, frame, t)
                };
                pass.generation_changed |= node.esc.generation() != generation;
                fx
            }
            FrameKind::Malformed => {
                node.esc.count_frame();
                FrameEffects::default()
            }
        };
        if fx.latch {
            let res = node.esc.model().ports.map(|k| k.stamp_resolution_ns());
            let ports = tm.ports[i].map(|o| o.map(|o| t_send + o));
            // The processing unit's stamp equals port 0's when the frame entered there.
            let entered_at_0 = tm.in_port[i] == 0;
            if let Some(dc) = node.esc.dc_mut() {
                dc.latch(ports, t, entered_at_0, res);
            }
        }
        if fx.loops_changed {
            pass.loops_changed = true;
            node.plan = build_plan(&node.esc, &node.links, usize::from(node.entry_port));
        }
    }

    /// The frame's way through the segment, by walking the ports in processing order from the
    /// master's slave: the one walk every frame's timing and the ground truth come from.
    fn walk(&self) -> Timing {
        let n = self.nodes.len();
        let mut t = Timing::unreached(n);
        let first = usize::from(self.first);
        let entry = usize::from(self.nodes[first].entry_port);
        // (The master's cable pulled, or the first slave off: every frame is lost.)
        if let Some(l) = self.nodes[first].links[entry]
            && self.nodes[first].esc.links()[entry]
        {
            t.back = self
                .walk_from(first, entry, l.delay_ps, &mut t)
                .map(|b| b + l.delay_ps);
        }
        t
    }

    /// The walk inside slave `idx`, entered through `in_port` at `t_in`: where it returns the
    /// frame (`None`: lost in it or below it).
    fn walk_from(&self, idx: usize, in_port: usize, t_in: u64, t: &mut Timing) -> Option<u64> {
        let node = &self.nodes[idx];
        let plan = if in_port == usize::from(node.entry_port) {
            node.plan
        } else {
            build_plan(&node.esc, &node.links, in_port)
        };
        t.ports[idx][in_port] = Some(t_in);
        t.in_port[idx] = in_port as u8;
        let mut t_cur = t_in;
        let mut through_pu = false;
        for step in &plan.steps[..usize::from(plan.len)] {
            match *step {
                Step::Pu => {
                    through_pu = true;
                    t.pu[idx] = Some(t_cur);
                    t.flat.push((idx, t_cur));
                }
                Step::Lost => return None,
                Step::Port(p, link) => {
                    let d = if through_pu {
                        node.processing_ps
                    } else {
                        node.forwarding_ps
                    };
                    through_pu = false;
                    // A second cable to the master (redundancy) is not modelled.
                    let Peer::Slave(peer) = link.peer else {
                        return None;
                    };
                    let back = self.walk_from(
                        usize::from(peer),
                        usize::from(link.peer_port),
                        t_cur + d + link.delay_ps,
                        t,
                    )?;
                    t_cur = back + link.delay_ps;
                    t.ports[idx][usize::from(p)] = Some(t_cur);
                }
            }
        }
        Some(
            t_cur
                + if through_pu {
                    node.processing_ps
                } else {
                    node.forwarding_ps
                },
        )
    }

    /// Time from the master sending a frame to its first bit reaching each slave's processing
    /// unit, ps (`None`: not reached): the static ground truth of propagation (the same for
    /// every frame while the loops do not change).
    pub fn pu_offsets_ps(&self) -> Vec<Option<u64>> {
        match &self.timing {
            Some(t) => t.pu.clone(),
            None => self.walk().pu,
        }
    }

    /// Twice the time from the master to the farthest processing unit, ps: how long a frame's
    /// first bit takes round the segment and back, past its own length on the wire.
    pub fn round_trip_ps(&self) -> u64 {
        2 * self
            .pu_offsets_ps()
            .iter()
            .flatten()
            .max()
            .copied()
            .unwrap_or(0)
    }

    /// True propagation delay from the reference's processing unit to each slave's, ns: what
    /// 0x0928 should hold. `None` for slaves the frame does not reach.
    pub fn true_delays_ns(&self, reference: usize) -> Vec<Option<f64>> {
        let off = self.pu_offsets_ps();
        let r = off[reference];
        off.iter()
            .map(|o| match (o, r) {
                (Some(o), Some(r)) => Some((*o as f64 - r as f64) / PS_PER_NS as f64),
                _ => None,
            })
            .collect()
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

/// A long frame's datagrams (more than a shape holds: the bring-up's per-slave exchanges of a
/// large network, one FPRD or FPWR per slave) sorted by the station they name, so that each ESC
/// takes the ones that name it and those that address every ESC, in frame order, instead of
/// walking hundreds it would pass by: the same effects (a configured-address datagram that names
/// another station does nothing at an ESC but pass, FRMW aside, which every ESC takes) at a cost
/// that no longer grows with the square of the network. Not used where a datagram of the frame
/// could change whom a later one names (a write of the station address, the alias or DL control,
/// a logical write, a read-write command, which writes at the physical R/W offset) or where the
/// chain is too long to list.
#[derive(Debug, Clone, Default)]
struct LongIndex {
    /// Whether the frame being passed is indexed.
    usable: bool,
    /// Offsets of the datagrams every ESC takes (position, broadcast, logical, FRMW, NOP).
    everyone: Vec<u16>,
    /// (station, offset) of the other configured-address datagrams, sorted.
    by_station: Vec<(u16, u16)>,
    /// The offsets one ESC takes, in frame order.
    subset: Vec<u16>,
}

impl LongIndex {
    /// Indexes `frame`'s datagrams; false where it cannot be (see [`LongIndex`]).
    fn build(&mut self, frame: &[u8]) -> bool {
        let mut all = [0u16; 256];
        let Some(m) = datagram_offsets(frame, &mut all).filter(|&m| m <= all.len()) else {
            return false;
        };
        self.everyone.clear();
        self.by_station.clear();
        for &at in &all[..m] {
            let d = ecsync_wire::Datagram::new_unchecked(&frame[usize::from(at)..]);
            let Ok(cmd) = d.command() else {
                self.everyone.push(at);
                continue;
            };
            let (lo, hi) = (usize::from(d.ado()), usize::from(d.ado()) + d.data_len());
            let names_whom = |a: usize, b: usize| lo < b && a < hi;
            // (A read-write command writes at the physical R/W offset of 0x0108 from its
            // address, which an earlier datagram may have set: not indexed at all.)
            let read_write =
                cmd.reads() && cmd.writes() && !matches!(cmd, Command::Frmw | Command::Armw);
            if read_write {
                return false;
            }
            if cmd.writes()
                && (cmd.address_mode() == AddressMode::Logical
                    || names_whom(
                        usize::from(reg::STATION_ADDRESS),
                        usize::from(reg::STATION_ALIAS) + 2,
                    )
                    || names_whom(
                        usize::from(reg::DL_CONTROL),
                        usize::from(reg::DL_CONTROL) + 4,
                    ))
            {
                return false;
            }
            if cmd.address_mode() == AddressMode::Configured && cmd != Command::Frmw {
                self.by_station.push((d.adp(), at));
            } else {
                self.everyone.push(at);
            }
        }
        self.by_station.sort_unstable();
        true
    }

    /// The offsets an ESC named by `addresses` (station, alias) takes, in frame order.
    fn for_esc(&mut self, (station, alias): (u16, Option<u16>)) -> &[u16] {
        self.subset.clear();
        self.subset.extend_from_slice(&self.everyone);
        for a in std::iter::once(station).chain(alias.filter(|&a| a != station)) {
            let from = self.by_station.partition_point(|&(s, _)| s < a);
            self.subset.extend(
                self.by_station[from..]
                    .iter()
                    .take_while(|&&(s, _)| s == a)
                    .map(|&(_, at)| at),
            );
        }
        self.subset.sort_unstable();
        &self.subset
    }
}

/// A frame with more datagrams than the replay handles: walked at each ESC, never cached.
#[cold]
#[inline(never)]
fn process_long_frame(esc: &mut Esc, frame: &mut [u8], t_ps: u64) -> FrameEffects {
    let mut all = [0u16; 256];
    match datagram_offsets(frame, &mut all) {
        Some(m) if m <= all.len() => {
            let e = esc.process_frame(frame, &all[..m], 0, t_ps);
            FrameEffects {
                latch: e.latch_receive_times,
                loops_changed: e.loops_changed,
            }
        }
        _ => {
            esc.count_frame();
            process_datagrams(esc, frame, t_ps)
        }
    }
}

/// What the segment knows about a frame before it enters the first ESC.
#[derive(Debug, Clone, Copy)]
struct FrameCtx {
    offsets: [u16; MAX_SHAPE_DATAGRAMS],
    /// Datagrams in `offsets`; 0 with `shape` 0 means more than fit (walked per ESC).
    n: u8,
    shape: u32,
}

/// Offsets of the datagrams of a well-formed EtherCAT command frame; `None` if malformed.
/// Returns the number of datagrams, which may exceed `out.len()` (then `out` is partial).
fn datagram_offsets(frame: &[u8], out: &mut [u16]) -> Option<usize> {
    let f = EcatFrame::new_checked(frame).ok()?;
    let mut n = 0;
    let mut iter = f.datagrams();
    loop {
        let at = EcatFrame::<&[u8]>::first_datagram_offset() + iter.offset();
        match iter.next() {
            None => break,
            Some(Err(_)) => return None,
            Some(Ok(_)) => {
                if n < out.len() {
                    out[n] = at as u16;
                }
                n += 1;
            }
        }
    }
    Some(n)
}

/// What a frame's pass through the segment did so far.
#[derive(Debug)]
struct Pass {
    deferred: Deferred,
    generation_changed: bool,
    loops_changed: bool,
}

#[derive(Debug, Clone, Copy, Default)]
struct FrameEffects {
    latch: bool,
    loops_changed: bool,
}

/// Processes every datagram of a validated frame at an ESC.
fn process_datagrams(esc: &mut Esc, frame: &mut [u8], t_ps: u64) -> FrameEffects {
    let fx = esc.process_chain(frame, t_ps);
    FrameEffects {
        latch: fx.latch_receive_times,
        loops_changed: fx.loops_changed,
    }
}
