//! EtherCAT on the wire: frame and datagram views and builders, the fifteen command codes,
//! working-counter rules, register addresses, typed views of the ESC's structured registers
//! (FMMU and SyncManager entries, AL control and status with the AL status code, DL status),
//! wrap-safe Distributed Clocks time arithmetic and the CiA data type codes.
//!
//! The style follows smoltcp's `wire` module: a packet is a typed view over a byte buffer
//! (`new_checked` validates, accessors read and write fields in place) and a builder emits
//! frames into a caller-provided buffer. Nothing here allocates, so the same code runs in a
//! `no_std` master, in the simulator's hot path and in a fuzzer.
//!
//! ```
//! use ecsync_wire::{Command, FrameBuilder, EcatFrame, DatagramAddress};
//!
//! let mut buf = [0u8; 128];
//! let mut b = FrameBuilder::new(&mut buf, [0xff; 6], [0x02, 0, 0, 0, 0, 1]).unwrap();
//! b.push(Command::Brd, 0x42, DatagramAddress::Position { adp: 0, ado: 0x0130 }, &[0, 0]).unwrap();
//! let len = b.finish();
//! let frame = EcatFrame::new_checked(&buf[..len]).unwrap();
//! let dg = frame.datagrams().next().unwrap().unwrap();
//! assert_eq!(dg.command(), Ok(Command::Brd));
//! assert_eq!(dg.index(), 0x42);
//! assert_eq!(dg.data(), &[0, 0]);
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod al;
mod builder;
mod command;
pub mod data_type;
mod datagram;
pub mod dc_time;
pub mod dl;
mod error;
pub mod fmmu;
mod frame;
pub mod mailbox;
pub mod register;
pub mod sii;
pub mod sync_manager;

pub use al::{
    AL_CONTROL_LEN, AL_STATUS_BLOCK_LEN, AL_STATUS_LEN, AlControl, AlControlRepr, AlState,
    AlStatus, AlStatusCode, AlStatusRepr,
};
pub use builder::FrameBuilder;
pub use command::{AddressMode, Command};
pub use datagram::{
    DATAGRAM_HEADER_LEN, DATAGRAM_OVERHEAD, Datagram, DatagramAddress, MAX_DATAGRAM_DATA, WKC_LEN,
    header_shape_key,
};
pub use dl::{DL_STATUS_LEN, DlStatus, DlStatusRepr, PortStatus};
pub use error::WireError;
pub use fmmu::{FMMU_ENTRY_LEN, Fmmu, FmmuRepr};
pub use frame::{
    DatagramIter, ECAT_HEADER_LEN, ECAT_TYPE_COMMANDS, ETH_HEADER_LEN, ETHERTYPE_ETHERCAT,
    EcatFrame, MAX_FRAME_LEN, MIN_FRAME_LEN, is_returned_frame, mark_returned_frame,
};
pub use sync_manager::{
    SM_ENTRY_LEN, SmActivate, SmBufferState, SmControl, SmDirection, SmMode, SmPdiControl,
    SmStatus, SyncManager, SyncManagerRepr,
};
