//! SYNC0, the state machine up to OP and the monitoring of the cyclic frame.

use super::clocks::{CycleGrid, DcGroup};
use super::config::{BringupConfig, BringupTimeouts, SyncUnitPlan};
use crate::MasterError;
use crate::io::{Link, Pdu, PduReply};
use crate::network::{DcCapability, Phase, ReferenceReading, SlaveId, SlaveInfo, Sync0Config};
use ecsync_dc::time::SystemTime;
use ecsync_wire::register::{self as reg};
use ecsync_wire::{
    AlControlRepr, AlState, AlStatus, AlStatusCode, Command, DatagramAddress, dc_time,
};

/// [`Phase::Sync0`]: SYNC0 on the absolute grid of the reference's system time, programmed in
/// every slave with a system time, and the master time by which every programmed slave has
/// had its first pulse. `None` if there is none to program (not reached: the reference has
/// one).
pub(super) async fn start_sync0(
    link: &Link,
    cfg: &BringupConfig,
    slaves: &[SlaveInfo],
    dc: &DcGroup,
) -> Result<Option<(Sync0Config, u64)>, MasterError> {
    let now_sys = link
        .fprd(
            dc.reference.station,
            reg::DC_SYSTEM_TIME,
            8,
            "read system time",
        )
        .await
        .map_err(|e| e.at(Phase::Sync0, dc.reference))?;
    let read_at_ns = link.now().as_ns();
    let now_sys = u64::from_le_bytes(now_sys[..8].try_into().unwrap_or([0; 8]));
    // A 32-bit reference reads 0 in the upper half: its time extended next to the master's,
    // as every later reading of it is (`ReferenceReading::of`, the cyclic engine), so that
    // the start's grid is the one the cyclic phase aims at (the ESC takes the lower half).
    let now_sys = ecsync_dc::sync::reference_time_from_read(read_at_ns, now_sys);
    let first_start = ecsync_dc::sync0_start_time(
        SystemTime::from_ns(now_sys),
        cfg.sync0_lead_ns,
        cfg.cycle_ns,
        cfg.sync0_shift_ns,
    )
    .as_ns();
    let dc_slaves: Vec<SlaveId> = slaves
        .iter()
        .filter(|s| s.dc == DcCapability::SystemTime)
        .map(SlaveInfo::id)
        .collect();
    if dc_slaves.is_empty() {
        return Ok(None);
    }
    // Every slave's four writes side by side: four rounds for the network, not four round
    // trips per slave (a 512-drive line took about 2 s one slave after the other).
    let each = link
        .side_by_side(
            dc_slaves,
            |l, id| async move {
                let at = |e: MasterError| e.at(Phase::Sync0, id);
                let plan = SyncUnitPlan::of(id.position, &cfg.oversampled, cfg.cycle_ns);
                l.fpwr(id.station, reg::DC_ACTIVATION, &[0x00], "SYNC0 off")
                    .await
                    .map_err(at)?;
                l.fpwr(
                    id.station,
                    reg::DC_SYNC0_CYCLE,
                    &plan.sync0_cycle_ns.to_le_bytes(),
                    "SYNC0 cycle",
                )
                .await
                .map_err(at)?;
                if let Some(d) = plan.sync1_cycle_ns {
                    l.fpwr(
                        id.station,
                        reg::DC_SYNC1_CYCLE,
                        &d.to_le_bytes(),
                        "SYNC1 cycle",
                    )
                    .await
                    .map_err(at)?;
                }
                // A start time already past when SYNC0 is switched on fires only after the
                // system time's low 32 bits wrap, 4.3 s later (the ESC compares those): on a
                // network whose rounds take long, the start moves on by whole cycles, on the
                // same grid, once less than half the lead is left (the system time estimated
                // by the master's clock since the read: their rates differ by parts per
                // million).
                let master_now_ns = l.now().as_ns();
                let sys_now_ns = now_sys.wrapping_add(master_now_ns.saturating_sub(read_at_ns));
                let (start, basis_ns) =
                    if sys_now_ns.saturating_add(cfg.sync0_lead_ns / 2) > first_start {
                        let start = ecsync_dc::sync0_start_time(
                            SystemTime::from_ns(sys_now_ns),
                            cfg.sync0_lead_ns,
                            cfg.cycle_ns,
                            cfg.sync0_shift_ns,
                        );
                        (start.as_ns(), master_now_ns)
                    } else {
                        (first_start, read_at_ns)
                    };
                // An oversampled slave's SYNC0 a SYNC0 cycle later: its SYNC1 on the grid.
                let start = start.wrapping_add(u64::from(plan.start_after_grid_ns));
                l.fpwr(
                    id.station,
                    reg::DC_START_TIME,
                    &start.to_le_bytes(),
                    "SYNC0 start",
                )
                .await
                .map_err(at)?;
                l.fpwr(
                    id.station,
                    reg::DC_ACTIVATION,
                    &[plan.activation()],
                    "SYNC0 on",
                )
                .await
                .map_err(at)?;
                Ok::<u64, MasterError>(basis_ns)
            },
            "SYNC0",
        )
        .await?;
    // Each start lies less than the lead and a cycle after the system time it was computed
    // from: the master's time then, plus that, is past every first pulse (the clocks' rates
    // differ by parts per million, microseconds over the lead). Not the start itself: where
    // its grid falls in the master's cycle would then move the bring-up's end by a cycle (a
    // 32-bit reference's grid is another than a 64-bit one's on the same network).
    let basis_ns = each
        .into_iter()
        .collect::<Result<Vec<u64>, _>>()?
        .into_iter()
        .max()
        .unwrap_or(read_at_ns);
    // (An oversampled slave's first SYNC1 comes a cycle after the grid's pulse.)
    let oversampling_cycle = if cfg.oversampled.is_empty() {
        0
    } else {
        cfg.cycle_ns
    };
    let first_pulses_ns = basis_ns
        .saturating_add(cfg.sync0_lead_ns)
        .saturating_add(u64::from(cfg.cycle_ns))
        .saturating_add(u64::from(oversampling_cycle));
    Ok(Some((
        Sync0Config {
            start_ns: first_start,
            cycle_ns: cfg.cycle_ns,
            shift_ns: cfg.sync0_shift_ns,
        },
        first_pulses_ns,
    )))
}

/// Part of [`Phase::SafeOp`]: the cyclic frame on the grid until every slave's SYNC0 has
/// pulsed (`first_pulses_ns`, master time) and a cycle more. A drive asked for OP before its
/// first SYNC0 pulse has no synchronisation to check (real drives refuse OP then, or count
/// the missing pulses as sync errors); the process data and the reference's time keep coming
/// meanwhile, as in OP.
pub(super) async fn await_first_pulses(
    link: &Link,
    cyclic: &CyclicFrame,
    grid: &mut CycleGrid,
    first_pulses_ns: u64,
) -> Result<(), MasterError> {
    let until_ns = first_pulses_ns.saturating_add(grid.cycle_ns);
    while link.now().as_ns() < until_ns {
        grid.tick(link).await;
        link.pdus(&cyclic.pdus, "cyclic").await?;
    }
    Ok(())
}

/// The cyclic frame of OP: the FRMW first (its send is the reference's time), the process
/// image's LRWs, then every synced slave's 0x092C. In a network where those reads (and the OP
/// wait's read of AL status) would not fit half a cycle, one BRD of 0x092C instead, as the
/// cyclic engine reads it, and the AL status BRD with it: one exchange a cycle that ends
/// within the cycle. A 512-drive line's exchange with a read per slave took 2.6 ms of its 2 ms
/// cycle, and its drives missed a SYNC0 pulse every few cycles of the OP wait and monitoring.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct CyclicFrame {
    pub(super) pdus: Vec<Pdu>,
    /// The LRWs are `pdus[1..lrw_end]`.
    pub(super) lrw_end: usize,
    /// Each synced slave's 0x092C is read after the LRWs (else one BRD of it, then one of AL
    /// status).
    pub(super) per_slave: bool,
}

impl CyclicFrame {
    pub(super) fn new(
        dc: &DcGroup,
        lrw: &[crate::pdi::LrwChunk],
        slaves: &[SlaveInfo],
        cycle_ns: u32,
    ) -> Self {
        let mut pdus = vec![dc.frmw()];
        pdus.extend(lrw.iter().map(|c| {
            Pdu::new(
                Command::Lrw,
                DatagramAddress::Logical(c.logical),
                vec![0; c.len as usize],
            )
        }));
        let lrw_end = pdus.len();
        let reads: Vec<Pdu> = dc.difference_reads().collect();
        let per_slave_ns = exchange_estimate_ns(pdus.iter().chain(&reads), slaves)
            + exchange_estimate_ns([&al_status_brd()], slaves);
        let per_slave = per_slave_ns <= u64::from(cycle_ns) / 2;
        if per_slave {
            pdus.extend(reads);
        } else {
            pdus.push(Pdu::new(
                Command::Brd,
                DatagramAddress::position(0, reg::DC_SYSTEM_TIME_DIFF),
                vec![0; 4],
            ));
            pdus.push(al_status_brd());
        }
        CyclicFrame {
            pdus,
            lrw_end,
            per_slave,
        }
    }

    /// The largest |0x092C| a cycle's replies show. From the BRD, the OR of every slave's
    /// magnitude: no smaller than the largest, so a bound that holds.
    pub(super) fn worst_of(
        &self,
        dc: &DcGroup,
        r: &[PduReply],
        phase: Phase,
    ) -> Result<u32, MasterError> {
        if self.per_slave {
            return dc.worst_of(&r[self.lrw_end..], phase);
        }
        let p = &r[self.lrw_end];
        // Every slave with a system time answers (others may too).
        let least = dc.synced.len() as u16 + 1;
        if p.wkc < least {
            return Err(MasterError::WorkingCounter {
                command: Command::Brd,
                what: "read system time difference",
                expected: least,
                got: p.wkc,
            }
            .during(phase));
        }
        let raw = u32::from_le_bytes(
            p.data
                .get(..4)
                .and_then(|d| d.try_into().ok())
                .ok_or(MasterError::BadReply("system time difference"))?,
        );
        Ok(dc_time::decode_time_difference(raw).unsigned_abs())
    }

    /// The reply of the AL status BRD when it rides along.
    pub(super) fn al_status<'a>(&self, r: &'a [PduReply]) -> Option<&'a PduReply> {
        (!self.per_slave).then(|| r.get(self.lrw_end + 1)).flatten()
    }
}

/// A broadcast read of AL status: every slave's state OR-ed, the working counter the slaves
/// that answered.
pub(super) fn al_status_brd() -> Pdu {
    Pdu::new(
        Command::Brd,
        DatagramAddress::position(0, reg::AL_STATUS),
        vec![0; 2],
    )
}

/// About how long an exchange of `pdus` takes on a 100 Mbit/s network, ns: every byte of its
/// frames on the wire (Ethernet's header, checksum, preamble and gap with each frame), and the
/// way to the farthest slave and back (its measured delay, twice).
pub(super) fn exchange_estimate_ns<'a>(
    pdus: impl IntoIterator<Item = &'a Pdu>,
    slaves: &[SlaveInfo],
) -> u64 {
    use ecsync_wire::{ECAT_HEADER_LEN, ETH_HEADER_LEN, MAX_FRAME_LEN};
    // The headers before the datagrams; checksum, preamble and the gap after.
    pub(super) const FRAME_OVERHEAD: usize = ETH_HEADER_LEN + ECAT_HEADER_LEN + 4 + 8 + 12;
    pub(super) const ROOM: usize = MAX_FRAME_LEN - ETH_HEADER_LEN - ECAT_HEADER_LEN;
    let bytes: usize = pdus
        .into_iter()
        .map(|p| ecsync_wire::DATAGRAM_HEADER_LEN + p.data.len() + 2)
        .sum();
    let frames = bytes.div_ceil(ROOM).max(1);
    let far_ns = slaves
        .iter()
        .filter_map(|s| s.delay_ns)
        .fold(0.0f64, f64::max);
    (bytes + frames * FRAME_OVERHEAD) as u64 * 80 + 2 * far_ns.max(0.0) as u64
}

/// [`Phase::Op`]: requests OP from every slave, then runs the cyclic frame until a broadcast
/// read of AL status shows every slave in OP (a slave goes to OP only with process data
/// flowing).
pub(super) async fn enter_op(
    link: &Link,
    timeouts: &BringupTimeouts,
    slaves: &[SlaveInfo],
    cyclic: &CyclicFrame,
    grid: &mut CycleGrid,
) -> Result<(), MasterError> {
    let op = AlControlRepr::request(AlState::Op).to_bytes();
    // Requests that one by one would take longer than a cycle (a round trip each, ~1 s for a
    // 1 000-drive line) leave the first drives in OP with their outputs late or missing,
    // counting missed SYNC0 pulses (a drive with SSC's error limit leaves OP for it): they go
    // in one exchange (as many frames as it needs), right after a cycle's process data. Where
    // the wire alone says so, every slave's request goes there: a first request on its own
    // left the first drive of a 1 000-drive line in OP through the long exchange of the
    // others' requests, and it missed the SYNC0 pulse that exchange covered.
    let one_request = Pdu::new(
        Command::Fpwr,
        DatagramAddress::Configured {
            adp: 0,
            ado: reg::AL_CONTROL,
        },
        op.to_vec(),
    );
    let one_by_one_ns = exchange_estimate_ns([&one_request], slaves) * slaves.len() as u64;
    let slaves_one_by_one = if one_by_one_ns > grid.cycle_ns {
        request_op_at_once(link, slaves, &op, cyclic, grid).await?;
        &[][..]
    } else {
        slaves
    };
    // The process data keeps coming while the requests go out one by one (a large network's
    // take longer than a cycle): a slave in OP without outputs for its watchdog time (100 ms)
    // would fall back to SAFE-OP.
    let mut last_cyclic = link.now().as_ns();
    for (n, s) in slaves_one_by_one.iter().enumerate() {
        let sent = link.now().as_ns();
        link.fpwr(s.station, reg::AL_CONTROL, &op, "request OP")
            .await
            .map_err(|e| e.at(Phase::Op, s.id()))?;
        let round_trip_ns = link.now().as_ns().saturating_sub(sent);
        if link.now().as_ns().saturating_sub(last_cyclic) >= grid.cycle_ns {
            link.pdus(&cyclic.pdus, "cyclic").await?;
            last_cyclic = link.now().as_ns();
        }
        // The measured round trip (a host's latency included) says so: the others at once.
        if n == 0 && round_trip_ns.saturating_mul(slaves.len() as u64) > grid.cycle_ns {
            request_op_at_once(link, &slaves[1..], &op, cyclic, grid).await?;
            break;
        }
    }
    let count = slaves.len() as u16;
    // Cycle until every slave reports OP.
    let deadline = link.now().as_ns() + timeouts.op_timeout_ns;
    loop {
        grid.tick(link).await;
        let (cycle, _) = link.pdus(&cyclic.pdus, "cyclic").await?;
        let al = match cyclic.al_status(&cycle) {
            Some(al) => al.clone(),
            None => {
                let (r, _) = link.pdus(&[al_status_brd()], "AL status").await?;
                r.into_iter()
                    .next()
                    .ok_or(MasterError::BadReply("AL status"))?
            }
        };
        // The slaves' AL status OR-ed: OP, and none shows the error indication.
        let status =
            AlStatus::new_checked(&al.data[..]).map_err(|_| MasterError::BadReply("AL status"))?;
        if al.wkc == count && status.state() == Ok(AlState::Op) && !status.error() {
            return Ok(());
        }
        if status.error() || link.now().as_ns() > deadline {
            // Who refused, and why: each slave's AL status and code (a drive's 0x002D, 0x0036,
            // ... is the message the user needs, not the OR of the states).
            for s in slaves {
                let st = link
                    .fprd(s.station, reg::AL_STATUS, 6, "AL status and code")
                    .await?;
                let a = AlStatus::new_checked(&st[..])
                    .map_err(|_| MasterError::BadReply("AL status"))?;
                if a.error() {
                    return Err(MasterError::StateChange {
                        slave: s.station,
                        state: AlState::Op,
                        code: a.status_code().unwrap_or(AlStatusCode::NoError),
                    });
                }
            }
        }
        if link.now().as_ns() > deadline {
            return Err(MasterError::NetworkStateTimeout {
                state: AlState::Op,
                answered: al.wkc,
                expected: count,
                status: al.data[0],
            });
        }
    }
}

/// Part of [`Phase::Op`] in a large network: OP requested from `slaves` in one exchange on the
/// cycle grid, after the cycle's process data.
pub(super) async fn request_op_at_once(
    link: &Link,
    slaves: &[SlaveInfo],
    op: &[u8],
    cyclic: &CyclicFrame,
    grid: &mut CycleGrid,
) -> Result<(), MasterError> {
    let requests: Vec<Pdu> = slaves
        .iter()
        .map(|s| {
            Pdu::new(
                Command::Fpwr,
                DatagramAddress::Configured {
                    adp: s.station,
                    ado: reg::AL_CONTROL,
                },
                op.to_vec(),
            )
        })
        .collect();
    grid.tick(link).await;
    link.pdus(&cyclic.pdus, "cyclic").await?;
    let (replies, _) = link.pdus(&requests, "request OP").await?;
    match slaves.iter().zip(&replies).find(|(_, r)| r.wkc != 1) {
        Some((s, r)) => Err(MasterError::WorkingCounter {
            command: Command::Fpwr,
            what: "request OP",
            expected: 1,
            got: r.wkc,
        }
        .at(Phase::Op, s.id())),
        None => Ok(()),
    }
}

/// [`Phase::Monitor`]: [`BringupConfig::monitor_cycles`] cycles of the cyclic frame in OP,
/// the process data's working counter checked; returns the largest |0x092C| seen and the
/// reference's time as the last cycle's FRMW read it.
pub(super) async fn monitor(
    link: &Link,
    cfg: &BringupConfig,
    dc: &DcGroup,
    cyclic: &CyclicFrame,
    pdi_len: u32,
    expected_lrw_wkc: u16,
    grid: &mut CycleGrid,
) -> Result<(u32, Option<ReferenceReading>), MasterError> {
    let k = cyclic.lrw_end;
    let mut max_abs = 0u32;
    let mut reading = None;
    for _ in 0..cfg.monitor_cycles {
        grid.tick(link).await;
        // The FRMW is in the exchange's first frame, whose send time the reply carries.
        let (r, first) = link.pdus(&cyclic.pdus, "cyclic").await?;
        let worst = cyclic.worst_of(dc, &r, Phase::Monitor)?;
        max_abs = max_abs.max(worst);
        reading = ReferenceReading::of(&r[0], first.sent.as_ns()).or(reading);
        let got: u16 = r[1..k].iter().map(|p| p.wkc).sum();
        if pdi_len > 0 && got != expected_lrw_wkc {
            return Err(MasterError::WorkingCounter {
                command: Command::Lrw,
                what: "process data",
                expected: expected_lrw_wkc,
                got,
            });
        }
    }
    Ok((max_abs, reading))
}

/// Requests an AL state from one slave and waits until it is reached or refused, polling AL
/// status every [`BringupTimeouts::state_poll_interval_ns`] for up to
/// [`BringupTimeouts::state_timeout_ns`].
pub async fn request_state(
    link: &Link,
    station: u16,
    state: AlState,
    timeouts: &BringupTimeouts,
) -> Result<(), MasterError> {
    request_state_with(link, station, AlControlRepr::request(state), timeouts).await
}

/// [`request_state`] with the whole AL control value (an error acknowledge with it).
pub async fn request_state_with(
    link: &Link,
    station: u16,
    control: AlControlRepr,
    timeouts: &BringupTimeouts,
) -> Result<(), MasterError> {
    let state = control.state;
    let request = control.to_bytes();
    link.fpwr(station, reg::AL_CONTROL, &request, "AL control")
        .await?;
    let start = link.now().as_ns();
    loop {
        // AL status and, four bytes on, the AL status code, in one read.
        let v = link
            .fprd(
                station,
                reg::AL_STATUS,
                ecsync_wire::al::AL_STATUS_BLOCK_LEN,
                "AL status",
            )
            .await?;
        let status =
            AlStatus::new_checked(&v[..]).map_err(|_| MasterError::BadReply("AL status"))?;
        if status.error() {
            return Err(MasterError::StateChange {
                slave: station,
                state,
                // The read reaches the code (the datagram has the length asked for).
                code: status.status_code().unwrap_or(AlStatusCode::NoError),
            });
        }
        if status.state_raw() == state.code() {
            return Ok(());
        }
        if link.now().as_ns().saturating_sub(start) > timeouts.state_timeout_ns {
            return Err(MasterError::StateTimeout {
                slave: station,
                state,
            });
        }
        let t = link.now().as_ns() + timeouts.state_poll_interval_ns;
        link.sleep_until(t).await;
    }
}

impl ReferenceReading {
    /// The reading a reply carries of the reference's system time (0x0910: the FRMW's or a
    /// read's), whose frame left at `master_sent_ns`; `None` if the reference did not answer.
    pub(crate) fn of(reply: &PduReply, master_sent_ns: u64) -> Option<Self> {
        if reply.wkc == 0 {
            return None;
        }
        let raw = u64::from_le_bytes(reply.data.get(..8)?.try_into().ok()?);
        let reference_ns = ecsync_dc::sync::reference_time_from_read(master_sent_ns, raw);
        Some(ReferenceReading {
            master_sent_ns,
            reference_ns,
        })
    }
}
