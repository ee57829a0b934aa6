//! The in-process transport: drives an [`Engine`] against a virtual [`Segment`] in virtual time.

use crate::io::{Action, Engine, Event};
use ecsync_esc::clock::{CrystalParams, LocalClock};
use ecsync_esc::pcap::PcapCapture;
use ecsync_esc::{Segment, frame_wire_time_ps};
use std::fs::File;
use std::io::BufWriter;

/// Master clock at simulation start: 2026-11-22 00:00 UTC in DC time (ns since 2000-01-01).
pub const SIM_EPOCH_NS: u64 = 848_620_800_000_000_000;

/// The master's clock: a crystal (ppm and wander, the same model as the ESCs') mapping real time
/// to master time, ns since the DC epoch.
///
/// No control loop steers it, so between two wander steps it is one straight line; the line is
/// cached (its start and slope both ways) so that reading and inverting it every cycle costs a
/// multiplication each.
#[derive(Debug, Clone)]
pub struct MasterClock {
    clock: LocalClock,
    line: Line,
}

/// The master clock's straight piece from `anchor_ps` up to `next_ps` (the next wander step).
#[derive(Debug, Clone, Copy)]
struct Line {
    anchor_ps: u64,
    next_ps: u64,
    /// Master time at the anchor: whole ns and fraction.
    a_ns: u64,
    a_frac: f64,
    /// Master ns per real ps, and real ps per master ns.
    ns_per_ps: f64,
    ps_per_ns: f64,
}

impl Line {
    fn of(clock: &LocalClock) -> Line {
        let anchor_ps = clock.anchor_ps();
        let (a_ns, a_frac) = clock.local_exact_ns(anchor_ps);
        let rate = clock.rate();
        Line {
            anchor_ps,
            next_ps: clock.next_wander_ps(),
            a_ns,
            a_frac,
            ns_per_ps: rate * 1e-3,
            ps_per_ns: 1e3 / rate,
        }
    }
}

impl MasterClock {
    /// An ideal clock reading `epoch_ns` at real time 0.
    pub fn ideal(epoch_ns: u64) -> Self {
        Self::new(CrystalParams {
            initial_local_ns: epoch_ns,
            ..CrystalParams::default()
        })
    }

    /// A clock with this crystal (its `initial_local_ns` is the master time at real time 0).
    pub fn new(crystal: CrystalParams) -> Self {
        let clock = LocalClock::new(crystal);
        let line = Line::of(&clock);
        MasterClock { clock, line }
    }

    /// Moves to the straight piece that holds real time `t_ps` (forward only).
    #[cold]
    #[inline(never)]
    fn advance(&mut self, t_ps: u64) {
        self.clock.advance_to(t_ps);
        self.line = Line::of(&self.clock);
    }

    /// Master time at real time `t_ps`, ns (the last whole nanosecond).
    #[inline]
    pub fn master_ns(&mut self, t_ps: u64) -> u64 {
        if t_ps >= self.line.next_ps {
            self.advance(t_ps);
        }
        let l = &self.line;
        // Signed: a time slightly before the anchor reads back along the same line.
        let d = (t_ps.wrapping_sub(l.anchor_ps) as i64) as f64 * l.ns_per_ps + l.a_frac;
        l.a_ns
            .wrapping_add(ecsync_esc::clock::floor_split(d).0 as u64)
    }

    /// Real time (ps) at which the master clock reads `t_ns` (the inverse of
    /// [`MasterClock::master_ns`], to a picosecond).
    #[inline]
    pub fn real_ps_at(&mut self, t_ns: u64) -> u64 {
        loop {
            let l = &self.line;
            // Signed 64-bit difference: an i128 conversion costs a libcall on the hot path.
            let d_ns = (t_ns.wrapping_sub(l.a_ns) as i64) as f64 - l.a_frac;
            let r = l.anchor_ps as f64 + d_ns * l.ps_per_ns;
            // Rounds half up; `r` is not negative (no libm `round` call).
            let r = (r.max(0.0) + 0.5) as u64;
            // The rate is constant up to the next wander step: beyond it, step there first.
            if r < l.next_ps || l.next_ps <= l.anchor_ps {
                return r;
            }
            let next = l.next_ps;
            self.advance(next);
        }
    }
}

/// A frame exchange as the driver saw it, for observers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchange {
    /// Real time the frame left the master, ps.
    pub sent_ps: u64,
    /// Real time the reply was complete at the master, ps (`None`: lost).
    pub received_ps: Option<u64>,
}

/// Runs master procedures against a segment in virtual time.
pub struct SimTransport {
    /// The segment.
    pub segment: Segment,
    /// Real time now, ps since the start of the simulation.
    pub now_ps: u64,
    /// The master's clock.
    pub master_clock: MasterClock,
    /// Delay from the master's send timestamp to the frame's first bit on the wire, ps.
    pub tx_latency_ps: u64,
    /// Delay from the reply's last bit to the master's receive timestamp, ps.
    pub rx_latency_ps: u64,
    /// How long the master waits before declaring a frame lost, ps.
    pub timeout_ps: u64,
    capture: Option<PcapCapture<BufWriter<File>>>,
}

impl std::fmt::Debug for SimTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimTransport")
            .field("now_ps", &self.now_ps)
            .finish_non_exhaustive()
    }
}

impl SimTransport {
    /// A transport with an ideal master clock and a few microseconds of NIC latency.
    pub fn new(segment: Segment) -> Self {
        SimTransport {
            segment,
            now_ps: 0,
            master_clock: MasterClock::ideal(SIM_EPOCH_NS),
            tx_latency_ps: 2_000_000,
            rx_latency_ps: 3_000_000,
            timeout_ps: 10_000_000_000,
            capture: None,
        }
    }

    /// A copy of this transport in its current state (segment, clocks, time) without the
    /// capture: several experiments can continue from one bring-up.
    pub fn fork(&self) -> SimTransport {
        SimTransport {
            segment: self.segment.clone(),
            now_ps: self.now_ps,
            master_clock: self.master_clock.clone(),
            tx_latency_ps: self.tx_latency_ps,
            rx_latency_ps: self.rx_latency_ps,
            timeout_ps: self.timeout_ps,
            capture: None,
        }
    }

    /// Captures every frame (sent and returned) to a pcap file.
    pub fn capture_to(&mut self, path: &std::path::Path) -> Result<(), pcap_file_error::Error> {
        self.capture = Some(PcapCapture::create(path).map_err(pcap_file_error::Error)?);
        Ok(())
    }

    /// Flushes the capture, returning the number of frames written.
    pub fn finish_capture(&mut self) -> std::io::Result<u64> {
        match self.capture.take() {
            Some(c) => {
                let n = c.frames();
                c.finish()?;
                Ok(n)
            }
            None => Ok(0),
        }
    }

    /// Master clock now, ns.
    pub fn master_now_ns(&mut self) -> u64 {
        let t = self.now_ps;
        self.master_clock.master_ns(t)
    }

    /// Real time (ps) at master time `t_ns`.
    pub fn real_ps_at(&mut self, t_ns: u64) -> u64 {
        self.master_clock.real_ps_at(t_ns)
    }

    /// Runs an engine to completion. `observe` sees the segment after every exchange, with the
    /// events the procedure reported.
    pub fn run<T: 'static>(
        &mut self,
        engine: &mut Engine<T>,
        mut observe: impl FnMut(&Segment, &Exchange, &[Event]),
    ) -> T {
        loop {
            let now = self.master_now_ns();
            let frame = match engine.poll(now) {
                Action::Done(v) => return v,
                Action::WaitUntil(t) => {
                    let t_ps = self.real_ps_at(t).max(self.now_ps + 1000);
                    self.now_ps = t_ps;
                    continue;
                }
                Action::Send(f) => f.to_vec(),
            };
            let mut frame = frame;
            let sent_ns = now;
            let t_tx = self.now_ps + self.tx_latency_ps;
            if let Some(c) = &mut self.capture {
                let _ = c.record(t_tx, &frame);
            }
            let out = self.segment.process(&mut frame, t_tx);
            let ex = match out.returned_sof_ps {
                Some(t) => {
                    let t_rx = t + frame_wire_time_ps(frame.len()) + self.rx_latency_ps;
                    if let Some(c) = &mut self.capture {
                        let _ = c.record(t + frame_wire_time_ps(frame.len()), &frame);
                    }
                    self.now_ps = t_rx;
                    let rx_ns = self.master_now_ns();
                    engine.handle_reply(&frame, sent_ns, rx_ns);
                    Exchange {
                        sent_ps: t_tx,
                        received_ps: Some(t_rx),
                    }
                }
                None => {
                    self.now_ps = t_tx + self.timeout_ps;
                    engine.handle_lost();
                    Exchange {
                        sent_ps: t_tx,
                        received_ps: None,
                    }
                }
            };
            let events = engine.take_events();
            observe(&self.segment, &ex, &events);
        }
    }
}

/// Error type for capture creation.
pub mod pcap_file_error {
    /// A pcap file could not be created.
    #[derive(Debug, thiserror::Error)]
    #[error("pcap capture: {0}")]
    pub struct Error(pub pcap_file::PcapError);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn master_clock_inverts() {
        let mut c = MasterClock::new(CrystalParams {
            ppm: -37.5,
            wander_ppm_per_sqrt_s: 0.1,
            wander_step_ps: 1_000_000_000,
            initial_local_ns: SIM_EPOCH_NS,
            seed: 3,
        });
        for k in 1..2_000u64 {
            let t = k * 7_777_777_777;
            let m = c.master_ns(t);
            let back = c.real_ps_at(m);
            assert!(back.abs_diff(t) <= 1_000, "{t} -> {m} -> {back}");
        }
        let m = c.master_ns(1_000_000_000_000);
        assert!((m - SIM_EPOCH_NS) < 1_000_000_000 && (m - SIM_EPOCH_NS) > 999_900_000);
    }
}
