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

use crate::link::NetError;
use crate::sys::{self, PacketSocket, Ready, TPID_8021AD, TPID_8021Q, VlanTag};
use ecsync_sim::Segment;
use ecsync_sim::fault::{FaultPlayer, FrameFate};
use ecsync_sim::pcap::PcapCapture;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

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
}

/// Most VLAN tags a frame may carry (802.1ad S-tag outside, 802.1Q C-tag inside).
const MAX_TAGS: usize = 2;

/// The VLAN tags a frame arrived in, outermost first.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Tags {
    tags: [Option<VlanTag>; MAX_TAGS],
}

impl Tags {
    fn len(&self) -> usize {
        self.tags.iter().flatten().count()
    }

    fn push(&mut self, t: VlanTag) -> bool {
        match self.tags.iter_mut().find(|s| s.is_none()) {
            Some(slot) => {
                *slot = Some(t);
                true
            }
            None => false,
        }
    }
}

/// Takes the frame's VLAN tags off: the one the kernel took off already (`stripped`), then those
/// still in the bytes, in place. Returns the untagged length and the tags, or `None` when there
/// are more tags than [`MAX_TAGS`].
fn untag(frame: &mut [u8], mut len: usize, stripped: Option<VlanTag>) -> Option<(usize, Tags)> {
    let mut tags = Tags::default();
    if let Some(t) = stripped {
        tags.push(t);
    }
    while len >= 18 {
        let tpid = u16::from_be_bytes([frame[12], frame[13]]);
        if tpid != TPID_8021Q && tpid != TPID_8021AD {
            break;
        }
        let tci = u16::from_be_bytes([frame[14], frame[15]]);
        if !tags.push(VlanTag { tpid, tci }) {
            return None;
        }
        frame.copy_within(16..len, 12);
        len -= 4;
    }
    Some((len, tags))
}

/// Puts `tags` back after the source address of the untagged frame `frame[..len]`; `frame` has
/// room for them. Returns the tagged length.
fn retag(frame: &mut [u8], len: usize, tags: &Tags) -> usize {
    let n = 4 * tags.len();
    frame.copy_within(12..len, 12 + n);
    for (i, t) in tags.tags.iter().flatten().enumerate() {
        frame[12 + 4 * i..16 + 4 * i].copy_from_slice(&t.to_bytes());
    }
    len + n
}

/// Serves `segment` on `sock` until `stop` is raised. `capture` records every frame in and out.
/// `faults` plays a fault schedule on the segment's frames (the segment's kinds; the master
/// host's are refused before serving starts). `on_frame` sees the counters after each frame.
pub fn serve<W: Write>(
    sock: &PacketSocket,
    segment: &mut Segment,
    mut capture: Option<&mut PcapCapture<W>>,
    mut faults: Option<&mut FaultPlayer>,
    stop: &AtomicBool,
    mut on_frame: impl FnMut(&ServeStats),
) -> Result<ServeStats, NetError> {
    let io = |what| move |source| NetError::Io { what, source };
    let t0_mono = sys::monotonic_ns();
    let mut stats = ServeStats::default();
    // Room for the longest frame and its tags.
    let mut buf = vec![0u8; 2048];
    let room = buf.len() - 4 * MAX_TAGS;
    let mut last_ps = 0u64;
    // Kernel stamps onto the monotonic clock: a frame stamped across a step of the wall clock
    // is taken as arriving now (its stamp would put it off by the step).
    let mut rt_map = crate::wall_clock::RealtimeMap::new();
    // Replies to send later (a delay, a second responder's copy): when (monotonic ns), bytes.
    let mut later: std::collections::VecDeque<(u64, Vec<u8>)> = std::collections::VecDeque::new();
    let send = |sock: &PacketSocket, frame: &[u8], stats: &mut ServeStats| match sock.send(frame) {
        Ok(()) => Ok(()),
        Err(e) if sys::link_is_down(&e) => {
            stats.link_down_errors += 1;
            Ok(())
        }
        Err(e) => Err(NetError::Io {
            what: "send",
            source: e,
        }),
    };
    while !stop.load(Ordering::Relaxed) {
        while later
            .front()
            .is_some_and(|(at, _)| *at <= sys::monotonic_ns())
        {
            if let Some((_, f)) = later.pop_front() {
                send(sock, &f, &mut stats)?;
            }
        }
        let rx_epoch = rt_map.epoch();
        let got = match sock.recv(&mut buf[..room]) {
            Ok(r) => r,
            Err(e) if sys::link_is_down(&e) => {
                // The interface is down: wait and try again, as a slave waits for its link.
                stats.link_down_errors += 1;
                std::thread::sleep(std::time::Duration::from_millis(10));
                continue;
            }
            Err(e) => return Err(io("receive")(e)),
        };
        let Some(r) = got else {
            let wait_ns = later.front().map_or(50_000_000, |(at, _)| {
                at.saturating_sub(sys::monotonic_ns()).max(1)
            });
            let ready = match sock.wait(wait_ns.min(50_000_000)) {
                Ok(r) => r,
                Err(e) if sys::link_is_down(&e) => {
                    stats.link_down_errors += 1;
                    std::thread::sleep(std::time::Duration::from_millis(10));
                    continue;
                }
                Err(e) => return Err(io("wait for a frame")(e)),
            };
            if ready == Ready::ErrorQueue {
                // Transmit timestamps of the replies: not needed here, but they must be read
                // or every wait returns at once.
                while sock
                    .take_tx_timestamp()
                    .map_err(io("TX timestamp"))?
                    .is_some()
                {}
            }
            continue;
        };
        stats.received += 1;
        if r.truncated {
            stats.truncated += 1;
            continue;
        }
        if r.len > 6 && buf[6] & 0x02 != 0 {
            stats.marked_on_arrival += 1;
        }
        // The instant the frame arrived, on the segment's time line (ps since serving began).
        let mono = r
            .kernel_rx_realtime_ns
            .and_then(|rt| rt_map.to_monotonic_ns(rt, rx_epoch))
            .unwrap_or_else(sys::monotonic_ns);
        let t_ps = (mono.saturating_sub(t0_mono))
            .saturating_mul(1000)
            .max(last_ps);
        last_ps = t_ps;
        let Some((len, tags)) = untag(&mut buf, r.len, r.vlan) else {
            stats.not_returned += 1;
            on_frame(&stats);
            continue;
        };
        if let Some(c) = capture.as_deref_mut() {
            // As it was on the wire, tags included.
            let mut wire = buf[..len + 4 * tags.len()].to_vec();
            retag(&mut wire, len, &tags);
            let _ = c.record(t_ps, &wire);
        }
        let fate = match faults.as_deref_mut() {
            Some(f) => f.before_frame(segment, &buf[..len], t_ps),
            None => FrameFate::default(),
        };
        if fate.lost_out {
            stats.dropped_by_faults += 1;
            on_frame(&stats);
            continue;
        }
        let out = segment.process(&mut buf[..len], t_ps);
        if fate.lost_back && out.returned_sof_ps.is_some() {
            stats.dropped_by_faults += 1;
            on_frame(&stats);
            continue;
        }
        match out.returned_sof_ps {
            Some(back_ps) => {
                let n = retag(&mut buf, len, &tags);
                let now = sys::monotonic_ns();
                if fate.extra_delay_ps > 0 {
                    later.push_back((now + fate.extra_delay_ps / 1000, buf[..n].to_vec()));
                    stats.deferred_sends += 1;
                } else {
                    send(sock, &buf[..n], &mut stats)?;
                }
                if let Some(lag) = fate.copy_after_ps {
                    let at = now + fate.extra_delay_ps / 1000 + lag / 1000;
                    later.push_back((at, buf[..n].to_vec()));
                    stats.deferred_sends += 1;
                }
                // (Deferred sends in the order they are due.)
                later.make_contiguous().sort_by_key(|x| x.0);
                stats.answered += 1;
                stats.answered_tagged += u64::from(tags.len() > 0);
                if let Some(c) = capture.as_deref_mut() {
                    let _ = c.record(back_ps, &buf[..n]);
                }
            }
            None => stats.not_returned += 1,
        }
        on_frame(&stats);
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(tags: &[[u8; 4]]) -> Vec<u8> {
        let mut f = vec![0xff; 6];
        f.extend_from_slice(&[0x02, 0, 0, 0, 0, 1]);
        for t in tags {
            f.extend_from_slice(t);
        }
        f.extend_from_slice(&[0x88, 0xa4, 0x0c, 0x10, 7, 0x5a]);
        f.resize(f.len() + 32, 0);
        f
    }

    #[test]
    fn tags_come_off_and_go_back_where_they_were() {
        // 802.1Q, PCP 5, VID 0x123: TCI 0xa123.
        let q = VlanTag {
            tpid: TPID_8021Q,
            tci: 0xa123,
        };
        assert_eq!((q.vid(), q.pcp()), (0x123, 5));
        let tagged = frame(&[q.to_bytes()]);
        assert_eq!(&tagged[12..18], &[0x81, 0x00, 0xa1, 0x23, 0x88, 0xa4]);
        let plain = frame(&[]);
        // In the bytes.
        let mut buf = tagged.clone();
        buf.resize(tagged.len() + 8, 0);
        let (len, tags) = untag(&mut buf, tagged.len(), None).unwrap();
        assert_eq!(&buf[..len], &plain[..]);
        assert_eq!(tags.len(), 1);
        assert_eq!(retag(&mut buf, len, &tags), tagged.len());
        assert_eq!(&buf[..tagged.len()], &tagged[..]);
        // Taken off by the kernel (auxiliary data): the bytes are untagged.
        let mut buf = plain.clone();
        buf.resize(plain.len() + 8, 0);
        let (len, tags) = untag(&mut buf, plain.len(), Some(q)).unwrap();
        assert_eq!(len, plain.len());
        let n = retag(&mut buf, len, &tags);
        assert_eq!(&buf[..n], &tagged[..]);
        // 802.1ad outside (from the kernel), 802.1Q inside (in the bytes).
        let s = VlanTag {
            tpid: TPID_8021AD,
            tci: 0x0007,
        };
        let qinq = frame(&[s.to_bytes(), q.to_bytes()]);
        let mut buf = frame(&[q.to_bytes()]);
        buf.resize(buf.len() + 8, 0);
        let (len, tags) = untag(&mut buf, qinq.len() - 4, Some(s)).unwrap();
        assert_eq!(&buf[..len], &plain[..]);
        let n = retag(&mut buf, len, &tags);
        assert_eq!(&buf[..n], &qinq[..]);
        // Untagged frames stay as they are.
        let mut buf = plain.clone();
        let (len, tags) = untag(&mut buf, plain.len(), None).unwrap();
        assert_eq!((len, tags.len()), (plain.len(), 0));
        assert_eq!(retag(&mut buf, len, &tags), plain.len());
        assert_eq!(buf, plain);
        // Three tags: refused.
        let mut buf = frame(&[q.to_bytes(), q.to_bytes(), q.to_bytes()]);
        let n = buf.len();
        assert!(untag(&mut buf, n, None).is_none());
    }
}
