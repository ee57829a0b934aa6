//! Lock detection from the System Time Difference register (0x092C), the datasheet's way
//! (section I, 9.1.3.5): the network is in sync when every slave's |difference| stays below a
//! threshold.

use ecsync_wire::dc_time::decode_time_difference;

/// Decides when the segment is in sync from successive reads of 0x092C.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LockDetector {
    threshold_ns: u32,
    required: u32,
    run: u32,
    first_good_ns: Option<u64>,
    locked_at_ns: Option<u64>,
    last_violation_ns: Option<u64>,
}

impl LockDetector {
    /// Locked once `required` consecutive reads all stay below `threshold_ns`.
    pub const fn new(threshold_ns: u32, required: u32) -> Self {
        LockDetector {
            threshold_ns,
            required,
            run: 0,
            first_good_ns: None,
            locked_at_ns: None,
            last_violation_ns: None,
        }
    }

    /// Feeds one round of 0x092C values (raw register contents of every synchronised slave)
    /// read at time `t_ns`; returns the largest |difference| in ns.
    pub fn update_raw(&mut self, raw: impl IntoIterator<Item = u32>, t_ns: u64) -> u32 {
        let worst = raw
            .into_iter()
            .map(|r| decode_time_difference(r).unsigned_abs())
            .max()
            .unwrap_or(0);
        self.update(worst, t_ns);
        worst
    }

    /// Feeds the largest |difference| of one round read at `t_ns`.
    pub fn update(&mut self, worst_abs_ns: u32, t_ns: u64) {
        if worst_abs_ns < self.threshold_ns {
            if self.run == 0 {
                self.first_good_ns = Some(t_ns);
            }
            self.run = self.run.saturating_add(1);
            if self.run >= self.required && self.locked_at_ns.is_none() {
                self.locked_at_ns = self.first_good_ns;
            }
        } else {
            self.run = 0;
            self.first_good_ns = None;
            self.last_violation_ns = Some(t_ns);
            self.locked_at_ns = None;
        }
    }

    /// Whether the segment is locked now.
    pub fn is_locked(&self) -> bool {
        self.locked_at_ns.is_some()
    }

    /// When the current good run began, if it has lasted long enough to count as lock.
    pub fn locked_at_ns(&self) -> Option<u64> {
        self.locked_at_ns
    }

    /// When a read last exceeded the threshold.
    pub fn last_violation_ns(&self) -> Option<u64> {
        self.last_violation_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locks_after_a_run_and_unlocks_on_a_violation() {
        let mut l = LockDetector::new(100, 3);
        l.update_raw([0x8000_00c8], 0); // 200 ns ahead
        assert!(!l.is_locked());
        l.update_raw([50, 0x8000_0010], 10);
        l.update_raw([20], 20);
        assert!(!l.is_locked());
        l.update_raw([99], 30);
        assert_eq!(l.locked_at_ns(), Some(10));
        assert_eq!(l.update_raw([100], 40), 100);
        assert!(!l.is_locked());
        assert_eq!(l.last_violation_ns(), Some(40));
    }
}
