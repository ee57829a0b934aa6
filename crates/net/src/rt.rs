//! Real-time settings for the cyclic task: SCHED_FIFO, locked memory, a CPU of its own. Each is
//! tried; what the system refuses is reported with what to do about it, and the run goes on.

use crate::sys;

/// What the process got.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize)]
pub struct RtReport {
    /// SCHED_FIFO priority, if granted.
    pub fifo_priority: Option<i32>,
    /// Whether all memory is locked.
    pub memory_locked: bool,
    /// The CPU the task is pinned to, if pinned.
    pub cpu: Option<usize>,
    /// Whether the kernel is PREEMPT_RT.
    pub preempt_rt: bool,
    /// One line per setting not granted, with what to do.
    pub warnings: Vec<String>,
}

/// Whether the running kernel is PREEMPT_RT (/sys/kernel/realtime reads 1).
pub fn kernel_is_preempt_rt() -> bool {
    std::fs::read_to_string("/sys/kernel/realtime")
        .map(|s| s.trim() == "1")
        .unwrap_or(false)
}

/// Which CPU to run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pin {
    /// Leave it to the scheduler.
    No,
    /// The last CPU (where `isolcpus` usually puts the real-time core).
    Last,
    /// This one.
    Cpu(usize),
}

/// Applies the settings to the calling thread (and locks the process's memory): SCHED_FIFO at
/// `priority` (0: leave the policy alone), and the CPU.
pub fn setup(priority: i32, pin: Pin) -> RtReport {
    let mut r = RtReport {
        preempt_rt: kernel_is_preempt_rt(),
        ..RtReport::default()
    };
    if priority > 0 {
        match sys::set_fifo(priority) {
            Ok(()) => r.fifo_priority = Some(priority),
            Err(e) => r.warnings.push(format!(
                "SCHED_FIFO priority {priority} not granted ({e}): the real-time thread runs at normal priority; run as root or give the user an rtprio limit in /etc/security/limits.conf"
            )),
        }
    }
    match sys::lock_memory() {
        Ok(()) => r.memory_locked = true,
        Err(e) => r.warnings.push(format!(
            "memory not locked ({e}): page faults may delay cycles; run as root or raise the memlock limit (ulimit -l)"
        )),
    }
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let want = match pin {
        Pin::No => None,
        Pin::Last => Some(cpus.saturating_sub(1)),
        Pin::Cpu(c) => Some(c),
    };
    if let Some(want) = want {
        match sys::pin_to_cpu(want) {
            Ok(()) => r.cpu = Some(want),
            Err(e) => r.warnings.push(format!(
                "not pinned to CPU {want} ({e}): the scheduler may move the task between cores"
            )),
        }
    }
    if !r.preempt_rt {
        r.warnings.push(
            "the kernel is not PREEMPT_RT (/sys/kernel/realtime): expect tens of microseconds of wake-up latency and rare millisecond outliers".to_string(),
        );
    }
    r
}
