//! The AF_PACKET socket on EtherType 0x88A4: frames out and in with the kernel's (or the NIC's)
//! timestamps, VLAN-tagged EtherCAT kept by a socket filter.

#![allow(unsafe_code)]

use super::nic::ifreq_ioctl;
use super::*;
use std::ffi::CString;
use std::io;
use std::mem::size_of;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

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
    pub(super) fd: OwnedFd,
    pub(super) ifindex: libc::c_int,
    pub(super) timestamps: TimestampSupport,
    pub(super) promiscuous: bool,
    /// A send gave up waiting for room in the queue: the next ones try once, without
    /// waiting, until one goes out (a queue that stays full would otherwise cost a millisecond
    /// a frame, tens of them a cycle in a large network's exchange).
    pub(super) queue_stuck: std::sync::atomic::AtomicBool,
}

pub(super) fn timespec_ns(ts: &libc::timespec) -> Option<u64> {
    if ts.tv_sec == 0 && ts.tv_nsec == 0 {
        return None;
    }
    let s = u64::try_from(ts.tv_sec).ok()?;
    let n = u64::try_from(ts.tv_nsec).ok()?;
    s.checked_mul(1_000_000_000)?.checked_add(n)
}

/// Sets an integer-sized socket option.
pub(super) fn setsockopt<T>(
    fd: &OwnedFd,
    level: libc::c_int,
    name: libc::c_int,
    value: &T,
) -> io::Result<()> {
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
pub(super) struct Control {
    /// The first software timestamp (SCM_TIMESTAMPING's first entry, or SCM_TIMESTAMPNS).
    pub(super) timestamp: Option<u64>,
    /// The raw hardware timestamp (SCM_TIMESTAMPING's third entry), the PHC's time.
    pub(super) hw_timestamp: Option<u64>,
    /// The VLAN tag of PACKET_AUXDATA, when the kernel marks it valid.
    pub(super) vlan: Option<VlanTag>,
}

/// Walks the control messages of a `recvmsg` result.
pub(super) fn control_messages(msg: &libc::msghdr) -> Control {
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

    pub(super) fn open_with(iface: &str, vlan_aware: bool) -> Result<PacketSocket, OpenError> {
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
        Ok(wait_any([Some(self), None], timeout_ns)?[0])
    }

    /// Waits up to `timeout_ns` for room to send.
    pub(super) fn wait_writable(&self, timeout_ns: u64) {
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
pub(super) const SEND_WAIT_NS: u64 = 1_000_000;

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

/// Waits up to `timeout_ns` for a frame (or a transmit timestamp) on either socket: what each
/// one has (two sockets in one wait: the two ports of a ring's master, or of a served ring).
pub fn wait_any(socks: [Option<&PacketSocket>; 2], timeout_ns: u64) -> io::Result<[Ready; 2]> {
    let fd = |s: Option<&PacketSocket>| s.map_or(-1, |s| s.fd.as_raw_fd());
    // A negative fd is ignored by poll: one socket waits alone.
    let mut p = socks.map(|s| libc::pollfd {
        fd: fd(s),
        events: libc::POLLIN,
        revents: 0,
    });
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: `p` and `ts` are live locals; two pollfds are passed; no signal mask.
    let r = unsafe { libc::ppoll(p.as_mut_ptr(), 2, &ts, std::ptr::null()) };
    if r < 0 {
        let e = io::Error::last_os_error();
        return if e.raw_os_error() == Some(libc::EINTR) {
            Ok([Ready::Nothing; 2])
        } else {
            Err(e)
        };
    }
    Ok(p.map(|p| {
        if p.revents & libc::POLLIN != 0 {
            Ready::Frame
        } else if p.revents & libc::POLLERR != 0 {
            // The error queue holds a transmit timestamp: it must be read, or every poll
            // returns at once.
            Ready::ErrorQueue
        } else {
            Ready::Nothing
        }
    }))
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
