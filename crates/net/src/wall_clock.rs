//! Kernel timestamps (CLOCK_REALTIME) on the steady clock (CLOCK_MONOTONIC), through their
//! difference, watched for steps.
//!
//! The kernel stamps frames on the wall clock, the engine runs on the monotonic one. Their
//! difference is constant but for steps of the wall clock (`date -s`, an NTP or PTP daemon
//! that steps, a virtual machine's clock set again after it was paused). A stamp taken before
//! a step and converted after it lands off by the whole step: a frame "sent" after its own
//! transmit stamp, a reply that arrived before it left, a segment whose frames arrive out of
//! time. [`RealtimeMap`] reads the difference each time it converts; a stamp that may have
//! been taken on either side of the step it just saw is put on the side that is not after
//! the conversion and nearer to it (right whenever the stamp is younger than the step is
//! large), and one from before two or more steps is not converted at all: the caller counts
//! it unstamped, which every user of a stamp already handles.
//!
//! ```
//! use ecsync_net::wall_clock::RealtimeMap;
//!
//! let mut map = RealtimeMap::new();
//! let rt = ecsync_net::sys::realtime_ns();
//! let epoch = map.epoch();
//! let mono = map.to_monotonic_ns(rt, epoch).expect("no step of the wall clock just now");
//! assert!(mono.abs_diff(ecsync_net::sys::monotonic_ns()) < 100_000_000);
//! ```

use crate::sys;

/// A change of the difference larger than this is a step of the wall clock (reading the
/// difference is exact to the time between two clock reads, well under a microsecond unless
/// the reader was preempted, and such readings are retried).
pub const STEP_NS: u64 = 20_000;

/// Two monotonic reads further apart than this around the wall-clock read: the thread was
/// preempted between them and the reading is retried.
const READ_GAP_NS: u64 = 5_000;

/// How far a converted stamp may be off the monotonic clock: the difference is read as the
/// middle of two monotonic reads at most 5 us apart, around the wall-clock read. A
/// kernel stamp taken a microsecond after a send timestamp (a veth pair's) may come out before
/// it by up to this much.
pub const CONVERSION_ERROR_NS: u64 = READ_GAP_NS / 2;

/// CLOCK_REALTIME minus CLOCK_MONOTONIC, ns (wrapping), and how many steps it took.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RealtimeMap {
    rt_minus_mono_ns: u64,
    /// The difference before the last step.
    before_step_ns: u64,
    epoch: u64,
}

impl Default for RealtimeMap {
    fn default() -> Self {
        Self::new()
    }
}

impl RealtimeMap {
    /// The difference now.
    pub fn new() -> Self {
        let d = read_difference()
            .unwrap_or_else(|| sys::realtime_ns().wrapping_sub(sys::monotonic_ns()));
        RealtimeMap {
            rt_minus_mono_ns: d,
            before_step_ns: d,
            epoch: 0,
        }
    }

    /// The number of steps seen so far: a stamp read in one epoch is converted in the same
    /// one only.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Reads the difference again; true if it stepped since the last reading (the epoch
    /// moves on).
    pub fn refresh(&mut self) -> bool {
        match read_difference() {
            Some(d) => self.observe(d),
            None => false,
        }
    }

    /// Takes a reading of the difference: true if it is a step.
    fn observe(&mut self, rt_minus_mono_ns: u64) -> bool {
        let stepped =
            (rt_minus_mono_ns.wrapping_sub(self.rt_minus_mono_ns) as i64).unsigned_abs() > STEP_NS;
        if stepped {
            self.epoch += 1;
            self.before_step_ns = self.rt_minus_mono_ns;
        }
        self.rt_minus_mono_ns = rt_minus_mono_ns;
        stepped
    }

    /// CLOCK_MONOTONIC of the kernel stamp `rt_ns` read in epoch `read_in`, after reading the
    /// difference again. Across the one step seen since, the stamp goes on the side of it
    /// that is not after now and nearer to now; `None` across two or more.
    pub fn to_monotonic_ns(&mut self, rt_ns: u64, read_in: u64) -> Option<u64> {
        self.refresh();
        self.convert(rt_ns, read_in, sys::monotonic_ns())
    }

    /// The conversion with the differences as last read, at CLOCK_MONOTONIC `now_ns`.
    fn convert(&self, rt_ns: u64, read_in: u64, now_ns: u64) -> Option<u64> {
        let after = rt_ns.wrapping_sub(self.rt_minus_mono_ns);
        if read_in == self.epoch {
            return Some(after);
        }
        if read_in + 1 != self.epoch {
            return None;
        }
        let before = rt_ns.wrapping_sub(self.before_step_ns);
        // Of the two readings, the latest that is not in the future (a little slack for the
        // difference's own reading).
        let not_after_now = |t: u64| t <= now_ns + READ_GAP_NS;
        match (not_after_now(before), not_after_now(after)) {
            (true, true) => Some(before.max(after)),
            (true, false) => Some(before),
            (false, true) => Some(after),
            (false, false) => None,
        }
    }
}

/// The difference, from a wall-clock read between two monotonic reads close together (their
/// middle); `None` if every try was preempted.
fn read_difference() -> Option<u64> {
    for _ in 0..4 {
        let a = sys::monotonic_ns();
        let rt = sys::realtime_ns();
        let b = sys::monotonic_ns();
        if b.wrapping_sub(a) <= READ_GAP_NS {
            return Some(rt.wrapping_sub(a + (b - a) / 2));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const D: u64 = 1_764_000_000_000_000_000;

    #[test]
    fn a_stamp_across_a_step_of_the_wall_clock_goes_on_its_side_of_the_step() {
        let mut m = RealtimeMap {
            rt_minus_mono_ns: D,
            before_step_ns: D,
            epoch: 0,
        };
        // Jitter of the reading is no step.
        assert!(!m.observe(D + 800));
        assert!(!m.observe(D - 300));
        let e0 = m.epoch();
        assert_eq!(m.convert(D + 5_000_000, e0, 5_000_400), Some(5_000_300));
        // The wall clock set 338 us ahead (a paused VM's clock set again). A stamp taken
        // 5 us before now, before the step: on the new difference it would land 343 us ago
        // (before its own send); on the old one it is 5 us ago, not after now.
        assert!(m.observe(D + 338_553));
        let now = 5_005_300;
        assert_eq!(m.convert(D + 5_000_000, e0, now), Some(5_000_300));
        // One taken 5 us ago after the step: the old difference would put it 333 us in the
        // future, the new one puts it right.
        let stamp_after = D + 338_553 + 5_000_300;
        assert_eq!(m.convert(stamp_after, e0, now), Some(5_000_300));
        // In the new epoch, the new difference only.
        let e1 = m.epoch();
        assert_eq!(m.convert(stamp_after, e1, now), Some(5_000_300));
        // Set back by 1 ms: a stamp read before it, taken before it, would be 1 ms in the
        // future on the new difference; one taken after it is the latest reading not after now.
        assert!(m.observe(D - 661_447));
        let now = 7_000_000;
        assert_eq!(m.convert(D + 338_553 + 6_990_000, e1, now), Some(6_990_000));
        assert_eq!(m.convert(D - 661_447 + 6_990_000, e1, now), Some(6_990_000));
        // From before two steps: not converted.
        assert_eq!(m.convert(D + 6_990_000, e0, now), None);
    }

    #[test]
    fn the_difference_read_here_is_steady() {
        let mut m = RealtimeMap::new();
        let e = m.epoch();
        let rt = sys::realtime_ns();
        let mono = m.to_monotonic_ns(rt, e).unwrap();
        assert!(mono.abs_diff(sys::monotonic_ns()) < 100_000_000);
    }
}
