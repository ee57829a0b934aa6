//! ecsync on a real network (Linux): the master engine of `ecsync-master` over an AF_PACKET raw
//! socket, in real time, and the virtual segment of `ecsync-sim` served on a network interface so
//! that any EtherCAT master can be tested against it without hardware.
//!
//! * [`sys`]: the only code that talks to the OS (sockets, kernel timestamps, clocks, real-time
//!   scheduling); everything else is safe.
//! * [`HostClock`]: the master's clock, CLOCK_MONOTONIC shifted to DC time (ns since 2000).
//! * [`RealLink`]: frames out and frames in with kernel timestamps, the real network's
//!   [`ecsync_master::Transport`]: the bring-up and the cyclic phase run over it with the same
//!   drivers as in the simulator ([`ecsync_master::driver`]).
//! * [`serve`]: the virtual segment answering on an interface.
//! * [`host_record`]: the timing of this host's periodic loop, cycle by cycle (`ecsync host record`).
//! * [`wall_clock`]: kernel stamps (CLOCK_REALTIME) onto the monotonic clock, minding steps
//!   of the wall clock.
//! * [`rt`]: SCHED_FIFO, mlockall and CPU affinity when permitted, with a report of what was not.
//!
//! This crate holds what the architecture first placed in `ecsync-master` as its "Linux raw
//! socket transport": keeping it apart leaves `ecsync-master` sans-IO and free of `unsafe`.
//!
//! The master's clock needs neither root nor a network interface:
//!
//! ```
//! use ecsync_net::{HostClock, NetError, RealLink};
//! use std::time::{SystemTime, UNIX_EPOCH};
//!
//! let clock = HostClock::new();
//! let t0 = clock.now_ns();
//! // DC time counts ns since 2000-01-01: the wall clock less 946 684 800 s.
//! let wall_ns = SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_nanos() as u64;
//! assert!((wall_ns - 946_684_800_000_000_000).abs_diff(t0) < 100_000_000, "within 100 ms");
//! // It is CLOCK_MONOTONIC shifted once: steady, and mapped back onto it for sleeping.
//! let mono = ecsync_net::sys::monotonic_ns();
//! let t1 = clock.now_ns();
//! assert!(t1 >= t0);
//! assert!(clock.to_monotonic_ns(t1) - mono < 100_000_000);
//!
//! // A raw socket on an interface that does not exist (or without CAP_NET_RAW) is refused.
//! assert!(matches!(RealLink::open("ecsync-none0"), Err(NetError::Open(_))));
//! ```
#![deny(unsafe_code)]
#![warn(missing_docs)]
#![cfg(target_os = "linux")]

pub mod host_record;
mod link;
pub mod rt;
pub mod serve;
pub mod sys;
pub mod tx_stamp;
pub mod txtime;
pub mod wall_clock;

pub use link::{HostClock, NetError, RealLink, SendControl};
