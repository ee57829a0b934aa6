//! Frames out, replies in, on a raw socket in real time.

use crate::sys::{self, OpenError, PacketSocket, Ready, TimestampSupport};
use ecsync_master::{Action, Engine, Event};
use std::io;

/// Nanoseconds from 1970-01-01 to 2000-01-01, the epoch of DC system time.
pub const DC_EPOCH_UNIX_NS: u64 = 946_684_800_000_000_000;

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

    /// Master time of a kernel timestamp (CLOCK_REALTIME ns since 1970), through the current
    /// difference of the two clocks.
    pub fn from_realtime_ns(&self, rt_ns: u64) -> u64 {
        let rt_minus_mono = sys::realtime_ns().wrapping_sub(sys::monotonic_ns());
        rt_ns
            .wrapping_sub(rt_minus_mono)
            .wrapping_add(self.offset_ns)
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

/// Counters of a link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkStats {
    /// Frames sent.
    pub sent: u64,
    /// Replies matched to the frame they answer.
    pub replies: u64,
    /// Frames whose reply did not come back in time.
    pub lost: u64,
    /// EtherCAT frames received that answered nothing pending (late replies to lost frames,
    /// other masters' traffic).
    pub unmatched: u64,
    /// Frames too long for the buffer.
    pub truncated: u64,
}

/// A reply and its timestamps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchanged<'a> {
    /// The frame as it came back.
    pub reply: &'a [u8],
    /// Master time taken right before the send call (t_ms), ns.
    pub sent_ns: u64,
    /// Master time the reply arrived (the kernel's timestamp when it gives one), ns.
    pub received_ns: u64,
    /// The kernel's software transmit timestamp, master time, ns.
    pub kernel_tx_ns: Option<u64>,
    /// Whether `received_ns` is the kernel's receive timestamp (else the time `recv` returned).
    pub kernel_rx: bool,
}

/// A master's link: one raw socket, the host clock, a reply timeout.
#[derive(Debug)]
pub struct RealLink {
    sock: PacketSocket,
    clock: HostClock,
    /// How long to wait for a reply before the frame counts as lost, ns.
    pub timeout_ns: u64,
    /// In [`RealLink::run`] (the bring-up), how long to wait for a reply, ns, and how often a
    /// lost frame is sent again before the procedure hears of the loss (as SOEM and ethercrab
    /// do: the first frames meet cold caches and page faults on both ends).
    pub procedure_timeout_ns: u64,
    /// See `procedure_timeout_ns`.
    pub procedure_retries: u32,
    buf: Vec<u8>,
    stats: LinkStats,
}

/// The frame `reply` answers `sent` if its first datagram has the same command and index and
/// it is at least as long (a NIC may pad it).
fn answers(sent: &[u8], reply: &[u8]) -> bool {
    reply.len() >= sent.len()
        && reply.len() >= 18
        && sent.len() >= 18
        && reply[12..14] == sent[12..14]
        && reply[16] == sent[16]
        && reply[17] == sent[17]
}

impl RealLink {
    /// Opens interface `iface`.
    pub fn open(iface: &str) -> Result<RealLink, NetError> {
        Ok(RealLink {
            sock: PacketSocket::open(iface)?,
            clock: HostClock::new(),
            timeout_ns: 2_000_000,
            procedure_timeout_ns: 20_000_000,
            procedure_retries: 3,
            buf: vec![0; 2048],
            stats: LinkStats::default(),
        })
    }

    /// The clock.
    pub fn clock(&self) -> &HostClock {
        &self.clock
    }

    /// Counters so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Kernel timestamps available.
    pub fn timestamps(&self) -> TimestampSupport {
        self.sock.timestamps()
    }

    /// Whether the interface is promiscuous.
    pub fn promiscuous(&self) -> bool {
        self.sock.promiscuous()
    }

    /// Sends `frame` (after dropping whatever arrived late) and waits for its reply until the
    /// timeout. `None`: lost.
    pub fn exchange(&mut self, frame: &[u8]) -> Result<Option<Exchanged<'_>>, NetError> {
        let io = |what| move |source| NetError::Io { what, source };
        // Late replies of earlier frames must not be taken for this one's.
        while let Some(r) = self.sock.recv(&mut self.buf).map_err(io("receive"))? {
            self.stats.unmatched += 1;
            self.stats.truncated += u64::from(r.truncated);
        }
        while self
            .sock
            .take_tx_timestamp()
            .map_err(io("TX timestamp"))?
            .is_some()
        {}
        let sent_ns = self.clock.now_ns();
        self.sock.send(frame).map_err(io("send"))?;
        self.stats.sent += 1;
        let deadline = self.clock.to_monotonic_ns(sent_ns) + self.timeout_ns;
        let mut tx_rt = None;
        loop {
            match self.sock.recv(&mut self.buf).map_err(io("receive"))? {
                Some(r) if !r.truncated && answers(frame, &self.buf[..r.len]) => {
                    let now = self.clock.now_ns();
                    let (received_ns, kernel_rx) = match r.kernel_rx_realtime_ns {
                        Some(t) => (self.clock.from_realtime_ns(t), true),
                        None => (now, false),
                    };
                    if tx_rt.is_none() {
                        tx_rt = self.sock.take_tx_timestamp().map_err(io("TX timestamp"))?;
                    }
                    self.stats.replies += 1;
                    return Ok(Some(Exchanged {
                        reply: &self.buf[..r.len],
                        sent_ns,
                        received_ns,
                        kernel_tx_ns: tx_rt.map(|t| self.clock.from_realtime_ns(t)),
                        kernel_rx,
                    }));
                }
                Some(r) => {
                    self.stats.unmatched += 1;
                    self.stats.truncated += u64::from(r.truncated);
                }
                None => {
                    let now = sys::monotonic_ns();
                    if now >= deadline {
                        self.stats.lost += 1;
                        return Ok(None);
                    }
                    match self
                        .sock
                        .wait(deadline - now)
                        .map_err(io("wait for a reply"))?
                    {
                        Ready::ErrorQueue => {
                            // Read it, or the next wait returns at once (a busy loop that
                            // would starve a peer on the same CPU).
                            let t = self.sock.take_tx_timestamp().map_err(io("TX timestamp"))?;
                            if tx_rt.is_none() {
                                tx_rt = t;
                            }
                        }
                        Ready::Frame | Ready::Nothing => {}
                    }
                }
            }
        }
    }

    /// Runs a sans-IO procedure (the DC bring-up, say) to completion in real time; `on_event`
    /// sees what it reports along the way.
    pub fn run<T: 'static>(
        &mut self,
        engine: &mut Engine<T>,
        mut on_event: impl FnMut(&Event),
    ) -> Result<T, NetError> {
        loop {
            let now = self.clock.now_ns();
            let frame = match engine.poll(now) {
                Action::Done(v) => return Ok(v),
                Action::WaitUntil(t) => {
                    if t > now {
                        self.clock.sleep_until(t);
                    }
                    continue;
                }
                Action::Send(f) => f.to_vec(),
            };
            let cyclic_timeout = self.timeout_ns;
            self.timeout_ns = self.procedure_timeout_ns;
            let mut got = None;
            for _ in 0..=self.procedure_retries {
                if let Some(x) = self.exchange(&frame)? {
                    got = Some((x.reply.to_vec(), x.sent_ns, x.received_ns));
                    break;
                }
            }
            self.timeout_ns = cyclic_timeout;
            match got {
                Some((reply, sent, received)) => engine.handle_reply(&reply, sent, received),
                None => engine.handle_lost(),
            }
            for e in engine.take_events() {
                on_event(&e);
            }
        }
    }
}
