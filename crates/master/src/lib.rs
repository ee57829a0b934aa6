//! A sans-IO EtherCAT master engine: the DC bring-up (scan, SII identity, topology, propagation
//! delays, offsets, static drift compensation, SYNC0, state machine) written once as `async`
//! procedures over a [`Link`], and run by transports that do the I/O: [`sim::SimTransport`]
//! against the virtual segment in virtual time, a raw socket on a real network. What a run of
//! the cyclic phase measures is summarised by [`stats`] (the simulator's lab and the real
//! master alike) and written by [`output`].
//!
//! The bring-up of a line of three simulated slaves up to lock, in virtual time:
//!
//! ```
//! use ecsync_esc::{Segment, preset};
//! use ecsync_master::sim::SimTransport;
//! use ecsync_master::{BringupConfig, Engine, Stage, bringup};
//!
//! let mut sim = SimTransport::new(Segment::new(&preset::line(3, 1)).unwrap());
//! let cfg = BringupConfig {
//!     until: Stage::Lock,
//!     static_drift_frames: 2_000,
//!     lock_hold_checks: 5,
//!     ..BringupConfig::default()
//! };
//! let mut engine = Engine::new(move |link| bringup(link, cfg));
//! let net = sim.run_procedure(&mut engine, |_, _, _| {}).expect("bring-up");
//!
//! assert_eq!(net.slaves.len(), 3);
//! assert_eq!(net.reference, 0);
//! // The measured propagation delays agree with the segment's ground truth within 20 ns.
//! let truth = sim.segment().true_delays_ns(usize::from(net.reference));
//! for s in &net.slaves {
//!     let t = truth[usize::from(s.position)].unwrap();
//!     assert!((s.delay_ns.unwrap() - t).abs() <= 20.0);
//! }
//! assert!(net.lock.converged);
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bench;
pub mod bringup;
pub mod coe;
pub mod cyclic;
pub mod driver;
mod error;
pub mod io;
pub mod output;
pub mod pdi;
pub mod recovery;
pub mod sii;
pub mod sim;
pub mod stats;
pub mod transport;
pub mod twin;

pub use bringup::{
    BringupConfig, BringupTimeouts, Network, Phase, SlaveId, SlaveInfo, Stage, bringup,
};
pub use error::MasterError;
pub use io::{Action, Engine, Event, Link};
pub use transport::{Received, Transport};
