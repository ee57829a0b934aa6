//! The truth a network twin is checked against, and `compare`'s ranking on it.

use super::*;

/// The preset's crystals against the reference's (position 0), ppm: the truth a twin's are
/// checked against (the segment runs on this host's clock, so only relative figures compare).
pub(crate) fn true_relative_ppm() -> Vec<f64> {
    let specs = ecsync_sim::config::parse_segment("paper-2024", preset::PAPER_2024_TOML).unwrap();
    let r = specs[0].crystal.ppm;
    specs
        .iter()
        .map(|s| ((1.0 + s.crystal.ppm * 1e-6) / (1.0 + r * 1e-6) - 1.0) * 1e6)
        .collect()
}

/// `compare` on a twin's segment with the preset's host, run and method tables ranks the
/// methods as `compare` on the preset does.
pub(crate) fn ranks_as_the_preset(twin_text: &str, dir: &Path) {
    let rest = preset::PAPER_2024_TOML
        .find("\n[host]")
        .map(|at| &preset::PAPER_2024_TOML[at..])
        .expect("the preset has a [host] table");
    let scenario = dir.join("twin-scenario.toml");
    std::fs::write(&scenario, format!("{twin_text}\n{rest}")).unwrap();
    let preset_file = dir.join("paper-2024.toml");
    std::fs::write(&preset_file, preset::PAPER_2024_TOML).unwrap();
    let on_twin = ranking(&scenario, &dir.join("cmp-twin"));
    let on_preset = ranking(&preset_file, &dir.join("cmp-preset"));
    println!("ranking on the twin: {on_twin:?}; on the preset: {on_preset:?}");
    assert_eq!(on_twin, on_preset, "the twin ranks the methods otherwise");
}

/// `compare` on a scenario file, short (one run, 20 000 cycles), its ranking.
fn ranking(scenario: &Path, out: &Path) -> Vec<String> {
    let o = Command::new(ecsync())
        .args([
            "compare",
            "--config",
            scenario.to_str().unwrap(),
            "--runs",
            "1",
            "--cycles",
            "20000",
            "--warmup-s",
            "15",
            "--seed",
            "7",
            "--host",
            "preempt-rt-stress",
            "--threads",
            "2",
            "--quiet",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .expect("run ecsync compare");
    assert!(
        o.status.success(),
        "compare --config {}: {}",
        scenario.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("compare JSON");
    j["recommendation"]["ranking"]
        .as_array()
        .expect("a ranking")
        .iter()
        .map(|m| m.as_str().unwrap_or_default().to_string())
        .collect()
}
