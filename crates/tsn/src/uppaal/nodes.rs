//! The models' processes: oscillators and clocks, the slaves, the master, the TSN bridge.

use super::builder::*;
use crate::ta::{Kind, Process, Sync};

/// `Oscillator(TIC, t)`: CHOOSE (committed) picks 9 or 10, RUN ticks every period.
/// `exact_guard`: M2 writes the tick guard `t == TIC_period`, M1 and M3 `t >= TIC_period`.
pub(super) fn oscillator(
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
pub(super) fn clock(
    name: &'static str,
    tic: usize,
    lt: usize,
    num_period: usize,
    stop_eq: bool,
) -> Process {
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

pub(super) const HOP: i32 = LOCAL_DELAY_SLAVE + TRANSMISSION_DELAY;

/// Channels a slave forwards between.
pub(super) struct SlaveChans {
    pub(super) sm_in: usize,
    pub(super) sm_out: usize,
    pub(super) dmt_in: usize,
    pub(super) dmr_in: usize,
    pub(super) dmc_in: usize,
    pub(super) dmt_out: usize,
    pub(super) dmr_out: usize,
    pub(super) dmc_out: usize,
}

/// `Slave(...)`: forwards DM_T, DM_R, DM_C and SM with a 25-unit hop, latching T2 (DM_T in),
/// T3 (DM_R in) and setting its time from SM.
#[allow(clippy::too_many_arguments)]
pub(super) fn slave(
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
pub(super) fn last_slave(
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
pub(super) struct MasterBinding {
    pub(super) sm_out: usize,
    pub(super) lt: usize,
    pub(super) dmt_out: usize,
    pub(super) dmr_in: usize,
    pub(super) dmc_out: usize,
    pub(super) t1: usize,
    pub(super) t4: usize,
    pub(super) mref: usize,
    /// Its oscillator's clock: `Local_time + gt` interpolates the local time.
    pub(super) gt: usize,
    pub(super) t2: [usize; 2],
    pub(super) t3: [usize; 2],
    pub(super) delay: [usize; 2],
    /// M3: it waits for the first gPTP SM (broadcast channel).
    pub(super) gptp_sm_in: Option<usize>,
}

/// `Master(...)`: DM_T at once (M1, M2) or at its first trigger after gPTP sync (M3), DM_C one
/// period later with the delays computed, then SM every period from `Trigger`.
pub(super) fn master(b: &mut Builder, name: &'static str, m: MasterBinding) -> Process {
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
pub(super) fn bridge(
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
