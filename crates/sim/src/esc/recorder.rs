//! What the plain path notes of the datagram it is processing, for the fast path
//! ([`super::fast`]) to record as a program: the register access it made (a DC register read
//! or written straight through, the logical copies through the FMMUs), or that it cannot be
//! repeated. The register and process data code fill it in as they act; nothing here acts.

/// What one datagram did at this ESC, recorded so that the same frame shape can replay it while
/// the ESC's configuration is unchanged (the cyclic frame is the same every cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum Act {
    /// Nothing beyond the address and working counter updates.
    #[default]
    None,
    /// System time read (0x0910) into the data, ORed for broadcast reads.
    SysTimeRead { or: bool },
    /// System time write (0x0910): the time control loop compares.
    SysTimeWrite,
    /// System time difference read (0x092C).
    DiffRead { or: bool },
    /// Logical access: the recorder's logical ops.
    Logical,
}

/// One step of a logical access.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum LogicalOp {
    /// Datagram data -> process RAM.
    #[default]
    Refresh,
    Write {
        data_off: u16,
        ram_off: u16,
        len: u16,
    },
    Read {
        data_off: u16,
        ram_off: u16,
        len: u16,
    },
}

/// Logical ops one datagram may record.
const MAX_LOGICAL_OPS: usize = 8;

/// The recorder for the datagram being processed.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Recorder {
    active: bool,
    pub(super) cacheable: bool,
    pub(super) act: Act,
    ops: [LogicalOp; MAX_LOGICAL_OPS],
    nops: u8,
}

impl Recorder {
    /// A recorder for one datagram; `active` when its ops are wanted.
    pub(super) fn start(active: bool) -> Self {
        Recorder {
            active,
            cacheable: true,
            ..Recorder::default()
        }
    }

    /// The access cannot be replayed (it depends on or changes more than the recorded ops).
    pub(super) fn uncacheable(&mut self) {
        self.cacheable = false;
    }

    /// Records a step of a logical access.
    pub(super) fn op(&mut self, op: LogicalOp) {
        if !self.active {
            return;
        }
        if usize::from(self.nops) < MAX_LOGICAL_OPS {
            self.ops[usize::from(self.nops)] = op;
            self.nops += 1;
        } else {
            self.cacheable = false;
        }
    }

    /// The steps of the logical access recorded.
    pub(super) fn logical_ops(&self) -> &[LogicalOp] {
        &self.ops[..usize::from(self.nops)]
    }
}
