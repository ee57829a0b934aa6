//! Propagation delays from latched port receive times, and the crystals' rates.

use super::config::BringupConfig;
use crate::MasterError;
use crate::io::{Link, Pdu};
use crate::network::{DcCapability, Phase, SlaveInfo};
use ecsync_dc::fit::LineFit;
use ecsync_dc::{SlavePorts, TreeNode, build_tree, propagation_delays};
use ecsync_wire::register::{self as reg};
use ecsync_wire::{Command, DatagramAddress, dc_time};

/// What the last latch of [`measure_delays`] leaves for the offsets.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Latch {
    /// Master time right before the last latch frame was sent, ns.
    pub(super) sent_ns: u64,
    /// Each slave's processing unit receive time (0x0918) of the last latch, ns (0 where the
    /// slave has no system time).
    pub(super) pu_stamps_ns: Vec<u64>,
    /// With [`BringupConfig::master_is_reference`]: the master's delay to the reference, ns
    /// (mean over the rounds).
    pub(super) master_delay_ns: Option<f64>,
    /// Its spread (max - min) over the rounds, ns.
    pub(super) master_delay_spread_ns: Option<f64>,
}

/// [`Phase::Delays`]: propagation delays, averaged over latch rounds with the send instant
/// dithered across the receive stamps' 40 ns resolution. Records each slave's parent, entry
/// port and delay; returns the last latch for the offsets.
///
/// Step by step: the latch rounds (`latch_round`), spread over the latch window so that each
/// slave's clock rate against the master can be measured from its first and last port 0
/// stamps (`correct_clock_rates`); each round's tree and delays, averaged (`average_delays`).
pub(super) async fn measure_delays(
    link: &Link,
    cfg: &BringupConfig,
    slaves: &mut [SlaveInfo],
    reference: usize,
) -> Result<Latch, MasterError> {
    let n = slaves.len();
    let rounds = cfg.latch_rounds.max(1);
    let gap_ns = (cfg.latch_window_ns / u64::from(rounds)).max(cfg.latch_min_gap_ns);
    let mut all_ports: Vec<Vec<SlavePorts>> = Vec::with_capacity(rounds as usize);
    let mut sent_at: Vec<u64> = Vec::with_capacity(rounds as usize);
    let mut round_trips: Vec<f64> = Vec::with_capacity(rounds as usize);
    let mut last_pu = vec![0u64; n];
    for round in 0..rounds {
        let dither = u64::from(round) * LATCH_DITHER_NS / u64::from(rounds);
        let t = link.now().as_ns() + gap_ns + dither;
        link.sleep_until(t).await;
        let last = round + 1 == rounds;
        let r = latch_round(link, cfg, slaves, last.then_some(&mut last_pu)).await?;
        all_ports.push(r.ports);
        sent_at.push(r.sent_ns);
        round_trips.push(r.round_trip_ns);
    }
    correct_clock_rates(&mut all_ports, &sent_at);
    let d = average_delays(cfg, &all_ports, &round_trips, reference)?;
    let (master_delay_ns, master_delay_spread_ns) =
        if cfg.master_is_reference && d.md_min.is_finite() {
            (
                Some(d.md_sum / f64::from(rounds)),
                Some(d.md_max - d.md_min),
            )
        } else {
            (None, None)
        };
    for (i, s) in slaves.iter_mut().enumerate() {
        s.parent = d.tree[i].parent;
        s.entry_port = d.tree[i].entry_port;
        // Receive-time-only slaves get theirs too (a master's picture of the segment), though
        // nothing is written to them.
        if s.dc != DcCapability::None && d.delays[i].is_some() {
            s.delay_ns = Some(d.sums[i] / f64::from(rounds));
            s.delay_spread_ns = Some(d.maxs[i] - d.mins[i]);
        }
    }
    Ok(Latch {
        sent_ns: sent_at.last().copied().unwrap_or(0),
        pu_stamps_ns: last_pu,
        master_delay_ns,
        master_delay_spread_ns,
    })
}

/// One latch round as read back.
struct LatchRound {
    /// Every slave's ports and receive times.
    ports: Vec<SlavePorts>,
    /// The latch frame's send timestamp, master time, ns.
    sent_ns: u64,
    /// Its round trip, ns.
    round_trip_ns: f64,
}

/// Latches every port's receive time by a BWR of 0x0900 and reads them back (one FPRD of the
/// four receive times per slave that has them, batched into as few frames as fit); with
/// `pu_stamps`, also each system-time slave's processing unit stamp (0x0918) into it (the last
/// round: for the offsets).
async fn latch_round(
    link: &Link,
    cfg: &BringupConfig,
    slaves: &[SlaveInfo],
    mut pu_stamps: Option<&mut Vec<u64>>,
) -> Result<LatchRound, MasterError> {
    let n = slaves.len();
    let r = link
        .pdu(
            Command::Bwr,
            DatagramAddress::position(0, reg::DC_RECEIVE_TIME_PORT0),
            vec![0; 4],
            "latch receive times",
        )
        .await?;
    let latch_sent = link.last_sent().as_ns();
    let round_trip_ns = link.last_received().as_ns().wrapping_sub(latch_sent) as i64 as f64;
    let expected = slaves.iter().filter(|s| s.dc != DcCapability::None).count() as u16;
    if r.wkc != expected {
        return Err(MasterError::WorkingCounter {
            command: Command::Bwr,
            what: "latch receive times",
            expected,
            got: r.wkc,
        });
    }
    let mut ports = vec![SlavePorts::default(); n];
    let mut reads = Vec::new();
    let mut owners = Vec::new();
    for (i, s) in slaves.iter().enumerate() {
        ports[i].open = s.open_ports;
        if let Some(e) = cfg
            .esi
            .iter()
            .find(|e| e.vendor_id == s.vendor_id && e.product_code == s.product_code)
        {
            ports[i].forwarding_ns = e.forwarding_ns;
            ports[i].processing_ns = e.processing_ns;
        }
        if s.dc == DcCapability::None {
            continue;
        }
        reads.push(Pdu::new(
            Command::Fprd,
            DatagramAddress::configured(s.station, reg::DC_RECEIVE_TIME_PORT0),
            vec![0; 16],
        ));
        owners.push((i, false));
        if pu_stamps.is_some() && s.dc == DcCapability::SystemTime {
            reads.push(Pdu::new(
                Command::Fprd,
                DatagramAddress::configured(s.station, reg::DC_RECEIVE_TIME_PU),
                vec![0; 8],
            ));
            owners.push((i, true));
        }
    }
    let (replies, _) = link.pdus(&reads, "read receive times").await?;
    for (r, &(i, is_pu)) in replies.iter().zip(&owners) {
        if r.wkc != 1 {
            return Err(MasterError::WorkingCounter {
                command: Command::Fprd,
                what: "read receive times",
                expected: 1,
                got: r.wkc,
            }
            .at(Phase::Delays, slaves[i].id()));
        }
        let t = &r.data;
        if is_pu {
            if let Some(pu) = pu_stamps.as_deref_mut() {
                pu[i] = u64::from_le_bytes(t[..8].try_into().unwrap_or([0; 8]));
            }
        } else {
            ports[i].times = Some(core::array::from_fn(|p| {
                u32::from_le_bytes([t[4 * p], t[4 * p + 1], t[4 * p + 2], t[4 * p + 3]])
            }));
        }
    }
    Ok(LatchRound {
        ports,
        sent_ns: latch_sent,
        round_trip_ns,
    })
}

/// Each slave's clock rate from the first and last latch (local time elapsed at its entry
/// port over master time elapsed, `sent_at`), set on every round's ports where plausible
/// (anything else is a misread).
fn correct_clock_rates(all_ports: &mut [Vec<SlavePorts>], sent_at: &[u64]) {
    let master_span = sent_at
        .last()
        .copied()
        .unwrap_or(0)
        .saturating_sub(sent_at[0]) as f64;
    if all_ports.len() <= 1 || master_span <= 0.0 {
        return;
    }
    for i in 0..all_ports[0].len() {
        let (Some(a), Some(b)) = (
            all_ports[0][i].times,
            all_ports[all_ports.len() - 1][i].times,
        ) else {
            continue;
        };
        let e = ecsync_dc::topology::entry_port(&all_ports[0][i]).unwrap_or(0);
        let local = f64::from(dc_time::diff_u32(b[usize::from(e)], a[usize::from(e)]));
        let rate = local / master_span;
        if (rate - 1.0).abs() < PLAUSIBLE_RATE_ERROR {
            for round in all_ports.iter_mut() {
                round[i].clock_rate = rate;
            }
        }
    }
}

/// The rounds' delays summed, with their extremes, and the master's delay to the reference
/// (with [`BringupConfig::master_is_reference`]).
struct DelaySums {
    /// The last round's tree and delays (every round finds the same tree).
    tree: Vec<TreeNode>,
    delays: Vec<Option<f64>>,
    sums: Vec<f64>,
    mins: Vec<f64>,
    maxs: Vec<f64>,
    md_sum: f64,
    md_min: f64,
    md_max: f64,
}

/// Each round's tree and propagation delays from `reference`, summed over the rounds.
fn average_delays(
    cfg: &BringupConfig,
    all_ports: &[Vec<SlavePorts>],
    round_trips: &[f64],
    reference: usize,
) -> Result<DelaySums, MasterError> {
    let n = all_ports.first().map_or(0, Vec::len);
    let mut d = DelaySums {
        tree: vec![TreeNode::default(); n],
        delays: vec![None; n],
        sums: vec![0.0f64; n],
        mins: vec![f64::INFINITY; n],
        maxs: vec![f64::NEG_INFINITY; n],
        md_sum: 0.0,
        md_min: f64::INFINITY,
        md_max: f64::NEG_INFINITY,
    };
    for (round, ports) in all_ports.iter().enumerate() {
        build_tree(ports, &mut d.tree)?;
        propagation_delays(ports, &d.tree, reference, &mut d.delays)?;
        if cfg.master_is_reference {
            // Master -> first slave, then on to the reference (its delay relative to the
            // first slave is minus the first slave's delay relative to it).
            if let (Some(d0), Some(first)) = (
                ecsync_dc::master_delay_ns(round_trips[round], &ports[0], d.tree[0].entry_port),
                d.delays[0],
            ) {
                let m = d0 - first;
                d.md_sum += m;
                d.md_min = d.md_min.min(m);
                d.md_max = d.md_max.max(m);
            }
        }
        for (i, v) in d.delays.iter().enumerate() {
            if let Some(v) = v {
                d.sums[i] += v;
                d.mins[i] = d.mins[i].min(*v);
                d.maxs[i] = d.maxs[i].max(*v);
            }
        }
    }
    Ok(d)
}

/// Latches of [`measure_clock_rates`]: one every this long, ns (at most; fewer over a short
/// window). Well under the 2.1 s in which a 32-bit receive time's difference stays unambiguous,
/// and many points for the fit.
pub(super) const RATE_LATCH_STEP_NS: u64 = 20_000_000;

/// Least-squares slope of `y` on `x` (`None` with fewer than two distinct `x`).
fn slope(x: &[f64], y: &[f64]) -> Option<f64> {
    LineFit::of(x.iter().copied().zip(y.iter().copied())).slope()
}

/// Slope of the floor of `y` on `x`: where `y` is a clock read at instants `x` stamped late by a
/// delay that is never less than some least value but often more (a master's send stamps taken
/// before the kernel and the wire, on a loaded host up to milliseconds more), the points near
/// the least delay carry the rate, the others only their extra delay. Fitted by least squares,
/// then again on the quarter of the points furthest below the line, three times.
fn floor_slope(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    let mut keep: Vec<usize> = (0..n).collect();
    let mut b = slope(x, y)?;
    for _ in 0..3 {
        let xs: Vec<f64> = keep.iter().map(|&k| x[k]).collect();
        let ys: Vec<f64> = keep.iter().map(|&k| y[k]).collect();
        b = slope(&xs, &ys)?;
        let mut by_residual: Vec<(f64, usize)> = (0..n).map(|k| (y[k] - b * x[k], k)).collect();
        by_residual.sort_by(|a, c| a.0.total_cmp(&c.0));
        // Latency makes y larger: the floor is the smallest residuals.
        keep = by_residual
            .iter()
            .take((n / 4).max(2))
            .map(|&(_, k)| k)
            .collect();
    }
    let xs: Vec<f64> = keep.iter().map(|&k| x[k]).collect();
    let ys: Vec<f64> = keep.iter().map(|&k| y[k]).collect();
    slope(&xs, &ys).or(Some(b))
}

/// Every slave's crystal against the reference's: port receive times (0x0900, local time,
/// uncorrected: the drift correction is reset first by writing 0x0930) latched every
/// `RATE_LATCH_STEP_NS` over `window_ns` of master time; each slave's entry port stamps fitted
/// on the reference's (least squares, so the 40 ns stamp resolution averages out over the many
/// latches). Every latch frame reaches every slave a fixed time after the reference, so the
/// ratio is the crystals' alone, whatever the master's send jitter. Records
/// [`SlaveInfo::ppm_vs_reference`]; returns the reference's crystal against the master's clock,
/// fitted on the master's send stamps (as good as they are).
pub async fn measure_clock_rates(
    link: &Link,
    slaves: &mut [SlaveInfo],
    reference: usize,
    window_ns: u64,
) -> Result<Option<f64>, MasterError> {
    link.bwr(
        reg::DC_SPEED_COUNTER_START,
        &0x1000u16.to_le_bytes(),
        "reset the drift correction",
    )
    .await?;
    let n = slaves.len();
    let latches = (window_ns / RATE_LATCH_STEP_NS).clamp(1, 10_000) + 1;
    let step_ns = window_ns / (latches - 1);
    let expected = slaves.iter().filter(|s| s.dc != DcCapability::None).count() as u16;
    // Per slave: the entry port's stamps, unwrapped from 32 bits by adding each latch's
    // difference to the one before, ns since the first latch.
    let mut local: Vec<Vec<f64>> = vec![Vec::with_capacity(latches as usize); n];
    let mut last: Vec<Option<u32>> = vec![None; n];
    let mut master: Vec<f64> = Vec::with_capacity(latches as usize);
    let start = link.now().as_ns();
    for k in 0..latches {
        link.sleep_until(start + k * step_ns).await;
        let r = link
            .pdu(
                Command::Bwr,
                DatagramAddress::position(0, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 4],
                "latch receive times",
            )
            .await?;
        let sent = link.last_sent().as_ns();
        if r.wkc != expected {
            return Err(MasterError::WorkingCounter {
                command: Command::Bwr,
                what: "latch receive times",
                expected,
                got: r.wkc,
            });
        }
        let owners: Vec<usize> = (0..n)
            .filter(|&i| slaves[i].dc != DcCapability::None)
            .collect();
        let reads: Vec<Pdu> = owners
            .iter()
            .map(|&i| {
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::configured(slaves[i].station, reg::DC_RECEIVE_TIME_PORT0),
                    vec![0; 16],
                )
            })
            .collect();
        let (replies, _) = link.pdus(&reads, "read receive times").await?;
        for (r, &i) in replies.iter().zip(&owners) {
            let e = 4 * usize::from(slaves[i].entry_port.min(3));
            let (true, Some(b)) = (r.wkc == 1, r.data.get(e..e + 4)) else {
                return Err(MasterError::WorkingCounter {
                    command: Command::Fprd,
                    what: "read receive times",
                    expected: 1,
                    got: r.wkc,
                }
                .at(Phase::Delays, slaves[i].id()));
            };
            let t = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            let prev = local[i].last().copied().unwrap_or(0.0);
            let d = last[i].map_or(0, |l| dc_time::diff_u32(t, l));
            local[i].push(prev + f64::from(d));
            last[i] = Some(t);
        }
        master.push(sent.wrapping_sub(start) as f64);
    }
    let reference_local = local[reference].clone();
    for (i, s) in slaves.iter_mut().enumerate() {
        s.ppm_vs_reference = slope(&reference_local, &local[i])
            .filter(|r| (r - 1.0).abs() < PLAUSIBLE_RATE_ERROR)
            .map(|r| (r - 1.0) * 1e6);
    }
    Ok(floor_slope(&master, &reference_local)
        .filter(|r| (r - 1.0).abs() < PLAUSIBLE_RATE_ERROR)
        .map(|r| (r - 1.0) * 1e6))
}

/// The delay rounds dither their send instant across this span, ns: the receive time stamps'
/// resolution, so that the mean over the rounds resolves below it.
const LATCH_DITHER_NS: u64 = 40;

/// A clock rate (a slave's local time over master time) further than this from 1 is a
/// misread, not a crystal (crystals are within 100 ppm).
const PLAUSIBLE_RATE_ERROR: f64 = 1e-3;
