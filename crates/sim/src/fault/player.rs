//! The player: the schedule made to happen on a segment and its master's host, by the clock
//! and frame by frame.

use super::{Epoch, Fault, FaultKind, FaultSchedule, KindName, SlaveRef};
use crate::rng::{SplitMix64, unit_from_bits};
use crate::segment::Segment;
use ecsync_wire::{Command, EcatFrame};
use std::fmt;

/// What happens to one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameFate {
    /// Lost before the first slave: nobody sees it.
    pub lost_out: bool,
    /// Processed, then lost (or its FCS broken) on the way back: the master never gets it.
    pub lost_back: bool,
    /// Of a frame lost on the way back, whether its FCS broke (a `corrupt` fault) rather than
    /// the frame vanishing: the ESCs behind the break count it (see the module's doc).
    pub corrupt: bool,
    /// Added to the reply's arrival, ps.
    pub extra_delay_ps: u64,
    /// A second copy of the reply arrives this much after the first, ps.
    pub copy_after_ps: Option<u64>,
}

/// Whether a fault started or ended. Its [`Display`](fmt::Display) and serialized form are
/// `start` and `end`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Edge {
    /// The fault began (or, for an instantaneous one, happened).
    Start,
    /// Its window ended.
    End,
}

impl Edge {
    /// `start` or `end`.
    pub fn as_str(self) -> &'static str {
        match self {
            Edge::Start => "start",
            Edge::End => "end",
        }
    }
}

impl fmt::Display for Edge {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl serde::Serialize for Edge {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// One thing the player did, for the report.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct FaultEvent {
    /// Real time, ps since the start of the simulation (or of `serve`).
    pub t_ps: u64,
    /// Time after the epoch, ns.
    pub since_epoch_ns: u64,
    /// Index of the entry in the schedule.
    pub fault: usize,
    /// Its kind.
    pub kind: KindName,
    /// Whether it started or ended.
    pub edge: Edge,
    /// What happened, in words.
    pub detail: String,
}

/// Counts of what the player did to frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct FaultCounts {
    /// Frames lost on the way out.
    pub lost_out: u64,
    /// Frames lost on the way back.
    pub lost_back: u64,
    /// Frames whose FCS broke.
    pub corrupted: u64,
    /// Of the frames lost (either way), those that carried process data (the cyclic frames).
    pub lost_with_process_data: u64,
    /// Replies delayed.
    pub delayed: u64,
    /// Replies sent twice.
    pub duplicated: u64,
}

/// Frames before the epoch are numbered in a space of their own (only a fault injected at a real
/// time can take them), so that the draws of the frames after it stay the schedule's.
const PRE_EPOCH_FRAME: u64 = 1 << 63;

/// Plays a [`FaultSchedule`] on a segment: by the clock ([`FaultPlayer::advance_to`]) and frame
/// by frame ([`FaultPlayer::before_frame`]).
#[derive(Debug, Clone)]
pub struct FaultPlayer {
    schedule: FaultSchedule,
    seed: u64,
    origin_ps: Option<u64>,
    /// The current frame's number for the draws (see [`FaultPlayer::before_frame`]).
    frame_no: u64,
    /// Frames with process data since the epoch, and other frames since the last of them.
    pd_frames: u64,
    since_pd: u64,
    /// Frames before the epoch.
    pre_epoch_frames: u64,
    /// Per fault: the real time its window starts, ps, for a fault injected at a time (`None`:
    /// the schedule's `at_s` after the epoch).
    anchor_ps: Vec<Option<u64>>,
    /// Per fault: started, ended; a burst's frames left.
    started: Vec<bool>,
    ended: Vec<bool>,
    burst_left: Vec<u32>,
    events: Vec<FaultEvent>,
    counts: FaultCounts,
    /// The schedule's state before the first fault (slaves not yet connected) is set.
    initialised: bool,
}

/// The positions of the last `n` slaves of the segment (at least one stays).
fn hot_slaves(segment: &Segment, n: u16) -> std::ops::Range<usize> {
    let len = segment.len();
    len.saturating_sub(usize::from(n)).max(1).min(len)..len
}

/// The frames a fault of this kind takes in a row (0: not a burst).
fn burst_of(kind: &FaultKind) -> u32 {
    match *kind {
        FaultKind::Loss { burst, .. } | FaultKind::Corrupt { burst, .. } => burst.unwrap_or(0),
        _ => 0,
    }
}

impl FaultPlayer {
    /// A player of `schedule` whose random draws come from `seed` unless the schedule names
    /// its own.
    pub fn new(schedule: FaultSchedule, seed: u64) -> Self {
        let n = schedule.faults.len();
        FaultPlayer {
            seed: schedule.seed.unwrap_or(seed),
            burst_left: schedule.faults.iter().map(|f| burst_of(&f.kind)).collect(),
            schedule,
            origin_ps: None,
            frame_no: 0,
            pd_frames: 0,
            since_pd: 0,
            pre_epoch_frames: 0,
            anchor_ps: vec![None; n],
            started: vec![false; n],
            ended: vec![false; n],
            events: Vec::new(),
            counts: FaultCounts::default(),
            initialised: false,
        }
    }

    /// The schedule, with the faults injected so far after the file's (their indices are those
    /// [`FaultPlayer::inject`] returned).
    pub fn schedule(&self) -> &FaultSchedule {
        &self.schedule
    }

    /// What happened so far.
    pub fn events(&self) -> &[FaultEvent] {
        &self.events
    }

    /// What was done to frames so far.
    pub fn counts(&self) -> FaultCounts {
        self.counts
    }

    /// Real time of the epoch, ps, once it came.
    pub fn origin_ps(&self) -> Option<u64> {
        self.origin_ps
    }

    /// Sets the epoch to real time `t_ps` (a control command's "now"), whatever the schedule's
    /// `epoch` says: the schedule's `at_s` count from it, and the draws' frame numbers start
    /// again. Edges already played are not played again.
    pub fn set_epoch(&mut self, t_ps: u64) {
        self.origin_ps = Some(t_ps);
        self.pd_frames = 0;
        self.since_pd = 0;
    }

    /// Real time fault `f`'s window starts and ends, ps (`None`: no such fault, or a fault of
    /// the schedule before the epoch is known; an end of `None`: it lasts to the end).
    pub fn window_ps(&self, f: usize) -> Option<(u64, Option<u64>)> {
        let fault = self.schedule.faults.get(f)?;
        let start = match self.anchor_ps[f] {
            Some(a) => a,
            None => self
                .origin_ps?
                .saturating_add(fault.at_ns.saturating_mul(1000)),
        };
        let end = fault
            .for_ns
            .map(|d| start.saturating_add(d.saturating_mul(1000)));
        Some((start, end))
    }

    /// Whether fault `f` has started and not ended (its window is open).
    pub fn is_active(&self, f: usize) -> bool {
        self.started.get(f).is_some_and(|&s| s) && !self.ended[f]
    }

    /// Real time of the next edge (start or end) of a segment fault not yet played, ps: when
    /// a caller that waits between frames should call [`FaultPlayer::advance_to`]. `None`
    /// before the epoch is known (unless a fault was injected at a time) or when nothing is
    /// left.
    pub fn next_due_ps(&self) -> Option<u64> {
        (0..self.schedule.faults.len())
            .filter(|&f| !self.ended[f] && !self.schedule.faults[f].kind.is_host_fault())
            .filter_map(|f| {
                let (start, end) = self.window_ps(f)?;
                if self.started[f] { end } else { Some(start) }
            })
            .min()
    }

    /// Plays every edge of a segment fault due at or before real time `t_ps`, in time order,
    /// each at its own time: the segment's action (a slave off, a cable pulled) and the logged
    /// event are the edge's time, not `t_ps`. A window that lies between two frames happens.
    pub fn advance_to(&mut self, segment: &mut Segment, t_ps: u64) {
        self.play_due(segment, t_ps, false);
    }

    /// Adds segment fault `fault` whose window starts at real time `at_ps` (now or later; its
    /// `at_ns` is ignored) and returns its index in [`FaultPlayer::schedule`]. The window is
    /// anchored in real time, so it plays before the epoch too (its `at_ns` is set to its time
    /// after the epoch when that is known, else 0). Host faults (`is_host_fault`) are not
    /// played by a segment: callers refuse them.
    pub fn inject(&mut self, fault: Fault, at_ps: u64) -> usize {
        let f = self.schedule.faults.len();
        let at_ns = self.origin_ps.map_or(0, |o| at_ps.saturating_sub(o) / 1000);
        self.schedule.faults.push(Fault { at_ns, ..fault });
        self.anchor_ps.push(Some(at_ps));
        self.started.push(false);
        self.ended.push(false);
        self.burst_left.push(burst_of(&fault.kind));
        f
    }

    /// Ends now, at real time `t_ps`, the active segment fault `which` (`None`: all of them):
    /// its end edge is played and logged at `t_ps` (a slave on again, a cable plugged in).
    /// Edges due by `t_ps` are played first. Faults not started yet still come at their time.
    /// Returns how many were ended.
    pub fn clear(&mut self, segment: &mut Segment, which: Option<usize>, t_ps: u64) -> usize {
        self.advance_to(segment, t_ps);
        let mut n = 0;
        for f in 0..self.schedule.faults.len() {
            let kind = self.schedule.faults[f].kind;
            if which.is_some_and(|w| w != f) || !self.is_active(f) || kind.is_host_fault() {
                continue;
            }
            self.ended[f] = true;
            let detail = end_fault(segment, &kind, t_ps);
            self.log(t_ps, f, Edge::End, detail);
            n += 1;
        }
        n
    }

    fn since(&self, t_ps: u64) -> Option<u64> {
        self.origin_ps.map(|o| t_ps.saturating_sub(o) / 1000)
    }

    fn log(&mut self, t_ps: u64, fault: usize, edge: Edge, detail: String) {
        let kind = self.schedule.faults[fault].kind.name();
        self.events.push(FaultEvent {
            t_ps,
            since_epoch_ns: self.since(t_ps).unwrap_or(0),
            fault,
            kind,
            edge,
            detail,
        });
    }

    /// A uniform draw for fault `f` and the current frame: a hash, so every run of the schedule
    /// draws the same for the same frame whatever else happened.
    fn draw(&self, f: usize) -> f64 {
        let mut r = SplitMix64(
            self.seed ^ (self.frame_no.wrapping_mul(0x9E37_79B9_7F4A_7C15)) ^ ((f as u64) << 48),
        );
        r.next();
        unit_from_bits(r.next())
    }

    /// Sets the segment up as the schedule has it before its first fault: slaves that appear
    /// later (hot connect) not connected yet. [`FaultPlayer::before_frame`] does it at the
    /// first frame; a caller that attaches the player later (at the cyclic phase) calls it
    /// before the bring-up.
    pub fn prepare(&mut self, segment: &mut Segment) {
        self.initialised = true;
        for f in self.schedule.faults.iter() {
            if let FaultKind::HotConnect { slaves } = f.kind {
                for p in hot_slaves(segment, slaves) {
                    segment.start_unplugged(p, segment.entry_port(p));
                }
            }
        }
    }

    /// Plays the segment faults' edges due by `t_ps`, in time order; `at_frame`: each at `t_ps`
    /// (a frame-driven caller's, see [`FaultPlayer::before_frame`]), else at its own time.
    fn play_due(&mut self, segment: &mut Segment, t_ps: u64, at_frame: bool) {
        if !self.initialised {
            self.prepare(segment);
        }
        let mut due: Vec<(u64, usize, Edge)> = Vec::new();
        for f in 0..self.schedule.faults.len() {
            if self.ended[f] || self.schedule.faults[f].kind.is_host_fault() {
                continue;
            }
            let Some((start, end)) = self.window_ps(f) else {
                continue;
            };
            if start > t_ps {
                continue;
            }
            if !self.started[f] {
                due.push((start, f, Edge::Start));
            }
            if let Some(end) = end
                && end <= t_ps
            {
                due.push((end, f, Edge::End));
            }
        }
        if at_frame {
            due.iter_mut().for_each(|d| d.0 = t_ps);
        }
        // Ties (a zero-length window, edges played at one frame) go by the schedule's order,
        // a fault's start before its end.
        due.sort_by_key(|&(t, f, edge)| (t, f, edge == Edge::End));
        for (t, f, edge) in due {
            let kind = self.schedule.faults[f].kind;
            let detail = match edge {
                Edge::Start => {
                    self.started[f] = true;
                    start_fault(segment, &kind, t)
                }
                Edge::End => {
                    self.ended[f] = true;
                    end_fault(segment, &kind, t)
                }
            };
            self.log(t, f, edge, detail);
        }
    }

    /// Numbers the current frame for the draws: the frames with process data since the epoch,
    /// and the others since the last of them. A master's extra frames (a recovery's, a
    /// diagnosis') then leave the cyclic frames' draws as they are: every method of a
    /// comparison loses the same cycles.
    fn number(&mut self, process_data: bool) {
        if self.origin_ps.is_none() {
            self.pre_epoch_frames += 1;
            self.frame_no = PRE_EPOCH_FRAME | self.pre_epoch_frames;
            return;
        }
        if process_data {
            self.pd_frames += 1;
            self.since_pd = 0;
        } else {
            self.since_pd += 1;
        }
        self.frame_no = self.pd_frames << 16 | self.since_pd.min(0xffff);
    }

    /// Before `segment` takes a frame leaving at real time `t_ps`: starts and ends the
    /// segment's faults that are due (power, links) and says what becomes of the frame.
    ///
    /// The edges due are played at `t_ps`, the frame's time: a simulator whose only events are
    /// its frames (one a cycle) sees each edge at the first frame after it, as it always has,
    /// so its outputs stay what they were. A caller that waits between frames calls
    /// [`FaultPlayer::advance_to`] (at [`FaultPlayer::next_due_ps`], and with the frame's time
    /// before this) to have each edge at its own time.
    pub fn before_frame(&mut self, segment: &mut Segment, frame: &[u8], t_ps: u64) -> FrameFate {
        let pd = carries_process_data(frame);
        if self.origin_ps.is_none() && (self.schedule.epoch == Epoch::Start || pd) {
            self.origin_ps = Some(t_ps);
        }
        self.play_due(segment, t_ps, true);
        self.number(pd);
        let mut fate = FrameFate::default();
        for f in 0..self.schedule.faults.len() {
            let fault = self.schedule.faults[f];
            if fault.kind.is_host_fault() || !self.is_active(f) {
                continue;
            }
            match fault.kind {
                FaultKind::Loss { probability, burst } if self.take(f, burst, probability) => {
                    // Lost on the way out or back, evenly.
                    if self.draw(f + 1000) < 0.5 {
                        fate.lost_out = true;
                    } else {
                        fate.lost_back = true;
                    }
                }
                FaultKind::Corrupt { probability, burst } if self.take(f, burst, probability) => {
                    fate.lost_back = true;
                    fate.corrupt = true;
                    self.counts.corrupted += 1;
                }
                FaultKind::Delay { extra_ns } => {
                    fate.extra_delay_ps = fate.extra_delay_ps.saturating_add(extra_ns * 1000);
                }
                FaultKind::SecondResponder { lag_ns } => fate.copy_after_ps = Some(lag_ns * 1000),
                _ => {}
            }
        }
        if fate.lost_out {
            self.counts.lost_out += 1;
            fate.lost_back = false;
            fate.corrupt = false;
        } else if fate.lost_back {
            self.counts.lost_back += 1;
        }
        if fate.corrupt {
            segment.break_fcs_of_next_frame();
        }
        if pd && (fate.lost_out || fate.lost_back) {
            self.counts.lost_with_process_data += 1;
        }
        if !fate.lost_out && !fate.lost_back {
            self.counts.delayed += u64::from(fate.extra_delay_ps > 0);
            self.counts.duplicated += u64::from(fate.copy_after_ps.is_some());
        }
        fate
    }

    /// Whether fault `f` takes the current frame: a burst's next frame, or a draw.
    fn take(&mut self, f: usize, burst: Option<u32>, probability: f64) -> bool {
        match burst {
            Some(_) => {
                if self.burst_left[f] > 0 {
                    self.burst_left[f] -= 1;
                    true
                } else {
                    false
                }
            }
            None => probability > 0.0 && self.draw(f) < probability,
        }
    }

    /// The master host's faults due by real time `t_ps`: the stall to add to a wake-up now, ns,
    /// and the step of the master's clock, ns. Each is played once.
    pub fn host_faults(&mut self, t_ps: u64) -> (u64, i64) {
        let Some(now) = self.since(t_ps) else {
            return (0, 0);
        };
        let (mut stall, mut step) = (0u64, 0i64);
        for f in 0..self.schedule.faults.len() {
            let fault = self.schedule.faults[f];
            if self.started[f] || now < fault.at_ns {
                continue;
            }
            let detail = match fault.kind {
                FaultKind::HostStall { stall_ns } => {
                    stall += stall_ns;
                    format!("the cyclic task stalls {} us", stall_ns / 1000)
                }
                FaultKind::ClockStep { step_ns } => {
                    step += step_ns;
                    format!("the master's clock steps {} us", step_ns as f64 / 1e3)
                }
                _ => continue,
            };
            self.started[f] = true;
            self.ended[f] = true;
            self.log(t_ps, f, Edge::Start, detail);
        }
        (stall, step)
    }
}

/// Whether a frame carries process data: an LRW, LRD or LWR datagram (the cyclic phase has
/// begun, whichever way the master exchanges its process data).
fn carries_process_data(frame: &[u8]) -> bool {
    EcatFrame::new_checked(frame).is_ok_and(|f| {
        f.datagrams().any(|d| {
            d.is_ok_and(|d| matches!(d.command(), Ok(Command::Lrw | Command::Lrd | Command::Lwr)))
        })
    })
}

fn resolve(segment: &Segment, slave: SlaveRef) -> Option<usize> {
    match slave {
        SlaveRef::Position(p) => (p < segment.len()).then_some(p),
        SlaveRef::Reference => (0..segment.len()).find(|&p| segment.esc(p).dc().is_some()),
    }
}

fn start_fault(segment: &mut Segment, kind: &FaultKind, t_ps: u64) -> String {
    match *kind {
        FaultKind::HotConnect { slaves } => {
            let r = hot_slaves(segment, slaves);
            for p in r.clone() {
                segment.set_link(p, segment.entry_port(p), true);
            }
            format!("slaves {} to {} connected", r.start + 1, r.end)
        }
        FaultKind::AlError { slave, code } => match resolve(segment, slave) {
            Some(p) => {
                let code = ecsync_wire::AlStatusCode::from(code);
                segment.esc_mut(p).raise_al_error(code);
                format!(
                    "slave {}: AL error {code}, now {}",
                    p + 1,
                    segment.esc(p).al_state()
                )
            }
            None => format!("{slave} is not in the segment: no error raised"),
        },
        FaultKind::PowerCycle { slave } => match resolve(segment, slave) {
            Some(p) => {
                segment.power_off(p, t_ps);
                format!("slave {} switched off", p + 1)
            }
            None => format!("{slave} is not in the segment: nothing switched off"),
        },
        FaultKind::LinkDown { slave, port } => match resolve(segment, slave) {
            Some(p) => {
                if segment.set_link(p, usize::from(port), false) {
                    format!("the cable at port {port} of slave {} pulled", p + 1)
                } else {
                    format!(
                        "slave {} has no cable at port {port}: nothing pulled",
                        p + 1
                    )
                }
            }
            None => format!("{slave} is not in the segment: nothing pulled"),
        },
        _ => String::new(),
    }
}

fn end_fault(segment: &mut Segment, kind: &FaultKind, t_ps: u64) -> String {
    match *kind {
        FaultKind::PowerCycle { slave } => match resolve_off(segment, slave) {
            Some(p) => {
                segment.power_on(p, t_ps);
                format!("slave {} switched on again (from reset)", p + 1)
            }
            None => String::new(),
        },
        FaultKind::LinkDown { slave, port } => match resolve(segment, slave) {
            Some(p) => {
                segment.set_link(p, usize::from(port), true);
                format!(
                    "the cable at port {port} of slave {} plugged in again",
                    p + 1
                )
            }
            None => String::new(),
        },
        _ => String::new(),
    }
}

/// The slave a power cycle switched off (the reference is looked up among the slaves that are
/// off, as its DC unit is gone while it is).
fn resolve_off(segment: &Segment, slave: SlaveRef) -> Option<usize> {
    match slave {
        SlaveRef::Position(p) => (p < segment.len()).then_some(p),
        SlaveRef::Reference => {
            (0..segment.len()).find(|&p| segment.is_powered_off(p) || segment.esc(p).dc().is_some())
        }
    }
}
