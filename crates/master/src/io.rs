//! The sans-IO boundary. Master procedures are `async` code written against a [`Link`]; they
//! never touch a socket or a clock. An [`Engine`] runs such a procedure step by step: each
//! [`Engine::poll`] says what the procedure needs (send this frame, wake me at that time) and
//! the driver — the in-process segment, a raw socket — does it and hands back the reply with
//! its timestamps. The same procedure thus runs in virtual time against the simulator and in
//! real time on a network interface.

use crate::MasterError;
use ecsync_dc::time::MasterInstant;
use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::task::{Context, Poll, Waker};

mod side_by_side;

/// Source MAC of frames the master sends (locally administered bit clear, so returning frames,
/// which the first ESC marks, are told apart).
pub const MASTER_MAC: [u8; 6] = [0x00, 0x1b, 0x21, 0xec, 0x00, 0x01];

/// A reply with the master clock's timestamps.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Reply {
    /// The frame as it came back.
    pub frame: Vec<u8>,
    /// Right before the frame was handed to the network (t_ms).
    pub sent: MasterInstant,
    /// When the reply was received.
    pub received: MasterInstant,
}

/// Something the procedure reports to the driver along the way.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A bring-up phase begins (reported for the phases a progress line names, see
    /// [`crate::bringup::bringup`]).
    Phase(crate::network::Phase),
    /// System time offsets and delays were written (ground truth can be compared now).
    OffsetsWritten,
}

#[derive(Debug, Default)]
struct Shared {
    now_ns: u64,
    outgoing: Option<Vec<u8>>,
    sleep_until: Option<u64>,
    /// The reply, or the number of sends after which the frame was given up.
    reply: Option<Result<Reply, u32>>,
    events: Vec<Event>,
    next_index: u8,
    last_sent_ns: u64,
    last_received_ns: u64,
    /// The distribution of the system time that rides along the exchanges, if on.
    keep_time: Option<KeepTime>,
    /// An exchange's frames to send back to back ([`Action::SendAll`]).
    outgoing_all: Option<Vec<Vec<u8>>>,
    /// Their replies, in order: each the reply or the sends after which it was given up.
    replies: Option<Vec<Result<Reply, u32>>>,
    /// The driver takes an exchange's frames back to back ([`Engine::send_back_to_back`]).
    batches: bool,
}

/// The system time's distribution kept up between the cyclic frames ([`Link::keep_time`]).
#[derive(Debug, Clone)]
struct KeepTime {
    /// The FRMW of the reference's System Time.
    frmw: Pdu,
    /// Longest time between two FRMWs, ns.
    interval_ns: u64,
    /// When the last frame with the FRMW left, ns.
    last_ns: u64,
}

/// The procedure's handle on the network: frames out, replies in, time.
#[derive(Debug, Clone)]
pub struct Link {
    shared: Arc<Mutex<Shared>>,
}

/// One datagram of a request frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pdu {
    /// Command.
    pub command: Command,
    /// Raw 32-bit address.
    pub address: u32,
    /// Data (zeros of the read length for reads).
    pub data: Vec<u8>,
}

impl Pdu {
    /// A datagram.
    pub fn new(command: Command, address: DatagramAddress, data: Vec<u8>) -> Self {
        Pdu {
            command,
            address: address.raw(),
            data,
        }
    }
}

/// One datagram of a reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PduReply {
    /// Data as returned.
    pub data: Vec<u8>,
    /// Working counter.
    pub wkc: u16,
    /// Address field as returned (ADP incremented by auto-increment commands).
    pub address: u32,
}

struct Exchange<'a> {
    link: &'a Link,
    frame: Option<Vec<u8>>,
}

impl Future for Exchange<'_> {
    type Output = Result<Reply, u32>;
    fn poll(mut self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<Self::Output> {
        let mut s = self.link.lock();
        if let Some(f) = self.frame.take() {
            s.outgoing = Some(f);
            s.reply = None;
            return Poll::Pending;
        }
        match s.reply.take() {
            Some(r) => Poll::Ready(r),
            None => Poll::Pending,
        }
    }
}

struct BatchExchange<'a> {
    link: &'a Link,
    frames: Option<Vec<Vec<u8>>>,
}

impl Future for BatchExchange<'_> {
    type Output = Vec<Result<Reply, u32>>;
    fn poll(mut self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<Self::Output> {
        let mut s = self.link.lock();
        if let Some(f) = self.frames.take() {
            s.outgoing_all = Some(f);
            s.replies = None;
            return Poll::Pending;
        }
        match s.replies.take() {
            Some(r) => Poll::Ready(r),
            None => Poll::Pending,
        }
    }
}

struct Sleep<'a> {
    link: &'a Link,
    until_ns: u64,
}

impl Future for Sleep<'_> {
    type Output = ();
    fn poll(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<()> {
        let mut s = self.link.lock();
        if s.now_ns >= self.until_ns {
            s.sleep_until = None;
            Poll::Ready(())
        } else {
            s.sleep_until = Some(self.until_ns);
            Poll::Pending
        }
    }
}

/// The datagrams and `extra` fit one frame.
fn fits_with(pdus: &[Pdu], extra: &Pdu) -> bool {
    let room =
        ecsync_wire::MAX_FRAME_LEN - ecsync_wire::ETH_HEADER_LEN - ecsync_wire::ECAT_HEADER_LEN;
    let used: usize = pdus
        .iter()
        .chain([extra])
        .map(|p| ecsync_wire::DATAGRAM_OVERHEAD + p.data.len())
        .sum();
    used <= room
}

/// What [`Link::build_frame`] put into a frame besides the datagrams asked for.
#[derive(Debug)]
struct Built {
    /// The first datagram's index.
    first_index: u8,
    /// The time's FRMW, last in the frame, if it rides along.
    extra: Option<Pdu>,
}

/// The error of an exchange whose frame with `pdus` was lost after `attempts` sends.
fn lost(what: &'static str, pdus: &[Pdu], attempts: u32) -> MasterError {
    MasterError::FrameLost {
        what,
        first: pdus.first().map(|p| (p.command, p.address)),
        datagrams: pdus.len() as u16,
        attempts,
    }
}

/// The replies to `pdus` in a frame built as `built`, in order; the time's FRMW checked and
/// left out (nobody waits for it).
fn parse_reply(pdus: &[Pdu], built: &Built, reply: &Reply) -> Result<Vec<PduReply>, MasterError> {
    let f = EcatFrame::new_checked(&reply.frame[..])
        .map_err(|_| MasterError::BadReply("not an EtherCAT frame"))?;
    let mut out = Vec::with_capacity(pdus.len());
    for (i, d) in f.datagrams().enumerate() {
        let d = d.map_err(|_| MasterError::BadReply("malformed datagram"))?;
        let req = pdus
            .get(i)
            .or(built.extra.as_ref().filter(|_| i == pdus.len()))
            .ok_or(MasterError::BadReply("extra datagram"))?;
        if d.index() != built.first_index.wrapping_add(i as u8)
            || d.command_code() != req.command.code()
            || d.data_len() != req.data.len()
        {
            return Err(MasterError::BadReply("datagram index, command or length"));
        }
        if i == pdus.len() {
            continue;
        }
        out.push(PduReply {
            data: d.data().to_vec(),
            wkc: d.wkc(),
            address: d.address_raw(),
        });
    }
    if out.len() != pdus.len() {
        return Err(MasterError::BadReply("missing datagram"));
    }
    Ok(out)
}

impl Link {
    /// The state shared with the engine (a procedure never panics while holding it; a poisoned
    /// lock is taken as it is).
    fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The master's clock now.
    pub fn now(&self) -> MasterInstant {
        MasterInstant::from_ns(self.lock().now_ns)
    }

    /// Right before the last frame that came back was sent (its send timestamp).
    pub fn last_sent(&self) -> MasterInstant {
        MasterInstant::from_ns(self.lock().last_sent_ns)
    }

    /// When the last frame that came back was received (its receive timestamp).
    pub fn last_received(&self) -> MasterInstant {
        MasterInstant::from_ns(self.lock().last_received_ns)
    }

    /// Reports an event to the driver.
    pub fn event(&self, e: Event) {
        self.lock().events.push(e);
    }

    /// Keeps the slaves' clocks fed with the reference's time from now on: the first frame of
    /// an exchange that leaves `interval_ns` or more after the last frame with `frmw` (the FRMW
    /// of the reference's System Time) carries it too, and its reply is not handed back. Once
    /// drift compensation has locked, a master distributes the system time every cycle (the
    /// ESC datasheet's dynamic drift compensation); without it the time control loops run free
    /// on the frequency they have learnt, whose error the static compensation only makes
    /// small: a 256-drive line's configuration, seconds of frames without an FRMW, let drives
    /// drift 2.8 us from the reference. `None` stops it.
    pub fn keep_time(&self, keep: Option<(Pdu, u64)>) {
        let now_ns = self.now().as_ns();
        self.lock().keep_time = keep.map(|(frmw, interval_ns)| KeepTime {
            frmw,
            interval_ns,
            last_ns: now_ns,
        });
    }

    /// Sends a raw frame and waits for its reply; `Err(sends)`: lost after that many sends.
    pub async fn exchange(&self, frame: Vec<u8>) -> Result<Reply, u32> {
        Exchange {
            link: self,
            frame: Some(frame),
        }
        .await
    }

    /// Waits until master time `until_ns`.
    pub async fn sleep_until(&self, until_ns: u64) {
        Sleep {
            link: self,
            until_ns,
        }
        .await
    }

    /// Sends the datagrams and returns their replies in order: in one frame when they fit, else
    /// in as many frames as they need (each up to `MAX_FRAME_LEN`, in order), so that a network
    /// of any size can be asked everything at once. The frames go back to back when the driver
    /// asked for it ([`Engine::send_back_to_back`]), else each after the last one's reply. The
    /// reply is the first frame's (its timestamps).
    pub async fn pdus(
        &self,
        pdus: &[Pdu],
        what: &'static str,
    ) -> Result<(Vec<PduReply>, Reply), MasterError> {
        // The first frame keeps room for the time's FRMW when it is kept up.
        let keep_room = self
            .lock()
            .keep_time
            .as_ref()
            .map_or(0, |k| ecsync_wire::DATAGRAM_OVERHEAD + k.frmw.data.len());
        let room =
            ecsync_wire::MAX_FRAME_LEN - ecsync_wire::ETH_HEADER_LEN - ecsync_wire::ECAT_HEADER_LEN;
        let mut parts = Vec::new();
        let mut start = 0;
        loop {
            let mut end = start;
            let mut used = if start == 0 { keep_room } else { 0 };
            while end < pdus.len() {
                let need = ecsync_wire::DATAGRAM_OVERHEAD + pdus[end].data.len();
                if used + need > room && end > start {
                    break;
                }
                used += need;
                end += 1;
            }
            parts.push(start..end);
            start = end;
            if start >= pdus.len() {
                break;
            }
        }
        let mut out = Vec::with_capacity(pdus.len());
        if parts.len() > 1 && self.lock().batches {
            // Back to back, as the cyclic frames go: a large network's exchange takes one
            // round trip, not one per frame.
            let mut sent: Vec<Built> = Vec::with_capacity(parts.len());
            let mut frames = Vec::with_capacity(parts.len());
            for (k, r) in parts.iter().enumerate() {
                // A reply is matched to its frame by the first datagram's command and index:
                // no two frames of the exchange start with the same index (a large exchange's
                // indices wrap, and a second responder's copy of one frame would otherwise
                // answer another).
                {
                    let mut s = self.lock();
                    while sent.len() < 256 && sent.iter().any(|b| b.first_index == s.next_index) {
                        s.next_index = s.next_index.wrapping_add(1);
                    }
                }
                let (frame, built) = self.build_frame(&pdus[r.clone()], k == 0, what)?;
                frames.push(frame);
                sent.push(built);
            }
            let replies = BatchExchange {
                link: self,
                frames: Some(frames),
            }
            .await;
            let mut first = None;
            for ((r, built), reply) in parts.into_iter().zip(&sent).zip(replies) {
                let part = &pdus[r];
                let reply = reply.map_err(|attempts| lost(what, part, attempts))?;
                out.extend(parse_reply(part, built, &reply)?);
                first.get_or_insert(reply);
            }
            return Ok((out, first.unwrap_or_default()));
        }
        let mut first = None;
        for (k, r) in parts.into_iter().enumerate() {
            let part = &pdus[r];
            let (frame, built) = self.build_frame(part, k == 0, what)?;
            let reply = self
                .exchange(frame)
                .await
                .map_err(|attempts| lost(what, part, attempts))?;
            out.extend(parse_reply(part, &built, &reply)?);
            first.get_or_insert(reply);
        }
        Ok((out, first.unwrap_or_default()))
    }

    /// The frame of `pdus`, their indices taken from the link's. The time's FRMW, when it is
    /// kept up and due, goes last in the frame (`may_keep_time`: the exchange's first frame,
    /// which has room for it).
    fn build_frame(
        &self,
        pdus: &[Pdu],
        may_keep_time: bool,
        what: &'static str,
    ) -> Result<(Vec<u8>, Built), MasterError> {
        let mut buf = vec![0u8; ecsync_wire::MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC)
            .map_err(|_| MasterError::BadReply("frame buffer"))?;
        let mut s = self.lock();
        let now_ns = s.now_ns;
        let mut extra = None;
        if let Some(k) = s.keep_time.as_mut() {
            let carries = pdus
                .iter()
                .any(|p| p.command == k.frmw.command && p.address == k.frmw.address);
            if carries {
                k.last_ns = now_ns;
            } else if may_keep_time
                && now_ns.saturating_sub(k.last_ns) >= k.interval_ns
                && fits_with(pdus, &k.frmw)
            {
                k.last_ns = now_ns;
                extra = Some(k.frmw.clone());
            }
        }
        let first_index = s.next_index;
        for (i, p) in pdus.iter().chain(extra.as_ref()).enumerate() {
            b.push(
                p.command,
                first_index.wrapping_add(i as u8),
                DatagramAddress::Logical(p.address),
                &p.data,
            )
            .map_err(|_| MasterError::Config(format!("{what}: a datagram larger than a frame")))?;
        }
        s.next_index = first_index.wrapping_add((pdus.len() + usize::from(extra.is_some())) as u8);
        let n = b.finish();
        buf.truncate(n);
        Ok((buf, Built { first_index, extra }))
    }

    /// One datagram in its own frame.
    pub async fn pdu(
        &self,
        command: Command,
        address: DatagramAddress,
        data: Vec<u8>,
        what: &'static str,
    ) -> Result<PduReply, MasterError> {
        let (mut r, _) = self.pdus(&[Pdu::new(command, address, data)], what).await?;
        Ok(r.remove(0))
    }

    /// One datagram whose working counter must equal `expected`.
    pub async fn pdu_wkc(
        &self,
        command: Command,
        address: DatagramAddress,
        data: Vec<u8>,
        expected: u16,
        what: &'static str,
    ) -> Result<Vec<u8>, MasterError> {
        let r = self.pdu(command, address, data, what).await?;
        if r.wkc != expected {
            return Err(MasterError::WorkingCounter {
                command,
                what,
                expected,
                got: r.wkc,
            });
        }
        Ok(r.data)
    }

    /// FPRD of `len` bytes from one slave (WKC 1).
    pub async fn fprd(
        &self,
        station: u16,
        register: u16,
        len: usize,
        what: &'static str,
    ) -> Result<Vec<u8>, MasterError> {
        self.pdu_wkc(
            Command::Fprd,
            DatagramAddress::Configured {
                adp: station,
                ado: register,
            },
            vec![0; len],
            1,
            what,
        )
        .await
    }

    /// FPWR to one slave (WKC 1).
    pub async fn fpwr(
        &self,
        station: u16,
        register: u16,
        data: &[u8],
        what: &'static str,
    ) -> Result<(), MasterError> {
        self.pdu_wkc(
            Command::Fpwr,
            DatagramAddress::Configured {
                adp: station,
                ado: register,
            },
            data.to_vec(),
            1,
            what,
        )
        .await
        .map(|_| ())
    }

    /// BWR to all slaves; returns the working counter.
    pub async fn bwr(
        &self,
        register: u16,
        data: &[u8],
        what: &'static str,
    ) -> Result<u16, MasterError> {
        Ok(self
            .pdu(
                Command::Bwr,
                DatagramAddress::Position {
                    adp: 0,
                    ado: register,
                },
                data.to_vec(),
                what,
            )
            .await?
            .wkc)
    }
}

/// What the procedure needs next.
#[derive(Debug, PartialEq, Eq)]
pub enum Action<'a, T> {
    /// Send this frame now and hand its reply to [`Engine::handle_reply`] (or report loss with
    /// [`Engine::handle_lost`]).
    Send(&'a [u8]),
    /// Send these frames now, back to back, and hand their replies to
    /// [`Engine::handle_replies`], in the same order. Only for a driver that asked for it
    /// ([`Engine::send_back_to_back`]).
    SendAll(&'a [Vec<u8>]),
    /// Nothing to do before master time `t_ns`; poll again then.
    WaitUntil(MasterInstant),
    /// The procedure finished.
    Done(T),
}

type Proc<T> = Pin<Box<dyn Future<Output = T> + Send>>;

/// Runs an async procedure step by step, without I/O of its own.
pub struct Engine<T> {
    link: Link,
    proc: Option<Proc<T>>,
    pending: Option<Vec<u8>>,
    pending_all: Option<Vec<Vec<u8>>>,
    result: Option<T>,
}

impl<T> std::fmt::Debug for Engine<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine").finish_non_exhaustive()
    }
}

impl<T: 'static> Engine<T> {
    /// Wraps a procedure built from a link.
    pub fn new<F, Fut>(make: F) -> Self
    where
        F: FnOnce(Link) -> Fut,
        Fut: Future<Output = T> + Send + 'static,
    {
        let link = Link {
            shared: Arc::new(Mutex::new(Shared::default())),
        };
        let proc: Proc<T> = Box::pin(make(link.clone()));
        Engine {
            link,
            proc: Some(proc),
            pending: None,
            pending_all: None,
            result: None,
        }
    }

    /// The driver sends the frames of an exchange that needs several back to back
    /// ([`Action::SendAll`]); otherwise (the default) they come one at a time, each after the
    /// last one's reply.
    pub fn send_back_to_back(&mut self) {
        self.link.lock().batches = true;
    }

    /// Advances the procedure at master time `now_ns`.
    pub fn poll(&mut self, now: MasterInstant) -> Action<'_, T> {
        self.link.lock().now_ns = now.as_ns();
        if self.pending.is_some() {
            // A frame is out; the driver must answer it first.
            return Action::Send(self.pending.as_deref().unwrap_or(&[]));
        }
        if self.pending_all.is_some() {
            return Action::SendAll(self.pending_all.as_deref().unwrap_or(&[]));
        }
        if let Some(p) = self.proc.as_mut() {
            let mut cx = Context::from_waker(Waker::noop());
            if let Poll::Ready(v) = p.as_mut().poll(&mut cx) {
                self.proc = None;
                self.result = Some(v);
            }
        }
        if let Some(v) = self.result.take() {
            return Action::Done(v);
        }
        let mut s = self.link.lock();
        if let Some(f) = s.outgoing.take() {
            drop(s);
            self.pending = Some(f);
            return Action::Send(self.pending.as_deref().unwrap_or(&[]));
        }
        if let Some(f) = s.outgoing_all.take() {
            drop(s);
            self.pending_all = Some(f);
            return Action::SendAll(self.pending_all.as_deref().unwrap_or(&[]));
        }
        match s.sleep_until {
            Some(t) => Action::WaitUntil(MasterInstant::from_ns(t)),
            // A procedure that waits on nothing would never finish; treat as a busy poll.
            None => Action::WaitUntil(now),
        }
    }

    /// The frame sent last came back: `sent_ns` is the master time right before sending,
    /// `received_ns` the time the reply arrived.
    pub fn handle_reply(&mut self, frame: &[u8], sent: MasterInstant, received: MasterInstant) {
        self.pending = None;
        let mut s = self.link.lock();
        s.now_ns = s.now_ns.max(received.as_ns());
        s.last_sent_ns = sent.as_ns();
        s.last_received_ns = received.as_ns();
        s.reply = Some(Ok(Reply {
            frame: frame.to_vec(),
            sent,
            received,
        }));
    }

    /// The frames of [`Action::SendAll`] came back or were given up: one entry each, in their
    /// order (`Err(sends)`: lost after that many sends). The master's clock moves to the last
    /// reply's arrival; the link's last send and receive times are the last reply's.
    pub fn handle_replies(&mut self, replies: Vec<Result<Reply, u32>>) {
        self.pending_all = None;
        let mut s = self.link.lock();
        for r in replies.iter().flatten() {
            s.now_ns = s.now_ns.max(r.received.as_ns());
            s.last_sent_ns = r.sent.as_ns();
            s.last_received_ns = r.received.as_ns();
        }
        s.replies = Some(replies);
    }

    /// The frame sent last was lost.
    pub fn handle_lost(&mut self) {
        self.handle_lost_after(1);
    }

    /// Reports that the frame was lost after `attempts` sends (the driver's retries).
    pub fn handle_lost_after(&mut self, attempts: u32) {
        self.pending = None;
        self.link.lock().reply = Some(Err(attempts.max(1)));
    }

    /// Takes the events reported since the last call.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.link.lock().events)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frmw() -> Pdu {
        Pdu::new(
            Command::Frmw,
            DatagramAddress::Configured {
                adp: 0x1000,
                ado: 0x0910,
            },
            vec![0; 8],
        )
    }

    fn fprd(ado: u16) -> Pdu {
        Pdu::new(
            Command::Fprd,
            DatagramAddress::Configured { adp: 0x1001, ado },
            vec![0; 2],
        )
    }

    /// The commands of a frame the engine sends.
    fn commands(frame: &[u8]) -> Vec<u8> {
        EcatFrame::new_checked(frame)
            .unwrap()
            .datagrams()
            .map(|d| d.unwrap().command_code())
            .collect()
    }

    /// With the time kept up every millisecond, the first exchange a millisecond or more after
    /// the last FRMW carries one last in its frame, its reply kept from the procedure; an
    /// exchange with its own FRMW counts as one; sooner, or with the keeping off, no FRMW.
    #[test]
    fn kept_time_rides_along_once_a_cycle() {
        let mut engine = Engine::new(|link: Link| async move {
            link.keep_time(Some((frmw(), 1_000_000)));
            let mut wkcs = Vec::new();
            for (at_ns, pdus) in [
                (500_000, vec![fprd(0x130)]),
                (1_000_000, vec![fprd(0x130), fprd(0x134)]),
                (1_500_000, vec![fprd(0x130)]),
                (2_200_000, vec![frmw(), fprd(0x130)]),
                (3_100_000, vec![fprd(0x130)]),
                (4_200_000, vec![fprd(0x130)]),
            ] {
                link.sleep_until(at_ns).await;
                if at_ns == 4_200_000 {
                    link.keep_time(None);
                }
                let (r, _) = link.pdus(&pdus, "test").await.unwrap();
                wkcs.push(r.iter().map(|p| p.wkc).collect::<Vec<_>>());
            }
            wkcs
        });
        let (mut now_ns, mut sent) = (0u64, Vec::new());
        let wkcs = loop {
            match engine.poll(MasterInstant::from_ns(now_ns)) {
                Action::Send(f) => {
                    let f = f.to_vec();
                    sent.push(commands(&f));
                    // Every datagram answered by one slave.
                    let reply = answered(&f);
                    engine.handle_reply(
                        &reply,
                        MasterInstant::from_ns(now_ns),
                        MasterInstant::from_ns(now_ns + 10_000),
                    );
                    now_ns += 10_000;
                }
                Action::SendAll(_) => panic!("frames at once, not asked for"),
                Action::WaitUntil(t) => now_ns = now_ns.max(t.as_ns()),
                Action::Done(v) => break v,
            }
        };
        let (rd, rw) = (Command::Fprd.code(), Command::Frmw.code());
        assert_eq!(
            sent,
            vec![
                vec![rd],
                vec![rd, rd, rw],
                vec![rd],
                vec![rw, rd],
                vec![rd],
                vec![rd],
            ]
        );
        assert_eq!(
            wkcs,
            vec![vec![1], vec![1, 1], vec![1], vec![1, 1], vec![1], vec![1]]
        );
    }

    /// `n` FPRDs of `len` bytes, one to each of `n` stations.
    fn reads(n: u16, len: usize) -> Vec<Pdu> {
        (0..n)
            .map(|i| {
                Pdu::new(
                    Command::Fprd,
                    DatagramAddress::Configured {
                        adp: 0x1000 + i,
                        ado: 0x0910,
                    },
                    vec![0; len],
                )
            })
            .collect()
    }

    /// `frame` answered (see [`answered`]), sent at 0 and back at 1 us.
    fn answered_ok(frame: &[u8]) -> Result<Reply, u32> {
        Ok(Reply {
            frame: answered(frame),
            sent: MasterInstant::from_ns(0),
            received: MasterInstant::from_ns(1_000),
        })
    }

    /// Echoes `frame` with every datagram's working counter 1.
    fn answered(frame: &[u8]) -> Vec<u8> {
        let lens: Vec<usize> = EcatFrame::new_checked(frame)
            .unwrap()
            .datagrams()
            .map(|d| d.unwrap().total_len())
            .collect();
        let mut reply = frame.to_vec();
        let mut at = ecsync_wire::ETH_HEADER_LEN + ecsync_wire::ECAT_HEADER_LEN;
        for len in lens {
            ecsync_wire::Datagram::new_checked(&mut reply[at..])
                .unwrap()
                .set_wkc(1);
            at += len;
        }
        reply
    }

    /// 300 reads of 16 bytes need four frames: a driver that asked for it gets them at once
    /// (their datagram indices running on from frame to frame), and the replies in the order
    /// asked; one frame lost names its first datagram; without asking, the frames come one by
    /// one, each after the last one's reply.
    #[test]
    fn an_exchange_of_several_frames_goes_back_to_back() {
        let reads = reads(300, 16);
        let make = |reads: Vec<Pdu>| {
            move |link: Link| async move {
                let first = link.pdus(&reads, "reads").await.map(|(r, _)| r.len());
                let second = link.pdus(&reads, "reads").await.map(|(r, _)| r.len());
                (first, second)
            }
        };
        // Back to back, the second exchange's third frame lost.
        let mut engine = Engine::new(make(reads.clone()));
        engine.send_back_to_back();
        let mut batches = Vec::new();
        let mut lost_first = None;
        let out = loop {
            match engine.poll(MasterInstant::from_ns(0)) {
                Action::SendAll(frames) => {
                    let frames = frames.to_vec();
                    let indices: Vec<Vec<u8>> = frames
                        .iter()
                        .map(|f| {
                            EcatFrame::new_checked(&f[..])
                                .unwrap()
                                .datagrams()
                                .map(|d| d.unwrap().index())
                                .collect()
                        })
                        .collect();
                    let all: Vec<u8> = indices.concat();
                    assert_eq!(all.len(), 300);
                    assert!(all.windows(2).all(|w| w[1] == w[0].wrapping_add(1)));
                    let lose = batches.len() == 1;
                    batches.push(frames.len());
                    let replies = frames
                        .iter()
                        .enumerate()
                        .map(|(k, f)| {
                            if lose && k == 2 {
                                let f = EcatFrame::new_checked(&f[..]).unwrap();
                                lost_first = f.datagrams().next().map(|d| d.unwrap().address_raw());
                                Err(4)
                            } else {
                                answered_ok(f)
                            }
                        })
                        .collect();
                    engine.handle_replies(replies);
                }
                Action::Send(_) => panic!("a frame alone"),
                Action::WaitUntil(_) => panic!("a wait"),
                Action::Done(v) => break v,
            }
        };
        // 28 bytes a read, 53 to a frame.
        assert_eq!(batches, vec![6, 6]);
        assert_eq!(out.0.unwrap(), 300);
        match out.1 {
            Err(MasterError::FrameLost {
                first, attempts, ..
            }) => {
                assert_eq!(attempts, 4);
                assert_eq!(first.map(|f| f.1), lost_first);
                assert_eq!(lost_first, Some(reads[2 * 53].address));
            }
            other => panic!("{other:?}"),
        }
        // One by one.
        let mut engine = Engine::new(make(reads));
        let mut frames = 0;
        let out = loop {
            match engine.poll(MasterInstant::from_ns(0)) {
                Action::Send(f) => {
                    let reply = answered(f);
                    frames += 1;
                    engine.handle_reply(
                        &reply,
                        MasterInstant::from_ns(0),
                        MasterInstant::from_ns(1_000),
                    );
                }
                Action::SendAll(_) => panic!("frames at once, not asked for"),
                Action::WaitUntil(_) => panic!("a wait"),
                Action::Done(v) => break v,
            }
        };
        assert_eq!(frames, 12);
        assert_eq!((out.0.unwrap(), out.1.unwrap()), (300, 300));
    }

    /// Frames of 32 datagrams: the ninth would start on the first one's index; it starts one
    /// later, and every reply still reaches its datagram.
    #[test]
    fn no_two_frames_of_an_exchange_start_on_one_index() {
        let reads = reads(300, 34);
        let mut engine = Engine::new(move |link: Link| async move {
            link.pdus(&reads, "reads").await.map(|(r, _)| r.len())
        });
        engine.send_back_to_back();
        let mut firsts = Vec::new();
        let out = loop {
            match engine.poll(MasterInstant::from_ns(0)) {
                Action::SendAll(frames) => {
                    let frames = frames.to_vec();
                    firsts = frames
                        .iter()
                        .map(|f| EcatFrame::new_checked(&f[..]).unwrap().first_datagram_id())
                        .collect();
                    let replies = frames.iter().map(|f| answered_ok(f)).collect();
                    engine.handle_replies(replies);
                }
                Action::Send(_) => panic!("a frame alone"),
                Action::WaitUntil(_) => panic!("a wait"),
                Action::Done(v) => break v,
            }
        };
        assert_eq!(out.unwrap(), 300);
        assert_eq!(firsts.len(), 10);
        let indices: Vec<u8> = firsts.iter().map(|f| f.unwrap().1).collect();
        assert_eq!(indices[..9], [0, 32, 64, 96, 128, 160, 192, 224, 1]);
        let mut unique = indices.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), indices.len(), "{indices:?}");
    }
}
