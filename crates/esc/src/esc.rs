//! One virtual EtherCAT slave controller: its memory, register semantics, working-counter rules,
//! FMMUs, SyncManagers, SII EEPROM interface, AL state machine and DC unit.
//!
//! Datagrams are processed by [`Esc::process_datagram`] when a frame passes the processing unit.
//! Nothing here allocates after construction.
//!
//! Deviation from the silicon, kept on purpose: register writes take effect immediately rather
//! than at the end of a frame with a good FCS (a read later in the same frame sees the new value),
//! because frames here are never corrupted on the wire. Side effects that the datasheet places at
//! the end of the frame (DC compare, EEPROM command) use the frame's SOF time, which gives the
//! same result.

use crate::dc_unit::{DC_BLOCK_LEN, DC_BLOCK_START, DcParams, DcUnit};
use crate::model::{DcSupport, DeviceInfo, EscModel};
use crate::{clock::CrystalParams, sii_image};
use ecsync_wire::register::{self as reg, al_state, al_status_code, dl_status, sii_control};
use ecsync_wire::{Command, DATAGRAM_HEADER_LEN};

const REG_SPACE: usize = 0x1000;

// Attribute bits of the register map.
const EXISTS: u8 = 1;
const WRITABLE: u8 = 2;

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

#[derive(Debug, Clone, Copy, Default)]
struct Fmmu {
    logical: u32,
    len: u16,
    physical: u16,
    read: bool,
    write: bool,
}

#[derive(Debug, Clone, Copy, Default)]
struct SyncManager {
    start: u16,
    len: u16,
    ecat_writes: bool,
    enabled: bool,
}

#[derive(Debug, Clone)]
struct SiiState {
    image: Vec<u8>,
    busy_until_ps: u64,
    pending_read: Option<u32>,
    read_busy_ps: u64,
}

/// What one datagram did at this ESC, recorded so that the same frame shape can replay it while
/// the ESC's configuration is unchanged (the cyclic frame is the same every cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum Act {
    /// Nothing beyond the address and working counter updates.
    #[default]
    None,
    /// System time read (0x0910) into the data, ORed for broadcast reads.
    SysTimeRead { or: bool },
    /// System time write (0x0910): the time control loop compares.
    SysTimeWrite,
    /// System time difference read (0x092C).
    DiffRead { or: bool },
    /// Logical access: `ops[start..start + count]` of the program.
    Logical { start: u8, count: u8 },
}

/// One step of a logical access.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum LogicalOp {
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

/// One step of a recorded program, with absolute offsets into the frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum Op {
    #[default]
    Nop,
    /// Increment the 16-bit ADP at `at`.
    AdpInc { at: u16 },
    /// System time read into the data at `at`.
    SysRead { at: u16, len: u8, or: bool },
    /// System time write from the data at `at`.
    SysWrite { at: u16, len: u8 },
    /// System time difference read into the data at `at`.
    DiffRead { at: u16, len: u8, or: bool },
    /// Frame bytes at `at` -> process RAM.
    ToRam { at: u16, ram: u16, len: u16 },
    /// Process RAM -> frame bytes at `at`.
    FromRam { at: u16, ram: u16, len: u16 },
    /// The application refreshes its inputs.
    Refresh,
    /// Add `inc` to the working counter at `at`.
    Wkc { at: u16, inc: u16 },
    /// Fused: a system time read or write and its working counter.
    SysFused(SysStep),
    /// Fused: ADP increment (if `adp` is not 0), difference read, working counter.
    DiffFused(DiffStep),
    /// Fused: an LRW through one write and one read FMMU with the application in between.
    LrwFused(LrwStep),
}

/// A system time read or write (FRMW of 0x0910) and its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct SysStep {
    at: u16,
    len: u8,
    write: bool,
    wkc: u16,
    inc: u16,
}

/// An ADP increment (if `adp` is not 0), a difference read (BRD of 0x092C), its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct DiffStep {
    adp: u16,
    at: u16,
    len: u8,
    or: bool,
    wkc: u16,
    inc: u16,
}

/// An LRW through one write and one read FMMU with the application in between.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct LrwStep {
    w_at: u16,
    w_ram: u16,
    w_len: u16,
    r_at: u16,
    r_ram: u16,
    r_len: u16,
    wkc: u16,
    inc: u16,
}

/// The cyclic frame's whole program at one ESC (system time, process data, time difference, in
/// this order; at the reference under bus shift, a system time write first), replayed straight
/// through: no dispatch per step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct CyclicSteps {
    /// Bus shift's write of the master's time to the reference, before its FRMW.
    pre: Option<SysStep>,
    sys: SysStep,
    lrw: LrwStep,
    diff: DiffStep,
    /// Where the three working counters and the BRD's position field are, packed (see
    /// [`Deferred`]).
    layout: u64,
}

impl CyclicSteps {
    fn new(pre: Option<SysStep>, sys: SysStep, lrw: LrwStep, diff: DiffStep) -> Self {
        let layout = u64::from(sys.wkc)
            | u64::from(lrw.wkc) << 16
            | u64::from(diff.wkc) << 32
            | u64::from(diff.adp) << 48;
        CyclicSteps {
            pre,
            sys,
            lrw,
            diff,
            layout,
        }
    }
}

/// Working counter and position (ADP) increments of cyclic replays, added to the frame once for
/// a run of consecutive slaves instead of once per slave.
///
/// This is exact: a replayed program never reads a working counter or an ADP, so only the sum
/// matters, and [`Deferred::flush`] runs before any slave that processes the frame in full
/// (which may read them) and at the end of the frame.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Deferred {
    layout: u64,
    sys: u16,
    lrw: u16,
    diff: u16,
    adp: u16,
}

impl Deferred {
    /// Adds the pending increments to the frame.
    #[inline(always)]
    pub(crate) fn flush(&mut self, frame: &mut [u8]) {
        if self.sys | self.lrw | self.diff | self.adp != 0 {
            let l = self.layout;
            add_wkc(frame, l as u16, self.sys);
            add_wkc(frame, (l >> 16) as u16, self.lrw);
            add_wkc(frame, (l >> 32) as u16, self.diff);
            add_wkc(frame, (l >> 48) as u16, self.adp);
        }
        *self = Deferred::default();
    }
}

/// Fuses the common sequences of a recorded program into single steps (fewer dispatches).
fn fuse(ops: &[Op], out: &mut [Op; MAX_OPS]) -> u8 {
    let mut n = 0usize;
    let mut i = 0usize;
    while i < ops.len() {
        let rest = &ops[i..];
        let (op, used) = match rest {
            [
                Op::SysRead { at, len, or: false },
                Op::Wkc { at: w, inc },
                ..,
            ] => (
                Op::SysFused(SysStep {
                    at: *at,
                    len: *len,
                    write: false,
                    wkc: *w,
                    inc: *inc,
                }),
                2,
            ),
            [Op::SysWrite { at, len }, Op::Wkc { at: w, inc }, ..] => (
                Op::SysFused(SysStep {
                    at: *at,
                    len: *len,
                    write: true,
                    wkc: *w,
                    inc: *inc,
                }),
                2,
            ),
            [
                Op::AdpInc { at: a },
                Op::DiffRead { at, len, or },
                Op::Wkc { at: w, inc },
                ..,
            ] => (
                Op::DiffFused(DiffStep {
                    adp: *a,
                    at: *at,
                    len: *len,
                    or: *or,
                    wkc: *w,
                    inc: *inc,
                }),
                3,
            ),
            [
                Op::ToRam {
                    at: wa,
                    ram: wr,
                    len: wl,
                },
                Op::Refresh,
                Op::FromRam {
                    at: ra,
                    ram: rr,
                    len: rl,
                },
                Op::Wkc { at: w, inc },
                ..,
            ] => (
                Op::LrwFused(LrwStep {
                    w_at: *wa,
                    w_ram: *wr,
                    w_len: *wl,
                    r_at: *ra,
                    r_ram: *rr,
                    r_len: *rl,
                    wkc: *w,
                    inc: *inc,
                }),
                4,
            ),
            [op, ..] => (*op, 1),
            [] => break,
        };
        out[n] = op;
        n += 1;
        i += used;
    }
    n as u8
}

#[inline]
fn add_wkc(frame: &mut [u8], at: u16, inc: u16) {
    let at = usize::from(at);
    let w = u16::from_le_bytes([frame[at], frame[at + 1]]).wrapping_add(inc);
    frame[at..at + 2].copy_from_slice(&w.to_le_bytes());
}

/// The system time read or write of a [`SysStep`], without its working counter.
#[inline(always)]
fn sys_access(dc: &mut DcUnit, frame: &mut [u8], s: &SysStep, t_ps: u64) {
    let (a, l) = (usize::from(s.at), usize::from(s.len));
    if s.write {
        dc.write_system_time(&frame[a..a + l], t_ps);
    } else {
        dc.read_fast(reg::DC_SYSTEM_TIME, &mut frame[a..a + l], false, t_ps);
    }
}

#[inline(always)]
fn sys_step(dc: &mut DcUnit, frame: &mut [u8], s: &SysStep, t_ps: u64) {
    sys_access(dc, frame, s, t_ps);
    add_wkc(frame, s.wkc, s.inc);
}

/// The time difference read of a [`DiffStep`], without its ADP and working counter.
#[inline(always)]
fn diff_access(dc: &DcUnit, frame: &mut [u8], d: &DiffStep) {
    let (a, l) = (usize::from(d.at), usize::from(d.len));
    dc.read_time_difference(&mut frame[a..a + l], d.or);
}

#[inline(always)]
fn diff_step(dc: &DcUnit, frame: &mut [u8], d: &DiffStep) {
    add_wkc(frame, d.adp, 1);
    diff_access(dc, frame, d);
    add_wkc(frame, d.wkc, d.inc);
}

/// The outputs of an [`LrwStep`]: frame -> process RAM.
#[inline(always)]
fn lrw_in(ram: &mut [u8], frame: &[u8], s: &LrwStep) {
    let (d, r, l) = (
        usize::from(s.w_at),
        usize::from(s.w_ram),
        usize::from(s.w_len),
    );
    copy_small(&mut ram[r..r + l], &frame[d..d + l]);
}

/// The inputs of an [`LrwStep`]: process RAM -> frame.
#[inline(always)]
fn lrw_out(frame: &mut [u8], ram: &[u8], s: &LrwStep) {
    let (d, r, l) = (
        usize::from(s.r_at),
        usize::from(s.r_ram),
        usize::from(s.r_len),
    );
    copy_small(&mut frame[d..d + l], &ram[r..r + l]);
}

/// The application (a loopback device): statusword, then the outputs echoed, then a cycle
/// counter, laid out as `l` says.
#[inline(always)]
fn refresh_inputs(ram: &mut [u8], l: AppLayout, al_state: u8, app_cycles: &mut u16) {
    let status: u16 = if al_state == al_state::OP {
        0x1237
    } else {
        0x0231
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

const MAX_PROGRAM_DATAGRAMS: usize = 8;
const MAX_PROGRAM_OPS: usize = 8;
const MAX_OPS: usize = 32;

/// The recorded steps for one frame shape.
#[derive(Debug, Clone, Copy)]
struct Program {
    shape: u32,
    generation: u64,
    ops: [Op; MAX_OPS],
    n: u8,
    counted: u8,
    /// `ops` as one straight-through step, when they are the cyclic frame's three.
    cyclic: Option<CyclicSteps>,
    /// Frames replayed by `cyclic` and not yet in the ESC's counters (one increment per frame
    /// instead of three; see [`Esc::stats`]).
    replays: u64,
}

impl Default for Program {
    fn default() -> Self {
        Program {
            shape: 0,
            generation: 0,
            ops: [Op::Nop; MAX_OPS],
            n: 0,
            counted: 0,
            cyclic: None,
            replays: 0,
        }
    }
}

impl Program {
    fn push(&mut self, op: Op) -> bool {
        if usize::from(self.n) < MAX_OPS {
            self.ops[usize::from(self.n)] = op;
            self.n += 1;
            true
        } else {
            false
        }
    }
}

/// The recorder for the datagram being processed.
#[derive(Debug, Clone, Copy, Default)]
struct Recorder {
    active: bool,
    cacheable: bool,
    act: Act,
    ops: [LogicalOp; MAX_PROGRAM_OPS],
    nops: u8,
}

impl Recorder {
    fn uncacheable(&mut self) {
        self.cacheable = false;
    }

    fn op(&mut self, op: LogicalOp) {
        if !self.active {
            return;
        }
        if usize::from(self.nops) < MAX_PROGRAM_OPS {
            self.ops[usize::from(self.nops)] = op;
            self.nops += 1;
        } else {
            self.cacheable = false;
        }
    }
}

/// The application's buffers in process RAM (see `Esc::app_layout`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct AppLayout {
    ib: usize,
    ob: usize,
    n: usize,
    tail: usize,
}

/// Counters of what an ESC saw, for diagnostics and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EscStats {
    /// Frames that passed the processing unit.
    pub frames: u64,
    /// Datagrams that addressed this ESC (changed the working counter).
    pub datagrams_counted: u64,
    /// Frames whose datagrams were replayed from a recorded program.
    pub replayed_frames: u64,
}

/// A virtual ESC.
#[derive(Debug, Clone)]
pub struct Esc {
    model: EscModel,
    regs: Box<[u8; REG_SPACE]>,
    attr: Box<[u8; REG_SPACE]>,
    ram: Box<[u8]>,
    dc: Option<DcUnit>,
    dc_block: Box<[u8; DC_BLOCK_LEN]>,
    sii: SiiState,
    al_state: u8,
    al_error: bool,
    al_code: u16,
    fmmus: [Fmmu; 16],
    /// Indices of active FMMUs with write / read enabled, lowest first.
    fmmu_writers: ([u8; 16], u8),
    fmmu_readers: ([u8; 16], u8),
    sms: [SyncManager; 16],
    link: [bool; 4],
    loop_mode: [LoopMode; 4],
    output_sm: Option<usize>,
    input_sm: Option<usize>,
    app: Option<AppLayout>,
    app_cycles: u16,
    stats: EscStats,
    device: DeviceInfo,
    /// Bumped by every change that could make a datagram act differently (register writes,
    /// state changes); a recorded program is valid only for the generation it was recorded in.
    generation: u64,
    program: Program,
    rec: Recorder,
}

/// Side effects of processing one datagram that the segment must act on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DatagramEffects {
    /// Latch receive times of this frame (a write to 0x0900).
    pub latch_receive_times: bool,
    /// Loop settings changed (DL control written).
    pub loops_changed: bool,
}

/// Copies a few dozen bytes without a call into `memcpy`: the process data of one slave in the
/// replayed cyclic frame. Lengths up to 32 bytes take two overlapping word copies (the head and
/// the tail of the range), longer ones `copy_from_slice`.
#[inline]
fn copy_small(dst: &mut [u8], src: &[u8]) {
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

fn ranges_overlap(lo: usize, hi: usize, a: usize, len: usize) -> bool {
    lo < a + len && a < hi
}

impl Esc {
    /// Powers up an ESC: loads the SII image (identity, alias, pulse length) and starts its clock.
    pub fn new(model: EscModel, device: DeviceInfo, crystal: CrystalParams) -> Self {
        let image = sii_image::build(&model, &device);
        let mut esc = Esc {
            regs: Box::new([0; REG_SPACE]),
            attr: Box::new([0; REG_SPACE]),
            ram: vec![0; usize::from(model.ram_kib) * 1024].into_boxed_slice(),
            dc: model.dc.has_receive_times().then(|| {
                DcUnit::new(DcParams {
                    crystal,
                    is_64bit: model.dc == DcSupport::Full64,
                    sof_resolution_ns: model.ports[0].stamp_resolution_ns(),
                })
            }),
            dc_block: Box::new([0; DC_BLOCK_LEN]),
            sii: SiiState {
                image,
                busy_until_ps: 0,
                pending_read: None,
                read_busy_ps: (model.sii_read_busy_us * 1e6) as u64,
            },
            al_state: al_state::INIT,
            al_error: false,
            al_code: 0,
            fmmus: [Fmmu::default(); 16],
            fmmu_writers: ([0; 16], 0),
            fmmu_readers: ([0; 16], 0),
            sms: [SyncManager::default(); 16],
            link: [false; 4],
            loop_mode: [LoopMode::Auto; 4],
            output_sm: None,
            input_sm: None,
            app: None,
            app_cycles: 0,
            stats: EscStats::default(),
            model,
            device,
            generation: 0,
            program: Program::default(),
            rec: Recorder::default(),
        };
        esc.build_attributes();
        esc.reset_registers();
        esc
    }

    fn mark(&mut self, addr: u16, len: u16, bits: u8) {
        for a in addr..addr + len {
            self.attr[usize::from(a)] = bits;
        }
    }

    /// Which registers exist and which the EtherCAT side may write (datasheet section II).
    fn build_attributes(&mut self) {
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
        for n in 0..u16::from(self.model.fmmu_count.min(16)) {
            self.mark(reg::FMMU_BASE + n * reg::FMMU_LEN, reg::FMMU_LEN, rw);
        }
        for n in 0..u16::from(self.model.sm_count.min(16)) {
            let base = reg::SM_BASE + n * reg::SM_LEN;
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

    fn put_u16(&mut self, addr: u16, v: u16) {
        let a = usize::from(addr);
        self.regs[a..a + 2].copy_from_slice(&v.to_le_bytes());
    }

    fn get_u16(&self, addr: u16) -> u16 {
        let a = usize::from(addr);
        u16::from_le_bytes([self.regs[a], self.regs[a + 1]])
    }

    fn reset_registers(&mut self) {
        self.regs[usize::from(reg::TYPE)] = self.model.esc_type;
        self.regs[usize::from(reg::REVISION)] = self.model.revision;
        self.put_u16(reg::BUILD, self.model.build);
        self.regs[usize::from(reg::FMMU_COUNT)] = self.model.fmmu_count;
        self.regs[usize::from(reg::SM_COUNT)] = self.model.sm_count;
        self.regs[usize::from(reg::RAM_SIZE)] = self.model.ram_kib;
        self.regs[usize::from(reg::PORT_DESCRIPTOR)] = self.model.port_descriptor();
        self.put_u16(reg::FEATURES, self.model.features());
        let img = &self.sii.image;
        let word = |w: usize| u16::from_le_bytes([img[2 * w], img[2 * w + 1]]);
        let (w0, w1, w2, alias) = (word(0), word(1), word(2), word(4));
        self.put_u16(reg::STATION_ALIAS, alias);
        let dl_control: u32 = 0x0007_0001;
        self.regs[0x100..0x104].copy_from_slice(&dl_control.to_le_bytes());
        self.put_u16(reg::PDI_CONTROL, w0);
        self.put_u16(0x0150, w1);
        self.put_u16(reg::SII_CONTROL, sii_control::READ_SIZE_8);
        self.put_u16(reg::AL_CONTROL, u16::from(al_state::INIT));
        if let Some(dc) = &mut self.dc {
            // Pulse length is loaded from SII word 2 into 0x0982 (read-only from ECAT).
            dc.write(reg::DC_PULSE_LENGTH, &w2.to_le_bytes(), 0);
        }
        self.update_al_registers();
        self.update_dl_status();
    }

    /// The ESC model.
    pub fn model(&self) -> &EscModel {
        &self.model
    }

    /// The device description.
    pub fn device(&self) -> &DeviceInfo {
        &self.device
    }

    /// The SII image.
    pub fn sii_image(&self) -> &[u8] {
        &self.sii.image
    }

    /// The DC unit, if the ESC has one.
    pub fn dc(&self) -> Option<&DcUnit> {
        self.dc.as_ref()
    }

    /// Mutable DC unit.
    pub fn dc_mut(&mut self) -> Option<&mut DcUnit> {
        self.dc.as_mut()
    }

    /// Current AL state (1, 2, 4 or 8).
    pub fn al_state(&self) -> u8 {
        self.al_state
    }

    /// Configured station address.
    pub fn station_address(&self) -> u16 {
        self.get_u16(reg::STATION_ADDRESS)
    }

    /// Counters.
    pub fn stats(&self) -> EscStats {
        let mut s = self.stats;
        let p = &self.program;
        s.frames += p.replays;
        s.replayed_frames += p.replays;
        s.datagrams_counted += p.replays * u64::from(p.counted);
        s
    }

    /// Sets which ports have a physical link (done once by the segment).
    pub fn set_links(&mut self, link: [bool; 4]) {
        self.generation += 1;
        self.link = link;
        self.update_dl_status();
    }

    /// Whether a frame leaves through port `p` (link and loop open) rather than looping back.
    /// `Err(())` if the port is forced open without a link: the frame is lost there.
    #[allow(clippy::result_unit_err)]
    pub fn port_forwards(&self, p: usize) -> Result<bool, ()> {
        if self.model.ports[p] == crate::model::PortKind::None {
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

    fn update_dl_status(&mut self) {
        let mut s = dl_status::PDI_OPERATIONAL | dl_status::PDI_WATCHDOG;
        for p in 0..4 {
            if self.model.ports[p] == crate::model::PortKind::None {
                s |= dl_status::loop_closed(p);
                continue;
            }
            if self.link[p] {
                s |= dl_status::link(p) | dl_status::communication(p);
            }
            if !matches!(self.port_forwards(p), Ok(true)) {
                s |= dl_status::loop_closed(p);
            }
        }
        self.put_u16(reg::DL_STATUS, s);
    }

    fn update_al_registers(&mut self) {
        let status = u16::from(self.al_state)
            | if self.al_error {
                al_state::ERROR_FLAG
            } else {
                0
            };
        self.put_u16(reg::AL_STATUS, status);
        self.put_u16(reg::AL_STATUS_CODE, self.al_code);
    }

    /// Handles a write to AL control: the transitions of the datasheet's state machine (figure
    /// "EtherCAT State Machine"), with the status codes of ETG.1020.
    fn request_state(&mut self, control: u16) {
        self.generation += 1;
        let requested = (control & 0x0f) as u8;
        let ack = control & al_state::ERROR_FLAG != 0;
        if self.al_error && !ack && requested != al_state::INIT {
            return; // an unacknowledged error blocks new requests
        }
        if ack || requested == al_state::INIT {
            self.al_error = false;
            self.al_code = al_status_code::NO_ERROR;
        }
        use al_state::*;
        let from = self.al_state;
        let fail = |esc: &mut Esc, code: u16| {
            esc.al_error = true;
            esc.al_code = code;
        };
        match requested {
            INIT | PRE_OP | SAFE_OP | OP => {}
            BOOTSTRAP => {
                fail(self, al_status_code::BOOTSTRAP_NOT_SUPPORTED);
                self.update_al_registers();
                return;
            }
            _ => {
                fail(self, al_status_code::UNKNOWN_STATE);
                self.update_al_registers();
                return;
            }
        }
        let valid = from == requested
            || matches!(
                (from, requested),
                (INIT, PRE_OP)
                    | (PRE_OP, INIT)
                    | (PRE_OP, SAFE_OP)
                    | (SAFE_OP, PRE_OP)
                    | (SAFE_OP, INIT)
                    | (SAFE_OP, OP)
                    | (OP, SAFE_OP)
                    | (OP, PRE_OP)
                    | (OP, INIT)
            );
        if !valid {
            fail(self, al_status_code::INVALID_STATE_CHANGE);
        } else if from == PRE_OP && requested == SAFE_OP {
            match self.check_process_data_config() {
                Ok(()) => self.al_state = requested,
                Err(code) => fail(self, code),
            }
        } else {
            self.al_state = requested;
        }
        if self.al_state < SAFE_OP {
            self.output_sm = None;
            self.input_sm = None;
            self.app = None;
        }
        self.update_al_registers();
    }

    /// PRE-OP -> SAFE-OP: the process data SyncManagers must be configured as the SII describes
    /// (the application's check; a wrong length gives "invalid output/input configuration").
    fn check_process_data_config(&mut self) -> Result<(), u16> {
        let out_len = self.device.output_bytes() as u16;
        let in_len = self.device.input_bytes() as u16;
        let find = |esc: &Esc, start: u16, ecat_writes: bool| {
            esc.sms
                .iter()
                .take(usize::from(esc.model.sm_count))
                .position(|s| s.enabled && s.start == start && s.ecat_writes == ecat_writes)
        };
        let out = if out_len > 0 {
            let i = find(self, sii_image::SM_OUTPUT_START, true)
                .ok_or(al_status_code::INVALID_OUTPUT_CONFIG)?;
            if self.sms[i].len != out_len {
                return Err(al_status_code::INVALID_OUTPUT_CONFIG);
            }
            Some(i)
        } else {
            None
        };
        let inp = if in_len > 0 {
            let i = find(self, sii_image::SM_INPUT_START, false)
                .ok_or(al_status_code::INVALID_INPUT_CONFIG)?;
            if self.sms[i].len != in_len {
                return Err(al_status_code::INVALID_INPUT_CONFIG);
            }
            Some(i)
        } else {
            None
        };
        self.output_sm = out;
        self.input_sm = inp;
        self.app = self.app_layout();
        Ok(())
    }

    /// Completes an EEPROM command whose busy time has elapsed.
    fn sii_update(&mut self, t_ps: u64) {
        if let Some(addr) = self.sii.pending_read {
            if t_ps >= self.sii.busy_until_ps {
                self.generation += 1;
                let at = addr as usize * 2;
                for i in 0..8 {
                    self.regs[usize::from(reg::SII_DATA) + i] =
                        self.sii.image.get(at + i).copied().unwrap_or(0xff);
                }
                self.sii.pending_read = None;
                let c = self.get_u16(reg::SII_CONTROL)
                    & !(sii_control::BUSY | sii_control::COMMAND_MASK);
                self.put_u16(reg::SII_CONTROL, c);
            }
        }
    }

    fn sii_control_written(&mut self, written: u16, t_ps: u64) {
        let status_bits = sii_control::READ_SIZE_8;
        let mut c = status_bits | (self.get_u16(reg::SII_CONTROL) & 0xf800 & !sii_control::BUSY);
        match written & sii_control::COMMAND_MASK {
            0 => c &= !(sii_control::COMMAND_ERROR | sii_control::WRITE_ENABLE_ERROR),
            sii_control::CMD_READ => {
                let addr = u32::from_le_bytes([
                    self.regs[0x504],
                    self.regs[0x505],
                    self.regs[0x506],
                    self.regs[0x507],
                ]);
                self.sii.pending_read = Some(addr);
                self.sii.busy_until_ps = t_ps + self.sii.read_busy_ps;
                c |= sii_control::BUSY | sii_control::CMD_READ;
            }
            sii_control::CMD_WRITE => {
                if written & sii_control::WRITE_ENABLE == 0 {
                    c |= sii_control::WRITE_ENABLE_ERROR;
                } else {
                    let addr = u32::from_le_bytes([
                        self.regs[0x504],
                        self.regs[0x505],
                        self.regs[0x506],
                        self.regs[0x507],
                    ]) as usize;
                    if addr * 2 + 1 < self.sii.image.len() {
                        self.sii.image[addr * 2] = self.regs[0x508];
                        self.sii.image[addr * 2 + 1] = self.regs[0x509];
                    } else {
                        c |= sii_control::COMMAND_ERROR;
                    }
                }
            }
            sii_control::CMD_RELOAD => {}
            _ => c |= sii_control::COMMAND_ERROR,
        }
        self.sii_update(t_ps);
        if self.sii.pending_read.is_none() {
            c &= !(sii_control::BUSY | sii_control::COMMAND_MASK);
        }
        self.put_u16(reg::SII_CONTROL, c);
    }

    fn parse_fmmus(&mut self) {
        for n in 0..usize::from(self.model.fmmu_count.min(16)) {
            let b = &self.regs[0x600 + 16 * n..0x600 + 16 * n + 16];
            let active = b[12] & 1 != 0;
            self.fmmus[n] = Fmmu {
                logical: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                len: if active {
                    u16::from_le_bytes([b[4], b[5]])
                } else {
                    0
                },
                physical: u16::from_le_bytes([b[8], b[9]]),
                read: active && b[11] & 1 != 0,
                write: active && b[11] & 2 != 0,
            };
        }
        self.fmmu_writers.1 = 0;
        self.fmmu_readers.1 = 0;
        for n in 0..usize::from(self.model.fmmu_count.min(16)) {
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

    fn parse_sms(&mut self) {
        self.app = None;
        for n in 0..usize::from(self.model.sm_count.min(16)) {
            let b = &self.regs[0x800 + 8 * n..0x800 + 8 * n + 8];
            self.sms[n] = SyncManager {
                start: u16::from_le_bytes([b[0], b[1]]),
                len: u16::from_le_bytes([b[2], b[3]]),
                ecat_writes: (b[4] >> 2) & 0b11 == 0b01,
                enabled: b[6] & 1 != 0,
            };
        }
        if self.input_sm.is_some() {
            self.app = self.app_layout();
        }
    }

    fn parse_dl_control(&mut self) {
        for p in 0..4 {
            self.loop_mode[p] = match (self.regs[0x101] >> (2 * p)) & 0b11 {
                0b00 => LoopMode::Auto,
                0b01 => LoopMode::AutoClose,
                0b10 => LoopMode::Open,
                _ => LoopMode::Closed,
            };
        }
        self.update_dl_status();
    }

    fn alias_enabled(&self) -> bool {
        self.regs[0x103] & 0x01 != 0
    }

    /// Reads physical memory into `out`; returns whether the access counts (at least one byte
    /// exists). Bytes that do not exist leave `out` unchanged. With `or`, data is ORed (BRD).
    fn read_physical(&mut self, ado: u16, out: &mut [u8], or: bool, t_ps: u64) -> bool {
        // The cyclic frame's DC reads (system time, time difference) skip the register shadow.
        if (ado == reg::DC_SYSTEM_TIME || ado == reg::DC_SYSTEM_TIME_DIFF)
            && self.attr[usize::from(ado)] & EXISTS != 0
        {
            if let Some(dc) = &mut self.dc {
                if dc.read_fast(ado, out, or, t_ps) {
                    self.rec.act = if ado == reg::DC_SYSTEM_TIME {
                        Act::SysTimeRead { or }
                    } else {
                        Act::DiffRead { or }
                    };
                    return true;
                }
            }
        }
        self.rec.uncacheable();
        let lo = usize::from(ado);
        let hi = lo + out.len();
        let mut counted = false;
        if lo < REG_SPACE {
            let rhi = hi.min(REG_SPACE);
            if ranges_overlap(lo, rhi, usize::from(DC_BLOCK_START), DC_BLOCK_LEN) {
                if let Some(dc) = &mut self.dc {
                    let (a, b) = (
                        lo.max(usize::from(DC_BLOCK_START)),
                        rhi.min(usize::from(DC_BLOCK_START) + DC_BLOCK_LEN),
                    );
                    dc.refresh(&mut self.dc_block, a as u16, b as u16, t_ps);
                    self.regs[a..b].copy_from_slice(
                        &self.dc_block
                            [a - usize::from(DC_BLOCK_START)..b - usize::from(DC_BLOCK_START)],
                    );
                }
            }
            if ranges_overlap(lo, rhi, 0x502, 14) {
                self.sii_update(t_ps);
            }
            if ranges_overlap(lo, rhi, usize::from(sii_image::SM_INPUT_START), 1)
                || ranges_overlap(lo, rhi, 0x1000, 0)
            {
                // (process RAM is handled below)
            }
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
            let start = lo.max(REG_SPACE);
            let end = hi.min(REG_SPACE + self.ram.len());
            if start < end {
                counted = true;
                let src = &self.ram[start - REG_SPACE..end - REG_SPACE];
                let dst = &mut out[start - lo..end - lo];
                if or {
                    dst.iter_mut().zip(src).for_each(|(d, s)| *d |= *s);
                } else {
                    dst.copy_from_slice(src);
                }
            }
        }
        counted
    }

    /// Writes `data` to physical memory; returns whether the access counts (at least one byte
    /// writable) and what the segment must do.
    fn write_physical(
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
        {
            if let Some(dc) = &mut self.dc {
                // (The register shadow of 0x0910 is refreshed from the clock on every read.)
                dc.write_system_time(data, t_ps);
                self.rec.act = Act::SysTimeWrite;
                return true;
            }
        }
        self.rec.uncacheable();
        self.generation += 1;
        let lo = usize::from(ado);
        let hi = lo + data.len();
        let mut counted = false;
        if lo < REG_SPACE {
            let rhi = hi.min(REG_SPACE);
            // While the EEPROM interface is busy its registers are write-protected.
            self.sii_update(t_ps);
            let sii_busy = self.sii.pending_read.is_some();
            let al_control_before = self.get_u16(reg::AL_CONTROL);
            for (i, a) in (lo..rhi).enumerate() {
                if self.attr[a] & WRITABLE != 0 {
                    counted = true;
                    if sii_busy && (0x502..0x510).contains(&a) {
                        continue;
                    }
                    self.regs[a] = data[i];
                }
            }
            if !counted {
                return hi > REG_SPACE && self.write_ram(lo, hi, data);
            }
            if ranges_overlap(lo, rhi, usize::from(DC_BLOCK_START), DC_BLOCK_LEN) {
                if let Some(dc) = &mut self.dc {
                    let (a, b) = (
                        lo.max(usize::from(DC_BLOCK_START)),
                        rhi.min(usize::from(DC_BLOCK_START) + DC_BLOCK_LEN),
                    );
                    let e = dc.write(a as u16, &data[a - lo..b - lo], t_ps);
                    fx.latch_receive_times |= e.latch_receive_times;
                }
            }
            if ranges_overlap(lo, rhi, usize::from(reg::AL_CONTROL), 2) {
                let v = self.get_u16(reg::AL_CONTROL);
                let _ = al_control_before;
                self.request_state(v);
            }
            if ranges_overlap(lo, rhi, 0x502, 2) && !sii_busy {
                let v = self.get_u16(reg::SII_CONTROL);
                // Only the command and write-enable bits are the master's; the rest is status.
                let written = u16::from_le_bytes([
                    if lo <= 0x502 { data[0x502 - lo] } else { 0 },
                    if lo <= 0x503 && rhi > 0x503 {
                        data[0x503 - lo]
                    } else {
                        (v >> 8) as u8
                    },
                ]);
                self.sii_control_written(written, t_ps);
            }
            if ranges_overlap(lo, rhi, 0x600, 0x100) {
                self.parse_fmmus();
            }
            if ranges_overlap(lo, rhi, 0x800, 0x80) {
                self.parse_sms();
            }
            if ranges_overlap(lo, rhi, 0x100, 4) {
                self.parse_dl_control();
                fx.loops_changed = true;
            }
            if ranges_overlap(lo, rhi, usize::from(reg::RX_ERROR_COUNTER), 0x0c) {
                self.regs[0x300..0x30c].fill(0);
            }
        }
        if hi > REG_SPACE {
            counted |= self.write_ram(lo, hi, data);
        }
        counted
    }

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

    /// Whether the SyncManager covering physical `addr` lets the process data through in the
    /// current state. The virtual application enables the input SyncManager from SAFE-OP on and
    /// the output SyncManager in OP only, as slave stacks do (outputs are ignored in SAFE-OP), so
    /// the working counter of an LRW is 3 per slave in OP and 1 in SAFE-OP.
    fn sm_allows(&self, addr: u16, write: bool) -> bool {
        let sm = if write { self.output_sm } else { self.input_sm };
        match sm {
            Some(i) => {
                let s = self.sms[i];
                let inside = addr >= s.start && addr < s.start.saturating_add(s.len);
                inside && (!write || self.al_state == al_state::OP)
            }
            None => {
                // Not a process data SyncManager area: plain memory.
                !self
                    .sms
                    .iter()
                    .take(usize::from(self.model.sm_count))
                    .any(|s| s.enabled && addr >= s.start && addr < s.start.saturating_add(s.len))
            }
        }
    }

    /// The application: refreshes the inputs from the outputs before a read of the input buffer
    /// (a loopback device: statusword, then the outputs echoed, then a cycle counter).
    #[inline(always)]
    fn app_refresh_inputs(&mut self) {
        if let Some(l) = self.app {
            refresh_inputs(&mut self.ram, l, self.al_state, &mut self.app_cycles);
            return;
        }
        self.app_refresh_slow();
    }

    /// Where the application's echo goes, when the buffers allow the fast copy (the output
    /// buffer before the input buffer, as the SII lays them out).
    fn app_layout(&self) -> Option<AppLayout> {
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
        Some(AppLayout {
            ib,
            ob,
            n,
            tail: ib + ilen - 2,
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
        let status: u16 = if self.al_state == al_state::OP {
            0x1237
        } else {
            0x0231
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
        self.app_cycles = self.app_cycles.wrapping_add(1);
        let tail = ib + ilen - 2;
        if tail >= ib + 2 {
            self.ram[tail..tail + 2].copy_from_slice(&self.app_cycles.to_le_bytes());
        }
    }

    /// LRD/LWR/LRW through the FMMUs. Returns the working counter increment.
    fn logical(&mut self, cmd: Command, laddr: u32, data: &mut [u8]) -> u16 {
        self.rec.act = Act::Logical { start: 0, count: 0 };
        let len = data.len() as u64;
        let lstart = u64::from(laddr);
        let mut read_hit = false;
        let mut write_hit = false;
        if cmd.writes() {
            for k in 0..usize::from(self.fmmu_writers.1) {
                let f = self.fmmus[usize::from(self.fmmu_writers.0[k])];
                let (fs, fe) = (
                    u64::from(f.logical),
                    u64::from(f.logical) + u64::from(f.len),
                );
                let (s, e) = (lstart.max(fs), (lstart + len).min(fe));
                if s >= e {
                    continue;
                }
                let phys = u64::from(f.physical) + (s - fs);
                if phys < REG_SPACE as u64 || !self.sm_allows(phys as u16, true) {
                    continue;
                }
                let r0 = phys as usize - REG_SPACE;
                let n_bytes = (e - s) as usize;
                if r0 + n_bytes <= self.ram.len() {
                    self.ram[r0..r0 + n_bytes]
                        .copy_from_slice(&data[(s - lstart) as usize..(e - lstart) as usize]);
                    write_hit = true;
                    self.rec.op(LogicalOp::Write {
                        data_off: (s - lstart) as u16,
                        ram_off: r0 as u16,
                        len: n_bytes as u16,
                    });
                }
            }
        }
        if cmd.reads() {
            let mut refreshed = false;
            for k in 0..usize::from(self.fmmu_readers.1) {
                let f = self.fmmus[usize::from(self.fmmu_readers.0[k])];
                let (fs, fe) = (
                    u64::from(f.logical),
                    u64::from(f.logical) + u64::from(f.len),
                );
                let (s, e) = (lstart.max(fs), (lstart + len).min(fe));
                if s >= e {
                    continue;
                }
                let phys = u64::from(f.physical) + (s - fs);
                if phys < REG_SPACE as u64 || !self.sm_allows(phys as u16, false) {
                    continue;
                }
                if !refreshed {
                    self.app_refresh_inputs();
                    refreshed = true;
                    self.rec.op(LogicalOp::Refresh);
                }
                let r0 = phys as usize - REG_SPACE;
                let n_bytes = (e - s) as usize;
                if r0 + n_bytes <= self.ram.len() {
                    data[(s - lstart) as usize..(e - lstart) as usize]
                        .copy_from_slice(&self.ram[r0..r0 + n_bytes]);
                    read_hit = true;
                    self.rec.op(LogicalOp::Read {
                        data_off: (s - lstart) as u16,
                        ram_off: r0 as u16,
                        len: n_bytes as u16,
                    });
                }
            }
        }
        match cmd {
            Command::Lrd => u16::from(read_hit),
            Command::Lwr => u16::from(write_hit),
            _ => u16::from(read_hit) + 2 * u16::from(write_hit),
        }
    }

    /// Processes one datagram as it passes the processing unit in a frame whose first bit
    /// reached the unit at `t_ps`. `dg` is the whole datagram (header, data, working counter);
    /// its length must already have been validated.
    pub fn process_datagram(&mut self, dg: &mut [u8], t_ps: u64) -> DatagramEffects {
        let mut fx = DatagramEffects::default();
        let Ok(cmd) = Command::from_code(dg[0]) else {
            return fx;
        };
        let adp = u16::from_le_bytes([dg[2], dg[3]]);
        let ado = u16::from_le_bytes([dg[4], dg[5]]);
        let n = usize::from(u16::from_le_bytes([dg[6], dg[7]]) & 0x07ff);
        let (head, rest) = dg.split_at_mut(DATAGRAM_HEADER_LEN);
        let (data, wkc_bytes) = rest.split_at_mut(n);
        let mut inc: u16 = 0;
        use ecsync_wire::AddressMode;
        match cmd.address_mode() {
            AddressMode::None => {}
            AddressMode::Position | AddressMode::Broadcast => {
                head[2..4].copy_from_slice(&adp.wrapping_add(1).to_le_bytes());
                let addressed = cmd.address_mode() == AddressMode::Broadcast || adp == 0;
                match cmd {
                    Command::Armw => {
                        inc = if adp == 0 {
                            u16::from(self.read_physical(ado, data, false, t_ps))
                        } else {
                            u16::from(self.write_physical(ado, data, t_ps, &mut fx))
                        };
                    }
                    _ if addressed => inc = self.physical(cmd, ado, data, t_ps, &mut fx),
                    _ => {}
                }
            }
            AddressMode::Configured => {
                let me = adp == self.station_address()
                    || (self.alias_enabled() && adp == self.get_u16(reg::STATION_ALIAS));
                if cmd == Command::Frmw {
                    inc = if me {
                        u16::from(self.read_physical(ado, data, false, t_ps))
                    } else {
                        u16::from(self.write_physical(ado, data, t_ps, &mut fx))
                    };
                } else if me {
                    inc = self.physical(cmd, ado, data, t_ps, &mut fx);
                }
            }
            AddressMode::Logical => {
                let laddr = u32::from_le_bytes([head[2], head[3], head[4], head[5]]);
                if self.model.features() & reg::features::NO_LRW != 0 && cmd == Command::Lrw {
                    // not supported
                } else {
                    inc = self.logical(cmd, laddr, data);
                }
            }
        }
        if inc > 0 {
            self.stats.datagrams_counted += 1;
            let wkc = u16::from_le_bytes([wkc_bytes[0], wkc_bytes[1]]).wrapping_add(inc);
            wkc_bytes.copy_from_slice(&wkc.to_le_bytes());
        }
        fx
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
        if shape != 0 && self.program.shape == shape && self.program.generation == self.generation {
            self.replay(frame, t_ps);
            return DatagramEffects::default();
        }
        self.process_frame_full(frame, offsets, shape, t_ps)
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
        let record = shape != 0 && offsets.len() <= MAX_PROGRAM_DATAGRAMS;
        let generation = self.generation;
        let mut prog = Program {
            shape,
            generation,
            ..Program::default()
        };
        let mut ok = record;
        let mut out = DatagramEffects::default();
        for &at in offsets {
            let at = usize::from(at);
            let n = usize::from(u16::from_le_bytes([frame[at + 6], frame[at + 7]]) & 0x07ff);
            let total = ecsync_wire::DATAGRAM_OVERHEAD + n;
            self.rec = Recorder {
                active: ok,
                cacheable: true,
                ..Recorder::default()
            };
            let wkc_at = at + DATAGRAM_HEADER_LEN + n;
            let wkc_before = u16::from_le_bytes([frame[wkc_at], frame[wkc_at + 1]]);
            let fx = self.process_datagram(&mut frame[at..at + total], t_ps);
            out.latch_receive_times |= fx.latch_receive_times;
            out.loops_changed |= fx.loops_changed;
            if !ok {
                continue;
            }
            if !self.rec.cacheable {
                ok = false;
                continue;
            }
            let wkc_after = u16::from_le_bytes([frame[wkc_at], frame[wkc_at + 1]]);
            let data = (at + DATAGRAM_HEADER_LEN) as u16;
            let mode = Command::from_code(frame[at]).ok().map(|c| c.address_mode());
            let mut pushed = true;
            if matches!(
                mode,
                Some(ecsync_wire::AddressMode::Position | ecsync_wire::AddressMode::Broadcast)
            ) {
                pushed &= prog.push(Op::AdpInc { at: at as u16 + 2 });
            }
            let len = n.min(8) as u8;
            match self.rec.act {
                Act::None => {}
                Act::SysTimeRead { or } => pushed &= prog.push(Op::SysRead { at: data, len, or }),
                Act::SysTimeWrite => pushed &= prog.push(Op::SysWrite { at: data, len }),
                Act::DiffRead { or } => pushed &= prog.push(Op::DiffRead { at: data, len, or }),
                Act::Logical { .. } => {
                    for op in &self.rec.ops[..usize::from(self.rec.nops)] {
                        pushed &= prog.push(match *op {
                            LogicalOp::Refresh => Op::Refresh,
                            LogicalOp::Write {
                                data_off,
                                ram_off,
                                len,
                            } => Op::ToRam {
                                at: data + data_off,
                                ram: ram_off,
                                len,
                            },
                            LogicalOp::Read {
                                data_off,
                                ram_off,
                                len,
                            } => Op::FromRam {
                                at: data + data_off,
                                ram: ram_off,
                                len,
                            },
                        });
                    }
                }
            }
            let inc = wkc_after.wrapping_sub(wkc_before);
            if inc != 0 {
                pushed &= prog.push(Op::Wkc {
                    at: wkc_at as u16,
                    inc,
                });
                prog.counted += 1;
            }
            ok &= pushed;
        }
        self.rec = Recorder::default();
        if ok && self.generation == generation {
            // The replays of the program replaced go into the counters.
            self.stats = self.stats();
            let raw = prog.ops;
            prog.n = fuse(&raw[..usize::from(prog.n)], &mut prog.ops);
            prog.cyclic = match prog.ops[..usize::from(prog.n)] {
                [Op::SysFused(sys), Op::LrwFused(lrw), Op::DiffFused(diff)] => {
                    Some(CyclicSteps::new(None, sys, lrw, diff))
                }
                [
                    Op::SysFused(pre),
                    Op::SysFused(sys),
                    Op::LrwFused(lrw),
                    Op::DiffFused(diff),
                ] => Some(CyclicSteps::new(Some(pre), sys, lrw, diff)),
                _ => None,
            };
            self.program = prog;
        }
        out
    }

    /// Replays the recorded program op by op (the segment's straight-through replay,
    /// [`Esc::replay_cyclic`], takes the cyclic frame before it gets here).
    fn replay(&mut self, frame: &mut [u8], t_ps: u64) {
        self.stats.replayed_frames += 1;
        self.stats.datagrams_counted += u64::from(self.program.counted);
        self.replay_ops(frame, t_ps);
    }

    fn replay_ops(&mut self, frame: &mut [u8], t_ps: u64) {
        for k in 0..usize::from(self.program.n) {
            match self.program.ops[k] {
                Op::Nop => {}
                Op::AdpInc { at } => {
                    let at = usize::from(at);
                    let adp = u16::from_le_bytes([frame[at], frame[at + 1]]).wrapping_add(1);
                    frame[at..at + 2].copy_from_slice(&adp.to_le_bytes());
                }
                Op::SysRead { at, len, or } => {
                    let at = usize::from(at);
                    if let Some(dc) = &mut self.dc {
                        dc.read_fast(
                            reg::DC_SYSTEM_TIME,
                            &mut frame[at..at + usize::from(len)],
                            or,
                            t_ps,
                        );
                    }
                }
                Op::DiffRead { at, len, or } => {
                    let at = usize::from(at);
                    if let Some(dc) = &mut self.dc {
                        dc.read_fast(
                            reg::DC_SYSTEM_TIME_DIFF,
                            &mut frame[at..at + usize::from(len)],
                            or,
                            t_ps,
                        );
                    }
                }
                Op::SysWrite { at, len } => {
                    let (at, len) = (usize::from(at), usize::from(len));
                    if let Some(dc) = &mut self.dc {
                        dc.write_system_time(&frame[at..at + len], t_ps);
                    }
                }
                Op::ToRam { at, ram, len } => {
                    let (d, r, l) = (usize::from(at), usize::from(ram), usize::from(len));
                    copy_small(&mut self.ram[r..r + l], &frame[d..d + l]);
                }
                Op::FromRam { at, ram, len } => {
                    let (d, r, l) = (usize::from(at), usize::from(ram), usize::from(len));
                    copy_small(&mut frame[d..d + l], &self.ram[r..r + l]);
                }
                Op::Refresh => self.app_refresh_inputs(),
                Op::Wkc { at, inc } => add_wkc(frame, at, inc),
                Op::SysFused(s) => {
                    if let Some(dc) = &mut self.dc {
                        sys_step(dc, frame, &s, t_ps);
                    } else {
                        add_wkc(frame, s.wkc, s.inc);
                    }
                }
                Op::DiffFused(d) => {
                    if let Some(dc) = &self.dc {
                        diff_step(dc, frame, &d);
                    } else {
                        add_wkc(frame, d.adp, 1);
                        add_wkc(frame, d.wkc, d.inc);
                    }
                }
                Op::LrwFused(l) => {
                    lrw_in(&mut self.ram, frame, &l);
                    self.app_refresh_inputs();
                    lrw_out(frame, &self.ram, &l);
                    add_wkc(frame, l.wkc, l.inc);
                }
            }
        }
    }

    /// The cyclic frame at this ESC, if it has the three-step program for `shape` recorded in
    /// the current generation: the steps run, their working counter and ADP increments go to
    /// `d` (see [`Deferred`]). Returns false, touching nothing, otherwise; the caller then
    /// flushes `d` and calls [`Esc::process_frame`].
    #[inline(always)]
    pub(crate) fn replay_cyclic(
        &mut self,
        frame: &mut [u8],
        shape: u32,
        t_ps: u64,
        d: &mut Deferred,
    ) -> bool {
        let Esc {
            program,
            dc,
            ram,
            app,
            al_state,
            app_cycles,
            generation,
            ..
        } = self;
        if shape == 0 || program.shape != shape || program.generation != *generation {
            return false;
        }
        let (Some(c), Some(dc), Some(app)) = (&program.cyclic, dc.as_mut(), app.as_ref()) else {
            return false;
        };
        program.replays += 1;
        if c.layout != d.layout {
            d.flush(frame);
            d.layout = c.layout;
        }
        if let Some(pre) = &c.pre {
            sys_step(dc, frame, pre, t_ps);
        }
        sys_access(dc, frame, &c.sys, t_ps);
        lrw_in(ram, frame, &c.lrw);
        refresh_inputs(ram, *app, *al_state, app_cycles);
        lrw_out(frame, ram, &c.lrw);
        diff_access(dc, frame, &c.diff);
        d.sys = d.sys.wrapping_add(c.sys.inc);
        d.lrw = d.lrw.wrapping_add(c.lrw.inc);
        d.diff = d.diff.wrapping_add(c.diff.inc);
        d.adp = d.adp.wrapping_add(1);
        true
    }

    /// Marks that a frame passed the processing unit.
    pub fn count_frame(&mut self) {
        self.stats.frames += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{DeviceInfo, EscModel};

    fn esc() -> Esc {
        let mut e = Esc::new(
            EscModel::servo_mii(),
            DeviceInfo::servo_drive(7),
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        e
    }

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

    fn dg(cmd: Command, adp: u16, ado: u16, data: &[u8]) -> Vec<u8> {
        let mut v = vec![cmd.code(), 0];
        v.extend_from_slice(&adp.to_le_bytes());
        v.extend_from_slice(&ado.to_le_bytes());
        v.extend_from_slice(&(data.len() as u16).to_le_bytes());
        v.extend_from_slice(&[0, 0]);
        v.extend_from_slice(data);
        v.extend_from_slice(&[0, 0]);
        v
    }

    fn wkc(d: &[u8]) -> u16 {
        u16::from_le_bytes([d[d.len() - 2], d[d.len() - 1]])
    }

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
    fn eeprom_read_takes_its_busy_time() {
        let mut e = esc();
        e.process_datagram(&mut dg(Command::Apwr, 0, 0x0010, &[0x00, 0x10]), 0);
        // Read word 8 (vendor ID): control = read command, address 8.
        let mut d = dg(
            Command::Fpwr,
            0x1000,
            0x0502,
            &[0x00, 0x01, 0x08, 0x00, 0x00, 0x00],
        );
        e.process_datagram(&mut d, 1_000_000);
        assert_eq!(wkc(&d), 1);
        let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
        e.process_datagram(&mut s, 5_000_000);
        assert_eq!(u16::from_le_bytes([s[10], s[11]]) & 0x8000, 0x8000, "busy");
        let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
        e.process_datagram(&mut s, 30_000_000);
        assert_eq!(
            u16::from_le_bytes([s[10], s[11]]),
            0x0040,
            "idle, 8-byte reads"
        );
        let mut r = dg(Command::Fprd, 0x1000, 0x0508, &[0; 8]);
        e.process_datagram(&mut r, 31_000_000);
        let id = ecsync_wire::sii::identity(e.sii_image()).unwrap();
        assert_eq!(
            u32::from_le_bytes(r[10..14].try_into().unwrap()),
            id.vendor_id
        );
        assert_eq!(
            u32::from_le_bytes(r[14..18].try_into().unwrap()),
            id.product_code
        );
    }

    #[test]
    fn al_state_machine() {
        let mut e = esc();
        let st = |e: &mut Esc| {
            let mut d = dg(Command::Brd, 0, 0x0130, &[0, 0, 0, 0, 0, 0]);
            e.process_datagram(&mut d, 0);
            (
                u16::from_le_bytes([d[10], d[11]]),
                u16::from_le_bytes([d[14], d[15]]),
            )
        };
        // INIT -> OP is invalid: error flag, code 0x0011, state stays INIT.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x08, 0]), 0);
        assert_eq!(st(&mut e), (0x0011, 0x0011));
        // A new request without acknowledge is ignored...
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x02, 0]), 0);
        assert_eq!(st(&mut e), (0x0011, 0x0011));
        // ...with acknowledge it is taken.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x12, 0]), 0);
        assert_eq!(st(&mut e), (0x0002, 0));
        // PRE-OP -> SAFE-OP without SyncManagers: invalid output configuration.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x04, 0]), 0);
        assert_eq!(st(&mut e), (0x0012, 0x001d));
    }
}
