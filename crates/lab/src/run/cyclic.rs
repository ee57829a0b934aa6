//! A method's cyclic phase on the run's network: the session, the host's noise, and what the
//! run's observers measured at the end.

use super::*;

/// The host's noise of a block of cycles as the simulated host's timing (cycles outside the
/// block are drawn on the spot).
struct NoiseHost {
    first: u64,
    block: Arc<[CycleNoise]>,
    noise: HostNoise,
    send: SendMode,
    send_params: SendParams,
    seed: u64,
}

impl HostModel for NoiseHost {
    fn cycle(&self, cycle: u64) -> HostDelays {
        let n = cycle
            .checked_sub(self.first)
            .and_then(|k| self.block.get(k as usize).copied())
            .unwrap_or_else(|| self.noise.cycle(cycle));
        ecsync_sim::send::apply(self.send, &self.send_params, n, self.seed, cycle).delays
    }
}

/// One method's run in progress: the cyclic phase, resumable in steps of any number of cycles
/// (so that a scheduler can share the cores fairly between runs; the result does not depend on
/// the steps).
pub struct Run {
    sim: SimTransport,
    session: Session<Method>,
    noise: HostNoise,
    /// How the host sends, with what, and the run's seed its draws take.
    send: SendMode,
    send_params: SendParams,
    send_seed: u64,
    /// The run's noise drawn once for all methods (see [`SharedNoise`]); without it, each step
    /// draws its own.
    shared_noise: Option<Arc<SharedNoise>>,
    /// What the cycles measure.
    obs: Observers,
    next_cycle: u64,
    warmup_cycles: u64,
    total_cycles: u64,
}

impl std::fmt::Debug for Run {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Run")
            .field("method", &self.obs.res.method)
            .field("run", &self.obs.res.run)
            .field("next_cycle", &self.next_cycle)
            .finish_non_exhaustive()
    }
}

/// The fresh result of `entry`'s run `run`, one [`SlaveTruth`] per DC slave.
fn empty_result(
    s: &Scenario,
    entry: Entry,
    run: u32,
    dc_slaves: &[(usize, usize)],
    lock_ms: Option<f64>,
    controller: bool,
) -> RunResult {
    let per_slave = dc_slaves
        .iter()
        .map(|&(x, spec)| SlaveTruth {
            position: x as u16,
            name: s.slave_names.get(spec).cloned().unwrap_or_default(),
            margin: Stats::new(),
            latest_end_ns: f64::NEG_INFINITY,
            late_frames: 0,
            sync0_missed: 0,
            last_outputs_ns: None,
            drive_sm_events_missed: None,
            drive_count_at_start: None,
            drive_restarts: 0,
            sync0_missed_at_restart: 0,
            on_sync1: false,
        })
        .collect();
    RunResult {
        method: entry.name(),
        send: entry.send,
        launch_misses: 0,
        spin_ns: 0.0,
        run,
        cycles_done: 0,
        m_rs: Stats::new(),
        rs_is: Stats::new(),
        phase: Stats::new(),
        phase_error: Stats::new(),
        slave_diff: Stats::new(),
        margin: Stats::new(),
        per_slave,
        late_frames: 0,
        latest_end_ns: f64::NEG_INFINITY,
        lost_frames: 0,
        late_or_lost_frames: 0,
        frames_per_cycle: 1,
        wild_schedule_cycles: 0,
        grid_slips: 0,
        reached_end: false,
        bad_wkc: 0,
        series: Default::default(),
        series_block: Bands::new(s.cycles).block_cycles(),
        lock_ms,
        init_drift: None,
        controller: controller.then(ControllerTruth::default),
        frame_wire_ns: 0.0,
        max_round_trip_ns: 0.0,
        max_round_trip_unfaulted_ns: 0.0,
        longest_frame_fault: None,
        samples_error: None,
        faults: None,
        left_op: Vec::new(),
        recording_stopped: None,
    }
}

impl Run {
    /// Method `entry.kind`, sending as `entry.send` says, from the brought-up network `up`
    /// (which it copies).
    pub fn new(s: &Scenario, up: &BroughtUp, entry: Entry) -> Result<Run, RunError> {
        let mut sim = up.sim.fork();
        if let Some(f) = &s.faults
            && f.epoch == Epoch::Cyclic
        {
            sim.set_faults(FaultPlayer::new(f.clone(), up.seed));
        }
        let net = &up.net;
        let lock_ms = net.lock.time_to_lock_ns.map(|t| t as f64 / 1e6);
        let reference = usize::from(net.reference);

        let method: Method = s.params.build(entry.kind, &s.method_context());
        let noise = HostNoise::replaying(s.host, up.seed, s.host_trace.clone());
        let period = u64::from(s.cycle_ns);
        let init_frames = method.init_cycles().min(s.warmup_cycles);
        let has_log = method.controller_log().is_some();
        // The cyclic phase's host: its receive latency; a lost frame is given up half a cycle
        // after its send, or when the cycle's frames could have come back, if that is later
        // (a large network's frames take milliseconds on the wire: half a cycle would count
        // every one lost; the driver gives up at the next cycle's slot in any case).
        let rx_latency_ps = (s.host.rx_latency_ns * 1000.0) as u64;
        let way_round_ps = sim.segment().round_trip_ps();
        let cycle_wire_ps = |eng: &CyclicEngine<Method>| -> u64 {
            (0..eng.frame_count())
                .map(|k| frame_wire_time_ps(eng.frame_len_of(k)))
                .sum()
        };
        let cfg = SessionConfig {
            cycle_ns: s.cycle_ns,
            measure_init_frames: method.init_cycles().max(10_000).min(s.warmup_cycles.max(1)),
            // Slaves that lose their configuration (a power cycle) are brought back while the
            // cycle goes on, as on a real network.
            recovery: Some(ecsync_master::recovery::RecoveryConfig {
                cycle_ns: s.cycle_ns,
                sync0_shift_ns: s.sync0_shift_ns(),
                sync0_lead_ns: RECOVERY_SYNC0_LEAD_NS,
                timeouts: ecsync_master::bringup::BringupTimeouts::default(),
                static_drift_frames: RECOVERY_STATIC_DRIFT_FRAMES,
                sync_error_limit: s.sync_error_limit,
                oversampled: super::oversampled_of(sim.segment()),
            }),
        };
        // The first cycle: frames aimed at the target phase of the reference's grid, less the
        // mean time from the cycle's start to the frame's arrival at the reference that the
        // master knows of its own host (e_m and the NIC latency; j_s's mean it does not). On a
        // real host the reading holds the NIC's latency; the simulated bring-up runs with the
        // ideal host's few microseconds instead of the host model's, so the reading holds those
        // and the difference is taken off here.
        let aim = Aim::ReferenceGrid {
            now: sim.master_now(),
            target_phase_ns: s.target_phase_ns,
            lead: MasterDuration::from_ns(
                ((s.host.em_ns + s.host.tx_latency_ns) as u64)
                    .saturating_sub(sim.tx_latency_ps() / 1000),
            ),
        };
        let session = Session::new(net, method, aim, cfg, |eng| {
            let comes_back_ns =
                (cycle_wire_ps(eng) + way_round_ps + rx_latency_ps) / 1000 + REPLY_MARGIN_NS;
            CyclicLimits {
                reply_timeout: MasterDuration::from_ns((period / 2).max(comes_back_ns)),
                lost_in_a_row: u64::MAX,
                // (`hwstamp` runs only master-shift methods: see `SendMode::applies_to`.)
                t_ms_from_tx_stamp: entry.send == SendMode::Hwstamp,
                ..CyclicLimits::default()
            }
        })
        .map_err(|e| match e {
            SessionError::Frame(w) => RunError::Frame(w),
            SessionError::NoReference => RunError::Bringup(MasterError::Config(e.to_string())),
        })?;
        sim.set_rx_latency_ps(rx_latency_ps);
        let eng = session.engine();
        // The slaves whose SYNC0 the ground truth judges: those with a system time (SYNC0 runs
        // on it: a terminal with receive times only, as the EL2828, has none) and process
        // data that the bring-up took in. A coupler (no process data) takes no outputs at
        // SYNC0, and a slave that was absent then (hot-connected later) has no SYNC0 running:
        // neither has a deadline.
        let dc_slaves: Vec<usize> = (0..sim.segment().len())
            .filter(|&x| sim.segment().esc(x).model().dc.has_system_time())
            .filter(|&x| {
                net.slaves
                    .get(x)
                    .is_some_and(|n| n.outputs.1 > 0 || n.inputs.1 > 0)
            })
            .collect();
        let named: Vec<(usize, usize)> = dc_slaves
            .iter()
            .map(|&x| (x, sim.segment().spec_index(x)))
            .collect();
        // Which frame of a cycle carries each DC slave's outputs (its SYNC0 needs that one),
        // and how long that frame is on the wire.
        let out_frames: Vec<(usize, u64)> = dc_slaves
            .iter()
            .map(|&x| {
                let k = net
                    .slaves
                    .get(x)
                    .filter(|s| s.outputs.1 > 0)
                    .and_then(|s| eng.frame_of_logical(s.outputs.0))
                    .unwrap_or(0);
                (k, frame_wire_time_ps(eng.frame_len_of(k)))
            })
            .collect();
        let mut res = empty_result(s, entry, up.run, &named, lock_ms, has_log);
        res.frames_per_cycle = eng.frame_count();
        let truth = GroundTruth::new(GridSpec {
            reference,
            dc_slaves,
            out_frames,
            period_ns: period,
            shift_ns: f64::from(s.sync0_shift_ns()),
            target_ns: s.target_phase_ns,
            regrid: s.faults.is_some(),
            init_frames,
        });
        let obs = Observers::new(
            res,
            s.cycles,
            truth,
            s.faults.is_some(),
            s.warmup_cycles,
            net.expected_lrw_wkc,
            net.pdi_len,
            cycle_wire_ps(eng),
        );
        Ok(Run {
            sim,
            session,
            noise,
            send: entry.send,
            send_params: s.send,
            send_seed: up.seed,
            shared_noise: None,
            obs,
            next_cycle: 0,
            warmup_cycles: s.warmup_cycles,
            total_cycles: s.warmup_cycles + s.cycles,
        })
    }

    /// Writes one CSV row per recorded cycle to `dir/<method>-run<r>.csv` (`--samples`).
    pub fn write_samples(&mut self, dir: &Path) -> Result<(), RunError> {
        let path = dir.join(format!(
            "{}-run{}.csv",
            self.obs.res.method, self.obs.res.run
        ));
        let sink = SampleSink::create(
            &path,
            &self.obs.truth.dc_slaves,
            self.obs.res.controller.is_some(),
        )?;
        self.obs.samples = Some(sink);
        Ok(())
    }

    /// Takes the run's noise from `shared` (drawn once for all methods of the run) instead of
    /// drawing it; `shared` must hold this run's noise.
    pub fn share_noise(&mut self, shared: Arc<SharedNoise>) {
        debug_assert_eq!(*shared.noise(), self.noise);
        if *shared.noise() == self.noise {
            self.shared_noise = Some(shared);
        }
    }

    /// Has the master read every drive's SM-event-missed counter (0x1C32:0B) over CoE this
    /// often, in the cycles' spare slot, as `ecsync run` does (a comparison does not: its
    /// figures are the segment's own). The reads are [`Run::drive_counter_reads`].
    pub fn read_drive_counters_every(&mut self, every_ns: u64) {
        self.session
            .driver_mut()
            .set_sync_counters_every(Some(MasterDuration::from_ns(every_ns)));
    }

    /// The master's first and last read of each drive's 0x1C32:0B over CoE so far
    /// ([`Run::read_drive_counters_every`]), in network order.
    pub fn drive_counter_reads(
        &self,
    ) -> Vec<(
        ecsync_master::driver::SyncCounter,
        ecsync_master::driver::SyncCounter,
    )> {
        self.session.driver().sync_counters()
    }

    /// Hands every frame of the cycles run from now on to `tap` as the segment saw it (see
    /// [`ecsync_sim::transport::FrameTap`]: the judge of `ecsync serve` can follow a run of
    /// ecsync's own master); `None` removes it. The run's result does not change.
    pub fn set_frame_tap(&mut self, tap: Option<ecsync_sim::transport::FrameTap>) {
        self.sim.set_frame_tap(tap);
    }

    /// The simulator's transport (its segment's ground truth, its faults).
    pub fn sim(&self) -> &SimTransport {
        &self.sim
    }

    /// Cycles run so far (warm-up included).
    pub fn cycles_run(&self) -> u64 {
        self.next_cycle
    }

    /// Cycles still to run (warm-up included).
    pub fn remaining(&self) -> u64 {
        self.total_cycles.saturating_sub(self.next_cycle)
    }

    /// Recorded cycles run so far.
    pub fn recorded(&self) -> u64 {
        self.next_cycle.saturating_sub(self.warmup_cycles)
    }

    /// Runs up to `max_cycles` more cycles; returns how many ran.
    pub fn step(&mut self, max_cycles: u64) -> u64 {
        let start = self.next_cycle;
        let end = self.total_cycles.min(start.saturating_add(max_cycles));
        if end <= start {
            return 0;
        }
        // The noise of these cycles, drawn in one go (or taken from the other methods' draw),
        // is the simulated host's timing.
        let block: Arc<[CycleNoise]> = match &self.shared_noise {
            Some(sh) => sh.block(start, end - start),
            None => (start..end).map(|i| self.noise.cycle(i)).collect(),
        };
        // What the send mode does with the recorded cycles' noise: CPU spun, launch times
        // missed (the same pure function the transport applies).
        if self.send != SendMode::Plain {
            for (k, n) in block.iter().enumerate() {
                let i = start + k as u64;
                if i < self.warmup_cycles {
                    continue;
                }
                let o =
                    ecsync_sim::send::apply(self.send, &self.send_params, *n, self.send_seed, i);
                self.obs.res.spin_ns += o.spin_ns;
                self.obs.res.launch_misses += u64::from(o.delays.dropped);
            }
        }
        self.sim.set_host(Box::new(NoiseHost {
            first: start,
            block,
            noise: self.noise.clone(),
            send: self.send,
            send_params: self.send_params,
            seed: self.send_seed,
        }));
        // The simulator cannot fail, and a lab run stops only at its cycle count.
        match self
            .session
            .run(&mut self.sim, end - start, None, &mut self.obs)
        {
            Ok(_) => {}
            Err(never) => match never {},
        }
        self.next_cycle = self.session.engine().cycle().max(start);
        self.next_cycle - start
    }

    /// The result (of the cycles run so far).
    pub fn finish(self) -> Result<RunResult, RunError> {
        let Observers {
            mut res,
            series,
            truth,
            faults,
            samples,
            ..
        } = self.obs;
        res.reached_end = self.next_cycle >= self.total_cycles;
        let driver = self.session.driver();
        let t0 = self.session.first().as_ns();
        let ms = |t: u64| t.saturating_sub(t0) as f64 / 1e6;
        for e in driver.recoveries() {
            let Some(Ok(r)) = &e.outcome else { continue };
            for l in &r.left_op {
                res.left_op.push(LeftOpOut {
                    run: res.run,
                    slave: l.position + 1,
                    state: l.state_name(),
                    al_status_code: l.al_status_code(),
                    reason: l.reason(),
                    found_ms: ms(e.started.as_ns()),
                    // The recovery ends once every slave it took on is in OP again.
                    back_in_op_ms: e.ended.map(MasterInstant::as_ns).map(ms),
                });
            }
        }
        res.wild_schedule_cycles = self.session.engine().health().wild_schedule_cycles;
        res.grid_slips = truth.grid_slips;
        res.faults =
            faults.map(|f| f.finish(&self.sim, driver, self.session.engine().health(), t0));
        if let (Some(ft), Some(p)) = (res.faults.as_mut(), self.sim.faults()) {
            ft.clock_step_slots = clock_step_slots(p, self.session.engine().config().period_ns);
        }
        let [a, b, c] = series;
        res.series = [a.finish(), b.finish(), c.finish()];
        let init_frames = truth.init_frames;
        if init_frames >= 2 && self.next_cycle >= init_frames {
            let d = truth.init_fit.slope().unwrap_or(0.0);
            res.init_drift = Some(InitDrift {
                frames: init_frames,
                drift_ns_per_cycle: d,
                offset_ns: d * (init_frames - 1) as f64 / 2.0,
            });
        }
        if let Some(sk) = samples {
            res.samples_error = sk.finish();
        }
        Ok(res)
    }
}

/// The cycle slots the clock steps `p` played moved the master's time by: |step| over the
/// period `period_ns`, plus two each (the cycle it came in, and the one its detection takes).
fn clock_step_slots(p: &ecsync_sim::fault::FaultPlayer, period_ns: u32) -> u64 {
    use ecsync_sim::fault::{Edge, FaultKind};
    let period = u64::from(period_ns.max(1));
    (p.events().iter())
        .filter(|e| e.edge == Edge::Start)
        .filter_map(|e| match p.schedule().faults.get(e.fault)?.kind {
            FaultKind::ClockStep { step_ns } => Some(step_ns.unsigned_abs() / period + 2),
            _ => None,
        })
        .sum()
}
