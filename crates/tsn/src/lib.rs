//! TSN integration for EtherCAT.
//!
//! [`uppaal`] rebuilds the three UPPAAL models of Bujosa Mateu et al., "Clock Synchronization
//! in Integrated TSN-EtherCAT Networks" (M1: no TSN; M2: a TSN bridge whose gate is open 30 of
//! every 100 units, the master not synchronized to it; M3: the same bridge with the master
//! synchronized by gPTP), and [`ta`] explores every behaviour their nondeterminism allows.
//! [`analyze`] reports what the paper's queries ask — the largest measured delays, the range of
//! every pairwise clock difference once the slaves are synchronized, whether the bridge's gate
//! ever blocks a DC frame — and [`paper`] puts Tables I and II of the paper beside ours.
//!
//! gPTP (IEEE 802.1AS) is here as a sans-IO time-aware system ([`gptp`], its messages in
//! [`gptp_msg`]), simulated by one message exchange ([`gptp_net`]) that both the line of
//! [`gptp_sim`] and the integrated network drive; [`qbv`] holds the bridge's gate schedules.
//!
//! With the feature `network` (off by default, so that the models build on few dependencies),
//! `network` builds the paper's integrated network from the simulator's parts as the
//! EtherCAT master's transport: the master's PTP hardware clock disciplined by gPTP, the
//! time-aware bridge with its 802.1Qbv gates, store and forward and cross traffic, and the
//! virtual segment (the lab runs and measures its variants).
//!
//! A gPTP message round trip: a Pdelay_Resp encoded into a buffer and decoded back.
//!
//! ```
//! use ecsync_tsn::gptp_msg::{
//!     DecodeError, HEADER_LEN, Header, Message, PortIdentity, Timestamp, decode, message_type,
//! };
//!
//! let requester = PortIdentity { clock_identity: [0, 1, 2, 0xff, 0xfe, 3, 4, 5], port_number: 1 };
//! let msg = Message::PdelayResp {
//!     // t2: when the request arrived, ns since the PTP epoch.
//!     request_receipt: Timestamp::from_ns(1_700_000_000_123_456_789),
//!     requesting: requester,
//! };
//! let header = Header { sequence_id: 42, ..Header::default() };
//! let mut buf = [0u8; 64];
//! let n = msg.encode(&header, &mut buf).unwrap();
//! assert_eq!(n, HEADER_LEN + 20);
//! assert_eq!(msg.message_type(), message_type::PDELAY_RESP);
//!
//! let (h, m) = decode(&buf[..n]).unwrap();
//! assert_eq!((h.sequence_id, m), (42, msg));
//! let Message::PdelayResp { request_receipt, .. } = m else { unreachable!() };
//! assert_eq!(request_receipt.to_ns(), 1_700_000_000_123_456_789);
//! assert_eq!(decode(&buf[..n - 1]), Err(DecodeError::Truncated));
//! ```
//!
//! The UPPAAL models are explored exhaustively (M1 takes about a second): the worst cases are the
//! bounds the paper's queries state.
//!
//! ```no_run
//! use ecsync_tsn::{Model, Pair, analyze};
//!
//! let r = analyze(Model::M1);
//! assert_eq!(r.delay_max, [40, 60], "A[] Delay[0] <= 40, A[] Delay[1] <= 60");
//! let s1_s2 = r.diff.iter().find(|d| d.0 == Pair::S1S2).unwrap().1;
//! assert_eq!((s1_s2.max_a_minus_b, s1_s2.max_b_minus_a), (30, 40));
//! assert!(r.blocked.is_none(), "no TSN bridge in M1");
//! ```

#![warn(missing_docs)]

pub mod gptp;
pub mod gptp_msg;
pub mod gptp_net;
pub mod gptp_sim;
#[cfg(feature = "network")]
pub mod network;
pub mod qbv;
pub mod ta;
pub mod uppaal;

pub use uppaal::Model;

/// A pair of nodes whose clock difference the paper's Table II reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Pair {
    /// Master and slave S1.
    MasterS1,
    /// Master and slave S2.
    MasterS2,
    /// Slave S1 and slave S2.
    S1S2,
}

impl Pair {
    /// The three pairs, in the paper's column order.
    pub const ALL: [Pair; 3] = [Pair::MasterS1, Pair::MasterS2, Pair::S1S2];

    /// The paper's column title.
    pub fn title(self) -> &'static str {
        match self {
            Pair::MasterS1 => "M-S1 clock diff",
            Pair::MasterS2 => "M-S2 clock diff",
            Pair::S1S2 => "S1-S2 clock diff",
        }
    }
}

/// The extremes of `a - b` over every reachable state in which the last slave has received an
/// SM (`Num_period > 0`, as the paper's queries restrict).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct DiffRange {
    /// Largest `a - b` (the bound `A[] Num_period > 0 imply a - b <= c` is tight at this c).
    pub max_a_minus_b: i32,
    /// Largest `b - a`.
    pub max_b_minus_a: i32,
}

impl DiffRange {
    /// The width of the range of `a - b`: what the paper's Table II compares.
    pub fn span(&self) -> i32 {
        self.max_a_minus_b + self.max_b_minus_a
    }
}

/// What exploring one model found.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ModelReport {
    /// Which model.
    pub model: Model,
    /// Reachable states (integer time).
    pub states: usize,
    /// Largest `Delay[0]` (S1) and `Delay[1]` (S2) the master computes, in any behaviour.
    pub delay_max: [i32; 2],
    /// Smallest of each, once computed (nonzero).
    pub delay_min: [i32; 2],
    /// Per pair, the range of the clock difference.
    pub diff: Vec<(Pair, DiffRange)>,
    /// The bridge's gate held back a DC frame in some behaviour (SM, DM_T, DM_C), per kind.
    pub blocked: Option<GateBlocks>,
    /// Some behaviour reaches a state without any successor (every run of these models ends
    /// so, by design: the clocks stop after the second SM period).
    pub deadlock: bool,
}

/// Which DC frames the gate can hold back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct GateBlocks {
    /// An SM frame waited at the closed gate.
    pub sm: bool,
    /// A DM_T frame waited.
    pub dm_t: bool,
    /// A DM_C frame waited.
    pub dm_c: bool,
}

impl GateBlocks {
    /// Any DC frame.
    pub fn any(&self) -> bool {
        self.sm || self.dm_t || self.dm_c
    }
}

/// Explores `model` exhaustively.
pub fn analyze(model: Model) -> ModelReport {
    let (net, p) = uppaal::build(model);
    let pairs = [
        (Pair::MasterS1, p.master, p.s1),
        (Pair::MasterS2, p.master, p.s2),
        (Pair::S1S2, p.s1, p.s2),
    ];
    let mut diff = [(i32::MIN, i32::MIN); 3];
    let mut delay_max = [i32::MIN; 2];
    let mut delay_min = [i32::MAX; 2];
    let mut blocks = GateBlocks {
        sm: false,
        dm_t: false,
        dm_c: false,
    };
    let ex = net.explore(|s| {
        let v = &s.vars;
        for (i, &d) in p.delay.iter().enumerate() {
            delay_max[i] = delay_max[i].max(v[d]);
            if v[d] != 0 {
                delay_min[i] = delay_min[i].min(v[d]);
            }
        }
        if v[p.num_period] > 0 {
            for (k, &(_, a, b)) in pairs.iter().enumerate() {
                diff[k].0 = diff[k].0.max(v[a] - v[b]);
                diff[k].1 = diff[k].1.max(v[b] - v[a]);
            }
        }
        if let Some((n0, [sm, dmt, dmc])) = p.gate {
            let l = s.loc[n0];
            blocks.sm |= l == sm;
            blocks.dm_t |= l == dmt;
            blocks.dm_c |= l == dmc;
        }
    });
    ModelReport {
        model,
        states: ex.states,
        delay_max,
        delay_min,
        diff: pairs
            .iter()
            .zip(diff)
            .map(|(&(pair, _, _), (ab, ba))| {
                (
                    pair,
                    DiffRange {
                        max_a_minus_b: ab,
                        max_b_minus_a: ba,
                    },
                )
            })
            .collect(),
        blocked: p.gate.map(|_| blocks),
        deadlock: ex.deadlock,
    }
}

pub mod paper;
