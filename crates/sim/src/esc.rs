//! One virtual EtherCAT slave controller: its memory, register semantics, working-counter rules,
//! FMMUs, SyncManagers, SII EEPROM interface, AL state machine and DC unit.
//!
//! Datagrams are processed by [`Esc::process_datagram`] when a frame passes the processing unit.
//! Nothing here allocates after construction.
//!
//! Deviation from the silicon, kept on purpose: register writes take effect immediately rather
//! than at the end of a frame with a good FCS (a read later in the same frame sees the new value),
//! because frames here are never corrupted on the wire. Side effects that the datasheet places at
//! the end of the frame (DC compare, EEPROM command) use the frame's SOF time, which gives the
//! same result.
//!
//! The ESC is split by responsibility, one module each:
//! - [`registers`]: the register file (which bytes exist and which the EtherCAT side may write),
//!   physical reads and writes and their side effects, DL control and DL status;
//! - [`al`]: the AL state machine (AL control, AL status, AL status code);
//! - [`sii`]: the SII EEPROM interface and its busy time;
//! - [`mailbox`]: the mailbox SyncManagers and the CoE server behind them;
//! - [`process_data`]: FMMUs, SyncManagers, logical addressing and the loopback application;
//! - [`datagram`]: datagram processing (address modes, working counters), one datagram at a
//!   time, every datagram decoded: the plain path;
//! - [`watchdog`]: the process data watchdog and its expiry;
//! - [`sync`]: the drive's application in time (the SYNC0 deadline, SM events missed).
//!
//! Apart from the ESC, the speed: [`fast`], the fast path, repeats what a frame of the same
//! shape did instead of decoding it again, with the same bytes and times as the plain path
//! (its contract: the equivalence tests, `tests/replay_equivalence.rs`). The ESC holds its
//! program slots and notes, in [`recorder`], what the plain path did for it to record.

mod al;
mod cia402;
mod datagram;
mod fast;
mod mailbox;
mod process_data;
mod recorder;
mod registers;
mod sii;
mod sm_status;
mod sync;
#[cfg(test)]
mod sync1_tests;
mod watchdog;

use crate::dc_unit::{DC_BLOCK_LEN, DcParams, DcUnit};
use crate::model::{DcSupport, DeviceInfo, EscModel};
use crate::{clock::CrystalParams, sii_image};
use ecsync_wire::register::{self as reg, MAX_FMMUS, MAX_SYNC_MANAGERS};
use ecsync_wire::{AlState, AlStatusCode};
use process_data::{AppLayout, FmmuMapping, SmBuffer};
use recorder::Recorder;
use registers::REG_SPACE;
use sii::SiiState;

pub use datagram::DatagramEffects;
pub(crate) use fast::{Deferred, MAX_PROGRAM_DATAGRAMS, PlannedSteps};
pub use registers::LoopMode;
pub use sm_status::AnswerBufferHabit;

/// FMMUs and SyncManagers an ESC has at most (the register map's room).
const FMMUS: usize = MAX_FMMUS as usize;
const SMS: usize = MAX_SYNC_MANAGERS as usize;

/// Counters of what an ESC saw, for diagnostics and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EscStats {
    /// Frames that passed the processing unit.
    pub frames: u64,
    /// Datagrams that addressed this ESC (changed the working counter).
    pub datagrams_counted: u64,
    /// Frames whose datagrams were replayed from a recorded program.
    pub replayed_frames: u64,
}

/// Aligns the ESC to a cache line: its hot fields come first (see [`Esc`]).
#[derive(Debug, Clone, Copy, Default)]
#[repr(align(64))]
struct CacheLine;

/// A virtual ESC.
///
/// Laid out by hand (`repr(C)`), by cache line: what a replayed cyclic frame reads and
/// updates first (the generation, the watchdog's check, the fast path's slot keys and replay
/// counters and the flags on line 0; the process RAM and the application on lines 1-2; the
/// SYNC0 check on line 3; the DC unit's three hot lines on 5-7), then the fast path's program
/// look-up and straight-through steps (a large network's visit plans copy them once), then
/// the cold parts. In a network of
/// hundreds of drives every ESC's state has left the cache by its next frame, and the cost of
/// a visit is the lines it touches.
///
/// The large cold parts (the recorded programs, FMMUs, SyncManagers, the device description;
/// the clock's random generator) are boxed: an ESC is 1.3 KiB instead of 4.3, so that a large
/// network's ESCs, visited in order, lie close together (at 1 000 drives a slave-cycle costs
/// about 13 % less, measured side by side; the README's "Speed"). Each program's op count
/// and counted datagrams stay with the look-up (`fast::Slots`).
#[derive(Debug, Clone)]
#[repr(C)]
pub struct Esc {
    _align: [CacheLine; 0],
    // Line 0: what every visit of a cyclic frame reads and updates (the generation its
    // program was recorded in, the watchdog's check, the counters and flags).
    /// Bumped by every change that could make a datagram act differently (register writes,
    /// state changes); a recorded program is valid only for the generation it was recorded in.
    generation: u64,
    /// The process data watchdog's time while armed (OP, outputs triggering it), ps; 0: off.
    wd_period_ps: u64,
    /// The last write of the outputs, ps.
    wd_last_write_ps: u64,
    /// The fast path's part of line 0: each program slot's shape, replays not yet counted and
    /// whether it writes the outputs.
    slot_keys: fast::SlotKeys,
    al_state: AlState,
    /// The frame being processed wrote the outputs (the SYNC0 deadline is checked at its
    /// end).
    sync_pending: bool,
    /// The outputs were written by the datagram being processed.
    pd_written: bool,
    /// The application takes its outputs at SYNC1, not SYNC0 (0x1C32:01 = 3, as an
    /// oversampling terminal runs: see `sync.rs`).
    sync1_mode: bool,
    // Lines 1-2: the process RAM and the application.
    ram: Box<[u8]>,
    app: Option<AppLayout>,
    app_mem: process_data::AppMemory,
    // Lines 3-4: the SYNC0 deadline's bookkeeping (what the outputs' check uses on line 3).
    _align_sync: [CacheLine; 0],
    sync: sync::SyncMonitor,
    // Lines 5-7: the DC unit's hot lines (its registers, its time control loop, its
    // clock's hot part), its cold part after.
    _align_dc: [CacheLine; 0],
    dc: Option<DcUnit>,
    // The fast path's program look-up and straight-through steps, which a large network's
    // visit plans read once, when they are made (a small network's frames read them every
    // time, from the L1 cache).
    _align_slots: [CacheLine; 0],
    slots: fast::Slots,
    // Cold: what the full path and the bring-up use.
    model: EscModel,
    regs: Box<[u8; REG_SPACE]>,
    attr: Box<[u8; REG_SPACE]>,
    dc_block: Box<[u8; DC_BLOCK_LEN]>,
    sii: SiiState,
    al_error: bool,
    al_code: AlStatusCode,
    /// An AL control write the firmware has not taken yet: when it takes it, ps, and the
    /// value written.
    al_pending: Option<(u64, u16)>,
    fmmus: Box<[FmmuMapping; FMMUS]>,
    /// Indices of active FMMUs with write / read enabled, lowest first.
    fmmu_writers: ([u8; FMMUS], u8),
    fmmu_readers: ([u8; FMMUS], u8),
    sms: Box<[SmBuffer; SMS]>,
    link: [bool; 4],
    loop_mode: [LoopMode; 4],
    output_sm: Option<usize>,
    input_sm: Option<usize>,
    stats: EscStats,
    device: Box<DeviceInfo>,
    /// What the plain path noted of the datagram being processed, for the fast path.
    rec: Recorder,
    /// The mailbox and its CoE server (a device with a mailbox); boxed, it is rarely used.
    mbx: Option<Box<mailbox::MailboxState>>,
    /// The mailbox SyncManagers' status bits besides "full".
    sm_status: sm_status::MailboxStatusBits,
    /// Where the last counting of missed SM events ended (ground truth: `sync.rs`).
    sync_end: sync::SyncEnd,
}

// The hot lines as laid out above (a field added to a hot line must fit it): a large
// network's visits read lines 0-3 and 5-7, consecutive (the adjacent-line prefetch brings
// pairs).
const _: () = {
    use core::mem::offset_of;
    assert!(offset_of!(Esc, ram) == 64);
    assert!(offset_of!(Esc, app_mem) + size_of::<process_data::AppMemory>() <= 192);
    assert!(offset_of!(Esc, sync) == 192);
    assert!(offset_of!(Esc, dc) == 320);
    // (The DC unit's lines begin at the option's: no tag before them.)
    assert!(size_of::<Option<DcUnit>>() == size_of::<DcUnit>());
};

impl Esc {
    /// Powers up an ESC: loads the SII image (identity, alias, pulse length) and starts its clock.
    pub fn new(model: EscModel, device: DeviceInfo, crystal: CrystalParams) -> Self {
        Self::new_at(model, device, crystal, 0)
    }

    /// Powers up an ESC at real time `t_ps` (its clock reads the crystal's `initial_local_ns`
    /// then).
    pub fn new_at(model: EscModel, device: DeviceInfo, crystal: CrystalParams, t_ps: u64) -> Self {
        let image = sii_image::build(&model, &device);
        let mbx = device.mailbox.map(|mut l| {
            // A device family's own response time (the application's) over the device's.
            l.response_ns = model.mailbox_response_ns.unwrap_or(l.response_ns);
            Box::new(mailbox::MailboxState::new(
                l,
                crate::coe::SdoServer::new(&device),
            ))
        });
        let mut esc = Esc {
            _align_sync: [],
            _align_dc: [],
            _align_slots: [],
            regs: Box::new([0; REG_SPACE]),
            attr: Box::new([0; REG_SPACE]),
            ram: vec![0; usize::from(model.ram_kib) * 1024].into_boxed_slice(),
            dc: model.dc.has_receive_times().then(|| {
                DcUnit::new_at(
                    DcParams {
                        crystal,
                        is_64bit: model.dc == DcSupport::Full64,
                        sof_resolution_ns: model.ports[0].stamp_resolution_ns(),
                    },
                    t_ps,
                )
            }),
            dc_block: Box::new([0; DC_BLOCK_LEN]),
            sii: SiiState::new(image, model.sii_read_busy_us),
            al_state: AlState::Init,
            al_error: false,
            al_code: AlStatusCode::NoError,
            al_pending: None,
            fmmus: Box::new([FmmuMapping::default(); FMMUS]),
            fmmu_writers: ([0; FMMUS], 0),
            fmmu_readers: ([0; FMMUS], 0),
            sms: Box::new([SmBuffer::default(); SMS]),
            link: [false; 4],
            loop_mode: [LoopMode::Auto; 4],
            output_sm: None,
            input_sm: None,
            app: None,
            app_mem: process_data::AppMemory::default(),
            stats: EscStats::default(),
            model,
            device: Box::new(device),
            generation: 0,
            slot_keys: fast::SlotKeys::new(),
            slots: fast::Slots::new(),
            _align: [],
            rec: Recorder::default(),
            mbx,
            wd_period_ps: 0,
            wd_last_write_ps: 0,
            pd_written: false,
            sync_pending: false,
            sync1_mode: false,
            sync: sync::SyncMonitor::default(),
            sm_status: sm_status::MailboxStatusBits::default(),
            sync_end: sync::SyncEnd::default(),
        };
        esc.sync.pll_limit_ns = esc.device.pll_limit_ns;
        esc.build_attributes();
        esc.reset_registers();
        esc
    }

    /// This ESC switched off and on again at real time `t_ps`: registers at their reset
    /// values, AL Init, process RAM cleared, its clock started again from 0 at `t_ps` (the
    /// same crystal; its wander goes on from another seed), the SII EEPROM's contents kept;
    /// the links are the segment's to set.
    pub fn power_cycled(&self, t_ps: u64) -> Esc {
        let crystal = self.dc.as_ref().map_or_else(CrystalParams::default, |dc| {
            let mut c = *dc.clock().params();
            c.initial_local_ns = 0;
            c.seed = crate::rng::SplitMix64(c.seed ^ t_ps).next();
            c
        });
        let mut esc = Esc::new_at(self.model.clone(), (*self.device).clone(), crystal, t_ps);
        esc.sii = self.sii.clone();
        esc.sii.power_up();
        esc.set_answer_buffer_habit(self.answer_buffer_habit());
        esc.sync.powered_up_after(&self.sync);
        esc
    }

    /// Puts `image` into this ESC's SII EEPROM in place of the one built from its description
    /// (a real device's EEPROM: a dump, or the words a capture read) and loads it as at power-up
    /// (the registers at their reset values, the words the ESC takes from the EEPROM then:
    /// PDI control, PDI configuration, SYNC pulse length, station alias). Meant for an ESC that
    /// has not seen a frame yet; a power cycle keeps the image, as it keeps any EEPROM's.
    pub fn load_sii_image(&mut self, image: Vec<u8>) {
        self.generation += 1;
        self.sii = SiiState::new(image, self.model.sii_read_busy_us);
        self.reset_registers();
    }

    /// The ESC model.
    pub fn model(&self) -> &EscModel {
        &self.model
    }

    /// The device description.
    pub fn device(&self) -> &DeviceInfo {
        &self.device
    }

    /// The SII image.
    pub fn sii_image(&self) -> &[u8] {
        self.sii.image()
    }

    /// The DC unit, if the ESC has one.
    pub fn dc(&self) -> Option<&DcUnit> {
        self.dc.as_ref()
    }

    /// Mutable DC unit.
    pub fn dc_mut(&mut self) -> Option<&mut DcUnit> {
        self.dc.as_mut()
    }

    /// Current AL state.
    pub fn al_state(&self) -> AlState {
        self.al_state
    }

    /// Configured station address.
    pub fn station_address(&self) -> u16 {
        self.get_u16(reg::STATION_ADDRESS)
    }

    /// The addresses a configured-address datagram (FPxx) names this ESC by: its station
    /// address, and its alias while DL control enables it.
    pub(crate) fn configured_addresses(&self) -> (u16, Option<u16>) {
        (
            self.station_address(),
            self.alias_enabled()
                .then(|| self.get_u16(reg::STATION_ALIAS)),
        )
    }

    /// Counters.
    pub fn stats(&self) -> EscStats {
        let mut s = self.stats;
        self.count_pending_replays(&mut s);
        s
    }

    /// The configuration generation: it changes with everything that could make a datagram
    /// act differently (the segment's visit plans hold while no ESC's changes).
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }

    /// Marks that a frame passed the processing unit.
    pub fn count_frame(&mut self) {
        self.stats.frames += 1;
    }
}

/// What the tests of the modules share: an ESC and hand-built datagrams.
#[cfg(test)]
mod testing {
    use super::Esc;
    use crate::clock::CrystalParams;
    use crate::model::{DeviceInfo, EscModel};
    use ecsync_wire::Command;

    /// A servo drive's ESC with a link on port 0, without a mailbox (the AL state machine
    /// goes to PRE-OP without one set up; the mailbox has its own tests).
    pub(super) fn esc() -> Esc {
        esc_of(EscModel::servo_mii())
    }

    /// [`esc`] on another ESC model.
    pub(super) fn esc_of(model: EscModel) -> Esc {
        let mut e = Esc::new(
            model,
            DeviceInfo {
                mailbox: None,
                ..DeviceInfo::servo_drive(7)
            },
            CrystalParams::default(),
        );
        e.set_links([true, false, false, false]);
        e
    }

    /// A datagram built byte by byte from the datasheet's layout (independent of the wire
    /// crate's builder).
    pub(super) fn dg(cmd: Command, adp: u16, ado: u16, data: &[u8]) -> Vec<u8> {
        let mut v = vec![cmd.code(), 0];
        v.extend_from_slice(&adp.to_le_bytes());
        v.extend_from_slice(&ado.to_le_bytes());
        v.extend_from_slice(&(data.len() as u16).to_le_bytes());
        v.extend_from_slice(&[0, 0]);
        v.extend_from_slice(data);
        v.extend_from_slice(&[0, 0]);
        v
    }

    /// The working counter: the datagram's last two bytes.
    pub(super) fn wkc(d: &[u8]) -> u16 {
        u16::from_le_bytes([d[d.len() - 2], d[d.len() - 1]])
    }

    /// A BWR of `data` to `ado` at `t_ps`: its working counter.
    pub(super) fn put(e: &mut Esc, ado: u16, data: &[u8], t_ps: u64) -> u16 {
        let mut d = dg(Command::Bwr, 0, ado, data);
        e.process_datagram(&mut d, t_ps);
        wkc(&d)
    }

    /// A BRD of `n` bytes at `ado` at `t_ps`: its working counter and the bytes.
    pub(super) fn get(e: &mut Esc, ado: u16, n: usize, t_ps: u64) -> (u16, Vec<u8>) {
        let mut d = dg(Command::Brd, 0, ado, &vec![0; n]);
        e.process_datagram(&mut d, t_ps);
        (wkc(&d), d[10..10 + n].to_vec())
    }

    /// [`get`]'s bytes alone.
    pub(super) fn read(e: &mut Esc, ado: u16, n: usize, t_ps: u64) -> Vec<u8> {
        get(e, ado, n, t_ps).1
    }
}
