//! ESC DL status (ESC datasheet section II, 0x0110, 2 bytes, read-only).
//!
//! | bit | meaning |
//! |---|---|
//! | 0 | PDI operational (EEPROM loaded correctly) |
//! | 1 | PDI watchdog status: 1 = reloaded, 0 = expired |
//! | 2 | enhanced link detection active |
//! | 3 | reserved |
//! | 4 + p | physical link on port p |
//! | 8 + 2p | loop on port p closed |
//! | 9 + 2p | communication established on port p |
//!
//! ```
//! use ecsync_wire::{DlStatus, DlStatusRepr};
//!
//! // An EK1100 coupler in ethercrab's capture: ports 0 and 1 linked and communicating, the
//! // unused ports 2 and 3 closed.
//! let dl = DlStatusRepr::parse(&DlStatus::new_checked(&0x5a31u16.to_le_bytes()[..]).unwrap());
//! assert!(dl.pdi_operational);
//! assert_eq!(dl.ports.map(|p| p.open()), [true, true, false, false]);
//! ```

use crate::WireError;
use crate::register::dl_status as bits;

/// Bytes of the DL status register.
pub const DL_STATUS_LEN: usize = 2;
/// Ports an ESC has at most.
pub const PORTS: usize = 4;

/// The state of one port as DL status reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct PortStatus {
    /// A physical link is detected.
    pub physical_link: bool,
    /// The loop is closed: the port does not forward to its link partner.
    pub loop_closed: bool,
    /// Communication is established (a stable link partner).
    pub communication: bool,
}

impl PortStatus {
    /// Whether frames leave through the port: link up and loop open (what a master's topology
    /// scan calls an open port).
    pub const fn open(&self) -> bool {
        self.physical_link && !self.loop_closed
    }
}

/// A typed view over DL status.
#[derive(Debug, Clone, Copy)]
pub struct DlStatus<T> {
    buffer: T,
}

impl<T: AsRef<[u8]>> DlStatus<T> {
    /// Wraps a buffer without checking it; accessors panic if it is shorter than
    /// [`DL_STATUS_LEN`].
    pub const fn new_unchecked(buffer: T) -> Self {
        DlStatus { buffer }
    }

    /// Wraps a buffer after checking it holds the register.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let have = buffer.as_ref().len();
        if have < DL_STATUS_LEN {
            return Err(WireError::Truncated {
                needed: DL_STATUS_LEN,
                have,
            });
        }
        Ok(DlStatus { buffer })
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    /// The raw register value.
    pub fn raw(&self) -> u16 {
        let b = self.buffer.as_ref();
        u16::from_le_bytes([b[0], b[1]])
    }

    /// PDI operational: the EEPROM was loaded correctly.
    pub fn pdi_operational(&self) -> bool {
        self.raw() & bits::PDI_OPERATIONAL != 0
    }

    /// The PDI watchdog was reloaded (has not expired).
    pub fn pdi_watchdog_ok(&self) -> bool {
        self.raw() & bits::PDI_WATCHDOG != 0
    }

    /// Enhanced link detection is active.
    pub fn enhanced_link_detection(&self) -> bool {
        self.raw() & bits::ENHANCED_LINK != 0
    }

    /// The status of port `port`; `None` for a port number of 4 or more.
    pub fn port(&self, port: usize) -> Option<PortStatus> {
        if port >= PORTS {
            return None;
        }
        let r = self.raw();
        Some(PortStatus {
            physical_link: r & bits::link(port) != 0,
            loop_closed: r & bits::loop_closed(port) != 0,
            communication: r & bits::communication(port) != 0,
        })
    }

    /// The status of the four ports.
    pub fn ports(&self) -> [PortStatus; PORTS] {
        core::array::from_fn(|p| self.port(p).unwrap_or_default())
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> DlStatus<T> {
    /// Sets the raw register value.
    pub fn set_raw(&mut self, value: u16) {
        self.buffer.as_mut()[..DL_STATUS_LEN].copy_from_slice(&value.to_le_bytes());
    }
}

/// The contents of DL status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct DlStatusRepr {
    /// PDI operational (EEPROM loaded).
    pub pdi_operational: bool,
    /// PDI watchdog reloaded (not expired).
    pub pdi_watchdog_ok: bool,
    /// Enhanced link detection active.
    pub enhanced_link_detection: bool,
    /// Ports 0 to 3.
    pub ports: [PortStatus; PORTS],
}

impl DlStatusRepr {
    /// Reads the register (bit 3, reserved, is ignored).
    pub fn parse<T: AsRef<[u8]>>(reg: &DlStatus<T>) -> Self {
        DlStatusRepr {
            pdi_operational: reg.pdi_operational(),
            pdi_watchdog_ok: reg.pdi_watchdog_ok(),
            enhanced_link_detection: reg.enhanced_link_detection(),
            ports: reg.ports(),
        }
    }

    /// The register value.
    pub fn value(&self) -> u16 {
        let flag = |on: bool, bit: u16| if on { bit } else { 0 };
        let mut v = flag(self.pdi_operational, bits::PDI_OPERATIONAL)
            | flag(self.pdi_watchdog_ok, bits::PDI_WATCHDOG)
            | flag(self.enhanced_link_detection, bits::ENHANCED_LINK);
        for (p, s) in self.ports.iter().enumerate() {
            v |= flag(s.physical_link, bits::link(p))
                | flag(s.loop_closed, bits::loop_closed(p))
                | flag(s.communication, bits::communication(p));
        }
        v
    }

    /// Bytes [`DlStatusRepr::emit`] writes.
    pub const fn buffer_len(&self) -> usize {
        DL_STATUS_LEN
    }

    /// Writes the register.
    pub fn emit<T: AsRef<[u8]> + AsMut<[u8]>>(&self, reg: &mut DlStatus<T>) {
        reg.set_raw(self.value());
    }

    /// The register's two bytes.
    pub fn to_bytes(&self) -> [u8; DL_STATUS_LEN] {
        self.value().to_le_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(v: u16) -> DlStatusRepr {
        DlStatusRepr::parse(&DlStatus::new_checked(&v.to_le_bytes()[..]).unwrap())
    }

    #[test]
    fn real_devices_from_ethercrabs_capture() {
        // shared/captures/README.md: EL2828 0x5A33, EL2889 0x5613, EK1100 0x5A31. By hand from
        // the datasheet table: 0x5A33 = bits 0, 1, 4, 5, 9, 11, 12, 14: PDI operational,
        // watchdog reloaded, links on ports 0 and 1, communication on 0 and 1, loops 2 and 3
        // closed.
        let el2828 = parse(0x5a33);
        let linked = PortStatus {
            physical_link: true,
            loop_closed: false,
            communication: true,
        };
        let closed = PortStatus {
            physical_link: false,
            loop_closed: true,
            communication: false,
        };
        assert_eq!(
            el2828,
            DlStatusRepr {
                pdi_operational: true,
                pdi_watchdog_ok: true,
                enhanced_link_detection: false,
                ports: [linked, linked, closed, closed],
            }
        );
        // The last terminal of the line: port 1 without link, closed.
        let el2889 = parse(0x5613);
        assert_eq!(el2889.ports, [linked, closed, closed, closed]);
        assert_eq!(el2889.ports.map(|p| p.open()), [true, false, false, false]);
        let ek1100 = parse(0x5a31);
        assert!(!ek1100.pdi_watchdog_ok);
        for v in [0x5a33, 0x5613, 0x5a31] {
            assert_eq!(parse(v).value(), v);
        }
    }

    #[test]
    fn ports_beyond_three_do_not_exist() {
        let v = DlStatus::new_checked(&[0xffu8, 0xff][..]).unwrap();
        assert!(v.port(3).is_some());
        assert_eq!(v.port(4), None);
        assert!(DlStatus::new_checked(&[0u8][..]).is_err());
    }

    proptest! {
        #[test]
        fn round_trips_every_value_but_the_reserved_bit(v: u16) {
            prop_assert_eq!(parse(v).value(), v & !0x0008);
            let r = parse(v);
            prop_assert_eq!(parse(u16::from_le_bytes(r.to_bytes())), r);
        }
    }
}
