//! The replays: a recorded program run op by op ([`Esc::replay`]), the cyclic frame's steps
//! straight through ([`Esc::replay_cyclic`]), a segment's visit plan's steps
//! ([`Esc::replay_planned`]), and the working counter increments of a run of slaves summed
//! before they go to the frame ([`Deferred`]).
//!
//! A large network's drives take the clock's branch-free arithmetic here (`BRANCH_FREE`, see
//! `LocalClock::advance_to_in`); the plain path never does.

use super::PROGRAM_SLOTS;
use super::program::{CopyStep, DiffStep, LrwStep, Op, Simple, Straight, SysStep};
use crate::dc_unit::DcUnit;
use crate::esc::process_data::{AppLayout, AppMemory, copy_small, refresh_inputs};
use crate::esc::{Esc, EscStats};
use ecsync_wire::AlState;
use ecsync_wire::register as reg;

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

/// Adds `inc` to the 16-bit counter at the recorded frame offset `at` (a working counter, or
/// an ADP whose place was recorded from the datagram's header).
#[inline]
fn add_wkc(frame: &mut [u8], at: u16, inc: u16) {
    let at = usize::from(at);
    let w = u16::from_le_bytes([frame[at], frame[at + 1]]).wrapping_add(inc);
    frame[at..at + 2].copy_from_slice(&w.to_le_bytes());
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

impl Esc {
    /// Replays the program in slot `k` op by op (the segment's straight-through replay,
    /// [`Esc::replay_cyclic`], takes the cyclic frame before it gets here).
    #[inline]
    pub(super) fn replay(&mut self, k: usize, frame: &mut [u8], t_ps: u64) {
        self.stats.replayed_frames += 1;
        self.stats.datagrams_counted += u64::from(self.slots.counted[k]);
        if self.slots.ops[k] > 0 {
            self.replay_ops(k, frame, t_ps);
        }
        if self.slot_keys.writes_ram[k] {
            self.outputs_written(t_ps);
        }
    }

    fn replay_ops(&mut self, slot: usize, frame: &mut [u8], t_ps: u64) {
        for k in 0..usize::from(self.slots.programs[slot].n) {
            match self.slots.programs[slot].ops[k] {
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
    /// in the current generation ([`CyclicSteps`](super::program::CyclicSteps), [`Simple`]): the steps run, their working
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
            slot_keys,
            slots,
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
            let steps = &slots.fast[k].steps;
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
            let (r, wrapped) = slot_keys.replays[k].overflowing_add(1);
            slot_keys.replays[k] = r;
            if slot_keys.writes_ram[k] {
                *wd_last_write_ps = t_ps;
                *sync_pending = true;
            }
            if wrapped {
                self.fold_wrapped_replays(k);
            }
        }
        done
    }

    /// The one-step program ([`Simple`]) this ESC replays for frames of `shape`, resolved once
    /// for a segment's visit plan ([`PlannedSteps`]); `None` if it has none for it in the
    /// current generation (the visit then looks its program up by slot).
    pub(crate) fn planned_steps(&self, shape: u32) -> Option<PlannedSteps> {
        let k = self.program_slot(shape)?;
        // (The one-frame cycle's steps stay with the slot: a plan holds only the one-step
        // programs of a large network's frames, and so keeps its visits short.)
        let Straight::Simple(steps) = self.slots.fast[k].steps else {
            return None;
        };
        Some(PlannedSteps {
            generation: self.generation,
            counted: self.slots.counted[k],
            writes_ram: self.slot_keys.writes_ram[k],
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
    pub(crate) fn add_replays_to(&self, s: &mut EscStats, n: u64) {
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
    app_mem: &mut AppMemory,
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
