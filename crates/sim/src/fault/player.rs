//! The player: the schedule made to happen, frame by frame, on a segment and its master's host.

use super::{Epoch, FaultKind, FaultSchedule, KindName, SlaveRef};
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

/// Plays a [`FaultSchedule`] on a segment, frame by frame.
#[derive(Debug, Clone)]
pub struct FaultPlayer {
    schedule: FaultSchedule,
    seed: u64,
    origin_ps: Option<u64>,
    /// The current frame's number for the draws (see [`FaultPlayer::before_frame`]).
    frame_no: u64,
    lrw_frames: u64,
    since_lrw: u64,
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

impl FaultPlayer {
    /// A player of `schedule` whose random draws come from `seed` unless the schedule names
    /// its own.
    pub fn new(schedule: FaultSchedule, seed: u64) -> Self {
        let n = schedule.faults.len();
        FaultPlayer {
            seed: schedule.seed.unwrap_or(seed),
            burst_left: schedule
                .faults
                .iter()
                .map(|f| match f.kind {
                    FaultKind::Loss { burst, .. } | FaultKind::Corrupt { burst, .. } => {
                        burst.unwrap_or(0)
                    }
                    _ => 0,
                })
                .collect(),
            schedule,
            origin_ps: None,
            frame_no: 0,
            lrw_frames: 0,
            since_lrw: 0,
            started: vec![false; n],
            ended: vec![false; n],
            events: Vec::new(),
            counts: FaultCounts::default(),
            initialised: false,
        }
    }

    /// The schedule.
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
                    segment.set_link(p, segment.entry_port(p), false);
                }
            }
        }
    }

    /// Before `segment` takes a frame leaving at real time `t_ps`: starts and ends the
    /// segment's faults that are due (power, links) and says what becomes of the frame.
    pub fn before_frame(&mut self, segment: &mut Segment, frame: &[u8], t_ps: u64) -> FrameFate {
        if !self.initialised {
            self.prepare(segment);
        }
        if self.origin_ps.is_none() {
            let at_epoch = match self.schedule.epoch {
                Epoch::Start => true,
                Epoch::Cyclic => carries_lrw(frame),
            };
            if !at_epoch {
                return FrameFate::default();
            }
            self.origin_ps = Some(t_ps);
        }
        let now = self.since(t_ps).unwrap_or(0);
        // A frame's number: the frames with process data since the epoch, and the others
        // since the last of them. A master's extra frames (a recovery's, a diagnosis') then
        // leave the cyclic frames' draws as they are: every method of a comparison loses the
        // same cycles.
        let lrw = carries_lrw(frame);
        if lrw {
            self.lrw_frames += 1;
            self.since_lrw = 0;
        } else {
            self.since_lrw += 1;
        }
        self.frame_no = self.lrw_frames << 16 | self.since_lrw.min(0xffff);
        let mut fate = FrameFate::default();
        for f in 0..self.schedule.faults.len() {
            let fault = self.schedule.faults[f];
            if fault.kind.is_host_fault() {
                continue;
            }
            let covers = fault.covers(now);
            if covers && !self.started[f] {
                self.started[f] = true;
                let detail = start_fault(segment, &fault.kind, t_ps);
                self.log(t_ps, f, Edge::Start, detail);
            }
            if self.started[f] && !covers && !self.ended[f] && now >= fault.at_ns {
                self.ended[f] = true;
                let detail = end_fault(segment, &fault.kind, t_ps);
                self.log(t_ps, f, Edge::End, detail);
            }
            if !covers {
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
        } else if fate.lost_back {
            self.counts.lost_back += 1;
        }
        if lrw && (fate.lost_out || fate.lost_back) {
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

/// Whether a frame carries an LRW (the cyclic phase has begun).
fn carries_lrw(frame: &[u8]) -> bool {
    EcatFrame::new_checked(frame).is_ok_and(|f| {
        f.datagrams()
            .any(|d| d.is_ok_and(|d| d.command() == Ok(Command::Lrw)))
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
