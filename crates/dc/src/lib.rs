//! Distributed Clocks math for EtherCAT masters: the segment's tree and propagation delays from
//! port receive times, system time offsets, SYNC0 start times and lock detection.
//!
//! `no_std` and allocation-free: every function works on slices the caller owns, so it runs in
//! a microcontroller master as well as in the simulator.
//!
//! The master synchronization methods ([`sync`], [`dcm`], [`masters`], [`estimate`]) are named once, in the
//! [`registry`]; [`method`] holds their parameters with defaults and [`Method`], which runs any
//! of them. With the `serde` feature the parameters deserialize from a scenario's
//! `[methods.<name>]` tables.
//!
//! ```
//! use ecsync_dc::sync::CycleInput;
//! use ecsync_dc::time::{MasterInstant, SystemTime};
//! use ecsync_dc::{MasterSync, MethodContext, MethodKind, MethodParams};
//!
//! // `snap`, what ethercrab ships, at a 1 ms cycle aiming at the grid point itself.
//! let kind: MethodKind = "snap".parse().unwrap();
//! let ctx = MethodContext { cycle_ns: 1_000_000, target_phase_ns: 0 };
//! let mut method = MethodParams::default().build(kind, &ctx);
//! assert!(method.is_master_shift());
//!
//! // The frame sent at 10 ms (master time) read the reference's system time 300 us past one of
//! // its grid points: the method waits from the send to the next grid point, 700 us.
//! let out = method.update(&CycleInput {
//!     cycle: 0,
//!     period_ns: 1_000_000,
//!     nominal_start: MasterInstant::from_ns(10_000_000),
//!     scheduled_start: MasterInstant::from_ns(10_000_000),
//!     send: MasterInstant::from_ns(10_000_000),
//!     receive: MasterInstant::from_ns(10_020_000),
//!     ref_time: Some(SystemTime::from_ns(5_000_300_000)),
//! });
//! assert_eq!(out.error_ns, 300_000);
//! assert_eq!(out.next_start.as_ns(), 10_700_000);
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod dcm;
pub mod estimate;
pub mod fit;
pub mod lock;
pub mod masters;
pub mod method;
pub mod offset;
pub mod registry;
pub mod sync;
pub mod time;
pub mod topology;

pub use dcm::{Dcm, DcmMode, DcmParams, SetValueRef};
pub use estimate::{Des, Kalman};
pub use lock::LockDetector;
pub use masters::{IghAppTime, KickcatPll, LinuxcncPll};
pub use method::{Method, MethodContext, MethodParams, ParamError};
pub use offset::{sync0_start_time, system_time_offset};
pub use registry::MethodKind;
pub use sync::{
    BusShift, ControllerLog, CycleInput, CycleOutput, MasterSync, MedianFit, MedianSync, PiM2s,
    ReferenceWrite, Snap, SoemPi, WriteTimes,
};
pub use topology::{
    SlavePorts, TopologyError, TreeNode, arrival_times, build_tree, master_delay_ns,
    propagation_delays,
};
