//! The SII EEPROM interface (ESC datasheet section II, 0x0500-0x050F, and section I, "SII
//! EEPROM"): commands written to the control register, a read that stays busy for the EEPROM's
//! read time, writes with the write-enable bit, and the words loaded at power-up.

use super::Esc;
use ecsync_wire::register::{self as reg, sii_control};
use ecsync_wire::sii as layout;

/// Bytes of the data register 0x0508-0x050F.
const DATA_BYTES: usize = 8;

/// The EEPROM behind the interface and the command in progress.
#[derive(Debug, Clone)]
pub(super) struct SiiState {
    image: Vec<u8>,
    busy_until_ps: u64,
    pending_read: Option<u32>,
    read_busy_ps: u64,
}

impl SiiState {
    /// An idle interface to `image`, whose reads take `read_busy_us`.
    pub(super) fn new(image: Vec<u8>, read_busy_us: f64) -> Self {
        SiiState {
            image,
            busy_until_ps: 0,
            pending_read: None,
            read_busy_ps: (read_busy_us * 1e6) as u64,
        }
    }

    /// After a power cycle: no read in progress (the contents stay).
    pub(super) fn power_up(&mut self) {
        self.busy_until_ps = 0;
        self.pending_read = None;
    }

    /// The EEPROM's contents.
    pub(super) fn image(&self) -> &[u8] {
        &self.image
    }

    /// Whether a read is in progress (the interface's registers are write-protected).
    pub(super) fn busy(&self) -> bool {
        self.pending_read.is_some()
    }

    fn word(&self, w: u16) -> u16 {
        let at = usize::from(w) * 2;
        match self.image.get(at..at + 2) {
            Some(b) => u16::from_le_bytes([b[0], b[1]]),
            // An erased EEPROM reads all ones.
            None => 0xffff,
        }
    }

    /// The words the ESC loads at power-up: PDI control (word 0), PDI configuration (1), SYNC
    /// pulse length (2) and the station alias (4).
    pub(super) fn reset_words(&self) -> [u16; 4] {
        [
            self.word(layout::WORD_PDI_CONTROL),
            self.word(1),
            self.word(2),
            self.word(layout::WORD_ALIAS),
        ]
    }
}

impl Esc {
    /// Completes an EEPROM command whose busy time has elapsed.
    pub(super) fn sii_update(&mut self, t_ps: u64) {
        let Some(addr) = self.sii.pending_read else {
            return;
        };
        if t_ps < self.sii.busy_until_ps {
            return;
        }
        self.generation += 1;
        let at = addr as usize * 2;
        let data = usize::from(reg::SII_DATA);
        // 8 or 4 bytes, as 0x0502 bit 6 announces; after a 4-byte read 0x050C-0x050F read
        // zeros, as the AKD's emulated EEPROM gives them (issue 32, point 5).
        let n = self.model.sii_read_bytes();
        for i in 0..DATA_BYTES {
            self.regs[data + i] = if i < n {
                self.sii.image.get(at + i).copied().unwrap_or(0xff)
            } else {
                0
            };
        }
        self.sii.pending_read = None;
        let c = self.get_u16(reg::SII_CONTROL) & !(sii_control::BUSY | sii_control::COMMAND_MASK);
        self.put_u16(reg::SII_CONTROL, c);
    }

    /// The master wrote `written` to the control register (0x0502): starts its command.
    pub(super) fn sii_control_written(&mut self, written: u16, t_ps: u64) {
        // The static bits (read size, emulation, address bytes) are the model's.
        let status_bits = self.model.sii_control_idle;
        let mut c = status_bits | (self.get_u16(reg::SII_CONTROL) & 0xf800 & !sii_control::BUSY);
        match written & sii_control::COMMAND_MASK {
            0 => c &= !(sii_control::COMMAND_ERROR | sii_control::WRITE_ENABLE_ERROR),
            sii_control::CMD_READ => {
                self.sii.pending_read = Some(self.get_u32(reg::SII_ADDRESS));
                self.sii.busy_until_ps = t_ps + self.sii.read_busy_ps;
                c |= sii_control::BUSY | sii_control::CMD_READ;
            }
            sii_control::CMD_WRITE => {
                if written & sii_control::WRITE_ENABLE == 0 {
                    c |= sii_control::WRITE_ENABLE_ERROR;
                } else {
                    let addr = self.get_u32(reg::SII_ADDRESS) as usize;
                    let word = [
                        self.regs[usize::from(reg::SII_DATA)],
                        self.regs[usize::from(reg::SII_DATA) + 1],
                    ];
                    match self.sii.image.get_mut(addr * 2..addr * 2 + 2) {
                        Some(w) => w.copy_from_slice(&word),
                        None => c |= sii_control::COMMAND_ERROR,
                    }
                }
            }
            sii_control::CMD_RELOAD => {}
            _ => c |= sii_control::COMMAND_ERROR,
        }
        self.sii_update(t_ps);
        if self.sii.pending_read.is_none() {
            c &= !(sii_control::BUSY | sii_control::COMMAND_MASK);
        }
        self.put_u16(reg::SII_CONTROL, c);
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{dg, esc, wkc};
    use ecsync_wire::Command;

    #[test]
    fn eeprom_read_takes_its_busy_time() {
        let mut e = esc();
        e.process_datagram(&mut dg(Command::Apwr, 0, 0x0010, &[0x00, 0x10]), 0);
        // Read word 8 (vendor ID): control = read command, address 8.
        let mut d = dg(
            Command::Fpwr,
            0x1000,
            0x0502,
            &[0x00, 0x01, 0x08, 0x00, 0x00, 0x00],
        );
        e.process_datagram(&mut d, 1_000_000);
        assert_eq!(wkc(&d), 1);
        let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
        e.process_datagram(&mut s, 5_000_000);
        assert_eq!(u16::from_le_bytes([s[10], s[11]]) & 0x8000, 0x8000, "busy");
        let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
        e.process_datagram(&mut s, 30_000_000);
        assert_eq!(
            u16::from_le_bytes([s[10], s[11]]),
            0x0040,
            "idle, 8-byte reads"
        );
        let mut r = dg(Command::Fprd, 0x1000, 0x0508, &[0; 8]);
        e.process_datagram(&mut r, 31_000_000);
        let id = ecsync_wire::sii::identity(e.sii_image()).unwrap();
        assert_eq!(
            u32::from_le_bytes(r[10..14].try_into().unwrap()),
            id.vendor_id
        );
        assert_eq!(
            u32::from_le_bytes(r[14..18].try_into().unwrap()),
            id.product_code
        );
    }

    #[test]
    fn writes_need_the_write_enable_bit_and_an_address_inside() {
        let mut e = esc();
        e.process_datagram(&mut dg(Command::Apwr, 0, 0x0010, &[0x00, 0x10]), 0);
        let status = |e: &mut super::Esc| {
            let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
            e.process_datagram(&mut s, 0);
            u16::from_le_bytes([s[10], s[11]])
        };
        // Write command without write enable: write enable error (bit 14).
        e.process_datagram(
            &mut dg(
                Command::Fpwr,
                0x1000,
                0x0502,
                &[0x00, 0x02, 0x04, 0, 0, 0, 0xcd, 0xab],
            ),
            0,
        );
        assert_eq!(status(&mut e) & 0x4000, 0x4000);
        // With it: word 4 (the alias) takes the data.
        e.process_datagram(
            &mut dg(
                Command::Fpwr,
                0x1000,
                0x0502,
                &[0x01, 0x02, 0x04, 0, 0, 0, 0xcd, 0xab],
            ),
            0,
        );
        assert_eq!(&e.sii_image()[8..10], &[0xcd, 0xab]);
        // Past the end of the EEPROM: command error (bit 13), nothing panics.
        e.process_datagram(
            &mut dg(
                Command::Fpwr,
                0x1000,
                0x0502,
                &[0x01, 0x02, 0xff, 0xff, 0xff, 0x7f],
            ),
            0,
        );
        assert_eq!(status(&mut e) & 0x2000, 0x2000);
    }

    /// An ESC announcing 4-byte reads (0x0502 bit 6 clear, as the AKD's 0x0020) fills
    /// 0x0508-0x050B and reads zeros in 0x050C-0x050F; its idle status is the model's.
    #[test]
    fn four_byte_reads_fill_half_the_data_register() {
        let mut e = super::super::testing::esc_of(crate::model::EscModel::akd_drive());
        e.process_datagram(&mut dg(Command::Apwr, 0, 0x0010, &[0x00, 0x10]), 0);
        let mut s = dg(Command::Fprd, 0x1000, 0x0502, &[0, 0]);
        e.process_datagram(&mut s, 0);
        assert_eq!(
            u16::from_le_bytes([s[10], s[11]]),
            0x0020,
            "idle, as the AKD"
        );
        // Read word 8 (vendor ID, product code follow).
        e.process_datagram(
            &mut dg(
                Command::Fpwr,
                0x1000,
                0x0502,
                &[0x00, 0x01, 0x08, 0x00, 0x00, 0x00],
            ),
            1_000_000,
        );
        let mut r = dg(Command::Fprd, 0x1000, 0x0508, &[0xaa; 8]);
        e.process_datagram(&mut r, 1_000_000_000);
        assert_eq!(wkc(&r), 1);
        let id = ecsync_wire::sii::identity(e.sii_image()).unwrap();
        assert_eq!(
            u32::from_le_bytes(r[10..14].try_into().unwrap()),
            id.vendor_id
        );
        assert_eq!(&r[14..18], &[0, 0, 0, 0], "0x050C-0x050F");
    }
}
