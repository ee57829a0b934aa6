//! Master synchronization: keeping the master's cycle in step with the DC reference clock.
//!
//! One trait, [`MasterSync`], and the methods the SPEC names (the vendor note's DCM is in
//! [`crate::dcm`]):
//!
//! | type | name | what it is |
//! |---|---|---|
//! | [`MedianSync`] | `median` | the letter's method (Xu et al. 2024, eq. 5-14): master shift, error from the send timestamp, median filter, gain k |
//! | [`MedianFit`] | `median-fit` | the letter's filter and gain, h_mr and the drift fitted over the init frames: it holds a target phase on any crystals |
//! | [`PiM2s`] | `pi-m2s` | the letter's E-M2S baseline: master shift with a PI controller whose error is taken from the theoretical cycle start |
//! | [`BusShift`] | `bus-shift` | the letter's E-S2M baseline and the vendor's default: the master's time is written to the reference clock every cycle |
//! | [`Snap`] | `snap` | what ethercrab ships: every cycle the wait is set so the next cycle starts on the reference's grid, gain 1, no filter |
//! | [`SoemPi`] | `soem-pi` | SOEM's sample loop (`ec_sync` in its examples) |
//!
//! # Notation (the letter's)
//!
//! Cycle i starts at the theoretical time `t_mt^i` on the master clock; the master timestamps
//! `t_ms^i` right before sending (so `t_ms = t_mt + j_s + e_m`); the frame passes the reference
//! clock when its system time reads `t_ra^i` (returned by the FRMW of 0x0910). `P` is the SYNC0
//! period. The nominal grid is `t_mt^1 + i P`; a master-shift method moves its cycles by `-δ̂^i`
//! from it (eq. 14): `t_mt^{i+1} = t_mt^1 + i P - δ̂^i`.
//!
//! # Signs
//!
//! The letter's equations (10), (13), (14) converge as written: with `h_mr = mean(t_ms - t_ra)`,
//! `φ = t_ra + h_mr - (t_ms + δ̂) = δ - δ̂ + j_c` where δ grows when the reference runs fast
//! against the master, and moving the master's cycles earlier by δ̂ (eq. 14) keeps the frames at
//! a constant phase of the reference's clock. They are implemented as written. (The loop is of
//! type 1 on phase: a constant drift of Δ ns per cycle leaves a mean φ of Δ / k.)
//!
//! Everything is `no_std`, allocation-free, O(w) per update, and wrap-safe: times are 64-bit
//! DC/master nanoseconds and every difference is taken with wrapping arithmetic (a 32-bit
//! reference time is extended to 64 bits with [`crate::sync::extend_reference_time`] first).

use crate::fit::LineFit;
use crate::offset::round_ns;
use crate::registry::MethodKind;
use crate::time::{MasterInstant, SystemTime};
use ecsync_wire::dc_time::{diff_u64, extend_u32};

/// What the master saw in the cycle that just completed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleInput {
    /// Cycle index i in the cyclic phase, from 0.
    pub cycle: u64,
    /// SYNC0 period `P`, ns.
    pub period_ns: u32,
    /// `t_mt^1 + i P`: the cycle's place on the nominal grid.
    pub nominal_start: MasterInstant,
    /// `t_mt^i`: when the cycle was scheduled to start.
    pub scheduled_start: MasterInstant,
    /// `t_ms^i`: the timestamp right before the frame was sent.
    pub send: MasterInstant,
    /// When the reply arrived.
    pub receive: MasterInstant,
    /// `t_ra^i`: the reference clock's system time read by the FRMW in the frame, 64-bit; `None`
    /// if the frame was lost or the reference did not answer.
    pub ref_time: Option<SystemTime>,
}

impl CycleInput {
    /// `t_ra^i` in ns (the methods' arithmetic is on integers).
    pub fn ref_time_ns(&self) -> Option<u64> {
        self.ref_time.map(SystemTime::as_ns)
    }
}

/// What a method decides after a cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CycleOutput {
    /// `t_mt^{i+1}`: when the next cycle should start.
    pub next_start: MasterInstant,
    /// The error the method acted on this cycle, ns (0 while initialising).
    pub error_ns: i64,
    /// The method's accumulated correction, ns: δ̂ for master shift; for bus shift the last
    /// value written to the reference minus the send timestamp.
    pub correction_ns: i64,
}

/// Where a bus-shift method's per-cycle write to the reference clock goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceWrite {
    /// Nothing is written (master shift).
    None,
    /// System Time (0x0910): the value is a master time the reference's time control loop
    /// compares with its own (the letter's E-S2M).
    SystemTime,
    /// System Time Offset (0x0920): the value is an adjustment, ns (two's complement), added to
    /// the offset the bring-up wrote; the reference's system time moves by it at once, without
    /// its time control loop.
    OffsetAdjust,
}

/// When the cycle was to start and when its frame leaves, on the master's clock: the times a
/// bus-shift method may write into the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteTimes {
    /// `t_mt^i`: when the cycle's task was to wake (its target time).
    pub scheduled: MasterInstant,
    /// `t_ms^i`: the send timestamp, taken right before the frame leaves.
    pub send: MasterInstant,
}

/// A controller's state after a cycle, for its log (the columns of a vendor DCM log).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControllerLog {
    /// The set value: the target phase of the frame's arrival at the reference against the DC
    /// grid, ns.
    pub set_value_ns: i64,
    /// This cycle's controller error, ns.
    pub error_ns: i64,
    /// The filtered error the controller acted on, ns.
    pub filtered_error_ns: f64,
    /// The accumulated re-adjustment, ns (the master's timer moved earlier by it, or the
    /// reference's time moved back by it).
    pub adjustment_ns: i64,
    /// The drift between the master's clock and the reference the controller has learnt, ppm.
    pub drift_ppm: f64,
    /// Whether this cycle's error passed the validity check (the filter against send jitter).
    pub valid: bool,
    /// "In sync": the filtered error stayed within the band for the hold time.
    pub in_sync: bool,
}

/// A master synchronization method.
pub trait MasterSync {
    /// Short name (`median`, `pi-m2s`, ...): for the methods of this crate, their
    /// [`MethodKind::name`].
    fn name(&self) -> &'static str;

    /// Whether the method moves the master's cycles (master shift) rather than the reference
    /// clock (bus shift).
    fn is_master_shift(&self) -> bool {
        true
    }

    /// Which register of the reference the method writes every cycle (fixed per method).
    fn reference_write_kind(&self) -> ReferenceWrite {
        if self.is_master_shift() {
            ReferenceWrite::None
        } else {
            ReferenceWrite::SystemTime
        }
    }

    /// The value to write in the frame about to leave (see
    /// [`MasterSync::reference_write_kind`]): a master time for System Time, an adjustment (ns,
    /// two's complement) for the offset; `None` writes nothing this cycle.
    fn reference_write(&self, _at: WriteTimes) -> Option<u64> {
        None
    }

    /// The controller's state after the last update, for methods that keep a log.
    fn controller_log(&self) -> Option<ControllerLog> {
        None
    }

    /// Cycles the method spends initialising (it does not correct meanwhile).
    fn init_cycles(&self) -> u64 {
        0
    }

    /// Takes the measurements of a completed cycle and decides the next start.
    fn update(&mut self, input: &CycleInput) -> CycleOutput;
}

/// Extends a 32-bit reference time to 64 bits next to an estimate (the previous reference
/// time plus one period), correct while the estimate is within ±2.1 s.
pub fn extend_reference_time(estimate_ns: u64, low32: u32) -> u64 {
    extend_u32(estimate_ns, low32)
}

/// The reference's time from an 8-byte read of 0x0910 (`raw`): a 32-bit reference reads 0 in
/// the upper half, and its time is extended next to `estimate_ns` ([`extend_reference_time`]:
/// the master's clock, or the previous reading plus a period); a 64-bit one's is as read.
pub fn reference_time_from_read(estimate_ns: u64, raw: u64) -> u64 {
    if raw >> 32 == 0 {
        extend_reference_time(estimate_ns, raw as u32)
    } else {
        raw
    }
}

/// The nominal start of the next cycle: `t_mt^1 + (i + 1) P`.
pub(crate) fn next_nominal(input: &CycleInput) -> u64 {
    input
        .nominal_start
        .as_ns()
        .wrapping_add(u64::from(input.period_ns))
}

/// A running mean of `t_a - t_b` over the initialisation frames (eq. 5-7).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct InitMean {
    sum: i128,
    n: u64,
}

impl InitMean {
    fn add(&mut self, d: i64) {
        self.sum += i128::from(d);
        self.n += 1;
    }

    fn mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum as f64 / self.n as f64
        }
    }
}

/// Largest median window.
pub const MAX_WINDOW: usize = 63;

/// A sliding median of the last `w` values, kept sorted: O(w) per insertion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlidingMedian {
    w: usize,
    ring: [i64; MAX_WINDOW],
    sorted: [i64; MAX_WINDOW],
    len: usize,
    pos: usize,
}

impl SlidingMedian {
    /// A window of `w` values (1 ..= [`MAX_WINDOW`]).
    pub const fn new(w: usize) -> Self {
        let w = if w == 0 {
            1
        } else if w > MAX_WINDOW {
            MAX_WINDOW
        } else {
            w
        };
        SlidingMedian {
            w,
            ring: [0; MAX_WINDOW],
            sorted: [0; MAX_WINDOW],
            len: 0,
            pos: 0,
        }
    }

    /// Adds a value and returns the median of the window (the lower middle for even counts).
    /// The outgoing value is replaced in place and the new one bubbled to its rank: O(w) with
    /// no moves beyond its neighbours.
    pub fn push(&mut self, v: i64) -> i64 {
        let mut at;
        if self.len == self.w {
            let old = self.ring[self.pos];
            at = self.sorted[..self.len].partition_point(|&x| x < old);
            self.sorted[at] = v;
        } else {
            at = self.len;
            self.sorted[at] = v;
            self.len += 1;
        }
        while at > 0 && self.sorted[at - 1] > self.sorted[at] {
            self.sorted.swap(at - 1, at);
            at -= 1;
        }
        while at + 1 < self.len && self.sorted[at + 1] < self.sorted[at] {
            self.sorted.swap(at, at + 1);
            at += 1;
        }
        self.ring[self.pos] = v;
        self.pos += 1;
        if self.pos == self.w {
            self.pos = 0;
        }
        self.sorted[(self.len - 1) / 2]
    }
}

/// The letter's method: M2S with the error from the send timestamp, a median filter and an
/// integrating gain (eq. 5-14).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MedianSync {
    /// Median window w (the letter: 11).
    pub window: usize,
    /// Gain k (the letter: 0.01).
    pub gain: f64,
    /// Frames averaged for h_mr (the letter: 10 000 at 1 ms).
    pub init_frames: u64,
    h: InitMean,
    h_mr: f64,
    delta_hat: f64,
    median: SlidingMedian,
}

impl Default for MedianSync {
    fn default() -> Self {
        Self::new(11, 0.01, 10_000)
    }
}

impl MedianSync {
    /// A compensator with window `w`, gain `k` and `init_frames` frames for h_mr.
    pub const fn new(window: usize, gain: f64, init_frames: u64) -> Self {
        MedianSync {
            window,
            gain,
            init_frames,
            h: InitMean { sum: 0, n: 0 },
            h_mr: 0.0,
            delta_hat: 0.0,
            median: SlidingMedian::new(window),
        }
    }

    /// `h_mr` (eq. 7), ns, once initialised.
    pub fn h_mr_ns(&self) -> f64 {
        self.h_mr
    }

    /// δ̂, ns.
    pub fn delta_hat_ns(&self) -> f64 {
        self.delta_hat
    }
}

impl MasterSync for MedianSync {
    fn name(&self) -> &'static str {
        MethodKind::Median.name()
    }

    fn init_cycles(&self) -> u64 {
        self.init_frames
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let mut error = 0;
        if let Some(t_ra) = input.ref_time_ns() {
            if input.cycle < self.init_frames {
                // Eq. 5-7: h_mr = AVG(t_ms - t_ra).
                self.h.add(diff_u64(input.send.as_ns(), t_ra));
                self.h_mr = self.h.mean();
            } else {
                // Eq. 10: φ = t_ra + h_mr - (t_ms + δ̂).
                let phi = diff_u64(t_ra, input.send.as_ns()) as f64 + self.h_mr - self.delta_hat;
                let phi = round_ns(phi);
                // Eq. 12-13.
                let med = self.median.push(phi);
                self.delta_hat += self.gain * med as f64;
                error = phi;
            }
        }
        // Eq. 14.
        let corr = round_ns(self.delta_hat);
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(
                next_nominal(input).wrapping_sub(corr as u64),
            ),
            error_ns: error,
            correction_ns: corr,
        }
    }
}

/// Wraps `x` into `[-p/2, p/2)`.
pub fn wrap_phase(x: i64, period_ns: u32) -> i64 {
    let p = i64::from(period_ns.max(1));
    (x + p / 2).rem_euclid(p) - p / 2
}

/// Where a reference time lies against the DC grid (multiples of the period, on which SYNC0
/// start times are placed) and a target phase: `t - target` wrapped into `[-P/2, P/2)`, ns.
pub fn grid_phase(t_ns: u64, target_phase_ns: i64, period_ns: u32) -> i64 {
    let p = i128::from(period_ns.max(1));
    let r = (i128::from(t_ns) - i128::from(target_phase_ns)).rem_euclid(p) as i64;
    wrap_phase(r, period_ns)
}

/// `median-fit`: the letter's median filter and gain, but `h_mr` and the master-to-reference
/// drift fitted together over the initialisation frames (least squares), so that it holds the
/// target phase whatever the crystals.
///
/// The letter averages `t_ms - t_ra` over the init frames as if the clocks did not drift
/// meanwhile (eq. 7): with a drift of `d` ns per cycle, the loop then holds the phase the frames
/// had on average during init, `d N / 2` from where they started (5 us per ppm over 10 000
/// frames at 1 ms). Here, during init:
///
/// * `y_i = t_ms^i - t_ra^i` is fitted as `a_y + b_y i` (its noise is the NIC's only: the send
///   timestamp moves with the send);
/// * the frame's arrival phase at the reference against the grid and the target, `p_i`, lies
///   on `a_p + b_p i` with the same drift, `b_p = -b_y`; `a_p` is their mean less the drift at
///   their mean cycle (the phases carry the scheduling jitter, whose outliers must not tilt
///   the line).
///
/// After init the letter's loop runs with `h_mr = a_y + a_p` and the drift fed forward: eq. 13
/// becomes `δ̂^i = δ̂^{i-1} - b_y + k median(φ)`. Then `φ = 0` means the frame arrives on the
/// target (the loop holds `p = a_p + a_y - h_mr = 0`), and the drift leaves no lag (the letter's
/// loop, of type 1, trails a drift of `d` by `d / k`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MedianFit {
    /// Median window w (the letter: 11).
    pub window: usize,
    /// Gain k (the letter: 0.01).
    pub gain: f64,
    /// Frames fitted during init.
    pub init_frames: u64,
    /// Where the frame should reach the reference against the DC grid, ns.
    pub target_phase_ns: i64,
    fit_y: LineFit,
    fit_p: LineFit,
    /// The first init frame's phase, send delay and y.
    first: Option<(f64, f64, f64)>,
    ready: bool,
    h_mr: f64,
    drift_per_cycle: f64,
    phase_at_init_end: f64,
    delta_hat: f64,
    median: SlidingMedian,
}

impl MedianFit {
    /// A fitted compensator with window `w`, gain `k`, `init_frames` fitted frames and a
    /// target phase.
    pub const fn new(window: usize, gain: f64, init_frames: u64, target_phase_ns: i64) -> Self {
        MedianFit {
            window,
            gain,
            init_frames,
            target_phase_ns,
            fit_y: LineFit::new(),
            fit_p: LineFit::new(),
            first: None,
            ready: false,
            h_mr: 0.0,
            drift_per_cycle: 0.0,
            phase_at_init_end: 0.0,
            delta_hat: 0.0,
            median: SlidingMedian::new(window),
        }
    }

    /// The fitted `h_mr`, ns (0 until the init frames are done).
    pub fn h_mr_ns(&self) -> f64 {
        self.h_mr
    }

    /// The fitted drift of the reference against the master, ns per cycle (the reference's
    /// phase moves by it each cycle when uncorrected).
    pub fn drift_ns_per_cycle(&self) -> f64 {
        self.drift_per_cycle
    }

    /// The phase against the target the uncorrected frames would have had at the end of init,
    /// ns: what the loop has to pull in.
    pub fn phase_at_init_end_ns(&self) -> f64 {
        self.phase_at_init_end
    }

    /// δ̂, ns.
    pub fn delta_hat_ns(&self) -> f64 {
        self.delta_hat
    }

    fn finish_init(&mut self) {
        let (a_y, b_y) = self.fit_y.line();
        // The phase's line has the drift of `y` (reversed): only its level is taken from the
        // phases, as their mean less the drift at their mean cycle. (A slope fitted to the
        // phases themselves would carry the scheduling jitter's outliers, a host stall of
        // milliseconds near either end of the init weighing most.)
        let b_p = -b_y;
        let a_p = self.fit_p.mean_y() - b_p * self.fit_p.mean_x();
        self.h_mr = a_y + a_p;
        self.drift_per_cycle = b_p;
        self.phase_at_init_end = a_p + b_p * self.init_frames as f64;
        self.ready = true;
    }
}

impl MasterSync for MedianFit {
    fn name(&self) -> &'static str {
        MethodKind::MedianFit.name()
    }

    fn init_cycles(&self) -> u64 {
        self.init_frames
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let mut error = 0;
        if input.cycle < self.init_frames {
            if let Some(t_ra) = input.ref_time_ns() {
                let x = input.cycle as f64;
                let y = diff_u64(input.send.as_ns(), t_ra) as f64;
                self.fit_y.add(x, y);
                // The phase, continued from the first one through what moved it: the send's
                // delay from its cycle's start (the host's jitter, a stall of milliseconds
                // included, which wrapping at ±P/2 would fold back) and y. The schedule runs on
                // the nominal grid during init, so nothing else moves it.
                let s = diff_u64(input.send.as_ns(), input.scheduled_start.as_ns()) as f64;
                let (p0, s0, y0) = *self.first.get_or_insert((
                    grid_phase(t_ra, self.target_phase_ns, input.period_ns) as f64,
                    s,
                    y,
                ));
                self.fit_p.add(x, p0 + (s - s0) - (y - y0));
            }
        } else {
            if !self.ready {
                self.finish_init();
            }
            // The drift is fed forward every cycle, a lost frame's included.
            self.delta_hat += self.drift_per_cycle;
            if let Some(t_ra) = input.ref_time_ns() {
                let phi = diff_u64(t_ra, input.send.as_ns()) as f64 + self.h_mr - self.delta_hat;
                let phi = round_ns(phi);
                let med = self.median.push(phi);
                self.delta_hat += self.gain * med as f64;
                error = phi;
            }
        }
        let corr = round_ns(self.delta_hat);
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(
                next_nominal(input).wrapping_sub(corr as u64),
            ),
            error_ns: error,
            correction_ns: corr,
        }
    }
}

/// The letter's E-M2S baseline: master shift with a PI controller on the error from the
/// theoretical cycle start, so scheduling jitter and execution time reach the controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PiM2s {
    /// Proportional gain (the letter: 0.125).
    pub kp: f64,
    /// Integral gain (the letter: 0.0005).
    pub ki: f64,
    /// Frames averaged for the offset before control starts.
    pub init_frames: u64,
    h: InitMean,
    h_mt: f64,
    integral: f64,
    delta_hat: f64,
}

impl Default for PiM2s {
    fn default() -> Self {
        Self::new(0.125, 0.0005, 10_000)
    }
}

impl PiM2s {
    /// A PI master shift with the given gains.
    pub const fn new(kp: f64, ki: f64, init_frames: u64) -> Self {
        PiM2s {
            kp,
            ki,
            init_frames,
            h: InitMean { sum: 0, n: 0 },
            h_mt: 0.0,
            integral: 0.0,
            delta_hat: 0.0,
        }
    }
}

impl MasterSync for PiM2s {
    fn name(&self) -> &'static str {
        MethodKind::PiM2s.name()
    }

    fn init_cycles(&self) -> u64 {
        self.init_frames
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let mut error = 0;
        if let Some(t_ra) = input.ref_time_ns() {
            if input.cycle < self.init_frames {
                self.h.add(diff_u64(input.scheduled_start.as_ns(), t_ra));
                self.h_mt = self.h.mean();
            } else {
                // e = t_ra + h - (t_mt + δ̂) = t_ra + h - nominal: the scheduling jitter and the
                // execution time between t_mt and the send are in it.
                let e = diff_u64(t_ra, input.scheduled_start.as_ns()) as f64 + self.h_mt
                    - self.delta_hat;
                self.integral += e;
                self.delta_hat += self.kp * e + self.ki * self.integral;
                error = round_ns(e);
            }
        }
        let corr = round_ns(self.delta_hat);
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(
                next_nominal(input).wrapping_sub(corr as u64),
            ),
            error_ns: error,
            correction_ns: corr,
        }
    }
}

/// The letter's E-S2M baseline (the vendor's "bus shift"): the master runs on its own timer
/// and writes its send timestamp into the reference clock's System Time every cycle; the
/// reference's time control loop follows the master, the other slaves follow the reference.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BusShift {
    /// Added to the send timestamp before it is written (compensation of the master-to-
    /// reference latency the reference's 0x0928 does not hold), ns.
    pub write_offset_ns: i64,
}

impl MasterSync for BusShift {
    fn name(&self) -> &'static str {
        MethodKind::BusShift.name()
    }

    fn is_master_shift(&self) -> bool {
        false
    }

    fn reference_write(&self, at: WriteTimes) -> Option<u64> {
        Some(at.send.as_ns().wrapping_add(self.write_offset_ns as u64))
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(next_nominal(input)),
            error_ns: input
                .ref_time_ns()
                .map_or(0, |t_ra| diff_u64(t_ra, input.send.as_ns())),
            correction_ns: self.write_offset_ns,
        }
    }
}

/// What ethercrab 0.7 ships (`CycleInfo::next_cycle_wait`): the task takes `now` at the top of
/// its loop, calls `tx_rx_dc` (which sends at once) and sleeps until `now + P - (t_ra mod P) +
/// shift` — a phase snap with gain 1 and no filter. `now` is the send timestamp here (ethercrab's
/// documented loop takes it right before the exchange).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Snap {
    /// ethercrab's `sync0_shift`, ns.
    pub shift_ns: u32,
}

impl MasterSync for Snap {
    fn name(&self) -> &'static str {
        MethodKind::Snap.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let p = u64::from(input.period_ns.max(1));
        match input.ref_time_ns() {
            Some(t_ra) => {
                let phase = t_ra % p;
                let wait = p - phase + u64::from(self.shift_ns);
                let next = input.send.as_ns().wrapping_add(wait);
                let wrapped = if phase > p / 2 {
                    phase as i64 - p as i64
                } else {
                    phase as i64
                };
                CycleOutput {
                    next_start: crate::time::MasterInstant::from_ns(next),
                    error_ns: wrapped,
                    correction_ns: diff_u64(next_nominal(input), next),
                }
            }
            None => CycleOutput {
                next_start: crate::time::MasterInstant::from_ns(input.send.as_ns().wrapping_add(p)),
                error_ns: 0,
                correction_ns: diff_u64(next_nominal(input), input.send.as_ns().wrapping_add(p)),
            },
        }
    }
}

/// SOEM's sample loop (`ec_sync` in its `red_test`/`simple_test`):
///
/// ```c
/// delta = (reftime - offset) % cycletime;
/// if (delta > cycletime / 2) delta -= cycletime;
/// if (delta > 0) integral++;
/// if (delta < 0) integral--;
/// *offsettime = -(delta / 100) - (integral / 20);
/// ```
///
/// and the task wakes at `previous wake + cycletime + offsettime`. The integral counts signs
/// and the divisions truncate, as in C. (The SPEC sketches this as `0.01 e + 0.00002 I` with
/// `I += e`; SOEM's code is what SOEM users run, so it is what this implements.)
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SoemPi {
    /// SOEM's `offset` (its example uses 50 µs: the task runs 50 µs after the DC grid), ns.
    pub offset_ns: i64,
    /// Divisor of the proportional term (SOEM: 100).
    pub p_divisor: i64,
    /// Divisor of the sign-counting integral (SOEM: 20).
    pub i_divisor: i64,
    integral: i64,
}

impl SoemPi {
    /// SOEM's loop with its divisors and the given offset.
    pub const fn new(offset_ns: i64) -> Self {
        SoemPi {
            offset_ns,
            p_divisor: 100,
            i_divisor: 20,
            integral: 0,
        }
    }
}

impl MasterSync for SoemPi {
    fn name(&self) -> &'static str {
        MethodKind::SoemPi.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let p = i64::from(input.period_ns.max(1));
        let mut delta = 0;
        if let Some(t_ra) = input.ref_time_ns() {
            delta = (t_ra as i64).wrapping_sub(self.offset_ns).rem_euclid(p);
            if delta > p / 2 {
                delta -= p;
            }
            if delta > 0 {
                self.integral += 1;
            }
            if delta < 0 {
                self.integral -= 1;
            }
        }
        let toff = -(delta / self.p_divisor.max(1)) - (self.integral / self.i_divisor.max(1));
        let next = input
            .scheduled_start
            .as_ns()
            .wrapping_add(p as u64)
            .wrapping_add(toff as u64);
        CycleOutput {
            next_start: crate::time::MasterInstant::from_ns(next),
            error_ns: delta,
            correction_ns: diff_u64(next_nominal(input), next),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u32 = 1_000_000;

    fn input(i: u64, sched: u64, send: u64, t_ra: Option<u64>) -> CycleInput {
        CycleInput {
            cycle: i,
            period_ns: P,
            nominal_start: crate::time::MasterInstant::from_ns(1_000_000_000 + i * u64::from(P)),
            scheduled_start: crate::time::MasterInstant::from_ns(sched),
            send: crate::time::MasterInstant::from_ns(send),
            receive: crate::time::MasterInstant::from_ns(send + 50_000),
            ref_time: t_ra.map(crate::time::SystemTime::from_ns),
        }
    }

    #[test]
    fn sliding_median_matches_sorting() {
        // Against a sort of the last w values, over a pseudo-random sequence with repeats.
        let mut m = SlidingMedian::new(11);
        let mut hist = std::vec::Vec::new();
        let mut x = 12345u64;
        for _ in 0..5_000 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let v = ((x >> 33) % 200) as i64 - 100;
            hist.push(v);
            let got = m.push(v);
            let mut last: std::vec::Vec<i64> = hist.iter().rev().take(11).copied().collect();
            last.sort();
            assert_eq!(got, last[(last.len() - 1) / 2]);
        }
    }

    #[test]
    fn sliding_median_by_hand() {
        let mut m = SlidingMedian::new(3);
        assert_eq!(m.push(5), 5);
        assert_eq!(m.push(1), 1); // [1, 5] -> lower middle
        assert_eq!(m.push(9), 5); // [1, 5, 9]
        assert_eq!(m.push(-100), 1); // 5 leaves: [-100, 1, 9]
        assert_eq!(m.push(7), 7); // 1 leaves: [-100, 7, 9]
        assert_eq!(m.push(8), 7); // 9 leaves: [-100, 7, 8]
    }

    #[test]
    fn median_hand_computed_sequence() {
        // init_frames = 2, w = 3, k = 0.5. t_ra = t_ms + 1000 during init: h_mr = -1000.
        let mut m = MedianSync::new(3, 0.5, 2);
        let base = 1_000_000_000u64;
        for i in 0..2 {
            let t = base + i * u64::from(P);
            let o = m.update(&input(i, t, t + 20_000, Some(t + 21_000)));
            assert_eq!(
                o.next_start.as_ns(),
                t + u64::from(P),
                "no correction while initialising"
            );
        }
        assert_eq!(m.h_mr_ns(), -1000.0);
        // Cycle 2: reference 40 ns further: φ = 40, median [40] = 40, δ̂ = 20.
        let t = base + 2 * u64::from(P);
        let o = m.update(&input(2, t, t + 20_000, Some(t + 21_040)));
        assert_eq!(o.error_ns, 40);
        assert_eq!(o.correction_ns, 20);
        assert_eq!(o.next_start.as_ns(), t + u64::from(P) - 20);
        // Cycle 3 (sent 20 ns early per eq. 14): the reference reads 21_060 after the nominal
        // start: φ = t_ra + h - (t_ms + δ̂) = (21_060 - 19_980) - 1000 - 20 = 60;
        // median [40, 60] = 40; δ̂ = 40.
        let t = base + 3 * u64::from(P);
        let o = m.update(&input(3, t - 20, t + 19_980, Some(t + 21_060)));
        assert_eq!(o.error_ns, 60);
        assert_eq!(o.correction_ns, 40);
        // Cycle 4: a 1 ms outlier of the NIC (+1_000_000 in t_ra): φ huge but the median of
        // [40, 60, 1_000_000 - ...] is 60: δ̂ moves by 30 only.
        let t = base + 4 * u64::from(P);
        let o = m.update(&input(4, t - 40, t + 19_960, Some(t + 1_021_080)));
        assert_eq!(o.error_ns, 1_000_000 + 21_080 - 19_960 - 1000 - 40);
        assert_eq!(o.correction_ns, 70);
    }

    #[test]
    fn median_is_wrap_safe_across_a_32_bit_reference_wrap() {
        // The reference's low 32 bits wrap between cycles; the engine extends them next to the
        // previous value + P. The result equals the unwrapped computation.
        let mut a = MedianSync::new(3, 0.5, 1);
        let mut b = MedianSync::new(3, 0.5, 1);
        let base = 1_000_000_000u64;
        let ra0 = (7u64 << 32) - 1_500_000; // 1.5 ms before a wrap
        let mut prev = ra0;
        for i in 0..4u64 {
            let t = base + i * u64::from(P);
            let ra = ra0 + i * u64::from(P) + 10 * i;
            let ext = extend_reference_time(prev + u64::from(P), ra as u32);
            assert_eq!(ext, ra);
            prev = ext;
            let oa = a.update(&input(i, t, t + 20_000, Some(ra)));
            let shifted = ra.wrapping_sub(7u64 << 32).wrapping_add(1u64 << 40);
            let ob = b.update(&input(i, t, t + 20_000, Some(shifted)));
            assert_eq!(oa, ob);
        }
    }

    /// A noise-free closed loop: the reference drifts 50 ns per cycle (50 ppm) against the
    /// master, and the frames start 9 us after the grid point. The letter's median holds the
    /// phase the frames had on average during its 1000 init frames, 50 x 999 / 2 = 24.975 us
    /// after where they started; median-fit holds the target (3 us) exactly.
    #[test]
    fn median_fit_holds_the_target_where_median_drifts_off() {
        fn run(m: &mut dyn MasterSync) -> i64 {
            let p = u64::from(P);
            let base = 1_000_000 * p;
            let mut sched = base;
            let mut last_phase = 0;
            for i in 0..6_000u64 {
                let send = sched + 20_000;
                // Reference time at arrival: 9 us after the grid point when sent on the nominal
                // schedule, later by 50 ns each cycle.
                let t_ra = send - 20_000 + 9_000 + 50 * i;
                last_phase = grid_phase(t_ra, 0, P);
                let o = m.update(&CycleInput {
                    cycle: i,
                    period_ns: P,
                    nominal_start: crate::time::MasterInstant::from_ns(base + i * p),
                    scheduled_start: crate::time::MasterInstant::from_ns(sched),
                    send: crate::time::MasterInstant::from_ns(send),
                    receive: crate::time::MasterInstant::from_ns(send + 50_000),
                    ref_time: Some(crate::time::SystemTime::from_ns(t_ra)),
                });
                sched = o.next_start.as_ns();
            }
            last_phase
        }
        let median = run(&mut MedianSync::new(11, 0.01, 1000));
        // The type-1 loop also trails the drift by 50 / 0.01 = 5 us.
        assert!((median - (9_000 + 24_975 + 5_000)).abs() <= 60, "{median}");
        let mut fit = MedianFit::new(11, 0.01, 1000, 3_000);
        let fitted = run(&mut fit);
        assert!((fitted - 3_000).abs() <= 60, "{fitted}");
        assert!((fit.drift_ns_per_cycle() - 50.0).abs() < 1e-6);
        // At the end of init the uncorrected frames were 6 us + 50 ns x 1000 past the target.
        assert!((fit.phase_at_init_end_ns() - (9_000.0 - 3_000.0 + 50_000.0)).abs() < 1e-3);
    }

    #[test]
    fn grid_phase_wraps_around_the_target() {
        let p = u64::from(P);
        assert_eq!(grid_phase(7 * p + 10, 0, P), 10);
        assert_eq!(grid_phase(7 * p - 10, 0, P), -10);
        assert_eq!(grid_phase(7 * p + 300_000, 250_000, P), 50_000);
        assert_eq!(grid_phase(7 * p + 100_000, -250_000, P), 350_000);
        assert_eq!(grid_phase(7 * p + p / 2, 0, P), -(p as i64) / 2);
    }

    #[test]
    fn pi_m2s_hand_computed_sequence() {
        // init 1 frame: h = t_mt - t_ra = -21_000. Then the reference reads 21_100 after the
        // theoretical start: e = 100; I = 100; δ̂ = 0.125*100 + 0.0005*100 = 12.55 -> 13.
        let mut c = PiM2s::new(0.125, 0.0005, 1);
        let base = 1_000_000_000u64;
        c.update(&input(0, base, base + 20_000, Some(base + 21_000)));
        let t = base + u64::from(P);
        let o = c.update(&input(1, t, t + 20_500, Some(t + 21_100)));
        assert_eq!(
            o.error_ns, 100,
            "the 500 ns of scheduling jitter does not matter here"
        );
        assert_eq!(o.correction_ns, 13);
        // The task was 5 us late: the frame, and so the reference reading, moved by 5 us, and
        // E-M2S, measuring from t_mt, takes all of it for drift:
        // e = (26_100 + 13) - 21_000 - 12.55 = 5_100.45.
        let t = base + 2 * u64::from(P);
        let o = c.update(&input(2, t - 13, t + 25_000, Some(t + 26_100)));
        assert_eq!(o.error_ns, 5_100);
    }

    #[test]
    fn bus_shift_writes_the_send_time() {
        let b = BusShift {
            write_offset_ns: 300,
        };
        assert_eq!(
            b.reference_write(WriteTimes {
                scheduled: crate::time::MasterInstant::from_ns(1_000),
                send: crate::time::MasterInstant::from_ns(5_000)
            }),
            Some(5_300)
        );
        assert!(!b.is_master_shift());
        let mut b = b;
        let o = b.update(&input(3, 7, 8, Some(10)));
        assert_eq!(o.next_start.as_ns(), 1_000_000_000 + 4 * u64::from(P));
        assert_eq!(o.error_ns, 2);
    }

    #[test]
    fn snap_waits_to_the_next_grid_point() {
        let mut s = Snap { shift_ns: 0 };
        // Reference at 123_456 into its cycle; sent at master 9_900_000 (the reply at
        // 10_000_000 does not matter): wait P - 123_456 from the send.
        let mut i = input(0, 0, 9_900_000, Some(77 * u64::from(P) + 123_456));
        i.receive = crate::time::MasterInstant::from_ns(10_000_000);
        let o = s.update(&i);
        assert_eq!(o.next_start.as_ns(), 9_900_000 + 1_000_000 - 123_456);
        assert_eq!(o.error_ns, 123_456);
        // With ethercrab's sync0_shift the wait grows by the shift.
        let mut s = Snap { shift_ns: 250_000 };
        let o = s.update(&i);
        assert_eq!(
            o.next_start.as_ns(),
            9_900_000 + 1_000_000 - 123_456 + 250_000
        );
    }

    #[test]
    fn soem_pi_hand_computed_sequence() {
        // offset 50_000; reference 50_250 into the cycle: delta = 250 -> integral 1;
        // toff = -(250/100) - (1/20) = -2 - 0 = -2.
        let mut s = SoemPi::new(50_000);
        let o = s.update(&input(0, 1_000, 2_000, Some(9 * u64::from(P) + 50_250)));
        assert_eq!(o.error_ns, 250);
        assert_eq!(o.next_start.as_ns(), 1_000 + u64::from(P) - 2);
        // delta -30 (wrapped: 999_970 > P/2): integral back to 0; toff = -(-30/100) - 0 = 0.
        let o = s.update(&input(
            1,
            1_000,
            2_000,
            Some(9 * u64::from(P) + 50_000 - 30),
        ));
        assert_eq!(o.error_ns, -30);
        assert_eq!(o.next_start.as_ns(), 1_000 + u64::from(P));
        // Twenty positive deltas: the sign integral reaches 20 and adds -1.
        for k in 0..20 {
            s.update(&input(2 + k, 0, 0, Some(50_010)));
        }
        let o = s.update(&input(30, 0, 0, Some(50_010)));
        assert_eq!(o.next_start.as_ns(), u64::from(P) - 1);
    }
}
