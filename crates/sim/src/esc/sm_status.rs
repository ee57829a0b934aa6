//! The mailbox SyncManagers' status bits besides "mailbox full" (ESC datasheet section II,
//! SyncManager status 0x0805 + 8n): bit 0, interrupt write (the writing side has filled the
//! buffer; cleared when the reading side reads its first byte), bit 1, interrupt read (the
//! reading side has emptied it; cleared when the writing side writes its first byte), bit 7,
//! write buffer open (the writing side has begun writing and not finished).
//!
//! What real devices show, from the SM status polls of ../shared/captures/ (the EL3004 and
//! EK1914 in ethercrab's, the AKD and the LAN9252 in SOEM's):
//! - SM0 (the master writes, the application reads): 0x00 before the first request; 0x02
//!   after the application has taken a request (interrupt read), until the master writes the
//!   next one;
//! - SM1 (the application writes, the master reads): 0x00 before the first answer; 0x09 while
//!   an answer waits (full, interrupt write); 0x02 once the master has read it (interrupt
//!   read); what follows is the application's habit ([`AnswerBufferHabit`]): the AKD leaves
//!   0x02 until its next answer, the EK1914 takes the interrupt after some 650 us (0x00), the
//!   EL3004 takes it and opens the buffer for its next answer at once (0x80 until that answer
//!   is complete), the LAN9252 the same about 20 ms after the read (0x80 for the 20 ms before
//!   its answer of about 38 ms is complete; before its first answer, with no read before it,
//!   it shows 0x00 all along).

use super::Esc;
use ecsync_wire::register as reg;

/// SM status bit 0: interrupt write.
const INTERRUPT_WRITE: u8 = 0x01;
/// SM status bit 1: interrupt read.
const INTERRUPT_READ: u8 = 0x02;
/// SM status bit 7: write buffer open.
const WRITE_BUFFER_OPEN: u8 = 0x80;

/// What the application does with the answer buffer (SM1) after the master has read an
/// answer, as the SM1 status polls of real devices show it (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AnswerBufferHabit {
    /// Leaves the read interrupt set until it writes its next answer, which it writes at once
    /// (the buffer never seen open): the AKD.
    #[default]
    KeepsReadInterrupt,
    /// Takes the read interrupt `after_ns` after the master's read: clears it and, with
    /// `opens`, opens the buffer for its next answer (write buffer open until that answer is
    /// complete). The EL3004 opens it within 0.3 ms, the LAN9252 about 20 ms after the read,
    /// the EK1914 clears the interrupt after about 650 us without opening.
    TakesReadInterrupt {
        /// After the master's read, ns.
        after_ns: u64,
        /// Whether it opens the buffer then.
        opens: bool,
    },
}

/// The mailbox's status bits besides bit 3 and what they follow.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct MailboxStatusBits {
    habit: AnswerBufferHabit,
    /// The time of the access being processed, ps.
    now_ps: u64,
    /// The mailbox SyncManagers and their full flags as last seen.
    sms: (Option<usize>, Option<usize>),
    full: (bool, bool),
    /// When the master last emptied SM1 (until the application takes the interrupt), ps.
    read_ps: Option<u64>,
}

impl Esc {
    /// The application's habit with the answer buffer (see [`AnswerBufferHabit`]); kept over
    /// a power cycle.
    pub fn set_answer_buffer_habit(&mut self, habit: AnswerBufferHabit) {
        self.sm_status.habit = habit;
    }

    /// The application's habit with the answer buffer.
    pub fn answer_buffer_habit(&self) -> AnswerBufferHabit {
        self.sm_status.habit
    }

    fn sm_status_change(&mut self, sm: Option<usize>, set: u8, clear: u8) {
        if let Some(i) = sm {
            let at = usize::from(reg::sync_manager_address(i as u8)) + 5;
            self.regs[at] = (self.regs[at] & !clear) | set;
        }
    }

    /// Before an access at `t_ps`: the application takes the read interrupt when its time
    /// has come.
    pub(super) fn sm_status_tick(&mut self, t_ps: u64) {
        let s = &mut self.sm_status;
        s.now_ps = t_ps;
        if let AnswerBufferHabit::TakesReadInterrupt { after_ns, opens } = s.habit
            && s.read_ps.is_some_and(|r| t_ps >= r + after_ns * 1000)
        {
            s.read_ps = None;
            let set = if opens { WRITE_BUFFER_OPEN } else { 0 };
            let in_sm = s.sms.1;
            self.sm_status_change(in_sm, set, INTERRUPT_READ);
        }
    }

    /// The mailbox's state as it is now (its SyncManagers, whether each is full): the status
    /// bits follow its changes.
    pub(super) fn sm_status_follow(
        &mut self,
        out_sm: Option<usize>,
        out_full: bool,
        in_sm: Option<usize>,
        in_full: bool,
    ) {
        let s = self.sm_status;
        if (out_sm, in_sm) != s.sms {
            // A SyncManager switched on, off or moved: its buffer starts empty.
            self.sm_status_change(
                out_sm,
                0,
                INTERRUPT_WRITE | INTERRUPT_READ | WRITE_BUFFER_OPEN,
            );
            self.sm_status_change(
                in_sm,
                0,
                INTERRUPT_WRITE | INTERRUPT_READ | WRITE_BUFFER_OPEN,
            );
            self.sm_status = MailboxStatusBits {
                habit: s.habit,
                now_ps: s.now_ps,
                sms: (out_sm, in_sm),
                full: (out_full, in_full),
                ..MailboxStatusBits::default()
            };
            return;
        }
        let now = s.now_ps;
        match (s.full.0, out_full) {
            // The master's request written: interrupt write.
            (false, true) => self.sm_status_change(out_sm, INTERRUPT_WRITE, INTERRUPT_READ),
            // The application has taken it: interrupt read.
            (true, false) => self.sm_status_change(out_sm, INTERRUPT_READ, INTERRUPT_WRITE),
            _ => {}
        }
        match (s.full.1, in_full) {
            // The application's answer complete: interrupt write, the buffer closed.
            (false, true) => {
                self.sm_status.read_ps = None;
                self.sm_status_change(in_sm, INTERRUPT_WRITE, INTERRUPT_READ | WRITE_BUFFER_OPEN);
            }
            // The master has read it: interrupt read; the application's habit.
            (true, false) => {
                self.sm_status.read_ps = Some(now);
                self.sm_status_change(in_sm, INTERRUPT_READ, INTERRUPT_WRITE);
                self.sm_status_tick(now);
            }
            _ => {}
        }
        self.sm_status.full = (out_full, in_full);
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dg, wkc};
    use super::*;
    use crate::clock::CrystalParams;
    use crate::model::{DeviceInfo, EscModel};
    use ecsync_wire::Command;

    const US: u64 = 1_000_000;

    /// A drive with the standard mailbox (answers 200 us after a request) set up, in PRE-OP.
    fn drive(habit: AnswerBufferHabit) -> Esc {
        let mut e = Esc::new(
            EscModel::servo_mii(),
            DeviceInfo::servo_drive(7).with_mailbox(),
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        e.set_answer_buffer_habit(habit);
        for (ado, data) in [
            (
                0x0800,
                &[0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00][..],
            ),
            (0x0808, &[0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00]),
            (0x0120, &[0x02, 0x00]),
        ] {
            e.process_datagram(&mut dg(Command::Bwr, 0, ado, data), 0);
        }
        e
    }

    fn status(e: &mut Esc, ado: u16, t_ps: u64) -> u8 {
        let mut d = dg(Command::Brd, 0, ado, &[0]);
        e.process_datagram(&mut d, t_ps);
        d[10]
    }

    /// An SDO upload of 0x1018:01 written at `t_ps`, its answer read 300 us later.
    fn exchange(e: &mut Esc, counter: u8, t_ps: u64) {
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
            0x18,
            0x10,
            1,
        ];
        m.resize(128, 0);
        let mut w = dg(Command::Bwr, 0, 0x1000, &m);
        e.process_datagram(&mut w, t_ps);
        assert_eq!(wkc(&w), 1);
        assert_eq!(status(e, 0x0805, t_ps), 0x09, "SM0: full, interrupt write");
        assert_eq!(status(e, 0x080d, t_ps + 300 * US), 0x09, "SM1: the answer");
        assert_eq!(status(e, 0x0805, t_ps + 300 * US), 0x02, "SM0: taken");
        let mut r = dg(Command::Brd, 0, 0x1080, &[0; 128]);
        e.process_datagram(&mut r, t_ps + 300 * US);
        assert_eq!(wkc(&r), 1);
    }

    /// The AKD's habit, the default: 0x02 after the read until the next answer.
    #[test]
    fn the_read_interrupt_stays_until_the_next_answer() {
        let mut e = drive(AnswerBufferHabit::default());
        assert_eq!(status(&mut e, 0x080d, 0), 0x00, "no answer yet");
        assert_eq!(status(&mut e, 0x0805, 0), 0x00, "no request yet");
        exchange(&mut e, 1, US);
        assert_eq!(status(&mut e, 0x080d, 302 * US), 0x02);
        assert_eq!(status(&mut e, 0x080d, 10_000 * US), 0x02);
        exchange(&mut e, 2, 10_000 * US);
    }

    /// The EK1914's: the interrupt taken 650 us after the read, the buffer not opened; the
    /// EL3004's: taken and opened at once, until the next answer is complete (0x09).
    #[test]
    fn the_application_takes_the_read_interrupt_as_its_habit_says() {
        let mut e = drive(AnswerBufferHabit::TakesReadInterrupt {
            after_ns: 650_000,
            opens: false,
        });
        exchange(&mut e, 1, US);
        assert_eq!(status(&mut e, 0x080d, 950 * US), 0x02);
        assert_eq!(status(&mut e, 0x080d, 951 * US), 0x00);
        let mut e = drive(AnswerBufferHabit::TakesReadInterrupt {
            after_ns: 0,
            opens: true,
        });
        exchange(&mut e, 1, US);
        assert_eq!(status(&mut e, 0x080d, 302 * US), 0x80, "open");
        exchange(&mut e, 2, 1_000 * US);
        // Power cycled, the habit stays.
        assert_eq!(
            e.power_cycled(0).answer_buffer_habit(),
            e.answer_buffer_habit()
        );
    }
}
