//! The segment's shape: slaves, cables and ports, and the way a frame walks them (its timing
//! relative to its send time, walked again only when a loop changes).

use super::*;

#[derive(Debug, Clone, Copy)]
pub(super) enum Peer {
    Master,
    Slave(u16),
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Link {
    pub(super) peer: Peer,
    pub(super) peer_port: u8,
    pub(super) delay_ps: u64,
}

#[derive(Debug, Clone)]
pub(super) struct Node {
    pub(super) esc: Esc,
    pub(super) links: [Option<Link>; 4],
    pub(super) entry_port: u8,
    pub(super) forwarding_ps: u64,
    pub(super) processing_ps: u64,
    /// What a frame entering at `entry_port` meets, in processing order (rebuilt when the
    /// master changes the loop settings).
    pub(super) plan: Plan,
    /// Switched off (a power cycle in progress): its links are down.
    pub(super) off: bool,
}

/// One element of a frame's way through an ESC.
#[derive(Debug, Clone, Copy)]
pub(super) enum Step {
    /// The processing unit.
    Pu,
    /// An open port with a cable: out and back.
    Port(u8, Link),
    /// A port forced open without a link: the frame is lost there.
    Lost,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Plan {
    pub(super) steps: [Step; 5],
    pub(super) len: u8,
}

pub(super) fn build_plan(esc: &Esc, links: &[Option<Link>; 4], entry: usize) -> Plan {
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

/// Where a frame's first bit is, relative to the moment it left the master: the traversal's
/// timing depends on the topology, the delays and the loop settings only, never on the frame.
/// One walk of the ports ([`Segment::walk`]) computes it; every frame, replayed or decoded,
/// then meets the processing units in its order at its times.
#[derive(Debug)]
pub(super) struct Timing {
    /// Per slave: arrival at the processing unit, ps after the send (`None`: not reached).
    pub(super) pu: Vec<Option<u64>>,
    /// Per slave: arrival at each port, ps after the send.
    pub(super) ports: Vec<[Option<u64>; 4]>,
    /// Per slave: the port the frame came in through.
    pub(super) in_port: Vec<u8>,
    /// Back at the master, ps after the send; `None` if the frame is lost on the way.
    pub(super) back: Option<u64>,
    /// The master's port it comes back on: 0 its first, 1 its second (a ring's: the frame
    /// left the segment through the cable of [`Segment::connect_ring`]).
    pub(super) back_port: u8,
    /// The slaves in the order their processing units see the frame, with their `pu`.
    pub(super) flat: Vec<(usize, u64)>,
}

impl Timing {
    pub(super) fn unreached(n: usize) -> Timing {
        Timing {
            pu: vec![None; n],
            ports: vec![[None; 4]; n],
            in_port: vec![0; n],
            back: None,
            back_port: 0,
            flat: Vec::new(),
        }
    }
}

pub(super) fn ps(ns: f64) -> u64 {
    (ns * PS_PER_NS as f64).round() as u64
}

/// The processing order after port `p`: 0 -> PU -> 3 -> 1 -> 2 -> 0. `None` stands for the
/// processing unit.
pub(super) const RING: [Option<usize>; 5] = [Some(0), None, Some(3), Some(1), Some(2)];

pub(super) fn ring_pos(port: usize) -> usize {
    RING.iter().position(|x| *x == Some(port)).unwrap_or(0)
}

/// A segment's slaves (at least one), exactly one of them connected to the master.
pub(super) fn check_one_master(spec: &[SlaveSpec]) -> Result<(), TopologyError> {
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
    Ok(())
}

/// Every slave's links by port, in the spec's order: each slave's numbers checked, then its
/// cable up connected at both ends.
pub(super) fn link_slaves(spec: &[SlaveSpec]) -> Result<Vec<[Option<Link>; 4]>, TopologyError> {
    let mut links: Vec<[Option<Link>; 4]> = vec![[None; 4]; spec.len()];
    for (i, s) in spec.iter().enumerate() {
        check_numbers(i, s)?;
        link_upstream(spec, i, &mut links)?;
    }
    Ok(links)
}

/// Slave `i`'s cable length and delays are finite and not negative.
fn check_numbers(i: usize, s: &SlaveSpec) -> Result<(), TopologyError> {
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
    Ok(())
}

/// Slave `i`'s cable from its entry port to its upstream (the master, or a port of a slave
/// before it), in `links` at both ends: the ports exist and are free. Its delay is the PHYs'
/// (their mean between two slaves) and the cable's.
fn link_upstream(
    spec: &[SlaveSpec],
    i: usize,
    links: &mut [[Option<Link>; 4]],
) -> Result<(), TopologyError> {
    let s = &spec[i];
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
    Ok(())
}

/// The slaves' spec indices in network order: depth-first in processing order from the
/// master's slave.
pub(super) fn network_order(spec: &[SlaveSpec], links: &[[Option<Link>; 4]]) -> Vec<usize> {
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
    order
}

/// The slaves as nodes in network `order`: each ESC powered up with its links (their peers
/// renumbered to network positions) and its way through the ports planned.
pub(super) fn build_nodes(
    spec: &[SlaveSpec],
    links: &[[Option<Link>; 4]],
    order: &[usize],
) -> Vec<Node> {
    let mut new_index = vec![0u16; spec.len()];
    for (pos, &i) in order.iter().enumerate() {
        new_index[i] = pos as u16;
    }
    order
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
        .collect()
}

/// Why a frame's walk through a slave did not return through the port it came in by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Gone {
    /// Lost (a port forced open without a link).
    Lost,
    /// Out of the segment to the master, through a ring's second cable ([`Timing::back_port`]).
    Exited,
}

impl Segment {
    /// The frame's way through the segment, by walking the ports in processing order from the
    /// master's slave: the one walk every frame's timing and the ground truth come from.
    pub(super) fn walk(&self) -> Timing {
        let first = usize::from(self.first);
        self.walk_in(first, usize::from(self.nodes[first].entry_port), 0)
    }

    /// The way of a frame the master sends on its second port, into a ring's last slave
    /// ([`Segment::connect_ring`]); unreached without a ring.
    pub(super) fn walk_secondary(&self) -> Timing {
        match self.ring {
            Some((pos, port)) => self.walk_in(usize::from(pos), usize::from(port), 1),
            None => Timing::unreached(self.nodes.len()),
        }
    }

    /// The walk of a frame the master sends on its port `master_port`, which is cabled to
    /// port `entry` of slave `first`.
    fn walk_in(&self, first: usize, entry: usize, master_port: u8) -> Timing {
        let mut t = Timing::unreached(self.nodes.len());
        // (The master's cable pulled, or the first slave off: every frame is lost.)
        if let Some(l) = self.nodes[first].links[entry]
            && self.nodes[first].esc.links()[entry]
        {
            match self.walk_from(first, entry, l.delay_ps, &mut t) {
                Ok(b) => {
                    t.back = Some(b + l.delay_ps);
                    t.back_port = master_port;
                }
                // (Where it left is in `t` already.)
                Err(Gone::Exited) => {}
                Err(Gone::Lost) => t.back = None,
            }
        }
        t
    }

    /// The walk inside slave `idx`, entered through `in_port` at `t_in`: where it returns the
    /// frame, or why it does not (lost in it or below it; out to the master through a ring's
    /// second cable).
    pub(super) fn walk_from(
        &self,
        idx: usize,
        in_port: usize,
        t_in: u64,
        t: &mut Timing,
    ) -> Result<u64, Gone> {
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
                Step::Lost => return Err(Gone::Lost),
                Step::Port(p, link) => {
                    let d = if through_pu {
                        node.processing_ps
                    } else {
                        node.forwarding_ps
                    };
                    through_pu = false;
                    let Peer::Slave(peer) = link.peer else {
                        // A ring's cable back to the master: the frame leaves the segment.
                        t.back = Some(t_cur + d + link.delay_ps);
                        t.back_port = link.peer_port;
                        return Err(Gone::Exited);
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
        Ok(t_cur
            + if through_pu {
                node.processing_ps
            } else {
                node.forwarding_ps
            })
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

    /// How long a frame's first bit takes round the segment and back to the master, past its
    /// own length on the wire, ps. In a tree that is not twice the time to the farthest
    /// processing unit: the last branch's drives are reached after the first branches' way
    /// round, and the frame comes back from them through their branch alone (a tree of 20
    /// lines of 100 drives: 1 963 us round, where twice the farthest is 3 827 us). A segment
    /// whose frames do not come back (a loop opened onto a dead cable): twice the time to the
    /// farthest processing unit.
    pub fn round_trip_ps(&self) -> u64 {
        let back = match &self.timing {
            Some(t) => t.back,
            None => self.walk().back,
        };
        back.unwrap_or_else(|| {
            2 * self
                .pu_offsets_ps()
                .iter()
                .flatten()
                .max()
                .copied()
                .unwrap_or(0)
        })
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
}
