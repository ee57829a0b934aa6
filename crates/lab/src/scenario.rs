//! Scenarios: a segment, a host, and how to run the comparison, in one TOML file. Errors name
//! the file, the line, the field and the fix; nothing panics on bad input.

use crate::host::{HostParams, Jitter};
use ecsync_esc::SlaveSpec;
use ecsync_esc::config::{ConfigError, SegmentConfig, line_of, toml_error};
use serde::Deserialize;

/// The methods a comparison can run, in the order reports list them.
pub const METHODS: [&str; 5] = ["median", "pi-m2s", "bus-shift", "snap", "soem-pi"];

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
    #[serde(rename = "pi-m2s")]
    pi_m2s: Option<PiParams>,
    #[serde(rename = "bus-shift")]
    bus_shift: Option<BusShiftParams>,
    snap: Option<SnapParams>,
    #[serde(rename = "soem-pi")]
    soem_pi: Option<SoemParams>,
}

/// Parameters of `median` (the letter's defaults).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct MedianParams {
    /// Median window w.
    #[serde(default = "d_w")]
    pub window: i64,
    /// Gain k.
    #[serde(default = "d_k")]
    pub gain: f64,
    /// Frames averaged for h_mr.
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

/// Parameters of `bus-shift`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct BusShiftParams {
    /// Added to the written master time, ns.
    #[serde(default)]
    pub write_offset_ns: i64,
}

/// Parameters of `snap`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SnapParams {
    /// ethercrab's sync0_shift, ns.
    #[serde(default)]
    pub shift_ns: i64,
}

/// Parameters of `soem-pi`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SoemParams {
    /// SOEM's offset, ns.
    #[serde(default)]
    pub offset_ns: i64,
}

/// A validated scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Where it came from, for reports.
    pub name: String,
    /// The segment.
    pub slaves: Vec<SlaveSpec>,
    /// Host preset name (or "custom").
    pub host_name: String,
    /// The host.
    pub host: HostParams,
    /// Cycle time and SYNC0 period, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift after the grid point the master aims its frames at, % of the cycle.
    pub sync0_shift_pct: f64,
    /// Runs with different seeds.
    pub runs: u32,
    /// Recorded cycles per run.
    pub cycles: u64,
    /// Warm-up cycles per run (not recorded).
    pub warmup_cycles: u64,
    /// Base seed.
    pub seed: u64,
    /// Methods to compare.
    pub methods: Vec<String>,
    /// Static drift compensation frames of the bring-up.
    pub static_drift_frames: u32,
    /// `median` parameters.
    pub median: MedianParams,
    /// `pi-m2s` parameters.
    pub pi_m2s: PiParams,
    /// `bus-shift` parameters.
    pub bus_shift: BusShiftParams,
    /// `snap` parameters.
    pub snap: SnapParams,
    /// `soem-pi` parameters.
    pub soem_pi: SoemParams,
}

impl Scenario {
    /// SYNC0 shift, ns.
    pub fn sync0_shift_ns(&self) -> u32 {
        (f64::from(self.cycle_ns) * self.sync0_shift_pct / 100.0).round() as u32
    }
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

/// Parses and checks a scenario.
pub fn parse(file: &str, text: &str) -> Result<Scenario, ConfigError> {
    let f: File = toml::from_str(text).map_err(|e| toml_error(file, text, &e))?;
    let err = |table: &str, key: &str, message: String, fix: &str| ConfigError {
        file: file.to_string(),
        line: key_line(text, table, key)
            .or_else(|| text.find(&format!("[{table}]")).map(|at| line_of(text, at))),
        field: format!("{table}.{key}"),
        message,
        fix: fix.to_string(),
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
    let custom = f.host.master_ppm.is_some()
        || f.host.js.is_some()
        || f.host.jc.is_some()
        || f.host.em_ns.is_some()
        || f.host.em_jitter.is_some()
        || f.host.tx_latency_ns.is_some()
        || f.host.rx_latency_ns.is_some()
        || f.host.master_wander_ppm_per_sqrt_s.is_some();
    if let Some(v) = f.host.master_ppm {
        host.master_ppm = v;
    }
    if let Some(v) = f.host.master_wander_ppm_per_sqrt_s {
        host.master_wander_ppm_per_sqrt_s = v;
    }
    if let Some(v) = f.host.js {
        host.js = v;
    }
    if let Some(v) = f.host.em_ns {
        host.em_ns = v;
    }
    if let Some(v) = f.host.em_jitter {
        host.em_jitter = v;
    }
    if let Some(v) = f.host.jc {
        host.jc = v;
    }
    if let Some(v) = f.host.tx_latency_ns {
        host.tx_latency_ns = v;
    }
    if let Some(v) = f.host.rx_latency_ns {
        host.rx_latency_ns = v;
    }
    if !(host.master_ppm.is_finite() && host.master_ppm.abs() <= 1000.0) {
        return Err(err(
            "host",
            "master_ppm",
            format!("{} ppm is not a crystal error", host.master_ppm),
            "give a value between -1000 and 1000",
        ));
    }
    for (name, j) in [
        ("js", host.js),
        ("em_jitter", host.em_jitter),
        ("jc", host.jc),
    ] {
        if let Err((field, why)) = j.validate() {
            return Err(err(
                &format!("host.{name}"),
                field,
                why,
                "give a finite value >= 0 (tail_p between 0 and 1)",
            ));
        }
    }
    for (key, v) in [
        ("em_ns", host.em_ns),
        ("tx_latency_ns", host.tx_latency_ns),
        ("rx_latency_ns", host.rx_latency_ns),
        (
            "master_wander_ppm_per_sqrt_s",
            host.master_wander_ppm_per_sqrt_s,
        ),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(err(
                "host",
                key,
                format!("{v} must be a finite number >= 0"),
                "give a non-negative value",
            ));
        }
    }

    // Run.
    let r = &f.run;
    if !(r.cycle_us.is_finite() && r.cycle_us > 0.0) {
        return Err(err(
            "run",
            "cycle_us",
            format!("cycle time {} us is not positive", r.cycle_us),
            "give a cycle time in microseconds greater than 0, e.g. 1000",
        ));
    }
    if r.cycle_us > 4_000_000.0 || r.cycle_us < 1.0 {
        return Err(err(
            "run",
            "cycle_us",
            format!("cycle time {} us is outside 1 us ..= 4 s", r.cycle_us),
            "give a cycle time between 1 and 4000000 us",
        ));
    }
    let cycle_ns = (r.cycle_us * 1000.0).round() as u32;
    if !(r.sync0_shift_pct.is_finite() && (0.0..100.0).contains(&r.sync0_shift_pct)) {
        return Err(err(
            "run",
            "sync0_shift_pct",
            format!("{} % is not within the cycle", r.sync0_shift_pct),
            "give a percentage from 0 up to (not including) 100",
        ));
    }
    if r.runs < 1 || r.runs > 1000 {
        return Err(err(
            "run",
            "runs",
            format!("{} runs", r.runs),
            "give between 1 and 1000 runs",
        ));
    }
    if r.cycles < 1 || r.cycles > 1_000_000_000 {
        return Err(err(
            "run",
            "cycles",
            format!("{} recorded cycles", r.cycles),
            "give between 1 and 1000000000 cycles",
        ));
    }
    if !(r.warmup_s.is_finite() && r.warmup_s >= 0.0 && r.warmup_s <= 86_400.0) {
        return Err(err(
            "run",
            "warmup_s",
            format!("{} s of warm-up", r.warmup_s),
            "give between 0 and 86400 s",
        ));
    }
    if r.static_drift_frames < 0 || r.static_drift_frames > 10_000_000 {
        return Err(err(
            "run",
            "static_drift_frames",
            format!("{}", r.static_drift_frames),
            "give between 0 and 10000000 frames",
        ));
    }
    if r.methods.is_empty() {
        return Err(err(
            "run",
            "methods",
            "no methods".into(),
            &format!("name at least one of: {}", METHODS.join(", ")),
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
    let warmup_cycles = (r.warmup_s * 1e9 / f64::from(cycle_ns)).round() as u64;

    // Methods.
    let median = f.methods.median.unwrap_or(MedianParams {
        window: d_w(),
        gain: d_k(),
        init_frames: d_init(),
    });
    if median.window <= 0
        || median.window % 2 == 0
        || median.window as usize > ecsync_dc::sync::MAX_WINDOW
    {
        return Err(err(
            "methods.median",
            "window",
            format!(
                "window w = {} must be odd and between 1 and {}",
                median.window,
                ecsync_dc::sync::MAX_WINDOW
            ),
            "use an odd width such as 11 (the letter's), so the median is one of the samples",
        ));
    }
    if !(median.gain.is_finite() && median.gain > 0.0 && median.gain <= 1.0) {
        return Err(err(
            "methods.median",
            "gain",
            format!("gain k = {} must lie in (0, 1]", median.gain),
            "use a small gain such as 0.01 (the letter's)",
        ));
    }
    let pi_m2s = f.methods.pi_m2s.unwrap_or(PiParams {
        kp: d_kp(),
        ki: d_ki(),
        init_frames: d_init(),
    });
    for (k, v) in [("kp", pi_m2s.kp), ("ki", pi_m2s.ki)] {
        if !(v.is_finite() && (0.0..=2.0).contains(&v)) {
            return Err(err(
                "methods.pi-m2s",
                k,
                format!("{v} is not a usable gain"),
                "give a gain between 0 and 2 (the letter: kp 0.125, ki 0.0005)",
            ));
        }
    }
    for (table, v) in [
        ("methods.median", median.init_frames),
        ("methods.pi-m2s", pi_m2s.init_frames),
    ] {
        if v < 1 || v as u64 > warmup_cycles.max(1) {
            return Err(err(
                table,
                "init_frames",
                format!("{v} initialisation frames with {warmup_cycles} warm-up cycles"),
                "give at least 1 and no more than the warm-up cycles (run.warmup_s / cycle)",
            ));
        }
    }
    Ok(Scenario {
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
        runs: r.runs as u32,
        cycles: r.cycles as u64,
        warmup_cycles,
        seed: r.seed,
        methods: METHODS
            .iter()
            .filter(|m| r.methods.iter().any(|x| x == *m))
            .map(|s| s.to_string())
            .collect(),
        static_drift_frames: r.static_drift_frames as u32,
        median,
        pi_m2s,
        bus_shift: f.methods.bus_shift.unwrap_or_default(),
        snap: f.methods.snap.unwrap_or_default(),
        soem_pi: f.methods.soem_pi.unwrap_or_default(),
    })
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
        assert!(e.line.is_some() && e.fix.contains("greater than 0"), "{e}");
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
