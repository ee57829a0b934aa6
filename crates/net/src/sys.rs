//! The one module of ecsync that talks to the operating system: AF_PACKET sockets, kernel
//! timestamps, clocks, sleeping, real-time scheduling, memory locking, CPU affinity and network
//! namespaces. Everything else is safe Rust on top of the small API below.
//!
//! Every `unsafe` block is a single FFI call (or the parsing of what it returned) and says why it
//! is sound. The invariants are always the same few: pointers come from live Rust references or
//! buffers whose length is passed alongside, structures are plain C structs zero-initialised
//! before the kernel fills them, and file descriptors are owned by an [`OwnedFd`] from the moment
//! the kernel hands them out.
#![allow(unsafe_code)]

use std::ffi::CString;
use std::io;
use std::mem::{MaybeUninit, size_of};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

/// EtherType of EtherCAT frames.
pub const ETHERTYPE_ETHERCAT: u16 = 0x88a4;

// Kernel ABI values (include/uapi/linux/if_packet.h and net_tstamp.h), written out so that the
// module does not depend on which of them a given libc version exports.
const SOL_PACKET: libc::c_int = 263;
const PACKET_ADD_MEMBERSHIP: libc::c_int = 1;
const PACKET_MR_PROMISC: libc::c_ushort = 1;
const PACKET_IGNORE_OUTGOING: libc::c_int = 23;
const PACKET_AUXDATA: libc::c_int = 8;
const PACKET_OUTGOING: u8 = 4;
const TP_STATUS_VLAN_VALID: u32 = 1 << 4;
const TP_STATUS_VLAN_TPID_VALID: u32 = 1 << 6;
const ETH_P_ALL: u16 = 0x0003;
const SO_ATTACH_FILTER: libc::c_int = 26;
/// TPID of an IEEE 802.1Q (C-VLAN) tag.
pub const TPID_8021Q: u16 = 0x8100;
/// TPID of an IEEE 802.1ad (S-VLAN) tag.
pub const TPID_8021AD: u16 = 0x88a8;
const SOF_TIMESTAMPING_TX_SOFTWARE: libc::c_uint = 1 << 1;
const SOF_TIMESTAMPING_RX_SOFTWARE: libc::c_uint = 1 << 3;
const SOF_TIMESTAMPING_SOFTWARE: libc::c_uint = 1 << 4;
const SOF_TIMESTAMPING_OPT_TSONLY: libc::c_uint = 1 << 11;
const SOF_TIMESTAMPING_TX_HARDWARE: libc::c_uint = 1 << 0;
const SOF_TIMESTAMPING_RAW_HARDWARE: libc::c_uint = 1 << 6;
// include/uapi/linux/sockios.h, ethtool.h and net_tstamp.h.
const SIOCETHTOOL: libc::c_ulong = 0x8946;
const SIOCSHWTSTAMP: libc::c_ulong = 0x89b0;
const SIOCGHWTSTAMP: libc::c_ulong = 0x89b1;
const ETHTOOL_GET_TS_INFO: u32 = 0x41;
const HWTSTAMP_TX_ON: i32 = 1;
const HWTSTAMP_FILTER_NONE: i32 = 0;
/// `CLOCKFD` of the kernel's posix-timers: a dynamic clock's id is `(~fd << 3) | CLOCKFD`.
const CLOCKFD: libc::clockid_t = 3;

/// `struct ethtool_ts_info` of ethtool.h.
#[repr(C)]
#[derive(Default)]
struct EthtoolTsInfo {
    cmd: u32,
    so_timestamping: u32,
    phc_index: i32,
    tx_types: u32,
    tx_reserved: [u32; 3],
    rx_filters: u32,
    rx_reserved: [u32; 3],
}

/// `struct hwtstamp_config` of net_tstamp.h.
#[repr(C)]
struct HwtstampConfig {
    flags: i32,
    tx_type: i32,
    rx_filter: i32,
}

/// `struct ifreq` with its union as the data pointer (`ifr_data`): 16 bytes of name and the
/// union's 24.
#[repr(C)]
struct IfreqData {
    name: [libc::c_char; libc::IFNAMSIZ],
    data: *mut libc::c_void,
    pad: [u8; 16],
}

/// `struct packet_mreq` of if_packet.h.
#[repr(C)]
struct PacketMreq {
    mr_ifindex: libc::c_int,
    mr_type: libc::c_ushort,
    mr_alen: libc::c_ushort,
    mr_address: [u8; 8],
}

/// `struct tpacket_auxdata` of if_packet.h: what the kernel knows of a received frame beyond
/// its bytes, among it the VLAN tag it took off (VLAN offload, or the stack's own untagging).
#[repr(C)]
#[derive(Clone, Copy)]
struct TpacketAuxdata {
    tp_status: u32,
    tp_len: u32,
    tp_snaplen: u32,
    tp_mac: u16,
    tp_net: u16,
    tp_vlan_tci: u16,
    tp_vlan_tpid: u16,
}

/// `struct sock_filter` of filter.h: one classic BPF instruction.
#[repr(C)]
struct SockFilter {
    code: u16,
    jt: u8,
    jf: u8,
    k: u32,
}

/// `struct sock_fprog` of filter.h.
#[repr(C)]
struct SockFprog {
    len: libc::c_ushort,
    filter: *const SockFilter,
}

/// The classic BPF program of a VLAN-aware socket: accepts EtherCAT frames, untagged or with
/// one 802.1Q or 802.1ad tag in the bytes (the kernel usually takes the tag off before packet
/// sockets see the frame, leaving EtherType 0x88A4 at offset 12 and the tag in the auxiliary
/// data; a frame that kept its tag has 0x88A4 at offset 16), and nothing else.
const VLAN_ECAT_FILTER: [SockFilter; 8] = [
    // A = EtherType at offset 12.
    SockFilter {
        code: 0x28,
        jt: 0,
        jf: 0,
        k: 12,
    },
    // EtherCAT: accept (instruction 6).
    SockFilter {
        code: 0x15,
        jt: 4,
        jf: 0,
        k: ETHERTYPE_ETHERCAT as u32,
    },
    // 802.1Q or 802.1ad: look behind the tag (instruction 4); anything else: reject (7).
    SockFilter {
        code: 0x15,
        jt: 1,
        jf: 0,
        k: TPID_8021Q as u32,
    },
    SockFilter {
        code: 0x15,
        jt: 0,
        jf: 3,
        k: TPID_8021AD as u32,
    },
    // A = EtherType behind the tag.
    SockFilter {
        code: 0x28,
        jt: 0,
        jf: 0,
        k: 16,
    },
    SockFilter {
        code: 0x15,
        jt: 0,
        jf: 1,
        k: ETHERTYPE_ETHERCAT as u32,
    },
    // Accept the whole frame.
    SockFilter {
        code: 0x06,
        jt: 0,
        jf: 0,
        k: 0x0004_0000,
    },
    // Reject.
    SockFilter {
        code: 0x06,
        jt: 0,
        jf: 0,
        k: 0,
    },
];

/// An IEEE 802.1Q (or 802.1ad) VLAN tag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VlanTag {
    /// Tag protocol identifier: [`TPID_8021Q`] or [`TPID_8021AD`].
    pub tpid: u16,
    /// Tag control information: PCP (bits 15:13), DEI (bit 12), VID (bits 11:0).
    pub tci: u16,
}

impl VlanTag {
    /// VLAN identifier.
    pub const fn vid(self) -> u16 {
        self.tci & 0x0fff
    }

    /// Priority code point.
    pub const fn pcp(self) -> u8 {
        (self.tci >> 13) as u8
    }

    /// The 4 bytes of the tag as they stand in a frame after the source address.
    pub const fn to_bytes(self) -> [u8; 4] {
        let [a, b] = self.tpid.to_be_bytes();
        let [c, d] = self.tci.to_be_bytes();
        [a, b, c, d]
    }
}

/// Why a packet socket could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The interface name is not a valid Linux interface name.
    #[error("`{0}` is not a valid interface name (1 to 15 bytes, no NUL or '/')")]
    BadName(String),
    /// No interface of that name.
    #[error("interface {0} does not exist (`ip link` lists the interfaces)")]
    NoInterface(String),
    /// The process may not open raw sockets.
    #[error(
        "opening a raw socket on {0} needs CAP_NET_RAW: run as root, or grant it with `setcap cap_net_raw,cap_net_admin=eip <path to ecsync>`"
    )]
    Permission(String),
    /// Anything else the kernel refused.
    #[error("raw socket on {iface}: {what}: {source}")]
    Os {
        /// Interface.
        iface: String,
        /// The call that failed.
        what: &'static str,
        /// The error.
        source: io::Error,
    },
}

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
    /// The kernel's software transmit timestamps.
    pub fn software_tx(&self) -> bool {
        self.so_timestamping & SOF_TIMESTAMPING_TX_SOFTWARE != 0
    }

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
fn ioctl_socket() -> io::Result<OwnedFd> {
    // SAFETY: plain FFI call with constant arguments; the result is checked below.
    let raw = unsafe { libc::socket(libc::AF_INET, libc::SOCK_DGRAM | libc::SOCK_CLOEXEC, 0) };
    if raw < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `raw` is a new file descriptor that nothing else owns.
    Ok(unsafe { OwnedFd::from_raw_fd(raw) })
}

/// An interface ioctl whose `ifr_data` points at `data`.
fn ifreq_ioctl<T>(iface: &str, request: libc::c_ulong, data: &mut T) -> io::Result<()> {
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
    iface: String,
    tx_type: i32,
    rx_filter: i32,
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
    fd: OwnedFd,
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

/// One transmit timestamp message of the socket's error queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TxStamps {
    /// The kernel's software stamp, CLOCK_REALTIME ns.
    pub software_ns: Option<u64>,
    /// The NIC's hardware stamp, its PTP hardware clock's ns.
    pub hardware_ns: Option<u64>,
}

/// A frame received from a packet socket.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Received {
    /// Bytes of the frame (the buffer holds `min(len, buffer length)` of them).
    pub len: usize,
    /// Whether the frame was longer than the buffer.
    pub truncated: bool,
    /// The kernel's software receive timestamp, CLOCK_REALTIME ns.
    pub kernel_rx_realtime_ns: Option<u64>,
    /// The VLAN tag the kernel took off the frame before the socket saw it (only on sockets
    /// opened with [`PacketSocket::open_vlan_aware`]; a tag still in the bytes is not here).
    pub vlan: Option<VlanTag>,
}

/// An AF_PACKET socket bound to one interface that sends and receives EtherCAT frames
/// (EtherType 0x88A4) only, non-blocking, with the interface in promiscuous mode. The frames
/// the host sends itself are never received (`PACKET_IGNORE_OUTGOING`, and the packet type
/// `PACKET_OUTGOING` of the sender's address where a kernel lacks that option).
#[derive(Debug)]
pub struct PacketSocket {
    fd: OwnedFd,
    ifindex: libc::c_int,
    timestamps: TimestampSupport,
    promiscuous: bool,
    /// A send gave up waiting for room in the queue: the next ones try once, without
    /// waiting, until one goes out (a queue that stays full would otherwise cost a millisecond
    /// a frame, tens of them a cycle in a large network's exchange).
    queue_stuck: std::sync::atomic::AtomicBool,
}

fn timespec_ns(ts: &libc::timespec) -> Option<u64> {
    if ts.tv_sec == 0 && ts.tv_nsec == 0 {
        return None;
    }
    let s = u64::try_from(ts.tv_sec).ok()?;
    let n = u64::try_from(ts.tv_nsec).ok()?;
    s.checked_mul(1_000_000_000)?.checked_add(n)
}

/// Sets an integer-sized socket option.
fn setsockopt<T>(fd: &OwnedFd, level: libc::c_int, name: libc::c_int, value: &T) -> io::Result<()> {
    // SAFETY: `value` is a live reference to a `T` and its size is passed with it; the kernel
    // only reads that many bytes. The fd is open (owned by `fd`).
    let r = unsafe {
        libc::setsockopt(
            fd.as_raw_fd(),
            level,
            name,
            (value as *const T).cast(),
            size_of::<T>() as libc::socklen_t,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// What the control messages of a `recvmsg` result carry.
#[derive(Default)]
struct Control {
    /// The first software timestamp (SCM_TIMESTAMPING's first entry, or SCM_TIMESTAMPNS).
    timestamp: Option<u64>,
    /// The raw hardware timestamp (SCM_TIMESTAMPING's third entry), the PHC's time.
    hw_timestamp: Option<u64>,
    /// The VLAN tag of PACKET_AUXDATA, when the kernel marks it valid.
    vlan: Option<VlanTag>,
}

/// Walks the control messages of a `recvmsg` result.
fn control_messages(msg: &libc::msghdr) -> Control {
    let mut out = Control::default();
    // SAFETY: `msg` was filled by a successful recvmsg whose control buffer is still alive (the
    // caller keeps it on its stack); CMSG_FIRSTHDR/CMSG_NXTHDR only walk within
    // `msg_control..msg_control + msg_controllen`, and each header's data is read with an
    // unaligned read of exactly the size the kernel documents for its type after checking the
    // header's length.
    unsafe {
        let mut c = libc::CMSG_FIRSTHDR(msg);
        while !c.is_null() {
            let h = &*c;
            let data = libc::CMSG_DATA(c);
            let avail = (h.cmsg_len as usize).saturating_sub(libc::CMSG_LEN(0) as usize);
            if h.cmsg_level == libc::SOL_SOCKET && out.timestamp.is_none() {
                if h.cmsg_type == libc::SCM_TIMESTAMPING && avail >= 3 * size_of::<libc::timespec>()
                {
                    let ts: [libc::timespec; 3] = std::ptr::read_unaligned(data.cast());
                    out.timestamp = timespec_ns(&ts[0]);
                    out.hw_timestamp = timespec_ns(&ts[2]);
                } else if h.cmsg_type == libc::SCM_TIMESTAMPNS
                    && avail >= size_of::<libc::timespec>()
                {
                    let ts: libc::timespec = std::ptr::read_unaligned(data.cast());
                    out.timestamp = timespec_ns(&ts);
                }
            } else if h.cmsg_level == SOL_PACKET
                && h.cmsg_type == PACKET_AUXDATA
                && avail >= size_of::<TpacketAuxdata>()
            {
                let aux: TpacketAuxdata = std::ptr::read_unaligned(data.cast());
                if aux.tp_status & TP_STATUS_VLAN_VALID != 0 {
                    out.vlan = Some(VlanTag {
                        tpid: if aux.tp_status & TP_STATUS_VLAN_TPID_VALID != 0 {
                            aux.tp_vlan_tpid
                        } else {
                            TPID_8021Q
                        },
                        tci: aux.tp_vlan_tci,
                    });
                }
            }
            c = libc::CMSG_NXTHDR(msg, c);
        }
    }
    out
}

impl PacketSocket {
    /// Opens a socket on `iface` that sees EtherCAT frames (EtherType 0x88A4). A frame that
    /// arrived with a VLAN tag reaches it too, but without its tag and without word of it: the
    /// kernel takes the tag off and clears it before it hands a frame to sockets bound to one
    /// EtherType. [`PacketSocket::open_vlan_aware`] keeps it.
    pub fn open(iface: &str) -> Result<PacketSocket, OpenError> {
        Self::open_with(iface, false)
    }

    /// Opens a socket on `iface` that sees EtherCAT frames untagged and in one VLAN tag, and
    /// tells which tag each had ([`Received::vlan`] when the kernel took it off, as Linux does
    /// on receive whether or not the NIC offloads it; otherwise the tag is still in the bytes).
    /// It listens to every EtherType (the only way to see the tag, which the kernel reports to
    /// such sockets only) behind a BPF filter that lets EtherCAT frames through and nothing
    /// else, attached before the socket is bound so that nothing else is ever queued.
    pub fn open_vlan_aware(iface: &str) -> Result<PacketSocket, OpenError> {
        Self::open_with(iface, true)
    }

    fn open_with(iface: &str, vlan_aware: bool) -> Result<PacketSocket, OpenError> {
        if iface.is_empty() || iface.len() > 15 || iface.contains(['\0', '/']) {
            return Err(OpenError::BadName(iface.to_string()));
        }
        let os = |what, source| OpenError::Os {
            iface: iface.to_string(),
            what,
            source,
        };
        let name = CString::new(iface).map_err(|_| OpenError::BadName(iface.to_string()))?;
        // SAFETY: `name` is a NUL-terminated string that outlives the call.
        let ifindex = unsafe { libc::if_nametoindex(name.as_ptr()) };
        if ifindex == 0 {
            return Err(OpenError::NoInterface(iface.to_string()));
        }
        let ifindex = ifindex as libc::c_int;
        let ethertype = if vlan_aware {
            ETH_P_ALL
        } else {
            ETHERTYPE_ETHERCAT
        };
        // A VLAN-aware socket is created receiving nothing (protocol 0) and starts receiving
        // when it is bound, after its filter is attached.
        let proto = if vlan_aware {
            0
        } else {
            i32::from(ethertype.to_be())
        };
        // SAFETY: plain FFI call with constant arguments; the result is checked below.
        let raw = unsafe {
            libc::socket(
                libc::AF_PACKET,
                libc::SOCK_RAW | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
                proto,
            )
        };
        if raw < 0 {
            let e = io::Error::last_os_error();
            return Err(match e.raw_os_error() {
                Some(libc::EPERM) | Some(libc::EACCES) => OpenError::Permission(iface.to_string()),
                _ => os("socket(AF_PACKET)", e),
            });
        }
        // SAFETY: `raw` is a new file descriptor that nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        if vlan_aware {
            let prog = SockFprog {
                len: VLAN_ECAT_FILTER.len() as libc::c_ushort,
                filter: VLAN_ECAT_FILTER.as_ptr(),
            };
            // The kernel copies the program during the call; `VLAN_ECAT_FILTER` is a constant
            // that outlives it anyway.
            setsockopt(&fd, libc::SOL_SOCKET, SO_ATTACH_FILTER, &prog)
                .map_err(|e| os("attach the EtherCAT filter", e))?;
            setsockopt(&fd, SOL_PACKET, PACKET_AUXDATA, &1 as &libc::c_int)
                .map_err(|e| os("PACKET_AUXDATA", e))?;
        }

        // SAFETY: `sockaddr_ll` is a plain C struct for which all-zero bytes are valid.
        let mut addr: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        addr.sll_family = libc::AF_PACKET as u16;
        addr.sll_protocol = ethertype.to_be();
        addr.sll_ifindex = ifindex;
        // SAFETY: `addr` is a live, initialised sockaddr_ll and its size is passed with it.
        let r = unsafe {
            libc::bind(
                fd.as_raw_fd(),
                (&addr as *const libc::sockaddr_ll).cast(),
                size_of::<libc::sockaddr_ll>() as libc::socklen_t,
            )
        };
        if r < 0 {
            return Err(os("bind", io::Error::last_os_error()));
        }
        // Promiscuous: EtherCAT frames go to any destination address.
        let mreq = PacketMreq {
            mr_ifindex: ifindex,
            mr_type: PACKET_MR_PROMISC,
            mr_alen: 0,
            mr_address: [0; 8],
        };
        let promiscuous = setsockopt(&fd, SOL_PACKET, PACKET_ADD_MEMBERSHIP, &mreq).is_ok();
        // Our own frames are not to be read back (filtered by packet type as well, for
        // kernels before 4.20 that lack the option).
        let _ = setsockopt(&fd, SOL_PACKET, PACKET_IGNORE_OUTGOING, &1 as &libc::c_int);
        let flags: libc::c_uint = SOF_TIMESTAMPING_RX_SOFTWARE
            | SOF_TIMESTAMPING_TX_SOFTWARE
            | SOF_TIMESTAMPING_SOFTWARE
            | SOF_TIMESTAMPING_OPT_TSONLY;
        let timestamps = if setsockopt(&fd, libc::SOL_SOCKET, libc::SO_TIMESTAMPING, &flags).is_ok()
        {
            TimestampSupport {
                rx_software: true,
                tx_software: true,
                tx_hardware: false,
            }
        } else {
            TimestampSupport {
                rx_software: setsockopt(&fd, libc::SOL_SOCKET, libc::SO_TIMESTAMPNS, &1i32).is_ok(),
                tx_software: false,
                tx_hardware: false,
            }
        };
        Ok(PacketSocket {
            fd,
            ifindex,
            timestamps,
            promiscuous,
            queue_stuck: std::sync::atomic::AtomicBool::new(false),
        })
    }

    /// Interface index.
    pub fn ifindex(&self) -> i32 {
        self.ifindex
    }

    /// Which kernel timestamps the socket gets.
    pub fn timestamps(&self) -> TimestampSupport {
        self.timestamps
    }

    /// Whether the interface could be put into promiscuous mode.
    pub fn promiscuous(&self) -> bool {
        self.promiscuous
    }

    /// Sends one frame (as is: short frames are not padded). Waits up to a millisecond for
    /// room in the socket's queue; if there is still none (the interface lost its carrier and
    /// its queue stopped), the kernel's last refusal (EAGAIN or ENOBUFS) is returned, which
    /// [`link_is_down`] reads as a frame lost for now, never a reason to stop. After such a
    /// refusal the next sends do not wait until one goes out.
    pub fn send(&self, frame: &[u8]) -> io::Result<()> {
        use std::sync::atomic::Ordering::Relaxed;
        let wait_ns = if self.queue_stuck.load(Relaxed) {
            0
        } else {
            SEND_WAIT_NS
        };
        let give_up_ns = monotonic_ns() + wait_ns;
        loop {
            // SAFETY: `frame` is a live slice and its length is passed with it; the socket is
            // bound, so no destination address is needed.
            let r = unsafe {
                libc::send(
                    self.fd.as_raw_fd(),
                    frame.as_ptr().cast(),
                    frame.len(),
                    libc::MSG_DONTWAIT,
                )
            };
            if r >= 0 {
                self.queue_stuck.store(false, Relaxed);
                return if r as usize == frame.len() {
                    Ok(())
                } else {
                    Err(io::Error::other(format!(
                        "sent {r} of {} bytes",
                        frame.len()
                    )))
                };
            }
            let e = io::Error::last_os_error();
            match e.raw_os_error() {
                Some(code @ (libc::EAGAIN | libc::ENOBUFS)) => {
                    let now = monotonic_ns();
                    if now >= give_up_ns {
                        self.queue_stuck.store(true, Relaxed);
                        return Err(e);
                    }
                    if code == libc::EAGAIN {
                        // The socket's own queue is full: wait until it has room.
                        self.wait_writable(give_up_ns - now);
                    } else {
                        // The device refused the frame (its queue full, or a veth whose peer
                        // cannot take more): the socket reads writable all along, so polling
                        // would spin; try again a little later.
                        std::thread::sleep(std::time::Duration::from_nanos(
                            (give_up_ns - now).min(50_000),
                        ));
                    }
                }
                Some(libc::EINTR) => {}
                _ => return Err(e),
            }
        }
    }

    /// Receives one frame if one is waiting (`None` if none is); frames the host sent itself
    /// are skipped.
    pub fn recv(&self, buf: &mut [u8]) -> io::Result<Option<Received>> {
        loop {
            // SAFETY: all-zero bytes are valid for these plain C structs.
            let mut from: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
            let mut control = [0u64; 32];
            let mut iov = libc::iovec {
                iov_base: buf.as_mut_ptr().cast(),
                iov_len: buf.len(),
            };
            // SAFETY: as above.
            let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
            msg.msg_name = (&mut from as *mut libc::sockaddr_ll).cast();
            msg.msg_namelen = size_of::<libc::sockaddr_ll>() as libc::socklen_t;
            msg.msg_iov = &mut iov;
            msg.msg_iovlen = 1;
            msg.msg_control = control.as_mut_ptr().cast();
            msg.msg_controllen = size_of::<[u64; 32]>() as _;
            // SAFETY: every pointer in `msg` refers to a live local (`from`, `iov` -> `buf`,
            // `control`) with its length alongside; MSG_TRUNC makes the kernel return the
            // frame's full length without writing beyond `buf`.
            let r = unsafe {
                libc::recvmsg(
                    self.fd.as_raw_fd(),
                    &mut msg,
                    libc::MSG_DONTWAIT | libc::MSG_TRUNC,
                )
            };
            if r < 0 {
                let e = io::Error::last_os_error();
                return match e.raw_os_error() {
                    Some(libc::EAGAIN) => Ok(None),
                    Some(libc::EINTR) => continue,
                    _ => Err(e),
                };
            }
            // The host's own frames, looped back to packet sockets, are not received (on
            // kernels from 4.20 on, PACKET_IGNORE_OUTGOING keeps them away already).
            if from.sll_pkttype == PACKET_OUTGOING {
                continue;
            }
            let len = r as usize;
            let control = control_messages(&msg);
            return Ok(Some(Received {
                len: len.min(buf.len()),
                truncated: len > buf.len(),
                kernel_rx_realtime_ns: control.timestamp,
                vlan: control.vlan,
            }));
        }
    }

    /// Switches on the NIC's hardware transmit timestamps of `iface` (SIOCSHWTSTAMP,
    /// HWTSTAMP_TX_ON, its receive filter left as it was: a ptp4l on the interface keeps its
    /// receive stamps) and asks for them on this socket; the NIC's setting before is returned,
    /// to be put back ([`restore_hw_tx_stamps`]). With hardware stamps on, the kernel queues no
    /// software transmit stamp for the frames the NIC stamps. Refused with what is missing
    /// where the NIC has none (see [`NicTimestamping::hardware_missing`]).
    pub fn enable_hardware_tx_stamps(&mut self, iface: &str) -> io::Result<HwStampSetting> {
        let caps = nic_timestamping(iface)?;
        let missing = caps.hardware_missing();
        if !missing.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::Unsupported,
                format!(
                    "{iface} has no hardware transmit timestamps: its driver lacks {} (ethtool -T {iface})",
                    missing.join(", ")
                ),
            ));
        }
        // The setting as it is (a driver without SIOCGHWTSTAMP: stamping off).
        let mut before = HwtstampConfig {
            flags: 0,
            tx_type: 0,
            rx_filter: HWTSTAMP_FILTER_NONE,
        };
        if ifreq_ioctl(iface, SIOCGHWTSTAMP, &mut before).is_err() {
            before = HwtstampConfig {
                flags: 0,
                tx_type: 0,
                rx_filter: HWTSTAMP_FILTER_NONE,
            };
        }
        let mut cfg = HwtstampConfig {
            flags: 0,
            tx_type: HWTSTAMP_TX_ON,
            rx_filter: before.rx_filter,
        };
        ifreq_ioctl(iface, SIOCSHWTSTAMP, &mut cfg)?;
        let setting = HwStampSetting {
            iface: iface.to_string(),
            tx_type: before.tx_type,
            rx_filter: before.rx_filter,
        };
        let flags: libc::c_uint = SOF_TIMESTAMPING_RX_SOFTWARE
            | SOF_TIMESTAMPING_TX_SOFTWARE
            | SOF_TIMESTAMPING_SOFTWARE
            | SOF_TIMESTAMPING_TX_HARDWARE
            | SOF_TIMESTAMPING_RAW_HARDWARE
            | SOF_TIMESTAMPING_OPT_TSONLY;
        if let Err(e) = setsockopt(&self.fd, libc::SOL_SOCKET, libc::SO_TIMESTAMPING, &flags) {
            restore_hw_tx_stamps(&setting);
            return Err(e);
        }
        self.timestamps.tx_software = true;
        self.timestamps.tx_hardware = true;
        Ok(setting)
    }

    /// The kernel's software transmit timestamp of a frame sent earlier (CLOCK_REALTIME ns),
    /// if one is queued.
    pub fn take_tx_timestamp(&self) -> io::Result<Option<u64>> {
        Ok(self.take_tx_stamps()?.and_then(|s| s.software_ns))
    }

    /// The next transmit timestamp message queued for a frame sent earlier, if one is: the
    /// kernel's software stamp (CLOCK_REALTIME ns) and the NIC's (PHC ns), each if given. With
    /// hardware stamps on, the driver queues the two in separate messages.
    pub fn take_tx_stamps(&self) -> io::Result<Option<TxStamps>> {
        if !self.timestamps.tx_software {
            return Ok(None);
        }
        let mut data = [0u8; 64];
        let mut control = [0u64; 32];
        let mut iov = libc::iovec {
            iov_base: data.as_mut_ptr().cast(),
            iov_len: data.len(),
        };
        // SAFETY: all-zero bytes are valid for msghdr.
        let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
        msg.msg_iov = &mut iov;
        msg.msg_iovlen = 1;
        msg.msg_control = control.as_mut_ptr().cast();
        msg.msg_controllen = size_of::<[u64; 32]>() as _;
        // SAFETY: the pointers in `msg` refer to live locals with their lengths alongside.
        let r = unsafe {
            libc::recvmsg(
                self.fd.as_raw_fd(),
                &mut msg,
                libc::MSG_ERRQUEUE | libc::MSG_DONTWAIT,
            )
        };
        if r < 0 {
            let e = io::Error::last_os_error();
            return match e.raw_os_error() {
                Some(libc::EAGAIN) | Some(libc::EINTR) => Ok(None),
                _ => Err(e),
            };
        }
        let c = control_messages(&msg);
        Ok(Some(TxStamps {
            software_ns: c.timestamp,
            hardware_ns: c.hw_timestamp.filter(|_| self.timestamps.tx_hardware),
        }))
    }

    /// Waits until a frame can be read, a transmit timestamp is queued, or `timeout_ns` passed.
    pub fn wait(&self, timeout_ns: u64) -> io::Result<Ready> {
        let mut p = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ts = libc::timespec {
            tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
        };
        // SAFETY: `p` and `ts` are live locals; one pollfd is passed; no signal mask.
        let r = unsafe { libc::ppoll(&mut p, 1, &ts, std::ptr::null()) };
        if r < 0 {
            let e = io::Error::last_os_error();
            return if e.raw_os_error() == Some(libc::EINTR) {
                Ok(Ready::Nothing)
            } else {
                Err(e)
            };
        }
        Ok(if p.revents & libc::POLLIN != 0 {
            Ready::Frame
        } else if p.revents & libc::POLLERR != 0 {
            // The error queue holds a transmit timestamp: it must be read, or every poll
            // returns at once.
            Ready::ErrorQueue
        } else {
            Ready::Nothing
        })
    }

    /// Waits up to `timeout_ns` for room to send.
    fn wait_writable(&self, timeout_ns: u64) {
        let mut p = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLOUT,
            revents: 0,
        };
        let ts = libc::timespec {
            tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
        };
        // SAFETY: `p` and `ts` are live locals; one pollfd is passed; no signal mask.
        unsafe { libc::ppoll(&mut p, 1, &ts, std::ptr::null()) };
    }
}

/// How long [`PacketSocket::send`] waits for room in a full send queue, ns: a cycle's worth at
/// the shortest cycles; longer, and a master whose link is down would stall its cycle waiting.
const SEND_WAIT_NS: u64 = 1_000_000;

/// Whether an I/O error says the interface is down, gone or stalled for now (a cable pulled,
/// the peer's interface down, the veth peer's namespace being set up, a send queue that stayed
/// full): the frame is lost, and a master or a served segment goes on, as with any lost frame.
pub fn link_is_down(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::ENETDOWN)
            | Some(libc::ENXIO)
            | Some(libc::ENODEV)
            | Some(libc::ENOBUFS)
            | Some(libc::EAGAIN)
    )
}

/// What [`PacketSocket::wait`] saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ready {
    /// A frame can be read.
    Frame,
    /// The error queue holds something (a transmit timestamp): read it with
    /// [`PacketSocket::take_tx_timestamp`].
    ErrorQueue,
    /// The timeout passed (or a signal came).
    Nothing,
}

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = MaybeUninit::<libc::timespec>::uninit();
    // SAFETY: `ts` is a live, writable timespec; clock_gettime fills it on success, and the
    // clocks used here (CLOCK_MONOTONIC, CLOCK_REALTIME) always exist on Linux.
    let ts = unsafe {
        if libc::clock_gettime(clock, ts.as_mut_ptr()) != 0 {
            return 0;
        }
        ts.assume_init()
    };
    (ts.tv_sec as u64)
        .wrapping_mul(1_000_000_000)
        .wrapping_add(ts.tv_nsec as u64)
}

/// CLOCK_MONOTONIC now, ns.
pub fn monotonic_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// CLOCK_REALTIME now, ns since 1970.
pub fn realtime_ns() -> u64 {
    clock_ns(libc::CLOCK_REALTIME)
}

/// Sleeps until CLOCK_MONOTONIC reads `t_ns` (an absolute deadline, so that wake-ups do not
/// accumulate the latency of earlier ones). Returns at once if `t_ns` has passed.
pub fn sleep_until_monotonic(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a live timespec; no remaining-time output is requested (absolute).
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Switches the calling thread to SCHED_FIFO at `priority` (1-99).
pub fn set_fifo(priority: i32) -> io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: `param` is a live sched_param; pid 0 is the calling thread.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Locks the process's current and future memory (no page faults in the cycle).
pub fn lock_memory() -> io::Result<()> {
    // SAFETY: plain FFI call with constant flags.
    let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Pins the calling thread to CPU `cpu`.
pub fn pin_to_cpu(cpu: usize) -> io::Result<()> {
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(io::Error::new(io::ErrorKind::InvalidInput, "CPU index"));
    }
    // SAFETY: cpu_set_t is a plain bit array for which all-zero bytes are valid; CPU_SET is
    // given an index below CPU_SETSIZE (checked above); sched_setaffinity reads
    // size_of::<cpu_set_t>() bytes of the live `set`.
    let r = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set)
    };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Moves the calling thread into the network namespace `name` (as `ip netns` made it, under
/// /run/netns). Sockets opened afterwards by this thread live in that namespace.
pub fn enter_netns(name: &str) -> io::Result<()> {
    if name.is_empty() || name.contains(['/', '\0']) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "namespace name",
        ));
    }
    let f = std::fs::File::open(format!("/run/netns/{name}"))?;
    // SAFETY: `f` is an open file (kept alive across the call); setns only reads its fd.
    let r = unsafe { libc::setns(f.as_raw_fd(), libc::CLONE_NEWNET) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}
