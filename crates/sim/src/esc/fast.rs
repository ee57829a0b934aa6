//! The fast path: what makes the cyclic frame cheap, kept apart from the ESC it speeds up.
//!
//! The cyclic frame is the same every cycle, and while nothing in the ESC changes it does the
//! same every cycle. The plain path ([`super::datagram`]) decodes every datagram, noting what
//! each one did ([`super::recorder`]); [`Esc::process_frame`] keeps that as a program of steps
//! with absolute frame offsets in one of the ESC's program slots, under the frame's shape and
//! the ESC's configuration generation, and the next frame of that shape runs the program
//! instead of decoding its datagrams again. Any register write, state change or access the
//! recorder cannot repeat moves the generation on, and with it every program.
//!
//! - [`program`]: the steps, a recorded program, their fusion, and the straight-through step
//!   the cyclic frame's programs become;
//! - [`replay`]: the replays: op by op, the cyclic frame straight through, a segment's visit
//!   plan, and the working counters of a run of slaves summed ([`Deferred`]);
//! - here: the ESC's program slots (the look-up by shape, the installation of a program, the
//!   replays not yet in the ESC's counters) and a frame's way through them.
//!
//! What the ESC gives it: the plain path for one datagram (`Esc::datagram_in_frame`) and the
//! end of a frame (`Esc::end_of_frame`), the recorder the register and process data code fill
//! in, and its state (the generation, the process RAM and application, the DC unit). What it
//! gives the ESC: its slots ([`SlotKeys`] on the ESC's first cache line, [`Slots`] after) and
//! the replays to count ([`Esc::count_pending_replays`]). Nothing here allocates.
//!
//! The contract: the fast path changes nothing but the time a frame takes. The equivalence
//! tests check it, `tests/replay_equivalence.rs`: a bring-up and thousands of cycles with the
//! replay on and off (`Segment::set_replay`) give byte-identical frames, clocks and counters
//! (`replay_is_exact`, `replay_of_a_cycle_of_several_frames_is_exact`,
//! `an_offset_write_every_cycle_keeps_the_visit_plans_and_changes_nothing`,
//! `long_frames_by_station_are_exact`, `visit_plans_outlive_their_program_slots`), and the
//! branch-free clock a large network's drives take here is the plain clock to the bit
//! (`branch_free_clock_is_the_same_clock`, in `clock.rs`). What it saves is measured by
//! `cargo bench -p ecsync-sim --bench cycle`.

mod program;
mod replay;

use super::datagram::DatagramEffects;
use super::recorder::{Act, Recorder};
use super::{Esc, EscStats};
use ecsync_wire::{AddressMode, Datagram};
use program::{FastSlot, Op, Program, Straight, fuse, writes_outputs};

pub(crate) use replay::{Deferred, PlannedSteps};

/// Frames with more datagrams than this are never recorded.
pub(crate) const MAX_PROGRAM_DATAGRAMS: usize = 8;
/// Programs an ESC keeps, one per frame shape: in a network whose process image takes
/// several frames, an ESC sees the first frame (FRMW, BRD of the time difference) and the one
/// with its process data; the spare slots take a bring-up or diagnostic frame without
/// replacing either.
const PROGRAM_SLOTS: usize = 4;

/// What the ESC's first cache line holds of its program slots: what every replayed frame
/// reads and updates (see [`Esc`]'s layout).
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub(super) struct SlotKeys {
    /// Frames each slot's program replayed straight through and not yet in the ESC's
    /// counters (one increment per frame instead of three; see [`Esc::stats`]; folded into
    /// them before it wraps).
    replays: [u32; PROGRAM_SLOTS],
    /// Each slot's shape.
    shapes: [u32; PROGRAM_SLOTS],
    /// Each slot's program writes process RAM (the outputs): a replay restarts the process
    /// data watchdog.
    writes_ram: [bool; PROGRAM_SLOTS],
}

/// The rest of the program slots: the look-up and the straight-through steps, which a large
/// network's visit plans read once, when they are made (a small network's frames read them
/// every time, from the L1 cache), and the programs themselves, boxed (cold: what the full
/// path and the bring-up use).
#[derive(Debug, Clone)]
#[repr(C)]
pub(super) struct Slots {
    /// Each slot's generation (empty slots carry u64::MAX, which no ESC reaches).
    generations: [u64; PROGRAM_SLOTS],
    /// Each slot's program: its op count and the datagrams whose working counter it counts
    /// (the program's `n` and `counted`, kept here with the hot fields: a replay op by op of
    /// an empty program, most ESCs' part of a large network's bring-up frames, then reads
    /// nothing of the boxed programs).
    ops: [u8; PROGRAM_SLOTS],
    counted: [u8; PROGRAM_SLOTS],
    /// The slot the next recording replaces when none is free.
    next: u8,
    /// Programs recorded for the last few frame shapes: a cycle of several frames (the
    /// first with the DC datagrams, the others with process data) keeps each one's.
    programs: Box<[Program; PROGRAM_SLOTS]>,
    /// Each slot's straight-through steps, a line each.
    fast: [FastSlot; PROGRAM_SLOTS],
}

// The look-up on one line, the steps on the next four.
const _: () = {
    use core::mem::offset_of;
    assert!(offset_of!(Slots, programs) + size_of::<Box<[Program; PROGRAM_SLOTS]>>() <= 64);
    assert!(offset_of!(Slots, fast) == 64);
    assert!(size_of::<Slots>() == 64 + PROGRAM_SLOTS * 64);
};

impl SlotKeys {
    /// No slot used.
    pub(super) fn new() -> Self {
        SlotKeys {
            replays: [0; PROGRAM_SLOTS],
            // (Shape 0 is never recorded; the empty slots' generation keeps it from matching.)
            shapes: [0; PROGRAM_SLOTS],
            writes_ram: [false; PROGRAM_SLOTS],
        }
    }
}

impl Slots {
    /// No program recorded.
    pub(super) fn new() -> Self {
        Slots {
            // No generation is u64::MAX: an empty slot matches no frame, shape 0 (never
            // recorded) included.
            generations: [u64::MAX; PROGRAM_SLOTS],
            ops: [0; PROGRAM_SLOTS],
            counted: [0; PROGRAM_SLOTS],
            next: 0,
            programs: Box::new([Program::default(); PROGRAM_SLOTS]),
            fast: [FastSlot::default(); PROGRAM_SLOTS],
        }
    }
}

impl Esc {
    /// The slot of the program recorded for frames of `shape` in the current generation.
    #[inline(always)]
    fn program_slot(&self, shape: u32) -> Option<usize> {
        // (Empty slots carry the generation u64::MAX, which no ESC reaches: shape 0 finds
        // none.)
        let g = self.generation;
        // The slots in turn, as a small network's one frame always finds the first.
        (0..PROGRAM_SLOTS)
            .find(|&k| self.slot_keys.shapes[k] == shape && self.slots.generations[k] == g)
    }

    /// Whether a frame of `shape` would do nothing at this ESC but pass: `Some(true)` if its
    /// program, recorded in the current generation, is empty (no datagram addresses the ESC),
    /// `Some(false)` if it has steps, `None` if none is recorded. The segment passes frames by
    /// ESCs they do nothing at ([`Esc::count_passed_frames`]).
    #[inline]
    pub(crate) fn replays_nothing(&self, shape: u32) -> Option<bool> {
        self.program_slot(shape).map(|k| self.slots.ops[k] == 0)
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
    fn install(&mut self, recorded: &Program) {
        let g = self.generation;
        let k = match self
            .slot_keys
            .shapes
            .iter()
            .position(|&s| s == recorded.shape)
            .or_else(|| self.slots.generations.iter().position(|&pg| pg != g))
        {
            Some(k) => k,
            None => {
                let k = usize::from(self.slots.next);
                self.slots.next = ((k + 1) % PROGRAM_SLOTS) as u8;
                k
            }
        };
        // The replays of the program replaced go into the counters.
        let replays = u64::from(std::mem::take(&mut self.slot_keys.replays[k]));
        self.stats.frames += replays;
        self.stats.replayed_frames += replays;
        self.stats.datagrams_counted += replays * u64::from(self.slots.counted[k]);
        self.slot_keys.shapes[k] = recorded.shape;
        self.slots.generations[k] = recorded.generation;
        // The recorded ops go into the slot fused (the ops past `n` are never read: no copy
        // of the whole program, which is hundreds of bytes and cold).
        let prog = &mut self.slots.programs[k];
        prog.shape = recorded.shape;
        prog.generation = recorded.generation;
        prog.counted = recorded.counted;
        prog.n = fuse(&recorded.ops[..usize::from(recorded.n)], &mut prog.ops);
        self.slots.ops[k] = prog.n;
        self.slots.counted[k] = prog.counted;
        let ops = &prog.ops[..usize::from(prog.n)];
        self.slot_keys.writes_ram[k] = writes_outputs(ops);
        self.slots.fast[k].steps = Straight::of(ops);
    }

    /// Adds to `s` the frames the slots replayed straight through that are not yet in the
    /// ESC's counters (see [`SlotKeys`]).
    pub(super) fn count_pending_replays(&self, s: &mut EscStats) {
        for (&counted, &replays) in self.slots.counted.iter().zip(&self.slot_keys.replays) {
            let replays = u64::from(replays);
            s.frames += replays;
            s.replayed_frames += replays;
            s.datagrams_counted += replays * u64::from(counted);
        }
    }

    /// Slot `k`'s replay count wrapped to 0: its 2^32 replays go into the counters.
    #[cold]
    #[inline(never)]
    fn fold_wrapped_replays(&mut self, k: usize) {
        let replays = 1u64 << 32;
        self.stats.frames += replays;
        self.stats.replayed_frames += replays;
        self.stats.datagrams_counted += replays * u64::from(self.slots.counted[k]);
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
}
