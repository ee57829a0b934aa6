//! What the master engine needs of a network and a host, and nothing more: a clock, a way to
//! wait, frames out and frames in with their timestamps. The in-process segment
//! (`ecsync_sim::transport::SimTransport`), the raw socket (`ecsync-net`) and the TSN network
//! (`ecsync-tsn`) implement it; the one bring-up driver and the one cyclic driver
//! ([`crate::driver`]) run the engine over any of them, so the real path differs from the
//! simulator only here.

use ecsync_dc::time::{MasterDuration, MasterInstant};

/// A frame that arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Received {
    /// Bytes written into the caller's buffer.
    pub len: usize,
    /// When the frame arrived (a receive timestamp where the transport has one).
    pub received: MasterInstant,
    /// The transmit timestamp of the last frame sent, where the transport has one (a kernel or
    /// NIC stamp).
    pub tx_stamp: Option<MasterInstant>,
    /// Whether `received` is a receive timestamp of the kernel or NIC (else the time the
    /// transport saw the frame).
    pub stamped: bool,
    /// The frame did not fit the buffer (only the first `len` bytes are there).
    pub truncated: bool,
    /// The master port it arrived on: 0 the first (the only one of most transports), 1 the
    /// second of a ring ([`crate::redundancy::SecondPort`]).
    pub port: u8,
}

impl Received {
    /// When the frame arrived, master time, ns.
    pub fn received_ns(&self) -> u64 {
        self.received.as_ns()
    }

    /// The transmit timestamp, master time, ns.
    pub fn tx_stamp_ns(&self) -> Option<u64> {
        self.tx_stamp.map(MasterInstant::as_ns)
    }
}

/// A network and the host's clock, as the master engine sees them. Every instant is the
/// master's clock's ([`MasterInstant`]).
pub trait Transport {
    /// What can go wrong (the simulator's transports cannot fail).
    type Error: std::error::Error + 'static;

    /// The master's clock now.
    fn now(&mut self) -> MasterInstant;

    /// Waits until `t` (at once if it has passed). A host wakes late by its scheduling
    /// latency: read [`Transport::now`] after it.
    fn sleep_until(&mut self, t: MasterInstant);

    /// When a frame of `len` bytes handed over now leaves: now, for a host that sends at
    /// once; a later launch time for a NIC that schedules its frames (TSN).
    fn send_time(&mut self, len: usize) -> MasterInstant {
        let _ = len;
        self.now()
    }

    /// Sends a frame of `len` bytes, to leave at `at` (from [`Transport::send_time`]);
    /// returns its send timestamp (`at` itself, or the NIC's stamp of the launch). `fill`
    /// writes the whole frame into the transport's own buffer (`len` bytes of unspecified
    /// content), so that a frame is built where it leaves from, without a copy (smoltcp's
    /// transmit token works the same way).
    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Self::Error>;

    /// Sends `frame`, to leave at `at`: [`Transport::send_with`] with a copy.
    fn send(&mut self, frame: &[u8], at: MasterInstant) -> Result<MasterInstant, Self::Error> {
        self.send_with(frame.len(), at, |buf| buf.copy_from_slice(frame))
    }

    /// The next frame that arrives before `deadline`, as `buf[..len]`; `None` once the
    /// deadline has passed (the transport's time is then at the deadline or later).
    ///
    /// A transport that already holds the frame in a buffer of its own (the simulated segment)
    /// swaps that buffer in instead of copying; one that reads from a device grows `buf` to the
    /// longest frame it accepts and reads into it.
    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Self::Error>;

    /// The cyclic driver is about to run cycle `cycle` (a simulated host draws that cycle's
    /// noise; a real one has nothing to do).
    fn start_cycle(&mut self, cycle: u64) {
        let _ = cycle;
    }
}

/// The error of a transport that cannot fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("infallible")]
pub enum Never {}

/// A transport that gives up when asked: every send, wait and receive first looks at `stop`,
/// and once it is set fails with [`Interrupted::Stopped`]. A procedure (a bring-up of thousands
/// of slaves runs for minutes of CPU time) driven over it ends within one exchange of Ctrl-C.
#[derive(Debug)]
pub struct Interruptible<'a, T> {
    /// The transport.
    pub inner: &'a mut T,
    stop: &'a core::sync::atomic::AtomicBool,
}

impl<'a, T: Transport> Interruptible<'a, T> {
    /// `inner`, stopped by setting `stop`.
    pub fn new(inner: &'a mut T, stop: &'a core::sync::atomic::AtomicBool) -> Self {
        Interruptible { inner, stop }
    }

    fn check(&self) -> Result<(), Interrupted<T::Error>> {
        if self.stop.load(core::sync::atomic::Ordering::Relaxed) {
            Err(Interrupted::Stopped)
        } else {
            Ok(())
        }
    }
}

/// Why an [`Interruptible`] transport failed.
#[derive(Debug, thiserror::Error)]
pub enum Interrupted<E: std::error::Error + 'static> {
    /// Its stop flag was set.
    #[error("stopped")]
    Stopped,
    /// The transport itself failed.
    #[error(transparent)]
    Transport(E),
}

impl<T: Transport> Transport for Interruptible<'_, T> {
    type Error = Interrupted<T::Error>;

    fn now(&mut self) -> MasterInstant {
        self.inner.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        // A wait cannot fail: a stop during it is seen by the send or receive that follows.
        self.inner.sleep_until(t);
    }

    fn send_time(&mut self, len: usize) -> MasterInstant {
        self.inner.send_time(len)
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Self::Error> {
        self.check()?;
        self.inner
            .send_with(len, at, fill)
            .map_err(Interrupted::Transport)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Self::Error> {
        self.check()?;
        self.inner
            .recv(buf, deadline)
            .map_err(Interrupted::Transport)
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.inner.start_cycle(cycle);
    }
}

/// Host stalls: the transport `inner`, whose cyclic task wakes late in chosen cycles (a page
/// fault, an interrupt storm, a VM's neighbour) and on time in the others. The cyclic driver's
/// overrun policy meets them the same way over any transport.
#[derive(Debug)]
pub struct HostStall<T> {
    /// The transport.
    pub inner: T,
    /// The cycles whose wake-up stalls, and by how much.
    stalls: Vec<(u64, MasterDuration)>,
    /// The stall of the cycle about to run (taken by its first wait).
    armed: MasterDuration,
}

impl<T> HostStall<T> {
    /// `inner` with a stall of `stall` in cycle `at_cycle`.
    pub fn new(inner: T, at_cycle: u64, stall: MasterDuration) -> Self {
        Self::at_cycles(inner, vec![(at_cycle, stall)])
    }

    /// `inner` with a stall in each of `stalls`' cycles (cycle, how long; the first entry of
    /// a cycle counts).
    pub fn at_cycles(inner: T, stalls: Vec<(u64, MasterDuration)>) -> Self {
        HostStall {
            inner,
            stalls,
            armed: MasterDuration::ZERO,
        }
    }
}

impl<T: Transport> Transport for HostStall<T> {
    type Error = T::Error;

    fn now(&mut self) -> MasterInstant {
        self.inner.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        let extra = std::mem::take(&mut self.armed);
        self.inner.sleep_until(t.saturating_add(extra));
    }

    fn send_time(&mut self, len: usize) -> MasterInstant {
        self.inner.send_time(len)
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, T::Error> {
        self.inner.send_with(len, at, fill)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, T::Error> {
        self.inner.recv(buf, deadline)
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.armed = self
            .stalls
            .iter()
            .find(|s| s.0 == cycle)
            .map_or(MasterDuration::ZERO, |s| s.1);
        self.inner.start_cycle(cycle);
    }
}

/// How the host hands a cyclic frame to the wire: the modes `compare` simulates and `ecsync
/// run` implements (its `--send`; hardware transmit stamps are its `--tx-stamp`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum SendMode {
    /// Timestamp and send when the task gets there (the letter's testbed).
    Plain,
    /// Wake early, busy-wait to the instant.
    Spin,
    /// Hand the frame over early with its launch time.
    Txtime,
    /// Send as plain; t_ms is the NIC's hardware transmit stamp.
    Hwstamp,
}

impl SendMode {
    /// Every mode, in report order.
    pub const ALL: [SendMode; 4] = [
        SendMode::Plain,
        SendMode::Spin,
        SendMode::Txtime,
        SendMode::Hwstamp,
    ];

    /// The mode's name as written in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            SendMode::Plain => "plain",
            SendMode::Spin => "spin",
            SendMode::Txtime => "txtime",
            SendMode::Hwstamp => "hwstamp",
        }
    }

    /// Whether method `kind` runs with this mode: a transmit stamp comes after the send, which
    /// a bus-shift method has written into the frame already.
    pub fn applies_to(self, kind: ecsync_dc::MethodKind) -> bool {
        self != SendMode::Hwstamp || kind.is_master_shift()
    }
}

impl std::fmt::Display for SendMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for SendMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        SendMode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("no send mode \"{s}\": plain, spin, txtime or hwstamp"))
    }
}
