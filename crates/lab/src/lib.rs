//! The lab: scenarios (network + host + run); the one session loop ([`session`]) that every
//! cyclic phase runs on, with typed observers; runs of every master synchronization method on
//! the virtual segment with common random numbers (the host's noise drawn once per run),
//! statistics against the letter's Table 1 and against ground truth, the verdict, the report and
//! its plots, output files written atomically; `ecsync run`'s session on a real network as a
//! library function (`realnet`, Linux); the TSN study. The top of the library stack: it depends
//! on the simulator, the engine and (on Linux) the real network, and nothing but the binary
//! depends on it.
//!
//! The built-in scenario (the letter's testbed, `paper-2024`) parsed and checked, and a value it
//! cannot run with refused with the field and the fix:
//!
//! ```
//! use ecsync_dc::MethodKind;
//! use ecsync_sim::preset::PAPER_2024_TOML;
//!
//! let s = ecsync_lab::parse("paper-2024.toml", PAPER_2024_TOML).unwrap();
//! assert_eq!(s.slaves.len(), 6);
//! assert_eq!(s.cycle_ns, 1_000_000);
//! assert_eq!((s.runs, s.cycles, s.seed), (5, 1_800_000, 2024));
//! assert_eq!(s.methods, MethodKind::DEFAULT);
//! assert!(s.is_letter_testbed());
//!
//! let bad = PAPER_2024_TOML.replace("cycle_us = 1000", "cycle_us = 0.5");
//! let e = ecsync_lab::parse("bad.toml", &bad).unwrap_err();
//! assert_eq!(e.field, "run.cycle_us");
//! assert!(e.line.is_some() && !e.fix.is_empty());
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod compare;
mod html;
pub mod judge;
pub mod letter;
pub mod output;
pub mod plots;
#[cfg(target_os = "linux")]
pub mod realnet;
pub mod report;
pub mod run;
pub mod scenario;
pub mod session;
pub mod stats;
pub mod sweep_report;
pub mod tsn;

pub use compare::{Comparison, compare};
pub use scenario::{Scenario, parse};
