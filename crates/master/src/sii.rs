//! Reading a slave's SII EEPROM through the ESC's EEPROM interface (0x0500-0x050F), the
//! datasheet's procedure (section I, 11.2.3): wait until not busy, clear errors, write the
//! command with the word address, poll busy, read 4 or 8 data bytes.

use crate::MasterError;
use crate::io::Link;
use ecsync_wire::register::{self as reg, sii_control};
use ecsync_wire::sii::{self, category};

/// How long the EEPROM may stay busy for one command by default, ns of master time (see
/// [`crate::bringup::BringupTimeouts::sii_busy_timeout_ns`] for why).
pub const BUSY_TIMEOUT_NS: u64 = 100_000_000;

/// The bytes of EEPROM a reader reads at most (4 096 words: the categories a master reads lie
/// well within).
const MAX_BYTES: usize = 8192;

/// Reads EEPROM words of one slave, remembering what it has read.
#[derive(Debug)]
pub struct SiiReader<'a> {
    link: &'a Link,
    station: u16,
    busy_timeout_ns: u64,
    /// The bytes read so far from the start of the EEPROM, grown as reads go (a network's
    /// slaves are identified side by side: each reader holds only what it has read).
    cache: Vec<Option<u8>>,
}

impl<'a> SiiReader<'a> {
    /// A reader for the slave at `station`, whose EEPROM may stay busy for
    /// [`BUSY_TIMEOUT_NS`] per command.
    pub fn new(link: &'a Link, station: u16) -> Self {
        SiiReader {
            link,
            station,
            busy_timeout_ns: BUSY_TIMEOUT_NS,
            cache: Vec::new(),
        }
    }

    /// The reader with another limit on how long the EEPROM may stay busy per command, ns.
    pub fn with_busy_timeout_ns(mut self, timeout_ns: u64) -> Self {
        self.busy_timeout_ns = timeout_ns;
        self
    }

    async fn wait_idle(&self) -> Result<u16, MasterError> {
        let start = self.link.now().as_ns();
        loop {
            let v = self
                .link
                .fprd(self.station, reg::SII_CONTROL, 2, "SII status")
                .await?;
            let c = u16::from_le_bytes([v[0], v[1]]);
            if c & sii_control::BUSY == 0 {
                return Ok(c);
            }
            if self.link.now().as_ns().saturating_sub(start) > self.busy_timeout_ns {
                return Err(MasterError::Sii {
                    slave: self.station,
                    what: "stayed busy",
                });
            }
        }
    }

    /// Takes the EEPROM for the EtherCAT side (0x0500 = 0x02 then 0x00: force, then release
    /// the PDI's claim).
    pub async fn take_ownership(&self) -> Result<(), MasterError> {
        self.link
            .fpwr(self.station, reg::SII_CONFIG, &[0x02], "SII owner")
            .await?;
        self.link
            .fpwr(self.station, reg::SII_CONFIG, &[0x00], "SII owner")
            .await
    }

    async fn read_chunk(&mut self, word: u16) -> Result<(), MasterError> {
        let status = self.wait_idle().await?;
        if status & (sii_control::COMMAND_ERROR | sii_control::WRITE_ENABLE_ERROR) != 0 {
            self.link
                .fpwr(self.station, reg::SII_CONTROL, &[0, 0], "SII clear errors")
                .await?;
        }
        let mut cmd = [0u8; 6];
        cmd[0..2].copy_from_slice(&sii_control::CMD_READ.to_le_bytes());
        cmd[2..6].copy_from_slice(&u32::from(word).to_le_bytes());
        self.link
            .fpwr(self.station, reg::SII_CONTROL, &cmd, "SII read command")
            .await?;
        let status = self.wait_idle().await?;
        if status & sii_control::COMMAND_ERROR != 0 {
            return Err(MasterError::Sii {
                slave: self.station,
                what: "command error",
            });
        }
        let n = if status & sii_control::READ_SIZE_8 != 0 {
            8
        } else {
            4
        };
        let data = self
            .link
            .fprd(self.station, reg::SII_DATA, n, "SII data")
            .await?;
        for (i, b) in data.into_iter().enumerate() {
            let at = usize::from(word) * 2 + i;
            if at < MAX_BYTES {
                if at >= self.cache.len() {
                    self.cache.resize(at + 1, None);
                }
                self.cache[at] = Some(b);
            }
        }
        Ok(())
    }

    /// Reads `len` bytes starting at byte address `2 * word`.
    pub async fn read(&mut self, word: u16, len: usize) -> Result<Vec<u8>, MasterError> {
        let start = usize::from(word) * 2;
        let end = (start + len).min(MAX_BYTES);
        let mut at = start;
        while at < end {
            if self.cache.get(at).is_none_or(Option::is_none) {
                self.read_chunk((at / 2) as u16).await?;
            }
            at += 1;
        }
        Ok((start..end)
            .map(|at| self.cache.get(at).copied().flatten().unwrap_or(0xff))
            .collect())
    }

    /// Finds a category: its data word address and size in bytes.
    pub async fn find_category(&mut self, kind: u16) -> Result<Option<(u16, usize)>, MasterError> {
        let mut w = sii::WORD_FIRST_CATEGORY;
        for _ in 0..256 {
            let h = self.read(w, 4).await?;
            let t = u16::from_le_bytes([h[0], h[1]]);
            let size = u16::from_le_bytes([h[2], h[3]]);
            if t == category::END {
                return Ok(None);
            }
            if t == kind {
                return Ok(Some((w + 2, usize::from(size) * 2)));
            }
            match w.checked_add(2 + size) {
                Some(n) if usize::from(n) * 2 < MAX_BYTES => w = n,
                _ => return Ok(None),
            }
        }
        Ok(None)
    }

    /// Reads a whole category's data.
    pub async fn category(&mut self, kind: u16) -> Result<Option<Vec<u8>>, MasterError> {
        match self.find_category(kind).await? {
            Some((w, len)) => Ok(Some(self.read(w, len).await?)),
            None => Ok(None),
        }
    }
}

/// Total bits of the PDOs of a TxPDO/RxPDO category that are assigned to SyncManager `sm`.
pub fn pdo_bits_for_sm(cat: &[u8], sm: u8) -> u32 {
    let mut at = 0;
    let mut bits = 0u32;
    while at + 8 <= cat.len() {
        let entries = usize::from(cat[at + 2]);
        let pdo_sm = cat[at + 3];
        let mut e = at + 8;
        for _ in 0..entries {
            if e + 8 > cat.len() {
                break;
            }
            if pdo_sm == sm {
                bits += u32::from(cat[e + 5]);
            }
            e += 8;
        }
        at = e;
    }
    bits
}
