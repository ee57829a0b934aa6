//! How far the bring-up goes and how long it waits: [`BringupConfig`], [`BringupTimeouts`].

use crate::MasterError;

/// Forwarding and processing delay of an ESC, as a master learns them from the ESI. Needed for
/// exact delays when ESCs of different kinds share a segment (see `ecsync_dc::topology`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct EsiTiming {
    /// Vendor ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Forwarding delay tF, ns.
    pub forwarding_ns: i32,
    /// Processing delay tP, ns.
    pub processing_ns: i32,
}

/// Where the bring-up stops.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Stage {
    /// After measuring propagation delays (identity only from the SII, nothing written).
    Delays,
    /// After offsets, static drift compensation and lock.
    Lock,
    /// After SYNC0, process data mapping and OP, with the cyclic frame monitored.
    Op,
}

/// How far to bring the network up and how.
#[derive(Debug, Clone, PartialEq)]
pub struct BringupConfig {
    /// Where to stop.
    pub until: Stage,
    /// Latches of the receive times whose delays are averaged.
    pub latch_rounds: u32,
    /// The latch rounds are spread over this much master time, ns: long enough that each
    /// slave's clock rate relative to the master can be measured from its first and last port 0
    /// stamps (20 ms at 25 ppm is 500 ns of drift, a clear signal over the 40 ns stamp
    /// resolution) and the spans corrected for it, short against the rest of the bring-up.
    pub latch_window_ns: u64,
    /// The least gap between two latch rounds, ns, however many rounds share the window: a
    /// frame and its read-back must have left the segment before the next latch.
    pub latch_min_gap_ns: u64,
    /// Separate FRMW frames of static drift compensation (the datasheet recommends ~15000).
    pub static_drift_frames: u32,
    /// Read every slave's 0x092C after this many static drift frames.
    pub check_every_frames: u32,
    /// Lock when every |0x092C| stays below this, ns.
    pub lock_threshold_ns: u32,
    /// ... for this many consecutive checks.
    pub lock_hold_checks: u32,
    /// Cycle time of the cyclic phase and SYNC0, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift: SYNC0 fires this long after the cycle's grid point, ns.
    pub sync0_shift_ns: u32,
    /// How far ahead of the current system time SYNC0 starts, ns.
    pub sync0_lead_ns: u64,
    /// Cycles to run in the cyclic frame after OP, monitoring 0x092C.
    pub monitor_cycles: u32,
    /// ESI timing of known ESCs.
    pub esi: Vec<EsiTiming>,
    /// The master stamps its frames in hardware (send: first bit on the wire; receive: first
    /// bit of the returned frame) and is itself the DC reference, as in the TSN paper: measure
    /// its delay to the reference from the latch frames' round trips and set the reference's
    /// system time to the master's clock at the frame's arrival (instead of at its send).
    pub master_is_reference: bool,
    /// How long each wait of the bring-up may last.
    pub timeouts: BringupTimeouts,
    /// Measure every slave's crystal against the reference's (and the reference's against the
    /// master's clock) from port receive times latched over this much master time, ns, right
    /// after the delays, while the local clocks are still uncorrected ([`measure_clock_rates`](super::measure_clock_rates)).
    /// 0: not measured. A twin of the network (`ecsync run --save-network`) needs it; 2 s
    /// resolves 0.02 ppm with 40 ns stamps.
    pub rate_window_ns: u64,
    /// Read the SII's device name, mailbox and SyncManagers even when the bring-up stops after
    /// the delays (a twin of the network names and types its devices from them).
    pub read_sii_details: bool,
    /// The sync error counter limit (0x10F1:02, ETG.1020's error settings) written over CoE to
    /// every drive set to DC SYNC0, in PRE-OP with the sync mode, as a master's startup SDO
    /// does (TwinCAT's startup list, IgH's `ecrt_slave_config_sdo16`). Past it a drive leaves
    /// OP with AL status code 0x001A; 0 switches its reaction off (SSC V5.13, `DC_CheckWatchdog`:
    /// a limit of 0 keeps the SM-Sync sequence valid). `None`: not written, every drive keeps
    /// its own (the virtual drive's is 0).
    pub sync_error_limit: Option<u16>,
    /// The slaves run on SYNC1 with oversampling (an EL4732-like terminal), by position:
    /// see [`Oversampled`]. Every other slave with a system time runs on SYNC0.
    pub oversampled: Vec<Oversampled>,
    /// The segment is a ring (cable redundancy): the last slave's port 1 is cabled back to
    /// the master's second port. The bring-up closes that port's loop (DL control) so that
    /// it measures a line (a frame that left by the second port latches no receive time on
    /// its way back), and opens it again (auto) at its end: the cyclic phase runs the ring
    /// ([`crate::redundancy::Redundant`]).
    pub ring: bool,
}

/// A slave the master runs on SYNC1 with oversampling, as the "DC oversampling" operation
/// mode of a terminal's ESI has a master do (TwinCAT's Sync0 factor of the cycle and SYNC1
/// shift): its application takes a block of `samples` values at each SYNC1 event and plays
/// one per SYNC0 pulse. The master writes 0x1C32:01 = 3 (DC SYNC1) and 0x1C32:02 = the
/// cycle over CoE, SYNC0 every cycle / `samples`, SYNC1 (0x09A4) the cycle less a SYNC0
/// cycle (ethercrab #368: SYNC0 x (samples - 1)), 0x0981 = 0x07, and starts SYNC0 a SYNC0
/// cycle after the grid's pulse: SYNC1 then falls on the grid (cycle start plus the SYNC0
/// shift), where a SYNC0-mode drive's pulse is, and the deadline of the frame is the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Oversampled {
    /// Auto-increment position.
    pub position: u16,
    /// Samples per cycle (1-100); the cycle must be a whole number of nanoseconds times it.
    pub samples: u8,
}

/// What a slave's SYNC unit is programmed with: SYNC0's cycle, SYNC1's cycle (0x09A4) when
/// it runs, and how far SYNC0's start lies after the grid's pulse, ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SyncUnitPlan {
    pub(crate) sync0_cycle_ns: u32,
    pub(crate) sync1_cycle_ns: Option<u32>,
    pub(crate) start_after_grid_ns: u32,
}

impl SyncUnitPlan {
    /// The plan of a slave at `position` among `oversampled`, on a cycle of `cycle_ns`.
    pub(crate) fn of(position: u16, oversampled: &[Oversampled], cycle_ns: u32) -> Self {
        match oversampled.iter().find(|o| o.position == position) {
            Some(o) if o.samples > 0 => {
                let c0 = cycle_ns / u32::from(o.samples);
                SyncUnitPlan {
                    sync0_cycle_ns: c0,
                    sync1_cycle_ns: Some(cycle_ns - c0),
                    start_after_grid_ns: c0,
                }
            }
            _ => SyncUnitPlan {
                sync0_cycle_ns: cycle_ns,
                sync1_cycle_ns: None,
                start_after_grid_ns: 0,
            },
        }
    }

    /// 0x0981: SYNC0 (and SYNC1) on, cyclic operation.
    pub(crate) fn activation(&self) -> u8 {
        if self.sync1_cycle_ns.is_some() {
            0x07
        } else {
            0x03
        }
    }
}

/// The oversampled slaves are possible on a cycle of `cycle_ns`.
fn check_oversampled(oversampled: &[Oversampled], cycle_ns: u32) -> Result<(), MasterError> {
    for o in oversampled {
        if !(1..=100).contains(&o.samples) || !cycle_ns.is_multiple_of(u32::from(o.samples)) {
            return Err(MasterError::Config(format!(
                "slave {}: {} samples per cycle of {cycle_ns} ns: give 1 to 100 samples that divide the cycle into whole nanoseconds",
                o.position, o.samples
            )));
        }
    }
    Ok(())
}

impl Default for BringupConfig {
    fn default() -> Self {
        BringupConfig {
            until: Stage::Op,
            latch_rounds: 64,
            latch_window_ns: 20_000_000,
            latch_min_gap_ns: 2_000,
            static_drift_frames: 15_000,
            check_every_frames: 100,
            lock_threshold_ns: 100,
            lock_hold_checks: 1_000,
            cycle_ns: 1_000_000,
            sync0_shift_ns: 300_000,
            sync0_lead_ns: 100_000_000,
            monitor_cycles: 1_000,
            esi: Vec::new(),
            master_is_reference: false,
            timeouts: BringupTimeouts::default(),
            rate_window_ns: 0,
            read_sii_details: false,
            sync_error_limit: None,
            oversampled: Vec::new(),
            ring: false,
        }
    }
}

impl BringupConfig {
    /// Checks what the bring-up cannot run with (before any frame is sent).
    pub(super) fn validate(&self) -> Result<(), MasterError> {
        if self.cycle_ns == 0 || self.sync0_shift_ns >= self.cycle_ns {
            return Err(MasterError::Config(format!(
                "cycle {} ns and SYNC0 shift {} ns: the shift must lie within the cycle",
                self.cycle_ns, self.sync0_shift_ns
            )));
        }
        check_oversampled(&self.oversampled, self.cycle_ns)
    }
}

/// How long the bring-up waits for the network, master time. Each wait polls by exchanging
/// frames, so a timeout bounds both the time and the frames a dead or refusing slave costs.
/// (How long one frame is waited for, and how often a lost one is sent again, is the driver's
/// [`crate::driver::ProcedureConfig`].)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BringupTimeouts {
    /// How long a slave's SII EEPROM may stay busy with one command, ns. 100 ms: an EEPROM
    /// read of 8 bytes over I2C takes well under a millisecond, SOEM allows 20 ms and ethercrab
    /// 10 ms; the margin covers slow EEPROMs and a host that stalls during the poll, and a
    /// missing EEPROM still fails in a tenth of a second.
    pub sii_busy_timeout_ns: u64,
    /// How long one slave may take to report a requested AL state (PRE-OP, SAFE-OP), ns. 5 s:
    /// a slave's application may take seconds to accept a state (it checks its SyncManagers,
    /// starts its firmware's tasks); ethercrab waits 5 s, SOEM 2 s.
    pub state_timeout_ns: u64,
    /// The pause between two reads of AL status while waiting for a state, ns. 100 us: a state
    /// reached is seen within a tenth of a millisecond, and the wait costs at most one frame
    /// per 100 us on the wire.
    pub state_poll_interval_ns: u64,
    /// How long the whole network may take to report OP with the cyclic frame running, ns.
    /// 10 s, twice a single state change: a slave enters OP only once it has seen valid
    /// process data and its SYNC0 running, and all slaves must get there.
    pub op_timeout_ns: u64,
    /// Give up if the network is not locked this long after the static drift compensation,
    /// ns. 30 s: the time control loops pull in a few ppm of crystal difference in seconds;
    /// the timeout runs from the end of the static drift compensation, whose length grows with
    /// the network, so large networks get the same allowance.
    pub lock_timeout_ns: u64,
    /// ... and not before this many lock checks (each an FRMW of the reference's time, one step
    /// of every slave's loop): the loops converge by writes, not by time, and a long cycle (a
    /// network of thousands of slaves needs tens of milliseconds) gets as many as 30 s give at
    /// 1 ms. A 5 000-drive line at 20 ms took 21 906 after its static drift compensation.
    pub lock_timeout_checks: u64,
}

impl Default for BringupTimeouts {
    fn default() -> Self {
        BringupTimeouts {
            sii_busy_timeout_ns: crate::sii::BUSY_TIMEOUT_NS,
            state_timeout_ns: 5_000_000_000,
            state_poll_interval_ns: 100_000,
            op_timeout_ns: 10_000_000_000,
            lock_timeout_ns: 30_000_000_000,
            lock_timeout_checks: 30_000,
        }
    }
}
