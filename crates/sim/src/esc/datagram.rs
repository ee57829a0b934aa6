//! Datagram processing (ESC datasheet section I, "EtherCAT datagram" and "Working counter"):
//! the address modes, the commands' read and write halves, the working counter rules, and the
//! recording of what a frame did so that the next frame of the same shape can replay it
//! ([`super::replay`]).
//!
//! Headers are read through the wire crate's [`Datagram`] and [`EcatFrame`] views.

use super::Esc;
use super::replay::{MAX_PROGRAM_DATAGRAMS, Op, Program};
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
    fn merge(&mut self, other: DatagramEffects) {
        self.latch_receive_times |= other.latch_receive_times;
        self.loops_changed |= other.loops_changed;
    }
}

/// What one datagram did at this ESC, recorded so that the same frame shape can replay it while
/// the ESC's configuration is unchanged (the cyclic frame is the same every cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum Act {
    /// Nothing beyond the address and working counter updates.
    #[default]
    None,
    /// System time read (0x0910) into the data, ORed for broadcast reads.
    SysTimeRead { or: bool },
    /// System time write (0x0910): the time control loop compares.
    SysTimeWrite,
    /// System time difference read (0x092C).
    DiffRead { or: bool },
    /// Logical access: the recorder's logical ops.
    Logical,
}

/// One step of a logical access.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum LogicalOp {
    /// Datagram data -> process RAM.
    #[default]
    Refresh,
    Write {
        data_off: u16,
        ram_off: u16,
        len: u16,
    },
    Read {
        data_off: u16,
        ram_off: u16,
        len: u16,
    },
}

/// Logical ops one datagram may record.
const MAX_LOGICAL_OPS: usize = 8;

/// The recorder for the datagram being processed.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Recorder {
    active: bool,
    pub(super) cacheable: bool,
    pub(super) act: Act,
    ops: [LogicalOp; MAX_LOGICAL_OPS],
    nops: u8,
}

impl Recorder {
    /// A recorder for one datagram; `active` when its ops are wanted.
    fn start(active: bool) -> Self {
        Recorder {
            active,
            cacheable: true,
            ..Recorder::default()
        }
    }

    /// The access cannot be replayed (it depends on or changes more than the recorded ops).
    pub(super) fn uncacheable(&mut self) {
        self.cacheable = false;
    }

    /// Records a step of a logical access.
    pub(super) fn op(&mut self, op: LogicalOp) {
        if !self.active {
            return;
        }
        if usize::from(self.nops) < MAX_LOGICAL_OPS {
            self.ops[usize::from(self.nops)] = op;
            self.nops += 1;
        } else {
            self.cacheable = false;
        }
    }

    fn logical_ops(&self) -> &[LogicalOp] {
        &self.ops[..usize::from(self.nops)]
    }
}

/// Adds to the 16-bit counter at `frame[at..at + 2]` (a working counter or an ADP whose place
/// was recorded from the datagram's header).
#[inline]
pub(super) fn add_u16_at(frame: &mut [u8], at: u16, inc: u16) {
    let at = usize::from(at);
    let w = u16::from_le_bytes([frame[at], frame[at + 1]]).wrapping_add(inc);
    frame[at..at + 2].copy_from_slice(&w.to_le_bytes());
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
    fn datagram_in_frame(&mut self, dg: &mut [u8], t_ps: u64) -> DatagramEffects {
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

    /// Processes the datagrams of a frame (at `offsets`, already validated) as it passes the
    /// processing unit. Frames of the same `shape` (same datagram headers, as the segment
    /// tells; 0 = do not cache) replay what the last one did while nothing in the ESC changed,
    /// instead of decoding every access again: the cyclic frame costs a fraction. The replay is
    /// exact: it was recorded from the full path, and any register write, state change or
    /// uncacheable access invalidates it.
    pub fn process_frame(
        &mut self,
        frame: &mut [u8],
        offsets: &[u16],
        shape: u32,
        t_ps: u64,
    ) -> DatagramEffects {
        self.stats.frames += 1;
        // (An expiry changes the generation: no recorded program holds after it.)
        self.watchdog_check(t_ps);
        if let Some(k) = self.program_slot(shape) {
            self.replay(k, frame, t_ps);
            self.end_of_frame(t_ps + crate::phy::frame_wire_time_ps(frame.len()));
            return DatagramEffects::default();
        }
        let fx = self.process_frame_full(frame, offsets, shape, t_ps);
        self.end_of_frame(t_ps + crate::phy::frame_wire_time_ps(frame.len()));
        fx
    }

    /// Every datagram decoded in full, recording a program for the next frame of this shape.
    /// Out of line: the replay above is the hot path and stays small.
    #[inline(never)]
    fn process_frame_full(
        &mut self,
        frame: &mut [u8],
        offsets: &[u16],
        shape: u32,
        t_ps: u64,
    ) -> DatagramEffects {
        let generation = self.generation;
        let mut prog = Program::new(shape, generation);
        let mut recording = shape != 0 && offsets.len() <= MAX_PROGRAM_DATAGRAMS;
        let mut out = DatagramEffects::default();
        for &at in offsets {
            let at = usize::from(at);
            let (total, wkc_at) = {
                let d = Datagram::new_unchecked(&frame[at..]);
                (d.total_len(), at + d.wkc_offset())
            };
            self.rec = Recorder::start(recording);
            let wkc_before = u16::from_le_bytes([frame[wkc_at], frame[wkc_at + 1]]);
            out.merge(self.datagram_in_frame(&mut frame[at..at + total], t_ps));
            recording = recording
                && self.rec.cacheable
                && self.record(&mut prog, &frame[at..at + total], at, wkc_before);
        }
        self.rec = Recorder::default();
        if recording && self.generation == generation {
            self.install(&prog);
        }
        out
    }

    /// Appends to `prog` what the datagram at frame offset `at` (`dg`, as processed) did, as
    /// the recorder saw it; false if the program is full.
    fn record(&self, prog: &mut Program, dg: &[u8], at: usize, wkc_before: u16) -> bool {
        let d = Datagram::new_unchecked(dg);
        let data = (at + Datagram::<&[u8]>::data_offset()) as u16;
        let mut pushed = true;
        if matches!(
            d.command().map(|c| c.address_mode()),
            Ok(AddressMode::Position | AddressMode::Broadcast)
        ) {
            pushed &= prog.push(Op::AdpInc {
                at: (at + Datagram::<&[u8]>::adp_offset()) as u16,
            });
        }
        // The DC registers read and written fast are 8 bytes at most.
        let len = d.data_len().min(8) as u8;
        match self.rec.act {
            Act::None => {}
            Act::SysTimeRead { or } => pushed &= prog.push(Op::SysRead { at: data, len, or }),
            Act::SysTimeWrite => pushed &= prog.push(Op::SysWrite { at: data, len }),
            Act::DiffRead { or } => pushed &= prog.push(Op::DiffRead { at: data, len, or }),
            Act::Logical => {
                for op in self.rec.logical_ops() {
                    pushed &= prog.push(Op::from_logical(*op, data));
                }
            }
        }
        let inc = d.wkc().wrapping_sub(wkc_before);
        if inc != 0 {
            pushed &= prog.push(Op::Wkc {
                at: (at + d.wkc_offset()) as u16,
                inc,
            });
            prog.counted += 1;
        }
        pushed
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
