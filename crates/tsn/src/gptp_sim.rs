//! gPTP on simulated links: time-aware systems in a line (grandmaster, bridges, end station),
//! each with a free-running crystal (ppm error) that stamps messages, and at every system
//! that is not the grandmaster a clock disciplined by the servo. Messages travel as encoded
//! bytes (what [`crate::gptp_msg`] writes is what the other end decodes), timestamps are
//! taken at the wire with a hardware timestamper's granularity, and the ground truth — true
//! time, every clock's reading — is known, so the disciplined clocks are measured against the
//! grandmaster exactly. The exchange of messages is [`crate::gptp_net`]'s, shared with the TSN
//! network's bridge and master.

use crate::gptp::{Config, SystemIdentity, TimeAwareSystem};
use crate::gptp_net::{GptpMedium, GptpNetwork, Transmission};

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

/// One system's clocks: its free-running crystal, and the clock the servo disciplines.
struct Node {
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

/// The line as the exchange sees it: true time in float ns, every link the same delay, no
/// wire occupancy (a system's messages of one instant leave together), hardware timestamps
/// on the granularity's grid.
struct LineMedium {
    nodes: Vec<Node>,
    link_delay_ns: f64,
    granularity_ns: f64,
}

impl LineMedium {
    fn stamp(&self, node: usize, t_ns: f64) -> u64 {
        let g = self.granularity_ns;
        ((self.nodes[node].local(t_ns) / g).floor() * g) as u64
    }

    /// Port `port` of node `i` leads to which node and port: end points have port 0 towards
    /// their only neighbour; a bridge's port 0 faces node i-1, port 1 node i+1.
    fn peer(&self, i: usize, port: usize) -> (usize, usize) {
        let n = self.nodes.len();
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
    }
}

impl GptpMedium<f64> for LineMedium {
    fn timestamp_ns(&mut self, node: usize, t: f64) -> u64 {
        self.stamp(node, t)
    }

    fn transmit(&mut self, node: usize, port: usize, ready: f64, _: &[u8]) -> Transmission<f64> {
        let (peer, peer_port) = self.peer(node, port);
        Transmission {
            tx_ns: self.stamp(node, ready),
            arrival: ready + self.link_delay_ns,
            peer,
            peer_port,
            next_ready: ready,
        }
    }

    fn follow_up(&mut self, node: usize, system: &mut TimeAwareSystem) {
        discipline(&mut self.nodes[node], system);
    }
}

/// Runs the line and measures the end station against the grandmaster.
pub fn run_line(spec: &LineSpec) -> LineResult {
    let n = spec.nodes.len();
    assert!(n >= 2, "a line of at least two systems");
    let systems = (0..n)
        .map(|i| {
            let ports = if i == 0 || i == n - 1 { 1 } else { 2 };
            let identity = SystemIdentity::with_default_quality(
                spec.nodes[i].priority1,
                [0x02, 0, 0, 0xff, 0xfe, 0, 0, i as u8],
            );
            TimeAwareSystem::new(Config::new(identity, ports))
        })
        .collect();
    let mut medium = LineMedium {
        nodes: spec
            .nodes
            .iter()
            .map(|s| Node {
                ppm: s.ppm,
                initial_ns: s.initial_ns,
                disc_anchor_local: 0.0,
                disc_anchor_value: 0.0,
                disc_frequency: 0.0,
                disciplined: false,
            })
            .collect(),
        link_delay_ns: spec.link_delay_ns,
        granularity_ns: spec.timestamp_granularity_ns.max(1.0),
    };
    let step_ns = 1_000_000u64;
    let mut net = GptpNetwork::new(systems, 0.0, step_ns as f64);
    let (mut sum_sq, mut max_abs, mut samples) = (0.0f64, 0.0f64, 0u64);
    let mut t_tick = 0u64;
    while t_tick <= spec.duration_ns {
        // Deliveries up to the tick, then every system's timers, then the measurement (with a
        // link of no delay, what the polls sent arrives after it, at the next tick's turn).
        let t = t_tick as f64;
        net.deliver_until(t, &mut medium);
        net.poll_all(t, &mut medium);
        if t_tick >= spec.measure_from_ns {
            let gm = grandmaster(net.systems());
            let es = &medium.nodes[n - 1];
            if es.disciplined && gm != n - 1 {
                let e = es.disciplined_at_local(es.local(t)) - medium.nodes[gm].local(t);
                sum_sq += e * e;
                max_abs = max_abs.max(e.abs());
                samples += 1;
            }
        }
        t_tick += step_ns;
    }
    LineResult {
        offset_rms_ns: if samples > 0 {
            (sum_sq / samples as f64).sqrt()
        } else {
            f64::NAN
        },
        offset_max_abs_ns: max_abs,
        measured_link_delay_ns: net.systems()[n - 1]
            .mean_link_delay_ns(0)
            .unwrap_or(f64::NAN),
        grandmaster: grandmaster(net.systems()),
        samples,
    }
}

/// The index of the system that considers itself grandmaster (the first, if several do).
fn grandmaster(systems: &[TimeAwareSystem]) -> usize {
    systems.iter().position(|s| s.is_grandmaster()).unwrap_or(0)
}

/// Applies the servo's decision to a node's disciplined clock.
fn discipline(node: &mut Node, sys: &mut TimeAwareSystem) {
    // The Sync's arrival in local time is what the servo compares at; the disciplined clock's
    // reading then is computed from its current line.
    let Some(rx_local) = sys.last_sync_rx_ns() else {
        return;
    };
    let rx_local = rx_local as f64;
    let at_rx = if node.disciplined {
        node.disciplined_at_local(rx_local)
    } else {
        rx_local
    };
    if let Some(adj) = sys.servo(at_rx.floor() as u64, at_rx - at_rx.floor()) {
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
