//! Process data: the FMMUs that map the logical address space onto the process RAM, the
//! SyncManagers that guard the buffers, logical reads and writes (LRD, LWR, LRW), and the
//! application behind them (a loopback device).
//!
//! The FMMU and SyncManager registers are decoded through the wire crate's views when they are
//! written; the datagram path then works on the decoded copies below.
//!
//! An FMMU maps any physical address, registers included (datasheet section I, "FMMU"): the
//! digital I/O terminals map their outputs onto the digital output register 0x0F00, where a
//! SyncManager is configured too (the EL2828 and EL2889 in ../shared/captures/: FPWR 0x0800 =
//! `00 0f 01 00 44 00 01 00`, FMMU to 0x0F00, every LRW counted). A SyncManager in register
//! space belongs to the digital I/O PDI, which has no firmware to hold it back: its buffer takes
//! writes whenever it is enabled, in any AL state (replay-dc.pcapng, frame 3022: the LRW before
//! SAFE-OP counts 4 at the two terminals). Through an FMMU the model writes only the registers
//! that hold plain data (the digital outputs 0x0F00-0x0F03, the user RAM 0x0F80-0x0FFF) and reads
//! the registers the register file holds as they stand (not the DC block or the EEPROM
//! interface, which it computes on a physical read): no master maps the others.

use super::cia402::{self, DriveMemory, DrivePlan};
use super::recorder::{Act, LogicalOp};
use super::registers::{EXISTS, REG_SPACE, WRITABLE};
use super::{Esc, FMMUS, SMS};
use ecsync_wire::register as reg;
use ecsync_wire::{AlState, Command, FMMU_ENTRY_LEN, Fmmu, SM_ENTRY_LEN, SmDirection, SyncManager};

/// Statusword of the loopback application in OP: ready, switched on, operation enabled.
const STATUS_OP: u16 = 0x1237;
/// Statusword below OP: ready to switch on, voltage enabled.
const STATUS_NOT_OP: u16 = 0x0231;

/// An FMMU as the logical path uses it: a length of 0 when it is inactive.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct FmmuMapping {
    logical: u32,
    len: u16,
    physical: u16,
    read: bool,
    write: bool,
}

/// A SyncManager's buffer.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SmBuffer {
    pub(super) start: u16,
    pub(super) len: u16,
    /// Direction "write": the EtherCAT side writes (outputs).
    pub(super) ecat_writes: bool,
    pub(super) enabled: bool,
    /// Mailbox mode (else buffered: process data).
    pub(super) mailbox: bool,
}

impl SmBuffer {
    fn contains(&self, addr: u16) -> bool {
        addr >= self.start && addr < self.start.saturating_add(self.len)
    }
}

/// The application's buffers in process RAM (see `Esc::app_layout`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct AppLayout {
    ib: usize,
    ob: usize,
    n: usize,
    tail: usize,
    /// A CiA 402 drive's objects where its mapping puts them (else the loopback runs).
    drive: Option<DrivePlan>,
}

/// What the application keeps between cycles.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct AppMemory {
    /// The loopback's cycle counter.
    cycles: u16,
    /// The drive's state and position.
    pub(super) drive: DriveMemory,
}

/// Copies a few dozen bytes without a call into `memcpy`: the process data of one slave in the
/// replayed cyclic frame. Lengths up to 32 bytes take two overlapping word copies (the head and
/// the tail of the range), longer ones `copy_from_slice`.
#[inline]
pub(super) fn copy_small(dst: &mut [u8], src: &[u8]) {
    let n = dst.len().min(src.len());
    let (dst, src) = (&mut dst[..n], &src[..n]);
    macro_rules! two_words {
        ($w:literal) => {{
            let head: [u8; $w] = src[..$w].try_into().unwrap_or([0; $w]);
            let tail: [u8; $w] = src[n - $w..].try_into().unwrap_or([0; $w]);
            dst[..$w].copy_from_slice(&head);
            dst[n - $w..].copy_from_slice(&tail);
        }};
    }
    // The process data of a slave (tens of bytes) first: one comparison on the common path.
    if (16..=32).contains(&n) {
        two_words!(16);
        return;
    }
    match n {
        0 => {}
        1 => dst[0] = src[0],
        2..=3 => two_words!(2),
        4..=7 => two_words!(4),
        8..=15 => two_words!(8),
        _ => dst.copy_from_slice(src),
    }
}

/// The application, laid out as `l` says: a CiA 402 drive on its mapping, or a loopback
/// device (statusword, then the outputs echoed, then a cycle counter).
#[inline(always)]
pub(super) fn refresh_inputs(ram: &mut [u8], l: AppLayout, al_state: AlState, mem: &mut AppMemory) {
    if let Some(p) = &l.drive {
        cia402::step(ram, p, al_state, &mut mem.drive);
        return;
    }
    let app_cycles = &mut mem.cycles;
    let status: u16 = if al_state == AlState::Op {
        STATUS_OP
    } else {
        STATUS_NOT_OP
    };
    ram[l.ib..l.ib + 2].copy_from_slice(&status.to_le_bytes());
    if l.n > 0 {
        let (a, b) = ram.split_at_mut(l.ib + 2);
        copy_small(&mut b[..l.n], &a[l.ob..l.ob + l.n]);
    }
    *app_cycles = app_cycles.wrapping_add(1);
    if l.tail >= l.ib + 2 {
        ram[l.tail..l.tail + 2].copy_from_slice(&app_cycles.to_le_bytes());
    }
}

impl Esc {
    /// FMMUs the model has (at most the register map's sixteen).
    fn fmmu_count(&self) -> u8 {
        self.model.fmmu_count.min(FMMUS as u8)
    }

    /// SyncManagers the model has (at most the register map's sixteen).
    fn sm_count(&self) -> u8 {
        self.model.sm_count.min(SMS as u8)
    }

    /// Decodes the FMMU registers after a write to them.
    pub(super) fn parse_fmmus(&mut self) {
        for n in 0..self.fmmu_count() {
            let f = Fmmu::new_unchecked(self.reg_bytes(reg::fmmu_address(n), FMMU_ENTRY_LEN));
            let active = f.active();
            self.fmmus[usize::from(n)] = FmmuMapping {
                logical: f.logical_start(),
                len: if active { f.length_bytes() } else { 0 },
                physical: f.physical_start(),
                read: active && f.read_enabled(),
                write: active && f.write_enabled(),
            };
        }
        self.fmmu_writers.1 = 0;
        self.fmmu_readers.1 = 0;
        for n in 0..usize::from(self.fmmu_count()) {
            let f = self.fmmus[n];
            if f.len == 0 {
                continue;
            }
            if f.write {
                self.fmmu_writers.0[usize::from(self.fmmu_writers.1)] = n as u8;
                self.fmmu_writers.1 += 1;
            }
            if f.read {
                self.fmmu_readers.0[usize::from(self.fmmu_readers.1)] = n as u8;
                self.fmmu_readers.1 += 1;
            }
        }
    }

    /// Decodes the SyncManager registers after a write to them.
    pub(super) fn parse_sms(&mut self) {
        self.app = None;
        for n in 0..self.sm_count() {
            let s = SyncManager::new_unchecked(
                self.reg_bytes(reg::sync_manager_address(n), SM_ENTRY_LEN),
            );
            self.sms[usize::from(n)] = SmBuffer {
                start: s.physical_start(),
                len: s.length_bytes(),
                // A reserved direction is no write direction, as the silicon's decoder reads it.
                ecat_writes: s.direction() == Ok(SmDirection::Write),
                enabled: s.enabled(),
                mailbox: s.mode() == Ok(ecsync_wire::SmMode::Mailbox),
            };
        }
        self.mailbox_sms_changed();
        if self.input_sm.is_some() {
            self.app = self.app_layout();
            self.app_mem.drive.inputs_lost();
        }
    }

    /// The first enabled SyncManager whose buffer starts at `start` in the given direction.
    pub(super) fn find_sm(&self, start: u16, ecat_writes: bool) -> Option<usize> {
        self.sms
            .iter()
            .take(usize::from(self.model.sm_count))
            .position(|s| s.enabled && s.start == start && s.ecat_writes == ecat_writes)
    }

    /// Whether the SyncManager covering physical `addr` lets the process data through in the
    /// current state. The virtual application enables the input SyncManager from SAFE-OP on and
    /// the output SyncManager in OP only, as slave stacks do (outputs are ignored in SAFE-OP), so
    /// the working counter of an LRW is 3 per slave in OP and 1 in SAFE-OP.
    fn sm_allows(&self, addr: u16, write: bool) -> bool {
        let sm = if write { self.output_sm } else { self.input_sm };
        match sm {
            Some(i) => self.sms[i].contains(addr) && (!write || self.al_state == AlState::Op),
            // Not a process data SyncManager area: plain memory.
            None => !self
                .sms
                .iter()
                .take(usize::from(self.model.sm_count))
                .any(|s| s.enabled && s.contains(addr)),
        }
    }

    /// The application: refreshes the inputs from the outputs before a read of the input buffer
    /// (a loopback device: statusword, then the outputs echoed, then a cycle counter).
    #[inline(always)]
    pub(super) fn app_refresh_inputs(&mut self) {
        if let Some(l) = self.app {
            refresh_inputs(&mut self.ram, l, self.al_state, &mut self.app_mem);
            return;
        }
        self.app_refresh_slow();
    }

    /// Where the application's echo goes, when the buffers allow the fast copy (the output
    /// buffer before the input buffer, as the SII lays them out).
    pub(super) fn app_layout(&self) -> Option<AppLayout> {
        let i = self.input_sm?;
        let is = self.sms[i];
        let ib = usize::from(is.start).checked_sub(REG_SPACE)?;
        let ilen = usize::from(is.len);
        if ib + ilen > self.ram.len() || ilen < 2 {
            return None;
        }
        let (ob, n) = match self.output_sm {
            Some(o) => {
                let os = self.sms[o];
                let ob = usize::from(os.start).checked_sub(REG_SPACE)?;
                let n = usize::from(os.len)
                    .min(ilen - 2)
                    .min(self.ram.len().saturating_sub(ob));
                if ob + n > ib + 2 {
                    return None;
                }
                (ob, n)
            }
            None => (0, 0),
        };
        let drive = self.sdo_server().and_then(|c| {
            let (ob, ib) = (
                self.output_sm
                    .map_or(0, |o| usize::from(self.sms[o].start) - REG_SPACE),
                ib,
            );
            DrivePlan::new(
                &c.od.assigned_entries(0x1c12),
                &c.od.assigned_entries(0x1c13),
                ob,
                ib,
                c.od.read_u32(0x1c32, 2),
            )
        });
        Some(AppLayout {
            ib,
            ob,
            n,
            tail: ib + ilen - 2,
            drive,
        })
    }

    #[inline(never)]
    fn app_refresh_slow(&mut self) {
        let (Some(i), o) = (self.input_sm, self.output_sm) else {
            return;
        };
        let is = self.sms[i];
        let ib = usize::from(is.start).saturating_sub(REG_SPACE);
        let ilen = usize::from(is.len);
        if ib + ilen > self.ram.len() || ilen < 2 {
            return;
        }
        let status: u16 = if self.al_state == AlState::Op {
            STATUS_OP
        } else {
            STATUS_NOT_OP
        };
        self.ram[ib..ib + 2].copy_from_slice(&status.to_le_bytes());
        if let Some(o) = o {
            let os = self.sms[o];
            let ob = usize::from(os.start).saturating_sub(REG_SPACE);
            let n = usize::from(os.len)
                .min(ilen - 2)
                .min(self.ram.len().saturating_sub(ob));
            if ob + n <= ib + 2 {
                let (a, b) = self.ram.split_at_mut(ib + 2);
                copy_small(&mut b[..n], &a[ob..ob + n]);
            } else {
                self.ram.copy_within(ob..ob + n, ib + 2);
            }
        }
        self.app_mem.cycles = self.app_mem.cycles.wrapping_add(1);
        let tail = ib + ilen - 2;
        if tail >= ib + 2 {
            self.ram[tail..tail + 2].copy_from_slice(&self.app_mem.cycles.to_le_bytes());
        }
    }

    /// The part of the logical range `lstart..lstart + len` that FMMU `f` maps: (offset in the
    /// datagram's data, physical address, bytes). The bytes may still run past the end of the
    /// RAM.
    #[inline]
    fn fmmu_span(f: FmmuMapping, lstart: u64, len: u64) -> Option<(usize, usize, usize)> {
        let fs = u64::from(f.logical);
        let fe = fs + u64::from(f.len);
        let (s, e) = (lstart.max(fs), (lstart + len).min(fe));
        if s >= e {
            return None;
        }
        let phys = u64::from(f.physical) + (s - fs);
        Some(((s - lstart) as usize, phys as usize, (e - s) as usize))
    }

    /// The part of the logical range that FMMU `f` maps into the process RAM area and the
    /// SyncManagers let through: (offset in the datagram's data, offset in RAM, bytes). The
    /// bytes may still run past the end of the RAM.
    #[inline]
    fn fmmu_window(
        &self,
        f: FmmuMapping,
        lstart: u64,
        len: u64,
        write: bool,
    ) -> Option<(usize, usize, usize)> {
        let (d0, phys, n) = Self::fmmu_span(f, lstart, len)?;
        if phys < REG_SPACE || !self.sm_allows(phys as u16, write) {
            return None;
        }
        Some((d0, phys - REG_SPACE, n))
    }

    /// The part of the logical range that FMMU `f` maps into register space: (offset in the
    /// datagram's data, register address, bytes), the bytes clipped to the registers.
    #[inline(never)]
    fn fmmu_register_window(
        &self,
        f: FmmuMapping,
        lstart: u64,
        len: u64,
    ) -> Option<(usize, usize, usize)> {
        let (d0, phys, n) = Self::fmmu_span(f, lstart, len)?;
        (phys < REG_SPACE).then(|| (d0, phys, n.min(REG_SPACE - phys)))
    }

    /// Whether register `a` takes an FMMU's write: a register holding plain data (see the
    /// module's documentation), writable, and inside an enabled process data SyncManager the
    /// EtherCAT side writes if one covers it.
    fn register_takes_logical_write(&self, a: usize) -> bool {
        (0x0f00..REG_SPACE).contains(&a)
            && self.attr[a] & WRITABLE != 0
            && self.register_sm_allows(a as u16, true)
    }

    /// Whether register `a` gives an FMMU's read: a register the register file holds (not the
    /// DC block or the EEPROM interface), inside an enabled SyncManager the EtherCAT side
    /// reads if one covers it.
    fn register_gives_logical_read(&self, a: usize) -> bool {
        let computed = (0x0500..0x0510).contains(&a) || (0x0900..0x0a00).contains(&a);
        !computed && self.attr[a] & EXISTS != 0 && self.register_sm_allows(a as u16, false)
    }

    /// A process data SyncManager in register space: its buffer is the register's bytes, open
    /// whenever it is enabled, in the direction it was set up for (no application holds it:
    /// see the module's documentation). Registers no enabled SyncManager covers are open.
    fn register_sm_allows(&self, addr: u16, write: bool) -> bool {
        let mut covering = self
            .sms
            .iter()
            .take(usize::from(self.model.sm_count))
            .filter(|s| s.enabled && s.contains(addr))
            .peekable();
        covering.peek().is_none() || covering.any(|s| !s.mailbox && s.ecat_writes == write)
    }

    /// The writes and reads of a logical access that FMMUs map into register space: what
    /// [`Esc::logical`] adds to the working counter for them (write hit, read hit). Such an
    /// access is never recorded for the fast path (it copies into the RAM only).
    #[inline(never)]
    fn logical_registers(&mut self, cmd: Command, lstart: u64, data: &mut [u8]) -> (bool, bool) {
        let len = data.len() as u64;
        let (mut write_hit, mut read_hit) = (false, false);
        if cmd.writes() {
            for k in 0..usize::from(self.fmmu_writers.1) {
                let f = self.fmmus[usize::from(self.fmmu_writers.0[k])];
                let Some((d0, a0, n)) = self.fmmu_register_window(f, lstart, len) else {
                    continue;
                };
                self.rec.uncacheable();
                for i in 0..n {
                    if self.register_takes_logical_write(a0 + i) {
                        self.regs[a0 + i] = data[d0 + i];
                        write_hit = true;
                    }
                }
                // The outputs' buffer restarts the watchdog, as in process RAM.
                self.pd_written |= write_hit;
            }
        }
        if cmd.reads() {
            for k in 0..usize::from(self.fmmu_readers.1) {
                let f = self.fmmus[usize::from(self.fmmu_readers.0[k])];
                let Some((d0, a0, n)) = self.fmmu_register_window(f, lstart, len) else {
                    continue;
                };
                self.rec.uncacheable();
                for i in 0..n {
                    if self.register_gives_logical_read(a0 + i) {
                        data[d0 + i] = self.regs[a0 + i];
                        read_hit = true;
                    }
                }
            }
        }
        (write_hit, read_hit)
    }

    /// Whether an FMMU maps into register space (the common process data never does: its
    /// logical path stays as it was).
    #[inline]
    fn maps_registers(&self) -> bool {
        self.fmmus[..usize::from(self.fmmu_count())]
            .iter()
            .any(|f| f.len > 0 && usize::from(f.physical) < REG_SPACE)
    }

    /// The outputs as the device takes them: the buffers of the enabled process data
    /// SyncManagers the EtherCAT side writes, in SyncManager order, from the register file
    /// (the digital output register 0x0F00, which drives a terminal's outputs) or the process
    /// RAM. Empty without such a SyncManager.
    pub fn outputs(&self) -> Vec<u8> {
        let mut out = Vec::new();
        for s in self.sms.iter().take(usize::from(self.sm_count())) {
            if !(s.enabled && s.ecat_writes && !s.mailbox) {
                continue;
            }
            for a in usize::from(s.start)..usize::from(s.start) + usize::from(s.len) {
                out.push(match a.checked_sub(REG_SPACE) {
                    None => self.regs[a],
                    Some(r) => self.ram.get(r).copied().unwrap_or(0),
                });
            }
        }
        out
    }

    /// Whether the device has outputs at all: process data it declares for the master to
    /// write (a coupler such as the EK1100 has none).
    pub fn has_outputs(&self) -> bool {
        !self.device().outputs.is_empty()
    }

    /// LRD/LWR/LRW through the FMMUs. Returns the working counter increment.
    pub(super) fn logical(&mut self, cmd: Command, laddr: u32, data: &mut [u8]) -> u16 {
        self.rec.act = Act::Logical;
        let len = data.len() as u64;
        let lstart = u64::from(laddr);
        let mut read_hit = false;
        let mut write_hit = false;
        if cmd.writes() {
            for k in 0..usize::from(self.fmmu_writers.1) {
                let f = self.fmmus[usize::from(self.fmmu_writers.0[k])];
                let Some((d0, r0, n)) = self.fmmu_window(f, lstart, len, true) else {
                    continue;
                };
                if r0 + n > self.ram.len() {
                    continue;
                }
                self.ram[r0..r0 + n].copy_from_slice(&data[d0..d0 + n]);
                write_hit = true;
                self.pd_written = true;
                self.rec.op(LogicalOp::Write {
                    data_off: d0 as u16,
                    ram_off: r0 as u16,
                    len: n as u16,
                });
            }
        }
        if cmd.reads() {
            let mut refreshed = false;
            for k in 0..usize::from(self.fmmu_readers.1) {
                let f = self.fmmus[usize::from(self.fmmu_readers.0[k])];
                let Some((d0, r0, n)) = self.fmmu_window(f, lstart, len, false) else {
                    continue;
                };
                // The application refreshes its inputs once, before the first read that
                // reaches its buffer (even one that then runs past the RAM).
                if !refreshed {
                    self.app_refresh_inputs();
                    refreshed = true;
                    self.rec.op(LogicalOp::Refresh);
                }
                if r0 + n > self.ram.len() {
                    continue;
                }
                data[d0..d0 + n].copy_from_slice(&self.ram[r0..r0 + n]);
                read_hit = true;
                self.rec.op(LogicalOp::Read {
                    data_off: d0 as u16,
                    ram_off: r0 as u16,
                    len: n as u16,
                });
            }
        }
        if self.maps_registers() {
            let (w, r) = self.logical_registers(cmd, lstart, data);
            write_hit |= w;
            read_hit |= r;
        }
        match cmd {
            Command::Lrd => u16::from(read_hit),
            Command::Lwr => u16::from(write_hit),
            _ => u16::from(read_hit) + 2 * u16::from(write_hit),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::copy_small;

    #[test]
    fn copy_small_copies_every_length_exactly() {
        let src: Vec<u8> = (1..=100u8).collect();
        for n in 0..=100 {
            for dst_len in [n, n + 3] {
                let mut got = vec![0u8; dst_len];
                copy_small(&mut got, &src[..n]);
                let mut want = vec![0u8; dst_len];
                want[..n].copy_from_slice(&src[..n]);
                assert_eq!(got, want, "n = {n}, dst {dst_len}");
            }
        }
    }
}
