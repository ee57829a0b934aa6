//! A network of timed automata with UPPAAL's semantics, explored exhaustively in integer time.
//!
//! The paper's models use only closed constraints (`<=`, `>=`, `==`) against integers, so by the
//! digitization theorem for closed timed automata, delays of one time unit reach exactly the
//! (location, integer variable) states that dense time reaches; every query reads only those.
//!
//! The rules followed (UPPAAL's system description semantics):
//! - a delay needs every process out of urgent and committed locations and every invariant to
//!   hold after it (all invariants here are upper bounds, so the end point decides);
//! - an action is an internal edge, a binary synchronisation (one `c!`, one `c?` of another
//!   process, both guards on the pre-state, the sender's update first) or a broadcast (the
//!   sender, and every other process with an enabled `c?` edge, one edge each);
//! - while a process is in a committed location, the next action must move one that is;
//! - a transition exists only if the target state satisfies every process's invariant,
//!   including processes that did not move.
//!
//! Clocks that are only ever compared with constants up to `cap - 1` are capped at `cap`: a
//! value beyond every constant behaves like any other, and the state space stays finite.

/// Integer variables and clocks of a state, by index.
pub type Vars = [i32];

/// A guard or invariant.
pub type Pred = Box<dyn Fn(&Vars) -> bool + Send + std::marker::Sync>;
/// An update.
pub type Update = Box<dyn Fn(&mut Vars) + Send + std::marker::Sync>;

/// How time behaves in a location.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Time may pass.
    Normal,
    /// Time may not pass.
    Urgent,
    /// Time may not pass and the next action must leave a committed location.
    Committed,
}

/// A location of a template instance.
pub struct Location {
    /// Name (the XML's or ours).
    pub name: &'static str,
    /// Urgency.
    pub kind: Kind,
    /// Invariant, if any.
    pub invariant: Option<Pred>,
}

/// A synchronisation label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sync {
    /// No synchronisation.
    None,
    /// `c!`
    Send(usize),
    /// `c?`
    Recv(usize),
}

/// An edge.
pub struct Edge {
    /// Source location.
    pub from: usize,
    /// Target location.
    pub to: usize,
    /// Guard (none: true).
    pub guard: Option<Pred>,
    /// Synchronisation.
    pub sync: Sync,
    /// Update (none: nothing).
    pub update: Option<Update>,
}

/// A process: a template instance with its parameters bound.
pub struct Process {
    /// Instance name (as in the system line).
    pub name: &'static str,
    /// Locations; the first is initial.
    pub locations: Vec<Location>,
    /// Edges.
    pub edges: Vec<Edge>,
}

/// A clock: its variable and the cap beyond which its value no longer matters.
#[derive(Debug, Clone, Copy)]
pub struct ClockVar {
    /// Index in the variables.
    pub var: usize,
    /// Values above are stored as `cap` (`None`: never capped).
    pub cap: Option<i32>,
}

/// A network of timed automata.
pub struct Network {
    /// Processes in system-line order.
    pub processes: Vec<Process>,
    /// Names of the variables, by index (for reports).
    pub var_names: Vec<String>,
    /// Initial values.
    pub init: Vec<i32>,
    /// Which variables are clocks.
    pub clocks: Vec<ClockVar>,
    /// Which channels are broadcast, by channel index.
    pub broadcast: Vec<bool>,
}

/// A state: one location per process, then the variables, packed into 16-bit words (UPPAAL's
/// `int` is 16-bit; clocks are capped or bounded by invariants).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct State {
    /// Location per process.
    pub loc: Vec<u8>,
    /// Variables (integers and clocks).
    pub vars: Vec<i32>,
}

/// What the explorer found.
#[derive(Debug, Clone)]
pub struct Exploration {
    /// States visited.
    pub states: usize,
    /// A reachable state without any successor (UPPAAL's deadlock, here the end of every run).
    pub deadlock: bool,
}

/// Reused buffers for successor generation.
#[derive(Default)]
struct Scratch {
    loc: Vec<u8>,
    vars: Vec<i32>,
}

/// Edges by (process, location), and binary/broadcast receivers by channel.
struct Index {
    /// `out[p][l]`: edges of process p leaving location l.
    out: Vec<Vec<Vec<usize>>>,
    /// `recv[ch]`: (process, edge) pairs receiving on channel ch.
    recv: Vec<Vec<(usize, usize)>>,
}

impl Network {
    /// The initial state.
    pub fn initial(&self) -> State {
        State {
            loc: vec![0; self.processes.len()],
            vars: self.init.clone(),
        }
    }

    fn index(&self) -> Index {
        let out = self
            .processes
            .iter()
            .map(|p| {
                (0..p.locations.len())
                    .map(|l| {
                        (0..p.edges.len())
                            .filter(|&e| p.edges[e].from == l)
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let mut recv = vec![Vec::new(); self.broadcast.len()];
        for (p, proc_) in self.processes.iter().enumerate() {
            for (e, edge) in proc_.edges.iter().enumerate() {
                if let Sync::Recv(ch) = edge.sync {
                    recv[ch].push((p, e));
                }
            }
        }
        Index { out, recv }
    }

    fn invariants_hold(&self, loc: &[u8], vars: &Vars) -> bool {
        self.processes.iter().zip(loc).all(|(p, &l)| {
            p.locations[l as usize]
                .invariant
                .as_ref()
                .is_none_or(|i| i(vars))
        })
    }

    fn cap(&self, vars: &mut Vars) {
        for c in &self.clocks {
            if let Some(cap) = c.cap
                && vars[c.var] > cap
            {
                vars[c.var] = cap;
            }
        }
    }

    fn enabled(e: &Edge, vars: &Vars) -> bool {
        e.guard.as_ref().is_none_or(|g| g(vars))
    }

    /// Calls `emit` with each successor's locations and variables (scratch buffers: nothing is
    /// allocated per successor).
    fn successors_indexed(
        &self,
        idx: &Index,
        s: &State,
        sc: &mut Scratch,
        emit: &mut dyn FnMut(&[u8], &[i32]),
    ) {
        let n = self.processes.len();
        let kind = |p: usize| self.processes[p].locations[s.loc[p] as usize].kind;
        let mut committed = [false; 64];
        let mut any_committed = false;
        let mut frozen = false;
        for (p, c) in committed.iter_mut().enumerate().take(n) {
            let k = kind(p);
            *c = k == Kind::Committed;
            any_committed |= *c;
            frozen |= k != Kind::Normal;
        }
        let Scratch { loc, vars } = sc;
        let mut finish = |loc: &mut Vec<u8>, vars: &mut Vec<i32>| {
            self.cap(vars);
            if self.invariants_hold(loc, vars) {
                emit(loc, vars);
            }
        };
        let reset = |loc: &mut Vec<u8>, vars: &mut Vec<i32>| {
            loc.clear();
            loc.extend_from_slice(&s.loc);
            vars.clear();
            vars.extend_from_slice(&s.vars);
        };
        for (p, proc_) in self.processes.iter().enumerate() {
            for &ei in &idx.out[p][s.loc[p] as usize] {
                let e = &proc_.edges[ei];
                if !Self::enabled(e, &s.vars) {
                    continue;
                }
                match e.sync {
                    Sync::None => {
                        if any_committed && !committed[p] {
                            continue;
                        }
                        reset(loc, vars);
                        if let Some(u) = &e.update {
                            u(vars);
                        }
                        loc[p] = e.to as u8;
                        finish(loc, vars);
                    }
                    Sync::Send(ch) if self.broadcast[ch] => {
                        // Every other process with an enabled c? edge takes part (the first
                        // such edge; the models have at most one per process and location).
                        reset(loc, vars);
                        let mut involves_committed = committed[p];
                        if let Some(u) = &e.update {
                            u(vars);
                        }
                        loc[p] = e.to as u8;
                        let mut taken = [false; 64];
                        for &(q, ri) in &idx.recv[ch] {
                            let r = &self.processes[q].edges[ri];
                            if q == p || taken[q] || r.from != s.loc[q] as usize {
                                continue;
                            }
                            if Self::enabled(r, &s.vars) {
                                taken[q] = true;
                                involves_committed |= committed[q];
                                if let Some(u) = &r.update {
                                    u(vars);
                                }
                                loc[q] = r.to as u8;
                            }
                        }
                        if any_committed && !involves_committed {
                            continue;
                        }
                        finish(loc, vars);
                    }
                    Sync::Send(ch) => {
                        for &(q, ri) in &idx.recv[ch] {
                            let r = &self.processes[q].edges[ri];
                            if q == p
                                || r.from != s.loc[q] as usize
                                || !Self::enabled(r, &s.vars)
                                || (any_committed && !committed[p] && !committed[q])
                            {
                                continue;
                            }
                            reset(loc, vars);
                            if let Some(u) = &e.update {
                                u(vars);
                            }
                            if let Some(u) = &r.update {
                                u(vars);
                            }
                            loc[p] = e.to as u8;
                            loc[q] = r.to as u8;
                            finish(loc, vars);
                        }
                    }
                    Sync::Recv(_) => {}
                }
            }
        }
        // Delay by one unit.
        if !frozen {
            reset(loc, vars);
            for c in &self.clocks {
                vars[c.var] += 1;
            }
            finish(loc, vars);
        }
    }

    fn pack_into(loc: &[u8], vars: &[i32], out: &mut Vec<i16>) {
        out.clear();
        out.extend(loc.iter().map(|&l| i16::from(l)));
        out.extend(
            vars.iter().map(|&v| {
                i16::try_from(v).expect("UPPAAL ints are 16-bit: a value left the range")
            }),
        );
    }

    fn unpack(&self, packed: &[i16], s: &mut State) {
        let n = self.processes.len();
        s.loc.clear();
        s.loc.extend(packed[..n].iter().map(|&l| l as u8));
        s.vars.clear();
        s.vars.extend(packed[n..].iter().map(|&v| i32::from(v)));
    }

    /// Visits every reachable state once, breadth first, calling `visit` on each.
    ///
    /// Every state has the same width, so the states live packed one after the other in one
    /// arena in the order they were found, which is also the breadth-first queue; the hash
    /// table holds only their positions.
    pub fn explore(&self, mut visit: impl FnMut(&State)) -> Exploration {
        use std::hash::BuildHasher;
        assert!(self.processes.len() <= 64, "at most 64 processes");
        let idx = self.index();
        let init = self.initial();
        let width = init.loc.len() + init.vars.len();
        let hasher = hashbrown::DefaultHashBuilder::default();
        let mut table: hashbrown::HashTable<u32> = hashbrown::HashTable::new();
        let mut arena: Vec<i16> = Vec::new();
        let mut buf = Vec::new();
        Self::pack_into(&init.loc, &init.vars, &mut buf);
        arena.extend_from_slice(&buf);
        table.insert_unique(hasher.hash_one(&buf[..]), 0, |_| 0);
        let mut deadlock = false;
        let mut s = init;
        let mut sc = Scratch::default();
        let mut next = 0usize;
        while next * width < arena.len() {
            let at = next * width;
            next += 1;
            self.unpack(&arena[at..at + width], &mut s);
            visit(&s);
            let mut any = false;
            self.successors_indexed(&idx, &s, &mut sc, &mut |loc, vars| {
                any = true;
                Self::pack_into(loc, vars, &mut buf);
                let h = hasher.hash_one(&buf[..]);
                let found = table
                    .find(h, |&i| {
                        let i = i as usize * width;
                        arena[i..i + width] == buf[..]
                    })
                    .is_some();
                if !found {
                    let id = u32::try_from(arena.len() / width).expect("under 4 G states");
                    arena.extend_from_slice(&buf);
                    table.insert_unique(h, id, |&i| {
                        let i = i as usize * width;
                        hasher.hash_one(&arena[i..i + width])
                    });
                }
            });
            deadlock |= !any;
        }
        Exploration {
            states: arena.len() / width,
            deadlock,
        }
    }

    /// The index of the process named `name`.
    pub fn process(&self, name: &str) -> Option<usize> {
        self.processes.iter().position(|p| p.name == name)
    }

    /// The index of location `loc` of process `p`.
    pub fn location(&self, p: usize, loc: &str) -> Option<u8> {
        self.processes[p]
            .locations
            .iter()
            .position(|l| l.name == loc)
            .map(|i| i as u8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two processes: A ticks a clock to 3 and sends; B receives and stops. A hand-made case:
    /// the send happens at exactly t = 3, and the end state has no successor.
    #[test]
    fn binary_sync_at_the_invariant_bound_then_deadlock() {
        let t = 0;
        let fired_at = 1;
        let net = Network {
            processes: vec![
                Process {
                    name: "A",
                    locations: vec![
                        Location {
                            name: "wait",
                            kind: Kind::Normal,
                            invariant: Some(Box::new(move |v| v[t] <= 3)),
                        },
                        Location {
                            name: "done",
                            kind: Kind::Normal,
                            invariant: Some(Box::new(move |v| v[t] <= 3)),
                        },
                    ],
                    edges: vec![Edge {
                        from: 0,
                        to: 1,
                        guard: Some(Box::new(move |v| v[t] >= 3)),
                        sync: Sync::Send(0),
                        update: Some(Box::new(move |v| v[fired_at] = v[t] + 100)),
                    }],
                },
                Process {
                    name: "B",
                    locations: vec![
                        Location {
                            name: "idle",
                            kind: Kind::Normal,
                            invariant: None,
                        },
                        Location {
                            name: "got",
                            kind: Kind::Committed,
                            invariant: None,
                        },
                    ],
                    edges: vec![Edge {
                        from: 0,
                        to: 1,
                        guard: None,
                        sync: Sync::Recv(0),
                        update: None,
                    }],
                },
            ],
            var_names: vec!["t".into(), "fired_at".into()],
            init: vec![0, 0],
            clocks: vec![ClockVar { var: t, cap: None }],
            broadcast: vec![false],
        };
        let mut fired = Vec::new();
        let ex = net.explore(|s| {
            if s.vars[fired_at] != 0 {
                fired.push(s.vars[fired_at]);
            }
        });
        assert_eq!(fired, [103]);
        // t = 0..=3 waiting, then the synchronised state (no delay out of "got", no edge).
        assert_eq!(ex.states, 5);
        assert!(ex.deadlock);
    }
}
