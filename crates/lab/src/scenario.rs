//! Scenarios: a segment, a host, and how to run the comparison, in one TOML file. Errors name
//! the file, the line, the field and the fix; nothing panics on bad input. The same checks run
//! on a scenario whose values the command line changed ([`Scenario::check`]), so a value is
//! refused with the same words wherever it came from.

use crate::host::{HostParams, Jitter};
use ecsync_esc::SlaveSpec;
use ecsync_esc::config::{ConfigError, SegmentConfig, line_of, toml_error};
use serde::Deserialize;

/// The methods a comparison can run, in the order reports list them.
pub const METHODS: [&str; 8] = [
    "median",
    "median-fit",
    "pi-m2s",
    "bus-shift",
    "dcm-bus-shift",
    "dcm-master-shift",
    "snap",
    "soem-pi",
];

/// What each method is, in a few words (for `--help` and reports).
pub fn method_summary(name: &str) -> &'static str {
    match name {
        "median" => {
            "the letter's method: master shift, median filter w, gain k, h_mr averaged over the init frames (eq. 5-14)"
        }
        "median-fit" => {
            "the letter's filter and gain with h_mr and the drift fitted over the init frames: holds the target on any crystals"
        }
        "pi-m2s" => {
            "the letter's E-M2S baseline: master shift, PI on the error from the cycle start"
        }
        "bus-shift" => {
            "the letter's E-S2M baseline: the send timestamp written to the reference's 0x0910 every cycle"
        }
        "dcm-bus-shift" => {
            "the vendor note's DCM bus shift: filtered PI on the frame's phase, the reference's time moved"
        }
        "dcm-master-shift" => {
            "the vendor note's DCM master shift: the same controller moving the master's timer"
        }
        "snap" => {
            "what ethercrab ships: wait to the reference's next grid point from the send, gain 1, no filter"
        }
        "soem-pi" => "SOEM's sample loop: sign-counting integral on the reference time's phase",
        _ => "",
    }
}

/// The cycle times a scenario accepts, us: EtherCAT cycles run from tens of microseconds to
/// about 100 ms.
pub const CYCLE_US_RANGE: (f64, f64) = (10.0, 100_000.0);

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    segment: SegmentConfig,
    #[serde(default)]
    host: HostFile,
    #[serde(default)]
    run: RunFile,
    #[serde(default)]
    methods: MethodsFile,
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
    METHODS.iter().map(|s| s.to_string()).collect()
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
        }
    }
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MethodsFile {
    median: Option<MedianParams>,
    #[serde(rename = "median-fit")]
    median_fit: Option<MedianParams>,
    #[serde(rename = "pi-m2s")]
    pi_m2s: Option<PiParams>,
    #[serde(rename = "bus-shift")]
    bus_shift: Option<BusShiftParams>,
    #[serde(rename = "dcm-bus-shift")]
    dcm_bus_shift: Option<DcmFileParams>,
    #[serde(rename = "dcm-master-shift")]
    dcm_master_shift: Option<DcmFileParams>,
    snap: Option<AimedParams>,
    #[serde(rename = "soem-pi")]
    soem_pi: Option<AimedParams>,
}

/// Parameters of `median` and `median-fit` (the letter's defaults).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct MedianParams {
    /// Median window w.
    #[serde(default = "d_w")]
    pub window: i64,
    /// Gain k.
    #[serde(default = "d_k")]
    pub gain: f64,
    /// Frames averaged (median) or fitted (median-fit) for h_mr.
    #[serde(default = "d_init")]
    pub init_frames: i64,
}
fn d_w() -> i64 {
    11
}
fn d_k() -> f64 {
    0.01
}
fn d_init() -> i64 {
    10_000
}

impl Default for MedianParams {
    fn default() -> Self {
        MedianParams {
            window: d_w(),
            gain: d_k(),
            init_frames: d_init(),
        }
    }
}

/// Parameters of `pi-m2s` (the letter's defaults).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct PiParams {
    /// Proportional gain.
    #[serde(default = "d_kp")]
    pub kp: f64,
    /// Integral gain.
    #[serde(default = "d_ki")]
    pub ki: f64,
    /// Frames averaged for the offset.
    #[serde(default = "d_init")]
    pub init_frames: i64,
}
fn d_kp() -> f64 {
    0.125
}
fn d_ki() -> f64 {
    0.0005
}

impl Default for PiParams {
    fn default() -> Self {
        PiParams {
            kp: d_kp(),
            ki: d_ki(),
            init_frames: d_init(),
        }
    }
}

/// Parameters of `bus-shift`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct BusShiftParams {
    /// Added to the written master time, ns.
    #[serde(default)]
    pub write_offset_ns: i64,
}

/// `snap` and `soem-pi` aim at `run.target_phase_us`; their own offsets of earlier versions are
/// refused with that hint.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct AimedParams {
    shift_ns: Option<i64>,
    offset_ns: Option<i64>,
}

/// The set value's reference of a DCM controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SetValueRefFile {
    /// The cyclic frame's send (the vendor's default).
    FrameSend,
    /// The cycle's start (the vendor's enhanced mode).
    CycleStart,
}

/// Parameters of `dcm-bus-shift` and `dcm-master-shift` (see `ecsync_dc::dcm`; defaults from
/// [`ecsync_dc::DcmParams::default_for`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DcmFileParams {
    /// What the set value is measured from: "frame-send" or "cycle-start".
    #[serde(default = "d_svr")]
    pub set_value_ref: SetValueRefFile,
    /// Proportional gain.
    #[serde(default = "d_dcm_kp")]
    pub kp: f64,
    /// Integral gain.
    #[serde(default = "d_dcm_ki")]
    pub ki: f64,
    /// Filter weight 2^-depth.
    #[serde(default = "d_dcm_depth")]
    pub filter_depth: i64,
    /// Errors further than this from the filtered error are not used once in sync, us.
    #[serde(default = "d_dcm_valid")]
    pub max_valid_us: f64,
    /// The in-sync band, us.
    #[serde(default = "d_dcm_band")]
    pub in_sync_limit_us: f64,
    /// How long the filtered error must stay in the band, ms.
    #[serde(default = "d_dcm_hold")]
    pub in_sync_hold_ms: f64,
    /// The most the re-adjustment's proportional part moves per cycle, ppm of the cycle (0: no
    /// limit; bus shift's default 5, master shift's 0).
    #[serde(default)]
    pub max_slew_ppm: Option<f64>,
}
fn d_svr() -> SetValueRefFile {
    SetValueRefFile::FrameSend
}
fn dcm_defaults() -> ecsync_dc::DcmParams {
    ecsync_dc::DcmParams::default_for(0, 1_000_000)
}
fn d_dcm_kp() -> f64 {
    dcm_defaults().kp
}
fn d_dcm_ki() -> f64 {
    dcm_defaults().ki
}
fn d_dcm_depth() -> i64 {
    i64::from(dcm_defaults().filter_depth)
}
fn d_dcm_valid() -> f64 {
    dcm_defaults().max_valid_ns as f64 / 1000.0
}
fn d_dcm_band() -> f64 {
    dcm_defaults().in_sync_limit_ns as f64 / 1000.0
}
fn d_dcm_hold() -> f64 {
    // 1.5 s: the default's hold is given in cycles of 1 ms.
    dcm_defaults().in_sync_hold_cycles as f64
}

impl Default for DcmFileParams {
    fn default() -> Self {
        DcmFileParams {
            set_value_ref: d_svr(),
            kp: d_dcm_kp(),
            ki: d_dcm_ki(),
            filter_depth: d_dcm_depth(),
            max_valid_us: d_dcm_valid(),
            in_sync_limit_us: d_dcm_band(),
            in_sync_hold_ms: d_dcm_hold(),
            max_slew_ppm: None,
        }
    }
}

impl DcmFileParams {
    /// The controller's parameters at a cycle and target, for bus shift or master shift.
    pub fn to_params(
        &self,
        target_phase_ns: i64,
        cycle_ns: u32,
        bus_shift: bool,
    ) -> ecsync_dc::DcmParams {
        let default_slew = if bus_shift {
            ecsync_dc::DcmParams::default_bus_shift(0, 1_000_000).max_slew_ppm
        } else {
            0.0
        };
        ecsync_dc::DcmParams {
            max_slew_ppm: self.max_slew_ppm.unwrap_or(default_slew),
            set_value_ref: match self.set_value_ref {
                SetValueRefFile::FrameSend => ecsync_dc::SetValueRef::FrameSend,
                SetValueRefFile::CycleStart => ecsync_dc::SetValueRef::CycleStart,
            },
            target_phase_ns,
            kp: self.kp,
            ki: self.ki,
            filter_depth: self.filter_depth.clamp(0, 20) as u8,
            max_valid_ns: (self.max_valid_us * 1000.0).round() as i64,
            in_sync_limit_ns: (self.in_sync_limit_us * 1000.0).round() as i64,
            in_sync_hold_cycles: ((self.in_sync_hold_ms * 1e6 / f64::from(cycle_ns.max(1))).round()
                as u64)
                .max(1),
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
    /// Host preset name (or "<preset> (modified)").
    pub host_name: String,
    /// The host.
    pub host: HostParams,
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
    pub methods: Vec<String>,
    /// Static drift compensation frames of the bring-up.
    pub static_drift_frames: u32,
    /// `median` parameters.
    pub median: MedianParams,
    /// `median-fit` parameters.
    pub median_fit: MedianParams,
    /// `pi-m2s` parameters.
    pub pi_m2s: PiParams,
    /// `bus-shift` parameters.
    pub bus_shift: BusShiftParams,
    /// `dcm-bus-shift` parameters.
    pub dcm_bus_shift: DcmFileParams,
    /// `dcm-master-shift` parameters.
    pub dcm_master_shift: DcmFileParams,
}

/// A value a scenario cannot run with: the field (dotted, as in the file), what is wrong and
/// what to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The table, e.g. `run` or `methods.median`.
    pub table: String,
    /// The key in it.
    pub key: String,
    /// What is wrong.
    pub message: String,
    /// What to do.
    pub fix: String,
}

impl Problem {
    fn new(table: &str, key: &str, message: String, fix: impl Into<String>) -> Self {
        Problem {
            table: table.to_string(),
            key: key.to_string(),
            message,
            fix: fix.into(),
        }
    }

    /// The dotted field.
    pub fn field(&self) -> String {
        format!("{}.{}", self.table, self.key)
    }
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}; fix: {}", self.field(), self.message, self.fix)
    }
}

/// Plural of a count: "1 run", "2 runs".
pub fn plural(n: u64, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

impl Scenario {
    /// SYNC0 shift, ns.
    pub fn sync0_shift_ns(&self) -> u32 {
        (f64::from(self.cycle_ns) * self.sync0_shift_pct / 100.0).round() as u32
    }

    /// Whether this is the letter's testbed (the paper-2024 segment, its host and cycle), the
    /// only scenario on which the letter's Table 1 values are a comparison.
    pub fn is_letter_testbed(&self) -> bool {
        let Ok(p) = parse("paper-2024", ecsync_esc::preset::PAPER_2024_TOML) else {
            return false;
        };
        self.slaves == p.slaves && self.host == p.host && self.cycle_ns == p.cycle_ns
    }

    /// The method's initialisation frames (0 for methods without).
    pub fn init_frames(&self, method: &str) -> u64 {
        match method {
            "median" => self.median.init_frames.max(0) as u64,
            "median-fit" => self.median_fit.init_frames.max(0) as u64,
            "pi-m2s" => self.pi_m2s.init_frames.max(0) as u64,
            _ => 0,
        }
    }

    /// Checks every value a run depends on; the first problem found.
    pub fn check(&self) -> Result<(), Problem> {
        check_host(&self.host, self.cycle_ns)?;
        let (lo, hi) = CYCLE_US_RANGE;
        let cycle_us = f64::from(self.cycle_ns) / 1000.0;
        if !(lo..=hi).contains(&cycle_us) {
            return Err(cycle_problem(cycle_us));
        }
        if !(self.sync0_shift_pct.is_finite() && (0.0..100.0).contains(&self.sync0_shift_pct)) {
            return Err(Problem::new(
                "run",
                "sync0_shift_pct",
                format!("{} % is not within the cycle", self.sync0_shift_pct),
                "give a percentage from 0 up to (not including) 100: SYNC0 fires that far after the DC grid point",
            ));
        }
        let half = i64::from(self.cycle_ns / 2);
        if self.target_phase_ns < -half || self.target_phase_ns >= half {
            return Err(Problem::new(
                "run",
                "target_phase_us",
                format!(
                    "{} us is not within half a cycle of the grid point",
                    self.target_phase_ns as f64 / 1000.0
                ),
                format!(
                    "give a phase from {} up to (not including) {} us; the frames should reach the reference before SYNC0 (run.sync0_shift_pct)",
                    -half as f64 / 1000.0,
                    half as f64 / 1000.0
                ),
            ));
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
                "no methods".into(),
                format!("name at least one of: {}", METHODS.join(", ")),
            ));
        }
        for m in &self.methods {
            if !METHODS.contains(&m.as_str()) {
                return Err(Problem::new(
                    "run",
                    "methods",
                    format!("unknown method \"{m}\""),
                    format!("use: {}", METHODS.join(", ")),
                ));
            }
        }
        for (table, p) in [
            ("methods.median", &self.median),
            ("methods.median-fit", &self.median_fit),
        ] {
            check_median(table, p)?;
        }
        for (k, v) in [("kp", self.pi_m2s.kp), ("ki", self.pi_m2s.ki)] {
            if !(v.is_finite() && (0.0..=2.0).contains(&v)) {
                return Err(Problem::new(
                    "methods.pi-m2s",
                    k,
                    format!("{v} is not a usable gain"),
                    "give a gain between 0 and 2 (the letter: kp 0.125, ki 0.0005)",
                ));
            }
        }
        // The DCM tables are checked against the cycle where they are used.
        for (name, d) in [
            ("dcm-bus-shift", &self.dcm_bus_shift),
            ("dcm-master-shift", &self.dcm_master_shift),
        ] {
            if self.methods.iter().any(|m| m == name) {
                check_dcm(&format!("methods.{name}"), d, self.cycle_ns)?;
            }
        }
        // Initialisation frames happen in the warm-up, which must hold them.
        for m in &self.methods {
            let init = self.init_frames(m);
            let table = match m.as_str() {
                "median" => "methods.median",
                "median-fit" => "methods.median-fit",
                "pi-m2s" => "methods.pi-m2s",
                _ => continue,
            };
            if init < 1 {
                return Err(Problem::new(
                    table,
                    "init_frames",
                    format!("{init} initialisation frames"),
                    "give at least 1 (the letter: 10000)",
                ));
            }
            if init > self.warmup_cycles {
                return Err(Problem::new(
                    "run",
                    "warmup_s",
                    format!(
                        "a warm-up of {} is shorter than {m}'s {} initialisation frames ({table}.init_frames)",
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
    let hint = if cycle_us > hi && cycle_us >= 1000.0 * lo {
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

fn check_median(table: &str, p: &MedianParams) -> Result<(), Problem> {
    if p.window <= 0 || p.window % 2 == 0 || p.window as usize > ecsync_dc::sync::MAX_WINDOW {
        return Err(Problem::new(
            table,
            "window",
            format!(
                "window w = {} must be odd and between 1 and {}",
                p.window,
                ecsync_dc::sync::MAX_WINDOW
            ),
            "use an odd width such as 11 (the letter's), so the median is one of the samples",
        ));
    }
    if !(p.gain.is_finite() && p.gain > 0.0 && p.gain <= 1.0) {
        return Err(Problem::new(
            table,
            "gain",
            format!("gain k = {} must lie in (0, 1]", p.gain),
            "use a small gain such as 0.01 (the letter's)",
        ));
    }
    Ok(())
}

fn check_dcm(table: &str, d: &DcmFileParams, cycle_ns: u32) -> Result<(), Problem> {
    for (k, v, max) in [("kp", d.kp, 1.0), ("ki", d.ki, 0.25)] {
        if !(v.is_finite() && v >= 0.0 && v <= max) {
            return Err(Problem::new(
                table,
                k,
                format!("{v} is not a usable gain (0 ..= {max})"),
                "the defaults are kp 0.004, ki 0.000004 (a loop of about 0.5 s at 1 ms)",
            ));
        }
    }
    if !(0..=16).contains(&d.filter_depth) {
        return Err(Problem::new(
            table,
            "filter_depth",
            format!("{}", d.filter_depth),
            "give a depth between 0 (no filter) and 16 (weight 2^-16); the default is 6",
        ));
    }
    let cycle_us = f64::from(cycle_ns) / 1000.0;
    for (k, v) in [
        ("max_valid_us", d.max_valid_us),
        ("in_sync_limit_us", d.in_sync_limit_us),
    ] {
        if !(v.is_finite() && v > 0.0 && v <= cycle_us) {
            return Err(Problem::new(
                table,
                k,
                format!("{v} us"),
                format!("give a time above 0 and at most the cycle ({cycle_us} us)"),
            ));
        }
    }
    if let Some(v) = d.max_slew_ppm {
        if !(v.is_finite() && (0.0..=1000.0).contains(&v)) {
            return Err(Problem::new(
                table,
                "max_slew_ppm",
                format!("{v} ppm"),
                "give between 0 (no limit) and 1000 ppm; bus shift's default is 5",
            ));
        }
    }
    if !(d.in_sync_hold_ms.is_finite()
        && d.in_sync_hold_ms >= 0.0
        && d.in_sync_hold_ms <= 600_000.0)
    {
        return Err(Problem::new(
            table,
            "in_sync_hold_ms",
            format!("{} ms", d.in_sync_hold_ms),
            "give between 0 and 600000 ms",
        ));
    }
    Ok(())
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

/// The line of `key = ...` inside table `table` (dotted, as in its header), if present.
pub(crate) fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
    let mut current = String::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            current = l.trim_matches(['[', ']']).trim().to_string();
            continue;
        }
        if current == table {
            if let Some((k, _)) = l.split_once('=') {
                if k.trim() == key {
                    return Some(i + 1);
                }
            }
        }
    }
    None
}

/// A problem located in the scenario file `file` with text `text`.
pub fn locate(file: &str, text: &str, p: Problem) -> ConfigError {
    // A nested table's key (host.js.sigma_ns) may sit in an inline table: fall back to the
    // table's key in its parent, then to the table header.
    let line = key_line(text, &p.table, &p.key)
        .or_else(|| {
            let (parent, last) = p.table.rsplit_once('.')?;
            key_line(text, parent, last)
        })
        .or_else(|| {
            text.find(&format!("[{}]", p.table))
                .map(|at| line_of(text, at))
        });
    ConfigError {
        file: file.to_string(),
        line,
        field: p.field(),
        message: p.message,
        fix: p.fix,
    }
}

/// Parses and checks a scenario.
pub fn parse(file: &str, text: &str) -> Result<Scenario, ConfigError> {
    let f: File = toml::from_str(text).map_err(|e| toml_error(file, text, &e))?;
    let err = |table: &str, key: &str, message: String, fix: &str| {
        locate(file, text, Problem::new(table, key, message, fix))
    };
    let slaves = f.segment.to_specs(file, text, "segment")?;

    // Host: a preset, then overrides.
    let preset = f
        .host
        .preset
        .clone()
        .unwrap_or_else(|| "preempt-rt-stress".to_string());
    let mut host = HostParams::preset(&preset).ok_or_else(|| {
        err(
            "host",
            "preset",
            format!("unknown host preset \"{preset}\""),
            &format!("use one of: {}", HostParams::PRESETS.join(", ")),
        )
    })?;
    let h = &f.host;
    let custom = h.master_ppm.is_some()
        || h.js.is_some()
        || h.jc.is_some()
        || h.em_ns.is_some()
        || h.em_jitter.is_some()
        || h.tx_latency_ns.is_some()
        || h.rx_latency_ns.is_some()
        || h.master_wander_ppm_per_sqrt_s.is_some();
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

    // Run.
    let r = &f.run;
    let (lo, hi) = CYCLE_US_RANGE;
    if !(r.cycle_us.is_finite() && (lo..=hi).contains(&r.cycle_us)) {
        return Err(locate(file, text, cycle_problem(r.cycle_us)));
    }
    let cycle_ns = (r.cycle_us * 1000.0).round() as u32;
    if !r.target_phase_us.is_finite() || r.target_phase_us.abs() > 1e7 {
        return Err(err(
            "run",
            "target_phase_us",
            format!("{}", r.target_phase_us),
            "give the target phase in us, within half a cycle of the grid point",
        ));
    }
    for (key, v, lo, hi) in [
        ("runs", r.runs, 1, 1000),
        ("cycles", r.cycles, 1, 1_000_000_000),
        ("static_drift_frames", r.static_drift_frames, 0, 10_000_000),
    ] {
        if v < lo || v > hi {
            return Err(err(
                "run",
                key,
                format!("{v}"),
                &format!("give between {lo} and {hi}"),
            ));
        }
    }
    if !(r.warmup_s.is_finite() && r.warmup_s >= 0.0 && r.warmup_s <= 86_400.0) {
        return Err(err(
            "run",
            "warmup_s",
            format!("{} s of warm-up", r.warmup_s),
            "give between 0 and 86400 s",
        ));
    }
    for m in &r.methods {
        if !METHODS.contains(&m.as_str()) {
            return Err(err(
                "run",
                "methods",
                format!("unknown method \"{m}\""),
                &format!("use: {}", METHODS.join(", ")),
            ));
        }
    }
    for (table, a) in [
        ("methods.snap", f.methods.snap),
        ("methods.soem-pi", f.methods.soem_pi),
    ] {
        let Some(a) = a else { continue };
        for (key, v) in [("shift_ns", a.shift_ns), ("offset_ns", a.offset_ns)] {
            if v.is_some() {
                return Err(err(
                    table,
                    key,
                    "every method now aims at the scenario's target phase".into(),
                    "remove the field and set run.target_phase_us (us after the DC grid point) instead",
                ));
            }
        }
    }
    let s = Scenario {
        name: file.to_string(),
        slaves,
        host_name: if custom {
            format!("{preset} (modified)")
        } else {
            preset
        },
        host,
        cycle_ns,
        sync0_shift_pct: r.sync0_shift_pct,
        target_phase_ns: (r.target_phase_us * 1000.0).round() as i64,
        runs: r.runs as u32,
        cycles: r.cycles as u64,
        warmup_cycles: (r.warmup_s * 1e9 / f64::from(cycle_ns)).round() as u64,
        seed: r.seed,
        methods: METHODS
            .iter()
            .filter(|m| r.methods.iter().any(|x| x == *m))
            .map(|s| s.to_string())
            .collect(),
        static_drift_frames: r.static_drift_frames as u32,
        median: f.methods.median.unwrap_or_default(),
        median_fit: f.methods.median_fit.unwrap_or_default(),
        pi_m2s: f.methods.pi_m2s.unwrap_or_default(),
        bus_shift: f.methods.bus_shift.unwrap_or_default(),
        dcm_bus_shift: f.methods.dcm_bus_shift.unwrap_or_default(),
        dcm_master_shift: f.methods.dcm_master_shift.unwrap_or_default(),
    };
    s.check().map_err(|p| locate(file, text, p))?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn preset() -> String {
        ecsync_esc::preset::PAPER_2024_TOML.to_string()
    }

    #[test]
    fn the_preset_parses() {
        let s = parse("paper-2024.toml", &preset()).unwrap();
        assert_eq!(s.slaves.len(), 6);
        assert_eq!(s.cycle_ns, 1_000_000);
        assert_eq!(s.runs, 5);
        assert_eq!(s.cycles, 1_800_000);
        assert_eq!(s.warmup_cycles, 120_000);
        assert_eq!(s.methods, METHODS);
        assert_eq!(s.median.window, 11);
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
        assert_eq!(s.methods, ["bus-shift", "snap"]);
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
