//! A schedule checked against what it plays on: every fault that names a slave, a port or a
//! number of slaves against the network (refused otherwise: the player would do nothing and
//! say little), and the faults against the run's length (warned about: a fault that starts
//! after the end never happens), before anything is simulated or served.

use super::{Epoch, FaultKind, FaultSchedule, SlaveRef};
use crate::config::ConfigError;
use crate::segment::Segment;

impl FaultSchedule {
    /// The error of fault `n`'s `key`, located at the entry's line.
    fn entry_error(&self, n: usize, key: &str, message: String, fix: String) -> ConfigError {
        ConfigError {
            file: self.file.clone(),
            line: self.lines.get(n).copied(),
            field: format!("fault[{n}].{key}"),
            message,
            fix,
        }
    }

    /// Refuses the first fault that names a slave the network (`segment`, called `network` in
    /// messages) does not have, a port of a slave without a cable there, or more slaves to
    /// connect late than can be absent (the first stays): the player would skip it.
    pub fn check_segment(&self, segment: &Segment, network: &str) -> Result<(), ConfigError> {
        let len = segment.len();
        for (n, f) in self.faults.iter().enumerate() {
            let (slave, port) = match f.kind {
                FaultKind::PowerCycle { slave } | FaultKind::AlError { slave, .. } => (slave, None),
                FaultKind::LinkDown { slave, port } => (slave, Some(port)),
                FaultKind::HotConnect { slaves } if usize::from(slaves) >= len => {
                    return Err(self.entry_error(
                        n,
                        "slaves",
                        format!(
                            "{slaves} slaves cannot appear late: {network} has {len} (the first stays connected)"
                        ),
                        format!("give slaves from 1 to {}", len.saturating_sub(1)),
                    ));
                }
                _ => continue,
            };
            let pos = match slave {
                SlaveRef::Position(p) if p < len => p,
                SlaveRef::Position(p) => {
                    return Err(self.entry_error(
                        n,
                        "slave",
                        format!(
                            "slave {} is not in the network: {network} has {len} slaves",
                            p + 1
                        ),
                        format!(
                            "give a network position from 1 to {len} (1 = the slave next to the master), or \"reference\""
                        ),
                    ));
                }
                SlaveRef::Reference => match (0..len).find(|&p| segment.esc(p).dc().is_some()) {
                    Some(p) => p,
                    None => {
                        return Err(self.entry_error(
                            n,
                            "slave",
                            format!("{network} has no slave with a DC unit: no reference"),
                            format!("give a network position from 1 to {len}"),
                        ));
                    }
                },
            };
            if let Some(port) = port
                && !segment.has_cable(pos, usize::from(port))
            {
                let cabled: Vec<String> = (0..4)
                    .filter(|&q| segment.has_cable(pos, q))
                    .map(|q| q.to_string())
                    .collect();
                return Err(self.entry_error(
                    n,
                    "port",
                    format!(
                        "slave {} of {network} has no cable at port {port}: nothing would be pulled",
                        pos + 1
                    ),
                    format!(
                        "give a port of slave {} with a cable: {}",
                        pos + 1,
                        cabled.join(" or ")
                    ),
                ));
            }
        }
        Ok(())
    }

    /// What the user should hear about a schedule that plays less than it seems: no fault at
    /// all, and (given `end_ns`, the run's length after the epoch, and `how`, how to make the
    /// run longer) every fault that starts at or after the end, which never happens.
    pub fn warnings(&self, end_ns: Option<u64>, how: &str) -> Vec<String> {
        if self.faults.is_empty() {
            return vec![format!(
                "{}: no [[fault]] entry: the run plays no fault (presets/faults-demo.toml shows the entries)",
                self.file
            )];
        }
        let Some(end_ns) = end_ns else {
            return Vec::new();
        };
        let from = match self.epoch {
            Epoch::Cyclic => "the start of the cyclic phase",
            Epoch::Start => "the first frame",
        };
        self.faults
            .iter()
            .enumerate()
            .filter(|(_, f)| f.at_ns >= end_ns)
            .map(|(n, f)| {
                let line = self.lines.get(n).map_or(String::new(), |l| format!(":{l}"));
                format!(
                    "{}{line}: fault[{n}].at_s: the {} fault at {} s starts after the run's end, {} s after {from}: it is never played; fix: give at_s below {} or {how}",
                    self.file,
                    f.kind.name(),
                    f.at_ns as f64 / 1e9,
                    end_ns as f64 / 1e9,
                    end_ns as f64 / 1e9,
                )
            })
            .collect()
    }
}
