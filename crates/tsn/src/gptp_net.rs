//! The message exchange between simulated gPTP time-aware systems, written once for every
//! simulation of them ([`crate::gptp_sim::run_line`] and the TSN network's bridge and master):
//! what a system emits is encoded, put on a link by the simulation's [`GptpMedium`] (which
//! knows the link's delay, its queues and gates, and each system's timestamper), delivered at
//! its arrival time as bytes, decoded and fed to the receiving [`TimeAwareSystem`] with its
//! receive timestamp; transmit timestamps go back to the sender, which may answer them
//! (Follow_Up, Pdelay_Resp_Follow_Up) at once.
//!
//! The exchange is generic over the simulation's time ([`SimTime`]: integer picoseconds in the
//! network, float nanoseconds in the line) because each simulation's arithmetic is its own
//! and its results are recorded; the exchange itself does no arithmetic on time.
//!
//! Bytes that do not decode are counted and dropped, as a real stack drops a malformed frame:
//! nothing a peer sends can stop the simulation.

use crate::gptp::{Outgoing, TimeAwareSystem};
use crate::gptp_msg::{self, Message};
use core::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

/// A point of simulated time: ordered totally, so that deliveries are taken in time order
/// (and, at one instant, in the order they were sent).
pub trait SimTime: Copy + core::fmt::Debug {
    /// The total order of two instants.
    fn order(&self, other: &Self) -> Ordering;
}

impl SimTime for u64 {
    fn order(&self, other: &Self) -> Ordering {
        self.cmp(other)
    }
}

impl SimTime for f64 {
    fn order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

/// How one message went onto the wire, as the simulation's medium decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transmission<T> {
    /// The sender's transmit timestamp (its free-running clock on its timestamper's grid), ns.
    pub tx_ns: u64,
    /// When the message arrives at the peer (the instant of its receive timestamp).
    pub arrival: T,
    /// The receiving system.
    pub peer: usize,
    /// The port it arrives on.
    pub peer_port: usize,
    /// When the sender's next message can be ready (the end of this one on a serial wire, or
    /// the same instant where the simulation does not model the wire's occupancy).
    pub next_ready: T,
}

/// What a simulation supplies around the exchange: the systems' timestamps, the wire, and what
/// a disciplined clock does with the servo's decision.
pub trait GptpMedium<T> {
    /// The timestamp system `node` takes at `t` (its free-running clock's reading on its
    /// timestamper's grid), ns: the local time of a poll and of a reception.
    fn timestamp_ns(&mut self, node: usize, t: T) -> u64;

    /// Puts the encoded message `payload` from `node`'s `port` on the wire, ready to leave at
    /// `ready`.
    fn transmit(&mut self, node: usize, port: usize, ready: T, payload: &[u8]) -> Transmission<T>;

    /// A Follow_Up has been fed to `node`: the servo may have a decision for its disciplined
    /// clock ([`TimeAwareSystem::servo`]).
    fn follow_up(&mut self, node: usize, system: &mut TimeAwareSystem);
}

/// Messages the exchange counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ExchangeCounts {
    /// Messages put on a wire.
    pub sent: u64,
    /// Messages delivered and decoded.
    pub received: u64,
    /// Deliveries that did not decode as gPTP (dropped).
    pub undecodable: u64,
    /// Messages a system emitted that could not be encoded (dropped).
    pub unencodable: u64,
}

/// A message in flight: when it arrives, where, its bytes.
#[derive(Debug, Clone)]
struct Delivery<T> {
    at: T,
    /// Sending order, for deliveries at the same instant.
    seq: u64,
    node: usize,
    port: usize,
    bytes: Vec<u8>,
}

impl<T: SimTime> PartialEq for Delivery<T> {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o).is_eq()
    }
}
impl<T: SimTime> Eq for Delivery<T> {}
impl<T: SimTime> PartialOrd for Delivery<T> {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl<T: SimTime> Ord for Delivery<T> {
    fn cmp(&self, o: &Self) -> Ordering {
        self.at.order(&o.at).then(self.seq.cmp(&o.seq))
    }
}

/// Time-aware systems and the messages in flight between them.
#[derive(Debug)]
pub struct GptpNetwork<T: SimTime> {
    systems: Vec<TimeAwareSystem>,
    queue: BinaryHeap<Reverse<Delivery<T>>>,
    seq: u64,
    /// Messages to send and the answers to their transmit timestamps (kept to reuse).
    out: Vec<Outgoing>,
    more: Vec<Outgoing>,
    /// The next poll of [`GptpNetwork::run_until`], and the polls' period.
    next_poll: T,
    poll_period: T,
    counts: ExchangeCounts,
}

impl<T: SimTime + core::ops::Add<Output = T>> GptpNetwork<T> {
    /// The systems (indexed as the medium knows them), nothing in flight; [`Self::run_until`]
    /// polls them all at `first_poll` and every `poll_period` after.
    pub fn new(systems: Vec<TimeAwareSystem>, first_poll: T, poll_period: T) -> Self {
        GptpNetwork {
            systems,
            queue: BinaryHeap::new(),
            seq: 0,
            out: Vec::new(),
            more: Vec::new(),
            next_poll: first_poll,
            poll_period,
            counts: ExchangeCounts::default(),
        }
    }

    /// The systems.
    pub fn systems(&self) -> &[TimeAwareSystem] {
        &self.systems
    }

    /// What the exchange counted.
    pub fn counts(&self) -> ExchangeCounts {
        self.counts
    }

    /// When the next message arrives.
    pub fn next_delivery(&self) -> Option<T> {
        self.queue.peek().map(|Reverse(d)| d.at)
    }

    /// Delivers every message that arrives at or before `t`, in time order, with what they
    /// cause (answers arriving by `t` too).
    pub fn deliver_until(&mut self, t: T, medium: &mut impl GptpMedium<T>) {
        while self.next_delivery().is_some_and(|at| at.order(&t).is_le()) {
            self.deliver_next(medium);
        }
    }

    /// Polls every system at `t` in index order (timers: Sync, Pdelay_Req, Announce), each
    /// sending what it emits before the next is polled.
    pub fn poll_all(&mut self, t: T, medium: &mut impl GptpMedium<T>) {
        for node in 0..self.systems.len() {
            let local_ns = medium.timestamp_ns(node, t);
            let mut out = core::mem::take(&mut self.out);
            self.systems[node].poll(local_ns, &mut out);
            self.send(node, t, &mut out, medium);
            self.out = out;
        }
    }

    /// Runs the exchange up to `until`: deliveries and periodic polls in time order, a
    /// delivery before a poll at the same instant.
    pub fn run_until(&mut self, until: T, medium: &mut impl GptpMedium<T>) {
        loop {
            let poll = self.next_poll;
            match self.next_delivery() {
                Some(at) if at.order(&poll).is_le() => {
                    if at.order(&until).is_gt() {
                        return;
                    }
                    self.deliver_next(medium);
                }
                _ => {
                    if poll.order(&until).is_gt() {
                        return;
                    }
                    self.next_poll = poll + self.poll_period;
                    self.poll_all(poll, medium);
                }
            }
        }
    }

    /// Puts raw bytes in flight to `node`'s `port`, arriving at `at`: a frame from outside the
    /// simulated systems (another stack's, or a corrupted one), handled as any delivery.
    pub fn inject(&mut self, at: T, node: usize, port: usize, bytes: Vec<u8>) {
        self.seq += 1;
        self.queue.push(Reverse(Delivery {
            at,
            seq: self.seq,
            node,
            port,
            bytes,
        }));
    }

    /// Delivers the first message in flight.
    fn deliver_next(&mut self, medium: &mut impl GptpMedium<T>) {
        let Some(Reverse(d)) = self.queue.pop() else {
            return;
        };
        let Ok((header, message)) = gptp_msg::decode(&d.bytes) else {
            self.counts.undecodable += 1;
            return;
        };
        self.counts.received += 1;
        let rx_ns = medium.timestamp_ns(d.node, d.at);
        let mut out = core::mem::take(&mut self.out);
        let system = &mut self.systems[d.node];
        system.on_message(d.port, &header, &message, rx_ns, &mut out);
        if matches!(message, Message::FollowUp { .. }) {
            medium.follow_up(d.node, system);
        }
        self.send(d.node, d.at, &mut out, medium);
        self.out = out;
    }

    /// Sends what `node` emitted at `t`, one message after the other; the answers to their
    /// transmit timestamps follow.
    fn send(
        &mut self,
        node: usize,
        t: T,
        out: &mut Vec<Outgoing>,
        medium: &mut impl GptpMedium<T>,
    ) {
        let mut buf = [0u8; gptp_msg::MAX_LEN];
        let mut ready = t;
        let mut more = core::mem::take(&mut self.more);
        while !out.is_empty() {
            for o in out.drain(..) {
                let Ok(len) = o.message.encode(&o.header, &mut buf) else {
                    self.counts.unencodable += 1;
                    continue;
                };
                let tx = medium.transmit(node, o.port, ready, &buf[..len]);
                self.counts.sent += 1;
                self.systems[node]
                    .on_tx_timestamp(o.port, &o.header, &o.message, tx.tx_ns, &mut more);
                self.seq += 1;
                self.queue.push(Reverse(Delivery {
                    at: tx.arrival,
                    seq: self.seq,
                    node: tx.peer,
                    port: tx.peer_port,
                    bytes: buf[..len].to_vec(),
                }));
                ready = tx.next_ready;
            }
            core::mem::swap(out, &mut more);
        }
        self.more = more;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gptp::{Config, SystemIdentity};

    /// Two systems on one link of 1 us, ideal clocks (true time in ns), timestamps exact.
    struct Pair;

    impl GptpMedium<u64> for Pair {
        fn timestamp_ns(&mut self, _: usize, t: u64) -> u64 {
            t
        }
        fn transmit(&mut self, node: usize, _: usize, ready: u64, _: &[u8]) -> Transmission<u64> {
            Transmission {
                tx_ns: ready,
                arrival: ready + 1_000,
                peer: 1 - node,
                peer_port: 0,
                next_ready: ready,
            }
        }
        fn follow_up(&mut self, _: usize, system: &mut TimeAwareSystem) {
            let rx = system.last_sync_rx_ns().unwrap_or(0);
            let _ = system.servo(rx, 0.0);
        }
    }

    fn pair() -> GptpNetwork<u64> {
        let sys = |p1: u8, id: u8| {
            let identity =
                SystemIdentity::with_default_quality(p1, [0, 0, 0, 0xff, 0xfe, 0, 0, id]);
            TimeAwareSystem::new(Config::new(identity, 1))
        };
        GptpNetwork::new(vec![sys(10, 1), sys(200, 2)], 0, 1_000_000)
    }

    /// The pair synchronizes: the link delay is measured exactly and the better priority1 is
    /// the grandmaster.
    #[test]
    fn two_systems_measure_their_link() {
        let mut net = pair();
        net.run_until(5_000_000_000, &mut Pair);
        let s = net.systems();
        assert!(s[0].is_grandmaster() && !s[1].is_grandmaster());
        assert_eq!(s[1].mean_link_delay_ns(0), Some(1_000.0));
        let c = net.counts();
        assert!(c.sent > 40 && c.received + 5 >= c.sent, "{c:?}");
        assert_eq!(c.undecodable, 0);
    }

    /// Whatever bytes arrive, the exchange counts what it cannot decode and goes on: every
    /// prefix of every message a system sends, and garbage.
    #[test]
    fn malformed_frames_are_counted_and_dropped() {
        let mut net = pair();
        net.run_until(3_000_000_000, &mut Pair);
        let mut buf = [0u8; gptp_msg::MAX_LEN];
        let h = crate::gptp_msg::Header {
            sequence_id: 1,
            ..Default::default()
        };
        let n = Message::Sync
            .encode(&h, &mut buf)
            .expect("MAX_LEN holds any message");
        let mut t = 3_000_000_001;
        let mut bad = 0;
        for k in 0..n {
            net.inject(t, 1, 0, buf[..k].to_vec());
            t += 1;
            bad += 1;
        }
        net.inject(t, 1, 0, vec![0xff; 200]);
        bad += 1;
        net.run_until(6_000_000_000, &mut Pair);
        assert_eq!(net.counts().undecodable, bad);
        assert_eq!(net.systems()[1].mean_link_delay_ns(0), Some(1_000.0));
    }
}
