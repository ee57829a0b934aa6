//! A private network for `ecsync serve --sandbox`: the process moves into a network namespace
//! of its own (inside a user namespace of its own when it lacks the privilege, as `unshare -rn`
//! does, so that no root and no capability from outside is needed), brings `lo` up and makes a
//! veth pair there by rtnetlink (no `ip` command needed); the child it later spawns inherits
//! the namespaces. Also: the termination signals recorded (which one, and whether a terminal
//! sent it) so that they can be forwarded to the child, the child's scheduling reset, and the
//! terminal lent to the child's process group while it runs.

#![allow(unsafe_code)]

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::process::CommandExt;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicPtr, Ordering};
use std::time::{Duration, Instant};

// include/uapi/linux/netlink.h, rtnetlink.h, if_link.h, veth.h, if.h.
const NETLINK_ROUTE: libc::c_int = 0;
const NLMSG_ERROR: u16 = 2;
const NLM_F_REQUEST: u16 = 0x1;
const NLM_F_ACK: u16 = 0x4;
const NLM_F_EXCL: u16 = 0x200;
const NLM_F_CREATE: u16 = 0x400;
const RTM_NEWLINK: u16 = 16;
const RTM_GETLINK: u16 = 18;
const IFLA_IFNAME: u16 = 3;
const IFLA_OPERSTATE: u16 = 16;
const IFLA_LINKINFO: u16 = 18;
const IFLA_INFO_KIND: u16 = 1;
const IFLA_INFO_DATA: u16 = 2;
const VETH_INFO_PEER: u16 = 1;
const IFF_UP: u32 = 0x1;
const IF_OPER_UP: u8 = 6;
const NLMSG_HDRLEN: usize = 16;
const IFINFOMSG_LEN: usize = 16;
/// `si_code` of a signal the kernel sent (a terminal's Ctrl-C to its foreground group).
const SI_KERNEL: libc::c_int = 0x80;

/// What [`enter`] set up.
#[derive(Debug, Clone)]
pub struct Sandbox {
    /// Whether a user namespace was needed (the process lacked CAP_SYS_ADMIN): inside it the
    /// process is root of its own namespaces only (no SCHED_FIFO).
    pub user_namespace: bool,
    /// Why /sys shows the host's network devices and not the namespace's (mounting a sysfs of
    /// the namespace failed), if it does.
    pub sysfs_warning: Option<String>,
}

/// Moves the (single-threaded) process into a network namespace of its own, with a mount
/// namespace in which /sys is the new network's, and a user namespace mapping the caller to
/// root where the caller cannot make a network namespace otherwise; then brings `lo` up, makes
/// each veth pair `a`-`b` of `pairs` and sets both ends up, returning once all are
/// operationally up.
pub fn enter(pairs: &[(&str, &str)]) -> io::Result<Sandbox> {
    let threads = std::fs::read_dir("/proc/self/task")?.count();
    if threads != 1 {
        return Err(io::Error::other(format!(
            "the process runs {threads} threads; a namespace can only be entered while it runs one (an internal error of ecsync)"
        )));
    }
    // SAFETY: plain FFI calls without pointers.
    let (uid, gid) = unsafe { (libc::geteuid(), libc::getegid()) };
    // SAFETY: unshare takes flags only; the process is single-threaded (checked above).
    let user_namespace = if unsafe { libc::unshare(libc::CLONE_NEWNET | libc::CLONE_NEWNS) } == 0 {
        false
    } else {
        let flags = libc::CLONE_NEWUSER | libc::CLONE_NEWNET | libc::CLONE_NEWNS;
        // SAFETY: as above.
        if unsafe { libc::unshare(flags) } != 0 {
            let e = io::Error::last_os_error();
            return Err(io::Error::new(
                e.kind(),
                format!(
                    "cannot make a user and network namespace ({e}): unprivileged user namespaces are refused here (sysctl user.max_user_namespaces, kernel.unprivileged_userns_clone, AppArmor's kernel.apparmor_restrict_unprivileged_userns, or a container's seccomp profile); run as root or allow them"
                ),
            ));
        }
        let write = |f: &str, s: String| {
            std::fs::write(format!("/proc/self/{f}"), s)
                .map_err(|e| io::Error::new(e.kind(), format!("writing /proc/self/{f}: {e}")))
        };
        write("setgroups", "deny".into())?;
        write("uid_map", format!("0 {uid} 1"))?;
        write("gid_map", format!("0 {gid} 1"))?;
        true
    };
    let sysfs_warning = mount_sysfs().err().map(|e| {
        format!("/sys shows the host's network devices, not the sandbox's (mounting a sysfs failed: {e})")
    });
    let mut nl = Netlink::open()?;
    nl.set_up("lo")?;
    for &(a, b) in pairs {
        nl.add_veth(a, b).map_err(|e| {
            io::Error::new(e.kind(), format!("creating the veth pair {a}/{b}: {e}"))
        })?;
        nl.set_up(a)?;
        nl.set_up(b)?;
    }
    let t0 = Instant::now();
    for &(a, b) in pairs {
        while nl.operstate(a)? != IF_OPER_UP || nl.operstate(b)? != IF_OPER_UP {
            if t0.elapsed() > Duration::from_secs(5) {
                return Err(io::Error::other(format!(
                    "the veth pair {a}/{b} is not up after 5 s"
                )));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    Ok(Sandbox {
        user_namespace,
        sysfs_warning,
    })
}

/// Makes every mount of the new mount namespace private (nothing done here reaches the host's)
/// and mounts a sysfs of the new network namespace on /sys.
fn mount_sysfs() -> io::Result<()> {
    let c = |s: &str| std::ffi::CString::new(s).expect("no NUL");
    let (root, sys, sysfs) = (c("/"), c("/sys"), c("sysfs"));
    let flags = libc::MS_REC | libc::MS_PRIVATE;
    // SAFETY: the strings are live NUL-terminated C strings; null type and data are allowed for
    // a propagation change.
    let r = unsafe {
        libc::mount(
            std::ptr::null(),
            root.as_ptr(),
            std::ptr::null(),
            flags,
            std::ptr::null(),
        )
    };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: as above; sysfs takes no data.
    let r = unsafe {
        libc::mount(
            sysfs.as_ptr(),
            sys.as_ptr(),
            sysfs.as_ptr(),
            0,
            std::ptr::null(),
        )
    };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// A NETLINK_ROUTE socket and the sequence number of its next request.
struct Netlink {
    fd: OwnedFd,
    seq: u32,
}

/// Appends attribute `ty` with `data` (padded to 4 bytes).
fn attr(buf: &mut Vec<u8>, ty: u16, data: &[u8]) {
    buf.extend_from_slice(&((4 + data.len()) as u16).to_ne_bytes());
    buf.extend_from_slice(&ty.to_ne_bytes());
    buf.extend_from_slice(data);
    buf.resize(buf.len().next_multiple_of(4), 0);
}

/// Appends nested attribute `ty` whose content `f` appends.
fn nest(buf: &mut Vec<u8>, ty: u16, f: impl FnOnce(&mut Vec<u8>)) {
    let at = buf.len();
    buf.extend_from_slice(&[0, 0]);
    buf.extend_from_slice(&ty.to_ne_bytes());
    f(buf);
    let len = (buf.len() - at) as u16;
    buf[at..at + 2].copy_from_slice(&len.to_ne_bytes());
}

/// A `struct ifinfomsg` (AF_UNSPEC, no index: the device is named by IFLA_IFNAME).
fn ifinfomsg(flags: u32, change: u32) -> [u8; IFINFOMSG_LEN] {
    let mut m = [0u8; IFINFOMSG_LEN];
    m[8..12].copy_from_slice(&flags.to_ne_bytes());
    m[12..16].copy_from_slice(&change.to_ne_bytes());
    m
}

/// An interface name as IFLA_IFNAME carries it (NUL-terminated).
fn ifname(name: &str) -> io::Result<Vec<u8>> {
    if name.is_empty() || name.len() >= libc::IFNAMSIZ || name.contains(['/', '\0', ' ']) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("\"{name}\" is not an interface name (1 to 15 characters, no '/' or space)"),
        ));
    }
    let mut v = name.as_bytes().to_vec();
    v.push(0);
    Ok(v)
}

impl Netlink {
    fn open() -> io::Result<Netlink> {
        // SAFETY: plain FFI call; the descriptor is owned from here on.
        let fd = unsafe {
            libc::socket(
                libc::AF_NETLINK,
                libc::SOCK_RAW | libc::SOCK_CLOEXEC,
                NETLINK_ROUTE,
            )
        };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` was just returned by socket() and is owned by nobody else.
        let fd = unsafe { OwnedFd::from_raw_fd(fd) };
        let tv = libc::timeval {
            tv_sec: 5,
            tv_usec: 0,
        };
        // SAFETY: `tv` is a live timeval whose size is passed.
        unsafe {
            libc::setsockopt(
                fd.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_RCVTIMEO,
                (&tv as *const libc::timeval).cast(),
                size_of::<libc::timeval>() as libc::socklen_t,
            );
        }
        Ok(Netlink { fd, seq: 0 })
    }

    /// Sends request `ty` with `body` and returns the kernel's first answer to it (its type
    /// and bytes after the header); an error answer is returned as the error it carries.
    fn request(&mut self, ty: u16, flags: u16, body: &[u8]) -> io::Result<(u16, Vec<u8>)> {
        self.seq += 1;
        let mut msg = Vec::with_capacity(NLMSG_HDRLEN + body.len());
        msg.extend_from_slice(&((NLMSG_HDRLEN + body.len()) as u32).to_ne_bytes());
        msg.extend_from_slice(&ty.to_ne_bytes());
        msg.extend_from_slice(&(flags | NLM_F_REQUEST).to_ne_bytes());
        msg.extend_from_slice(&self.seq.to_ne_bytes());
        msg.extend_from_slice(&0u32.to_ne_bytes());
        msg.extend_from_slice(body);
        // SAFETY: all-zero bytes are a valid sockaddr_nl (the kernel as destination: pid 0).
        let mut dst: libc::sockaddr_nl = unsafe { std::mem::zeroed() };
        dst.nl_family = libc::AF_NETLINK as libc::sa_family_t;
        // SAFETY: `msg` and `dst` are live for the call, their lengths passed alongside.
        let n = unsafe {
            libc::sendto(
                self.fd.as_raw_fd(),
                msg.as_ptr().cast(),
                msg.len(),
                0,
                (&dst as *const libc::sockaddr_nl).cast(),
                size_of::<libc::sockaddr_nl>() as libc::socklen_t,
            )
        };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        let mut buf = vec![0u8; 16384];
        loop {
            // SAFETY: `buf` is a live, writable buffer whose length is passed.
            let n =
                unsafe { libc::recv(self.fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len(), 0) };
            if n < 0 {
                return Err(io::Error::last_os_error());
            }
            let mut at = 0;
            while at + NLMSG_HDRLEN <= n as usize {
                let h = &buf[at..];
                let len = u32::from_ne_bytes(h[0..4].try_into().unwrap()) as usize;
                let mty = u16::from_ne_bytes(h[4..6].try_into().unwrap());
                let seq = u32::from_ne_bytes(h[8..12].try_into().unwrap());
                if len < NLMSG_HDRLEN || at + len > n as usize {
                    break;
                }
                if seq == self.seq {
                    let payload = h[NLMSG_HDRLEN..len].to_vec();
                    if mty == NLMSG_ERROR && payload.len() >= 4 {
                        let err = i32::from_ne_bytes(payload[0..4].try_into().unwrap());
                        if err != 0 {
                            return Err(io::Error::from_raw_os_error(-err));
                        }
                    }
                    return Ok((mty, payload));
                }
                at += len.next_multiple_of(4);
            }
        }
    }

    /// Sets interface `name` up.
    fn set_up(&mut self, name: &str) -> io::Result<()> {
        let mut body = ifinfomsg(IFF_UP, IFF_UP).to_vec();
        attr(&mut body, IFLA_IFNAME, &ifname(name)?);
        self.request(RTM_NEWLINK, NLM_F_ACK, &body)
            .map(|_| ())
            .map_err(|e| io::Error::new(e.kind(), format!("setting {name} up: {e}")))
    }

    /// Makes the veth pair `a`-`b`.
    fn add_veth(&mut self, a: &str, b: &str) -> io::Result<()> {
        let (a, b) = (ifname(a)?, ifname(b)?);
        let mut body = ifinfomsg(0, 0).to_vec();
        attr(&mut body, IFLA_IFNAME, &a);
        nest(&mut body, IFLA_LINKINFO, |li| {
            attr(li, IFLA_INFO_KIND, b"veth");
            nest(li, IFLA_INFO_DATA, |d| {
                nest(d, VETH_INFO_PEER, |p| {
                    p.extend_from_slice(&ifinfomsg(0, 0));
                    attr(p, IFLA_IFNAME, &b);
                });
            });
        });
        let flags = NLM_F_ACK | NLM_F_CREATE | NLM_F_EXCL;
        self.request(RTM_NEWLINK, flags, &body).map(|_| ())
    }

    /// The operational state of interface `name` (IF_OPER_*; 0, unknown, if not reported).
    fn operstate(&mut self, name: &str) -> io::Result<u8> {
        let mut body = ifinfomsg(0, 0).to_vec();
        attr(&mut body, IFLA_IFNAME, &ifname(name)?);
        let (_, reply) = self.request(RTM_GETLINK, 0, &body)?;
        let mut at = IFINFOMSG_LEN;
        while at + 4 <= reply.len() {
            let len = u16::from_ne_bytes([reply[at], reply[at + 1]]) as usize;
            let ty = u16::from_ne_bytes([reply[at + 2], reply[at + 3]]) & 0x3fff;
            if len < 4 || at + len > reply.len() {
                break;
            }
            if ty == IFLA_OPERSTATE && len >= 5 {
                return Ok(reply[at + 4]);
            }
            at += len.next_multiple_of(4);
        }
        Ok(0)
    }
}

/// The stop flag the termination signals raise, and the last one caught (0: none) with its
/// `si_code`.
static STOP_FLAG: AtomicPtr<AtomicBool> = AtomicPtr::new(std::ptr::null_mut());
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);
static LAST_CODE: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int, info: *mut libc::siginfo_t, _: *mut libc::c_void) {
    // SAFETY: the kernel passes a valid siginfo to an SA_SIGINFO handler; only atomics are
    // touched (async-signal-safe).
    let code = if info.is_null() {
        0
    } else {
        unsafe { (*info).si_code }
    };
    LAST_CODE.store(code, Ordering::Relaxed);
    LAST_SIGNAL.store(sig, Ordering::Relaxed);
    let flag = STOP_FLAG.load(Ordering::Relaxed);
    if !flag.is_null() {
        // SAFETY: the pointer came from a `&'static AtomicBool`.
        unsafe { (*flag).store(true, Ordering::Relaxed) };
    }
}

/// From now on SIGINT, SIGTERM and SIGHUP raise `stop` and are recorded (replacing any
/// earlier handler of theirs), for [`stop_signal`].
pub fn catch_termination_signals(stop: &'static AtomicBool) -> io::Result<()> {
    STOP_FLAG.store((stop as *const AtomicBool).cast_mut(), Ordering::Relaxed);
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: all-zero bytes are a valid sigaction; the handler is an extern "C" function
        // of the SA_SIGINFO signature; the mask is emptied by sigemptyset on a live set.
        let r = unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as *const () as usize;
            sa.sa_flags = libc::SA_SIGINFO | libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut())
        };
        if r != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

/// The last termination signal caught, and whether the kernel sent it (a terminal's Ctrl-C,
/// which reached the whole foreground process group: a child in it has it already) rather
/// than a process (`kill`).
pub fn stop_signal() -> Option<(i32, bool)> {
    match LAST_SIGNAL.load(Ordering::Relaxed) {
        0 => None,
        s => Some((s, LAST_CODE.load(Ordering::Relaxed) == SI_KERNEL)),
    }
}

/// Sends `sig` to process `pid`.
pub fn send_signal(pid: u32, sig: i32) -> io::Result<()> {
    // SAFETY: plain FFI call.
    if unsafe { libc::kill(pid as libc::pid_t, sig) } == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Sends `sig` to every process of the process group `pgid`.
pub fn signal_group(pgid: u32, sig: i32) -> io::Result<()> {
    // SAFETY: plain FFI call; a negative pid names a process group.
    if unsafe { libc::kill(-(pgid as libc::pid_t), sig) } == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Whether stdin is this process's controlling terminal and this process's group its
/// foreground group: the terminal is this process's to lend to a child ([`TerminalLoan`]).
/// Not so with stdin a file or a pipe, nor for a process started in the background (`&`).
pub fn owns_foreground_terminal() -> bool {
    // SAFETY: plain FFI calls that only inspect descriptor 0 (tcgetpgrp fails with ENOTTY on a
    // terminal that is not this process's controlling one).
    unsafe { libc::isatty(0) == 1 && libc::tcgetpgrp(0) == libc::getpgrp() }
}

/// The terminal on stdin lent to a child's process group ([`plain_child`] gives it to the
/// group before the child runs its program, so that the child never reads it from the
/// background and stops with SIGTTIN). While it lives SIGTTOU is ignored by this process:
/// taking the terminal back from the background is allowed then, and a status line this
/// process writes to the terminal does not stop it on a terminal with `tostop` set. Dropped,
/// it takes the terminal back for this process's group and restores SIGTTOU's disposition.
pub struct TerminalLoan {
    previous_ttou: libc::sigaction,
}

impl TerminalLoan {
    /// Starts a loan (to be given to [`plain_child`]); only where
    /// [`owns_foreground_terminal`].
    pub fn begin() -> io::Result<TerminalLoan> {
        // SAFETY: all-zero bytes are a valid sigaction; both structures are live for the call.
        unsafe {
            let mut ignore: libc::sigaction = std::mem::zeroed();
            ignore.sa_sigaction = libc::SIG_IGN;
            libc::sigemptyset(&mut ignore.sa_mask);
            let mut previous_ttou: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(libc::SIGTTOU, &ignore, &mut previous_ttou) != 0 {
                return Err(io::Error::last_os_error());
            }
            Ok(TerminalLoan { previous_ttou })
        }
    }

    /// Whether SIGTTOU was ignored before the loan (a child then keeps it ignored, as it
    /// would have inherited it).
    fn ttou_was_ignored(&self) -> bool {
        self.previous_ttou.sa_sigaction == libc::SIG_IGN
    }
}

impl Drop for TerminalLoan {
    fn drop(&mut self) {
        // SAFETY: plain FFI calls on descriptor 0 and this process's group; SIGTTOU is still
        // ignored by the first, so that it is allowed from the background; the sigaction
        // restored is the one the kernel gave back in `begin`.
        unsafe {
            libc::tcsetpgrp(0, libc::getpgrp());
            libc::sigaction(libc::SIGTTOU, &self.previous_ttou, std::ptr::null_mut());
        }
    }
}

/// Makes `cmd`'s process start at normal scheduling (not this thread's SCHED_FIFO), lead a
/// process group of its own (its pid is the group's id: [`signal_group`] reaches it and what
/// it started, a shell's children too), and be sent SIGTERM should this process die without
/// stopping it. With `terminal`, its group is made the foreground group of the terminal on
/// stdin before it runs its program (and SIGTTOU, which the loan ignores, made default again
/// unless it was ignored before).
pub fn plain_child(cmd: &mut Command, terminal: Option<&TerminalLoan>) {
    let lend = terminal.is_some();
    let keep_ttou_ignored = terminal.is_some_and(TerminalLoan::ttou_was_ignored);
    // SAFETY: the closure runs in the forked child before exec and calls only
    // async-signal-safe functions (sched_setscheduler, setpgid, prctl, tcsetpgrp, signal) on
    // values it owns.
    unsafe {
        cmd.pre_exec(move || {
            let p = libc::sched_param { sched_priority: 0 };
            libc::sched_setscheduler(0, libc::SCHED_OTHER, &p);
            if libc::setpgid(0, 0) != 0 {
                return Err(io::Error::last_os_error());
            }
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong);
            if lend {
                // From the background (the new group): allowed, SIGTTOU being ignored (the
                // loan's disposition, inherited). A failure leaves the child as it was before
                // terminals were lent: it runs, and reading the terminal stops it.
                libc::tcsetpgrp(0, libc::getpid());
                if !keep_ttou_ignored {
                    libc::signal(libc::SIGTTOU, libc::SIG_DFL);
                }
            }
            Ok(())
        });
    }
}
