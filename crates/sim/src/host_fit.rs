//! The host model fitted to a recorded trace ([`fit`]): the wake-up latency's floor and jitter
//! (a folded Gaussian with exponential pulses), the execution time, the NIC's delay and the
//! bursts, as a `[host]` table the scenario takes ([`HostFit::to_toml`]).

use crate::host::{Bursts, HostNoise, HostParams, Jitter};
use crate::host_trace::TraceRow;

/// Quantile `q` (0..=1) of sorted values, by linear interpolation.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let x = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x - x.floor());
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] + f * (sorted[j] - sorted[i])
}

fn sorted(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = v.collect();
    v.sort_by(f64::total_cmp);
    v
}

/// The standard normal CDF (erfc by Numerical Recipes' Chebyshev fit, |error| < 1.2e-7).
fn phi(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * z);
    let erfc = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        1.0 - 0.5 * erfc
    } else {
        0.5 * erfc
    }
}

/// Where the core's Gaussian ends and the pulses are counted, in core sigmas: the core lies
/// beyond it in 6.3e-5 (folded) or 3.2e-5 (one side) of the cycles.
const TAIL_SIGMAS: f64 = 4.0;

/// Fits a [`Jitter`] to deviations `x` (from the floor for a folded core, from the median
/// otherwise; pulses go up): the core's sigma from two quantiles, the pulses from the cycles
/// beyond [`TAIL_SIGMAS`] core sigmas. An exponential pulse added to the core exceeds a
/// threshold t by an Exp(m) amount (memoryless), so m is an excess quantile over its level, and it exceeds t with
/// probability exp(-t/m) E[exp(c/m)], which gives the pulses' probability.
fn fit_jitter(x: &[f64], folded: bool) -> Jitter {
    let s = sorted(x.iter().copied());
    let n = s.len().max(1) as f64;
    let mut p = 0.0_f64;
    let mut sigma = 0.0;
    let mut mean_ns = 0.0;
    let (mut heavy_share, mut heavy_mean_ns) = (0.0, 0.0);
    let mut final_two: Option<(f64, f64, f64, f64)> = None;
    // E[exp(c/m)] of the core c (|N(0, sigma)| folded): how the core lifts a pulse of mean m.
    let e_core = |sigma: f64, m: f64| {
        let r = sigma / m;
        if folded {
            2.0 * (r * r / 2.0).exp() * phi(r)
        } else {
            (r * r / 2.0).exp()
        }
    };
    for _ in 0..3 {
        // The pulses sit above the core's quantiles: read the core's at shifted levels.
        let lv = |a: f64| (a * (1.0 - p)).min(1.0);
        sigma = if folded {
            // Folded N(0, s): q50 = 0.674 s, q90 = 1.645 s.
            quantile(&s, lv(0.9)) / 1.644_854
        } else {
            // N(0, s): q75 - q25 = 1.349 s.
            (quantile(&s, lv(0.75)) - quantile(&s, lv(0.25))) / 1.348_98
        }
        .max(0.0);
        let t = TAIL_SIGMAS * sigma;
        let beyond: Vec<f64> = s.iter().filter(|&&v| v > t).map(|v| v - t).collect();
        let core_beyond = if folded {
            2.0 * (1.0 - phi(TAIL_SIGMAS))
        } else {
            1.0 - phi(TAIL_SIGMAS)
        };
        let k = beyond.len() as f64 / n - core_beyond * (1.0 - p);
        // Pulses only where the cycles beyond the threshold stand out of the core's own
        // (three standard deviations of their count, and ten).
        let expected = core_beyond * (1.0 - p) * n;
        if (beyond.len() as f64) < expected + 3.0 * expected.sqrt() + 10.0 || k <= 0.0 {
            p = 0.0;
            mean_ns = 0.0;
            final_two = None;
            break;
        }
        // One class first, to place the core (its quantiles shift with the pulses' share): the
        // excess's quantile at level a over -ln(1 - a) (any a, for an exponential), a where
        // the whole distribution's p99 and p99.9 lie among the pulses (their geometric middle).
        let kf = beyond.len() as f64 / n;
        let level = |q: f64| (1.0 - (1.0 - q) / kf).clamp(0.5, 0.999);
        let a = 1.0 - ((1.0 - level(0.99)) * (1.0 - level(0.999))).sqrt();
        mean_ns = quantile(&sorted(beyond.iter().copied()), a) / -(1.0 - a).ln();
        p = (k / ((-t / mean_ns).exp() * e_core(sigma, mean_ns))).clamp(0.0, 1.0);
        // Then the tail's shape. The excesses over the threshold are, for each pulse class,
        // exponential with the class's mean (memoryless: the core's part below the threshold
        // does not matter). A real host's tail is heavier than one exponential (many short
        // preemptions, a few stalls of milliseconds): two classes are fitted to the excesses
        // (maximum likelihood) where they stand apart, each class's share of the cycles
        // beyond the threshold taken back to its pulses' probability (a pulse of mean m takes
        // the core past t with probability exp(-t/m) E[exp(c/m)]).
        let (w_heavy, m_light, m_heavy) = fit_two_exponentials(&beyond);
        if w_heavy > 0.0 {
            let pulses = |share: f64, m: f64| k * share / ((-t / m).exp() * e_core(sigma, m));
            let (p_light, p_heavy) = (pulses(1.0 - w_heavy, m_light), pulses(w_heavy, m_heavy));
            final_two = Some((
                (p_light + p_heavy).clamp(0.0, 1.0),
                m_light,
                p_heavy / (p_light + p_heavy),
                m_heavy,
            ));
        } else {
            final_two = None;
        }
    }
    // The two classes replace the one where they were fitted (the core as the one class
    // placed it).
    if p > 0.0
        && let Some((p2, m_light, share, m_heavy)) = final_two
    {
        p = p2;
        mean_ns = m_light;
        heavy_share = share;
        heavy_mean_ns = m_heavy;
    }
    Jitter {
        sigma_ns: sigma,
        folded,
        tail_p: p,
        tail_mean_ns: mean_ns,
        tail_sign: 1.0,
        max_abs_ns: s.last().map_or(0.0, |m| m.abs()).max(TAIL_SIGMAS * sigma),
        tail_heavy_share: heavy_share,
        tail_heavy_mean_ns: heavy_mean_ns,
    }
}

/// A mixture of two exponentials fitted to `x` (all >= 0) by expectation maximisation:
/// (weight of the heavier, mean of the lighter, mean of the heavier), ns. One exponential
/// (weight 0) where the data do not hold two apart: fewer than 20 samples, or means within a
/// factor of 2 of each other, or a heavier class of under 5 samples.
pub fn fit_two_exponentials(x: &[f64]) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n.max(1.0);
    if x.len() < 20 || mean <= 0.0 {
        return (0.0, mean.max(0.0), 0.0);
    }
    let s = sorted(x.iter().copied());
    // Start: the lighter class from the median, the heavier from the top percent.
    let mut m1 = (quantile(&s, 0.5) / std::f64::consts::LN_2).max(mean * 0.1);
    let mut m2 = (quantile(&s, 0.99) / 100f64.ln()).max(2.0 * m1);
    let mut w2 = 0.1;
    for _ in 0..500 {
        let (mut r_sum, mut r_x, mut q_x) = (0.0, 0.0, 0.0);
        for &v in x {
            let f1 = (1.0 - w2) / m1 * (-v / m1).exp();
            let f2 = w2 / m2 * (-v / m2).exp();
            let r = if f1 + f2 > 0.0 { f2 / (f1 + f2) } else { 1.0 };
            r_sum += r;
            r_x += r * v;
            q_x += (1.0 - r) * v;
        }
        let (w_new, m2_new, m1_new) = (
            r_sum / n,
            r_x / r_sum.max(1e-12),
            q_x / (n - r_sum).max(1e-12),
        );
        let done = (w_new - w2).abs() < 1e-9 && (m1_new / m1 - 1.0).abs() < 1e-9;
        (w2, m1, m2) = (w_new, m1_new.max(1e-9), m2_new.max(1e-9));
        if done || w2 <= 0.0 || w2 >= 1.0 {
            break;
        }
    }
    if m2 < m1 {
        (w2, m1, m2) = (1.0 - w2, m2, m1);
    }
    if !(w2 > 0.0 && w2 < 1.0) || m2 < 2.0 * m1 || w2 * n < 5.0 {
        return (0.0, mean, 0.0);
    }
    (w2, m1, m2)
}

/// Cycles per window of the burst detection: long enough for a robust median, short against
/// the bursts it looks for.
pub const BURST_WINDOW_CYCLES: usize = 50;

/// The host model fitted to a trace.
#[derive(Debug, Clone, PartialEq)]
pub struct HostFit {
    /// The parameters: what the trace measured, the base preset's for the rest.
    pub params: HostParams,
    /// The wake-up latency's floor, ns (counted in `params.em_ns`).
    pub wake_floor_ns: f64,
    /// Mean execution time measured, ns.
    pub exec_mean_ns: f64,
    /// Cycles fitted.
    pub cycles: usize,
    /// Whether the trace had TX delays (else j_c and the TX latency are the base preset's).
    pub tx_measured: bool,
}

/// Fits the host model to `rows`, keeping `base`'s crystal and receive latency (and its j_c and
/// TX latency when the trace has no TX delays).
pub fn fit(rows: &[TraceRow], base: HostParams) -> HostFit {
    let wake: Vec<f64> = rows.iter().map(|r| r.wake_latency_ns).collect();
    // Floor and core from the quantiles: folded N(0, s) has q50 = 0.674 s, q90 = 1.645 s.
    let floor_of = |v: &[f64]| {
        let s = sorted(v.iter().copied());
        let (q50, q90) = (quantile(&s, 0.5), quantile(&s, 0.9));
        let sd = ((q90 - q50) / (1.644_854 - 0.674_490)).max(0.0);
        (q50 - 0.674_490 * sd).max(s.first().copied().unwrap_or(0.0).min(q50))
    };
    let floor0 = floor_of(&wake);
    // Bursts: windows whose median stands far above the typical window's.
    let meds: Vec<f64> = wake
        .chunks(BURST_WINDOW_CYCLES)
        .map(|w| quantile(&sorted(w.iter().map(|v| v - floor0)), 0.5))
        .collect();
    let sm = sorted(meds.iter().copied());
    let m = quantile(&sm, 0.5).max(1.0);
    let mad = quantile(&sorted(sm.iter().map(|v| (v - m).abs())), 0.5) * 1.4826;
    let thr = (2.0 * m).max(m + 8.0 * mad);
    let burst: Vec<bool> = meds.iter().map(|&v| v > thr).collect();
    let n_burst = burst.iter().filter(|&&b| b).count();
    let quiet: Vec<f64> = wake
        .chunks(BURST_WINDOW_CYCLES)
        .zip(&burst)
        .filter(|(_, b)| !**b)
        .flat_map(|(w, _)| w.iter().copied())
        .collect();
    let quiet = if quiet.len() < 2 { wake.clone() } else { quiet };
    let floor = floor_of(&quiet);
    let js = fit_jitter(
        &quiet
            .iter()
            .map(|v| (v - floor).max(0.0))
            .collect::<Vec<_>>(),
        true,
    );
    let bursts = if n_burst == 0 || n_burst == burst.len() {
        Bursts::NONE
    } else {
        let in_b: Vec<f64> = wake
            .chunks(BURST_WINDOW_CYCLES)
            .zip(&burst)
            .filter(|(_, b)| **b)
            .flat_map(|(w, _)| w.iter().map(|v| (v - floor).max(0.0)))
            .collect();
        let q_med = quantile(&sorted(quiet.iter().map(|v| (v - floor).max(0.0))), 0.5);
        let b_med = quantile(&sorted(in_b.into_iter()), 0.5);
        let runs = burst.windows(2).filter(|w| w[1] && !w[0]).count() + usize::from(burst[0]);
        Bursts {
            p: n_burst as f64 / burst.len() as f64,
            mean_cycles: (n_burst * BURST_WINDOW_CYCLES) as f64 / runs.max(1) as f64,
            js_scale: (b_med / q_med.max(1.0)).clamp(1.0, 1_000.0),
        }
    };
    let exec = sorted(rows.iter().map(|r| r.exec_ns));
    let exec_med = quantile(&exec, 0.5);
    let exec_mean = exec.iter().sum::<f64>() / exec.len().max(1) as f64;
    let em_jitter = fit_jitter(
        &exec.iter().map(|v| v - exec_med).collect::<Vec<_>>(),
        false,
    );
    let tx: Vec<f64> = rows.iter().filter_map(|r| r.tx_delay_ns).collect();
    let (jc, tx_latency_ns) = if tx.len() >= 2 {
        let med = quantile(&sorted(tx.iter().copied()), 0.5);
        let up = fit_jitter(&tx.iter().map(|v| v - med).collect::<Vec<_>>(), false);
        let down = fit_jitter(&tx.iter().map(|v| med - v).collect::<Vec<_>>(), false);
        // One pulse direction in the model: the side with more of them.
        let jc = if down.tail_p > up.tail_p {
            Jitter {
                tail_sign: -1.0,
                ..down
            }
        } else {
            up
        };
        (jc, med)
    } else {
        (base.jc, base.tx_latency_ns)
    };
    HostFit {
        params: HostParams {
            js,
            em_ns: exec_med + floor,
            em_jitter,
            jc,
            tx_latency_ns,
            bursts,
            ..base
        },
        wake_floor_ns: floor,
        exec_mean_ns: exec_mean,
        cycles: rows.len(),
        tx_measured: tx.len() >= 2,
    }
}

impl HostFit {
    /// The `[host]` table of a scenario, with `preset` as the base for what the trace does not
    /// measure.
    pub fn to_toml(&self, preset: &str, source: &str) -> String {
        let p = &self.params;
        let j = |j: &Jitter| {
            let heavy = if j.tail_heavy_share > 0.0 {
                format!(
                    ", tail_heavy_share = {:.6}, tail_heavy_mean_ns = {:.1}",
                    j.tail_heavy_share, j.tail_heavy_mean_ns
                )
            } else {
                String::new()
            };
            format!(
                "{{ sigma_ns = {:.1}, folded = {}, tail_p = {:.6}, tail_mean_ns = {:.1}, tail_sign = {:.1}, max_abs_ns = {:.1}{heavy} }}",
                j.sigma_ns, j.folded, j.tail_p, j.tail_mean_ns, j.tail_sign, j.max_abs_ns
            )
        };
        let mut t = format!(
            "# Fitted by `ecsync host fit` to {source} ({} cycles).\n# Wake-up latency = {:.0} ns floor + j_s; the floor is counted in em_ns (e_m = {:.0} ns measured + the floor).\n",
            self.cycles,
            self.wake_floor_ns,
            p.em_ns - self.wake_floor_ns
        );
        if !self.tx_measured {
            t.push_str(&format!(
                "# The trace has no TX delays (recorded without --iface): jc and tx_latency_ns are {preset}'s.\n"
            ));
        }
        t.push_str(&format!(
            "# master_ppm, its wander and rx_latency_ns are not measured by a host trace: {preset}'s.\n[host]\npreset = \"{preset}\"\njs = {}\nem_ns = {:.1}\nem_jitter = {}\njc = {}\ntx_latency_ns = {:.1}\n",
            j(&p.js),
            p.em_ns,
            j(&p.em_jitter),
            j(&p.jc),
            p.tx_latency_ns
        ));
        if !p.bursts.is_none() {
            t.push_str(&format!(
                "bursts = {{ p = {:.6}, mean_cycles = {:.1}, js_scale = {:.3} }}\n",
                p.bursts.p, p.bursts.mean_cycles, p.bursts.js_scale
            ));
        }
        t
    }

    /// The model's wake-up latency quantiles `qs` (floor + j_s), from `cycles` cycles drawn
    /// with seed `seed`.
    pub fn predicted_wake_quantiles(&self, qs: &[f64], cycles: u64, seed: u64) -> Vec<f64> {
        let noise = HostNoise::new(self.params, seed);
        let s = sorted((0..cycles).map(|c| self.wake_floor_ns + noise.cycle(c).js_ns));
        qs.iter().map(|&q| quantile(&s, q)).collect()
    }
}

/// Measured wake-up latency quantiles of `rows`.
pub fn wake_quantiles(rows: &[TraceRow], qs: &[f64]) -> Vec<f64> {
    let s = sorted(rows.iter().map(|r| r.wake_latency_ns));
    qs.iter().map(|&q| quantile(&s, q)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phi_is_the_normal_cdf() {
        assert!((phi(0.0) - 0.5).abs() < 1e-7);
        assert!((phi(1.959_964) - 0.975).abs() < 1e-6);
        assert!((phi(-4.0) - 3.167e-5).abs() < 1e-7);
    }
}
