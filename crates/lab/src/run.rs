//! One run of one method: bring the segment up, run the cyclic phase with the host's noise,
//! measure what the letter measures and what only the simulator knows.

use crate::host::{CycleNoise, HostNoise, SharedNoise};
use crate::scenario::Scenario;
use crate::stats::{Stats, Summary};
use ecsync_dc::sync::MasterSync;
use ecsync_dc::{BusShift, MedianSync, PiM2s, Snap, SoemPi};
use ecsync_esc::clock::CrystalParams;
use ecsync_esc::{Segment, frame_wire_time_ps};
use ecsync_master::bringup::{BringupConfig, Network, Stage, bringup};
use ecsync_master::cyclic::{CycleRecord, CyclicConfig, CyclicEngine};
use ecsync_master::sim::{MasterClock, SIM_EPOCH_NS, SimTransport};
use ecsync_master::{Engine, MasterError};
use serde::Serialize;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// The five methods behind one type (static dispatch, no allocation; the median's window
/// makes it the large one, and one method lives per run).
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum Method {
    /// The letter's median-filter drift compensator.
    Median(MedianSync),
    /// E-M2S.
    PiM2s(PiM2s),
    /// E-S2M.
    BusShift(BusShift),
    /// ethercrab's snap.
    Snap(Snap),
    /// SOEM's sample PI.
    SoemPi(SoemPi),
}

impl Method {
    /// The method named `name` with the scenario's parameters.
    pub fn from_scenario(name: &str, s: &Scenario) -> Option<Method> {
        Some(match name {
            "median" => Method::Median(MedianSync::new(
                s.median.window as usize,
                s.median.gain,
                s.median.init_frames as u64,
            )),
            "pi-m2s" => Method::PiM2s(PiM2s::new(
                s.pi_m2s.kp,
                s.pi_m2s.ki,
                s.pi_m2s.init_frames as u64,
            )),
            "bus-shift" => Method::BusShift(BusShift {
                write_offset_ns: s.bus_shift.write_offset_ns,
            }),
            "snap" => Method::Snap(Snap {
                shift_ns: s.snap.shift_ns.clamp(0, i64::from(u32::MAX)) as u32,
            }),
            "soem-pi" => Method::SoemPi(SoemPi::new(s.soem_pi.offset_ns)),
            _ => return None,
        })
    }

    fn inner(&self) -> &dyn MasterSync {
        match self {
            Method::Median(m) => m,
            Method::PiM2s(m) => m,
            Method::BusShift(m) => m,
            Method::Snap(m) => m,
            Method::SoemPi(m) => m,
        }
    }

    fn inner_mut(&mut self) -> &mut dyn MasterSync {
        match self {
            Method::Median(m) => m,
            Method::PiM2s(m) => m,
            Method::BusShift(m) => m,
            Method::Snap(m) => m,
            Method::SoemPi(m) => m,
        }
    }
}

impl MasterSync for Method {
    fn name(&self) -> &'static str {
        self.inner().name()
    }
    fn is_master_shift(&self) -> bool {
        self.inner().is_master_shift()
    }
    fn reference_write(&self, send_ns: u64) -> Option<u64> {
        self.inner().reference_write(send_ns)
    }
    fn init_cycles(&self) -> u64 {
        self.inner().init_cycles()
    }
    fn update(&mut self, input: &ecsync_dc::CycleInput) -> ecsync_dc::CycleOutput {
        self.inner_mut().update(input)
    }
}

/// A point of a time series: min and max of a quantity over a block of cycles, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Envelope {
    /// First cycle of the block.
    pub cycle: u64,
    /// Smallest value.
    pub min: f32,
    /// Largest value.
    pub max: f32,
}

/// Cycles per time series point.
pub const SERIES_BLOCK: u64 = 1_000;

/// What one run of one method measured.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// Method.
    pub method: String,
    /// Run index.
    pub run: u32,
    /// The letter's M-rS error, ns.
    pub m_rs: Stats,
    /// The letter's rS-IS error (|BRD of 0x092C|), ns.
    pub rs_is: Stats,
    /// Truth: the frame's arrival at the reference against the DC grid point it aims at, ns.
    pub phase: Stats,
    /// Truth: the largest |slave - reference| system time difference at the frame's pass, ns.
    pub slave_diff: Stats,
    /// Truth: SYNC0 margin at the last slave (SYNC0 time minus the frame's end there), ns.
    pub margin: Stats,
    /// Cycles whose frame reached the last slave after its SYNC0 (margin < 0).
    pub late_frames: u64,
    /// The latest end of a frame at the last slave after its grid point, ns: the smallest SYNC0
    /// shift without a late frame.
    pub latest_end_ns: f64,
    /// Frames lost.
    pub lost_frames: u64,
    /// Cycles whose LRW working counter was not the expected one.
    pub bad_wkc: u64,
    /// Time series of M-rS, rS-IS and the true phase.
    pub series: [Vec<Envelope>; 3],
    /// Bring-up: DC lock time, ms.
    pub lock_ms: Option<f64>,
}

impl RunResult {
    /// Summaries of the five quantities.
    pub fn summaries(&self) -> [Summary; 5] {
        [
            self.m_rs.summary(),
            self.rs_is.summary(),
            self.phase.summary(),
            self.slave_diff.summary(),
            self.margin.summary(),
        ]
    }
}

/// Why a run could not complete.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The bring-up failed.
    #[error("bring-up failed: {0}")]
    Bringup(#[from] MasterError),
    /// The scenario names a method that does not exist.
    #[error("unknown method {0}")]
    UnknownMethod(String),
    /// The cyclic frame does not fit.
    #[error("cyclic frame: {0}")]
    Frame(ecsync_wire::WireError),
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The seed of run `run`.
pub fn run_seed(base: u64, run: u32) -> u64 {
    splitmix(base ^ splitmix(u64::from(run) + 1))
}

pub(crate) struct Series {
    out: Vec<Envelope>,
    cur: Option<Envelope>,
}

impl Series {
    pub(crate) fn new(cap: usize) -> Self {
        Series {
            out: Vec::with_capacity(cap),
            cur: None,
        }
    }

    pub(crate) fn add(&mut self, cycle: u64, x: f64) {
        let block = cycle / SERIES_BLOCK * SERIES_BLOCK;
        let x = x as f32;
        match &mut self.cur {
            Some(e) if e.cycle == block => {
                // Plain comparisons (no NaN handling: the errors recorded are never NaN).
                if x < e.min {
                    e.min = x;
                }
                if x > e.max {
                    e.max = x;
                }
            }
            _ => {
                if let Some(e) = self.cur.take() {
                    self.out.push(e);
                }
                self.cur = Some(Envelope {
                    cycle: block,
                    min: x,
                    max: x,
                });
            }
        }
    }

    pub(crate) fn finish(mut self) -> Vec<Envelope> {
        if let Some(e) = self.cur.take() {
            self.out.push(e);
        }
        self.out
    }
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
}

/// Brings up the network of run `run` of the scenario.
pub fn bring_up(s: &Scenario, run: u32) -> Result<BroughtUp, RunError> {
    let seed = run_seed(s.seed, run);
    // The same hardware in every run; the crystals' wander and the host's noise differ.
    let mut specs = s.slaves.clone();
    for (i, sp) in specs.iter_mut().enumerate() {
        sp.crystal.seed = splitmix(seed ^ (0x5eed_0000 + i as u64) ^ sp.crystal.seed);
    }
    let segment = Segment::new(&specs).map_err(|e| MasterError::Config(e.to_string()))?;
    let mut sim = SimTransport::new(segment);
    sim.master_clock = MasterClock::new(CrystalParams {
        ppm: s.host.master_ppm,
        wander_ppm_per_sqrt_s: s.host.master_wander_ppm_per_sqrt_s,
        wander_step_ps: ecsync_esc::clock::DEFAULT_WANDER_STEP_PS,
        initial_local_ns: SIM_EPOCH_NS,
        seed: splitmix(seed ^ 0x4a57_e700),
    });
    let cfg = BringupConfig {
        until: Stage::Op,
        static_drift_frames: s.static_drift_frames,
        cycle_ns: s.cycle_ns,
        sync0_shift_ns: s.sync0_shift_ns(),
        lock_hold_checks: 200,
        monitor_cycles: 10,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim.run(&mut engine, |_, _, _| {})?;
    Ok(BroughtUp {
        sim,
        net,
        seed,
        run,
    })
}

/// One method's run in progress: the cyclic phase, resumable in steps of any number of cycles
/// (so that a scheduler can share the cores fairly between runs; the result does not depend on
/// the steps).
pub struct Run {
    sim: SimTransport,
    eng: CyclicEngine<Method>,
    noise: HostNoise,
    /// The run's noise drawn once for all methods (see [`SharedNoise`]); without it, each step
    /// draws its own into `noise_buf`.
    shared_noise: Option<Arc<SharedNoise>>,
    noise_buf: Vec<CycleNoise>,
    res: RunResult,
    series: [Series; 3],
    grid0: Option<(u64, i64)>,
    prev_done_ns: u64,
    next_cycle: u64,
    warmup_cycles: u64,
    total_cycles: u64,
    period_ns: u64,
    shift_ns: f64,
    rx_latency_ps: u64,
    reference: usize,
    last: usize,
    expected_lrw_wkc: u16,
    pdi_len: u32,
}

impl std::fmt::Debug for Run {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Run")
            .field("method", &self.res.method)
            .field("run", &self.res.run)
            .field("next_cycle", &self.next_cycle)
            .finish_non_exhaustive()
    }
}

impl Run {
    /// Method `method_name` from the brought-up network `up` (which it copies).
    pub fn new(s: &Scenario, up: &BroughtUp, method_name: &str) -> Result<Run, RunError> {
        let mut sim = up.sim.fork();
        let net = &up.net;
        let lock_ms = net.lock.time_to_lock_ns.map(|t| t as f64 / 1e6);
        let reference = usize::from(net.reference);
        let last = sim.segment.len() - 1;
        let ref_station = net.slaves[reference].station;

        let method = Method::from_scenario(method_name, s)
            .ok_or_else(|| RunError::UnknownMethod(method_name.to_string()))?;
        let noise = HostNoise::new(s.host, up.seed);
        let period = u64::from(s.cycle_ns);
        let cyc_cfg = CyclicConfig {
            period_ns: s.cycle_ns,
            reference_station: ref_station,
            pdi_len: net.pdi_len,
            measure_init_frames: method.init_cycles().max(10_000).min(s.warmup_cycles.max(1)),
        };
        // The first cycle: frames aimed at the reference's grid points. The reference's system
        // time is close to the master's clock after the bring-up (its offset is the master's
        // time), so the grid is the master's multiples of P, minus the mean time from the cycle
        // start to the frame's arrival at the reference (e_m and the NIC latency; j_s's mean
        // too).
        let now = sim.master_now_ns();
        let lead = s.host.em_ns + s.host.tx_latency_ns;
        let first = (now / period + 2) * period - lead as u64;
        let eng = CyclicEngine::new(method, cyc_cfg, first).map_err(RunError::Frame)?;
        let cap = (s.cycles / SERIES_BLOCK + 2) as usize;
        Ok(Run {
            sim,
            eng,
            noise,
            shared_noise: None,
            noise_buf: Vec::new(),
            res: RunResult {
                method: method_name.to_string(),
                run: up.run,
                m_rs: Stats::new(-200_000.0, 10.0, 40_000),
                rs_is: Stats::new(0.0, 1.0, 20_000),
                phase: Stats::new(-200_000.0, 10.0, 40_000),
                slave_diff: Stats::new(0.0, 1.0, 20_000),
                margin: Stats::new(-500_000.0, 10.0, 100_000),
                late_frames: 0,
                latest_end_ns: f64::NEG_INFINITY,
                lost_frames: 0,
                bad_wkc: 0,
                series: Default::default(),
                lock_ms,
            },
            series: [Series::new(cap), Series::new(cap), Series::new(cap)],
            grid0: None,
            prev_done_ns: 0,
            next_cycle: 0,
            warmup_cycles: s.warmup_cycles,
            total_cycles: s.warmup_cycles + s.cycles,
            period_ns: period,
            shift_ns: f64::from(s.sync0_shift_ns()),
            rx_latency_ps: (s.host.rx_latency_ns * 1000.0) as u64,
            reference,
            last,
            expected_lrw_wkc: net.expected_lrw_wkc,
            pdi_len: net.pdi_len,
        })
    }

    /// Takes the run's noise from `shared` (drawn once for all methods of the run) instead of
    /// drawing it; `shared` must hold this run's noise.
    pub fn share_noise(&mut self, shared: Arc<SharedNoise>) {
        debug_assert_eq!(*shared.noise(), self.noise);
        if *shared.noise() == self.noise {
            self.shared_noise = Some(shared);
        }
    }

    /// Cycles still to run (warm-up included).
    pub fn remaining(&self) -> u64 {
        self.total_cycles - self.next_cycle
    }

    /// Runs up to `max_cycles` more cycles; returns how many ran.
    pub fn step(&mut self, max_cycles: u64) -> u64 {
        let end = self
            .total_cycles
            .min(self.next_cycle.saturating_add(max_cycles));
        let start = self.next_cycle;
        // The noise of these cycles, drawn in one go (or taken from the other methods' draw).
        let shared_block;
        let noise_block: &[CycleNoise] = match &self.shared_noise {
            Some(sh) => {
                shared_block = sh.block(start, end - start);
                &shared_block
            }
            None => {
                let noise = self.noise;
                self.noise_buf.clear();
                self.noise_buf.extend((start..end).map(|i| noise.cycle(i)));
                &self.noise_buf
            }
        };
        let Run {
            sim,
            eng,
            res,
            series,
            grid0,
            prev_done_ns,
            ..
        } = self;
        let (warmup, period, shift, rx_latency_ps) = (
            self.warmup_cycles,
            self.period_ns,
            self.shift_ns,
            self.rx_latency_ps,
        );
        let (reference, last) = (self.reference, self.last);
        let (expected_wkc, pdi_len) = (self.expected_lrw_wkc, self.pdi_len);
        for (i, noise_i) in (start..end).zip(noise_block) {
            // The task wakes at the scheduled start (or when the previous cycle is done, if it
            // overran), late by j_s, and runs e_m before it timestamps and sends.
            let wake = eng.scheduled_start_ns().max(*prev_done_ns);
            let send_ns = wake + (noise_i.js_ns + noise_i.em_ns) as u64;
            let tx_ps = sim.master_clock.real_ps_at(send_ns) + (noise_i.tx_ns * 1000.0) as u64;
            let frame = eng.frame_to_send(send_ns);
            let n = frame.len();
            let out = sim.segment.process(frame, tx_ps);
            let rec: CycleRecord = match out.returned_sof_ps {
                Some(t) => {
                    let rx_ps = t + frame_wire_time_ps(n) + rx_latency_ps;
                    let rx_ns = sim.master_clock.master_ns(rx_ps);
                    *prev_done_ns = rx_ns;
                    eng.complete_in_place(true, send_ns, rx_ns)
                }
                None => {
                    *prev_done_ns = send_ns + period / 2;
                    eng.complete_in_place(false, send_ns, *prev_done_ns)
                }
            };
            if i < warmup {
                continue;
            }
            let k = i - warmup;
            if rec.receive_ns.is_none() {
                res.lost_frames += 1;
                continue;
            }
            if rec.lrw_wkc != Some(expected_wkc) && pdi_len > 0 {
                res.bad_wkc += 1;
            }
            if let Some(m) = rec.m_rs_ns {
                res.m_rs.add(m as f64);
                series[0].add(k, m as f64);
            }
            if let Some(v) = rec.rs_is_ns {
                res.rs_is.add(f64::from(v));
                series[1].add(k, f64::from(v));
            }
            // Ground truth from the segment.
            let trace = sim.segment.trace();
            let (Some(pu_ref), Some(pu_last)) = (trace[reference].pu_ps, trace[last].pu_ps) else {
                continue;
            };
            let seg = &sim.segment;
            let sys =
                |slave: usize, t_ps: u64| seg.esc(slave).dc().map(|d| d.system_time_split(t_ps));
            let Some(r) = sys(reference, pu_ref) else {
                continue;
            };
            // The grid point this frame aims at: fixed by the first recorded frame, one per
            // cycle.
            let (g0, k0) = *grid0.get_or_insert_with(|| {
                let g = ((r.0 as f64 + r.1) / period as f64).round() as u64;
                (g, k as i64)
            });
            let grid = (g0 + (k as i64 - k0) as u64) * period;
            let phase = (r.0.wrapping_sub(grid) as i64) as f64 + r.1;
            res.phase.add(phase);
            series[2].add(k, phase);
            // The slaves' differences move slowly (the loops act once per cycle): every 8th
            // cycle is sampled.
            if k % 8 == 0 {
                let mut worst = 0.0f64;
                for x in 0..seg.len() {
                    if x == reference {
                        continue;
                    }
                    if let Some(v) = sys(x, pu_ref) {
                        let d = (v.0.wrapping_sub(r.0) as i64) as f64 + (v.1 - r.1);
                        worst = worst.max(d.abs());
                    }
                }
                res.slave_diff.add(worst);
            }
            // The frame has passed the last slave when its last bit has: SYNC0 needs it by
            // then.
            let end_ps = pu_last + frame_wire_time_ps(n);
            if let Some(e) = sys(last, end_ps) {
                let end_after_grid = (e.0.wrapping_sub(grid) as i64) as f64 + e.1;
                let margin = shift - end_after_grid;
                res.margin.add(margin);
                if margin < 0.0 {
                    res.late_frames += 1;
                }
                res.latest_end_ns = res.latest_end_ns.max(end_after_grid);
            }
        }
        self.next_cycle = end;
        end - start
    }

    /// The result (of the cycles run so far).
    pub fn finish(self) -> RunResult {
        let mut res = self.res;
        let [a, b, c] = self.series;
        res.series = [a.finish(), b.finish(), c.finish()];
        res
    }
}

/// Runs method `method_name` in run `run` of the scenario, bring-up included. `progress` counts
/// simulated cycles.
pub fn run_one(
    s: &Scenario,
    method_name: &str,
    run: u32,
    progress: &AtomicU64,
) -> Result<RunResult, RunError> {
    let up = bring_up(s, run)?;
    let mut r = Run::new(s, &up, method_name)?;
    while r.remaining() > 0 {
        let n = r.step(4096);
        progress.fetch_add(n, Ordering::Relaxed);
    }
    Ok(r.finish())
}
