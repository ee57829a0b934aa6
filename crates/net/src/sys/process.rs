//! The process and its clocks: monotonic and real time, sleeping to an absolute instant,
//! SCHED_FIFO, locked memory, CPU affinity, entering a network namespace.

#![allow(unsafe_code)]

use std::io;
use std::mem::{MaybeUninit, size_of};
use std::os::fd::AsRawFd;

pub(super) fn clock_ns(clock: libc::clockid_t) -> u64 {
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

/// Sets the calling thread's timer slack, ns (PR_SET_TIMERSLACK): how late the kernel may
/// wake a sleep or a poll's timeout to batch wake-ups (50 us by default for normal threads,
/// none under SCHED_FIFO). A server that paces its replies to the microsecond asks for 1 ns.
pub fn set_timer_slack_ns(ns: u64) -> io::Result<()> {
    // SAFETY: plain prctl with integer arguments.
    let r = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, ns.max(1) as libc::c_ulong, 0, 0, 0) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Takes `file`'s exclusive advisory lock (flock) if no other open file holds it: `Ok(false)`
/// when one does. The lock lasts as long as the file stays open, and the kernel drops it when
/// the process ends however it ends: no stale lock outlives its holder.
pub fn try_lock_exclusive(file: &std::fs::File) -> io::Result<bool> {
    // SAFETY: plain FFI call on a descriptor `file` owns and keeps open for the call.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}
