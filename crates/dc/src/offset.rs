//! System time offsets (0x0920) and SYNC0 start times (0x0990).

use crate::time::SystemTime;

/// Rounds a nanosecond value to the nearest integer without `std`.
pub fn round_ns(x: f64) -> i64 {
    if x >= 0.0 {
        (x + 0.5) as i64
    } else {
        (x - 0.5) as i64
    }
}

/// The System Time Offset (0x0920) that makes a slave's system time equal the reference's.
///
/// `own_stamp_ns` is the slave's local time when the latch frame reached its processing unit
/// (0x0918); `reference_time` the system time the reference had when the same frame reached
/// *it*; `delay_ns` the propagation delay from the reference to this slave. When the frame
/// reached this slave the reference read `reference_time + delay_ns`, so that is what the
/// slave's system time must read at its own stamp. For the reference itself pass `delay_ns = 0`
/// and the master's time (SOEM, IgH and ethercrab put the master's clock there).
pub fn system_time_offset(reference_time: SystemTime, delay_ns: i64, own_stamp_ns: u64) -> u64 {
    reference_time
        .wrapping_add_signed(delay_ns)
        .as_ns()
        .wrapping_sub(own_stamp_ns)
}

/// The first instant on the absolute SYNC0 grid (system time `k * cycle + shift`) at least
/// `lead_ns` after `now`. Starting on the absolute grid makes every slave's SYNC0 fall on the
/// same system-time phase, whenever each was programmed.
pub fn sync0_start_time(now: SystemTime, lead_ns: u64, cycle_ns: u32, shift_ns: u32) -> SystemTime {
    let cycle = u64::from(cycle_ns.max(1));
    let shift = u64::from(shift_ns) % cycle;
    let earliest = now.as_ns().saturating_add(lead_ns);
    let base = earliest - earliest % cycle + shift;
    SystemTime::from_ns(if base >= earliest { base } else { base + cycle })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_aligns_a_slave_with_the_reference() {
        // Reference system time 5_000_000 at its stamp; slave 300 ns downstream stamped 12_345.
        // At its stamp the slave must read 5_000_300.
        let off = system_time_offset(SystemTime::from_ns(5_000_000), 300, 12_345);
        assert_eq!(12_345u64.wrapping_add(off), 5_000_300);
        // A slave whose local clock is ahead of the target gets a negative (two's complement)
        // offset.
        let off = system_time_offset(SystemTime::from_ns(1_000), 0, 9_000);
        assert_eq!(off as i64, -8_000);
    }

    #[test]
    fn sync0_start_lies_on_the_grid() {
        assert_eq!(
            sync0_start_time(SystemTime::from_ns(1_234_567), 100_000, 1_000_000, 0),
            SystemTime::from_ns(2_000_000)
        );
        assert_eq!(
            sync0_start_time(SystemTime::from_ns(1_234_567), 100_000, 1_000_000, 300_000),
            SystemTime::from_ns(2_300_000)
        );
        assert_eq!(
            sync0_start_time(SystemTime::from_ns(1_134_567), 100_000, 1_000_000, 300_000),
            SystemTime::from_ns(1_300_000)
        );
        assert_eq!(
            sync0_start_time(SystemTime::from_ns(1_900_001), 0, 1_000_000, 900_000),
            SystemTime::from_ns(2_900_000)
        );
        assert_eq!(
            sync0_start_time(SystemTime::from_ns(0), 0, 1_000, 0),
            SystemTime::from_ns(0)
        );
    }

    #[test]
    fn rounding() {
        assert_eq!(round_ns(2.5), 3);
        assert_eq!(round_ns(-2.5), -3);
        assert_eq!(round_ns(-2.4), -2);
    }
}
