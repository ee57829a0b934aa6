use ecsync_wire::Command;

/// Why the master could not go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MasterError {
    /// A frame did not come back (lost, or the network is down).
    #[error("frame lost: no reply to {what}")]
    FrameLost {
        /// What the frame was for.
        what: &'static str,
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
    #[error("slave {slave}: could not enter state {state:#x} (AL status code {code:#06x})")]
    StateChange {
        /// Station address.
        slave: u16,
        /// Requested state.
        state: u8,
        /// AL status code.
        code: u16,
    },
    /// A slave did not reach a state in time.
    #[error("slave {slave}: timed out waiting for state {state:#x}")]
    StateTimeout {
        /// Station address.
        slave: u16,
        /// Requested state.
        state: u8,
    },
    /// The clocks did not lock in the allowed time.
    #[error("DC did not lock within {0} ms")]
    NoLock(u64),
    /// The configuration is unusable.
    #[error("configuration: {0}")]
    Config(String),
}
