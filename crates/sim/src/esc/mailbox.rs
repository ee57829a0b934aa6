//! The mailbox (ESC datasheet section I, "SyncManager", mailbox mode; ETG.1000.4 section 5.6):
//! two SyncManagers in mailbox mode guard one buffer each, SM0 for the master's messages, SM1
//! for the slave's answers, and the application (the CoE server of [`crate::coe`]) behind them.
//!
//! What the EtherCAT side sees, as the datasheet gives it:
//! - a write to the mailbox out buffer is taken only while it is empty; the write of its last
//!   byte makes it full (status bit 3), and the application takes the message; a write while it
//!   is full is ignored and does not count in the working counter;
//! - a read of the mailbox in buffer works only while it is full (otherwise it does not count
//!   and returns nothing); the read of its last byte empties it;
//! - the answer comes `response_ns` after the message (the application's time), read through
//!   the SM1 status polls the masters make;
//! - the repeat request: toggling SM1's activate bit 1 puts the last answer in the buffer again,
//!   acknowledged in SM1's PDI control bit 1;
//! - the mailbox counter: a message with the counter of the one before (not 0) is a repeat the
//!   master sent after a lost answer, and is not processed twice;
//! - emergency messages (ETG.1000.6 5.6.4, CoE service 1): an error the application raises
//!   (an AL error: sync error, watchdog, fatal sync error) is sent unasked as an emergency,
//!   error code 0xA000 ("EtherCAT state machine transition error" of ETG.1000.6's table of
//!   EtherCAT error codes; error register bit 4, communication error) with the AL status code
//!   in the first two of its five manufacturer bytes. It waits in a queue of
//!   [`EMERGENCY_QUEUE`] (the oldest dropped, as a slave stack's ring does) until SM1 is
//!   empty and no answer is due, and goes before nothing the master asked for.
//! - a message the application cannot take gets a mailbox error reply (type 0, ETG.1000.4
//!   table 30) where ETG's slave stack code (SSC) sends one, with SSC's code: 0x08 for a
//!   length past the mailbox (`MBX_MailboxWriteInd`), 0x02 for a protocol other than CoE
//!   (`MailboxServiceInd`), 0x04/0x05 for CoE services a slave does not serve or that do not
//!   exist (`COE_ServiceInd`), 0x08/0x06 for SDO and SDO Information lengths (`sdoserv.c`; see
//!   [`MailboxFault`]); the channel is not looked at, as SSC does not
//!   (tests/mailbox_errors.rs).

use super::Esc;
use crate::coe::{MailboxFault, SdoServer};
use crate::model::MailboxLayout;
use ecsync_wire::mailbox::{
    MAILBOX_HEADER_LEN, Mailbox, MailboxErrorCode, MailboxRepr, MailboxType, emit_mailbox_error,
};
use ecsync_wire::register as reg;

/// Emergencies an ESC keeps while SM1 is occupied.
pub const EMERGENCY_QUEUE: usize = 4;
/// CoE emergency error code of an AL state machine error (ETG.1000.6).
pub const EMERGENCY_ESM_ERROR: u16 = 0xa000;

/// The mailbox of one ESC.
#[derive(Debug, Clone)]
pub(super) struct MailboxState {
    layout: MailboxLayout,
    server: SdoServer,
    /// The SyncManagers in mailbox mode, by direction (their index), while enabled.
    out_sm: Option<usize>,
    in_sm: Option<usize>,
    out_full: bool,
    in_full: bool,
    /// The answer being prepared: when it is ready (ps) and the message.
    pending: Option<(u64, Vec<u8>)>,
    /// The last answer put in the buffer (for a repeat request).
    last: Vec<u8>,
    /// The counter of the master's last message.
    last_counter: u8,
    /// This slave's counter, 1 to 7 in turn.
    own_counter: u8,
    /// SM1's repeat request bit as last seen.
    repeat: bool,
    /// Emergency messages (whole mailbox messages) waiting for SM1.
    emergencies: std::collections::VecDeque<Vec<u8>>,
    /// Emergencies sent (put into SM1).
    emergencies_sent: u64,
}

impl MailboxState {
    pub(super) fn new(layout: MailboxLayout, mut server: SdoServer) -> Self {
        server.set_request_room(usize::from(layout.out_len).saturating_sub(MAILBOX_HEADER_LEN));
        MailboxState {
            layout,
            server,
            out_sm: None,
            in_sm: None,
            out_full: false,
            in_full: false,
            pending: None,
            last: Vec::new(),
            last_counter: 0,
            own_counter: 0,
            emergencies: std::collections::VecDeque::new(),
            emergencies_sent: 0,
            repeat: false,
        }
    }

    /// The mailbox stops (the slave goes to INIT, or the master switches SM0 or SM1 off): the
    /// counters start again, as ETG's slave stack's `MBX_StopMailboxHandler` resets
    /// `u8MbxWriteCounter` and `u8MbxReadCounter`. A new master session's first message may
    /// carry the counter the last session ended with; kept, it would be dropped as a repeat and
    /// the master's first SDO would time out.
    pub(super) fn stop(&mut self) {
        self.last_counter = 0;
        self.own_counter = 0;
        self.pending = None;
    }

    /// The CoE server (its dictionary).
    pub(super) fn server(&self) -> &SdoServer {
        &self.server
    }

    /// The CoE server, to change (the drive's own counters).
    pub(super) fn server_mut(&mut self) -> &mut SdoServer {
        &mut self.server
    }
}

impl Esc {
    /// The SyncManagers were written: which are the mailbox's, and a repeat request.
    pub(super) fn mailbox_sms_changed(&mut self) {
        let Some(m) = self.mbx.as_deref_mut() else {
            return;
        };
        let find = |ecat_writes: bool| {
            self.sms
                .iter()
                .take(usize::from(self.model.sm_count))
                .position(|s| s.enabled && s.mailbox && s.ecat_writes == ecat_writes)
        };
        let (out_sm, in_sm) = (find(true), find(false));
        // SM0 or SM1 switched off (its activate bit 0 cleared, its control byte no longer
        // mailbox mode, or moved) stops the mailbox as going to INIT does: ETG's slave stack
        // calls MBX_StopMailboxHandler then too, and its counters start again.
        if (m.out_sm.is_some() && out_sm != m.out_sm) || (m.in_sm.is_some() && in_sm != m.in_sm) {
            m.stop();
        }
        // A SyncManager switched off (or moved) forgets its buffer's state.
        if out_sm != m.out_sm {
            m.out_full = false;
        }
        if in_sm != m.in_sm {
            m.in_full = false;
            m.pending = None;
        }
        m.out_sm = out_sm;
        m.in_sm = in_sm;
        if let Some(i) = in_sm {
            let base = usize::from(reg::sync_manager_address(i as u8));
            let repeat = self.regs[base + 6] & 0x02 != 0;
            if repeat != m.repeat {
                m.repeat = repeat;
                // The last answer again, and the acknowledge in the PDI control byte.
                if !m.last.is_empty() {
                    put_in_buffer(&mut self.ram, self.sms[i], &m.last);
                    m.in_full = true;
                }
                self.regs[base + 7] = (self.regs[base + 7] & !0x02) | (u8::from(repeat) << 1);
            }
        }
        self.update_mailbox_status();
    }

    /// SM status bit 3 (mailbox full) of both mailbox SyncManagers; the other bits follow
    /// (`sm_status`).
    fn update_mailbox_status(&mut self) {
        let Some(m) = self.mbx.as_deref() else {
            return;
        };
        let (out_sm, out_full, in_sm, in_full) = (m.out_sm, m.out_full, m.in_sm, m.in_full);
        for (sm, full) in [(out_sm, out_full), (in_sm, in_full)] {
            if let Some(i) = sm {
                let at = usize::from(reg::sync_manager_address(i as u8)) + 5;
                self.regs[at] = (self.regs[at] & !0x08) | (u8::from(full) << 3);
            }
        }
        self.sm_status_follow(out_sm, out_full, in_sm, in_full);
    }

    /// The answer, once it is ready at `t_ps`, goes into the mailbox in buffer (when that is
    /// empty).
    pub(super) fn mailbox_tick(&mut self, t_ps: u64) {
        self.sm_status_tick(t_ps);
        let Some(m) = self.mbx.as_deref_mut() else {
            return;
        };
        let Some(i) = m.in_sm else {
            return;
        };
        if m.in_full {
            return;
        }
        let Some((ready, _)) = &m.pending else {
            // No answer due: an emergency, if one waits.
            if let Some(msg) = m.emergencies.pop_front() {
                put_in_buffer(&mut self.ram, self.sms[i], &msg);
                m.in_full = true;
                m.emergencies_sent += 1;
                m.last = msg;
                self.update_mailbox_status();
            }
            return;
        };
        if *ready > t_ps {
            return;
        }
        let Some((_, msg)) = m.pending.take() else {
            return;
        };
        put_in_buffer(&mut self.ram, self.sms[i], &msg);
        m.in_full = true;
        // The application has taken the message it answers.
        m.out_full = false;
        m.last = msg;
        self.update_mailbox_status();
    }

    /// What a physical access to `lo..hi` (physical addresses) does to the mailbox: `Some(false)`
    /// refuses it (no data, no count), `Some(true)` lets it through, `None`: not a mailbox
    /// buffer.
    pub(super) fn mailbox_gate(&self, lo: usize, hi: usize, write: bool) -> Option<bool> {
        let m = self.mbx.as_deref()?;
        let overlaps = |sm: Option<usize>| {
            sm.map(|i| self.sms[i]).filter(|b| {
                let (s, e) = (
                    usize::from(b.start),
                    usize::from(b.start) + usize::from(b.len),
                );
                lo < e && hi > s
            })
        };
        if overlaps(m.out_sm).is_some() {
            // The master's buffer: written while empty, never read from this side.
            return Some(write && !m.out_full);
        }
        if overlaps(m.in_sm).is_some() {
            return Some(!write && m.in_full);
        }
        None
    }

    /// After an access the gate let through: a write of the out buffer's last byte hands the
    /// message to the application, a read of the in buffer's last byte empties it.
    pub(super) fn mailbox_accessed(&mut self, hi: usize, write: bool, t_ps: u64) {
        if write {
            // A read of the drive's counters answers with them as they are now.
            self.sync_catch_up(t_ps);
        }
        let state = self.al_state;
        let Some(m) = self.mbx.as_deref_mut() else {
            return;
        };
        let sm = if write { m.out_sm } else { m.in_sm };
        let Some(i) = sm else {
            return;
        };
        let b = self.sms[i];
        let end = usize::from(b.start) + usize::from(b.len);
        if hi < end {
            return;
        }
        if !write {
            m.in_full = false;
            // The next fragment of a long SDO Information answer, the application's time
            // after the master has read the one before.
            if m.pending.is_none()
                && let Some(coe) = m.server.next_fragment()
            {
                let ready = t_ps.saturating_add(m.layout.response_ns.saturating_mul(1000));
                m.pending = Some((ready, coe_message(m, &coe)));
            }
            self.update_mailbox_status();
            return;
        }
        m.out_full = true;
        let request = self.ram[buffer_in_ram(self.ram.len(), b)].to_vec();
        let room = usize::from(m.layout.in_len).saturating_sub(MAILBOX_HEADER_LEN);
        let answer = answer(m, &request, state, room);
        match answer {
            Some(msg) => {
                let ready = t_ps.saturating_add(m.layout.response_ns.saturating_mul(1000));
                m.pending = Some((ready, msg));
            }
            // Nothing to answer: the application has taken the message.
            None => m.out_full = false,
        }
        self.update_mailbox_status();
        self.sync_settings_changed();
    }

    /// The application sends an emergency: CoE error `code`, error register `register`,
    /// manufacturer bytes `data` (queued until SM1 is free; see the module documentation).
    pub fn send_emergency(&mut self, code: u16, register: u8, data: [u8; 5]) {
        let Some(m) = self.mbx.as_deref_mut() else {
            return;
        };
        // CoE header: number 0, service 1 (emergency); then code, register, data.
        let mut coe = vec![0x00, 0x10];
        coe.extend_from_slice(&code.to_le_bytes());
        coe.push(register);
        coe.extend_from_slice(&data);
        let msg = coe_message(m, &coe);
        if m.emergencies.len() == EMERGENCY_QUEUE {
            m.emergencies.pop_front();
        }
        m.emergencies.push_back(msg);
    }

    /// Emergencies this ESC has put into SM1 so far.
    pub fn emergencies_sent(&self) -> u64 {
        self.mbx.as_deref().map_or(0, |m| m.emergencies_sent)
    }

    /// The CoE server behind the mailbox, if the device has one.
    pub fn sdo_server(&self) -> Option<&SdoServer> {
        self.mbx.as_deref().map(MailboxState::server)
    }

    /// The CoE server, to change the drive's own entries.
    pub fn sdo_server_mut(&mut self) -> Option<&mut SdoServer> {
        self.mbx.as_deref_mut().map(MailboxState::server_mut)
    }
}

/// Where SyncManager buffer `b` lies in the process RAM (of `ram_len` bytes).
fn buffer_in_ram(ram_len: usize, b: super::process_data::SmBuffer) -> std::ops::Range<usize> {
    let start = usize::from(b.start)
        .saturating_sub(super::registers::REG_SPACE)
        .min(ram_len);
    start..start + usize::from(b.len).min(ram_len - start)
}

/// Writes message `msg` into SyncManager buffer `b`, the rest of the buffer zeroed (the
/// application writes the whole buffer, which is what makes it full).
fn put_in_buffer(ram: &mut [u8], b: super::process_data::SmBuffer, msg: &[u8]) {
    let r = buffer_in_ram(ram.len(), b);
    let buf = &mut ram[r];
    buf.fill(0);
    let k = msg.len().min(buf.len());
    buf[..k].copy_from_slice(&msg[..k]);
}

/// The address in the header of the slave's answers: 0, the master's. ETG.1000.4 (table 29)
/// has the address of the source where the master is the client, and real devices answer
/// with 0 whatever their station address: the EL3004 and EK1914 (ethercrab's captures) and the
/// Kollmorgen AKD (SOEM's), all in ../shared/captures/ (tests/captures_mailbox.rs).
const ANSWER_ADDRESS: u16 = 0;

/// The whole answer message (header and data) to the master's message `request` (the buffer),
/// or `None` for one that gets no answer.
fn answer(
    m: &mut MailboxState,
    request: &[u8],
    state: ecsync_wire::AlState,
    room: usize,
) -> Option<Vec<u8>> {
    let error = |m: &mut MailboxState, code: MailboxErrorCode| {
        let mut out = vec![0u8; MAILBOX_HEADER_LEN + ecsync_wire::mailbox::MAILBOX_ERROR_LEN];
        let c = next_counter(m);
        let _ = emit_mailbox_error(&mut out, ANSWER_ADDRESS, c, code);
        Some(out)
    };
    // A length past the mailbox: 0x08, SSC's `MBX_MailboxWriteInd` ("size specified in
    // mailbox header too large"), before anything else (the counter too).
    let Ok(msg) = Mailbox::new_checked(request) else {
        return error(m, MailboxErrorCode::InvalidSize);
    };
    let counter = msg.counter();
    if counter != 0 && counter == m.last_counter {
        // The same message again (the master lost the answer and repeats): not processed a
        // second time; the repeat request gives the answer back.
        return None;
    }
    m.last_counter = counter;
    // The channel is not looked at: SSC's `MBX_MailboxWriteInd` never does (ETG.1000.4 has it
    // reserved, 0), so a real slave answers a message with another channel as any other and
    // never sends 0x03 (invalid channel).
    // A protocol the slave does not have (this one has CoE only; the error type 0 from the
    // master included): 0x02, SSC's `MailboxServiceInd` default.
    match msg.mailbox_type() {
        Ok(MailboxType::Coe) => {}
        // EoE where the device has it (crate::coe's EoE part).
        Ok(MailboxType::Eoe) => {
            return match m.server.eoe(msg.payload()) {
                Some(answer) => answer.map(|a| message(m, MailboxType::Eoe, &a)),
                None => error(m, MailboxErrorCode::UnsupportedProtocol),
            };
        }
        _ => return error(m, MailboxErrorCode::UnsupportedProtocol),
    }
    let coe = match m.server.handle(msg.payload(), state, room) {
        Ok(Some(c)) => c,
        Ok(None) => return None,
        Err(f) => {
            return error(
                m,
                match f {
                    MailboxFault::SizeTooShort => MailboxErrorCode::SizeTooShort,
                    MailboxFault::ServiceNotSupported => MailboxErrorCode::ServiceNotSupported,
                    MailboxFault::InvalidHeader => MailboxErrorCode::InvalidHeader,
                    MailboxFault::InvalidSize => MailboxErrorCode::InvalidSize,
                },
            );
        }
    };
    Some(coe_message(m, &coe))
}

/// The slave's counter for its next message, 1 to 7 in turn.
fn next_counter(m: &mut MailboxState) -> u8 {
    m.own_counter = if m.own_counter >= 7 {
        1
    } else {
        m.own_counter + 1
    };
    m.own_counter
}

/// A CoE message `coe` of the slave's, its mailbox header in front with the next counter.
fn coe_message(m: &mut MailboxState, coe: &[u8]) -> Vec<u8> {
    message(m, MailboxType::Coe, coe)
}

/// A message `data` of the slave's of protocol `mailbox_type`, its mailbox header in front
/// with the next counter.
fn message(m: &mut MailboxState, mailbox_type: MailboxType, data: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; MAILBOX_HEADER_LEN + data.len()];
    let c = next_counter(m);
    Mailbox::new_unchecked(&mut out[..]).set_header(&MailboxRepr {
        length: data.len() as u16,
        address: ANSWER_ADDRESS,
        channel: 0,
        priority: 0,
        mailbox_type,
        counter: c,
    });
    out[MAILBOX_HEADER_LEN..].copy_from_slice(data);
    out
}

#[cfg(test)]
mod tests {
    use super::super::Esc;
    use super::super::testing::{get, put};
    use crate::clock::CrystalParams;
    use crate::model::{DeviceInfo, EscModel};

    fn drive() -> Esc {
        let mut e = Esc::new(
            EscModel::servo_mii(),
            DeviceInfo::servo_drive(7).with_mailbox(),
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        e
    }

    /// A 128-byte mailbox with an SDO upload of `index:sub`, counter `counter`.
    fn upload(index: u16, sub: u8, counter: u8) -> Vec<u8> {
        let mut m = vec![10, 0, 0, 0, 0, 0x03 | (counter << 4), 0x00, 0x20, 0x40];
        m.extend_from_slice(&index.to_le_bytes());
        m.extend_from_slice(&[sub, 0, 0, 0, 0]);
        m.resize(128, 0);
        m
    }

    #[test]
    fn an_sdo_upload_goes_through_sm0_and_comes_back_on_sm1() {
        let mut e = drive();
        // A station address: the answers' header still carries 0, as real devices' do.
        assert_eq!(put(&mut e, 0x0010, &[0x01, 0x10], 0), 1);
        // PRE-OP before the mailbox is set up: 0x0016.
        assert_eq!(put(&mut e, 0x0120, &[0x02, 0], 0), 1);
        let (_, st) = get(&mut e, 0x0130, 6, 0);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x11, 0x0016));
        // SM0 and SM1 as the SII says (0x1000/128 control 0x26, 0x1080/128 control 0x22).
        let img = e.sii_image().to_vec();
        assert_eq!(
            ecsync_wire::sii::word(&img, 0x18)
                .ok()
                .zip(ecsync_wire::sii::word(&img, 0x1a).ok()),
            Some((0x1000, 0x1080))
        );
        assert_eq!(ecsync_wire::sii::word(&img, 0x1c), Ok(0x0004), "CoE");
        put(
            &mut e,
            0x0800,
            &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00],
            0,
        );
        put(
            &mut e,
            0x0808,
            &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00],
            0,
        );
        put(&mut e, 0x0120, &[0x12, 0], 0);
        assert_eq!(get(&mut e, 0x0130, 2, 0).1, [0x02, 0x00], "PRE-OP");
        // Nothing to read yet: the working counter says so.
        assert_eq!(get(&mut e, 0x1080, 128, 0).0, 0);
        // The request: taken, SM0 full; a second one while full is not.
        let t0 = 1_000_000_000;
        assert_eq!(put(&mut e, 0x1000, &upload(0x1018, 2, 1), t0), 1);
        assert_eq!(get(&mut e, 0x0805, 1, t0).1[0] & 0x08, 0x08);
        assert_eq!(put(&mut e, 0x1000, &upload(0x1018, 3, 2), t0), 0);
        // The answer 200 us later.
        assert_eq!(get(&mut e, 0x080d, 1, t0 + 100_000_000).1[0] & 0x08, 0);
        assert_eq!(get(&mut e, 0x080d, 1, t0 + 200_000_000).1[0] & 0x08, 0x08);
        assert_eq!(
            get(&mut e, 0x0805, 1, t0 + 200_000_000).1[0] & 0x08,
            0,
            "taken"
        );
        let (w, r) = get(&mut e, 0x1080, 128, t0 + 210_000_000);
        assert_eq!(w, 1);
        // Header: 10 bytes of CoE, type 3, counter 1; SDO response, expedited 4 bytes, the
        // product code 0x4024.
        assert_eq!(
            &r[..16],
            &[
                10, 0, 0, 0, 0, 0x13, 0x00, 0x30, 0x43, 0x18, 0x10, 2, 0x24, 0x40, 0, 0
            ]
        );
        assert_eq!(
            get(&mut e, 0x080d, 1, t0 + 210_000_000).1[0] & 0x08,
            0,
            "read out"
        );
        assert_eq!(get(&mut e, 0x1080, 128, t0 + 210_000_000).0, 0);
        // The repeat request: SM1's activate bit 1 toggled gives the answer again, acknowledged
        // in its PDI control bit 1.
        put(&mut e, 0x080e, &[0x03], t0 + 220_000_000);
        assert_eq!(get(&mut e, 0x080f, 1, t0 + 220_000_000).1[0] & 0x02, 0x02);
        let (w, again) = get(&mut e, 0x1080, 128, t0 + 220_000_000);
        assert_eq!((w, again), (1, r));
        // The same counter again is a repeat: not answered twice.
        assert_eq!(
            put(&mut e, 0x1000, &upload(0x1018, 2, 1), t0 + 300_000_000),
            1
        );
        assert_eq!(get(&mut e, 0x080d, 1, t0 + 900_000_000).1[0] & 0x08, 0);
        // A protocol the drive does not have (EoE): a mailbox error, service 1, code 2.
        let mut eoe = upload(0x1018, 2, 3);
        eoe[5] = 0x02 | (3 << 4);
        put(&mut e, 0x1000, &eoe, t0 + 1_000_000_000);
        let (w, r) = get(&mut e, 0x1080, 128, t0 + 1_300_000_000);
        assert_eq!((w, &r[..10]), (1, &[4, 0, 0, 0, 0, 0x20, 1, 0, 2, 0][..]));
    }
}

#[cfg(test)]
mod fragment_tests {
    use super::super::testing::{get, put};
    use crate::clock::CrystalParams;
    use crate::coe::{Access, Entry, Object, ObjectCode, data_type};
    use crate::model::{DeviceInfo, EscModel};

    #[test]
    fn a_long_od_list_is_read_fragment_by_fragment_through_sm1() {
        let mut e = super::Esc::new(
            EscModel::servo_mii(),
            DeviceInfo::servo_drive(7),
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        let od = &mut e.sdo_server_mut().unwrap().od;
        for k in 0..100u16 {
            od.insert(Object {
                index: 0x2000 + k,
                name: "Manufacturer object".into(),
                code: ObjectCode::Var,
                entries: vec![Entry {
                    subindex: 0,
                    name: "Manufacturer object".into(),
                    data_type: data_type::UINT32,
                    bits: 32,
                    access: Access::ReadOnly,
                    value: vec![0; 4],
                    pdo_mapping: 0,
                }],
            });
        }
        let objects = e.sdo_server().unwrap().od.objects().len();
        put(
            &mut e,
            0x0800,
            &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00],
            0,
        );
        put(
            &mut e,
            0x0808,
            &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00],
            0,
        );
        put(&mut e, 0x0120, &[0x02, 0], 0);
        // Get OD list, all objects (list type 1), counter 1.
        let mut m = vec![8, 0, 0, 0, 0, 0x13, 0x00, 0x80, 0x01, 0, 0, 0, 0x01, 0x00];
        m.resize(128, 0);
        let t0 = 1_000_000_000;
        assert_eq!(put(&mut e, 0x1000, &m, t0), 1);
        let mut indices = 0;
        let mut t = t0;
        let mut counters = Vec::new();
        loop {
            // Each fragment 200 us after the request or after the master read the one before.
            assert_eq!(get(&mut e, 0x080d, 1, t + 199_000_000).1[0] & 0x08, 0);
            t += 200_000_000;
            assert_eq!(get(&mut e, 0x080d, 1, t).1[0] & 0x08, 0x08);
            let (w, r) = get(&mut e, 0x1080, 128, t);
            assert_eq!(w, 1);
            let len = usize::from(u16::from_le_bytes([r[0], r[1]]));
            counters.push(r[5] >> 4);
            assert_eq!(r[5] & 0x0f, 3, "CoE");
            let left = u16::from_le_bytes([r[10], r[11]]);
            assert_eq!(r[8], 0x02 | if left > 0 { 0x80 } else { 0 });
            indices += (len - 6) / 2;
            if left == 0 {
                break;
            }
        }
        // The list type and every object; the slave's counter goes on with each message.
        assert_eq!(indices, 1 + objects);
        assert_eq!(counters, [1, 2, 3]);
        // Nothing more after the last one.
        assert_eq!(get(&mut e, 0x1080, 128, t + 10_000_000_000).0, 0);
    }
}

#[cfg(test)]
mod sync_mode_tests {
    use super::super::testing::{dg, put, read};
    use crate::clock::CrystalParams;
    use crate::model::{DeviceInfo, EscModel};
    use ecsync_wire::Command;

    /// A drive in SAFE-OP after 0x1C32:01 = `mode` over CoE, with or without SYNC0 started.
    fn safe_op(mode: u16, sync0: bool) -> super::Esc {
        let mut e = super::Esc::new(
            EscModel::servo_mii(),
            DeviceInfo::servo_drive(7),
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        put(
            &mut e,
            0x0800,
            &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00],
            0,
        );
        put(
            &mut e,
            0x0808,
            &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00],
            0,
        );
        put(&mut e, 0x0120, &[0x02, 0], 0);
        // The SDO download of the sync mode, its answer read 1 ms later.
        let mut m = vec![10, 0, 0, 0, 0, 0x13, 0x00, 0x20, 0x2b, 0x32, 0x1c, 0x01];
        m.extend_from_slice(&mode.to_le_bytes());
        m.resize(128, 0);
        put(&mut e, 0x1000, &m, 1_000_000);
        let mut d = dg(Command::Brd, 0, 0x1080, &[0; 128]);
        e.process_datagram(&mut d, 1_000_000_000);
        assert_eq!(d[10 + 8], 0x60, "download answered");
        put(
            &mut e,
            0x0810,
            &[0x00, 0x11, 16, 0, 0x64, 0, 1, 0],
            2_000_000_000,
        );
        put(
            &mut e,
            0x0818,
            &[0x80, 0x11, 18, 0, 0x20, 0, 1, 0],
            2_000_000_000,
        );
        if sync0 {
            put(&mut e, 0x09a0, &1_000_000u32.to_le_bytes(), 2_000_000_000);
            put(&mut e, 0x0990, &10_000_000u64.to_le_bytes(), 2_000_000_000);
            put(&mut e, 0x0981, &[0x03], 2_000_000_000);
        }
        put(&mut e, 0x0120, &[0x04, 0], 2_000_000_000);
        assert_eq!(read(&mut e, 0x0130, 2, 2_000_000_000)[0], 0x04, "SAFE-OP");
        e
    }

    #[test]
    fn a_drive_in_dc_mode_without_sync0_refuses_op_with_0x002d() {
        let mut e = safe_op(2, false);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        let st = read(&mut e, 0x0130, 6, 3_000_000_000);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x002d));
        // With SYNC0 running it goes to OP; in free run it does without.
        let mut e = safe_op(2, true);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        assert_eq!(read(&mut e, 0x0130, 2, 3_000_000_000)[0], 0x08);
        let mut e = safe_op(0, false);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        assert_eq!(read(&mut e, 0x0130, 2, 3_000_000_000)[0], 0x08);
    }

    /// |0x092C| past the drive's PLL limit: 0x0032 with the next outputs, OP left.
    #[test]
    fn past_its_pll_limit_the_drive_leaves_op_with_0x0032() {
        let mut e = safe_op(2, true);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        e.set_pll_error_limit_ns(1_000);
        let ms = 1_000_000_000u64;
        for k in 0..3 {
            put(&mut e, 0x1100, &[0u8; 16], 3_500_000_000 + k * ms);
        }
        assert_eq!(
            read(&mut e, 0x0130, 2, 6_000_000_000)[0],
            0x08,
            "locked: OP"
        );
        // The reference's time 5 us ahead: the filtered difference follows over the writes.
        let now = e.dc().unwrap().system_time_ns(6_000_000_000);
        for k in 0..200u64 {
            let t = 6_000_000_000 + k * 10_000_000;
            let sys = now + 5_000 + k * 10_000;
            put(&mut e, 0x0910, &sys.to_le_bytes()[..4], t);
            put(&mut e, 0x1100, &[0u8; 16], t);
        }
        let st = read(&mut e, 0x0130, 6, 9_000_000_000);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x0032));
    }

    /// 0x1C32:02 set (in PRE-OP) to 500 us while SYNC0 runs every 1 ms: OP refused with 0x0035;
    /// at 0 (not set) the drive follows SYNC0 and goes to OP.
    #[test]
    fn a_cycle_time_other_than_sync0_s_refuses_op_with_0x0035() {
        use ecsync_wire::AlState;
        for (cycle_time, status, code) in [(500_000u32, 0x14, 0x0035), (0, 0x08, 0)] {
            let mut e = safe_op(2, true);
            e.sdo_server_mut()
                .unwrap()
                .od
                .write(0x1c32, 2, &cycle_time.to_le_bytes(), AlState::PreOp)
                .unwrap();
            put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
            let st = read(&mut e, 0x0130, 6, 3_000_000_000);
            assert_eq!(
                (st[0], u16::from_le_bytes([st[4], st[5]])),
                (status, code),
                "0x1C32:02 = {cycle_time}"
            );
        }
    }

    /// SYNC0 every 25 us, under the drive's minimum cycle time (0x1C32:05, 31.25 us): OP
    /// refused with 0x0036.
    #[test]
    fn sync0_faster_than_the_minimum_cycle_time_refuses_op_with_0x0036() {
        let mut e = safe_op(2, true);
        assert_eq!(
            e.sdo_server().unwrap().od.read_u32(0x1c32, 5),
            31_250,
            "the drive's minimum"
        );
        put(&mut e, 0x0981, &[0x00], 2_500_000_000);
        put(&mut e, 0x09a0, &25_000u32.to_le_bytes(), 2_500_000_000);
        put(&mut e, 0x0981, &[0x03], 2_500_000_000);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        let st = read(&mut e, 0x0130, 6, 3_000_000_000);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x0036));
    }

    /// An SDO upload of `index:sub` at `t_ps`, its answer read 1 ms later: the data bytes of
    /// an expedited answer.
    fn upload(e: &mut super::Esc, index: u16, sub: u8, counter: u8, t_ps: u64) -> Vec<u8> {
        let [lo, hi] = index.to_le_bytes();
        let mut m = vec![
            10,
            0,
            0,
            0,
            0,
            0x03 | (counter << 4),
            0x00,
            0x20,
            0x40,
            lo,
            hi,
            sub,
        ];
        m.resize(128, 0);
        put(e, 0x1000, &m, t_ps);
        let mut d = dg(Command::Brd, 0, 0x1080, &[0; 128]);
        e.process_datagram(&mut d, t_ps + 1_000_000_000);
        assert_eq!(
            d[10 + 8] & 0xe0,
            0x40,
            "upload answered: {:02x?}",
            &d[10..26]
        );
        d[10 + 12..10 + 16].to_vec()
    }

    /// Outputs written by hand against SYNC0 at 10 ms + k ms (shift 0 here): on time, late,
    /// none; 0x1C32:0B read over CoE counts the pulses without new outputs, worked out by hand.
    #[test]
    fn sm_events_missed_counts_sync0_pulses_without_new_outputs() {
        let mut e = safe_op(2, true);
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        assert_eq!(read(&mut e, 0x0130, 2, 3_000_000_000)[0], 0x08, "OP");
        assert!(e.runs_on_sync0());
        // The DC system time is the local time here (no offset written): pulses at 10 ms +
        // k ms of local time, local time = real time for the default crystal.
        let local = |t_ps: u64| e.dc().unwrap().system_time_split(t_ps).0;
        // 20 ms, ps (within the process data watchdog's 100 ms after OP at 3 ms).
        let t0 = 20_000_000_000u64;
        let base = local(t0);
        let pulse_k = (base - 10_000_000) / 1_000_000 + 1; // the first pulse after t0
        let pulse_ns = |k: u64| 10_000_000 + k * 1_000_000;
        // Real time (ps) at which the frame end is `before_ns` before pulse k.
        let at = |k: u64, before_ns: i64| {
            t0 + ((pulse_ns(k) as i64 - before_ns - base as i64) * 1000) as u64
        };
        let write = |e: &mut super::Esc, t_ps: u64| put(e, 0x1100, &[0u8; 16], t_ps);
        let mut k = pulse_k + 1;
        for _ in 0..5 {
            write(&mut e, at(k, 100_000));
            k += 1;
        }
        assert_eq!(e.sm_events_missed(), 0);
        // Late (20 us after its pulse), then on time: one missed.
        write(&mut e, at(k, -20_000));
        k += 1;
        write(&mut e, at(k, 100_000));
        k += 1;
        assert_eq!(e.sm_events_missed(), 1);
        // Two cycles without outputs: two missed.
        k += 2;
        write(&mut e, at(k, 100_000));
        assert_eq!(e.sm_events_missed(), 3);
        let v = upload(&mut e, 0x1c32, 0x0b, 2, at(k, 50_000));
        assert_eq!(u16::from_le_bytes([v[0], v[1]]), 3);
        // 0x002C: SYNC0 switched off under a drive running on it in OP.
        put(&mut e, 0x0981, &[0x00], at(k + 2, 0));
        let st = read(&mut e, 0x0130, 6, at(k + 2, 0));
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x002c));
    }

    /// Past 0x10F1:02 (written over CoE) the drive leaves OP with 0x001A.
    #[test]
    fn past_the_sync_error_limit_the_drive_leaves_op_with_0x001a() {
        let mut e = safe_op(2, true);
        // 0x10F1:02 = 4 (SSC's default), an expedited download of 2 bytes.
        let mut m = vec![
            10, 0, 0, 0, 0, 0x23, 0x00, 0x20, 0x2b, 0xf1, 0x10, 0x02, 4, 0,
        ];
        m.resize(128, 0);
        put(&mut e, 0x1000, &m, 2_500_000_000);
        let mut d = dg(Command::Brd, 0, 0x1080, &[0; 128]);
        e.process_datagram(&mut d, 2_800_000_000);
        assert_eq!(d[10 + 8], 0x60, "download answered");
        put(&mut e, 0x0120, &[0x08, 0], 3_000_000_000);
        let ms = 1_000_000_000u64; // 1 ms, ps
        let t0 = 3_000_000_000u64 + ms / 2;
        let write = |e: &mut super::Esc, t_ps: u64| put(e, 0x1100, &[0u8; 16], t_ps);
        // Frames every ms (SYNC0 from 10 ms on), one cycle left out: 3 up, 1 down per SM
        // event: 2.
        for k in 0..10 {
            write(&mut e, t0 + k * ms);
        }
        write(&mut e, t0 + 11 * ms);
        assert_eq!(read(&mut e, 0x0130, 2, t0 + 11 * ms)[0], 0x08, "still OP");
        // Another one soon after: 2 + 3 > 4.
        write(&mut e, t0 + 13 * ms);
        let st = read(&mut e, 0x0130, 6, t0 + 13 * ms);
        assert_eq!((st[0], u16::from_le_bytes([st[4], st[5]])), (0x14, 0x001a));
        assert_eq!(e.sm_events_missed(), 2);
        // And an emergency in SM1, unasked: CoE (type 3), service 1, error code 0xA000,
        // error register 0x10, the AL status code in the manufacturer bytes.
        let full = read(&mut e, 0x080d, 1, t0 + 14 * ms)[0] & 0x08 != 0;
        assert!(full, "SM1 holds the emergency");
        let m = read(&mut e, 0x1080, 128, t0 + 14 * ms);
        assert_eq!((m[0], m[5] & 0x0f), (10, 3), "length 10, CoE: {m:02x?}");
        assert_eq!(
            &m[6..16],
            &[0x00, 0x10, 0x00, 0xa0, 0x10, 0x1a, 0x00, 0x00, 0x00, 0x00]
        );
        assert_eq!(e.emergencies_sent(), 1);
    }
}
