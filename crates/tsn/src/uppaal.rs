//! The three UPPAAL models of Bujosa Mateu et al., "Clock Synchronization in Integrated
//! TSN-EtherCAT Networks" (the `M1.xml`, `M2.xml`, `M3.xml` files), rebuilt edge by edge:
//!
//! - **M1**: an EtherCAT master and two slaves (the paper's S1 and S2), no TSN;
//! - **M2**: a TSN bridge between master and slaves whose gate is open 30 of every 100 units of
//!   the bridge's own clock; the master is not synchronized to the bridge;
//! - **M3**: the same bridge, plus gPTP: the bridge is the grandmaster and the master a
//!   time-aware end station that starts only once synchronized and then acts as DC reference.
//!
//! Every oscillator ticks every 9 or 10 real units (chosen once) and adds 10 to its node's
//! local time; a hop (processing 10 + transmission 15) takes 25 real units; the master measures
//! the delays with DM_T/DM_R/DM_C (T1..T4, rounded to the clock's 10-unit grain) and
//! distributes its time by SM, which each slave sets as `Master_ref_time + Delay`. The models
//! stop themselves after the last slave's second SM. Names, guards, invariants and updates are
//! the XML's (`docs/design/tsn-uppaal-notes.md` transcribes them); location names in capitals
//! are ours where the XML has none.

use crate::ta::{ClockVar, Edge, Kind, Location, Network, Process, Sync};

const LOCAL_DELAY_MASTER: i32 = 10;
const LOCAL_DELAY_SLAVE: i32 = 10;
const LOCAL_DELAY_SWITCH: i32 = 10;
const TRANSMISSION_DELAY: i32 = 15;
const PERIOD: i32 = 100;
const GATE_OPEN: i32 = 30;
/// Slave and master clocks `t` are compared with 25 at most.
const HOP_CLOCK_CAP: i32 = 26;

/// Which model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Model {
    /// No TSN.
    M1,
    /// TSN bridge, no gPTP.
    M2,
    /// TSN bridge, master synchronized by gPTP.
    M3,
}

impl Model {
    /// All three.
    pub const ALL: [Model; 3] = [Model::M1, Model::M2, Model::M3];

    /// The paper's name of the model.
    pub fn title(self) -> &'static str {
        match self {
            Model::M1 => "No TSN (M1)",
            Model::M2 => "No Sync TSN (M2)",
            Model::M3 => "Sync TSN (M3)",
        }
    }
}

/// Indices of the quantities the queries read.
#[derive(Debug, Clone, Copy)]
pub struct Probes {
    /// `Local_time` of the master, the paper's S1 and S2.
    pub master: usize,
    /// `Local_time` of slave S1.
    pub s1: usize,
    /// `Local_time` of slave S2.
    pub s2: usize,
    /// `Local_time` of the bridge (M2, M3).
    pub bridge: Option<usize>,
    /// `Delay[0]`, `Delay[1]`.
    pub delay: [usize; 2],
    /// `Num_period`.
    pub num_period: usize,
    /// The bridge process and its three blocked locations (M2, M3).
    pub gate: Option<(usize, [u8; 3])>,
}

struct Builder {
    names: Vec<String>,
    init: Vec<i32>,
    clocks: Vec<ClockVar>,
    channels: Vec<(String, bool)>,
}

impl Builder {
    fn new() -> Self {
        Builder {
            names: Vec::new(),
            init: Vec::new(),
            clocks: Vec::new(),
            channels: Vec::new(),
        }
    }
    fn int(&mut self, name: &str) -> usize {
        self.names.push(name.to_string());
        self.init.push(0);
        self.names.len() - 1
    }
    fn ints<const N: usize>(&mut self, name: &str) -> [usize; N] {
        std::array::from_fn(|i| self.int(&format!("{name}[{i}]")))
    }
    fn clock(&mut self, name: &str, cap: Option<i32>) -> usize {
        let v = self.int(name);
        self.clocks.push(ClockVar { var: v, cap });
        v
    }
    fn chan(&mut self, name: &str, broadcast: bool) -> usize {
        self.channels.push((name.to_string(), broadcast));
        self.channels.len() - 1
    }
    fn chans<const N: usize>(&mut self, name: &str) -> [usize; N] {
        std::array::from_fn(|i| self.chan(&format!("{name}[{i}]"), false))
    }
    fn finish(self, processes: Vec<Process>) -> Network {
        Network {
            processes,
            var_names: self.names,
            init: self.init,
            clocks: self.clocks,
            broadcast: self.channels.iter().map(|c| c.1).collect(),
        }
    }
}

fn loc(name: &'static str, kind: Kind, inv: Option<crate::ta::Pred>) -> Location {
    Location {
        name,
        kind,
        invariant: inv,
    }
}

fn edge(
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
fn trigger_plus2(l: i32, d: i32) -> i32 {
    ((l / PERIOD) + 2) * PERIOD - d
}

/// `(L % Period) < (Period - d) ? (((L/Period) + 1) * Period) - d : (((L/Period) + 2) * Period) - d`
fn trigger_next(l: i32, d: i32) -> i32 {
    if l % PERIOD < PERIOD - d {
        ((l / PERIOD) + 1) * PERIOD - d
    } else {
        ((l / PERIOD) + 2) * PERIOD - d
    }
}

/// `Oscillator(TIC, t)`: CHOOSE (committed) picks 9 or 10, RUN ticks every period.
/// `exact_guard`: M2 writes the tick guard `t == TIC_period`, M1 and M3 `t >= TIC_period`.
fn oscillator(
    b: &mut Builder,
    name: &'static str,
    tic: usize,
    t: usize,
    exact_guard: bool,
) -> Process {
    let period = b.int(&format!("{name}.TIC_period"));
    Process {
        name,
        locations: vec![
            loc("CHOOSE", Kind::Committed, None),
            loc(
                "RUN",
                Kind::Normal,
                Some(Box::new(move |v| v[t] <= v[period])),
            ),
        ],
        edges: vec![
            edge(
                0,
                1,
                None,
                Sync::None,
                Some(Box::new(move |v| v[period] = 10)),
            ),
            edge(
                0,
                1,
                None,
                Sync::None,
                Some(Box::new(move |v| v[period] = 9)),
            ),
            edge(
                1,
                1,
                Some(if exact_guard {
                    Box::new(move |v| v[t] == v[period])
                } else {
                    Box::new(move |v| v[t] >= v[period])
                }),
                Sync::Send(tic),
                Some(Box::new(move |v| v[t] = 0)),
            ),
        ],
    }
}

/// `Clock(TIC, Local_time)`: +10 per tick until the second SM period, then STOPPED.
/// `stop_eq`: M2/M3 guard `Num_period == 2`, M1 `Num_period >= 2`.
fn clock(name: &'static str, tic: usize, lt: usize, num_period: usize, stop_eq: bool) -> Process {
    Process {
        name,
        locations: vec![
            loc("COUNT", Kind::Normal, None),
            loc("STOPPED", Kind::Normal, None),
        ],
        edges: vec![
            edge(
                0,
                1,
                Some(if stop_eq {
                    Box::new(move |v| v[num_period] == 2)
                } else {
                    Box::new(move |v| v[num_period] >= 2)
                }),
                Sync::Recv(tic),
                None,
            ),
            edge(
                0,
                0,
                Some(Box::new(move |v| v[num_period] < 2)),
                Sync::Recv(tic),
                Some(Box::new(move |v| v[lt] += 10)),
            ),
        ],
    }
}

const HOP: i32 = LOCAL_DELAY_SLAVE + TRANSMISSION_DELAY;

/// Channels a slave forwards between.
struct SlaveChans {
    sm_in: usize,
    sm_out: usize,
    dmt_in: usize,
    dmr_in: usize,
    dmc_in: usize,
    dmt_out: usize,
    dmr_out: usize,
    dmc_out: usize,
}

/// `Slave(...)`: forwards DM_T, DM_R, DM_C and SM with a 25-unit hop, latching T2 (DM_T in),
/// T3 (DM_R in) and setting its time from SM.
#[allow(clippy::too_many_arguments)]
fn slave(
    b: &mut Builder,
    name: &'static str,
    c: SlaveChans,
    lt: usize,
    t2: usize,
    t3: usize,
    delay: usize,
    mref: usize,
) -> Process {
    let t = b.clock(&format!("{name}.t"), Some(HOP_CLOCK_CAP));
    let hop_inv = move || -> Option<crate::ta::Pred> { Some(Box::new(move |v| v[t] <= HOP)) };
    let hop_done = move || -> Option<crate::ta::Pred> { Some(Box::new(move |v| v[t] >= HOP)) };
    // 0 WAIT_DMT, 1 FWD_DMT, 2 WAIT_DMR, 3 FWD_DMR, 4 WAIT_DMC, 5 FWD_DMC, 6 SM_DONE, 7 FWD_SM,
    // 8 WAIT_SM
    Process {
        name,
        locations: vec![
            loc("WAIT_DMT", Kind::Normal, None),
            loc("FWD_DMT", Kind::Normal, hop_inv()),
            loc("WAIT_DMR", Kind::Normal, None),
            loc("FWD_DMR", Kind::Normal, hop_inv()),
            loc("WAIT_DMC", Kind::Normal, None),
            loc("FWD_DMC", Kind::Normal, hop_inv()),
            loc("SM_DONE", Kind::Urgent, None),
            loc("FWD_SM", Kind::Normal, hop_inv()),
            loc("WAIT_SM", Kind::Normal, None),
        ],
        edges: vec![
            edge(
                0,
                1,
                None,
                Sync::Recv(c.dmt_in),
                Some(Box::new(move |v| {
                    v[t2] = v[lt];
                    v[t] = 0;
                })),
            ),
            edge(
                2,
                3,
                None,
                Sync::Recv(c.dmr_in),
                Some(Box::new(move |v| {
                    v[t3] = v[lt];
                    v[t] = 0;
                })),
            ),
            edge(1, 2, hop_done(), Sync::Send(c.dmt_out), None),
            edge(5, 8, hop_done(), Sync::Send(c.dmc_out), None),
            edge(
                4,
                5,
                None,
                Sync::Recv(c.dmc_in),
                Some(Box::new(move |v| v[t] = 0)),
            ),
            edge(3, 4, hop_done(), Sync::Send(c.dmr_out), None),
            edge(6, 8, None, Sync::None, None),
            edge(7, 6, hop_done(), Sync::Send(c.sm_out), None),
            edge(
                8,
                7,
                None,
                Sync::Recv(c.sm_in),
                Some(Box::new(move |v| {
                    v[lt] = v[mref] + v[delay];
                    v[t] = 0;
                })),
            ),
        ],
    }
}

/// `Last_slave(...)`: returns DM_T as DM_R after a hop (T2 = T3), counts SM periods.
#[allow(clippy::too_many_arguments)]
fn last_slave(
    b: &mut Builder,
    name: &'static str,
    sm_in: usize,
    lt: usize,
    dmt_in: usize,
    dmr_out: usize,
    dmc_in: usize,
    t2: usize,
    t3: usize,
    delay: usize,
    mref: usize,
    num_period: usize,
) -> Process {
    let t = b.clock(&format!("{name}.t"), Some(HOP_CLOCK_CAP));
    // 0 WAIT_DMT, 1 RET_DMR, 2 WAIT_DMC, 3 SYNCED
    Process {
        name,
        locations: vec![
            loc("WAIT_DMT", Kind::Normal, None),
            loc(
                "RET_DMR",
                Kind::Normal,
                Some(Box::new(move |v| v[t] <= HOP)),
            ),
            loc("WAIT_DMC", Kind::Normal, None),
            loc("SYNCED", Kind::Normal, None),
        ],
        edges: vec![
            edge(2, 3, None, Sync::Recv(dmc_in), None),
            edge(
                3,
                3,
                None,
                Sync::Recv(sm_in),
                Some(Box::new(move |v| {
                    v[lt] = v[mref] + v[delay];
                    v[num_period] += 1;
                })),
            ),
            edge(
                0,
                1,
                None,
                Sync::Recv(dmt_in),
                Some(Box::new(move |v| {
                    v[t2] = v[lt];
                    v[t3] = v[lt];
                    v[t] = 0;
                })),
            ),
            edge(
                1,
                2,
                Some(Box::new(move |v| v[t] >= HOP)),
                Sync::Send(dmr_out),
                None,
            ),
        ],
    }
}

/// The master's variables and channels.
struct MasterBinding {
    sm_out: usize,
    lt: usize,
    dmt_out: usize,
    dmr_in: usize,
    dmc_out: usize,
    t1: usize,
    t4: usize,
    mref: usize,
    /// Its oscillator's clock: `Local_time + gt` interpolates the local time.
    gt: usize,
    t2: [usize; 2],
    t3: [usize; 2],
    delay: [usize; 2],
    /// M3: it waits for the first gPTP SM (broadcast channel).
    gptp_sm_in: Option<usize>,
}

/// `Master(...)`: DM_T at once (M1, M2) or at its first trigger after gPTP sync (M3), DM_C one
/// period later with the delays computed, then SM every period from `Trigger`.
fn master(b: &mut Builder, name: &'static str, m: MasterBinding) -> Process {
    let t = b.clock(&format!("{name}.t"), Some(HOP_CLOCK_CAP));
    let trigger = b.int(&format!("{name}.Trigger"));
    let MasterBinding {
        sm_out,
        lt,
        dmt_out,
        dmr_in,
        dmc_out,
        t1,
        t4,
        mref,
        gt,
        t2,
        t3,
        delay,
        gptp_sm_in,
    } = m;
    let hop = LOCAL_DELAY_MASTER + TRANSMISSION_DELAY;
    let d = LOCAL_DELAY_MASTER;
    let wait_trigger =
        move || -> Option<crate::ta::Pred> { Some(Box::new(move |v| v[lt] + v[gt] <= v[trigger])) };
    let at_trigger =
        move || -> Option<crate::ta::Pred> { Some(Box::new(move |v| v[lt] + v[gt] >= v[trigger])) };
    // Locations: [WAIT_GPTP (M3)], INIT, TX_SM, WAIT_SM_TRIG, TX_DMC, WAIT_DMT, WAIT_CALC,
    // TX_DMT, WAIT_DMR.
    let o = usize::from(gptp_sm_in.is_some());
    let (init, tx_sm, wait_sm, tx_dmc, wait_dmt, wait_calc, tx_dmt, wait_dmr) =
        (o, o + 1, o + 2, o + 3, o + 4, o + 5, o + 6, o + 7);
    let mut locations = Vec::new();
    if gptp_sm_in.is_some() {
        locations.push(loc("WAIT_GPTP", Kind::Normal, None));
    }
    locations.extend([
        loc("INIT", Kind::Urgent, None),
        loc("TX_SM", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
        loc("WAIT_SM_TRIG", Kind::Normal, wait_trigger()),
        loc("TX_DMC", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
        loc("WAIT_DMT", Kind::Normal, wait_trigger()),
        loc("WAIT_CALC", Kind::Normal, wait_trigger()),
        loc("TX_DMT", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
        loc("WAIT_DMR", Kind::Normal, None),
    ]);
    let calculate_delays = move |v: &mut [i32]| {
        for i in 0..2 {
            v[delay[i]] = ((((v[t4] - v[t1] - LOCAL_DELAY_MASTER - v[t3[i]] - LOCAL_DELAY_SLAVE
                + v[t2[i]])
                / 2)
                + LOCAL_DELAY_MASTER)
                / 10)
                * 10;
        }
    };
    let mut edges = Vec::new();
    if let Some(ch) = gptp_sm_in {
        edges.push(edge(0, init, None, Sync::Recv(ch), None));
        // M3: INIT aims at the next trigger of the (now synchronized) local time.
        edges.push(edge(
            init,
            wait_dmt,
            None,
            Sync::None,
            Some(Box::new(move |v| v[trigger] = trigger_next(v[lt], d))),
        ));
    } else {
        edges.push(edge(
            init,
            wait_dmt,
            None,
            Sync::None,
            Some(Box::new(move |v| v[trigger] = trigger_plus2(v[lt], d))),
        ));
    }
    edges.extend([
        edge(
            tx_sm,
            wait_sm,
            Some(Box::new(move |v| v[t] >= hop)),
            Sync::Send(sm_out),
            Some(Box::new(move |v| v[trigger] = trigger_next(v[lt], d))),
        ),
        edge(
            wait_sm,
            tx_sm,
            at_trigger(),
            Sync::None,
            Some(Box::new(move |v| {
                v[t] = 0;
                v[mref] = v[lt];
            })),
        ),
        edge(
            tx_dmc,
            wait_sm,
            Some(Box::new(move |v| v[t] >= hop)),
            Sync::Send(dmc_out),
            Some(Box::new(move |v| v[trigger] = trigger_plus2(v[lt], d))),
        ),
        edge(
            wait_calc,
            tx_dmc,
            at_trigger(),
            Sync::None,
            Some(Box::new(move |v| {
                calculate_delays(v);
                v[t] = 0;
            })),
        ),
        edge(
            wait_dmt,
            tx_dmt,
            // M1 and M2: no guard (DM_T may leave at any instant before the trigger); M3
            // waits for the trigger.
            if gptp_sm_in.is_some() {
                at_trigger()
            } else {
                None
            },
            Sync::None,
            Some(Box::new(move |v| {
                v[t1] = v[lt];
                v[t] = 0;
            })),
        ),
        edge(
            tx_dmt,
            wait_dmr,
            Some(Box::new(move |v| v[t] >= hop)),
            Sync::Send(dmt_out),
            None,
        ),
        edge(
            wait_dmr,
            wait_calc,
            None,
            Sync::Recv(dmr_in),
            Some(Box::new(move |v| {
                v[t4] = v[lt];
                v[trigger] = trigger_next(v[lt], d);
            })),
        ),
    ]);
    Process {
        name,
        locations,
        edges,
    }
}

/// `Network(...)`: the bridge's gate, open while its local time is within the first 30 of
/// every 100 units; a frame arriving with the gate closed waits for the next opening.
#[allow(clippy::too_many_arguments)]
fn bridge(
    name: &'static str,
    sm_in: usize,
    sm_out: usize,
    lt: usize,
    dmt_in: usize,
    dmc_in: usize,
    dmt_out: usize,
    dmc_out: usize,
) -> Process {
    let phase = move |v: &[i32]| v[lt] % PERIOD;
    let closed_inv = move || -> Option<crate::ta::Pred> {
        Some(Box::new(move |v| phase(v) >= GATE_OPEN || phase(v) == 0))
    };
    let open_inv =
        move || -> Option<crate::ta::Pred> { Some(Box::new(move |v| phase(v) <= GATE_OPEN)) };
    let g =
        |f: fn(i32) -> bool| -> Option<crate::ta::Pred> { Some(Box::new(move |v| f(phase(v)))) };
    // 0 OPEN_IDLE (initial), 1 OPEN_USED, 2 CLOSED, 3 SM_bloqued, 4 DM_T_bloqued,
    // 5 DM_C_bloqued, 6 FWD_SM, 7 FWD_DMT, 8 FWD_DMC
    Process {
        name,
        locations: vec![
            loc("OPEN_IDLE", Kind::Normal, open_inv()),
            loc("OPEN_USED", Kind::Normal, open_inv()),
            loc("CLOSED", Kind::Normal, closed_inv()),
            loc("SM_bloqued", Kind::Normal, closed_inv()),
            loc("DM_T_bloqued", Kind::Normal, closed_inv()),
            loc("DM_C_bloqued", Kind::Normal, closed_inv()),
            loc("FWD_SM", Kind::Committed, None),
            loc("FWD_DMT", Kind::Committed, None),
            loc("FWD_DMC", Kind::Committed, None),
        ],
        edges: vec![
            edge(6, 1, None, Sync::Send(sm_out), None),
            edge(0, 6, g(|p| p < GATE_OPEN), Sync::Recv(sm_in), None),
            edge(7, 1, None, Sync::Send(dmt_out), None),
            edge(0, 7, g(|p| p < GATE_OPEN), Sync::Recv(dmt_in), None),
            edge(8, 1, None, Sync::Send(dmc_out), None),
            edge(0, 8, g(|p| p < GATE_OPEN), Sync::Recv(dmc_in), None),
            edge(1, 2, g(|p| p == GATE_OPEN), Sync::None, None),
            edge(3, 1, g(|p| p == 0), Sync::Send(sm_out), None),
            edge(2, 3, g(|p| p >= GATE_OPEN), Sync::Recv(sm_in), None),
            edge(4, 1, g(|p| p == 0), Sync::Send(dmt_out), None),
            edge(2, 4, g(|p| p >= GATE_OPEN), Sync::Recv(dmt_in), None),
            edge(5, 1, g(|p| p == 0), Sync::Send(dmc_out), None),
            edge(2, 5, g(|p| p >= GATE_OPEN), Sync::Recv(dmc_in), None),
            edge(2, 0, g(|p| p == 0), Sync::None, None),
            edge(0, 2, g(|p| p == GATE_OPEN), Sync::None, None),
        ],
    }
}

/// The model as a network, with the indices its queries read.
pub fn build(model: Model) -> (Network, Probes) {
    let mut b = Builder::new();
    match model {
        Model::M1 => {
            let t: [usize; 3] = std::array::from_fn(|i| b.clock(&format!("t[{i}]"), None));
            let tic: [usize; 3] = b.chans("TIC");
            let lt: [usize; 3] = b.ints("Local_time");
            let sm: [usize; 3] = b.chans("SM");
            let [mref] = b.ints::<1>("Master_ref_time");
            let num_period = b.int("Num_period");
            let dmt: [usize; 2] = b.chans("DM_T");
            let dmr: [usize; 2] = b.chans("DM_R");
            let dmc: [usize; 2] = b.chans("DM_C");
            let [t1] = b.ints::<1>("T1");
            let t2: [usize; 2] = b.ints("T2");
            let t3: [usize; 2] = b.ints("T3");
            let [t4] = b.ints::<1>("T4");
            let delay: [usize; 2] = b.ints("Delay");
            let om0 = oscillator(&mut b, "OM0", tic[0], t[0], false);
            let cm0 = clock("CM0", tic[0], lt[0], num_period, false);
            let m0 = master(
                &mut b,
                "M0",
                MasterBinding {
                    sm_out: sm[0],
                    lt: lt[0],
                    dmt_out: dmt[0],
                    dmr_in: dmr[0],
                    dmc_out: dmc[0],
                    t1,
                    t4,
                    mref,
                    gt: t[0],
                    t2,
                    t3,
                    delay,
                    gptp_sm_in: None,
                },
            );
            let o0 = oscillator(&mut b, "O0", tic[1], t[1], false);
            let c0 = clock("C0", tic[1], lt[1], num_period, false);
            let s0 = slave(
                &mut b,
                "S0",
                SlaveChans {
                    sm_in: sm[0],
                    sm_out: sm[1],
                    dmt_in: dmt[0],
                    dmr_in: dmr[1],
                    dmc_in: dmc[0],
                    dmt_out: dmt[1],
                    dmr_out: dmr[0],
                    dmc_out: dmc[1],
                },
                lt[1],
                t2[0],
                t3[0],
                delay[0],
                mref,
            );
            let o1 = oscillator(&mut b, "O1", tic[2], t[2], false);
            let c1 = clock("C1", tic[2], lt[2], num_period, false);
            let s1 = last_slave(
                &mut b, "S1", sm[1], lt[2], dmt[1], dmr[1], dmc[1], t2[1], t3[1], delay[1], mref,
                num_period,
            );
            let net = b.finish(vec![om0, cm0, m0, o0, c0, s0, o1, c1, s1]);
            let probes = Probes {
                master: lt[0],
                s1: lt[1],
                s2: lt[2],
                bridge: None,
                delay,
                num_period,
                gate: None,
            };
            (net, probes)
        }
        Model::M2 | Model::M3 => {
            let m3 = model == Model::M3;
            let t: [usize; 4] = std::array::from_fn(|i| b.clock(&format!("t[{i}]"), None));
            let tic: [usize; 4] = b.chans("TIC");
            let lt: [usize; 4] = b.ints("Local_time");
            let sm: [usize; 3] = b.chans("SM");
            let [mref] = b.ints::<1>("Master_ref_time");
            let num_period = b.int("Num_period");
            let dmt: [usize; 3] = b.chans("DM_T");
            let dmr: [usize; 2] = b.chans("DM_R");
            let dmc: [usize; 3] = b.chans("DM_C");
            let [t1] = b.ints::<1>("T1");
            let t2: [usize; 2] = b.ints("T2");
            let t3: [usize; 2] = b.ints("T3");
            let [t4] = b.ints::<1>("T4");
            let delay: [usize; 2] = b.ints("Delay");
            let exact = model == Model::M2;
            let mut procs = Vec::new();
            procs.push(oscillator(&mut b, "OM0", tic[1], t[1], exact));
            procs.push(clock("CM0", tic[1], lt[1], num_period, true));
            let gptp = if m3 {
                let sm_g = b.chan("SM_gPTP[0]", true);
                let network_ref_time = b.int("Network_ref_time");
                let dmt_g = b.chan("DM_T_gPTP[0]", false);
                let dmr_g = b.chan("DM_R_gPTP[0]", false);
                let dmc_g = b.chan("DM_C_gPTP[0]", false);
                let [t1g] = b.ints::<1>("T1_gPTP");
                let [t2g] = b.ints::<1>("T2_gPTP");
                let [t3g] = b.ints::<1>("T3_gPTP");
                let [t4g] = b.ints::<1>("T4_gPTP");
                let [delay_g] = b.ints::<1>("Delay_gPTP");
                Some((
                    sm_g,
                    network_ref_time,
                    dmt_g,
                    dmr_g,
                    dmc_g,
                    t1g,
                    t2g,
                    t3g,
                    t4g,
                    delay_g,
                ))
            } else {
                None
            };
            procs.push(master(
                &mut b,
                "M0",
                MasterBinding {
                    sm_out: sm[0],
                    lt: lt[1],
                    dmt_out: dmt[0],
                    dmr_in: dmr[0],
                    dmc_out: dmc[0],
                    t1,
                    t4,
                    mref,
                    gt: t[1],
                    t2,
                    t3,
                    delay,
                    gptp_sm_in: gptp.map(|g| g.0),
                },
            ));
            if let Some((sm_g, nref, dmt_g, dmr_g, dmc_g, _, t2g, t3g, _, delay_g)) = gptp {
                procs.push(master_gptp(
                    &mut b, "Mg0", sm_g, lt[1], dmt_g, dmr_g, dmc_g, t2g, t3g, delay_g, nref,
                ));
            }
            procs.push(oscillator(&mut b, "ON0", tic[0], t[0], exact));
            procs.push(clock("CN0", tic[0], lt[0], num_period, true));
            let n0 = procs.len();
            procs.push(bridge(
                "N0", sm[0], sm[1], lt[0], dmt[0], dmc[0], dmt[1], dmc[1],
            ));
            if let Some((sm_g, nref, dmt_g, dmr_g, dmc_g, t1g, t2g, t3g, t4g, delay_g)) = gptp {
                procs.push(network_gptp(
                    &mut b,
                    "Ng00",
                    GptpBridgeBinding {
                        sm_out: sm_g,
                        lt: lt[0],
                        dmt_out: dmt_g,
                        dmr_in: dmr_g,
                        dmc_out: dmc_g,
                        t1: t1g,
                        t4: t4g,
                        gt: t[0],
                        t2: t2g,
                        t3: t3g,
                        delay: delay_g,
                        network_ref_time: nref,
                    },
                ));
            }
            procs.push(oscillator(&mut b, "O0", tic[2], t[2], exact));
            procs.push(clock("C0", tic[2], lt[2], num_period, true));
            procs.push(slave(
                &mut b,
                "S0",
                SlaveChans {
                    sm_in: sm[1],
                    sm_out: sm[2],
                    dmt_in: dmt[1],
                    dmr_in: dmr[1],
                    dmc_in: dmc[1],
                    dmt_out: dmt[2],
                    dmr_out: dmr[0],
                    dmc_out: dmc[2],
                },
                lt[2],
                t2[0],
                t3[0],
                delay[0],
                mref,
            ));
            procs.push(oscillator(&mut b, "O1", tic[3], t[3], exact));
            procs.push(clock("C1", tic[3], lt[3], num_period, true));
            procs.push(last_slave(
                &mut b, "S1", sm[2], lt[3], dmt[2], dmr[1], dmc[2], t2[1], t3[1], delay[1], mref,
                num_period,
            ));
            let net = b.finish(procs);
            let blocked = ["SM_bloqued", "DM_T_bloqued", "DM_C_bloqued"]
                .map(|l| net.location(n0, l).expect("bridge location"));
            let probes = Probes {
                master: lt[1],
                s1: lt[2],
                s2: lt[3],
                bridge: Some(lt[0]),
                delay,
                num_period,
                gate: Some((n0, blocked)),
            };
            (net, probes)
        }
    }
}

/// `Master_gPTP(...)` (M3): the master as a gPTP end station: answers the bridge's delay
/// measurement, then sets its local time from every gPTP SM.
#[allow(clippy::too_many_arguments)]
fn master_gptp(
    b: &mut Builder,
    name: &'static str,
    sm_in: usize,
    lt: usize,
    dmt_in: usize,
    dmr_out: usize,
    dmc_in: usize,
    t2: usize,
    t3: usize,
    delay: usize,
    network_ref_time: usize,
) -> Process {
    let t = b.clock(&format!("{name}.t"), Some(HOP_CLOCK_CAP));
    let hop = LOCAL_DELAY_MASTER + TRANSMISSION_DELAY;
    // 0 WAIT_DMT, 1 RET_DMR, 2 WAIT_DMC, 3 SYNCED
    Process {
        name,
        locations: vec![
            loc("WAIT_DMT", Kind::Normal, None),
            loc(
                "RET_DMR",
                Kind::Normal,
                Some(Box::new(move |v| v[t] <= hop)),
            ),
            loc("WAIT_DMC", Kind::Normal, None),
            loc("SYNCED", Kind::Normal, None),
        ],
        edges: vec![
            edge(2, 3, None, Sync::Recv(dmc_in), None),
            edge(
                3,
                3,
                None,
                Sync::Recv(sm_in),
                Some(Box::new(move |v| v[lt] = v[network_ref_time] + v[delay])),
            ),
            edge(
                0,
                1,
                None,
                Sync::Recv(dmt_in),
                Some(Box::new(move |v| {
                    v[t2] = v[lt];
                    v[t3] = v[lt];
                    v[t] = 0;
                })),
            ),
            edge(
                1,
                2,
                Some(Box::new(move |v| v[t] >= hop)),
                Sync::Send(dmr_out),
                None,
            ),
        ],
    }
}

struct GptpBridgeBinding {
    sm_out: usize,
    lt: usize,
    dmt_out: usize,
    dmr_in: usize,
    dmc_out: usize,
    t1: usize,
    t4: usize,
    gt: usize,
    t2: usize,
    t3: usize,
    delay: usize,
    network_ref_time: usize,
}

/// `Network_gPTP(...)` (M3): the bridge as grandmaster: measures the master's delay at once,
/// then sends its time every period (broadcast).
fn network_gptp(b: &mut Builder, name: &'static str, g: GptpBridgeBinding) -> Process {
    let t = b.clock(&format!("{name}.t"), Some(HOP_CLOCK_CAP));
    let trigger = b.int(&format!("{name}.Trigger"));
    let hop = LOCAL_DELAY_SWITCH + TRANSMISSION_DELAY;
    let d = LOCAL_DELAY_SWITCH;
    let GptpBridgeBinding {
        sm_out,
        lt,
        dmt_out,
        dmr_in,
        dmc_out,
        t1,
        t4,
        gt,
        t2,
        t3,
        delay,
        network_ref_time,
    } = g;
    // 0 INIT (urgent, initial), 1 TX_DMT, 2 WAIT_DMR, 3 CALC (urgent), 4 TX_DMC,
    // 5 WAIT_SM_TRIG, 6 TX_SM
    Process {
        name,
        locations: vec![
            loc("INIT", Kind::Urgent, None),
            loc("TX_DMT", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
            loc("WAIT_DMR", Kind::Normal, None),
            loc("CALC", Kind::Urgent, None),
            loc("TX_DMC", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
            loc(
                "WAIT_SM_TRIG",
                Kind::Normal,
                Some(Box::new(move |v| v[lt] + v[gt] <= v[trigger])),
            ),
            loc("TX_SM", Kind::Normal, Some(Box::new(move |v| v[t] <= hop))),
        ],
        edges: vec![
            edge(
                6,
                5,
                Some(Box::new(move |v| v[t] >= hop)),
                Sync::Send(sm_out),
                Some(Box::new(move |v| v[trigger] = trigger_next(v[lt], d))),
            ),
            edge(
                5,
                6,
                Some(Box::new(move |v| v[lt] + v[gt] >= v[trigger])),
                Sync::None,
                Some(Box::new(move |v| {
                    v[t] = 0;
                    v[network_ref_time] = v[lt];
                })),
            ),
            edge(
                4,
                5,
                Some(Box::new(move |v| v[t] >= hop)),
                Sync::Send(dmc_out),
                Some(Box::new(move |v| v[trigger] = trigger_next(v[lt], d))),
            ),
            edge(
                3,
                4,
                None,
                Sync::None,
                Some(Box::new(move |v| {
                    v[delay] =
                        ((((v[t4] - v[t1] - LOCAL_DELAY_SWITCH - v[t3] - LOCAL_DELAY_MASTER
                            + v[t2])
                            / 2)
                            + LOCAL_DELAY_SWITCH)
                            / 10)
                            * 10;
                    v[t] = 0;
                })),
            ),
            edge(
                0,
                1,
                None,
                Sync::None,
                Some(Box::new(move |v| {
                    v[t1] = v[lt];
                    v[t] = 0;
                })),
            ),
            edge(
                1,
                2,
                Some(Box::new(move |v| v[t] >= hop)),
                Sync::Send(dmt_out),
                None,
            ),
            edge(
                2,
                3,
                None,
                Sync::Recv(dmr_in),
                Some(Box::new(move |v| v[t4] = v[lt])),
            ),
        ],
    }
}
