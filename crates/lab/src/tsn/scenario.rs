//! The TSN scenario file: the EtherCAT segment, the master, the time-aware bridge with its gate
//! control lists, gPTP, and which variants to run. Every error names the file, the line, the
//! field and the fix, located by the same [`ConfigSource`] as the compare scenario's.

use ecsync_sim::SlaveSpec;
use ecsync_sim::config::{ConfigError, ConfigSource, SegmentConfig};
use ecsync_tsn::qbv::{PortSchedule, ScheduleError, Window};
use serde::Deserialize;

pub use ecsync_tsn::network::{BridgeParams, GptpParams, MasterParams, NetworkParams, Variant};

/// The built-in preset `tsn-2020`: embedded from the repository's `presets/tsn-2020.toml`, the
/// file users read and edit.
pub const TSN_2020_TOML: &str = include_str!("../../../../presets/tsn-2020.toml");

/// A TSN scenario.
#[derive(Debug, Clone)]
pub struct TsnScenario {
    /// Where it came from.
    pub name: String,
    /// The EtherCAT segment.
    pub slaves: Vec<SlaveSpec>,
    /// Seed of launch jitter and cross traffic.
    pub seed: u64,
    /// EtherCAT cycle and SYNC0 period, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift after the cycle's grid point, ns.
    pub sync0_shift_ns: u32,
    /// Cycles before recording.
    pub warmup_cycles: u64,
    /// Recorded cycles.
    pub cycles: u64,
    /// Static drift compensation frames of the bring-up.
    pub static_drift_frames: u32,
    /// Variants to run.
    pub variants: Vec<Variant>,
    /// The master.
    pub master: MasterParams,
    /// The bridge.
    pub bridge: BridgeParams,
    /// gPTP.
    pub gptp: GptpParams,
}

impl TsnScenario {
    /// The network it describes, for [`ecsync_tsn::network::TsnNetwork`].
    pub fn network_params(&self) -> NetworkParams<'_> {
        NetworkParams {
            slaves: &self.slaves,
            seed: self.seed,
            master: &self.master,
            bridge: &self.bridge,
            gptp: &self.gptp,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    tsn: TsnTable,
    master: MasterTable,
    bridge: BridgeTable,
    gptp: GptpTable,
    #[serde(default)]
    segment: Option<SegmentConfig>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TsnTable {
    seed: u64,
    cycle_ns: i64,
    sync0_shift_ns: i64,
    warmup_s: f64,
    duration_s: f64,
    #[serde(default = "default_drift_frames")]
    static_drift_frames: u32,
    variants: Vec<String>,
}

fn default_drift_frames() -> u32 {
    15_000
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MasterTable {
    ppm: f64,
    #[serde(default = "default_wander")]
    wander_ppm_per_sqrt_s: f64,
    clock_offset_ns: i64,
    timestamp_ns: i64,
    launch_jitter_ns: f64,
    cable_m: f64,
    launch_margin_ns: i64,
    priority1: u8,
}

fn default_wander() -> f64 {
    ecsync_sim::clock::CRYSTAL_WANDER_PPM_PER_SQRT_S
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PortTable {
    #[serde(default)]
    window: Vec<Window>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BridgeTable {
    ppm: f64,
    #[serde(default = "default_wander")]
    wander_ppm_per_sqrt_s: f64,
    initial_ns: u64,
    residence_ns: i64,
    cycle_ns: i64,
    #[serde(default)]
    base_ns: u64,
    cross_traffic_load: f64,
    cross_traffic_frame_bytes: u64,
    priority1: u8,
    ethercat_port: PortTable,
    master_port: PortTable,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GptpTable {
    sync_interval_ns: i64,
    pdelay_interval_ns: i64,
    settle_s: f64,
    kp: f64,
    ki: f64,
}

/// Wire time of the largest EtherCAT frame (1514 bytes without FCS), ns.
fn max_frame_ns() -> u64 {
    ecsync_sim::frame_wire_time_ps(1514) / 1000
}

/// Parses and checks a TSN scenario: the segment, then each table in the file's order (the
/// first bad field is the one reported).
pub fn parse(file: &str, text: &str) -> Result<TsnScenario, ConfigError> {
    let src = ConfigSource::new(file, text);
    let f: File = src.deserialize()?;
    let slaves = match &f.segment {
        Some(s) => s.to_specs(file, text, "segment")?,
        None => ecsync_sim::preset::paper_2024(),
    };
    let t = &f.tsn;
    let recording = t.recording(&src)?;
    let master = f.master.params(&src)?;
    let bridge = f.bridge.params(&src, t.cycle_ns)?;
    let gptp = f.gptp.params(&src)?;
    Ok(TsnScenario {
        name: file.to_string(),
        slaves,
        seed: t.seed,
        cycle_ns: t.cycle_ns as u32,
        sync0_shift_ns: t.sync0_shift_ns as u32,
        warmup_cycles: recording.warmup_cycles,
        cycles: recording.cycles,
        static_drift_frames: t.static_drift_frames,
        variants: recording.variants,
        master,
        bridge,
        gptp,
    })
}

/// What `[tsn]` says to record, checked.
struct Recording {
    /// Cycles before recording.
    warmup_cycles: u64,
    /// Recorded cycles (at least one).
    cycles: u64,
    /// The variants, each once, in the file's order.
    variants: Vec<Variant>,
}

impl TsnTable {
    /// Checks the cycle and the SYNC0 shift within it, turns the warm-up and the duration into
    /// cycles, and reads the variants.
    fn recording(&self, src: &ConfigSource<'_>) -> Result<Recording, ConfigError> {
        let err = |key: &str, message: String, fix: &str| src.error("tsn", key, message, fix);
        if self.cycle_ns <= 0 || self.cycle_ns > i64::from(u32::MAX) {
            return Err(err(
                "cycle_ns",
                format!("{} is not a cycle time", self.cycle_ns),
                "give the EtherCAT cycle in ns, e.g. 1000000",
            ));
        }
        if self.sync0_shift_ns < 0 || self.sync0_shift_ns >= self.cycle_ns {
            return Err(err(
                "sync0_shift_ns",
                format!("{} ns is not within the cycle", self.sync0_shift_ns),
                "give a shift between 0 and the cycle",
            ));
        }
        let cycle = self.cycle_ns as f64;
        let secs = |v: f64, key: &str| -> Result<u64, ConfigError> {
            if !(v.is_finite() && (0.0..=86_400.0).contains(&v)) {
                return Err(err(
                    key,
                    format!("{v} is not a duration"),
                    "give seconds between 0 and 86400",
                ));
            }
            Ok((v * 1e9 / cycle).round() as u64)
        };
        let warmup_cycles = secs(self.warmup_s, "warmup_s")?;
        let cycles = secs(self.duration_s, "duration_s")?;
        if cycles == 0 {
            return Err(err(
                "duration_s",
                "records no cycle".into(),
                "give at least one cycle's worth of seconds",
            ));
        }
        let mut variants = Vec::new();
        for v in &self.variants {
            let Some(x) = Variant::from_name(v) else {
                return Err(err(
                    "variants",
                    format!("unknown variant \"{v}\""),
                    "use M1, M2 and M3",
                ));
            };
            if !variants.contains(&x) {
                variants.push(x);
            }
        }
        if variants.is_empty() {
            return Err(err(
                "variants",
                "no variant".into(),
                "list at least one of M1, M2, M3",
            ));
        }
        Ok(Recording {
            warmup_cycles,
            cycles,
            variants,
        })
    }
}

impl MasterTable {
    /// Checks the master's crystal, timestamp granularity, launch jitter, cable and launch
    /// margin.
    fn params(&self, src: &ConfigSource<'_>) -> Result<MasterParams, ConfigError> {
        let err = |key: &str, message: String, fix: &str| src.error("master", key, message, fix);
        if !(self.ppm.is_finite() && self.ppm.abs() <= 500.0) {
            return Err(err(
                "ppm",
                format!("{} ppm is not a crystal error", self.ppm),
                "give a value within +-500",
            ));
        }
        if self.timestamp_ns <= 0 || self.timestamp_ns > 1_000 {
            return Err(err(
                "timestamp_ns",
                format!("{} ns is not a timestamp granularity", self.timestamp_ns),
                "give 1..1000 (8 for a 125 MHz hardware timestamper)",
            ));
        }
        if !(self.launch_jitter_ns.is_finite() && self.launch_jitter_ns >= 0.0) {
            return Err(err(
                "launch_jitter_ns",
                "must be a non-negative standard deviation".into(),
                "give 0 or more",
            ));
        }
        if !(self.cable_m.is_finite() && self.cable_m >= 0.0 && self.cable_m <= 100.0) {
            return Err(err(
                "cable_m",
                format!("{} m is not a 100BASE-TX cable", self.cable_m),
                "give 0..100 m",
            ));
        }
        if self.launch_margin_ns < 0 {
            return Err(err(
                "launch_margin_ns",
                "is negative".into(),
                "give 0 or more ns",
            ));
        }
        Ok(MasterParams {
            ppm: self.ppm,
            wander_ppm_per_sqrt_s: self.wander_ppm_per_sqrt_s,
            clock_offset_ns: self.clock_offset_ns,
            timestamp_ns: self.timestamp_ns as u64,
            launch_jitter_ns: self.launch_jitter_ns,
            cable_m: self.cable_m,
            launch_margin_ns: self.launch_margin_ns as u64,
            priority1: self.priority1,
        })
    }
}

impl BridgeTable {
    /// Checks the bridge's crystal, residence time, gate cycle (a divisor of the EtherCAT
    /// cycle `cycle_ns`) and cross traffic, then both ports' gate schedules.
    fn params(&self, src: &ConfigSource<'_>, cycle_ns: i64) -> Result<BridgeParams, ConfigError> {
        let err = |key: &str, message: String, fix: &str| src.error("bridge", key, message, fix);
        if !(self.ppm.is_finite() && self.ppm.abs() <= 500.0) {
            return Err(err(
                "ppm",
                format!("{} ppm is not a crystal error", self.ppm),
                "give a value within +-500",
            ));
        }
        if self.residence_ns < 0 {
            return Err(err(
                "residence_ns",
                "is negative".into(),
                "give 0 or more ns",
            ));
        }
        if self.cycle_ns <= 0 || cycle_ns % self.cycle_ns != 0 {
            return Err(err(
                "cycle_ns",
                format!(
                    "the gate cycle of {} ns does not divide the EtherCAT cycle of {} ns",
                    self.cycle_ns, cycle_ns
                ),
                "make the gate cycle the EtherCAT cycle (or a divisor of it)",
            ));
        }
        if !(self.cross_traffic_load.is_finite() && (0.0..1.0).contains(&self.cross_traffic_load)) {
            return Err(err(
                "cross_traffic_load",
                format!("{} is not a load", self.cross_traffic_load),
                "give a share of the best-effort time, 0 <= load < 1",
            ));
        }
        if !(64..=1522).contains(&self.cross_traffic_frame_bytes) {
            return Err(err(
                "cross_traffic_frame_bytes",
                format!(
                    "{} is not an Ethernet frame size",
                    self.cross_traffic_frame_bytes
                ),
                "give 64..1522",
            ));
        }
        let ethercat_port = self.schedule(src, "ethercat_port", &self.ethercat_port)?;
        let master_port = self.schedule(src, "master_port", &self.master_port)?;
        Ok(BridgeParams {
            ppm: self.ppm,
            wander_ppm_per_sqrt_s: self.wander_ppm_per_sqrt_s,
            initial_ns: self.initial_ns,
            residence_ns: self.residence_ns as u64,
            cycle_ns: self.cycle_ns as u64,
            base_ns: self.base_ns,
            ethercat_port,
            master_port,
            cross_traffic_load: self.cross_traffic_load,
            cross_traffic_frame_bytes: self.cross_traffic_frame_bytes,
            priority1: self.priority1,
        })
    }

    /// Port `port`'s gate control list as a schedule on the gate cycle, checked: windows within
    /// the cycle, not overlapping, one at least long enough for the largest EtherCAT frame. Its
    /// best-effort guard band is a cross-traffic frame's time on the wire (preamble, frame and
    /// gap at 80 ns a byte).
    fn schedule(
        &self,
        src: &ConfigSource<'_>,
        port: &str,
        p: &PortTable,
    ) -> Result<PortSchedule, ConfigError> {
        let guard_ns = (8 + self.cross_traffic_frame_bytes + 12) * 80;
        let table = format!("bridge.{port}");
        let s = PortSchedule::new(self.cycle_ns as u64, self.base_ns, &p.window, guard_ns)
            .and_then(|s| s.check_fits(max_frame_ns()).map(|()| s))
            .map_err(|e: ScheduleError| {
                src.error(
                    &table,
                    "window",
                    format!("bad gate schedule: {e}"),
                    "each [[bridge.<port>.window]] gives open_ns < close_ns within the gate cycle, windows must not overlap, and the list must not be empty",
                )
            })?;
        Ok(s)
    }
}

impl GptpTable {
    /// Checks gPTP's Sync and Pdelay intervals, its settling time and its servo's gains.
    fn params(&self, src: &ConfigSource<'_>) -> Result<GptpParams, ConfigError> {
        let err = |key: &str, message: String, fix: &str| src.error("gptp", key, message, fix);
        let pos = |v: i64, key: &str| -> Result<u64, ConfigError> {
            if v <= 0 || v > 60_000_000_000 {
                return Err(err(
                    key,
                    format!("{v} ns is not an interval"),
                    "give 1 ns .. 60 s (802.1AS: 125000000 for Sync, 1000000000 for Pdelay)",
                ));
            }
            Ok(v as u64)
        };
        let sync_interval_ns = pos(self.sync_interval_ns, "sync_interval_ns")?;
        let pdelay_interval_ns = pos(self.pdelay_interval_ns, "pdelay_interval_ns")?;
        if !(self.settle_s.is_finite() && (0.0..=3600.0).contains(&self.settle_s)) {
            return Err(err(
                "settle_s",
                format!("{} is not a duration", self.settle_s),
                "give 0..3600 s",
            ));
        }
        if !(self.kp.is_finite()
            && self.kp > 0.0
            && self.kp < 2.0
            && self.ki.is_finite()
            && self.ki >= 0.0
            && self.ki < 1.0)
        {
            return Err(err(
                "kp",
                format!(
                    "kp {} and ki {} do not make a stable servo",
                    self.kp, self.ki
                ),
                "give 0 < kp < 2 and 0 <= ki < 1 (defaults 0.7 and 0.3)",
            ));
        }
        Ok(GptpParams {
            sync_interval_ns,
            pdelay_interval_ns,
            settle_ns: (self.settle_s * 1e9) as u64,
            kp: self.kp,
            ki: self.ki,
        })
    }
}

/// The built-in preset.
pub fn preset() -> TsnScenario {
    parse("presets/tsn-2020.toml", TSN_2020_TOML).expect("the built-in preset is valid")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_preset_parses() {
        let s = preset();
        assert_eq!(s.variants, vec![Variant::M1, Variant::M2, Variant::M3]);
        assert_eq!(s.slaves.len(), 6);
        assert!((s.bridge.ethercat_port.open_fraction() - 0.3).abs() < 1e-9);
    }

    fn with_windows(ecat: &str) -> String {
        let mut t = TSN_2020_TOML.to_string();
        let start = t.find("[[bridge.ethercat_port.window]]").unwrap();
        let end = t.find("[[bridge.master_port.window]]").unwrap();
        t.replace_range(start..end, ecat);
        t
    }

    #[test]
    fn bad_gate_schedules_name_the_field_and_the_reason() {
        let overlap = with_windows(
            "[[bridge.ethercat_port.window]]\nopen_ns = 0\nclose_ns = 300000\n\n[[bridge.ethercat_port.window]]\nopen_ns = 200000\nclose_ns = 500000\n\n",
        );
        let err = parse("x.toml", &overlap).unwrap_err();
        // Located at the port's first window.
        let at = overlap.find("[[bridge.ethercat_port.window]]").unwrap();
        assert_eq!(err.line, Some(overlap[..at].matches('\n').count() + 1));
        let e = err.to_string();
        assert!(e.contains("bridge.ethercat_port.window"), "{e}");
        assert!(e.contains("overlap from 200000 to 300000"), "{e}");

        let long =
            with_windows("[[bridge.ethercat_port.window]]\nopen_ns = 0\nclose_ns = 1500000\n\n");
        let e = parse("x.toml", &long).unwrap_err().to_string();
        assert!(e.contains("longer than the gate cycle"), "{e}");

        let empty = with_windows("[bridge.ethercat_port]\n\n");
        let e = parse("x.toml", &empty).unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        assert!(e.starts_with("x.toml:"), "{e}");

        let tiny =
            with_windows("[[bridge.ethercat_port.window]]\nopen_ns = 0\nclose_ns = 50000\n\n");
        let e = parse("x.toml", &tiny).unwrap_err().to_string();
        assert!(e.contains("largest EtherCAT frame"), "{e}");
    }

    #[test]
    fn other_bad_fields_are_named() {
        let t = TSN_2020_TOML.replace("variants = [\"M1\", \"M2\", \"M3\"]", "variants = [\"M4\"]");
        let err = parse("x.toml", &t).unwrap_err();
        let at = t.find("variants = [\"M4\"]").unwrap();
        assert_eq!(err.line, Some(t[..at].matches('\n').count() + 1));
        let e = err.to_string();
        assert!(e.contains("tsn.variants") && e.contains("M4"), "{e}");
        let t = TSN_2020_TOML.replace("[gptp]", "[gptp]\nbogus = 1");
        let e = parse("x.toml", &t).unwrap_err().to_string();
        assert!(e.contains("unknown field"), "{e}");
    }
}
