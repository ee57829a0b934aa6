//! The time control loop of [`DcUnit`]: the compare of a system time write, the two means
//! (0x092C, 0x0932) and the speed counter, as [the module's model](super#time-control-loop-model)
//! lays them out with the datasheet's words for each rule.

use super::DcUnit;
use crate::clock::TICK_NS;
use ecsync_wire::dc_time;

/// Speed Counter Start: reset value 0x1000, bits 14:0, "Minimum value: 0x0080 to 0x3FFF"
/// (ESC datasheet section II, register 0x0930).
pub(super) const SPEED_COUNTER_START_RESET: u16 = 0x1000;
pub(super) const SPEED_COUNTER_START_MIN: u16 = 0x0080;
pub(super) const SPEED_COUNTER_START_MAX: u16 = 0x3fff;

/// Ticks the speed counter takes beyond its reload value per step: the `+ 2` of the
/// deviation formula in the note to 0x0932 (section II), whose step periods are
/// `start ± diff + 2` ticks.
const RELOAD_TICKS: f64 = 2.0;

/// The largest Speed Counter Diff a start value allows: "Range: ±(Speed Counter Start − 0x7F)"
/// (section II, 0x0932).
pub(super) fn speed_counter_diff_max(start: u16) -> i32 {
    i32::from(start) - 0x7f
}

/// The clock deviation (a fraction: local clock period minus the reference's, over the
/// reference's) a Speed Counter Diff `diff` stands for at Speed Counter Start `start`, by the
/// note to 0x0932 (section II): `deviation = diff / (5 (start + diff + 2) (start − diff + 2))`.
pub fn speed_counter_deviation(start: u16, diff: f64) -> f64 {
    let s = f64::from(start) + RELOAD_TICKS;
    diff / (5.0 * (s + diff) * (s - diff))
}

/// The Speed Counter Diff (not rounded) whose deviation is `deviation`: the root of
/// `5 d (s² − D²) = D` (`s = start + 2`) that [`speed_counter_deviation`] maps to `deviation`,
/// written so that it is exact at 0.
pub fn speed_counter_diff_for(start: u16, deviation: f64) -> f64 {
    let s = f64::from(start) + RELOAD_TICKS;
    let k = 5.0 * deviation * s;
    2.0 * k * s / (1.0 + (1.0 + 4.0 * k * k).sqrt())
}

/// The weight of the next value in a mean of `1 / w_full` (`2^depth`) values that holds
/// `count`: `1 / (count + 1)` while it fills, `w_full` once full. Counts the value in.
#[inline(always)]
fn mean_weight(count: &mut u32, w_full: f64) -> f64 {
    if f64::from(*count) * w_full < 1.0 {
        *count += 1;
        1.0 / f64::from(*count)
    } else {
        w_full
    }
}

/// What a sum of the mean of `1 / w_full` values that holds `count` keeps of itself when the
/// next value comes: all while it fills, `1 - w_full` once full. Counts the value in.
#[inline(always)]
fn mean_keep(count: &mut u32, w_full: f64) -> f64 {
    if f64::from(*count) * w_full < 1.0 {
        *count += 1;
        1.0
    } else {
        1.0 - w_full
    }
}

impl DcUnit {
    /// Speed Counter Diff (0x0932) as the register reads it: the integer nearest to the one
    /// that stands for the frequency correction in force, within the register's range.
    pub fn speed_counter_diff(&self) -> i16 {
        let max = speed_counter_diff_max(self.speed_counter_start);
        let d = speed_counter_diff_for(self.speed_counter_start, self.clock.drift_correction());
        (d.round() as i32).clamp(-max, max) as i16
    }

    /// Writing Speed Counter Start: "A write access resets System Time Difference
    /// (0x092C:0x092F) and Speed Counter Diff (0x0932:0x0933)" (section II, 0x0930); "The
    /// filters are reset by writing the Speed Counter Start value ... Writing the current
    /// value of the register again is sufficient" (section I, 9.1.4). The start value is
    /// limited to the register's range.
    pub(super) fn write_speed_counter_start(&mut self, start: u16, t_ps: u64) {
        self.speed_counter_start = start.clamp(SPEED_COUNTER_START_MIN, SPEED_COUNTER_START_MAX);
        let s = f64::from(self.speed_counter_start) + RELOAD_TICKS;
        self.slew_rate = 1.0 / (TICK_NS * s);
        let d_max = f64::from(speed_counter_diff_max(self.speed_counter_start));
        self.deviation_max = speed_counter_deviation(self.speed_counter_start, d_max);
        self.clock.set_drift_correction(t_ps, 0.0);
        self.clock.set_slew(t_ps, 0.0, 0.0);
        self.set_dt_filtered(0.0);
        self.dt_count = 0;
        self.speed_count = 0;
        self.deviation_sum_ns = 0.0;
        self.elapsed_sum_ns = 0.0;
        self.has_last_sample = false;
    }

    /// The filter depth of the System Time Difference mean (0x0934 bits 3:0): from the next
    /// difference on; the mean itself is not reset (section I, 9.1.4 names 0x0930 as the
    /// reset).
    pub(super) fn set_dt_filter_depth(&mut self, depth: u8) {
        self.dt_filter_depth = depth & 0x0f;
        self.dt_weight = 1.0 / f64::from(1u32 << self.dt_filter_depth);
    }

    /// The filter depth of the clock period deviation mean (0x0935 bits 3:0), likewise.
    pub(super) fn set_speed_filter_depth(&mut self, depth: u8) {
        self.speed_filter_depth = depth & 0x0f;
        self.speed_weight = 1.0 / f64::from(1u32 << self.speed_filter_depth);
    }

    /// The time control loop's step on a write of `received` (bits 31:0 of the written system
    /// time) at real time `t_ps`: see [the model](super#time-control-loop-model), whose
    /// numbers the comments give.
    #[inline(always)]
    pub(super) fn compare_system_time<const BRANCH_FREE: bool>(
        &mut self,
        received: u32,
        t_ps: u64,
    ) {
        self.clock.advance_to_in::<BRANCH_FREE>(t_ps);
        // (1) "Δt = (t_Local time + t_Offset − t_Propagation delay) − t_Received System Time"
        // (section I, 9.1.5), with the local copy latched at the frame's start.
        let read = self
            .sof_at_anchor()
            .wrapping_add(self.offset)
            .wrapping_sub(u64::from(self.delay));
        let dt = dc_time::diff_u32(read as u32, received);
        if dt.unsigned_abs() >= 1 << 30 {
            // (1) Shown, not steering; the next write starts a new interval.
            self.set_dt_filtered(f64::from(dt));
            self.has_last_sample = false;
            return;
        }
        let dt = f64::from(dt);

        // (2) The mean difference, 0x092C.
        let w = mean_weight(&mut self.dt_count, self.dt_weight);
        self.set_dt_filtered_in::<BRANCH_FREE>(self.dt_filtered + (dt - self.dt_filtered) * w);

        // (4) The clock period deviation over the interval since the previous write, its mean
        // the frequency correction. `last_sample_dt` is the difference the previous write
        // left once its phase step was done; the part of that step still pending (signed) is
        // expected to be left over, and `c` was in force all along.
        let mut c = self.clock.drift_correction();
        if self.has_last_sample {
            let elapsed_ns = (t_ps - self.last_sample_ps) as i64 as f64 * 1e-3;
            if elapsed_ns >= 1_000.0 {
                let pending = self.clock.slew_remaining_ns();
                let unexplained = dt - (self.last_sample_dt - pending);
                // The correction the crystal's deviation over the interval asks for, times the
                // interval; their mean over the intervals' time, within the speed counter
                // diff's range.
                let sample = c * elapsed_ns - unexplained;
                let keep = mean_keep(&mut self.speed_count, self.speed_weight);
                self.deviation_sum_ns = self.deviation_sum_ns * keep + sample;
                self.elapsed_sum_ns = self.elapsed_sum_ns * keep + elapsed_ns;
                c = (self.deviation_sum_ns / self.elapsed_sum_ns)
                    .clamp(-self.deviation_max, self.deviation_max);
            }
        }

        // (3) The phase: the mean difference stepped away, one nanosecond per speed counter
        // period (the clock is at `t_ps` already).
        self.clock
            .retune_at_anchor_in::<BRANCH_FREE>(c, -self.dt_filtered, self.slew_rate);
        self.has_last_sample = true;
        self.last_sample_ps = t_ps;
        self.last_sample_dt = dt - self.dt_filtered;
    }
}
