//! The process image, mailboxes, sync mode and process data of each slave.

use super::config::{BringupTimeouts, Oversampled, SyncUnitPlan};
use super::operational::request_state;
use crate::MasterError;
use crate::io::Link;
use crate::network::{DcCapability, Phase, SlaveInfo};
use ecsync_wire::register::{self as reg};
use ecsync_wire::{AlState, FmmuRepr, SmActivate, SmControl, SmDirection, SmMode, SyncManagerRepr};

/// The logical process image, as [`map_process_image`] lays it out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct ProcessImage {
    /// Bytes (outputs then inputs).
    pub(super) pdi_len: u32,
    /// Its LRWs in the cyclic exchange.
    pub(super) lrw: Vec<crate::pdi::LrwChunk>,
}

/// Bytes of a slave's process data SyncManagers of SII type `kind` (3 outputs, 4 inputs),
/// together: a slave may spread its outputs over several (the EL2889: two of one byte, at
/// 0x0F00 and 0x0F01), which the image holds one after the other.
fn sm_bytes(s: &SlaveInfo, kind: u8) -> u16 {
    s.sms
        .iter()
        .filter(|m| m.kind == kind)
        .map(|m| m.len)
        .fold(0, u16::saturating_add)
}

/// Process data mapping: outputs of all slaves, then inputs, in the logical image (recorded
/// in each slave's `outputs` and `inputs`). No frames: the SyncManagers and FMMUs are written
/// in [`Phase::ProcessData`].
pub(super) fn map_process_image(slaves: &mut [SlaveInfo]) -> ProcessImage {
    let mut logical = 0u32;
    for s in slaves.iter_mut() {
        if s.sms.iter().any(|m| m.kind == 3) {
            let len = sm_bytes(s, 3);
            s.outputs = (logical, len);
            logical += u32::from(len);
        }
    }
    for s in slaves.iter_mut() {
        if s.sms.iter().any(|m| m.kind == 4) {
            let len = sm_bytes(s, 4);
            s.inputs = (logical, len);
            logical += u32::from(len);
        }
    }
    let pdi_len = logical;
    // The LRWs of the cyclic exchange: one when the image fits a frame, else as many as it
    // needs, split on slave boundaries.
    let mut ranges: Vec<(u32, u32, u16)> = slaves
        .iter()
        .filter(|s| s.outputs.1 > 0)
        .map(|s| (s.outputs.0, u32::from(s.outputs.1), 2))
        .chain(
            slaves
                .iter()
                .filter(|s| s.inputs.1 > 0)
                .map(|s| (s.inputs.0, u32::from(s.inputs.1), 1)),
        )
        .collect();
    ranges.sort_by_key(|r| r.0);
    let lrw = crate::pdi::lrw_chunks(pdi_len, &ranges);
    ProcessImage { pdi_len, lrw }
}

/// [`Phase::PreOp`], [`Phase::SafeOp`]: requests `state` from every slave and waits for each
/// ([`request_state`]), the slaves side by side ([`Link::side_by_side`]: a 2 000-drive line's
/// SAFE-OP took 7.9 s of round trips one slave after the other, 13 ms so); the first slave in
/// order that failed is the error.
pub(super) async fn request_all(
    link: &Link,
    slaves: &[SlaveInfo],
    state: AlState,
    phase: Phase,
    timeouts: &BringupTimeouts,
) -> Result<(), MasterError> {
    let each = link
        .side_by_side(
            slaves.iter().map(SlaveInfo::id).collect(),
            |l, id| async move {
                request_state(&l, id.station, state, timeouts)
                    .await
                    .map_err(|e| e.at(phase, id))
            },
            "AL state",
        )
        .await?;
    each.into_iter().collect()
}

/// Part of [`Phase::PreOp`]: the mailbox SyncManagers of every slave that has a mailbox, in
/// INIT (a slave refuses PRE-OP without them: AL status code 0x0016): SM0 written by the
/// master, SM1 read, both in mailbox mode, as the SII's words give them.
pub(crate) async fn configure_mailboxes(
    link: &Link,
    slaves: &[SlaveInfo],
) -> Result<(), MasterError> {
    let each = link
        .side_by_side(
            slaves.iter().collect(),
            |l, s| async move { configure_mailbox_of(&l, s).await },
            "mailbox SyncManagers",
        )
        .await?;
    each.into_iter().collect()
}

/// [`configure_mailboxes`] of one slave.
async fn configure_mailbox_of(link: &Link, s: &SlaveInfo) -> Result<(), MasterError> {
    let Some(m) = s.mailbox else { return Ok(()) };
    for (n, start, len, direction) in [
        (0u16, m.out_start, m.out_len, SmDirection::Write),
        (1, m.in_start, m.in_len, SmDirection::Read),
    ] {
        let smr = SyncManagerRepr {
            physical_start: start,
            length_bytes: len,
            control: SmControl {
                mode: SmMode::Mailbox,
                direction,
                ecat_event: false,
                al_event: true,
                watchdog: false,
            },
            activate: SmActivate {
                enable: true,
                ..SmActivate::default()
            },
            ..SyncManagerRepr::default()
        }
        .to_bytes();
        link.fpwr(
            s.station,
            reg::SM_BASE + n * reg::SM_LEN,
            &smr,
            "configure mailbox SyncManager",
        )
        .await
        .map_err(|e| e.at(Phase::PreOp, s.id()))?;
    }
    Ok(())
}

/// [`configure_sync_mode`] of every slave, side by side (each drive's mailbox exchanges
/// merged into one frame a round); the first slave in order that failed is the error.
pub(crate) async fn configure_sync_modes(
    link: &Link,
    slaves: &[SlaveInfo],
    cycle_ns: u32,
    sync_error_limit: Option<u16>,
    oversampled: &[Oversampled],
) -> Result<(), MasterError> {
    let each = link
        .side_by_side(
            slaves.iter().collect(),
            |l, s: &SlaveInfo| async move {
                let plan = SyncUnitPlan::of(s.position, oversampled, cycle_ns);
                configure_sync_mode(&l, s, cycle_ns, sync_error_limit, plan)
                    .await
                    .map_err(|e| e.at(Phase::PreOp, s.id()))
            },
            "sync mode",
        )
        .await?;
    each.into_iter().collect()
}

/// Part of [`Phase::PreOp`], in PRE-OP: a drive with CoE and a system time is switched to DC
/// SYNC0 synchronisation the way masters do it (ETG.1020 section 12): 0x1C32:01 and 0x1C33:01
/// = 2 (3, DC SYNC1, for an oversampled slave: `plan`), and 0x1C32:02 the cycle time; then, when one is configured, the sync error counter
/// limit 0x10F1:02 ([`BringupConfig::sync_error_limit`]). An object the drive does not have is
/// skipped (not every device has its SyncManager parameters or error settings), and so is a
/// read-only cycle time; any other abort is an error.
pub(crate) async fn configure_sync_mode(
    link: &Link,
    s: &SlaveInfo,
    cycle_ns: u32,
    sync_error_limit: Option<u16>,
    plan: SyncUnitPlan,
) -> Result<(), MasterError> {
    let Some(m) = s.mailbox.filter(|m| m.coe()) else {
        return Ok(());
    };
    if s.dc != DcCapability::SystemTime {
        return Ok(());
    }
    let mut c = crate::coe::SdoClient::new(link, s.station, m);
    let limit = sync_error_limit.map(u16::to_le_bytes);
    let mode = if plan.sync1_cycle_ns.is_some() {
        3u16
    } else {
        2
    };
    let writes: [(u16, u8, &[u8]); 3] = [
        (0x1c32, 1, &mode.to_le_bytes()),
        (0x1c32, 2, &cycle_ns.to_le_bytes()),
        (0x1c33, 1, &mode.to_le_bytes()),
    ];
    let limit_write = limit.as_ref().map(|v| (0x10f1u16, 2u8, &v[..]));
    for (index, sub, v) in writes.into_iter().chain(limit_write) {
        match c.download(index, sub, v).await {
            Ok(()) => {}
            // Not there: the drive has no such parameter (0x06020000, 0x06090011).
            Err(MasterError::SdoAbort {
                code: 0x0602_0000 | 0x0609_0011,
                ..
            }) => {}
            // A sync mode the drive refuses (0x06090030, value range exceeded: its 0x1C32:04
            // has no DC SYNC0): it runs on its own, as a drive without the objects does.
            Err(MasterError::SdoAbort {
                code: 0x0609_0030, ..
            }) if sub == 1 => return Ok(()),
            // A cycle time the drive does not let the master set (read-only, 0x06010002): it
            // keeps its own and follows SYNC0. Devices differ here: ecsync's drive has 0x1C32:02
            // rw in PRE-OP, Ingenia's EVS-NET-01 ESI has it `ro`.
            Err(MasterError::SdoAbort {
                code: 0x0601_0002, ..
            }) if (index, sub) == (0x1c32, 2) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// [`Phase::ProcessData`]: each slave's process data SyncManagers and an FMMU for each, mapped
/// where [`map_process_image`] placed them (several of one direction one after the other);
/// returns the LRW working counter OP must show: 2 per slave that takes outputs and 1 per
/// slave that gives inputs, however many FMMUs it has (an ESC counts a datagram once).
pub(crate) async fn configure_process_data(
    link: &Link,
    slaves: &[SlaveInfo],
) -> Result<u16, MasterError> {
    let each = link
        .side_by_side(
            slaves.iter().collect(),
            |l, s| async move { configure_process_data_of(&l, s).await },
            "process data",
        )
        .await?;
    each.into_iter()
        .try_fold(0u16, |sum, wkc| Ok(sum.saturating_add(wkc?)))
}

/// [`configure_process_data`] of one slave: its share of the LRW working counter.
async fn configure_process_data_of(link: &Link, s: &SlaveInfo) -> Result<u16, MasterError> {
    let mut expected_lrw_wkc = 0u16;
    let mut fmmu_n = 0u16;
    // The next logical address of each direction's SyncManagers.
    let (mut next_out, mut next_in) = (s.outputs.0, s.inputs.0);
    for sm in &s.sms {
        let len = sm.len;
        if len == 0 {
            continue;
        }
        let next = if sm.kind == 3 {
            &mut next_out
        } else {
            &mut next_in
        };
        let log = *next;
        *next += u32::from(len);
        // The SII's control byte, as the slave describes its buffer (a reserved mode or
        // direction is the slave's error, reported, never written).
        let control = SmControl::from_bits(sm.control).map_err(|_| {
            MasterError::BadReply("SII SyncManager control").at(Phase::ProcessData, s.id())
        })?;
        let smr = SyncManagerRepr {
            physical_start: sm.start,
            length_bytes: len,
            control,
            activate: SmActivate {
                enable: true,
                ..SmActivate::default()
            },
            ..SyncManagerRepr::default()
        }
        .to_bytes();
        link.fpwr(
            s.station,
            reg::SM_BASE + u16::from(sm.index) * reg::SM_LEN,
            &smr,
            "configure SyncManager",
        )
        .await
        .map_err(|e| e.at(Phase::ProcessData, s.id()))?;
        // Whole bytes: start bit 0, end bit 7; outputs (SII type 3) written by the master.
        let f = FmmuRepr {
            logical_start: log,
            length_bytes: len,
            logical_start_bit: 0,
            logical_end_bit: 7,
            physical_start: sm.start,
            physical_start_bit: 0,
            read: sm.kind != 3,
            write: sm.kind == 3,
            active: true,
        }
        .to_bytes();
        link.fpwr(
            s.station,
            reg::FMMU_BASE + fmmu_n * reg::FMMU_LEN,
            &f,
            "configure FMMU",
        )
        .await
        .map_err(|e| e.at(Phase::ProcessData, s.id()))?;
        fmmu_n += 1;
    }
    if s.outputs.1 > 0 {
        expected_lrw_wkc += 2;
    }
    if s.inputs.1 > 0 {
        expected_lrw_wkc += 1;
    }
    Ok(expected_lrw_wkc)
}
