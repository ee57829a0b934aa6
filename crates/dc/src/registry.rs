//! The registry of master synchronization methods: each one's name, in one place.
//!
//! [`MethodKind`]'s [`Display`](fmt::Display) and [`FromStr`] use the name,
//! [`MasterSync::name`](crate::MasterSync::name) of every method in [`crate::sync`] and
//! [`crate::dcm`] returns it, and a scenario's `[methods.<name>]` tables are keyed by it
//! ([`crate::method::MethodParams`], with the `serde` feature). The parameters and the type that
//! runs any method are in [`crate::method`]; this module is below it so that the methods
//! themselves can name their kind without an import circle.
//!
//! ```
//! use ecsync_dc::MethodKind;
//!
//! let kind: MethodKind = "median-fit".parse().unwrap();
//! assert_eq!(kind, MethodKind::MedianFit);
//! assert_eq!(kind.to_string(), "median-fit");
//! assert!("median-fitt".parse::<MethodKind>().is_err());
//! assert!(MethodKind::list().to_string().starts_with("median, median-fit, pi-m2s"));
//! ```

use core::fmt;
use core::str::FromStr;

/// A master synchronization method, by name. The order of [`MethodKind::ALL`] is the order
/// reports list them in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MethodKind {
    /// `median`: the letter's method ([`MedianSync`](crate::MedianSync)).
    Median,
    /// `median-fit`: the letter's filter and gain with h_mr and the drift fitted ([`MedianFit`](crate::MedianFit)).
    MedianFit,
    /// `pi-m2s`: the letter's E-M2S baseline ([`PiM2s`](crate::PiM2s)).
    PiM2s,
    /// `bus-shift`: the letter's E-S2M baseline ([`BusShift`](crate::BusShift)).
    BusShift,
    /// `dcm-bus-shift`: the vendor note's DCM moving the reference's time ([`Dcm`](crate::Dcm)).
    DcmBusShift,
    /// `dcm-master-shift`: the vendor note's DCM moving the master's timer ([`Dcm`](crate::Dcm)).
    DcmMasterShift,
    /// `snap`: what ethercrab ships ([`Snap`](crate::Snap)).
    Snap,
    /// `soem-pi`: SOEM's sample loop ([`SoemPi`](crate::SoemPi)).
    SoemPi,
    /// `kickcat-pll`: KickCAT's soft PLL ([`KickcatPll`](crate::KickcatPll)).
    KickcatPll,
    /// `igh-app-time`: IgH's bus shift, the application time written by FPWR
    /// ([`IghAppTime`](crate::IghAppTime)).
    IghAppTime,
    /// `linuxcnc-pll`: linuxcnc-ethercat's PLL ([`LinuxcncPll`](crate::LinuxcncPll)).
    LinuxcncPll,
    /// `des`: double exponential smoothing of the offset and drift ([`Des`](crate::Des)).
    Des,
    /// `kalman`: a two-state Kalman filter of the offset and drift ([`Kalman`](crate::Kalman)).
    Kalman,
}

/// How many methods there are.
pub const METHOD_COUNT: usize = 13;

impl MethodKind {
    /// Every method, in report order.
    pub const ALL: [MethodKind; METHOD_COUNT] = [
        MethodKind::Median,
        MethodKind::MedianFit,
        MethodKind::PiM2s,
        MethodKind::BusShift,
        MethodKind::DcmBusShift,
        MethodKind::DcmMasterShift,
        MethodKind::Snap,
        MethodKind::SoemPi,
        MethodKind::KickcatPll,
        MethodKind::IghAppTime,
        MethodKind::LinuxcncPll,
        MethodKind::Des,
        MethodKind::Kalman,
    ];

    /// The methods a scenario runs when it names none, and `compare`'s built-in presets: the
    /// letter's four, the vendor note's two DCMs, and what ethercrab and SOEM ship: the first
    /// eight of [`MethodKind::ALL`]. The others run when named (`--methods`, a scenario's
    /// `run.methods`).
    pub const DEFAULT: [MethodKind; 8] = {
        let mut d = [MethodKind::Median; 8];
        let mut i = 0;
        while i < d.len() {
            d[i] = MethodKind::ALL[i];
            i += 1;
        }
        d
    };

    /// Every method's name, in report order.
    pub const NAMES: [&'static str; METHOD_COUNT] = {
        let mut names = [""; METHOD_COUNT];
        let mut i = 0;
        while i < METHOD_COUNT {
            names[i] = MethodKind::ALL[i].name();
            i += 1;
        }
        names
    };

    /// The method's name: the word a scenario, the command line and every report use.
    pub const fn name(self) -> &'static str {
        match self {
            MethodKind::Median => "median",
            MethodKind::MedianFit => "median-fit",
            MethodKind::PiM2s => "pi-m2s",
            MethodKind::BusShift => "bus-shift",
            MethodKind::DcmBusShift => "dcm-bus-shift",
            MethodKind::DcmMasterShift => "dcm-master-shift",
            MethodKind::Snap => "snap",
            MethodKind::SoemPi => "soem-pi",
            MethodKind::KickcatPll => "kickcat-pll",
            MethodKind::IghAppTime => "igh-app-time",
            MethodKind::LinuxcncPll => "linuxcnc-pll",
            MethodKind::Des => "des",
            MethodKind::Kalman => "kalman",
        }
    }

    /// What the method is, in a few words (for `--help` and reports).
    pub const fn summary(self) -> &'static str {
        match self {
            MethodKind::Median => {
                "the letter's method: master shift, median filter w, gain k, h_mr averaged over the init frames (eq. 5-14)"
            }
            MethodKind::MedianFit => {
                "the letter's filter and gain with h_mr and the drift fitted over the init frames: holds the target on any crystals"
            }
            MethodKind::PiM2s => {
                "the letter's E-M2S baseline: master shift, PI on the error from the cycle start"
            }
            MethodKind::BusShift => {
                "the letter's E-S2M baseline: the send timestamp written to the reference's 0x0910 every cycle"
            }
            MethodKind::DcmBusShift => {
                "the vendor note's DCM bus shift: filtered PI on the frame's phase, the reference's time moved"
            }
            MethodKind::DcmMasterShift => {
                "the vendor note's DCM master shift: the same controller moving the master's timer"
            }
            MethodKind::Snap => {
                "what ethercrab ships: wait to the reference's next grid point from the send, gain 1, no filter"
            }
            MethodKind::SoemPi => {
                "SOEM's sample loop: sign-counting integral on the reference time's phase"
            }
            MethodKind::KickcatPll => {
                "KickCAT's soft PLL: clamped PI on the smoothed phase, slew-limited, with lock hysteresis"
            }
            MethodKind::IghAppTime => {
                "IgH's bus shift: the application time (read right before the send) written to 0x0910 by FPWR every second cycle"
            }
            MethodKind::LinuxcncPll => {
                "linuxcnc-ethercat's PLL: the task's period stepped by +-P/1000 on the sign of the folded reference phase"
            }
            MethodKind::Des => {
                "double exponential smoothing of the master-to-reference offset and drift, fed forward"
            }
            MethodKind::Kalman => {
                "a two-state Kalman filter of the master-to-reference offset and drift, fed forward"
            }
        }
    }

    /// Whether the method shifts the master (its sends follow the network's time) rather than
    /// the network (it writes its send time into the reference's clock before the frame
    /// leaves): only a master-shift method can take a transmit stamp, which comes after the
    /// send, as its t_ms.
    pub const fn is_master_shift(self) -> bool {
        !matches!(
            self,
            MethodKind::BusShift | MethodKind::DcmBusShift | MethodKind::IghAppTime
        )
    }

    /// Whether the method spends initialisation frames before it corrects (their number is
    /// its `init_frames` parameter).
    pub const fn has_init_frames(self) -> bool {
        matches!(
            self,
            MethodKind::Median | MethodKind::MedianFit | MethodKind::PiM2s
        )
    }

    /// The names of all methods, comma-separated, for messages (`median, median-fit, ...`).
    pub const fn list() -> MethodList {
        MethodList
    }
}

impl fmt::Display for MethodKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is no method's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown method; use one of: {}", MethodList)]
pub struct ParseMethodError;

impl FromStr for MethodKind {
    type Err = ParseMethodError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        MethodKind::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or(ParseMethodError)
    }
}

/// The names of all methods, comma-separated ([`MethodKind::list`]); a type, not a string,
/// because this crate does not allocate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MethodList;

impl fmt::Display for MethodList {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, name) in MethodKind::NAMES.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(name)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_parses_back_and_displays_itself() {
        for (i, m) in MethodKind::ALL.into_iter().enumerate() {
            assert_eq!(m.name().parse::<MethodKind>(), Ok(m));
            assert_eq!(MethodKind::NAMES[i], m.name());
            assert!(!m.summary().is_empty());
        }
        // Names are exact: no case folding, no prefixes.
        assert_eq!("Median".parse::<MethodKind>(), Err(ParseMethodError));
        assert_eq!("med".parse::<MethodKind>(), Err(ParseMethodError));
        assert_eq!("".parse::<MethodKind>(), Err(ParseMethodError));
    }
}
