//! The replay fast path. The cyclic frame is the same every cycle, and while nothing in the ESC
//! changes it does the same every cycle: [`super::datagram`] records what a frame of a given
//! shape did as a program of steps with absolute frame offsets, and the next frame of that shape
//! runs the program instead of decoding its datagrams again. The cyclic frame's three steps
//! (system time, process data, time difference) run straight through in
//! [`Esc::replay_cyclic`], and their working counter increments are summed over a run of slaves
//! ([`Deferred`]).
//!
//! The recorded offsets are positions taken from the datagram headers when they were decoded
//! (through the wire crate's views); the replay patches those positions without decoding again.

use super::Esc;
use super::datagram::{LogicalOp, add_u16_at};
use super::process_data::{AppLayout, copy_small, refresh_inputs};
use crate::dc_unit::DcUnit;
use ecsync_wire::AlState;
use ecsync_wire::register as reg;

/// Frames with more datagrams than this are never recorded.
pub(super) const MAX_PROGRAM_DATAGRAMS: usize = 8;
/// Steps a program holds.
const MAX_OPS: usize = 32;
/// Programs an ESC keeps, one per frame shape: in a network whose process image takes
/// several frames, an ESC sees the first frame (FRMW, BRD of the time difference) and the one
/// with its process data; the spare slots take a bring-up or diagnostic frame without
/// replacing either.
pub(crate) const PROGRAM_SLOTS: usize = 4;

/// One step of a recorded program, with absolute offsets into the frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum Op {
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
    /// Fused: outputs written through one FMMU (frame -> RAM) and the working counter: a slave
    /// whose outputs and inputs are in different frames of a large network's cycle.
    WriteFused(CopyStep),
    /// Fused: the application refreshes its inputs, one FMMU reads them (RAM -> frame), and
    /// the working counter.
    ReadFused(CopyStep),
}

/// A copy between frame and process RAM through one FMMU, and its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct CopyStep {
    at: u16,
    ram: u16,
    len: u16,
    wkc: u16,
    inc: u16,
}

/// A program of one step replayed straight through by [`Esc::replay_cyclic`]: the process
/// data of a large network's frames that carry no DC datagram. Tagged by a byte of its own,
/// as [`Straight`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(super) enum Simple {
    /// The DC steps without process data: the first frame of a large network's cycle at a
    /// slave whose process data another frame carries (a system time write first at the
    /// reference under bus shift).
    Dc {
        pre: Option<SysStep>,
        sys: SysStep,
        diff: DiffStep,
    },
    /// An LRW through a write and a read FMMU.
    Lrw(LrwStep),
    /// Outputs only.
    Write(CopyStep),
    /// Inputs only.
    Read(CopyStep),
}

impl Op {
    /// The step of a logical access whose datagram data starts at frame offset `data`.
    pub(super) fn from_logical(op: LogicalOp, data: u16) -> Op {
        match op {
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
        }
    }
}

/// A system time read or write (FRMW of 0x0910) and its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct SysStep {
    at: u16,
    len: u8,
    write: bool,
    wkc: u16,
    inc: u16,
}

/// An ADP increment (if `adp` is not 0), a difference read (BRD of 0x092C), its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct DiffStep {
    adp: u16,
    at: u16,
    len: u8,
    or: bool,
    wkc: u16,
    inc: u16,
}

/// An LRW through one write and one read FMMU with the application in between.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct LrwStep {
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
pub(super) struct CyclicSteps {
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

    /// The pending increments go to the frame first if the next step counts at other places.
    #[inline(always)]
    pub(crate) fn switch_layout(&mut self, layout: u64, frame: &mut [u8]) {
        if layout != self.layout {
            self.flush(frame);
            self.layout = layout;
        }
    }
}

/// Fuses the common sequences of a recorded program into single steps (fewer dispatches).
/// Inline: its one caller is [`Esc::install`], which the full path inlines.
#[inline]
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
            [Op::ToRam { at, ram, len }, Op::Wkc { at: w, inc }, ..] => (
                Op::WriteFused(CopyStep {
                    at: *at,
                    ram: *ram,
                    len: *len,
                    wkc: *w,
                    inc: *inc,
                }),
                2,
            ),
            [
                Op::Refresh,
                Op::FromRam { at, ram, len },
                Op::Wkc { at: w, inc },
                ..,
            ] => (
                Op::ReadFused(CopyStep {
                    at: *at,
                    ram: *ram,
                    len: *len,
                    wkc: *w,
                    inc: *inc,
                }),
                3,
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

/// Adds `inc` to the working counter (or ADP) at the recorded frame offset `at`.
#[inline]
fn add_wkc(frame: &mut [u8], at: u16, inc: u16) {
    add_u16_at(frame, at, inc);
}

/// The system time read or write of a [`SysStep`], without its working counter.
/// `BRANCH_FREE`: a large network's drive (see `LocalClock::advance_to_in`).
#[inline(always)]
fn sys_access<const BRANCH_FREE: bool>(dc: &mut DcUnit, frame: &mut [u8], s: &SysStep, t_ps: u64) {
    let (a, l) = (usize::from(s.at), usize::from(s.len));
    if s.write {
        dc.write_system_time_in::<BRANCH_FREE>(&frame[a..a + l], t_ps);
    } else {
        dc.read_fast(reg::DC_SYSTEM_TIME, &mut frame[a..a + l], false, t_ps);
    }
}

#[inline(always)]
fn sys_step(dc: &mut DcUnit, frame: &mut [u8], s: &SysStep, t_ps: u64) {
    sys_access::<false>(dc, frame, s, t_ps);
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

/// Outputs of a [`CopyStep`]: frame -> process RAM.
#[inline(always)]
fn copy_in(ram: &mut [u8], frame: &[u8], c: &CopyStep) {
    let (d, r, l) = (usize::from(c.at), usize::from(c.ram), usize::from(c.len));
    copy_small(&mut ram[r..r + l], &frame[d..d + l]);
}

/// Inputs of a [`CopyStep`]: process RAM -> frame.
#[inline(always)]
fn copy_out(frame: &mut [u8], ram: &[u8], c: &CopyStep) {
    let (d, r, l) = (usize::from(c.at), usize::from(c.ram), usize::from(c.len));
    copy_small(&mut frame[d..d + l], &ram[r..r + l]);
}

/// The recorded steps for one frame shape.
#[derive(Debug, Clone, Copy)]
pub(super) struct Program {
    pub(super) shape: u32,
    pub(super) generation: u64,
    ops: [Op; MAX_OPS],
    n: u8,
    pub(super) counted: u8,
}

/// A recorded program as one straight-through step ([`Esc::replay_cyclic`]), if its steps are
/// the cyclic frame's DC steps with or without the process data ([`CyclicSteps`]), or one step
/// of process data ([`Simple`]).
///
/// Tagged by a byte of its own (`repr(u8)`): the replay tests it every frame, and a tag packed
/// into the steps' niches takes several instructions to decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub(super) enum Straight {
    /// The program is replayed op by op, if at all.
    #[default]
    None,
    Cyclic(CyclicSteps),
    Simple(Simple),
}

/// What a straight-through replay reads of one program slot, on a cache line of its own: in a
/// large network every ESC's slots are out of the cache again by the next frame, and the
/// steps (a few dozen bytes) are all a replay needs of the program (its ops, hundreds of bytes,
/// stay cold).
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
pub(crate) struct FastSlot {
    pub(super) steps: Straight,
}

// One cache line per slot.
const _: () = assert!(core::mem::size_of::<FastSlot>() == 64);

impl Default for Program {
    fn default() -> Self {
        Program {
            shape: 0,
            generation: 0,
            ops: [Op::Nop; MAX_OPS],
            n: 0,
            counted: 0,
        }
    }
}

impl Program {
    /// An empty program for frames of `shape`, valid in `generation`. Inline, so that the
    /// full path builds it in place rather than copying it.
    #[inline]
    pub(super) fn new(shape: u32, generation: u64) -> Self {
        Program {
            shape,
            generation,
            ..Program::default()
        }
    }

    /// Appends a step; false if the program is full.
    #[inline]
    pub(super) fn push(&mut self, op: Op) -> bool {
        if usize::from(self.n) < MAX_OPS {
            self.ops[usize::from(self.n)] = op;
            self.n += 1;
            true
        } else {
            false
        }
    }
}

impl Esc {
    /// The slot of the program recorded for frames of `shape` in the current generation.
    #[inline(always)]
    pub(super) fn program_slot(&self, shape: u32) -> Option<usize> {
        // (Empty slots carry the generation u64::MAX, which no ESC reaches: shape 0 finds
        // none.)
        let g = self.generation;
        // The slots in turn, as a small network's one frame always finds the first.
        (0..PROGRAM_SLOTS).find(|&k| self.key_shapes[k] == shape && self.key_generations[k] == g)
    }

    /// Whether a frame of `shape` would do nothing at this ESC but pass: `Some(true)` if its
    /// program, recorded in the current generation, is empty (no datagram addresses the ESC),
    /// `Some(false)` if it has steps, `None` if none is recorded. The segment passes frames by
    /// ESCs they do nothing at ([`Esc::count_passed_frames`]).
    #[inline]
    pub(crate) fn replays_nothing(&self, shape: u32) -> Option<bool> {
        self.program_slot(shape).map(|k| self.slot_ops[k] == 0)
    }

    /// Counts `frames` frames that passed the processing unit and did nothing, as the replay of
    /// an empty program would (the segment did not hand them to the ESC).
    pub(crate) fn count_passed_frames(&mut self, frames: u64) {
        self.stats.frames += frames;
        self.stats.replayed_frames += frames;
    }

    /// Makes a freshly recorded program the one replayed for its shape: its steps fused, the
    /// cyclic frame's recognised. It takes the slot of the same shape, else a slot recorded in
    /// an older generation (never valid again), else the slots in turn. By reference: the
    /// program is large, and it is copied once, into place.
    #[inline]
    pub(super) fn install(&mut self, recorded: &Program) {
        let g = self.generation;
        let k = match self
            .key_shapes
            .iter()
            .position(|&s| s == recorded.shape)
            .or_else(|| self.key_generations.iter().position(|&pg| pg != g))
        {
            Some(k) => k,
            None => {
                let k = usize::from(self.next_slot);
                self.next_slot = ((k + 1) % PROGRAM_SLOTS) as u8;
                k
            }
        };
        // The replays of the program replaced go into the counters.
        let replays = u64::from(std::mem::take(&mut self.replays[k]));
        self.stats.frames += replays;
        self.stats.replayed_frames += replays;
        self.stats.datagrams_counted += replays * u64::from(self.slot_counted[k]);
        self.key_shapes[k] = recorded.shape;
        self.key_generations[k] = recorded.generation;
        // The recorded ops go into the slot fused (the ops past `n` are never read: no copy
        // of the whole program, which is hundreds of bytes and cold).
        let prog = &mut self.programs[k];
        prog.shape = recorded.shape;
        prog.generation = recorded.generation;
        prog.counted = recorded.counted;
        prog.n = fuse(&recorded.ops[..usize::from(recorded.n)], &mut prog.ops);
        self.slot_ops[k] = prog.n;
        self.slot_counted[k] = prog.counted;
        let ops = &prog.ops[..usize::from(prog.n)];
        self.writes_ram[k] = ops.iter().any(|op| match op {
            Op::ToRam { .. } | Op::WriteFused(_) => true,
            Op::LrwFused(l) => l.w_len > 0,
            _ => false,
        });
        self.fast[k].steps = match *ops {
            [Op::SysFused(sys), Op::LrwFused(lrw), Op::DiffFused(diff)] => {
                Straight::Cyclic(CyclicSteps::new(None, sys, lrw, diff))
            }
            [
                Op::SysFused(pre),
                Op::SysFused(sys),
                Op::LrwFused(lrw),
                Op::DiffFused(diff),
            ] => Straight::Cyclic(CyclicSteps::new(Some(pre), sys, lrw, diff)),
            [Op::SysFused(sys), Op::DiffFused(diff)] => Straight::Simple(Simple::Dc {
                pre: None,
                sys,
                diff,
            }),
            [Op::SysFused(pre), Op::SysFused(sys), Op::DiffFused(diff)] => {
                Straight::Simple(Simple::Dc {
                    pre: Some(pre),
                    sys,
                    diff,
                })
            }
            [Op::LrwFused(lrw)] => Straight::Simple(Simple::Lrw(lrw)),
            [Op::WriteFused(w)] => Straight::Simple(Simple::Write(w)),
            [Op::ReadFused(r)] => Straight::Simple(Simple::Read(r)),
            _ => Straight::None,
        };
    }

    /// Replays the program in slot `k` op by op (the segment's straight-through replay,
    /// [`Esc::replay_cyclic`], takes the cyclic frame before it gets here).
    #[inline]
    pub(super) fn replay(&mut self, k: usize, frame: &mut [u8], t_ps: u64) {
        self.stats.replayed_frames += 1;
        self.stats.datagrams_counted += u64::from(self.slot_counted[k]);
        if self.slot_ops[k] > 0 {
            self.replay_ops(k, frame, t_ps);
        }
        if self.writes_ram[k] {
            self.outputs_written(t_ps);
        }
    }

    fn replay_ops(&mut self, slot: usize, frame: &mut [u8], t_ps: u64) {
        for k in 0..usize::from(self.programs[slot].n) {
            match self.programs[slot].ops[k] {
                Op::Nop => {}
                Op::AdpInc { at } => add_wkc(frame, at, 1),
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
                Op::WriteFused(c) => {
                    copy_in(&mut self.ram, frame, &c);
                    add_wkc(frame, c.wkc, c.inc);
                }
                Op::ReadFused(c) => {
                    self.app_refresh_inputs();
                    copy_out(frame, &self.ram, &c);
                    add_wkc(frame, c.wkc, c.inc);
                }
            }
        }
    }

    /// A cyclic frame at this ESC, if it has a straight-through program for `shape` recorded
    /// in the current generation ([`CyclicSteps`], [`Simple`]): the steps run, their working
    /// counter and ADP increments go to `d` (see [`Deferred`]). Returns false, touching
    /// nothing, otherwise; the caller then flushes `d` and calls [`Esc::process_frame`].
    #[inline(always)]
    pub(crate) fn replay_cyclic(
        &mut self,
        frame: &mut [u8],
        shape: u32,
        t_ps: u64,
        d: &mut Deferred,
    ) -> bool {
        let done = self.replay_cyclic_steps(frame, shape, t_ps, d);
        if self.sync_pending {
            self.end_of_frame(t_ps + crate::phy::frame_wire_time_ps(frame.len()));
        }
        done
    }

    #[inline(always)]
    fn replay_cyclic_steps(
        &mut self,
        frame: &mut [u8],
        shape: u32,
        t_ps: u64,
        d: &mut Deferred,
    ) -> bool {
        // An expired watchdog changes the state first: the full path takes the frame then.
        if self.watchdog_check(t_ps) {
            return false;
        }
        let Some(k) = self.program_slot(shape) else {
            return false;
        };
        // (k is below PROGRAM_SLOTS, a power of two: the mask spares the bounds check.)
        let k = k & (PROGRAM_SLOTS - 1);
        let Esc {
            fast,
            replays,
            writes_ram,
            dc,
            ram,
            app,
            al_state,
            app_mem,
            wd_last_write_ps,
            sync_pending,
            ..
        } = self;
        // The one-frame cycle's steps tested first, on their own (a match of the three
        // together costs a dozen instructions more per frame).
        let done = {
            let steps = &fast[k].steps;
            if let Straight::Cyclic(c) = steps {
                let (Some(dc), Some(app)) = (dc.as_mut(), app.as_ref()) else {
                    return false;
                };
                d.switch_layout(c.layout, frame);
                if let Some(pre) = &c.pre {
                    sys_step(dc, frame, pre, t_ps);
                }
                sys_access::<false>(dc, frame, &c.sys, t_ps);
                lrw_in(ram, frame, &c.lrw);
                refresh_inputs(ram, *app, *al_state, app_mem);
                lrw_out(frame, ram, &c.lrw);
                diff_access(dc, frame, &c.diff);
                d.sys = d.sys.wrapping_add(c.sys.inc);
                d.lrw = d.lrw.wrapping_add(c.lrw.inc);
                d.diff = d.diff.wrapping_add(c.diff.inc);
                d.adp = d.adp.wrapping_add(1);
                true
            } else if let (Straight::Simple(simple), Some(app)) = (steps, app.as_ref()) {
                replay_simple(
                    simple,
                    dc.as_mut(),
                    ram,
                    app,
                    *al_state,
                    app_mem,
                    frame,
                    t_ps,
                    d,
                )
            } else {
                false
            }
        };
        if done {
            let (r, wrapped) = replays[k].overflowing_add(1);
            replays[k] = r;
            if writes_ram[k] {
                *wd_last_write_ps = t_ps;
                *sync_pending = true;
            }
            if wrapped {
                self.fold_wrapped_replays(k);
            }
        }
        done
    }

    /// Slot `k`'s replay count wrapped to 0: its 2^32 replays go into the counters.
    #[cold]
    #[inline(never)]
    fn fold_wrapped_replays(&mut self, k: usize) {
        let replays = 1u64 << 32;
        self.stats.frames += replays;
        self.stats.replayed_frames += replays;
        self.stats.datagrams_counted += replays * u64::from(self.slot_counted[k]);
    }

    /// The one-step program ([`Simple`]) this ESC replays for frames of `shape`, resolved once
    /// for a segment's visit plan ([`PlannedSteps`]); `None` if it has none for it in the
    /// current generation (the visit then looks its program up by slot).
    pub(crate) fn planned_steps(&self, shape: u32) -> Option<PlannedSteps> {
        let k = self.program_slot(shape)?;
        // (The one-frame cycle's steps stay with the slot: a plan holds only the one-step
        // programs of a large network's frames, and so keeps its visits short.)
        let Straight::Simple(steps) = self.fast[k].steps else {
            return None;
        };
        Some(PlannedSteps {
            generation: self.generation,
            counted: self.slot_counted[k],
            writes_ram: self.writes_ram[k],
            steps,
        })
    }

    /// A cyclic frame at this ESC by the steps a visit plan resolved: what
    /// [`Esc::replay_cyclic`] does, without looking the program up. Returns false, touching
    /// nothing, if they no longer hold (the ESC's generation moved) or the watchdog expired;
    /// the caller then flushes `d` and calls [`Esc::process_frame`].
    #[inline(always)]
    pub(crate) fn replay_planned(
        &mut self,
        p: &PlannedSteps,
        frame: &mut [u8],
        t_ps: u64,
        d: &mut Deferred,
    ) -> bool {
        let done = self.replay_planned_steps(p, frame, t_ps, d);
        if self.sync_pending {
            self.end_of_frame_in::<true>(t_ps + crate::phy::frame_wire_time_ps(frame.len()));
        }
        done
    }

    /// Whether planned steps no longer hold at this ESC (see [`Esc::replay_planned`]).
    pub(crate) fn planned_stale(&self, p: &PlannedSteps) -> bool {
        self.generation != p.generation
    }

    #[inline(always)]
    fn replay_planned_steps(
        &mut self,
        p: &PlannedSteps,
        frame: &mut [u8],
        t_ps: u64,
        d: &mut Deferred,
    ) -> bool {
        if self.watchdog_check(t_ps) {
            return false;
        }
        // The steps are the shape's program in the generation the plan was made in: they hold
        // while it stands.
        if self.generation != p.generation {
            return false;
        }
        let Esc {
            dc,
            ram,
            app,
            al_state,
            app_mem,
            ..
        } = self;
        let Some(app) = app.as_ref() else {
            return false;
        };
        let done = replay_simple(
            &p.steps,
            dc.as_mut(),
            ram,
            app,
            *al_state,
            app_mem,
            frame,
            t_ps,
            d,
        );
        // (The replay is counted by the plan: see `count_planned_replays`.)
        if done && p.writes_ram {
            self.outputs_written(t_ps);
        }
        done
    }

    /// `n` replays of planned steps go into the counters (the segment counts them while its
    /// plan holds).
    pub(crate) fn count_planned_replays(&mut self, p: &PlannedSteps, n: u64) {
        p.add_replays_to(&mut self.stats, n);
    }
}

impl PlannedSteps {
    /// `n` replays of these steps, added to `s`.
    pub(crate) fn add_replays_to(&self, s: &mut super::EscStats, n: u64) {
        s.frames += n;
        s.replayed_frames += n;
        s.datagrams_counted += n * u64::from(self.counted);
    }
}

/// One ESC's straight-through steps for a frame shape, as a segment's visit plan keeps them
/// (a copy of its program slot's, resolved when the plan is made): a visit by plan reads the
/// ESC's first line, not its program look-up and slot lines, and the plan's steps lie in
/// visit order, where the cache's prefetcher finds them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PlannedSteps {
    generation: u64,
    /// The program's counted datagrams (the plan counts the replays) and whether it writes
    /// the outputs.
    counted: u8,
    writes_ram: bool,
    steps: Simple,
}

/// A [`Simple`] program: the DC steps or the process data of one frame of a large network's
/// cycle (see [`Esc::replay_cyclic`]); false, touching nothing, for DC steps without a DC unit.
/// Inline: a drive of a large network takes three of these a cycle, and the call with its
/// arguments cost about 30 instructions each.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn replay_simple(
    simple: &Simple,
    dc: Option<&mut DcUnit>,
    ram: &mut [u8],
    app: &AppLayout,
    al_state: AlState,
    app_mem: &mut super::process_data::AppMemory,
    frame: &mut [u8],
    t_ps: u64,
    d: &mut Deferred,
) -> bool {
    // (Each step's working-counter layout is worked out in its own arm: one match a frame.)
    match simple {
        Simple::Dc { pre, sys, diff } => {
            let Some(dc) = dc else {
                return false;
            };
            let layout = u64::from(sys.wkc) | u64::from(diff.wkc) << 32 | u64::from(diff.adp) << 48;
            d.switch_layout(layout, frame);
            if let Some(pre) = pre {
                sys_step(dc, frame, pre, t_ps);
            }
            sys_access::<true>(dc, frame, sys, t_ps);
            diff_access(dc, frame, diff);
            d.sys = d.sys.wrapping_add(sys.inc);
            d.diff = d.diff.wrapping_add(diff.inc);
            d.adp = d.adp.wrapping_add(1);
        }
        Simple::Lrw(l) => {
            d.switch_layout(u64::from(l.wkc) << 16, frame);
            lrw_in(ram, frame, l);
            refresh_inputs(ram, *app, al_state, app_mem);
            lrw_out(frame, ram, l);
            d.lrw = d.lrw.wrapping_add(l.inc);
        }
        Simple::Write(c) => {
            d.switch_layout(u64::from(c.wkc) << 16, frame);
            copy_in(ram, frame, c);
            d.lrw = d.lrw.wrapping_add(c.inc);
        }
        Simple::Read(c) => {
            d.switch_layout(u64::from(c.wkc) << 16, frame);
            refresh_inputs(ram, *app, al_state, app_mem);
            copy_out(frame, ram, c);
            d.lrw = d.lrw.wrapping_add(c.inc);
        }
    }
    true
}
