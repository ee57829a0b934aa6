//! Faults: a schedule of what goes wrong on a segment and its master's host, in one TOML format
//! (`[[fault]]` entries), and the player that makes it happen, frame by frame, in virtual time
//! ([`FaultPlayer`] in the simulator's transport) and on a served interface (`ecsync serve
//! --faults`), so that the same faults meet the simulator's master and any real one.
//!
//! ```toml
//! seed = 7            # optional: the draws of random faults (else the run's seed)
//! epoch = "cyclic"    # at_s counts from the first frame with process data (LRW); "start":
//!                     # from the first frame of all (the bring-up)
//!
//! [[fault]]
//! at_s = 0.0
//! kind = "loss"
//! probability = 0.1   # or frames = N: a burst of N frames in a row
//!
//! [[fault]]
//! at_s = 20.0
//! for_s = 0.2         # how long the slave stays off
//! kind = "power_cycle"
//! slave = "reference" # or a network position, 1 = the slave next to the master
//!
//! [[fault]]
//! at_s = 40.0
//! for_s = 0.05
//! kind = "link_down"  # the cable behind slave 3 pulled: the segment behind it is gone
//! slave = 3           # and port 1 (the default) of slave 3 is looped
//! ```
//!
//! Kinds: `loss`, `corrupt` (the frame's FCS broken on its way back: the slaves acted on it, the
//! master's NIC drops it), `delay` (`extra_us` on every reply while it lasts), `power_cycle`
//! (the slave off for `for_s`, then up again from reset: registers, AL Init, a new power-up
//! time of its clock; the SII is kept; the slaves behind it are cut off meanwhile),
//! `link_down` (`slave`, `port`), `hot_connect` (`slaves`: the last N slaves absent until
//! `at_s`), `host_stall` (`stall_ms`: the master's cyclic task wakes that
//! late once), `clock_step` (`step_us`, signed: the master's clock jumps), `second_responder`
//! (every frame answered twice while it lasts, the copy `lag_us` later), `al_error` (`slave`,
//! `code`, 0x001A by default: the slave's application raises an AL error and falls back from
//! OP to SAFE-OP, as a drive does on a synchronization error). Random draws are a
//! hash of the seed and the frame's number since the epoch: every method of a comparison loses
//! the same frames.

use crate::config::{ConfigError, ConfigSource};
use crate::rng::{SplitMix64, unit_from_bits};
use crate::segment::Segment;
use ecsync_wire::{Command, EcatFrame};
use serde::Deserialize;
use std::fmt;

/// The built-in schedule `faults-demo`: the paper network's faults (5 % loss, the
/// reference's power cycle at 20 s, the cable behind drive 3 pulled at 40 s, a 10 ms host
/// stall at 60 s).
pub const FAULTS_DEMO_TOML: &str = include_str!("../../../presets/faults-demo.toml");

/// The built-in schedules by name.
pub const BUILT_IN: [(&str, &str); 1] = [("faults-demo", FAULTS_DEMO_TOML)];

/// Where `at_s` counts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Epoch {
    /// The first frame that carries process data (an LRW): the cyclic phase.
    #[default]
    Cyclic,
    /// The first frame of all: the bring-up.
    Start,
}

/// Which slave a fault hits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlaveRef {
    /// Network position, 0-based (the file's `slave = 1` is position 0).
    Position(usize),
    /// The reference clock: the first slave with a DC unit.
    Reference,
}

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultKind {
    /// Frames lost with this probability each (or a burst: `burst` frames in a row).
    Loss {
        /// Probability per frame (1.0 for a burst).
        probability: f64,
        /// A burst of this many frames instead of a window of time.
        burst: Option<u32>,
    },
    /// Frames whose FCS breaks on the way back: processed by the slaves, dropped by the NIC.
    Corrupt {
        /// Probability per frame.
        probability: f64,
        /// A burst of this many frames.
        burst: Option<u32>,
    },
    /// Every reply later by this much.
    Delay {
        /// Extra delay, ns.
        extra_ns: u64,
    },
    /// A slave switched off, and on again at the end of the window.
    PowerCycle {
        /// The slave.
        slave: SlaveRef,
    },
    /// A port's cable pulled, plugged in again at the end of the window.
    LinkDown {
        /// The slave.
        slave: SlaveRef,
        /// Its port.
        port: u8,
    },
    /// The master's cyclic task wakes this much late, once.
    HostStall {
        /// Stall, ns.
        stall_ns: u64,
    },
    /// The master's clock jumps.
    ClockStep {
        /// Step, ns (negative: back).
        step_ns: i64,
    },
    /// The last `slaves` slaves of the network are not connected until the fault starts
    /// (their cables plugged in then): slaves that appear at the end (hot connect).
    HotConnect {
        /// How many.
        slaves: u16,
    },
    /// The slave's application raises an AL error (ETG.1000.6): the error indication with
    /// `code` in AL status, OP left for SAFE-OP.
    AlError {
        /// The slave.
        slave: SlaveRef,
        /// The AL status code.
        code: u16,
    },
    /// A second device answers every frame again.
    SecondResponder {
        /// The copy's lag behind the reply, ns.
        lag_ns: u64,
    },
}

impl FaultKind {
    /// The name in the file.
    pub fn name(&self) -> &'static str {
        match self {
            FaultKind::Loss { .. } => "loss",
            FaultKind::Corrupt { .. } => "corrupt",
            FaultKind::Delay { .. } => "delay",
            FaultKind::PowerCycle { .. } => "power_cycle",
            FaultKind::LinkDown { .. } => "link_down",
            FaultKind::HostStall { .. } => "host_stall",
            FaultKind::ClockStep { .. } => "clock_step",
            FaultKind::SecondResponder { .. } => "second_responder",
            FaultKind::HotConnect { .. } => "hot_connect",
            FaultKind::AlError { .. } => "al_error",
        }
    }

    /// Whether the fault is the master host's (stall, clock step): played by the simulator's
    /// transport, not by a served segment.
    pub fn is_host_fault(&self) -> bool {
        matches!(
            self,
            FaultKind::HostStall { .. } | FaultKind::ClockStep { .. }
        )
    }
}

/// One entry of the schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    /// When it starts, ns after the epoch.
    pub at_ns: u64,
    /// How long it lasts, ns (`None`: to the end; instantaneous kinds ignore it).
    pub for_ns: Option<u64>,
    /// What.
    pub kind: FaultKind,
}

impl Fault {
    /// Whether `t_ns` (after the epoch) is inside the fault's window.
    fn covers(&self, t_ns: u64) -> bool {
        t_ns >= self.at_ns
            && self
                .for_ns
                .is_none_or(|d| t_ns < self.at_ns.saturating_add(d))
    }
}

/// A parsed fault schedule.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultSchedule {
    /// Seed of the random draws (`None`: the run's).
    pub seed: Option<u64>,
    /// Where `at_s` counts from.
    pub epoch: Epoch,
    /// The faults, in the file's order.
    pub faults: Vec<Fault>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRepr {
    seed: Option<u64>,
    #[serde(default)]
    epoch: Epoch,
    #[serde(default)]
    fault: Vec<EntryRepr>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EntryRepr {
    at_s: f64,
    for_s: Option<f64>,
    kind: String,
    probability: Option<f64>,
    frames: Option<u32>,
    extra_us: Option<f64>,
    slave: Option<SlaveRepr>,
    port: Option<u8>,
    stall_ms: Option<f64>,
    step_us: Option<f64>,
    lag_us: Option<f64>,
    slaves: Option<u16>,
    code: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum SlaveRepr {
    Position(i64),
    Name(String),
}

/// The kinds a file may name, for the error's fix.
const KINDS: &str = "loss, corrupt, delay, power_cycle, link_down, host_stall, clock_step, \
                     second_responder, hot_connect, al_error";

/// The default time a power-cycled slave stays off, ns.
pub const DEFAULT_OFF_NS: u64 = 200_000_000;

impl FaultSchedule {
    /// Parses a schedule; `file` names it in errors (which give the entry, the field and the
    /// fix).
    pub fn parse(file: &str, text: &str) -> Result<FaultSchedule, ConfigError> {
        let src = ConfigSource::new(file, text);
        let f: FileRepr = src.deserialize()?;
        let mut faults = Vec::with_capacity(f.fault.len());
        for (n, e) in f.fault.iter().enumerate() {
            faults.push(entry(&src, n, e)?);
        }
        Ok(FaultSchedule {
            seed: f.seed,
            epoch: f.epoch,
            faults,
        })
    }

    /// Reads and parses a schedule file, or the built-in schedule of that name (when no such
    /// file exists).
    pub fn load(path: &std::path::Path) -> Result<FaultSchedule, ConfigError> {
        let name = path.display().to_string();
        if !path.exists()
            && let Some((n, text)) = BUILT_IN.iter().find(|(n, _)| *n == name)
        {
            return Self::parse(n, text);
        }
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            file: name.clone(),
            line: None,
            field: "(file)".into(),
            message: format!("cannot read it: {e}"),
            fix: format!(
                "give the path of a fault schedule (TOML with [[fault]] entries) or a built-in one: {}",
                BUILT_IN.map(|b| b.0).join(", ")
            ),
        })?;
        Self::parse(&name, &text)
    }

    /// Whether the schedule holds faults of the master's host (see
    /// [`FaultKind::is_host_fault`]).
    pub fn has_host_faults(&self) -> bool {
        self.faults.iter().any(|f| f.kind.is_host_fault())
    }
}

/// The 1-based line of the `n`-th `[[fault]]` header and of `key` inside that entry.
fn entry_line(text: &str, n: usize, key: Option<&str>) -> Option<usize> {
    let mut seen = 0usize;
    let mut header = None;
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with("[[fault]]") {
            if header.is_some() {
                break;
            }
            if seen == n {
                header = Some(i + 1);
            }
            seen += 1;
            continue;
        }
        if l.starts_with('[') && header.is_some() {
            break;
        }
        if let (Some(_), Some(k)) = (header, key)
            && l.split_once('=').is_some_and(|(a, _)| a.trim() == k)
        {
            return Some(i + 1);
        }
    }
    header
}

fn entry(src: &ConfigSource, n: usize, e: &EntryRepr) -> Result<Fault, ConfigError> {
    let field = |key: &str| format!("fault[{n}].{key}");
    let err = |key: &str, message: String, fix: &str| {
        src.at(entry_line(src.text, n, Some(key)), field(key), message, fix)
    };
    let seconds = |key: &str, v: f64| -> Result<u64, ConfigError> {
        if !v.is_finite() || !(0.0..=1e9).contains(&v) {
            return Err(err(
                key,
                format!("{v} is not a time"),
                "give seconds, 0 or more",
            ));
        }
        Ok((v * 1e9).round() as u64)
    };
    let at_ns = seconds("at_s", e.at_s)?;
    let for_ns = e.for_s.map(|v| seconds("for_s", v)).transpose()?;
    let probability = |required: bool| -> Result<(f64, Option<u32>), ConfigError> {
        match (e.probability, e.frames) {
            (Some(_), Some(_)) => Err(err(
                "frames",
                "both probability and frames are given".into(),
                "give probability (random loss while it lasts) or frames (a burst), not both",
            )),
            (Some(p), None) if (0.0..=1.0).contains(&p) => Ok((p, None)),
            (Some(p), None) => Err(err(
                "probability",
                format!("{p} is not a probability"),
                "give a number from 0 to 1, e.g. 0.1 for 10 %",
            )),
            (None, Some(0)) => Err(err(
                "frames",
                "a burst of 0 frames".into(),
                "give 1 or more frames",
            )),
            (None, Some(k)) => Ok((1.0, Some(k))),
            (None, None) if required => Err(err(
                "probability",
                format!("kind \"{}\" needs probability or frames", e.kind),
                "add probability = 0.1 (random) or frames = 10 (a burst)",
            )),
            (None, None) => Ok((1.0, None)),
        }
    };
    let micros = |key: &str, v: Option<f64>, default: f64| -> Result<f64, ConfigError> {
        let v = v.unwrap_or(default);
        if !v.is_finite() || v.abs() > 1e12 {
            return Err(err(
                key,
                format!("{v} is out of range"),
                "give a finite number",
            ));
        }
        Ok(v)
    };
    let slave = || -> Result<SlaveRef, ConfigError> {
        match &e.slave {
            Some(SlaveRepr::Position(p)) if *p >= 1 && *p <= 65_535 => {
                Ok(SlaveRef::Position(*p as usize - 1))
            }
            Some(SlaveRepr::Name(s)) if s == "reference" => Ok(SlaveRef::Reference),
            Some(SlaveRepr::Position(p)) => Err(err(
                "slave",
                format!("{p} is no network position"),
                "give the slave's position, 1 for the one next to the master, or \"reference\"",
            )),
            Some(SlaveRepr::Name(s)) => Err(err(
                "slave",
                format!("\"{s}\" names no slave"),
                "give the slave's position, 1 for the one next to the master, or \"reference\"",
            )),
            None => Err(err(
                "slave",
                format!("kind \"{}\" needs the slave it hits", e.kind),
                "add slave = 3 (network position, 1 = next to the master) or slave = \"reference\"",
            )),
        }
    };
    // Parameters a kind does not take are refused: a typo would otherwise be silently ignored.
    let allowed: &[&str] = match e.kind.as_str() {
        "loss" | "corrupt" => &["probability", "frames"],
        "delay" => &["extra_us"],
        "power_cycle" => &["slave"],
        "link_down" => &["slave", "port"],
        "host_stall" => &["stall_ms"],
        "clock_step" => &["step_us"],
        "second_responder" => &["lag_us"],
        "hot_connect" => &["slaves"],
        "al_error" => &["slave", "code"],
        other => {
            return Err(err(
                "kind",
                format!("unknown fault kind \"{other}\""),
                &format!("use one of {KINDS}"),
            ));
        }
    };
    let given = [
        ("probability", e.probability.is_some()),
        ("frames", e.frames.is_some()),
        ("extra_us", e.extra_us.is_some()),
        ("slave", e.slave.is_some()),
        ("port", e.port.is_some()),
        ("stall_ms", e.stall_ms.is_some()),
        ("step_us", e.step_us.is_some()),
        ("lag_us", e.lag_us.is_some()),
        ("slaves", e.slaves.is_some()),
        ("code", e.code.is_some()),
    ];
    if let Some((k, _)) = given.iter().find(|(k, g)| *g && !allowed.contains(k)) {
        return Err(err(
            k,
            format!("kind \"{}\" takes no {k}", e.kind),
            &format!("remove it; \"{}\" takes {}", e.kind, allowed.join(", ")),
        ));
    }
    let kind = match e.kind.as_str() {
        "loss" => {
            let (probability, burst) = probability(true)?;
            FaultKind::Loss { probability, burst }
        }
        "corrupt" => {
            let (probability, burst) = probability(true)?;
            FaultKind::Corrupt { probability, burst }
        }
        "delay" => {
            let us = micros("extra_us", e.extra_us, f64::NAN)?;
            if us < 0.0 {
                return Err(err(
                    "extra_us",
                    format!("{us} is negative"),
                    "give the extra delay in microseconds, 0 or more",
                ));
            }
            FaultKind::Delay {
                extra_ns: (us * 1e3).round() as u64,
            }
        }
        "power_cycle" => FaultKind::PowerCycle { slave: slave()? },
        "al_error" => {
            let code = e.code.unwrap_or(0x001A);
            let Ok(code) = u16::try_from(code) else {
                return Err(err(
                    "code",
                    format!("{code} is no AL status code"),
                    "give a code from 0x0001 to 0xFFFF, e.g. 0x001A (synchronization error)",
                ));
            };
            if code == 0 {
                return Err(err(
                    "code",
                    "0 is \"no error\"".to_string(),
                    "give a code from 0x0001 to 0xFFFF, e.g. 0x001A (synchronization error)",
                ));
            }
            FaultKind::AlError {
                slave: slave()?,
                code,
            }
        }
        "link_down" => {
            let port = e.port.unwrap_or(1);
            if port > 3 {
                return Err(err(
                    "port",
                    format!("port {port} does not exist"),
                    "give a port from 0 to 3 (1: the one to the next slave of a line)",
                ));
            }
            FaultKind::LinkDown {
                slave: slave()?,
                port,
            }
        }
        "host_stall" => {
            let ms = micros("stall_ms", e.stall_ms, f64::NAN)?;
            if ms <= 0.0 {
                return Err(err(
                    "stall_ms",
                    format!("{ms} is not a stall"),
                    "give the stall in milliseconds, more than 0",
                ));
            }
            FaultKind::HostStall {
                stall_ns: (ms * 1e6).round() as u64,
            }
        }
        "clock_step" => {
            let us = micros("step_us", e.step_us, f64::NAN)?;
            FaultKind::ClockStep {
                step_ns: (us * 1e3).round() as i64,
            }
        }
        "second_responder" => {
            let us = micros("lag_us", e.lag_us, 5.0)?;
            if us < 0.0 {
                return Err(err(
                    "lag_us",
                    format!("{us} is negative"),
                    "give the copy's lag in microseconds, 0 or more",
                ));
            }
            FaultKind::SecondResponder {
                lag_ns: (us * 1e3).round() as u64,
            }
        }
        "hot_connect" => match e.slaves {
            Some(n) if n >= 1 => FaultKind::HotConnect { slaves: n },
            _ => {
                return Err(err(
                    "slaves",
                    format!(
                        "kind \"{}\" needs how many slaves appear, 1 or more",
                        e.kind
                    ),
                    "add slaves = 2 (the last two slaves of the network, absent until at_s)",
                ));
            }
        },
        _ => unreachable!("kinds checked above"),
    };
    let for_ns = match kind {
        FaultKind::PowerCycle { .. } => Some(for_ns.unwrap_or(DEFAULT_OFF_NS)),
        _ => for_ns,
    };
    Ok(Fault {
        at_ns,
        for_ns,
        kind,
    })
}

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
    pub kind: &'static str,
    /// `start` or `end`.
    pub edge: &'static str,
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

    fn log(&mut self, t_ps: u64, fault: usize, edge: &'static str, detail: String) {
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
                self.log(t_ps, f, "start", detail);
            }
            if self.started[f] && !covers && !self.ended[f] && now >= fault.at_ns {
                self.ended[f] = true;
                let detail = end_fault(segment, &fault.kind, t_ps);
                self.log(t_ps, f, "end", detail);
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
            self.log(t_ps, f, "start", detail);
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

impl fmt::Display for SlaveRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SlaveRef::Position(p) => write!(f, "slave {}", p + 1),
            SlaveRef::Reference => write!(f, "the reference"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEMO: &str = r#"
epoch = "cyclic"
[[fault]]
at_s = 0
kind = "loss"
probability = 0.05

[[fault]]
at_s = 20
kind = "power_cycle"
slave = "reference"

[[fault]]
at_s = 40
for_s = 0.05
kind = "link_down"
slave = 3

[[fault]]
at_s = 60
kind = "host_stall"
stall_ms = 10
"#;

    #[test]
    fn the_built_in_demo_parses() {
        let s = FaultSchedule::load(std::path::Path::new("faults-demo")).unwrap();
        assert_eq!(s.faults.len(), 4);
        assert_eq!(s.faults[1].at_ns, 20_000_000_000);
    }

    #[test]
    fn parses_the_demo() {
        let s = FaultSchedule::parse("f.toml", DEMO).unwrap();
        assert_eq!(s.faults.len(), 4);
        assert_eq!(
            s.faults[1],
            Fault {
                at_ns: 20_000_000_000,
                for_ns: Some(DEFAULT_OFF_NS),
                kind: FaultKind::PowerCycle {
                    slave: SlaveRef::Reference
                }
            }
        );
        assert_eq!(
            s.faults[2].kind,
            FaultKind::LinkDown {
                slave: SlaveRef::Position(2),
                port: 1
            }
        );
        assert!(s.has_host_faults());
    }

    #[test]
    fn an_al_error_takes_a_code_and_refuses_none() {
        let s = FaultSchedule::parse(
            "f.toml",
            "[[fault]]\nat_s = 1\nkind = \"al_error\"\nslave = 2\n\n[[fault]]\nat_s = 2\nkind = \"al_error\"\nslave = \"reference\"\ncode = 0x002C\n",
        )
        .unwrap();
        assert_eq!(
            s.faults[0].kind,
            FaultKind::AlError {
                slave: SlaveRef::Position(1),
                code: 0x001A
            }
        );
        assert_eq!(
            s.faults[1].kind,
            FaultKind::AlError {
                slave: SlaveRef::Reference,
                code: 0x002C
            }
        );
        for bad in ["0", "65536", "-1"] {
            let e = FaultSchedule::parse(
                "f.toml",
                &format!("[[fault]]\nat_s = 1\nkind = \"al_error\"\nslave = 2\ncode = {bad}\n"),
            )
            .unwrap_err();
            assert_eq!(e.field, "fault[0].code", "{bad}: {e}");
            assert!(e.fix.contains("0x001A"), "{e}");
        }
        // A parameter it does not take.
        let e = FaultSchedule::parse(
            "f.toml",
            "[[fault]]\nat_s = 1\nkind = \"al_error\"\nport = 1\nslave = 2\n",
        )
        .unwrap_err();
        assert_eq!(e.field, "fault[0].port", "{e}");
    }

    #[test]
    fn errors_name_the_entry_the_field_and_the_fix() {
        let text = "[[fault]]\nat_s = 1\nkind = \"loss\"\nframes = 2\n\n[[fault]]\nat_s = 2\nkind = \"loss\"\nprobability = 1.5\n";
        let e = FaultSchedule::parse("f.toml", text).unwrap_err();
        assert_eq!(e.field, "fault[1].probability");
        assert_eq!(e.line, Some(9));
        assert!(e.fix.contains("0 to 1"), "{e}");
        let e =
            FaultSchedule::parse("f.toml", "[[fault]]\nat_s = 1\nkind = \"loss\"\n").unwrap_err();
        assert_eq!(e.field, "fault[0].probability");
        let e =
            FaultSchedule::parse("f.toml", "[[fault]]\nat_s = 1\nkind = \"lost\"\n").unwrap_err();
        assert!(e.to_string().contains("unknown fault kind \"lost\""), "{e}");
        assert_eq!(e.line, Some(3));
        let e = FaultSchedule::parse(
            "f.toml",
            "[[fault]]\nat_s = 1\nkind = \"delay\"\nextra_us = 5\nslave = 2\n",
        )
        .unwrap_err();
        assert_eq!(e.field, "fault[0].slave");
        assert!(e.message.contains("takes no slave"), "{e}");
        let e =
            FaultSchedule::parse("f.toml", "[[fault]]\nat_s = -1\nkind = \"delay\"\n").unwrap_err();
        assert_eq!(e.field, "fault[0].at_s");
        let e = FaultSchedule::parse(
            "f.toml",
            "[[fault]]\nat_s = 1\nkind = \"power_cycle\"\nslave = 0\n",
        )
        .unwrap_err();
        assert!(e.fix.contains("reference"), "{e}");
    }

    #[test]
    fn the_same_frames_are_lost_whatever_else_happens() {
        let s = FaultSchedule::parse(
            "f.toml",
            "epoch = \"start\"\n[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.3\n",
        )
        .unwrap();
        let mut seg = Segment::new(&crate::preset::line(3, 1)).unwrap();
        let frame = [0u8; 60];
        let mut a = FaultPlayer::new(s.clone(), 5);
        let mut b = FaultPlayer::new(s, 5);
        let fa: Vec<bool> = (0..10_000)
            .map(|k| {
                let f = a.before_frame(&mut seg, &frame, k * 1_000_000_000);
                f.lost_out || f.lost_back
            })
            .collect();
        // The other player's frames come at other times: the same ones are lost.
        let fb: Vec<bool> = (0..10_000)
            .map(|k| {
                let f = b.before_frame(&mut seg, &frame, k * 1_000_000_000 + 7_777);
                f.lost_out || f.lost_back
            })
            .collect();
        assert_eq!(fa, fb);
        let lost = fa.iter().filter(|&&l| l).count();
        assert!((2_700..3_300).contains(&lost), "{lost} of 10 000 at 30 %");
    }

    /// A broadcast read's working counter: the slaves it reached.
    fn count(seg: &mut Segment, p: &mut FaultPlayer, t_ps: u64) -> u16 {
        let mut buf = [0u8; 60];
        let mut b =
            ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [2, 0, 0, 0, 0, 1]).unwrap();
        b.push_zeroed(
            Command::Brd,
            0,
            ecsync_wire::DatagramAddress::position(0, 0),
            1,
        )
        .unwrap();
        let n = b.finish();
        let fate = p.before_frame(seg, &buf[..n], t_ps);
        assert!(!fate.lost_out && !fate.lost_back);
        seg.process(&mut buf[..n], t_ps);
        let f = EcatFrame::new_checked(&buf[..n]).unwrap();
        f.datagrams().next().unwrap().unwrap().wkc()
    }

    #[test]
    fn hot_connected_slaves_appear_at_their_time() {
        let s = FaultSchedule::parse(
            "f.toml",
            "epoch = \"start\"\n[[fault]]\nat_s = 0.01\nkind = \"hot_connect\"\nslaves = 2\n",
        )
        .unwrap();
        let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
        let mut p = FaultPlayer::new(s, 1);
        assert_eq!(
            count(&mut seg, &mut p, 0),
            3,
            "the last two are not connected yet"
        );
        assert_eq!(count(&mut seg, &mut p, 5_000_000_000), 3);
        assert_eq!(
            count(&mut seg, &mut p, 20_000_000_000),
            5,
            "connected at 10 ms"
        );
        assert_eq!(p.events()[0].detail, "slaves 4 to 5 connected");
    }

    #[test]
    fn a_pulled_cable_and_a_power_cycle_cut_the_segment_behind() {
        let s = FaultSchedule::parse(
            "f.toml",
            "epoch = \"start\"\n[[fault]]\nat_s = 0.01\nfor_s = 0.01\nkind = \"link_down\"\nslave = 2\n\n[[fault]]\nat_s = 0.03\nfor_s = 0.01\nkind = \"power_cycle\"\nslave = 4\n",
        )
        .unwrap();
        let mut seg = Segment::new(&crate::preset::line(5, 1)).unwrap();
        let mut p = FaultPlayer::new(s, 1);
        let ms = |m: u64| m * 1_000_000_000;
        assert_eq!(count(&mut seg, &mut p, 0), 5);
        assert_eq!(
            count(&mut seg, &mut p, ms(15)),
            2,
            "slaves 3-5 behind the cable"
        );
        assert_eq!(count(&mut seg, &mut p, ms(25)), 5, "plugged in again");
        assert_eq!(
            count(&mut seg, &mut p, ms(35)),
            3,
            "slave 4 off: 4 and 5 gone"
        );
        assert!(seg.is_powered_off(3));
        assert_eq!(count(&mut seg, &mut p, ms(45)), 5, "on again");
        assert_eq!(
            seg.esc(3).al_state(),
            ecsync_wire::AlState::Init,
            "from reset"
        );
    }

    #[test]
    fn a_burst_takes_its_frames_in_a_row() {
        let s = FaultSchedule::parse(
            "f.toml",
            "epoch = \"start\"\n[[fault]]\nat_s = 0.0105\nkind = \"loss\"\nframes = 3\n",
        )
        .unwrap();
        let mut seg = Segment::new(&crate::preset::line(2, 1)).unwrap();
        let mut p = FaultPlayer::new(s, 1);
        let lost: Vec<u64> = (0..30u64)
            .filter(|&k| {
                let f = p.before_frame(&mut seg, &[0u8; 60], k * 1_000_000_000);
                f.lost_out || f.lost_back
            })
            .collect();
        assert_eq!(lost, vec![11, 12, 13]);
    }
}
