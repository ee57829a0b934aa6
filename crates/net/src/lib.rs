//! ecsync on a real network (Linux): the master engine of `ecsync-master` over an AF_PACKET raw
//! socket, in real time, and the virtual segment of `ecsync-esc` served on a network interface so
//! that any EtherCAT master can be tested against it without hardware.
//!
//! * [`sys`]: the only code that talks to the OS (sockets, kernel timestamps, clocks, real-time
//!   scheduling); everything else is safe.
//! * [`HostClock`]: the master's clock, CLOCK_MONOTONIC shifted to DC time (ns since 2000).
//! * [`RealLink`]: frames out and frames in with kernel timestamps, the real network's
//!   [`ecsync_master::Transport`]: the bring-up and the cyclic phase run over it with the same
//!   drivers as in the simulator ([`ecsync_master::driver`]).
//! * [`serve`]: the virtual segment answering on an interface.
//! * [`rt`]: SCHED_FIFO, mlockall and CPU affinity when permitted, with a report of what was not.
//!
//! This crate holds what the architecture first placed in `ecsync-master` as its "Linux raw
//! socket transport": keeping it apart leaves `ecsync-master` sans-IO and free of `unsafe`.
#![deny(unsafe_code)]
#![warn(missing_docs)]
#![cfg(target_os = "linux")]

mod link;
pub mod rt;
pub mod serve;
pub mod sys;

pub use link::{HostClock, NetError, RealLink};
