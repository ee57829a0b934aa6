//! What three more open masters ship, as [`MasterSync`] methods:
//!
//! | type | name | source |
//! |---|---|---|
//! | [`KickcatPll`] | `kickcat-pll` | KickCAT's `SoftPll` (`lib/include/kickcat/OS/SoftPll.h`, `lib/src/OS/SoftPll.cc`, its PR #429), driven by `Timer::sync_to` |
//! | [`IghAppTime`] | `igh-app-time` | the IgH master's `ecrt_master_sync_reference_clock[_to]` (`master/master.c`) as its `examples/dc_user/main.c` calls it |
//! | [`LinuxcncPll`] | `linuxcnc-pll` | linuxcnc-ethercat's `lcec_write_master` (`src/lcec_main.c`, with the folded error of its PRs #502/#507) |
//!
//! Each follows its source's arithmetic and defaults (cited on the type); where ecsync's frame
//! differs from the source's, the type says what was mapped to what. Like `snap` and `soem-pi`
//! they aim at the run's target phase, so that every method of a comparison aims at the same
//! place.

use crate::offset::round_ns;
use crate::registry::MethodKind;
use crate::sync::{CycleInput, CycleOutput, MasterSync, WriteTimes, grid_phase, next_nominal};
use crate::time::MasterInstant;
use ecsync_wire::dc_time::diff_u64;

/// `next` as a [`CycleOutput`] with the error acted on; the correction is its distance before
/// the nominal grid.
fn output(input: &CycleInput, next: u64, error_ns: i64) -> CycleOutput {
    CycleOutput {
        next_start: MasterInstant::from_ns(next),
        error_ns,
        correction_ns: diff_u64(next_nominal(input), next),
    }
}

/// Parameters of `kickcat-pll` (KickCAT's `SoftPll` defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct KickcatPllParams {
    /// Weight of the new error in the exponential moving average (`ema_alpha`).
    pub ema_alpha: f64,
    /// Proportional gain on the averaged error (`kp`).
    pub kp: f64,
    /// Integral gain on the clamped sum of the errors (`ki`).
    pub ki: f64,
    /// The most the wake-up moves per cycle, us (`slew_limit`).
    pub slew_limit_us: f64,
    /// Clamp of the raw error sum, us (`integrator_clamp`).
    pub integrator_clamp_us: f64,
    /// Once locked, errors beyond this are rejected, us (`outlier_reject`).
    pub outlier_reject_us: f64,
}

impl Default for KickcatPllParams {
    fn default() -> Self {
        KickcatPllParams {
            ema_alpha: 0.1,
            kp: 0.05,
            ki: 0.0005,
            slew_limit_us: 20.0,
            integrator_clamp_us: 200.0,
            outlier_reject_us: 150.0,
        }
    }
}

/// KickCAT's soft PLL (`SoftPll::update`, driven by `Timer::sync_to`, which adds the returned
/// correction to the next deadline before the timer adds the period): every cycle the
/// reference time's phase against the target, folded into ±P/2, is averaged (EMA, α 0.1); a
/// PI (kp 0.05 on the average, ki 0.0005 on the raw sum clamped at ±200 us) gives a correction
/// clamped at ±20 us (the slew limit), by which the next wake-up comes earlier. A lock detector
/// with hysteresis (locked after 500 averaged errors under 8 us, the count leaking by one on
/// each over; unlocked after 200 in a row over 20 us) gates the outlier rejection: once it
/// has locked, errors beyond 150 us are rejected (the last correction is applied again) and
/// 200 rejections in a row reset the PLL. A lost frame coasts (the last correction again).
///
/// KickCAT learns its target from the first sample unless told one; here it is the run's
/// target phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KickcatPll {
    p: KickcatPllParams,
    target_phase_ns: i64,
    ema: f64,
    integ: f64,
    correction_ns: i64,
    locked: bool,
    ever_locked: bool,
    lock_count: u32,
    unlock_count: u32,
    reject_streak: u32,
}

/// Averaged errors under the lock threshold before the PLL says it is locked (`lock_samples`).
const KICKCAT_LOCK_SAMPLES: u32 = 500;
/// The lock threshold, ns (`lock_threshold`).
const KICKCAT_LOCK_NS: i64 = 8_000;
/// Averaged errors in a row over the unlock threshold before it unlocks (`unlock_samples`).
const KICKCAT_UNLOCK_SAMPLES: u32 = 200;
/// The unlock threshold, ns (`unlock_threshold`).
const KICKCAT_UNLOCK_NS: i64 = 20_000;
/// Rejections in a row that reset the PLL (`reject_escape_samples`).
const KICKCAT_REJECT_ESCAPE: u32 = 200;

impl KickcatPll {
    /// The PLL with `p`, aiming at `target_phase_ns` after the grid point.
    pub const fn new(p: KickcatPllParams, target_phase_ns: i64) -> Self {
        KickcatPll {
            p,
            target_phase_ns,
            ema: 0.0,
            integ: 0.0,
            correction_ns: 0,
            locked: false,
            ever_locked: false,
            lock_count: 0,
            unlock_count: 0,
            reject_streak: 0,
        }
    }

    /// Whether the lock detector says locked.
    pub fn is_locked(&self) -> bool {
        self.locked
    }

    /// The averaged error, ns.
    pub fn averaged_error_ns(&self) -> f64 {
        self.ema
    }

    fn reset(&mut self) {
        *self = KickcatPll::new(self.p, self.target_phase_ns);
    }

    /// One sample: the correction (ns, positive: the next wake-up earlier) and the error.
    fn sample(&mut self, ref_ns: u64, period_ns: u32) -> i64 {
        let err = grid_phase(ref_ns, self.target_phase_ns, period_ns);
        let reject = if self.ever_locked && err.abs() as f64 > self.p.outlier_reject_us * 1e3 {
            self.reject_streak += 1;
            if self.reject_streak >= KICKCAT_REJECT_ESCAPE {
                self.reset();
                return err;
            }
            true
        } else {
            self.reject_streak = 0;
            false
        };
        if reject {
            return err;
        }
        let a = self.p.ema_alpha;
        self.ema = a * err as f64 + (1.0 - a) * self.ema;
        let clamp = self.p.integrator_clamp_us * 1e3;
        self.integ = (self.integ + err as f64).clamp(-clamp, clamp);
        let u = self.p.kp * self.ema + self.p.ki * self.integ;
        let slew = round_ns(self.p.slew_limit_us * 1e3);
        self.correction_ns = round_ns(u).clamp(-slew, slew);
        let abs = (self.ema as i64).abs();
        if !self.locked {
            if abs < KICKCAT_LOCK_NS {
                self.lock_count += 1;
                if self.lock_count >= KICKCAT_LOCK_SAMPLES {
                    self.locked = true;
                    self.ever_locked = true;
                    self.unlock_count = 0;
                }
            } else {
                self.lock_count = self.lock_count.saturating_sub(1);
            }
        } else {
            if abs > KICKCAT_UNLOCK_NS {
                self.unlock_count += 1;
            } else {
                self.unlock_count = 0;
            }
            if self.unlock_count >= KICKCAT_UNLOCK_SAMPLES {
                self.locked = false;
                self.lock_count = 0;
            }
        }
        err
    }
}

impl MasterSync for KickcatPll {
    fn name(&self) -> &'static str {
        MethodKind::KickcatPll.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let err = match input.ref_time_ns() {
            Some(t_ra) => self.sample(t_ra, input.period_ns),
            None => 0,
        };
        // `next_deadline += -correction`, then the timer adds the period.
        let next = input
            .scheduled_start
            .as_ns()
            .wrapping_add(u64::from(input.period_ns))
            .wrapping_sub(self.correction_ns as u64);
        output(input, next, err)
    }
}

/// Which master time IgH's application hands to `ecrt_master_sync_reference_clock_to`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(rename_all = "kebab-case")
)]
pub enum AppTime {
    /// The clock read right before the frame is queued and sent (`dc_user/main.c`:
    /// `clock_gettime` then `ecrt_master_application_time`, then the send): the send timestamp.
    #[default]
    Send,
    /// The cycle's target wake-up time, which IgH's examples call "more stable" (the jitter of
    /// the wake-up and the work before the send is then not in the written time, but in when the
    /// frame reaches the reference).
    Target,
}

/// Parameters of `igh-app-time` (IgH's `dc_user` example's).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct IghAppTimeParams {
    /// The reference is written every this many cycles (the example's `sync_ref_counter`
    /// reloaded with 1: every second cycle).
    pub sync_every: i64,
    /// The time written.
    pub app_time: AppTime,
}

impl Default for IghAppTimeParams {
    fn default() -> Self {
        IghAppTimeParams {
            sync_every: 2,
            app_time: AppTime::Send,
        }
    }
}

/// The IgH master's bus shift: the application's time is written by FPWR into the reference's
/// System Time (0x0910), whose time control loop follows it, every `sync_every` cycles, and the
/// FRMW that follows hands the reference's time to the other slaves every cycle. IgH writes the
/// low 32 bits (`EC_WRITE_U32`) and adds no delay compensation to the written value; the ESC's
/// loop compares the low 32 bits only, so the 64-bit write of the engine's frame is the same
/// to it. Between writes the reference runs on its own, corrected, rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IghAppTime {
    /// Cycles between writes (at least 1).
    pub sync_every: u64,
    /// The time written.
    pub app_time: AppTime,
    /// Cycles to go before the next write (the example's `sync_ref_counter`).
    counter: u64,
}

impl IghAppTime {
    /// Writes every `sync_every` cycles (0 is taken as 1), the first cycle's included.
    pub const fn new(sync_every: u64, app_time: AppTime) -> Self {
        IghAppTime {
            sync_every: if sync_every == 0 { 1 } else { sync_every },
            app_time,
            counter: 0,
        }
    }
}

impl MasterSync for IghAppTime {
    fn name(&self) -> &'static str {
        MethodKind::IghAppTime.name()
    }

    fn is_master_shift(&self) -> bool {
        false
    }

    fn reference_write(&self, at: WriteTimes) -> Option<u64> {
        (self.counter == 0).then_some(match self.app_time {
            AppTime::Send => at.send.as_ns(),
            AppTime::Target => at.scheduled.as_ns(),
        })
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        // `if (sync_ref_counter) sync_ref_counter--; else { sync_ref_counter = N - 1; sync(); }`
        self.counter = if self.counter == 0 {
            self.sync_every - 1
        } else {
            self.counter - 1
        };
        let error = input
            .ref_time_ns()
            .map_or(0, |t_ra| diff_u64(t_ra, input.send.as_ns()));
        output(input, next_nominal(input), error)
    }
}

/// Parameters of `linuxcnc-pll` (linuxcnc-ethercat's defaults, as fractions of the period).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct LinuxcncPllParams {
    /// The step the task's period moves by, ns; 0: the period / 1000 (`pll_step`'s default).
    pub step_ns: i64,
}

/// linuxcnc-ethercat's PLL (`lcec_write_master` with `sync_to_ref_clock`): a bang-bang
/// controller of the real-time task's period. Every cycle the master's application time at
/// the cycle (the scheduled start plus the task's latency up to the call) is compared with the
/// reference's time of the last frame; the error, folded into ±P/2 (the fix of #502/#507, before
/// which a start more than half a period off locked onto the wrong side), sets the correction
/// `rtapi_task_pll_set_correction` applies to the next period: `+step` when the master is ahead
/// of the reference, `-step` when behind (step: P / 1000, 1 us at 1 ms). A cycle without a
/// reading keeps the last correction. (With `pll_max_err` at its default of a whole period the
/// resync branch only moves linuxcnc's bookkeeping by whole periods: no phase changes.)
///
/// Mapped to ecsync's frame: the application time is the send timestamp (the call sits right
/// before the send) and the reference's time is taken at that instant (the frame's reading
/// less its way from the send), so the error is `grid_phase(t_ra - (t_ms - t_mt))` against the
/// target: the loop holds the reference's time at the cycle's start on the target, and the
/// frame reaches the reference one send delay later.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinuxcncPll {
    /// The step, ns.
    pub step_ns: i64,
    /// Where the reference's time at the cycle's start is held, ns after the grid point.
    pub target_phase_ns: i64,
    pll_out_ns: i64,
}

impl LinuxcncPll {
    /// The PLL with a step of `step_ns` (0: P / 1000 at the first cycle).
    pub const fn new(step_ns: i64, target_phase_ns: i64) -> Self {
        LinuxcncPll {
            step_ns,
            target_phase_ns,
            pll_out_ns: 0,
        }
    }

    /// The correction applied to the next period, ns.
    pub fn pll_out_ns(&self) -> i64 {
        self.pll_out_ns
    }
}

impl MasterSync for LinuxcncPll {
    fn name(&self) -> &'static str {
        MethodKind::LinuxcncPll.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let p = input.period_ns.max(1);
        if self.step_ns <= 0 {
            self.step_ns = i64::from(p / 1000).max(1);
        }
        let mut error = 0;
        if let Some(t_ra) = input.ref_time_ns() {
            let late = diff_u64(input.send.as_ns(), input.scheduled_start.as_ns());
            // The reference's phase at the cycle's start against the target (positive: the
            // reference is ahead, the master late); linuxcnc's pll_err is its negative.
            error = grid_phase(t_ra.wrapping_sub(late as u64), self.target_phase_ns, p);
            let pll_err = -error;
            self.pll_out_ns = if pll_err < 0 {
                -self.step_ns
            } else {
                self.step_ns
            };
        }
        // The correction is clamped to ±P/100 by the RTAPI hook.
        let clamp = i64::from(p / 100);
        let corr = self.pll_out_ns.clamp(-clamp, clamp);
        let next = input
            .scheduled_start
            .as_ns()
            .wrapping_add(u64::from(p))
            .wrapping_add(corr as u64);
        output(input, next, error)
    }
}

#[cfg(test)]
#[path = "masters_tests.rs"]
mod tests;
