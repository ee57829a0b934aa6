//! One run of one method: bring the segment up, run the cyclic phase with the host's noise,
//! measure what the letter measures and what only the simulator knows.

use crate::scenario::Scenario;
use crate::session::{Aim, Session, SessionConfig, SessionError};
use crate::stats::{Stats, Summary};
use ecsync_dc::Method;
use ecsync_dc::fit::LineFit;
use ecsync_dc::sync::MasterSync;
use ecsync_dc::time::{MasterDuration, MasterInstant};
use ecsync_master::bringup::{BringupConfig, Network, Oversampled, Stage, bringup};
use ecsync_master::cyclic::CyclicEngine;
use ecsync_master::driver::{CycleReport, CyclicLimits};
use ecsync_master::network::Phase;
use ecsync_master::{Engine, Event, MasterError};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::fault::{Edge, Epoch, FaultCounts, FaultEvent, FaultKind, FaultPlayer, KindName};
use ecsync_sim::host::{CycleNoise, HostNoise, SharedNoise};
use ecsync_sim::rng::splitmix64;
use ecsync_sim::send::{Entry, SendMode, SendParams};
use ecsync_sim::transport::{HostDelays, HostModel, MasterClock, SIM_EPOCH_NS, SimTransport};
use ecsync_sim::{Segment, frame_wire_time_ps};
use observe::{GridSpec, GroundTruth, Observers, SampleSink};
use serde::Serialize;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

mod cyclic;
mod fit;
mod observe;
mod result;

pub use cyclic::Run;
pub use fit::{CycleFit, check_cycle_fits, cycle_fit};
pub use result::*;

/// Why a run could not complete.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The bring-up failed.
    #[error("bring-up failed: {0}")]
    Bringup(#[from] MasterError),
    /// The cyclic frame does not fit.
    #[error("cyclic frame: {0}")]
    Frame(ecsync_wire::WireError),
    /// The cycle is shorter than the network's frames need to come back (every one would be
    /// lost): found before anything is simulated.
    #[error(
        "the {cycle_us} us cycle is too short for this network: its {} cyclic frames take {:.1} us on the wire, their first bit {:.1} us round the segment and the host {:.1} us, so the last reply comes {:.1} us after the cycle's start even without jitter, and every frame would be lost; set run.cycle_us (or --cycle-us) to {} or more ({} us of room for the host's jitter: what this host's latest send exceeds in one of twenty comparisons of this length, at least the engine's {} us reply margin; a cycle whose frame goes out later than that loses it, and `ecsync tune --method <method> --shortest-cycle` finds the shortest cycle this host holds)",
        fit.frames,
        fit.wire_ns as f64 / 1000.0,
        fit.round_trip_ns as f64 / 1000.0,
        fit.host_ns as f64 / 1000.0,
        fit.needed_cycle_ns as f64 / 1000.0,
        fit.suggested_cycle_us(),
        fit.room_ns.div_ceil(1000),
        REPLY_MARGIN_NS / 1000
    )]
    CycleTooShort {
        /// The scenario's cycle, us.
        cycle_us: f64,
        /// What the network needs.
        fit: CycleFit,
    },
    /// No slave takes process data on SYNC0 (couplers, terminals without a system time):
    /// there is no deadline to judge the methods' frames by.
    #[error(
        "no slave of the {slaves} has a SYNC0 deadline: none has both a system time (SYNC0 runs on it) and process data (what SYNC0 takes); the comparison judges each method by its frames' margin before the drives' SYNC0, so it would have nothing to judge. fix: add a DC slave with process data (model \"servo-mii\", device \"servo-drive\"), or give one an ESI device with PDOs"
    )]
    NoSync0Slave {
        /// Slaves in the scenario.
        slaves: usize,
    },
    /// Stopped (Ctrl-C) before the bring-up was done: nothing was measured.
    #[error("stopped during the bring-up, before any cycle was measured")]
    Interrupted,
    /// The per-cycle samples could not be written.
    #[error("writing the samples to {path}: {err}")]
    Samples {
        /// The file.
        path: String,
        /// What went wrong.
        err: std::io::Error,
    },
}

/// The seed of run `run`.
pub fn run_seed(base: u64, run: u32) -> u64 {
    splitmix64(base ^ splitmix64(u64::from(run) + 1))
}

/// A run's network after its bring-up: every method of the run continues from a copy of it
/// (the bring-up does not depend on the method, and it is the same hardware and seed).
#[derive(Debug)]
pub struct BroughtUp {
    sim: SimTransport,
    net: Network,
    seed: u64,
    run: u32,
}

impl BroughtUp {
    /// The run's seed (of its noise and crystals).
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The network as the bring-up found and configured it.
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The simulator's transport after the bring-up (its segment's ground truth, its faults).
    pub fn sim(&self) -> &SimTransport {
        &self.sim
    }
}

/// The crystals of run `run` (the same hardware in every run; the wander differs).
pub fn run_specs(s: &Scenario, run: u32) -> Vec<ecsync_sim::SlaveSpec> {
    let seed = run_seed(s.seed, run);
    let mut specs = s.slaves.clone();
    for (i, sp) in specs.iter_mut().enumerate() {
        sp.crystal.seed = splitmix64(seed ^ (0x5eed_0000 + i as u64) ^ sp.crystal.seed);
    }
    specs
}

/// Brings up the network of run `run` of the scenario.
pub fn bring_up(s: &Scenario, run: u32) -> Result<BroughtUp, RunError> {
    bring_up_watched(s, run, &BringupWatch::default())
}

/// What a bring-up reports while it goes, and the flag that stops it: a large segment's
/// bring-up runs for minutes, and Ctrl-C must end it within a second.
#[derive(Debug, Default, Clone, Copy)]
pub struct BringupWatch<'a> {
    /// Set to stop: the bring-up ends after the exchange in flight ([`RunError::Interrupted`]).
    pub stop: Option<&'a AtomicBool>,
    /// Where the bring-up says how far it got.
    pub progress: Option<&'a BringupProgress>,
}

/// How far the bring-ups of a comparison got: frames exchanged, the latest phase begun, runs
/// done. Shared by the runs' threads; read by a progress line.
#[derive(Debug, Default)]
pub struct BringupProgress {
    /// Frames exchanged by every bring-up so far.
    pub frames: AtomicU64,
    /// Bring-ups done.
    pub runs_up: AtomicU32,
    phase: Mutex<Option<Phase>>,
}

impl BringupProgress {
    /// The latest phase a bring-up began, if any.
    pub fn phase(&self) -> Option<Phase> {
        self.phase.lock().ok().and_then(|p| *p)
    }

    fn saw(&self, events: &[Event]) {
        self.frames.fetch_add(1, Ordering::Relaxed);
        for e in events {
            if let Event::Phase(p) = e
                && let Ok(mut cur) = self.phase.lock()
            {
                *cur = Some(*p);
            }
        }
    }
}

/// [`bring_up`], reporting to and stopped by `watch`.
pub fn bring_up_watched(
    s: &Scenario,
    run: u32,
    watch: &BringupWatch<'_>,
) -> Result<BroughtUp, RunError> {
    let seed = run_seed(s.seed, run);
    let specs = run_specs(s, run);
    let segment = Segment::new(&specs).map_err(|e| MasterError::Config(e.to_string()))?;
    let mut sim = SimTransport::new(segment);
    sim.set_master_clock(MasterClock::new(CrystalParams {
        ppm: s.host.master_ppm,
        wander_ppm_per_sqrt_s: s.host.master_wander_ppm_per_sqrt_s,
        wander_step_ps: ecsync_sim::clock::DEFAULT_WANDER_STEP_PS,
        initial_local_ns: SIM_EPOCH_NS,
        seed: splitmix64(seed ^ 0x4a57_e700),
    }));
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: s.static_drift_frames,
        cycle_ns: s.cycle_ns,
        sync0_shift_ns: s.sync0_shift_ns(),
        lock_hold_checks: 200,
        monitor_cycles: 10,
        sync_error_limit: s.sync_error_limit,
        oversampled: oversampled_of(sim.segment()),
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    // Faults counted from the first frame play on the bring-up too: a lost datagram is then
    // waited for a few milliseconds and sent again, as on a real network.
    // Slaves that appear later are not there for the bring-up, whatever the epoch.
    if let Some(f) = &s.faults {
        FaultPlayer::new(f.clone(), seed).prepare(sim.segment_mut());
    }
    let procedure = match &s.faults {
        Some(f) if f.epoch == Epoch::Start => {
            sim.set_faults(FaultPlayer::new(f.clone(), seed));
            FAULTY_PROCEDURE
        }
        _ => ecsync_sim::transport::SIM_PROCEDURE,
    };
    let never = AtomicBool::new(false);
    let stop = watch.stop.unwrap_or(&never);
    let observe = |_: &mut SimTransport, _: &_, events: &[Event]| {
        if let Some(p) = watch.progress {
            p.saw(events);
        }
    };
    let net = sim
        .run_procedure_until(&mut engine, procedure, stop, observe)
        .ok_or(RunError::Interrupted)??;
    if let Some(p) = watch.progress {
        p.runs_up.fetch_add(1, Ordering::Relaxed);
    }
    Ok(BroughtUp {
        sim,
        net,
        seed,
        run,
    })
}

/// The segment's oversampling terminals, as the master is set up for them (what an ENI's DC
/// operation mode tells a real master: here the scenario says which device each slave is).
pub fn oversampled_of(seg: &Segment) -> Vec<Oversampled> {
    (0..seg.len())
        .filter_map(|p| {
            let samples = seg.esc(p).device().oversampling;
            (samples > 0).then_some(Oversampled {
                position: p as u16,
                samples,
            })
        })
        .collect()
}

/// A recovered slave's SYNC0 starts at least this long after the recovery reads the time, ns
/// (the rest of the recovery's frames, one per cycle, come first).
const RECOVERY_SYNC0_LEAD_NS: u64 = 20_000_000;
/// What a reply may take past the cycle's frames' way back before it counts as lost (the
/// host's receive path beyond its modelled latency), ns.
const REPLY_MARGIN_NS: u64 = 100_000;

/// FRMW frames of static drift compensation a recovery sends after a reset slave's offset.
const RECOVERY_STATIC_DRIFT_FRAMES: u32 = 15_000;

/// How the bring-up waits and retries on a segment with faults: 5 ms, ten times.
pub const FAULTY_PROCEDURE: ecsync_master::driver::ProcedureConfig =
    ecsync_master::driver::ProcedureConfig {
        reply_timeout_ns: 5_000_000,
        retries: 10,
    };
