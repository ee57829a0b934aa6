//! The judge's figures as summary.json has them ([`JudgeOut`]), and the per-drive table for a
//! terminal.

use super::{Judge, Lost};
use crate::run::Band;
use crate::stats::{Dist, Stats};
use ecsync_sim::Segment;
use serde::Serialize;
use std::fmt::Write as _;

/// The master's frame phase at the reference, against its SYNC0 pulses: the time the frame's
/// first bit reached the reference after the pulse it was meant for (negative: before it), in
/// the reference's system time, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhaseOut {
    /// Frames measured.
    pub n: u64,
    /// Mean, ns.
    pub mean_ns: Option<f64>,
    /// Standard deviation, ns.
    pub std_ns: Option<f64>,
    /// 0.1th and 99.9th percentile of the phase itself, ns.
    pub p001_ns: Option<f64>,
    /// 99.9th percentile of the phase, ns.
    pub p999_ns: Option<f64>,
    /// 99.9th percentile of |phase - mean| (the jitter's half-width), ns: what `--expect
    /// phase_p999_us` tests.
    pub dev_p999_ns: Option<f64>,
    /// Smallest and largest, ns.
    pub min_ns: Option<f64>,
    /// Largest, ns.
    pub max_ns: Option<f64>,
    /// Least-squares slope of the phase over real time, ns/s.
    pub drift_ns_per_s: Option<f64>,
}

/// One drive.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriveOut {
    /// Network (auto-increment) position, 0-based.
    pub position: usize,
    /// The scenario's name.
    pub name: String,
    /// Its SYNC0 cycle at the end, ns (None: SYNC0 not running); SYNC1's period for a
    /// drive on SYNC1 (`on_sync1`).
    pub sync0_cycle_ns: Option<u32>,
    /// Frames with outputs for it (in OP; a drive on SYNC0 says which) while its SYNC0 ran.
    pub frames: u64,
    /// SYNC0 margin (the pulse the outputs were meant for minus the instant the frame's last
    /// bit passed the drive, its system time): smallest, 0.1th percentile and mean, ns.
    pub margin_min_ns: Option<f64>,
    /// 0.1th percentile of the margin, ns.
    pub margin_p001_ns: Option<f64>,
    /// Mean margin, ns.
    pub margin_mean_ns: Option<f64>,
    /// Frames whose last bit passed it after the pulse they were meant for.
    pub late: u64,
    /// SYNC0 pulses with no new outputs since the previous pulse.
    pub missed: u64,
    /// It runs on SYNC1 (an oversampling terminal, 0x1C32:01 = 3): its events (`frames`,
    /// `margin_*`, `late`, `missed`) are SYNC1's, every `sync0_cycle_ns` (SYNC1's period).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub on_sync1: bool,
    /// Outputs no event took (a frame with new outputs came before the next event: the
    /// master sent more often than the drive's cycle; on an oversampling terminal, blocks of
    /// samples never played).
    #[serde(skip_serializing_if = "is_zero")]
    pub overwritten: u64,
    /// |0x092C| as the master would read it (bit 31 the sign): mean and largest, ns.
    pub time_diff_mean_ns: Option<f64>,
    /// Largest |0x092C|, ns.
    pub time_diff_max_ns: Option<f64>,
    /// Largest |system time - the reference's| (every 8th frame), ns.
    pub deviation_max_ns: f64,
    /// AL errors raised: its error flag (0x0130 bit 4) going from clear to set, from the
    /// segment's truth after each frame, whether the master read it or not.
    pub al_errors: u64,
    /// Of those, how many the master read (the error flag appearing in its reads of 0x0130).
    pub al_errors_read: u64,
    /// The AL status codes (0x0134) seen with the error flag, as `0x001A`.
    pub al_codes: Vec<String>,
    /// AL state at the end.
    pub al_state: String,
}

/// A fault and the master's way back.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultOut {
    /// Index in the schedule.
    pub fault: usize,
    /// Its kind.
    pub kind: String,
    /// What the player did.
    pub detail: String,
    /// Start and end, s after the first frame.
    pub start_s: f64,
    /// End (None: no window, or not over).
    pub end_s: Option<f64>,
    /// Positions in OP when it started.
    pub drives_in_op: Vec<usize>,
    /// From its start to the first frame with process data flowing (the usual working
    /// counter) with every drive that was in OP in OP again, ms; None: never by the end.
    pub recovery_ms: Option<f64>,
}

/// Everything the judge found (summary.json).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JudgeOut {
    /// The preset or scenario served.
    pub preset: String,
    /// From the first frame to the last, s.
    pub run_s: f64,
    /// Frames seen.
    pub frames: u64,
    /// Frames with process data (cycles).
    pub pd_frames: u64,
    /// The reference (the first slave whose SYNC0 runs) at the end.
    pub reference: Option<usize>,
    /// Its SYNC0 cycle, ns.
    pub cycle_ns: Option<u32>,
    /// The usual working counter of the process data datagrams.
    pub wkc_usual: Option<u32>,
    /// Frames with process data whose working counter was not the usual one, or 0.
    pub wkc_errors: u64,
    /// Of those, 0.
    pub wkc_zero: u64,
    /// The phase at the reference.
    pub phase: PhaseOut,
    /// The drives' spread (largest |system time - the reference's|, every 8th frame):
    /// 99.9th percentile and largest, ns.
    pub spread_p999_ns: Option<f64>,
    /// Largest spread, ns.
    pub spread_max_ns: Option<f64>,
    /// Smallest SYNC0 margin of any drive, ns.
    pub margin_min_ns: Option<f64>,
    /// 0.1th percentile of each frame's smallest margin, ns.
    pub margin_p001_ns: Option<f64>,
    /// Frames that reached some drive after the SYNC0 pulse they were meant for.
    pub late: u64,
    /// SYNC0 pulses without new outputs (per frame the most any drive missed: the drives
    /// share one grid).
    pub missed: u64,
    /// Frames lost (either way).
    pub lost: u64,
    /// Of those, with process data.
    pub lost_pd: u64,
    /// Replies the serving host sent later than the threshold past their wire time.
    pub late_replies: u64,
    /// The threshold, ns.
    pub late_reply_threshold_ns: u64,
    /// Of the late replies, those later than the stall threshold (a stall of the serving host
    /// long enough to cost a master its reply).
    pub stalled_replies: u64,
    /// The stall threshold, ns.
    pub stalled_reply_threshold_ns: u64,
    /// The latest reply, ns past its wire time.
    pub late_reply_max_ns: u64,
    /// Retries: frames repeating the index and headers of one just sent or lost.
    pub duplicates: u64,
    /// AL errors raised (the drives' error flags, from the segment's truth), summed over
    /// drives.
    pub al_errors: u64,
    /// AL errors the master read, summed over drives.
    pub al_errors_read: u64,
    /// Per drive.
    pub drives: Vec<DriveOut>,
    /// The faults played, with the way back.
    pub faults: Vec<FaultOut>,
    /// Frames with process data per band point.
    pub band_frames: u64,
    /// The phase per block of frames (percentile bands), ns.
    pub phase_bands: Vec<Band>,
    /// Each frame's smallest margin per block of frames, ns.
    pub margin_bands: Vec<Band>,
}

impl JudgeOut {
    /// The largest recovery of any fault, ms: infinite when one never came back, None
    /// without faults.
    pub fn recovery_max_ms(&self) -> Option<f64> {
        self.faults
            .iter()
            .map(|f| f.recovery_ms.unwrap_or(f64::INFINITY))
            .reduce(f64::max)
    }
}

fn some(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The 99.9th percentile of |x - m| from `d`'s buckets (each bucket's value as recorded).
fn dev_quantile(d: &Dist, m: f64, q: f64) -> Option<f64> {
    let mut v: Vec<(f64, u64)> = d
        .bins()
        .into_iter()
        .map(|(x, c)| ((x - m).abs(), c))
        .collect();
    let n: u64 = v.iter().map(|b| b.1).sum();
    if n == 0 {
        return None;
    }
    v.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let rank = ((q * n as f64).ceil() as u64).clamp(1, n);
    let mut acc = 0;
    for (x, c) in v {
        acc += c;
        if acc >= rank {
            return Some(x);
        }
    }
    None
}

fn phase_out(s: &Stats, drift: Option<f64>) -> PhaseOut {
    let m = s.summary();
    PhaseOut {
        n: s.count(),
        mean_ns: some(m.mean),
        std_ns: some(m.std),
        p001_ns: some(m.p001),
        p999_ns: some(m.p999),
        dev_p999_ns: if s.count() > 0 {
            // Within the buckets' resolution, no further than the exact extremes allow.
            dev_quantile(&s.dist, m.mean, 0.999)
                .map(|v| v.min((m.max - m.mean).abs().max((m.mean - m.min).abs())))
        } else {
            None
        },
        min_ns: some(m.min),
        max_ns: some(m.max),
        drift_ns_per_s: drift,
    }
}

impl Judge {
    /// The figures so far (call it at any time: on exit, every N seconds).
    pub fn summary(&self, seg: &Segment) -> JudgeOut {
        let t0 = self.first_ps.unwrap_or(0);
        let s = |t: u64| t.saturating_sub(t0) as f64 / 1e12;
        let drives = self
            .drives
            .iter()
            .enumerate()
            .map(|(p, d)| {
                let m = d.margin.summary();
                let td = d.time_diff.summary();
                DriveOut {
                    position: p,
                    name: d.name.clone(),
                    sync0_cycle_ns: d.sync0.map(|x| x.1),
                    frames: d.frames,
                    margin_min_ns: some(m.min),
                    margin_p001_ns: some(m.p001),
                    margin_mean_ns: some(m.mean),
                    late: d.late,
                    missed: d.missed,
                    on_sync1: d.on_sync1,
                    overwritten: d.overwritten,
                    time_diff_mean_ns: some(td.mean),
                    time_diff_max_ns: some(td.max),
                    deviation_max_ns: d.dev_max_ns,
                    al_errors: d.al_errors,
                    al_errors_read: d.al_errors_read,
                    al_codes: d.al_codes.iter().map(|c| format!("0x{c:04X}")).collect(),
                    al_state: format!("{:?}", seg.esc(p).al_state()),
                }
            })
            .collect::<Vec<_>>();
        let faults = self
            .faults
            .iter()
            .map(|f| FaultOut {
                fault: f.fault,
                kind: f.kind.clone(),
                detail: f.detail.clone(),
                start_s: s(f.start_ps),
                end_s: f.end_ps.map(s),
                drives_in_op: f.in_op.clone(),
                recovery_ms: f
                    .recovered_ps
                    .map(|r| r.saturating_sub(f.start_ps) as f64 / 1e9),
            })
            .collect();
        let sp = self.spread.summary();
        let wm = self.worst_margin.summary();
        JudgeOut {
            preset: self.opts.preset.clone(),
            run_s: s(self.last_ps),
            frames: self.frames,
            pd_frames: self.pd_frames,
            reference: self.reference.map(|r| r.0),
            cycle_ns: self.reference.map(|r| r.2),
            wkc_usual: self.wkc.usual,
            wkc_errors: self.wkc.changed,
            wkc_zero: self.wkc.zero,
            phase: phase_out(&self.phase, self.phase_fit.slope()),
            spread_p999_ns: some(sp.p999),
            spread_max_ns: some(sp.max),
            margin_min_ns: drives
                .iter()
                .filter_map(|d| d.margin_min_ns)
                .reduce(f64::min),
            margin_p001_ns: some(wm.p001),
            late: self.late,
            missed: self.missed,
            lost: self.lost,
            lost_pd: self.lost_pd,
            late_replies: self.replies_late,
            late_reply_threshold_ns: self.opts.late_reply_ns,
            stalled_replies: self.replies_stalled,
            stalled_reply_threshold_ns: self.opts.stalled_reply_ns,
            late_reply_max_ns: self.reply_late_max_ns,
            duplicates: self.retries,
            al_errors: drives.iter().map(|d| d.al_errors).sum(),
            al_errors_read: drives.iter().map(|d| d.al_errors_read).sum(),
            drives,
            faults,
            band_frames: self.phase_bands.block(),
            phase_bands: self.phase_bands.bands(),
            margin_bands: self.margin_bands.bands(),
        }
    }
}

/// `Lost` in words, for messages.
impl std::fmt::Display for Lost {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Lost::No => "answered",
            Lost::Out => "lost on the way out",
            Lost::Back => "lost on the way back",
        })
    }
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

fn us(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{:.1}", v / 1000.0))
}

fn ns(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{v:.0}"))
}

/// The per-drive figures as a text table (for stderr).
pub fn per_drive_table(out: &JudgeOut) -> String {
    let mut t = String::new();
    let w = out
        .drives
        .iter()
        .map(|d| d.name.len())
        .max()
        .unwrap_or(5)
        .max(5);
    let _ = writeln!(
        t,
        "{:>3}  {:<w$}  {:>8}  {:>9}  {:>9}  {:>6}  {:>6}  {:>9}  {:>9}  {:>7}  {:>6}  state",
        "pos",
        "drive",
        "frames",
        "margin",
        "p0.1",
        "late",
        "missed",
        "|092C|",
        "|092C|",
        "dev",
        "AL err",
    );
    let _ = writeln!(
        t,
        "{:>3}  {:<w$}  {:>8}  {:>9}  {:>9}  {:>6}  {:>6}  {:>9}  {:>9}  {:>7}  {:>6}",
        "", "", "", "min us", "us", "", "", "mean ns", "max ns", "max ns", ""
    );
    for d in &out.drives {
        let codes = if d.al_codes.is_empty() {
            String::new()
        } else {
            format!(" ({})", d.al_codes.join(", "))
        };
        let _ = writeln!(
            t,
            "{:>3}  {:<w$}  {:>8}  {:>9}  {:>9}  {:>6}  {:>6}  {:>9}  {:>9}  {:>7.0}  {:>6}  {}{codes}",
            d.position,
            d.name,
            d.frames,
            us(d.margin_min_ns),
            us(d.margin_p001_ns),
            d.late,
            d.missed,
            ns(d.time_diff_mean_ns),
            ns(d.time_diff_max_ns),
            d.deviation_max_ns,
            d.al_errors,
            d.al_state
        );
    }
    for d in out
        .drives
        .iter()
        .filter(|d| d.on_sync1 || d.overwritten > 0)
    {
        let on = if d.on_sync1 {
            format!(
                "on SYNC1 (every {:.1} us: its events are SYNC1's)",
                f64::from(d.sync0_cycle_ns.unwrap_or(0)) / 1000.0
            )
        } else {
            "on SYNC0".to_string()
        };
        let _ = writeln!(
            t,
            "{:>3}  {}: {on}; {} frame(s) of outputs overwritten before an event took them",
            d.position, d.name, d.overwritten
        );
    }
    t
}
