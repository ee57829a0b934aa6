//! The cyclic loop on a real network: wake at the method's scheduled start (absolute deadline on
//! CLOCK_MONOTONIC), timestamp, send the cyclic frame, wait for it, let the method decide the
//! next start. Nothing is allocated per cycle.

use crate::link::{NetError, RealLink};
use ecsync_dc::MasterSync;
use ecsync_master::cyclic::{CycleRecord, CyclicEngine};
use std::sync::atomic::{AtomicBool, Ordering};

/// When the loop stops by itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CyclicLimits {
    /// Stop after this much master time, ns.
    pub duration_ns: Option<u64>,
    /// Stop after this many cycles.
    pub max_cycles: Option<u64>,
    /// Give up when this many frames in a row were lost: the network is gone.
    pub lost_in_a_row: u64,
}

impl Default for CyclicLimits {
    fn default() -> Self {
        CyclicLimits {
            duration_ns: None,
            max_cycles: None,
            lost_in_a_row: 100,
        }
    }
}

/// One cycle as it happened on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RealCycle {
    /// What the engine and the method made of it.
    pub record: CycleRecord,
    /// When the task woke, master time, ns.
    pub woke_ns: u64,
    /// Wake-up latency: woke minus scheduled, ns (negative never happens on Linux). When the
    /// task woke a whole period or more late, from the slot it missed first.
    pub wake_latency_ns: i64,
    /// Cycles skipped right before this one because the task woke after their slots had
    /// passed: the host stalled for at least a period.
    pub skipped_before: u64,
    /// The kernel's transmit timestamp, master time, ns.
    pub kernel_tx_ns: Option<u64>,
    /// Send timestamp to reply, ns.
    pub round_trip_ns: Option<u64>,
}

/// Why the loop stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stopped {
    /// The duration passed.
    Duration,
    /// The cycle count was reached.
    Cycles,
    /// The stop flag was raised (Ctrl-C).
    Interrupted,
    /// Frames stopped coming back.
    NetworkGone {
        /// The cycle of the last frame that came back (`None`: none did).
        last_good_cycle: Option<u64>,
        /// Frames lost in a row.
        lost_in_a_row: u64,
    },
}

/// Runs the cyclic phase until a limit, the stop flag, or the network's loss.
pub fn run_cyclic<S: MasterSync>(
    link: &mut RealLink,
    eng: &mut CyclicEngine<S>,
    limits: CyclicLimits,
    stop: &AtomicBool,
    mut on_cycle: impl FnMut(&RealCycle),
) -> Result<Stopped, NetError> {
    let clock = *link.clock();
    let period_ns = u64::from(eng.config().period_ns.max(1));
    let start = eng.scheduled_start_ns();
    let mut lost_row = 0u64;
    let mut last_good = None;
    let mut n = 0u64;
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Stopped::Interrupted);
        }
        if limits.max_cycles.is_some_and(|m| n >= m) {
            return Ok(Stopped::Cycles);
        }
        let scheduled = eng.scheduled_start_ns();
        if limits
            .duration_ns
            .is_some_and(|d| scheduled.wrapping_sub(start) >= d)
        {
            return Ok(Stopped::Duration);
        }
        clock.sleep_until(scheduled);
        let woke = clock.now_ns();
        // Woke a whole period late or more: those slots are gone. Skip them and run the
        // cycle whose slot is now (as a PLC task skips an overrun), rather than a burst.
        let late_ns = woke.saturating_sub(scheduled);
        let skipped = late_ns / period_ns;
        if skipped > 0 {
            eng.skip_cycles(skipped);
        }
        let send_ns = clock.now_ns();
        let frame = eng.frame_to_send(send_ns);
        let (record, kernel_tx_ns, round_trip_ns) = match link.exchange(frame)? {
            Some(x) => {
                let (tx, rx) = (x.kernel_tx_ns, x.received_ns);
                let rec = eng.complete(Some(x.reply), send_ns, rx);
                lost_row = 0;
                last_good = Some(rec.cycle);
                (rec, tx, Some(rx.saturating_sub(send_ns)))
            }
            None => {
                lost_row += 1;
                (eng.complete(None, send_ns, clock.now_ns()), None, None)
            }
        };
        on_cycle(&RealCycle {
            record,
            woke_ns: woke,
            wake_latency_ns: woke.wrapping_sub(scheduled) as i64,
            skipped_before: skipped,
            kernel_tx_ns,
            round_trip_ns,
        });
        n += 1;
        if lost_row >= limits.lost_in_a_row.max(1) {
            return Ok(Stopped::NetworkGone {
                last_good_cycle: last_good,
                lost_in_a_row: lost_row,
            });
        }
    }
}
