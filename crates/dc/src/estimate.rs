//! Master shift by estimation: the master-to-reference offset and drift estimated from every
//! frame and fed forward, so that the next frame reaches the reference on the target.
//!
//! | type | name | estimator |
//! |---|---|---|
//! | [`Des`] | `des` | double exponential smoothing (Holt's level and trend), as Jin et al., "DES-Based Synchronization Algorithm Optimization for EtherCAT Master–Slave System", *Processes* 13(11):3643, 2025 (and their patent US 12 314 198 B1) smooth the drift |
//! | [`Kalman`] | `kalman` | a two-state (offset, drift) Kalman filter, the model of the Kalman clock servos for IEEE 1588 (e.g. Giorgi and Narduzzi, IEEE Trans. Instrum. Meas. 60(8), 2011; IEEE Trans. Instrum. Meas. 74, 2025) |
//!
//! Both see `y_i = t_ra^i - t_ms^i`, the reference's time where the frame passed it less the
//! send timestamp: the clocks' offset plus the way to the reference, with the NIC's noise only
//! (the send's jitter moves both ends). It changes by the drift each cycle, whatever the master
//! does, so the estimators run open-loop and their one-cycle-ahead forecast `ŷ` sets the next
//! start: the frame sent `s̄` after its cycle's start (the send's mean delay: the median of the
//! first 63, then an average of the delays clamped to within 50 us of it) reaches the
//! reference at `t_mt + s̄ + ŷ`, which is put on the target phase of the DC grid.
//! The papers write the estimate into the slaves (the patent) or the reference; here, as
//! master-shift methods, it moves the master's cycles (the comparison's master-shift family).

use crate::offset::round_ns;
use crate::registry::MethodKind;
use crate::sync::{CycleInput, CycleOutput, MasterSync, SlidingMedian, grid_phase, next_nominal};
use crate::time::MasterInstant;
use ecsync_wire::dc_time::diff_u64;

/// Width of the median that starts the send delay's average.
const SEND_DELAY_WINDOW: usize = 63;
/// Weight of a new delay in the send delay's average (2^-10: a second at 1 ms).
const SEND_DELAY_WEIGHT: f64 = 1.0 / 1024.0;
/// A delay counts at most this far from the average, ns (a host's stall of milliseconds moves
/// the average by 50 ns, not by a millisecond's share).
const SEND_DELAY_CLAMP_NS: f64 = 50_000.0;

/// The mean delay of the send after its cycle's start: the median of the first
/// [`SEND_DELAY_WINDOW`] delays, then an exponential average of the delays, each clamped to
/// within [`SEND_DELAY_CLAMP_NS`] of it. The mean, not the median, because the comparison (and a
/// drive's margin) counts the frames' mean arrival: a host's delays lean late, their median
/// sits microseconds before their mean.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SendDelay {
    median: SlidingMedian,
    n: usize,
    mean_ns: f64,
}

impl SendDelay {
    const fn new() -> Self {
        SendDelay {
            median: SlidingMedian::new(SEND_DELAY_WINDOW),
            n: 0,
            mean_ns: 0.0,
        }
    }

    fn add(&mut self, s_ns: i64) -> f64 {
        if self.n < SEND_DELAY_WINDOW {
            self.n += 1;
            self.mean_ns = self.median.push(s_ns) as f64;
        } else {
            let d = (s_ns as f64 - self.mean_ns).clamp(-SEND_DELAY_CLAMP_NS, SEND_DELAY_CLAMP_NS);
            self.mean_ns += SEND_DELAY_WEIGHT * d;
        }
        self.mean_ns
    }
}

/// One cycle's offset reading or its absence, to an estimator of `r_i = y_i - y_0`, ns.
trait Estimator {
    /// A reading of this cycle.
    fn observe(&mut self, r_ns: f64);
    /// No reading this cycle (a lost frame): the estimate runs on.
    fn skip(&mut self);
    /// The estimate for the next cycle, ns.
    fn forecast(&self) -> f64;
}

/// Where the next start goes, from an estimator's forecast.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Aim {
    target_phase_ns: i64,
    y0: Option<i64>,
    send_delay: SendDelay,
    /// Makes `δ̂ = offset + s̄ + ŷ` put the first forecast on the target (a constant after).
    offset: Option<f64>,
    delta_hat: f64,
}

impl Aim {
    const fn new(target_phase_ns: i64) -> Self {
        Aim {
            target_phase_ns,
            y0: None,
            send_delay: SendDelay::new(),
            offset: None,
            delta_hat: 0.0,
        }
    }

    fn update(&mut self, input: &CycleInput, est: &mut impl Estimator) -> CycleOutput {
        let s = diff_u64(input.send.as_ns(), input.scheduled_start.as_ns());
        let sd = self.send_delay.add(s);
        let mut error = 0;
        match input.ref_time_ns() {
            Some(t_ra) => {
                let y = diff_u64(t_ra, input.send.as_ns());
                let y0 = *self.y0.get_or_insert(y);
                est.observe(y.wrapping_sub(y0) as f64);
                error = grid_phase(t_ra, self.target_phase_ns, input.period_ns);
            }
            None => est.skip(),
        }
        let next_nominal = next_nominal(input);
        if let Some(y0) = self.y0 {
            let ahead = sd + est.forecast();
            let offset = *self.offset.get_or_insert_with(|| {
                let arrival = next_nominal
                    .wrapping_add(y0 as u64)
                    .wrapping_add(round_ns(ahead) as u64);
                grid_phase(arrival, self.target_phase_ns, input.period_ns) as f64 - ahead
            });
            self.delta_hat = offset + ahead;
        }
        let corr = round_ns(self.delta_hat);
        CycleOutput {
            next_start: MasterInstant::from_ns(next_nominal.wrapping_sub(corr as u64)),
            error_ns: error,
            correction_ns: corr,
        }
    }
}

/// Parameters of `des`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct DesParams {
    /// Level smoothing α (0, 1].
    pub alpha: f64,
    /// Trend smoothing β (0, 1].
    pub beta: f64,
}

impl Default for DesParams {
    /// The paper gives no constants for a 1 ms cycle that the comparison could take; these are
    /// ecsync's: the level averages about 1/α = 50 frames (the NIC's noise down by ~7), the
    /// drift about 1/β = 2 000 (a crystal's drift changes over seconds, not milliseconds).
    fn default() -> Self {
        DesParams {
            alpha: 0.02,
            beta: 0.0005,
        }
    }
}

/// Holt's double exponential smoothing of `r`: level `L` and trend `T` (the drift, ns per
/// cycle), `L_i = α r_i + (1 - α)(L_{i-1} + T_{i-1})`, `T_i = β (L_i - L_{i-1}) + (1 - β)
/// T_{i-1}`, the first reading the level and no trend; the forecast is `L + T`. Holt's method
/// follows a constant drift without lag (the trend takes it up), where a single exponential
/// average trails it by `T (1 - α) / α`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DesEstimator {
    alpha: f64,
    beta: f64,
    level: f64,
    trend: f64,
    started: bool,
}

impl DesEstimator {
    /// An estimator with smoothing constants α and β.
    pub const fn new(alpha: f64, beta: f64) -> Self {
        DesEstimator {
            alpha,
            beta,
            level: 0.0,
            trend: 0.0,
            started: false,
        }
    }

    /// The smoothed level, ns.
    pub fn level_ns(&self) -> f64 {
        self.level
    }

    /// The smoothed trend, ns per cycle.
    pub fn trend_ns_per_cycle(&self) -> f64 {
        self.trend
    }
}

impl Estimator for DesEstimator {
    fn observe(&mut self, r: f64) {
        if !self.started {
            self.started = true;
            self.level = r;
            return;
        }
        let prev = self.level;
        self.level = self.alpha * r + (1.0 - self.alpha) * (self.level + self.trend);
        self.trend = self.beta * (self.level - prev) + (1.0 - self.beta) * self.trend;
    }

    fn skip(&mut self) {
        self.level += self.trend;
    }

    fn forecast(&self) -> f64 {
        self.level + self.trend
    }
}

/// `des`: the master-to-reference offset and drift by Holt's double exponential smoothing
/// ([`DesEstimator`]), fed forward (see the [module](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Des {
    est: DesEstimator,
    aim: Aim,
}

impl Des {
    /// Smoothing α and β, aiming at `target_phase_ns` after the grid point.
    pub const fn new(alpha: f64, beta: f64, target_phase_ns: i64) -> Self {
        Des {
            est: DesEstimator::new(alpha, beta),
            aim: Aim::new(target_phase_ns),
        }
    }

    /// The estimator.
    pub fn estimator(&self) -> &DesEstimator {
        &self.est
    }
}

impl MasterSync for Des {
    fn name(&self) -> &'static str {
        MethodKind::Des.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        self.aim.update(input, &mut self.est)
    }
}

/// Parameters of `kalman`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
pub struct KalmanParams {
    /// The reading's noise σ, ns (the NIC's: send timestamp to wire).
    pub meas_sigma_ns: f64,
    /// The drift's random walk per cycle σ, ns per cycle (how fast the crystals' difference
    /// wanders: with temperature, over seconds).
    pub drift_walk_ns: f64,
    /// Readings whose innovation lies beyond this many σ of its predicted spread are not used
    /// (after 20 in a row the filter starts again from the reading: a step, not an outlier).
    pub gate_sigma: f64,
}

impl Default for KalmanParams {
    /// ecsync's: a NIC's noise of 0.5 us and a drift that wanders 0.01 ns per cycle each cycle
    /// make a filter whose offset gain settles near 0.006 and drift gain near 2e-5 (a loop of
    /// some 200 cycles), about the bandwidth of `median-fit`.
    fn default() -> Self {
        KalmanParams {
            meas_sigma_ns: 500.0,
            drift_walk_ns: 0.01,
            gate_sigma: 5.0,
        }
    }
}

/// Rejected readings in a row after which the filter restarts from the reading.
const KALMAN_RESTART_AFTER: u32 = 20;
/// The drift's spread at the start: 100 ppm at 1 ms, ns per cycle.
const KALMAN_DRIFT0_NS: f64 = 100.0;

/// A Kalman filter of `x = (r, d)`, offset and drift per cycle, with `r_{i+1} = r_i + d_i`,
/// `d_{i+1} = d_i + w` (`w` the drift's random walk), read as `z_i = r_i + v` (`v` the NIC's
/// noise). Prediction `P = F P Fᵀ + Q`, gain `K = P Hᵀ / (H P Hᵀ + R)`, the update in Joseph-free
/// form (the two-state covariance stays symmetric by construction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanEstimator {
    r_var: f64,
    q_drift: f64,
    gate_sigma: f64,
    offset: f64,
    drift: f64,
    p00: f64,
    p01: f64,
    p11: f64,
    started: bool,
    rejected_in_a_row: u32,
}

impl KalmanEstimator {
    /// A filter with the reading's σ, the drift's walk σ and the gate.
    pub const fn new(meas_sigma_ns: f64, drift_walk_ns: f64, gate_sigma: f64) -> Self {
        KalmanEstimator {
            r_var: meas_sigma_ns * meas_sigma_ns,
            q_drift: drift_walk_ns * drift_walk_ns,
            gate_sigma,
            offset: 0.0,
            drift: 0.0,
            p00: 0.0,
            p01: 0.0,
            p11: 0.0,
            started: false,
            rejected_in_a_row: 0,
        }
    }

    /// The estimated offset, ns.
    pub fn offset_ns(&self) -> f64 {
        self.offset
    }

    /// The estimated drift, ns per cycle.
    pub fn drift_ns_per_cycle(&self) -> f64 {
        self.drift
    }

    /// The gains the last update used: (offset, drift).
    pub fn gains(&self) -> (f64, f64) {
        let s = self.p00 + self.r_var;
        (self.p00 / s, self.p01 / s)
    }

    fn start(&mut self, z: f64) {
        self.started = true;
        self.offset = z;
        self.p00 = self.r_var;
        self.p01 = 0.0;
        self.p11 = KALMAN_DRIFT0_NS * KALMAN_DRIFT0_NS;
        self.rejected_in_a_row = 0;
    }

    fn predict(&mut self) {
        self.offset += self.drift;
        self.p00 += 2.0 * self.p01 + self.p11;
        self.p01 += self.p11;
        self.p11 += self.q_drift;
    }
}

impl Estimator for KalmanEstimator {
    fn observe(&mut self, z: f64) {
        if !self.started {
            self.start(z);
            return;
        }
        self.predict();
        let nu = z - self.offset;
        let s = self.p00 + self.r_var;
        if nu * nu > self.gate_sigma * self.gate_sigma * s {
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= KALMAN_RESTART_AFTER {
                let drift = self.drift;
                self.start(z);
                self.drift = drift;
            }
            return;
        }
        self.rejected_in_a_row = 0;
        let (k0, k1) = (self.p00 / s, self.p01 / s);
        self.offset += k0 * nu;
        self.drift += k1 * nu;
        let (p00, p01) = (self.p00, self.p01);
        self.p00 = p00 - k0 * p00;
        self.p01 = p01 - k0 * p01;
        self.p11 -= k1 * p01;
    }

    fn skip(&mut self) {
        if self.started {
            self.predict();
        }
    }

    fn forecast(&self) -> f64 {
        self.offset + self.drift
    }
}

/// `kalman`: the master-to-reference offset and drift by a two-state Kalman filter
/// ([`KalmanEstimator`]), fed forward (see the [module](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kalman {
    est: KalmanEstimator,
    aim: Aim,
}

impl Kalman {
    /// The filter of `p`, aiming at `target_phase_ns` after the grid point.
    pub const fn new(p: &KalmanParams, target_phase_ns: i64) -> Self {
        Kalman {
            est: KalmanEstimator::new(p.meas_sigma_ns, p.drift_walk_ns, p.gate_sigma),
            aim: Aim::new(target_phase_ns),
        }
    }

    /// The estimator.
    pub fn estimator(&self) -> &KalmanEstimator {
        &self.est
    }
}

impl MasterSync for Kalman {
    fn name(&self) -> &'static str {
        MethodKind::Kalman.name()
    }

    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        self.aim.update(input, &mut self.est)
    }
}

#[cfg(test)]
#[path = "estimate_tests.rs"]
mod tests;
