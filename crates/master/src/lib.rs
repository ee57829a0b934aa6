//! A sans-IO EtherCAT master engine: the DC bring-up (scan, SII identity, topology, propagation
//! delays, offsets, static drift compensation, SYNC0, state machine) written once as `async`
//! procedures over a [`Link`], and run by transports that do the I/O: [`sim::SimTransport`]
//! against the virtual segment in virtual time, a raw socket on a real network. What a run of
//! the cyclic phase measures is summarised by [`stats`] (the simulator's lab and the real
//! master alike) and written by [`output`].
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bench;
pub mod bringup;
pub mod cyclic;
pub mod driver;
mod error;
pub mod io;
pub mod output;
pub mod pdi;
pub mod sii;
pub mod sim;
pub mod stats;
pub mod transport;

pub use bringup::{
    BringupConfig, BringupTimeouts, Network, Phase, SlaveId, SlaveInfo, Stage, bringup,
};
pub use error::MasterError;
pub use io::{Action, Engine, Event, Link};
pub use transport::{Received, Transport};
