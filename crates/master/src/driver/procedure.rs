//! The bring-up driver: an `async` procedure run over a transport, its frames sent (back to
//! back where asked), their replies matched, lost ones sent again.

use super::*;
use crate::io::{Action, Engine, Event};
use crate::transport::Transport;

/// How a procedure's frames are waited for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProcedureConfig {
    /// How long to wait for a reply, ns.
    pub reply_timeout_ns: u64,
    /// How often a lost frame is sent again before the procedure hears of the loss (the first
    /// frames on a real network meet cold caches and page faults on both ends).
    pub retries: u32,
}

impl ProcedureConfig {
    /// How long to wait for a reply.
    pub fn reply_timeout(&self) -> MasterDuration {
        MasterDuration::from_ns(self.reply_timeout_ns)
    }
}

impl Default for ProcedureConfig {
    fn default() -> Self {
        ProcedureConfig {
            reply_timeout_ns: 20_000_000,
            retries: 3,
        }
    }
}

/// One exchange of a procedure, for observers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProcedureExchange {
    /// Send timestamp of the last attempt.
    pub sent: MasterInstant,
    /// When its reply came (`None`: lost every time).
    pub received: Option<MasterInstant>,
    /// Sends, the first included.
    pub attempts: u32,
}

/// Runs a sans-IO procedure (the DC bring-up, say) to completion over `tr`. `observe` sees the
/// transport after every exchange, with the events the procedure reported.
pub fn run_procedure<T: 'static, Tr: Transport>(
    tr: &mut Tr,
    engine: &mut Engine<T>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
    mut observe: impl FnMut(&mut Tr, &ProcedureExchange, &[Event]),
) -> Result<T, Tr::Error> {
    let mut buf = vec![0u8; 2048];
    engine.send_back_to_back();
    loop {
        let now = tr.now();
        let frame = match engine.poll(now) {
            Action::Done(v) => return Ok(v),
            Action::WaitUntil(t) => {
                tr.sleep_until(t);
                continue;
            }
            Action::Send(f) => f.to_vec(),
            Action::SendAll(frames) => {
                let frames = frames.to_vec();
                let done = exchange_all(tr, &frames, &mut buf, cfg, stats)?;
                let exchanges: Vec<ProcedureExchange> = done
                    .iter()
                    .map(|(sent, r, attempts)| ProcedureExchange {
                        sent: *sent,
                        received: r.as_ref().ok().map(|r| r.received),
                        attempts: *attempts,
                    })
                    .collect();
                engine.handle_replies(done.into_iter().map(|(_, r, _)| r).collect());
                let events = engine.take_events();
                for (k, ex) in exchanges.iter().enumerate() {
                    observe(tr, ex, if k == 0 { &events } else { &[] });
                }
                continue;
            }
        };
        let (got, attempts, sent) =
            exchange_tries(tr, &frame, &mut buf, cfg, stats, cfg.retries + 1)?;
        match got {
            Some(r) => engine.handle_reply(&buf[..r.received.len], r.sent, r.received.received),
            None => engine.handle_lost_after(attempts),
        }
        let events = engine.take_events();
        observe(
            tr,
            &ProcedureExchange {
                sent,
                received: got.map(|r| r.received.received),
                attempts,
            },
            &events,
        );
    }
}

/// Sends `frame` up to `tries` times, each after the last one was lost: its reply (`None`: lost
/// every time), the sends made, and the last send's timestamp (after a loss, the time it was
/// given up).
pub(super) fn exchange_tries<Tr: Transport>(
    tr: &mut Tr,
    frame: &[u8],
    buf: &mut Vec<u8>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
    tries: u32,
) -> Result<(Option<Reply>, u32, MasterInstant), Tr::Error> {
    let (mut sends, mut sent) = (0, MasterInstant::default());
    for _ in 0..tries {
        sends += 1;
        match exchange(tr, frame, buf, cfg.reply_timeout(), stats)? {
            Some(r) => return Ok((Some(r), sends, r.sent)),
            None => sent = tr.now(),
        }
    }
    Ok((None, sends, sent))
}

/// Sends `frames` back to back and waits for their replies until `cfg.reply_timeout_ns` after
/// the last send; a frame whose reply did not come is sent again alone, up to `cfg.retries`
/// times. Per frame, in order: its last send timestamp, its reply (`Err(sends)`: lost after
/// that many), its sends. Replies are matched to the earliest unanswered frame they answer (a
/// line returns frames in the order sent).
#[allow(clippy::type_complexity)]
pub(super) fn exchange_all<Tr: Transport>(
    tr: &mut Tr,
    frames: &[Vec<u8>],
    buf: &mut Vec<u8>,
    cfg: ProcedureConfig,
    stats: &mut ExchangeStats,
) -> Result<Vec<(MasterInstant, Result<crate::io::Reply, u32>, u32)>, Tr::Error> {
    let mut sent = Vec::with_capacity(frames.len());
    for f in frames {
        let at = tr.send_time(f.len());
        sent.push(tr.send(f, at)?);
        stats.sent += 1;
    }
    let mut got: Vec<Option<crate::io::Reply>> = vec![None; frames.len()];
    let mut pending = frames.len();
    let deadline = sent
        .last()
        .copied()
        .unwrap_or_default()
        .saturating_add(cfg.reply_timeout());
    while pending > 0 {
        let Some(r) = tr.recv(buf, deadline)? else {
            break;
        };
        let k = (!r.truncated)
            .then(|| {
                (0..frames.len()).find(|&k| got[k].is_none() && answers(&frames[k], &buf[..r.len]))
            })
            .flatten();
        match k {
            Some(k) => {
                got[k] = Some(crate::io::Reply {
                    frame: buf[..r.len].to_vec(),
                    sent: sent[k],
                    received: r.received,
                });
                stats.replies += 1;
                pending -= 1;
            }
            None => {
                stats.stale += 1;
                stats.truncated += u64::from(r.truncated);
            }
        }
    }
    let mut out = Vec::with_capacity(frames.len());
    for (k, g) in got.into_iter().enumerate() {
        if let Some(r) = g {
            out.push((sent[k], Ok(r), 1));
            continue;
        }
        stats.lost += 1;
        let (again, tries, last) = exchange_tries(tr, &frames[k], buf, cfg, stats, cfg.retries)?;
        let reply = again.map(|r| crate::io::Reply {
            frame: buf[..r.received.len].to_vec(),
            sent: r.sent,
            received: r.received.received,
        });
        let sent_at = if tries == 0 { sent[k] } else { last };
        out.push((sent_at, reply.ok_or(1 + tries), 1 + tries));
    }
    Ok(out)
}
