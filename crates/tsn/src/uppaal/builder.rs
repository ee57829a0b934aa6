//! What every process of the models is built from: the models' constants (the XML's), the
//! builder of channels and clocks, locations and edges.

use crate::ta::{ClockVar, Edge, Kind, Location, Network, Process, Sync};

pub(super) const LOCAL_DELAY_MASTER: i32 = 10;
pub(super) const LOCAL_DELAY_SLAVE: i32 = 10;
pub(super) const LOCAL_DELAY_SWITCH: i32 = 10;
pub(super) const TRANSMISSION_DELAY: i32 = 15;
pub(super) const PERIOD: i32 = 100;
pub(super) const GATE_OPEN: i32 = 30;
/// Slave and master clocks `t` are compared with 25 at most.
pub(super) const HOP_CLOCK_CAP: i32 = 26;

pub(super) struct Builder {
    pub(super) names: Vec<String>,
    pub(super) init: Vec<i32>,
    pub(super) clocks: Vec<ClockVar>,
    pub(super) channels: Vec<(String, bool)>,
}

impl Builder {
    pub(super) fn new() -> Self {
        Builder {
            names: Vec::new(),
            init: Vec::new(),
            clocks: Vec::new(),
            channels: Vec::new(),
        }
    }
    pub(super) fn int(&mut self, name: &str) -> usize {
        self.names.push(name.to_string());
        self.init.push(0);
        self.names.len() - 1
    }
    pub(super) fn ints<const N: usize>(&mut self, name: &str) -> [usize; N] {
        std::array::from_fn(|i| self.int(&format!("{name}[{i}]")))
    }
    pub(super) fn clock(&mut self, name: &str, cap: Option<i32>) -> usize {
        let v = self.int(name);
        self.clocks.push(ClockVar { var: v, cap });
        v
    }
    pub(super) fn chan(&mut self, name: &str, broadcast: bool) -> usize {
        self.channels.push((name.to_string(), broadcast));
        self.channels.len() - 1
    }
    pub(super) fn chans<const N: usize>(&mut self, name: &str) -> [usize; N] {
        std::array::from_fn(|i| self.chan(&format!("{name}[{i}]"), false))
    }
    pub(super) fn finish(self, processes: Vec<Process>) -> Network {
        Network {
            processes,
            var_names: self.names,
            init: self.init,
            clocks: self.clocks,
            broadcast: self.channels.iter().map(|c| c.1).collect(),
        }
    }
}

pub(super) fn loc(name: &'static str, kind: Kind, inv: Option<crate::ta::Pred>) -> Location {
    Location {
        name,
        kind,
        invariant: inv,
    }
}

pub(super) fn edge(
    from: usize,
    to: usize,
    guard: Option<crate::ta::Pred>,
    sync: Sync,
    update: Option<crate::ta::Update>,
) -> Edge {
    Edge {
        from,
        to,
        guard,
        sync,
        update,
    }
}

/// `(((L/Period) + 2) * Period) - d`
pub(super) fn trigger_plus2(l: i32, d: i32) -> i32 {
    ((l / PERIOD) + 2) * PERIOD - d
}

/// `(L % Period) < (Period - d) ? (((L/Period) + 1) * Period) - d : (((L/Period) + 2) * Period) - d`
pub(super) fn trigger_next(l: i32, d: i32) -> i32 {
    if l % PERIOD < PERIOD - d {
        ((l / PERIOD) + 1) * PERIOD - d
    } else {
        ((l / PERIOD) + 2) * PERIOD - d
    }
}
