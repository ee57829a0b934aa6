//! The virtual segment on a network interface: every EtherCAT frame that arrives is processed by
//! the segment at the instant it arrived and sent back, as the last ESC's open port would return
//! it. The ESCs' clocks run on CLOCK_MONOTONIC with their configured crystal errors, so a master
//! on the other end sees drifting slave clocks, propagation delays and a time control loop as on
//! real hardware.
//!
//! As a real ESC does with whatever arrives at its port 0, every EtherCAT frame is processed,
//! whatever its source address says (a master whose NIC address is locally administered, bit
//! 0x02 of the first byte set, is answered like any other). The segment's own answers, which a
//! packet socket would see again on the way out, are told apart by the socket address's packet
//! type (`PACKET_OUTGOING`, see [`crate::sys::PacketSocket`]), not by the frame's contents.
//!
//! A request in a VLAN tag (IEEE 802.1Q or 802.1ad) is answered in the same tag, as ESCs
//! process tagged EtherCAT frames and leave the tag as it is. Serve on a socket opened with
//! [`PacketSocket::open_vlan_aware`]: Linux takes the tag off every received frame and tells it
//! only to sockets that listen to every EtherType. The segment processes the frame without its
//! tag (its timing model does not count the tag's 4 bytes on the wire: 320 ns later data, for
//! the slaves, that no register shows) and the tag is put back in front of the EtherType on
//! the way out.
//!
//! Replies are paced to the segment's wire time by default ([`Pace::Wire`]): a reply leaves
//! when its last bit would reach the master on the modelled wire (the request's arrival, the
//! segment's round trip to the frame's return, the frame's own length at 100 Mbit/s), so a
//! master's frame-size and cycle-budget behaviour meets the real limits. How late this host
//! sent a reply past that instant is measured apart ([`ServeStats::host_late_max_ns`]): the
//! serving host's lateness is not the model's.
//!
//! Faults are played by the clock: a window starts and ends at its time whether or not a frame
//! arrives ([`FaultPlayer::advance_to`] between frames). A fault that takes the cable at the
//! first slave's port 0 (or switches that slave off) takes the served interface down with it
//! when [`ServeConfig::carrier_iface`] names it, so a master that watches carrier sees it.

mod masters;
mod tags;

pub use masters::{MasterWatch, SecondMaster};

use crate::link::NetError;
use crate::sys::{self, PacketSocket, Ready};
use ecsync_sim::Segment;
use ecsync_sim::fault::{FaultEvent, FaultPlayer, FrameFate};
use ecsync_sim::pcap::PcapCapture;
use ecsync_sim::phy::frame_wire_time_ps;
use std::collections::VecDeque;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use tags::{MAX_TAGS, retag, untag};

/// Counters of a serving segment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ServeStats {
    /// EtherCAT frames received.
    pub received: u64,
    /// Frames processed and sent back.
    pub answered: u64,
    /// Of the answered frames, those answered in the VLAN tag they arrived in.
    pub answered_tagged: u64,
    /// Frames that arrived with bit 0x02 of the source address's first byte set (a locally
    /// administered master NIC, or a frame that had passed an ESC already): processed as any
    /// frame, counted for the record.
    pub marked_on_arrival: u64,
    /// Frames the segment did not return (malformed, not EtherCAT behind a tag, or lost in the
    /// topology).
    pub not_returned: u64,
    /// Frames too long for the buffer.
    pub truncated: u64,
    /// Frames the fault schedule dropped (on the way in or out).
    pub dropped_by_faults: u64,
    /// Replies the fault schedule delayed or sent twice, sent later.
    pub deferred_sends: u64,
    /// Times the interface was down (a receive or send refused with ENETDOWN or ENXIO):
    /// serving goes on, trying again.
    pub link_down_errors: u64,
    /// Replies sent at their wire time ([`Pace::Wire`]).
    pub paced: u64,
    /// Of them, those this host sent more than [`HOST_LATE_NS`] after their wire time.
    pub host_late: u64,
    /// Of them, those this host sent more than [`HOST_STALL_NS`] after their wire time.
    pub host_stalled: u64,
    /// The latest a reply left after its wire time, ns (this host's lateness, not the
    /// model's).
    pub host_late_max_ns: u64,
    /// Frames from a second master's address.
    pub second_master_frames: u64,
    /// Times the served interface was taken down or up with the first slave's link.
    pub carrier_changes: u64,
    /// Times the ring's second interface was taken down or up with the ring cable's link.
    #[serde(skip_serializing_if = "is_zero")]
    pub ring_carrier_changes: u64,
    /// Frames received on a ring's second interface ([`ServeConfig::ring`]; not in
    /// `received`).
    #[serde(skip_serializing_if = "is_zero")]
    pub received_on_ring: u64,
    /// Frames sent back out of the ring's second interface (in `answered`).
    #[serde(skip_serializing_if = "is_zero")]
    pub answered_on_ring: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// A reply this much after its wire time is counted late in [`ServeStats::host_late`], ns:
/// beyond a good host's wake-up latency.
pub const HOST_LATE_NS: u64 = 50_000;

/// A reply this much after its wire time is counted in [`ServeStats::host_stalled`], ns: a
/// stall of this host long enough to cost a master with a 1 ms cycle the reply (its next
/// cycle's send), which a master's test can then tell from a fault of the segment.
pub const HOST_STALL_NS: u64 = 1_000_000;

/// How far behind the clock [`Segment::expire_watchdogs`] plays the drives' watchdogs between
/// frames, ps: longer than a frame waits in the socket unless this host stalled.
const WATCHDOG_GRACE_PS: u64 = 20_000_000_000;

/// When replies leave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pace {
    /// At the segment's wire time: no earlier than the reply's last bit would reach the master.
    #[default]
    Wire,
    /// As soon as the segment processed the frame (the behaviour before pacing).
    None,
}

/// How [`serve`] serves.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServeConfig<'a> {
    /// When replies leave.
    pub pace: Pace,
    /// The served interface, taken down while the first slave's link is (`None`: never).
    pub carrier_iface: Option<&'a str>,
    /// The ring's second interface by name, taken down while the ring cable's link is
    /// (`None`: never).
    pub ring_carrier_iface: Option<&'a str>,
    /// A ring's second interface: where the slave with a ring port (`ring_port`) is cabled
    /// back to the master's second port. Frames arriving there enter the ring at its far end
    /// ([`Segment::process_secondary`]), and every frame leaves by the interface of the port
    /// it left the ring by (`None`: one interface; a frame leaving at the far end is lost).
    pub ring: Option<&'a PacketSocket>,
}

/// The segment and its faults, to change between frames (a control command).
pub struct Served<'a> {
    /// The segment.
    pub segment: &'a mut Segment,
    /// Its fault player.
    pub faults: &'a mut FaultPlayer,
    /// The counters so far.
    pub stats: &'a ServeStats,
    /// Now, ps on the segment's time line.
    pub now_ps: u64,
}

/// What a caller of [`serve`] sees and does while it serves. Every method has a default that
/// does nothing.
pub trait ServeHooks {
    /// After a frame that left the master at `t_ps` (the segment's time line): `frame` as the
    /// segment returned it (untagged; the request when a fault dropped it on the way out,
    /// `lost_out`); `lost_back` when a fault dropped it after the slaves processed it.
    fn frame(&mut self, _segment: &Segment, _frame: &[u8], _t_ps: u64, _lost: FrameLoss) {}
    /// After a frame that entered a ring at its far end (on [`ServeConfig::ring`]: a redundant
    /// master's second copy), as [`ServeHooks::frame`] for the first port's frames.
    fn frame_on_ring(&mut self, _segment: &Segment, _frame: &[u8], _t_ps: u64, _lost: FrameLoss) {}
    /// A reply left `late_ns` after its wire time.
    fn reply_sent(&mut self, _late_ns: u64) {}
    /// A fault started or ended.
    fn fault_event(&mut self, _event: &FaultEvent) {}
    /// Something the user should know (a second master, the carrier not switchable).
    fn warning(&mut self, _text: &str) {}
    /// Called between frames, at most every [`ServeHooks::poll_interval_ns`]: control
    /// commands, status.
    fn poll(&mut self, _served: &mut Served<'_>) {}
    /// How often [`ServeHooks::poll`] is called, ns.
    fn poll_interval_ns(&self) -> u64 {
        100_000_000
    }
}

/// Hooks that do nothing.
impl ServeHooks for () {}

/// A caller's hooks, lent: they are there after serving.
impl<H: ServeHooks> ServeHooks for &mut H {
    fn frame(&mut self, segment: &Segment, frame: &[u8], t_ps: u64, lost: FrameLoss) {
        (**self).frame(segment, frame, t_ps, lost);
    }
    fn frame_on_ring(&mut self, segment: &Segment, frame: &[u8], t_ps: u64, lost: FrameLoss) {
        (**self).frame_on_ring(segment, frame, t_ps, lost);
    }
    fn reply_sent(&mut self, late_ns: u64) {
        (**self).reply_sent(late_ns);
    }
    fn fault_event(&mut self, event: &FaultEvent) {
        (**self).fault_event(event);
    }
    fn warning(&mut self, text: &str) {
        (**self).warning(text);
    }
    fn poll(&mut self, served: &mut Served<'_>) {
        (**self).poll(served);
    }
    fn poll_interval_ns(&self) -> u64 {
        (**self).poll_interval_ns()
    }
}

/// What became of a frame on its way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameLoss {
    /// Answered (or lost in the topology: the segment's own doing).
    No,
    /// A fault dropped it before the first slave: nothing processed it.
    Out,
    /// A fault dropped it after the slaves processed it: their outputs were taken.
    Back,
}

/// A reply waiting for its time.
struct Pending {
    due_ns: u64,
    /// A reply's first copy (its lateness is measured), not a second responder's.
    reply: bool,
    /// Out of the ring's second interface.
    ring: bool,
    bytes: Vec<u8>,
}

/// The replies waiting, in the order they are due, and spare buffers (no allocation per frame
/// once warm).
#[derive(Default)]
struct Outbox {
    queue: VecDeque<Pending>,
    spare: Vec<Vec<u8>>,
    /// When the last reply leaves on each interface: a later one cannot overtake it on the
    /// wire.
    last_due_ns: [u64; 2],
}

impl Outbox {
    fn push(&mut self, due_ns: u64, reply: bool, ring: bool, frame: &[u8]) {
        let mut bytes = self.spare.pop().unwrap_or_default();
        bytes.clear();
        bytes.extend_from_slice(frame);
        let p = Pending {
            due_ns,
            reply,
            ring,
            bytes,
        };
        let at = self.queue.partition_point(|q| q.due_ns <= due_ns);
        self.queue.insert(at, p);
    }

    fn next_due_ns(&self) -> Option<u64> {
        self.queue.front().map(|p| p.due_ns)
    }
}

fn send(sock: &PacketSocket, frame: &[u8], stats: &mut ServeStats) -> Result<(), NetError> {
    match sock.send(frame) {
        Ok(()) => Ok(()),
        Err(e) if sys::link_is_down(&e) => {
            stats.link_down_errors += 1;
            Ok(())
        }
        Err(e) => Err(NetError::Io {
            what: "send",
            source: e,
        }),
    }
}

/// The serving loop's state besides the segment.
struct Loop<'s, H> {
    sock: &'s PacketSocket,
    config: ServeConfig<'s>,
    hooks: H,
    stats: ServeStats,
    outbox: Outbox,
    masters: MasterWatch,
    t0_mono: u64,
    last_ps: u64,
    events_seen: usize,
    /// Whether the first and the ring's interfaces are up (as this serve last set them).
    carrier_up: [bool; 2],
    carrier_warned: bool,
    next_poll_ns: u64,
}

impl<H: ServeHooks> Loop<'_, H> {
    fn now_ps(&self) -> u64 {
        (sys::monotonic_ns().saturating_sub(self.t0_mono))
            .saturating_mul(1000)
            .max(self.last_ps)
    }

    /// Sends the replies that are due.
    fn send_due(&mut self) -> Result<(), NetError> {
        while let Some(due) = self.outbox.next_due_ns() {
            let now = sys::monotonic_ns();
            if due > now {
                break;
            }
            let p = self.outbox.queue.pop_front().expect("a reply is due");
            let sock = match (p.ring, self.config.ring) {
                (true, Some(r)) => r,
                _ => self.sock,
            };
            send(sock, &p.bytes, &mut self.stats)?;
            if p.reply && self.config.pace == Pace::Wire {
                let late = now - due;
                self.stats.paced += 1;
                self.stats.host_late += u64::from(late > HOST_LATE_NS);
                self.stats.host_stalled += u64::from(late > HOST_STALL_NS);
                self.stats.host_late_max_ns = self.stats.host_late_max_ns.max(late);
                self.hooks.reply_sent(late);
            }
            self.outbox.spare.push(p.bytes);
        }
        Ok(())
    }

    /// Plays the fault edges that are due by the clock, each at its own time, then follows the
    /// first slave's link with the carrier.
    fn play_faults(&mut self, segment: &mut Segment, faults: &mut FaultPlayer) {
        let now_ps = self.now_ps();
        while let Some(due) = faults.next_due_ps().filter(|&d| d <= now_ps) {
            faults.advance_to(segment, due);
            self.last_ps = self.last_ps.max(due);
        }
        self.fault_events(segment, faults);
    }

    /// Hands the player's new events to the hooks and follows the first slave's link with
    /// the served interface.
    fn fault_events(&mut self, segment: &Segment, faults: &FaultPlayer) {
        let events = faults.events();
        if events.len() == self.events_seen {
            return;
        }
        for e in &events[self.events_seen..] {
            self.hooks.fault_event(e);
        }
        self.events_seen = events.len();
        let ends = [
            (self.config.carrier_iface, Some(segment.master_link_up())),
            (self.config.ring_carrier_iface, segment.ring_link_up()),
        ];
        for (k, (iface, up)) in ends.into_iter().enumerate() {
            if let (Some(iface), Some(up)) = (iface, up) {
                self.follow_carrier(k, iface, up);
            }
        }
    }

    /// Takes interface `k` (0 the first, 1 the ring's) `iface` up or down with its link.
    fn follow_carrier(&mut self, k: usize, iface: &str, up: bool) {
        if up == self.carrier_up[k] {
            return;
        }
        match sys::set_interface_up(iface, up) {
            Ok(()) => {
                self.carrier_up[k] = up;
                if k == 0 {
                    self.stats.carrier_changes += 1;
                } else {
                    self.stats.ring_carrier_changes += 1;
                }
            }
            Err(e) if !self.carrier_warned => {
                self.carrier_warned = true;
                self.hooks.warning(&format!(
                    "cannot take {iface} {} with {} ({e}): a master that watches carrier does not see it; serve with CAP_NET_ADMIN (root, or --sandbox)",
                    if up { "up" } else { "down" },
                    if k == 0 {
                        "the first slave's link"
                    } else {
                        "the ring cable's link"
                    }
                ));
            }
            Err(_) => {}
        }
    }

    fn poll(&mut self, segment: &mut Segment, faults: &mut FaultPlayer) {
        let now = sys::monotonic_ns();
        if now < self.next_poll_ns {
            return;
        }
        self.next_poll_ns = now + self.hooks.poll_interval_ns();
        let now_ps = self.now_ps();
        // The drives' process data watchdogs by the clock, a grace behind it: a frame that
        // arrived before the expiry and still waits in the socket must find them as it left
        // them.
        segment.expire_watchdogs(now_ps.saturating_sub(WATCHDOG_GRACE_PS));
        let mut served = Served {
            segment,
            faults,
            stats: &self.stats,
            now_ps,
        };
        self.hooks.poll(&mut served);
        self.fault_events(segment, faults);
    }

    /// Waits for a frame, a reply's time, a fault's edge or the next poll.
    fn wait(&mut self, faults: &FaultPlayer) -> Result<(), NetError> {
        let now = sys::monotonic_ns();
        let mut until = now + 50_000_000;
        until = until.min(self.next_poll_ns);
        if let Some(d) = self.outbox.next_due_ns() {
            until = until.min(d);
        }
        if let Some(d) = faults.next_due_ps() {
            until = until.min(self.t0_mono + d / 1000);
        }
        let socks = [Some(self.sock), self.config.ring];
        let ready = match sys::wait_any(socks, until.saturating_sub(now).max(1)) {
            Ok(r) => r,
            Err(e) if sys::link_is_down(&e) => {
                self.stats.link_down_errors += 1;
                std::thread::sleep(std::time::Duration::from_millis(1));
                return Ok(());
            }
            Err(e) => {
                return Err(NetError::Io {
                    what: "wait for a frame",
                    source: e,
                });
            }
        };
        for (sock, ready) in socks.into_iter().zip(ready) {
            if let (Some(sock), Ready::ErrorQueue) = (sock, ready) {
                // Transmit timestamps of the replies: not needed here, but they must be read
                // or every wait returns at once.
                while sock
                    .take_tx_timestamp()
                    .map_err(|source| NetError::Io {
                        what: "TX timestamp",
                        source,
                    })?
                    .is_some()
                {}
            }
        }
        Ok(())
    }

    /// Queues (or sends) the answer to a frame that arrived at monotonic `mono_ns`, segment
    /// time `t_ps`, and came back at `back_ps`.
    fn answer(
        &mut self,
        ring: bool,
        frame: &[u8],
        mono_ns: u64,
        t_ps: u64,
        back_ps: u64,
        fate: FrameFate,
    ) -> Result<(), NetError> {
        let base = match self.config.pace {
            // The reply's last bit reaches the master: the round trip to its first bit, then
            // the frame's length on the wire.
            Pace::Wire => {
                let wire_ps = back_ps.saturating_sub(t_ps) + frame_wire_time_ps(frame.len());
                let last = &mut self.outbox.last_due_ns[usize::from(ring)];
                let due = (mono_ns + wire_ps.div_ceil(1000)).max(*last);
                *last = due;
                due
            }
            Pace::None => sys::monotonic_ns(),
        };
        let due = base + fate.extra_delay_ps / 1000;
        if fate.extra_delay_ps > 0 {
            self.stats.deferred_sends += 1;
        }
        if self.config.pace == Pace::None && fate.extra_delay_ps == 0 {
            let sock = self.config.ring.filter(|_| ring).unwrap_or(self.sock);
            send(sock, frame, &mut self.stats)?;
        } else {
            self.outbox.push(due, true, ring, frame);
        }
        if let Some(lag) = fate.copy_after_ps {
            self.outbox.push(due + lag / 1000, false, ring, frame);
            self.stats.deferred_sends += 1;
        }
        Ok(())
    }
}

/// Serves `segment` on `sock` until `stop` is raised. `capture` records every frame in and out.
/// `faults` plays a fault schedule on the segment (the segment's kinds; the master host's are
/// refused before serving starts), by the clock; the hooks see every frame and may change the
/// segment and its faults between frames.
pub fn serve<W: Write, H: ServeHooks>(
    sock: &PacketSocket,
    segment: &mut Segment,
    mut capture: Option<&mut PcapCapture<W>>,
    faults: &mut FaultPlayer,
    config: ServeConfig<'_>,
    stop: &AtomicBool,
    hooks: H,
) -> Result<ServeStats, NetError> {
    // Replies are timed to the microsecond: no batching of wake-ups (best effort).
    let _ = sys::set_timer_slack_ns(1);
    let mut lp = Loop {
        sock,
        config,
        hooks,
        stats: ServeStats::default(),
        outbox: Outbox::default(),
        masters: MasterWatch::default(),
        t0_mono: sys::monotonic_ns(),
        last_ps: 0,
        events_seen: 0,
        carrier_up: [true; 2],
        carrier_warned: false,
        next_poll_ns: 0,
    };
    // Room for the longest frame and its tags.
    let mut buf = vec![0u8; 2048];
    // Kernel stamps onto the monotonic clock: a frame stamped across a step of the wall clock
    // is taken as arriving now (its stamp would put it off by the step).
    let mut rt_map = crate::wall_clock::RealtimeMap::new();
    while !stop.load(Ordering::Relaxed) {
        lp.send_due()?;
        lp.play_faults(segment, faults);
        lp.poll(segment, faults);
        let rx_epoch = rt_map.epoch();
        // The first interface's frames first: a redundant master sends its first port's copy
        // first.
        let mut got = None;
        let downs = lp.stats.link_down_errors;
        for (ring, sock) in [(false, Some(sock)), (true, config.ring)] {
            let Some(sock) = sock else { continue };
            if let Some(r) = lp.receive(sock, &mut buf)? {
                got = Some((ring, r));
                break;
            }
        }
        let Some((ring, r)) = got else {
            lp.wait(faults)?;
            if lp.stats.link_down_errors != downs {
                // An interface is down: try again in a while, as a slave waits for its link.
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            continue;
        };
        // The instant the frame arrived, on the segment's time line (ps since serving began).
        let mono = r
            .kernel_rx_realtime_ns
            .and_then(|rt| rt_map.to_monotonic_ns(rt, rx_epoch))
            .unwrap_or_else(sys::monotonic_ns);
        lp.frame_in(
            segment,
            faults,
            capture.as_deref_mut(),
            &mut buf,
            r,
            ring,
            mono,
        )?;
    }
    Ok(lp.stats)
}

impl<H: ServeHooks> Loop<'_, H> {
    /// A frame from `sock`, if one is there (an interface that is down is counted in
    /// `link_down_errors`).
    fn receive(
        &mut self,
        sock: &PacketSocket,
        buf: &mut [u8],
    ) -> Result<Option<sys::Received>, NetError> {
        let room = buf.len() - 4 * MAX_TAGS;
        match sock.recv(&mut buf[..room]) {
            Ok(r) => Ok(r),
            Err(e) if sys::link_is_down(&e) => {
                self.stats.link_down_errors += 1;
                Ok(None)
            }
            Err(e) => Err(NetError::Io {
                what: "receive",
                source: e,
            }),
        }
    }

    /// A frame that arrived at CLOCK_MONOTONIC `mono` on the first interface or (`ring`) the
    /// ring's second: through the faults and the segment, answered on the interface of the
    /// port it left by.
    #[allow(clippy::too_many_arguments)]
    fn frame_in<W: Write>(
        &mut self,
        segment: &mut Segment,
        faults: &mut FaultPlayer,
        mut capture: Option<&mut PcapCapture<W>>,
        buf: &mut [u8],
        r: sys::Received,
        ring: bool,
        mono: u64,
    ) -> Result<(), NetError> {
        if ring {
            self.stats.received_on_ring += 1;
        } else {
            self.stats.received += 1;
        }
        if r.truncated {
            self.stats.truncated += 1;
            return Ok(());
        }
        if r.len > 6 && buf[6] & 0x02 != 0 {
            self.stats.marked_on_arrival += 1;
        }
        let t_ps = (mono.saturating_sub(self.t0_mono))
            .saturating_mul(1000)
            .max(self.last_ps);
        self.last_ps = t_ps;
        let Some((len, tags)) = untag(buf, r.len, r.vlan) else {
            self.stats.not_returned += 1;
            return Ok(());
        };
        if let Some(c) = capture.as_deref_mut() {
            // As it was on the wire, tags included.
            let mut wire = buf[..len + 4 * tags.len()].to_vec();
            retag(&mut wire, len, &tags);
            let _ = c.record(t_ps, &wire);
        }
        // A redundant master's second port has an address of its own (ecsync's flips a bit of
        // it, SOEM's is another): a second master is looked for on the first interface only.
        if !ring && let Some(found) = self.masters.see(&buf[..len]) {
            self.hooks.warning(&found.to_string());
        }
        self.stats.second_master_frames = self.masters.other_address_frames;
        let fate = faults.before_frame(segment, &buf[..len], t_ps);
        self.fault_events(segment, faults);
        let judged = |hooks: &mut H, seg: &Segment, frame: &[u8], lost| {
            if ring {
                hooks.frame_on_ring(seg, frame, t_ps, lost);
            } else {
                hooks.frame(seg, frame, t_ps, lost);
            }
        };
        if fate.lost_out {
            self.stats.dropped_by_faults += 1;
            judged(&mut self.hooks, segment, &buf[..len], FrameLoss::Out);
            return Ok(());
        }
        let out = if ring {
            segment.process_secondary(&mut buf[..len], t_ps)
        } else {
            segment.process(&mut buf[..len], t_ps)
        };
        let lost_back = fate.lost_back && out.returned_sof_ps.is_some();
        let loss = if lost_back {
            FrameLoss::Back
        } else {
            FrameLoss::No
        };
        judged(&mut self.hooks, segment, &buf[..len], loss);
        if lost_back {
            self.stats.dropped_by_faults += 1;
            return Ok(());
        }
        match out.returned_sof_ps {
            // Out at a ring's far end (a segment with `ring_port`) where this serve has one
            // interface: it does not come back to the master.
            Some(_) if out.returned_port != 0 && self.config.ring.is_none() => {
                self.stats.not_returned += 1
            }
            Some(back_ps) => {
                let out_ring = out.returned_port != 0;
                let n = retag(buf, len, &tags);
                self.answer(out_ring, &buf[..n], mono, t_ps, back_ps, fate)?;
                self.stats.answered += 1;
                self.stats.answered_on_ring += u64::from(out_ring);
                self.stats.answered_tagged += u64::from(tags.len() > 0);
                if let Some(c) = capture {
                    let _ = c.record(back_ps, &buf[..n]);
                }
            }
            None => self.stats.not_returned += 1,
        }
        Ok(())
    }
}
