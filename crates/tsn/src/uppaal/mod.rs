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

use crate::ta::Network;

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
