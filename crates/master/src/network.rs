//! What the bring-up learns about a network: the slaves, their clocks, the reference, the lock,
//! SYNC0 and the process image; and the [`Phase`]s and slave names errors and events carry.
//! The types every part of the engine shares, kept apart from the procedures that fill them.

use ecsync_wire::sii::Identity;
use std::fmt;

/// First configured station address; slave k gets `STATION_BASE + k`.
pub const STATION_BASE: u16 = 0x1000;

/// A phase of the bring-up, in the order [`bringup`](crate::bringup::bringup) runs them. Its [`Display`](fmt::Display)
/// is the name progress lines and errors use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Phase {
    /// Counting the slaves (a broadcast read of the ESC type).
    Scan,
    /// Every slave to INIT (errors acknowledged), FMMUs and SyncManagers cleared, SYNC off.
    Reset,
    /// Configured station addresses, by auto-increment position.
    StationAddresses,
    /// ESC type, features and ports, the SII identity; with [`Stage::Lock`](crate::bringup::Stage::Lock) and beyond also the
    /// device name and the process data SyncManagers.
    Identify,
    /// Which slaves without a system time have receive times; the reference clock.
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
    pub(crate) fn at_position(position: u16) -> Self {
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

/// What a slave's DC unit keeps, as the master learns it from which reads count: a read of
/// the system time's registers (0x0920), else of the receive times (0x0900). Never from
/// 0x0008, whose DC bit real devices set with receive times alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DcCapability {
    /// No DC.
    None,
    /// Port receive times only: delays measured, never the reference nor synchronised.
    ReceiveTimes,
    /// System time: can be the reference or be synchronised.
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
    /// port over the reference's between latches [`BringupConfig::rate_window_ns`](crate::bringup::BringupConfig::rate_window_ns) apart, minus
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
    /// With [`BringupConfig::master_is_reference`](crate::bringup::BringupConfig::master_is_reference): the master's delay to the reference's
    /// processing unit, ns (mean over the latch rounds), and its spread (max - min).
    pub master_delay_ns: Option<f64>,
    /// Spread of the master delay over the rounds, ns.
    pub master_delay_spread_ns: Option<f64>,
    /// The reference's crystal against the master's clock, ppm (a least-squares fit of its
    /// entry port stamps on the master's send stamps over [`BringupConfig::rate_window_ns`](crate::bringup::BringupConfig::rate_window_ns)):
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
}
