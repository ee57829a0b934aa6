//! The segment's tree and propagation delays, from what a master can read: which ports are open
//! (DL status 0x0110) and the port receive times latched by one BWR to 0x0900.
//!
//! # Tree
//!
//! Slaves are numbered in network order, the order in which a frame passes their processing
//! units. A frame visits a slave's ports in the order 0 -> processing unit -> 3 -> 1 -> 2, so
//! network order is a depth-first walk of the tree that visits each slave's children in that port
//! order. Walking the slaves in network order, each one hangs on the most recent slave that still
//! has an open port without a child; slaves whose ports are all used are finished.
//!
//! # Delays
//!
//! For a slave X whose nearest ancestor with receive times is A, reached through A's port `c`
//! (the ports before `c` in A's order, starting at its entry port, being `p0 .. prev`):
//!
//! ```text
//! arrival(X) = arrival(A) + (t_A[prev] - t_A[entry]) + (t_A[c] - t_A[prev] - loop(X)) / 2 + k
//! loop(X)    = t_X[last open port] - t_X[entry]
//! ```
//!
//! `t_A[c] - t_A[prev]` is the round trip from A's port `prev` through everything behind `c`;
//! removing X's own loop leaves the path from A to X and back. The cables are symmetric, the
//! ESCs are not: the way out leaves A through its processing delay tP (when `prev` is A's entry
//! port 0, the processing unit sitting between ports 0 and 3) or its forwarding delay tF, and
//! crosses every 2-port slave without receive times between A and X through *its* processing
//! unit (tP) where the way back forwards (tF); the way back leaves X through tP if X has no
//! other open port, else tF. Half the round trip therefore misses
//! `k = (out_A - back_X + sum(tP_n - tF_n)) / 2` of the true one-way time, which the master can
//! add when it knows the ESCs' delays (ESI; for identical ESCs only tDiff = tP - tF matters,
//! datasheet section I table 30). With all delays unknown (zero) this is the formula of SOEM and
//! ethercrab, generalised to any tree. Slaves without receive times must have at most two open
//! ports (datasheet: "devices with more than two ports must support at least receive times").
//!
//! The delay of X relative to the reference R is `arrival(X) - arrival(R)`: what 0x0928 holds.

use ecsync_wire::dc_time::diff_u32;

/// What the master read from one slave.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SlavePorts {
    /// Ports that forward (link up and loop open, from DL status 0x0110).
    pub open: [bool; 4],
    /// Receive times of ports 0..3 (0x0900..0x090F), if the slave has them.
    pub times: Option<[u32; 4]>,
    /// Forwarding delay tF of this slave's ESC, ns (from the ESI; 0 if unknown).
    pub forwarding_ns: i32,
    /// Processing delay tP of this slave's ESC, ns (from the ESI; 0 if unknown).
    pub processing_ns: i32,
    /// Rate of this slave's local clock relative to the master's time base (1 + frequency
    /// error), if measured; 0 means unknown (taken as 1). Spans between receive stamps are
    /// local-time durations: over a 100 us round trip a 100 ppm clock is 10 ns off.
    pub clock_rate: f64,
}

/// A slave's place in the tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TreeNode {
    /// Parent slave and the parent's port this slave hangs on; `None` for the first slave.
    pub parent: Option<(u16, u8)>,
    /// The port through which frames enter.
    pub entry_port: u8,
    /// Open ports after the entry port not yet given a child (scratch for building).
    next_child: u8,
}

/// Why the ports do not describe a tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TopologyError {
    /// A slave reports no open port.
    #[error("slave {0} has no open port")]
    NoOpenPort(u16),
    /// A slave appears in network order but no earlier slave has a free port for it.
    #[error("slave {0} has no upstream slave with a free port")]
    NoParent(u16),
    /// More slaves than the output has room for.
    #[error("output holds {have} entries, {needed} needed")]
    OutputTooShort {
        /// Entries needed.
        needed: usize,
        /// Entries provided.
        have: usize,
    },
    /// The reference clock has no receive times.
    #[error("slave {0} cannot be the reference: it has no receive times")]
    BadReference(u16),
    /// A slave without receive times has more than two open ports.
    #[error("slave {0} has more than two open ports but no receive times")]
    JunctionWithoutTimes(u16),
}

/// Processing order of ports: 0 -> (processing unit) -> 3 -> 1 -> 2.
pub const PORT_ORDER: [u8; 4] = [0, 3, 1, 2];

fn order_index(port: u8) -> usize {
    PORT_ORDER.iter().position(|&p| p == port).unwrap_or(0)
}

/// The open ports of a slave after `entry`, in processing order.
fn ports_after(open: &[bool; 4], entry: u8) -> impl Iterator<Item = u8> + '_ {
    let start = order_index(entry);
    (1..4)
        .map(move |k| PORT_ORDER[(start + k) % 4])
        .filter(move |&p| open[usize::from(p)])
}

/// The entry port: for slaves with receive times the open port stamped first (wrap-safe), else
/// port 0 if open, else the first open port.
pub fn entry_port(s: &SlavePorts) -> Option<u8> {
    let open: heapless_ports::Ports = s.open.into();
    if let Some(t) = s.times {
        open.iter().find(|&p| {
            open.iter()
                .all(|q| diff_u32(t[usize::from(q)], t[usize::from(p)]) >= 0)
        })
    } else if s.open[0] {
        Some(0)
    } else {
        open.iter().next()
    }
}

mod heapless_ports {
    /// The open ports of a slave as a tiny set.
    #[derive(Clone, Copy)]
    pub struct Ports([bool; 4]);
    impl From<[bool; 4]> for Ports {
        fn from(v: [bool; 4]) -> Self {
            Ports(v)
        }
    }
    impl Ports {
        pub fn iter(self) -> impl Iterator<Item = u8> {
            (0..4u8).filter(move |&p| self.0[usize::from(p)])
        }
    }
}

/// Builds the tree. `out[i]` receives slave i's parent and entry port.
pub fn build_tree(slaves: &[SlavePorts], out: &mut [TreeNode]) -> Result<(), TopologyError> {
    if out.len() < slaves.len() {
        return Err(TopologyError::OutputTooShort {
            needed: slaves.len(),
            have: out.len(),
        });
    }
    for (i, s) in slaves.iter().enumerate() {
        let entry = entry_port(s).ok_or(TopologyError::NoOpenPort(i as u16))?;
        let open_count = s.open.iter().filter(|&&o| o).count();
        if s.times.is_none() && open_count > 2 {
            return Err(TopologyError::JunctionWithoutTimes(i as u16));
        }
        out[i] = TreeNode {
            parent: None,
            entry_port: entry,
            next_child: ports_after(&s.open, entry).count() as u8,
        };
        if i == 0 {
            continue;
        }
        // Hang on the most recent slave with a free port, walking up from the previous one.
        let mut cand = Some(i - 1);
        while let Some(c) = cand {
            if out[c].next_child > 0 {
                break;
            }
            cand = out[c].parent.map(|(p, _)| usize::from(p));
        }
        let c = cand.ok_or(TopologyError::NoParent(i as u16))?;
        let s_c = &slaves[c];
        let total = ports_after(&s_c.open, out[c].entry_port).count() as u8;
        let k = total - out[c].next_child;
        let port = ports_after(&s_c.open, out[c].entry_port)
            .nth(usize::from(k))
            .ok_or(TopologyError::NoParent(i as u16))?;
        out[c].next_child -= 1;
        out[i].parent = Some((c as u16, port));
    }
    Ok(())
}

/// `t[b] - t[a]` of one slave's stamps in the master's time base, ns.
fn span(s: &SlavePorts, t: &[u32; 4], a: u8, b: u8) -> f64 {
    let local = f64::from(diff_u32(t[usize::from(b)], t[usize::from(a)]));
    if s.clock_rate > 0.0 {
        local / s.clock_rate
    } else {
        local
    }
}

/// A slave's own loop: from its entry stamp to its last open port's stamp, ns.
fn own_loop(s: &SlavePorts, entry: u8) -> f64 {
    match (s.times, ports_after(&s.open, entry).last()) {
        (Some(t), Some(last)) => span(s, &t, entry, last),
        _ => 0.0,
    }
}

/// Whether the way out of a slave through port `c` passes its processing unit: only when `c` is
/// the first open port after the entry port 0 (the unit sits between port 0 and port 3).
fn out_passes_pu(s: &SlavePorts, entry: u8, c: u8) -> bool {
    entry == 0 && ports_after(&s.open, entry).next() == Some(c)
}

/// Whether the way back out of a slave's entry port passes its processing unit: when no other
/// port is open and the entry is port 0.
fn back_passes_pu(s: &SlavePorts, entry: u8) -> bool {
    entry == 0 && ports_after(&s.open, entry).next().is_none()
}

/// Delay from the master's network interface to the first slave's processing unit, ns, for a
/// master that stamps its frames in hardware: `round_trip_ns` from the first bit leaving (T1)
/// to the first bit of the returned frame arriving (T4), in the master's time. It is the
/// formula of the delays above with the master as the ancestor: the master's way out has no
/// delay of its own (T1 is taken on the wire), the first slave's own loop is removed, and its
/// way back through its processing (no other port open) or forwarding delay. Whatever lies
/// between the master and the first slave (cables, PHYs, a bridge that stores and forwards
/// both directions alike) is measured as half the round trip; an asymmetry (a frame held on
/// one way only) is not, which is the TSN paper's point. `None` without receive times.
pub fn master_delay_ns(round_trip_ns: f64, first: &SlavePorts, entry: u8) -> Option<f64> {
    first.times?;
    let back = if back_passes_pu(first, entry) {
        first.processing_ns
    } else {
        first.forwarding_ns
    };
    Some((round_trip_ns - own_loop(first, entry) - f64::from(back)) / 2.0)
}

/// Arrival time of the frame at each slave relative to the first slave with receive times, in
/// ns (`None` for slaves without receive times). `tree` from [`build_tree`].
pub fn arrival_times(
    slaves: &[SlavePorts],
    tree: &[TreeNode],
    out: &mut [Option<f64>],
) -> Result<(), TopologyError> {
    if out.len() < slaves.len() || tree.len() < slaves.len() {
        return Err(TopologyError::OutputTooShort {
            needed: slaves.len(),
            have: out.len().min(tree.len()),
        });
    }
    for i in 0..slaves.len() {
        out[i] = None;
        let x = &slaves[i];
        if x.times.is_none() {
            continue;
        }
        // Walk up to the nearest ancestor with receive times, summing the tDiffs of 2-port
        // slaves without receive times on the way (they forward through their processing unit
        // on the way out).
        let mut child = i;
        let mut passthrough: i64 = 0;
        let mut found = None;
        while let Some((p, port)) = tree[child].parent {
            let p = usize::from(p);
            if slaves[p].times.is_some() {
                found = Some((p, port));
                break;
            }
            if tree[p].entry_port == 0 {
                passthrough += i64::from(slaves[p].processing_ns - slaves[p].forwarding_ns);
            }
            child = p;
        }
        let Some((a, c)) = found else {
            out[i] = Some(0.0); // the root of the DC tree
            continue;
        };
        let (Some(arr_a), Some(ta)) = (out[a], slaves[a].times) else {
            continue;
        };
        let sa = &slaves[a];
        let ea = tree[a].entry_port;
        // The port before c in A's order (the entry port if c is the first).
        let mut prev = ea;
        for p in ports_after(&sa.open, ea) {
            if p == c {
                break;
            }
            prev = p;
        }
        let ex = tree[i].entry_port;
        let round_trip = span(sa, &ta, prev, c) - own_loop(x, ex);
        let mut k = passthrough;
        k += i64::from(if out_passes_pu(sa, ea, c) {
            sa.processing_ns
        } else {
            sa.forwarding_ns
        });
        k -= i64::from(if back_passes_pu(x, ex) {
            x.processing_ns
        } else {
            x.forwarding_ns
        });
        out[i] = Some(arr_a + span(sa, &ta, ea, prev) + (round_trip + k as f64) / 2.0);
    }
    Ok(())
}

/// Propagation delays from the reference to every slave, ns: `delay[i] = arrival[i] -
/// arrival[reference]`, `None` for slaves without receive times.
pub fn propagation_delays(
    slaves: &[SlavePorts],
    tree: &[TreeNode],
    reference: usize,
    out: &mut [Option<f64>],
) -> Result<(), TopologyError> {
    if slaves.get(reference).and_then(|s| s.times).is_none() {
        return Err(TopologyError::BadReference(reference as u16));
    }
    arrival_times(slaves, tree, out)?;
    let r = out[reference].unwrap_or(0.0);
    for d in out.iter_mut().take(slaves.len()).flatten() {
        *d -= r;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line_slave(t0: u32, t1: Option<u32>) -> SlavePorts {
        let mut times = [0u32; 4];
        times[0] = t0;
        if let Some(t1) = t1 {
            times[1] = t1;
        }
        SlavePorts {
            open: [true, t1.is_some(), false, false],
            times: Some(times),
            ..SlavePorts::default()
        }
    }

    #[test]
    fn line_matches_the_letters_equation_8() {
        // Three slaves in a line with local clocks at arbitrary offsets. Worked by hand:
        // d_{r,n} = ((t_p1^r - t_p0^r) - (t_p1^n - t_p0^n)) / 2 (the letter's eq. 8).
        let s = [
            line_slave(1_000, Some(1_000 + 2_000)),
            line_slave(50_000, Some(50_000 + 1_000)),
            line_slave(7_000_000, None),
        ];
        let mut tree = [TreeNode::default(); 3];
        build_tree(&s, &mut tree).unwrap();
        assert_eq!(tree[1].parent, Some((0, 1)));
        assert_eq!(tree[2].parent, Some((1, 1)));
        let mut d = [None; 3];
        propagation_delays(&s, &tree, 0, &mut d).unwrap();
        assert_eq!(d, [Some(0.0), Some(500.0), Some(1_000.0)]);
    }

    #[test]
    fn wraps_inside_a_slave_are_harmless() {
        let s = [
            line_slave(u32::MAX - 500, Some(1_499)),
            line_slave(10, None),
        ];
        let mut tree = [TreeNode::default(); 2];
        build_tree(&s, &mut tree).unwrap();
        assert_eq!(tree[0].entry_port, 0);
        let mut d = [None; 2];
        propagation_delays(&s, &tree, 0, &mut d).unwrap();
        assert_eq!(d[1], Some(1_000.0));
    }

    #[test]
    fn junction_with_port_3_branch() {
        // A junction J (ports 0, 3, 1 open) with an end slave B on port 3 and an end slave C on
        // port 1. Network order: J, B, C. Times worked by hand with 100 ns internal delays and
        // 200 ns links:
        // J: t0 = 0; out port 3 at 100; B arrives 300, leaves 400 (PU, tP = 100); back at J
        // port 3 at 600; out port 1 at 700; C arrives 900, leaves 1000; back at J port 1 at 1200.
        let j = SlavePorts {
            open: [true, true, false, true],
            times: Some([0, 1_200, 0, 600]),
            ..SlavePorts::default()
        };
        let b = line_slave(80_000, None);
        let c = line_slave(9_000, None);
        let s = [j, b, c];
        let mut tree = [TreeNode::default(); 3];
        build_tree(&s, &mut tree).unwrap();
        assert_eq!(tree[1].parent, Some((0, 3)));
        assert_eq!(tree[2].parent, Some((0, 1)));
        let mut d = [None; 3];
        propagation_delays(&s, &tree, 0, &mut d).unwrap();
        // True: B arrives 300 after J, C 900 after J.
        assert_eq!(d, [Some(0.0), Some(300.0), Some(900.0)]);
    }

    #[test]
    fn tdiff_correction() {
        // Line A -> B -> C with tP = 150, tF = 100 (tDiff 50) and 200 ns links; A's clock reads
        // real time. A: t0 = 0, out through its PU at 150; B arrives at 350 (B local 10_000), out
        // at 500; C arrives at 700 and, as the end, leaves through its PU at 850; back at B port 1
        // at 1050 (B local 10_700); B forwards (tF) to port 0 at 1150; A port 1 at 1350.
        let a = SlavePorts {
            open: [true, true, false, false],
            times: Some([0, 1_350, 0, 0]),
            forwarding_ns: 100,
            processing_ns: 150,
            clock_rate: 0.0,
        };
        let b = SlavePorts {
            open: [true, true, false, false],
            times: Some([10_000, 10_700, 0, 0]),
            forwarding_ns: 100,
            processing_ns: 150,
            clock_rate: 0.0,
        };
        let c = SlavePorts {
            open: [true, false, false, false],
            times: Some([5, 0, 0, 0]),
            forwarding_ns: 100,
            processing_ns: 150,
            clock_rate: 0.0,
        };
        let s = [a, b, c];
        let mut tree = [TreeNode::default(); 3];
        build_tree(&s, &mut tree).unwrap();
        let mut d = [None; 3];
        propagation_delays(&s, &tree, 0, &mut d).unwrap();
        assert_eq!(d[1], Some(350.0));
        assert_eq!(d[2], Some(700.0));
        let s0: [SlavePorts; 3] = s.map(|x| SlavePorts {
            forwarding_ns: 0,
            processing_ns: 0,
            ..x
        });
        propagation_delays(&s0, &tree, 0, &mut d).unwrap();
        assert_eq!(
            d[1],
            Some(325.0),
            "ignoring tDiff is off by tDiff/2 on this hop"
        );
    }

    #[test]
    fn different_escs() {
        // A (tP 300, tF 300) -> B (tP 100, tF 100, end of line), 200 ns link. A: t0 = 0, out at
        // 300, B arrives at 500, leaves through its PU at 600, back at A port 1 at 800.
        // Half the round trip says 400; the truth is 500.
        let a = SlavePorts {
            open: [true, true, false, false],
            times: Some([0, 800, 0, 0]),
            forwarding_ns: 300,
            processing_ns: 300,
            clock_rate: 0.0,
        };
        let b = SlavePorts {
            open: [true, false, false, false],
            times: Some([123, 0, 0, 0]),
            forwarding_ns: 100,
            processing_ns: 100,
            clock_rate: 0.0,
        };
        let mut tree = [TreeNode::default(); 2];
        build_tree(&[a, b], &mut tree).unwrap();
        let mut d = [None; 2];
        propagation_delays(&[a, b], &tree, 0, &mut d).unwrap();
        assert_eq!(d[1], Some(500.0));
    }

    #[test]
    fn clock_rates_scale_the_spans() {
        // A's clock runs 100 ppm fast: its 1_000_100 ns local loop is 1_000_000 ns of master
        // time; B's end-of-line loop is empty. Half of it is the delay.
        let a = SlavePorts {
            open: [true, true, false, false],
            times: Some([0, 1_000_100, 0, 0]),
            clock_rate: 1.0001,
            ..SlavePorts::default()
        };
        let b = SlavePorts {
            open: [true, false, false, false],
            times: Some([5, 0, 0, 0]),
            ..SlavePorts::default()
        };
        let mut tree = [TreeNode::default(); 2];
        build_tree(&[a, b], &mut tree).unwrap();
        let mut d = [None; 2];
        propagation_delays(&[a, b], &tree, 0, &mut d).unwrap();
        assert!((d[1].unwrap() - 500_000.0).abs() < 1e-6);
    }

    #[test]
    fn bad_trees() {
        let lone = SlavePorts {
            open: [false; 4],
            times: None,
            ..SlavePorts::default()
        };
        let mut tree = [TreeNode::default(); 2];
        assert_eq!(
            build_tree(&[lone], &mut tree),
            Err(TopologyError::NoOpenPort(0))
        );
        let end = line_slave(0, None);
        assert_eq!(
            build_tree(&[end, end], &mut tree),
            Err(TopologyError::NoParent(1))
        );
    }
}
