//! Every master synchronization method's parameters with their defaults, their checks, and
//! one type, [`Method`], that runs any method of the [registry](crate::registry) by static
//! dispatch.
//!
//! A scenario's `[methods]` table is a [`MethodParams`] (with the `serde` feature it
//! deserializes from it, keyed by the registry's names); [`MethodParams::build`] makes the
//! method a [`MethodKind`] names, at a cycle and target phase ([`MethodContext`]).
//!
//! ```
//! use ecsync_dc::method::{MethodContext, MethodKind, MethodParams};
//! use ecsync_dc::MasterSync;
//!
//! let kind: MethodKind = "median-fit".parse().unwrap();
//! let params = MethodParams::default();
//! let ctx = MethodContext { cycle_ns: 1_000_000, target_phase_ns: 0 };
//! params.check().unwrap();
//! params.check_use(kind, &ctx).unwrap();
//! let method = params.build(kind, &ctx);
//! assert_eq!(method.name(), "median-fit");
//! assert_eq!(method.init_cycles(), 10_000);
//! assert!("median-fitt".parse::<MethodKind>().is_err());
//! ```

use crate::dcm::{Dcm, DcmMode, DcmParams, SetValueRef};
use crate::estimate::{Des, DesParams, Kalman, KalmanParams};
use crate::masters::{
    IghAppTime, IghAppTimeParams, KickcatPll, KickcatPllParams, LinuxcncPll, LinuxcncPllParams,
};
pub use crate::registry::{MethodKind, MethodList, ParseMethodError};
use crate::sync::{
    BusShift, ControllerLog, CycleInput, CycleOutput, MAX_WINDOW, MasterSync, MedianFit,
    MedianSync, PiM2s, ReferenceWrite, Snap, SoemPi, WriteTimes,
};
use core::fmt;

/// Parameters of `median` and `median-fit` (the letter's defaults). The integers are signed so
/// that a negative value in a file is refused by [`MethodParams::check`] with a hint rather than
/// by the parser with a type error.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct MedianParams {
    /// Median window w (odd, 1 ..= [`MAX_WINDOW`]).
    pub window: i64,
    /// Gain k.
    pub gain: f64,
    /// Frames averaged (median) or fitted (median-fit) for h_mr.
    pub init_frames: i64,
}

impl Default for MedianParams {
    fn default() -> Self {
        MedianParams {
            window: 11,
            gain: 0.01,
            init_frames: 10_000,
        }
    }
}

/// Parameters of `pi-m2s` (the letter's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct PiM2sParams {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain.
    pub ki: f64,
    /// Frames averaged for the offset.
    pub init_frames: i64,
}

impl Default for PiM2sParams {
    fn default() -> Self {
        PiM2sParams {
            kp: 0.125,
            ki: 0.0005,
            init_frames: 10_000,
        }
    }
}

/// Parameters of `bus-shift`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct BusShiftParams {
    /// Added to the written master time, ns.
    pub write_offset_ns: i64,
}

/// `snap` and `soem-pi` have no parameters of their own: they aim at the run's target phase
/// ([`MethodContext::target_phase_ns`]). The offsets they had in earlier versions are still
/// read, so that [`MethodParams::check`] refuses them with that hint instead of the parser
/// calling them unknown.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct AimedParams {
    shift_ns: Option<i64>,
    offset_ns: Option<i64>,
}

/// Parameters of `dcm-bus-shift` and `dcm-master-shift` in a scenario's units (times in us
/// and ms, independent of the cycle); [`DcmSettings::to_params`] turns them into the
/// controller's [`DcmParams`] at a cycle. Defaults from [`DcmParams::default_for`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct DcmSettings {
    /// What the set value is measured from: "frame-send" or "cycle-start".
    pub set_value_ref: SetValueRef,
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain.
    pub ki: f64,
    /// Filter weight 2^-depth.
    pub filter_depth: i64,
    /// Errors further than this from the filtered error are not used once in sync, us.
    pub max_valid_us: f64,
    /// The in-sync band, us.
    pub in_sync_limit_us: f64,
    /// How long the filtered error must stay in the band, ms.
    pub in_sync_hold_ms: f64,
    /// The most the re-adjustment's proportional part moves per cycle, ppm of the cycle (0: no
    /// limit; `None`: bus shift's default 5, master shift's 0).
    pub max_slew_ppm: Option<f64>,
}

/// The cycle the DCM defaults are stated at (their hold time is given in cycles of it).
const DCM_DEFAULT_CYCLE_NS: u32 = 1_000_000;

impl Default for DcmSettings {
    fn default() -> Self {
        let d = DcmParams::default_for(0, DCM_DEFAULT_CYCLE_NS);
        DcmSettings {
            set_value_ref: d.set_value_ref,
            kp: d.kp,
            ki: d.ki,
            filter_depth: i64::from(d.filter_depth),
            max_valid_us: d.max_valid_ns as f64 / 1000.0,
            in_sync_limit_us: d.in_sync_limit_ns as f64 / 1000.0,
            // 1.5 s: the default's hold is given in cycles of 1 ms.
            in_sync_hold_ms: d.in_sync_hold_cycles as f64,
            max_slew_ppm: None,
        }
    }
}

/// Rounds half away from zero, as `f64::round` (which `core` lacks), saturating as `as` does:
/// exact, since subtracting the integer part of a float below 2^53 is exact and above it
/// every float is an integer.
fn round_to_i64(x: f64) -> i64 {
    let t = x as i64;
    let frac = x - t as f64;
    if frac >= 0.5 {
        t.saturating_add(1)
    } else if frac <= -0.5 {
        t.saturating_sub(1)
    } else {
        t
    }
}

impl DcmSettings {
    /// The controller's parameters at a cycle and target, for bus shift or master shift.
    pub fn to_params(&self, target_phase_ns: i64, cycle_ns: u32, bus_shift: bool) -> DcmParams {
        let default_slew = if bus_shift {
            DcmParams::default_bus_shift(0, DCM_DEFAULT_CYCLE_NS).max_slew_ppm
        } else {
            0.0
        };
        DcmParams {
            max_slew_ppm: self.max_slew_ppm.unwrap_or(default_slew),
            set_value_ref: self.set_value_ref,
            target_phase_ns,
            kp: self.kp,
            ki: self.ki,
            filter_depth: self.filter_depth.clamp(0, 20) as u8,
            max_valid_ns: round_to_i64(self.max_valid_us * 1000.0),
            in_sync_limit_ns: round_to_i64(self.in_sync_limit_us * 1000.0),
            in_sync_hold_cycles: round_to_i64(
                self.in_sync_hold_ms * 1e6 / f64::from(cycle_ns.max(1)),
            )
            .max(1) as u64,
        }
    }
}

/// Every method's parameters: a scenario's `[methods]` table, one `[methods.<name>]` table per
/// method, each optional (defaults otherwise). With the `serde` feature it deserializes from
/// that table; an unknown method's table or an unknown field is refused by name.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MethodParams {
    /// `median`.
    pub median: MedianParams,
    /// `median-fit`.
    pub median_fit: MedianParams,
    /// `pi-m2s`.
    pub pi_m2s: PiM2sParams,
    /// `bus-shift`.
    pub bus_shift: BusShiftParams,
    /// `dcm-bus-shift`.
    pub dcm_bus_shift: DcmSettings,
    /// `dcm-master-shift`.
    pub dcm_master_shift: DcmSettings,
    /// `snap`.
    pub snap: AimedParams,
    /// `soem-pi`.
    pub soem_pi: AimedParams,
    /// `kickcat-pll`.
    pub kickcat_pll: KickcatPllParams,
    /// `igh-app-time`.
    pub igh_app_time: IghAppTimeParams,
    /// `linuxcnc-pll`.
    pub linuxcnc_pll: LinuxcncPllParams,
    /// `des`.
    pub des: DesParams,
    /// `kalman`.
    pub kalman: KalmanParams,
}

/// What every method of a run shares: the cycle and the phase the frames aim at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MethodContext {
    /// Cycle time and SYNC0 period, ns.
    pub cycle_ns: u32,
    /// Where the frame's arrival at the reference is aimed against the DC grid point, ns
    /// (within half a cycle).
    pub target_phase_ns: i64,
}

impl MethodContext {
    /// A target phase given in us (a scenario's `run.target_phase_us`), ns; refused when it is
    /// no number or absurdly large (whether it lies within half the cycle is
    /// [`MethodContext::check`]'s).
    pub fn target_phase_from_us(target_phase_us: f64) -> Result<i64, ParamError> {
        if !target_phase_us.is_finite() || target_phase_us.abs() > 1e7 {
            return Err(ParamError::run(
                "target_phase_us",
                ParamProblem::TargetPhaseNotANumber(target_phase_us),
            ));
        }
        Ok(round_to_i64(target_phase_us * 1000.0))
    }

    /// Checks that the target phase lies within half a cycle of the grid point.
    pub fn check(&self) -> Result<(), ParamError> {
        let half = i64::from(self.cycle_ns / 2);
        if self.target_phase_ns < -half || self.target_phase_ns >= half {
            return Err(ParamError::run(
                "target_phase_us",
                ParamProblem::TargetPhaseOutside {
                    target_phase_ns: self.target_phase_ns,
                    half_cycle_ns: half,
                },
            ));
        }
        Ok(())
    }
}

impl MethodParams {
    /// The parameters of `kind`'s initialisation frames (`None` for methods without).
    fn init_frames_param(&self, kind: MethodKind) -> Option<i64> {
        match kind {
            MethodKind::Median => Some(self.median.init_frames),
            MethodKind::MedianFit => Some(self.median_fit.init_frames),
            MethodKind::PiM2s => Some(self.pi_m2s.init_frames),
            _ => None,
        }
    }

    /// The method's initialisation frames (0 for methods without, and for a negative value,
    /// which [`MethodParams::check_use`] refuses).
    pub fn init_frames(&self, kind: MethodKind) -> u64 {
        self.init_frames_param(kind).map_or(0, |n| n.max(0) as u64)
    }

    /// Sets the initialisation frames of every method that has them (`ecsync run --init-s`).
    pub fn set_init_frames(&mut self, frames: i64) {
        self.median.init_frames = frames;
        self.median_fit.init_frames = frames;
        self.pi_m2s.init_frames = frames;
    }

    /// Checks the values that do not depend on the run, in every method's table (whether the
    /// method runs or not: a table is either right or wrong), in report order.
    pub fn check(&self) -> Result<(), ParamError> {
        for (kind, p) in [
            (MethodKind::Median, &self.median),
            (MethodKind::MedianFit, &self.median_fit),
        ] {
            if p.window <= 0 || p.window % 2 == 0 || p.window as usize > MAX_WINDOW {
                return Err(ParamError::method(
                    kind,
                    "window",
                    ParamProblem::MedianWindow(p.window),
                ));
            }
            if !(p.gain.is_finite() && p.gain > 0.0 && p.gain <= 1.0) {
                return Err(ParamError::method(
                    kind,
                    "gain",
                    ParamProblem::MedianGain(p.gain),
                ));
            }
        }
        for (key, v) in [("kp", self.pi_m2s.kp), ("ki", self.pi_m2s.ki)] {
            if !(v.is_finite() && (0.0..=2.0).contains(&v)) {
                return Err(ParamError::method(
                    MethodKind::PiM2s,
                    key,
                    ParamProblem::PiGain(v),
                ));
            }
        }
        for (kind, a) in [
            (MethodKind::Snap, &self.snap),
            (MethodKind::SoemPi, &self.soem_pi),
        ] {
            for (key, v) in [("shift_ns", a.shift_ns), ("offset_ns", a.offset_ns)] {
                if v.is_some() {
                    return Err(ParamError::method(kind, key, ParamProblem::OwnOffset));
                }
            }
        }
        self.check_more()
    }

    /// [`MethodParams::check`] of the methods after the letter's, the vendor's and the two
    /// masters' first ones: every value within its range, named with its default.
    fn check_more(&self) -> Result<(), ParamError> {
        use MethodKind as K;
        let (k, i, l) = (&self.kickcat_pll, &self.igh_app_time, &self.linuxcnc_pll);
        let (dk, di, dl) = (
            KickcatPllParams::default(),
            IghAppTimeParams::default(),
            LinuxcncPllParams::default(),
        );
        let (d, kf) = (&self.des, &self.kalman);
        let (dd, dkf) = (DesParams::default(), KalmanParams::default());
        let unit = |v: f64| v > 0.0 && v <= 1.0;
        let gain = |v: f64| (0.0..=1.0).contains(&v);
        let positive = |v: f64| v > 0.0 && v <= 1e9;
        let some = |v: f64| (0.0..=1e9).contains(&v);
        type Rule = (
            MethodKind,
            &'static str,
            f64,
            f64,
            &'static str,
            fn(f64) -> bool,
        );
        let rules: [Rule; 13] = [
            (
                K::KickcatPll,
                "ema_alpha",
                k.ema_alpha,
                dk.ema_alpha,
                "(0, 1]",
                unit,
            ),
            (K::KickcatPll, "kp", k.kp, dk.kp, "[0, 1]", gain),
            (K::KickcatPll, "ki", k.ki, dk.ki, "[0, 1]", gain),
            (
                K::KickcatPll,
                "slew_limit_us",
                k.slew_limit_us,
                dk.slew_limit_us,
                "(0, 1e9]",
                positive,
            ),
            (
                K::KickcatPll,
                "integrator_clamp_us",
                k.integrator_clamp_us,
                dk.integrator_clamp_us,
                "[0, 1e9]",
                some,
            ),
            (
                K::KickcatPll,
                "outlier_reject_us",
                k.outlier_reject_us,
                dk.outlier_reject_us,
                "(0, 1e9]",
                positive,
            ),
            (
                K::IghAppTime,
                "sync_every",
                i.sync_every as f64,
                di.sync_every as f64,
                "1 ..= 1000",
                |v| (1.0..=1000.0).contains(&v),
            ),
            (
                K::LinuxcncPll,
                "step_ns",
                l.step_ns as f64,
                dl.step_ns as f64,
                "0 (a thousandth of the cycle) ..= 100000",
                |v| (0.0..=100_000.0).contains(&v),
            ),
            (K::Des, "alpha", d.alpha, dd.alpha, "(0, 1]", unit),
            (K::Des, "beta", d.beta, dd.beta, "(0, 1]", unit),
            (
                K::Kalman,
                "meas_sigma_ns",
                kf.meas_sigma_ns,
                dkf.meas_sigma_ns,
                "(0, 1e9]",
                positive,
            ),
            (
                K::Kalman,
                "drift_walk_ns",
                kf.drift_walk_ns,
                dkf.drift_walk_ns,
                "[0, 1e9]",
                some,
            ),
            (
                K::Kalman,
                "gate_sigma",
                kf.gate_sigma,
                dkf.gate_sigma,
                "(0, 1e9]",
                positive,
            ),
        ];
        for (kind, key, value, default, range, ok) in rules {
            if !(value.is_finite() && ok(value)) {
                return Err(ParamError::method(
                    kind,
                    key,
                    ParamProblem::OutOfRange {
                        value,
                        range,
                        default,
                    },
                ));
            }
        }
        Ok(())
    }

    /// Checks the table of a method about to run in `ctx`: its initialisation frames, and
    /// DCM's times against the cycle (so a DCM table a short cycle cannot use is refused only
    /// where DCM runs).
    pub fn check_use(&self, kind: MethodKind, ctx: &MethodContext) -> Result<(), ParamError> {
        if let Some(n) = self.init_frames_param(kind)
            && n < 1
        {
            return Err(ParamError::method(
                kind,
                "init_frames",
                ParamProblem::InitFrames(n),
            ));
        }
        let d = match kind {
            MethodKind::DcmBusShift => &self.dcm_bus_shift,
            MethodKind::DcmMasterShift => &self.dcm_master_shift,
            _ => return Ok(()),
        };
        let err = |key, problem| Err(ParamError::method(kind, key, problem));
        for (key, v, max) in [("kp", d.kp, 1.0), ("ki", d.ki, 0.25)] {
            if !(v.is_finite() && v >= 0.0 && v <= max) {
                return err(key, ParamProblem::DcmGain { value: v, max });
            }
        }
        if !(0..=16).contains(&d.filter_depth) {
            return err("filter_depth", ParamProblem::DcmFilterDepth(d.filter_depth));
        }
        let cycle_us = f64::from(ctx.cycle_ns) / 1000.0;
        for (key, v) in [
            ("max_valid_us", d.max_valid_us),
            ("in_sync_limit_us", d.in_sync_limit_us),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= cycle_us) {
                return err(
                    key,
                    ParamProblem::DcmTime {
                        value_us: v,
                        cycle_us,
                    },
                );
            }
        }
        if let Some(v) = d.max_slew_ppm
            && !(v.is_finite() && (0.0..=1000.0).contains(&v))
        {
            return err("max_slew_ppm", ParamProblem::DcmSlew(v));
        }
        let hold = d.in_sync_hold_ms;
        if !(hold.is_finite() && (0.0..=600_000.0).contains(&hold)) {
            return err("in_sync_hold_ms", ParamProblem::DcmHold(hold));
        }
        Ok(())
    }

    /// The method `kind` with these parameters, aiming at `ctx`'s target phase. The values are
    /// taken as they are: check them first ([`MethodParams::check`],
    /// [`MethodParams::check_use`], [`MethodContext::check`]).
    pub fn build(&self, kind: MethodKind, ctx: &MethodContext) -> Method {
        let target = ctx.target_phase_ns;
        let window = |p: &MedianParams| p.window.max(0) as usize;
        let init = |n: i64| n.max(0) as u64;
        match kind {
            MethodKind::Median => Method::Median(MedianSync::new(
                window(&self.median),
                self.median.gain,
                init(self.median.init_frames),
            )),
            MethodKind::MedianFit => Method::MedianFit(MedianFit::new(
                window(&self.median_fit),
                self.median_fit.gain,
                init(self.median_fit.init_frames),
                target,
            )),
            MethodKind::PiM2s => Method::PiM2s(PiM2s::new(
                self.pi_m2s.kp,
                self.pi_m2s.ki,
                init(self.pi_m2s.init_frames),
            )),
            MethodKind::BusShift => Method::BusShift(BusShift {
                write_offset_ns: self.bus_shift.write_offset_ns,
            }),
            MethodKind::DcmBusShift => Method::Dcm(Dcm::new(
                DcmMode::BusShift,
                self.dcm_bus_shift.to_params(target, ctx.cycle_ns, true),
            )),
            MethodKind::DcmMasterShift => Method::Dcm(Dcm::new(
                DcmMode::MasterShift,
                self.dcm_master_shift.to_params(target, ctx.cycle_ns, false),
            )),
            // ethercrab's sync0_shift: the wait runs to the grid point plus the shift.
            MethodKind::Snap => Method::Snap(Snap {
                shift_ns: target.rem_euclid(i64::from(ctx.cycle_ns.max(1))) as u32,
            }),
            // SOEM's offset: the task runs that far after the reference's grid.
            MethodKind::SoemPi => Method::SoemPi(SoemPi::new(target)),
            MethodKind::KickcatPll => Method::KickcatPll(KickcatPll::new(self.kickcat_pll, target)),
            MethodKind::IghAppTime => Method::IghAppTime(IghAppTime::new(
                self.igh_app_time.sync_every.max(1) as u64,
                self.igh_app_time.app_time,
            )),
            MethodKind::LinuxcncPll => {
                Method::LinuxcncPll(LinuxcncPll::new(self.linuxcnc_pll.step_ns, target))
            }
            MethodKind::Des => Method::Des(Des::new(self.des.alpha, self.des.beta, target)),
            MethodKind::Kalman => Method::Kalman(Kalman::new(&self.kalman, target)),
        }
    }
}

/// Where a refused parameter sits in a scenario: its `[run]` table or a method's table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamTable {
    /// `run` (the target phase).
    Run,
    /// `methods.<name>`.
    Method(MethodKind),
}

impl fmt::Display for ParamTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParamTable::Run => f.write_str("run"),
            ParamTable::Method(m) => write!(f, "methods.{m}"),
        }
    }
}

/// What is wrong with a parameter, with the value that was given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamProblem {
    /// The median window is even, not positive or above [`MAX_WINDOW`].
    MedianWindow(i64),
    /// The median gain is outside (0, 1].
    MedianGain(f64),
    /// A `pi-m2s` gain is outside [0, 2].
    PiGain(f64),
    /// A negative or zero count of initialisation frames.
    InitFrames(i64),
    /// `snap` or `soem-pi` given an offset of its own (earlier versions had one).
    OwnOffset,
    /// A DCM gain outside [0, max].
    DcmGain {
        /// The gain given.
        value: f64,
        /// The largest usable.
        max: f64,
    },
    /// A DCM filter depth outside 0 ..= 16.
    DcmFilterDepth(i64),
    /// A DCM time not within (0, cycle].
    DcmTime {
        /// The time given, us.
        value_us: f64,
        /// The cycle, us.
        cycle_us: f64,
    },
    /// A DCM slew limit outside [0, 1000] ppm.
    DcmSlew(f64),
    /// A DCM hold time outside [0, 600000] ms.
    DcmHold(f64),
    /// A value outside its range.
    OutOfRange {
        /// The value given.
        value: f64,
        /// The range, as the message says it.
        range: &'static str,
        /// The default.
        default: f64,
    },
    /// The target phase is no number or absurdly large, us.
    TargetPhaseNotANumber(f64),
    /// The target phase lies outside half a cycle of the grid point.
    TargetPhaseOutside {
        /// The target, ns.
        target_phase_ns: i64,
        /// Half the cycle, ns.
        half_cycle_ns: i64,
    },
}

/// A parameter a method cannot run with: where it is, what is wrong ([`ParamError::message`])
/// and what to do ([`ParamError::fix`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{table}.{key}: {}; fix: {}", self.message(), self.fix())]
pub struct ParamError {
    /// The table.
    pub table: ParamTable,
    /// The key in it.
    pub key: &'static str,
    /// What is wrong.
    pub problem: ParamProblem,
}

impl ParamError {
    fn method(kind: MethodKind, key: &'static str, problem: ParamProblem) -> Self {
        ParamError {
            table: ParamTable::Method(kind),
            key,
            problem,
        }
    }

    fn run(key: &'static str, problem: ParamProblem) -> Self {
        ParamError {
            table: ParamTable::Run,
            key,
            problem,
        }
    }

    /// What is wrong, with the value given.
    pub fn message(&self) -> impl fmt::Display + '_ {
        Words(self, false)
    }

    /// What to do.
    pub fn fix(&self) -> impl fmt::Display + '_ {
        Words(self, true)
    }
}

/// The message (`false`) or the fix (`true`) of a [`ParamError`].
struct Words<'a>(&'a ParamError, bool);

impl fmt::Display for Words<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use ParamProblem as P;
        let fix = self.1;
        match (self.0.problem, fix) {
            (P::MedianWindow(w), false) => {
                write!(
                    f,
                    "window w = {w} must be odd and between 1 and {MAX_WINDOW}"
                )
            }
            (P::MedianWindow(_), true) => f.write_str(
                "use an odd width such as 11 (the letter's), so the median is one of the samples",
            ),
            (P::MedianGain(g), false) => write!(f, "gain k = {g} must lie in (0, 1]"),
            (P::MedianGain(_), true) => f.write_str("use a small gain such as 0.01 (the letter's)"),
            (P::PiGain(v), false) => write!(f, "{v} is not a usable gain"),
            (P::PiGain(_), true) => {
                f.write_str("give a gain between 0 and 2 (the letter: kp 0.125, ki 0.0005)")
            }
            (P::InitFrames(n), false) => write!(f, "{n} initialisation frames"),
            (P::InitFrames(_), true) => f.write_str("give at least 1 (the letter: 10000)"),
            (P::OwnOffset, false) => {
                f.write_str("every method now aims at the scenario's target phase")
            }
            (P::OwnOffset, true) => f.write_str(
                "remove the field and set run.target_phase_us (us after the DC grid point) instead",
            ),
            (P::DcmGain { value, max }, false) => {
                write!(f, "{value} is not a usable gain (0 ..= {max})")
            }
            (P::DcmGain { .. }, true) => f.write_str(
                "the defaults are kp 0.004, ki 0.000004 (a loop of about 0.5 s at 1 ms)",
            ),
            (P::DcmFilterDepth(d), false) => write!(f, "{d}"),
            (P::DcmFilterDepth(_), true) => f.write_str(
                "give a depth between 0 (no filter) and 16 (weight 2^-16); the default is 6",
            ),
            (P::DcmTime { value_us, .. }, false) => write!(f, "{value_us} us"),
            (P::DcmTime { cycle_us, .. }, true) => write!(
                f,
                "give a time above 0 and at most the cycle ({cycle_us} us)"
            ),
            (P::DcmSlew(v), false) => write!(f, "{v} ppm"),
            (P::DcmSlew(_), true) => {
                f.write_str("give between 0 (no limit) and 1000 ppm; bus shift's default is 5")
            }
            (P::DcmHold(v), false) => write!(f, "{v} ms"),
            (P::DcmHold(_), true) => f.write_str("give between 0 and 600000 ms"),
            (P::OutOfRange { value, range, .. }, false) => {
                write!(f, "{value} is outside {range}")
            }
            (P::OutOfRange { range, default, .. }, true) => {
                write!(
                    f,
                    "give a value in {range}, or leave it out for the default {default}"
                )
            }
            (P::TargetPhaseNotANumber(v), false) => write!(f, "{v}"),
            (P::TargetPhaseNotANumber(_), true) => {
                f.write_str("give the target phase in us, within half a cycle of the grid point")
            }
            (
                P::TargetPhaseOutside {
                    target_phase_ns, ..
                },
                false,
            ) => write!(
                f,
                "{} us is not within half a cycle of the grid point",
                target_phase_ns as f64 / 1000.0
            ),
            (P::TargetPhaseOutside { half_cycle_ns, .. }, true) => write!(
                f,
                "give a phase from {} up to (not including) {} us; the frames should reach the reference before SYNC0 (run.sync0_shift_pct)",
                -half_cycle_ns as f64 / 1000.0,
                half_cycle_ns as f64 / 1000.0
            ),
        }
    }
}

/// Any method of the registry behind one type: static dispatch by `match`, no allocation, no
/// virtual call on the per-cycle path. (The median's window makes it the large variant; one
/// method lives per run, so the size does not matter.)
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum Method {
    /// `median`.
    Median(MedianSync),
    /// `median-fit`.
    MedianFit(MedianFit),
    /// `pi-m2s`.
    PiM2s(PiM2s),
    /// `bus-shift`.
    BusShift(BusShift),
    /// `dcm-bus-shift` or `dcm-master-shift` (by its mode).
    Dcm(Dcm),
    /// `snap`.
    Snap(Snap),
    /// `soem-pi`.
    SoemPi(SoemPi),
    /// `kickcat-pll`.
    KickcatPll(KickcatPll),
    /// `igh-app-time`.
    IghAppTime(IghAppTime),
    /// `linuxcnc-pll`.
    LinuxcncPll(LinuxcncPll),
    /// `des`.
    Des(Des),
    /// `kalman`.
    Kalman(Kalman),
}

impl Method {
    /// Which method this is.
    pub fn kind(&self) -> MethodKind {
        match self {
            Method::Median(_) => MethodKind::Median,
            Method::MedianFit(_) => MethodKind::MedianFit,
            Method::PiM2s(_) => MethodKind::PiM2s,
            Method::BusShift(_) => MethodKind::BusShift,
            Method::Dcm(m) => m.kind(),
            Method::Snap(_) => MethodKind::Snap,
            Method::SoemPi(_) => MethodKind::SoemPi,
            Method::KickcatPll(_) => MethodKind::KickcatPll,
            Method::IghAppTime(_) => MethodKind::IghAppTime,
            Method::LinuxcncPll(_) => MethodKind::LinuxcncPll,
            Method::Des(_) => MethodKind::Des,
            Method::Kalman(_) => MethodKind::Kalman,
        }
    }
}

/// `$body` with `$m` bound to the method inside, whichever it is.
macro_rules! dispatch {
    ($self:expr, $m:ident => $body:expr) => {
        match $self {
            Method::Median($m) => $body,
            Method::MedianFit($m) => $body,
            Method::PiM2s($m) => $body,
            Method::BusShift($m) => $body,
            Method::Dcm($m) => $body,
            Method::Snap($m) => $body,
            Method::SoemPi($m) => $body,
            Method::KickcatPll($m) => $body,
            Method::IghAppTime($m) => $body,
            Method::LinuxcncPll($m) => $body,
            Method::Des($m) => $body,
            Method::Kalman($m) => $body,
        }
    };
}

impl MasterSync for Method {
    fn name(&self) -> &'static str {
        self.kind().name()
    }

    #[inline]
    fn is_master_shift(&self) -> bool {
        dispatch!(self, m => m.is_master_shift())
    }

    #[inline]
    fn reference_write_kind(&self) -> ReferenceWrite {
        dispatch!(self, m => m.reference_write_kind())
    }

    #[inline]
    fn reference_write(&self, at: WriteTimes) -> Option<u64> {
        dispatch!(self, m => m.reference_write(at))
    }

    #[inline]
    fn controller_log(&self) -> Option<ControllerLog> {
        dispatch!(self, m => m.controller_log())
    }

    #[inline]
    fn init_cycles(&self) -> u64 {
        dispatch!(self, m => m.init_cycles())
    }

    #[inline]
    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        dispatch!(self, m => m.update(input))
    }
}

#[cfg(feature = "serde")]
mod de {
    //! `MethodKind` and `MethodParams` from a scenario, keyed by the registry's names.

    use super::{MethodKind, MethodParams};
    use core::fmt;
    use serde::de::{self, Deserialize, Deserializer, MapAccess, Visitor};

    impl<'de> Deserialize<'de> for MethodKind {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct V;
            impl Visitor<'_> for V {
                type Value = MethodKind;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    write!(f, "a method name ({})", MethodKind::list())
                }
                fn visit_str<E: de::Error>(self, v: &str) -> Result<MethodKind, E> {
                    v.parse()
                        .map_err(|_| E::unknown_variant(v, &MethodKind::NAMES))
                }
            }
            d.deserialize_str(V)
        }
    }

    impl serde::Serialize for MethodKind {
        fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            s.serialize_str(self.name())
        }
    }

    /// A key of the `[methods]` table: a method's name; anything else is an unknown field.
    struct TableKey(MethodKind);

    impl<'de> Deserialize<'de> for TableKey {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct V;
            impl Visitor<'_> for V {
                type Value = TableKey;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    f.write_str("a method's table")
                }
                fn visit_str<E: de::Error>(self, v: &str) -> Result<TableKey, E> {
                    v.parse()
                        .map(TableKey)
                        .map_err(|_| E::unknown_field(v, &MethodKind::NAMES))
                }
            }
            d.deserialize_identifier(V)
        }
    }

    impl<'de> Deserialize<'de> for MethodParams {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct V;
            impl<'de> Visitor<'de> for V {
                type Value = MethodParams;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    f.write_str("a table of method tables ([methods.<name>])")
                }
                fn visit_map<A: MapAccess<'de>>(
                    self,
                    mut map: A,
                ) -> Result<MethodParams, A::Error> {
                    let mut p = MethodParams::default();
                    while let Some(TableKey(kind)) = map.next_key()? {
                        match kind {
                            MethodKind::Median => p.median = map.next_value()?,
                            MethodKind::MedianFit => p.median_fit = map.next_value()?,
                            MethodKind::PiM2s => p.pi_m2s = map.next_value()?,
                            MethodKind::BusShift => p.bus_shift = map.next_value()?,
                            MethodKind::DcmBusShift => p.dcm_bus_shift = map.next_value()?,
                            MethodKind::DcmMasterShift => p.dcm_master_shift = map.next_value()?,
                            MethodKind::Snap => p.snap = map.next_value()?,
                            MethodKind::SoemPi => p.soem_pi = map.next_value()?,
                            MethodKind::KickcatPll => p.kickcat_pll = map.next_value()?,
                            MethodKind::IghAppTime => p.igh_app_time = map.next_value()?,
                            MethodKind::LinuxcncPll => p.linuxcnc_pll = map.next_value()?,
                            MethodKind::Des => p.des = map.next_value()?,
                            MethodKind::Kalman => p.kalman = map.next_value()?,
                        }
                    }
                    Ok(p)
                }
            }
            d.deserialize_struct("MethodParams", &MethodKind::NAMES, V)
        }
    }
}

#[cfg(test)]
#[path = "method_tests.rs"]
mod tests;
