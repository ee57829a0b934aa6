//! A gPTP (IEEE 802.1AS) time-aware system, sans-IO: messages and timestamps in, messages to
//! send out, no sockets and no clocks of its own. The same code runs in the simulator and can
//! later run on an interface with hardware timestamps.
//!
//! What it does, per 802.1AS-2020:
//! - **BMCA** (10.3): every port keeps the last Announce it received (priority vector:
//!   grandmaster systemIdentity, stepsRemoved, the sender's port identity); the best of those
//!   and of the system itself decides the grandmaster, the slave port, and which ports are
//!   master (announce and send time) or passive. An Announce not renewed within three intervals
//!   expires.
//! - **Peer delay** (11.2.19): each port measures its link with Pdelay_Req / Pdelay_Resp /
//!   Pdelay_Resp_Follow_Up: `neighborRateRatio = (t3 - t3_first) / (t4 - t4_first)`,
//!   `meanLinkDelay = ((t4 - t1) * neighborRateRatio - (t3 - t2)) / 2`; and answers its peer's.
//! - **Sync transport** (two-step, 10.2 and 11.2.14/15): the grandmaster sends Sync on its
//!   master ports and a Follow_Up with the precise origin time; a relay (a bridge) forwards them
//!   on its master ports with `correctionField += link delay + residence time` (both in the
//!   grandmaster's time base, by rateRatio) and `rateRatio *= neighborRateRatio`.
//! - **Servo** at every time-aware system that is not the grandmaster: the grandmaster time at
//!   the Sync's arrival is `preciseOriginTimestamp + correctionField + meanLinkDelay`; the
//!   offset drives a PI controller, fed forward with rateRatio, whose output the caller applies
//!   to its clock as a frequency adjustment (and once, at the first Sync, as a phase step).
//!
//! All times are the system's local clock in nanoseconds (as its timestamps give them).

use crate::gptp_msg::{
    Announce, ClockQuality, FollowUpInfo, Header, Message, PortIdentity, Timestamp, flags,
};

/// A system's identity for the BMCA (compared in this order; smaller wins).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SystemIdentity {
    /// priority1 (246 for a time-aware bridge or end station able to be grandmaster; 255 not).
    pub priority1: u8,
    /// clockQuality.
    pub quality: ClockQuality,
    /// priority2.
    pub priority2: u8,
    /// clockIdentity (tie breaker).
    pub clock_identity: [u8; 8],
}

impl SystemIdentity {
    /// A time-aware system of the default quality (802.1AS 8.6.2: clockClass 248, accuracy
    /// unknown 0xfe, offsetScaledLogVariance 0x4e5d, priority2 248) with this priority1 and
    /// clockIdentity.
    pub fn with_default_quality(priority1: u8, clock_identity: [u8; 8]) -> Self {
        SystemIdentity {
            priority1,
            quality: ClockQuality {
                clock_class: 248,
                clock_accuracy: 0xfe,
                offset_scaled_log_variance: 0x4e5d,
            },
            priority2: 248,
            clock_identity,
        }
    }
}

/// Role of a port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum PortRole {
    /// Sends Announce and time downstream.
    Master,
    /// Receives time from the grandmaster.
    Slave,
    /// Neither (a loop or a worse path).
    Passive,
}

/// Configuration of a time-aware system.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    /// Its identity.
    pub identity: SystemIdentity,
    /// Number of ports.
    pub ports: usize,
    /// Sync interval, ns (802.1AS default 125 ms).
    pub sync_interval_ns: u64,
    /// Pdelay_Req interval, ns (default 1 s).
    pub pdelay_interval_ns: u64,
    /// Announce interval, ns (default 1 s).
    pub announce_interval_ns: u64,
    /// Servo gains on the phase error: proportional and integral, per Sync.
    pub kp: f64,
    /// Integral gain.
    pub ki: f64,
}

impl Config {
    /// 802.1AS default intervals and a servo that settles in a few seconds.
    pub fn new(identity: SystemIdentity, ports: usize) -> Self {
        Config {
            identity,
            ports,
            sync_interval_ns: 125_000_000,
            pdelay_interval_ns: 1_000_000_000,
            announce_interval_ns: 1_000_000_000,
            kp: 0.7,
            ki: 0.3,
        }
    }
}

/// A message to send on a port.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outgoing {
    /// Port index.
    pub port: usize,
    /// Header.
    pub header: Header,
    /// Body.
    pub message: Message,
}

/// What the caller should do to its clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockAdjust {
    /// Step the clock by this much (ns; once, at the first Sync).
    pub step_ns: f64,
    /// Run the clock at `1 + frequency` times its free-running rate from now on.
    pub frequency: f64,
}

#[derive(Debug, Clone, Copy, Default)]
struct AnnounceSeen {
    gm: Option<SystemIdentity>,
    steps_removed: u16,
    sender: PortIdentity,
    expires_ns: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct PortData {
    role: Option<PortRole>,
    announce: AnnounceSeen,
    next_announce_ns: u64,
    next_sync_ns: u64,
    next_pdelay_ns: u64,
    seq_announce: u16,
    seq_sync: u16,
    seq_pdelay: u16,
    // Initiator.
    pd_t1: Option<u64>,
    pd_t2: Option<Timestamp>,
    pd_t4: Option<u64>,
    pd_first: Option<(u64, u64)>,
    neighbor_rate_ratio: f64,
    mean_link_delay_ns: Option<f64>,
    // Responder: the request being answered (requester, sequence, t2).
    pd_answer: Option<(PortIdentity, u16, u64)>,
    // Master side: a Sync sent whose Follow_Up waits for its transmit timestamp.
    sync_pending: Option<u16>,
}

/// The time carried by the last Sync/Follow_Up pair received on the slave port.
#[derive(Debug, Clone, Copy)]
struct SyncInfo {
    /// Grandmaster time when the Sync left the upstream port: the precise origin (whole ns,
    /// exact at any epoch) plus the correction (a small, fractional amount).
    gm_origin_ns: u64,
    /// The correction, ns.
    gm_correction_ns: f64,
    /// Its arrival, local time.
    rx_ns: u64,
    /// Grandmaster frequency over local frequency.
    rate_ratio: f64,
}

/// A gPTP time-aware system.
#[derive(Debug, Clone)]
pub struct TimeAwareSystem {
    cfg: Config,
    ports: Vec<PortData>,
    sync_rx: Option<(u16, u64)>,
    last_sync: Option<SyncInfo>,
    gm: SystemIdentity,
    steps_removed: u16,
    slave_port: Option<usize>,
    // Servo.
    stepped: bool,
    integral: f64,
    last_offset_ns: Option<f64>,
    frequency: f64,
    // Grandmaster: its own Syncs' origin.
    started: bool,
}

impl TimeAwareSystem {
    /// A system that has not heard anyone yet (it is its own grandmaster).
    pub fn new(cfg: Config) -> Self {
        TimeAwareSystem {
            ports: vec![
                PortData {
                    neighbor_rate_ratio: 1.0,
                    ..PortData::default()
                };
                cfg.ports
            ],
            gm: cfg.identity,
            cfg,
            sync_rx: None,
            last_sync: None,
            steps_removed: 0,
            slave_port: None,
            stepped: false,
            integral: 0.0,
            last_offset_ns: None,
            frequency: 0.0,
            started: false,
        }
    }

    /// This system's port identity on `port`.
    pub fn port_identity(&self, port: usize) -> PortIdentity {
        PortIdentity {
            clock_identity: self.cfg.identity.clock_identity,
            port_number: port as u16 + 1,
        }
    }

    /// The grandmaster it follows (itself if it is the grandmaster).
    pub fn grandmaster(&self) -> SystemIdentity {
        self.gm
    }

    /// Whether this system is the grandmaster.
    pub fn is_grandmaster(&self) -> bool {
        self.gm == self.cfg.identity
    }

    /// The role of `port`.
    pub fn role(&self, port: usize) -> PortRole {
        self.ports[port].role.unwrap_or(PortRole::Master)
    }

    /// The measured mean link delay on `port`, ns.
    pub fn mean_link_delay_ns(&self, port: usize) -> Option<f64> {
        self.ports[port].mean_link_delay_ns
    }

    /// The measured neighbor rate ratio on `port`.
    pub fn neighbor_rate_ratio(&self, port: usize) -> f64 {
        self.ports[port].neighbor_rate_ratio
    }

    /// The last offset from the grandmaster the servo saw (disciplined clock - grandmaster), ns.
    pub fn offset_ns(&self) -> Option<f64> {
        self.last_offset_ns
    }

    /// When the last Sync used arrived, local time.
    pub fn last_sync_rx_ns(&self) -> Option<u64> {
        self.last_sync.map(|s| s.rx_ns)
    }

    /// Grandmaster time at local time `local_ns`, from the last Sync (None before one): whole
    /// nanoseconds and the fraction. Absolute times stay integers (a float holds whole
    /// nanoseconds only up to 2^53, 104 days: PTP's TAI timescale is at 1.8e18); only the
    /// differences, small, are floating point.
    pub fn gm_time_at(&self, local_ns: u64) -> Option<(u64, f64)> {
        let s = self.last_sync?;
        let link = self
            .slave_port
            .and_then(|p| self.ports[p].mean_link_delay_ns)
            .unwrap_or(0.0);
        let since_rx = (local_ns.wrapping_sub(s.rx_ns) as i64) as f64;
        let rest = s.gm_correction_ns + link * s.rate_ratio + since_rx * s.rate_ratio;
        let whole = rest.floor();
        Some((
            s.gm_origin_ns.wrapping_add(whole as i64 as u64),
            rest - whole,
        ))
    }

    fn header(&self, port: usize, seq: u16, flags: u16, log: i8) -> Header {
        Header {
            domain: 0,
            flags,
            correction_scaled_ns: 0,
            source: self.port_identity(port),
            sequence_id: seq,
            log_message_interval: log,
        }
    }

    fn update_roles(&mut self, now_ns: u64) {
        // Priority vectors: grandmaster, stepsRemoved, then the sender's port identity breaks
        // ties between two ports that hear the same grandmaster at the same distance.
        let me = PortIdentity {
            clock_identity: self.cfg.identity.clock_identity,
            port_number: 0,
        };
        let mut best_vec: (SystemIdentity, u16, PortIdentity) = (self.cfg.identity, 0, me);
        let mut slave = None;
        for (i, p) in self.ports.iter_mut().enumerate() {
            if p.announce.expires_ns <= now_ns {
                p.announce.gm = None;
            }
            if let Some(gm) = p.announce.gm {
                let cand = (
                    gm,
                    p.announce.steps_removed.saturating_add(1),
                    p.announce.sender,
                );
                // A path back to ourselves is no grandmaster.
                if gm.clock_identity != self.cfg.identity.clock_identity && cand < best_vec {
                    best_vec = cand;
                    slave = Some(i);
                }
            }
        }
        let best = (best_vec.0, best_vec.1);
        if best.0 != self.gm {
            // A new grandmaster: the servo starts over.
            self.last_sync = None;
            self.stepped = false;
            self.integral = 0.0;
        }
        self.gm = best.0;
        self.steps_removed = best.1;
        self.slave_port = slave;
        for (i, p) in self.ports.iter_mut().enumerate() {
            p.role = Some(if Some(i) == slave {
                PortRole::Slave
            } else if p
                .announce
                .gm
                .is_some_and(|g| (g, p.announce.steps_removed) < (best.0, best.1))
            {
                PortRole::Passive
            } else {
                PortRole::Master
            });
        }
    }

    /// Periodic work at local time `now_ns`: Announce, Sync (grandmaster), Pdelay_Req.
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<Outgoing>) {
        if !self.started {
            self.started = true;
            for p in &mut self.ports {
                p.next_announce_ns = now_ns;
                p.next_sync_ns = now_ns;
                p.next_pdelay_ns = now_ns;
            }
        }
        self.update_roles(now_ns);
        let gm_here = self.is_grandmaster();
        for i in 0..self.ports.len() {
            if now_ns >= self.ports[i].next_pdelay_ns {
                self.ports[i].next_pdelay_ns = now_ns + self.cfg.pdelay_interval_ns;
                self.ports[i].seq_pdelay = self.ports[i].seq_pdelay.wrapping_add(1);
                self.ports[i].pd_t1 = None;
                self.ports[i].pd_t2 = None;
                self.ports[i].pd_t4 = None;
                let h = self.header(i, self.ports[i].seq_pdelay, 0, 0);
                out.push(Outgoing {
                    port: i,
                    header: h,
                    message: Message::PdelayReq,
                });
            }
            let master = self.role(i) == PortRole::Master;
            if master && now_ns >= self.ports[i].next_announce_ns {
                self.ports[i].next_announce_ns = now_ns + self.cfg.announce_interval_ns;
                self.ports[i].seq_announce = self.ports[i].seq_announce.wrapping_add(1);
                let mut a = Announce {
                    current_utc_offset: 37,
                    priority1: self.gm.priority1,
                    clock_quality: self.gm.quality,
                    priority2: self.gm.priority2,
                    grandmaster_identity: self.gm.clock_identity,
                    steps_removed: self.steps_removed,
                    time_source: 0xa0,
                    ..Announce::default()
                };
                a.path[0] = self.cfg.identity.clock_identity;
                a.path_len = 1;
                let h = self.header(i, self.ports[i].seq_announce, flags::PTP_TIMESCALE, 0);
                out.push(Outgoing {
                    port: i,
                    header: h,
                    message: Message::Announce(a),
                });
            }
            if gm_here && master && now_ns >= self.ports[i].next_sync_ns {
                self.ports[i].next_sync_ns = now_ns + self.cfg.sync_interval_ns;
                self.send_sync(i, out);
            }
        }
    }

    fn send_sync(&mut self, port: usize, out: &mut Vec<Outgoing>) {
        let p = &mut self.ports[port];
        p.seq_sync = p.seq_sync.wrapping_add(1);
        p.sync_pending = Some(p.seq_sync);
        let seq = p.seq_sync;
        let h = self.header(port, seq, flags::TWO_STEP | flags::PTP_TIMESCALE, -3);
        out.push(Outgoing {
            port,
            header: h,
            message: Message::Sync,
        });
    }

    /// A message arrived on `port` at local time `rx_ns` (its receive timestamp).
    pub fn on_message(
        &mut self,
        port: usize,
        h: &Header,
        m: &Message,
        rx_ns: u64,
        out: &mut Vec<Outgoing>,
    ) {
        if h.source.clock_identity == self.cfg.identity.clock_identity {
            return;
        }
        match *m {
            Message::Announce(a) => {
                let gm = SystemIdentity {
                    priority1: a.priority1,
                    quality: a.clock_quality,
                    priority2: a.priority2,
                    clock_identity: a.grandmaster_identity,
                };
                // Path trace: an Announce that has passed us already is a loop.
                if a.path[..usize::from(a.path_len.min(8))]
                    .contains(&self.cfg.identity.clock_identity)
                {
                    return;
                }
                self.ports[port].announce = AnnounceSeen {
                    gm: Some(gm),
                    steps_removed: a.steps_removed,
                    sender: h.source,
                    expires_ns: rx_ns + 3 * self.cfg.announce_interval_ns,
                };
                self.update_roles(rx_ns);
            }
            Message::PdelayReq => {
                // Answer: Pdelay_Resp with t2 now, its Follow_Up with t3 once sent.
                self.ports[port].pd_answer = Some((h.source, h.sequence_id, rx_ns));
                let hr = Header {
                    sequence_id: h.sequence_id,
                    ..self.header(port, h.sequence_id, flags::TWO_STEP, 0x7f)
                };
                out.push(Outgoing {
                    port,
                    header: hr,
                    message: Message::PdelayResp {
                        request_receipt: Timestamp::from_ns(rx_ns),
                        requesting: h.source,
                    },
                });
            }
            Message::PdelayResp {
                request_receipt,
                requesting,
            } => {
                let me = self.port_identity(port);
                let p = &mut self.ports[port];
                if requesting == me && h.sequence_id == p.seq_pdelay {
                    p.pd_t2 = Some(request_receipt);
                    p.pd_t4 = Some(rx_ns);
                }
            }
            Message::PdelayRespFollowUp {
                response_origin,
                requesting,
            } => {
                let me = self.port_identity(port);
                let p = &mut self.ports[port];
                if requesting != me || h.sequence_id != p.seq_pdelay {
                    return;
                }
                if let (Some(t1), Some(t2), Some(t4)) = (p.pd_t1, p.pd_t2, p.pd_t4) {
                    let t3 = response_origin.to_ns();
                    match p.pd_first {
                        Some((t3_0, t4_0)) if t4 > t4_0 => {
                            p.neighbor_rate_ratio = (t3.wrapping_sub(t3_0) as i64) as f64
                                / (t4.wrapping_sub(t4_0) as i64) as f64;
                        }
                        _ => p.pd_first = Some((t3, t4)),
                    }
                    let d = ((t4.wrapping_sub(t1) as i64) as f64 * p.neighbor_rate_ratio
                        - (t3.wrapping_sub(t2.to_ns()) as i64) as f64)
                        / 2.0;
                    p.mean_link_delay_ns = Some(d);
                }
            }
            Message::Sync => {
                if Some(port) == self.slave_port {
                    self.sync_rx = Some((h.sequence_id, rx_ns));
                }
            }
            Message::FollowUp {
                precise_origin,
                info,
            } => {
                if Some(port) != self.slave_port {
                    return;
                }
                let Some((seq, sync_rx)) = self.sync_rx else {
                    return;
                };
                if seq != h.sequence_id {
                    return;
                }
                let upstream_rate =
                    1.0 + f64::from(info.cumulative_scaled_rate_offset) / (1u64 << 41) as f64;
                let rate_ratio = upstream_rate * self.ports[port].neighbor_rate_ratio;
                self.last_sync = Some(SyncInfo {
                    gm_origin_ns: precise_origin.to_ns(),
                    gm_correction_ns: h.correction_scaled_ns as f64 / 65536.0,
                    rx_ns: sync_rx,
                    rate_ratio,
                });
                // Relay on every master port (a bridge).
                for i in 0..self.ports.len() {
                    if i != port && self.role(i) == PortRole::Master {
                        self.send_sync(i, out);
                    }
                }
            }
        }
    }

    /// The transmit timestamp (local time) of a message this system sent on `port`.
    pub fn on_tx_timestamp(
        &mut self,
        port: usize,
        h: &Header,
        m: &Message,
        tx_ns: u64,
        out: &mut Vec<Outgoing>,
    ) {
        match m {
            Message::PdelayReq if h.sequence_id == self.ports[port].seq_pdelay => {
                self.ports[port].pd_t1 = Some(tx_ns);
            }
            Message::PdelayResp { requesting, .. } => {
                if let Some((req, seq, _)) = self.ports[port].pd_answer
                    && req == *requesting
                    && seq == h.sequence_id
                {
                    let hf = self.header(port, seq, 0, 0x7f);
                    out.push(Outgoing {
                        port,
                        header: hf,
                        message: Message::PdelayRespFollowUp {
                            response_origin: Timestamp::from_ns(tx_ns),
                            requesting: req,
                        },
                    });
                }
            }
            Message::Sync => {
                if self.ports[port].sync_pending != Some(h.sequence_id) {
                    return;
                }
                self.ports[port].sync_pending = None;
                // Grandmaster time when this Sync left, and the rate to the grandmaster.
                let (origin_ns, correction_ns, rate) = if self.is_grandmaster() {
                    (tx_ns, 0.0, 1.0)
                } else if let (Some(s), Some((now_ns, now_frac))) =
                    (self.last_sync, self.gm_time_at(tx_ns))
                {
                    // The upstream's precise origin, and everything since in the correction.
                    let correction = (now_ns.wrapping_sub(s.gm_origin_ns) as i64) as f64 + now_frac;
                    (s.gm_origin_ns, correction, s.rate_ratio)
                } else {
                    return;
                };
                let mut hf = self.header(port, h.sequence_id, flags::PTP_TIMESCALE, -3);
                hf.correction_scaled_ns = (correction_ns * 65536.0).round() as i64;
                out.push(Outgoing {
                    port,
                    header: hf,
                    message: Message::FollowUp {
                        precise_origin: Timestamp::from_ns(origin_ns),
                        info: FollowUpInfo {
                            cumulative_scaled_rate_offset: ((rate - 1.0) * (1u64 << 41) as f64)
                                .round()
                                as i32,
                            ..FollowUpInfo::default()
                        },
                    },
                });
            }
            _ => {}
        }
    }

    /// The servo's decision after the last Follow_Up (call once per Sync received), for a
    /// clock disciplined to the grandmaster that read `clock_at_rx_ns` (and the fraction
    /// `clock_at_rx_frac`) when that Sync arrived and runs at `1 + frequency` times the local
    /// oscillator: `None` before the first Sync or
    /// on the grandmaster. The first decision steps the phase and takes the measured rate; the
    /// next ones are a PI on the phase error on top of the rate.
    pub fn servo(&mut self, clock_at_rx_ns: u64, clock_at_rx_frac: f64) -> Option<ClockAdjust> {
        if self.is_grandmaster() {
            return None;
        }
        let s = self.last_sync?;
        let (gm_ns, gm_frac) = self.gm_time_at(s.rx_ns)?;
        let offset =
            (clock_at_rx_ns.wrapping_sub(gm_ns) as i64) as f64 + (clock_at_rx_frac - gm_frac);
        self.last_offset_ns = Some(offset);
        if !self.stepped {
            self.stepped = true;
            self.integral = 0.0;
            self.frequency = s.rate_ratio - 1.0;
            return Some(ClockAdjust {
                step_ns: -offset,
                frequency: self.frequency,
            });
        }
        let interval = self.cfg.sync_interval_ns as f64;
        self.integral += self.cfg.ki * offset / interval;
        self.frequency = (s.rate_ratio - 1.0) - self.cfg.kp * offset / interval - self.integral;
        Some(ClockAdjust {
            step_ns: 0.0,
            frequency: self.frequency,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(p1: u8, last: u8) -> SystemIdentity {
        SystemIdentity::with_default_quality(p1, [0, 0, 0, 0xff, 0xfe, 0, 0, last])
    }

    /// Peer delay by hand: the responder's clock runs 100 ppm fast and is 1 ms ahead; the link
    /// is 500 ns each way; the responder turns the request around in 10 us of its time.
    #[test]
    fn peer_delay_and_neighbor_rate_ratio_by_hand() {
        let mut a = TimeAwareSystem::new(Config::new(id(246, 1), 1));
        let mut out = Vec::new();
        let rate = 1.0001;
        let resp_time = |true_ns: f64| 1_000_000.0 + true_ns * rate;
        for k in 0..3u64 {
            let t = k * 1_000_000_000 + 10_000_000;
            a.poll(t, &mut out);
            let req = out
                .iter()
                .find(|o| o.message == Message::PdelayReq)
                .copied()
                .unwrap();
            out.clear();
            a.on_tx_timestamp(0, &req.header, &req.message, t, &mut out); // t1 (local = true)
            let t2 = resp_time(t as f64 + 500.0).round() as u64;
            let t3 = t2 + 10_000;
            let t4 = ((t3 as f64 - 1_000_000.0) / rate + 500.0).round() as u64;
            let peer = PortIdentity {
                clock_identity: [9; 8],
                port_number: 1,
            };
            let hr = Header {
                source: peer,
                sequence_id: req.header.sequence_id,
                ..Header::default()
            };
            a.on_message(
                0,
                &hr,
                &Message::PdelayResp {
                    request_receipt: Timestamp::from_ns(t2),
                    requesting: a.port_identity(0),
                },
                t4,
                &mut out,
            );
            a.on_message(
                0,
                &hr,
                &Message::PdelayRespFollowUp {
                    response_origin: Timestamp::from_ns(t3),
                    requesting: a.port_identity(0),
                },
                t4,
                &mut out,
            );
            out.clear();
        }
        assert!(
            (a.neighbor_rate_ratio(0) - 1.0001).abs() < 1e-9,
            "{}",
            a.neighbor_rate_ratio(0)
        );
        let d = a.mean_link_delay_ns(0).unwrap();
        // ((t4 - t1) * r - (t3 - t2)) / 2 = 500 ns (within the 1 ns rounding of t2, t4).
        assert!((d - 500.0).abs() < 1.0, "{d}");
    }

    /// BMCA: a better Announce makes its port the slave port and the sender's grandmaster ours;
    /// an Announce that carries our own identity in its path is ignored; expiry restores us.
    #[test]
    fn bmca_picks_the_better_grandmaster_and_expires_it() {
        let mut b = TimeAwareSystem::new(Config::new(id(246, 5), 2));
        let mut out = Vec::new();
        b.poll(0, &mut out);
        assert!(b.is_grandmaster());
        let better = id(100, 9);
        let mut a = Announce {
            priority1: better.priority1,
            clock_quality: better.quality,
            priority2: better.priority2,
            grandmaster_identity: better.clock_identity,
            steps_removed: 0,
            ..Announce::default()
        };
        a.path[0] = better.clock_identity;
        a.path_len = 1;
        let h = Header {
            source: PortIdentity {
                clock_identity: better.clock_identity,
                port_number: 1,
            },
            ..Header::default()
        };
        b.on_message(1, &h, &Message::Announce(a), 1_000, &mut out);
        assert_eq!(b.grandmaster(), better);
        assert_eq!((b.role(0), b.role(1)), (PortRole::Master, PortRole::Slave));
        // Our own identity in the path: a loop, ignored.
        let mut looped = a;
        looped.path[1] = id(246, 5).clock_identity;
        looped.path_len = 2;
        looped.priority1 = 1;
        b.on_message(0, &h, &Message::Announce(looped), 2_000, &mut out);
        assert_eq!(b.grandmaster(), better);
        // Three announce intervals of silence: back to itself.
        b.poll(1_000 + 3_000_000_000, &mut out);
        assert!(b.is_grandmaster());
    }
}
