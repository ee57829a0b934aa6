//! Procedures of many slaves run side by side: each written as if it had the network to
//! itself, their exchanges merged into one exchange a round.
//!
//! A line of 2 000 drives takes about 2 ms for a frame to go round. Reading the SII EEPROMs
//! one slave after the other costs a round trip per EEPROM command and poll (about 275 a
//! slave): 20 minutes for the identification alone. Run side by side, every slave's next
//! command rides in the same frames, and the whole network takes as many rounds as one slave
//! takes exchanges. SOEM reads the identities of all slaves this way (`ecx_readeeprom1`, then
//! `ecx_readeeprom2`); here any procedure written against a [`Link`] can be.

use super::{Link, MasterError, Pdu, Reply, Shared};
use ecsync_wire::{Datagram, EcatFrame};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};

/// One procedure of [`Link::side_by_side`]: its own link, whose frames the runner merges.
struct Member<F: Future> {
    link: Link,
    proc: Option<Pin<Box<F>>>,
}

/// A member's request frame: its datagrams as the runner sends them, and where each lies.
struct Request {
    member: usize,
    frame: Vec<u8>,
    offsets: Vec<usize>,
}

impl Request {
    /// Parses a member's frame; `None` if it is not a well-formed EtherCAT frame (a member
    /// never builds one).
    fn parse(member: usize, frame: Vec<u8>, pdus: &mut Vec<Pdu>) -> Option<Self> {
        let mut offsets = Vec::new();
        let f = EcatFrame::new_checked(&frame[..]).ok()?;
        for (at, d) in f.datagrams().with_frame_offsets() {
            let d = d.ok()?;
            pdus.push(Pdu {
                command: d.command().ok()?,
                address: d.address_raw(),
                data: d.data().to_vec(),
            });
            offsets.push(at);
        }
        Some(Request {
            member,
            frame,
            offsets,
        })
    }
}

impl Link {
    /// Runs `make(link, item)` for every item side by side and returns their results in the
    /// items' order. Each procedure gets a link of its own and exchanges frames on it as on
    /// any link; each round, the runner takes the frame every waiting procedure wants to
    /// exchange and sends their datagrams together in one exchange on `self` (in as many
    /// frames as they need, see [`Link::pdus`]), then hands each procedure its datagrams'
    /// replies in a reply frame of its own, with the merged exchange's timestamps. A procedure
    /// that sleeps is polled again when the earliest sleeper's time has come, if no other
    /// procedure has a frame to exchange before.
    ///
    /// When the merged exchange's frame is lost, every procedure in it sees its frame lost
    /// (after as many sends); any other failure of the exchange ends the run with that error.
    pub async fn side_by_side<I, R, F>(
        &self,
        items: Vec<I>,
        mut make: impl FnMut(Link, I) -> F,
        what: &'static str,
    ) -> Result<Vec<R>, MasterError>
    where
        F: Future<Output = R>,
    {
        let mut members: Vec<Member<F>> = items
            .into_iter()
            .map(|item| {
                let link = Link {
                    shared: Arc::new(Mutex::new(Shared::default())),
                };
                let proc = Some(Box::pin(make(link.clone(), item)));
                Member { link, proc }
            })
            .collect();
        let mut results: Vec<Option<R>> = members.iter().map(|_| None).collect();
        loop {
            let now_ns = self.now().as_ns();
            let mut requests = Vec::new();
            let mut pdus = Vec::new();
            let mut wake_ns: Option<u64> = None;
            for (k, m) in members.iter_mut().enumerate() {
                let Some(proc) = m.proc.as_mut() else {
                    continue;
                };
                m.link.lock().now_ns = now_ns;
                // (A context of its own each time: none is held across the awaits below.)
                let mut cx = Context::from_waker(Waker::noop());
                if let Poll::Ready(r) = proc.as_mut().poll(&mut cx) {
                    results[k] = Some(r);
                    m.proc = None;
                    continue;
                }
                let mut s = m.link.lock();
                if let Some(frame) = s.outgoing.take() {
                    drop(s);
                    let r = Request::parse(k, frame, &mut pdus)
                        .ok_or(MasterError::BadReply("a procedure's frame is malformed"))?;
                    requests.push(r);
                } else {
                    // Sleeping (or waiting on nothing: polled again next round).
                    let t = s.sleep_until.unwrap_or(now_ns.saturating_add(1));
                    wake_ns = Some(wake_ns.map_or(t, |w| w.min(t)));
                }
            }
            if requests.is_empty() {
                match wake_ns {
                    Some(t) => {
                        self.sleep_until(t).await;
                        continue;
                    }
                    None => break,
                }
            }
            match self.pdus(&pdus, what).await {
                Ok((replies, first)) => {
                    let mut replies = replies.into_iter();
                    for r in requests {
                        let reply = answer(r.frame, &r.offsets, &mut replies, &first);
                        hand_back(&members[r.member].link, Ok(reply));
                    }
                }
                Err(MasterError::FrameLost { attempts, .. }) => {
                    for r in requests {
                        hand_back(&members[r.member].link, Err(attempts));
                    }
                }
                Err(e) => return Err(e),
            }
        }
        Ok(results.into_iter().flatten().collect())
    }
}

/// A member's reply: its request with the replies' data, working counters and addresses.
fn answer(
    mut frame: Vec<u8>,
    offsets: &[usize],
    replies: &mut impl Iterator<Item = super::PduReply>,
    first: &Reply,
) -> Reply {
    for &at in offsets {
        let Some(r) = replies.next() else { break };
        let mut d = Datagram::new_unchecked(&mut frame[at..]);
        d.set_address_raw(r.address);
        let n = d.data_len().min(r.data.len());
        d.data_mut()[..n].copy_from_slice(&r.data[..n]);
        d.set_wkc(r.wkc);
    }
    Reply {
        frame,
        sent: first.sent,
        received: first.received,
    }
}

/// Hands a member the reply to its frame, as the engine hands the procedure's link one.
fn hand_back(link: &Link, reply: Result<Reply, u32>) {
    let mut s = link.lock();
    if let Ok(r) = &reply {
        s.now_ns = s.now_ns.max(r.received.as_ns());
        s.last_sent_ns = r.sent.as_ns();
        s.last_received_ns = r.received.as_ns();
    }
    s.reply = Some(reply);
}

#[cfg(test)]
mod tests {
    use super::super::{Action, Engine};
    use super::*;
    use ecsync_dc::time::MasterInstant;

    type Got = Vec<Result<Vec<Vec<u8>>, MasterError>>;

    /// Three members: station s reads s registers, one per exchange (0x10, 0x11, ...), and
    /// stops at its first error. Returns what each got, per frame the datagrams' (station,
    /// register), and how many frames were sent.
    fn run(lose_frame: Option<usize>) -> (Got, Vec<Vec<(u16, u16)>>) {
        let mut engine = Engine::new(|link: Link| async move {
            link.side_by_side(
                vec![1u16, 2, 3],
                |l, station| async move {
                    let mut got = Vec::new();
                    for k in 0..station {
                        got.push(l.fprd(station, 0x10 + k, 2, "test read").await?);
                    }
                    Ok(got)
                },
                "side by side",
            )
            .await
            .unwrap()
        });
        let (mut now_ns, mut frames) = (0u64, Vec::new());
        let got = loop {
            match engine.poll(MasterInstant::from_ns(now_ns)) {
                Action::Send(f) => {
                    let mut f = f.to_vec();
                    let mut seen = Vec::new();
                    let offsets: Vec<usize> = EcatFrame::new_checked(&f[..])
                        .unwrap()
                        .datagrams()
                        .with_frame_offsets()
                        .map(|(at, d)| {
                            let d = d.unwrap();
                            seen.push((d.adp(), d.ado()));
                            at
                        })
                        .collect();
                    // The slave at station s answers with (s, register) and counts it.
                    for at in offsets {
                        let mut d = Datagram::new_unchecked(&mut f[at..]);
                        let (s, r) = (d.adp() as u8, d.ado() as u8);
                        d.data_mut().copy_from_slice(&[s, r]);
                        d.set_wkc(1);
                    }
                    frames.push(seen);
                    if lose_frame == Some(frames.len()) {
                        engine.handle_lost_after(3);
                    } else {
                        let (sent, back) = (now_ns, now_ns + 10_000);
                        engine.handle_reply(
                            &f,
                            MasterInstant::from_ns(sent),
                            MasterInstant::from_ns(back),
                        );
                    }
                    now_ns += 10_000;
                }
                Action::SendAll(_) => panic!("frames at once, not asked for"),
                Action::WaitUntil(t) => now_ns = now_ns.max(t.as_ns()),
                Action::Done(v) => break v,
            }
        };
        (got, frames)
    }

    /// Each round's frame holds the datagram of every member still reading, in the members'
    /// order; the whole takes as many frames as the longest member's exchanges, and each
    /// member gets its own replies.
    #[test]
    fn the_members_exchanges_share_frames_and_each_gets_its_replies() {
        let (got, frames) = run(None);
        assert_eq!(
            frames,
            vec![
                vec![(1, 0x10), (2, 0x10), (3, 0x10)],
                vec![(2, 0x11), (3, 0x11)],
                vec![(3, 0x12)],
            ]
        );
        let want = |s: u8| Ok((0..s).map(|k| vec![s, 0x10 + k]).collect::<Vec<_>>());
        assert_eq!(got, vec![want(1), want(2), want(3)]);
    }

    /// A lost merged frame is lost for every member in it (after the driver's sends), and
    /// the members not in it are not touched.
    #[test]
    fn a_lost_frame_is_lost_for_each_member_in_it() {
        let (got, frames) = run(Some(2));
        assert_eq!(frames.len(), 2);
        assert_eq!(got[0], Ok(vec![vec![1, 0x10]]));
        for g in &got[1..] {
            match g {
                Err(MasterError::FrameLost {
                    what: "test read",
                    attempts: 3,
                    datagrams: 1,
                    ..
                }) => {}
                other => panic!("expected the member's own frame lost, got {other:?}"),
            }
        }
    }
}
