//! The DC bring-up: scan, addressing, SII identity, topology and propagation delays, system time
//! offsets, static drift compensation, lock detection, process data mapping, SYNC0 and the
//! state machine up to OP — the sequence of the datasheet (section I, 9.1.3.6) as SOEM and IgH
//! run it, with delays averaged over several latches.
//!
//! [`bringup`] is the sequence of [`Phase`]s, one function each; a phase takes what the phases
//! before it learned (typed results such as the slave count, the reference clock, the last
//! latch) and returns its own. An error names the phase it happened in and, where the failing
//! exchange concerned one slave, that slave ([`MasterError::Bringup`]). Every timeout is a
//! field of [`BringupTimeouts`].

use crate::MasterError;
use crate::io::{Event, Link};
use ecsync_wire::AlState;
use ecsync_wire::register as reg;

mod clocks;
mod config;
mod delays;
mod discovery;
mod mapping;
mod operational;

use clocks::{CycleGrid, DcGroup, static_drift, wait_for_lock, write_offsets};
use delays::measure_delays;
use discovery::{assign_station_addresses, identify, probe_dc, reset, scan};
use mapping::{map_process_image, request_all};
use operational::{CyclicFrame, await_first_pulses, enter_op, monitor, start_sync0};

pub use crate::network::*;
pub(crate) use config::SyncUnitPlan;
pub use config::{BringupConfig, BringupTimeouts, EsiTiming, Oversampled, Stage};
pub use delays::measure_clock_rates;
use mapping::configure_sync_modes;
pub(crate) use mapping::{configure_mailboxes, configure_process_data, configure_sync_mode};
pub use operational::{request_state, request_state_with};

/// Runs the bring-up on a link: the phases in order, each fed what the ones before learned,
/// up to [`BringupConfig::until`].
pub async fn bringup(link: Link, cfg: BringupConfig) -> Result<Network, MasterError> {
    cfg.validate()?;
    // Progress events keep the steps `ecsync run` has always printed: reset and addressing
    // belong to "scan", the DC probe to "identify", lock, PRE-OP and the mapping to "drift".
    link.event(Event::Phase(Phase::Scan));
    let scanned = scan(&link).await.map_err(|e| e.during(Phase::Scan))?;
    reset(&link).await.map_err(|e| e.during(Phase::Reset))?;
    let addressed = assign_station_addresses(&link, scanned)
        .await
        .map_err(|e| e.during(Phase::StationAddresses))?;
    let ring_end = addressed.slaves.last().copied().filter(|_| cfg.ring);
    if let Some(last) = ring_end {
        ring_port(&link, last, true)
            .await
            .map_err(|e| e.during(Phase::StationAddresses))?;
    }

    link.event(Event::Phase(Phase::Identify));
    let mut slaves = identify(&link, &addressed, &cfg)
        .await
        .map_err(|e| e.during(Phase::Identify))?;
    let reference = probe_dc(&link, &mut slaves)
        .await
        .map_err(|e| e.during(Phase::DcProbe))?;

    link.event(Event::Phase(Phase::Delays));
    let latch = measure_delays(&link, &cfg, &mut slaves, reference.index)
        .await
        .map_err(|e| e.during(Phase::Delays))?;
    let mut net = Network {
        slaves,
        reference: reference.index as u16,
        lock: LockReport::not_run(),
        sync0: None,
        pdi_len: 0,
        lrw: Vec::new(),
        expected_lrw_wkc: 0,
        done_ns: 0,
        master_delay_ns: latch.master_delay_ns,
        master_delay_spread_ns: latch.master_delay_spread_ns,
        reference_ppm_vs_master: None,
        reference_reading: None,
    };
    if cfg.rate_window_ns > 0 {
        net.reference_ppm_vs_master =
            measure_clock_rates(&link, &mut net.slaves, reference.index, cfg.rate_window_ns)
                .await
                .map_err(|e| e.during(Phase::Delays))?;
    }
    if cfg.until == Stage::Delays {
        return Ok(net.done_at(&link));
    }

    link.event(Event::Phase(Phase::Offsets));
    write_offsets(&link, &mut net.slaves, &latch)
        .await
        .map_err(|e| e.during(Phase::Offsets))?;

    link.event(Event::Phase(Phase::StaticDrift));
    let dc = DcGroup::of(&net.slaves, reference.id);
    let drift = static_drift(&link, &cfg, &dc)
        .await
        .map_err(|e| e.during(Phase::StaticDrift))?;
    let locked = wait_for_lock(&link, &cfg, &dc, drift)
        .await
        .map_err(|e| e.during(Phase::Lock))?;
    net.lock = locked.report;
    let mut grid = locked.grid;
    let image = map_process_image(&mut net.slaves);
    net.pdi_len = image.pdi_len;
    net.lrw = image.lrw;
    if cfg.until == Stage::Lock {
        return Ok(net.done_at(&link));
    }

    // From the lock on, every cycle's frames distribute the reference's time, as the cyclic
    // frames will: the configuration below takes seconds in a large network.
    link.keep_time(Some((dc.frmw(), u64::from(cfg.cycle_ns))));
    let to_op = configure_and_start(&link, &cfg, &mut net, &dc, &mut grid).await;
    link.keep_time(None);
    to_op?;
    if let Some(last) = ring_end {
        ring_port(&link, last, false)
            .await
            .map_err(|e| e.during(Phase::Monitor))?;
    }
    Ok(net.done_at(&link))
}

/// The ring's last slave's port 1 loop ([`BringupConfig::ring`]): closed (DL control 0x0101
/// bits 2-3 = 11) or back to auto (00). (A bring-up that stops before OP leaves it closed.)
async fn ring_port(link: &Link, last: SlaveId, close: bool) -> Result<(), MasterError> {
    let at = |e: MasterError| e.at(Phase::StationAddresses, last);
    let v = link
        .fprd(last.station, reg::DL_CONTROL + 1, 1, "read DL control")
        .await
        .map_err(at)?;
    let b = (v.first().copied().unwrap_or(0) & !0x0c) | if close { 0x0c } else { 0 };
    let what = if close {
        "close the ring port"
    } else {
        "open the ring port"
    };
    link.fpwr(last.station, reg::DL_CONTROL + 1, &[b], what)
        .await
        .map_err(at)?;
    Ok(())
}

/// PRE-OP, the mailboxes and sync mode, the process data, SYNC0, SAFE-OP and OP, then
/// [`BringupConfig::monitor_cycles`] cycles of monitoring.
async fn configure_and_start(
    link: &Link,
    cfg: &BringupConfig,
    net: &mut Network,
    dc: &DcGroup,
    grid: &mut CycleGrid,
) -> Result<(), MasterError> {
    configure_mailboxes(link, &net.slaves)
        .await
        .map_err(|e| e.during(Phase::PreOp))?;
    request_all(
        link,
        &net.slaves,
        AlState::PreOp,
        Phase::PreOp,
        &cfg.timeouts,
    )
    .await
    .map_err(|e| e.during(Phase::PreOp))?;
    configure_sync_modes(
        link,
        &net.slaves,
        cfg.cycle_ns,
        cfg.sync_error_limit,
        &cfg.oversampled,
    )
    .await
    .map_err(|e| e.during(Phase::PreOp))?;
    net.expected_lrw_wkc = configure_process_data(link, &net.slaves)
        .await
        .map_err(|e| e.during(Phase::ProcessData))?;

    link.event(Event::Phase(Phase::Sync0));
    let sync0 = start_sync0(link, cfg, &net.slaves, dc)
        .await
        .map_err(|e| e.during(Phase::Sync0))?;
    net.sync0 = sync0.map(|(s, _)| s);

    let cyclic = CyclicFrame::new(dc, &net.lrw, &net.slaves, cfg.cycle_ns);
    link.event(Event::Phase(Phase::SafeOp));
    request_all(
        link,
        &net.slaves,
        AlState::SafeOp,
        Phase::SafeOp,
        &cfg.timeouts,
    )
    .await
    .map_err(|e| e.during(Phase::SafeOp))?;
    if let Some((_, first_pulses_ns)) = sync0 {
        await_first_pulses(link, &cyclic, grid, first_pulses_ns)
            .await
            .map_err(|e| e.during(Phase::SafeOp))?;
    }
    link.event(Event::Phase(Phase::Op));
    enter_op(link, &cfg.timeouts, &net.slaves, &cyclic, grid)
        .await
        .map_err(|e| e.during(Phase::Op))?;

    link.event(Event::Phase(Phase::Monitor));
    let (max_abs, reading) = monitor(
        link,
        cfg,
        dc,
        &cyclic,
        net.pdi_len,
        net.expected_lrw_wkc,
        grid,
    )
    .await
    .map_err(|e| e.during(Phase::Monitor))?;
    net.lock.max_abs_092c_after_lock_ns = max_abs;
    net.lock.max_abs_092c_by_broadcast = !cyclic.per_slave;
    net.reference_reading = match reading {
        Some(r) => Some(r),
        // Nothing monitored: one FRMW more, for where the reference's time stands (lost, the
        // first cycle aims at the master's own grid, as it would without the reading).
        None => match link.pdus(&[dc.frmw()], "read the reference's time").await {
            Ok((r, reply)) => r
                .first()
                .and_then(|p| ReferenceReading::of(p, reply.sent.as_ns())),
            Err(_) => None,
        },
    };
    Ok(())
}

impl Network {
    /// The network as it stands when the bring-up returns.
    fn done_at(mut self, link: &Link) -> Network {
        self.done_ns = link.now().as_ns();
        self
    }
}

impl LockReport {
    /// The report of a bring-up that stopped before the static drift compensation.
    fn not_run() -> Self {
        LockReport {
            converged: false,
            time_to_lock_ns: None,
            drift_start_ns: 0,
            declared_ns: None,
            max_abs_092c_after_lock_ns: 0,
            max_abs_092c_by_broadcast: false,
            frmw_frames: 0,
        }
    }
}
