//! `ecsync tsn run` end to end: the realistic M1/M2/M3 network on the built-in preset, what the
//! paper claims checked against the simulator's ground truth, the capture read by tshark, the
//! report files, reproducibility, and bad gate schedules.

use std::path::{Path, PathBuf};
use std::process::Command;

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-tsn-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn run(out: &Path, extra: &[&str]) -> serde_json::Value {
    let o = ecsync()
        .args(["tsn", "run", "--json", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON on stdout");
    let file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        j["variants"], file["variants"],
        "stdout and summary.json agree"
    );
    j
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn u(v: &serde_json::Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn the_preset_shows_what_the_paper_claims_against_ground_truth() {
    let out = tmp("preset");
    let pcap = tmp("preset-pcap");
    let j = run(
        &out,
        &["--pcap", pcap.to_str().unwrap(), "--pcap-seconds", "0.5"],
    );
    let v = &j["variants"];
    let (m1, m2, m3) = (&v["M1"], &v["M2"], &v["M3"]);
    for m in [m1, m2, m3] {
        assert_eq!(m["converged"], true, "{m}");
        assert_eq!(u(&m["lost_frames"]), 0);
        assert_eq!(m["delays"].as_array().unwrap().len(), 6);
    }
    // M1 has no bridge: nothing held, delays exact.
    assert_eq!(u(&m1["blocked"]["cyclic_forward"]), 0);
    assert!(f(&m1["max_abs_delay_error_ns"]) <= 20.0, "{m1}");

    // M2: the gate holds DC frames (delay measurement and cyclic) and the delays come out
    // wrong; nothing is held on the way back.
    let b2 = &m2["blocked"];
    assert!(u(&b2["latch_forward"]) > 0, "M2 holds DM_T: {b2}");
    assert!(u(&b2["cyclic_forward"]) > 0, "M2 holds SM: {b2}");
    assert_eq!(
        u(&b2["bringup_return"]) + u(&b2["cyclic_return"]),
        0,
        "DM_R never"
    );
    assert!(
        f(&m2["max_abs_delay_error_ns"]) > 1_000.0,
        "M2 mis-measures: {}",
        m2["delays"]
    );
    // Each measured delay against the truth computed independently by the simulator.
    for d in m2["delays"].as_array().unwrap() {
        let e = f(&d["measured_ns"]) - f(&d["true_ns"]);
        assert!((e - f(&d["error_ns"])).abs() < 1e-6);
    }

    // M3: nothing held, delays within 20 ns of the truth, precision at least 3 times M2's.
    let b3 = &m3["blocked"];
    for k in [
        "bringup_forward",
        "bringup_return",
        "cyclic_forward",
        "cyclic_return",
    ] {
        assert_eq!(u(&b3[k]), 0, "M3 holds nothing: {b3}");
    }
    assert!(u(&b3["cyclic_frames"]) > 60_000);
    for d in m3["delays"].as_array().unwrap() {
        assert!(f(&d["error_ns"]).abs() <= 20.0, "M3 delay: {d}");
    }
    let p2 = f(&m2["slave_spread"]["p99_abs"]);
    let p3 = f(&m3["slave_spread"]["p99_abs"]);
    assert!(p2 >= 3.0 * p3, "precision p99: M2 {p2} ns, M3 {p3} ns");
    // The master and the slaves: M3 as close as M1 (tens of ns), M2 hundreds of us apart.
    assert!(f(&m3["master_minus_reference"]["max_abs"]) < 200.0, "{m3}");
    assert!(f(&m2["master_minus_reference"]["max_abs"]) > 10_000.0);
    // gPTP: the master within 100 ns RMS of the grandmaster, the bridge.
    let g = &m3["gptp"];
    assert_eq!(g["bridge_is_grandmaster"], true);
    assert!(f(&g["offset"]["rms"]) < 100.0, "{g}");
    assert!(u(&g["offset"]["n"]) >= 59_000);
    assert!((f(&g["measured_link_delay_ns"]) - f(&g["true_link_delay_ns"])).abs() < 20.0);
    assert!(m1["gptp"].is_null() && m2["gptp"].is_null());
    // Cross traffic towards the master in the best-effort time: about half of it busy.
    for m in [m2, m3] {
        let n = u(&m["cross_traffic_frames"]);
        assert!((150_000..300_000).contains(&n), "{n}");
    }
    assert!(m1["cross_traffic_frames"].is_null());
    assert!(u(&g["held_by_cross_traffic"]) > 0);

    let fi = &j["findings"];
    assert_eq!(fi["m2_blocks_dc_frames"], true);
    assert_eq!(fi["m3_blocked_frames"], 0);
    assert_eq!(fi["m3_delays_within_20ns"], true);
    assert_eq!(fi["precision_at_least_3x_better"], true);
    assert_eq!(fi["gptp_offset_under_100ns"], true);
    assert!(fi["notes"].as_array().unwrap().len() >= 3);

    for name in [
        "summary.json",
        "summary.csv",
        "table.txt",
        "report.html",
        "tsn_histograms.svg",
        "tsn_histograms.png",
        "tsn_series_precision.png",
        "tsn_series_master_minus_reference.svg",
        "tsn_series_gate_hold.png",
        "tsn_gptp_offset.svg",
    ] {
        let p = out.join(name);
        assert!(
            std::fs::metadata(&p)
                .map(|m| m.len() > 100)
                .unwrap_or(false),
            "{} missing",
            p.display()
        );
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("tsn_histograms.svg") && html.contains("M3"));

    // The captures, read back without Wireshark (its dissectors are the test below): EtherCAT
    // frames on every variant's wire, gPTP (EtherType 0x88F7) only on M3's.
    for v in ["M1", "M2", "M3"] {
        let types = ethertypes(&pcap.join(format!("{v}.pcap")));
        assert!(types.contains(&0x88a4), "{v}: {types:x?}");
        assert_eq!(types.contains(&0x88f7), v == "M3", "{v}: {types:x?}");
    }
}

/// The EtherTypes of a pcap's frames (under any VLAN tags).
fn ethertypes(p: &Path) -> std::collections::BTreeSet<u16> {
    let file = std::fs::File::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let mut r = pcap_file::pcap::PcapReader::new(file).expect("a pcap header");
    let mut types = std::collections::BTreeSet::new();
    while let Some(packet) = r.next_packet() {
        let d = packet.expect("a whole packet").data;
        let mut at = 12;
        while matches!(u16::from_be_bytes([d[at], d[at + 1]]), 0x8100 | 0x88a8) {
            at += 4;
        }
        types.insert(u16::from_be_bytes([d[at], d[at + 1]]));
    }
    types
}

/// tshark, or a panic saying so: the test that calls it is `#[ignore = "needs tshark"]` and
/// runs only when asked for, where a missing tshark is a failure, not a pass.
fn tshark() -> Command {
    let ok = Command::new("tshark")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(ok, "this test needs tshark: apt-get install tshark");
    Command::new("tshark")
}

/// A short run's captures through Wireshark's dissectors: EtherCAT and 802.1AS frames, none
/// malformed, every gPTP message type on M3's wire.
#[test]
#[ignore = "needs tshark"]
fn tshark_reads_every_variant_s_capture_without_malformed_frames() {
    let out = tmp("tshark");
    let pcap = tmp("tshark-pcap");
    run(
        &out,
        &[
            "--duration-s",
            "3",
            "--pcap",
            pcap.to_str().unwrap(),
            "--pcap-seconds",
            "0.5",
        ],
    );
    for v in ["M1", "M2", "M3"] {
        let p = pcap.join(format!("{v}.pcap"));
        let o = tshark()
            .args(["-r"])
            .arg(&p)
            .args(["-q", "-z", "io,phs"])
            .output()
            .unwrap();
        let phs = String::from_utf8_lossy(&o.stdout);
        assert!(phs.contains("ecat"), "{v}: {phs}");
        assert_eq!(
            phs.contains("ptp"),
            v == "M3",
            "{v}: gPTP only in M3: {phs}"
        );
        let o = tshark()
            .args(["-r"])
            .arg(&p)
            .args(["-Y", "_ws.malformed"])
            .output()
            .unwrap();
        assert!(
            o.stdout.is_empty(),
            "{v}: malformed frames: {}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
    // Every gPTP message type went over the master's wire.
    let o = tshark()
        .args(["-r"])
        .arg(pcap.join("M3.pcap"))
        .args(["-Y", "ptp", "-T", "fields", "-e", "ptp.v2.messagetype"])
        .output()
        .unwrap();
    let types: std::collections::BTreeSet<String> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(str::to_string)
        .collect();
    for t in ["0x00", "0x02", "0x03", "0x08", "0x0a", "0x0b"] {
        assert!(types.contains(t), "message type {t} missing: {types:?}");
    }
}

/// summary.json without wall times.
fn without_wall_time(p: &Path) -> String {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.contains("\"wall_s\""))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn a_run_is_reproducible() {
    let a = tmp("det-a");
    let b = tmp("det-b");
    run(&a, &["--duration-s", "3"]);
    run(&b, &["--duration-s", "3"]);
    let ja = without_wall_time(&a.join("summary.json"));
    assert!(ja.len() > 2000);
    assert_eq!(ja, without_wall_time(&b.join("summary.json")));
}

fn preset_text() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../presets/tsn-2020.toml"
    ))
    .unwrap()
}

fn with_ethercat_windows(windows: &str) -> String {
    let mut t = preset_text();
    let start = t.find("[[bridge.ethercat_port.window]]").unwrap();
    let end = t.find("# Egress towards the master").unwrap();
    t.replace_range(start..end, windows);
    t
}

#[test]
fn bad_gate_schedules_are_refused_with_a_clear_message() {
    let dir = tmp("bad");
    let cases = [
        (
            "overlap",
            "[[bridge.ethercat_port.window]]\nopen_ns = 0\nclose_ns = 300000\n\n[[bridge.ethercat_port.window]]\nopen_ns = 250000\nclose_ns = 400000\n\n",
            "overlap from 250000 to 300000",
        ),
        (
            "longer",
            "[[bridge.ethercat_port.window]]\nopen_ns = 0\nclose_ns = 1200000\n\n",
            "longer than the gate cycle",
        ),
        (
            "empty",
            "[bridge.ethercat_port]\n\n",
            "gate control list is empty",
        ),
    ];
    for (name, windows, expect) in cases {
        let p = dir.join(format!("{name}.toml"));
        std::fs::write(&p, with_ethercat_windows(windows)).unwrap();
        let o = ecsync()
            .args(["tsn", "run", "--config"])
            .arg(&p)
            .args(["--out"])
            .arg(dir.join("out"))
            .output()
            .unwrap();
        assert!(!o.status.success(), "{name} accepted");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(expect), "{name}: {e}");
        assert!(e.contains("bridge.ethercat_port.window"), "{name}: {e}");
        assert!(
            e.contains(&format!("{name}.toml:")),
            "{name}: names the file and line: {e}"
        );
        assert!(!e.contains("panicked"), "{e}");
        assert!(!dir.join("out").join("summary.json").exists());
    }
}

/// A report folder that cannot be written (a file in its place) fails before the variants run,
/// naming `--out` and the fix.
#[test]
fn an_unwritable_out_fails_before_the_runs() {
    let dir = tmp("unwritable");
    let file = dir.join("a-file");
    std::fs::write(&file, b"not a folder").unwrap();
    let o = ecsync()
        .args(["tsn", "run", "--json", "--out"])
        .arg(file.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--out: cannot write into"), "{err}");
    assert!(!err.contains("running "), "no variant started: {err}");
    assert!(o.stdout.is_empty());
}
