//! The one module of ecsync that talks to the operating system: AF_PACKET sockets, kernel
//! timestamps, clocks, sleeping, real-time scheduling, memory locking, CPU affinity and network
//! namespaces. Everything else is safe Rust on top of the small API below.
//!
//! Every `unsafe` block is a single FFI call (or the parsing of what it returned) and says why it
//! is sound. The invariants are always the same few: pointers come from live Rust references or
//! buffers whose length is passed alongside, structures are plain C structs zero-initialised
//! before the kernel fills them, and file descriptors are owned by an [`OwnedFd`](std::os::fd::OwnedFd) from the moment
//! the kernel hands them out.
#![allow(unsafe_code)]

use std::io;

mod nic;
mod process;
pub mod sandbox;
mod socket;

pub use nic::{
    HwStampSetting, NicTimestamping, Phc, TimestampSupport, nic_timestamping, restore_hw_tx_stamps,
    set_interface_up,
};
pub use process::{
    enter_netns, lock_memory, monotonic_ns, pin_to_cpu, realtime_ns, set_fifo, set_timer_slack_ns,
    sleep_until_monotonic, try_lock_exclusive,
};
pub use socket::{PacketSocket, Ready, Received, TxStamps, link_is_down, wait_any};

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
