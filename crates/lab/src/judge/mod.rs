//! The judge: what a master that ecsync does not control (any master on the other end of
//! `ecsync serve`) did right or wrong, from the segment's ground truth, frame by frame.
//!
//! Per run and per drive, over the frames with process data (any LRW, LRD or LWR datagram):
//! the working counter against the run's usual one; the frame's phase at the reference (the
//! first slave whose SYNC0 runs) against its SYNC0 pulses; each DC drive's SYNC0 margin (its
//! next pulse minus the instant the frame's last bit passed it), the frames that came after
//! the pulse they were meant for (`late`) and the pulses with no new outputs since the one
//! before (`missed`); the drives' spread and 0x092C as the master would read it; lost,
//! late-answered and repeated frames; the AL errors raised (the drives' own error flags) and
//! those the master read; the way back to OP after each fault. [`Judge::summary`] gives it as
//! [`JudgeOut`] (summary.json), [`report_html`] as compare's report, [`Expect`] tests it
//! against thresholds (`--expect`).
//!
//! A black box does not say which pulse a frame was meant for: the judge takes the pulse whose
//! offset from the frame is nearest the typical offset of the last 16 frames (their median,
//! kept within one cycle before a pulse), and calls the frame late at a drive when its last
//! bit passed the drive after that pulse. A second late frame in a row with one pulse since the
//! first, the last four frames marching steadily over the pulse, means the master's frames
//! moved past it for good (a master not synchronized to DC drifting over the grid): from it on
//! they are meant for the next pulse, and the crossing costs one late frame and one missed
//! pulse; a master whose frames jitter late twice in a row has two late frames, as compare
//! counts them (its late frames, missed pulses, phase and margins are compare's on
//! paper-2024, tests/judge_compare.rs). The pulses' grid runs back from SYNC0's start
//! time as compare's grid does; no pulse is missed before the first. [`Judge::frame`]
//! allocates nothing once the statistics' ranges are settled (it runs in serve's real-time
//! loop).
//!
//! What a frame carries is read from its datagrams: the process data frames' outputs are taken
//! to reach every DC drive the frame passes (the FMMU mapping is not read: a master that splits
//! its drives' outputs over several frames has each drive's missed pulses undercounted).
//!
//! AL errors are counted from the segment's truth: each time a drive's error flag (0x0130 bit
//! 4) goes from clear to set, with its code (0x0134), as the ESC holds them after each frame
//! (an error raised between two frames is seen at the next; the master need not read AL
//! status). A flag raised and cleared again between two frames' ends (acknowledged in the
//! frame that read it) is counted when that frame read it set. What the master read
//! (FPRD/APRD/FPRW/APRW of 0x0130) is counted apart, as the error flag appearing in its reads.

mod expect;
mod out;
mod parse;
mod report;
mod track;

pub use expect::{Expect, ExpectError};
pub use out::{DriveOut, FaultOut, JudgeOut, PhaseOut, per_drive_table};
pub use report::report_html;

use crate::stats::Stats;
use ecsync_sim::Segment;
use ecsync_sim::fault::{Edge, FaultEvent};
use ecsync_sim::phy::frame_wire_time_ps;
use ecsync_wire::AlState;
use ecsync_wire::dc_time::decode_time_difference;
use parse::{AlRead, MAX_AL_READS, parse};
use track::{BandBlocks, Slope, Tracker, WkcWatch};

/// How a [`Judge`] is set up.
#[derive(Debug, Clone)]
pub struct JudgeOptions {
    /// Per network position, the scenario's slave names (missing ones are named `slave N`).
    pub names: Vec<String>,
    /// The preset or scenario served, for the report.
    pub preset: String,
    /// A reply the serving host sent more than this past its wire time is counted late, ns.
    pub late_reply_ns: u64,
    /// A reply sent more than this past its wire time is counted as a stall of the serving
    /// host too (long enough to cost a master its reply), ns.
    pub stalled_reply_ns: u64,
    /// A frame that repeats the index and datagram headers of one sent less than this before
    /// is a retry, ns (and one that repeats a lost frame's within 100 ms).
    pub retry_window_ns: u64,
    /// Frames with process data per point of the plots' bands.
    pub band_frames: u64,
}

impl Default for JudgeOptions {
    fn default() -> Self {
        JudgeOptions {
            names: Vec::new(),
            preset: String::new(),
            late_reply_ns: 10_000,
            stalled_reply_ns: 1_000_000,
            retry_window_ns: 500_000,
            band_frames: 1000,
        }
    }
}

/// What became of a frame on its way (the fault player's verdict, or the segment's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lost {
    /// Answered.
    No,
    /// Lost before the first slave: the segment did not process it (its trace is not this
    /// frame's).
    Out,
    /// Processed, then lost on the way back: its outputs reached the drives, the master got
    /// no answer.
    Back,
}

/// Within this after a lost frame, a frame repeating its index and headers is a retry, ps.
const RETRY_AFTER_LOSS_PS: u64 = 100_000_000_000;

/// One drive's state and figures.
#[derive(Debug, Clone)]
struct Drive {
    name: String,
    /// The events its application takes outputs at (start time, cycle) at the last frame:
    /// SYNC0's pulses, or SYNC1's for a drive on SYNC1 (an oversampling terminal).
    sync0: Option<(u64, u32)>,
    /// It runs on SYNC1.
    on_sync1: bool,
    /// Outputs that no event took: a frame after them came before the next event.
    overwritten: u64,
    track: Tracker,
    margin: Stats,
    late: u64,
    missed: u64,
    /// The system time (ns) its last outputs were complete at.
    last_out_ns: Option<u64>,
    frames: u64,
    time_diff: Stats,
    /// Largest |system time - the reference's|, ns.
    dev_max_ns: f64,
    /// AL errors raised: the error flag going from clear to set (the ESC's, or a read's).
    al_errors: u64,
    /// The AL status codes seen with the error flag, in order of first appearance.
    al_codes: Vec<u16>,
    /// The error flag as the ESC held it after the last frame.
    al_error_now: bool,
    /// AL errors the master read: the error flag appearing in its reads of 0x0130.
    al_errors_read: u64,
    /// The error flag as the master last read it.
    al_read_now: bool,
    in_op: bool,
    reached: bool,
    /// The last frame came after its pulse.
    prev_late: bool,
    /// The drive application's last outputs as the judge last saw them (drives on SYNC0).
    outputs_seen_ns: Option<u64>,
    /// Frames with outputs between the last pulse and the next, so far.
    in_interval: u32,
    /// How many a steady interval gets (one per pulse for a master whose cycle is SYNC0's).
    usual_in_interval: u32,
    /// The pulses before this interval that found no new outputs and no frame of this
    /// interval was counted late for yet.
    missed_unclaimed: u32,
    /// This interval followed a missed pulse.
    after_miss: bool,
}

impl Drive {
    fn new(name: String) -> Self {
        Drive {
            name,
            sync0: None,
            on_sync1: false,
            overwritten: 0,
            track: Tracker::default(),
            margin: Stats::new(),
            late: 0,
            missed: 0,
            last_out_ns: None,
            frames: 0,
            time_diff: Stats::new(),
            dev_max_ns: 0.0,
            al_errors: 0,
            al_codes: Vec::with_capacity(8),
            al_error_now: false,
            al_errors_read: 0,
            al_read_now: false,
            in_op: false,
            reached: false,
            prev_late: false,
            outputs_seen_ns: None,
            in_interval: 0,
            usual_in_interval: 1,
            missed_unclaimed: 0,
            after_miss: false,
        }
    }

    /// Counts a frame with outputs into the pulse intervals (`pulses`: the pulses since the
    /// last one's outputs, `None` for the first) and says whether it shows that a frame before
    /// it was late: pulses found no new outputs, and the interval after them gets more frames
    /// than a steady interval does. Each frame more was meant for one of the pulses missed
    /// (a master delayed past its pulse by more than the distance from its usual instant to the
    /// pulse after, which the tracker alone takes for an early frame for the next pulse; or a
    /// master that stalled and then sends the cycles it owes at once).
    fn interval(&mut self, pulses: Option<i64>, late_now: bool) -> bool {
        match pulses {
            Some(0) => self.in_interval += 1,
            Some(n) if n > 0 => {
                if !self.after_miss && self.in_interval > 0 {
                    self.usual_in_interval = self.in_interval;
                }
                self.after_miss = n >= 2;
                self.missed_unclaimed = (n - 1) as u32;
                self.in_interval = 1;
            }
            _ => {
                self.in_interval = 1;
                self.after_miss = false;
                self.missed_unclaimed = 0;
            }
        }
        if late_now {
            // Late by the tracker: it claims one of the pulses missed.
            self.missed_unclaimed = self.missed_unclaimed.saturating_sub(1);
            return false;
        }
        let retro = self.missed_unclaimed > 0 && self.in_interval > self.usual_in_interval;
        if retro {
            self.missed_unclaimed -= 1;
        }
        retro
    }
}

/// A fault that started, and the way back.
#[derive(Debug, Clone)]
struct FaultRec {
    fault: usize,
    kind: String,
    detail: String,
    start_ps: u64,
    end_ps: Option<u64>,
    /// Positions in OP when it started.
    in_op: Vec<usize>,
    /// The usual working counter before it.
    usual_wkc: Option<u32>,
    recovered_ps: Option<u64>,
}

/// An index's last frame: its headers' hash, when, whether it was lost.
#[derive(Debug, Clone, Copy, Default)]
struct Sent {
    shape: u64,
    t_ps: u64,
    /// The last interval at which frames of this index and shape repeated (not a retry), ps.
    gap_ps: u64,
    seen: bool,
    lost: bool,
}

/// The judge of a black-box master: see the module documentation.
#[derive(Debug, Clone)]
pub struct Judge {
    opts: JudgeOptions,
    drives: Vec<Drive>,
    first_ps: Option<u64>,
    last_ps: u64,
    frames: u64,
    pd_frames: u64,
    lost: u64,
    lost_pd: u64,
    wkc: WkcWatch,
    last_wkc: Option<u32>,
    /// The first datagram's index of the last frame with process data (a ring's second copy
    /// of it completes its working counter).
    last_pd_index: Option<u8>,
    /// The reference's SYNC0 (position, start, cycle) at the last frame that had one.
    reference: Option<(usize, u64, u32)>,
    phase_track: Tracker,
    phase: Stats,
    phase_fit: Slope,
    spread: Stats,
    worst_margin: Stats,
    late: u64,
    missed: u64,
    replies_late: u64,
    replies_stalled: u64,
    reply_late_max_ns: u64,
    retries: u64,
    sent: Box<[Sent; 256]>,
    faults: Vec<FaultRec>,
    phase_bands: BandBlocks,
    margin_bands: BandBlocks,
    al: [Option<AlRead>; MAX_AL_READS],
}

impl Judge {
    /// A judge of the master that will talk to `seg`.
    pub fn new(seg: &Segment, opts: JudgeOptions) -> Judge {
        let drives = (0..seg.len())
            .map(|p| {
                let name = opts
                    .names
                    .get(p)
                    .cloned()
                    .unwrap_or_else(|| format!("slave {}", p + 1));
                Drive::new(name)
            })
            .collect();
        Judge {
            phase_bands: BandBlocks::new(opts.band_frames),
            margin_bands: BandBlocks::new(opts.band_frames),
            opts,
            drives,
            first_ps: None,
            last_ps: 0,
            frames: 0,
            pd_frames: 0,
            lost: 0,
            lost_pd: 0,
            wkc: WkcWatch::default(),
            last_wkc: None,
            last_pd_index: None,
            reference: None,
            phase_track: Tracker::default(),
            phase: Stats::new(),
            phase_fit: Slope::default(),
            spread: Stats::new(),
            worst_margin: Stats::new(),
            late: 0,
            missed: 0,
            replies_late: 0,
            replies_stalled: 0,
            reply_late_max_ns: 0,
            retries: 0,
            sent: Box::new([Sent::default(); 256]),
            faults: Vec::with_capacity(16),
            al: [None; MAX_AL_READS],
        }
    }

    /// After the segment processed (or the fault player dropped) one frame that left the master
    /// at real time `t_ps` (ps, the segment's time line): `frame` as the segment returned it
    /// (working counters filled in; the request itself when [`Lost::Out`]); `seg.trace()` is
    /// this frame's unless it was lost on the way out. Call it for every frame, the bring-up's
    /// too (AL status reads, retries).
    pub fn frame(&mut self, seg: &Segment, frame: &[u8], t_ps: u64, lost: Lost) {
        self.first_ps.get_or_insert(t_ps);
        self.last_ps = self.last_ps.max(t_ps);
        self.frames += 1;
        let (info, n_al) = parse(frame, &mut self.al);
        self.retry(&info, t_ps, lost);
        if lost != Lost::No {
            self.lost += 1;
            self.lost_pd += u64::from(info.process_data);
        }
        if lost == Lost::Out {
            // Nothing reached a slave; an error raised since the last frame is there.
            self.al_truth(seg);
            return;
        }
        let trace = seg.trace();
        for (p, d) in self.drives.iter_mut().enumerate() {
            d.in_op = seg.esc(p).al_state() == AlState::Op && !seg.is_powered_off(p);
            d.reached = trace.pu_ps(p).is_some();
        }
        if lost == Lost::No {
            self.al_reads(seg, n_al);
        }
        self.al_truth(seg);
        if !info.process_data {
            return;
        }
        let k = self.pd_frames;
        self.pd_frames += 1;
        self.wkc.add(info.pd_wkc, self.last_wkc);
        self.last_wkc = Some(info.pd_wkc);
        self.last_pd_index = Some(info.index);
        if lost == Lost::No {
            self.recoveries(info.pd_wkc, t_ps);
        }
        self.reference_phase(seg, k, t_ps);
        if info.outputs {
            let wire_ps = frame_wire_time_ps(frame.len());
            self.margins(seg, k, wire_ps);
        }
    }

    /// After the segment processed a redundant master's second copy of a frame, which entered a
    /// ring at its far end ([`Judge::frame`] saw the first copy): the slaves it reached (those
    /// beyond a break; an intact ring's copy passes the ports alone and reaches none) have
    /// their margins, late frames and missed pulses from it, and its working counter completes
    /// the first copy's (the master merges the two). Nothing else counts it: the frame is the
    /// first copy's.
    pub fn frame_on_ring(&mut self, seg: &Segment, frame: &[u8], t_ps: u64, lost: Lost) {
        self.last_ps = self.last_ps.max(t_ps);
        self.al_truth(seg);
        if lost != Lost::No {
            return;
        }
        let (info, _) = parse(frame, &mut self.al);
        let trace = seg.trace();
        if !info.process_data || !(0..seg.len()).any(|p| trace.pu_ps(p).is_some()) {
            return;
        }
        if self.last_pd_index == Some(info.index)
            && let Some(first) = self.last_wkc
            && info.pd_wkc > 0
        {
            let whole = first + info.pd_wkc;
            self.wkc.amend(first, whole);
            self.last_wkc = Some(whole);
        }
        if info.outputs {
            let wire_ps = frame_wire_time_ps(frame.len());
            self.margins(seg, self.pd_frames.saturating_sub(1), wire_ps);
        }
    }

    /// The serving host sent a reply `host_late_ns` past its wire time.
    pub fn reply_late(&mut self, host_late_ns: u64) {
        if host_late_ns > self.opts.late_reply_ns {
            self.replies_late += 1;
        }
        if host_late_ns > self.opts.stalled_reply_ns {
            self.replies_stalled += 1;
        }
        self.reply_late_max_ns = self.reply_late_max_ns.max(host_late_ns);
    }

    /// A fault the player played (its start or end).
    pub fn fault_event(&mut self, ev: &FaultEvent) {
        match ev.edge {
            Edge::Start => self.faults.push(FaultRec {
                fault: ev.fault,
                kind: ev.kind.as_str().to_string(),
                detail: ev.detail.clone(),
                start_ps: ev.t_ps,
                end_ps: None,
                in_op: (0..self.drives.len())
                    .filter(|&p| self.drives[p].in_op)
                    .collect(),
                usual_wkc: self.wkc.usual,
                recovered_ps: None,
            }),
            Edge::End => {
                if let Some(f) = self.faults.iter_mut().rev().find(|f| f.fault == ev.fault) {
                    f.end_ps = Some(ev.t_ps);
                }
            }
        }
    }

    /// A retry: the index and headers of a frame sent a moment ago, or of a lost one.
    fn retry(&mut self, info: &parse::FrameInfo, t_ps: u64, lost: Lost) {
        if info.datagrams == 0 {
            return;
        }
        let s = &mut self.sent[usize::from(info.index)];
        let mut gap_ps = 0;
        if s.seen && s.shape == info.shape {
            let dt = t_ps.saturating_sub(s.t_ps);
            // Sooner than this index's frames usually repeat (a master that sends its cyclic
            // frame with one index every cycle does not retry each time).
            let sooner = s.gap_ps == 0 || dt.saturating_mul(4) < s.gap_ps.saturating_mul(3);
            let window = dt < self.opts.retry_window_ns * 1000;
            if sooner && (window || (s.lost && dt < RETRY_AFTER_LOSS_PS)) {
                self.retries += 1;
            } else {
                gap_ps = dt;
            }
        }
        *s = Sent {
            shape: info.shape,
            t_ps,
            gap_ps: if gap_ps > 0 { gap_ps } else { s.gap_ps },
            seen: true,
            lost: lost != Lost::No,
        };
    }

    /// The AL errors as the ESCs hold them after a frame: a drive's error flag going from clear
    /// to set counts once, with its code (a powered-off drive's flag is clear).
    fn al_truth(&mut self, seg: &Segment) {
        for (p, d) in self.drives.iter_mut().enumerate().take(seg.len()) {
            let (_, set, code) = seg.esc(p).al_status();
            // A device emulation ESC's copied acknowledge is no error of the device.
            let set = set && !seg.esc(p).al_error_is_echo() && !seg.is_powered_off(p);
            if set && !d.al_error_now {
                d.al_errors += 1;
            }
            if set && !d.al_codes.contains(&code) {
                d.al_codes.push(code);
            }
            d.al_error_now = set;
        }
    }

    /// The AL status reads of an answered frame: an error flag that appears in them counts
    /// once as read; one the ESC did not hold after the last frame counts as raised (the same
    /// frame may clear it before [`Judge::al_truth`] looks).
    fn al_reads(&mut self, seg: &Segment, n: usize) {
        let visited = (0..seg.len()).filter(|&p| self.drives[p].reached).count() as u16;
        for r in self.al[..n].iter().flatten() {
            let pos = match (r.station, r.returned_adp) {
                (Some(st), _) => position_of(seg, st),
                (None, Some(adp)) => Some(usize::from(visited.wrapping_sub(adp))),
                _ => None,
            };
            let Some((p, d)) = pos.and_then(|p| Some((p, self.drives.get_mut(p)?))) else {
                continue;
            };
            let echo = p < seg.len() && seg.esc(p).al_error_is_echo();
            let error = r.status & 0x10 != 0 && !echo;
            if error && !d.al_read_now {
                d.al_errors_read += 1;
            }
            if error && !d.al_error_now {
                d.al_errors += 1;
                d.al_error_now = true;
            }
            if error
                && let Some(c) = r.code
                && !d.al_codes.contains(&c)
            {
                d.al_codes.push(c);
            }
            d.al_read_now = error;
        }
    }

    /// A frame with process data that came back: faults whose drives are all in OP again.
    fn recoveries(&mut self, wkc: u32, t_ps: u64) {
        for f in self.faults.iter_mut().filter(|f| f.recovered_ps.is_none()) {
            let flowing = wkc != 0 && f.usual_wkc.is_none_or(|u| u == wkc);
            let all_op = f
                .in_op
                .iter()
                .all(|&p| self.drives[p].in_op && self.drives[p].reached);
            if flowing && all_op && t_ps >= f.start_ps {
                f.recovered_ps = Some(t_ps);
            }
        }
    }

    /// The frame's phase at the reference: the first slave whose SYNC0 runs; its spread
    /// every 8th frame.
    fn reference_phase(&mut self, seg: &Segment, k: u64, t_ps: u64) {
        let trace = seg.trace();
        let found = (0..seg.len()).find_map(|p| {
            let dc = seg.esc(p).dc()?;
            let (s, c) = dc.sync0().filter(|x| x.1 > 0)?;
            Some((p, s, c, dc))
        });
        let Some((r, s, c, dc)) = found else {
            return;
        };
        if self.reference.is_some_and(|x| x != (r, s, c)) {
            self.phase_track.reset();
        }
        self.reference = Some((r, s, c));
        let Some(pu) = trace.pu_ps(r) else { return };
        let at = dc.system_time_split(pu);
        // The pulses' grid runs back from the start time too (as compare's grid does): frames
        // before SYNC0's first pulse are judged against it, and miss no pulse.
        let p = f64::from(c);
        let x = after_pulse(at, s, c);
        let phase = self.phase_track.place(x, p);
        self.phase.add(phase);
        self.phase_fit
            .add(t_ps as f64 / 1e12, self.phase_track.unwrapped());
        self.phase_bands.add(k, phase);
        if k.is_multiple_of(8) {
            let mut worst = 0.0f64;
            for (x, d) in self.drives.iter_mut().enumerate() {
                let Some(dx) = seg.esc(x).dc().filter(|u| u.sync0().is_some()) else {
                    continue;
                };
                if x == r {
                    continue;
                }
                let v = dx.system_time_split(pu);
                let dev = ((v.0.wrapping_sub(at.0) as i64) as f64 + (v.1 - at.1)).abs();
                d.dev_max_ns = d.dev_max_ns.max(dev);
                worst = worst.max(dev);
            }
            self.spread.add(worst);
        }
    }

    /// Each DC drive's margin before the SYNC0 pulse the frame's outputs were meant for, its
    /// late frames and missed pulses, and its 0x092C.
    fn margins(&mut self, seg: &Segment, k: u64, wire_ps: u64) {
        let trace = seg.trace();
        let mut worst = f64::INFINITY;
        // The drives share one grid: the pulses a frame's lateness left without outputs are
        // counted once for the run (the most any drive missed), per drive each.
        let mut most_missed = 0;
        let mut any_retro = false;
        for (x, d) in self.drives.iter_mut().enumerate() {
            let esc = seg.esc(x);
            // A drive on SYNC1 (an oversampling terminal) takes its outputs at SYNC1's events.
            let sync = esc.application_events().filter(|s| s.1 > 0);
            d.on_sync1 = esc.runs_on_sync1();
            if sync != d.sync0 || seg.is_powered_off(x) {
                d.track.reset();
                d.last_out_ns = None;
                d.prev_late = false;
                d.al_read_now &= !seg.is_powered_off(x);
            }
            d.sync0 = sync;
            let (Some(dc), Some((s, c)), Some(pu)) = (esc.dc(), sync, trace.pu_ps(x)) else {
                continue;
            };
            let mut raw = [0u8; 4];
            dc.read_time_difference(&mut raw, false);
            let td = decode_time_difference(u32::from_le_bytes(raw));
            d.time_diff.add(f64::from(td).abs());
            if esc.al_state() == AlState::SafeOp {
                // A drive in SAFE-OP keeps its outputs safe and takes none from the frames (a
                // master brings the process data up there before OP): no margin, no late
                // frame, no missed pulse until it is in OP.
                d.last_out_ns = None;
                d.prev_late = false;
                continue;
            }
            if !esc.runs_on_sync0() && !esc.has_outputs() {
                // A device without outputs (a coupler whose SYNC0 a master switched on, as
                // SOEM does on every DC slave): no frame is meant for a pulse of its.
                continue;
            }
            if esc.runs_on_sync0() {
                // The drive's application says whether this frame wrote its outputs: a frame
                // whose logical datagrams map only other drives' (a master that splits its
                // process data over frames) is not this drive's.
                let w = esc.last_outputs_ns();
                if w.is_none() || w == d.outputs_seen_ns {
                    continue;
                }
                d.outputs_seen_ns = w;
            }
            d.frames += 1;
            // Complete when the last bit has passed: the outputs take effect after the FCS.
            let e = dc.system_time_split(pu + wire_ps);
            // The pulses since the last outputs (none before SYNC0's first): all but the first
            // found none new.
            let pulse_no = |t: u64| {
                let d = dc_diff(t, s);
                if d < 0 { -1 } else { d / i64::from(c) }
            };
            let mut pulses = None;
            if let Some(prev) = d.last_out_ns.replace(e.0) {
                let n = pulse_no(e.0) - pulse_no(prev);
                if n == 0 {
                    // The outputs before these: no event took them.
                    d.overwritten += 1;
                }
                let m = (n - 1).max(0) as u64;
                d.missed += m;
                most_missed = most_missed.max(m);
                pulses = Some(n);
            }
            let x_after = after_pulse(e, s, c);
            let p = f64::from(c);
            let v = d.track.place(x_after, p);
            let mut margin = -v;
            if margin < 0.0 && d.prev_late && pulses == Some(1) && d.track.marching() {
                // A second frame after its pulse with one pulse since the last (late) one, the
                // recent frames marching steadily over it: the master's frames have moved past
                // the pulse (a master drifting over the grid, not synchronized to it): they
                // are meant for the next pulse, which this one makes. The pulse the move
                // skipped is counted missed, once. (Two late frames in a row of a master whose
                // frames jitter, a loaded host's, are both late, as compare counts them.)
                d.track.reanchor(v - p, p);
                margin += p;
            }
            d.prev_late = margin < 0.0;
            d.margin.add(margin);
            worst = worst.min(margin);
            let retro = d.interval(pulses, margin < 0.0);
            d.late += u64::from(margin < 0.0 || retro);
            any_retro |= retro;
        }
        self.missed += most_missed;
        // A frame found late afterwards (see `Drive::interval`) is counted with this one's.
        self.late += u64::from(worst < 0.0) + u64::from(any_retro);
        if worst.is_finite() {
            self.worst_margin.add(worst);
            self.margin_bands.add(k, worst);
        }
    }
}

/// The position of the slave with station address `st`: masters number them 0x1000 + n (SOEM,
/// ecsync), n + 1 or n, so those are tried first; then every slave (a large network's master
/// reads many slaves' AL status every cycle).
fn position_of(seg: &Segment, st: u16) -> Option<usize> {
    let n = seg.len();
    let is = |p: usize| p < n && seg.esc(p).station_address() == st;
    let guesses = [
        usize::from(st.wrapping_sub(0x1000)),
        usize::from(st.wrapping_sub(1)),
        usize::from(st),
    ];
    guesses
        .into_iter()
        .find(|&p| is(p))
        .or_else(|| (0..n).find(|&p| is(p)))
}

/// System time `t` minus `s`, ns, both on the unit's 64-bit time line (a 32-bit unit's
/// SYNC0 start is there too: `ecsync_sim::DcUnit::sync0`), so the pulses a cycle apart stay
/// so across the 32-bit register's wraps.
fn dc_diff(t: u64, s: u64) -> i64 {
    t.wrapping_sub(s) as i64
}

/// The time of `at` (system time, ns and fraction) after the last SYNC0 pulse at or before
/// it (pulses at `s` + n `c`), in [0, c), ns.
fn after_pulse(at: (u64, f64), s: u64, c: u32) -> f64 {
    let c = i64::from(c);
    let x = dc_diff(at.0, s).rem_euclid(c) as f64 + at.1;
    if x >= c as f64 { x - c as f64 } else { x }
}
