use crate::WireError;

/// The fifteen EtherCAT datagram commands (ETG.1000.4, ESC datasheet section I, table
/// "EtherCAT command types").
///
/// Names follow the datasheet (and ethercrab): `Ap*` auto-increment (position) addressing,
/// `Fp*` configured station address, `B*` broadcast, `L*` logical, `*Rmw` read-multiple-write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum Command {
    /// No operation: the slave ignores the datagram.
    Nop = 0,
    /// Auto-increment physical read.
    Aprd = 1,
    /// Auto-increment physical write.
    Apwr = 2,
    /// Auto-increment physical read-write.
    Aprw = 3,
    /// Configured address physical read.
    Fprd = 4,
    /// Configured address physical write.
    Fpwr = 5,
    /// Configured address physical read-write.
    Fprw = 6,
    /// Broadcast read: every slave ORs its data into the datagram.
    Brd = 7,
    /// Broadcast write.
    Bwr = 8,
    /// Broadcast read-write.
    Brw = 9,
    /// Logical memory read.
    Lrd = 10,
    /// Logical memory write.
    Lwr = 11,
    /// Logical memory read-write.
    Lrw = 12,
    /// Auto-increment physical read, multiple write: the addressed slave reads, all others write.
    Armw = 13,
    /// Configured address physical read, multiple write.
    Frmw = 14,
}

/// How a command selects the slaves it acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AddressMode {
    /// No slave acts.
    None,
    /// The slave whose auto-increment position counter reaches zero (ADP is incremented by each
    /// slave the datagram passes).
    Position,
    /// The slave whose configured station address (0x0010) or alias (0x0012) equals ADP.
    Configured,
    /// Every slave.
    Broadcast,
    /// Every slave with an FMMU mapping the 32-bit logical address range.
    Logical,
}

impl Command {
    /// All commands in code order.
    pub const ALL: [Command; 15] = [
        Command::Nop,
        Command::Aprd,
        Command::Apwr,
        Command::Aprw,
        Command::Fprd,
        Command::Fpwr,
        Command::Fprw,
        Command::Brd,
        Command::Bwr,
        Command::Brw,
        Command::Lrd,
        Command::Lwr,
        Command::Lrw,
        Command::Armw,
        Command::Frmw,
    ];

    /// Decodes a command byte.
    pub fn from_code(code: u8) -> Result<Self, WireError> {
        Self::ALL
            .get(usize::from(code))
            .copied()
            .ok_or(WireError::UnknownCommand(code))
    }

    /// The command byte.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// How the command addresses slaves.
    pub const fn address_mode(self) -> AddressMode {
        use Command::*;
        match self {
            Nop => AddressMode::None,
            Aprd | Apwr | Aprw | Armw => AddressMode::Position,
            Fprd | Fpwr | Fprw | Frmw => AddressMode::Configured,
            Brd | Bwr | Brw => AddressMode::Broadcast,
            Lrd | Lwr | Lrw => AddressMode::Logical,
        }
    }

    /// Whether an addressed slave reads memory into the datagram.
    pub const fn reads(self) -> bool {
        use Command::*;
        matches!(
            self,
            Aprd | Aprw | Fprd | Fprw | Brd | Brw | Lrd | Lrw | Armw | Frmw
        )
    }

    /// Whether an addressed slave writes the datagram into memory.
    pub const fn writes(self) -> bool {
        use Command::*;
        matches!(
            self,
            Apwr | Aprw | Fpwr | Fprw | Bwr | Brw | Lwr | Lrw | Armw | Frmw
        )
    }

    /// Whether this is a read-multiple-write command (ARMW, FRMW): the addressed slave reads,
    /// every other slave writes.
    pub const fn is_read_multiple_write(self) -> bool {
        matches!(self, Command::Armw | Command::Frmw)
    }

    /// Datasheet mnemonic, as Wireshark prints it.
    pub const fn mnemonic(self) -> &'static str {
        use Command::*;
        match self {
            Nop => "NOP",
            Aprd => "APRD",
            Apwr => "APWR",
            Aprw => "APRW",
            Fprd => "FPRD",
            Fpwr => "FPWR",
            Fprw => "FPRW",
            Brd => "BRD",
            Bwr => "BWR",
            Brw => "BRW",
            Lrd => "LRD",
            Lwr => "LWR",
            Lrw => "LRW",
            Armw => "ARMW",
            Frmw => "FRMW",
        }
    }
}

impl core::fmt::Display for Command {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.mnemonic())
    }
}

impl TryFrom<u8> for Command {
    type Error = WireError;
    fn try_from(code: u8) -> Result<Self, WireError> {
        Self::from_code(code)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_match_the_datasheet_table() {
        // ESC datasheet section I, table "EtherCAT command types".
        let table = [
            (0, "NOP"),
            (1, "APRD"),
            (2, "APWR"),
            (3, "APRW"),
            (4, "FPRD"),
            (5, "FPWR"),
            (6, "FPRW"),
            (7, "BRD"),
            (8, "BWR"),
            (9, "BRW"),
            (10, "LRD"),
            (11, "LWR"),
            (12, "LRW"),
            (13, "ARMW"),
            (14, "FRMW"),
        ];
        for (code, name) in table {
            let c = Command::from_code(code).unwrap();
            assert_eq!(c.code(), code);
            assert_eq!(c.mnemonic(), name);
        }
        assert_eq!(Command::from_code(15), Err(WireError::UnknownCommand(15)));
        assert_eq!(
            Command::from_code(0xff),
            Err(WireError::UnknownCommand(0xff))
        );
    }

    #[test]
    fn read_write_classes() {
        assert!(!Command::Nop.reads() && !Command::Nop.writes());
        assert!(Command::Lrw.reads() && Command::Lrw.writes());
        assert!(Command::Bwr.writes() && !Command::Bwr.reads());
        assert!(Command::Frmw.is_read_multiple_write());
        assert_eq!(Command::Armw.address_mode(), AddressMode::Position);
        assert_eq!(Command::Frmw.address_mode(), AddressMode::Configured);
    }
}
