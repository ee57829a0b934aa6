//! Cable redundancy: the master on both ends of a ring (ETG.1500 "cable redundancy"; the ESC
//! datasheet's loop control). The segment's last slave is cabled back to a second master
//! port; every frame leaves on both ports, and the two copies that come back are made one.
//!
//! - **Ring intact**: the first port's copy passes every slave and arrives at the second
//!   port; the second port's copy runs the ring backwards through the ports alone (each ESC's
//!   processing unit follows its port 0) and arrives at the first, untouched. The first
//!   port's copy is the frame.
//! - **Ring broken** (a cable pulled, a slave dead): the ports on both sides of the break
//!   close, each copy is processed by the slaves on its side and comes back on the port it
//!   left by. The two are merged datagram by datagram: the working counters add up, and each
//!   data byte is the one a side changed (a byte both changed, as a broadcast read ORs them,
//!   is ORed). Two sides never write the same byte of a logical datagram (each slave's inputs
//!   are its own), so the merged frame is the one an intact line would have returned.
//!
//! SOEM's redundancy sends the first port's returned frame out of the second port again to
//! combine them (`ecx_waitinframe_red`); that costs a second round trip, past SYNC0 for the
//! far side's outputs, and its second copy's FRMW writes the template's zeros into the far
//! side's clocks (SOEM #621). Here both copies leave at once, and the second port's copy
//! carries no clock write: its FRMW and ARMW datagrams, and any write of the receive-time
//! latch (0x0900), become NOPs. The slaves behind a break keep the drift compensation their
//! time control loops learned (holdover: at the residual rate error of a locked loop a few
//! nanoseconds per second) and take the reference's time again when the ring is whole.
//!
//! [`Redundant`] is a [`Transport`] over a transport with a second port ([`SecondPort`]): the
//! engine, its bring-up and cyclic drivers run over it unchanged. It allocates nothing per
//! frame (its buffers are made once).

use crate::transport::{Received, Transport};
use ecsync_dc::time::MasterInstant;

/// A transport with a second master port (the far end of a ring).
pub trait SecondPort: Transport {
    /// Sends `frame` on the second port, to leave at `at`; what arrives there comes back
    /// through [`Transport::recv`] with [`Received::port`] 1.
    fn send_secondary(&mut self, frame: &[u8], at: MasterInstant) -> Result<(), Self::Error>;
}

/// The longest frame a slot keeps (an Ethernet frame without FCS).
const MAX_FRAME: usize = 1514;
/// Frames in flight at once (a cycle's frames and the bring-up's).
const SLOTS: usize = 16;
/// Where the EtherCAT datagrams start (Ethernet header and EtherCAT header).
const FIRST_DATAGRAM: usize = 16;
/// A datagram's header and working counter, bytes.
const DATAGRAM_HEADER: usize = 10;

/// What the ring did, as the frames showed it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RedundancyStats {
    /// Frames that went round the intact ring.
    pub intact: u64,
    /// Frames made of two copies (the ring broken).
    pub merged: u64,
    /// Frames of which only one copy came back by the deadline.
    pub partial: u64,
    /// Times the ring was found broken after it was whole (or at the start).
    pub breaks: u64,
    /// Times it was found whole again.
    pub restores: u64,
    /// The ring is broken now (by the last frame).
    pub broken: bool,
}

#[derive(Debug, Clone)]
struct Slot {
    used: bool,
    delivered: bool,
    /// The first datagram's index and the frame's length: which frame the copies are of.
    key: (u8, usize),
    sent: Vec<u8>,
    /// The copies back: their bytes, when they arrived and on which port.
    first: Option<Received>,
    first_buf: Vec<u8>,
    second: Option<Received>,
    second_buf: Vec<u8>,
    /// Its age, for reuse.
    serial: u64,
}

impl Slot {
    fn new() -> Self {
        Slot {
            used: false,
            delivered: false,
            key: (0, 0),
            sent: vec![0; MAX_FRAME],
            first: None,
            first_buf: vec![0; MAX_FRAME],
            second: None,
            second_buf: vec![0; MAX_FRAME],
            serial: 0,
        }
    }

    /// Complete: the first port's copy went round the ring, or both came back (the second
    /// on the first port: it went round the ports alone, the ring closed at its far end by a
    /// loop, and the first is whole), or the first came back and no second comes
    /// (`far_silent`).
    fn complete(&self, far_silent: bool) -> bool {
        self.first.is_some_and(|r| r.port == 1)
            || self.first.is_some() && (self.second.is_some() || far_silent)
    }
}

/// A [`Transport`] that sends every frame on both ports of a ring and gives back one frame
/// of the two copies (see the module documentation).
#[derive(Debug)]
pub struct Redundant<'a, T> {
    inner: &'a mut T,
    slots: Vec<Slot>,
    serial: u64,
    rx: Vec<u8>,
    second: Vec<u8>,
    stats: RedundancyStats,
    /// Frames in a row whose first port's copy came back by the first port and whose second
    /// did not come by the deadline. From [`SILENT_AFTER`] on the ring is taken as open at its
    /// far end (the ring cable pulled, the last slave off): a first copy back is the frame,
    /// without waiting for a second, until a second comes again. (One late copy on a loaded
    /// host is not that.)
    silent_run: u32,
}

/// Frames in a row without a second copy after which none is waited for.
const SILENT_AFTER: u32 = 3;

impl<'a, T: SecondPort> Redundant<'a, T> {
    /// Redundancy over `inner`.
    pub fn new(inner: &'a mut T) -> Self {
        Redundant {
            inner,
            slots: (0..SLOTS).map(|_| Slot::new()).collect(),
            serial: 0,
            rx: Vec::with_capacity(MAX_FRAME),
            second: vec![0; MAX_FRAME],
            stats: RedundancyStats::default(),
            silent_run: 0,
        }
    }

    /// What the ring did so far.
    pub fn stats(&self) -> RedundancyStats {
        self.stats
    }

    /// The transport underneath.
    pub fn inner(&mut self) -> &mut T {
        self.inner
    }

    /// The transport underneath, to look at.
    pub fn get_ref(&self) -> &T {
        self.inner
    }

    /// The slot for a new frame: a free one, else the oldest.
    fn take_slot(&mut self) -> usize {
        self.serial += 1;
        let k = (0..SLOTS)
            .find(|&k| !self.slots[k].used)
            .unwrap_or_else(|| {
                (0..SLOTS)
                    .min_by_key(|&k| self.slots[k].serial)
                    .unwrap_or(0)
            });
        let s = &mut self.slots[k];
        s.used = true;
        s.delivered = false;
        s.first = None;
        s.second = None;
        s.serial = self.serial;
        k
    }

    /// A frame that arrived (in `self.rx`): into its slot as the first or second port's
    /// copy.
    fn file(&mut self, r: Received) {
        let n = r.len.min(self.rx.len()).min(MAX_FRAME);
        let frame = &self.rx[..n];
        let Some(k) = (0..SLOTS).find(|&k| {
            let s = &self.slots[k];
            s.used && !s.delivered && s.key == key_of(frame)
        }) else {
            // A second copy back by the second port after its frame went without it: the far
            // side answers again (the ring broken elsewhere now).
            let late_second = (0..SLOTS).any(|k| {
                let s = &self.slots[k];
                s.delivered && s.key == key_of(frame) && n >= 12 && frame[11] != s.sent[11]
            });
            if late_second && r.port == 1 {
                self.silent_run = 0;
            }
            return;
        };
        let s = &mut self.slots[k];
        // The second copy's source address differs from the first's in its last byte (the
        // ESCs set bit 1 of the first byte on the way: not compared).
        let from_second = n >= 12 && frame[11] != s.sent[11];
        if from_second {
            self.silent_run = 0;
            s.second_buf[..n].copy_from_slice(frame);
            s.second = Some(Received { len: n, ..r });
        } else {
            s.first_buf[..n].copy_from_slice(frame);
            s.first = Some(Received { len: n, ..r });
        }
    }

    /// The frame of slot `k` into `buf`: the first copy, merged with the second where the
    /// ring is broken; the ring's state from it.
    fn deliver(&mut self, k: usize, buf: &mut Vec<u8>) -> Received {
        let s = &mut self.slots[k];
        s.delivered = true;
        s.used = false;
        let n = s.key.1;
        buf.clear();
        buf.resize(n, 0);
        let (first, second) = (s.first, s.second);
        let broken = match (first, second) {
            (Some(f), _) if f.port == 1 => {
                buf.copy_from_slice(&s.first_buf[..n]);
                self.stats.intact += 1;
                self.silent_run = 0;
                false
            }
            (Some(_), Some(g)) if g.port == 1 => {
                merge(&s.sent[..n], &s.first_buf[..n], &s.second_buf[..n], buf);
                self.stats.merged += 1;
                true
            }
            (Some(_), Some(_)) => {
                buf.copy_from_slice(&s.first_buf[..n]);
                self.stats.intact += 1;
                false
            }
            (Some(_), _) => {
                // Back by the port it left by, the second copy not: the ring is open at its
                // far end (or the far side's copy late), and the next frames do not wait.
                buf.copy_from_slice(&s.first_buf[..n]);
                self.stats.partial += 1;
                self.silent_run += 1;
                true
            }
            (None, Some(_)) => {
                // Came back on the second port (`recv` delivers no other alone).
                merge(&s.sent[..n], &s.sent[..n], &s.second_buf[..n], buf);
                self.stats.partial += 1;
                true
            }
            (None, None) => unreachable!("a slot is delivered with a copy back"),
        };
        if broken && !self.stats.broken {
            self.stats.breaks += 1;
        } else if !broken && self.stats.broken {
            self.stats.restores += 1;
        }
        self.stats.broken = broken;
        let r = first.or(second).expect("a copy back");
        Received {
            len: n,
            port: 0,
            ..r
        }
    }
}

/// The first datagram's index and the frame's length.
fn key_of(frame: &[u8]) -> (u8, usize) {
    (
        frame.get(FIRST_DATAGRAM + 1).copied().unwrap_or(0),
        frame.len(),
    )
}

/// The second port's copy of `frame` in `out`: its source address's last byte changed (to
/// tell the copies apart), its FRMW and ARMW datagrams and its writes of the receive-time
/// latch (0x0900) made NOPs (see the module documentation).
pub fn second_copy(frame: &[u8], out: &mut [u8]) {
    let n = frame.len();
    out[..n].copy_from_slice(frame);
    if n >= 12 {
        out[11] ^= 0x01;
    }
    for_each_datagram(n, out, |out, at, _| {
        let cmd = out[at];
        let ado = u16::from_le_bytes([out[at + 4], out[at + 5]]);
        // ARMW 13, FRMW 14; writes: APWR 2, FPWR 5, BWR 8, APRW 3, FPRW 6, BRW 9.
        let clock = matches!(cmd, 13 | 14);
        let latch = matches!(cmd, 2 | 3 | 5 | 6 | 8 | 9) && ado == 0x0900;
        if clock || latch {
            out[at] = 0;
        }
    });
}

/// Calls `f(frame, offset, data_len)` for each datagram of the `n`-byte frame (a malformed
/// chain ends the walk).
fn for_each_datagram(n: usize, frame: &mut [u8], mut f: impl FnMut(&mut [u8], usize, usize)) {
    let mut at = FIRST_DATAGRAM;
    while at + DATAGRAM_HEADER + 2 <= n {
        let len_word = u16::from_le_bytes([frame[at + 6], frame[at + 7]]);
        let len = usize::from(len_word & 0x07ff);
        if at + DATAGRAM_HEADER + len + 2 > n {
            return;
        }
        f(frame, at, len);
        if len_word & 0x8000 == 0 {
            return;
        }
        at += DATAGRAM_HEADER + len + 2;
    }
}

/// The frame of two copies processed by the two sides of a broken ring, into `out`: the
/// first's headers, each datagram's working counter the sum, each data byte the one a side
/// changed from `sent` (both: ORed).
pub fn merge(sent: &[u8], first: &[u8], second: &[u8], out: &mut [u8]) {
    let n = sent.len();
    out[..n].copy_from_slice(first);
    for_each_datagram(n, out, |out, at, len| {
        let d = at + DATAGRAM_HEADER;
        for i in d..d + len {
            let (s, p, q) = (sent[i], first[i], second[i]);
            out[i] = if q == s {
                p
            } else if p == s {
                q
            } else {
                p | q
            };
        }
        let w = d + len;
        let wkc = u16::from_le_bytes([first[w], first[w + 1]])
            .wrapping_add(u16::from_le_bytes([second[w], second[w + 1]]));
        out[w..w + 2].copy_from_slice(&wkc.to_le_bytes());
    });
}

impl<T: SecondPort> Transport for Redundant<'_, T> {
    type Error = T::Error;

    fn now(&mut self) -> MasterInstant {
        self.inner.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
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
        let k = self.take_slot();
        let n = len.min(MAX_FRAME);
        let sent = &mut self.slots[k].sent;
        let stamp = self.inner.send_with(len, at, |buf| {
            fill(buf);
            sent[..n].copy_from_slice(&buf[..n]);
        })?;
        let s = &mut self.slots[k];
        s.key = key_of(&s.sent[..n]);
        second_copy(&s.sent[..n], &mut self.second);
        self.inner.send_secondary(&self.second[..n], at)?;
        Ok(stamp)
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Self::Error> {
        loop {
            let far_silent = self.silent_run >= SILENT_AFTER;
            if let Some(k) = (0..SLOTS).find(|&k| {
                let s = &self.slots[k];
                s.used && !s.delivered && s.complete(far_silent)
            }) {
                return Ok(Some(self.deliver(k, buf)));
            }
            match self.inner.recv(&mut self.rx, deadline)? {
                Some(r) => self.file(r),
                None => {
                    // The deadline: a frame of which one copy came back processed, the oldest
                    // first: the first port's on the port it left by (the ring broken, the
                    // far side's copy late), or the second port's on the second (the same,
                    // the near side's late). A second copy that went round the ports alone
                    // is no frame (the ring is whole and the first copy late): the frame is
                    // lost, as on one port, and a first copy that comes later is late.
                    let partial = (0..SLOTS)
                        .filter(|&k| {
                            let s = &self.slots[k];
                            s.used
                                && !s.delivered
                                && (s.first.is_some() || s.second.is_some_and(|g| g.port == 1))
                        })
                        .min_by_key(|&k| self.slots[k].serial);
                    return Ok(partial.map(|k| self.deliver(k, buf)));
                }
            }
        }
    }

    fn start_cycle(&mut self, cycle: u64) {
        self.inner.start_cycle(cycle);
    }
}

#[cfg(test)]
#[path = "redundancy_tests.rs"]
mod tests;
