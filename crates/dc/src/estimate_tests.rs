//! Tests of `estimate.rs`: the estimators by hand, the methods in a closed loop.

use super::*;
use crate::time::SystemTime;

const P: u32 = 1_000_000;

#[test]
fn des_by_hand() {
    // α 0.5, β 0.5: readings 0, 10, 20.
    let mut d = DesEstimator::new(0.5, 0.5);
    d.observe(0.0);
    assert_eq!((d.level_ns(), d.trend_ns_per_cycle()), (0.0, 0.0));
    // L = 0.5 * 10 + 0.5 * (0 + 0) = 5; T = 0.5 * (5 - 0) + 0.5 * 0 = 2.5.
    d.observe(10.0);
    assert_eq!((d.level_ns(), d.trend_ns_per_cycle()), (5.0, 2.5));
    // L = 0.5 * 20 + 0.5 * (5 + 2.5) = 13.75; T = 0.5 * 8.75 + 0.5 * 2.5 = 5.625.
    d.observe(20.0);
    assert_eq!((d.level_ns(), d.trend_ns_per_cycle()), (13.75, 5.625));
    assert_eq!(d.forecast(), 19.375);
    // A lost reading: the level runs on by the trend.
    d.skip();
    assert_eq!(d.level_ns(), 19.375);
    // On a ramp Holt's forecast ends without lag (a single average would trail it by
    // T (1 - α) / α = 10 x 0.98 / 0.02 = 490 ns).
    let mut d = DesEstimator::new(0.02, 0.0005);
    for i in 0..60_000 {
        d.observe(10.0 * f64::from(i));
    }
    assert!((d.forecast() - 600_000.0).abs() < 0.5, "{}", d.forecast());
    assert!((d.trend_ns_per_cycle() - 10.0).abs() < 1e-3);
}

#[test]
fn kalman_by_hand() {
    // σ_v 10 ns (R = 100), no drift walk: start at 0 with P = diag(100, 100^2).
    let mut k = KalmanEstimator::new(10.0, 0.0, 1e9);
    k.observe(0.0);
    // Predict: P00 = 100 + 0 + 10_000 = 10_100, P01 = 10_000, P11 = 10_000; reading 50:
    // S = 10_200, K = (10_100/10_200, 10_000/10_200); offset = 50 x 0.990196 = 49.5098,
    // drift = 50 x 0.980392 = 49.0196.
    k.observe(50.0);
    assert!((k.offset_ns() - 50.0 * 10_100.0 / 10_200.0).abs() < 1e-9);
    assert!((k.drift_ns_per_cycle() - 50.0 * 10_000.0 / 10_200.0).abs() < 1e-9);
    // A ramp of 50 ns per cycle: the drift converges to it.
    for i in 2..200 {
        k.observe(50.0 * i as f64);
    }
    assert!(
        (k.drift_ns_per_cycle() - 50.0).abs() < 1e-3,
        "{}",
        k.drift_ns_per_cycle()
    );
    assert!(
        (k.forecast() - 50.0 * 200.0).abs() < 1e-3,
        "{}",
        k.forecast()
    );
}

#[test]
fn kalman_gains_settle_where_the_default_says() {
    let p = KalmanParams::default();
    let mut k = KalmanEstimator::new(p.meas_sigma_ns, p.drift_walk_ns, p.gate_sigma);
    for i in 0..200_000 {
        k.observe(f64::from(i % 7) * 100.0);
    }
    let (k0, k1) = k.gains();
    // The steady state of this model's Riccati equation: with λ = σ_w/σ_v = 2e-5 the drift
    // gain is about λ and the offset gain about sqrt(2 λ) (the α-β filter's relations for
    // small λ: β ≈ λ, α ≈ sqrt(2 β)).
    assert!((k1 / 2e-5 - 1.0).abs() < 0.05, "drift gain {k1}");
    assert!(
        (k0 / (2.0 * 2e-5f64).sqrt() - 1.0).abs() < 0.05,
        "offset gain {k0}"
    );
}

#[test]
fn kalman_gates_an_outlier_and_restarts_on_a_step() {
    let mut k = KalmanEstimator::new(100.0, 0.01, 5.0);
    for i in 0..5_000 {
        k.observe(f64::from(i % 3) * 50.0);
    }
    let before = k.offset_ns();
    // One NIC stall of 1 ms: beyond 5 σ, not used.
    k.observe(1_000_000.0);
    assert!((k.offset_ns() - before).abs() < 100.0);
    // A step that stays: after 20 readings the filter starts again from it.
    for _ in 0..20 {
        k.observe(1_000_000.0);
    }
    assert!(
        (k.offset_ns() - 1_000_000.0).abs() < 1_000.0,
        "{}",
        k.offset_ns()
    );
}

/// A closed loop with the NIC's noise: the reference drifts 30 ns per cycle against the master,
/// the frame leaves 20 us after its start (±2 us), the reading carries ±300 ns of noise. Both
/// methods end with the frames on the target (mean within 50 ns) from a start 300 us off.
#[test]
fn des_and_kalman_hold_the_target_on_a_drift() {
    fn run(m: &mut dyn MasterSync) -> (f64, f64) {
        let p = u64::from(P);
        let base = 1_000_000 * p;
        let mut sched = base;
        let mut x = 99u64;
        let mut rnd = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((x >> 33) % 1000) as i64 - 500
        };
        let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
        for i in 0..40_000u64 {
            let send = sched + (20_000 + 4 * rnd()) as u64;
            let true_ra = 7_000 * p + (send - base) + 300_000 + 30 * i;
            let t_ra = (true_ra as i64 + rnd() * 6 / 10) as u64;
            let phase = grid_phase(true_ra, 100_000, P) as f64;
            if i >= 30_000 {
                sum += phase;
                sum2 += phase * phase;
                n += 1.0;
            }
            let o = m.update(&CycleInput {
                cycle: i,
                period_ns: P,
                nominal_start: MasterInstant::from_ns(base + i * p),
                scheduled_start: MasterInstant::from_ns(sched),
                send: MasterInstant::from_ns(send),
                receive: MasterInstant::from_ns(send + 50_000),
                ref_time: Some(SystemTime::from_ns(t_ra)),
            });
            sched = o.next_start.as_ns();
        }
        let mean = sum / n;
        (mean, (sum2 / n - mean * mean).sqrt())
    }
    let d = DesParams::default();
    let (mean, sd) = run(&mut Des::new(d.alpha, d.beta, 100_000));
    assert!(mean.abs() < 50.0 && sd < 2_000.0, "des: {mean} ± {sd}");
    let (mean, sd) = run(&mut Kalman::new(&KalmanParams::default(), 100_000));
    assert!(mean.abs() < 50.0 && sd < 2_000.0, "kalman: {mean} ± {sd}");
}
