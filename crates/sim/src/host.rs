//! The master host: its crystal, and the letter's jitter sources as seeded random processes.
//!
//! * `j_s`: thread scheduling and processing jitter between the theoretical cycle start and the
//!   send timestamp (eq. 1), never negative;
//! * `e_m`: execution time of the application and data exchange (eq. 1);
//! * `j_c`: NIC driver jitter between the send timestamp and the frame's first bit on the wire
//!   (eq. 2), modelled as pulse noise as the letter does (a Gaussian core plus rare pulses).
//!
//! Every sample is a pure function of (seed, source, cycle index): a counter-based generator, so
//! every method of a comparison sees exactly the same noise in the same cycle whatever it does
//! (common random numbers), and a run is reproducible bit for bit.
//!
//! Correlated noise ([`Bursts`]): a loaded or virtual host has phases (stress-ng's bursts, a
//! hypervisor's steal) in which j_s is several times larger for hundreds of cycles. Time is cut
//! into epochs of a fixed length, each a burst or not by a hash of (seed, epoch) alone, so the
//! regime too is a pure function of (seed, cycle), and the per-cycle draws are the same with or
//! without bursts. A recorded trace can stand in for the model ([`crate::host_trace`]).

use crate::host_trace::Replay;
use crate::rng::{SplitMix64, splitmix64, unit_from_bits as unit};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// A jitter distribution: a Gaussian core plus, with probability `tail_p`, an exponential pulse
/// of mean `tail_mean_ns` in the direction `tail_sign`, clamped to `max_abs_ns`. With `folded`,
/// the core is |N(0, σ)| (a delay that cannot be negative).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Jitter {
    /// Standard deviation of the Gaussian core, ns.
    pub sigma_ns: f64,
    /// Fold the core to non-negative values.
    #[serde(default)]
    pub folded: bool,
    /// Probability of a pulse per cycle.
    #[serde(default)]
    pub tail_p: f64,
    /// Mean pulse size, ns.
    #[serde(default)]
    pub tail_mean_ns: f64,
    /// Direction of pulses: +1 later, -1 earlier.
    #[serde(default = "one")]
    pub tail_sign: f64,
    /// Clamp of |sample|, ns.
    #[serde(default = "big")]
    pub max_abs_ns: f64,
    /// Share of the pulses that come from a second, heavier class (0: one class). A real
    /// host's tail is heavier than one exponential: many short preemptions and a few long
    /// stalls. Which class a pulse is of is read from the same uniform that decided it comes
    /// (below `tail_p`, it is uniform again), so a model without it draws exactly as before.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub tail_heavy_share: f64,
    /// Mean size of the heavier class's pulses, ns.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub tail_heavy_mean_ns: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn one() -> f64 {
    1.0
}
fn big() -> f64 {
    1e9
}

impl Jitter {
    /// No jitter.
    pub const ZERO: Jitter = Jitter {
        sigma_ns: 0.0,
        folded: false,
        tail_p: 0.0,
        tail_mean_ns: 0.0,
        tail_sign: 1.0,
        max_abs_ns: 1e9,
        tail_heavy_share: 0.0,
        tail_heavy_mean_ns: 0.0,
    };

    /// A sample from a standard normal `g`, a uniform deciding whether a pulse comes and, only
    /// when one does, a uniform for its size.
    fn sample(&self, g: f64, u_pulse: f64, u_size: impl FnOnce() -> f64) -> f64 {
        let mut v = g * self.sigma_ns;
        if self.folded {
            v = v.abs();
        }
        if self.tail_p > 0.0 && u_pulse < self.tail_p {
            v += self.pulse(u_size(), u_pulse / self.tail_p);
        }
        v.clamp(-self.max_abs_ns, self.max_abs_ns)
    }

    /// An exponential pulse, of the heavier class when `u_class` (uniform) is below its share.
    /// Out of line so that the logarithm is only computed for the rare cycles that have one
    /// (the optimiser would otherwise compute it every time and select).
    #[cold]
    #[inline(never)]
    fn pulse(&self, u_size: f64, u_class: f64) -> f64 {
        let mean = if u_class < self.tail_heavy_share {
            self.tail_heavy_mean_ns
        } else {
            self.tail_mean_ns
        };
        self.tail_sign.signum() * -mean * u_size.ln()
    }

    /// The latest a sample comes, ns, about once in `draws` draws: the core's expected
    /// largest of that many (`sigma * sqrt(2 ln draws)`), plus, when the pulses make it later,
    /// the pulse size that many draws exceed about once (`mean * ln(draws * tail_p)`, of the
    /// class that reaches further), clamped to `max_abs_ns`. A bound to plan with, not a
    /// certainty: once in a run of that length a sample comes about this late.
    pub fn latest_in_ns(&self, draws: f64) -> f64 {
        let n = draws.max(2.0);
        let core = self.sigma_ns * (2.0 * n.ln()).sqrt();
        let pulse = if self.tail_p > 0.0 && self.tail_sign > 0.0 {
            let light = n * self.tail_p * (1.0 - self.tail_heavy_share);
            let heavy = n * self.tail_p * self.tail_heavy_share;
            let reach = |count: f64, mean: f64| if count > 1.0 { mean * count.ln() } else { 0.0 };
            reach(light, self.tail_mean_ns).max(reach(heavy, self.tail_heavy_mean_ns))
        } else {
            0.0
        };
        (core + pulse).min(self.max_abs_ns)
    }

    /// Checks the numbers; returns the field at fault and why.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (f, v) in [
            ("sigma_ns", self.sigma_ns),
            ("tail_mean_ns", self.tail_mean_ns),
            ("max_abs_ns", self.max_abs_ns),
            ("tail_heavy_mean_ns", self.tail_heavy_mean_ns),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((f, format!("{v} must be a finite number >= 0")));
            }
        }
        if !(0.0..=1.0).contains(&self.tail_p) {
            return Err(("tail_p", format!("{} is not a probability", self.tail_p)));
        }
        if !(0.0..=1.0).contains(&self.tail_heavy_share) {
            return Err((
                "tail_heavy_share",
                format!("{} is not a share (0 ..= 1)", self.tail_heavy_share),
            ));
        }
        Ok(())
    }
}

/// Bursty phases of j_s: a fraction `p` of the cycles lies in bursts of mean length
/// `mean_cycles`, in which j_s (core, pulses and clamp alike) is `js_scale` times larger.
///
/// Realised block-wise: epochs of `mean_cycles * (1 - p)` cycles, each a burst with probability
/// `p` independently of the others, so runs of burst epochs are geometric with the mean length
/// asked for and the regime of a cycle is a hash of (seed, epoch).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bursts {
    /// Fraction of the cycles in a burst (0: no bursts).
    #[serde(default)]
    pub p: f64,
    /// Mean length of a burst, cycles.
    #[serde(default = "d_burst_cycles")]
    pub mean_cycles: f64,
    /// Factor on j_s in a burst.
    #[serde(default = "one")]
    pub js_scale: f64,
}

fn d_burst_cycles() -> f64 {
    1_000.0
}

impl Default for Bursts {
    fn default() -> Self {
        Bursts::NONE
    }
}

/// Salt of the burst regime's hash, apart from the per-cycle stream's.
const BURST_SALT: u64 = 0xb0b5_7e11_a5ed_0001;

impl Bursts {
    /// No bursts: every preset's regime.
    pub const NONE: Bursts = Bursts {
        p: 0.0,
        mean_cycles: 1_000.0,
        js_scale: 1.0,
    };

    /// Whether there are none.
    pub fn is_none(&self) -> bool {
        self.p <= 0.0 || self.js_scale == 1.0
    }

    /// Length of an epoch, cycles: a run of burst epochs is geometric with mean `1 / (1 - p)`
    /// epochs, so that a burst lasts `mean_cycles` on average.
    pub fn epoch_cycles(&self) -> u64 {
        (self.mean_cycles * (1.0 - self.p)).round().max(1.0) as u64
    }

    /// Whether cycle `cycle` of the run seeded `seed` lies in a burst.
    pub fn in_burst(&self, seed: u64, cycle: u64) -> bool {
        if self.is_none() {
            return false;
        }
        let epoch = cycle / self.epoch_cycles();
        unit(splitmix64(
            seed ^ BURST_SALT ^ splitmix64(epoch ^ BURST_SALT),
        )) <= self.p
    }

    /// Checks the numbers; returns the field at fault and why.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(0.0..1.0).contains(&self.p) {
            return Err((
                "p",
                format!("{} is not a fraction of the cycles below 1", self.p),
            ));
        }
        if !(self.mean_cycles.is_finite() && self.mean_cycles >= 1.0) {
            return Err((
                "mean_cycles",
                format!("{} must be a number of cycles >= 1", self.mean_cycles),
            ));
        }
        if !(self.js_scale.is_finite() && self.js_scale > 0.0 && self.js_scale <= 1_000.0) {
            return Err((
                "js_scale",
                format!("{} must be a factor in (0, 1000]", self.js_scale),
            ));
        }
        Ok(())
    }
}

/// The host's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostParams {
    /// Master crystal error, ppm (the master's clock against real time).
    pub master_ppm: f64,
    /// Master crystal wander, ppm per sqrt(s).
    pub master_wander_ppm_per_sqrt_s: f64,
    /// Scheduling and processing jitter j_s.
    pub js: Jitter,
    /// Mean execution time e_m, ns.
    pub em_ns: f64,
    /// Variation of the execution time.
    pub em_jitter: Jitter,
    /// NIC driver jitter j_c.
    pub jc: Jitter,
    /// Mean latency from the send timestamp to the first bit on the wire, ns.
    pub tx_latency_ns: f64,
    /// Latency from the reply's last bit to the receive timestamp, ns.
    pub rx_latency_ns: f64,
    /// Bursty phases of j_s (none by default: the presets have none).
    #[serde(default, skip_serializing_if = "Bursts::is_none")]
    pub bursts: Bursts,
}

impl HostParams {
    /// How much later than its mean plan (`em_ns` and `tx_latency_ns` after the cycle's slot)
    /// a frame reaches the wire, ns, about once in `cycles` cycles: the scheduling jitter j_s
    /// (scaled in bursts, when there are any), the execution time's variation and the NIC's
    /// jitter j_c, each at [`Jitter::latest_in_ns`].
    pub fn latest_send_delay_ns(&self, cycles: f64) -> f64 {
        let burst = if self.bursts.is_none() {
            1.0
        } else {
            self.bursts.js_scale.max(1.0)
        };
        self.js.latest_in_ns(cycles) * burst
            + self.em_jitter.latest_in_ns(cycles)
            + self.jc.latest_in_ns(cycles)
    }

    /// A host preset by name.
    pub fn preset(name: &str) -> Option<HostParams> {
        Some(match name {
            "preempt-rt-stress" => HostParams::preempt_rt_stress(),
            "preempt-rt-idle" => HostParams::preempt_rt_idle(),
            "vanilla-linux" => HostParams::vanilla_linux(),
            "ideal" => HostParams::ideal(),
            _ => return None,
        })
    }

    /// The preset names.
    pub const PRESETS: [&'static str; 4] = [
        "preempt-rt-stress",
        "preempt-rt-idle",
        "vanilla-linux",
        "ideal",
    ];

    /// The letter's testbed: PREEMPT_RT 4.4 on an i3-4170 with an RTL8169 NIC, stress-ng
    /// loading every CPU. Calibrated so that the letter's M-rS standard deviations of `median`
    /// (0.729 us) and `pi-m2s` (2.609 us) come out (see presets/paper-2024.toml for the
    /// reasoning behind every number).
    pub fn preempt_rt_stress() -> HostParams {
        HostParams {
            master_ppm: 13.3,
            master_wander_ppm_per_sqrt_s: 0.005,
            js: Jitter {
                sigma_ns: 16_000.0,
                folded: true,
                tail_p: 0.01,
                tail_mean_ns: 8_000.0,
                tail_sign: 1.0,
                max_abs_ns: 90_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            // The application's work is nearly constant; its variation is in j_s.
            em_ns: 20_000.0,
            em_jitter: Jitter::ZERO,
            jc: Jitter {
                sigma_ns: 430.0,
                folded: false,
                tail_p: 0.011,
                tail_mean_ns: 4_000.0,
                tail_sign: -1.0,
                max_abs_ns: 12_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            tx_latency_ns: 15_000.0,
            rx_latency_ns: 10_000.0,
            bursts: Bursts::NONE,
        }
    }

    /// PREEMPT_RT without load: a few microseconds of scheduling jitter, a quiet NIC.
    pub fn preempt_rt_idle() -> HostParams {
        HostParams {
            js: Jitter {
                sigma_ns: 1_500.0,
                folded: true,
                tail_p: 0.001,
                tail_mean_ns: 3_000.0,
                tail_sign: 1.0,
                max_abs_ns: 30_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            jc: Jitter {
                sigma_ns: 250.0,
                folded: false,
                tail_p: 0.0005,
                tail_mean_ns: 1_500.0,
                tail_sign: -1.0,
                max_abs_ns: 8_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            ..HostParams::preempt_rt_stress()
        }
    }

    /// A stock kernel: tens of microseconds of scheduling jitter with millisecond outliers.
    pub fn vanilla_linux() -> HostParams {
        HostParams {
            js: Jitter {
                sigma_ns: 25_000.0,
                folded: true,
                tail_p: 0.01,
                tail_mean_ns: 120_000.0,
                tail_sign: 1.0,
                max_abs_ns: 900_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            jc: Jitter {
                sigma_ns: 2_000.0,
                folded: false,
                tail_p: 0.005,
                tail_mean_ns: 8_000.0,
                tail_sign: -1.0,
                max_abs_ns: 30_000.0,
                tail_heavy_share: 0.0,
                tail_heavy_mean_ns: 0.0,
            },
            ..HostParams::preempt_rt_stress()
        }
    }

    /// No jitter at all, a perfect crystal: the methods' behaviour on their own.
    pub fn ideal() -> HostParams {
        HostParams {
            master_ppm: 0.0,
            master_wander_ppm_per_sqrt_s: 0.0,
            js: Jitter::ZERO,
            em_ns: 20_000.0,
            em_jitter: Jitter::ZERO,
            jc: Jitter::ZERO,
            tx_latency_ns: 15_000.0,
            rx_latency_ns: 10_000.0,
            bursts: Bursts::NONE,
        }
    }
}

/// The host's noise for one run: the model's, or a recorded trace's replayed in blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct HostNoise {
    params: HostParams,
    seed: u64,
    replay: Option<Arc<Replay>>,
}

/// One cycle's noise, ns.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleNoise {
    /// Scheduling and processing jitter j_s (>= 0).
    pub js_ns: f64,
    /// Execution time e_m (> 0).
    pub em_ns: f64,
    /// NIC latency from the timestamp to the wire, tx latency plus j_c (> 0).
    pub tx_ns: f64,
}

impl HostNoise {
    /// The noise of a run.
    pub fn new(params: HostParams, seed: u64) -> Self {
        HostNoise {
            params,
            seed,
            replay: None,
        }
    }

    /// The noise of a run that replays `replay` (a recorded trace) instead of the model's j_s
    /// and e_m, and its TX delay where the trace has one; `params` gives the rest.
    pub fn replaying(params: HostParams, seed: u64, replay: Option<Arc<Replay>>) -> Self {
        HostNoise {
            params,
            seed,
            replay,
        }
    }

    /// The noise of cycle `cycle`.
    pub fn cycle(&self, cycle: u64) -> CycleNoise {
        let p = &self.params;
        // A generator seeded by (run seed, cycle): the same draws for every method.
        let mut rng = SplitMix64(splitmix64(self.seed ^ splitmix64(cycle)));
        let mut draw = |j: &Jitter| {
            let g = if j.sigma_ns > 0.0 {
                StandardNormal.sample(&mut rng)
            } else {
                0.0
            };
            let a = if j.tail_p > 0.0 {
                unit(rng.next())
            } else {
                1.0
            };
            j.sample(g, a, || unit(rng.next()))
        };
        let mut js = draw(&p.js).max(0.0);
        // The regime is hashed apart from the stream: the draws above are the same either way.
        if p.bursts.in_burst(self.seed, cycle) {
            js *= p.bursts.js_scale;
        }
        let em = (p.em_ns + draw(&p.em_jitter)).max(0.0);
        let jc = draw(&p.jc);
        let mut n = CycleNoise {
            js_ns: js,
            em_ns: em,
            tx_ns: (p.tx_latency_ns + jc).max(1_000.0),
        };
        if let Some(r) = &self.replay {
            let row = r.row(self.seed, cycle);
            n.js_ns = row.wake_latency_ns.max(0.0);
            n.em_ns = row.exec_ns.max(0.0);
            if let Some(tx) = row.tx_delay_ns {
                n.tx_ns = tx.max(1_000.0);
            }
        }
        n
    }

    /// The parameters.
    pub fn params(&self) -> &HostParams {
        &self.params
    }
}

/// One run's noise, drawn once in blocks and handed to every method of the run: the methods
/// see the same noise (common random numbers), so drawing it again for each would only cost
/// time. A block is dropped once all `users` have taken it, so memory stays at a few blocks
/// while the methods of a run advance together (as the comparison's scheduler keeps them).
#[derive(Debug)]
pub struct SharedNoise {
    noise: HostNoise,
    users: u32,
    /// Blocks not yet taken by every user.
    blocks: Mutex<Vec<PendingBlock>>,
}

/// A block of noise: its first cycle, the noise, the users still to take it.
type PendingBlock = (u64, Arc<[CycleNoise]>, u32);

impl SharedNoise {
    /// The noise `noise` for `users` methods.
    pub fn new(noise: HostNoise, users: u32) -> Self {
        SharedNoise {
            noise,
            users: users.max(1),
            blocks: Mutex::new(Vec::new()),
        }
    }

    /// The noise of the run.
    pub fn noise(&self) -> &HostNoise {
        &self.noise
    }

    /// The noise of cycles `first..first + len`; every user takes each block once.
    pub fn block(&self, first: u64, len: u64) -> Arc<[CycleNoise]> {
        let draw =
            || -> Arc<[CycleNoise]> { (first..first + len).map(|i| self.noise.cycle(i)).collect() };
        let Ok(mut blocks) = self.blocks.lock() else {
            return draw();
        };
        if let Some(k) = blocks
            .iter()
            .position(|(f, b, _)| *f == first && b.len() as u64 == len)
        {
            let b = Arc::clone(&blocks[k].1);
            blocks[k].2 -= 1;
            if blocks[k].2 == 0 {
                blocks.swap_remove(k);
            }
            return b;
        }
        let b = draw();
        if self.users > 1 {
            blocks.push((first, Arc::clone(&b), self.users - 1));
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_blocks_are_the_cycles_noise_and_are_dropped_after_the_last_user() {
        let n = HostNoise::new(HostParams::preempt_rt_stress(), 3);
        let shared = SharedNoise::new(n.clone(), 3);
        for _ in 0..3 {
            let b = shared.block(1_000, 50);
            assert_eq!(b.len(), 50);
            for (k, c) in b.iter().enumerate() {
                assert_eq!(*c, n.cycle(1_000 + k as u64));
            }
        }
        assert!(shared.blocks.lock().unwrap().is_empty());
        // A different block is drawn afresh, with the right cycles.
        assert_eq!(shared.block(1_050, 10)[0], n.cycle(1_050));
        assert_eq!(shared.blocks.lock().unwrap().len(), 1);
    }

    #[test]
    fn noise_is_a_function_of_seed_and_cycle() {
        let n = HostNoise::new(HostParams::preempt_rt_stress(), 7);
        let a = n.cycle(123_456);
        let _ = n.cycle(5);
        assert_eq!(n.cycle(123_456), a);
        assert_ne!(
            HostNoise::new(HostParams::preempt_rt_stress(), 8).cycle(123_456),
            a
        );
    }

    #[test]
    fn distributions_have_the_configured_moments() {
        let p = HostParams {
            jc: Jitter {
                sigma_ns: 500.0,
                ..Jitter::ZERO
            },
            js: Jitter {
                sigma_ns: 1_000.0,
                folded: true,
                ..Jitter::ZERO
            },
            ..HostParams::ideal()
        };
        let n = HostNoise::new(p, 1);
        let k = 200_000;
        let (mut s, mut s2, mut js) = (0.0, 0.0, 0.0);
        for i in 0..k {
            let c = n.cycle(i);
            let jc = c.tx_ns - p.tx_latency_ns;
            s += jc;
            s2 += jc * jc;
            js += c.js_ns;
        }
        let mean = s / k as f64;
        let std = (s2 / k as f64 - mean * mean).sqrt();
        assert!(mean.abs() < 5.0, "{mean}");
        assert!((std - 500.0).abs() < 5.0, "{std}");
        // E|N(0, s)| = s sqrt(2/pi).
        let m = js / k as f64;
        assert!(
            (m - 1_000.0 * (2.0 / std::f64::consts::PI).sqrt()).abs() < 8.0,
            "{m}"
        );
    }

    #[test]
    fn pulses_go_the_configured_way() {
        let j = Jitter {
            sigma_ns: 0.0,
            folded: false,
            tail_p: 1.0,
            tail_mean_ns: 100.0,
            tail_sign: -1.0,
            max_abs_ns: 1e9,
            tail_heavy_share: 0.0,
            tail_heavy_mean_ns: 0.0,
        };
        assert!(j.sample(0.3, 0.0, || 0.5) < 0.0);
    }
}
