//! A frame's pass through the segment: classified, then replayed along its shape's plan or
//! processed datagram by datagram at each ESC in the order the frame reaches them.

use super::plans::{FrameCtx, MAX_SHAPE_DATAGRAMS, PLAN_MIN_SLAVES, PlannedVisit};
use super::topology::{Timing, build_plan};
use super::*;

/// How the ESCs take a frame.
#[derive(Debug, Clone, Copy)]
pub(super) enum FrameKind {
    /// A well-formed chain of at most [`MAX_SHAPE_DATAGRAMS`] datagrams.
    Chain(FrameCtx),
    /// A well-formed chain of more: each ESC walks it.
    Long,
    /// A malformed chain: forwarded untouched (each ESC counts the frame).
    Malformed,
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
pub(super) struct LongIndex {
    /// Whether the frame being passed is indexed.
    pub(super) usable: bool,
    /// Offsets of the datagrams every ESC takes (position, broadcast, logical, FRMW, NOP).
    pub(super) everyone: Vec<u16>,
    /// (station, offset) of the other configured-address datagrams, sorted.
    pub(super) by_station: Vec<(u16, u16)>,
    /// The offsets one ESC takes, in frame order.
    pub(super) subset: Vec<u16>,
}

impl LongIndex {
    /// Indexes `frame`'s datagrams; false where it cannot be (see [`LongIndex`]).
    pub(super) fn build(&mut self, frame: &[u8]) -> bool {
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
    pub(super) fn for_esc(&mut self, (station, alias): (u16, Option<u16>)) -> &[u16] {
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
pub(super) fn process_long_frame(esc: &mut Esc, frame: &mut [u8], t_ps: u64) -> FrameEffects {
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

/// Offsets of the datagrams of a well-formed EtherCAT command frame; `None` if malformed.
/// Returns the number of datagrams, which may exceed `out.len()` (then `out` is partial).
pub(super) fn datagram_offsets(frame: &[u8], out: &mut [u16]) -> Option<usize> {
    let f = EcatFrame::new_checked(frame).ok()?;
    let mut n = 0;
    for (at, d) in f.datagrams().with_frame_offsets() {
        d.ok()?;
        if n < out.len() {
            out[n] = at as u16;
        }
        n += 1;
    }
    Some(n)
}

/// What a frame's pass through the segment did so far.
#[derive(Debug)]
pub(super) struct Pass {
    pub(super) deferred: Deferred,
    pub(super) generation_changed: bool,
    pub(super) loops_changed: bool,
}

#[derive(Debug, Clone, Copy, Default)]
pub(super) struct FrameEffects {
    pub(super) latch: bool,
    pub(super) loops_changed: bool,
}

/// Processes every datagram of a validated frame at an ESC.
pub(super) fn process_datagrams(esc: &mut Esc, frame: &mut [u8], t_ps: u64) -> FrameEffects {
    let fx = esc.process_chain(frame, t_ps);
    FrameEffects {
        latch: fx.latch_receive_times,
        loops_changed: fx.loops_changed,
    }
}

impl Segment {
    /// Passes a frame (Ethernet, no FCS) through the segment: every ESC processes it in place,
    /// as the wire would hand it back. `t_send_ps` is when its first bit leaves the master.
    pub fn process(&mut self, frame: &mut [u8], t_send_ps: u64) -> FrameOutcome {
        self.frames += 1;
        let fcs_breaks = std::mem::take(&mut self.fcs_break_pending);
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
                        returned_port: 0,
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
        let (back, returned_port) = (tm.back, tm.back_port);
        if fcs_breaks && back.is_some() {
            self.count_broken_fcs(&tm.flat);
        }
        if !loops_changed {
            self.timing = Some(tm);
        } else {
            self.timing_secondary = None;
        }
        self.outcome(back.map(|b| t_send_ps + b), kind, returned_port)
    }

    fn outcome(&mut self, returned_sof_ps: Option<u64>, kind: FrameKind, port: u8) -> FrameOutcome {
        if returned_sof_ps.is_none() {
            self.lost += 1;
        }
        FrameOutcome {
            returned_sof_ps,
            processed: !matches!(kind, FrameKind::Malformed),
            returned_port: port,
        }
    }

    /// [`Segment::process`] for a frame the master sends on its second port (a ring's:
    /// [`Segment::connect_ring`]; without one it is lost). Frames on this port are few (a
    /// redundant master's copy of each cycle's frame): no visit plan, every ESC on the way
    /// takes it in full.
    pub fn process_secondary(&mut self, frame: &mut [u8], t_send_ps: u64) -> FrameOutcome {
        self.frames += 1;
        let kind = match self.shapes.find(frame) {
            Some((_, ctx)) if self.replay => FrameKind::Chain(ctx),
            _ => match self.classify(frame) {
                Some((k, _)) => k,
                None => {
                    self.trace = FrameTrace {
                        sent_ps: t_send_ps,
                        timing: self.unreached.clone(),
                    };
                    return self.outcome(None, FrameKind::Malformed, 1);
                }
            },
        };
        let tm = match self.timing_secondary.take() {
            Some(t) => t,
            None => Arc::new(self.walk_secondary()),
        };
        self.trace = FrameTrace {
            sent_ps: t_send_ps,
            timing: tm.clone(),
        };
        let loops_changed = self.process_flat::<false>(frame, kind, None, &tm, t_send_ps);
        let (back, port) = (tm.back, tm.back_port);
        if loops_changed {
            self.timing = None;
        } else {
            self.timing_secondary = Some(tm);
        }
        self.outcome(back.map(|b| t_send_ps + b), kind, port)
    }

    /// How the ESCs take a frame that is not of a remembered shape (`None`: not EtherCAT),
    /// remembering its shape (and its slot in the shape cache, whose plan then ends).
    pub(super) fn classify(&mut self, frame: &[u8]) -> Option<(FrameKind, Option<usize>)> {
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
    pub(super) fn process_flat<const PLANS: bool>(
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
    pub(super) fn visit_some(
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
    pub(super) fn visit(
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
    pub(super) fn visit_in_full(
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
}
