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
/// methods as `compare` on the preset does, to the ranking's own resolution: two methods may
/// swap places only where the preset's figures tie them on every key the verdict ranks by
/// (late frames, holding the target, the safe shift in steps of 0.5 %, the slave spread in
/// steps of 10 % of the best or 2 ns), up to one step: two figures a hair apart can sit in
/// neighbouring steps when a step's edge falls between them (soem-pi 41.9 and dcm-bus-shift
/// 46.2 ns on the preset, steps of 4.2 ns). Since MII stamps sit on the crystals' grids, most
/// methods' slave spread is the stamps' (45-48 ns on paper-2024), and a twin's measured
/// crystals and delays reorder such ties (dcm-bus-shift 2nd on the twin, 4th on the preset).
pub(crate) fn ranks_as_the_preset(twin_text: &str, dir: &Path) {
    let rest = preset::PAPER_2024_TOML
        .find("\n[host]")
        .map(|at| &preset::PAPER_2024_TOML[at..])
        .expect("the preset has a [host] table");
    let scenario = dir.join("twin-scenario.toml");
    std::fs::write(&scenario, format!("{twin_text}\n{rest}")).unwrap();
    let preset_file = dir.join("paper-2024.toml");
    std::fs::write(&preset_file, preset::PAPER_2024_TOML).unwrap();
    let (on_twin, _) = ranking(&scenario, &dir.join("cmp-twin"));
    let (on_preset, figures) = ranking(&preset_file, &dir.join("cmp-preset"));
    println!("ranking on the twin: {on_twin:?}; on the preset: {on_preset:?}");
    let mut twin_sorted = on_twin.clone();
    twin_sorted.sort();
    let mut preset_sorted = on_preset.clone();
    preset_sorted.sort();
    assert_eq!(twin_sorted, preset_sorted, "the same methods");
    let place = |r: &[String], m: &str| r.iter().position(|x| x == m).unwrap();
    for (i, a) in on_preset.iter().enumerate() {
        for b in &on_preset[i + 1..] {
            if place(&on_twin, a) < place(&on_twin, b) {
                continue;
            }
            let key = |m: &str| {
                let g = &figures[m]["ground_truth"];
                (
                    g["late_frames"].as_u64().unwrap(),
                    g["holds_target"].as_bool().unwrap(),
                    g["smallest_safe_shift_pct"].as_f64().unwrap(),
                    g["slave_ref_diff"]["p999_abs"].as_f64().unwrap(),
                )
            };
            let (ka, kb) = (key(a), key(b));
            let spread_step = (0.1 * ka.3.min(kb.3)).max(2.0);
            assert!(
                ka.0 == kb.0
                    && ka.1 == kb.1
                    && (ka.2 - kb.2).abs() < 2.0 * 0.5
                    && (ka.3 - kb.3).abs() < 2.0 * spread_step,
                "the twin ranks {b} before {a}, which the preset's figures separate: {ka:?} vs {kb:?}"
            );
        }
    }
}

/// `compare` on a scenario file, short (one run, 20 000 cycles): its ranking and its
/// methods' figures.
fn ranking(scenario: &Path, out: &Path) -> (Vec<String>, serde_json::Value) {
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
    let r = j["recommendation"]["ranking"]
        .as_array()
        .expect("a ranking")
        .iter()
        .map(|m| m.as_str().unwrap_or_default().to_string())
        .collect();
    (r, j["methods"].clone())
}
