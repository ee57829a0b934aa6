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

use crate::ta::{Network, Process};

mod builder;
mod gptp;
mod nodes;

use builder::*;
use gptp::{GptpBridgeBinding, master_gptp, network_gptp};
use nodes::{MasterBinding, SlaveChans, bridge, clock, last_slave, master, oscillator, slave};

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

/// The model as a network, with the indices its queries read.
pub fn build(model: Model) -> (Network, Probes) {
    match model {
        Model::M1 => build_m1(),
        Model::M2 | Model::M3 => build_bridged(model),
    }
}

/// The variables and channels every model declares first, in the XML's order: per node (`N`:
/// the master, a bridge if any, the two slaves) a clock `t`, a tick channel and a local time;
/// the SM channels; the master's reference time and the period count; the delay measurement's
/// channels (DM_T and DM_C per hop, `H`), timestamps and delays.
struct Globals<const N: usize, const H: usize> {
    t: [usize; N],
    tic: [usize; N],
    lt: [usize; N],
    sm: [usize; 3],
    mref: usize,
    num_period: usize,
    dmt: [usize; H],
    dmr: [usize; 2],
    dmc: [usize; H],
    t1: usize,
    t2: [usize; 2],
    t3: [usize; 2],
    t4: usize,
    delay: [usize; 2],
}

impl<const N: usize, const H: usize> Globals<N, H> {
    /// Declares them in `b`.
    fn declare(b: &mut Builder) -> Self {
        let t: [usize; N] = std::array::from_fn(|i| b.clock(&format!("t[{i}]"), None));
        let tic = b.chans("TIC");
        let lt = b.ints("Local_time");
        let sm = b.chans("SM");
        let [mref] = b.ints::<1>("Master_ref_time");
        let num_period = b.int("Num_period");
        let dmt = b.chans("DM_T");
        let dmr = b.chans("DM_R");
        let dmc = b.chans("DM_C");
        let [t1] = b.ints::<1>("T1");
        let t2 = b.ints("T2");
        let t3 = b.ints("T3");
        let [t4] = b.ints::<1>("T4");
        let delay = b.ints("Delay");
        Globals {
            t,
            tic,
            lt,
            sm,
            mref,
            num_period,
            dmt,
            dmr,
            dmc,
            t1,
            t2,
            t3,
            t4,
            delay,
        }
    }

    /// The master's binding to them, as node `m` (its local time and clock); `gptp_sm_in`:
    /// M3's gPTP SM channel.
    fn master_binding(&self, m: usize, gptp_sm_in: Option<usize>) -> MasterBinding {
        MasterBinding {
            sm_out: self.sm[0],
            lt: self.lt[m],
            dmt_out: self.dmt[0],
            dmr_in: self.dmr[0],
            dmc_out: self.dmc[0],
            t1: self.t1,
            t4: self.t4,
            mref: self.mref,
            gt: self.t[m],
            t2: self.t2,
            t3: self.t3,
            delay: self.delay,
            gptp_sm_in,
        }
    }
}

/// M3's gPTP variables and channels, between the bridge (grandmaster) and the master.
#[derive(Clone, Copy)]
struct GptpVars {
    sm: usize,
    network_ref_time: usize,
    dmt: usize,
    dmr: usize,
    dmc: usize,
    t1: usize,
    t2: usize,
    t3: usize,
    t4: usize,
    delay: usize,
}

impl GptpVars {
    /// Declares them in `b`.
    fn declare(b: &mut Builder) -> Self {
        let sm = b.chan("SM_gPTP[0]", true);
        let network_ref_time = b.int("Network_ref_time");
        let dmt = b.chan("DM_T_gPTP[0]", false);
        let dmr = b.chan("DM_R_gPTP[0]", false);
        let dmc = b.chan("DM_C_gPTP[0]", false);
        let [t1] = b.ints::<1>("T1_gPTP");
        let [t2] = b.ints::<1>("T2_gPTP");
        let [t3] = b.ints::<1>("T3_gPTP");
        let [t4] = b.ints::<1>("T4_gPTP");
        let [delay] = b.ints::<1>("Delay_gPTP");
        GptpVars {
            sm,
            network_ref_time,
            dmt,
            dmr,
            dmc,
            t1,
            t2,
            t3,
            t4,
            delay,
        }
    }
}

/// M1: the master and the two slaves, each with its oscillator and clock, on one line.
fn build_m1() -> (Network, Probes) {
    let mut b = Builder::new();
    let g: Globals<3, 2> = Globals::declare(&mut b);
    let om0 = oscillator(&mut b, "OM0", g.tic[0], g.t[0], false);
    let cm0 = clock("CM0", g.tic[0], g.lt[0], g.num_period, false);
    let m0 = master(&mut b, "M0", g.master_binding(0, None));
    let mut procs = vec![om0, cm0, m0];
    procs.extend(slaves(&mut b, &g, 1, 0, false, false));
    let net = b.finish(procs);
    let probes = Probes {
        master: g.lt[0],
        s1: g.lt[1],
        s2: g.lt[2],
        bridge: None,
        delay: g.delay,
        num_period: g.num_period,
        gate: None,
    };
    (net, probes)
}

/// M2 and M3: the bridge (node 0) between the master (node 1) and the two slaves, and in M3
/// the gPTP processes of master and bridge; M2's oscillators tick exactly.
fn build_bridged(model: Model) -> (Network, Probes) {
    let mut b = Builder::new();
    let g: Globals<4, 3> = Globals::declare(&mut b);
    let exact = model == Model::M2;
    let mut procs = Vec::new();
    procs.push(oscillator(&mut b, "OM0", g.tic[1], g.t[1], exact));
    procs.push(clock("CM0", g.tic[1], g.lt[1], g.num_period, true));
    let gptp = (model == Model::M3).then(|| GptpVars::declare(&mut b));
    procs.push(master(
        &mut b,
        "M0",
        g.master_binding(1, gptp.map(|v| v.sm)),
    ));
    if let Some(v) = gptp {
        procs.push(master_gptp(
            &mut b,
            "Mg0",
            v.sm,
            g.lt[1],
            v.dmt,
            v.dmr,
            v.dmc,
            v.t2,
            v.t3,
            v.delay,
            v.network_ref_time,
        ));
    }
    procs.push(oscillator(&mut b, "ON0", g.tic[0], g.t[0], exact));
    procs.push(clock("CN0", g.tic[0], g.lt[0], g.num_period, true));
    let n0 = procs.len();
    procs.push(bridge(
        "N0", g.sm[0], g.sm[1], g.lt[0], g.dmt[0], g.dmc[0], g.dmt[1], g.dmc[1],
    ));
    if let Some(v) = gptp {
        procs.push(network_gptp(
            &mut b,
            "Ng00",
            GptpBridgeBinding {
                sm_out: v.sm,
                lt: g.lt[0],
                dmt_out: v.dmt,
                dmr_in: v.dmr,
                dmc_out: v.dmc,
                t1: v.t1,
                t4: v.t4,
                gt: g.t[0],
                t2: v.t2,
                t3: v.t3,
                delay: v.delay,
                network_ref_time: v.network_ref_time,
            },
        ));
    }
    procs.extend(slaves(&mut b, &g, 2, 1, exact, true));
    let net = b.finish(procs);
    let blocked = ["SM_bloqued", "DM_T_bloqued", "DM_C_bloqued"]
        .map(|l| net.location(n0, l).expect("bridge location"));
    let probes = Probes {
        master: g.lt[1],
        s1: g.lt[2],
        s2: g.lt[3],
        bridge: Some(g.lt[0]),
        delay: g.delay,
        num_period: g.num_period,
        gate: Some((n0, blocked)),
    };
    (net, probes)
}

/// The slaves S0 and S1, nodes `n` and `n + 1` behind hop `h` (their SM and DM_T/DM_C
/// channels are the hop's and the next), each with its oscillator and clock; `exact` and
/// `stop_eq` are the model's guards of the oscillators' ticks and the clocks' stop.
fn slaves<const N: usize, const H: usize>(
    b: &mut Builder,
    g: &Globals<N, H>,
    n: usize,
    h: usize,
    exact: bool,
    stop_eq: bool,
) -> [Process; 6] {
    let o0 = oscillator(b, "O0", g.tic[n], g.t[n], exact);
    let c0 = clock("C0", g.tic[n], g.lt[n], g.num_period, stop_eq);
    let s0 = slave(
        b,
        "S0",
        SlaveChans {
            sm_in: g.sm[h],
            sm_out: g.sm[h + 1],
            dmt_in: g.dmt[h],
            dmr_in: g.dmr[1],
            dmc_in: g.dmc[h],
            dmt_out: g.dmt[h + 1],
            dmr_out: g.dmr[0],
            dmc_out: g.dmc[h + 1],
        },
        g.lt[n],
        g.t2[0],
        g.t3[0],
        g.delay[0],
        g.mref,
    );
    let o1 = oscillator(b, "O1", g.tic[n + 1], g.t[n + 1], exact);
    let c1 = clock("C1", g.tic[n + 1], g.lt[n + 1], g.num_period, stop_eq);
    let s1 = last_slave(
        b,
        "S1",
        g.sm[h + 1],
        g.lt[n + 1],
        g.dmt[h + 1],
        g.dmr[1],
        g.dmc[h + 1],
        g.t2[1],
        g.t3[1],
        g.delay[1],
        g.mref,
        g.num_period,
    );
    [o0, c0, s0, o1, c1, s1]
}
