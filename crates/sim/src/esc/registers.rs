//! The register file (ESC datasheet section II): which bytes exist and which the EtherCAT side
//! may write, their reset values, physical reads and writes with the side effects a write has
//! on the other parts of the ESC, DL control (loop settings) and DL status.

use super::{DatagramEffects, Esc};
use crate::dc_unit::{DC_BLOCK_LEN, DC_BLOCK_START};
use crate::model::{DcSupport, PortKind};
use crate::segment::ErrorCounter;
use ecsync_wire::register as reg;
use ecsync_wire::{AlControl, AlControlRepr, AlState, DlStatus, DlStatusRepr, PortStatus};

/// Bytes of register space before the process RAM.
pub(super) const REG_SPACE: usize = 0x1000;

// Attribute bits of the register map.
pub(super) const EXISTS: u8 = 1;
pub(super) const WRITABLE: u8 = 2;

/// Registers the EEPROM interface write-protects while it is busy (0x0502-0x050F).
const SII_INTERFACE: core::ops::Range<usize> =
    reg::SII_CONTROL as usize..reg::SII_CONTROL as usize + 14;
/// AL control (0x0120-0x0121).
const AL_CONTROL_BYTES: core::ops::Range<usize> =
    reg::AL_CONTROL as usize..reg::AL_CONTROL as usize + ecsync_wire::AL_CONTROL_LEN;
/// Bytes of DL control (0x0100).
const DL_CONTROL_LEN: usize = 4;
/// DL control at reset: forwarding rule 1 (non-EtherCAT frames destroyed), loops auto, RX
/// FIFO size 7.
const DL_CONTROL_RESET: u32 = 0x0007_0001;
/// The RX error counters a write clears (0x0300-0x030B).
const RX_ERROR_COUNTERS_LEN: usize = 0x0c;
/// The ECAT processing unit error counter (0x030C) and the PDI error counter (0x030D): each
/// cleared by a write to it alone.
const PU_ERROR_COUNTER: usize = ErrorCounter::ProcessingUnit.address() as usize;
const PDI_ERROR_COUNTER: usize = PU_ERROR_COUNTER + 1;
/// The lost link counters (0x0310-0x0313), one per port, cleared together.
const LOST_LINK_COUNTERS_LEN: usize = 4;

/// Loop setting of a port (DL control 0x0100 bits 8+2p..9+2p).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopMode {
    /// Closed at link down, open at link up.
    Auto,
    /// Closed at link down; opened again by the master.
    AutoClose,
    /// Always open: a frame sent to a port without link is lost.
    Open,
    /// Always closed: the frame loops back inside the ESC.
    Closed,
}

pub(super) fn ranges_overlap(lo: usize, hi: usize, a: usize, len: usize) -> bool {
    lo < a + len && a < hi
}

/// The part of `lo..hi` inside `start..start + len`.
fn clamp_to(lo: usize, hi: usize, start: usize, len: usize) -> (usize, usize) {
    (lo.max(start), hi.min(start + len))
}

impl Esc {
    fn mark(&mut self, addr: u16, len: u16, bits: u8) {
        for a in addr..addr + len {
            self.attr[usize::from(a)] = bits;
        }
    }

    /// Which registers exist and which the EtherCAT side may write (datasheet section II).
    pub(super) fn build_attributes(&mut self) {
        let rw = EXISTS | WRITABLE;
        self.mark(0x0000, 0x0010, EXISTS); // information
        self.mark(reg::STATION_ADDRESS, 2, rw);
        self.mark(reg::STATION_ALIAS, 2, EXISTS);
        self.mark(0x0020, 2, rw); // write enable / protection
        self.mark(0x0030, 2, rw);
        self.mark(0x0040, 2, rw); // ESC reset
        self.mark(reg::DL_CONTROL, 4, rw);
        self.mark(0x0108, 2, rw); // physical R/W offset
        self.mark(reg::DL_STATUS, 2, EXISTS);
        self.mark(reg::AL_CONTROL, 2, rw);
        self.mark(reg::AL_STATUS, 2, EXISTS);
        self.mark(reg::AL_STATUS_CODE, 2, EXISTS);
        self.mark(0x0138, 2, rw); // LED override
        self.mark(reg::PDI_CONTROL, 5, EXISTS);
        self.mark(0x0150, 4, EXISTS);
        self.mark(0x0200, 2, rw); // ECAT event mask
        self.mark(0x0204, 4, EXISTS);
        self.mark(0x0210, 2, EXISTS);
        self.mark(0x0220, 4, EXISTS);
        self.mark(reg::RX_ERROR_COUNTER, 0x0e, rw);
        self.mark(reg::LOST_LINK_COUNTER, 4, rw);
        self.mark(0x0400, 2, rw);
        self.mark(0x0410, 2, rw);
        self.mark(0x0420, 2, rw);
        self.mark(0x0440, 1, EXISTS);
        self.mark(0x0442, 2, rw);
        self.mark(reg::SII_CONFIG, 1, rw);
        self.mark(reg::SII_PDI_ACCESS, 1, EXISTS);
        self.mark(reg::SII_CONTROL, 0x0e, rw);
        self.mark(0x0510, 0x0c, rw); // MII management
        for n in 0..self.model.fmmu_count.min(reg::MAX_FMMUS) {
            self.mark(reg::fmmu_address(n), reg::FMMU_LEN, rw);
        }
        for n in 0..self.model.sm_count.min(reg::MAX_SYNC_MANAGERS) {
            // Status (offset 5) and PDI control (offset 7) belong to the slave's side.
            let base = reg::sync_manager_address(n);
            self.mark(base, 5, rw);
            self.mark(base + 5, 1, EXISTS);
            self.mark(base + 6, 1, rw);
            self.mark(base + 7, 1, EXISTS);
        }
        match self.model.dc {
            DcSupport::None => {}
            DcSupport::ReceiveTimes => self.mark(0x0900, 0x10, rw),
            DcSupport::Full32 | DcSupport::Full64 => {
                self.mark(0x0900, 0x10, rw);
                self.mark(reg::DC_SYSTEM_TIME, 8, rw);
                self.mark(reg::DC_RECEIVE_TIME_PU, 8, EXISTS);
                self.mark(reg::DC_SYSTEM_TIME_OFFSET, 12, rw);
                self.mark(reg::DC_SYSTEM_TIME_DIFF, 4, EXISTS);
                self.mark(reg::DC_SPEED_COUNTER_START, 2, rw);
                self.mark(reg::DC_SPEED_COUNTER_DIFF, 2, EXISTS);
                self.mark(reg::DC_TIME_DIFF_FILTER_DEPTH, 3, rw);
                self.mark(reg::DC_CYCLIC_UNIT_CONTROL, 2, rw);
                self.mark(reg::DC_PULSE_LENGTH, 3, EXISTS);
                self.mark(reg::DC_SYNC0_STATUS, 2, EXISTS);
                self.mark(reg::DC_START_TIME, 8, rw);
                self.mark(reg::DC_NEXT_SYNC1, 8, EXISTS);
                self.mark(reg::DC_SYNC0_CYCLE, 8, rw);
                self.mark(0x09a8, 2, rw); // latch control
                self.mark(0x09ae, 2, EXISTS);
                self.mark(0x09b0, 0x20, EXISTS);
            }
        }
        self.mark(0x0f00, 4, rw); // digital outputs
        self.mark(0x0f80, 0x80, rw); // user RAM
    }

    /// The register bytes `addr..addr + len`.
    pub(super) fn reg_bytes(&self, addr: u16, len: usize) -> &[u8] {
        let a = usize::from(addr);
        &self.regs[a..a + len]
    }

    /// The register bytes `addr..addr + len`, to write.
    pub(super) fn reg_bytes_mut(&mut self, addr: u16, len: usize) -> &mut [u8] {
        let a = usize::from(addr);
        &mut self.regs[a..a + len]
    }

    pub(super) fn put_u16(&mut self, addr: u16, v: u16) {
        self.reg_bytes_mut(addr, 2)
            .copy_from_slice(&v.to_le_bytes());
    }

    pub(super) fn get_u16(&self, addr: u16) -> u16 {
        let b = self.reg_bytes(addr, 2);
        u16::from_le_bytes([b[0], b[1]])
    }

    pub(super) fn get_u32(&self, addr: u16) -> u32 {
        let b = self.reg_bytes(addr, 4);
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// The power-up values: identity from the model, the EEPROM's words loaded, INIT.
    pub(super) fn reset_registers(&mut self) {
        self.regs[usize::from(reg::TYPE)] = self.model.esc_type;
        self.regs[usize::from(reg::REVISION)] = self.model.revision;
        self.put_u16(reg::BUILD, self.model.build);
        self.regs[usize::from(reg::FMMU_COUNT)] = self.model.fmmu_count;
        self.regs[usize::from(reg::SM_COUNT)] = self.model.sm_count;
        self.regs[usize::from(reg::RAM_SIZE)] = self.model.ram_kib;
        self.regs[usize::from(reg::PORT_DESCRIPTOR)] = self.model.port_descriptor();
        self.put_u16(reg::FEATURES, self.model.features());
        let [w0, w1, w2, alias] = self.sii.reset_words();
        self.put_u16(reg::STATION_ALIAS, alias);
        self.reg_bytes_mut(reg::DL_CONTROL, DL_CONTROL_LEN)
            .copy_from_slice(&DL_CONTROL_RESET.to_le_bytes());
        self.put_u16(reg::PDI_CONTROL, w0);
        self.put_u16(0x0150, w1);
        self.put_u16(reg::SII_CONTROL, self.model.sii_control_idle);
        // The watchdogs' reset values: 100 us ticks, 100 ms each; process data watchdog
        // running (0x0440 bit 0 = 1: not expired).
        self.put_u16(0x0400, super::watchdog::WATCHDOG_DIVIDER_RESET);
        self.put_u16(0x0410, super::watchdog::PDI_WATCHDOG_RESET);
        self.put_u16(0x0420, super::watchdog::PD_WATCHDOG_RESET);
        self.regs[0x0440] = 0x01;
        AlControlRepr::request(AlState::Init).emit(&mut AlControl::new_unchecked(
            self.reg_bytes_mut(reg::AL_CONTROL, ecsync_wire::AL_CONTROL_LEN),
        ));
        if let Some(dc) = &mut self.dc {
            // Pulse length is loaded from SII word 2 into 0x0982 (read-only from ECAT).
            dc.write(reg::DC_PULSE_LENGTH, &w2.to_le_bytes(), 0);
        }
        self.update_al_registers();
        self.update_dl_status();
    }

    /// Sets which ports have a physical link. A link lost at an open port in auto or
    /// auto-close loop mode counts in its lost link counter (0x0310 + p; the datasheet's
    /// section I, "Error Counters": "counts only if port is in Auto or Auto close mode"): a
    /// port the master forced open or closed does not count.
    pub fn set_links(&mut self, link: [bool; 4]) {
        for (p, &up) in link.iter().enumerate() {
            let auto = matches!(self.loop_mode[p], LoopMode::Auto | LoopMode::AutoClose);
            if auto && self.port_forwards(p) == Ok(true) && !up {
                self.count_error(ErrorCounter::LostLink(p));
            }
        }
        self.set_links_uncounted(link);
    }

    /// Sets which ports have a physical link without counting a lost one: the cables as the
    /// segment starts (a port whose cable is plugged in later never had a link).
    pub(crate) fn set_links_uncounted(&mut self, link: [bool; 4]) {
        self.generation += 1;
        self.link = link;
        self.update_dl_status();
    }

    /// Counts one error in `counter`, which stops at 0xFF. Errors are counted only at a port
    /// that exists (section II: "only counted if the corresponding port is enabled").
    pub(crate) fn count_error(&mut self, counter: ErrorCounter) {
        let port = match counter {
            ErrorCounter::InvalidFrame(p)
            | ErrorCounter::ForwardedRxError(p)
            | ErrorCounter::LostLink(p) => Some(p),
            ErrorCounter::ProcessingUnit => None,
        };
        if port.is_some_and(|p| self.model.ports[p] == PortKind::None) {
            return;
        }
        // (A counter is read through the register file, never through a recorded program:
        // no generation moves.)
        let r = &mut self.regs[usize::from(counter.address())];
        *r = r.saturating_add(1);
    }

    /// The error counters, registers 0x0300-0x0313 as a master reads them (0x030E-0x030F do
    /// not exist and read 0): for a status report that does not send a frame.
    pub fn error_counters(&self) -> [u8; 0x14] {
        let mut out = [0u8; 0x14];
        out.copy_from_slice(self.reg_bytes(reg::RX_ERROR_COUNTER, 0x14));
        out
    }

    /// Which ports have a physical link.
    pub fn links(&self) -> [bool; 4] {
        self.link
    }

    /// Whether a frame leaves through port `p` (link and loop open) rather than looping back.
    /// `Err(())` if the port is forced open without a link: the frame is lost there.
    #[allow(clippy::result_unit_err)]
    pub fn port_forwards(&self, p: usize) -> Result<bool, ()> {
        if self.model.ports[p] == PortKind::None {
            return Ok(false);
        }
        match self.loop_mode[p] {
            LoopMode::Closed => Ok(false),
            LoopMode::Open => {
                if self.link[p] {
                    Ok(true)
                } else {
                    Err(())
                }
            }
            LoopMode::Auto | LoopMode::AutoClose => Ok(self.link[p]),
        }
    }

    /// DL status from the links and loops: an unimplemented port is closed, a linked port
    /// communicates.
    pub(super) fn update_dl_status(&mut self) {
        let ports = core::array::from_fn(|p| {
            let implemented = self.model.ports[p] != PortKind::None;
            PortStatus {
                physical_link: implemented && self.link[p],
                loop_closed: !implemented || !matches!(self.port_forwards(p), Ok(true)),
                communication: implemented && self.link[p],
            }
        });
        // A device family (its model gives its PDI control, see `EscModel::pdi_control`)
        // shows what PDI control (0x0140-0x0141) sets: an ESC without a PDI (type 0) has no PDI
        // watchdog reloaded, as the EK1100 shows (DL status 0x5A31, bit 1 clear, in
        // replay-dc.pcapng and soem-sdinfo-ek1100-el1004.pcapng, with 0x0140 = 0); enhanced
        // link detection (bit 2) as 0x0141 bit 1 enables it for all ports (the LAN9252: 0x0141 =
        // 0x0E, DL status 0x5617 in soem-single-lan9252.pcapng). The other models show a PDI
        // with its watchdog reloaded and no enhanced link detection, as they always did.
        let (pdi_watchdog_ok, enhanced_link_detection) = match self.model.pdi_control {
            Some(_) => {
                let pdi_type = self.regs[usize::from(reg::PDI_CONTROL)];
                let esc_config = self.regs[usize::from(reg::PDI_CONTROL) + 1];
                (pdi_type != 0, esc_config & 0x02 != 0)
            }
            None => (true, false),
        };
        let status = DlStatusRepr {
            pdi_operational: true,
            pdi_watchdog_ok,
            enhanced_link_detection,
            ports,
        };
        status.emit(&mut DlStatus::new_unchecked(
            self.reg_bytes_mut(reg::DL_STATUS, ecsync_wire::DL_STATUS_LEN),
        ));
    }

    fn parse_dl_control(&mut self) {
        // Loop settings: DL control bits 8 + 2p..9 + 2p, i.e. byte 1.
        let loops = self.regs[usize::from(reg::DL_CONTROL) + 1];
        for p in 0..4 {
            self.loop_mode[p] = match (loops >> (2 * p)) & 0b11 {
                0b00 => LoopMode::Auto,
                0b01 => LoopMode::AutoClose,
                0b10 => LoopMode::Open,
                _ => LoopMode::Closed,
            };
        }
        self.update_dl_status();
    }

    /// Whether the station alias may address this ESC (DL control bit 24).
    pub(crate) fn alias_enabled(&self) -> bool {
        self.regs[usize::from(reg::DL_CONTROL) + 3] & 0x01 != 0
    }

    /// Reads physical memory into `out`; returns whether the access counts (at least one byte
    /// exists). Bytes that do not exist leave `out` unchanged. With `or`, data is ORed (BRD).
    pub(super) fn read_physical(&mut self, ado: u16, out: &mut [u8], or: bool, t_ps: u64) -> bool {
        // The cyclic frame's DC reads (system time, time difference) skip the register shadow.
        if (ado == reg::DC_SYSTEM_TIME || ado == reg::DC_SYSTEM_TIME_DIFF)
            && self.attr[usize::from(ado)] & EXISTS != 0
            && self.read_dc_fast(ado, out, or, t_ps)
        {
            return true;
        }
        self.rec.uncacheable();
        if self.mbx.is_some() {
            self.mailbox_tick(t_ps);
        }
        self.al_tick(t_ps);
        let lo = usize::from(ado);
        let hi = lo + out.len();
        let mut counted = false;
        if lo < REG_SPACE {
            let rhi = hi.min(REG_SPACE);
            self.refresh_shadows(lo, rhi, t_ps);
            for (i, a) in (lo..rhi).enumerate() {
                if self.attr[a] & EXISTS != 0 {
                    counted = true;
                    if or {
                        out[i] |= self.regs[a];
                    } else {
                        out[i] = self.regs[a];
                    }
                }
            }
        }
        if hi > REG_SPACE {
            match self.mailbox_gate(lo, hi, false) {
                // An empty mailbox: nothing read, nothing counted.
                Some(false) => {}
                Some(true) => {
                    counted |= self.read_ram(lo, hi, out, or);
                    self.mailbox_accessed(hi, false, t_ps);
                }
                None => counted |= self.read_ram(lo, hi, out, or),
            }
        }
        counted
    }

    /// A system time or time difference read straight from the DC unit; false (nothing read)
    /// without one.
    fn read_dc_fast(&mut self, ado: u16, out: &mut [u8], or: bool, t_ps: u64) -> bool {
        let Some(dc) = &mut self.dc else {
            return false;
        };
        if !dc.read_fast(ado, out, or, t_ps) {
            return false;
        }
        self.rec.act = if ado == reg::DC_SYSTEM_TIME {
            super::recorder::Act::SysTimeRead { or }
        } else {
            super::recorder::Act::DiffRead { or }
        };
        true
    }

    /// Brings the register shadows a read of `lo..hi` sees up to date: the DC block from the
    /// clock, the EEPROM interface from its pending command.
    fn refresh_shadows(&mut self, lo: usize, hi: usize, t_ps: u64) {
        let dc_start = usize::from(DC_BLOCK_START);
        if ranges_overlap(lo, hi, dc_start, DC_BLOCK_LEN)
            && let Some(dc) = &mut self.dc
        {
            let (a, b) = clamp_to(lo, hi, dc_start, DC_BLOCK_LEN);
            dc.refresh(&mut self.dc_block, a as u16, b as u16, t_ps);
            self.regs[a..b].copy_from_slice(&self.dc_block[a - dc_start..b - dc_start]);
        }
        if ranges_overlap(lo, hi, SII_INTERFACE.start, SII_INTERFACE.len()) {
            self.sii_update(t_ps);
        }
    }

    /// Process RAM part of a read of `lo..hi` (physical addresses); whether any byte exists.
    fn read_ram(&self, lo: usize, hi: usize, out: &mut [u8], or: bool) -> bool {
        let start = lo.max(REG_SPACE);
        let end = hi.min(REG_SPACE + self.ram.len());
        if start >= end {
            return false;
        }
        let src = &self.ram[start - REG_SPACE..end - REG_SPACE];
        let dst = &mut out[start - lo..end - lo];
        if or {
            dst.iter_mut().zip(src).for_each(|(d, s)| *d |= *s);
        } else {
            dst.copy_from_slice(src);
        }
        true
    }

    /// Writes `data` to physical memory; returns whether the access counts (at least one byte
    /// writable) and what the segment must do.
    pub(super) fn write_physical(
        &mut self,
        ado: u16,
        data: &[u8],
        t_ps: u64,
        fx: &mut DatagramEffects,
    ) -> bool {
        // The cyclic frame's system time write (FRMW/ARMW) goes straight to the control loop.
        if ado == reg::DC_SYSTEM_TIME
            && data.len() <= 8
            && self.attr[usize::from(ado)] & WRITABLE != 0
            && let Some(dc) = &mut self.dc
        {
            // (The register shadow of 0x0910 is refreshed from the clock on every read.)
            dc.write_system_time(data, t_ps);
            self.rec.act = super::recorder::Act::SysTimeWrite;
            return true;
        }
        self.rec.uncacheable();
        let lo = usize::from(ado);
        let hi = lo + data.len();
        // A write of the System Time Offset or Delay (DCM in bus shift writes the reference's
        // offset every cycle) changes the DC unit's state only, which every recorded step reads
        // when it runs: the programs stay valid, and so do a large network's visit plans (a
        // new generation every cycle ended them all, and every frame visited every ESC). The
        // frame that writes is still not recorded here.
        let dc_time_only = lo >= usize::from(reg::DC_SYSTEM_TIME_OFFSET)
            && hi <= usize::from(reg::DC_SYSTEM_TIME_DIFF);
        if !dc_time_only {
            self.generation += 1;
        }
        if self.mbx.is_some() {
            self.mailbox_tick(t_ps);
        }
        self.al_tick(t_ps);
        if lo >= REG_SPACE {
            return self.write_ram_gated(lo, hi, data, t_ps);
        }
        let rhi = hi.min(REG_SPACE);
        // While the EEPROM interface is busy its registers are write-protected.
        self.sii_update(t_ps);
        let sii_busy = self.sii.busy();
        // While the firmware has not read the last AL control write, AL control takes none:
        // its bytes neither change nor count.
        let al_locked = self.al_control_locked();
        let mut counted = false;
        for (i, a) in (lo..rhi).enumerate() {
            if self.attr[a] & WRITABLE != 0 && !(al_locked && AL_CONTROL_BYTES.contains(&a)) {
                counted = true;
                if !(sii_busy && SII_INTERFACE.contains(&a)) {
                    self.regs[a] = data[i];
                }
            }
        }
        if !counted {
            return hi > REG_SPACE && self.write_ram_gated(lo, hi, data, t_ps);
        }
        self.registers_written(lo, rhi, data, (sii_busy, al_locked), t_ps, fx);
        if hi > REG_SPACE {
            self.write_ram_gated(lo, hi, data, t_ps);
        }
        true
    }

    /// A write of process RAM through the mailbox's gate (a full mailbox takes nothing).
    fn write_ram_gated(&mut self, lo: usize, hi: usize, data: &[u8], t_ps: u64) -> bool {
        match self.mailbox_gate(lo, hi, true) {
            Some(false) => false,
            Some(true) => {
                let w = self.write_ram(lo, hi, data);
                self.mailbox_accessed(hi, true, t_ps);
                w
            }
            None => {
                let w = self.write_ram(lo, hi, data);
                // A write into the output SyncManager's buffer restarts the watchdog, physical
                // or logical.
                if let Some(i) = self.output_sm {
                    let b = self.sms[i];
                    let (s, e) = (
                        usize::from(b.start),
                        usize::from(b.start) + usize::from(b.len),
                    );
                    self.pd_written |= w && lo < e && hi > s;
                }
                w
            }
        }
    }

    /// What a write of `data` to registers `lo..hi` sets off in the other parts of the ESC
    /// (`locked`: the EEPROM interface was busy, AL control refused the write).
    fn registers_written(
        &mut self,
        lo: usize,
        hi: usize,
        data: &[u8],
        locked: (bool, bool),
        t_ps: u64,
        fx: &mut DatagramEffects,
    ) {
        let (sii_busy, al_locked) = locked;
        let dc_start = usize::from(DC_BLOCK_START);
        if ranges_overlap(lo, hi, dc_start, DC_BLOCK_LEN)
            && let Some(dc) = &mut self.dc
        {
            let (a, b) = clamp_to(lo, hi, dc_start, DC_BLOCK_LEN);
            let e = dc.write(a as u16, &data[a - lo..b - lo], t_ps);
            fx.latch_receive_times |= e.latch_receive_times;
            if ranges_overlap(lo, hi, usize::from(reg::DC_ACTIVATION), 1) {
                self.sync0_activation_changed();
            }
        }
        if !al_locked && ranges_overlap(lo, hi, AL_CONTROL_BYTES.start, AL_CONTROL_BYTES.len()) {
            self.al_control_written(t_ps);
        }
        let sii_control = usize::from(reg::SII_CONTROL);
        if ranges_overlap(lo, hi, sii_control, 2) && !sii_busy {
            // Only the command and write-enable bits are the master's; the rest is status.
            let v = self.get_u16(reg::SII_CONTROL);
            let written = u16::from_le_bytes([
                if lo <= sii_control {
                    data[sii_control - lo]
                } else {
                    0
                },
                if lo <= sii_control + 1 && hi > sii_control + 1 {
                    data[sii_control + 1 - lo]
                } else {
                    (v >> 8) as u8
                },
            ]);
            self.sii_control_written(written, t_ps);
        }
        let fmmus = usize::from(reg::FMMU_BASE);
        if ranges_overlap(
            lo,
            hi,
            fmmus,
            usize::from(reg::MAX_FMMUS) * usize::from(reg::FMMU_LEN),
        ) {
            self.parse_fmmus();
        }
        let sms = usize::from(reg::SM_BASE);
        let sms_len = usize::from(reg::MAX_SYNC_MANAGERS) * usize::from(reg::SM_LEN);
        if ranges_overlap(lo, hi, sms, sms_len) {
            self.parse_sms();
        }
        if ranges_overlap(lo, hi, sms, sms_len)
            || ranges_overlap(lo, hi, 0x0400, 0x22)
            || ranges_overlap(
                lo,
                hi,
                usize::from(reg::AL_CONTROL),
                ecsync_wire::AL_CONTROL_LEN,
            )
        {
            self.update_watchdog(t_ps);
        }
        if ranges_overlap(lo, hi, usize::from(reg::DL_CONTROL), DL_CONTROL_LEN) {
            self.parse_dl_control();
            fx.loops_changed = true;
        }
        // The error counters are cleared by a write, whatever its value (section II): any of
        // 0x0300-0x030B clears all twelve, 0x030C and 0x030D each themselves, any of
        // 0x0310-0x0313 all four.
        let rx_errors = usize::from(reg::RX_ERROR_COUNTER);
        if ranges_overlap(lo, hi, rx_errors, RX_ERROR_COUNTERS_LEN) {
            self.regs[rx_errors..rx_errors + RX_ERROR_COUNTERS_LEN].fill(0);
        }
        for a in [PU_ERROR_COUNTER, PDI_ERROR_COUNTER] {
            if ranges_overlap(lo, hi, a, 1) {
                self.regs[a] = 0;
            }
        }
        let lost_links = usize::from(reg::LOST_LINK_COUNTER);
        if ranges_overlap(lo, hi, lost_links, LOST_LINK_COUNTERS_LEN) {
            self.regs[lost_links..lost_links + LOST_LINK_COUNTERS_LEN].fill(0);
        }
    }

    /// Process RAM part of a write of `lo..hi` (physical addresses); whether any byte exists.
    fn write_ram(&mut self, lo: usize, hi: usize, data: &[u8]) -> bool {
        let start = lo.max(REG_SPACE);
        let end = hi.min(REG_SPACE + self.ram.len());
        if start < end {
            self.ram[start - REG_SPACE..end - REG_SPACE]
                .copy_from_slice(&data[start - lo..end - lo]);
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dg, esc, wkc};
    use ecsync_wire::Command;

    #[test]
    fn read_only_and_missing_registers_do_not_count() {
        let mut e = esc();
        // Write to the read-only type register: WKC unchanged, register unchanged.
        let mut d = dg(Command::Bwr, 0, 0x0000, &[0x55]);
        e.process_datagram(&mut d, 0);
        assert_eq!(wkc(&d), 0);
        let mut d = dg(Command::Brd, 0, 0x0000, &[0]);
        e.process_datagram(&mut d, 0);
        assert_eq!((wkc(&d), d[10]), (1, 0x11));
        // FMMU 8 does not exist on an 8-FMMU ESC.
        let mut d = dg(Command::Bwr, 0, 0x0680, &[0; 16]);
        e.process_datagram(&mut d, 0);
        assert_eq!(wkc(&d), 0);
        // 0x092C is read-only.
        let mut d = dg(Command::Bwr, 0, 0x092c, &[0; 4]);
        e.process_datagram(&mut d, 0);
        assert_eq!(wkc(&d), 0);
    }

    #[test]
    fn dl_status_shows_the_links_and_loops() {
        // Port 0 linked (MII), port 1 without link, ports 2 and 3 not implemented: bits 0, 1
        // (PDI operational, watchdog), 4 (link 0), 9 (communication 0), 10, 12, 14 (loops 1-3
        // closed) = 0x5613, what the EL2889 at the end of ethercrab's line shows.
        let mut e = esc();
        let mut d = dg(Command::Brd, 0, 0x0110, &[0, 0]);
        e.process_datagram(&mut d, 0);
        assert_eq!(u16::from_le_bytes([d[10], d[11]]), 0x5613);
    }
}
