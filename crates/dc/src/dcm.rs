//! The vendor note's DC master synchronization (DCM, "Class A - Master Synchronization"):
//! a PI controller on the distance between the master's cyclic frame and the DC grid, against a
//! set value, with a filter against the frame's send jitter; its re-adjustment moves either the
//! reference clock's time (bus shift) or the master's timer (master shift).
//!
//! # What the note says and what is assumed here
//!
//! The note: "The DCM Controller cyclically calculates the difference between the EtherCAT master
//! time and the DC clock master time. According to the set value (which is the distance of the
//! SYNC pulse to the timer-interrupt in the master) the PI controller algorithm calculates the
//! re-adjustment value. When using Master Shift the re-adjustment value affects the physical
//! timer of the EtherCAT Master whereas when using Bus Shift it affects register 0x910 of the DC
//! reference clock." The set value is by default "the time between cyclic frame and Sync0"
//! (its error depends on the send jitter, which a filter deals with), or in the enhanced mode
//! "the time between start of cycle and Sync0" (independent of the send jitter; it needs the
//! timer's count at the send). The vendor's masters report "DCM in sync" when the controller
//! error stays within a limit for a settle time, and log per cycle the set value, the error, the
//! filtered error, the adjustment and the drift in ppm.
//!
//! The model (each number a parameter, defaults chosen and tested here, not the vendor's):
//!
//! * Set value: the target phase of the frame's arrival at the reference against the DC grid
//!   (the grid point SYNC0 is shifted from), so every method of a comparison aims at the same
//!   point. The error of a cycle is where the reference's time `t_ra` read in the frame lies
//!   against the grid and the target, wrapped into ±P/2 ([`SetValueRef::FrameSend`]); in the
//!   enhanced mode ([`SetValueRef::CycleStart`]) this cycle's send delay from its scheduled start
//!   (`t_ms - t_mt`, which the master knows) is taken out, less its running mean, so the frame's
//!   mean still sits on the target while the scheduling jitter leaves the error.
//! * Filter against send jitter: an error further than `max_valid_ns` from the filtered error
//!   is not used once the controller is in sync (a frame the host held back; 64 such in a row
//!   are taken as a real step); the valid ones are averaged by an exponential filter of weight
//!   `2^-filter_depth`.
//! * PI on the rate: each cycle the re-adjustment grows by `kp e_f + ki sum(e_f)`, so the
//!   integral learns the drift between the master's clock and the reference (the "PI drift
//!   controller"; its ppm is logged) and a constant drift leaves no error. The proportional
//!   part is limited to `max_slew_ppm` of the cycle (bus shift: the other slaves must be able
//!   to follow the reference); while it is at the limit the learnt drift ramps at
//!   [`DRIFT_RAMP_PPM_PER_S`] instead of integrating (no wind-up), so the integral carries any
//!   drift, however far beyond the limit. Which way it ramps: towards the drift the phase's slip
//!   shows (its filtered change per cycle plus the proportional part) while that is more than
//!   the limit away, else towards the phase error. The phase error alone cannot say it: a drift
//!   more than the limit away slips the phase through ±P/2, the wrapped error changes sign at
//!   every slip, and a ramp on its sign goes back and forth without ever learning the drift
//!   (it did: a reference at -49 ppm and a master at +40 ppm never locked). The filtered error
//!   is wrapped as the error is, so a slip does not drag it through 0.
//! * Master shift moves the master's next cycle start earlier by the re-adjustment. Bus shift
//!   moves the reference's system time back by it: the note's register 0x0910 is the system time
//!   the reference reads and distributes, and the re-adjustment reaches it through the
//!   reference's System Time Offset (0x0920, written every cycle), not through a write of
//!   0x0910 itself: a write of 0x0910 starts the reference's time control loop, which compares
//!   the written value with its local time at the frame's arrival and so takes the NIC's jitter
//!   of every frame into the reference (the letter's E-S2M, `bus-shift`, does exactly that). The
//!   filtered, slowly changing re-adjustment is what the other slaves then follow by FRMW.
//! * In sync: `|e_f|` within `in_sync_limit_ns` for `in_sync_hold_cycles` cycles in a row; out of
//!   sync as soon as it leaves the band.

use crate::offset::round_ns;
use crate::registry::MethodKind;
use crate::sync::{
    ControllerLog, CycleInput, CycleOutput, MasterSync, ReferenceWrite, WriteTimes, grid_phase,
    wrap_phase,
};
use ecsync_wire::dc_time::diff_u64;

/// What the re-adjustment moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DcmMode {
    /// The reference clock's time (the note's default).
    BusShift,
    /// The master's timer.
    MasterShift,
}

/// What the set value is measured from (in a scenario: `"frame-send"` or `"cycle-start"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize, serde::Serialize),
    serde(rename_all = "kebab-case")
)]
pub enum SetValueRef {
    /// The cyclic frame's send (the note's default): the error carries the send jitter, which
    /// the filter deals with.
    FrameSend,
    /// The start of the cycle (the note's enhanced mode): the master takes this cycle's send
    /// delay out of the error.
    CycleStart,
}

/// The controller's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DcmParams {
    /// What the set value is measured from.
    pub set_value_ref: SetValueRef,
    /// Target phase of the frame's arrival at the reference against the DC grid, ns.
    pub target_phase_ns: i64,
    /// Proportional gain (per cycle, on the filtered error).
    pub kp: f64,
    /// Integral gain (per cycle, on the sum of the filtered errors).
    pub ki: f64,
    /// The filter's weight is `2^-filter_depth`.
    pub filter_depth: u8,
    /// Errors further than this from the filtered error are not used once in sync, ns.
    pub max_valid_ns: i64,
    /// The band of "in sync", ns.
    pub in_sync_limit_ns: i64,
    /// Cycles the filtered error must stay in the band before "in sync".
    pub in_sync_hold_cycles: u64,
    /// The most the proportional part moves the re-adjustment per cycle, as a rate in ppm of
    /// the cycle (0: no limit). Bus shift needs one: the other slaves follow the reference's
    /// time with a slew of at most 24 ppm (their speed counter's 0x1000), so a re-adjustment
    /// that moves faster leaves them behind by microseconds while it pulls in.
    pub max_slew_ppm: f64,
}

impl DcmParams {
    /// The defaults aiming at `target_phase_ns`, at a cycle of `period_ns`.
    ///
    /// The loop's natural frequency is 0.002 per cycle with damping 1 (`kp = 2 ζ ω`,
    /// `ki = ω²`): it settles in about half a second at 1 ms, slowly enough that the filtered
    /// scheduling jitter of a loaded PREEMPT_RT host moves the re-adjustment by a few ns per
    /// cycle, which the slaves' time control loops (24 ppm of slew) follow; the filter (depth 6,
    /// 64 cycles) is eight times faster than the loop. The in-sync band is 5 us for 1.5 s.
    pub fn default_for(target_phase_ns: i64, period_ns: u32) -> Self {
        let p = f64::from(period_ns.max(1));
        DcmParams {
            set_value_ref: SetValueRef::FrameSend,
            target_phase_ns,
            kp: 0.004,
            ki: 4.0e-6,
            filter_depth: 6,
            max_valid_ns: 50_000,
            in_sync_limit_ns: 5_000,
            in_sync_hold_cycles: round_ns(1.5e9 / p).max(1) as u64,
            max_slew_ppm: 0.0,
        }
    }

    /// The defaults for bus shift: as [`DcmParams::default_for`] with the pull-in limited to
    /// 5 ppm, a fifth of what the slaves' time control loops can follow.
    pub fn default_bus_shift(target_phase_ns: i64, period_ns: u32) -> Self {
        DcmParams {
            max_slew_ppm: 5.0,
            ..Self::default_for(target_phase_ns, period_ns)
        }
    }
}

/// The vendor note's DCM controller, in bus shift or master shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dcm {
    mode: DcmMode,
    /// The parameters.
    pub params: DcmParams,
    weight: f64,
    filtered: f64,
    integral: f64,
    adjustment: f64,
    rate: f64,
    /// The proportional part of the last rate, ns per cycle.
    p_part: f64,
    /// Filtered drift still to learn (the drift minus the learnt one), ns per cycle.
    drift_error: f64,
    send_delay_mean: f64,
    send_delay_n: u64,
    started: bool,
    in_sync: bool,
    good_run: u64,
    invalid_run: u32,
    log: ControllerLog,
}

impl Dcm {
    /// A controller in `mode` with `params`.
    pub fn new(mode: DcmMode, params: DcmParams) -> Self {
        Dcm {
            mode,
            params,
            weight: 1.0 / f64::from(1u32 << params.filter_depth.min(20)),
            filtered: 0.0,
            integral: 0.0,
            adjustment: 0.0,
            rate: 0.0,
            p_part: 0.0,
            drift_error: 0.0,
            send_delay_mean: 0.0,
            send_delay_n: 0,
            started: false,
            in_sync: false,
            good_run: 0,
            invalid_run: 0,
            log: ControllerLog {
                set_value_ns: params.target_phase_ns,
                ..ControllerLog::default()
            },
        }
    }

    /// The mode.
    pub fn mode(&self) -> DcmMode {
        self.mode
    }

    /// Which method of the registry this is (by its mode).
    pub fn kind(&self) -> MethodKind {
        match self.mode {
            DcmMode::BusShift => MethodKind::DcmBusShift,
            DcmMode::MasterShift => MethodKind::DcmMasterShift,
        }
    }

    /// Whether the controller is in sync.
    pub fn in_sync(&self) -> bool {
        self.in_sync
    }
}

/// Consecutive invalid errors after which the controller takes them as a real step.
const MAX_INVALID_RUN: u32 = 64;

/// How fast the learnt drift moves while the proportional part is at its limit, ppm per
/// second: the slaves' own drift estimate (0x0935's depth 12, about 4 s) trails a reference
/// whose rate ramps by `r` ppm/s by about `4 r` ppm, which with the 5 ppm limit stays well
/// within the 24 ppm their phase slew holds.
pub const DRIFT_RAMP_PPM_PER_S: f64 = 2.0;

/// The drift error's filter is this many times slower than the phase error's: the slip per
/// cycle of the filtered error is a few ns under a loaded host's scheduling jitter, the drift
/// it shows (tens of ns per cycle when the ramp matters) must stand out of that.
const DRIFT_FILTER_SLOWER: f64 = 16.0;

/// `x` wrapped into `[-P/2, P/2)`, for values a few periods at most from that range.
fn wrap_phase_f64(x: f64, period_ns: f64) -> f64 {
    let mut y = x;
    while y >= period_ns / 2.0 {
        y -= period_ns;
    }
    while y < -period_ns / 2.0 {
        y += period_ns;
    }
    y
}

impl MasterSync for Dcm {
    fn name(&self) -> &'static str {
        self.kind().name()
    }

    fn is_master_shift(&self) -> bool {
        self.mode == DcmMode::MasterShift
    }

    fn reference_write_kind(&self) -> ReferenceWrite {
        match self.mode {
            DcmMode::BusShift => ReferenceWrite::OffsetAdjust,
            DcmMode::MasterShift => ReferenceWrite::None,
        }
    }

    fn reference_write(&self, _at: WriteTimes) -> Option<u64> {
        match self.mode {
            DcmMode::BusShift => Some(round_ns(-self.adjustment) as u64),
            DcmMode::MasterShift => None,
        }
    }

    fn controller_log(&self) -> Option<ControllerLog> {
        Some(self.log)
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let prm = self.params;
        let mut log = ControllerLog {
            set_value_ns: prm.target_phase_ns,
            in_sync: self.in_sync,
            ..self.log
        };
        log.valid = false;
        if let Some(t_ra) = input.ref_time_ns() {
            let mut e = grid_phase(t_ra, prm.target_phase_ns, input.period_ns);
            if prm.set_value_ref == SetValueRef::CycleStart {
                // This cycle's send delay against its running mean (cumulative for the first
                // 1024 cycles, then with weight 1/1024).
                let s = diff_u64(input.send.as_ns(), input.scheduled_start.as_ns()) as f64;
                self.send_delay_n += 1;
                let w = 1.0 / (self.send_delay_n.min(1024) as f64);
                self.send_delay_mean += (s - self.send_delay_mean) * w;
                e = wrap_phase(e - round_ns(s - self.send_delay_mean), input.period_ns);
            }
            let e_f = e as f64;
            if !self.started {
                // The filter starts at the first error instead of pulling it in from 0.
                self.filtered = e_f;
                self.started = true;
            }
            let valid = !self.in_sync
                || (e_f - self.filtered).abs() <= prm.max_valid_ns as f64
                || self.invalid_run >= MAX_INVALID_RUN;
            if valid {
                self.invalid_run = 0;
                let period = f64::from(input.period_ns);
                let before = self.filtered;
                let step = wrap_phase_f64(e_f - self.filtered, period) * self.weight;
                self.filtered = wrap_phase_f64(self.filtered + step, period);
                // The phase moves by the drift less the rate applied: the slip plus the last
                // proportional part is the drift the integral has still to learn.
                let slip = wrap_phase_f64(self.filtered - before, period);
                self.drift_error +=
                    (slip + self.p_part - self.drift_error) * self.weight / DRIFT_FILTER_SLOWER;
                let mut p_part = prm.kp * self.filtered;
                let limit = prm.max_slew_ppm * 1e-6 * period;
                if limit > 0.0 && p_part.abs() > limit {
                    p_part = p_part.clamp(-limit, limit);
                    // At the limit the integral would wind up with the pull-in and overshoot;
                    // the learnt drift ramps at DRIFT_RAMP_PPM_PER_S instead: towards the drift
                    // while the phase slips past what the limit holds (the error's sign flips
                    // at each slip), else towards the error.
                    if prm.ki > 0.0 {
                        let ramp = DRIFT_RAMP_PPM_PER_S * 1e-6 * period * period * 1e-9;
                        let towards = if self.drift_error.abs() > limit {
                            self.drift_error.signum()
                        } else {
                            self.filtered.signum()
                        };
                        self.integral += towards * ramp / prm.ki;
                    }
                } else {
                    self.integral += self.filtered;
                }
                self.p_part = p_part;
                self.rate = p_part + prm.ki * self.integral;
            } else {
                self.invalid_run += 1;
            }
            // In sync.
            if self.filtered.abs() <= prm.in_sync_limit_ns as f64 {
                self.good_run += 1;
                if self.good_run >= prm.in_sync_hold_cycles {
                    self.in_sync = true;
                }
            } else {
                self.good_run = 0;
                self.in_sync = false;
            }
            log.error_ns = e;
            log.valid = valid;
        }
        // The rate goes on through lost frames: the drift does not stop.
        self.adjustment += self.rate;
        log.filtered_error_ns = self.filtered;
        log.adjustment_ns = round_ns(self.adjustment);
        log.drift_ppm = prm.ki * self.integral / f64::from(input.period_ns.max(1)) * 1e6;
        log.in_sync = self.in_sync;
        self.log = log;
        let next_nominal = input
            .nominal_start
            .as_ns()
            .wrapping_add(u64::from(input.period_ns));
        let corr = round_ns(self.adjustment);
        let next = match self.mode {
            DcmMode::MasterShift => next_nominal.wrapping_sub(corr as u64),
            DcmMode::BusShift => next_nominal,
        };
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(next),
            error_ns: log.error_ns,
            correction_ns: corr,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u32 = 1_000_000;

    /// A closed loop by hand: a reference drifting 20 ppm (20 ns per cycle) against the
    /// master, frames aimed 13 us late, no noise. The master-shift controller pulls the phase
    /// onto the target, learns the drift (20 ppm) and reports in sync.
    #[test]
    fn master_shift_converges_and_learns_the_drift() {
        let prm = DcmParams {
            in_sync_hold_cycles: 200,
            ..DcmParams::default_for(0, P)
        };
        let mut c = Dcm::new(DcmMode::MasterShift, prm);
        let p = u64::from(P);
        let base = 1_000_000 * p;
        let mut sched = base;
        let mut last = ControllerLog::default();
        for i in 0..20_000u64 {
            let nominal = base + i * p;
            let send = sched + 20_000;
            // The frame reaches the reference 13 us after its grid point when sent on the
            // nominal grid, and 20 ns later every cycle (the reference runs fast).
            let t_ra = send + 13_000 - 20_000 + 20 * i;
            let o = c.update(&CycleInput {
                cycle: i,
                period_ns: P,
                nominal_start: crate::time::MasterInstant::from_ns(nominal),
                scheduled_start: crate::time::MasterInstant::from_ns(sched),
                send: crate::time::MasterInstant::from_ns(send),
                receive: crate::time::MasterInstant::from_ns(send + 50_000),
                ref_time: Some(crate::time::SystemTime::from_ns(t_ra)),
            });
            sched = o.next_start.as_ns();
            last = c.controller_log().unwrap();
        }
        assert!(last.error_ns.abs() <= 2, "{last:?}");
        assert!((last.drift_ppm - 20.0).abs() < 0.05, "{last:?}");
        assert!(last.in_sync && c.in_sync());
    }

    /// A closed bus-shift loop by hand with the proportional part limited to 5 ppm: the
    /// reference's crystal 89 ppm slow against the master's (-49 ppm against +40 ppm), the frame
    /// first 300 us after the target, no noise. The reference's phase, computed here from the
    /// drift and the offsets written, must end on the target, the learnt drift at 89 ppm and the
    /// controller in sync. (Before the ramp followed the slip, the phase slipped through
    /// +-P/2 every few seconds and the learnt drift went back and forth between -16 and -28 ppm.)
    #[test]
    fn bus_shift_learns_a_drift_far_beyond_its_slew_limit() {
        for drift_ns_per_cycle in [89i64, -89, 100, -100] {
            let prm = DcmParams::default_bus_shift(0, P);
            let mut c = Dcm::new(DcmMode::BusShift, prm);
            let p = u64::from(P);
            let base = 1_000_000 * p;
            // The reference's time is its own (drifting) time plus the offsets written so far;
            // the master's frame leaves on the nominal grid.
            let mut offset_ns: i64 = 0;
            let mut phase_ns = 0i64;
            let mut last = ControllerLog::default();
            for i in 0..150_000u64 {
                let own = 300_000 + drift_ns_per_cycle * i as i64;
                let t_ra = (base + i * p).wrapping_add_signed(own + offset_ns);
                phase_ns = grid_phase(t_ra, 0, P);
                c.update(&CycleInput {
                    cycle: i,
                    period_ns: P,
                    nominal_start: crate::time::MasterInstant::from_ns(base + i * p),
                    scheduled_start: crate::time::MasterInstant::from_ns(base + i * p),
                    send: crate::time::MasterInstant::from_ns(base + i * p + 20_000),
                    receive: crate::time::MasterInstant::from_ns(base + i * p + 70_000),
                    ref_time: Some(crate::time::SystemTime::from_ns(t_ra)),
                });
                // The offset the next frame writes (0x0920 moves the reference's time).
                offset_ns = c.reference_write(WriteTimes::default()).unwrap() as i64;
                last = c.controller_log().unwrap();
            }
            let d = drift_ns_per_cycle as f64;
            assert!(
                phase_ns.abs() <= 100,
                "{drift_ns_per_cycle}: phase {phase_ns} {last:?}"
            );
            assert!(
                (last.drift_ppm - d).abs() < 0.5,
                "{drift_ns_per_cycle}: {last:?}"
            );
            assert!(c.in_sync(), "{drift_ns_per_cycle}: {last:?}");
        }
    }

    /// Bus shift writes the negated re-adjustment as the offset change, and its schedule stays
    /// on the nominal grid.
    #[test]
    fn bus_shift_writes_the_offset_adjustment() {
        let mut c = Dcm::new(DcmMode::BusShift, DcmParams::default_for(0, P));
        assert_eq!(c.reference_write_kind(), ReferenceWrite::OffsetAdjust);
        assert!(!c.is_master_shift());
        let p = u64::from(P);
        let o = c.update(&CycleInput {
            cycle: 0,
            period_ns: P,
            nominal_start: crate::time::MasterInstant::from_ns(5 * p),
            scheduled_start: crate::time::MasterInstant::from_ns(5 * p),
            send: crate::time::MasterInstant::from_ns(5 * p + 20_000),
            receive: crate::time::MasterInstant::from_ns(5 * p + 70_000),
            // 10 us after the grid point.
            ref_time: Some(crate::time::SystemTime::from_ns(77 * p + 10_000)),
        });
        assert_eq!(o.next_start.as_ns(), 6 * p);
        let log = c.controller_log().unwrap();
        assert_eq!(log.error_ns, 10_000);
        // First error: filter starts there; rate = kp 10000 + ki 10000.
        let rate = 0.004 * 10_000.0 + 4.0e-6 * 10_000.0;
        assert_eq!(log.adjustment_ns, round_ns(rate));
        assert_eq!(
            c.reference_write(WriteTimes::default()),
            Some(round_ns(-rate) as u64)
        );
    }

    /// The enhanced set value takes this cycle's send delay out: a frame the host sent 30 us
    /// late (its reference time 30 us later) gives the same error as the others.
    #[test]
    fn cycle_start_reference_removes_the_send_delay() {
        let mut prm = DcmParams::default_for(0, P);
        prm.set_value_ref = SetValueRef::CycleStart;
        let mut c = Dcm::new(DcmMode::MasterShift, prm);
        let p = u64::from(P);
        let mut errs = [0i64; 3];
        for (i, late) in [0u64, 0, 30_000].iter().enumerate() {
            let sched = (10 + i as u64) * p;
            let send = sched + 20_000 + late;
            let o = c.update(&CycleInput {
                cycle: i as u64,
                period_ns: P,
                nominal_start: crate::time::MasterInstant::from_ns(sched),
                scheduled_start: crate::time::MasterInstant::from_ns(sched),
                send: crate::time::MasterInstant::from_ns(send),
                receive: crate::time::MasterInstant::from_ns(send + 50_000),
                ref_time: Some(crate::time::SystemTime::from_ns(send + 5_000)),
            });
            let _ = o;
            errs[i] = c.controller_log().unwrap().error_ns;
        }
        // Cycle 0: the mean is its own delay: error 25 us. Cycle 1: the same. Cycle 2: the send
        // delay is 50 us against a running mean of (20 + 20 + 50) / 3 = 30 us: 20 us are taken
        // out of the 55 us phase.
        assert_eq!(errs[0], 25_000);
        assert_eq!(errs[1], 25_000);
        assert_eq!(errs[2], 55_000 - 20_000);
    }

    /// "In sync" comes after the error has stayed in its band for the hold time, not before,
    /// and goes as soon as the filtered error leaves the band.
    #[test]
    fn in_sync_waits_out_the_hold_time_and_goes_when_the_error_leaves_the_band() {
        let prm = DcmParams {
            in_sync_hold_cycles: 10,
            in_sync_limit_ns: 5_000,
            ..DcmParams::default_for(0, P)
        };
        let mut c = Dcm::new(DcmMode::MasterShift, prm);
        let p = u64::from(P);
        let mut went_out = None;
        for i in 0..400u64 {
            // 100 ns off the target for 50 cycles, then a step of 200 us (open loop: the
            // reference's time is given, whatever the controller does).
            let off = if i < 50 { 100 } else { 200_000 };
            c.update(&CycleInput {
                cycle: i,
                period_ns: P,
                nominal_start: crate::time::MasterInstant::from_ns(i * p),
                scheduled_start: crate::time::MasterInstant::from_ns(i * p),
                send: crate::time::MasterInstant::from_ns(i * p + 20_000),
                receive: crate::time::MasterInstant::from_ns(i * p + 70_000),
                ref_time: Some(crate::time::SystemTime::from_ns(1000 * p + i * p + off)),
            });
            let log = c.controller_log().unwrap();
            if i < 9 {
                assert!(!log.in_sync, "in sync after {} cycles: {log:?}", i + 1);
            } else if i < 50 {
                // The tenth cycle in the band, and on while it stays there.
                assert!(log.in_sync, "{i} {log:?}");
            }
            if i >= 50 && went_out.is_none() && !log.in_sync {
                went_out = Some(i);
                assert!(log.filtered_error_ns.abs() > 5_000.0, "{log:?}");
            }
            if went_out.is_none() && log.filtered_error_ns.abs() > 5_000.0 {
                panic!("still in sync with a filtered error of {log:?}");
            }
        }
        assert!(went_out.is_some(), "never left in sync");
        assert!(!c.in_sync());
    }

    /// Once in sync, a single outlier (a frame held back 80 us) is not used.
    #[test]
    fn the_validity_gate_drops_an_outlier_once_in_sync() {
        let prm = DcmParams {
            in_sync_hold_cycles: 10,
            ..DcmParams::default_for(0, P)
        };
        let mut c = Dcm::new(DcmMode::MasterShift, prm);
        let p = u64::from(P);
        for i in 0..30u64 {
            let late = if i == 25 { 80_000 } else { 0 };
            c.update(&CycleInput {
                cycle: i,
                period_ns: P,
                nominal_start: crate::time::MasterInstant::from_ns(i * p),
                scheduled_start: crate::time::MasterInstant::from_ns(i * p),
                send: crate::time::MasterInstant::from_ns(i * p + 20_000 + late),
                receive: crate::time::MasterInstant::from_ns(i * p + 70_000),
                ref_time: Some(crate::time::SystemTime::from_ns(
                    1000 * p + i * p + 100 + late,
                )),
            });
            let log = c.controller_log().unwrap();
            if i == 25 {
                assert!(!log.valid && log.in_sync, "{log:?}");
            } else {
                assert!(log.valid, "{i} {log:?}");
            }
        }
    }
}
