//! ESC register addresses and bit fields (ESC datasheet section II, "Register Description").
//! Names follow the datasheet; sizes are in the doc comments.

/// Type (u8).
pub const TYPE: u16 = 0x0000;
/// Revision (u8).
pub const REVISION: u16 = 0x0001;
/// Build (u16).
pub const BUILD: u16 = 0x0002;
/// FMMUs supported (u8).
pub const FMMU_COUNT: u16 = 0x0004;
/// SyncManagers supported (u8).
pub const SM_COUNT: u16 = 0x0005;
/// RAM size in KiB (u8).
pub const RAM_SIZE: u16 = 0x0006;
/// Port descriptor (u8): 2 bits per port, 0 not implemented, 1 not configured, 2 EBUS, 3 MII.
pub const PORT_DESCRIPTOR: u16 = 0x0007;
/// ESC features supported (u16), see [`features`].
pub const FEATURES: u16 = 0x0008;
/// Configured station address (u16).
pub const STATION_ADDRESS: u16 = 0x0010;
/// Configured station alias (u16), loaded from SII word 4.
pub const STATION_ALIAS: u16 = 0x0012;
/// ESC DL control (u32): forwarding rule and loop control per port.
pub const DL_CONTROL: u16 = 0x0100;
/// ESC DL status (u16), see [`dl_status`].
pub const DL_STATUS: u16 = 0x0110;
/// AL control (u16).
pub const AL_CONTROL: u16 = 0x0120;
/// AL status (u16).
pub const AL_STATUS: u16 = 0x0130;
/// AL status code (u16).
pub const AL_STATUS_CODE: u16 = 0x0134;
/// PDI control (u8).
pub const PDI_CONTROL: u16 = 0x0140;
/// RX error counters, 2 bytes per port (u16 x 4).
pub const RX_ERROR_COUNTER: u16 = 0x0300;
/// Lost link counters, 1 byte per port.
pub const LOST_LINK_COUNTER: u16 = 0x0310;
/// SII EEPROM configuration (u8).
pub const SII_CONFIG: u16 = 0x0500;
/// SII EEPROM PDI access state (u8).
pub const SII_PDI_ACCESS: u16 = 0x0501;
/// SII EEPROM control/status (u16), see [`sii_control`].
pub const SII_CONTROL: u16 = 0x0502;
/// SII EEPROM word address (u32).
pub const SII_ADDRESS: u16 = 0x0504;
/// SII EEPROM data (4 or 8 bytes read, 2 bytes written).
pub const SII_DATA: u16 = 0x0508;
/// First FMMU; each FMMU occupies [`FMMU_LEN`] bytes (layout: [`crate::fmmu`]).
pub const FMMU_BASE: u16 = 0x0600;
/// Bytes per FMMU.
pub const FMMU_LEN: u16 = crate::fmmu::FMMU_ENTRY_LEN as u16;
/// FMMUs the register map has room for (0x0600-0x06FF).
pub const MAX_FMMUS: u8 = 16;
/// First SyncManager; each occupies [`SM_LEN`] bytes (layout: [`crate::sync_manager`]).
pub const SM_BASE: u16 = 0x0800;
/// Bytes per SyncManager.
pub const SM_LEN: u16 = crate::sync_manager::SM_ENTRY_LEN as u16;
/// SyncManagers the register map has room for (0x0800-0x087F).
pub const MAX_SYNC_MANAGERS: u8 = 16;

/// Address of FMMU `n`'s entry (`0x0600 + 16 n`); `n` is taken modulo [`MAX_FMMUS`], as the
/// register map holds no more.
pub const fn fmmu_address(n: u8) -> u16 {
    FMMU_BASE + (n % MAX_FMMUS) as u16 * FMMU_LEN
}

/// Address of SyncManager `n`'s entry (`0x0800 + 8 n`); `n` is taken modulo
/// [`MAX_SYNC_MANAGERS`].
pub const fn sync_manager_address(n: u8) -> u16 {
    SM_BASE + (n % MAX_SYNC_MANAGERS) as u16 * SM_LEN
}
/// Receive time port 0 (u32). A write to this register latches the receive times on all ports.
pub const DC_RECEIVE_TIME_PORT0: u16 = 0x0900;
/// Receive time port 1 (u32).
pub const DC_RECEIVE_TIME_PORT1: u16 = 0x0904;
/// Receive time port 2 (u32).
pub const DC_RECEIVE_TIME_PORT2: u16 = 0x0908;
/// Receive time port 3 (u32).
pub const DC_RECEIVE_TIME_PORT3: u16 = 0x090c;
/// System time (u64 read; u32 or u64 write triggers the time control loop).
pub const DC_SYSTEM_TIME: u16 = 0x0910;
/// Receive time of the EtherCAT processing unit (u64), local time.
pub const DC_RECEIVE_TIME_PU: u16 = 0x0918;
/// System time offset (u64).
pub const DC_SYSTEM_TIME_OFFSET: u16 = 0x0920;
/// System time delay (u32).
pub const DC_SYSTEM_TIME_DELAY: u16 = 0x0928;
/// System time difference (u32, sign-magnitude).
pub const DC_SYSTEM_TIME_DIFF: u16 = 0x092c;
/// Speed counter start (u16).
pub const DC_SPEED_COUNTER_START: u16 = 0x0930;
/// Speed counter diff (i16).
pub const DC_SPEED_COUNTER_DIFF: u16 = 0x0932;
/// System time difference filter depth (u8).
pub const DC_TIME_DIFF_FILTER_DEPTH: u16 = 0x0934;
/// Speed counter filter depth (u8).
pub const DC_SPEED_COUNTER_FILTER_DEPTH: u16 = 0x0935;
/// Cyclic unit control (u8).
pub const DC_CYCLIC_UNIT_CONTROL: u16 = 0x0980;
/// Activation (u8): bit 0 cyclic operation, bit 1 SYNC0, bit 2 SYNC1.
pub const DC_ACTIVATION: u16 = 0x0981;
/// Pulse length of SYNC signals in units of 10 ns (u16).
pub const DC_PULSE_LENGTH: u16 = 0x0982;
/// Activation status (u8).
pub const DC_ACTIVATION_STATUS: u16 = 0x0984;
/// SYNC0 status (u8).
pub const DC_SYNC0_STATUS: u16 = 0x098e;
/// SYNC1 status (u8).
pub const DC_SYNC1_STATUS: u16 = 0x098f;
/// Start time cyclic operation (u64 write) / next SYNC0 pulse (u64 read).
pub const DC_START_TIME: u16 = 0x0990;
/// Next SYNC1 pulse (u64).
pub const DC_NEXT_SYNC1: u16 = 0x0998;
/// SYNC0 cycle time (u32, ns).
pub const DC_SYNC0_CYCLE: u16 = 0x09a0;
/// SYNC1 cycle time (u32, ns).
pub const DC_SYNC1_CYCLE: u16 = 0x09a4;
/// Start of process data RAM.
pub const PROCESS_RAM: u16 = 0x1000;

/// Bits of [`FEATURES`] (0x0008).
pub mod features {
    /// FMMU operation is byte oriented (0 = bit oriented, as on the ET1100 and ET1200).
    pub const FMMU_BYTE_ORIENTED: u16 = 1 << 0;
    /// Distributed clocks available.
    pub const DC: u16 = 1 << 2;
    /// DC system time is 64 bits wide (0 = 32 bits).
    pub const DC_64BIT: u16 = 1 << 3;
    /// Low jitter EBUS.
    pub const LOW_JITTER_EBUS: u16 = 1 << 4;
    /// Enhanced link detection on EBUS.
    pub const ENHANCED_LINK_EBUS: u16 = 1 << 5;
    /// Enhanced link detection on MII.
    pub const ENHANCED_LINK_MII: u16 = 1 << 6;
    /// Separate handling of FCS errors.
    pub const SEPARATE_FCS: u16 = 1 << 7;
    /// Enhanced DC SYNC activation.
    pub const ENHANCED_DC_SYNC: u16 = 1 << 8;
    /// LRW not supported.
    pub const NO_LRW: u16 = 1 << 9;
    /// BRW, APRW and FPRW not supported.
    pub const NO_READ_WRITE: u16 = 1 << 10;
}

/// Bits of [`DL_STATUS`] (0x0110).
pub mod dl_status {
    /// PDI operational (EEPROM loaded correctly).
    pub const PDI_OPERATIONAL: u16 = 1 << 0;
    /// PDI watchdog not expired.
    pub const PDI_WATCHDOG: u16 = 1 << 1;
    /// Enhanced link detection active.
    pub const ENHANCED_LINK: u16 = 1 << 2;

    /// Physical link on port `p` (0..4).
    pub const fn link(p: usize) -> u16 {
        1 << (4 + p)
    }

    /// Loop closed on port `p` (the port does not forward to its link partner).
    pub const fn loop_closed(p: usize) -> u16 {
        1 << (8 + 2 * p)
    }

    /// Communication established on port `p`.
    pub const fn communication(p: usize) -> u16 {
        1 << (9 + 2 * p)
    }
}

/// Fields of [`SII_CONTROL`] (0x0502).
pub mod sii_control {
    /// ECAT write enable.
    pub const WRITE_ENABLE: u16 = 1 << 0;
    /// Read size: 1 = 8 bytes, 0 = 4 bytes.
    pub const READ_SIZE_8: u16 = 1 << 6;
    /// Address algorithm: 1 = two address bytes.
    pub const TWO_ADDRESS_BYTES: u16 = 1 << 7;
    /// Command field mask (bits 10:8).
    pub const COMMAND_MASK: u16 = 0x0700;
    /// Read command.
    pub const CMD_READ: u16 = 0x0100;
    /// Write command.
    pub const CMD_WRITE: u16 = 0x0200;
    /// Reload command.
    pub const CMD_RELOAD: u16 = 0x0400;
    /// Checksum error in the ESC configuration area.
    pub const CHECKSUM_ERROR: u16 = 1 << 11;
    /// Device information error (EEPROM not loaded).
    pub const DEVICE_INFO_ERROR: u16 = 1 << 12;
    /// Command error (the last command could not be executed).
    pub const COMMAND_ERROR: u16 = 1 << 13;
    /// Write enable error.
    pub const WRITE_ENABLE_ERROR: u16 = 1 << 14;
    /// Busy: a command is in progress.
    pub const BUSY: u16 = 1 << 15;
}

/// AL state codes as bytes, for code that writes AL control by hand. They are
/// [`crate::AlState`]'s encoding (the one place it is defined); prefer the enum and the views
/// of [`crate::al`].
pub mod al_state {
    use crate::AlState;
    /// INIT.
    pub const INIT: u8 = AlState::Init.code();
    /// PRE-OPERATIONAL.
    pub const PRE_OP: u8 = AlState::PreOp.code();
    /// BOOTSTRAP.
    pub const BOOTSTRAP: u8 = AlState::Bootstrap.code();
    /// SAFE-OPERATIONAL.
    pub const SAFE_OP: u8 = AlState::SafeOp.code();
    /// OPERATIONAL.
    pub const OP: u8 = AlState::Op.code();
    /// AL status bit 4: error indication; AL control bit 4: error acknowledge.
    pub const ERROR_FLAG: u16 = 1 << 4;
}

/// AL status codes (0x0134) the virtual ESC reports (ETG.1000.6).
pub mod al_status_code {
    /// No error.
    pub const NO_ERROR: u16 = 0x0000;
    /// Invalid requested state change.
    pub const INVALID_STATE_CHANGE: u16 = 0x0011;
    /// Unknown requested state.
    pub const UNKNOWN_STATE: u16 = 0x0012;
    /// Bootstrap not supported.
    pub const BOOTSTRAP_NOT_SUPPORTED: u16 = 0x0013;
    /// Invalid output configuration (SyncManager).
    pub const INVALID_OUTPUT_CONFIG: u16 = 0x001d;
    /// Invalid input configuration.
    pub const INVALID_INPUT_CONFIG: u16 = 0x001e;
    /// Invalid DC SYNC configuration.
    pub const INVALID_DC_SYNC_CONFIG: u16 = 0x0030;
}
