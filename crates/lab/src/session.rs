//! The one session loop: the cyclic phase of a brought-up network, over any [`Transport`].
//!
//! `compare` (each method's run on the simulated segment), `tsn run` (each variant behind the
//! bridge) and `run` (a real network, [`crate::realnet`]) all start their cyclic phase here:
//! the frames laid out from the [`Network`] the bring-up found, the first cycle aimed, the
//! engine and the cyclic driver built (with the recovery of slaves that lose their
//! configuration, where asked for), and every cycle handed to a [`CycleObserver`]. What each
//! of them measures is its observers' business; how a cycle is run is this module's (and the
//! driver's) alone.

use ecsync_dc::sync::MasterSync;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine, first_cycle_start};
use ecsync_master::driver::{CycleReport, CyclicDriver, CyclicLimits, Stopped};
use ecsync_master::network::Network;
use ecsync_master::recovery::RecoveryConfig;
use ecsync_master::transport::Transport;
use ecsync_wire::WireError;
use std::sync::atomic::AtomicBool;

/// Sees every cycle of a session as it happened, with the transport (a simulator's observer
/// reads its ground truth there; a real network's, its send control).
pub trait CycleObserver<Tr> {
    /// One cycle, answered or lost.
    fn on_cycle(&mut self, tr: &mut Tr, cycle: &CycleReport);
}

impl<Tr, F: FnMut(&mut Tr, &CycleReport)> CycleObserver<Tr> for F {
    fn on_cycle(&mut self, tr: &mut Tr, cycle: &CycleReport) {
        self(tr, cycle)
    }
}

/// Where the first cycle's frames go out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Aim {
    /// At the target phase of the reference's SYNC0 grid, where the bring-up's last reading
    /// put it against the master's clock (see [`first_cycle_start`]), `lead` early: the
    /// mean time from the cycle's start to the frame's arrival at the reference that the
    /// master knows of its own host.
    ReferenceGrid {
        /// The master's clock now.
        now: MasterInstant,
        /// Where in the cycle the frames aim, ns after the grid point.
        target_phase_ns: i64,
        /// Sent this much early.
        lead: MasterDuration,
    },
    /// At this instant (a caller that knows better: a time-aware bridge's window).
    At(MasterInstant),
}

/// What a session needs besides the network and the method.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionConfig {
    /// Cycle time, ns.
    pub cycle_ns: u32,
    /// Cycles the engine measures the reference's drift over before the method takes over
    /// ([`CyclicConfig::measure_init_frames`]).
    pub measure_init_frames: u64,
    /// Bring slaves that lose their configuration back while the cycle goes on (`None`: not).
    pub recovery: Option<RecoveryConfig>,
}

/// Why a session could not start.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The network has no reference clock to aim at.
    #[error("the bring-up found no reference clock")]
    NoReference,
    /// The cyclic frames cannot be laid out.
    #[error("cyclic frame: {0}")]
    Frame(WireError),
}

/// The cyclic phase of one network under one method: the engine, the driver, and where it
/// started.
#[derive(Debug)]
pub struct Session<S: MasterSync> {
    engine: CyclicEngine<S>,
    driver: CyclicDriver,
    first: MasterInstant,
}

/// The cyclic frames' layout for `net` (the reference's station and offset, the process
/// data's datagrams).
fn cyclic_config(
    net: &Network,
    cycle_ns: u32,
    measure_init_frames: u64,
) -> Result<CyclicConfig, SessionError> {
    CyclicConfig::for_network(net, cycle_ns, measure_init_frames).ok_or(SessionError::NoReference)
}

impl<S: MasterSync> Session<S> {
    /// The session of `method` on `net`, its first cycle aimed as `aim` says; `limits` are
    /// the driver's, given the engine (a reply timeout may depend on the frames' wire time).
    pub fn new(
        net: &Network,
        method: S,
        aim: Aim,
        cfg: SessionConfig,
        limits: impl FnOnce(&CyclicEngine<S>) -> CyclicLimits,
    ) -> Result<Self, SessionError> {
        let cyc = cyclic_config(net, cfg.cycle_ns, cfg.measure_init_frames)?;
        let first = match aim {
            Aim::ReferenceGrid {
                now,
                target_phase_ns,
                lead,
            } => first_cycle_start(
                now,
                net.reference_reading,
                method.reference_write_kind(),
                cfg.cycle_ns,
                target_phase_ns,
                lead,
            ),
            Aim::At(t) => t,
        };
        let engine = CyclicEngine::new(method, cyc, first).map_err(SessionError::Frame)?;
        let mut driver = CyclicDriver::new(limits(&engine));
        if let Some(r) = cfg.recovery {
            driver.set_recovery(net.clone(), r);
        }
        Ok(Session {
            engine,
            driver,
            first,
        })
    }

    /// The length of the first cyclic frame a session of `method` on `net` sends, bytes
    /// (before a session starts: where its first cycle is aimed may depend on it).
    pub fn first_frame_len(net: &Network, method: S, cycle_ns: u32) -> Result<usize, SessionError> {
        let cyc = cyclic_config(net, cycle_ns, 1)?;
        let mut probe = CyclicEngine::new(method, cyc, MasterInstant::default())
            .map_err(SessionError::Frame)?;
        Ok(probe.frame_to_send(MasterInstant::default()).len())
    }

    /// Runs up to `slice` more cycles, or until a limit, the stop flag or the network's loss
    /// ([`CyclicDriver::run`]), each handed to `observer`.
    pub fn run<Tr: Transport>(
        &mut self,
        tr: &mut Tr,
        slice: u64,
        stop: Option<&AtomicBool>,
        observer: &mut impl CycleObserver<Tr>,
    ) -> Result<Option<Stopped>, Tr::Error> {
        self.driver.run(tr, &mut self.engine, slice, stop, |tr, c| {
            observer.on_cycle(tr, c)
        })
    }

    /// The engine (its method, its health, the next cycle).
    pub fn engine(&self) -> &CyclicEngine<S> {
        &self.engine
    }

    /// The driver (its counters, recoveries and drive counter reads).
    pub fn driver(&self) -> &CyclicDriver {
        &self.driver
    }

    /// The driver, to change what it reads in the spare time.
    pub fn driver_mut(&mut self) -> &mut CyclicDriver {
        &mut self.driver
    }

    /// The first cycle's scheduled start.
    pub fn first(&self) -> MasterInstant {
        self.first
    }
}
