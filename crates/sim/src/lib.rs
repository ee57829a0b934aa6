//! The virtual EtherCAT segment and everything simulated around a master: ESCs faithful to the
//! ESC datasheet (Beckhoff, "EtherCAT Slave Controller Hardware Data Sheet", sections I and II)
//! with four ports, the processing order 0 -> processing unit -> 3 -> 1 -> 2, loop-back of closed
//! ports, per-hop and cable delays, the datasheet's working-counter rules, FMMUs and
//! SyncManagers, an SII EEPROM, the AL state machine, and a Distributed Clocks unit whose clock
//! is evaluated analytically between events; device models and ESI files; the fault schedule;
//! the master host's noise ([`host`], [`send`]) and its recorded traces ([`host_trace`]); the
//! simulated transport and master clock ([`transport`]); pcap capture.
//!
//! It depends on `ecsync-master` for the [`ecsync_master::Transport`] trait it implements, never
//! the other way round, and on nothing that measures or reports (that is `ecsync-lab`).
//!
//! A broadcast read through a line of three slaves:
//!
//! ```
//! use ecsync_sim::{preset, Segment};
//! use ecsync_wire::{Command, DatagramAddress, EcatFrame, FrameBuilder};
//!
//! let mut seg = Segment::new(&preset::line(3, 1)).unwrap();
//! let mut buf = [0u8; 64];
//! let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0; 6]).unwrap();
//! b.push_zeroed(Command::Brd, 0, DatagramAddress::Position { adp: 0, ado: 0x0000 }, 1).unwrap();
//! let n = b.finish();
//! let out = seg.process(&mut buf[..n], 0);
//! assert!(out.returned_sof_ps.is_some());
//! let f = EcatFrame::new_checked(&buf[..n]).unwrap();
//! assert_eq!(f.datagrams().next().unwrap().unwrap().wkc(), 3, "three slaves counted");
//! ```
//!
//! The master engine's bring-up of the same line up to lock, in virtual time:
//!
//! ```
//! use ecsync_sim::{Segment, preset};
//! use ecsync_sim::transport::SimTransport;
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
pub mod catalog;
pub mod clock;
pub mod coe;
pub mod config;
pub mod dc_unit;
mod esc;
pub mod esi;
pub mod fault;
pub mod host;
pub mod host_fit;
pub mod host_trace;
pub mod model;
pub mod pcap;
pub mod phy;
pub mod preset;
pub mod rng;
mod segment;
pub mod send;
pub mod sii_image;
pub mod transport;
pub mod twin;

pub use esc::{AnswerBufferHabit, DatagramEffects, Esc, EscStats, LoopMode};
pub use phy::{BYTE_TIME_PS, CABLE_PS_PER_M, frame_wire_time_ps};
pub use segment::{
    FrameOutcome, FrameTrace, RingCable, Segment, SlaveSpec, TopologyError, Upstream,
    frame_is_processable,
};
