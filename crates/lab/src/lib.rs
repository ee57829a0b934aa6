//! The lab: scenarios (network + host + run), the host's noise, runs of every master
//! synchronization method on the virtual segment with common random numbers, statistics against
//! the letter's Table 1 and against ground truth, and the report.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod compare;
pub mod host;
pub mod letter;
pub mod plots;
pub mod report;
pub mod run;
pub mod scenario;
pub mod tsn;

/// The statistics live in ecsync-master, where the real master's `ecsync run` uses them too
/// without the simulator; the lab's modules keep naming them `crate::stats`.
pub use ecsync_master::stats;

pub use compare::{Comparison, compare};
pub use scenario::{Scenario, parse};
