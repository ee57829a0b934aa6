//! Real captures replayed against segments built like the captured networks (issue 32,
//! acceptance 1): the network is read out of the capture itself ([`network`], [`od`]), a
//! segment built of it ([`build`]), the master's frames fed into it at their captured
//! instants and every datagram compared with the real devices' answer ([`compare`]).

pub mod build;
pub mod capture;
pub mod compare;
pub mod network;
pub mod od;

use crate::common::captures_dir;
use ecsync_sim::AnswerBufferHabit;
use std::collections::BTreeMap;

/// How long a device takes to answer a mailbox request when the capture shows none, ns
/// (`MailboxLayout::STANDARD`'s).
const DEFAULT_RESPONSE_NS: u64 = 200_000;

/// A capture replayed.
pub struct Replayed {
    pub exchanges: Vec<capture::Exchange>,
    pub network: network::Network,
    pub slaves: Vec<build::Slave>,
    /// Each slave's mailbox answer time, ns, as fitted to the capture.
    pub response_ns: Vec<u64>,
    pub outcome: compare::Outcome,
    /// The segment as the replay left it.
    pub segment: ecsync_sim::Segment,
}

/// The answer time that fits the most of a device's exchanges: inside as many of the
/// windows (after the last poll that found SM1 empty, no later than the first that found it
/// full) as one time can be, in the middle of what those windows share.
pub fn response_time(windows: &[(u64, u64)]) -> u64 {
    let covered = |c: u64| -> Vec<&(u64, u64)> {
        windows
            .iter()
            .filter(|(lo, hi)| *lo < c && c <= *hi)
            .collect()
    };
    let Some(best) = windows
        .iter()
        .map(|w| w.1)
        .max_by_key(|&c| (covered(c).len(), u64::MAX - c))
    else {
        return DEFAULT_RESPONSE_NS;
    };
    let w = covered(best);
    let lo = w.iter().map(|w| w.0).max().unwrap_or(0);
    let hi = w.iter().map(|w| w.1).min().unwrap_or(best);
    (lo + hi).div_ceil(2)
}

/// The habit most of a device's answers show (see [`network::Habit`]), its time fitted as
/// [`response_time`] fits the answer time; the datasheet's behaviour (the read interrupt kept)
/// when the capture shows none.
pub fn habit(habits: &[network::Habit]) -> AnswerBufferHabit {
    use network::Habit;
    let kind = |h: &Habit| match h {
        Habit::Keeps => None,
        Habit::Takes { opens, .. } => Some(*opens),
    };
    let Some(most) = habits
        .iter()
        .map(kind)
        .max_by_key(|k| habits.iter().filter(|h| kind(h) == *k).count())
    else {
        return AnswerBufferHabit::KeepsReadInterrupt;
    };
    let Some(opens) = most else {
        return AnswerBufferHabit::KeepsReadInterrupt;
    };
    let windows: Vec<(u64, u64)> = habits
        .iter()
        .filter_map(|h| match h {
            Habit::Takes { opens: o, window } if *o == opens => Some(*window),
            _ => None,
        })
        .collect();
    AnswerBufferHabit::TakesReadInterrupt {
        after_ns: response_time(&windows),
        opens,
    }
}

/// Reads `file` from the shared captures, builds its network and replays it.
pub fn replay(file: &str) -> Replayed {
    let exchanges = capture::load(&captures_dir().join(file));
    let network = network::derive(&exchanges);
    let dictionaries = (0..network.slaves.len())
        .map(|p| od::dictionary(&exchanges, &network, p))
        .collect();
    let response_ns: Vec<u64> = network
        .slaves
        .iter()
        .map(|s| response_time(&s.response_windows))
        .collect();
    let habits: Vec<AnswerBufferHabit> = network.slaves.iter().map(|s| habit(&s.habits)).collect();
    let mut slaves = build::slaves(&network, dictionaries, &response_ns);
    for (s, h) in slaves.iter_mut().zip(&habits) {
        s.habit = *h;
    }
    let mut seg = build::segment(&slaves);
    let mailboxes: Vec<_> = network.slaves.iter().map(|s| s.mailbox).collect();
    let outcome = compare::replay(&exchanges, &mut seg, &mailboxes);
    Replayed {
        exchanges,
        network,
        slaves,
        response_ns,
        outcome,
        segment: seg,
    }
}

/// One class of difference a capture is known to show today, and why.
pub struct Known {
    /// The class, as [`compare::Outcome`] names it ("FPRD AL status 0x0130-0x0135: state").
    pub class: &'static str,
    /// How many instances the replay gave when the list was written: more fails.
    pub count: usize,
    /// The cause.
    pub reason: &'static str,
}

/// Checks the classes found against the list of those known: a class not listed fails, a
/// listed class that no longer appears fails (the list must be kept true), a class with more
/// instances than listed fails. `what` names the kind of difference in the message.
pub fn check(what: &str, found: &BTreeMap<String, Vec<String>>, known: &[Known]) -> Vec<String> {
    let mut errors = Vec::new();
    for (class, v) in found {
        match known.iter().find(|k| k.class == class) {
            None => errors.push(format!(
                "{what} class not listed: {class}: {} (first: {})",
                v.len(),
                v[0]
            )),
            Some(k) if v.len() > k.count => errors.push(format!(
                "{what} class grew: {class}: {} (listed {}; first: {})",
                v.len(),
                k.count,
                v[0]
            )),
            Some(_) => {}
        }
    }
    for k in known {
        if !found.contains_key(k.class) {
            errors.push(format!(
                "{what} class listed but gone (take it off the list): {} ({})",
                k.class, k.reason
            ));
        }
    }
    errors
}
