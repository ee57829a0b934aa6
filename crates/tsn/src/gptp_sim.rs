//! gPTP on simulated links: time-aware systems in a line (grandmaster, bridges, end station),
//! each with a free-running crystal (ppm error) that stamps messages, and at every system
//! that is not the grandmaster a clock disciplined by the servo. Messages travel as encoded
//! bytes (what [`crate::gptp_msg`] writes is what the other end decodes), timestamps are
//! taken at the wire with a hardware timestamper's granularity, and the ground truth — true
//! time, every clock's reading — is known, so the disciplined clocks are measured against the
//! grandmaster exactly.

use crate::gptp::{Config, Outgoing, SystemIdentity, TimeAwareSystem};
use crate::gptp_msg::{self, ClockQuality, Message};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// One system of the line.
#[derive(Debug, Clone, Copy)]
pub struct NodeSpec {
    /// priority1 (the smallest becomes grandmaster).
    pub priority1: u8,
    /// Crystal error, ppm.
    pub ppm: f64,
    /// Local clock reading at true time 0, ns.
    pub initial_ns: f64,
}

/// The line and its links.
#[derive(Debug, Clone)]
pub struct LineSpec {
    /// Systems in line order; 0 and the last are end points (one port), the others bridges.
    pub nodes: Vec<NodeSpec>,
    /// Propagation delay of each link, ns (both directions).
    pub link_delay_ns: f64,
    /// Timestamp granularity, ns (8 for a 125 MHz hardware timestamper).
    pub timestamp_granularity_ns: f64,
    /// How long to run, true time ns.
    pub duration_ns: u64,
    /// Measure from this true time on, ns.
    pub measure_from_ns: u64,
}

/// What a run measured at the last system (the end station).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct LineResult {
    /// RMS of disciplined clock minus grandmaster clock, sampled every millisecond, ns.
    pub offset_rms_ns: f64,
    /// Largest |disciplined - grandmaster|, ns.
    pub offset_max_abs_ns: f64,
    /// Mean link delay the end station measured, ns.
    pub measured_link_delay_ns: f64,
    /// The index of the system that became grandmaster.
    pub grandmaster: usize,
    /// Samples.
    pub samples: u64,
}

struct Node {
    sys: TimeAwareSystem,
    ppm: f64,
    initial_ns: f64,
    /// Disciplined clock: reading at the anchor (local ns), and its rate over local.
    disc_anchor_local: f64,
    disc_anchor_value: f64,
    disc_frequency: f64,
    disciplined: bool,
}

impl Node {
    fn local(&self, t_ns: f64) -> f64 {
        self.initial_ns + t_ns * (1.0 + self.ppm * 1e-6)
    }
    fn disciplined_at_local(&self, local: f64) -> f64 {
        self.disc_anchor_value + (local - self.disc_anchor_local) * (1.0 + self.disc_frequency)
    }
}

/// A delivery: at true time, to node, on its port, the encoded message.
struct Delivery {
    t_ns: f64,
    seq: u64,
    node: usize,
    port: usize,
    bytes: Vec<u8>,
}

impl PartialEq for Delivery {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o).is_eq()
    }
}
impl Eq for Delivery {}
impl PartialOrd for Delivery {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Delivery {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.t_ns.total_cmp(&o.t_ns).then(self.seq.cmp(&o.seq))
    }
}

/// Runs the line and measures the end station against the grandmaster.
pub fn run_line(spec: &LineSpec) -> LineResult {
    let n = spec.nodes.len();
    assert!(n >= 2, "a line of at least two systems");
    let mut nodes: Vec<Node> = spec
        .nodes
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let ports = if i == 0 || i == n - 1 { 1 } else { 2 };
            let identity = SystemIdentity {
                priority1: s.priority1,
                quality: ClockQuality {
                    clock_class: 248,
                    clock_accuracy: 0xfe,
                    offset_scaled_log_variance: 0x4e5d,
                },
                priority2: 248,
                clock_identity: [0x02, 0, 0, 0xff, 0xfe, 0, 0, i as u8],
            };
            Node {
                sys: TimeAwareSystem::new(Config::new(identity, ports)),
                ppm: s.ppm,
                initial_ns: s.initial_ns,
                disc_anchor_local: 0.0,
                disc_anchor_value: 0.0,
                disc_frequency: 0.0,
                disciplined: false,
            }
        })
        .collect();
    // Port p of node i: end points have port 0 towards their only neighbour; a bridge's port 0
    // faces node i-1, port 1 node i+1.
    let peer = |i: usize, port: usize| -> (usize, usize) {
        let towards_next = if i == 0 {
            true
        } else if i == n - 1 {
            false
        } else {
            port == 1
        };
        if towards_next {
            (i + 1, 0)
        } else {
            let j = i - 1;
            (j, if j == 0 { 0 } else { 1 })
        }
    };
    let g = spec.timestamp_granularity_ns.max(1.0);
    let stamp = |x: f64| (x / g).floor() * g;
    let mut queue: BinaryHeap<Reverse<Delivery>> = BinaryHeap::new();
    let mut seq = 0u64;
    let mut out: Vec<Outgoing> = Vec::new();
    let mut more: Vec<Outgoing> = Vec::new();
    let mut buf = [0u8; 128];
    let (mut sum_sq, mut max_abs, mut samples) = (0.0f64, 0.0f64, 0u64);
    let step_ns = 1_000_000u64;
    let mut t_tick = 0u64;
    // Sends `out` from node i at true time t: transmit timestamps back to the sender (which
    // may produce follow-ups, sent at the same instant), deliveries to the peers.
    let mut send_all = |nodes: &mut Vec<Node>,
                        i: usize,
                        t: f64,
                        out: &mut Vec<Outgoing>,
                        more: &mut Vec<Outgoing>,
                        queue: &mut BinaryHeap<Reverse<Delivery>>| {
        while !out.is_empty() {
            for o in out.drain(..) {
                let len = o.message.encode(&o.header, &mut buf).expect("buffer");
                let tx = stamp(nodes[i].local(t)) as u64;
                nodes[i]
                    .sys
                    .on_tx_timestamp(o.port, &o.header, &o.message, tx, more);
                let (j, pj) = peer(i, o.port);
                seq += 1;
                queue.push(Reverse(Delivery {
                    t_ns: t + spec.link_delay_ns,
                    seq,
                    node: j,
                    port: pj,
                    bytes: buf[..len].to_vec(),
                }));
            }
            std::mem::swap(out, more);
        }
    };
    while t_tick <= spec.duration_ns {
        // Deliveries before the next tick.
        while let Some(Reverse(d)) = queue.peek() {
            if d.t_ns > t_tick as f64 {
                break;
            }
            let Reverse(d) = queue.pop().expect("peeked");
            let Ok((h, m)) = gptp_msg::decode(&d.bytes) else {
                continue;
            };
            let rx = stamp(nodes[d.node].local(d.t_ns)) as u64;
            nodes[d.node].sys.on_message(d.port, &h, &m, rx, &mut out);
            if matches!(m, Message::FollowUp { .. }) {
                discipline(&mut nodes[d.node]);
            }
            send_all(&mut nodes, d.node, d.t_ns, &mut out, &mut more, &mut queue);
        }
        let t = t_tick as f64;
        for i in 0..n {
            let local = stamp(nodes[i].local(t)) as u64;
            nodes[i].sys.poll(local, &mut out);
            send_all(&mut nodes, i, t, &mut out, &mut more, &mut queue);
        }
        if t_tick >= spec.measure_from_ns {
            let gm = (0..n).find(|&i| nodes[i].sys.is_grandmaster()).unwrap_or(0);
            let es = &nodes[n - 1];
            if es.disciplined && gm != n - 1 {
                let e = es.disciplined_at_local(es.local(t)) - nodes[gm].local(t);
                sum_sq += e * e;
                max_abs = max_abs.max(e.abs());
                samples += 1;
            }
        }
        t_tick += step_ns;
    }
    let gm = (0..n).find(|&i| nodes[i].sys.is_grandmaster()).unwrap_or(0);
    LineResult {
        offset_rms_ns: if samples > 0 {
            (sum_sq / samples as f64).sqrt()
        } else {
            f64::NAN
        },
        offset_max_abs_ns: max_abs,
        measured_link_delay_ns: nodes[n - 1].sys.mean_link_delay_ns(0).unwrap_or(f64::NAN),
        grandmaster: gm,
        samples,
    }
}

/// Applies the servo's decision to a node's disciplined clock.
fn discipline(node: &mut Node) {
    // The Sync's arrival in local time is what the servo compares at; the disciplined clock's
    // reading then is computed from its current line.
    let Some(rx_local) = node.sys.last_sync_rx_ns() else {
        return;
    };
    let rx_local = rx_local as f64;
    let at_rx = if node.disciplined {
        node.disciplined_at_local(rx_local)
    } else {
        rx_local
    };
    if let Some(adj) = node.sys.servo(at_rx.floor() as u64, at_rx - at_rx.floor()) {
        // Re-anchor at the Sync's arrival with the new rate (and the step, once).
        node.disc_anchor_value = at_rx + adj.step_ns;
        node.disc_anchor_local = rx_local;
        node.disc_frequency = adj.frequency;
        node.disciplined = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Grandmaster, one bridge, end station; crystals within +-50 ppm; 500 ns links; 8 ns
    /// hardware timestamps. The end station's disciplined clock against the grandmaster's.
    #[test]
    fn an_end_station_behind_a_bridge_follows_the_grandmaster() {
        let spec = LineSpec {
            nodes: vec![
                NodeSpec {
                    priority1: 100,
                    ppm: 20.0,
                    initial_ns: 1.0e12,
                },
                NodeSpec {
                    priority1: 246,
                    ppm: -30.0,
                    initial_ns: 5.0e9,
                },
                NodeSpec {
                    priority1: 246,
                    ppm: 45.0,
                    initial_ns: 123.0,
                },
            ],
            link_delay_ns: 500.0,
            timestamp_granularity_ns: 8.0,
            duration_ns: 20_000_000_000,
            measure_from_ns: 10_000_000_000,
        };
        let r = run_line(&spec);
        println!("{r:?}");
        assert_eq!(r.grandmaster, 0, "the best priority1 wins the BMCA");
        assert!((r.measured_link_delay_ns - 500.0).abs() < 10.0, "{r:?}");
        assert!(r.samples > 9_000);
        assert!(r.offset_rms_ns < 100.0, "{r:?}");
    }

    /// Two bridges: the correction field carries two residence times and two link delays,
    /// rateRatio the product of three neighbour ratios; the grandmaster is chosen by priority
    /// although it is not the first system.
    #[test]
    fn two_bridges_and_a_grandmaster_chosen_by_priority() {
        let node = |priority1, ppm, initial_ns| NodeSpec {
            priority1,
            ppm,
            initial_ns,
        };
        let spec = LineSpec {
            nodes: vec![
                node(246, -12.0, 7.0e11),
                node(50, 33.0, 2.0e9),
                node(246, -48.0, 0.0),
                node(246, 41.0, 9.9e10),
            ],
            link_delay_ns: 1_250.0,
            timestamp_granularity_ns: 8.0,
            duration_ns: 30_000_000_000,
            measure_from_ns: 15_000_000_000,
        };
        let r = run_line(&spec);
        println!("{r:?}");
        assert_eq!(r.grandmaster, 1);
        assert!((r.measured_link_delay_ns - 1_250.0).abs() < 10.0, "{r:?}");
        assert!(r.offset_rms_ns < 100.0, "{r:?}");
    }
}
