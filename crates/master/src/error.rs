use crate::network::{Phase, SlaveId};
use ecsync_wire::{AlState, AlStatusCode, Command};

/// "BRD 0x0000:0x0130 and 2 more datagrams": what a lost frame carried.
fn sent_text(first: Option<(Command, u32)>, datagrams: u16) -> String {
    let Some((cmd, raw)) = first else {
        return "no datagram".to_string();
    };
    let addr = if matches!(cmd, Command::Lrd | Command::Lwr | Command::Lrw) {
        format!("{raw:#010x}")
    } else {
        format!("{:#06x}:{:#06x}", raw & 0xffff, raw >> 16)
    };
    match datagrams {
        0 | 1 => format!("{cmd} {addr}"),
        n => format!("{cmd} {addr} and {} more datagrams", n - 1),
    }
}

/// Why the master could not go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MasterError {
    /// A frame did not come back (lost, or the network is down).
    #[error("frame lost: no reply to {what} ({}) after {attempts} {}", sent_text(*first, *datagrams), if *attempts == 1 { "send" } else { "sends" })]
    FrameLost {
        /// What the frame was for.
        what: &'static str,
        /// Its first datagram's command and address (raw: ADP and ADO, or logical).
        first: Option<(Command, u32)>,
        /// Datagrams in it.
        datagrams: u16,
        /// How often it was sent (the driver's retries and the first).
        attempts: u32,
    },
    /// The reply does not match the request (other datagrams, other indices).
    #[error("reply does not match the request ({0})")]
    BadReply(&'static str),
    /// No slave answered.
    #[error("no slaves found")]
    NoSlaves,
    /// A datagram's working counter differs from what the command needs.
    #[error("{command} {what}: working counter {got}, expected {expected}")]
    WorkingCounter {
        /// The command.
        command: Command,
        /// What it was for.
        what: &'static str,
        /// Expected value.
        expected: u16,
        /// Value received.
        got: u16,
    },
    /// The EEPROM stayed busy too long or reported an error.
    #[error("slave {slave}: SII EEPROM {what}")]
    Sii {
        /// Station address.
        slave: u16,
        /// What went wrong.
        what: &'static str,
    },
    /// The ports read from the slaves do not form a tree.
    #[error("topology: {0}")]
    Topology(#[from] ecsync_dc::TopologyError),
    /// No slave has a DC system time to act as reference.
    #[error("no DC-capable slave to act as reference clock")]
    NoReferenceClock,
    /// A slave refused a state change.
    #[error("slave {slave}: could not enter {state}: AL status code {code}")]
    StateChange {
        /// Station address.
        slave: u16,
        /// Requested state.
        state: AlState,
        /// AL status code: why.
        code: AlStatusCode,
    },
    /// A slave did not reach a state in time.
    #[error("slave {slave}: timed out waiting for {state}")]
    StateTimeout {
        /// Station address.
        slave: u16,
        /// Requested state.
        state: AlState,
    },
    /// Not every slave reached a state in time, as a broadcast read of AL status shows (which
    /// cannot tell the slaves apart).
    #[error(
        "timed out waiting for every slave to report {state} ({answered} of {expected} \
         answered, their AL status OR-ed {status:#04x})"
    )]
    NetworkStateTimeout {
        /// Requested state.
        state: AlState,
        /// Slaves that answered the last read (its working counter).
        answered: u16,
        /// Slaves in the network.
        expected: u16,
        /// The low byte of AL status of the last read, OR-ed over the slaves that answered.
        status: u8,
    },
    /// A slave's mailbox did not carry an exchange.
    #[error("slave {slave}: mailbox: {what}")]
    Mailbox {
        /// Station address.
        slave: u16,
        /// What went wrong.
        what: &'static str,
    },
    /// A slave aborted an SDO transfer.
    #[error(
        "slave {slave}: SDO {index:#06x}:{subindex:02x} aborted with {code:#010x} ({})",
        sdo_abort_text(*code)
    )]
    SdoAbort {
        /// Station address.
        slave: u16,
        /// Object index.
        index: u16,
        /// Subindex.
        subindex: u8,
        /// Abort code.
        code: u32,
    },
    /// The clocks did not lock in the allowed time.
    #[error("DC did not lock within {0} ms")]
    NoLock(u64),
    /// The configuration is unusable.
    #[error("configuration: {0}")]
    Config(String),
    /// The bring-up failed in `phase`; `slave` is the one slave the failing exchange concerned,
    /// where there is one (the frame was addressed to it alone, or its datagram came back with
    /// a wrong working counter), and `None` for broadcasts and frames to many slaves.
    #[error("{}", bringup_message(*phase, slave.as_ref(), cause))]
    Bringup {
        /// The phase.
        phase: Phase,
        /// The slave the failing exchange concerned.
        slave: Option<SlaveId>,
        /// What went wrong (never itself a [`MasterError::Bringup`]).
        cause: Box<MasterError>,
    },
}

impl MasterError {
    /// The bring-up phase the error happened in, if it happened in one.
    pub fn phase(&self) -> Option<Phase> {
        match self {
            MasterError::Bringup { phase, .. } => Some(*phase),
            _ => None,
        }
    }

    /// The slave the failing exchange concerned, if the error names one.
    pub fn slave(&self) -> Option<SlaveId> {
        match self {
            MasterError::Bringup { slave, .. } => *slave,
            _ => None,
        }
    }

    /// What went wrong, without the phase and slave around it.
    pub fn root(&self) -> &MasterError {
        match self {
            MasterError::Bringup { cause, .. } => cause,
            e => e,
        }
    }

    /// The error as one of `phase`, unless it already names its phase.
    pub(crate) fn during(self, phase: Phase) -> Self {
        match self {
            e @ MasterError::Bringup { .. } => e,
            e => MasterError::Bringup {
                phase,
                slave: None,
                cause: Box::new(e),
            },
        }
    }

    /// The error as one of `phase` at `slave`, unless it already names its phase.
    pub(crate) fn at(self, phase: Phase, slave: SlaveId) -> Self {
        match self {
            e @ MasterError::Bringup { .. } => e,
            e => MasterError::Bringup {
                phase,
                slave: Some(slave),
                cause: Box::new(e),
            },
        }
    }

    /// The message without the slave the error names itself, for when the context names it.
    fn without_slave(&self) -> String {
        match self {
            MasterError::Sii { what, .. } => format!("SII EEPROM {what}"),
            MasterError::StateChange { state, code, .. } => {
                format!("could not enter {state}: AL status code {code}")
            }
            MasterError::StateTimeout { state, .. } => format!("timed out waiting for {state}"),
            e => e.to_string(),
        }
    }
}

/// `phase: slave: cause`, or `phase: cause` when the exchange concerned no one slave.
fn bringup_message(phase: Phase, slave: Option<&SlaveId>, cause: &MasterError) -> String {
    match slave {
        Some(s) => format!("{phase}: {s}: {}", cause.without_slave()),
        None => format!("{phase}: {cause}"),
    }
}

/// What an SDO abort code means (ETG.1000.6 table 41), for the messages.
fn sdo_abort_text(code: u32) -> &'static str {
    match code {
        0x0503_0000 => "toggle bit not changed",
        0x0504_0001 => "command specifier unknown",
        0x0601_0000 => "unsupported access",
        0x0601_0001 => "write-only object",
        0x0601_0002 => "read-only object",
        0x0601_0003 => "subindex 0 must be 0 first",
        0x0602_0000 => "object does not exist",
        0x0607_0010 => "length does not match",
        0x0607_0012 => "length too high",
        0x0607_0013 => "length too low",
        0x0609_0011 => "subindex does not exist",
        0x0609_0030 => "value out of range",
        0x0800_0000 => "general error",
        0x0800_0020 => "cannot be stored",
        0x0800_0022 => "not in the present state",
        _ => "see ETG.1000.6 table 41",
    }
}
