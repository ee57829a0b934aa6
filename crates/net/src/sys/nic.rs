//! The NIC's timestamping: what the interface can stamp (ethtool), hardware stamps switched on
//! and restored (SIOCSHWTSTAMP), and its PTP hardware clock.

#![allow(unsafe_code)]

use super::process::clock_ns;
use super::*;
use std::ffi::CString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

/// Which kernel timestamps a socket gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct TimestampSupport {
    /// Software receive timestamps (taken by the kernel when the frame arrived).
    pub rx_software: bool,
    /// Software transmit timestamps (taken by the driver as the frame went to the device).
    pub tx_software: bool,
    /// Hardware transmit timestamps (the NIC's, in its PTP hardware clock's time), once
    /// switched on by [`PacketSocket::enable_hardware_tx_stamps`].
    pub tx_hardware: bool,
}

/// What an interface's driver says it can timestamp (`ethtool -T`, ETHTOOL_GET_TS_INFO).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct NicTimestamping {
    /// The SOF_TIMESTAMPING_* capabilities.
    pub so_timestamping: u32,
    /// The PTP hardware clock's index (`/dev/ptpN`), if the NIC has one.
    pub phc_index: Option<u32>,
    /// The HWTSTAMP_TX_* modes the NIC supports, as bits.
    pub tx_types: u32,
}

impl NicTimestamping {
    /// Hardware transmit timestamps: all of the pieces [`NicTimestamping::hardware_missing`]
    /// names are there.
    pub fn hardware_tx(&self) -> bool {
        self.hardware_missing().is_empty()
    }

    /// What hardware transmit timestamps need that the NIC lacks, in `ethtool -T`'s words.
    pub fn hardware_missing(&self) -> Vec<&'static str> {
        let mut m = Vec::new();
        if self.so_timestamping & SOF_TIMESTAMPING_TX_HARDWARE == 0 {
            m.push("hardware-transmit (SOF_TIMESTAMPING_TX_HARDWARE)");
        }
        if self.so_timestamping & SOF_TIMESTAMPING_RAW_HARDWARE == 0 {
            m.push("hardware-raw-clock (SOF_TIMESTAMPING_RAW_HARDWARE)");
        }
        if self.phc_index.is_none() {
            m.push("a PTP Hardware Clock (none)");
        }
        if self.tx_types & (1 << HWTSTAMP_TX_ON) == 0 {
            m.push("Hardware Transmit Timestamp Mode on (HWTSTAMP_TX_ON)");
        }
        m
    }
}

/// A socket for the interface ioctls (any socket of the namespace will do).
pub(super) fn ioctl_socket() -> io::Result<OwnedFd> {
    // SAFETY: plain FFI call with constant arguments; the result is checked below.
    let raw = unsafe { libc::socket(libc::AF_INET, libc::SOCK_DGRAM | libc::SOCK_CLOEXEC, 0) };
    if raw < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `raw` is a new file descriptor that nothing else owns.
    Ok(unsafe { OwnedFd::from_raw_fd(raw) })
}

/// An interface ioctl whose `ifr_data` points at `data`.
pub(super) fn ifreq_ioctl<T>(iface: &str, request: libc::c_ulong, data: &mut T) -> io::Result<()> {
    let mut ifr = IfreqData {
        name: [0; libc::IFNAMSIZ],
        data: (data as *mut T).cast(),
        pad: [0; 16],
    };
    if iface.len() >= libc::IFNAMSIZ || iface.as_bytes().contains(&0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "interface name",
        ));
    }
    for (d, &b) in ifr.name.iter_mut().zip(iface.as_bytes()) {
        *d = b as libc::c_char;
    }
    let sock = ioctl_socket()?;
    // SAFETY: `ifr` is a live ifreq whose name is NUL-terminated (the array is zeroed past the
    // name) and whose data pointer refers to `data`, a live value of the type `request`
    // expects; the kernel reads and writes only within them.
    let r = unsafe { libc::ioctl(sock.as_raw_fd(), request as _, &mut ifr) };
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(())
    }
}

/// What `iface`'s driver can timestamp (ETHTOOL_GET_TS_INFO). A driver without the call
/// gets the kernel's software stamps only.
pub fn nic_timestamping(iface: &str) -> io::Result<NicTimestamping> {
    let mut info = EthtoolTsInfo {
        cmd: ETHTOOL_GET_TS_INFO,
        ..EthtoolTsInfo::default()
    };
    match ifreq_ioctl(iface, SIOCETHTOOL, &mut info) {
        Ok(()) => Ok(NicTimestamping {
            so_timestamping: info.so_timestamping,
            phc_index: u32::try_from(info.phc_index).ok(),
            tx_types: info.tx_types,
        }),
        Err(e) if e.raw_os_error() == Some(libc::EOPNOTSUPP) => Ok(NicTimestamping {
            so_timestamping: SOF_TIMESTAMPING_TX_SOFTWARE
                | SOF_TIMESTAMPING_RX_SOFTWARE
                | SOF_TIMESTAMPING_SOFTWARE,
            phc_index: None,
            tx_types: 0,
        }),
        Err(e) => Err(e),
    }
}

/// A NIC's hardware timestamping setting as it was before ecsync switched its transmit stamps
/// on, to be put back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HwStampSetting {
    pub(super) iface: String,
    pub(super) tx_type: i32,
    pub(super) rx_filter: i32,
}

/// Puts a NIC's hardware timestamping setting back (best effort: the interface may be gone).
pub fn restore_hw_tx_stamps(s: &HwStampSetting) {
    let mut cfg = HwtstampConfig {
        flags: 0,
        tx_type: s.tx_type,
        rx_filter: s.rx_filter,
    };
    let _ = ifreq_ioctl(&s.iface, SIOCSHWTSTAMP, &mut cfg);
}

/// A PTP hardware clock (`/dev/ptpN`), read as a dynamic POSIX clock.
#[derive(Debug)]
pub struct Phc {
    pub(super) fd: OwnedFd,
}

impl Phc {
    /// Opens `/dev/ptp{index}`.
    pub fn open(index: u32) -> io::Result<Phc> {
        let path = CString::new(format!("/dev/ptp{index}")).expect("no NUL in a number");
        // SAFETY: `path` is a NUL-terminated string that outlives the call.
        let raw = unsafe { libc::open(path.as_ptr(), libc::O_RDONLY | libc::O_CLOEXEC) };
        if raw < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `raw` is a new file descriptor that nothing else owns.
        Ok(Phc {
            fd: unsafe { OwnedFd::from_raw_fd(raw) },
        })
    }

    /// One reading of the PHC between two of CLOCK_REALTIME: (realtime before, PHC, realtime
    /// after), ns.
    pub fn sandwich(&self) -> (u64, u64, u64) {
        let id = (!(self.fd.as_raw_fd() as libc::clockid_t) << 3) | CLOCKFD;
        let before = realtime_ns();
        let phc = clock_ns(id);
        (before, phc, realtime_ns())
    }
}

/// `struct ifreq` with `ifr_flags`.
#[repr(C)]
struct IfreqFlags {
    name: [libc::c_char; libc::IFNAMSIZ],
    flags: libc::c_short,
    pad: [u8; 22],
}

/// Sets `iface` administratively up or down (SIOCSIFFLAGS, IFF_UP; needs CAP_NET_ADMIN in the
/// interface's network namespace). On a veth pair the peer's carrier follows: this is how a
/// served segment shows a master that watches carrier the cable at its first slave pulled.
pub fn set_interface_up(iface: &str, up: bool) -> io::Result<()> {
    if iface.len() >= libc::IFNAMSIZ || iface.as_bytes().contains(&0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "interface name",
        ));
    }
    let mut ifr = IfreqFlags {
        name: [0; libc::IFNAMSIZ],
        flags: 0,
        pad: [0; 22],
    };
    for (d, &b) in ifr.name.iter_mut().zip(iface.as_bytes()) {
        *d = b as libc::c_char;
    }
    let sock = ioctl_socket()?;
    // SAFETY: `ifr` is a live ifreq with a NUL-terminated name; SIOCGIFFLAGS writes only its
    // flags field, SIOCSIFFLAGS reads it.
    let r = unsafe { libc::ioctl(sock.as_raw_fd(), libc::SIOCGIFFLAGS as _, &mut ifr) };
    if r < 0 {
        return Err(io::Error::last_os_error());
    }
    let up_flag = libc::IFF_UP as libc::c_short;
    ifr.flags = if up {
        ifr.flags | up_flag
    } else {
        ifr.flags & !up_flag
    };
    // SAFETY: as above.
    let r = unsafe { libc::ioctl(sock.as_raw_fd(), libc::SIOCSIFFLAGS as _, &mut ifr) };
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(())
    }
}
