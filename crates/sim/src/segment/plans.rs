//! The fast path's memory: the frame shapes seen recently (a four-way set-associative cache on
//! the first datagram's command and address) and, in large networks, the visit plan of each shape:
//! the ESCs a frame of that shape does something at. `tests/replay_equivalence.rs` is its
//! contract: the same bytes and figures as the full path.

use super::topology::Timing;
use super::*;

/// The smallest network whose frames follow visit plans. Below, a cycle's one or few frames do
/// something at nearly every ESC, and the replay of an empty program costs less than the plan's
/// upkeep; the results are the same either way.
pub(super) const PLAN_MIN_SLAVES: usize = 32;

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
pub(super) struct VisitPlan {
    pub(super) shape: u32,
    pub(super) epoch: u64,
    pub(super) timing: Arc<Timing>,
    /// The ESCs the frame does something at, in the walk's order, with their steps.
    pub(super) visits: Vec<PlannedVisit>,
    /// Per slave: the frame passes by it doing nothing.
    pub(super) idle: Vec<bool>,
    /// Frames passed by the idle ESCs and not yet in their counters.
    pub(super) idle_frames: u64,
}

/// One visit of a [`VisitPlan`]: the slave, when the frame reaches its processing unit, and
/// its one-step program for the frame (`None`: looked up by program slot, replayed op by op
/// or decoded, as without a plan). The plan's visits lie one after the other in the order
/// they are made, so a large network's cycle reads its steps as a stream rather than from
/// each ESC's program slots.
#[derive(Debug, Clone, Copy)]
pub(super) struct PlannedVisit {
    pub(super) slave: u32,
    pub(super) pu_ps: u64,
    pub(super) steps: Option<crate::esc::PlannedSteps>,
    /// Frames its steps replayed and not yet in the ESC's counters (brought up to date as the
    /// idle frames are: the visit touches nothing of the ESC's counters).
    pub(super) replays: u64,
}

const _: () = assert!(size_of::<PlannedVisit>() <= 64);

impl VisitPlan {
    pub(super) fn holds(&self, shape: u32, epoch: u64, tm: &Arc<Timing>) -> bool {
        self.shape == shape && self.epoch == epoch && Arc::ptr_eq(&self.timing, tm)
    }
}

/// A frame shape: the Ethernet type and EtherCAT header, then per datagram its first 8 header
/// bytes but the index, and the last 2 (command, address, length and flags, IRQ), as words for the
/// comparison every cyclic frame makes; where the datagrams are; and the id the ESCs key their
/// recorded programs on.
#[derive(Debug, Clone, Copy)]
pub(super) struct Shape {
    pub(super) head: u32,
    pub(super) words: [(u64, u16); MAX_SHAPE_DATAGRAMS],
    pub(super) offsets: [u16; MAX_SHAPE_DATAGRAMS],
    pub(super) n: u8,
    /// The frame length the chain needs.
    pub(super) min_len: usize,
    pub(super) id: u32,
}

/// Recently seen frame shapes, four-way set-associative on the first datagram's command and
/// address (which the frames of one cycle do not share): a cycle of several frames finds each of
/// its shapes again without decoding, where one remembered shape would be replaced at every
/// frame; the other ways keep shapes whose command and address fall in one set (the first
/// frame's FRMW and an LRW of a 1 000-drive cycle) from replacing each other every cycle. With
/// two ways and 128 sets, the FRMW and two LRWs of a 5 000-drive cycle (117 frames, 166 KiB of
/// image) fell in one set: all three were decoded anew at every ESC every cycle, 15 000 full
/// passes a cycle and 12.8x the six-drive cost per slave-cycle.
#[derive(Debug, Clone)]
pub(super) struct ShapeCache {
    pub(super) slots: Box<[Option<Shape>; SHAPE_SLOTS]>,
    /// Per set: the way the next new shape takes when none is empty (the set's ways in turn:
    /// a cycle of up to four shapes in one set keeps them all).
    pub(super) next_way: Box<[u8; SHAPE_SETS]>,
    pub(super) last_id: u32,
}

/// Sets of the shape cache: the LRWs of an image of up to 256 KiB (7 500 drives of 34 bytes)
/// each have a set of their own.
pub(super) const SHAPE_SETS: usize = 256;
/// Ways per set.
pub(super) const SHAPE_WAYS: usize = 4;
/// The shapes remembered at once.
pub(super) const SHAPE_SLOTS: usize = SHAPE_WAYS * SHAPE_SETS;

impl ShapeCache {
    pub(super) fn new() -> Self {
        ShapeCache {
            slots: Box::new([None; SHAPE_SLOTS]),
            next_way: Box::new([0; SHAPE_SETS]),
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
    pub(super) fn set_of(frame: &[u8]) -> usize {
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
    pub(super) fn find(&self, frame: &[u8]) -> Option<(usize, FrameCtx)> {
        let set = Self::set_of(frame);
        for way in 0..SHAPE_WAYS {
            let k = SHAPE_WAYS * set + way;
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
    /// id. A new shape takes an empty way of its set, else the set's ways in turn.
    pub(super) fn insert(&mut self, frame: &[u8], offsets: &[u16]) -> (usize, u32) {
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
        let base = SHAPE_WAYS * set;
        for way in 0..SHAPE_WAYS {
            if let Some(old) = &self.slots[base + way]
                && old.n == s.n
                && old.offsets == s.offsets
                && old.matches(frame)
            {
                return (base + way, old.id);
            }
        }
        let way = match (0..SHAPE_WAYS).find(|&w| self.slots[base + w].is_none()) {
            Some(w) => w,
            None => {
                let w = usize::from(self.next_way[set]);
                self.next_way[set] = ((w + 1) % SHAPE_WAYS) as u8;
                w
            }
        };
        self.last_id = self.last_id.wrapping_add(1).max(1);
        s.id = self.last_id;
        self.slots[base + way] = Some(s);
        (base + way, s.id)
    }
}

impl Shape {
    /// Whether the frame's Ethernet type, EtherCAT header and datagram headers are this
    /// shape's.
    #[inline]
    pub(super) fn matches(&self, frame: &[u8]) -> bool {
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

    pub(super) fn ctx(&self) -> FrameCtx {
        FrameCtx {
            offsets: self.offsets,
            n: self.n,
            shape: self.id,
        }
    }
}

/// Frames with more datagrams than this are never replayed (the ESCs record no program for
/// them: see `Esc::process_frame`).
pub(super) const MAX_SHAPE_DATAGRAMS: usize = crate::esc::MAX_PROGRAM_DATAGRAMS;

impl Segment {
    /// Ends the plan of shape slot `k`: the frames it passed by its idle ESCs go into their
    /// counters. Returns it, for its buffers.
    pub(super) fn end_plan(&mut self, k: usize) -> Option<VisitPlan> {
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

    pub(super) fn end_plans(&mut self) {
        for k in 0..self.plans.len() {
            self.end_plan(k);
        }
    }

    /// Makes the visit plan of shape slot `k` for frames of `shape` after one has passed, if
    /// every ESC on the way has a program for it (see [`VisitPlan`]).
    pub(super) fn make_plan(&mut self, k: usize, shape: u32, tm: &Arc<Timing>) {
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
}

/// What the segment knows about a frame before it enters the first ESC.
#[derive(Debug, Clone, Copy)]
pub(super) struct FrameCtx {
    pub(super) offsets: [u16; MAX_SHAPE_DATAGRAMS],
    /// Datagrams in `offsets`; 0 with `shape` 0 means more than fit (walked per ESC).
    pub(super) n: u8,
    pub(super) shape: u32,
}
