//! Table 1 of the letter (Xu et al., "Clock Drift Compensation for Master-Slave Clock
//! Synchronization in EtherCAT Networks", IEICE Trans. Fundamentals, 2024), in ns.

use ecsync_dc::MethodKind;

/// MMean, MStd, MMax, MMin of one error.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Row {
    /// MMean, ns.
    pub mean: f64,
    /// MStd, ns.
    pub std: f64,
    /// MMax, ns.
    pub max: f64,
    /// MMin, ns.
    pub min: f64,
}

/// The letter's M-rS and rS-IS rows for a method (`median` is "Proposed", `pi-m2s` is E-M2S,
/// `bus-shift` is E-S2M); `None` for methods the letter did not measure.
pub fn table1(method: MethodKind) -> Option<(Row, Row)> {
    let r = |mean: f64, std: f64, max: f64, min: f64| Row {
        mean: mean * 1000.0,
        std: std * 1000.0,
        max: max * 1000.0,
        min: min * 1000.0,
    };
    Some(match method {
        MethodKind::Median => (
            r(-0.091, 0.729, 2.153, -11.858),
            r(0.098, 0.017, 0.132, 0.061),
        ),
        MethodKind::PiM2s => (
            r(1.236, 2.609, 28.002, -18.315),
            r(0.135, 0.033, 0.229, 0.085),
        ),
        MethodKind::BusShift => (
            r(-0.082, 0.867, 3.274, -12.479),
            r(0.502, 0.369, 2.913, 0.156),
        ),
        _ => return None,
    })
}

/// The letter's name for a method.
pub fn letter_name(method: MethodKind) -> &'static str {
    match method {
        MethodKind::Median => "Proposed",
        MethodKind::PiM2s => "E-M2S",
        MethodKind::BusShift => "E-S2M",
        _ => "-",
    }
}
