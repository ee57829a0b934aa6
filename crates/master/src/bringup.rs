//! The DC bring-up: scan, addressing, SII identity, topology and propagation delays, system time
//! offsets, static drift compensation, lock detection, process data mapping, SYNC0 and the
//! state machine up to OP — the sequence of the datasheet (section I, 9.1.3.6) as SOEM and IgH
//! run it, with delays averaged over several latches.

use crate::MasterError;
use crate::io::{Event, Link, Pdu};
use crate::sii::{SiiReader, pdo_bits_for_sm};
use ecsync_dc::{LockDetector, SlavePorts, TreeNode, build_tree, propagation_delays};
use ecsync_wire::register::{self as reg, al_state, dl_status, features};
use ecsync_wire::sii::{self, Identity, category};
use ecsync_wire::{Command, DatagramAddress, dc_time};

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
    /// Separate FRMW frames of static drift compensation (the datasheet recommends ~15000).
    pub static_drift_frames: u32,
    /// Read every slave's 0x092C after this many static drift frames.
    pub check_every_frames: u32,
    /// Lock when every |0x092C| stays below this, ns.
    pub lock_threshold_ns: u32,
    /// ... for this many consecutive checks.
    pub lock_hold_checks: u32,
    /// Give up if not locked this long after the static drift compensation, ns.
    pub lock_timeout_ns: u64,
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
}

impl Default for BringupConfig {
    fn default() -> Self {
        BringupConfig {
            until: Stage::Op,
            latch_rounds: 64,
            static_drift_frames: 15_000,
            check_every_frames: 100,
            lock_threshold_ns: 100,
            lock_hold_checks: 1_000,
            lock_timeout_ns: 30_000_000_000,
            cycle_ns: 1_000_000,
            sync0_shift_ns: 300_000,
            sync0_lead_ns: 100_000_000,
            monitor_cycles: 1_000,
            esi: Vec::new(),
            master_is_reference: false,
        }
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
    /// Output bytes (RxPDO) and where they sit in the logical process image.
    pub outputs: (u32, u16),
    /// Input bytes (TxPDO) and where they sit in the logical process image.
    pub inputs: (u32, u16),
    /// Output and input SyncManager indices and physical starts.
    #[serde(skip)]
    pub sms: Vec<SmConfig>,
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
    /// FRMW frames sent before lock.
    pub frmw_frames: u64,
}

/// SYNC0 as programmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Sync0Config {
    /// Start time (system time), ns.
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

/// Runs the bring-up on a link.
pub async fn bringup(link: Link, cfg: BringupConfig) -> Result<Network, MasterError> {
    if cfg.cycle_ns == 0 || cfg.sync0_shift_ns >= cfg.cycle_ns {
        return Err(MasterError::Config(format!(
            "cycle {} ns and SYNC0 shift {} ns: the shift must lie within the cycle",
            cfg.cycle_ns, cfg.sync0_shift_ns
        )));
    }
    link.event(Event::Phase("scan"));
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

    // Reset: INIT with error acknowledge, FMMUs and SyncManagers cleared, SYNC off.
    let mut reset = vec![Pdu::new(
        Command::Bwr,
        position_addr(0, reg::AL_CONTROL),
        vec![0x11, 0x00],
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

    // Addresses.
    for pos in 0..count {
        link.pdu_wkc(
            Command::Apwr,
            position_addr(pos, reg::STATION_ADDRESS),
            (STATION_BASE + pos).to_le_bytes().to_vec(),
            1,
            "set station address",
        )
        .await?;
    }

    // Identity, features, ports.
    link.event(Event::Phase("identify"));
    let mut slaves = Vec::with_capacity(usize::from(count));
    for pos in 0..count {
        let station = STATION_BASE + pos;
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
        let mut sii = SiiReader::new(&link, station);
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
        let details = cfg.until > Stage::Delays;
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
        slaves.push(SlaveInfo {
            position: pos,
            station,
            alias: u16::from_le_bytes([r[1].data[0], r[1].data[1]]),
            esc_type: info[0],
            features: feats,
            identity,
            vendor_id: identity.vendor_id,
            product_code: identity.product_code,
            serial: identity.serial,
            name,
            dc,
            open_ports: open,
            parent: None,
            entry_port: 0,
            delay_ns: None,
            delay_spread_ns: None,
            offset: None,
            outputs: (0, 0),
            inputs: (0, 0),
            sms,
        });
    }

    // Slaves without the DC feature may still have receive times (junctions must): probe
    // 0x0900 with a read and see who counts it.
    for s in slaves.iter_mut().filter(|s| s.dc == DcCapability::None) {
        let r = link
            .pdu(
                Command::Fprd,
                fp(s.station, reg::DC_RECEIVE_TIME_PORT0),
                vec![0; 4],
                "probe receive times",
            )
            .await?;
        if r.wkc == 1 {
            s.dc = DcCapability::ReceiveTimes;
        }
    }
    let reference = slaves
        .iter()
        .position(|s| s.dc == DcCapability::SystemTime)
        .ok_or(MasterError::NoReferenceClock)?;
    let ref_station = slaves[reference].station;

    // Propagation delays, averaged over latch rounds with the send instant dithered across the
    // receive stamps' 40 ns resolution.
    link.event(Event::Phase("delays"));
    let n = slaves.len();
    let rounds = cfg.latch_rounds.max(1);
    let mut sums = vec![0.0f64; n];
    let mut mins = vec![f64::INFINITY; n];
    let mut maxs = vec![f64::NEG_INFINITY; n];
    let mut last_pu = vec![0u64; n];
    let mut latch_sent_ns = 0;
    let mut tree = vec![TreeNode::default(); n];
    let mut delays = vec![None; n];
    // The rounds are spread over ~20 ms so that each slave's clock rate relative to the master
    // can be measured from its first and last port 0 stamps and the spans corrected for it.
    let gap_ns = (20_000_000 / u64::from(rounds)).max(2_000);
    let mut all_ports: Vec<Vec<SlavePorts>> = Vec::with_capacity(rounds as usize);
    let mut sent_at: Vec<u64> = Vec::with_capacity(rounds as usize);
    let mut round_trips: Vec<f64> = Vec::with_capacity(rounds as usize);
    for round in 0..rounds {
        let dither = u64::from(round) * 40 / u64::from(rounds);
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
        let latch_sent = r_sent(&link);
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
                });
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
            // Only plausible rates (within 0.1 %) are used; anything else is a misread.
            if (rate - 1.0).abs() < 1e-3 {
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

    if cfg.until == Stage::Delays {
        return Ok(Network {
            slaves,
            reference: reference as u16,
            lock: LockReport {
                converged: false,
                time_to_lock_ns: None,
                drift_start_ns: 0,
                declared_ns: None,
                max_abs_092c_after_lock_ns: 0,
                frmw_frames: 0,
            },
            sync0: None,
            pdi_len: 0,
            lrw: Vec::new(),
            expected_lrw_wkc: 0,
            done_ns: link.now_ns(),
            master_delay_ns,
            master_delay_spread_ns,
        });
    }

    // Offsets from the last latch, written together with the delays in one frame, then the
    // loop filters reset (0x0934: time difference depth 0, speed counter depth 12, as SOEM and
    // ethercrab write; then 0x0930, whose write resets the filters).
    link.event(Event::Phase("offsets"));
    // The reference's system time takes the master's clock at the latch (SOEM, IgH, ethercrab);
    // a master that is the reference itself takes its clock at the frame's arrival there.
    let ref_time = latch_sent_ns
        .wrapping_add(master_delay_ns.map_or(0, |d| ecsync_dc::offset::round_ns(d).max(0) as u64));
    let mut writes = Vec::new();
    for (i, s) in slaves.iter_mut().enumerate() {
        if s.dc != DcCapability::SystemTime {
            continue;
        }
        let delay = ecsync_dc::offset::round_ns(s.delay_ns.unwrap_or(0.0)).max(0);
        let offset = ecsync_dc::system_time_offset(ref_time, delay, last_pu[i]);
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
    }
    let (r, _) = link.pdus(&writes, "write offsets and delays").await?;
    if let Some(bad) = r.iter().find(|p| p.wkc != 1) {
        return Err(MasterError::WorkingCounter {
            command: Command::Fpwr,
            what: "write offsets and delays",
            expected: 1,
            got: bad.wkc,
        });
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

    // Static drift compensation, with lock checks.
    link.event(Event::Phase("drift"));
    let synced: Vec<u16> = slaves
        .iter()
        .filter(|s| s.dc == DcCapability::SystemTime && s.station != ref_station)
        .map(|s| s.station)
        .collect();
    let frmw = || {
        Pdu::new(
            Command::Frmw,
            fp(ref_station, reg::DC_SYSTEM_TIME),
            vec![0; 8],
        )
    };
    let check_pdus = |with_frmw: bool| {
        let mut v = Vec::with_capacity(synced.len() + 1);
        if with_frmw {
            v.push(frmw());
        }
        v.extend(
            synced
                .iter()
                .map(|&st| Pdu::new(Command::Fprd, fp(st, reg::DC_SYSTEM_TIME_DIFF), vec![0; 4])),
        );
        v
    };
    let worst_of = |replies: &[crate::io::PduReply]| -> Result<u32, MasterError> {
        let mut worst = 0u32;
        for p in replies {
            if p.wkc != 1 {
                return Err(MasterError::WorkingCounter {
                    command: Command::Fprd,
                    what: "read system time difference",
                    expected: 1,
                    got: p.wkc,
                });
            }
            let raw = u32::from_le_bytes([p.data[0], p.data[1], p.data[2], p.data[3]]);
            worst = worst.max(dc_time::decode_time_difference(raw).unsigned_abs());
        }
        Ok(worst)
    };
    let drift_start = link.now_ns();
    let mut lock = LockDetector::new(cfg.lock_threshold_ns, cfg.lock_hold_checks.max(1));
    let mut frmw_frames = 0u64;
    for i in 0..cfg.static_drift_frames {
        let r = link
            .pdu(
                Command::Frmw,
                fp(ref_station, reg::DC_SYSTEM_TIME),
                vec![0; 8],
                "static drift compensation",
            )
            .await?;
        frmw_frames += 1;
        if r.wkc == 0 {
            return Err(MasterError::WorkingCounter {
                command: Command::Frmw,
                what: "static drift compensation",
                expected: 1,
                got: 0,
            });
        }
        if cfg.check_every_frames > 0 && (i + 1) % cfg.check_every_frames == 0 && !synced.is_empty()
        {
            let (r, _) = link
                .pdus(&check_pdus(false), "read system time difference")
                .await?;
            lock.update(worst_of(&r)?, link.now_ns());
        }
    }

    // Cyclic FRMW until locked. The timeout runs from the end of the static drift
    // compensation, whose length grows with the network (a frame passes every slave).
    let cycle = u64::from(cfg.cycle_ns);
    let mut next = (link.now_ns() / cycle + 1) * cycle;
    let lock_start = link.now_ns();
    while !synced.is_empty() && !lock.is_locked() {
        if link.now_ns().saturating_sub(lock_start) > cfg.lock_timeout_ns {
            return Err(MasterError::NoLock(cfg.lock_timeout_ns / 1_000_000));
        }
        link.sleep_until(next).await;
        next += cycle;
        let (r, _) = link.pdus(&check_pdus(true), "cyclic DC").await?;
        frmw_frames += 1;
        lock.update(worst_of(&r[1..])?, link.now_ns());
    }
    let mut lock_report = LockReport {
        converged: synced.is_empty() || lock.is_locked(),
        time_to_lock_ns: if synced.is_empty() {
            Some(0)
        } else {
            lock.locked_at_ns().map(|t| t.saturating_sub(drift_start))
        },
        drift_start_ns: drift_start,
        declared_ns: (synced.is_empty() || lock.is_locked()).then(|| link.now_ns()),
        max_abs_092c_after_lock_ns: 0,
        frmw_frames,
    };

    // Process data mapping: outputs of all slaves, then inputs, in the logical image.
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
    let mut expected_lrw_wkc = 0u16;
    let mut sync0 = None;
    let to_op = cfg.until == Stage::Op;
    if !to_op {
        return Ok(Network {
            slaves,
            reference: reference as u16,
            lock: lock_report,
            sync0,
            pdi_len,
            lrw,
            expected_lrw_wkc,
            done_ns: link.now_ns(),
            master_delay_ns,
            master_delay_spread_ns,
        });
    }
    {
        for s in &slaves {
            request_state(&link, s.station, al_state::PRE_OP).await?;
        }
        for s in &slaves {
            let mut fmmu_n = 0u16;
            for sm in &s.sms {
                let (log, len) = if sm.kind == 3 { s.outputs } else { s.inputs };
                if len == 0 {
                    continue;
                }
                let mut smr = [0u8; 8];
                smr[0..2].copy_from_slice(&sm.start.to_le_bytes());
                smr[2..4].copy_from_slice(&len.to_le_bytes());
                smr[4] = sm.control;
                smr[6] = 0x01;
                link.fpwr(
                    s.station,
                    reg::SM_BASE + u16::from(sm.index) * reg::SM_LEN,
                    &smr,
                    "configure SyncManager",
                )
                .await?;
                let mut f = [0u8; 16];
                f[0..4].copy_from_slice(&log.to_le_bytes());
                f[4..6].copy_from_slice(&len.to_le_bytes());
                f[7] = 7;
                f[8..10].copy_from_slice(&sm.start.to_le_bytes());
                f[11] = if sm.kind == 3 { 0x02 } else { 0x01 };
                f[12] = 0x01;
                link.fpwr(
                    s.station,
                    reg::FMMU_BASE + fmmu_n * reg::FMMU_LEN,
                    &f,
                    "configure FMMU",
                )
                .await?;
                fmmu_n += 1;
                expected_lrw_wkc += if sm.kind == 3 { 2 } else { 1 };
            }
        }
    }

    // SYNC0 on the absolute grid of the reference's system time.
    link.event(Event::Phase("sync0"));
    let now_sys = link
        .fprd(ref_station, reg::DC_SYSTEM_TIME, 8, "read system time")
        .await?;
    let now_sys = u64::from_le_bytes(now_sys[..8].try_into().unwrap_or([0; 8]));
    let start =
        ecsync_dc::sync0_start_time(now_sys, cfg.sync0_lead_ns, cfg.cycle_ns, cfg.sync0_shift_ns);
    for s in slaves.iter().filter(|s| s.dc == DcCapability::SystemTime) {
        link.fpwr(s.station, reg::DC_ACTIVATION, &[0x00], "SYNC0 off")
            .await?;
        link.fpwr(
            s.station,
            reg::DC_SYNC0_CYCLE,
            &cfg.cycle_ns.to_le_bytes(),
            "SYNC0 cycle",
        )
        .await?;
        link.fpwr(
            s.station,
            reg::DC_START_TIME,
            &start.to_le_bytes(),
            "SYNC0 start",
        )
        .await?;
        link.fpwr(s.station, reg::DC_ACTIVATION, &[0x03], "SYNC0 on")
            .await?;
        sync0 = Some(Sync0Config {
            start_ns: start,
            cycle_ns: cfg.cycle_ns,
            shift_ns: cfg.sync0_shift_ns,
        });
    }

    // SAFE-OP and OP with the cyclic frame running, then monitoring.
    let cyclic = |with_lrw: bool| {
        let mut v = vec![frmw()];
        if with_lrw {
            v.extend(lrw.iter().map(|c| {
                Pdu::new(
                    Command::Lrw,
                    DatagramAddress::Logical(c.logical),
                    vec![0; c.len as usize],
                )
            }));
        }
        v.extend(
            synced
                .iter()
                .map(|&st| Pdu::new(Command::Fprd, fp(st, reg::DC_SYSTEM_TIME_DIFF), vec![0; 4])),
        );
        v
    };
    let k = 1 + if to_op { lrw.len() } else { 0 };
    {
        link.event(Event::Phase("safe-op"));
        for s in &slaves {
            request_state(&link, s.station, al_state::SAFE_OP).await?;
        }
        link.event(Event::Phase("op"));
        for s in &slaves {
            link.fpwr(s.station, reg::AL_CONTROL, &[al_state::OP, 0], "request OP")
                .await?;
        }
        // Cycle until every slave reports OP.
        let deadline = link.now_ns() + 10_000_000_000;
        loop {
            link.sleep_until(next).await;
            next += cycle;
            link.pdus(&cyclic(true), "cyclic").await?;
            let (r, _) = link
                .pdus(
                    &[Pdu::new(
                        Command::Brd,
                        position_addr(0, reg::AL_STATUS),
                        vec![0; 2],
                    )],
                    "AL status",
                )
                .await?;
            if r[0].wkc == count && r[0].data[0] & 0x1f == al_state::OP {
                break;
            }
            if link.now_ns() > deadline {
                return Err(MasterError::StateTimeout {
                    slave: 0,
                    state: al_state::OP,
                });
            }
        }
    }
    link.event(Event::Phase("monitor"));
    for _ in 0..cfg.monitor_cycles {
        link.sleep_until(next).await;
        next += cycle;
        let (r, _) = link.pdus(&cyclic(to_op), "cyclic").await?;
        let worst = worst_of(&r[k..])?;
        lock_report.max_abs_092c_after_lock_ns = lock_report.max_abs_092c_after_lock_ns.max(worst);
        let got: u16 = r[1..k].iter().map(|p| p.wkc).sum();
        if to_op && pdi_len > 0 && got != expected_lrw_wkc {
            return Err(MasterError::WorkingCounter {
                command: Command::Lrw,
                what: "process data",
                expected: expected_lrw_wkc,
                got,
            });
        }
    }
    Ok(Network {
        slaves,
        reference: reference as u16,
        lock: lock_report,
        sync0,
        pdi_len,
        lrw,
        expected_lrw_wkc,
        done_ns: link.now_ns(),
        master_delay_ns,
        master_delay_spread_ns,
    })
}

/// Requests an AL state from one slave and waits until it is reached or refused.
pub async fn request_state(link: &Link, station: u16, state: u8) -> Result<(), MasterError> {
    link.fpwr(station, reg::AL_CONTROL, &[state, 0], "AL control")
        .await?;
    let start = link.now_ns();
    loop {
        let v = link.fprd(station, reg::AL_STATUS, 6, "AL status").await?;
        let status = u16::from_le_bytes([v[0], v[1]]);
        if status & al_state::ERROR_FLAG != 0 {
            return Err(MasterError::StateChange {
                slave: station,
                state,
                code: u16::from_le_bytes([v[4], v[5]]),
            });
        }
        if (status & 0x0f) as u8 == state {
            return Ok(());
        }
        if link.now_ns().saturating_sub(start) > 5_000_000_000 {
            return Err(MasterError::StateTimeout {
                slave: station,
                state,
            });
        }
        let t = link.now_ns() + 100_000;
        link.sleep_until(t).await;
    }
}
