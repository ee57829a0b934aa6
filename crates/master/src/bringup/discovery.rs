//! The bring-up's first phases: scan, reset, station addresses, identity and the DC probe.

use super::config::{BringupConfig, Stage};
use crate::MasterError;
use crate::io::{Link, Pdu};
use crate::network::{DcCapability, MailboxInfo, Phase, SlaveId, SlaveInfo, SmConfig};
use crate::sii::{SiiReader, pdo_bits_for_sm};
use ecsync_wire::dl::DlStatus;
use ecsync_wire::register::{self as reg};
use ecsync_wire::sii::{self, category};
use ecsync_wire::{AlControlRepr, AlState, Command, DatagramAddress};

/// What [`scan`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Scanned {
    /// Slaves that answered the broadcast (at least one).
    pub(super) count: u16,
}

/// [`Phase::Scan`]: counts the slaves by the working counter of a broadcast read.
pub(super) async fn scan(link: &Link) -> Result<Scanned, MasterError> {
    let count = link
        .pdu(
            Command::Brd,
            DatagramAddress::position(0, reg::TYPE),
            vec![0],
            "count slaves",
        )
        .await?
        .wkc;
    if count == 0 {
        return Err(MasterError::NoSlaves);
    }
    Ok(Scanned { count })
}

/// [`Phase::Reset`]: INIT with error acknowledge, FMMUs and SyncManagers cleared, SYNC off, in
/// one exchange of broadcast writes.
pub(super) async fn reset(link: &Link) -> Result<(), MasterError> {
    let init = AlControlRepr {
        state: AlState::Init,
        error_ack: true,
        id_request: false,
    };
    let mut reset = vec![Pdu::new(
        Command::Bwr,
        DatagramAddress::position(0, reg::AL_CONTROL),
        init.to_bytes().to_vec(),
    )];
    for n in 0..16 {
        reset.push(Pdu::new(
            Command::Bwr,
            DatagramAddress::position(0, reg::FMMU_BASE + n * reg::FMMU_LEN),
            vec![0; 16],
        ));
        reset.push(Pdu::new(
            Command::Bwr,
            DatagramAddress::position(0, reg::SM_BASE + n * reg::SM_LEN),
            vec![0; 8],
        ));
    }
    reset.push(Pdu::new(
        Command::Bwr,
        DatagramAddress::position(0, reg::DC_ACTIVATION),
        vec![0],
    ));
    link.pdus(&reset, "reset").await?;
    Ok(())
}

/// What [`assign_station_addresses`] set up: every slave, addressable by station.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Addressed {
    /// In network order.
    pub(super) slaves: Vec<SlaveId>,
}

/// [`Phase::StationAddresses`]: slave k gets station `STATION_BASE + k`.
pub(super) async fn assign_station_addresses(
    link: &Link,
    scanned: Scanned,
) -> Result<Addressed, MasterError> {
    let slaves: Vec<SlaveId> = (0..scanned.count).map(SlaveId::at_position).collect();
    // Every slave's APWR in one exchange (a long line's round trip is milliseconds: one by
    // one, a 2 000-drive line took 3.9 s). Each names its slave by position, which no earlier
    // datagram of the exchange changes.
    let writes: Vec<Pdu> = slaves
        .iter()
        .map(|id| {
            Pdu::new(
                Command::Apwr,
                DatagramAddress::position(id.position, reg::STATION_ADDRESS),
                id.station.to_le_bytes().to_vec(),
            )
        })
        .collect();
    let (replies, _) = link.pdus(&writes, "set station address").await?;
    for (r, &id) in replies.iter().zip(&slaves) {
        if r.wkc != 1 {
            return Err(MasterError::WorkingCounter {
                command: Command::Apwr,
                what: "set station address",
                expected: 1,
                got: r.wkc,
            }
            .at(Phase::StationAddresses, id));
        }
    }
    Ok(Addressed { slaves })
}

/// [`Phase::Identify`]: what every slave is; see [`identify_slave`].
pub(super) async fn identify(
    link: &Link,
    addressed: &Addressed,
    cfg: &BringupConfig,
) -> Result<Vec<SlaveInfo>, MasterError> {
    // Side by side: a long line's round trip is milliseconds, and one slave's identification
    // takes hundreds of exchanges (most of them EEPROM commands and busy polls).
    let each = link
        .side_by_side(
            addressed.slaves.clone(),
            |l, id| async move {
                identify_slave(&l, id, cfg)
                    .await
                    .map_err(|e| e.at(Phase::Identify, id))
            },
            "identify",
        )
        .await?;
    each.into_iter().collect()
}

/// ESC type, features and open ports, whether it keeps a system time (see
/// [`take_eeprom_probing_system_time`]), then the SII: identity always; the device name and
/// the process data SyncManagers (with their PDO sizes) only when the bring-up goes beyond
/// the delays, since they cost many EEPROM reads.
pub(super) async fn identify_slave(
    link: &Link,
    id: SlaveId,
    cfg: &BringupConfig,
) -> Result<SlaveInfo, MasterError> {
    let SlaveId {
        position: pos,
        station,
    } = id;
    let (r, _) = link
        .pdus(
            &[
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::configured(station, 0x0000),
                    vec![0; 16],
                ),
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::configured(station, reg::STATION_ALIAS),
                    vec![0; 2],
                ),
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::configured(station, reg::DL_STATUS),
                    vec![0; 2],
                ),
            ],
            "read ESC information",
        )
        .await?;
    for p in &r {
        if p.wkc != 1 {
            return Err(MasterError::WorkingCounter {
                command: Command::Fprd,
                what: "read ESC information",
                expected: 1,
                got: p.wkc,
            });
        }
    }
    let info = &r[0].data;
    let feats = u16::from_le_bytes([info[8], info[9]]);
    let dls = DlStatus::new_checked(&r[2].data[..])
        .map_err(|_| MasterError::BadReply("DL status shorter than its register"))?;
    let open = dls.ports().map(|p| p.open());
    let system_time = take_eeprom_probing_system_time(link, station).await?;
    let mut sii =
        SiiReader::new(link, station).with_busy_timeout_ns(cfg.timeouts.sii_busy_timeout_ns);
    let id_bytes = sii.read(sii::WORD_VENDOR_ID, 16).await?;
    let identity = sii::identity(&{
        let mut img = vec![0u8; 16];
        img.extend_from_slice(&id_bytes);
        img
    })
    .map_err(|_| MasterError::Sii {
        slave: station,
        what: "identity unreadable",
    })?;
    let details = cfg.until > Stage::Delays || cfg.read_sii_details;
    let name = if !details {
        String::new()
    } else {
        match (
            sii.category(category::GENERAL).await?,
            sii.category(category::STRINGS).await?,
        ) {
            (Some(g), Some(s)) if g.len() > sii::general::NAME_IDX => {
                sii::string(&s, g[sii::general::NAME_IDX])
                    .map(|b| String::from_utf8_lossy(b).into_owned())
                    .unwrap_or_default()
            }
            _ => String::new(),
        }
    };
    // The standard mailbox (SOEM and ethercrab read these words of every slave).
    let mailbox = if details {
        let w = sii.read(sii::WORD_STD_RX_MAILBOX_OFFSET, 10).await?;
        let word = |k: usize| u16::from_le_bytes([w[2 * k], w[2 * k + 1]]);
        let m = MailboxInfo {
            out_start: word(0),
            out_len: word(1),
            in_start: word(2),
            in_len: word(3),
            protocols: word(4),
        };
        // (An erased EEPROM reads 0xFFFF.)
        (m.out_len > 0 && m.in_len > 0 && m.out_len != 0xffff && m.in_len != 0xffff).then_some(m)
    } else {
        None
    };
    let mut sms = Vec::new();
    let smcat = if details {
        sii.category(category::SYNC_MANAGER).await?
    } else {
        None
    };
    if let Some(smcat) = smcat {
        let tx = sii.category(category::TXPDO).await?.unwrap_or_default();
        let rx = sii.category(category::RXPDO).await?.unwrap_or_default();
        for (i, e) in smcat.chunks_exact(8).enumerate() {
            let kind = e[7];
            let bits = match kind {
                3 => pdo_bits_for_sm(&rx, i as u8),
                4 => pdo_bits_for_sm(&tx, i as u8),
                _ => continue,
            };
            sms.push(SmConfig {
                index: i as u8,
                start: u16::from_le_bytes([e[0], e[1]]),
                control: e[4],
                kind,
                len: bits.div_ceil(8) as u16,
            });
        }
    }
    // Receive times are probed later, on the slaves without a system time ([`probe_dc`]).
    let dc = if system_time {
        DcCapability::SystemTime
    } else {
        DcCapability::None
    };
    Ok(SlaveInfo {
        position: pos,
        station,
        alias: u16::from_le_bytes([r[1].data[0], r[1].data[1]]),
        esc_type: info[0],
        features: feats,
        identity,
        vendor_id: identity.vendor_id,
        product_code: identity.product_code,
        serial: identity.serial,
        revision: identity.revision,
        port_descriptor: info[7],
        name,
        dc,
        open_ports: open,
        parent: None,
        entry_port: 0,
        delay_ns: None,
        delay_spread_ns: None,
        offset: None,
        ppm_vs_reference: None,
        outputs: (0, 0),
        inputs: (0, 0),
        sms,
        mailbox,
    })
}

/// Takes the EEPROM for the EtherCAT side as [`SiiReader::take_ownership`] does (0x0500 =
/// 0x02, then 0x00) and reads the system time offset (0x0920) in the second frame: whether that
/// read counts is whether the slave keeps a system time. 0x0008's DC bit does not say it: the
/// EL2828, EL1004, EK1914 and EL3004 set it and latch receive times, yet every access to
/// 0x0910-0x0930 gets working counter 0 there (../shared/captures/README.md; the EL2828's
/// 0x0910, 0x0918, 0x0920 and 0x092C in replay-dc.pcapng). The system time's registers exist
/// together or not at all; of them the offset is read, which the master writes next, and whose
/// read leaves the virtual segment's clocks as they were (a read of 0x0910 brings the simulated
/// clock to the read's instant, which moves later figures in their last bits). The read rides in
/// the frame's padding (a 1-byte write is a 29-byte frame, the read adds 20, under the 60-byte
/// Ethernet minimum): it costs no wire time, and a bring-up takes as long as before.
async fn take_eeprom_probing_system_time(link: &Link, station: u16) -> Result<bool, MasterError> {
    link.fpwr(station, reg::SII_CONFIG, &[0x02], "SII owner")
        .await?;
    let (r, _) = link
        .pdus(
            &[
                Pdu::new(
                    Command::Fpwr,
                    DatagramAddress::configured(station, reg::SII_CONFIG),
                    vec![0x00],
                ),
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::configured(station, reg::DC_SYSTEM_TIME_OFFSET),
                    vec![0; 8],
                ),
            ],
            "SII owner",
        )
        .await?;
    if r[0].wkc != 1 {
        return Err(MasterError::WorkingCounter {
            command: Command::Fpwr,
            what: "SII owner",
            expected: 1,
            got: r[0].wkc,
        });
    }
    Ok(r[1].wkc == 1)
}

/// The slave whose system time the others follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct ReferenceClock {
    /// Its index in the slave list (its position).
    pub(super) index: usize,
    /// Its position and station.
    pub(super) id: SlaveId,
}

/// [`Phase::DcProbe`]: slaves without a system time (whose read of 0x0920 did not count, see
/// [`identify_slave`]) may still have receive times (junctions must, and terminals such as the
/// EL2828 do): probe 0x0900 with a read and see who counts it. The reference clock is the
/// first slave with a system time.
pub(super) async fn probe_dc(
    link: &Link,
    slaves: &mut [SlaveInfo],
) -> Result<ReferenceClock, MasterError> {
    for s in slaves.iter_mut().filter(|s| s.dc == DcCapability::None) {
        let r = link
            .pdu(
                Command::Fprd,
                DatagramAddress::configured(s.station, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 4],
                "probe receive times",
            )
            .await
            .map_err(|e| e.at(Phase::DcProbe, s.id()))?;
        if r.wkc == 1 {
            s.dc = DcCapability::ReceiveTimes;
        }
    }
    let index = slaves
        .iter()
        .position(|s| s.dc == DcCapability::SystemTime)
        .ok_or(MasterError::NoReferenceClock)?;
    Ok(ReferenceClock {
        index,
        id: slaves[index].id(),
    })
}
