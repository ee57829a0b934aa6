//! Bringing slaves back while the cycle goes on: a sans-IO procedure, run by the cyclic driver
//! one frame per cycle next to the cyclic frames ([`crate::driver::CyclicDriver::set_recovery`]),
//! after the cyclic engine saw a slave lose its configuration (a power cycle: the LRW's working
//! counter short, |0x092C| far off, the reference's time gone or restarted).
//!
//! What it does, in the bring-up's order but only for the slaves that lost their
//! configuration, and from what the bring-up measured (the cables and delays are the same):
//! 1. reads every slave's station address by position: a slave that answers with another
//!    address has been reset; one that does not answer is not back yet (the procedure fails
//!    and the driver tries again later);
//! 2. gives it its station address again;
//! 3. a DC slave: latches the receive times (BWR 0x0900) and sets its offset (0x0920) so
//!    that its system time continues the segment's timeline, read from a slave that kept it
//!    (the reference, or after the reference's own reset any synced slave): offset = that
//!    slave's system time at the latch, less its delay, plus this one's delay, less this
//!    one's local receive time; writes its delay (0x0928) and resets its time control loop
//!    (0x0930), runs a static drift compensation (FRMW frames back to back) and starts its
//!    SYNC0 on the segment's grid;
//! 4. takes it to PRE-OP, configures its SyncManagers and FMMUs, to SAFE-OP and to OP (the
//!    cyclic frames bring it its process data meanwhile).

use crate::bringup::{BringupTimeouts, request_state};
use crate::error::MasterError;
use crate::io::{Link, Pdu};
use crate::network::{DcCapability, Network, SlaveInfo};
use ecsync_dc::time::SystemTime;
use ecsync_wire::register as reg;
use ecsync_wire::{AlControlRepr, AlState, Command, DatagramAddress};

/// How a recovery sets SYNC0 up and waits for the states.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoveryConfig {
    /// Cycle time and SYNC0 period, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift after the grid point, ns.
    pub sync0_shift_ns: u32,
    /// SYNC0's first pulse this long after the recovery reads the time, at least, ns.
    pub sync0_lead_ns: u64,
    /// State timeouts.
    pub timeouts: BringupTimeouts,
    /// At most this many FRMW frames of static drift compensation after a reset slave's
    /// offset is written, until its |0x092C| stays under 100 ns (its time control loop learns
    /// its crystal's drift from them; the cyclic FRMW alone, one a cycle, takes seconds for
    /// tens of ppm).
    pub static_drift_frames: u32,
    /// The sync error counter limit written again to a reset drive with its sync mode
    /// ([`crate::BringupConfig::sync_error_limit`]; `None`: not written).
    pub sync_error_limit: Option<u16>,
    /// The slaves run on SYNC1 with oversampling ([`crate::BringupConfig::oversampled`]): a
    /// reset one gets its SYNC1 set-up again.
    pub oversampled: Vec<crate::bringup::Oversampled>,
}

/// What a recovery did.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Recovered {
    /// Positions of the slaves it configured again (empty: none had lost its configuration).
    pub positions: Vec<u16>,
    /// The reference clock was among them.
    pub reference: bool,
    /// The System Time Offset written to the reset reference (a method that adjusts the
    /// reference's offset adjusts this one from now on).
    pub reference_offset: Option<u64>,
    /// Slaves that answer beyond the network as brought up (hot-connected at the end): counted,
    /// not taken in (a new bring-up maps their process data).
    pub appeared: u16,
    /// Slaves that kept their configuration but had left OP (an AL error of their own, a
    /// state request of someone else), as their AL status said: taken back to OP (the error
    /// acknowledged), their clocks left as they were.
    pub left_op: Vec<LeftOp>,
}

/// A slave found out of OP with its station address kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeftOp {
    /// Network position.
    pub position: u16,
    /// The state it was in (AL status bits 3:0).
    pub state: u8,
    /// The error indication (AL status bit 4).
    pub error: bool,
    /// The AL status code (0x0134).
    pub code: u16,
}

impl LeftOp {
    /// The state it was in, by name (or its register value where it is none).
    pub fn state_name(&self) -> String {
        AlState::from_register(self.state)
            .map_or_else(|_| format!("state 0x{:X}", self.state), |s| s.to_string())
    }

    /// The AL status code it gave, 0 without the error indication.
    pub fn al_status_code(&self) -> u16 {
        if self.error { self.code } else { 0 }
    }

    /// Why, in words: the AL status code's meaning.
    pub fn reason(&self) -> String {
        if self.error {
            ecsync_wire::AlStatusCode::from(self.code).to_string()
        } else {
            "no error indication".to_string()
        }
    }
}

impl std::fmt::Display for LeftOp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "slave {} in {}", self.position + 1, self.state_name())?;
        if self.error {
            let code = ecsync_wire::AlStatusCode::from(self.code);
            write!(f, " with AL error {code}")?;
        }
        Ok(())
    }
}

/// |0x092C| under this is a reset slave locked again, ns.
const LOCKED_NS: u32 = 100;

fn position_addr(pos: u16, ado: u16) -> DatagramAddress {
    DatagramAddress::position(pos, ado)
}

fn u64_of(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    let n = b.len().min(8);
    a[..n].copy_from_slice(&b[..n]);
    u64::from_le_bytes(a)
}

/// Runs the recovery of `net` (see the module documentation), step by step: how many slaves
/// answer (`count_appeared`); who lost the configuration (`find_reset`) and who left OP
/// with it kept (`find_left_op`); their station addresses (`restore_addresses`); DC on
/// the segment's timeline (`restore_dc`); their states and process data
/// (`restore_states`).
pub async fn recover(
    link: Link,
    net: Network,
    cfg: RecoveryConfig,
) -> Result<Recovered, MasterError> {
    let appeared = count_appeared(&link, &net).await?;
    let reset = find_reset(&link, &net).await?;
    let left_op = find_left_op(&link, &net, &reset).await?;
    let mut out = Recovered {
        reference: reset.contains(&net.reference),
        positions: reset.clone(),
        reference_offset: None,
        appeared,
        left_op: left_op.clone(),
    };
    if reset.is_empty() && left_op.is_empty() {
        return Ok(out);
    }
    restore_addresses(&link, &net, &reset).await?;
    let dc = restore_dc(&link, &net, &cfg, &reset).await?;
    out.reference_offset = dc.reference_offset;
    out.positions = restore_states(&link, &net, &cfg, &reset, &left_op, dc.first_pulses_ns).await?;
    Ok(out)
}

/// Slaves that answer beyond the network as brought up (hot-connected at the end).
async fn count_appeared(link: &Link, net: &Network) -> Result<u16, MasterError> {
    let (count, _) = link
        .pdus(
            &[Pdu::new(
                Command::Brd,
                position_addr(0, reg::TYPE),
                vec![0; 1],
            )],
            "count slaves",
        )
        .await?;
    Ok(count[0].wkc.saturating_sub(net.slaves.len() as u16))
}

/// The slaves that lost their configuration: their station address is gone. An error if a
/// slave does not answer at all (it is not back).
async fn find_reset(link: &Link, net: &Network) -> Result<Vec<u16>, MasterError> {
    let reads: Vec<Pdu> = net
        .slaves
        .iter()
        .map(|s| {
            Pdu::new(
                Command::Aprd,
                position_addr(s.position, reg::STATION_ADDRESS),
                vec![0; 2],
            )
        })
        .collect();
    let (r, _) = link.pdus(&reads, "read station addresses").await?;
    let mut reset = Vec::new();
    for (s, p) in net.slaves.iter().zip(&r) {
        if p.wkc != 1 {
            return Err(MasterError::WorkingCounter {
                command: Command::Aprd,
                what: "read station address (the slave is not back)",
                expected: 1,
                got: p.wkc,
            });
        }
        if u16::from_le_bytes([p.data[0], p.data[1]]) != s.station {
            reset.push(s.position);
        }
    }
    Ok(reset)
}

/// The slaves with their address but not in OP: a recovery that stopped half way (a lost
/// frame) or a slave that left OP by itself (configured again as well).
async fn find_left_op(
    link: &Link,
    net: &Network,
    reset: &[u16],
) -> Result<Vec<LeftOp>, MasterError> {
    let kept: Vec<&SlaveInfo> = net
        .slaves
        .iter()
        .filter(|s| !reset.contains(&s.position))
        .collect();
    let mut left_op = Vec::new();
    if kept.is_empty() {
        return Ok(left_op);
    }
    // AL status and, four bytes on, its code, in one read per slave.
    let reads: Vec<Pdu> = kept
        .iter()
        .map(|s| {
            Pdu::new(
                Command::Fprd,
                DatagramAddress::Configured {
                    adp: s.station,
                    ado: reg::AL_STATUS,
                },
                vec![0; ecsync_wire::al::AL_STATUS_BLOCK_LEN],
            )
        })
        .collect();
    let (r, _) = link.pdus(&reads, "read AL status").await?;
    for (s, p) in kept.iter().zip(&r) {
        let Ok(a) = ecsync_wire::AlStatus::new_checked(&p.data[..]) else {
            continue;
        };
        if p.wkc == 1 && (a.state() != Ok(AlState::Op) || a.error()) {
            left_op.push(LeftOp {
                position: s.position,
                state: a.state_raw(),
                error: a.error(),
                code: a.status_code().map_or(0, |c| c.code()),
            });
        }
    }
    Ok(left_op)
}

/// The slave at network position `pos`.
fn info(net: &Network, pos: u16) -> &SlaveInfo {
    &net.slaves[usize::from(pos)]
}

/// The reset slaves' station addresses, written again by position.
async fn restore_addresses(link: &Link, net: &Network, reset: &[u16]) -> Result<(), MasterError> {
    for &pos in reset {
        link.pdu_wkc(
            Command::Apwr,
            position_addr(pos, reg::STATION_ADDRESS),
            info(net, pos).station.to_le_bytes().to_vec(),
            1,
            "station address",
        )
        .await?;
    }
    Ok(())
}

/// DC for the reset slaves with a system time: the timeline from a slave that kept it
/// (offsets and delays), static drift compensation, SYNC0 on the segment's grid. The
/// reference's new offset, if it was reset.
async fn restore_dc(
    link: &Link,
    net: &Network,
    cfg: &RecoveryConfig,
    reset: &[u16],
) -> Result<RestoredDc, MasterError> {
    let dc_reset: Vec<u16> = reset
        .iter()
        .copied()
        .filter(|&p| info(net, p).dc == DcCapability::SystemTime)
        .collect();
    if dc_reset.is_empty() {
        return Ok(RestoredDc::default());
    }
    let keeper = std::iter::once(net.reference)
        .chain(
            net.slaves
                .iter()
                .filter(|s| s.dc == DcCapability::SystemTime)
                .map(|s| s.position),
        )
        .find(|p| !reset.contains(p));
    let Some(keeper) = keeper else {
        return Err(MasterError::Config(
            "every slave with a system time was reset: the segment's time is gone (bring it up again)"
                .into(),
        ));
    };
    let k = info(net, keeper);
    let reference_offset = write_offsets(link, net, k, &dc_reset).await?;
    compensate_drift(link, net, cfg, &dc_reset).await?;
    let first_pulses_ns = restart_sync0(link, net, k, cfg, &dc_reset).await?;
    Ok(RestoredDc {
        reference_offset,
        first_pulses_ns: Some(first_pulses_ns),
    })
}

/// What [`restore_dc`] leaves for the states.
#[derive(Debug, Clone, Copy, Default)]
struct RestoredDc {
    /// The reference's new offset, if it was reset.
    reference_offset: Option<u64>,
    /// Master time by which every restarted SYNC0 has pulsed, ns.
    first_pulses_ns: Option<u64>,
}

/// Latches the receive times and writes each slave of `dc_reset` its delay and the offset
/// that puts it on the reference's time as the keeper `k` has it; resets its loop filter.
/// The reference's offset, if it is among them.
async fn write_offsets(
    link: &Link,
    net: &Network,
    k: &SlaveInfo,
    dc_reset: &[u16],
) -> Result<Option<u64>, MasterError> {
    link.bwr(reg::DC_RECEIVE_TIME_PORT0, &[0; 4], "latch receive times")
        .await?;
    let k_local = u64_of(
        &link
            .fprd(k.station, reg::DC_RECEIVE_TIME_PU, 8, "receive time")
            .await?,
    );
    let k_offset = u64_of(
        &link
            .fprd(
                k.station,
                reg::DC_SYSTEM_TIME_OFFSET,
                8,
                "system time offset",
            )
            .await?,
    );
    let delay_of = |s: &SlaveInfo| ecsync_dc::offset::round_ns(s.delay_ns.unwrap_or(0.0)).max(0);
    // The reference's system time at the latch, as the keeper has it.
    let ref_time = k_local
        .wrapping_add(k_offset)
        .wrapping_sub(delay_of(k) as u64);
    let mut reference_offset = None;
    for &pos in dc_reset {
        let s = info(net, pos);
        let local = u64_of(
            &link
                .fprd(s.station, reg::DC_RECEIVE_TIME_PU, 8, "receive time")
                .await?,
        );
        let delay = delay_of(s);
        let offset = ecsync_dc::system_time_offset(SystemTime::from_ns(ref_time), delay, local);
        if pos == net.reference {
            reference_offset = Some(offset);
        }
        link.fpwr(
            s.station,
            reg::DC_SYSTEM_TIME_DELAY,
            &(delay as u32).to_le_bytes(),
            "write delay",
        )
        .await?;
        link.fpwr(
            s.station,
            reg::DC_SYSTEM_TIME_OFFSET,
            &offset.to_le_bytes(),
            "write offset",
        )
        .await?;
        link.fpwr(
            s.station,
            reg::DC_TIME_DIFF_FILTER_DEPTH,
            &[0x00, 0x0c],
            "filter depths",
        )
        .await?;
        link.fpwr(
            s.station,
            reg::DC_SPEED_COUNTER_START,
            &0x1000u16.to_le_bytes(),
            "reset loop filter",
        )
        .await?;
    }
    Ok(reference_offset)
}

/// Static drift compensation: the reference's time to every slave after it, frame after
/// frame (the driver sends them back to back in the rest of each cycle), until the reset
/// slaves' |0x092C| stays under 100 ns for three checks of 250 frames (a crystal near the
/// reference's is there at once), at most `static_drift_frames`.
async fn compensate_drift(
    link: &Link,
    net: &Network,
    cfg: &RecoveryConfig,
    dc_reset: &[u16],
) -> Result<(), MasterError> {
    let reference = info(net, net.reference).station;
    let frmw = Pdu::new(
        Command::Frmw,
        DatagramAddress::Configured {
            adp: reference,
            ado: reg::DC_SYSTEM_TIME,
        },
        vec![0; 8],
    );
    let mut good_checks = 0;
    for n in 1..=cfg.static_drift_frames {
        // A lost FRMW is one write fewer for the loop, not a failure of the recovery.
        match link
            .pdus(std::slice::from_ref(&frmw), "static drift compensation")
            .await
        {
            Ok(_) | Err(MasterError::FrameLost { .. }) => {}
            Err(e) => return Err(e),
        }
        if n % 250 != 0 {
            continue;
        }
        let mut worst = 0u32;
        for &pos in dc_reset {
            let v = link
                .fprd(
                    info(net, pos).station,
                    reg::DC_SYSTEM_TIME_DIFF,
                    4,
                    "read system time difference",
                )
                .await?;
            let raw = u32::from_le_bytes([v[0], v[1], v[2], v[3]]);
            worst = worst.max(ecsync_wire::dc_time::decode_time_difference(raw).unsigned_abs());
        }
        good_checks = if worst < LOCKED_NS {
            good_checks + 1
        } else {
            0
        };
        if good_checks >= 3 {
            break;
        }
    }
    Ok(())
}

/// SYNC0 of the reset slaves on the segment's grid (the start time is a grid point plus the
/// shift), read from the keeper `k`'s system time. Returns the master time by which the
/// first pulse has come and a cycle more (each start is less than the lead and a cycle after
/// the time it was computed from).
async fn restart_sync0(
    link: &Link,
    net: &Network,
    k: &SlaveInfo,
    cfg: &RecoveryConfig,
    dc_reset: &[u16],
) -> Result<u64, MasterError> {
    let now_sys = u64_of(
        &link
            .fprd(k.station, reg::DC_SYSTEM_TIME, 8, "read system time")
            .await?,
    );
    let read_at_ns = link.now().as_ns();
    // A 32-bit keeper's time extended next to the master's, as the bring-up's (its grid).
    let now_sys = ecsync_dc::sync::reference_time_from_read(read_at_ns, now_sys);
    let start_after = |sys_ns: u64| {
        ecsync_dc::sync0_start_time(
            SystemTime::from_ns(sys_ns),
            cfg.sync0_lead_ns,
            cfg.cycle_ns,
            cfg.sync0_shift_ns,
        )
        .as_ns()
    };
    let (mut start, mut basis_ns) = (start_after(now_sys), read_at_ns);
    for &pos in dc_reset {
        let st = info(net, pos).station;
        // Four frames a slave, one a cycle: with several reset slaves the start may come
        // within half the lead; then a later one on the same grid (as the bring-up does: a
        // start already past fires only when the low 32 bits wrap, 4.3 s on).
        let now_ns = link.now().as_ns();
        let sys_now_ns = now_sys.wrapping_add(now_ns.saturating_sub(read_at_ns));
        if sys_now_ns.saturating_add(cfg.sync0_lead_ns / 2) > start {
            (start, basis_ns) = (start_after(sys_now_ns), now_ns);
        }
        let plan = crate::bringup::SyncUnitPlan::of(pos, &cfg.oversampled, cfg.cycle_ns);
        link.fpwr(st, reg::DC_ACTIVATION, &[0x00], "SYNC0 off")
            .await?;
        link.fpwr(
            st,
            reg::DC_SYNC0_CYCLE,
            &plan.sync0_cycle_ns.to_le_bytes(),
            "SYNC0 cycle",
        )
        .await?;
        if let Some(d) = plan.sync1_cycle_ns {
            link.fpwr(st, reg::DC_SYNC1_CYCLE, &d.to_le_bytes(), "SYNC1 cycle")
                .await?;
        }
        let start_at = start.wrapping_add(u64::from(plan.start_after_grid_ns));
        link.fpwr(
            st,
            reg::DC_START_TIME,
            &start_at.to_le_bytes(),
            "SYNC0 start",
        )
        .await?;
        link.fpwr(st, reg::DC_ACTIVATION, &[plan.activation()], "SYNC0 on")
            .await?;
    }
    let oversampling_cycle = if cfg.oversampled.is_empty() {
        0
    } else {
        cfg.cycle_ns
    };
    Ok(basis_ns
        .saturating_add(cfg.sync0_lead_ns)
        .saturating_add(2 * u64::from(cfg.cycle_ns))
        .saturating_add(u64::from(oversampling_cycle)))
}

/// The states of the reset slaves and of those that left OP, the process data between
/// PRE-OP and SAFE-OP; an error indication is acknowledged with the first request (an
/// unacknowledged one refuses every request). The positions configured, in order.
async fn restore_states(
    link: &Link,
    net: &Network,
    cfg: &RecoveryConfig,
    reset: &[u16],
    left_op: &[LeftOp],
    first_pulses_ns: Option<u64>,
) -> Result<Vec<u16>, MasterError> {
    let mut states: Vec<u16> = reset
        .iter()
        .copied()
        .chain(left_op.iter().map(|l| l.position))
        .collect();
    states.sort_unstable();
    // A reset slave with a mailbox needs its mailbox SyncManagers before PRE-OP.
    let reset_slaves: Vec<SlaveInfo> = reset.iter().map(|&p| info(net, p).clone()).collect();
    crate::bringup::configure_mailboxes(link, &reset_slaves).await?;
    for &pos in &states {
        let s = info(net, pos);
        let ack = AlControlRepr {
            state: AlState::PreOp,
            error_ack: true,
            id_request: false,
        };
        crate::bringup::request_state_with(link, s.station, ack, &cfg.timeouts).await?;
        if reset.contains(&pos) {
            // Its CoE parameters were reset with it.
            let plan = crate::bringup::SyncUnitPlan::of(pos, &cfg.oversampled, cfg.cycle_ns);
            crate::bringup::configure_sync_mode(link, s, cfg.cycle_ns, cfg.sync_error_limit, plan)
                .await?;
        }
        crate::bringup::configure_process_data(link, std::slice::from_ref(s)).await?;
        request_state(link, s.station, AlState::SafeOp, &cfg.timeouts).await?;
        // A restarted SYNC0 pulses before its slave is asked for OP (as in the bring-up).
        if let Some(t) =
            first_pulses_ns.filter(|_| reset.contains(&pos) && s.dc == DcCapability::SystemTime)
            && link.now().as_ns() < t
        {
            link.sleep_until(t).await;
        }
        request_state(link, s.station, AlState::Op, &cfg.timeouts).await?;
    }
    Ok(states)
}
