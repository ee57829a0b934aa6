//! `ecsync compare` tells the truth: every figure of summary.json recomputed from the per-cycle
//! samples (`--samples`), the verdict's schema and rule, the letter's rows only on its testbed,
//! Ctrl-C, and the command line's refusals.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-truth-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// The exact quantile as summary.json defines it: rank ceil(q n), ascending.
fn exact(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    let r = ((q * n as f64).ceil() as usize).clamp(1, n);
    sorted[r - 1]
}

fn bound(j: &serde_json::Value, v: f64) -> f64 {
    let q = &j["quantiles"];
    q["rel_error"].as_f64().unwrap() * v.abs() + q["abs_error_ns"].as_f64().unwrap()
}

/// Columns of a samples file by name.
fn read_samples(p: &Path) -> BTreeMap<String, Vec<Option<f64>>> {
    let text = std::fs::read_to_string(p).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let mut cols: BTreeMap<String, Vec<Option<f64>>> =
        head.iter().map(|h| (h.clone(), Vec::new())).collect();
    for l in lines {
        let cells: Vec<&str> = l.split(',').collect();
        for (i, h) in head.iter().enumerate() {
            let v = cells.get(i).and_then(|c| c.parse::<f64>().ok());
            cols.get_mut(h).unwrap().push(v);
        }
    }
    cols
}

fn check_summary(j: &serde_json::Value, what: &str, s: &serde_json::Value, xs: &mut [f64]) {
    xs.sort_by(f64::total_cmp);
    assert_eq!(s["n"].as_u64().unwrap() as usize, xs.len(), "{what} n");
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let rms = (xs.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let std = (xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n).sqrt();
    let f = |k: &str| s[k].as_f64().unwrap_or(f64::NAN);
    // The samples are written with 3 decimals.
    let close = |a: f64, b: f64| (a - b).abs() <= 0.001 + 1e-9 * b.abs();
    assert!(
        close(f("min"), xs[0]),
        "{what} min {} vs {}",
        f("min"),
        xs[0]
    );
    assert!(close(f("max"), xs[xs.len() - 1]), "{what} max");
    assert!(
        (f("mean") - mean).abs() <= 0.001,
        "{what} mean {} vs {mean}",
        f("mean")
    );
    assert!(
        (f("rms") - rms).abs() <= 0.001,
        "{what} rms {} vs {rms}",
        f("rms")
    );
    assert!(
        (f("std") - std).abs() <= 0.01,
        "{what} std {} vs {std}",
        f("std")
    );
    for (k, q) in [
        ("p001", 0.001),
        ("p01", 0.01),
        ("p50", 0.5),
        ("p99", 0.99),
        ("p999", 0.999),
    ] {
        let e = exact(xs, q);
        let got = f(k);
        assert!(
            (got - e).abs() <= bound(j, e) + 0.001,
            "{what} {k}: reported {got}, exact {e}"
        );
    }
    let mut mags: Vec<f64> = xs.iter().map(|x| x.abs()).collect();
    mags.sort_by(f64::total_cmp);
    for (k, q) in [("p99_abs", 0.99), ("p999_abs", 0.999)] {
        let e = exact(&mags, q);
        assert!((f(k) - e).abs() <= bound(j, e) + 0.001, "{what} {k}");
    }
}

/// Acceptance 2: the schema, the rule, and every percentile recomputed from `--samples`
/// within the stated bound, on a network that is not the letter's testbed (its rows absent).
#[test]
fn every_figure_is_recomputed_from_the_samples() {
    let out = tmp("samples");
    let samples = out.join("samples");
    let cfg = out.join("net.toml");
    // The preset with its reference drive's crystal moved: another network.
    let text = ecsync_sim::preset::PAPER_2024_TOML.replacen("ppm = 12.4", "ppm = -20.5", 1);
    std::fs::write(&cfg, text).unwrap();
    let o = ecsync()
        .args(["compare", "--quiet", "--runs", "2", "--cycles", "6000"])
        .args(["--warmup-s", "11", "--out"])
        .arg(&out)
        .arg("--config")
        .arg(&cfg)
        .arg("--samples")
        .arg(&samples)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = json(&out.join("summary.json"));
    // The verdict.
    let rec = &j["recommendation"];
    let ranking: Vec<&str> = rec["ranking"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    // Every method ranked but a controller that never reported in sync in a recorded cycle
    // (11 s of warm-up leave a DCM pulling in): its figures are its pull-in.
    let never_in_sync: Vec<&str> = j["methods"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(_, m)| m["controller"]["in_sync_fraction"].as_f64() == Some(0.0))
        .map(|(k, _)| k.as_str())
        .collect();
    let mut not_ranked: Vec<&str> = rec["not_ranked"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["method"].as_str().unwrap())
        .collect();
    not_ranked.sort_unstable();
    assert_eq!(not_ranked, never_in_sync, "{rec}");
    assert_eq!(
        ranking.len() + not_ranked.len(),
        ecsync_dc::MethodKind::DEFAULT.len()
    );
    assert_eq!(rec["method"].as_str().unwrap(), ranking[0]);
    assert!(rec["reason"].as_str().unwrap().len() > 80, "{rec}");
    // Late or lost: a cycle whose drives kept the outputs before, or whose inputs never came.
    let late = |m: &str| {
        j["methods"][m]["ground_truth"]["late_or_lost_frames"]
            .as_u64()
            .unwrap()
    };
    let fewest = ranking.iter().map(|m| late(m)).min().unwrap();
    assert_eq!(
        late(ranking[0]),
        fewest,
        "the pick has the fewest late or lost frames"
    );
    // Not the letter's testbed: no letter rows anywhere.
    assert_eq!(j["letter_testbed"], false);
    assert!(j["methods"]["median"]["letter"].is_null());
    let t1 = std::fs::read_to_string(out.join("table1.txt")).unwrap();
    assert!(!t1.contains("letter  "), "{t1}");
    assert!(!t1.contains("MMean letter"), "{t1}");

    for (name, m) in j["methods"].as_object().unwrap() {
        let g = &m["ground_truth"];
        for k in ["mean", "std", "rms", "p99", "p999", "min", "max", "max_abs"] {
            assert!(g["phase"][k].is_number(), "{name} phase.{k}");
        }
        assert!(g["target_phase_ns"].is_number() && g["smallest_safe_shift_pct"].is_number());
        // Pool both runs' samples.
        let mut cols: BTreeMap<String, Vec<Option<f64>>> = BTreeMap::new();
        for r in 0..2 {
            for (k, v) in read_samples(&samples.join(format!("{name}-run{r}.csv"))) {
                cols.entry(k).or_default().extend(v);
            }
        }
        let col = |k: &str| -> Vec<f64> { cols[k].iter().flatten().copied().collect() };
        assert_eq!(
            cols["cycle"].len(),
            12_000,
            "{name}: one row per recorded cycle"
        );
        check_summary(
            &j,
            &format!("{name} phase"),
            &g["phase"],
            &mut col("true_phase_ns"),
        );
        check_summary(
            &j,
            &format!("{name} m_rs"),
            &m["m_rs_pooled"],
            &mut col("m_rs_ns"),
        );
        check_summary(
            &j,
            &format!("{name} rs_is"),
            &m["rs_is_pooled"],
            &mut col("rs_is_ns"),
        );
        check_summary(
            &j,
            &format!("{name} spread"),
            &g["slave_ref_diff"],
            &mut col("slave_spread_ns"),
        );
        check_summary(
            &j,
            &format!("{name} margin"),
            &g["sync0_margin"],
            &mut col("worst_margin_ns"),
        );
        let lates = col("late").iter().filter(|&&x| x == 1.0).count() as u64;
        assert_eq!(g["late_frames"].as_u64().unwrap(), lates, "{name} late");
        // Per slave: margin min and p0.1, and the shift each needs.
        let slaves = g["per_slave"].as_array().unwrap();
        assert_eq!(slaves.len(), 6);
        for s in slaves {
            let pos = s["position"].as_u64().unwrap();
            let mut xs = col(&format!("margin_{pos}_ns"));
            xs.sort_by(f64::total_cmp);
            let min = s["margin_min_ns"].as_f64().unwrap();
            assert!((min - xs[0]).abs() <= 0.001, "{name} slave {pos} min");
            let p = s["margin_p001_ns"].as_f64().unwrap();
            let e = exact(&xs, 0.001);
            assert!(
                (p - e).abs() <= bound(&j, e) + 0.001,
                "{name} slave {pos} p0.1"
            );
            let shift = s["smallest_safe_shift_pct"].as_f64().unwrap();
            // The shift needed: the latest end after the grid point, rounded up to 0.1 % (0
            // when every frame passed before the grid point).
            let latest = 300_000.0 - xs[0];
            if latest <= 0.0 {
                assert_eq!(shift, 0.0, "{name} slave {pos}");
            } else {
                assert!(
                    shift * 10_000.0 >= latest - 0.01 && (shift - 0.1) * 10_000.0 < latest,
                    "{name} slave {pos}: {shift} % for {latest} ns"
                );
            }
        }
        if let Some(ctl) = m["controller"].as_object() {
            assert!(ctl["in_sync_fraction"].is_number());
            let adj = col("ctl_adjustment_ns");
            assert_eq!(
                adj.len(),
                12_000,
                "{name}: the controller's log every cycle"
            );
        }
    }
}

// Acceptance 4 (SIGINT stops a long comparison and keeps what it measured) is in
// tests/interrupt.rs, beside the bring-up's.

fn refused(args: &[&str]) -> String {
    let o = ecsync().args(args).output().unwrap();
    assert!(!o.status.success(), "{args:?} was accepted");
    let e = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!e.contains("panicked"), "{e}");
    e
}

/// Item 8: the command line.
#[test]
fn the_command_line_refuses_with_a_hint() {
    // A negative number is a value, refused by its range.
    let e = refused(&["compare", "--shift-pct", "-10", "--quiet"]);
    assert!(!e.contains("unexpected argument"), "{e}");
    assert!(e.contains("--shift-pct") && e.contains("fix:"), "{e}");
    // A target at or after SYNC0 leaves no margin (every frame late, warnings of 450000 % of
    // a 0 us margin): refused on the options that made it, or on the file's field.
    for args in [
        &["--shift-pct", "0"][..],
        &["--target-phase-us", "400"][..],
        &["--shift-pct", "10", "--target-phase-us", "100"][..],
    ] {
        let mut a = vec!["compare", "--quiet"];
        a.extend_from_slice(args);
        let e = refused(&a);
        assert!(
            e.contains("at or after SYNC0") && e.contains("--shift-pct") && e.contains("fix:"),
            "{e}"
        );
    }
    let dir = tmp("target");
    let f = dir.join("late.toml");
    std::fs::write(
        &f,
        ecsync_sim::preset::PAPER_2024_TOML.replace("target_phase_us = 0", "target_phase_us = 350"),
    )
    .unwrap();
    let e = refused(&["compare", "--config", f.to_str().unwrap(), "--quiet"]);
    assert!(
        e.contains("late.toml:") && e.contains("run.target_phase_us"),
        "{e}"
    );
    // --help lists the methods, the host presets and the defaults.
    let o = ecsync().args(["compare", "--help"]).output().unwrap();
    let h = String::from_utf8_lossy(&o.stdout);
    for m in ecsync_dc::MethodKind::NAMES {
        assert!(h.contains(m), "{m} in --help");
    }
    for p in ecsync_sim::host::HostParams::PRESETS {
        assert!(h.contains(p), "{p} in --help");
    }
    // Every command that takes --preset names every built-in network (the list is prose).
    for cmd in ["compare", "bringup", "serve", "sweep", "tune", "run", "tsn"] {
        let o = ecsync().args([cmd, "--help"]).output().unwrap();
        let h = String::from_utf8_lossy(&o.stdout);
        if h.contains("--preset") {
            for (n, _) in ecsync_sim::preset::NETWORKS {
                assert!(h.contains(n), "{n} in {cmd} --help");
            }
        }
    }
    assert!(
        h.contains("SYNC0 shift 30 %") && h.contains("1800000"),
        "{h}"
    );
    // Warm-up shorter than an init: the same words on the command line and in the file.
    let cli = refused(&["compare", "--warmup-s", "5", "--quiet"]);
    assert!(cli.contains("--warmup-s"), "{cli}");
    let dir = tmp("cli");
    let f = dir.join("short.toml");
    std::fs::write(
        &f,
        ecsync_sim::preset::PAPER_2024_TOML.replace("warmup_s = 120", "warmup_s = 5"),
    )
    .unwrap();
    let file = refused(&["compare", "--config", f.to_str().unwrap(), "--quiet"]);
    assert!(
        file.contains("short.toml:") && file.contains("run.warmup_s"),
        "{file}"
    );
    let words = "shorter than median's 10000 initialisation frames";
    assert!(cli.contains(words) && file.contains(words), "{cli}\n{file}");
    // Implausible values.
    let f = dir.join("cycle.toml");
    std::fs::write(
        &f,
        ecsync_sim::preset::PAPER_2024_TOML.replace("cycle_us = 1000", "cycle_us = 1000000"),
    )
    .unwrap();
    let e = refused(&["compare", "--config", f.to_str().unwrap()]);
    assert!(
        e.contains("run.cycle_us") && e.contains("did you mean 1000 us"),
        "{e}"
    );
    let f = dir.join("jitter.toml");
    std::fs::write(
        &f,
        ecsync_sim::preset::PAPER_2024_TOML.replace(
            "preset = \"preempt-rt-stress\"",
            "preset = \"preempt-rt-stress\"\njs = { sigma_ns = 1e9 }",
        ),
    )
    .unwrap();
    let e = refused(&["compare", "--config", f.to_str().unwrap()]);
    assert!(e.contains("host.js.sigma_ns") && e.contains("fix:"), "{e}");
    // bench --cycles 0.
    let e = refused(&["bench", "--cycles", "0", "--skip-compare"]);
    assert!(e.contains("--cycles") && e.contains("fix:"), "{e}");
    // bringup (and serve, which reads the file the same way) refuse unknown sections and
    // fields exactly as compare does.
    let f = dir.join("unknown.toml");
    std::fs::write(
        &f,
        format!("{}\n[extra]\nx = 1\n", ecsync_sim::preset::PAPER_2024_TOML),
    )
    .unwrap();
    let c = refused(&["compare", "--config", f.to_str().unwrap()]);
    let b = refused(&["bringup", "--config", f.to_str().unwrap()]);
    assert!(c.contains("unknown field") && c.contains("extra"), "{c}");
    assert_eq!(c, b, "compare and bringup refuse with the same words");
    let f = dir.join("typo.toml");
    std::fs::write(
        &f,
        ecsync_sim::preset::PAPER_2024_TOML.replacen("cable_m = 2.0", "cable_mm = 2.0", 1),
    )
    .unwrap();
    let c = refused(&["compare", "--config", f.to_str().unwrap()]);
    let b = refused(&["bringup", "--config", f.to_str().unwrap()]);
    assert!(c.contains("cable_mm"), "{c}");
    assert_eq!(c, b);
    #[cfg(target_os = "linux")]
    {
        let s = refused(&["serve", "--iface", "lo", "--config", f.to_str().unwrap()]);
        assert_eq!(c, s, "serve refuses like compare");
    }
}

/// The template documents every [host] field.
#[test]
fn the_template_documents_every_host_field() {
    let t = ecsync_sim::preset::PAPER_2024_TOML;
    let host = &t[t.find("[host]").unwrap()..t.find("[run]").unwrap()];
    // Every field the parser takes, read from its own source: a field added to [host] (or to
    // a jitter process, or to the bursts) and not documented fails here.
    let fields_of = |file: &str, item: &str| -> Vec<String> {
        let src =
            std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(file))
                .unwrap();
        let body = &src[src.find(item).unwrap_or_else(|| panic!("{item} in {file}"))..];
        let body = &body[body.find('{').unwrap() + 1..body.find("\n}").unwrap()];
        body.lines()
            .map(str::trim)
            .filter(|l| !l.starts_with("//") && !l.starts_with('#'))
            .filter_map(|l| l.split_once(':').map(|(n, _)| n.trim_start_matches("pub ")))
            .map(str::to_owned)
            .collect()
    };
    let mut fields = fields_of("../lab/src/scenario.rs", "struct HostFile {");
    fields.extend(fields_of("../sim/src/host.rs", "pub struct Jitter {"));
    fields.extend(fields_of("../sim/src/host.rs", "pub struct Bursts {"));
    assert!(fields.len() >= 18, "{fields:?}");
    for f in &fields {
        assert!(
            host.contains(&format!("{f} =")),
            "[host] does not document {f}"
        );
    }
    // The documented values are the preset's own: uncommented, they change nothing.
    let uncommented: String = t
        .lines()
        .map(|l| match l.strip_prefix("# ") {
            Some(r) if host.contains(l) && r.contains(" = ") && !r.contains(':') => r,
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n");
    let a = ecsync_lab::parse("a", t).unwrap();
    let b = ecsync_lab::parse("b", &uncommented).unwrap();
    assert_eq!(a.host, b.host);
}

/// The README's own-network example: the twelve-drive file runs, and the comparison warns
/// about the crystals and about median's offset, while median-fit holds its target.
#[test]
fn the_twelve_drive_example_warns_about_median() {
    let out = tmp("twelve");
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/twelve-drives.toml");
    let o = ecsync()
        .args(["compare", "--quiet", "--runs", "1", "--cycles", "3000"])
        .args([
            "--warmup-s",
            "11",
            "--methods",
            "median,median-fit",
            "--out",
        ])
        .arg(&out)
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = json(&out.join("summary.json"));
    assert_eq!(j["slaves"], 12);
    let kinds: Vec<(&str, &str)> = j["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| {
            (
                w["kind"].as_str().unwrap(),
                w["method"].as_str().unwrap_or(""),
            )
        })
        .collect();
    assert!(kinds.contains(&("crystal_difference", "")), "{kinds:?}");
    assert!(kinds.contains(&("off_target", "median")), "{kinds:?}");
    assert!(!kinds.iter().any(|k| k.1 == "median-fit"), "{kinds:?}");
    assert_eq!(j["recommendation"]["method"], "median-fit");
    let off = j["methods"]["median"]["ground_truth"]["offset_from_target_ns"]
        .as_f64()
        .unwrap();
    assert!((200_000.0..300_000.0).contains(&off.abs()), "{off}");
}

fn compare_json(out: &Path, args: &[&str], config: Option<&str>) -> (serde_json::Value, String) {
    let mut c = ecsync();
    c.args(["compare", "--out"]).arg(out).args(args);
    if let Some(text) = config {
        let f = out.join("net.toml");
        std::fs::write(&f, text).unwrap();
        c.arg("--config").arg(f);
    }
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (
        json(&out.join("summary.json")),
        String::from_utf8_lossy(&o.stdout).to_string(),
    )
}

fn warning_kinds(j: &serde_json::Value) -> Vec<String> {
    j["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["kind"].as_str().unwrap().to_string())
        .collect()
}

/// The warnings where a figure is at risk, each where it should come: jitter eating the margin,
/// late frames; and "1 run", "1 thread". A cycle shorter than the frame's way is refused.
#[test]
fn warnings_come_where_the_figures_are_at_risk() {
    let base = ecsync_sim::preset::PAPER_2024_TOML;
    // A 45 us cycle: the frame needs about 52 us from its send to its reply, 74 from the
    // cycle's start (the host's 20 us of execution first). Refused before the bring-up, with
    // the cycle to set, and nothing written.
    let out = tmp("short-cycle");
    let text = base.replace("cycle_us = 1000", "cycle_us = 45").replace(
        "methods = [\"median\", \"median-fit\", \"pi-m2s\", \"bus-shift\", \"dcm-bus-shift\", \"dcm-master-shift\", \"snap\", \"soem-pi\"]",
        "methods = [\"bus-shift\"]",
    );
    let f = out.join("net.toml");
    std::fs::write(&f, &text).unwrap();
    let o = ecsync()
        .args(["compare", "--quiet", "--runs", "1", "--out"])
        .arg(out.join("report"))
        .arg("--config")
        .arg(&f)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!(
            "{}: the 45 us cycle is too short for this network: its 1 cyclic frames take 24.0 us on the wire",
            f.display()
        )) && err.contains("set run.cycle_us (or --cycle-us) to 180 or more"),
        "{err}"
    );
    assert!(!out.join("report").join("summary.json").exists());
    // A shift of 3 %: the loaded host's jitter takes the frames past SYNC0.
    let out = tmp("small-shift");
    let (j, stdout) = compare_json(
        &out,
        &[
            "--quiet",
            "--runs",
            "1",
            "--cycles",
            "20000",
            "--warmup-s",
            "11",
            "--shift-pct",
            "3",
            "--methods",
            "dcm-master-shift,median-fit,snap",
            "--threads",
            "1",
        ],
        None,
    );
    let k = warning_kinds(&j);
    assert!(k.contains(&"late_frames".into()), "{k:?}");
    assert!(
        stdout.contains("1 run x") && stdout.contains("on 1 thread"),
        "{stdout}"
    );
    // The pick has the fewest late (or lost) frames of all, and here they differ between the
    // methods.
    let late_of = |m: &str| {
        j["methods"][m]["ground_truth"]["late_or_lost_frames"]
            .as_u64()
            .unwrap()
    };
    let lates: Vec<u64> = ["dcm-master-shift", "median-fit", "snap"]
        .iter()
        .map(|m| late_of(m))
        .collect();
    let pick = j["recommendation"]["method"].as_str().unwrap();
    assert_eq!(late_of(pick), *lates.iter().min().unwrap(), "{lates:?}");
    assert!(lates.iter().max() > lates.iter().min(), "{lates:?}");
    assert_eq!(j["recommendation"]["ranking"].as_array().unwrap().len(), 3);
    // Just above the smallest safe shift the small shift's run found (the same seed, so the
    // same frames): no late frame, but the jitter's tail takes over half the margin.
    let safe = j["methods"]["dcm-master-shift"]["ground_truth"]["smallest_safe_shift_pct"]
        .as_f64()
        .unwrap();
    let tight = format!("{:.1}", safe + 0.5);
    let out = tmp("tight-shift");
    let (j, stdout) = compare_json(
        &out,
        &[
            "--runs",
            "1",
            "--cycles",
            "20000",
            "--warmup-s",
            "11",
            "--shift-pct",
            &tight,
            "--methods",
            "dcm-master-shift",
            "--threads",
            "1",
        ],
        None,
    );
    let k = warning_kinds(&j);
    let g = &j["methods"]["dcm-master-shift"]["ground_truth"];
    assert_eq!(g["late_frames"].as_u64(), Some(0), "at {tight} %");
    assert!(k.contains(&"jitter_eats_margin".into()), "{k:?}");
    assert!(!k.contains(&"late_frames".into()), "{k:?}");
    assert!(
        stdout.contains("1 run x") && stdout.contains("on 1 thread."),
        "{stdout}"
    );
}

/// The vendor's enhanced set value (the cycle's start) holds the target too and reports in
/// sync; the controller's log comes with the samples.
#[test]
fn dcm_with_the_cycle_start_set_value() {
    let text = ecsync_sim::preset::PAPER_2024_TOML.replace(
        "[methods.dcm-master-shift]\nset_value_ref = \"frame-send\"",
        "[methods.dcm-master-shift]\nset_value_ref = \"cycle-start\"",
    );
    assert_ne!(text, ecsync_sim::preset::PAPER_2024_TOML);
    let out = tmp("cycle-start");
    let (j, _) = compare_json(
        &out,
        &[
            "--quiet",
            "--runs",
            "1",
            "--cycles",
            "30000",
            "--warmup-s",
            "5",
            "--methods",
            "dcm-master-shift,dcm-bus-shift",
        ],
        Some(&text),
    );
    for m in ["dcm-master-shift", "dcm-bus-shift"] {
        let mo = &j["methods"][m];
        let off = mo["ground_truth"]["offset_from_target_ns"]
            .as_f64()
            .unwrap();
        assert!(off.abs() < 2_000.0, "{m}: {off} ns off its target");
        assert_eq!(
            mo["controller"]["in_sync_at_end"], true,
            "{m}: {}",
            mo["controller"]
        );
    }
}

/// The output stays the same size whatever the cycle count: series of at most 600 points.
#[test]
fn output_size_is_bounded() {
    let size = |cycles: &str| {
        let out = tmp(&format!("size-{cycles}"));
        compare_json(
            &out,
            &[
                "--quiet",
                "--runs",
                "1",
                "--cycles",
                cycles,
                "--warmup-s",
                "0",
                "--methods",
                "bus-shift,snap",
            ],
            None,
        );
        // Every file the comparison writes, by name.
        std::fs::read_dir(&out)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().into_owned(),
                    e.metadata().unwrap().len(),
                )
            })
            .collect::<std::collections::BTreeMap<String, u64>>()
    };
    let (small, large) = (size("6000"), size("600000"));
    assert_eq!(
        small.keys().collect::<Vec<_>>(),
        large.keys().collect::<Vec<_>>()
    );
    assert!(small.len() >= 15, "{small:?}");
    for (f, &s) in &small {
        let l = large[f];
        // (PNGs compress what they show: a denser band may cost some more bytes.)
        assert!(
            (l as f64) < 1.5 * s as f64 + 4096.0 && l < 2_000_000,
            "{f}: {s} bytes at 6000 cycles, {l} at 600000"
        );
    }
}

/// `--host` puts another preset in place of the file's host but keeps the machine's crystal
/// the file gives (`[host] master_ppm`): it showed the preset's (0 for ideal, +13.3 for the
/// stressed RT host) and compared a crystal the file never described; `--master-ppm` still
/// overrides both, and a file without master_ppm takes the preset's.
#[test]
fn another_host_preset_keeps_the_file_s_master_crystal() {
    let text = include_str!("../../../presets/paper-2024.toml").replacen(
        "[host]",
        "[host]\nmaster_ppm = -20.0",
        1,
    );
    let base = [
        "--methods",
        "median",
        "--runs",
        "1",
        "--cycles",
        "1000",
        "--quiet",
    ];
    let run = |name: &str, extra: &[&str], cfg: Option<&str>| {
        let out = tmp(name);
        let args: Vec<&str> = base.iter().chain(extra).copied().collect();
        let (j, _) = compare_json(&out, &args, cfg);
        (
            j["host"].as_str().unwrap().to_string(),
            j["master_ppm"].as_f64().unwrap(),
        )
    };
    assert_eq!(
        run("host-keep", &["--host", "ideal"], Some(&text)),
        ("ideal (modified)".to_string(), -20.0)
    );
    assert_eq!(
        run(
            "host-override",
            &["--host", "ideal", "--master-ppm", "7"],
            Some(&text)
        ),
        ("ideal (modified)".to_string(), 7.0)
    );
    assert_eq!(
        run("host-preset", &["--host", "ideal"], None),
        ("ideal".to_string(), 0.0)
    );
}
