//! Faults: a schedule of what goes wrong on a segment and its master's host, in one TOML format
//! (`[[fault]]` entries), and the player that makes it happen, in virtual time ([`FaultPlayer`]
//! in the simulator's transport) and on a served interface (`ecsync serve --faults`), so that
//! the same faults meet the simulator's master and any real one.
//!
//! ```toml
//! seed = 7            # optional: the draws of random faults (else the run's seed)
//! epoch = "cyclic"    # at_s counts from the first frame with process data (an LRW, LRD or
//!                     # LWR datagram); "start": from the first frame of all (the bring-up)
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
//! master's NIC drops it; the ESCs behind the break count it, see "Error counters" below), `delay` (`extra_us` on every reply while it lasts), `power_cycle`
//! (the slave off for `for_s`, then up again from reset: registers, AL Init, a new power-up
//! time of its clock; the SII is kept; the slaves behind it are cut off meanwhile),
//! `link_down` (`slave`, `port`), `hot_connect` (`slaves`: the last N slaves absent until
//! `at_s`), `host_stall` (`stall_ms`: the master's cyclic task wakes that
//! late once), `clock_step` (`step_us`, signed: the master's clock jumps), `second_responder`
//! (every frame answered twice while it lasts, the copy `lag_us` later), `al_error` (`slave`,
//! `code`, 0x001A by default: the slave's application raises an AL error and falls back from
//! OP to SAFE-OP, as a drive does on a synchronization error). Random draws are a
//! hash of the seed and the frame's number since the epoch (frames with process data, and the
//! others since the last of them): every method of a comparison loses the same frames.
//!
//! # Time
//!
//! A fault's window starts and ends by the clock, whether or not a frame arrives:
//! [`FaultPlayer::advance_to`] plays every edge due, each at its own time (the slave switched
//! off, the cable pulled, the event logged at the edge's time), and
//! [`FaultPlayer::next_due_ps`] says when the next one is due, for a caller that waits between
//! frames (`serve`). [`FaultPlayer::before_frame`] plays the edges due before the frame at the
//! frame's time: the simulator, whose only events are its frames (one a cycle), sees each edge
//! at the first frame after it, as it always has (its outputs unchanged), and a window with no
//! frame in it starts and ends at the frame after it rather than never.
//!
//! The epoch is the schedule's (`"cyclic"` or `"start"`), or an explicit one:
//! [`FaultPlayer::set_epoch`] (a control command's "now"; it wins over the file's if it comes
//! first, and moves the schedule if it comes later). The file has no third value: an explicit
//! epoch is a moment of the run, which a control command names and a file cannot.
//!
//! # Error counters
//!
//! The ESCs count what the faults do as the datasheet has them (section I "Error Counters",
//! section II 0x0300-0x0313; each stops at 0xFF, a power cycle starts them at 0). A
//! `link_down` counts one lost link (0x0310 + port) at both ends of the pulled cable, where the
//! port is in auto or auto-close loop mode; so does a `power_cycle` at the neighbours of the
//! slave switched off. A `corrupt` frame breaks on the first cable of its way back, from the
//! last slave it reaches to that slave's upstream neighbour (a fixed place, so every run counts
//! the same): the neighbour counts an invalid frame at the port it received it through
//! (0x0300 + 2 * port, a CRC error, "initially detected") and marks it; every slave after it
//! towards the master counts a forwarded RX error at its receiving port (0x0308 + port). The
//! frame comes back through ports, not processing units: 0x030C does not count. With one slave
//! the break is on the master's cable and no ESC sees it.
//!
//! # On demand
//!
//! [`FaultPlayer::inject`] adds a segment fault whose window starts at a real time (before the
//! epoch too: its times are real time, not the schedule's); [`parse_fault_entry`] reads one
//! entry as the file's `[[fault]]` entries are read (`at_s` may be absent); and
//! [`FaultPlayer::clear`] ends active faults now. Host faults (`host_stall`, `clock_step`) are
//! the simulator's master's ([`FaultKind::is_host_fault`]): callers that serve a segment refuse
//! them.

use serde::Deserialize;
use std::fmt;

mod check;
mod player;
mod schedule;

pub use schedule::parse_fault_entry;

pub use player::{Edge, FaultCounts, FaultEvent, FaultPlayer, FrameFate};

/// The built-in schedule `faults-demo`: the paper network's faults (5 % loss, the
/// reference's power cycle at 20 s, the cable behind drive 3 pulled at 40 s, a 10 ms host
/// stall at 60 s).
pub const FAULTS_DEMO_TOML: &str = include_str!("../../../../presets/faults-demo.toml");

/// The built-in schedules by name.
pub const BUILT_IN: [(&str, &str); 1] = [("faults-demo", FAULTS_DEMO_TOML)];

/// The default time a power-cycled slave stays off, ns.
pub const DEFAULT_OFF_NS: u64 = 200_000_000;

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
    /// The kind's name, as the file gives it.
    pub fn name(&self) -> KindName {
        match self {
            FaultKind::Loss { .. } => KindName::Loss,
            FaultKind::Corrupt { .. } => KindName::Corrupt,
            FaultKind::Delay { .. } => KindName::Delay,
            FaultKind::PowerCycle { .. } => KindName::PowerCycle,
            FaultKind::LinkDown { .. } => KindName::LinkDown,
            FaultKind::HostStall { .. } => KindName::HostStall,
            FaultKind::ClockStep { .. } => KindName::ClockStep,
            FaultKind::SecondResponder { .. } => KindName::SecondResponder,
            FaultKind::HotConnect { .. } => KindName::HotConnect,
            FaultKind::AlError { .. } => KindName::AlError,
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

/// The kinds of fault, by the name a schedule's `kind` gives them (the [`FaultKind`] without
/// its parameters). Its [`Display`](fmt::Display), `FromStr` and serialized form are that name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum KindName {
    /// `loss`
    Loss,
    /// `corrupt`
    Corrupt,
    /// `delay`
    Delay,
    /// `power_cycle`
    PowerCycle,
    /// `link_down`
    LinkDown,
    /// `host_stall`
    HostStall,
    /// `clock_step`
    ClockStep,
    /// `second_responder`
    SecondResponder,
    /// `hot_connect`
    HotConnect,
    /// `al_error`
    AlError,
}

impl KindName {
    /// Every kind, in the order the documentation lists them.
    pub const ALL: [KindName; 10] = [
        KindName::Loss,
        KindName::Corrupt,
        KindName::Delay,
        KindName::PowerCycle,
        KindName::LinkDown,
        KindName::HostStall,
        KindName::ClockStep,
        KindName::SecondResponder,
        KindName::HotConnect,
        KindName::AlError,
    ];

    /// The name in the file.
    pub fn as_str(self) -> &'static str {
        match self {
            KindName::Loss => "loss",
            KindName::Corrupt => "corrupt",
            KindName::Delay => "delay",
            KindName::PowerCycle => "power_cycle",
            KindName::LinkDown => "link_down",
            KindName::HostStall => "host_stall",
            KindName::ClockStep => "clock_step",
            KindName::SecondResponder => "second_responder",
            KindName::HotConnect => "hot_connect",
            KindName::AlError => "al_error",
        }
    }

    /// The parameters an entry of this kind may give, besides `at_s`, `for_s` and `kind`.
    pub fn parameters(self) -> &'static [&'static str] {
        match self {
            KindName::Loss | KindName::Corrupt => &["probability", "frames"],
            KindName::Delay => &["extra_us"],
            KindName::PowerCycle => &["slave"],
            KindName::LinkDown => &["slave", "port"],
            KindName::HostStall => &["stall_ms"],
            KindName::ClockStep => &["step_us"],
            KindName::SecondResponder => &["lag_us"],
            KindName::HotConnect => &["slaves"],
            KindName::AlError => &["slave", "code"],
        }
    }

    /// The names, comma-separated, for an error's fix.
    pub fn list() -> String {
        Self::ALL.map(Self::as_str).join(", ")
    }
}

impl fmt::Display for KindName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for KindName {
    type Err = ();

    fn from_str(s: &str) -> Result<Self, ()> {
        Self::ALL.into_iter().find(|k| k.as_str() == s).ok_or(())
    }
}

impl serde::Serialize for KindName {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
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

/// A parsed fault schedule.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultSchedule {
    /// Seed of the random draws (`None`: the run's).
    pub seed: Option<u64>,
    /// Where `at_s` counts from.
    pub epoch: Epoch,
    /// The faults, in the file's order.
    pub faults: Vec<Fault>,
    /// The file the schedule was read from, as given (or the built-in schedule's name), for
    /// messages; empty for a schedule built in code.
    pub file: String,
    /// Each fault's line in that file (its `[[fault]]` header), in the order of `faults`
    /// (faults injected later have none).
    pub lines: Vec<usize>,
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
mod tests;
