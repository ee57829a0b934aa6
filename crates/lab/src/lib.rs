//! The lab: scenarios (network + host + run), the host's noise, runs of every master
//! synchronization method on the virtual segment with common random numbers, statistics against
//! the letter's Table 1 and against ground truth, and the report.
#![forbid(unsafe_code)]

pub mod compare;
pub mod host;
pub mod letter;
pub mod plots;
pub mod report;
pub mod run;
pub mod scenario;
pub mod stats;
pub mod tsn;

pub use compare::{Comparison, compare};
pub use scenario::{Scenario, parse};
