//! How the master host puts its cyclic frame on the wire: the send modes the comparison runs
//! every method with.
//!
//! * `plain`: as the letter's testbed does: the task wakes at the cycle start (late by j_s),
//!   works for e_m, takes the send timestamp t_ms and hands the frame to the driver, which puts
//!   it on the wire tx latency + j_c later. Neither j_s nor j_c can be filtered out by a method:
//!   they happen after its decision.
//! * `spin`: the task wakes `spin_margin_ns` early, works, then busy-waits on the clock up to
//!   the exact send instant. j_s and e_m vanish as long as they fit in the margin (beyond it the
//!   frame is late by what is left); the residual is the clock read's granularity; j_c stays.
//!   The price is the CPU time spun, reported per cycle.
//! * `txtime`: the task wakes `txtime_lead_ns` early, works and hands the frame over with its
//!   launch time (SO_TXTIME with the ETF qdisc and the NIC's launch-time offload): the frame
//!   leaves at the launch time plus the NIC's launch jitter, and t_ms is the launch time. A
//!   frame handed over after its launch time less the qdisc's delta is dropped (ETF's
//!   deadline miss, read back from the socket's error queue) and counted.
//! * `hwstamp`: sent as `plain`, but the NIC stamps the frame in hardware as its first bit
//!   leaves, and a master-shift method takes that stamp (mapped to the host's clock, within
//!   `hw_stamp_error_ns`) as its t_ms: the stack's latency and j_c leave the method's
//!   measurement. The frame still leaves when j_s lets it: what the mode buys is a truer
//!   measurement, not a truer send. Bus-shift methods write their send time into the frame
//!   before it leaves and have no such column.
//!
//! Every draw is a pure function of (seed, cycle), like the host's own noise: every method and
//! mode of a run sees the same host.

use crate::host::CycleNoise;
use crate::rng::{SplitMix64, splitmix64};
use crate::transport::HostDelays;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

pub use ecsync_master::transport::SendMode;

/// One column of a comparison: a method and the send mode it runs with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Entry {
    /// The method.
    pub kind: ecsync_dc::MethodKind,
    /// How the host sends its frames.
    pub send: SendMode,
}

impl Entry {
    /// The name reports give it: the method's (`plain`, the letter's way), else
    /// `<method>+<mode>`.
    pub fn name(&self) -> String {
        match self.send {
            SendMode::Plain => self.kind.name().to_string(),
            m => format!("{}+{m}", self.kind.name()),
        }
    }
}

/// The send modes' parameters (the scenario's `[send]` table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SendParams {
    /// `spin`: how early the task wakes before the send instant, ns.
    pub spin_margin_ns: f64,
    /// `spin`: the busy-wait's residual: the send instant is late by up to this (uniform),
    /// one read of the clock and the loop around it, ns.
    pub spin_residual_ns: f64,
    /// `txtime`: how early the task hands the frame over, ns.
    pub txtime_lead_ns: f64,
    /// `txtime`: the ETF qdisc's delta: a frame must be handed over this long before its
    /// launch time, ns.
    pub txtime_delta_ns: f64,
    /// `txtime`: the NIC's launch jitter (standard deviation), ns.
    pub launch_jitter_ns: f64,
    /// `txtime`: from the launch time to the first bit on the wire, ns.
    pub launch_to_wire_ns: f64,
    /// `hwstamp`: the hardware transmit stamp's error against the first bit's true time on the
    /// master's clock (standard deviation), ns: the PHC's resolution and its mapping to the
    /// host clock.
    pub hw_stamp_error_ns: f64,
}

impl Default for SendParams {
    fn default() -> Self {
        SendParams {
            spin_margin_ns: 50_000.0,
            spin_residual_ns: 100.0,
            txtime_lead_ns: 100_000.0,
            txtime_delta_ns: 10_000.0,
            launch_jitter_ns: 50.0,
            launch_to_wire_ns: 1_000.0,
            hw_stamp_error_ns: 20.0,
        }
    }
}

impl SendParams {
    /// Checks the numbers the modes `modes` use (another mode's are not read); the field at
    /// fault and why.
    pub fn validate(
        &self,
        cycle_ns: u32,
        modes: &[SendMode],
    ) -> Result<(), (&'static str, String)> {
        let spin = modes.contains(&SendMode::Spin);
        let txtime = modes.contains(&SendMode::Txtime);
        for (f, v) in [
            ("spin_margin_ns", self.spin_margin_ns),
            ("spin_residual_ns", self.spin_residual_ns),
            ("txtime_lead_ns", self.txtime_lead_ns),
            ("txtime_delta_ns", self.txtime_delta_ns),
            ("launch_jitter_ns", self.launch_jitter_ns),
            ("launch_to_wire_ns", self.launch_to_wire_ns),
            ("hw_stamp_error_ns", self.hw_stamp_error_ns),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((f, format!("{v} must be a finite number >= 0")));
            }
        }
        for (f, v, used) in [
            ("spin_margin_ns", self.spin_margin_ns, spin),
            ("txtime_lead_ns", self.txtime_lead_ns, txtime),
        ] {
            if used && v >= f64::from(cycle_ns) {
                return Err((
                    f,
                    format!(
                        "{} us is not shorter than the {} us cycle",
                        v / 1e3,
                        f64::from(cycle_ns) / 1e3
                    ),
                ));
            }
        }
        if txtime && self.txtime_delta_ns > self.txtime_lead_ns {
            return Err((
                "txtime_delta_ns",
                format!(
                    "{} us is more than the lead of {} us: every frame would miss its launch time",
                    self.txtime_delta_ns / 1e3,
                    self.txtime_lead_ns / 1e3
                ),
            ));
        }
        Ok(())
    }
}

/// What one cycle's send costs and does under a mode, beyond the host's delays.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SendOutcome {
    /// The delays the simulated transport applies.
    pub delays: HostDelays,
    /// CPU time spent busy-waiting, ns.
    pub spin_ns: f64,
}

/// The cycle's send under `mode`, from the host's noise `n` of cycle `cycle` (run seed `seed`).
pub fn apply(mode: SendMode, p: &SendParams, n: CycleNoise, seed: u64, cycle: u64) -> SendOutcome {
    let work = n.js_ns + n.em_ns;
    match mode {
        SendMode::Plain => SendOutcome {
            delays: HostDelays {
                wake_to_send_ns: work,
                tx_ns: n.tx_ns,
                dropped: false,
                tx_stamp_error_ns: None,
            },
            spin_ns: 0.0,
        },
        SendMode::Hwstamp => {
            let mut rng = SplitMix64(splitmix64(seed ^ 0x4857_5354 ^ splitmix64(cycle)));
            let g: f64 = StandardNormal.sample(&mut rng);
            SendOutcome {
                delays: HostDelays {
                    wake_to_send_ns: work,
                    tx_ns: n.tx_ns,
                    dropped: false,
                    tx_stamp_error_ns: Some(g * p.hw_stamp_error_ns),
                },
                spin_ns: 0.0,
            }
        }
        SendMode::Spin => {
            // Woken `margin` early: what the work leaves of the margin is spun away.
            let late = (work - p.spin_margin_ns).max(0.0);
            let mut rng = SplitMix64(splitmix64(seed ^ 0x5350_494e ^ splitmix64(cycle)));
            let residual = p.spin_residual_ns * crate::rng::unit_from_bits(rng.next());
            SendOutcome {
                delays: HostDelays {
                    wake_to_send_ns: late + residual,
                    tx_ns: n.tx_ns,
                    dropped: false,
                    tx_stamp_error_ns: None,
                },
                spin_ns: (p.spin_margin_ns - work).max(0.0) + residual,
            }
        }
        SendMode::Txtime => {
            // Handed over at lead - work before the launch time; too late for the qdisc's
            // delta and it is dropped.
            let dropped = work > p.txtime_lead_ns - p.txtime_delta_ns;
            let mut rng = SplitMix64(splitmix64(seed ^ 0x5458_5449 ^ splitmix64(cycle)));
            let g: f64 = StandardNormal.sample(&mut rng);
            SendOutcome {
                delays: HostDelays {
                    // t_ms is the launch time itself.
                    wake_to_send_ns: 0.0,
                    tx_ns: (p.launch_to_wire_ns + g * p.launch_jitter_ns).max(0.0),
                    dropped,
                    tx_stamp_error_ns: None,
                },
                spin_ns: 0.0,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(js_ns: f64) -> CycleNoise {
        CycleNoise {
            js_ns,
            em_ns: 20_000.0,
            tx_ns: 7_000.0,
        }
    }

    #[test]
    fn plain_is_the_hosts_noise_unchanged() {
        let o = apply(
            SendMode::Plain,
            &SendParams::default(),
            noise(5_000.0),
            1,
            2,
        );
        assert_eq!(o.delays.wake_to_send_ns, 25_000.0);
        assert_eq!(o.delays.tx_ns, 7_000.0);
        assert!(!o.delays.dropped);
    }

    #[test]
    fn spin_takes_out_what_fits_in_the_margin_and_costs_the_rest_of_it() {
        let p = SendParams::default();
        // 25 us of work in a 50 us margin: on time (but for the residual), 25 us spun.
        let o = apply(SendMode::Spin, &p, noise(5_000.0), 1, 2);
        assert!(o.delays.wake_to_send_ns <= p.spin_residual_ns);
        assert!((o.spin_ns - 25_000.0 - o.delays.wake_to_send_ns).abs() < 1e-9);
        // 60 us of work: 10 us late, nothing spun but the residual; j_c stays.
        let o = apply(SendMode::Spin, &p, noise(40_000.0), 1, 2);
        assert!((o.delays.wake_to_send_ns - 10_000.0).abs() <= p.spin_residual_ns);
        assert_eq!(o.delays.tx_ns, 7_000.0);
    }

    #[test]
    fn txtime_sends_at_the_launch_time_and_drops_what_comes_too_late() {
        let p = SendParams::default();
        let o = apply(SendMode::Txtime, &p, noise(5_000.0), 1, 2);
        assert_eq!(o.delays.wake_to_send_ns, 0.0);
        assert!(!o.delays.dropped);
        // 95 us of work against 100 us of lead less 10 us of delta: missed.
        let o = apply(SendMode::Txtime, &p, noise(75_000.0), 1, 2);
        assert!(o.delays.dropped);
        // The launch jitter has the configured spread (independent truth: the parameter).
        let xs: Vec<f64> = (0..20_000)
            .map(|c| apply(SendMode::Txtime, &p, noise(0.0), 9, c).delays.tx_ns)
            .collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let sd = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64).sqrt();
        assert!((mean - 1_000.0).abs() < 2.0, "{mean}");
        assert!((sd - 50.0).abs() < 2.0, "{sd}");
    }

    #[test]
    fn hwstamp_sends_as_plain_and_stamps_within_its_error() {
        let p = SendParams::default();
        let plain = apply(SendMode::Plain, &p, noise(5_000.0), 1, 2);
        let hw = apply(SendMode::Hwstamp, &p, noise(5_000.0), 1, 2);
        assert_eq!(hw.delays.wake_to_send_ns, plain.delays.wake_to_send_ns);
        assert_eq!(hw.delays.tx_ns, plain.delays.tx_ns);
        assert_eq!(plain.delays.tx_stamp_error_ns, None);
        let xs: Vec<f64> = (0..20_000)
            .map(|c| {
                apply(SendMode::Hwstamp, &p, noise(0.0), 9, c)
                    .delays
                    .tx_stamp_error_ns
                    .unwrap()
            })
            .collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let sd = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64).sqrt();
        assert!(mean.abs() < 1.0, "{mean}");
        assert!((sd - 20.0).abs() < 1.0, "{sd}");
        assert!(SendMode::Hwstamp.applies_to(ecsync_dc::MethodKind::MedianFit));
        assert!(!SendMode::Hwstamp.applies_to(ecsync_dc::MethodKind::BusShift));
        assert!(SendMode::Txtime.applies_to(ecsync_dc::MethodKind::BusShift));
    }

    #[test]
    fn names_round_trip() {
        for m in SendMode::ALL {
            assert_eq!(m.name().parse::<SendMode>(), Ok(m));
        }
        assert!("etf".parse::<SendMode>().is_err());
    }
}
