//! M3's gPTP: the master as a time-aware end station and the bridge as grandmaster.

use super::builder::*;
use crate::ta::{Kind, Process, Sync};

/// `Master_gPTP(...)` (M3): the master as a gPTP end station: answers the bridge's delay
/// measurement, then sets its local time from every gPTP SM.
#[allow(clippy::too_many_arguments)]
pub(super) fn master_gptp(
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

pub(super) struct GptpBridgeBinding {
    pub(super) sm_out: usize,
    pub(super) lt: usize,
    pub(super) dmt_out: usize,
    pub(super) dmr_in: usize,
    pub(super) dmc_out: usize,
    pub(super) t1: usize,
    pub(super) t4: usize,
    pub(super) gt: usize,
    pub(super) t2: usize,
    pub(super) t3: usize,
    pub(super) delay: usize,
    pub(super) network_ref_time: usize,
}

/// `Network_gPTP(...)` (M3): the bridge as grandmaster: measures the master's delay at once,
/// then sends its time every period (broadcast).
pub(super) fn network_gptp(b: &mut Builder, name: &'static str, g: GptpBridgeBinding) -> Process {
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
