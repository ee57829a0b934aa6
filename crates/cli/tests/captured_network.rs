//! The network of the captures of real hardware, `presets/ek1100-el2828-el2889.toml` (an EK1100
//! coupler with an EL2828 and an EL2889 digital output terminal; ../shared/captures/), under
//! ecsync's bring-up, `compare`, and SOEM (pysoem) over `serve`: the EL2828 says DC in 0x0008
//! and keeps no system time, so the reference is the EK1100 and the EL2889 the one slave
//! synchronised; the terminals' outputs go through SyncManagers at 0x0F00, and every LRW
//! counts what the real devices counted in the captures.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const PRESET: &str = "ek1100-el2828-el2889";

/// The masters that run in real time take the machine's cores one at a time.
static TIMED: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn ok(out: std::process::Output) -> std::process::Output {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `ecsync bringup --preset ek1100-el2828-el2889 --json`: ecsync's master picks the EK1100 as
/// reference (the first slave whose system time answers) and synchronises the EL2889 alone
/// (offset written, its true system time within 100 ns of the reference's after the lock);
/// the EL2828, whose 0x0008 says DC, is found with receive times only and gets its delay; every
/// delay within 30 ns of the segment's truth: without ESI timings (Beckhoff's give none) a
/// master cannot see that the way out through the EK1100 (107.5 ns) is shorter than the way
/// back through an ET1200 (145 ns), half the difference plus the EK1100's 40 and 10 ns stamp
/// grids (tests/clocks_by_answer.rs in ecsync-sim: with the timings, within 10 ns; without,
/// what ethercrab measured on the real devices). OP with the LRW working counter of two
/// terminals taking outputs (4) over their 3 bytes.
#[test]
fn bringup_picks_the_ek1100_and_syncs_the_el2889_alone() {
    let out = ok(ecsync()
        .args(["bringup", "--preset", PRESET, "--json"])
        .output()
        .unwrap());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["reference"], 0, "the EK1100");
    let slaves = v["slaves"].as_array().unwrap();
    let names: Vec<&str> = slaves.iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["EK1100", "EL2828", "EL2889"]);
    let dc: Vec<&str> = slaves.iter().map(|s| s["dc"].as_str().unwrap()).collect();
    assert_eq!(dc, ["system-time", "receive-times", "system-time"]);
    let synced: Vec<bool> = slaves.iter().map(|s| s["offset"].is_u64()).collect();
    assert_eq!(synced, [true, false, true], "offsets written");
    let products: Vec<u64> = slaves
        .iter()
        .map(|s| s["product_code"].as_u64().unwrap())
        .collect();
    assert_eq!(products, [0x044c_2c52, 0x0b0c_3052, 0x0b49_3052]);
    for s in slaves {
        let d = s["delay_ns"].as_f64().unwrap();
        let t = s["true_delay_ns"].as_f64().unwrap();
        assert!((d - t).abs() <= 30.0, "{}: {d} vs {t}", s["name"]);
    }
    let lock = &v["lock"];
    assert_eq!(lock["converged"], true);
    let max = lock["max_abs_diff_ns"].as_f64().unwrap();
    assert!(max < 100.0, "EL2889 - EK1100 after lock: {max} ns");
    assert_eq!(v["pdi_bytes"], 3);
    assert_eq!(v["expected_lrw_wkc"], 4);
}

/// `ecsync compare --preset ek1100-el2828-el2889` runs (two methods, a short run) and reports
/// them.
#[test]
fn compare_runs_on_the_captured_network() {
    let dir = std::env::temp_dir().join(format!("ecsync-captured-{}", std::process::id()));
    let out = ok(ecsync()
        .args(["compare", "--preset", PRESET, "--quiet", "--json"])
        .args([
            "--methods",
            "median-fit,snap",
            "--runs",
            "1",
            "--cycles",
            "3000",
        ])
        .args(["--warmup-s", "11", "--out"])
        .arg(&dir)
        .output()
        .unwrap());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for m in ["median-fit", "snap"] {
        assert!(v["methods"][m].is_object(), "{m} reported: {v}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The folder of the real captures (`../shared/captures/`: `$ECSYNC_SHARED/captures` if set,
/// else beside the repository), or a panic naming where it was looked for: the tests that call
/// this are ignored unless asked for.
fn captures_dir() -> PathBuf {
    let dir = match std::env::var_os("ECSYNC_SHARED") {
        Some(d) => PathBuf::from(d).join("captures"),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/captures"),
    };
    assert!(
        dir.join("replay-issue-255.pcapng").is_file(),
        "this test needs ../shared/captures (set ECSYNC_SHARED): {}",
        dir.display()
    );
    dir
}

/// The working counters the real devices gave the LRWs of a capture: each returned frame's
/// (the first ESC sets bit 1 of the source address) LRW datagrams.
fn captured_lrw_working_counters(file: &str) -> Vec<u16> {
    use pcap_file::pcapng::{Block, PcapNgReader};
    let path = captures_dir().join(file);
    let f = std::fs::File::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut r = PcapNgReader::new(std::io::BufReader::new(f)).expect("pcapng");
    let mut out = Vec::new();
    while let Some(b) = r.next_block() {
        let Block::EnhancedPacket(p) = b.expect("a block") else {
            continue;
        };
        if p.data.len() < 12 || p.data[6] & 0x02 == 0 {
            continue;
        }
        let Ok(frame) = ecsync_wire::EcatFrame::new_checked(&p.data[..]) else {
            continue;
        };
        for d in frame.datagrams().map_while(Result::ok) {
            if d.command_code() == ecsync_wire::Command::Lrw.code() {
                out.push(d.wkc());
            }
        }
    }
    out
}

/// SOEM (pysoem) over a veth pair against `serve --preset ek1100-el2828-el2889 --sandbox`: it
/// scans the three devices with their real identities, maps the terminals' outputs from their
/// SII (1 byte on the EL2828, 2 on the EL2889), reaches OP, and every LRW of its cyclic
/// exchange counts what replay-issue-255.pcapng's LRWs counted at the real devices.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces), pysoem, ../shared/captures"]
fn pysoem_reaches_op_with_the_captures_lrw_working_counters() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let real = captured_lrw_working_counters("replay-issue-255.pcapng");
    assert_eq!(real.len(), 64, "the capture's LRWs");
    let py = std::env::var("ECSYNC_PYSOEM_PYTHON").unwrap_or_else(|_| "python3".into());
    let has_pysoem = Command::new(&py)
        .args(["-c", "import pysoem"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        has_pysoem,
        "this test needs pysoem: set ECSYNC_PYSOEM_PYTHON to a Python that has it"
    );
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/digital_outputs.py");
    let t0 = Instant::now();
    let out = ecsync()
        .args(["serve", "--preset", PRESET, "--quiet", "--sandbox", "--"])
        .arg(&py)
        .arg(&script)
        .args(["--cycles", &real.len().to_string()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("--sandbox: cannot make"),
        "this test needs network namespaces, and this machine refused: {stderr}"
    );
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(t0.elapsed() < Duration::from_secs(240));
    // The ready line first, then the script's JSON.
    let line = stdout
        .lines()
        .find(|l| l.contains("\"wkc\""))
        .unwrap_or_else(|| panic!("the script's summary: {stdout}"));
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    let products: Vec<(u64, u64, u64)> = v["slaves"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["vendor"].as_u64().unwrap(),
                s["product"].as_u64().unwrap(),
                s["outputs"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        products,
        [
            (2, 0x044c_2c52, 0),
            (2, 0x0b0c_3052, 1),
            (2, 0x0b49_3052, 2)
        ]
    );
    let wkc: Vec<u16> = v["wkc"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_u64().unwrap() as u16)
        .collect();
    assert_eq!(wkc, real, "every LRW counts as at the real devices");
    assert_eq!(v["expected_wkc"], 4, "SOEM's own expectation");
}

/// `ecsync run` (ecsync's own master, in real time over a veth pair) against `serve --preset
/// ek1100-el2828-el2889 --sandbox`: the same choice as in virtual time (the EK1100 the
/// reference, the EL2889 the one clock synchronised, the EL2828 with receive times only), the
/// terminals' 3 bytes of outputs in OP, and no LRW with another working counter than 4.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn ecsync_run_over_serve_picks_the_ek1100_and_syncs_the_el2889_alone() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let run = format!(
        "{} run --iface \"$ECSYNC_IFACE\" --method median --duration 2 --static-drift 2000 --json",
        env!("CARGO_BIN_EXE_ecsync")
    );
    let out = ecsync()
        .args(["serve", "--preset", PRESET, "--quiet", "--sandbox", "--"])
        .args(["sh", "-c", &run])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("--sandbox: cannot make"),
        "this test needs network namespaces, and this machine refused: {stderr}"
    );
    assert!(out.status.success(), "{stdout}{stderr}");
    // The ready line, then run's summary.
    let at = stdout.find("\n{").expect("run's JSON after the ready line");
    let v: serde_json::Value = serde_json::from_str(&stdout[at + 1..]).unwrap();
    let b = &v["bringup"];
    assert_eq!(b["reference"], 0, "the EK1100");
    let slaves = b["slaves"].as_array().unwrap();
    let dc: Vec<&str> = slaves.iter().map(|s| s["dc"].as_str().unwrap()).collect();
    assert_eq!(dc, ["system-time", "receive-times", "system-time"]);
    let synced: Vec<bool> = slaves.iter().map(|s| s["offset"].is_u64()).collect();
    assert_eq!(synced, [true, false, true], "offsets written");
    assert_eq!(b["converged"], true);
    assert_eq!(
        (b["pdi_bytes"].as_u64(), b["expected_lrw_wkc"].as_u64()),
        (Some(3), Some(4))
    );
    assert_eq!(v["bad_wkc"], 0, "{stdout}");
}
