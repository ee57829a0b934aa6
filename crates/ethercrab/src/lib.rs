//! ecsync's master synchronization methods in [ethercrab]'s cyclic loop.
//!
//! ethercrab's `SubDeviceGroup::tx_rx_dc` returns the reference clock's system time and a
//! `next_cycle_wait` that snaps the next cycle onto the reference's grid: every cycle, with gain
//! 1 and no filter, so the host's scheduling jitter goes straight into the cycle start. [`DcLoop`]
//! replaces that wait with any ecsync [`MasterSync`] method of the master-shift kind; with
//! [`MedianSync`] it is the median-filter drift compensator of Xu et al. (2024), which keeps the
//! frames at a fixed phase of the DC grid while decoupling the jitter.
//!
//! [`DcLoop`] needs no network of its own: it takes what `tx_rx_dc` returned. Here two cycles are
//! fed by hand, the reference's grid 300 us behind the frame's arrival each time:
//!
//! ```
//! use ecsync_ethercrab::{DcLoop, MedianSync};
//! use ethercrab::subdevice_group::CycleInfo;
//! use std::time::{Duration, Instant};
//!
//! let period = Duration::from_millis(1);
//! let mut sync = DcLoop::new(MedianSync::new(11, 0.01, 1000), period).unwrap();
//! let info = |dc_system_time| CycleInfo {
//!     dc_system_time,
//!     cycle_start_offset: Duration::from_micros(300),
//!     next_cycle_wait: Duration::from_micros(700),
//! };
//! let close = |a: Duration, b: Duration| a.abs_diff(b) < Duration::from_micros(1);
//!
//! // The first cycle primes the loop: the next starts where ethercrab's own wait puts it.
//! let sent = Instant::now();
//! let next = sync.update(sent, sent + Duration::from_micros(50), &info(1_000_000_300_000));
//! assert!(close(next - sent, Duration::from_micros(700)));
//! assert_eq!(sync.cycles(), 0);
//!
//! // While the median method initialises (its first 1000 frames) it keeps the nominal period.
//! let after = sync.update(next, next + Duration::from_micros(50), &info(1_000_001_300_000));
//! assert!(close(after - next, period));
//! assert_eq!(sync.cycles(), 1);
//!
//! // Bus shift writes to the reference, which `tx_rx_dc` cannot: refused, IgH's way too.
//! assert!(DcLoop::new(ecsync_dc::BusShift::default(), period).is_err());
//! let igh = ecsync_dc::IghAppTime::new(2, ecsync_dc::masters::AppTime::Send);
//! assert!(DcLoop::new(igh, period).is_err());
//!
//! // Every master-shift method of the registry drives the loop: KickCAT's soft PLL, say, or
//! // the Kalman filter (any of them built by name from its parameters).
//! use ecsync_dc::{MethodContext, MethodKind, MethodParams};
//! let ctx = MethodContext { cycle_ns: 1_000_000, target_phase_ns: 0 };
//! for kind in MethodKind::ALL.into_iter().filter(|k| k.is_master_shift()) {
//!     assert!(DcLoop::new(MethodParams::default().build(kind, &ctx), period).is_ok());
//! }
//! ```
//!
//! In ethercrab's cyclic loop (needs a network interface and EtherCAT slaves):
//!
//! ```no_run
//! # async fn cycle<const N: usize, const P: usize>(
//! #     group: &ethercrab::SubDeviceGroup<
//! #         N,
//! #         P,
//! #         ethercrab::DefaultLock,
//! #         ethercrab::subdevice_group::Op,
//! #         ethercrab::subdevice_group::HasDc,
//! #     >,
//! #     maindevice: &ethercrab::MainDevice<'_>,
//! # ) -> Result<(), ethercrab::error::Error> {
//! use ecsync_ethercrab::{DcLoop, MedianSync};
//! use std::time::{Duration, Instant};
//!
//! // The letter's parameters: window 11, gain 0.01; h_mr averaged over the first second.
//! let mut sync = DcLoop::new(MedianSync::new(11, 0.01, 1000), Duration::from_millis(1))
//!     .expect("a master-shift method");
//! loop {
//!     let sent = Instant::now(); // t_ms: right before the frame goes out
//!     let r = group.tx_rx_dc(maindevice).await?;
//!     let next = sync.update(sent, Instant::now(), &r.extra);
//!     // ... process data ...
//!     async_io::Timer::at(next).await;
//! }
//! # }
//! ```
//!
//! Bus shift (the master's time written to the reference every cycle) needs a write in the
//! cyclic frame that `tx_rx_dc` does not send; [`DcLoop::new`] refuses it.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub use ecsync_dc::sync::{CycleInput, CycleOutput, MasterSync};
use ecsync_dc::time::{MasterInstant, SystemTime};
pub use ecsync_dc::{
    Des, Kalman, KickcatPll, LinuxcncPll, MedianFit, MedianSync, PiM2s, Snap, SoemPi,
};
use ethercrab::subdevice_group::CycleInfo;
use std::time::{Duration, Instant};

/// The method given is not a master-shift method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotMasterShift(pub &'static str);

impl std::fmt::Display for NotMasterShift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} moves the reference clock, not the master's cycle: tx_rx_dc sends no write to the reference",
            self.0
        )
    }
}

impl std::error::Error for NotMasterShift {}

/// A master-shift method driving ethercrab's cycle.
#[derive(Debug, Clone)]
pub struct DcLoop<S> {
    sync: S,
    period_ns: u32,
    epoch: Instant,
    /// Nominal start of cycle 0 (master ns since `epoch`), once primed.
    first_ns: Option<u64>,
    cycle: u64,
    scheduled_ns: u64,
    last: CycleOutput,
}

fn ns_since(epoch: Instant, t: Instant) -> u64 {
    u64::try_from(t.saturating_duration_since(epoch).as_nanos()).unwrap_or(u64::MAX)
}

impl<S: MasterSync> DcLoop<S> {
    /// `sync` at cycle time `period` (the SYNC0 period ethercrab's DC configuration uses).
    pub fn new(sync: S, period: Duration) -> Result<Self, NotMasterShift> {
        if !sync.is_master_shift() {
            return Err(NotMasterShift(sync.name()));
        }
        Ok(DcLoop {
            sync,
            period_ns: u32::try_from(period.as_nanos()).unwrap_or(u32::MAX).max(1),
            epoch: Instant::now(),
            first_ns: None,
            cycle: 0,
            scheduled_ns: 0,
            last: CycleOutput::default(),
        })
    }

    /// Feeds one `tx_rx_dc`: `sent` is the instant taken right before the call (the letter's
    /// send timestamp), `received` right after it returned, `info` what it returned. Returns the
    /// instant the next cycle should start.
    ///
    /// The first call only primes the loop: the next cycle starts where ethercrab's own wait puts
    /// it (the grid point plus the configured SYNC0 shift), and the method keeps that phase from
    /// then on.
    pub fn update(&mut self, sent: Instant, received: Instant, info: &CycleInfo) -> Instant {
        let send_ns = ns_since(self.epoch, sent);
        let receive_ns = ns_since(self.epoch, received);
        let Some(first) = self.first_ns else {
            let first = send_ns
                .saturating_add(u64::try_from(info.next_cycle_wait.as_nanos()).unwrap_or(u64::MAX));
            self.first_ns = Some(first);
            self.scheduled_ns = first;
            return self.epoch + Duration::from_nanos(first);
        };
        let input = CycleInput {
            cycle: self.cycle,
            period_ns: self.period_ns,
            nominal_start: MasterInstant::from_ns(
                first.wrapping_add(self.cycle.wrapping_mul(u64::from(self.period_ns))),
            ),
            scheduled_start: MasterInstant::from_ns(self.scheduled_ns),
            send: MasterInstant::from_ns(send_ns),
            receive: MasterInstant::from_ns(receive_ns),
            ref_time: Some(SystemTime::from_ns(info.dc_system_time)),
        };
        self.last = self.sync.update(&input);
        self.cycle += 1;
        // A method may ask for a start already past (after an overrun): start at once.
        self.scheduled_ns = self.last.next_start.as_ns();
        self.epoch + Duration::from_nanos(self.scheduled_ns)
    }

    /// What the method decided in the last cycle (its error and correction, ns).
    pub fn last(&self) -> CycleOutput {
        self.last
    }

    /// Cycles fed after the priming one.
    pub fn cycles(&self) -> u64 {
        self.cycle
    }

    /// The method.
    pub fn method(&self) -> &S {
        &self.sync
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecsync_dc::BusShift;

    /// A reference clock running `ppm` fast against the master's Instant, read when the frame
    /// reaches it `latency_ns` after the send.
    fn info(epoch: Instant, sent: Instant, ppm: f64, latency_ns: u64, period: u64) -> CycleInfo {
        let t = ns_since(epoch, sent) + latency_ns;
        let dc = 1_000_000_000_000 + (t as f64 * (1.0 + ppm * 1e-6)) as u64;
        let phase = dc % period;
        CycleInfo {
            dc_system_time: dc,
            cycle_start_offset: Duration::from_nanos(phase),
            next_cycle_wait: Duration::from_nanos(period - phase),
        }
    }

    #[test]
    fn median_holds_the_phase_of_a_drifting_reference() {
        // The reference runs 50 ppm fast: with a fixed 1 ms period the frames would slip 50 ns
        // per cycle against its grid (100 us over the 2000 cycles). DcLoop with the median method
        // must hold the phase it started with.
        let period = 1_000_000u64;
        let mut l =
            DcLoop::new(MedianSync::new(11, 0.01, 100), Duration::from_nanos(period)).unwrap();
        let epoch = l.epoch;
        let mut sent = epoch + Duration::from_micros(10);
        let mut phases = Vec::new();
        for k in 0..2_000u64 {
            // Send jitter of a few microseconds, deterministic.
            let jitter = Duration::from_nanos(k * 7919 % 5_000);
            let at = sent + jitter;
            let i = info(epoch, at, 50.0, 20_000, period);
            phases.push(i.dc_system_time % period);
            let next = l.update(at, at + Duration::from_micros(60), &i);
            assert!(next > at, "cycle {k}: the next start lies ahead");
            sent = next;
        }
        // After the first 500 cycles the phase stays within a few microseconds of where the
        // loop settled; the 50 ppm slip would have moved it by 75 us by the end.
        let settled = phases[500] as i64;
        for (k, &p) in phases.iter().enumerate().skip(500) {
            let d = p as i64 - settled;
            assert!(d.abs() < 8_000, "cycle {k}: phase moved {d} ns");
        }
        // The method's correction tracks the drift: 50 ns per cycle of the 2000.
        let corr = l.last().correction_ns;
        assert!(
            (corr - 100_000).abs() < 10_000,
            "δ̂ = {corr} ns, the drift was 100 us"
        );
    }

    #[test]
    fn without_the_loop_the_phase_would_slip() {
        // The counter-check of the test above: a fixed period lets the 50 ppm reference slip.
        let period = 1_000_000u64;
        let epoch = Instant::now();
        let first = info(epoch, epoch, 50.0, 20_000, period).dc_system_time % period;
        let last = info(
            epoch,
            epoch + Duration::from_nanos(2_000 * period),
            50.0,
            20_000,
            period,
        )
        .dc_system_time
            % period;
        assert!((last as i64 - first as i64).abs() > 90_000);
    }

    #[test]
    fn bus_shift_is_refused() {
        let e = DcLoop::new(BusShift::default(), Duration::from_millis(1)).unwrap_err();
        assert!(e.to_string().contains("bus-shift"));
    }
}
