//! Frames out, frames in, on a raw socket in real time: the real network's [`Transport`].

use crate::sys::{self, OpenError, PacketSocket, Phc, Ready, TimestampSupport};
use crate::tx_stamp::{PHC_READINGS, PHC_REFRESH_NS, PhcMap, TxStampSource, phc_offset_ns};
use crate::wall_clock::RealtimeMap;
use ecsync_dc::time::MasterInstant;
use ecsync_master::redundancy::SecondPort;
use ecsync_master::transport::{Received, Transport};
use std::io;

/// Nanoseconds from 1970-01-01 to 2000-01-01, the epoch of DC system time.
pub const DC_EPOCH_UNIX_NS: u64 = 946_684_800_000_000_000;

/// Receive buffer length: the longest Ethernet frame with a VLAN tag, and room to spare.
const RECV_BUF_LEN: usize = 2048;

/// The master's clock on a real host: CLOCK_MONOTONIC (steady, never stepped) shifted once, at
/// start, so that it reads DC time (ns since 2000) the way the wall clock did then.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HostClock {
    offset_ns: u64,
}

impl Default for HostClock {
    fn default() -> Self {
        Self::new()
    }
}

impl HostClock {
    /// The clock, aligned to the wall clock now.
    pub fn new() -> Self {
        let rt = sys::realtime_ns();
        let mono = sys::monotonic_ns();
        HostClock {
            offset_ns: rt.wrapping_sub(DC_EPOCH_UNIX_NS).wrapping_sub(mono),
        }
    }

    /// Master time now, ns since 2000.
    pub fn now_ns(&self) -> u64 {
        sys::monotonic_ns().wrapping_add(self.offset_ns)
    }

    /// CLOCK_MONOTONIC at master time `t_ns`.
    pub fn to_monotonic_ns(&self, t_ns: u64) -> u64 {
        t_ns.wrapping_sub(self.offset_ns)
    }

    /// Sleeps until master time `t_ns` (absolute).
    pub fn sleep_until(&self, t_ns: u64) {
        sys::sleep_until_monotonic(self.to_monotonic_ns(t_ns));
    }

    /// Master time at CLOCK_MONOTONIC `mono_ns`.
    pub fn from_monotonic_ns(&self, mono_ns: u64) -> u64 {
        mono_ns.wrapping_add(self.offset_ns)
    }
}

/// What went wrong on the network.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    /// The socket could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// A socket call failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: &'static str,
        /// The error.
        source: io::Error,
    },
    /// The bring-up failed.
    #[error("bring-up: {0}")]
    Bringup(#[from] ecsync_master::MasterError),
}

/// A master's link: one raw socket and the host clock, as a [`Transport`]: the one bring-up
/// driver and the one cyclic driver of `ecsync-master` run over it.
#[derive(Debug)]
pub struct RealLink {
    sock: PacketSocket,
    clock: HostClock,
    /// The transmit timestamp (CLOCK_REALTIME) of the last frame sent, or in the cyclic phase
    /// of the cycle's first frame, once read, and the wall clock's epoch it was read in.
    tx_rt: Option<(u64, u64)>,
    /// Kernel stamps onto the monotonic clock, minding steps of the wall clock.
    rt_map: RealtimeMap,
    /// In the cyclic phase: frames sent since the cycle started (the first stamp read after
    /// the first is that frame's: the error queue keeps the order of the sends).
    sent_in_cycle: Option<u32>,
    /// The NIC's PTP hardware clock and its mapping to CLOCK_REALTIME, with hardware
    /// transmit stamps on; the next instant (CLOCK_REALTIME) the mapping is measured again.
    phc: Option<(Phc, PhcMap, u64)>,
    /// The NIC's timestamping setting before hardware stamps were switched on.
    hw_restore: Option<sys::HwStampSetting>,
    /// CLOCK_REALTIME right before the cycle's first send: a stamp earlier than it is a
    /// stale one of an earlier frame (a NIC that queued it late).
    first_send_rt: u64,
    /// The frame being sent.
    tx_buf: Vec<u8>,
    /// Sends and receives refused because the interface was down.
    link_down: u64,
    /// How the cyclic task reaches its send instant.
    send: SendControl,
    /// The cycle the driver is about to run (its start is the next wait), if one.
    cycle_armed: Option<u64>,
    /// The second master port of a ring (cable redundancy, [`SecondPort`]): its socket, and
    /// its sends and receives refused because its interface was down.
    ring: Option<(PacketSocket, u64)>,
}

/// How a real master's cyclic task reaches the instant it sends at.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SendControl {
    /// Busy-wait the last this many ns before each cycle's start instead of sleeping through
    /// them (`None`: sleep to the instant, the kernel's timer wakes the task as late as it
    /// does).
    pub spin_margin_ns: Option<u64>,
    /// Spin in odd cycles only: the two ways side by side in one run, on the same host at the
    /// same moments.
    pub alternate: bool,
    /// CPU time spent busy-waiting so far, ns, and the cycles that spun.
    pub spun_ns: u64,
    /// Cycles that spun.
    pub spun_cycles: u64,
}

impl SendControl {
    /// Whether cycle `cycle` spins.
    pub fn spins(&self, cycle: u64) -> bool {
        self.spin_margin_ns.is_some() && (!self.alternate || cycle % 2 == 1)
    }
}

impl RealLink {
    /// Sends and receives refused because the interface was down (each such frame counted
    /// lost).
    pub fn link_down_errors(&self) -> u64 {
        self.link_down
    }

    /// Opens interface `iface`.
    pub fn open(iface: &str) -> Result<RealLink, NetError> {
        Ok(RealLink {
            sock: PacketSocket::open(iface)?,
            link_down: 0,
            clock: HostClock::new(),
            tx_rt: None,
            rt_map: RealtimeMap::new(),
            sent_in_cycle: None,
            phc: None,
            hw_restore: None,
            first_send_rt: 0,
            tx_buf: Vec::with_capacity(RECV_BUF_LEN),
            send: SendControl::default(),
            cycle_armed: None,
            ring: None,
        })
    }

    /// Opens `iface` as the second master port of a ring: the far end of the line cabled
    /// back (cable redundancy). Frames sent there with [`SecondPort::send_secondary`] and
    /// frames arriving there come back through [`Transport::recv`] with port 1; wrap the link
    /// in [`ecsync_master::redundancy::Redundant`] to send every frame on both ports.
    pub fn open_ring(&mut self, iface: &str) -> Result<(), NetError> {
        self.ring = Some((PacketSocket::open(iface)?, 0));
        Ok(())
    }

    /// Sends and receives refused because the second port's interface was down.
    pub fn ring_link_down_errors(&self) -> u64 {
        self.ring.as_ref().map_or(0, |r| r.1)
    }

    /// Sets how the cyclic task reaches its send instants.
    pub fn set_send_control(&mut self, c: SendControl) {
        self.send = c;
    }

    /// How the cyclic task reaches its send instants, with what spinning cost so far.
    pub fn send_control(&self) -> SendControl {
        self.send
    }

    /// The clock.
    pub fn clock(&self) -> &HostClock {
        &self.clock
    }

    /// Kernel timestamps available.
    pub fn timestamps(&self) -> TimestampSupport {
        self.sock.timestamps()
    }

    /// Switches `iface`'s NIC to hardware transmit timestamps and takes them as the frames'
    /// transmit stamps from now on ([`Received::tx_stamp`]), mapped from its PTP hardware
    /// clock to the host's; the NIC's setting is put back when the link is dropped. Refused,
    /// naming what is missing, where the NIC has none; nothing is changed then (the PHC is
    /// opened and read before the NIC and the socket are switched).
    pub fn enable_hardware_tx_stamps(&mut self, iface: &str) -> Result<(), String> {
        let caps = sys::nic_timestamping(iface)
            .map_err(|e| format!("ethtool -T {iface} (ETHTOOL_GET_TS_INFO): {e}"))?;
        let index = caps
            .phc_index
            .ok_or_else(|| format!("{iface} has no PTP hardware clock"))?;
        let phc = Phc::open(index).map_err(|e| format!("/dev/ptp{index}: {e}"))?;
        let mut map = PhcMap::default();
        measure_phc(&phc, &mut map)
            .ok_or_else(|| format!("/dev/ptp{index} cannot be read (clock_gettime)"))?;
        let setting = self
            .sock
            .enable_hardware_tx_stamps(iface)
            .map_err(|e| format!("hardware TX timestamps on {iface}: {e}"))?;
        self.hw_restore = Some(setting);
        self.phc = Some((phc, map, sys::realtime_ns() + PHC_REFRESH_NS));
        Ok(())
    }

    /// Where the transmit stamps come from: the NIC, the kernel, or nowhere.
    pub fn tx_stamp_source(&self) -> Option<TxStampSource> {
        if self.phc.is_some() {
            Some(TxStampSource::NicHardware)
        } else if self.sock.timestamps().tx_software {
            Some(TxStampSource::KernelSoftware)
        } else {
            None
        }
    }

    /// Reads the queued transmit stamps: the first of the cycle's first frame, in the cyclic
    /// phase, is kept (a hardware one, with hardware stamps on); `discard` empties the queue.
    fn read_tx_stamps(&mut self, discard: bool) -> Result<(), NetError> {
        // The epoch the stamps were taken in: the one before this reading of the clocks'
        // difference (a step seen now may lie between a stamp and this read).
        let epoch = self.rt_map.epoch();
        self.rt_map.refresh();
        while let Some(m) = self.sock.take_tx_stamps().map_err(io_err("TX timestamp"))? {
            if discard || self.tx_rt.is_some() {
                continue;
            }
            let t = match &self.phc {
                Some((_, map, _)) => m.hardware_ns.and_then(|t| map.to_realtime_ns(t)),
                None => m.software_ns,
            };
            // (The PHC's mapping may put a true stamp a little early: a microsecond of slack.)
            self.tx_rt = t
                .filter(|&t| t + 1_000 >= self.first_send_rt)
                .map(|t| (t, epoch));
        }
        Ok(())
    }

    /// Whether the interface is promiscuous.
    pub fn promiscuous(&self) -> bool {
        self.sock.promiscuous()
    }
}

impl Drop for RealLink {
    fn drop(&mut self) {
        if let Some(s) = self.hw_restore.take() {
            sys::restore_hw_tx_stamps(&s);
        }
    }
}

/// Measures the PHC's offset from CLOCK_REALTIME into `map` (the narrowest of a few
/// readings); `None` if no reading worked.
fn measure_phc(phc: &Phc, map: &mut PhcMap) -> Option<()> {
    let readings: [(u64, u64, u64); PHC_READINGS] = std::array::from_fn(|_| phc.sandwich());
    let (at, offset) = phc_offset_ns(&readings)?;
    map.add(at, offset);
    Some(())
}

fn io_err(what: &'static str) -> impl Fn(io::Error) -> NetError {
    move |source| NetError::Io { what, source }
}

impl Transport for RealLink {
    type Error = NetError;

    fn now(&mut self) -> MasterInstant {
        MasterInstant::from_ns(self.clock.now_ns())
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        let t_ns = t.as_ns();
        // The PHC's mapping measured again when due, in the time the task would sleep anyway
        // (never between a cycle's wake-up and its frames).
        if let Some((phc, map, next)) = &mut self.phc
            && sys::realtime_ns() >= *next
        {
            measure_phc(phc, map);
            *next = sys::realtime_ns() + PHC_REFRESH_NS;
        }
        let spin = match self.cycle_armed.take() {
            Some(c) if self.send.spins(c) => self.send.spin_margin_ns,
            _ => None,
        };
        let Some(margin) = spin else {
            if t_ns > self.clock.now_ns() {
                self.clock.sleep_until(t_ns);
            }
            return;
        };
        // The timer wakes the task `margin` early (late by the kernel's wake-up latency);
        // the rest is a busy loop on the clock, which no scheduler latency delays unless the
        // task is preempted in it.
        let wake = t_ns.saturating_sub(margin);
        if wake > self.clock.now_ns() {
            self.clock.sleep_until(wake);
        }
        let from = self.clock.now_ns();
        let mut now = from;
        while now < t_ns {
            std::hint::spin_loop();
            now = self.clock.now_ns();
        }
        self.send.spun_ns += now.saturating_sub(from);
        self.send.spun_cycles += 1;
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.cycle_armed = Some(cycle);
        self.sent_in_cycle = Some(0);
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, NetError> {
        self.tx_buf.resize(len, 0);
        fill(&mut self.tx_buf);
        // The transmit timestamps of earlier frames must not be taken for this one's (in the
        // cyclic phase: for the cycle's first frame's).
        let first = self.sent_in_cycle.is_none_or(|n| n == 0);
        self.read_tx_stamps(first)?;
        if first {
            self.tx_rt = None;
            self.first_send_rt = sys::realtime_ns();
        }
        if let Some(n) = &mut self.sent_in_cycle {
            *n += 1;
        }
        match self.sock.send(&self.tx_buf) {
            Ok(()) => {}
            // Lost on a link that is down: the reply's deadline tells the driver.
            Err(e) if sys::link_is_down(&e) => self.link_down += 1,
            Err(e) => return Err(io_err("send")(e)),
        }
        Ok(at)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, NetError> {
        let deadline = self.clock.to_monotonic_ns(deadline.as_ns());
        // Room for the longest Ethernet frame (and a VLAN tag): a longer one is reported
        // truncated.
        if buf.len() < RECV_BUF_LEN {
            buf.resize(RECV_BUF_LEN, 0);
        }
        // A receive stamp is from this epoch of the wall clock or an earlier one.
        let rx_epoch = self.rt_map.epoch();
        loop {
            let first = self.take_frame(buf, 0, rx_epoch)?;
            if let Taken::Frame(r) = first {
                return Ok(Some(r));
            }
            let first_down = first == Taken::Down;
            if first_down && self.ring.is_none() {
                // No link: nothing can come before the deadline but the link itself.
                let now = sys::monotonic_ns();
                if now >= deadline {
                    return Ok(None);
                }
                std::thread::sleep(std::time::Duration::from_nanos(
                    (deadline - now).min(1_000_000),
                ));
                continue;
            }
            if let Taken::Frame(r) = self.take_frame(buf, 1, rx_epoch)? {
                return Ok(Some(r));
            }
            let now = sys::monotonic_ns();
            if now >= deadline {
                return Ok(None);
            }
            // A first port that is down is not waited on (its error would end every wait): the
            // second port's frames come meanwhile.
            let first_sock = (!first_down).then_some(&self.sock);
            let ring = self.ring.as_ref().map(|r| &r.0);
            let wait_ns = if first_down {
                (deadline - now).min(1_000_000)
            } else {
                deadline - now
            };
            let ready = match sys::wait_any([first_sock, ring], wait_ns) {
                Ok(r) => r,
                Err(e) if sys::link_is_down(&e) => {
                    self.link_down += 1;
                    continue;
                }
                Err(e) => return Err(io_err("wait for a reply")(e)),
            };
            if ready[0] == Ready::ErrorQueue {
                // Read it, or the next wait returns at once (a busy loop that would starve a
                // peer on the same CPU).
                self.read_tx_stamps(false)?;
            }
            if ready[1] == Ready::ErrorQueue
                && let Some((r, _)) = &self.ring
            {
                // The second port's transmit stamps: no method takes them.
                while r
                    .take_tx_stamps()
                    .map_err(io_err("TX timestamp"))?
                    .is_some()
                {}
            }
        }
    }
}

impl RealLink {
    /// A frame from port `port`'s socket, if one is there.
    fn take_frame(&mut self, buf: &mut [u8], port: u8, rx_epoch: u64) -> Result<Taken, NetError> {
        let (sock, down) = match (port, &mut self.ring) {
            (0, _) => (&self.sock, &mut self.link_down),
            (_, Some((s, down))) => (&*s, down),
            (_, None) => return Ok(Taken::Nothing),
        };
        let r = match sock.recv(buf) {
            Ok(Some(r)) => r,
            Ok(None) => return Ok(Taken::Nothing),
            Err(e) if sys::link_is_down(&e) => {
                *down += 1;
                return Ok(Taken::Down);
            }
            Err(e) => return Err(io_err("receive")(e)),
        };
        let now = self.clock.now_ns();
        // A stamp across the step just seen goes on its side of the step; one across two is
        // no stamp: the frame counts unstamped (received now).
        let rx_mono = r
            .kernel_rx_realtime_ns
            .and_then(|t| self.rt_map.to_monotonic_ns(t, rx_epoch));
        let (received_ns, stamped) = match rx_mono {
            Some(m) => (self.clock.from_monotonic_ns(m), true),
            None => (now, false),
        };
        if self.tx_rt.is_none() {
            self.read_tx_stamps(false)?;
        }
        let tx_mono = self
            .tx_rt
            .and_then(|(t, e)| self.rt_map.to_monotonic_ns(t, e));
        Ok(Taken::Frame(Received {
            len: r.len.min(buf.len()),
            received: MasterInstant::from_ns(received_ns),
            tx_stamp: tx_mono.map(|m| MasterInstant::from_ns(self.clock.from_monotonic_ns(m))),
            stamped,
            truncated: r.truncated,
            port,
        }))
    }
}

/// What a port's socket had.
#[derive(Debug, PartialEq)]
enum Taken {
    Frame(Received),
    Nothing,
    /// The interface is down (counted).
    Down,
}

impl SecondPort for RealLink {
    fn send_secondary(&mut self, frame: &[u8], _at: MasterInstant) -> Result<(), NetError> {
        let Some((sock, down)) = &mut self.ring else {
            return Ok(());
        };
        match sock.send(frame) {
            Ok(()) => Ok(()),
            // Lost on a link that is down: the first port's copy may still come back.
            Err(e) if sys::link_is_down(&e) => {
                *down += 1;
                Ok(())
            }
            Err(e) => Err(io_err("send on the ring's second port")(e)),
        }
    }
}
