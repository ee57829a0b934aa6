//! The AL state machine (ESC datasheet section I, "EtherCAT State Machine"; ETG.1000.6): AL
//! control requests a state, AL status and the AL status code report the outcome. Every access
//! goes through the wire crate's views, so the state encoding and the error flag live in one
//! place ([`ecsync_wire::AlState`]).

use super::Esc;
use crate::model::{AlBehaviour, AlFirmware};
use ecsync_wire::register as reg;
use ecsync_wire::{AL_STATUS_BLOCK_LEN, AlControl, AlState, AlStatus};
use ecsync_wire::{AlStatusCode, AlStatusRepr};

impl Esc {
    /// Writes the state, the error flag and the status code to AL status (0x0130-0x0135).
    pub(super) fn update_al_registers(&mut self) {
        let status = AlStatusRepr {
            state: self.al_state,
            error: self.al_error,
            id_loaded: false,
            code: self.al_code,
        };
        let regs = self.reg_bytes_mut(reg::AL_STATUS, AL_STATUS_BLOCK_LEN);
        // The slice has the block's length: the emit cannot fail.
        let _ = status.emit(&mut AlStatus::new_unchecked(regs));
    }

    /// AL status as the ESC holds it (what 0x0130-0x0135 read): the state, the error
    /// indication (0x0130 bit 4) and the AL status code (0x0134).
    pub fn al_status(&self) -> (AlState, bool, u16) {
        (self.al_state, self.al_error, u16::from(self.al_code))
    }

    /// Whether the error indication is only the master's acknowledge copied back: a device
    /// emulation ESC shows AL control as written, bit 4 included (0x11 after a write of 0x11,
    /// as the EK1100 and ET1200 terminals read in the captures), with no status code. Such a
    /// flag reports no error of the device.
    pub fn al_error_is_echo(&self) -> bool {
        self.al_error
            && matches!(self.model.al, AlBehaviour::DeviceEmulation)
            && self.al_code == AlStatusCode::NoError
    }

    /// AL control was written at `t_ps`: the master requests a state. Who answers is the
    /// model's [`AlBehaviour`]: the ESC itself at once (device emulation), or a firmware, at
    /// once or when it takes the write ([`AlFirmware::response_ns`] later, see
    /// [`Esc::al_tick`]).
    pub(super) fn al_control_written(&mut self, t_ps: u64) {
        let value = self.get_u16(reg::AL_CONTROL);
        match self.model.al {
            AlBehaviour::DeviceEmulation => self.emulate_al(value),
            AlBehaviour::Firmware(AlFirmware { response_ns: 0, .. }) => self.take_al_control(value),
            AlBehaviour::Firmware(f) => {
                self.al_pending = Some((t_ps.saturating_add(f.response_ns * 1000), value));
            }
        }
    }

    /// Whether AL control refuses a write now: its firmware has not read the last one yet
    /// (the handshake of [`AlFirmware::control_handshake`]).
    pub(super) fn al_control_locked(&self) -> bool {
        matches!(self.model.al, AlBehaviour::Firmware(f) if f.control_handshake)
            && self.al_pending.is_some()
    }

    /// The firmware takes a pending AL control write whose time has come (by `t_ps`).
    pub(super) fn al_tick(&mut self, t_ps: u64) {
        if let Some((at, value)) = self.al_pending
            && t_ps >= at
        {
            self.al_pending = None;
            self.take_al_control(value);
            // The process data watchdog follows the state (it runs in OP only).
            self.update_watchdog(t_ps);
        }
    }

    /// The firmware acts on AL control `value`.
    fn take_al_control(&mut self, value: u16) {
        let bytes = value.to_le_bytes();
        let control = AlControl::new_unchecked(&bytes[..]);
        let (requested, ack) = (control.requested(), control.error_ack());
        self.request_state(requested, ack);
    }

    /// Device emulation: AL control `value` copied to AL status, the acknowledge bit shown as
    /// the error indication, the status code left 0 (section II, 0x0120 and 0x0130): nothing is
    /// checked. A value that names no state leaves AL status as it was.
    fn emulate_al(&mut self, value: u16) {
        let bytes = value.to_le_bytes();
        let control = AlControl::new_unchecked(&bytes[..]);
        self.generation += 1;
        if let Ok(to) = control.requested() {
            let from = self.al_state;
            self.al_error = control.error_ack();
            self.al_code = AlStatusCode::NoError;
            self.al_state = to;
            if from == AlState::Op && to != AlState::Op {
                self.sync_left_op();
            }
            if matches!(to, AlState::SafeOp | AlState::Op)
                && !matches!(from, AlState::SafeOp | AlState::Op)
            {
                // The outputs and inputs as the master set the SyncManagers up, if they fit
                // the device (else none: the device has no process data to act on).
                let _ = self.check_process_data_config();
            }
            self.state_entered();
        }
        self.update_al_registers();
    }

    /// A state request: the transitions of the datasheet's state machine (figure "EtherCAT
    /// State Machine"), with the status codes of ETG.1020. `requested` is an error for a
    /// value that names no state; `ack` acknowledges the error indication.
    fn request_state(&mut self, requested: Result<AlState, ecsync_wire::WireError>, ack: bool) {
        self.generation += 1;
        let to_init = requested == Ok(AlState::Init);
        if self.al_error && !ack && !to_init {
            return; // an unacknowledged error blocks new requests
        }
        if ack || to_init {
            self.al_error = false;
            self.al_code = AlStatusCode::NoError;
        }
        match requested {
            Ok(AlState::Bootstrap) => self.fail(AlStatusCode::BootstrapNotSupported),
            Err(_) => self.fail(AlStatusCode::UnknownRequestedState),
            Ok(to) => self.transition(to),
        }
        self.update_al_registers();
    }

    /// The application raises an error by itself (a drive's synchronization error, a
    /// watchdog): the error indication with `code`, and OP left for SAFE-OP (ETG.1000.6: an
    /// error in OP takes the slave to SAFE-OP with the error flag; in a lower state it stays).
    /// It stays so until the master acknowledges it (AL control with the acknowledge bit).
    pub fn raise_al_error(&mut self, code: AlStatusCode) {
        self.generation += 1;
        // A device with CoE tells the master by an emergency too.
        let [lo, hi] = u16::from(code).to_le_bytes();
        self.send_emergency(super::mailbox::EMERGENCY_ESM_ERROR, 0x10, [lo, hi, 0, 0, 0]);
        if self.al_state == AlState::Op {
            self.al_state = AlState::SafeOp;
            self.sync_left_op();
            // Out of OP: the process data watchdog no longer runs.
            self.wd_period_ps = 0;
        }
        self.fail(code);
        self.update_al_registers();
    }

    /// Sets the error indication with its code; the state stays.
    fn fail(&mut self, code: AlStatusCode) {
        self.al_error = true;
        self.al_code = code;
    }

    /// A request of INIT, PRE-OP, SAFE-OP or OP from the current state.
    fn transition(&mut self, to: AlState) {
        use AlState::{Init, Op, PreOp, SafeOp};
        let from = self.al_state;
        let valid = from == to
            || matches!(
                (from, to),
                (Init, PreOp)
                    | (PreOp, Init)
                    | (PreOp, SafeOp)
                    | (SafeOp, PreOp)
                    | (SafeOp, Init)
                    | (SafeOp, Op)
                    | (Op, SafeOp)
                    | (Op, PreOp)
                    | (Op, Init)
            );
        if !valid {
            self.fail(AlStatusCode::InvalidStateChange);
        } else if (from, to) == (Init, PreOp) && !self.mailbox_configured() {
            // A device with a mailbox needs SM0 and SM1 set up as its SII says before PRE-OP
            // (ETG.1000.6: 0x0016 otherwise).
            self.fail(AlStatusCode::InvalidMailboxConfig);
        } else if (from, to) == (SafeOp, Op) && self.waits_for_sync0_in_vain() {
            // A drive set to DC SYNC0 (0x1C32:01 = 2) waits for its sync signals before OP; with
            // SYNC0 not activated none comes (ETG.1020: 0x002D, no sync error).
            self.fail(AlStatusCode::NoSyncError);
        } else if (from, to) == (SafeOp, Op) && self.sync1_config_invalid() {
            // Set to run on SYNC1 without a SYNC1 that fits the terminal's samples per cycle
            // (ETG.1000.6: 0x0030, invalid DC SYNC configuration).
            self.fail(AlStatusCode::InvalidDcSyncConfiguration);
        } else if (from, to) == (SafeOp, Op) && self.sync0_faster_than_it_can() {
            // SYNC0 faster than the drive's minimum cycle time (0x1C32:05): ETG.1020's 0x0036
            // (SYNC0 cycle time not supported).
            self.fail(AlStatusCode::DcSync0CycleTime);
        } else if (from, to) == (SafeOp, Op) && self.cycle_time_disagrees_with_sync0() {
            // The cycle time the master set (0x1C32:02) is not SYNC0's: the drive cannot tell
            // which to run its control on (ETG.1020's 0x0035, invalid sync cycle time; SOEM
            // #961: a master that leaves :02 at another value than the SYNC0 cycle).
            self.fail(AlStatusCode::DcInvalidSyncCycleTime);
        } else if (from, to) == (PreOp, SafeOp) {
            match self.check_process_data_config() {
                Ok(()) => self.al_state = to,
                Err(code) => self.fail(code),
            }
        } else {
            self.al_state = to;
        }
        if from == Op && self.al_state != Op {
            self.sync_left_op();
        }
        self.state_entered();
    }

    /// What the state now in AL status means for the rest of the ESC: in INIT the mailbox
    /// stops; below SAFE-OP the application has no process data.
    fn state_entered(&mut self) {
        use AlState::{Init, Op, SafeOp};
        if self.al_state == Init
            && let Some(m) = self.mbx.as_deref_mut()
        {
            m.stop();
        }
        if !matches!(self.al_state, SafeOp | Op) {
            self.output_sm = None;
            self.input_sm = None;
            self.app = None;
        }
    }

    /// Bytes of outputs and inputs: as the PDO assignment in the object dictionary lays them
    /// (the master may have mapped other PDOs in PRE-OP), else as the SII describes them.
    fn mapped_bytes(&self) -> (u16, u16) {
        match self.sdo_server() {
            Some(c) => {
                let bytes = |assign: u16| {
                    let bits: usize =
                        c.od.assigned_entries(assign)
                            .iter()
                            .map(|e| usize::from(e.2))
                            .sum();
                    bits.div_ceil(8) as u16
                };
                (bytes(0x1c12), bytes(0x1c13))
            }
            None => (
                self.device.output_bytes() as u16,
                self.device.input_bytes() as u16,
            ),
        }
    }

    /// The sync mode 0x1C32:01 (0 without a dictionary).
    fn od_sync_mode(&self) -> u32 {
        self.sdo_server().map_or(0, |c| c.od.read_u32(0x1c32, 1))
    }

    /// The drive is set to DC SYNC0 or SYNC1 and its SYNC0 runs faster than 0x1C32:05 allows
    /// (an oversampling terminal plays a sample per SYNC0: its minimum is a sample's).
    fn sync0_faster_than_it_can(&self) -> bool {
        let Some(c) = self.sdo_server() else {
            return false;
        };
        if !matches!(c.od.read_u32(0x1c32, 1), 2 | 3) {
            return false;
        }
        let minimum = c.od.read_u32(0x1c32, 5);
        self.dc
            .as_ref()
            .and_then(|d| d.sync0())
            .is_some_and(|(_, cycle)| cycle > 0 && cycle < minimum)
    }

    /// The drive runs on a DC signal (0x1C32:01 = 2 or 3), the signal runs, and 0x1C32:02
    /// (the cycle time, ns) is neither 0 (not set: the drive follows the signal) nor the
    /// period of the events its application runs on (SYNC0's cycle; in SYNC1 mode SYNC1's
    /// period, the cycle of an oversampling terminal's blocks: ETG.1020 has :02 the cycle
    /// and :0A the SYNC0 cycle).
    fn cycle_time_disagrees_with_sync0(&self) -> bool {
        let Some(c) = self.sdo_server() else {
            return false;
        };
        let mode = c.od.read_u32(0x1c32, 1);
        let cycle_time = c.od.read_u32(0x1c32, 2);
        let Some(dc) = self.dc.as_ref() else {
            return false;
        };
        let period = match mode {
            2 => dc.sync0().map(|(_, cycle)| cycle),
            3 => dc.sync1_grid().map(|(_, period)| period),
            _ => None,
        };
        cycle_time != 0 && period.is_some_and(|p| p > 0 && p != cycle_time)
    }

    /// The drive is set to DC SYNC0 or SYNC1 over CoE and its SYNC0 does not run.
    fn waits_for_sync0_in_vain(&self) -> bool {
        matches!(self.od_sync_mode(), 2 | 3) && self.dc.as_ref().is_none_or(|d| d.sync0().is_none())
    }

    /// The drive is set to DC SYNC1 (0x1C32:01 = 3) and SYNC1 does not run, or (an
    /// oversampling terminal) its period is not the terminal's samples per cycle times the
    /// SYNC0 cycle: ETG.1000.6's 0x0030, invalid DC SYNC configuration. ethercrab #368: an
    /// EL4732 set to SYNC1 = the cycle instead of SYNC0 x (n - 1) stayed out of OP.
    fn sync1_config_invalid(&self) -> bool {
        if self.od_sync_mode() != 3 {
            return false;
        }
        let Some(dc) = self.dc.as_ref() else {
            return true;
        };
        let (Some((_, c0)), Some((_, period))) = (dc.sync0(), dc.sync1_grid()) else {
            return true;
        };
        let n = u64::from(self.device.oversampling);
        n > 0 && u64::from(period) != n * u64::from(c0)
    }

    /// Whether the mailbox SyncManagers are as the device's layout has them (true without a
    /// mailbox).
    fn mailbox_configured(&self) -> bool {
        let Some(m) = self.device.mailbox else {
            return true;
        };
        let ok = |start: u16, len: u16, ecat_writes: bool| {
            self.sms
                .iter()
                .take(usize::from(self.model.sm_count))
                .any(|s| {
                    s.enabled
                        && s.mailbox
                        && s.start == start
                        && s.len == len
                        && s.ecat_writes == ecat_writes
                })
        };
        ok(m.out_start, m.out_len, true) && ok(m.in_start, m.in_len, false)
    }

    /// PRE-OP -> SAFE-OP: the process data SyncManagers must be configured as the SII describes
    /// (the application's check; a wrong length gives "invalid output/input configuration").
    fn check_process_data_config(&mut self) -> Result<(), AlStatusCode> {
        let (out_len, in_len) = self.mapped_bytes();
        let (out_start, in_start) = self.device.process_data_starts();
        let out = if out_len > 0 {
            let i = self
                .find_sm(out_start, true)
                .ok_or(AlStatusCode::InvalidOutputConfiguration)?;
            if self.sms[i].len != out_len {
                return Err(AlStatusCode::InvalidOutputConfiguration);
            }
            Some(i)
        } else {
            None
        };
        let inp = if in_len > 0 {
            let i = self
                .find_sm(in_start, false)
                .ok_or(AlStatusCode::InvalidInputConfiguration)?;
            if self.sms[i].len != in_len {
                return Err(AlStatusCode::InvalidInputConfiguration);
            }
            Some(i)
        } else {
            None
        };
        self.output_sm = out;
        self.input_sm = inp;
        self.app = self.app_layout();
        self.app_mem.drive.inputs_lost();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dg, esc};
    use ecsync_wire::{AlState, Command};

    #[test]
    fn al_state_machine() {
        let mut e = esc();
        let st = |e: &mut super::Esc| {
            let mut d = dg(Command::Brd, 0, 0x0130, &[0, 0, 0, 0, 0, 0]);
            e.process_datagram(&mut d, 0);
            (
                u16::from_le_bytes([d[10], d[11]]),
                u16::from_le_bytes([d[14], d[15]]),
            )
        };
        // INIT -> OP is invalid: error flag, code 0x0011, state stays INIT.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x08, 0]), 0);
        assert_eq!(st(&mut e), (0x0011, 0x0011));
        // A new request without acknowledge is ignored...
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x02, 0]), 0);
        assert_eq!(st(&mut e), (0x0011, 0x0011));
        // ...with acknowledge it is taken.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x12, 0]), 0);
        assert_eq!(st(&mut e), (0x0002, 0));
        assert_eq!(e.al_state(), AlState::PreOp);
        // PRE-OP -> SAFE-OP without SyncManagers: invalid output configuration.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x04, 0]), 0);
        assert_eq!(st(&mut e), (0x0012, 0x001d));
    }

    #[test]
    fn an_application_error_in_safe_op_stays_until_acknowledged() {
        let mut e = esc();
        let st = |e: &mut super::Esc| {
            let mut d = dg(Command::Brd, 0, 0x0130, &[0, 0, 0, 0, 0, 0]);
            e.process_datagram(&mut d, 0);
            (d[10], u16::from_le_bytes([d[14], d[15]]))
        };
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x02, 0]), 0);
        e.raise_al_error(ecsync_wire::AlStatusCode::from(0x001a));
        // PRE-OP stays PRE-OP (only OP falls back), with the flag and the code.
        assert_eq!(st(&mut e), (0x12, 0x001a));
        // Refused without the acknowledge, taken with it.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x02, 0]), 0);
        assert_eq!(st(&mut e), (0x12, 0x001a));
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x12, 0]), 0);
        assert_eq!(st(&mut e), (0x02, 0));
    }

    #[test]
    fn bootstrap_and_unknown_states_are_refused() {
        let mut e = esc();
        let st = |e: &mut super::Esc| {
            let mut d = dg(Command::Brd, 0, 0x0130, &[0, 0, 0, 0, 0, 0]);
            e.process_datagram(&mut d, 0);
            (d[10], d[14])
        };
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x03, 0]), 0);
        assert_eq!(
            st(&mut e),
            (0x11, 0x13),
            "INIT + error, bootstrap not supported"
        );
        // State 5 names no state: unknown requested state (acknowledging the last error).
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x15, 0]), 0);
        assert_eq!(st(&mut e), (0x11, 0x12));
        // Requesting INIT clears the error without an acknowledge.
        e.process_datagram(&mut dg(Command::Bwr, 0, 0x0120, &[0x01, 0]), 0);
        assert_eq!(st(&mut e), (0x01, 0x00));
    }

    /// AL status byte and working counter of a read of 0x0130 at `t_ps`.
    fn status(e: &mut super::Esc, t_ps: u64) -> (u8, u16) {
        let mut d = dg(Command::Brd, 0, 0x0130, &[0, 0]);
        e.process_datagram(&mut d, t_ps);
        (d[10], super::super::testing::wkc(&d))
    }

    /// The working counter of a write of AL control at `t_ps`.
    fn control(e: &mut super::Esc, value: u8, t_ps: u64) -> u16 {
        let mut d = dg(Command::Bwr, 0, 0x0120, &[value, 0]);
        e.process_datagram(&mut d, t_ps);
        super::super::testing::wkc(&d)
    }

    /// A firmware with the handshake (section II, 0x0120: AL control behaves like a mailbox
    /// while device emulation is off): a second write before the firmware has read the first
    /// is not taken and does not count; the state shows when the firmware takes the request;
    /// then AL control takes writes again.
    #[test]
    fn a_firmware_takes_al_control_after_its_response_time_and_refuses_writes_until_then() {
        use crate::model::{AlBehaviour, AlFirmware, EscModel};
        let mut model = EscModel::servo_mii();
        model.al = AlBehaviour::Firmware(AlFirmware {
            response_ns: 4_000_000,
            control_handshake: true,
        });
        let mut e = super::super::testing::esc_of(model);
        const MS: u64 = 1_000_000_000;
        assert_eq!(control(&mut e, 0x02, 0), 1, "after reset: taken");
        assert_eq!(status(&mut e, MS), (0x01, 1), "not yet acted on");
        assert_eq!(control(&mut e, 0x02, MS), 0, "refused: not read yet");
        assert_eq!(e.get_u16(0x0120), 0x0002, "AL control kept the first");
        assert_eq!(status(&mut e, 3 * MS), (0x01, 1));
        assert_eq!(status(&mut e, 4 * MS), (0x02, 1), "PRE-OP when taken");
        // Taken: the next write counts, and an invalid request shows its error in time.
        assert_eq!(control(&mut e, 0x08, 5 * MS), 1);
        assert_eq!(status(&mut e, 8 * MS), (0x02, 1));
        assert_eq!(status(&mut e, 9 * MS), (0x12, 1), "PRE-OP -> OP refused");
        // Without the handshake every write counts; the last one is acted on... after its
        // own response time from the write.
        let mut model = EscModel::servo_mii();
        model.al = AlBehaviour::Firmware(AlFirmware {
            response_ns: 4_000_000,
            control_handshake: false,
        });
        let mut e = super::super::testing::esc_of(model);
        assert_eq!(control(&mut e, 0x02, 0), 1);
        assert_eq!(control(&mut e, 0x02, MS), 1);
        assert_eq!(
            status(&mut e, 4 * MS),
            (0x01, 1),
            "the second write restarted it"
        );
        assert_eq!(status(&mut e, 5 * MS), (0x02, 1));
    }

    /// Device emulation (section II, 0x0120/0x0130): AL control copied to AL status within the
    /// frame, the acknowledge bit as the error indication, no check, code 0.
    #[test]
    fn device_emulation_copies_al_control_to_al_status() {
        use crate::model::{DcSupport, EscModel};
        let mut e = super::super::testing::esc_of(EscModel::et1200_terminal(DcSupport::Full64));
        let code = |e: &mut super::Esc| {
            let mut d = dg(Command::Brd, 0, 0x0134, &[0, 0]);
            e.process_datagram(&mut d, 0);
            u16::from_le_bytes([d[10], d[11]])
        };
        for (written, read) in [(0x11, 0x11), (0x12, 0x12), (0x02, 0x02), (0x04, 0x04)] {
            assert_eq!(control(&mut e, written, 0), 1);
            assert_eq!(status(&mut e, 0), (read, 1), "written {written:#04x}");
            assert_eq!(code(&mut e), 0);
        }
        // INIT -> OP is not refused either: nothing is checked.
        let mut e = super::super::testing::esc_of(EscModel::et1100_coupler());
        assert_eq!(control(&mut e, 0x08, 0), 1);
        assert_eq!(status(&mut e, 0), (0x08, 1));
        assert_eq!(control(&mut e, 0x08, 0), 1, "every write is taken");
    }
}
