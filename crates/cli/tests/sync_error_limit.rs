//! Issue 13, acceptance 3, through the binary: a scenario's `[run] sync_error_limit` is the
//! 0x10F1:02 the master writes to the drives; with a SYNC0 shift too small for the host,
//! `ecsync compare` reports in summary.json and on the terminal the drives that left OP and
//! their AL status code (0x001A), without a fault schedule; a value that is not an
//! UNSIGNED16 is refused by `compare` and by `run --config` with the file, field and fix.

use std::path::PathBuf;
use std::process::Command;

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-sel-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// paper-2024 at a 4 % shift, one run of 5000 cycles of dcm-master-shift, and `extra` in its
/// `[run]` table, written to `dir`.
fn scenario(dir: &std::path::Path, extra: &str) -> PathBuf {
    let mut t = ecsync_sim::preset::PAPER_2024_TOML.to_string();
    for (from, to) in [
        ("sync0_shift_pct = 30", "sync0_shift_pct = 4".to_string()),
        ("runs = 5", "runs = 1".to_string()),
        ("cycles = 1800000", "cycles = 5000".to_string()),
        ("warmup_s = 120", "warmup_s = 0.5".to_string()),
        (
            "static_drift_frames = 15000",
            format!("static_drift_frames = 15000\n{extra}"),
        ),
    ] {
        assert!(t.contains(from), "the preset has `{from}`");
        t = t.replacen(from, &to, 1);
    }
    let m = t.find("\nmethods = [").unwrap() + 1;
    let end = m + t[m..].find('\n').unwrap();
    t.replace_range(m..end, "methods = [\"dcm-master-shift\"]");
    let p = dir.join("deadline.toml");
    std::fs::write(&p, t).unwrap();
    p
}

#[test]
fn compare_reports_the_drives_that_left_op_on_a_configured_limit() {
    for limit in [None, Some(4)] {
        let dir = tmp(&format!("cmp-{limit:?}"));
        let extra = limit.map_or(String::new(), |l| format!("sync_error_limit = {l}"));
        let cfg = scenario(&dir, &extra);
        let out = dir.join("out");
        let o = ecsync()
            .args(["compare", "--quiet", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout);
        let j: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
        let m = &j["methods"]["dcm-master-shift"];
        assert!(
            m["ground_truth"]["per_slave"][5]["late_frames"]
                .as_u64()
                .unwrap()
                > 10,
            "the shift is too small"
        );
        if limit.is_none() {
            assert!(m.get("left_op").is_none(), "{}", m["left_op"]);
            assert!(!stdout.contains("left OP"), "{stdout}");
            continue;
        }
        let left = m["left_op"].as_array().expect("left_op in summary.json");
        assert!(
            left.iter().any(|l| l["slave"] == 6
                && l["state"] == "SAFE-OP"
                && l["al_status_code"] == 0x001a
                && l["back_in_op_ms"].is_number()),
            "{left:?}"
        );
        assert!(
            stdout.contains("Warning: dcm-master-shift: drives left OP")
                && stdout.contains("slave 6 (drive-6) with AL status code 0x001a"),
            "{stdout}"
        );
    }
}

#[test]
fn a_limit_that_is_not_an_unsigned16_is_refused_with_file_field_and_fix() {
    let dir = tmp("bad");
    let cfg = scenario(&dir, "sync_error_limit = 70000");
    let o = ecsync()
        .args(["compare", "--quiet", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("deadline.toml")
            && e.contains("run.sync_error_limit")
            && e.contains("70000")
            && e.contains("0 to 65535"),
        "{e}"
    );
    // `run` reads the same key of its --config before it opens any interface.
    let o = ecsync()
        .args(["run", "--iface", "ecsync-no-such-if", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("deadline.toml")
            && e.contains("run.sync_error_limit")
            && e.contains("0 to 65535"),
        "{e}"
    );
}
