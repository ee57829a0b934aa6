//! Every output of the existing presets stays what it was: summary.json of `compare` (reduced to
//! 2 runs of 20 000 cycles), the bring-up JSON, `tsn run`'s and `tsn models`' JSON, against
//! files recorded before a refactoring (`tests/golden/`). The machine's own figures (wall time,
//! threads) are left out. `ECSYNC_BLESS=1 cargo test -p ecsync --test golden` records them
//! anew, for a change that means to alter an output (and says so).

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn golden(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

/// The value without the keys that measure the machine.
fn strip(v: &mut Value) {
    match v {
        Value::Object(m) => {
            m.retain(|k, _| k != "wall_s" && k != "threads");
            for x in m.values_mut() {
                strip(x);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(strip),
        // A path into the checkout (the scenario file) is kept relative to the workspace: the
        // clone's location is the machine's, not the output's.
        Value::String(t) => {
            if let Some((_, rest)) = t.split_once("/crates/cli/../../") {
                *t = rest.to_string();
            }
        }
        _ => {}
    }
}

/// The first path where `a` and `b` differ.
fn first_difference(a: &Value, b: &Value, path: &str) -> Option<String> {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for k in x.keys().chain(y.keys()) {
                match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => {
                        if let Some(d) = first_difference(p, q, &format!("{path}.{k}")) {
                            return Some(d);
                        }
                    }
                    _ => return Some(format!("{path}.{k}: present in only one")),
                }
            }
            None
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (p, q))| first_difference(p, q, &format!("{path}[{i}]"))),
        _ if a == b => None,
        _ => Some(format!("{path}: {a} now, {b} recorded")),
    }
}

fn check(name: &str, json: &[u8]) {
    let mut now: Value = serde_json::from_slice(json).expect("JSON output");
    strip(&mut now);
    let path = golden(name);
    if std::env::var_os("ECSYNC_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, serde_json::to_string_pretty(&now).unwrap() + "\n").unwrap();
        return;
    }
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (record it with ECSYNC_BLESS=1)", path.display()));
    let mut recorded: Value = serde_json::from_str(&text).unwrap();
    strip(&mut recorded);
    if let Some(d) = first_difference(&now, &recorded, name) {
        panic!("{name} changed: {d}");
    }
}

fn ecsync(args: &[&str]) -> Vec<u8> {
    let o = Command::new(env!("CARGO_BIN_EXE_ecsync"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o.stdout
}

#[test]
fn compare_is_unchanged() {
    let out = std::env::temp_dir().join(format!("ecsync-golden-{}", std::process::id()));
    let json = ecsync(&[
        "compare",
        "--quiet",
        "--json",
        "--runs",
        "2",
        "--cycles",
        "20000",
        "--warmup-s",
        "12",
        "--out",
        out.to_str().unwrap(),
    ]);
    check("compare-paper-2024.json", &json);
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/twelve-drives.toml");
    let json = ecsync(&[
        "compare",
        "--quiet",
        "--json",
        "--runs",
        "1",
        "--cycles",
        "20000",
        "--warmup-s",
        "12",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    check("compare-twelve-drives.json", &json);
}

#[test]
fn bringup_is_unchanged() {
    check(
        "bringup-paper-2024.json",
        &ecsync(&["bringup", "--preset", "paper-2024", "--json"]),
    );
}

#[test]
fn tsn_run_is_unchanged() {
    let out = std::env::temp_dir().join(format!("ecsync-golden-tsn-{}", std::process::id()));
    check(
        "tsn-run-2020.json",
        &ecsync(&["tsn", "run", "--json", "--out", out.to_str().unwrap()]),
    );
}

#[test]
fn tsn_models_are_unchanged() {
    check("tsn-models.json", &ecsync(&["tsn", "models", "--json"]));
}
