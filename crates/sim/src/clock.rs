//! The DC unit's local clock: a crystal with a static frequency error and random-walk wander,
//! corrected by the ESC's time control loop, evaluated analytically between events.
//!
//! # Model
//!
//! Real time `t` is in picoseconds since the start of the simulation. The local time `L(t)` in
//! nanoseconds obeys
//!
//! ```text
//! dL/dt = 1 + e_osc(t) + c_drift + c_slew(t)
//! ```
//!
//! * `e_osc(t) = ppm * 1e-6 + w(t)`: the crystal's static error plus wander. `w` is a random walk
//!   of frequency, piecewise constant on a fixed real-time grid (`wander_step_ps`): at every grid
//!   point it takes a Gaussian step with standard deviation `wander_ppm_per_sqrt_s * sqrt(step)`.
//!   Because the grid depends on real time only, a clock's trajectory is the same whatever frames
//!   it sees: every sync method run on the same seed meets the same crystals.
//! * `c_drift`, `c_slew`: the time control loop, see
//!   [its model](crate::dc_unit#time-control-loop-model).
//!
//! Registers show the local time at the last 10 ns tick: the ESC's system time counter advances
//! once per 100 MHz tick. The model quantises the counter's value to a fixed 10 ns grid (the
//! residue the counter had at power-up); the real counter's residue creeps by a nanosecond each
//! time the loop inserts a 9 or 11 ns step, a difference far below anything measured here.
//!
//! Between events nothing is stepped: `local_at` evaluates the piecewise-linear function directly,
//! and `advance_to` moves the anchor forward only across wander grid points and control loop
//! updates.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Picoseconds per nanosecond.
pub const PS_PER_NS: u64 = 1000;
/// System time counter tick.
pub const TICK_NS: f64 = 10.0;

/// The default wander grid: one second (ps). The frequency takes a step of
/// `wander_ppm_per_sqrt_s` standard deviation once per second; a finer grid changes nothing
/// measurable (the steps shrink with the square root of the grid) and costs a Gaussian sample
/// per clock per grid point.
pub const DEFAULT_WANDER_STEP_PS: u64 = 1_000_000_000_000;

/// Random-walk wander of every crystal the presets and scenario files do not give one, ppm per
/// sqrt(s): a few parts per billion over seconds, typical of an uncompensated quartz at constant
/// temperature.
pub const CRYSTAL_WANDER_PPM_PER_SQRT_S: f64 = 0.005;

/// Crystal parameters of one clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrystalParams {
    /// Static frequency error in ppm (positive: the clock runs fast).
    pub ppm: f64,
    /// Random-walk frequency wander: standard deviation of the frequency after one second, in ppm.
    pub wander_ppm_per_sqrt_s: f64,
    /// Grid on which the wander takes its steps, in ps.
    pub wander_step_ps: u64,
    /// Local time at real time 0, in ns (the instant the ESC powered up is arbitrary).
    pub initial_local_ns: u64,
    /// Seed of the wander process.
    pub seed: u64,
}

impl Default for CrystalParams {
    fn default() -> Self {
        CrystalParams {
            ppm: 0.0,
            wander_ppm_per_sqrt_s: 0.0,
            wander_step_ps: DEFAULT_WANDER_STEP_PS,
            initial_local_ns: 0,
            seed: 0,
        }
    }
}

/// A local time value split into an integer and a fractional part, so that picosecond-level
/// drift accumulates exactly over hours while the integer part holds 64-bit DC times.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Split {
    ns: u64,
    frac: f64,
}

/// `(x.floor() as i64, x.floor())` without a libm call (the baseline x86-64 target has no
/// SSE4.1 `roundsd`) and with one float-to-integer conversion: truncation, corrected for
/// negative non-integers. Exact for |x| < 2^63 (from 2^53 on, x is an integer); beyond, the
/// integer saturates as `as i64` does. Shared with the master's simulated clock.
#[inline]
pub fn floor_split(x: f64) -> (i64, f64) {
    let w = x as i64;
    let t = w as f64;
    if t > x {
        (w.saturating_sub(1), t - 1.0)
    } else {
        (w, t)
    }
}

impl Split {
    #[inline]
    fn add(self, delta_ns: f64) -> Split {
        let total = self.frac + delta_ns;
        let (whole_ns, whole) = floor_split(total);
        Split {
            ns: self.ns.wrapping_add(whole_ns as u64),
            frac: total - whole,
        }
    }
}

/// Fraction bits of the crystal's count (see `LocalClock::crystal_ns`): a rate of 1 + 50 ppm
/// is 2^50 / 1000 units per ps, exact to 4e-13, and a count spans 2^64 ns.
const CRYSTAL_FP_BITS: u32 = 50;

/// The crystal's rate `one_plus_osc` (local ns per real ns) in 2^-50 ns per ps.
fn crystal_rate_fp(one_plus_osc: f64) -> u64 {
    (one_plus_osc * (1u64 << CRYSTAL_FP_BITS) as f64 / 1000.0).round() as u64
}

/// The local clock of one ESC.
///
/// `repr(C)`, the fields every read uses first (one cache line), the crystal's parameters and
/// the wander's random number generator (read only at a wander step, boxed: its 300 bytes
/// would sit between one ESC's hot lines and the next's) after them.
#[derive(Debug, Clone)]
#[repr(C)]
pub struct LocalClock {
    /// Real time of the anchor, ps.
    anchor_ps: u64,
    /// Local time at the anchor.
    anchor_local: Split,
    /// `1 + oscillator_error()`, kept up to date with the wander (the rate's part that does
    /// not change with the control loop; the same operations as computing it every time).
    one_plus_osc: f64,
    /// Next wander grid point, ps.
    next_wander_ps: u64,
    /// Time control loop corrections currently in force.
    c_drift: f64,
    slew_rate: f64,
    slew_remaining_ns: f64,
    // (The hot part ends here: 64 bytes.)
    /// The crystal's own count (local time without the loop's corrections) at real time
    /// `crystal_ref_ps`, the last change of its rate, in 2^-50 ns; and the crystal's rate in
    /// 2^-50 ns per ps. Fixed point: an MII stamp reads it, and a floating-point chain there
    /// made the FRMW's work per slave half as long again (21 -> 33 ns in `ecsync bench --part
    /// frmw`).
    crystal_ref_ps: u64,
    crystal_ref_fp: u128,
    crystal_rate_fp: u64,
    /// Residue of the counter's values modulo 10 ns.
    tick_residue: u64,
    /// Current wander, as a fraction (not ppm).
    wander: f64,
    params: CrystalParams,
    rng: Box<ChaCha8Rng>,
}

impl LocalClock {
    /// A clock whose local time at real time 0 is `params.initial_local_ns`.
    pub fn new(params: CrystalParams) -> Self {
        LocalClock {
            params,
            rng: Box::new(ChaCha8Rng::seed_from_u64(params.seed)),
            anchor_ps: 0,
            anchor_local: Split {
                ns: params.initial_local_ns,
                frac: 0.0,
            },
            tick_residue: params.initial_local_ns % 10,
            wander: 0.0,
            one_plus_osc: 1.0 + (params.ppm * 1e-6 + 0.0),
            next_wander_ps: params.wander_step_ps.max(1),
            c_drift: 0.0,
            slew_rate: 0.0,
            slew_remaining_ns: 0.0,
            crystal_ref_ps: 0,
            crystal_ref_fp: u128::from(params.initial_local_ns) << CRYSTAL_FP_BITS,
            crystal_rate_fp: crystal_rate_fp(1.0 + params.ppm * 1e-6),
        }
    }

    /// A clock switched on at real time `t_ps`: it reads `params.initial_local_ns` then (a
    /// power cycle's restart; [`LocalClock::new`] is the clock switched on at real time 0).
    pub fn new_at(params: CrystalParams, t_ps: u64) -> Self {
        let mut c = LocalClock::new(params);
        c.anchor_ps = t_ps;
        c.crystal_ref_ps = t_ps;
        c.next_wander_ps = t_ps.saturating_add(params.wander_step_ps.max(1));
        c
    }

    /// The crystal parameters.
    pub fn params(&self) -> &CrystalParams {
        &self.params
    }

    /// Current oscillator frequency error (static plus wander), as a fraction.
    pub fn oscillator_error(&self) -> f64 {
        self.params.ppm * 1e-6 + self.wander
    }

    /// Local clock rate relative to real time (1.0 = perfect), control loop included.
    pub fn rate(&self) -> f64 {
        1.0 + self.oscillator_error() + self.c_drift + self.slew_rate
    }

    /// Local time advance over `dt_ns` real nanoseconds from the anchor, without crossing a
    /// wander grid point. Without a branch on whether a slew is running: see
    /// [`LocalClock::move_anchor`].
    #[inline]
    fn delta_from_anchor(&self, dt_ns: f64) -> f64 {
        let base = dt_ns * (self.one_plus_osc + self.c_drift);
        // With no slew (rate and remainder 0) the slewed part is +0, and `base` (nonzero, or
        // +0) plus +0 is `base` exactly.
        let slewed = (self.slew_rate.abs() * dt_ns).min(self.slew_remaining_ns);
        base + slewed.copysign(self.slew_rate)
    }

    /// The counter value at the last tick at or before local time `ns`.
    #[inline(always)]
    pub(crate) fn quantise(&self, ns: u64) -> u64 {
        ns - (ns.wrapping_sub(self.tick_residue) % 10)
    }

    /// Local time at real time `t_ps` in ns, with fraction, not quantised. `t_ps` may lie before
    /// the anchor (the current rates are extrapolated backwards) or beyond the next wander grid
    /// point (the wander step there is not yet known, so the current rate is extrapolated; call
    /// [`LocalClock::advance_to`] first for exact values).
    pub fn local_exact_ns(&self, t_ps: u64) -> (u64, f64) {
        self.local_exact_ns_in::<false>(t_ps)
    }

    /// [`LocalClock::local_exact_ns`], branch-free if `BRANCH_FREE` (see
    /// [`LocalClock::advance_to_in`]); the same figures either way.
    #[inline]
    pub(crate) fn local_exact_ns_in<const BRANCH_FREE: bool>(&self, t_ps: u64) -> (u64, f64) {
        let dt_ns = (t_ps as i64).wrapping_sub(self.anchor_ps as i64) as f64 * 1e-3;
        let s = self.anchor_local.add(self.delta_from_anchor(dt_ns));
        (s.ns, s.frac)
    }

    /// Local time at real time `t_ps` as the registers show it: the counter at its last tick.
    pub fn local_ns(&self, t_ps: u64) -> u64 {
        self.quantise(self.local_exact_ns(t_ps).0)
    }

    /// The crystal's own count at real time `t_ps` (at or after the last wander step), whole
    /// nanoseconds: the local time without the time control loop's corrections. The MII
    /// receive clocks' edges are the crystal's. Computed when asked (a stamp), from the count
    /// at the last change of the crystal's rate: nothing is added on the clock's hot path.
    #[inline(always)]
    pub fn crystal_ns(&self, t_ps: u64) -> u64 {
        (self.crystal_fp(t_ps) >> CRYSTAL_FP_BITS) as u64
    }

    #[inline(always)]
    fn crystal_fp(&self, t_ps: u64) -> u128 {
        let dt_ps = t_ps.wrapping_sub(self.crystal_ref_ps);
        self.crystal_ref_fp
            .wrapping_add(u128::from(dt_ps) * u128::from(self.crystal_rate_fp))
    }

    /// Local time (register view) at the anchor.
    #[inline]
    pub fn local_ns_at_anchor(&self) -> u64 {
        self.quantise(self.anchor_local.ns)
    }

    /// Local time at the anchor, whole nanoseconds, not quantised to the counter's tick.
    #[inline]
    pub fn anchor_ns(&self) -> u64 {
        self.anchor_local.ns
    }

    /// Real time of the next wander step, ps: the rate is constant until then.
    pub fn next_wander_ps(&self) -> u64 {
        self.next_wander_ps
    }

    /// Residue modulo 10 ns of every counter value (the tick grid).
    pub fn tick_residue(&self) -> u64 {
        self.tick_residue
    }

    /// Real time of the anchor, ps.
    pub fn anchor_ps(&self) -> u64 {
        self.anchor_ps
    }

    /// Moves the anchor to `t_ps`, applying every wander step on the way. Times before the anchor
    /// are ignored (events are processed in time order per clock; a frame that overtakes another
    /// by a few microseconds reads the clock through [`LocalClock::local_ns`] instead).
    #[inline]
    pub fn advance_to(&mut self, t_ps: u64) {
        self.advance_to_in::<false>(t_ps);
    }

    /// [`LocalClock::advance_to`]; if `BRANCH_FREE`, without a branch on whether a slew is
    /// running, for a large network's drives: a drive's slew ends before its next frame in
    /// some cycles and not in others, a pattern the CPU's branch predictor learns for a
    /// handful of drives and not for hundreds (at 4 ms cycles it missed a fifth of the time,
    /// and a 1 000-drive slave-cycle took 7-10 % longer). The figures are the same either
    /// way (`branch_free_clock_is_the_same_clock`); a small network keeps the branch, which
    /// costs it fewer instructions.
    #[inline(always)]
    pub(crate) fn advance_to_in<const BRANCH_FREE: bool>(&mut self, t_ps: u64) {
        if t_ps <= self.anchor_ps {
            return;
        }
        if t_ps < self.next_wander_ps {
            self.move_anchor(t_ps);
        } else {
            self.advance_across_wander(t_ps);
        }
    }

    #[cold]
    #[inline(never)]
    fn advance_across_wander(&mut self, t_ps: u64) {
        while self.next_wander_ps <= t_ps {
            let at = self.next_wander_ps;
            self.move_anchor(at);
            if self.params.wander_ppm_per_sqrt_s > 0.0 {
                self.crystal_ref_fp = self.crystal_fp(at);
                self.crystal_ref_ps = at;
                let step_s = self.params.wander_step_ps as f64 * 1e-12;
                let z: f64 = StandardNormal.sample(&mut *self.rng);
                self.wander += z * self.params.wander_ppm_per_sqrt_s * 1e-6 * step_s.sqrt();
                self.one_plus_osc = 1.0 + self.oscillator_error();
                self.crystal_rate_fp = crystal_rate_fp(self.one_plus_osc);
            }
            self.next_wander_ps = at.saturating_add(self.params.wander_step_ps.max(1));
        }
        self.move_anchor(t_ps);
    }

    // (Inline: the cyclic frames move a DC unit's anchor once per drive and frame.)
    /// Moves the anchor to `t_ps` without a branch on whether a slew is running, for every
    /// network: a large network's drives end their slews before the next frame in some cycles
    /// and not in others, a pattern the branch predictor does not learn for hundreds of them
    /// (a 1 000-drive slave-cycle took 7-10 % longer with the branch), and since MII stamps
    /// sit on the crystal's grid a small network's slaves step their phase at most frames too
    /// (`ecsync bench` on paper-2024: 38 -> 35.5 ns per slave-cycle without the branch).
    #[inline(always)]
    fn move_anchor(&mut self, t_ps: u64) {
        if t_ps <= self.anchor_ps {
            return;
        }
        // Through i64: one conversion instruction (u64 -> f64 takes several on x86-64).
        let dt_ns = (t_ps - self.anchor_ps) as i64 as f64 * 1e-3;
        // No slew is rate and remainder 0 (`retune_at_anchor_in`, `set_slew` and the end below
        // set both): the slewed part is then +0. `slewed` is at most the remainder, so what
        // remains is +0 when the slew ends, never negative: only the rate is set to 0 then.
        let rate = self.slew_rate;
        let slewed = (rate.abs() * dt_ns).min(self.slew_remaining_ns);
        let d = dt_ns * (self.one_plus_osc + self.c_drift) + slewed.copysign(rate);
        let remaining = self.slew_remaining_ns - slewed;
        self.slew_remaining_ns = remaining;
        self.slew_rate = std::hint::select_unpredictable(remaining <= 0.0, 0.0, rate);
        self.anchor_local = self.anchor_local.add(d);
        self.anchor_ps = t_ps;
    }

    /// Sets the drift correction and a new slew at the anchor (the clock must have been
    /// advanced to the current time): the time control loop's update after a compare.
    #[inline]
    pub fn retune_at_anchor(&mut self, drift: f64, slew_amount_ns: f64, slew_rate: f64) {
        self.retune_at_anchor_in::<false>(drift, slew_amount_ns, slew_rate);
    }

    /// [`LocalClock::retune_at_anchor`], branch-free if `BRANCH_FREE` (whether the filtered
    /// difference is 0 varies drive by drive; see [`LocalClock::advance_to_in`]).
    #[inline(always)]
    pub(crate) fn retune_at_anchor_in<const BRANCH_FREE: bool>(
        &mut self,
        drift: f64,
        slew_amount_ns: f64,
        slew_rate: f64,
    ) {
        self.c_drift = drift;
        if BRANCH_FREE {
            // (Selected as integers: selects of floats became branches again.)
            let none = (slew_amount_ns == 0.0) | (slew_rate <= 0.0);
            let rate = slew_rate.copysign(slew_amount_ns).to_bits();
            let remaining = slew_amount_ns.abs().to_bits();
            self.slew_rate = f64::from_bits(std::hint::select_unpredictable(none, 0, rate));
            self.slew_remaining_ns =
                f64::from_bits(std::hint::select_unpredictable(none, 0, remaining));
            return;
        }
        if slew_amount_ns == 0.0 || slew_rate <= 0.0 {
            self.slew_rate = 0.0;
            self.slew_remaining_ns = 0.0;
        } else {
            self.slew_rate = slew_rate.copysign(slew_amount_ns);
            self.slew_remaining_ns = slew_amount_ns.abs();
        }
    }

    /// Sets the frequency correction of the drift compensation (fraction), from `t_ps` on.
    pub fn set_drift_correction(&mut self, t_ps: u64, c: f64) {
        self.advance_to(t_ps);
        self.c_drift = c;
    }

    /// Current drift correction (fraction).
    pub fn drift_correction(&self) -> f64 {
        self.c_drift
    }

    /// Starts slewing `amount_ns` (signed: positive moves the clock forward) at `rate` (fraction,
    /// > 0), replacing any slew in progress.
    pub fn set_slew(&mut self, t_ps: u64, amount_ns: f64, rate: f64) {
        self.advance_to(t_ps);
        if amount_ns == 0.0 || rate <= 0.0 {
            self.slew_rate = 0.0;
            self.slew_remaining_ns = 0.0;
        } else {
            self.slew_rate = rate.copysign(amount_ns);
            self.slew_remaining_ns = amount_ns.abs();
        }
    }

    /// Slew still to be applied (signed ns).
    pub fn slew_remaining_ns(&self) -> f64 {
        self.slew_remaining_ns.copysign(self.slew_rate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000_000; // ps

    #[test]
    fn a_fast_crystal_gains_its_ppm() {
        let mut c = LocalClock::new(CrystalParams {
            ppm: 50.0,
            initial_local_ns: 1_000,
            ..Default::default()
        });
        // After 1 s of real time a +50 ppm clock is 50 us ahead.
        let t = 1000 * MS;
        let (ns, _) = c.local_exact_ns(t);
        assert_eq!(ns, 1_000 + 1_000_000_000 + 50_000);
        c.advance_to(t / 2);
        assert_eq!(
            c.local_exact_ns(t).0,
            ns,
            "advancing the anchor changes nothing"
        );
    }

    #[test]
    fn register_reads_are_quantised_to_the_tick() {
        let c = LocalClock::new(CrystalParams::default());
        assert_eq!(c.local_ns(0), 0);
        assert_eq!(c.local_ns(9_999), 0);
        assert_eq!(c.local_ns(10_000), 10);
        assert_eq!(c.local_ns(25_000), 20);
        assert_eq!(c.local_ns(1_000_005_000), 1_000_000);
        // The grid keeps the power-up residue.
        let c = LocalClock::new(CrystalParams {
            initial_local_ns: 1_003,
            ..Default::default()
        });
        assert_eq!(c.local_ns(0), 1_003);
        assert_eq!(c.local_ns(9_999), 1_003);
        assert_eq!(c.local_ns(10_000), 1_013);
    }

    #[test]
    fn slew_stops_when_done() {
        let mut c = LocalClock::new(CrystalParams::default());
        // Move 100 ns forward at 1e-4 (100 ns per ms of real time): done after 1 ms.
        c.set_slew(0, 100.0, 1e-4);
        assert_eq!(c.local_exact_ns(MS / 2).0, 500_000 + 50);
        assert_eq!(c.local_exact_ns(2 * MS).0, 2_000_000 + 100);
        c.advance_to(3 * MS);
        assert_eq!(c.slew_remaining_ns(), 0.0);
        assert_eq!(c.local_exact_ns(4 * MS).0, 4_000_000 + 100);
        // Backwards.
        c.set_slew(4 * MS, -40.0, 1e-4);
        assert_eq!(c.local_exact_ns(5 * MS).0, 5_000_000 + 60);
    }

    #[test]
    fn wander_is_a_function_of_real_time_only() {
        let p = CrystalParams {
            ppm: -20.0,
            wander_ppm_per_sqrt_s: 0.5,
            wander_step_ps: MS,
            seed: 7,
            ..Default::default()
        };
        let mut a = LocalClock::new(p);
        let mut b = LocalClock::new(p);
        // a is advanced in many small steps, b in one: same trajectory.
        for i in 0..1000u64 {
            a.advance_to(i * 333_333_333);
        }
        let t = 1000 * 333_333_333;
        a.advance_to(t);
        b.advance_to(t);
        assert_eq!(a.local_exact_ns(t).0, b.local_exact_ns(t).0);
        assert!((a.local_exact_ns(t).1 - b.local_exact_ns(t).1).abs() < 1e-3);
        assert_ne!(a.oscillator_error(), -20e-6, "wander moved the frequency");
    }
}

#[cfg(test)]
mod fast_math_tests {
    use super::*;

    #[test]
    fn floor() {
        for x in [
            -10.5,
            -10.0,
            -0.25,
            0.0,
            0.25,
            9.999,
            10.0,
            12345.678,
            -3e12 - 0.5,
            9.1e15 + 0.5,
            1.0e17,
            -1.0e17,
        ] {
            assert_eq!(floor_split(x), (x.floor() as i64, x.floor()), "{x}");
        }
        // Beyond i64: the integer saturates as `as` does.
        for x in [1e300, -1e300] {
            assert_eq!(floor_split(x).0, x.floor() as i64, "{x}");
        }
    }
}

#[cfg(test)]
mod branch_free_tests {
    use super::*;
    use proptest::prelude::*;

    /// One step of a time control loop's life: the clock advanced by `dt_ps`, read at an
    /// offset around the new anchor, retuned with a slew (sometimes none).
    #[derive(Debug, Clone)]
    struct Step {
        dt_ps: u64,
        read_offset_ps: i64,
        drift: f64,
        slew_ns: f64,
    }

    fn step() -> impl Strategy<Value = Step> {
        (
            prop_oneof![Just(0u64), 1u64..5_000_000_000, 1u64..20_000_000],
            -3_000_000_000i64..3_000_000_000,
            -1e-4f64..1e-4,
            prop_oneof![Just(0.0f64), -200.0f64..200.0, -1e-3f64..1e-3],
        )
            .prop_map(|(dt_ps, read_offset_ps, drift, slew_ns)| Step {
                dt_ps,
                read_offset_ps,
                drift,
                slew_ns,
            })
    }

    fn state(c: &LocalClock) -> [u64; 5] {
        [
            c.anchor_local.ns,
            c.anchor_local.frac.to_bits(),
            c.anchor_ps,
            c.slew_rate.to_bits(),
            c.slew_remaining_ns.to_bits(),
        ]
    }

    proptest! {
        /// The branch-free clock a large network's drives use is the same clock, to the bit:
        /// anchors, slews and every read, whether slews end between reads or outlast them.
        #[test]
        fn branch_free_clock_is_the_same_clock(
            ppm in -50.0f64..50.0,
            initial in 0u64..1 << 50,
            // The DC unit's slew rates: 1 / (10 * speed counter start), 0x1000 by default.
            speed in prop_oneof![Just(4096u32), 1u32..0x8000],
            steps in proptest::collection::vec(step(), 1..60),
        ) {
            let params = CrystalParams { ppm, initial_local_ns: initial, ..Default::default() };
            let (mut a, mut b) = (LocalClock::new(params), LocalClock::new(params));
            let rate = 1.0 / (10.0 * f64::from(speed));
            let mut t = 0u64;
            for s in steps {
                t += s.dt_ps;
                a.advance_to_in::<false>(t);
                b.advance_to_in::<true>(t);
                prop_assert_eq!(state(&a), state(&b));
                let at = t.saturating_add_signed(s.read_offset_ps);
                let (ra, rb) = (a.local_exact_ns_in::<false>(at), b.local_exact_ns_in::<true>(at));
                prop_assert_eq!((ra.0, ra.1.to_bits()), (rb.0, rb.1.to_bits()));
                a.retune_at_anchor_in::<false>(s.drift, s.slew_ns, rate);
                b.retune_at_anchor_in::<true>(s.drift, s.slew_ns, rate);
                prop_assert_eq!(state(&a), state(&b));
            }
        }
    }
}
