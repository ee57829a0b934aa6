//! `ecsync host record`: the timing of this host's periodic real-time loop, cycle by cycle, the
//! measurement the simulator's host model is fitted to (ecsync-lab's `host_trace`).
//!
//! Each cycle the task sleeps to its slot (clock_nanosleep, TIMER_ABSTIME, CLOCK_MONOTONIC, as
//! `ecsync run` does), then measures: the wake-up latency (wake-up minus slot), the execution
//! time (wake-up to the send timestamp: building the cycle's frame), and, on an interface, the
//! time from the send timestamp to the kernel's software TX timestamp (SO_TIMESTAMPING). The
//! frame is a broadcast read of register 0x0000 (the ESC type), which changes nothing on an
//! EtherCAT segment.

use crate::link::NetError;
use crate::sys::{self, PacketSocket, Ready};
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};
use std::sync::atomic::{AtomicBool, Ordering};

/// The source address of the recorder's frames (`ecsync run`'s master address).
const SRC_MAC: [u8; 6] = [0x00, 0x1b, 0x21, 0xec, 0x00, 0x01];

/// What to record.
#[derive(Debug, Clone, Copy)]
pub struct RecordConfig<'a> {
    /// The cycle, ns.
    pub cycle_ns: u64,
    /// How long, ns.
    pub duration_ns: u64,
    /// Raised to stop early (Ctrl-C).
    pub stop: Option<&'a AtomicBool>,
}

/// One recorded cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordedCycle {
    /// The cycle's index from the first slot (skipped slots counted).
    pub cycle: u64,
    /// Its slot, CLOCK_MONOTONIC ns.
    pub scheduled_ns: u64,
    /// Wake-up minus slot, ns.
    pub wake_latency_ns: i64,
    /// Wake-up to the send timestamp, ns.
    pub exec_ns: u64,
    /// Send timestamp to the kernel's TX timestamp, ns (none without an interface, or when the
    /// kernel gave none in time).
    pub tx_delay_ns: Option<i64>,
}

/// What a recording did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordSummary {
    /// Cycles recorded.
    pub cycles: u64,
    /// Slots skipped because the task woke after they had passed.
    pub skipped: u64,
    /// Frames sent whose TX timestamp did not come within the wait (or that the interface
    /// refused: down, or its queue full).
    pub tx_stamps_missing: u64,
}

/// Records the loop's timing, handing every cycle to `on_cycle` (outside the measured times),
/// sending a frame on `sock` each cycle when given.
pub fn record(
    cfg: RecordConfig<'_>,
    sock: Option<&PacketSocket>,
    mut on_cycle: impl FnMut(&RecordedCycle),
) -> Result<RecordSummary, NetError> {
    let io = |what: &'static str| move |source| NetError::Io { what, source };
    let period = cfg.cycle_ns.max(1);
    // How long a TX timestamp is waited for: the kernel's come within microseconds; a quarter
    // cycle keeps the next slot clear.
    let tx_wait_ns = (period / 4).clamp(1_000, 2_000_000);
    let mut buf = vec![0u8; 64];
    let mut s = RecordSummary::default();
    // Start on a slot a few cycles ahead, so the first sleep is a real one.
    let t0 = (sys::monotonic_ns() / period + 3) * period;
    let end = t0.saturating_add(cfg.duration_ns);
    let mut k = 0u64;
    let mut rt_map = crate::wall_clock::RealtimeMap::new();
    loop {
        let slot = t0 + k * period;
        if slot >= end || cfg.stop.is_some_and(|f| f.load(Ordering::Relaxed)) {
            break;
        }
        sys::sleep_until_monotonic(slot);
        let woke = sys::monotonic_ns();
        // The cycle's work: drop stale TX timestamps, build the frame.
        if let Some(sock) = sock {
            while sock
                .take_tx_timestamp()
                .map_err(io("TX timestamp"))?
                .is_some()
            {}
        }
        let len = {
            let mut b =
                FrameBuilder::new(&mut buf, [0xff; 6], SRC_MAC).map_err(|_| NetError::Io {
                    what: "frame",
                    source: std::io::Error::other("frame buffer too short"),
                })?;
            b.push(
                Command::Brd,
                k as u8,
                DatagramAddress::Position { adp: 0, ado: 0 },
                &[0, 0],
            )
            .map_err(|_| NetError::Io {
                what: "frame",
                source: std::io::Error::other("frame buffer too short"),
            })?;
            b.finish().max(60)
        };
        let send_mono = sys::monotonic_ns();
        // The stamp is on the wall clock: taken across a step of it, it says nothing.
        let epoch = rt_map.epoch();
        let mut tx_delay_ns = None;
        // A frame the interface refused (down, or its queue full) has no stamp to wait for:
        // counted missing, and the recording goes on.
        let sent = match sock.map(|sock| sock.send(&buf[..len])) {
            Some(Ok(())) => sock,
            Some(Err(e)) if sys::link_is_down(&e) => {
                s.tx_stamps_missing += 1;
                None
            }
            Some(Err(e)) => return Err(io("send")(e)),
            None => None,
        };
        if let Some(sock) = sent {
            let deadline = send_mono + tx_wait_ns;
            loop {
                if let Some(t) = sock.take_tx_timestamp().map_err(io("TX timestamp"))? {
                    match rt_map.to_monotonic_ns(t, epoch) {
                        Some(m) => tx_delay_ns = Some(m as i64 - send_mono as i64),
                        None => s.tx_stamps_missing += 1,
                    }
                    break;
                }
                let now = sys::monotonic_ns();
                if now >= deadline {
                    s.tx_stamps_missing += 1;
                    break;
                }
                // A frame coming in (the segment's answer) is no stamp: read it and go on.
                // The interface gone down meanwhile: no stamp is coming (counted missing).
                match sock.wait(deadline - now) {
                    Ok(Ready::Frame) => {
                        let mut rx = [0u8; 2048];
                        match sock.recv(&mut rx) {
                            Ok(_) => {}
                            Err(e) if sys::link_is_down(&e) => {
                                s.tx_stamps_missing += 1;
                                break;
                            }
                            Err(e) => return Err(io("receive")(e)),
                        }
                    }
                    Ok(_) => {}
                    Err(e) if sys::link_is_down(&e) => {
                        s.tx_stamps_missing += 1;
                        break;
                    }
                    Err(e) => return Err(io("wait")(e)),
                }
            }
        }
        let c = RecordedCycle {
            cycle: k,
            scheduled_ns: slot,
            wake_latency_ns: woke as i64 - slot as i64,
            exec_ns: send_mono.saturating_sub(woke),
            tx_delay_ns,
        };
        on_cycle(&c);
        s.cycles += 1;
        k += 1;
        // Slots already passed are skipped (counted), as the master's cyclic driver does.
        let now = sys::monotonic_ns();
        let next = t0 + k * period;
        if now > next {
            let behind = (now - next) / period;
            s.skipped += behind;
            k += behind;
        }
    }
    Ok(s)
}
