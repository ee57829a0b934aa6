//! Distributed Clocks math for EtherCAT masters: the segment's tree and propagation delays from
//! port receive times, system time offsets, SYNC0 start times and lock detection.
//!
//! `no_std` and allocation-free: every function works on slices the caller owns, so it runs in
//! a microcontroller master as well as in the simulator.
//!
//! The master synchronization methods ([`sync`], [`dcm`]) are named once, in the
//! [`registry`]; [`method`] holds their parameters with defaults and [`Method`], which runs any
//! of them. With the `serde` feature the parameters deserialize from a scenario's
//! `[methods.<name>]` tables.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod dcm;
pub mod lock;
pub mod method;
pub mod offset;
pub mod registry;
pub mod sync;
pub mod topology;

pub use dcm::{Dcm, DcmMode, DcmParams, SetValueRef};
pub use lock::LockDetector;
pub use method::{Method, MethodContext, MethodParams, ParamError};
pub use offset::{sync0_start_time, system_time_offset};
pub use registry::MethodKind;
pub use sync::{
    BusShift, ControllerLog, CycleInput, CycleOutput, MasterSync, MedianFit, MedianSync, PiM2s,
    ReferenceWrite, Snap, SoemPi,
};
pub use topology::{
    SlavePorts, TopologyError, TreeNode, arrival_times, build_tree, master_delay_ns,
    propagation_delays,
};
