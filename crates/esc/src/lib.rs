//! A virtual EtherCAT segment faithful to the ESC datasheet (Beckhoff, "EtherCAT Slave Controller
//! Hardware Data Sheet", sections I and II): ESCs with four ports, the processing order
//! 0 -> processing unit -> 3 -> 1 -> 2, loop-back of closed ports, per-hop and cable delays,
//! the datasheet's working-counter rules, FMMUs and SyncManagers, an SII EEPROM, the AL state
//! machine, and a Distributed Clocks unit whose clock is evaluated analytically between events.
//!
//! ```
//! use ecsync_esc::{preset, Segment};
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
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod clock;
pub mod coe;
pub mod config;
pub mod dc_unit;
mod esc;
pub mod esi;
pub mod fault;
pub mod model;
pub mod pcap;
pub mod preset;
pub mod rng;
mod segment;
pub mod sii_image;

pub use esc::{DatagramEffects, Esc, EscStats, LoopMode};
pub use segment::{
    BYTE_TIME_PS, CABLE_PS_PER_M, FrameOutcome, FrameTrace, Segment, SlaveSpec, TopologyError,
    Upstream, frame_is_processable, frame_wire_time_ps,
};
