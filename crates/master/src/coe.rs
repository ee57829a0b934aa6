//! SDO transfers over a slave's mailbox (ETG.1000.6 section 5.6.2), as SOEM's `ecx_SDOread` /
//! `ecx_SDOwrite` and ethercrab's `sdo_read` / `sdo_write` do them: the request written whole
//! into SM0's buffer, SM1's status polled until the answer is there, the answer read whole.
//!
//! Expedited transfers (up to 4 bytes) and normal uploads that fit one mailbox; an abort comes
//! back as [`MasterError::SdoAbort`] with the slave's code.

use crate::MasterError;
use crate::io::Link;
use crate::network::MailboxInfo;
use ecsync_wire::mailbox::coe::{self, COE_HEADER_LEN, CoeService, SDO_LEN};
use ecsync_wire::mailbox::{MAILBOX_HEADER_LEN, Mailbox, MailboxRepr, MailboxType};
use ecsync_wire::register as reg;

/// How long an answer may take, ns (a drive answers within milliseconds).
pub const MAILBOX_TIMEOUT_NS: u64 = 100_000_000;
/// Between two polls of SM1's status, ns.
const POLL_NS: u64 = 50_000;

/// The SDO client of one slave: its mailbox and the counter of its messages.
#[derive(Debug)]
pub struct SdoClient<'a> {
    link: &'a Link,
    station: u16,
    mbx: MailboxInfo,
    counter: u8,
    /// Emergency messages read on the way.
    emergencies: u32,
}

/// Whether mailbox message `r` is a CoE emergency.
fn is_emergency(r: &[u8]) -> bool {
    Mailbox::new_checked(r).is_ok_and(|m| {
        m.mailbox_type() == Ok(MailboxType::Coe)
            && coe::Coe::new_checked(m.payload())
                .is_ok_and(|c| c.service() == Ok(coe::CoeService::Emergency))
    })
}

impl<'a> SdoClient<'a> {
    /// The client of the slave at `station` with mailbox `mbx`.
    pub fn new(link: &'a Link, station: u16, mbx: MailboxInfo) -> Self {
        SdoClient {
            link,
            station,
            mbx,
            counter: 0,
            emergencies: 0,
        }
    }

    /// Emergency messages this client read instead of an answer (or as a stale message).
    pub fn emergencies(&self) -> u32 {
        self.emergencies
    }

    /// The client of the slave at `station` going on from the mailbox counter `counter` of
    /// the last message sent to it (a slave ignores a message with its last one's counter as
    /// a repeat: ETG.1000.4, the mailbox counter; a master keeps it per slave).
    pub fn going_on_from(link: &'a Link, station: u16, mbx: MailboxInfo, counter: u8) -> Self {
        SdoClient {
            counter,
            ..SdoClient::new(link, station, mbx)
        }
    }

    /// The counter of the last message sent.
    pub fn counter(&self) -> u8 {
        self.counter
    }

    fn next_counter(&mut self) -> u8 {
        self.counter = if self.counter >= 7 {
            1
        } else {
            self.counter + 1
        };
        self.counter
    }

    /// One mailbox exchange: `coe` (CoE header and data) out, the answer's CoE part back.
    async fn exchange(&mut self, coe: &[u8]) -> Result<Vec<u8>, MasterError> {
        let (station, m) = (self.station, self.mbx);
        let sm1_status = reg::sync_manager_address(1) + 5;
        let sm0_status = reg::sync_manager_address(0) + 5;
        // A stale answer in SM1 (of an exchange given up on) is read out first.
        let st = self
            .link
            .fprd(station, sm1_status, 1, "mailbox in status")
            .await?;
        if st[0] & 0x08 != 0 {
            let r = self
                .link
                .fprd(station, m.in_start, usize::from(m.in_len), "stale mailbox")
                .await?;
            self.emergencies += u32::from(is_emergency(&r));
        }
        let st = self
            .link
            .fprd(station, sm0_status, 1, "mailbox out status")
            .await?;
        if st[0] & 0x08 != 0 {
            return Err(MasterError::Mailbox {
                slave: station,
                what: "its mailbox out is still full",
            });
        }
        let mut msg = vec![0u8; usize::from(m.out_len)];
        if MAILBOX_HEADER_LEN + coe.len() > msg.len() {
            return Err(MasterError::Mailbox {
                slave: station,
                what: "the request is longer than its mailbox",
            });
        }
        let counter = self.next_counter();
        Mailbox::new_unchecked(&mut msg[..]).set_header(&MailboxRepr {
            length: coe.len() as u16,
            address: 0,
            channel: 0,
            priority: 0,
            mailbox_type: MailboxType::Coe,
            counter,
        });
        msg[MAILBOX_HEADER_LEN..MAILBOX_HEADER_LEN + coe.len()].copy_from_slice(coe);
        let wrote = self
            .link
            .pdu_wkc(
                ecsync_wire::Command::Fpwr,
                ecsync_wire::DatagramAddress::Configured {
                    adp: station,
                    ado: m.out_start,
                },
                msg,
                1,
                "mailbox write",
            )
            .await;
        match wrote {
            Ok(_) => {}
            // A resend after a lost reply finds the mailbox full with the first copy: the
            // message is in (a resend taken again carries the same counter, and the slave does
            // not act on it twice).
            Err(MasterError::WorkingCounter { got: 0, .. }) => {
                let st = self
                    .link
                    .fprd(station, sm0_status, 1, "mailbox out status")
                    .await?;
                if st[0] & 0x08 == 0 {
                    return Err(MasterError::Mailbox {
                        slave: station,
                        what: "it did not take the request",
                    });
                }
            }
            Err(e) => return Err(e),
        }
        let mut repeats = 0;
        let r = loop {
            self.wait_for_answer().await?;
            match self
                .link
                .fprd(station, m.in_start, usize::from(m.in_len), "mailbox read")
                .await
            {
                // An emergency the slave sent unasked (ETG.1000.6 5.6.4) is not the answer:
                // counted, and the answer awaited after it.
                Ok(r) if is_emergency(&r) => {
                    self.emergencies += 1;
                    continue;
                }
                Ok(r) => break r,
                // The answer was read and its reply lost (a resend finds the mailbox empty):
                // the repeat request puts it back (ETG.1000.4 5.6.2.3, as SOEM does).
                Err(MasterError::WorkingCounter { got: 0, .. }) if repeats < 3 => {
                    repeats += 1;
                    self.repeat_request().await?;
                }
                Err(e) => return Err(e),
            }
        };
        let msg = Mailbox::new_checked(&r[..]).map_err(|_| MasterError::Mailbox {
            slave: station,
            what: "its answer has a bad mailbox header",
        })?;
        match msg.mailbox_type() {
            Ok(MailboxType::Coe) => Ok(msg.payload().to_vec()),
            Ok(MailboxType::Error) => Err(MasterError::Mailbox {
                slave: station,
                what: "it answered with a mailbox error",
            }),
            _ => Err(MasterError::Mailbox {
                slave: station,
                what: "it answered with another protocol",
            }),
        }
    }

    /// Polls SM1's status until the answer is there.
    async fn wait_for_answer(&mut self) -> Result<(), MasterError> {
        let sm1_status = reg::sync_manager_address(1) + 5;
        let start = self.link.now().as_ns();
        loop {
            let st = self
                .link
                .fprd(self.station, sm1_status, 1, "mailbox in status")
                .await?;
            if st[0] & 0x08 != 0 {
                return Ok(());
            }
            if self.link.now().as_ns().saturating_sub(start) > MAILBOX_TIMEOUT_NS {
                return Err(MasterError::Mailbox {
                    slave: self.station,
                    what: "no answer in its mailbox within 100 ms",
                });
            }
            let t = self.link.now().as_ns() + POLL_NS;
            self.link.sleep_until(t).await;
        }
    }

    /// Toggles SM1's repeat request and waits for the slave's acknowledge.
    async fn repeat_request(&mut self) -> Result<(), MasterError> {
        let activate = reg::sync_manager_address(1) + 6;
        let v = self
            .link
            .fprd(self.station, activate, 2, "mailbox in activate")
            .await?;
        let toggled = v[0] ^ 0x02;
        self.link
            .fpwr(self.station, activate, &[toggled], "mailbox repeat request")
            .await?;
        let start = self.link.now().as_ns();
        loop {
            let v = self
                .link
                .fprd(self.station, activate + 1, 1, "mailbox repeat acknowledge")
                .await?;
            if v[0] & 0x02 == toggled & 0x02 {
                return Ok(());
            }
            if self.link.now().as_ns().saturating_sub(start) > MAILBOX_TIMEOUT_NS {
                return Err(MasterError::Mailbox {
                    slave: self.station,
                    what: "no acknowledge of the repeat request within 100 ms",
                });
            }
            let t = self.link.now().as_ns() + POLL_NS;
            self.link.sleep_until(t).await;
        }
    }

    /// The answer's SDO part, or the abort it is.
    fn sdo_answer(&self, r: &[u8], index: u16, sub: u8) -> Result<Vec<u8>, MasterError> {
        let c = coe::Coe::new_checked(r).map_err(|_| MasterError::BadReply("CoE header"))?;
        let p = c.payload();
        if p.len() >= SDO_LEN && p[0] == coe::SDO_ABORT {
            return Err(MasterError::SdoAbort {
                slave: self.station,
                index,
                subindex: sub,
                code: u32::from_le_bytes([p[4], p[5], p[6], p[7]]),
            });
        }
        if c.service() != Ok(CoeService::SdoResponse) || p.len() < SDO_LEN {
            return Err(MasterError::BadReply("SDO response"));
        }
        Ok(p.to_vec())
    }

    /// Reads `index:sub` (expedited, or normal within one mailbox).
    pub async fn upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, MasterError> {
        let mut req = vec![0u8; COE_HEADER_LEN + SDO_LEN];
        coe::emit_coe_header(&mut req, CoeService::SdoRequest, 0);
        req[2] = 0x40;
        req[3..5].copy_from_slice(&index.to_le_bytes());
        req[5] = sub;
        let r = self.exchange(&req).await?;
        let p = self.sdo_answer(&r, index, sub)?;
        let cmd = p[0];
        if cmd & 0xe0 != 0x40 {
            return Err(MasterError::BadReply("SDO upload response"));
        }
        if cmd & 0x02 != 0 {
            // Expedited: 4 - n bytes in the data.
            let n = if cmd & 0x01 != 0 {
                4 - usize::from((cmd >> 2) & 0x03)
            } else {
                4
            };
            return Ok(p[4..4 + n].to_vec());
        }
        let size = u32::from_le_bytes([p[4], p[5], p[6], p[7]]) as usize;
        let data = &p[SDO_LEN..];
        if data.len() < size {
            return Err(MasterError::Mailbox {
                slave: self.station,
                what: "the object does not fit one mailbox (segmented upload not done here)",
            });
        }
        Ok(data[..size].to_vec())
    }

    /// Writes 1 to 4 bytes to `index:sub` (expedited).
    pub async fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), MasterError> {
        let n = data.len();
        if !(1..=4).contains(&n) {
            return Err(MasterError::Config(format!(
                "an expedited SDO download takes 1 to 4 bytes, not {n}"
            )));
        }
        let mut req = vec![0u8; COE_HEADER_LEN + SDO_LEN];
        coe::emit_coe_header(&mut req, CoeService::SdoRequest, 0);
        req[2] = 0x23 | (((4 - n) as u8) << 2);
        req[3..5].copy_from_slice(&index.to_le_bytes());
        req[5] = sub;
        req[6..6 + n].copy_from_slice(data);
        let r = self.exchange(&req).await?;
        let p = self.sdo_answer(&r, index, sub)?;
        if p[0] != coe::SDO_DOWNLOAD_RESPONSE {
            return Err(MasterError::BadReply("SDO download response"));
        }
        Ok(())
    }
}
