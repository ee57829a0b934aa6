//! The master's PTP hardware clock (PHC): the simulator's master clock as its crystal, and
//! the line the gPTP servo steers over the crystal's reading.

use crate::gptp::TimeAwareSystem;
use ecsync_sim::clock::floor_split;
use ecsync_sim::transport::MasterClock;

/// The master's hardware clock: a crystal ([`MasterClock`]: its ppm and wander, real time to
/// crystal nanoseconds and back), and in M3 a rate and phase the gPTP servo sets over the
/// crystal's reading: `value = anchor_value + (crystal - anchor_crystal) * (1 + freq)`.
///
/// The crystal's arithmetic is the master clock's; what the PHC adds is the servo's line,
/// which a [`MasterClock`] does not have (no control loop steers the simulator's master). gPTP
/// stamps its messages with the crystal (the free-running timestamper), the EtherCAT master
/// reads the steered value.
#[derive(Debug, Clone)]
pub struct Phc {
    crystal: MasterClock,
    anchor_crystal_ns: u64,
    anchor_value_ns: u64,
    anchor_frac_ns: f64,
    freq: f64,
}

impl Phc {
    /// A clock that reads what its crystal reads, at the crystal's rate, from the crystal's
    /// reading `crystal_ns` on.
    pub fn new(crystal: MasterClock, crystal_ns: u64) -> Self {
        Phc {
            crystal,
            anchor_crystal_ns: crystal_ns,
            anchor_value_ns: crystal_ns,
            anchor_frac_ns: 0.0,
            freq: 0.0,
        }
    }

    /// The crystal's reading at real time `t_ps`, ns (the free-running clock gPTP stamps
    /// with).
    pub fn crystal_ns(&mut self, t_ps: u64) -> u64 {
        self.crystal.master_ns(t_ps)
    }

    /// The clock's reading when the crystal reads `crystal_ns`: whole ns and fraction.
    pub fn at_crystal(&self, crystal_ns: u64) -> (u64, f64) {
        // Signed: a crystal reading before the anchor reads back along the same line.
        let d = (crystal_ns.wrapping_sub(self.anchor_crystal_ns) as i64) as f64;
        let v = d * (1.0 + self.freq) + self.anchor_frac_ns;
        let (whole, floor) = floor_split(v);
        (self.anchor_value_ns.wrapping_add(whole as u64), v - floor)
    }

    /// The clock's reading at real time `t_ps`: whole ns and fraction.
    pub fn exact_at(&mut self, t_ps: u64) -> (u64, f64) {
        let x = self.crystal_ns(t_ps);
        self.at_crystal(x)
    }

    /// The clock's reading at real time `t_ps`, ns.
    pub fn ns_at(&mut self, t_ps: u64) -> u64 {
        self.exact_at(t_ps).0
    }

    /// Real time at which the clock reads `ns`, ps.
    pub fn real_ps_at(&mut self, ns: u64) -> u64 {
        let d = (ns.wrapping_sub(self.anchor_value_ns) as i64) as f64 - self.anchor_frac_ns;
        let x = (d / (1.0 + self.freq)).round();
        self.crystal
            .real_ps_at(self.anchor_crystal_ns.wrapping_add(x as i64 as u64))
    }

    /// From now on reads `value_ns + value_frac_ns` when the crystal reads `at_crystal_ns`, at
    /// `1 + freq` times the crystal's rate.
    pub fn steer(&mut self, at_crystal_ns: u64, value_ns: u64, value_frac_ns: f64, freq: f64) {
        self.anchor_crystal_ns = at_crystal_ns;
        self.anchor_value_ns = value_ns;
        self.anchor_frac_ns = value_frac_ns;
        self.freq = freq;
    }

    /// Applies the servo's decision after a Follow_Up `system` (the master's time-aware
    /// system, stamping with this clock's crystal) received: the clock is re-anchored at the
    /// Sync's arrival with the new rate (and once, the phase step). Whether it was steered.
    pub fn discipline(&mut self, system: &mut TimeAwareSystem) -> bool {
        let Some(rx_ns) = system.last_sync_rx_ns() else {
            return false;
        };
        let (w, f) = self.at_crystal(rx_ns);
        let Some(adj) = system.servo(w, f) else {
            return false;
        };
        // The step is whole and fractional nanoseconds on top of an integer reading.
        let step = f + adj.step_ns;
        let (whole, floor) = floor_split(step);
        self.steer(
            rx_ns,
            w.wrapping_add(whole as u64),
            step - floor,
            adj.frequency,
        );
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecsync_sim::clock::CrystalParams;

    fn phc() -> Phc {
        let crystal = MasterClock::new(CrystalParams {
            ppm: 37.0,
            initial_local_ns: 5_000_000_000,
            ..CrystalParams::default()
        });
        Phc::new(crystal, 5_000_000_000)
    }

    /// Unsteered, the PHC is its crystal.
    #[test]
    fn unsteered_it_reads_its_crystal() {
        let mut p = phc();
        for t_ps in [0, 1_234_567, 9_000_000_000_000] {
            let x = p.crystal_ns(t_ps);
            assert_eq!(p.ns_at(t_ps), x);
        }
    }

    /// Steered, reading and inverting agree within two nanoseconds (the inverse rounds to the
    /// nearest crystal nanosecond, and reading floors the crystal and the line); the fraction
    /// stays in [0, 1).
    #[test]
    fn steered_it_inverts_its_reading() {
        let mut p = phc();
        let x = p.crystal_ns(1_000_000_000_000);
        p.steer(x, x + 123_456, 0.75, -21e-6);
        for t_ps in [1_000_000_000_000u64, 1_500_000_000_123, 7_000_000_000_000] {
            let (w, f) = p.exact_at(t_ps);
            assert!((0.0..1.0).contains(&f));
            let back = p.real_ps_at(w);
            let again = p.ns_at(back);
            assert!(again.abs_diff(w) <= 2, "{w} {again}");
        }
    }
}
