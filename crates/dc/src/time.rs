//! Time in the domains a master meets, as types: an instant of the master's clock and a span
//! of it ([`MasterInstant`], [`MasterDuration`]), the segment's DC system time
//! ([`SystemTime`], 64 bit) and the 32-bit DC time the ESCs' short registers hold
//! ([`DcTime32`], which wraps every 4.29 s). A master time and a system time do not mix by
//! accident: the offset between them is what the master measures.
//!
//! The hot arithmetic stays on integers behind them: each type is one `u64` (or `u32`) with
//! `const` constructors and accessors, and every operation says how it treats overflow
//! (`saturating_`, `wrapping_`, or a signed difference). The unit conversions are written
//! once, here ([`NS_PER_US`], [`NS_PER_MS`], [`NS_PER_S`], [`PS_PER_NS`]).
//!
//! ```
//! use ecsync_dc::time::{DcTime32, MasterDuration, MasterInstant, SystemTime};
//!
//! let sent = MasterInstant::from_ns(10_000_000);
//! let deadline = sent.saturating_add(MasterDuration::from_us(500));
//! assert_eq!(deadline.as_ns(), 10_500_000);
//! assert_eq!(deadline.signed_since(sent), 500_000);
//!
//! // A 32-bit receive time just after its wrap is 1 us after one just before it.
//! let before = DcTime32::of(SystemTime::from_ns(u64::from(u32::MAX) - 499));
//! let after = DcTime32::from_raw(500);
//! assert_eq!(after.signed_since(before), 1_000);
//! ```

use ecsync_wire::dc_time;

/// Nanoseconds per microsecond.
pub const NS_PER_US: u64 = 1_000;
/// Nanoseconds per millisecond.
pub const NS_PER_MS: u64 = 1_000_000;
/// Nanoseconds per second.
pub const NS_PER_S: u64 = 1_000_000_000;
/// Picoseconds per nanosecond (the simulator's real time is in ps).
pub const PS_PER_NS: u64 = 1_000;

/// An instant of the master's clock (the host's monotonic clock, or the simulated master's
/// crystal), ns since that clock's epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[repr(transparent)]
pub struct MasterInstant(u64);

/// A span of the master's clock, ns (a period, a timeout, a lead): never negative.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[repr(transparent)]
pub struct MasterDuration(u64);

/// A DC system time: ns since 2000-01-01 on the segment's timeline (the reference clock's,
/// which every synchronized slave follows). Arithmetic on it wraps, as the registers do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[repr(transparent)]
pub struct SystemTime(u64);

/// The low 32 bits of a DC time, as the ESCs' 32-bit registers hold it (0x0900 receive
/// times of a 32-bit DC unit, 0x0910 read as 4 bytes): it wraps every 2^32 ns (4.29 s), so
/// two of them compare only by their wrapping difference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(transparent)]
pub struct DcTime32(u32);

impl MasterInstant {
    /// The instant `ns` after the clock's epoch.
    pub const fn from_ns(ns: u64) -> Self {
        MasterInstant(ns)
    }

    /// ns after the clock's epoch.
    pub const fn as_ns(self) -> u64 {
        self.0
    }

    /// `d` later, at most the last instant.
    pub const fn saturating_add(self, d: MasterDuration) -> Self {
        MasterInstant(self.0.saturating_add(d.0))
    }

    /// `d` earlier, at least the epoch.
    pub const fn saturating_sub(self, d: MasterDuration) -> Self {
        MasterInstant(self.0.saturating_sub(d.0))
    }

    /// The span since `earlier` (zero if `earlier` is later).
    pub const fn saturating_since(self, earlier: MasterInstant) -> MasterDuration {
        MasterDuration(self.0.saturating_sub(earlier.0))
    }

    /// `self - earlier` in ns, negative if `earlier` is later (wrapping: two instants less
    /// than 2^63 ns apart, which every master clock's are).
    pub const fn signed_since(self, earlier: MasterInstant) -> i64 {
        self.0.wrapping_sub(earlier.0) as i64
    }

    /// Moved by `ns` (either way), wrapping.
    pub const fn wrapping_add_signed(self, ns: i64) -> Self {
        MasterInstant(self.0.wrapping_add_signed(ns))
    }
}

impl MasterDuration {
    /// Zero.
    pub const ZERO: MasterDuration = MasterDuration(0);

    /// `ns` nanoseconds.
    pub const fn from_ns(ns: u64) -> Self {
        MasterDuration(ns)
    }

    /// `us` microseconds.
    pub const fn from_us(us: u64) -> Self {
        MasterDuration(us.saturating_mul(NS_PER_US))
    }

    /// `ms` milliseconds.
    pub const fn from_ms(ms: u64) -> Self {
        MasterDuration(ms.saturating_mul(NS_PER_MS))
    }

    /// In ns.
    pub const fn as_ns(self) -> u64 {
        self.0
    }

    /// In us, as a float (for reports).
    pub fn as_us_f64(self) -> f64 {
        self.0 as f64 / NS_PER_US as f64
    }

    /// In s, as a float (for reports).
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 / NS_PER_S as f64
    }
}

impl SystemTime {
    /// The system time `ns` after 2000-01-01.
    pub const fn from_ns(ns: u64) -> Self {
        SystemTime(ns)
    }

    /// ns after 2000-01-01.
    pub const fn as_ns(self) -> u64 {
        self.0
    }

    /// `self - earlier` in ns, negative if `earlier` is later (wrapping).
    pub const fn signed_since(self, earlier: SystemTime) -> i64 {
        dc_time::diff_u64(self.0, earlier.0)
    }

    /// Moved by `ns` (either way), wrapping.
    pub const fn wrapping_add_signed(self, ns: i64) -> Self {
        SystemTime(dc_time::add_signed_u64(self.0, ns))
    }

    /// The 64-bit time whose low 32 bits are `low` and which lies within 2^31 ns of `self`:
    /// a 32-bit register's value placed on the 64-bit timeline.
    pub const fn extend(self, low: DcTime32) -> SystemTime {
        SystemTime(dc_time::extend_u32(self.0, low.0))
    }
}

impl DcTime32 {
    /// The register's raw value.
    pub const fn from_raw(raw: u32) -> Self {
        DcTime32(raw)
    }

    /// The low 32 bits of `t`.
    pub const fn of(t: SystemTime) -> Self {
        DcTime32(t.0 as u32)
    }

    /// The raw value.
    pub const fn raw(self) -> u32 {
        self.0
    }

    /// `self - earlier` in ns, wrap-aware: right for two times less than 2^31 ns (2.1 s)
    /// apart, whichever side of a wrap they lie.
    pub const fn signed_since(self, earlier: DcTime32) -> i64 {
        dc_time::diff_u32(self.0, earlier.0) as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_32_bit_time_extends_to_the_64_bit_one_nearest() {
        // Hand-computed: near 0x1_0000_0010, the low word 0xFFFF_FFF0 is 32 ns earlier.
        let near = SystemTime::from_ns(0x1_0000_0010);
        assert_eq!(
            near.extend(DcTime32::from_raw(0xFFFF_FFF0)).as_ns(),
            0xFFFF_FFF0
        );
        assert_eq!(near.extend(DcTime32::from_raw(0x20)).as_ns(), 0x1_0000_0020);
        // Exactly the time itself.
        assert_eq!(near.extend(DcTime32::of(near)), near);
    }

    #[test]
    fn differences_keep_their_sign_across_a_wrap() {
        let a = DcTime32::from_raw(u32::MAX - 9);
        let b = DcTime32::from_raw(10);
        assert_eq!(b.signed_since(a), 20);
        assert_eq!(a.signed_since(b), -20);
        let m = MasterInstant::from_ns(5);
        assert_eq!(
            m.saturating_since(MasterInstant::from_ns(9)),
            MasterDuration::ZERO
        );
        assert_eq!(m.signed_since(MasterInstant::from_ns(9)), -4);
    }

    #[test]
    fn units_convert_once() {
        assert_eq!(MasterDuration::from_us(250).as_ns(), 250_000);
        assert_eq!(MasterDuration::from_ms(3).as_ns(), 3 * NS_PER_MS);
        assert_eq!(MasterDuration::from_ns(1_500).as_us_f64(), 1.5);
        assert_eq!(MasterDuration::from_ns(NS_PER_S / 2).as_secs_f64(), 0.5);
    }
}
