//! Scenarios: a segment, a host, and how to run the comparison, in one TOML file. Errors name
//! the file, the line, the field and the fix; nothing panics on bad input. The same checks run
//! on a scenario whose values the command line changed ([`Scenario::check`]), so a value is
//! refused with the same words wherever it came from. The errors are ecsync-sim's
//! ([`ConfigSource`] locates every one); the methods' tables and their checks are ecsync-dc's
//! registry ([`MethodParams`]).

use ecsync_dc::method::{MethodContext, MethodKind, MethodParams, ParamError};
use ecsync_sim::SlaveSpec;
pub use ecsync_sim::config::Problem;
use ecsync_sim::config::{ConfigError, ConfigSource, SegmentConfig};
use ecsync_sim::host::{Bursts, HostParams, Jitter};
use ecsync_sim::host_trace::Replay;
use ecsync_sim::send::{Entry, SendMode, SendParams};
use serde::Deserialize;
use std::sync::Arc;

/// The cycle times a scenario accepts, us: EtherCAT cycles run from tens of microseconds to
/// about 100 ms.
pub const CYCLE_US_RANGE: (f64, f64) = (10.0, 100_000.0);

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    /// Missing, it is an empty segment, refused as one (naming `[[segment.slave]]`).
    #[serde(default)]
    segment: SegmentConfig,
    #[serde(default)]
    host: HostFile,
    #[serde(default)]
    run: RunFile,
    /// The methods' tables, read by the registry's names (ecsync-dc).
    #[serde(default)]
    methods: MethodParams,
    /// How the host sends (ecsync_sim::send).
    #[serde(default)]
    send: SendFile,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SendFile {
    modes: Option<Vec<String>>,
    spin_margin_us: Option<f64>,
    spin_residual_ns: Option<f64>,
    txtime_lead_us: Option<f64>,
    txtime_delta_us: Option<f64>,
    launch_jitter_ns: Option<f64>,
    launch_to_wire_ns: Option<f64>,
    hw_stamp_error_ns: Option<f64>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct HostFile {
    preset: Option<String>,
    master_ppm: Option<f64>,
    master_wander_ppm_per_sqrt_s: Option<f64>,
    js: Option<Jitter>,
    em_ns: Option<f64>,
    em_jitter: Option<Jitter>,
    jc: Option<Jitter>,
    tx_latency_ns: Option<f64>,
    rx_latency_ns: Option<f64>,
    bursts: Option<Bursts>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RunFile {
    #[serde(default = "d_cycle")]
    cycle_us: f64,
    #[serde(default = "d_shift")]
    sync0_shift_pct: f64,
    #[serde(default)]
    target_phase_us: f64,
    #[serde(default = "d_runs")]
    runs: i64,
    #[serde(default = "d_cycles")]
    cycles: i64,
    #[serde(default = "d_warmup")]
    warmup_s: f64,
    #[serde(default = "d_seed")]
    seed: u64,
    #[serde(default = "d_methods")]
    methods: Vec<String>,
    #[serde(default = "d_static")]
    static_drift_frames: i64,
    /// 0x10F1:02 the master writes to every DC drive in PRE-OP (absent: not written).
    #[serde(default)]
    sync_error_limit: Option<i64>,
}

fn d_cycle() -> f64 {
    1000.0
}
fn d_shift() -> f64 {
    30.0
}
fn d_runs() -> i64 {
    5
}
fn d_cycles() -> i64 {
    1_800_000
}
fn d_warmup() -> f64 {
    120.0
}
fn d_seed() -> u64 {
    2024
}
fn d_methods() -> Vec<String> {
    MethodKind::DEFAULT
        .iter()
        .map(|m| m.name().to_string())
        .collect()
}
fn d_static() -> i64 {
    15_000
}

impl Default for RunFile {
    fn default() -> Self {
        RunFile {
            cycle_us: d_cycle(),
            sync0_shift_pct: d_shift(),
            target_phase_us: 0.0,
            runs: d_runs(),
            cycles: d_cycles(),
            warmup_s: d_warmup(),
            seed: d_seed(),
            methods: d_methods(),
            static_drift_frames: d_static(),
            sync_error_limit: None,
        }
    }
}

/// A validated scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Where it came from, for reports.
    pub name: String,
    /// The segment.
    pub slaves: Vec<SlaveSpec>,
    /// The slaves' names as the file gives them, in the order of `slaves` (the tables and
    /// plots name slaves by these, not by position alone).
    pub slave_names: Vec<String>,
    /// Host preset name (or "`<preset> (modified)`").
    pub host_name: String,
    /// The host.
    pub host: HostParams,
    /// The master PC's crystal error the file's `[host] master_ppm` gives, if it does: the
    /// machine's own, kept when another host preset replaces the rest (`compare --host`).
    pub file_master_ppm: Option<f64>,
    /// A recorded host trace replayed instead of the model's j_s, e_m (and TX delay where the
    /// trace has it): `compare --host-trace`.
    pub host_trace: Option<Arc<Replay>>,
    /// Cycle time and SYNC0 period, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift after the DC grid point, % of the cycle.
    pub sync0_shift_pct: f64,
    /// Where every master-shift method aims the frame's arrival at the reference against the
    /// DC grid point (the vendor note's set value, counted from the grid), ns.
    pub target_phase_ns: i64,
    /// Runs with different seeds.
    pub runs: u32,
    /// Recorded cycles per run.
    pub cycles: u64,
    /// Warm-up cycles per run (not recorded).
    pub warmup_cycles: u64,
    /// Base seed.
    pub seed: u64,
    /// Methods to compare, in report order.
    pub methods: Vec<MethodKind>,
    /// Send modes every method runs with (`[send] modes`; plain alone by default).
    pub send_modes: Vec<SendMode>,
    /// The send modes' parameters.
    pub send: SendParams,
    /// Static drift compensation frames of the bring-up.
    pub static_drift_frames: u32,
    /// The sync error counter limit (0x10F1:02) the master writes over CoE to every drive it
    /// sets to DC SYNC0, in PRE-OP (`[run] sync_error_limit`; `None`: not written, each drive
    /// keeps its own: the virtual drive's 0 counts without reacting). Past it a drive leaves
    /// OP with AL status code 0x001A, and the comparison reports it.
    pub sync_error_limit: Option<u16>,
    /// Every method's parameters (the `[methods.<name>]` tables; defaults where absent).
    pub params: MethodParams,
    /// Faults to play on every run (`compare --faults FILE`); `None`: none.
    pub faults: Option<ecsync_sim::fault::FaultSchedule>,
}

/// The problem a refused method parameter is, located in the scenario like any other.
pub fn param_problem(e: ParamError) -> Problem {
    Problem::new(
        e.table.to_string(),
        e.key,
        e.message().to_string(),
        e.fix().to_string(),
    )
}

/// Plural of a count: "1 run", "2 runs".
pub fn plural(n: u64, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

impl Scenario {
    /// The comparison's columns: every method with every send mode, method by method.
    pub fn entries(&self) -> Vec<Entry> {
        self.methods
            .iter()
            .flat_map(|&kind| {
                self.send_modes
                    .iter()
                    .filter(move |m| m.applies_to(kind))
                    .map(move |&send| Entry { kind, send })
            })
            .collect()
    }

    /// SYNC0 shift, ns.
    pub fn sync0_shift_ns(&self) -> u32 {
        (f64::from(self.cycle_ns) * self.sync0_shift_pct / 100.0).round() as u32
    }

    /// Whether this is the letter's testbed (the paper-2024 segment, its host and cycle), the
    /// only scenario on which the letter's Table 1 values are a comparison.
    pub fn is_letter_testbed(&self) -> bool {
        let Ok(p) = parse("paper-2024", ecsync_sim::preset::PAPER_2024_TOML) else {
            return false;
        };
        // Faults and a replayed host trace are not the letter's testbed, however alike the rest.
        self.slaves == p.slaves
            && self.host == p.host
            && self.cycle_ns == p.cycle_ns
            && self.faults.is_none()
            && self.host_trace.is_none()
    }

    /// The method's initialisation frames (0 for methods without).
    pub fn init_frames(&self, method: MethodKind) -> u64 {
        self.params.init_frames(method)
    }

    /// What every method of the scenario shares: its cycle and target phase.
    pub fn method_context(&self) -> MethodContext {
        MethodContext {
            cycle_ns: self.cycle_ns,
            target_phase_ns: self.target_phase_ns,
        }
    }

    /// A target phase at or after SYNC0 (every frame would reach the drives after their
    /// pulse, and the margin between them is none): the problem, on the target's field.
    pub fn target_after_sync0(&self) -> Option<Problem> {
        let shift_ns = i64::from(self.sync0_shift_ns());
        (self.target_phase_ns >= shift_ns).then(|| {
            let us = |ns: i64| ns as f64 / 1000.0;
            Problem::new(
                "run",
                "target_phase_us",
                format!(
                    "{:.1} us is at or after SYNC0 ({:.1} us into the cycle at a {} % shift): every frame would reach the drives after their pulse",
                    us(self.target_phase_ns),
                    us(shift_ns),
                    self.sync0_shift_pct
                ),
                format!(
                    "aim before SYNC0 (target_phase_us below {:.1}, less the frames' way through the network), or put SYNC0 later (sync0_shift_pct above {:.1}, the same way more)",
                    us(shift_ns),
                    100.0 * self.target_phase_ns as f64 / f64::from(self.cycle_ns)
                ),
            )
        })
    }

    /// Checks every value a run depends on; the first problem found.
    pub fn check(&self) -> Result<(), Problem> {
        // The cycle first: the host's jitter is judged against it.
        let (lo, hi) = CYCLE_US_RANGE;
        let cycle_us = f64::from(self.cycle_ns) / 1000.0;
        if !(lo..=hi).contains(&cycle_us) {
            return Err(cycle_problem(cycle_us));
        }
        check_host(&self.host, self.cycle_ns)?;
        if !(self.sync0_shift_pct.is_finite() && (0.0..100.0).contains(&self.sync0_shift_pct)) {
            return Err(Problem::new(
                "run",
                "sync0_shift_pct",
                format!("{} % is not within the cycle", self.sync0_shift_pct),
                "give a percentage from 0 up to (not including) 100: SYNC0 fires that far after the DC grid point",
            ));
        }
        let ctx = self.method_context();
        ctx.check().map_err(param_problem)?;
        if let Some(p) = self.target_after_sync0() {
            return Err(p);
        }
        if !(1..=1000).contains(&self.runs) {
            return Err(Problem::new(
                "run",
                "runs",
                plural(u64::from(self.runs), "run", "runs"),
                "give between 1 and 1000 runs",
            ));
        }
        if !(1..=1_000_000_000).contains(&self.cycles) {
            return Err(Problem::new(
                "run",
                "cycles",
                format!("{} recorded cycles", self.cycles),
                "give between 1 and 1000000000 cycles",
            ));
        }
        let warmup_s = self.warmup_cycles as f64 * f64::from(self.cycle_ns) * 1e-9;
        if warmup_s > 86_400.0 {
            return Err(Problem::new(
                "run",
                "warmup_s",
                format!("{warmup_s} s of warm-up"),
                "give between 0 and 86400 s",
            ));
        }
        if self.static_drift_frames > 10_000_000 {
            return Err(Problem::new(
                "run",
                "static_drift_frames",
                format!("{}", self.static_drift_frames),
                "give between 0 and 10000000 frames",
            ));
        }
        if self.methods.is_empty() {
            return Err(Problem::new(
                "run",
                "methods",
                "no methods",
                format!("name at least one of: {}", MethodKind::list()),
            ));
        }
        if self.send_modes.is_empty() {
            return Err(Problem::new(
                "send",
                "modes",
                "no send modes",
                "name at least one of: plain, spin, txtime, hwstamp",
            ));
        }
        if self.entries().is_empty() {
            return Err(Problem::new(
                "send",
                "modes",
                "hwstamp alone with bus-shift methods only: nothing to run (a transmit stamp comes after the send, which a bus-shift method has already written into the frame)",
                "add a master-shift method, or the send mode plain",
            ));
        }
        if let Err((field, message)) = self.send.validate(self.cycle_ns, &self.send_modes) {
            // The file gives the long ones in us.
            let key = match field {
                "spin_margin_ns" => "spin_margin_us",
                "txtime_lead_ns" => "txtime_lead_us",
                "txtime_delta_ns" => "txtime_delta_us",
                k => k,
            };
            return Err(Problem::new(
                "send",
                key,
                message,
                "give a time from 0 up to the cycle (txtime_delta_us at most txtime_lead_us)",
            ));
        }
        self.params.check().map_err(param_problem)?;
        for &m in &self.methods {
            self.params.check_use(m, &ctx).map_err(param_problem)?;
        }
        // Initialisation frames happen in the warm-up, which must hold them.
        for &m in &self.methods {
            let init = self.init_frames(m);
            if init > self.warmup_cycles {
                return Err(Problem::new(
                    "run",
                    "warmup_s",
                    format!(
                        "a warm-up of {} is shorter than {m}'s {} initialisation frames (methods.{m}.init_frames)",
                        plural(self.warmup_cycles, "cycle", "cycles"),
                        init
                    ),
                    format!(
                        "give a warm-up of at least {} s, or fewer init_frames",
                        (init as f64 * f64::from(self.cycle_ns) * 1e-9 * 1000.0).ceil() / 1000.0
                    ),
                ));
            }
        }
        Ok(())
    }
}

fn cycle_problem(cycle_us: f64) -> Problem {
    let (lo, hi) = CYCLE_US_RANGE;
    // The millisecond reading is a hint only when it is a cycle this file takes (not for
    // inf, nor for 1e9 us, whose reading in ms is out of range as well).
    let hint = if cycle_us > hi && (lo..=hi).contains(&(cycle_us / 1000.0)) {
        format!(
            " ({cycle_us} us is {} ms: did you mean {} us?)",
            cycle_us / 1000.0,
            cycle_us / 1000.0
        )
    } else {
        String::new()
    };
    Problem::new(
        "run",
        "cycle_us",
        format!("a cycle of {cycle_us} us is not an EtherCAT cycle{hint}"),
        format!("give a cycle time between {lo} and {hi} us, e.g. 1000 for 1 ms"),
    )
}

/// Checks the host's numbers against the cycle.
fn check_host(host: &HostParams, cycle_ns: u32) -> Result<(), Problem> {
    if !(host.master_ppm.is_finite() && host.master_ppm.abs() <= 500.0) {
        return Err(Problem::new(
            "host",
            "master_ppm",
            format!("{} ppm is not a crystal error", host.master_ppm),
            "give the master clock's error against real time, between -500 and 500 ppm (PC crystals are within +-100)",
        ));
    }
    let cycle = f64::from(cycle_ns);
    for (name, j) in [
        ("js", host.js),
        ("em_jitter", host.em_jitter),
        ("jc", host.jc),
    ] {
        let table = format!("host.{name}");
        if let Err((field, why)) = j.validate() {
            return Err(Problem::new(
                &table,
                field,
                why,
                "give a finite value >= 0 (tail_p between 0 and 1)",
            ));
        }
        if j.sigma_ns > cycle {
            return Err(Problem::new(
                &table,
                "sigma_ns",
                format!(
                    "a jitter of {} ns is more than the cycle ({} ns): every frame would miss its cycle",
                    j.sigma_ns, cycle
                ),
                "give the standard deviation in ns (a loaded PREEMPT_RT host: 16000; a stock kernel: 25000)",
            ));
        }
        if j.tail_mean_ns > 100.0 * cycle || j.tail_mean_ns > 1e9 {
            return Err(Problem::new(
                &table,
                "tail_mean_ns",
                format!("pulses of {} ns on average", j.tail_mean_ns),
                "give the mean pulse in ns, at most 100 cycles (and 1 s)",
            ));
        }
    }
    for (key, v) in [
        ("em_ns", host.em_ns),
        ("tx_latency_ns", host.tx_latency_ns),
        ("rx_latency_ns", host.rx_latency_ns),
    ] {
        if !(v.is_finite() && v >= 0.0 && v < cycle) {
            return Err(Problem::new(
                "host",
                key,
                format!("{v} ns must be a number >= 0 and shorter than the cycle ({cycle} ns)"),
                "give the time in ns (the letter's host: em_ns 20000, tx_latency_ns 15000, rx_latency_ns 10000)",
            ));
        }
    }
    if let Err((field, why)) = host.bursts.validate() {
        return Err(Problem::new(
            "host.bursts",
            field,
            why,
            "give p in [0, 1), mean_cycles >= 1 and js_scale in (0, 1000] (ecsync host fit writes them)",
        ));
    }
    let w = host.master_wander_ppm_per_sqrt_s;
    if !(w.is_finite() && (0.0..=10.0).contains(&w)) {
        return Err(Problem::new(
            "host",
            "master_wander_ppm_per_sqrt_s",
            format!("{w}"),
            "give a random-walk wander between 0 and 10 ppm per sqrt(s) (a quartz: 0.005)",
        ));
    }
    Ok(())
}

/// Parses and checks a scenario: the segment, then the host, the run and the send tables in
/// that order (the first bad field is the one reported), then the whole.
pub fn parse(file: &str, text: &str) -> Result<Scenario, ConfigError> {
    let src = ConfigSource::new(file, text);
    let f: File = src.deserialize()?;
    let slaves = f.segment.to_specs(file, text, "segment")?;
    let (host_name, host) = f.host.params(&src)?;
    let run = f.run.check(&src)?;
    let (send_modes, send) = f.send.params(&src)?;
    let r = &f.run;
    let slave_names = f
        .segment
        .slave
        .iter()
        .map(|sp| sp.get_ref().name.clone())
        .collect();
    let s = Scenario {
        name: file.to_string(),
        slaves,
        slave_names,
        host_name,
        host,
        file_master_ppm: f.host.master_ppm,
        host_trace: None,
        cycle_ns: run.cycle_ns,
        sync0_shift_pct: r.sync0_shift_pct,
        target_phase_ns: run.target_phase_ns,
        runs: r.runs as u32,
        cycles: r.cycles as u64,
        warmup_cycles: (r.warmup_s * 1e9 / f64::from(run.cycle_ns)).round() as u64,
        seed: r.seed,
        methods: run.methods,
        static_drift_frames: r.static_drift_frames as u32,
        sync_error_limit: run.sync_error_limit,
        params: f.methods,
        faults: None,
        send_modes,
        send,
    };
    s.check().map_err(|p| src.locate(p))?;
    Ok(s)
}

impl HostFile {
    /// The host: its preset with the file's overrides; its name says "(modified)" if any.
    fn params(&self, src: &ConfigSource<'_>) -> Result<(String, HostParams), ConfigError> {
        let preset = self
            .preset
            .clone()
            .unwrap_or_else(|| "preempt-rt-stress".to_string());
        let mut host = HostParams::preset(&preset).ok_or_else(|| {
            src.error(
                "host",
                "preset",
                format!("unknown host preset \"{preset}\""),
                format!("use one of: {}", HostParams::PRESETS.join(", ")),
            )
        })?;
        let h = self;
        let custom = h.master_ppm.is_some()
            || h.js.is_some()
            || h.jc.is_some()
            || h.em_ns.is_some()
            || h.em_jitter.is_some()
            || h.tx_latency_ns.is_some()
            || h.rx_latency_ns.is_some()
            || h.master_wander_ppm_per_sqrt_s.is_some()
            || h.bursts.is_some();
        if let Some(v) = h.master_ppm {
            host.master_ppm = v;
        }
        if let Some(v) = h.master_wander_ppm_per_sqrt_s {
            host.master_wander_ppm_per_sqrt_s = v;
        }
        if let Some(v) = h.js {
            host.js = v;
        }
        if let Some(v) = h.em_ns {
            host.em_ns = v;
        }
        if let Some(v) = h.em_jitter {
            host.em_jitter = v;
        }
        if let Some(v) = h.jc {
            host.jc = v;
        }
        if let Some(v) = h.tx_latency_ns {
            host.tx_latency_ns = v;
        }
        if let Some(v) = h.rx_latency_ns {
            host.rx_latency_ns = v;
        }
        if let Some(v) = h.bursts {
            host.bursts = v;
        }
        let name = if custom {
            format!("{preset} (modified)")
        } else {
            preset
        };
        Ok((name, host))
    }
}

/// What `[run]` gives that needs more than a copy, checked.
struct RunChecked {
    /// The cycle, ns.
    cycle_ns: u32,
    /// Where every master-shift method aims, ns after the DC grid point.
    target_phase_ns: i64,
    /// The methods in the report's order, each once, whatever the file's order.
    methods: Vec<MethodKind>,
    /// 0x10F1:02 for the drives, if the file sets it.
    sync_error_limit: Option<u16>,
}

impl RunFile {
    /// Checks the cycle, the target, the counts, the warm-up, the methods and the sync error
    /// counter limit.
    fn check(&self, src: &ConfigSource<'_>) -> Result<RunChecked, ConfigError> {
        let err = |key: &str, message: String, fix: &str| src.error("run", key, message, fix);
        let r = self;
        let (lo, hi) = CYCLE_US_RANGE;
        if !(r.cycle_us.is_finite() && (lo..=hi).contains(&r.cycle_us)) {
            return Err(src.locate(cycle_problem(r.cycle_us)));
        }
        let cycle_ns = (r.cycle_us * 1000.0).round() as u32;
        let target_phase_ns = MethodContext::target_phase_from_us(r.target_phase_us)
            .map_err(|e| src.locate(param_problem(e)))?;
        for (key, v, lo, hi) in [
            ("runs", r.runs, 1, 1000),
            ("cycles", r.cycles, 1, 1_000_000_000),
            ("static_drift_frames", r.static_drift_frames, 0, 10_000_000),
        ] {
            if v < lo || v > hi {
                return Err(err(
                    key,
                    format!("{v}"),
                    &format!("give between {lo} and {hi}"),
                ));
            }
        }
        if !(r.warmup_s.is_finite() && r.warmup_s >= 0.0 && r.warmup_s <= 86_400.0) {
            return Err(err(
                "warmup_s",
                format!("{} s of warm-up", r.warmup_s),
                "give between 0 and 86400 s",
            ));
        }
        let mut methods = Vec::new();
        for m in &r.methods {
            match m.parse::<MethodKind>() {
                Ok(k) => methods.push(k),
                Err(_) => {
                    return Err(err(
                        "methods",
                        format!("unknown method \"{m}\""),
                        &format!("use: {}", MethodKind::list()),
                    ));
                }
            }
        }
        // SSC keeps 0x10F1:02 as an UNSIGNED16 (TOBJ10F1.u16SyncErrorCounterLimit).
        let sync_error_limit = match r.sync_error_limit {
            None => None,
            Some(v) => Some(u16::try_from(v).map_err(|_| {
                err(
                    "sync_error_limit",
                    format!("{v} is not a sync error counter limit (0x10F1:02 is an UNSIGNED16)"),
                    "give 0 to 65535: each missed SYNC0 adds 3 to the drive's counter and each good cycle takes 1 away, past the limit the drive leaves OP with 0x001A (ETG's slave stack code: 4 by default; 0 switches the reaction off); or leave it out to keep the drives' own",
                )
            })?),
        };
        Ok(RunChecked {
            cycle_ns,
            target_phase_ns,
            // Report order, each once, whatever the file's order.
            methods: MethodKind::ALL
                .into_iter()
                .filter(|m| methods.contains(m))
                .collect(),
            sync_error_limit,
        })
    }
}

impl SendFile {
    /// The send modes (report order, each once; `plain` alone if the file names none) and
    /// their parameters, the defaults where the file says nothing.
    fn params(&self, src: &ConfigSource<'_>) -> Result<(Vec<SendMode>, SendParams), ConfigError> {
        let sf = self;
        let mut send_modes = Vec::new();
        for m in sf.modes.clone().unwrap_or_else(|| vec!["plain".into()]) {
            match m.parse::<SendMode>() {
                Ok(k) => send_modes.push(k),
                Err(e) => {
                    return Err(src.error(
                        "send",
                        "modes",
                        e,
                        "use plain, spin, txtime and/or hwstamp",
                    ));
                }
            }
        }
        let d = SendParams::default();
        let us = |v: Option<f64>, dflt: f64| v.map_or(dflt, |x| x * 1000.0);
        let send = SendParams {
            spin_margin_ns: us(sf.spin_margin_us, d.spin_margin_ns),
            spin_residual_ns: sf.spin_residual_ns.unwrap_or(d.spin_residual_ns),
            txtime_lead_ns: us(sf.txtime_lead_us, d.txtime_lead_ns),
            txtime_delta_ns: us(sf.txtime_delta_us, d.txtime_delta_ns),
            launch_jitter_ns: sf.launch_jitter_ns.unwrap_or(d.launch_jitter_ns),
            launch_to_wire_ns: sf.launch_to_wire_ns.unwrap_or(d.launch_to_wire_ns),
            hw_stamp_error_ns: sf.hw_stamp_error_ns.unwrap_or(d.hw_stamp_error_ns),
        };
        // Report order, each once.
        let send_modes = SendMode::ALL
            .into_iter()
            .filter(|m| send_modes.contains(m))
            .collect();
        Ok((send_modes, send))
    }
}

/// Parses `table` (a `[host]` table, [`ecsync_sim::host_fit::HostFit::to_toml`]) in the place of the letter's
/// scenario's own, as `compare` would read it.
pub fn check_in_scenario(table: &str) -> Result<Scenario, ConfigError> {
    let body = table.split_once("[host]\n").map_or(table, |(_, b)| b);
    let text =
        ecsync_sim::preset::PAPER_2024_TOML.replacen("preset = \"preempt-rt-stress\"\n", body, 1);
    parse("fitted [host]", &text)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn preset() -> String {
        ecsync_sim::preset::PAPER_2024_TOML.to_string()
    }

    #[test]
    fn the_preset_parses() {
        let s = parse("paper-2024.toml", &preset()).unwrap();
        assert_eq!(s.slaves.len(), 6);
        assert_eq!(s.cycle_ns, 1_000_000);
        assert_eq!(s.runs, 5);
        assert_eq!(s.cycles, 1_800_000);
        assert_eq!(s.warmup_cycles, 120_000);
        assert_eq!(s.methods, MethodKind::DEFAULT);
        assert_eq!(s.params.median.window, 11);
        assert_eq!(s.target_phase_ns, 0);
        assert!(s.is_letter_testbed());
    }

    fn bad(replace: (&str, &str)) -> ConfigError {
        let t = preset().replace(replace.0, replace.1);
        assert_ne!(t, preset(), "the replacement must apply: {replace:?}");
        parse("p.toml", &t).unwrap_err()
    }

    #[test]
    fn bad_scenarios_name_field_and_fix() {
        let e = bad(("cycle_us = 1000", "cycle_us = -1000"));
        assert_eq!(e.field, "run.cycle_us");
        assert!(e.line.is_some() && e.fix.contains("between"), "{e}");
        let e = bad(("window = 11", "window = 10"));
        assert_eq!(e.field, "methods.median.window");
        assert!(e.to_string().contains("odd"), "{e}");
        let e = bad(("window = 11", "window = 0"));
        assert_eq!(e.field, "methods.median.window");
        let e = bad(("cycle_us = 1000", "cycle_us = 1000\ncycle_uss = 3"));
        assert!(e.message.contains("unknown field"), "{e}");
        assert!(e.to_string().contains("cycle_uss"), "{e}");
        let e = bad(("preset = \"preempt-rt-stress\"", "preset = \"rt\""));
        assert_eq!(e.field, "host.preset");
        assert!(e.fix.contains("preempt-rt-idle"));
    }

    #[test]
    fn implausible_values_are_refused_with_a_hint() {
        // A 1 s cycle: the hint names the millisecond reading.
        let e = bad(("cycle_us = 1000", "cycle_us = 1000000"));
        assert_eq!(e.field, "run.cycle_us");
        assert!(e.message.contains("did you mean 1000 us"), "{e}");
        // No hint where the reading in ms is no cycle either (it said "inf us is inf ms: did
        // you mean inf us?", and "did you mean 1000000 us?" for 1e9).
        for v in ["inf", "1e9"] {
            let e = bad(("cycle_us = 1000", &format!("cycle_us = {v}")));
            assert_eq!(e.field, "run.cycle_us");
            assert!(!e.message.contains("did you mean"), "{e}");
        }
        // Absurd jitter.
        let e = bad((
            "preset = \"preempt-rt-stress\"",
            "preset = \"preempt-rt-stress\"\njs = { sigma_ns = 1e9 }",
        ));
        assert_eq!(e.field, "host.js.sigma_ns");
        assert!(e.line.is_some(), "{e}");
        let e = bad((
            "preset = \"preempt-rt-stress\"",
            "preset = \"preempt-rt-stress\"\nem_ns = 2e6",
        ));
        assert_eq!(e.field, "host.em_ns");
        let e = bad(("sync0_shift_pct = 30", "sync0_shift_pct = -10"));
        assert_eq!(e.field, "run.sync0_shift_pct");
        let e = bad(("target_phase_us = 0", "target_phase_us = 700"));
        assert_eq!(e.field, "run.target_phase_us");
    }

    #[test]
    fn warmup_shorter_than_the_init_is_refused() {
        let e = bad(("warmup_s = 120", "warmup_s = 5"));
        assert_eq!(e.field, "run.warmup_s");
        assert!(
            e.message.contains("median's 10000 initialisation frames"),
            "{e}"
        );
        assert!(e.fix.contains("at least 10 s"), "{e}");
        // Without the methods that have an init, a short warm-up is fine.
        let t = preset().replace("warmup_s = 120", "warmup_s = 5").replace(
            "methods = [\"median\", \"median-fit\", \"pi-m2s\", \"bus-shift\", \"dcm-bus-shift\", \"dcm-master-shift\", \"snap\", \"soem-pi\"]",
            "methods = [\"bus-shift\", \"snap\"]",
        );
        let s = parse("p.toml", &t).unwrap();
        assert_eq!(s.methods, [MethodKind::BusShift, MethodKind::Snap]);
    }

    /// The `[methods]` table is read by the registry's names: an unknown method's table, an
    /// unknown field and a bad enum value are refused, located, naming what is expected.
    #[test]
    fn method_tables_are_read_by_the_registrys_names() {
        let t = preset() + "\n[methods.medain]\nwindow = 5\n";
        let e = parse("p.toml", &t).unwrap_err();
        assert!(e.message.contains("unknown field `medain`"), "{e}");
        assert!(
            e.message.contains("`median-fit`") && e.message.contains("`soem-pi`"),
            "{e}"
        );
        assert!(e.line.is_some() && e.fix.contains("spelling"), "{e}");
        let e = bad(("kp = 0.125 ", "kpp = 0.125 "));
        assert!(
            e.message
                .contains("unknown field `kpp`, expected one of `kp`, `ki`, `init_frames`"),
            "{e}"
        );
        let e = bad((
            "set_value_ref = \"frame-send\"",
            "set_value_ref = \"cycle-end\"",
        ));
        assert!(
            e.message.contains("`frame-send`") && e.message.contains("`cycle-start`"),
            "{e}"
        );
        // A table's values are its method's parameters; the other tables keep theirs.
        let t = preset()
            .replacen(
                "[methods.dcm-bus-shift]\nset_value_ref = \"frame-send\"",
                "[methods.dcm-bus-shift]\nset_value_ref = \"cycle-start\"",
                1,
            )
            .replacen("kp = 0.004", "kp = 0.002", 1);
        let s = parse("p.toml", &t).unwrap();
        assert_eq!(s.params.dcm_bus_shift.kp, 0.002);
        assert_eq!(
            s.params.dcm_bus_shift.set_value_ref,
            ecsync_dc::SetValueRef::CycleStart
        );
        assert_eq!(
            s.params.dcm_master_shift,
            ecsync_dc::method::DcmSettings {
                max_slew_ppm: Some(0.0),
                ..Default::default()
            }
        );
    }

    /// `[run] sync_error_limit`: absent, nothing is written; a value is the drives' 0x10F1:02;
    /// one that is not an UNSIGNED16 is refused, located, with the range and what it does.
    #[test]
    fn the_sync_error_limit_is_read_and_checked() {
        assert_eq!(parse("p.toml", &preset()).unwrap().sync_error_limit, None);
        let with = |v: &str| {
            preset().replace(
                "static_drift_frames = 15000",
                &format!("static_drift_frames = 15000\nsync_error_limit = {v}"),
            )
        };
        assert_ne!(with("4"), preset(), "the replacement must apply");
        assert_eq!(
            parse("p.toml", &with("4")).unwrap().sync_error_limit,
            Some(4)
        );
        assert_eq!(
            parse("p.toml", &with("0")).unwrap().sync_error_limit,
            Some(0)
        );
        for bad in ["-1", "65536"] {
            let e = parse("p.toml", &with(bad)).unwrap_err();
            assert_eq!(e.field, "run.sync_error_limit", "{bad}: {e}");
            assert!(e.line.is_some(), "{e}");
            assert!(
                e.message.contains(bad) && e.message.contains("UNSIGNED16"),
                "{e}"
            );
            assert!(
                e.fix.contains("0 to 65535") && e.fix.contains("0x001A"),
                "{e}"
            );
        }
        // Not a whole number: serde's words, located at the key.
        let e = parse("p.toml", &with("4.5")).unwrap_err();
        assert!(e.to_string().contains("sync_error_limit"), "{e}");
        let e = parse("p.toml", &with("\"4\"")).unwrap_err();
        assert!(e.to_string().contains("sync_error_limit"), "{e}");
    }

    #[test]
    fn old_method_offsets_point_to_the_target() {
        let t = preset() + "\n[methods.snap]\nshift_ns = 5000\n";
        let e = parse("p.toml", &t).unwrap_err();
        assert_eq!(e.field, "methods.snap.shift_ns");
        assert!(e.fix.contains("run.target_phase_us"), "{e}");
    }

    #[test]
    fn a_changed_segment_is_not_the_letters_testbed() {
        let t = preset().replace("ppm = 12.4", "ppm = 12.5");
        assert!(!parse("p.toml", &t).unwrap().is_letter_testbed());
        let t = preset().replace(
            "preset = \"preempt-rt-stress\"",
            "preset = \"preempt-rt-idle\"",
        );
        assert!(!parse("p.toml", &t).unwrap().is_letter_testbed());
        // The letter's testbed with faults played is not the letter's either.
        let mut s = parse("p.toml", &preset()).unwrap();
        assert!(s.is_letter_testbed());
        s.faults = Some(
            ecsync_sim::fault::FaultSchedule::parse(
                "faults-demo",
                ecsync_sim::fault::FAULTS_DEMO_TOML,
            )
            .unwrap(),
        );
        assert!(!s.is_letter_testbed());
    }

    #[test]
    fn too_many_slaves() {
        let mut t = String::from("[segment]\n");
        for i in 0..65_536 {
            let up = if i == 0 {
                "master".to_string()
            } else {
                format!("s{}", i - 1)
            };
            t.push_str(&format!(
                "[[segment.slave]]\nname = \"s{i}\"\nupstream = \"{up}\"\n"
            ));
        }
        let e = parse("big.toml", &t).unwrap_err();
        assert_eq!(e.field, "segment.slave");
        assert!(e.message.contains("65535"), "{e}");
    }
}
