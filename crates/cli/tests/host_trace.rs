//! `compare --host-trace` and `host fit` on a trace file: a replay is a function of the seed
//! (two compares write the same summary, another seed another), a malformed trace is refused
//! naming its file, line and column, and the fitted `[host]` table and its check come out.

use std::path::{Path, PathBuf};
use std::process::Command;

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ecsync-host-trace-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A trace like a loaded host's: 50 us wake-ups with a spread, bursts of 10x every 5000 cycles.
fn write_trace(path: &Path) {
    let mut t = String::from("cycle,scheduled_ns,wake_latency_ns,exec_ns,tx_delay_ns\n");
    let mut x = 12345u64;
    for c in 0..20_000u64 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let spread = x % 8_000;
        let wake = if c % 5_000 < 400 { 10 * spread } else { spread } + 50_000;
        t.push_str(&format!(
            "{c},{},{wake},{},{}\n",
            c * 1_000_000,
            900 + x % 200,
            14_000 + x % 900
        ));
    }
    std::fs::write(path, t).unwrap();
}

/// The value without the keys that measure the machine (at every depth).
fn strip(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| k != "wall_s" && k != "threads");
            m.values_mut().for_each(strip);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
        _ => {}
    }
}

/// summary.json without the machine's figures.
fn summary(out: &Path) -> String {
    let text = std::fs::read_to_string(out.join("summary.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    strip(&mut v);
    v.to_string()
}

fn compare(trace: &Path, out: &Path, seed: &str) {
    let o = ecsync()
        .args(["compare", "--host-trace"])
        .arg(trace)
        .args([
            "--runs",
            "1",
            "--cycles",
            "4000",
            "--warmup-s",
            "1",
            "--methods",
            "bus-shift,snap",
            "--threads",
            "1",
            "--quiet",
            "--seed",
            seed,
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_replay_is_a_function_of_the_seed() {
    let d = dir("replay");
    let trace = d.join("trace.csv");
    write_trace(&trace);
    let (a, b, c) = (d.join("a"), d.join("b"), d.join("c"));
    compare(&trace, &a, "7");
    compare(&trace, &b, "7");
    compare(&trace, &c, "8");
    let (sa, sb, sc) = (summary(&a), summary(&b), summary(&c));
    assert_eq!(sa, sb, "the same seed, the same summary");
    assert_ne!(sa, sc, "another seed, another replay");
    assert!(sa.contains("trace "), "the host is named as the trace");
}

#[test]
fn a_malformed_trace_is_refused_with_file_line_and_field() {
    let d = dir("malformed");
    let trace = d.join("bad.csv");
    std::fs::write(
        &trace,
        "cycle,scheduled_ns,wake_latency_ns,exec_ns,tx_delay_ns\n0,0,50000,900,\n1,1,50000,9x0,\n",
    )
    .unwrap();
    let want = format!("{}:3: exec_ns", trace.display());
    for args in [vec!["compare", "--host-trace"], vec!["host", "fit"]] {
        let o = ecsync().args(&args).arg(&trace).output().unwrap();
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(&want), "{args:?}: {err}");
    }
}

#[test]
fn host_fit_writes_a_host_table_and_checks_the_second_half() {
    let d = dir("fit");
    let trace = d.join("trace.csv");
    write_trace(&trace);
    let table = d.join("host.toml");
    let o = ecsync()
        .args(["host", "fit", "--check", "--out"])
        .arg(&table)
        .arg(&trace)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("[host]") && out.contains("bursts = {"),
        "{out}"
    );
    assert!(
        out.contains("wake-up p99: predicted") && out.contains("wake-up p99.9: predicted"),
        "{out}"
    );
    let written = std::fs::read_to_string(&table).unwrap();
    assert!(ecsync_lab::scenario::check_in_scenario(&written).is_ok());
}

/// A trace of a core jitter (50-58 us) and `outliers` wake-ups of 2 ms spread over `n` cycles;
/// its wake-up latencies.
fn write_thin_trace(path: &Path, n: u64, outliers: u64) -> Vec<f64> {
    let mut t = String::from("cycle,scheduled_ns,wake_latency_ns,exec_ns,tx_delay_ns\n");
    let mut wakes = Vec::new();
    let mut x = 12345u64;
    for c in 0..n {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let every = n / outliers.max(1);
        let wake = if outliers > 0 && c % every == every / 2 {
            2_000_000 + x % 1_000
        } else {
            50_000 + x % 8_000
        };
        wakes.push(wake as f64);
        t.push_str(&format!(
            "{c},{},{wake},{},\n",
            c * 1_000_000,
            900 + x % 200
        ));
    }
    std::fs::write(path, t).unwrap();
    wakes
}

/// The figure after `key` in `line`, up to the next space.
fn figure_after(line: &str, key: &str) -> f64 {
    let rest = &line[line.find(key).unwrap() + key.len()..];
    rest.split(' ').next().unwrap().parse().unwrap()
}

/// A short trace's few long wake-ups are too few to fit pulses to: the model then misses the
/// trace's own p99.9 by thirty times, and `host fit` says so (it printed the table alone),
/// with the trace's figure computed here by hand; a trace without them has no warning.
#[test]
fn host_fit_warns_when_its_model_misses_the_trace_it_was_fitted_on() {
    let d = dir("thin");
    for (outliers, warned) in [(6, true), (0, false)] {
        let trace = d.join(format!("thin-{outliers}.csv"));
        let mut wakes = write_thin_trace(&trace, 3_000, outliers);
        let o = ecsync().args(["host", "fit"]).arg(&trace).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (out, err) = (
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
        );
        let line = out
            .lines()
            .find(|l| l.starts_with("# the model against the cycles it was fitted on"))
            .unwrap_or_else(|| panic!("{out}"));
        // The trace's p99.9 by linear interpolation between ranks, as quantiles are read.
        wakes.sort_by(f64::total_cmp);
        let x = 0.999 * (wakes.len() - 1) as f64;
        let (i, f) = (x.floor() as usize, x - x.floor());
        let p999_us = (wakes[i] + f * (wakes[i + 1] - wakes[i])) / 1000.0;
        let printed = figure_after(line, "p99.9 ");
        let trace_printed = figure_after(line.rsplit_once("(the trace ").unwrap().1, "");
        assert!((trace_printed - p999_us).abs() < 0.06, "{line}: {p999_us}");
        let off = !(0.5..=2.0).contains(&(printed / trace_printed));
        assert_eq!(off, warned, "{line}");
        assert_eq!(
            err.contains("warning: the model's wake-up p99.9") && err.contains("record longer"),
            warned,
            "{err}"
        );
    }
}
