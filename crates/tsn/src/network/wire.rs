//! What the network's parts share: timestamps on a clock's grain, a frame's time on the wire,
//! seeded noise, the capture of what crossed.

use ecsync_sim::frame_wire_time_ps;
use ecsync_sim::pcap::PcapCapture;
use ecsync_sim::rng::SplitMix64;
use std::fs::File;
use std::io::BufWriter;

/// SplitMix64 (the host noise's stream): the seeded noise of launch jitter and cross traffic.
#[derive(Debug, Clone)]
pub(super) struct Noise(SplitMix64);

impl Noise {
    pub(super) fn new(seed: u64) -> Self {
        Noise(SplitMix64(seed))
    }
    /// Uniform in (0, 1].
    pub(super) fn unit(&mut self) -> f64 {
        self.0.next_unit()
    }
    /// Standard normal (Box-Muller).
    pub(super) fn normal(&mut self) -> f64 {
        let (u, v) = (self.unit(), self.unit());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The capture at the master's port, up to a real time.
#[derive(Debug, Default)]
pub(super) struct Capture {
    pub(super) file: Option<PcapCapture<BufWriter<File>>>,
    pub(super) until_ps: u64,
    /// The first record that could not be written (the capture's own I/O).
    pub(super) error: Option<String>,
}

impl Capture {
    pub(super) fn record(&mut self, t_ps: u64, frame: &[u8]) {
        if t_ps > self.until_ps {
            return;
        }
        if let Some(c) = &mut self.file
            && let Err(e) = c.record(t_ps, frame)
        {
            self.error.get_or_insert_with(|| e.to_string());
        }
    }
}

/// A hardware timestamp: the clock's reading on the timestamper's grid of `g` ns.
pub(super) fn stamp(g: u64, ns: u64) -> u64 {
    let g = g.max(1);
    ns / g * g
}

/// A frame's time on the wire, whole ns.
pub(super) fn wire_ns(len: usize) -> u64 {
    frame_wire_time_ps(len) / 1000
}
