//! Datagram processing (ESC datasheet section I, "EtherCAT datagram" and "Working counter"):
//! the address modes, the commands' read and write halves and the working counter rules, one
//! datagram at a time. This is the plain path: every datagram decoded in full. The fast path
//! ([`super::fast`]) runs frames through it and records what it did.
//!
//! Headers are read through the wire crate's [`Datagram`] and [`EcatFrame`] views.

use super::Esc;
use ecsync_wire::register::{self as reg, features};
use ecsync_wire::{AddressMode, Command, Datagram, EcatFrame};

/// Side effects of processing one datagram that the segment must act on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DatagramEffects {
    /// Latch receive times of this frame (a write to 0x0900).
    pub latch_receive_times: bool,
    /// Loop settings changed (DL control written).
    pub loops_changed: bool,
}

impl DatagramEffects {
    /// Both effects: what a frame's datagrams ask of the segment together.
    pub(super) fn merge(&mut self, other: DatagramEffects) {
        self.latch_receive_times |= other.latch_receive_times;
        self.loops_changed |= other.loops_changed;
    }
}

impl Esc {
    /// Processes one datagram as it passes the processing unit in a frame whose first bit
    /// reached the unit at `t_ps`. `dg` is the whole datagram (header, data, working counter);
    /// its length must already have been validated.
    pub fn process_datagram(&mut self, dg: &mut [u8], t_ps: u64) -> DatagramEffects {
        let fx = self.datagram_in_frame(dg, t_ps);
        self.end_of_frame(t_ps);
        fx
    }

    /// One datagram of a frame: what the frame's end does (the outputs taken, the SYNC0
    /// deadline) is left to [`Esc::end_of_frame`].
    pub(super) fn datagram_in_frame(&mut self, dg: &mut [u8], t_ps: u64) -> DatagramEffects {
        self.watchdog_check(t_ps);
        let fx = self.process_datagram_at(dg, t_ps);
        if std::mem::take(&mut self.pd_written) {
            self.outputs_written(t_ps);
        }
        fx
    }

    fn process_datagram_at(&mut self, dg: &mut [u8], t_ps: u64) -> DatagramEffects {
        let mut fx = DatagramEffects::default();
        let mut d = Datagram::new_unchecked(dg);
        let Ok(cmd) = d.command() else {
            return fx;
        };
        let (adp, ado) = (d.adp(), d.ado());
        let inc = match cmd.address_mode() {
            AddressMode::None => 0,
            AddressMode::Position | AddressMode::Broadcast => {
                // Every slave increments the position on the way.
                d.set_adp(adp.wrapping_add(1));
                let broadcast = cmd.address_mode() == AddressMode::Broadcast;
                self.position_addressed(cmd, adp, broadcast, ado, d.data_mut(), t_ps, &mut fx)
            }
            AddressMode::Configured => {
                let me = adp == self.station_address()
                    || (self.alias_enabled() && adp == self.get_u16(reg::STATION_ALIAS));
                self.station_addressed(cmd, me, ado, d.data_mut(), t_ps, &mut fx)
            }
            AddressMode::Logical => {
                let unsupported =
                    cmd == Command::Lrw && self.model.features() & features::NO_LRW != 0;
                if unsupported {
                    0
                } else {
                    let laddr = d.address_raw();
                    self.logical(cmd, laddr, d.data_mut())
                }
            }
        };
        if inc > 0 {
            self.stats.datagrams_counted += 1;
            d.set_wkc(d.wkc().wrapping_add(inc));
        }
        fx
    }

    /// An auto-increment or broadcast datagram: the working counter increment. `adp` is the
    /// position as the datagram arrived (0 at the addressed slave).
    #[allow(clippy::too_many_arguments)]
    fn position_addressed(
        &mut self,
        cmd: Command,
        adp: u16,
        broadcast: bool,
        ado: u16,
        data: &mut [u8],
        t_ps: u64,
        fx: &mut DatagramEffects,
    ) -> u16 {
        match cmd {
            // Read at the addressed slave, write at every other one.
            Command::Armw if adp == 0 => u16::from(self.read_physical(ado, data, false, t_ps)),
            Command::Armw => u16::from(self.write_physical(ado, data, t_ps, fx)),
            _ if broadcast || adp == 0 => self.physical(cmd, ado, data, t_ps, fx),
            _ => 0,
        }
    }

    /// A configured-address datagram (`me`: it names this station): the working counter
    /// increment.
    fn station_addressed(
        &mut self,
        cmd: Command,
        me: bool,
        ado: u16,
        data: &mut [u8],
        t_ps: u64,
        fx: &mut DatagramEffects,
    ) -> u16 {
        match cmd {
            // Read at the addressed slave, write at every other one.
            Command::Frmw if me => u16::from(self.read_physical(ado, data, false, t_ps)),
            Command::Frmw => u16::from(self.write_physical(ado, data, t_ps, fx)),
            _ if me => self.physical(cmd, ado, data, t_ps, fx),
            _ => 0,
        }
    }

    /// Register access of an addressed APxx/FPxx/Bxx datagram. Read-write commands read before
    /// they write (the datagram returns the old memory); the write address is shifted by the
    /// physical R/W offset 0x0108.
    fn physical(
        &mut self,
        cmd: Command,
        ado: u16,
        data: &mut [u8],
        t_ps: u64,
        fx: &mut DatagramEffects,
    ) -> u16 {
        let or = cmd == Command::Brd || cmd == Command::Brw;
        match (cmd.reads(), cmd.writes()) {
            (true, false) => u16::from(self.read_physical(ado, data, or, t_ps)),
            (false, true) => u16::from(self.write_physical(ado, data, t_ps, fx)),
            (true, true) => {
                self.rec.uncacheable();
                // Keep the incoming data for the write; the read replaces the datagram's data.
                // A stack buffer keeps this allocation-free for register-sized accesses.
                let mut buf = [0u8; ecsync_wire::MAX_DATAGRAM_DATA];
                let incoming = &mut buf[..data.len()];
                incoming.copy_from_slice(data);
                let r = self.read_physical(ado, data, or, t_ps);
                let offset = self.get_u16(0x0108);
                let w = self.write_physical(ado.wrapping_add(offset), incoming, t_ps, fx);
                u16::from(r) + 2 * u16::from(w)
            }
            (false, false) => 0,
        }
    }

    /// Processes the datagram chain of a frame already validated, at a frame offset list too
    /// long to pass (never recorded).
    pub(crate) fn process_chain(&mut self, frame: &mut [u8], t_ps: u64) -> DatagramEffects {
        let mut out = DatagramEffects::default();
        let Ok(f) = EcatFrame::new_checked(&frame[..]) else {
            return out;
        };
        let mut at = EcatFrame::<&[u8]>::first_datagram_offset();
        let end = at + f.ecat_len();
        while let Ok(d) = Datagram::new_checked(&frame[at..end]) {
            let (total, more) = (d.total_len(), d.more_follows());
            out.merge(self.datagram_in_frame(&mut frame[at..at + total], t_ps));
            at += total;
            if !more {
                break;
            }
        }
        self.end_of_frame(t_ps + crate::phy::frame_wire_time_ps(frame.len()));
        out
    }
}
