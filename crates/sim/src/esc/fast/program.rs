//! The recorded programs: the steps a frame of one shape took at the ESC, with absolute
//! offsets into the frame (positions taken from the datagram headers when they were decoded,
//! through the wire crate's views: a replay patches them without decoding again), fused into
//! fewer steps, and recognised as one straight-through step where they are the cyclic frame's
//! ([`Straight`]).

use crate::esc::recorder::LogicalOp;

/// Steps a program holds.
pub(super) const MAX_OPS: usize = 32;

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
    pub(super) at: u16,
    pub(super) ram: u16,
    pub(super) len: u16,
    pub(super) wkc: u16,
    pub(super) inc: u16,
}

/// A program of one step replayed straight through by `Esc::replay_cyclic`: the process
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
    pub(super) at: u16,
    pub(super) len: u8,
    pub(super) write: bool,
    pub(super) wkc: u16,
    pub(super) inc: u16,
}

/// An ADP increment (if `adp` is not 0), a difference read (BRD of 0x092C), its working counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct DiffStep {
    pub(super) adp: u16,
    pub(super) at: u16,
    pub(super) len: u8,
    pub(super) or: bool,
    pub(super) wkc: u16,
    pub(super) inc: u16,
}

/// An LRW through one write and one read FMMU with the application in between.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct LrwStep {
    pub(super) w_at: u16,
    pub(super) w_ram: u16,
    pub(super) w_len: u16,
    pub(super) r_at: u16,
    pub(super) r_ram: u16,
    pub(super) r_len: u16,
    pub(super) wkc: u16,
    pub(super) inc: u16,
}

/// The cyclic frame's whole program at one ESC (system time, process data, time difference, in
/// this order; at the reference under bus shift, a system time write first), replayed straight
/// through: no dispatch per step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct CyclicSteps {
    /// Bus shift's write of the master's time to the reference, before its FRMW.
    pub(super) pre: Option<SysStep>,
    pub(super) sys: SysStep,
    pub(super) lrw: LrwStep,
    pub(super) diff: DiffStep,
    /// Where the three working counters and the BRD's position field are, packed (see
    /// `Deferred`).
    pub(super) layout: u64,
}

impl CyclicSteps {
    pub(super) fn new(pre: Option<SysStep>, sys: SysStep, lrw: LrwStep, diff: DiffStep) -> Self {
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

/// Fuses the common sequences of a recorded program into single steps (fewer dispatches).
/// Inline: its one caller is `Esc::install`, which the full path inlines.
#[inline]
pub(super) fn fuse(ops: &[Op], out: &mut [Op; MAX_OPS]) -> u8 {
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

/// The recorded steps for one frame shape.
#[derive(Debug, Clone, Copy)]
pub(super) struct Program {
    pub(super) shape: u32,
    pub(super) generation: u64,
    pub(super) ops: [Op; MAX_OPS],
    pub(super) n: u8,
    pub(super) counted: u8,
}

/// A recorded program as one straight-through step (`Esc::replay_cyclic`), if its steps are
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

impl Straight {
    /// The straight-through step of a fused program, if it is one.
    pub(super) fn of(ops: &[Op]) -> Straight {
        match *ops {
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
        }
    }
}

/// Whether a fused program writes process RAM (the outputs): its replay restarts the process
/// data watchdog.
pub(super) fn writes_outputs(ops: &[Op]) -> bool {
    ops.iter().any(|op| match op {
        Op::ToRam { .. } | Op::WriteFused(_) => true,
        Op::LrwFused(l) => l.w_len > 0,
        _ => false,
    })
}

/// What a straight-through replay reads of one program slot, on a cache line of its own: in a
/// large network every ESC's slots are out of the cache again by the next frame, and the
/// steps (a few dozen bytes) are all a replay needs of the program (its ops, hundreds of bytes,
/// stay cold).
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
pub(super) struct FastSlot {
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
