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
use crate::io::{Event, Link, Pdu, PduReply};
use crate::sii::{SiiReader, pdo_bits_for_sm};
use ecsync_dc::{LockDetector, SlavePorts, TreeNode, build_tree, propagation_delays};
use ecsync_wire::register::{self as reg, dl_status, features};
use ecsync_wire::sii::{self, Identity, category};
use ecsync_wire::{
    AlControlRepr, AlState, AlStatus, AlStatusCode, Command, DatagramAddress, FmmuRepr, SmActivate,
    SmControl, SmDirection, SmMode, SyncManagerRepr, dc_time,
};
use std::fmt;

/// First configured station address; slave k gets `STATION_BASE + k`.
pub const STATION_BASE: u16 = 0x1000;

/// Forwarding and processing delay of an ESC, as a master learns them from the ESI. Needed for
/// exact delays when ESCs of different kinds share a segment (see `ecsync_dc::topology`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct EsiTiming {
    /// Vendor ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Forwarding delay tF, ns.
    pub forwarding_ns: i32,
    /// Processing delay tP, ns.
    pub processing_ns: i32,
}

/// Where the bring-up stops.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Stage {
    /// After measuring propagation delays (identity only from the SII, nothing written).
    Delays,
    /// After offsets, static drift compensation and lock.
    Lock,
    /// After SYNC0, process data mapping and OP, with the cyclic frame monitored.
    Op,
}

/// How far to bring the network up and how.
#[derive(Debug, Clone, PartialEq)]
pub struct BringupConfig {
    /// Where to stop.
    pub until: Stage,
    /// Latches of the receive times whose delays are averaged.
    pub latch_rounds: u32,
    /// The latch rounds are spread over this much master time, ns: long enough that each
    /// slave's clock rate relative to the master can be measured from its first and last port 0
    /// stamps (20 ms at 25 ppm is 500 ns of drift, a clear signal over the 40 ns stamp
    /// resolution) and the spans corrected for it, short against the rest of the bring-up.
    pub latch_window_ns: u64,
    /// The least gap between two latch rounds, ns, however many rounds share the window: a
    /// frame and its read-back must have left the segment before the next latch.
    pub latch_min_gap_ns: u64,
    /// Separate FRMW frames of static drift compensation (the datasheet recommends ~15000).
    pub static_drift_frames: u32,
    /// Read every slave's 0x092C after this many static drift frames.
    pub check_every_frames: u32,
    /// Lock when every |0x092C| stays below this, ns.
    pub lock_threshold_ns: u32,
    /// ... for this many consecutive checks.
    pub lock_hold_checks: u32,
    /// Cycle time of the cyclic phase and SYNC0, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift: SYNC0 fires this long after the cycle's grid point, ns.
    pub sync0_shift_ns: u32,
    /// How far ahead of the current system time SYNC0 starts, ns.
    pub sync0_lead_ns: u64,
    /// Cycles to run in the cyclic frame after OP, monitoring 0x092C.
    pub monitor_cycles: u32,
    /// ESI timing of known ESCs.
    pub esi: Vec<EsiTiming>,
    /// The master stamps its frames in hardware (send: first bit on the wire; receive: first
    /// bit of the returned frame) and is itself the DC reference, as in the TSN paper: measure
    /// its delay to the reference from the latch frames' round trips and set the reference's
    /// system time to the master's clock at the frame's arrival (instead of at its send).
    pub master_is_reference: bool,
    /// How long each wait of the bring-up may last.
    pub timeouts: BringupTimeouts,
    /// Measure every slave's crystal against the reference's (and the reference's against the
    /// master's clock) from port receive times latched over this much master time, ns, right
    /// after the delays, while the local clocks are still uncorrected ([`measure_clock_rates`]).
    /// 0: not measured. A twin of the network (`ecsync run --save-network`) needs it; 2 s
    /// resolves 0.02 ppm with 40 ns stamps.
    pub rate_window_ns: u64,
    /// Read the SII's device name, mailbox and SyncManagers even when the bring-up stops after
    /// the delays (a twin of the network names and types its devices from them).
    pub read_sii_details: bool,
    /// The sync error counter limit (0x10F1:02, ETG.1020's error settings) written over CoE to
    /// every drive set to DC SYNC0, in PRE-OP with the sync mode, as a master's startup SDO
    /// does (TwinCAT's startup list, IgH's `ecrt_slave_config_sdo16`). Past it a drive leaves
    /// OP with AL status code 0x001A; 0 switches its reaction off (SSC V5.13, `DC_CheckWatchdog`:
    /// a limit of 0 keeps the SM-Sync sequence valid). `None`: not written, every drive keeps
    /// its own (the virtual drive's is 0).
    pub sync_error_limit: Option<u16>,
}

impl Default for BringupConfig {
    fn default() -> Self {
        BringupConfig {
            until: Stage::Op,
            latch_rounds: 64,
            latch_window_ns: 20_000_000,
            latch_min_gap_ns: 2_000,
            static_drift_frames: 15_000,
            check_every_frames: 100,
            lock_threshold_ns: 100,
            lock_hold_checks: 1_000,
            cycle_ns: 1_000_000,
            sync0_shift_ns: 300_000,
            sync0_lead_ns: 100_000_000,
            monitor_cycles: 1_000,
            esi: Vec::new(),
            master_is_reference: false,
            timeouts: BringupTimeouts::default(),
            rate_window_ns: 0,
            read_sii_details: false,
            sync_error_limit: None,
        }
    }
}

impl BringupConfig {
    /// Checks what the bring-up cannot run with (before any frame is sent).
    fn validate(&self) -> Result<(), MasterError> {
        if self.cycle_ns == 0 || self.sync0_shift_ns >= self.cycle_ns {
            return Err(MasterError::Config(format!(
                "cycle {} ns and SYNC0 shift {} ns: the shift must lie within the cycle",
                self.cycle_ns, self.sync0_shift_ns
            )));
        }
        Ok(())
    }
}

/// How long the bring-up waits for the network, master time. Each wait polls by exchanging
/// frames, so a timeout bounds both the time and the frames a dead or refusing slave costs.
/// (How long one frame is waited for, and how often a lost one is sent again, is the driver's
/// [`crate::driver::ProcedureConfig`].)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BringupTimeouts {
    /// How long a slave's SII EEPROM may stay busy with one command, ns. 100 ms: an EEPROM
    /// read of 8 bytes over I2C takes well under a millisecond, SOEM allows 20 ms and ethercrab
    /// 10 ms; the margin covers slow EEPROMs and a host that stalls during the poll, and a
    /// missing EEPROM still fails in a tenth of a second.
    pub sii_busy_timeout_ns: u64,
    /// How long one slave may take to report a requested AL state (PRE-OP, SAFE-OP), ns. 5 s:
    /// a slave's application may take seconds to accept a state (it checks its SyncManagers,
    /// starts its firmware's tasks); ethercrab waits 5 s, SOEM 2 s.
    pub state_timeout_ns: u64,
    /// The pause between two reads of AL status while waiting for a state, ns. 100 us: a state
    /// reached is seen within a tenth of a millisecond, and the wait costs at most one frame
    /// per 100 us on the wire.
    pub state_poll_interval_ns: u64,
    /// How long the whole network may take to report OP with the cyclic frame running, ns.
    /// 10 s, twice a single state change: a slave enters OP only once it has seen valid
    /// process data and its SYNC0 running, and all slaves must get there.
    pub op_timeout_ns: u64,
    /// Give up if the network is not locked this long after the static drift compensation,
    /// ns. 30 s: the time control loops pull in a few ppm of crystal difference in seconds;
    /// the timeout runs from the end of the static drift compensation, whose length grows with
    /// the network, so large networks get the same allowance.
    pub lock_timeout_ns: u64,
}

impl Default for BringupTimeouts {
    fn default() -> Self {
        BringupTimeouts {
            sii_busy_timeout_ns: crate::sii::BUSY_TIMEOUT_NS,
            state_timeout_ns: 5_000_000_000,
            state_poll_interval_ns: 100_000,
            op_timeout_ns: 10_000_000_000,
            lock_timeout_ns: 30_000_000_000,
        }
    }
}

/// A phase of the bring-up, in the order [`bringup`] runs them. Its [`Display`](fmt::Display)
/// is the name progress lines and errors use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Phase {
    /// Counting the slaves (a broadcast read of the ESC type).
    Scan,
    /// Every slave to INIT (errors acknowledged), FMMUs and SyncManagers cleared, SYNC off.
    Reset,
    /// Configured station addresses, by auto-increment position.
    StationAddresses,
    /// ESC type, features and ports, the SII identity; with [`Stage::Lock`] and beyond also the
    /// device name and the process data SyncManagers.
    Identify,
    /// Which slaves without the DC feature have receive times; the reference clock.
    DcProbe,
    /// Receive time latches, topology and propagation delays.
    Delays,
    /// System time offsets and delays written, the time control loop filters reset.
    Offsets,
    /// Static drift compensation: FRMW frames with lock checks.
    StaticDrift,
    /// Cyclic FRMW until every slave's 0x092C holds below the threshold.
    Lock,
    /// INIT to PRE-OP.
    PreOp,
    /// SyncManagers and FMMUs of the process data.
    ProcessData,
    /// SYNC0 programmed on the reference's system time grid.
    Sync0,
    /// PRE-OP to SAFE-OP.
    SafeOp,
    /// SAFE-OP to OP with the cyclic frame running.
    Op,
    /// The cyclic frame in OP, 0x092C and the process data working counter watched.
    Monitor,
}

impl Phase {
    /// The phase's name, as progress lines and errors print it.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Scan => "scan",
            Phase::Reset => "reset",
            Phase::StationAddresses => "station addresses",
            Phase::Identify => "identify",
            Phase::DcProbe => "DC probe",
            Phase::Delays => "delays",
            Phase::Offsets => "offsets",
            Phase::StaticDrift => "drift",
            Phase::Lock => "lock",
            Phase::PreOp => "pre-op",
            Phase::ProcessData => "process data",
            Phase::Sync0 => "sync0",
            Phase::SafeOp => "safe-op",
            Phase::Op => "op",
            Phase::Monitor => "monitor",
        }
    }
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A slave as errors name it: where it sits and the address the master gave it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SlaveId {
    /// Auto-increment position (network order, from 0).
    pub position: u16,
    /// Configured station address.
    pub station: u16,
}

impl SlaveId {
    /// The slave at `position`, with the station address this bring-up gives it.
    fn at_position(position: u16) -> Self {
        SlaveId {
            position,
            station: STATION_BASE + position,
        }
    }
}

impl fmt::Display for SlaveId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "slave {} (station {:#06x})", self.position, self.station)
    }
}

/// DC capability as read from 0x0008 and the presence of receive times.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DcCapability {
    /// No DC.
    None,
    /// Port receive times only.
    ReceiveTimes,
    /// System time (can be synchronised).
    SystemTime,
}

/// What the master learned about one slave.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SlaveInfo {
    /// Auto-increment position (network order).
    pub position: u16,
    /// Configured station address.
    pub station: u16,
    /// Station alias.
    pub alias: u16,
    /// ESC type.
    pub esc_type: u8,
    /// ESC features (0x0008).
    pub features: u16,
    /// SII identity.
    #[serde(skip)]
    pub identity: Identity,
    /// Vendor ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Serial number.
    pub serial: u32,
    /// Revision number (SII).
    pub revision: u32,
    /// Port descriptor (0x0007): two bits per port, 0b11 MII, 0b10 EBUS, 0b00 none.
    pub port_descriptor: u8,
    /// Device name from the SII strings.
    pub name: String,
    /// DC capability.
    pub dc: DcCapability,
    /// Open ports (DL status).
    pub open_ports: [bool; 4],
    /// Parent position and port, from the topology.
    pub parent: Option<(u16, u8)>,
    /// Entry port.
    pub entry_port: u8,
    /// Measured propagation delay from the reference, ns (mean over the latch rounds).
    pub delay_ns: Option<f64>,
    /// Spread (max - min) of the delay over the latch rounds, ns.
    pub delay_spread_ns: Option<f64>,
    /// System time offset written to 0x0920.
    pub offset: Option<u64>,
    /// Crystal error against the reference's, ppm: local time elapsed at this slave's entry
    /// port over the reference's between latches [`BringupConfig::rate_window_ns`] apart, minus
    /// one (`None`: not measured, or the slave has no receive times).
    pub ppm_vs_reference: Option<f64>,
    /// Output bytes (RxPDO) and where they sit in the logical process image.
    pub outputs: (u32, u16),
    /// Input bytes (TxPDO) and where they sit in the logical process image.
    pub inputs: (u32, u16),
    /// Output and input SyncManager indices and physical starts.
    #[serde(skip)]
    pub sms: Vec<SmConfig>,
    /// The mailbox, as the SII's words 0x18-0x1C give it (`None`: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mailbox: Option<MailboxInfo>,
}

/// A slave's standard mailbox (SII words 0x18-0x1C) and the SyncManagers that hold it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct MailboxInfo {
    /// SM0, master to slave: physical start.
    pub out_start: u16,
    /// SM0 length, bytes.
    pub out_len: u16,
    /// SM1, slave to master: physical start.
    pub in_start: u16,
    /// SM1 length, bytes.
    pub in_len: u16,
    /// The protocols (word 0x1C: bit 2 CoE).
    pub protocols: u16,
}

impl MailboxInfo {
    /// Whether the slave speaks CoE.
    pub fn coe(&self) -> bool {
        self.protocols & ecsync_wire::mailbox::MailboxType::Coe.protocol_bit() != 0
    }
}

impl SlaveInfo {
    /// Position and station address.
    pub fn id(&self) -> SlaveId {
        SlaveId {
            position: self.position,
            station: self.station,
        }
    }
}

/// A process data SyncManager as the SII describes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SmConfig {
    /// Index.
    pub index: u8,
    /// Physical start.
    pub start: u16,
    /// Control byte.
    pub control: u8,
    /// 3 = outputs, 4 = inputs.
    pub kind: u8,
    /// Bytes (from the PDOs assigned to it).
    pub len: u16,
}

/// The outcome of lock detection.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LockReport {
    /// Whether every |0x092C| stayed below the threshold.
    pub converged: bool,
    /// From the start of drift compensation to the first check of the run that held, ns.
    pub time_to_lock_ns: Option<u64>,
    /// Master time when drift compensation started, ns.
    pub drift_start_ns: u64,
    /// Master time when the master declared the network in sync (the good run had lasted
    /// `lock_hold_checks` checks), ns.
    pub declared_ns: Option<u64>,
    /// Largest |0x092C| seen while monitoring after lock, ns.
    pub max_abs_092c_after_lock_ns: u32,
    /// The monitoring read 0x092C by one broadcast (a network whose reads per slave would not
    /// fit the cycle): [`LockReport::max_abs_092c_after_lock_ns`] is the OR of every slave's
    /// magnitude, a bound on the largest rather than the largest.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub max_abs_092c_by_broadcast: bool,
    /// FRMW frames sent before lock.
    pub frmw_frames: u64,
}

/// SYNC0 as programmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Sync0Config {
    /// Start time (system time) of the first slave programmed, ns. The others start on the same
    /// grid, whole cycles later where their programming came too close to it.
    pub start_ns: u64,
    /// Cycle, ns.
    pub cycle_ns: u32,
    /// Shift within the cycle, ns.
    pub shift_ns: u32,
}

/// The network as brought up.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Network {
    /// Slaves in network order.
    pub slaves: Vec<SlaveInfo>,
    /// Position of the reference clock.
    pub reference: u16,
    /// Lock detection.
    pub lock: LockReport,
    /// SYNC0, when configured.
    pub sync0: Option<Sync0Config>,
    /// Bytes of the logical process image (outputs then inputs).
    pub pdi_len: u32,
    /// Its LRWs in the cyclic exchange (one when it fits a frame).
    #[serde(skip)]
    pub lrw: Vec<crate::pdi::LrwChunk>,
    /// Expected LRW working counter in OP.
    pub expected_lrw_wkc: u16,
    /// Master time when bring-up finished, ns.
    pub done_ns: u64,
    /// With [`BringupConfig::master_is_reference`]: the master's delay to the reference's
    /// processing unit, ns (mean over the latch rounds), and its spread (max - min).
    pub master_delay_ns: Option<f64>,
    /// Spread of the master delay over the rounds, ns.
    pub master_delay_spread_ns: Option<f64>,
    /// The reference's crystal against the master's clock, ppm (a least-squares fit of its
    /// entry port stamps on the master's send stamps over [`BringupConfig::rate_window_ns`]):
    /// only as good as the master's send stamps, microseconds off on a loaded host, so a few
    /// tenths of a ppm over 2 s (`None`: not measured).
    pub reference_ppm_vs_master: Option<f64>,
    /// The reference's system time as the bring-up's last FRMW read it, with the master's
    /// time of that frame's send (`None` if the bring-up stopped before OP): where the
    /// reference's grid lies against the master's clock when the cyclic phase begins. The
    /// offsets made the two agree, but the reference's crystal has run against the master's
    /// since, over the whole configuration (a large network's takes tens of seconds: a
    /// 1 000-drive line's reference was 440 us from the master's time at its end).
    #[serde(skip)]
    pub reference_reading: Option<ReferenceReading>,
}

/// The reference's system time read by an FRMW, and when the master sent that frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReferenceReading {
    /// Master time right before the frame was sent, ns.
    pub master_sent_ns: u64,
    /// The reference's system time as the frame passed it (a 32-bit reference's extended next
    /// to the master's time), ns.
    pub reference_ns: u64,
}

impl ReferenceReading {
    /// The reference's system time minus the master's time, ns. The frame's way from the
    /// master's send to the reference (the NIC's latency, the wire) is in it: a cyclic frame
    /// sent on this estimate passes the reference when the reference's time is where it
    /// should be.
    pub fn reference_minus_master_ns(&self) -> i64 {
        self.reference_ns.wrapping_sub(self.master_sent_ns) as i64
    }

    fn of(reply: &PduReply, master_sent_ns: u64) -> Option<Self> {
        if reply.wkc == 0 {
            return None;
        }
        let raw = u64::from_le_bytes(reply.data.get(..8)?.try_into().ok()?);
        // A 32-bit reference reads 0 in the upper half.
        let reference_ns = if raw >> 32 == 0 {
            ecsync_dc::sync::extend_reference_time(master_sent_ns, raw as u32)
        } else {
            raw
        };
        Some(ReferenceReading {
            master_sent_ns,
            reference_ns,
        })
    }
}

/// Master time right before the last frame was sent.
fn r_sent(link: &Link) -> u64 {
    link.last_sent_ns()
}

fn position_addr(pos: u16, ado: u16) -> DatagramAddress {
    DatagramAddress::position(pos, ado)
}

fn fp(station: u16, ado: u16) -> DatagramAddress {
    DatagramAddress::Configured { adp: station, ado }
}

/// The delay rounds dither their send instant across this span, ns: the receive time stamps'
/// resolution, so that the mean over the rounds resolves below it.
const LATCH_DITHER_NS: u64 = 40;

/// A clock rate (a slave's local time over master time) further than this from 1 is a
/// misread, not a crystal (crystals are within 100 ppm).
const PLAUSIBLE_RATE_ERROR: f64 = 1e-3;

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
    Ok(net.done_at(&link))
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
    for s in &net.slaves {
        configure_sync_mode(link, s, cfg.cycle_ns, cfg.sync_error_limit)
            .await
            .map_err(|e| e.at(Phase::PreOp, s.id()))?;
    }
    net.expected_lrw_wkc = configure_process_data(link, &net.slaves)
        .await
        .map_err(|e| e.during(Phase::ProcessData))?;

    link.event(Event::Phase(Phase::Sync0));
    net.sync0 = start_sync0(link, cfg, &net.slaves, dc)
        .await
        .map_err(|e| e.during(Phase::Sync0))?;

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
                .and_then(|p| ReferenceReading::of(p, reply.sent_ns)),
            Err(_) => None,
        },
    };
    Ok(())
}

impl Network {
    /// The network as it stands when the bring-up returns.
    fn done_at(mut self, link: &Link) -> Network {
        self.done_ns = link.now_ns();
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

/// What [`scan`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Scanned {
    /// Slaves that answered the broadcast (at least one).
    count: u16,
}

/// [`Phase::Scan`]: counts the slaves by the working counter of a broadcast read.
async fn scan(link: &Link) -> Result<Scanned, MasterError> {
    let count = link
        .pdu(
            Command::Brd,
            position_addr(0, reg::TYPE),
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
async fn reset(link: &Link) -> Result<(), MasterError> {
    let init = AlControlRepr {
        state: AlState::Init,
        error_ack: true,
        id_request: false,
    };
    let mut reset = vec![Pdu::new(
        Command::Bwr,
        position_addr(0, reg::AL_CONTROL),
        init.to_bytes().to_vec(),
    )];
    for n in 0..16 {
        reset.push(Pdu::new(
            Command::Bwr,
            position_addr(0, reg::FMMU_BASE + n * reg::FMMU_LEN),
            vec![0; 16],
        ));
        reset.push(Pdu::new(
            Command::Bwr,
            position_addr(0, reg::SM_BASE + n * reg::SM_LEN),
            vec![0; 8],
        ));
    }
    reset.push(Pdu::new(
        Command::Bwr,
        position_addr(0, reg::DC_ACTIVATION),
        vec![0],
    ));
    link.pdus(&reset, "reset").await?;
    Ok(())
}

/// What [`assign_station_addresses`] set up: every slave, addressable by station.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Addressed {
    /// In network order.
    slaves: Vec<SlaveId>,
}

/// [`Phase::StationAddresses`]: slave k gets station `STATION_BASE + k`.
async fn assign_station_addresses(link: &Link, scanned: Scanned) -> Result<Addressed, MasterError> {
    let slaves: Vec<SlaveId> = (0..scanned.count).map(SlaveId::at_position).collect();
    for &id in &slaves {
        link.pdu_wkc(
            Command::Apwr,
            position_addr(id.position, reg::STATION_ADDRESS),
            id.station.to_le_bytes().to_vec(),
            1,
            "set station address",
        )
        .await
        .map_err(|e| e.at(Phase::StationAddresses, id))?;
    }
    Ok(Addressed { slaves })
}

/// [`Phase::Identify`]: what every slave is; see [`identify_slave`].
async fn identify(
    link: &Link,
    addressed: &Addressed,
    cfg: &BringupConfig,
) -> Result<Vec<SlaveInfo>, MasterError> {
    let mut slaves = Vec::with_capacity(addressed.slaves.len());
    for &id in &addressed.slaves {
        let s = identify_slave(link, id, cfg)
            .await
            .map_err(|e| e.at(Phase::Identify, id))?;
        slaves.push(s);
    }
    Ok(slaves)
}

/// ESC type, features and open ports, then the SII: identity always; the device name and
/// the process data SyncManagers (with their PDO sizes) only when the bring-up goes beyond
/// the delays, since they cost many EEPROM reads.
async fn identify_slave(
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
                Pdu::new(Command::Fprd, fp(station, 0x0000), vec![0; 16]),
                Pdu::new(Command::Fprd, fp(station, reg::STATION_ALIAS), vec![0; 2]),
                Pdu::new(Command::Fprd, fp(station, reg::DL_STATUS), vec![0; 2]),
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
    let dls = u16::from_le_bytes([r[2].data[0], r[2].data[1]]);
    let open = core::array::from_fn(|p| {
        dls & dl_status::link(p) != 0 && dls & dl_status::loop_closed(p) == 0
    });
    let mut sii =
        SiiReader::new(link, station).with_busy_timeout_ns(cfg.timeouts.sii_busy_timeout_ns);
    sii.take_ownership().await?;
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
    let dc = if feats & features::DC != 0 {
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

/// The slave whose system time the others follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ReferenceClock {
    /// Its index in the slave list (its position).
    index: usize,
    /// Its position and station.
    id: SlaveId,
}

/// [`Phase::DcProbe`]: slaves without the DC feature may still have receive times (junctions
/// must): probe 0x0900 with a read and see who counts it. The reference clock is the first
/// slave with a system time.
async fn probe_dc(link: &Link, slaves: &mut [SlaveInfo]) -> Result<ReferenceClock, MasterError> {
    for s in slaves.iter_mut().filter(|s| s.dc == DcCapability::None) {
        let r = link
            .pdu(
                Command::Fprd,
                fp(s.station, reg::DC_RECEIVE_TIME_PORT0),
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

/// What the last latch of [`measure_delays`] leaves for the offsets.
#[derive(Debug, Clone, PartialEq)]
struct Latch {
    /// Master time right before the last latch frame was sent, ns.
    sent_ns: u64,
    /// Each slave's processing unit receive time (0x0918) of the last latch, ns (0 where the
    /// slave has no system time).
    pu_stamps_ns: Vec<u64>,
    /// With [`BringupConfig::master_is_reference`]: the master's delay to the reference, ns
    /// (mean over the rounds).
    master_delay_ns: Option<f64>,
    /// Its spread (max - min) over the rounds, ns.
    master_delay_spread_ns: Option<f64>,
}

/// [`Phase::Delays`]: propagation delays, averaged over latch rounds with the send instant
/// dithered across the receive stamps' 40 ns resolution. Records each slave's parent, entry
/// port and delay; returns the last latch for the offsets.
async fn measure_delays(
    link: &Link,
    cfg: &BringupConfig,
    slaves: &mut [SlaveInfo],
    reference: usize,
) -> Result<Latch, MasterError> {
    let n = slaves.len();
    let rounds = cfg.latch_rounds.max(1);
    let mut sums = vec![0.0f64; n];
    let mut mins = vec![f64::INFINITY; n];
    let mut maxs = vec![f64::NEG_INFINITY; n];
    let mut last_pu = vec![0u64; n];
    let mut latch_sent_ns = 0;
    let mut tree = vec![TreeNode::default(); n];
    let mut delays = vec![None; n];
    // The rounds are spread over the latch window so that each slave's clock rate relative to
    // the master can be measured from its first and last port 0 stamps and the spans corrected
    // for it.
    let gap_ns = (cfg.latch_window_ns / u64::from(rounds)).max(cfg.latch_min_gap_ns);
    let mut all_ports: Vec<Vec<SlavePorts>> = Vec::with_capacity(rounds as usize);
    let mut sent_at: Vec<u64> = Vec::with_capacity(rounds as usize);
    let mut round_trips: Vec<f64> = Vec::with_capacity(rounds as usize);
    for round in 0..rounds {
        let dither = u64::from(round) * LATCH_DITHER_NS / u64::from(rounds);
        let t = link.now_ns() + gap_ns + dither;
        link.sleep_until(t).await;
        let r = link
            .pdu(
                Command::Bwr,
                position_addr(0, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 4],
                "latch receive times",
            )
            .await?;
        let latch_sent = r_sent(link);
        round_trips.push(link.last_received_ns().wrapping_sub(latch_sent) as i64 as f64);
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
        // One FPRD of the four receive times per slave that has them, batched into as few
        // frames as fit; the processing unit's 64-bit stamp only in the last round (offsets).
        let last = round + 1 == rounds;
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
                fp(s.station, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 16],
            ));
            owners.push((i, false));
            if last && s.dc == DcCapability::SystemTime {
                reads.push(Pdu::new(
                    Command::Fprd,
                    fp(s.station, reg::DC_RECEIVE_TIME_PU),
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
                last_pu[i] = u64::from_le_bytes(t[..8].try_into().unwrap_or([0; 8]));
            } else {
                ports[i].times = Some(core::array::from_fn(|p| {
                    u32::from_le_bytes([t[4 * p], t[4 * p + 1], t[4 * p + 2], t[4 * p + 3]])
                }));
            }
        }
        all_ports.push(ports);
        sent_at.push(latch_sent);
        latch_sent_ns = latch_sent;
    }
    // Clock rates from the first and last latch: local time elapsed at the entry port over
    // master time elapsed.
    let master_span = sent_at
        .last()
        .copied()
        .unwrap_or(0)
        .saturating_sub(sent_at[0]) as f64;
    if rounds > 1 && master_span > 0.0 {
        for i in 0..n {
            let (Some(a), Some(b)) = (
                all_ports[0][i].times,
                all_ports[all_ports.len() - 1][i].times,
            ) else {
                continue;
            };
            let e = ecsync_dc::topology::entry_port(&all_ports[0][i]).unwrap_or(0);
            let local = f64::from(dc_time::diff_u32(b[usize::from(e)], a[usize::from(e)]));
            let rate = local / master_span;
            // Only plausible rates are used; anything else is a misread.
            if (rate - 1.0).abs() < PLAUSIBLE_RATE_ERROR {
                for round in all_ports.iter_mut() {
                    round[i].clock_rate = rate;
                }
            }
        }
    }
    let (mut md_sum, mut md_min, mut md_max) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for (round, ports) in all_ports.iter().enumerate() {
        build_tree(ports, &mut tree)?;
        propagation_delays(ports, &tree, reference, &mut delays)?;
        if cfg.master_is_reference {
            // Master -> first slave, then on to the reference (its delay relative to the
            // first slave is minus the first slave's delay relative to it).
            if let (Some(d0), Some(first)) = (
                ecsync_dc::master_delay_ns(round_trips[round], &ports[0], tree[0].entry_port),
                delays[0],
            ) {
                let d = d0 - first;
                md_sum += d;
                md_min = md_min.min(d);
                md_max = md_max.max(d);
            }
        }
        for (i, d) in delays.iter().enumerate() {
            if let Some(d) = d {
                sums[i] += d;
                mins[i] = mins[i].min(*d);
                maxs[i] = maxs[i].max(*d);
            }
        }
    }
    let (master_delay_ns, master_delay_spread_ns) = if cfg.master_is_reference && md_min.is_finite()
    {
        (Some(md_sum / f64::from(rounds)), Some(md_max - md_min))
    } else {
        (None, None)
    };
    for (i, s) in slaves.iter_mut().enumerate() {
        s.parent = tree[i].parent;
        s.entry_port = tree[i].entry_port;
        if s.dc == DcCapability::SystemTime && delays[i].is_some() {
            s.delay_ns = Some(sums[i] / f64::from(rounds));
            s.delay_spread_ns = Some(maxs[i] - mins[i]);
        }
    }
    Ok(Latch {
        sent_ns: latch_sent_ns,
        pu_stamps_ns: last_pu,
        master_delay_ns,
        master_delay_spread_ns,
    })
}

/// Latches of [`measure_clock_rates`]: one every this long, ns (at most; fewer over a short
/// window). Well under the 2.1 s in which a 32-bit receive time's difference stays unambiguous,
/// and many points for the fit.
const RATE_LATCH_STEP_NS: u64 = 20_000_000;

/// Least-squares slope of `y` on `x` (`None` with fewer than two distinct `x`).
fn slope(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    if n < 2 {
        return None;
    }
    let mx = x[..n].iter().sum::<f64>() / n as f64;
    let my = y[..n].iter().sum::<f64>() / n as f64;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for k in 0..n {
        sxy += (x[k] - mx) * (y[k] - my);
        sxx += (x[k] - mx) * (x[k] - mx);
    }
    (sxx > 0.0).then(|| sxy / sxx)
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
    let start = link.now_ns();
    for k in 0..latches {
        link.sleep_until(start + k * step_ns).await;
        let r = link
            .pdu(
                Command::Bwr,
                position_addr(0, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 4],
                "latch receive times",
            )
            .await?;
        let sent = r_sent(link);
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
                    fp(slaves[i].station, reg::DC_RECEIVE_TIME_PORT0),
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

/// [`Phase::Offsets`]: offsets from the last latch, written together with the delays in one
/// frame, then the loop filters reset (0x0934: time difference depth 0, speed counter depth
/// 12, as SOEM and ethercrab write; then 0x0930, whose write resets the filters). Records
/// each slave's offset.
async fn write_offsets(
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
        let offset = ecsync_dc::system_time_offset(ref_time, delay, latch.pu_stamps_ns[i]);
        s.offset = Some(offset);
        writes.push(Pdu::new(
            Command::Fpwr,
            fp(s.station, reg::DC_SYSTEM_TIME_DELAY),
            (delay as u32).to_le_bytes().to_vec(),
        ));
        writes.push(Pdu::new(
            Command::Fpwr,
            fp(s.station, reg::DC_SYSTEM_TIME_OFFSET),
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
struct DcGroup {
    /// The reference clock.
    reference: SlaveId,
    /// Every other slave with a system time, in network order.
    synced: Vec<SlaveId>,
}

impl DcGroup {
    fn of(slaves: &[SlaveInfo], reference: SlaveId) -> Self {
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
    fn frmw(&self) -> Pdu {
        Pdu::new(
            Command::Frmw,
            fp(self.reference.station, reg::DC_SYSTEM_TIME),
            vec![0; 8],
        )
    }

    /// One FPRD of 0x092C per synced slave.
    fn difference_reads(&self) -> impl Iterator<Item = Pdu> + '_ {
        self.synced.iter().map(|s| {
            Pdu::new(
                Command::Fprd,
                fp(s.station, reg::DC_SYSTEM_TIME_DIFF),
                vec![0; 4],
            )
        })
    }

    /// The reads of every synced slave's 0x092C, after an FRMW when `with_frmw`.
    fn check_pdus(&self, with_frmw: bool) -> Vec<Pdu> {
        let mut v = Vec::with_capacity(self.synced.len() + 1);
        if with_frmw {
            v.push(self.frmw());
        }
        v.extend(self.difference_reads());
        v
    }

    /// The largest |0x092C| of the replies to [`DcGroup::difference_reads`]; a slave that did
    /// not answer is named, in `phase`.
    fn worst_of(&self, replies: &[PduReply], phase: Phase) -> Result<u32, MasterError> {
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
struct Drift {
    /// The detector, fed by the checks so far.
    detector: LockDetector,
    /// Master time when drift compensation started, ns.
    start_ns: u64,
    /// FRMW frames sent.
    frmw_frames: u64,
}

/// [`Phase::StaticDrift`]: separate FRMW frames, every slave's 0x092C read after every
/// [`BringupConfig::check_every_frames`] of them.
async fn static_drift(
    link: &Link,
    cfg: &BringupConfig,
    dc: &DcGroup,
) -> Result<Drift, MasterError> {
    let start_ns = link.now_ns();
    let mut detector = LockDetector::new(cfg.lock_threshold_ns, cfg.lock_hold_checks.max(1));
    let mut frmw_frames = 0u64;
    for i in 0..cfg.static_drift_frames {
        let r = link
            .pdu(
                Command::Frmw,
                fp(dc.reference.station, reg::DC_SYSTEM_TIME),
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
            detector.update(dc.worst_of(&r, Phase::StaticDrift)?, link.now_ns());
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
struct CycleGrid {
    /// Cycle, ns.
    cycle_ns: u64,
    /// The next grid point, ns.
    next_ns: u64,
}

impl CycleGrid {
    /// The grid of `cycle_ns` from the first point after now.
    fn after_now(link: &Link, cycle_ns: u32) -> Self {
        let cycle_ns = u64::from(cycle_ns);
        CycleGrid {
            cycle_ns,
            next_ns: (link.now_ns() / cycle_ns + 1) * cycle_ns,
        }
    }

    /// Waits for the next grid point.
    async fn tick(&mut self, link: &Link) {
        link.sleep_until(self.next_ns).await;
        self.next_ns += self.cycle_ns;
    }
}

/// What [`wait_for_lock`] leaves: the lock report and the grid the cyclic frames go on on.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Locked {
    report: LockReport,
    grid: CycleGrid,
}

/// [`Phase::Lock`]: cyclic FRMW until locked. The timeout runs from the end of the static
/// drift compensation, whose length grows with the network (a frame passes every slave).
async fn wait_for_lock(
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
    let lock_start = link.now_ns();
    let timeout_ns = cfg.timeouts.lock_timeout_ns;
    while !synced.is_empty() && !lock.is_locked() {
        if link.now_ns().saturating_sub(lock_start) > timeout_ns {
            return Err(MasterError::NoLock(timeout_ns / 1_000_000));
        }
        grid.tick(link).await;
        let (r, _) = link.pdus(&dc.check_pdus(true), "cyclic DC").await?;
        frmw_frames += 1;
        lock.update(dc.worst_of(&r[1..], Phase::Lock)?, link.now_ns());
    }
    let report = LockReport {
        converged: synced.is_empty() || lock.is_locked(),
        time_to_lock_ns: if synced.is_empty() {
            Some(0)
        } else {
            lock.locked_at_ns().map(|t| t.saturating_sub(drift_start))
        },
        drift_start_ns: drift_start,
        declared_ns: (synced.is_empty() || lock.is_locked()).then(|| link.now_ns()),
        max_abs_092c_after_lock_ns: 0,
        max_abs_092c_by_broadcast: false,
        frmw_frames,
    };
    Ok(Locked { report, grid })
}

/// The logical process image, as [`map_process_image`] lays it out.
#[derive(Debug, Clone, PartialEq, Eq)]
struct ProcessImage {
    /// Bytes (outputs then inputs).
    pdi_len: u32,
    /// Its LRWs in the cyclic exchange.
    lrw: Vec<crate::pdi::LrwChunk>,
}

/// Process data mapping: outputs of all slaves, then inputs, in the logical image (recorded
/// in each slave's `outputs` and `inputs`). No frames: the SyncManagers and FMMUs are written
/// in [`Phase::ProcessData`].
fn map_process_image(slaves: &mut [SlaveInfo]) -> ProcessImage {
    let mut logical = 0u32;
    for s in slaves.iter_mut() {
        if let Some(sm) = s.sms.iter().find(|m| m.kind == 3) {
            s.outputs = (logical, sm.len);
            logical += u32::from(sm.len);
        }
    }
    for s in slaves.iter_mut() {
        if let Some(sm) = s.sms.iter().find(|m| m.kind == 4) {
            s.inputs = (logical, sm.len);
            logical += u32::from(sm.len);
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

/// [`Phase::PreOp`], [`Phase::SafeOp`]: requests `state` from every slave in turn and waits
/// for each ([`request_state`]).
async fn request_all(
    link: &Link,
    slaves: &[SlaveInfo],
    state: AlState,
    phase: Phase,
    timeouts: &BringupTimeouts,
) -> Result<(), MasterError> {
    for s in slaves {
        request_state(link, s.station, state, timeouts)
            .await
            .map_err(|e| e.at(phase, s.id()))?;
    }
    Ok(())
}

/// Part of [`Phase::PreOp`]: the mailbox SyncManagers of every slave that has a mailbox, in
/// INIT (a slave refuses PRE-OP without them: AL status code 0x0016): SM0 written by the
/// master, SM1 read, both in mailbox mode, as the SII's words give them.
pub(crate) async fn configure_mailboxes(
    link: &Link,
    slaves: &[SlaveInfo],
) -> Result<(), MasterError> {
    for s in slaves {
        let Some(m) = s.mailbox else { continue };
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
    }
    Ok(())
}

/// Part of [`Phase::PreOp`], in PRE-OP: a drive with CoE and a system time is switched to DC
/// SYNC0 synchronisation the way masters do it (ETG.1020 section 12): 0x1C32:01 and 0x1C33:01
/// = 2, and 0x1C32:02 the cycle time; then, when one is configured, the sync error counter
/// limit 0x10F1:02 ([`BringupConfig::sync_error_limit`]). An object the drive does not have is
/// skipped (not every device has its SyncManager parameters or error settings), and so is a
/// read-only cycle time; any other abort is an error.
pub(crate) async fn configure_sync_mode(
    link: &Link,
    s: &SlaveInfo,
    cycle_ns: u32,
    sync_error_limit: Option<u16>,
) -> Result<(), MasterError> {
    let Some(m) = s.mailbox.filter(|m| m.coe()) else {
        return Ok(());
    };
    if s.dc != DcCapability::SystemTime {
        return Ok(());
    }
    let mut c = crate::coe::SdoClient::new(link, s.station, m);
    let limit = sync_error_limit.map(u16::to_le_bytes);
    let writes: [(u16, u8, &[u8]); 3] = [
        (0x1c32, 1, &2u16.to_le_bytes()),
        (0x1c32, 2, &cycle_ns.to_le_bytes()),
        (0x1c33, 1, &2u16.to_le_bytes()),
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
/// where [`map_process_image`] placed them; returns the LRW working counter OP must show.
pub(crate) async fn configure_process_data(
    link: &Link,
    slaves: &[SlaveInfo],
) -> Result<u16, MasterError> {
    let mut expected_lrw_wkc = 0u16;
    for s in slaves {
        let mut fmmu_n = 0u16;
        for sm in &s.sms {
            let (log, len) = if sm.kind == 3 { s.outputs } else { s.inputs };
            if len == 0 {
                continue;
            }
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
            expected_lrw_wkc += if sm.kind == 3 { 2 } else { 1 };
        }
    }
    Ok(expected_lrw_wkc)
}

/// [`Phase::Sync0`]: SYNC0 on the absolute grid of the reference's system time, programmed in
/// every slave with a system time. `None` if there is none to program (not reached: the
/// reference has one).
async fn start_sync0(
    link: &Link,
    cfg: &BringupConfig,
    slaves: &[SlaveInfo],
    dc: &DcGroup,
) -> Result<Option<Sync0Config>, MasterError> {
    let now_sys = link
        .fprd(
            dc.reference.station,
            reg::DC_SYSTEM_TIME,
            8,
            "read system time",
        )
        .await
        .map_err(|e| e.at(Phase::Sync0, dc.reference))?;
    let read_at_ns = link.now_ns();
    let now_sys = u64::from_le_bytes(now_sys[..8].try_into().unwrap_or([0; 8]));
    let first_start =
        ecsync_dc::sync0_start_time(now_sys, cfg.sync0_lead_ns, cfg.cycle_ns, cfg.sync0_shift_ns);
    let mut start = first_start;
    let mut sync0 = None;
    for s in slaves.iter().filter(|s| s.dc == DcCapability::SystemTime) {
        let at = |e: MasterError| e.at(Phase::Sync0, s.id());
        // A start time already past when SYNC0 is switched on fires only after the system
        // time's low 32 bits wrap, 4.3 s later (the ESC compares those): a large network's
        // slaves, programmed one by one (four round trips each), would pass the lead. A later
        // slave's start moves on by whole cycles, on the same grid, once less than half the
        // lead is left (the system time estimated by the master's clock since the read: their
        // rates differ by parts per million).
        let sys_now_ns = now_sys.wrapping_add(link.now_ns().saturating_sub(read_at_ns));
        if sys_now_ns.saturating_add(cfg.sync0_lead_ns / 2) > start {
            start = ecsync_dc::sync0_start_time(
                sys_now_ns,
                cfg.sync0_lead_ns,
                cfg.cycle_ns,
                cfg.sync0_shift_ns,
            );
        }
        link.fpwr(s.station, reg::DC_ACTIVATION, &[0x00], "SYNC0 off")
            .await
            .map_err(at)?;
        link.fpwr(
            s.station,
            reg::DC_SYNC0_CYCLE,
            &cfg.cycle_ns.to_le_bytes(),
            "SYNC0 cycle",
        )
        .await
        .map_err(at)?;
        link.fpwr(
            s.station,
            reg::DC_START_TIME,
            &start.to_le_bytes(),
            "SYNC0 start",
        )
        .await
        .map_err(at)?;
        link.fpwr(s.station, reg::DC_ACTIVATION, &[0x03], "SYNC0 on")
            .await
            .map_err(at)?;
        sync0 = Some(Sync0Config {
            start_ns: first_start,
            cycle_ns: cfg.cycle_ns,
            shift_ns: cfg.sync0_shift_ns,
        });
    }
    Ok(sync0)
}

/// The cyclic frame of OP: the FRMW first (its send is the reference's time), the process
/// image's LRWs, then every synced slave's 0x092C. In a network where those reads (and the OP
/// wait's read of AL status) would not fit half a cycle, one BRD of 0x092C instead, as the
/// cyclic engine reads it, and the AL status BRD with it: one exchange a cycle that ends
/// within the cycle. A 512-drive line's exchange with a read per slave took 2.6 ms of its 2 ms
/// cycle, and its drives missed a SYNC0 pulse every few cycles of the OP wait and monitoring.
#[derive(Debug, Clone, PartialEq, Eq)]
struct CyclicFrame {
    pdus: Vec<Pdu>,
    /// The LRWs are `pdus[1..lrw_end]`.
    lrw_end: usize,
    /// Each synced slave's 0x092C is read after the LRWs (else one BRD of it, then one of AL
    /// status).
    per_slave: bool,
}

impl CyclicFrame {
    fn new(
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
                position_addr(0, reg::DC_SYSTEM_TIME_DIFF),
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
    fn worst_of(&self, dc: &DcGroup, r: &[PduReply], phase: Phase) -> Result<u32, MasterError> {
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
    fn al_status<'a>(&self, r: &'a [PduReply]) -> Option<&'a PduReply> {
        (!self.per_slave).then(|| r.get(self.lrw_end + 1)).flatten()
    }
}

/// A broadcast read of AL status: every slave's state OR-ed, the working counter the slaves
/// that answered.
fn al_status_brd() -> Pdu {
    Pdu::new(Command::Brd, position_addr(0, reg::AL_STATUS), vec![0; 2])
}

/// About how long an exchange of `pdus` takes on a 100 Mbit/s network, ns: every byte of its
/// frames on the wire (Ethernet's header, checksum, preamble and gap with each frame), and the
/// way to the farthest slave and back (its measured delay, twice).
fn exchange_estimate_ns<'a>(pdus: impl IntoIterator<Item = &'a Pdu>, slaves: &[SlaveInfo]) -> u64 {
    use ecsync_wire::{ECAT_HEADER_LEN, ETH_HEADER_LEN, MAX_FRAME_LEN};
    // The headers before the datagrams; checksum, preamble and the gap after.
    const FRAME_OVERHEAD: usize = ETH_HEADER_LEN + ECAT_HEADER_LEN + 4 + 8 + 12;
    const ROOM: usize = MAX_FRAME_LEN - ETH_HEADER_LEN - ECAT_HEADER_LEN;
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
async fn enter_op(
    link: &Link,
    timeouts: &BringupTimeouts,
    slaves: &[SlaveInfo],
    cyclic: &CyclicFrame,
    grid: &mut CycleGrid,
) -> Result<(), MasterError> {
    let op = AlControlRepr::request(AlState::Op).to_bytes();
    // The process data keeps coming while the requests go out one by one (a large network's
    // take longer than a cycle): a slave in OP without outputs for its watchdog time (100 ms)
    // would fall back to SAFE-OP.
    let mut last_cyclic = link.now_ns();
    for (n, s) in slaves.iter().enumerate() {
        let sent = link.now_ns();
        link.fpwr(s.station, reg::AL_CONTROL, &op, "request OP")
            .await
            .map_err(|e| e.at(Phase::Op, s.id()))?;
        let round_trip_ns = link.now_ns().saturating_sub(sent);
        if link.now_ns().saturating_sub(last_cyclic) >= grid.cycle_ns {
            link.pdus(&cyclic.pdus, "cyclic").await?;
            last_cyclic = link.now_ns();
        }
        // Requests that one by one would take longer than a cycle (a large network's: a round
        // trip each, ~1 s for a 1 000-drive line) leave the first drives in OP with their
        // outputs late or missing, counting missed SYNC0 pulses (a drive with SSC's error
        // limit leaves OP for it): the others go in one exchange (as many frames as it needs),
        // right after a cycle's process data.
        if n == 0 && round_trip_ns.saturating_mul(slaves.len() as u64) > grid.cycle_ns {
            request_op_at_once(link, &slaves[1..], &op, cyclic, grid).await?;
            break;
        }
    }
    let count = slaves.len() as u16;
    // Cycle until every slave reports OP.
    let deadline = link.now_ns() + timeouts.op_timeout_ns;
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
        if status.error() || link.now_ns() > deadline {
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
        if link.now_ns() > deadline {
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
async fn request_op_at_once(
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
async fn monitor(
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
        reading = ReferenceReading::of(&r[0], first.sent_ns).or(reading);
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
    let start = link.now_ns();
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
        if link.now_ns().saturating_sub(start) > timeouts.state_timeout_ns {
            return Err(MasterError::StateTimeout {
                slave: station,
                state,
            });
        }
        let t = link.now_ns() + timeouts.state_poll_interval_ns;
        link.sleep_until(t).await;
    }
}
