//! The virtual segment on a network interface: every EtherCAT frame that arrives is processed by
//! the segment at the instant it arrived and sent back, as the last ESC's open port would return
//! it. The ESCs' clocks run on CLOCK_MONOTONIC with their configured crystal errors, so a master
//! on the other end sees drifting slave clocks, propagation delays and a time control loop as on
//! real hardware.
//!
//! As a real ESC does with whatever arrives at its port 0, every EtherCAT frame is processed,
//! whatever its source address says (a master whose NIC address is locally administered, bit
//! 0x02 of the first byte set, is answered like any other). The segment's own answers, which a
//! packet socket would see again on the way out, are told apart by the socket address's packet
//! type (`PACKET_OUTGOING`, see [`crate::sys::PacketSocket`]), not by the frame's contents.

use crate::link::NetError;
use crate::sys::{self, PacketSocket, Ready};
use ecsync_esc::Segment;
use ecsync_esc::pcap::PcapCapture;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

/// Counters of a serving segment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ServeStats {
    /// EtherCAT frames received.
    pub received: u64,
    /// Frames processed and sent back.
    pub answered: u64,
    /// Frames that arrived with bit 0x02 of the source address's first byte set (a locally
    /// administered master NIC, or a frame that had passed an ESC already): processed as any
    /// frame, counted for the record.
    pub marked_on_arrival: u64,
    /// Frames the segment did not return (malformed, or lost in the topology).
    pub not_returned: u64,
    /// Frames too long for the buffer.
    pub truncated: u64,
}

/// Serves `segment` on `sock` until `stop` is raised. `capture` records every frame in and out.
/// `on_frame` sees the counters after each frame.
pub fn serve<W: Write>(
    sock: &PacketSocket,
    segment: &mut Segment,
    mut capture: Option<&mut PcapCapture<W>>,
    stop: &AtomicBool,
    mut on_frame: impl FnMut(&ServeStats),
) -> Result<ServeStats, NetError> {
    let io = |what| move |source| NetError::Io { what, source };
    let t0_mono = sys::monotonic_ns();
    let mut stats = ServeStats::default();
    let mut buf = vec![0u8; 2048];
    let mut last_ps = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let Some(r) = sock.recv(&mut buf).map_err(io("receive"))? else {
            if sock.wait(50_000_000).map_err(io("wait for a frame"))? == Ready::ErrorQueue {
                // Transmit timestamps of the replies: not needed here, but they must be read
                // or every wait returns at once.
                while sock
                    .take_tx_timestamp()
                    .map_err(io("TX timestamp"))?
                    .is_some()
                {}
            }
            continue;
        };
        stats.received += 1;
        if r.truncated {
            stats.truncated += 1;
            continue;
        }
        let frame = &mut buf[..r.len];
        if frame.len() > 6 && frame[6] & 0x02 != 0 {
            stats.marked_on_arrival += 1;
        }
        // The instant the frame arrived, on the segment's time line (ps since serving began).
        let mono = match r.kernel_rx_realtime_ns {
            Some(rt) => rt.wrapping_sub(sys::realtime_ns().wrapping_sub(sys::monotonic_ns())),
            None => sys::monotonic_ns(),
        };
        let t_ps = (mono.saturating_sub(t0_mono))
            .saturating_mul(1000)
            .max(last_ps);
        last_ps = t_ps;
        if let Some(c) = capture.as_deref_mut() {
            let _ = c.record(t_ps, frame);
        }
        let out = segment.process(frame, t_ps);
        match out.returned_sof_ps {
            Some(back_ps) => {
                sock.send(frame).map_err(io("send"))?;
                stats.answered += 1;
                if let Some(c) = capture.as_deref_mut() {
                    let _ = c.record(back_ps, frame);
                }
            }
            None => stats.not_returned += 1,
        }
        on_frame(&stats);
    }
    Ok(stats)
}
