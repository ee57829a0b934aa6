//! Offsets, static drift compensation and the wait for lock.

use super::config::BringupConfig;
use super::delays::Latch;
use crate::MasterError;
use crate::io::{Event, Link, Pdu, PduReply};
use crate::network::{DcCapability, LockReport, Phase, SlaveId, SlaveInfo};
use ecsync_dc::LockDetector;
use ecsync_dc::time::SystemTime;
use ecsync_wire::register::{self as reg};
use ecsync_wire::{Command, DatagramAddress, dc_time};

/// [`Phase::Offsets`]: offsets from the last latch, written together with the delays in one
/// frame, then the loop filters reset (0x0934: time difference depth 0, speed counter depth
/// 12, as SOEM and ethercrab write; then 0x0930, whose write resets the filters). Records
/// each slave's offset.
pub(super) async fn write_offsets(
    link: &Link,
    slaves: &mut [SlaveInfo],
    latch: &Latch,
) -> Result<(), MasterError> {
    // The reference's system time takes the master's clock at the latch (SOEM, IgH, ethercrab);
    // a master that is the reference itself takes its clock at the frame's arrival there.
    let ref_time = latch.sent_ns.wrapping_add(
        latch
            .master_delay_ns
            .map_or(0, |d| ecsync_dc::offset::round_ns(d).max(0) as u64),
    );
    let mut writes = Vec::new();
    let mut owners = Vec::new();
    for (i, s) in slaves.iter_mut().enumerate() {
        if s.dc != DcCapability::SystemTime {
            continue;
        }
        let delay = ecsync_dc::offset::round_ns(s.delay_ns.unwrap_or(0.0)).max(0);
        let offset = ecsync_dc::system_time_offset(
            SystemTime::from_ns(ref_time),
            delay,
            latch.pu_stamps_ns[i],
        );
        s.offset = Some(offset);
        writes.push(Pdu::new(
            Command::Fpwr,
            DatagramAddress::configured(s.station, reg::DC_SYSTEM_TIME_DELAY),
            (delay as u32).to_le_bytes().to_vec(),
        ));
        writes.push(Pdu::new(
            Command::Fpwr,
            DatagramAddress::configured(s.station, reg::DC_SYSTEM_TIME_OFFSET),
            offset.to_le_bytes().to_vec(),
        ));
        owners.extend([s.id(), s.id()]);
    }
    let (r, _) = link.pdus(&writes, "write offsets and delays").await?;
    if let Some((bad, &id)) = r.iter().zip(&owners).find(|(p, _)| p.wkc != 1) {
        return Err(MasterError::WorkingCounter {
            command: Command::Fpwr,
            what: "write offsets and delays",
            expected: 1,
            got: bad.wkc,
        }
        .at(Phase::Offsets, id));
    }
    link.event(Event::OffsetsWritten);
    link.bwr(
        reg::DC_TIME_DIFF_FILTER_DEPTH,
        &[0x00, 0x0c],
        "filter depths",
    )
    .await?;
    link.bwr(
        reg::DC_SPEED_COUNTER_START,
        &0x1000u16.to_le_bytes(),
        "reset loop filters",
    )
    .await?;
    Ok(())
}

/// The DC slaves as the drift compensation and the cyclic frame address them: the reference,
/// whose system time an FRMW carries to the others, and the others, whose 0x092C is read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct DcGroup {
    /// The reference clock.
    pub(super) reference: SlaveId,
    /// Every other slave with a system time, in network order.
    pub(super) synced: Vec<SlaveId>,
}

impl DcGroup {
    pub(super) fn of(slaves: &[SlaveInfo], reference: SlaveId) -> Self {
        DcGroup {
            reference,
            synced: slaves
                .iter()
                .filter(|s| s.dc == DcCapability::SystemTime && s.station != reference.station)
                .map(SlaveInfo::id)
                .collect(),
        }
    }

    /// The FRMW that reads the reference's system time and writes it to every later slave.
    pub(super) fn frmw(&self) -> Pdu {
        Pdu::new(
            Command::Frmw,
            DatagramAddress::configured(self.reference.station, reg::DC_SYSTEM_TIME),
            vec![0; 8],
        )
    }

    /// One FPRD of 0x092C per synced slave.
    pub(super) fn difference_reads(&self) -> impl Iterator<Item = Pdu> + '_ {
        self.synced.iter().map(|s| {
            Pdu::new(
                Command::Fprd,
                DatagramAddress::configured(s.station, reg::DC_SYSTEM_TIME_DIFF),
                vec![0; 4],
            )
        })
    }

    /// The reads of every synced slave's 0x092C, after an FRMW when `with_frmw`.
    pub(super) fn check_pdus(&self, with_frmw: bool) -> Vec<Pdu> {
        let mut v = Vec::with_capacity(self.synced.len() + 1);
        if with_frmw {
            v.push(self.frmw());
        }
        v.extend(self.difference_reads());
        v
    }

    /// The largest |0x092C| of the replies to [`DcGroup::difference_reads`]; a slave that did
    /// not answer is named, in `phase`.
    pub(super) fn worst_of(&self, replies: &[PduReply], phase: Phase) -> Result<u32, MasterError> {
        let mut worst = 0u32;
        for (p, &id) in replies.iter().zip(&self.synced) {
            if p.wkc != 1 {
                return Err(MasterError::WorkingCounter {
                    command: Command::Fprd,
                    what: "read system time difference",
                    expected: 1,
                    got: p.wkc,
                }
                .at(phase, id));
            }
            let raw = u32::from_le_bytes([p.data[0], p.data[1], p.data[2], p.data[3]]);
            worst = worst.max(dc_time::decode_time_difference(raw).unsigned_abs());
        }
        Ok(worst)
    }
}

/// Where [`static_drift`] leaves the lock detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Drift {
    /// The detector, fed by the checks so far.
    pub(super) detector: LockDetector,
    /// Master time when drift compensation started, ns.
    pub(super) start_ns: u64,
    /// FRMW frames sent.
    pub(super) frmw_frames: u64,
}

/// [`Phase::StaticDrift`]: separate FRMW frames, every slave's 0x092C read after every
/// [`BringupConfig::check_every_frames`] of them.
pub(super) async fn static_drift(
    link: &Link,
    cfg: &BringupConfig,
    dc: &DcGroup,
) -> Result<Drift, MasterError> {
    let start_ns = link.now().as_ns();
    let mut detector = LockDetector::new(cfg.lock_threshold_ns, cfg.lock_hold_checks.max(1));
    let mut frmw_frames = 0u64;
    for i in 0..cfg.static_drift_frames {
        let r = link
            .pdu(
                Command::Frmw,
                DatagramAddress::configured(dc.reference.station, reg::DC_SYSTEM_TIME),
                vec![0; 8],
                "static drift compensation",
            )
            .await
            .map_err(|e| e.at(Phase::StaticDrift, dc.reference))?;
        frmw_frames += 1;
        if r.wkc == 0 {
            return Err(MasterError::WorkingCounter {
                command: Command::Frmw,
                what: "static drift compensation",
                expected: 1,
                got: 0,
            }
            .at(Phase::StaticDrift, dc.reference));
        }
        if cfg.check_every_frames > 0
            && (i + 1) % cfg.check_every_frames == 0
            && !dc.synced.is_empty()
        {
            let (r, _) = link
                .pdus(&dc.check_pdus(false), "read system time difference")
                .await?;
            detector.update(dc.worst_of(&r, Phase::StaticDrift)?, link.now().as_ns());
        }
    }
    Ok(Drift {
        detector,
        start_ns,
        frmw_frames,
    })
}

/// The cycle grid of the cyclic frames from the lock wait on: master time, multiples of the
/// cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct CycleGrid {
    /// Cycle, ns.
    pub(super) cycle_ns: u64,
    /// The next grid point, ns.
    pub(super) next_ns: u64,
}

impl CycleGrid {
    /// The grid of `cycle_ns` from the first point after now.
    pub(super) fn after_now(link: &Link, cycle_ns: u32) -> Self {
        let cycle_ns = u64::from(cycle_ns);
        CycleGrid {
            cycle_ns,
            next_ns: (link.now().as_ns() / cycle_ns + 1) * cycle_ns,
        }
    }

    /// Waits for the next grid point. Points already past (the configuration between the
    /// lock and the cyclic frames takes seconds in a large network) are skipped, not made up
    /// by frames back to back: the next point on the same grid after now.
    pub(super) async fn tick(&mut self, link: &Link) {
        let now_ns = link.now().as_ns();
        if self.next_ns < now_ns {
            self.next_ns += (now_ns - self.next_ns).div_ceil(self.cycle_ns) * self.cycle_ns;
        }
        link.sleep_until(self.next_ns).await;
        self.next_ns += self.cycle_ns;
    }
}

/// What [`wait_for_lock`] leaves: the lock report and the grid the cyclic frames go on on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Locked {
    pub(super) report: LockReport,
    pub(super) grid: CycleGrid,
}

/// [`Phase::Lock`]: cyclic FRMW until locked. The timeout runs from the end of the static
/// drift compensation, whose length grows with the network (a frame passes every slave).
pub(super) async fn wait_for_lock(
    link: &Link,
    cfg: &BringupConfig,
    dc: &DcGroup,
    drift: Drift,
) -> Result<Locked, MasterError> {
    let Drift {
        detector: mut lock,
        start_ns: drift_start,
        mut frmw_frames,
    } = drift;
    let synced = &dc.synced;
    let mut grid = CycleGrid::after_now(link, cfg.cycle_ns);
    let lock_start = link.now().as_ns();
    let timeout_ns = cfg.timeouts.lock_timeout_ns;
    let mut checks = 0u64;
    while !synced.is_empty() && !lock.is_locked() {
        let waited_ns = link.now().as_ns().saturating_sub(lock_start);
        if waited_ns > timeout_ns && checks >= cfg.timeouts.lock_timeout_checks {
            return Err(MasterError::NoLock(waited_ns / 1_000_000));
        }
        checks += 1;
        grid.tick(link).await;
        let (r, _) = link.pdus(&dc.check_pdus(true), "cyclic DC").await?;
        frmw_frames += 1;
        lock.update(dc.worst_of(&r[1..], Phase::Lock)?, link.now().as_ns());
    }
    let report = LockReport {
        converged: synced.is_empty() || lock.is_locked(),
        time_to_lock_ns: if synced.is_empty() {
            Some(0)
        } else {
            lock.locked_at_ns().map(|t| t.saturating_sub(drift_start))
        },
        drift_start_ns: drift_start,
        declared_ns: (synced.is_empty() || lock.is_locked()).then(|| link.now().as_ns()),
        max_abs_092c_after_lock_ns: 0,
        max_abs_092c_by_broadcast: false,
        frmw_frames,
    };
    Ok(Locked { report, grid })
}
