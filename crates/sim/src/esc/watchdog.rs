//! The process data watchdog (ESC datasheet section II, 0x0400-0x0443; ETG.1000.6 on its
//! expiry): a SyncManager whose control byte has the watchdog trigger (bit 6, the outputs')
//! restarts it with every write of its buffer; if no write comes for the watchdog time, it
//! expires: 0x0440 bit 0 reads 0, the counter 0x0442 counts it, and the application leaves OP
//! for SAFE-OP with AL status code 0x001B (SyncManager watchdog), as drives do.
//!
//! Time: 0x0400 is the divider, one watchdog tick every (divider + 2) x 40 ns (reset value
//! 0x09C2: 100 us); 0x0420 the process data watchdog time in ticks (reset value 0x03E8: 100 ms);
//! 0 switches it off.

use super::Esc;
use ecsync_wire::register as reg;
use ecsync_wire::{AlState, AlStatusCode};

/// Watchdog divider (0x0400) at reset.
pub const WATCHDOG_DIVIDER_RESET: u16 = 0x09c2;
/// PDI watchdog time (0x0410) at reset.
pub const PDI_WATCHDOG_RESET: u16 = 0x03e8;
/// Process data watchdog time (0x0420) at reset.
pub const PD_WATCHDOG_RESET: u16 = 0x03e8;
/// SyncManager control bit 6: accesses trigger the watchdog.
const SM_WATCHDOG_TRIGGER: u8 = 0x40;

impl Esc {
    /// The watchdog's time from the registers, ps: (divider + 2) x 40 ns per tick.
    pub fn process_data_watchdog_ps(&self) -> u64 {
        let div = u64::from(self.get_u16(0x0400));
        let ticks = u64::from(self.get_u16(0x0420));
        (div + 2) * 40_000 * ticks
    }

    /// Arms the watchdog in OP when the output SyncManager triggers it (at `t_ps`, the time of
    /// the change), or disarms it.
    pub(super) fn update_watchdog(&mut self, t_ps: u64) {
        let triggered = self.output_sm.is_some_and(|i| {
            let base = usize::from(reg::sync_manager_address(i as u8));
            self.regs[base + 4] & SM_WATCHDOG_TRIGGER != 0
        });
        let period = if self.al_state == AlState::Op && triggered {
            self.process_data_watchdog_ps()
        } else {
            0
        };
        if period != 0 && self.wd_period_ps == 0 {
            // Armed from now: running, not expired.
            self.wd_last_write_ps = t_ps;
            self.regs[0x0440] |= 0x01;
        }
        self.wd_period_ps = period;
    }

    /// The outputs were written at `t_ps`: the watchdog starts again.
    #[inline(always)]
    pub(super) fn outputs_written(&mut self, t_ps: u64) {
        self.wd_last_write_ps = t_ps;
        self.sync_pending = true;
    }

    /// Whether the watchdog expired before `t_ps` (and, if so, what it does).
    #[inline(always)]
    pub(super) fn watchdog_check(&mut self, t_ps: u64) -> bool {
        if self.wd_period_ps != 0 && t_ps > self.wd_last_write_ps.saturating_add(self.wd_period_ps)
        {
            self.watchdog_expired();
            return true;
        }
        false
    }

    /// Plays the process data watchdog's expiry by the clock, between frames: when no write
    /// of the outputs came for its time before `t_ps`, the drive leaves OP now (as a real one
    /// does 100 ms after its master stopped), not only when the next frame finds it expired.
    /// Whether it expired.
    pub fn expire_watchdog(&mut self, t_ps: u64) -> bool {
        self.watchdog_check(t_ps)
    }

    #[inline(never)]
    fn watchdog_expired(&mut self) {
        // In OP on its DC signal the drive counted every pulse without outputs up to the
        // expiry (found only now, with the next frame): counted so before it leaves OP.
        let expiry_ps = self.wd_last_write_ps.saturating_add(self.wd_period_ps);
        self.sync_catch_up(expiry_ps);
        self.wd_period_ps = 0;
        self.regs[0x0440] &= !0x01;
        self.regs[0x0442] = self.regs[0x0442].saturating_add(1);
        if self.al_state == AlState::Op {
            self.raise_al_error(AlStatusCode::SyncManagerWatchdog);
        } else {
            self.generation += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dg, esc, wkc};
    use ecsync_wire::Command;

    fn put(e: &mut super::Esc, ado: u16, data: &[u8], t_ps: u64) -> u16 {
        let mut d = dg(Command::Bwr, 0, ado, data);
        e.process_datagram(&mut d, t_ps);
        wkc(&d)
    }

    fn get(e: &mut super::Esc, ado: u16, n: usize, t_ps: u64) -> Vec<u8> {
        let mut d = dg(Command::Brd, 0, ado, &vec![0; n]);
        e.process_datagram(&mut d, t_ps);
        d[10..10 + n].to_vec()
    }

    #[test]
    fn the_watchdogs_read_their_reset_values() {
        let mut e = esc();
        assert_eq!(get(&mut e, 0x0400, 2, 0), [0xc2, 0x09]);
        assert_eq!(get(&mut e, 0x0410, 2, 0), [0xe8, 0x03]);
        assert_eq!(get(&mut e, 0x0420, 2, 0), [0xe8, 0x03]);
        assert_eq!(get(&mut e, 0x0440, 1, 0), [0x01], "not expired");
    }

    /// A drive in OP with its outputs at 0x1000 (16 bytes, control 0x64: watchdog trigger) and
    /// inputs at 0x1100, as the SII of the mailbox-less drive says.
    fn in_op(e: &mut super::Esc, t_ps: u64) {
        put(e, 0x0120, &[0x02, 0], t_ps);
        put(e, 0x0800, &[0x00, 0x10, 16, 0, 0x64, 0, 1, 0], t_ps);
        put(e, 0x0808, &[0x00, 0x11, 18, 0, 0x20, 0, 1, 0], t_ps);
        put(e, 0x0120, &[0x04, 0], t_ps);
        put(e, 0x0120, &[0x08, 0], t_ps);
        assert_eq!(e.al_state(), ecsync_wire::AlState::Op);
    }

    #[test]
    fn outputs_that_stop_in_op_expire_it_after_the_time_its_registers_give() {
        let mut e = esc();
        // A 20 ms watchdog: divider 2498 (100 us ticks), 200 ticks.
        put(&mut e, 0x0420, &200u16.to_le_bytes(), 0);
        let wd_ps = (0x09c2u64 + 2) * 40_000 * 200;
        assert_eq!(wd_ps, 20_000_000_000);
        in_op(&mut e, 0);
        // Outputs written every millisecond for 50 ms: it holds.
        let mut t = 0;
        for _ in 0..50 {
            t += 1_000_000_000;
            assert_eq!(put(&mut e, 0x1000, &[7; 16], t), 1);
        }
        assert_eq!(e.al_state(), ecsync_wire::AlState::Op);
        let last = t;
        // No outputs: still OP just before the time is up, SAFE-OP with 0x001B just after.
        assert_eq!(get(&mut e, 0x0130, 2, last + wd_ps - 1_000)[0], 0x08);
        assert_eq!(get(&mut e, 0x0440, 1, last + wd_ps - 1_000), [0x01]);
        let st = get(&mut e, 0x0130, 6, last + wd_ps + 1_000);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x001b));
        assert_eq!(
            get(&mut e, 0x0440, 1, last + wd_ps + 2_000),
            [0x00],
            "expired"
        );
        assert_eq!(
            get(&mut e, 0x0442, 1, last + wd_ps + 2_000),
            [0x01],
            "counted"
        );
        // Outputs are not taken in SAFE-OP.
        assert_eq!(put(&mut e, 0x1000, &[7; 16], last + wd_ps + 3_000), 1);
        // Acknowledged and back to OP, it runs again.
        put(&mut e, 0x0120, &[0x18, 0], last + wd_ps + 4_000);
        eprintln!("{:02x?}", get(&mut e, 0x0130, 6, last + wd_ps + 4_500));
        assert_eq!(e.al_state(), ecsync_wire::AlState::Op);
        assert_eq!(get(&mut e, 0x0440, 1, last + wd_ps + 5_000), [0x01]);
    }

    #[test]
    fn a_watchdog_time_of_zero_switches_it_off() {
        let mut e = esc();
        put(&mut e, 0x0420, &[0, 0], 0);
        in_op(&mut e, 0);
        assert_eq!(
            get(&mut e, 0x0130, 1, 10_000_000_000_000)[0],
            0x08,
            "OP after 10 s"
        );
    }
}
