//! A sans-IO EtherCAT master engine: the DC bring-up (scan, SII identity, topology, propagation
//! delays, offsets, static drift compensation, SYNC0, state machine), the cyclic phase and the
//! recovery from faults, written once as `async` procedures over a [`Link`] and driven by a
//! [`Transport`] that does the I/O: the virtual segment in virtual time (`ecsync-sim`), a raw
//! socket on a real network (`ecsync-net`), the TSN bridge (`ecsync-tsn`).
//!
//! It owns the engine, the drivers ([`driver`], [`cyclic`]) and the `Transport` trait; it depends
//! on the wire format (`ecsync-wire`) and the DC algorithms (`ecsync-dc`) only, never on a
//! simulator: a master on real hardware takes nothing of the virtual segment with it.
//!
//! The engine does no I/O of its own: it says what it needs ([`Action`]) and is told what
//! happened. Driven by hand with no slave on the wire (every frame lost), the bring-up gives up
//! at the scan and says which exchange went unanswered:
//!
//! ```
//! use ecsync_dc::time::{MasterDuration, MasterInstant};
//! use ecsync_master::{Action, BringupConfig, Engine, MasterError, Phase, bringup};
//!
//! let mut engine = Engine::new(|link| bringup(link, BringupConfig::default()));
//! let mut now = MasterInstant::from_ns(0);
//! let mut frames = 0;
//! let result = loop {
//!     match engine.poll(now) {
//!         Action::Send(frame) => {
//!             // An EtherCAT frame (EtherType 0x88A4) that nobody answers.
//!             assert_eq!(frame[12..14], [0x88, 0xa4]);
//!             frames += 1;
//!             now = now.saturating_add(MasterDuration::from_ms(1));
//!             engine.handle_lost();
//!         }
//!         Action::SendAll(_) => engine.handle_lost(),
//!         Action::WaitUntil(t) => now = t,
//!         Action::Done(result) => break result,
//!     }
//! };
//! assert!(frames > 0);
//! // The scan's first broadcast read, counting the slaves, was lost.
//! let e = result.unwrap_err();
//! assert_eq!(e.phase(), Some(Phase::Scan));
//! assert!(matches!(e.root(), MasterError::FrameLost { what: "count slaves", .. }), "{e}");
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bringup;
pub mod coe;
pub mod cyclic;
pub mod driver;
mod error;
pub mod io;
pub mod network;
pub mod pdi;
pub mod recovery;
pub mod redundancy;
pub mod sii;
pub mod transport;

pub use bringup::{
    BringupConfig, BringupTimeouts, Network, Phase, SlaveId, SlaveInfo, Stage, bringup,
};
pub use error::MasterError;
pub use io::{Action, Engine, Event, Link};
pub use transport::{Received, Transport};
