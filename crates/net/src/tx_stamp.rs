//! Transmit timestamps as the master's send time t_ms.
//!
//! The letter's master-shift methods take t_ms, the send timestamp, in user space right
//! before the frame goes to the kernel: everything after it (the stack, the driver, the NIC's
//! queue: the jitter j_c) lands in the reference time they compare it with and passes for
//! network behaviour. The kernel's software transmit stamp (taken by the driver as the frame
//! goes to the device) leaves out the stack; the NIC's hardware stamp (taken as the frame's
//! first bit leaves) leaves out everything. `ecsync run --tx-stamp` hands the method the best
//! the interface gives (see [`TxStampMode`]).
//!
//! A hardware stamp is in the PTP hardware clock's time, free-running beside the host's: it
//! is mapped to CLOCK_REALTIME (and from there to the master's clock) by readings of the PHC
//! between two of CLOCK_REALTIME, the narrowest of a few, taken again every
//! [`PHC_REFRESH_NS`] and extrapolated between with the rate of the last two ([`PhcMap`]).

use std::fmt;
use std::str::FromStr;

/// How often the PHC-to-host mapping is measured again, ns: a free-running PHC drifts from
/// the host clock by up to ~100 ppm, which the rate of the last two readings takes out to well
/// under a microsecond over this long.
pub const PHC_REFRESH_NS: u64 = 100_000_000;

/// Readings of the PHC per measurement; the narrowest sandwich is kept.
pub const PHC_READINGS: usize = 5;

/// Which transmit timestamp the master-shift methods take as t_ms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TxStampMode {
    /// The user-space timestamp right before the send (the letter's t_ms).
    Off,
    /// The kernel's software transmit stamp.
    Software,
    /// The NIC's hardware transmit stamp; refused where the NIC has none.
    Hardware,
    /// Hardware where the NIC gives it, the kernel's software stamp otherwise.
    #[default]
    Auto,
}

impl TxStampMode {
    /// Every mode, in the order `--help` lists them.
    pub const ALL: [TxStampMode; 4] = [
        TxStampMode::Off,
        TxStampMode::Software,
        TxStampMode::Hardware,
        TxStampMode::Auto,
    ];

    /// The mode's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TxStampMode::Off => "off",
            TxStampMode::Software => "software",
            TxStampMode::Hardware => "hardware",
            TxStampMode::Auto => "auto",
        }
    }
}

impl fmt::Display for TxStampMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for TxStampMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        TxStampMode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!("unknown TX stamp mode {s:?}; use off, software, hardware or auto")
            })
    }
}

/// The source a run's t_ms came from, once the mode met the interface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TxStampSource {
    /// The user-space send timestamp.
    SendTimestamp,
    /// The kernel's software transmit stamp.
    KernelSoftware,
    /// The NIC's hardware transmit stamp.
    NicHardware,
}

/// The offset of a PHC reading from the middle of the CLOCK_REALTIME readings around it, of
/// the narrowest of `readings` (realtime before, PHC, realtime after; ns): `(realtime at the
/// middle, PHC - realtime)`. `None` without a usable reading (a PHC read that failed reads 0).
pub fn phc_offset_ns(readings: &[(u64, u64, u64)]) -> Option<(u64, i64)> {
    readings
        .iter()
        .filter(|&&(a, p, b)| p != 0 && b >= a)
        .min_by_key(|&&(a, _, b)| b - a)
        .map(|&(a, p, b)| {
            let mid = a + (b - a) / 2;
            (mid, p as i64 - mid as i64)
        })
}

/// PHC time to CLOCK_REALTIME from the last two offset measurements: the last offset,
/// extrapolated with the rate between the two.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhcMap {
    last: Option<(u64, i64)>,
    rate: f64,
}

impl PhcMap {
    /// Adds a measurement (from [`phc_offset_ns`]).
    pub fn add(&mut self, at_realtime_ns: u64, offset_ns: i64) {
        if let Some((t0, o0)) = self.last
            && at_realtime_ns > t0
        {
            self.rate = (offset_ns - o0) as f64 / (at_realtime_ns - t0) as f64;
        }
        self.last = Some((at_realtime_ns, offset_ns));
    }

    /// The CLOCK_REALTIME instant of PHC time `phc_ns` (`None` before any measurement).
    pub fn to_realtime_ns(&self, phc_ns: u64) -> Option<u64> {
        let (t1, o1) = self.last?;
        // phc = rt + o1 + rate (rt - t1)  =>  rt = (phc - o1 + rate t1) / (1 + rate).
        // (In integers but for the small correction: an f64 holds a date in ns to 256 ns.)
        let rt_first = (phc_ns as i64).wrapping_sub(o1);
        let dt = rt_first.wrapping_sub(t1 as i64) as f64;
        let correction = self.rate * dt / (1.0 + self.rate);
        Some(rt_first.wrapping_sub(correction.round() as i64) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_parse_and_print() {
        for m in TxStampMode::ALL {
            assert_eq!(m.name().parse::<TxStampMode>(), Ok(m));
        }
        let e = "nic".parse::<TxStampMode>().unwrap_err();
        assert!(e.contains("off, software, hardware or auto"), "{e}");
    }

    #[test]
    fn the_narrowest_sandwich_gives_the_offset() {
        // A PHC 1 000 000 ns ahead; the second reading was delayed by a preemption after the
        // PHC read (wide), the third is tight.
        let r = [
            (1_000, 1_001_020, 1_040),
            (2_000, 1_002_010, 9_000),
            (3_000, 1_003_005, 3_010),
            (0, 0, 10),
        ];
        assert_eq!(phc_offset_ns(&r), Some((3_005, 1_000_000)));
        assert_eq!(phc_offset_ns(&[]), None);
        assert_eq!(phc_offset_ns(&[(5, 0, 6)]), None);
    }

    #[test]
    fn a_drifting_phc_maps_back_to_the_host_time() {
        // The PHC runs 80 ppm fast and 5 s ahead of a date in 2026 (CLOCK_REALTIME's ns
        // need 61 bits: no f64 may hold them).
        const T0: u64 = 1_795_000_000_000_000_000;
        let phc = |rt: u64| 5_000_000_000 + rt + ((rt - T0) as f64 * 80e-6) as u64;
        let mut m = PhcMap::default();
        assert_eq!(m.to_realtime_ns(123), None);
        for rt in [T0 + 10_000_000_000, T0 + 10_100_000_000] {
            m.add(rt, phc(rt) as i64 - rt as i64);
        }
        // 70 ms after the last measurement: within a nanosecond or two.
        for rt in [
            T0 + 10_100_000_000,
            T0 + 10_170_000_000,
            T0 + 10_200_000_000,
        ] {
            let back = m.to_realtime_ns(phc(rt)).unwrap();
            assert!((back as i64 - rt as i64).abs() <= 2, "{rt}: {back}");
        }
        // Without the rate (one measurement) the error grows with the drift: 80 ppm of 70 ms.
        let mut one = PhcMap::default();
        let rt0 = T0 + 10_100_000_000;
        one.add(rt0, phc(rt0) as i64 - rt0 as i64);
        let back = one.to_realtime_ns(phc(rt0 + 70_000_000)).unwrap();
        assert!(((back as i64 - (rt0 + 70_000_000) as i64) - 5_600).abs() <= 2);
    }
}
