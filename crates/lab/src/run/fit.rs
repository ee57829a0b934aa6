//! Whether a network's cyclic frames fit its cycle, worked out from the scenario before
//! anything is simulated: a network of thousands of drives needs frames for milliseconds, and a
//! cycle shorter than their way round loses every one of them (each reply comes after the next
//! cycle has begun), after minutes of bring-up.
//!
//! The frames are the master's own plan ([`ecsync_master::cyclic::cycle_frame_lens`]) of the
//! process image the bring-up maps: every reached slave's outputs, then every one's inputs, as
//! the devices describe them, in LRWs of at most a frame ([`ecsync_master::pdi::lrw_chunks`]).
//! A cycle's replies are all back after the host's execution and transmit latency, the frames
//! back to back on the wire, the first bit's way round the segment and the receive latency: a
//! shorter cycle loses every frame even on a host without jitter, and is refused. A cycle just
//! above that loses the frames the host's jitter delays: the simulation counts those, and the
//! cycle the refusal suggests leaves room for them (the latest the host model sends but once in
//! twenty comparisons of its length, or a replayed trace's worst cycle).

use super::{REPLY_MARGIN_NS, RunError};
use crate::Scenario;
use ecsync_master::MasterError;
use ecsync_master::cyclic::{CyclicConfig, cycle_frame_lens};
use ecsync_master::pdi::lrw_chunks;
use ecsync_sim::{Segment, frame_wire_time_ps};

/// The suggested cycle's room is exceeded in one of this many comparisons of the scenario's
/// length (the host model's latest send about once in that many times its cycles).
pub const ONE_IN: f64 = 20.0;

/// What a cycle of the scenario's network takes, ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleFit {
    /// Frames per cycle.
    pub frames: usize,
    /// The cycle's frames back to back on the wire.
    pub wire_ns: u64,
    /// A frame's first bit from the master round the segment and back.
    pub round_trip_ns: u64,
    /// The host's part: execution before the send, transmit and receive latency.
    pub host_ns: u64,
    /// From the cycle's start to its last reply on a host without jitter: the shortest cycle.
    pub needed_cycle_ns: u64,
    /// The room the suggested cycle leaves for the host: how late past their mean plan its
    /// frames reach the wire at most but in one of twenty comparisons of this length (the
    /// host model's jitter), or a replayed trace's worst cycle; the engine's reply margin at
    /// least.
    pub room_ns: u64,
    /// Slaves with a SYNC0 deadline: a system time (SYNC0 runs on it) and process data (what
    /// SYNC0 takes). A coupler, a terminal without DC, one with receive times only have none.
    pub sync0_slaves: usize,
}

impl CycleFit {
    /// The cycle to configure: the shortest with room for the host's jitter
    /// ([`CycleFit::room_ns`]), rounded up to 10 us, us.
    pub fn suggested_cycle_us(&self) -> u64 {
        (self.needed_cycle_ns + self.room_ns).div_ceil(10_000) * 10
    }
}

/// The cycle the scenario's network needs (the longest of its methods': a bus-shift method's
/// write to the reference lengthens the first frame).
pub fn cycle_fit(s: &Scenario) -> Result<CycleFit, RunError> {
    let config = |e: String| RunError::Bringup(MasterError::Config(e));
    let seg = Segment::new(&s.slaves).map_err(|e| config(e.to_string()))?;
    let reached = seg.pu_offsets_ps();
    let reached: Vec<usize> = (0..seg.len())
        .filter(|&x| reached.get(x).is_some_and(Option::is_some))
        .collect();
    let slaves: Vec<(u32, u32)> = reached
        .iter()
        .map(|&x| {
            let d = seg.esc(x).device();
            (d.output_bytes() as u32, d.input_bytes() as u32)
        })
        .collect();
    let sync0_slaves = reached
        .iter()
        .zip(&slaves)
        .filter(|&(&x, &(o, i))| seg.esc(x).model().dc.has_system_time() && o + i > 0)
        .count();
    // The bring-up's image: all outputs (working counter 2 each), then all inputs (1 each).
    let mut ranges = Vec::with_capacity(2 * slaves.len());
    let mut logical = 0u32;
    for (len, wkc) in slaves
        .iter()
        .map(|&(o, _)| (o, 2))
        .chain(slaves.iter().map(|&(_, i)| (i, 1)))
        .filter(|&(len, _)| len > 0)
    {
        ranges.push((logical, len, wkc));
        logical += len;
    }
    let cfg = CyclicConfig {
        period_ns: s.cycle_ns,
        reference_station: 0x1000,
        pdi_len: logical,
        measure_init_frames: 0,
        reference_offset_ns: 0,
        lrw: lrw_chunks(logical, &ranges),
    };
    let bus_shift = s.methods.iter().any(|k| !k.is_master_shift());
    let lens = cycle_frame_lens(&cfg, bus_shift).map_err(RunError::Frame)?;
    let wire_ns = lens.iter().map(|&n| frame_wire_time_ps(n)).sum::<u64>() / 1000;
    let round_trip_ns = seg.round_trip_ps() / 1000;
    let h = &s.host;
    let host_ns = (h.em_ns + h.tx_latency_ns + h.rx_latency_ns).max(0.0) as u64;
    let late_ns = match &s.host_trace {
        // The trace's cycles stand in for j_s, e_m and (where it has them) the TX delay: its
        // worst cycle against the mean plan the host's figures give.
        Some(r) => r
            .trace()
            .rows
            .iter()
            .map(|row| {
                row.wake_latency_ns.max(0.0)
                    + row.exec_ns.max(0.0)
                    + row.tx_delay_ns.unwrap_or(h.tx_latency_ns)
                    - h.em_ns
                    - h.tx_latency_ns
            })
            .fold(0.0, f64::max),
        // Once in twenty comparisons of this length: a bound reached once in this one would
        // lose a frame in every other comparison.
        None => h.latest_send_delay_ns(ONE_IN * s.runs as f64 * s.cycles as f64),
    };
    Ok(CycleFit {
        frames: lens.len(),
        wire_ns,
        round_trip_ns,
        host_ns,
        needed_cycle_ns: host_ns + wire_ns + round_trip_ns,
        room_ns: (late_ns.ceil() as u64).max(REPLY_MARGIN_NS),
        sync0_slaves,
    })
}

/// [`cycle_fit`], refused when the scenario's cycle is shorter than the network needs, or
/// when no slave has a SYNC0 deadline (the comparison judges every method by its frames'
/// margin before the drives' SYNC0: without one, its shifts and margins would be empty).
pub fn check_cycle_fits(s: &Scenario) -> Result<CycleFit, RunError> {
    let fit = cycle_fit(s)?;
    if fit.sync0_slaves == 0 {
        return Err(RunError::NoSync0Slave {
            slaves: s.slaves.len(),
        });
    }
    if u64::from(s.cycle_ns) < fit.needed_cycle_ns {
        return Err(RunError::CycleTooShort {
            cycle_us: f64::from(s.cycle_ns) / 1000.0,
            fit,
        });
    }
    Ok(fit)
}
