//! SyncManager entries (ESC datasheet section II, registers 0x0800-0x087F; ETG.1000.4 6.7.2):
//! eight bytes per SyncManager, SyncManager `n` at `0x0800 + 8 n` (see
//! [`crate::register::sync_manager_address`]).
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0x0 | 2 | physical start address |
//! | 0x2 | 2 | length in bytes |
//! | 0x4 | 1 | control: mode (1:0), direction (3:2), ECAT event (4), AL event (5), watchdog (6) |
//! | 0x5 | 1 | status (read-only from EtherCAT) |
//! | 0x6 | 1 | activate: enable (0), repeat (1), latch on ECAT (6) / PDI (7) access |
//! | 0x7 | 1 | PDI control (read-only from EtherCAT): deactivated (0), repeat ack (1) |
//!
//! ```
//! use ecsync_wire::{SmDirection, SmMode, SyncManager, SyncManagerRepr};
//!
//! // A Kollmorgen AKD's mailbox out (master -> slave), as SOEM configures it.
//! let bytes = [0x00, 0x18, 0x00, 0x04, 0x26, 0x00, 0x01, 0x00];
//! let sm = SyncManagerRepr::parse(&SyncManager::new_checked(&bytes[..]).unwrap()).unwrap();
//! assert_eq!((sm.physical_start, sm.length_bytes), (0x1800, 1024));
//! assert_eq!(sm.control.mode, SmMode::Mailbox);
//! assert_eq!(sm.control.direction, SmDirection::Write);
//! assert!(sm.activate.enable);
//! assert_eq!(sm.to_bytes(), bytes);
//! ```

use crate::WireError;

/// Bytes of one SyncManager entry.
pub const SM_ENTRY_LEN: usize = 8;

mod field {
    use core::ops::Range;
    pub const PHYSICAL_START: Range<usize> = 0..2;
    pub const LENGTH: Range<usize> = 2..4;
    pub const CONTROL: usize = 4;
    pub const STATUS: usize = 5;
    pub const ACTIVATE: usize = 6;
    pub const PDI_CONTROL: usize = 7;
}

/// Operation mode (control bits 1:0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SmMode {
    /// Buffered (three-buffer) mode: process data; the reader always gets the newest buffer.
    #[default]
    Buffered,
    /// Mailbox (single-buffer) mode with handshake: mailbox protocols.
    Mailbox,
}

impl SmMode {
    const MASK: u8 = 0b11;

    /// Decodes control bits 1:0; 0b01 and 0b11 are reserved.
    pub const fn from_bits(bits: u8) -> Result<Self, WireError> {
        match bits & Self::MASK {
            0b00 => Ok(SmMode::Buffered),
            0b10 => Ok(SmMode::Mailbox),
            v => Err(WireError::Reserved {
                field: "SyncManager mode",
                value: v,
            }),
        }
    }

    /// The two bits, unshifted.
    pub const fn bits(self) -> u8 {
        match self {
            SmMode::Buffered => 0b00,
            SmMode::Mailbox => 0b10,
        }
    }
}

/// Direction (control bits 3:2), as the EtherCAT side sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SmDirection {
    /// EtherCAT reads, the PDI writes: inputs, or the slave's mailbox to the master.
    #[default]
    Read,
    /// EtherCAT writes, the PDI reads: outputs, or the master's mailbox to the slave.
    Write,
}

impl SmDirection {
    const SHIFT: u8 = 2;
    const MASK: u8 = 0b11;

    /// Decodes the two direction bits (already shifted down); 0b10 and 0b11 are reserved.
    pub const fn from_bits(bits: u8) -> Result<Self, WireError> {
        match bits & Self::MASK {
            0b00 => Ok(SmDirection::Read),
            0b01 => Ok(SmDirection::Write),
            v => Err(WireError::Reserved {
                field: "SyncManager direction",
                value: v,
            }),
        }
    }

    /// The two bits, unshifted.
    pub const fn bits(self) -> u8 {
        match self {
            SmDirection::Read => 0b00,
            SmDirection::Write => 0b01,
        }
    }
}

const CONTROL_ECAT_EVENT: u8 = 1 << 4;
const CONTROL_AL_EVENT: u8 = 1 << 5;
const CONTROL_WATCHDOG: u8 = 1 << 6;

/// The control register (offset 0x4), the same byte the SII's SyncManager category holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SmControl {
    /// Operation mode.
    pub mode: SmMode,
    /// Direction.
    pub direction: SmDirection,
    /// Interrupt in the ECAT event request register (0x0210).
    pub ecat_event: bool,
    /// Interrupt in the AL event request register (0x0220), for the slave's application.
    pub al_event: bool,
    /// Accesses trigger the process data watchdog.
    pub watchdog: bool,
}

impl SmControl {
    /// Decodes the register; reserved mode or direction values are an error, bit 7 (reserved)
    /// is ignored.
    pub const fn from_bits(bits: u8) -> Result<Self, WireError> {
        let mode = match SmMode::from_bits(bits) {
            Ok(m) => m,
            Err(e) => return Err(e),
        };
        let direction = match SmDirection::from_bits(bits >> SmDirection::SHIFT) {
            Ok(d) => d,
            Err(e) => return Err(e),
        };
        Ok(SmControl {
            mode,
            direction,
            ecat_event: bits & CONTROL_ECAT_EVENT != 0,
            al_event: bits & CONTROL_AL_EVENT != 0,
            watchdog: bits & CONTROL_WATCHDOG != 0,
        })
    }

    /// The register value.
    pub const fn bits(self) -> u8 {
        self.mode.bits()
            | self.direction.bits() << SmDirection::SHIFT
            | if self.ecat_event {
                CONTROL_ECAT_EVENT
            } else {
                0
            }
            | if self.al_event { CONTROL_AL_EVENT } else { 0 }
            | if self.watchdog { CONTROL_WATCHDOG } else { 0 }
    }
}

/// Buffer state of a buffered SyncManager (status bits 5:4): the buffer written last.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SmBufferState {
    /// First buffer.
    #[default]
    First,
    /// Second buffer.
    Second,
    /// Third buffer.
    Third,
    /// No buffer written yet.
    None,
}

const STATUS_INTERRUPT_WRITE: u8 = 1 << 0;
const STATUS_INTERRUPT_READ: u8 = 1 << 1;
const STATUS_MAILBOX_FULL: u8 = 1 << 3;
const STATUS_BUFFER_SHIFT: u8 = 4;
const STATUS_READ_OPEN: u8 = 1 << 6;
const STATUS_WRITE_OPEN: u8 = 1 << 7;

/// The status register (offset 0x5), read-only from EtherCAT.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SmStatus {
    /// A buffer was completely written (interrupt pending).
    pub interrupt_write: bool,
    /// A buffer was completely read (interrupt pending).
    pub interrupt_read: bool,
    /// Mailbox mode: the mailbox is full.
    pub mailbox_full: bool,
    /// Buffered mode: the buffer written last.
    pub buffer_state: SmBufferState,
    /// A read access has opened a buffer.
    pub read_buffer_open: bool,
    /// A write access has opened a buffer.
    pub write_buffer_open: bool,
}

impl SmStatus {
    /// Decodes the register (bit 2, reserved, is ignored).
    pub const fn from_bits(bits: u8) -> Self {
        SmStatus {
            interrupt_write: bits & STATUS_INTERRUPT_WRITE != 0,
            interrupt_read: bits & STATUS_INTERRUPT_READ != 0,
            mailbox_full: bits & STATUS_MAILBOX_FULL != 0,
            buffer_state: match (bits >> STATUS_BUFFER_SHIFT) & 0b11 {
                0b00 => SmBufferState::First,
                0b01 => SmBufferState::Second,
                0b10 => SmBufferState::Third,
                _ => SmBufferState::None,
            },
            read_buffer_open: bits & STATUS_READ_OPEN != 0,
            write_buffer_open: bits & STATUS_WRITE_OPEN != 0,
        }
    }

    /// The register value.
    pub const fn bits(self) -> u8 {
        let buffer: u8 = match self.buffer_state {
            SmBufferState::First => 0b00,
            SmBufferState::Second => 0b01,
            SmBufferState::Third => 0b10,
            SmBufferState::None => 0b11,
        };
        (if self.interrupt_write {
            STATUS_INTERRUPT_WRITE
        } else {
            0
        }) | if self.interrupt_read {
            STATUS_INTERRUPT_READ
        } else {
            0
        } | if self.mailbox_full {
            STATUS_MAILBOX_FULL
        } else {
            0
        } | buffer << STATUS_BUFFER_SHIFT
            | if self.read_buffer_open {
                STATUS_READ_OPEN
            } else {
                0
            }
            | if self.write_buffer_open {
                STATUS_WRITE_OPEN
            } else {
                0
            }
    }
}

const ACTIVATE_ENABLE: u8 = 1 << 0;
const ACTIVATE_REPEAT: u8 = 1 << 1;
const ACTIVATE_LATCH_ECAT: u8 = 1 << 6;
const ACTIVATE_LATCH_PDI: u8 = 1 << 7;

/// The activate register (offset 0x6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SmActivate {
    /// The SyncManager is enabled.
    pub enable: bool,
    /// Repeat request (mailbox resend).
    pub repeat: bool,
    /// DC latch event on EtherCAT accesses.
    pub latch_ecat: bool,
    /// DC latch event on PDI accesses.
    pub latch_pdi: bool,
}

impl SmActivate {
    /// Decodes the register (bits 5:2, reserved, are ignored).
    pub const fn from_bits(bits: u8) -> Self {
        SmActivate {
            enable: bits & ACTIVATE_ENABLE != 0,
            repeat: bits & ACTIVATE_REPEAT != 0,
            latch_ecat: bits & ACTIVATE_LATCH_ECAT != 0,
            latch_pdi: bits & ACTIVATE_LATCH_PDI != 0,
        }
    }

    /// The register value.
    pub const fn bits(self) -> u8 {
        (if self.enable { ACTIVATE_ENABLE } else { 0 })
            | if self.repeat { ACTIVATE_REPEAT } else { 0 }
            | if self.latch_ecat {
                ACTIVATE_LATCH_ECAT
            } else {
                0
            }
            | if self.latch_pdi {
                ACTIVATE_LATCH_PDI
            } else {
                0
            }
    }
}

const PDI_DEACTIVATE: u8 = 1 << 0;
const PDI_REPEAT_ACK: u8 = 1 << 1;

/// The PDI control register (offset 0x7), written by the slave's application.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SmPdiControl {
    /// The application has deactivated the SyncManager.
    pub deactivated: bool,
    /// Acknowledge of a repeat request.
    pub repeat_ack: bool,
}

impl SmPdiControl {
    /// Decodes the register (bits 7:2, reserved, are ignored).
    pub const fn from_bits(bits: u8) -> Self {
        SmPdiControl {
            deactivated: bits & PDI_DEACTIVATE != 0,
            repeat_ack: bits & PDI_REPEAT_ACK != 0,
        }
    }

    /// The register value.
    pub const fn bits(self) -> u8 {
        (if self.deactivated { PDI_DEACTIVATE } else { 0 })
            | if self.repeat_ack { PDI_REPEAT_ACK } else { 0 }
    }
}

/// A typed view over one SyncManager entry: `buffer` starts at the entry's first byte and holds
/// at least [`SM_ENTRY_LEN`] bytes.
#[derive(Debug, Clone, Copy)]
pub struct SyncManager<T> {
    buffer: T,
}

impl<T: AsRef<[u8]>> SyncManager<T> {
    /// Wraps a buffer without checking it; accessors panic if it is shorter than
    /// [`SM_ENTRY_LEN`]. Use [`SyncManager::new_checked`] on untrusted input.
    pub const fn new_unchecked(buffer: T) -> Self {
        SyncManager { buffer }
    }

    /// Wraps a buffer after checking it holds a whole entry.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let have = buffer.as_ref().len();
        if have < SM_ENTRY_LEN {
            return Err(WireError::Truncated {
                needed: SM_ENTRY_LEN,
                have,
            });
        }
        Ok(SyncManager { buffer })
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    fn b(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Physical start address of the buffer.
    pub fn physical_start(&self) -> u16 {
        let b = &self.b()[field::PHYSICAL_START];
        u16::from_le_bytes([b[0], b[1]])
    }

    /// Length of the buffer in bytes.
    pub fn length_bytes(&self) -> u16 {
        let b = &self.b()[field::LENGTH];
        u16::from_le_bytes([b[0], b[1]])
    }

    /// The raw control register.
    pub fn control_raw(&self) -> u8 {
        self.b()[field::CONTROL]
    }

    /// The control register; an error for a reserved mode or direction.
    pub fn control(&self) -> Result<SmControl, WireError> {
        SmControl::from_bits(self.control_raw())
    }

    /// The operation mode alone (a reserved direction does not matter here).
    pub fn mode(&self) -> Result<SmMode, WireError> {
        SmMode::from_bits(self.control_raw())
    }

    /// The direction alone (a reserved mode does not matter here).
    pub fn direction(&self) -> Result<SmDirection, WireError> {
        SmDirection::from_bits(self.control_raw() >> SmDirection::SHIFT)
    }

    /// The status register.
    pub fn status(&self) -> SmStatus {
        SmStatus::from_bits(self.b()[field::STATUS])
    }

    /// The activate register.
    pub fn activate(&self) -> SmActivate {
        SmActivate::from_bits(self.b()[field::ACTIVATE])
    }

    /// Whether the SyncManager is enabled (activate bit 0).
    pub fn enabled(&self) -> bool {
        self.b()[field::ACTIVATE] & ACTIVATE_ENABLE != 0
    }

    /// The PDI control register.
    pub fn pdi_control(&self) -> SmPdiControl {
        SmPdiControl::from_bits(self.b()[field::PDI_CONTROL])
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> SyncManager<T> {
    fn bm(&mut self) -> &mut [u8] {
        self.buffer.as_mut()
    }

    /// Sets the physical start address.
    pub fn set_physical_start(&mut self, address: u16) {
        self.bm()[field::PHYSICAL_START].copy_from_slice(&address.to_le_bytes());
    }

    /// Sets the length in bytes.
    pub fn set_length_bytes(&mut self, len: u16) {
        self.bm()[field::LENGTH].copy_from_slice(&len.to_le_bytes());
    }

    /// Sets the control register.
    pub fn set_control(&mut self, control: SmControl) {
        self.bm()[field::CONTROL] = control.bits();
    }

    /// Sets the status register.
    pub fn set_status(&mut self, status: SmStatus) {
        self.bm()[field::STATUS] = status.bits();
    }

    /// Sets the activate register.
    pub fn set_activate(&mut self, activate: SmActivate) {
        self.bm()[field::ACTIVATE] = activate.bits();
    }

    /// Sets the PDI control register.
    pub fn set_pdi_control(&mut self, pdi: SmPdiControl) {
        self.bm()[field::PDI_CONTROL] = pdi.bits();
    }
}

/// The contents of one SyncManager entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct SyncManagerRepr {
    /// Physical start address of the buffer.
    pub physical_start: u16,
    /// Length of the buffer in bytes.
    pub length_bytes: u16,
    /// Control register.
    pub control: SmControl,
    /// Status register (what a master writes here is ignored by the ESC).
    pub status: SmStatus,
    /// Activate register.
    pub activate: SmActivate,
    /// PDI control register (what a master writes here is ignored by the ESC).
    pub pdi_control: SmPdiControl,
}

impl SyncManagerRepr {
    /// Reads an entry; an error for a reserved mode or direction.
    pub fn parse<T: AsRef<[u8]>>(entry: &SyncManager<T>) -> Result<Self, WireError> {
        Ok(SyncManagerRepr {
            physical_start: entry.physical_start(),
            length_bytes: entry.length_bytes(),
            control: entry.control()?,
            status: entry.status(),
            activate: entry.activate(),
            pdi_control: entry.pdi_control(),
        })
    }

    /// Bytes [`SyncManagerRepr::emit`] writes.
    pub const fn buffer_len(&self) -> usize {
        SM_ENTRY_LEN
    }

    /// Writes the whole entry.
    pub fn emit<T: AsRef<[u8]> + AsMut<[u8]>>(&self, entry: &mut SyncManager<T>) {
        entry.set_physical_start(self.physical_start);
        entry.set_length_bytes(self.length_bytes);
        entry.set_control(self.control);
        entry.set_status(self.status);
        entry.set_activate(self.activate);
        entry.set_pdi_control(self.pdi_control);
    }

    /// The entry as the 8 bytes a master writes to `0x0800 + 8 n`.
    pub fn to_bytes(&self) -> [u8; SM_ENTRY_LEN] {
        let mut b = [0u8; SM_ENTRY_LEN];
        self.emit(&mut SyncManager::new_unchecked(&mut b[..]));
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    // FPWR 0x0800 to station 0x1002 in shared/captures/soem-sdinfo-ek1100-el1004.pcapng (frame
    // 442): the EL1004's input buffer, one byte at 0x1000, buffered, EtherCAT reads, enabled.
    const SOEM_EL1004: [u8; 8] = [0x00, 0x10, 0x01, 0x00, 0x00, 0x00, 0x01, 0x00];
    // FPWR 0x0800, 16 bytes, to the AKD in soem-sdinfo-akd.pcapng (frame 263): SM0 and SM1.
    const SOEM_AKD_MAILBOXES: [u8; 16] = [
        0x00, 0x18, 0x00, 0x04, 0x26, 0x00, 0x01, 0x00, 0x00, 0x1c, 0x00, 0x04, 0x22, 0x00, 0x01,
        0x00,
    ];

    fn parse(b: &[u8]) -> SyncManagerRepr {
        SyncManagerRepr::parse(&SyncManager::new_checked(b).unwrap()).unwrap()
    }

    #[test]
    fn parses_real_soem_entries() {
        let input = parse(&SOEM_EL1004);
        assert_eq!(
            input,
            SyncManagerRepr {
                physical_start: 0x1000,
                length_bytes: 1,
                activate: SmActivate {
                    enable: true,
                    ..SmActivate::default()
                },
                ..SyncManagerRepr::default()
            }
        );
        assert_eq!(input.to_bytes(), SOEM_EL1004);
        // 0x26 = 0b0010_0110: mailbox (10), write (01), AL event; 0x22: mailbox, read, AL event.
        let out = parse(&SOEM_AKD_MAILBOXES[..8]);
        let inp = parse(&SOEM_AKD_MAILBOXES[8..]);
        let ctl = |direction| SmControl {
            mode: SmMode::Mailbox,
            direction,
            al_event: true,
            ..SmControl::default()
        };
        assert_eq!(
            (out.physical_start, out.length_bytes, out.control),
            (0x1800, 1024, ctl(SmDirection::Write))
        );
        assert_eq!(
            (inp.physical_start, inp.length_bytes, inp.control),
            (0x1c00, 1024, ctl(SmDirection::Read))
        );
        assert_eq!(out.to_bytes(), SOEM_AKD_MAILBOXES[..8]);
        assert_eq!(inp.to_bytes(), SOEM_AKD_MAILBOXES[8..]);
    }

    #[test]
    fn control_bits_by_hand_from_the_datasheet_table() {
        // The virtual drive's output SyncManager: buffered (00), write (01 << 2), AL event
        // (bit 5), watchdog (bit 6) = 0x64; its input: buffered, read, AL event = 0x20.
        let out = SmControl {
            direction: SmDirection::Write,
            al_event: true,
            watchdog: true,
            ..SmControl::default()
        };
        assert_eq!(out.bits(), 0x64);
        assert_eq!(SmControl::from_bits(0x64), Ok(out));
        assert_eq!(
            SmControl::from_bits(0x20).unwrap().direction,
            SmDirection::Read
        );
        assert_eq!(
            SmStatus {
                mailbox_full: true,
                buffer_state: SmBufferState::None,
                ..SmStatus::default()
            }
            .bits(),
            0b0011_1000
        );
    }

    #[test]
    fn reserved_control_values_are_errors() {
        for (bits, field) in [
            (0x01, "SyncManager mode"),
            (0x03, "SyncManager mode"),
            (0x08, "SyncManager direction"),
            (0x0c, "SyncManager direction"),
        ] {
            assert!(
                matches!(SmControl::from_bits(bits), Err(WireError::Reserved { field: f, .. }) if f == field),
                "{bits:#04x}"
            );
        }
        let mut b = SOEM_EL1004;
        b[4] = 0x09; // reserved mode and direction
        let v = SyncManager::new_checked(&b[..]).unwrap();
        assert!(SyncManagerRepr::parse(&v).is_err());
        assert!(v.mode().is_err() && v.direction().is_err());
        b[4] = 0x05; // write, reserved mode: the direction alone is still known
        let v = SyncManager::new_checked(&b[..]).unwrap();
        assert_eq!(v.direction(), Ok(SmDirection::Write));
    }

    #[test]
    fn short_buffers_are_errors() {
        for n in 0..SM_ENTRY_LEN {
            assert_eq!(
                SyncManager::new_checked(&SOEM_EL1004[..n]).unwrap_err(),
                WireError::Truncated { needed: 8, have: n }
            );
        }
    }

    fn control() -> impl Strategy<Value = SmControl> {
        (any::<(bool, bool, bool, bool, bool)>()).prop_map(|(m, d, e, a, w)| SmControl {
            mode: if m { SmMode::Mailbox } else { SmMode::Buffered },
            direction: if d {
                SmDirection::Write
            } else {
                SmDirection::Read
            },
            ecat_event: e,
            al_event: a,
            watchdog: w,
        })
    }

    fn repr() -> impl Strategy<Value = SyncManagerRepr> {
        (
            any::<u16>(),
            any::<u16>(),
            control(),
            any::<u8>(),
            any::<u8>(),
            any::<u8>(),
        )
            .prop_map(|(start, len, control, st, act, pdi)| SyncManagerRepr {
                physical_start: start,
                length_bytes: len,
                control,
                status: SmStatus::from_bits(st),
                activate: SmActivate::from_bits(act),
                pdi_control: SmPdiControl::from_bits(pdi),
            })
    }

    proptest! {
        #[test]
        fn repr_round_trips(r in repr()) {
            prop_assert_eq!(parse(&r.to_bytes()), r);
        }

        #[test]
        fn any_bytes_parse_without_panic(b in proptest::collection::vec(any::<u8>(), 0..20)) {
            match SyncManager::new_checked(&b[..]) {
                Ok(v) => {
                    let _ = (v.physical_start(), v.length_bytes(), v.status(), v.enabled());
                    let _ = (v.activate(), v.pdi_control(), v.mode(), v.direction());
                    if let Ok(r) = SyncManagerRepr::parse(&v) {
                        prop_assert_eq!(parse(&r.to_bytes()), r);
                    }
                }
                Err(e) => prop_assert!(b.len() < SM_ENTRY_LEN, "{e}"),
            }
        }
    }
}
